//! Sizes computed from a form ([`Count`]) and the declarative structural checks a host runs
//! on every form before any gather reads it ([`FormCheck`]).
//!
//! A compressor (built-in or plugin) declares what must hold (`row_ptr` is a pointer array
//! over `col_idx`, `col_idx` is below the column count, ...) and the host verifies it, so a
//! bad offset array is a clear [`FormError`] naming the array and the element, never an
//! out-of-bounds read or a GPU loop of billions of steps. The checks run on every form before
//! every GPU upload, so they are written to cost less than a gather: typed slices, no
//! widening copies.

use crate::{array, meta, ArrayData, FormData, FormError};

/// One factor of a [`Count`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Factor {
    Const(u64),
    /// Rows of `T` (vertices x M).
    Rows,
    /// Columns of `T` (N).
    Cols,
    /// Vertices (rows / M).
    Vertices,
    /// Local directions per vertex, M.
    LocalDirs,
    /// A `meta` value of the form.
    Meta(String),
    /// A `meta` value plus a constant.
    MetaPlus(String, u64),
    /// The element count of a form array.
    Len(String),
}

/// A size computed from a form: the product of its factors (empty = 1).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Count(pub Vec<Factor>);

impl Count {
    pub fn of(factors: impl IntoIterator<Item = Factor>) -> Self {
        Count(factors.into_iter().collect())
    }

    /// Evaluate on `form` (checked arithmetic; a missing meta key or array is an error).
    pub fn eval(&self, form: &dyn FormData) -> Result<u64, FormError> {
        let mut n: u64 = 1;
        for f in &self.0 {
            let v = match f {
                Factor::Const(c) => *c,
                Factor::Rows => form.rows() as u64,
                Factor::Cols => form.cols() as u64,
                Factor::Vertices => form.vertices() as u64,
                Factor::LocalDirs => form.local_dirs() as u64,
                Factor::Meta(k) => meta(form, k)?,
                Factor::MetaPlus(k, a) => meta(form, k)?
                    .checked_add(*a)
                    .ok_or_else(|| FormError::new(form, k, format!("+ {a} overflows u64")))?,
                Factor::Len(a) => array(form, a)?.len() as u64,
            };
            n = n.checked_mul(v).ok_or_else(|| FormError::new(form, "size", format!("{self:?} overflows u64")))?;
        }
        Ok(n)
    }
}

/// A structural fact about a form that the host verifies before any gather reads the form.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FormCheck {
    /// `array` has exactly `count` elements.
    Len { array: String, count: Count },
    /// `array` (integers) has `count + 1` non-decreasing entries running from 0 to `total`: a
    /// CSR-style pointer array of `count` ranges into something of `total` elements (usually
    /// `Len(target)`).
    Ptr { array: String, count: Count, total: Count },
    /// Every element of the integer `array` is at least 0 and below `bound`.
    Below { array: String, bound: Count },
    /// Every element of the float `array` is finite.
    Finite { array: String },
    /// Every element of the u16 `array`, read as IEEE half-float bits, is finite.
    FiniteHalf { array: String },
    /// The value of `count` lies in `min..=max`.
    Range { count: Count, min: u64, max: u64 },
    /// Ids local to groups of rows: rows are grouped `group_rows` at a time (row `r` is in
    /// group `g = r / group_rows`), `bases` is a pointer array over groups, and every id of
    /// row `r` (the integer `ids` in the range `ptr[r]..ptr[r + 1]`) satisfies
    /// `bases[g] + id < bases[g + 1]`: it names an element of its own group (biclustering's
    /// per-block bicluster ids).
    Grouped { ids: String, ptr: String, group_rows: Count, bases: String },
}

/// An integer array as typed slices, for the checks (f32 is not an integer array).
enum Ints<'a> {
    U8(&'a [u8]),
    I8(&'a [i8]),
    U16(&'a [u16]),
    I16(&'a [i16]),
    U32(&'a [u32]),
}

impl<'a> Ints<'a> {
    fn of(form: &'a dyn FormData, name: &str) -> Result<Self, FormError> {
        Ok(match array(form, name)? {
            ArrayData::U8(v) => Ints::U8(v),
            ArrayData::I8(v) => Ints::I8(v),
            ArrayData::U16(v) => Ints::U16(v),
            ArrayData::I16(v) => Ints::I16(v),
            ArrayData::U32(v) => Ints::U32(v),
            ArrayData::F32(_) => return Err(FormError::new(form, name, "is f32, an integer array was expected")),
        })
    }

    fn len(&self) -> usize {
        match self {
            Ints::U8(v) => v.len(),
            Ints::I8(v) => v.len(),
            Ints::U16(v) => v.len(),
            Ints::I16(v) => v.len(),
            Ints::U32(v) => v.len(),
        }
    }

    fn get(&self, i: usize) -> i64 {
        match self {
            Ints::U8(v) => v[i] as i64,
            Ints::I8(v) => v[i] as i64,
            Ints::U16(v) => v[i] as i64,
            Ints::I16(v) => v[i] as i64,
            Ints::U32(v) => v[i] as i64,
        }
    }

    /// The first element (and its index) outside `0..bound`.
    fn first_outside(&self, bound: i64) -> Option<(usize, i64)> {
        fn find<T: Copy + Into<i64>>(v: &[T], bound: i64) -> Option<(usize, i64)> {
            v.iter().position(|&x| x.into() < 0 || x.into() >= bound).map(|i| (i, v[i].into()))
        }
        match self {
            Ints::U8(v) => find(v, bound),
            Ints::I8(v) => find(v, bound),
            Ints::U16(v) => find(v, bound),
            Ints::I16(v) => find(v, bound),
            Ints::U32(v) => find(v, bound),
        }
    }

    /// `n + 1` non-decreasing entries from 0 to `total`, else what is wrong.
    fn check_ptr(&self, n: u64, total: i64) -> Result<(), String> {
        let len = self.len();
        if len as u64 != n.saturating_add(1) {
            return Err(format!("has {len} entries, expected {n} + 1"));
        }
        if self.get(0) != 0 || self.get(len - 1) != total {
            return Err(format!("must run from 0 to {total}"));
        }
        fn decrease<T: Copy + Into<i64>>(v: &[T]) -> Option<usize> {
            v.windows(2).position(|w| w[1].into() < w[0].into())
        }
        let at = match self {
            Ints::U8(v) => decrease(v),
            Ints::I8(v) => decrease(v),
            Ints::U16(v) => decrease(v),
            Ints::I16(v) => decrease(v),
            Ints::U32(v) => decrease(v),
        };
        match at {
            Some(i) => Err(format!("decreases at entry {i}")),
            None => Ok(()),
        }
    }
}

impl FormCheck {
    /// Verify the check on `form`; the error says which array and which element failed.
    pub fn run(&self, form: &dyn FormData) -> Result<(), FormError> {
        let bad = |array: &str, what: String| Err(FormError::new(form, array, what));
        match self {
            FormCheck::Len { array: name, count } => {
                let (n, want) = (array(form, name)?.len() as u64, count.eval(form)?);
                if n != want {
                    return bad(name, format!("has {n} elements, expected {want} ({count:?})"));
                }
            }
            FormCheck::Ptr { array: name, count, total } => {
                let (n, total) = (count.eval(form)?, i64::try_from(total.eval(form)?).unwrap_or(i64::MAX));
                if let Err(m) = Ints::of(form, name)?.check_ptr(n, total) {
                    return bad(name, format!("(a pointer array) {m}"));
                }
            }
            FormCheck::Below { array: name, bound } => {
                let b = i64::try_from(bound.eval(form)?).unwrap_or(i64::MAX);
                if let Some((i, v)) = Ints::of(form, name)?.first_outside(b) {
                    return bad(name, format!("element {i} is {v}, not in 0..{b}"));
                }
            }
            FormCheck::Finite { array: name } => match array(form, name)? {
                ArrayData::F32(v) => {
                    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                        return bad(name, format!("element {i} is not finite"));
                    }
                }
                other => return bad(name, format!("is {}, an f32 array was expected", other.element_type())),
            },
            FormCheck::FiniteHalf { array: name } => match array(form, name)? {
                ArrayData::U16(v) => {
                    // Exponent bits all ones: an f16 infinity or NaN.
                    if let Some(i) = v.iter().position(|&b| b & 0x7c00 == 0x7c00) {
                        return bad(name, format!("element {i} is not a finite half float"));
                    }
                }
                other => return bad(name, format!("is {}, u16 half-float bits were expected", other.element_type())),
            },
            FormCheck::Range { count, min, max } => {
                let v = count.eval(form)?;
                if v < *min || v > *max {
                    return bad(&format!("{count:?}"), format!("is {v}, not in {min}..={max}"));
                }
            }
            FormCheck::Grouped { ids, ptr, group_rows, bases } => {
                let (id, p, base) = (Ints::of(form, ids)?, Ints::of(form, ptr)?, Ints::of(form, bases)?);
                let g = group_rows.eval(form)?;
                let rows = form.rows();
                if g == 0 && rows > 0 {
                    return bad(ptr, "groups of 0 rows".into());
                }
                if p.len() != rows + 1 {
                    return bad(ptr, format!("has {} entries for {rows} rows", p.len()));
                }
                for r in 0..rows {
                    let group = (r as u64 / g) as usize;
                    if group + 1 >= base.len() {
                        return bad(bases, format!("has no group {group} (for row {r})"));
                    }
                    let (lo, hi) = (base.get(group), base.get(group + 1));
                    let (start, end) = (p.get(r), p.get(r + 1));
                    if start < 0 || start > end || end > id.len() as i64 {
                        return bad(ptr, format!("row {r}'s range {start}..{end} is not within {ids}"));
                    }
                    for e in start as usize..end as usize {
                        let x = id.get(e);
                        if x < 0 || lo + x >= hi {
                            return bad(
                                ids,
                                format!("row {r} names element {x} of group {group}, which has {}", hi - lo),
                            );
                        }
                    }
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{KernelDesc, PassDesc, ScratchDesc};
    use std::collections::BTreeMap;

    /// A form of 3 rows of one direction over 6 columns.
    #[derive(Clone)]
    struct Probe {
        arrays: Vec<(String, ArrayData)>,
        meta: BTreeMap<String, u64>,
    }

    impl FormData for Probe {
        fn kind(&self) -> &str {
            "probe"
        }
        fn find_array(&self, name: &str) -> Option<&ArrayData> {
            self.arrays.iter().find(|(n, _)| n == name).map(|(_, a)| a)
        }
        fn find_meta(&self, key: &str) -> Option<u64> {
            self.meta.get(key).copied()
        }
        fn rows(&self) -> usize {
            3
        }
        fn cols(&self) -> usize {
            6
        }
        fn vertices(&self) -> usize {
            3
        }
        fn local_dirs(&self) -> usize {
            1
        }
    }

    fn form() -> Probe {
        Probe {
            arrays: vec![
                ("ptr".into(), ArrayData::U32(vec![0, 2, 2, 4])),
                ("idx".into(), ArrayData::U16(vec![0, 5, 1, 2])),
                ("val".into(), ArrayData::F32(vec![1.0, 2.0, 3.0, 4.0])),
                ("half".into(), ArrayData::U16(vec![0x3c00, 0x0001])),
                // Rows 0-1 in group 0 (2 elements), row 2 in group 1 (3 elements).
                ("bases".into(), ArrayData::U32(vec![0, 2, 5])),
                ("local".into(), ArrayData::U16(vec![1, 0, 0, 2])),
            ],
            meta: [("k".to_string(), 2), ("two".to_string(), 2)].into(),
        }
    }

    fn desc(checks: Vec<FormCheck>) -> KernelDesc {
        KernelDesc {
            kind: "probe".into(),
            wgsl: String::new(),
            passes: vec![PassDesc { entry_point: "main".into(), threads: Count::of([Factor::Rows]) }],
            scratch: vec![ScratchDesc {
                name: "s".into(),
                words: Count::of([Factor::MetaPlus("k".into(), 1), Factor::Len("idx".into())]),
            }],
            meta_keys: vec!["k".into()],
            checks,
        }
    }

    fn all_checks() -> Vec<FormCheck> {
        let len = |a: &str| Count::of([Factor::Len(a.into())]);
        vec![
            FormCheck::Len { array: "val".into(), count: len("idx") },
            FormCheck::Ptr { array: "ptr".into(), count: Count::of([Factor::Rows]), total: len("idx") },
            FormCheck::Below { array: "idx".into(), bound: Count::of([Factor::Cols]) },
            FormCheck::Finite { array: "val".into() },
            FormCheck::FiniteHalf { array: "half".into() },
            FormCheck::Range { count: Count::of([Factor::Meta("k".into())]), min: 1, max: 127 },
            FormCheck::Grouped {
                ids: "local".into(),
                ptr: "ptr".into(),
                group_rows: Count::of([Factor::Meta("two".into())]),
                bases: "bases".into(),
            },
        ]
    }

    #[test]
    fn counts_evaluate_on_the_form() {
        let f = form();
        assert_eq!(desc(vec![]).scratch[0].words.eval(&f).unwrap(), 3 * 4);
        assert_eq!(Count::of([]).eval(&f).unwrap(), 1);
        assert!(Count::of([Factor::Meta("nope".into())]).eval(&f).is_err());
        assert!(Count::of([Factor::Const(u64::MAX), Factor::Const(2)]).eval(&f).is_err());
    }

    #[test]
    fn good_form_passes_every_check() {
        desc(all_checks()).check_form(&form()).unwrap();
    }

    #[test]
    fn each_broken_invariant_is_caught() {
        let d = desc(all_checks());
        let with = |name: &str, data: ArrayData| {
            let mut f = form();
            f.arrays.iter_mut().find(|(n, _)| n == name).unwrap().1 = data;
            f
        };
        let mut k0 = form();
        k0.meta.insert("k".into(), 0);
        let cases = [
            (with("val", ArrayData::F32(vec![1.0; 3])), "'val' has 3 elements, expected 4"),
            (with("ptr", ArrayData::U32(vec![0, 2, 4])), "expected 3 + 1"),
            (with("ptr", ArrayData::U32(vec![1, 2, 2, 4])), "from 0"),
            (with("ptr", ArrayData::U32(vec![0, 3, 2, 4])), "decreases at entry 1"),
            (with("idx", ArrayData::U16(vec![0, 6, 1, 2])), "'idx' element 1 is 6"),
            (with("idx", ArrayData::F32(vec![0.0; 4])), "integer array"),
            (with("val", ArrayData::F32(vec![1.0, f32::NAN, 3.0, 4.0])), "'val' element 1"),
            (with("half", ArrayData::U16(vec![0x3c00, 0x7c00])), "'half' element 1"),
            (with("half", ArrayData::U32(vec![0])), "half-float bits"),
            (k0, "is 0, not in 1..=127"),
            // Row 0 (group 0, 2 elements) names element 2.
            (with("local", ArrayData::U16(vec![2, 0, 0, 2])), "row 0 names element 2 of group 0"),
            // Row 2 (group 1, 3 elements) names element 3.
            (with("local", ArrayData::U16(vec![1, 0, 0, 3])), "row 2 names element 3 of group 1"),
            (with("bases", ArrayData::U32(vec![0, 2])), "has no group 1"),
        ];
        for (f, needle) in cases {
            let e = d.check_form(&f).unwrap_err().to_string();
            assert!(e.contains(needle), "{e} lacks {needle}");
        }
        let mut f = form();
        f.meta.clear();
        assert!(d.check_form(&f).unwrap_err().to_string().contains("'k'"));
        let mut other = desc(all_checks());
        other.kind = "other".into();
        assert!(other.check_form(&form()).is_err());
    }
}
