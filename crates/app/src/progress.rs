//! Progress bars on stderr (indicatif), silenced by `--quiet` or when stderr is not a terminal.

use std::ops::ControlFlow;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use warpbench_io::Progress;

/// A progress bar that follows `warpbench_io` progress reports, switching label per stage.
#[derive(Debug)]
pub struct Bar {
    bar: ProgressBar,
    stage: &'static str,
}

impl Bar {
    #[must_use]
    pub fn new(quiet: bool) -> Self {
        let bar = ProgressBar::with_draw_target(
            Some(0),
            if quiet { ProgressDrawTarget::hidden() } else { ProgressDrawTarget::stderr() },
        );
        let style = ProgressStyle::with_template("{msg:>24} [{bar:40}] {percent:>3}% {elapsed}")
            .map_or_else(|_| ProgressStyle::default_bar(), |s| s.progress_chars("=> "));
        bar.set_style(style);
        Self { bar, stage: "" }
    }

    /// Feeds one report into the bar; never cancels.
    pub fn update(&mut self, p: Progress) -> ControlFlow<()> {
        if p.stage != self.stage {
            self.stage = p.stage;
            self.bar.set_message(p.stage);
            self.bar.set_length(p.total);
        }
        self.bar.set_position(p.done);
        ControlFlow::Continue(())
    }

    /// Shows `done` of `total` for `stage` (for work that reports its own progress, like the export's slices).
    pub fn set(&self, stage: &'static str, done: u64, total: u64) {
        if self.bar.message() != stage {
            self.bar.set_message(stage);
        }
        self.bar.set_length(total);
        self.bar.set_position(done);
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

/// Runs `work` with a progress callback `(done, total)` that draws a bar labelled `stage` on stderr from its first
/// report (none with `quiet`, or for work that reports nothing), cleared when `work` returns; the callback never
/// cancels.
pub fn with_bar<T>(quiet: bool, stage: &'static str, work: impl FnOnce(&mut dyn FnMut(u64, u64) -> bool) -> T) -> T {
    let mut bar: Option<Bar> = None;
    let result = work(&mut |done, total| {
        let _ = bar.get_or_insert_with(|| Bar::new(quiet)).update(Progress { stage, done, total });
        true
    });
    if let Some(bar) = bar {
        bar.finish();
    }
    result
}
