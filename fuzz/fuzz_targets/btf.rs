//! cargo-fuzz target `btf`: the body is `biscale_fuzz::btf` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::btf(data));
