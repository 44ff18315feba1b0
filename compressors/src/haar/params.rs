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
    /// How each row's coefficients are ranked for the selection: `area` (default),
    /// `side` or `magnitude` ([`HaarWeighting`]).
    pub weighting: HaarWeighting,
    /// Store the kept values as IEEE half floats (2 bytes) instead of f32 (4 bytes). Relative
    /// rounding 2^-11 per value. Default false.
    pub f16_values: bool,
}

/// The weight `w_i` of a coefficient's rank `|c_i| w_i` in the selection, from `A_i`, the
/// solid angle of basis function `i`'s support (module docs of `haar`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum HaarWeighting {
    /// `w_i = A_i`: Ng et al. 2003's area weighting.
    #[default]
    Area,
    /// `w_i = sqrt(A_i)`, the support's side: the expected size of term `i`'s share of
    /// `T L` when the light is smooth over its support (`|(W L)_i|` grows as the square
    /// root of the support for an orthonormal basis).
    Side,
    /// `w_i = 1`: `|c_i|` alone, L2-optimal for the row itself.
    Magnitude,
}

impl HaarWeighting {
    /// The weight of a support of solid angle `area`.
    pub fn weight(self, area: f64) -> f64 {
        match self {
            HaarWeighting::Area => area,
            HaarWeighting::Side => area.sqrt(),
            HaarWeighting::Magnitude => 1.0,
        }
    }

    /// The config value (`area`, `side`, `magnitude`).
    pub fn name(self) -> &'static str {
        match self {
            HaarWeighting::Area => "area",
            HaarWeighting::Side => "side",
            HaarWeighting::Magnitude => "magnitude",
        }
    }
}

impl Default for Haar {
    fn default() -> Self {
        Self { terms: 12, weighting: HaarWeighting::Area, f16_values: false }
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
