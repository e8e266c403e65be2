//! A parser's small blocks in an arena of our own, whose memory becomes one
//! kept large block once they are all freed, so that the weld, right after
//! the parse, reuses pages the parse touched instead of faulting in fresh
//! ones.
//!
//! Why: tobj parses an OBJ into many small blocks of malloc's (a `String`
//! per line, each object's vertices and indices, its index map). glibc puts
//! them in a thread arena's heaps and unmaps those heaps when they are
//! freed, at the end of the load, and the weld then maps as much fresh
//! memory again: on the 5M-triangle scene the weld, one thread, took
//! 165–263 ms in single builds and 72–80 ms in a batch's second build of
//! the same file, whose blocks came from the kept blocks of the first
//! (`svpack build a.obj b.obj --jobs 1 --threads 1 --timings --json`, three
//! batches; in a profile of a single build 72% of the weld's samples were
//! the kernel zeroing fresh pages, benches/ROUNDS.md, Fifty-fourth round).
//! The host backs fresh memory slowly (see the parent module); the
//! parse's pages were touched a moment ago. With the arena, standalone
//! builds of the 5M scene (`python3 benches/compare_binaries.py --rest 3
//! --threads 1,2 OLD NEW target/targets/scene_5000000.obj 8`): the weld
//! 242.3 → 74.9 ms at the median with one thread, 55.4 → 42.9 with two;
//! the peak memory 344.1 → 326.4 and 392.0 → 326.3 MiB; the load within
//! the noise.
//!
//! How: while [`Arena::scope`] runs on a thread, that thread's small
//! allocations (at most [`MAX_BLOCK`] bytes, alignment at most 16) come
//! from a reserved range: each size rounded up to a power of two, freed
//! blocks on a list per size (popped first), fresh ones from a bump pointer
//! in a chunk of the range the thread took (the next one, when its chunk
//! is full). The sizes tobj asks for repeat (a line's `String`, an object's
//! buffers), so the lists serve most of its churn and the range stays near
//! what is live at once. Up to [`OWNERS`] threads run scopes of one arena
//! (the OBJ loader's two readers of a split text), each with lists of its
//! own (the owners); a block is reused only when its chunk's owner frees
//! it, and one freed on another thread is counted and not reused. Why two:
//! with one owner, the second reader's blocks were malloc's, unmapped at
//! the end of the load, and a two-thread build of the 5M scene then
//! faulted in 34 MiB of fresh huge pages in its weld that a one-thread
//! build took from the kept blocks (an allocation log); with two owners,
//! its fresh huge pages 138 → 92 MiB, as with one thread (94), those after
//! the load 50 → 4 MiB (`python3 benches/fresh_pages.py --by-stage BIN
//! build target/targets/scene_5000000.obj -o OUT --threads 2`, two runs
//! each, benches/ROUNDS.md, Sixty-sixth round). When
//! the [`Arena`] is dropped, the touched part of the range goes to the
//! allocator's `keep_or_unmap` (kept while a [`super::KeepFreed`] guard
//! lives) by runs of [`CHUNK`]s none of whose blocks is still live, and
//! the rest of the range is unmapped. A chunk that still holds a live block stays
//! the arena's until its last block is freed (a block a scope made for a
//! process-wide static would hold its chunk for good: the OBJ loader makes
//! tobj's before its first scope, `load::obj`'s `warm_up_tobj`). One
//! arena exists at a time; a parse that finds it taken (a batch parsing two
//! inputs at once, or a parse while an earlier one's chunk is held) uses
//! malloc as before.
//!
//! The arena never changes what the program computes: the same bytes are
//! stored wherever the blocks live.

use std::cell::{Cell, UnsafeCell};
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, AtomicUsize, Ordering::*};

/// Largest block the arena serves; larger ones go to malloc or, from
/// [`super::HUGE_MIN`] on, to mappings of their own.
pub const MAX_BLOCK: usize = 1 << 20;

/// The unit in which the range is handed over (a huge page, the unit of
/// the large blocks made from it). No block crosses a chunk's end.
pub const CHUNK: usize = super::HUGE_MIN;

/// Most chunks an arena spans: 8 GiB of address space.
const MAX_CHUNKS: usize = 4096;

/// log2 of the smallest block (a free block holds the list's link).
const MIN_SHIFT: u32 = 4;

/// Size classes: 16 bytes to [`MAX_BLOCK`], powers of two.
const CLASSES: usize = (MAX_BLOCK.trailing_zeros() - MIN_SHIFT + 1) as usize;

/// Most threads that run scopes of one arena (see the module
/// documentation).
pub const OWNERS: usize = 2;

/// An owner's state: one free list per class (each free block's first
/// word is the next one's address, 0 ends a list), the bump pointer with
/// the end of the owner's current chunk (both 0 before its first chunk;
/// `full` once the range has no chunk left for it), and per chunk it took
/// the blocks handed out less those it freed.
///
/// Aligned so that two owners' lists share no cache line: each owner writes
/// its own on every allocation and free. Without it (and with the chunks'
/// counts in one array for both), the 5M scene's two-thread load took
/// 1351.4 / 1501.1 ms against 1150.2 / 1256.8 with one owner (fastest /
/// median of 14 alternations, `python3 benches/compare_binaries.py
/// --threads 2 OLD NEW target/targets/scene_5000000.obj 14`); aligned,
/// 1157.6 / 1264.8 against 1149.0 / 1251.5.
#[repr(C, align(128))]
struct Lists {
    free: [usize; CLASSES],
    bump: usize,
    end: usize,
    full: bool,
    held: [u32; MAX_CHUNKS],
}

/// [`Lists`] behind a cell that only its owner thread touches while the
/// arena is open (see [`owner_lists`]); read by others once it is closed.
struct OwnerOnly(UnsafeCell<Lists>);

// SAFETY: while the arena is open only an owner reads or writes its lists
// (each owner's place is taken once, by `Arena::scope`'s compare-exchange);
// once it is closed nobody writes them, and the close's `SeqCst` store
// orders the owners' writes before every later read; `open` resets them
// while no arena exists, so no scope runs.
unsafe impl Sync for OwnerOnly {}

static LISTS: [OwnerOnly; OWNERS] = [const {
    OwnerOnly(UnsafeCell::new(Lists {
        free: [0; CLASSES],
        bump: 0,
        end: 0,
        full: false,
        held: [0; MAX_CHUNKS],
    }))
}; OWNERS];

/// The reserved range, `BASE..END` (both 0 without an arena); `BASE` is
/// chunk-aligned.
static BASE: AtomicUsize = AtomicUsize::new(0);
static END: AtomicUsize = AtomicUsize::new(0);
/// Per chunk: it is the arena's (its small blocks are the arena's blocks).
static LIVE: [AtomicBool; MAX_CHUNKS] = [const { AtomicBool::new(false) }; MAX_CHUNKS];
/// Per chunk: blocks freed by other threads, or by anyone after the close.
static FREED_ELSEWHERE: [AtomicU32; MAX_CHUNKS] = [const { AtomicU32::new(0) }; MAX_CHUNKS];
/// Per chunk: the owner that took it (its place in [`OWNER`]).
static CHUNK_OWNER: [AtomicU8; MAX_CHUNKS] = [const { AtomicU8::new(0) }; MAX_CHUNKS];
/// The next chunk no owner has taken.
static NEXT: AtomicUsize = AtomicUsize::new(0);
/// Bytes handed to the allocator's `keep_or_unmap` by every arena so far.
static HANDED_OVER: AtomicUsize = AtomicUsize::new(0);
/// Chunks still the arena's after the close.
static HELD_CHUNKS: AtomicUsize = AtomicUsize::new(0);
/// An arena exists (from [`open`] until its last chunk is handed over).
static TAKEN: AtomicBool = AtomicBool::new(false);
/// The owner threads' ids ([`thread_id`]), 0 for a place no scope took.
static OWNER: [AtomicUsize; OWNERS] = [const { AtomicUsize::new(0) }; OWNERS];
/// The [`Arena`] was dropped: no block is handed out any more.
static CLOSED: AtomicBool = AtomicBool::new(false);

thread_local! {
    /// This thread allocates from the arena (inside [`Arena::scope`]): its
    /// place in [`OWNER`] plus one, 0 outside a scope.
    static ACTIVE: Cell<usize> = const { Cell::new(0) };
    /// A byte whose address names this thread.
    static ID: u8 = const { 0 };
}

/// This thread's id: the address of its [`ID`], never 0.
fn thread_id() -> usize {
    ID.with(|id| id as *const u8 as usize)
}

/// The block size of a request of `size` bytes.
#[inline]
fn class_size(size: usize) -> usize {
    size.max(1 << MIN_SHIFT).next_power_of_two()
}

#[inline]
fn class_index(block: usize) -> usize {
    (block.trailing_zeros() - MIN_SHIFT) as usize
}

/// Owner `k`'s lists.
///
/// # Safety
/// Only owner `k`'s thread may call it, while the arena is open, and hold
/// one reference at a time (or `open`, while no arena exists).
#[allow(clippy::mut_from_ref)]
unsafe fn owner_lists(k: usize) -> &'static mut Lists {
    // SAFETY: the caller's.
    unsafe { &mut *LISTS[k].0.get() }
}

/// Chunk `c`'s blocks handed out less those its owner freed, once the
/// arena is closed.
fn held(c: usize) -> u32 {
    let k = CHUNK_OWNER[c].load(Relaxed) as usize;
    // SAFETY: read once the arena is closed, when nobody writes the lists.
    unsafe { (*LISTS[k].0.get()).held[c] }
}

/// Whether `p` is in one of the arena's chunks (then a small block at `p`
/// is the arena's: nothing else is placed in its range while it is
/// reserved, and a chunk handed over stops being the arena's first).
#[inline]
pub(super) fn owns(p: *mut u8) -> bool {
    let (p, base) = (p as usize, BASE.load(Acquire));
    p >= base && p < END.load(Acquire) && LIVE[(p - base) / CHUNK].load(Acquire)
}

/// Whether a block of `size` bytes reallocated to `new_size` stays where
/// it is (the same class).
#[inline]
pub(super) fn same_block(size: usize, new_size: usize) -> bool {
    new_size <= MAX_BLOCK && class_size(size) == class_size(new_size)
}

/// A block of `size` bytes (alignment `align`) from the arena when this
/// thread is inside a scope and the arena can serve it, else null. With
/// `zeroed`, its first `size` bytes are zero.
#[inline]
pub(super) fn alloc(size: usize, align: usize, zeroed: bool) -> *mut u8 {
    let k = ACTIVE.with(|a| a.get());
    if k == 0 || size > MAX_BLOCK || align > 16 {
        return std::ptr::null_mut();
    }
    let k = k - 1;
    let block = class_size(size);
    let base = BASE.load(Relaxed);
    // SAFETY: a thread is active only inside a scope of its own, as owner
    // `k` of the open arena (`Arena::scope`).
    let lists = unsafe { owner_lists(k) };
    let head = &mut lists.free[class_index(block)];
    let p = if *head != 0 {
        let p = *head;
        // SAFETY: a listed block is a freed block of this class, whose
        // first word holds the next one's address.
        *head = unsafe { (p as *const usize).read() };
        if zeroed {
            // SAFETY: the block is `block >= size` bytes and ours.
            unsafe { std::ptr::write_bytes(p as *mut u8, 0, size) };
        }
        p
    } else {
        if lists.bump + block > lists.end {
            // The owner's next chunk (no block crosses a chunk's end: the
            // rest of the last one stays untouched).
            if lists.full {
                return std::ptr::null_mut();
            }
            let c = NEXT.fetch_add(1, Relaxed);
            if base + (c + 1) * CHUNK > END.load(Relaxed) {
                lists.full = true;
                return std::ptr::null_mut();
            }
            CHUNK_OWNER[c].store(k as u8, Relaxed);
            LIVE[c].store(true, Release);
            lists.bump = base + c * CHUNK;
            lists.end = lists.bump + CHUNK;
        }
        let p = lists.bump;
        lists.bump += block;
        // Never handed out before: a fresh mapping's zeros.
        p
    };
    lists.held[(p - base) / CHUNK] += 1;
    p as *mut u8
}

/// Frees the arena's block `p` of `size` bytes (as allocated).
///
/// # Safety
/// `p` must be a live block of the arena ([`owns`]) of that size.
pub(super) unsafe fn dealloc(p: *mut u8, size: usize) {
    let chunk = (p as usize - BASE.load(Acquire)) / CHUNK;
    // (The block was handed to this thread after its chunk was taken.)
    let k = CHUNK_OWNER[chunk].load(Relaxed) as usize;
    if !CLOSED.load(SeqCst) && OWNER[k].load(Relaxed) == thread_id() {
        // SAFETY: the open arena's owner `k` (see `alloc`).
        let lists = unsafe { owner_lists(k) };
        let head = &mut lists.free[class_index(class_size(size))];
        // SAFETY: the block is at least a word and ours.
        unsafe { (p as *mut usize).write(*head) };
        *head = p as usize;
        lists.held[chunk] -= 1;
        return;
    }
    // Another thread's free, or one after the close: counted, not reused.
    let freed = FREED_ELSEWHERE[chunk].fetch_add(1, SeqCst) + 1;
    if CLOSED.load(SeqCst) && freed == held(chunk) {
        release(chunk..chunk + 1);
    }
}

/// Hands chunks of `chunks` that hold no live block to the kept blocks
/// (or unmaps them), in runs of chunks in a row, each chunk once (whoever
/// takes it first from [`LIVE`]); the last chunk to go ends the arena.
/// Only after the close, when the per-chunk counts are final.
fn release(chunks: std::ops::Range<usize>) {
    let base = BASE.load(Acquire);
    let free = |c: usize| held(c) == FREED_ELSEWHERE[c].load(SeqCst);
    let mut taken = 0;
    let mut run = chunks.start..chunks.start;
    for c in chunks.clone().chain([chunks.end]) {
        if c < chunks.end && free(c) && LIVE[c].swap(false, AcqRel) {
            if run.is_empty() {
                run = c..c;
            }
            run.end = c + 1;
            taken += 1;
            continue;
        }
        if !run.is_empty() {
            // SAFETY: the run lies in the arena's mapping, holds no live
            // block, and was taken from `LIVE` by this call alone.
            unsafe {
                super::keep_or_unmap((base + run.start * CHUNK) as *mut u8, run.len() * CHUNK)
            };
            HANDED_OVER.fetch_add(run.len() * CHUNK, Relaxed);
            run = c..c;
        }
    }
    if taken > 0 && HELD_CHUNKS.fetch_sub(taken, AcqRel) == taken {
        end();
    }
}

/// Ends the arena once no chunk is its: out of the range first (a small
/// block malloc later places where the range was must not look like the
/// arena's), then free for the next [`open`].
fn end() {
    BASE.store(0, Release);
    END.store(0, Release);
    TAKEN.store(false, Release);
}

/// Bytes of arena chunks handed over so far in this process (to the kept
/// blocks while a [`super::KeepFreed`] guard lived, else unmapped): a
/// parse whose arena is handed over adds the chunks it touched.
pub fn handed_over() -> usize {
    HANDED_OVER.load(Relaxed)
}

/// A parser's arena (see the module documentation): reserved by [`open`],
/// used by [`Arena::scope`], handed over when dropped.
#[must_use = "the arena is handed over when this is dropped"]
#[derive(Debug)]
pub struct Arena {
    /// This value reserved the arena (and closes it on drop).
    reserved: bool,
    /// The mapping as `mmap` returned it, and its length.
    mapping: (usize, usize),
}

/// Reserves an arena of `capacity` bytes of address space (at most 8 GiB;
/// nothing is faulted in until used) for the next [`Arena::scope`]. The
/// arena does nothing when another one exists, on systems other than
/// Linux, or when the reservation fails: scopes then allocate as usual.
pub fn open(capacity: usize) -> Arena {
    let none = Arena {
        reserved: false,
        mapping: (0, 0),
    };
    if !cfg!(target_os = "linux") || capacity == 0 || TAKEN.swap(true, AcqRel) {
        return none;
    }
    // Whole chunks, and one more to align the base, so that the runs handed
    // over are the size of the large blocks made from them.
    let len = capacity
        .min((MAX_CHUNKS - 1) * CHUNK)
        .next_multiple_of(CHUNK)
        + CHUNK;
    #[cfg(target_os = "linux")]
    // SAFETY: an anonymous private mapping has no preconditions.
    let p = unsafe {
        libc::mmap(
            std::ptr::null_mut(),
            len,
            libc::PROT_READ | libc::PROT_WRITE,
            libc::MAP_PRIVATE | libc::MAP_ANONYMOUS | libc::MAP_NORESERVE,
            -1,
            0,
        )
    };
    #[cfg(target_os = "linux")]
    if p == libc::MAP_FAILED {
        TAKEN.store(false, Release);
        return none;
    }
    #[cfg(not(target_os = "linux"))]
    let p = std::ptr::null_mut::<u8>();
    let base = (p as usize).next_multiple_of(CHUNK);
    for (k, owner) in OWNER.iter().enumerate() {
        // SAFETY: the arena was not taken, so no scope runs and nobody
        // else touches the lists; every chunk of the last arena was
        // handed over.
        let lists = unsafe { owner_lists(k) };
        (lists.free, lists.bump, lists.end, lists.full) = ([0; CLASSES], 0, 0, false);
        lists.held.fill(0);
        owner.store(0, Relaxed);
    }
    for f in &FREED_ELSEWHERE {
        f.store(0, Relaxed);
    }
    NEXT.store(0, Relaxed);
    CLOSED.store(false, SeqCst);
    END.store(p as usize + len, Release);
    BASE.store(base, Release);
    Arena {
        reserved: true,
        mapping: (p as usize, len),
    }
}

impl Arena {
    /// Runs `work` with this thread's small allocations in the arena (see
    /// the module documentation). The first [`OWNERS`] threads to run a
    /// scope own the arena, each its own place; on any other thread, or
    /// without an arena, `work` allocates as usual.
    pub fn scope<T>(&self, work: impl FnOnce() -> T) -> T {
        if !self.reserved || ACTIVE.with(|a| a.get()) != 0 {
            return work();
        }
        // This thread's place: one it took before, else the first free
        // one (places are taken in order and kept until the next arena).
        let me = thread_id();
        let place =
            (0..OWNERS).find(
                |&k| match OWNER[k].compare_exchange(0, me, AcqRel, Acquire) {
                    Ok(_) => true,
                    Err(o) => o == me,
                },
            );
        let Some(k) = place else {
            return work();
        };
        /// Ends the scope, also when `work` panics.
        struct Active;
        impl Drop for Active {
            fn drop(&mut self) {
                ACTIVE.with(|a| a.set(0));
            }
        }
        ACTIVE.with(|a| a.set(k + 1));
        let _active = Active;
        work()
    }
}

impl Drop for Arena {
    fn drop(&mut self) {
        if !self.reserved {
            return;
        }
        let base = BASE.load(Acquire);
        // The scopes borrowed this value, so they have ended; the owners'
        // writes happened before this drop (on its thread, or before the
        // join of theirs). The chunks taken are the first `used`.
        let chunks = (END.load(Acquire) - base) / CHUNK;
        let used = NEXT.load(Acquire).min(chunks);
        let live = (0..used).filter(|&c| LIVE[c].load(Acquire)).count();
        HELD_CHUNKS.store(live, SeqCst);
        CLOSED.store(true, SeqCst);
        // The head before the base and the tail past the touched chunks were
        // never handed out.
        let (mapped, len) = self.mapping;
        let touched = base + used * CHUNK;
        // SAFETY: parts of the arena's own mapping that hold no block.
        unsafe {
            if base > mapped {
                super::sys::unmap(mapped as *mut u8, base - mapped);
            }
            if mapped + len > touched {
                super::sys::unmap(touched as *mut u8, mapped + len - touched);
            }
        }
        if live == 0 {
            end();
            return;
        }
        release(0..used);
    }
}
