// Gather on the quantized sparse-row form (plugin `quantized`, plugins/quantized/src/lib.rs):
// L*[r] = scale * sum_{e in row_ptr[r]..row_ptr[r+1]} codes[e] * L[col_idx[e]],
// one invocation per row, accumulated in f32 in column order (the order of the CPU gather).
// col_idx (u16) and codes (u8) arrive packed in 32-bit words; the prelude's u16_at / u8_at
// unpack them. params, light, lstar and meta_values come from the prelude (bindings 0-3).

@group(0) @binding(4) var<storage, read> row_ptr: array<u32>;
@group(0) @binding(5) var<storage, read> col_idx: array<u32>;
@group(0) @binding(6) var<storage, read> codes: array<u32>;
@group(0) @binding(7) var<storage, read> scale: array<f32>;

fn row_lstar(r: u32) -> vec3<f32> {
    let end = row_ptr[r + 1u];
    var acc = vec3<f32>(0.0);
    for (var e = row_ptr[r]; e < end; e++) {
        let k = u16_at(col_idx[e >> 1u], e);
        let q = f32(u8_at(codes[e >> 2u], e));
        acc += q * light_at(k);
    }
    return scale[0] * acc;
}
