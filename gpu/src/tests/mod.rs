//! Tests of the GPU runtime against CPU references. They run on whatever adapter
//! [`GpuContext::new`] finds (lavapipe on machines without a GPU). Without any adapter they
//! print why and pass, unless `BISCALE_REQUIRE_GPU=1` is set, which turns that into a failure.

mod gather;
mod layout;
mod moments;
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
