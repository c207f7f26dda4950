//! The reports of `warpbench eval`: the `warpbench-eval/1` and `warpbench-eval-suite/1` JSON documents (fields in
//! `docs/cli.md`), the text table, and the suite's markdown section.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::anyhow;
use serde::Serialize;
use warpbench_solver::diagnostics::ErrorStats;

use super::options::{EvalArgs, SuiteOptions, TreStatistic};
use crate::exit::Failure;

/// Schema name of one evaluation.
pub const EVAL_SCHEMA: &str = "warpbench-eval/1";
/// Schema name of a suite.
pub const SUITE_SCHEMA: &str = "warpbench-eval-suite/1";
/// The markers around the suite's generated section of a markdown file.
pub const SUITE_BEGIN: &str = "<!-- eval-suite:begin -->";
pub const SUITE_END: &str = "<!-- eval-suite:end -->";

/// The volume and its foreground.
#[derive(Clone, Debug, Serialize)]
pub struct VolumeSummary {
    pub path: String,
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    /// Otsu's threshold, in the volume's units.
    pub threshold: f64,
    pub foreground_voxels: usize,
    pub foreground_percent: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct WarpSummary {
    pub kind: &'static str,
    pub amplitude_mm: f64,
    pub seed: u64,
}

#[derive(Clone, Debug, Serialize)]
pub struct LandmarkSummary {
    pub count: usize,
    /// "random" or "features".
    pub placement: &'static str,
}

/// Error statistics in mm.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Stats {
    pub count: usize,
    pub mean: f64,
    pub median: f64,
    pub p95: f64,
    pub max: f64,
    pub rms: f64,
}

impl From<&ErrorStats> for Stats {
    fn from(s: &ErrorStats) -> Self {
        Self { count: s.count, mean: s.mean, median: s.median, p95: s.p95, max: s.max, rms: s.rms }
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct JacobianSummary {
    pub min_det: f64,
    pub max_det: f64,
    pub folding_percent: f64,
    /// Cells per axis of the grid over the foreground box.
    pub grid: [usize; 3],
    pub box_min_mm: [f64; 3],
    pub box_max_mm: [f64; 3],
}

/// NCC and RMSE against the ground truth V over V's foreground.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Agreement {
    pub ncc: f64,
    pub rmse: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct ImageSummary {
    pub control_grid: usize,
    pub voxels: usize,
    /// M(u(x)) through the fitted pull-back.
    pub recovered: Agreement,
    /// M itself (no registration).
    pub before: Agreement,
    /// M(ũ(x)) through the same control grid, ũ ≈ d⁻¹ fitted by scattered-data interpolation.
    pub true_warp: Agreement,
    /// ‖d(ũ(y)) − y‖ of that fitted inverse over the fixed box.
    pub true_warp_inverse_consistency_mm: crate::warp::InverseConsistency,
}

/// The accuracy gate of `--max-tre-mm`.
#[derive(Clone, Debug, Serialize)]
pub struct Gate {
    pub max_tre_mm: f64,
    pub statistic: &'static str,
    pub value_mm: f64,
    pub passed: bool,
}

impl Gate {
    #[must_use]
    pub fn new(max_tre_mm: f64, statistic: TreStatistic, tre: &Stats) -> Self {
        let value_mm = match statistic {
            TreStatistic::Mean => tre.mean,
            TreStatistic::Median => tre.median,
            TreStatistic::P95 => tre.p95,
            TreStatistic::Max => tre.max,
        };
        Self { max_tre_mm, statistic: statistic.name(), value_mm, passed: value_mm <= max_tre_mm }
    }
}

/// One evaluation, schema `warpbench-eval/1`.
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    pub schema: &'static str,
    pub volume: VolumeSummary,
    pub warp: WarpSummary,
    pub method: String,
    pub landmarks: LandmarkSummary,
    pub tre_mm: Stats,
    /// `None` (null) when every refit failed.
    pub leave_one_out_mm: Option<Stats>,
    pub leave_one_out_failed: usize,
    pub inverse_consistency_mm: Stats,
    pub jacobian: JacobianSummary,
    pub image: ImageSummary,
    /// Present when `--max-tre-mm` was given.
    pub gate: Option<Gate>,
}

fn stats_row(out: &mut String, label: &str, s: Option<&Stats>) {
    match s {
        Some(s) => {
            let _ =
                writeln!(out, "{label:<24}{:>9.3}{:>9.3}{:>9.3}{:>9.3}{:>8}", s.mean, s.median, s.p95, s.max, s.count);
        }
        None => {
            let _ = writeln!(out, "{label:<24}{:>9}{:>9}{:>9}{:>9}{:>8}", "-", "-", "-", "-", 0);
        }
    }
}

impl EvalReport {
    /// The human-readable report.
    #[must_use]
    pub fn text(&self) -> String {
        let v = &self.volume;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "volume     {} ({}×{}×{}, {:.3}×{:.3}×{:.3} mm)",
            v.path, v.dims[0], v.dims[1], v.dims[2], v.spacing_mm[0], v.spacing_mm[1], v.spacing_mm[2]
        );
        let _ = writeln!(
            out,
            "foreground {} voxels ({:.1} %) above Otsu's threshold {:.4}",
            v.foreground_voxels, v.foreground_percent, v.threshold
        );
        let _ = writeln!(out, "warp       {}, {} mm, seed {}", self.warp.kind, self.warp.amplitude_mm, self.warp.seed);
        let _ =
            writeln!(out, "landmarks  {} ({}), method {}", self.landmarks.count, self.landmarks.placement, self.method);
        let _ = writeln!(out);
        let _ =
            writeln!(out, "{:<24}{:>9}{:>9}{:>9}{:>9}{:>8}", "error (mm)", "mean", "median", "p95", "max", "points");
        stats_row(&mut out, "TRE (held out)", Some(&self.tre_mm));
        stats_row(&mut out, "leave-one-out", self.leave_one_out_mm.as_ref());
        stats_row(&mut out, "inverse consistency", Some(&self.inverse_consistency_mm));
        if self.leave_one_out_failed > 0 {
            let _ = writeln!(out, "({} leave-one-out refits failed)", self.leave_one_out_failed);
        }
        let j = &self.jacobian;
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "Jacobian   det ∇u in [{:.4}, {:.4}], folding {:.3} % ({}×{}×{} cells over the foreground box)",
            j.min_det, j.max_det, j.folding_percent, j.grid[0], j.grid[1], j.grid[2]
        );
        let i = &self.image;
        let _ = writeln!(
            out,
            "image      NCC {:.4}, RMSE {:.3} over {} foreground voxels ({}³ control texture)",
            i.recovered.ncc, i.recovered.rmse, i.voxels, i.control_grid
        );
        let _ = writeln!(
            out,
            "           before registration NCC {:.4}, RMSE {:.3}; through the true warp NCC {:.4}, RMSE {:.3}",
            i.before.ncc, i.before.rmse, i.true_warp.ncc, i.true_warp.rmse
        );
        let c = &i.true_warp_inverse_consistency_mm;
        let _ = writeln!(
            out,
            "           (the true warp inverted by scattered-data interpolation: max {:.4} mm, RMS {:.5} mm)",
            c.max_mm, c.rms_mm
        );
        if let Some(g) = &self.gate {
            let verdict = if g.passed { "passed" } else { "FAILED" };
            let _ =
                writeln!(out, "gate       TRE {} {:.3} mm ≤ {} mm: {verdict}", g.statistic, g.value_mm, g.max_tre_mm);
        }
        out
    }
}

/// A suite, schema `warpbench-eval-suite/1`.
#[derive(Clone, Debug, Serialize)]
pub struct SuiteReport {
    pub schema: &'static str,
    pub volume: VolumeSummary,
    pub amplitude_mm: f64,
    pub seed: u64,
    pub held_out: usize,
    pub placement: &'static str,
    pub control_grid: usize,
    pub kinds: Vec<String>,
    pub landmark_counts: Vec<usize>,
    pub methods: Vec<String>,
    /// UTC date of the run, YYYY-MM-DD.
    pub date: String,
    pub machine: String,
    pub elapsed_s: f64,
    pub cases: Vec<EvalReport>,
}

impl SuiteReport {
    #[must_use]
    pub fn new(
        opts: &EvalArgs,
        suite: &SuiteOptions,
        volume: &VolumeSummary,
        cases: Vec<EvalReport>,
        elapsed_s: f64,
    ) -> Self {
        let threads = std::thread::available_parallelism().map_or(1, std::num::NonZero::get);
        Self {
            schema: SUITE_SCHEMA,
            volume: volume.clone(),
            amplitude_mm: opts.amplitude_mm,
            seed: opts.seed,
            held_out: opts.held_out,
            placement: if opts.on_features { "features" } else { "random" },
            control_grid: opts.grid,
            kinds: suite.kinds.clone(),
            landmark_counts: suite.landmark_counts.clone(),
            methods: suite.methods.iter().map(|m| m.name().to_owned()).collect(),
            date: utc_date(std::time::SystemTime::now()),
            machine: suite.machine.clone().unwrap_or_else(|| format!("machine with {threads} threads")),
            elapsed_s,
            cases,
        }
    }

    /// The generated markdown section, markers included; `markdown` is the file it goes into (for the command line
    /// that regenerates it).
    #[must_use]
    pub fn markdown(&self, markdown: Option<&Path>) -> String {
        let v = &self.volume;
        let mut out = String::new();
        let _ = writeln!(out, "{SUITE_BEGIN}");
        let _ = writeln!(out, "## `warpbench eval --suite` on a real volume (generated)");
        let _ = writeln!(out);
        let paragraph = format!(
            "Volume `{}` ({}×{}×{} voxels of {:.3}×{:.3}×{:.3} mm; foreground: {} voxels above Otsu's threshold \
             {:.4}). Warps of {} mm, seed {}, landmarks {} in the moving volume's foreground, {} held-out foreground \
             points, image metrics through a {}³ control texture. Measured {} on a {} in {:.0} s ({} build). \
             This section is rewritten by:",
            v.path,
            v.dims[0],
            v.dims[1],
            v.dims[2],
            v.spacing_mm[0],
            v.spacing_mm[1],
            v.spacing_mm[2],
            v.foreground_voxels,
            v.threshold,
            self.amplitude_mm,
            self.seed,
            if self.placement == "features" { "on strong-gradient voxels" } else { "random" },
            self.held_out,
            self.control_grid,
            self.date,
            self.machine,
            self.elapsed_s,
            if cfg!(debug_assertions) { "debug" } else { "release" }
        );
        let _ = writeln!(out, "{}", wrap(&paragraph, 118));
        let _ = writeln!(out);
        let _ = writeln!(out, "```sh");
        let _ = writeln!(
            out,
            "cargo run --release -p warpbench-app -- eval --volume {} \\\n    --amplitude-mm {} --seed {}{} \
             --grid {} --suite \\\n    --suite-kinds {} \\\n    --suite-n {} --suite-methods {}{}",
            v.path,
            self.amplitude_mm,
            self.seed,
            if self.placement == "features" { " --on-features" } else { "" },
            self.control_grid,
            self.kinds.join(","),
            self.landmark_counts.iter().map(ToString::to_string).collect::<Vec<_>>().join(","),
            self.methods.join(","),
            markdown.map_or_else(String::new, |p| format!(
                " \\\n    --suite-md {} --machine {:?}",
                p.display(),
                self.machine
            ))
        );
        let _ = writeln!(out, "```");
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "| warp | N | method | TRE mean mm | median | p95 | max | LOO mean mm | inv. cons. mean mm | min det J | \
             folding % | NCC | RMSE |"
        );
        let _ = writeln!(out, "|---|---|---|---|---|---|---|---|---|---|---|---|---|");
        for c in &self.cases {
            let loo = c.leave_one_out_mm.map_or_else(|| "-".to_owned(), |s| format!("{:.3}", s.mean));
            let _ = writeln!(
                out,
                "| {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {loo} | {:.3} | {:.3} | {:.2} | {:.4} | {:.2} |",
                c.warp.kind,
                c.landmarks.count,
                c.method,
                c.tre_mm.mean,
                c.tre_mm.median,
                c.tre_mm.p95,
                c.tre_mm.max,
                c.inverse_consistency_mm.mean,
                c.jacobian.min_det,
                c.jacobian.folding_percent,
                c.image.recovered.ncc,
                c.image.recovered.rmse
            );
        }
        let _ = writeln!(out);
        let _ = writeln!(out, "For scale, the image metrics of the moving volume itself and through the true warp:");
        let _ = writeln!(out);
        let _ = writeln!(out, "| warp | NCC before | RMSE before | NCC true warp | RMSE true warp |");
        let _ = writeln!(out, "|---|---|---|---|---|");
        let mut seen = Vec::new();
        for c in &self.cases {
            if !seen.contains(&c.warp.kind) {
                seen.push(c.warp.kind);
                let i = &c.image;
                let _ = writeln!(
                    out,
                    "| {} | {:.4} | {:.2} | {:.4} | {:.2} |",
                    c.warp.kind, i.before.ncc, i.before.rmse, i.true_warp.ncc, i.true_warp.rmse
                );
            }
        }
        let _ = writeln!(out, "{SUITE_END}");
        out
    }
}

/// `text` with its spaces turned into line breaks so that lines stay within `width` characters (longer words stand
/// alone).
fn wrap(text: &str, width: usize) -> String {
    let mut out = String::new();
    let mut line = 0;
    for word in text.split(' ') {
        let len = word.chars().count();
        if line > 0 && line + 1 + len > width {
            out.push('\n');
            line = 0;
        } else if line > 0 {
            out.push(' ');
            line += 1;
        }
        out.push_str(word);
        line += len;
    }
    out
}

/// Writes `value` as pretty JSON to `path`, atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<(), Failure> {
    let text = serde_json::to_string_pretty(value).map_err(|e| Failure::Internal(anyhow!("JSON report: {e}")))?;
    warpbench_io::atomic::write_atomic(path, |w| {
        w.write_all(text.as_bytes())?;
        w.write_all(b"\n")
    })?;
    Ok(())
}

/// `text` with the section between [`SUITE_BEGIN`] and [`SUITE_END`] replaced by `section` (which carries its own
/// markers), or with `section` appended when the markers are absent.
pub fn splice_section(text: &str, section: &str) -> Result<String, String> {
    match (text.find(SUITE_BEGIN), text.find(SUITE_END)) {
        (Some(begin), Some(end)) if end > begin => {
            let after = &text[end + SUITE_END.len()..];
            let after = after.strip_prefix('\n').unwrap_or(after);
            Ok(format!("{}{section}{after}", &text[..begin]))
        }
        (None, None) => {
            let sep = if text.is_empty() || text.ends_with("\n\n") {
                ""
            } else if text.ends_with('\n') {
                "\n"
            } else {
                "\n\n"
            };
            Ok(format!("{text}{sep}{section}"))
        }
        _ => Err(format!("has a broken generated section: it needs {SUITE_BEGIN} followed by {SUITE_END}")),
    }
}

/// Replaces (or adds) the suite's section of the markdown file at `path` (created when missing).
pub fn replace_section(path: &Path, section: &str) -> Result<(), Failure> {
    let text = match std::fs::read_to_string(path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => String::new(),
        Err(e) => return Err(Failure::BadInput(anyhow!("{}: {e}", path.display()))),
    };
    let updated = splice_section(&text, section).map_err(|e| Failure::BadInput(anyhow!("{}: {e}", path.display())))?;
    warpbench_io::atomic::write_atomic(path, |w| w.write_all(updated.as_bytes()))?;
    Ok(())
}

/// `time` as a UTC date, YYYY-MM-DD (days to civil date: Hinnant, "chrono-Compatible Low-Level Date Algorithms").
#[must_use]
pub fn utc_date(time: std::time::SystemTime) -> String {
    let secs = time.duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let z = (secs / 86_400) as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}-{month:02}-{day:02}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_keeps_words_and_width() {
        let text = "aa bbb cccc dd eeeeeeeeeeee f";
        let wrapped = wrap(text, 8);
        assert_eq!(wrapped, "aa bbb\ncccc dd\neeeeeeeeeeee\nf");
        assert_eq!(wrapped.replace('\n', " "), text);
    }

    #[test]
    fn dates_are_civil() {
        let at = |s: u64| utc_date(std::time::UNIX_EPOCH + std::time::Duration::from_secs(s));
        assert_eq!(at(0), "1970-01-01");
        assert_eq!(at(951_782_400), "2000-02-29");
        assert_eq!(at(1_795_305_600), "2026-11-22");
    }

    #[test]
    fn the_section_is_replaced_appended_or_refused() {
        let section = format!("{SUITE_BEGIN}\nnew\n{SUITE_END}\n");
        let old = format!("# A\ntext\n\n{SUITE_BEGIN}\nold\n{SUITE_END}\n## B\n");
        assert_eq!(splice_section(&old, &section).expect("markers"), format!("# A\ntext\n\n{section}## B\n"));
        assert_eq!(splice_section("# A\n", &section).expect("append"), format!("# A\n\n{section}"));
        assert_eq!(splice_section("", &section).expect("new file"), section);
        assert!(splice_section(&format!("{SUITE_END}\n{SUITE_BEGIN}"), &section).is_err());
        assert!(splice_section(SUITE_BEGIN, &section).is_err());
    }
}
