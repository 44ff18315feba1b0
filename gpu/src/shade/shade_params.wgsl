// Shared by shade/shade.wgsl and present/present.wgsl, which are compiled with this file
// prepended (biscale-gpu, shade/shade_params.wgsl).
//
// Mirror of the Rust `ShadeParams` (#[repr(C)], 160 bytes; checked by the layout test).
// Each vec3 is followed by a scalar so WGSL's 16-byte vec3 alignment adds no hidden padding.
struct ShadeParams {
    // World to clip, reversed Z (depth 1 at the near plane), for rasterization only.
    view_proj: mat4x4<f32>,
    // Pixel rays exactly as biscale_core::scene::Camera::ray builds them:
    // dir = normalize(forward + right * (2 px / w - 1) + up * (1 - 2 py / h)), with `right`
    // and `up` already scaled by tan(fov_y / 2) * aspect and tan(fov_y / 2).
    cam_right: vec3<f32>,
    width: u32,
    cam_up: vec3<f32>,
    height: u32,
    cam_forward: vec3<f32>,
    local_dirs: u32,
    camera_pos: vec3<f32>,
    pad_camera: u32,
    material_count: u32,
    // 1: material_ids holds one id per triangle; 0: a placeholder, every triangle uses material 0.
    has_material_ids: u32,
    vertex_count: u32,
    triangle_count: u32,
    // LPCA BTFs use at most this many (leading) components per cluster; 0xffffffff: all.
    max_components: u32,
    // The per-pixel resolve the moments pass runs (RESOLVE_*; the L* pass ignores it).
    resolve: u32,
    // The local grid's side m (M = m * m bins), 0 without bins.
    moment_grid: u32,
    // The moments' lobe: 0 the mean direction, 1 the bin centre.
    lobe: u32,
}
