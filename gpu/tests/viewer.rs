//! The viewer end to end (cargo feature `viewer`): open the window on a small scene, render a
//! few frames, capture the real surface texture, and compare it with the same frame drawn
//! offscreen through the public API. Needs a display: run it headless with
//!
//! ```text
//! xvfb-run -s "-screen 0 1024x768x24" cargo test -p biscale-gpu --features viewer --test viewer
//! ```
//!
//! Without DISPLAY / WAYLAND_DISPLAY (or without a GPU adapter) it prints why and passes,
//! unless `BISCALE_REQUIRE_DISPLAY=1`. One test only: winit allows one event loop per process
//! (`viewer_moments.rs` is the same with light moments, in its own process).
#![cfg(feature = "viewer")]

mod common;

use biscale_compressors::sparse::Sparse;
use biscale_core::compress::Compressor;
use biscale_core::sampling::LightVector;
use biscale_gpu::viewer::{run_viewer, Screenshot};
use biscale_gpu::{GpuGather, GpuShader, ToneMap, ToneMapSettings};

#[test]
fn window_shows_the_tone_mapped_frame() {
    let Some(ctx) = common::display_and_adapter() else { return };
    let (setup, form) = common::plane_setup(false);
    // Bad setups are refused before any window opens.
    let mut bad = setup.clone();
    bad.forms.clear();
    assert!(run_viewer(bad).is_err());

    let dir = std::env::temp_dir().join(format!("biscale-viewer-test-{}", std::process::id()));
    let path = dir.join("shot.png");
    let mut shot_setup = setup.clone();
    shot_setup.screenshot = Some(Screenshot { path: path.clone(), frames: 3 });
    run_viewer(shot_setup).unwrap();
    let shot = image::open(&path).unwrap().to_rgb8();
    if std::env::var_os("BISCALE_KEEP_SHOT").is_none() {
        std::fs::remove_dir_all(&dir).ok();
    }

    // The same frame offscreen: same camera, same light (LightVector::from_env at the same
    // rotation), same tone map.
    let camera = setup.camera;
    let mut shader = GpuShader::new(&ctx, &setup.scene, &camera).unwrap();
    let mut gather = GpuGather::new(&ctx, &form, &Sparse.kernels(&form).unwrap()).unwrap();
    let rotation = setup.env_rotation;
    gather.gather(&LightVector::from_env(&setup.env, biscale_core::sampling::Cubemap::new(4), rotation)).unwrap();
    let mut tm = ToneMap::new(&ctx, wgpu::TextureFormat::Rgba8UnormSrgb).unwrap();
    tm.set_environment(Some(&setup.env)).unwrap();
    let settings = ToneMapSettings { exposure: setup.exposure, env_rotation: rotation as f32, background: true };
    let want = tm.render_rgba8(&mut shader, &gather, &settings).unwrap();
    common::assert_shows(&shot, &want, (camera.width, camera.height));
}
