//! A global allocator that asks Linux for transparent huge pages on large
//! buffers.
//!
//! Why: a build touches a few hundred bytes of fresh memory per triangle (the
//! soup, the welded mesh, the edges, the output buffers). With 4 KiB pages
//! every first touch of a page is a fault, and on the full Stanford dragon the
//! profile showed a quarter of the whole build inside the page-fault handler
//! (`asm_exc_page_fault` 25 %, of which zeroing the pages, `clear_page_erms`,
//! was only 4 %). Many distributions set transparent huge pages to `madvise`,
//! so they are only used where a program asks; this allocator asks for every
//! allocation of at least [`HUGE_MIN`] bytes, which cuts the fault count of
//! those buffers by 512.
//!
//! Small blocks go to [`std::alloc::System`] unchanged (but inside an
//! arena's scope, below). Blocks of at least
//! [`HUGE_MIN`] bytes get an anonymous mapping of their own, a whole number
//! of huge pages long, with an `madvise(MADV_HUGEPAGE)` hint. The hint never changes what the program
//! computes, and a kernel without THP ignores it. On other systems the
//! allocator is exactly `System`.
//!
//! **The hint pauses while fresh huge pages are slow** ([`cold_memory_seen`]):
//! the first whole huge page of every fresh block is faulted in and timed
//! when the block is mapped, and one slower than [`COLD_FAULT`] turns the
//! hint into `MADV_NOHUGEPAGE` for that block and for every fresh block of
//! the next [`COLD_PAUSE`], up to a budget of half the free memory in
//! fragments smaller than a huge page, less the output a build expects to
//! write ([`reserve_page_cache`]); the first fresh block after the
//! pause probes again. Why, with the figures: [`cold_memory_seen`] and
//! [`reserve_page_cache`].
//!
//! **While a [`KeepFreed`] guard lives, freed large blocks are kept for
//! reuse** ([`CACHE_SLOTS`] of them, at most [`CACHE_BYTES`] in all, or
//! less under a batch's memory budget: [`KeepFreed::within`])
//! instead of being unmapped at once; the last guard's drop unmaps what is
//! left. A build holds one (`build::build_file_with`), and so does a
//! batch (`build::build_batch_with`), so that one input's freed blocks
//! serve the next input's build. Why: a
//! build frees big buffers between stages (the soup after welding, the
//! topology's listing after the edges are made) and allocates new ones
//! right after, and every fresh page is a fault and a page zeroed by the
//! kernel; on the dragon the topology stage spent 11 of its 40 ms in the
//! kernel's `clear_page_erms` (`perf record` of `examples/stage_probe.rs`).
//! A kept block is handed out again (cut to size, or, when none is long
//! enough, several moved side by side with `mremap`, which moves page
//! tables, not bytes, and a fresh tail after them if they do not cover the
//! request), zeroed by a `memset` only when the caller asks for zeroed
//! memory, as `vec![0; n]` does. A buffer reserved longer than it will be
//! written ([`vec_touching`]) takes kept memory for its front only. The
//! tail cut off a kept block, and the tail a shrinking `realloc` gives up,
//! are kept as blocks of their own rather than unmapped: their pages are
//! often touched already. On a 5M-triangle scene this took the fresh pages
//! a build faults in (kernel `mm_page_alloc` events, huge pages) from 286
//! to 266 MiB with one thread and from 384–394 to 316–322 MiB with two
//! (`benches/fresh_pages.py`, two runs each), where the topology's count
//! array was cut from the soup's 30 MiB positions and its edge arrays
//! shrunk from their record-sized reservations. glibc's malloc keeps
//! freed memory in the same way for blocks below its mmap threshold. Why
//! only under a guard: kept blocks still count in the process's memory, and
//! while `verify` (whose many small allocations go to malloc) ran with them
//! kept its peak grew from 366 to 402 MiB on the dragon, for no time gained
//! (measured again in the forty-second round, on a `verify` several times
//! faster by then: about 3% faster, within the drift, for 6–17 MiB more
//! peak memory).
//!
//! **A parser's small blocks can come from an arena of our own**
//! ([`arena`]): the OBJ loader runs tobj inside [`arena::Arena::scope`]
//! (both readers of a text parsed in two parts), and once the models are
//! freed the pages they used become a kept block, which the weld takes
//! instead of faulting in fresh memory (the 5M scene's weld, one thread,
//! 242 → 75 ms at the median of eight standalone builds; the figures are
//! in [`arena`]).
//!
//! The `svpack` binary and the benchmarks install it with
//! `#[global_allocator]`; library users choose their own allocator.

use std::alloc::{GlobalAlloc, Layout, System};

pub mod arena;

/// Allocations of at least this many bytes get their own huge-page mapping:
/// one huge page (2 MiB on x86-64) is the smallest range the hint can help.
pub const HUGE_MIN: usize = 2 << 20;

/// A fresh huge page that takes longer than this to fault in means the
/// system hands out cold huge pages, and [`HugePageAlloc`] pauses asking
/// for them (see [`cold_memory_seen`]). On this project's virtual machine a
/// huge page faults in in 0.23–0.30 ms when the host still backs it and in
/// 5.4–6.0 ms when it does not (a local probe, 36 faults in three runs).
pub const COLD_FAULT: std::time::Duration = std::time::Duration::from_millis(2);

/// How long [`HugePageAlloc`] gives fresh large blocks small pages after a
/// slow huge page (see [`cold_memory_seen`]). Long enough that a build of
/// the dragon (0.1–0.3 s) probes once; short enough that a long-running
/// process (a batch, a benchmark), whose own freed blocks come back as
/// huge pages the host still backs, gets them again: each probe of cold
/// memory costs about 5 ms against 0.7 ms for the same 2 MiB in small
/// pages, so one a second is at most 0.5% of the time.
pub const COLD_PAUSE: std::time::Duration = std::time::Duration::from_secs(1);

/// Whether a fresh huge page has been slower than [`COLD_FAULT`] to fault
/// in since the process started, so that [`HugePageAlloc`] gave fresh large
/// blocks small pages for a while (`MADV_NOHUGEPAGE`, for [`COLD_PAUSE`]
/// after each slow fault, while a budget lasts: half the free memory in
/// fragments smaller than a huge page, `/proc/buddyinfo`, less the page
/// cache a build expects to fill, [`reserve_page_cache`]; the first fresh
/// block after the pause probes again).
///
/// Why: on a virtual machine whose host takes freed guest memory back
/// (free page reporting, as Firecracker, WSL 2 and some clouds do), the
/// guest reports free 2 MiB blocks to the host about two seconds after
/// they are freed, and a huge page the guest then hands out is faulted in
/// by the host as well: 114–129 ms for 48 MiB here against 5.8–11.1 ms for
/// one the host still backs, while small pages come from the guest's
/// smaller free fragments, which are not reported themselves: 16.0–19.7 ms
/// either way (`examples/first_touch.rs`). The allocator cannot know in advance which
/// kind the kernel will hand out, so it times the first huge page of each
/// fresh block: a build started seconds after the last one (cold memory)
/// then costs about what small pages cost, and one started right after
/// another (warm) keeps its huge pages. Build timings report it
/// (`cold_memory` in `build --timings --json`).
pub fn cold_memory_seen() -> bool {
    #[cfg(target_os = "linux")]
    return sys::cold_seen();
    #[cfg(not(target_os = "linux"))]
    false
}

/// Tells [`HugePageAlloc`] that about `bytes` of page cache (an output
/// file about to be written) will draw on the same free fragments as small
/// pages: the small-page budget of a pause (see [`cold_memory_seen`])
/// shrinks by as much, down to nothing. A build calls it with an estimate
/// of its output as soon as it has read its input, and sets the
/// reservation to the output its triangles are expected to give once it
/// has loaded them ([`PageCacheReservation::resize`]). Why: a
/// 5M-triangle build (690 MiB output) whose buffers took small pages left
/// its output cold pages: its write stage took 1.2–1.8 s against 0.2–0.6
/// s.
pub fn reserve_page_cache(bytes: u64) -> PageCacheReservation {
    let mut r = PageCacheReservation { taken: 0 };
    r.resize(bytes);
    r
}

/// The part of the small-page budget one output's page cache holds
/// ([`reserve_page_cache`]). Dropping it gives nothing back: the output's
/// pages stay in the cache after the build.
#[derive(Debug)]
pub struct PageCacheReservation {
    /// Bytes actually taken from the budget (less than asked when the
    /// budget ran out).
    taken: u64,
}

impl PageCacheReservation {
    /// Makes the reservation `bytes`: takes more from the budget (as much
    /// as is left), or gives back what it holds beyond `bytes`. Why: the
    /// first estimate, 8 bytes per input byte, comes before the input is
    /// parsed; the 5M-triangle OBJ scene (204 MB) reserved 1.6 GB with it,
    /// more than twice its 721 MB output and the whole budget, so that
    /// its buffers never took small pages however cold the huge ones were
    /// (benches/ROUNDS.md, "Forty-sixth round").
    pub fn resize(&mut self, bytes: u64) {
        #[cfg(target_os = "linux")]
        {
            if bytes > self.taken {
                self.taken += sys::take_up_to(bytes - self.taken);
            } else {
                sys::give_back(self.taken - bytes);
                self.taken = bytes;
            }
        }
        #[cfg(not(target_os = "linux"))]
        let _ = bytes;
    }

    /// Bytes this reservation holds (less than asked when the budget ran
    /// out; always zero off Linux).
    pub fn taken(&self) -> u64 {
        self.taken
    }
}

/// Smallest buffer that [`large_capacity`] rounds up to [`HUGE_MIN`] bytes.
pub const ROUND_UP_FROM: usize = HUGE_MIN / 4;

/// The capacity to reserve for a buffer of `n` elements of `T` that a build
/// makes per vertex or per triangle: `n`, or, when `n` elements take from
/// [`ROUND_UP_FROM`] up to [`HUGE_MIN`] bytes, as many as fill `HUGE_MIN`
/// bytes, so that [`HugePageAlloc`] gives it a large block (a kept one, or
/// huge pages) instead of malloc's 4 KiB pages.
///
/// Why: a fresh 4 KiB page costs 1.4 µs here, 0.35 ms per MiB (a local
/// probe like `examples/first_touch.rs` without the huge-page hint),
/// against 0.12 ms per MiB for huge pages (`first_touch`) and nothing for
/// a kept block; the weld's run ids and bucket numbers and the topology's
/// counts (1.75, 0.87 and 1.75 MB on the dragon) were 4.0 MiB of fresh
/// 4 KiB pages with one thread, 5.5 with two (`benches/fresh_pages.py`). Why not a lower [`HUGE_MIN`] for all
/// blocks (tried in the eleventh round): the OBJ parser's many blocks of
/// 1–2 MiB then each took a huge page, and an OBJ build's peak memory grew
/// from 70 to 87 MiB. Only the buffers that ask get the rounding.
pub fn large_capacity<T>(n: usize) -> usize {
    let size = std::mem::size_of::<T>();
    let bytes = n.saturating_mul(size);
    if size > 0 && (ROUND_UP_FROM..HUGE_MIN).contains(&bytes) {
        HUGE_MIN.div_ceil(size)
    } else {
        n
    }
}

/// `n` zeroed elements, in a buffer of [`large_capacity`]`(n)` (fresh
/// mappings are zero already; a kept block is zeroed by `memset`).
pub fn zeroed_large<T: bytemuck::Zeroable>(n: usize) -> Vec<T> {
    let mut v = bytemuck::zeroed_vec(large_capacity::<T>(n));
    v.truncate(n);
    v
}

/// Large blocks' alignment limit: `mmap` returns page-aligned memory.
const PAGE: usize = 4096;

/// Most freed large blocks kept for reuse (see the module documentation).
/// A build ends holding about a dozen large blocks (soup, welded mesh,
/// edges, tails); with 8 slots a batch's next input found only part of
/// them (dragon batch: 30 MiB of fresh huge pages per further input, 18
/// with 16 slots). A slot costs a compare under the lock.
pub const CACHE_SLOTS: usize = 16;

/// Most bytes of freed large blocks kept for reuse: above this, a freed
/// block is unmapped at once.
pub const CACHE_BYTES: usize = 256 << 20;

/// Most bytes of freed large blocks kept now: [`CACHE_BYTES`], or less
/// while a [`KeepFreed::within`] guard lives.
static CACHE_LIMIT: std::sync::atomic::AtomicUsize =
    std::sync::atomic::AtomicUsize::new(CACHE_BYTES);

/// Number of live [`KeepFreed`] guards.
static KEEPERS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// While one of these lives, [`HugePageAlloc`] keeps freed large blocks for
/// reuse (see the module documentation); the last one to drop gives the
/// kept blocks back to the system. Guards nest and may live on several
/// threads at once (a batch builds several inputs in parallel).
#[derive(Debug)]
#[must_use = "blocks are kept only while the guard lives"]
pub struct KeepFreed {
    /// The cache's limit to set back on drop ([`KeepFreed::within`]).
    restore: Option<usize>,
}

impl KeepFreed {
    /// Starts keeping freed large blocks, until the guard (and every other
    /// live guard) is dropped.
    pub fn new() -> Self {
        KEEPERS.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        KeepFreed { restore: None }
    }

    /// [`KeepFreed::new`], keeping at most `limit` bytes (and never more
    /// than [`CACHE_BYTES`]) until this guard drops: what a batch under a
    /// memory budget allows its kept blocks (`build::BatchConfig`).
    pub fn within(limit: usize) -> Self {
        use std::sync::atomic::Ordering::SeqCst;
        let old = CACHE_LIMIT.swap(limit.min(CACHE_BYTES), SeqCst);
        let mut guard = Self::new();
        guard.restore = Some(old);
        guard
    }
}

impl Default for KeepFreed {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for KeepFreed {
    fn drop(&mut self) {
        if let Some(limit) = self.restore {
            CACHE_LIMIT.store(limit, std::sync::atomic::Ordering::SeqCst);
        }
        if KEEPERS.fetch_sub(1, std::sync::atomic::Ordering::SeqCst) == 1 {
            release();
        }
    }
}

/// Unmaps every kept block.
fn release() {
    #[cfg(target_os = "linux")]
    while let Some((p, s)) = take(0) {
        // SAFETY: a kept block is a mapping of `s` bytes nobody else holds.
        unsafe { sys::unmap(p, s) };
    }
}

/// Freed large blocks, `(address, span)`; span 0 marks a free slot. A lock
/// around an array: `std::sync::Mutex` never allocates (it is a futex), so
/// it is usable inside an allocator, and large blocks are few and big, so
/// the lock is never contended for long.
#[cfg(target_os = "linux")]
static CACHE: std::sync::Mutex<[(usize, usize); CACHE_SLOTS]> =
    std::sync::Mutex::new([(0, 0); CACHE_SLOTS]);

/// Keeps the freed block `p` (a mapping of `span` bytes) for reuse if a
/// [`KeepFreed`] guard lives, joined with the kept blocks it touches (see
/// below), when a slot is free and the cache stays within its limit
/// ([`CACHE_BYTES`], or a [`KeepFreed::within`] guard's).
/// Returns the block when it is not kept (the cache then unchanged), for
/// the caller to unmap.
///
/// Why join: a kept block is cut to the size asked for and its tail kept on
/// its own, and a block too short was grown with `mremap`, whose new tail
/// is fresh memory (until the sixty-fourth round; now the short blocks are
/// gathered, [`gather`]). Without joining, a loop that frees and asks again
/// for the same buffers cut its blocks into ever smaller pieces, filled the
/// slots with them and grew the pieces back with fresh pages: 14–16 huge
/// pages faulted in per run of the dragon's weld, topology and bucket
/// counts, and five `mremap` calls (`strace`), 2–3 ms of the kernel zeroing
/// pages (`RECYCLE=1 cargo run --release --example stage_probe -- buckets`:
/// 14 faults a run before, none after, the runs' median 29.7–30.2 →
/// 27.5–28.4 ms); and a batch of six copies of the dragon, one job, one
/// thread, faulted in 140 MiB of fresh anonymous memory before, 60–65 after
/// (`benches/fresh_pages.py`).
///
/// The price is in a batch's peak memory: the pieces used to be unmapped
/// for want of a slot, or grown into address space never touched, and
/// joined they stay resident: 73 → 81–85 MiB with one job, 147 →
/// 163–169 MiB with two (`python3 benches/rebuild.py --jobs J OLD NEW
/// dragon.glb 6 8`, whose wall times moved within the noise with one job
/// and were 8% shorter with two). A single build's peak is unchanged (54
/// MiB). Bounding the cache by the most bytes ever live at once did not
/// lower the batch's peak and gave back part of the fresh memory
/// (benches/ROUNDS.md, Twenty-seventh round).
///
/// Blocks that touch were mostly one mapping once (a block and the tail
/// cut off it); two mappings side by side are joined too, and what
/// `mremap` then cannot grow as one is copied instead ([`HugePageAlloc`]'s
/// `realloc`) or left kept for a fresh block (`large_block`).
#[cfg(target_os = "linux")]
fn keep(p: *mut u8, span: usize) -> Option<(*mut u8, usize)> {
    if KEEPERS.load(std::sync::atomic::Ordering::Relaxed) == 0 {
        return Some((p, span));
    }
    let Ok(mut cache) = CACHE.lock() else {
        return Some((p, span));
    };
    // Kept blocks never touch (each was joined when kept), so at most one
    // ends where this one starts and one starts where it ends.
    let (lo, hi) = (p as usize, p as usize + span);
    let before = cache.iter().position(|c| c.1 > 0 && c.0 + c.1 == lo);
    let after = cache.iter().position(|c| c.1 > 0 && c.0 == hi);
    let start = before.map_or(lo, |i| cache[i].0);
    let end = after.map_or(hi, |i| cache[i].0 + cache[i].1);
    let held: usize = cache.iter().map(|c| c.1).sum();
    // The neighbours' bytes are counted in `held` already.
    if held + span > CACHE_LIMIT.load(std::sync::atomic::Ordering::Relaxed) {
        return Some((p, span));
    }
    for i in before.into_iter().chain(after) {
        cache[i] = (0, 0);
    }
    match cache.iter_mut().find(|c| c.1 == 0) {
        Some(slot) => {
            *slot = (start, end - start);
            None
        }
        None => Some((p, span)),
    }
}

/// Frees the large block `p` of `span` bytes: kept for reuse when
/// [`keep`] takes it, else unmapped.
///
/// # Safety
/// `p..p + span` must be a mapping this allocator owns and nobody uses.
#[cfg(target_os = "linux")]
unsafe fn keep_or_unmap(p: *mut u8, span: usize) {
    if let Some((p, span)) = keep(p, span) {
        // SAFETY: the caller's contract.
        unsafe { sys::unmap(p, span) }
    }
}

/// A kept block for a request of `span` bytes, taken out of the cache: the
/// smallest one at least that long, else the longest one (which the caller
/// grows). `None` if the cache is empty.
#[cfg(target_os = "linux")]
fn take(span: usize) -> Option<(*mut u8, usize)> {
    let mut cache = CACHE.lock().ok()?;
    let held = || (0..CACHE_SLOTS).filter(|&i| cache[i].1 > 0);
    let pick = held()
        .filter(|&i| cache[i].1 >= span)
        .min_by_key(|&i| cache[i].1)
        .or_else(|| held().max_by_key(|&i| cache[i].1))?;
    let (p, s) = std::mem::take(&mut cache[pick]);
    Some((p as *mut u8, s))
}

/// A large block of exactly `span` bytes (a mapping), built from kept
/// blocks when the cache holds any, else freshly mapped; with `zeroed`, its
/// first `size` bytes are zero. Null on failure.
///
/// Its front, all of it or the part the caller expects to write
/// ([`vec_touching`]), comes from kept blocks: the smallest one long
/// enough, cut to size, or else several, longest first, moved side by
/// side into a new mapping ([`gather`]); only what the cache cannot cover
/// is fresh. Why several: a build frees blocks of all sizes between its
/// stages, and when no single one was long enough the longest was grown
/// with fresh pages while the shorter ones stayed unused. On the
/// 5M-triangle scene the topology's listings (78 MiB) took a kept block of
/// 58 MiB and 20 MiB of fresh pages while 52 MiB sat in three shorter
/// kept blocks (an allocation log, sixty-fourth round).
#[cfg(target_os = "linux")]
fn large_block(span: usize, size: usize, zeroed: bool) -> *mut u8 {
    // The front to build from kept memory, in whole huge pages.
    let front = match FRONT.with(|f| f.replace(0)) {
        0 => span,
        f => self::span(f).min(span),
    };
    let Some((p, s)) = take(front) else {
        // Fresh anonymous mappings are zero.
        return sys::map(span);
    };
    let (p, reused) = if s >= front {
        if s > front {
            // Cut to size: the tail stays kept when it fits the cache (its
            // pages may have been touched already), else goes back to the
            // system.
            // SAFETY: `p..p + s` is a mapping this allocator owns; its tail
            // is a mapping of its own from now on.
            unsafe { keep_or_unmap(p.add(front), s - front) };
        }
        if front == span {
            (p, span)
        } else {
            // SAFETY: `p..p + front` is a block this allocator owns.
            unsafe { gather(p, front, front, span) }
        }
    } else {
        // SAFETY: as above, for `p..p + s`.
        unsafe { gather(p, s, front, span) }
    };
    if zeroed && !p.is_null() {
        // Only the reused pages can hold old data.
        // SAFETY: `p` is valid for `span >= size` bytes.
        unsafe { std::ptr::write_bytes(p, 0, size.min(reused)) };
    }
    p
}

std::thread_local! {
    /// Bytes of the next large block on this thread that its caller
    /// expects to write; zero for all of it ([`vec_touching`]).
    static FRONT: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// A vector with room for `capacity` elements, of which the caller expects
/// to write about the first `touched`: under [`HugePageAlloc`], kept blocks
/// back only that front and the rest of the room is fresh address space,
/// faulted in only if written. With any other global allocator, exactly
/// `Vec::with_capacity(capacity)`.
///
/// Why: the topology reserves its edge arrays for as many edges as records
/// (an edge has at least one record) and writes about half of that. A kept
/// block handed out whole to the first array left half of its kept pages
/// unwritten, while the last array faulted in fresh ones: 18 MiB of them
/// on the 5M-triangle scene, where a fresh huge page the host has to back
/// too costs about 6 ms (sixty-fourth round).
pub fn vec_touching<T>(capacity: usize, touched: usize) -> Vec<T> {
    let bytes = touched
        .min(capacity)
        .saturating_mul(std::mem::size_of::<T>());
    FRONT.with(|f| f.set(bytes.max(1)));
    let v = Vec::with_capacity(capacity);
    // A small vector, or one that does not reach this allocator, leaves
    // the hint unread.
    FRONT.with(|f| f.set(0));
    v
}

/// A block of `span` bytes whose first `want` bytes are kept memory: the
/// kept block `p` of `s` bytes first, then more kept blocks taken from the
/// cache, each moved (its page tables, not its bytes: `mremap`) into a new
/// mapping after the last; the rest is fresh. Returns the block and how
/// many of its first bytes are kept memory (`want`, or less when the cache
/// ran out); null if no mapping could be made (the blocks then go back to
/// the cache).
///
/// # Safety
/// `p..p + s` must be a block this allocator owns that nobody uses, with
/// `s <= want <= span`, all multiples of [`HUGE_MIN`].
#[cfg(target_os = "linux")]
unsafe fn gather(p: *mut u8, s: usize, want: usize, span: usize) -> (*mut u8, usize) {
    let r = sys::reserve(span);
    if r.is_null() {
        // SAFETY: the caller's contract.
        unsafe { keep_or_unmap(p, s) };
        return (r, 0);
    }
    let mut at = 0;
    let mut piece = Some((p, s));
    while let Some((p, s)) = piece {
        let used = s.min(want - at);
        // SAFETY: `p..p + s` is a kept block nobody uses (the caller's, or
        // one `take` handed out); its tail becomes a block of its own, and
        // `r + at .. r + at + used` lies inside the new mapping.
        unsafe {
            if used < s {
                keep_or_unmap(p.add(used), s - used);
            }
            sys::move_into(p, used, r.add(at));
        }
        at += used;
        piece = if at < want { take(want - at) } else { None };
    }
    if at < span {
        // SAFETY (of the hint): the rest of the new mapping, untouched.
        sys::hint_fresh(unsafe { r.add(at) }, span - at);
    }
    (r, at)
}

/// [`System`] for small blocks; on Linux, its own anonymous mapping with the
/// `MADV_HUGEPAGE` hint for blocks of at least [`HUGE_MIN`] bytes (see the
/// module documentation).
///
/// Large blocks bypass malloc because glibc's dynamic mmap threshold serves
/// them from the brk heap after the first large free, where they neither
/// keep the hint nor grow without copying; a mapping of their own grows with
/// `mremap`, which moves page tables instead of bytes.
#[derive(Debug, Default, Clone, Copy)]
pub struct HugePageAlloc;

/// The length of the mapping that holds a large block of `size` bytes: the
/// next multiple of [`HUGE_MIN`].
///
/// Why: Linux places a mapping on a huge-page boundary only when its length
/// is a multiple of the huge-page size, and backs with huge pages only the
/// whole aligned 2 MiB ranges inside it. A 3.5 MiB buffer got one huge
/// page and 384 small ones (`AnonHugePages` in `/proc/self/smaps`, kernel
/// 6.18); rounded up to 4 MiB it gets two. On the dragon the weld and
/// topology stages allocate a dozen buffers of 2–14 MiB, so most of their
/// first touches were small-page faults (benches/ROUNDS.md, "Eighth round"). The cost
/// is address space, and at most the zeroing of one huge page per buffer
/// where a buffer's tail reaches into it.
#[inline]
fn span(size: usize) -> usize {
    size.next_multiple_of(HUGE_MIN)
}

#[inline]
fn is_large(size: usize, align: usize) -> bool {
    cfg!(target_os = "linux") && size >= HUGE_MIN && align <= PAGE
}

#[cfg(target_os = "linux")]
mod sys {
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering::Relaxed};
    use std::time::Duration;

    /// Until when (monotonic clock, ns) fresh mappings get small pages: set
    /// [`super::COLD_PAUSE`] after a slow huge page.
    static COLD_UNTIL: AtomicU64 = AtomicU64::new(0);

    /// Whether a huge page has been slow (see [`super::cold_memory_seen`]).
    static COLD_SEEN: AtomicBool = AtomicBool::new(false);

    /// The monotonic clock in ns (`Instant` cannot be stored in an atomic).
    fn now_ns() -> u64 {
        let mut t = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `t` is a valid timespec to write.
        unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut t) };
        t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
    }

    /// Whether fresh mappings get the huge-page hint now.
    pub fn hinting() -> bool {
        now_ns() >= COLD_UNTIL.load(Relaxed)
    }

    pub fn cold_seen() -> bool {
        COLD_SEEN.load(Relaxed)
    }

    /// Ends a pause now (tests, whose blocks may have met cold memory).
    #[cfg(test)]
    pub fn end_pause() {
        COLD_UNTIL.store(0, Relaxed);
    }

    /// Bytes of small pages fresh mappings may still take during pauses;
    /// `u64::MAX` until first measured ([`small_page_budget`], by the first
    /// reserve or the first slow huge page).
    static SMALL_LEFT: AtomicU64 = AtomicU64::new(u64::MAX);

    /// Half the free memory in blocks smaller than a huge page
    /// (`/proc/buddyinfo`, every zone): the memory small pages come from
    /// warm, which the page cache needs as well (see [`take_small`]). Zero
    /// if the file cannot be read. Reads into a stack buffer: this runs
    /// inside the allocator.
    fn small_page_budget() -> u64 {
        let mut buf = [0u8; 4096];
        // SAFETY: a NUL-terminated path; the descriptor is closed below.
        let fd = unsafe { libc::open(c"/proc/buddyinfo".as_ptr(), libc::O_RDONLY) };
        if fd < 0 {
            return 0;
        }
        let mut len = 0;
        while len < buf.len() {
            // SAFETY: the rest of `buf` is valid for writes.
            let n = unsafe { libc::read(fd, buf[len..].as_mut_ptr().cast(), buf.len() - len) };
            if n <= 0 {
                break;
            }
            len += n as usize;
        }
        // SAFETY: `fd` is open and ours.
        unsafe { libc::close(fd) };
        let below = (super::HUGE_MIN / super::PAGE).trailing_zeros() as usize;
        small_free_bytes(&buf[..len], below) / 2
    }

    /// Free bytes in blocks of order below `below`, from the text of
    /// `/proc/buddyinfo` ("Node 0, zone Normal c0 c1 …", the counts of free
    /// blocks of 4 KiB · 2^order).
    pub fn small_free_bytes(text: &[u8], below: usize) -> u64 {
        let mut total = 0u64;
        for line in text.split(|&b| b == b'\n') {
            let words = line
                .split(|b| b.is_ascii_whitespace())
                .filter(|w| !w.is_empty());
            for (order, w) in words.skip(4).take(below).enumerate() {
                let count = std::str::from_utf8(w)
                    .ok()
                    .and_then(|w| w.parse::<u64>().ok());
                total += count.unwrap_or(0) * ((super::PAGE as u64) << order);
            }
        }
        total
    }

    /// Whether a fresh mapping of `size` bytes may take small pages during
    /// a pause, taking them from the budget if so. Why a budget: small
    /// pages come from the guest's free fragments, the memory the host
    /// still backs after a rest, and the page cache that takes a build's
    /// output draws on the same fragments ([`super::reserve_page_cache`]).
    fn take_small(size: usize) -> bool {
        take_budget(size as u64)
    }

    /// Takes `bytes` from the small-page budget (measured first if it has
    /// not been): all or nothing.
    fn take_budget(bytes: u64) -> bool {
        measure_budget();
        SMALL_LEFT
            .fetch_update(Relaxed, Relaxed, |left| left.checked_sub(bytes))
            .is_ok()
    }

    /// Takes up to `bytes` from the small-page budget (measured first if it
    /// has not been), as much as is left; returns what it took.
    pub fn take_up_to(bytes: u64) -> u64 {
        measure_budget();
        let before = SMALL_LEFT
            .fetch_update(Relaxed, Relaxed, |left| Some(left.saturating_sub(bytes)))
            .unwrap_or(0);
        before.min(bytes)
    }

    /// Returns `bytes` taken by [`take_up_to`] to the budget.
    pub fn give_back(bytes: u64) {
        let _ = SMALL_LEFT.fetch_update(Relaxed, Relaxed, |left| Some(left.saturating_add(bytes)));
    }

    /// Reads the budget the first time it is needed.
    fn measure_budget() {
        if SMALL_LEFT.load(Relaxed) == u64::MAX {
            let _ = SMALL_LEFT.compare_exchange(u64::MAX, small_page_budget(), Relaxed, Relaxed);
        }
    }

    /// Sets the budget of [`take_small`] (tests).
    #[cfg(test)]
    pub fn set_small_budget(bytes: u64) {
        SMALL_LEFT.store(bytes, Relaxed);
    }

    /// The budget left (tests).
    #[cfg(test)]
    pub fn small_budget_left() -> u64 {
        SMALL_LEFT.load(Relaxed)
    }

    /// Fresh mappings get small pages for the next `pause`.
    fn pause_hinting(pause: Duration) {
        COLD_SEEN.store(true, Relaxed);
        let ns = u64::try_from(pause.as_nanos()).unwrap_or(u64::MAX);
        COLD_UNTIL.store(now_ns().saturating_add(ns), Relaxed);
    }

    /// A fresh zeroed mapping of `size` bytes, or null. With the huge-page
    /// hint while [`hinting`], after which its first whole huge page is
    /// faulted in and timed: slower than [`super::COLD_FAULT`], the hint
    /// pauses for [`super::COLD_PAUSE`], this mapping's other pages included.
    pub fn map(size: usize) -> *mut u8 {
        map_with(size, super::COLD_FAULT, super::COLD_PAUSE)
    }

    /// A fresh anonymous private mapping of `size` bytes, not yet hinted;
    /// null on failure.
    fn anon(size: usize) -> *mut libc::c_void {
        // SAFETY: an anonymous private mapping has no preconditions.
        let p = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                size,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                -1,
                0,
            )
        };
        if p == libc::MAP_FAILED {
            std::ptr::null_mut()
        } else {
            p
        }
    }

    /// [`map`] with `cold` as the slowest fault that keeps the hint and
    /// `pause` as the pause after a slower one (tests pass a zero `cold` to
    /// take the cold path on any machine).
    pub fn map_with(size: usize, cold: Duration, pause: Duration) -> *mut u8 {
        let p = anon(size);
        if p.is_null() {
            return std::ptr::null_mut();
        }
        // During a pause, small pages while the budget lasts. With the
        // budget spent (a build whose output takes the warm memory) there
        // is nothing to probe for: huge pages, as without the probe.
        let hint = hinting();
        advise(p, size, hint || !take_small(size));
        if hint && SMALL_LEFT.load(Relaxed) > 0 && first_huge_fault(p.cast(), size) > cold {
            pause_hinting(pause);
            if take_small(size) {
                advise(p, size, false);
            }
        }
        p.cast()
    }

    /// Faults in the first whole huge page of the fresh mapping `p` of
    /// `size` bytes by writing a zero into it (a read would map the shared
    /// zero page), and returns how long that took; zero if the mapping
    /// holds no whole huge page.
    fn first_huge_fault(p: *mut u8, size: usize) -> Duration {
        let first = (p as usize).next_multiple_of(super::HUGE_MIN);
        if first + super::HUGE_MIN > p as usize + size {
            return Duration::ZERO;
        }
        let t = std::time::Instant::now();
        // SAFETY: `first` lies inside the mapping, which is writable and
        // still all zero, as the caller expects of a fresh block after this.
        unsafe { p.add(first - p as usize).write_volatile(0) };
        t.elapsed()
    }

    /// The hint if `hint`, else its opposite (so that a kernel whose
    /// transparent huge pages are `always` backs the mapping with small
    /// pages too). Either only changes how later faults are served; a
    /// kernel without THP rejects both, which is harmless, so the result is
    /// not checked.
    fn advise(p: *mut libc::c_void, size: usize, hint: bool) {
        let advice = if hint {
            libc::MADV_HUGEPAGE
        } else {
            libc::MADV_NOHUGEPAGE
        };
        // SAFETY: `p..p + size` is a mapping this allocator owns.
        unsafe { libc::madvise(p, size, advice) };
    }

    /// A fresh mapping of `size` bytes for [`super::gather`], not yet
    /// hinted and not probed: kept blocks are about to replace its front
    /// (the probe would fault it in), and [`hint_fresh`] hints the rest.
    /// Null on failure.
    pub fn reserve(size: usize) -> *mut u8 {
        anon(size).cast()
    }

    /// Hints the fresh pages `p..p + size` of a mapping as [`map`] hints a
    /// fresh one (without its probe), taking them from the small-page
    /// budget during a pause.
    pub fn hint_fresh(p: *mut u8, size: usize) {
        advise(p.cast(), size, hinting() || !take_small(size));
    }

    /// Moves the pages of `p..p + len` (page tables, not bytes) to `to..to
    /// + len`, which they replace: in one `mremap`, or, for a block joined
    /// from two mappings, which kernels before 6.17 do not move in one,
    /// [`move_by_huge_pages`].
    ///
    /// # Safety
    /// `p..p + len` must be a block this allocator owns that nobody uses,
    /// and `to..to + len` part of a mapping of its own nobody uses.
    pub unsafe fn move_into(p: *mut u8, len: usize, to: *mut u8) {
        // SAFETY: the caller's contract.
        if !unsafe { move_one(p, len, to) } {
            // SAFETY: the caller's contract.
            unsafe { move_by_huge_pages(p, len, to) };
        }
    }

    /// [`move_into`] a huge page at a time: every mapping this allocator
    /// makes is a whole number of them, so no piece spans two. A piece that
    /// still cannot move is unmapped, and `to`'s fresh page stays in its
    /// place.
    ///
    /// # Safety
    /// As [`move_into`].
    pub unsafe fn move_by_huge_pages(p: *mut u8, len: usize, to: *mut u8) {
        for at in (0..len).step_by(super::HUGE_MIN) {
            let n = super::HUGE_MIN.min(len - at);
            // SAFETY: pieces of the caller's ranges.
            unsafe {
                if !move_one(p.add(at), n, to.add(at)) {
                    unmap(p.add(at), n);
                }
            }
        }
    }

    /// One `mremap` of `p..p + len` onto `to`; whether it moved.
    ///
    /// # Safety
    /// As [`move_into`].
    unsafe fn move_one(p: *mut u8, len: usize, to: *mut u8) -> bool {
        let flags = libc::MREMAP_MAYMOVE | libc::MREMAP_FIXED;
        // SAFETY: the caller's contract.
        let q = unsafe { libc::mremap(p.cast(), len, len, flags, to) };
        q != libc::MAP_FAILED
    }

    /// # Safety
    /// `p` must come from [`map`] or [`remap`] with length `size`.
    pub unsafe fn unmap(p: *mut u8, size: usize) {
        // SAFETY: the caller's contract.
        unsafe { libc::munmap(p.cast(), size) };
    }

    /// # Safety
    /// `p` must come from [`map`] or [`remap`] with length `old`.
    pub unsafe fn remap(p: *mut u8, old: usize, new: usize) -> *mut u8 {
        // SAFETY: the caller's contract; MAYMOVE lets the kernel move the
        // page tables when the range cannot grow in place.
        let q = unsafe { libc::mremap(p.cast(), old, new, libc::MREMAP_MAYMOVE) };
        if q == libc::MAP_FAILED {
            return std::ptr::null_mut();
        }
        advise(q, new, hinting() || !take_small(new - old));
        q.cast()
    }
}

#[cfg(not(target_os = "linux"))]
mod sys {
    pub fn map(_: usize) -> *mut u8 {
        unreachable!("large blocks use System off Linux")
    }
    pub unsafe fn unmap(_: *mut u8, _: usize) {
        unreachable!("large blocks use System off Linux")
    }
    pub unsafe fn remap(_: *mut u8, _: usize, _: usize) -> *mut u8 {
        unreachable!("large blocks use System off Linux")
    }
}

#[cfg(not(target_os = "linux"))]
unsafe fn keep_or_unmap(_: *mut u8, _: usize) {
    unreachable!("large blocks use System off Linux")
}

#[cfg(not(target_os = "linux"))]
fn large_block(_: usize, _: usize, _: bool) -> *mut u8 {
    unreachable!("large blocks use System off Linux")
}

// SAFETY: small blocks are System's, or an arena's (alignment at most 16,
// and told apart by address: nothing else is placed in an arena's live
// chunks, `arena::owns`); large blocks are whole mappings, which are
// page-aligned (so every alignment up to PAGE holds) and zeroed, and are
// only ever released or resized here (`is_large` of the layout the caller
// passes back decides which kind a block is, and the GlobalAlloc contract
// says that is the layout it was allocated with).
unsafe impl GlobalAlloc for HugePageAlloc {
    #[inline]
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let a = arena::alloc(layout.size(), layout.align(), false);
        if !a.is_null() {
            return a;
        }
        if is_large(layout.size(), layout.align()) {
            large_block(span(layout.size()), layout.size(), false)
        } else {
            // SAFETY: the caller's contract.
            unsafe { System.alloc(layout) }
        }
    }

    #[inline]
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let a = arena::alloc(layout.size(), layout.align(), true);
        if !a.is_null() {
            return a;
        }
        if is_large(layout.size(), layout.align()) {
            large_block(span(layout.size()), layout.size(), true)
        } else {
            // SAFETY: the caller's contract.
            unsafe { System.alloc_zeroed(layout) }
        }
    }

    #[inline]
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if is_large(layout.size(), layout.align()) {
            // SAFETY: large blocks are mappings of exactly this size.
            unsafe { keep_or_unmap(ptr, span(layout.size())) }
        } else if arena::owns(ptr) {
            // SAFETY: a small block in the arena's range is its block.
            unsafe { arena::dealloc(ptr, layout.size()) }
        } else {
            // SAFETY: the caller's contract.
            unsafe { System.dealloc(ptr, layout) }
        }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let align = layout.align();
        // An arena's block stays where it is within its size class, and
        // otherwise moves like a block crossing HUGE_MIN (below).
        let in_arena = !is_large(layout.size(), align) && arena::owns(ptr);
        if in_arena && arena::same_block(layout.size(), new_size) {
            return ptr;
        }
        match (is_large(layout.size(), align), is_large(new_size, align)) {
            // SAFETY: a mapping of exactly `layout.size()` bytes.
            (true, true) => {
                let (old, new) = (span(layout.size()), span(new_size));
                if new < old {
                    // Shrunk: the block stays where it is and its tail is
                    // freed like a block of its own (kept under a guard).
                    // SAFETY: `ptr..ptr + old` is a mapping this allocator
                    // owns; its tail is a mapping of its own from now on.
                    unsafe { keep_or_unmap(ptr.add(new), old - new) };
                    ptr
                } else {
                    // SAFETY: a mapping of exactly `old` bytes.
                    let q = unsafe { sys::remap(ptr, old, new) };
                    if !q.is_null() {
                        return q;
                    }
                    // `mremap` moves one mapping only; a kept block joined
                    // from two (see `keep`) is copied to a new block.
                    let q = large_block(new, new_size, false);
                    if !q.is_null() {
                        // SAFETY: both blocks are valid for the old size
                        // and distinct; the old one is ours to free.
                        unsafe {
                            std::ptr::copy_nonoverlapping(ptr, q, layout.size());
                            keep_or_unmap(ptr, old);
                        }
                    }
                    q
                }
            }
            // SAFETY: the caller's contract.
            (false, false) if !in_arena => unsafe { System.realloc(ptr, layout, new_size) },
            _ => {
                // Crossing HUGE_MIN, or out of an arena's block: move
                // between the kinds of block (`dealloc` tells them apart).
                // SAFETY: the caller guarantees a valid size for `align`.
                let new_layout = unsafe { Layout::from_size_align_unchecked(new_size, align) };
                // SAFETY: the caller guarantees a non-zero size.
                let new = unsafe { self.alloc(new_layout) };
                if !new.is_null() {
                    // SAFETY: both blocks are valid for the smaller size and
                    // are distinct allocations.
                    unsafe {
                        std::ptr::copy_nonoverlapping(ptr, new, layout.size().min(new_size));
                        self.dealloc(ptr, layout);
                    }
                }
                new
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The cache is one for the process: tests that use it run one at a time.
    static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

    /// Whether the kernel may back the mapping holding `p` with huge pages
    /// (`THPeligible` in `/proc/self/smaps`), or None if no mapping holds it.
    #[cfg(target_os = "linux")]
    fn thp_eligible(p: *mut u8) -> Option<bool> {
        let smaps = std::fs::read_to_string("/proc/self/smaps").unwrap();
        let mut inside = false;
        for line in smaps.lines() {
            let range = line.split_whitespace().next().unwrap_or("");
            if let Some((lo, hi)) = range.split_once('-')
                && let (Ok(lo), Ok(hi)) =
                    (usize::from_str_radix(lo, 16), usize::from_str_radix(hi, 16))
            {
                inside = (lo..hi).contains(&(p as usize));
            } else if inside && let Some(v) = line.strip_prefix("THPeligible:") {
                return Some(v.trim() == "1");
            }
        }
        None
    }

    /// While the hint is on a fresh block may take huge pages; once a first
    /// fault is slower than the threshold (zero here, so any machine takes
    /// this path), that block and the fresh blocks of the pause after it
    /// are not eligible (`MADV_NOHUGEPAGE`) while the small-page budget
    /// lasts, and after the pause a fresh block is again; with no budget
    /// there is no probe. Caught: the slow block left with its hint
    /// (eligible), later blocks given the hint during the pause, the hint
    /// never coming back, blocks past the budget given small pages, and a
    /// probe (and pause) with no budget.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_slow_first_huge_page_pauses_the_hint() {
        use std::time::Duration;
        let _serial = SERIAL.lock().unwrap();
        let thp_on = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled")
            .is_ok_and(|s| !s.contains("[never]"));
        let size = 4 * HUGE_MIN;
        // Another test's block may have met cold memory on this machine
        // and started a pause (with or without a budget left): end it.
        sys::end_pause();
        let before = sys::map_with(size, Duration::MAX, COLD_PAUSE);
        assert!(!before.is_null());
        assert_eq!(thp_eligible(before), Some(thp_on), "a fresh block");
        // A slow first fault, with a pause longer than this test, and small
        // pages for two blocks only.
        sys::end_pause();
        sys::set_small_budget(2 * size as u64);
        let long = Duration::from_secs(3600);
        let slow = sys::map_with(size, Duration::ZERO, long);
        assert!(!slow.is_null());
        assert!(cold_memory_seen() && !sys::hinting());
        assert_eq!(thp_eligible(slow), Some(false), "the block that was slow");
        let during = sys::map_with(size, Duration::MAX, long);
        assert_eq!(
            thp_eligible(during),
            Some(false),
            "a block during the pause"
        );
        // The budget is spent: huge pages again, cold or not.
        let spent = sys::map_with(size, Duration::MAX, long);
        assert_eq!(thp_eligible(spent), Some(thp_on), "a block past the budget");
        // With no budget at all, no probe: a slow fault changes nothing.
        sys::end_pause();
        sys::set_small_budget(0);
        let unprobed = sys::map_with(size, Duration::ZERO, long);
        assert!(sys::hinting(), "a probe with no budget");
        assert_eq!(
            thp_eligible(unprobed),
            Some(thp_on),
            "a block with no budget"
        );
        // A slow fault with a short pause: the hint is back once it ends.
        let short = Duration::from_millis(20);
        sys::end_pause();
        sys::set_small_budget(u64::MAX - 1);
        let last = sys::map_with(size, Duration::ZERO, short);
        assert_eq!(thp_eligible(last), Some(false), "a slow block, short pause");
        std::thread::sleep(2 * short);
        assert!(sys::hinting());
        let after = sys::map_with(size, Duration::MAX, COLD_PAUSE);
        assert_eq!(thp_eligible(after), Some(thp_on), "a block after the pause");
        sys::end_pause();
        sys::set_small_budget(u64::MAX);
        // The blocks are usable and zero, the probed pages too.
        for p in [before, slow, during, spent, unprobed, last, after] {
            unsafe {
                let s = std::slice::from_raw_parts_mut(p, size);
                assert!(s.iter().all(|&b| b == 0));
                s.fill(1);
                sys::unmap(p, size);
            }
        }
    }

    /// `/proc/buddyinfo` counts: every zone's blocks below the order
    /// asked, 4 KiB · 2^order each. Caught: the zone's name read as a
    /// count, and orders at or above the limit counted.
    #[cfg(target_os = "linux")]
    #[test]
    fn free_fragments_from_buddyinfo() {
        let text = b"Node 0, zone      DMA      0      0      0      0      0      0      0      0      1      1      3 \n\
Node 0, zone    DMA32      4      1      2      2      2      2      1      4      4      2    752 \n\
Node 0, zone   Normal   1934   1541   1487   1378    992    686    470    318    244    195    249 \n";
        let bytes = |counts: &[u64]| -> u64 {
            counts
                .iter()
                .enumerate()
                .map(|(o, &c)| c * (4096 << o))
                .sum()
        };
        let dma = [0, 0, 0, 0, 0, 0, 0, 0, 1];
        let dma32 = [4, 1, 2, 2, 2, 2, 1, 4, 4];
        let normal = [1934, 1541, 1487, 1378, 992, 686, 470, 318, 244];
        assert_eq!(sys::small_free_bytes(text, 1), 4096 * (4 + 1934));
        assert_eq!(
            sys::small_free_bytes(text, 9),
            bytes(&dma) + bytes(&dma32) + bytes(&normal)
        );
        assert_eq!(sys::small_free_bytes(b"", 9), 0);
    }

    /// The output's expected page cache comes off the small-page budget,
    /// down to nothing, and a smaller estimate later gives back what the
    /// reservation took beyond it, never more. Caught: the budget left
    /// unchanged, a reserve larger than the budget refused whole (the
    /// budget kept), a reservation counting what it asked for rather than
    /// what it took (a later shrink gives back more than it took), and a
    /// shrink giving nothing back.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_reserved_page_cache_shrinks_the_small_page_budget() {
        let _serial = SERIAL.lock().unwrap();
        const MIB: u64 = 1 << 20;
        sys::set_small_budget(10 * MIB);
        let small = reserve_page_cache(4 * MIB);
        assert_eq!(sys::small_budget_left(), 6 * MIB);
        let mut large = reserve_page_cache(100 * MIB);
        assert_eq!(sys::small_budget_left(), 0);
        assert_eq!(large.taken(), 6 * MIB, "only what was left");
        // Shrunk below what it took: the difference comes back.
        large.resize(2 * MIB);
        assert_eq!(
            (large.taken(), sys::small_budget_left()),
            (2 * MIB, 4 * MIB)
        );
        // Grown again: as much as is left.
        large.resize(50 * MIB);
        assert_eq!((large.taken(), sys::small_budget_left()), (6 * MIB, 0));
        // Shrunk while others hold the rest: back to what it took less the
        // new size, whatever it asked for before.
        large.resize(5 * MIB);
        assert_eq!(sys::small_budget_left(), MIB);
        large.resize(0);
        assert_eq!(sys::small_budget_left(), 6 * MIB);
        assert_eq!(small.taken(), 4 * MIB);
        sys::set_small_budget(u64::MAX);
    }

    /// A layout of `size` bytes, the alignment the crate's buffers have.
    #[cfg(target_os = "linux")]
    fn lay(size: usize) -> Layout {
        Layout::from_size_align(size, 8).unwrap()
    }

    /// The lock of the tests that use the cache, and a guard that keeps
    /// freed blocks.
    #[cfg(target_os = "linux")]
    fn serial_and_kept() -> (std::sync::MutexGuard<'static, ()>, KeepFreed) {
        let serial = SERIAL.lock().unwrap();
        (serial, KeepFreed::new())
    }

    /// Unmaps every kept block (tests empty the cache themselves rather
    /// than by a guard's drop: a build test running meanwhile may hold a
    /// guard of its own).
    #[cfg(target_os = "linux")]
    fn empty_cache() {
        while let Some((p, s)) = take(0) {
            // SAFETY: a kept block is a mapping nobody else holds.
            unsafe { sys::unmap(p, s) };
        }
    }

    /// Blocks and bytes the cache holds.
    #[cfg(target_os = "linux")]
    fn cached() -> (usize, usize) {
        let cache = CACHE.lock().unwrap();
        let held = cache.iter().filter(|c| c.1 > 0);
        (held.clone().count(), held.map(|c| c.1).sum())
    }

    /// Under a guard, a freed block comes back for the next large request,
    /// cut to size, grown, or whole, and `alloc_zeroed` never shows its old
    /// bytes; the cache keeps no more than its limits, nothing without a
    /// guard, and empties when the last guard drops. Caught: a reused block
    /// not zeroed, a grown block cut to its old length (the write at its end
    /// faults), and blocks kept with no guard.
    #[cfg(target_os = "linux")]
    #[test]
    fn freed_blocks_are_reused_and_zeroed_on_request() {
        let _serial = SERIAL.lock().unwrap();
        let a = HugePageAlloc;
        // Without a guard nothing is kept.
        unsafe { a.dealloc(a.alloc(lay(HUGE_MIN)), lay(HUGE_MIN)) };
        assert_eq!(cached(), (0, 0));
        let outer = KeepFreed::new();
        for (first, second) in [
            (3 * HUGE_MIN, 3 * HUGE_MIN),     // same span
            (5 * HUGE_MIN, 2 * HUGE_MIN + 1), // cut
            (HUGE_MIN, 6 * HUGE_MIN - 4),     // grown
        ] {
            unsafe {
                let p = a.alloc(lay(first));
                std::slice::from_raw_parts_mut(p, first).fill(0xab);
                a.dealloc(p, lay(first));
                assert_eq!(cached(), (1, span(first)));
                let q = a.alloc_zeroed(lay(second));
                // The block was taken; a cut keeps its tail.
                let tail = span(first).saturating_sub(span(second));
                assert_eq!(cached(), (usize::from(tail > 0), tail));
                if tail > 0 {
                    let (t, s) = take(0).unwrap();
                    assert_eq!((t as usize, s), (q as usize + span(second), tail));
                    // The tail is a mapping of its own: it can go alone.
                    sys::unmap(t, s);
                }
                let s = std::slice::from_raw_parts_mut(q, second);
                assert!(s.iter().all(|&b| b == 0), "{first} -> {second}");
                s.fill(1);
                a.dealloc(q, lay(second));
                // Not zeroed: usable to its end.
                let r = a.alloc(lay(second));
                *r.add(second - 1) = 2;
                a.dealloc(r, lay(second));
                let (p, s) = take(0).unwrap();
                sys::unmap(p, s);
            }
        }
        // Shrinking keeps the tail, which comes back whole and, on
        // request, zeroed; the shrunk block keeps its bytes and can grow
        // again.
        unsafe {
            let p = a.alloc(lay(6 * HUGE_MIN));
            std::slice::from_raw_parts_mut(p, 6 * HUGE_MIN).fill(9);
            let q = a.realloc(p, lay(6 * HUGE_MIN), 2 * HUGE_MIN);
            assert_eq!(q, p, "shrunk in place");
            assert_eq!(cached(), (1, 4 * HUGE_MIN));
            let t = a.alloc_zeroed(lay(4 * HUGE_MIN));
            assert_eq!(t as usize, p as usize + 2 * HUGE_MIN, "the tail came back");
            let tail = std::slice::from_raw_parts_mut(t, 4 * HUGE_MIN);
            assert!(tail.iter().all(|&b| b == 0));
            tail.fill(1);
            assert!(
                std::slice::from_raw_parts(q, 2 * HUGE_MIN)
                    .iter()
                    .all(|&b| b == 9)
            );
            let r = a.realloc(q, lay(2 * HUGE_MIN), 3 * HUGE_MIN);
            *r.add(3 * HUGE_MIN - 1) = 2;
            assert!(
                std::slice::from_raw_parts(t, 4 * HUGE_MIN)
                    .iter()
                    .all(|&b| b == 1)
            );
            a.dealloc(r, lay(3 * HUGE_MIN));
            a.dealloc(t, lay(4 * HUGE_MIN));
            empty_cache();
        }
        // Limits: at most CACHE_SLOTS blocks and CACHE_BYTES bytes.
        let big = CACHE_BYTES / 2 + HUGE_MIN;
        unsafe {
            let blocks: Vec<*mut u8> = (0..3).map(|_| a.alloc(lay(big))).collect();
            for &p in &blocks {
                a.dealloc(p, lay(big));
            }
            assert_eq!(cached(), (1, span(big)));
            let (p, s) = take(0).unwrap();
            sys::unmap(p, s);
        }
        // Slots: every other huge page of one mapping, so that no two of
        // the freed blocks touch (touching blocks are joined into one).
        let pieces = 2 * (CACHE_SLOTS + 2);
        let region = sys::map(pieces * HUGE_MIN);
        assert!(!region.is_null());
        unsafe {
            for i in (0..pieces).step_by(2) {
                keep_or_unmap(region.add(i * HUGE_MIN), HUGE_MIN);
            }
        }
        assert_eq!(cached(), (CACHE_SLOTS, CACHE_SLOTS * HUGE_MIN));
        // Guards nest: the kept blocks go when the last one drops.
        let inner = KeepFreed::new();
        drop(outer);
        assert_eq!(cached(), (CACHE_SLOTS, CACHE_SLOTS * HUGE_MIN));
        drop(inner);
        assert_eq!(cached(), (0, 0));
        unsafe {
            for i in (1..pieces).step_by(2) {
                sys::unmap(region.add(i * HUGE_MIN), HUGE_MIN);
            }
        }
    }

    /// Freed blocks that touch are kept as one: a block cut from a kept one
    /// comes back whole once freed, so freeing and asking again for the
    /// same sizes neither maps nor grows anything (before the joining, the
    /// pieces were grown back with fresh pages); pieces of a mapping freed
    /// out of order join up from both sides; a join that would pass
    /// [`CACHE_BYTES`] leaves the cache as it was. A block joined from two
    /// mappings goes to the front of a larger block asked for (moved in one
    /// `mremap` since Linux 6.17, else a huge page at a time, which is
    /// tested on its own), and is copied when grown by `realloc`. Caught:
    /// no joining (the counts), the join that passes the limit dropping its
    /// neighbours, the joined block left kept or unmapped (fresh zeros at
    /// the front), pieces moved a huge page at a time unmapped instead,
    /// and the grow without the copy (a null pointer).
    #[cfg(target_os = "linux")]
    #[test]
    fn freed_blocks_that_touch_are_kept_as_one() {
        let (_serial, keep) = serial_and_kept();
        let a = HugePageAlloc;
        unsafe {
            let p = a.alloc(lay(5 * HUGE_MIN));
            a.dealloc(p, lay(5 * HUGE_MIN));
            for size in [2 * HUGE_MIN, 3 * HUGE_MIN, HUGE_MIN + 1] {
                let q = a.alloc(lay(size));
                assert_eq!(q, p, "the kept block is cut, not mapped afresh");
                a.dealloc(q, lay(size));
                assert_eq!(
                    cached(),
                    (1, 5 * HUGE_MIN),
                    "{size}: the cut came back whole"
                );
            }
            let (q, s) = take(0).unwrap();
            sys::unmap(q, s);

            // Five pieces of one mapping, freed 0, 2, 1, 4, 3.
            let r = sys::map(5 * HUGE_MIN);
            let piece = |i: usize| r.add(i * HUGE_MIN);
            keep_or_unmap(piece(0), HUGE_MIN);
            keep_or_unmap(piece(2), HUGE_MIN);
            assert_eq!(cached(), (2, 2 * HUGE_MIN));
            keep_or_unmap(piece(1), HUGE_MIN);
            assert_eq!(cached(), (1, 3 * HUGE_MIN));
            keep_or_unmap(piece(4), HUGE_MIN);
            assert_eq!(cached(), (2, 4 * HUGE_MIN));
            keep_or_unmap(piece(3), HUGE_MIN);
            assert_eq!(cached(), (1, 5 * HUGE_MIN));
            assert_eq!(take(0), Some((r, 5 * HUGE_MIN)));

            // Over the limit: the neighbour stays kept, the block goes.
            let big = CACHE_BYTES - HUGE_MIN;
            let r = sys::map(big + 2 * HUGE_MIN);
            keep_or_unmap(r, big);
            keep_or_unmap(r.add(big), 2 * HUGE_MIN);
            assert_eq!(cached(), (1, big));
            assert_eq!(take(0), Some((r, big)));
            sys::unmap(r, big);

            // Two mappings side by side, as the kernel may place them: here
            // one mapping split in two by a different hint on each half.
            let r = sys::map(4 * HUGE_MIN);
            libc::madvise(r.cast(), 2 * HUGE_MIN, libc::MADV_NOHUGEPAGE);
            libc::madvise(
                r.add(2 * HUGE_MIN).cast(),
                2 * HUGE_MIN,
                libc::MADV_HUGEPAGE,
            );
            keep_or_unmap(r, 2 * HUGE_MIN);
            keep_or_unmap(r.add(2 * HUGE_MIN), 2 * HUGE_MIN);
            assert_eq!(cached(), (1, 4 * HUGE_MIN));
            // Asked for more than it holds, the joined block is moved to
            // the front of a new block, whose tail is fresh (freed here
            // directly, so that it cannot join anything).
            std::slice::from_raw_parts_mut(r, 4 * HUGE_MIN).fill(5);
            let f = a.alloc(lay(6 * HUGE_MIN));
            assert!(!f.is_null());
            assert_eq!(cached(), (0, 0), "the joined block was used");
            let front = std::slice::from_raw_parts(f, 6 * HUGE_MIN);
            assert!(front[..4 * HUGE_MIN].iter().all(|&b| b == 5));
            assert!(front[4 * HUGE_MIN..].iter().all(|&b| b == 0));
            sys::unmap(f, 6 * HUGE_MIN);
            // Two mappings moved a huge page at a time (what kernels
            // before 6.17 need for a block joined from two) arrive whole.
            let r = sys::map(4 * HUGE_MIN);
            std::slice::from_raw_parts_mut(r, 4 * HUGE_MIN).fill(5);
            libc::madvise(r.cast(), 2 * HUGE_MIN, libc::MADV_NOHUGEPAGE);
            let to = sys::reserve(4 * HUGE_MIN);
            sys::move_by_huge_pages(r, 4 * HUGE_MIN, to);
            let moved = std::slice::from_raw_parts(to, 4 * HUGE_MIN);
            assert!(moved.iter().all(|&b| b == 5), "moved whole");
            sys::unmap(to, 4 * HUGE_MIN);
            // Joined again, and asked for whole.
            let r = sys::map(4 * HUGE_MIN);
            libc::madvise(r.cast(), 2 * HUGE_MIN, libc::MADV_NOHUGEPAGE);
            keep_or_unmap(r, 2 * HUGE_MIN);
            keep_or_unmap(r.add(2 * HUGE_MIN), 2 * HUGE_MIN);
            assert_eq!(cached(), (1, 4 * HUGE_MIN));
            let q = a.alloc(lay(4 * HUGE_MIN));
            assert_eq!(q, r);
            let bytes = std::slice::from_raw_parts_mut(q, 4 * HUGE_MIN);
            for (i, b) in bytes.iter_mut().enumerate() {
                *b = i as u8;
            }
            let g = a.realloc(q, lay(4 * HUGE_MIN), 9 * HUGE_MIN);
            assert!(!g.is_null(), "grown across two mappings");
            let grown = std::slice::from_raw_parts_mut(g, 9 * HUGE_MIN);
            assert!(
                grown[..4 * HUGE_MIN]
                    .iter()
                    .enumerate()
                    .all(|(i, &b)| b == i as u8)
            );
            grown[9 * HUGE_MIN - 1] = 7;
            a.dealloc(g, lay(9 * HUGE_MIN));
            empty_cache();
        }
        drop(keep);
    }

    /// Kept blocks that touch nothing else, each too short for a request,
    /// are moved side by side to make its front, longest first, the last
    /// one cut; what the cache cannot cover is a fresh tail. Their bytes
    /// come along (page tables move, not bytes), or zeros on request, and
    /// the block is whole: freed, it comes back as one. Caught: the longest
    /// block grown with fresh pages instead (the other blocks left kept, and
    /// zeros where their bytes should be), pieces moved to the wrong place,
    /// the cut piece's tail lost, and `alloc_zeroed` clearing only the
    /// first piece.
    #[cfg(target_os = "linux")]
    #[test]
    fn short_kept_blocks_are_gathered_into_a_longer_one() {
        let (_serial, _keep) = serial_and_kept();
        let a = HugePageAlloc;
        // Pieces of 1, 2 and 3 huge pages with a page left out between
        // them (so that none joins another), bytes 1, 2 and 3.
        let kept = |sizes: &[usize]| unsafe {
            let region = sys::map(12 * HUGE_MIN);
            let mut at = 0;
            let mut pieces = Vec::new();
            for (i, &n) in sizes.iter().enumerate() {
                let p = region.add(at * HUGE_MIN);
                std::slice::from_raw_parts_mut(p, n * HUGE_MIN).fill(i as u8 + 1);
                pieces.push((p, n));
                at += n + 1;
            }
            sys::unmap(region.add(at * HUGE_MIN), (12 - at) * HUGE_MIN);
            for (i, &(p, n)) in pieces.iter().enumerate() {
                keep_or_unmap(p, n * HUGE_MIN);
                sys::unmap(p.add(n * HUGE_MIN), HUGE_MIN);
                assert_eq!(cached().0, i + 1);
            }
        };
        unsafe {
            kept(&[1, 2, 3]);
            let p = a.alloc(lay(5 * HUGE_MIN));
            // Three pages of the longest, two of the next; the shortest
            // stays kept.
            assert_eq!(cached(), (1, HUGE_MIN));
            let bytes = std::slice::from_raw_parts_mut(p, 5 * HUGE_MIN);
            for (page, want) in bytes.chunks(HUGE_MIN).zip([3, 3, 3, 2, 2]) {
                assert!(page.iter().all(|&b| b == want), "page of {want}");
            }
            bytes[5 * HUGE_MIN - 1] = 9;
            a.dealloc(p, lay(5 * HUGE_MIN));
            // (One block, or one joined with the kept page if the kernel
            // placed the new mapping beside it.)
            assert_eq!(cached().1, 6 * HUGE_MIN, "freed whole");
            empty_cache();

            // Longer than all of them: the front is theirs, the tail fresh;
            // the cut piece's tail is kept.
            kept(&[1, 2, 3]);
            let p = a.alloc_zeroed(lay(8 * HUGE_MIN - 5));
            assert_eq!(cached(), (0, 0));
            let bytes = std::slice::from_raw_parts(p, 8 * HUGE_MIN - 5);
            assert!(bytes.iter().all(|&b| b == 0), "zeroed throughout");
            a.dealloc(p, lay(8 * HUGE_MIN - 5));
            empty_cache();
            kept(&[2, 3]);
            let p = a.alloc(lay(4 * HUGE_MIN));
            assert_eq!(cached(), (1, HUGE_MIN), "the cut tail stays kept");
            let bytes = std::slice::from_raw_parts(p, 4 * HUGE_MIN);
            assert!(bytes[..3 * HUGE_MIN].iter().all(|&b| b == 2));
            assert!(bytes[3 * HUGE_MIN..].iter().all(|&b| b == 1));
            a.dealloc(p, lay(4 * HUGE_MIN));
            empty_cache();
        }
    }

    /// `vec_touching` builds only the front it is told of from kept memory
    /// and leaves the rest of the kept block for the next request; the
    /// hint does not outlive its vector. Caught: the hint ignored (the
    /// whole block taken), the hint left set for the next allocation, and
    /// the front rounded down instead of up (the last touched page fresh).
    #[cfg(target_os = "linux")]
    #[test]
    fn a_vector_touching_its_front_takes_only_that_front_kept() {
        let (_serial, _keep) = serial_and_kept();
        let a = HugePageAlloc;
        unsafe {
            let p = a.alloc(lay(8 * HUGE_MIN));
            std::slice::from_raw_parts_mut(p, 8 * HUGE_MIN).fill(7);
            a.dealloc(p, lay(8 * HUGE_MIN));
        }
        // With the global allocator of this test binary (not necessarily
        // ours), so through `HugePageAlloc` by hand: the hint is the
        // thread's, and a vector's allocation reads it.
        FRONT.with(|f| f.set(2 * HUGE_MIN - 100));
        let v = unsafe { a.alloc(lay(8 * HUGE_MIN)) };
        assert_eq!(FRONT.with(|f| f.get()), 0, "the hint is read once");
        assert_eq!(cached(), (1, 6 * HUGE_MIN), "only the front was taken");
        unsafe {
            let bytes = std::slice::from_raw_parts_mut(v, 8 * HUGE_MIN);
            assert!(bytes[..2 * HUGE_MIN].iter().all(|&b| b == 7));
            assert!(bytes[2 * HUGE_MIN..].iter().all(|&b| b == 0));
            let w = a.alloc(lay(6 * HUGE_MIN));
            assert_eq!(cached(), (0, 0), "the next request takes the rest");
            a.dealloc(w, lay(6 * HUGE_MIN));
            a.dealloc(v, lay(8 * HUGE_MIN));
            empty_cache();
        }
        // `vec_touching` clears the hint even when no large block reads it.
        let small: Vec<u8> = vec_touching(16, 8);
        assert!(small.capacity() >= 16);
        assert_eq!(FRONT.with(|f| f.get()), 0);
    }

    #[test]
    fn large_and_small_blocks_round_trip() {
        let _serial = SERIAL.lock().unwrap();
        let a = HugePageAlloc;
        for size in [16, HUGE_MIN - 1, HUGE_MIN, 3 * HUGE_MIN + 123] {
            let layout = Layout::from_size_align(size, 64).unwrap();
            unsafe {
                let p = a.alloc_zeroed(layout);
                assert!(!p.is_null());
                assert_eq!(p as usize % 64, 0);
                let s = std::slice::from_raw_parts_mut(p, size);
                assert!(s.iter().all(|&b| b == 0));
                s.fill(7);
                let q = a.realloc(p, layout, size * 2);
                let s = std::slice::from_raw_parts(q, size);
                assert!(s.iter().all(|&b| b == 7), "realloc kept the contents");
                a.dealloc(q, Layout::from_size_align(size * 2, 64).unwrap());
            }
        }
    }

    #[test]
    fn large_mappings_are_whole_huge_pages() {
        let _serial = SERIAL.lock().unwrap();
        assert_eq!(span(HUGE_MIN), HUGE_MIN);
        assert_eq!(span(HUGE_MIN + 1), 2 * HUGE_MIN);
        assert_eq!(span(7 * HUGE_MIN / 2), 4 * HUGE_MIN);
        // Resizing within one span, and across spans, keeps the contents
        // and the block usable up to its new size.
        let a = HugePageAlloc;
        let size = 5 * HUGE_MIN / 2;
        let layout = Layout::from_size_align(size, 8).unwrap();
        unsafe {
            let p = a.alloc(layout);
            assert!(!p.is_null());
            std::slice::from_raw_parts_mut(p, size).fill(3);
            let grown = 3 * HUGE_MIN - 8;
            let q = a.realloc(p, layout, grown);
            assert!(std::slice::from_raw_parts(q, size).iter().all(|&b| b == 3));
            std::slice::from_raw_parts_mut(q, grown)[size..].fill(4);
            let shrunk = HUGE_MIN + 100;
            let r = a.realloc(q, Layout::from_size_align(grown, 8).unwrap(), shrunk);
            assert!(
                std::slice::from_raw_parts(r, shrunk)
                    .iter()
                    .all(|&b| b == 3)
            );
            let big = 9 * HUGE_MIN + 1;
            let w = a.realloc(r, Layout::from_size_align(shrunk, 8).unwrap(), big);
            assert!(
                std::slice::from_raw_parts(w, shrunk)
                    .iter()
                    .all(|&b| b == 3)
            );
            std::slice::from_raw_parts_mut(w, big)[big - 1] = 5;
            a.dealloc(w, Layout::from_size_align(big, 8).unwrap());
        }
    }

    /// Buffers from a quarter of a huge page up to one are rounded up to a
    /// whole one, others keep their length; `zeroed_large` gives `n` zeros
    /// in the rounded buffer. Caught: rounding from `HUGE_MIN` instead of
    /// `ROUND_UP_FROM` (the dragon's 1.75 MB arrays kept their 4 KiB pages),
    /// and a capacity in bytes instead of elements.
    #[test]
    fn per_vertex_buffers_round_up_to_a_huge_page() {
        let quarter = ROUND_UP_FROM / 4;
        assert_eq!(large_capacity::<u32>(quarter - 1), quarter - 1);
        assert_eq!(large_capacity::<u32>(quarter), HUGE_MIN / 4);
        assert_eq!(large_capacity::<u32>(437_646), HUGE_MIN / 4);
        assert_eq!(large_capacity::<u16>(437_646), HUGE_MIN / 2);
        assert_eq!(large_capacity::<u32>(HUGE_MIN / 4), HUGE_MIN / 4);
        assert_eq!(large_capacity::<u32>(HUGE_MIN), HUGE_MIN);
        assert_eq!(large_capacity::<[f32; 3]>(100_000), HUGE_MIN.div_ceil(12));
        assert_eq!(large_capacity::<()>(usize::MAX), usize::MAX);
        let v = zeroed_large::<u32>(437_646);
        assert_eq!((v.len(), v.capacity()), (437_646, HUGE_MIN / 4));
        assert!(v.iter().all(|&x| x == 0));
    }

    /// Inside a scope the small blocks come from the arena and are reused
    /// by size; outside it, and on other threads, they do not; a block
    /// keeps its bytes across a reallocation; a reused block asked for
    /// zeroed is zero; and once every block is freed and the arena
    /// dropped, its touched chunks are one kept block, which the next large
    /// request gets whole. Caught: a reused block not zeroed, a
    /// reallocation across classes that lost bytes, and an arena that was
    /// never handed over (the kept block missing).
    #[cfg(target_os = "linux")]
    #[test]
    fn a_parsers_arena_serves_its_scope_and_becomes_a_kept_block() {
        let (_serial, keep) = serial_and_kept();
        let a = HugePageAlloc;
        assert_eq!(cached(), (0, 0));
        let ar = arena::open(64 << 20);
        let outside = unsafe { a.alloc(lay(100)) };
        assert!(!arena::owns(outside), "no scope, no arena");
        let mut blocks = ar.scope(|| unsafe {
            let mut v = Vec::new();
            for (i, size) in [16, 100, 4096, 100_000, arena::MAX_BLOCK]
                .into_iter()
                .enumerate()
            {
                let p = a.alloc(lay(size));
                assert!(arena::owns(p), "{size} bytes in the arena");
                std::slice::from_raw_parts_mut(p, size).fill(i as u8 + 1);
                v.push((p, size));
            }
            // Larger than the arena serves: malloc's or a mapping's.
            let big = a.alloc(lay(arena::MAX_BLOCK + 1));
            assert!(!arena::owns(big));
            a.dealloc(big, lay(arena::MAX_BLOCK + 1));
            // Another thread's allocations are its own.
            let p = std::thread::scope(|s| s.spawn(|| a.alloc(lay(100)) as usize).join());
            let p = p.unwrap() as *mut u8;
            assert!(!arena::owns(p));
            a.dealloc(p, lay(100));
            // A freed block comes back for a request of its class, and
            // zeroed when asked.
            let (p, size) = v.remove(1);
            a.dealloc(p, lay(size));
            let q = a.alloc_zeroed(lay(120));
            assert_eq!(q, p, "reused");
            assert!(std::slice::from_raw_parts(q, 120).iter().all(|&b| b == 0));
            v.push((q, 120));
            // Within its class a block stays; across, it moves with its
            // bytes, into the arena or, from HUGE_MIN on, a mapping.
            let (p, size) = v.remove(0); // the 16 bytes of 1s
            assert_eq!(a.realloc(p, lay(size), 12), p);
            v.push((p, 12));
            let (p, size) = v.remove(1); // the 100,000 bytes of 4s
            let q = a.realloc(p, lay(size), 200_000);
            assert!(q != p && arena::owns(q));
            assert!(std::slice::from_raw_parts(q, size).iter().all(|&b| b == 4));
            let r = a.realloc(q, lay(200_000), HUGE_MIN);
            assert!(!arena::owns(r));
            assert!(std::slice::from_raw_parts(r, size).iter().all(|&b| b == 4));
            a.dealloc(r, lay(HUGE_MIN));
            v
        });
        // Out of the scope: malloc's again.
        let after = unsafe { a.alloc(lay(100)) };
        assert!(!arena::owns(after));
        unsafe {
            a.dealloc(after, lay(100));
            a.dealloc(outside, lay(100));
        }
        // The large block freed above is kept; set it aside.
        let (kept, bytes) = cached();
        assert_eq!((kept, bytes), (1, HUGE_MIN));
        let (p, s) = take(0).unwrap();
        unsafe { sys::unmap(p, s) };
        for (p, size) in blocks.drain(..) {
            unsafe { a.dealloc(p, lay(size)) };
        }
        drop(ar);
        // 16 + 128 + 4 KiB + 128 KiB + 1 MiB + 256 KiB touched: one chunk.
        assert_eq!(cached(), (1, arena::CHUNK));
        let (p, s) = take(0).unwrap();
        // SAFETY: the kept block is ours.
        unsafe { keep_or_unmap(p, s) };
        let q = unsafe { a.alloc(lay(arena::CHUNK)) };
        assert_eq!(q, p, "the next large request gets the arena's chunk");
        unsafe { a.dealloc(q, lay(arena::CHUNK)) };
        drop(keep);
        assert_eq!(cached(), (0, 0));
    }

    /// A block still live when the arena is dropped holds its chunk (and a
    /// new arena stays inert) until it is freed; the other chunks are kept
    /// at once, and the held one joins them when its block goes, whichever
    /// thread frees it. Caught: a chunk handed over under a live block (its
    /// bytes then belong to a large block too), and a late free that never
    /// released its chunk.
    #[cfg(target_os = "linux")]
    #[test]
    fn a_block_live_at_an_arenas_close_holds_its_chunk_until_freed() {
        let (_serial, keep) = serial_and_kept();
        let a = HugePageAlloc;
        let ar = arena::open(64 << 20);
        // A small block, then six blocks of 1 MiB over four chunks.
        let (survivor, rest) = ar.scope(|| unsafe {
            let s = a.alloc(lay(64));
            let rest: Vec<*mut u8> = (0..6).map(|_| a.alloc(lay(arena::MAX_BLOCK))).collect();
            (s, rest)
        });
        for p in rest {
            unsafe { a.dealloc(p, lay(arena::MAX_BLOCK)) };
        }
        unsafe { survivor.write_bytes(9, 64) };
        drop(ar);
        // Chunk 0 holds the survivor and the first 1 MiB block (the second
        // did not fit); chunks 1 to 3, the other five blocks, were freed.
        assert!(arena::owns(survivor));
        let base = survivor as usize;
        assert_eq!(cached(), (1, 3 * arena::CHUNK));
        // While the chunk is held, no new arena.
        let inert = arena::open(64 << 20);
        let p = inert.scope(|| unsafe { a.alloc(lay(64)) });
        assert!(!arena::owns(p));
        unsafe { a.dealloc(p, lay(64)) };
        drop(inert);
        assert!(
            unsafe { std::slice::from_raw_parts(survivor, 64) }
                .iter()
                .all(|&b| b == 9)
        );
        // Freed on another thread: the chunk goes, joined with the others.
        let s = survivor as usize;
        std::thread::scope(|t| {
            t.spawn(|| unsafe { a.dealloc(s as *mut u8, lay(64)) });
        });
        assert!(!arena::owns(survivor));
        assert_eq!(cached(), (1, 4 * arena::CHUNK));
        let (p, _) = take(0).unwrap();
        assert_eq!(p as usize, base);
        unsafe { sys::unmap(p, 4 * arena::CHUNK) };
        // And a new arena works again.
        let again = arena::open(64 << 20);
        let p = again.scope(|| unsafe { a.alloc(lay(64)) });
        assert!(arena::owns(p));
        unsafe { a.dealloc(p, lay(64)) };
        drop(again);
        drop(keep);
        assert_eq!(cached(), (0, 0));
    }

    /// Scopes of one arena on two threads (the OBJ loader's two readers)
    /// make it two owners: each gets blocks in chunks of its own and
    /// reuses the blocks it frees itself, not one the other owner frees;
    /// a third thread's scope allocates as usual; and once every block is
    /// freed and the arena dropped, both owners' chunks are one kept block.
    /// Caught: one owner only (the second thread's blocks were malloc's),
    /// a block freed onto the freeing thread's lists whoever's chunk it is
    /// in (reused by the wrong owner), and a chunk's count read from the
    /// first owner's lists (the second owner's chunk never handed over).
    #[cfg(target_os = "linux")]
    #[test]
    fn an_arenas_two_owners_each_reuse_their_own_blocks() {
        let (_serial, keep) = serial_and_kept();
        let a = HugePageAlloc;
        assert_eq!(cached(), (0, 0));
        let ar = arena::open(64 << 20);
        let chunk = |p: usize| p / arena::CHUNK;
        let (p0, r, q1) = ar.scope(|| unsafe {
            let p0 = a.alloc(lay(100)) as usize;
            assert!(arena::owns(p0 as *mut u8));
            let (q1, x1) = std::thread::scope(|s| {
                s.spawn(|| {
                    ar.scope(|| {
                        let p1 = a.alloc(lay(100));
                        assert!(arena::owns(p1), "the second owner's block");
                        assert_ne!(chunk(p1 as usize), chunk(p0), "a chunk of its own");
                        a.dealloc(p1, lay(100));
                        let q1 = a.alloc(lay(100));
                        assert_eq!(q1, p1, "its own free reused");
                        // A third thread's scope, while this one lives
                        // (a thread's id is the address of a thread
                        // local, which a later thread may get again): no
                        // place left.
                        std::thread::scope(|s| {
                            s.spawn(|| {
                                ar.scope(|| {
                                    let p = a.alloc(lay(100));
                                    assert!(!arena::owns(p), "a third thread's block");
                                    a.dealloc(p, lay(100));
                                })
                            });
                        });
                        (q1 as usize, a.alloc(lay(100)) as usize)
                    })
                })
                .join()
                .unwrap()
            });
            // The second owner's block freed here is not reused here.
            a.dealloc(x1 as *mut u8, lay(100));
            let r = a.alloc(lay(100)) as usize;
            assert!(
                r != x1 && chunk(r) == chunk(p0),
                "the first owner's own block"
            );
            (p0, r, q1)
        });
        for p in [p0, r, q1] {
            unsafe { a.dealloc(p as *mut u8, lay(100)) };
        }
        drop(ar);
        assert_eq!(cached(), (1, 2 * arena::CHUNK));
        empty_cache();
        drop(keep);
    }
}
