//! The Vulkan instance of an owned context, the debug messenger that records the validation layer's messages, the
//! engine's allocation callbacks, and the guard ([`Objects`]) that destroys every object a context made, in order.

use super::{vk_check, GpuError, Result};
use ash::vk;
use gpu_allocator::vulkan::Allocator;
use std::ffi::{c_void, CStr};
use std::sync::{Arc, Mutex, MutexGuard};

const VALIDATION_LAYER: &CStr = c"VK_LAYER_KHRONOS_validation";

pub(super) type Messages = Arc<Mutex<Vec<String>>>;
type Messenger = (ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT);

/// The host engine's allocation callbacks ([`RawDevice::allocation_callbacks`]; none for owned contexts), passed
/// to every create and destroy call the context and its buffers, kernels and timers make.
#[derive(Clone, Copy, Default)]
pub(crate) struct HostAllocator(pub(super) Option<vk::AllocationCallbacks<'static>>);

// SAFETY: the callbacks are plain function pointers and the engine's `pUserData`; `Context::from_raw`'s contract
// requires that they may be called from any thread, concurrently, and that `pUserData` stays valid as long as the
// context and everything made from it. The context never dereferences `pUserData` itself: it only hands the struct
// to Vulkan calls. (ash declares `AllocationCallbacks` Send and Sync unconditionally; this impl states the reason
// here instead of relying on that.)
unsafe impl Send for HostAllocator {}
// SAFETY: as above; the struct is never mutated after creation.
unsafe impl Sync for HostAllocator {}

impl HostAllocator {
    /// The callbacks to pass to a create or destroy call.
    pub(crate) fn get(&self) -> Option<&vk::AllocationCallbacks<'static>> {
        self.0.as_ref()
    }
}

/// Whether a context destroys its device.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Ownership {
    /// Created by the context ([`Context::new`]).
    Owned,
    /// A host engine's ([`Context::from_raw`]): never destroyed here.
    Borrowed,
}

/// Every Vulkan object a context made, the guard that destroys them: each is recorded here as soon as it exists,
/// so an error at any step of creation just returns and drops the guard, and a finished context drops it last.
/// Drop destroys in reverse order of creation: it waits for the device, frees the allocator's memory, destroys the
/// command pools and the context's own pipeline cache, then what the context owns: the device, the debug messenger,
/// the instance; then frees the message
/// sink the messengers write into, which must outlive `vkDestroyInstance` (the messenger chained to the instance's
/// creation may report during it); the loader is unloaded last.
#[derive(Default)]
pub(super) struct Objects {
    /// The Vulkan loader (owned contexts).
    pub(super) entry: Option<ash::Entry>,
    /// The boxed [`Messages`] the debug messengers get as user data (null without validation).
    pub(super) sink: Option<std::ptr::NonNull<Messages>>,
    /// The instance, when the context created it.
    pub(super) instance: Option<ash::Instance>,
    /// The debug messenger on that instance.
    pub(super) messenger: Option<Messenger>,
    /// The device the pool and allocator belong to, and whether the context created it.
    pub(super) device: Option<(ash::Device, Ownership)>,
    /// The idle command pools of the convenience submissions (one per submission in progress, reused after).
    pub(super) pools: Mutex<Vec<vk::CommandPool>>,
    /// The pipeline cache the context created ([`Context::new`]); an engine's cache is never destroyed here.
    pub(super) own_cache: Option<vk::PipelineCache>,
    /// The engine's allocation callbacks, for every create and destroy call.
    pub(super) host_alloc: HostAllocator,
    /// The allocator.
    pub(super) allocator: Option<Mutex<Allocator>>,
}

// SAFETY: the sink pointer is a boxed Arc only touched at creation and destruction, and by the driver's callback,
// which only locks the mutex inside it; everything else is Vulkan handles and ash's function tables.
unsafe impl Send for Objects {}
unsafe impl Sync for Objects {}

impl Drop for Objects {
    fn drop(&mut self) {
        // SAFETY: every buffer, kernel and timer holds an Arc<Inner>, so none is alive when the context's objects
        // go; the device is idle after the wait; each object is destroyed once, after everything made from it.
        unsafe {
            if let Some((device, ownership)) = &self.device {
                let _ = device.device_wait_idle();
                drop(self.allocator.take());
                let alloc = self.host_alloc.get();
                for pool in lock(&self.pools).drain(..) {
                    device.destroy_command_pool(pool, alloc);
                }
                if let Some(cache) = self.own_cache.take() {
                    device.destroy_pipeline_cache(cache, alloc);
                }
                if *ownership == Ownership::Owned {
                    device.destroy_device(None);
                }
            }
            if let Some((du, messenger)) = self.messenger.take() {
                du.destroy_debug_utils_messenger(messenger, None);
            }
            if let Some(instance) = &self.instance {
                instance.destroy_instance(None);
            }
            if let Some(sink) = self.sink.take() {
                drop(Box::from_raw(sink.as_ptr()));
            }
        }
        // `entry` drops after this, unloading the loader when nothing uses it any more.
    }
}

impl Objects {
    /// Loads Vulkan and creates an instance (with the validation layer and a messenger recording its warnings and
    /// errors when `validation`); the guard and the messages the messenger records.
    pub(super) fn with_instance(validation: bool) -> Result<(Objects, Messages)> {
        let mut o = Objects::default();
        // SAFETY: loading the system Vulkan loader library; ash checks the symbols it resolves.
        let entry = unsafe { ash::Entry::load() }.map_err(|e| GpuError::Loader(e.to_string()))?;
        // The guard keeps the loader loaded until everything made from it is destroyed.
        o.entry = Some(entry.clone());
        let messages: Messages = Arc::new(Mutex::new(Vec::new()));
        // SAFETY: plain queries of the loader.
        let loader_version =
            unsafe { entry.try_enumerate_instance_version() }.ok().flatten().unwrap_or(vk::API_VERSION_1_0);
        if vk::api_version_major(loader_version) == 1 && vk::api_version_minor(loader_version) < 2 {
            return Err(GpuError::Unsupported {
                name: "Vulkan loader".into(),
                missing: vec![format!(
                    "Vulkan 1.2 instance (loader supports {}.{})",
                    vk::api_version_major(loader_version),
                    vk::api_version_minor(loader_version)
                )],
            });
        }
        let api = if vk::api_version_minor(loader_version) >= 3 { vk::API_VERSION_1_3 } else { vk::API_VERSION_1_2 };
        let app =
            vk::ApplicationInfo::default().application_name(c"meshchar").engine_name(c"meshchar").api_version(api);
        let mut layers = Vec::new();
        let mut exts = Vec::new();
        if validation {
            // SAFETY: plain query.
            let available = unsafe { entry.enumerate_instance_layer_properties() }.unwrap_or_default();
            if !available.iter().any(|l| l.layer_name_as_c_str().is_ok_and(|n| n == VALIDATION_LAYER)) {
                return Err(GpuError::NoValidationLayer);
            }
            layers.push(VALIDATION_LAYER.as_ptr());
            exts.push(ash::ext::debug_utils::NAME.as_ptr());
            o.sink = Some(std::ptr::NonNull::from(Box::leak(Box::new(messages.clone()))));
        }
        let user = o.sink.map_or(std::ptr::null_mut(), |p| p.as_ptr() as *mut c_void);
        let messenger_info = || {
            vk::DebugUtilsMessengerCreateInfoEXT::default()
                .message_severity(
                    vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
                )
                .message_type(
                    vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                        | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                        | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
                )
                .pfn_user_callback(Some(debug_callback))
                .user_data(user)
        };
        // Chained to the instance's creation, this messenger also reports during vkCreateInstance and
        // vkDestroyInstance.
        let mut chained = messenger_info();
        let mut info = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&exts);
        if validation {
            info = info.push_next(&mut chained);
        }
        // SAFETY: the create info and everything it points to live until the call returns; the sink outlives the
        // instance (see Drop).
        let instance = vk_check("vkCreateInstance", unsafe { entry.create_instance(&info, None) })?;
        o.instance = Some(instance.clone());
        if validation {
            let du = ash::ext::debug_utils::Instance::new(&entry, &instance);
            // SAFETY: valid instance with VK_EXT_debug_utils enabled; the sink outlives the messenger.
            let m = vk_check("vkCreateDebugUtilsMessengerEXT", unsafe {
                du.create_debug_utils_messenger(&messenger_info(), None)
            })?;
            o.messenger = Some((du, m));
        }
        Ok((o, messages))
    }

    pub(super) fn instance(&self) -> Result<&ash::Instance> {
        self.instance.as_ref().ok_or_else(|| GpuError::Buffer("context: no instance".into()))
    }
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    types: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    if data.is_null() || user.is_null() {
        return vk::FALSE;
    }
    // SAFETY: the driver passes a valid callback data pointer; `user` is the boxed Arc created with the messenger.
    let (data, messages) = unsafe { (&*data, &*(user as *const Messages)) };
    let text = if data.p_message.is_null() {
        String::new()
    } else {
        // SAFETY: p_message is a NUL-terminated string when not null.
        unsafe { CStr::from_ptr(data.p_message) }.to_string_lossy().into_owned()
    };
    if let Ok(mut m) = messages.lock() {
        m.push(format!("[{severity:?} {types:?}] {text}"));
    }
    vk::FALSE
}

pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}
