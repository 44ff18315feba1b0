//! The parameters of the sparse baseline: none; any key in its config table is an error.

use serde::{Deserialize, Serialize};

/// `[[compressors]] kind = "sparse"` takes no other key.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SparseParams {}
