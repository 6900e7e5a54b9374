//! The seed thesis's selection rules, written down with explicit thresholds.

use super::{empty_share, Policy, Reason, ReasonKind, SceneKind, SceneSummary, Selection, Structure};
use crate::characterize::Characterization;

/// The seed thesis's selection rules (section 3.1.3, Tables 5.1 and 5.2), written down with explicit thresholds.
///
/// The rules, in the order they are tried (the first that decides wins; every rule that fired is in the reasons):
///
/// 1. **Distribution** (3.1.3, "Distribution of primitives"): a uniform distribution favours a grid, the least
///    adaptive structure, which is poor on anything else. Uniform here means, in *every* frame, either the
///    chi-square test accepts uniformity at `alpha` (`chi2 <= critical`), or the effect size is negligible:
///    Cramér's `V <= near_uniform_v`. The second clause exists because at these `n` the test rejects uniformity
///    for almost every real mesh, even for deviations too small to matter. A grid also needs few empty classes
///    (3.1.3, "Empty classes": empty cells are wasted tests): the share of empty classes must be at most
///    `grid_max_empty_share`. Then: **grid**.
///    One exception: `k = 1` because every centroid has the same Morton code (more than two triangles) is a point
///    mass, not a uniform distribution, and falls through to the rules below (the failure study's "all centroids
///    equal" case: a grid puts every triangle in every cell it overlaps and traces about 10x slower than a BVH).
/// 2. **Kind of scene** (3.1.3, "Kind of scenes"; Table 5.2): a dynamic scene (more than one frame) needs a
///    structure that is rebuilt or refit fast rather than the best static one; the thesis selects a BVH for every
///    frame of its animation. Then: **bvh**, with the frame-to-frame change in the reasons.
/// 3. **Architectural interior** (Table 5.1: Sponza, an atrium, gets a kd-tree; the objects get BVHs): geometry
///    spread over the whole bounds, with no empty region of code space, yet not near uniform. The checkable
///    criterion: no empty classes and `near_uniform_v < V <= spread_max_v`. Spatial splits (kd-tree) suit such
///    scenes: the geometry lines the walls of a box, and a kd-tree's planes cut the empty interior away. Then:
///    **kdtree**.
/// 4. **Concentration and empty classes** (3.1.3, "Concentration" and "Empty classes"): otherwise the triangles are
///    concentrated in some classes and/or leave classes empty, which favours an object hierarchy that adapts to the
///    geometry and has no empty nodes. Then: **bvh**.
///
/// **BIH** is never selected: the thesis treats it as a BVH variant (section 2.3.2.1) and its results select a BVH
/// wherever an object hierarchy wins (Tables 5.1 and 5.2), so no characterization outcome of the thesis points to
/// BIH over BVH. LBVH and HLBVH are ways to build a BVH, not separate outcomes of this policy.
///
/// The default thresholds were set on the meshes in `shared/meshes` (30-bit codes, Doane, all triangles; see the
/// field docs): with them the Stanford bunny and dragon, the Happy Buddha and the other scanned objects get a BVH and
/// Dabrovic's Sponza a kd-tree, as Table 5.1 has for the corresponding scenes. The kd-tree band rests on a single
/// example and a narrow margin; treat it as a hypothesis for the evaluation to test, not a finding.
#[derive(Clone, Debug, PartialEq)]
pub struct ThesisPolicy {
    /// Cramér's V at or below which a distribution counts as near uniform (default 0.05: with about 20 classes,
    /// Cohen's `w = V sqrt(k - 1)` is then about 0.2, between Cohen's "small" 0.1 and "medium" 0.3; a uniform
    /// random triangle soup measures about 0.01, the least uniform real meshes here 0.1 to 0.65).
    pub near_uniform_v: f64,
    /// Largest share of empty classes that still allows a grid (default 0).
    pub grid_max_empty_share: f64,
    /// Largest Cramér's V for the spread-out (kd-tree) rule (default 0.085, between Dabrovic's Sponza at 0.077 and
    /// the next lowest mesh here, the rocker arm at 0.094; the Happy Buddha measures 0.105, the bunny 0.114).
    pub spread_max_v: f64,
}

impl Default for ThesisPolicy {
    fn default() -> Self {
        ThesisPolicy { near_uniform_v: 0.05, grid_max_empty_share: 0.0, spread_max_v: 0.085 }
    }
}

fn pct(x: f64) -> String {
    format!("{:.1}%", 100.0 * x)
}

/// The frame that is furthest from uniform (largest V), to quote in reasons.
fn worst_frame(frames: &[Characterization]) -> (usize, &Characterization) {
    let mut best = 0;
    for (i, f) in frames.iter().enumerate() {
        if f.stats.cramers_v > frames[best].stats.cramers_v {
            best = i;
        }
    }
    (best, &frames[best])
}

impl ThesisPolicy {
    fn frame_label(scene: &SceneSummary<'_>, i: usize) -> String {
        if scene.frames.len() > 1 {
            format!("frame {i}: ")
        } else {
            String::new()
        }
    }

    /// Whether a frame's distribution counts as uniform, and why in words.
    fn uniformity(&self, c: &Characterization) -> (bool, String) {
        let s = &c.stats;
        if s.dof == 0 && c.triangles > 2 && c.code_stats.code_min == c.code_stats.code_max {
            return (
                false,
                format!(
                    "k = 1 class because all {} centroids share one Morton code: a point mass, the most concentrated \
                     distribution there is, not a uniform one",
                    c.triangles
                ),
            );
        }
        if s.dof == 0 {
            return (
                true,
                format!("k = 1 class (n = {}): nothing to test, the distribution is trivially uniform", c.triangles),
            );
        }
        if s.uniform {
            (
                true,
                format!(
                    "chi-square {:.4} <= critical value {:.4} (dof {}, alpha {}): uniformity is not rejected \
                     (p = {:.3e}); Cramér's V = {:.4}",
                    s.chi_square, s.critical_value, s.dof, c.params.alpha, s.p_value, s.cramers_v
                ),
            )
        } else if s.cramers_v <= self.near_uniform_v {
            (
                true,
                format!(
                    "chi-square {:.4} > critical value {:.4} (dof {}, alpha {}, p = {:.3e}) rejects uniformity, but \
                     Cramér's V = {:.4} <= {} (negligible effect at n = {}): near uniform",
                    s.chi_square,
                    s.critical_value,
                    s.dof,
                    c.params.alpha,
                    s.p_value,
                    s.cramers_v,
                    self.near_uniform_v,
                    c.triangles
                ),
            )
        } else {
            (
                false,
                format!(
                    "chi-square {:.4} > critical value {:.4} (dof {}, alpha {}, p = {:.3e}) and Cramér's V = {:.4} > \
                     {}: not uniform",
                    s.chi_square, s.critical_value, s.dof, c.params.alpha, s.p_value, s.cramers_v, self.near_uniform_v
                ),
            )
        }
    }

    fn concentration(c: &Characterization) -> String {
        let s = &c.stats;
        format!(
            "{} of {} classes are concentrated (above the mean count {:.1}) and hold {} of the triangles; {} empty \
             class{} ({})",
            s.concentrated_classes,
            c.classes,
            c.triangles as f64 / c.classes.max(1) as f64,
            pct(s.concentrated_share),
            s.empty_classes,
            if s.empty_classes == 1 { "" } else { "es" },
            pct(empty_share(c))
        )
    }
}

/// The thesis policy's lines, each a rule that fired or fell through.
fn rules(lines: Vec<String>) -> Vec<Reason> {
    lines.into_iter().map(|l| Reason::new(ReasonKind::Rule, l)).collect()
}

impl Policy for ThesisPolicy {
    fn name(&self) -> &str {
        "thesis"
    }

    fn select(&self, scene: &SceneSummary<'_>) -> Selection {
        // The thesis's rules price no build: a grid past the count threshold is excluded whatever its count.
        let excluded = scene.exclusions_unpriced();
        let mut sel = self.rules(scene, &excluded);
        for e in &excluded {
            if !sel.reasons.iter().any(|r| r.text.contains(&e.reason)) {
                sel.reasons.push(Reason::new(ReasonKind::Excluded, format!("excluded before choosing: {}", e.reason)));
            }
        }
        sel.excluded = excluded;
        sel
    }
}

impl ThesisPolicy {
    /// The rules of the type's docs, skipping the structures in `excluded` (a rule that points to one falls
    /// through to the next, and says so).
    fn rules(&self, scene: &SceneSummary<'_>, excluded: &[super::Exclusion]) -> Selection {
        let out = |s: Structure| excluded.iter().find(|e| e.structure == s);
        let mut reasons = Vec::new();
        if scene.frames.is_empty() {
            reasons.push("no characterized frame: default to a BVH, which suits any geometry".to_string());
            return Selection::new(Structure::Bvh, rules(reasons));
        }

        // Rule 1: distribution (and empty classes) -> grid.
        let mut all_uniform = true;
        let mut grid_ok = true;
        let mut uniform_reasons = Vec::new();
        for (i, c) in scene.frames.iter().enumerate() {
            let (u, why) = self.uniformity(c);
            if !u {
                all_uniform = false;
                // Quote the first non-uniform frame only.
                reasons.push(format!("distribution: {}{why}", Self::frame_label(scene, i)));
                break;
            }
            if empty_share(c) > self.grid_max_empty_share {
                grid_ok = false;
                reasons.push(format!(
                    "distribution: {}{why}; but {} of {} classes are empty ({} > {}): a grid would waste cells",
                    Self::frame_label(scene, i),
                    c.stats.empty_classes,
                    c.classes,
                    pct(empty_share(c)),
                    pct(self.grid_max_empty_share)
                ));
                break;
            }
            uniform_reasons.push(format!("distribution: {}{why}", Self::frame_label(scene, i)));
        }
        let grid_out = out(Structure::Grid).filter(|_| all_uniform && grid_ok);
        if let Some(e) = grid_out {
            reasons.extend(uniform_reasons.drain(..).take(1));
            reasons.push(format!("the distribution points to a grid, but it is excluded: {}", e.reason));
        }
        if all_uniform && grid_ok && grid_out.is_none() {
            if scene.frames.len() > 3 {
                let n = uniform_reasons.len();
                uniform_reasons.truncate(1);
                uniform_reasons.push(format!("(and likewise in all {n} frames)"));
            }
            reasons.extend(uniform_reasons);
            reasons.push(format!(
                "uniform distribution with at most {} empty classes: a grid, the cheapest structure to build and \
                 traverse on uniform geometry (thesis 3.1.3)",
                pct(self.grid_max_empty_share)
            ));
            if scene.kind == SceneKind::Dynamic {
                reasons.push(format!(
                    "dynamic scene of {} frames: a grid is also rebuilt in a single O(n) pass per frame",
                    scene.frames.len()
                ));
            }
            return Selection::new(Structure::Grid, rules(reasons));
        }

        let (wi, worst) = worst_frame(scene.frames);

        // Rule 2: kind of scene -> BVH for animations.
        if scene.kind == SceneKind::Dynamic {
            let ch = scene.change.as_ref();
            reasons.push(format!(
                "dynamic scene: {} frames; largest frame-to-frame change of the bounds diagonal {}, of Cramér's V \
                 {:.4}, of the empty-class share {}",
                scene.frames.len(),
                pct(ch.map_or(0.0, |c| c.max_diagonal_change)),
                ch.map_or(0.0, |c| c.max_effect_size_change),
                pct(ch.map_or(0.0, |c| c.max_empty_share_change))
            ));
            reasons.push(format!("concentration: {}{}", Self::frame_label(scene, wi), Self::concentration(worst)));
            reasons.push(
                "the structure must be rebuilt or refit every frame: a BVH, as the thesis selects for every frame of \
                 its animated scene (Table 5.2)"
                    .to_string(),
            );
            return Selection::new(Structure::Bvh, rules(reasons));
        }

        // Static from here on: a single frame.
        let c = &scene.frames[0];
        let s = &c.stats;
        reasons.push(format!("concentration: {}", Self::concentration(c)));

        // Rule 3: spread-out architectural geometry -> kd-tree.
        let spread = s.empty_classes == 0 && s.cramers_v > self.near_uniform_v && s.cramers_v <= self.spread_max_v;
        if let Some(e) = out(Structure::KdTree).filter(|_| spread) {
            reasons.push(format!(
                "spread out (no empty class, Cramér's V = {:.4}): the rule points to a kd-tree, but it is excluded: {}",
                s.cramers_v, e.reason
            ));
        } else if spread {
            reasons.push(format!(
                "spread out: no empty class and Cramér's V = {:.4} in ({}, {}] (bounds aspect {:.2}): geometry \
                 lines the whole bounds like an architectural interior, which spatial splits cut well: a kd-tree \
                 (Sponza in thesis Table 5.1)",
                s.cramers_v,
                self.near_uniform_v,
                self.spread_max_v,
                scene.aspect()
            ));
            return Selection::new(Structure::KdTree, rules(reasons));
        }

        // Rule 4: concentration / empty classes -> BVH.
        let mut why = Vec::new();
        if s.empty_classes > 0 {
            why.push(format!("{} empty class{}", s.empty_classes, if s.empty_classes == 1 { "" } else { "es" }));
        }
        if s.cramers_v > self.spread_max_v {
            why.push(format!("Cramér's V = {:.4} > {}", s.cramers_v, self.spread_max_v));
        }
        if s.dof == 0 && c.code_stats.code_min == c.code_stats.code_max {
            why.push(format!("all {} centroids share one Morton code", c.triangles));
        }
        if why.is_empty() {
            why.push(format!("Cramér's V = {:.4}, no rule above applies", s.cramers_v));
        }
        reasons.push(format!(
            "non-uniform and concentrated ({}): an object hierarchy adapts to concentrated geometry and has no empty \
             nodes: a BVH (thesis 3.1.3; Table 5.1 selects a BVH for its scanned objects)",
            why.join(", ")
        ));
        Selection::new(Structure::Bvh, rules(reasons))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::characterize::{histogram_stats, CodeStats, Moments, Params};
    use num_bigint::BigUint;

    /// A characterization whose histogram is `hist`; the statistics come from the real `histogram_stats`.
    fn fake(hist: &[u64], lo: [f32; 3], hi: [f32; 3]) -> Characterization {
        let n: u64 = hist.iter().sum();
        let params = Params::default();
        Characterization {
            total_triangles: n,
            triangles: n,
            lo,
            hi,
            code_stats: CodeStats {
                n,
                code_min: 0,
                code_max: 1 << 29,
                s1: BigUint::default(),
                s2: BigUint::default(),
                s3: BigUint::default(),
            },
            moments: Moments { mean: 0.0, std_dev: 1.0, skewness: 0.0 },
            classes: hist.len() as u32,
            histogram: hist.to_vec(),
            stats: histogram_stats(hist, n, params.alpha),
            params,
            per_triangle: None,
            timings: Vec::new(),
            backend: "test".into(),
            device: "test".into(),
        }
    }

    fn unit(hist: &[u64]) -> Characterization {
        fake(hist, [0.0; 3], [3.0; 3])
    }

    /// `k = 10`, `n = 10000`, counts alternating `1000 + d`, `1000 - d`: chi2 = d^2 / 100, V = d / 3000.
    fn alternating(d: u64) -> Vec<u64> {
        (0..10).map(|i| if i % 2 == 0 { 1000 + d } else { 1000 - d }).collect()
    }

    fn select(frames: &[Characterization]) -> Selection {
        ThesisPolicy::default().select(&SceneSummary::new("scene", frames))
    }

    fn mentions(sel: &Selection, text: &str) -> bool {
        sel.reasons.iter().any(|r| r.text.contains(text))
    }

    #[test]
    fn exactly_uniform_selects_grid() {
        let c = unit(&[100; 10]);
        assert!(c.stats.uniform);
        let sel = select(std::slice::from_ref(&c));
        assert_eq!(sel.structure, Structure::Grid);
        assert!(mentions(&sel, "uniformity is not rejected"), "{:?}", sel.reasons);
        assert!(mentions(&sel, &format!("critical value {:.4}", c.stats.critical_value)));
    }

    #[test]
    fn negligible_effect_selects_grid_despite_the_test() {
        // n = 1,000,000 in 10 classes, +-1%: the test rejects, V = 0.01.
        let hist: Vec<u64> = (0..10).map(|i| if i % 2 == 0 { 101_000 } else { 99_000 }).collect();
        let c = unit(&hist);
        assert!(!c.stats.uniform);
        assert!(c.stats.cramers_v < 0.05);
        let sel = select(std::slice::from_ref(&c));
        assert_eq!(sel.structure, Structure::Grid);
        assert!(mentions(&sel, "rejects uniformity, but"), "{:?}", sel.reasons);
        assert!(mentions(&sel, &format!("Cramér's V = {:.4}", c.stats.cramers_v)));
    }

    #[test]
    fn empty_class_rules_out_the_grid() {
        // 399 equal classes and one empty one: V = 1/399, near uniform, but a class is empty.
        let mut hist = vec![1000u64; 400];
        hist[123] = 0;
        let c = unit(&hist);
        assert!(c.stats.cramers_v <= 0.05);
        let sel = select(std::slice::from_ref(&c));
        assert_eq!(sel.structure, Structure::Bvh);
        assert!(mentions(&sel, "a grid would waste cells"), "{:?}", sel.reasons);
        assert!(mentions(&sel, "1 empty class"), "{:?}", sel.reasons);
    }

    #[test]
    fn spread_out_scene_selects_kdtree() {
        let c = unit(&alternating(210));
        assert!((c.stats.cramers_v - 0.07).abs() < 1e-12);
        let sel = select(std::slice::from_ref(&c));
        assert_eq!(sel.structure, Structure::KdTree, "{:?}", sel.reasons);
        assert!(mentions(&sel, "Cramér's V = 0.0700 in (0.05, 0.085]"), "{:?}", sel.reasons);
    }

    #[test]
    fn concentrated_scene_selects_bvh() {
        let c = unit(&alternating(600));
        assert!((c.stats.cramers_v - 0.2).abs() < 1e-12);
        let sel = select(std::slice::from_ref(&c));
        assert_eq!(sel.structure, Structure::Bvh);
        assert!(mentions(&sel, "Cramér's V = 0.2000 > 0.085"), "{:?}", sel.reasons);
        assert!(mentions(&sel, "5 of 10 classes are concentrated"), "{:?}", sel.reasons);
        assert!(mentions(&sel, "hold 80.0% of the triangles"), "{:?}", sel.reasons);
    }

    #[test]
    fn animation_selects_bvh_with_change() {
        let f0 = fake(&alternating(300), [0.0; 3], [3.0, 3.0, 3.0]);
        let f1 = fake(&alternating(600), [0.0; 3], [6.0, 6.0, 6.0]);
        let frames = [f0, f1];
        let scene = SceneSummary::new("anim", &frames);
        assert_eq!(scene.kind, SceneKind::Dynamic);
        let ch = scene.change.expect("two frames have a change");
        assert!((ch.max_diagonal_change - 0.5).abs() < 1e-12);
        assert!((ch.max_effect_size_change - 0.1).abs() < 1e-12);
        let sel = ThesisPolicy::default().select(&scene);
        assert_eq!(sel.structure, Structure::Bvh);
        assert!(mentions(&sel, "dynamic scene: 2 frames"), "{:?}", sel.reasons);
        assert!(mentions(&sel, "bounds diagonal 50.0%"), "{:?}", sel.reasons);
        assert!(mentions(&sel, "Table 5.2"), "{:?}", sel.reasons);
        // A spread-out animation is still a BVH: the kd-tree rule is for static scenes.
        let frames = [unit(&alternating(210)), unit(&alternating(210))];
        assert_eq!(select(&frames).structure, Structure::Bvh);
    }

    #[test]
    fn uniform_animation_selects_grid() {
        let frames = [unit(&[100; 10]), unit(&[50; 20]), unit(&[100; 10]), unit(&[100; 10])];
        let sel = select(&frames);
        assert_eq!(sel.structure, Structure::Grid);
        assert!(mentions(&sel, "single O(n) pass per frame"), "{:?}", sel.reasons);
        assert!(mentions(&sel, "all 4 frames"), "{:?}", sel.reasons);
        // One non-uniform frame is enough to leave the grid.
        let frames = [unit(&[100; 10]), unit(&alternating(600))];
        let sel = select(&frames);
        assert_eq!(sel.structure, Structure::Bvh);
        assert!(mentions(&sel, "frame 1: chi-square"), "{:?}", sel.reasons);
    }

    #[test]
    fn single_class_and_no_frames() {
        let sel = select(&[unit(&[5])]);
        assert_eq!(sel.structure, Structure::Grid);
        assert!(mentions(&sel, "k = 1 class"));
        let sel = select(&[]);
        assert_eq!(sel.structure, Structure::Bvh);
        assert!(!sel.reasons.is_empty());
    }

    #[test]
    fn names_round_trip() {
        for s in Structure::ALL {
            assert_eq!(Structure::from_name(s.name()), Some(s));
            assert_eq!(serde_json::to_string(&s).ok(), Some(format!("\"{}\"", s.name())));
        }
        assert_eq!(serde_json::to_string(&SceneKind::Dynamic).ok().as_deref(), Some("\"dynamic\""));
    }

    #[test]
    fn aspect_of_bounds() {
        let frames = [fake(&[1], [0.0, 0.0, 0.0], [4.0, 2.0, 1.0])];
        assert_eq!(SceneSummary::new("a", &frames).aspect(), 4.0);
        let flat = [fake(&[1], [0.0; 3], [4.0, 2.0, 0.0])];
        assert_eq!(SceneSummary::new("a", &flat).aspect(), f64::INFINITY);
    }
}
