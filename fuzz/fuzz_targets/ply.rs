//! cargo-fuzz target `ply`: the body is `biscale_fuzz::ply` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::ply(data));
