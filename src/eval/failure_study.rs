//! The failure study (`docs/failure-study.md`): the scenes on which characterization, policy or oracle are pushed
//! past their comfort zone, and the measurements the study reports on each.
//!
//! Everything here except the oracle's timings is deterministic: the scenes come from seeded generators, the
//! statistics are exact (identical on every backend, see `docs/spec.md`), and SAH costs, hit counts and traversal
//! counters do not depend on timing or thread count. `examples/failure_study.rs` prints the tables of the study from
//! these functions, and `tests/core/failure_study.rs` pins every claim of the study on them.

use crate::accel::bvh::Bvh;
use crate::accel::lbvh::Lbvh;
use crate::accel::{AccelError, AccelStructure};
use crate::characterize::{CharError, Characterization, Characterizer, Params};
use crate::geom::Camera;
use crate::geom::WorkloadKind;
use crate::mesh::{generate, Animation, Mesh, MeshError};
use crate::select::{Policy, SceneSummary, ThesisPolicy};
use crate::select::{SceneKind, Structure};
use crate::trace::workload::{mesh_bounds, primary_rays};
use crate::trace::{trace, RaySet};
use std::time::Instant;

/// One scene of the study: a name, what it stands for, and its frames (one for a static scene).
#[derive(Clone, Debug)]
pub struct Case {
    /// Short name (`tiny_n_3`, `all_equal`, ...), the key of the tables.
    pub name: String,
    /// What the scene is, in words.
    pub description: String,
    /// The frames (one for a static scene, all with one topology).
    pub frames: Vec<Mesh>,
}

impl Case {
    /// A static case.
    pub fn fixed(name: impl Into<String>, description: impl Into<String>, mesh: Mesh) -> Case {
        Case { name: name.into(), description: description.into(), frames: vec![mesh] }
    }

    /// The frames as an [`Animation`] (one frame for a static case).
    pub fn animation(&self) -> Result<Animation, MeshError> {
        Animation::new(self.name.clone(), self.frames.clone())
    }
}

/// The meshes one after the other in one mesh (positions appended, indices shifted; object ids dropped).
pub fn concat(name: impl Into<String>, meshes: &[&Mesh]) -> Result<Mesh, MeshError> {
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    let name = name.into();
    for m in meshes {
        m.validate()?;
        let base =
            u32::try_from(positions.len() + m.positions.len()).map(|_| positions.len() as u32).map_err(|_| {
                MeshError::Invalid {
                    file: name.clone(),
                    reason: "the meshes together need more vertices than 32-bit indices address".into(),
                }
            })?;
        positions.extend_from_slice(&m.positions);
        indices.extend(m.indices.iter().map(|t| t.map(|i| i + base)));
    }
    Mesh::new(name, positions, indices)
}

/// A nearly uniform scene for the large-`n` case: `n` triangles of which `n / 25` (4 %) sit in one gaussian blob
/// and the rest are a uniform random soup. The blob shifts about 4 % of the mass into a few classes, an effect of
/// Cramér's V of a few hundredths that does not depend on `n`.
///
/// Fails when `n` exceeds [`generate::MAX_SOUP_TRIANGLES`].
pub fn near_uniform_mixture(n: usize, seed: u64) -> Result<Mesh, MeshError> {
    if n > generate::MAX_SOUP_TRIANGLES {
        return Err(MeshError::Invalid {
            file: format!("near_uniform_mixture(n={n})"),
            reason: format!("more than {} triangles", generate::MAX_SOUP_TRIANGLES),
        });
    }
    let blob = n / 25;
    let soup = generate::random_soup(n - blob, seed);
    let cluster = generate::clustered(blob, 1, seed ^ 0x9e37_79b9);
    concat(format!("near_uniform_mixture(n={n}, seed={seed})"), &[&soup, &cluster])
}

/// Sizes of the large-`n` case.
pub const LARGE_N_SIZES: [usize; 4] = [1_000, 10_000, 100_000, 1_000_000];

/// Frames of the explosion case.
pub const EXPLOSION_FRAMES: usize = 16;

/// The cases of the study that need no file, in the study's order. `large_n_max` caps the sizes of the large-`n`
/// case (the tests use smaller ones than the example).
pub fn generated_cases(large_n_max: usize) -> Result<Vec<Case>, MeshError> {
    let mut out = Vec::new();
    for &n in LARGE_N_SIZES.iter().filter(|&&n| n <= large_n_max) {
        out.push(Case::fixed(
            format!("large_n_{n}"),
            format!("{n} triangles: uniform soup with 4% in one blob"),
            near_uniform_mixture(n, 7)?,
        ));
    }
    for n in [1usize, 2, 3, 5, 10] {
        out.push(Case::fixed(format!("tiny_n_{n}"), format!("{n} random triangles"), generate::random_soup(n, 3)));
    }
    out.push(Case::fixed("all_equal", "1,000 copies of one triangle", generate::all_equal(1000)));
    out.push(Case::fixed("flat", "10,000 triangles in the plane z = 0", generate::flat(10_000, 5)));
    out.push(Case::fixed(
        "collinear",
        "1,000 triangles with centroids on the x axis",
        generate::collinear_centroids(1000),
    ));
    let soup = generate::random_soup(5000, 11);
    out.push(Case::fixed("soup_5000", "5,000 random triangles (reference for the next three)", soup.clone()));
    out.push(Case::fixed("duplicated_4x", "the same soup, every triangle 4 times", generate::duplicated(&soup, 4)?));
    out.push(Case::fixed("huge_1e30", "the same soup scaled by 1e30", generate::scaled(&soup, 1e30)?));
    out.push(Case::fixed("tiny_1e-30", "the same soup scaled by 1e-30", generate::scaled(&soup, 1e-30)?));
    out.push(Case::fixed("zero_area", "3,000 zero-area triangles", generate::zero_area(3000, 13)));
    out.push(Case::fixed(
        "teapot_in_stadium",
        "992-triangle teapot (diagonal 1) inside a 2e4-wide box of 12 triangles",
        generate::teapot_in_stadium(17),
    ));
    out.push(Case::fixed(
        "long_thin",
        "one sliver along the scene diagonal plus 1,000 small triangles",
        generate::long_thin_triangle(),
    ));
    out.push(Case::fixed(
        "overlapping_large",
        "2,000 triangles with vertices uniform in the unit cube",
        generate::overlapping_large(2000, 19),
    ));
    let teapot = crate::mesh::default_teapot();
    let anim = generate::explode(&teapot, EXPLOSION_FRAMES, 23)?;
    out.push(Case {
        name: "explosion".into(),
        description: format!("the embedded teapot exploding along its normals, {EXPLOSION_FRAMES} frames"),
        frames: anim.frames,
    });
    Ok(out)
}

/// The numbers of one frame (everything but timings: identical on every backend and every run).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FrameStats {
    /// `n`.
    pub triangles: u64,
    /// Zero-area triangles.
    pub zero_area: u64,
    /// Step 2 bounds.
    pub lo: [f32; 3],
    /// Step 2 bounds.
    pub hi: [f32; 3],
    /// Smallest and largest Morton code.
    pub code_range: [u64; 2],
    /// `k`.
    pub classes: u32,
    /// The histogram.
    pub histogram: Vec<u64>,
    /// Chi-square.
    pub chi_square: f64,
    /// Degrees of freedom.
    pub dof: u32,
    /// p-value.
    pub p_value: f64,
    /// Whether the test accepts uniformity at the parameters' alpha.
    pub uniform: bool,
    /// Cramér's V.
    pub effect_size: f64,
    /// Empty classes.
    pub empty_classes: u32,
    /// Classes above the mean count.
    pub concentrated_classes: u32,
    /// Share of the triangles in them.
    pub concentrated_share: f64,
}

impl FrameStats {
    /// The figures of a characterization of `mesh`.
    pub fn of(mesh: &Mesh, c: &Characterization) -> FrameStats {
        let s = &c.stats;
        FrameStats {
            triangles: c.triangles,
            zero_area: mesh.zero_area_count() as u64,
            lo: c.lo,
            hi: c.hi,
            code_range: [c.code_stats.code_min, c.code_stats.code_max],
            classes: c.classes,
            histogram: c.histogram.clone(),
            chi_square: s.chi_square,
            dof: s.dof,
            p_value: s.p_value,
            uniform: s.uniform,
            effect_size: s.cramers_v,
            empty_classes: s.empty_classes,
            concentrated_classes: s.concentrated_classes,
            concentrated_share: s.concentrated_share,
        }
    }
}

/// What characterization and policy say about a case.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct CaseStats {
    /// The case's name.
    pub case: String,
    /// Static or dynamic.
    pub kind: SceneKind,
    /// Every frame's figures.
    pub frames: Vec<FrameStats>,
    /// What [`ThesisPolicy`] selects.
    pub selected: Structure,
    /// Why.
    pub reasons: Vec<crate::select::Reason>,
}

/// Characterizes every frame of `case` with `engine` and lets the default [`ThesisPolicy`] select.
pub fn characterize_case(case: &Case, engine: &mut Characterizer, params: &Params) -> Result<CaseStats, CharError> {
    let chars: Vec<Characterization> = if case.frames.len() > 1 {
        engine.characterize_animation(&case.animation()?, params)?
    } else {
        case.frames.iter().map(|m| engine.characterize(m, params)).collect::<Result<_, _>>()?
    };
    let summary = SceneSummary::new(case.name.clone(), &chars);
    let sel = ThesisPolicy::default().select(&summary);
    Ok(CaseStats {
        case: case.name.clone(),
        kind: summary.kind,
        frames: case.frames.iter().zip(&chars).map(|(m, c)| FrameStats::of(m, c)).collect(),
        selected: sel.structure,
        reasons: sel.reasons,
    })
}

/// Primary rays of the automatic camera of `mesh` at `resolution x resolution`, traced through a binned-SAH BVH
/// and through the brute-force reference: how many hit (in both: the structure is not at fault when nothing hits).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct HitCount {
    /// Rays traced.
    pub rays: usize,
    /// Rays that hit a triangle in the BVH.
    pub bvh_hits: usize,
    /// Rays that hit a triangle in the brute-force reference.
    pub brute_hits: usize,
}

/// Counts the hits of the primary rays of the automatic camera (see [`HitCount`]).
pub fn primary_hits(mesh: &Mesh, resolution: u32) -> Result<HitCount, AccelError> {
    let camera = Camera::frame(&mesh_bounds(mesh));
    let rays =
        RaySet { kind: WorkloadKind::Primary, rays: primary_rays(&camera, resolution, resolution), any_hit: false };
    let bvh = Bvh::build(mesh)?;
    let brute = crate::accel::brute::BruteForce::build(mesh)?;
    let count = |a: &dyn AccelStructure| trace(a, &rays).hits.iter().filter(|h| h.is_some()).count();
    Ok(HitCount { rays: rays.rays.len(), bvh_hits: count(&bvh), brute_hits: count(&brute) })
}

/// One frame of the refit study: a tree built on frame 0 and refitted, against a tree built for the frame.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct RefitFrame {
    /// Frame index.
    pub frame: usize,
    /// SAH cost of the binned-SAH BVH built for this frame.
    pub bvh_rebuild_sah: f64,
    /// SAH cost of the binned-SAH BVH of frame 0 refitted to this frame.
    pub bvh_refit_sah: f64,
    /// SAH cost of the LBVH built for this frame.
    pub lbvh_rebuild_sah: f64,
    /// SAH cost of the LBVH of frame 0 refitted to this frame.
    pub lbvh_refit_sah: f64,
    /// Triangle tests per primary ray, refitted BVH (camera framing every frame, `resolution` of the study).
    pub bvh_refit_prim_tests: f64,
    /// Triangle tests per primary ray, rebuilt BVH.
    pub bvh_rebuild_prim_tests: f64,
    /// Milliseconds to build the binned-SAH BVH for this frame (timing: varies with load).
    pub bvh_build_ms: f64,
    /// Milliseconds to refit the frame-0 BVH to this frame (timing: varies with load).
    pub bvh_refit_ms: f64,
    /// Milliseconds to trace the primary rays through the rebuilt BVH (timing).
    pub bvh_rebuild_trace_ms: f64,
    /// Milliseconds to trace the primary rays through the refitted BVH (timing).
    pub bvh_refit_trace_ms: f64,
}

/// Builds the BVH and LBVH of frame 0, refits them frame by frame, and compares with fresh builds: SAH costs,
/// triangle tests per primary ray (`resolution x resolution` rays from a camera that frames every frame), and
/// build, refit and trace times.
pub fn refit_study(anim: &Animation, resolution: u32) -> Result<Vec<RefitFrame>, AccelError> {
    let Some(first) = anim.frames.first() else {
        return Ok(Vec::new());
    };
    let mut bounds = mesh_bounds(first);
    for f in &anim.frames {
        bounds = bounds.union(&mesh_bounds(f));
    }
    let camera = Camera::frame(&bounds);
    let rays =
        RaySet { kind: WorkloadKind::Primary, rays: primary_rays(&camera, resolution, resolution), any_hit: false };
    let per_ray = |tests: u64| tests as f64 / rays.rays.len().max(1) as f64;
    let mut bvh = Bvh::build(first)?;
    let mut lbvh = Lbvh::build(first)?;
    let mut out = Vec::with_capacity(anim.frames.len());
    for (i, frame) in anim.frames.iter().enumerate() {
        let t = Instant::now();
        bvh.refit(frame)?;
        let bvh_refit_ms = t.elapsed().as_secs_f64() * 1e3;
        lbvh.refit(frame)?;
        let t = Instant::now();
        let fresh = Bvh::build(frame)?;
        let bvh_build_ms = t.elapsed().as_secs_f64() * 1e3;
        let fresh_lbvh = Lbvh::build(frame)?;
        let refit_trace = trace(&bvh, &rays);
        let rebuild_trace = trace(&fresh, &rays);
        out.push(RefitFrame {
            frame: i,
            bvh_rebuild_sah: fresh.tree().sah_cost(),
            bvh_refit_sah: bvh.tree().sah_cost(),
            lbvh_rebuild_sah: fresh_lbvh.tree().sah_cost(),
            lbvh_refit_sah: lbvh.tree().sah_cost(),
            bvh_refit_prim_tests: per_ray(refit_trace.counters.prim_tests),
            bvh_rebuild_prim_tests: per_ray(rebuild_trace.counters.prim_tests),
            bvh_build_ms,
            bvh_refit_ms,
            bvh_rebuild_trace_ms: rebuild_trace.seconds * 1e3,
            bvh_refit_trace_ms: refit_trace.seconds * 1e3,
        });
    }
    Ok(out)
}
