//! cargo-fuzz target `npz`: the body is `biscale_fuzz::npz` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::npz(data));
