//! A file's bytes, read into memory or mapped: what the loaders and
//! [`crate::format::read_file`] work on.
//!
//! Why map: reading copies the file into fresh memory, which this kind of
//! machine (a VM whose host hands pages out slowly) zeroes at as little as
//! 0.4 GB/s. Mapped with `MAP_POPULATE`, the page cache's own pages are the
//! bytes: the 16 MB `dragon.glb` opened and read in 11–15 ms, mapped in
//! 1.0 ms (a C probe, fresh process each time, 3 runs; benches/ROUNDS.md,
//! "Ninth round"). Small files are read: a mapping costs more than it saves there.
//!
//! Like any reader of a mapped file, this assumes no other process rewrites
//! or truncates the file in place while it is mapped (svpack itself never
//! does: it writes a temp file and renames or swaps it into the old one's
//! place, and a mapping of the old file keeps the old bytes).

use std::path::Path;

/// Files of at least this many bytes are mapped by [`read_or_map`].
pub const MAP_MIN: u64 = 1 << 20;

/// A file's bytes: read into memory, or mapped. Derefs to `[u8]`.
#[derive(Debug, Clone)]
pub enum FileBytes {
    /// Read into memory (small and compressed files, and files given as bytes).
    Read(Vec<u8>),
    /// The file on disk, mapped read-only ([`read_or_map`], files of at
    /// least [`MAP_MIN`] bytes).
    Mapped(std::sync::Arc<memmap2::Mmap>),
}

impl std::ops::Deref for FileBytes {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        match self {
            FileBytes::Read(v) => v,
            FileBytes::Mapped(m) => m,
        }
    }
}

impl From<Vec<u8>> for FileBytes {
    fn from(v: Vec<u8>) -> Self {
        FileBytes::Read(v)
    }
}

impl FileBytes {
    /// The bytes as a vector of their own (a copy when mapped).
    pub fn into_vec(self) -> Vec<u8> {
        match self {
            FileBytes::Read(v) => v,
            FileBytes::Mapped(m) => m.to_vec(),
        }
    }

    /// Says the first `len` bytes will not be read again: a mapped file's
    /// whole pages among them leave the process's resident set (they stay
    /// in the page cache, and would come back on a read); read bytes stay.
    /// For a build that keeps an input only to finish its digest (see
    /// `load::PendingDigest`): 15 MiB of the dragon's GLB are mapped from
    /// its load to its write.
    pub fn release_prefix(&self, len: usize) {
        #[cfg(unix)]
        if let FileBytes::Mapped(m) = self {
            let len = len.min(m.len()) & !(page_size() - 1);
            if len > 0 {
                // SAFETY: the mapping is read-only and of a file, so
                // MADV_DONTNEED only drops page-table entries: a later read
                // faults the same bytes back in from the file (under the
                // module's contract that nobody rewrites it).
                let _ =
                    unsafe { m.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, 0, len) };
            }
        }
        #[cfg(not(unix))]
        let _ = len;
    }
}

/// The system's page size, a power of two.
#[cfg(unix)]
fn page_size() -> usize {
    // SAFETY: `sysconf` has no preconditions.
    let n = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    if n > 0 && (n as usize).is_power_of_two() {
        n as usize
    } else {
        4096
    }
}

/// The bytes of the file at `path`: mapped (pages populated up front) when
/// it has at least [`MAP_MIN`] bytes and the mapping succeeds, read
/// otherwise. See the module documentation for the contract a mapping
/// relies on.
pub fn read_or_map(path: &Path) -> std::io::Result<FileBytes> {
    let file = std::fs::File::open(path)?;
    let len = file.metadata()?.len();
    if len >= MAP_MIN {
        // SAFETY: memmap2's contract: the file must not change while
        // mapped; see the module documentation.
        if let Ok(map) = unsafe { memmap2::MmapOptions::new().populate().map(&file) } {
            return Ok(FileBytes::Mapped(std::sync::Arc::new(map)));
        }
    }
    let mut data = Vec::with_capacity(len as usize);
    std::io::Read::read_to_end(&mut &file, &mut data)?;
    Ok(FileBytes::Read(data))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The resident kilobytes of the mapping that starts at `addr`, from
    /// `/proc/self/smaps` (per mapping, so other tests' memory does not
    /// count).
    #[cfg(target_os = "linux")]
    fn resident_kib(addr: usize) -> u64 {
        let smaps = std::fs::read_to_string("/proc/self/smaps").unwrap();
        let mut lines = smaps.lines();
        while let Some(line) = lines.next() {
            let start = line.split('-').next().unwrap_or("");
            if usize::from_str_radix(start, 16) == Ok(addr) {
                for l in lines.by_ref() {
                    if let Some(v) = l.strip_prefix("Rss:") {
                        return v.trim().trim_end_matches("kB").trim().parse().unwrap();
                    }
                }
            }
        }
        panic!("no mapping at {addr:#x}");
    }

    /// A mapped file's released prefix leaves the mapping's resident set and
    /// reads back the same. Caught: a release that does nothing (the
    /// resident set stays whole).
    #[cfg(target_os = "linux")]
    #[test]
    fn released_prefix_leaves_the_resident_set_and_reads_the_same() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("f.bin");
        let bytes: Vec<u8> = (0..8u32 << 20).map(|i| (i * 31 / 7) as u8).collect();
        std::fs::write(&path, &bytes).unwrap();
        let data = read_or_map(&path).unwrap();
        let FileBytes::Mapped(m) = &data else {
            panic!("an 8 MiB file is mapped");
        };
        let addr = m.as_ptr() as usize;
        assert_eq!(resident_kib(addr), 8 << 10, "populated when mapped");
        data.release_prefix((6 << 20) + 100);
        assert_eq!(resident_kib(addr), 2 << 10);
        assert!(data[..] == bytes[..]);
        // Read bytes are kept as they are.
        let read = FileBytes::Read(bytes.clone());
        read.release_prefix(1 << 20);
        assert!(read[..] == bytes[..]);
    }
}
