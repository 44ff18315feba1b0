// Gather on the raw sparse CSR form (compressor `sparse`, compressors/src/sparse/mod.rs):
// L*[r] = sum_{i in row_ptr[r]..row_ptr[r+1]} values[i] * L[col_idx[i]], one invocation per row,
// accumulated in f32 in column order (the same order as the CPU gather).

// params, light, lstar and meta_values come from the prelude (bindings 0-3).
@group(0) @binding(4) var<storage, read> row_ptr: array<u32>;
@group(0) @binding(5) var<storage, read> col_idx: array<u32>;
@group(0) @binding(6) var<storage, read> values: array<f32>;

fn row_lstar(r: u32) -> vec3<f32> {
    let end = row_ptr[r + 1u];
    var acc = vec3<f32>(0.0);
    for (var i = row_ptr[r]; i < end; i++) {
        acc += values[i] * light_at(col_idx[i]);
    }
    return acc;
}
