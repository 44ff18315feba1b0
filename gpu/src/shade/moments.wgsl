// The per-pixel resolves of light moments (biscale-gpu, shade/moments.wgsl; compiled after
// bins.wgsl, shade.wgsl and brdf.wgsl): `runtime.moments_resolve = "pixel"` and
// `"pixel_analytic"`, `biscale_shading::cpu::shade_moments` and `shade_moments_analytic` in
// f32. The three moment gathers (`L d_x`, `L d_y`, `L d_z`, as the GPU gathers leave them) are
// read in place; nothing is resolved per vertex first.
//
// At a hit with frame (t, bt, n) and view e, each of its triangle's three vertices is resolved
// at the hit's own frame and the three results are blended by the barycentric weights:
//
// * "pixel" (the BTF's tables): bin j of the vertex sends its exact-cosine power to the bins
//   around its mean direction in the hit's frame (`spread`, as the vertex resolve), each bin i
//   divided by its mean cosine and dotted with the BTF's b_i at the hit's texel and view. The
//   dot product is linear, so each bin's share is dotted as it is spread, and no M-sized
//   array is kept per pixel.
// * "pixel_analytic" (a material with an analytic BRDF, `brdfs[material].kind != BRDF_NONE`):
//   bin j gives f(w_j, e) (n . D_j) per channel, w_j the unit luminance direction of D_j in
//   the hit's frame (skipped when it is zero or at or below the horizon) and e the view taken
//   a hair above the horizon (`above_horizon`). Other materials are shaded as "pixel".

// The three gathered moments: rows v * M + j, RGB interleaved (GpuGather's `L*` layout).
@group(0) @binding(10) var<storage, read> moment_x: array<f32>;
@group(0) @binding(11) var<storage, read> moment_y: array<f32>;
@group(0) @binding(12) var<storage, read> moment_z: array<f32>;
// 1 / cosbar_i per bin of the local grid (the moments' own buffer, which their vertex resolve reads).
@group(0) @binding(15) var<storage, read> inv_mean_cosine: array<f32>;

// Channel c of row `row`'s three moments: the world vector D_c.
fn moment(row: u32, c: u32) -> vec3<f32> {
    let k = 3u * row + c;
    return vec3<f32>(moment_x[k], moment_y[k], moment_z[k]);
}

// `shading::cpu::above_horizon`: v normalised, its elevation raised to 1e-6 if below (azimuth
// kept; straight up when it has none).
fn above_horizon(v: vec3<f32>) -> vec3<f32> {
    let min_z = 1e-6;
    var d = vec3<f32>(0.0, 0.0, 1.0);
    if dot(v, v) > 0.0 {
        d = normalize(v);
    }
    if d.z >= min_z {
        return d;
    }
    let xy = sqrt(d.x * d.x + d.y * d.y);
    if xy > 0.0 {
        let s = sqrt(1.0 - min_z * min_z) / xy;
        return vec3<f32>(d.x * s, d.y * s, min_z);
    }
    return vec3<f32>(0.0, 0.0, 1.0);
}

// One vertex's moments resolved at the hit with the BTF's tables, dotted with them.
fn table_resolve(hit: Hit, bv: BtfView, v: u32) -> vec3<f32> {
    let bins = params.local_dirs;
    var sum = vec3<f32>(0.0);
    for (var j = 0u; j < bins; j++) {
        let row = v * bins + j;
        let s = spread(moment(row, 0u), moment(row, 1u), moment(row, 2u), hit.t, hit.bt, hit.n, j, params.moment_grid, params.lobe);
        for (var k = 0u; k < s.count; k++) {
            let i = s.bins[k];
            sum += (s.weights[k] * inv_mean_cosine[i]) * s.power * btf_at(bv, i);
        }
    }
    return sum;
}

// One vertex's moments shaded at the hit with the material's own BRDF (`analytic_resolve`).
fn analytic_resolve(hit: Hit, brdf: Brdf, view: vec3<f32>, v: u32) -> vec3<f32> {
    let bins = params.local_dirs;
    var sum = vec3<f32>(0.0);
    for (var j = 0u; j < bins; j++) {
        let row = v * bins + j;
        let d0 = moment(row, 0u);
        let d1 = moment(row, 1u);
        let d2 = moment(row, 2u);
        let p = vec3<f32>(dot(hit.n, d0), dot(hit.n, d1), dot(hit.n, d2));
        if all(p == vec3<f32>(0.0)) {
            continue;
        }
        let g = d0 * LUMINANCE.x + d1 * LUMINANCE.y + d2 * LUMINANCE.z;
        let local = vec3<f32>(dot(g, hit.t), dot(g, hit.bt), dot(g, hit.n));
        let big = max(max(abs(local.x), abs(local.y)), abs(local.z));
        if !(big > 0.0) || !(local.z > 0.0) {
            continue;
        }
        // Scaled by a power of two (exact) before normalising, so that tiny moments neither
        // underflow nor lose their direction.
        let w = normalize(ldexp(local, vec3<i32>(-frexp(big).exp)));
        sum += brdf_eval(brdf, w, view) * p;
    }
    return sum;
}

@compute @workgroup_size(8, 8)
fn shade_moment_pixels(@builtin(global_invocation_id) gid: vec3<u32>) {
    let sample = sample_hit(gid);
    if !sample.covered {
        return;
    }
    let hit = sample.hit;
    let material = material_of(hit.tri);
    let brdf = brdfs[material];
    var acc = vec3<f32>(0.0);
    if params.resolve == RESOLVE_PIXEL_ANALYTIC && brdf.kind != BRDF_NONE {
        let view = above_horizon(hit.e_local);
        for (var k = 0u; k < 3u; k++) {
            acc += hit.b[k] * analytic_resolve(hit, brdf, view, hit.corner[k]);
        }
    } else {
        let bv = btf_view(hit, material);
        for (var k = 0u; k < 3u; k++) {
            acc += hit.b[k] * table_resolve(hit, bv, hit.corner[k]);
        }
    }
    textureStore(image, vec2<i32>(gid.xy), vec4<f32>(acc, 1.0));
}
