//! The driver's acceleration structures (`meshchar::accel::driver`): built over geometry views with every
//! build-flag choice, compacted, updated over an animation, and traced with ray queries whose hits are checked
//! against the CPU reference. With the validation layer on; under `REQUIRE_GPU=1` a device without ray queries is
//! a failure (CI installs lavapipe from Mesa 25, which has them).

use crate::common;
use crate::gpu_support;

use meshchar::accel::device_trace::TraceRay;
use meshchar::accel::driver::{hit_agrees, DriverBuilder, DriverFlags};
use meshchar::accel::{build_structure, AccelStructure, StructureName};
use meshchar::geom::Camera;
use meshchar::geom::{Ray, TraceCounters, WorkloadKind};
use meshchar::gpu::{Context, MeshBuffers};
use meshchar::mesh::{generate, load::load_mesh, Mesh};
use meshchar::trace::workload::{build_workload, mesh_bounds};

/// A context with ray queries, or `None` (skip) when the device has none and `REQUIRE_GPU` is not `1`.
fn ray_query_context() -> Option<gpu_support::GpuTest> {
    let ctx = gpu_support::context()?;
    if !ctx.caps().ray_query {
        if std::env::var("REQUIRE_GPU").is_ok_and(|v| v == "1") {
            panic!(
                "REQUIRE_GPU=1 but {} ({}) has no VK_KHR_acceleration_structure / VK_KHR_ray_query (lavapipe has them from Mesa 24.1; scripts/setup installs Mesa 25 from Debian backports)",
                ctx.caps().name,
                ctx.caps().driver
            );
        }
        eprintln!("skipping: no ray queries on {}", ctx.caps().name);
        return None;
    }
    Some(ctx)
}

/// Rays whose hits disagree with the CPU reference: another triangle at a `t` more than `1e-4 t + 1e-6 extent`
/// away, or a hit where the other misses away from the hit triangle's edges (any-hit rays: occluded or not).
fn disagreements(
    reference: &dyn AccelStructure,
    rays: &[Ray],
    any: bool,
    hits: &[meshchar::accel::device_trace::TraceHit],
    extent: f32,
) -> usize {
    let mut bad = 0;
    for (r, h) in rays.iter().zip(hits) {
        let mut c = TraceCounters::default();
        if any {
            bad += usize::from(reference.occluded(r, &mut c) != h.hit().is_some());
            continue;
        }
        let want = reference.intersect(r, &mut c);
        bad += usize::from(!hit_agrees(want, h.hit(), extent));
    }
    bad
}

fn check_scene(ctx: &Context, builder: &DriverBuilder, name: &str, mesh: &Mesh, res: u32) {
    let buffers = MeshBuffers::upload(ctx, &mesh.positions, &mesh.indices).unwrap();
    let view = buffers.view();
    let bounds = mesh_bounds(mesh);
    let extent = bounds.extent().max_element();
    let camera = Camera::frame(&bounds);
    let reference = build_structure(StructureName::Bvh, mesh).unwrap();
    for flags in DriverFlags::ALL {
        let s = builder.build(&view, flags).unwrap_or_else(|e| panic!("{name} {}: {e}", flags.name()));
        assert!(s.gpu_ms() > 0.0 && s.built_bytes() > 0, "{name} {}: {s:?} {:?}", flags.name(), s.timings());
        if flags.compacts() {
            let c = s.compacted_bytes().expect("compacted size");
            assert!(c > 0 && c <= s.built_bytes(), "{name}: compacted {c} of {}", s.built_bytes());
        }
        for kind in [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse] {
            let set = build_workload(kind, mesh, &camera, res, reference.as_ref());
            let dev: Vec<TraceRay> = set.rays.iter().map(TraceRay::from).collect();
            let out = builder.trace(&s, &dev, set.any_hit).unwrap();
            let bad = disagreements(reference.as_ref(), &set.rays, set.any_hit, &out.hits, extent);
            let hits = out.hits.iter().filter(|h| h.hit().is_some()).count();
            let mut c = TraceCounters::default();
            let want = set
                .rays
                .iter()
                .filter(|r| {
                    if set.any_hit {
                        reference.occluded(r, &mut c)
                    } else {
                        reference.intersect(r, &mut c).is_some()
                    }
                })
                .count();
            assert_eq!(hits > 0, want > 0, "{name} {} {kind:?}: {hits} hits, the reference {want}", flags.name());
            // Edge and silhouette rays may go either way between two watertight-enough tests: at most 0.2%.
            assert!(
                bad * 500 <= set.rays.len(),
                "{name} {} {kind:?}: {bad} of {} rays disagree",
                flags.name(),
                set.rays.len()
            );
        }
    }
}

#[test]
fn driver_structures_trace_like_the_cpu_reference() {
    let Some(ctx) = ray_query_context() else { return };
    let builder = DriverBuilder::new(&ctx).expect("builder");
    for rel in ["stanford-bunny/bun_zipper.ply", "dabrovic-sponza/sponza.obj", "small/teapot-pd.obj"] {
        let mesh = load_mesh(&common::shared_mesh(rel)).unwrap();
        check_scene(&ctx, &builder, rel, &mesh, 64);
    }
    check_scene(&ctx, &builder, "soup", &generate::random_soup(5000, 3), 48);
    check_scene(&ctx, &builder, "single", &generate::single_triangle(), 16);
    gpu_support::assert_no_validation_messages(&ctx);
}

/// A view as an engine's: interleaved vertices (32-byte stride), the mesh after other vertices in the buffer, its
/// indices relative to its own first vertex and a base vertex adding the offset (vkCmdDrawIndexed's
/// vertexOffset), 32-bit and 16-bit: every flag set's hits equal the CPU reference of the mesh alone.
#[test]
fn a_view_with_a_base_vertex_and_a_stride_traces_its_own_vertices() {
    use meshchar::gpu::{GeometryView, IndexType};
    let Some(ctx) = ray_query_context() else { return };
    let builder = DriverBuilder::new(&ctx).expect("builder");
    let mesh = load_mesh(&common::shared_mesh("small/teapot-pd.obj")).unwrap();
    let before = 137u32;
    // Vertices: `before` others (far away, so that reading them instead would be seen), then the mesh's; each
    // vertex is 8 floats, position first.
    let mut floats = Vec::new();
    for k in 0..before {
        floats.extend_from_slice(&[100.0 + k as f32, -50.0, 75.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
    }
    for p in &mesh.positions {
        floats.extend_from_slice(&[p[0], p[1], p[2], 0.0, 0.0, 1.0, 0.5, 0.5]);
    }
    let vertices = ctx.upload("vertices", &floats).unwrap();
    let u32s: Vec<u32> = mesh.indices.iter().flatten().copied().collect();
    let mut u16s: Vec<u16> = u32s.iter().map(|&i| i as u16).collect();
    if u16s.len() % 2 == 1 {
        u16s.push(0);
    }
    let idx32 = ctx.upload("indices32", &u32s).unwrap();
    let idx16 = ctx.upload("indices16", &u16s).unwrap();
    let bounds = mesh_bounds(&mesh);
    let camera = Camera::frame(&bounds);
    let rays: Vec<Ray> = (0..48 * 48).map(|k| camera.ray(k % 48, k / 48, 48, 48)).collect();
    let dev: Vec<TraceRay> = rays.iter().map(TraceRay::from).collect();
    let reference = build_structure(StructureName::Bvh, &mesh).unwrap();
    let want_hits = rays.iter().filter(|r| reference.intersect(r, &mut TraceCounters::default()).is_some()).count();
    assert!(want_hits > 100, "the camera sees the mesh: {want_hits} hits");
    let vertex_count = u64::from(before) + mesh.positions.len() as u64;
    for (buffer, t) in [(&idx32, IndexType::U32), (&idx16, IndexType::U16)] {
        // SAFETY: both buffers live to the end of the test, hold the vertices and indices counted, and nothing
        // writes them after the upload.
        let view = unsafe {
            GeometryView::from_addresses(
                vertices.address(),
                32,
                vertex_count,
                Some((buffer.address(), t, before)),
                mesh.triangle_count() as u64,
            )
        }
        .unwrap();
        for flags in DriverFlags::ALL {
            let s = builder.build(&view, flags).unwrap();
            let out = builder.trace(&s, &dev, false).unwrap();
            let bad = disagreements(reference.as_ref(), &rays, false, &out.hits, bounds.extent().max_element());
            assert_eq!(bad, 0, "{t:?} {}: {bad} of {} rays disagree", flags.name(), rays.len());
            assert_eq!(out.hits.iter().filter(|h| h.hit().is_some()).count(), want_hits, "{t:?} {}", flags.name());
        }
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// `rt_update` over the frames of an animation (vertices moved in place, same topology): after each update the
/// hits equal the CPU reference of that frame; structures built without ALLOW_UPDATE refuse an update.
#[test]
fn an_updated_driver_structure_follows_the_animation() {
    let Some(ctx) = ray_query_context() else { return };
    let builder = DriverBuilder::new(&ctx).expect("builder");
    let base = load_mesh(&common::shared_mesh("small/bunny-lowres-pd.obj")).unwrap();
    let buffers = MeshBuffers::upload(&ctx, &base.positions, &base.indices).unwrap();
    let mut s = builder.build(&buffers.view(), DriverFlags::Update).unwrap();
    let fixed = builder.build(&buffers.view(), DriverFlags::FastTrace).unwrap();
    let mut fixed = fixed;
    assert!(builder.update(&buffers.view(), &mut fixed).is_err(), "an update without ALLOW_UPDATE is refused");
    for frame in 1..4 {
        let mut mesh = base.clone();
        let k = frame as f32 * 0.05;
        for p in mesh.positions.iter_mut() {
            p[0] += k * p[1];
            p[2] += k * p[1] * p[1];
        }
        let moved = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
        builder.update(&moved.view(), &mut s).unwrap();
        assert!(s.timings().iter().any(|(n, _)| n == "blas_update"), "{:?}", s.timings());
        let bounds = mesh_bounds(&mesh);
        let reference = build_structure(StructureName::Bvh, &mesh).unwrap();
        let set = build_workload(WorkloadKind::Primary, &mesh, &Camera::frame(&bounds), 48, reference.as_ref());
        let dev: Vec<TraceRay> = set.rays.iter().map(TraceRay::from).collect();
        let out = builder.trace(&s, &dev, false).unwrap();
        let bad = disagreements(reference.as_ref(), &set.rays, false, &out.hits, bounds.extent().max_element());
        assert!(bad * 500 <= set.rays.len(), "frame {frame}: {bad} of {} rays disagree", set.rays.len());
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

/// The oracle over a three-frame animation: `rt_update` is built on frame 0 and updated on the next, `rt_fast_trace`
/// rebuilt on each; both report one build and one trace time per frame and agree with the CPU reference.
#[test]
fn the_oracle_follows_an_animation_with_update_and_rebuild() {
    use meshchar::eval::oracle::{evaluate_scene_on, DeviceOracle, OracleConfig, Rebuild};
    let Some(ctx) = ray_query_context() else { return };
    let base = load_mesh(&common::shared_mesh("small/spot.obj")).unwrap();
    let frames: Vec<Mesh> = (0..3)
        .map(|f| {
            let mut m = base.clone();
            for p in m.positions.iter_mut() {
                p[1] += 0.1 * f as f32 * p[0];
            }
            m
        })
        .collect();
    let scene = meshchar::mesh::Animation { name: "bent spot".into(), frames };
    let config = OracleConfig {
        resolution: 24,
        repeats: 2,
        rebuild: Rebuild::PerFrame,
        structures: vec![StructureName::Bvh],
        driver: vec![DriverFlags::Update, DriverFlags::FastTrace],
        ..Default::default()
    };
    let device = DeviceOracle::new(&ctx).unwrap();
    let e = evaluate_scene_on(&scene, &config, None, &|_| {}, Some(&device)).unwrap();
    assert_eq!(e.driver_structures.len(), 2);
    for (d, per_frame) in e.driver_structures.iter().zip(["update", "rebuild"]) {
        assert!(d.valid && d.hits_agree, "{d:?}");
        assert_eq!(d.per_frame, per_frame);
        assert_eq!((d.frame_build_ms.len(), d.frame_trace_ms.len()), (3, 3), "{d:?}");
        assert!(d.frame_build_ms.iter().chain(&d.frame_trace_ms).all(|&ms| ms > 0.0), "{d:?}");
        let sum: f64 = d.frame_build_ms.iter().sum();
        assert!(
            sum <= d.build_ms * 1.5 + 1.0 && sum >= d.build_ms * 0.5 - 1.0,
            "per-frame builds {sum} vs {}",
            d.build_ms
        );
        assert_eq!(d.rays, 3 * 24 * 24, "every frame's rays, first repeat");
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

static ENGINE_MESSAGES: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

unsafe extern "system" fn engine_message(
    _: ash::vk::DebugUtilsMessageSeverityFlagsEXT,
    _: ash::vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const ash::vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    _: *mut std::ffi::c_void,
) -> ash::vk::Bool32 {
    // SAFETY: the layer passes valid callback data.
    let text = unsafe { data.as_ref().and_then(|d| d.message_as_c_str()) }
        .map(|m| m.to_string_lossy().into_owned())
        .unwrap_or_default();
    if let Ok(mut m) = ENGINE_MESSAGES.lock() {
        m.push(text);
    }
    ash::vk::FALSE
}

/// An engine creates its device with `ray_tracing_device_extensions` and `ray_tracing_device_features` beside the
/// required ones and says so (`RawDevice::ray_query_enabled`): the context reports ray queries and the driver
/// structures build and trace on it; the same device handed over without the flag gets no ray queries, and the
/// builder refuses with the reason. With the validation layer on the engine's instance, silent.
#[test]
fn an_engine_device_with_ray_queries_builds_driver_structures() {
    use ash::vk;
    use meshchar::gpu::{
        enumerate_devices, ray_tracing_device_extensions, ray_tracing_device_features, required_device_features,
        RawDevice,
    };
    let Some(own) = ray_query_context() else { return };
    drop(own);
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
            .message_type(vk::DebugUtilsMessageTypeFlagsEXT::GENERAL | vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION)
            .pfn_user_callback(Some(engine_message));
        let messenger = du.create_debug_utils_messenger(&messenger_info, None).expect("messenger");
        let pdev = instance.enumerate_physical_devices().expect("physical devices")[summary.index];
        let priorities = [1.0f32];
        let queues = [vk::DeviceQueueCreateInfo::default().queue_family_index(family).queue_priorities(&priorities)];
        let mut core = vk::PhysicalDeviceFeatures::default();
        let mut v12 = vk::PhysicalDeviceVulkan12Features::default();
        required_device_features(&mut core, &mut v12);
        let mut f_as = vk::PhysicalDeviceAccelerationStructureFeaturesKHR::default();
        let mut f_rq = vk::PhysicalDeviceRayQueryFeaturesKHR::default();
        let names = ray_tracing_device_features(&mut f_as, &mut f_rq);
        assert!(names.contains(&"rayQuery") && names.contains(&"accelerationStructure"), "{names:?}");
        let mut f2 = vk::PhysicalDeviceFeatures2::default()
            .features(core)
            .push_next(&mut v12)
            .push_next(&mut f_as)
            .push_next(&mut f_rq);
        let ext: Vec<*const std::ffi::c_char> = ray_tracing_device_extensions().iter().map(|e| e.as_ptr()).collect();
        let dinfo = vk::DeviceCreateInfo::default()
            .queue_create_infos(&queues)
            .enabled_extension_names(&ext)
            .push_next(&mut f2);
        let device = instance.create_device(pdev, &dinfo, None).expect("engine device with ray queries");
        {
            let raw = RawDevice {
                ray_query_enabled: true,
                ..RawDevice::new(instance.clone(), device.clone(), pdev, family, 0)
            };
            // SAFETY: created with the required and the ray-tracing features and extensions, a compute queue at
            // (family, 0); the test uses the queue only through the context.
            let ctx = meshchar::gpu::Context::from_raw(raw).expect("context");
            assert!(ctx.caps().ray_query, "the engine enabled ray queries");
            let builder = DriverBuilder::new(&ctx).expect("builder");
            let mesh = generate::random_soup(400, 9);
            let buffers = MeshBuffers::upload(&ctx, &mesh.positions, &mesh.indices).unwrap();
            // Recorded into a command buffer of the engine's own: meshchar submits and waits for nothing.
            let waits = ctx.host_waits();
            let mut s = gpu_support::in_caller_command_buffer(&ctx, |rec| {
                builder.record_build(rec, &buffers.view(), DriverFlags::FastBuild)
            })
            .expect("build");
            assert_eq!(ctx.host_waits(), waits, "recording a build waits for nothing");
            s.finish().expect("timestamps");
            assert!(s.gpu_ms() > 0.0);
            let camera = Camera::frame(&mesh_bounds(&mesh));
            let rays: Vec<Ray> = (0..256).map(|k| camera.ray(k % 16, k / 16, 16, 16)).collect();
            let dev: Vec<TraceRay> = rays.iter().map(TraceRay::from).collect();
            let out = builder.trace(&s, &dev, false).expect("trace");
            let reference = build_structure(StructureName::Bvh, &mesh).unwrap();
            let bad =
                disagreements(reference.as_ref(), &rays, false, &out.hits, mesh_bounds(&mesh).extent().max_element());
            assert_eq!(bad, 0, "hits on the engine's device");
        }
        {
            let raw = RawDevice::new(instance.clone(), device.clone(), pdev, family, 0);
            // SAFETY: as above.
            let ctx = meshchar::gpu::Context::from_raw(raw).expect("context");
            assert!(!ctx.caps().ray_query, "not enabled by the engine: not used");
            let e = DriverBuilder::new(&ctx).expect_err("no ray queries");
            assert!(e.to_string().contains("VK_KHR_ray_query"), "{e}");
        }
        device.destroy_device(None);
        du.destroy_debug_utils_messenger(messenger, None);
        instance.destroy_instance(None);
    }
    let m = ENGINE_MESSAGES.lock().unwrap();
    assert!(m.is_empty(), "{} validation message(s):\n{}", m.len(), m.join("\n"));
}
