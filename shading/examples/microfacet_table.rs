//! Print biscale's rough conductor and rough plastic BRDFs (GGX, `biscale_shading::microfacet`
//! through the synthesized BTFs' `Brdf`) on random direction pairs as CSV, for
//! scripts/mitsuba_bsdf_check.py to compare with Mitsuba 3:
//!
//! ```text
//! cargo run -p biscale-shading --example microfacet_table [pairs per material, default 40] > table.csv
//! ```
//!
//! Columns: `alpha,kind,params,light_x,light_y,light_z,view_x,view_y,view_z,r,g,b`. `kind` is
//! Mitsuba's plugin name; `params` its other parameters as `name=v` or `name=r:g:b`, joined by
//! `;`; `r,g,b` is `f(light, view)` without the cosine (Mitsuba's `eval` with `si.wi = view`
//! and `wo = light`, divided by `light_z`).

use biscale_shading::synth::Brdf;
use glam::DVec3;
use rand::{Rng, SeedableRng};

fn rgb(v: [f32; 3]) -> String {
    format!("{}:{}:{}", v[0], v[1], v[2])
}

fn main() {
    let pairs: usize = std::env::args().nth(1).map_or(40, |s| s.parse().expect("pairs per material: a number"));
    let mut materials = Vec::new();
    for alpha in [0.05f32, 0.2, 0.5, 1.0] {
        // Mitsuba's default conductor (F = 1) and a coloured metal.
        materials.push(Brdf::RoughConductor { alpha, eta: [0.0; 3], k: [1.0; 3], specular_reflectance: [1.0; 3] });
        materials.push(Brdf::RoughConductor {
            alpha,
            eta: [0.2, 0.9, 1.1],
            k: [3.9, 2.4, 2.2],
            specular_reflectance: [1.0, 0.9, 0.8],
        });
        for nonlinear in [false, true] {
            materials.push(Brdf::RoughPlastic {
                alpha,
                int_ior: 1.49,
                ext_ior: 1.000277,
                diffuse_reflectance: [0.8, 0.4, 0.1],
                specular_reflectance: [1.0, 1.0, 0.7],
                nonlinear,
            });
        }
        materials.push(Brdf::RoughPlastic {
            alpha,
            int_ior: 1.9,
            ext_ior: 1.33,
            diffuse_reflectance: [0.5; 3],
            specular_reflectance: [1.0; 3],
            nonlinear: false,
        });
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2024);
    let mut dir = |near: Option<DVec3>| -> DVec3 {
        // Half the views near the mirror direction of the light (inside the lobe), the rest
        // uniform over the hemisphere; z >= 0.02 (Mitsuba's f32 at grazing aside).
        if let Some(r) = near {
            for _ in 0..100 {
                let jitter = DVec3::new(rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.3));
                let d = (r + jitter).normalize();
                if d.z >= 0.02 {
                    return d;
                }
            }
        }
        let z: f64 = rng.gen_range(0.02..1.0);
        let phi: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
        let s = (1.0 - z * z).sqrt();
        DVec3::new(s * phi.cos(), s * phi.sin(), z)
    };
    println!("alpha,kind,params,light_x,light_y,light_z,view_x,view_y,view_z,r,g,b");
    for brdf in &materials {
        brdf.validate().expect("valid material");
        let (alpha, kind, params) = match *brdf {
            Brdf::RoughConductor { alpha, eta, k, specular_reflectance } => (
                alpha,
                "roughconductor",
                format!("eta={};k={};specular_reflectance={}", rgb(eta), rgb(k), rgb(specular_reflectance)),
            ),
            Brdf::RoughPlastic { alpha, int_ior, ext_ior, diffuse_reflectance, specular_reflectance, nonlinear } => (
                alpha,
                "roughplastic",
                format!(
                    "int_ior={int_ior};ext_ior={ext_ior};diffuse_reflectance={};specular_reflectance={};nonlinear={nonlinear}",
                    rgb(diffuse_reflectance),
                    rgb(specular_reflectance)
                ),
            ),
            _ => unreachable!("only microfacet BRDFs are listed"),
        };
        for i in 0..pairs {
            let light = dir(None);
            let view = dir((i % 2 == 0).then(|| DVec3::new(-light.x, -light.y, light.z)));
            let f = brdf.eval_scaled(light, view, [1.0; 3]);
            println!(
                "{alpha},{kind},{params},{},{},{},{},{},{},{:e},{:e},{:e}",
                light.x, light.y, light.z, view.x, view.y, view.z, f[0], f[1], f[2]
            );
        }
    }
}
