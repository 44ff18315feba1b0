// Gather on the clustered-PCA form (compressor `cpca`, compressors/src/cpca/mod.rs; Sloan et
// al. 2003). The clustered unit is U = unit_rows rows (1, or a vertex's M); every basis vector
// is U segments of N values, segment (v U + j) holding row j of vector v. Two passes:
//   cpca_project, one 64-invocation workgroup per segment s (K (C + 1) U of them):
//       P[s] = basis[s N ..][..N] . L   (strided partial sums, then a tree reduction)
//   row_lstar (the shared gather_rows pass), one invocation per row r = u U + j, k = cluster[u]:
//       L*_r = P[k (C+1) U + j] + sum_{c=1..C} coeffs[u C + c - 1] P[(k (C+1) + c) U + j],  0 when k = K
// meta_values = [clusters K, components C, unit_rows U].

@group(0) @binding(4) var<storage, read> basis: array<f32>;          // K (C + 1) U N
@group(0) @binding(5) var<storage, read> cluster: array<u32>;        // u16 per unit, packed 2 per word
@group(0) @binding(6) var<storage, read> coeffs: array<f32>;         // units C
@group(0) @binding(7) var<storage, read_write> proj: array<f32>;     // K (C + 1) U x RGB

var<workgroup> partial: array<vec3<f32>, 64>;

@compute @workgroup_size(64)
fn cpca_project(inv: Invocation) {
    // The whole workgroup works on one vector, so the barriers stay in uniform control flow.
    let v = inv.wid.y * inv.nwg.x + inv.wid.x;
    let lid = inv.lid;
    let vectors = params.threads / 64u;
    let n = params.cols;
    var acc = vec3<f32>(0.0);
    if v < vectors {
        for (var k = lid; k < n; k += 64u) {
            acc += basis[v * n + k] * light_at(k);
        }
    }
    partial[lid] = acc;
    workgroupBarrier();
    for (var s = 32u; s > 0u; s >>= 1u) {
        if lid < s {
            partial[lid] += partial[lid + s];
        }
        workgroupBarrier();
    }
    if lid == 0u && v < vectors {
        proj[3u * v] = partial[0].x;
        proj[3u * v + 1u] = partial[0].y;
        proj[3u * v + 2u] = partial[0].z;
    }
}

fn proj_at(v: u32) -> vec3<f32> {
    return vec3<f32>(proj[3u * v], proj[3u * v + 1u], proj[3u * v + 2u]);
}

fn row_lstar(r: u32) -> vec3<f32> {
    let units = meta_values[2];
    let u = r / units;
    let j = r % units;
    let k = u16_at(cluster[u >> 1u], u);
    let clusters = meta_values[0];
    let c = meta_values[1];
    if k >= clusters {
        return vec3<f32>(0.0);
    }
    let base = k * (c + 1u);
    var acc = proj_at(base * units + j);
    for (var v = 0u; v < c; v++) {
        acc += coeffs[u * c + v] * proj_at((base + 1u + v) * units + j);
    }
    return acc;
}
