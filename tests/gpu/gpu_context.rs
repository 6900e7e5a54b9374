//! The Vulkan context: device choice, capability reporting, and a validation layer that really reports misuse.

use crate::gpu_support;

use meshchar::gpu::{enumerate_devices, Context, ContextDesc, GpuError, MemoryKind};

#[test]
fn validation_layer_reports_misuse() {
    let Some(ctx) = gpu_support::context() else { return };
    let buf = ctx.create_buffer("misuse", 64, MemoryKind::DeviceLocal).expect("buffer");
    // vkCmdFillBuffer requires a size that is a multiple of 4: the layer must say so.
    ctx.submit_and_wait(|rec| {
        rec.fill(&buf, 0, Some(6), 0);
        Ok(())
    })
    .expect("submit");
    let m = ctx.validation_messages();
    assert!(m.iter().any(|s| s.contains("vkCmdFillBuffer")), "the validation layer stayed silent: {m:?}");
}

#[test]
fn device_choice_by_name_index_and_unknown() {
    let Some(ctx) = gpu_support::context() else { return };
    let name = ctx.caps().name.clone();
    let (list, selected) = enumerate_devices().expect("enumerate");
    let selected = selected.expect("a usable device is selected");
    assert_eq!(list[selected].caps.name, name);
    // By a name substring (case-insensitive) and by index.
    let word = name.split_whitespace().next().unwrap_or(&name).to_uppercase();
    let by_name =
        Context::new(&ContextDesc { validation: true, device: Some(word), ..Default::default() }).expect("by name");
    assert_eq!(by_name.caps().name, name);
    let by_index = Context::new(&ContextDesc {
        validation: true,
        device: Some(list[selected].index.to_string()),
        ..Default::default()
    })
    .expect("index");
    assert_eq!(by_index.caps().name, name);
    match Context::new(&ContextDesc {
        validation: true,
        device: Some("no such device 42".into()),
        ..Default::default()
    }) {
        Err(GpuError::DeviceNotFound(w, available)) => {
            assert_eq!(w, "no such device 42");
            assert!(available.contains(&name), "{available}");
        }
        other => panic!("expected DeviceNotFound, got {other:?}"),
    }
    gpu_support::assert_no_validation_messages(&by_name);
    gpu_support::assert_no_validation_messages(&by_index);
}

#[test]
fn capabilities_are_queried_and_sane() {
    let Some(ctx) = gpu_support::context() else { return };
    let c = ctx.caps();
    assert!(c.missing().is_empty(), "{:?}", c.missing());
    assert!(c.subgroup_size.is_power_of_two() && (4..=128).contains(&c.subgroup_size));
    assert!(c.min_subgroup_size <= c.subgroup_size && c.subgroup_size <= c.max_subgroup_size);
    let wg = c.workgroup_size();
    assert!(wg >= c.max_subgroup_size && wg <= c.max_workgroup_invocations && wg / c.min_subgroup_size <= 64);
    if c.name.contains("llvmpipe") {
        // Mesa's lavapipe as documented for this project's CI machines.
        assert_eq!(c.subgroup_size, 8);
        assert_eq!(c.max_storage_buffer_range, 128 << 20);
    }
    let (list, selected) = enumerate_devices().expect("enumerate");
    let json = serde_json::to_value(&list).expect("json");
    let first = &json[selected.expect("selected")];
    for field in ["name", "subgroup_size", "max_storage_buffer_range", "device_type", "api_version"] {
        assert!(first.get(field).is_some(), "missing {field} in {first}");
    }
    gpu_support::assert_no_validation_messages(&ctx);
}

#[test]
fn buffers_round_trip_and_reject_out_of_range_access() {
    let Some(ctx) = gpu_support::context() else { return };
    let data: Vec<u32> = (0..10_000u32).map(|i| i.wrapping_mul(2_654_435_761)).collect();
    let buf = ctx.upload("data", &data).expect("upload");
    assert_eq!(ctx.read_buffer::<u32>(&buf, 0, data.len()).expect("read"), data);
    assert_eq!(ctx.read_buffer::<u32>(&buf, 400, 3).expect("read"), data[100..103].to_vec());
    assert!(matches!(ctx.read_buffer::<u32>(&buf, 4, data.len()), Err(GpuError::Buffer(_))));
    let mut host = ctx.create_buffer("host", 16, MemoryKind::Upload).expect("upload buffer");
    assert!(matches!(host.write(8, &[1u32, 2, 3]), Err(GpuError::Buffer(_))));
    let too_big = ctx.caps().max_buffer_size.unwrap_or(u64::MAX).saturating_add(4);
    assert!(ctx.create_buffer("huge", too_big, MemoryKind::DeviceLocal).is_err());
    gpu_support::assert_no_validation_messages(&ctx);
}
