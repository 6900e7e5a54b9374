//! `examples/engine_frame.rs`, run as an engine would run it: its own instance (validation layer on), device, queue
//! and allocator, meshchar only through `Context::from_raw`, one command buffer per frame with two frames in flight.
//! Pipelined (the default): 60 frames, none with a host wait, none with a validation message, every planned report
//! equal to the CPU reference on the positions the frame read back, rebuilds and refits counted consistently with
//! the summary. Staged: its frames do wait (so the counter counts).
//!
//! The binary is the built example beside this test's directory (`target/<profile>/examples/engine_frame`): build
//! the examples first (`cargo build --release --examples`, as `scripts/test` does). A missing binary, or one older
//! than the sources, fails the test.

use crate::gpu_support;

use crate::example_binary;
use serde_json::Value;

use std::path::PathBuf;
use std::process::{Command, Output, Stdio};

/// The example binary ([`example_binary::path`]).
fn binary() -> PathBuf {
    example_binary::path("engine_frame")
}

fn run(args: &[&str]) -> Output {
    Command::new(binary())
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("cannot run engine_frame: {e}"))
}

/// Runs the example with `args` (which include `--json`), expects exit 0, and returns its frame lines and summary.
fn frames(args: &[&str]) -> (Vec<Value>, Value) {
    let out = run(args);
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert_eq!(out.status.code(), Some(0), "engine_frame {args:?}\nstdout:\n{stdout}\nstderr:\n{stderr}");
    let mut values: Vec<Value> =
        stdout.lines().map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON ({e}): {l}"))).collect();
    let summary = values.pop().expect("a summary line");
    assert_eq!(summary["summary"], Value::Bool(true), "the last line is the summary: {summary}");
    assert!(values.iter().all(|v| v.get("summary").is_none()), "one summary, last");
    (values, summary)
}

fn u(v: &Value, key: &str) -> u64 {
    v[key].as_u64().unwrap_or_else(|| panic!("{key} is not a count in {v}"))
}

#[test]
fn pipelined_frames_never_wait_stay_silent_and_equal_the_reference() {
    if gpu_support::context().is_none() {
        return;
    }
    let (lines, summary) = frames(&["--frames", "60", "--json", "--check"]);
    assert_eq!(lines.len(), 60, "one line per frame");
    let (mut rebuilds, mut refits) = (0u64, 0u64);
    for (t, l) in lines.iter().enumerate() {
        assert_eq!(u(l, "frame"), t as u64, "frames in order: {l}");
        assert_eq!(l["mode"], "pipelined");
        assert_eq!(u(l, "host_waits"), 0, "frame {t} waited on the host: {l}");
        assert_eq!(u(l, "engine_waits"), 0, "frame {t}: {l}");
        assert_eq!(u(l, "validation_messages"), 0, "frame {t}: {l}");
        assert_eq!(l["reference_equal"], Value::Bool(true), "frame {t}: {l}");
        assert!(l["characterize_ms"].as_f64().is_some_and(|ms| ms > 0.0), "frame {t}: {l}");
        let meshes = l["meshes"].as_array().expect("meshes");
        assert_eq!(meshes.len(), 2, "{l}");
        assert_eq!(meshes[0]["index_type"], "u16");
        assert_eq!(meshes[1]["index_type"], "u32");
        assert_eq!(u(l, "triangles"), meshes.iter().map(|m| u(m, "triangles")).sum::<u64>());
        let mut frame_rebuilds = 0u64;
        let bound = summary["redecide_drift"].as_f64().expect("redecide_drift");
        let redecided: Vec<&str> =
            l["redecided"].as_array().expect("redecided").iter().filter_map(|x| x.as_str()).collect();
        for m in meshes {
            // The rule decides again exactly where the features drifted past its bound since the last decision
            // (every mesh on the first frame); otherwise the last decision holds and the tree is refitted.
            let since = m["drift_since_decision"].as_f64().expect("drift_since_decision");
            let decided = m["decided"].as_bool().expect("decided");
            assert_eq!(decided, t == 0 || since > bound, "frame {t}: {m} (bound {bound})");
            assert_eq!(redecided.contains(&m["mesh"].as_str().unwrap_or_default()), decided, "frame {t}: {l}");
            if !decided {
                assert_eq!(m["decision"], "refit", "a decision kept refits: frame {t}: {m}");
            }
            assert!(m["decision_us"].as_f64().is_some_and(|us| us >= 0.0), "{m}");
            assert_eq!(m["reference_equal"], Value::Bool(true), "frame {t}: {m}");
            match m["decision"].as_str() {
                Some("rebuild") => {
                    assert!(m["build_ms"].as_f64().is_some() && m.get("refit_ms").is_none(), "{m}");
                    frame_rebuilds += 1;
                }
                Some("refit") => {
                    assert!(m["refit_ms"].as_f64().is_some() && m.get("build_ms").is_none(), "{m}");
                    refits += 1;
                }
                _ => panic!("frame {t}: no decision in {m}"),
            }
        }
        rebuilds += frame_rebuilds;
        let want = if frame_rebuilds > 0 { "rebuild" } else { "refit" };
        assert_eq!(l["decision"], want, "frame {t}: {l}");
        assert_eq!(l.get("build_ms").is_some(), frame_rebuilds > 0, "{l}");
        assert_eq!(l.get("refit_ms").is_some(), frame_rebuilds < meshes.len() as u64, "{l}");
        if t == 0 {
            assert_eq!(frame_rebuilds, 2, "the first frame builds every tree: {l}");
        }
    }
    assert!(rebuilds >= 2, "at least the first frame's rebuilds");
    assert_eq!(u(&summary, "frames"), 60);
    assert_eq!(u(&summary, "rebuilds"), rebuilds);
    assert_eq!(u(&summary, "refits"), refits);
    assert_eq!(rebuilds + refits, 120, "a decision per mesh and frame");
    assert_eq!(u(&summary, "host_waits"), 0);
    assert_eq!(u(&summary, "validation_messages"), 0, "{summary}");
    assert_eq!(summary["reference_equal"], Value::Bool(true));
    let redecisions: usize = lines.iter().map(|l| l["redecided"].as_array().map_or(0, Vec::len)).sum();
    assert_eq!(u(&summary, "redecisions"), redecisions as u64);
    assert!((2..120).contains(&redecisions), "decided again only where the geometry drifted: {redecisions}");
    assert!(summary["decision_share"].as_f64().is_some() && summary["median_gpu_ms"].as_f64().is_some_and(|g| g > 0.0));
    let mean: f64 = lines.iter().map(|l| l["characterize_ms"].as_f64().unwrap_or(0.0)).sum::<f64>() / 60.0;
    let reported = summary["mean_characterize_ms"].as_f64().expect("mean_characterize_ms");
    assert!((reported - mean).abs() <= 1e-9 * mean.max(1.0), "mean {reported} vs {mean}");
}

#[test]
fn staged_frames_wait_and_equal_the_reference() {
    if gpu_support::context().is_none() {
        return;
    }
    let (lines, summary) = frames(&["--frames", "3", "--json", "--check", "--mode", "staged"]);
    assert_eq!(lines.len(), 3);
    for l in &lines {
        assert_eq!(l["mode"], "staged");
        assert!(u(l, "host_waits") > 0, "the staged characterization waits on the host: {l}");
        assert_eq!(u(l, "engine_waits"), 1, "{l}");
        assert_eq!(u(l, "validation_messages"), 0, "{l}");
        assert_eq!(l["reference_equal"], Value::Bool(true), "{l}");
    }
    assert_eq!(u(&summary, "host_waits"), lines.iter().map(|l| u(l, "host_waits")).sum::<u64>());
    assert_eq!(u(&summary, "validation_messages"), 0);
}

#[test]
fn help_and_png() {
    let out = run(&["--help"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0));
    for w in ["Usage: engine_frame", "--frames", "--mode", "pipelined", "staged", "--check", "--png", "--json"] {
        assert!(stdout.contains(w), "--help lacks {w:?}:\n{stdout}");
    }
    let bad = run(&["--frames", "0"]);
    assert_eq!(bad.status.code(), Some(2), "--frames 0 is a usage error");
    if gpu_support::context().is_none() {
        return;
    }
    let dir = std::env::temp_dir().join(format!("meshchar-engine-frame-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary directory");
    let png = dir.join("last.png");
    let png_arg = png.to_str().expect("a UTF-8 temporary path");
    let out = run(&["--frames", "3", "--subdivide", "0", "--png", png_arg]);
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&png).expect("the PNG was written");
    assert!(bytes.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    let _ = std::fs::remove_dir_all(&dir);
}

/// With ray queries (`--ray-query on`): `--structure rt_update` runs every mesh-frame on the driver's updatable
/// structure (rebuilt on frame 0, then updated or rebuilt as the rule says), with no host wait, no validation
/// message and every report equal to the reference; the picture comes from ray queries and every pixel hits the
/// CPU reference's triangle. `--structure auto` names a structure per mesh and counts the driver's, and
/// `--ray-query off` never uses it.
#[test]
fn ray_query_frames_use_the_driver_structure_and_trace_the_picture() {
    let Some(ctx) = gpu_support::context() else { return };
    if !ctx.caps().ray_query {
        assert!(
            std::env::var("REQUIRE_GPU").map_or(true, |v| v != "1"),
            "REQUIRE_GPU=1 but {} has no ray queries (scripts/setup installs Mesa 25 from Debian backports)",
            ctx.caps().name
        );
        let out = run(&["--frames", "2", "--ray-query", "on"]);
        assert_ne!(out.status.code(), Some(0), "--ray-query on without ray queries fails");
        return;
    }
    drop(ctx);
    let dir = std::env::temp_dir().join(format!("meshchar-engine-frame-rq-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary directory");
    let png = dir.join("rq.png");
    let png_arg = png.to_str().expect("a UTF-8 temporary path");
    let args =
        ["--frames", "8", "--json", "--check", "--ray-query", "on", "--structure", "rt_update", "--png", png_arg];
    let (lines, summary) = frames(&args);
    assert_eq!(lines.len(), 8);
    for (t, l) in lines.iter().enumerate() {
        assert_eq!(u(l, "host_waits"), 0, "frame {t}: {l}");
        assert_eq!(l["reference_equal"], Value::Bool(true), "frame {t}: {l}");
        for m in l["meshes"].as_array().expect("meshes") {
            assert_eq!(m["structure"], "rt_update", "frame {t}: {m}");
            assert!(matches!(m["decision"].as_str(), Some("rebuild" | "refit")), "{m}");
            if t == 0 {
                assert_eq!(m["decision"], "rebuild", "frame 0 builds: {m}");
            }
        }
    }
    assert_eq!(summary["ray_query"], Value::Bool(true));
    assert_eq!(u(&summary, "driver_mesh_frames"), 16, "{summary}");
    assert_eq!(u(&summary, "validation_messages"), 0, "{summary}");
    let pic = &summary["picture"];
    assert_eq!(pic["traced_by"], "ray query", "{summary}");
    assert!(u(pic, "pixels") > 0);
    assert_eq!(u(pic, "pixels_equal_to_cpu"), u(pic, "pixels"), "every pixel hits the reference's triangle: {pic}");
    assert!(std::fs::read(&png).expect("the PNG").starts_with(b"\x89PNG\r\n\x1a\n"));
    // auto: a structure per mesh, the driver's counted.
    let (lines, summary) = frames(&["--frames", "4", "--json", "--ray-query", "on"]);
    let on_driver = lines
        .iter()
        .flat_map(|l| l["meshes"].as_array().cloned().unwrap_or_default())
        .inspect(|m| assert!(matches!(m["structure"].as_str(), Some("lbvh" | "rt_update")), "{m}"))
        .filter(|m| m["structure"] == "rt_update")
        .count() as u64;
    assert_eq!(u(&summary, "driver_mesh_frames"), on_driver, "{summary}");
    // off: the LBVH only.
    let (lines, summary) = frames(&["--frames", "2", "--json", "--ray-query", "off"]);
    assert_eq!(summary["ray_query"], Value::Bool(false));
    assert_eq!(u(&summary, "driver_mesh_frames"), 0);
    assert!(lines
        .iter()
        .flat_map(|l| l["meshes"].as_array().cloned().unwrap_or_default())
        .all(|m| m["structure"] == "lbvh"));
    let bad = run(&["--frames", "2", "--ray-query", "off", "--structure", "rt_update"]);
    assert_ne!(bad.status.code(), Some(0), "rt_update without ray queries is an error");
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--structure rt_update"), "the error names the flag");
    let _ = std::fs::remove_dir_all(&dir);
}
