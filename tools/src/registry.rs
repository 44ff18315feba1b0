//! Compressor construction from the config: the one place that maps a config `kind` to a
//! built-in compressor (a closed set, one `match`).

use crate::config::CompressorConfig;
use crate::pipeline::{PipelineError, Result};
use crate::plan::CompressorSetting;
use biscale_compressors::bicluster::{table_stats, Bicluster};
use biscale_compressors::cpca::Cpca;
use biscale_compressors::haar::Haar;
use biscale_compressors::plugin::PluginCompressor;
use biscale_compressors::sparse::Sparse;
use biscale_compressors::BuiltinCompressor;
use biscale_core::compress::{CompressedForm, Compressor};
use biscale_core::transfer::TransferMatrix;

/// The compressor for one (sweep-expanded) setting.
pub fn build(setting: &CompressorSetting) -> Result<Box<dyn Compressor>> {
    // Sweeps are expanded by the planner, so each parameter holds one value here.
    let one = |s: &Option<crate::config::Sweep<usize>>| s.as_ref().map(|s| s.0[0]);
    let c = match &setting.config {
        CompressorConfig::Sparse {} => BuiltinCompressor::Sparse(Sparse),
        CompressorConfig::Bicluster { block_vertices } => {
            let default = Bicluster::default();
            BuiltinCompressor::Bicluster(Bicluster {
                block_vertices: one(block_vertices).unwrap_or(default.block_vertices),
                ..default
            })
        }
        CompressorConfig::Cpca { clusters, components, iterations } => {
            let default = Cpca::default();
            BuiltinCompressor::Cpca(Cpca {
                clusters: one(clusters).unwrap_or(default.clusters),
                components: one(components).unwrap_or(default.components),
                iterations: iterations.unwrap_or(default.iterations),
                ..default
            })
        }
        CompressorConfig::Haar { terms } => {
            BuiltinCompressor::Haar(Haar::with_terms(one(terms).unwrap_or(Haar::default().terms)))
        }
        CompressorConfig::Plugin { path, params } => {
            let params = serde_json::to_value(params)
                .map_err(|e| PipelineError::Other(format!("{}: plugin params: {e}", setting.label)))?;
            let plugin = PluginCompressor::load(path, params)
                .map_err(|e| PipelineError::Other(format!("compressor '{}': {e}", setting.label)))?;
            return Ok(Box::new(plugin));
        }
    };
    Ok(Box::new(c))
}

/// The GPU kernels of a plugin compressor (built-ins are found by their form's kind).
pub fn plugin_kernels(setting: &CompressorSetting) -> Result<Option<biscale_core::kernels::KernelDesc>> {
    match &setting.config {
        CompressorConfig::Plugin { path, params } => {
            let params = serde_json::to_value(params).map_err(|e| PipelineError::Other(e.to_string()))?;
            let plugin = PluginCompressor::load(path, params)
                .map_err(|e| PipelineError::Other(format!("compressor '{}': {e}", setting.label)))?;
            Ok(Some(plugin.gpu_kernels().clone()))
        }
        _ => Ok(None),
    }
}

/// Compressor-specific statistics for the report, computed from the form's arrays
/// (biclustering: the paper's Table I quantities).
pub fn stats(kind: &str, form: &CompressedForm, t: &TransferMatrix) -> Option<serde_json::Value> {
    match kind {
        "bicluster" => match table_stats(form, t) {
            Ok(s) => serde_json::to_value(s).ok(),
            Err(e) => {
                eprintln!("warning: bicluster stats: {e}");
                None
            }
        },
        _ => None,
    }
}
