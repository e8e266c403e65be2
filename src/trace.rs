//! An opt-in timeline of what each thread does (`svpack build --trace
//! FILE`): named intervals, per thread, written as Chrome trace event JSON
//! (open it in `ui.perfetto.dev` or `chrome://tracing`;
//! `benches/trace_summary.py` sums it up).
//!
//! Why: with two threads a build is a chain of passes, fills and copies
//! into the page cache shared between the threads, and only a timeline
//! shows which of them the other waits for. Until the forty-seventh round
//! such timelines came from local edits that were not kept
//! (benches/ROUNDS.md, "Fortieth round"), so no command reproduced them.
//!
//! Recording is process-wide: [`start`] turns it on for every thread, the
//! [`Recording`] it returns turns it off and hands back the events. While
//! it is off an interval costs one relaxed atomic load; while it is on,
//! a lock and a push when the interval ends (the build records a few
//! hundred: its stages, the weld's steps, the topology's passes, and each
//! unit's fill and write).

use std::cell::Cell;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering::Relaxed};
use std::time::Instant;

static ON: AtomicBool = AtomicBool::new(false);
static LOG: Mutex<Option<Log>> = Mutex::new(None);
static NEXT_THREAD: AtomicU32 = AtomicU32::new(0);

thread_local! {
    /// This thread's number in traces (0: not numbered yet; numbers start
    /// at 1, in the order threads first record).
    static THREAD: Cell<u32> = const { Cell::new(0) };
}

struct Log {
    epoch: Instant,
    events: Vec<Event>,
    threads: Vec<(u32, String)>,
}

/// One interval of one thread.
#[derive(Debug, Clone, PartialEq)]
pub struct Event {
    /// What the thread did (a stage, a pass, `fill`, `file write`, ...).
    pub name: &'static str,
    /// The thread's number (see [`Trace::threads`]).
    pub thread: u32,
    /// Start, in microseconds since [`start`].
    pub start_us: f64,
    /// Length in microseconds.
    pub dur_us: f64,
    /// A number that tells intervals of one name apart (a unit's index),
    /// if any.
    pub arg: Option<u64>,
}

/// The events of one recording, and the threads that made them.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trace {
    /// Every interval, in the order they ended.
    pub events: Vec<Event>,
    /// Each recording thread's number and name (`rayon N` for thread N of
    /// a rayon pool, else the thread's own name or `thread`).
    pub threads: Vec<(u32, String)>,
}

/// Turns recording on for every thread of the process, until the returned
/// [`Recording`] is finished or dropped. Events of an earlier recording
/// still open are discarded.
pub fn start() -> Recording {
    let mut log = LOG.lock().unwrap_or_else(|e| e.into_inner());
    *log = Some(Log {
        epoch: Instant::now(),
        events: Vec::new(),
        threads: Vec::new(),
    });
    ON.store(true, Relaxed);
    Recording(())
}

/// Whether a recording is on.
#[inline]
pub fn on() -> bool {
    ON.load(Relaxed)
}

/// A recording in progress (see [`start`]); dropping it turns recording
/// off and discards the events.
pub struct Recording(());

impl Recording {
    /// Turns recording off and returns what was recorded.
    pub fn finish(self) -> Trace {
        // (Taken once: dropping `self` would take again.)
        std::mem::forget(self);
        take()
    }
}

impl Drop for Recording {
    fn drop(&mut self) {
        take();
    }
}

fn take() -> Trace {
    ON.store(false, Relaxed);
    let log = LOG.lock().unwrap_or_else(|e| e.into_inner()).take();
    log.map(|l| Trace {
        events: l.events,
        threads: l.threads,
    })
    .unwrap_or_default()
}

/// Records the interval from `start` to now as `name` on this thread, if
/// a recording is on (for code that times itself already).
#[inline]
pub fn since(name: &'static str, start: Instant) {
    if on() {
        record(name, None, start, Instant::now());
    }
}

/// Records the interval from `start` to `end` as `name` on this thread, if
/// a recording is on (for steps timed back to back, whose intervals must
/// not overlap).
#[inline]
pub fn between(name: &'static str, start: Instant, end: Instant) {
    if on() {
        record(name, None, start, end);
    }
}

/// [`since`], with a number that tells intervals apart (a unit's index).
#[inline]
pub fn since_n(name: &'static str, n: u64, start: Instant) {
    if on() {
        record(name, Some(n), start, Instant::now());
    }
}

/// The time now if a recording is on: the start to pass to [`since`] or
/// [`since_n`] once the interval ends (nothing is read when off).
#[inline]
pub fn now() -> Option<Instant> {
    on().then(Instant::now)
}

/// An interval that records itself as `name` when dropped (or ended), if
/// a recording was on when it began.
#[must_use = "the interval ends when this is dropped"]
pub struct Span {
    name: &'static str,
    arg: Option<u64>,
    start: Option<Instant>,
}

/// An interval named `name` from now until the [`Span`] is dropped.
#[inline]
pub fn span(name: &'static str) -> Span {
    Span {
        name,
        arg: None,
        start: now(),
    }
}

/// [`span`], with a number that tells intervals apart (a unit's index).
#[inline]
pub fn span_n(name: &'static str, n: u64) -> Span {
    Span {
        name,
        arg: Some(n),
        start: now(),
    }
}

impl Span {
    /// Ends the interval now (as dropping it does).
    pub fn end(self) {}
}

impl Drop for Span {
    #[inline]
    fn drop(&mut self) {
        if let Some(start) = self.start {
            record(self.name, self.arg, start, Instant::now());
        }
    }
}

#[cold]
fn record(name: &'static str, arg: Option<u64>, start: Instant, end: Instant) {
    let thread = THREAD.with(|t| {
        if t.get() == 0 {
            t.set(NEXT_THREAD.fetch_add(1, Relaxed) + 1);
        }
        t.get()
    });
    let mut log = LOG.lock().unwrap_or_else(|e| e.into_inner());
    let Some(log) = log.as_mut() else {
        return;
    };
    // An interval begun before the recording started counts from its
    // start.
    let start = start.max(log.epoch);
    let us = |t: Instant| t.duration_since(log.epoch).as_secs_f64() * 1e6;
    if !log.threads.iter().any(|(n, _)| *n == thread) {
        log.threads.push((thread, thread_name()));
    }
    log.events.push(Event {
        name,
        thread,
        start_us: us(start),
        dur_us: end.duration_since(start).as_secs_f64() * 1e6,
        arg,
    });
}

fn thread_name() -> String {
    match rayon::current_thread_index() {
        Some(i) => format!("rayon {i}"),
        None => std::thread::current()
            .name()
            .unwrap_or("thread")
            .to_string(),
    }
}

impl Trace {
    /// The trace as Chrome trace event JSON: one complete (`X`) event per
    /// interval, times in microseconds, and a `thread_name` metadata event
    /// per thread.
    pub fn to_chrome_json(&self) -> String {
        let mut events: Vec<serde_json::Value> = self
            .threads
            .iter()
            .map(|(n, name)| {
                serde_json::json!({
                    "name": "thread_name", "ph": "M", "pid": 1, "tid": n,
                    "args": { "name": name }
                })
            })
            .collect();
        events.extend(self.events.iter().map(|e| {
            let mut v = serde_json::json!({
                "name": e.name, "cat": "svpack", "ph": "X", "pid": 1, "tid": e.thread,
                "ts": e.start_us, "dur": e.dur_us
            });
            if let Some(n) = e.arg {
                v["args"] = serde_json::json!({ "n": n });
            }
            v
        }));
        serde_json::to_string(&serde_json::json!({
            "traceEvents": events,
            "displayTimeUnit": "ms",
        }))
        .expect("a trace serialises")
    }
}

/// Where a trace goes: a temp file beside its path, made before the work
/// it records (so that a path it cannot write to fails first), which
/// replaces the path once the trace is written.
pub struct TraceFile {
    path: std::path::PathBuf,
    tmp: tempfile::NamedTempFile,
}

impl TraceFile {
    /// The temp file beside `path`.
    pub fn create(path: &std::path::Path) -> crate::error::Result<TraceFile> {
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => std::path::Path::new("."),
        };
        let tmp =
            tempfile::NamedTempFile::new_in(dir).map_err(|e| crate::error::Error::io(path, e))?;
        Ok(TraceFile {
            path: path.to_path_buf(),
            tmp,
        })
    }

    /// Writes `trace` ([`Trace::to_chrome_json`]) and puts it in place.
    pub fn write(mut self, trace: &Trace) -> crate::error::Result<()> {
        use std::io::Write;
        let err = |e| crate::error::Error::io(&self.path, e);
        self.tmp
            .write_all(trace.to_chrome_json().as_bytes())
            .map_err(err)?;
        self.tmp.persist(&self.path).map_err(|e| err(e.error))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Recordings are process-wide: the tests that start one take turns.
    static TURN: Mutex<()> = Mutex::new(());

    fn ours<'a>(t: &'a Trace, name: &str) -> Vec<&'a Event> {
        t.events.iter().filter(|e| e.name == name).collect()
    }

    /// Intervals are recorded only while a recording is on, each on its
    /// own thread's number, with its length and number. Caught: a span
    /// recorded with no length, and every thread given the same number.
    #[test]
    fn records_intervals_per_thread_only_while_on() {
        let _turn = TURN.lock().unwrap_or_else(|e| e.into_inner());
        // Off: nothing is kept.
        drop(span("trace-test-off"));
        let rec = start();
        {
            let _s = span_n("trace-test-outer", 7);
            std::thread::sleep(std::time::Duration::from_millis(2));
            let before = Instant::now();
            std::thread::Builder::new()
                .name("trace-test-thread".into())
                .spawn(|| drop(span("trace-test-other")))
                .unwrap()
                .join()
                .unwrap();
            since("trace-test-since", before);
        }
        let t = rec.finish();
        drop(span("trace-test-after"));
        assert!(ours(&t, "trace-test-off").is_empty());
        assert!(ours(&t, "trace-test-after").is_empty());
        let [outer] = ours(&t, "trace-test-outer")[..] else {
            panic!("one outer interval: {t:?}")
        };
        assert_eq!(outer.arg, Some(7));
        assert!(outer.dur_us >= 2000.0, "{outer:?}");
        let [other] = ours(&t, "trace-test-other")[..] else {
            panic!("one interval on the other thread: {t:?}")
        };
        let [inner] = ours(&t, "trace-test-since")[..] else {
            panic!("one interval from `since`: {t:?}")
        };
        assert_eq!(inner.thread, outer.thread);
        assert_ne!(other.thread, outer.thread);
        // Nested: the inner interval lies within the outer one.
        assert!(inner.start_us >= outer.start_us);
        assert!(inner.start_us + inner.dur_us <= outer.start_us + outer.dur_us + 1.0);
        let name = |n: u32| t.threads.iter().find(|(m, _)| *m == n).map(|(_, s)| s);
        assert_eq!(
            name(other.thread).map(String::as_str),
            Some("trace-test-thread")
        );
    }

    /// The JSON has a complete event per interval with its thread, times
    /// and number, and a name per thread. Caught: `dur` written in
    /// milliseconds.
    #[test]
    fn chrome_json_has_every_interval_and_thread() {
        let t = Trace {
            events: vec![Event {
                name: "fill",
                thread: 2,
                start_us: 10.0,
                dur_us: 1500.0,
                arg: Some(3),
            }],
            threads: vec![(2, "rayon 1".into())],
        };
        let v: serde_json::Value = serde_json::from_str(&t.to_chrome_json()).unwrap();
        let events = v["traceEvents"].as_array().unwrap();
        assert_eq!(events.len(), 2);
        let meta = &events[0];
        assert_eq!(
            (&meta["ph"], &meta["tid"], &meta["args"]["name"]),
            (&"M".into(), &2.into(), &"rayon 1".into())
        );
        let e = &events[1];
        assert_eq!(e["name"], "fill");
        assert_eq!(e["ph"], "X");
        assert_eq!(e["tid"], 2);
        assert_eq!(e["ts"].as_f64(), Some(10.0));
        assert_eq!(e["dur"].as_f64(), Some(1500.0));
        assert_eq!(e["args"]["n"], 3);
    }
}
