//! The low-frequency method: spherical-harmonics bi-scale radiance transfer (Sloan et al.
//! 2003), in biscale's vocabulary.
//!
//! * **Light**: the run's cubemap light `L` projected onto world SH of the setting's order
//!   (`biscale_core::sh::ShProjection`: exact for the piecewise-constant cubemap radiance up
//!   to the sub-texel midpoint rule), so both methods see the same light.
//! * **Transfer**: `M_p` per vertex, ray traced with the same frames, BVH and origin offset as
//!   `T` (`biscale_core::transfer::sh`), cached like `T`; compressed by the setting's
//!   `compressor` (raw `sparse` by default; `cpca` is Sloan's CPCA of these matrices).
//! * **Meso scale**: each material's BTF (the same table the all-frequency path shades with)
//!   projected onto local SH, the radiance transfer texture (`biscale_core::sh::rtt`). The
//!   BTF's patch tiling by UV plays the role of Sloan's id map: the same `tiling` places the
//!   patch in both methods, so an id map is not needed for the comparison.
//! * **Runtime**: the compressor's gather `l_p = M_p L_sh` (CPU, and wgpu on the GPU backend)
//!   and the same shaders as the all-frequency path: they take a dot product over the local
//!   basis, bins or SH alike.

use super::MethodKind;
use biscale_compressors::registry;
use serde::{Deserialize, Serialize};
use serde_json::Value;

/// Default rays per vertex of `M_p`.
pub const DEFAULT_RAYS: u32 = 1024;

/// The parameters of one SH setting (`[[methods]] kind = "sh"`).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ShParams {
    /// SH order `n`: bands `0..n`, `n^2` coefficients (Sloan's 5 gives 25), `2..=8`.
    pub order: u32,
    /// Rays per vertex for `M_p` (rounded up to a square stratified grid), default 1024.
    #[serde(default = "default_rays")]
    pub rays: u32,
    /// Interreflection bounces folded into `M_p` (default 0: shadowed transfer only).
    #[serde(default)]
    pub bounces: u32,
    /// The compressor of the `M_p` set, a compressor table (`{ kind = "cpca", clusters = 32,
    /// components = 8 }`); default: the raw matrices (`sparse`).
    #[serde(default)]
    pub compressor: Option<Value>,
}

fn default_rays() -> u32 {
    DEFAULT_RAYS
}

/// Most bounces a setting may ask for.
pub const MAX_BOUNCES: u32 = 8;

impl ShParams {
    pub fn parse(p: &Value) -> Result<Self, String> {
        let s: ShParams = registry::parse(p)?;
        if !(2..=biscale_core::sh::MAX_SH_ORDER).contains(&s.order) {
            return Err(format!("order must be 2..={}, got {}", biscale_core::sh::MAX_SH_ORDER, s.order));
        }
        biscale_core::transfer::sh::ShTransferSettings::new(s.order, s.rays, 0).map_err(|e| e.to_string())?;
        if s.bounces > MAX_BOUNCES {
            return Err(format!("bounces must be 0..={MAX_BOUNCES}, got {}", s.bounces));
        }
        if let Some(c) = &s.compressor {
            let (kind, params) = compressor_parts(c)?;
            let k = registry::find(&kind)
                .ok_or_else(|| format!("unknown compressor kind `{kind}`, expected one of {:?}", registry::names()))?;
            if k.role == registry::Role::External {
                return Err("a plugin cannot compress the SH transfer (give sparse or cpca)".into());
            }
            (k.check)(&params).map_err(|e| format!("compressor: {e}"))?;
        }
        Ok(s)
    }

    /// The compressor's registry kind and parameters (`sparse` with none by default).
    pub fn compressor(&self) -> (String, Value) {
        match &self.compressor {
            Some(c) => compressor_parts(c).expect("checked when the config was read"),
            None => (raw_kind().into(), Value::Object(Default::default())),
        }
    }
}

/// The kind of the raw matrices, the default compressor of `M_p`.
fn raw_kind() -> &'static str {
    registry::by_role(registry::Role::Raw).expect("the registry has a raw kind").name
}

/// `kind` and the other keys of a compressor table given as JSON.
fn compressor_parts(c: &Value) -> Result<(String, Value), String> {
    let Value::Object(map) = c else { return Err("compressor must be a table with a kind".into()) };
    let kind = map.get("kind").and_then(Value::as_str).ok_or("compressor needs kind = \"...\"")?.to_string();
    let mut rest = map.clone();
    rest.remove("kind");
    Ok((kind, Value::Object(rest)))
}

/// The registry entry: labels like `sh-n5`, `sh-n5-b1-r4096`, `sh-n5-cpca-k32-c8`.
pub const KIND: MethodKind = MethodKind {
    name: "sh",
    about: "low-frequency bi-scale rendering: SH light, per-vertex SH transfer, radiance transfer textures (Sloan et al. 2003)",
    label: |p| {
        let s = ShParams::parse(p)?;
        let mut label = format!("sh-n{}", s.order);
        if s.bounces > 0 {
            label += &format!("-b{}", s.bounces);
        }
        if p.get("rays").is_some() {
            label += &format!("-r{}", s.rays);
        }
        if s.compressor.is_some() {
            let (kind, params) = s.compressor();
            let k = registry::find(&kind).expect("checked");
            label += &format!("-{}", (k.label)(&params)?);
        }
        Ok(label)
    },
    check: |p| ShParams::parse(p).map(drop),
};
