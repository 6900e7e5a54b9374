//! Scene families: seeded generators of whole scenes of one kind at a requested triangle count, for fitting and
//! evaluating selection policies on more than scanned objects seen from outside.
//!
//! | family | [`Family`] | what it builds |
//! |---|---|---|
//! | `interior` | [`Family::Interior`] | a grid of closed rooms (floor, ceiling, large wall quads) joined by doorways, furnished with boxes (tables, cabinets, shelves of small items) |
//! | `city` | [`Family::City`] | a ground plane with blocks of buildings between streets: boxes of log-normal heights, some with a setback tier |
//! | `vegetation` | [`Family::Vegetation`] | a patch of ground covered by grass blades (one thin triangle each) and trees whose crowns are clouds of small leaf triangles: many small disjoint triangles |
//! | `terrain` | [`Family::Terrain`] | a heightfield of value noise (three octaves) with rocks and trees standing on it |
//! | `particles` | [`Family::Particles`] | tiny triangles in a volume: a uniform haze and a few dense plumes |
//! | `engineering` | [`Family::Engineering`] | machine parts: long pipes of few segments (long slivers), disks and flanges triangulated as fans from their centres, plates and bolts |
//! | `stadium` | [`Family::Stadium`] | copies of the embedded teapot (subdivided as needed), clustered near a random point, inside the 12 triangles of a huge box (after [`super::generate::teapot_in_stadium`]) |
//!
//! [`generate`] makes a scene of a family with **exactly** the requested number of triangles: each family builds
//! its fixed part (walls, ground, box) and then objects until the count is reached; the last object is cut short
//! (a prefix of its triangles) when it does not fit, and a request smaller than the fixed part gets a prefix of the
//! fixed part. A request of 0 gives an empty mesh; more than [`MAX_FAMILY_TRIANGLES`] is refused with
//! [`MeshError::Invalid`].
//!
//! Every generator is deterministic: the same family, count and seed give the same mesh, bit for bit, on every
//! machine. A [`SplitMix64`] drives the choices, the arithmetic is IEEE f64 (additions, multiplications, divisions
//! and square roots only, no library transcendental function) rounded once to f32, and no hash map is iterated.
//! Different seeds give different scenes. Coordinates are finite and of the order of the scene (metres: a room is
//! 8 m wide, a city block 60 m); y is up.

use super::{Mesh, MeshError};
use crate::rng::SplitMix64;

/// Largest triangle count [`generate`] accepts: `2^26` (67,108,864).
pub const MAX_FAMILY_TRIANGLES: usize = 1 << 26;

/// A kind of scene (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Family {
    /// Closed rooms joined by doorways, with furniture.
    Interior,
    /// Boxes of varied heights on a ground plane.
    City,
    /// Grass blades and leaves over a patch of ground.
    Vegetation,
    /// A heightfield with objects on it.
    Terrain,
    /// Tiny triangles in a volume.
    Particles,
    /// Machine parts with long slivers and fans.
    Engineering,
    /// Teapots in a stadium.
    Stadium,
}

impl Family {
    /// Every family, in the order of the module docs.
    pub const ALL: [Family; 7] = [
        Family::Interior,
        Family::City,
        Family::Vegetation,
        Family::Terrain,
        Family::Particles,
        Family::Engineering,
        Family::Stadium,
    ];

    /// The lowercase name (`interior`, `city`, `vegetation`, `terrain`, `particles`, `engineering`, `stadium`).
    pub fn name(self) -> &'static str {
        match self {
            Family::Interior => "interior",
            Family::City => "city",
            Family::Vegetation => "vegetation",
            Family::Terrain => "terrain",
            Family::Particles => "particles",
            Family::Engineering => "engineering",
            Family::Stadium => "stadium",
        }
    }

    /// Parses a name of [`Family::name`] (case-insensitive); `None` for anything else.
    pub fn from_name(s: &str) -> Option<Family> {
        Family::ALL.into_iter().find(|f| f.name().eq_ignore_ascii_case(s.trim()))
    }
}

impl std::fmt::Display for Family {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Family {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Family::from_name(s).ok_or_else(|| {
            let names: Vec<&str> = Family::ALL.iter().map(|f| f.name()).collect();
            format!("unknown scene family {s:?} ({})", names.join(", "))
        })
    }
}

/// The prefix of a generated scene's name: `family:NAME:TRIANGLES[:SEED]` ([`parse_spec`]).
pub const SPEC_PREFIX: &str = "family:";

/// A generated scene named on a command line or in a record: `family:NAME:TRIANGLES[:SEED]`, for instance
/// `family:city:100000:7` (seed 0 when left out; `TRIANGLES` may use `_` separators and a `k` or `m` suffix:
/// `100k`, `2m`). `None` when `s` does not start with [`SPEC_PREFIX`]; otherwise the family, the triangle count
/// and the seed, or why the spec is wrong.
pub fn parse_spec(s: &str) -> Option<Result<(Family, usize, u64), String>> {
    let rest = s.strip_prefix(SPEC_PREFIX)?;
    let parts: Vec<&str> = rest.split(':').collect();
    let usage = || format!("{s:?}: a generated scene is family:NAME:TRIANGLES[:SEED]");
    Some((|| {
        if !(2..=3).contains(&parts.len()) {
            return Err(usage());
        }
        let family: Family = parts[0].parse()?;
        let (n, seed) = count_and_seed(&parts[1..], &usage())?;
        Ok((family, n, seed))
    })())
}

/// The `TRIANGLES[:SEED]` part of a scene spec (`TRIANGLES` with optional `_` separators and a `k` or `m` suffix;
/// seed 0 when left out); `usage` heads the error.
pub(crate) fn count_and_seed(parts: &[&str], usage: &str) -> Result<(usize, u64), String> {
    let raw = parts.first().copied().unwrap_or("");
    let count = raw.trim().replace('_', "").to_ascii_lowercase();
    let (digits, scale) = match count.strip_suffix('k') {
        Some(d) => (d, 1_000u64),
        None => match count.strip_suffix('m') {
            Some(d) => (d, 1_000_000),
            None => (count.as_str(), 1),
        },
    };
    let whole = !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit());
    if !whole {
        return Err(format!("{usage}: the triangle count {raw:?} is not a whole number"));
    }
    let n = digits
        .parse::<u64>()
        .ok()
        .and_then(|d| d.checked_mul(scale))
        .ok_or_else(|| format!("{usage}: the triangle count {raw:?} is too large"))?;
    let n = usize::try_from(n).map_err(|_| format!("{usage}: {n} triangles is too many"))?;
    let seed = match parts.get(1) {
        Some(t) => t.trim().parse::<u64>().map_err(|_| format!("{usage}: the seed {t:?} is not a whole number"))?,
        None => 0,
    };
    Ok((n, seed))
}

/// A scene of `family` with exactly `triangles` triangles from `seed` (see the module docs).
///
/// Fails with [`MeshError::Invalid`] when `triangles` exceeds [`MAX_FAMILY_TRIANGLES`].
pub fn generate(family: Family, triangles: usize, seed: u64) -> Result<Mesh, MeshError> {
    let name = format!("{family}(n={triangles}, seed={seed})");
    if triangles > MAX_FAMILY_TRIANGLES {
        return Err(MeshError::Invalid {
            file: name,
            reason: format!(
                "{triangles} triangles requested: more than the {MAX_FAMILY_TRIANGLES} a scene family generates"
            ),
        });
    }
    // Each family's stream of choices is its own: the seed mixed with the family.
    let mut rng = SplitMix64::new(seed ^ (0x6a09_e667_f3bc_c908u64.wrapping_mul(family as u64 + 1)));
    let mut b = Builder::new(triangles);
    if triangles > 0 {
        match family {
            Family::Interior => interior(&mut b, &mut rng),
            Family::City => city(&mut b, &mut rng),
            Family::Vegetation => vegetation(&mut b, &mut rng),
            Family::Terrain => terrain(&mut b, &mut rng),
            Family::Particles => particles(&mut b, &mut rng),
            Family::Engineering => engineering(&mut b, &mut rng),
            Family::Stadium => stadium(&mut b, &mut rng),
        }
    }
    let mesh = b.finish(name);
    mesh.validate()?;
    Ok(mesh)
}

type P = [f64; 3];

fn add(a: P, b: P) -> P {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: P, b: P) -> P {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn scale(a: P, s: f64) -> P {
    a.map(|c| c * s)
}

fn norm(a: P) -> P {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    if l > 0.0 {
        scale(a, 1.0 / l)
    } else {
        [0.0, 1.0, 0.0]
    }
}

fn cross(a: P, b: P) -> P {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// `(cos, sin)` of the angle `2 pi k / m` without a library transcendental function (so the same bits on every
/// machine): a Taylor series at `1 / 256` of the angle, doubled back; `|cos^2 + sin^2 - 1|` is a few ulps.
fn unit_circle(k: usize, m: usize) -> (f64, f64) {
    // The angle divided by 2^8 is small enough for a short Taylor series; doubling back 8 times with
    // cos 2a = c^2 - s^2, sin 2a = 2 c s gives the angle.
    let m = m.max(1);
    let theta = std::f64::consts::TAU * (k % m) as f64 / m as f64;
    let steps = 8;
    let a = theta / (1u32 << steps) as f64; // at most 2 pi / 256
                                            // cos and sin of a small angle by Taylor series (|a| < 0.025: the terms shown reach f64 precision).
    let a2 = a * a;
    let mut c = 1.0 - a2 / 2.0 * (1.0 - a2 / 12.0 * (1.0 - a2 / 30.0 * (1.0 - a2 / 56.0)));
    let mut s = a * (1.0 - a2 / 6.0 * (1.0 - a2 / 20.0 * (1.0 - a2 / 42.0 * (1.0 - a2 / 72.0))));
    for _ in 0..steps {
        let (c2, s2) = (c * c - s * s, 2.0 * c * s);
        // Renormalize so that rounding does not grow over the doublings.
        let r = (c2 * c2 + s2 * s2).sqrt();
        c = c2 / r;
        s = s2 / r;
    }
    (c, s)
}

/// Accumulates triangles up to the target count; every primitive stops at the target.
struct Builder {
    positions: Vec<[f32; 3]>,
    indices: Vec<[u32; 3]>,
    target: usize,
}

impl Builder {
    fn new(target: usize) -> Self {
        Builder { positions: Vec::new(), indices: Vec::new(), target }
    }

    fn full(&self) -> bool {
        self.indices.len() >= self.target
    }

    fn left(&self) -> usize {
        self.target.saturating_sub(self.indices.len())
    }

    fn vertex(&mut self, p: P) -> u32 {
        // The target is at most 2^26 triangles and no primitive adds more than 3 vertices per triangle plus a few,
        // so the count fits u32.
        self.positions.push(p.map(|c| c as f32));
        (self.positions.len() - 1) as u32
    }

    fn tri_ix(&mut self, a: u32, b: u32, c: u32) {
        if !self.full() {
            self.indices.push([a, b, c]);
        }
    }

    fn tri(&mut self, a: P, b: P, c: P) {
        if !self.full() {
            let (a, b, c) = (self.vertex(a), self.vertex(b), self.vertex(c));
            self.indices.push([a, b, c]);
        }
    }

    /// Two triangles over four corners in order around the quad.
    fn quad(&mut self, a: P, b: P, c: P, d: P) {
        if self.full() {
            return;
        }
        let (a, b, c, d) = (self.vertex(a), self.vertex(b), self.vertex(c), self.vertex(d));
        self.tri_ix(a, b, c);
        self.tri_ix(a, c, d);
    }

    /// An axis-aligned box over 8 shared corners: 12 triangles, or 10 without the bottom face.
    fn cuboid(&mut self, lo: P, hi: P, bottom: bool) {
        if self.full() {
            return;
        }
        let base = self.positions.len() as u32;
        for i in 0..8u32 {
            let pick = |bit: u32, a: usize| if i & bit != 0 { hi[a] } else { lo[a] };
            self.vertex([pick(1, 0), pick(2, 1), pick(4, 2)]);
        }
        // Corner k: x from bit 0, y from bit 1, z from bit 2. Bottom (y = lo) first so that it can be skipped.
        const FACES: [[u32; 4]; 6] =
            [[0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5], [0, 2, 3, 1], [4, 5, 7, 6]];
        for (f, [a, b, c, d]) in FACES.into_iter().enumerate() {
            if f == 0 && !bottom {
                continue;
            }
            self.tri_ix(base + a, base + b, base + c);
            self.tri_ix(base + a, base + c, base + d);
        }
    }

    /// A fan of `m` triangles around `center` in the plane spanned by the unit vectors `u`, `v`: a disk of radius
    /// `r`, or an annulus from `r0` to `r` (2 m triangles) when `r0 > 0`.
    fn disk(&mut self, center: P, u: P, v: P, r0: f64, r: f64, m: usize) {
        let ring = |rad: f64, k: usize| {
            let (c, s) = unit_circle(k, m);
            add(center, add(scale(u, rad * c), scale(v, rad * s)))
        };
        for k in 0..m {
            if self.full() {
                return;
            }
            if r0 > 0.0 {
                self.quad(ring(r0, k), ring(r, k), ring(r, k + 1), ring(r0, k + 1));
            } else {
                self.tri(center, ring(r, k), ring(r, k + 1));
            }
        }
    }

    /// The side of a cylinder from `a` to `b` of radius `r`: `m` segments around, one along (2 m long triangles).
    fn pipe(&mut self, a: P, b: P, r: f64, m: usize) {
        let axis = norm(sub(b, a));
        let helper = if axis[1].abs() < 0.9 { [0.0, 1.0, 0.0] } else { [1.0, 0.0, 0.0] };
        let u = norm(cross(axis, helper));
        let v = cross(axis, u);
        let at = |p: P, k: usize| {
            let (c, s) = unit_circle(k, m);
            add(p, add(scale(u, r * c), scale(v, r * s)))
        };
        for k in 0..m {
            if self.full() {
                return;
            }
            self.quad(at(a, k), at(b, k), at(b, k + 1), at(a, k + 1));
        }
    }

    fn finish(self, name: String) -> Mesh {
        Mesh { name, positions: self.positions, indices: self.indices, object_ids: None }
    }
}

fn range(rng: &mut SplitMix64, lo: f64, hi: f64) -> f64 {
    rng.range(lo, hi)
}

/// A uniformly random point of the unit ball (rejection from the cube).
fn in_ball(rng: &mut SplitMix64) -> P {
    loop {
        let p = [rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)];
        if p[0] * p[0] + p[1] * p[1] + p[2] * p[2] <= 1.0 {
            return p;
        }
    }
}

/// A small triangle around `c` of size about `s`: corners at `c + s * q` with `q` in the unit ball.
fn small_tri(b: &mut Builder, rng: &mut SplitMix64, c: P, s: f64) {
    let (p, q, r) = (in_ball(rng), in_ball(rng), in_ball(rng));
    b.tri(add(c, scale(p, s)), add(c, scale(q, s)), add(c, scale(r, s)));
}

/// `exp(x)` for `|x|` of a few units without the library: `(1 + x / 2^10)^(2^10)` is within 0.5% here, which is
/// plenty for a size distribution.
fn exp_approx(x: f64) -> f64 {
    let mut y = 1.0 + x / 1024.0;
    for _ in 0..10 {
        y *= y;
    }
    y
}

/// Interiors: `rooms_x x rooms_z` rooms of 8 x 3 x 6 m, doorways in every wall between two rooms, furniture.
fn interior(b: &mut Builder, rng: &mut SplitMix64) {
    let n = b.target;
    // 2 rooms up to 2K triangles, one more per doubling, at most 16.
    let rooms = (2 + (n / 2000).max(1).ilog2() as usize).min(16);
    let rx = (rooms as f64).sqrt().ceil() as usize;
    let rz = rooms.div_ceil(rx);
    let (w, h, d) = (8.0, 3.0, 6.0);
    let (door_w, door_h) = (1.0, 2.1);
    // Floors and ceilings.
    for i in 0..rx {
        for k in 0..rz {
            let (x0, z0) = (i as f64 * w, k as f64 * d);
            b.quad([x0, 0.0, z0], [x0, 0.0, z0 + d], [x0 + w, 0.0, z0 + d], [x0 + w, 0.0, z0]);
            b.quad([x0, h, z0], [x0 + w, h, z0], [x0 + w, h, z0 + d], [x0, h, z0 + d]);
        }
    }
    // Walls: planes x = i w (i in 0 ..= rx) and z = k d; inner ones have a doorway per room they separate.
    let wall_x = |b: &mut Builder, x: f64, z0: f64, z1: f64, door: Option<f64>| match door {
        None => b.quad([x, 0.0, z0], [x, h, z0], [x, h, z1], [x, 0.0, z1]),
        Some(c) => {
            let (a, e) = (c - door_w / 2.0, c + door_w / 2.0);
            b.quad([x, 0.0, z0], [x, h, z0], [x, h, a], [x, 0.0, a]);
            b.quad([x, 0.0, e], [x, h, e], [x, h, z1], [x, 0.0, z1]);
            b.quad([x, door_h, a], [x, h, a], [x, h, e], [x, door_h, e]);
        }
    };
    let wall_z = |b: &mut Builder, z: f64, x0: f64, x1: f64, door: Option<f64>| match door {
        None => b.quad([x0, 0.0, z], [x1, 0.0, z], [x1, h, z], [x0, h, z]),
        Some(c) => {
            let (a, e) = (c - door_w / 2.0, c + door_w / 2.0);
            b.quad([x0, 0.0, z], [a, 0.0, z], [a, h, z], [x0, h, z]);
            b.quad([e, 0.0, z], [x1, 0.0, z], [x1, h, z], [e, h, z]);
            b.quad([a, door_h, z], [e, door_h, z], [e, h, z], [a, h, z]);
        }
    };
    for i in 0..=rx {
        for k in 0..rz {
            let inner = i > 0 && i < rx;
            let door = inner.then(|| k as f64 * d + range(rng, 1.0, d - 1.0));
            wall_x(b, i as f64 * w, k as f64 * d, (k + 1) as f64 * d, door);
        }
    }
    for k in 0..=rz {
        for i in 0..rx {
            let inner = k > 0 && k < rz;
            let door = inner.then(|| i as f64 * w + range(rng, 1.0, w - 1.0));
            wall_z(b, k as f64 * d, i as f64 * w, (i + 1) as f64 * w, door);
        }
    }
    // Furniture: pieces of 12 to ~200 triangles; their size shrinks as more of them share the floor.
    let pieces_per_room = (b.left() / 60).div_ceil(rx * rz).max(1);
    let s = (24.0 / pieces_per_room as f64).sqrt().clamp(0.05, 1.0);
    while !b.full() {
        let room = rng.below((rx * rz) as u64) as usize;
        let (x0, z0) = ((room % rx) as f64 * w, (room / rx) as f64 * d);
        let (cx, cz) = (x0 + range(rng, 0.6, w - 0.6), z0 + range(rng, 0.6, d - 0.6));
        match rng.below(3) {
            0 => {
                // A table: top and four legs.
                let (hw, hd, th) = (s * range(rng, 0.3, 0.8), s * range(rng, 0.3, 0.6), s * 0.75);
                b.cuboid([cx - hw, th - 0.04 * s, cz - hd], [cx + hw, th, cz + hd], true);
                for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                    let (lx, lz) = (cx + sx * (hw - 0.05 * s), cz + sz * (hd - 0.05 * s));
                    b.cuboid([lx - 0.03 * s, 0.0, lz - 0.03 * s], [lx + 0.03 * s, th - 0.04 * s, lz + 0.03 * s], false);
                }
            }
            1 => {
                // A cabinet.
                let (hw, hd, ht) = (s * range(rng, 0.2, 0.6), s * range(rng, 0.2, 0.4), s * range(rng, 0.5, 2.0));
                b.cuboid([cx - hw, 0.0, cz - hd], [cx + hw, ht.min(h - 0.1), cz + hd], false);
            }
            _ => {
                // A shelf of small items: three boards and items on each.
                let (hw, hd) = (s * range(rng, 0.4, 0.9), s * 0.15);
                for level in 0..3 {
                    let y = s * (0.3 + 0.6 * level as f64);
                    b.cuboid([cx - hw, y, cz - hd], [cx + hw, y + 0.02 * s, cz + hd], true);
                    let items = 1 + rng.below(8);
                    for _ in 0..items {
                        let ix = cx + range(rng, -hw, hw);
                        let (iw, ih) = (s * range(rng, 0.02, 0.06), s * range(rng, 0.05, 0.25));
                        b.cuboid([ix - iw, y + 0.02 * s, cz - iw], [ix + iw, y + 0.02 * s + ih, cz + iw], false);
                    }
                }
            }
        }
    }
}

/// Cities: a ground quad, blocks of 4 x 4 lots of 15 m between 10 m streets, a building (box of 10 triangles, 20
/// with a setback tier) per lot, heights log-normal.
fn city(b: &mut Builder, rng: &mut SplitMix64) {
    let n = b.target;
    let buildings = (n.saturating_sub(2) / 12).max(1);
    let lots_side = (buildings as f64).sqrt().ceil() as usize;
    let blocks = lots_side.div_ceil(4);
    let (lot, street) = (15.0, 10.0);
    let block = 4.0 * lot + street;
    let side = blocks as f64 * block + street;
    b.quad([0.0, 0.0, 0.0], [0.0, 0.0, side], [side, 0.0, side], [side, 0.0, 0.0]);
    // A building per lot while triangles last; then, if any are left, more storeys on random lots (antennas).
    'lots: for bz in 0..blocks {
        for bx in 0..blocks {
            for lz in 0..4 {
                for lx in 0..4 {
                    if b.full() {
                        break 'lots;
                    }
                    let x0 = street + bx as f64 * block + lx as f64 * lot;
                    let z0 = street + bz as f64 * block + lz as f64 * lot;
                    let (mx, mz) = (range(rng, 0.5, 3.0), range(rng, 0.5, 3.0));
                    let hgt = 6.0 * exp_approx(0.8 * rng.gaussian().clamp(-3.0, 4.0));
                    b.cuboid([x0 + mx, 0.0, z0 + mz], [x0 + lot - mx, hgt, z0 + lot - mz], false);
                    if rng.below(4) == 0 {
                        let inset = range(rng, 1.0, 3.0);
                        let top = hgt * range(rng, 1.1, 1.6);
                        b.cuboid(
                            [x0 + mx + inset, hgt, z0 + mz + inset],
                            [x0 + lot - mx - inset, top, z0 + lot - mz - inset],
                            false,
                        );
                    }
                }
            }
        }
    }
    while !b.full() {
        let (x, z) = (range(rng, 0.0, side), range(rng, 0.0, side));
        let hgt = range(rng, 3.0, 40.0);
        b.cuboid([x, 0.0, z], [x + 0.3, hgt, z + 0.3], false);
    }
}

/// Vegetation: a 40 x 40 m patch (2 ground triangles); trees (a trunk box, a crown of leaves) take a third of the
/// triangles, grass blades (one thin triangle each, tilted at random) the rest.
fn vegetation(b: &mut Builder, rng: &mut SplitMix64) {
    let n = b.target;
    let side = 40.0;
    b.quad([0.0, 0.0, 0.0], [0.0, 0.0, side], [side, 0.0, side], [side, 0.0, 0.0]);
    let leaves_total = n / 3;
    let trees = (leaves_total / 2000).clamp(1, 64);
    let leaves_per_tree = leaves_total / trees;
    for _ in 0..trees {
        if b.full() {
            return;
        }
        let (x, z) = (range(rng, 3.0, side - 3.0), range(rng, 3.0, side - 3.0));
        let th = range(rng, 3.0, 6.0);
        b.cuboid([x - 0.15, 0.0, z - 0.15], [x + 0.15, th, z + 0.15], false);
        let r = range(rng, 1.5, 3.0);
        let c = [x, th + r * 0.7, z];
        // Leaves: 8 cm triangles in the crown's shell.
        for _ in 0..leaves_per_tree.saturating_sub(10) {
            if b.full() {
                return;
            }
            let p = in_ball(rng);
            let p = scale(norm(p), r * (0.6 + 0.4 * (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt()));
            small_tri(b, rng, add(c, p), 0.08);
        }
    }
    // Grass blades: base 1-2 cm, 10-40 cm tall, leaning up to about 30 degrees.
    while !b.full() {
        let (x, z) = (range(rng, 0.0, side), range(rng, 0.0, side));
        let (wdt, ht) = (range(rng, 0.005, 0.01), range(rng, 0.1, 0.4));
        let (dx, dz) = (range(rng, -0.5, 0.5), range(rng, -0.5, 0.5));
        let (ox, oz) = (range(rng, -1.0, 1.0), range(rng, -1.0, 1.0));
        let o = norm([ox, 0.0, oz]);
        b.tri(
            [x - o[0] * wdt, 0.0, z - o[2] * wdt],
            [x + o[0] * wdt, 0.0, z + o[2] * wdt],
            [x + dx * ht, ht, z + dz * ht],
        );
    }
}

/// Value noise: a random value per lattice point (from a hash of its coordinates and the seed), interpolated with
/// smoothstep.
fn value_noise(seed: u64, x: f64, z: f64) -> f64 {
    let hash = |i: i64, k: i64| {
        let mut g = SplitMix64::new(
            seed ^ (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ (k as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f),
        );
        g.next_f64()
    };
    let (i, k) = (x.floor(), z.floor());
    let (fx, fz) = (x - i, z - k);
    let (sx, sz) = (fx * fx * (3.0 - 2.0 * fx), fz * fz * (3.0 - 2.0 * fz));
    let (i, k) = (i as i64, k as i64);
    let a = hash(i, k) + sx * (hash(i + 1, k) - hash(i, k));
    let c = hash(i, k + 1) + sx * (hash(i + 1, k + 1) - hash(i, k + 1));
    a + sz * (c - a)
}

/// Terrain: a `g x g` heightfield over 1 km (three octaves of value noise, up to about 120 m), three quarters of
/// the triangles; rocks (boxes) and trees (a trunk and an octahedral crown) on it for the rest.
fn terrain(b: &mut Builder, rng: &mut SplitMix64) {
    let n = b.target;
    let g = (((n * 3 / 4) / 2) as f64).sqrt().floor().max(1.0) as usize;
    let side = 1000.0;
    let noise_seed = rng.next_u64();
    let height = |x: f64, z: f64| {
        let (u, v) = (x / side * 6.0, z / side * 6.0);
        80.0 * value_noise(noise_seed, u, v)
            + 30.0 * value_noise(noise_seed ^ 1, 2.0 * u, 2.0 * v)
            + 10.0 * value_noise(noise_seed ^ 2, 4.0 * u, 4.0 * v)
    };
    let step = side / g as f64;
    let base = b.positions.len() as u32;
    for k in 0..=g {
        for i in 0..=g {
            let (x, z) = (i as f64 * step, k as f64 * step);
            b.vertex([x, height(x, z), z]);
        }
    }
    let w = (g + 1) as u32;
    for k in 0..g as u32 {
        for i in 0..g as u32 {
            let a = base + k * w + i;
            b.tri_ix(a, a + w, a + 1);
            b.tri_ix(a + 1, a + w, a + w + 1);
        }
    }
    while !b.full() {
        let (x, z) = (range(rng, 0.0, side), range(rng, 0.0, side));
        let y = height(x, z);
        if rng.below(3) == 0 {
            let r = range(rng, 0.5, 4.0);
            b.cuboid([x - r, y - 0.3 * r, z - r], [x + r, y + r, z + r], false);
        } else {
            let th = range(rng, 4.0, 12.0);
            b.cuboid([x - 0.2, y - 0.5, z - 0.2], [x + 0.2, y + th, z + 0.2], false);
            let (r, cy) = (range(rng, 1.5, 4.0), y + th + 1.0);
            let tip = [[r, 0.0, 0.0], [0.0, 0.0, r], [-r, 0.0, 0.0], [0.0, 0.0, -r]];
            for (j, &t) in tip.iter().enumerate() {
                let (p, q) = (add([x, cy, z], t), add([x, cy, z], tip[(j + 1) % 4]));
                b.tri(p, q, [x, cy + 1.5 * r, z]);
                b.tri(q, p, [x, cy - 0.5 * r, z]);
            }
        }
    }
}

/// Particles: tiny triangles (1 to 5 mm) in a 10 m cube: 40% a uniform haze, 60% in 3 to 8 plumes (gaussian
/// columns, narrow at the bottom, wider at the top).
fn particles(b: &mut Builder, rng: &mut SplitMix64) {
    let plumes: Vec<(f64, f64)> = (0..3 + rng.below(6)).map(|_| (range(rng, 2.0, 8.0), range(rng, 2.0, 8.0))).collect();
    while !b.full() {
        let s = range(rng, 0.001, 0.005);
        let c = if rng.below(5) < 2 {
            [range(rng, 0.0, 10.0), range(rng, 0.0, 10.0), range(rng, 0.0, 10.0)]
        } else {
            let (px, pz) = plumes[rng.below(plumes.len() as u64) as usize];
            let y = range(rng, 0.0, 10.0);
            let spread = 0.05 + 0.08 * y;
            [px + spread * rng.gaussian(), y, pz + spread * rng.gaussian()]
        };
        small_tri(b, rng, c, s);
    }
}

/// Engineering: parts on a 4 m bench: pipes 1-3 m long of 2-10 cm radius with 8 to 24 segments (long slivers),
/// flanges (annuli) and end caps (fans of up to 256 slivers from the centre), a perforated-looking plate (a fan per
/// hole), bolts (hexagonal fans and sides).
fn engineering(b: &mut Builder, rng: &mut SplitMix64) {
    let x = [1.0, 0.0, 0.0];
    let y = [0.0, 1.0, 0.0];
    let z = [0.0, 0.0, 1.0];
    // A base plate with a fan per hole: radial slivers to the hole's rim.
    b.cuboid([0.0, -0.05, 0.0], [4.0, 0.0, 2.0], true);
    while !b.full() {
        match rng.below(4) {
            0 | 1 => {
                let a = [range(rng, 0.2, 3.8), range(rng, 0.05, 1.0), range(rng, 0.2, 1.8)];
                let r = range(rng, 0.02, 0.1);
                let len = range(rng, 1.0, 3.0);
                let dir = norm([range(rng, -1.0, 1.0), range(rng, -0.2, 0.2), range(rng, -1.0, 1.0)]);
                let e = add(a, scale(dir, len));
                let m = 8 + rng.below(17) as usize;
                b.pipe(a, e, r, m);
                // End caps: fans with many more segments than the pipe (the slivers of a CAD export).
                let helper = if dir[1].abs() < 0.9 { y } else { x };
                let u = norm(cross(dir, helper));
                let v = cross(dir, u);
                let fan = 32 << rng.below(4);
                b.disk(a, u, v, 0.0, r, fan as usize);
                b.disk(e, u, v, 0.0, r, fan as usize);
                // A flange at a third of the way.
                if rng.below(2) == 0 {
                    b.disk(add(a, scale(dir, len / 3.0)), u, v, r, 2.5 * r, m);
                }
            }
            2 => {
                // A bolt: hexagonal head (two fans and six sides) and a thin shank of 6 long triangles pairs.
                let c = [range(rng, 0.1, 3.9), 0.0, range(rng, 0.1, 1.9)];
                let r = range(rng, 0.005, 0.02);
                b.pipe(c, add(c, [0.0, 6.0 * r, 0.0]), r * 0.5, 6);
                let top = add(c, [0.0, 6.0 * r, 0.0]);
                b.pipe(top, add(top, [0.0, r, 0.0]), r, 6);
                b.disk(add(top, [0.0, r, 0.0]), z, x, 0.0, r, 6);
            }
            _ => {
                // A disk (a gear blank): a fan of 64 to 512 slivers on each face.
                let c = [range(rng, 0.3, 3.7), range(rng, 0.0, 0.5), range(rng, 0.3, 1.7)];
                let r = range(rng, 0.05, 0.3);
                let m = 64 << rng.below(4);
                b.disk(c, z, x, 0.0, r, m as usize);
                b.disk(add(c, [0.0, 0.02, 0.0]), x, z, 0.0, r, m as usize);
                b.pipe(c, add(c, [0.0, 0.02, 0.0]), r, m as usize);
            }
        }
    }
}

/// Stadium: the 12 triangles of the cube `[-10^4, 10^4]^3`, then copies of the embedded teapot scaled to a
/// diagonal of 1 around a random point of `[-100, 100]^3` (within 2 units of it): as many of the largest
/// subdivision (`992 * 4^l` triangles) as fit, then smaller ones, the last cut short.
fn stadium(b: &mut Builder, rng: &mut SplitMix64) {
    let r = 1.0e4;
    b.cuboid([-r, -r, -r], [r, r, r], true);
    let teapot = super::default_teapot();
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in &teapot.positions {
        for a in 0..3 {
            lo[a] = lo[a].min(f64::from(p[a]));
            hi[a] = hi[a].max(f64::from(p[a]));
        }
    }
    let center = scale(add(lo, hi), 0.5);
    let e = sub(hi, lo);
    let diag = (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]).sqrt();
    let s = if diag > 0.0 { 1.0 / diag } else { 1.0 };
    let spot = [range(rng, -100.0, 100.0), range(rng, -100.0, 100.0), range(rng, -100.0, 100.0)];
    let mut levels: Vec<Mesh> = vec![teapot];
    while !b.full() {
        // The largest subdivision that fits what is left (the base teapot when none does).
        let left = b.left();
        while let Some(next) =
            levels.last().filter(|m| m.triangle_count() * 4 <= left).and_then(|m| super::generate::subdivide(m, 1).ok())
        {
            levels.push(next);
        }
        let Some(copy) = levels.iter().rev().find(|m| m.triangle_count() <= left).or(levels.first()) else { break };
        let offset = add(spot, [range(rng, -2.0, 2.0), range(rng, -2.0, 2.0), range(rng, -2.0, 2.0)]);
        let base = b.positions.len() as u32;
        for p in &copy.positions {
            let q = add(scale(sub(p.map(f64::from), center), s), offset);
            b.vertex(q);
        }
        for t in &copy.indices {
            b.tri_ix(base + t[0], base + t[1], base + t[2]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_names_are_refused() {
        for f in Family::ALL {
            assert_eq!(Family::from_name(f.name()), Some(f));
            assert_eq!(f.name().to_uppercase().parse::<Family>(), Ok(f));
        }
        assert_eq!(Family::from_name("forest"), None);
        assert!("forest".parse::<Family>().is_err_and(|e| e.contains("interior")));
    }

    #[test]
    fn unit_circle_is_on_the_circle() {
        for m in [3, 6, 7, 64, 512] {
            for k in 0..=m {
                let (c, s) = unit_circle(k, m);
                assert!((c * c + s * s - 1.0).abs() < 1e-12, "k {k} m {m}");
            }
        }
        let (c, s) = unit_circle(1, 4);
        assert!(c.abs() < 1e-12 && (s - 1.0).abs() < 1e-12);
    }

    #[test]
    fn exp_approx_is_close() {
        for x in [-3.0, -1.0, 0.0, 0.5, 2.0, 3.2] {
            let rel = exp_approx(x) / f64::exp(x) - 1.0;
            assert!(rel.abs() < 0.01, "exp({x}): {rel}");
        }
    }
}
