//! Crossings counted on a camera's image: the boxes a view's primary rays cross ([`screen_crossings`]), the boxes
//! they enter before their first hits ([`near_crossings`]) and the secondary rays from those hits.

use super::*;

/// The mean number of triangle boxes covering a point of `camera`'s square image: per box, the share of the image
/// its screen rectangle covers (the rectangle of its corners' projections, clipped at a near plane a millionth of
/// the boxes' extent in front of the eye and to the image), 1 for a box holding the eye, summed. What a primary ray
/// crosses on average, perspective included: a close camera looking into dense geometry sees far more than the
/// parallel estimate of `Crossings::per_ray` without a view (the engineering family close up: 2,163 against 150).
/// One pass over the boxes, in parallel chunks summed in order (deterministic): 4.9 ms for 200,000 boxes and 24 ms
/// for the dragon's 871,414 on the 2-core VM (two threads, warm; `cargo bench --bench accel -- screen_crossings`,
/// 2026-12-05).
/// Non-finite projections count nothing.
pub fn screen_crossings(boxes: &[Aabb], camera: &Camera) -> f64 {
    use rayon::prelude::*;
    let near = near_plane(&boxes.iter().fold(Aabb::EMPTY, |a, b| a.union(b)));
    let parts: Vec<f64> =
        boxes.par_chunks(4096).map(|c| c.iter().map(|b| screen_share(b, camera, near)).sum::<f64>()).collect();
    parts.iter().sum()
}

/// The share of `camera`'s image covered by the screen rectangle of `b` (see [`screen_crossings`]).
fn screen_share(b: &Aabb, camera: &Camera, near: f32) -> f64 {
    match screen_rect(b, camera, near) {
        Some((lo, hi)) => {
            let size = hi - lo;
            let share = f64::from(size.x) * f64::from(size.y) / 4.0;
            if share.is_finite() {
                share
            } else {
                0.0
            }
        }
        None => 0.0,
    }
}

/// The screen rectangle of `b` on `camera`'s square image, `(lo, hi)` in `[-1, 1]^2` (x to the right, y up): the
/// rectangle of its corners' projections, clipped at the plane `near` in front of the eye and to the image; the
/// whole image for a box holding the eye; `None` when it covers nothing or a projection is not finite.
fn screen_rect(b: &Aabb, camera: &Camera, near: f32) -> Option<(glam::Vec2, glam::Vec2)> {
    if b.min.cmple(camera.eye).all() && b.max.cmpge(camera.eye).all() {
        return Some((-glam::Vec2::ONE, glam::Vec2::ONE));
    }
    let corner = |k: usize| {
        Vec3::new(
            if k & 1 == 0 { b.min.x } else { b.max.x },
            if k & 2 == 0 { b.min.y } else { b.max.y },
            if k & 4 == 0 { b.min.z } else { b.max.z },
        ) - camera.eye
    };
    let (mut lo, mut hi) = (glam::Vec2::splat(f32::INFINITY), glam::Vec2::splat(f32::NEG_INFINITY));
    let mut add = |v: Vec3| {
        let z = v.dot(camera.forward).max(near) * camera.tan_half_fov;
        let p = glam::Vec2::new(v.dot(camera.right) / z, v.dot(camera.up) / z);
        lo = lo.min(p);
        hi = hi.max(p);
    };
    for k in 0..8 {
        let v = corner(k);
        let z = v.dot(camera.forward);
        if z >= near {
            add(v);
        }
        // The edges from this corner towards larger coordinates, cut by the near plane.
        for bit in [1, 2, 4] {
            if k & bit == 0 {
                let u = corner(k | bit);
                let zu = u.dot(camera.forward);
                if (z < near) != (zu < near) {
                    add(v + (u - v) * ((near - z) / (zu - z)));
                }
            }
        }
    }
    let (lo, hi) = (lo.max(-glam::Vec2::ONE), hi.min(glam::Vec2::ONE));
    if lo.is_finite() && hi.is_finite() && lo.cmplt(hi).all() {
        Some((lo, hi))
    } else {
        None
    }
}

/// The near plane [`screen_crossings`] and [`near_crossings`] clip at: a millionth of the extent of `scene` (or of
/// their distance from the origin, if larger) in front of the eye.
fn near_plane(scene: &Aabb) -> f32 {
    let extent = (scene.max - scene.min).max_element().max((scene.max.abs().max(scene.min.abs())).max_element());
    if extent.is_finite() && extent > 0.0 {
        extent * 1e-6
    } else {
        1e-6
    }
}

/// The side of the square sample of primary rays [`near_crossings`] traces at most (1,024 rays).
pub const NEAR_SAMPLES: u32 = 32;

/// The box-ray pairs each of the two passes of [`near_crossings`] over its primary sample examines at most, about:
/// the sample shrinks (to 8 x 8 at least) where the image count times the sample's rays would exceed it. The shadow
/// passes are not bounded by it: each box visits the shadow rays in the bins it covers.
const NEAR_WORK: f64 = 16.0 * 1024.0 * 1024.0;

/// The side of the square sample of primary rays of [`near_crossings`] (and [`crate::cost::probe()`]) for a camera whose
/// image count ([`screen_crossings`]) is `image`: `NEAR_SAMPLES`, less (8 at least) where `image` times the
/// sample's rays would exceed about 16 million box-ray pairs.
pub fn near_sample_side(image: f64) -> u32 {
    let mut side = NEAR_SAMPLES;
    if image.is_finite() && image * f64::from(side * side) > NEAR_WORK {
        side = ((NEAR_WORK / image).sqrt() as u32).clamp(8, NEAR_SAMPLES);
    }
    side
}

/// The mean number of triangle boxes a primary ray of `camera` enters no later than its first hit (or at all, for
/// a ray that hits nothing), over a square sample of its rays: the rays through the pixel centres of a
/// `NEAR_SAMPLES`-square image (fewer where `image`, the count of [`screen_crossings`], times their number would
/// exceed about 16 million box-ray pairs), `boxes[i]` the box of `tris[i]`. Two passes over the triangles, each
/// visiting only the sample rays inside the triangle box's screen rectangle (the rectangle of
/// [`screen_crossings`]): the first finds each ray's closest hit, the second counts the boxes each ray enters no
/// later than it (up to where a closest-hit traversal still visits nodes: `geom::cull_bound` of the hit) and the
/// boxes holding the origin of the secondary ray each hit starts; then the shadow rays from those origins, sorted by
/// direction into the faces of a cube around the light, are tested for occlusion and their crossings counted the
/// same way, in two more passes ([`NearCrossings`]). Each count is kept per ray, as a mean with its standard
/// error ([`SampledMean`]); the floors take the mean less two standard errors (`SampledMean::lower_bound`).
/// Counted only on the triangles' boxes as screen rectangles: a box of no area on the image (seen edge-on) and a
/// box that holds a secondary ray's origin without covering its pixel's centre (within the surface offset of its
/// edge) are missed, which errs on the low side.
///
/// Why it matters: a hierarchy whose every node bounds whole triangles (the binned-SAH BVH, the LBVH, the HLBVH and
/// the BIH) visits, in front-to-back closest-hit traversal, every leaf whose box the ray enters before the closest
/// hit found so far, so it tests at least every triangle whose own box the ray enters before its first hit: this
/// count, per ray, is a lower bound on their triangle tests (`overlap_floor`). The image count of
/// [`screen_crossings`] also counts the boxes behind the first hit, which the traversal never reaches. A kd-tree
/// and a grid store a triangle only in the cells it overlaps, not in every cell its box does, so the bound does not
/// hold for them (long thin triangles across a grid's cells: the engineering family).
///
/// The same argument holds for a diffuse ray (closest hit) and the boxes holding its origin, which it enters at
/// once ([`NearCrossings::holding_origin`]), and for a shadow ray that nothing occludes (an any-hit query that
/// finds nothing visits every node its segment crosses; [`NearCrossings::unoccluded_shadow`]): the four structures'
/// floors for diffuse and shadow rays.
///
/// Deterministic: the closest hits are minima (the lower triangle index on equal distances) and the counts
/// integers. All zero for no triangle.
pub fn near_crossings(boxes: &[Aabb], tris: &[crate::geom::Triangle], camera: &Camera, image: f64) -> NearCrossings {
    use crate::geom::ray::RayInv;
    use rayon::prelude::*;
    let n = boxes.len().min(tris.len());
    if n == 0 {
        return NearCrossings::default();
    }
    let side = near_sample_side(image);
    let s = side as usize;
    let rays: Vec<RayInv> =
        (0..side * side).map(|k| RayInv::new(&camera.ray(k % side, k / side, side, side))).collect();
    let scene = boxes[..n].iter().fold(Aabb::EMPTY, |a, b| a.union(b));
    let near = near_plane(&scene);
    let sf = side as f32;
    // The sample rays whose pixel centres lie in a box's screen rectangle (widened by a thousandth of a sample
    // against the rounding of the projections; the tests below are exact): columns x0..x1, rows y0..y1. Computed
    // once per box, for both passes; most boxes of a large mesh hold no sample centre.
    let at = |p: f32| (p * sf - 0.5 - 1e-3).ceil().max(0.0) as usize;
    let to = |p: f32| ((p * sf - 0.5 + 1e-3).floor() + 1.0).clamp(0.0, sf) as usize;
    let ranges: Vec<Option<[u16; 4]>> = boxes[..n]
        .par_iter()
        .map(|b| {
            let (lo, hi) = screen_rect(b, camera, near)?;
            // Column x has its centre at (x + 0.5) / side * 2 - 1; row y at 1 - (y + 0.5) / side * 2.
            let (cx0, cx1) = (at((lo.x + 1.0) * 0.5), to((hi.x + 1.0) * 0.5));
            let (ry0, ry1) = (at((1.0 - hi.y) * 0.5), to((1.0 - lo.y) * 0.5));
            (cx0 < cx1 && ry0 < ry1).then_some([cx0 as u16, cx1 as u16, ry0 as u16, ry1 as u16])
        })
        .collect();
    const CHUNK: usize = 4096;
    // Per sample ray, its closest hit: distance and triangle (the lower index on equal distances, whatever the
    // chunking).
    let closest = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut d = vec![(f32::INFINITY, u32::MAX); s * s];
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let Some([x0, x1, y0, y1]) = ranges[i] else { continue };
                for y in y0 as usize..y1 as usize {
                    for x in x0 as usize..x1 as usize {
                        let k = y * s + x;
                        let r = &rays[k];
                        if let Some((t, _, _)) = crate::geom::intersect_triangle(&tris[i], r.o, r.d, 0.0, d[k].0) {
                            d[k] = (t, i as u32);
                        }
                    }
                }
            }
            d
        })
        .reduce(
            || vec![(f32::INFINITY, u32::MAX); s * s],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| {
                    if y.0 < x.0 || (y.0 == x.0 && y.1 < x.1) {
                        *x = y;
                    }
                });
                a
            },
        );
    // Counted up to where a traversal still visits nodes once the closest hit is found: the hit's distance enlarged
    // as the slab test enlarges exits, plus the tie margin (`geom::cull_bound`), so that a box the ray enters at
    // its hit point counts whatever the rounding.
    let bound: Vec<f32> = rays
        .iter()
        .zip(&closest)
        .map(|(r, &(t, _))| crate::geom::cull_bound(t, crate::geom::tie_margin(r.o, r.d, &scene)))
        .collect();
    // The origin of the secondary ray each hit starts, as the shadow and diffuse workloads place it.
    let origins: Vec<Option<Vec3>> = rays
        .iter()
        .zip(&closest)
        .map(|(r, &(t, i))| {
            let tri = tris.get(i as usize)?;
            crate::geom::camera::secondary_start(tri, r.o + r.d * t, r.d, &scene).map(|(o, _)| o)
        })
        .collect();
    // Per sample ray: the boxes it enters, and those holding its hit's secondary origin.
    let (entered, holding) = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let (mut entered, mut holding) = (vec![0u32; s * s], vec![0u32; s * s]);
            for i in c * CHUNK..((c + 1) * CHUNK).min(n) {
                let Some([x0, x1, y0, y1]) = ranges[i] else { continue };
                let b = &boxes[i];
                let (lo, hi) = (b.min.to_array(), b.max.to_array());
                for y in y0 as usize..y1 as usize {
                    for x in x0 as usize..x1 as usize {
                        let k = y * s + x;
                        entered[k] += rays[k].slab(&lo, &hi, 0.0, bound[k]).is_some() as u32;
                        if let Some(o) = origins[k] {
                            holding[k] += (b.min.cmple(o).all() && b.max.cmpge(o).all()) as u32;
                        }
                    }
                }
            }
            (entered, holding)
        })
        .reduce(|| (vec![0u32; s * s], vec![0u32; s * s]), |a, b| (add_counts(a.0, &b.0), add_counts(a.1, &b.1)));
    let hits = origins.iter().filter(|o| o.is_some()).count();
    let light = crate::geom::camera::default_light(&scene);
    let unoccluded = shadow_crossings(&boxes[..n], &tris[..n], &origins, light, near);
    let holding: Vec<u32> = holding.iter().zip(&origins).filter(|(_, o)| o.is_some()).map(|(h, _)| *h).collect();
    NearCrossings {
        entered: SampledMean::of(&entered),
        holding_origin: SampledMean::of(&holding),
        hit_share: hits as f64 / (s * s) as f64,
        unoccluded_shadow: SampledMean::of(&unoccluded),
    }
}

/// `a + b`, element by element (saturating).
fn add_counts(mut a: Vec<u32>, b: &[u32]) -> Vec<u32> {
    a.iter_mut().zip(b).for_each(|(x, y)| *x = x.saturating_add(*y));
    a
}

/// A per-ray count averaged over a sample of rays: its mean and the standard error of that mean.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct SampledMean {
    /// The mean over the sample (0 for no ray).
    pub mean: f64,
    /// The standard error of the mean: the sample's standard deviation over the square root of its size (0 for
    /// fewer than two rays).
    pub standard_error: f64,
    /// The rays sampled.
    pub rays: usize,
}

impl SampledMean {
    /// The mean and standard error of `counts`.
    pub fn of(counts: &[u32]) -> SampledMean {
        let n = counts.len();
        if n == 0 {
            return SampledMean::default();
        }
        let mean = counts.iter().map(|&c| f64::from(c)).sum::<f64>() / n as f64;
        let var = if n > 1 {
            counts.iter().map(|&c| (f64::from(c) - mean).powi(2)).sum::<f64>() / (n - 1) as f64
        } else {
            0.0
        };
        SampledMean { mean, standard_error: (var / n as f64).sqrt(), rays: n }
    }

    /// What the floor takes ([`overlap_floor`]): the mean less twice its standard error, at least 0. The count is a
    /// lower bound per ray, but its sampled mean can exceed the mean over a workload's every ray by its sampling
    /// error; two standard errors below it, it does so for about 1 in 40 samples.
    pub(crate) fn lower_bound(&self) -> f64 {
        (self.mean - 2.0 * self.standard_error).max(0.0)
    }

    /// The mean plus twice its standard error: with [`SampledMean::lower_bound`], the band that holds the mean over
    /// every ray of the workload for about 19 samples in 20 ([`overlap_floor`] holds a probed structure's predicted
    /// counts in it, [`crate::cost::probe()`]).
    pub(crate) fn upper_bound(&self) -> f64 {
        (self.mean + 2.0 * self.standard_error).max(self.lower_bound())
    }
}

/// Bins per side of the grid over the rays' span on each face of the cube around the light that
/// [`shadow_crossings`] sorts its rays into.
const SHADOW_BINS: usize = 32;

/// For the shadow rays from `origins` to `light` (as the shadow workload makes them: `tmax` just short of the
/// light), per ray, the boxes it crosses if no triangle occludes it (0 if one does). The rays all meet at the
/// light, so each is sorted by its direction from the light into a bin of one face of a cube around it, and each
/// box visits only the bins its screen rectangle on a face covers (a camera at the light with a 90-degree view per
/// face): first the triangles, to find the occluded rays, then the boxes, to count the crossings of the others.
fn shadow_crossings(
    boxes: &[Aabb],
    tris: &[crate::geom::Triangle],
    origins: &[Option<Vec3>],
    light: Vec3,
    near: f32,
) -> Vec<u32> {
    use crate::geom::ray::RayInv;
    use rayon::prelude::*;
    let axes = [Vec3::X, Vec3::Y, Vec3::Z];
    // Face f looks along +axis (f even) or -axis (f odd) of axis f / 2.
    let faces: Vec<Camera> = (0..6)
        .map(|f| {
            let forward = if f % 2 == 0 { axes[f / 2] } else { -axes[f / 2] };
            let up = if f / 2 == 1 { Vec3::Z } else { Vec3::Y };
            Camera { eye: light, forward, right: forward.cross(up), up, tan_half_fov: 1.0 }
        })
        .collect();
    // Each ray's direction seen from the light: the face of its largest component, and its place there.
    let mut rays: Vec<(RayInv, f32)> = Vec::new();
    let mut placed: Vec<(usize, glam::Vec2)> = Vec::new();
    for o in origins.iter().flatten() {
        let Some(ray) = crate::geom::camera::shadow_ray(*o, light) else { continue };
        let tmax = ray.tmax;
        let u = *o - light;
        let a = (0..3).max_by(|&i, &j| u[i].abs().total_cmp(&u[j].abs())).unwrap_or(0);
        let f = 2 * a + (u[a] < 0.0) as usize;
        let cam = &faces[f];
        let z = u.dot(cam.forward);
        if z.is_nan() || z <= 0.0 {
            continue;
        }
        placed.push((f, glam::Vec2::new(u.dot(cam.right) / z, u.dot(cam.up) / z)));
        rays.push((RayInv::new(&ray), tmax));
    }
    // Per face, a grid of SHADOW_BINS x SHADOW_BINS bins over the rectangle its rays' places span.
    let g = SHADOW_BINS;
    let mut span = [(glam::Vec2::splat(f32::INFINITY), glam::Vec2::splat(f32::NEG_INFINITY)); 6];
    for &(f, p) in &placed {
        span[f] = (span[f].0.min(p), span[f].1.max(p));
    }
    let used: Vec<usize> = (0..6).filter(|&f| span[f].0.x <= span[f].1.x).collect();
    let bin_of = |f: usize, p: glam::Vec2| -> (usize, usize) {
        let (lo, hi) = span[f];
        let cell = |x: f32, l: f32, h: f32| {
            let w = h - l;
            if w > 0.0 {
                (((x - l) / w * g as f32).floor().max(0.0) as usize).min(g - 1)
            } else {
                0
            }
        };
        (cell(p.x, lo.x, hi.x), cell(p.y, lo.y, hi.y))
    };
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); 6 * g * g];
    for (k, &(f, p)) in placed.iter().enumerate() {
        let (x, y) = bin_of(f, p);
        bins[(f * g + y) * g + x].push(k as u32);
    }
    // Per box and used face, the bins its rectangle covers (widened by a hundred-thousandth against the rounding of
    // the projections; the tests are exact), none where it misses the rays' span.
    let cover = |b: &Aabb, f: usize| -> Option<[u8; 4]> {
        let (lo, hi) = screen_rect(b, &faces[f], near)?;
        let (lo, hi) = (lo - glam::Vec2::splat(1e-5), hi + glam::Vec2::splat(1e-5));
        let (slo, shi) = span[f];
        if hi.x < slo.x || hi.y < slo.y || lo.x > shi.x || lo.y > shi.y {
            return None;
        }
        let ((x0, y0), (x1, y1)) = (bin_of(f, lo.max(slo)), bin_of(f, hi.min(shi)));
        // Bins per side fit a byte (SHADOW_BINS <= 255).
        Some([x0 as u8, (x1 + 1) as u8, y0 as u8, (y1 + 1) as u8])
    };
    // Computed once per box and used face, for both passes.
    let covers: Vec<Option<[u8; 4]>> =
        boxes.par_iter().flat_map_iter(|b| used.iter().map(move |&f| cover(b, f))).collect();
    let visit = |i: usize, each: &mut dyn FnMut(usize)| {
        for (j, &f) in used.iter().enumerate() {
            let Some([x0, x1, y0, y1]) = covers[i * used.len() + j] else { continue };
            for y in y0 as usize..y1 as usize {
                for x in x0 as usize..x1 as usize {
                    for &k in &bins[(f * g + y) * g + x] {
                        each(k as usize);
                    }
                }
            }
        }
    };
    const CHUNK: usize = 4096;
    let m = rays.len();
    let n = boxes.len().min(tris.len());
    let occluded = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut o = vec![false; m];
            let (start, end) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            for (i, tri) in (start..end).zip(&tris[start..end]) {
                visit(i, &mut |k| {
                    let (r, tmax) = &rays[k];
                    if !o[k] && crate::geom::intersect_triangle(tri, r.o, r.d, 0.0, *tmax).is_some() {
                        o[k] = true;
                    }
                });
            }
            o
        })
        .reduce(
            || vec![false; m],
            |mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x |= y);
                a
            },
        );
    (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| {
            let mut count = vec![0u32; m];
            let (start, end) = (c * CHUNK, ((c + 1) * CHUNK).min(n));
            for (i, b) in (start..end).zip(&boxes[start..end]) {
                let (lo, hi) = (b.min.to_array(), b.max.to_array());
                visit(i, &mut |k| {
                    let (r, tmax) = &rays[k];
                    count[k] += (!occluded[k] && r.slab(&lo, &hi, 0.0, *tmax).is_some()) as u32;
                });
            }
            count
        })
        .reduce(|| vec![0u32; m], |a, b| add_counts(a, &b))
}

/// What [`near_crossings`] counts on its sample of a camera's primary rays.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct NearCrossings {
    /// The triangle boxes a ray enters no later than its first hit (every box it enters, for a ray that hits
    /// nothing), over the sample rays.
    pub entered: SampledMean,
    /// Over the rays that hit, the triangle boxes holding the origin of the secondary ray the hit starts (off the
    /// surface along the normal facing the ray: `geom::camera::surface_offset`). A diffuse ray enters each such box
    /// at once, so a closest-hit traversal of a hierarchy whose nodes bound whole triangles tests each of their
    /// triangles.
    pub holding_origin: SampledMean,
    /// The share of the sample rays that hit.
    pub hit_share: f64,
    /// Over the shadow rays those hits start (to the shadow workload's light, `geom::camera::default_light`), the
    /// triangle boxes a ray crosses when no triangle occludes it (0 for an occluded ray). An any-hit query that
    /// finds nothing visits every node its segment crosses, so a hierarchy whose nodes bound whole triangles tests
    /// every such triangle.
    pub unoccluded_shadow: SampledMean,
}

/// `sum_a w_a f_a / sum_a w_a s_a`, 0 when the denominator is not positive and finite.
pub(super) fn ratio(f: [f64; 3], s: [f64; 3], w: [f64; 3]) -> f64 {
    let den: f64 = (0..3).map(|a| w[a] * s[a]).sum();
    if den.is_finite() && den > 0.0 {
        (0..3).map(|a| w[a] * f[a]).sum::<f64>() / den
    } else {
        0.0
    }
}
