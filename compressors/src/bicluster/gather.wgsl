// Gather on the greedy constant-column bicluster form (compressor `bicluster`,
// compressors/src/bicluster/mod.rs; Sun et al., Algorithm 2). Two passes, in the same f32
// order as the CPU gather:
//   bicluster_sums, one invocation per bicluster b:
//       a_b = sum_{e in b} bc_vals[e] * (L[bc_cols[e]] / q)
//   row_lstar (the shared gather_rows pass), one invocation per row i:
//       L*_i = sum_{e in row i} a[id(e)],  id = block_bc_base[i / block_rows] + row_bc[e]
//       (block-local u16 ids when row_bc_local = 1, global u32 ids otherwise)
// meta_values = [value_scale q, block_rows, row_bc_local].

@group(0) @binding(4) var<storage, read> bc_col_ptr: array<u32>;
@group(0) @binding(5) var<storage, read> bc_cols: array<u32>;       // u16, packed 2 per word
@group(0) @binding(6) var<storage, read> bc_vals: array<u32>;       // i8, packed 4 per word
@group(0) @binding(7) var<storage, read> row_ptr: array<u32>;
@group(0) @binding(8) var<storage, read> row_bc: array<u32>;        // u16 packed, or u32
@group(0) @binding(9) var<storage, read> block_bc_base: array<u32>;
@group(0) @binding(10) var<storage, read_write> bc_sums: array<f32>; // biclusters x RGB

@compute @workgroup_size(64)
fn bicluster_sums(inv: Invocation) {
    let b = thread_index(inv, 64u);
    if b >= params.threads {
        return;
    }
    let inv_q = 1.0 / f32(meta_values[0]);
    let end = bc_col_ptr[b + 1u];
    var acc = vec3<f32>(0.0);
    for (var e = bc_col_ptr[b]; e < end; e++) {
        let k = u16_at(bc_cols[e >> 1u], e);
        let t = f32(i8_at(bc_vals[e >> 2u], e));
        acc += t * (light_at(k) * inv_q);
    }
    bc_sums[3u * b] = acc.x;
    bc_sums[3u * b + 1u] = acc.y;
    bc_sums[3u * b + 2u] = acc.z;
}

fn row_lstar(i: u32) -> vec3<f32> {
    let local = meta_values[2] == 1u;
    var base = 0u;
    if local {
        base = block_bc_base[i / max(meta_values[1], 1u)];
    }
    let end = row_ptr[i + 1u];
    var acc = vec3<f32>(0.0);
    for (var e = row_ptr[i]; e < end; e++) {
        var b: u32;
        if local {
            b = base + u16_at(row_bc[e >> 1u], e);
        } else {
            b = row_bc[e];
        }
        acc += vec3<f32>(bc_sums[3u * b], bc_sums[3u * b + 1u], bc_sums[3u * b + 2u]);
    }
    return acc;
}
