//! cargo-fuzz target `shard_manifest`: the body is `biscale_fuzz::shard_manifest` (see fuzz/src/lib.rs).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| biscale_fuzz::shard_manifest(data));
