//! The analytic BRDFs the shader evaluates for `runtime.moments_resolve = "pixel_analytic"`
//! (`brdf.wgsl`): each material's [`Brdf`] as the plain record the WGSL reads, its parameters
//! taken from the `Brdf` itself and the rough plastic's coating table from [`Brdf::coating`],
//! the table the CPU evaluates, so the GPU and
//! the CPU share every constant and differ only in the formulas' arithmetic (f32 here), which
//! the test `brdf_matches_the_cpu` bounds.

use biscale_shading::microfacet::TRANSMITTANCE_RES;
use biscale_shading::synth::Brdf;

/// `GpuBrdf::kind` of a material shaded from its BTF's tables (no analytic BRDF).
pub const BRDF_NONE: u32 = 0;

/// The kinds' codes in WGSL, by [`Brdf::kind`] name (`BRDF_` + the name in upper snake case).
const KINDS: [(&str, u32); 5] =
    [("lambertian", 1), ("phong", 2), ("ashikhmin-shirley", 3), ("rough-conductor", 4), ("rough-plastic", 5)];

/// One material's analytic BRDF as `brdf.wgsl` reads it (mirrors WGSL `Brdf`, 80 bytes;
/// checked by the layout test). The four vectors hold the kind's parameters:
///
/// | kind | `a` | `b` | `c` | `s` |
/// |---|---|---|---|---|
/// | lambertian | albedo | | | |
/// | phong | `kd` | `ks` | | exponent |
/// | ashikhmin-shirley | `rd` | `rs` | | `nu`, `nv` |
/// | rough-conductor | `eta` | `k` | `specular_reflectance` | `alpha` |
/// | rough-plastic | `diffuse_reflectance` | `specular_reflectance` | | `alpha`, `int_ior / ext_ior`, `R_int` |
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct GpuBrdf {
    pub kind: u32,
    /// Rough plastic: first float of its external transmittance table in the coating buffer.
    pub coating: u32,
    /// Rough plastic: 1 for `nonlinear`.
    pub nonlinear: u32,
    pub _pad: u32,
    pub a: [f32; 4],
    pub b: [f32; 4],
    pub c: [f32; 4],
    pub s: [f32; 4],
}
const _: () = assert!(std::mem::size_of::<GpuBrdf>() == 80);

fn rgb(v: [f32; 3]) -> [f32; 4] {
    [v[0], v[1], v[2], 0.0]
}

/// The WGSL constants of the kinds (`BRDF_NONE`, `BRDF_LAMBERTIAN`, ...) and the coating
/// table's node count, generated from the Rust ones.
pub fn brdf_constants_wgsl() -> String {
    let mut s = format!("const BRDF_NONE: u32 = {BRDF_NONE}u;\nconst COATING_NODES: u32 = {TRANSMITTANCE_RES}u;\n");
    for (name, code) in KINDS {
        s += &format!("const BRDF_{}: u32 = {code}u;\n", name.replace('-', "_").to_uppercase());
    }
    s
}

/// `brdf`'s code in WGSL.
fn kind_code(brdf: &Brdf) -> u32 {
    KINDS.iter().find(|(name, _)| *name == brdf.kind()).map(|(_, code)| *code).expect("every Brdf kind has a code")
}

impl GpuBrdf {
    /// The record of `brdf`; a rough plastic's coating table is appended to `coating`.
    pub fn new(brdf: &Brdf, coating: &mut Vec<f32>) -> Self {
        let mut g = GpuBrdf { kind: kind_code(brdf), ..Default::default() };
        match *brdf {
            Brdf::Lambertian { albedo } => g.a = rgb(albedo),
            Brdf::Phong { kd, ks, exponent } => {
                (g.a, g.b) = (rgb(kd), rgb(ks));
                g.s[0] = exponent;
            }
            Brdf::AshikhminShirley { rd, rs, nu, nv } => {
                (g.a, g.b) = (rgb(rd), rgb(rs));
                g.s[..2].copy_from_slice(&[nu, nv]);
            }
            Brdf::RoughConductor { alpha, eta, k, specular_reflectance } => {
                (g.a, g.b, g.c) = (rgb(eta), rgb(k), rgb(specular_reflectance));
                g.s[0] = alpha;
            }
            Brdf::RoughPlastic { alpha, diffuse_reflectance, specular_reflectance, nonlinear, .. } => {
                // The relative IOR and the table exactly as the CPU evaluates them.
                let table = brdf.coating().expect("a rough plastic has a coating");
                g.coating = coating.len() as u32;
                coating.extend(table.external_transmittance.iter().map(|&t| t as f32));
                (g.a, g.b) = (rgb(diffuse_reflectance), rgb(specular_reflectance));
                g.s[..3].copy_from_slice(&[alpha, table.eta as f32, table.internal_reflectance as f32]);
                g.nonlinear = u32::from(nonlinear);
            }
        }
        g
    }

    /// The records of `brdfs` (one per material, `None`: shaded from the tables) and the
    /// coating tables they index (a placeholder float when there are none: wgpu cannot bind an
    /// empty buffer).
    pub fn records(brdfs: &[Option<Brdf>]) -> (Vec<GpuBrdf>, Vec<f32>) {
        let mut coating = vec![];
        let records =
            brdfs.iter().map(|b| b.as_ref().map_or_else(GpuBrdf::default, |b| GpuBrdf::new(b, &mut coating))).collect();
        if coating.is_empty() {
            coating.push(0.0);
        }
        (records, coating)
    }
}
