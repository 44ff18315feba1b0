// The per-row pass (biscale-kernels ROW_PASS, appended to a program by `with_row_pass`).
// A program whose last pass computes each row of L* on its own defines
//   fn row_lstar(r: u32) -> vec3<f32>
// and names that pass `gather_rows` (ROW_ENTRY) with one thread per row; this entry point does
// the thread indexing, the bounds check and the store.

@compute @workgroup_size(64)
fn gather_rows(inv: Invocation) {
    let r = thread_index(inv, 64u);
    if r >= params.threads {
        return;
    }
    store_lstar(r, row_lstar(r));
}
