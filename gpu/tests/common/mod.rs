//! What the viewer's end-to-end tests share (`viewer.rs`, `viewer_moments.rs`: one window per
//! process, winit allows one event loop): the display check, a small scene and the comparison
//! of the captured window with the same frame drawn offscreen.

use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::{bins, cubemap, random_transfer};
use biscale_core::compress::{CompressContext, CompressedForm, Compressor};
use biscale_core::geometry::{shapes, VertexFrame};
use biscale_core::sampling::EnvMap;
use biscale_core::scene::{Btf, Camera, Material, ShadeScene};
use biscale_gpu::viewer::{ViewerForm, ViewerSetup};
use biscale_gpu::{GpuContext, Rgba8Image};
use glam::Vec3;

/// A context when there is a display and an adapter; `None` (with the reason printed) when
/// not, which fails the test with `BISCALE_REQUIRE_DISPLAY=1`.
pub fn display_and_adapter() -> Option<GpuContext> {
    let required = std::env::var("BISCALE_REQUIRE_DISPLAY").is_ok_and(|v| v == "1");
    if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
        assert!(!required, "BISCALE_REQUIRE_DISPLAY=1 but neither DISPLAY nor WAYLAND_DISPLAY is set");
        eprintln!("SKIPPING viewer test: no display (run under xvfb-run)");
        return None;
    }
    match GpuContext::new() {
        Ok(c) => Some(c),
        Err(e) => {
            assert!(!required, "BISCALE_REQUIRE_DISPLAY=1 but {e}");
            eprintln!("SKIPPING viewer test: {e}");
            None
        }
    }
}

/// A Phong plane under a smooth sky, T random (cubemap 4, 4x4 local bins), one sparse form:
/// the viewer's setup (rotation 0.7, exposure -2, background on, no screenshot) and its form.
pub fn plane_setup(light_moments: bool) -> (ViewerSetup, CompressedForm) {
    let mut mesh = shapes::grid_plane(8, 2.0);
    mesh.uvs = None;
    let nv = mesh.positions.len();
    let frame = VertexFrame::from_normal_tangent(Vec3::Y, Vec3::X);
    let btf = Btf::phong([0.6, 0.5, 0.4], [0.3, 0.3, 0.3], 16.0, bins(4), 4).unwrap();
    let scene = ShadeScene::new(mesh, vec![frame; nv], vec![Material::new(btf)], None).unwrap();
    let t = random_transfer(nv, 4, 4, 0.3, 5);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let (ew, eh) = (64, 32);
    let mut env = EnvMap::constant(ew, eh, [0.0; 3]);
    for y in 0..eh {
        for x in 0..ew {
            env.pixels[y * ew + x] = [0.2 + 0.6 * x as f32 / ew as f32, 0.2 + 0.6 * y as f32 / eh as f32, 0.5];
        }
    }
    let camera = Camera {
        position: Vec3::new(0.3, 0.8, 2.2),
        target: Vec3::new(0.0, 0.0, 0.0),
        up: Vec3::Y,
        fov_y_degrees: 50.0,
        width: 320,
        height: 280,
        samples_per_pixel: 1,
    };
    let setup = ViewerSetup {
        title: "viewer test".into(),
        scene,
        forms: vec![ViewerForm { label: "sparse".into(), form: form.clone(), kernels: Sparse.kernels(&form).unwrap() }],
        initial_form: 0,
        env,
        light_basis: cubemap(4),
        env_rotation: 0.7,
        sun_boost: None,
        camera,
        exposure: -2.0,
        background: true,
        screenshot: None,
        continuous: false,
        light_moments,
        moments_resolve: biscale_shading::runtime::MomentsResolve::Vertex,
        analytic: vec![],
    };
    (setup, form)
}

/// The captured window `shot` shows the offscreen frame `want` (of the camera's size `w x h`)
/// below the text overlay, and the overlay's white text. Returns false (with the reason
/// printed) when the window did not get the size it asked for, so nothing could be compared.
pub fn assert_shows(shot: &image::RgbImage, want: &Rgba8Image, (w, h): (u32, u32)) -> bool {
    // Without a window manager the window gets the size it asked for; elsewhere it may not,
    // and then only the capture itself is checked.
    assert!(shot.width() > 0 && shot.height() > 0);
    if (shot.width(), shot.height()) != (w, h) {
        eprintln!("window is {}x{}, not {w}x{h}: skipping the pixel comparison", shot.width(), shot.height());
        return false;
    }
    // The text overlay is in the top-left corner: its box darkens, its glyphs are white.
    let white =
        (0..40).flat_map(|y| (0..w).map(move |x| (x, y))).filter(|&(x, y)| shot.get_pixel(x, y).0 == [255; 3]).count();
    assert!(white > 30, "{white} white text pixels in the overlay");
    // Below the overlay (7 lines of 15 px text start at y = 8; the box ends above y = 150),
    // the window shows the offscreen frame. The viewer's orbit camera reproduces the position
    // to ~1e-6 (f32 through f64 trigonometry), which can move a triangle edge or a lat-long
    // pixel boundary across a pixel centre, so we allow a few differing pixels; all others
    // agree within one 8-bit level (sRGB conversion rounding).
    let (compared, off) = differing(|x, y| shot.get_pixel(x, y).0, want, (w, h), 1);
    assert!(off * 100 <= compared, "{off} of {compared} pixels differ from the offscreen frame");
    // And the frame is not flat: the shaded plane and the sky gradient give many colours.
    let distinct: std::collections::BTreeSet<[u8; 3]> =
        (160..h).flat_map(|y| (0..w).map(move |x| (x, y))).map(|(x, y)| shot.get_pixel(x, y).0).collect();
    assert!(distinct.len() > 50, "only {} distinct colours below the overlay", distinct.len());
    true
}

/// (pixels compared, pixels whose largest channel difference exceeds `levels`) of `got`
/// against `want` below the overlay (rows 160 and down).
pub fn differing(
    got: impl Fn(u32, u32) -> [u8; 3],
    want: &Rgba8Image,
    (w, h): (u32, u32),
    levels: u8,
) -> (usize, usize) {
    let (mut compared, mut off) = (0, 0);
    for y in 160..h {
        for x in 0..w {
            let i = ((y * w + x) * 4) as usize;
            let g = got(x, y);
            let diff = (0..3).map(|k| g[k].abs_diff(want.pixels[i + k])).max().unwrap();
            compared += 1;
            off += usize::from(diff > levels);
        }
    }
    (compared, off)
}
