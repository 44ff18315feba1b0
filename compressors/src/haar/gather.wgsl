// Gather on the non-linear Haar form (compressor `haar`, compressors/src/haar/mod.rs; Ng et al.
// 2003). Two passes:
//   haar_light, one invocation per (face, channel) (18): the light's forward non-standard
//       Haar transform l^ = W L in the standard in-place layout, level by level exactly as
//       haar::forward_face (f32 here, f64 on the CPU);
//   row_lstar (the shared gather_rows pass), one invocation per row r: L*_r = sum_{e in row r} coeff[e] * l^[coeff_idx[e]].
// R is params.light_resolution (the form's cubemap). The value array is `coeff_val` (f32) or
// `coeff_f16` (u16 half bits, packed 2 per word); the host splices in the matching
// declaration below.

@group(0) @binding(4) var<storage, read> row_ptr: array<u32>;
@group(0) @binding(5) var<storage, read> coeff_idx: array<u32>;     // u16, packed 2 per word
//#VALUES
@group(0) @binding(7) var<storage, read_write> light_hat: array<f32>; // N x RGB
@group(0) @binding(8) var<storage, read_write> haar_tmp: array<f32>;  // N x RGB

fn lh(base: u32, r: u32, i: u32, j: u32, c: u32) -> u32 {
    return 3u * (base + i * r + j) + c;
}

@compute @workgroup_size(32)
fn haar_light(inv: Invocation) {
    let id = thread_index(inv, 32u);
    if id >= params.threads {
        return;
    }
    let face = id / 3u;
    let c = id % 3u;
    let r = params.light_resolution;
    let base = face * r * r;
    for (var k = 0u; k < r * r; k++) {
        light_hat[3u * (base + k) + c] = light[3u * (base + k) + c];
    }
    var s = r;
    while s > 1u {
        let h = s / 2u;
        for (var i = 0u; i < h; i++) {
            for (var j = 0u; j < h; j++) {
                let a = light_hat[lh(base, r, 2u * i, 2u * j, c)];
                let b = light_hat[lh(base, r, 2u * i, 2u * j + 1u, c)];
                let cc = light_hat[lh(base, r, 2u * i + 1u, 2u * j, c)];
                let d = light_hat[lh(base, r, 2u * i + 1u, 2u * j + 1u, c)];
                haar_tmp[lh(base, r, i, j, c)] = 0.5 * (a + b + cc + d);
                haar_tmp[lh(base, r, i, j + h, c)] = 0.5 * (a - b + cc - d);
                haar_tmp[lh(base, r, i + h, j, c)] = 0.5 * (a + b - cc - d);
                haar_tmp[lh(base, r, i + h, j + h, c)] = 0.5 * (a - b - cc + d);
            }
        }
        for (var i = 0u; i < s; i++) {
            for (var j = 0u; j < s; j++) {
                light_hat[lh(base, r, i, j, c)] = haar_tmp[lh(base, r, i, j, c)];
            }
        }
        s = h;
    }
}

fn row_lstar(row: u32) -> vec3<f32> {
    let end = row_ptr[row + 1u];
    var acc = vec3<f32>(0.0);
    for (var e = row_ptr[row]; e < end; e++) {
        let k = u16_at(coeff_idx[e >> 1u], e);
        acc += coeff_at(e) * vec3<f32>(light_hat[3u * k], light_hat[3u * k + 1u], light_hat[3u * k + 2u]);
    }
    return acc;
}
