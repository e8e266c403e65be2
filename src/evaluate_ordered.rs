//! The shared evaluation of [`Strategy::Reference`](crate::evaluate::Strategy)
//! (each caps triangle's sign once, then every side record as the signed
//! sum of its triangles' signs) with the triangles numbered in the order the
//! side records first name them.
//!
//! Why: the side records are in (A, B) order (format-spec §4.1), a sweep
//! along x; the caps are in input order. A record's slots read its
//! triangles' signs, and from a table in input order each read lands
//! anywhere in it: on the 871k-triangle dragon, 2.6M reads scattered over
//! 871 KB, nearly every one a first-level cache miss, most of the sides'
//! time. Numbered in the order the records first name them, the triangles
//! of 16 consecutive records lie within a few thousand numbers of each
//! other (on the dragon, every block of 16 within 16,384), so the reads hit
//! the first-level cache, and each slot's number fits 16 bits over a base
//! per block. The caps' corners, renumbered in the same order, are closer
//! too. The caller still gets the signs in input order: one scattered
//! access per triangle, a third as many as the reads it replaces, but
//! each still a first-level cache miss, which takes most of what the
//! sides gain. For one light it is a read (each triangle of the input
//! order reads its sign through its evaluation number); for a group of
//! lights a write (see [`OrderedEvaluation::group_cap_signs`]).
//!
//! On the dragon, one thread (`cargo run --release --example stage_probe
//! -- evaluate target/dragon/dragon.glb`, its `auto` and `input order`
//! rows: fastest / median of 40 alternated rounds, five runs, on an AMD
//! EPYC, Zen 4, twenty-sixth round, with one light's signs still written
//! to input order): the whole evaluation 3.01–3.48 / 3.33–3.83 ms here
//! against 2.97–3.67 / 3.46–4.34 ms with the same kernels in input order,
//! which took 0.99–1.06× this path's time at the fastest and 1.02–1.13× at
//! the median; the caps alone 1.31–1.44 against 1.51–1.72 ms at the
//! fastest. Local probes put the rest at about 0.45 ms for the scattered
//! writes and 0.85 ms for the sides (2.3–2.5 ms for the sides in input
//! order with their gathers, the caps computed once). Reading the signs
//! back instead of writing them took 4.6–12.6% off the whole (thirtieth
//! round, see [`OrderedEvaluation::cap_signs`]). Thirty-seventh round:
//! 2.21–2.32 ms at the fastest, 1.69–1.77 ns per side record (the caps'
//! kernel in 256-bit AVX-512 code, `evaluate_indexed::Kernel`, and the
//! three streams prefetched, `hint::prefetch_stream`: the caps'
//! corner ids, the evaluation numbers of the reads into input order, the
//! sides' offsets).
//!
//! Per light:
//! 1. The caps, in evaluation order ([`IndexedCaps`] over the triangles
//!    renumbered so): each sign `s` of triangle `i` is written as the pair
//!    `(s, −s)` at `2i, 2i + 1` of the *signed* table, and reaches the
//!    triangle's place in input order.
//! 2. The sides: slot `j` of a record stores `2i + odd` (its triangle and
//!    whether its corners are an odd permutation of the triangle's, see
//!    `verify::DecodedBucket::slot_parity`) less its block's base, so its
//!    contribution `parity · s` is one byte of the signed table, and the
//!    record's multiplicity is the sum of its slots' bytes.
//!
//! The sums are integers of at most `k` terms −1, 0, +1, added with i8
//! wrapping: the same bits as the plain path's i32 sum truncated to i8
//! ([`crate::evaluate_simd::try_sides_from_caps`]), and the signs are
//! [`IndexedCaps`]'s, so the results are bit for bit the other paths'; the
//! tests compare them. Records the tables cannot hold (a slot that names no
//! triangle, in a damaged file; a block whose slots span more than 16 bits;
//! the last records of a bucket, fewer than a block) are left to the caller,
//! listed by [`OrderedEvaluation::leftovers`].
//!
//! A group of [`LIGHT_GROUP`] lights goes through the same steps once
//! ([`OrderedEvaluation::group_cap_signs`], then
//! [`OrderedEvaluation::group_sides`]): the caps kernel gathers and
//! transposes each block's corners once for the four lights and writes
//! their signs as one `u32` per pair entry, a byte per light, biased by one
//! so that a record's slots add as plain integers without carries; the
//! sides read one entry per slot for the four lights; the signs go to input
//! order as one byte per triangle, two bits per light, read back through
//! the triangle's evaluation number as for one light. On the dragon, one
//! thread (twenty-eighth round, an AMD EPYC, when the signs went to input
//! order as one `u32` per triangle): 1.22–1.27 ns per side record per
//! light at the fastest, against 2.43–2.55 ns for the same lights one at a
//! time (`cargo run --release --example stage_probe -- evaluate
//! target/dragon/dragon.glb`, its `four lights` lines, four runs; the caps
//! alone 0.61–0.64 against 1.11–1.26 ms per light; a local probe put the
//! sides at 0.5 ms per light against 0.85 ms). For the byte per triangle,
//! see [`OrderedEvaluation::group_cap_signs`].

use crate::evaluate_indexed::{IndexedCaps, LIGHT_GROUP, chunks_of};
use crate::multiplicity::Light;
use crate::verify::UNKNOWN;
use rayon::prelude::*;
use std::ops::Range;

/// Records per block: each block has one base for its slots' 16-bit offsets.
pub const BLOCK: usize = 16;

/// Triangles per call of the caps kernel, and side records per rayon
/// task (a multiple of [`BLOCK`]).
const CHUNK: usize = 4096;

/// Evaluation numbers per 64-byte line.
const LINE: usize = 16;

/// Base of a block the tables do not hold.
const NOT_PACKED: u32 = u32::MAX;

/// Base of a block whose slots span more than 16 bits of the signed table:
/// its slots' indices are whole `u32`s in [`PackedSlots::wide`], from the
/// index its first offset word holds. No base of a packed block is this
/// large: `new` declines 2^31 triangles or more, so every signed-table
/// index is below 2^32 − 2.
const WIDE: u32 = u32::MAX - 1;

/// One sides bucket's slots as offsets into the signed table.
#[derive(Debug, Clone)]
struct PackedSlots {
    /// Opposite slots per record.
    k: usize,
    /// Per block of [`BLOCK`] records: the smallest signed-table index its
    /// slots read, or [`WIDE`], or [`NOT_PACKED`].
    base: Vec<u32>,
    /// Per slot of every whole block: its signed-table index less the
    /// block's base (0 in blocks not packed), 16 bits each, four to a word
    /// ([`offset`]); a [`WIDE`] block's first word is where its indices
    /// start in `wide`.
    offsets: Vec<u64>,
    /// The signed-table index of every slot of the [`WIDE`] blocks, block
    /// after block.
    ///
    /// Why: on the 5M scene, whose parts lie side by side along x, 15% of
    /// the side records were in blocks spanning more than 16 bits, and the
    /// caller evaluated them record by record from the records' floats
    /// (`evaluate_simd::try_sides_from_caps`): 28% of a profile of its
    /// evaluation, against 9% for the caps kernel.
    wide: Vec<u32>,
    /// Record ranges the tables do not hold, in order.
    leftovers: Vec<Range<usize>>,
}

/// The caps in the order the side records first name them, and each
/// bucket's slots as offsets into the per-light signed table. Built once
/// per file by [`OrderedEvaluation::new`]; per light,
/// [`OrderedEvaluation::cap_signs`] then [`OrderedEvaluation::sides`].
#[derive(Debug, Clone)]
pub struct OrderedEvaluation {
    /// The caps triangles in evaluation order.
    caps: IndexedCaps,
    /// Per evaluation number: the triangle's number in input order.
    order: Vec<u32>,
    /// Per triangle in input order: its evaluation number (the inverse of
    /// `order`), which one light's signs are read back through
    /// ([`OrderedEvaluation::cap_signs`]).
    rank: Vec<u32>,
    /// Per sides bucket, in the file's order.
    buckets: Vec<PackedSlots>,
}

/// One bucket's slots as `verify::DecodedBucket` has them: opposite slots
/// per record, each slot's caps triangle in input order (`u32::MAX` for
/// none) and its parity (±1, 0 with no triangle).
pub type Slots<'a> = (usize, &'a [u32], &'a [i8]);

impl OrderedEvaluation {
    /// Numbers the triangles of `caps` (corner ids into `positions`) in the
    /// order `buckets`' slots first name them, the rest after them in input
    /// order, and packs the slots. `None` when [`IndexedCaps::new`]
    /// declines the table (then callers evaluate the records), when there
    /// are 2^31 triangles or more, when a slot names a triangle past
    /// `caps`, or when a bucket has no slots per record (which
    /// `format::read_file` does not accept).
    pub fn new(positions: &[[f32; 3]], caps: &[[u32; 3]], buckets: &[Slots]) -> Option<Self> {
        let n = caps.len();
        if n >= 1 << 31 || buckets.iter().any(|&(k, ..)| k == 0) {
            return None;
        }
        // rank[t]: triangle t's evaluation number; order: its inverse.
        let mut rank = vec![u32::MAX; n];
        let mut order = Vec::with_capacity(n);
        for &(_, tri, _) in buckets {
            for &t in tri.iter().filter(|&&t| t != UNKNOWN) {
                let r = rank.get_mut(t as usize)?;
                if *r == u32::MAX {
                    *r = order.len() as u32;
                    order.push(t);
                }
            }
        }
        for (t, r) in rank.iter_mut().enumerate() {
            if *r == u32::MAX {
                *r = order.len() as u32;
                order.push(t as u32);
            }
        }
        let in_order: Vec<[u32; 3]> = order.iter().map(|&t| caps[t as usize]).collect();
        let caps = IndexedCaps::new(positions, &in_order)?;
        drop(in_order);
        let buckets = buckets
            .iter()
            .map(|&(k, tri, parity)| pack(k, tri, parity, &rank))
            .collect();
        Some(OrderedEvaluation {
            caps,
            order,
            rank,
            buckets,
        })
    }

    /// The caps in evaluation order: [`IndexedCaps::cap_signs`] gives
    /// their signs in that order.
    pub fn caps(&self) -> &IndexedCaps {
        &self.caps
    }

    /// Per evaluation number: the triangle's number in input order.
    pub fn order(&self) -> &[u32] {
        &self.order
    }

    /// Per triangle in input order: its evaluation number (the inverse of
    /// [`OrderedEvaluation::order`]).
    pub fn rank(&self) -> &[u32] {
        &self.rank
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// True when there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// Sign of every caps triangle for light `l`: into `out` in input order
    /// (`out.len()` must be [`OrderedEvaluation::len`]), and into `scratch`
    /// (resized to three times that): first the pairs
    /// [`OrderedEvaluation::sides`] reads, then the signs in evaluation
    /// order.
    ///
    /// The signs are computed in one pass, then paired in a second, and
    /// put in input order in a third, which reads each triangle's sign
    /// through its evaluation number (`rank`): the reads land anywhere in
    /// the signs (871 KB on the dragon), but in the second-level cache,
    /// and the writes go in order. Until the thirtieth round each sign
    /// was written to its place instead, in the pairing pass (done per
    /// chunk right after the signs, those writes had made the whole
    /// evaluation slower, benches/ROUNDS.md, Twenty-sixth round). The
    /// reads against those writes, the dragon's whole one-light
    /// evaluation, fastest of 40 alternated rounds, six alternations of
    /// the two binaries (`cargo run --release --example stage_probe --
    /// evaluate target/dragon/dragon.glb`, its `auto` row): 2.608–2.880
    /// against 2.776–3.135 ms, 4.6–12.6% less in each pair. The group's
    /// table is a `u32` per triangle, 7 MB on the dragon, and there the
    /// reads were slower than the writes (benches/ROUNDS.md,
    /// Twenty-eighth round).
    pub fn cap_signs(&self, l: Light, scratch: &mut Vec<i8>, out: &mut [i8]) {
        let n = self.order.len();
        assert_eq!(out.len(), n, "caps size mismatch");
        scratch.resize(3 * n, 0);
        let (pairs, signs) = scratch.split_at_mut(2 * n);
        self.caps.cap_signs(l, signs);
        pairs
            .par_chunks_mut(2 * CHUNK)
            .zip(signs.par_chunks(CHUNK))
            .for_each(|(pairs, signs)| {
                for (p, &s) in pairs.chunks_exact_mut(2).zip(signs) {
                    p[0] = s;
                    p[1] = s.wrapping_neg();
                }
            });
        let signs = &*signs;
        out.par_chunks_mut(CHUNK)
            .zip(self.rank.par_chunks(CHUNK))
            // SAFETY: `rank` is a permutation of 0..n (`new` numbers each
            // triangle once), and `signs` holds n signs.
            .for_each(|(out, rank)| unsafe { read_back(signs, rank, out) });
    }

    /// [`OrderedEvaluation::cap_signs`] for a group of [`LIGHT_GROUP`]
    /// lights, light `i`'s signs into `out[i]` in input order: computed in
    /// one pass over the triangles, which writes them as the group's signed
    /// table in `scratch` ([`IndexedCaps::cap_sign_pairs`]), the table
    /// [`OrderedEvaluation::group_sides`] reads. The same bits as a call
    /// of `cap_signs` per light.
    ///
    /// The table has the pair layout of the one-light scratch, a `u32` per
    /// entry with one byte per light: entry `2i` holds `1 + s` of each
    /// light's sign `s` of triangle `i`, entry `2i + 1` holds `1 − s`. Biased
    /// so that no byte is negative: a record of `k ≤ 127` slots sums its
    /// entries as plain `u32`s, each byte at most `2k` with no carry into
    /// the next, and subtracts `k` from each byte. One load and one add
    /// per slot for the four lights, where the one-light sums take a load
    /// and an add per slot per light.
    ///
    /// To input order as for one light: a pass in input order reads each
    /// triangle's signs through its evaluation number (`rank`), from a
    /// byte per triangle that holds the four lights' `1 + s` in two bits
    /// each (871 KB on the dragon, small enough for this Xeon's 1.25 MiB
    /// second-level cache), and writes the four lights' arrays in order.
    /// Until the fifty-seventh round each
    /// triangle's `1 + s` entry (a `u32`, read in order from the 7 MB
    /// table) was written to its place in a table in input order, and the
    /// lights' arrays were cut from that: on the dragon, one thread, a
    /// local probe put that scatter at 2.24 ms and the cut at 0.75 ms per
    /// group, where the byte per triangle costs 0.2 ms more in the caps
    /// pass and its read-back 0.99 ms. The whole evaluation, four lights
    /// at once, per light, fastest of 40 alternated rounds, five
    /// alternations (`cargo run --release --example stage_probe --
    /// evaluate target/dragon/dragon.glb`, its `four lights` line; an Intel
    /// Xeon; benches/ROUNDS.md, Fifty-seventh round): 2.19–2.47 → 1.70–1.79
    /// ms (1.67–1.89 → 1.30–1.37 ns per side record), 1.33–1.43 → 1.86–2.05
    /// times as fast as the same lights one at a time in the same runs.
    pub fn group_cap_signs(
        &self,
        lights: &[Light; LIGHT_GROUP],
        scratch: &mut GroupScratch,
        out: [&mut [i8]; LIGHT_GROUP],
    ) {
        let n = self.order.len();
        for o in &out {
            assert_eq!(o.len(), n, "caps size mismatch");
        }
        scratch.table.resize(2 * n, 0);
        scratch.packed.resize(n, 0);
        self.caps
            .cap_sign_pairs(lights, &mut scratch.table, &mut scratch.packed);
        let packed = &scratch.packed[..];
        // A chunk's bytes first, then each light's array from them: the
        // read-back loop as tight as one light's, and the unpacking a loop
        // over bytes in order.
        chunks_of(out, CHUNK)
            .into_par_iter()
            .zip(self.rank.par_chunks(CHUNK))
            .for_each(|(mut out, rank)| {
                let mut bytes = [0u8; CHUNK];
                let bytes = &mut bytes[..rank.len()];
                // SAFETY: `rank` is a permutation of 0..n (`new` numbers
                // each triangle once), and `packed` holds n bytes.
                unsafe { read_back(packed, rank, bytes) };
                for (l, out) in out.iter_mut().enumerate() {
                    for (o, &b) in out.iter_mut().zip(&*bytes) {
                        *o = (b >> (2 * l) & 3) as i8 - 1;
                    }
                }
            });
    }

    /// [`OrderedEvaluation::sides`] for the group of lights whose table
    /// [`OrderedEvaluation::group_cap_signs`] left in `scratch`: light `i`'s
    /// multiplicities into `out[i]`; the records of
    /// [`OrderedEvaluation::leftovers`] are left as they are.
    pub fn group_sides(
        &self,
        bucket: usize,
        scratch: &GroupScratch,
        out: [&mut [i8]; LIGHT_GROUP],
    ) {
        let b = &self.buckets[bucket];
        let table = &scratch.table[..];
        assert_eq!(table.len(), 2 * self.order.len(), "scratch size mismatch");
        for o in &out {
            assert_eq!(o.len() / BLOCK, b.base.len(), "bucket size mismatch");
        }
        let k = b.k;
        chunks_of(out, CHUNK)
            .into_par_iter()
            .zip(b.base.par_chunks(CHUNK / BLOCK))
            .zip(b.offsets.par_chunks(CHUNK * k / SLOTS_PER_WORD))
            .for_each(|((out, base), offsets)| {
                let slots = Blocks {
                    base,
                    offsets,
                    wide: &b.wide,
                };
                // SAFETY: every packed block's base + offset, and every
                // index of `wide`, is below 2 · len() (`pack`), which is
                // table.len() (asserted).
                unsafe {
                    match k {
                        1 => group_blocks(1, table, slots, out),
                        2 => group_blocks(2, table, slots, out),
                        3 => group_blocks(3, table, slots, out),
                        4 => group_blocks(4, table, slots, out),
                        5 => group_blocks(5, table, slots, out),
                        _ => group_blocks(k, table, slots, out),
                    }
                }
            });
    }

    /// Multiplicities of bucket `bucket`'s records from the signed pairs in
    /// the scratch of [`OrderedEvaluation::cap_signs`] (for the same light),
    /// into `out` (one per record); the records of
    /// [`OrderedEvaluation::leftovers`] are left as they are.
    pub fn sides(&self, bucket: usize, scratch: &[i8], out: &mut [i8]) {
        let b = &self.buckets[bucket];
        let n = self.order.len();
        assert_eq!(scratch.len(), 3 * n, "scratch size mismatch");
        let signed = &scratch[..2 * n];
        assert_eq!(out.len() / BLOCK, b.base.len(), "bucket size mismatch");
        let k = b.k;
        out.par_chunks_mut(CHUNK)
            .zip(b.base.par_chunks(CHUNK / BLOCK))
            .zip(b.offsets.par_chunks(CHUNK * k / SLOTS_PER_WORD))
            .for_each(|((out, base), offsets)| {
                let slots = Blocks {
                    base,
                    offsets,
                    wide: &b.wide,
                };
                // SAFETY: every packed block's base + offset, and every
                // index of `wide`, is below 2 · len() (`pack`), which is
                // signed.len() (asserted).
                unsafe {
                    match k {
                        1 => blocks(1, signed, slots, out),
                        2 => blocks(2, signed, slots, out),
                        3 => blocks(3, signed, slots, out),
                        4 => blocks(4, signed, slots, out),
                        5 => blocks(5, signed, slots, out),
                        _ => blocks(k, signed, slots, out),
                    }
                }
            });
    }

    /// Record ranges of bucket `bucket` that [`OrderedEvaluation::sides`]
    /// leaves to the caller, in order.
    pub fn leftovers(&self, bucket: usize) -> &[Range<usize>] {
        &self.buckets[bucket].leftovers
    }
}

/// The scratch of a group of lights: the group's signed table in
/// evaluation order, and its signs as a byte per triangle, also in
/// evaluation order (see [`OrderedEvaluation::group_cap_signs`]). Kept
/// between groups like the other buffers.
#[derive(Debug, Clone, Default)]
pub struct GroupScratch {
    table: Vec<u32>,
    packed: Vec<u8>,
}

/// `out[i] = table[rank[i]]` for every `i` of `out` (as long as `rank`):
/// a table in evaluation order read back into input order, a line of
/// evaluation numbers at a time, the stream prefetched
/// (`hint::prefetch_stream`). One light's signs and a group's bytes.
///
/// # Safety
/// Every element of `rank` must be below `table.len()`.
#[inline(always)]
unsafe fn read_back<T: Copy>(table: &[T], rank: &[u32], out: &mut [T]) {
    for (out, rank) in out.chunks_mut(LINE).zip(rank.chunks(LINE)) {
        crate::hint::prefetch_stream(rank.as_ptr());
        for (o, &r) in out.iter_mut().zip(rank) {
            // SAFETY: the caller's.
            *o = unsafe { *table.get_unchecked(r as usize) };
        }
    }
}

/// The slots of one bucket as offsets over a base per block of [`BLOCK`]
/// records; `rank` gives each triangle's evaluation number.
fn pack(k: usize, tri: &[u32], parity: &[i8], rank: &[u32]) -> PackedSlots {
    let per_block = BLOCK * k;
    let (blocks, records) = (tri.len() / per_block, tri.len() / k);
    let mut base = vec![NOT_PACKED; blocks];
    let mut offsets = vec![0u64; blocks * per_block / SLOTS_PER_WORD];
    let mut wide = Vec::new();
    let mut leftovers: Vec<Range<usize>> = Vec::new();
    let mut leave = |r: Range<usize>| match leftovers.last_mut() {
        Some(last) if last.end == r.start => last.end = r.end,
        _ => leftovers.push(r),
    };
    // A slot's signed-table index: 2 · its triangle's number, + 1 when odd.
    let index = |t: u32, p: i8| match (t, p) {
        (UNKNOWN, _) | (_, 0) => None,
        (t, p) => Some(2 * rank[t as usize] + u32::from(p < 0)),
    };
    for (b, base) in base.iter_mut().enumerate() {
        let at = b * per_block..(b + 1) * per_block;
        let (tri, parity) = (&tri[at.clone()], &parity[at.clone()]);
        let span = tri
            .iter()
            .zip(parity)
            .try_fold((u32::MAX, 0), |(lo, hi), (&t, &p)| {
                index(t, p).map(|i| (lo.min(i), hi.max(i)))
            });
        let words = &mut offsets[b * per_block / SLOTS_PER_WORD..][..per_block / SLOTS_PER_WORD];
        // (Some below: every slot of the block was checked by `span`.)
        match span {
            Some((lo, hi)) if hi - lo <= u16::MAX as u32 => {
                *base = lo;
                for (i, (&t, &p)) in tri.iter().zip(parity).enumerate() {
                    let o = u64::from(index(t, p).unwrap() - lo);
                    words[i / SLOTS_PER_WORD] |= o << (16 * (i % SLOTS_PER_WORD));
                }
            }
            Some(_) => {
                *base = WIDE;
                words[0] = wide.len() as u64;
                wide.extend(tri.iter().zip(parity).map(|(&t, &p)| index(t, p).unwrap()));
            }
            None => leave(b * BLOCK..(b + 1) * BLOCK),
        }
    }
    if records > blocks * BLOCK {
        leave(blocks * BLOCK..records);
    }
    PackedSlots {
        k,
        base,
        offsets,
        wide,
        leftovers,
    }
}

/// Slots' offsets per `u64` of [`PackedSlots::offsets`]: four records
/// (`k` slots each) take `k` whole words.
const SLOTS_PER_WORD: usize = 4;

/// Offset `i` of `words` (a block's, or four records'): 16 bits of word
/// `i / 4`.
///
/// Why words: a record's slots cost a load of the offset and a load of
/// the byte it names, and with `u16` offsets those loads were most of the
/// sides' instructions; now one load serves four offsets, and shifts take
/// them apart. The dragon's whole one-light evaluation, one thread,
/// fastest of 40 alternated rounds, five alternations of the two binaries
/// (`cargo run --release --example stage_probe -- evaluate
/// target/dragon/dragon.glb`, its `auto` row): 2.75–2.86 ms with `u16`
/// offsets, 2.48–2.61 ms with words; the sides alone 0.84 → 0.71 ms (a
/// local probe); four lights at once 1.51–1.57 → 1.43–1.53 ms per light
/// (benches/ROUNDS.md, Thirty-second round).
#[inline(always)]
fn offset(words: &[u64], i: usize) -> usize {
    ((words[i / SLOTS_PER_WORD] >> (16 * (i % SLOTS_PER_WORD))) & 0xFFFF) as usize
}

/// [`crate::hint::prefetch_stream`] of each line of a block's offsets
/// (`BLOCK · k` of 2 bytes): the sides read them in order, and the
/// hardware's prefetch alone left the loops waiting on them (as the
/// build's passes, see `STREAM_AHEAD`).
#[inline(always)]
fn prefetch_offsets(block: &[u64]) {
    for line in block.chunks(8) {
        crate::hint::prefetch_stream(line.as_ptr());
    }
}

/// A run of blocks of one bucket, as a rayon task of the sides takes them:
/// their bases and offset words, and the bucket's [`PackedSlots::wide`].
#[derive(Clone, Copy)]
struct Blocks<'a> {
    base: &'a [u32],
    offsets: &'a [u64],
    wide: &'a [u32],
}

/// The signed-table indices of a [`WIDE`] block's slots, whose first offset
/// word is `words[0]`.
///
/// # Safety
/// `words` must be a [`WIDE`] block's offset words and `wide` its bucket's
/// (`pack` stores `BLOCK · k` indices from the one the word holds).
#[inline(always)]
unsafe fn wide_slots<'a>(k: usize, wide: &'a [u32], words: &[u64]) -> &'a [u32] {
    let at = words[0] as usize;
    // SAFETY: the caller's.
    unsafe { wide.get_unchecked(at..at + BLOCK * k) }
}

/// Every packed block of `slots` (records of `k` slots): each record's sum of
/// its slots' bytes of `signed`. Inlined into each of the callers' arms, so
/// that a constant `k` unrolls the slot loop and turns [`offset`]'s word
/// indices and shifts into constants.
///
/// # Safety
/// For every block whose base is neither [`NOT_PACKED`] nor [`WIDE`], the
/// base plus each of its offsets must be below `signed.len()`; for every
/// [`WIDE`] block, its first offset word must name `BLOCK · k` indices of
/// `wide`, each below `signed.len()`.
#[inline(always)]
unsafe fn blocks(k: usize, signed: &[i8], slots: Blocks, out: &mut [i8]) {
    for ((out, &b), offsets) in out
        .chunks_exact_mut(BLOCK)
        .zip(slots.base)
        .zip(slots.offsets.chunks_exact(BLOCK * k / SLOTS_PER_WORD))
    {
        prefetch_offsets(offsets);
        if b == NOT_PACKED {
            continue;
        }
        if b == WIDE {
            // SAFETY: the caller's.
            let wide = unsafe { wide_slots(k, slots.wide, offsets) };
            for (m, idx) in out.iter_mut().zip(wide.chunks_exact(k)) {
                let mut sum = 0i8;
                for &i in idx {
                    // SAFETY: the caller's.
                    sum = sum.wrapping_add(unsafe { *signed.get_unchecked(i as usize) });
                }
                *m = sum;
            }
            continue;
        }
        let signed = &signed[b as usize..];
        // Four records at a time: `k` whole words.
        for (m, words) in out
            .chunks_exact_mut(SLOTS_PER_WORD)
            .zip(offsets.chunks_exact(k))
        {
            for (r, m) in m.iter_mut().enumerate() {
                let mut sum = 0i8;
                for j in 0..k {
                    let o = offset(words, r * k + j);
                    // SAFETY: the caller's.
                    sum = sum.wrapping_add(unsafe { *signed.get_unchecked(o) });
                }
                *m = sum;
            }
        }
    }
}

/// A record's entries of a group's table summed byte by byte, each byte
/// wrapping on its own (as i8): the plain `u32` sum of [`group_blocks`]
/// whenever no byte carries (`k ≤ 127`), and the sum for any `k` (the
/// bias comes back off after).
#[inline(always)]
fn group_sum(entries: impl Iterator<Item = u32>) -> u32 {
    let mut bytes = [0u8; LIGHT_GROUP];
    for e in entries {
        for (b, e) in bytes.iter_mut().zip(e.to_le_bytes()) {
            *b = b.wrapping_add(e);
        }
    }
    u32::from_le_bytes(bytes)
}

/// [`blocks`] for a group of lights: each record's sum of its slots'
/// entries of the group's `table`, one byte per light of `out`.
///
/// # Safety
/// As [`blocks`], with `table` for `signed`.
#[inline(always)]
unsafe fn group_blocks(k: usize, table: &[u32], slots: Blocks, out: [&mut [i8]; LIGHT_GROUP]) {
    let mut out = out.map(|o| o.chunks_exact_mut(BLOCK));
    for (&b, offsets) in slots
        .base
        .iter()
        .zip(slots.offsets.chunks_exact(BLOCK * k / SLOTS_PER_WORD))
    {
        // Some: each output holds a block per base.
        let mut out = out.each_mut().map(|o| o.next().expect("a block per base"));
        prefetch_offsets(offsets);
        if b == NOT_PACKED {
            continue;
        }
        let mut sums = [0u32; BLOCK];
        if b == WIDE {
            // SAFETY: the caller's.
            let wide = unsafe { wide_slots(k, slots.wide, offsets) };
            for (sum, idx) in sums.iter_mut().zip(wide.chunks_exact(k)) {
                // SAFETY: the caller's.
                *sum = group_sum(
                    idx.iter()
                        .map(|&i| unsafe { *table.get_unchecked(i as usize) }),
                );
            }
        } else if k <= 127 {
            let table = &table[b as usize..];
            // Each byte of a sum is (1 + s) summed over k slots: at most
            // 2k ≤ 254, so no carry crosses into the next byte.
            for (sums, words) in sums
                .chunks_exact_mut(SLOTS_PER_WORD)
                .zip(offsets.chunks_exact(k))
            {
                for (r, sum) in sums.iter_mut().enumerate() {
                    for j in 0..k {
                        let o = offset(words, r * k + j);
                        // SAFETY: the caller's.
                        *sum = sum.wrapping_add(unsafe { *table.get_unchecked(o) });
                    }
                }
            }
        } else {
            let table = &table[b as usize..];
            for (r, sum) in sums.iter_mut().enumerate() {
                let o = |j| offset(offsets, r * k + j);
                // SAFETY: the caller's.
                *sum = group_sum((0..k).map(|j| unsafe { *table.get_unchecked(o(j)) }));
            }
        }
        // Light `l`'s byte of each sum, less the bias: a loop LLVM
        // vectorises over the block's records.
        for (l, out) in out.iter_mut().enumerate() {
            for (m, &sum) in out.iter_mut().zip(&sums) {
                *m = ((sum >> (8 * l)) as u8).wrapping_sub(k as u8) as i8;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    //! Against the input-order path ([`IndexedCaps`] over the caps as given,
    //! then each slot's `parity · sign` summed), bit for bit: buckets of
    //! every slot count the kernels specialise and one they do not, tails
    //! shorter than a block, slots that name no triangle, blocks whose slots
    //! span more than 16 bits, lights on a corner and directional lights,
    //! one thread and two.
    use super::*;
    use crate::multiplicity::test_bits;

    /// A strictly increasing table (x strictly increasing), with shared
    /// y and z values so that the sorted corner order has ties to break.
    fn table(n: usize) -> Vec<[f32; 3]> {
        (0..n)
            .map(|i| {
                [
                    i as f32 * 0.25 - 40.0,
                    (i % 7) as f32 - 3.0,
                    (i % 5) as f32 * 0.5,
                ]
            })
            .collect()
    }

    /// `n` triangles over `points` points, their corners near each other
    /// (as on a mesh), in random stored orders.
    fn triangles(n: usize, points: usize, seed: u64) -> Vec<[u32; 3]> {
        let mut next = test_bits(seed);
        (0..n)
            .map(|_| {
                let a = (next() % (points as u64 - 8)) as u32;
                let b = a + 1 + (next() % 4) as u32;
                let c = a + 1 + (next() % 7) as u32;
                match next() % 3 {
                    0 => [a, b, c],
                    1 => [c, a, b],
                    _ => [b, a, c],
                }
            })
            .collect()
    }

    /// A bucket of `records` records of `k` slots: triangles named near
    /// the record's place (as the sides' (A, B) order does), parities ±1,
    /// and every `unknown`-th slot naming no triangle (0 means none).
    fn bucket(
        k: usize,
        records: usize,
        tris: usize,
        unknown: usize,
        seed: u64,
    ) -> (Vec<u32>, Vec<i8>) {
        let mut next = test_bits(seed);
        (0..records * k)
            .map(|j| {
                if unknown > 0 && j % unknown == unknown - 1 {
                    return (UNKNOWN, 0);
                }
                let near = j / k * tris / records.max(1);
                let t = (near + (next() % 40) as usize).min(tris - 1) as u32;
                (t, if next().is_multiple_of(2) { 1 } else { -1 })
            })
            .unzip()
    }

    /// The input-order oracle: the caps' signs, and per record the sum of
    /// `parity · sign` over its slots (None where a slot names no triangle).
    fn oracle(
        positions: &[[f32; 3]],
        caps: &[[u32; 3]],
        buckets: &[(usize, Vec<u32>, Vec<i8>)],
        l: Light,
    ) -> Want {
        let ix = IndexedCaps::new(positions, caps).unwrap();
        let mut signs = vec![0i8; caps.len()];
        ix.cap_signs(l, &mut signs);
        let sides = buckets
            .iter()
            .map(|(k, tri, parity)| {
                tri.chunks_exact(*k)
                    .zip(parity.chunks_exact(*k))
                    .map(|(t, p)| {
                        t.iter().zip(p).try_fold(0i32, |sum, (&t, &p)| {
                            let s = *signs.get(t as usize)?;
                            Some(sum + p as i32 * s as i32)
                        })
                    })
                    .map(|m| m.map(|m| m as i8))
                    .collect()
            })
            .collect();
        (signs, sides)
    }

    /// Runs `o` for `l` and checks it against the oracle: every record
    /// outside the leftovers equal, every record with an unknown slot
    /// among the leftovers. Returns how many records were left over.
    fn check(
        o: &OrderedEvaluation,
        positions: &[[f32; 3]],
        caps: &[[u32; 3]],
        buckets: &[(usize, Vec<u32>, Vec<i8>)],
        l: Light,
    ) -> usize {
        let (signs, sides) = oracle(positions, caps, buckets, l);
        let mut scratch = Vec::new();
        let mut out = vec![0i8; caps.len()];
        o.cap_signs(l, &mut scratch, &mut out);
        assert!(out == signs, "caps differ for {l:?}");
        let mut left = 0;
        for (i, want) in sides.iter().enumerate() {
            // A value no record can have, so that a record the kernel
            // skipped without listing it is caught.
            let mut m = vec![i8::MIN; want.len()];
            o.sides(i, &scratch, &mut m);
            let mut listed = vec![false; want.len()];
            for r in o.leftovers(i) {
                left += r.len();
                listed[r.clone()].iter_mut().for_each(|x| *x = true);
            }
            for (r, (&got, &want)) in m.iter().zip(want).enumerate() {
                match want {
                    None => assert!(
                        listed[r],
                        "bucket {i} record {r}: unknown slot not left over"
                    ),
                    Some(_) if listed[r] => {}
                    Some(w) => assert_eq!(got, w, "bucket {i} record {r} for {l:?}"),
                }
            }
        }
        left
    }

    /// A bucket as `new` takes it: slots per record, triangles, parities.
    type Bucket = (usize, Vec<u32>, Vec<i8>);

    /// What [`oracle`] gives for one light: the caps' signs in input
    /// order, and per bucket each record's multiplicity (None where a slot
    /// names no triangle).
    type Want = (Vec<i8>, Vec<Vec<Option<i8>>>);

    /// The tests' mesh: 5000 triangles over a table of 3000 points, and
    /// buckets of slot counts 1–4 (specialised) and 6 (the general loop),
    /// record counts that leave tails, one bucket (k = 3) with unknown
    /// slots; `seed` picks the triangles, `seed + 1..` the buckets.
    fn mesh(seed: u64) -> (Vec<[f32; 3]>, Vec<[u32; 3]>, Vec<Bucket>) {
        let positions = table(3000);
        let caps = triangles(5000, positions.len(), seed);
        let buckets = [
            (1, 1003, 0),
            (2, 2500, 0),
            (3, 800, 97),
            (4, 161, 0),
            (6, 90, 0),
        ]
        .iter()
        .enumerate()
        .map(|(s, &(k, records, unknown))| {
            let (tri, parity) = bucket(k, records, caps.len(), unknown, seed + 1 + s as u64);
            (k, tri, parity)
        })
        .collect();
        (positions, caps, buckets)
    }

    /// [`OrderedEvaluation::new`] over `buckets`.
    fn ordered(positions: &[[f32; 3]], caps: &[[u32; 3]], buckets: &[Bucket]) -> OrderedEvaluation {
        let slots: Vec<Slots> = buckets
            .iter()
            .map(|(k, t, p)| (*k, &t[..], &p[..]))
            .collect();
        OrderedEvaluation::new(positions, caps, &slots).unwrap()
    }

    #[test]
    fn equals_the_input_order_path_bit_for_bit() {
        let (positions, caps, buckets) = mesh(11);
        let o = ordered(&positions, &caps, &buckets);
        let on_corner = {
            let p = positions[caps[17][1] as usize];
            [p[0], p[1], p[2], 1.0]
        };
        let lights = [
            [3.0, 2.5, 4.0, 1.0],
            [-10.0, 0.5, -2.0, 1.0],
            [0.3, -1.0, 0.2, 0.0],
            on_corner,
        ];
        for pool in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(pool)
                .build()
                .unwrap();
            for l in lights {
                let left = pool.install(|| check(&o, &positions, &caps, &buckets, l));
                // The tails, the blocks with an unknown slot (those of the
                // k = 3 bucket with a slot j ≡ 96 mod 97), nothing else.
                let tails: usize = buckets.iter().map(|(k, t, _)| t.len() / k % BLOCK).sum();
                let with_unknown = (0..800 / BLOCK)
                    .filter(|b| (b * 3 * BLOCK..(b + 1) * 3 * BLOCK).any(|j| j % 97 == 96))
                    .count();
                assert_eq!(left, tails + with_unknown * BLOCK);
            }
        }
    }

    /// A group of lights through the group's table against the oracle of
    /// each light: the caps in input order equal, every record outside the
    /// leftovers equal, every leftover left as it was. Buckets of every
    /// specialised slot count, the general loop, and 130 slots, past the
    /// 127 the biased sums hold without carries (so the byte-by-byte
    /// loop); a light on a corner and a directional one; one thread and two.
    #[test]
    fn a_group_of_lights_equals_one_light_at_a_time() {
        let (positions, caps, mut buckets) = mesh(13);
        // 130 slots naming one triangle each record, all even: sums of
        // ±130, which wrap in an i8 as the shader's would.
        let tri: Vec<u32> = (0..40u32).flat_map(|r| [r * 7; 130]).collect();
        let parity = vec![1i8; tri.len()];
        buckets.push((130, tri, parity));
        let o = ordered(&positions, &caps, &buckets);
        let p = positions[caps[40][2] as usize];
        let lights: [Light; LIGHT_GROUP] = [
            [3.0, 2.5, 4.0, 1.0],
            [p[0], p[1], p[2], 1.0],
            [0.3, -1.0, 0.2, 0.0],
            [-10.0, 0.5, -2.0, 1.0],
        ];
        let want: Vec<_> = lights
            .iter()
            .map(|&l| oracle(&positions, &caps, &buckets, l))
            .collect();
        assert!(
            want.iter()
                .any(|(_, s)| s[5].iter().flatten().any(|&m| m == -126))
        );
        check_group(&o, &caps, &buckets, &lights, &want);
    }

    /// The group path (`group_cap_signs`, then `group_sides` per bucket)
    /// against `want`, the oracle's signs and sides per light, on one
    /// thread and two; the records `o` leaves to the caller must be left
    /// as they are.
    fn check_group(
        o: &OrderedEvaluation,
        caps: &[[u32; 3]],
        buckets: &[Bucket],
        lights: &[Light; LIGHT_GROUP],
        want: &[Want],
    ) {
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let mut scratch = GroupScratch::default();
            let mut got = vec![vec![i8::MIN; caps.len()]; LIGHT_GROUP];
            let out: [&mut [i8]; LIGHT_GROUP] = {
                let mut g = got.iter_mut();
                std::array::from_fn(|_| &mut g.next().unwrap()[..])
            };
            pool.install(|| o.group_cap_signs(lights, &mut scratch, out));
            for (i, (got, (signs, _))) in got.iter().zip(want).enumerate() {
                assert!(got == signs, "light {i}: caps differ");
            }
            for (b, (_, tri, _)) in buckets.iter().enumerate() {
                let records = tri.len() / buckets[b].0;
                let mut m = vec![vec![i8::MIN; records]; LIGHT_GROUP];
                let out: [&mut [i8]; LIGHT_GROUP] = {
                    let mut g = m.iter_mut();
                    std::array::from_fn(|_| &mut g.next().unwrap()[..])
                };
                pool.install(|| o.group_sides(b, &scratch, out));
                let mut left = vec![false; records];
                for r in o.leftovers(b) {
                    left[r.clone()].iter_mut().for_each(|x| *x = true);
                }
                for (i, (m, (_, sides))) in m.iter().zip(want).enumerate() {
                    for (r, (&got, &w)) in m.iter().zip(&sides[b]).enumerate() {
                        let w = if left[r] { i8::MIN } else { w.unwrap() };
                        assert_eq!(got, w, "light {i}, bucket {b}, record {r}");
                    }
                }
            }
        }
    }

    #[test]
    fn blocks_spanning_more_than_16_bits_read_whole_indices() {
        // Records 0..40,000 name triangles 0..40,000 in order (evaluation
        // numbers in that order), then blocks naming triangles at both
        // ends: more than 16 bits apart in the signed table. One slot per
        // record (one such block); two (the block of the record that names
        // triangles 39,999 and 0, then two more, odd slots among them, so
        // that blocks start past the first index of `wide`); 130 (the
        // group's bytes summed one by one). None is left to the caller.
        let positions = table(3000);
        let n = 40_000u32;
        let caps = triangles(n as usize, positions.len(), 5);
        let far = |i: u32| if i % 5 == 3 { n - 1 - i % 7 } else { i % 11 };
        let mut one: Vec<u32> = (0..n).collect();
        one.extend((0..BLOCK as u32).map(far));
        let mut two: Vec<u32> = (0..n).flat_map(|t| [t, (t + 1) % n]).collect();
        two.extend((0..4 * BLOCK as u32).map(far));
        let many: Vec<u32> = (0..130 * BLOCK as u32).map(far).collect();
        let buckets: Vec<Bucket> = [(1, one), (2, two), (130, many)]
            .into_iter()
            .map(|(k, tri)| {
                let parity = (0..tri.len()).map(|i| [1, -1, 1][i % 3]).collect();
                (k, tri, parity)
            })
            .collect();
        let o = ordered(&positions, &caps, &buckets);
        for (b, wide_blocks) in [1, 3, 1].into_iter().enumerate() {
            assert!(o.leftovers(b).is_empty(), "bucket {b}");
            let slots = &o.buckets[b];
            let wide = slots.base.iter().filter(|&&x| x == WIDE).count();
            assert_eq!(wide, wide_blocks, "bucket {b}");
            assert_eq!(slots.wide.len(), wide * BLOCK * slots.k);
        }
        let lights = [
            [3.0, 2.5, 4.0, 1.0],
            [-1.0, 0.5, 2.0, 1.0],
            [0.3, -1.0, 0.2, 0.0],
            [-10.0, 0.5, -2.0, 1.0],
        ];
        for l in lights {
            assert_eq!(check(&o, &positions, &caps, &buckets, l), 0);
        }
        let want: Vec<_> = lights
            .iter()
            .map(|&l| oracle(&positions, &caps, &buckets, l))
            .collect();
        check_group(&o, &caps, &buckets, &lights, &want);
    }

    #[test]
    fn declines_what_the_tables_cannot_hold() {
        let positions = table(10);
        let caps = vec![[0, 1, 2], [2, 3, 4]];
        let (tri, parity) = (vec![0u32, 1], vec![1i8, -1]);
        assert!(OrderedEvaluation::new(&positions, &caps, &[(1, &tri, &parity)]).is_some());
        // A slot past the caps; a bucket without slots; a table
        // `IndexedCaps` declines.
        assert!(OrderedEvaluation::new(&positions, &caps, &[(1, &[0, 2], &parity)]).is_none());
        assert!(OrderedEvaluation::new(&positions, &caps, &[(0, &[], &[])]).is_none());
        let mut unsorted = positions.clone();
        unsorted.swap(3, 4);
        assert!(OrderedEvaluation::new(&unsorted, &caps, &[(1, &tri, &parity)]).is_none());
    }
}
