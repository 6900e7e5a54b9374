use super::context::Inner;
use super::{vk_check, Context, GpuError, Result};
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationCreateDesc, AllocationScheme};
use gpu_allocator::MemoryLocation;
use std::sync::Arc;

/// Where a buffer lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MemoryKind {
    /// Device-local memory for the kernels' arrays.
    DeviceLocal,
    /// Host-visible memory the host writes and the device reads (staging, small parameters).
    Upload,
    /// Host-visible, cached memory the device writes and the host reads back.
    Readback,
}

/// A buffer with its memory, usable as a storage buffer, a transfer source and destination, and through its device
/// address. Freed (buffer first, then memory) when dropped; it keeps its [`Context`] alive.
pub struct Buffer {
    ctx: Arc<Inner>,
    buffer: vk::Buffer,
    allocation: Option<Allocation>,
    size: u64,
    address: vk::DeviceAddress,
    kind: MemoryKind,
    name: String,
}

impl std::fmt::Debug for Buffer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Buffer").field("name", &self.name).field("size", &self.size).field("kind", &self.kind).finish()
    }
}

impl Buffer {
    /// The Vulkan handle.
    pub fn handle(&self) -> vk::Buffer {
        self.buffer
    }
    /// Size in bytes.
    pub fn size(&self) -> u64 {
        self.size
    }
    /// Device address (for `buffer_reference` access in shaders and for engines).
    pub fn address(&self) -> u64 {
        self.address
    }
    /// Memory kind.
    pub fn kind(&self) -> MemoryKind {
        self.kind
    }
    /// Debug name.
    pub fn name(&self) -> &str {
        &self.name
    }

    fn mapped(&self) -> Result<&[u8]> {
        let a = self.allocation.as_ref().ok_or_else(|| GpuError::Buffer(format!("{}: freed", self.name)))?;
        a.mapped_slice().ok_or_else(|| GpuError::Buffer(format!("{}: not host visible", self.name)))
    }

    /// Writes `data` at byte `offset` of a host-visible buffer.
    pub fn write<T: bytemuck::Pod>(&mut self, offset: u64, data: &[T]) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let end = offset.checked_add(bytes.len() as u64).filter(|&e| e <= self.size).ok_or_else(|| {
            GpuError::Buffer(format!(
                "{}: write of {} bytes at {offset} past its {} bytes",
                self.name,
                bytes.len(),
                self.size
            ))
        })?;
        let name = self.name.clone();
        let a = self.allocation.as_mut().ok_or_else(|| GpuError::Buffer(format!("{name}: freed")))?;
        let slice = a.mapped_slice_mut().ok_or_else(|| GpuError::Buffer(format!("{name}: not host visible")))?;
        slice[offset as usize..end as usize].copy_from_slice(bytes);
        Ok(())
    }

    /// Reads `count` elements of `T` from byte `offset` of a host-visible buffer.
    pub fn read<T: bytemuck::Pod>(&self, offset: u64, count: usize) -> Result<Vec<T>> {
        let bytes = (count * std::mem::size_of::<T>()) as u64;
        let end = offset.checked_add(bytes).filter(|&e| e <= self.size).ok_or_else(|| {
            GpuError::Buffer(format!("{}: read of {bytes} bytes at {offset} past its {} bytes", self.name, self.size))
        })?;
        let slice = &self.mapped()?[offset as usize..end as usize];
        // The mapping may not be aligned for T: copy through an owned vector.
        let mut out = vec![T::zeroed(); count];
        bytemuck::cast_slice_mut::<T, u8>(&mut out).copy_from_slice(slice);
        Ok(out)
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        // SAFETY: the buffer was created from this device; the caller guarantees the device no longer uses it
        // (every convenience path waits for its submission).
        unsafe { self.ctx.device.destroy_buffer(self.buffer, self.ctx.alloc()) };
        if let Some(a) = self.allocation.take() {
            if let Ok(mut allocator) = self.ctx.allocator() {
                let _ = allocator.free(a);
            }
        }
    }
}

impl Context {
    /// Creates a buffer of `size` bytes (at least 4, rounded up to a multiple of 4) in memory of `kind`.
    ///
    /// The device's limits, as queried, are honoured: a size above `maxBufferSize` (where reported) or
    /// `maxMemoryAllocationSize`, or a buffer whose memory requirements exceed `maxMemoryAllocationSize`, gives
    /// [`GpuError::Limit`]. Buffers of 64 MiB and more get a dedicated allocation of their own size; smaller ones
    /// share memory blocks of at most 256 MiB (64 MiB host-visible), which the context also keeps within
    /// `maxMemoryAllocationSize`. No allocation is ever larger than that limit.
    pub fn create_buffer(&self, name: &str, size: u64, kind: MemoryKind) -> Result<Buffer> {
        let size = size.max(4).next_multiple_of(4);
        let caps = &self.inner.caps;
        let limit = caps.max_buffer_size.unwrap_or(u64::MAX).min(caps.max_memory_allocation_size);
        if size > limit {
            return Err(GpuError::Limit { what: format!("buffer {name}"), requested: size, limit });
        }
        let dev = &self.inner.device;
        let alloc = self.inner.alloc();
        let mut usage = vk::BufferUsageFlags::STORAGE_BUFFER
            | vk::BufferUsageFlags::TRANSFER_SRC
            | vk::BufferUsageFlags::TRANSFER_DST
            | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS;
        if caps.ray_query {
            // Any buffer may hold geometry for, or be, a driver acceleration structure (crate::accel::driver).
            usage |= vk::BufferUsageFlags::ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_KHR
                | vk::BufferUsageFlags::ACCELERATION_STRUCTURE_STORAGE_KHR;
        }
        let info = vk::BufferCreateInfo::default().size(size).usage(usage).sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create info.
        let buffer = vk_check("vkCreateBuffer", unsafe { dev.create_buffer(&info, alloc) })?;
        // SAFETY: buffer from this device.
        let requirements = unsafe { dev.get_buffer_memory_requirements(buffer) };
        if requirements.size > caps.max_memory_allocation_size {
            // SAFETY: unbound buffer of ours.
            unsafe { dev.destroy_buffer(buffer, alloc) };
            let limit = caps.max_memory_allocation_size;
            return Err(GpuError::Limit {
                what: format!("memory of buffer {name}"),
                requested: requirements.size,
                limit,
            });
        }
        let location = match kind {
            MemoryKind::DeviceLocal => MemoryLocation::GpuOnly,
            MemoryKind::Upload => MemoryLocation::CpuToGpu,
            MemoryKind::Readback => MemoryLocation::GpuToCpu,
        };
        let large = size >= 64 << 20;
        let allocation = self.inner.allocator()?.allocate(&AllocationCreateDesc {
            name,
            requirements,
            location,
            linear: true,
            allocation_scheme: if large {
                AllocationScheme::DedicatedBuffer(buffer)
            } else {
                AllocationScheme::GpuAllocatorManaged
            },
        });
        let allocation = match allocation {
            Ok(a) => a,
            Err(source) => {
                // SAFETY: unbound buffer of ours.
                unsafe { dev.destroy_buffer(buffer, alloc) };
                return Err(GpuError::Alloc { name: name.into(), bytes: size, source });
            }
        };
        // SAFETY: memory allocated for this buffer's requirements.
        let bound = unsafe { dev.bind_buffer_memory(buffer, allocation.memory(), allocation.offset()) };
        if let Err(result) = bound {
            // SAFETY: as above.
            unsafe { dev.destroy_buffer(buffer, alloc) };
            if let Ok(mut allocator) = self.inner.allocator() {
                let _ = allocator.free(allocation);
            }
            return Err(GpuError::Vk { call: "vkBindBufferMemory", result });
        }
        // SAFETY: bound buffer with SHADER_DEVICE_ADDRESS usage; the feature is enabled.
        let address = unsafe { dev.get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(buffer)) };
        Ok(Buffer {
            ctx: self.inner.clone(),
            buffer,
            allocation: Some(allocation),
            size,
            address,
            kind,
            name: name.to_string(),
        })
    }

    /// Creates a device-local buffer holding `data` (through a staging buffer; submits and waits).
    pub fn upload<T: bytemuck::Pod>(&self, name: &str, data: &[T]) -> Result<Buffer> {
        let bytes = std::mem::size_of_val(data) as u64;
        let dst = self.create_buffer(name, bytes, MemoryKind::DeviceLocal)?;
        self.write_buffer(&dst, 0, data)?;
        Ok(dst)
    }

    /// Writes `data` into any buffer at byte `offset` (through a staging buffer when it is not host visible;
    /// submits and waits).
    pub fn write_buffer<T: bytemuck::Pod>(&self, dst: &Buffer, offset: u64, data: &[T]) -> Result<()> {
        let bytes = std::mem::size_of_val(data) as u64;
        if bytes == 0 {
            return Ok(());
        }
        if offset + bytes > dst.size() {
            return Err(GpuError::Buffer(format!("{}: write of {bytes} bytes at {offset} past its end", dst.name())));
        }
        let mut staging = self.create_buffer("staging", bytes, MemoryKind::Upload)?;
        staging.write(0, data)?;
        self.submit_and_wait(|rec| {
            rec.copy(&staging, 0, dst, offset, bytes);
            Ok(())
        })
    }

    /// Reads `count` elements of `T` from byte `offset` of any buffer (through a readback buffer; submits and
    /// waits).
    pub fn read_buffer<T: bytemuck::Pod>(&self, src: &Buffer, offset: u64, count: usize) -> Result<Vec<T>> {
        let bytes = (count * std::mem::size_of::<T>()) as u64;
        if count == 0 {
            return Ok(Vec::new());
        }
        if offset + bytes > src.size() {
            return Err(GpuError::Buffer(format!("{}: read of {bytes} bytes at {offset} past its end", src.name())));
        }
        let readback = self.create_buffer("readback", bytes, MemoryKind::Readback)?;
        self.submit_and_wait(|rec| {
            rec.copy(src, offset, &readback, 0, bytes);
            rec.host_read_barrier();
            Ok(())
        })?;
        readback.read(0, count)
    }
}
