//! The runtime's choices, each one type from its config key (`runtime.backend`,
//! `runtime.moments_resolve`) through the shaders to `metrics.json` and the report, so no stage
//! matches on a spelling: where the images are made, and where light moments are resolved into
//! the `L*` a BTF is dotted with.

use serde::{Deserialize, Serialize};

/// `runtime.backend`: where the runtime gathers and shades. Serialised as the config spells it.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq, Hash)]
#[serde(rename_all = "snake_case")]
pub enum Backend {
    /// The CPU reference (every run's images).
    #[default]
    Cpu,
    /// wgpu, beside the CPU images (`metrics.json`'s `gpu` records).
    Gpu,
}

impl Backend {
    /// The config's spelling.
    pub fn name(self) -> &'static str {
        match self {
            Backend::Cpu => "cpu",
            Backend::Gpu => "gpu",
        }
    }
}

impl std::fmt::Display for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// `runtime.moments_resolve`: where the three gathered light moments of a vertex become the
/// `L*` its BTF is dotted with. Serialised as the config spells it (`vertex`, `pixel`,
/// `pixel_analytic`).
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq, Hash)]
#[serde(rename_all = "snake_case")]
pub enum MomentsResolve {
    /// At each vertex, then blended across the triangle ([`crate::cpu::shade`]).
    #[default]
    Vertex,
    /// Each vertex's moments resolved at the pixel's own frame with the BTF's tables, then
    /// blended ([`crate::cpu::shade_moments`]).
    Pixel,
    /// As `Pixel`, with an analytic material's own BRDF at each bin's mean direction and the
    /// pixel's exact view instead of its tables ([`crate::cpu::shade_moments_analytic`]).
    PixelAnalytic,
}

impl MomentsResolve {
    /// Every resolve, in declaration order.
    pub const ALL: [MomentsResolve; 3] = [MomentsResolve::Vertex, MomentsResolve::Pixel, MomentsResolve::PixelAnalytic];

    /// The config's spelling.
    pub fn name(self) -> &'static str {
        match self {
            MomentsResolve::Vertex => "vertex",
            MomentsResolve::Pixel => "pixel",
            MomentsResolve::PixelAnalytic => "pixel_analytic",
        }
    }

    /// Whether the moments are resolved at every shading point.
    pub fn per_pixel(self) -> bool {
        self != MomentsResolve::Vertex
    }

    /// Why an `L*` alone cannot be shaded or scored under this resolve, and what to do instead:
    /// the per-pixel resolves shade a vertex's three moment gathers, which an `L*` does not
    /// hold. `None` for `vertex`. The one refusal every entry point (`eval --lstar`, the
    /// Python module's `shade` and `evaluate`) gives.
    pub fn refuses_lstar(self) -> Option<String> {
        self.per_pixel().then(|| {
            format!(
                "runtime.moments_resolve = \"{}\" shades the three moment gathers, which an L* does not hold: \
                 score or shade it with runtime.moments_resolve = \"vertex\", or use a form",
                self.name()
            )
        })
    }
}

#[cfg(test)]
mod tests {
    use super::{Backend, MomentsResolve};

    #[test]
    fn serialised_as_the_config_spells_it() {
        for b in [Backend::Cpu, Backend::Gpu] {
            assert_eq!(serde_json::to_string(&b).unwrap(), format!("\"{b}\""));
        }
        for r in MomentsResolve::ALL {
            let json = serde_json::to_string(&r).unwrap();
            assert_eq!(json, format!("\"{}\"", r.name()));
            assert_eq!(serde_json::from_str::<MomentsResolve>(&json).unwrap(), r);
        }
    }
}
