//! How much of the 3-D view the window renders per UI frame, so that panels never wait on it.
//!
//! On a GPU the view renders in a few ms and is simply drawn again when it changes. A CPU driver (lavapipe,
//! llvmpipe) takes seconds for a full-quality view, and egui shares its queue, so a whole frame at once would freeze
//! the window. There the view is paced:
//! - when it changes, a reduced view (the interaction sample rate, at [`interactive_size`]) is shown at once;
//! - then the full-quality view is rendered in bands of rows ([`band_rows`]), back to back on a thread of its own
//!   ([`RefineJob`]), each sized to about [`INTERACTIVE_BUDGET_MS`] from the measured cost per pixel, into a target
//!   of its own, and shown once its last band is done. Bands give exactly the one-pass image (each ray depends on
//!   its pixel only), so the result does not depend on timing: only how long it takes does.

use warpbench_gpu::RenderTarget;

/// What the 3-D view may cost per UI frame on a CPU driver, ms: a reduced view while the user interacts, or one
/// band of the full view.
pub const INTERACTIVE_BUDGET_MS: f64 = 60.0;

/// The cost per pixel of a full-quality view assumed on a CPU driver before one has been measured, ms (lavapipe on
/// 2 cores of this project's machine: about 4 µs; see `docs/benchmarks.md`).
pub const CPU_GUESS_MS_PER_PX: f64 = 4e-3;

/// The smallest scale per side of the 3-D view while interacting: shaded DVR of two volumes on lavapipe can cost
/// 10 µs per pixel, and a coarse view that follows the pointer serves better than a sharp one that lags it.
pub const MIN_INTERACTIVE_SCALE: f64 = 0.125;

/// The 3-D view's size while interacting: `full` on a GPU (`ms_per_px` unknown); on a CPU driver scaled down so that
/// `ms_per_px` (measured at full quality; the interaction rate halves it again) gives about
/// [`INTERACTIVE_BUDGET_MS`], at most [`MIN_INTERACTIVE_SCALE`] smaller per side.
#[must_use]
pub fn interactive_size(full: (u32, u32), ms_per_px: Option<f64>) -> (u32, u32) {
    let Some(per_px) = ms_per_px.filter(|v| *v > 0.0) else { return full };
    let pixels = f64::from(full.0) * f64::from(full.1);
    let scale = (INTERACTIVE_BUDGET_MS / (0.5 * per_px * pixels)).sqrt().clamp(MIN_INTERACTIVE_SCALE, 1.0);
    let shrink = |n: u32| ((f64::from(n) * scale).round() as u32).max(16);
    (shrink(full.0), shrink(full.1))
}

/// How many rows of a full-quality view `width` pixels wide fit in [`INTERACTIVE_BUDGET_MS`] at `ms_per_px`
/// ([`CPU_GUESS_MS_PER_PX`] when that is not a positive number): at least one, at most `height`.
#[must_use]
pub fn band_rows(width: u32, height: u32, ms_per_px: f64) -> u32 {
    let per_px = if ms_per_px.is_finite() && ms_per_px > 0.0 { ms_per_px } else { CPU_GUESS_MS_PER_PX };
    let rows = INTERACTIVE_BUDGET_MS / (per_px * f64::from(width.max(1)));
    // `as` saturates: a huge quotient is clamped below.
    (rows.floor() as u32).clamp(1, height.max(1))
}

/// The bands of a full-quality view `width` × `height` and what they cost so far.
#[derive(Clone, Debug, PartialEq)]
pub struct Bands {
    pub width: u32,
    pub height: u32,
    /// Rows `0..rows_done` are rendered.
    pub rows_done: u32,
    /// The last band's cost per pixel, ms.
    last_ms_per_px: Option<f64>,
    /// The time spent on the bands so far, ms.
    spent_ms: f64,
    /// The last band's rows.
    last_rows: Option<u32>,
}

impl Bands {
    #[must_use]
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, rows_done: 0, last_ms_per_px: None, spent_ms: 0.0, last_rows: None }
    }

    /// The next band, sized by [`band_rows`] from the higher of the last whole view's average cost per pixel
    /// (`view_ms_per_px`; [`CPU_GUESS_MS_PER_PX`] before one is measured) and the last band's. Rows cost what their
    /// rays cross: empty rows (above the head) are cheap, and sizing the band after them by their cost alone would
    /// overrun the budget many times over.
    #[must_use]
    pub fn next(&self, view_ms_per_px: Option<f64>) -> std::ops::Range<u32> {
        let floor = view_ms_per_px.unwrap_or(CPU_GUESS_MS_PER_PX);
        // `max` ignores a NaN side; `band_rows` falls back to the guess for what remains unusable.
        let cost = self.last_ms_per_px.map_or(floor, |band| band.max(floor));
        let rows = band_rows(self.width, self.height, cost);
        self.rows_done..self.rows_done.saturating_add(rows).min(self.height)
    }

    /// [`Self::next`] for the refinement thread: the first band is `align` rows, each later one at most twice the
    /// last, or half of it after a band over the budget (a row's cost is only known once rows near it are measured:
    /// the head's rows cost 30 times those above it, and one band sized by the cheap rows would hold the queue for
    /// seconds), and the end is rounded up to a multiple of `align` rows (or the last row), so that bands all start
    /// and end on multiples of `align`.
    #[must_use]
    pub fn next_aligned(&self, view_ms_per_px: Option<f64>, align: u32) -> std::ops::Range<u32> {
        let band = self.next(view_ms_per_px);
        let align = align.max(1);
        let limit = match (self.last_rows, self.last_ms_per_px) {
            (Some(rows), Some(per_px)) => {
                // Over the budget: the cost rises along the rows, and the band's last rows cost more than its mean.
                let over = per_px * f64::from(self.width) * f64::from(rows) > INTERACTIVE_BUDGET_MS;
                if over { rows / 2 } else { rows.saturating_mul(2) }
            }
            _ => align,
        }
        .max(align);
        let end = band.end.min(band.start.saturating_add(limit));
        let end = end.div_ceil(align).saturating_mul(align).min(self.height);
        band.start..end.max(band.start.saturating_add(1)).min(self.height)
    }

    /// Records that `band` (from [`Self::next`]) took `ms`.
    pub fn rendered(&mut self, band: &std::ops::Range<u32>, ms: f64) {
        let rows = band.end.saturating_sub(band.start);
        let pixels = f64::from(self.width) * f64::from(rows);
        self.rows_done = band.end.max(self.rows_done);
        self.last_ms_per_px = Some(ms / pixels.max(1.0));
        self.last_rows = Some(rows);
        self.spent_ms += ms;
    }

    /// Whether every row is rendered.
    #[must_use]
    pub fn done(&self) -> bool {
        self.rows_done >= self.height
    }

    /// The rendered fraction, 0..=1.
    #[must_use]
    pub fn progress(&self) -> f32 {
        self.rows_done as f32 / self.height.max(1) as f32
    }

    /// The average cost per pixel of the rows rendered so far, ms.
    #[must_use]
    pub fn ms_per_px(&self) -> Option<f64> {
        let pixels = f64::from(self.width) * f64::from(self.rows_done);
        (pixels > 0.0).then(|| self.spent_ms / pixels)
    }
}

/// The rows of the bands a refinement thread starts at: llvmpipe shades 4×4 pixel blocks, so a band of one row
/// costs about as much as four, and bands start and end on multiples of this.
pub const BAND_ALIGN_ROWS: u32 = 4;

/// A full-quality 3-D view being rendered band by band into a target of its own, on a thread of its own, while the
/// window shows the reduced one and stays responsive.
///
/// The bands run back to back on the thread, each waited for, so that a UI frame queues behind at most one band
/// ([`INTERACTIVE_BUDGET_MS`]). The UI thread does not draw a frame per band: on a CPU driver egui's own frame costs
/// about as much as a band (it is drawn by the same CPU), so a frame per band would double the time to the full
/// view. It only looks in for the progress now and then, and the thread wakes it when the view is done.
#[derive(Debug)]
pub struct RefineJob {
    size: (u32, u32),
    /// Rows rendered so far.
    rows_done: std::sync::Arc<std::sync::atomic::AtomicU32>,
    cancel: std::sync::Arc<std::sync::atomic::AtomicBool>,
    /// Set while the UI thread works on a frame ([`Self::hold`]): no band starts then.
    held: std::sync::Arc<std::sync::atomic::AtomicBool>,
    done: std::sync::mpsc::Receiver<Result<Refined, String>>,
    /// The thread, joined when the job is dropped so that no band outlives its view (nor the device, at exit).
    thread: Option<std::thread::JoinHandle<()>>,
}

/// What a finished [`RefineJob`] hands back.
#[derive(Debug)]
pub struct Refined {
    pub target: RenderTarget,
    /// The view's average cost per pixel, ms.
    pub ms_per_px: Option<f64>,
}

/// What a refinement thread renders with: the device, the ray caster and the frame's draw data.
#[derive(Debug)]
pub struct RefineWork {
    pub ctx: std::sync::Arc<warpbench_gpu::GpuContext>,
    pub renderer: std::sync::Arc<warpbench_gpu::RaycastRenderer>,
    pub data: warpbench_gpu::RaycastDrawData,
    pub target: RenderTarget,
    /// The last whole view's cost per pixel, ms, for the first band's size.
    pub view_ms_per_px: Option<f64>,
}

impl RefineJob {
    /// Starts rendering `work`'s frame band by band on a new thread, which calls `wake` when it is done.
    ///
    /// # Errors
    /// When the thread cannot be started.
    pub fn start(work: RefineWork, wake: impl FnOnce() + Send + 'static) -> std::io::Result<Self> {
        use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
        let size = (work.target.width, work.target.height);
        let rows_done = std::sync::Arc::new(AtomicU32::new(0));
        let cancel = std::sync::Arc::new(AtomicBool::new(false));
        let (send, done) = std::sync::mpsc::channel();
        let held = std::sync::Arc::new(AtomicBool::new(false));
        let (rows, stop, hold) = (rows_done.clone(), cancel.clone(), held.clone());
        let thread = std::thread::Builder::new().name("refine 3-D view".into()).spawn(move || {
            let RefineWork { ctx, renderer, data, target, view_ms_per_px } = work;
            let mut bands = Bands::new(target.width, target.height);
            let result = loop {
                // On two cores a band beside the UI thread's frame (layout, the autosave, a fit) would make the
                // window answer its input late: the band waits for the frame.
                while hold.load(Ordering::Acquire) && !stop.load(Ordering::Relaxed) {
                    std::thread::sleep(std::time::Duration::from_millis(2));
                }
                if stop.load(Ordering::Relaxed) {
                    // Nobody waits for the image any more.
                    return;
                }
                if bands.done() {
                    break Ok(Refined { ms_per_px: bands.ms_per_px(), target });
                }
                let band = bands.next_aligned(view_ms_per_px, BAND_ALIGN_ROWS);
                let start = std::time::Instant::now();
                let rendered = renderer
                    .render_rows(&ctx, &data, &target, band.clone())
                    .and_then(|()| ctx.wait_idle())
                    .map_err(|e| format!("rendering the 3-D view: {e}"));
                if let Err(e) = rendered {
                    break Err(e);
                }
                bands.rendered(&band, start.elapsed().as_secs_f64() * 1e3);
                rows.store(bands.rows_done, Ordering::Relaxed);
            };
            // The receiver is gone when the view changed meanwhile: nothing to hand back.
            if send.send(result).is_ok() {
                wake();
            }
        })?;
        Ok(Self { size, rows_done, cancel, held, done, thread: Some(thread) })
    }

    /// The size of the view it renders.
    #[must_use]
    pub fn size(&self) -> (u32, u32) {
        self.size
    }

    /// The rendered fraction, 0..=1.
    #[must_use]
    pub fn progress(&self) -> f32 {
        self.rows_done.load(std::sync::atomic::Ordering::Relaxed) as f32 / self.size.1.max(1) as f32
    }

    /// Holds the next band back while `held` (the UI thread sets it for the time of its frame's work).
    pub fn hold(&self, held: bool) {
        self.held.store(held, std::sync::atomic::Ordering::Release);
    }

    /// The finished view, once the thread is done (`None` while it runs).
    #[must_use]
    pub fn poll(&self) -> Option<Result<Refined, String>> {
        match self.done.try_recv() {
            Ok(result) => Some(result),
            Err(std::sync::mpsc::TryRecvError::Empty) => None,
            Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                Some(Err("the thread refining the 3-D view stopped".into()))
            }
        }
    }
}

impl Drop for RefineJob {
    /// A view that changed or closed stops its thread after the band in flight (a band is sized to a frame's
    /// budget), and waits for it: a band still rendering when the window closes would use the device as the process
    /// tears it down.
    fn drop(&mut self) {
        self.cancel.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            // A thread that panicked has nothing left to stop.
            let _ = thread.join();
        }
    }
}

/// The window's frame rate over the last second, from the frames' start times (what the status bar shows).
#[derive(Debug, Default)]
pub struct FrameRate {
    starts: std::collections::VecDeque<std::time::Instant>,
}

impl FrameRate {
    const WINDOW: std::time::Duration = std::time::Duration::from_secs(1);

    /// Records a frame that started at `now`.
    pub fn tick(&mut self, now: std::time::Instant) {
        self.starts.push_back(now);
        while self.starts.front().is_some_and(|&t| now.duration_since(t) > Self::WINDOW) {
            self.starts.pop_front();
        }
    }

    /// Frames per second over the last second; `None` when fewer than two frames started in it (an idle window
    /// draws no frames).
    #[must_use]
    pub fn fps(&self) -> Option<f64> {
        let (first, last) = (self.starts.front()?, self.starts.back()?);
        let span = last.duration_since(*first).as_secs_f64();
        (self.starts.len() >= 2 && span > 0.0).then(|| (self.starts.len() - 1) as f64 / span)
    }

    /// How long after `now` the window must draw once more so that the rate it shows turns to idle if no other
    /// frame comes: just after the last frame has left the one-second window. `None` when it shows idle already.
    ///
    /// An idle window draws nothing, so without this frame the status bar would go on showing the last rate. The
    /// frame it asks for is counted too, but alone in its second it makes no rate, so it asks for no further one.
    #[must_use]
    pub fn redraw_to_idle_in(&self, now: std::time::Instant) -> Option<std::time::Duration> {
        self.fps()?;
        let last = *self.starts.back()?;
        let idle_at = last + Self::WINDOW + std::time::Duration::from_millis(1);
        Some(idle_at.saturating_duration_since(now))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_frame_rate_counts_the_last_second_only() {
        let t0 = std::time::Instant::now();
        let ms = |n: u64| t0 + std::time::Duration::from_millis(n);
        let mut rate = FrameRate::default();
        assert_eq!(rate.fps(), None);
        rate.tick(ms(0));
        assert_eq!(rate.fps(), None, "one frame is no rate");
        // 11 frames 50 ms apart: 20 fps.
        for i in 1..=10 {
            rate.tick(ms(50 * i));
        }
        assert!((rate.fps().expect("a rate") - 20.0).abs() < 1e-9);
        // After a pause, the frames before it no longer count: two frames 100 ms apart, 10 fps.
        rate.tick(ms(5000));
        assert_eq!(rate.fps(), None, "the first frame after an idle second");
        rate.tick(ms(5100));
        assert!((rate.fps().expect("a rate") - 10.0).abs() < 1e-9);
    }

    #[test]
    fn a_window_that_goes_idle_draws_once_more_to_say_so() {
        let t0 = std::time::Instant::now();
        let ms = |n: u64| t0 + std::time::Duration::from_millis(n);
        let mut rate = FrameRate::default();
        rate.tick(ms(0));
        assert_eq!(rate.redraw_to_idle_in(ms(0)), None, "no rate shown, nothing to take back");
        rate.tick(ms(100));
        rate.tick(ms(200));
        // The last frame leaves the window 1 s after it started.
        let wait = rate.redraw_to_idle_in(ms(200)).expect("a rate is shown");
        assert_eq!(wait, std::time::Duration::from_millis(1001));
        // The frame drawn then shows idle and asks for no other.
        let woken = ms(200) + wait;
        rate.tick(woken);
        assert_eq!(rate.fps(), None);
        assert_eq!(rate.redraw_to_idle_in(woken), None);
    }

    #[test]
    fn the_interactive_view_shrinks_to_the_budget_on_cpu_drivers_only() {
        let full = (1000, 500);
        // A GPU (no measurement): full size.
        assert_eq!(interactive_size(full, None), full);
        // Cheap enough already: full size.
        assert_eq!(interactive_size(full, Some(1e-6)), full);
        // 400 ms for 500 000 pixels at full quality: half of that at the interaction rate, scaled down to 60 ms.
        let per_px = 400.0 / 500_000.0;
        let (w, h) = interactive_size(full, Some(per_px));
        let cost = 0.5 * per_px * f64::from(w) * f64::from(h);
        assert!(w < 1000 && (cost - INTERACTIVE_BUDGET_MS).abs() < 0.1 * INTERACTIVE_BUDGET_MS, "{w}x{h}: {cost} ms");
        assert!((f64::from(w) / f64::from(h) - 2.0).abs() < 0.05, "aspect kept: {w}x{h}");
        // Never below an eighth per side (lavapipe's 16 s for this view would ask for less).
        assert_eq!(interactive_size(full, Some(16_000.0 / 500_000.0)), (125, 63));
    }

    #[test]
    fn a_band_fills_the_budget_and_stays_within_the_view() {
        // 4 µs per pixel, 1000 wide: 4 ms per row, 15 rows in 60 ms.
        assert_eq!(band_rows(1000, 700, 4e-3), 15);
        // Cheap: the whole view in one band; absurdly slow: still one row; nonsense costs fall back to the guess
        // (4 µs per pixel, the same 15 rows).
        assert_eq!(band_rows(1000, 700, 1e-9), 700);
        assert_eq!(band_rows(1000, 700, 1e3), 1);
        assert_eq!(band_rows(1000, 700, f64::NAN), 15);
        assert_eq!(band_rows(1000, 700, -1.0), 15);
        // Unmeasured bands use the guess too.
        assert_eq!(Bands::new(1000, 700).next(None), 0..15);
        // Cost at most the budget, within a row of it.
        let per_px = 3.3e-3;
        let rows = band_rows(640, 480, per_px);
        let cost = |r: u32| per_px * 640.0 * f64::from(r);
        assert!(cost(rows) <= INTERACTIVE_BUDGET_MS && cost(rows + 1) > INTERACTIVE_BUDGET_MS, "{rows} rows");
    }

    #[test]
    fn aligned_bands_start_and_end_on_the_alignment_and_cover_the_view_once() {
        // A cost that gives bands of 1 to 7 rows: each is widened to a multiple of 4, the last ends at the bottom.
        let mut bands = Bands::new(100, 103);
        let mut covered = 0;
        while !bands.done() {
            let band = bands.next_aligned(Some(60.0 / (100.0 * f64::from(1 + covered % 7))), BAND_ALIGN_ROWS);
            assert_eq!(band.start, covered, "contiguous");
            assert!(band.start.is_multiple_of(BAND_ALIGN_ROWS), "{band:?} starts off the alignment");
            assert!(band.end.is_multiple_of(BAND_ALIGN_ROWS) || band.end == 103, "{band:?} ends off the alignment");
            assert!(band.len() >= 3, "{band:?} is narrower than the alignment");
            bands.rendered(&band, 1.0);
            covered = band.end;
        }
        assert_eq!(covered, 103);

        // A head below empty rows, as lavapipe renders it (the first view, its cost unknown): 0.6 µs per pixel
        // above row 200, rising over 50 rows to 30 µs inside. The bands start at 4 rows, at most double, and the
        // one that meets the rise holds the queue for at most a few budgets, where one band sized by the cheap rows
        // alone would hold it for seconds.
        let width = 500;
        let us_per_px = |r: u32| 0.6 + 29.4 * (f64::from(r.saturating_sub(200)) / 50.0).min(1.0);
        let row_ms = |r: u32| us_per_px(r) * 1e-3 * f64::from(width);
        let mut bands = Bands::new(width, 600);
        let (mut worst, mut last, mut count) = (0.0_f64, 0, 0);
        while !bands.done() {
            let band = bands.next_aligned(None, BAND_ALIGN_ROWS);
            if last == 0 {
                assert_eq!(band.len(), 4, "the first band is the alignment");
            } else {
                assert!(band.len() <= 2 * last, "{band:?} more than doubles {last} rows");
            }
            let ms: f64 = band.clone().map(row_ms).sum();
            worst = worst.max(ms);
            bands.rendered(&band, ms);
            (last, count) = (band.len(), count + 1);
        }
        assert!(worst <= 3.0 * INTERACTIVE_BUDGET_MS, "a band took {worst:.0} ms");
        let one_band: f64 = (0..600).map(row_ms).sum();
        assert!(count < 150 && one_band > 50.0 * INTERACTIVE_BUDGET_MS, "{count} bands for {one_band:.0} ms");
    }

    #[test]
    fn bands_cover_the_view_once_and_stay_near_the_budget_where_the_cost_changes() {
        // A 500 × 300 view whose rows 0..100 are empty (0.1 µs per pixel) and the rest cost 4 µs per pixel.
        let cost = |row: u32| if row < 100 { 1e-4 } else { 4e-3 };
        let mut bands = Bands::new(500, 300);
        let mut worst_ms = 0.0f64;
        let mut frames = 0;
        while !bands.done() {
            let band = bands.next(None);
            assert_eq!(band.start, bands.rows_done, "bands are contiguous");
            assert!(!band.is_empty(), "a band advances");
            let ms: f64 = band.clone().map(|r| 500.0 * cost(r)).sum();
            worst_ms = worst_ms.max(ms);
            bands.rendered(&band, ms);
            frames += 1;
            assert!(frames < 1000, "does not end");
        }
        assert_eq!(bands.rows_done, 300);
        assert!((bands.progress() - 1.0).abs() < f32::EPSILON);
        // Sized by the empty rows' cost, the band after them would be the whole rest: 200 rows × 2 ms = 400 ms.
        assert!(worst_ms <= INTERACTIVE_BUDGET_MS + 1e-9, "a band took {worst_ms} ms");
        let average = bands.ms_per_px().expect("measured");
        let expected = (100.0 * 1e-4 + 200.0 * 4e-3) / 300.0;
        assert!((average - expected).abs() < 1e-9, "{average} vs {expected}");
        // With the whole view's average known (below the heavy rows' cost), a band over the heavy rows costs at most
        // their cost over the average times the budget, and the next one fits.
        let mut again = Bands::new(500, 300);
        again.rendered(&(0..100), 100.0 * 500.0 * 1e-4);
        let band = again.next(Some(average));
        let ms: f64 = band.clone().map(|r| 500.0 * cost(r)).sum();
        assert!(ms <= 4e-3 / average * INTERACTIVE_BUDGET_MS, "{ms} ms");
        again.rendered(&band, ms);
        let ms: f64 = again.next(Some(average)).map(|r| 500.0 * cost(r)).sum();
        assert!(ms <= INTERACTIVE_BUDGET_MS + 1e-9, "{ms} ms");
    }
}
