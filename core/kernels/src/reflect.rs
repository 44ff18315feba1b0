//! naga reflection of a gather program (feature `reflect`): the one place that parses a
//! [`KernelDesc`]'s WGSL, validates it, and says what each `@group(0)` global is for.
//!
//! Bindings are never listed by hand. A global is bound by its *name*:
//!
//! | name | must be |
//! |---|---|
//! | `params` | `var<uniform> GatherParams` (the prelude's) |
//! | `light`, `lstar`, `meta_values` | the prelude's storage arrays |
//! | a declared scratch buffer | `var<storage, read_write>` |
//! | anything else | a form array: `var<storage, read> <name>: array<f32>` for f32 arrays, `array<u32>` or `array<i32>` for integer arrays (packed, see [`ArrayData::pack_words`]) |
//!
//! [`reflect`] checks everything that does not depend on a form (at plugin load, and before a
//! GPU runtime builds the program); [`Reflected::check_arrays`] checks that a form has every
//! array the program binds, with a compatible element type.

use crate::{ArrayData, FormData, FormError, GatherParams, KernelDesc, PRELUDE, RESERVED_NAMES};
use std::collections::BTreeSet;

/// Element type of a reflected storage array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Elem {
    F32,
    U32,
    I32,
    /// Anything else (a struct, a vector, ...): allowed only for scratch buffers.
    Other,
}

/// What a global of the program binds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Role {
    /// The uniform `params` ([`GatherParams`]).
    Params,
    /// `L`, N texels x RGB f32 (read-only).
    Light,
    /// `L*`, rows x RGB f32 (read-write).
    Lstar,
    /// The program's meta keys' values, in order (u32, read-only).
    Meta,
    /// A scratch buffer the program declares (read-write).
    Scratch,
    /// The form array of this name (read-only).
    FormArray,
}

/// One reflected `@group(0)` global.
#[derive(Clone, Debug)]
pub struct Global {
    pub name: String,
    pub binding: u32,
    pub role: Role,
    /// True for read-only storage and for the uniform.
    pub read_only: bool,
    pub elem: Elem,
    /// Byte size of a uniform (`params`); `None` for storage.
    pub uniform_size: Option<u64>,
}

/// A parsed and checked program: the full source (prelude included), its globals in binding
/// order and its compute entry points' workgroup sizes.
#[derive(Clone, Debug)]
pub struct Reflected {
    pub source: String,
    pub globals: Vec<Global>,
    pub workgroup_sizes: Vec<(String, [u32; 3])>,
}

/// A program that does not compile or breaks the binding conventions.
#[derive(Debug, thiserror::Error)]
#[error("WGSL program '{kind}': {message}")]
pub struct ReflectError {
    pub kind: String,
    pub message: String,
}

/// Parse and validate `desc`'s WGSL (prelude included) with naga and check every convention
/// above, the passes' entry points and the scratch buffers (see the module docs).
pub fn reflect(desc: &KernelDesc) -> Result<Reflected, ReflectError> {
    let source = format!("{PRELUDE}\n{}", desc.wgsl);
    let err = |message: String| ReflectError { kind: desc.kind.clone(), message };
    let located = |report: String| {
        let n = PRELUDE.lines().count() + 1;
        err(format!("{report}\n(line numbers count the {n} lines of the gather prelude before the program's own WGSL)"))
    };
    let module = naga::front::wgsl::parse_str(&source).map_err(|e| located(e.emit_to_string(&source)))?;
    // `unpack2x16float` (half-float values) is core WGSL, which naga gates behind a capability.
    let capabilities = naga::valid::Capabilities::default() | naga::valid::Capabilities::SHADER_FLOAT16_IN_FLOAT32;
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), capabilities)
        .validate(&module)
        .map_err(|e| located(e.emit_to_string(&source)))?;
    let mut seen = BTreeSet::new();
    for s in &desc.scratch {
        if RESERVED_NAMES.contains(&s.name.as_str()) || !seen.insert(s.name.as_str()) {
            return Err(err(format!("scratch buffer '{}' is reserved or declared twice", s.name)));
        }
    }
    let is_scratch = |name: &str| desc.scratch.iter().any(|s| s.name == name);
    let mut globals = Vec::new();
    for (_, g) in module.global_variables.iter() {
        let Some(rb) = &g.binding else { continue };
        let name = g.name.clone().unwrap_or_default();
        if rb.group != 0 {
            return Err(err(format!("global '{name}' is in group {}; gather programs use group 0 only", rb.group)));
        }
        let global = match g.space {
            naga::AddressSpace::Uniform => {
                let size = module.types[g.ty].inner.size(module.to_ctx()) as u64;
                if name != "params" {
                    return Err(err(format!("uniform '{name}': only 'params' may be a uniform")));
                }
                if size != std::mem::size_of::<GatherParams>() as u64 {
                    return Err(err(format!("'params' is {size} bytes, GatherParams is 32")));
                }
                Global {
                    name,
                    binding: rb.binding,
                    role: Role::Params,
                    read_only: true,
                    elem: Elem::Other,
                    uniform_size: Some(size),
                }
            }
            naga::AddressSpace::Storage { access } => {
                let read_only = !access.contains(naga::StorageAccess::STORE);
                let elem = match &module.types[g.ty].inner {
                    naga::TypeInner::Array { base, .. } => match module.types[*base].inner {
                        naga::TypeInner::Scalar(naga::Scalar { kind: naga::ScalarKind::Float, width: 4 }) => Elem::F32,
                        naga::TypeInner::Scalar(naga::Scalar { kind: naga::ScalarKind::Uint, width: 4 }) => Elem::U32,
                        naga::TypeInner::Scalar(naga::Scalar { kind: naga::ScalarKind::Sint, width: 4 }) => Elem::I32,
                        _ => Elem::Other,
                    },
                    _ => Elem::Other,
                };
                let (role, want) = match name.as_str() {
                    "light" => (Role::Light, Some((Elem::F32, true))),
                    "lstar" => (Role::Lstar, Some((Elem::F32, false))),
                    "meta_values" => (Role::Meta, Some((Elem::U32, true))),
                    _ if is_scratch(&name) => {
                        if read_only {
                            return Err(err(format!("scratch buffer '{name}' must be var<storage, read_write>")));
                        }
                        (Role::Scratch, None)
                    }
                    _ => {
                        if !read_only {
                            return Err(err(format!(
                                "global '{name}' is read_write but is not a declared scratch buffer"
                            )));
                        }
                        if elem == Elem::Other {
                            return Err(err(format!(
                                "form array '{name}' must be declared array<f32>, array<u32> or array<i32>"
                            )));
                        }
                        (Role::FormArray, None)
                    }
                };
                if let Some((e, ro)) = want {
                    if (e, ro) != (elem, read_only) {
                        return Err(err(format!("'{name}' must be declared as the prelude declares it")));
                    }
                }
                Global { name, binding: rb.binding, role, read_only, elem, uniform_size: None }
            }
            other => return Err(err(format!("global '{name}' has unsupported address space {other:?}"))),
        };
        globals.push(global);
    }
    globals.sort_by_key(|g| g.binding);
    for w in globals.windows(2) {
        if w[0].binding == w[1].binding {
            return Err(err(format!("'{}' and '{}' share binding {}", w[0].name, w[1].name, w[0].binding)));
        }
    }
    if let Some(s) = desc.scratch.iter().find(|s| !globals.iter().any(|g| g.name == s.name)) {
        return Err(err(format!("scratch buffer '{}' is not declared in the WGSL", s.name)));
    }
    for role in [Role::Light, Role::Lstar] {
        if !globals.iter().any(|g| g.role == role) {
            return Err(err(format!("the program does not bind {role:?} (the prelude declares it)")));
        }
    }
    let workgroup_sizes: Vec<(String, [u32; 3])> = module
        .entry_points
        .iter()
        .filter(|e| e.stage == naga::ShaderStage::Compute)
        .map(|e| (e.name.clone(), e.workgroup_size))
        .collect();
    for p in &desc.passes {
        if !workgroup_sizes.iter().any(|(n, _)| *n == p.entry_point) {
            let names: Vec<&str> = module.entry_points.iter().map(|e| e.name.as_str()).collect();
            return Err(err(format!(
                "pass entry point '{}' is not a @compute function (found {names:?})",
                p.entry_point
            )));
        }
    }
    Ok(Reflected { source, globals, workgroup_sizes })
}

impl Reflected {
    /// Invocations per workgroup of the compute entry point `name`.
    pub fn workgroup_size(&self, name: &str) -> Option<u64> {
        self.workgroup_sizes.iter().find(|(n, _)| n == name).map(|(_, w)| w.iter().map(|&x| x as u64).product())
    }

    /// An error unless `form` has every array the program binds, with a compatible element
    /// type (f32 arrays as `array<f32>`, integer arrays as `array<u32>` or `array<i32>`).
    pub fn check_arrays(&self, form: &dyn FormData) -> Result<(), FormError> {
        for g in self.globals.iter().filter(|g| g.role == Role::FormArray) {
            let data = form.find_array(&g.name).ok_or_else(|| {
                FormError::new(
                    form,
                    &g.name,
                    "is bound by the WGSL but the form has no such array (nor is it a scratch buffer)",
                )
            })?;
            let ok = match data {
                ArrayData::F32(_) => g.elem == Elem::F32,
                _ => matches!(g.elem, Elem::U32 | Elem::I32),
            };
            if !ok {
                return Err(FormError::new(
                    form,
                    &g.name,
                    format!(
                        "is {} but the WGSL declares array<{:?}> (f32 arrays need array<f32>, integer arrays array<u32> or array<i32>)",
                        data.element_type(),
                        g.elem
                    ),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Count, Factor, PassDesc, ScratchDesc};

    fn desc(wgsl: &str) -> KernelDesc {
        KernelDesc {
            kind: "probe".into(),
            wgsl: wgsl.into(),
            passes: vec![PassDesc { entry_point: "main".into(), threads: Count::of([Factor::Rows]) }],
            scratch: vec![ScratchDesc { name: "tmp".into(), words: Count::of([Factor::Rows]) }],
            meta_keys: vec![],
            checks: vec![],
        }
    }

    const GOOD: &str = "@group(0) @binding(4) var<storage, read> codes: array<u32>;
@group(0) @binding(5) var<storage, read> scale: array<f32>;
@group(0) @binding(6) var<storage, read_write> tmp: array<f32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) id: vec3<u32>) {
    tmp[id.x] = scale[0] * f32(codes[id.x]) + light[0];
    store_lstar(id.x, vec3<f32>(tmp[id.x]));
}";

    #[test]
    fn a_good_program_is_reflected_by_role() {
        let r = reflect(&desc(GOOD)).unwrap();
        let roles: Vec<(&str, Role)> = r.globals.iter().map(|g| (g.name.as_str(), g.role.clone())).collect();
        assert_eq!(
            roles,
            [
                ("params", Role::Params),
                ("light", Role::Light),
                ("lstar", Role::Lstar),
                ("meta_values", Role::Meta),
                ("codes", Role::FormArray),
                ("scale", Role::FormArray),
                ("tmp", Role::Scratch),
            ]
        );
        assert_eq!(r.workgroup_size("main"), Some(64));
    }

    #[test]
    fn broken_conventions_are_errors() {
        let cases = [
            (GOOD.replace("fn main", "fn other"), "not a @compute function"),
            (
                GOOD.replace("read_write> tmp", "read> tmp")
                    .replace("tmp[id.x] = scale[0] * f32(codes[id.x]) + light[0];", ""),
                "must be var<storage, read_write>",
            ),
            (GOOD.replace("read> codes", "read_write> codes"), "is read_write but is not a declared scratch"),
            (
                GOOD.replace("codes: array<u32>", "codes: array<vec2<u32>>")
                    .replace("f32(codes[id.x])", "f32(codes[id.x].x)"),
                "must be declared array<f32>",
            ),
            (GOOD.replace("@group(0) @binding(5)", "@group(1) @binding(5)"), "group 1"),
            (GOOD.replace("@binding(5)", "@binding(4)"), "is invalid"),
            (GOOD.replace("scale[0]", "scale[0"), "expected"),
        ];
        for (wgsl, needle) in cases {
            let e = reflect(&desc(&wgsl)).unwrap_err().to_string();
            assert!(e.contains(needle), "{e} lacks {needle}");
        }
        let mut d = desc(GOOD);
        d.scratch.push(ScratchDesc { name: "light".into(), words: Count::of([]) });
        assert!(reflect(&d).unwrap_err().to_string().contains("reserved"));
        let mut d = desc(GOOD);
        d.scratch.push(ScratchDesc { name: "missing".into(), words: Count::of([]) });
        assert!(reflect(&d).unwrap_err().to_string().contains("not declared in the WGSL"));
    }
}
