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
//! Small blocks go to [`std::alloc::System`] unchanged. Blocks of at least
//! [`HUGE_MIN`] bytes get an anonymous mapping of their own, a whole number
//! of huge pages long, with an `madvise(MADV_HUGEPAGE)` hint. The hint never changes what the program
//! computes, and a kernel without THP ignores it. On other systems the
//! allocator is exactly `System`.
//!
//! The `svpack` binary and the benchmarks install it with
//! `#[global_allocator]`; library users choose their own allocator.

use std::alloc::{GlobalAlloc, Layout, System};

/// Allocations of at least this many bytes get their own huge-page mapping:
/// one huge page (2 MiB on x86-64) is the smallest range the hint can help.
pub const HUGE_MIN: usize = 2 << 20;

/// Large blocks' alignment limit: `mmap` returns page-aligned memory.
const PAGE: usize = 4096;

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
/// first touches were small-page faults (README, "Eighth round"). The cost
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
    /// A fresh zeroed mapping of `size` bytes with the huge-page hint, or null.
    pub fn map(size: usize) -> *mut u8 {
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
            return std::ptr::null_mut();
        }
        advise(p, size);
        p.cast()
    }

    /// The hint only changes how later faults are served; a kernel without
    /// THP rejects it, which is harmless, so the result is not checked.
    pub fn advise(p: *mut libc::c_void, size: usize) {
        // SAFETY: `p..p + size` is a mapping this allocator owns.
        unsafe { libc::madvise(p, size, libc::MADV_HUGEPAGE) };
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
        advise(q, new);
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

// SAFETY: small blocks are System's; large blocks are whole mappings, which
// are page-aligned (so every alignment up to PAGE holds) and zeroed, and are
// only ever released or resized here (`is_large` of the layout the caller
// passes back decides which kind a block is, and the GlobalAlloc contract
// says that is the layout it was allocated with).
unsafe impl GlobalAlloc for HugePageAlloc {
    #[inline]
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if is_large(layout.size(), layout.align()) {
            sys::map(span(layout.size()))
        } else {
            // SAFETY: the caller's contract.
            unsafe { System.alloc(layout) }
        }
    }

    #[inline]
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if is_large(layout.size(), layout.align()) {
            // Fresh anonymous mappings are zero.
            sys::map(span(layout.size()))
        } else {
            // SAFETY: the caller's contract.
            unsafe { System.alloc_zeroed(layout) }
        }
    }

    #[inline]
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if is_large(layout.size(), layout.align()) {
            // SAFETY: large blocks are mappings of exactly this size.
            unsafe { sys::unmap(ptr, span(layout.size())) }
        } else {
            // SAFETY: the caller's contract.
            unsafe { System.dealloc(ptr, layout) }
        }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let align = layout.align();
        match (is_large(layout.size(), align), is_large(new_size, align)) {
            // SAFETY: a mapping of exactly `layout.size()` bytes.
            (true, true) => unsafe { sys::remap(ptr, span(layout.size()), span(new_size)) },
            // SAFETY: the caller's contract.
            (false, false) => unsafe { System.realloc(ptr, layout, new_size) },
            _ => {
                // Crossing HUGE_MIN: move between the two kinds of block.
                // SAFETY: the caller guarantees a valid size for `align`.
                let new_layout = unsafe { Layout::from_size_align_unchecked(new_size, align) };
                // SAFETY: non-zero size (at least one side is large).
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

    #[test]
    fn large_and_small_blocks_round_trip() {
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
}
