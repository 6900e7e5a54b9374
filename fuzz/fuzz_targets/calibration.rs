//! The calibration-file parser on arbitrary text: `CostModel::from_json`; a model it accepts must save and load again
//! and predict and choose without a panic for every workload kind.
#![no_main]

use libfuzzer_sys::fuzz_target;
use meshchar::characterize::features::Derived;
use meshchar::cost::{CostError, CostModel, Workload};
use meshchar::geom::WorkloadKind;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let r = CostModel::from_json(&text);
    meshchar_fuzz::report(&r, |m| format!("{} structures", m.structures.len()));
    let m = match r {
        Ok(m) => m,
        Err(e) => {
            let msg = e.to_string();
            assert!(!msg.is_empty());
            assert!(matches!(e, CostError::Parse(_) | CostError::Version { .. }), "{e:?}");
            return;
        }
    };
    let again = CostModel::from_json(&m.to_json()).unwrap_or_else(|e| panic!("a loaded model does not reload: {e}"));
    assert_eq!(again.structures.len(), m.structures.len());
    let d = Derived {
        ln_n: 10.0,
        fill_at_n: 0.4,
        ln_tris_per_cell: 0.5,
        empty_d3: 0.3,
        size_mean: 8.0,
        size_spread: 1.5,
        aspect_log2: 1.0,
    };
    for kind in [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse] {
        let w = Workload { kind, rays_per_frame: 1 << 20, frames: 100, builds: 1, view: None };
        let preds: Vec<_> = m.structures.iter().map(|s| s.predict(&d, 1 << 16, &w)).collect();
        let _ = meshchar::select::choose(&preds, 0.05);
    }
});
