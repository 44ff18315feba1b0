//! BTFs synthesized by ray tracing small tileable height-field patches, the way Sloan et al.
//! built their radiance transfer textures ("Bi-scale radiance transfer", SIGGRAPH 2003,
//! section 5) and Sun et al. their meso-scale BTFs.
//!
//! * [`heightfield`]: periodic height fields from procedural recipes (bumps, weave, stucco,
//!   holes, bricks, scales) or grayscale images, and albedo maps.
//! * [`brdf`]: Lambertian, normalized Phong, Ashikhmin-Shirley and the GGX rough conductor and
//!   rough plastic ([`crate::microfacet`], Mitsuba 3's) meso-scale BRDFs.
//! * [`synthesize`]: the generator, rayon-parallel; [`BtfSpec`] holds its inputs.
//! * [`file`](mod@file): the binary BTF file (`save_btf` / `load_btf`, f32 / f16 / u8).
//! * [`preview`]: contact sheets of a BTF under several lights and views.
//!
//! # What is computed
//!
//! docs/DESIGN.md section 3: `b(u, e, d_j)` is the outgoing radiance at patch texel `u` towards
//! view `e` under a directional light of unit perpendicular irradiance from `d_j`:
//!
//! ```text
//! b(u, e, d_j) = mean over s x s view rays r through u's footprint of
//!     f(X_r; d_j, e) * max(0, n_r . dbar_j) * V(X_r, d_j)      (+ one bounce, optional)
//! ```
//!
//! * **Masking.** `X_r` is the first hit of a ray cast from above along `-e` through the
//!   sample point `(x, y)` of the texel's footprint on the **macro plane** `z = mean height`,
//!   on the infinitely tiled surface (rays wrap periodically: `trace.rs` walks the grid in
//!   unbounded cell coordinates, so no 3x3 tiling is built and grazing rays never escape it). A texel may thus show a point of
//!   another texel or patch, and never one hidden behind a bump.
//! * **Facets.** The surface is the piecewise-linear triangulation of the height field (two
//!   triangles per cell); `n_r` is the hit triangle's geometric normal. The BRDF is evaluated in
//!   the facet's frame (normal `n_r`, tangent = patch +X projected onto the facet), which the
//!   anisotropic Ashikhmin-Shirley BRDF needs.
//! * **Directions.** `d_j` and `e` are the bin centres of the light and view
//!   [`HemisphereGrid`](biscale_core::sampling::HemisphereGrid)s (local +Z = macro normal, +X =
//!   tangent). The cosine uses the same **bin-mean** convention as [`Btf::lambertian`](biscale_core::scene::Btf::lambertian):
//!   `dbar_j` is the mean direction over bin `j` (its `z` is the bin-mean cosine), so a flat
//!   patch gives `cosbar_j` exactly, and for a tilted facet `n . dbar_j` is the exact mean
//!   cosine whenever the bin lies wholly above the facet's horizon (bins straddling it use the
//!   clamp, which can only under-estimate: energy stays bounded).
//! * **Shadowing.** `V(X, d_j)` is 0 when the ray from `X` towards the bin centre `d_j` hits
//!   the tiled surface, or when `d_j` is below the facet's horizon.
//! * **Albedo map.** Scales the BRDF's diffuse term at `X_r`'s patch coordinates.
//! * **Interreflection** (optional, one bounce). `bounce_rays` cosine-weighted directions `w_k`
//!   around `n_r` (R2 sequence, Cranley-Patterson rotated per visible point) find the facet
//!   `q_k` each one sees; the bounce adds `pi / K * sum_k f(X; w_k, e) f(q_k; d_j, -w_k) E_j(q_k)`,
//!   where `E_j(q)` is `q`'s triangle's direct irradiance: `max(0, n_q . dbar_j)` times its
//!   unshadowed fraction at 4 points. Rays that escape see the black sky (the light is one
//!   direction). The estimator is unbiased for the triangle-averaged visibility; its noise
//!   falls as `1 / sqrt(K s^2)` per texel.
//! * **Flat patches** (zero amplitude) are tabulated without ray tracing: with no albedo map,
//!   [`Btf::lambertian`](biscale_core::scene::Btf::lambertian) / [`Btf::phong`](biscale_core::scene::Btf::phong)
//!   themselves (one texel; a Lambertian one has no view axis), the other BRDFs analytically
//!   at one texel (a flat GGX patch is the flat GGX material Mitsuba renders).
//!
//! Shortest use:
//!
//! ```no_run
//! use biscale_shading::synth::*;
//! let hf = HeightField::procedural(&Recipe::new(Pattern::Bumps, 0.05, 4, 1), 128).unwrap();
//! let spec = BtfSpec::new(hf, Brdf::Lambertian { albedo: [0.8; 3] });
//! let btf = synthesize(&spec, None).unwrap();
//! save_btf(&btf, "bumps.btf".as_ref(), BtfEncoding::F16).unwrap();
//! save_contact_sheet(&btf, &[0, 27, 63], &[0, 66], "bumps.png".as_ref()).unwrap();
//! ```

pub mod brdf;
pub mod file;
mod generate;
pub mod heightfield;
pub mod preview;
mod trace;

pub use brdf::Brdf;
pub use file::{
    btf_artifact, btf_from_artifact, decode_btf, encode_btf, load_btf, save_btf, BtfEncoding, BTF_ARTIFACT,
};
pub use generate::{synthesize, BtfSpec};
pub use heightfield::{AlbedoMap, HeightField, Pattern, Recipe};
pub use preview::{comparison_sheet, contact_sheet, save_contact_sheet, COMPARISON_GAP};

#[cfg(test)]
mod tests;
