//! GPU test support: a validated context on the machine's Vulkan device (lavapipe in CI), failing instead of
//! skipping when `REQUIRE_GPU=1`, and a check that the validation layer stayed silent.
#![allow(dead_code)]

use meshchar::gpu::{Context, ContextDesc};

/// A context with the Khronos validation layer on, or `None` (with a note on stderr) when no usable device exists
/// and `REQUIRE_GPU` is not `1`.
pub fn context() -> Option<GpuTest> {
    context_with(ContextDesc { validation: true, ..Default::default() })
}

/// Most workgroups per dispatch dimension that tests of the tiling loops use: far below the 65,535 of lavapipe and
/// the 2^31 - 1 of discrete GPUs, so that "more workgroups than one dispatch allows" needs little host memory on any
/// device.
pub const TEST_DISPATCH_GROUPS: u32 = 4096;

/// [`context`] with the dispatch size capped at [`TEST_DISPATCH_GROUPS`] (see `ContextDesc::max_dispatch_groups`).
pub fn capped_context() -> Option<GpuTest> {
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
pub fn assert_no_validation_messages(ctx: &Context) {
    let m = ctx.validation_messages();
    assert!(m.is_empty(), "{} validation message(s):\n{}", m.len(), m.join("\n"));
}

/// Records with `record` into a command buffer the test owns (its own pool, on the context's queue family),
/// submits it to the context's queue and waits on a fence of its own: what an engine does, with meshchar only
/// recording. Returns what `record` returned.
pub fn in_caller_command_buffer<T>(ctx: &Context, record: impl FnOnce(&mut meshchar::gpu::Recorder<'_>) -> T) -> T {
    use ash::vk;
    let dev = ctx.device();
    let info = vk::CommandPoolCreateInfo::default().queue_family_index(ctx.queue_family());
    // SAFETY: plain Vulkan object creation and submission on the context's device, single-threaded; every object is
    // destroyed after the fence wait.
    unsafe {
        let pool = dev.create_command_pool(&info, None).expect("command pool");
        let alloc = vk::CommandBufferAllocateInfo::default()
            .command_pool(pool)
            .level(vk::CommandBufferLevel::PRIMARY)
            .command_buffer_count(1);
        let cmd = dev.allocate_command_buffers(&alloc).expect("command buffer")[0];
        dev.begin_command_buffer(cmd, &vk::CommandBufferBeginInfo::default()).expect("begin");
        let out = {
            let mut rec = meshchar::gpu::Recorder::new(ctx, cmd);
            record(&mut rec)
        };
        dev.end_command_buffer(cmd).expect("end");
        let fence = dev.create_fence(&vk::FenceCreateInfo::default(), None).expect("fence");
        let queue = dev.get_device_queue(ctx.queue_family(), 0);
        let cmds = [cmd];
        dev.queue_submit(queue, &[vk::SubmitInfo::default().command_buffers(&cmds)], fence).expect("submit");
        dev.wait_for_fences(&[fence], true, u64::MAX).expect("wait");
        dev.destroy_fence(fence, None);
        dev.destroy_command_pool(pool, None);
        out
    }
}

/// Holds the calling test apart from every other test of its binary that takes a turn: every test that gets its
/// context from [`context`] or [`capped_context`] holds one while the context lives, and tests that create devices
/// themselves take one for their whole run. The Khronos validation layer of Debian 12 (1.3.239) can crash when one
/// thread creates a device while another calls into a different device: two core dumps of
/// `tests/gpu/gpu_pipeline_cache.rs` (2 crashes in 1,575 runs) show one thread in `vkCreateDevice` and the other inside
/// the layer, called from a command being recorded or from a pipeline being destroyed, jumping to a small address.
/// A thread may hold several turns at once (a test that creates a second context while holding the first); other
/// threads wait until it has dropped them all.
pub fn one_at_a_time() -> Turn {
    let (lock, freed) = &TURN;
    let me = std::thread::current().id();
    // A test that panicked while holding a turn has failed already; the others may still run.
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
pub struct Turn(());

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

/// A test's context and its turn ([`one_at_a_time`]): the context is destroyed before the turn is given up. Reads as
/// the [`Context`] it holds.
pub struct GpuTest {
    ctx: Context,
    _turn: Turn,
}

impl std::ops::Deref for GpuTest {
    type Target = Context;
    fn deref(&self) -> &Context {
        &self.ctx
    }
}
