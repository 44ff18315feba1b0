//! cargo-fuzz target `form`: the body is `biscale_fuzz::form` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::form(data));
