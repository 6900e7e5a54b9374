//! Lists every Vulkan device with the properties meshchar relies on, and which one it would pick.
//!
//! `cargo run --release --example devices -- [--json]`

use anyhow::Context as _;
use clap::Parser;
use cli::args::JsonArg;
use meshchar::gpu::enumerate_devices;
use std::process::ExitCode;

#[path = "support/cli.rs"]
mod cli;

/// Lists Vulkan devices and the one meshchar would use.
///
/// MESHCHAR_DEVICE=<index or name substring> overrides the choice; VK_DRIVER_FILES selects drivers.
#[derive(Parser, Debug)]
#[command(name = "devices", args_override_self = true)]
#[command(mut_arg("json", |a| a.help("One JSON object: {\"devices\": [...], \"selected\": index or null}")))]
struct Args {
    #[command(flatten)]
    json: JsonArg,
}

fn main() -> ExitCode {
    cli::main_with(run)
}

fn run(args: Args) -> anyhow::Result<()> {
    let json = args.json.json;
    // A driver list that the Vulkan loader cannot use fails inside the loader, whose message does not say which
    // list it was given: name it here.
    let drivers = ["VK_DRIVER_FILES", "VK_ICD_FILENAMES"]
        .into_iter()
        .find_map(|var| std::env::var(var).ok().map(|v| format!(" of {var}={v}")));
    let (list, selected) =
        enumerate_devices().with_context(|| format!("listing the Vulkan devices{}", drivers.unwrap_or_default()))?;
    if json {
        let v = serde_json::json!({ "devices": list, "selected": selected });
        println!("{v}");
        return Ok(());
    }
    if list.is_empty() {
        println!("no Vulkan device found");
    }
    for d in &list {
        let c = &d.caps;
        let mark = if Some(d.index) == selected { "*" } else { " " };
        println!("{mark} [{}] {} ({}, Vulkan {}, driver {})", d.index, c.name, c.device_type, c.api_version, c.driver);
        println!(
            "      subgroup size {} (min {}, max {}), ops: {}{}",
            c.subgroup_size,
            c.min_subgroup_size,
            c.max_subgroup_size,
            c.subgroup_operations.join(" "),
            if c.subgroup_in_compute { "" } else { " (not in compute!)" }
        );
        println!(
            "      workgroups per dispatch {:?}, workgroup size {:?} / {} invocations, shared memory {} KiB",
            c.max_workgroup_count,
            c.max_workgroup_size,
            c.max_workgroup_invocations,
            c.max_shared_memory / 1024
        );
        println!(
            "      storage-buffer range {} MiB, allocation {} MiB, buffer {}",
            c.max_storage_buffer_range >> 20,
            c.max_memory_allocation_size >> 20,
            c.max_buffer_size.map(|b| format!("{} MiB", b >> 20)).unwrap_or_else(|| "n/a".into())
        );
        println!(
            "      float64 {}, int64 {}, int64 atomics {}, buffer device address {}, timestamps {} bits at {} ns",
            c.float64, c.int64, c.int64_atomics, c.buffer_device_address, c.timestamp_valid_bits, c.timestamp_period
        );
        println!(
            "      driver acceleration structures and ray queries (rt_* candidates): {}",
            if c.ray_query {
                "yes (VK_KHR_acceleration_structure, VK_KHR_ray_query: accelerationStructure, rayQuery)".to_string()
            } else {
                "no (needs VK_KHR_acceleration_structure and VK_KHR_ray_query; lavapipe from Mesa 24.1)".to_string()
            }
        );
        println!(
            "      device UUID {}, driver UUID {}, pipeline cache UUID {}",
            c.device_uuid, c.driver_uuid, c.pipeline_cache_uuid
        );
        if !d.missing.is_empty() {
            println!("      cannot run meshchar: missing {}", d.missing.join(", "));
        }
    }
    match selected {
        Some(i) => println!("selected: [{i}] {}", list[i].caps.name),
        None => println!("selected: none (the CPU path will be used)"),
    }
    Ok(())
}
