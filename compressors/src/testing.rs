//! Test inputs shared by the compressors' tests (and the integration tests): random transfer
//! matrices with the real value set, random and stiff light vectors, and the lossless check.

use biscale_core::basis::{LightBasis, LocalBasis};
use biscale_core::compress::{CompressedForm, Compressor};
use biscale_core::gather::{reference_product, LocalRadiance};
use biscale_core::sampling::LightVector;
use biscale_core::transfer::TransferMatrix;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The `R x R` cubemap light basis (tests only: panics on a bad resolution).
pub fn cubemap(resolution: u32) -> LightBasis {
    LightBasis::cubemap(resolution).expect("a valid cubemap resolution")
}

/// The `m x m` bin local basis (tests only: panics on a bad grid).
pub fn bins(m: u32) -> LocalBasis {
    LocalBasis::bins(m).expect("a valid local grid")
}

/// A random `T` of `vertices` vertices of `local_grid x local_grid` bins and `6 R^2` columns
/// whose non-zeros (a fraction `density`) take the box-filtered visibility values
/// {1/4, 1/2, 3/4, 1}.
pub fn random_transfer(vertices: usize, local_grid: u32, resolution: u32, density: f64, seed: u64) -> TransferMatrix {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let local = LocalBasis::bins(local_grid).expect("a valid local grid");
    let light = LightBasis::cubemap(resolution).expect("a valid cubemap resolution");
    let (rows, cols) = (vertices * local.len(), light.len());
    let mut indptr = vec![0usize];
    let (mut indices, mut data) = (vec![], vec![]);
    for _ in 0..rows {
        for c in 0..cols {
            if rng.gen::<f64>() < density {
                indices.push(c);
                data.push(rng.gen_range(1..=4) as f32 / 4.0);
            }
        }
        indptr.push(indices.len());
    }
    TransferMatrix::new(local, light, sprs::CsMat::new((rows, cols), indptr, indices, data)).expect("a consistent T")
}

/// A random positive light vector, with one texel a "sun" 10^6 times brighter when `seed`
/// is odd (the stiff case).
pub fn random_light(resolution: u32, seed: u64) -> LightVector {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut light = LightVector::constant(LightBasis::cubemap(resolution).expect("a valid resolution"), [1.0; 3]);
    for p in &mut light.power {
        for c in p.iter_mut() {
            *c *= rng.gen_range(0.0..2.0f32);
        }
    }
    if seed % 2 == 1 {
        let k = rng.gen_range(0..light.len());
        light.power[k] = light.power[k].map(|v| v * 1e6 + 1e-3);
    }
    light
}

/// Bound on the relative L2 error of an f32 gather against the f64 product for rows of at
/// most `terms` non-negative terms: each f32 sum of n non-negative terms has relative error
/// at most about n * 2^-24 (plus one rounding per product); we allow `(n + 2) * 2^-24`.
pub fn f32_sum_bound(terms: usize) -> f64 {
    (terms as f64 + 2.0) * f32::EPSILON as f64 / 2.0
}

/// Assert that `compressor`'s gather on `form` reproduces `T L` to f32 rounding.
pub fn assert_lossless(compressor: &dyn Compressor, form: &CompressedForm, t: &TransferMatrix, light: &LightVector) {
    let got: LocalRadiance = compressor.gather(form, light).expect("gather");
    let reference = reference_product(t, light);
    let max_row = (0..t.rows()).map(|r| t.csr().outer_view(r).unwrap().nnz()).max().unwrap_or(0);
    let bound = f32_sum_bound(max_row);
    for (r, (g, e)) in got.values().iter().zip(&reference).enumerate() {
        for c in 0..3 {
            let err = (g[c] as f64 - e[c]).abs();
            assert!(err <= bound * e[c].abs() + 1e-30, "row {r} channel {c}: {} vs {} (bound {bound})", g[c], e[c]);
        }
    }
}

/// Assert that every row and channel of `got` is within `bound(row, channel)` of the f64
/// `reference` (each compressor's test derives its own per-entry rounding bound).
pub fn assert_within(got: &LocalRadiance, reference: &[[f64; 3]], bound: impl Fn(usize, usize) -> f64) {
    assert_eq!(got.values().len(), reference.len(), "rows");
    for (r, (g, e)) in got.values().iter().zip(reference).enumerate() {
        for c in 0..3 {
            let (err, b) = ((g[c] as f64 - e[c]).abs(), bound(r, c));
            assert!(err <= b, "row {r} channel {c}: gather {} vs f64 {} (err {err:e}, bound {b:e})", g[c], e[c]);
        }
    }
}

/// The exact product with `light` of the matrix a form of the example `quantized` plugin
/// stores (`value = codes[e] * scale`), in f64, with each row's number of stored terms: the
/// reference both the plugin's CPU and GPU gathers are checked against.
pub fn quantized_stored_product(form: &CompressedForm, light: &LightVector) -> Vec<([f64; 3], usize)> {
    let (rp, ci, codes) = (form.u32s("row_ptr").unwrap(), form.u16s("col_idx").unwrap(), form.u8s("codes").unwrap());
    let s = form.f32s("scale").unwrap()[0] as f64;
    (0..form.rows())
        .map(|r| {
            let span = rp[r] as usize..rp[r + 1] as usize;
            let row = std::array::from_fn(|c| {
                span.clone().map(|e| codes[e] as f64 * s * light.power[ci[e] as usize][c] as f64).sum()
            });
            (row, span.len())
        })
        .collect()
}

/// Assert that `compressor` builds, from the parts of `t` cut at the vertex boundaries
/// `cuts` (increasing, inside `0..vertices`), forms that merge into exactly the form of the
/// whole: the same arrays, meta, flops and lossless flag (build time aside), and that the
/// vertex ranges reproduce `T` when stacked. Returns the merged form.
pub fn assert_parts_merge_to_whole(compressor: &dyn Compressor, t: &TransferMatrix, cuts: &[usize]) -> CompressedForm {
    use biscale_core::compress::CompressContext;
    let ctx = CompressContext { seed: 7, progress: None, sweep: None };
    let whole = compressor.compress(t, &ctx).expect("compress the whole");
    let bounds: Vec<usize> = std::iter::once(0).chain(cuts.iter().copied()).chain([t.vertices()]).collect();
    let ranges: Vec<_> = bounds.windows(2).map(|w| w[0]..w[1]).collect();
    let rows: Vec<TransferMatrix> = ranges.iter().map(|r| t.vertex_rows(r.clone()).expect("a range")).collect();
    assert_eq!(&TransferMatrix::stack(rows.clone()).expect("stack"), t, "stacked ranges are T");
    let parts = ranges
        .iter()
        .zip(&rows)
        .map(|(r, part)| compressor.compress_part(part, r.start, &ctx).expect("compress a part"))
        .collect();
    let mut merged = compressor.merge_parts(t.shape(), parts).expect("merge");
    merged.build_seconds = whole.build_seconds;
    assert_eq!(merged, whole, "{} cut at {cuts:?}", compressor.kind());
    merged
}
