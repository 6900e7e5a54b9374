//! Calibration files: the shipped one is valid and canonical, an explicit path that cannot be used is an error
//! (never the shipped model in its place), and every rule of `CostModel::validate` refuses what it should, naming
//! the field and the structure.

use super::common;

use meshchar::accel::StructureName;
use meshchar::cost::{
    registry, CostError, CostModel, TraceTarget, COST_MODEL_VERSION, FEATURE_NAMES, PRICE_NAMES, SHIPPED_CPU,
    SHIPPED_MODELS,
};
use meshchar::eval::oracle::{DeviceRecord, TraceBackend};
use serde_json::{json, Value};
use std::path::PathBuf;

fn shipped() -> CostModel {
    CostModel::shipped().expect("the shipped calibration is valid")
}

/// The shipped file as a JSON value, to edit.
fn shipped_json() -> Value {
    serde_json::from_str(SHIPPED_CPU).unwrap()
}

/// The error of the shipped file with one edit.
fn refused(edit: impl FnOnce(&mut Value)) -> CostError {
    let mut v = shipped_json();
    edit(&mut v);
    match CostModel::from_json(&v.to_string()) {
        Ok(_) => panic!("accepted after the edit: {v}"),
        Err(e) => e,
    }
}

/// `e` is `Invalid` for exactly `field` (and `structure`), and its message names the field.
fn assert_invalid(e: &CostError, want_field: &str, want_structure: Option<StructureName>) {
    match e {
        CostError::Invalid { field, structure, .. } => {
            assert_eq!(field, want_field, "{e}");
            assert_eq!(*structure, want_structure, "{e}");
        }
        other => panic!("expected Invalid({want_field}), got {other:?}"),
    }
    assert!(e.to_string().starts_with(&format!("{want_field}: ")), "{e}");
}

fn write(name: &str, text: &str) -> PathBuf {
    common::temp_file(name, text.as_bytes())
}

#[test]
fn the_shipped_file_is_valid_canonical_and_round_trips() {
    let m = shipped();
    m.validate().unwrap();
    assert_eq!(m.version, COST_MODEL_VERSION);
    assert_eq!(m.feature_names, FEATURE_NAMES);
    assert_eq!(m.price_names, PRICE_NAMES);
    let names: Vec<StructureName> = m.structures.iter().map(|s| s.structure).collect();
    assert_eq!(names, StructureName::ALL, "the shipped default covers every structure once");
    // to_json then from_json gives the same model, and the shipped text is exactly what to_json writes (as `save`
    // writes it: with a final newline), so the file has no field the model drops.
    let text = m.to_json();
    assert_eq!(CostModel::from_json(&text).unwrap(), m);
    assert_eq!(text + "\n", SHIPPED_CPU);
    // The file on disk is the one compiled in.
    let disk =
        std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("assets/cost-model-cpu.json")).unwrap();
    assert_eq!(disk, SHIPPED_CPU);
}

#[test]
fn the_implicit_default_is_the_shipped_model() {
    assert_eq!(CostModel::load(None).unwrap(), shipped());
}

#[test]
fn an_explicit_file_is_loaded_as_written() {
    let mut m = shipped();
    m.device = "another device".into();
    m.structures[0].build_ln_a = -7.25;
    let path = common::temp_dir("cost-file").join("cal.json");
    m.save(&path).unwrap();
    let back = CostModel::load(Some(&path)).unwrap();
    assert_eq!(back, m);
    assert_ne!(back, shipped());
}

#[test]
fn a_missing_explicit_file_is_an_error_not_the_shipped_model() {
    let path = common::temp_dir("cost-file").join("missing.json");
    let e = CostModel::load(Some(&path)).unwrap_err();
    assert!(
        matches!(&e, CostError::Io { path: p, source } if *p == path.display().to_string()
        && source.kind() == std::io::ErrorKind::NotFound),
        "{e:?}"
    );
    assert!(e.to_string().contains("missing.json"), "{e}");
    // A directory is not readable as a file either.
    let dir = common::temp_dir("cost-file");
    assert!(matches!(CostModel::load(Some(&dir)), Err(CostError::Io { .. })));
}

#[test]
fn broken_json_is_an_error_with_the_path() {
    for (name, text) in [("garbage.json", "{ not json"), ("empty.json", ""), ("truncated.json", &SHIPPED_CPU[..500])] {
        let path = write(name, text);
        let e = CostModel::load(Some(&path)).unwrap_err();
        match &e {
            CostError::File { path: p, source } => {
                assert_eq!(*p, path.display().to_string());
                assert!(matches!(**source, CostError::Parse(_)), "{name}: {source:?}");
            }
            other => panic!("{name}: {other:?}"),
        }
        assert!(e.to_string().contains(&path.display().to_string()), "{e}");
    }
    // JSON, but not an object.
    assert_invalid(&CostModel::from_json("[1, 2]").unwrap_err(), "top level", None);
}

#[test]
fn a_negative_price_is_an_error_naming_it() {
    let mut v = shipped_json();
    v["structures"][2]["trace_price"][3] = json!(-1.5);
    let path = write("negative.json", &v.to_string());
    let e = CostModel::load(Some(&path)).unwrap_err();
    let CostError::File { source, .. } = &e else { panic!("{e:?}") };
    assert_invalid(source, "structures[2] (grid).trace_price[3] (box)", Some(StructureName::Grid));
    let msg = e.to_string();
    assert!(msg.contains(&path.display().to_string()) && msg.contains("-1.5"), "{msg}");
    // Every price column, on every structure.
    for (i, s) in StructureName::ALL.iter().enumerate() {
        for (j, p) in PRICE_NAMES.iter().enumerate() {
            let e = refused(|v| v["structures"][i]["trace_price"][j] = json!(-1e-9));
            assert_invalid(&e, &format!("structures[{i}] ({s}).trace_price[{j}] ({p})"), Some(*s));
        }
    }
    // Zero is a price (the shipped file has zeros), but not every price zero, and not a millisecond per test.
    let e = refused(|v| v["structures"][1]["trace_price"] = json!(vec![0.0; PRICE_NAMES.len()]));
    assert_invalid(&e, "structures[1] (kdtree).trace_price", Some(StructureName::KdTree));
    let e = refused(|v| v["structures"][1]["trace_price"][4] = json!(2e6));
    assert_invalid(&e, "structures[1] (kdtree).trace_price[4] (prim)", Some(StructureName::KdTree));
    // One price too few or too many.
    let e = refused(|v| {
        v["structures"][0]["trace_price"].as_array_mut().unwrap().pop();
    });
    assert_invalid(&e, "structures[0] (bvh).trace_price", Some(StructureName::Bvh));
}

#[test]
fn reordered_or_renamed_feature_names_are_errors_naming_the_first_mismatch() {
    // ln_n and ln_tris_per_cell swapped: position 3 is the first that differs.
    let e = refused(|v| v["feature_names"].as_array_mut().unwrap().swap(3, 4));
    assert_invalid(&e, "feature_names[3]", None);
    assert!(e.to_string().contains("\"ln_tris_per_cell\", expected \"ln_n\""), "{e}");
    let e = refused(|v| v["feature_names"][9] = json!("aspect"));
    assert_invalid(&e, "feature_names[9]", None);
    let e = refused(|v| {
        v["feature_names"].as_array_mut().unwrap().pop();
    });
    assert_invalid(&e, "feature_names[9]", None);
    let e = refused(|v| v["feature_names"].as_array_mut().unwrap().push(json!("extra")));
    assert_invalid(&e, "feature_names[10]", None);
    let e = refused(|v| {
        v.as_object_mut().unwrap().remove("feature_names");
    });
    assert_invalid(&e, "top level", None);
    assert!(e.to_string().contains("feature_names"), "{e}");
    // The price names likewise.
    let e = refused(|v| v["price_names"].as_array_mut().unwrap().swap(3, 5));
    assert_invalid(&e, "price_names[3]", None);
    let e = refused(|v| v["price_names"][0] = json!("ray"));
    assert_invalid(&e, "price_names[0]", None);
    let e = refused(|v| {
        v.as_object_mut().unwrap().remove("price_names");
    });
    assert!(e.to_string().contains("price_names"), "{e}");
}

#[test]
fn non_finite_coefficients_are_errors_naming_them() {
    // serde_json writes NaN and the infinities as null; reading the file back names the coefficient.
    for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut m = shipped();
        m.structures[3].box_coef[5] = x;
        let e = CostModel::from_json(&m.to_json()).unwrap_err();
        assert_invalid(&e, "structures[3] (bih).box_coef[5] (fill_at_n)", Some(StructureName::Bih));
        // validate() on the model itself says the same.
        assert_invalid(
            &m.validate().unwrap_err(),
            "structures[3] (bih).box_coef[5] (fill_at_n)",
            Some(StructureName::Bih),
        );
        let mut m = shipped();
        m.structures[4].prim_coef[0] = x;
        assert_invalid(
            &m.validate().unwrap_err(),
            "structures[4] (lbvh).prim_coef[0] (intercept)",
            Some(StructureName::Lbvh),
        );
        let mut m = shipped();
        m.structures[5].build_exponent = x;
        let e = CostModel::from_json(&m.to_json()).unwrap_err();
        assert_invalid(&e, "structures[5] (hlbvh).build_exponent", Some(StructureName::Hlbvh));
        let mut m = shipped();
        m.total_rms_log = x;
        assert_invalid(&CostModel::from_json(&m.to_json()).unwrap_err(), "total_rms_log", None);
    }
    // A number beyond f64 in the text is not JSON serde_json reads.
    let ln_a = format!("\"build_ln_a\": {}", shipped().structures[0].build_ln_a);
    let text = SHIPPED_CPU.replacen(&ln_a, "\"build_ln_a\": -1e400", 1);
    assert_ne!(text, SHIPPED_CPU);
    assert!(CostModel::from_json(&text).is_err());
    // Huge but finite coefficients would overflow theta . phi.
    let e = refused(|v| v["structures"][0]["prim_coef"][3] = json!(1e300));
    assert_invalid(&e, "structures[0] (bvh).prim_coef[3] (ln_n)", Some(StructureName::Bvh));
    let e = refused(|v| v["structures"][0]["prim_coef"][3] = json!(-1000.5));
    assert_invalid(&e, "structures[0] (bvh).prim_coef[3] (ln_n)", Some(StructureName::Bvh));
    let e = refused(|v| {
        v["structures"][1]["box_coef"].as_array_mut().unwrap().push(json!(0.0));
    });
    assert_invalid(&e, "structures[1] (kdtree).box_coef", Some(StructureName::KdTree));
}

#[test]
fn another_version_is_an_error() {
    let e = refused(|v| v["version"] = json!(COST_MODEL_VERSION + 1));
    assert!(
        matches!(e, CostError::Version { found, expected } if found == u64::from(COST_MODEL_VERSION) + 1
        && expected == COST_MODEL_VERSION),
        "{e:?}"
    );
    assert!(e.to_string().starts_with("version: "), "{e}");
    let e = refused(|v| v["version"] = json!(1u64 << 40));
    assert!(matches!(e, CostError::Version { found, .. } if found == 1 << 40), "{e:?}");
    assert_invalid(&refused(|v| v["version"] = json!("1")), "version", None);
    assert_invalid(&refused(|v| v["version"] = json!(1.5)), "version", None);
    assert_invalid(
        &refused(|v| {
            v.as_object_mut().unwrap().remove("version");
        }),
        "version",
        None,
    );
    // Through load: the path, then the version.
    let mut v = shipped_json();
    v["version"] = json!(0);
    let path = write("stale.json", &v.to_string());
    let e = CostModel::load(Some(&path)).unwrap_err();
    assert!(matches!(&e, CostError::File { source, .. } if matches!(**source, CostError::Version { found: 0, .. })));
}

#[test]
fn the_device_is_required() {
    assert_invalid(&refused(|v| v["device"] = json!("  ")), "device", None);
    assert_invalid(&refused(|v| v["device"] = json!(3)), "device", None);
    assert_invalid(
        &refused(|v| {
            v.as_object_mut().unwrap().remove("device");
        }),
        "device",
        None,
    );
}

#[test]
fn structure_names_are_known_and_not_duplicated() {
    let e = refused(|v| v["structures"][2]["structure"] = json!("octree"));
    assert_invalid(&e, "structures[2].structure", None);
    assert!(e.to_string().contains("\"octree\""), "{e}");
    // Brute force is the reference, never a calibrated structure.
    assert_invalid(&refused(|v| v["structures"][0]["structure"] = json!("brute")), "structures[0].structure", None);
    assert_invalid(&refused(|v| v["structures"][0]["structure"] = json!(1)), "structures[0].structure", None);
    // lbvh twice: the second one is named.
    let e = refused(|v| v["structures"][5]["structure"] = json!("lbvh"));
    assert_invalid(&e, "structures[5].structure", Some(StructureName::Lbvh));
    assert!(e.to_string().contains("structures[4]"), "{e}");
    let e = refused(|v| v["structures"] = json!([]));
    assert_invalid(&e, "structures", None);
    assert_invalid(&refused(|v| v["structures"] = json!({})), "structures", None);
    // A field of a structure missing, or one it does not have.
    let e = refused(|v| {
        v["structures"][1].as_object_mut().unwrap().remove("build_exponent");
    });
    assert_invalid(&e, "structures[1] (kdtree)", Some(StructureName::KdTree));
    assert!(e.to_string().contains("build_exponent"), "{e}");
    let e = refused(|v| v["structures"][1]["build_exp"] = json!(1.0));
    assert_invalid(&e, "structures[1] (kdtree)", Some(StructureName::KdTree));
    // An unknown top-level key (a misspelled `refit` would otherwise read as no refit model).
    let e = refused(|v| v["refit_model"] = v["refit"].clone());
    assert_invalid(&e, "top level", None);
    assert!(e.to_string().contains("refit_model"), "{e}");
}

#[test]
fn build_law_constants_are_in_range() {
    let bvh = Some(StructureName::Bvh);
    for b in [-0.01, 2.01, 10.0] {
        let e = refused(|v| v["structures"][0]["build_exponent"] = json!(b));
        assert_invalid(&e, "structures[0] (bvh).build_exponent", bvh);
    }
    for a in [-23.5, 9.5] {
        let e = refused(|v| v["structures"][0]["build_ln_a"] = json!(a));
        assert_invalid(&e, "structures[0] (bvh).build_ln_a", bvh);
    }
    // The ends of the ranges are accepted (by a law without curvature, whose slope is b at every size).
    for (a, b) in [(-23.0, 0.0), (9.0, 2.0)] {
        let mut v = shipped_json();
        v["structures"][0]["build_ln_a"] = json!(a);
        v["structures"][0]["build_exponent"] = json!(b);
        v["structures"][0]["build_curvature"] = json!(0.0);
        CostModel::from_json(&v.to_string()).unwrap();
    }
    let e = refused(|v| v["structures"][3]["fit"]["total"] = json!(-0.1));
    assert_invalid(&e, "structures[3] (bih).fit.total", Some(StructureName::Bih));
    assert_invalid(&refused(|v| v["total_rms_log"] = json!(-1.0)), "total_rms_log", None);
}

#[test]
fn refit_model_fields_are_in_range() {
    for (field, bad) in [
        ("sah_growth_per_drift", json!(-0.5)),
        ("sah_growth_per_drift", json!(1000.5)),
        ("refit_ns_per_triangle", json!(0.0)),
        ("refit_ns_per_triangle", json!(-3.0)),
        ("refit_ns_per_triangle", json!(2e6)),
        ("fit_rms", json!(-0.01)),
        ("samples", json!(0)),
    ] {
        let e = refused(|v| v["refit"][field] = bad.clone());
        assert_invalid(&e, &format!("refit.{field}"), None);
    }
    // No refit model is fine.
    let mut v = shipped_json();
    v.as_object_mut().unwrap().remove("refit");
    assert_eq!(CostModel::from_json(&v.to_string()).unwrap().refit, None);
    v["refit"] = Value::Null;
    assert_eq!(CostModel::from_json(&v.to_string()).unwrap().refit, None);
}

/// lavapipe's device record as `evaluate --trace-backend vulkan` writes it on the build machine, with another UUID
/// when `uuid` is given.
fn lavapipe_record(uuid: &str) -> DeviceRecord {
    DeviceRecord {
        name: "llvmpipe (LLVM 15.0.6, 256 bits)".into(),
        device_type: "cpu".into(),
        driver: "llvmpipe Mesa 22.3.6 (LLVM 15.0.6)".into(),
        driver_version: 1,
        device_uuid: uuid.into(),
    }
}

/// The shipped CPU model turned into a device calibration of `device`.
fn device_model(device: DeviceRecord) -> CostModel {
    CostModel {
        device: device.name.clone(),
        trace_backend: TraceBackend::Vulkan,
        trace_device: Some(device),
        ..shipped()
    }
}

#[test]
fn a_file_without_the_tracer_fields_is_a_cpu_calibration() {
    let mut v = shipped_json();
    let obj = v.as_object_mut().unwrap();
    assert_eq!(obj.remove("trace_backend"), Some(json!("cpu")), "the shipped CPU file says cpu");
    assert!(!obj.contains_key("trace_device"), "a CPU file names no device");
    let m = CostModel::from_json(&v.to_string()).expect("a file written before the fields existed loads");
    assert_eq!((m.trace_backend, m.trace_device), (TraceBackend::Cpu, None));
}

#[test]
fn a_device_calibration_round_trips_its_device_fields() {
    let m = device_model(lavapipe_record("6d65736132322e332e36000000000000"));
    let text = m.to_json();
    let v: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["trace_backend"], "vulkan");
    assert_eq!(v["trace_device"]["name"], "llvmpipe (LLVM 15.0.6, 256 bits)");
    assert_eq!(v["trace_device"]["driver"], "llvmpipe Mesa 22.3.6 (LLVM 15.0.6)");
    assert_eq!(v["trace_device"]["driver_version"], 1);
    assert_eq!(v["trace_device"]["device_uuid"], "6d65736132322e332e36000000000000");
    assert!(v.get("chosen_as").is_none(), "how a model was chosen is not part of the file: {v}");
    assert_eq!(CostModel::from_json(&text).unwrap(), m);
    let path = common::temp_dir("cost-file").join("device.json");
    m.save(&path).unwrap();
    assert_eq!(CostModel::load(Some(&path)).unwrap(), m);
}

#[test]
fn the_tracer_fields_are_validated() {
    let e = refused(|v| v["trace_backend"] = json!("vulkan"));
    assert_invalid(&e, "trace_device", None);
    let record = serde_json::to_value(lavapipe_record("")).unwrap();
    let e = refused(|v| v["trace_device"] = record.clone());
    assert_invalid(&e, "trace_device", None);
    let e = refused(|v| {
        v["trace_backend"] = json!("vulkan");
        v["trace_device"] = json!({"name": " "});
    });
    assert_invalid(&e, "trace_device.name", None);
    assert!(matches!(refused(|v| v["trace_backend"] = json!("metal")), CostError::Invalid { .. }));
}

#[test]
fn the_registry_picks_by_uuid_then_by_name_then_falls_back_to_the_cpu() {
    let lavapipe_uuid = "6d65736132322e332e36000000000000";
    let gpu = DeviceRecord {
        name: "Some Discrete GPU".into(),
        device_type: "discrete".into(),
        driver: "vendor 1.2".into(),
        driver_version: 7,
        device_uuid: "00112233445566778899aabbccddeeff".into(),
    };
    let candidates = [shipped(), device_model(lavapipe_record(lavapipe_uuid)), device_model(gpu.clone())];
    assert_eq!(registry::choose(&candidates, TraceTarget::Cpu).map(|c| c.index), Some(0));
    // lavapipe of the same Mesa: the UUID matches.
    let same = lavapipe_record(lavapipe_uuid);
    let c = registry::choose(&candidates, TraceTarget::Device(&same)).unwrap();
    assert_eq!(c.index, 1);
    assert!(c.reason.contains("UUID"), "{}", c.reason);
    // Another lavapipe build: another UUID and driver, matched by name, the driver said.
    let other = DeviceRecord { driver: "llvmpipe Mesa 23.1".into(), driver_version: 2, ..lavapipe_record("ff") };
    let c = registry::choose(&candidates, TraceTarget::Device(&other)).unwrap();
    assert_eq!(c.index, 1);
    assert!(c.reason.contains("lavapipe, matched by name") && c.reason.contains("Mesa 23.1"), "{}", c.reason);
    // The UUID first: a record with the GPU's UUID under another name is the GPU.
    let renamed = DeviceRecord { name: "renamed".into(), ..gpu.clone() };
    assert_eq!(registry::choose(&candidates, TraceTarget::Device(&renamed)).unwrap().index, 2);
    // A device with no calibration: the CPU's, and the reason says so.
    let unknown = DeviceRecord { name: "Unknown GPU".into(), device_uuid: "aa".into(), ..gpu };
    let c = registry::choose(&candidates, TraceTarget::Device(&unknown)).unwrap();
    assert_eq!(c.index, 0);
    assert!(c.reason.contains("no calibration of Unknown GPU"), "{}", c.reason);
    // No CPU calibration to fall back on: none.
    assert_eq!(registry::choose(&candidates[1..], TraceTarget::Device(&unknown)), None);
}

#[test]
fn the_shipped_models_are_chosen_by_tracer_and_an_explicit_file_wins() {
    let cpu = CostModel::for_trace_target(None, TraceTarget::Cpu).unwrap();
    assert_eq!(cpu.trace_backend, TraceBackend::Cpu);
    let said = cpu.chosen_as.clone().unwrap();
    assert!(said.starts_with("assets/cost-model-cpu.json: "), "{said}");
    let path = common::temp_dir("cost-file").join("explicit.json");
    shipped().save(&path).unwrap();
    let device = lavapipe_record("6d65736132322e332e36000000000000");
    let m = CostModel::for_trace_target(Some(&path), TraceTarget::Device(&device)).unwrap();
    let said = m.chosen_as.clone().unwrap();
    assert!(said.starts_with(&format!("{}: --cost-model, measured with cpu", path.display())), "{said}");
    assert_eq!(CostModel { chosen_as: None, ..m }, shipped());
    let missing = common::temp_dir("cost-file").join("no-such-model.json");
    assert!(matches!(CostModel::for_trace_target(Some(&missing), TraceTarget::Cpu), Err(CostError::Io { .. })));
}

#[test]
fn the_shipped_lavapipe_file_is_canonical_and_chosen_on_lavapipe_only() {
    let models = CostModel::shipped_models().expect("every shipped file is valid");
    assert_eq!(models.len(), SHIPPED_MODELS.len());
    for (m, s) in models.iter().zip(SHIPPED_MODELS) {
        assert_eq!(m.to_json() + "\n", s.text, "{} is what to_json writes", s.file);
    }
    let lavapipe = &models[1];
    assert_eq!(SHIPPED_MODELS[1].file, "assets/cost-model-lavapipe.json");
    assert_eq!(lavapipe.trace_backend, TraceBackend::Vulkan);
    let recorded = lavapipe.trace_device.clone().expect("the lavapipe file names its device");
    assert_eq!(registry::device_family(&recorded), "lavapipe", "{recorded:?}");
    let names: Vec<StructureName> = lavapipe.structures.iter().map(|s| s.structure).collect();
    assert_eq!(names, StructureName::ALL, "the lavapipe file covers every structure once");
    // The same device: by UUID. Another lavapipe (another Mesa, another UUID): by name.
    for (device, how) in [
        (recorded.clone(), "the device UUID"),
        (lavapipe_record("0123456789abcdef0123456789abcdef"), "lavapipe, matched by name"),
        (DeviceRecord { name: "llvmpipe (LLVM 17.0.6, 128 bits)".into(), ..lavapipe_record("") }, "by name"),
    ] {
        let m = CostModel::for_trace_target(None, TraceTarget::Device(&device)).unwrap();
        let said = m.chosen_as.clone().unwrap();
        assert!(said.starts_with("assets/cost-model-lavapipe.json: ") && said.contains(how), "{said}");
        assert_eq!(CostModel { chosen_as: None, ..m }, *lavapipe);
    }
    // Any other device, and the CPU tracer: the CPU file.
    let gpu = DeviceRecord { name: "NVIDIA H200".into(), driver: "NVIDIA 550".into(), ..lavapipe_record("ab") };
    let m = CostModel::for_trace_target(None, TraceTarget::Device(&gpu)).unwrap();
    assert!(m.chosen_as.as_deref().unwrap().starts_with("assets/cost-model-cpu.json: no calibration of NVIDIA H200"));
    assert_eq!(CostModel { chosen_as: None, ..m }, shipped());
    let m = CostModel::for_trace_target(None, TraceTarget::Cpu).unwrap();
    assert_eq!(CostModel { chosen_as: None, ..m }, shipped());
}

#[test]
fn crossing_coefficients_are_none_or_two_in_range_and_round_trip() {
    // Two, in range: written and read back as they are.
    let mut m = shipped();
    m.structures[2].crossing_coef = vec![0.5, -0.25];
    let back = CostModel::from_json(&m.to_json()).unwrap();
    assert_eq!(back.structures[2].crossing_coef, vec![0.5, -0.25]);
    // The shipped file has none, and writes none.
    assert!(shipped().structures.iter().all(|s| s.crossing_coef.is_empty()));
    assert!(!shipped().to_json().contains("crossing_coef"));
    // One, or three: an error naming the field.
    for bad in [json!([0.5]), json!([0.5, 0.5, 0.5])] {
        let e = refused(|v| v["structures"][2]["crossing_coef"] = bad.clone());
        assert_invalid(&e, "structures[2] (grid).crossing_coef", Some(StructureName::Grid));
    }
    let e = refused(|v| v["structures"][2]["crossing_coef"] = json!([0.5, 1e4]));
    assert_invalid(&e, "structures[2] (grid).crossing_coef[1] (prim)", Some(StructureName::Grid));
    let mut m = shipped();
    m.structures[2].crossing_coef = vec![f64::NAN, 0.0];
    assert_invalid(
        &m.validate().unwrap_err(),
        "structures[2] (grid).crossing_coef[0] (box)",
        Some(StructureName::Grid),
    );
}

#[test]
fn crossing_means_are_none_or_three_in_range_and_only_with_coefficients() {
    let mut m = shipped();
    m.structures[2].crossing_coef = vec![0.5, -0.25];
    m.structures[2].crossing_mean = vec![1.5, 2.0, 0.0];
    let back = CostModel::from_json(&m.to_json()).unwrap();
    assert_eq!(back.structures[2].crossing_mean, vec![1.5, 2.0, 0.0]);
    assert!(!shipped().to_json().contains("crossing_mean"));
    // Two, or four: an error naming the field; a negative or a huge mean names the value.
    for bad in [json!([1.0, 1.0]), json!([1.0, 1.0, 1.0, 1.0])] {
        let e = CostModel::from_json(&{
            let mut v: serde_json::Value = serde_json::from_str(&m.to_json()).unwrap();
            v["structures"][2]["crossing_mean"] = bad.clone();
            v.to_string()
        })
        .unwrap_err();
        assert_invalid(&e, "structures[2] (grid).crossing_mean", Some(StructureName::Grid));
    }
    for (j, bad) in [(0, -0.5), (2, 46.0)] {
        let mut b = m.clone();
        b.structures[2].crossing_mean[j] = bad;
        let name = ["primary", "shadow", "diffuse"][j];
        let field = format!("structures[2] (grid).crossing_mean[{j}] ({name})");
        assert_invalid(&b.validate().unwrap_err(), &field, Some(StructureName::Grid));
    }
    // Means without coefficients: refused, a model without them reads no count.
    let e = refused(|v| v["structures"][2]["crossing_mean"] = json!([1.0, 1.0, 1.0]));
    assert_invalid(&e, "structures[2] (grid).crossing_mean", Some(StructureName::Grid));
}

#[test]
fn a_work_law_is_none_three_or_four_constants_in_range() {
    let mut m = shipped();
    m.structures[2].build_work_coef = vec![-9.0, 0.9, 0.7];
    let back = CostModel::from_json(&m.to_json()).unwrap();
    assert_eq!(back.structures[2].build_work_coef, vec![-9.0, 0.9, 0.7]);
    for bad in [json!([-9.0, 0.9]), json!([-9.0, 0.9, 0.7, 0.1, 0.2])] {
        let e = CostModel::from_json(&{
            let mut v: serde_json::Value = serde_json::from_str(&m.to_json()).unwrap();
            v["structures"][2]["build_work_coef"] = bad.clone();
            v.to_string()
        })
        .unwrap_err();
        assert_invalid(&e, "structures[2] (grid).build_work_coef", Some(StructureName::Grid));
    }
    // Each constant in its range: ln a as the plain law's, the exponents of n and of the work per triangle in [0, 2].
    for (j, bad) in [(0, 10.0), (1, -0.1), (2, -0.5), (2, 2.5), (2, f64::NAN)] {
        let mut b = m.clone();
        b.structures[2].build_work_coef[j] = bad;
        let field = format!("structures[2] (grid).build_work_coef[{j}]");
        assert_invalid(&b.validate().unwrap_err(), &field, Some(StructureName::Grid));
    }
    // A fourth constant, the curvature, in [0, 1], with the range of sizes it was fitted on.
    m.structures[2].build_work_coef = vec![-9.0, 0.9, 0.7, 0.05];
    m.structures[2].build_ln_n_range = vec![7.0, 13.0];
    assert_eq!(CostModel::from_json(&m.to_json()).unwrap(), m);
    for bad in [-0.01, 1.5, f64::INFINITY] {
        let mut b = m.clone();
        b.structures[2].build_work_coef[3] = bad;
        assert_invalid(
            &b.validate().unwrap_err(),
            "structures[2] (grid).build_work_coef[3]",
            Some(StructureName::Grid),
        );
    }
}

#[test]
fn a_curved_build_law_needs_its_range_of_sizes_and_a_curvature_in_range() {
    let m = shipped();
    // The shipped fit bends its laws (its sizes span 1K to 871K triangles).
    assert!(m.structures.iter().any(|s| s.build_curvature > 0.0 && s.build_ln_n_range.len() == 2), "{m:?}");
    let (i, _) = m.structures.iter().enumerate().find(|(_, s)| s.build_curvature > 0.0).unwrap();
    let st = Some(m.structures[i].structure);
    let name = m.structures[i].structure.as_str();
    let field = |f: &str| format!("structures[{i}] ({name}).{f}");
    for bad in [-0.1, 1.01, f64::NAN] {
        let mut b = m.clone();
        b.structures[i].build_curvature = bad;
        assert_invalid(&b.validate().unwrap_err(), &field("build_curvature"), st);
    }
    let beyond = meshchar::cost::BUILD_LN_N_LIMIT + 0.1;
    for bad in [
        vec![],
        vec![7.0],
        vec![13.0, 7.0],
        vec![7.0, f64::NAN],
        vec![-1.0, 7.0],
        vec![7.0, 8.0, 9.0],
        vec![7.0, beyond],
    ] {
        let mut b = m.clone();
        b.structures[i].build_ln_n_range = bad.clone();
        let e = b.validate().unwrap_err();
        assert_invalid(&e, &field("build_ln_n_range"), st);
    }
    // A curvature whose law would fall with more triangles at the edge of its sizes (the slope there, b + 2 d (lo -
    // 10), below 0), or rise faster than quadratically at the other, is refused naming the curvature.
    let [lo, hi] = m.structures[i].build_ln_n_range[..] else { unreachable!() };
    let b = m.structures[i].build_exponent;
    for d in [(b + 0.1) / (2.0 * (10.0 - lo)), (2.1 - b) / (2.0 * (hi - 10.0))] {
        let mut c = m.clone();
        c.structures[i].build_curvature = d;
        assert!(meshchar::cost::BUILD_CURVATURE_RANGE.contains(&d), "{d}");
        let e = c.validate().unwrap_err();
        assert_invalid(&e, &field("build_curvature"), st);
        assert!(e.to_string().contains("slope"), "{e}");
    }
    // Without a curvature the range may go (a law in n alone, as files before it).
    let mut b = m.clone();
    for s in &mut b.structures {
        s.build_curvature = 0.0;
        s.build_work_coef.truncate(3);
        s.build_ln_n_range.clear();
    }
    assert_eq!(CostModel::from_json(&b.to_json()).unwrap(), b);
}

#[test]
fn a_file_of_the_previous_format_is_refused_with_its_version() {
    // Version 1 had no count bounds (the overlap floor's factors were typed into the source) and read files of
    // fewer prices: refused as a whole, naming the version.
    let mut v = shipped_json();
    v["version"] = serde_json::json!(1);
    match CostModel::from_json(&v.to_string()) {
        Err(meshchar::cost::CostError::Version { found, expected }) => {
            assert_eq!((found, expected), (1, meshchar::cost::COST_MODEL_VERSION))
        }
        other => panic!("{other:?}"),
    }
    // Without its count bounds, a file of this version is refused by name.
    let mut v = shipped_json();
    v.as_object_mut().unwrap().remove("count_bounds");
    assert!(CostModel::from_json(&v.to_string()).unwrap_err().to_string().contains("count_bounds"));
    // A file that names one price fewer is refused by name.
    let mut v = shipped_json();
    v["price_names"].as_array_mut().unwrap().pop();
    let e = CostModel::from_json(&v.to_string()).unwrap_err();
    assert_invalid(&e, &format!("price_names[{}]", PRICE_NAMES.len() - 1), None);
}

#[test]
fn the_shipped_file_has_timed_probe_ratios_for_every_structure_and_refuses_bad_ones() {
    let t = shipped().timed.expect("the shipped CPU calibration carries timed-probe ratios");
    assert!(t.records > 0);
    for s in StructureName::ALL {
        let r = t.of(s).unwrap_or_else(|| panic!("{s}"));
        assert!(r.build.is_some() && r.trace.iter().all(Option::is_some), "{r:?}");
    }
    for bad in [json!(0.0), json!(-2.0), json!(1e9)] {
        let e = refused(|v| v["timed"]["structures"][0]["build"] = bad.clone());
        assert_invalid(&e, "timed", None);
    }
    let e = refused(|v| {
        let first = v["timed"]["structures"][0].clone();
        v["timed"]["structures"].as_array_mut().unwrap().push(first);
    });
    assert_invalid(&e, "timed", None);
    // Without the block, the file loads and the policy has nothing to blend with.
    let mut v = shipped_json();
    v.as_object_mut().unwrap().remove("timed");
    let m = CostModel::from_json(&v.to_string()).expect("a file without timed ratios loads");
    assert_eq!(m.timed, None);
    // A ratio not fitted is null.
    let mut v = shipped_json();
    v["timed"]["structures"][0]["trace"][1] = Value::Null;
    let m = CostModel::from_json(&v.to_string()).expect("an unfitted ratio is null");
    assert_eq!(m.timed.unwrap().structures[0].trace[1], None);
}

/// The size laws read the triangle count alone: a file whose size law reads a geometric feature, or a view, is
/// refused naming the structure; the shipped one reads and predicts from `n` alone.
#[test]
fn size_laws_read_the_triangle_count_alone() {
    let shipped = CostModel::from_json(SHIPPED_CPU).unwrap();
    let w = meshchar::cost::Workload {
        kind: meshchar::geom::WorkloadKind::Primary,
        rays_per_frame: 65536,
        frames: 1,
        builds: 1,
        view: None,
    };
    let p = shipped.predict_size(20_000, &w).expect("the shipped file has size laws");
    assert_eq!(p.len(), shipped.structures.len());
    assert!(p.iter().all(|p| p.total_ms.is_finite() && p.total_ms > 0.0));
    assert!(shipped.predict_size(200_000, &w).unwrap()[0].total_ms > p[0].total_ms, "more triangles cost more");
    let e = refused(|v| v["structures"][0]["size"]["box_coef"][5] = serde_json::json!(0.3));
    assert!(e.to_string().contains("triangle count"), "{e}");
    let e = refused(|v| v["structures"][1]["size"]["view_prim_coef"] = serde_json::json!([0.1, 0.0, 0.0]));
    assert!(e.to_string().contains("triangle count"), "{e}");
    // Without size laws a file still reads, and predicts nothing by size.
    let mut v: Value = serde_json::from_str(SHIPPED_CPU).unwrap();
    for s in v["structures"].as_array_mut().unwrap() {
        s.as_object_mut().unwrap().remove("size");
    }
    let m = CostModel::from_json(&v.to_string()).unwrap();
    assert!(m.predict_size(20_000, &w).is_none());
}
