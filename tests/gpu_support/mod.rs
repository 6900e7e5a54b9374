//! GPU test support: a validated context on the machine's Vulkan device (lavapipe in CI), failing instead of
//! skipping when `REQUIRE_GPU=1`, and a check that the validation layer stayed silent.
#![allow(dead_code)]

use meshchar::gpu::{Context, ContextDesc};

/// A context with the Khronos validation layer on, or `None` (with a note on stderr) when no usable device exists
/// and `REQUIRE_GPU` is not `1`.
pub fn context() -> Option<Context> {
    context_with(ContextDesc { validation: true, ..Default::default() })
}

/// Most workgroups per dispatch dimension that tests of the tiling loops use: far below the 65,535 of lavapipe and
/// the 2^31 - 1 of discrete GPUs, so that "more workgroups than one dispatch allows" needs little host memory on any
/// device.
pub const TEST_DISPATCH_GROUPS: u32 = 4096;

/// [`context`] with the dispatch size capped at [`TEST_DISPATCH_GROUPS`] (see `ContextDesc::max_dispatch_groups`).
pub fn capped_context() -> Option<Context> {
    context_with(ContextDesc {
        validation: true,
        max_dispatch_groups: Some(TEST_DISPATCH_GROUPS),
        ..Default::default()
    })
}

fn context_with(desc: ContextDesc) -> Option<Context> {
    match Context::new(&desc) {
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
