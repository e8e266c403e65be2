//! CPU hints shared by the hot loops.

/// Hints the CPU that `p` will be read soon. For loops that read a table
/// larger than L2 at scattered places known a few iterations ahead (the
/// corner positions of the layout): without it they wait for one cache miss
/// after another. Measure before adding one: in the evaluator's gather of
/// triangle signs (a table that mostly fits in L2) it made things slower.
#[inline(always)]
pub(crate) fn prefetch<T>(p: &T) {
    prefetch_ptr(p as *const T)
}

/// [`prefetch`] of both ends of `*p`: a 12-byte position straddles two
/// cache lines once in eight, and a prefetch of its start fetches only
/// the first. The layout's fills on the 5M scene (30 MB of positions),
/// one thread, each unit written, fastest of 6: sides 45.2–45.9 →
/// 41.8–42.5 ms, caps from the welded mesh 39.7–41.0 → 32.9–33.0 ms; the
/// dragon's (5 MB, mostly in L3) unchanged (`stage_probe -- fill-write`,
/// two and three alternations).
#[inline(always)]
pub(crate) fn prefetch_whole<T>(p: &T) {
    let start = p as *const T as *const u8;
    prefetch_ptr(start);
    prefetch_ptr(start.wrapping_add(std::mem::size_of::<T>() - 1));
}

/// [`prefetch`] of an address that need not be valid (it is never read):
/// for a hint computed from values that may be stale, such as a slot one
/// past the end of a buffer.
#[inline(always)]
pub(crate) fn prefetch_ptr<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch is a hint: it loads nothing into registers and
    // never faults, whatever the address; SSE is part of x86-64.
    unsafe {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        _mm_prefetch::<_MM_HINT_T0>(p.cast())
    };
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}
