//! Meso-scale shading.
