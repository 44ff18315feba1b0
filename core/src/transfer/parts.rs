//! `T` left in a sharded precompute's files, and the one view every pass over `T` takes.
//!
//! A merge that stacked every shard's rows would hold all of `T` (12 bytes per non-zero), which
//! stops scale-out at one machine's memory. Everything the runtime needs from `T` after the
//! compressors have run is row-separable: the f64 baseline `T L` (with or without light
//! moments), the error terms of a form (sums of squares over rows), the value histogram. So a
//! pass can visit `T` as consecutive vertex ranges, loading each part when it is reached and
//! dropping it after; it holds one part at a time and gets, row for row and sum for sum in
//! the same order, what the pass over the whole matrix gets.
//!
//! * [`TransferParts`]: the part files, checked once when opened (bases, consecutive ranges).
//! * [`TransferView`]: `T` whole or as parts; [`TransferView::for_each_part`] is the pass,
//!   [`TransferView::map_rows`] a row-separable product over it.

use super::TransferMatrix;
use crate::basis::{LightBasis, LocalBasis, TransferShape};
use crate::error::{CoreError, Result};
use std::path::{Path, PathBuf};

/// A sharded precompute's `T`: one file per consecutive vertex range
/// ([`TransferMatrix::save`] of a [`super::build_range`]).
#[derive(Clone, Debug)]
pub struct TransferParts {
    shape: TransferShape,
    nnz: usize,
    /// Each part's file, first vertex and vertices.
    parts: Vec<(PathBuf, usize, usize)>,
}

impl TransferParts {
    /// The parts in `files`, in order, each loaded once to check that all share one pair of
    /// bases and together hold the rows of `vertices` vertices; `visit` sees every part
    /// with its first vertex during that pass (so a caller can take its statistics without
    /// a second one).
    pub fn open(
        files: Vec<PathBuf>,
        vertices: usize,
        mut visit: impl FnMut(usize, &TransferMatrix) -> Result<()>,
    ) -> Result<Self> {
        let mut bases: Option<(LocalBasis, LightBasis)> = None;
        let (mut first, mut nnz, mut parts) = (0usize, 0usize, vec![]);
        for path in files {
            let part = load(&path)?;
            let (local, light) = *bases.get_or_insert((part.local_basis(), part.light_basis()));
            if (part.local_basis(), part.light_basis()) != (local, light) {
                return Err(CoreError::Invalid(format!(
                    "{}: is {} x {}, the first part {local} x {light}",
                    path.display(),
                    part.local_basis(),
                    part.light_basis()
                )));
            }
            visit(first, &part)?;
            nnz += part.nnz();
            parts.push((path, first, part.vertices()));
            first += part.vertices();
        }
        let (local, light) = bases.ok_or_else(|| CoreError::Invalid("no transfer parts to open".into()))?;
        if first != vertices {
            return Err(CoreError::Invalid(format!(
                "the transfer parts hold {first} vertices, the mesh has {vertices}"
            )));
        }
        Ok(Self { shape: TransferShape::new(vertices, local, light), nnz, parts })
    }

    pub fn shape(&self) -> TransferShape {
        self.shape
    }
    pub fn nnz(&self) -> usize {
        self.nnz
    }
    /// The vertices of the largest part: what a pass holds of `T` at once.
    pub fn largest_part(&self) -> usize {
        self.parts.iter().map(|p| p.2).max().unwrap_or(0)
    }
    /// How many files hold `T`.
    pub fn len(&self) -> usize {
        self.parts.len()
    }
    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }
}

fn load(path: &Path) -> Result<TransferMatrix> {
    TransferMatrix::load(path).map_err(CoreError::from)
}

/// `T` whole in memory, or as a sharded precompute's parts read one at a time: what a pass
/// over `T` (a product, a form's error, a statistic) takes, so it never needs all of `T` at once.
#[derive(Clone, Copy, Debug)]
pub enum TransferView<'a> {
    Whole(&'a TransferMatrix),
    Parts(&'a TransferParts),
}

impl<'a> From<&'a TransferMatrix> for TransferView<'a> {
    fn from(t: &'a TransferMatrix) -> Self {
        TransferView::Whole(t)
    }
}

impl<'a> From<&'a TransferParts> for TransferView<'a> {
    fn from(t: &'a TransferParts) -> Self {
        TransferView::Parts(t)
    }
}

impl TransferView<'_> {
    pub fn shape(&self) -> TransferShape {
        match self {
            TransferView::Whole(t) => t.shape(),
            TransferView::Parts(p) => p.shape,
        }
    }
    pub fn local_basis(&self) -> LocalBasis {
        self.shape().local
    }
    pub fn light_basis(&self) -> LightBasis {
        self.shape().light
    }
    pub fn vertices(&self) -> usize {
        self.shape().vertices
    }
    /// `M`, the rows per vertex.
    pub fn local_dirs(&self) -> usize {
        self.shape().local_dirs()
    }
    pub fn rows(&self) -> usize {
        self.shape().rows()
    }
    pub fn cols(&self) -> usize {
        self.shape().cols()
    }
    pub fn nnz(&self) -> usize {
        match self {
            TransferView::Whole(t) => t.nnz(),
            TransferView::Parts(p) => p.nnz,
        }
    }
    /// The matrix, when it is whole in memory.
    pub fn whole(&self) -> Option<&TransferMatrix> {
        match self {
            TransferView::Whole(t) => Some(t),
            TransferView::Parts(_) => None,
        }
    }

    /// `f(first_vertex, part)` for each part of `T` in row order: the whole matrix once, or
    /// each part file loaded in turn and dropped after `f` returns.
    pub fn for_each_part<E: From<CoreError>>(
        &self,
        mut f: impl FnMut(usize, &TransferMatrix) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        match self {
            TransferView::Whole(t) => f(0, t),
            TransferView::Parts(p) => {
                for (path, first, vertices) in &p.parts {
                    let part = load(path)?;
                    if part.shape() != TransferShape::new(*vertices, p.shape.local, p.shape.light) {
                        let what = format!("{}: changed since it was opened", path.display());
                        return Err(CoreError::Invalid(what).into());
                    }
                    f(*first, &part)?;
                }
                Ok(())
            }
        }
    }

    /// A row-separable product over `T`: `f(first_vertex, part)` returns the part's items in
    /// row (or vertex) order, and the result is their concatenation, so it equals `f(0, T)`
    /// wherever `f` computes each row on its own.
    pub fn map_rows<X, E: From<CoreError>>(
        &self,
        mut f: impl FnMut(usize, &TransferMatrix) -> std::result::Result<Vec<X>, E>,
    ) -> std::result::Result<Vec<X>, E> {
        let mut out = vec![];
        self.for_each_part(|first, part| -> std::result::Result<(), E> {
            out.extend(f(first, part)?);
            Ok(())
        })?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gather::reference_product;
    use crate::sampling::LightVector;
    use rand::{Rng, SeedableRng};

    /// A random `T` of `vertices` vertices (2x2 bins, a 6x2x2 cubemap), a third of it non-zero.
    fn random(vertices: usize, seed: u64) -> TransferMatrix {
        let (local, light) = (LocalBasis::bins(2).unwrap(), LightBasis::cubemap(2).unwrap());
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut tri = sprs::TriMat::new((vertices * local.len(), light.len()));
        for r in 0..vertices * local.len() {
            for c in 0..light.len() {
                if rng.gen::<f64>() < 0.3 {
                    tri.add_triplet(r, c, rng.gen_range(1..=4) as f32 / 4.0);
                }
            }
        }
        TransferMatrix::new(local, light, tri.to_csr()).unwrap()
    }

    /// `t`'s rows of `ranges`, each saved in `dir`.
    fn save_parts(t: &TransferMatrix, ranges: &[std::ops::Range<usize>], dir: &Path) -> Vec<PathBuf> {
        ranges
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let path = dir.join(format!("part{i}.bsf"));
                t.vertex_rows(r.clone()).unwrap().save(&path).unwrap();
                path
            })
            .collect()
    }

    #[test]
    fn a_pass_over_parts_is_the_pass_over_the_whole_matrix() {
        let dir = tempfile::tempdir().unwrap();
        let t = random(10, 1);
        let files = save_parts(&t, &[0..3, 3..7, 7..10], dir.path());
        let mut opened = vec![];
        let parts = TransferParts::open(files, 10, |first, p| {
            opened.push((first, p.vertices()));
            Ok(())
        })
        .unwrap();
        assert_eq!(opened, [(0, 3), (3, 4), (7, 3)]);
        assert_eq!((parts.shape(), parts.nnz(), parts.len(), parts.largest_part()), (t.shape(), t.nnz(), 3, 4));

        // The product of T in parts is the product of T, bit for bit (each row on its own).
        let power = (0..24).map(|k| [k as f32 * 0.5 + 1.0, 2.0 / (k as f32 + 1.0), 0.25]).collect();
        let light = LightVector::new(t.light_basis(), power).unwrap();
        let whole = reference_product(&t, &light);
        let view = TransferView::from(&parts);
        let streamed = view.map_rows(|_, p| -> Result<_> { Ok(reference_product(p, &light)) }).unwrap();
        assert_eq!(streamed, whole);
        let mut firsts = vec![];
        view.for_each_part(|first, _| -> Result<()> {
            firsts.push(first);
            Ok(())
        })
        .unwrap();
        assert_eq!(firsts, [0, 3, 7]);
        let one = TransferView::from(&t);
        assert_eq!(one.map_rows(|_, p| -> Result<_> { Ok(reference_product(p, &light)) }).unwrap(), whole);
        assert!(one.whole().is_some() && view.whole().is_none());
    }

    #[test]
    fn parts_that_do_not_make_the_matrix_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let t = random(6, 2);
        let files = save_parts(&t, &[0..2, 2..6], dir.path());
        let e = TransferParts::open(files.clone(), 7, |_, _| Ok(())).unwrap_err().to_string();
        assert!(e.contains("hold 6 vertices, the mesh has 7"), "{e}");
        assert!(TransferParts::open(vec![], 0, |_, _| Ok(())).unwrap_err().to_string().contains("no transfer parts"));

        // A part in other bases, at open and when it is swapped in after.
        let other = {
            let local = LocalBasis::bins(3).unwrap();
            let csr = sprs::CsMat::zero((4 * local.len(), 24));
            TransferMatrix::new(local, t.light_basis(), csr).unwrap()
        };
        let odd = dir.path().join("odd.bsf");
        other.save(&odd).unwrap();
        let e = TransferParts::open(vec![files[0].clone(), odd.clone()], 6, |_, _| Ok(())).unwrap_err().to_string();
        assert!(e.contains("odd.bsf") && e.contains("the first part"), "{e}");
        let parts = TransferParts::open(files.clone(), 6, |_, _| Ok(())).unwrap();
        std::fs::copy(&odd, &files[1]).unwrap();
        let e = TransferView::from(&parts).for_each_part(|_, _| -> Result<()> { Ok(()) }).unwrap_err().to_string();
        assert!(e.contains("part1.bsf") && e.contains("changed since it was opened"), "{e}");
    }
}
