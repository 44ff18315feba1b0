// Tone mapping of the shaded HDR image onto a display target (biscale-gpu, present/present.wgsl).
//
// One full-screen triangle. Every target pixel reads the HDR image's pixel under it (nearest,
// so a target of the image's size is a 1:1 copy), puts the environment behind uncovered
// pixels (alpha 0) when one is bound, then applies the tone map of
// biscale_core::scene::HdrImage::to_srgb8: value * 2^exposure, NaN to 0, clamped to [0, 1], and
// sRGB-encoded here unless the target format encodes itself (an *Srgb format).

// ShadeParams: see shade/shade_params.wgsl, prepended by the host.

// Mirror of the Rust `ToneParams` (32 bytes).
struct ToneParams {
    // 2^exposure.
    scale: f32,
    // Rotation of the environment about +Y, radians (EnvMap::radiance's `rotation`).
    env_rotation: f32,
    // 1: write sRGB-encoded values (UNORM target); 0: linear (the target format encodes).
    encode_srgb: u32,
    // 1: an environment is bound and drawn behind uncovered pixels.
    has_env: u32,
    target_width: f32,
    target_height: f32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> shade: ShadeParams;
@group(0) @binding(1) var<uniform> tone: ToneParams;
@group(0) @binding(2) var image: texture_2d<f32>;
@group(0) @binding(3) var env: texture_2d<f32>;

const PI: f32 = 3.14159265358979323846;

@vertex
fn present_vs(@builtin(vertex_index) vi: u32) -> @builtin(position) vec4<f32> {
    // (-1,-1), (3,-1), (-1,3): one triangle covering the viewport.
    let x = f32((vi << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(vi & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

// sRGB transfer function (IEC 61966-2-1), as shading::image::linear_to_srgb.
fn linear_to_srgb(x: f32) -> f32 {
    if x <= 0.0031308 {
        return 12.92 * x;
    }
    return 1.055 * pow(x, 1.0 / 2.4) - 0.055;
}

// EnvMap::radiance(d, rotation): rotate d by -rotation about +Y, take its lat-long
// coordinates (u = atan2(x, -z) / 2 pi, v = acos(y) / pi), then interpolate bilinearly between
// pixel centres, wrapping in u and clamping at the poles.
fn env_radiance(d_world: vec3<f32>) -> vec3<f32> {
    let a = -tone.env_rotation;
    let c = cos(a);
    let s = sin(a);
    let d = normalize(vec3<f32>(c * d_world.x + s * d_world.z, d_world.y, -s * d_world.x + c * d_world.z));
    var u = atan2(d.x, -d.z) / (2.0 * PI);
    if u < 0.0 {
        u += 1.0;
    }
    u = min(u, 1.0);
    let v = acos(clamp(d.y, -1.0, 1.0)) / PI;
    let dims = vec2<i32>(textureDimensions(env));
    let x = u * f32(dims.x) - 0.5;
    let y = clamp(v * f32(dims.y) - 0.5, 0.0, f32(dims.y - 1));
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let c0 = ((i32(x0) % dims.x) + dims.x) % dims.x;
    let c1 = (c0 + 1) % dims.x;
    let r0 = i32(y0);
    let r1 = min(r0 + 1, dims.y - 1);
    let p00 = textureLoad(env, vec2<i32>(c0, r0), 0).rgb;
    let p01 = textureLoad(env, vec2<i32>(c1, r0), 0).rgb;
    let p10 = textureLoad(env, vec2<i32>(c0, r1), 0).rgb;
    let p11 = textureLoad(env, vec2<i32>(c1, r1), 0).rgb;
    return (p00 * (1.0 - fx) + p01 * fx) * (1.0 - fy) + (p10 * (1.0 - fx) + p11 * fx) * fy;
}

@fragment
fn present_fs(@builtin(position) frag: vec4<f32>) -> @location(0) vec4<f32> {
    let dims = textureDimensions(image);
    let scaled = floor(frag.xy / vec2<f32>(tone.target_width, tone.target_height) * vec2<f32>(dims));
    let px = min(vec2<u32>(max(scaled, vec2<f32>(0.0))), dims - vec2<u32>(1u));
    let texel = textureLoad(image, px, 0);
    var rgb = texel.rgb;
    if texel.a < 0.5 && tone.has_env == 1u {
        // The pixel centre's primary ray, as shade_pixels (and shading::camera::Camera::ray).
        let sx = 2.0 * (f32(px.x) + 0.5) / f32(shade.width) - 1.0;
        let sy = 1.0 - 2.0 * (f32(px.y) + 0.5) / f32(shade.height);
        rgb = env_radiance(normalize(shade.cam_forward + shade.cam_right * sx + shade.cam_up * sy));
    }
    var out = vec3<f32>(0.0);
    for (var c = 0; c < 3; c++) {
        let v = rgb[c] * tone.scale;
        // NaN (v != v) becomes 0, as to_srgb8; +inf clamps to 1.
        var t = select(clamp(v, 0.0, 1.0), 0.0, v != v);
        if tone.encode_srgb == 1u {
            t = linear_to_srgb(t);
        }
        out[c] = t;
    }
    return vec4<f32>(out, 1.0);
}
