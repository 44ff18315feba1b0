//! `T` left in a sharded precompute's files, and the one view every pass over `T` takes.
//!
//! A merge that stacked every shard's rows would hold all of `T` (12 bytes per non-zero), which
//! stops scale-out at one machine's memory. Everything the runtime needs from `T` after the
//! compressors have run is row-separable: the f64 baseline `T L` (with or without light
//! moments), the error terms of a form (sums of squares over rows), the value histogram. So a
//! pass can visit `T` as consecutive vertex ranges, loading each part when it is reached and
//! dropping it after (the next is read ahead, so two are in memory at once); it gets, row for
//! row and sum for sum in the same order, what the pass over the whole matrix gets.
//!
//! * [`TransferParts`]: the part files with their writers' records, each part checked against
//!   its record whenever a pass reads it.
//! * [`TransferView`]: `T` whole or as parts; [`TransferView::for_each_part`] is the pass,
//!   [`TransferView::map_rows`] a row-separable product over it.

use super::TransferMatrix;
use crate::basis::{LightBasis, LocalBasis, TransferShape};
use crate::error::{CoreError, Result};
use std::path::{Path, PathBuf};

/// A sharded precompute's `T`: one file per consecutive vertex range
/// ([`TransferMatrix::save`] of a [`super::build_range`]), each with its writer's record.
#[derive(Clone, Debug)]
pub struct TransferParts {
    shape: TransferShape,
    nnz: usize,
    /// Each part's file and record, and its first vertex.
    parts: Vec<(PartFile, usize)>,
}

/// One part of `T` in a file, as the shard that wrote it recorded it.
#[derive(Clone, Debug, PartialEq)]
pub struct PartFile {
    pub path: PathBuf,
    pub vertices: usize,
    pub nnz: usize,
    /// Its stored values that are not 0, when the writer counted them (a pass that needs the
    /// count then reads no part for it).
    pub nonzero: Option<usize>,
}

impl TransferParts {
    /// `T` of `shape` held by `parts`, in row order. Nothing is read here (opening costs no
    /// pass over `T`); the records must cover `shape`'s vertices, and every pass checks each
    /// part against its record (bases, vertices, non-zeros) when it reads it.
    pub fn new(shape: TransferShape, parts: Vec<PartFile>) -> Result<Self> {
        if parts.is_empty() {
            return Err(CoreError::Invalid("no transfer parts".into()));
        }
        let (mut first, mut nnz, mut out) = (0usize, 0usize, vec![]);
        for p in parts {
            nnz += p.nnz;
            let vertices = p.vertices;
            out.push((p, first));
            first += vertices;
        }
        if first != shape.vertices {
            return Err(CoreError::Invalid(format!(
                "the transfer parts hold {first} vertices, T has {}",
                shape.vertices
            )));
        }
        Ok(Self { shape, nnz, parts: out })
    }

    pub fn shape(&self) -> TransferShape {
        self.shape
    }
    pub fn nnz(&self) -> usize {
        self.nnz
    }
    /// The vertices of the largest part: what a pass holds of `T` at once.
    pub fn largest_part(&self) -> usize {
        self.parts.iter().map(|(p, _)| p.vertices).max().unwrap_or(0)
    }
    /// How many files hold `T`.
    pub fn len(&self) -> usize {
        self.parts.len()
    }
    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }
}

impl TransferParts {
    /// One part, checked against its record.
    fn read(&self, record: &PartFile) -> Result<TransferMatrix> {
        let part = load(&record.path)?;
        let expected = TransferShape::new(record.vertices, self.shape.local, self.shape.light);
        let counted = record.nonzero.map(|_| part.nonzero_values());
        if part.shape() != expected || part.nnz() != record.nnz || counted != record.nonzero {
            return Err(CoreError::Invalid(format!(
                "{}: holds {} with {} non-zeros ({:?} not 0), its record says {expected} with {} ({:?})",
                record.path.display(),
                part.shape(),
                part.nnz(),
                counted,
                record.nnz,
                record.nonzero
            )));
        }
        Ok(part)
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
    /// The stored values that are not 0: counted (a pass over `T`'s parts), or summed from
    /// the parts' records when every one of them has the count.
    pub fn nonzero(&self) -> Result<usize> {
        if let TransferView::Parts(p) = self {
            if let Some(n) = p.parts.iter().map(|(r, _)| r.nonzero).sum::<Option<usize>>() {
                return Ok(n);
            }
        }
        let mut n = 0;
        self.for_each_part(|_, part| -> Result<()> {
            n += part.nonzero_values();
            Ok(())
        })?;
        Ok(n)
    }

    /// The matrix, when it is whole in memory.
    pub fn whole(&self) -> Option<&TransferMatrix> {
        match self {
            TransferView::Whole(t) => Some(t),
            TransferView::Parts(_) => None,
        }
    }

    /// `f(first_vertex, part)` for each part of `T` in row order: the whole matrix once, or
    /// each part file loaded in turn and dropped after `f` returns. The next part is read on
    /// a thread of its own while `f` works on this one (reading is one core's decoding; `f`
    /// may use the others), so at most two parts are in memory at once.
    pub fn for_each_part<E: From<CoreError>>(
        &self,
        mut f: impl FnMut(usize, &TransferMatrix) -> std::result::Result<(), E>,
    ) -> std::result::Result<(), E> {
        match self {
            TransferView::Whole(t) => f(0, t),
            TransferView::Parts(p) => std::thread::scope(|scope| {
                let read = |i: usize| p.parts.get(i).map(|(record, _)| scope.spawn(move || p.read(record)));
                let mut next = read(0);
                for (i, (_, first)) in p.parts.iter().enumerate() {
                    let reading = next.take().expect("a read was started for every part");
                    let part = reading.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic))?;
                    next = read(i + 1);
                    f(*first, &part)?;
                }
                Ok(())
            }),
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

    /// The parts' records, as shards write them.
    fn records(t: &TransferMatrix, files: &[PathBuf], ranges: &[std::ops::Range<usize>]) -> Vec<PartFile> {
        files
            .iter()
            .zip(ranges)
            .map(|(f, r)| {
                let part = t.vertex_rows(r.clone()).unwrap();
                PartFile { path: f.clone(), vertices: r.len(), nnz: part.nnz(), nonzero: Some(part.nonzero_values()) }
            })
            .collect()
    }

    #[test]
    fn a_pass_over_parts_is_the_pass_over_the_whole_matrix() {
        let dir = tempfile::tempdir().unwrap();
        let t = random(10, 1);
        let ranges = [0..3, 3..7, 7..10];
        let files = save_parts(&t, &ranges, dir.path());
        let parts = TransferParts::new(t.shape(), records(&t, &files, &ranges)).unwrap();
        assert_eq!((parts.shape(), parts.nnz(), parts.len(), parts.largest_part()), (t.shape(), t.nnz(), 3, 4));
        // The count of values that are not 0: from the records when all have it, else counted.
        let mut unrecorded = records(&t, &files, &ranges);
        unrecorded[1].nonzero = None;
        let counted = TransferParts::new(t.shape(), unrecorded).unwrap();
        assert_eq!(TransferView::from(&parts).nonzero().unwrap(), t.nonzero_values());
        assert_eq!(TransferView::from(&counted).nonzero().unwrap(), t.nonzero_values());
        assert_eq!(TransferView::from(&t).nonzero().unwrap(), t.nonzero_values());

        // The product of T in parts is the product of T, bit for bit (each row on its own).
        let power = (0..24).map(|k| [k as f32 * 0.5 + 1.0, 2.0 / (k as f32 + 1.0), 0.25]).collect();
        let light = LightVector::new(t.light_basis(), power).unwrap();
        let whole = reference_product(&t, &light);
        let view = TransferView::from(&parts);
        let streamed = view.map_rows(|_, p| -> Result<_> { Ok(reference_product(p, &light)) }).unwrap();
        assert_eq!(streamed, whole);
        let mut visited = vec![];
        view.for_each_part(|first, p| -> Result<()> {
            visited.push((first, p.vertices()));
            Ok(())
        })
        .unwrap();
        assert_eq!(visited, [(0, 3), (3, 4), (7, 3)]);
        let one = TransferView::from(&t);
        assert_eq!(one.map_rows(|_, p| -> Result<_> { Ok(reference_product(p, &light)) }).unwrap(), whole);
        assert!(one.whole().is_some() && view.whole().is_none());
    }

    #[test]
    fn parts_that_do_not_make_the_matrix_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let t = random(6, 2);
        let ranges = [0..2, 2..6];
        let files = save_parts(&t, &ranges, dir.path());
        let recs = records(&t, &files, &ranges);
        let seven = TransferShape::new(7, t.local_basis(), t.light_basis());
        let e = TransferParts::new(seven, recs.clone()).unwrap_err().to_string();
        assert!(e.contains("hold 6 vertices, T has 7"), "{e}");
        assert!(TransferParts::new(t.shape(), vec![]).unwrap_err().to_string().contains("no transfer parts"));

        // A part that is not what its record says (other bases; a non-zero fewer) is named
        // when a pass reads it.
        let pass = |parts: &TransferParts| {
            TransferView::from(parts).for_each_part(|_, _| -> Result<()> { Ok(()) }).unwrap_err().to_string()
        };
        let mut short = recs.clone();
        short[1].nnz += 1;
        let e = pass(&TransferParts::new(t.shape(), short).unwrap());
        assert!(e.contains("part1.bsf") && e.contains("its record says"), "{e}");
        let mut miscounted = recs.clone();
        miscounted[0].nonzero = miscounted[0].nonzero.map(|n| n - 1);
        let e = pass(&TransferParts::new(t.shape(), miscounted).unwrap());
        assert!(e.contains("part0.bsf") && e.contains("its record says"), "{e}");
        let local = LocalBasis::bins(3).unwrap();
        let other = TransferMatrix::new(local, t.light_basis(), sprs::CsMat::zero((4 * local.len(), 24))).unwrap();
        other.save(&files[1]).unwrap();
        let e = pass(&TransferParts::new(t.shape(), recs).unwrap());
        assert!(e.contains("part1.bsf") && e.contains("its record says"), "{e}");
    }
}
