//! Synthetic scenes for tests, benchmarks and the failure study.
//!
//! Scenes of a family (interiors, cities, vegetation, terrains, particle soups, engineering models, teapots in a
//! stadium) at a requested triangle count are [`generate`]d by [`super::families`], re-exported here.
//!
//! Every generator is deterministic: the same arguments (and seed) give the same mesh, bit for bit, on every machine
//! (a SplitMix64 generator drives them and all arithmetic is plain IEEE f64 rounded once to f32). Every mesh they
//! return has finite coordinates and indices in range. Generators that build a triangle soup give every triangle its
//! own three vertices.
//!
//! Generators that take a triangle count panic when the count exceeds [`MAX_SOUP_TRIANGLES`] (the vertices would not
//! be addressable by `u32` indices); transformations of an existing mesh return a [`MeshError`] instead, since their
//! input may come from a file.

use super::{Animation, Mesh, MeshError};
use crate::rng::SplitMix64;

pub use super::families::{generate, Family, MAX_FAMILY_TRIANGLES};
use std::collections::HashMap;

/// Largest triangle count a soup generator accepts: its `3 n` vertices must be addressable by `u32` indices.
pub const MAX_SOUP_TRIANGLES: usize = (u32::MAX / 3) as usize;

/// The crate's SplitMix64, with the vector helpers the generators use.
struct Rng(SplitMix64);

impl Rng {
    fn new(seed: u64) -> Self {
        Rng(SplitMix64::new(seed))
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        self.0.range(lo, hi)
    }

    fn gaussian(&mut self) -> f64 {
        self.0.gaussian()
    }

    fn point(&mut self, lo: f64, hi: f64) -> [f64; 3] {
        [self.range(lo, hi), self.range(lo, hi), self.range(lo, hi)]
    }

    /// A uniformly distributed unit vector.
    fn direction(&mut self) -> [f64; 3] {
        loop {
            let v = [self.gaussian(), self.gaussian(), self.gaussian()];
            let len = dot(v, v).sqrt();
            if len > 1e-6 {
                return v.map(|c| c / len);
            }
        }
    }
}

fn add(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    a.map(|c| c * s)
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

fn to_f32(p: [f64; 3]) -> [f32; 3] {
    p.map(|c| c as f32)
}

fn to_f64(p: [f32; 3]) -> [f64; 3] {
    p.map(f64::from)
}

fn check_count(n: usize) {
    assert!(n <= MAX_SOUP_TRIANGLES, "{n} triangles: more than MAX_SOUP_TRIANGLES ({MAX_SOUP_TRIANGLES})");
}

/// Builds a soup mesh from triangles whose coordinates the caller guarantees finite.
fn soup(name: String, tris: impl IntoIterator<Item = [[f32; 3]; 3]>) -> Mesh {
    let mut positions = Vec::new();
    let mut indices = Vec::new();
    for t in tris {
        // Callers check the count against MAX_SOUP_TRIANGLES, so the base fits u32.
        let base = positions.len() as u32;
        positions.extend_from_slice(&t);
        indices.push([base, base + 1, base + 2]);
    }
    Mesh { name, positions, indices, object_ids: None }
}

/// A small triangle around `center`: each vertex is `center + size * u` with `u` uniform in `[-1, 1)^3`.
fn small_triangle(rng: &mut Rng, center: [f64; 3], size: f64) -> [[f64; 3]; 3] {
    let mut corner = || add(center, scale(rng.point(-1.0, 1.0), size));
    [corner(), corner(), corner()]
}

/// `n` small random triangles in the unit cube.
///
/// Each triangle's centre is uniform in `[0.01, 0.99]^3`; its vertices lie within `size` of the centre on every axis,
/// with `size` uniform in `[0.002, 0.01)`. Every vertex lies in `[0, 1]^3`.
///
/// # Panics
///
/// If `n > MAX_SOUP_TRIANGLES`.
pub fn random_soup(n: usize, seed: u64) -> Mesh {
    check_count(n);
    let mut rng = Rng::new(seed);
    let tris: Vec<[[f32; 3]; 3]> = (0..n)
        .map(|_| {
            let c = rng.point(0.01, 0.99);
            let s = rng.range(0.002, 0.01);
            small_triangle(&mut rng, c, s).map(|v| to_f32(v.map(|x| x.clamp(0.0, 1.0))))
        })
        .collect();
    soup(format!("random_soup(n={n}, seed={seed})"), tris)
}

/// `n` small triangles in `clusters` gaussian blobs (`clusters = 0` counts as 1).
///
/// Blob centres are uniform in `[0.1, 0.9]^3`; triangle `i` belongs to blob `i mod clusters` (so blobs hold equal
/// shares, within one), and its centre is the blob centre plus a gaussian offset of standard deviation 0.03 on every
/// axis. Triangles are small (vertices within 0.004 of their centre). Most of the mesh lies in the unit cube, but the
/// gaussian tails are not clipped.
///
/// # Panics
///
/// If `n > MAX_SOUP_TRIANGLES`.
pub fn clustered(n: usize, clusters: usize, seed: u64) -> Mesh {
    check_count(n);
    let k = clusters.max(1);
    let mut rng = Rng::new(seed);
    let centers: Vec<[f64; 3]> = (0..k).map(|_| rng.point(0.1, 0.9)).collect();
    let sigma = 0.03;
    let tris: Vec<[[f32; 3]; 3]> = centers
        .iter()
        .cycle()
        .take(n)
        .map(|&blob| {
            let c = add(blob, [rng.gaussian() * sigma, rng.gaussian() * sigma, rng.gaussian() * sigma]);
            let s = rng.range(0.001, 0.004);
            small_triangle(&mut rng, c, s).map(to_f32)
        })
        .collect();
    soup(format!("clustered(n={n}, clusters={k}, seed={seed})"), tris)
}

/// `n` small random triangles in the plane `z = 0`: like [`random_soup`] in `x` and `y`, and every vertex has
/// `z = 0.0` exactly (positive zero), so the scene has zero extent along z.
///
/// # Panics
///
/// If `n > MAX_SOUP_TRIANGLES`.
pub fn flat(n: usize, seed: u64) -> Mesh {
    check_count(n);
    let mut rng = Rng::new(seed);
    let tris: Vec<[[f32; 3]; 3]> = (0..n)
        .map(|_| {
            let c = [rng.range(0.01, 0.99), rng.range(0.01, 0.99), 0.0];
            let s = rng.range(0.002, 0.01);
            small_triangle(&mut rng, c, s).map(|v| [v[0].clamp(0.0, 1.0) as f32, v[1].clamp(0.0, 1.0) as f32, 0.0])
        })
        .collect();
    soup(format!("flat(n={n}, seed={seed})"), tris)
}

const UNIT_TRIANGLE: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

/// `n` copies of the triangle `(0,0,0), (1,0,0), (0,1,0)`, each with its own three vertices: every centroid is the
/// same point.
///
/// # Panics
///
/// If `n > MAX_SOUP_TRIANGLES`.
pub fn all_equal(n: usize) -> Mesh {
    check_count(n);
    soup(format!("all_equal(n={n})"), std::iter::repeat_n(UNIT_TRIANGLE, n))
}

/// One triangle: `(0,0,0), (1,0,0), (0,1,0)`.
pub fn single_triangle() -> Mesh {
    soup("single_triangle".into(), [UNIT_TRIANGLE])
}

/// Two triangles: `(0,0,0), (1,0,0), (0,1,0)` and the same shape moved by `(1,1,1)`, so the scene has extent 2 along
/// x and y and 1 along z.
pub fn two_triangles() -> Mesh {
    let moved = UNIT_TRIANGLE.map(|v| v.map(|c| c + 1.0));
    soup("two_triangles".into(), [UNIT_TRIANGLE, moved])
}

/// The mesh with every coordinate multiplied by `factor` (in f64, rounded once to f32): for huge (`1e30`) and tiny
/// (`1e-30`) scenes. Topology and object ids are kept.
///
/// Fails with [`MeshError::NonFinite`] when a product leaves the f32 range (or `factor` is not finite).
pub fn scaled(mesh: &Mesh, factor: f64) -> Result<Mesh, MeshError> {
    let out = Mesh {
        name: format!("{} scaled by {factor:e}", mesh.name),
        positions: mesh.positions.iter().map(|&p| to_f32(scale(to_f64(p), factor))).collect(),
        indices: mesh.indices.clone(),
        object_ids: mesh.object_ids.clone(),
    };
    out.validate()?;
    Ok(out)
}

/// `n` triangles whose centroids lie on the x axis: triangle `i` lies in the plane `x = i / (n - 1)` and its three
/// vertices are placed so that the centroid key of every triangle (`(v0 + v1) + v2`) has `y = 0` and `z = 0`
/// exactly. The triangles themselves are not degenerate (about 0.01 across).
///
/// # Panics
///
/// If `n > MAX_SOUP_TRIANGLES`.
pub fn collinear_centroids(n: usize) -> Mesh {
    check_count(n);
    let d = 0.01f32;
    let h = d * 0.5; // exact: d - h - h == 0
    let a = 0.008_66f32;
    let denom = n.saturating_sub(1).max(1) as f64;
    let tris = (0..n).map(|i| {
        let x = (i as f64 / denom) as f32;
        [[x, d, 0.0], [x, -h, a], [x, -h, -a]]
    });
    soup(format!("collinear_centroids(n={n})"), tris)
}

/// The mesh repeated `copies` times (identical positions): vertices and triangles are appended copy after copy, and
/// object ids (if any) repeat with them. `copies = 0` gives an empty mesh.
///
/// Fails with [`MeshError::Invalid`] when the copies need more vertices than `u32` indices address.
pub fn duplicated(mesh: &Mesh, copies: usize) -> Result<Mesh, MeshError> {
    let nv = mesh.positions.len();
    let total = nv.checked_mul(copies).filter(|&t| t <= u32::MAX as usize + 1);
    if total.is_none() {
        return Err(MeshError::Invalid {
            file: mesh.name.clone(),
            reason: format!("{copies} copies of {nv} vertices exceed 32-bit indices"),
        });
    }
    let mut positions = Vec::with_capacity(nv * copies);
    let mut indices = Vec::with_capacity(mesh.indices.len().saturating_mul(copies));
    for c in 0..copies {
        // c * nv < total <= 2^32, so it fits u32 for every copy that has a vertex.
        let base = (c * nv) as u32;
        positions.extend_from_slice(&mesh.positions);
        indices.extend(mesh.indices.iter().map(|t| t.map(|i| base.wrapping_add(i))));
    }
    let out = Mesh {
        name: format!("{} x{copies}", mesh.name),
        positions,
        indices,
        object_ids: mesh.object_ids.as_ref().map(|ids| ids.repeat(copies)),
    };
    out.validate()?;
    Ok(out)
}

/// A small dense object inside a huge sparse box: the embedded Utah teapot ([`super::default_teapot`], 992
/// triangles), centred and scaled to a bounding-box diagonal of 1 unit and moved to a random point of `[-100, 100]^3`,
/// inside the 12 triangles of the surface of the cube `[-10^4, 10^4]^3`.
///
/// Object 0 is the teapot (triangles `0..992`), object 1 the box (the last 12 triangles).
pub fn teapot_in_stadium(seed: u64) -> Mesh {
    let teapot = super::default_teapot();
    let (lo, hi) = bounds(&teapot.positions);
    let center = scale(add(lo, hi), 0.5);
    let diag = dot(sub(hi, lo), sub(hi, lo)).sqrt();
    let s = if diag > 0.0 { 1.0 / diag } else { 1.0 };
    let mut rng = Rng::new(seed);
    let offset = rng.point(-100.0, 100.0);
    let mut positions: Vec<[f32; 3]> =
        teapot.positions.iter().map(|&p| to_f32(add(scale(sub(to_f64(p), center), s), offset))).collect();
    let mut indices = teapot.indices.clone();
    let mut object_ids = vec![0u32; indices.len()];
    let r = 1.0e4f32;
    let base = positions.len() as u32;
    for i in 0..8u32 {
        let corner = |bit: u32| if i & bit != 0 { r } else { -r };
        positions.push([corner(1), corner(2), corner(4)]);
    }
    // Corner k has x set by bit 0, y by bit 1, z by bit 2; two triangles per face.
    const FACES: [[u32; 4]; 6] = [[0, 2, 6, 4], [1, 5, 7, 3], [0, 4, 5, 1], [2, 3, 7, 6], [0, 1, 3, 2], [4, 6, 7, 5]];
    for [a, b, c, d] in FACES {
        indices.push([base + a, base + b, base + c]);
        indices.push([base + a, base + c, base + d]);
        object_ids.extend([1, 1]);
    }
    Mesh { name: format!("teapot_in_stadium(seed={seed})"), positions, indices, object_ids: Some(object_ids) }
}

/// One sliver across the scene plus some normal geometry: triangle 0 runs from `(0,0,0)` to `(1,1,1)` along the
/// diagonal of the unit cube and is `1e-4` wide; it is followed by the 1,000 triangles of
/// `random_soup(1000, 0x5eed)` (`long_thin(1001, 0x5eed)`).
pub fn long_thin_triangle() -> Mesh {
    Mesh { name: "long_thin_triangle".into(), ..long_thin(1001, 0x5eed) }
}

/// [`long_thin_triangle`] with `n` triangles in all: the sliver followed by `random_soup(n - 1, seed)` (an empty
/// mesh for `n = 0`).
///
/// # Panics
///
/// If `n > MAX_SOUP_TRIANGLES`.
pub fn long_thin(n: usize, seed: u64) -> Mesh {
    check_count(n);
    let sliver = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [1.0001, 1.0, 1.0]];
    let rest = random_soup(n.saturating_sub(1), seed);
    let tris = std::iter::once(sliver)
        .take(n.min(1))
        .chain((0..rest.triangle_count()).map(|i| rest.triangle(i).map(|v| v.to_array())));
    soup(format!("long_thin(n={n}, seed={seed})"), tris)
}

/// `n` large overlapping triangles: every vertex is uniform in the unit cube, so a typical triangle spans a good part
/// of the scene and crosses many others.
///
/// # Panics
///
/// If `n > MAX_SOUP_TRIANGLES`.
pub fn overlapping_large(n: usize, seed: u64) -> Mesh {
    check_count(n);
    let mut rng = Rng::new(seed);
    let tris: Vec<[[f32; 3]; 3]> =
        (0..n).map(|_| [rng.point(0.0, 1.0), rng.point(0.0, 1.0), rng.point(0.0, 1.0)].map(to_f32)).collect();
    soup(format!("overlapping_large(n={n}, seed={seed})"), tris)
}

/// `n` triangles of exactly zero area, of three kinds in turn (triangle `i` is of kind `i mod 3`): all three
/// vertices equal; two vertices equal; three distinct vertices on a line parallel to a coordinate axis. All lie in
/// the unit cube, and [`Mesh::zero_area_count`] is `n`.
///
/// # Panics
///
/// If `n > MAX_SOUP_TRIANGLES`.
pub fn zero_area(n: usize, seed: u64) -> Mesh {
    check_count(n);
    let mut rng = Rng::new(seed);
    let tris: Vec<[[f32; 3]; 3]> = (0..n)
        .map(|i| {
            let p = to_f32(rng.point(0.1, 0.9));
            match i % 3 {
                0 => [p, p, p],
                1 => [p, p, to_f32(rng.point(0.1, 0.9))],
                _ => {
                    let axis = (rng.0.next_u64() % 3) as usize;
                    let mut q = p;
                    let mut r = p;
                    q[axis] = rng.range(0.0, 0.1) as f32;
                    r[axis] = rng.range(0.9, 1.0) as f32;
                    [p, q, r]
                }
            }
        })
        .collect();
    soup(format!("zero_area(n={n}, seed={seed})"), tris)
}

/// The `n` triangles that the loaders' fan rule makes of one polygon whose `n + 2` corners cycle over the three
/// points `p0 = (0,0,0)`, `p1 = (1,0,0)`, `p2 = (0,1,0)`: triangle `i - 1` is `(p0, p[i mod 3], p[(i + 1) mod 3])` for
/// `i` in `1 ..= n`, over three shared vertices. Triangles `0, 3, 6, ...` are the unit triangle; the others have
/// two equal corners (zero area: the legs `p0 p2` and `p0 p1`). So `ceil(n / 3)` coincident copies of one triangle
/// with zero-area segments on two sides of its box, the degenerate case of a polygon face written by a careless
/// exporter (an OBJ face `f 1 2 3 1 2 3 ...` loads to exactly this).
///
/// # Panics
///
/// If `n > MAX_SOUP_TRIANGLES` (the same limit as the soups, for one rule).
pub fn fan_polygon(n: usize) -> Mesh {
    check_count(n);
    let positions = UNIT_TRIANGLE.to_vec();
    let indices = (1..=n as u32).map(|i| [0, i % 3, (i + 1) % 3]).collect();
    Mesh { name: format!("fan_polygon(n={n})"), positions, indices, object_ids: None }
}

/// A flat lattice with zero-area triangles along its diagonal: `k x k` squares of side `1 / k` in the plane `z = 0`,
/// each split into two triangles (`2 k^2` triangles over shared vertices), followed by `m` collinear zero-area
/// triangles `(0,0,0), (t,t,0), (1,1,0)` with `t = (i + 1) / (m + 1)` for `i` in `0 .. m` (exactly collinear: the
/// cross product of their edges is exactly zero). With `k = 300` and `m = 400`, the 180,400-triangle scene on which
/// a grid that stores a triangle in every cell of its bounding box needs 400 references per cell.
///
/// # Panics
///
/// If the `(k + 1)^2 + 3 m` vertices are more than `u32` indices address.
pub fn lattice_with_diagonal(k: usize, m: usize) -> Mesh {
    let vertices = (k + 1).checked_mul(k + 1).and_then(|v| v.checked_add(m.checked_mul(3)?));
    assert!(
        vertices.is_some_and(|v| v <= u32::MAX as usize),
        "lattice_with_diagonal(k={k}, m={m}): more vertices than u32 indices address"
    );
    let mut positions = Vec::with_capacity(vertices.unwrap_or(0));
    for y in 0..=k {
        for x in 0..=k {
            positions.push([(x as f64 / k.max(1) as f64) as f32, (y as f64 / k.max(1) as f64) as f32, 0.0]);
        }
    }
    let w = (k + 1) as u32;
    let mut indices = Vec::with_capacity(2 * k * k + m);
    for y in 0..k as u32 {
        for x in 0..k as u32 {
            let a = y * w + x;
            indices.push([a, a + 1, a + w]);
            indices.push([a + 1, a + w + 1, a + w]);
        }
    }
    for i in 0..m {
        let t = ((i + 1) as f64 / (m + 1) as f64) as f32;
        let base = positions.len() as u32;
        positions.extend([[0.0, 0.0, 0.0], [t, t, 0.0], [1.0, 1.0, 0.0]]);
        indices.push([base, base + 1, base + 2]);
    }
    Mesh { name: format!("lattice_with_diagonal(k={k}, m={m})"), positions, indices, object_ids: None }
}

/// Splits every triangle into 4 through its edge midpoints, `levels` times: `4^levels` times as many triangles, for
/// scaling studies beyond the largest real mesh. Triangle `(a, b, c)` with midpoints `ab`, `bc`, `ca` becomes
/// `(a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)` (winding kept), in that order, in place of its parent.
/// Midpoints are shared by the triangles on both sides of an edge; object ids are inherited.
///
/// Fails with [`MeshError::Invalid`] when the result would need more vertices than `u32` indices address.
pub fn subdivide(mesh: &Mesh, levels: u32) -> Result<Mesh, MeshError> {
    mesh.validate()?;
    let mut positions = mesh.positions.clone();
    let mut indices = mesh.indices.clone();
    let mut object_ids = mesh.object_ids.clone();
    for _ in 0..levels {
        // Each triangle adds at most 3 vertices.
        let bound = indices.len().checked_mul(3).and_then(|n| n.checked_add(positions.len()));
        if bound.is_none_or(|n| n > u32::MAX as usize) {
            return Err(MeshError::Invalid {
                file: mesh.name.clone(),
                reason: format!("subdividing {levels} times needs more vertices than 32-bit indices address"),
            });
        }
        let mut midpoints: HashMap<(u32, u32), u32> = HashMap::with_capacity(indices.len() * 3 / 2);
        let mut next = Vec::with_capacity(indices.len() * 4);
        for &[a, b, c] in &indices {
            let mut mid = |u: u32, v: u32| -> u32 {
                let key = (u.min(v), u.max(v));
                *midpoints.entry(key).or_insert_with(|| {
                    // Indices were validated, so both lookups succeed.
                    let pu = positions.get(u as usize).copied().unwrap_or_default();
                    let pv = positions.get(v as usize).copied().unwrap_or_default();
                    positions.push(to_f32(scale(add(to_f64(pu), to_f64(pv)), 0.5)));
                    // Bounded above by the check at the start of the level.
                    (positions.len() - 1) as u32
                })
            };
            let (ab, bc, ca) = (mid(a, b), mid(b, c), mid(c, a));
            next.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        indices = next;
        object_ids = object_ids.map(|ids| ids.iter().flat_map(|&id| [id; 4]).collect());
    }
    let out = Mesh { name: format!("{} subdivided {levels}x", mesh.name), positions, indices, object_ids };
    out.validate()?;
    Ok(out)
}

fn bounds(positions: &[[f32; 3]]) -> ([f64; 3], [f64; 3]) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in positions {
        for a in 0..3 {
            lo[a] = lo[a].min(f64::from(p[a]));
            hi[a] = hi[a].max(f64::from(p[a]));
        }
    }
    if positions.is_empty() {
        ([0.0; 3], [0.0; 3])
    } else {
        (lo, hi)
    }
}

/// An exploding mesh, after the thesis's exploding-dragon scene: `frames` frames (at least 1) in which every triangle
/// moves along its own unit normal at its own constant speed.
///
/// The mesh is first made a soup (every triangle gets its own three vertices, in triangle order), so the topology is
/// the same in every frame. Frame 0 is that soup: its triangle `i` has exactly the vertices of the input's triangle
/// `i`. In frame `f` every vertex of triangle `i` is moved by `f * speed_i * normal_i`, with `speed_i` uniform in
/// `[0.005, 0.02)` times the diagonal of the input's bounding box per frame. A zero-area triangle, which has no
/// normal, moves along a random direction. Object ids are kept.
///
/// Fails when the input is invalid, when the soup needs more vertices than `u32` indices address, or when a moved
/// coordinate leaves the f32 range.
pub fn explode(mesh: &Mesh, frames: usize, seed: u64) -> Result<Animation, MeshError> {
    mesh.validate()?;
    let n = mesh.triangle_count();
    if n > MAX_SOUP_TRIANGLES {
        return Err(MeshError::Invalid {
            file: mesh.name.clone(),
            reason: format!("{n} triangles: a soup of them needs more vertices than 32-bit indices address"),
        });
    }
    let tris: Vec<[[f32; 3]; 3]> = (0..n).map(|i| mesh.triangle(i).map(|v| v.to_array())).collect();
    let (lo, hi) = bounds(&mesh.positions);
    let diag = dot(sub(hi, lo), sub(hi, lo)).sqrt();
    let diag = if diag > 0.0 && diag.is_finite() { diag } else { 1.0 };
    let mut rng = Rng::new(seed);
    let velocity: Vec<[f64; 3]> = tris
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(to_f64);
            let nrm = cross(sub(b, a), sub(c, a));
            let len = dot(nrm, nrm).sqrt();
            let dir = if len > 0.0 && len.is_finite() { scale(nrm, 1.0 / len) } else { rng.direction() };
            scale(dir, rng.range(0.005, 0.02) * diag)
        })
        .collect();
    let mut out = Vec::with_capacity(frames.max(1));
    for f in 0..frames.max(1) {
        let name = format!("{} exploded (seed={seed}) frame {f}", mesh.name);
        let frame_tris = tris.iter().zip(&velocity).map(|(t, &vel)| {
            if f == 0 {
                *t
            } else {
                let d = scale(vel, f as f64);
                t.map(|v| to_f32(add(to_f64(v), d)))
            }
        });
        let mut m = soup(name, frame_tris);
        m.object_ids = mesh.object_ids.clone();
        m.validate()?;
        out.push(m);
    }
    Animation::new(format!("{} exploded (seed={seed})", mesh.name), out)
}
