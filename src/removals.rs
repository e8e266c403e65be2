//! Removing the previous outputs a batch replaces, beside the builds.
//!
//! Rebuilding in place swaps the new output in and then removes the old
//! file (`format::persist`). On a filesystem mounted with `discard` (ext4
//! here, as some cloud images are) that removal waits for the device to
//! discard the old file's blocks: 27 ms for the dragon's 120 MiB here
//! (`cargo run --release --example stage_probe -- replace DIR`),
//! with the thread asleep in `blkdev_issue_discard` under `unlinkat`
//! (5.5 ms of CPU). A build thread that waits there builds nothing, so a
//! batch hands its old files to one thread of its own ([`Remover`]) and
//! waits for it once, at its end.
//!
//! Why a thread-local hand-off and not a parameter: the builds call
//! `format::persist` deep inside the writers, on whichever worker of the
//! batch's thread pool finishes them; the pool's workers each hold a
//! sender ([`Remover::attach`], the pool's start handler), and a thread
//! without one (a build outside a batch, a test) removes inline, as before.

use crate::error::Error;
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::sync::mpsc;

/// What the removing thread is sent.
enum Job {
    /// The old file swapped out of `output`, to remove.
    Remove {
        output: PathBuf,
        old: tempfile::TempPath,
    },
    /// Everything sent before this has been received: stop.
    End,
}

thread_local! {
    /// This thread's way to the removing thread of its batch, if any.
    static SENDER: RefCell<Option<mpsc::Sender<Job>>> = const { RefCell::new(None) };
}

/// A thread that removes the old outputs of one batch, one after the
/// other, while the builds go on.
pub struct Remover {
    sender: mpsc::Sender<Job>,
    thread: std::thread::JoinHandle<Vec<(PathBuf, Error)>>,
}

impl Remover {
    /// Starts the removing thread; `None` if the system cannot start one
    /// (then every build removes its old output itself).
    pub fn start() -> Option<Remover> {
        let (sender, receiver) = mpsc::channel();
        let thread = std::thread::Builder::new()
            .name("svpack-remove".into())
            .spawn(move || {
                let mut failed = Vec::new();
                for job in receiver {
                    match job {
                        Job::Remove { output, old } => {
                            if let Err(e) = remove(old) {
                                failed.push((output, e));
                            }
                        }
                        Job::End => break,
                    }
                }
                failed
            })
            .ok()?;
        Some(Remover { sender, thread })
    }

    /// Makes the calling thread hand its old outputs to this remover
    /// (for a thread pool's start handler).
    pub fn attach(&self) -> impl Fn(usize) + Send + Sync + 'static {
        let sender = self.sender.clone();
        move |_| SENDER.with(|s| *s.borrow_mut() = Some(sender.clone()))
    }

    /// Waits until every old output handed over so far is removed; returns
    /// those that could not be, each with the output it was swapped out of
    /// and the error naming it (the file is left under its temp name).
    pub fn finish(self) -> Vec<(PathBuf, Error)> {
        // The batch's builds have returned, so whatever they handed over
        // is queued before this (one channel: sends ordered by happens-before
        // are received in that order).
        let _ = self.sender.send(Job::End);
        self.thread.join().unwrap_or_default()
    }
}

/// Removes `old`, the file swapped out of `output`: on the calling
/// thread's [`Remover`] if it has one (which reports failures at its
/// [`Remover::finish`]), else now.
pub(crate) fn remove_old(output: &Path, old: tempfile::TempPath) -> crate::error::Result<()> {
    let job = Job::Remove {
        output: output.to_path_buf(),
        old,
    };
    let job = SENDER.with(|s| match &*s.borrow() {
        Some(sender) => sender.send(job).err().map(|e| e.0),
        None => Some(job),
    });
    match job {
        // No remover, or its thread is gone: remove it here.
        Some(Job::Remove { old, .. }) => remove(old),
        _ => Ok(()),
    }
}

/// Removes `old`; an error names it.
fn remove(old: tempfile::TempPath) -> crate::error::Result<()> {
    let path = old.to_path_buf();
    old.close().map_err(|e| Error::io(&path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file and a directory handed to a remover (attached to this thread
    /// as a pool's start handler would): the file is gone once the remover
    /// finishes, the directory (which cannot be removed as a file) is
    /// reported with the output it was swapped out of and left alone. With
    /// the remover finished, this thread removes inline again, and reports
    /// a failure at once.
    #[test]
    fn removes_on_its_thread_and_reports_failures_with_their_output() {
        let dir = tempfile::tempdir().unwrap();
        let file = |name: &str| {
            let p = dir.path().join(name);
            std::fs::write(&p, b"old").unwrap();
            p
        };
        let sub = |name: &str| {
            let p = dir.path().join(name);
            std::fs::create_dir(&p).unwrap();
            std::fs::write(p.join("keep"), b"x").unwrap();
            p
        };
        let remover = Remover::start().unwrap();
        remover.attach()(0);
        let (a, d) = (file("a.tmp"), sub("d.tmp"));
        remove_old(
            Path::new("out/a.svpk"),
            tempfile::TempPath::try_from_path(&a).unwrap(),
        )
        .unwrap();
        remove_old(
            Path::new("out/d.svpk"),
            tempfile::TempPath::try_from_path(&d).unwrap(),
        )
        .unwrap();
        let failed = remover.finish();
        assert!(
            !a.exists(),
            "the file is removed by the time finish returns"
        );
        assert_eq!(failed.len(), 1);
        assert_eq!(failed[0].0, Path::new("out/d.svpk"));
        assert!(failed[0].1.to_string().contains("d.tmp"), "{}", failed[0].1);
        assert!(d.join("keep").is_file());

        let (b, e) = (file("b.tmp"), sub("e.tmp"));
        remove_old(
            Path::new("out/b.svpk"),
            tempfile::TempPath::try_from_path(&b).unwrap(),
        )
        .unwrap();
        assert!(!b.exists(), "removed inline");
        let err = remove_old(
            Path::new("out/e.svpk"),
            tempfile::TempPath::try_from_path(&e).unwrap(),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("e.tmp"), "{err}");
        assert!(e.join("keep").is_file());
    }
}
