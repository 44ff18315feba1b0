//! cargo-fuzz target `config`: the body is `biscale_fuzz::config` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::config(data));
