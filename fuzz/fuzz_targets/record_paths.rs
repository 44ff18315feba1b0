//! cargo-fuzz target `record_paths`: the body is `biscale_fuzz::record_paths` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::record_paths(data));
