// The bins of a hemisphere grid, located in f32 (biscale-gpu, moments/bins.wgsl): shared by
// the light-moments resolve (`resolve.wgsl`, per vertex) and the per-pixel resolves of the
// shader (`shade/moments.wgsl`), which are compiled with this file prepended. Pure functions,
// no bindings. `spread` is the one place that decides where a bin's light goes.

// `biscale_core::gather::moments::LUMINANCE` (Rec. 709).
const LUMINANCE = vec3<f32>(0.2126, 0.7152, 0.0722);
const FOUR_OVER_PI: f32 = 1.2732395447351628;
const PI_OVER_4: f32 = 0.7853981633974483;
const TAN_PI_OVER_8: f32 = 0.41421356237309503;

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

// The bilinear cell of a non-zero local direction in an m x m grid (m >= 2): the bin at its
// lower corner (`y0 * m + x0`) and the fractions towards its right and upper neighbours, the
// weights of `biscale_core::scene::btf::light_weights`.
struct Cell {
    corner: u32,
    fx: f32,
    fy: f32,
}

fn cell_of(local: vec3<f32>, m: u32) -> Cell {
    let sq = square_of(local);
    let x = grid_coord(sq.x, f32(m));
    let y = grid_coord(sq.y, f32(m));
    let x0 = min(u32(x), m - 2u);
    let y0 = min(u32(y), m - 2u);
    var c: Cell;
    c.corner = y0 * m + x0;
    c.fx = clamp(x - f32(x0), 0.0, 1.0);
    c.fy = clamp(y - f32(y0), 0.0, 1.0);
    return c;
}

// Where bin j of a vertex's three gathered moments sends its light, resolved at the frame
// (t, bt, n) of an m x m grid with lobe 0 (the mean direction) or 1 (the bin centre):
// `biscale_core::gather::moments::resolve` for one bin. `power` is its exact-cosine power
// n . D_c per channel; the first `count` of `bins` receive it with `weights` (which sum to 1).
// The CPU's special cases, in the same order: a bin whose three powers are all 0 sends
// nothing; the bin-centre lobe keeps the power in bin j; a luminance direction that is exactly
// 0 keeps it in bin j; a 1x1 grid puts it in bin 0; a local direction whose squared length is
// not positive goes to the pole (+Z, as `light_weights` does).
struct Spread {
    power: vec3<f32>,
    count: u32,
    bins: vec4<u32>,
    weights: vec4<f32>,
}

fn spread(d0: vec3<f32>, d1: vec3<f32>, d2: vec3<f32>, t: vec3<f32>, bt: vec3<f32>, n: vec3<f32>, j: u32, m: u32, lobe: u32) -> Spread {
    var s: Spread;
    s.power = vec3<f32>(dot(n, d0), dot(n, d1), dot(n, d2));
    s.count = 1u;
    s.bins = vec4<u32>(j, 0u, 0u, 0u);
    s.weights = vec4<f32>(1.0, 0.0, 0.0, 0.0);
    if all(s.power == vec3<f32>(0.0)) {
        s.count = 0u;
        return s;
    }
    if lobe == 1u {
        return s;
    }
    let g = d0 * LUMINANCE.x + d1 * LUMINANCE.y + d2 * LUMINANCE.z;
    if all(g == vec3<f32>(0.0)) {
        return s;
    }
    if m == 1u {
        s.bins.x = 0u;
        return s;
    }
    var local = vec3<f32>(dot(g, t), dot(g, bt), dot(g, n));
    if !(dot(local, local) > 0.0) {
        local = vec3<f32>(0.0, 0.0, 1.0);
    }
    let c = cell_of(local, m);
    s.count = 4u;
    s.bins = vec4<u32>(c.corner, c.corner + 1u, c.corner + m, c.corner + m + 1u);
    s.weights = vec4<f32>((1.0 - c.fx) * (1.0 - c.fy), c.fx * (1.0 - c.fy), (1.0 - c.fx) * c.fy, c.fx * c.fy);
    return s;
}
