//! How fast buffered writes fill the page cache here, and whether two
//! threads fill one file faster than one: writes `MIB` MiB (default 128) in
//! 1 MiB positioned writes (`pwrite`, as svpack's streamed writer does with
//! its units) from buffers already in cache, into new files in `DIR`
//! (default: the current directory), four ways:
//!
//! - one thread, one file;
//! - two threads, one file, alternate megabytes each;
//! - two threads, two files, half the bytes each;
//! - one thread, one file whose blocks are reserved first (`fallocate`, as
//!   `format::write_file_streamed` does on ext4 and XFS), the call timed;
//! - two threads, one reserved file: one writes the last four fifths, the
//!   other fills the first fifth through a shared mapping (no write call,
//!   so no inode lock);
//! - two threads, one reserved file: one fills each megabyte into a buffer
//!   (a `memset`, as cheap as a fill gets), the other writes the buffers it
//!   is handed (four in flight), so the copy reads memory another core
//!   wrote.
//!
//! Five rounds of each, interleaved; prints the fastest and the median.
//!
//! Why: the two-thread build writes its payload from both threads, and the
//! copy into the page cache is most of its write stage. On Linux a buffered
//! write holds the file's inode lock, so writers of one file take turns
//! whatever the offsets (two files have two locks): on this machine's ext4
//! one file takes as long with two threads as with one, two files half as
//! long. That copy is the floor of a two-thread build's write stage.
//!
//! `cargo run --release --example file_write -- 128 /work`

#[cfg(target_os = "linux")]
fn main() {
    use std::os::unix::fs::FileExt;
    use std::os::unix::io::AsRawFd;
    use std::time::Instant;
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mib: usize = args
        .first()
        .map(|a| a.parse().expect("MIB: a size in MiB"))
        .unwrap_or(128);
    let dir = std::path::PathBuf::from(args.get(1).map_or(".", |d| d.as_str()));
    const CHUNK: usize = 1 << 20;
    let size = mib * CHUNK;
    let buf: Vec<u8> = (0..CHUNK).map(|i| (i * 7 + 3) as u8).collect();
    let path = |n: usize| dir.join(format!(".svpack-file-write-{n}.tmp"));
    let create = |n: usize, len: usize, reserve: bool| {
        // (Readable too: a shared mapping needs it.)
        let f = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(path(n))
            .expect("a new file in DIR");
        f.set_len(len as u64).unwrap();
        if reserve {
            // SAFETY: an open descriptor; the call only reserves blocks.
            unsafe { libc::fallocate(f.as_raw_fd(), 0, 0, len as libc::off_t) };
        }
        f
    };
    // Writes chunks `first, first + step, …` below `len` of `f`.
    let fill = |f: &std::fs::File, first: usize, step: usize, len: usize| {
        for c in (first..len / CHUNK).step_by(step) {
            f.write_all_at(&buf, (c * CHUNK) as u64).unwrap();
        }
    };
    let ways = [
        "one thread, one file",
        "two threads, one file",
        "two threads, two files",
        "one thread, one file, blocks reserved first",
        "two threads, one reserved file, its first fifth through a mapping",
        "two threads, one reserved file, buffers filled by one, written by the other",
    ];
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); ways.len()];
    for _ in 0..5 {
        for (w, t) in times.iter_mut().enumerate() {
            let start = Instant::now();
            match w {
                0 | 3 => fill(&create(0, size, w == 3), 0, 1, size),
                1 => {
                    let f = create(0, size, false);
                    std::thread::scope(|s| {
                        s.spawn(|| fill(&f, 1, 2, size));
                        fill(&f, 0, 2, size);
                    });
                }
                2 => {
                    let (a, b) = (create(0, size / 2, false), create(1, size / 2, false));
                    std::thread::scope(|s| {
                        s.spawn(|| fill(&b, 0, 1, size / 2));
                        fill(&a, 0, 1, size / 2);
                    });
                }
                4 => {
                    let f = create(0, size, true);
                    let mapped = size / 5 / CHUNK * CHUNK;
                    std::thread::scope(|s| {
                        // (Nothing to map below 5 MiB: a mapping cannot be
                        // empty.)
                        s.spawn(|| {
                            if mapped == 0 {
                                return;
                            }
                            // SAFETY: a new file of this process, not
                            // truncated while mapped, its blocks reserved.
                            let mut m = unsafe {
                                memmap2::MmapOptions::new().len(mapped).map_mut(&f).unwrap()
                            };
                            for c in m.chunks_mut(CHUNK) {
                                c.copy_from_slice(&buf[..c.len()]);
                            }
                        });
                        for c in mapped / CHUNK..size / CHUNK {
                            f.write_all_at(&buf, (c * CHUNK) as u64).unwrap();
                        }
                    });
                }
                _ => {
                    let f = create(0, size, true);
                    let (full_tx, full_rx) = std::sync::mpsc::sync_channel::<(usize, Vec<u8>)>(4);
                    let (free_tx, free_rx) = std::sync::mpsc::channel::<Vec<u8>>();
                    for _ in 0..4 {
                        free_tx.send(vec![0u8; CHUNK]).unwrap();
                    }
                    std::thread::scope(|s| {
                        s.spawn(move || {
                            for c in 0..size / CHUNK {
                                let mut b = free_rx.recv().unwrap();
                                b.fill(c as u8 | 1);
                                full_tx.send((c, b)).unwrap();
                            }
                        });
                        for (c, b) in full_rx {
                            f.write_all_at(&b, (c * CHUNK) as u64).unwrap();
                            let _ = free_tx.send(b);
                        }
                    });
                }
            }
            t.push(start.elapsed().as_secs_f64() * 1e3);
            let _ = std::fs::remove_file(path(0));
            let _ = std::fs::remove_file(path(1));
        }
    }
    for (way, t) in ways.iter().zip(&mut times) {
        t.sort_by(f64::total_cmp);
        println!(
            "{way}: {:.1} ms fastest, {:.1} ms median ({:.2} GB/s)",
            t[0],
            t[t.len() / 2],
            size as f64 / t[0] / 1e6
        );
    }
}

#[cfg(not(target_os = "linux"))]
fn main() {
    eprintln!("file_write measures Linux page-cache writes only");
}
