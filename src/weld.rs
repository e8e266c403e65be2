//! Welding: merge corners with bit-identical positions and renumber vertices in
//! lexicographic (x, y, z) order.
//!
//! Renumbering in lexicographic order makes "vertex index a < vertex index b"
//! the same statement as "position a < position b" in the order the
//! multiplicity contract uses, so topology can orient edges by comparing
//! integers. It also makes the welded vertex numbering independent of how the
//! input happened to order its vertices.

use std::mem::MaybeUninit;

/// Result of [`weld`].
#[derive(Debug, Clone, Default)]
pub struct Welded {
    /// Distinct positions used by kept triangles, strictly increasing in
    /// lexicographic (x, y, z) order; no `-0.0`.
    pub positions: Vec<[f32; 3]>,
    /// Kept triangles, 3 indices each into `positions`, in input order and input winding.
    pub triangles: Vec<u32>,
    /// For each kept triangle, its index in the input soup (empty when made
    /// by [`weld_without_sources`]).
    pub source_triangle: Vec<u32>,
    /// The triangles dropped because two corners welded to the same
    /// position, as indices in the input soup, increasing: with them, a
    /// kept triangle's input triangle is found without
    /// [`Welded::source_triangle`] (`layout::SoupCaps`).
    pub dropped: Vec<u32>,
}

impl Welded {
    /// Number of triangles dropped because two corners welded to the same
    /// position.
    pub fn degenerate(&self) -> u64 {
        self.dropped.len() as u64
    }

    /// Number of kept triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len() / 3
    }

    /// The three corner positions of kept triangle `t`.
    pub fn corners(&self, t: usize) -> [[f32; 3]; 3] {
        let i = &self.triangles[3 * t..3 * t + 3];
        [
            self.positions[i[0] as usize],
            self.positions[i[1] as usize],
            self.positions[i[2] as usize],
        ]
    }
}

/// `+0.0` for both zeros, the value itself otherwise.
#[inline(always)]
pub fn canonical(v: f32) -> f32 {
    if v == 0.0 { 0.0 } else { v }
}

/// Maps an f32 to a u32 whose unsigned order equals the float order (for
/// non-NaN values; `-0.0` must already be canonical).
///
/// Branch-free (flip the sign bit of positives, every bit of negatives):
/// signs of mesh coordinates are close to random, and a branch here
/// mispredicted on every other vertex.
#[inline(always)]
pub(crate) fn order_key(v: f32) -> u32 {
    let b = v.to_bits();
    b ^ (((b as i32 >> 31) as u32) | 0x8000_0000)
}

/// Inverse of [`order_key`]: the float whose key is `k`.
#[inline(always)]
fn from_order_key(k: u32) -> f32 {
    f32::from_bits(k ^ ((((!k) as i32 >> 31) as u32) | 0x8000_0000))
}

/// One sortable word per input vertex: the position's order key in the high
/// 96 bits, the vertex's input index in the low 32. Runs of equal keys in the
/// sorted words are the welded vertices.
#[inline(always)]
fn vertex_word(p: [f32; 3], index: usize) -> u128 {
    ((order_key(canonical(p[0])) as u128) << 96)
        | ((order_key(canonical(p[1])) as u128) << 64)
        | ((order_key(canonical(p[2])) as u128) << 32)
        | index as u128
}

/// [`vertex_word`] of `two[0]`, by one 16-byte load (which takes in the
/// first four bytes of `two[1]` too), the three keys made at once and a
/// shuffle of the lanes (x, y, z, _) to the word's (index, z, y, x).
///
/// Why: the weld's scatter made every word from three scalar keys, each
/// shifted into place. One thread, `RECYCLE=1 RAYON_NUM_THREADS=1 cargo
/// run --release --example stage_probe -- weld FILE`, the sort step, three
/// alternations: the 5M scene 35.45–35.57 → 34.46–34.61 ms, the dragon
/// 6.42–6.50 → 6.31–6.41 ms (four).
#[inline(always)]
fn vertex_word_wide(two: &[[f32; 3]], index: usize) -> u128 {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        assert!(two.len() >= 2);
        // SAFETY: SSE2 is part of x86-64; the load reads 16 of the 24
        // bytes of `two`.
        unsafe {
            let v = _mm_loadu_ps(two.as_ptr().cast());
            // `canonical`: both zeros to +0.0 (NaN compares unequal).
            let v = _mm_castps_si128(_mm_andnot_ps(_mm_cmpeq_ps(v, _mm_setzero_ps()), v));
            // `order_key` of every lane: b ^ ((b >> 31) | sign bit), the
            // shift arithmetic.
            let k = _mm_xor_si128(
                v,
                _mm_or_si128(_mm_srai_epi32::<31>(v), _mm_set1_epi32(i32::MIN)),
            );
            // (x, y, z, _) to (_, z, y, x), then the index into the first.
            let k = _mm_shuffle_epi32::<0b00_01_10_11>(k);
            let w = _mm_move_ss(
                _mm_castsi128_ps(k),
                _mm_castsi128_ps(_mm_cvtsi32_si128(index as u32 as i32)),
            );
            std::mem::transmute::<__m128, u128>(w)
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        vertex_word(two[0], index)
    }
}

/// The position part of a word.
#[inline(always)]
fn key(w: u128) -> u128 {
    w >> 32
}

/// The canonical position whose order key is the key of `w`: the position
/// of every vertex whose word has that key, without a gather from the input.
#[inline(always)]
fn word_position(w: u128) -> [f32; 3] {
    [
        from_order_key((w >> 96) as u32),
        from_order_key((w >> 64) as u32),
        from_order_key((w >> 32) as u32),
    ]
}

/// Writes the position of word `*w` ([`word_position`]) to `out[0]`, and
/// four bytes of garbage to the start of `out[1]`, which the caller
/// writes later.
///
/// Why: one 16-byte load, the keys of all four lanes decoded at once and a
/// shuffle from the word's lanes (index, z, y, x) to (x, y, z, _), stored
/// whole: the weld's numbering step did three shifts, three decodings and
/// three stores per vertex. One thread, `RECYCLE=1 RAYON_NUM_THREADS=1
/// cargo run --release --example stage_probe -- weld FILE`: the dragon's
/// step 1.39–1.43 → 1.18–1.20 ms (four alternations), the 5M scene's
/// 8.84–9.26 → 7.55–7.86 ms (two).
#[inline(always)]
fn write_position_padded(out: &mut [MaybeUninit<[f32; 3]>], w: &u128) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        assert!(out.len() >= 2);
        // SAFETY: SSE2 is part of x86-64; the load reads `*w`, and the
        // store writes 16 of the at least 24 bytes of `out`.
        unsafe {
            let v = _mm_loadu_si128((w as *const u128).cast());
            // `from_order_key` of every lane: k ^ ((!k >> 31) | sign bit),
            // the shift arithmetic.
            let flip = _mm_or_si128(
                _mm_srai_epi32::<31>(_mm_xor_si128(v, _mm_set1_epi32(-1))),
                _mm_set1_epi32(i32::MIN),
            );
            let p = _mm_shuffle_epi32::<0b00_01_10_11>(_mm_xor_si128(v, flip));
            _mm_storeu_si128(out.as_mut_ptr().cast(), p);
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        out[0] = MaybeUninit::new(word_position(*w));
    }
}

/// Slices of at most this many words are insertion sorted, and buckets of
/// at most this many words left to the final insertion sort of
/// [`counting_pass`].
const SMALL_SORT: usize = 32;

/// Widest digit of a [`counting_pass`], in bits: at most 4096 counts, which
/// stay in L1; longer slices take more than one pass.
const MAX_DIGIT: u32 = 12;

/// Most buckets of one [`counting_pass`] it sorts from the list its scan
/// makes of them (longer than [`SMALL_SORT`]); with more, it walks all its
/// buckets to find them.
///
/// Why: the walk read every bucket's end, about as many as the words, to
/// find a handful of long buckets (the dragon, from a marching-cubes
/// surface, has 61% of its vertices on planes of one x holding more than 32
/// of them, one or a few per group of the weld). The dragon's weld sort,
/// one thread: 7.19–7.35 → 6.74–6.99 ms (`RECYCLE=1 RAYON_NUM_THREADS=1
/// cargo run --release --example stage_probe -- weld
/// target/dragon/dragon.glb`, six alternations).
const LONG_BUCKETS: usize = 64;

/// Sorts `w` in place; the compares are branchy but the slice is short.
fn insertion_sort(w: &mut [u128]) {
    let Some(&first) = w.first() else {
        return;
    };
    // The largest word so far, kept in registers: see `insertion_sort_into`.
    let mut last = first;
    for i in 1..w.len() {
        let x = w[i];
        if x >= last {
            last = x;
            continue;
        }
        insert(&mut w[..=i], x);
    }
}

/// [`insertion_sort`] of `src` into `dst` (same length). On words that are
/// already nearly in order this is one predictable compare per word.
///
/// A word no smaller than the largest so far (three in four on the dragon
/// after [`counting_pass`]) is compared with that word, kept in registers,
/// not with the one just stored: that load waited on the store before it,
/// a chain through memory from word to word. The dragon, one thread, with
/// [`insertion_sort`] done the same way: the bucket sorts 6.25–6.44 →
/// 5.78–5.79 ms (a local probe of them alone, three runs each), the weld
/// 18.73–19.18 → 18.30–18.87 ms (`stage_probe -- weld`, three alternations).
fn insertion_sort_into(src: &[u128], dst: &mut [u128]) {
    let Some(&first) = src.first() else {
        return;
    };
    dst[0] = first;
    let mut last = first;
    for (i, &x) in src.iter().enumerate().skip(1) {
        if x >= last {
            dst[i] = x;
            last = x;
            continue;
        }
        insert(&mut dst[..=i], x);
    }
}

/// Puts `x`, smaller than the word before the last slot of `w`, in its
/// place among them: the larger words move up one slot, into the last.
#[inline(always)]
fn insert(w: &mut [u128], x: u128) {
    let mut j = w.len() - 1;
    while j > 0 && w[j - 1] > x {
        w[j] = w[j - 1];
        j -= 1;
    }
    w[j] = x;
}

/// Smallest and largest value over `a` of the key component (32 bits) at
/// bit `SHIFT`.
#[inline(always)]
fn component_range<const SHIFT: u32>(a: &[u128]) -> (u32, u32) {
    a.iter().fold((u32::MAX, 0), |(lo, hi), &w| {
        let c = (w >> SHIFT) as u32;
        (lo.min(c), hi.max(c))
    })
}

/// Sorts the words of `a` by key, in place; `scratch` is as long as `a`.
/// With `INTO`, the sorted words go to `scratch` instead, and `a` is left
/// in any order. Words with equal keys may end up in any order: nothing
/// downstream depends on it.
///
/// Method: [`counting_pass`] on the first key component (x, y or z) that is
/// not the same in every word. One monomorphised pass per component keeps
/// the shifts constant.
fn sort_words<const INTO: bool>(a: &mut [u128], scratch: &mut [u128], counts: &mut Vec<u32>) {
    debug_assert_eq!(a.len(), scratch.len());
    if a.len() <= SMALL_SORT {
        if INTO {
            insertion_sort_into(a, scratch);
        } else {
            insertion_sort(a);
        }
        return;
    }
    let (lo, hi) = component_range::<96>(a);
    if lo != hi {
        return counting_pass::<96, false, INTO>(a, scratch, counts, lo, hi - lo);
    }
    let (lo, hi) = component_range::<64>(a);
    if lo != hi {
        return counting_pass::<64, false, INTO>(a, scratch, counts, lo, hi - lo);
    }
    let (lo, hi) = component_range::<32>(a);
    if lo != hi {
        return counting_pass::<32, false, INTO>(a, scratch, counts, lo, hi - lo);
    }
    // Otherwise every key is equal: nothing to order.
    if INTO {
        scratch.copy_from_slice(a);
    }
}

/// Sorts `words` by their high 96 bits with [`sort_words`]: positions as
/// the order keys of their coordinates ([`order_key`], x highest) above a
/// number, as the weld sorts its vertices; words with equal keys end up in
/// any order. One thread. For `verify`'s decode, which puts a file's
/// distinct positions in this order (`verify::decode`).
pub(crate) fn sort_position_words(words: &mut [u128]) {
    let mut scratch = vec![0u128; words.len()];
    sort_words::<false>(words, &mut scratch, &mut Vec::new());
}

/// Part of [`sort_words`] (same `INTO`): all words of `a` agree on the
/// key components before the one at bit `SHIFT`, whose values span
/// `base..=base + range` (`range > 0`).
///
/// A counting sort into one to two buckets per word, then an insertion sort
/// over the buckets. The bucket is the component minus `base`, shifted
/// right until it fits: non-decreasing in the key, because the components
/// before it are equal. Most buckets then hold at most one or two words, so
/// the slice comes out of the counting sort nearly sorted and the insertion
/// sort costs about one predictable compare per word, with no walk over
/// small buckets. Buckets too long for that (many words on one x, as on the
/// grid planes of a marching-cubes surface) are sorted the same way first.
/// The smallest and largest words land in different buckets, so every
/// bucket is shorter than `a` and the recursion ends.
///
/// The counting sort leaves the words in `scratch`. Each long bucket is
/// sorted from there straight to where the result goes (`a`, or with
/// `INTO` `scratch` itself), and only the runs of short buckets between
/// the long ones go through the final insertion sort (into `a`, or with
/// `INTO` in place). Why: until the thirty-sixth round a long bucket was
/// sorted back into `scratch` and then went through the insertion sort
/// over the whole slice with the rest, one more compare and copy of 70%
/// of the dragon's words (those on its grid planes). One thread,
/// `RECYCLE=1 RAYON_NUM_THREADS=1 cargo run --release --example
/// stage_probe -- weld`, the sort step: the dragon 6.85–6.89 → 6.44–6.49
/// ms (four alternations), the 5M scene 36.15–36.34 → 35.11–35.64 ms
/// (two); two threads, the dragon 3.85–3.87 → 3.61–3.65 ms (three).
///
/// With `CLAMP`, `base..=base + range` is a guess (from where `a` lies in
/// [`sort_vertices`]' buckets): components outside it go to the first or
/// last bucket, which keeps the bucket non-decreasing in the key, and the
/// final insertion sort orders whatever the guess; if every word lands in
/// one bucket, the exact passes of [`sort_words`] run instead, so the
/// recursion still ends. Why: finding the exact range took a pass over
/// every group's words, a fifth of the groups' sorting (`perf annotate`).
fn counting_pass<const SHIFT: u32, const CLAMP: bool, const INTO: bool>(
    a: &mut [u128],
    scratch: &mut [u128],
    counts: &mut Vec<u32>,
    base: u32,
    range: u32,
) {
    let bits = (usize::BITS - a.len().leading_zeros()).min(MAX_DIGIT);
    let down = (u32::BITS - range.leading_zeros()).saturating_sub(bits);
    let buckets = (range >> down) as usize + 1;
    let bucket = |w: u128| {
        let c = (w >> SHIFT) as u32;
        if CLAMP {
            ((c.saturating_sub(base) >> down) as usize).min(buckets - 1)
        } else {
            ((c - base) >> down) as usize
        }
    };
    // This pass's counts go on top of the callers' in `counts` (a stack, so
    // no allocation per pass); indices, not a slice, because the recursion
    // below pushes its own.
    let first = counts.len();
    counts.resize(first + buckets, 0);
    let count = &mut counts[first..];
    for &w in a.iter() {
        count[bucket(w)] += 1;
    }
    let mut sum = 0;
    let mut whole = false;
    // The buckets too long to be left to the final insertion sort, noted
    // as the scan passes them (at most `LONG_BUCKETS`; past that, all are
    // found by a walk over the buckets, as before).
    let mut long = [0u16; LONG_BUCKETS];
    let mut longs = 0usize;
    for (d, c) in count.iter_mut().enumerate() {
        let n = *c;
        whole |= n as usize == a.len();
        if n as usize > SMALL_SORT {
            if longs < LONG_BUCKETS {
                long[longs] = d as u16;
            }
            longs += 1;
        }
        *c = sum;
        sum += n;
    }
    if CLAMP && whole {
        // A guessed range that put every word in one bucket (many words
        // on one x): the exact passes instead of a scatter that moves none.
        counts.truncate(first);
        return sort_words::<INTO>(a, scratch, counts);
    }
    for &w in a.iter() {
        let c = &mut count[bucket(w)];
        scratch[*c as usize] = w;
        *c += 1;
    }
    // `counts[first + d]` is now the end of bucket d. Sorts the short
    // buckets from `done` to the long bucket `begin..end`, then that
    // bucket, each where the result goes; buckets are non-decreasing in
    // the key, so the runs can be sorted apart.
    let n = a.len();
    let mut done = 0;
    let mut finish = |counts: &mut Vec<u32>, begin: usize, end: usize| {
        if INTO {
            insertion_sort(&mut scratch[done..begin]);
            sort_words::<false>(&mut scratch[begin..end], &mut a[begin..end], counts);
        } else {
            insertion_sort_into(&scratch[done..begin], &mut a[done..begin]);
            sort_words::<true>(&mut scratch[begin..end], &mut a[begin..end], counts);
        }
        done = end;
    };
    if longs <= LONG_BUCKETS {
        for &d in &long[..longs] {
            let d = first + d as usize;
            let begin = if d == first {
                0
            } else {
                counts[d - 1] as usize
            };
            let end = counts[d] as usize;
            finish(counts, begin, end);
        }
    } else {
        let mut begin = 0;
        for d in first..first + buckets {
            let end = counts[d] as usize;
            if end - begin > SMALL_SORT {
                finish(counts, begin, end);
            }
            begin = end;
        }
    }
    // The short buckets after the last long one.
    finish(counts, n, n);
    counts.truncate(first);
}

/// The runs (welded ids) that no marked vertex is in, in increasing order:
/// `run[v]` is input vertex `v`'s run, and `marks[v]` is 1 when a kept
/// triangle has `v` as a corner, else 0.
///
/// Only the run of an unmarked vertex can be unused, and those are few: the
/// vertices of degenerate triangles, unreferenced ones, and copies of one
/// position that only a degenerate triangle names (an OBJ read in blocks
/// exports a vertex once per block that uses it: the full Stanford dragon's
/// OBJ gives 478,446 vertices for its 437,645, of which 2 are unmarked and
/// none unused). So the runs of the unmarked vertices are the candidates,
/// as bits, and one pass over the marked entries clears the candidates
/// they name, with a load and a test per entry. Until the thirty-second
/// round every entry set its run's flag in an array of a flag per run, and
/// then every run was copied: that OBJ's step 0.79–0.86 ms, 0.40–0.43
/// after (the marks still bits of `run` then; with the scan that finds
/// an unmarked entry; one thread, `RECYCLE=1
/// cargo run --release --example stage_probe -- weld
/// target/dragon/dragon.obj`, its `unused` step, three alternations).
fn unused_runs(run: &[u32], marks: &[u8], runs: usize) -> Vec<u32> {
    let mut maybe = vec![0u64; runs.div_ceil(64)];
    let bit = |r: u32| (r as usize / 64, 1u64 << (r % 64));
    // Block by block, only those with an unmarked vertex walked one by one
    // (an and of the block's marks, as in `weld`, vectorises).
    for (c, m) in run.chunks(VERTEX_BLOCK).zip(marks.chunks(VERTEX_BLOCK)) {
        if all_marked(m) {
            continue;
        }
        for (&r, &m) in c.iter().zip(m) {
            if m == 0 {
                let (w, b) = bit(r);
                maybe[w] |= b;
            }
        }
    }
    for (&r, &m) in run.iter().zip(marks) {
        if m != 0 {
            let (w, b) = bit(r);
            if maybe[w] & b != 0 {
                maybe[w] &= !b;
            }
        }
    }
    let mut unused = Vec::new();
    for (w, &bits) in maybe.iter().enumerate() {
        let mut bits = bits;
        while bits != 0 {
            unused.push((64 * w) as u32 + bits.trailing_zeros());
            bits &= bits - 1;
        }
    }
    unused
}

/// Whether every byte of `marks` (each 0 or 1) is 1: an and of them all,
/// which vectorises.
fn all_marked(marks: &[u8]) -> bool {
    marks.iter().fold(1, |all, &m| all & m) != 0
}

/// Number of distinct keys in sorted words.
fn distinct_keys(sorted: &[u128]) -> usize {
    match sorted.first() {
        None => 0,
        Some(_) => 1 + sorted.windows(2).filter(|p| key(p[0]) != key(p[1])).count(),
    }
}

/// Vertices per parallel block of the vertex passes.
const VERTEX_BLOCK: usize = 1 << 16;

/// Most buckets of [`sort_vertices`]; bucket numbers are kept as `u16`.
///
/// Why not more: the scatter writes into every bucket at once, and with
/// 4,096 buckets their next slots (a cache line each, 256 KB) no longer
/// stay in L1. The 5M-triangle scene's 2.57M vertices, one thread: the
/// sort 59.2–67.3 ms (median 63.8) with at most 4,096 buckets, 55.6–60.1
/// (median 59.1) with at most 1,024, seven alternations of `RECYCLE=1
/// cargo run --release --example stage_probe -- weld`; 512: 58.0–58.8,
/// two runs; the dragon (which took 4,096 and now takes 1,024) 9.9–11.0
/// against 9.8–10.7 ms; two threads, whose scatter parts then each wrote
/// half the buckets, unchanged.
const MAX_BUCKETS: usize = 1 << 10;

/// How many words ahead of its next slot [`sort_vertices`]' scatter asks
/// for a bucket's line (16 words, four cache lines; a read prefetch, as
/// for the topology's listings, `topology::LIST_AHEAD`). Each bucket is a
/// stream of its own, up to [`MAX_BUCKETS`] of them, more than the
/// hardware's prefetchers follow, so without the hint every fourth store
/// to a bucket waited for its line. One thread, `RECYCLE=1 cargo run
/// --release --example stage_probe -- weld`, the sort step's median of
/// four alternations: the 5M scene 58.0 → 54.6 ms (8 words ahead: 56.1;
/// in a second run, c423f54 against its parent, 58.9 → 55.0 ms), the
/// dragon, whose 7 MB of words L3 holds, 9.19 → 9.02 ms (9.51 → 9.49 ms:
/// noise).
const SCATTER_AHEAD: usize = 16;

/// Keys of the smallest and largest finite x of `c` (`u32::MAX` and 0 when
/// there is none): unreferenced vertices may hold anything, and non-finite
/// x go to the first or last bucket of [`sort_vertices`].
///
/// A non-finite x folds in the neutral keys instead of being filtered out,
/// so the fold vectorises: the 5M scene's sort 59.4–59.9 → 54.5–55.6 ms,
/// the dragon's 10.4–11.4 → 10.1–11.2 ms (one thread, `RECYCLE=1 cargo run
/// --release --example stage_probe -- weld`, three alternations).
#[inline(always)]
fn x_range(c: &[[f32; 3]]) -> (u32, u32) {
    c.iter().fold((u32::MAX, 0), |(lo, hi), p| {
        let k = order_key(canonical(p[0]));
        let finite = p[0].is_finite();
        (
            lo.min(if finite { k } else { u32::MAX }),
            hi.max(if finite { k } else { 0 }),
        )
    })
}

/// The linear buckets of x of [`sort_vertices`]: `buckets` of them (`top`
/// + 1) over the finite x from `xmin`, `scale` buckets per unit.
struct XBuckets {
    xmin: f64,
    scale: f64,
    top: f64,
    /// The key of the largest finite x.
    kmax: u32,
}

impl XBuckets {
    /// The bucket of `x`. Non-decreasing in the key: a monotone chain of
    /// rounded f64 operations, a clamp into the buckets and a truncation,
    /// which send -inf to the first bucket and +inf to the last; NaN
    /// (which has a key too) goes by the sign of its key.
    ///
    /// Branch-free but for NaN (rare), so that the loop computing every
    /// vertex's bucket vectorises; with one bucket `top` is 0 and every
    /// vertex lands in it.
    #[inline(always)]
    fn of(&self, x: f32) -> u16 {
        let t = (x as f64 - self.xmin) * self.scale;
        let t = if t.is_nan() {
            if order_key(x) > self.kmax {
                self.top
            } else {
                0.0
            }
        } else {
            t
        };
        // SAFETY: not NaN, and clamped into 0..=top (at most
        // `MAX_BUCKETS - 1`), so finite and in range for u32 and u16.
        unsafe { t.clamp(0.0, self.top).to_int_unchecked::<u32>() as u16 }
    }
}

/// `ids[i]` = the bucket of `c[i]`'s x.
#[inline(always)]
fn fill_ids(c: &[[f32; 3]], ids: &mut [u16], bucket: &XBuckets) {
    for (p, id) in c.iter().zip(ids.iter_mut()) {
        *id = bucket.of(p[0]);
    }
}

/// The vectors [`sort_vertices`]' two vectorised loops ([`x_range`] and
/// [`fill_ids`]) are compiled for, the widest the CPU has.
///
/// Why: the crate is built for the x86-64 baseline, so these loops ran in
/// 128-bit SSE2 vectors. In AVX-512 ones (where the crate's AVX-512
/// kernels run), one thread, `RECYCLE=1 RAYON_NUM_THREADS=1 cargo run
/// --release --example stage_probe -- weld FILE`, the sort step: the
/// dragon 6.30–6.40 → 5.84–5.94 ms (three alternations; with AVX2 only,
/// 6.05–6.21 ms in a first probe), the 5M scene 34.3–34.8 → 31.9 ms
/// (two).
#[derive(Clone, Copy)]
enum Wide {
    Base,
    #[cfg(target_arch = "x86_64")]
    Avx2,
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl Wide {
    /// The widest copy the CPU runs.
    fn detect() -> Self {
        *Self::available().last().expect("the baseline")
    }

    /// Every copy the CPU runs, narrowest first (the baseline always).
    fn available() -> Vec<Self> {
        #[allow(unused_mut)]
        let mut copies = vec![Wide::Base];
        #[cfg(target_arch = "x86_64")]
        {
            if crate::evaluate_simd::have_avx2() {
                copies.push(Wide::Avx2);
            }
            if crate::evaluate_simd::have_avx512vl() {
                copies.push(Wide::Avx512);
            }
        }
        copies
    }

    fn x_range(self, c: &[[f32; 3]]) -> (u32, u32) {
        match self {
            Wide::Base => x_range(c),
            // SAFETY: `detect` found the features.
            #[cfg(target_arch = "x86_64")]
            Wide::Avx2 => unsafe { wide::x_range_avx2(c) },
            #[cfg(target_arch = "x86_64")]
            Wide::Avx512 => unsafe { wide::x_range_avx512(c) },
        }
    }

    fn fill_ids(self, c: &[[f32; 3]], ids: &mut [u16], bucket: &XBuckets) {
        match self {
            Wide::Base => fill_ids(c, ids, bucket),
            // SAFETY: `detect` found the features.
            #[cfg(target_arch = "x86_64")]
            Wide::Avx2 => unsafe { wide::fill_ids_avx2(c, ids, bucket) },
            #[cfg(target_arch = "x86_64")]
            Wide::Avx512 => unsafe { wide::fill_ids_avx512(c, ids, bucket) },
        }
    }
}

/// The copies of [`Wide`].
#[cfg(target_arch = "x86_64")]
mod wide {
    use super::{XBuckets, fill_ids, x_range};

    #[target_feature(enable = "avx2")]
    pub(super) fn x_range_avx2(c: &[[f32; 3]]) -> (u32, u32) {
        x_range(c)
    }

    #[target_feature(enable = "avx2,avx512f,avx512vl,avx512dq,avx512bw")]
    pub(super) fn x_range_avx512(c: &[[f32; 3]]) -> (u32, u32) {
        x_range(c)
    }

    #[target_feature(enable = "avx2")]
    pub(super) fn fill_ids_avx2(c: &[[f32; 3]], ids: &mut [u16], bucket: &XBuckets) {
        fill_ids(c, ids, bucket)
    }

    #[target_feature(enable = "avx2,avx512f,avx512vl,avx512dq,avx512bw")]
    pub(super) fn fill_ids_avx512(c: &[[f32; 3]], ids: &mut [u16], bucket: &XBuckets) {
        fill_ids(c, ids, bucket)
    }
}

/// Writes the words ([`vertex_word`]) of all `positions` into `words` (as
/// long), sorted by key, and returns the sorted words in consecutive groups
/// that share no key, each with its number of distinct keys.
///
/// Method: a bucket sort on x, then [`sort_words`] within each bucket (the
/// groups). The buckets split the range of finite x linearly, so they hold
/// about the same number of vertices whatever the exponents: a radix digit
/// on the raw key spends its first bits on sign and exponent, and on the
/// Stanford dragon (x within ±0.11) an 11-bit one left all but 110 of its
/// 2048 buckets empty. The bucket is a non-decreasing function of the key,
/// so sorting within buckets sorts the whole. Each word is written once,
/// straight into its bucket, and each bucket (a hundred to a few thousand
/// words: at most [`MAX_BUCKETS`] of them) is then sorted in cache.
fn sort_vertices<'w>(
    positions: &[[f32; 3]],
    words: &'w mut [MaybeUninit<u128>],
) -> Vec<(&'w [u128], usize)> {
    use rayon::prelude::*;
    let n = positions.len();
    debug_assert_eq!(words.len(), n);
    // Keys of the smallest and largest finite x (`x_range`). This fold and
    // the buckets' loop below run in the widest vectors the CPU has: see
    // `Wide`.
    let wide = Wide::detect();
    let (kmin, kmax) = positions
        .par_chunks(VERTEX_BLOCK)
        .map(|c| wide.x_range(c))
        .reduce(|| (u32::MAX, 0), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    let buckets = if kmin < kmax {
        (n / 128).next_power_of_two().clamp(1 << 8, MAX_BUCKETS)
    } else {
        1 // At most one finite x: linear buckets would hold everything.
    };
    let (xmin, xmax) = (from_order_key(kmin) as f64, from_order_key(kmax) as f64);
    let scale = buckets as f64 / (xmax - xmin);
    let bucket = XBuckets {
        xmin,
        scale,
        top: (buckets - 1) as f64,
        kmax,
    };

    // The bucket of every vertex (kept, so the scatter need not compute it
    // again) and the size of every bucket, in two loops: the first
    // vectorises, the second is the counters' adds. Together, against one
    // loop doing both: the dragon's sort 9.2–10.6 → 8.4–9.4 ms, the 5M
    // scene's 55.2–60.4 → 54.3–56.9 ms (one thread, `RECYCLE=1 cargo run
    // --release --example stage_probe -- weld`, six alternations; with the
    // bucket's saturating cast and NaN branch the split gained nothing,
    // benches/ROUNDS.md "Seventeenth round").
    // (Rounded up to a large block: see `alloc::large_capacity`.)
    let mut ids = crate::alloc::zeroed_large::<u16>(n);
    // The input cut into one part per thread, each with its counts of
    // every bucket (its vertices' buckets computed a block at a time).
    let part_len = n.div_ceil(rayon::current_num_threads().max(1)).max(1);
    let counts: Vec<Vec<u32>> = positions
        .par_chunks(part_len)
        .zip(ids.par_chunks_mut(part_len))
        .map(|(c, ids)| {
            let _part = crate::trace::span("weld: sort (part)");
            let mut count = vec![0u32; buckets];
            for (c, ids) in c.chunks(VERTEX_BLOCK).zip(ids.chunks_mut(VERTEX_BLOCK)) {
                wide.fill_ids(c, ids, &bucket);
                for &b in ids.iter() {
                    count[b as usize] += 1;
                }
            }
            count
        })
        .collect();
    let mut sizes = vec![0u32; buckets];
    for c in &counts {
        sizes.iter_mut().zip(c).for_each(|(s, c)| *s += c);
    }

    // The scatter, one part of the input per thread: in every bucket, part
    // `i` writes its words after those of parts `0..i` (`next`, each
    // part's first slot in every bucket), so every bucket gets its
    // vertices in input order whatever the number of threads.
    //
    // Until the thirty-first round each thread took a run of buckets
    // instead, and read every vertex to find its own: with two threads
    // each read all the input, and the parts branched on every vertex's
    // bucket. The dragon's sort with two threads 4.48–4.51 → 3.78–3.79 ms
    // (one thread 7.43–7.51 → 7.26–7.29 ms), the 5M scene's 19.2–19.4 →
    // 18.6–19.3 ms (`RECYCLE=1 RAYON_NUM_THREADS=T cargo run --release
    // --example stage_probe -- weld FILE`, three and two alternations).
    let mut first_slot = 0;
    let mut starts: Vec<u32> = sizes
        .iter()
        .map(|&s| {
            first_slot += s;
            first_slot - s
        })
        .collect();
    let next: Vec<Vec<u32>> = counts
        .iter()
        .map(|c| {
            let part = starts.clone();
            starts.iter_mut().zip(c).for_each(|(s, c)| *s += c);
            part
        })
        .collect();
    let out = SharedSlots(words.as_mut_ptr());
    positions
        .par_chunks(part_len)
        .zip(ids.par_chunks(part_len))
        .zip(next)
        .enumerate()
        .for_each(|(part, ((c, ids), mut next))| {
            let _part = crate::trace::span("weld: sort (part)");
            let out = &out;
            let first = part * part_len;
            // Blocks of vertices, their slots taken at once (`slots::take`:
            // consecutive vertices often share a bucket, and each waited
            // for the previous one's store to its bucket's slot), each with
            // the vertex after it for `vertex_word_wide`; then the rest one
            // by one. One thread, `RECYCLE=1 RAYON_NUM_THREADS=1 cargo run
            // --release --example stage_probe -- weld FILE`, the sort step
            // on this AMD EPYC (Zen 3), binaries alternated: the dragon
            // 8.74–9.44 → 8.24–8.56 ms (four), the 5M scene 50.45–53.84 →
            // 44.80–45.90 ms (three).
            const BLOCK: usize = crate::slots::BLOCK;
            let done = c.len().saturating_sub(1) / BLOCK * BLOCK;
            for j in (0..done).step_by(BLOCK) {
                crate::hint::prefetch_stream(c.as_ptr().wrapping_add(j));
                let b: [usize; BLOCK] = std::array::from_fn(|k| ids[j + k] as usize);
                let slots = crate::slots::take(b, &mut next);
                for (i, slot) in (j..).zip(slots) {
                    // The bucket's line four lines on: see `SCATTER_AHEAD`.
                    crate::hint::prefetch_ptr(out.0.wrapping_add(slot + SCATTER_AHEAD));
                    let w = vertex_word_wide(&c[i..i + 2], first + i);
                    // SAFETY: the slot is below n (the buckets' sizes add
                    // up to n), and each is this part's alone: parts get
                    // disjoint runs of slots in every bucket, and `next`
                    // steps through this part's run.
                    unsafe { out.0.add(slot).write(MaybeUninit::new(w)) };
                }
            }
            for (i, (&p, &b)) in c.iter().zip(ids).enumerate().skip(done) {
                crate::hint::prefetch_stream(c.as_ptr().wrapping_add(i));
                let [slot] = crate::slots::take([b as usize], &mut next);
                crate::hint::prefetch_ptr(out.0.wrapping_add(slot + SCATTER_AHEAD));
                let w = match c.get(i..i + 2) {
                    Some(two) => vertex_word_wide(two, first + i),
                    None => vertex_word(p, first + i),
                };
                // SAFETY: as in the blocks.
                unsafe { out.0.add(slot).write(MaybeUninit::new(w)) };
            }
        });
    drop(ids);
    // SAFETY: the bucket sizes add up to n, and every bucket got exactly its
    // size of words (each vertex is in one bucket, and its part wrote it).
    let words = unsafe { assume_init_mut(words) };

    // Each bucket sorted on its own, in parallel.
    let mut groups = Vec::with_capacity(buckets);
    let mut rest = words;
    for &size in &sizes {
        let (head, tail) = rest.split_at_mut(size as usize);
        groups.push(head);
        rest = tail;
    }
    // The x keys bucket `b` spans, about: the keys of the x at its two
    // edges. Each group's first counting pass takes that range as given
    // instead of finding it (`counting_pass` with `CLAMP`): the dragon's
    // weld, one thread, 13.95 → 13.50 ms median of 12 (`stage_probe --
    // weld`, binaries alternated; two threads 7.41 → 7.18 ms of 8).
    let edge = |b: usize| order_key(canonical((xmin + b as f64 / scale) as f32));
    // Tasks of 64 groups at most, as well as at least. Why the upper
    // bound: rayon splits a job only while it has splits left or is
    // stolen, so the thread that started the job sorted its share in long
    // runs the other could not take a part of, and the other, with
    // nothing left to steal, waited: in two traced two-thread builds of
    // the dragon, 0.85 and 2.3 ms of a 9.5 and a 13.4 ms weld. Now the
    // last task left is 64 groups of the dragon's 1,024. Its sort step
    // with two threads 4.48–4.59 → 4.13–4.35 ms (seven alternations of
    // `RECYCLE=1 RAYON_NUM_THREADS=2 cargo run --release --example
    // stage_probe -- weld target/dragon/dragon.glb`); with one thread,
    // and on the 5M scene, unchanged within the noise.
    groups
        .into_par_iter()
        .enumerate()
        .with_min_len(64)
        .with_max_len(64)
        .map_init(
            // (A split's span lasts as long as its scratch.)
            || {
                let part = crate::trace::span("weld: sort (part)");
                (<(Vec<u128>, Vec<u32>)>::default(), part)
            },
            |((scratch, counts), _part), (b, g)| {
                if g.len() > SMALL_SORT {
                    scratch.resize(g.len(), 0);
                    // (One bucket: no linear scale to take edges from.)
                    let guess = (buckets > 1).then(|| (edge(b), edge(b + 1)));
                    match guess {
                        Some((lo, hi)) if lo < hi => {
                            counting_pass::<96, true, false>(g, scratch, counts, lo, hi - lo)
                        }
                        _ => sort_words::<false>(g, scratch, counts),
                    }
                } else {
                    insertion_sort(g);
                }
                (&*g, distinct_keys(g))
            },
        )
        .collect()
}

/// `w`, every element of which is written, as initialised.
///
/// # Safety
/// Every element of `w` must have been written.
unsafe fn assume_init_mut<T>(w: &mut [MaybeUninit<T>]) -> &mut [T] {
    // SAFETY: `MaybeUninit<T>` has `T`'s layout, and the caller has written
    // every element.
    unsafe { std::slice::from_raw_parts_mut(w.as_mut_ptr().cast(), w.len()) }
}

/// A pointer to slots that parallel jobs write, each to its own slots.
struct SharedSlots<T>(*mut T);
// SAFETY: shared only to write disjoint slots (see its uses).
unsafe impl<T> Sync for SharedSlots<T> {}

/// Fewest triangles per part of the renaming (step 3 of [`weld_passes`]):
/// smaller inputs take fewer parts than threads.
const TRI_BLOCK: usize = 1 << 14;

/// How many words ahead the numbering prefetches the run id slot it
/// will write (see `weld_in`, step 2).
const RUN_AHEAD: usize = 32;

/// Run ids stay below this: at most 2^31 distinct positions.
const RUN_LIMIT: u32 = 1 << 31;

/// What debug builds fill the uninitialised run ids and triangles with, to
/// check that every slot is written: run ids stay below [`RUN_LIMIT`].
const UNWRITTEN: u32 = u32::MAX;

/// Welds the soup `positions`/`indices` (3 indices per triangle, all in range,
/// all positions used by a triangle finite, fewer than 2^31 distinct
/// positions). Drops triangles with two equal welded corners.
///
/// Method: one sort. Every input vertex becomes a 128-bit word (position key
/// above index, `vertex_word`); after sorting, runs of equal position keys
/// are the welded vertices, already in lexicographic order, so numbering the
/// runs welds and orders in one pass. A hash map of positions followed by a
/// sort of the distinct ones did the same work twice, with a cache miss per
/// vertex in the map. The sort is a bucket sort on x with a radix sort per
/// bucket (`sort_vertices`); a comparison sort of the words was half of the
/// time, mostly mispredicted compares.
///
/// Every step runs in fixed blocks or on disjoint ranges, and the result is
/// the same whatever the number of threads.
pub fn weld(positions: &[[f32; 3]], indices: &[u32]) -> Welded {
    weld_in(positions, indices, true)
}

/// [`weld`] without [`Welded::source_triangle`] (left empty): what a build
/// needs, since only `lint` reads it. Why: it is 4 bytes per triangle of
/// fresh memory, written and then freed unread (3.5 MB on the 871k-triangle
/// dragon).
pub fn weld_without_sources(positions: &[[f32; 3]], indices: &[u32]) -> Welded {
    weld_in(positions, indices, false)
}

/// [`weld_without_sources`], with the wall time of each of its steps (for
/// `examples/stage_probe.rs`, which profiles them).
pub fn weld_without_sources_timed(positions: &[[f32; 3]], indices: &[u32]) -> (Welded, StepTimes) {
    let mut times = StepTimes::default();
    let welded = weld_in_timed(positions, indices, false, &mut times);
    (welded, times)
}

/// Wall time of each step of [`weld`] (see `weld_in`'s steps).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepTimes {
    /// Step 1, sorting the vertices' words (`sort_vertices`), with the
    /// output buffers' allocation before it.
    pub sort: std::time::Duration,
    /// Step 2, numbering the runs of equal positions.
    pub numbering: std::time::Duration,
    /// Step 3, the triangles in run ids, the dropped ones closed up (and
    /// the sources, when asked for).
    pub triangles: std::time::Duration,
    /// Step 4, dropping the runs no kept triangle uses.
    pub unused: std::time::Duration,
}

/// [`weld`], with [`Welded::source_triangle`] only when `sources`.
fn weld_in(positions: &[[f32; 3]], indices: &[u32], sources: bool) -> Welded {
    weld_in_timed(positions, indices, sources, &mut StepTimes::default())
}

/// [`weld_in`], its steps' times in `times`: [`weld_passes`] as one job on
/// rayon's pool (see `crate::pool`).
fn weld_in_timed(
    positions: &[[f32; 3]],
    indices: &[u32],
    sources: bool,
    times: &mut StepTimes,
) -> Welded {
    crate::pool::one_job(|| weld_passes(positions, indices, sources, times))
}

/// The steps of [`weld`] (with [`Welded::source_triangle`] only when
/// `sources`), their times in `times`.
fn weld_passes(
    positions: &[[f32; 3]],
    indices: &[u32],
    sources: bool,
    times: &mut StepTimes,
) -> Welded {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicU8, Ordering::Relaxed};
    use std::time::Instant;
    let started = Instant::now();
    let n = positions.len();
    let triangle_count = indices.len() / 3;
    // The output triangles, and until step 3 writes them, the sort's words
    // when they fit (16 bytes a vertex against 12 a triangle; closed meshes
    // have about two triangles a vertex): the first touch of fresh memory
    // (the kernel mapping and zeroing pages) costs about as much as the
    // writes, so one buffer for both saves a buffer's worth.
    //
    // Both uninitialised: every word and every triangle slot is written
    // before it is read, and zeroing them was a memset of the whole buffer
    // whenever the allocator reused a freed block for it, as for a batch's
    // later inputs (the dragon's weld with memory recycled: 15.0–16.4 →
    // 14.2–14.9 ms, `stage_probe -- weld`, 5 alternated runs).
    let mut triangles: Vec<u32> = Vec::with_capacity(3 * triangle_count);
    // Debug builds fill them with a value no vertex id reaches, and check
    // after step 3 that none is left.
    if cfg!(debug_assertions) {
        triangles
            .spare_capacity_mut()
            .fill(MaybeUninit::new(UNWRITTEN));
    }
    let mut own_words: Vec<u128> = Vec::new();
    let spare = triangles.spare_capacity_mut().get_mut(..4 * n);
    // SAFETY: any bytes are a `MaybeUninit<u128>`, and `align_to_mut` only
    // puts whole, aligned ones in the middle.
    let words: &mut [MaybeUninit<u128>] =
        match spare.map(|t| unsafe { t.align_to_mut::<MaybeUninit<u128>>() }) {
            Some(([], w, [])) => w,
            _ => {
                own_words.reserve_exact(n);
                &mut own_words.spare_capacity_mut()[..n]
            }
        };

    // 1. Sort all input vertices by position.
    let groups = sort_vertices(positions, words);
    times.sort = started.elapsed();
    crate::trace::since("weld: sort", started);
    let step = Instant::now();

    // 2. Number the runs of equal positions: `run[i]` is input vertex i's
    //    welded id before unused vertices are removed. A run's position is
    //    its key decoded. Groups share no key, so each numbers its runs from
    //    its own offset, in parallel.
    let runs: usize = groups.iter().map(|g| g.1).sum();
    assert!(
        runs < RUN_LIMIT as usize,
        "weld: 2^31 distinct positions or more"
    );
    // Both uninitialised, for the same reason as the triangles: each run
    // writes its position, and each input vertex is in one word.
    // (Rounded up to a large block: see `alloc::large_capacity`.)
    let mut run: Vec<u32> = Vec::with_capacity(crate::alloc::large_capacity::<u32>(n));
    if cfg!(debug_assertions) {
        for r in run.spare_capacity_mut() {
            r.write(UNWRITTEN);
        }
    }
    let run_at = SharedSlots(run.as_mut_ptr());
    let mut out_positions: Vec<[f32; 3]> = Vec::with_capacity(runs);
    let mut jobs = Vec::with_capacity(groups.len());
    let mut rest = &mut out_positions.spare_capacity_mut()[..runs];
    let mut first_run = 0;
    for &(words, distinct) in &groups {
        let (head, tail) = rest.split_at_mut(distinct);
        jobs.push((words, head, first_run));
        rest = tail;
        first_run += distinct as u32;
    }
    jobs.into_par_iter().with_min_len(64).for_each_init(
        || crate::trace::span("weld: numbering (part)"),
        |_part, (words, out, first_run)| {
            // Branch-free: every word writes its run's position (the same
            // value for every word of a run; 16 bytes but for the group's
            // last run, see `write_position_padded`), and the run id steps
            // when the key changes.
            //
            // The run ids go to the words' input indices, all over `run`,
            // which is larger than L2 on large meshes: the slot of the
            // word 32 ahead is prefetched. The 5M-triangle scene's
            // numbering 15.6–15.9 → 11.6–12.6 ms, the dragon's (1.7 MB of
            // run ids, in L2) unchanged at 1.6–1.8 ms (one thread,
            // `RECYCLE=1 cargo run --release --example stage_probe --
            // weld`, alternated; 16 ahead: 12.5–12.9 ms, 8: 13.1–14.0).
            let run_at = &run_at;
            let mut r = usize::MAX;
            let mut prev_key = words.first().map_or(0, |&w| !key(w));
            for (j, &w) in words.iter().enumerate() {
                // The words 2 KiB ahead (`hint::STREAM_AHEAD`; the read
                // just below is 512 bytes on): the 5M scene's numbering
                // 11.48 → 9.54 ms, the dragon's (7 MB of words, in L3)
                // unchanged at 1.27–1.28 ms (medians of four alternations,
                // same command).
                crate::hint::prefetch_stream(words.as_ptr().wrapping_add(j));
                if let Some(&ahead) = words.get(j + RUN_AHEAD) {
                    crate::hint::prefetch_ptr(run_at.0.wrapping_add(ahead as u32 as usize));
                }
                r = r.wrapping_add((key(w) != prev_key) as usize);
                prev_key = key(w);
                if r + 1 < out.len() {
                    write_position_padded(&mut out[r..r + 2], &words[j]);
                } else {
                    out[r] = MaybeUninit::new(word_position(w));
                }
                // SAFETY: the word's vertex index is below n, and no other
                // word has it (one word per input vertex), so no other job
                // writes this slot.
                unsafe { run_at.0.add(w as u32 as usize).write(first_run + r as u32) };
            }
        },
    );
    drop(groups);
    drop(own_words);
    // SAFETY: every run's position and every vertex's run were written
    // just above (the groups' distinct keys add up to `runs`).
    unsafe {
        out_positions.set_len(runs);
        run.set_len(n);
    }
    debug_assert!(!run.contains(&UNWRITTEN));
    times.numbering = step.elapsed();
    crate::trace::since("weld: numbering", step);
    let step = Instant::now();

    // 3. Triangles in run ids, one part of the input per thread; the
    //    degenerate ones are listed (they are rare) and closed up as the
    //    part goes. Every corner of a kept triangle marks its vertex, a
    //    byte of `marks`; a mark is only ever set, so the result is the
    //    same in any order.
    //
    //    Until the thirty-second round the mark was a bit of the vertex's
    //    entry of `run`, stored back into the entry the corner had just
    //    read: every line of `run` (4 bytes a vertex) was then dirty and
    //    went back to memory, and the renaming masked the bit off each run
    //    id. With a byte per vertex, `run` is only read here. One thread,
    //    `RECYCLE=1 cargo run --release --example stage_probe -- weld FILE`,
    //    three alternations: the dragon's step 3.30–3.33 → 2.82–2.96 ms
    //    (the glTF; its OBJ 3.22–3.40 → 2.83–3.17), the 5M scene's
    //    15.8–15.9 → 15.0–15.1 ms (two); with two threads, the dragon's
    //    1.66–1.67 → 1.41–1.42 ms.
    let mut marks: Vec<u8> = crate::alloc::zeroed_large(n);
    let marks_at = SharedSlots(marks.as_mut_ptr());
    // Each part renames its triangles in order and writes them closed up
    // from the part's start (a dropped triangle's slot takes the next kept
    // one); then each part after the first moves down to follow the kept
    // triangles before it, so with one thread nothing moves. The result
    // is the same for any number of parts.
    //
    // Until the thirty-fourth round fixed blocks of `TRI_BLOCK` triangles
    // were renamed in parallel, each in place, and then closed up: with a
    // triangle dropped near the front that moved nearly every triangle,
    // one thread or two (the dragon drops 108, the first at 14,955). The
    // dragon's step, `RECYCLE=1 RAYON_NUM_THREADS=T cargo run --release
    // --example stage_probe -- weld target/dragon/dragon.glb`, five
    // alternations: one thread 2.90–3.19 → 2.31–2.54 ms, two threads
    // 1.45–1.77 → 1.39–1.43 ms.
    let parts = rayon::current_num_threads().clamp(1, triangle_count.div_ceil(TRI_BLOCK).max(1));
    let part_len = triangle_count.div_ceil(parts).max(1);
    let out = &mut triangles.spare_capacity_mut()[..3 * triangle_count];
    let renamed: Vec<(usize, Vec<u32>)> = indices
        .par_chunks(3 * part_len)
        .zip(out.par_chunks_mut(3 * part_len))
        .enumerate()
        .map(|(part, (tris, out))| {
            let _part = crate::trace::span("weld: triangles (part)");
            // The marks' pointer, `run` as a slice and each triangle's
            // corners in locals: a byte stored through a pointer may alias
            // anything, so with them read through `marks_at`, the captured
            // `Vec` and `c`, the compiler loaded the pointers, `run`'s
            // length and the corners again after every mark. `RECYCLE=1
            // RAYON_NUM_THREADS=T cargo run --release --example
            // stage_probe -- weld FILE`, the triangles step, binaries
            // alternated: the dragon, one thread 2.22–2.24 → 1.77–1.79 ms
            // (three), two threads 1.35–1.43 → 1.03–1.12 ms (three); the
            // 5M scene, one thread 13.60–13.78 → 9.79–9.82 ms (two).
            let marks_at = &marks_at;
            let marks = marks_at.0;
            let run: &[u32] = &run;
            let first = part * part_len;
            let (mut kept, mut dropped) = (0, Vec::new());
            for (i, c) in tris.chunks_exact(3).enumerate() {
                crate::hint::prefetch_stream(tris.as_ptr().wrapping_add(3 * i));
                let c = [c[0], c[1], c[2]];
                let [a, b, d] = c.map(|v| run[v as usize]);
                // (kept <= i: inside the part's slots.)
                out[3 * kept..3 * kept + 3].copy_from_slice(&[a, b, d].map(MaybeUninit::new));
                if a != b && b != d && a != d {
                    for v in c {
                        // SAFETY: v < n (indices are in range), and a
                        // `u8` is an `AtomicU8`'s layout: the threads
                        // only ever store 1, atomically.
                        unsafe { AtomicU8::from_ptr(marks.add(v as usize)) }.store(1, Relaxed);
                    }
                    kept += 1;
                } else {
                    dropped.push((first + i) as u32);
                }
            }
            (kept, dropped)
        })
        .collect();
    let mut kept_triangles = 0;
    let moving = crate::trace::span("weld: move");
    for (part, &(kept, _)) in renamed.iter().enumerate() {
        let from = part * part_len;
        if from != kept_triangles {
            out.copy_within(3 * from..3 * (from + kept), 3 * kept_triangles);
        }
        kept_triangles += kept;
    }
    moving.end();
    // SAFETY: the parts wrote their kept triangles, now the first
    // `kept_triangles` in order.
    unsafe { triangles.set_len(3 * kept_triangles) };
    debug_assert!(!triangles.contains(&UNWRITTEN));
    let degenerate = (triangle_count - kept_triangles) as u64;
    let dropped: Vec<u32> = renamed.into_iter().flat_map(|(_, d)| d).collect();
    let source_triangle: Vec<u32> = if !sources {
        Vec::new()
    } else if degenerate == 0 {
        (0..triangle_count as u32).into_par_iter().collect()
    } else {
        let mut source = Vec::with_capacity(kept_triangles);
        let mut begin = 0;
        for &end in dropped.iter().chain(&[triangle_count as u32]) {
            source.extend(begin..end);
            begin = end + 1;
        }
        source
    };

    times.triangles = step.elapsed();
    crate::trace::since("weld: triangles", step);
    let step = Instant::now();

    // 4. Drop unused runs (those no kept triangle references) and renumber
    //    densely; the order stays lexicographic. Usually every vertex is
    //    marked, which one scan shows: an and of every mark per block,
    //    which vectorises (on the 5M scene 0.4 ms while the marks were
    //    bits of `run`, 0.1 ms as bytes).
    if !marks.par_chunks(VERTEX_BLOCK).all(all_marked) {
        let unused = unused_runs(&run, &marks, runs);
        if !unused.is_empty() {
            let mut rank = vec![u32::MAX; runs];
            let mut kept = 0;
            let mut unused = unused.iter().peekable();
            for r in 0..runs {
                if unused.next_if_eq(&&(r as u32)).is_none() {
                    rank[r] = kept as u32;
                    out_positions[kept] = out_positions[r];
                    kept += 1;
                }
            }
            out_positions.truncate(kept);
            triangles
                .par_iter_mut()
                .for_each(|v| *v = rank[*v as usize]);
        }
    }
    times.unused = step.elapsed();
    crate::trace::since("weld: unused", step);

    Welded {
        positions: out_positions,
        triangles,
        source_triangle,
        dropped,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::multiplicity::lex_less;

    #[test]
    fn merges_signed_zero_and_sorts() {
        let pos = [
            [1.0, 0.0, 0.0],
            [0.0, -0.0, 0.0],
            [0.0, 1.0, 0.0],
            [-0.0, 0.0, 0.0], // same as vertex 1
            [1.0, 0.0, 0.0],  // same as vertex 0
        ];
        let idx = [0, 1, 2, 4, 3, 2];
        let w = weld(&pos, &idx);
        assert_eq!(w.positions.len(), 3);
        assert!(w.positions.windows(2).all(|p| lex_less(p[0], p[1])));
        assert!(
            w.positions
                .iter()
                .flatten()
                .all(|v| v.to_bits() != (-0.0f32).to_bits())
        );
        assert_eq!(w.triangle_count(), 2);
        // Both triangles are the same triangle, same winding.
        assert_eq!(w.triangles[0..3], w.triangles[3..6]);
        assert_eq!(
            w.corners(0),
            [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
        );
    }

    #[test]
    fn drops_degenerates_and_unused() {
        let pos = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [5.0, 5.0, 5.0], // only in the degenerate triangle
        ];
        let idx = [0, 1, 2, 1, 3, 4];
        let w = weld(&pos, &idx);
        assert_eq!(w.degenerate(), 1);
        assert_eq!(w.triangle_count(), 1);
        assert_eq!(w.positions.len(), 3);
        assert_eq!(w.source_triangle, vec![0]);
    }

    #[test]
    fn keeps_a_position_whose_only_unmarked_copy_is_in_a_degenerate_triangle() {
        // Vertex 3 is vertex 1's position, named only by the degenerate
        // triangle (1, 3, 0): unmarked, but its run is used by vertex 1.
        // Vertex 5 is unreferenced and vertex 4 only in a degenerate
        // triangle: both runs are unused. Runs in order: 0 (0,0,0), 1
        // (0,1,0), 2 (1,0,0), 3 (5,5,5), 4 (7,7,7).
        let pos = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [5.0, 5.0, 5.0],
            [7.0, 7.0, 7.0],
        ];
        let idx = [1, 3, 0, 0, 1, 2, 4, 4, 2];
        let w = weld(&pos, &idx);
        assert_eq!(w.degenerate(), 2);
        assert_eq!(
            w.positions,
            vec![[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
        );
        assert_eq!(w.triangles, vec![0, 2, 1]);
        // Only vertex 3 unmarked: nothing is dropped.
        let w = weld(&pos[..4], &idx[..6]);
        assert_eq!(w.positions.len(), 3);
        assert_eq!(w.triangles, vec![0, 2, 1]);
    }

    #[test]
    fn matches_the_obvious_implementation() {
        // A lattice small enough that positions repeat (weld), with -0.0,
        // degenerate triangles, an unused and a NaN unreferenced vertex, and
        // more triangles than one parallel block.
        let mut bits = crate::multiplicity::test_bits(0x2545_f491_4f6c_dd1du64);
        let mut rng = move || bits() >> 11;
        let coord = |r: u64| [-1.0, -0.0, 0.0, 0.5, 1.0, 2.0][(r % 6) as usize];
        let mut pos: Vec<[f32; 3]> = (0..400)
            .map(|_| [coord(rng()), coord(rng()), coord(rng())])
            .collect();
        pos.push([9.0, 9.0, 9.0]); // never referenced
        pos.push([f32::NAN, 0.0, 0.0]); // never referenced
        let idx: Vec<u32> = (0..3 * (TRI_BLOCK + 999))
            .map(|_| (rng() % 400) as u32)
            .collect();
        let w = weld(&pos, &idx);
        let n = reference(&pos, &idx);
        assert!(w.degenerate() > 0 && w.positions.len() < 400);
        assert_eq!(w.positions, n.positions);
        assert_eq!(w.triangles, n.triangles);
        assert_eq!(w.source_triangle, n.source_triangle);
        assert_eq!(w.degenerate(), n.degenerate());
        // Without sources: the same mesh, and no sources.
        let ws = weld_without_sources(&pos, &idx);
        assert_eq!(ws.positions, n.positions);
        assert_eq!(ws.triangles, n.triangles);
        assert_eq!(ws.degenerate(), n.degenerate());
        assert!(ws.source_triangle.is_empty());
        // And the triangles before the first degenerate one (the path
        // with nothing dropped).
        let first_dropped = (n.source_triangle.iter())
            .enumerate()
            .position(|(i, &s)| s as usize != i)
            .unwrap();
        let clean = &idx[..3 * first_dropped];
        assert!(!clean.is_empty());
        assert_eq!(
            weld_without_sources(&pos, clean).triangles,
            weld(&pos, clean).triangles
        );
    }

    #[test]
    fn negative_values_order() {
        let pos = [[-2.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, -3.0, 0.0]];
        let w = weld(&pos, &[0, 1, 2]);
        assert_eq!(
            w.positions,
            vec![[-2.0, 0.0, 0.0], [-1.0, -3.0, 0.0], [-1.0, 0.0, 0.0]]
        );
        assert_eq!(w.triangles, vec![0, 2, 1]);
    }

    /// Positions that stress the sort: grid planes (long runs of one x, and
    /// of one x and y, as marching cubes makes), neighbours one ulp apart in
    /// z only, both signs and both zeros, values either side of a power of
    /// two, magnitudes from subnormal to huge, and repeats of positions from
    /// far back in the input (another parallel block, another bucket part).
    fn hard_positions(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut bits = crate::multiplicity::test_bits(seed);
        let mut rng = move || bits() >> 11;
        let unit = |r: u64| (r % 2001) as f32 / 1000.0 - 1.0;
        let mut pos: Vec<[f32; 3]> = Vec::with_capacity(n);
        while pos.len() < n {
            let r = rng();
            let old = pos.get((r >> 8) as usize % pos.len().max(1)).copied();
            let p = match (r % 10, old) {
                (0 | 1, _) => [
                    (r >> 8) as f32 % 16.0 * 0.25 - 2.0,
                    (r >> 12) as f32 % 8.0 * 0.25,
                    unit(rng()),
                ],
                (2, Some(o)) => o,
                (3, Some(o)) => {
                    let z = if rng() % 2 == 0 { 1 } else { u32::MAX };
                    let z = f32::from_bits(o[2].to_bits().wrapping_add(z));
                    [o[0], o[1], if z.is_finite() { z } else { o[2] }]
                }
                (4, Some(o)) => [o[0], unit(rng()), unit(rng())],
                (5, _) => [
                    [0.0, -0.0][(r >> 8) as usize % 2],
                    [0.0, -0.0, 1.0][(r >> 9) as usize % 3],
                    [0.0, -0.0][(r >> 11) as usize % 2],
                ],
                (6, _) => {
                    let near = [1.0f32, -1.0, 0.5, 2.0][(r >> 8) as usize % 4];
                    let d = (r >> 10) as u32 % 5;
                    [f32::from_bits(near.to_bits() + d - 2), near, -near]
                }
                (7, _) => {
                    let bits = |r: u64| {
                        let v = f32::from_bits(r as u32);
                        if v.is_finite() { v } else { 1.5 }
                    };
                    [bits(rng()), bits(rng()), bits(rng())]
                }
                _ => [unit(r >> 8), unit(rng()), unit(rng())],
            };
            pos.push(p);
        }
        pos
    }

    fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(f)
    }

    #[test]
    fn wide_words_match_vertex_word() {
        // Every kind of value in every lane: both zeros, NaN of either
        // sign, infinities, subnormals, and the hard positions.
        let specials = [
            0.0,
            -0.0,
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE / 4.0,
            -f32::MIN_POSITIVE / 4.0,
            f32::MAX,
            -1.5,
        ];
        let mut pos = hard_positions(500, 11);
        for (i, &x) in specials.iter().enumerate() {
            for (j, &y) in specials.iter().enumerate() {
                pos.push([x, y, specials[(i + j) % specials.len()]]);
            }
        }
        for i in 0..pos.len() - 1 {
            let index = i * 7_919 % (1 << 32);
            let want = vertex_word(pos[i], index);
            assert_eq!(
                vertex_word_wide(&pos[i..i + 2], index),
                want,
                "{:?}",
                pos[i]
            );
        }
    }

    #[test]
    fn wide_copies_match_the_base_loops() {
        // NaN, infinities and both zeros in x, among hard positions and
        // one lone huge x; every copy the CPU can run gives the base
        // loop's keys and buckets.
        let mut pos = hard_positions(3 * VERTEX_BLOCK / 2 + 13, 5);
        for (i, x) in [
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -0.0,
            0.0,
        ]
        .into_iter()
        .enumerate()
        {
            pos[100 * i + 7][0] = x;
        }
        pos[999][0] = 3.0e38;
        let copies = Wide::available();
        let (kmin, kmax) = x_range(&pos);
        let bucket = XBuckets {
            xmin: from_order_key(kmin) as f64,
            scale: 1024.0 / (from_order_key(kmax) as f64 - from_order_key(kmin) as f64),
            top: 1023.0,
            kmax,
        };
        let mut want = vec![0u16; pos.len()];
        fill_ids(&pos, &mut want, &bucket);
        assert!(want.contains(&0) && want.contains(&1023));
        for wide in copies {
            assert_eq!(wide.x_range(&pos), (kmin, kmax));
            let mut ids = vec![u16::MAX; pos.len()];
            wide.fill_ids(&pos, &mut ids, &bucket);
            assert!(ids == want, "the buckets");
        }
    }

    #[test]
    fn sort_matches_a_comparison_sort() {
        // More vertices than two parallel blocks; non-finite x, which have
        // buckets too; a lone huge x that leaves the other vertices a few
        // buckets, one x for all and ten, so that long slices go through
        // the radix passes of several components.
        let mut pos = hard_positions(2 * VERTEX_BLOCK + 777, 7);
        pos[10] = [f32::NAN, 0.0, 0.0];
        pos[11] = [-f32::NAN, 1.0, 0.0];
        pos[12] = [f32::INFINITY, 0.0, 0.0];
        pos[13] = [f32::NEG_INFINITY, 0.0, 0.0];
        let mut skewed = pos.clone();
        skewed[14] = [3.0e38, 0.0, 0.0];
        let one_x: Vec<[f32; 3]> = pos.iter().map(|p| [1.0, p[1], p[2]]).collect();
        // Ten x values, each alone in a bucket of thousands of words: every
        // group's guessed range puts all its words in one of its buckets.
        let few_x: Vec<[f32; 3]> = (pos.iter().enumerate())
            .map(|(i, p)| [(i % 10) as f32, p[1], p[2]])
            .collect();
        // A hundred non-finite x, more than the last bucket's guessed range
        // holds (and more than an insertion sort takes).
        let mut tails = pos.clone();
        for (i, p) in tails[20..120].iter_mut().enumerate() {
            p[0] = [f32::INFINITY, f32::NAN][i % 2];
        }
        for pos in [pos, skewed, one_x, few_x, tails] {
            let mut expect: Vec<u128> = pos
                .iter()
                .enumerate()
                .map(|(i, &p)| vertex_word(p, i))
                .collect();
            expect.sort_unstable();
            for threads in [1, 2, 3] {
                let mut words = vec![MaybeUninit::new(0u128); pos.len()];
                let groups = with_threads(threads, || {
                    sort_vertices(&pos, &mut words)
                        .into_iter()
                        .map(|(g, distinct)| (g.len(), distinct))
                        .collect::<Vec<_>>()
                });
                // SAFETY: initialised above (and written by the sort).
                let words: Vec<u128> = words.iter().map(|w| unsafe { w.assume_init() }).collect();
                // Sorted by key, and the same words.
                assert!(words.windows(2).all(|w| key(w[0]) <= key(w[1])));
                let mut all = words.clone();
                all.sort_unstable();
                assert_eq!(all, expect);
                // Groups cover the words, share no key, count their keys.
                let mut begin = 0;
                for (len, distinct) in groups {
                    let g = &words[begin..begin + len];
                    assert_eq!(distinct, distinct_keys(g));
                    if begin > 0 && len > 0 {
                        assert_ne!(key(words[begin - 1]), key(g[0]));
                    }
                    begin += len;
                }
                assert_eq!(begin, words.len());
            }
        }
    }

    #[test]
    fn long_buckets_sorted_from_the_scans_list_and_by_the_walk() {
        // Words on planes of one x (a marching-cubes surface): 3 planes of
        // 300 words among 3,000 distinct x leave a pass a few long buckets,
        // found from the scan's list; 200 planes of 40 words leave it more
        // than `LONG_BUCKETS`, found by the walk.
        let mut bits = crate::multiplicity::test_bits(0x5eed);
        let mut rng = move || bits() >> 11;
        let plane = |x: f32, rng: &mut dyn FnMut() -> u64| {
            [x, (rng() % 1000) as f32 * 0.5, (rng() % 7) as f32]
        };
        // x evenly spaced in key order (one exponent), so that each of the
        // pass's buckets holds one x.
        let x = |i: usize| 1.0 + i as f32 / (1 << 20) as f32;
        let mut few: Vec<[f32; 3]> = (0..3000).map(|i| plane(x(i), &mut rng)).collect();
        few.extend((0..900).map(|i| plane(x(i % 3 * 1000 + 1), &mut rng)));
        let many: Vec<[f32; 3]> = (0..8000).map(|i| plane(x(i % 200), &mut rng)).collect();
        // Lines of one x and y (a grid's edges along z): 3 planes, each
        // with 4 lines of 60 words among 500 other words, so that a long
        // bucket's own pass (on y) has long buckets (on z), three levels.
        let mut lines: Vec<[f32; 3]> = (0..3000).map(|i| plane(x(i), &mut rng)).collect();
        for i in 0..3 * 500 {
            lines.push(plane(x(i % 3 * 1000 + 1), &mut rng));
        }
        for i in 0..3 * 4 * 60 {
            let (p, l) = (i % 3, i / 3 % 4);
            lines.push([x(p * 1000 + 1), 2000.0 + l as f32, (rng() % 1000) as f32]);
        }
        // One case for each path.
        const { assert!(3 <= LONG_BUCKETS && LONG_BUCKETS < 200) };
        for pos in [few, many, lines] {
            let words: Vec<u128> = pos
                .iter()
                .enumerate()
                .map(|(i, &p)| vertex_word(p, i))
                .collect();
            let mut expect = words.clone();
            expect.sort_unstable();
            let (lo, hi) = component_range::<96>(&words);
            // In place, and into the scratch (as a long bucket's pass
            // sorts), each with the same words.
            for into in [false, true] {
                let mut a = words.clone();
                let mut scratch = vec![0u128; words.len()];
                let pass = if into {
                    counting_pass::<96, false, true>
                } else {
                    counting_pass::<96, false, false>
                };
                pass(&mut a, &mut scratch, &mut Vec::new(), lo, hi - lo);
                if into {
                    a = scratch;
                }
                assert!(
                    a.windows(2).all(|w| key(w[0]) <= key(w[1])),
                    "sorted, into: {into}"
                );
                a.sort_unstable();
                assert!(a == expect, "the same words, into: {into}");
            }
        }
    }

    /// The obvious implementation: a sorted map of canonical positions.
    fn reference(pos: &[[f32; 3]], idx: &[u32]) -> Welded {
        use std::collections::BTreeMap;
        let key = |i: u32| pos[i as usize].map(canonical).map(order_key);
        let mut out = Welded::default();
        let mut kept = Vec::new();
        let mut ids: BTreeMap<[u32; 3], u32> = BTreeMap::new();
        for (t, c) in idx.chunks_exact(3).enumerate() {
            let k = [key(c[0]), key(c[1]), key(c[2])];
            if k[0] == k[1] || k[1] == k[2] || k[0] == k[2] {
                out.dropped.push(t as u32);
            } else {
                kept.push((t as u32, c));
                for (k, &i) in k.into_iter().zip(c) {
                    ids.entry(k).or_insert(i);
                }
            }
        }
        for (n, first) in ids.values_mut().enumerate() {
            out.positions.push(pos[*first as usize].map(canonical));
            *first = n as u32;
        }
        for (t, c) in kept {
            out.triangles.extend(c.iter().map(|&i| ids[&key(i)]));
            out.source_triangle.push(t);
        }
        out
    }

    #[test]
    fn large_input_matches_reference_with_any_threads() {
        let mut pos = hard_positions(3 * VERTEX_BLOCK, 11);
        pos.push([f32::NAN, 0.0, 0.0]); // never referenced
        pos.push([f32::INFINITY, 0.0, 0.0]); // never referenced
        let mut bits = crate::multiplicity::test_bits(0x9e37_79b9_7f4a_7c15u64);
        let mut rng = move || bits() >> 11;
        // Mostly corners near each other in the input, as meshes have them,
        // some anywhere; the last 1000 finite vertices are never used.
        let used = (pos.len() - 2 - 1000) as u64;
        let idx: Vec<u32> = (0..6 * pos.len() as u64)
            .map(|i| {
                let r = rng();
                let v = if r % 4 == 0 {
                    r >> 2
                } else {
                    i / 6 + (r >> 2) % 64
                };
                (v % used) as u32
            })
            .collect();
        let expect = reference(&pos, &idx);
        assert!(expect.degenerate() > 0);
        for threads in [1, 2, 3] {
            let w = with_threads(threads, || weld(&pos, &idx));
            assert_eq!(w.positions, expect.positions, "{threads} threads");
            assert_eq!(w.triangles, expect.triangles, "{threads} threads");
            assert_eq!(w.source_triangle, expect.source_triangle);
            assert_eq!(w.degenerate(), expect.degenerate());
            assert_eq!(w.dropped, expect.dropped);
            // The timed form (what `stage_probe -- weld` runs) welds the
            // same, without sources.
            let (t, _) = with_threads(threads, || weld_without_sources_timed(&pos, &idx));
            assert!(t.positions == expect.positions, "{threads} threads, timed");
            assert!(t.triangles == expect.triangles, "{threads} threads, timed");
            assert!(t.dropped == expect.dropped, "{threads} threads, timed");
            assert!(t.source_triangle.is_empty());
        }
        // Every finite vertex once, in input order: no degenerate triangle
        // (repeated positions aside) and fewer triangles than vertices, so
        // the words do not fit in the triangle buffer.
        let idx: Vec<u32> = (0..(pos.len() as u32 - 2) / 3 * 3).collect();
        let expect = reference(&pos, &idx);
        let w = weld(&pos, &idx);
        assert_eq!(w.positions, expect.positions);
        assert_eq!(w.triangles, expect.triangles);
        assert_eq!(w.source_triangle, expect.source_triangle);
        assert_eq!(w.degenerate(), expect.degenerate());
    }

    /// Step 3's parts: each closes up its own dropped triangles as it
    /// renames, then moves down after the parts before it. Dropped: none,
    /// a few everywhere, every triangle of a part (the first, a middle
    /// one, the last), and many.
    #[test]
    fn dropped_triangles_closed_up_with_any_threads() {
        let count = 6 * TRI_BLOCK + 40;
        let pos: Vec<[f32; 3]> = (0..count + 2).map(|i| [i as f32, 0.5, -1.0]).collect();
        type Dropped = fn(usize, usize) -> bool;
        let cases: [(&str, Dropped); 6] = [
            ("none", |_, _| false),
            ("few", |t, _| {
                t % 997 == 3 || t == 1 || t == 6 * TRI_BLOCK + 39
            }),
            ("the first part", |t, n| t < n / 2 || t % 4093 == 0),
            ("a middle part", |t, n| (n / 3..2 * n / 3).contains(&t)),
            ("the last part", |t, n| t >= n / 2),
            ("many", |t, _| t % 7 < 3),
        ];
        for (what, drop) in &cases {
            // Triangle t is (t, t + 1, t + 2), or (t, t, t + 1) when dropped.
            let idx: Vec<u32> = (0..count)
                .flat_map(|t| {
                    let t = t as u32;
                    if drop(t as usize, count) {
                        [t, t, t + 1]
                    } else {
                        [t, t + 1, t + 2]
                    }
                })
                .collect();
            let expect = reference(&pos, &idx);
            for threads in [1, 2, 3] {
                let w = with_threads(threads, || weld(&pos, &idx));
                assert!(w.triangles == expect.triangles, "{what}, {threads} threads");
                assert!(w.dropped == expect.dropped, "{what}, {threads} threads");
                assert!(w.positions == expect.positions, "{what}, {threads} threads");
                assert!(
                    w.source_triangle == expect.source_triangle,
                    "{what}, {threads} threads"
                );
            }
        }
    }

    #[test]
    fn small_and_uniform_inputs() {
        let empty = weld(&[], &[]);
        assert!(empty.positions.is_empty() && empty.triangles.is_empty());
        // One x for every vertex (a single bucket).
        let pos: Vec<[f32; 3]> = (0..300)
            .map(|i| [2.0, (i % 7) as f32, (i % 5) as f32])
            .collect();
        let idx: Vec<u32> = (0..300).rev().collect();
        let (w, n) = (weld(&pos, &idx), reference(&pos, &idx));
        assert_eq!((w.positions, w.triangles), (n.positions, n.triangles));
        // One position for every vertex: every triangle degenerate.
        let w = weld(&[[1.0, -0.0, 3.0]; 30], &(0..30).collect::<Vec<u32>>());
        assert_eq!(w.degenerate(), 10);
        assert!(w.positions.is_empty() && w.triangles.is_empty());
        assert!(w.source_triangle.is_empty());
    }
}
