//! A parallel, stable LSD radix sort on the host for the builders' Morton keys (the LBVH, the HLBVH and the PLOC
//! builder sort `(code, triangle)` pairs).
//!
//! Each pass sorts by one digit of the key, stably: every chunk of the input counts its digits (in parallel), an
//! exclusive scan over (digit, chunk) gives every chunk the first output position of each of its digits, and every
//! chunk scatters its elements in input order to those positions (in parallel, disjoint writes). Passes whose digit
//! is the same for every element are skipped. Digits are at most 11 bits wide, as many passes as the key's highest
//! set bit needs (30-bit codes: three 10-bit passes).
//!
//! The result does not depend on the number of threads: a stable sort of given keys has one answer.

use rayon::prelude::*;

/// Inputs below this length are sorted by the standard library's stable sort on one thread.
const SMALL: usize = 2048;
/// Elements per chunk of a pass (at least; the input is cut into at most [`MAX_CHUNKS`] chunks).
const MIN_CHUNK: usize = 16_384;
const MAX_CHUNKS: usize = 64;
const MAX_DIGIT_BITS: u32 = 11;

/// Writes into disjoint positions of one slice from several threads.
#[derive(Clone, Copy)]
struct Scatter<T>(*mut T);
// SAFETY: the scatter of a pass writes every output position exactly once, from exactly one chunk (the offsets of
// the exclusive scan are disjoint ranges), and nothing reads the output before the pass ends.
unsafe impl<T: Send> Send for Scatter<T> {}
unsafe impl<T: Send> Sync for Scatter<T> {}

impl<T> Scatter<T> {
    /// # Safety
    /// `i` is in bounds of the slice the pointer came from, and no other thread writes or reads position `i`
    /// during the pass.
    #[inline]
    unsafe fn write(self, i: usize, v: T) {
        // SAFETY: see the function's contract.
        unsafe { self.0.add(i).write(v) }
    }
}

/// Sorts `v` stably by `key(x)`, which must be below `2^bits` (higher bits are ignored). Equal keys keep their
/// order in `v`.
pub(crate) fn sort_by_key<T, K>(v: &mut Vec<T>, bits: u32, key: K)
where
    T: Copy + Send + Sync + Default,
    K: Fn(&T) -> u64 + Sync,
{
    let n = v.len();
    let bits = bits.min(64);
    if n < SMALL || bits == 0 {
        let mask = if bits >= 64 { u64::MAX } else { (1u64 << bits) - 1 };
        v.sort_by_key(|x| key(x) & mask);
        return;
    }
    let passes = bits.div_ceil(MAX_DIGIT_BITS);
    let digit_bits = bits.div_ceil(passes);
    let buckets = 1usize << digit_bits;
    let mask = (buckets - 1) as u64;
    // The passes may cover more than `bits` bits (31 bits: three 11-bit digits); the bits above are ignored.
    let key_mask = if bits >= 64 { u64::MAX } else { (1u64 << bits) - 1 };
    let chunk = n.div_ceil(MAX_CHUNKS).max(MIN_CHUNK);
    let mut tmp: Vec<T> = vec![T::default(); n];
    let mut shift = 0;
    while shift < bits {
        let digit = |x: &T| (((key(x) & key_mask) >> shift) & mask) as usize;
        let mut counts: Vec<Vec<usize>> = v
            .par_chunks(chunk)
            .map(|c| {
                let mut h = vec![0usize; buckets];
                for x in c {
                    h[digit(x)] += 1;
                }
                h
            })
            .collect();
        // A digit shared by every element: this pass would keep the order.
        let single = (0..buckets).any(|d| counts.iter().map(|h| h[d]).sum::<usize>() == n);
        if !single {
            // Per chunk and digit, the range `offsets[d] .. ends[d]` of the output the scan reserves for the chunk's
            // elements of digit `d`.
            let mut ends = counts.clone();
            let mut at = 0;
            for d in 0..buckets {
                for (h, e) in counts.iter_mut().zip(ends.iter_mut()) {
                    let c = h[d];
                    h[d] = at;
                    at += c;
                    e[d] = at;
                }
            }
            let out = Scatter(tmp.as_mut_ptr());
            v.par_chunks(chunk).zip(counts.par_iter_mut()).zip(ends.par_iter()).for_each(|((c, offsets), ends)| {
                for x in c {
                    let d = digit(x);
                    // A key that changed between the count and the scatter (`key` not a pure function) would write
                    // outside the chunk's range: refused before it can.
                    assert!(offsets[d] < ends[d], "radix sort: the key of an element changed during the sort");
                    // SAFETY: `offsets[d] < ends[d]`, and the ranges `offsets[d] .. ends[d]` of all chunks and digits
                    // are disjoint and within `0 .. n = tmp.len()` (an exclusive scan of the counts); each position
                    // is written once, by the chunk that owns it.
                    unsafe { out.write(offsets[d], *x) };
                    offsets[d] += 1;
                }
            });
            std::mem::swap(v, &mut tmp);
        }
        shift += digit_bits;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: &mut u64) -> u64 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        *seed >> 11
    }

    #[test]
    fn equals_a_stable_sort_on_random_and_repeated_keys() {
        let mut seed = 7;
        for &(n, bits, range) in &[
            (0usize, 30u32, 1u64 << 30),
            (1, 30, 1 << 30),
            (100, 30, 1 << 30),
            (5000, 30, 1 << 30),
            (70_000, 30, 1 << 30),
            (70_000, 30, 16),
            (70_000, 30, 1),
            (300_000, 63, 1 << 63),
            (300_000, 63, 1000),
            (40_000, 7, 128),
        ] {
            let v: Vec<(u64, u32)> = (0..n).map(|i| (lcg(&mut seed) % range, i as u32)).collect();
            let mut expect = v.clone();
            expect.sort();
            let mut got = v;
            sort_by_key(&mut got, bits, |x| x.0);
            assert_eq!(got, expect, "n {n}, bits {bits}, range {range}");
        }
    }

    #[test]
    fn keys_packed_with_their_index_sort_by_the_high_bits_only() {
        let mut seed = 3;
        let v: Vec<u64> = (0..100_000u64).map(|i| ((lcg(&mut seed) % 5000) << 32) | i).collect();
        let mut expect = v.clone();
        expect.sort();
        let mut got = v;
        sort_by_key(&mut got, 30, |x| x >> 32);
        assert_eq!(got, expect);
    }

    #[test]
    fn bits_above_the_width_are_ignored_at_every_length() {
        // 31 bits take three 11-bit passes (33 bits): bit 31 and up must not take part, as on the small path.
        let mut seed = 5;
        for n in [1000usize, 50_000] {
            let v: Vec<(u64, u32)> = (0..n).map(|i| (lcg(&mut seed) % (1 << 40), i as u32)).collect();
            let mut expect = v.clone();
            expect.sort_by_key(|x| x.0 & ((1 << 31) - 1));
            let mut got = v;
            sort_by_key(&mut got, 31, |x| x.0);
            assert_eq!(got, expect, "n {n}");
        }
    }

    #[test]
    #[should_panic(expected = "the key of an element changed")]
    fn a_key_that_changes_during_the_sort_is_refused_not_written_out_of_range() {
        use std::sync::atomic::{AtomicU64, Ordering};
        let calls = AtomicU64::new(0);
        // Counted, a quarter of the keys are 1; scattered, every key is 1: more elements of digit 1 than the ranges
        // reserved for them.
        let n = 50_000u64;
        let mut v: Vec<u64> = (0..n).collect();
        sort_by_key(&mut v, 1, |x| u64::from(calls.fetch_add(1, Ordering::Relaxed) >= n || x % 4 == 0));
    }
}
