//! `--frame-log FILE`: one line per frame of the window, for measuring the window itself rather than a benchmark of
//! its parts (`data-scripts/window_bench.sh` reads it): when each frame started, what the 3-D view showed after it,
//! whether a pointer button was released in it, and how long the frame's own work took.
//!
//! Lines are tab-separated after a `#` header: `t_s` (seconds since the window opened), `phase` (`loading`,
//! `failed`, `ready`), `view` (`none`, `stale`, `reduced`, `refining <fraction>`, `full`), `released` (0 or 1) and
//! `ui_ms` (the frame's work on the UI thread, without egui's painting, which follows it).

use std::io::Write as _;
use std::path::Path;

use anyhow::Context as _;

/// The open frame log.
#[derive(Debug)]
pub struct FrameLog {
    out: std::io::LineWriter<std::fs::File>,
    start: std::time::Instant,
    /// A failed write ends the log (the window goes on).
    failed: bool,
}

/// One frame's line.
#[derive(Debug)]
pub struct FrameLine<'a> {
    pub started: std::time::Instant,
    pub phase: &'a str,
    pub view: String,
    pub released: bool,
    pub ui_ms: f64,
}

impl FrameLog {
    /// Creates (or truncates) `path` and writes the header.
    ///
    /// # Errors
    /// When the file cannot be created or written, naming it.
    pub fn create(path: &Path) -> anyhow::Result<Self> {
        let file = std::fs::File::create(path).with_context(|| format!("creating the frame log {}", path.display()))?;
        let mut out = std::io::LineWriter::new(file);
        writeln!(out, "# t_s\tphase\tview\treleased\tui_ms")
            .with_context(|| format!("writing the frame log {}", path.display()))?;
        Ok(Self { out, start: std::time::Instant::now(), failed: false })
    }

    /// Appends `line`.
    pub fn frame(&mut self, line: &FrameLine<'_>) {
        if self.failed {
            return;
        }
        let t = line.started.saturating_duration_since(self.start).as_secs_f64();
        let released = u8::from(line.released);
        if let Err(e) = writeln!(self.out, "{t:.4}\t{}\t{}\t{released}\t{:.2}", line.phase, line.view, line.ui_ms) {
            eprintln!("warpbench: the frame log stopped: {e}");
            self.failed = true;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_frame_is_one_tab_separated_line_after_the_header() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("frames.tsv");
        let mut log = FrameLog::create(&path).expect("create");
        let started = log.start + std::time::Duration::from_millis(1500);
        log.frame(&FrameLine { started, phase: "ready", view: "refining 0.25".into(), released: true, ui_ms: 3.5 });
        drop(log);
        let text = std::fs::read_to_string(&path).expect("read");
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines, ["# t_s\tphase\tview\treleased\tui_ms", "1.5000\tready\trefining 0.25\t1\t3.50"]);
    }

    #[test]
    fn a_log_that_cannot_be_created_names_its_file() {
        let err = FrameLog::create(Path::new("/nonexistent/dir/frames.tsv")).expect_err("no such folder");
        assert!(format!("{err:#}").contains("/nonexistent/dir/frames.tsv"), "{err:#}");
    }
}
