//! The two lookups [`crate::verify::decode`] makes for every record: a
//! position's bits to its id ([`PositionTable`]), and a triangle's sorted
//! corner ids to the caps triangle with those corners ([`TriangleIndex`]).
//!
//! Why not `HashMap`s: decoding the full Stanford dragon looks up 7.8M
//! positions (every caps corner, and every sides record's A, B and
//! opposite vertices) and 2.6M corner sets. In a general-purpose hash map
//! each lookup waits for a cache miss on a table larger than L2, and the
//! positions were first put in order by a comparison sort of all 2.6M caps
//! corners. Here the table is probed with the slot of the key `AHEAD`
//! positions on already prefetched, only the distinct positions are sorted,
//! and the triangles are listed under their smallest corner by a counting
//! sort, where a lookup reads one short list.

use crate::hint::prefetch;
use rayon::prelude::*;

/// Id of a position or triangle that is not there, and the free-slot mark.
pub(crate) const NONE: u32 = u32::MAX;

/// How many keys ahead the loops prefetch a slot.
const AHEAD: usize = 16;

/// Longest list of a smallest corner that [`TriangleIndex::first_copies`]
/// searches as it is; longer ones are sorted first.
const SHORT_LIST: usize = 16;

/// Keys per parallel block of [`PositionTable::ids`]; fixed, so the result
/// does not depend on the number of threads.
const BLOCK: usize = 1 << 14;

/// A position's key: the bits of its three coordinates.
pub(crate) type Key = [u32; 3];

/// Open-addressing table (linear probing) from a position's bits to its id,
/// at most half full. Each slot holds the key and the id (16 bytes), so a
/// probe reads one cache line.
#[derive(Debug)]
pub(crate) struct PositionTable {
    /// `[x, y, z, id]`; `id == NONE` marks a free slot.
    slots: Vec<[u32; 4]>,
    /// 64 − log2(slot count): the hash's top bits pick the home slot.
    shift: u32,
    /// Keys held.
    len: usize,
}

impl PositionTable {
    /// An empty table with room for `n` keys.
    fn with_room(n: usize) -> Self {
        let slots = (2 * n).next_power_of_two().max(64);
        PositionTable {
            slots: vec![[0, 0, 0, NONE]; slots],
            shift: 64 - slots.trailing_zeros(),
            len: 0,
        }
    }

    /// Home slot of `k`: a multiplicative hash of all 96 bits, whose top
    /// bits are well mixed (mesh coordinates share most of their bits).
    /// Each coordinate is multiplied on its own: with the first two joined
    /// into one 64-bit word, the key went through the stack and the CPU
    /// could not forward that word's load from the two 4-byte stores (a
    /// quarter of the numbering's samples, `perf annotate`), and the
    /// dragon's numbering took 54.7–73.1 ms instead of 37.5–38.4 (one
    /// thread, local timers, benches/ROUNDS.md, Forty-third round).
    #[inline(always)]
    fn home(&self, k: Key) -> usize {
        let h = u64::from(k[0]).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ u64::from(k[1]).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ u64::from(k[2]).wrapping_mul(0x1656_67B1_9E37_79F9);
        let h = (h ^ (h >> 29)).wrapping_mul(0xD6E8_FEB8_6659_FD93);
        (h >> self.shift) as usize
    }

    /// Prefetches the home slot of `k`.
    #[inline(always)]
    fn prefetch(&self, k: Key) {
        prefetch(&self.slots[self.home(k)]);
    }

    /// The slot holding `k`, or the free slot where it would go.
    #[inline(always)]
    fn find(&self, k: Key) -> usize {
        let mask = self.slots.len() - 1;
        let mut i = self.home(k);
        loop {
            let s = &self.slots[i];
            if s[3] == NONE || [s[0], s[1], s[2]] == k {
                return i;
            }
            i = (i + 1) & mask;
        }
    }

    /// The id of `k`, or [`NONE`].
    #[inline(always)]
    pub(crate) fn get(&self, k: Key) -> u32 {
        self.slots[self.find(k)][3]
    }

    /// Inserts every key not yet held, numbering them from 0 in order of
    /// first occurrence, and writes each key's number to `ids` (as long as
    /// the keys; `key(i)` is the i-th key). Returns the table and the
    /// distinct keys in that order.
    pub(crate) fn number(key: impl Fn(usize) -> Key, ids: &mut [u32]) -> (Self, Vec<Key>) {
        let n = ids.len();
        // Closed meshes have about one distinct position per six corners;
        // the table doubles when that guess is short.
        let mut t = PositionTable::with_room(n / 6);
        let mut distinct = Vec::new();
        for (i, out) in ids.iter_mut().enumerate() {
            if i + AHEAD < n {
                t.prefetch(key(i + AHEAD));
            }
            let k = key(i);
            let s = t.find(k);
            *out = if t.slots[s][3] == NONE {
                let id = distinct.len() as u32;
                t.slots[s] = [k[0], k[1], k[2], id];
                distinct.push(k);
                t.len += 1;
                if 2 * t.len > t.slots.len() {
                    t.grow();
                }
                id
            } else {
                t.slots[s][3]
            };
        }
        (t, distinct)
    }

    /// Doubles the slots and re-inserts every key.
    fn grow(&mut self) {
        let old = std::mem::replace(self, PositionTable::with_room(self.slots.len()));
        for s in old.slots.into_iter().filter(|s| s[3] != NONE) {
            let i = self.find([s[0], s[1], s[2]]);
            self.slots[i] = s;
        }
        self.len = old.len;
    }

    /// Replaces every held id `i` by `new[i]`.
    pub(crate) fn renumber(&mut self, new: &[u32]) {
        self.slots.par_chunks_mut(BLOCK).for_each(|c| {
            c.iter_mut()
                .filter(|s| s[3] != NONE)
                .for_each(|s| s[3] = new[s[3] as usize])
        });
    }

    /// The ids of `n` keys ([`NONE`] for those not held), looked up in
    /// parallel blocks with the slots prefetched ahead.
    pub(crate) fn ids(&self, n: usize, key: impl Fn(usize) -> Key + Sync) -> Vec<u32> {
        let mut out = vec![0u32; n];
        out.par_chunks_mut(BLOCK).enumerate().for_each(|(b, out)| {
            let first = b * BLOCK;
            let end = first + out.len();
            for (i, o) in (first..end).zip(out) {
                if i + AHEAD < end {
                    self.prefetch(key(i + AHEAD));
                }
                *o = self.get(key(i));
            }
        });
        out
    }
}

/// The caps triangles listed under their smallest corner id, each with its
/// other two corner ids, its number and the parity of its corners' sort:
/// the same answers as a map from sorted corner ids to the first triangle
/// with those corners, from a counting sort instead of hashing.
#[derive(Debug)]
pub(crate) struct TriangleIndex {
    /// `start[v]..start[v + 1]`: the entries of smallest corner `v`.
    start: Vec<u32>,
    /// `[second id, third id, triangle, parity (1 even, u32::MAX odd)]`, in
    /// triangle order within each list.
    entries: Vec<[u32; 4]>,
}

impl TriangleIndex {
    /// Lists the triangles of `caps` (corner ids below `positions`, or
    /// [`NONE`]) whose three corners are distinct known ids.
    pub(crate) fn new(caps: &[[u32; 3]], positions: usize) -> Self {
        let sorted = |c: [u32; 3]| {
            let (k, odd) = crate::evaluate_indexed::sort_ids(c);
            let valid = k[0] != k[1] && k[1] != k[2] && k[2] != NONE;
            (k, odd, valid)
        };
        let mut start = vec![0u32; positions + 1];
        for &c in caps {
            let (k, _, valid) = sorted(c);
            if valid {
                start[k[0] as usize + 1] += 1;
            }
        }
        for v in 0..positions {
            start[v + 1] += start[v];
        }
        let mut fill = start.clone();
        let mut entries = vec![[0u32; 4]; start[positions] as usize];
        for (t, &c) in caps.iter().enumerate() {
            let (k, odd, valid) = sorted(c);
            if valid {
                let at = &mut fill[k[0] as usize];
                entries[*at as usize] = [k[1], k[2], t as u32, if odd { u32::MAX } else { 1 }];
                *at += 1;
            }
        }
        TriangleIndex { start, entries }
    }

    /// Per caps triangle (`n` of them, as given to [`TriangleIndex::new`]):
    /// the first triangle with the same sorted corner ids, which
    /// [`TriangleIndex::get`] of them answers, or [`NONE`] for one not
    /// listed (its corners not three distinct known ids). One pass over the
    /// lists in order: `get` per triangle in caps order read a list
    /// anywhere, and the index and those lookups took 41.8–43.5 ms of the
    /// dragon's decode, against 23.2–25.0 for the index and this (one
    /// thread, local timers, three alternated runs, benches/ROUNDS.md,
    /// Forty-fourth round). A list longer than [`SHORT_LIST`] is sorted by
    /// corners first, so a vertex that is the smallest corner of many
    /// triangles (a fan in a damaged file) does not take time quadratic in
    /// them.
    pub(crate) fn first_copies(&self, n: usize) -> Vec<u32> {
        let mut first = vec![NONE; n];
        let mut long = Vec::new();
        for w in self.start.windows(2) {
            let list = &self.entries[w[0] as usize..w[1] as usize];
            if list.len() <= SHORT_LIST {
                for (i, e) in list.iter().enumerate() {
                    let f = list[..i].iter().find(|f| f[..2] == e[..2]).unwrap_or(e);
                    first[e[2] as usize] = f[2];
                }
            } else {
                // The list's triangles by corners, then by number.
                long.clear();
                long.extend(list.iter().map(|e| [e[0], e[1], e[2]]));
                long.sort_unstable();
                for same in long.chunk_by(|a, b| a[..2] == b[..2]) {
                    for e in same {
                        first[e[2] as usize] = same[0][2];
                    }
                }
            }
        }
        first
    }

    /// The first triangle (in caps order) whose sorted corner ids are `k`,
    /// with the parity of its corners' sort (+1 even, −1 odd).
    #[inline]
    pub(crate) fn get(&self, k: [u32; 3]) -> Option<(u32, i8)> {
        if k[2] == NONE {
            return None;
        }
        let v = k[0] as usize;
        self.entries[self.start[v] as usize..self.start[v + 1] as usize]
            .iter()
            .find(|e| e[0] == k[1] && e[1] == k[2])
            .map(|e| (e[2], e[3] as i32 as i8))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    /// Keys drawn from a small pool, so most repeat, with both zeros and
    /// NaN bits among them.
    fn keys(n: usize, pool: u32, seed: u64) -> Vec<Key> {
        let mut bits = crate::multiplicity::test_bits(seed);
        (0..n)
            .map(|_| {
                let r = (bits() >> 40) as u32 % pool;
                match r % 17 {
                    0 => [0x8000_0000, r, 0],
                    1 => [0, r, 0x7fc0_0001],
                    _ => [r.wrapping_mul(0x9E37_79B9), r / 3, r % 5],
                }
            })
            .collect()
    }

    #[test]
    fn numbering_and_lookups_match_a_hash_map() {
        for (n, pool) in [
            (0, 1),
            (1, 1),
            (5000, 100),
            (200_000, 60_000),
            (70_000, 1 << 30),
        ] {
            let k = keys(n, pool, 0x1234_5678 + n as u64);
            let mut ids = vec![0u32; n];
            let (mut table, distinct) = PositionTable::number(|i| k[i], &mut ids);
            // First-occurrence numbering, as a map builds it.
            let mut map: HashMap<Key, u32> = HashMap::new();
            let mut expected_distinct = Vec::new();
            for key in &k {
                let next = map.len() as u32;
                map.entry(*key).or_insert_with(|| {
                    expected_distinct.push(*key);
                    next
                });
            }
            assert_eq!(distinct, expected_distinct);
            assert_eq!(ids, k.iter().map(|key| map[key]).collect::<Vec<_>>());
            // Renumbered (reversed) and looked up, with absent keys mixed in.
            let rev: Vec<u32> = (0..distinct.len() as u32).rev().collect();
            table.renumber(&rev);
            let probe = keys(n + 3000, pool.saturating_mul(2), 99);
            let got = table.ids(probe.len(), |i| probe[i]);
            let want: Vec<u32> = probe
                .iter()
                .map(|key| map.get(key).map_or(NONE, |&i| rev[i as usize]))
                .collect();
            assert_eq!(got, want, "{n} keys");
            if n > 1000 {
                assert!(want.contains(&NONE) && want.iter().any(|&i| i != NONE));
            }
        }
    }

    /// The first 3,000 of `caps` with the ids of triangle `t` moved up by
    /// `40 · (t % 75)`, then the first 1,000 of those again: the same
    /// triangles repeat, but the lists of 3,000 positions are short.
    fn spread(caps: &[[u32; 3]]) -> Vec<[u32; 3]> {
        let moved: Vec<[u32; 3]> = caps[..3000]
            .iter()
            .enumerate()
            .map(|(t, c)| {
                c.map(|i| {
                    if i == NONE {
                        NONE
                    } else {
                        i + 40 * (t as u32 % 75)
                    }
                })
            })
            .collect();
        [&moved[..], &moved[..1000]].concat()
    }

    #[test]
    fn triangle_index_finds_the_first_triangle_with_the_corners() {
        let mut bits = crate::multiplicity::test_bits(0xabcdef);
        let n = 40u32;
        let mut caps: Vec<[u32; 3]> = (0..5000)
            .map(|_| {
                let mut c = [0; 3];
                for v in &mut c {
                    *v = (bits() >> 40) as u32 % n;
                }
                c
            })
            .collect();
        caps.push([3, NONE, 4]);
        caps.push([NONE, NONE, NONE]);
        let index = TriangleIndex::new(&caps, n as usize);
        let mut map: HashMap<[u32; 3], (u32, i8)> = HashMap::new();
        for (t, c) in caps.iter().enumerate() {
            let (k, odd) = crate::evaluate_indexed::sort_ids(*c);
            if k[0] != k[1] && k[1] != k[2] && k[2] != NONE {
                map.entry(k).or_insert((t as u32, if odd { -1 } else { 1 }));
            }
        }
        let mut found = 0;
        for a in 0..n {
            for b in a..n {
                for c in b..n {
                    assert_eq!(index.get([a, b, c]), map.get(&[a, b, c]).copied());
                    found += usize::from(map.contains_key(&[a, b, c]));
                }
            }
            assert_eq!(index.get([a, a + 1, NONE]), None);
        }
        assert!(found > 1000, "{found}");
        assert!(map.values().any(|v| v.1 == -1) && map.values().any(|v| v.1 == 1));
        // Each triangle's first copy, as `get` finds it: with 40 positions
        // the lists are long (sorted first), with 3,000 short.
        for (n, caps) in [(n, caps.clone()), (3000, spread(&caps))] {
            let index = TriangleIndex::new(&caps, n as usize);
            let first = index.first_copies(caps.len());
            let (mut copies, mut long, mut short) = (0, 0, 0);
            for (t, c) in caps.iter().enumerate() {
                let (k, _) = crate::evaluate_indexed::sort_ids(*c);
                let want = index.get(k).map_or(NONE, |f| f.0);
                assert_eq!(first[t], want, "triangle {t} of {}", caps.len());
                copies += usize::from(want != NONE && want != t as u32);
            }
            for w in index.start.windows(2) {
                let len = (w[1] - w[0]) as usize;
                long += usize::from(len > SHORT_LIST);
                short += usize::from((2..=SHORT_LIST).contains(&len));
            }
            assert!(copies > 100, "{copies}");
            if n == 40 {
                assert!(long > 10, "{long}");
            } else {
                assert!(short > 500 && long < 10, "{short} {long}");
            }
        }
    }
}
