//! The autosave: every change of the document reaches disk before a crash can take it.
//!
//! The window hands [`Autosave::observe`] the session as it is at the end of every frame. A frame is drawn for
//! every input event, so every change of the document (a pair placed, moved, deleted, renamed or switched; a
//! setting; a volume opened; the camera or a slice moved) is seen in the frame that made it. A changed session is
//! sent at once to a writer thread, which writes it atomically ([`session::save_creating_folder`]: temporary file,
//! fsync, rename), so the UI thread never waits on the disk. While the pointer is held (a landmark or the camera
//! being dragged, a slider moved) writes are coalesced to at most one every [`COALESCE`]; the window then asks for
//! a repaint when that time is up, so the last state of a drag is written even if the window goes idle in between.
//! On exit, [`Autosave::finish`] writes the final session (with `clean_exit` true) and waits for it.
//!
//! What a crash can take is therefore bounded by the writer: the change of the current frame until its write is
//! done (milliseconds), and during a drag at most [`COALESCE`] of movement.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::project::session::{self, SessionFile};

/// The longest time a change waits for its write while the pointer is held.
pub const COALESCE: Duration = Duration::from_secs(1);

/// A session for the writer, and whether to report back when it is on disk.
#[derive(Debug)]
struct Job {
    session: SessionFile,
    done: Option<Sender<()>>,
}

/// The autosave of one window: the writer thread and what it last wrote.
#[derive(Debug)]
pub struct Autosave {
    path: PathBuf,
    tx: Option<Sender<Job>>,
    writer: Option<JoinHandle<()>>,
    /// The session last sent to the writer.
    sent: Option<SessionFile>,
    sent_at: Option<Instant>,
    /// The last write's error, shown in the window (cleared by the next write that succeeds).
    error: Arc<Mutex<Option<String>>>,
}

impl Autosave {
    /// An autosave to `path`, with its writer thread.
    #[must_use]
    pub fn new(path: PathBuf) -> Self {
        let (tx, rx) = std::sync::mpsc::channel::<Job>();
        let error = Arc::new(Mutex::new(None));
        let writer = {
            let (path, error) = (path.clone(), Arc::clone(&error));
            std::thread::Builder::new().name("autosave".into()).spawn(move || write_loop(&path, &rx, &error)).ok()
        };
        Self { path, tx: writer.is_some().then_some(tx), writer, sent: None, sent_at: None, error }
    }

    /// Where the autosave is written.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The last write's error, if it failed.
    #[must_use]
    pub fn error(&self) -> Option<String> {
        self.error.lock().ok().and_then(|e| e.clone())
    }

    /// Sees the session as it is at the end of a frame: sends it to the writer when it changed, at once, or while
    /// `coalesce` (the pointer is held) at most every [`COALESCE`]. Returns when the window must draw again so that
    /// a held-back change is written (`None`: nothing held back).
    pub fn observe(&mut self, now: Instant, session: &SessionFile, coalesce: bool) -> Option<Duration> {
        if self.sent.as_ref() == Some(session) {
            return None;
        }
        if coalesce && let Some(at) = self.sent_at {
            let left = COALESCE.saturating_sub(now.saturating_duration_since(at));
            if !left.is_zero() {
                return Some(left);
            }
        }
        self.send(session.clone(), None);
        self.sent_at = Some(now);
        None
    }

    /// Writes `session` now and waits until it is on disk (or the writer is gone). For the exit, and for tests.
    pub fn write_and_wait(&mut self, session: &SessionFile) {
        let (done_tx, done_rx) = std::sync::mpsc::channel();
        if self.send(session.clone(), Some(done_tx)) {
            let _ = done_rx.recv();
        } else if let Err(e) = session::save_creating_folder(&self.path, session) {
            // No writer thread: write on this one.
            self.set_error(format!("{e:#}"));
        }
    }

    /// The last write of a normal exit: `session` (with `clean_exit` true), then the writer stops.
    pub fn finish(&mut self, session: &SessionFile) {
        self.write_and_wait(session);
        self.tx = None;
    }

    /// Sends a job to the writer; false when there is no writer.
    fn send(&mut self, session: SessionFile, done: Option<Sender<()>>) -> bool {
        self.sent = Some(session.clone());
        self.tx.as_ref().is_some_and(|tx| tx.send(Job { session, done }).is_ok())
    }

    fn set_error(&self, message: String) {
        if let Ok(mut e) = self.error.lock() {
            *e = Some(message);
        }
    }
}

impl Drop for Autosave {
    /// Lets the writer finish what it was sent, so that nothing is written after the window is gone.
    fn drop(&mut self) {
        self.tx = None;
        if let Some(writer) = self.writer.take() {
            let _ = writer.join();
        }
    }
}

/// The writer thread: writes each session it is sent; when several are waiting, only the newest (the others are
/// already out of date).
fn write_loop(path: &Path, rx: &Receiver<Job>, error: &Mutex<Option<String>>) {
    while let Ok(mut job) = rx.recv() {
        let mut waiting = Vec::new();
        while let Ok(next) = rx.try_recv() {
            waiting.extend(job.done.take());
            job = next;
        }
        let result = session::save_creating_folder(path, &job.session);
        if let Ok(mut e) = error.lock() {
            *e = result.err().map(|e| format!("autosave to {}: {e:#}", path.display()));
        }
        for done in waiting.into_iter().chain(job.done) {
            let _ = done.send(());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A session with `n` pairs.
    fn session(n: usize) -> SessionFile {
        let volume = crate::project::demo::phantom(4, 1.0, [0.0; 3], false);
        let pairs = (0..n)
            .map(|i| {
                let (m, f) = (i as f64, i as f64);
                warpbench_io::landmarks::LandmarkPair::new(
                    format!("Pt-{}", i + 1),
                    warpbench_io::geometry::Point3::new(m, 0.0, 0.0),
                    warpbench_io::geometry::Point3::new(0.0, f, 0.0),
                )
            })
            .collect();
        let document = crate::project::document::Document::new([None, None], [&volume, &volume], pairs);
        SessionFile::new(document, session::View::default(), false)
    }

    fn on_disk(path: &Path) -> Option<SessionFile> {
        session::load(path).ok()
    }

    #[test]
    fn a_change_is_written_at_once_and_a_held_pointer_coalesces() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("state/autosave.warpbench.json");
        let mut autosave = Autosave::new(path.clone());
        let t0 = Instant::now();
        assert_eq!(autosave.observe(t0, &session(1), false), None);
        // Unchanged: nothing to do.
        assert_eq!(autosave.observe(t0, &session(1), true), None);
        // A change while the pointer is held, within the coalescing time: held back, with the time to draw again.
        let later = t0 + Duration::from_millis(300);
        let wait = autosave.observe(later, &session(2), true).expect("held back");
        assert_eq!(wait, COALESCE.saturating_sub(Duration::from_millis(300)));
        // Once the time is up it is sent.
        assert_eq!(autosave.observe(t0 + COALESCE, &session(2), true), None);
        autosave.write_and_wait(&session(2));
        assert_eq!(on_disk(&path).expect("written").document.pairs.len(), 2);
        // Without the pointer held a change goes out at once, however soon after the last.
        assert_eq!(autosave.observe(t0 + COALESCE, &session(0), false), None);
        let mut last = session(0);
        last.clean_exit = true;
        autosave.finish(&last);
        let written = on_disk(&path).expect("written");
        assert!(written.clean_exit && written.document.pairs.is_empty());
        assert_eq!(autosave.error(), None);
    }

    #[test]
    fn a_failed_write_is_reported() {
        let dir = tempfile::tempdir().expect("tempdir");
        // The autosave's folder is a file: it cannot be created.
        let blocker = dir.path().join("blocker");
        std::fs::write(&blocker, b"").expect("write");
        let mut autosave = Autosave::new(blocker.join("autosave.warpbench.json"));
        autosave.write_and_wait(&session(1));
        let e = autosave.error().expect("an error");
        assert!(e.contains("blocker"), "{e}");
    }
}
