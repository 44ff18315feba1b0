//! Tests of the generator against analytic cases: flat patches, energy bounds, shadow lengths,
//! masking of deep pits, anisotropy; and of the file and preview.

use super::generate::{run, Mode};
use super::*;
use biscale_core::artifact::{Artifact, Field};
use biscale_core::basis::LocalBasis;
use biscale_core::compress::ArrayData;
use biscale_core::sampling::HemisphereGrid;
use biscale_core::scene::Btf;
use half::f16;
use std::f64::consts::PI;

fn spec(hf: HeightField, brdf: Brdf, res: u32, m: u32, v: Option<u32>) -> BtfSpec {
    BtfSpec { resolution: res, local_basis: bins(m), view_grid: v, ..BtfSpec::new(hf, brdf) }
}

fn bins(m: u32) -> LocalBasis {
    LocalBasis::bins(m).unwrap()
}

/// Value of `btf` at texel `t`, view `v`, light `j`.
fn at(btf: &Btf, t: usize, v: usize, j: usize) -> [f32; 3] {
    btf.data()[(t * btf.view_count() + v) * btf.light_count() + j]
}

fn close(a: f32, b: f32, rel: f32) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()) + 1e-9
}

const LAMBERT: Brdf = Brdf::Lambertian { albedo: [0.8, 0.5, 0.25] };
const PHONG: Brdf = Brdf::Phong { kd: [0.3, 0.2, 0.1], ks: [0.5, 0.6, 0.7], exponent: 20.0 };
const ASHIKHMIN: Brdf = Brdf::AshikhminShirley { rd: [0.4, 0.3, 0.2], rs: [0.05, 0.1, 0.2], nu: 60.0, nv: 8.0 };

#[test]
fn flat_patches_are_the_analytic_tables() {
    let flat = HeightField::flat(16).unwrap();
    let mut s = spec(flat.clone(), LAMBERT, 32, 8, Some(12));
    let btf = synthesize(&s, None).unwrap();
    let expect = Btf::lambertian([0.8, 0.5, 0.25], bins(8)).unwrap();
    assert_eq!(
        (btf.spatial(), btf.local_basis(), btf.view_grid(), btf.data()),
        (expect.spatial(), expect.local_basis(), expect.view_grid(), expect.data())
    );
    // ... which is the analytic BRDF times the bin-mean cosine at every sample.
    let Brdf::Lambertian { albedo } = LAMBERT else { unreachable!() };
    for j in 0..64 {
        let c = btf.local_basis().grid().unwrap().bin_mean_cosine(j as u32);
        for (got, a) in at(&btf, 0, 0, j).into_iter().zip(albedo) {
            assert!(close(got, (a as f64 / PI * c) as f32, 1e-7));
        }
    }
    s.brdf = PHONG;
    let btf = synthesize(&s, None).unwrap();
    let expect = Btf::phong([0.3, 0.2, 0.1], [0.5, 0.6, 0.7], 20.0, bins(8), 12).unwrap();
    assert_eq!(
        (btf.spatial(), btf.local_basis(), btf.view_grid(), btf.data()),
        (expect.spatial(), expect.local_basis(), expect.view_grid(), expect.data())
    );
    // Zero amplitude in a recipe is a flat patch.
    for p in Pattern::ALL {
        let f = if p == Pattern::Weave || p == Pattern::Bricks || p == Pattern::Scales { 4 } else { 3 };
        s.height_field = HeightField::procedural(&Recipe::new(p, 0.0, f, 5), 32).unwrap();
        assert_eq!(synthesize(&s, None).unwrap().data(), expect.data(), "{p:?}");
    }
}

#[test]
fn ray_traced_flat_patch_equals_the_analytic_table() {
    // Force the ray tracer onto a flat (but not zero: height 0.3) patch: every texel, view
    // and light must reproduce the analytic table. The facet normal is exactly +Z and the frame
    // exactly the patch frame, so the only differences are the f64 sums over the 2x2
    // supersamples before rounding to f32: 1e-6 relative.
    let mut flat = HeightField::flat(8).unwrap();
    flat.h.fill(0.3);
    for brdf in [LAMBERT, PHONG, ASHIKHMIN] {
        let s = BtfSpec { supersample: 2, ..spec(flat.clone(), brdf, 4, 4, Some(5)) };
        let traced = run(&s, None, Mode::Traced).unwrap();
        let analytic = synthesize(&s, None).unwrap();
        assert_eq!(traced.texel_count(), 16);
        let expect_views = analytic.view_count();
        for t in 0..16 {
            for v in 0..traced.view_count() {
                for j in 0..traced.light_count() {
                    let a = at(&analytic, 0, v.min(expect_views - 1), j);
                    let b = at(&traced, t, v, j);
                    for c in 0..3 {
                        assert!(close(a[c], b[c], 1e-6), "{brdf:?} t={t} v={v} j={j}: {a:?} vs {b:?}");
                    }
                }
            }
        }
    }
}

#[test]
fn white_lambertian_never_exceeds_its_albedo() {
    // sum_j b_j 2 pi / M <= albedo for every texel and view (module docs: n . dbar_j never
    // exceeds the bin's mean clamped cosine, whose integral over the facet's hemisphere is pi),
    // up to the f32 rounding of M values (M ulp ~ 1e-5 relative). Shadows must make some sums
    // clearly smaller, or the test would not exercise them.
    for (p, a, f) in [(Pattern::Bumps, 0.08, 3), (Pattern::Holes, 0.15, 2), (Pattern::Bricks, 0.05, 4)] {
        let hf = HeightField::procedural(&Recipe::new(p, a, f, 11), 48).unwrap();
        let s = BtfSpec { supersample: 2, ..spec(hf, Brdf::Lambertian { albedo: [1.0; 3] }, 12, 8, Some(6)) };
        let btf = synthesize(&s, None).unwrap();
        let w = btf.local_basis().grid().unwrap().bin_solid_angle();
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        for t in 0..btf.texel_count() {
            for v in 0..btf.view_count() {
                let sum: f64 = (0..btf.light_count()).map(|j| at(&btf, t, v, j)[0] as f64 * w).sum();
                lo = lo.min(sum);
                hi = hi.max(sum);
            }
        }
        assert!(hi <= 1.0 + 1e-5, "{p:?}: {hi}");
        assert!(lo < 0.9, "{p:?}: no shadowing seen ({lo})");
    }
}

#[test]
fn interreflection_adds_light_within_the_energy_bound() {
    // One bounce adds light wherever facets see each other, never removes any, and direct plus
    // one bounce cannot exceed the albedo (the full multiple-bounce answer does not). The
    // bounce is a Monte Carlo estimate (16 rays x 4 samples per texel); in the pits of
    // 'holes' the bounce is at most ~0.2 of the albedo, and its relative noise ~1/sqrt(64)
    // = 12%, so a 3% allowance over the bound is several standard deviations.
    let hf = HeightField::procedural(&Recipe::new(Pattern::Holes, 0.15, 2, 3), 48).unwrap();
    let albedo = 0.9f32;
    let base = BtfSpec { supersample: 2, ..spec(hf, Brdf::Lambertian { albedo: [albedo; 3] }, 12, 8, Some(4)) };
    let direct = synthesize(&base, None).unwrap();
    let both = synthesize(&BtfSpec { interreflection: true, ..base.clone() }, None).unwrap();
    let w = direct.local_basis().grid().unwrap().bin_solid_angle();
    let (mut gained, mut max_sum) = (0.0f64, 0.0f64);
    for (a, b) in direct.data().iter().zip(both.data()) {
        assert!(b[0] >= a[0], "{a:?} -> {b:?}");
        gained = gained.max((b[0] - a[0]) as f64);
    }
    for t in 0..both.texel_count() {
        for v in 0..both.view_count() {
            let sum: f64 = (0..both.light_count()).map(|j| at(&both, t, v, j)[0] as f64 * w).sum();
            max_sum = max_sum.max(sum);
        }
    }
    assert!(gained > 0.01, "the bounce added nothing ({gained})");
    assert!(max_sum <= albedo as f64 * 1.03, "{max_sum}");
    // Deterministic: the same spec gives the same table (per-point seeded sequences).
    assert_eq!(synthesize(&BtfSpec { interreflection: true, ..base }, None).unwrap().data(), both.data());
}

#[test]
fn shadow_of_a_ridge_has_length_height_times_tan_theta() {
    // A ridge of height H along y (samples 80..88 of 200 at H, others 0), seen from straight
    // above (no view axis). A light from the -x side (d.x < 0) darkens the ridge's far slope
    // (facing away) and then the floor until the shadow ray from the floor clears the ridge's
    // top corner at x0 = 87/200: the dark run along x is H |d.x| / d.z = H tan(theta) |cos(phi)|
    // long. Measured as the sum over texels of (1 - b / b_lit), where b_lit is the flat lit
    // floor's analytic value; each of the run's two ends is resolved to one sample spacing
    // (1/128 with 64 texels x 2 samples), so the length is within 2/128. The sample grid is
    // not aligned with the height samples (200 vs 128), so no sample sits on a crease.
    let n = 200usize;
    let h_ridge = 0.1f32;
    let mut h = vec![0.0f32; n * n];
    for j in 0..n {
        for i in 80..88 {
            h[j * n + i] = h_ridge;
        }
    }
    let hf = HeightField { width: n as u32, height: n as u32, h };
    let s = BtfSpec { supersample: 2, ..spec(hf, Brdf::Lambertian { albedo: [1.0; 3] }, 64, 8, None) };
    let btf = synthesize(&s, None).unwrap();
    let grid = btf.local_basis().grid().unwrap();
    let mut checked = 0;
    let mut lengths = vec![];
    for j in 0..grid.len() {
        let d = grid.bin_direction(j as u32).as_dvec3().normalize();
        let predicted = h_ridge as f64 * -d.x / d.z;
        if d.x >= 0.0 || !(0.03..0.85).contains(&predicted) {
            continue;
        }
        let lit = (grid.bin_mean_cosine(j as u32) / PI) as f32;
        for row in [0usize, 17, 63] {
            let dark: f64 =
                (0..64).map(|tx| (1.0 - at(&btf, row * 64 + tx, 0, j)[0] / lit).max(0.0) as f64).sum::<f64>() / 64.0;
            assert!(
                (dark - predicted).abs() <= 2.0 / 128.0 + 1e-6,
                "light {j} d={d}: dark {dark}, predicted {predicted}"
            );
        }
        let dark0: f64 = (0..64).map(|tx| (1.0 - at(&btf, tx, 0, j)[0] / lit).max(0.0) as f64).sum::<f64>() / 64.0;
        lengths.push((d.z, dark0));
        checked += 1;
    }
    assert!(checked >= 8, "only {checked} lights checked");
    // Grazing lights cast longer shadows than overhead ones: the mean measured length per
    // ring of bins (equal z) falls as the ring rises.
    let mut rings: Vec<(f64, f64, usize)> = vec![];
    for (z, len) in lengths {
        match rings.iter_mut().find(|r| (r.0 - z).abs() < 1e-5) {
            Some(r) => (r.1, r.2) = (r.1 + len, r.2 + 1),
            None => rings.push((z, len, 1)),
        }
    }
    rings.sort_by(|a, b| a.0.total_cmp(&b.0));
    let means: Vec<f64> = rings.iter().map(|r| r.1 / r.2 as f64).collect();
    assert!(means.len() >= 3 && means.windows(2).all(|w| w[0] > 1.3 * w[1]), "{rings:?}");
}

#[test]
fn grazing_lights_shadow_more_of_a_bumpy_patch() {
    let hf = HeightField::procedural(&Recipe::new(Pattern::Bumps, 0.08, 3, 2), 64).unwrap();
    let s = spec(hf, Brdf::Lambertian { albedo: [1.0; 3] }, 16, 8, None);
    let btf = synthesize(&s, None).unwrap();
    let grid = btf.local_basis().grid().unwrap();
    let dark = |j: usize| (0..btf.texel_count()).filter(|&t| at(&btf, t, 0, j)[0] == 0.0).count();
    let overhead = grid.bin_of(glam::Vec3::Z).unwrap() as usize; // a centre bin
    let grazing = 0; // a corner bin of the outer ring, z ~ 0.12
    assert!(grid.bin_direction(0).z < 0.25, "bin 0 is in the outer ring");
    assert_eq!(dark(overhead), 0);
    assert!(dark(grazing) > btf.texel_count() / 10, "{}", dark(grazing));
}

#[test]
fn deep_pit_bottoms_are_hidden_at_grazing_views() {
    // A square pit 0.5 deep over samples 24..40 of 64 (bottom at samples 24..=39): the albedo
    // map paints its bottom red (cells 24..=38) and everything else green. A bottom point is
    // visible along e only if its ray clears the rim; the longest horizontal run inside the
    // pit is its diagonal, sqrt(2) * 17/64, so for tan(theta_e) > sqrt(2) * 17/64 / 0.5 = 0.75
    // no bottom point is visible: the red channel must be exactly 0 for every texel and light.
    // Nearly overhead, the bottom is seen (red > 0).
    let n = 64usize;
    let mut h = vec![0.0f32; n * n];
    let mut rgb = vec![[0.0, 1.0, 0.0]; n * n];
    for j in 24..40 {
        for i in 24..40 {
            h[j * n + i] = -0.5;
            if i < 39 && j < 39 {
                rgb[j * n + i] = [1.0, 0.0, 0.0];
            }
        }
    }
    let hf = HeightField { width: 64, height: 64, h };
    let map = AlbedoMap { width: 64, height: 64, rgb };
    let s = BtfSpec {
        albedo_map: Some(map),
        supersample: 2,
        ..spec(hf, Brdf::Lambertian { albedo: [1.0; 3] }, 32, 4, Some(12))
    };
    let btf = synthesize(&s, None).unwrap();
    let vg = btf.view_grid().unwrap();
    let (mut grazing, mut overhead) = (0, 0);
    for v in 0..vg.len() {
        let e = vg.bin_direction(v as u32).as_dvec3();
        let tan = (1.0 - e.z * e.z).sqrt() / e.z;
        let red: f64 = (0..btf.texel_count())
            .flat_map(|t| (0..16).map(move |j| (t, j)))
            .map(|(t, j)| at(&btf, t, v, j)[0] as f64)
            .sum();
        if tan > 0.8 {
            assert_eq!(red, 0.0, "view {v} (tan {tan}) sees the pit's bottom");
            grazing += 1;
        } else if tan < 0.3 {
            assert!(red > 0.0, "view {v} (tan {tan}) does not see the pit's bottom");
            overhead += 1;
        }
    }
    assert!(grazing >= 60 && overhead >= 4, "{grazing} grazing, {overhead} overhead views");
}

/// The bin that 90 degrees of rotation about +Z takes bin `j` to: the concentric map turns
/// `(a, b)` into `(-b, a)`, i.e. `(col, row)` into `(m - 1 - row, col)`.
fn rotate_bin(g: HemisphereGrid, j: usize) -> usize {
    let m = g.m as usize;
    let (col, row) = (j % m, j / m);
    col * m + (m - 1 - row)
}

#[test]
fn swapping_nu_and_nv_rotates_the_ashikhmin_shirley_lobe() {
    // f_{nu,nv}(R l, R v) = f_{nv,nu}(l, v) for R = 90 degrees about the normal (the exponent
    // nu (h.x)^2 + nv (h.y)^2 sees (h.x, h.y) -> (-h.y, h.x)). So the table with swapped
    // exponents is the table read at rotated bins. Bin directions are f32 (6e-8 relative),
    // which exponents ~60 amplify to ~4e-6: 1e-4 relative covers it.
    let flat = HeightField::flat(8).unwrap();
    let a = synthesize(&spec(flat.clone(), ASHIKHMIN, 8, 8, Some(8)), None).unwrap();
    let Brdf::AshikhminShirley { rd, rs, nu, nv } = ASHIKHMIN else { unreachable!() };
    let b = synthesize(&spec(flat, Brdf::AshikhminShirley { rd, rs, nu: nv, nv: nu }, 8, 8, Some(8)), None).unwrap();
    let (lg, vg) = (a.local_basis().grid().unwrap(), a.view_grid().unwrap());
    // The rotation is what it claims.
    for j in 0..lg.len() {
        let (d, r) = (lg.bin_direction(j as u32), lg.bin_direction(rotate_bin(lg, j) as u32));
        assert!((glam::Vec3::new(-d.y, d.x, d.z) - r).length() < 1e-6);
    }
    let mut max_diff = 0.0f32;
    for v in 0..vg.len() {
        for j in 0..lg.len() {
            let (x, y) = (at(&b, 0, v, j), at(&a, 0, rotate_bin(vg, v), rotate_bin(lg, j)));
            for c in 0..3 {
                assert!(close(x[c], y[c], 1e-4), "v={v} j={j}: {x:?} vs {y:?}");
                let z = at(&a, 0, v, j)[c];
                max_diff = max_diff.max((x[c] - z).abs() / x[c].max(z));
            }
        }
    }
    assert!(max_diff > 0.5, "the two lobes barely differ ({max_diff}): not anisotropic");
}

#[test]
fn bad_specs_are_errors() {
    let hf = HeightField::procedural(&Recipe::new(Pattern::Bumps, 0.05, 2, 1), 16).unwrap();
    let ok = spec(hf.clone(), LAMBERT, 8, 4, Some(4));
    assert!(synthesize(&ok, None).is_ok());
    for bad in [
        BtfSpec { resolution: 0, ..ok.clone() },
        BtfSpec { view_grid: Some(65), ..ok.clone() },
        BtfSpec { view_grid: Some(0), ..ok.clone() },
        BtfSpec { view_grid: None, brdf: PHONG, ..ok.clone() },
        BtfSpec { supersample: 0, ..ok.clone() },
        BtfSpec { interreflection: true, bounce_rays: 0, ..ok.clone() },
        BtfSpec { brdf: Brdf::Phong { kd: [0.1; 3], ks: [0.1; 3], exponent: -1.0 }, ..ok.clone() },
        BtfSpec { height_field: HeightField { width: 4, height: 4, h: vec![0.0; 15] }, ..ok.clone() },
        BtfSpec { height_field: HeightField { width: 4, height: 4, h: vec![f32::NAN; 16] }, ..ok.clone() },
        BtfSpec { albedo_map: Some(AlbedoMap { width: 1, height: 1, rgb: vec![[f32::NAN; 3]] }), ..ok.clone() },
    ] {
        assert!(synthesize(&bad, None).is_err(), "{bad:?}");
    }
}

#[test]
fn progress_counts_every_texel_and_results_are_deterministic() {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let hf = HeightField::procedural(&Recipe::new(Pattern::Scales, 0.05, 4, 1), 32).unwrap();
    let s = spec(hf, PHONG, 8, 4, Some(4));
    let (calls, last) = (AtomicUsize::new(0), AtomicUsize::new(0));
    let cb = |k: usize| {
        calls.fetch_add(1, Ordering::Relaxed);
        last.fetch_max(k, Ordering::Relaxed);
    };
    let a = synthesize(&s, Some(&cb)).unwrap();
    assert_eq!((calls.into_inner(), last.into_inner()), (64, 64));
    assert_eq!(synthesize(&s, None).unwrap(), a);
    // Specular and anisotropic BTFs of every recipe are finite and non-negative.
    for p in Pattern::ALL {
        let hf = HeightField::procedural(&Recipe::new(p, 0.06, 2, 1), 32).unwrap();
        let btf = synthesize(&spec(hf, ASHIKHMIN, 4, 4, Some(4)), None).unwrap();
        assert!(btf.data().iter().flatten().all(|x| x.is_finite() && *x >= 0.0), "{p:?}");
    }
}

#[test]
fn files_round_trip_and_corruption_is_an_error_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let hf = HeightField::procedural(&Recipe::new(Pattern::Weave, 0.05, 4, 1), 32).unwrap();
    let btf = synthesize(&BtfSpec { name: "weave \u{2713}".into(), ..spec(hf, PHONG, 8, 4, Some(4)) }, None).unwrap();
    let path = dir.path().join("w.btf");
    save_btf(&btf, &path, BtfEncoding::F32).unwrap();
    assert_eq!(load_btf(&path).unwrap(), btf);
    // View-independent and one-texel tables.
    let lam = Btf::lambertian([0.5; 3], bins(8)).unwrap();
    save_btf(&lam, &path, BtfEncoding::F32).unwrap();
    assert_eq!(load_btf(&path).unwrap(), lam);

    // f16: 11 significant bits, relative error <= 2^-11 for normal values (>= 6.1e-5), and
    // absolute <= 2^-25 below that (subnormal spacing 6e-8, half of it for rounding).
    save_btf(&btf, &path, BtfEncoding::F16).unwrap();
    let h = load_btf(&path).unwrap();
    // In memory, the same bytes decode to the same table as the file.
    let bytes = encode_btf(&btf, BtfEncoding::F16).unwrap();
    assert_eq!(decode_btf(&bytes, &path).unwrap(), h);
    assert!(decode_btf(&bytes[..bytes.len() - 1], &path).is_err(), "truncated in memory");
    for (a, b) in btf.data().iter().flatten().zip(h.data().iter().flatten()) {
        assert!((a - b).abs() <= a.abs() / 2048.0 + 3e-8, "{a} vs {b}");
    }
    // u8: per-texel scale, rounding error <= half a step = max / 510 (plus f32 rounding).
    save_btf(&btf, &path, BtfEncoding::U8).unwrap();
    let q = load_btf(&path).unwrap();
    let per = btf.view_count() * btf.light_count();
    for (ta, tb) in btf.data().chunks(per).zip(q.data().chunks(per)) {
        let max = ta.iter().flatten().copied().fold(0.0f32, f32::max);
        for (a, b) in ta.iter().flatten().zip(tb.iter().flatten()) {
            assert!((a - b).abs() <= max / 510.0 * (1.0 + 1e-5), "{a} vs {b} (max {max})");
        }
    }
    // Files are the documented size: f16 is half of f32's payload; u8 a quarter plus the scales.
    let payload = |e| btf_artifact(&btf, e).unwrap().arrays.iter().map(|a| a.data.bytes()).sum::<u64>() as usize;
    assert_eq!(payload(BtfEncoding::F32), btf.data().len() * 12);
    assert_eq!(payload(BtfEncoding::F16), btf.data().len() * 6);
    assert_eq!(payload(BtfEncoding::U8), btf.data().len() * 3 + btf.texel_count() * 4);
    for e in [BtfEncoding::F32, BtfEncoding::F16, BtfEncoding::U8] {
        let header = encode_btf(&btf, e).unwrap().len() - payload(e);
        assert!(header < 300 + btf.name().len(), "{e:?}: {header} header bytes");
    }

    // Corruption.
    save_btf(&btf, &path, BtfEncoding::F16).unwrap();
    let good = std::fs::read(&path).unwrap();
    let bad = dir.path().join("bad.btf");
    let check = |bytes: &[u8], what: &str| {
        std::fs::write(&bad, bytes).unwrap();
        let e = load_btf(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.btf") && e.contains(what), "{what}: {e}");
    };
    let mut flipped = good.clone();
    flipped[good.len() / 2] ^= 0x10;
    check(&flipped, "checksum");
    check(&good[..good.len() - 7], "truncated");
    check(&good[..10], "truncated");
    check(&[], "magic");
    check(b"GIF89a.................................", "magic");
    let mut version = good.clone();
    version[8] = 9;
    check(&version, "version 9");
    // Consistent files whose fields do not describe their arrays (as a buggy writer could
    // make): caught before any table is built.
    let artifact = || btf_artifact(&btf, BtfEncoding::F16).unwrap();
    let with = |name: &str, f: Field| artifact().with(name, f).encode();
    check(&with("width", Field::U64(4096)), "need");
    check(&with("width", Field::U64(4097)), "spatial size");
    check(&with("view_grid", Field::U64(0)), "need");
    check(&with("encoding", Field::Str("f64".into())), "unknown BTF encoding");
    check(&with("encoding", Field::Str("f32".into())), "stored as u16");
    check(&with("local_basis", Field::Str("cubemap:8".into())), "bins");
    check(&Artifact::new("form").encode(), "btf was expected");
    let mut nan = artifact();
    nan.arrays[0].data = ArrayData::U16(vec![f16::NAN.to_bits(); btf.data().len() * 3]);
    check(&nan.encode(), "non-finite");
    let e = load_btf(&dir.path().join("missing.btf")).unwrap_err().to_string();
    assert!(e.contains("missing.btf"), "{e}");
    // Values f16 cannot hold are refused at write time; the old file stays.
    let mut data = btf.data().to_vec();
    data[3][1] = 1e6;
    let big = Btf::new(btf.spatial(), btf.local_basis(), btf.view_grid(), data, btf.name()).unwrap();
    assert!(save_btf(&big, &path, BtfEncoding::F16).unwrap_err().to_string().contains("f16"));
    assert_eq!(std::fs::read(&path).unwrap(), good);
    // Nothing but the files written is left in the folder (atomic writes clean up).
    let mut names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    names.sort();
    assert_eq!(names, ["bad.btf", "w.btf"]);
    // A file of the BTF format before the shared container is named as such.
    std::fs::write(&bad, b"BSCBTF\0\0\x01\0\0\0").unwrap();
    assert!(load_btf(&bad).unwrap_err().to_string().contains("earlier biscale"));
}

#[test]
fn comparison_sheets_put_dense_compressed_and_error_side_by_side() {
    use crate::synth::comparison_sheet;
    let hf = HeightField::procedural(&Recipe::new(Pattern::Bricks, 0.05, 4, 1), 32).unwrap();
    let btf = synthesize(&spec(hf, LAMBERT, 8, 4, Some(3)), None).unwrap();
    let (lights, views) = ([0usize, 5, 15], [4usize, 0]);
    let dense = contact_sheet(&btf, &lights, &views).unwrap();
    // A compressed table off by a known amount in one texel: the left panel is the dense sheet,
    // the middle one differs only there, the error panel is black elsewhere and white at the
    // largest error; the gain is the dense peak over that error.
    let mut data = btf.data().to_vec();
    let (texel, bump) = (9usize, 0.01f32);
    for v in 0..9 {
        for j in 0..16 {
            data[(texel * 9 + v) * 16 + j][1] += bump;
        }
    }
    let other = Btf::new(btf.spatial(), btf.local_basis(), btf.view_grid(), data, "off").unwrap();
    let (img, gain) = comparison_sheet(&btf, &other, &lights, &views).unwrap();
    let (w, h) = dense.dimensions();
    assert_eq!(img.dimensions(), (3 * w + 16, h));
    for y in 0..h {
        for x in 0..w {
            assert_eq!(img.get_pixel(x, y), dense.get_pixel(x, y));
        }
    }
    let peak = btf.data().iter().enumerate().filter(|(i, _)| {
        let (v, j) = ((i / 16) % 9, i % 16);
        views.contains(&v) && lights.contains(&j)
    });
    let peak = peak.flat_map(|(_, p)| *p).fold(0.0f32, f32::max);
    assert!((gain - peak / bump).abs() <= 1e-3 * gain, "{gain} vs {}", peak / bump);
    // Texel 9 is (1, 1): at 4x, pixel (5, 5) of each tile; texel 0 at (1, 1).
    let err_x0 = 2 * (w + 8);
    assert_eq!(img.get_pixel(err_x0 + 5, 5).0, [0, 255, 0], "the bumped texel's green error is the panel's white");
    assert_eq!(img.get_pixel(err_x0 + 1, 1).0, [0, 0, 0], "no error elsewhere");
    assert_ne!(img.get_pixel(w + 8 + 5, 5), dense.get_pixel(5, 5), "the middle panel shows the compressed table");
    let small = Btf::lambertian([0.5; 3], btf.local_basis()).unwrap();
    assert!(comparison_sheet(&btf, &small, &lights, &views).is_err(), "different shapes");
}

#[test]
fn contact_sheets_lay_tiles_out_with_gaps() {
    let hf = HeightField::procedural(&Recipe::new(Pattern::Bricks, 0.05, 4, 1), 32).unwrap();
    let btf = synthesize(&spec(hf, LAMBERT, 8, 4, Some(3)), None).unwrap();
    let (lights, views) = ([0usize, 5, 15], [4usize, 0]);
    let img = contact_sheet(&btf, &lights, &views).unwrap();
    // 8 texels enlarged 4x to 32 px; 3 columns and 2 rows with 1 px gaps.
    assert_eq!(img.dimensions(), (3 * 32 + 2, 2 * 32 + 1));
    let peak = btf.data().iter().enumerate().filter(|(i, _)| {
        let (v, j) = ((i / 16) % 9, i % 16);
        views.contains(&v) && lights.contains(&j)
    });
    let peak = peak.flat_map(|(_, p)| *p).fold(0.0f32, f32::max);
    for (r, &v) in views.iter().enumerate() {
        for (c, &j) in lights.iter().enumerate() {
            for (tx, ty) in [(0u32, 0u32), (7, 2), (3, 7)] {
                let px = img.get_pixel(c as u32 * 33 + tx * 4 + 1, r as u32 * 33 + ty * 4 + 2).0;
                let b = at(&btf, (ty * 8 + tx) as usize, v, j);
                let expect = b.map(|x| (biscale_core::scene::image::linear_to_srgb(x / peak) * 255.0 + 0.5) as u8);
                assert_eq!(px, expect);
            }
        }
    }
    assert_eq!(img.get_pixel(32, 10).0, [0, 0, 0], "gap column");
    assert_eq!(img.get_pixel(10, 32).0, [0, 0, 0], "gap row");
    assert!(contact_sheet(&btf, &[16], &[0]).is_err());
    assert!(contact_sheet(&btf, &[0], &[9]).is_err());
    assert!(contact_sheet(&btf, &[], &[0]).is_err());
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("sheet.png");
    save_contact_sheet(&btf, &lights, &views, &p).unwrap();
    assert_eq!(image::open(&p).unwrap().to_rgb8(), img);
}

/// A synthesized BTF with every component its clusters can hold: the LPCA reconstruction is
/// exact to rounding (the rank test of `core::scene::lpca` on a real table).
#[test]
fn lpca_of_a_synthesized_btf_with_full_components_is_exact() {
    use biscale_core::scene::{LpcaBtf, LpcaSettings};
    let hf = HeightField::procedural(&Recipe::new(Pattern::Bumps, 0.06, 2, 1), 16).unwrap();
    let btf = synthesize(&spec(hf, PHONG, 4, 4, Some(3)), None).unwrap();
    // 16 texels in 2 clusters: at most 15 centred directions per cluster.
    let (lpca, r) = LpcaBtf::compress(&btf, &LpcaSettings::new(2, 15), 5).unwrap();
    assert!(r.relative_rms_error < 1e-5, "{r:?}");
    let d = lpca.decode().unwrap();
    let err =
        btf.data().iter().flatten().zip(d.data().iter().flatten()).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
    let max = btf.data().iter().flatten().copied().fold(0.0, f32::max);
    assert!(err <= 1e-5 * max, "{err} of {max}");
    // And fewer components do lose something on this table.
    let (_, r) = LpcaBtf::compress(&btf, &LpcaSettings::new(1, 2), 5).unwrap();
    assert!(r.relative_rms_error > 1e-3, "{r:?}");
}
