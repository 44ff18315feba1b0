//! GPU gathers against the f64 reference product `T L`.
//!
//! Tolerance: the sparse kernel sums each row's `n` non-negative products `T_ik L_k` in f32
//! (in column order, possibly with fused multiply-adds). Recursive summation of `n`
//! non-negative terms plus one rounding per product is within `(n + 1) u` of the exact sum
//! relative to that sum (`u = 2^-24`), whatever the order; we allow `(n + 2) u`
//! (`testing::f32_sum_bound`). A zero row must come out exactly 0. Every element is checked
//! after poisoning `L*` with NaN, so an element the kernel never wrote fails.

use super::gpu_or_skip;
use crate::{GpuError, GpuGather, TimingMethod};
use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::{bins, cubemap, f32_sum_bound, random_light, random_transfer};
use biscale_core::compress::{ArrayData, CompressContext, CompressError, CompressedForm, Compressor};
use biscale_core::gather::{reference_product, LocalRadiance};
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use biscale_kernels::{Count, Factor, KernelDesc, PassDesc, ScratchDesc};
use rand::{Rng, SeedableRng};

/// `form` uploaded with its compressor's program.
pub(crate) fn upload(ctx: &crate::GpuContext, c: &dyn Compressor, form: &CompressedForm) -> GpuGather {
    GpuGather::new(ctx, form, &c.kernels(form).unwrap()).unwrap()
}

/// Gather `t` with `light` on the GPU (the sparse program, or the given one) and compare
/// every element.
fn check_sparse(ctx: &crate::GpuContext, t: &TransferMatrix, light: &LightVector, program: Option<&KernelDesc>) {
    let form = Sparse.compress(t, &CompressContext::default()).unwrap();
    let mut g = match program {
        Some(p) => GpuGather::new(ctx, &form, p).unwrap(),
        None => upload(ctx, &Sparse, &form),
    };
    g.fill_lstar(f32::NAN).unwrap();
    g.gather(light).unwrap();
    let got = g.read_lstar().unwrap();
    assert_eq!((got.vertices(), got.local_dirs(), got.values().len()), (t.vertices(), t.local_dirs(), t.rows()));
    let reference = reference_product(t, light);
    for (r, (g, e)) in got.values().iter().zip(&reference).enumerate() {
        let n = t.csr().outer_view(r).unwrap().nnz();
        let bound = f32_sum_bound(n);
        for c in 0..3 {
            assert!(g[c].is_finite(), "row {r} channel {c} not written (or not finite): {}", g[c]);
            let err = (g[c] as f64 - e[c]).abs();
            assert!(
                err <= bound * e[c],
                "row {r} ({n} terms) channel {c}: GPU {} vs f64 {} (bound {bound} relative)",
                g[c],
                e[c]
            );
        }
    }
}

#[test]
fn sparse_matches_f64_reference_with_8x8_and_16x16_local_directions() {
    let ctx = gpu_or_skip!();
    // Odd seeds put a sun 10^6 times brighter than the sky into the light (the stiff case).
    for (local_grid, seeds) in [(8u32, 0..4u64), (16, 4..6)] {
        for seed in seeds {
            let t = random_transfer(5, local_grid, 6, 0.15, seed);
            check_sparse(ctx, &t, &random_light(6, seed + 50), None);
        }
    }
}

#[test]
fn sparse_matches_f64_reference_on_the_real_cubemap_with_an_hdr_sun() {
    let ctx = gpu_or_skip!();
    // N = 6 * 32^2 = 6144 columns, as in the reference settings.
    let t = random_transfer(3, 8, 32, 0.03, 11);
    check_sparse(ctx, &t, &random_light(32, 13), None);
    // A sun 10^7 times the sky in one texel, and in one texel of each face.
    let mut light = LightVector::constant(cubemap(32), [0.5, 0.4, 0.3]);
    light.power[1234] = [1e7, 9e6, 8e6];
    check_sparse(ctx, &t, &light, None);
    for face in 0..6 {
        light.power[face * 1024 + 517] = [3e6, 2e6, 1e6];
    }
    check_sparse(ctx, &t, &light, None);
}

#[test]
fn all_black_light_and_empty_rows_give_exact_zeros() {
    let ctx = gpu_or_skip!();
    // Density 0.02 over 24 columns leaves most rows empty.
    let t = random_transfer(8, 8, 2, 0.02, 3);
    assert!((0..t.rows()).any(|r| t.csr().outer_view(r).unwrap().nnz() == 0));
    check_sparse(ctx, &t, &LightVector::constant(cubemap(2), [0.0; 3]), None);
    check_sparse(ctx, &t, &random_light(2, 4), None);
}

#[test]
fn dispatch_folds_past_the_workgroups_per_dimension_limit() {
    let ctx = gpu_or_skip!();
    // The sparse kernel with one invocation per workgroup, so that rows > the limit forces
    // the host to fold the grid into y (with a program other than the compressor's own).
    let max = ctx.limits().max_compute_workgroups_per_dimension as usize;
    if max > 1 << 20 {
        eprintln!("skipped: max_compute_workgroups_per_dimension = {max} is too large to exceed cheaply");
        return;
    }
    let vertices = max / 64 + 2;
    let t = random_transfer(vertices, 8, 1, 0.5, 9);
    let mut program = Sparse.kernels(&Sparse.compress(&t, &CompressContext::default()).unwrap()).unwrap();
    program.wgsl = program.wgsl.replace("@workgroup_size(64)", "@workgroup_size(1)").replace("(inv, 64u)", "(inv, 1u)");
    assert!(t.rows() > max);
    check_sparse(ctx, &t, &random_light(1, 10), Some(&program));
}

/// A form of every narrow integer type, read back exactly by a two-pass program with a
/// scratch buffer and a meta value.
#[test]
fn narrow_integers_unpack_exactly_through_scratch_and_meta() {
    let ctx = gpu_or_skip!();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(21);
    let n = 37; // not a multiple of 4: the last packed word is partial
    let u8s: Vec<u8> = (0..n).map(|_| rng.gen()).collect();
    let i8s: Vec<i8> = (0..n).map(|i| if i == 0 { -128 } else { rng.gen() }).collect();
    let u16s: Vec<u16> = (0..n).map(|i| if i == 1 { u16::MAX } else { rng.gen() }).collect();
    let i16s: Vec<i16> = (0..n).map(|i| if i == 2 { i16::MIN } else { rng.gen() }).collect();
    let offset = 100_000u64;
    // n vertices of one direction over a resolution-1 cubemap (6 texels).
    let shape = biscale_core::basis::TransferShape::new(n, bins(1), cubemap(1));
    let mut form = CompressedForm::new("probe", shape)
        .with_array("bytes_u8", ArrayData::U8(u8s.clone()))
        .with_array("bytes_i8", ArrayData::I8(i8s.clone()))
        .with_array("halves_u16", ArrayData::U16(u16s.clone()))
        .with_array("halves_i16", ArrayData::I16(i16s.clone()));
    form.meta = [("offset".to_string(), offset)].into();
    form.lossless = true;
    let wgsl = r#"
@group(0) @binding(4) var<storage, read> bytes_u8: array<u32>;
@group(0) @binding(5) var<storage, read> bytes_i8: array<u32>;
@group(0) @binding(6) var<storage, read> halves_u16: array<u32>;
@group(0) @binding(7) var<storage, read> halves_i16: array<i32>;
@group(0) @binding(8) var<storage, read_write> stash: array<f32>;

@compute @workgroup_size(16)
fn first(inv: Invocation) {
    let i = thread_index(inv, 16u);
    if i >= params.threads { return; }
    stash[i] = f32(u16_at(halves_u16[i >> 1u], i) + meta_values[0]);
}

@compute @workgroup_size(16)
fn second(inv: Invocation) {
    let i = linear_thread(inv.wid, inv.nwg, inv.lid, 16u);
    if i >= params.threads { return; }
    let a = f32(u8_at(bytes_u8[i >> 2u], i));
    let b = f32(i8_at(bytes_i8[i >> 2u], i)) * 65536.0 + f32(i16_at(bitcast<u32>(halves_i16[i >> 1u]), i));
    store_lstar(i, vec3<f32>(a, b, stash[i]));
}
"#;
    let program = KernelDesc {
        kind: "probe".into(),
        wgsl: wgsl.into(),
        passes: vec![
            PassDesc { entry_point: "first".into(), threads: Count::of([Factor::Len("halves_u16".into())]) },
            PassDesc { entry_point: "second".into(), threads: Count::of([Factor::Rows]) },
        ],
        scratch: vec![ScratchDesc { name: "stash".into(), words: Count::of([Factor::Rows]) }],
        meta_keys: vec!["offset".into()],
        checks: vec![],
    };
    let mut g = GpuGather::new(ctx, &form, &program).unwrap();
    g.fill_lstar(f32::NAN).unwrap();
    g.gather(&LightVector::constant(cubemap(1), [0.0; 3])).unwrap();
    let got = g.read_lstar().unwrap();
    for i in 0..n {
        // All values are integers below 2^24 in magnitude: exact in f32.
        let expect = [u8s[i] as f32, i8s[i] as f32 * 65536.0 + i16s[i] as f32, (u16s[i] as u64 + offset) as f32];
        assert_eq!(got.values()[i], expect, "element {i}");
    }
}

#[test]
fn bad_forms_programs_and_lights_are_errors_not_panics() {
    let ctx = gpu_or_skip!();
    let t = random_transfer(2, 2, 1, 0.5, 1);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();

    let program = Sparse.kernels(&form).unwrap();
    let mut other = form.clone();
    other.kind = "nonesuch".into();
    let e = GpuGather::new(ctx, &other, &program).err().expect("a form of another kind accepted");
    assert!(matches!(&e, GpuError::Compress(CompressError::Malformed { array, .. }) if array == "kind"), "{e}");

    // A decreasing row pointer would loop for ~4 billion steps on the GPU.
    let mut bad = form.clone();
    if let ArrayData::U32(rp) = &mut bad.arrays[0].data {
        rp[1] = rp[2] + 1;
    }
    let e = GpuGather::new(ctx, &bad, &program).err().expect("malformed form accepted");
    assert!(matches!(&e, GpuError::Compress(CompressError::Malformed { array, .. }) if array == "row_ptr"), "{e}");

    // A WGSL global that names no form array.
    let mut p = program.clone();
    p.wgsl.push_str(
        "\n@group(0) @binding(9) var<storage, read> nope: array<u32>;\nfn use_nope() -> u32 { return nope[0]; }\n",
    );
    let e = GpuGather::new(ctx, &form, &p).err().expect("unknown binding accepted");
    assert!(matches!(&e, GpuError::Compress(CompressError::Malformed { array, .. }) if array == "nope"), "{e}");

    // A form array bound with the wrong element type.
    let mut p = program.clone();
    p.wgsl = p.wgsl.replace("values: array<f32>", "values: array<u32>").replace("values[i] *", "f32(values[i]) *");
    let e = GpuGather::new(ctx, &form, &p).err().expect("type mismatch accepted");
    assert!(
        matches!(&e, GpuError::Compress(CompressError::Malformed { array, what, .. }) if array == "values" && what.contains("is f32")),
        "{e}"
    );

    // WGSL that does not compile is a parse error with the source location.
    let mut p = program.clone();
    p.wgsl.push_str("\nfn broken( {\n");
    assert!(matches!(GpuGather::new(ctx, &form, &p), Err(GpuError::Wgsl { .. })));

    // A scratch buffer past the binding limit is refused before anything is allocated.
    let mut p = program.clone();
    p.wgsl.push_str(
        "\n@group(0) @binding(9) var<storage, read_write> huge: array<f32>;\nfn use_huge() { huge[0] = 1.0; }\n",
    );
    p.scratch.push(ScratchDesc { name: "huge".into(), words: Count::of([Factor::Const(1 << 40)]) });
    let e = GpuGather::new(ctx, &form, &p).err().expect("huge scratch accepted");
    assert!(
        matches!(&e, GpuError::Limit { limit, .. } if *limit == "max_storage_buffer_binding_size" || *limit == "max_buffer_size"),
        "{e}"
    );
    assert!(e.to_string().contains("huge"), "{e}");

    // Lights of the wrong size or with NaN.
    let mut g = upload(ctx, &Sparse, &form);
    assert!(matches!(g.gather(&random_light(2, 0)), Err(GpuError::Input(_))));
    let mut light = random_light(1, 0);
    light.power[3][1] = f32::NAN;
    let e = g.gather(&light).unwrap_err();
    assert!(e.to_string().contains("texel 3"), "{e}");
}

#[test]
fn gather_timing_gives_finite_medians_per_pass() {
    let ctx = gpu_or_skip!();
    let t = random_transfer(16, 8, 4, 0.2, 2);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let mut g = upload(ctx, &Sparse, &form);
    let timing = g.time_gather(&random_light(4, 2), 3).unwrap();
    assert_eq!(timing.repetitions, 3);
    assert!(timing.median_ms.is_finite() && timing.median_ms >= 0.0, "{timing:?}");
    match timing.method {
        TimingMethod::GpuTimestamps => {
            assert_eq!(timing.passes.len(), 1);
            assert_eq!(timing.passes[0].name, biscale_kernels::ROW_ENTRY);
        }
        TimingMethod::WallClock => assert!(timing.passes.is_empty()),
    }
    // Timing leaves a correct L* behind.
    let got = g.read_lstar().unwrap();
    let reference = reference_product(&t, &random_light(4, 2));
    assert!(biscale_core::gather::relative_l2_error(got.values(), &reference) < 1e-6);
}

/// The timestamp path (query sets, resolve, read-back, per-pass medians), which the default
/// policy never takes on a CPU adapter, run by forcing it: on any adapter that advertises
/// timestamp queries (lavapipe does) a two-pass gather must report per-pass timestamps under
/// the kernels' names and leave a correct `L*`, and `Never` must fall back to the wall clock.
#[test]
fn forced_timestamps_time_every_pass_and_never_means_wall_clock() {
    use crate::{GpuContext, TimestampPolicy};
    use biscale_compressors::bicluster::Bicluster;
    let _ = gpu_or_skip!(); // no adapter at all: skip
    let t = random_transfer(24, 4, 4, 0.3, 5);
    let light = random_light(4, 6);
    let bicluster = Bicluster { block_vertices: 8, ..Bicluster::default() };
    let form = bicluster.compress(&t, &CompressContext::default()).unwrap();
    let kernels = bicluster.kernels(&form).unwrap();
    let reference = reference_product(&t, &light);

    let never = GpuContext::with_timestamps(TimestampPolicy::Never).unwrap();
    assert!(!never.has_timestamps());
    let timing = GpuGather::new(&never, &form, &kernels).unwrap().time_gather(&light, 2).unwrap();
    assert_eq!(timing.method, TimingMethod::WallClock);
    assert!(timing.passes.is_empty());

    let always = GpuContext::with_timestamps(TimestampPolicy::Always).unwrap();
    assert_eq!(always.has_timestamps(), always.adapter().timestamp_queries, "Always uses every advertised query");
    if !always.has_timestamps() {
        eprintln!("SKIPPING the timestamp half: {} has no timestamp queries", always.adapter());
        return;
    }
    let mut g = GpuGather::new(&always, &form, &kernels).unwrap();
    let timing = g.time_gather(&light, 3).unwrap();
    assert_eq!(timing.method, TimingMethod::GpuTimestamps);
    assert_eq!(timing.repetitions, 3);
    let names: Vec<&str> = timing.passes.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(names, ["bicluster_sums", biscale_kernels::ROW_ENTRY]);
    for p in &timing.passes {
        assert!(p.median_ms.is_finite() && p.median_ms >= 0.0, "{timing:?}");
    }
    assert!(timing.median_ms.is_finite() && timing.median_ms >= 0.0, "{timing:?}");
    eprintln!("forced timestamps on {}: {timing:?}", always.adapter());
    let got = g.read_lstar().unwrap();
    assert!(biscale_core::gather::relative_l2_error(got.values(), &reference) < 1e-6);
}

/// f16 bits to f32 (normal, subnormal, zero; the forms hold no infinities).
fn f16_to_f32(b: u16) -> f32 {
    let (sign, exp, frac) = ((b >> 15) as u32, ((b >> 10) & 0x1f) as i32, (b & 0x3ff) as f32);
    let mag = if exp == 0 { frac * 2f32.powi(-24) } else { (1.0 + frac / 1024.0) * 2f32.powi(exp - 15) };
    if sign == 1 {
        -mag
    } else {
        mag
    }
}

#[test]
fn bicluster_matches_f64_reference() {
    // The f64 reference is the exact product of the matrix the form stands for. Pass 1 sums l_b signed products
    // code * (L_k / q) in f32: error <= (l_b + 2) u A_b with A_b = sum |code| L_k / q. Pass 2
    // sums the row's r_i scalars: error <= r_i u sum |a_b| plus the pass-1 errors. We allow
    // u (r_i sum_b |a_b| + sum_b (l_b + 3) A_b), computed per row and channel in f64.
    // The lossy form (budget 0.3) is an ordinary form of T' = T - E: the same kernels must
    // compute T' L, so its reference is the f64 product with the decompressed T'.
    use biscale_compressors::bicluster::{decompress, Bicluster, BiclusterView};
    let ctx = gpu_or_skip!();
    let u = f32::EPSILON as f64 / 2.0;
    for (seed, block_vertices, error_budget) in [(1u64, 4usize, 0.0), (2, 0, 0.0), (3, 4, 0.3)] {
        let t = random_transfer(24, 8, 4, 0.2, seed);
        let bicluster = Bicluster { block_vertices, error_budget, ..Bicluster::default() };
        let form = bicluster.compress(&t, &CompressContext { seed, progress: None, sweep: None }).unwrap();
        assert_eq!(form.lossless, error_budget == 0.0);
        let t = decompress(&form).unwrap();
        let view = BiclusterView::new(&form).unwrap();
        for light in [random_light(4, seed + 20), random_light(4, seed + 21)] {
            let mut g = upload(ctx, &bicluster, &form);
            g.fill_lstar(f32::NAN).unwrap();
            g.gather(&light).unwrap();
            let got = g.read_lstar().unwrap();
            let reference = reference_product(&t, &light);
            let q = view.value_scale as f64;
            let (mut a, mut abs) = (vec![[0.0f64; 3]; view.biclusters()], vec![[0.0f64; 3]; view.biclusters()]);
            let mut len = vec![0usize; view.biclusters()];
            for b in 0..view.biclusters() {
                let (ks, ts) = view.bicluster(b);
                len[b] = ks.len();
                for (&k, &code) in ks.iter().zip(ts) {
                    for c in 0..3 {
                        let l = light.power[k as usize][c] as f64 / q;
                        a[b][c] += code as f64 * l;
                        abs[b][c] += (code as f64).abs() * l;
                    }
                }
            }
            for i in 0..t.rows() {
                let ids: Vec<usize> = view.row_biclusters(i).collect();
                for c in 0..3 {
                    let sum_a: f64 = ids.iter().map(|&b| a[b][c].abs()).sum();
                    let sum_p: f64 = ids.iter().map(|&b| (len[b] as f64 + 3.0) * abs[b][c]).sum();
                    let bound = u * (ids.len() as f64 * sum_a + sum_p);
                    let v = got.values()[i][c];
                    assert!(v.is_finite(), "row {i} not written");
                    assert!(
                        (v as f64 - reference[i][c]).abs() <= bound,
                        "row {i} c{c}: {v} vs {} (bound {bound:e})",
                        reference[i][c]
                    );
                }
            }
        }
    }
}

/// The light transform with every sign made +: bounds |W L| and its rounding error.
fn abs_transform(light: &LightVector) -> Vec<[f64; 3]> {
    let r = light.cubemap().unwrap().resolution as usize;
    let mut out: Vec<[f64; 3]> = light.power.iter().map(|p| p.map(|x| (x as f64).abs())).collect();
    for face in out.chunks_mut(r * r) {
        let mut s = r;
        while s > 1 {
            let h = s / 2;
            let mut tmp = face.to_vec();
            for i in 0..h {
                for j in 0..h {
                    let at = |a: usize, b: usize| face[a * r + b];
                    let v: [f64; 3] = std::array::from_fn(|c| {
                        0.5 * (at(2 * i, 2 * j)[c]
                            + at(2 * i, 2 * j + 1)[c]
                            + at(2 * i + 1, 2 * j)[c]
                            + at(2 * i + 1, 2 * j + 1)[c])
                    });
                    for (a, b) in [(i, j), (i, j + h), (i + h, j), (i + h, j + h)] {
                        tmp[a * r + b] = v;
                    }
                }
            }
            for i in 0..s {
                face[i * r..i * r + s].copy_from_slice(&tmp[i * r..i * r + s]);
            }
            s = h;
        }
    }
    out
}

/// How far a GPU Haar gather of `light` can be from the CPU's gather `cpu` of the same form,
/// per row and channel. The CPU transforms and accumulates in f64. The f32 light transform
/// makes 3 roundings per level on values bounded by the all-plus transform `A = |W| |L|`
/// (`log2 R` levels), storing `l^` one more; the row sum of `n` terms `c_e l^_k` adds
/// `(n + 1) u` of `sum |c_e| A_k`; the CPU result's own f32 rounding adds `u |cpu|`. The bound
/// is `u ((n + 3 + 3 log2 R) sum_e |c_e| A_k + |cpu|)`. Signed lights (the moments') are
/// bounded through `|L|`.
pub(super) fn haar_bound(form: &CompressedForm, light: &LightVector, cpu: &LocalRadiance) -> Vec<[f64; 3]> {
    let u = f32::EPSILON as f64 / 2.0;
    let levels = light.cubemap().unwrap().resolution.trailing_zeros() as f64;
    let a = abs_transform(light);
    let row_ptr = form.u32s("row_ptr").unwrap();
    let idx = form.u16s("coeff_idx").unwrap();
    let coeff: Vec<f32> = match form.u16s("coeff_f16") {
        Ok(bits) => bits.iter().map(|&b| f16_to_f32(b)).collect(),
        Err(_) => form.f32s("coeff_val").unwrap().to_vec(),
    };
    (0..form.rows())
        .map(|row| {
            let span = row_ptr[row] as usize..row_ptr[row + 1] as usize;
            let n = span.len() as f64;
            std::array::from_fn(|c| {
                let mag: f64 = span.clone().map(|e| (coeff[e] as f64).abs() * a[idx[e] as usize][c]).sum();
                u * ((n + 3.0 + 3.0 * levels) * mag + (cpu.values()[row][c] as f64).abs())
            })
        })
        .collect()
}

/// Every element of the GPU gather `got` within `bound` of the CPU's `cpu`, and written.
fn assert_within_bound(what: &str, got: &LocalRadiance, cpu: &LocalRadiance, bound: &[[f64; 3]]) {
    for (row, b) in bound.iter().enumerate() {
        for c in 0..3 {
            let v = got.values()[row][c];
            assert!(v.is_finite(), "{what}: row {row} not written");
            let err = (v as f64 - cpu.values()[row][c] as f64).abs();
            assert!(err <= b[c], "{what} row {row} c{c}: GPU {v} vs CPU {} (bound {:e})", cpu.values()[row][c], b[c]);
        }
    }
}

#[test]
fn haar_matches_its_cpu_gather_with_f32_and_f16_values() {
    // Against the CPU gather of the same (lossy) form, within `haar_bound`.
    use biscale_compressors::haar::{Haar, HaarWeighting};
    let ctx = gpu_or_skip!();
    let t = random_transfer(6, 8, 8, 0.2, 5);
    for haar in [
        Haar { terms: 12, weighting: HaarWeighting::Area, f16_values: false },
        Haar { terms: 20, weighting: HaarWeighting::Side, f16_values: true },
    ] {
        let form = haar.compress(&t, &CompressContext::default()).unwrap();
        assert_eq!(form.u16s("coeff_f16").is_ok(), haar.f16_values);
        for seed in [6u64, 7] {
            let light = random_light(8, seed);
            let mut g = upload(ctx, &haar, &form);
            g.fill_lstar(f32::NAN).unwrap();
            g.gather(&light).unwrap();
            let got = g.read_lstar().unwrap();
            let cpu = haar.gather(&form, &light).unwrap();
            assert_within_bound(&format!("{haar:?}"), &got, &cpu, &haar_bound(&form, &light, &cpu));
        }
    }
}

/// How far a GPU CPCA gather of `light` can be from the CPU's gather `cpu` of the same form
/// (f64 projections and sums), per row and channel. Each GPU projection `P_v = basis_v . L`
/// is summed by 64 lanes of `ceil(N / 64)` products each, then a 6-level tree: error
/// `<= (ceil(N / 64) + 7) u A_v` with `A_v = sum_k |basis_vk| |L_k|`. A row adds `C` products
/// to `P_0`: `(C + 1) u (|P_0| + sum |w_c P_c|)` plus the propagated projection errors; the
/// CPU's f32 rounding adds `u |cpu|`. An all-zero row (cluster id `K`) must be exactly 0.
/// Both units: rows, and whole vertices (a vertex's M rows as one vector, segment `j` of each
/// basis vector for row `j`).
pub(super) fn cpca_bound(form: &CompressedForm, light: &LightVector, cpu: &LocalRadiance) -> Vec<[f64; 3]> {
    let u = f32::EPSILON as f64 / 2.0;
    let (k, c, n) = (form.meta("clusters").unwrap() as usize, form.meta("components").unwrap() as usize, form.cols());
    let units = form.meta("unit_rows").unwrap() as usize;
    let cluster = form.u16s("cluster").unwrap();
    let (basis, coeffs) = (form.f32s("basis").unwrap(), form.f32s("coeffs").unwrap());
    let lane = n.div_ceil(64) as f64 + 7.0;
    let proj: Vec<([f64; 3], [f64; 3])> = basis
        .chunks(n)
        .map(|b| {
            let (mut p, mut a) = ([0.0f64; 3], [0.0f64; 3]);
            for (x, l) in b.iter().zip(&light.power) {
                for ch in 0..3 {
                    p[ch] += *x as f64 * l[ch] as f64;
                    a[ch] += (*x as f64 * l[ch] as f64).abs();
                }
            }
            (p, a)
        })
        .collect();
    (0..form.rows())
        .map(|r| {
            let (unit, j) = (r / units, r % units);
            let id = cluster[unit] as usize;
            std::array::from_fn(|ch| {
                if id == k {
                    return 0.0;
                }
                let seg = |v: usize| (id * (c + 1) + v) * units + j;
                let w = |v: usize| if v == 0 { 1.0 } else { coeffs[unit * c + v - 1] as f64 };
                let terms: f64 = (0..=c).map(|v| (w(v) * proj[seg(v)].0[ch]).abs()).sum();
                let prop: f64 = (0..=c).map(|v| w(v).abs() * lane * u * proj[seg(v)].1[ch]).sum();
                (c as f64 + 1.0) * u * terms + prop + u * (cpu.values()[r][ch] as f64).abs()
            })
        })
        .collect()
}

#[test]
fn cpca_matches_its_cpu_gather() {
    // Against the CPU gather of the same (lossy) form, within `cpca_bound`.
    use biscale_compressors::cpca::{Cpca, CpcaUnit};
    let ctx = gpu_or_skip!();
    let t = random_transfer(20, 8, 4, 0.05, 12);
    for cpca in [Cpca::new(6, 3), Cpca { unit: CpcaUnit::Vertex, ..Cpca::new(4, 3) }] {
        let form = cpca.compress(&t, &CompressContext { seed: 3, progress: None, sweep: None }).unwrap();
        if form.meta("unit_rows").unwrap() == 1 {
            let k = form.meta("clusters").unwrap() as usize;
            assert!(form.u16s("cluster").unwrap().iter().any(|&id| id as usize == k), "want at least one all-zero row");
        }
        for seed in [30u64, 31] {
            let light = random_light(4, seed);
            let mut g = upload(ctx, &cpca, &form);
            g.fill_lstar(f32::NAN).unwrap();
            g.gather(&light).unwrap();
            let got = g.read_lstar().unwrap();
            let cpu = cpca.gather(&form, &light).unwrap();
            assert_within_bound(&format!("{cpca:?}"), &got, &cpu, &cpca_bound(&form, &light, &cpu));
        }
    }
}
