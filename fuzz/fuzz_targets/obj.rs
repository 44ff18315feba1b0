//! cargo-fuzz target `obj`: the body is `biscale_fuzz::obj` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::obj(data));
