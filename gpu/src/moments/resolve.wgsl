// The light-moments resolve on the GPU: `biscale_core::gather::moments::resolve` in f32.
//
// One invocation per vertex. For every bin j of the vertex, the three gathered moments give
// the world vectors D_c (channel c); the bin's exact-cosine power is p_c = n . D_c, its mean
// direction the luminance's D = sum_c Y_c D_c. The power goes to the (up to) four bins around
// D with the bilinear weights of `biscale_core::scene::btf::light_weights` (the inverse
// Shirley-Chiu map of `HemisphereGrid::continuous_coords`), accumulated straight into the
// vertex's own rows of `resolved` (no other invocation touches them, so any grid size works
// without a private array), and every bin is finally divided by its mean cosine.
//
// The CPU's special cases, in the same order: a bin whose three powers are all 0 is skipped;
// the bin-centre lobe keeps each power in its own bin; a luminance direction that is exactly 0
// keeps the power in bin j; a local direction whose squared length is not positive goes to the
// pole (+Z, as `light_weights` does); a 1x1 grid puts everything in bin 0.

struct ResolveParams {
    vertices: u32,
    // The grid side m (bins per vertex m * m).
    grid: u32,
    // 0: the BRDF at the mean direction (Lobe::MeanDirection); 1: at the bin centre.
    lobe: u32,
    // Workgroups along x of the dispatch (the grid is folded into y past the x limit).
    groups_x: u32,
}

@group(0) @binding(0) var<uniform> params: ResolveParams;
// The three gathered moments L d_x, L d_y, L d_z: rows v * M + j, RGB interleaved (GpuGather's
// `L*` layout).
@group(0) @binding(1) var<storage, read> moment_x: array<f32>;
@group(0) @binding(2) var<storage, read> moment_y: array<f32>;
@group(0) @binding(3) var<storage, read> moment_z: array<f32>;
// Per vertex: tangent, bitangent, normal (9 f32), the frames T was traced with.
@group(0) @binding(4) var<storage, read> frames: array<f32>;
// 1 / cosbar_i per bin.
@group(0) @binding(5) var<storage, read> inv_mean_cosine: array<f32>;
// L*': rows v * M + i, RGB interleaved.
@group(0) @binding(6) var<storage, read_write> resolved: array<f32>;

// `biscale_core::gather::moments::LUMINANCE` (Rec. 709).
const LUMINANCE = vec3<f32>(0.2126, 0.7152, 0.0722);
const FOUR_OVER_PI: f32 = 1.2732395447351628;
const PI_OVER_4: f32 = 0.7853981633974483;
const TAN_PI_OVER_8: f32 = 0.41421356237309503;

// Channel c of row `row`'s three moments: the world vector D_c.
fn moment(row: u32, c: u32) -> vec3<f32> {
    let k = 3u * row + c;
    return vec3<f32>(moment_x[k], moment_y[k], moment_z[k]);
}

fn frame_vector(v: u32, which: u32) -> vec3<f32> {
    let k = 9u * v + 3u * which;
    return vec3<f32>(frames[k], frames[k + 1u], frames[k + 2u]);
}

fn accumulate(row: u32, p: vec3<f32>) {
    let k = 3u * row;
    resolved[k] += p.x;
    resolved[k + 1u] += p.y;
    resolved[k + 2u] += p.z;
}

// atan(t) for |t| <= 1: Cephes' atanf (one reduction about pi/4 and a degree-9 odd
// polynomial; peak relative error 1.9e-7 in IEEE f32), instead of the built-in `atan`, whose
// Vulkan precision is only 4096 ulp. The test `atan_unit_matches_f64` holds it to 4 ulp of 1.
fn atan_unit(t: f32) -> f32 {
    let a = abs(t);
    var x = a;
    var y = 0.0;
    if a > TAN_PI_OVER_8 {
        x = (a - 1.0) / (a + 1.0);
        y = PI_OVER_4;
    }
    let z = x * x;
    y += (((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z - 3.33329491539e-1) * z * x + x;
    return select(y, -y, t < 0.0);
}

// The concentric square point (a, b) in [-1, 1]^2 of the non-zero local direction d
// (`hemisphere_to_square` then `2 u - 1`): disk radius r = sqrt(1 - z) of the unit
// direction (1 below the horizon), angle that of (d.x, d.y). d is first scaled by a power of
// two (exact) so that its squares neither overflow nor underflow, and 1 - z is computed as
// (x^2 + y^2) / (|d| (|d| + z)), without the cancellation of 1 - z near the pole.
fn square_of(d: vec3<f32>) -> vec2<f32> {
    let big = max(max(abs(d.x), abs(d.y)), abs(d.z));
    let e = ldexp(d, vec3<i32>(-frexp(big).exp));
    let h2 = e.x * e.x + e.y * e.y;
    var r = 1.0;
    if e.z > 0.0 {
        let len = sqrt(h2 + e.z * e.z);
        r = min(sqrt(h2 / (len * (len + e.z))), 1.0);
    }
    if r == 0.0 || (e.x == 0.0 && e.y == 0.0) {
        return vec2<f32>(0.0);
    }
    if abs(e.x) >= abs(e.y) {
        let a = select(-r, r, e.x > 0.0);
        return vec2<f32>(a, a * atan_unit(e.y / e.x) * FOUR_OVER_PI);
    }
    let b = select(-r, r, e.y > 0.0);
    return vec2<f32>(b * atan_unit(e.x / e.y) * FOUR_OVER_PI, b);
}

// Square coordinate s in [-1, 1] to the continuous grid coordinate in [0, m - 1] (bin centres
// at integers), as `HemisphereGrid::continuous_coords`.
fn grid_coord(s: f32, m: f32) -> f32 {
    let u = clamp((s + 1.0) * 0.5, 0.0, 1.0);
    return clamp(u * m - 0.5, 0.0, m - 1.0);
}

@compute @workgroup_size(64)
fn resolve(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let v = (wid.y * params.groups_x + wid.x) * 64u + lid.x;
    if v >= params.vertices {
        return;
    }
    let m = params.grid;
    let bins = m * m;
    let base = v * bins;
    let tangent = frame_vector(v, 0u);
    let bitangent = frame_vector(v, 1u);
    let normal = frame_vector(v, 2u);
    for (var i = 0u; i < 3u * bins; i++) {
        resolved[3u * base + i] = 0.0;
    }
    for (var j = 0u; j < bins; j++) {
        let row = base + j;
        let d0 = moment(row, 0u);
        let d1 = moment(row, 1u);
        let d2 = moment(row, 2u);
        let p = vec3<f32>(dot(normal, d0), dot(normal, d1), dot(normal, d2));
        if all(p == vec3<f32>(0.0)) {
            continue;
        }
        if params.lobe == 1u {
            accumulate(row, p);
            continue;
        }
        let g = d0 * LUMINANCE.x + d1 * LUMINANCE.y + d2 * LUMINANCE.z;
        if all(g == vec3<f32>(0.0)) {
            accumulate(row, p);
            continue;
        }
        if m == 1u {
            accumulate(base, p);
            continue;
        }
        var local = vec3<f32>(dot(g, tangent), dot(g, bitangent), dot(g, normal));
        if !(dot(local, local) > 0.0) {
            local = vec3<f32>(0.0, 0.0, 1.0);
        }
        let sq = square_of(local);
        let x = grid_coord(sq.x, f32(m));
        let y = grid_coord(sq.y, f32(m));
        let x0 = min(u32(x), m - 2u);
        let y0 = min(u32(y), m - 2u);
        let fx = clamp(x - f32(x0), 0.0, 1.0);
        let fy = clamp(y - f32(y0), 0.0, 1.0);
        let at = base + y0 * m + x0;
        accumulate(at, ((1.0 - fx) * (1.0 - fy)) * p);
        accumulate(at + 1u, (fx * (1.0 - fy)) * p);
        accumulate(at + m, ((1.0 - fx) * fy) * p);
        accumulate(at + m + 1u, (fx * fy) * p);
    }
    for (var i = 0u; i < bins; i++) {
        let k = 3u * (base + i);
        let s = inv_mean_cosine[i];
        resolved[k] *= s;
        resolved[k + 1u] *= s;
        resolved[k + 2u] *= s;
    }
}
