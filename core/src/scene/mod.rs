//! The shading vocabulary every shader shares: the CPU shader and the ray-traced reference
//! (`biscale-shading`), the wgpu shader and the viewer (`biscale-gpu`) take the same
//! [`ShadeScene`], the same [`LocalRadiance`] and the same [`Camera`], and return the same
//! [`Render`].
//!
//! * [`ShadeScene`]: the mesh, one frame per vertex, the materials and (with several) one
//!   material id per triangle. Validated once at construction, so no shader checks it again;
//!   the check that `L*` fits the scene (its local basis is the materials' light basis, one
//!   block per vertex) is [`ShadeScene::check_lstar`], the one place it is made.
//! * [`Btf`], [`Material`]: the tabulated BTF `b(u, e, d_j)` and how often it tiles;
//!   [`BtfRepresentation`]: how a material stores it (dense, or local PCA, [`LpcaBtf`]).
//! * [`Camera`]: the pinhole camera; [`image`]: the RGB image type and its files.

pub mod btf;
pub mod camera;
pub mod image;
pub mod lpca;
pub mod representation;

pub use btf::Btf;
pub use camera::{Camera, Rays};
pub use image::{Background, HdrImage, Render};
pub use lpca::{LpcaBtf, LpcaQuantize, LpcaReport, LpcaSettings, LpcaUnit, DEFAULT_LPCA_ITERATIONS};
pub use representation::BtfRepresentation;

use crate::basis::LocalBasis;
use crate::error::{CoreError, Result};
use crate::gather::LocalRadiance;
use crate::geometry::{Mesh, SceneBvh, VertexFrame};
use std::sync::{Arc, OnceLock};

/// A BTF (dense or compressed) and how often its patch repeats per unit of texture coordinate.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub btf: BtfRepresentation,
    /// Patch repetitions per unit of uv: the BTF is looked up at `uv * tiling`.
    pub tiling: f32,
}

impl Material {
    /// A material with the patch tiled once per unit of uv.
    pub fn new(btf: impl Into<BtfRepresentation>) -> Self {
        Self { btf: btf.into(), tiling: 1.0 }
    }
}

/// Everything a shader needs besides `L*` and the camera (module docs).
#[derive(Debug)]
pub struct ShadeScene {
    mesh: Mesh,
    frames: Vec<VertexFrame>,
    materials: Vec<Material>,
    triangle_materials: Option<Vec<u32>>,
    local_basis: LocalBasis,
    /// The CPU shaders' BVH over the mesh in world space, built on first use (the GPU shader
    /// never needs it) and shared by every scene of the same mesh ([`Self::with_materials`]).
    bvh: Arc<OnceLock<SceneBvh>>,
}

impl Clone for ShadeScene {
    fn clone(&self) -> Self {
        Self {
            mesh: self.mesh.clone(),
            frames: self.frames.clone(),
            materials: self.materials.clone(),
            triangle_materials: self.triangle_materials.clone(),
            local_basis: self.local_basis,
            bvh: Arc::clone(&self.bvh),
        }
    }
}

impl ShadeScene {
    /// Check that the parts fit together and build the scene. `frames` has one frame per
    /// vertex (see [`crate::geometry::vertex_frames`]); all `materials` share one local basis
    /// (the rows of `T` are per vertex, not per material, so `L*` has one set of
    /// coefficients); `triangle_materials` indexes `materials` per triangle and may be `None`
    /// only with one material. Errors name the first part that does not fit.
    pub fn new(
        mesh: Mesh,
        frames: Vec<VertexFrame>,
        materials: Vec<Material>,
        triangle_materials: Option<Vec<u32>>,
    ) -> Result<Self> {
        let n = mesh.vertex_count();
        let bad = |m: String| Err(CoreError::Invalid(m));
        if frames.len() != n {
            return bad(format!("{} vertex frames for {n} vertices", frames.len()));
        }
        if let Some(v) = mesh.positions.iter().position(|p| !p.is_finite()) {
            return bad(format!("vertex {v}'s position is not finite: {:?}", mesh.positions[v]));
        }
        if let Some(v) = frames.iter().position(|f| !(f.normal.is_finite() && f.tangent.is_finite())) {
            return bad(format!("vertex {v}'s frame is not finite: {:?}", frames[v]));
        }
        if let Some(uvs) = &mesh.uvs {
            if uvs.len() != n {
                return bad(format!("{} UVs for {n} vertices", uvs.len()));
            }
            if let Some(v) = uvs.iter().position(|uv| !uv.is_finite()) {
                return bad(format!("vertex {v}'s uv is not finite"));
            }
        }
        if let Some(t) = mesh.triangles.iter().position(|t| t.iter().any(|&i| i as usize >= n)) {
            return bad(format!("triangle {t} indexes a vertex out of range (n = {n})"));
        }
        let local_basis = check_materials(mesh.triangles.len(), &materials, triangle_materials.as_deref())?;
        Ok(Self { mesh, frames, materials, triangle_materials, local_basis, bvh: Arc::default() })
    }

    /// The same mesh, frames and per-triangle material ids with other `materials` (one per
    /// material of this scene, checked as [`Self::new`] checks them), sharing this scene's BVH:
    /// the BTF study and the SH method shade one mesh with many material sets.
    pub fn with_materials(&self, materials: Vec<Material>) -> Result<Self> {
        if materials.len() != self.materials.len() {
            return Err(CoreError::Invalid(format!(
                "{} materials for a scene of {}",
                materials.len(),
                self.materials.len()
            )));
        }
        let local_basis = check_materials(self.mesh.triangles.len(), &materials, self.triangle_materials.as_deref())?;
        Ok(Self {
            mesh: self.mesh.clone(),
            frames: self.frames.clone(),
            materials,
            triangle_materials: self.triangle_materials.clone(),
            local_basis,
            bvh: Arc::clone(&self.bvh),
        })
    }

    pub fn mesh(&self) -> &Mesh {
        &self.mesh
    }

    /// One frame per vertex.
    pub fn frames(&self) -> &[VertexFrame] {
        &self.frames
    }

    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// Index into [`Self::materials`] per triangle; `None` for a one-material scene (no id
    /// buffer on the GPU).
    pub fn triangle_materials(&self) -> Option<&[u32]> {
        self.triangle_materials.as_deref()
    }

    /// The basis of the `L*` the scene is shaded with: every material's light directions.
    pub fn local_basis(&self) -> LocalBasis {
        self.local_basis
    }

    /// The material of triangle `t`.
    pub fn material(&self, triangle: u32) -> &Material {
        &self.materials[self.material_index(triangle)]
    }

    /// The index into [`Self::materials`] of triangle `t`'s material.
    pub fn material_index(&self, triangle: u32) -> usize {
        self.triangle_materials.as_ref().map_or(0, |ids| ids[triangle as usize] as usize)
    }

    /// The BVH over the mesh in world space (built on first use).
    pub fn bvh(&self) -> &SceneBvh {
        self.bvh.get_or_init(|| SceneBvh::build(&self.mesh.positions, &self.mesh.triangles))
    }

    /// An error unless `L*` of `vertices` vertices in `basis` fits this scene
    /// ([`check_lstar_shape`]).
    pub fn check_lstar_shape(&self, basis: LocalBasis, vertices: usize) -> Result<()> {
        check_lstar_shape(self.local_basis, self.mesh.vertex_count(), basis, vertices)
    }

    /// [`Self::check_lstar_shape`] for `L*` in hand, and every value finite.
    pub fn check_lstar(&self, lstar: &LocalRadiance) -> Result<()> {
        self.check_lstar_shape(lstar.basis(), lstar.vertices())?;
        let m = lstar.local_dirs();
        if let Some(i) = lstar.values().iter().position(|v| !v.iter().all(|x| x.is_finite())) {
            return Err(CoreError::Invalid(format!("L* is not finite at vertex {} coefficient {}", i / m, i % m)));
        }
        Ok(())
    }
}

/// The one check that `L*` fits a scene: `L*` of `vertices` vertices in `basis` can be shaded
/// with BTFs whose light directions are `scene_basis` on a mesh of `scene_vertices` vertices
/// only when the bases are the same (`T`'s local basis is the BTFs' light basis) and there is
/// one block per vertex. Shaders that keep only the scene's shape (the GPU's) call it directly.
pub fn check_lstar_shape(
    scene_basis: LocalBasis,
    scene_vertices: usize,
    basis: LocalBasis,
    vertices: usize,
) -> Result<()> {
    if basis != scene_basis || vertices != scene_vertices {
        return Err(CoreError::Invalid(format!(
            "L* has {vertices} vertices of {basis}; the mesh has {scene_vertices} vertices and its BTFs' light directions are {scene_basis}"
        )));
    }
    Ok(())
}

/// The checks of [`ShadeScene::new`] on the materials and per-triangle ids of a mesh of
/// `triangles` triangles; returns the materials' shared local basis.
fn check_materials(triangles: usize, materials: &[Material], triangle_materials: Option<&[u32]>) -> Result<LocalBasis> {
    let bad = |m: String| Err(CoreError::Invalid(m));
    let Some(first) = materials.first() else {
        return bad("the scene has no material".into());
    };
    let local_basis = first.btf.local_basis();
    for (i, m) in materials.iter().enumerate() {
        if m.btf.local_basis() != local_basis {
            return bad(format!(
                "material {i} ({}) has light directions in {}, material 0 ({}) in {local_basis}: all must share the local basis",
                m.btf.name(),
                m.btf.local_basis(),
                first.btf.name(),
            ));
        }
        if !(m.tiling.is_finite() && m.tiling > 0.0) {
            return bad(format!("material {i} ({}) has tiling {}, must be finite and > 0", m.btf.name(), m.tiling));
        }
    }
    match triangle_materials {
        None if materials.len() > 1 => {
            return bad(format!("{} materials but no per-triangle material ids", materials.len()));
        }
        Some(ids) if ids.len() != triangles => {
            return bad(format!("{} material ids for {triangles} triangles", ids.len()));
        }
        Some(ids) => {
            if let Some(t) = ids.iter().position(|&i| i as usize >= materials.len()) {
                return bad(format!("triangle {t} uses material {} of {}", ids[t], materials.len()));
            }
        }
        None => {}
    }
    Ok(local_basis)
}
