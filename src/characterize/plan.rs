//! Planned characterization (docs/spec.md, "Planned characterization"): the host decisions of a characterization
//! fixed in advance, so that every pass records into one command buffer with no host wait inside a frame.
//!
//! The staged characterization decides two things on the host between its passes: the quantizer (`lo`, `scale`)
//! after the bounds, and the class count `k` with the code range of the class rule after the moments. A [`Plan`]
//! fixes both before the run. In an animation, frame `t` runs with the plan that the last report read back gives
//! ([`Plan::after`]: frame `t - 1`'s, or an older one when several frames are in flight), so the report of frame
//! `t` costs no wait; the report still carries frame `t`'s own bounds, code range and moments. What the plan
//! changes is only where a key outside the planned bounds lands (the nearest cell) and which classes the codes fall
//! in (codes outside the planned range go to the first or last class): the numbers are exact for that plan, and
//! [`reference()`] reproduces them bit for bit on the CPU. With the plan of the frame itself ([`Plan::exact`]) the
//! planned run equals the staged one.

use super::finalize::{class_count_of, class_of, histogram_stats};
use super::{Backend, CharError, Characterization, CodeStats, Exact, Features, Params, PassTime, PerTriangle};
use crate::characterize::cpu::cpu_device_name;
use crate::keys::{centroid_key, morton, quantize, KeyBounds, MortonBits, Quantizer};
use crate::mesh::Mesh;
use num_bigint::BigUint;

/// The host decisions of one characterization, fixed before it runs.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Plan {
    /// The code width.
    pub bits: MortonBits,
    /// `lo` of the quantizer (step 3).
    pub lo: [f32; 3],
    /// `hi` of the quantizer's bounds (step 2; the codes read only `lo` and `scale`).
    pub hi: [f32; 3],
    /// `scale` of the quantizer (step 3).
    pub scale: [f32; 3],
    /// `m_min` of the class rule (step 7).
    pub code_min: u64,
    /// `m_max` of the class rule (step 7).
    pub code_max: u64,
    /// `k` (step 6).
    pub classes: u32,
}

impl Plan {
    /// The plan for the next run that a report gives: the quantizer of its own bounds, its code range, and the
    /// class count its code statistics give under `params.class_rule`, at most `max_classes` (the device's limit,
    /// `crate::characterize::gpu::passes::CharacterizeGpu::max_classes`).
    ///
    /// Errors: bounds that cannot be quantized ([`CharError::Input`]).
    pub fn after(report: &Characterization, params: &Params, max_classes: u32) -> Result<Plan, CharError> {
        let mut bounds = KeyBounds::EMPTY;
        bounds.add(report.lo);
        bounds.add(report.hi);
        let q = Quantizer::new(&bounds, params.morton_bits)
            .map_err(|e| CharError::Input { mesh: "plan".into(), reason: e.to_string() })?;
        Ok(Plan {
            bits: params.morton_bits,
            lo: q.lo(),
            hi: q.hi(),
            scale: q.scale(),
            code_min: report.code_stats.code_min,
            code_max: report.code_stats.code_max,
            classes: class_count_of(params.class_rule, &report.code_stats).clamp(1, max_classes.max(1)),
        })
    }

    /// The plan that a staged run of `mesh` decides (its own bounds, code range and class count): with it a planned
    /// run equals the staged one. Computed on the CPU.
    pub fn exact(mesh: &Mesh, params: &Params, max_classes: u32) -> Result<Plan, CharError> {
        let c = super::cpu::fast(mesh, params)?;
        let mut p = Plan::after(&c, params, max_classes)?;
        p.classes = c.classes.min(max_classes.max(1));
        Ok(p)
    }

    /// The plan's quantizer (steps 2-4: `lo`, `hi`, `scale` and the code width), as the device builders take it
    /// ([`crate::accel::gpu::BvhBuilder::record_lbvh`], [`crate::accel::lbvh::Lbvh::build_quantized`]): a tree
    /// rebuilt in the same command buffer as the planned characterization uses the codes that run used.
    pub fn quantizer(&self) -> Quantizer {
        Quantizer::from_parts(self.lo, self.hi, self.scale, self.bits)
    }

    /// `t_j = ceil(j (m_max - m_min) / k)`, `j = 1 .. k - 1`: the class thresholds of the plan.
    pub fn thresholds(&self) -> Vec<u64> {
        super::class_thresholds(self.code_min, self.code_max, self.classes)
    }

    /// The plan as the GPU passes take it.
    pub(crate) fn pass_plan(&self) -> super::gpu::passes::PassPlan {
        super::gpu::passes::PassPlan {
            lo: self.lo,
            scale: self.scale,
            code_min: self.code_min,
            classes: super::gpu::passes::ClassPlan { k: self.classes, thresholds: self.thresholds() },
        }
    }
}

/// A characterization run with a plan, and the plan.
#[derive(Clone, Debug, PartialEq)]
pub struct PlannedCharacterization {
    /// The report: the run's own bounds, code statistics and moments; `k` and the histogram of the plan.
    pub report: Characterization,
    /// The plan it ran with.
    pub plan: Plan,
}

/// The CPU reference of a planned run's scene features (docs/spec.md, "Planned characterization"): those of
/// [`crate::characterize::features_cpu`], except that the occupied cells are counted on the plan's codes
/// (`morton(quantize(key, plan.lo, plan.scale))`, clamped as in [`reference()`]), as the device's feature pass of a
/// planned run counts them. With the mesh's own plan ([`Plan::exact`]) it equals `features_cpu`; with a stale plan
/// the occupied cells may differ from it, the other features never.
///
/// Errors: as [`reference()`] for the plan and the parameters, as `features_cpu` for the mesh.
pub fn features_reference(mesh: &Mesh, params: &Params, plan: &Plan) -> Result<Features, CharError> {
    if plan.bits != params.morton_bits {
        return Err(CharError::Input {
            mesh: mesh.name.clone(),
            reason: format!(
                "plan of {}-bit codes for {}-bit parameters",
                plan.bits.total(),
                params.morton_bits.total()
            ),
        });
    }
    crate::characterize::features::features_with(mesh, params, Some(plan.quantizer()))
}

/// The CPU reference of a planned run (docs/spec.md, "Planned characterization"), one element at a time: keys and
/// their bounds as in steps 1-2; codes `morton(quantize(key, plan.lo, plan.scale))` (a key below `lo` quantizes to
/// 0, one past the top to `2^b - 1`); the exact code statistics of those codes; classes
/// `class_of(m, plan.code_min, plan.code_max, plan.classes)` (codes outside the range clamp to its ends); the
/// histogram and steps 9-10 as usual.
///
/// Errors: invalid parameters or mesh, no sampled triangles, a plan whose code width is not `params.morton_bits`
/// or with no class, keys whose bounds are not finite.
pub fn reference(mesh: &Mesh, params: &Params, plan: &Plan) -> Result<PlannedCharacterization, CharError> {
    let start = std::time::Instant::now();
    params.validate()?;
    mesh.validate()?;
    let input = |reason: String| CharError::Input { mesh: mesh.name.clone(), reason };
    if plan.bits != params.morton_bits || plan.classes == 0 {
        return Err(input(format!(
            "plan of {}-bit codes and {} classes for {}-bit parameters",
            plan.bits.total(),
            plan.classes,
            params.morton_bits.total()
        )));
    }
    let stride = params.sample_stride.max(1) as usize;
    let keys: Vec<[f32; 3]> = (0..mesh.triangle_count())
        .step_by(stride)
        .map(|i| {
            let [a, b, c] = mesh.indices[i];
            let p = &mesh.positions;
            centroid_key(p[a as usize], p[b as usize], p[c as usize])
        })
        .collect();
    if keys.is_empty() {
        return Err(CharError::Empty { mesh: mesh.name.clone() });
    }
    let mut bounds = KeyBounds::EMPTY;
    for &k in &keys {
        bounds.add(k);
    }
    let (lo, hi) = (bounds.lo(), bounds.hi());
    if !lo.iter().chain(&hi).all(|c| c.is_finite()) {
        return Err(input(format!("bounds of the centroid keys {lo:?} .. {hi:?} are not finite")));
    }
    let codes: Vec<u64> =
        keys.iter().map(|&k| morton(quantize(k, plan.lo, plan.scale, plan.bits), plan.bits)).collect();
    let (mut s1, mut s2, mut s3) = (BigUint::default(), BigUint::default(), BigUint::default());
    for &c in &codes {
        let m = BigUint::from(c);
        s1 += &m;
        s2 += &m * &m;
        s3 += &m * &m * &m;
    }
    let code_stats = CodeStats {
        n: codes.len() as u64,
        code_min: codes.iter().copied().min().unwrap_or(0),
        code_max: codes.iter().copied().max().unwrap_or(0),
        s1,
        s2,
        s3,
    };
    let k = plan.classes;
    let classes: Vec<u32> = codes.iter().map(|&c| class_of(c, plan.code_min, plan.code_max, k)).collect();
    let mut histogram = vec![0u64; k as usize];
    for &c in &classes {
        histogram[c as usize] += 1;
    }
    let stats = histogram_stats(&histogram, code_stats.n, params.alpha);
    let per_triangle = params.keep_per_triangle.then_some(PerTriangle { codes, classes });
    let exact = Exact { lo, hi, code_stats, classes: k, histogram, stats, per_triangle };
    let timings = vec![PassTime { name: PassTime::TOTAL.into(), ms: start.elapsed().as_secs_f64() * 1e3 }];
    let report = Characterization::from_exact(mesh, params, exact, timings, Backend::Naive, cpu_device_name(1));
    Ok(PlannedCharacterization { report, plan: plan.clone() })
}

/// One line: the code width, the quantizer, the code range and `k`.
impl std::fmt::Display for Plan {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}-bit codes, lo {:?}, scale {:?}, codes {} ..= {}, {} classes",
            self.bits.total(),
            self.lo,
            self.scale,
            self.code_min,
            self.code_max,
            self.classes
        )
    }
}
