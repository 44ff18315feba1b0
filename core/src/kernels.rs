//! Plain description of a compressed form's GPU gather kernels, and declarative checks of a
//! form's structure (DESIGN.md section 4: compressed forms are data).
//!
//! Built-in compressors have their gather programs compiled into the wgpu runtime
//! (`biscale-gpu`, `gather/kinds.rs`). A compressor loaded from a shared library hands over the
//! same parts as plain data instead: WGSL text, passes, scratch buffers, the meta keys the
//! kernels read, and a list of [`FormCheck`]s. The description lives here, in `biscale-core`,
//! so that the plugin host (`biscale-compressors`) can produce it and the GPU runtime can turn
//! it into a `GatherProgram` without either crate depending on the other.
//!
//! [`Count`] and [`Factor`] are also the GPU runtime's own (`biscale_gpu::{Count, Factor}`
//! re-export them), so a plugin's sizes reach the runtime unconverted.
//!
//! The checks are run by the *host*, never by the plugin: a plugin declares what must hold
//! (`row_ptr` is a pointer array over `col_idx`, `col_idx` is below the column count, ...) and
//! the host verifies it on every form before a CPU or GPU gather reads it, so a bad offset array
//! is a clear error and never an out-of-bounds read or a GPU loop of billions of steps.

use crate::compress::{ArrayData, CompressError, CompressedForm};

/// Run `$body` with `$v` bound to the integer array `$name` of `$form` as a typed slice (an
/// f32 array is an error). Generic code over the slice avoids widening copies: the checks
/// run on every form before every gather, so they must cost less than the gather.
macro_rules! with_ints {
    ($form:expr, $name:expr, $v:ident => $body:expr) => {
        match $form.array($name)? {
            ArrayData::U8($v) => $body,
            ArrayData::I8($v) => $body,
            ArrayData::U16($v) => $body,
            ArrayData::I16($v) => $body,
            ArrayData::U32($v) => $body,
            ArrayData::F32(_) => {
                return Err(CompressError::malformed(&$form.kind, $name, "is f32, an integer array was expected"))
            }
        }
    };
}

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
    pub fn eval(&self, form: &CompressedForm) -> Result<u64, CompressError> {
        let mut n: u64 = 1;
        for f in &self.0 {
            let v = match f {
                Factor::Const(c) => *c,
                Factor::Rows => form.rows() as u64,
                Factor::Cols => form.cols() as u64,
                Factor::Vertices => form.vertices() as u64,
                Factor::LocalDirs => form.local_dirs() as u64,
                Factor::Meta(k) => form.meta(k)?,
                Factor::MetaPlus(k, a) => form
                    .meta(k)?
                    .checked_add(*a)
                    .ok_or_else(|| CompressError::malformed(&form.kind, k, format!("+ {a} overflows u64")))?,
                Factor::Len(a) => form.array(a)?.len() as u64,
            };
            n = n
                .checked_mul(v)
                .ok_or_else(|| CompressError::malformed(&form.kind, "size", format!("{self:?} overflows u64")))?;
        }
        Ok(n)
    }
}

/// One compute dispatch: a WGSL entry point run for `threads` invocations.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PassDesc {
    pub entry_point: String,
    pub threads: Count,
}

/// A read-write buffer of `words` 32-bit words that the kernels use between passes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ScratchDesc {
    pub name: String,
    pub words: Count,
}

/// A structural fact about a form that the host verifies before any gather reads the form.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FormCheck {
    /// `array` has exactly `count` elements.
    Len { array: String, count: Count },
    /// `array` (integers) has `count + 1` non-decreasing entries running from 0 to the length
    /// of `target`: a CSR-style pointer array of `count` ranges into `target`.
    Ptr { array: String, count: Count, target: String },
    /// Every element of the integer `array` is at least 0 and below `bound`.
    Below { array: String, bound: Count },
    /// Every element of the float `array` is finite.
    Finite { array: String },
}

impl FormCheck {
    /// Verify the check on `form`; the error says which check and which element failed.
    pub fn run(&self, form: &CompressedForm) -> Result<(), CompressError> {
        let bad = |array: &str, m: String| Err(CompressError::malformed(&form.kind, array, m));
        match self {
            FormCheck::Len { array, count } => {
                let (n, want) = (form.array(array)?.len() as u64, count.eval(form)?);
                if n != want {
                    return bad(array, format!("has {n} elements, expected {want} ({count:?})"));
                }
            }
            FormCheck::Ptr { array, count, target } => {
                let (n, total) = (count.eval(form)?, form.array(target)?.len() as i64);
                let r = with_ints!(form, array, v => check_ptr(v, n, total));
                r.or_else(|m| bad(array, format!("(a pointer array) {m} (len('{target}') = {total})")))?;
            }
            FormCheck::Below { array, bound } => {
                let b = i64::try_from(bound.eval(form)?).unwrap_or(i64::MAX);
                let r = with_ints!(form, array, v => check_below(v, b));
                r.or_else(|(i, v)| bad(array, format!("element {i} is {v}, not in 0..{b}")))?;
            }
            FormCheck::Finite { array } => {
                if let Some(i) = form.f32s(array)?.iter().position(|v| !v.is_finite()) {
                    return bad(array, format!("element {i} is not finite"));
                }
            }
        }
        Ok(())
    }
}

/// `v` has `n + 1` non-decreasing entries from 0 to `total`.
fn check_ptr<T: Copy + Into<i64>>(v: &[T], n: u64, total: i64) -> Result<(), String> {
    if v.len() as u64 != n.saturating_add(1) {
        return Err(format!("has {} entries, expected {n} + 1", v.len()));
    }
    if v[0].into() != 0 || v[v.len() - 1].into() != total {
        return Err("must run from 0 to the length of its target".into());
    }
    if let Some(i) = v.windows(2).position(|w| w[1].into() < w[0].into()) {
        return Err(format!("decreases at entry {i}"));
    }
    Ok(())
}

/// Every element of `v` is in `0..bound`; else the first that is not.
fn check_below<T: Copy + Into<i64>>(v: &[T], bound: i64) -> Result<(), (usize, i64)> {
    match v.iter().position(|&x| x.into() < 0 || x.into() >= bound) {
        Some(i) => Err((i, v[i].into())),
        None => Ok(()),
    }
}

/// Everything a GPU runtime needs to run a form's gather, as plain data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct KernelDesc {
    /// The compressor kind whose forms these kernels read (equals the form's `kind`).
    pub kind: String,
    /// WGSL source without the runtime's prelude (which declares `params`, `light`, `lstar`,
    /// `meta_values` and the packing helpers; `biscale-gpu`, `gather/prelude.wgsl`).
    pub wgsl: String,
    /// Passes in order, all in one submission.
    pub passes: Vec<PassDesc>,
    pub scratch: Vec<ScratchDesc>,
    /// Meta keys copied, in this order, into the `meta_values` array.
    pub meta_keys: Vec<String>,
    /// Structural checks the host runs on every form before a gather.
    pub checks: Vec<FormCheck>,
}

impl KernelDesc {
    /// Run every declared check on `form` and evaluate every count (so a pass or scratch size
    /// that names a missing meta key or array fails here, before any upload).
    pub fn check_form(&self, form: &CompressedForm) -> Result<(), CompressError> {
        if form.kind != self.kind {
            return Err(CompressError::malformed(
                &form.kind,
                "kind",
                format!("given to the kernels of '{}'", self.kind),
            ));
        }
        for c in &self.checks {
            c.run(form)?;
        }
        for k in &self.meta_keys {
            form.meta(k)?;
        }
        for p in &self.passes {
            p.threads.eval(form)?;
        }
        for s in &self.scratch {
            s.words.eval(form)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::basis::{LightBasis, LocalBasis, TransferShape};

    fn form() -> CompressedForm {
        let shape = TransferShape::new(3, LocalBasis::bins(1).unwrap(), LightBasis::cubemap(1).unwrap());
        let mut f = CompressedForm::new("probe", shape)
            .with_array("ptr", ArrayData::U32(vec![0, 2, 2, 4]))
            .with_array("idx", ArrayData::U16(vec![0, 5, 1, 2]))
            .with_array("val", ArrayData::F32(vec![1.0, 2.0, 3.0, 4.0]));
        f.meta = [("k".to_string(), 2)].into();
        f
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
        vec![
            FormCheck::Len { array: "val".into(), count: Count::of([Factor::Len("idx".into())]) },
            FormCheck::Ptr { array: "ptr".into(), count: Count::of([Factor::Rows]), target: "idx".into() },
            FormCheck::Below { array: "idx".into(), bound: Count::of([Factor::Cols]) },
            FormCheck::Finite { array: "val".into() },
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
            f.arrays.iter_mut().find(|a| a.name == name).unwrap().data = data;
            f
        };
        let cases = [
            (with("val", ArrayData::F32(vec![1.0; 3])), "'val' has 3 elements, expected 4"),
            (with("ptr", ArrayData::U32(vec![0, 2, 4])), "expected 3 + 1"),
            (with("ptr", ArrayData::U32(vec![1, 2, 2, 4])), "from 0"),
            (with("ptr", ArrayData::U32(vec![0, 3, 2, 4])), "decreases at entry 1"),
            (with("idx", ArrayData::U16(vec![0, 6, 1, 2])), "'idx' element 1 is 6"),
            (with("idx", ArrayData::F32(vec![0.0; 4])), "integer array"),
            (with("val", ArrayData::F32(vec![1.0, f32::NAN, 3.0, 4.0])), "'val' element 1"),
        ];
        for (f, needle) in cases {
            let e = d.check_form(&f).unwrap_err().to_string();
            assert!(e.contains(needle), "{e} lacks {needle}");
        }
        let mut f = form();
        f.meta.clear();
        assert!(d.check_form(&f).unwrap_err().to_string().contains("'k'"));
        f = form();
        f.kind = "other".into();
        assert!(d.check_form(&f).is_err());
    }
}
