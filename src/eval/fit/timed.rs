//! The timed probes' ratios to the oracle's times, fitted on the samples' timed probes.

use super::Sample;
use crate::accel::StructureName;
use crate::cost::timed::{kind_index, median, StructureRatios, TimedRatios, TIMED_RATIO_RANGE};

impl TimedRatios {
    /// The ratios of the timed probes of `samples` ([`Sample::timed`]) to their measurements; `None` when no
    /// sample has a timed probe of a validly measured structure.
    pub fn fit(samples: &[Sample]) -> Option<TimedRatios> {
        let mut logs: Vec<(StructureName, [Vec<f64>; 4])> = Vec::new();
        let mut records = 0;
        for smp in samples {
            let mut any = false;
            for p in &smp.timed {
                let Some(m) = smp.get(p.structure).filter(|m| m.valid) else { continue };
                let i = match logs.iter().position(|l| l.0 == p.structure) {
                    Some(i) => i,
                    None => {
                        logs.push((p.structure, Default::default()));
                        logs.len() - 1
                    }
                };
                if let Some(b) = p.build().filter(|_| m.build_ms_per_build > 0.0) {
                    logs[i].1[0].push((m.build_ms_per_build / b).ln());
                    any = true;
                }
                if let Some(t) = p.ns_per_ray(smp.workload.kind).filter(|_| m.trace_ns_per_ray > 0.0) {
                    logs[i].1[1 + kind_index(smp.workload.kind)].push((m.trace_ns_per_ray / t).ln());
                    any = true;
                }
            }
            records += any as usize;
        }
        if records == 0 {
            return None;
        }
        let mut structures: Vec<StructureRatios> = logs
            .into_iter()
            .map(|(structure, [b, p, s, d])| {
                // A ratio beyond the file's range (records of another tracer than the probes') is not fitted.
                let r = |v: Vec<f64>| {
                    median(v).map(f64::exp).filter(|x| (TIMED_RATIO_RANGE[0]..=TIMED_RATIO_RANGE[1]).contains(x))
                };
                StructureRatios { structure, build: r(b), trace: [r(p), r(s), r(d)] }
            })
            .collect();
        structures.sort_by_key(|r| StructureName::ALL.iter().position(|x| *x == r.structure));
        Some(TimedRatios { structures, records })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cost::timed::*;
    use crate::cost::{Prediction, Workload};
    use crate::eval::fit::{Measured, Sample};
    use crate::geom::{Camera, WorkloadKind};
    use crate::mesh::generate;
    use crate::mesh::Mesh;

    fn framing(mesh: &Mesh) -> Camera {
        let b = mesh_box(mesh);
        crate::cost::view::framing_camera(b.min.to_array(), b.max.to_array())
    }

    #[test]
    fn time_probes_builds_and_times_every_structure_on_the_same_rays() {
        let mesh = generate::teapot_in_stadium(3);
        let kinds = [WorkloadKind::Primary, WorkloadKind::Shadow, WorkloadKind::Diffuse];
        let probes = time_probes(&mesh, &framing(&mesh), &StructureName::ALL, &kinds);
        assert_eq!(probes.iter().map(|p| p.structure).collect::<Vec<_>>(), StructureName::ALL.to_vec());
        let side = TIMED_SIDE as usize;
        for p in &probes {
            assert!(p.build().is_some(), "{p:?}");
            assert_eq!(p.rays[0], side * side, "every primary ray of the sample is traced");
            assert_eq!(p.rays, probes[0].rays, "every structure traces the same rays");
            for k in kinds {
                let t =
                    p.ns_per_ray(k).unwrap_or_else(|| panic!("enough rays of every kind in a closed stadium: {p:?}"));
                assert!(t.is_finite() && t > 0.0, "{p:?}");
            }
        }
        // Only the kinds asked for are traced.
        let primary = time_probes(&mesh, &framing(&mesh), &[StructureName::Bvh], &[WorkloadKind::Primary]);
        assert_eq!(primary.len(), 1);
        assert_eq!(primary[0].rays[1..], [0, 0]);
        assert!(primary[0].ns_per_ray(WorkloadKind::Shadow).is_none());
    }

    #[test]
    fn time_probes_of_an_empty_mesh_or_a_missed_view_give_no_trace_time() {
        let empty = Mesh::new("empty", Vec::new(), Vec::new()).expect("an empty mesh is valid");
        let cam = framing(&generate::single_triangle());
        for p in time_probes(&empty, &cam, &StructureName::ALL, &[WorkloadKind::Primary, WorkloadKind::Diffuse]) {
            // Primary rays are traced (and miss); no hit starts a diffuse ray.
            assert_eq!(p.rays[2], 0, "{p:?}");
            assert!(p.ns_per_ray(WorkloadKind::Diffuse).is_none());
        }
    }

    fn prediction(structure: StructureName, build: f64, ns: f64, rays: f64) -> Prediction {
        Prediction {
            structure,
            build_ms_per_build: build,
            build_ms: build,
            box_tests_per_ray: 1.0,
            prim_tests_per_ray: 1.0,
            trace_ns_per_ray: ns,
            trace_ms: ns * rays * 1e-6,
            total_ms: build + ns * rays * 1e-6,
        }
    }

    fn probe(structure: StructureName, build_ms: f64, ns: [f64; 3]) -> TimedProbe {
        TimedProbe { structure, build_ms, trace_ns_per_ray: ns, rays: [4096; 3] }
    }

    fn workload(kind: WorkloadKind) -> Workload {
        Workload { kind, rays_per_frame: 1_000_000, frames: 1, builds: 1, view: None }
    }

    #[test]
    fn blend_takes_the_geometric_mean_of_the_prediction_and_the_scaled_probe() {
        let w = workload(WorkloadKind::Shadow);
        let mut preds = vec![
            prediction(StructureName::Bvh, 4.0, 100.0, 1e6),
            prediction(StructureName::Lbvh, 1.0, 50.0, 1e6),
            prediction(StructureName::Grid, 2.0, 80.0, 1e6),
        ];
        let timed = [
            probe(StructureName::Bvh, 9.0, [f64::NAN, 200.0, f64::NAN]),
            probe(StructureName::Lbvh, 1.0, [1.0, f64::NAN, 1.0]),
        ];
        let ratios = TimedRatios {
            structures: vec![
                StructureRatios { structure: StructureName::Bvh, build: Some(1.0), trace: [None, Some(0.5), None] },
                StructureRatios { structure: StructureName::Lbvh, build: None, trace: [Some(1.0); 3] },
            ],
            records: 3,
        };
        assert_eq!(blend(&mut preds, &timed, &ratios, &w), 1, "the LBVH has no shadow time and no build ratio");
        let bvh = &preds[0];
        assert!((bvh.build_ms - 6.0).abs() < 1e-12, "sqrt(4 x 9): {bvh:?}");
        assert!((bvh.trace_ns_per_ray - 100.0).abs() < 1e-12, "sqrt(100 x 0.5 x 200): {bvh:?}");
        assert!((bvh.total_ms - (6.0 + 100.0)).abs() < 1e-9, "{bvh:?}");
        assert_eq!(preds[1], prediction(StructureName::Lbvh, 1.0, 50.0, 1e6));
        assert_eq!(preds[2], prediction(StructureName::Grid, 2.0, 80.0, 1e6), "no probe: unchanged");
        // A prediction that is not finite is left as it is (no NaN from inf / inf).
        let mut inf =
            vec![Prediction { trace_ns_per_ray: f64::INFINITY, ..prediction(StructureName::Bvh, 4.0, 1.0, 1e6) }];
        inf[0].trace_ms = f64::INFINITY;
        blend(&mut inf, &timed, &ratios, &w);
        assert!(inf[0].trace_ns_per_ray.is_infinite() && !inf[0].total_ms.is_nan(), "{inf:?}");
        // Rebuilt every frame: the blended build counts once per build.
        let w = Workload { frames: 4, builds: 4, ..w };
        let mut p = vec![Prediction { build_ms: 16.0, ..prediction(StructureName::Bvh, 4.0, 100.0, 4e6) }];
        blend(&mut p, &timed, &ratios, &w);
        assert!((p[0].build_ms - 24.0).abs() < 1e-9 && (p[0].build_ms_per_build - 6.0).abs() < 1e-12, "{p:?}");
    }

    fn sample(kind: WorkloadKind, build: f64, ns: f64, probe_build: f64, probe_ns: f64) -> Sample {
        let mut t = [f64::NAN; 3];
        t[kind_index(kind)] = probe_ns;
        Sample {
            scene: "s".into(),
            workload: workload(kind),
            features: crate::characterize::features_cpu(&generate::single_triangle(), &Default::default())
                .expect("features"),
            measured: vec![Measured {
                structure: StructureName::Bih,
                valid: true,
                total_ms: build + ns,
                build_ms: build,
                trace_ms: ns,
                build_ms_per_build: build,
                trace_ns_per_ray: ns,
                box_tests_per_ray: 1.0,
                prim_tests_per_ray: 1.0,
                within_noise_of_best: true,
                total_ms_ci95: None,
                build_work: 0.0,
            }],
            baseline: None,
            driver: Vec::new(),
            frame_features: Vec::new(),
            crossings: None,
            timed: vec![probe(StructureName::Bih, probe_build, t)],
            frame_timings: Vec::new(),
            grid_build_work: 0.0,
            trace_backend: Default::default(),
            stage_ms: Default::default(),
        }
    }

    #[test]
    fn fit_takes_the_median_ratio_per_structure_and_kind() {
        let samples = vec![
            sample(WorkloadKind::Primary, 2.0, 10.0, 1.0, 20.0),
            sample(WorkloadKind::Primary, 3.0, 10.0, 1.0, 40.0),
            sample(WorkloadKind::Primary, 8.0, 10.0, 1.0, 10.0),
            sample(WorkloadKind::Diffuse, 4.0, 30.0, 1.0, 10.0),
        ];
        let r = TimedRatios::fit(&samples).expect("fitted");
        assert_eq!(r.records, 4);
        let b = r.of(StructureName::Bih).expect("the BIH");
        assert!((b.build.unwrap() - 12f64.sqrt()).abs() < 1e-12, "the median of the logs of 2, 3, 4, 8: {b:?}");
        assert!((b.trace[0].unwrap() - 0.5).abs() < 1e-12, "median of 0.5, 0.25, 1: {b:?}");
        assert_eq!(b.trace[1], None, "no shadow record");
        assert!((b.trace[2].unwrap() - 3.0).abs() < 1e-12);
        assert!(r.of(StructureName::Bvh).is_none());
        assert!(r.validate().is_ok());
        // A ratio beyond the file's range (records of a far faster tracer than the probes) is left unfitted.
        let fast = vec![sample(WorkloadKind::Shadow, 2.0, 0.001, 1.0, 10.0)];
        let r = TimedRatios::fit(&fast).expect("fitted");
        let b = r.of(StructureName::Bih).expect("the BIH");
        assert_eq!((b.build, b.trace[1]), (Some(2.0), None), "{b:?}");
        assert!(r.validate().is_ok());
        // No timed probes: nothing to fit.
        let none: Vec<Sample> = samples.into_iter().map(|s| Sample { timed: Vec::new(), ..s }).collect();
        assert_eq!(TimedRatios::fit(&none), None);
    }

    #[test]
    fn validate_refuses_ratios_out_of_range_and_repeated_structures() {
        let ok = StructureRatios { structure: StructureName::Bvh, build: Some(1.0), trace: [None, Some(0.5), None] };
        let r = |s: Vec<StructureRatios>| TimedRatios { structures: s, records: 1 };
        assert!(r(vec![ok]).validate().is_ok());
        for bad in [0.0, -1.0, 1e4, f64::NAN, f64::INFINITY] {
            let e = r(vec![StructureRatios { build: Some(bad), ..ok }]).validate();
            assert!(e.is_err(), "{bad}");
        }
        assert!(r(vec![ok, ok]).validate().unwrap_err().contains("twice"));
    }
}
