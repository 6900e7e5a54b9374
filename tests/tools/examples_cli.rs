//! The example binaries' command lines (clap): `--help` exits 0 with the usage, an unknown flag and a bad value exit
//! 2 with a message, `--json=false` never turns JSON on, a second positional where one is allowed exits 2,
//! `--flag=value` works, a runtime failure exits 1 naming the file, and nothing but the output appears when standard
//! error is not a terminal (no progress lines). Every example, on one bad input (a missing file, text named `.obj`,
//! an empty file, a garbage JSON file), exits nonzero without panicking and names the file; on one small good input
//! it exits 0 (tiny meshes and images, one repeat: seconds in all).
//!
//! The binaries are the built examples beside this test's directory (`target/<profile>/examples/<name>`): build
//! them first with `cargo build --release --examples` (as `scripts/test` does; `cargo test --examples` builds
//! test harnesses instead). A missing binary, or one older than the sources, fails the test.

use crate::example_binary;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};

const EXAMPLES: [&str; 10] = [
    "build_bvh",
    "calibrate",
    "characterize",
    "device_bench",
    "devices",
    "engine_frame",
    "evaluate",
    "failure_study",
    "render_classes",
    "tradeoff",
];

/// The example binary `name` ([`example_binary::path`]).
fn binary(name: &str) -> PathBuf {
    example_binary::path(name)
}

/// Runs example `name` with `args`, no standard input, its outputs captured (so not terminals).
fn run(name: &str, args: &[&str]) -> Output {
    Command::new(binary(name))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap_or_else(|e| panic!("cannot run {name}: {e}"))
}

/// Runs `evaluate ARGS` (which must include `--json`), asserts it succeeds, and returns its JSON lines.
fn evaluate_json(args: &[&str]) -> Vec<serde_json::Value> {
    let out = run("evaluate", args);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    stdout.lines().map(|l| serde_json::from_str(l).expect("a JSON line")).collect()
}

/// The scored policy `name` held out as `holdout` in a comparison's first JSON line.
fn policy_run<'a>(json: &'a serde_json::Value, name: &str, holdout: &str) -> &'a serde_json::Value {
    json["baselines"]["policies"]
        .as_array()
        .expect("policies")
        .iter()
        .find(|p| p["policy"] == name && p["holdout"] == holdout)
        .unwrap_or_else(|| panic!("{name} {holdout}: {json}"))
}

fn text(out: &Output) -> (String, String) {
    (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned())
}

/// `name args` exits 2 with an error message on standard error and nothing on standard output.
fn assert_usage_error(name: &str, args: &[&str]) {
    let out = run(name, args);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(2), "{name} {args:?}: exit code\nstdout: {stdout}\nstderr: {stderr}");
    assert!(stderr.contains("error:"), "{name} {args:?}: no message on stderr: {stderr:?}");
    assert!(stdout.is_empty(), "{name} {args:?}: printed on stdout: {stdout:?}");
}

/// A small mesh (a tetrahedron) in a fresh directory.
fn tetrahedron(dir_name: &str) -> (PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("meshchar-examples-cli-{}-{dir_name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temporary directory");
    let path = dir.join("tetrahedron.obj");
    std::fs::write(&path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n").expect("mesh");
    (dir, path)
}

#[test]
fn help_exits_0_with_the_usage() {
    for name in EXAMPLES {
        for flag in ["--help", "-h"] {
            let out = run(name, &[flag]);
            let (stdout, stderr) = text(&out);
            assert_eq!(out.status.code(), Some(0), "{name} {flag}: {stderr}");
            assert!(stdout.contains(&format!("Usage: {name}")), "{name} {flag}: no usage in {stdout:?}");
            assert!(stdout.contains("--help"), "{name} {flag}: {stdout:?}");
        }
    }
}

#[test]
fn long_help_keeps_the_explanations() {
    let cases: &[(&str, &[&str])] = &[
        ("characterize", &["--class-rule <doane|sturges|sqrt|N>", "[possible values: 30, 63]", "embedded default"]),
        ("evaluate", &["--compare-policies <FILE>", "--oracle-cache", "policy-regret-<workload>.svg"]),
        ("tradeoff", &["tradeoff-statistics.svg", "[default: cpu,vulkan,naive]", "--oracle-resolution"]),
        ("build_bvh", &["lbvh", "hlbvh", "sah", "--cluster-bits"]),
        ("calibrate", &["--from-oracle", "--no-refit", "../shared/meshes/bart"]),
        ("failure_study", &["--large-n-max", "--conference", "zero-area"]),
        ("render_classes", &["--inside", "FILE.json", "16..=4096"]),
        ("devices", &["MESHCHAR_DEVICE", "\"selected\""]),
    ];
    for (name, wanted) in cases {
        let (stdout, _) = text(&run(name, &["--help"]));
        for w in *wanted {
            assert!(stdout.contains(w), "{name} --help lacks {w:?}:\n{stdout}");
        }
    }
}

#[test]
fn unknown_flags_exit_2() {
    for name in EXAMPLES {
        assert_usage_error(name, &["--no-such-flag"]);
        assert_usage_error(name, &["-x"]);
    }
}

#[test]
fn bad_values_exit_2() {
    let cases: &[(&str, &[&str])] = &[
        ("characterize", &["--resolution", "abc"]),
        ("characterize", &["--resolution", "0"]),
        ("characterize", &["--backend", "nope"]),
        ("characterize", &["--morton-bits", "7"]),
        ("characterize", &["--class-rule", "0"]),
        ("characterize", &["--class-rule", "many"]),
        ("characterize", &["--alpha", "1.5"]),
        ("characterize", &["--sample-stride", "0"]),
        ("characterize", &["--policy", "nope"]),
        ("characterize", &["--workload", "nope"]),
        ("characterize", &["--frames", "0"]),
        ("characterize", &["--resolution"]),
        ("characterize", &["--view", "sideways"]),
        ("characterize", &["--camera", "1,2,3"]),
        ("characterize", &["--view", "inside", "--camera", "0,0,1,0,0,0"]),
        ("characterize", &["--budget-references-per-triangle", "-1"]),
        ("characterize", &["--budget-min-references", "many"]),
        ("characterize", &["--budget-references-per-triangle", "65"]),
        ("characterize", &["--budget-min-references", "33554433"]),
        ("characterize", &["--budget-grid-references-per-triangle", "65"]),
        ("characterize", &["--budget-grid-min-references", "33554433"]),
        ("evaluate", &["x.obj", "--budget-grid-references-per-triangle", "-1"]),
        ("evaluate", &["x.obj", "--budget-bytes", "-5"]),
        ("evaluate", &["x.obj", "--precision", "0"]),
        ("evaluate", &["x.obj", "--precision", "2"]),
        ("evaluate", &["x.obj", "--max-repeats", "0"]),
        ("evaluate", &["x.obj", "--precision-ms", "100"]),
        ("evaluate", &["x.obj", "--precision", "0.02", "--precision-ms=-1"]),
        ("evaluate", &["x.obj", "--precision", "0.02", "--precision-ms", "nan"]),
        ("evaluate", &["x.obj", "--view", "sideways"]),
        ("evaluate", &["x.obj", "--resolution", "abc"]),
        ("evaluate", &["x.obj", "--resolution", "16385"]),
        ("evaluate", &["x.obj", "--workload", "nope"]),
        ("evaluate", &["x.obj", "--tie-margin", "1.5"]),
        ("evaluate", &["x.obj", "--repeats", "0"]),
        ("evaluate", &["x.obj", "--rebuild", "sometimes"]),
        ("evaluate", &["x.obj", "--trace-backend", "gpu"]),
        ("evaluate", &["x.obj", "--structures", "bvh,octree"]),
        ("evaluate", &["x.obj", "--camera", "1,2,3"]),
        ("evaluate", &["x.obj", "--camera", "0,0,0,0,0,0"]),
        ("evaluate", &[]),
        ("build_bvh", &["x.obj", "--backend", "nope"]),
        ("build_bvh", &["x.obj", "--backend", "naive"]),
        ("build_bvh", &["x.obj", "--builder", "nope"]),
        ("build_bvh", &["x.obj", "--max-leaf", "0"]),
        ("build_bvh", &["x.obj", "--cluster-bits", "99"]),
        ("build_bvh", &["x.obj", "--builder", "sah", "--backend", "vulkan"]),
        ("build_bvh", &[]),
        ("calibrate", &["--resolution", "4097"]),
        ("calibrate", &["--repeats", "0"]),
        ("calibrate", &["--repeats", "10001"]),
        ("evaluate", &["x.obj", "--repeats", "18446744073709551615"]),
        ("evaluate", &["x.obj", "--precision", "0.02", "--max-repeats", "10001"]),
        ("tradeoff", &["x.obj", "--out", "d", "--oracle-repeats", "10001"]),
        ("calibrate", &["stray"]),
        ("failure_study", &["--repeats", "101"]),
        ("failure_study", &["--backend", "nope"]),
        ("failure_study", &["--large-n-max", "-1"]),
        ("render_classes", &["x.obj", "--out", "x.png", "--resolution", "15"]),
        ("render_classes", &["x.obj", "--out", "x.png", "--morton-bits", "7"]),
        ("render_classes", &["x.obj", "--out", "x.png", "--frame", "abc"]),
        ("render_classes", &["x.obj"]),
        ("tradeoff", &["x.obj", "--out", "d", "--backends", "cpu,nope"]),
        ("tradeoff", &["x.obj", "--out", "d", "--bits", "30,7"]),
        ("tradeoff", &["x.obj", "--out", "d", "--strides", "1,0"]),
        ("tradeoff", &["x.obj", "--out", "d", "--rules", "doane,0"]),
        ("tradeoff", &["x.obj", "--out", "d", "--strides", ","]),
        ("tradeoff", &["x.obj", "--out", "d", "--tie-margin", "-0.1"]),
        ("tradeoff", &["x.obj", "--out", "d", "--oracle-resolution", "abc"]),
        ("tradeoff", &["x.obj"]),
        ("tradeoff", &["--out", "d"]),
        ("devices", &["stray"]),
    ];
    for (name, args) in cases {
        assert_usage_error(name, args);
    }
}

/// `characterize --json` on 2,000 large overlapping triangles at 16 x 16 rays with `extra` flags: its first report.
fn overlapping_report(extra: &[&str]) -> serde_json::Value {
    // Level 1: the mesh's bounds pass counts the grid's references exactly.
    let mut a =
        vec!["degenerate:overlapping:2000:1", "--backend", "cpu", "--json", "--resolution", "16", "--level", "1"];
    a.extend_from_slice(extra);
    let out = run("characterize", &a);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "{a:?}\n{stderr}");
    serde_json::from_str(stdout.lines().next().unwrap_or_default()).expect("characterize --json")
}

#[test]
fn the_budget_flags_reach_the_policy() {
    // The default budget keeps every structure for 2,000 large overlapping triangles (246,329 grid references).
    let v = overlapping_report(&[]);
    assert_eq!(v["excluded"].as_array().map(Vec::len), Some(0), "{}", v["excluded"]);
    // A budget of 1 reference per triangle, at least 1,000, drops the grid (counted exactly) and the kd-tree.
    let v = overlapping_report(&["--budget-references-per-triangle", "1", "--budget-min-references", "1000"]);
    let out = v["excluded"].as_array().expect("excluded");
    let grid = out.iter().find(|e| e["structure"] == "grid").expect("the grid excluded");
    // Counted exactly: what the built grid holds.
    use meshchar::accel::AccelStructure as _;
    let scene = meshchar::eval::load_scene(Path::new("degenerate:overlapping:2000:1")).expect("scene");
    let mesh = &scene.frames[0];
    let built = meshchar::accel::grid::Grid::build(mesh).and_then(|g| g.validate()).expect("grid").references as u64;
    let budget = (mesh.triangle_count() as u64).max(1000);
    assert_eq!(
        (grid["needed"].as_u64(), grid["budget"].as_u64(), grid["bound"].as_str()),
        (Some(built), Some(budget), Some("exact"))
    );
    assert!(out.iter().any(|e| e["structure"] == "kdtree"), "{out:?}");
    assert!(!["grid", "kdtree"].contains(&v["selected"].as_str().unwrap_or_default()), "{}", v["selected"]);
}

#[test]
fn a_grid_counted_exactly_is_priced_by_its_references_and_the_grid_flags_reach_the_policy() {
    // 20,000 large overlapping triangles: the grid needs 9.7 million references (487 per triangle), counted
    // exactly. The default budget keeps it (within its builder's limit) and prices its build by that count: the
    // shipped work law at 487 references per triangle, not the law in n alone (fitted on a few per triangle).
    let report = |extra: &[&str]| {
        let mut a =
            vec!["degenerate:overlapping:20000:1", "--backend", "cpu", "--json", "--resolution", "16", "--level", "1"];
        a.extend_from_slice(extra);
        let out = run("characterize", &a);
        let (stdout, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(0), "{a:?}\n{stderr}");
        serde_json::from_str::<serde_json::Value>(stdout.lines().next().unwrap_or_default()).expect("json")
    };
    let v = report(&[]);
    let excluded = v["excluded"].as_array().expect("excluded");
    assert!(excluded.iter().all(|e| e["structure"] != "grid"), "{excluded:?}");
    let scene = meshchar::eval::load_scene(Path::new("degenerate:overlapping:20000:1")).expect("scene");
    let mesh = &scene.frames[0];
    let bounds = meshchar::select::BuildBounds::of_mesh(mesh).expect("bounds");
    let work = bounds.grid_build_work().expect("counted exactly");
    let model = meshchar::cost::CostModel::shipped().expect("shipped model");
    let grid = model.get(meshchar::accel::StructureName::Grid).expect("grid model");
    let n = mesh.triangle_count() as u64;
    let predicted = v["predicted"].as_array().expect("predicted");
    let g = predicted.iter().find(|p| p["structure"] == "grid").expect("the grid predicted");
    let build = g["build_ms_per_build"].as_f64().expect("build");
    assert!((build / grid.build_ms(n, work) - 1.0).abs() < 1e-9, "{build} vs {}", grid.build_ms(n, work));
    assert!(build > 10.0 * grid.build_ms(n, 0.0), "{build} vs the law in n: {}", grid.build_ms(n, 0.0));
    // The grid's own flags: 16 per triangle, at least 2^22, exclude it; the kd-tree's flags set the grid's too.
    for flags in [
        &["--budget-grid-references-per-triangle", "16", "--budget-grid-min-references", "4194304"][..],
        &["--budget-references-per-triangle", "16", "--budget-min-references", "4194304"][..],
    ] {
        let v = report(flags);
        let excluded = v["excluded"].as_array().expect("excluded");
        let e = excluded.iter().find(|e| e["structure"] == "grid").unwrap_or_else(|| panic!("{flags:?}: {excluded:?}"));
        assert_eq!((e["needed"].as_f64(), e["bound"].as_str()), (Some(work), Some("exact")), "{e}");
    }
    // The grid's flags override the kd-tree's for the grid alone.
    let v = report(&[
        "--budget-references-per-triangle",
        "16",
        "--budget-grid-references-per-triangle",
        "64",
        "--budget-grid-min-references",
        "33554432",
    ]);
    let excluded: Vec<&str> =
        v["excluded"].as_array().expect("excluded").iter().filter_map(|e| e["structure"].as_str()).collect();
    assert_eq!(excluded, ["kdtree"]);
}

#[test]
fn timed_probes_reach_the_policy_and_leave_the_budget_standing() {
    let timed = |v: &serde_json::Value| {
        v["reasons"]
            .as_array()
            .expect("reasons")
            .iter()
            .filter_map(|r| r.as_str())
            .any(|r| r.starts_with("timed probes"))
    };
    assert!(!timed(&overlapping_report(&[])), "no probes timed unless asked");
    let v = overlapping_report(&["--timed-probes"]);
    assert!(timed(&v), "{}", v["reasons"]);
    // Structures over the budget are neither probed nor selected.
    let v = overlapping_report(&[
        "--timed-probes",
        "--budget-references-per-triangle",
        "1",
        "--budget-min-references",
        "1000",
    ]);
    let r: Vec<&str> = v["reasons"].as_array().expect("reasons").iter().filter_map(|r| r.as_str()).collect();
    let line = r.iter().find(|r| r.starts_with("timed probes")).expect("timed probes");
    assert!(!line.contains("grid ") && !line.contains("kdtree "), "{line}");
    assert!(!["grid", "kdtree"].contains(&v["selected"].as_str().unwrap_or_default()), "{}", v["selected"]);
}

#[test]
fn json_equals_false_never_turns_json_on() {
    for (name, args) in [
        ("characterize", &["--backend", "cpu"][..]),
        ("evaluate", &["x.obj"][..]),
        ("build_bvh", &["x.obj"][..]),
        ("devices", &[][..]),
    ] {
        let mut all = args.to_vec();
        all.push("--json=false");
        assert_usage_error(name, &all);
    }
}

#[test]
fn one_positional_means_one() {
    let (dir, mesh) = tetrahedron("positionals");
    let m = mesh.to_str().expect("utf-8 path");
    let png = dir.join("x.png");
    assert_usage_error("build_bvh", &["--backend", "cpu", m, m]);
    assert_usage_error("render_classes", &["--backend", "cpu", m, m, "--out", png.to_str().expect("utf-8 path")]);
    assert!(!png.exists(), "render_classes wrote a picture");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn flag_equals_value_and_plain_flags_work() {
    let out = run("characterize", &["--json", "--backend=cpu", "--morton-bits=63", "--class-rule=sturges"]);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(report["morton_bits"], 63);
    assert_eq!(report["class_rule"], "sturges");
    assert_eq!(report["backend"], "cpu");
    // The decision's cost against the chosen structure's predicted frame.
    // A decision on the triangle count alone did not read the characterization: it costs the selection only.
    let c = &report["selection_cost"];
    let by_size = report["reasons"][0].as_str().is_some_and(|r| r.contains("on the triangle count alone"));
    let characterize_ms = c["characterize_ms"].as_f64().unwrap();
    assert!(if by_size { characterize_ms == 0.0 } else { characterize_ms > 0.0 }, "{c}");
    assert!(c["select_ms"].as_f64().unwrap() > 0.0, "{c}");
    assert!(c["predicted_frame_ms"].as_f64().unwrap() > 0.0 && c["within_goal"].is_boolean(), "{c}");
    // A fixed level reads the characterization, and pays for it.
    let out = run("characterize", &["--json", "--backend=cpu", "--level=0"]);
    let report: serde_json::Value = serde_json::from_str(text(&out).0.trim()).expect("one JSON object");
    assert!(report["selection_cost"]["characterize_ms"].as_f64().unwrap() > 0.0, "{report}");
    // A view: the calibrated policy says what it saw.
    let out = run("characterize", &["--json", "--backend=cpu", "--view", "inside", "family:city:3000:1"]);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(report["mesh"], "family:city:3000:1");
    let reasons = report["reasons"].as_array().unwrap();
    assert!(reasons.iter().any(|r| r.as_str().unwrap().starts_with("view: eye inside the bounds")), "{reasons:?}");
    // The last of a repeated option wins, as before clap.
    let out = run("characterize", &["--json", "--backend", "naive", "--backend", "cpu"]);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).expect("one JSON object");
    assert_eq!(report["backend"], "cpu");
}

#[test]
fn runtime_failures_exit_1_naming_the_file() {
    let missing = std::env::temp_dir().join("meshchar-examples-cli-no-such-mesh.obj");
    let m = missing.to_str().expect("utf-8 path");
    for (name, args) in [
        ("characterize", vec!["--backend", "cpu", m]),
        ("evaluate", vec![m]),
        ("build_bvh", vec!["--backend", "cpu", m]),
        ("render_classes", vec![m, "--out", "x.png"]),
    ] {
        let out = run(name, &args);
        let (_, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {stderr}");
        assert!(stderr.starts_with(&format!("{name}: ")), "{name}: {stderr:?}");
        assert!(stderr.contains("no-such-mesh.obj"), "{name}: the message does not name the file: {stderr:?}");
        assert_eq!(stderr.matches("No such file").count(), 1, "{name}: cause repeated: {stderr:?}");
    }
}

#[test]
fn no_progress_output_without_a_terminal() {
    let (dir, mesh) = tetrahedron("progress");
    let m = mesh.to_str().expect("utf-8 path");
    // evaluate: the tables on stdout, nothing on stderr.
    let out = run("evaluate", &[m, "--resolution", "16", "--repeats", "1", "--structures", "bvh,grid"]);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "evaluate: {stderr}");
    assert!(stdout.contains("oracle best"), "evaluate: {stdout}");
    assert!(stderr.is_empty(), "evaluate wrote on stderr: {stderr:?}");
    // With --json: one JSON line per scene, nothing else.
    let out = run("evaluate", &[m, "--json", "--resolution", "16", "--repeats", "1", "--structures", "bvh"]);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "evaluate --json: {stderr}");
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    let line: serde_json::Value = serde_json::from_str(stdout.trim()).expect("a JSON line");
    assert_eq!(line["policy"], "calibrated");
    assert!(stderr.is_empty(), "evaluate --json wrote on stderr: {stderr:?}");
    // tradeoff measures its oracle and sweeps: no progress lines either.
    let out_dir = dir.join("tradeoff");
    let o = out_dir.to_str().expect("utf-8 path");
    let args = [
        m,
        "--out",
        o,
        "--policy",
        "thesis",
        "--backends",
        "cpu",
        "--strides",
        "1, 2,",
        "--bits",
        "30",
        "--rules",
        "doane",
        "--repeats",
        "1",
        "--oracle-resolution",
        "16",
        "--oracle-repeats",
        "1",
    ];
    let out = run("tradeoff", &args);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "tradeoff: {stderr}");
    assert!(stdout.contains("wrote:"), "tradeoff: {stdout}");
    assert!(stderr.is_empty(), "tradeoff wrote on stderr: {stderr:?}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out_dir.join("tradeoff.json")).expect("tradeoff.json"))
            .expect("JSON");
    assert_eq!(json["settings"].as_array().map(Vec::len), Some(2), "strides 1 and 2 on the CPU");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A fresh directory for one test, with the tetrahedron, text named `.obj`, an empty `.obj` and garbage JSON.
fn inputs(dir_name: &str) -> PathBuf {
    let (dir, _) = tetrahedron(dir_name);
    std::fs::write(dir.join("text.obj"), "this is not a mesh\n").expect("text.obj");
    std::fs::write(dir.join("empty.obj"), "").expect("empty.obj");
    std::fs::write(dir.join("garbage.json"), "{ not json\n").expect("garbage.json");
    dir
}

fn arg(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

#[test]
fn every_example_refuses_a_bad_input_naming_it() {
    let dir = inputs("bad");
    let (text, empty, garbage) = (dir.join("text.obj"), dir.join("empty.obj"), dir.join("garbage.json"));
    let (tet, missing, png) = (dir.join("tetrahedron.obj"), dir.join("no-such-mesh.obj"), dir.join("x.png"));
    let out_dir = dir.join("tradeoff");
    let bad_mesh = format!("bad={}", text.display());
    let cases: Vec<(&str, Vec<&str>, &Path)> = vec![
        ("build_bvh", vec!["--backend", "cpu", arg(&text)], &text),
        ("calibrate", vec!["--from-oracle", arg(&garbage), "--no-refit"], &garbage),
        ("characterize", vec!["--backend", "cpu", arg(&empty)], &empty),
        ("device_bench", vec!["characterize", "--quick", "--mesh", bad_mesh.as_str()], &text),
        // devices reads no file but the Vulkan driver list (below).
        ("engine_frame", vec!["--frames", "1", "--mesh", arg(&text)], &text),
        ("evaluate", vec![arg(&empty), "--resolution", "8", "--repeats", "1"], &empty),
        ("failure_study", vec!["--no-oracle", "--large-n-max", "0", "--conference", arg(&missing)], &missing),
        ("render_classes", vec![arg(&text), "--out", arg(&png), "--backend", "cpu"], &text),
        ("tradeoff", vec![arg(&tet), "--out", arg(&out_dir), "--oracle", arg(&garbage), "--backends", "cpu"], &garbage),
    ];
    let mut named: Vec<&str> = Vec::new();
    for (name, args, file) in &cases {
        let out = run(name, args);
        assert_refused(name, &out, file);
        named.push(name);
    }
    assert!(!png.exists(), "render_classes wrote a picture of text");
    // devices: a driver list that is not one.
    let out = Command::new(binary("devices"))
        .env("VK_DRIVER_FILES", &garbage)
        .env_remove("VK_ICD_FILENAMES")
        .stdin(Stdio::null())
        .output()
        .expect("run devices");
    assert_refused("devices", &out, &garbage);
    named.push("devices");
    named.sort_unstable();
    assert_eq!(named, EXAMPLES, "every example on a bad input");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A failed run: nonzero exit, not a panic (101), a message on standard error prefixed by the command that names
/// `file`.
fn assert_refused(name: &str, out: &Output, file: &Path) {
    let (stdout, stderr) = text(out);
    let code = out.status.code();
    assert!(code.is_some_and(|c| c != 0 && c != 101), "{name}: exit {code:?}\nstdout: {stdout}\nstderr: {stderr}");
    assert!(!stderr.contains("panicked"), "{name}: {stderr}");
    assert!(stderr.starts_with(&format!("{name}: ")), "{name}: {stderr:?}");
    let file_name = file.file_name().and_then(|f| f.to_str()).expect("file name");
    assert!(stderr.contains(file_name), "{name}: the message does not name {file_name}: {stderr:?}");
}

/// `n` small random triangles as OBJ text.
fn soup_obj(path: &Path, n: usize, seed: u64) {
    let mesh = meshchar::mesh::generate::random_soup(n, seed);
    let mut text = String::new();
    for p in &mesh.positions {
        text.push_str(&format!("v {} {} {}\n", p[0], p[1], p[2]));
    }
    for t in &mesh.indices {
        text.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
    }
    std::fs::write(path, text).expect("soup");
}

/// `evaluate --trace-backend vulkan --json` on a scene no test has seen (a seeded soup and a clustered scene): every
/// structure is traced on the device, valid, and agrees with the CPU reference on every ray, for each workload.
#[test]
fn evaluate_traces_on_the_device() {
    if std::env::var("REQUIRE_GPU").map_or(true, |v| v != "1")
        && meshchar::gpu::Context::new(&Default::default()).is_err()
    {
        eprintln!("skipping: no Vulkan device");
        return;
    }
    let dir = inputs("device-oracle");
    let p = dir.join("soup.obj");
    soup_obj(&p, 3000, 0x5eed);
    for workload in ["primary", "shadow", "diffuse"] {
        let out = run(
            "evaluate",
            &[
                arg(&p),
                "--json",
                "--trace-backend",
                "vulkan",
                "--resolution",
                "32",
                "--repeats",
                "1",
                "--workload",
                workload,
            ],
        );
        let (stdout, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(0), "{workload}: {stderr}");
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("evaluate --json");
        assert_eq!(v["trace_backend"], "vulkan", "{v}");
        assert!(v["device"]["name"].as_str().is_some_and(|n| !n.is_empty()), "{v}");
        assert!(v["hits_checked"].as_str().is_some(), "{v}");
        assert_eq!(v["ray_generation"], "device", "{v}");
        let structures = v["structures"].as_array().expect("structures");
        assert_eq!(structures.len(), 6, "{v}");
        for s in structures {
            assert_eq!((s["valid"].as_bool(), s["hits_agree"].as_bool()), (Some(true), Some(true)), "{workload}: {s}");
            if s["name"] == "lbvh" || s["name"] == "hlbvh" || s["name"] == "grid" {
                assert_eq!(s["build_backend"], "device", "{s}");
                assert!(s.get("upload_ms").is_none_or(|u| u.is_null()), "{s}");
            } else {
                assert_eq!(s["build_backend"], "host", "{s}");
                assert!(s["upload_ms"].as_f64().is_some_and(|u| u >= 0.0), "{s}");
            }
            assert!(s["build_ms"].as_f64().is_some_and(|b| b > 0.0), "{s}");
            assert!(s["trace_ms"].as_f64().is_some_and(|t| t > 0.0), "{s}");
        }
    }
}

/// The command: `evaluate --json --structures rt_fast_trace,rt_fast_build,bvh,lbvh` on a mesh no test
/// tuned for reports the driver structures valid, agreeing with the CPU reference, with build and trace times, beside
/// the project's; on the CPU backend they are reported as not measured, with the reason.
#[test]
fn evaluate_measures_the_driver_structures() {
    let ray_query = meshchar::gpu::Context::new(&Default::default()).map(|c| c.caps().ray_query);
    if std::env::var("REQUIRE_GPU").map_or(true, |v| v != "1") && !matches!(ray_query, Ok(true)) {
        eprintln!("skipping: no Vulkan device with ray queries");
        return;
    }
    let dir = inputs("driver-oracle");
    let p = dir.join("soup.obj");
    soup_obj(&p, 2000, 0xd21);
    for workload in ["primary", "shadow"] {
        let args =
            ["--json", "--trace-backend", "vulkan", "--resolution", "32", "--repeats", "2", "--workload", workload];
        let mut a: Vec<&str> = vec![arg(&p)];
        a.extend(args);
        a.extend(["--structures", "rt_fast_trace,rt_fast_build,bvh,lbvh"]);
        let out = run("evaluate", &a);
        let (stdout, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(0), "{stderr}");
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("evaluate --json");
        let ours: Vec<&str> = v["structures"].as_array().unwrap().iter().map(|s| s["name"].as_str().unwrap()).collect();
        assert_eq!(ours, ["bvh", "lbvh"], "{v}");
        let driver = v["driver_structures"].as_array().expect("driver_structures");
        let names: Vec<&str> = driver.iter().map(|s| s["name"].as_str().unwrap()).collect();
        assert_eq!(names, ["rt_fast_trace", "rt_fast_build"], "{v}");
        // The best of all four, computed here from the totals.
        let all = v["structures"].as_array().unwrap().iter().chain(driver);
        let best = all.min_by(|a, b| a["total_ms"].as_f64().unwrap().total_cmp(&b["total_ms"].as_f64().unwrap()));
        assert_eq!(v["best_candidate"], best.unwrap()["name"], "{v}");
        for d in driver {
            assert_eq!((d["valid"].as_bool(), d["hits_agree"].as_bool()), (Some(true), Some(true)), "{workload}: {d}");
            assert!(d["build_ms"].as_f64().is_some_and(|b| b > 0.0), "{d}");
            assert!(d["trace_ms"].as_f64().is_some_and(|t| t > 0.0), "{d}");
            assert!(d["rays"].as_u64().is_some_and(|r| r > 0), "{d}");
            assert_eq!(d["per_frame"], "rebuild", "{d}");
        }
    }
    let out =
        run("evaluate", &[arg(&p), "--json", "--resolution", "8", "--repeats", "1", "--structures", "bvh,rt_update"]);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("evaluate --json");
    let d = &v["driver_structures"][0];
    assert_eq!((d["name"].as_str(), d["valid"].as_bool()), (Some("rt_update"), Some(false)), "{v}");
    assert!(d["error"].as_str().is_some_and(|e| e.contains("--trace-backend vulkan")), "{d}");
    let out = run("evaluate", &[arg(&p), "--structures", "rt_fastest"]);
    assert_eq!(out.status.code(), Some(2), "an unknown name is a usage error");
}

#[test]
fn every_example_runs_on_a_small_input() {
    let dir = inputs("good");
    let tet = dir.join("tetrahedron.obj");
    let m = arg(&tet);
    let ok = |name: &str, args: &[&str]| -> String {
        let out = run(name, args);
        let (stdout, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(0), "{name} {args:?}\nstdout: {stdout}\nstderr: {stderr}");
        stdout
    };
    let mut ran = Vec::new();
    let stdout = ok("build_bvh", &["--backend", "cpu", "--json", m]);
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("build_bvh --json");
    assert_eq!((v["triangles"].as_u64(), v["valid"].as_bool()), (Some(4), Some(true)), "{v}");
    ran.push("build_bvh");
    let stdout = ok("characterize", &["--backend", "cpu", "--json", m]);
    let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("characterize --json");
    assert_eq!(v["triangles"], 4);
    ran.push("characterize");
    let stdout = ok("evaluate", &[m, "--resolution", "8", "--repeats", "1"]);
    assert!(stdout.contains("oracle best"), "{stdout}");
    ran.push("evaluate");
    // calibrate fits on three cached oracle lines (soups of 20, 2,000 and 100,000 triangles: the build law needs sizes
    // far apart, so that timing noise on a loaded machine does not turn the fitted build exponent negative: the 100,000-triangle build takes thousands of times the 20-triangle one), written by
    // evaluate.
    let lines = dir.join("oracle.jsonl");
    let mut jsonl = String::new();
    for (n, seed) in [(20, 1), (2000, 2), (100_000, 3)] {
        let p = dir.join(format!("soup{n}.obj"));
        soup_obj(&p, n, seed);
        jsonl.push_str(&ok(
            "evaluate",
            &[arg(&p), "--json", "--resolution", "8", "--repeats", "1", "--structures", "bvh"],
        ));
    }
    std::fs::write(&lines, jsonl).expect("oracle lines");
    let model = dir.join("model.json");
    let stdout = ok("calibrate", &["--from-oracle", arg(&lines), "--no-refit", "--out", arg(&model)]);
    assert!(stdout.contains("wrote") && model.is_file(), "{stdout}");
    ran.push("calibrate");
    let out = run("devices", &["--json"]);
    let (stdout, stderr) = text(&out);
    if out.status.code() == Some(0) {
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("devices --json");
        assert!(v["devices"].is_array(), "{v}");
    } else {
        // No Vulkan loader or driver on this machine: a message, not a panic; REQUIRE_GPU=1 makes it a failure.
        assert!(std::env::var("REQUIRE_GPU").map_or(true, |v| v != "1"), "devices: {stderr}");
        assert!(out.status.code().is_some_and(|c| c != 101) && stderr.starts_with("devices: "), "{stderr}");
    }
    ran.push("devices");
    let out = run("device_bench", &["sort", "--quick", "--rounds", "1"]);
    let (stdout, stderr) = text(&out);
    if out.status.code() == Some(0) {
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("device_bench sort");
        let sizes = v["sizes"].as_array().expect("sizes");
        assert!(!sizes.is_empty() && sizes.iter().all(|s| s["agrees"] == true), "{v}");
    } else {
        assert!(std::env::var("REQUIRE_GPU").map_or(true, |v| v != "1"), "device_bench: {stderr}");
        assert!(out.status.code().is_some_and(|c| c != 101) && stderr.starts_with("device_bench: "), "{stderr}");
    }
    ran.push("device_bench");
    let fs_dir = dir.join("failure-study");
    let stdout = ok("failure_study", &["--no-oracle", "--large-n-max", "0", "--backend", "cpu", "--out", arg(&fs_dir)]);
    assert!(stdout.contains("| all_equal |") && fs_dir.join("failure-study.json").is_file(), "{stdout}");
    ran.push("failure_study");
    let png = dir.join("classes.png");
    ok("render_classes", &[m, "--out", arg(&png), "--resolution", "16", "--backend", "cpu"]);
    assert!(png.is_file() && dir.join("classes.json").is_file(), "render_classes wrote no picture");
    ran.push("render_classes");
    let out_dir = dir.join("tradeoff");
    let args = [
        m,
        "--out",
        arg(&out_dir),
        "--policy",
        "thesis",
        "--backends",
        "cpu",
        "--strides",
        "1",
        "--bits",
        "30",
        "--rules",
        "doane",
        "--repeats",
        "1",
        "--oracle-resolution",
        "8",
        "--oracle-repeats",
        "1",
    ];
    assert!(ok("tradeoff", &args).contains("wrote:"));
    ran.push("tradeoff");
    assert!(ok("engine_frame", &["--frames", "2", "--subdivide", "0", "--json"]).contains("\"summary\""));
    ran.push("engine_frame");
    ran.sort_unstable();
    assert_eq!(ran, EXAMPLES, "every example on a good input");
    let _ = std::fs::remove_dir_all(&dir);
}

/// An oracle record of `docs/data/oracle-shadow.jsonl` (a CPU record), retraced as `backend` on `uuid` when given.
fn oracle_line(device_uuid: Option<&str>) -> String {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("docs/data/oracle-shadow.jsonl")).expect("the CPU oracle file");
    let mut v: serde_json::Value = serde_json::from_str(text.lines().next().expect("a record")).expect("a record");
    if let Some(uuid) = device_uuid {
        v["trace_backend"] = serde_json::json!("vulkan");
        v["device"] = serde_json::json!({
            "name": "llvmpipe (LLVM 15.0.6, 256 bits)",
            "device_type": "cpu",
            "driver": "llvmpipe Mesa 22.3.6 (LLVM 15.0.6)",
            "driver_version": 1,
            "device_uuid": uuid,
        });
    }
    v.to_string() + "\n"
}

/// `calibrate --from-oracle` and `evaluate --compare-policies` refuse records of two tracers (a CPU and a device
/// record; two devices), exit 1 and name both records; `--trace-backend vulkan` refuses CPU records.
#[test]
fn one_fit_reads_the_records_of_one_tracer() {
    let dir = inputs("mixed-tracers");
    let cpu = dir.join("cpu.jsonl");
    let lavapipe = dir.join("lavapipe.jsonl");
    let other = dir.join("other-device.jsonl");
    std::fs::write(&cpu, oracle_line(None)).unwrap();
    std::fs::write(&lavapipe, oracle_line(Some("6d65736132322e332e36000000000000"))).unwrap();
    std::fs::write(&other, oracle_line(Some("00112233445566778899aabbccddeeff"))).unwrap();
    for (a, b, found) in [(&cpu, &lavapipe, ": traced with vulkan on llvmpipe"), (&lavapipe, &other, "UUID 0011")] {
        for (name, flag) in [("calibrate", "--from-oracle"), ("evaluate", "--compare-policies")] {
            let out = run(name, &[flag, arg(a), flag, arg(b), "--no-refit"][..if name == "calibrate" { 5 } else { 4 }]);
            let (stdout, stderr) = text(&out);
            assert_eq!(out.status.code(), Some(1), "{name}: {stdout}\n{stderr}");
            assert!(stderr.contains(&format!("{}:1: traced with", b.display())), "{name}: {stderr}");
            assert!(stderr.contains(found), "{name}: {stderr}");
            assert!(stderr.contains(&format!("{}:1 with", a.display())), "{name}: {stderr}");
            assert!(stderr.contains("apart"), "{name}: {stderr}");
        }
    }
    let out = run("calibrate", &["--from-oracle", arg(&cpu), "--trace-backend", "vulkan", "--no-refit"]);
    let (_, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("--trace-backend vulkan, but the --from-oracle records were traced with cpu"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// On the device: `evaluate --trace-backend vulkan --json` on three unseen soups, `calibrate --from-oracle` on its
/// records writes a calibration that records the device; `characterize` and `evaluate` with `--trace-backend
/// vulkan` on lavapipe say that they use `assets/cost-model-lavapipe.json`, with `--cost-model` the given file, and
/// on the CPU the CPU file.
#[test]
fn a_device_calibration_records_its_device_and_is_chosen_on_it() {
    if std::env::var("REQUIRE_GPU").map_or(true, |v| v != "1")
        && meshchar::gpu::Context::new(&Default::default()).is_err()
    {
        eprintln!("skipping: no Vulkan device");
        return;
    }
    let dir = inputs("device-calibration");
    let mut lines = String::new();
    let mut meshes = Vec::new();
    // Sizes an order of magnitude apart, so that the build laws are fitted on more than the fixed overheads.
    for (i, n) in [500, 5000, 40000].into_iter().enumerate() {
        let p = dir.join(format!("soup-{n}.obj"));
        soup_obj(&p, n, 0xca1 + i as u64);
        meshes.push(p);
    }
    for workload in ["primary", "shadow"] {
        let mut a = vec!["--json", "--trace-backend", "vulkan", "--resolution", "16", "--repeats", "1"];
        a.extend(["--policy", "thesis", "--workload", workload]);
        a.extend(meshes.iter().map(|p| arg(p)));
        let out = run("evaluate", &a);
        let (stdout, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(0), "{stderr}");
        lines.push_str(&stdout);
    }
    let records = dir.join("device.jsonl");
    std::fs::write(&records, &lines).unwrap();
    let file = dir.join("device-model.json");
    let out = run("calibrate", &["--from-oracle", arg(&records), "--no-refit", "--out", arg(&file)]);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "{stdout}\n{stderr}");
    let first: serde_json::Value = serde_json::from_str(lines.lines().next().unwrap()).unwrap();
    let model = meshchar::cost::CostModel::load(Some(&file)).expect("the written file loads");
    assert_eq!(model.trace_backend, meshchar::eval::oracle::TraceBackend::Vulkan);
    let d = model.trace_device.expect("the device is recorded");
    assert_eq!(serde_json::to_value(&d).unwrap(), first["device"], "the records' device, every field");
    assert_eq!(model.device, d.name);
    assert!(stdout.contains(&format!("traced with vulkan on {}", d.name)), "{stdout}");
    // Which file the policy uses, said where the policy is printed.
    let lavapipe = meshchar::cost::registry::device_family(&d) == "lavapipe";
    let mesh = arg(&meshes[0]);
    for (name, extra) in [("characterize", vec![]), ("evaluate", vec!["--resolution", "8", "--repeats", "1"])] {
        let run_with = |more: &[&str]| {
            let mut a = vec![mesh, "--trace-backend", "vulkan"];
            a.extend(&extra);
            a.extend(more);
            let out = run(name, &a);
            let (stdout, stderr) = text(&out);
            assert_eq!(out.status.code(), Some(0), "{name}: {stderr}");
            stdout
        };
        let stdout = run_with(&[]);
        if lavapipe {
            assert!(
                stdout.contains("calibrated policy: cost model assets/cost-model-lavapipe.json: "),
                "{name}: {stdout}"
            );
            // The shipped file was measured on one lavapipe build: the same build matches by UUID, another
            // (another Mesa) by name, and the policy says which.
            assert!(
                stdout.contains("assets/cost-model-lavapipe.json: the device UUID")
                    || stdout.contains("is lavapipe, matched by name"),
                "{name}: {stdout}"
            );
        } else {
            assert!(
                stdout.contains("calibrated policy: cost model assets/cost-model-cpu.json: no calibration"),
                "{stdout}"
            );
        }
        let stdout = run_with(&["--cost-model", arg(&file)]);
        assert!(
            stdout.contains(&format!("calibrated policy: cost model {}: --cost-model", file.display())),
            "{stdout}"
        );
        let mut a = vec![mesh];
        a.extend(&extra);
        let out = run(name, &a);
        let (stdout, _) = text(&out);
        assert!(stdout.contains("cost model assets/cost-model-cpu.json: tracing on the CPU"), "{name}: {stdout}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_polygon_over_three_points_gives_a_report_at_the_default_resolution() {
    // One OBJ face of 300,002 corners cycling over three vertices: 300,000 triangles, 100,000 copies of one. At
    // 1024 x 1024 rays a structure that tests every copy would trace for minutes; the BVH, the kd-tree and the BIH
    // keep one copy, the structures over the trace budget are reported failed, and the report names one of the
    // three best.
    let dir = std::env::temp_dir().join(format!("meshchar-examples-cli-fan-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("dir");
    let file = dir.join("fan.obj");
    let mut obj = String::from("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1");
    for i in 0..300_001usize {
        obj.push_str([" 2", " 3", " 1"][i % 3]);
    }
    obj.push('\n');
    std::fs::write(&file, obj).expect("fan.obj");
    for name in ["characterize", "build_bvh"] {
        let out = run(name, &["--backend", "cpu", arg(&file)]);
        assert_eq!(out.status.code(), Some(0), "{name}: {:?}", text_of(&out));
    }
    let out = run("evaluate", &["--repeats", "1", "--json", arg(&file)]);
    let (stdout, stderr) = text(&out);
    assert_eq!(out.status.code(), Some(0), "{stderr}");
    let j: serde_json::Value = serde_json::from_str(stdout.lines().next().expect("a line")).expect("json");
    assert_eq!(j["triangles"], 300_000);
    assert_eq!(j["resolution"], 1024);
    let best = j["oracle_best"].as_str().expect("a best structure");
    assert!(["bvh", "kdtree", "bih"].contains(&best), "{stdout}");
    let over: Vec<&str> = j["structures"]
        .as_array()
        .expect("structures")
        .iter()
        .filter(|s| s["error"].as_str().is_some_and(|e| e.contains("over the trace budget")))
        .filter_map(|s| s["name"].as_str())
        .collect();
    assert!(over.contains(&"lbvh") && !over.contains(&"kdtree") && !over.contains(&"bih"), "{over:?}");
    std::fs::remove_dir_all(&dir).ok();
}

fn text_of(out: &Output) -> String {
    let (a, b) = text(out);
    format!("{a}{b}")
}

/// The primary-ray family records at 2K and 20K triangles, four views each (56: two sizes, so that the
/// comparison's and the calibration's fits are defined), written to `dir/records.jsonl`.
fn family_records(dir: &Path) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text_in = std::fs::read_to_string(root.join("docs/data/families-primary.jsonl")).expect("family records");
    let lines: Vec<&str> = text_in.lines().filter(|l| l.contains(":2k:1\"") || l.contains(":20k:1\"")).collect();
    assert_eq!(lines.len(), 56, "seven families, two sizes, four views");
    let file = dir.join("records.jsonl");
    std::fs::write(&file, lines.join("\n") + "\n").unwrap();
    file
}

/// `evaluate --compare-policies ... --cost-model FILE --proxy --json`: the comparison, then the given calibration
/// scored as it is, then the deterministic proxy, one JSON line each, on records of generated scenes (no mesh files).
#[test]
fn compare_policies_scores_a_given_calibration_and_the_proxy() {
    let dir = inputs("compare-fixed-proxy");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let file = family_records(&dir);
    let model = root.join("assets/cost-model-cpu.json");
    let json = evaluate_json(&["--compare-policies", arg(&file), "--cost-model", arg(&model), "--proxy", "--json"]);
    assert_eq!(json.len(), 3, "{json:?}");
    let fixed = &json[1]["fixed_cost_model"];
    assert_eq!(fixed["file"], serde_json::json!(arg(&model)));
    assert_eq!(fixed["score"]["scored"].as_u64().unwrap() + fixed["score"]["failed"].as_u64().unwrap(), 56, "{fixed}");
    let regret = fixed["score"]["mean_regret"].as_f64().unwrap();
    assert!(regret.is_finite() && regret >= 0.0, "{fixed}");
    let proxy = &json[2]["proxy"];
    for price in ["box_ns", "triangle_ns"] {
        let p = proxy["prices"][price].as_f64().unwrap();
        assert!(p.is_finite() && p > 0.0, "{proxy}");
    }
    assert_eq!(proxy["agreement"]["samples"].as_u64(), Some(56), "{proxy}");
    assert!(proxy["comparison"]["calibrated_held_out"]["scored"].as_u64().is_some(), "{proxy}");
    let cv: Vec<&serde_json::Value> = json[0]["baselines"]["policies"]
        .as_array()
        .map(|p| p.iter().filter(|p| p["policy"] == "calibrated_cv").collect())
        .unwrap_or_default();
    assert_eq!(cv.len(), 2, "calibrated_cv held out by scene and by family: {}", json[0]);
    for run in &cv {
        let ridges = run["ridges"].as_array().expect("the ridge chosen without each group");
        assert!(!ridges.is_empty() && ridges.iter().all(|r| r[1].as_f64().is_some_and(|x| x > 0.0)), "{run}");
    }
    // The calibration with its ridge chosen by cross-validation, and the flag that cannot go with --ridge.
    let fitted = dir.join("cv.json");
    let out = run("calibrate", &["--from-oracle", arg(&file), "--no-refit", "--ridge-cv", "--out", arg(&fitted)]);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success() && stderr.contains("chosen ridge"), "{stdout}\n{stderr}");
    let written: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&fitted).unwrap()).unwrap();
    assert!(written["source"].as_str().unwrap().contains("by leave-one-family-out"), "{written}");
    let out = run("calibrate", &["--from-oracle", arg(&file), "--no-refit", "--ridge-cv", "--ridge", "1"]);
    assert_eq!(out.status.code(), Some(2), "{:?}", text(&out));
    // Without --json, the rows are named.
    let out = run("evaluate", &["--compare-policies", arg(&file), "--cost-model", arg(&model), "--proxy"]);
    let (stdout, _) = text(&out);
    assert!(stdout.contains("calibrated, as given") && stdout.contains("deterministic proxy"), "{stdout}");
    assert!(
        stdout.contains("calibrated_cv (family_out): ridge chosen without each group (+x: with the crossings): city "),
        "{stdout}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// `characterize --workload shadow|diffuse`: the calibrated policy is told the secondary rays a frame makes (the
/// oracle's count where the sample is the whole image), or `--secondary-rays N`; a reason says which.
#[test]
fn characterize_tells_the_policy_the_secondary_rays_a_frame_makes() {
    for (scene, kind) in [("family:vegetation:2k:1", "shadow"), ("family:terrain:2k:1", "diffuse")] {
        let common = [scene, "--workload", kind, "--resolution", "64", "--json"];
        let out = run("evaluate", &[&common[..], &["--repeats", "1", "--structures", "lbvh"][..]].concat());
        let (stdout, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(0), "{stderr}");
        let record: serde_json::Value = serde_json::from_str(stdout.lines().next().unwrap_or_default()).expect("JSON");
        let want = record["rays_per_frame"].as_u64().expect("rays_per_frame");
        assert!(want > 0 && want < 64 * 64, "{scene}: {want} of 4,096 primary rays start one");
        let reasons = |extra: &[&str]| {
            let out = run("characterize", &[&common[..], &["--backend", "cpu"][..], extra].concat());
            let (stdout, stderr) = text(&out);
            assert_eq!(out.status.code(), Some(0), "{stderr}");
            let v: serde_json::Value = serde_json::from_str(stdout.lines().next().unwrap_or_default()).expect("JSON");
            v["reasons"]
                .as_array()
                .expect("reasons")
                .iter()
                .filter_map(|r| r.as_str().map(String::from))
                .collect::<Vec<_>>()
        };
        let r = reasons(&[]);
        let line = format!("{kind} rays per frame: {want} estimated from 64x64 of the 64x64 primary rays");
        assert!(r.last().is_some_and(|x| x.starts_with(&line)), "{scene}: {r:?}");
        assert!(r[1].starts_with("margin"), "the policy's reasons keep their places: {r:?}");
        assert!(r.iter().any(|x| x.contains(&format!("for {want} {kind} rays/frame"))), "{scene}: {r:?}");
        let r = reasons(&["--secondary-rays", "1234"]);
        assert_eq!(r.last(), Some(&format!("{kind} rays per frame: 1234 (--secondary-rays)")));
        assert!(r.iter().any(|x| x.contains(&format!("for 1234 {kind} rays/frame"))), "{scene}: {r:?}");
    }
    // Primary rays are the image's pixels: no such reason.
    let out = run("characterize", &["family:city:2k:1", "--backend", "cpu", "--json", "--resolution", "64"]);
    let (stdout, _) = text(&out);
    assert!(
        out.status.success() && !stdout.contains("rays per frame:") && stdout.contains("4096 primary rays/frame"),
        "{stdout}"
    );
    assert_usage_error("characterize", &["--secondary-rays", "-5"]);
    // Only shadow or diffuse rays under the calibrated policy are counted so.
    assert_usage_error("characterize", &["--backend", "cpu", "--secondary-rays", "5"]);
    assert_usage_error(
        "characterize",
        &["--backend", "cpu", "--workload", "shadow", "--policy", "thesis", "--secondary-rays", "5"],
    );
    assert_usage_error("engine_frame", &["--secondary-rays", "5"]);
}

/// `evaluate --compare-policies ... --cost-model FILE`: the given calibration scored per workload too, and the
/// workloads' scores add up to the whole.
#[test]
fn a_given_calibration_is_scored_per_workload() {
    let dir = inputs("compare-fixed-workloads");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for w in ["primary", "shadow"] {
        let text_in = std::fs::read_to_string(root.join(format!("docs/data/families-{w}.jsonl"))).expect("records");
        let lines: Vec<&str> = text_in.lines().filter(|l| l.contains(":2k:1\"") || l.contains(":20k:1\"")).collect();
        assert_eq!(lines.len(), 56, "{w}: seven families, two sizes, four views");
        let file = dir.join(format!("{w}.jsonl"));
        std::fs::write(&file, lines.join("\n") + "\n").unwrap();
        files.push(file);
    }
    let model = root.join("assets/cost-model-cpu.json");
    let args =
        ["--compare-policies", arg(&files[0]), "--compare-policies", arg(&files[1]), "--cost-model", arg(&model)];
    let json = evaluate_json(&[&args[..], &["--json"][..]].concat());
    let fixed = &json[1]["fixed_cost_model"];
    let by = fixed["by_workload"].as_array().expect("by_workload");
    let names: Vec<&str> = by.iter().filter_map(|w| w["workload"].as_str()).collect();
    assert_eq!(names, ["primary", "shadow"], "{fixed}");
    let n = |s: &serde_json::Value| s["scored"].as_u64().unwrap();
    let (mut scored, mut sum, mut worst) = (0, 0.0, 0.0f64);
    for w in by {
        assert_eq!(n(&w["score"]) + w["score"]["failed"].as_u64().unwrap(), 56, "{w}");
        assert!(w["timed_score"].is_null() && w["measured_score"].is_null(), "not asked for: {w}");
        scored += n(&w["score"]);
        sum += w["score"]["mean_regret"].as_f64().unwrap() * n(&w["score"]) as f64;
        worst = worst.max(w["score"]["worst_regret"].as_f64().unwrap());
    }
    let all = &fixed["score"];
    assert_eq!(scored, n(all));
    assert!((sum / scored as f64 - all["mean_regret"].as_f64().unwrap()).abs() < 1e-12, "{fixed}");
    assert_eq!(worst, all["worst_regret"].as_f64().unwrap());
    // The text names each workload's line.
    let out = run("evaluate", &args);
    let (stdout, _) = text(&out);
    assert!(out.status.success(), "{stdout}");
    for w in ["primary", "shadow"] {
        assert!(stdout.lines().any(|l| l.trim_start().starts_with(w) && l.contains(": as given ")), "{w}: {stdout}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `evaluate --compare-policies ... --timed-probes` and `calibrate --from-oracle ... --timed-probes`: the timed policy
/// held out both ways and the given calibration with probes, scored on every record; a calibration written with the
/// ratios; both flags refused without the records they need. (What the probes measure is not checked here: it is
/// timing, not deterministic.)
#[test]
fn timed_probes_in_the_comparison_and_the_calibration() {
    let dir = inputs("compare-timed");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let file = family_records(&dir);
    let model = root.join("assets/cost-model-cpu.json");
    let json =
        evaluate_json(&["--compare-policies", arg(&file), "--cost-model", arg(&model), "--timed-probes", "--json"]);
    for holdout in ["scene_out", "family_out"] {
        let p = policy_run(&json[0], "calibrated_timed", holdout);
        assert_eq!(p["overall"]["scored"].as_u64(), Some(56), "{p}");
    }
    let timed = &json[1]["fixed_cost_model"]["timed_score"];
    assert_eq!(timed["scored"].as_u64(), Some(56), "{}", json[1]);
    // Without the flag: no timed rows.
    let out = run("evaluate", &["--compare-policies", arg(&file), "--json"]);
    let (stdout, _) = text(&out);
    assert!(out.status.success() && !stdout.contains("calibrated_timed"), "{stdout}");
    // The calibration's ratios.
    let fitted = dir.join("timed.json");
    let out = run("calibrate", &["--from-oracle", arg(&file), "--no-refit", "--timed-probes", "--out", arg(&fitted)]);
    let (stdout, stderr) = text(&out);
    assert!(out.status.success() && stdout.contains("timed-probe ratios"), "{stdout}\n{stderr}");
    let written = meshchar::cost::CostModel::load(Some(&fitted)).expect("a valid calibration");
    let ratios = written.timed.expect("the timed block");
    assert_eq!(ratios.records, 56);
    for s in meshchar::accel::StructureName::ALL {
        let r = ratios.of(s).unwrap_or_else(|| panic!("{s}"));
        assert!(
            r.build.is_some() && r.trace[0].is_some() && r.trace[1..] == [None, None],
            "primary records only: {r:?}"
        );
    }
    assert_usage_error("calibrate", &["--timed-probes"]);
    assert_usage_error("evaluate", &["--timed-probes", "family:city:2k:1"]);
    let _ = std::fs::remove_dir_all(&dir);
}

/// `characterize --measure-close-calls`: a reason says what was measured (with the `measured` totals in the JSON) or
/// why nothing was; `--measure-max-ms` needs the flag. `evaluate --compare-policies ... --measure-close-calls`: the
/// measured policy held out both ways and the given calibration with its close calls measured, scored on every
/// record. (What the frames measure is timing, not checked here.)
#[test]
fn close_calls_measured_in_the_report_and_the_comparison() {
    let dir = inputs("compare-measured");
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // The shipped calibration without its timed-probe ratios predicts deterministically: the close calls are the
    // same on every run, and some family scene at 2K triangles is one.
    let model = meshchar::cost::CostModel::shipped().expect("shipped model");
    let plain = dir.join("no-ratios.json");
    meshchar::cost::CostModel { timed: None, ..model }.save(&plain).expect("saved");
    let mut measured = 0;
    for family in ["interior", "city", "vegetation", "terrain", "particles", "engineering", "stadium"] {
        let scene = format!("family:{family}:2k:1");
        let a =
            ["--backend", "cpu", "--json", "--resolution", "128", "--cost-model", arg(&plain), "--measure-close-calls"];
        let out = run("characterize", &[&[scene.as_str()][..], &a[..]].concat());
        let (stdout, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(0), "{scene}: {stderr}");
        let v: serde_json::Value = serde_json::from_str(stdout.lines().next().unwrap_or_default()).expect("JSON");
        let reasons: Vec<&str> = v["reasons"].as_array().expect("reasons").iter().filter_map(|r| r.as_str()).collect();
        let line = reasons.iter().find(|r| r.starts_with("measured close call")).expect("measured close call");
        let Some(m) = v["measured"].as_array() else {
            assert!(line.starts_with("measured close call: none: no close call"), "{scene}: {line}");
            continue;
        };
        measured += 1;
        assert!(m.len() >= 2 && line.starts_with("measured close call ("), "{line}");
        let total = |t: &serde_json::Value| t["total_ms"].as_f64().expect("total_ms");
        let least = m.iter().min_by(|a, b| total(a).total_cmp(&total(b))).expect("measured");
        assert_eq!(least["structure"], v["selected"], "{scene}: {m:?}");
        assert!(m.iter().all(|t| t["rays"].as_u64() == Some(128 * 128) && t["repeats"].as_u64() == Some(3)), "{m:?}");
        // The same scene with a measuring budget nothing fits: nothing measured, and the reason says so.
        let out = run("characterize", &[&[scene.as_str()][..], &a[..], &["--measure-max-ms", "0.000001"][..]].concat());
        let (stdout, _) = text(&out);
        let v: serde_json::Value = serde_json::from_str(stdout.lines().next().unwrap_or_default()).expect("JSON");
        assert!(v["measured"].is_null(), "{}", v["measured"]);
        assert!(v["reasons"].to_string().contains("allowed"), "{}", v["reasons"]);
    }
    assert!(measured > 0, "a close call among the seven families");
    assert!(!overlapping_report(&[])["reasons"].to_string().contains("measured close call"));
    assert_usage_error("characterize", &["--backend", "cpu", "--measure-max-ms", "10"]);
    assert_usage_error("characterize", &["--backend", "cpu", "--measure-close-calls", "--measure-max-ms", "0"]);

    let file = family_records(&dir);
    let model = root.join("assets/cost-model-cpu.json");
    let json = evaluate_json(&[
        "--compare-policies",
        arg(&file),
        "--cost-model",
        arg(&model),
        "--measure-close-calls",
        "--json",
    ]);
    let policies = json[0]["baselines"]["policies"].as_array().expect("policies");
    for holdout in ["scene_out", "family_out"] {
        let p = policy_run(&json[0], "calibrated_measured", holdout);
        assert_eq!(p["overall"]["scored"].as_u64(), Some(56), "{p}");
    }
    assert!(!policies.iter().any(|p| p["policy"] == "calibrated_timed"), "no timed probes asked for");
    assert_eq!(json[1]["fixed_cost_model"]["measured_score"]["scored"].as_u64(), Some(56), "{}", json[1]);
    assert!(json[1]["fixed_cost_model"]["timed_score"].is_null());
    assert_usage_error("evaluate", &["--measure-close-calls", "family:city:2k:1"]);
    // The oracle against itself: the records as their own second run regret nothing.
    let json = evaluate_json(&["--compare-policies", arg(&file), "--repeat-oracle", arg(&file), "--json"]);
    let policies = json[0]["baselines"]["policies"].as_array().expect("policies");
    let p = policy_run(&json[0], "repeat_oracle", "repeat");
    assert_eq!(p["overall"]["scored"].as_u64(), Some(56), "{p}");
    assert_eq!(p["overall"]["mean_regret"].as_f64(), Some(0.0), "{p}");
    assert!(!policies.iter().any(|p| p["policy"] == "calibrated_measured"), "nothing measured unless asked");
    assert_usage_error(
        "evaluate",
        &["--compare-policies", arg(&file), "--repeat-oracle", arg(&file), "--frames-sweep", "1,10"],
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// An output that cannot be written (`> /dev/full`: no space left) ends a tool with the error on standard error and
/// status 1, not a panic: `characterize` (text and JSON) and `build_bvh`, all through `support::cli::main_with`; and
/// `--help` / `-h`, which clap would print itself and report as written.
#[test]
fn a_full_standard_output_is_an_error_not_a_panic() {
    let full = Path::new("/dev/full");
    if !full.exists() {
        eprintln!("skipping: no /dev/full on this system");
        return;
    }
    let cases: [(&str, &[&str]); 5] = [
        ("characterize", &["family:city:200:1", "--backend", "cpu"]),
        ("characterize", &["family:city:200:1", "--backend", "cpu", "--json"]),
        ("build_bvh", &["family:city:200:1", "--builder", "sah"]),
        ("evaluate", &["--help"]),
        ("tradeoff", &["-h"]),
    ];
    for (name, args) in cases {
        let out = Command::new(binary(name))
            .args(args)
            .stdin(Stdio::null())
            .stdout(std::fs::OpenOptions::new().write(true).open(full).expect("open /dev/full"))
            .output()
            .unwrap_or_else(|e| panic!("cannot run {name}: {e}"));
        let (_, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(1), "{name} {args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{name}: {stderr}");
        assert!(stderr.starts_with(&format!("{name}: cannot write to standard output: ")), "{name}: {stderr:?}");
    }
}

/// A scene that would need more memory than the process may have is refused with the figures, not aborted in an
/// allocation: under an address-space limit of about 1.9 GiB (`ulimit -v`), 5 million triangles (2.4 GiB at
/// `BYTES_PER_TRIANGLE`) are refused by `characterize`, 8 million (2.4 GiB at `BUILD_BYTES_PER_TRIANGLE`) by
/// `build_bvh`, and 20,000 run; a record naming 5 million is refused by `evaluate --compare-policies` and `calibrate
/// --from-oracle`.
#[test]
fn a_scene_past_the_memory_it_may_have_is_refused_with_the_figures() {
    if !Path::new("/proc/self/limits").exists() || !Path::new("/bin/sh").exists() {
        eprintln!("skipping: no /proc/self/limits or /bin/sh on this system");
        return;
    }
    let limited = |name: &str, args: &str| {
        let cmd = format!("ulimit -v 2000000 && exec '{}' {args}", binary(name).display());
        Command::new("/bin/sh").args(["-c", &cmd]).stdin(Stdio::null()).output().expect("run under sh")
    };
    for (name, args) in
        [("characterize", "family:city:5000000:1 --backend cpu"), ("build_bvh", "family:city:8000000:1 --builder sah")]
    {
        let out = limited(name, args);
        let (_, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {stderr}");
        assert!(!stderr.contains("panicked") && !stderr.contains("memory allocation"), "{name}: {stderr}");
        let scene = args.split(' ').next().unwrap_or_default();
        let n = scene.split(':').nth(2).unwrap_or_default();
        assert!(stderr.starts_with(&format!("{name}: {scene}: {n} triangles need about ")), "{name}: {stderr:?}");
    }
    let out = limited("characterize", "family:city:20000:1 --backend cpu");
    assert!(out.status.success(), "{}", text(&out).1);
    // A scene named by an oracle record, not on the command line: `evaluate --compare-policies` and `calibrate
    // --from-oracle` refuse it the same way, naming the file and the record's mesh.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let lines = std::fs::read_to_string(root.join("docs/data/families-seed2-primary.jsonl")).expect("records");
    let mut rec: serde_json::Value = serde_json::from_str(lines.lines().next().expect("a record")).expect("JSON");
    rec["mesh"] = serde_json::json!("family:city:5000000:1");
    let dir = std::env::temp_dir().join(format!("meshchar-examples-cli-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let file = dir.join("huge.jsonl");
    std::fs::write(&file, format!("{rec}\n")).expect("write");
    for (name, flag) in [("evaluate", "--compare-policies"), ("calibrate", "--from-oracle")] {
        let out = limited(name, &format!("{flag} '{}'", file.display()));
        let (_, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {stderr}");
        assert!(!stderr.contains("panicked") && !stderr.contains("memory allocation"), "{name}: {stderr}");
        let want = format!("{}: family:city:5000000:1: 5000000 triangles need about ", file.display());
        assert!(stderr.contains(&want), "{name}: {stderr:?}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `tradeoff --oracle FILE` refuses a file whose records name no validly measured structure (every structure
/// invalid, or a negative total), as `evaluate` does, instead of scoring nothing and succeeding.
#[test]
fn tradeoff_refuses_oracle_records_without_a_valid_structure() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let lines = std::fs::read_to_string(root.join("docs/data/families-seed2-primary.jsonl")).expect("records");
    let mut rec: serde_json::Value = serde_json::from_str(lines.lines().next().expect("a record")).expect("JSON");
    let dir = std::env::temp_dir().join(format!("meshchar-examples-cli-tradeoff-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let structures = rec["structures"].as_array().expect("structures").len();
    for (label, field, value) in
        [("invalid", "valid", serde_json::json!(false)), ("negative", "total_ms", serde_json::json!(-1.0))]
    {
        for k in 0..structures {
            rec["structures"][k][field] = value.clone();
        }
        let file = dir.join(format!("{label}.jsonl"));
        std::fs::write(&file, format!("{rec}\n")).expect("write");
        let out = run("tradeoff", &["--oracle", file.to_str().expect("path"), "--out", dir.to_str().expect("path")]);
        let (_, stderr) = text(&out);
        assert_eq!(out.status.code(), Some(1), "{label}: {stderr}");
        assert!(stderr.contains("no record names a validly measured structure"), "{label}: {stderr}");
        let mut restore: serde_json::Value =
            serde_json::from_str(lines.lines().next().expect("a record")).expect("JSON");
        std::mem::swap(&mut rec, &mut restore);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
