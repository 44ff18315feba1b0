//! Random test inputs that the tests of several crates share (cargo feature `testing`, and
//! core's own tests), so that each generator exists once.

use crate::scene::HdrImage;
use rand::{Rng, SeedableRng};

/// A `w x h` image of values spanning twelve orders of magnitude (`[0, 1) x 10^[-6, 6)`), as
/// HDR renders do, from `seed`.
pub fn random_hdr_image(w: u32, h: u32, seed: u64) -> HdrImage {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let pixels =
        (0..w * h).map(|_| std::array::from_fn(|_| rng.gen::<f32>() * 10f32.powi(rng.gen_range(-6..6)))).collect();
    HdrImage { width: w, height: h, pixels }
}

/// A `T` in the bases `local` and `light` from row lists of `(column, value)` (tests only:
/// panics on rows that do not fit the bases).
pub fn transfer_from_rows(
    local: crate::basis::LocalBasis,
    light: crate::basis::LightBasis,
    rows: &[Vec<(usize, f32)>],
) -> crate::transfer::TransferMatrix {
    let mut indptr = vec![0usize];
    let (mut indices, mut data) = (vec![], vec![]);
    for row in rows {
        for &(k, v) in row {
            indices.push(k);
            data.push(v);
        }
        indptr.push(indices.len());
    }
    let csr = sprs::CsMat::new((rows.len(), light.len()), indptr, indices, data);
    crate::transfer::TransferMatrix::new(local, light, csr).expect("rows that fit the bases")
}
