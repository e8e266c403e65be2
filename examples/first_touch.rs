//! How fast this machine hands out fresh memory: maps `MIB` MiB (default
//! 400) of anonymous memory with the huge-page hint, as svpack's allocator
//! does for large buffers, touches one byte per 4 KiB page, then overwrites
//! the whole block, and unmaps it; four rounds in one process.
//!
//! The first round touches pages the process has never had: on a virtual
//! machine whose host takes freed guest memory back (free page reporting,
//! ballooning), each of them is faulted in by the host too. Later rounds get
//! pages the process has just freed. The gap between the two is what a fresh
//! buffer costs a one-shot command such as `svpack build` beyond writing it.
//!
//! With `small` after the size the mapping gets `MADV_NOHUGEPAGE` instead
//! of the hint: small pages, which the guest takes from its free fragments
//! (not reported to the host themselves), against huge pages, which come
//! from free 2 MiB blocks the host may have taken back. Run each in a new process
//! after a few seconds of rest (`sleep 4`), when the host has taken the
//! freed blocks back, to see what `alloc::cold_memory_seen` guards
//! against, and right after another run to see the warm case:
//!
//! ```text
//! cargo run --release --example first_touch -- 400
//! sleep 4; target/release/examples/first_touch 48        # cold huge pages
//! sleep 4; target/release/examples/first_touch 48 small  # small pages
//! ```
//!
//! With `steps` after the size, each huge page's first fault is timed on
//! its own, and the first round prints how many were slower than 2 ms and
//! where the first of them was: right after another run, a block's first
//! pages come warm (the blocks freed last) and its later ones can come
//! cold, which a probe of the first page alone (`alloc::cold_memory_seen`)
//! does not see (`alloc::populate`):
//!
//! ```text
//! target/release/examples/first_touch 100 steps
//! ```

#[cfg(target_os = "linux")]
fn main() {
    use std::time::Instant;
    let mib: usize = std::env::args()
        .nth(1)
        .map(|a| a.parse().expect("MIB: a size in MiB"))
        .unwrap_or(400);
    let small = std::env::args().nth(2).as_deref() == Some("small");
    let steps = std::env::args().nth(2).as_deref() == Some("steps");
    let size = mib << 20;
    for round in 0..4 {
        // SAFETY: an anonymous private mapping has no preconditions; it is
        // used only within `size` bytes and unmapped once.
        unsafe {
            let p = libc::mmap(
                std::ptr::null_mut(),
                size,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                -1,
                0,
            );
            assert!(p != libc::MAP_FAILED, "mmap of {mib} MiB failed");
            let advice = if small {
                libc::MADV_NOHUGEPAGE
            } else {
                libc::MADV_HUGEPAGE
            };
            libc::madvise(p, size, advice);
            let bytes = p as *mut u8;
            let mut step_ms = Vec::new();
            let t = Instant::now();
            for i in (0..size).step_by(4096) {
                if steps && i % (2 << 20) == 0 {
                    let s = Instant::now();
                    bytes.add(i).write_volatile(1);
                    step_ms.push(s.elapsed().as_secs_f64() * 1e3);
                }
                bytes.add(i).write_volatile(1);
            }
            let touch = t.elapsed().as_secs_f64();
            if steps {
                // Each huge page's fault, in the order the pages were
                // touched: which were slower than 2 ms (faulted in by the
                // host as well).
                let cold: Vec<usize> = (0..step_ms.len()).filter(|&i| step_ms[i] > 2.0).collect();
                println!(
                    "round {round}: {} of {} huge pages slower than 2 ms, the first at {:?}; \
                     the first eight {:.2?} ms",
                    cold.len(),
                    step_ms.len(),
                    cold.first(),
                    &step_ms[..step_ms.len().min(8)]
                );
            }
            let t = Instant::now();
            std::ptr::write_bytes(bytes, 0, size);
            std::hint::black_box(bytes.add(size / 2).read_volatile());
            let fill = t.elapsed().as_secs_f64();
            libc::munmap(p, size);
            println!(
                "round {round}: first touch {:.1} ms ({:.2} GB/s), then filling it {:.1} ms ({:.2} GB/s)",
                touch * 1e3,
                size as f64 / touch / 1e9,
                fill * 1e3,
                size as f64 / fill / 1e9
            );
        }
    }
}

#[cfg(not(target_os = "linux"))]
fn main() {
    eprintln!("first_touch measures Linux anonymous mappings only");
}
