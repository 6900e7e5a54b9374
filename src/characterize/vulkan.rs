//! The Vulkan backend: the exact GPU passes of `super::gpu` (characterization and scene features), finished on
//! the host by the math of `super::finalize`, the same as the CPU paths'.

use super::features::{features_from_gpu, SIZE_BINS};
use super::finalize::class_count_of;
use super::gpu::features::FeaturesGpu;
use super::gpu::passes::{CharacterizeGpu, ClassPlan, CodeSums};
use super::plan::{Plan, PlannedCharacterization};
use super::Features;
use super::{
    class_thresholds, Backend, CharError, Characterization, CodeStats, Exact, MortonBits, Params, PassTime, PerTriangle,
};
use crate::gpu::{Context, GeometryView, MeshBuffers, Pass, Recorder, RunError};
use crate::mesh::{Animation, Mesh};
use num_bigint::BigUint;
use std::time::Instant;

/// Sum of 24-bit limbs (each may hold more than 24 bits) as an exact integer.
pub(crate) fn limbs_to_biguint(limbs: &[u64]) -> BigUint {
    limbs.iter().rev().fold(BigUint::default(), |acc, &l| (acc << 24u32) + BigUint::from(l))
}

fn code_stats(s: &CodeSums) -> CodeStats {
    CodeStats {
        n: s.n,
        code_min: s.code_min,
        code_max: s.code_max,
        s1: limbs_to_biguint(&s.limbs[0]),
        s2: limbs_to_biguint(&s.limbs[1]),
        s3: limbs_to_biguint(&s.limbs[2]),
    }
}

/// Characterization on a Vulkan device. Pipelines and buffers are made once and reused for every mesh and frame.
///
/// Pipelines are ready before any work is timed: some drivers compile a pipeline only at its first dispatch
/// (lavapipe compiles it with LLVM then, inside the pass's timestamps), so [`VulkanBackend::new`] runs every
/// pipeline once on a tiny mesh and reports that warm-up apart ([`VulkanBackend::warmup_ms`]). Other operations
/// on the same context are not warmed by it: a caller that times `accel::gpu::BvhBuilder` builds warms the builder
/// with a tiny build first.
pub struct VulkanBackend {
    ctx: Context,
    gpu: CharacterizeGpu,
    features: Option<FeaturesGpu>,
    mesh: Option<MeshBuffers>,
    warmup_ms: f64,
    /// What each slot's recorded planned run needs to be finished.
    planned: Vec<Option<PlannedSlot>>,
    /// Each slot's feature pass (sharing the pipelines of `features`).
    slot_features: Vec<FeaturesGpu>,
}

/// A planned run recorded into a slot: its parameters, plan and triangle count, and its feature pass.
struct PlannedSlot {
    params: Params,
    plan: Plan,
    total_triangles: u64,
    name: String,
    with_features: bool,
}

impl VulkanBackend {
    /// Builds the pipelines on `ctx`'s device (through its pipeline cache) and warms them: a characterization of
    /// a tiny mesh with each code width, each followed by the feature pass, so that every pipeline of the
    /// characterization and the features has been dispatched once (see [`VulkanBackend::warmup_ms`]). The warm-up
    /// waits for the device like [`VulkanBackend::characterize`] does (it counts in
    /// [`Context::host_waits`](crate::gpu::Context::host_waits)) and leaves no mesh behind.
    pub fn new(ctx: &Context) -> Result<Self, CharError> {
        Self::with_slots(ctx, 1)
    }

    /// Builds the pipelines with `slots` slots for planned runs in flight at once (at least 1; the staged methods
    /// use slot 0), and warms them as [`VulkanBackend::new`] does.
    pub fn with_slots(ctx: &Context, slots: usize) -> Result<Self, CharError> {
        let slots = slots.max(1);
        let start = Instant::now();
        let features = FeaturesGpu::new(ctx, SIZE_BINS as u32).map_err(gpu_err)?;
        // Every slot's feature pass shares the warmed pipelines.
        let slot_features =
            (0..slots).map(|_| features.sharing_pipelines().map_err(gpu_err)).collect::<Result<Vec<_>, _>>()?;
        let mut backend = VulkanBackend {
            ctx: ctx.clone(),
            gpu: CharacterizeGpu::with_slots(ctx, slots).map_err(gpu_err)?,
            features: Some(features),
            mesh: None,
            warmup_ms: 0.0,
            planned: (0..slots).map(|_| None).collect(),
            slot_features,
        };
        let warm = backend.warm_up();
        // The warm-up's mesh is not the caller's: a feature pass must follow a characterization of theirs.
        backend.mesh = None;
        warm?;
        backend.warmup_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(backend)
    }

    /// Dispatches every pipeline once: keys and bounds, codes and moments, classes and histogram, chi-square and
    /// the two feature passes, with 30-bit and with 63-bit codes.
    fn warm_up(&mut self) -> Result<(), CharError> {
        let mesh = warmup_mesh()?;
        for morton_bits in [MortonBits::Bits30, MortonBits::Bits63] {
            let params = Params { morton_bits, ..Params::default() };
            let c = self.run(&mesh, &params, false)?;
            self.features_of_last(&mesh, &params, c.triangles)?;
        }
        Ok(())
    }

    /// Wall time of the warm-up in [`VulkanBackend::new`], in milliseconds: the pipelines' creation plus one
    /// tiny run of each (on drivers that compile at the first dispatch, most of it is that compilation). No pass
    /// time reported by [`VulkanBackend::characterize`] and the others includes it.
    pub fn warmup_ms(&self) -> f64 {
        self.warmup_ms
    }

    /// Records a planned characterization of the geometry `view` (named `name` in the report) into `rec` (see
    /// [`super::plan`] and `CharacterizeGpu::record` for the plan rule and the recording contract), and with
    /// `features` the scene-feature pass after it, reading the codes it leaves (no second read of the geometry's
    /// keys). Nothing waits. [`VulkanBackend::finish_planned`] reads the report once the command buffer has
    /// completed.
    #[allow(clippy::too_many_arguments)]
    pub fn record_planned(
        &mut self,
        rec: &mut Recorder<'_>,
        slot: usize,
        view: &GeometryView<'_>,
        name: &str,
        params: &Params,
        plan: &Plan,
        features: bool,
    ) -> Result<(), CharError> {
        params.validate()?;
        let input = |reason: String| CharError::Input { mesh: name.to_string(), reason };
        if plan.bits != params.morton_bits {
            return Err(input(format!(
                "a {}-bit plan for {}-bit parameters",
                plan.bits.total(),
                params.morton_bits.total()
            )));
        }
        let n_slots = self.planned.len();
        if slot >= n_slots {
            return Err(CharError::Gpu(format!("slot {slot} of {n_slots}")));
        }
        let stride = params.sample_stride as u64;
        self.gpu
            .record(rec, slot, view, params.morton_bits, stride, &plan.pass_plan())
            .map_err(|e| run_err(e, name))?;
        self.planned[slot] = None;
        if features {
            let (Some(fg), Some((_, codes, _))) = (self.slot_features.get_mut(slot), self.gpu.slot_arrays(slot)) else {
                return Err(CharError::Gpu("feature pass without the slot's codes".into()));
            };
            rec.dependency(Pass::Compute, Pass::Compute);
            let n = view.triangle_count().div_ceil(stride.max(1));
            fg.record(rec, view, codes, n, stride, params.morton_bits).map_err(gpu_err)?;
        }
        self.planned[slot] = Some(PlannedSlot {
            params: params.clone(),
            plan: plan.clone(),
            total_triangles: view.triangle_count(),
            name: name.to_string(),
            with_features: features,
        });
        Ok(())
    }

    /// The report of the planned run recorded into `slot`, and its scene features when they were recorded, once
    /// the command buffer has completed and the caller has seen it complete. Before that: an error
    /// ([`CharError::Gpu`] saying the work has not completed), and the run stays pending.
    pub fn finish_planned(&mut self, slot: usize) -> Result<(PlannedCharacterization, Option<Features>), CharError> {
        let Some(Some(p)) = self.planned.get_mut(slot) else {
            return Err(CharError::Gpu(format!("slot {slot} has no recorded planned run")));
        };
        let name = p.name.clone();
        let out = self.gpu.finish(slot).map_err(|e| run_err(e, &name))?;
        let p = self.planned[slot].as_mut().ok_or_else(|| CharError::Gpu("slot emptied".into()))?;
        let features = match (self.slot_features.get_mut(slot), p.with_features) {
            (Some(fg), true) => {
                let g = fg.finish().map_err(gpu_err)?;
                Some(features_from_gpu(&g, out.n, p.total_triangles, p.params.morton_bits))
            }
            _ => None,
        };
        let hstats = super::finalize::histogram_stats_exact(
            out.chi_numerator,
            out.empty_classes,
            out.concentrated_classes,
            out.concentrated_triangles,
            out.n,
            out.plan.k,
            p.params.alpha,
        );
        let timings: Vec<PassTime> =
            out.timings.iter().map(|(name, ms)| PassTime { name: name.clone(), ms: *ms }).collect();
        let exact = Exact {
            lo: out.lo,
            hi: out.hi,
            code_stats: code_stats(&out.sums),
            classes: out.plan.k,
            histogram: out.histogram,
            stats: hstats,
            per_triangle: None,
        };
        let device = self.ctx.caps().name.clone();
        let report =
            Characterization::from_exact_total(p.total_triangles, &p.params, exact, timings, Backend::Vulkan, device);
        Ok((PlannedCharacterization { report, plan: p.plan.clone() }, features))
    }

    /// The context.
    pub fn context(&self) -> &Context {
        &self.ctx
    }

    /// The GPU passes (for their device arrays: keys, codes, classes).
    /// The most classes the device passes take (a [`crate::characterize::plan::Plan`]'s `classes` is clamped to it).
    pub fn max_classes(&self) -> u32 {
        self.passes().max_classes()
    }

    pub(crate) fn passes(&self) -> &CharacterizeGpu {
        &self.gpu
    }

    /// Characterizes one mesh (uploads it).
    pub fn characterize(&mut self, mesh: &Mesh, params: &Params) -> Result<Characterization, CharError> {
        self.run(mesh, params, false)
    }

    /// Characterizes one mesh and measures its scene features ([`super::features`]) with one more pass over the
    /// codes the characterization left on the device (no second upload). The features equal
    /// [`super::features_cpu`] exactly. The pass's GPU time is appended to the characterization's timings as
    /// `features`.
    pub fn characterize_with_features(
        &mut self,
        mesh: &Mesh,
        params: &Params,
    ) -> Result<(Characterization, Features), CharError> {
        let mut c = self.run(mesh, params, false)?;
        let (f, timings) = self.features_of_last(mesh, params, c.triangles)?;
        c.timings.extend(timings.into_iter().map(|(name, ms)| PassTime { name, ms }));
        Ok((c, f))
    }

    fn features_of_last(
        &mut self,
        mesh: &Mesh,
        params: &Params,
        n: u64,
    ) -> Result<(Features, Vec<(String, f64)>), CharError> {
        if self.features.is_none() {
            self.features = Some(FeaturesGpu::new(&self.ctx, SIZE_BINS as u32).map_err(gpu_err)?);
        }
        let (Some(fg), Some(buffers), Some((_, codes, _))) =
            (self.features.as_mut(), self.mesh.as_ref(), self.gpu.device_arrays())
        else {
            return Err(CharError::Gpu("feature pass without a characterized mesh".into()));
        };
        let g = fg.run(&buffers.view(), codes, n, params.sample_stride as u64, params.morton_bits).map_err(gpu_err)?;
        let f = features_from_gpu(&g, n, mesh.triangle_count() as u64, params.morton_bits);
        Ok((f, g.timings))
    }

    /// Characterizes every frame of an animation: the indices are uploaded once, each frame uploads only its
    /// positions, and pipelines and scratch buffers are reused.
    pub fn characterize_animation(
        &mut self,
        anim: &Animation,
        params: &Params,
    ) -> Result<Vec<Characterization>, CharError> {
        let mut out = Vec::with_capacity(anim.frames.len());
        for (i, frame) in anim.frames.iter().enumerate() {
            out.push(self.run(frame, params, i > 0)?);
        }
        Ok(out)
    }

    fn run(&mut self, mesh: &Mesh, params: &Params, same_topology: bool) -> Result<Characterization, CharError> {
        params.validate()?;
        mesh.validate().map_err(CharError::Mesh)?;
        if mesh.triangle_count() == 0 {
            return Err(CharError::Empty { mesh: mesh.name.clone() });
        }
        let start = Instant::now();
        match &self.mesh {
            Some(m) if same_topology => m.update_positions(&self.ctx, &mesh.positions).map_err(gpu_err)?,
            _ => {
                self.mesh = None;
                self.mesh = Some(MeshBuffers::upload(&self.ctx, &mesh.positions, &mesh.indices).map_err(gpu_err)?);
            }
        }
        let upload_ms = start.elapsed().as_secs_f64() * 1e3;
        let Some(buffers) = self.mesh.as_ref() else { return Err(CharError::Gpu("mesh buffers missing".into())) };
        let rule = params.class_rule;
        let max_k = self.gpu.max_classes();
        let plan = move |s: &CodeSums| -> Result<ClassPlan, String> {
            let stats = code_stats(s);
            let k = class_count_of(rule, &stats).min(max_k);
            Ok(ClassPlan { k, thresholds: class_thresholds(s.code_min, s.code_max, k) })
        };
        let out = self
            .gpu
            .run(&buffers.view(), params.morton_bits, params.sample_stride as u64, &plan, params.keep_per_triangle)
            .map_err(|e| match e {
                RunError::Gpu(g) => gpu_err(g),
                RunError::Input(i) => CharError::Input { mesh: mesh.name.clone(), reason: i.to_string() },
            })?;
        let k = out.plan.k;
        let hstats = super::finalize::histogram_stats_exact(
            out.chi_numerator,
            out.empty_classes,
            out.concentrated_classes,
            out.concentrated_triangles,
            out.n,
            k,
            params.alpha,
        );
        let mut timings: Vec<PassTime> = vec![PassTime { name: "upload".into(), ms: upload_ms }];
        timings.extend(out.timings.iter().map(|(name, ms)| PassTime { name: name.clone(), ms: *ms }));
        timings.push(PassTime { name: PassTime::TOTAL.into(), ms: start.elapsed().as_secs_f64() * 1e3 });
        let exact = Exact {
            lo: out.lo,
            hi: out.hi,
            code_stats: code_stats(&out.sums),
            classes: k,
            histogram: out.histogram,
            stats: hstats,
            per_triangle: out.per_triangle.map(|(codes, classes)| PerTriangle { codes, classes }),
        };
        let device = self.ctx.caps().name.clone();
        Ok(Characterization::from_exact(mesh, params, exact, timings, Backend::Vulkan, device))
    }
}

fn run_err(e: RunError, name: &str) -> CharError {
    match e {
        RunError::Gpu(g) => gpu_err(g),
        RunError::Input(i) => CharError::Input { mesh: name.to_string(), reason: i.to_string() },
    }
}

/// The mesh of the warm-up: two triangles spanning a unit box (non-empty bounds in every axis).
fn warmup_mesh() -> Result<Mesh, CharError> {
    let positions = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 1.0]];
    Mesh::new("warm-up", positions, vec![[0, 1, 2], [1, 3, 2]]).map_err(CharError::Mesh)
}

fn gpu_err(e: crate::gpu::GpuError) -> CharError {
    CharError::Gpu(e.to_string())
}
