//! No catastrophe: bounds on what the grid and the kd-tree would store, computed before anything is built, and a
//! [`Budget`] that takes a structure out of a policy's candidates when its bound exceeds it.
//!
//! The grid and the kd-tree store a triangle once per cell or leaf it overlaps, so their references (and their build
//! time, which is proportional to them) grow faster than `n` on degenerate input: copies of one large triangle, a
//! fan over three points, many large overlapping triangles. The builders stop at their own budgets
//! ([`AccelError::OverBudget`](crate::accel::AccelError::OverBudget)), but a policy that picks such a structure has
//! already lost: the build runs up to the budget and fails, or succeeds after seconds where a BVH takes
//! milliseconds. So the policies look at [`BuildBounds`] first.
//!
//! # The grid's bound
//!
//! [`BuildBounds::of_mesh`] applies the grid's own rules (`accel::grid`, with its default options; see
//! [`GridRule`]): the resolution from the triangle count and the scene's bounds; a triangle's cells within the cells
//! of its bounding box widened by `1e-4` of a cell (the same f32 arithmetic), clipped slab by slab across the box's
//! shortest side with the grid's own widening and Sutherland-Hodgman clipping; a zero-area triangle counts one
//! cell, as the grid stores it. Per slab the bound is the product of the clipped polygon's cells along the two
//! other axes, where the grid clips once more per row, so the sum is an **upper bound** of the grid's references,
//! exact for a triangle one slab thick and one row wide; it costs one clip per slab a triangle meets (one or two for
//! a small triangle), not one per row and cell as the build's count does. Where that bound exceeds `grid_count_threshold`
//! (or the smaller grid budget a caller passes to `BuildBounds::of_frames_viewed_within`), the budget's verdict
//! and the grid's priced build rest on it, and it can be several times the grid's count (large triangles cross many rows of a slab:
//! 39.3 million against 9.8 million for 20,000 large overlapping triangles), so the references are then **counted
//! exactly**, by the grid's own rule (`GridFrame::for_each_run`: one clip per row, the same code the grid builds
//! with), in index order until the count passes the grid builder's own budget ([`Budget::BUILDERS`]; past it the
//! figure stays an upper bound, [`Bound::Upper`], and no budget keeps a grid that builds); 77 ms against the slab
//! bound's 9 ms there, 3 ms for a fan of 2,000 triangles over one polygon, and nothing on a scene within the
//! threshold. The bytes follow as the grid counts them (cell starts, references, triangle records).
//!
//! `BuildBounds::of_features` bounds the same from the [`Features`] alone (when no mesh is at hand): a triangle
//! of size bin `k` has a largest extent below `2^(e(S) - k + 1)`, so at most that many cells (plus two) along each
//! axis; triangles of zero or subnormal extent count 8 cells. The size histogram tells neither zero-area triangles
//! nor slivers from others, so this bound is far larger than the mesh's where zero-area triangles or long slivers
//! span the scene (400 collinear ones across a lattice count as 400 full rows of cells). It is an upper bound when
//! the features cover every triangle (`sample_stride` 1; the triangle count is scaled from the sample otherwise, an
//! estimate).
//!
//! # The kd-tree's estimate
//!
//! The kd-tree's duplication depends on the SAH's choices and has no cheap exact bound; the **estimate** is
//! [`KD_FACTOR`] (2) times the grid's bound over the triangles of non-zero area, plus one per zero-area triangle
//! (the kd-tree carries them as points). Where the SAH keeps splitting, its leaves are smaller than the grid's cells
//! and it duplicates more than the grid: on the generated scenes of `src/eval/tests/budget.rs` (4,000 triangles) the actual
//! references are 0.9 to 1.0 times the estimate on the flat lattice and the terrain, 0.3 to 0.5 on interiors,
//! cities and vegetation, but **3.2 times** on the engineering model (fans of slivers: 51 references per triangle
//! against an estimate of 16), so the estimate is no bound and the kd-tree's own budget stays the backstop. Where
//! coincident or large overlapping triangles make every split useless, the SAH stops and the estimate is far too
//! large (copies of one triangle: 1 reference per triangle against an estimate of about 10^5).
//!
//! # The budget
//!
//! A [`Budget`] allows the kd-tree `max(references_per_triangle * n, min_references)` references, the grid
//! `max(grid_references_per_triangle * n, grid_min_references)`, and each `max_bytes` bytes. [`Budget::default`]
//! gives the kd-tree 16 references per triangle (three times the most the grid needs on a shared mesh, 5.0 on the
//! teapot, and a quarter of the builders' 64), at least `2^22`, and the grid its builder's own limit (64 per
//! triangle, at least `2^25`); both 4 GiB. The grid's is the looser because its count is exact where it matters:
//! past `grid_count_threshold` (the kd-tree's default, `max(16 n, 2^22)`) the bound pass counts the grid's
//! references exactly, and the calibrated policy prices the grid's build by them ([`BuildBounds::grid_build_work`],
//! the work law of `cost::StructureModel::build_work_coef`): 20,000 large overlapping triangles need 9.7 million
//! references, a build of 265 ms that the law in `n` alone put at 3.2 ms and the work law at 170 ms. A slow grid is
//! then left out by its predicted total, and a fast one (the best there for primary rays, at a third of the BVH's
//! total) stays a candidate. Where nothing prices the build (an upper bound, bounds from features alone, or the
//! thesis policy, `Budget::check_unpriced`) the grid is held to the kd-tree's limits too, as before (by default
//! the threshold). The kd-tree's figure is an estimate with no exact count, so its budget stays the
//! guard. Both are below the builders' own budgets ([`Budget::BUILDERS`]), so a structure the policy keeps never
//! fails its build with `OverBudget` (the kd-tree's estimate permitting). [`Budget::check`] lists the structures
//! whose bound exceeds the budget as [`Exclusion`]s, with the numbers.

use super::Structure;
use crate::accel::grid_rule::{GridFrame, GridOptions};
use crate::characterize::features::{exponent, SIZE_BINS};
use crate::characterize::Features;
use crate::cost::Crossings;
use crate::geom::{Aabb, Triangle};
use crate::mesh::{Mesh, MeshError};
use glam::Vec3;

/// The grid's resolution rule and cell mapping (`accel::grid`): its default options, so that the bound follows the
/// grid the oracle and the engine build.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GridRule {
    /// Cells per triangle (`GridOptions::density`, default 4).
    pub density: f32,
    /// Largest cells along one axis (`GridOptions::max_resolution`, default 1024).
    pub max_resolution: u32,
    /// Largest cells in all (`GridOptions::max_cells`, default `2^24`).
    pub max_cells: usize,
}

impl Default for GridRule {
    fn default() -> Self {
        GridRule { density: 4.0, max_resolution: 1024, max_cells: 1 << 24 }
    }
}

#[cfg(feature = "eval")]
impl From<&crate::accel::grid::GridOptions> for GridRule {
    fn from(o: &crate::accel::grid::GridOptions) -> Self {
        GridRule { density: o.density, max_resolution: o.max_resolution, max_cells: o.max_cells }
    }
}

/// The kd-tree's estimate is this many times the grid's bound (see the module docs).
pub const KD_FACTOR: u64 = 2;

/// Bytes of one triangle record ([`Triangle`]) as the structures count them.
const TRIANGLE_BYTES: u64 = std::mem::size_of::<Triangle>() as u64;

impl GridRule {
    /// The padded bounds and the resolution of a grid over `n` triangles in `bounds`: `accel::grid::grid_resolution`
    /// (the density rule of Cleary and Wyvill; a zero extent padded to `1e-3` of the largest, to 1 for a point).
    pub fn resolution(&self, bounds: &Aabb, n: usize) -> (Aabb, [u32; 3]) {
        crate::accel::grid_rule::resolution(bounds, n, self.density, self.max_resolution, self.max_cells)
    }

    /// The frame of a grid over `n` triangles in `scene` under this rule, as the grid computes it.
    fn frame(&self, scene: &Aabb, n: usize) -> GridFrame {
        let o = GridOptions {
            density: self.density,
            max_resolution: self.max_resolution,
            max_cells: self.max_cells,
            ..GridOptions::default()
        };
        GridFrame::new(scene, n, &o)
    }
}

/// At most how many cells of `frame` along axis `a` a box of extent below `t` covers (f32 rounding included).
fn span_cells(frame: &GridFrame, t: f64, a: usize) -> u64 {
    let c = f64::from(frame.cell_size[a]);
    let k = if c > 0.0 { (t / c * (1.0 + 1e-5) + 1e-3).floor() } else { f64::INFINITY };
    let k = if k.is_finite() { k as u64 + 2 } else { u64::MAX };
    k.min(u64::from(frame.res[a]))
}

/// The grid's references counted exactly ([`GridFrame::cell_count`]: one clip per row), in index order, chunk by
/// chunk, until the count passes `cap`: then the triangles not counted, and any whose count reached the cap, add
/// their slab bounds (`upper`), and the figure is an upper bound. A chunk holds triangles whose slab bounds, each
/// capped at what is left of `cap`, sum to no more than that (as the grid's builder sizes its own), so no chunk
/// counts much past the cap.
/// A triangle flagged in `copy` (a coincident copy, which the grid stores once) counts nothing.
fn exact_references(
    frame: &GridFrame,
    tris: &[Triangle],
    boxes: &[Aabb],
    upper: &[u64],
    copy: &[bool],
    cap: u64,
) -> (u64, Bound) {
    use rayon::prelude::*;
    let mut prefix = 0u64;
    let mut i = 0;
    while i < tris.len() {
        let left = cap.saturating_sub(prefix).saturating_add(1);
        let (mut j, mut acc) = (i, 0u64);
        while j < tris.len() && j - i < 65_536 {
            let u = upper[j].min(left);
            if j > i && acc.saturating_add(u) > left {
                break;
            }
            acc = acc.saturating_add(u);
            j += 1;
        }
        let counted = (i..j)
            .into_par_iter()
            .map(|k| {
                if copy.get(k) == Some(&true) {
                    return 0;
                }
                let c = frame.cell_count(&tris[k], &boxes[k], left);
                if c >= left {
                    upper[k]
                } else {
                    c
                }
            })
            .reduce(|| 0u64, u64::saturating_add);
        prefix = prefix.saturating_add(counted);
        i = j;
        if prefix > cap {
            let rest = upper[i..].iter().fold(0u64, |a, &b| a.saturating_add(b));
            return (prefix.saturating_add(rest), Bound::Upper);
        }
    }
    (prefix, Bound::Exact)
}

/// Whether a [`BuildBounds`] figure is exact, an upper bound or an estimate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Bound {
    /// The structure's count.
    Exact,
    /// Never below the structure's actual count.
    Upper,
    /// A prediction that can be below the actual count.
    Estimate,
}

/// Bounds on what the grid and the kd-tree would store for a scene, computed without building them (see the
/// module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BuildBounds {
    /// Triangles of the scene.
    pub triangles: u64,
    /// Where the bounds come from: `mesh` ([`BuildBounds::of_mesh`]) or `features` (`BuildBounds::of_features`).
    pub source: &'static str,
    /// The grid's resolution (cells along x, y, z).
    pub grid_resolution: [u32; 3],
    /// The grid's cell references: an upper bound (from the mesh, or from complete features) or an estimate.
    pub grid_references: u64,
    /// Whether [`BuildBounds::grid_references`] is an upper bound.
    pub grid_bound: Bound,
    /// The grid's bytes (cell starts, references, triangle records) at [`BuildBounds::grid_references`].
    pub grid_bytes: u64,
    /// The kd-tree's leaf references: an estimate.
    pub kdtree_references: u64,
    /// The kd-tree's bytes at [`BuildBounds::kdtree_references`]: nodes (about one per reference), references,
    /// triangle records, boxes and ids; an estimate.
    pub kdtree_bytes: u64,
    /// Overlap: the triangle boxes' projected areas against the scene box's, and a camera's count on its image
    /// ([`Crossings`], `crate::cost::overlap`), from which the calibrated policy floors its test counts; `None`
    /// from features alone. Of the first frame when bounds of several frames are merged ([`BuildBounds::max`]).
    pub(crate) box_crossings: Option<Crossings>,
    /// The timed probes of a static scene's view ([`crate::cost::timed`], `BuildBounds::with_timed_probes`),
    /// which the calibrated policy blends into its predictions when its model has their ratios; empty unless
    /// asked for (they are not deterministic).
    pub timed: Vec<crate::cost::timed::TimedProbe>,
}

impl BuildBounds {
    /// The grid's build work ([`crate::accel::AccelStats::build_work`]: its references) where it is known without
    /// building the grid: the references counted exactly from the mesh ([`Bound::Exact`]; the bound pass counts them
    /// where their slab bound exceeds `grid_count_threshold` or the budget). The calibrated policy prices the
    /// grid's build by it ([`crate::cost::StructureModel::build_work_coef`]) instead of by its law in `n` alone, which
    /// was fitted on grids of a few references per triangle. `None` otherwise: an upper bound would overprice the
    /// build (1.1 to 1.9 times the count on the generated families, 2.5 on large overlapping triangles).
    pub fn grid_build_work(&self) -> Option<f64> {
        (self.source == "mesh" && self.grid_bound == Bound::Exact && self.grid_references > 0)
            .then_some(self.grid_references as f64)
    }

    /// These bounds with the timed probes (`crate::cost::timed::time_probes`) of `mesh` (a static scene) seen
    /// from `camera` (`None`: the framing camera of its box) for rays of `kind`: each of `structures` that `budget`
    /// does not exclude ([`Budget::check`]) built once and traced on a sample of the view
    /// ([`super::Selector`] at level 2 probes the contenders of a first selection only).
    pub(crate) fn with_timed_probes(
        mut self,
        mesh: &Mesh,
        camera: Option<&crate::geom::Camera>,
        kind: crate::geom::WorkloadKind,
        structures: &[Structure],
        budget: &Budget,
    ) -> BuildBounds {
        let excluded = budget.check(&self);
        // A grid past the count threshold has no probe ([`crate::cost::probe::PROBE_GRID_BUDGET`]): not built for
        // one here either (its build is priced by its references instead).
        let past = self.grid_references > grid_count_threshold(self.triangles);
        let structures: Vec<Structure> = structures
            .iter()
            .copied()
            .filter(|s| {
                let out = excluded.iter().any(|e| e.structure == *s);
                let unprobed = *s == Structure::Grid && past;
                !out && !unprobed
            })
            .collect();
        let b = crate::cost::timed::mesh_box(mesh);
        let camera =
            camera.copied().unwrap_or_else(|| crate::cost::view::framing_camera(b.min.to_array(), b.max.to_array()));
        self.timed = crate::cost::timed::time_probes(mesh, &camera, &structures, &[kind]);
        self
    }

    /// The bounds of a mesh (see the module docs), with the grid's default rule: one O(n) pass, and the framing
    /// camera's view of the crossings ([`BuildBounds::of_mesh_viewed`]).
    ///
    /// Fails when the mesh is invalid (a non-finite coordinate, an index out of range).
    pub fn of_mesh(mesh: &Mesh) -> Result<BuildBounds, MeshError> {
        BuildBounds::of_mesh_viewed(mesh, None)
    }

    /// `BuildBounds::of_mesh_with` under the grid's default rule, with the crossings of `camera`'s primary rays
    /// counted on its image (`Crossings::viewed_from`; `None`: the framing camera, what the policy assumes
    /// without one), from the same triangle boxes ([`crate::cost::screen_crossings`]: 4.9 ms of this pass's 24
    /// ms for 200,000 triangles on the 2-core VM, `cargo bench --bench accel -- screen_crossings`).
    pub fn of_mesh_viewed(mesh: &Mesh, camera: Option<&crate::geom::Camera>) -> Result<BuildBounds, MeshError> {
        let view = Some((camera, true, &crate::cost::PROBED[..]));
        BuildBounds::of_mesh_counted(mesh, &GridRule::default(), view, &Budget::default())
    }

    /// The largest bounds over the frames of a scene ([`BuildBounds::of_mesh`] of each, [`BuildBounds::max`]);
    /// `None` for no frame.
    #[cfg(test)]
    pub(crate) fn of_frames(frames: &[Mesh]) -> Result<Option<BuildBounds>, MeshError> {
        BuildBounds::of_frames_viewed(frames, None)
    }

    /// [`BuildBounds::of_frames`] with the first frame's crossings viewed from `camera` (the frame the policy
    /// floors; [`BuildBounds::of_mesh_viewed`]).
    #[cfg(test)]
    pub(crate) fn of_frames_viewed(
        frames: &[Mesh],
        camera: Option<&crate::geom::Camera>,
    ) -> Result<Option<BuildBounds>, MeshError> {
        BuildBounds::of_frames_viewed_within(frames, camera, &Budget::default())
    }

    /// [`BuildBounds::of_frames_viewed`] for a policy that will check them against `budget`: the grid's
    /// references are counted exactly where their slab bound, or the bytes it implies, exceeds the smaller of
    /// `budget`'s grid limits and [`grid_count_threshold`] (see the module docs), so that neither the budget's verdict
    /// nor the grid's priced build rests on the looser
    /// bound (up to the builders' own budget, [`Budget::BUILDERS`], past which no grid builds).
    #[cfg(test)]
    pub(crate) fn of_frames_viewed_within(
        frames: &[Mesh],
        camera: Option<&crate::geom::Camera>,
        budget: &Budget,
    ) -> Result<Option<BuildBounds>, MeshError> {
        BuildBounds::of_frames_probed(frames, camera, budget, &crate::cost::PROBED)
    }

    /// [`BuildBounds::of_frames_viewed_within`] with count probes of `probes` only (of those [`crate::cost::PROBED`]
    /// holds; none for an animation): what the selection's first level of inquiry learns.
    pub(crate) fn of_frames_probed(
        frames: &[Mesh],
        camera: Option<&crate::geom::Camera>,
        budget: &Budget,
        probes: &[Structure],
    ) -> Result<Option<BuildBounds>, MeshError> {
        let mut out: Option<BuildBounds> = None;
        let rule = GridRule::default();
        for (i, f) in frames.iter().enumerate() {
            // An animation's first frame without the boxes entered before the hits: they bound that frame's rays
            // only (`Crossings::over_frames` would drop them; the pass is skipped instead).
            let view = (i == 0).then_some((camera, frames.len() == 1, probes));
            let b = BuildBounds::of_mesh_counted(f, &rule, view, budget)?;
            out = Some(match out {
                Some(o) => o.max(&b),
                None => b,
            });
        }
        Ok(out)
    }

    /// [`BuildBounds::of_mesh`] under a given grid rule, without a camera's view of the crossings.
    #[cfg(feature = "eval")]
    pub(crate) fn of_mesh_with(mesh: &Mesh, rule: &GridRule) -> Result<BuildBounds, MeshError> {
        BuildBounds::of_mesh_counted(mesh, rule, None, &Budget::default())
    }

    /// The one pass over the triangles behind [`BuildBounds::of_mesh_with`] and [`BuildBounds::of_mesh_viewed`]:
    /// `view` is `Some((camera, near))` to count the crossings on that camera's image (`None` as the camera: the
    /// framing one), and with `near` also the boxes its rays enter before their hits ([`Crossings::with_view`]).
    fn of_mesh_counted(
        mesh: &Mesh,
        rule: &GridRule,
        view: Option<(Option<&crate::geom::Camera>, bool, &[Structure])>,
        budget: &Budget,
    ) -> Result<BuildBounds, MeshError> {
        crate::in_pool(|| BuildBounds::of_mesh_counted_here(mesh, rule, view, budget))
    }

    fn of_mesh_counted_here(
        mesh: &Mesh,
        rule: &GridRule,
        view: Option<(Option<&crate::geom::Camera>, bool, &[Structure])>,
        budget: &Budget,
    ) -> Result<BuildBounds, MeshError> {
        use rayon::prelude::*;
        mesh.validate()?;
        let n = mesh.triangle_count();
        // In parallel where the result cannot depend on the schedule: the records and boxes (per triangle) and the
        // saturating counts (sums of non-negative integers, associative). The boxes' union (whose min and max may
        // pick either zero of +-0 in another order) and the face-area sums of the crossings ([`Crossings::of`]) stay
        // in mesh order, so that the bounds are the same bits on any number of threads.
        let (tris, boxes): (Vec<Triangle>, Vec<Aabb>) = (0..n)
            .into_par_iter()
            .map(|i| {
                let v = mesh.triangle(i);
                (Triangle::new(&v), Aabb::of_triangle(&v))
            })
            .unzip();
        let scene = boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b));
        if n == 0 || !(scene.max - scene.min).is_finite() {
            // Empty, or too wide for the grid (it refuses such bounds itself): nothing to bound.
            return Ok(BuildBounds::empty(n as u64, "mesh"));
        }
        let grid = rule.frame(&scene, n);
        // Coincident copies: the grid and the kd-tree store each group once.
        let copy = crate::accel::copies::copy_mask(n, &crate::accel::copies::position_copies(mesh, &tris));
        let upper: Vec<u64> = tris
            .par_iter()
            .zip(&boxes)
            .zip(&copy)
            .map(|((t, b), &c)| if c { 0 } else { grid.slab_bound(t, b) })
            .collect();
        let (g, k) = tris
            .par_iter()
            .zip(&upper)
            .zip(&copy)
            .map(|((t, &c), &dup)| match (dup, t.is_degenerate()) {
                (true, _) => (0, 0),
                (false, true) => (c, 1),
                (false, false) => (c, c.saturating_mul(KD_FACTOR)),
            })
            .reduce(|| (0u64, 0u64), |a, b| (a.0.saturating_add(b.0), a.1.saturating_add(b.1)));
        // Where the slab bound exceeds the count threshold or the caller's grid budget (references or bytes), the
        // budget's verdict and the grid's priced build rest on it, and the bound can be several times the grid's
        // count (large triangles across many rows of a slab): count exactly, up to what the grid's builder allows
        // (past it no budget keeps a grid that builds).
        let nu = n as u64;
        let refs_allowed = budget.grid_references(nu).min(grid_count_threshold(nu));
        let bytes_allowed = budget.max_bytes.min(Budget::default().max_bytes);
        let over = |g: u64| g > refs_allowed || BuildBounds::grid_bytes(&grid, nu, g) > bytes_allowed;
        let (g, kind) = if over(g) {
            exact_references(&grid, &tris, &boxes, &upper, &copy, Budget::BUILDERS.grid_references(nu))
        } else {
            (g, Bound::Upper)
        };
        let mut crossings = Crossings::of(mesh, boxes.iter().zip(&tris).map(|(b, t)| (*b, t.is_degenerate())), &scene);
        if let Some((camera, near, probes)) = view {
            crossings = crossings.viewed_from(&boxes, if near { &tris } else { &[] }, &scene, camera);
            if near {
                // A grid past the count threshold (the probe's own budget, `cost::probe::PROBE_GRID_BUDGET`) or the
                // caller's grid budget is priced by its count or excluded: none is built for a probe.
                let skip: Vec<Structure> = crate::cost::PROBED
                    .into_iter()
                    .filter(|s| !probes.contains(s) || (*s == Structure::Grid && over(g)))
                    .collect();
                crossings = crossings.with_probes_but(mesh, &scene, &skip);
            }
        }
        Ok(BuildBounds { box_crossings: Some(crossings), ..BuildBounds::finish(n as u64, "mesh", &grid, g, kind, k) })
    }

    /// The bounds from a scene's features alone (see the module docs), with the grid's default rule.
    pub(crate) fn of_features(f: &Features) -> BuildBounds {
        BuildBounds::of_features_with(f, &GridRule::default())
    }

    /// [`BuildBounds::of_features`] under a given grid rule.
    pub(crate) fn of_features_with(f: &Features, rule: &GridRule) -> BuildBounds {
        let n = f.scene_triangles();
        let scene = Aabb::new(Vec3::from_array(f.lo), Vec3::from_array(f.hi));
        if n == 0 || f.triangles == 0 || scene.is_empty() || !(scene.max - scene.min).is_finite() {
            return BuildBounds::empty(n, "features");
        }
        let nu = usize::try_from(n).unwrap_or(usize::MAX);
        let grid = rule.frame(&scene, nu);
        let s = scene.extent().max_element();
        let scale = n as f64 / f.triangles as f64;
        let bound = |cells: &GridFrame| -> u64 {
            let mut total = 8.0 * f.zero_extent as f64;
            if let Some(es) = exponent(s) {
                for (k, &count) in f.size_histogram.iter().enumerate().take(SIZE_BINS) {
                    if count == 0 {
                        continue;
                    }
                    // Largest extent below 2^(e(S) - k + 1) (the last bin holds everything smaller).
                    let t = 2f64.powi(es - k as i32 + 1);
                    let per: f64 = (0..3)
                        .map(|a| {
                            let e = f64::from(scene.max[a] - scene.min[a]);
                            span_cells(cells, t.min(e), a) as f64
                        })
                        .product();
                    total += count as f64 * per;
                }
            }
            let v = (total * scale).ceil();
            if v >= u64::MAX as f64 {
                u64::MAX
            } else {
                v as u64
            }
        };
        let g = bound(&grid);
        let k = g.saturating_mul(KD_FACTOR);
        let kind = if f.triangles >= n { Bound::Upper } else { Bound::Estimate };
        BuildBounds::finish(n, "features", &grid, g, kind, k)
    }

    fn empty(n: u64, source: &'static str) -> BuildBounds {
        BuildBounds {
            triangles: n,
            source,
            grid_resolution: [0; 3],
            grid_references: 0,
            grid_bound: Bound::Upper,
            grid_bytes: 0,
            kdtree_references: 0,
            kdtree_bytes: 0,
            box_crossings: None,
            timed: Vec::new(),
        }
    }

    /// The grid's bytes for `n` triangles and `g` references: cell starts, references, triangle records.
    fn grid_bytes(grid: &GridFrame, n: u64, g: u64) -> u64 {
        let tri = n.saturating_mul(TRIANGLE_BYTES);
        grid.cells().saturating_add(1).saturating_mul(4).saturating_add(g.saturating_mul(4)).saturating_add(tri)
    }

    fn finish(n: u64, source: &'static str, grid: &GridFrame, g: u64, kind: Bound, k: u64) -> BuildBounds {
        let tri = n.saturating_mul(TRIANGLE_BYTES);
        BuildBounds {
            triangles: n,
            source,
            grid_resolution: grid.res,
            grid_references: g,
            grid_bound: kind,
            grid_bytes: BuildBounds::grid_bytes(grid, n, g),
            kdtree_references: k,
            // Nodes of 8 bytes (about one per reference), 4-byte references, records, 24-byte boxes, 4-byte ids.
            kdtree_bytes: k.saturating_mul(12).saturating_add(tri).saturating_add(n.saturating_mul(28)),
            box_crossings: None,
            timed: Vec::new(),
        }
    }

    /// The references and bytes bounded for `structure`, `None` for the structures that store every triangle once
    /// (the BVH family and the BIH: `n` references, no duplication).
    pub fn of(&self, structure: Structure) -> Option<(u64, u64)> {
        match structure {
            Structure::Grid => Some((self.grid_references, self.grid_bytes)),
            Structure::KdTree => Some((self.kdtree_references, self.kdtree_bytes)),
            _ => None,
        }
    }

    /// The larger of two bounds, figure by figure (the frames of an animation: a structure rebuilt every frame must
    /// fit every frame).
    pub fn max(self, o: &BuildBounds) -> BuildBounds {
        let pick = |a: u64, b: u64| a.max(b);
        BuildBounds {
            triangles: self.triangles.max(o.triangles),
            source: self.source,
            grid_resolution: if o.grid_references > self.grid_references {
                o.grid_resolution
            } else {
                self.grid_resolution
            },
            grid_references: pick(self.grid_references, o.grid_references),
            grid_bound: match (self.grid_bound, o.grid_bound) {
                (Bound::Exact, Bound::Exact) => Bound::Exact,
                (Bound::Estimate, _) | (_, Bound::Estimate) => Bound::Estimate,
                _ => Bound::Upper,
            },
            grid_bytes: pick(self.grid_bytes, o.grid_bytes),
            kdtree_references: pick(self.kdtree_references, o.kdtree_references),
            kdtree_bytes: pick(self.kdtree_bytes, o.kdtree_bytes),
            // The first frame's: the calibrated policy floors every frame's predictions with them; what another
            // frame changes of the scene's box undoes the rules that rest on it (`Crossings::over_frames`).
            box_crossings: match (self.box_crossings, o.box_crossings) {
                (Some(a), Some(b)) => Some(a.over_frames(&b)),
                (a, b) => a.or(b),
            },
            // Timed probes describe a static scene's one mesh; an animation's frames have none.
            timed: Vec::new(),
        }
    }
}

/// How many references and bytes a policy lets a structure have (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Budget {
    /// References allowed per triangle: the kd-tree's.
    pub references_per_triangle: f64,
    /// References always allowed, however few the triangles: the kd-tree's.
    pub min_references: u64,
    /// Bytes allowed per structure.
    pub max_bytes: u64,
    /// The grid's references allowed per triangle. The bound pass counts the grid's references exactly wherever
    /// they may exceed `grid_count_threshold`, and the calibrated policy then prices the grid's build by them, so
    /// the default is the builder's own limit: a slow grid is left out by its predicted time, not by a guess at it.
    pub grid_references_per_triangle: f64,
    /// The grid's references always allowed, however few the triangles.
    pub grid_min_references: u64,
}

impl Default for Budget {
    fn default() -> Self {
        Budget {
            references_per_triangle: 16.0,
            min_references: 1 << 22,
            max_bytes: 4 << 30,
            grid_references_per_triangle: Budget::BUILDERS.grid_references_per_triangle,
            grid_min_references: Budget::BUILDERS.grid_min_references,
        }
    }
}

/// References above which the bound pass counts the grid's references exactly, so that the calibrated policy prices
/// the grid's build by them: `max(16 n, 2^22)` for `n` triangles, three times the most a grid needs on a shared mesh
/// (5.0 per triangle, the teapot) and far beyond the grids the build laws were fitted on (at most 5.25 per triangle).
/// It is the probes' own grid budget ([`crate::cost::probe::PROBE_GRID_BUDGET`]): a grid past it is neither built
/// for a probe nor left to the law in `n`.
pub(crate) fn grid_count_threshold(n: u64) -> u64 {
    let [per, least] = crate::cost::probe::PROBE_GRID_BUDGET;
    allowed(per as f64, least as u64, n)
}

impl Budget {
    /// The builders' own budgets (the `GridOptions` defaults: 64 per triangle, at least `2^25`, 4 GiB; the kd-tree,
    /// which never fails, is held to the same):
    /// the loosest budget under which a kept grid never fails its build with `OverBudget`.
    pub const BUILDERS: Budget = Budget {
        references_per_triangle: 64.0,
        min_references: 1 << 25,
        max_bytes: 4 << 30,
        grid_references_per_triangle: 64.0,
        grid_min_references: 1 << 25,
    };

    /// No limit: nothing is ever excluded.
    pub const UNLIMITED: Budget = Budget {
        references_per_triangle: f64::INFINITY,
        min_references: u64::MAX,
        max_bytes: u64::MAX,
        grid_references_per_triangle: f64::INFINITY,
        grid_min_references: u64::MAX,
    };

    /// This budget with the kd-tree's reference limits for the grid too.
    #[cfg(test)]
    pub(crate) fn same_for_the_grid(self) -> Budget {
        Budget {
            grid_references_per_triangle: self.references_per_triangle,
            grid_min_references: self.min_references,
            ..self
        }
    }

    /// The kd-tree's references allowed for `n` triangles: `max(references_per_triangle * n, min_references)`.
    pub fn references(&self, n: u64) -> u64 {
        allowed(self.references_per_triangle, self.min_references, n)
    }

    /// The grid's references allowed for `n` triangles: `max(grid_references_per_triangle * n,
    /// grid_min_references)`.
    pub(crate) fn grid_references(&self, n: u64) -> u64 {
        allowed(self.grid_references_per_triangle, self.grid_min_references, n)
    }

    /// The structures whose bounds exceed this budget, grid first.
    ///
    /// The grid's own limits hold where its build is priced by its references ([`BuildBounds::grid_build_work`]);
    /// elsewhere (an upper bound, or bounds from features) the grid is held to the kd-tree's limits too, as before
    /// the grid had its own (by default `grid_count_threshold`), since nothing would price a larger grid's build.
    pub fn check(&self, bounds: &BuildBounds) -> Vec<Exclusion> {
        self.check_priced(bounds, bounds.grid_build_work().is_some())
    }

    /// [`Budget::check`] for a policy that prices no build (the thesis policy): the grid held to the kd-tree's
    /// limits too (by default [`grid_count_threshold`]), whatever its count.
    pub(crate) fn check_unpriced(&self, bounds: &BuildBounds) -> Vec<Exclusion> {
        self.check_priced(bounds, false)
    }

    fn check_priced(&self, bounds: &BuildBounds, grid_priced: bool) -> Vec<Exclusion> {
        let mut out = Vec::new();
        for s in [Structure::Grid, Structure::KdTree] {
            let Some((refs, bytes)) = bounds.of(s) else { continue };
            let (allowed, per_triangle, least) = if s == Structure::Grid {
                let own = self.grid_references(bounds.triangles);
                let kd = self.references(bounds.triangles);
                if grid_priced || own <= kd {
                    (own, self.grid_references_per_triangle, self.grid_min_references)
                } else {
                    (kd, self.references_per_triangle, self.min_references)
                }
            } else {
                (self.references(bounds.triangles), self.references_per_triangle, self.min_references)
            };
            let kind = if s == Structure::Grid { bounds.grid_bound } else { Bound::Estimate };
            let word = match kind {
                Bound::Exact => "exactly",
                Bound::Upper => "at most",
                Bound::Estimate => "an estimated",
            };
            let per = refs as f64 / bounds.triangles.max(1) as f64;
            if refs > allowed {
                out.push(Exclusion {
                    structure: s,
                    what: "references",
                    needed: refs,
                    budget: allowed,
                    bound: kind,
                    reason: format!(
                        "{s}: {word} {refs} references ({per:.1} per triangle, from the {}) exceed the budget of \
                         {allowed} ({} per triangle for {} triangles, at least {})",
                        bounds.source, per_triangle, bounds.triangles, least
                    ),
                });
            } else if bytes > self.max_bytes {
                out.push(Exclusion {
                    structure: s,
                    what: "bytes",
                    needed: bytes,
                    budget: self.max_bytes,
                    bound: kind,
                    reason: format!(
                        "{s}: {word} {bytes} bytes (from the {}) exceed the budget of {} bytes",
                        bounds.source, self.max_bytes
                    ),
                });
            }
        }
        out
    }
}

/// `max(per * n, least)`, saturating.
fn allowed(per: f64, least: u64, n: u64) -> u64 {
    let v = per.max(0.0) * n as f64;
    let v = if v >= u64::MAX as f64 || v.is_nan() { u64::MAX } else { v as u64 };
    v.max(least)
}

/// A structure a policy did not consider because its bound exceeds the budget.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Exclusion {
    /// The structure.
    pub structure: Structure,
    /// What exceeds the budget: `references` or `bytes`.
    pub what: &'static str,
    /// The bound (or estimate).
    pub needed: u64,
    /// The budget.
    pub budget: u64,
    /// Whether `needed` is exact, an upper bound or an estimate.
    pub bound: Bound,
    /// The sentence for reports.
    pub reason: String,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::generate;

    #[test]
    fn budget_arithmetic() {
        let b = Budget::default();
        assert_eq!(b.references(0), 1 << 22);
        assert_eq!(b.references(1_000_000), 16_000_000);
        assert_eq!(Budget::UNLIMITED.references(u64::MAX), u64::MAX);
        assert_eq!(Budget::BUILDERS.references(1 << 20), 1 << 26);
    }

    #[test]
    fn empty_and_tiny_meshes_bound_to_nothing_or_little() {
        let empty = Mesh::default();
        let b = BuildBounds::of_mesh(&empty).expect("empty mesh");
        assert_eq!((b.grid_references, b.kdtree_references), (0, 0));
        assert!(Budget::default().check(&b).is_empty());
        let one = generate::single_triangle();
        let b = BuildBounds::of_mesh(&one).expect("one triangle");
        // One triangle in a flat grid of 16 x 16 cells: at least one, at most every cell, nothing excluded.
        let cells: u64 = b.grid_resolution.iter().map(|&r| u64::from(r)).product();
        assert_eq!(b.grid_resolution[2], 1, "{b:?}");
        assert!(b.grid_references >= 1 && b.grid_references <= cells, "{b:?}");
        assert!(Budget::default().check(&b).is_empty());
    }

    #[test]
    fn near_copies_are_excluded_and_the_reason_says_why_and_copies_are_not() {
        // 30,000 copies of one triangle: the grid stores the group once, a triangle's cells, and keeps the grid.
        let copies = BuildBounds::of_mesh(&generate::all_equal(30_000)).expect("bounds");
        let cells: u64 = copies.grid_resolution.iter().map(|&r| u64::from(r)).product();
        assert!(copies.grid_references <= cells, "{copies:?}");
        assert!(Budget::default().check(&copies).iter().all(|e| e.structure != Structure::Grid), "{copies:?}");
        // 30,000 near copies (the third vertex moved by 2^-20 each): every one in the cells along its hypotenuse.
        let positions =
            (0..30_000).flat_map(|i| [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0 + i as f32 / 1_048_576.0, 0.0]]);
        let indices = (0..30_000u32).map(|i| [3 * i, 3 * i + 1, 3 * i + 2]).collect();
        let m = Mesh::new("near copies", positions.collect(), indices).expect("mesh");
        let b = BuildBounds::of_mesh(&m).expect("bounds");
        let ex = Budget::default().check(&b);
        assert!(ex.iter().any(|e| e.structure == Structure::Grid && e.what == "references"), "{b:?} {ex:?}");
        assert!(ex[0].reason.contains("exceed the budget"), "{}", ex[0].reason);
        assert!(Budget::UNLIMITED.check(&b).is_empty());
    }
}
