//! cargo-fuzz target `config_set`: the body is `biscale_fuzz::config_set` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::config_set(data));
