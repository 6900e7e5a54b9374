//! Pipelines ready before work is timed: the crate's own pipeline-cache file (round trip; corrupted, truncated,
//! foreign files ignored with a warning), a host engine's pipeline cache and allocation callbacks through
//! `Context::from_raw` (every object created and destroyed with them), and the warm-up of `VulkanBackend::new`.
//! Runs on lavapipe with the validation layer on, one test at a time (`gpu_support::one_at_a_time`: these tests
//! create devices back to back, and the validation layer can crash when a device is created beside work on another).

use crate::gpu_support;

use ash::vk;
use meshchar::characterize::vulkan::VulkanBackend;
use meshchar::characterize::Params;
use meshchar::gpu::{enumerate_devices, required_device_features, Context, ContextDesc, RawDevice};
use meshchar::mesh::generate;
use std::ffi::c_void;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
use std::sync::Mutex;

/// A fresh directory for one test's files.
fn scratch_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("meshchar-pcache-{test}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch directory");
    dir
}

fn context_with_cache(path: &Path) -> Option<Context> {
    let desc = ContextDesc { validation: true, pipeline_cache: Some(path.to_path_buf()), ..Default::default() };
    match Context::new(&desc) {
        Ok(ctx) => Some(ctx),
        Err(e) => {
            assert!(std::env::var("REQUIRE_GPU").map_or(true, |v| v != "1"), "REQUIRE_GPU=1 but: {e}");
            eprintln!("skipping GPU test: {e}");
            None
        }
    }
}

/// A context that builds and warms every characterization pipeline through a cache saved to `path`; the saved
/// file's bytes.
fn saved_cache(path: &Path) -> Option<Vec<u8>> {
    let ctx = context_with_cache(path)?;
    assert!(ctx.warnings().is_empty(), "a missing file is no warning: {:?}", ctx.warnings());
    let backend = VulkanBackend::new(&ctx).expect("backend");
    let written = ctx.save_pipeline_cache().expect("save").expect("a context with a cache file writes it");
    let file = std::fs::read(path).expect("the file exists");
    assert_eq!(file.len(), written);
    drop(backend);
    gpu_support::assert_no_validation_messages(&ctx);
    Some(file)
}

/// The Vulkan data in a cache file (after the crate's 64-byte header).
const HEADER: usize = 64;

#[test]
fn pipeline_cache_round_trip() {
    let _apart = gpu_support::one_at_a_time();
    let dir = scratch_dir("round-trip");
    let path = dir.join("nested").join("pipelines.bin");
    let Some(file) = saved_cache(&path) else { return };
    assert!(file.len() >= HEADER + 32, "the file holds the driver's cache header at least: {} bytes", file.len());
    let ctx = context_with_cache(&path).expect("second context");
    assert!(ctx.warnings().is_empty(), "a valid file loads without warnings: {:?}", ctx.warnings());
    let data = ctx.pipeline_cache_data().expect("cache data");
    assert!(!data.is_empty(), "the loaded cache has data");
    assert_eq!(data[..32], file[HEADER..HEADER + 32], "the loaded cache has the saved Vulkan header");
    // Saving again replaces the file atomically and leaves no temporary file behind.
    let again = ctx.save_pipeline_cache().expect("save again").expect("written");
    assert_eq!(std::fs::metadata(&path).map(|m| m.len() as usize).ok(), Some(again));
    let entries = std::fs::read_dir(path.parent().expect("parent")).map(|r| r.count()).unwrap_or(0);
    assert_eq!(entries, 1, "only the cache file is left in its directory");
    gpu_support::assert_no_validation_messages(&ctx);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Loads `bytes` as a cache file: the context works, has an empty (header-only) cache, and warned once with
/// `reason` in the text.
fn assert_ignored(dir: &Path, name: &str, bytes: &[u8], reason: &str) {
    let path = dir.join(name);
    std::fs::write(&path, bytes).expect("write the test file");
    let ctx = context_with_cache(&path).expect("context");
    let w = ctx.warnings();
    assert_eq!(w.len(), 1, "{name}: one warning: {w:?}");
    assert!(w[0].contains(reason) && w[0].contains("using an empty cache"), "{name}: {w:?}");
    assert!(w[0].contains(&path.display().to_string()), "{name}: the warning names the file: {w:?}");
    assert!(!ctx.pipeline_cache_data().expect("data").is_empty(), "{name}: an empty cache still has its header");
    // Pipelines build and run through the empty cache.
    let mut backend = VulkanBackend::new(&ctx).expect("backend");
    let mesh = generate::random_soup(300, 7);
    backend.characterize(&mesh, &Params::default()).expect("characterize");
    drop(backend);
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn corrupted_and_truncated_files_are_ignored_with_a_warning() {
    let _apart = gpu_support::one_at_a_time();
    let dir = scratch_dir("corrupted");
    let Some(file) = saved_cache(&dir.join("valid.bin")) else { return };
    let mut corrupted = file.clone();
    let last = corrupted.len() - 1;
    corrupted[last] ^= 0x5a;
    assert_ignored(&dir, "corrupted.bin", &corrupted, "corrupted");
    assert_ignored(&dir, "truncated.bin", &file[..file.len() - 3], "truncated");
    assert_ignored(&dir, "header-only.bin", &file[..20], "not a meshchar pipeline cache");
    assert_ignored(&dir, "garbage.bin", b"this is not a pipeline cache at all, just some text", "not a meshchar");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_file_of_another_device_or_driver_is_ignored_with_a_warning() {
    let _apart = gpu_support::one_at_a_time();
    let dir = scratch_dir("foreign");
    let Some(file) = saved_cache(&dir.join("valid.bin")) else { return };
    // deviceUUID at bytes 16..32, driverUUID at 32..48 of the crate's header.
    let mut other_device = file.clone();
    other_device[16] ^= 0xff;
    assert_ignored(&dir, "other-device.bin", &other_device, "another device or driver");
    let mut other_driver = file.clone();
    other_driver[47] ^= 0xff;
    assert_ignored(&dir, "other-driver.bin", &other_driver, "another device or driver");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn warm_up_is_reported_apart() {
    let _apart = gpu_support::one_at_a_time();
    let Some(ctx) = gpu_support::context() else { return };
    let waits = ctx.host_waits();
    let mut backend = VulkanBackend::new(&ctx).expect("backend");
    assert!(backend.warmup_ms() > 0.0);
    assert!(ctx.host_waits() > waits, "the warm-up ran on the device");
    // No mesh is left behind: a feature pass needs a characterization of the caller's first.
    let mesh = generate::random_soup(500, 11);
    let (c, f) = backend.characterize_with_features(&mesh, &Params::default()).expect("characterize");
    assert_eq!(c.triangles, mesh.triangle_count() as u64);
    assert_eq!(Ok(f), meshchar::characterize::features_cpu(&mesh, &Params::default()).map_err(|e| e.to_string()));
    gpu_support::assert_no_validation_messages(&ctx);
}

// ---- A host engine's device, pipeline cache and allocation callbacks ----

/// Host allocations made through the test's callbacks that are not freed yet, and all made.
static LIVE: AtomicI64 = AtomicI64::new(0);
static TOTAL: AtomicU64 = AtomicU64::new(0);

/// Every allocation has `align.max(16)` bytes in front of it: its size and alignment just before the pointer.
fn layout(size: usize, align: usize) -> Option<std::alloc::Layout> {
    let align = align.max(16);
    std::alloc::Layout::from_size_align(size.checked_add(align)?, align).ok()
}

unsafe extern "system" fn allocate(
    _: *mut c_void,
    size: usize,
    align: usize,
    _: vk::SystemAllocationScope,
) -> *mut c_void {
    let Some(l) = layout(size, align) else { return std::ptr::null_mut() };
    // SAFETY: non-zero layout; the header fits in front of the returned pointer (at least 16 bytes, aligned).
    unsafe {
        let base = std::alloc::alloc(l);
        if base.is_null() {
            return base.cast();
        }
        let p = base.add(l.align());
        p.cast::<usize>().sub(1).write(l.align());
        p.cast::<usize>().sub(2).write(size);
        LIVE.fetch_add(1, Ordering::SeqCst);
        TOTAL.fetch_add(1, Ordering::SeqCst);
        p.cast()
    }
}

unsafe extern "system" fn free(_: *mut c_void, p: *mut c_void) {
    if p.is_null() {
        return;
    }
    // SAFETY: `p` came from `allocate`, which wrote its header.
    unsafe {
        let p = p.cast::<u8>();
        let (align, size) = (p.cast::<usize>().sub(1).read(), p.cast::<usize>().sub(2).read());
        if let Some(l) = layout(size, align) {
            std::alloc::dealloc(p.sub(align), l);
            LIVE.fetch_sub(1, Ordering::SeqCst);
        }
    }
}

unsafe extern "system" fn reallocate(
    user: *mut c_void,
    p: *mut c_void,
    size: usize,
    align: usize,
    scope: vk::SystemAllocationScope,
) -> *mut c_void {
    // SAFETY: Vulkan's reallocation rules on top of `allocate` and `free`.
    unsafe {
        if p.is_null() {
            return allocate(user, size, align, scope);
        }
        if size == 0 {
            free(user, p);
            return std::ptr::null_mut();
        }
        let new = allocate(user, size, align, scope);
        if !new.is_null() {
            let old = p.cast::<usize>().sub(2).read();
            std::ptr::copy_nonoverlapping(p.cast::<u8>(), new.cast::<u8>(), old.min(size));
            free(user, p);
        }
        new
    }
}

static MESSAGES: Mutex<Vec<String>> = Mutex::new(Vec::new());

unsafe extern "system" fn record_message(
    _: vk::DebugUtilsMessageSeverityFlagsEXT,
    _: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    _: *mut c_void,
) -> vk::Bool32 {
    // SAFETY: the layer passes valid callback data.
    let text = unsafe { data.as_ref().and_then(|d| d.message_as_c_str()) }
        .map(|m| m.to_string_lossy().into_owned())
        .unwrap_or_default();
    if let Ok(mut m) = MESSAGES.lock() {
        m.push(text);
    }
    vk::FALSE
}

#[test]
fn engine_pipeline_cache_and_allocation_callbacks() {
    let _apart = gpu_support::one_at_a_time();
    // The machine's device with meshchar's own context first: skip (or fail under REQUIRE_GPU) like every test.
    if gpu_support::context().is_none() {
        return;
    }
    let (list, selected) = enumerate_devices().expect("devices");
    let summary = &list[selected.expect("a usable device")];
    let family = summary.caps.queue_family.expect("a compute queue");
    // SAFETY (whole test): the engine's side, plain Vulkan; every object is destroyed after its users.
    unsafe {
        let entry = ash::Entry::load().expect("loader");
        let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_2);
        let layers = [c"VK_LAYER_KHRONOS_validation".as_ptr()];
        let exts = [ash::ext::debug_utils::NAME.as_ptr()];
        let info = vk::InstanceCreateInfo::default()
            .application_info(&app)
            .enabled_layer_names(&layers)
            .enabled_extension_names(&exts);
        let instance = entry.create_instance(&info, None).expect("instance with the validation layer");
        let du = ash::ext::debug_utils::Instance::new(&entry, &instance);
        let messenger_info = vk::DebugUtilsMessengerCreateInfoEXT::default()
            .message_severity(
                vk::DebugUtilsMessageSeverityFlagsEXT::WARNING | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
            )
            .message_type(
                vk::DebugUtilsMessageTypeFlagsEXT::GENERAL
                    | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                    | vk::DebugUtilsMessageTypeFlagsEXT::PERFORMANCE,
            )
            .pfn_user_callback(Some(record_message));
        let messenger = du.create_debug_utils_messenger(&messenger_info, None).expect("messenger");
        let pdev = instance.enumerate_physical_devices().expect("physical devices")[summary.index];

        let priorities = [1.0f32];
        let queues = [vk::DeviceQueueCreateInfo::default().queue_family_index(family).queue_priorities(&priorities)];
        let mut core = vk::PhysicalDeviceFeatures::default();
        let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
        required_device_features(&mut core, &mut v12);
        let mut f2 = vk::PhysicalDeviceFeatures2::default().features(core).push_next(&mut v12);
        let dinfo = vk::DeviceCreateInfo::default().queue_create_infos(&queues).push_next(&mut f2);
        let device = instance.create_device(pdev, &dinfo, None).expect("engine device");
        let engine_cache =
            device.create_pipeline_cache(&vk::PipelineCacheCreateInfo::default(), None).expect("engine cache");

        let callbacks = vk::AllocationCallbacks::default()
            .pfn_allocation(Some(allocate))
            .pfn_reallocation(Some(reallocate))
            .pfn_free(Some(free));
        let (live0, total0) = (LIVE.load(Ordering::SeqCst), TOTAL.load(Ordering::SeqCst));
        let raw = RawDevice {
            pipeline_cache: engine_cache,
            allocation_callbacks: Some(callbacks),
            ..RawDevice::new(instance.clone(), device.clone(), pdev, family, 0)
        };
        // SAFETY: the device has the required features and a compute queue at (family, 0); the engine's cache and
        // callbacks outlive the context; the test uses the queue only through the context.
        let ctx = Context::from_raw(raw).expect("context on the engine's device");
        assert_eq!(ctx.pipeline_cache(), engine_cache, "kernels are created through the engine's cache");
        assert_eq!(ctx.save_pipeline_cache().expect("save"), None, "the engine saves its own cache");
        assert!(ctx.warnings().is_empty());
        {
            // Kernels, pipeline layouts, shader modules, buffers, query pools, command pools and fences.
            let mut backend = VulkanBackend::new(&ctx).expect("backend");
            let mesh = generate::random_soup(300, 7);
            backend.characterize_with_features(&mesh, &Params::default()).expect("characterize");
            assert!(TOTAL.load(Ordering::SeqCst) > total0, "the context allocates through the engine's callbacks");
            assert!(LIVE.load(Ordering::SeqCst) > live0, "its objects live in the engine's host memory");
        }
        assert!(!ctx.pipeline_cache_data().expect("data").is_empty());
        drop(ctx);
        assert_eq!(LIVE.load(Ordering::SeqCst), live0, "everything created with the callbacks was destroyed with them");
        assert!(!device.get_pipeline_cache_data(engine_cache).expect("engine cache data").is_empty());
        device.destroy_pipeline_cache(engine_cache, None);
        device.destroy_device(None);
        du.destroy_debug_utils_messenger(messenger, None);
        instance.destroy_instance(None);
    }
    let m = MESSAGES.lock().map(|m| m.clone()).unwrap_or_default();
    assert!(m.is_empty(), "{} validation message(s):\n{}", m.len(), m.join("\n"));
}
