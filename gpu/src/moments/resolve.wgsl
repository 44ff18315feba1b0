// The light-moments resolve on the GPU: `biscale_core::gather::moments::resolve` in f32.
//
// One invocation per vertex. For every bin j of the vertex, the three gathered moments give
// the world vectors D_c (channel c); the bin's exact-cosine power is p_c = n . D_c, its mean
// direction the luminance's D = sum_c Y_c D_c. The power goes to the (up to) four bins around
// D with the bilinear weights of `biscale_core::scene::btf::light_weights` (the inverse
// Shirley-Chiu map of `HemisphereGrid::continuous_coords`), accumulated straight into the
// vertex's own rows of `resolved` (no other invocation touches them, so any grid size works
// without a private array), and every bin is finally divided by its mean cosine. Where each
// bin's light goes, special cases included, is `spread` (`bins.wgsl`, prepended by the host),
// which the shader's per-pixel resolves share.

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
        let s = spread(moment(row, 0u), moment(row, 1u), moment(row, 2u), tangent, bitangent, normal, j, m, params.lobe);
        for (var k = 0u; k < s.count; k++) {
            accumulate(base + s.bins[k], s.weights[k] * s.power);
        }
    }
    for (var i = 0u; i < bins; i++) {
        let k = 3u * (base + i);
        let s = inv_mean_cosine[i];
        resolved[k] *= s;
        resolved[k + 1u] *= s;
        resolved[k + 2u] *= s;
    }
}
