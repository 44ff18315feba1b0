//! A plugin form (the example `quantized` cdylib, loaded through the C ABI) on the GPU,
//! against the plugin's CPU gather and the f64 product of the matrix the form stores.
//!
//! Tolerance: the WGSL and the CPU gather both sum a row's `n` non-negative products
//! `q_e L_k` in f32 in entry order and multiply by the scale once; whatever the order and
//! whether the GPU fuses multiply-adds, each is within `(n + 1) u + u` of the exact value
//! relative to it (`u = 2^-24`), so we allow `f32_sum_bound(n + 1) = (n + 3) u` against the
//! f64 reference and twice that between GPU and CPU. Every element is checked after poisoning
//! `L*` with NaN.

use super::gpu_or_skip;
use crate::{GpuError, GpuGather};
use biscale_compressors::plugin::testing::build_plugin;
use biscale_compressors::plugin::PluginCompressor;
use biscale_compressors::testing::{cubemap, f32_sum_bound, quantized_stored_product, random_light, random_transfer};
use biscale_core::compress::{ArrayData, CompressContext, CompressError, Compressor};
use biscale_core::sampling::LightVector;

fn quantized(params: serde_json::Value) -> PluginCompressor {
    let lib = build_plugin("biscale-plugin-quantized", &[], None).unwrap();
    PluginCompressor::load(&lib, params).unwrap()
}

#[test]
fn quantized_plugin_form_matches_its_cpu_gather_and_the_f64_reference() {
    let ctx = gpu_or_skip!();
    let plugin = quantized(serde_json::json!({}));
    // 8x8 and 16x16 local directions; resolution 32 is the reference cubemap (N = 6144, which
    // u16 column indices hold). Odd light seeds carry a sun 10^6 times the sky.
    for (seed, (vertices, dirs, res, density)) in
        [(5, 8, 6, 0.15), (5, 8, 6, 0.15), (2, 16, 4, 0.2), (3, 8, 32, 0.03)].into_iter().enumerate()
    {
        let seed = seed as u64;
        let t = random_transfer(vertices, dirs, res, density, seed);
        let form = plugin.compress(&t, &CompressContext::default()).unwrap();
        let mut lights = vec![random_light(res, seed + 40)];
        let mut sun = LightVector::constant(cubemap(res), [0.5, 0.4, 0.3]);
        sun.power[t.cols() / 3] = [1e7, 9e6, 8e6];
        lights.push(sun);
        // Both ways in: the compressor's kernels (checked by the host first), and the plain
        // description the plugin returned at load.
        for (i, light) in lights.iter().enumerate() {
            let mut g = if i == 0 {
                GpuGather::new(ctx, &form, &plugin.kernels(&form).unwrap()).unwrap()
            } else {
                GpuGather::new(ctx, &form, plugin.gpu_kernels()).unwrap()
            };
            assert_eq!(g.kind(), "plugin:quantized");
            g.fill_lstar(f32::NAN).unwrap();
            g.gather(light).unwrap();
            let got = g.read_lstar().unwrap();
            let cpu = plugin.gather(&form, light).unwrap();
            for (r, (exact, terms)) in quantized_stored_product(&form, light).into_iter().enumerate() {
                let bound = f32_sum_bound(terms + 1);
                for (c, exact) in exact.into_iter().enumerate() {
                    let (v, w) = (got.values()[r][c], cpu.values()[r][c]);
                    assert!(v.is_finite(), "row {r} channel {c} not written: {v}");
                    assert!((v as f64 - exact).abs() <= bound * exact, "row {r} c{c}: GPU {v} vs f64 {exact}");
                    assert!((v as f64 - w as f64).abs() <= 2.0 * bound * exact, "row {r} c{c}: GPU {v} vs CPU {w}");
                }
            }
        }
    }
}

#[test]
fn a_tampered_plugin_form_is_refused_before_upload() {
    let ctx = gpu_or_skip!();
    let plugin = quantized(serde_json::json!({}));
    let t = random_transfer(4, 8, 2, 0.3, 1);
    let mut form = plugin.compress(&t, &CompressContext::default()).unwrap();
    // A decreasing row pointer would make one invocation loop ~4 billion times.
    if let ArrayData::U32(rp) = &mut form.arrays.iter_mut().find(|a| a.name == "row_ptr").unwrap().data {
        rp[1] = rp[2] + 1;
    }
    let e = GpuGather::new(ctx, &form, plugin.gpu_kernels()).err().expect("tampered form accepted");
    assert!(matches!(&e, GpuError::Compress(CompressError::Malformed { array, .. }) if array == "row_ptr"), "{e}");
}
