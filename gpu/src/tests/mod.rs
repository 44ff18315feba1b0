//! Tests of the GPU runtime against CPU references. They run on whatever adapter
//! [`GpuContext::new`] finds (lavapipe on machines without a GPU). Without any adapter they
//! print why and pass, unless `BISCALE_REQUIRE_GPU=1` is set, which turns that into a failure.

mod gather;
mod layout;
mod moments;
mod pixel_resolve;
mod plugin;
mod sh;
mod shading;

use crate::GpuContext;
use std::sync::OnceLock;

/// The shared context, or `None` (with a printed reason) when there is no adapter.
pub(crate) fn ctx() -> Option<&'static GpuContext> {
    static CTX: OnceLock<Option<GpuContext>> = OnceLock::new();
    CTX.get_or_init(|| match GpuContext::new() {
        Ok(c) => {
            eprintln!("GPU tests run on {} (timestamps: {})", c.adapter(), c.has_timestamps());
            Some(c)
        }
        Err(e) => {
            if std::env::var("BISCALE_REQUIRE_GPU").is_ok_and(|v| v == "1") {
                panic!("BISCALE_REQUIRE_GPU=1 but {e}");
            }
            eprintln!("SKIPPING GPU tests: {e}");
            None
        }
    })
    .as_ref()
}

/// A Phong plane (`[-1, 1]^2` in XZ, 6x6 cells, no UVs, every frame +Y up) on 4x4 light bins
/// and 4x4 views, the small scene several shading tests draw, and its vertex count.
pub(crate) fn phong_plane() -> (biscale_core::scene::ShadeScene, usize) {
    use biscale_core::geometry::{shapes, VertexFrame};
    use biscale_core::scene::{Btf, Material, ShadeScene};
    let mut mesh = shapes::grid_plane(6, 2.0);
    mesh.uvs = None;
    let nv = mesh.positions.len();
    let frame = VertexFrame::from_normal_tangent(glam::Vec3::Y, glam::Vec3::X);
    let btf = Btf::phong([0.6, 0.5, 0.4], [0.3, 0.3, 0.3], 16.0, biscale_compressors::testing::bins(4), 4).unwrap();
    (ShadeScene::new(mesh, vec![frame; nv], vec![Material::new(btf)], None).unwrap(), nv)
}

/// The shared context or return from the test with a message.
macro_rules! gpu_or_skip {
    () => {
        match crate::tests::ctx() {
            Some(c) => c,
            None => {
                eprintln!("skipped: no GPU adapter");
                return;
            }
        }
    };
}
pub(crate) use gpu_or_skip;
