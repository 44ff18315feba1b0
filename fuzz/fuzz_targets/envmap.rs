//! cargo-fuzz target `envmap`: the body is `biscale_fuzz::envmap` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::envmap(data));
