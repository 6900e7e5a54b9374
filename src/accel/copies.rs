//! Coincident copies: triangles whose three vertex positions are bit-identical, in the same order. Under the tie rule
//! (the nearest hit, the smaller triangle index among equal distances) a copy never decides a hit that the copy with
//! the smallest index would not, so a structure may keep one triangle of each group and list the others as its
//! copies: the hits and any-hit answers stay those of every triangle, and a ray tests the group once.

use super::Mesh;
use crate::geom::Triangle;

/// The bits of triangle `i`'s three vertex positions in order (all ones past the mesh).
pub(crate) fn position_bits(mesh: &Mesh, i: u32) -> [u32; 9] {
    let mut out = [u32::MAX; 9];
    if let Some(t) = mesh.indices.get(i as usize) {
        for (k, &v) in t.iter().enumerate() {
            if let Some(p) = mesh.positions.get(v as usize) {
                out[3 * k..3 * k + 3].copy_from_slice(&p.map(f32::to_bits));
            }
        }
    }
    out
}

/// The bits of a triangle record (its corner and two edges), which two copies share.
pub(crate) fn record_bits(t: &Triangle) -> [[u32; 3]; 3] {
    [t.v0, t.e1, t.e2].map(|x| x.to_array().map(f32::to_bits))
}

/// A 64-bit hash of `bits` (a multiply-rotate mix; equal bits give equal hashes, and the groups are confirmed on the
/// bits themselves).
fn hash(bits: &[u32; 9]) -> u64 {
    bits.iter()
        .fold(0x9e37_79b9_7f4a_7c15u64, |h, &b| (h ^ u64::from(b)).wrapping_mul(0xff51_afd7_ed55_8ccd).rotate_left(29))
}

/// The copies of `mesh` as `(copy, kept)` triangle indices, `kept` the smallest index of its group, sorted by
/// `copy`; empty when no two triangles share their positions. One parallel pass hashes every triangle's positions
/// into a filter of 32 bits per triangle (one bit each); only the triangles whose bit another set before,
/// and those that share a hash with one of them, are sorted and compared bit for bit, so that a mesh without copies
/// pays the pass and a few percent of a sort.
///
/// `tris` are the mesh's triangle records in mesh order (`crate::accel::prepare`): the hash reads them, which lie in
/// order in memory, instead of the vertices through the indices; copies have equal records, and the groups are
/// confirmed on the positions.
pub(crate) fn position_copies(mesh: &Mesh, tris: &[Triangle]) -> Vec<(u32, u32)> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicU64, Ordering};
    let n = tris.len().min(mesh.triangle_count()).min(u32::MAX as usize) as u32;
    if n < 2 {
        return Vec::new();
    }
    let hashes: Vec<u64> = tris[..n as usize]
        .par_iter()
        .map(|t| {
            let r = record_bits(t);
            hash(&[r[0][0], r[0][1], r[0][2], r[1][0], r[1][1], r[1][2], r[2][0], r[2][1], r[2][2]])
        })
        .collect();
    let words = (n as usize * 32).next_power_of_two() / 64;
    let filter: Vec<AtomicU64> = (0..words).map(|_| AtomicU64::new(0)).collect();
    let mask = (words * 64 - 1) as u64;
    let set = |b: u64| {
        let bit = 1u64 << (b & 63);
        filter[(b >> 6) as usize].fetch_or(bit, Ordering::Relaxed) & bit != 0
    };
    // A triangle whose bit was set already may share its hash with another (or meet a false positive). Of two equal
    // hashes exactly one finds the bit set (`fetch_or` is atomic), whichever the schedule; the groups are then formed
    // from every triangle with such a hash, so the result does not depend on the schedule.
    let mut seen: Vec<u64> = hashes.par_iter().filter(|&&h| set(h & mask)).copied().collect();
    if seen.is_empty() {
        return Vec::new();
    }
    seen.par_sort_unstable();
    seen.dedup();
    let mut keys: Vec<([u32; 9], u32)> = (0..n)
        .into_par_iter()
        .filter(|&i| seen.binary_search(&hashes[i as usize]).is_ok())
        .map(|i| (position_bits(mesh, i), i))
        .collect();
    // By position bits, then index, so that the first of a group is its smallest index.
    keys.par_sort_unstable();
    let mut pairs = Vec::new();
    let mut first = 0;
    for w in 1..keys.len() {
        if keys[w].0 == keys[first].0 {
            pairs.push((keys[w].1, keys[first].1));
        } else {
            first = w;
        }
    }
    pairs.sort_unstable();
    pairs
}

/// Whether triangle `i` of a mesh with `copies` ([`position_copies`]) is a copy, as a mask over the triangles.
pub(crate) fn copy_mask(n: usize, copies: &[(u32, u32)]) -> Vec<bool> {
    let mut mask = vec![false; n];
    for &(c, _) in copies {
        mask[c as usize] = true;
    }
    mask
}
