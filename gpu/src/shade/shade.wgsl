// Visibility-buffer bi-scale shading (biscale-gpu, shade/shade.wgsl).
//
// Pass 1 (`vis_vs` / `vis_fs`, a render pass with a depth test): every pixel stores the id
// (+1, 0 = background) of the nearest triangle covering its centre.
// Pass 2 (`shade_pixels`, compute, one invocation per pixel): intersects the pixel's ray with
// that triangle for exact perspective-correct barycentrics, interpolates the vertices' L*
// (M bins x RGB) and frames, finds the view direction in the local frame, and evaluates the
// meso-scale integral of Sun et al. (eq. 2):  B(x, e) = sum_j b(u, e, d_j) L*(x, d_j),
// with b bilinear between the 4 nearest view-grid samples.
//
// Materials: b is the BTF of the triangle's material (material_ids[tri], or material 0 when
// params.has_material_ids = 0 and that binding is a placeholder), looked up at the nearest
// texel of uv * tiling with its own view grid. A material's header says how its BTF is
// represented (biscale_core::scene::BtfRepresentation): a dense table, or local PCA (cluster
// means and eigen-BRDFs, per-unit weights, per-unit cluster ids). Both are evaluated through
// one interface: `btf_sample` resolves one view sample of a texel once per pixel, `btf_value`
// gives its value for light bin j. All floats live in the one `btf` buffer, the LPCA ids in
// `btf_ids`.

// ShadeParams: see shade_params.wgsl, prepended by the host.

// Mirror of the Rust `GpuMaterialHeader` (48 bytes; checked by the layout test).
struct MaterialHeader {
    // First float of this material's table (dense) or basis (LPCA) in `btf`.
    data_offset: u32,
    width: u32,
    height: u32,
    // View grid m, 0 for a view-independent BTF.
    view_m: u32,
    // Patch repetitions per unit of uv.
    tiling: f32,
    // 0: dense table, 1: local PCA.
    kind: u32,
    // LPCA: clusters K (an id >= K is an all-zero unit) and components C besides the mean.
    clusters: u32,
    components: u32,
    // LPCA: 1 when a unit is one (texel, view), 0 when it is a whole texel.
    per_view: u32,
    // LPCA: first float of the weights (C per unit) in `btf`, first id in `btf_ids`.
    weights_offset: u32,
    ids_offset: u32,
    pad0: u32,
}

// Mirror of the Rust `GpuVertex` (48 bytes).
struct Vertex {
    position: vec3<f32>,
    u: f32,
    normal: vec3<f32>,
    v: f32,
    tangent: vec3<f32>,
    pad: f32,
}

@group(0) @binding(0) var<uniform> params: ShadeParams;
@group(0) @binding(1) var<storage, read> vertices: array<Vertex>;
@group(0) @binding(2) var<storage, read> indices: array<u32>;
// L*: (vertex * M + j) * 3 + channel (the gather's output buffer).
@group(0) @binding(3) var<storage, read> lstar: array<f32>;
// All materials' BTF floats back to back. Dense: value at
// data_offset + ((texel * views + view) * M + j) * 3 + channel. LPCA: cluster k's vector c
// (0 = mean) at data_offset + (k * (C + 1) + c) * D, D = 3 M (per view) or 3 views M (per
// texel, view v's segment at v * 3 M); unit u's weights at weights_offset + u * C.
@group(0) @binding(4) var<storage, read> btf: array<f32>;
@group(0) @binding(5) var visibility: texture_2d<u32>;
@group(0) @binding(6) var image: texture_storage_2d<rgba32float, write>;
@group(0) @binding(7) var<storage, read> materials: array<MaterialHeader>;
// One material id per triangle (validated on the host), or a 4-byte placeholder.
@group(0) @binding(8) var<storage, read> material_ids: array<u32>;
// LPCA cluster ids of every compressed material back to back (unit u at ids_offset + u), or
// a 4-byte placeholder.
@group(0) @binding(9) var<storage, read> btf_ids: array<u32>;

// ---- pass 1: visibility ----

struct VisOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) @interpolate(flat) tri: u32,
}

@vertex
fn vis_vs(@builtin(vertex_index) vi: u32) -> VisOut {
    var out: VisOut;
    out.clip = params.view_proj * vec4<f32>(vertices[indices[vi]].position, 1.0);
    out.tri = vi / 3u + 1u;
    return out;
}

@fragment
fn vis_fs(in: VisOut) -> @location(0) u32 {
    return in.tri;
}

// ---- Shirley-Chiu concentric parameterization (exact port of core/src/sampling/hemisphere.rs) ----

const PI: f32 = 3.14159265358979323846;
const FRAC_PI_2: f32 = 1.57079632679489661923;
const FRAC_PI_4: f32 = 0.785398163397448309616;

// disk_to_square
fn disk_to_square(p: vec2<f32>) -> vec2<f32> {
    let r = length(p);
    if r == 0.0 {
        return vec2<f32>(0.5, 0.5);
    }
    var phi = atan2(p.y, p.x);
    if phi < -FRAC_PI_4 {
        phi += 2.0 * PI;
    }
    var a: f32;
    var b: f32;
    if phi < FRAC_PI_4 {
        a = r;
        b = phi / FRAC_PI_4 * r;
    } else if phi < 3.0 * FRAC_PI_4 {
        a = -(phi - FRAC_PI_2) / FRAC_PI_4 * r;
        b = r;
    } else if phi < 5.0 * FRAC_PI_4 {
        a = -r;
        b = -(phi - PI) / FRAC_PI_4 * r;
    } else {
        a = (phi - 3.0 * FRAC_PI_2) / FRAC_PI_4 * r;
        b = -r;
    }
    return clamp(vec2<f32>((a + 1.0) * 0.5, (b + 1.0) * 0.5), vec2<f32>(0.0), vec2<f32>(1.0));
}

// hemisphere_to_square
fn hemisphere_to_square(d: vec3<f32>) -> vec2<f32> {
    let z = clamp(d.z, 0.0, 1.0);
    let r = sqrt(1.0 - z);
    let xy = d.xy;
    let len = length(xy);
    if len == 0.0 {
        return vec2<f32>(0.5, 0.5);
    }
    return disk_to_square(xy * (r / len));
}

// HemisphereGrid::continuous_coords: (x, y) in [0, m-1]^2, integers at bin centres.
fn continuous_coords(m: u32, dir: vec3<f32>) -> vec2<f32> {
    var d = dir;
    if d.z < 1e-6 {
        d.z = 1e-6;
    }
    let uv = hemisphere_to_square(normalize(d));
    let mf = f32(m);
    return clamp(uv * mf - 0.5, vec2<f32>(0.0), vec2<f32>(mf - 1.0));
}

// VertexFrame::from_normal (Duff et al. 2017): tangent and bitangent around unit n.
// sign = copysign(1, n.z), so -0.0 counts as negative exactly as on the CPU.
fn duff_basis(n: vec3<f32>) -> array<vec3<f32>, 2> {
    let s = select(1.0, -1.0, (bitcast<u32>(n.z) & 0x80000000u) != 0u);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return array<vec3<f32>, 2>(
        vec3<f32>(1.0 + s * n.x * n.x * a, s * b, -s * n.x),
        vec3<f32>(b, s + n.y * n.y * a, -n.y),
    );
}

// Btf::texel_of: nearest texel, wrapping; row = floor(v * height).
fn wrap_texel(x: f32, n: u32) -> u32 {
    let i = floor(x * f32(n));
    let r = i - f32(n) * floor(i / f32(n));
    return min(u32(max(r, 0.0)), n - 1u);
}

fn lstar_at(vertex: u32, j: u32) -> vec3<f32> {
    let k = (vertex * params.local_dirs + j) * 3u;
    return vec3<f32>(lstar[k], lstar[k + 1u], lstar[k + 2u]);
}

// One view sample of one texel of a material, resolved once per pixel: where its values
// start (`base`, a float index), where its LPCA weights start, and its bilinear weight (0 for
// an all-zero LPCA unit).
struct BtfSample {
    base: u32,
    weights: u32,
    weight: f32,
}

fn btf_sample(mat: MaterialHeader, texel: u32, view: u32, views: u32, weight: f32) -> BtfSample {
    var s: BtfSample;
    s.weight = weight;
    let m3 = params.local_dirs * 3u;
    if mat.kind == 0u {
        s.base = mat.data_offset + (texel * views + view) * m3;
        s.weights = 0u;
        return s;
    }
    // LpcaBtf::unit_of: the unit holding (texel, view) and the segment of its vector.
    var unit = texel;
    var segment = view;
    var d = m3 * views;
    if mat.per_view != 0u {
        unit = texel * views + view;
        segment = 0u;
        d = m3;
    }
    let k = btf_ids[mat.ids_offset + unit];
    if k >= mat.clusters {
        s.weight = 0.0;
        s.base = mat.data_offset;
        s.weights = mat.weights_offset;
        return s;
    }
    s.base = mat.data_offset + k * (mat.components + 1u) * d + segment * m3;
    s.weights = mat.weights_offset + unit * mat.components;
    return s;
}

// b(u, e_v, d_j) of one resolved sample: the table entry, or mean + sum_c w_c E_c over the
// first min(C, params.max_components) components (in f32, as LpcaBtf::eval_into of
// LpcaBtf::truncated). `stride` is the LPCA vector length D.
fn btf_value(mat: MaterialHeader, s: BtfSample, stride: u32, j: u32) -> vec3<f32> {
    var k = s.base + j * 3u;
    var b = vec3<f32>(btf[k], btf[k + 1u], btf[k + 2u]);
    if mat.kind == 0u {
        return b;
    }
    let used = min(mat.components, params.max_components);
    for (var c = 0u; c < used; c++) {
        k += stride;
        b += btf[s.weights + c] * vec3<f32>(btf[k], btf[k + 1u], btf[k + 2u]);
    }
    return b;
}

// ---- pass 2: shading ----

// A shading sample: the pixel's primary ray against the triangle the visibility pass found
// there, as shading::cpu::primary_hit gives it.
struct Hit {
    tri: u32,
    // The triangle's vertices and their barycentric weights.
    corner: vec3<u32>,
    b: vec3<f32>,
    // The interpolated frame (tangent, bitangent, normal) and the view direction (towards the
    // camera) in it.
    t: vec3<f32>,
    bt: vec3<f32>,
    n: vec3<f32>,
    e_local: vec3<f32>,
    uv: vec2<f32>,
}

// A sample of the grid and its hit: `covered` is false outside the image (nothing is written)
// and where the visibility pass stored no triangle (the sample is written black, uncovered);
// both shading passes start here.
struct SampleHit {
    covered: bool,
    hit: Hit,
}

fn sample_hit(gid: vec3<u32>) -> SampleHit {
    var s: SampleHit;
    s.covered = false;
    if gid.x >= params.width || gid.y >= params.height {
        return s;
    }
    let px = vec2<i32>(gid.xy);
    // The triangle id (+1, 0 = background) the visibility pass stored there.
    let id = textureLoad(visibility, px, 0).x;
    if id == 0u {
        textureStore(image, px, vec4<f32>(0.0));
        return s;
    }
    s.covered = true;
    s.hit = hit_at(gid.xy, id - 1u);
    return s;
}

fn hit_at(gid: vec2<u32>, tri: u32) -> Hit {
    var hit: Hit;
    hit.tri = tri;
    hit.corner = vec3<u32>(indices[3u * tri], indices[3u * tri + 1u], indices[3u * tri + 2u]);
    let v0 = vertices[hit.corner.x];
    let v1 = vertices[hit.corner.y];
    let v2 = vertices[hit.corner.z];

    // The pixel centre's primary ray (shading::camera::Camera::ray).
    let sx = 2.0 * (f32(gid.x) + 0.5) / f32(params.width) - 1.0;
    let sy = 1.0 - 2.0 * (f32(gid.y) + 0.5) / f32(params.height);
    let o = params.camera_pos;
    let dir = normalize(params.cam_forward + params.cam_right * sx + params.cam_up * sy);

    // Moller-Trumbore barycentrics (no culling; the rasterizer already chose the triangle),
    // clamped to the triangle and renormalized as shading::cpu::primary_hit does.
    let e1 = v1.position - v0.position;
    let e2 = v2.position - v0.position;
    let pvec = cross(dir, e2);
    let det = dot(e1, pvec);
    var b = vec3<f32>(1.0, 0.0, 0.0);
    if abs(det) > 0.0 {
        let inv = 1.0 / det;
        let tvec = o - v0.position;
        let qvec = cross(tvec, e1);
        let b1 = dot(tvec, pvec) * inv;
        let b2 = dot(dir, qvec) * inv;
        let w = max(vec3<f32>(1.0 - b1 - b2, b1, b2), vec3<f32>(0.0));
        let sum = w.x + w.y + w.z;
        if sum > 0.0 {
            b = w / sum;
        }
    }
    hit.b = b;

    // Interpolated frame as VertexFrame::from_normal_tangent: normalized normal (the face
    // normal where vertex normals cancel), tangent made orthogonal to it, bitangent n x t.
    var n_raw = b.x * v0.normal + b.y * v1.normal + b.z * v2.normal;
    if !(dot(n_raw, n_raw) > 1e-12) {
        n_raw = cross(e1, e2);
    }
    var n = vec3<f32>(0.0, 1.0, 0.0);
    if dot(n_raw, n_raw) > 0.0 {
        n = normalize(n_raw);
    }
    let t_raw = b.x * v0.tangent + b.y * v1.tangent + b.z * v2.tangent;
    let t_orth = t_raw - n * dot(n, t_raw);
    var t: vec3<f32>;
    var bt: vec3<f32>;
    if length(t_orth) > 1e-6 * length(t_raw) {
        t = normalize(t_orth);
        bt = cross(n, t);
    } else {
        let basis = duff_basis(n);
        t = basis[0];
        bt = basis[1];
    }
    hit.t = t;
    hit.bt = bt;
    hit.n = n;
    hit.e_local = vec3<f32>(dot(-dir, t), dot(-dir, bt), dot(-dir, n));
    hit.uv = b.x * vec2<f32>(v0.u, v0.v) + b.y * vec2<f32>(v1.u, v1.v) + b.z * vec2<f32>(v2.u, v2.v);
    return hit;
}

// The triangle's material (ids are checked on the host; the min only guards the bounds).
fn material_of(tri: u32) -> u32 {
    if params.has_material_ids != 0u {
        return min(material_ids[tri], params.material_count - 1u);
    }
    return 0u;
}

// A hit's BTF at its texel and view: up to four view samples (bilinear in the view grid),
// each resolved once, and the LPCA vector length `stride`.
struct BtfView {
    mat: MaterialHeader,
    sample: array<BtfSample, 4>,
    samples: u32,
    stride: u32,
}

fn btf_view(hit: Hit, material: u32) -> BtfView {
    var bv: BtfView;
    let mat = materials[material];
    bv.mat = mat;

    // Btf::texel_of(uv * tiling): the material's nearest texel, wrapping.
    let tuv = hit.uv * mat.tiling;
    let texel = wrap_texel(tuv.y, mat.height) * mat.width + wrap_texel(tuv.x, mat.width);

    // View samples: Btf::view_weights, bilinear between the 4 nearest view-grid bin centres.
    var views = 1u;
    var view_idx = array<u32, 4>(0u, 0u, 0u, 0u);
    var view_w = array<f32, 4>(1.0, 0.0, 0.0, 0.0);
    var samples = 1u;
    if mat.view_m > 0u {
        let m = mat.view_m;
        views = m * m;
        if m > 1u {
            let c = continuous_coords(m, hit.e_local);
            let x0 = min(u32(floor(c.x)), m - 2u);
            let y0 = min(u32(floor(c.y)), m - 2u);
            let fx = clamp(c.x - f32(x0), 0.0, 1.0);
            let fy = clamp(c.y - f32(y0), 0.0, 1.0);
            view_idx = array<u32, 4>(y0 * m + x0, y0 * m + x0 + 1u, (y0 + 1u) * m + x0, (y0 + 1u) * m + x0 + 1u);
            view_w = array<f32, 4>((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
            samples = 4u;
        }
    }
    for (var s = 0u; s < samples; s++) {
        bv.sample[s] = btf_sample(mat, texel, view_idx[s], views, view_w[s]);
    }
    bv.samples = samples;
    bv.stride = params.local_dirs * 3u * views;
    if mat.per_view != 0u {
        bv.stride = params.local_dirs * 3u;
    }
    return bv;
}

// b(u, e, d_j) of a hit's BTF view: its samples' values blended by their weights.
fn btf_at(bv: BtfView, j: u32) -> vec3<f32> {
    var sample = bv.sample;
    var bj = vec3<f32>(0.0);
    for (var s = 0u; s < bv.samples; s++) {
        if sample[s].weight != 0.0 {
            bj += sample[s].weight * btf_value(bv.mat, sample[s], bv.stride, j);
        }
    }
    return bj;
}

@compute @workgroup_size(8, 8)
fn shade_pixels(@builtin(global_invocation_id) gid: vec3<u32>) {
    let sample = sample_hit(gid);
    if !sample.covered {
        return;
    }
    let hit = sample.hit;
    let bv = btf_view(hit, material_of(hit.tri));
    var acc = vec3<f32>(0.0);
    for (var j = 0u; j < params.local_dirs; j++) {
        let l = hit.b.x * lstar_at(hit.corner.x, j) + hit.b.y * lstar_at(hit.corner.y, j) + hit.b.z * lstar_at(hit.corner.z, j);
        acc += btf_at(bv, j) * l;
    }
    textureStore(image, vec2<i32>(gid.xy), vec4<f32>(acc, 1.0));
}
