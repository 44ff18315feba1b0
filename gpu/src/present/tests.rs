//! The tone-mapping pass against the CPU tone map of the report (`HdrImage::to_srgb8`) and
//! the CPU background (`EnvMap::radiance` through `Camera::ray`).

use super::{Rgba8Image, ToneMap, ToneMapSettings};
use crate::tests::gpu_or_skip;
use crate::{GpuContext, GpuGather, GpuShader};
use biscale_compressors::sparse::Sparse;
use biscale_compressors::testing::{random_light, random_transfer};
use biscale_core::compress::{CompressContext, Compressor};
use biscale_core::sampling::EnvMap;
use biscale_core::scene::image::linear_to_srgb;
use biscale_core::scene::{Camera, Render};
use glam::Vec3;

const FORMATS: [wgpu::TextureFormat; 4] = [
    wgpu::TextureFormat::Rgba8Unorm,
    wgpu::TextureFormat::Rgba8UnormSrgb,
    wgpu::TextureFormat::Bgra8Unorm,
    wgpu::TextureFormat::Bgra8UnormSrgb,
];

/// A Lambertian plane ([-1, 1]^2 in XZ) seen at a grazing angle so the top of the image is
/// sky, with a random sparse T gathered on the GPU.
fn scene(ctx: &GpuContext, cam: Camera) -> (GpuShader, GpuGather) {
    let (scene, nv) = crate::tests::phong_plane();
    let shader = GpuShader::new(ctx, &scene, &cam).unwrap();
    let t = random_transfer(nv, 4, 4, 0.3, 5);
    let form = Sparse.compress(&t, &CompressContext::default()).unwrap();
    let mut gather = GpuGather::new(ctx, &form, &Sparse.kernels(&form).unwrap()).unwrap();
    gather.gather(&random_light(4, 6)).unwrap();
    (shader, gather)
}

fn camera(w: u32, h: u32) -> Camera {
    Camera {
        position: Vec3::new(0.3, 0.6, 2.2),
        target: Vec3::new(0.0, 0.2, 0.0),
        up: Vec3::Y,
        fov_y_degrees: 55.0,
        width: w,
        height: h,
        samples_per_pixel: 1,
    }
}

/// Exposures (stops) that map the brightest covered pixel to 4 (many clip), 0.9, 0.3, 0.05
/// and 0.004 (the linear toe of the sRGB curve): the random scene has a small dynamic range,
/// so several exposures are needed to compare the whole curve.
fn exposures_for(img: &Render) -> Vec<f32> {
    let max = img.image.pixels.iter().flat_map(|p| p.iter().copied()).fold(0.0f32, f32::max);
    assert!(max > 0.0, "the test scene must be lit");
    [4.0f32, 0.9, 0.3, 0.05, 0.004].iter().map(|t| (t / max).log2()).collect()
}

fn px(img: &Rgba8Image, i: usize) -> [u8; 3] {
    [img.pixels[4 * i], img.pixels[4 * i + 1], img.pixels[4 * i + 2]]
}

#[test]
fn tone_map_matches_the_cpu_tone_map_on_every_format() {
    // Covered pixels: the GPU's tone map of the same HDR image must equal to_srgb8 within one
    // 8-bit level: both compute clamp(v 2^e) and the sRGB curve in f32 (pow may differ by a few
    // ulp), then round to 8 bits (the CPU adds 0.5 and truncates, the GPU's unorm / sRGB
    // conversion rounds to nearest with an allowed error of 0.6 levels), so values within
    // rounding distance of a level boundary may land on either side.
    let ctx = gpu_or_skip!();
    let (w, h) = (48, 36);
    let (mut shader, gather) = scene(ctx, camera(w, h));
    let hdr = shader.shade(&gather).unwrap();
    let covered = hdr.mask.iter().filter(|&&c| c).count();
    assert!(covered > (w * h / 8) as usize && covered < (w * h) as usize, "{covered} covered pixels");
    for format in FORMATS {
        let tm = ToneMap::new(ctx, format).unwrap();
        let (mut mid, mut clipped, mut toe) = (0, 0, 0);
        for exposure in exposures_for(&hdr) {
            let cpu = hdr.image.to_srgb8(exposure);
            let settings = ToneMapSettings { exposure, env_rotation: 0.0, background: true };
            let gpu = tm.render_rgba8(&mut shader, &gather, &settings).unwrap();
            assert_eq!((gpu.width, gpu.height), (w, h));
            for i in 0..(w * h) as usize {
                let g = px(&gpu, i);
                if !hdr.mask[i] {
                    // No environment set: black background.
                    assert_eq!(g, [0, 0, 0], "{format:?} background pixel {i}");
                    continue;
                }
                let c = &cpu.as_raw()[3 * i..3 * i + 3];
                for k in 0..3 {
                    assert!(
                        g[k].abs_diff(c[k]) <= 1,
                        "{format:?} exposure {exposure}: pixel {i} channel {k}: gpu {} cpu {}",
                        g[k],
                        c[k]
                    );
                    mid += usize::from(c[k] > 20 && c[k] < 235);
                    clipped += usize::from(c[k] == 255);
                    toe += usize::from(c[k] > 0 && c[k] <= 10);
                }
            }
        }
        // The comparison covers the curve, its linear toe and the clipping, not just black.
        assert!(
            mid > 300 && clipped > 100 && toe > 30,
            "{format:?}: {mid} mid-range, {clipped} clipped, {toe} toe values"
        );
    }
}

#[test]
fn background_is_the_rotated_environment_seen_through_the_pixel() {
    // A map with a gradient in u and v (and a jump at the u = 0 seam, which the bilinear
    // lookup must wrap across). The lookup is continuous, so the GPU's f32 directions (about
    // 1e-6 off the CPU's f64 ones) move a value by far less than an 8-bit level; what remains
    // is the sRGB / 8-bit rounding of the first test: one level.
    let ctx = gpu_or_skip!();
    let (w, h) = (64, 48);
    let cam = camera(w, h);
    let (mut shader, gather) = scene(ctx, cam);
    let hdr = shader.shade(&gather).unwrap();
    let (ew, eh) = (64, 32);
    let mut env = EnvMap::constant(ew, eh, [0.0; 3]);
    for y in 0..eh {
        for x in 0..ew {
            env.pixels[y * ew + x] = [0.2 + 0.6 * x as f32 / ew as f32, 0.2 + 0.6 * y as f32 / eh as f32, 0.5];
        }
    }
    let cpu_cam = Camera {
        position: cam.position,
        target: cam.target,
        up: cam.up,
        fov_y_degrees: cam.fov_y_degrees,
        width: w,
        height: h,
        samples_per_pixel: 1,
    };
    for rotation in [0.0f32, 1.3, -2.9] {
        let mut tm = ToneMap::new(ctx, wgpu::TextureFormat::Rgba8UnormSrgb).unwrap();
        tm.set_environment(Some(&env)).unwrap();
        let settings = ToneMapSettings { exposure: 0.0, env_rotation: rotation, background: true };
        let gpu = tm.render_rgba8(&mut shader, &gather, &settings).unwrap();
        let mut sky = 0;
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                if hdr.mask[i] {
                    continue;
                }
                sky += 1;
                let (_, d) = cpu_cam.ray(x as f32 + 0.5, y as f32 + 0.5);
                let want =
                    env.radiance(d, rotation as f64).map(|v| (linear_to_srgb(v.clamp(0.0, 1.0)) * 255.0 + 0.5) as u8);
                let got = px(&gpu, i);
                let diff = (0..3).map(|k| got[k].abs_diff(want[k])).max().unwrap();
                assert!(diff <= 1, "rotation {rotation}: pixel ({x}, {y}) gpu {got:?} cpu {want:?}");
            }
        }
        assert!(sky > (w * h / 8) as usize, "only {sky} sky pixels");
        // Without the background flag the sky is black.
        let settings = ToneMapSettings { background: false, ..settings };
        let dark = tm.render_rgba8(&mut shader, &gather, &settings).unwrap();
        assert!((0..(w * h) as usize).filter(|&i| !hdr.mask[i]).all(|i| px(&dark, i) == [0, 0, 0]));
    }
}

#[test]
fn a_cube_map_background_is_drawn_as_the_cpu_looks_it_up() {
    // A smooth cube map goes to the GPU through its lat-long view (4F x 2F): one 8-bit level
    // from that view's CPU lookup, as for a lat-long map, and a few from the cube map's own
    // (the view's bilinear resampling of a smooth map).
    let ctx = gpu_or_skip!();
    let (w, h) = (64, 48);
    let cam = camera(w, h);
    let (mut shader, gather) = scene(ctx, cam);
    let hdr = shader.shade(&gather).unwrap();
    let f = 16;
    let cube = biscale_core::sampling::Cubemap::new(f as u32);
    let pixels = (0..cube.texel_count())
        .map(|k| {
            let d = cube.texel_direction(k);
            [0.4 + 0.3 * d.x, 0.4 + 0.3 * d.y, 0.4 + 0.3 * d.z]
        })
        .collect();
    let env = EnvMap { width: f, height: 6 * f, pixels, layout: biscale_core::sampling::EnvLayout::Cube };
    let view = env.latlong_view();
    let srgb8 = |c: [f32; 3]| c.map(|v| (linear_to_srgb(v.clamp(0.0, 1.0)) * 255.0 + 0.5) as u8);
    let mut tm = ToneMap::new(ctx, wgpu::TextureFormat::Rgba8UnormSrgb).unwrap();
    tm.set_environment(Some(&env)).unwrap();
    let sky: Vec<usize> = (0..(w * h) as usize).filter(|&i| !hdr.mask[i]).collect();
    assert!(sky.len() > (w * h / 8) as usize, "only {} sky pixels", sky.len());
    for rotation in [0.0f32, 0.9] {
        let settings = ToneMapSettings { exposure: 0.0, env_rotation: rotation, background: true };
        let gpu = tm.render_rgba8(&mut shader, &gather, &settings).unwrap();
        for &i in &sky {
            let (_, d) = cam.ray((i % w as usize) as f32 + 0.5, (i / w as usize) as f32 + 0.5);
            let got = px(&gpu, i);
            let levels = |want: [u8; 3]| (0..3).map(|k| got[k].abs_diff(want[k])).max().unwrap();
            let (via_view, direct) = (view.radiance(d, rotation as f64), env.radiance(d, rotation as f64));
            assert!(levels(srgb8(via_view)) <= 1, "rotation {rotation}: pixel {i} gpu {got:?} cpu {via_view:?}");
            assert!(levels(srgb8(direct)) <= 4, "rotation {rotation}: pixel {i} gpu {got:?} cube {direct:?}");
        }
    }
}

#[test]
fn bad_targets_and_settings_are_errors() {
    let ctx = gpu_or_skip!();
    assert!(ToneMap::new(ctx, wgpu::TextureFormat::Depth32Float).is_err());
    let (mut shader, gather) = scene(ctx, camera(8, 8));
    let tm = ToneMap::new(ctx, wgpu::TextureFormat::Rgba16Float).unwrap();
    // Rendering to a float target works, but it cannot be read back as RGBA8.
    assert!(tm.render_rgba8(&mut shader, &gather, &ToneMapSettings::default()).is_err());
    let tm = ToneMap::new(ctx, wgpu::TextureFormat::Rgba8Unorm).unwrap();
    let nan = ToneMapSettings { exposure: f32::NAN, ..Default::default() };
    assert!(tm.render_rgba8(&mut shader, &gather, &nan).is_err());
    let mut tm = tm;
    let broken = EnvMap { width: 4, height: 2, pixels: vec![[0.0; 3]; 3], layout: Default::default() };
    assert!(tm.set_environment(Some(&broken)).is_err());
}
