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

#[cfg(target_os = "linux")]
fn main() {
    use std::time::Instant;
    let mib: usize = std::env::args()
        .nth(1)
        .map(|a| a.parse().expect("MIB: a size in MiB"))
        .unwrap_or(400);
    let small = std::env::args().nth(2).as_deref() == Some("small");
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
            let t = Instant::now();
            for i in (0..size).step_by(4096) {
                bytes.add(i).write_volatile(1);
            }
            let touch = t.elapsed().as_secs_f64();
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
