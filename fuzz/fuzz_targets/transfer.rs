//! cargo-fuzz target `transfer`: the body is `biscale_fuzz::transfer` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::transfer(data));
