//! The viewer with light moments end to end (cargo feature `viewer`; `viewer.rs` without
//! them): the window, opened with `light_moments`, shows the frame drawn offscreen from the
//! rotated light's moments gathered and resolved on the GPU ([`GpuMoments`]), which differs
//! from the plain `L*` frame (so a viewer that ignored the option would fail). Needs a
//! display, as `viewer.rs`:
//!
//! ```text
//! xvfb-run -s "-screen 0 1024x768x24" cargo test -p biscale-gpu --features viewer --test viewer_moments
//! ```
#![cfg(feature = "viewer")]

mod common;

use biscale_compressors::sparse::Sparse;
use biscale_core::basis::LightBasis;
use biscale_core::compress::Compressor;
use biscale_core::gather::moments::LightMoments;
use biscale_core::sampling::{Cubemap, LightVector};
use biscale_gpu::viewer::{run_viewer, Screenshot};
use biscale_gpu::{GpuGather, GpuMoments, GpuShader, ToneMap, ToneMapSettings};

#[test]
fn window_shows_the_frame_of_the_resolved_light_moments() {
    let Some(ctx) = common::display_and_adapter() else { return };
    let (setup, form) = common::plane_setup(true);
    // Light moments need texels and bins: an SH light basis is refused before any window opens.
    let mut bad = setup.clone();
    bad.light_basis = LightBasis::sh(2).unwrap();
    let e = run_viewer(bad).unwrap_err();
    assert!(e.to_string().contains("cubemap"), "{e}");

    let dir = std::env::temp_dir().join(format!("biscale-viewer-moments-test-{}", std::process::id()));
    let path = dir.join("shot.png");
    let mut shot_setup = setup.clone();
    shot_setup.screenshot = Some(Screenshot { path: path.clone(), frames: 3 });
    run_viewer(shot_setup).unwrap();
    let shot = image::open(&path).unwrap().to_rgb8();
    if std::env::var_os("BISCALE_KEEP_SHOT").is_none() {
        std::fs::remove_dir_all(&dir).ok();
    }

    // The same frame offscreen from the moments of the same light, and the plain frame.
    let camera = setup.camera;
    let size = (camera.width, camera.height);
    let light = LightVector::from_env(&setup.env, Cubemap::new(4), setup.env_rotation);
    let kernels = Sparse.kernels(&form).unwrap();
    let mut shader = GpuShader::new(&ctx, &setup.scene, &camera).unwrap();
    let mut moments = GpuMoments::new(GpuGather::new(&ctx, &form, &kernels).unwrap(), setup.scene.frames()).unwrap();
    moments.gather(&LightMoments::new(&light).unwrap()).unwrap();
    let mut gather = GpuGather::new(&ctx, &form, &kernels).unwrap();
    gather.gather(&light).unwrap();
    let mut tm = ToneMap::new(&ctx, wgpu::TextureFormat::Rgba8UnormSrgb).unwrap();
    tm.set_environment(Some(&setup.env)).unwrap();
    let settings =
        ToneMapSettings { exposure: setup.exposure, env_rotation: setup.env_rotation as f32, background: true };
    let want = tm.render_rgba8(&mut shader, &moments, &settings).unwrap();
    let plain = tm.render_rgba8(&mut shader, &gather, &settings).unwrap();
    let (compared, off) = common::differing(
        |x, y| std::array::from_fn(|k| plain.pixels[((y * size.0 + x) * 4) as usize + k]),
        &want,
        size,
        1,
    );
    assert!(off * 10 > compared, "light moments change only {off} of {compared} pixels: the comparison could not tell");
    common::assert_shows(&shot, &want, size);
}
