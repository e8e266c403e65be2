//! Cap signs from corner ids: [`Strategy::Reference`](crate::evaluate::Strategy)
//! orientations of every caps triangle, evaluated over a table of the
//! file's distinct positions with each triangle's corners sorted once per
//! file instead of once per light.
//!
//! Why: per light, the record kernel ([`crate::evaluate_simd::cap_signs`])
//! reads 48 bytes per triangle and runs the three-comparator network on
//! float corners (nine lexicographic comparisons and as many selects per
//! triangle). When the position table is strictly increasing in the
//! contract's lexicographic order, comparing two ids *is* comparing the two
//! positions (`a < b` ⇔ `lex_less(P[a], P[b])`, equal ids compare equal
//! both ways, NaN included), so the network run once on ids takes exactly
//! the decisions it would take on the floats: the same sorted corners, the
//! same parity. What is left per light is the contract's expression on
//! three gathered corners ([`crate::evaluate_simd`]'s `sorted_sign_nb`,
//! itself [`crate::multiplicity::ref_expr`]), reading 12 bytes of ids and
//! one parity byte per triangle. The results are bit for bit those of the
//! record kernel; the tests compare the two.
//!
//! A table that is not strictly increasing (a NaN, or `+0.0` and `−0.0` at
//! otherwise equal positions: distinct bit patterns that compare equal)
//! breaks the equivalence, and [`IndexedCaps::new`] declines it; callers
//! then use the record kernel.
//!
//! Several lights ([`IndexedCaps::cap_signs_many`],
//! [`IndexedCaps::cap_sign_pairs`]) share each block's gathers and
//! transposes, most of the one-light kernel's instructions: on the dragon,
//! 0.48–0.50 ms per light in groups of four against 0.91–0.94 ms one at a
//! time (one thread, `cargo run --release --example stage_probe --
//! evaluate target/dragon/dragon.glb`, its `four lights, caps alone`
//! line, three runs, thirty-seventh round; 0.61–0.64 against 1.11–1.26 ms
//! before that round's `Kernel::Avx512Vl` copy).

use crate::evaluate_simd::{Corner, LANES, sorted_sign_nb, sorted_sign_off_corners};
use crate::multiplicity::{Light, lex_less};
use rayon::prelude::*;

/// Triangles per rayon task: large enough that scheduling costs nothing.
const CHUNK: usize = 4096;

/// Lights per pass of [`IndexedCaps::cap_signs_many`].
pub const LIGHT_GROUP: usize = 4;

/// Caps triangles as sorted corner ids into a position table. Built once per
/// file by [`IndexedCaps::new`]; [`IndexedCaps::cap_signs`] per light.
#[derive(Debug, Clone)]
pub struct IndexedCaps {
    /// The positions the triangles use, `x, y, z` each, in order of first
    /// use, then one float more: a corner is one 16-byte load of its three
    /// floats and the next one (the next point's `x`, or that last float),
    /// which no kernel uses (see [`row`]).
    points: Vec<f32>,
    /// Per triangle, its corners in the order the contract's
    /// three-comparator network sorts them to, each as three times its id
    /// into the positions, the offset of its first float in `points` (see
    /// [`row`]).
    sorted: Vec<[u32; 3]>,
    /// Per triangle, whether that sort was an odd permutation.
    odd: Vec<bool>,
    /// Ids into `points` in the contract's lexicographic order: finds
    /// whether a point light sits on a corner with one binary search.
    lex: Vec<u32>,
}

/// The three-comparator network of the contract (format-spec §3) on ids:
/// the same comparator sequence, swapping only when the later id is
/// strictly smaller, and the parity of the swaps (true when odd). `verify`
/// keys triangles by the same sort.
pub(crate) fn sort_ids(mut v: [u32; 3]) -> ([u32; 3], bool) {
    let mut odd = false;
    for (i, j) in [(0, 1), (1, 2), (0, 1)] {
        if v[j] < v[i] {
            v.swap(i, j);
            odd = !odd;
        }
    }
    (v, odd)
}

impl IndexedCaps {
    /// Sorts the corners of every triangle of `caps` (ids into `positions`)
    /// once. `None` when `positions` is not strictly increasing under
    /// [`lex_less`] or an id is out of range: then id order would not be
    /// the contract's order, and the caller must evaluate the records.
    /// `None` too for more than about 1.43 billion positions, whose rows'
    /// offsets would not fit the `u32` corners (see `row`).
    pub fn new(positions: &[[f32; 3]], caps: &[[u32; 3]]) -> Option<Self> {
        if !positions.windows(2).all(|w| lex_less(w[0], w[1])) {
            return None;
        }
        let n = positions.len();
        if n > MAX_POINTS || caps.iter().flatten().any(|&i| i as usize >= n) {
            return None;
        }
        let (mut sorted, odd): (Vec<[u32; 3]>, Vec<bool>) =
            caps.iter().map(|&c| sort_ids(c)).unzip();
        // Renumber the table in order of first use by the triangles (the
        // corners' sorted order is kept; only the names change). The
        // lexicographic numbering scatters a triangle's corners over the
        // whole table, so every corner load missed the cache: on the 871k
        // triangle dragon this kernel was 2.3× slower than the record kernel
        // before, and is faster after (benches/evaluate.rs,
        // `caps/reference_indexed`).
        let mut rename = vec![u32::MAX; n];
        let mut points = Vec::with_capacity(3 * n + 1);
        for id in sorted.iter_mut().flatten() {
            let r = &mut rename[*id as usize];
            if *r == u32::MAX {
                *r = (points.len() / 3) as u32;
                points.extend_from_slice(&positions[*id as usize]);
            }
            *id = 3 * *r;
        }
        // The last row's fourth float (see `row`).
        points.push(0.0);
        // `positions` is in lexicographic order, so the used ones, renamed,
        // are too.
        let lex = rename.into_iter().filter(|&r| r != u32::MAX).collect();
        Some(IndexedCaps {
            points,
            sorted,
            odd,
            lex,
        })
    }

    /// Whether `l` is a point light equal (`==` on each coordinate, as the
    /// contract's test) to one of the triangles' corners. When it is not,
    /// no triangle needs the light-on-corner test.
    ///
    /// The table is strictly increasing and NaN-free (checked by `new`),
    /// and the lexicographic comparison below treats `−0.0` and `+0.0` as
    /// `==` does, so the binary search finds an equal point whenever there
    /// is one. A light with a NaN equals no corner; the search may then
    /// answer either way, and `true` only costs the test.
    pub(crate) fn light_on_a_corner(&self, l: Light) -> bool {
        use std::cmp::Ordering;
        l[3] == 1.0
            && self
                .lex
                .binary_search_by(|&i| {
                    // SAFETY: `lex` holds ids of `points`' rows (`new`),
                    // and three times an id is a row's offset.
                    let p = unsafe { row(&self.points, 3 * i) };
                    for a in 0..3 {
                        if p[a] < l[a] {
                            return Ordering::Less;
                        }
                        if p[a] > l[a] {
                            return Ordering::Greater;
                        }
                    }
                    Ordering::Equal
                })
                .is_ok()
    }

    /// Number of distinct positions the triangles use (rows of `points`).
    fn rows(&self) -> usize {
        self.points.len() / 3
    }

    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.sorted.len()
    }

    /// True when there are no triangles.
    pub fn is_empty(&self) -> bool {
        self.sorted.is_empty()
    }

    /// Triangle `t`'s corners in the contract's sorted order, and whether
    /// that order is an odd permutation of its stored one (then its
    /// orientation is the opposite of theirs). The points are in order of
    /// first use, so consecutive triangles read nearby rows.
    #[inline(always)]
    pub fn sorted_corners(&self, t: usize) -> ([&[f32; 3]; 3], bool) {
        // Array literals, not `map`: through `map` the row lookups were
        // compiled out of line (`try_map`, 6% of `verify`'s samples).
        let corner = |c: u32| -> &[f32; 3] {
            let r = c as usize;
            self.points[r..r + 3].try_into().expect("three floats")
        };
        let [a, b, c] = self.sorted[t];
        ([corner(a), corner(b), corner(c)], self.odd[t])
    }

    /// Whether triangle `t`'s sorted corners ([`IndexedCaps::sorted_corners`])
    /// are an odd permutation of its stored ones.
    #[inline(always)]
    pub fn odd(&self, t: usize) -> bool {
        self.odd[t]
    }

    /// The sorted corners of the [`LANES`] triangles from `first` into
    /// lanes: `dst[c][a][i]` is coordinate `a` of sorted corner `c` of
    /// triangle `first + i`, the floats [`IndexedCaps::sorted_corners`]
    /// gives. With `AVX2` each row is loaded whole and the rows transposed
    /// in registers: `verify`'s orientation check filters a block at a
    /// time in vectors, and element-by-element copies into the lanes went
    /// through the stack and were read back by wider loads, which the CPU
    /// cannot forward.
    ///
    /// # Safety
    /// With `AVX2`, the CPU must have AVX2 (the caller is compiled with
    /// it). Panics when the block passes the last triangle.
    #[inline(always)]
    pub(crate) unsafe fn sorted_corner_lanes<const AVX2: bool>(
        &self,
        first: usize,
        dst: &mut [Corner; 3],
    ) {
        let t = &self.sorted[first..first + LANES];
        for (c, d) in dst.iter_mut().enumerate() {
            // SAFETY: every stored corner names a row of `points` (`new`);
            // AVX2 is the caller's.
            unsafe { gather::<AVX2>(&self.points, t, c, d) };
        }
    }

    /// Reference orientation of every triangle for light `l`: `out[t]` is
    /// `tri_sign` of triangle `t`'s corners in their stored order, bit for
    /// bit what [`crate::evaluate_simd::cap_signs`] computes from the
    /// records. `out.len()` must equal [`IndexedCaps::len`].
    pub fn cap_signs(&self, l: Light, out: &mut [i8]) {
        assert_eq!(out.len(), self.sorted.len(), "caps size mismatch");
        let on_corner = self.light_on_a_corner(l);
        out.par_chunks_mut(CHUNK)
            .zip(self.sorted.par_chunks(CHUNK))
            .zip(self.odd.par_chunks(CHUNK))
            .for_each(|((o, t), odd)| self.signs(t, odd, l, on_corner, o));
    }

    /// [`IndexedCaps::cap_signs`] for several lights: `out[i]` gets light
    /// `i`'s signs, bit for bit what `cap_signs(lights[i], out[i])` writes.
    /// The lights go through the kernel in groups of [`LIGHT_GROUP`], each
    /// block of triangles gathered once per group (a group of one takes
    /// `cap_signs`' own path).
    pub fn cap_signs_many(&self, lights: &[Light], out: &mut [&mut [i8]]) {
        assert_eq!(lights.len(), out.len(), "one output per light");
        for o in out.iter() {
            assert_eq!(o.len(), self.sorted.len(), "caps size mismatch");
        }
        for (l, o) in lights.chunks(LIGHT_GROUP).zip(out.chunks_mut(LIGHT_GROUP)) {
            match l.len() {
                1 => self.cap_signs(l[0], o[0]),
                2 => self.group::<2>(l, o),
                3 => self.group::<3>(l, o),
                _ => self.group::<LIGHT_GROUP>(l, o),
            }
        }
    }

    /// One group of `N` lights (`lights.len()` and `out.len()` are `N`),
    /// chunk by chunk on rayon's threads.
    fn group<const N: usize>(&self, lights: &[Light], out: &mut [&mut [i8]]) {
        let lights: [Light; N] = lights.try_into().expect("a group of N lights");
        let on_corner = lights.iter().any(|&l| self.light_on_a_corner(l));
        let mut outs = out.iter_mut();
        let out: [&mut [i8]; N] = std::array::from_fn(|_| &mut **outs.next().expect("N outputs"));
        let jobs: Vec<Bytes<N>> = chunks_of(out, CHUNK).into_iter().map(Bytes).collect();
        jobs.into_par_iter()
            .zip(self.sorted.par_chunks(CHUNK))
            .zip(self.odd.par_chunks(CHUNK))
            .for_each(|((mut o, t), odd)| self.signs_many(t, odd, lights, on_corner, &mut o));
    }

    /// The signs of a group of [`LIGHT_GROUP`] lights as the biased pairs
    /// [`crate::evaluate_ordered`]'s group reads: `table[2t]` holds, byte
    /// `i` for light `i`, `1 + s` of triangle `t`'s sign `s`, and
    /// `table[2t + 1]` holds `1 − s` (so that no byte is negative). Written
    /// by the kernel as it computes the signs, each `s` bit for bit
    /// `cap_signs`'; `table.len()` must be twice [`IndexedCaps::len`].
    ///
    /// Also the same signs as a byte per triangle into `packed` (its length
    /// [`IndexedCaps::len`]): light `i`'s `1 + s` in bits `2i` and `2i + 1`,
    /// made from each chunk's entries while they are in cache.
    pub fn cap_sign_pairs(
        &self,
        lights: &[Light; LIGHT_GROUP],
        table: &mut [u32],
        packed: &mut [u8],
    ) {
        assert_eq!(table.len(), 2 * self.sorted.len(), "table size mismatch");
        assert_eq!(packed.len(), self.sorted.len(), "packed size mismatch");
        let on_corner = lights.iter().any(|&l| self.light_on_a_corner(l));
        table
            .par_chunks_mut(2 * CHUNK)
            .zip(packed.par_chunks_mut(CHUNK))
            .zip(self.sorted.par_chunks(CHUNK))
            .zip(self.odd.par_chunks(CHUNK))
            .for_each(|(((o, p), t), odd)| {
                self.signs_many(t, odd, *lights, on_corner, &mut Pairs(o));
                for (p, o) in p.iter_mut().zip(o.chunks_exact(2)) {
                    *p = packed_byte(o[0]);
                }
            });
    }

    /// One chunk of a group of `N` lights into `sink`, through the widest
    /// copy of the block loop the CPU runs ([`Kernel::detect`]; the lights
    /// share each block's corner loads and transposes).
    fn signs_many<const N: usize, S: Sink<N>>(
        &self,
        sorted: &[[u32; 3]],
        odd: &[bool],
        lights: [Light; N],
        on_corner: bool,
        sink: &mut S,
    ) {
        let form = Form::of(&lights, on_corner);
        // SAFETY: `detect` gives a copy the CPU runs; every corner names a
        // row of points (`new` stores them so); `sink` holds `sorted.len()`
        // triangles (the callers cut both into the same chunks).
        unsafe {
            run(
                Kernel::detect(),
                form,
                &self.points,
                sorted,
                odd,
                lights,
                sink,
            )
        }
    }

    /// One chunk, through the AVX-512 version where its gathers pay
    /// (`evaluate_simd::gather_caps`) and the table's float offsets fit
    /// their 32-bit indices (with the light-on-corner test only when
    /// `on_corner`), else through [`IndexedCaps::signs_many`]'s copies.
    fn signs(&self, sorted: &[[u32; 3]], odd: &[bool], l: Light, on_corner: bool, out: &mut [i8]) {
        #[cfg(target_arch = "x86_64")]
        if self.rows() <= MAX_GATHER_POINTS
            && crate::evaluate_simd::gather_caps(self.len() >= GATHER_MIN_TRIANGLES)
        {
            // SAFETY: the CPU has AVX-512F (`gather_caps` checks it); every
            // corner names a row of points (`new` stores them so), whose
            // float offsets fit an i32 (checked just above).
            return unsafe {
                if on_corner {
                    signs_avx512::<true>(&self.points, sorted, odd, l, out)
                } else {
                    signs_avx512::<false>(&self.points, sorted, odd, l, out)
                }
            };
        }
        self.signs_many(sorted, odd, [l], on_corner, &mut Bytes([out]));
    }
}

/// The copies of the block loop ([`signs_many_impl`]) that the crate
/// compiles: the same source under three sets of target features.
///
/// Why a copy with AVX-512 on 256-bit vectors: with AVX-512VL and BW the
/// compiler turns a block's signs into bytes with two compares into mask
/// registers and two `vpmovm2b` (the AVX2 copy: two extracts and four
/// packs), and has 32 vector registers instead of 16. On this machine's
/// Zen 4, where 512-bit vectors run as two halves and the gathers are slow
/// (see `evaluate_simd::gather_caps`), that copy took the dragon's caps
/// from 1.002 to 0.919 ms, and with [`Form::OffCornersPoint`] to 0.876
/// (fastest of 1,000 rounds, the copies alternated in one process, a
/// scratch probe; benches/ROUNDS.md, thirty-seventh round).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kernel {
    /// The baseline's (SSE2 on x86-64): the corners copied lane by lane.
    Plain,
    /// AVX2: each corner's row loaded whole, the loads transposed.
    Avx2,
    /// The AVX2 copy compiled with AVX-512F, VL, BW and DQ as well.
    Avx512Vl,
}

impl Kernel {
    /// The widest copy the CPU runs (no AVX-512 after
    /// `evaluate_simd::disable_avx512`).
    pub(crate) fn detect() -> Kernel {
        if crate::evaluate_simd::have_avx512vl() {
            Kernel::Avx512Vl
        } else if crate::evaluate_simd::have_avx2() {
            Kernel::Avx2
        } else {
            Kernel::Plain
        }
    }

    /// Every copy the CPU runs, the plain one first.
    #[cfg(test)]
    fn available() -> Vec<Kernel> {
        let mut v = vec![Kernel::Plain];
        if crate::evaluate_simd::have_avx2() {
            v.push(Kernel::Avx2);
        }
        if crate::evaluate_simd::have_avx512vl() {
            v.push(Kernel::Avx512Vl);
        }
        v
    }
}

/// What each lane of the block loop computes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Form {
    /// `sorted_sign_nb`, with the light-on-corner test: for a group where
    /// some light equals a corner.
    Tested,
    /// `sorted_sign_off_corners`: the caller knows no light is on a corner.
    OffCorners,
    /// The same for point lights only, each light's `w` replaced by the
    /// constant 1: the compiler then drops the contract's three products
    /// `r0·w` (`x · 1` is `x` exactly, NaN included), so the lanes hold
    /// the same floats with three multiplications fewer per block.
    OffCornersPoint,
}

impl Form {
    /// The form for `lights`: [`Form::Tested`] when `on_corner`.
    fn of(lights: &[Light], on_corner: bool) -> Form {
        if on_corner {
            Form::Tested
        } else if lights.iter().all(|l| l[3] == 1.0) {
            Form::OffCornersPoint
        } else {
            Form::OffCorners
        }
    }
}

/// [`signs_many_impl`] through copy `kernel` in form `form`.
///
/// # Safety
/// The CPU must run `kernel` ([`Kernel::detect`], [`Kernel::available`]);
/// every corner of `sorted` must name a row of `points` ([`row`]); `sink`
/// must hold `sorted.len()` triangles; with [`Form::OffCornersPoint`]
/// every light's `w` must be 1 (with [`Form::OffCorners`] or
/// [`Form::OffCornersPoint`], no point light may equal a corner, or those
/// triangles' signs are the expression's instead of 0).
unsafe fn run<const N: usize, S: Sink<N>>(
    kernel: Kernel,
    form: Form,
    points: &[f32],
    sorted: &[[u32; 3]],
    odd: &[bool],
    lights: [Light; N],
    sink: &mut S,
) {
    let args = (points, sorted, odd, lights, sink);
    // The copy `$copy` with the form's `TEST` and `POINT`.
    macro_rules! in_form {
        ($copy:ident) => {
            match form {
                Form::Tested => $copy::<true, false, N, S>(args),
                Form::OffCorners => $copy::<false, false, N, S>(args),
                Form::OffCornersPoint => $copy::<false, true, N, S>(args),
            }
        };
    }
    // SAFETY: the caller's.
    unsafe {
        match kernel {
            Kernel::Plain => in_form!(plain),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 => in_form!(avx2),
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx512Vl => in_form!(avx512vl),
            #[cfg(not(target_arch = "x86_64"))]
            _ => in_form!(plain),
        }
    }
}

/// The arguments of [`signs_many_impl`], as [`run`] passes them on.
type Args<'a, const N: usize, S> = (&'a [f32], &'a [[u32; 3]], &'a [bool], [Light; N], &'a mut S);

/// [`signs_many_impl`] in the baseline's instructions.
///
/// # Safety
/// As [`run`]'s.
unsafe fn plain<const TEST: bool, const POINT: bool, const N: usize, S: Sink<N>>(
    (points, sorted, odd, lights, sink): Args<N, S>,
) {
    // SAFETY: the caller's.
    unsafe { signs_many_impl::<false, TEST, POINT, N, S>(points, sorted, odd, lights, sink) }
}

/// [`signs_many_impl`] compiled with AVX2.
///
/// # Safety
/// As [`run`]'s; the CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn avx2<const TEST: bool, const POINT: bool, const N: usize, S: Sink<N>>(
    (points, sorted, odd, lights, sink): Args<N, S>,
) {
    // SAFETY: the caller's.
    unsafe { signs_many_impl::<true, TEST, POINT, N, S>(points, sorted, odd, lights, sink) }
}

/// [`signs_many_impl`] compiled with AVX2 and AVX-512F, VL, BW and DQ
/// ([`Kernel::Avx512Vl`]).
///
/// # Safety
/// As [`run`]'s; the CPU must have those features
/// (`evaluate_simd::have_avx512vl`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,avx512f,avx512vl,avx512bw,avx512dq")]
unsafe fn avx512vl<const TEST: bool, const POINT: bool, const N: usize, S: Sink<N>>(
    (points, sorted, odd, lights, sink): Args<N, S>,
) {
    // SAFETY: the caller's.
    unsafe { signs_many_impl::<true, TEST, POINT, N, S>(points, sorted, odd, lights, sink) }
}

/// The four floats of `points` from offset `r`: the row of a stored corner
/// (three times its id), its `x, y, z` and one float more.
///
/// Why 12-byte rows read 16 bytes at a time: the kernels load a corner
/// whole and transpose the loads, and with rows of `x, y, z, 0` the table
/// took 16 bytes per point, 7.0 MB on the dragon, with 12 it takes 5.2 MB
/// (one light reads about 32 MB in all, this CPU's L3 holds 32 MiB). The
/// offset is the corner itself: an x86 address scales an index by 4, so
/// each row load addresses `base + 4·r` with no instruction to compute it
/// (the corners were stored as twice their ids for rows of 16 bytes, for
/// the same reason, thirtieth round).
///
/// # Safety
/// `r + 4` must be at most `points.len()`.
#[inline(always)]
unsafe fn row(points: &[f32], r: u32) -> &[f32; 4] {
    // SAFETY: the caller's.
    unsafe { &*points.as_ptr().add(r as usize).cast::<[f32; 4]>() }
}

/// Most positions a table may hold: three times the largest id (a stored
/// corner, see [`row`]) fits a `u32`.
const MAX_POINTS: usize = u32::MAX as usize / 3;

/// Corner `c` of the [`LANES`] triangles `t` into lanes.
///
/// The rows are read without bounds checks: the 24 compares and branches
/// per block were an eighth of the AVX2 kernel's instructions, and their
/// removal made the dragon's caps 1–8% faster (1.75, 1.62, 1.73 against
/// 1.77, 1.76, 1.81 ms, fastest of 40 alternated rounds, three runs of
/// `cargo run --release --example stage_probe -- evaluate
/// target/dragon/dragon.glb` with each binary).
///
/// # Safety
/// Every corner of `t` must name a row of `points` (see [`row`]).
#[inline(always)]
unsafe fn gather<const AVX2: bool>(points: &[f32], t: &[[u32; 3]], c: usize, dst: &mut Corner) {
    // SAFETY: the caller's.
    let rows: [&[f32; 4]; LANES] = std::array::from_fn(|i| unsafe { row(points, t[i][c]) });
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        // SAFETY: `AVX2` is true only in code compiled with the `avx2`
        // feature, which runs only after the CPU was found to have it.
        unsafe { crate::evaluate_simd::load_rows_avx2(rows, dst) };
        return;
    }
    for (i, r) in rows.iter().enumerate() {
        for (a, lane) in dst.iter_mut().enumerate() {
            lane[i] = r[a];
        }
    }
}

/// Blocks of [`LANES`] triangles (three gathered corners, then one lane per
/// triangle through `sorted_sign_nb`, which LLVM vectorises, or with `TEST`
/// false `sorted_sign_off_corners`: the caller knows the light is on no
/// corner), then the tail triangle by triangle through `sorted_sign_nb`.
/// One light: [`signs_many_impl`] with a group of one.
///
/// The version without the test is the AVX2 kernel's since the
/// twenty-fifth round, when this machine's CPU became one (AMD Zen 4) on
/// which the AVX-512 kernel, which had it already, does not run: the
/// dragon's caps 1.83 → 1.63 ms (fastest of 40 alternated rounds, the
/// middle of three runs of `cargo run --release --example stage_probe --
/// evaluate target/dragon/dragon.glb` with each binary).
///
/// # Safety
/// Every corner of `sorted` must name a row of `points` ([`row`], as
/// `IndexedCaps::new` stores them).
#[inline(always)]
unsafe fn signs_impl<const AVX2: bool, const TEST: bool>(
    points: &[f32],
    sorted: &[[u32; 3]],
    odd: &[bool],
    l: Light,
    out: &mut [i8],
) {
    // SAFETY: the caller's.
    let out = &mut Bytes([out]);
    // SAFETY: the caller's; `out` holds `sorted.len()` triangles.
    unsafe { signs_many_impl::<AVX2, TEST, false, 1, _>(points, sorted, odd, [l], out) }
}

/// The `N` outputs cut into pieces of `chunk` bytes, the pieces at the
/// same place together: one rayon task each.
pub(crate) fn chunks_of<const N: usize>(out: [&mut [i8]; N], chunk: usize) -> Vec<[&mut [i8]; N]> {
    let pieces = out
        .iter()
        .map(|o| o.len().div_ceil(chunk))
        .max()
        .unwrap_or(0);
    let mut out = out.map(|o| o.chunks_mut(chunk));
    (0..pieces)
        .map(|_| out.each_mut().map(|o| o.next().unwrap_or_default()))
        .collect()
}

/// Where the kernel puts each light's signs.
trait Sink<const N: usize> {
    /// The signs of the chunk's block `b` (its triangles `LANES · b ..`),
    /// per light. Unchecked: the bounds checks of the two sinks' slices
    /// were 6 of the one-light block's 118 instructions, and the dragon's
    /// caps took 0.915 ms with them and 0.888 without (fastest of eight
    /// alternated runs of 300 rounds, a scratch probe).
    ///
    /// # Safety
    /// The sink must hold at least `LANES · (b + 1)` triangles.
    unsafe fn block(&mut self, b: usize, s: &[[i32; LANES]; N]);
    /// The signs of the chunk's triangle `t`, per light.
    fn one(&mut self, t: usize, s: [i32; N]);
}

/// One byte per triangle per light: `.0[light][triangle]`.
struct Bytes<'a, const N: usize>([&'a mut [i8]; N]);

impl<const N: usize> Sink<N> for Bytes<'_, N> {
    #[inline(always)]
    unsafe fn block(&mut self, b: usize, s: &[[i32; LANES]; N]) {
        for (o, s) in self.0.iter_mut().zip(s) {
            debug_assert!(o.len() >= LANES * (b + 1));
            // An array, so that the eight stores compile to one.
            // SAFETY: the caller's: bytes `LANES · b ..` of `o` are the
            // block's.
            let o = unsafe { &mut *o.as_mut_ptr().add(LANES * b).cast::<[i8; LANES]>() };
            for (o, &s) in o.iter_mut().zip(s) {
                *o = s as i8;
            }
        }
    }

    #[inline(always)]
    fn one(&mut self, t: usize, s: [i32; N]) {
        for (o, s) in self.0.iter_mut().zip(s) {
            o[t] = s as i8;
        }
    }
}

/// The biased pairs of [`IndexedCaps::cap_sign_pairs`], two entries per
/// triangle.
struct Pairs<'a>(&'a mut [u32]);

/// The byte of [`IndexedCaps::cap_sign_pairs`]' `packed` from a triangle's
/// `1 + s` entry: light `i`'s `1 + s` (0, 1 or 2, byte `i` of `plus`) in
/// bits `2i, 2i + 1` (each shift brings one byte's two bits down; the
/// bits it brings above them are cut off).
#[inline(always)]
fn packed_byte(plus: u32) -> u8 {
    const _: () = assert!(LIGHT_GROUP == 4, "four lights' two bits fill a byte");
    (plus | plus >> 6 | plus >> 12 | plus >> 18) as u8
}

/// Triangle `i`'s entries of the pairs from its lights' signs `s`.
#[inline(always)]
fn pair(s: impl Fn(usize) -> i32) -> [u32; 2] {
    let (mut plus, mut minus) = (0u32, 0u32);
    for l in 0..LIGHT_GROUP {
        plus |= ((1 + s(l)) as u32) << (8 * l);
        minus |= ((1 - s(l)) as u32) << (8 * l);
    }
    [plus, minus]
}

impl Sink<LIGHT_GROUP> for Pairs<'_> {
    #[inline(always)]
    unsafe fn block(&mut self, b: usize, s: &[[i32; LANES]; LIGHT_GROUP]) {
        debug_assert!(self.0.len() >= 2 * LANES * (b + 1));
        // SAFETY: the caller's: entries `2 · LANES · b ..` are the block's.
        let o = unsafe {
            &mut *self
                .0
                .as_mut_ptr()
                .add(2 * LANES * b)
                .cast::<[u32; 2 * LANES]>()
        };
        for (i, o) in o.chunks_exact_mut(2).enumerate() {
            o.copy_from_slice(&pair(|l| s[l][i]));
        }
    }

    #[inline(always)]
    fn one(&mut self, t: usize, s: [i32; LIGHT_GROUP]) {
        self.0[2 * t..2 * t + 2].copy_from_slice(&pair(|l| s[l]));
    }
}

/// [`signs_impl`] for `N` lights at once: each block's corners gathered and
/// transposed once, then every light's lanes from the same registers, into
/// `sink`. The gathers, their transposes and the corner differences that
/// do not depend on the light are most of the one-light kernel's
/// instructions, so a group of four lights costs far less than four
/// passes. Each light's lanes run the same `sorted_sign_nb` (or
/// `sorted_sign_off_corners`) on the same floats as a pass of its own: the
/// same bits.
///
/// With `POINT`, every light's `w` is taken as the constant 1
/// ([`Form::OffCornersPoint`]).
///
/// # Safety
/// Every corner of `sorted` must name a row of `points` ([`row`]), `sink`
/// must hold `sorted.len()` triangles, and with `POINT` every light's `w`
/// must be 1.
#[inline(always)]
unsafe fn signs_many_impl<
    const AVX2: bool,
    const TEST: bool,
    const POINT: bool,
    const N: usize,
    S: Sink<N>,
>(
    points: &[f32],
    sorted: &[[u32; 3]],
    odd: &[bool],
    lights: [Light; N],
    sink: &mut S,
) {
    let xyz = |r: u32| {
        // SAFETY: the caller's.
        let p = unsafe { row(points, r) };
        [p[0], p[1], p[2]]
    };
    let lights = if POINT {
        lights.map(|l| [l[0], l[1], l[2], 1.0])
    } else {
        lights
    };
    let mut tris = sorted.chunks_exact(LANES);
    let mut odds = odd.chunks_exact(LANES);
    for (b, (t, odd)) in (&mut tris).zip(&mut odds).enumerate() {
        // The corners' stream (96 bytes a block, so both of its lines).
        crate::hint::prefetch_stream(t.as_ptr());
        crate::hint::prefetch_stream(t.as_ptr().cast::<u8>().wrapping_add(64));
        let mut p = [[[0f32; LANES]; 3]; 3];
        for (c, p) in p.iter_mut().enumerate() {
            // SAFETY: the caller's.
            unsafe { gather::<AVX2>(points, t, c, p) };
        }
        let mut s = [[0i32; LANES]; N];
        for (s, &l) in s.iter_mut().zip(&lights) {
            for (i, s) in s.iter_mut().enumerate() {
                let c = |p: &Corner| [p[0][i], p[1][i], p[2][i]];
                let (r0, r1, r2) = (c(&p[0]), c(&p[1]), c(&p[2]));
                *s = if TEST {
                    sorted_sign_nb(r0, r1, r2, odd[i], l)
                } else {
                    sorted_sign_off_corners(r0, r1, r2, odd[i], l)
                };
            }
        }
        // SAFETY: `b` is a whole block of `sorted`, which the sink holds
        // (the caller's).
        unsafe { sink.block(b, &s) };
    }
    let at = sorted.len() - tris.remainder().len();
    for (i, (t, &odd)) in tris.remainder().iter().zip(odds.remainder()).enumerate() {
        let s = lights.map(|l| sorted_sign_nb(xyz(t[0]), xyz(t[1]), xyz(t[2]), odd, l));
        sink.one(at + i, s);
    }
}

/// Whether the AVX-512 kernel's gathers beat the copies without gathers on
/// this CPU ([`measure_gathers`], once per process). Only asked where the
/// CPU has AVX-512 (`evaluate_simd::gather_caps`).
#[cfg(target_arch = "x86_64")]
pub(crate) fn gathers_pay() -> bool {
    static PAY: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *PAY.get_or_init(measure_gathers)
}

/// Times the caps of one light over a table of 16,384 points (256 KiB)
/// and 4,096 triangles of pseudo-random corners
/// ([`gather_probe_table`]), through the AVX-512 kernel and through the
/// copy [`IndexedCaps::signs_many`] takes, five times each, alternated, on
/// the calling thread; true when the gathers' fastest run is at least 10%
/// shorter. Once per process, and only for a table of at least
/// [`GATHER_MIN_TRIANGLES`]. Why measure, not ask the
/// vendor: the gathers were much faster on a Sapphire Rapids Xeon and
/// slower on a Zen 4 EPYC, and so the rule was Intel's; on an Intel Xeon
/// at 2.8 GHz with AVX-512 (fifty-first round) they took the dragon's caps
/// 4.78–4.91 ms against 1.32–1.47 without (`cargo run --release --example
/// stage_probe -- evaluate target/dragon/dragon.glb`). Either kernel gives
/// the same bits.
#[cfg(target_arch = "x86_64")]
fn measure_gathers() -> bool {
    use std::time::{Duration, Instant};
    if !crate::evaluate_simd::have_avx512() {
        return false;
    }
    let Some(table) = gather_probe_table() else {
        return false;
    };
    let light = GATHER_PROBE_LIGHT;
    let mut out = vec![0i8; table.len()];
    let (mut gathers, mut rows) = (Duration::MAX, Duration::MAX);
    for _ in 0..5 {
        let t = Instant::now();
        // SAFETY: the CPU has AVX-512F (checked above); `new` stored every
        // corner as a row of its 16,384 points, far below
        // MAX_GATHER_POINTS.
        unsafe { signs_avx512::<false>(&table.points, &table.sorted, &table.odd, light, &mut out) };
        gathers = gathers.min(t.elapsed());
        let t = Instant::now();
        table.signs_many(
            &table.sorted,
            &table.odd,
            [light],
            false,
            &mut Bytes([&mut out]),
        );
        rows = rows.min(t.elapsed());
    }
    gathers * 10 < rows * 9
}

/// The table [`measure_gathers`] times: 16,384 points, strictly
/// increasing in the lexicographic order (x is the index), and 4,096
/// triangles of corners from a xorshift generator. None only if `new`
/// declined it (a test checks it does not).
#[cfg(any(target_arch = "x86_64", test))]
fn gather_probe_table() -> Option<IndexedCaps> {
    const POINTS: u32 = 1 << 14;
    const TRIANGLES: usize = 1 << 12;
    let positions: Vec<[f32; 3]> = (0..POINTS)
        .map(|i| [i as f32, (i % 97) as f32 * 0.25, (i % 89) as f32 * -0.5])
        .collect();
    let mut state = 0x9e37_79b9_u32;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        state % POINTS
    };
    let caps: Vec<[u32; 3]> = (0..TRIANGLES).map(|_| [next(), next(), next()]).collect();
    IndexedCaps::new(&positions, &caps)
}

/// The light of [`measure_gathers`]: a point off every corner of its table.
#[cfg(any(target_arch = "x86_64", test))]
const GATHER_PROBE_LIGHT: Light = [3.0e4 + 0.5, -2.5, 4.0, 1.0];

/// Fewest triangles for which the caps ask whether the gathers pay
/// ([`measure_gathers`], 0.41–0.43 ms here, once per process); smaller tables
/// take the copies without gathers (unless a benchmark's setting says
/// otherwise), the faster on two of the three CPUs measured, and on the
/// third (2.8–3.6 against 1.8 ns per side record for the gathers, sixth
/// round) slower by at most about 0.2 ms per light at this size.
const GATHER_MIN_TRIANGLES: usize = 1 << 16;

/// Most points whose float offsets (`3 · id + 2`) fit the AVX-512 gathers'
/// signed 32-bit indices.
const MAX_GATHER_POINTS: usize = (i32::MAX as usize - 2) / 3;

/// Triangles per AVX-512 block: one 512-bit vector of f32 lanes.
#[cfg(target_arch = "x86_64")]
const WIDE: usize = 16;

/// [`signs_impl`] in blocks of [`WIDE`] triangles with AVX-512: the corner
/// ids de-interleaved with two-source permutes; each corner's `x, y` pairs
/// fetched with two 64-bit gathers (8 lanes each) and split with two
/// permutes, its `z` with one 32-bit gather (32 loads per corner instead of
/// the 48 of three 32-bit gathers; the AVX2 version needs 24 row loads and
/// 21 shuffles per 8 triangles, and the shuffles, which have one port,
/// were its bottleneck); then the same per-lane `sorted_sign_nb` as every
/// other version, which LLVM vectorises 16 wide, or with `TEST` false
/// `sorted_sign_off_corners` (the caller knows the light is on no corner).
/// Gathers and permutes move bits and compute nothing, so the lanes hold
/// exactly the floats of the other versions. The tail goes through
/// [`signs_impl`].
///
/// # Safety
/// The CPU must have AVX-512F, every corner in `sorted` must name a row of
/// `points` ([`row`]), and the table must have at most
/// [`MAX_GATHER_POINTS`] rows.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2")]
unsafe fn signs_avx512<const TEST: bool>(
    points: &[f32],
    sorted: &[[u32; 3]],
    odd: &[bool],
    l: Light,
    out: &mut [i8],
) {
    use std::arch::x86_64::*;
    let vector = |f: &dyn Fn(u32) -> u32| -> __m512i {
        let idx: [u32; WIDE] = std::array::from_fn(|i| f(i as u32));
        // SAFETY: 16 u32 are 64 bytes.
        unsafe { _mm512_loadu_si512(idx.as_ptr().cast()) }
    };
    let corners = crate::evaluate_simd::TriangleCorners16::new();
    // x (even floats) and y (odd floats) of 2 × 8 gathered pairs.
    let (even, odd_f) = (vector(&|i| 2 * i), vector(&|i| 2 * i + 1));
    let base = points.as_ptr();
    let mut blocks = out.chunks_exact_mut(WIDE);
    let mut tris = sorted.chunks_exact(WIDE);
    let mut odds = odd.chunks_exact(WIDE);
    for ((o, t), odd) in (&mut blocks).zip(&mut tris).zip(&mut odds) {
        let ids = t.as_ptr().cast::<u32>();
        // SAFETY: a block is 16 triangles of 3 ids: 48 u32.
        let v = unsafe { [0, 16, 32].map(|at| _mm512_loadu_si512(ids.add(at).cast())) };
        let mut p = [[[0f32; WIDE]; 3]; 3];
        for (c, p) in p.iter_mut().enumerate() {
            // The corners as stored, their rows' float offsets (see `row`).
            let off = corners.corner(&v, c);
            // SAFETY: each offset is 3·id for a row id (caller), so
            // 3·id + 0..=2 index the table's floats and fit an i32
            // (caller); the 64-bit gathers read floats 3·id and 3·id + 1.
            unsafe {
                let lo = _mm512_i32gather_pd::<4>(_mm512_castsi512_si256(off), base.cast());
                let hi = _mm512_i32gather_pd::<4>(_mm512_extracti64x4_epi64::<1>(off), base.cast());
                let (lo, hi) = (_mm512_castpd_ps(lo), _mm512_castpd_ps(hi));
                _mm512_storeu_ps(p[0].as_mut_ptr(), _mm512_permutex2var_ps(lo, even, hi));
                _mm512_storeu_ps(p[1].as_mut_ptr(), _mm512_permutex2var_ps(lo, odd_f, hi));
                let z = _mm512_add_epi32(off, _mm512_set1_epi32(2));
                _mm512_storeu_ps(p[2].as_mut_ptr(), _mm512_i32gather_ps::<4>(z, base));
            }
        }
        let mut s = [0i32; WIDE];
        for (i, s) in s.iter_mut().enumerate() {
            let c = |p: &[[f32; WIDE]; 3]| [p[0][i], p[1][i], p[2][i]];
            let (r0, r1, r2) = (c(&p[0]), c(&p[1]), c(&p[2]));
            *s = if TEST {
                sorted_sign_nb(r0, r1, r2, odd[i], l)
            } else {
                sorted_sign_off_corners(r0, r1, r2, odd[i], l)
            };
        }
        for (o, s) in o.iter_mut().zip(s) {
            *o = s as i8;
        }
    }
    let n = blocks.into_remainder().len();
    let at = out.len() - n;
    // SAFETY: the caller's.
    unsafe { signs_impl::<true, true>(points, &sorted[at..], &odd[at..], l, &mut out[at..]) };
}

#[cfg(test)]
mod tests {
    //! Against the record kernel, bit for bit, on tables and triangles
    //! chosen to hit every tie of the lexicographic order (shared x or y,
    //! repeated corners), every orientation of the stored corners, lights on
    //! corners and directional lights; and the tables the equivalence does
    //! not hold for must be declined.
    use super::*;
    use crate::multiplicity::{PERMS, test_bits};

    /// The table the gathers are timed on is one `new` accepts (declined,
    /// the measurement would always answer no), its light is on none of
    /// its corners (the kernels timed skip that test), and every kernel
    /// gives it the same signs, most of them nonzero. Caught: the probe's
    /// points not strictly increasing (x as the index modulo 1,000); its
    /// light on a corner (point 1's position).
    #[test]
    fn the_gather_probe_table_is_accepted_and_every_kernel_agrees() {
        let table = gather_probe_table().expect("`new` accepts the probe's table");
        assert_eq!(table.len(), 1 << 12);
        assert!(!table.light_on_a_corner(GATHER_PROBE_LIGHT));
        let signs = |on_corner: bool| {
            let mut out = vec![0i8; table.len()];
            table.signs_many(
                &table.sorted,
                &table.odd,
                [GATHER_PROBE_LIGHT],
                on_corner,
                &mut Bytes([&mut out]),
            );
            out
        };
        let off = signs(false);
        assert!(off == signs(true));
        assert!(off.iter().filter(|&&s| s != 0).count() > table.len() / 2);
        #[cfg(target_arch = "x86_64")]
        if crate::evaluate_simd::have_avx512() {
            let mut gathered = vec![0i8; table.len()];
            // SAFETY: AVX-512F checked; `new` built the table's rows.
            unsafe {
                signs_avx512::<false>(
                    &table.points,
                    &table.sorted,
                    &table.odd,
                    GATHER_PROBE_LIGHT,
                    &mut gathered,
                )
            };
            assert!(off == gathered);
        }
    }

    /// A sorted, deduplicated table with many equal x and y coordinates.
    fn table(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut next = test_bits(seed);
        let mut coord = move || {
            const LATTICE: [f32; 7] = [-1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 1e-7];
            let r = next();
            if r.is_multiple_of(3) {
                (r >> 8) as f32 / (1u64 << 56) as f32 * 4.0 - 2.0
            } else {
                LATTICE[(r >> 8) as usize % LATTICE.len()]
            }
        };
        let mut p: Vec<[f32; 3]> = (0..n).map(|_| [coord(), coord(), coord()]).collect();
        p.sort_by(|a, b| a.partial_cmp(b).unwrap());
        p.dedup();
        p
    }

    /// Record-kernel signs of `caps` over `positions`, the oracle.
    fn by_records(positions: &[[f32; 3]], caps: &[[u32; 3]], l: Light) -> Vec<i8> {
        let data: Vec<f32> = caps
            .iter()
            .flat_map(|c| {
                c.iter()
                    .flat_map(|&i| positions[i as usize].into_iter().chain([1.0]))
            })
            .collect();
        let mut out = vec![0i8; caps.len()];
        crate::evaluate_simd::cap_signs(&data, l, &mut out);
        out
    }

    /// Every compiled version of the kernel this machine can run: each
    /// copy of the block loop in each form that applies to `l`, the
    /// dispatch, and the AVX-512 gathers' kernel.
    fn versions(ix: &IndexedCaps, l: Light) -> Vec<(String, Vec<i8>)> {
        let mut v = Vec::new();
        let mut o = vec![0i8; ix.len()];
        let on_corner = ix.light_on_a_corner(l);
        for kernel in Kernel::available() {
            for form in [Form::Tested, Form::OffCorners, Form::OffCornersPoint] {
                // The forms without the test only where no corner is the
                // light; the point form only for point lights.
                if form != Form::Tested && on_corner || form == Form::OffCornersPoint && l[3] != 1.0
                {
                    continue;
                }
                let out = &mut Bytes([&mut o[..]]);
                // SAFETY: `available` lists the copies this CPU runs; ids
                // come from `new`; `out` holds every triangle; the light
                // is a point light for the point form (checked above).
                unsafe { run(kernel, form, &ix.points, &ix.sorted, &ix.odd, [l], out) };
                v.push((format!("{kernel:?}, {form:?}"), o.clone()));
            }
        }
        ix.cap_signs(l, &mut o);
        v.push(("dispatch".to_string(), o.clone()));
        // The dispatch with the gathers' kernel chosen either way (the
        // setting is the process's; other tests running meanwhile only
        // get slower or faster).
        for (name, gathers) in [("dispatch, gathers", true), ("dispatch, no gathers", false)] {
            crate::evaluate_simd::prefer_gather_caps(Some(gathers));
            ix.cap_signs(l, &mut o);
            crate::evaluate_simd::prefer_gather_caps(None);
            v.push((name.to_string(), o.clone()));
        }
        #[cfg(target_arch = "x86_64")]
        if crate::evaluate_simd::have_avx512() {
            // SAFETY: only when the CPU has AVX-512F; ids come from `new`.
            unsafe { signs_avx512::<true>(&ix.points, &ix.sorted, &ix.odd, l, &mut o) };
            v.push(("avx512".to_string(), o.clone()));
            if !on_corner {
                // SAFETY: as above.
                unsafe { signs_avx512::<false>(&ix.points, &ix.sorted, &ix.odd, l, &mut o) };
                v.push(("avx512 without the corner test".to_string(), o));
            }
        }
        v
    }

    #[test]
    fn equals_record_kernel_bit_for_bit() {
        for seed in 1..=6u64 {
            let p = table(300, seed);
            let n = p.len() as u64;
            let mut next = test_bits(seed * 7919);
            // Random triangles in every stored order, a few with repeated
            // corners (degenerate: ties inside one triangle).
            let mut caps = Vec::new();
            for t in 0..2000 {
                let mut c = [0u32; 3].map(|_| (next() % n) as u32);
                if t % 50 == 0 {
                    c[2] = c[0];
                }
                let perm = PERMS[t % 6];
                caps.push([c[perm[0]], c[perm[1]], c[perm[2]]]);
            }
            let ix = IndexedCaps::new(&p, &caps).expect("a strictly increasing table");
            let corner = p[(next() % n) as usize];
            let lights = [
                [0.3, -2.0, 1.7, 1.0],
                [1.0, 0.5, -0.25, 0.0],
                [0.0, 0.0, 1.0, 0.0],
                [corner[0], corner[1], corner[2], 1.0],
                [0.5, 0.5, 0.5, 1.0],
            ];
            for l in lights {
                let want = by_records(&p, &caps, l);
                assert!(want.iter().any(|&s| s != 0));
                for (name, got) in versions(&ix, l) {
                    let bad = got.iter().zip(&want).position(|(g, w)| g != w);
                    assert_eq!(
                        bad, None,
                        "{name}, seed {seed}, light {l:?}: first wrong triangle"
                    );
                }
            }
        }
    }

    /// Groups of lights against one light at a time, bit for bit: every
    /// count from one to nine (whole groups, and the groups of one to three
    /// left over), over three chunks of triangles, with a light on a corner
    /// in the middle of the second group (only its group needs the test)
    /// and directional lights, on one thread and two.
    #[test]
    fn groups_of_lights_equal_one_light_at_a_time() {
        let p = table(400, 21);
        let n = p.len() as u64;
        let mut next = test_bits(77);
        let caps: Vec<[u32; 3]> = (0..2 * CHUNK + 1003)
            .map(|t| {
                let c = [0u32; 3].map(|_| (next() % n) as u32);
                let perm = PERMS[t % 6];
                [c[perm[0]], c[perm[1]], c[perm[2]]]
            })
            .collect();
        let ix = IndexedCaps::new(&p, &caps).unwrap();
        let corner = p[caps[5][1] as usize];
        let lights: [Light; 9] = [
            [0.3, -2.0, 1.7, 1.0],
            [1.0, 0.5, -0.25, 0.0],
            [0.5, 0.5, 0.5, 1.0],
            [-1.5, 0.25, 2.0, 1.0],
            [0.0, 0.0, 1.0, 0.0],
            [corner[0], corner[1], corner[2], 1.0],
            [2.0, 1.0, -1.0, 1.0],
            [0.1, 0.2, 0.3, 0.0],
            [-0.75, -1.0, 0.5, 1.0],
        ];
        assert!(ix.light_on_a_corner(lights[5]) && !ix.light_on_a_corner(lights[4]));
        let want: Vec<Vec<i8>> = lights
            .iter()
            .map(|&l| {
                let mut o = vec![0i8; ix.len()];
                ix.cap_signs(l, &mut o);
                o
            })
            .collect();
        // The light on the corner gives zeros that the others do not.
        assert!(
            want[5]
                .iter()
                .zip(&want[4])
                .any(|(&c, &o)| c == 0 && o != 0)
        );
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            for count in 1..=lights.len() {
                let mut got = vec![vec![i8::MIN; ix.len()]; count];
                let mut out: Vec<&mut [i8]> = got.iter_mut().map(|o| &mut o[..]).collect();
                pool.install(|| ix.cap_signs_many(&lights[..count], &mut out));
                for (i, (got, want)) in got.iter().zip(&want).enumerate() {
                    let bad = got.iter().zip(want).position(|(g, w)| g != w);
                    assert_eq!(bad, None, "{count} lights, light {i}: first wrong triangle");
                }
            }
        }
    }

    #[test]
    fn finds_exactly_the_lights_on_a_corner() {
        let p = table(400, 11);
        // Triangles over the even-numbered points only: odd ones are in
        // the table but no corner.
        let even: Vec<u32> = (0..p.len() as u32).step_by(2).collect();
        let caps: Vec<[u32; 3]> = even.windows(3).map(|w| [w[2], w[0], w[1]]).collect();
        let ix = IndexedCaps::new(&p, &caps).unwrap();
        let used: std::collections::HashSet<u32> = caps.iter().flatten().copied().collect();
        let mut zeros = 0;
        for (i, q) in p.iter().enumerate() {
            let want = used.contains(&(i as u32));
            assert_eq!(
                ix.light_on_a_corner([q[0], q[1], q[2], 1.0]),
                want,
                "point {i}"
            );
            // `==` equates −0.0 and +0.0, so the search must too.
            let neg = q.map(|v| if v == 0.0 { -v } else { v });
            zeros += (neg.map(f32::to_bits) != q.map(f32::to_bits)) as u32;
            assert_eq!(ix.light_on_a_corner([neg[0], neg[1], neg[2], 1.0]), want);
            // A directional light is never on a corner.
            assert!(!ix.light_on_a_corner([q[0], q[1], q[2], 0.0]));
            // Between two table points.
            let off = [q[0], q[1], f32::from_bits(q[2].to_bits() + 1)];
            if !p.contains(&off) {
                assert!(!ix.light_on_a_corner([off[0], off[1], off[2], 1.0]));
            }
        }
        assert!(zeros > 10, "the table must have zero coordinates");
        // A corner light through the whole kernel: every version agrees
        // with the records, whichever zero the light carries.
        let q = p[used
            .iter()
            .copied()
            .find(|&i| p[i as usize].contains(&0.0))
            .unwrap() as usize];
        let neg = q.map(|v| if v == 0.0 { -v } else { v });
        for l in [[q[0], q[1], q[2], 1.0], [neg[0], neg[1], neg[2], 1.0]] {
            let want = by_records(&p, &caps, l);
            assert!(want.contains(&0));
            for (name, got) in versions(&ix, l) {
                assert_eq!(got, want, "{name}, light {l:?}");
            }
        }
    }

    #[test]
    fn declines_tables_that_are_not_strictly_increasing() {
        let caps = [[0, 1, 2]];
        let ok = [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]];
        assert!(IndexedCaps::new(&ok, &caps).is_some());
        // ±0.0: distinct bits, equal positions.
        let zeros = [[0.0, -0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        assert!(IndexedCaps::new(&zeros, &caps).is_none());
        let nan = [[0.0, 0.0, 0.0], [f32::NAN, 0.0, 1.0], [1.0, 0.0, 0.0]];
        assert!(IndexedCaps::new(&nan, &caps).is_none());
        let unsorted = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [2.0, 0.0, 0.0]];
        assert!(IndexedCaps::new(&unsorted, &caps).is_none());
        assert!(IndexedCaps::new(&ok, &[[0, 1, 3]]).is_none());
    }
}
