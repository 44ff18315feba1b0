//! Helpers shared by the integration tests (scene builders).
