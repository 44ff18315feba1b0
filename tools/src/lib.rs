//! The biscale pipeline.
