//! The parameters of the Haar compressor (config keys, `metrics.json` params, label `haar-t<terms>`).

use biscale_core::compress::CompressError;
use serde::{Deserialize, Serialize};

/// Non-linear Haar approximation of every row of `T`. Every field is a config key with the
/// default given.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize, Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct Haar {
    /// Coefficients kept per row (`T` in Ng et al.; the comparison setting is 12, the
    /// default). Rows with fewer non-zero coefficients keep all of them. `terms >= N` keeps
    /// every row exactly.
    pub terms: usize,
    /// Rank coefficients by `|c_i| x solid angle of support` (Ng et al.'s area-weighted
    /// selection) instead of `|c_i|`. Default true.
    pub area_weighted: bool,
    /// Store the kept values as IEEE half floats (2 bytes) instead of f32 (4 bytes). Relative
    /// rounding 2^-11 per value. Default false.
    pub f16_values: bool,
}

impl Default for Haar {
    fn default() -> Self {
        Self { terms: 12, area_weighted: true, f16_values: false }
    }
}

impl Haar {
    /// The reference setting with `terms` coefficients per row.
    pub fn with_terms(terms: usize) -> Self {
        Self { terms, ..Self::default() }
    }

    /// These parameters, or what is wrong with them.
    pub fn validated(self) -> Result<Self, String> {
        if self.terms == 0 {
            return Err("haar terms must be at least 1".into());
        }
        Ok(self)
    }

    /// [`Self::validated`] as the compressor's error.
    pub(crate) fn check(&self) -> Result<(), CompressError> {
        self.validated().map(|_| ()).map_err(CompressError::Params)
    }
}
