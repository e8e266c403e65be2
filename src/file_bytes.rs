//! A file's bytes, read into memory or mapped: what the loaders and
//! [`crate::format::read_file`] work on.
//!
//! Why map: reading copies the file into fresh memory, which this kind of
//! machine (a VM whose host hands pages out slowly) zeroes at as little as
//! 0.4 GB/s. Mapped with `MAP_POPULATE`, the page cache's own pages are the
//! bytes: the 16 MB `dragon.glb` opened and read in 11–15 ms, mapped in
//! 1.0 ms (a C probe, fresh process each time, 3 runs; README, "Ninth
//! round"). Small files are read: a mapping costs more than it saves there.
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
