//! GPU test support: a validated context on the machine's Vulkan device (lavapipe in CI), failing instead of
//! skipping when `REQUIRE_GPU=1`, and a check that the validation layer stayed silent.
#![allow(dead_code)]

use meshchar::gpu::{Context, ContextDesc};

/// A context with the Khronos validation layer on, or `None` (with a note on stderr) when no usable device exists
/// and `REQUIRE_GPU` is not `1`.
pub fn context() -> Option<Context> {
    match Context::new(&ContextDesc { validation: true, device: None }) {
        Ok(ctx) => Some(ctx),
        Err(e) => {
            if std::env::var("REQUIRE_GPU").is_ok_and(|v| v == "1") {
                panic!("REQUIRE_GPU=1 but no usable Vulkan device with validation: {e}");
            }
            eprintln!("skipping GPU test: {e}");
            None
        }
    }
}

/// Fails the test if the validation layer reported anything.
pub fn assert_no_validation_messages(ctx: &Context) {
    let m = ctx.validation_messages();
    assert!(m.is_empty(), "{} validation message(s):\n{}", m.len(), m.join("\n"));
}
