//! Topology: every undirected edge with the opposite vertex of every triangle
//! on it. Works on any soup: open, non-manifold, inconsistently wound,
//! duplicated triangles.
//!
//! Vertices come from [`crate::weld`] numbered in lexicographic position order,
//! so the edge orientation A < B of the contract is simply `a < b` on indices.
//! Edges are produced sorted by (a, b); each edge's opposite vertices are in
//! triangle order. Both orders are fully determined by the input.
//!
//! Method: every triangle is listed (by its other two corners, 8 bytes)
//! under the two corners that are the smaller endpoint of one of its edges,
//! appended to the range of 2,048 vertices the corner falls in; then, range
//! by range, the listings are put by vertex in a buffer that stays in the
//! cache, and vertex by vertex that vertex's edges sorted by larger
//! endpoint, a handful of records on real meshes (the vertex valence). See
//! [`build_edges`].

use std::mem::MaybeUninit;

#[cfg(target_arch = "x86_64")]
mod count_avx2;
#[cfg(target_arch = "x86_64")]
mod emit_avx2;

/// Edges in compressed-row form.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Edges {
    /// Smaller endpoint of each edge (lexicographically smaller position).
    pub a: Vec<u32>,
    /// Larger endpoint of each edge.
    pub b: Vec<u32>,
    /// `opp_start[e]..opp_start[e + 1]` is edge `e`'s range in `opp`/`opp_tri`.
    pub opp_start: Vec<u32>,
    /// Opposite vertex of each (edge, triangle) pair.
    pub opp: Vec<u32>,
    /// Triangle (index into the welded triangle list) of each (edge,
    /// triangle) pair; empty when built by [`build_edges_opposites_only`].
    pub opp_tri: Vec<u32>,
}

impl Edges {
    /// Number of edges.
    pub fn len(&self) -> usize {
        self.a.len()
    }

    /// True when there are no edges.
    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }

    /// Opposite-vertex count of edge `e`.
    #[inline]
    pub fn fan(&self, e: usize) -> usize {
        (self.opp_start[e + 1] - self.opp_start[e]) as usize
    }

    /// Opposite vertices of edge `e`.
    pub fn opposites(&self, e: usize) -> &[u32] {
        self.slices().opposites(e)
    }
}

/// Builds the edge structure of `triangles` (3 vertex ids each, no repeated
/// id within a triangle) over `vertex_count` vertices.
///
/// Method: each triangle `lo < mid < hi` (its corners by id) is listed
/// under the two corners that are the smaller endpoint of one of its edges:
/// `lo` (edges lo–mid and lo–hi) and `mid` (edge mid–hi); `hi` is the
/// smaller endpoint of none. Then, vertex by vertex in id order, the
/// listings are read back and their edges at that vertex sorted by larger
/// endpoint: edges come out sorted by (a, b), each with its opposite
/// vertices in triangle order.
///
/// 1. **Count** the listings and records per range of `RANGE` vertices
///    (triangles cut into one chunk per thread and each chunk into two
///    parts, `CHUNK_PARTS`, each part with its own counts, in planes of
///    counters: see the pass; 16 triangles at a time in AVX-512 registers
///    where pass 3's kernel runs, `count_avx512`).
/// 2. **List** every triangle under its `lo` and `mid` by the pair of its
///    other two corners: `[mid, hi]` under `lo`, `[hi, lo]` under `mid`
///    (2 listings per triangle; the pair's order tells the two kinds
///    apart), and with `opp_tri` also its id in a second list. A listing
///    is appended to its vertex's range, packed with the vertex's place in
///    the range into 8 bytes (`Entry`; 12 bytes over 2^25 vertices), so
///    the pass writes one stream per range. Part `l` writes after parts
///    `0..l` in every range, so each vertex's listings are in triangle
///    order whatever the number of chunks; a chunk's parts are listed a
///    triangle of each in turn, two chains of updates to the ranges'
///    heads (`CHUNK_PARTS`).
///
///    Why ranges and not each vertex's own list (the method until the
///    twenty-first round, with the counts per vertex): the lists are 16
///    bytes per triangle, 80 MB on a 5M-triangle scene, and filling them
///    vertex by vertex is two scattered writes per triangle (and two
///    scattered counter updates in each of passes 1 and 2), which stay in
///    the caches on the dragon but not on larger meshes: 5M scene, one
///    thread, passes 1–3 146–165 → 108–116 ms, two threads 81–83 → 70–73
///    ms; the dragon 17.6–18.7 → 17.4–19.2 ms, where the counting and
///    listing gain what the range sort costs (`RECYCLE=1 cargo run
///    --release --example stage_probe -- passes`, benches/ROUNDS.md
///    "Twenty-first round").
/// 3. **Emit**, one group of consecutive vertices per thread (groups cut at
///    multiples of `RANGE` vertices so they hold about equal numbers of
///    records, counted per range in pass 1), range by range: the range's
///    listings put by vertex, each to its vertex's next slot of 8
///    (`sort_range`, in a buffer of the job's that stays in L2; the few
///    past 8 aside), then a vertex's listings are read in
///    order, each giving its edge records at that vertex (the listing, and
///    under `lo` also the swapped pair) without reading the triangle, its
///    few edge records sorted by larger endpoint, stably (`sort_small`, a
///    sorting network), its opposite vertices written over the group's own
///    listings, already read (8 or 12 bytes a listing, at most two records
///    of 4),
///    its triangles straight to their final place, and its edges one after
///    the other into its own slots of the edge arrays (half its records and
///    a sixteenth more; all that is left for the last group) and, when these
///    run out, into arrays of its own. Where the CPU has AVX-512 and BMI2
///    (and the mesh fewer than 2^28 vertices), each listing is unpacked by
///    one `pdep` (`sort_range_bmi2`) and a vertex with at most 8 listings
///    (so at most 16 records) is done in registers (`emit_range_avx512`,
///    two vertices at a time where both have at most 4 listings): 14.5–15.0 →
///    7.1–7.6 ms on the dragon, one thread, on the earlier Intel host
///    (`cargo run --release --example stage_probe -- passes`, the two
///    versions alternated; 9.1–9.3 ms with the kernel for up to 8 records
///    only).
/// 4. **Compact**: each group's opposite vertices are moved down after the
///    previous groups' (one move per group), each further group's edges
///    are moved from its slots to follow the previous groups' (one move
///    per group and array, within memory pass 3 wrote), with the edges it
///    had no slots for after them, and the listings' memory becomes `opp`.
///
/// Why not sort the 3·T half-edges themselves (the previous method, a
/// two-level counting sort of 16-byte records, kept as a bench baseline):
/// that writes and reads back 16 bytes per half-edge, 42 MB of fresh memory
/// on the 871k-triangle dragon; the listing is 16 bytes per triangle
/// (14 MB). On the dragon the CLI's topology stage went from 86.9 to 61.6 ms
/// on one thread (benches/ROUNDS.md, "Fourth round").
///
/// Why pairs and not triangle ids (4 bytes per listing, the fourth round's
/// method): with ids, pass 3 gathered every listed triangle from the
/// triangle table, one scattered read per listing (1.7M on the dragon,
/// prefetched). The pairs cost 7 MB more writes in pass 2 and turn pass 3
/// into a sequential read: 46.5–47.6 → 42.1–42.5 ms on one thread, 26.3–28.5
/// → 24.2–25.4 ms on two (benches/ROUNDS.md, "Eighth round").
///
/// The result does not depend on the number of threads.
pub fn build_edges(triangles: &[u32], vertex_count: usize) -> Edges {
    crate::pool::one_job(|| {
        build_edges_in::<true>(
            triangles.into(),
            vertex_count,
            chunks_for(triangles),
            Simd::Plain,
            false,
            None,
            None,
        )
        .0
    })
}

/// [`build_edges`] without `opp_tri` (left empty): what a build needs, since
/// the layout reads only the opposite vertices (`lint` needs the triangles).
/// Why: it is a quarter of the memory the edges take, 4 bytes per (edge,
/// triangle) pair (60 MB on a 5M-triangle scene), all of it fresh pages,
/// and one write per record less.
pub fn build_edges_opposites_only(triangles: &[u32], vertex_count: usize) -> Edges {
    opposites_only(triangles.into(), vertex_count, None, None).0
}

/// [`build_edges_opposites_only`] on triangles it takes, and frees once
/// they are listed (pass 2), before the arrays of the edges are allocated:
/// those then reuse the triangles' pages instead of fresh ones.
///
/// Why: a build's one-thread path writes the caps before the edges are
/// made, so nothing reads the welded triangles afterwards. On the
/// 5M-triangle scene (60 MB of triangles) the topology stage faulted in 66
/// MiB of fresh huge pages before, 40 after (`benches/fresh_pages.py
/// --by-stage`, one thread); on this project's virtual machine a fresh huge
/// page costs about 0.25 ms while the host still backs the memory and
/// about 4.3 ms once it has taken it back (`alloc::cold_memory_seen`): the
/// 5M scene's edges took 62.6–66.9 or 149.6–206.8 ms in eight one-thread
/// builds (local timers), with the same page faults.
pub fn build_edges_opposites_only_owned(triangles: Vec<u32>, vertex_count: usize) -> Edges {
    opposites_only(triangles.into(), vertex_count, None, None).0
}

/// [`build_edges_opposites_only`], with `consumer` reading the edges while
/// they are made: it runs beside the emit pass (on another thread when one
/// is free, else after it), and [`EmitFeed`] hands it each prefix of the
/// edges as soon as it is final. The emit pass then runs as one job, in
/// vertex order, so that each edge is written once, in its final place.
/// The edges returned are the same as without a consumer. Why: a build
/// copies each finished block of side records into the file while the
/// rest of the edges are made (benches/ROUNDS.md, "Nineteenth round").
pub fn build_edges_opposites_only_fed(
    triangles: &[u32],
    vertex_count: usize,
    consumer: &mut (dyn FnMut(&EmitFeed) + Send),
) -> Edges {
    opposites_only(triangles.into(), vertex_count, Some(consumer), None).0
}

/// [`build_edges_opposites_only_fed`] on triangles it shares with the
/// caller, and drops once they are listed (pass 2), like
/// [`build_edges_opposites_only_owned`] (they are freed once the caller
/// has dropped its share too); after pass 1 it calls `counted` with
/// whether the emit is fed (whether `consumer` will be called: not when
/// some edge has an odd number of opposite vertices, see the passes).
///
/// Why: a two-thread build writes the caps from the welded triangles on
/// the other thread, beside the topology (`build::build_file`). When the
/// emit is fed, the side blocks follow them there; when it is not, the
/// emit runs on both threads, and `counted` has this thread help with the
/// caps first, so that both threads are free for the emit. Shared, the
/// triangles are freed once both the topology and the caps are done with
/// them, before the emit's arrays are allocated if the caps are written
/// by then.
pub fn build_edges_opposites_only_shared_fed(
    triangles: std::sync::Arc<Vec<u32>>,
    vertex_count: usize,
    consumer: &mut (dyn FnMut(&EmitFeed) + Send),
    counted: &mut (dyn FnMut(bool) + Send),
) -> Edges {
    opposites_only(
        triangles.into(),
        vertex_count,
        Some(consumer),
        Some(counted),
    )
    .0
}

/// [`build_edges_opposites_only`], with the wall time of each of its four
/// passes (for `examples/stage_probe.rs`, which profiles them).
pub fn build_edges_opposites_only_timed(
    triangles: &[u32],
    vertex_count: usize,
) -> (Edges, PassTimes) {
    opposites_only(triangles.into(), vertex_count, None, None)
}

/// The opposites-only edges with their passes' times, as one job on
/// rayon's pool (see `crate::pool`).
fn opposites_only(
    triangles: Input<'_>,
    vertex_count: usize,
    consumer: Option<&mut (dyn FnMut(&EmitFeed) + Send)>,
    counted: Option<&mut (dyn FnMut(bool) + Send)>,
) -> (Edges, PassTimes) {
    crate::pool::one_job(|| {
        let chunks = chunks_for(&triangles);
        build_edges_in::<false>(
            triangles,
            vertex_count,
            chunks,
            simd_level(),
            false,
            consumer,
            counted,
        )
    })
}

/// Wall time of each pass of [`build_edges`] (see there for the passes).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PassTimes {
    /// Pass 1, counting the listings (with the prefix sums after it).
    pub count: std::time::Duration,
    /// Pass 2, listing every triangle under two corners.
    pub list: std::time::Duration,
    /// Pass 3, the edges and opposite vertices, vertex by vertex.
    pub emit: std::time::Duration,
    /// Pass 4, moving the groups' output into place.
    pub compact: std::time::Duration,
}

/// The triangles the topology reads in passes 1 and 2 and drops after
/// them: borrowed, its own (freed then), or shared with the caller (freed
/// once the caller has dropped its share too).
enum Input<'a> {
    Borrowed(&'a [u32]),
    Owned(Vec<u32>),
    Shared(std::sync::Arc<Vec<u32>>),
}

impl std::ops::Deref for Input<'_> {
    type Target = [u32];
    fn deref(&self) -> &[u32] {
        match self {
            Input::Borrowed(t) => t,
            Input::Owned(t) => t,
            Input::Shared(t) => t,
        }
    }
}

impl<'a> From<&'a [u32]> for Input<'a> {
    fn from(t: &'a [u32]) -> Self {
        Input::Borrowed(t)
    }
}

impl From<Vec<u32>> for Input<'_> {
    fn from(t: Vec<u32>) -> Self {
        Input::Owned(t)
    }
}

impl From<std::sync::Arc<Vec<u32>>> for Input<'_> {
    fn from(t: std::sync::Arc<Vec<u32>>) -> Self {
        Input::Shared(t)
    }
}

/// Chunks of the count and list passes: one per thread for large inputs.
fn chunks_for(triangles: &[u32]) -> usize {
    if triangles.len() < 3 * PARALLEL_MIN {
        1
    } else {
        rayon::current_num_threads().clamp(1, MAX_CHUNKS)
    }
}

/// [`build_edges`] (with `opp_tri` when `TRI`) with the triangles cut into
/// `chunks` chunks for the count and list passes (tests use it to vary the
/// cut), the kernels `simd` names (the CPU must have them; tests run
/// each), and the passes' times. The public entry points run it as one
/// job on rayon's pool (see `crate::pool`).
fn build_edges_in<const TRI: bool>(
    input: Input<'_>,
    vertex_count: usize,
    chunks: usize,
    simd: Simd,
    wide: bool,
    consumer: Option<&mut (dyn FnMut(&EmitFeed) + Send)>,
    on_counted: Option<&mut (dyn FnMut(bool) + Send)>,
) -> (Edges, PassTimes) {
    use rayon::prelude::*;
    use std::time::Instant;
    let started = Instant::now();
    let triangles: &[u32] = &input;
    let tcount = triangles.len() / 3;
    // Record offsets (3 per triangle) are u32.
    assert!(
        3 * tcount <= u32::MAX as usize,
        "topology: {tcount} triangles, at most {} supported",
        u32::MAX / 3
    );
    let ranges = vertex_count.div_ceil(RANGE);
    // Each chunk is cut into `CHUNK_PARTS` parts of `per` triangles (the
    // last fewer), each with its own counts and range heads.
    let per = tcount.div_ceil(CHUNK_PARTS * chunks.max(1)).max(1);
    let parts: Vec<&[u32]> = triangles.chunks(3 * per).collect();

    // Pass 1: listings and records (half-edges) per (part, range).
    // Fed, pass 1 also XORs a key of every edge of every triangle: an
    // edge on an even number of triangles cancels out, so a nonzero result
    // means some edge has an odd opposite count, 1 (open) most often. The
    // consumer (`layout::write_sides_ahead`) guesses that no edge has one
    // opposite vertex, and a wrong guess costs a copy of the side records;
    // so such a mesh is not fed, and its emit runs on every thread. The
    // keys are multiplied by an odd constant (a bijection), so one odd
    // edge never cancels out; several could, only by chance, and then the
    // guess is checked where the file is finished.
    let parity = consumer.is_some();
    let odd_edges = std::sync::atomic::AtomicU64::new(0);
    let counts: Vec<Vec<u64>> = parts
        .par_iter()
        .map(|tris| {
            let _part = crate::trace::span("topology: count (part)");
            let (count, odd) = count_chunk(tris, ranges, simd, parity);
            odd_edges.fetch_xor(odd, std::sync::atomic::Ordering::Relaxed);
            count
        })
        .collect();
    let consumer = consumer.filter(|_| odd_edges.into_inner() == 0);
    if let Some(on_counted) = on_counted {
        on_counted(consumer.is_some());
    }
    // Where each range's listings and records start.
    let mut list_start = vec![0u32; ranges + 1];
    let mut rec_start = vec![0usize; ranges + 1];
    for r in 0..ranges {
        let both: u64 = counts.iter().map(|rr| rr[r]).sum();
        list_start[r + 1] = list_start[r] + (both >> 32) as u32;
        rec_start[r + 1] = rec_start[r] + (both & u64::from(u32::MAX)) as usize;
    }
    let at = list_start[ranges] as usize;

    let counted = Instant::now();
    crate::trace::between("topology: count", started, counted);
    // Pass 2: list each triangle under its lo and mid corners, appended to
    // the corner's range. The listings are allocated uninitialised: every
    // slot is written exactly once below (checked where pass 3 reads them,
    // in debug builds), and zeroing them first was a write of 14 MB on the
    // dragon (or a fault per page on fresh memory).
    let bits = packed_bits(vertex_count).filter(|_| !wide);
    let words = if bits.is_some() { 2 } else { 3 };
    let mut list: Vec<u32> = Vec::with_capacity(words * at);
    let mut list_t: Vec<u32> = Vec::with_capacity(if TRI { at } else { 0 });
    if cfg!(debug_assertions) {
        list.spare_capacity_mut().fill(MaybeUninit::new(UNWRITTEN));
        list_t
            .spare_capacity_mut()
            .fill(MaybeUninit::new(UNWRITTEN));
    }
    // Each part's next slot per range: the range's start, after the
    // earlier parts' listings in the range.
    let mut heads: Vec<Vec<u32>> = Vec::with_capacity(counts.len());
    let mut next = list_start[..ranges].to_vec();
    for rr in &counts {
        heads.push(next.clone());
        for (h, &x) in next.iter_mut().zip(rr) {
            *h += (x >> 32) as u32;
        }
    }
    drop(counts);
    // (Debug builds check below that each part's heads end where the next
    // part's start, and the last part's at the ranges' ends: that every
    // part listed exactly what pass 1 counted for it. No triangles, no
    // parts.)
    let ends: Vec<Vec<u32>> = if cfg!(debug_assertions) {
        let last = (!heads.is_empty()).then_some(next);
        heads.iter().skip(1).cloned().chain(last).collect()
    } else {
        Vec::new()
    };
    let (list_at, list_t_at) = (list.as_mut_ptr() as usize, list_t.as_mut_ptr() as usize);
    parts
        .par_chunks(CHUNK_PARTS)
        .zip(heads.par_chunks_mut(CHUNK_PARTS))
        .enumerate()
        .for_each(|(ci, (tris, heads))| {
            let _part = crate::trace::span("topology: list (part)");
            let first_id = (CHUNK_PARTS * ci * per) as u32;
            // SAFETY: part `l` of chunk `ci` owns, in each range r, the
            // slots from `heads[l][r]` on, as many as pass 1 counted for
            // it; these are disjoint across parts and ranges and lie
            // inside `list` (and `list_t` when TRI), sized for `at`
            // entries.
            unsafe {
                match bits {
                    Some(bits) => list_ranges::<u64, TRI>(
                        tris, heads, first_id, per, bits, list_at, list_t_at,
                    ),
                    None => list_ranges::<[u32; 3], TRI>(
                        tris, heads, first_id, per, 0, list_at, list_t_at,
                    ),
                }
            }
        });
    debug_assert!(
        heads == ends,
        "topology: a part listed more or less than it counted"
    );
    drop(heads);
    // Nothing reads the triangles after pass 2: owned ones are freed here,
    // before the edges' arrays are allocated
    // (`build_edges_opposites_only_owned`).
    drop(parts);
    drop(input);
    // SAFETY: pass 1 counted every slot pass 2 writes, so all are written.
    unsafe {
        list.set_len(words * at);
        list_t.set_len(if TRI { at } else { 0 });
    }
    let buckets = Buckets {
        start: &list_start,
        records: &rec_start,
        at: list_at,
        tri: list_t_at,
        bits,
        narrow: Buckets::narrow_for(vertex_count),
    };
    let listed = Instant::now();
    crate::trace::between("topology: list", counted, listed);
    // Pass 3: the edges with their opposite vertices and triangles, one
    // job per group of consecutive ranges, the groups holding about equal
    // numbers of records (one group per thread: within a group, edges are
    // written one after the other). A group's records go to their final
    // place in `opp_tri` and over its own listings (moved to their final
    // place in pass 4); its edges to its own slots in `a`, `b` and
    // `opp_start` (past its first entry), then, if they run out, to
    // arrays of its own (`Overflow`); pass 4 closes the gaps between the
    // groups' edges.
    let n = rec_start[ranges];
    // Fed (`consumer`): one group, emitted in order, so that every edge
    // and record is written straight to its final place and a finished
    // prefix can be read while the rest is made.
    let groups = if consumer.is_some() {
        1
    } else {
        rayon::current_num_threads().clamp(1, ranges.max(1))
    };
    let mut group_start = vec![0usize; groups + 1];
    for (g, gs) in group_start.iter_mut().enumerate().skip(1) {
        // The first range boundary at or past g/groups of the records.
        let target = n / groups * g;
        *gs = rec_start.partition_point(|&x| x < target).min(ranges);
    }
    group_start[groups] = ranges;
    // Uninitialised, like the lists: the records fill `opp_tri` exactly
    // (checked per group below), and each group's edges the front of its
    // slots in `a`, `b` and `opp_start`, which pass 4 joins up; only what
    // is written is kept.
    //
    // `opp` has no memory of its own: each group writes its records over
    // its own listings, from their start, and pass 4 moves them down to
    // their final place. Why: it saves a buffer of 4 bytes per record
    // (10.5 MB of fresh memory on the dragon, a sixth of the build's peak).
    // Why it is safe: a listing is 8 or 12 bytes and gives at most 2
    // records of 4, and a range's listings are all read (into the job's
    // scratch) before its records are written, so a group's writes never
    // reach a listing it has not read, nor another group's listings.
    //
    // Each group but the last has `slots(m)` slots for its `m` records:
    // room for half of them (every edge of a closed mesh is on two
    // triangles) and for open edges up to a sixteenth more. The last
    // group has the rest of the arrays, sized for all the records, so it
    // never runs out (nor does a lone group). The slots follow each
    // other, so the written edges are the whole arrays but for a gap of
    // about a sixteenth of a group's records after each group, and kept
    // memory goes to that front (`alloc::vec_touching`). Pass 4 moves
    // each further group's edges across the gaps before it, within
    // memory already written.
    //
    // Why not, as until the sixty-fifth round, the edges of each further
    // group at their records' offsets (the written parts spread over the
    // arrays, so kept memory had to cover them all or leave fronts fresh),
    // or, in the sixty-fifth round, in arrays of its own appended in pass
    // 4 (the appended edges went to fresh memory: pass 4 took 20.4–44.8 ms
    // on the 5M scene with two threads, and the second group's emit, into
    // its fresh arrays, 34.2–67.7 ms against the first's 24.3–25.9, in
    // three traces; benches/ROUNDS.md, Sixty-sixth round).
    let slots = |m: usize| m / 2 + m / 32 + 1;
    let group_records = |g: usize| rec_start[group_start[g + 1]] - rec_start[group_start[g]];
    // Where each group's slots start, and the arrays' length.
    let mut slot_start = vec![0usize; groups + 1];
    for g in 0..groups - 1 {
        slot_start[g + 1] = slot_start[g] + slots(group_records(g));
    }
    let len = n.max(slot_start[groups - 1] + group_records(groups - 1));
    slot_start[groups] = len;
    let touched = slot_start[groups - 1] + slots(group_records(groups - 1));
    let mut e = Edges {
        a: crate::alloc::vec_touching(len, touched),
        b: crate::alloc::vec_touching(len, touched),
        opp_start: crate::alloc::vec_touching(len + 1, touched + 1),
        opp: Vec::new(),
        opp_tri: Vec::with_capacity(if TRI { n } else { 0 }),
    };
    // Where each group's records are written: the start of its listings,
    // in u32 (`words` per listing).
    let records_at = |g: usize| words * list_start[group_start[g]] as usize;
    // Per group, the edges written in its slots and the ones past them.
    let group_edges: Vec<(usize, Overflow)> = if let Some(consumer) = consumer {
        debug_assert!(!TRI, "fed emits are opposites-only");
        let edges = emit_fed(&mut e, n, &buckets, vertex_count, simd, consumer);
        vec![(edges, Overflow::default())]
    } else {
        let mut rt = &mut e.opp_tri.spare_capacity_mut()[..if TRI { n } else { 0 }];
        // `opp_start[0]` goes to the first group: written here, its first
        // touch of a fresh huge page was 0.26 ms before any group started, with
        // two threads on the dragon (local timers).
        let (rs0, mut rs) = e.opp_start.spare_capacity_mut()[..len + 1].split_at_mut(1);
        let (mut ra, mut rb) = (
            &mut e.a.spare_capacity_mut()[..len],
            &mut e.b.spare_capacity_mut()[..len],
        );
        let mut jobs = Vec::with_capacity(groups);
        let mut zero = Some(rs0);
        for g in 0..groups {
            let k = slot_start[g + 1] - slot_start[g];
            let (t1, t2) = rt.split_at_mut(if TRI { group_records(g) } else { 0 });
            let (a1, a2) = ra.split_at_mut(k);
            let (b1, b2) = rb.split_at_mut(k);
            let (s1, s2) = rs.split_at_mut(k);
            (rt, ra, rb, rs) = (t2, a2, b2, s2);
            jobs.push((zero.take().unwrap_or_default(), [t1, a1, b1, s1]));
        }
        jobs.into_par_iter()
            .enumerate()
            .map_init(
                // (A split's span lasts as long as its scratch.)
                || (Scratch::new(), crate::trace::span("topology: emit (part)")),
                |(scratch, _part): &mut (Scratch, crate::trace::Span),
                 (g, (zero, [ot, oa, ob, os]))| {
                    if let [z] = zero {
                        *z = MaybeUninit::new(0);
                    }
                    let first = group_start[g] * RANGE;
                    let last = (group_start[g + 1] * RANGE).min(vertex_count);
                    let out = GroupOut {
                        // SAFETY (of the writes through it): the group's
                        // records from here lie inside its listings (see
                        // where `e` is made), which only this job touches.
                        opp: (list_at as *mut u32).wrapping_add(records_at(g)),
                        tri: ot,
                        a: oa,
                        b: ob,
                        end: os,
                        base: rec_start[group_start[g]] as u32,
                        room: 0,
                        records: 0,
                        edges: 0,
                    };
                    let mut over = Overflow::default();
                    let (records, edges) = emit_ranges::<TRI>(
                        out,
                        &buckets,
                        first..last,
                        scratch,
                        simd,
                        Some(&mut over),
                    );
                    // The group's records filled their slots (and its
                    // range of `opp_tri`): pass 1 counted them.
                    assert_eq!(records, group_records(g), "topology: records miscounted");
                    (edges, over)
                },
            )
            .collect()
    };
    drop(list_t);

    let emitted = Instant::now();
    crate::trace::between("topology: emit", listed, emitted);
    // Pass 4: each group's records moved down from its listings to follow
    // the previous groups' (records never outnumber twice the listings
    // before them, so a move only overwrites listings already moved or
    // read), and each further group's edges moved across the gaps before
    // them (and a group's overflow after its own). The four arrays are
    // independent, so their moves run side by side: with one group per
    // thread there is one move per array and thread after the first (45
    // MB on a 5M-triangle scene with two threads).
    let move_records = || {
        for g in 0..groups {
            let (from, to) = (records_at(g), rec_start[group_start[g]]);
            let m = rec_start[group_start[g + 1]] - to;
            if from != to {
                // SAFETY: both ranges lie in `list`'s allocation (from + m
                // is at most `words` u32 per listing up to the group's end),
                // which nothing else touches now; `copy` allows the overlap.
                unsafe {
                    std::ptr::copy(
                        (list_at as *const u32).add(from),
                        (list_at as *mut u32).add(to),
                        m,
                    )
                };
            }
        }
    };
    // Each group's final place: after the previous groups' edges.
    let mut edge_start = vec![0usize; groups + 1];
    for (g, (written, over)) in group_edges.iter().enumerate() {
        edge_start[g + 1] = edge_start[g] + written + over.a.len();
    }
    let at = edge_start[groups];
    // Moves each group's edges in array `which` (0 for `a`, 1 for `b`, 2
    // for `opp_start`) from its slots to its final place in `v`; `shift`
    // is 1 for `opp_start`, whose first entry is not a group's. Groups
    // that move down go first, from the first, each to where the previous
    // ones end, which is no further than its slots: nothing unmoved is
    // overwritten. Then groups that move up (after an overflow), from the
    // last, each to where the next ones start. Then the overflows, past
    // their groups' edges.
    let move_edges = |v: &mut [MaybeUninit<u32>], shift: usize, which: usize| {
        let moved = |g: usize, v: &mut [MaybeUninit<u32>]| {
            let from = shift + slot_start[g];
            v.copy_within(from..from + group_edges[g].0, shift + edge_start[g]);
        };
        for g in (0..groups).filter(|&g| edge_start[g] < slot_start[g]) {
            moved(g, v);
        }
        for g in (0..groups).rev().filter(|&g| edge_start[g] > slot_start[g]) {
            moved(g, v);
        }
        for (g, (written, over)) in group_edges.iter().enumerate() {
            let over = over.array(which);
            let to = shift + edge_start[g] + written;
            for (to, &x) in v[to..to + over.len()].iter_mut().zip(over) {
                *to = MaybeUninit::new(x);
            }
        }
    };
    {
        let (va, vb, vs) = (
            e.a.spare_capacity_mut(),
            e.b.spare_capacity_mut(),
            e.opp_start.spare_capacity_mut(),
        );
        rayon::join(
            || rayon::join(move_records, || move_edges(va, 0, 0)),
            || rayon::join(|| move_edges(vb, 0, 1), || move_edges(vs, 1, 2)),
        );
    }
    drop(group_edges);
    let list = std::mem::ManuallyDrop::new(list);
    // SAFETY: `list`'s first `n` u32 are the records, all written
    // (asserted per group) and moved into place.
    e.opp = unsafe { Vec::from_raw_parts(list_at as *mut u32, n, list.capacity()) };
    e.opp.shrink_to_fit();
    // SAFETY: the records filled `opp_tri` (asserted per group);
    // `opp_start[0]` and the first `at` edges were written (pass 4 moved
    // each group's edges, all written, to follow the previous ones).
    unsafe {
        e.opp_tri.set_len(if TRI { n } else { 0 });
        e.a.set_len(at);
        e.b.set_len(at);
        e.opp_start.set_len(at + 1);
    }
    // Give back the tail sized for records (large blocks shrink in place,
    // see `crate::alloc`).
    e.a.shrink_to_fit();
    e.b.shrink_to_fit();
    e.opp_start.shrink_to_fit();
    crate::trace::since("topology: compact", emitted);
    let times = PassTimes {
        count: counted - started,
        list: listed - counted,
        emit: emitted - listed,
        compact: emitted.elapsed(),
    };
    (e, times)
}

/// The AVX-512 emit ([`emit_range_avx512`]) sorts keys `larger << 4 |
/// rank` of 32 bits, with all ones past the last record: for the records'
/// keys to fit, and their larger endpoints to differ from that padding's,
/// vertex ids must be below `KEY_IDS − 1`, so the vertex count below
/// `KEY_IDS`. Larger meshes take the scalar emit ([`emit_vertex`]).
const KEY_IDS: usize = 1 << 28;

/// Bits per vertex id in a packed listing (`u64` [`Entry`]): two ids and
/// the listed vertex's place in its range must fit in 64 bits. None when
/// the ids need more (over 2^25 vertices): the listings are then 12 bytes.
fn packed_bits(vertex_count: usize) -> Option<u32> {
    let bits = (usize::BITS - vertex_count.saturating_sub(1).leading_zeros()).max(1);
    (2 * bits + RANGE_SHIFT <= 64).then_some(bits)
}

/// A listing as pass 2 appends it to its range: the pair `[p, q]` and the
/// place in its range of the vertex it is listed under.
trait Entry: Copy {
    /// Vertex `v`'s listing `[p, q]`, ids of `bits` bits.
    fn new(v: u32, p: u32, q: u32, bits: u32) -> Self;
    /// The listed vertex's place in its range (below `RANGE`).
    fn place(self) -> usize;
    /// The pair, ids of `bits` bits.
    fn pair(self, bits: u32) -> [u32; 2];
    /// [`Entry::pair`] by one `pdep` where the entry is packed.
    ///
    /// # Safety
    /// The CPU must have BMI2.
    #[inline(always)]
    unsafe fn pair_deposited(self, bits: u32) -> [u32; 2] {
        self.pair(bits)
    }
    /// Whether this is the fill of debug builds' unwritten slots (all
    /// ones), which no listing is: its two ids would be equal.
    fn unwritten(self) -> bool;
}

/// 8 bytes, as a listing took before it carried its place:
/// `place << (64 - RANGE_SHIFT) | q << bits | p`.
impl Entry for u64 {
    #[inline(always)]
    fn new(v: u32, p: u32, q: u32, bits: u32) -> Self {
        (u64::from(v & (RANGE as u32 - 1)) << (64 - RANGE_SHIFT))
            | (u64::from(q) << bits)
            | u64::from(p)
    }
    #[inline(always)]
    fn place(self) -> usize {
        (self >> (64 - RANGE_SHIFT)) as usize
    }
    #[inline(always)]
    fn pair(self, bits: u32) -> [u32; 2] {
        let mask = (1u64 << bits) - 1;
        [(self & mask) as u32, ((self >> bits) & mask) as u32]
    }
    /// `p` and `q` deposited each in a half of a word, which is the pair
    /// (little-endian): one instruction for the two shifts and masks, in
    /// the loop of `sort_range` that puts every listing by vertex.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    unsafe fn pair_deposited(self, bits: u32) -> [u32; 2] {
        let mask = (1u64 << bits) - 1;
        // SAFETY: the caller's (BMI2).
        let w = unsafe { std::arch::x86_64::_pdep_u64(self, mask | (mask << 32)) };
        [w as u32, (w >> 32) as u32]
    }
    fn unwritten(self) -> bool {
        self == u64::MAX
    }
}

/// 12 bytes, `[v, p, q]`, for ids too wide to pack.
impl Entry for [u32; 3] {
    #[inline(always)]
    fn new(v: u32, p: u32, q: u32, _: u32) -> Self {
        [v, p, q]
    }
    #[inline(always)]
    fn place(self) -> usize {
        self[0] as usize & (RANGE - 1)
    }
    #[inline(always)]
    fn pair(self, _: u32) -> [u32; 2] {
        [self[1], self[2]]
    }
    fn unwritten(self) -> bool {
        self == [UNWRITTEN; 3]
    }
}

/// Pass 2 of [`build_edges`] for one chunk of triangles, cut into
/// `parts` of `per` triangles (the last fewer; the chunk's first id
/// `first_id`): `[mid, hi]` under lo and `[hi, lo]` under mid, each
/// appended to its vertex's range at its part's `heads` (and its triangle
/// id to the same slot of the ids at `tri_at` when TRI). A chunk of
/// [`CHUNK_PARTS`] parts is listed a triangle of each part in turn.
///
/// # Safety
/// The slots from `heads[l][r]` on, as many as part `l` lists in range
/// `r`, must lie in the listings at `list_at` (entries of type `E`) and
/// the ids at `tri_at`, and be written by no one else.
unsafe fn list_ranges<E: Entry, const TRI: bool>(
    parts: &[&[u32]],
    heads: &mut [Vec<u32>],
    first_id: u32,
    per: usize,
    bits: u32,
    list_at: usize,
    tri_at: usize,
) {
    let (out, out_t) = (list_at as *mut E, tri_at as *mut u32);
    // SAFETY (of the writes): the caller's.
    let put = |s: usize, e: E, id: u32| unsafe {
        out.add(s).write_unaligned(e);
        if TRI {
            out_t.add(s).write(id);
        }
    };
    let list = |t: &[u32], id: u32, head: &mut [u32]| {
        let (lo, mid, hi) = sort3(t);
        let (rl, rm) = ((lo >> RANGE_SHIFT) as usize, (mid >> RANGE_SHIFT) as usize);
        // (One update of the head for both listings where they fall in one
        // range, most triangles, measured no faster: the list pass 4.5–5.7
        // against 5.1–6.5 ms without on the dragon, 32.1–32.4 against
        // 30.3–32.8 ms on the 5M scene; one thread, `stage_probe --
        // passes`, three alternations with a local edit.)
        let s = head[rl] as usize;
        head[rl] += 1;
        // Each range is a stream of stores of its own: see `LIST_AHEAD`.
        crate::hint::prefetch_ptr(out.wrapping_add(s + LIST_AHEAD));
        put(s, E::new(lo, mid, hi, bits), id);
        let s = head[rm] as usize;
        head[rm] += 1;
        crate::hint::prefetch_ptr(out.wrapping_add(s + LIST_AHEAD));
        put(s, E::new(mid, hi, lo, bits), id);
    };
    // The triangles all the parts have, in step, with the parts and heads
    // as slices in locals (a store through a raw pointer may alias memory
    // they are read from, which would then be read again after it); then
    // the rest of each part.
    let mut done = 0;
    if let (Ok(in_step), Ok(hs)) = (
        <&[&[u32]; CHUNK_PARTS]>::try_from(parts),
        <&mut [Vec<u32>; CHUNK_PARTS]>::try_from(&mut *heads),
    ) {
        let (ts, hs) = (*in_step, hs.each_mut().map(|h| h.as_mut_slice()));
        done = ts[CHUNK_PARTS - 1].len() / 3;
        for i in 0..done {
            for l in 0..CHUNK_PARTS {
                crate::hint::prefetch_stream(ts[l].as_ptr().wrapping_add(3 * i));
                list(
                    &ts[l][3 * i..3 * i + 3],
                    first_id + (l * per + i) as u32,
                    hs[l],
                );
            }
        }
    }
    for (l, (t, h)) in parts.iter().zip(heads).enumerate() {
        for (i, c) in t.chunks_exact(3).enumerate().skip(done) {
            crate::hint::prefetch_stream(t.as_ptr().wrapping_add(3 * i));
            list(c, first_id + (l * per + i) as u32, h);
        }
    }
}

/// Parts of each chunk of passes 1 and 2: consecutive runs of its
/// triangles, each with its own counts and range heads; pass 2
/// ([`list_ranges`]) lists a triangle of each part in turn.
///
/// Why: each listing's head is loaded, incremented and stored, and the
/// next listing in the same range (most: a triangle's two corners and
/// consecutive triangles mostly fall in one range) loads it again, a
/// chain through memory from listing to listing. Two parts make two
/// chains, each half as long. One thread, `RECYCLE=1 RAYON_NUM_THREADS=1
/// cargo run --release --example stage_probe -- passes FILE`, the list
/// pass, fastest / median, binaries alternated: the dragon 3.65 / 3.71 →
/// 3.26 / 3.33 ms (eight), the 5M scene 21.88 / 21.89 → 19.85 / 20.36 ms
/// (four); four parts, in a first probe: the dragon as two, the 5M scene
/// as one (each job keeps four times the streams of stores going). The
/// same change (two chunks per thread, interleaved) was measured twice on
/// the AMD EPYC (Zen 4) of the twenty-fifth to fiftieth rounds and
/// dropped, 2–6% slower: the pass did not wait on the chain there. Our
/// reading, not measured: Zen 2 and later forward a store to a load of
/// the same address without its usual latency ("memory renaming"), and
/// this Xeon's Ice Lake cores do not (benches/ROUNDS.md, Sixtieth round).
const CHUNK_PARTS: usize = 2;

/// The listings pass 2 wrote, range after range, as pass 3 reads them.
struct Buckets<'a> {
    /// `start[r]..start[r + 1]` are range r's listings.
    start: &'a [u32],
    /// `records[r]..records[r + 1]` are range r's records (pass 1's
    /// counts).
    records: &'a [usize],
    /// The listings' address (pass 3 writes records over them once read).
    at: usize,
    /// The address of their triangle ids (with TRI).
    tri: usize,
    /// Bits per id of the packed `u64` entries, or None for `[u32; 3]`.
    bits: Option<u32>,
    /// Every vertex id is below [`KEY_IDS`] − 1.
    narrow: bool,
}

impl Buckets<'_> {
    /// [`Buckets::narrow`] for `vertex_count` vertices.
    fn narrow_for(vertex_count: usize) -> bool {
        vertex_count < KEY_IDS
    }
}

/// Slots of an edge array a job writes.
type Slots<'a> = &'a mut [MaybeUninit<u32>];

/// A group's edges past its slots in the edge arrays, in order ([`emit_ranges`]):
/// pass 4 puts them after the group's others.
#[derive(Default)]
struct Overflow {
    a: Vec<u32>,
    b: Vec<u32>,
    end: Vec<u32>,
}

impl Overflow {
    /// Room for `m` more edges in each array, past the ones written.
    fn room(&mut self, m: usize) -> (Slots<'_>, Slots<'_>, Slots<'_>) {
        for v in [&mut self.a, &mut self.b, &mut self.end] {
            v.reserve(m);
        }
        (
            &mut self.a.spare_capacity_mut()[..m],
            &mut self.b.spare_capacity_mut()[..m],
            &mut self.end.spare_capacity_mut()[..m],
        )
    }

    /// Marks `n` more edges written.
    ///
    /// # Safety
    /// The first `n` slots of the last [`Overflow::room`] must be written
    /// in every array.
    unsafe fn wrote(&mut self, n: usize) {
        for v in [&mut self.a, &mut self.b, &mut self.end] {
            // SAFETY: the caller's contract.
            unsafe { v.set_len(v.len() + n) };
        }
    }

    /// Array `which`: 0 for `a`, 1 for `b`, 2 for the ends.
    fn array(&self, which: usize) -> &[u32] {
        [&self.a, &self.b, &self.end][which]
    }
}

/// A pass 3 job's buffers: a range's listings in their vertices' slots
/// and their triangle ids, each vertex's number of listings, the listings
/// past the slots ([`sort_range`]), and the emit's own.
struct Scratch {
    pairs: Vec<[u32; 2]>,
    tri: Vec<u32>,
    fill: Box<[u32; RANGE]>,
    spill: Vec<Spilled>,
    buf: EmitBuf,
}

/// A listing past its vertex's [`SLOTS`]: the vertex's place in its
/// range, the pair and (with TRI) the triangle.
type Spilled = (u32, [u32; 2], u32);

/// Listing slots per vertex in a pass 3 job's scratch.
const SLOTS: usize = 8;

/// Where the slots start in a job's `pairs`: its first cache line
/// boundary, so that a vertex's slots are one line.
fn slots_at(pairs: &[[u32; 2]]) -> usize {
    pairs.as_ptr().align_offset(64)
}

/// The emit's own buffers: a vertex's records (`emit_vertex`), and the
/// listings of a vertex with more than [`SLOTS`] gathered in one place.
#[derive(Default)]
struct EmitBuf {
    records: Vec<[u32; 4]>,
    pairs: Vec<[u32; 2]>,
    tri: Vec<u32>,
}

impl Scratch {
    fn new() -> Self {
        Scratch {
            pairs: Vec::new(),
            tri: Vec::new(),
            fill: Box::new([0; RANGE]),
            spill: Vec::new(),
            buf: EmitBuf::default(),
        }
    }
}

/// Range `r`'s listings (of its `vertices` vertices) into `scratch` by
/// vertex, each vertex's in the order they were listed (so triangle
/// order), with their triangle ids when TRI: the range's i-th vertex's
/// first [`SLOTS`] listings in its slots from `i * SLOTS` (past
/// [`slots_at`]), the rest in `scratch.spill`, by vertex and then in
/// listing order, and its number of listings in `scratch.fill[i]`. One
/// pass: each listing goes to its vertex's next slot. The counters (8 KB)
/// and the slots (128 KB for a whole range) stay in L2.
///
/// Why slots (until the thirty-sixth round a counting sort on the place
/// put the listings one vertex after the other: a pass to count them,
/// the counts' sums, and a pass to scatter them, the next range's count
/// taken in the same loop as this range's scatter): no count pass, and a
/// vertex's listings (4 on average on the dragon, more than 8 for 84 of
/// its 435,545 vertices) lie in one cache line of their own. One thread,
/// `RECYCLE=1 RAYON_NUM_THREADS=1 cargo run --release --example
/// stage_probe -- passes FILE`, the emit pass: the dragon 7.55–7.67 →
/// 6.87–7.03 ms (three alternations), then 6.69–6.72 ms with the slots
/// on a cache-line boundary and the kernel's load of them whole
/// (against 6.84–6.90 without); the 5M scene 39.63–39.77 → 35.91–36.25
/// ms (two).
///
/// The listings go a block at a time ([`crate::slots`]): each listing's
/// slot is its vertex's counter, and a following listing of the same
/// vertex (most often the next: a triangle's and the next triangle's,
/// under the vertex they share) waited for its store. One thread,
/// `RECYCLE=1 RAYON_NUM_THREADS=1 cargo run --release --example
/// stage_probe -- passes FILE`, the emit pass on this AMD EPYC (Zen 3),
/// with ranges of 8,192 vertices then (see [`RANGE_SHIFT`]), fastest /
/// median, binaries alternated: the dragon 11.66 / 11.75 →
/// 10.12 / 10.25 ms, the 5M scene 59.26 / 59.45 → 50.06 / 51.49 ms (four
/// alternations each). Before, the ranges' sort alone (the kernel left
/// out, a local edit) took 5.5–5.9 ms of the dragon's 11.7, and 2.3–4.1 ms
/// with the counters not read at all.
// Inlined so that `sort_range_bmi2`'s copy is compiled with BMI2, which
// `Entry::pair_deposited`'s `pdep` needs to be inlined in its loop.
#[inline(always)]
fn sort_range<E: Entry, const TRI: bool, const DEPOSIT: bool>(
    buckets: &Buckets,
    r: usize,
    vertices: usize,
    scratch: &mut Scratch,
) {
    let from = buckets.start[r] as usize;
    let len = buckets.start[r + 1] as usize - from;
    let bits = buckets.bits.unwrap_or(0);
    // Entries are read unaligned: the listings are a Vec<u32> (their
    // memory becomes `opp`), so a u64 entry may sit at a 4-byte boundary.
    let at = buckets.at as *const E;
    // SAFETY (of every read below): pass 2 wrote the ranges' entries (and
    // ids), and no record has been written over them yet (the caller's
    // order).
    let entry = |j: usize| unsafe { at.wrapping_add(j).read_unaligned() };
    let ids = buckets.tri as *const u32;
    let fill = &mut scratch.fill[..vertices];
    fill.fill(0);
    scratch.spill.clear();
    // (One more vertex's worth: see `slots_at`.)
    if scratch.pairs.len() < (vertices + 1) * SLOTS {
        scratch.pairs.resize((vertices + 1) * SLOTS, [0; 2]);
    }
    if TRI && scratch.tri.len() < vertices * SLOTS {
        scratch.tri.resize(vertices * SLOTS, 0);
    }
    let first_slot = slots_at(&scratch.pairs);
    let pairs = &mut scratch.pairs[first_slot..first_slot + vertices * SLOTS];
    let (tri, spill) = (&mut scratch.tri[..], &mut scratch.spill);
    // Listing j, its vertex's c-th, to its slot (or the spill).
    let mut put = |j: usize, e: E, place: usize, c: usize| {
        let pair = if DEPOSIT {
            // SAFETY: DEPOSIT only in `sort_range_bmi2`.
            unsafe { e.pair_deposited(bits) }
        } else {
            e.pair(bits)
        };
        let id = if TRI {
            // SAFETY: as for the entries.
            let id = unsafe { ids.wrapping_add(j).read() };
            debug_assert!(id != UNWRITTEN, "topology: listing not written");
            id
        } else {
            0
        };
        if c < SLOTS {
            pairs[place * SLOTS + c] = pair;
            if TRI {
                tri[place * SLOTS + c] = id;
            }
        } else {
            spill.push((place as u32, pair, id));
        }
    };
    // Blocks of listings, their slots taken at once (`slots::take`), then
    // the rest one by one.
    const BLOCK: usize = crate::slots::BLOCK;
    let end = from + len;
    let mut j = from;
    while j + BLOCK <= end {
        crate::hint::prefetch_stream(at.wrapping_add(j));
        let e: [E; BLOCK] = std::array::from_fn(|k| entry(j + k));
        debug_assert!(
            e.iter().all(|e| !e.unwritten()),
            "topology: listing not written"
        );
        let p = e.map(|e| e.place());
        let c = crate::slots::take(p, fill);
        for k in 0..BLOCK {
            put(j + k, e[k], p[k], c[k]);
        }
        j += BLOCK;
    }
    for j in j..end {
        let e = entry(j);
        debug_assert!(!e.unwritten(), "topology: listing not written");
        let place = e.place();
        let [c] = crate::slots::take([place], fill);
        put(j, e, place, c);
    }
    // Each vertex's spilled listings together, in listing order (stable).
    spill.sort_by_key(|s| s.0);
}

/// [`sort_range`] with each packed listing's pair taken by one `pdep`
/// ([`Entry::pair_deposited`]), for CPUs with BMI2 (every one that runs
/// pass 3's AVX-512 kernel). Two shifts and two masks fewer per listing:
/// the emit pass 7.76–7.86 → 7.41–7.59 ms on the dragon, 41.3–41.5 →
/// 39.1–39.5 ms on the 5M scene, one thread (`RECYCLE=1 cargo run
/// --release --example stage_probe -- passes`, four and two
/// alternations).
///
/// # Safety
/// The CPU must have BMI2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "bmi2")]
unsafe fn sort_range_bmi2<E: Entry, const TRI: bool>(
    buckets: &Buckets,
    r: usize,
    vertices: usize,
    scratch: &mut Scratch,
) {
    sort_range::<E, TRI, true>(buckets, r, vertices, scratch)
}

/// Edges as borrowed arrays, in the layout of [`Edges`] (without the
/// opposite vertices' triangles): what the layout's fills read, from
/// finished [`Edges`] or from the prefix an [`EmitFeed`] hands out.
#[derive(Debug, Clone, Copy)]
pub struct EdgeSlices<'a> {
    /// Smaller endpoint of each edge.
    pub a: &'a [u32],
    /// Larger endpoint of each edge.
    pub b: &'a [u32],
    /// `opp_start[e]..opp_start[e + 1]` is edge `e`'s range in `opp` (one
    /// entry more than the edges).
    pub opp_start: &'a [u32],
    /// Opposite vertices.
    pub opp: &'a [u32],
}

impl<'a> EdgeSlices<'a> {
    /// Number of edges.
    pub fn len(&self) -> usize {
        self.a.len()
    }

    /// True when there are no edges.
    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }

    /// Opposite vertices of edge `e`.
    #[inline]
    pub fn opposites(self, e: usize) -> &'a [u32] {
        &self.opp[self.opp_start[e] as usize..self.opp_start[e + 1] as usize]
    }
}

impl Edges {
    /// The edges as [`EdgeSlices`].
    pub fn slices(&self) -> EdgeSlices<'_> {
        EdgeSlices {
            a: &self.a,
            b: &self.b,
            opp_start: &self.opp_start,
            opp: &self.opp,
        }
    }
}

/// The edges an emit pass run in order has finished so far, for a reader
/// on another thread ([`build_edges_opposites_only_fed`]).
///
/// The emit writes edge after edge, each with its opposite vertices, in
/// their final places; after every range of 2,048 vertices it
/// publishes how many edges are done (a release store), and a reader that
/// has seen that count (an acquire load) reads those edges while later
/// ones are written after them: the writer never writes below the count
/// again, and takes its mutable views of the arrays fresh for each step,
/// from the count on.
pub struct EmitFeed {
    records: usize,
    done: std::sync::atomic::AtomicUsize,
    ended: std::sync::atomic::AtomicBool,
    a: *const u32,
    b: *const u32,
    opp_start: *const u32,
    opp: *const u32,
}

// SAFETY: the pointers are only read, below the published count, which the
// writer never writes again (see the type's documentation).
unsafe impl Sync for EmitFeed {}

impl EmitFeed {
    /// Records (opposite vertices) the edges will have in all.
    pub fn records(&self) -> usize {
        self.records
    }

    /// Waits until at least `edges` edges are done or the emit has ended,
    /// doing `side` work meanwhile until it returns false, then spinning;
    /// returns the edges done and whether the emit has ended (then every
    /// edge is done).
    pub fn wait(&self, edges: usize, side: &dyn Fn() -> bool) -> (usize, bool) {
        use std::sync::atomic::Ordering::Acquire;
        let mut spins = 0u32;
        loop {
            // `ended` first: the count read after it is then the final one.
            let ended = self.ended.load(Acquire);
            let done = self.done.load(Acquire);
            if done >= edges || ended {
                return (done, ended);
            }
            if side() {
                continue;
            }
            spins += 1;
            if spins.is_multiple_of(1024) {
                std::thread::yield_now();
            } else {
                std::hint::spin_loop();
            }
        }
    }

    /// The first `n` edges; `n` must be at most a count [`EmitFeed::wait`]
    /// returned.
    pub fn edges(&self, n: usize) -> EdgeSlices<'_> {
        let done = self.done.load(std::sync::atomic::Ordering::Acquire);
        assert!(n <= done, "topology: {n} edges asked for, {done} done");
        // SAFETY: the first `done` edges, their `opp_start` entries
        // (`done + 1`, the first written before any is published) and
        // their opposite vertices are written and never written again
        // (see the type's documentation).
        unsafe {
            let records = *self.opp_start.add(n) as usize;
            EdgeSlices {
                a: std::slice::from_raw_parts(self.a, n),
                b: std::slice::from_raw_parts(self.b, n),
                opp_start: std::slice::from_raw_parts(self.opp_start, n + 1),
                opp: std::slice::from_raw_parts(self.opp, records),
            }
        }
    }
}

/// Vertices an [`EmitFeed`]'s emit pass does between two publications: a
/// range (pass 3 sorts and emits whole ranges), some 5,000 edges, so a
/// reader waits little, and 213 steps for the dragon's vertices.
const FEED_STEP: usize = RANGE;

/// Pass 3 of [`build_edges_in`] as one job in vertex order, with
/// `consumer` beside it reading the finished prefix (see [`EmitFeed`]):
/// the `n` records go over the listings in `buckets` (from the first, as
/// the first group's do) and the edges to the front of `e`'s arrays, all
/// in their final places. Returns the number of edges.
fn emit_fed(
    e: &mut Edges,
    n: usize,
    buckets: &Buckets,
    vertex_count: usize,
    simd: Simd,
    consumer: &mut (dyn FnMut(&EmitFeed) + Send),
) -> usize {
    use std::sync::atomic::Ordering::Release;
    let opp = buckets.at as *mut u32;
    // Raw pointers only, taken once: the writer's views of each step are
    // made from them, past what it has published (see `EmitFeed`).
    let (a, b, s) = (
        e.a.spare_capacity_mut()[..n].as_mut_ptr(),
        e.b.spare_capacity_mut()[..n].as_mut_ptr(),
        e.opp_start.spare_capacity_mut()[..n + 1].as_mut_ptr(),
    );
    // SAFETY: `opp_start` has room for n + 1 entries.
    unsafe { s.write(MaybeUninit::new(0)) };
    let feed = EmitFeed {
        records: n,
        done: 0.into(),
        ended: false.into(),
        a: a.cast(),
        b: b.cast(),
        opp_start: s.cast(),
        opp,
    };
    /// Marks the feed ended however the emit leaves (a panic included),
    /// so that a reader waiting on it returns.
    struct End<'a>(&'a EmitFeed);
    impl Drop for End<'_> {
        fn drop(&mut self) {
            self.0.ended.store(true, Release);
        }
    }
    let (pointers, feed_ref) = ((a as usize, b as usize, s as usize, opp as usize), &feed);
    let emit = move || {
        let _end = End(feed_ref);
        let (a, b, s, opp) = (
            pointers.0 as *mut MaybeUninit<u32>,
            pointers.1 as *mut MaybeUninit<u32>,
            pointers.2 as *mut MaybeUninit<u32>,
            pointers.3 as *mut u32,
        );
        let mut scratch = Scratch::new();
        let (mut records, mut edges) = (0usize, 0usize);
        let mut v = 0;
        while v < vertex_count {
            let next = (v + FEED_STEP).min(vertex_count);
            // SAFETY: slots `edges..n` of `a`, `b` and of `opp_start` past
            // its first entry lie in their arrays (edges never outnumber
            // records), and nothing else writes or reads them until they are
            // published; records go from `records` on, over listings already
            // read (as for a group).
            let out = unsafe {
                GroupOut {
                    opp: opp.add(records),
                    tri: &mut [],
                    a: std::slice::from_raw_parts_mut(a.add(edges), n - edges),
                    b: std::slice::from_raw_parts_mut(b.add(edges), n - edges),
                    end: std::slice::from_raw_parts_mut(s.add(1 + edges), n - edges),
                    base: records as u32,
                    room: 0,
                    records: 0,
                    edges: 0,
                }
            };
            // (The edge slots hold all the records left: no overflow.)
            let (r, ne) = emit_ranges::<false>(out, buckets, v..next, &mut scratch, simd, None);
            (records, edges) = (records + r, edges + ne);
            feed_ref.done.store(edges, Release);
            v = next;
        }
        assert_eq!(records, n, "topology: records miscounted");
        edges
    };
    let (edges, ()) = rayon::join(emit, || consumer(feed_ref));
    edges
}

/// One group's output in pass 3 of [`build_edges`]: where its records and
/// edges go, and how many of each it has written so far.
struct GroupOut<'a> {
    /// The group's records (opposite vertices), written over its own
    /// listings from their start.
    opp: *mut u32,
    /// Its range of `opp_tri` (empty without it).
    tri: &'a mut [MaybeUninit<u32>],
    /// Its slots in `a`, `b` and `opp_start` (past the first entry); a
    /// range is emitted here only with room for as many edges as it has
    /// records ([`emit_ranges`]).
    a: &'a mut [MaybeUninit<u32>],
    b: &'a mut [MaybeUninit<u32>],
    end: &'a mut [MaybeUninit<u32>],
    /// Position in `opp` of the group's first record.
    base: u32,
    /// How many u32 from `opp` on may be written: its records', and past
    /// them the listings already read (`emit_avx2` writes whole registers
    /// there). Set per range by [`emit_ranges`].
    room: usize,
    /// Records written.
    records: usize,
    /// Edges written.
    edges: usize,
}

/// A range's listings by vertex ([`sort_range`]), as pass 3's emit reads
/// them.
struct Listings<'a> {
    /// `fill[v - first]` is vertex v's number of listings.
    fill: &'a [u32],
    /// The vertex `fill` begins with.
    first: usize,
    /// [`SLOTS`] slots per vertex, its first listings from the first.
    pairs: &'a [[u32; 2]],
    /// Each slot's triangle (empty without `opp_tri`).
    tri: &'a [u32],
    /// The listings past the slots, by vertex.
    spill: &'a [Spilled],
    /// Every vertex id is below [`KEY_IDS`] − 1, so the AVX-512 kernel may
    /// sort keys of 32 bits (an id and a rank of 4 bits).
    narrow: bool,
}

impl Listings<'_> {
    /// Where vertex `v`'s slots start, and its number of listings (more
    /// than [`SLOTS`] when some are spilled: see [`Listings::gather`]).
    #[inline(always)]
    fn of(&self, v: usize) -> (usize, usize) {
        let p = v - self.first;
        (p * SLOTS, self.fill[p] as usize)
    }

    /// All `l` listings of vertex `v` (more than [`SLOTS`]) and their
    /// triangles into `buf`: its slots, then its spilled listings from
    /// `*spilled` on, which moves past them (vertices are asked for in
    /// order).
    fn gather(&self, v: usize, l: usize, spilled: &mut usize, buf: &mut EmitBuf) {
        let from = (v - self.first) * SLOTS;
        let rest = &self.spill[*spilled..*spilled + l - SLOTS];
        debug_assert!(rest.iter().all(|s| s.0 as usize == v - self.first));
        *spilled += l - SLOTS;
        buf.pairs.clear();
        buf.pairs.extend_from_slice(&self.pairs[from..from + SLOTS]);
        buf.pairs.extend(rest.iter().map(|s| s.1));
        buf.tri.clear();
        if !self.tri.is_empty() {
            buf.tri.extend_from_slice(&self.tri[from..from + SLOTS]);
            buf.tri.extend(rest.iter().map(|s| s.2));
        }
    }
}

/// Pass 3 for `vertices` (whole ranges; the last may end at the vertex
/// count): each range's listings put by vertex ([`sort_range`]), then
/// its edges emitted from there; its records go to `out` after the ones
/// before, over listings already read. Its edges go to `out`'s edge
/// slots while they have room for as many edges as the range has records,
/// then (this range and all later ones) to `overflow`, which must then be
/// given. Returns the numbers of records written and of edges written to
/// `out`.
fn emit_ranges<const TRI: bool>(
    out: GroupOut,
    buckets: &Buckets,
    vertices: std::ops::Range<usize>,
    scratch: &mut Scratch,
    simd: Simd,
    mut overflow: Option<&mut Overflow>,
) -> (usize, usize) {
    let GroupOut {
        opp,
        tri,
        a,
        b,
        end,
        base,
        ..
    } = out;
    let (mut records, mut edges) = (0usize, 0usize);
    let mut spilling = false;
    let listing_bytes = std::mem::size_of::<u32>() * if buckets.bits.is_some() { 2 } else { 3 };
    let mut v = vertices.start;
    while v < vertices.end {
        let next = (v + RANGE).min(vertices.end);
        let r = v >> RANGE_SHIFT;
        let n = next - v;
        match (buckets.bits, simd) {
            // SAFETY: `Simd::Avx512` is set only where the CPU has BMI2
            // (`simd_level`).
            #[cfg(target_arch = "x86_64")]
            (Some(_), Simd::Avx512) => unsafe {
                sort_range_bmi2::<u64, TRI>(buckets, r, n, scratch)
            },
            (Some(_), _) => sort_range::<u64, TRI, false>(buckets, r, n, scratch),
            (None, _) => sort_range::<[u32; 3], TRI, false>(buckets, r, n, scratch),
        }
        // Records may go as far as the listings read, which end with this
        // range's (a listing gives at most 2 records, and takes 2 or 3 u32).
        let read = buckets.at + listing_bytes * buckets.start[r + 1] as usize;
        let o_opp = opp.wrapping_add(records);
        // A range has no more edges than records, and the emit asks for
        // room for all of them.
        let m = buckets.records[r + 1] - buckets.records[r];
        spilling |= a.len() - edges < m;
        let (oa, ob, oe) = match (spilling, overflow.as_deref_mut()) {
            (false, _) => (&mut a[edges..], &mut b[edges..], &mut end[edges..]),
            (true, Some(over)) => over.room(m),
            (true, None) => panic!("topology: no room for a range's edges"),
        };
        let o = GroupOut {
            opp: o_opp,
            tri: if TRI { &mut tri[records..] } else { &mut [] },
            a: oa,
            b: ob,
            end: oe,
            base: base + records as u32,
            room: (read - o_opp as usize) / std::mem::size_of::<u32>(),
            records: 0,
            edges: 0,
        };
        let listings = Listings {
            fill: &scratch.fill[..n],
            first: v,
            pairs: &scratch.pairs[slots_at(&scratch.pairs)..][..n * SLOTS],
            tri: &scratch.tri[..if TRI { n * SLOTS } else { 0 }],
            spill: &scratch.spill,
            narrow: buckets.narrow,
        };
        let (rn, en) = emit_group::<TRI>(o, &listings, v..next, &mut scratch.buf, simd);
        records += rn;
        match overflow.as_deref_mut().filter(|_| spilling) {
            // SAFETY: the emit wrote the first `en` slots of `room`'s.
            Some(over) => unsafe { over.wrote(en) },
            None => edges += en,
        }
        v = next;
    }
    (records, edges)
}

/// Pass 3 of [`build_edges`] for a group's `vertices`, with the kernel
/// `simd` names (never with `opp_tri`, which `lint` alone asks for);
/// returns the numbers of records and edges written.
#[inline(always)]
fn emit_group<const TRI: bool>(
    out: GroupOut,
    listings: &Listings,
    vertices: std::ops::Range<usize>,
    buf: &mut EmitBuf,
    simd: Simd,
) -> (usize, usize) {
    #[cfg(target_arch = "x86_64")]
    if !TRI && listings.narrow {
        match simd {
            // SAFETY: `Simd::Avx512` is set only where the CPU has
            // AVX-512F and AVX-512VL, `Simd::Avx2` only where it has AVX2
            // and POPCNT (`simd_level`).
            Simd::Avx512 => return unsafe { emit_range_avx512(out, listings, vertices, buf) },
            Simd::Avx2 => {
                return unsafe { emit_avx2::emit_range_avx2(out, listings, vertices, buf) };
            }
            Simd::Plain => {}
        }
    }
    let _ = simd;
    emit_range::<TRI>(out, listings, vertices, buf)
}

/// [`emit_vertex`] for a group's `vertices`; returns the numbers of
/// records and edges written.
///
/// A function of its own, as the kernel is, not inlined into the job:
/// sharing the job's code with the call to the kernel, the loop took 7%
/// longer on the dragon (13.4–14.0 against 14.4–15.1 ms, `RECYCLE=1
/// NO_AVX512=1 cargo run --release --example stage_probe -- passes`).
#[inline(never)]
fn emit_range<const TRI: bool>(
    mut out: GroupOut,
    listings: &Listings,
    vertices: std::ops::Range<usize>,
    buf: &mut EmitBuf,
) -> (usize, usize) {
    let mut spilled = 0;
    for v in vertices {
        let (from, l) = listings.of(v);
        if l <= SLOTS {
            let listed = &listings.pairs[from..from + l];
            emit_vertex::<TRI>(
                &mut out,
                v as u32,
                from,
                listed,
                listings.tri,
                &mut buf.records,
            );
        } else {
            listings.gather(v, l, &mut spilled, buf);
            emit_vertex::<TRI>(
                &mut out,
                v as u32,
                0,
                &buf.pairs,
                &buf.tri,
                &mut buf.records,
            );
        }
    }
    (out.records, out.edges)
}

/// Which kernels the topology's passes run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Simd {
    /// The scalar loops.
    Plain,
    /// Pass 3's AVX2 kernel (`emit_avx2`) and pass 1's (`count_avx2`).
    Avx2,
    /// Pass 3's AVX-512 kernel and `sort_range_bmi2`, and pass 1's
    /// `count_avx512`.
    Avx512,
}

/// Set by [`scalar_topology`].
static SCALAR: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Makes the topology run its scalar passes, none of its AVX2 or AVX-512
/// kernels, until called again with `false`. For benchmarks, which time
/// both in one run; the edges are the same either way.
#[doc(hidden)]
pub fn scalar_topology(on: bool) {
    SCALAR.store(on, std::sync::atomic::Ordering::Relaxed);
}

/// The fastest [`Simd`] this CPU runs (run-time checks), `Plain` when
/// [`scalar_topology`] asks for it: `Avx512` where it has AVX-512F,
/// AVX-512VL, AVX-512DQ and BMI2 and `evaluate_simd::disable_avx512` has
/// not turned the crate's AVX-512 kernels off, else `Avx2` where it has
/// AVX2 and POPCNT, else `Plain`.
fn simd_level() -> Simd {
    if SCALAR.load(std::sync::atomic::Ordering::Relaxed) {
        return Simd::Plain;
    }
    #[cfg(target_arch = "x86_64")]
    {
        if crate::evaluate_simd::have_avx512()
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx512dq")
            && std::arch::is_x86_feature_detected!("bmi2")
        {
            return Simd::Avx512;
        }
        if avx2_kernels_run() {
            return Simd::Avx2;
        }
    }
    Simd::Plain
}

/// Whether the CPU runs the AVX2 kernels (`Simd::Avx2`): it has AVX2 and
/// POPCNT (run-time checks).
#[cfg(target_arch = "x86_64")]
fn avx2_kernels_run() -> bool {
    crate::evaluate_simd::have_avx2() && std::arch::is_x86_feature_detected!("popcnt")
}

/// Pass 3 for vertex `v`, whose listings `listed` start at `from`: its
/// records sorted by larger endpoint, stably (so by triangle within an
/// edge), its opposite vertices (and triangles) written in that order, and
/// one edge per larger endpoint.
#[inline(always)]
fn emit_vertex<const TRI: bool>(
    out: &mut GroupOut,
    v: u32,
    from: usize,
    listed: &[[u32; 2]],
    tri: &[u32],
    buf: &mut Vec<[u32; 4]>,
) {
    // Two record slots per listing, plus the block padding.
    let need = 2 * listed.len() + SMALL_RUN;
    if buf.len() < need {
        buf.resize(need, [0; 4]);
    }
    let mut k = 0;
    for (j, &[p, q]) in listed.iter().enumerate() {
        // Records are [_, larger endpoint, opposite, order]: the listing
        // itself, and when it was listed under lo (p < q) also its swap.
        // Both slots are written without a branch (the kinds alternate
        // unpredictably); a mid listing's second slot is overwritten by the
        // next record. `order` is the triangle, or without TRI the
        // listing's rank, which follows triangle order just the same.
        let order = if TRI { tri[from + j] } else { j as u32 };
        buf[k] = [0, p, q, order];
        buf[k + 1] = [0, q, p, order];
        k += 1 + usize::from(p < q);
    }
    // Pass 1 counted the group's records, so this holds; it is checked
    // because the writes below are unchecked.
    assert!(
        out.records + k <= out.a.len(),
        "topology: records miscounted"
    );
    // Writes one record, in order: its opposite vertex (and triangle) at
    // the next record slot, and an edge slot; only the last record of each
    // larger endpoint's run advances past that slot (no branch: it would
    // mispredict on about every other record). The edge's range ends here,
    // a global position in `opp`. `edges` never passes the records seen
    // before this one, so the slot exists.
    // (On locals, written back to `out` at the end.)
    let (opp, base, tri_out) = (out.opp, out.base, &mut *out.tri);
    let (a, b, end) = (&mut *out.a, &mut *out.b, &mut *out.end);
    let (mut records, mut edges) = (out.records, out.edges);
    let mut put = |rec: &[u32; 4], run_ends: bool| {
        // SAFETY: `records` is below the group's record count (asserted
        // above), and those slots are the group's (`GroupOut::opp`).
        unsafe { opp.add(records).write(rec[2]) };
        if TRI {
            tri_out[records] = MaybeUninit::new(rec[3]);
        }
        records += 1;
        a[edges] = MaybeUninit::new(v);
        b[edges] = MaybeUninit::new(rec[1]);
        end[edges] = MaybeUninit::new(base + records as u32);
        edges += usize::from(run_ends);
    };
    // By larger endpoint, then triangle: the listings are in triangle order
    // and a triangle has one record per larger endpoint, so a stable sort
    // by larger endpoint and the standard unstable sort on (larger,
    // triangle) agree.
    if k <= SMALL_RUN {
        let order = sort_small(buf[..SMALL_RUN].try_into().unwrap(), k);
        for j in 0..k {
            let (key, next) = (order[j] >> 32, order[j + 1] >> 32);
            put(&buf[order[j] as usize % SMALL_RUN], next != key);
        }
    } else {
        let sorted = &mut buf[..k];
        sorted.sort_unstable_by_key(|r| (u64::from(r[1]) << 32) | u64::from(r[3]));
        for (i, rec) in sorted.iter().enumerate() {
            put(rec, sorted.get(i + 1).is_none_or(|nx| nx[1] != rec[1]));
        }
    }
    (out.records, out.edges) = (records, edges);
}

/// [`emit_vertex`] for a group's `vertices`: vertices with at most 8
/// listings in AVX-512 registers (all but 84 of the dragon's 435,545), the
/// others by [`emit_vertex`]. Same output, word for word. Only for
/// `listings.narrow` (ids below [`KEY_IDS`] − 1).
///
/// Method, per vertex: its listings in one load; the larger endpoints are
/// the listings' words as they lie ([p, q] gives p, and q where p < q), the
/// opposite vertices the same words with each pair swapped; one compress of
/// each by the mask of records keeps them in listing (so triangle) order
/// (with at most 4 listings the words stay where they lie, and the other
/// lanes are padding). Keys `larger << 4 | rank` of 32 bits go through an
/// 8-input sorting network (a shuffle, a min, a max and a blend per
/// layer; see `sort8` for why not [`sort_small`]'s) in a 256-bit register,
/// or with 9 to 16 records (5.7% of the dragon's vertices, 10% of its
/// records) through it in two registers and a bitonic merge: distinct
/// keys, so the result is the stable order. The
/// ranks then permute the opposite vertices; an edge ends where the next
/// larger endpoint differs, and the edges are compressed out of the
/// records. Why: the scalar version spends its time moving records
/// through memory, on the network's 19 dependent compare-exchanges, and
/// above 8 records on the standard sort's mispredicted branches.
///
/// Why 32-bit keys in 256-bit registers (until the twenty-fifth round the
/// keys were `larger << 32 | rank`, 8 to a 512-bit register): this
/// machine's AMD EPYC runs a 512-bit operation as two 256-bit halves, and
/// the keys took conversions to and from 64 bits. One thread, `RECYCLE=1
/// cargo run --release --example stage_probe -- passes`, the emit pass's
/// median of alternated runs against the 64-bit keys: the dragon 11.0 →
/// 8.5 ms (six), the 5M scene 62.6 → 50.5 ms (four). The records of a
/// vertex with 9 to 16 go out as two halves of 8, each through the same
/// 256-bit code. A version that finished every vertex's records in one
/// 512-bit register was slower than one with the 256-bit code for up to 8
/// records (and the 64-bit keys above): the emit's medians 8.84 against
/// 8.65 ms on the dragon (five alternations), 57.6 against 51.8 ms on the
/// 5M scene (three). Over 2^28 vertices, where the keys would not fit,
/// the scalar emit runs ([`KEY_IDS`]).
///
/// Two vertices at a time: where a vertex and the next both have at most 4
/// listings (as 74% of the dragon's vertices have), their first 4 slots go
/// in the two 256-bit halves of one 512-bit register, through the same
/// network (`sort8x2`: no layer pairs lanes of different halves) and one
/// finish (`finish2`) whose compresses put the second vertex's records and
/// edges right after the first's. Why: the path for one such vertex waits
/// on its own chain of load, compare, network and compress: llvm-mca's Ice
/// Lake model gives it 37.2 cycles a vertex, against 18.7 that its ports
/// allow; the pair takes 56.2 cycles, 28.1 a vertex (each path cut by hand
/// from the disassembly of a build as `benches/kernel_mca.sh` makes it, its
/// branches left out, and given to `llvm-mca -mcpu=icelake-server`). This
/// Intel Xeon runs a 512-bit operation whole; on the AMD EPYC of the
/// earlier rounds, which runs it as two halves, the same idea was slower
/// (benches/ROUNDS.md, "Thirty-sixth round"). One thread, `RECYCLE=1
/// RAYON_NUM_THREADS=1 cargo run --release --example stage_probe -- passes
/// FILE`, the emit pass's fastest and median of alternated runs: the dragon
/// 9.08 / 9.36 → 8.42 / 8.75 ms (ten), the 5M scene 53.41 / 54.37 → 42.69 /
/// 42.75 ms (three).
///
/// Where two vertices do not both have at most 4 listings, but both have at
/// most 8 listings and 8 records, each vertex's records are first
/// compressed into its half, and the pair then goes the same way. Against
/// the pairs of at most 4 listings alone, the same command: the dragon 8.48
/// / 8.52 → 8.22 / 8.34 and 8.60 / 8.77 → 8.26 / 8.53 ms (two runs of eight
/// alternations), the 5M scene 42.14 / 42.16 against 42.21 / 42.31 ms
/// (three). Every pair through the compresses, those of at most 4 listings
/// too, was slower on the 5M scene (45.89 / 47.93 against 42.97 / 43.01
/// ms).
///
/// # Safety
/// The CPU must have AVX-512F and AVX-512VL.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512vl,popcnt")]
unsafe fn emit_range_avx512(
    mut group: GroupOut,
    listings: &Listings,
    vertices: std::ops::Range<usize>,
    buf: &mut EmitBuf,
) -> (usize, usize) {
    use std::arch::x86_64::*;
    debug_assert!(
        listings.narrow,
        "topology: 32-bit keys need ids below KEY_IDS - 1"
    );
    let rank = _mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
    let reverse = _mm256_set_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let none = _mm512_set1_epi32(-1);
    // One layer of compare-exchanges: lane i against `partner`'s lane i
    // (the keys `s` permuted), the lanes in `upper` keeping the larger.
    let layer = |s: __m256i, partner: __m256i, upper: u8| {
        _mm256_mask_blend_epi32(
            upper,
            _mm256_min_epu32(s, partner),
            _mm256_max_epu32(s, partner),
        )
    };
    // Partners at distance 1 and 2 lie in the same 128-bit half, where a
    // `vpshufd` finds them; distance 4 swaps the halves.
    let d1 = |s: __m256i, upper: u8| layer(s, _mm256_shuffle_epi32::<0xB1>(s), upper);
    let d2 = |s: __m256i, upper: u8| layer(s, _mm256_shuffle_epi32::<0x4E>(s), upper);
    let d4 = |s: __m256i, upper: u8| layer(s, _mm256_permute4x64_epi64::<0x4E>(s), upper);
    // Sorts 8 keys in 6 layers, 5 of them inside the halves: each half by
    // the network of 4 ((0,1)(2,3), (0,2)(1,3), (1,2)), then the halves
    // merged (lane i against lane 7 − i, then half-cleaners at distances 2
    // and 1). Why not an optimal network of 8 (`NETWORK8`, 19
    // compare-exchanges against these 22, also 6 layers, which this kernel
    // ran until the thirty-first round): four of its layers pair lanes of
    // different halves, each a `vpermd`, whose latency the pass waits on:
    // a vertex's records go through load, compress, network and
    // compress one after the other. One thread, the emit pass 8.95–9.01 →
    // 8.10–8.14 ms on the dragon and 50.4–50.5 → 45.9–46.3 ms on the 5M
    // scene (`RECYCLE=1 cargo run --release --example stage_probe --
    // passes`, three and two alternations; on the dragon 8.57–8.65 ms
    // with only NETWORK8's in-half layers by `vpshufd`).
    let sort8 = |s: __m256i| {
        let s = d1(s, 0xAA);
        let s = d2(s, 0xCC);
        let s = layer(s, _mm256_shuffle_epi32::<0xD8>(s), 0x44);
        let s = layer(s, _mm256_permutexvar_epi32(reverse, s), 0xF0);
        d1(d2(s, 0xCC), 0xAA)
    };
    // Half-cleaners at distances 4, 2 and 1: sorts a bitonic sequence.
    let merge8 = |s: __m256i| d1(d2(d4(s, 0xF0), 0xCC), 0xAA);
    let rank8 = _mm256_set_epi32(7, 6, 5, 4, 3, 2, 1, 0);
    let none8 = _mm256_set1_epi32(-1);
    // Writes `k` (at most 8) sorted records of vertex `v` and their edges:
    // `sorted` their keys, `after` keys whose first is the key after them
    // (all ones for none), `opp_lo` and `opp_hi` the vertex's opposite
    // vertices by rank.
    let finish = |out: &mut KernelOut,
                  sorted: __m256i,
                  after: __m256i,
                  opp_lo: __m256i,
                  opp_hi: __m256i,
                  k: usize,
                  v: usize| {
        let kmask = ((1u32 << k) - 1) as u8;
        let larger = _mm256_srli_epi32::<4>(sorted);
        let opposite = _mm256_permutex2var_epi32(
            opp_lo,
            _mm256_and_si256(sorted, _mm256_set1_epi32(15)),
            opp_hi,
        );
        let next = _mm256_srli_epi32::<4>(_mm256_alignr_epi32::<1>(after, sorted));
        let ends = _mm256_mask_cmpneq_epu32_mask(kmask, larger, next);
        let edges = ends.count_ones() as usize;
        let emask = ((1u32 << edges) - 1) as u8;
        let end = _mm256_add_epi32(
            rank8,
            _mm256_set1_epi32((out.base + out.records as u32 + 1) as i32),
        );
        let (a_at, b_at, end_at) = (
            _mm256_set1_epi32(v as i32),
            _mm256_maskz_compress_epi32(ends, larger),
            _mm256_maskz_compress_epi32(ends, end),
        );
        // SAFETY: records `records..records + k` are the group's
        // (asserted by the caller), and edges never outnumber records; the
        // whole stores write 8 slots from `edges` only inside `a`, `b` and
        // `end`, which are equally long.
        unsafe {
            _mm256_mask_storeu_epi32(out.opp.add(out.records).cast(), kmask, opposite);
            let (a, b, e) = (
                out.a.add(out.edges),
                out.b.add(out.edges),
                out.end.add(out.edges),
            );
            // Whole stores of the edges, with garbage past the vertex's
            // last edge, which the next vertex's edges overwrite (or which
            // lies past the edges the group returns), except near the
            // arrays' ends. Why: a masked store is slow on this machine's
            // AMD EPYC: with the 512-bit stores of the keys' previous form
            // (c6f213e), the emit pass's median of five alternations went
            // 13.8 → 11.5 ms on the dragon, 78.7 → 66.5 ms on the 5M scene
            // (three), one thread (`RECYCLE=1 cargo run --release --example
            // stage_probe -- passes`). The same for the records, which
            // would need the room past them tracked, gained nothing (11.9 /
            // 11.9 ms on the dragon, 71 / 66 ms on the 5M scene).
            if out.edges + 8 <= out.len {
                _mm256_storeu_si256(a.cast(), a_at);
                _mm256_storeu_si256(b.cast(), b_at);
                _mm256_storeu_si256(e.cast(), end_at);
            } else {
                _mm256_mask_storeu_epi32(a.cast(), emask, a_at);
                _mm256_mask_storeu_epi32(b.cast(), emask, b_at);
                _mm256_mask_storeu_epi32(e.cast(), emask, end_at);
            }
            // The three edge arrays 2 KiB ahead (`hint::STREAM_AHEAD`).
            // One thread, `RECYCLE=1 cargo run --release --example
            // stage_probe -- passes`, the emit pass's median of eight
            // alternations: the dragon 10.44 → 10.16 ms, the 5M scene 62.7
            // → 59.3 ms. In `emit_vertex` (`NO_AVX512=1`, four
            // alternations) it gained nothing: 19.23 → 19.20 and 90.9 →
            // 96.6 ms.
            crate::hint::prefetch_stream(a);
            crate::hint::prefetch_stream(b);
            crate::hint::prefetch_stream(e);
        }
        out.records += k;
        out.edges += edges;
    };
    // The network of `sort8` on two vertices' keys at once, one in each
    // 256-bit half of a 512-bit register (the halves never meet: every
    // partner lies in the lane's own half).
    let reverse2 = |s: __m512i| _mm512_permutex_epi64::<0x4E>(_mm512_shuffle_epi32::<0x1B>(s));
    let layer2 = |s: __m512i, partner: __m512i, upper: u16| {
        _mm512_mask_blend_epi32(
            upper,
            _mm512_min_epu32(s, partner),
            _mm512_max_epu32(s, partner),
        )
    };
    let sort8x2 = |s: __m512i| {
        let s = layer2(s, _mm512_shuffle_epi32::<0xB1>(s), 0xAAAA);
        let s = layer2(s, _mm512_shuffle_epi32::<0x4E>(s), 0xCCCC);
        let s = layer2(s, _mm512_shuffle_epi32::<0xD8>(s), 0x4444);
        let s = layer2(s, reverse2(s), 0xF0F0);
        let s = layer2(s, _mm512_shuffle_epi32::<0x4E>(s), 0xCCCC);
        layer2(s, _mm512_shuffle_epi32::<0xB1>(s), 0xAAAA)
    };
    // Each lane's rank in its half; the first lane of each lane's half;
    // 1 in the second vertex's half (its id is the first's plus 1).
    let rank8x2 = _mm512_set_epi32(7, 6, 5, 4, 3, 2, 1, 0, 7, 6, 5, 4, 3, 2, 1, 0);
    let half = _mm512_set_epi32(8, 8, 8, 8, 8, 8, 8, 8, 0, 0, 0, 0, 0, 0, 0, 0);
    let second = _mm512_set_epi32(1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0);
    // Writes two vertices' records and edges from their keys (`keys`,
    // the first vertex's in the low half, records with keys `larger << 4
    // | rank`, all ones elsewhere), their opposite vertices by rank in
    // `swapped`'s halves, `k0` records of the first and `k` of both.
    let finish2 =
        |out: &mut KernelOut, keys: __m512i, swapped: __m512i, k0: usize, k: usize, v: usize| {
            let sorted = sort8x2(keys);
            // Each vertex's records in its half's first lanes (the
            // rest all ones); the masks of both halves' records.
            let kmask = (((1u32 << k0) - 1) | (((1u32 << (k - k0)) - 1) << 8)) as u16;
            let larger = _mm512_srli_epi32::<4>(sorted);
            let opposite = _mm512_permutexvar_epi32(
                _mm512_or_si512(_mm512_and_si512(sorted, _mm512_set1_epi32(15)), half),
                swapped,
            );
            // The key after each: the first half's last lane has none
            // (not the second vertex's first key).
            let next = _mm512_srli_epi32::<4>(_mm512_mask_mov_epi32(
                _mm512_alignr_epi32::<1>(none, sorted),
                0x0080,
                none,
            ));
            let ends = _mm512_mask_cmpneq_epu32_mask(kmask, larger, next);
            let edges = ends.count_ones() as usize;
            let first_end = (out.base + out.records as u32 + 1) as i32;
            let end = _mm512_add_epi32(
                _mm512_set1_epi32(first_end),
                _mm512_mask_add_epi32(rank8x2, 0xFF00, rank8x2, _mm512_set1_epi32(k0 as i32)),
            );
            let (a_at, b_at, end_at) = (
                _mm512_maskz_compress_epi32(
                    ends,
                    _mm512_add_epi32(_mm512_set1_epi32(v as i32), second),
                ),
                _mm512_maskz_compress_epi32(ends, larger),
                _mm512_maskz_compress_epi32(ends, end),
            );
            // SAFETY: as in `finish`, for 16 slots.
            unsafe {
                _mm512_mask_storeu_epi32(
                    out.opp.add(out.records).cast(),
                    ((1u32 << k) - 1) as u16,
                    _mm512_maskz_compress_epi32(kmask, opposite),
                );
                let (a, b, e) = (
                    out.a.add(out.edges),
                    out.b.add(out.edges),
                    out.end.add(out.edges),
                );
                if out.edges + 16 <= out.len {
                    _mm512_storeu_si512(a.cast(), a_at);
                    _mm512_storeu_si512(b.cast(), b_at);
                    _mm512_storeu_si512(e.cast(), end_at);
                } else {
                    let emask = ((1u32 << edges) - 1) as u16;
                    _mm512_mask_storeu_epi32(a.cast(), emask, a_at);
                    _mm512_mask_storeu_epi32(b.cast(), emask, b_at);
                    _mm512_mask_storeu_epi32(e.cast(), emask, end_at);
                }
                crate::hint::prefetch_stream(a);
                crate::hint::prefetch_stream(b);
                crate::hint::prefetch_stream(e);
            }
            out.records += k;
            out.edges += edges;
        };
    // The lanes of `x` (listings' words, `swapped` the same with each
    // pair swapped) that are records, of those in `words`: word 2j is
    // listing j's p (always a record's larger endpoint), word 2j + 1 its q
    // (a record's where p < q); words outside `words` are not looked at.
    let records_of = |x: __m512i, swapped: __m512i, words: u16| {
        let lower = _mm512_cmplt_epu32_mask(x, swapped) & 0x5555 & words;
        (0x5555 & words) | (lower << 1)
    };
    let mut spilled = 0;
    let mut kout = KernelOut::of(&mut group);
    let mut next_v = vertices.start;
    while next_v < vertices.end {
        let v = next_v;
        next_v += 1;
        let out = &mut kout;
        let (from, l) = listings.of(v);
        if l <= 4 && v + 1 < vertices.end {
            let (_, l1) = listings.of(v + 1);
            if l1 <= 4 {
                // Two vertices of at most 4 listings each, one in each half
                // of a 512-bit register: their first 4 slots each.
                let slots = &listings.pairs[from..from + 2 * SLOTS];
                // SAFETY: the loads read the first 32 bytes of each
                // vertex's 64 in `slots`.
                let x = unsafe {
                    _mm512_inserti64x4::<1>(
                        _mm512_castsi256_si512(_mm256_loadu_si256(slots.as_ptr().cast())),
                        _mm256_loadu_si256(slots[SLOTS..].as_ptr().cast()),
                    )
                };
                let swapped = _mm512_ror_epi64::<32>(x);
                let words = (((1u32 << (2 * l)) - 1) | (((1u32 << (2 * l1)) - 1) << 8)) as u16;
                let records = records_of(x, swapped, words);
                let k0 = (records as u8).count_ones() as usize;
                let k = records.count_ones() as usize;
                assert!(out.records + k <= out.len, "topology: records miscounted");
                let keys = _mm512_mask_blend_epi32(
                    records,
                    none,
                    _mm512_or_si512(_mm512_slli_epi32::<4>(x), rank8x2),
                );
                finish2(out, keys, swapped, k0, k, v);
                next_v += 1;
                continue;
            }
        }
        if l <= 8 {
            // The vertex's 8 slots in one load, whatever its number of
            // listings (the lanes past them are not looked at).
            const { assert!(SLOTS == 8) };
            let slots = &listings.pairs[from..from + SLOTS];
            // SAFETY: the load reads the 64 bytes of `slots`.
            let x = unsafe { _mm512_loadu_si512(slots.as_ptr().cast()) };
            let swapped = _mm512_ror_epi64::<32>(x);
            let records = records_of(x, swapped, ((1u32 << (2 * l)) - 1) as u16);
            let k = records.count_ones() as usize;
            assert!(out.records + k <= out.len, "topology: records miscounted");
            if k <= 8 && v + 1 < vertices.end {
                let (_, l1) = listings.of(v + 1);
                if l1 <= 8 {
                    // SAFETY: the load reads the next vertex's 64 bytes
                    // of slots, right after this one's.
                    let x1 = unsafe {
                        _mm512_loadu_si512(
                            listings.pairs[from + SLOTS..from + 2 * SLOTS]
                                .as_ptr()
                                .cast(),
                        )
                    };
                    let s1 = _mm512_ror_epi64::<32>(x1);
                    let records1 = records_of(x1, s1, ((1u32 << (2 * l1)) - 1) as u16);
                    let k1 = records1.count_ones() as usize;
                    if k1 <= 8 {
                        assert!(
                            out.records + k + k1 <= out.len,
                            "topology: records miscounted"
                        );
                        let join = |a: __m512i, b: __m512i| {
                            _mm512_inserti64x4::<1>(a, _mm512_castsi512_si256(b))
                        };
                        let words = join(
                            _mm512_maskz_compress_epi32(records, x),
                            _mm512_maskz_compress_epi32(records1, x1),
                        );
                        let opposite = join(
                            _mm512_maskz_compress_epi32(records, swapped),
                            _mm512_maskz_compress_epi32(records1, s1),
                        );
                        let kmask = (((1u32 << k) - 1) | (((1u32 << k1) - 1) << 8)) as u16;
                        let keys = _mm512_mask_blend_epi32(
                            kmask,
                            none,
                            _mm512_or_si512(_mm512_slli_epi32::<4>(words), rank8x2),
                        );
                        finish2(out, keys, opposite, k, k + k1, v);
                        next_v += 1;
                        continue;
                    }
                }
            }
            if l <= 4 {
                // At most 8 words: keys made in place, with the rank of
                // each record its word's lane and the other lanes all
                // ones, so no compress stands between the load and the
                // network (the path below, where 16 words need one: a
                // `vpcompressd` of a whole register, whose latency the
                // vertex waits on as it waits on the network's). One
                // thread, the emit pass 8.10–8.14 → 7.72–7.75 ms on the
                // dragon, where a vertex has 4 listings on average, and
                // 45.9–46.3 → 40.9–41.3 ms on the 5M scene (`RECYCLE=1
                // cargo run --release --example stage_probe -- passes`,
                // three and two alternations). The same for 5 to 8
                // listings, two networks of 8 and a merge instead of the
                // compress, was slower on the dragon: 8.09–8.14 against
                // 7.72–8.01 ms.
                let keys = _mm256_mask_blend_epi32(
                    records as u8,
                    none8,
                    _mm256_or_si256(_mm256_slli_epi32::<4>(_mm512_castsi512_si256(x)), rank8),
                );
                let opp = _mm512_castsi512_si256(swapped);
                finish(out, sort8(keys), none8, opp, opp, k, v);
                continue;
            }
            let kmask = ((1u32 << k) - 1) as u16;
            // Keys `larger << 4 | rank`, all ones past the last record
            // (whose larger endpoint no record has: `narrow`).
            let keys = _mm512_mask_blend_epi32(
                kmask,
                none,
                _mm512_or_si512(
                    _mm512_slli_epi32::<4>(_mm512_maskz_compress_epi32(records, x)),
                    rank,
                ),
            );
            let opposite = _mm512_maskz_compress_epi32(records, swapped);
            let (opp_lo, opp_hi) = (
                _mm512_castsi512_si256(opposite),
                _mm512_extracti64x4_epi64::<1>(opposite),
            );
            let first = _mm512_castsi512_si256(keys);
            if k <= 8 {
                finish(out, sort8(first), none8, opp_lo, opp_hi, k, v);
            } else {
                // Two sorted halves, then a bitonic merge: the first half
                // against the second reversed gives the 8 smallest and the
                // 8 largest keys, each a bitonic sequence, which three
                // half-cleaners sort.
                let (a, b) = (sort8(first), sort8(_mm512_extracti64x4_epi64::<1>(keys)));
                let b = _mm256_permutexvar_epi32(reverse, b);
                let (lo, hi) = (
                    merge8(_mm256_min_epu32(a, b)),
                    merge8(_mm256_max_epu32(a, b)),
                );
                finish(out, lo, hi, opp_lo, opp_hi, 8, v);
                finish(out, hi, none8, opp_lo, opp_hi, k - 8, v);
            }
            continue;
        }
        listings.gather(v, l, &mut spilled, buf);
        (group.records, group.edges) = (kout.records, kout.edges);
        emit_vertex::<false>(
            &mut group,
            v as u32,
            0,
            &buf.pairs,
            &buf.tri,
            &mut buf.records,
        );
        // (Pointers taken again: `emit_vertex` wrote through the slices.)
        kout = KernelOut::of(&mut group);
    }
    (kout.records, kout.edges)
}

/// What [`emit_range_avx512`] writes through, as raw pointers and counts in
/// a local of its own.
///
/// Why: through the [`GroupOut`] it gets, whose address [`emit_vertex`]
/// also takes, every store of a record or an edge could have changed the
/// struct, so the kernel loaded its pointers and counts again after each
/// vertex's stores and stored the counts back. One thread, `RECYCLE=1
/// RAYON_NUM_THREADS=1 cargo run --release --example stage_probe --
/// passes FILE`, binaries alternated: the emit pass 6.71–6.77 → 6.56–6.60
/// ms on the dragon (four), 35.28–35.36 → 34.72–34.93 ms on the 5M scene
/// (two).
#[cfg(target_arch = "x86_64")]
struct KernelOut {
    /// [`GroupOut::opp`].
    opp: *mut u32,
    /// The starts of [`GroupOut::a`], [`GroupOut::b`] and
    /// [`GroupOut::end`], taken again after anything else writes them.
    a: *mut MaybeUninit<u32>,
    b: *mut MaybeUninit<u32>,
    end: *mut MaybeUninit<u32>,
    /// The length of `a`, `b` and `end`.
    len: usize,
    /// [`GroupOut::base`].
    base: u32,
    /// [`GroupOut::room`].
    room: usize,
    /// [`GroupOut::records`], handed back before anything else writes.
    records: usize,
    /// [`GroupOut::edges`], the same.
    edges: usize,
}

#[cfg(target_arch = "x86_64")]
impl KernelOut {
    /// The view of `out` as it stands.
    fn of(out: &mut GroupOut) -> Self {
        debug_assert!(out.a.len() == out.b.len() && out.a.len() == out.end.len());
        KernelOut {
            opp: out.opp,
            a: out.a.as_mut_ptr(),
            b: out.b.as_mut_ptr(),
            end: out.end.as_mut_ptr(),
            len: out.a.len(),
            base: out.base,
            room: out.room,
            records: out.records,
            edges: out.edges,
        }
    }
}

/// Pass 1 for one chunk of triangles: per range, its listings (high 32
/// bits) and records (low 32 bits), and with `parity` the xor of the keys
/// of its triangles' edges (see the pass in [`build_edges_in`]); the
/// kernel `simd` names ([`count_avx512`], 16 triangles a block, or
/// `count_avx2::count_avx2`, 8) takes the whole blocks, the scalar loop the
/// rest.
fn count_chunk(tris: &[u32], ranges: usize, simd: Simd, parity: bool) -> (Vec<u64>, u64) {
    // Lanes of counters, triangle i's in lane i % COUNT_LANES, each lane
    // two planes of its own (lo, then mid), summed after the loop: a
    // triangle's lo and mid, and consecutive triangles, mostly fall in one
    // range, and each add to a counter waits for the one before. A single
    // plane for all: 2.7–3.2 against 2.1–2.2 ms with four planes (two
    // lanes) on the dragon, 26 against 15 ms on the 5M scene; the four
    // planes' counters of a range side by side: 24 ms on the scene (one
    // thread, `stage_probe -- passes` on local edits, benches/ROUNDS.md
    // "Twenty-first round", where the planes are called lanes). How many
    // lanes: see `COUNT_LANES`.
    let mut lanes = vec![0u64; 2 * COUNT_LANES * ranges];
    let mut odd = 0u64;
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `Simd::Avx512` is set only where the CPU has AVX-512F and
    // AVX-512DQ, `Simd::Avx2` only where it has AVX2 (`simd_level`).
    let done = unsafe {
        match (simd, parity) {
            (Simd::Avx512, false) => count_avx512::<false>(tris, &mut lanes, ranges, &mut odd),
            (Simd::Avx512, true) => count_avx512::<true>(tris, &mut lanes, ranges, &mut odd),
            (Simd::Avx2, false) => {
                count_avx2::count_avx2::<false>(tris, &mut lanes, ranges, &mut odd)
            }
            (Simd::Avx2, true) => {
                count_avx2::count_avx2::<true>(tris, &mut lanes, ranges, &mut odd)
            }
            (Simd::Plain, _) => 0,
        }
    };
    #[cfg(not(target_arch = "x86_64"))]
    let done = {
        let _ = simd;
        0
    };
    for (i, t) in tris.chunks_exact(3).enumerate().skip(done) {
        crate::hint::prefetch_stream(tris.as_ptr().wrapping_add(3 * i));
        let (lo, mid, hi) = sort3(t);
        if parity {
            let key = |a: u32, b: u32| ((u64::from(a) << 32) | u64::from(b)).wrapping_mul(EDGE_KEY);
            odd ^= key(lo, mid) ^ key(lo, hi) ^ key(mid, hi);
        }
        let range = |v: u32| (v >> RANGE_SHIFT) as usize;
        count_triangle(&mut lanes, ranges, i % COUNT_LANES, range(lo), range(mid));
    }
    let count = (0..ranges)
        .map(|r| (0..2 * COUNT_LANES).map(|l| lanes[l * ranges + r]).sum())
        .collect();
    (count, odd)
}

/// Pass 1's counts (the loop in [`build_edges_in`]) for the whole blocks
/// of 16 triangles in `tris`, into the same [`COUNT_LANES`] lanes of
/// counters, and with `PARITY` the xor of their edges' keys into `odd`;
/// returns the number of triangles counted.
///
/// Each block is three loads; two permutes of each pair of registers take
/// out every triangle's first, second and third corner
/// (`evaluate_simd::TriangleCorners16`, as the caps' kernel does), and each
/// triangle's smallest and middle corner (as in [`sort3`]) and their
/// ranges come from a min, a max and xors on 16 triangles at once. The
/// counters' adds stay scalar. Why: the scalar loop spent most of its
/// instructions loading and ordering corners one triangle at a time. One
/// thread, the count pass 1.90–1.91 → 1.39–1.43 ms on the dragon and
/// 11.03–11.05 → 8.10–8.50 ms on the 5M scene (`RECYCLE=1 cargo run
/// --release --example stage_probe -- passes`, three and two
/// alternations). The same front end for pass 2 (the listings'
/// entries made 16 at a time, their appends scalar) was slower: 3.05–3.22
/// against 2.88–2.89 ms, its appends to the ranges' streams being what it
/// waits on.
///
/// A block's ranges are stored as the block is read, and its adds run one
/// block later. Why: without the adds the kernel took 0.17 ms on the
/// dragon, with them 1.53 ms (a scratch probe, fastest of 30), and their 32
/// scalar loads of the ranges came right after the two 64-byte stores that
/// hold them; a block later those stores are done. (That the loads waited
/// on the stores is our reading: fewer adds or other counters did not
/// explain the time, the same adds into 16 lanes taking 1.30–1.40 ms, and
/// one add for a triangle whose lo and mid share a range 1.46 ms.) The
/// count pass, one thread, with [`COUNT_LANES`] = 4: 1.39–1.41 → 1.06–1.13
/// ms on the dragon (`RECYCLE=1 cargo run --release --example stage_probe
/// -- passes target/dragon/dragon.glb`, three alternations; two threads
/// 0.73–0.76 → 0.56–0.59 ms) and 8.20–8.23 → 6.04–6.08 ms on the 5M scene
/// (two).
///
/// The parity of a fed build (see the pass) is the same xor of the same
/// keys, 8 triangles' keys at a time in 64-bit lanes (`vpmullq`), folded
/// into one word at the end: the order of xors does not change the
/// result. Until the thirty-fifth round a fed build counted in the scalar
/// loop. The fed topology on the dragon (`build_edges_opposites_only_fed`
/// with a consumer that reads nothing, fastest of 15, memory kept; a
/// scratch probe with the scalar loop forced by a local switch, now the
/// second line of `RECYCLE=1 cargo run --release --example stage_probe --
/// passes target/dragon/dragon.glb`): one thread 13.42–13.50 →
/// 11.81–11.95 ms, two threads 10.50–10.56 → 9.71–9.99 ms (three
/// alternations each).
///
/// # Safety
/// The CPU must have AVX-512F and AVX-512DQ.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512dq")]
unsafe fn count_avx512<const PARITY: bool>(
    tris: &[u32],
    lanes: &mut [u64],
    ranges: usize,
    odd: &mut u64,
) -> usize {
    use std::arch::x86_64::*;
    let blocks = tris.len() / 48;
    let mut parity = _mm512_setzero_si512();
    let factor = _mm512_set1_epi64(EDGE_KEY as i64);
    let corners = crate::evaluate_simd::TriangleCorners16::new();
    // Block b's ranges (16 lo, then 16 mid) in `held[b % 2]`.
    let mut held = [[0u32; 32]; 2];
    for b in 0..=blocks {
        if b < blocks {
            // SAFETY: block b's 48 words lie inside `tris`.
            let w = unsafe {
                let at = tris.as_ptr().add(48 * b);
                crate::hint::prefetch_stream(at);
                [0, 16, 32].map(|k| _mm512_loadu_si512(at.add(k).cast()))
            };
            let [x, y, z] = [0, 1, 2].map(|c| corners.corner(&w, c));
            let lo = _mm512_min_epu32(x, _mm512_min_epu32(y, z));
            let hi = _mm512_max_epu32(x, _mm512_max_epu32(y, z));
            let mid = _mm512_xor_si512(
                _mm512_xor_si512(x, y),
                _mm512_xor_si512(z, _mm512_xor_si512(lo, hi)),
            );
            if PARITY {
                let key = |a: __m256i, b: __m256i| {
                    let (a, b) = (_mm512_cvtepu32_epi64(a), _mm512_cvtepu32_epi64(b));
                    _mm512_mullo_epi64(_mm512_or_si512(_mm512_slli_epi64::<32>(a), b), factor)
                };
                let halves =
                    |v: __m512i| (_mm512_castsi512_si256(v), _mm512_extracti64x4_epi64::<1>(v));
                let ((l0, l1), (m0, m1), (u0, u1)) = (halves(lo), halves(mid), halves(hi));
                for (l, m, u) in [(l0, m0, u0), (l1, m1, u1)] {
                    let keys = _mm512_xor_si512(key(l, u), key(m, u));
                    parity = _mm512_ternarylogic_epi64::<0x96>(parity, key(l, m), keys);
                }
            }
            let slot = &mut held[b % 2];
            // SAFETY: 32 u32, 16 for each store.
            unsafe {
                _mm512_storeu_si512(
                    slot.as_mut_ptr().cast(),
                    _mm512_srli_epi32::<RANGE_SHIFT>(lo),
                );
                _mm512_storeu_si512(
                    slot.as_mut_ptr().add(16).cast(),
                    _mm512_srli_epi32::<RANGE_SHIFT>(mid),
                );
            }
        }
        if b > 0 {
            let slot = &held[(b - 1) % 2];
            for j in 0..16 {
                // A block starts at a multiple of 16, so `j % COUNT_LANES`
                // is the triangle's lane in the scalar loop's numbering too.
                let (l, m) = (slot[j] as usize, slot[16 + j] as usize);
                count_triangle(lanes, ranges, j % COUNT_LANES, l, m);
            }
        }
    }
    if PARITY {
        let mut words = [0u64; 8];
        // SAFETY: 8 u64.
        unsafe { _mm512_storeu_si512(words.as_mut_ptr().cast(), parity) };
        *odd ^= words.iter().fold(0, |x, &w| x ^ w);
    }
    16 * blocks
}

/// The odd constant a fed build's pass 1 multiplies each edge `(a, b)`,
/// as the word `a << 32 | b`, by (a bijection of the words) before it
/// xors them (see the pass).
const EDGE_KEY: u64 = 0x9e37_79b9_7f4a_7c15;

/// Lanes of pass 1's counters: a triangle's counts go to lane `i %
/// COUNT_LANES` (`i` its index in its chunk), so that consecutive
/// triangles, whose corners mostly fall in the same ranges, add to
/// different counters. With the adds a block after the ranges
/// ([`count_avx512`]), the count pass on the dragon took 1.06–1.10 ms with
/// 2 lanes, 1.05–1.08 with 4, 1.14–1.40 with 8 and 1.34–1.62 with 16 (more
/// counters in more lines of the first-level cache, is our reading), and
/// on the 5M scene 6.22–6.32 ms with 2 and 6.06–6.08 with 4 (one thread,
/// `RECYCLE=1 cargo run --release --example stage_probe -- passes`, local
/// edits, three and two runs). Until the thirty-fifth round there were 2,
/// and 4 without the delay measured no faster (benches/ROUNDS.md,
/// Thirty-fourth round, where each plane is called a lane).
const COUNT_LANES: usize = 4;

/// Pass 1's count of a triangle in lane `lane`, whose smallest and middle
/// corners fall in ranges `lo` and `mid`, into `lanes` (two planes of
/// `ranges` counters per lane: lo, then mid). Per range, listings in the
/// high half and records in the low half: one add for both (2 records
/// under lo, 1 under mid). All chunks together have fewer than 2^32
/// records (asserted in [`build_edges_in`]), so the low halves never
/// carry, even summed over chunks and lanes.
#[inline(always)]
fn count_triangle(lanes: &mut [u64], ranges: usize, lane: usize, lo: usize, mid: usize) {
    let plane = 2 * lane * ranges;
    lanes[plane + lo] += (1 << 32) | 2;
    lanes[plane + ranges + mid] += (1 << 32) | 1;
}

/// A triangle's corners in increasing id order (no repeated ids): the
/// smallest, the middle one, the largest, without branches.
#[inline(always)]
fn sort3(t: &[u32]) -> (u32, u32, u32) {
    let (a, b, c) = (t[0], t[1], t[2]);
    let lo = a.min(b).min(c);
    let hi = a.max(b).max(c);
    (lo, a ^ b ^ c ^ lo ^ hi, hi)
}

/// What debug builds fill uninitialised buffers with, to check that every
/// slot is written: no vertex, triangle or record index is `u32::MAX`.
const UNWRITTEN: u32 = u32::MAX;
/// Longest run of records [`sort_small`] sorts.
const SMALL_RUN: usize = 8;

/// The order of the first `m` records of `src` by larger endpoint (`r[1]`),
/// stably: entry `j < m` is the `j`-th record's key (larger endpoint, in
/// the high 32 bits) and index in `src` (the low bits); entries `m` and
/// beyond are `u64::MAX`, whose key (`u32::MAX`) no vertex id reaches, so
/// the entry after a run's last record always has another key.
///
/// Method: the keys with their indices below them, so that all are
/// distinct and equal endpoints keep their order, go through a fixed
/// sorting network for 8 inputs (19 compare-exchanges, each a `min` and a
/// `max`; padded with `u64::MAX`). Why: no data-dependent branch, and a
/// third of the work of ranking (which compared every pair, 64 compares,
/// and then moved the 16-byte records into place): the topology's emit
/// pass went from 18.4–18.6 to 14.6–14.8 ms on the dragon and from 121 to
/// 70 ms on the 5M-triangle scene, one thread (a local copy of this file
/// with timers per pass, not kept); the whole topology step from 32.9–33.6
/// to 28.4–29.2 ms on the dragon (`cargo run --release --example
/// stage_probe -- build target/dragon/dragon.glb`, one thread, both
/// versions alternated). A 16-input network (63 compare-
/// exchanges) for the 6% of the dragon's vertices with more records gained
/// nothing over the standard sort.
#[inline(always)]
fn sort_small(src: &[[u32; 4]; SMALL_RUN], m: usize) -> [u64; SMALL_RUN + 1] {
    let mut k: [u64; SMALL_RUN + 1] = std::array::from_fn(|i| {
        if i < m {
            (u64::from(src[i][1]) << 32) | i as u64
        } else {
            u64::MAX
        }
    });
    let mut ce = |a: usize, b: usize| {
        let (x, y) = (k[a], k[b]);
        k[a] = x.min(y);
        k[b] = x.max(y);
    };
    for layer in NETWORK8 {
        for &(a, b) in layer {
            ce(a, b);
        }
    }
    k
}

/// An optimal sorting network for 8 inputs (19 compare-exchanges, depth 6),
/// layer by layer: the pairs of a layer are disjoint. [`sort_small`] runs
/// it on scalars (`emit_range_avx512` has a network of its own).
const NETWORK8: [&[(usize, usize)]; 6] = [
    &[(0, 2), (1, 3), (4, 6), (5, 7)],
    &[(0, 4), (1, 5), (2, 6), (3, 7)],
    &[(0, 1), (2, 3), (4, 5), (6, 7)],
    &[(2, 4), (3, 5)],
    &[(1, 4), (3, 6)],
    &[(1, 2), (3, 4), (5, 6)],
];

/// log2 of the vertices per range of [`build_edges`]: enough ranges for
/// the threads to share, few enough that pass 2 writes few streams at once,
/// and small enough that a range's listings and slots stay in L2 while
/// pass 3 sorts and emits them.
///
/// 2,048 since the sixty-second round, on this AMD EPYC (Zen 3, 512 KiB
/// of L2), with the sort's blocks (`slots::take`): one thread, `RECYCLE=1
/// RAYON_NUM_THREADS=1 cargo run --release --example stage_probe --
/// passes FILE`, the topology, fastest / median of three alternations
/// against 8,192: the dragon 14.87 / 14.89 against 15.41 / 15.61 ms (the
/// emit 9.84 against 10.17 ms at the fastest, the list pass 3.72 against
/// 3.88), the 5M scene 78.95 / 80.65 against 85.02 / 85.33 ms (the emit
/// 48.85 against 51.56, the list pass 22.96 against 23.97). With 4,096
/// the 5M scene took 82.14–86.63 ms, with 1,024 the dragon's list pass
/// 4.46–4.80 ms. Before the blocks 8,192 had been best: an earlier
/// round's list pass with 4,096 vertices per range took 37 ms on the 5M
/// scene, with 16,384 30 ms, with 8,192 32 ms, and the dragon's 5.0, 4.7
/// and 4.0–4.6 ms; the sixtieth round (on the Intel Xeon) and the
/// sixty-first (on this host) measured 4,096 again and dropped it.
const RANGE_SHIFT: u32 = 11;
/// Vertices per range.
const RANGE: usize = 1 << RANGE_SHIFT;
/// How many listings ahead of a range's next slot pass 2 asks for that
/// line (with every listing; 16 listings, two or three cache lines). The
/// pass appends to every range at once, 53 streams on the dragon and 314
/// on the 5M scene, more than the hardware's prefetchers follow, so its
/// stores waited for their lines. A read prefetch is enough: the line
/// comes in exclusive when no other core holds it, and the store finds it
/// so (`_MM_HINT_ET0` compiles to the same `prefetcht0` without the
/// `prfchw` target feature). One thread, `RECYCLE=1 cargo run --release
/// --example stage_probe -- passes`, the list pass's median of four
/// alternations: the 5M scene 36.2 → 33.6 ms (8 or 32 listings ahead:
/// 33.7, 34.1; in a second run, c423f54 against its parent, 34.8 → 32.7
/// ms), the dragon, whose 53 streams the caches mostly hold, 6.25 → 6.16
/// ms (noise).
const LIST_AHEAD: usize = 16;
/// Below this many triangles the count and list passes run as one chunk:
/// a chunk costs a count array over all vertices.
const PARALLEL_MIN: usize = 1 << 16;
/// At most this many chunks (each costs 4 bytes per vertex).
const MAX_CHUNKS: usize = 8;

/// Edge statistics for summaries.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EdgeStats {
    /// Number of edges.
    pub edges: u64,
    /// Edges with exactly one opposite vertex (boundary).
    pub open_edges: u64,
    /// Edges with more than two opposite vertices.
    pub non_manifold_edges: u64,
    /// Largest opposite-vertex count.
    pub max_fan: u32,
    /// `(n, edges with n opposite vertices)`, increasing n, only nonzero counts.
    pub histogram: Vec<(u32, u64)>,
}

/// Computes [`EdgeStats`].
///
/// The histogram is counted per block of edges in parallel and the blocks'
/// counts summed, so it does not depend on the number of threads.
pub fn edge_stats(edges: &Edges) -> EdgeStats {
    use rayon::prelude::*;
    // Blocks overlap by one start, so every edge is in exactly one block.
    let starts = &edges.opp_start;
    let blocks = edges.len().div_ceil(STATS_BLOCK);
    let hist = (0..blocks)
        .into_par_iter()
        .map(|k| {
            let end = ((k + 1) * STATS_BLOCK).min(edges.len());
            fan_histogram(&starts[k * STATS_BLOCK..=end])
        })
        .reduce(Vec::new, |mut a, b| {
            add_histogram(&mut a, &b);
            a
        });
    EdgeStats::from_histogram(&hist)
}

/// Adds the fan histogram `h` to `sum` (either may be the longer), as
/// [`edge_stats`] and `layout::Plan` sum their blocks' histograms.
pub(crate) fn add_histogram(sum: &mut Vec<u64>, h: &[u64]) {
    if sum.len() < h.len() {
        sum.resize(h.len(), 0);
    }
    sum.iter_mut().zip(h).for_each(|(s, h)| *s += h);
}

impl EdgeStats {
    /// The statistics of edges whose opposite-vertex counts have the
    /// histogram `hist` (`hist[n]` edges with n opposite vertices), as
    /// `fan_histogram` counts them: how a build gets them from the
    /// layout's plan, which counts the same histogram per block.
    pub fn from_histogram(hist: &[u64]) -> EdgeStats {
        let histogram: Vec<(u32, u64)> = hist
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .map(|(n, &c)| (n as u32, c))
            .collect();
        EdgeStats {
            edges: hist.iter().sum(),
            open_edges: hist.get(1).copied().unwrap_or(0),
            non_manifold_edges: hist.iter().skip(3).sum(),
            max_fan: histogram.last().map(|h| h.0).unwrap_or(0),
            histogram,
        }
    }
}

/// Edges per block of [`edge_stats`].
const STATS_BLOCK: usize = 1 << 16;

/// `hist[n]` = edges with `n` opposite vertices, for the edges whose ranges
/// `starts` bounds (one start more than edges, fewer than 2^32 edges).
/// Also the layout's counting pass (`layout::Plan::new`).
///
/// Fans of one and two (almost every edge of a real mesh) are summed as
/// comparisons in u32 lanes, which vectorise, a chunk of [`FAN_CHUNK`] edges
/// at a time; only a chunk holding another fan is walked again, with a
/// branch per edge, while it is in the first-level cache. Why: incrementing
/// `hist[n]` for every edge took 2.7–3.4 ms for the dragon's 1.3M edges
/// (each increment waits on the previous one to the same counter, through
/// memory), and so did the same sums in u64, which did not vectorise; u32
/// sums take 0.7–0.9 ms (one thread, the stats called a second time on the
/// same edges; local timers, not kept).
///
/// Until the sixty-third round the walk was of the whole block. The 5M
/// scene's non-manifold edges (4,598 of 7.5M) are in 228 of its 230
/// blocks of `layout::BLOCK`, so its plan walked nearly every edge: `Plan::new`
/// over the scene's edges 7.0–7.9 ms, now 3.0–3.2 ms, against 1.7–2.1 ms
/// to read `starts` once (one thread, a local probe, fastest of 30, six
/// alternations; the dragon's, which has no such fans, 0.28–0.55 against
/// 0.30–0.53 ms; on the scene, chunks of 64 edges 2.9–3.2 ms, of 1,024
/// 4.5–4.7 ms, and the sums over the whole block with a second, vectorised
/// reading to find the chunks 4.0–4.3 ms, three alternations).
/// `RAYON_NUM_THREADS=1 cargo run --release --example stage_probe -- build
/// target/targets/scene_5000000.obj`, its `plan`: 7.24–11.96 → 2.98–5.32
/// ms (three alternations); the dragon's 0.30–0.52 → 0.48–0.53 ms, within
/// that probe's noise.
pub(crate) fn fan_histogram(starts: &[u32]) -> Vec<u64> {
    let mut hist = vec![0u64; 3];
    let fans = starts.len().saturating_sub(1);
    // u32 counts: callers pass blocks of at most 2^16 edges.
    let (mut one, mut two) = (0u32, 0u32);
    for first in (0..fans).step_by(FAN_CHUNK) {
        let chunk = &starts[first..=(first + FAN_CHUNK).min(fans)];
        let (mut o, mut t, mut rare) = (0u32, 0u32, 0u32);
        for (&s, &e) in chunk.iter().zip(&chunk[1..]) {
            let n = e.wrapping_sub(s);
            o += u32::from(n == 1);
            t += u32::from(n == 2);
            rare += u32::from(n.wrapping_sub(1) >= 2);
        }
        (one, two) = (one + o, two + t);
        if rare != 0 {
            for (&s, &e) in chunk.iter().zip(&chunk[1..]) {
                let n = (e - s) as usize;
                // Zero and more than two.
                if n.wrapping_sub(1) >= 2 {
                    if n >= hist.len() {
                        hist.resize(n + 1, 0);
                    }
                    hist[n] += 1;
                }
            }
        }
    }
    hist[1] += u64::from(one);
    hist[2] += u64::from(two);
    hist
}

/// Edges per chunk of [`fan_histogram`]: the unit its rare fans are walked
/// again in.
const FAN_CHUNK: usize = 256;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tetrahedron_is_closed() {
        let tris = [0, 1, 2, 0, 3, 1, 1, 3, 2, 2, 3, 0];
        let e = build_edges(&tris, 4);
        assert_eq!(e.len(), 6);
        assert!((0..6).all(|i| e.fan(i) == 2));
        assert!(e.a.iter().zip(&e.b).all(|(a, b)| a < b));
        // Sorted by (a, b).
        let keys: Vec<(u32, u32)> = e.a.iter().copied().zip(e.b.iter().copied()).collect();
        let mut sorted = keys.clone();
        sorted.sort();
        assert_eq!(keys, sorted);
    }

    /// No triangles: no edges, over no vertices or some, from every entry
    /// point (and no part for pass 2's check in debug builds).
    #[test]
    fn no_triangles_make_no_edges() {
        for vertices in [0, 5] {
            let e = build_edges(&[], vertices);
            assert_eq!((e.len(), e.opp.len(), e.opp_start.len()), (0, 0, 1));
            let e = build_edges_opposites_only(&[], vertices);
            assert_eq!((e.len(), e.opp.len()), (0, 0));
        }
    }

    /// The obvious implementation: a sorted map from (smaller, larger)
    /// endpoint to the (opposite, triangle) pairs in triangle order.
    fn naive(tris: &[u32]) -> Edges {
        let mut map: std::collections::BTreeMap<(u32, u32), Vec<(u32, u32)>> = Default::default();
        for (t, c) in tris.chunks_exact(3).enumerate() {
            for k in 0..3 {
                let (u, v, w) = (c[k], c[(k + 1) % 3], c[(k + 2) % 3]);
                map.entry((u.min(v), u.max(v)))
                    .or_default()
                    .push((w, t as u32));
            }
        }
        let mut e = Edges {
            opp_start: vec![0],
            ..Edges::default()
        };
        for ((a, b), opps) in map {
            e.a.push(a);
            e.b.push(b);
            for (o, t) in opps {
                e.opp.push(o);
                e.opp_tri.push(t);
            }
            e.opp_start.push(e.opp.len() as u32);
        }
        e
    }

    /// Panics unless `got == want`, naming the first array and index that
    /// differ (the arrays have hundreds of thousands of entries; printing
    /// them whole buried the answer).
    fn same_edges(got: &Edges, want: &Edges, what: &str) {
        let arrays = [
            ("a", &got.a, &want.a),
            ("b", &got.b, &want.b),
            ("opp_start", &got.opp_start, &want.opp_start),
            ("opp", &got.opp, &want.opp),
            ("opp_tri", &got.opp_tri, &want.opp_tri),
        ];
        for (name, g, w) in arrays {
            if let Some(i) = (0..g.len().min(w.len())).find(|&i| g[i] != w[i]) {
                panic!("{what}: {name}[{i}] is {}, expected {}", g[i], w[i]);
            }
            assert_eq!(g.len(), w.len(), "{what}: length of {name}");
        }
    }

    /// `triangles` random triangles over a strip of `vertices` vertices,
    /// each on three vertices a few ids apart, so that edges repeat (open,
    /// manifold and non-manifold edges, duplicates in both windings), in
    /// every corner order.
    fn strip_soup(vertices: usize, triangles: usize, seed: u64) -> Vec<u32> {
        let mut bits = crate::multiplicity::test_bits(seed);
        let mut rng = move || bits() >> 11;
        let mut tris = Vec::with_capacity(3 * triangles);
        while tris.len() < 3 * triangles {
            let a = (rng() % vertices as u64) as u32;
            let b = (a + 1 + (rng() % 3) as u32) % vertices as u32;
            let c = (a + 2 + (rng() % 5) as u32) % vertices as u32;
            if a != b && b != c && a != c {
                tris.extend_from_slice(&[a, b, c]);
            }
        }
        tris
    }

    #[test]
    fn count_kernel_counts_and_xors_as_the_scalar_loop() {
        // Pass 1 with each kernel the CPU has (AVX-512, AVX2) on the
        // whole blocks against the scalar loop on every triangle: the
        // same counts per range, and the same
        // xor of the edges' keys, exactly; and that xor is 0 on a soup
        // whose every edge has two triangles (each triangle twice). Sizes
        // with and without a tail after the last block, over one range
        // and several. Caught: the keys' xor without the (lo, mid) edge's
        // (a soup with each triangle twice still gives 0 then), and each
        // block's adds read from the block's own slot instead of the one
        // before.
        for (simd, (vertices, triangles, seed)) in kernels().into_iter().flat_map(|k| {
            [
                (5 * RANGE + 11, 16 * 700 + 9, 0x9e37_79b9),
                (300, 16 * 40, 0x2545_f491),
                (RANGE / 2, 15, 0x1234_5678),
            ]
            .map(|c| (k, c))
        }) {
            let soup = strip_soup(vertices, triangles, seed);
            let twice: Vec<u32> = soup
                .chunks_exact(3)
                .flat_map(|t| [t[0], t[1], t[2], t[1], t[0], t[2]])
                .collect();
            let ranges = vertices.div_ceil(RANGE);
            for tris in [&soup, &twice] {
                let (want, want_odd) = count_chunk(tris, ranges, Simd::Plain, true);
                for parity in [false, true] {
                    let (got, odd) = count_chunk(tris, ranges, simd, parity);
                    assert!(got == want, "{simd:?}, {vertices} vertices: counts");
                    assert_eq!(
                        odd,
                        if parity { want_odd } else { 0 },
                        "{simd:?}, {vertices}: xor"
                    );
                }
            }
            let (_, odd) = count_chunk(&twice, ranges, simd, true);
            assert_eq!(odd, 0, "{vertices} vertices: every edge twice");
            let (_, odd) = count_chunk(&soup, ranges, simd, true);
            assert_ne!(odd, 0, "{vertices} vertices: open edges");
        }
    }

    #[test]
    fn matches_the_obvious_implementation_across_ranges_and_chunks() {
        // Several vertex ranges; triangles over a random strip of vertices
        // so edges repeat (open, manifold and non-manifold edges,
        // duplicates in both windings), in every corner order, plus a
        // vertex with a large fan straddling the block-sort limit and one
        // on a range boundary. Cut into 1 to 5 chunks, with listings of
        // both widths, and through the public entry point with 1 to 4
        // threads (its chunks and groups). Caught, among others: each
        // chunk listing from its range's start (the earlier chunks'
        // listings not skipped) and a range's counts one place off in
        // `sort_range`.
        // (At least 24,653 vertices whatever the ranges' size: the strip
        // must be sparse enough that some vertices have few listings.)
        let vertices = (3 * RANGE + 77).max(24_653);
        let mut tris = strip_soup(vertices, PARALLEL_MIN + 5000, 0x9e37_79b9_7f4a_7c15);
        for i in 0..100u32 {
            tris.extend_from_slice(&[RANGE as u32, RANGE as u32 + 1 + i % 50, 5 + i]);
            tris.extend_from_slice(&[7 + i % 9, RANGE as u32 - 1, 2 * RANGE as u32 + i]);
        }
        // The AVX-512 kernel's cases all occur (by listings and records per
        // vertex): at most 8 records (class 1), 9 to 16 (two registers,
        // class 2), and more than 8 listings (the scalar path, class 3).
        let mut per_vertex = vec![(0u32, 0u32); vertices];
        for t in tris.chunks_exact(3) {
            let (lo, mid, _) = sort3(t);
            per_vertex[lo as usize].0 += 1;
            per_vertex[lo as usize].1 += 2;
            per_vertex[mid as usize].0 += 1;
            per_vertex[mid as usize].1 += 1;
        }
        let class = |&(l, k): &(u32, u32)| match (l, k) {
            (0, _) => 0,
            (..=8, ..=8) => 1,
            (..=8, _) => 2,
            _ => 3,
        };
        for c in 1..=3 {
            assert!(
                per_vertex.iter().any(|v| class(v) == c),
                "no vertex of class {c}"
            );
        }
        let expected = naive(&tris);
        let without_tri = Edges {
            opp_tri: Vec::new(),
            ..expected.clone()
        };
        // Both listing widths: packed (8 bytes) and, as over 2^26 vertices,
        // 12 bytes.
        for (chunks, wide) in (1..=5).flat_map(|c| [(c, false), (c, true)]) {
            same_edges(
                &build_edges_in::<true>(
                    (&tris[..]).into(),
                    vertices,
                    chunks,
                    Simd::Plain,
                    wide,
                    None,
                    None,
                )
                .0,
                &expected,
                &format!("{chunks} chunks, wide {wide}"),
            );
            for simd in simd_levels() {
                same_edges(
                    &build_edges_in::<false>(
                        (&tris[..]).into(),
                        vertices,
                        chunks,
                        simd,
                        wide,
                        None,
                        None,
                    )
                    .0,
                    &without_tri,
                    &format!("{chunks} chunks, opposites only, {simd:?}, wide {wide}"),
                );
            }
        }
        // The public entry point cuts chunks and groups by thread count.
        for threads in 1..=4 {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let got = pool.install(|| build_edges(&tris, vertices));
            same_edges(&got, &expected, &format!("{threads} threads"));
            let got = pool.install(|| build_edges_opposites_only(&tris, vertices));
            same_edges(
                &got,
                &without_tri,
                &format!("{threads} threads, opposites only"),
            );
            let got = pool.install(|| build_edges_opposites_only_owned(tris.clone(), vertices));
            same_edges(
                &got,
                &without_tri,
                &format!("{threads} threads, opposites only, owned"),
            );
        }
        same_edges(
            &build_edges(&tris[..3000], vertices),
            &naive(&tris[..3000]),
            "3000 triangles",
        );
        assert_eq!(build_edges(&[], 0), naive(&[]));
        assert_eq!(build_edges_opposites_only(&[], 5), naive(&[]));
        assert_eq!(
            build_edges_in::<true>(
                (&tris[..3]).into(),
                vertices,
                4,
                Simd::Plain,
                false,
                None,
                None
            )
            .0,
            naive(&tris[..3])
        );
    }

    /// Every [`Simd`] this CPU runs, `Plain` first.
    fn simd_levels() -> Vec<Simd> {
        let mut levels = vec![Simd::Plain];
        #[cfg(target_arch = "x86_64")]
        if avx2_kernels_run() {
            levels.push(Simd::Avx2);
        }
        if simd_level() == Simd::Avx512 {
            levels.push(Simd::Avx512);
        }
        levels
    }

    /// The emit kernels this CPU runs (every [`Simd`] but `Plain`).
    fn kernels() -> Vec<Simd> {
        simd_levels().split_off(1)
    }

    /// Pass 3 on triangles over the given vertex ids alone, by the kernel
    /// `simd` names (`Plain`: the scalar emit): the opposite vertices and
    /// the edges (a, b, end of its opposite vertices) it writes.
    fn emit_alone(tris: &[u32], simd: Simd) -> (Vec<u32>, Vec<[u32; 3]>) {
        let ids = tris.iter().copied();
        let (first, last) = (ids.clone().min().unwrap(), ids.max().unwrap());
        let mut under = vec![Vec::new(); (last - first + 1) as usize];
        for t in tris.chunks_exact(3) {
            let (lo, mid, hi) = sort3(t);
            under[(lo - first) as usize].push([mid, hi]);
            under[(mid - first) as usize].push([hi, lo]);
        }
        // The layout `sort_range` makes: each vertex's first listings in
        // its slots, the rest spilled, by vertex. The slots past a
        // vertex's listings hold what an earlier range left there: here a
        // listing of other vertices, which would give records if read.
        let mut fill = Vec::new();
        let mut pairs = vec![[first + 1, first + 2]; under.len() * SLOTS];
        let mut spill = Vec::new();
        for (p, l) in under.iter().enumerate() {
            fill.push(l.len() as u32);
            for (c, &pair) in l.iter().enumerate() {
                if c < SLOTS {
                    pairs[p * SLOTS + c] = pair;
                } else {
                    spill.push((p as u32, pair, 0));
                }
            }
        }
        let n = tris.len(); // (3 records per triangle at most)
        // (With a guard of 8 slots past the room the emit is given.)
        let mut opp = vec![UNWRITTEN; n + 8];
        let mut arrays = vec![vec![MaybeUninit::new(UNWRITTEN); n]; 3];
        let [a, b, end] = &mut arrays[..] else {
            unreachable!()
        };
        let out = GroupOut {
            opp: opp.as_mut_ptr(),
            tri: &mut [],
            a,
            b,
            end,
            base: 0,
            // No room past the records (exactly 3 per triangle): the
            // kernels' stores near the end must stop at them.
            room: n,
            records: 0,
            edges: 0,
        };
        let listings = Listings {
            fill: &fill,
            first: first as usize,
            pairs: &pairs,
            tri: &[],
            spill: &spill,
            narrow: true,
        };
        let mut buf = EmitBuf::default();
        let vertices = first as usize..last as usize + 1;
        let (records, edges) = emit_group::<false>(out, &listings, vertices, &mut buf, simd);
        assert!(
            opp[n..].iter().all(|&o| o == UNWRITTEN),
            "{simd:?}: a store past the room"
        );
        opp.truncate(records);
        // SAFETY: the emit wrote the first `edges` slots of each.
        let edge = |i: usize| std::array::from_fn(|x| unsafe { arrays[x][i].assume_init() });
        (opp, (0..edges).map(edge).collect())
    }

    /// The AVX-512 emit's path for two vertices at once (one in each half
    /// of a register) ends each vertex's edges at its own last record,
    /// even when its last larger endpoint is the next vertex's first (the
    /// pairs of other listing counts: the next test). Caught: the first
    /// vertex's last lane compared with the second vertex's first key
    /// (with 8 records, its last edge then ran on into the next vertex's).
    #[test]
    fn paired_vertices_end_their_own_edges() {
        // Vertex 0 is the smallest corner of 4 triangles (8 records, the
        // last on vertex 9); vertex 1 of one, on 9 and 10.
        let tris = [0, 2, 3, 0, 4, 5, 0, 6, 7, 0, 8, 9, 1, 9, 10];
        for simd in kernels() {
            let (opp, edges) = emit_alone(&tris, simd);
            assert_eq!(edges.iter().filter(|e| e[0] == 0).count(), 8, "{simd:?}");
            assert_eq!((opp, edges), emit_alone(&tris, Simd::Plain), "{simd:?}");
        }
    }

    /// The AVX-512 emit's pairs of vertices 0 and 1 give what the scalar
    /// emit gives for every mix of up to 4 listings of each kind, with
    /// larger endpoints shared between the two and both windings: those
    /// of at most 4 listings each, taken in place, and those of up to 8
    /// listings and 8 records (vertex 1 with 5 or 6, some of them as the
    /// middle corner above vertex 0), whose records are compressed into
    /// the halves first; also a vertex 1 of 10 records, which is not
    /// paired. Caught: the second vertex's records compressed by the
    /// first's mask; the first vertex's number of records taken for the
    /// second's; its edge ends counted from the pair's first record; the
    /// second vertex's ranks into the first vertex's opposite vertices.
    #[test]
    fn compressed_pairs_match_the_scalar_emit() {
        for (simd, middle) in kernels()
            .into_iter()
            .flat_map(|k| (0..=4u32).map(move |m| (k, m)))
        {
            for lower in 0..=4u32 {
                for own in 0..=4 - middle {
                    let mut tris = Vec::new();
                    // Vertex 1 as the middle corner above 0 (a listing of
                    // each), then as the smaller corner, both windings.
                    for i in 0..middle {
                        tris.extend_from_slice(&[0, 1, 20 + i]);
                    }
                    for j in 0..lower {
                        match j % 2 {
                            0 => tris.extend_from_slice(&[1, 9 - 2 * j, 30 + j]),
                            _ => tris.extend_from_slice(&[30 + j, 9 - 2 * j, 1]),
                        }
                    }
                    for i in 0..own {
                        tris.extend_from_slice(&[0, 3 + 2 * i, 2 + 2 * i]);
                    }
                    tris.extend_from_slice(&[2, 12, 13]);
                    assert_eq!(
                        emit_alone(&tris, simd),
                        emit_alone(&tris, Simd::Plain),
                        "{simd:?}: {middle} middle, {lower} lower and {own} of vertex 0's own"
                    );
                }
            }
        }
    }

    /// The AVX-512 emit's 32-bit keys hold every id below `KEY_IDS` − 1,
    /// the bound its callers keep to (`narrow`), and fail on the next one,
    /// whose larger endpoint is the padding's: vertices with 2 to 13
    /// records on the largest ids, in both windings, give what the scalar
    /// emit gives. Caught: `KEY_IDS` one larger than the kernel takes (the
    /// comparison below `KEY_IDS − 1` then fails).
    #[test]
    fn the_simd_emit_keys_hold_every_id_below_the_bound() {
        let fans = |top: u32| {
            let mut tris = Vec::new();
            for i in 0..7u32 {
                tris.extend_from_slice(&[top - 2, top - 3 - i, top]);
                tris.extend_from_slice(&[top - 3 - i, top - 1, top]);
            }
            // 12 records at top − 20, a third of them on the top id.
            for i in 0..6u32 {
                tris.extend_from_slice(&[top - 12 + i % 3, top - 20, top - i / 3]);
            }
            tris.extend_from_slice(&[top - 30, top - 20, top - 10]);
            tris
        };
        let tris = fans(KEY_IDS as u32 - 2);
        let records = |v: u32| {
            tris.chunks_exact(3).map(move |t| match sort3(t) {
                (lo, ..) if lo == v => 2,
                (_, mid, _) if mid == v => 1,
                _ => 0,
            })
        };
        let most = (0..KEY_IDS as u32 - 1)
            .rev()
            .take(40)
            .map(|v| records(v).sum::<u32>());
        assert!((9..=16).contains(&most.max().unwrap()));
        let beyond = fans(KEY_IDS as u32 - 1);
        for simd in kernels() {
            let plain = emit_alone(&tris, Simd::Plain);
            assert_eq!(emit_alone(&tris, simd), plain, "{simd:?}");
            let plain = emit_alone(&beyond, Simd::Plain);
            assert_ne!(emit_alone(&beyond, simd), plain, "{simd:?}");
        }
        assert!(!Buckets::narrow_for(KEY_IDS) && Buckets::narrow_for(KEY_IDS - 1));
    }

    /// Packed listings hold the widest ids their vertex count needs, and
    /// wider counts get the 12-byte form. Caught: the place packed and read
    /// two bits lower, over the pair's top bit (`64 - RANGE_SHIFT - 2`),
    /// which no other test catches (their ids are narrow; the cases with
    /// one field's low bit set against the other's top bit clear were
    /// added for it), and packing allowed with one bit more than fits
    /// (`2 * bits + RANGE_SHIFT <= 65`); the pair taken by `pdep` as well,
    /// where the CPU has it.
    #[test]
    fn listings_pack_every_id_their_vertex_count_allows() {
        assert_eq!(packed_bits(0), Some(1));
        assert_eq!(packed_bits(2), Some(1));
        assert_eq!(packed_bits(3), Some(2));
        let widest = (64 - RANGE_SHIFT) / 2;
        assert_eq!(packed_bits(1 << widest), Some(widest));
        assert_eq!(packed_bits((1 << widest) + 1), None);
        for bits in 1..=widest {
            let top = (1u64 << bits) as u32 - 1;
            // Each field's top and bottom bits set against the others'
            // clear, and the other way round.
            let cases = [
                (top, top, 0),
                (0, top, 0),
                (1, 0, top),
                (0, 0, top),
                (top, top - 1, top),
                (RANGE as u32, 1, 0),
            ];
            for (v, p, q) in cases {
                let e = u64::new(v, p, q, bits);
                assert_eq!(e.place(), v as usize % RANGE, "bits {bits}, {v} {p} {q}");
                assert_eq!(e.pair(bits), [p, q], "bits {bits}, {v} {p} {q}");
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("bmi2") {
                    // SAFETY: checked just above.
                    let deposited = unsafe { e.pair_deposited(bits) };
                    assert_eq!(deposited, [p, q], "bits {bits}, {v} {p} {q}");
                }
                assert!(!e.unwritten());
            }
        }
        let e = <[u32; 3]>::new(u32::MAX - 1, u32::MAX - 2, 7, 0);
        assert_eq!(
            (e.place(), e.pair(0)),
            ((u32::MAX - 1) as usize % RANGE, [u32::MAX - 2, 7])
        );
    }

    /// A vertex count, a strip soup over it with some edges on an odd
    /// number of triangles, and the same with every triangle twice (the
    /// second reversed), so every fan even.
    fn odd_and_even_soups() -> (usize, Vec<u32>, Vec<u32>) {
        let vertices = 5 * RANGE + 11;
        let odd = strip_soup(vertices, 60_000, 0x2545_f491_4f6c_dd1d);
        let even = odd
            .chunks_exact(3)
            .flat_map(|t| [t[0], t[1], t[2], t[2], t[1], t[0]])
            .collect();
        (vertices, odd, even)
    }

    /// The fed emit (`build_edges_opposites_only_fed`): every prefix the
    /// consumer is handed, read while the rest is being made, is the final
    /// edges' prefix, and the edges are the unfed ones; a mesh with an edge
    /// on an odd number of triangles is not fed. Caught: publishing the
    /// count before a step's edges are written (`done` stored first, the
    /// snapshots then held unwritten entries), and the parity left out of
    /// pass 1 (the odd soup fed).
    #[test]
    fn fed_emit_hands_out_final_prefixes_and_only_for_even_fans() {
        let (vertices, odd, even) = odd_and_even_soups();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        for (tris, fed) in [(&even, true), (&odd, false)] {
            let want = build_edges_opposites_only(tris, vertices);
            let mut seen = Vec::new();
            let got = pool.install(|| {
                build_edges_opposites_only_fed(tris, vertices, &mut |feed: &EmitFeed| {
                    assert_eq!(feed.records(), want.opp.len());
                    let mut want_edges = 1;
                    loop {
                        let (done, ended) = feed.wait(want_edges, &|| false);
                        let e = feed.edges(done);
                        seen.push((
                            done,
                            e.a.to_vec(),
                            e.b.to_vec(),
                            e.opp_start.to_vec(),
                            e.opp.to_vec(),
                        ));
                        if ended {
                            break;
                        }
                        want_edges = done + 1;
                    }
                })
            });
            same_edges(&got, &want, &format!("fed {fed}"));
            assert_eq!(!seen.is_empty(), fed, "fed {fed}: consumer called");
            if fed {
                assert_eq!(
                    seen.last().unwrap().0,
                    want.len(),
                    "the last prefix is every edge"
                );
                for (done, a, b, s, o) in &seen {
                    assert!(a[..] == want.a[..*done], "a, {done} edges");
                    assert!(b[..] == want.b[..*done], "b, {done} edges");
                    assert!(s[..] == want.opp_start[..=*done], "opp_start, {done} edges");
                    assert!(o[..] == want.opp[..o.len()], "opp, {done} edges");
                }
            }
        }
    }

    /// `build_edges_opposites_only_shared_fed`: its hook is called once,
    /// before any edge is handed out, with whether the emit is fed; the
    /// topology's share of the triangles is dropped once they are listed,
    /// before the emit (the consumer sees the caller's share alone); the
    /// edges are the plain ones, with one thread or two (two emit groups
    /// when not fed). Caught: the hook called after the emit (the fed
    /// soup's consumer ran first), with the flag before the parity check
    /// (true for the odd soup), and the triangles kept to the end (two
    /// shares in the consumer).
    #[test]
    fn shared_triangles_are_dropped_once_listed_and_counted_is_told_if_fed() {
        let (vertices, odd, even) = odd_and_even_soups();
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            for (tris, fed) in [(&even, true), (&odd, false)] {
                let what = format!("{threads} threads, fed {fed}");
                let want = build_edges_opposites_only(tris, vertices);
                let mine = std::sync::Arc::new(tris.clone());
                let events = std::sync::Mutex::new(Vec::new());
                let got = pool.install(|| {
                    build_edges_opposites_only_shared_fed(
                        mine.clone(),
                        vertices,
                        &mut |feed: &EmitFeed| {
                            let shares = std::sync::Arc::strong_count(&mine);
                            events.lock().unwrap().push(format!("fed, {shares} shares"));
                            feed.wait(feed.records(), &|| false);
                        },
                        &mut |f| events.lock().unwrap().push(format!("counted {f}")),
                    )
                });
                same_edges(&got, &want, &what);
                let mut want_events = vec![format!("counted {fed}")];
                if fed {
                    want_events.push("fed, 1 shares".into());
                }
                assert_eq!(events.into_inner().unwrap(), want_events, "{what}");
                assert_eq!(std::sync::Arc::strong_count(&mine), 1, "{what}");
            }
        }
    }

    /// Pass 3 gives each group but the last edge slots for half its
    /// records and a sixteenth more; a group with more edges (open ones)
    /// writes the rest aside, and pass 4 moves each group's edges down or
    /// up to follow the previous groups', then the ones aside. Two soups:
    /// a closed torus (half as many edges as records) whose vertex ids are
    /// 64 apart, so that a range holds few records and a group of it never
    /// runs out of slots, and a third as many random triangles (nearly
    /// every edge open) over the same span of ids, either first, with 1 to
    /// 4 threads: groups that run out of slots, and groups that move down
    /// (several in a row) and up. Caught: the down moves made from the last
    /// group (one overwrote the edges of the group before it, not yet
    /// moved), the up moves from the first, overflows put before their
    /// group's other edges or left out of the next groups' places, and a
    /// group going back to its slots after an overflow.
    #[test]
    fn groups_edges_meet_whatever_their_slots_hold() {
        const STRIDE: u32 = 64;
        let (w, h) = (64u32, 256u32);
        let span = w * h * STRIDE;
        let mut torus = Vec::new();
        for y in 0..h {
            for x in 0..w {
                let at = |dx: u32, dy: u32| ((y + dy) % h * w + (x + dx) % w) * STRIDE;
                torus.extend_from_slice(&[at(0, 0), at(1, 0), at(1, 1)]);
                torus.extend_from_slice(&[at(0, 0), at(1, 1), at(0, 1)]);
            }
        }
        let mut bits = crate::multiplicity::test_bits(0x2545_f491_4f6c_dd1d);
        let mut random = Vec::new();
        while 3 * random.len() < torus.len() {
            let t: [u32; 3] = std::array::from_fn(|_| (bits() >> 11) as u32 % span);
            if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
                random.extend_from_slice(&t);
            }
        }
        let shifted = |t: &[u32]| t.iter().map(|&v| v + span).collect::<Vec<_>>();
        let soups = [
            ("torus first", [torus.clone(), shifted(&random)].concat()),
            ("random first", [random.clone(), shifted(&torus)].concat()),
        ];
        let vertices = 2 * span as usize;
        for (name, tris) in &soups {
            let expected = naive(tris);
            let open = (0..expected.len()).filter(|&e| expected.fan(e) == 1);
            assert!(
                open.count() > expected.len() / 5,
                "{name}: too few open edges"
            );
            let without_tri = Edges {
                opp_tri: Vec::new(),
                ..expected.clone()
            };
            for threads in 1..=4 {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let what = format!("{name}, {threads} threads");
                let got = pool.install(|| build_edges(tris, vertices));
                same_edges(&got, &expected, &what);
                for simd in simd_levels() {
                    let got = pool.install(|| {
                        build_edges_in::<false>(
                            tris[..].into(),
                            vertices,
                            threads,
                            simd,
                            false,
                            None,
                            None,
                        )
                        .0
                    });
                    same_edges(&got, &without_tri, &format!("{what}, {simd:?}"));
                }
            }
        }
    }

    /// Every sequence of up to 8 keys over a 3-letter alphabet (ties are
    /// what stability is about) and over distinct large ids, against a
    /// stable sort of the indices by key. Caught: a network missing its
    /// last layer's (3, 4), and padding that sorts first (0 instead of
    /// `u64::MAX`); both also fail the comparison with the obvious
    /// implementation below.
    #[test]
    fn sort_small_is_a_stable_sort_by_larger_endpoint() {
        let check = |keys: &[u32]| {
            let m = keys.len();
            let mut src = [[0u32; 4]; SMALL_RUN];
            for (r, &k) in src.iter_mut().zip(keys) {
                r[1] = k;
            }
            // What follows the real records must not be read.
            for r in &mut src[m..] {
                r[1] = 0;
            }
            let order = sort_small(&src, m);
            let mut want: Vec<usize> = (0..m).collect();
            want.sort_by_key(|&i| keys[i]);
            let got: Vec<usize> = order[..m].iter().map(|&o| o as usize % SMALL_RUN).collect();
            assert_eq!(got, want, "keys {keys:?}");
            for (j, &o) in order[..m].iter().enumerate() {
                assert_eq!((o >> 32) as u32, keys[want[j]], "keys {keys:?}");
            }
            assert!(order[m..].iter().all(|&o| o == u64::MAX), "keys {keys:?}");
        };
        for m in 0..=SMALL_RUN {
            let mut keys = vec![0u32; m];
            for code in 0..3usize.pow(m as u32) {
                let mut c = code;
                for k in keys.iter_mut() {
                    *k = (c % 3) as u32;
                    c /= 3;
                }
                check(&keys);
            }
        }
        let mut bits = crate::multiplicity::test_bits(0x9e37_79b9_7f4a_7c15);
        for _ in 0..10_000 {
            let m = (bits() % 9) as usize;
            let keys: Vec<u32> = (0..m).map(|_| (bits() >> 33) as u32).collect();
            check(&keys);
        }
    }

    #[test]
    fn fan_keeps_triangle_order_and_duplicates() {
        // Edge (0,1) shared by 4 triangles, one duplicated with reversed winding.
        let tris = [0, 1, 2, 1, 0, 3, 4, 1, 0, 0, 2, 1];
        let e = build_edges(&tris, 5);
        let i = (0..e.len()).find(|&i| e.a[i] == 0 && e.b[i] == 1).unwrap();
        assert_eq!(e.opposites(i), &[2, 3, 4, 2]);
        assert_eq!(
            &e.opp_tri[e.opp_start[i] as usize..e.opp_start[i + 1] as usize],
            &[0, 1, 2, 3]
        );
        let s = edge_stats(&e);
        assert_eq!(s.max_fan, 4);
        assert_eq!(s.non_manifold_edges, 1);
    }

    /// `fan_histogram` against a plain count where fans other than one and
    /// two are few, as in a real mesh: none, one alone in a chunk, at a
    /// chunk's first or last edge or the block's last, a fan of zero; over
    /// blocks of a whole number of chunks and not. (The whole-block test
    /// below has such fans in every chunk.)
    #[test]
    fn fan_histogram_finds_sparse_fans_at_chunk_edges() {
        let plain = |starts: &[u32]| {
            let mut h = vec![0u64; 3];
            for w in starts.windows(2) {
                let n = (w[1] - w[0]) as usize;
                if n >= h.len() {
                    h.resize(n + 1, 0);
                }
                h[n] += 1;
            }
            h
        };
        let c = FAN_CHUNK;
        for edges in [0, 1, c - 1, c, c + 1, 5 * c + 77] {
            let last = edges.saturating_sub(1);
            for rare in [
                vec![],
                vec![0],
                vec![last],
                vec![c - 1],
                vec![c],
                vec![c + 3, 3 * c],
            ] {
                let mut starts = vec![0u32];
                for i in 0..edges {
                    let n = match rare.iter().position(|&r| r == i) {
                        Some(0) if i == c => 0,
                        Some(k) => 3 + k as u32,
                        None if i % 7 == 3 => 1,
                        None => 2,
                    };
                    starts.push(starts[i] + n);
                }
                assert_eq!(
                    fan_histogram(&starts),
                    plain(&starts),
                    "{edges} edges, other fans at {rare:?}"
                );
            }
        }
    }

    /// The histogram against a plain count, over several blocks, with fans
    /// of one, two and more, in any number of threads.
    #[test]
    fn edge_stats_match_a_plain_count() {
        // (Also from `layout::Plan`. Caught: the plan's histogram summed
        // over all blocks but the last.)
        let mut bits = crate::multiplicity::test_bits(0x5851_f42d_4c95_7f2d);
        let mut opp_start = vec![0u32];
        for _ in 0..3 * STATS_BLOCK + 123 {
            let r = bits() >> 58;
            // Mostly 2, some 1, a few 3..=9.
            let n = match r {
                0..=44 => 2,
                45..=58 => 1,
                _ => 3 + (r as u32 - 59),
            };
            opp_start.push(opp_start.last().unwrap() + n);
        }
        let m = opp_start.len() - 1;
        let e = Edges {
            a: vec![0; m],
            b: vec![1; m],
            opp: vec![0; *opp_start.last().unwrap() as usize],
            opp_start,
            opp_tri: Vec::new(),
        };
        let mut plain = std::collections::BTreeMap::<u32, u64>::new();
        for i in 0..m {
            *plain.entry(e.fan(i) as u32).or_default() += 1;
        }
        let expected: Vec<(u32, u64)> = plain.into_iter().collect();
        assert!(expected.len() >= 5, "{expected:?}");
        for threads in 1..=3 {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let s = pool.install(|| edge_stats(&e));
            assert_eq!(s.histogram, expected, "{threads} threads");
            assert_eq!(s.edges, m as u64);
            assert_eq!(s.open_edges, expected[0].1);
            let more: u64 = expected.iter().filter(|h| h.0 > 2).map(|h| h.1).sum();
            assert_eq!(s.non_manifold_edges, more);
            assert_eq!(s.max_fan, expected.last().unwrap().0);
            // The same from the layout's plan, which a build uses.
            let plan = pool.install(|| crate::layout::Plan::new(&e, 0, 5));
            assert_eq!(plan.edge_stats(), s, "{threads} threads, plan");
        }
        assert_eq!(edge_stats(&Edges::default()), EdgeStats::default());
        let plan = crate::layout::Plan::new(&Edges::default(), 0, 5);
        assert_eq!(plan.edge_stats(), EdgeStats::default());
    }
}
