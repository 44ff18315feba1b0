//! Open the interactive viewer on the bundled bunny without the CLI (cargo feature `viewer`).
//!
//! The bunny (`assets/meshes/bunny.obj`) with its real transfer matrix (traced with
//! `transfer::build`; by default at cubemap 16, visibility 32, 8x8 local bins so it builds in
//! seconds; `--full` for the reference 32 / 64 / 8), compressed as sparse and Haar (12 terms)
//! (`--all` adds CPCA 32x8 and biclustering), a view-dependent Phong BTF, under
//! `assets/envmaps/blender_forest.exr` (or `--env PATH`). `--light-moments` gathers the light's
//! direction moments and resolves them on the GPU (`[runtime] light_moments` of a config).
//!
//! ```text
//! cargo run --release -p biscale-gpu --features viewer --example view_demo -- \
//!     [--full] [--all] [--width 800 --height 600] [--rotation 90] [--exposure 0] [--form 0]
//!     [--env PATH] [--no-background] [--continuous] [--light-moments]
//!     [--screenshot out.png --frames 5]
//! ```
//!
//! Headless: `xvfb-run -s "-screen 0 1024x768x24" cargo run ... -- --screenshot shot.png`
//! (runtime packages: `scripts/setup-viewer.sh`).

use biscale_compressors::bicluster::Bicluster;
use biscale_compressors::cpca::Cpca;
use biscale_compressors::haar::Haar;
use biscale_compressors::sparse::Sparse;
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::geometry::{vertex_frames, Mesh};
use biscale_core::sampling::EnvMap;
use biscale_core::scene::{Btf, Camera, Material, ShadeScene};
use biscale_core::transfer::{self, TransferSettings};
use biscale_gpu::viewer::{run_viewer, Screenshot, ViewerForm, ViewerSetup};
use std::path::{Path, PathBuf};
use std::time::Instant;

fn arg<T: std::str::FromStr>(name: &str) -> Option<T> {
    let args: Vec<String> = std::env::args().collect();
    let i = args.iter().position(|a| a == name)?;
    let v = args.get(i + 1).unwrap_or_else(|| panic!("{name} needs a value"));
    Some(v.parse().unwrap_or_else(|_| panic!("bad value for {name}: {v}")))
}

fn flag(name: &str) -> bool {
    std::env::args().any(|a| a == name)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let (width, height) = (arg("--width").unwrap_or(800u32), arg("--height").unwrap_or(600u32));
    let settings = if flag("--full") { TransferSettings::default() } else { TransferSettings::new(16, 32, 8)? };

    let mesh: Mesh = Mesh::load_obj(&root.join("assets/meshes/bunny.obj"))?.mesh;
    let (frames, _) = vertex_frames(&mesh);
    let build = transfer::build(&mesh, &settings, None)?;
    eprintln!("transfer: {build}");
    let t = build.matrix;
    let mut compressors: Vec<(String, Box<dyn Compressor>)> =
        vec![("sparse".into(), Box::new(Sparse)), ("haar_t12".into(), Box::new(Haar::with_terms(12)))];
    if flag("--all") {
        compressors.push(("cpca_c32_k8".into(), Box::new(Cpca::new(32, 8))));
        compressors.push(("bicluster".into(), Box::new(Bicluster::default())));
    }
    let mut forms = vec![];
    for (label, c) in &compressors {
        let start = Instant::now();
        let form = c.compress(&t, &CompressContext { seed: 1, progress: None, sweep: None })?;
        eprintln!("{label}: {:.2} MB in {:.1} s", form.bytes() as f64 / 1e6, start.elapsed().as_secs_f64());
        forms.push(ViewerForm { label: label.clone(), kernels: c.kernels(&form)?, form });
    }

    let btf = Btf::phong([0.55, 0.50, 0.45], [0.25, 0.25, 0.25], 24.0, t.local_basis(), 12)?;
    let env_path = arg::<PathBuf>("--env").unwrap_or_else(|| root.join("assets/envmaps/blender_forest.exr"));
    let (env, warnings) = EnvMap::load(&env_path)?;
    for w in warnings {
        eprintln!("warning: {w}");
    }
    let (mut min, mut max) = (glam::Vec3::splat(f32::INFINITY), glam::Vec3::splat(f32::NEG_INFINITY));
    for p in &mesh.positions {
        min = min.min(*p);
        max = max.max(*p);
    }
    let camera = Camera::frame_bounds(min, max, width, height, 25.0, 15.0, 30.0);
    let screenshot =
        arg::<PathBuf>("--screenshot").map(|path| Screenshot { path, frames: arg("--frames").unwrap_or(5) });
    let setup = ViewerSetup {
        title: "bunny (view_demo)".into(),
        scene: ShadeScene::new(mesh, frames, vec![Material::new(btf)], None)?,
        forms,
        initial_form: arg("--form").unwrap_or(0),
        env,
        light_basis: settings.light_basis(),
        env_rotation: arg::<f64>("--rotation").unwrap_or(90.0).to_radians(),
        sun_boost: None,
        camera,
        exposure: arg("--exposure").unwrap_or(0.0),
        background: !flag("--no-background"),
        screenshot,
        continuous: flag("--continuous"),
        light_moments: flag("--light-moments"),
        moments_resolve: biscale_shading::runtime::MomentsResolve::Vertex,
        analytic: vec![],
    };
    run_viewer(setup)?;
    Ok(())
}
