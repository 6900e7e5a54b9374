//! Refit candidates of an animation: frame 0 built, every later frame refitted and traced ([`RefitCandidate`],
//! [`RefitResult`]).

use super::measure::{ms, Frame};
use super::Measurement;
use crate::accel::{AccelStructure, StructureName};
use crate::mesh::Mesh;
use crate::trace::{check_trace_budget, count_disagreements, trace};
use std::time::Instant;

/// A candidate that builds frame 0 of an animation and refits the tree to every later frame
/// ([`crate::accel::bvh::BvhTree::refit`]) instead of rebuilding it: what an engine does with a deforming mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RefitCandidate {
    /// The binned-SAH BVH, refitted: `bvh_refit`.
    #[serde(rename = "bvh_refit")]
    Bvh,
    /// The LBVH, refitted: `lbvh_refit`.
    #[serde(rename = "lbvh_refit")]
    Lbvh,
}

impl RefitCandidate {
    /// Every refit candidate.
    pub const ALL: [RefitCandidate; 2] = [RefitCandidate::Bvh, RefitCandidate::Lbvh];

    /// `bvh_refit` or `lbvh_refit`.
    pub fn name(self) -> &'static str {
        match self {
            RefitCandidate::Bvh => "bvh_refit",
            RefitCandidate::Lbvh => "lbvh_refit",
        }
    }

    /// Parses [`RefitCandidate::name`].
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == s)
    }

    /// The structure it builds on frame 0.
    pub fn structure(self) -> StructureName {
        match self {
            RefitCandidate::Bvh => StructureName::Bvh,
            RefitCandidate::Lbvh => StructureName::Lbvh,
        }
    }

    fn build(self, mesh: &Mesh) -> Result<Refitted, crate::accel::AccelError> {
        Ok(match self {
            RefitCandidate::Bvh => Refitted::Bvh(crate::accel::bvh::Bvh::build(mesh)?),
            RefitCandidate::Lbvh => Refitted::Lbvh(crate::accel::lbvh::Lbvh::build(mesh)?),
        })
    }
}

/// A tree that is refitted frame after frame.
pub(super) enum Refitted {
    Bvh(crate::accel::bvh::Bvh),
    Lbvh(crate::accel::lbvh::Lbvh),
}

impl Refitted {
    fn accel(&self) -> &dyn AccelStructure {
        match self {
            Refitted::Bvh(b) => b,
            Refitted::Lbvh(l) => l,
        }
    }

    fn refit(&mut self, mesh: &Mesh) -> Result<(), crate::accel::AccelError> {
        match self {
            Refitted::Bvh(b) => b.refit(mesh),
            Refitted::Lbvh(l) => l.refit(mesh),
        }
    }
}

/// What the oracle measured for one refit candidate on an animation.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RefitResult {
    /// `bvh_refit` or `lbvh_refit`.
    pub name: String,
    /// Median build of frame 0, ms.
    pub build_ms: f64,
    /// Median of the refits of frames 1 and later, summed, ms.
    pub refit_ms: f64,
    /// Median trace time over every frame, ms.
    pub trace_ms: f64,
    /// Median total (build, refits and traces of every frame), ms.
    pub total_ms: f64,
    /// Half the range of the totals over the repeats, ms.
    pub total_ms_spread: f64,
    /// Rays traced per repeat (over all measured frames).
    pub rays: u64,
    /// Box tests per ray over every frame.
    pub box_tests_per_ray: f64,
    /// Triangle tests per ray over every frame.
    pub prim_tests_per_ray: f64,
    /// SAH cost of frame 0's tree and of the last frame's refitted tree.
    pub sah_first_last: Option<[f64; 2]>,
    /// Memory of the tree, bytes.
    pub memory_bytes: usize,
    /// Every refitted tree validated.
    pub valid: bool,
    /// Every hit agreed with the reference on every frame.
    pub hits_agree: bool,
    /// Rays that disagreed with the reference.
    pub disagreements: usize,
    /// The build, refit or validation error, if any.
    pub error: Option<String>,
    /// Per frame: the median build (frame 0) or refit (later frames), ms.
    pub frame_update_ms: Vec<f64>,
    /// Per frame: the median trace, ms.
    pub frame_trace_ms: Vec<f64>,
}

/// What the oracle gathers for one refit candidate.
#[derive(Default)]
pub(super) struct RefitAcc {
    pub(super) kept: Vec<Option<Refitted>>,
    /// Per frame, per repeat: build or refit ms, and trace ms.
    pub(super) frames: Vec<(Vec<f64>, Vec<f64>)>,
    pub(super) rays: u64,
    pub(super) box_tests: u64,
    pub(super) prim_tests: u64,
    pub(super) memory: usize,
    pub(super) disagreements: usize,
    pub(super) valid: bool,
    pub(super) sah_first: Option<f64>,
    pub(super) sah_last: Option<f64>,
    pub(super) error: Option<String>,
}

impl RefitAcc {
    pub(super) fn result(&self, name: &str, repeats: usize) -> RefitResult {
        let ok = self.error.is_none() && self.rays > 0;
        let per_repeat = |pick: &dyn Fn(usize) -> f64| -> Vec<f64> { (0..repeats).map(pick).collect() };
        let build = per_repeat(&|r| self.frames.first().map_or(0.0, |f| f.0[r]));
        let refit = per_repeat(&|r| self.frames.iter().skip(1).map(|f| f.0[r]).sum());
        let traces = per_repeat(&|r| self.frames.iter().map(|f| f.1[r]).sum());
        let totals: Vec<f64> = (0..repeats).map(|r| build[r] + refit[r] + traces[r]).collect();
        let per_ray = |x: u64| if self.rays > 0 { x as f64 / self.rays as f64 } else { 0.0 };
        let med = |v: &[f64]| if ok { Measurement::of(v).median } else { 0.0 };
        RefitResult {
            name: name.to_string(),
            build_ms: med(&build),
            refit_ms: med(&refit),
            trace_ms: med(&traces),
            total_ms: med(&totals),
            total_ms_spread: if ok { Measurement::of(&totals).spread } else { 0.0 },
            rays: self.rays,
            box_tests_per_ray: per_ray(self.box_tests),
            prim_tests_per_ray: per_ray(self.prim_tests),
            sah_first_last: self.sah_first.zip(self.sah_last).map(|(a, b)| [a, b]),
            memory_bytes: self.memory,
            valid: ok && self.valid,
            hits_agree: ok && self.disagreements == 0,
            disagreements: self.disagreements,
            error: self.error.clone(),
            frame_update_ms: if ok {
                self.frames.iter().map(|f| Measurement::of(&f.0).median).collect()
            } else {
                vec![]
            },
            frame_trace_ms: if ok {
                self.frames.iter().map(|f| Measurement::of(&f.1).median).collect()
            } else {
                vec![]
            },
        }
    }

    /// Measures the candidate on one frame, every repeat: frame 0 built, later frames refitted from the tree kept
    /// for the repeat; the first error ends its measurement.
    pub(super) fn measure_frame(
        &mut self,
        cand: RefitCandidate,
        f: &Frame<'_>,
        on_device: bool,
        max_tests_per_ray: f64,
    ) {
        let a = self;
        let (repeats, mesh, rays, want, fi) = (f.repeats, f.mesh, f.rays, f.want, f.index);
        if a.error.is_some() {
            return;
        }
        if on_device {
            a.error = Some("refit candidates are measured on the CPU tracer only (--trace-backend cpu)".into());
            return;
        }
        a.frames.push((vec![0.0; repeats], vec![0.0; repeats]));
        for r in 0..repeats {
            f.progress_step(r, cand.name());
            let t = Instant::now();
            let updated = match a.kept[r].take() {
                Some(mut s) => s.refit(mesh).map(|_| s),
                None => cand.build(mesh),
            };
            let update_ms = ms(t);
            let s = match updated {
                Ok(s) => s,
                Err(e) => {
                    a.error = Some(e.to_string());
                    break;
                }
            };
            if r == 0 {
                if let Err(e) = check_trace_budget(s.accel(), rays, max_tests_per_ray) {
                    a.error = Some(e);
                    break;
                }
            }
            let out = trace(s.accel(), rays);
            if let Some(fr) = a.frames.last_mut() {
                fr.0[r] = update_ms;
                fr.1[r] = out.seconds * 1e3;
            }
            if r == 0 {
                a.rays += out.rays() as u64;
                a.box_tests += out.counters.box_tests;
                a.prim_tests += out.counters.prim_tests;
                a.memory = a.memory.max(s.accel().memory_bytes());
                a.disagreements += count_disagreements(&out, want);
                if let Err(e) = s.accel().validate() {
                    a.valid = false;
                    a.error.get_or_insert(e.to_string());
                }
                let sah = s.accel().sah_cost();
                if fi == 0 {
                    a.sah_first = sah;
                }
                a.sah_last = sah;
            }
            a.kept[r] = Some(s);
        }
    }
}
