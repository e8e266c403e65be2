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
/// two and three alternations). The sides' loop of the thirty-eighth
/// round asks for one end of each row (faster there: see
/// `layout::fill_sides`); the caps' still need both (the 5M scene's caps
/// from the welded mesh 24.1 ms with both ends, 31.6–33.0 with one:
/// `stage_probe -- build`, two alternations).
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

/// How far ahead, in bytes, [`prefetch_stream`] asks for a stream that a
/// loop reads in order: 2 KiB, 32 cache lines.
///
/// Why at all, when the hardware prefetches sequential reads: on this
/// project's machine (a virtual machine on a Xeon) it did not run far
/// enough ahead of loops that do little work per byte read, which waited
/// on their loads (`perf annotate`: most samples of the topology's count
/// and list passes on the instructions after the triangle loads). One
/// thread, `RECYCLE=1 cargo run --release --example stage_probe --
/// passes` (or `-- weld`), medians of four alternations, the dragon / the
/// 5M scene:
///
/// - the topology's count pass 2.48 → 1.82 / 15.7 → 10.7 ms, its list
///   pass 5.83 → 3.74 / 31.4 → 24.4 ms (the triangles);
/// - the weld's triangle step 3.82 → 3.33 / 19.1 → 16.8 ms (the input
///   indices), its sort 9.33 → 9.01 / 56.6 → 53.5 ms (the positions its
///   scatter reads);
/// - the topology's emit pass, whose range counts read the listings
///   (once per line): 11.16 → 10.64 / 66.0 → 62.0 ms (six alternations;
///   1 KiB ahead gained less, 4 KiB about the same).
///
/// The evaluator's one-light passes got it in the thirty-seventh round,
/// on this machine's AMD EPYC (the caps' corner ids, the evaluation
/// numbers its reads into input order go through, the sides' slot
/// offsets): the dragon's one-light evaluation 2.56–2.69 → 2.21–2.32 ms
/// at the fastest, three alternations of `cargo run --release --example
/// stage_probe -- evaluate target/dragon/dragon.glb` (its `auto` row).
pub(crate) const STREAM_AHEAD: usize = 2048;

/// [`prefetch_ptr`] of the byte [`STREAM_AHEAD`] past `p`, the element a
/// loop reading in order is at: call it with every element (a prefetch of
/// a line already asked for costs one instruction) or once per line.
#[inline(always)]
pub(crate) fn prefetch_stream<T>(p: *const T) {
    prefetch_ptr((p as *const u8).wrapping_add(STREAM_AHEAD))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prefetches_of_addresses_past_any_buffer_never_fault() {
        // The hot loops ask for lines past the ends of their buffers
        // (`prefetch_stream` 2 KiB on from the last element, a slot 16
        // past a bucket's end) and from stale indices: none of these may
        // be read. Unmapped addresses: the null page and the top of the
        // address space.
        let v = vec![1u32; 3];
        prefetch_stream(v.as_ptr().wrapping_add(2));
        prefetch_stream(std::ptr::null::<u32>());
        prefetch_ptr(std::ptr::null::<u8>());
        prefetch_ptr(usize::MAX as *const u8);
        prefetch_stream((usize::MAX - 8) as *const u64);
        prefetch_whole(&v[2]);
        assert_eq!(v, [1, 1, 1]);
    }
}
