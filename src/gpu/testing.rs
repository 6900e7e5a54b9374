//! GPU support of the crate's unit tests (the integration tests have their own, `tests/gpu_support`): a validated
//! context on the machine's Vulkan device (lavapipe in CI), failing instead of skipping when `REQUIRE_GPU=1`, one
//! test at a time per test binary while its context lives, and a check that the validation layer stayed silent.

use super::{Context, ContextDesc};

/// A context with the Khronos validation layer on, or `None` (with a note on stderr) when no usable device exists
/// and `REQUIRE_GPU` is not `1`.
pub(crate) fn context() -> Option<GpuTest> {
    context_with(ContextDesc { validation: true, ..Default::default() })
}

/// Most workgroups per dispatch dimension that tests of the tiling loops use: far below the 65,535 of lavapipe and
/// the 2^31 - 1 of discrete GPUs.
pub(crate) const TEST_DISPATCH_GROUPS: u32 = 4096;

/// [`context`] with the dispatch size capped at [`TEST_DISPATCH_GROUPS`] (see `ContextDesc::max_dispatch_groups`).
pub(crate) fn capped_context() -> Option<GpuTest> {
    context_with(ContextDesc {
        validation: true,
        max_dispatch_groups: Some(TEST_DISPATCH_GROUPS),
        ..Default::default()
    })
}

fn context_with(desc: ContextDesc) -> Option<GpuTest> {
    // The turn is taken before the device is created and given up after it is destroyed.
    let turn = one_at_a_time();
    match Context::new(&desc) {
        Ok(ctx) => Some(GpuTest { ctx, _turn: turn }),
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
pub(crate) fn assert_no_validation_messages(ctx: &Context) {
    let m = ctx.validation_messages();
    assert!(m.is_empty(), "{} validation message(s):\n{}", m.len(), m.join("\n"));
}

/// Holds the calling test apart from every other test of the binary that takes a turn, while its context lives
/// (the Khronos validation layer of Debian 12 can crash when one thread creates a device while another calls into a
/// different device; see `tests/gpu_support`). A thread may hold several turns at once.
pub(crate) fn one_at_a_time() -> Turn {
    let (lock, freed) = &TURN;
    let me = std::thread::current().id();
    let mut state = lock.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    loop {
        match *state {
            Some((owner, ref mut held)) if owner == me => {
                *held += 1;
                break;
            }
            None => {
                *state = Some((me, 1));
                break;
            }
            Some(_) => state = freed.wait(state).unwrap_or_else(|poisoned| poisoned.into_inner()),
        }
    }
    Turn(())
}

/// Which thread holds the turn and how many times, and the signal that it was given up.
type TurnState = (std::sync::Mutex<Option<(std::thread::ThreadId, usize)>>, std::sync::Condvar);

static TURN: TurnState = (std::sync::Mutex::new(None), std::sync::Condvar::new());

/// A test's turn ([`one_at_a_time`]), given up when dropped.
pub(crate) struct Turn(());

impl Drop for Turn {
    fn drop(&mut self) {
        let (lock, freed) = &TURN;
        let mut state = lock.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some((_, held)) = state.as_mut() {
            *held -= 1;
            if *held == 0 {
                *state = None;
                freed.notify_all();
            }
        }
    }
}

/// A test's context and its turn: the context is destroyed before the turn is given up. Reads as the [`Context`]
/// it holds.
pub(crate) struct GpuTest {
    ctx: Context,
    _turn: Turn,
}

impl std::ops::Deref for GpuTest {
    type Target = Context;
    fn deref(&self) -> &Context {
        &self.ctx
    }
}
