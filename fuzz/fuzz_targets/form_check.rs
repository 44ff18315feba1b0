//! cargo-fuzz target `form_check`: the body is `biscale_fuzz::form_check` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::form_check(data));
