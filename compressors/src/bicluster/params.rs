//! The parameters of the biclustering compressor (config keys, `metrics.json` params, label
//! `bicluster[-b<block_vertices>][-e<error_budget>]`).

use serde::{Deserialize, Serialize};

/// Parameters of the biclustering compressor. Every field is a config key with the default
/// given.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Bicluster {
    /// Vertices per independently biclustered block of rows (rows `v*M + j` of consecutive
    /// vertices in mesh order). Blocks run in parallel; larger blocks find more sharing.
    /// 0 = one global block (the paper's setting). Default 1024: on the bunny (6x32x32, 8x8)
    /// it keeps 22.1% of the raw flops and 1.06 bytes per non-zero against 21.3% / 1.00 for
    /// the global greedy (256: 25.2% / 1.29; 64: 31.8% / 1.75), while bounding the work per
    /// block so large meshes scale linearly and in parallel (see `examples/bicluster_bench.rs`).
    pub block_vertices: usize,
    /// Denominator `q` of the integer value codes (values are `code / q`); 0 = detect the
    /// smallest one that represents `T` exactly (4 for the 2x2 box-filtered reference).
    pub value_scale: u32,
    /// Lossy mode: the largest relative Frobenius error `||T - T'||_F / ||T||_F` the form may
    /// have, in `[0, 1]` (see `prune.rs` for why this norm). 0 = lossless (the paper's
    /// biclustering). The achieved error, and the relative `L*` error under the uniform sky,
    /// are in the form's stats.
    #[serde(skip_serializing_if = "is_zero")]
    pub error_budget: f64,
    /// What one column of a bicluster costs in the greedy's `dW`, against 1 for a row and 2
    /// for each non-zero it covers. The paper's flop count is 2 (`W(B) = r + 2l - 1`). The
    /// CPU gather's time says a column entry, with its share of its bicluster's pass-1 work,
    /// costs about 6 row-list entries (5.3 against 0.89 ns on the bunny). Raising the cost
    /// makes taller, narrower biclusters that gather faster for more flops and bytes: 16
    /// gathers about 5% faster for 5% (bunny) to 20% (30k bunny) more flops (BENCHMARKS,
    /// "A gather-aware greedy"). In `1..=64`.
    #[serde(skip_serializing_if = "is_paper_column_cost")]
    pub column_cost: u32,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// The paper's cost of a column in `W(B) = r + 2l - 1`.
pub const PAPER_COLUMN_COST: u32 = 2;

fn is_paper_column_cost(c: &u32) -> bool {
    *c == PAPER_COLUMN_COST
}

impl Default for Bicluster {
    fn default() -> Self {
        Self { block_vertices: 1024, value_scale: 0, error_budget: 0.0, column_cost: PAPER_COLUMN_COST }
    }
}

impl Bicluster {
    /// The paper's setting: one global greedy over all rows (single-threaded, slowest).
    pub fn global() -> Self {
        Self { block_vertices: 0, ..Self::default() }
    }

    /// Refuse a budget outside `[0, 1]` (or not a number) or a column cost outside `1..=64`,
    /// naming the key.
    pub fn validate(&self) -> Result<(), String> {
        if !(0.0..=1.0).contains(&self.error_budget) {
            return Err(format!(
                "bicluster: error_budget = {} must be a relative error in [0, 1] (0 = lossless)",
                self.error_budget
            ));
        }
        if !(1..=64).contains(&self.column_cost) {
            return Err(format!(
                "bicluster: column_cost = {} must be in 1..=64 (the paper's flop count is 2)",
                self.column_cost
            ));
        }
        Ok(())
    }

    /// The greedy's costs of a row and a column.
    pub fn costs(&self) -> super::greedy::Costs {
        super::greedy::Costs { row: 1, col: self.column_cost as u64 }
    }
}
