//! The convenience submission of a [`Context`]: record one command buffer, submit it, wait for it
//! ([`Context::submit_and_wait`]), with the count of host waits an engine checks its frame with.

use super::instance::lock;
use super::{vk_check, Context, Result};
use ash::vk;

impl Context {
    /// How many times the context's convenience paths ([`Context::submit_and_wait`] and everything built on it)
    /// have waited on the host for the device. An engine counts the waits inside its frame with it: the recording
    /// paths never wait.
    pub fn host_waits(&self) -> u64 {
        self.inner.host_waits.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// A command pool of the context's queue family, idle and owned by the caller until [`Context::put_pool`].
    fn take_pool(&self) -> Result<vk::CommandPool> {
        if let Some(pool) = lock(&self.inner.objects.pools).pop() {
            return Ok(pool);
        }
        let info = vk::CommandPoolCreateInfo::default()
            .queue_family_index(self.inner.queue_family)
            .flags(vk::CommandPoolCreateFlags::TRANSIENT);
        // SAFETY: valid device.
        vk_check("vkCreateCommandPool", unsafe { self.inner.device.create_command_pool(&info, self.inner.alloc()) })
    }

    /// Returns a pool taken by [`Context::take_pool`], reset (none of its command buffers is pending).
    fn put_pool(&self, pool: vk::CommandPool) {
        // SAFETY: no command buffer of the pool is pending (the caller waited or never submitted); the pool is
        // owned by this thread until it goes back to the list.
        let reset = unsafe { self.inner.device.reset_command_pool(pool, vk::CommandPoolResetFlags::empty()) };
        if reset.is_ok() {
            lock(&self.inner.objects.pools).push(pool);
        } else {
            // SAFETY: as above; a pool that cannot be reset is not reused.
            unsafe { self.inner.device.destroy_command_pool(pool, self.inner.alloc()) };
        }
    }

    /// Records one command buffer with `record`, submits it, waits for it, and returns what `record` returned.
    ///
    /// No lock is held while `record` runs or while the host waits: each call records into a command pool of its
    /// own (taken from an idle list), and the queue's mutex is held only around `vkQueueSubmit`. Every call counts
    /// in [`Context::host_waits`].
    pub fn submit_and_wait<T>(&self, record: impl FnOnce(&mut super::Recorder<'_>) -> Result<T>) -> Result<T> {
        let dev = &self.inner.device;
        let pool = self.take_pool()?;
        let result = (|| {
            let alloc = vk::CommandBufferAllocateInfo::default()
                .command_pool(pool)
                .level(vk::CommandBufferLevel::PRIMARY)
                .command_buffer_count(1);
            // SAFETY: the pool is owned by this call until put back.
            let cmd = vk_check("vkAllocateCommandBuffers", unsafe { dev.allocate_command_buffers(&alloc) })?[0];
            let begin = vk::CommandBufferBeginInfo::default().flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT);
            // SAFETY: fresh command buffer from our pool.
            vk_check("vkBeginCommandBuffer", unsafe { dev.begin_command_buffer(cmd, &begin) })?;
            // SAFETY: `cmd` is recording, from a pool of the context's compute family owned by this call; the
            // call waits for the submission before anything recorded can be freed by the caller.
            let mut rec = unsafe { super::Recorder::new(self, cmd) };
            let value = record(&mut rec)?;
            // SAFETY: recording state.
            vk_check("vkEndCommandBuffer", unsafe { dev.end_command_buffer(cmd) })?;
            // SAFETY: valid device.
            let fence_info = vk::FenceCreateInfo::default();
            // SAFETY: valid device.
            let fence = vk_check("vkCreateFence", unsafe { dev.create_fence(&fence_info, self.inner.alloc()) })?;
            let cmds = [cmd];
            let submit = [vk::SubmitInfo::default().command_buffers(&cmds)];
            let submitted = {
                let queue = lock(&self.inner.queue);
                // SAFETY: the queue is externally synchronized by its mutex; the command buffer is executable.
                vk_check("vkQueueSubmit", unsafe { dev.queue_submit(*queue, &submit, fence) })
            };
            let waited = submitted.and_then(|_| {
                self.inner.host_waits.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                // SAFETY: fence from this device; no lock is held while waiting.
                vk_check("vkWaitForFences", unsafe { dev.wait_for_fences(&[fence], true, u64::MAX) })
            });
            // SAFETY: the fence is signalled or was never submitted.
            unsafe { dev.destroy_fence(fence, self.inner.alloc()) };
            waited?;
            Ok(value)
        })();
        // The pool's command buffers are not pending (waited, or never submitted): resetting frees them.
        self.put_pool(pool);
        result
    }
}
