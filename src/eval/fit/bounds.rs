//! The overlap floor's factors ([`CountBounds`]) read off the records: the lower envelope of each structure's
//! measured tests per crossed box.

use super::Sample;
use crate::accel::StructureName;
use crate::cost::{CountBounds, StructureCountBounds, PROBED};

/// `x` rounded down to two significant digits (0 for a number that is not finite and positive).
fn two_digits_down(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return 0.0;
    }
    let scale = 10f64.powi(1 - x.log10().floor() as i32);
    (x * scale).floor() / scale
}

/// The factors of [`CountBounds`] over `samples` (see there for the rules): per structure and kind of ray, the
/// least measured box and triangle tests per crossing of the records that cross at least [`CountBounds::FROM`]
/// boxes, and per image crossing likewise; the kd-tree's triangle tests over the probed hierarchies' fewest.
pub fn fit_count_bounds(samples: &[Sample]) -> CountBounds {
    let mut structures = Vec::new();
    for s in StructureName::ALL {
        let mut per = [[f64::INFINITY; 2]; 3];
        let mut image = [[f64::INFINITY; 2]; 2];
        for smp in samples {
            let (Some(c), Some(m)) = (smp.crossings, smp.get(s).filter(|m| m.valid)) else { continue };
            // The floor bounds the rays that do not leave the scene at once (those test the root box alone): their
            // counts, from samples where some rays stay.
            let leave = c.leave_share.clamp(0.0, 1.0);
            if c.leave_flat_scene || leave > 0.9 {
                continue;
            }
            let k = crate::cost::timed::kind_index(smp.workload.kind);
            // The boxes this structure holds: the distinct triangles' for the BVH, those of non-zero area for the
            // kd-tree, all of them for the others.
            let x = match s {
                StructureName::Bvh => c.distinct,
                StructureName::KdTree => c.nondegenerate,
                _ => c.all,
            };
            let stay = 1.0 - leave;
            let counts = [(m.box_tests_per_ray - leave).max(0.0) / stay, m.prim_tests_per_ray / stay];
            if x >= CountBounds::FROM {
                for j in 0..2 {
                    per[k][j] = per[k][j].min(counts[j] / x);
                }
            }
            if k > 0 && c.image >= CountBounds::FROM && c.all > 0.0 {
                let y = c.image * x / c.all;
                for j in 0..2 {
                    image[k - 1][j] = image[k - 1][j].min(counts[j] / y);
                }
            }
        }
        // The definitions' zeros: no box floor for the kd-tree and the grid, no secondary floor for the grid.
        let finite = |v: f64| if v.is_finite() { two_digits_down(v) } else { 0.0 };
        let mut per = per.map(|r| r.map(finite));
        let mut image = image.map(|r| r.map(finite));
        if matches!(s, StructureName::KdTree | StructureName::Grid) {
            per.iter_mut().for_each(|r| r[0] = 0.0);
            image.iter_mut().for_each(|r| r[0] = 0.0);
        }
        if s == StructureName::Grid {
            per[1..].iter_mut().for_each(|r| *r = [0.0; 2]);
            image = [[0.0; 2]; 2];
        }
        if per.iter().chain(&image).flatten().any(|&v| v > 0.0) {
            structures.push(StructureCountBounds { structure: s, per_crossing: per, per_image_crossing: image });
        }
    }
    // The kd-tree against the probed object hierarchies' fewest triangle tests on the same rays.
    let mut kd = f64::INFINITY;
    for smp in samples {
        let (Some(c), Some(m)) = (smp.crossings, smp.get(StructureName::KdTree).filter(|m| m.valid)) else { continue };
        if c.nondegenerate < c.all {
            continue;
        }
        let fewest = PROBED
            .iter()
            .filter(|&&s| s != StructureName::Grid)
            .filter_map(|&s| c.probe(s))
            .map(|p| p.prim_tests.lower_bound())
            .fold(f64::INFINITY, f64::min);
        if fewest.is_finite() && fewest >= 0.5 {
            kd = kd.min(m.prim_tests_per_ray / fewest);
        }
    }
    CountBounds { structures, kd_tree_prim_floor: if kd.is_finite() { two_digits_down(kd) } else { 0.0 } }
}

#[cfg(test)]
mod tests {
    #[test]
    fn two_significant_digits_round_down() {
        assert_eq!(super::two_digits_down(0.0928), 0.092);
        assert_eq!(super::two_digits_down(0.8333), 0.83);
        assert_eq!(super::two_digits_down(12.99), 12.0);
        assert_eq!(super::two_digits_down(f64::NAN), 0.0);
    }
}
