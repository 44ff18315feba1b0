// Prelude prepended to every gather program (biscale-kernels, src/prelude.wgsl).
//
// Binding conventions (all in @group(0); the host reflects the program and binds by NAME).
// This prelude declares the four standard bindings; kernels declare their form arrays and
// scratch buffers at @binding(4) and up:
//   params : var<uniform> GatherParams          one per pass (threads = this pass's count)
//   light  : var<storage, read> array<f32>       L, N texels x RGB interleaved (3 floats each)
//   lstar  : var<storage, read_write> array<f32> L*, rows x RGB interleaved, row = v * M + j
//   meta_values : var<storage, read> array<u32>  the program's meta keys, in its declared order
//   <name> : var<storage, read> array<u32|i32|f32>  the form array called <name>
//   <name> : var<storage, read_write> array<...>    a scratch buffer the program declares
//
// Packing of narrow integer arrays (WGSL has no 8/16-bit storage without extensions):
// element i of a u8/i8 array lives in bits 8*(i%4)..8*(i%4)+8 of 32-bit word i/4, element i
// of a u16/i16 array in bits 16*(i%2).. of word i/2 (the little-endian bytes of the array,
// zero-padded to whole words). Read them with u8_at(arr[i >> 2u], i), i8_at, u16_at(arr[i >> 1u], i),
// i16_at; signed values are sign-extended.

// Mirror of the Rust `biscale_kernels::GatherParams` (#[repr(C)], 32 bytes; checked by a
// layout test).
struct GatherParams {
    rows: u32,
    cols: u32,
    local_dirs: u32,
    vertices: u32,
    // Invocations this pass must run; the grid is rounded up, so kernels return when
    // thread_index(...) >= threads.
    threads: u32,
    pass_index: u32,
    // Texels per cubemap face edge R of the form's light basis (0 for another basis).
    light_resolution: u32,
    pad0: u32,
}

@group(0) @binding(0) var<uniform> params: GatherParams;
@group(0) @binding(1) var<storage, read> light: array<f32>;
@group(0) @binding(2) var<storage, read_write> lstar: array<f32>;
@group(0) @binding(3) var<storage, read> meta_values: array<u32>;

// The builtins a gather entry point takes: `@compute @workgroup_size(64) fn pass(inv: Invocation)`.
struct Invocation {
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
}

// This invocation's index among the pass's threads, for workgroups of `group_size` (the
// entry point's @workgroup_size); kernels return when it is >= params.threads.
fn thread_index(inv: Invocation, group_size: u32) -> u32 {
    return linear_thread(inv.wid, inv.nwg, inv.lid, group_size);
}

// Linear invocation index over a 2D grid of 1D workgroups of `group_size` invocations
// (the host folds large dispatches into y to respect max_compute_workgroups_per_dimension).
fn linear_thread(wid: vec3<u32>, nwg: vec3<u32>, local_index: u32, group_size: u32) -> u32 {
    return (wid.y * nwg.x + wid.x) * group_size + local_index;
}

fn u8_at(word: u32, i: u32) -> u32 {
    return extractBits(word, (i & 3u) * 8u, 8u);
}

fn i8_at(word: u32, i: u32) -> i32 {
    return extractBits(bitcast<i32>(word), (i & 3u) * 8u, 8u);
}

fn u16_at(word: u32, i: u32) -> u32 {
    return extractBits(word, (i & 1u) * 16u, 16u);
}

fn i16_at(word: u32, i: u32) -> i32 {
    return extractBits(bitcast<i32>(word), (i & 1u) * 16u, 16u);
}

fn light_at(k: u32) -> vec3<f32> {
    return vec3<f32>(light[3u * k], light[3u * k + 1u], light[3u * k + 2u]);
}

fn store_lstar(row: u32, v: vec3<f32>) {
    lstar[3u * row] = v.x;
    lstar[3u * row + 1u] = v.y;
    lstar[3u * row + 2u] = v.z;
}

