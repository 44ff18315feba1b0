//! The scene stage: the mesh and its visibility geometry, the light, the camera and the shade
//! scene (the mesh with its materials on `T`'s local basis).

use crate::error::Result;
use crate::experiment::config::Experiment;
use crate::stages::materials::{load_materials, SceneMaterials};
use crate::store::cache::StageCache;
use biscale_core::geometry::{Mesh, Placement};
use biscale_core::sampling::{EnvMap, LightVector};
use biscale_core::scene::{Background, Camera, ShadeScene};
use biscale_core::transfer::TransferScene;

/// The loaded mesh and the geometry every visibility query shares.
pub struct Geometry {
    pub mesh: Mesh,
    /// What the loader repaired, and vertices whose normal fell back (one line each).
    pub repairs: Vec<String>,
    pub transfer: TransferScene,
    /// How the mesh was moved and scaled from its file's coordinates
    /// ([`biscale_core::geometry::placement`]); config values in world units go through it.
    pub placement: Placement,
}

impl Geometry {
    /// The experiment's camera for this geometry at `downscale` ([`camera_placed`]).
    pub fn camera(&self, exp: &Experiment, downscale: u32) -> Camera {
        camera_placed(exp, &self.mesh, &self.placement, downscale)
    }
}

/// Load the mesh, condition its coordinates for f32 (one similarity for every stage) and
/// build its transfer scene (frames and the normalised BVH), once.
pub fn load_geometry(exp: &Experiment) -> Result<Geometry> {
    let mut load = Mesh::load(&exp.mesh_path)?;
    let placement = biscale_core::geometry::placement::condition(&mut load.mesh);
    if !placement.is_identity() {
        load.repairs.push(format!(
            "coordinates out of f32's comfortable range: the mesh (and any camera position or target) \
             is moved by -({:.3e}, {:.3e}, {:.3e}) and scaled by 2^{}; images and transfer are unchanged by this similarity",
            placement.centre.x,
            placement.centre.y,
            placement.centre.z,
            placement.scale.log2().round()
        ));
    }
    let transfer = TransferScene::new(&load.mesh)?;
    let mut repairs = load.repairs;
    if transfer.frame_fallbacks() > 0 {
        repairs
            .push(format!("{} vertices had no usable normal (cancelling faces); used +Y", transfer.frame_fallbacks()));
    }
    Ok(Geometry { mesh: load.mesh, repairs, transfer, placement })
}

/// The lighting: `L` and the map it came from (for backgrounds).
pub struct Lighting {
    pub light: LightVector,
    pub env: EnvMap,
    pub rotation: f64,
    pub warnings: Vec<String>,
}

impl Lighting {
    /// What a primary ray that misses the mesh sees (per `report.background`).
    pub fn background(&self, exp: &Experiment) -> Background<'_> {
        if exp.file.report.background {
            Background::Env { env: &self.env, rotation: self.rotation }
        } else {
            Background::Black
        }
    }
}

/// `L` in the experiment's light basis, from its env map or constant sky (and `sun_boost`).
pub fn load_lighting(exp: &Experiment) -> Result<Lighting> {
    let l = &exp.file.lighting;
    let rotation = l.rotation_degrees.to_radians();
    let (env, mut warnings) = match (&exp.env_path, l.constant) {
        (Some(p), _) => EnvMap::load(p)?,
        (None, Some(c)) => (EnvMap::constant(64, 32, c), vec![]),
        (None, None) => unreachable!("validated by the config"),
    };
    let (light, boosted) = light_of(exp, &env, rotation);
    if let (Some(k), Some(boost)) = (boosted, &l.sun_boost) {
        warnings.push(format!("sun_boost: texel {k} multiplied by {}", boost.get_ref()));
    }
    Ok(Lighting { light, env, rotation, warnings })
}

/// `L` of `env` turned `rotation` radians about +Y on the config's cubemap, with its
/// `sun_boost` (and the texel it multiplied): the run's light, and every frame of a turning
/// light ([`crate::stages::animation`]), made one way.
pub fn light_of(exp: &Experiment, env: &EnvMap, rotation: f64) -> (LightVector, Option<usize>) {
    let mut light = LightVector::from_env(env, exp.transfer_settings().cubemap(), rotation);
    if exp.file.lighting.texel_directions == biscale_core::sampling::TexelDirections::Centre {
        light = light.with_centre_directions();
    }
    let boosted = exp.file.lighting.sun_boost.as_ref().and_then(|b| light.boost_brightest(*b.get_ref()));
    (light, boosted)
}

/// The shade scene: the mesh, the transfer scene's frames and the materials, whose BTFs are
/// built on `local`, `T`'s local basis (synthesized ones cached when there is a cache).
pub fn shade_scene(
    exp: &Experiment,
    geometry: &Geometry,
    local: biscale_core::basis::LocalBasis,
    cache: Option<&StageCache>,
) -> Result<(ShadeScene, SceneMaterials)> {
    let materials = load_materials(exp, &geometry.mesh, local, cache)?;
    let scene = ShadeScene::new(
        geometry.mesh.clone(),
        geometry.transfer.frames().to_vec(),
        materials.materials.clone(),
        materials.triangle_materials.clone(),
    )?;
    Ok((scene, materials))
}

/// The camera of the experiment at `downscale`, for a mesh in its file's coordinates.
pub fn camera(exp: &Experiment, mesh: &Mesh, downscale: u32) -> Camera {
    camera_placed(exp, mesh, &Placement::IDENTITY, downscale)
}

/// The camera of the experiment at `downscale` for `mesh` placed by `placement`: the
/// config's position and target (file coordinates) go through the same similarity.
pub fn camera_placed(exp: &Experiment, mesh: &Mesh, placement: &Placement, downscale: u32) -> Camera {
    let rt = &exp.file.runtime;
    let (w, h) = ((rt.width.get_ref() / downscale).max(1), (rt.height.get_ref() / downscale).max(1));
    let c = &rt.camera;
    let (min, max) = mesh.bounds();
    let mut cam = Camera::frame_bounds(min, max, w, h, c.azimuth_degrees, c.elevation_degrees, c.fov_y_degrees);
    if let Some(p) = c.position {
        cam.position = placement.apply(p.into());
    }
    if let Some(t) = c.target {
        cam.target = placement.apply(t.into());
    }
    cam.samples_per_pixel = rt.samples_per_pixel();
    cam
}
