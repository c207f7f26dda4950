//! `warpbench eval`: how well a landmark warp recovers a **known** deformation of a real volume.
//!
//! # Definitions
//!
//! Let V be the real volume (`--volume`), on its own grid, and d = `fixed_from_moving` a seeded synthetic forward
//! warp ([`warpbench_solver::synthetic`], `--kind`, `--amplitude-mm` A, `--seed`) over V's box of voxel edges Ω.
//!
//! - **Fixed** = V. **Moving** M = V deformed by d: M(y) = V(d(y)) on V's grid (export of V through d sampled at
//!   every voxel centre of the grid, trilinear, f32), so that M(u_true(x)) = V(x) with the true pull-back
//!   u_true = d⁻¹ = `moving_from_fixed`: the ground truth is exact up to the interpolation of V.
//! - **Foreground**: the voxels above Otsu's threshold ([`sampling`]); of V for fixed-space points, of M for
//!   moving-space points.
//! - **Landmarks** (`--landmarks` N): p_i in M's foreground (random, or on strong-gradient voxels with
//!   `--on-features`), q_i = d(p_i) (pairs whose q_i leaves Ω are redrawn).
//! - **Fit**: the pull-back u = `moving_from_fixed` fitted on the reversed pairs (q_i → p_i) with `--method`, as the
//!   renderer and the exporter use it, and the forward warp d̂ fitted on (p_i → q_i).
//! - **TRE** at held-out points: x_j, j = 1..H (`--held-out`, default and minimum 1 000) uniform in V's foreground
//!   (random voxels, uniform inside each; a different random stream from the landmarks), TRE_j = ‖u(x_j) −
//!   u_true(x_j)‖ in mm, with u_true(x_j) = d⁻¹(x_j) by the synthetic warp's inverse (to 10⁻⁹ mm). Reported as
//!   mean, median, 95th percentile (nearest rank), max and RMS.
//! - **Leave-one-out** error of landmark i: ‖u₋ᵢ(q_i) − p_i‖, u₋ᵢ refitted without pair i
//!   ([`warpbench_solver::diagnostics::leave_one_out`]).
//! - **Inverse consistency** at the held-out points: ‖d̂(u(x_j)) − x_j‖ (the two fitted directions; the solver fits
//!   both directly, which is what `render` and the app use, so this is the consistency they show).
//! - **Jacobian** of u: det ∇u at the cell centres of a grid over the box around V's foreground (2 mm cells, at most
//!   64 per axis; [`warpbench_solver::diagnostics::jacobian_determinants`]): the minimum and the folding
//!   percentage, 100 × (cells with det ≤ 0) / cells.
//! - **Image agreement**: the recovered volume R(x) = M(u(x)) (M exported through u sampled into a `--grid`³
//!   control texture over Ω, exactly as the renderer shows it) against the ground truth V, over V's foreground
//!   voxels: NCC = Σ(R − R̄)(V − V̄) / √(Σ(R − R̄)² Σ(V − V̄)²) and RMSE = √(mean (R − V)²) in V's units. For
//!   scale, the same numbers for M itself (before registration) and for M(ũ(x)) through the same control grid
//!   (the best any warp can do after two interpolations), ũ ≈ d⁻¹ fitted by scattered-data interpolation
//!   ([`warpbench_solver::invert`], as the product inverts every forward-only deformation), with its inverse
//!   consistency ‖d(ũ(y)) − y‖ over a 32³ grid of Ω.
//!
//! `--max-tre-mm X` is an accuracy gate: when the TRE statistic `--gate-statistic` (default the 95th percentile) is
//! above X, the report is still printed and written, and the exit code is 3.
//!
//! `--suite` runs the grid kinds × N × methods ([`SuiteOptions`]) on one volume, shows a progress bar, and writes a
//! markdown table (into a marked section of `--suite-md`) and, with `--json`, every case's report.

mod options;
mod report;
pub mod sampling;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::anyhow;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use warpbench_gpu::export::{ExportRequest, ExportSamples, OutputType, PullBack, SourceVolume, TargetGrid, export_cpu};
use warpbench_gpu::{ControlDesc, ExportedSamples};
use warpbench_io::Volume;
use warpbench_io::geometry::Point3;
use warpbench_solver::control::{ControlGrid, ControlTexture};
use warpbench_solver::diagnostics::{ErrorStats, jacobian_determinants};
use warpbench_solver::invert::{InvertParams, invert};
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Aabb, Fixed, Moving};
use warpbench_solver::synthetic::{SyntheticKind, SyntheticWarp};
use warpbench_solver::warp::{Parallelism, Warp};

pub use options::{EvalArgs, MIN_HELD_OUT, SuiteArgs, SuiteOptions, TreStatistic};
pub use report::{EvalReport, SUITE_BEGIN, SUITE_END, SuiteReport};

use crate::exit::Failure;
use crate::settings::MethodKind;
use crate::warp::InverseConsistency;
use crate::{fit, inputs, scene};
use sampling::SplitMix64;

/// Cell size of the Jacobian grid, mm, and its most cells per axis.
const JACOBIAN_CELL_MM: f64 = 2.0;
const JACOBIAN_MAX_CELLS: usize = 64;

/// Random streams of [`SplitMix64`] (module docs): held-out points; landmarks use `LANDMARK_STREAM + N`.
const HELD_OUT_STREAM: u64 = 1;
const LANDMARK_STREAM: u64 = 1 << 32;

fn bad(message: String) -> Failure {
    Failure::BadInput(anyhow!(message))
}

/// Runs `warpbench eval` (a single evaluation, or the suite), writing the text report to `out`.
pub fn run(opts: &EvalArgs, out: &mut dyn Write) -> Result<(), Failure> {
    let suite = opts.suite.options();
    let plan = Plan::new(opts, suite.as_ref())?;
    if let Some(json) = &opts.json {
        inputs::check_output(json, &[&opts.volume], opts.force).map_err(Failure::BadInput)?;
    }
    let started = Instant::now();
    let subject = Subject::load(&opts.volume, opts.quiet)?;
    let bar = case_bar(opts.quiet, plan.case_count());
    let mut reports = Vec::with_capacity(plan.case_count());
    for &kind in &plan.kinds {
        bar.set_message(format!("{kind}: moving volume, truth"));
        let truth = Truth::new(&subject, kind, opts)?;
        for &n in &plan.landmark_counts {
            let pairs = truth.landmarks(&subject, n, opts)?;
            for method in &plan.methods {
                let case = format!("{kind}, N = {n}, {method}");
                let progress = |what: &str, count: Option<(usize, usize)>| match count {
                    None => bar.set_message(format!("{case}: {what}")),
                    Some((done, total)) => bar.set_message(format!("{case}: {what} {done}/{total}")),
                };
                reports.push(evaluate(&subject, &truth, &pairs, method, opts, &progress)?);
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    let write_err = |e: std::io::Error| Failure::Internal(anyhow!("writing the report: {e}"));
    if let Some(suite) = &suite {
        let report = SuiteReport::new(opts, suite, &subject.summary(), reports, started.elapsed().as_secs_f64());
        let section = report.markdown(suite.markdown.as_deref());
        match &suite.markdown {
            Some(path) => {
                report::replace_section(path, &section)?;
                writeln!(
                    out,
                    "{} cases in {:.1} s; wrote the table into {}",
                    report.cases.len(),
                    report.elapsed_s,
                    path.display()
                )
                .map_err(write_err)?;
            }
            None => out.write_all(section.as_bytes()).map_err(write_err)?,
        }
        if let Some(json) = &opts.json {
            report::write_json(json, &report)?;
        }
        return Ok(());
    }
    let Some(mut report) = reports.pop() else {
        return Err(Failure::Internal(anyhow!("no evaluation ran")));
    };
    report.gate = opts.max_tre_mm.map(|max| report::Gate::new(max, opts.gate_statistic, &report.tre_mm));
    out.write_all(report.text().as_bytes()).map_err(write_err)?;
    if let Some(json) = &opts.json {
        report::write_json(json, &report)?;
    }
    match &report.gate {
        Some(g) if !g.passed => Err(Failure::AccuracyGate(anyhow!(
            "{}: TRE {} {:.3} mm exceeds --max-tre-mm {} mm ({} warp of {} mm, N = {}, {})",
            opts.volume.display(),
            g.statistic,
            g.value_mm,
            g.max_tre_mm,
            report.warp.kind,
            report.warp.amplitude_mm,
            report.landmarks.count,
            report.method
        ))),
        _ => Ok(()),
    }
}

/// The bar of the cases, on stderr unless `quiet` (and drawn only on a terminal, like every progress bar here). Its
/// message names the case and its stage ([`STAGES`]), and it ticks, so the elapsed time moves during a long stage.
fn case_bar(quiet: bool, cases: usize) -> ProgressBar {
    let target = if quiet { ProgressDrawTarget::hidden() } else { ProgressDrawTarget::stderr() };
    let bar = ProgressBar::with_draw_target(Some(cases as u64), target);
    let style = ProgressStyle::with_template("{msg:>32} [{bar:30}] {pos}/{len} {elapsed}")
        .map_or_else(|_| ProgressStyle::default_bar(), |s| s.progress_chars("=> "));
    bar.set_style(style);
    if !quiet {
        bar.enable_steady_tick(std::time::Duration::from_millis(200));
    }
    bar
}

/// The checked grid of cases.
struct Plan {
    kinds: Vec<SyntheticKind>,
    landmark_counts: Vec<usize>,
    methods: Vec<Method>,
}

impl Plan {
    /// The cases of `opts`: one, or the grid of `suite` (`--suite`).
    fn new(opts: &EvalArgs, suite: Option<&SuiteOptions>) -> Result<Self, Failure> {
        let (kinds, counts, methods): (Vec<String>, Vec<usize>, Vec<MethodKind>) = match suite {
            Some(s) => (s.kinds.clone(), s.landmark_counts.clone(), s.methods.clone()),
            None => (vec![opts.kind.clone()], vec![opts.landmarks], vec![opts.method]),
        };
        if suite.is_some() && opts.max_tre_mm.is_some() {
            return Err(bad("--max-tre-mm gates a single evaluation; it cannot be combined with --suite".into()));
        }
        if kinds.is_empty() || counts.is_empty() || methods.is_empty() {
            return Err(bad("--suite needs at least one kind, one landmark count and one method".into()));
        }
        let kinds = kinds
            .iter()
            .map(|k| k.parse::<SyntheticKind>().map_err(|e| bad(format!("--kind: {e}"))))
            .collect::<Result<Vec<_>, _>>()?;
        let methods = methods
            .iter()
            .map(|&m| inputs::checked_method(m, opts.stiffness, opts.levels))
            .collect::<Result<Vec<_>, _>>()
            .map_err(Failure::BadInput)?;
        for &n in &counts {
            for m in &methods {
                let needed = inputs::min_pairs(m) + 1;
                if n < needed {
                    return Err(bad(format!(
                        "--landmarks {n} is too few for {m}: it needs at least {needed} (its minimum plus one, so \
                         that leave-one-out can refit)"
                    )));
                }
            }
        }
        if !(opts.amplitude_mm.is_finite() && opts.amplitude_mm > 0.0) {
            return Err(bad(format!("--amplitude-mm {} must be a number > 0", opts.amplitude_mm)));
        }
        if opts.held_out < MIN_HELD_OUT {
            return Err(bad(format!("--held-out {} is below the minimum of {MIN_HELD_OUT}", opts.held_out)));
        }
        if let Some(max) = opts.max_tre_mm
            && !(max.is_finite() && max >= 0.0)
        {
            return Err(bad(format!("--max-tre-mm {max} must be a number ≥ 0")));
        }
        if !(2..=256).contains(&opts.grid) {
            return Err(bad(format!("--grid {} must be 2..=256 texels", opts.grid)));
        }
        Ok(Self { kinds, landmark_counts: counts, methods })
    }

    fn case_count(&self) -> usize {
        self.kinds.len() * self.landmark_counts.len() * self.methods.len()
    }
}

/// The real volume V and what every case derives from it once.
struct Subject {
    path: PathBuf,
    volume: Volume,
    /// V's samples as f32.
    values: Vec<f32>,
    /// Ω, V's box of voxel edges (fixed space; the moving volume shares V's grid).
    box_fixed: Aabb<Fixed>,
    threshold: f64,
    /// V's foreground voxels (linear indices).
    foreground: Vec<usize>,
    /// The box around V's foreground voxels (grown by half a voxel).
    foreground_box: Aabb<Fixed>,
    /// The value of exported voxels that map outside the volume: V's minimum.
    outside_value: f64,
}

impl Subject {
    fn load(path: &Path, quiet: bool) -> Result<Self, Failure> {
        let volume = inputs::load_volume(&inputs::VolumeArg::other(path), quiet).map_err(Failure::BadInput)?;
        let values = volume.data.to_f32();
        let threshold = sampling::otsu_threshold(&values).ok_or_else(|| {
            bad(format!("{}: the volume has fewer than two distinct values, so no foreground", path.display()))
        })?;
        let foreground = sampling::foreground(&values, threshold);
        let centres: Vec<Point3<Fixed>> =
            foreground.iter().map(|&i| Point3::from_array(sampling::voxel_centre(&volume, i))).collect();
        let half_voxel = 0.5 * volume.spacing_mm().into_iter().fold(0.0, f64::max);
        let foreground_box = Aabb::around(&centres, half_voxel)
            .ok_or_else(|| bad(format!("{}: no voxel is above the foreground threshold", path.display())))?;
        let outside_value = volume.data.finite_range().map_or(0.0, |(lo, _)| lo);
        let box_fixed = inputs::volume_box::<Fixed>(&volume);
        Ok(Self {
            path: path.to_owned(),
            volume,
            values,
            box_fixed,
            threshold,
            foreground,
            foreground_box,
            outside_value,
        })
    }

    fn box_moving(&self) -> Aabb<Moving> {
        Aabb::new(Point3::from_array(self.box_fixed.min.coords()), Point3::from_array(self.box_fixed.max.coords()))
    }

    fn summary(&self) -> report::VolumeSummary {
        report::VolumeSummary {
            path: self.path.display().to_string(),
            dims: self.volume.dims,
            spacing_mm: self.volume.spacing_mm(),
            threshold: self.threshold,
            foreground_voxels: self.foreground.len(),
            foreground_percent: 100.0 * self.foreground.len() as f64 / self.values.len().max(1) as f64,
        }
    }

    /// `samples` (on V's grid) resampled onto V's grid through `control`, as f32.
    fn export(&self, samples: ExportSamples<'_>, control: ControlDesc<'_>) -> Result<Vec<f32>, Failure> {
        let grid = self.volume.lps_from_index.rows();
        let source = SourceVolume { dims: self.volume.dims, samples, lps_from_index: grid };
        let target = TargetGrid { dims: self.volume.dims, lps_from_index: grid };
        let mut request = ExportRequest::new(source, target, PullBack::Control(control));
        request.output = OutputType::F32;
        request.outside_value = self.outside_value;
        let exported = export_cpu(&request, &mut |_| true)
            .map_err(|e| Failure::Internal(anyhow!("{}: resampling: {e}", self.path.display())))?;
        match exported.samples {
            ExportedSamples::F32(v) => Ok(v),
            other => Err(Failure::Internal(anyhow!("export returned {:?} samples, not f32", other.sample_type()))),
        }
    }

    /// NCC and RMSE of `recovered` against V over V's foreground.
    fn agreement(&self, recovered: &[f32]) -> report::Agreement {
        let n = self.foreground.len() as f64;
        let (mut sa, mut sb) = (0.0, 0.0);
        for &i in &self.foreground {
            sa += f64::from(recovered[i]);
            sb += f64::from(self.values[i]);
        }
        let (ma, mb) = (sa / n, sb / n);
        let (mut sab, mut saa, mut sbb, mut se) = (0.0, 0.0, 0.0, 0.0);
        for &i in &self.foreground {
            let (a, b) = (f64::from(recovered[i]), f64::from(self.values[i]));
            sab += (a - ma) * (b - mb);
            saa += (a - ma) * (a - ma);
            sbb += (b - mb) * (b - mb);
            se += (a - b) * (a - b);
        }
        let ncc = if saa > 0.0 && sbb > 0.0 { sab / (saa * sbb).sqrt() } else { 0.0 };
        report::Agreement { ncc, rmse: (se / n).sqrt() }
    }

    /// A pull-back through `control`, its control texture over Ω (made by [`scene::control_texture`], or by
    /// [`fit::control_texture`] for a fitted one), applied to the moving volume.
    fn recover(&self, moving: &[f32], (grid, texture): &(ControlGrid, ControlTexture)) -> Result<Vec<f32>, Failure> {
        self.export(ExportSamples::F32(moving), scene::control_desc(grid, texture))
    }
}

/// One synthetic warp on the subject: the moving volume, the held-out points and their true pull-back.
struct Truth {
    warp: SyntheticWarp,
    /// M(y) = V(d(y)) on V's grid.
    moving: Vec<f32>,
    moving_foreground: Vec<usize>,
    x_fixed: Vec<Point3<Fixed>>,
    /// u_true(x_j) = d⁻¹(x_j).
    u_true: Vec<Point3<Moving>>,
    before: report::Agreement,
    /// M(ũ(x)), ũ ≈ d⁻¹ fitted by scattered-data interpolation, through the control grid.
    ideal: report::Agreement,
    /// ‖d(ũ(y)) − y‖ over the fixed box.
    inverse_consistency: InverseConsistency,
}

impl Truth {
    fn new(subject: &Subject, kind: SyntheticKind, opts: &EvalArgs) -> Result<Self, Failure> {
        let path = subject.path.display();
        let warp = SyntheticWarp::new(kind, subject.box_moving(), opts.amplitude_mm, opts.seed)
            .map_err(|e| bad(format!("{path}: --kind {kind} --amplitude-mm {}: {e}", opts.amplitude_mm)))?;
        // d sampled at the voxel centres of V's grid (texel centres of a dims-sized texture over the voxel-edge box
        // are the voxel centres): the export then evaluates V(d(y)) at every voxel y up to f32 round-off.
        let dims = subject.volume.dims.map(|n| n.clamp(2, warpbench_solver::control::MAX_TEXELS));
        let texels = forward_texels(&warp, dims, subject.box_moving());
        let control = ControlDesc {
            dims,
            texels: &texels,
            box_min_ref: subject.box_fixed.min.coords(),
            box_max_ref: subject.box_fixed.max.coords(),
        };
        let moving = subject.export(scene::export_samples(&subject.volume.data), control)?;
        drop(texels);
        let moving_foreground = sampling::foreground(&moving, subject.threshold);

        if subject.foreground.len() < opts.held_out {
            return Err(bad(format!(
                "{path}: the foreground has {} voxels, fewer than the {} held-out points",
                subject.foreground.len(),
                opts.held_out
            )));
        }
        let mut rng = SplitMix64::new(opts.seed, HELD_OUT_STREAM);
        let points = sampling::random_points(&subject.volume, &subject.foreground, opts.held_out, &mut rng, |_| true);
        let mut x_fixed = Vec::with_capacity(points.len());
        let mut u_true = Vec::with_capacity(points.len());
        for x in points {
            let inverse = warp.invert_point_raw(x);
            if !inverse.converged {
                return Err(bad(format!(
                    "{path}: the {kind} warp of {} mm cannot be inverted at {x:?} mm (residual {:.3e} mm); use a \
                     smaller --amplitude-mm",
                    opts.amplitude_mm, inverse.residual_mm
                )));
            }
            x_fixed.push(Point3::from_array(x));
            u_true.push(Point3::from_array(inverse.point));
        }
        let before = subject.agreement(&moving);
        // For the picture, d is what a forward-only deformation is to the renderer (a brush, a forward field): its
        // pull-back comes from scattered-data interpolation (`solver::invert`, Brunet et al. 2006 §3.3), sampled
        // into the control texture, and how well that inverse undoes d is reported with the image it gives.
        let (inverse, inverse_report) =
            invert(&warp, subject.box_moving(), subject.box_fixed, &InvertParams::default())
                .map_err(|e| bad(format!("{path}: inverting the {kind} warp of {} mm: {e}", opts.amplitude_mm)))?;
        let control = scene::control_texture(&inverse, subject.box_fixed, opts.grid).map_err(Failure::BadInput)?;
        let ideal = subject.agreement(&subject.recover(&moving, &control)?);
        let inverse_consistency = InverseConsistency {
            rms_mm: inverse_report.rms_mm,
            max_mm: inverse_report.max_mm,
            points: inverse_report.check_points,
        };
        Ok(Self { warp, moving, moving_foreground, x_fixed, u_true, before, ideal, inverse_consistency })
    }

    /// N landmark pairs (p_i in M's foreground, q_i = d(p_i) inside Ω).
    fn landmarks(&self, subject: &Subject, n: usize, opts: &EvalArgs) -> Result<Pairs, Failure> {
        let mut rng = SplitMix64::new(opts.seed, LANDMARK_STREAM + n as u64);
        let inside = |p: [f64; 3]| subject.box_fixed.contains(&Point3::from_array(self.warp.apply_raw(p)));
        let points = if opts.on_features {
            sampling::feature_points(&subject.volume, &self.moving, &self.moving_foreground, n, &mut rng, inside)
        } else {
            sampling::random_points(&subject.volume, &self.moving_foreground, n, &mut rng, inside)
        };
        if points.len() < n {
            return Err(bad(format!(
                "{}: could place only {} of {n} landmarks in the moving volume's foreground ({} voxels)",
                subject.path.display(),
                points.len(),
                self.moving_foreground.len()
            )));
        }
        let p_moving: Vec<Point3<Moving>> = points.into_iter().map(Point3::from_array).collect();
        let q_fixed = p_moving.iter().map(|p| self.warp.apply(*p)).collect();
        Ok(Pairs { p_moving, q_fixed })
    }
}

/// The landmark pairs of one (kind, N).
struct Pairs {
    p_moving: Vec<Point3<Moving>>,
    q_fixed: Vec<Point3<Fixed>>,
}

/// d(y) − y at the texel centres of a `dims` texture over `domain` (x fastest), as `[dx, dy, dz, 0]` f32.
fn forward_texels(warp: &SyntheticWarp, dims: [usize; 3], domain: Aabb<Moving>) -> Vec<f32> {
    let (min, size) = (domain.min.coords(), domain.size());
    let mut texels = Vec::with_capacity(4 * dims.iter().product::<usize>());
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let abc = [i, j, k];
                let y: [f64; 3] = std::array::from_fn(|a| min[a] + (abc[a] as f64 + 0.5) / dims[a] as f64 * size[a]);
                let d = warp.displacement_raw(y);
                texels.extend([d[0] as f32, d[1] as f32, d[2] as f32, 0.0]);
            }
        }
    }
    texels
}

fn stats(values: &[f64], what: &str) -> Result<ErrorStats, Failure> {
    ErrorStats::of(values).ok_or_else(|| Failure::Internal(anyhow!("{what}: no finite value")))
}

/// The steps of one evaluation case, in order, as the progress bar names them.
pub const STAGES: [&str; 6] = [
    "fitting the pull-back",
    "fitting the forward warp",
    "held-out errors",
    "leave-one-out",
    "Jacobian",
    "recovering the image",
];

/// Fits `method` both ways on `pairs` and measures it against the truth (module docs), calling `progress` with each
/// of [`STAGES`] as it starts (and `None`), and during the leave-one-out refits with how many of the N are done (for
/// a TPS there are none: its leave-one-out errors come in closed form from one solve).
fn evaluate(
    subject: &Subject,
    truth: &Truth,
    pairs: &Pairs,
    method: &Method,
    opts: &EvalArgs,
    progress: &(dyn Fn(&'static str, Option<(usize, usize)>) + Sync),
) -> Result<EvalReport, Failure> {
    let stage = |what: &'static str| progress(what, None);
    let n = pairs.p_moving.len();
    let fit_error = |dir: &str, e: warpbench_solver::SolverError| {
        bad(format!("{}: fitting the {method} {dir} to {n} landmark pairs: {e}", subject.path.display()))
    };
    let (box_fixed, box_moving) = (subject.box_fixed, subject.box_moving());
    stage(STAGES[0]);
    let moving_from_fixed =
        fit::pullback(method, &pairs.q_fixed, &pairs.p_moving, box_fixed).map_err(|e| fit_error("pull-back", e))?;
    stage(STAGES[1]);
    let fixed_from_moving =
        fit::forward(method, &pairs.q_fixed, &pairs.p_moving, box_moving).map_err(|e| fit_error("forward warp", e))?;

    stage(STAGES[2]);
    let tre: Vec<f64> =
        truth.x_fixed.iter().zip(&truth.u_true).map(|(x, t)| moving_from_fixed.apply(*x).distance(t)).collect();
    let consistency: Vec<f64> =
        truth.x_fixed.iter().map(|x| fixed_from_moving.apply(moving_from_fixed.apply(*x)).distance(x)).collect();
    // A TPS in closed form from one solve; refitting it N times was O(N⁴): 2 000 pairs ran for hours.
    stage(STAGES[3]);
    let refits = AtomicUsize::new(0);
    let refitted = || progress(STAGES[3], Some((refits.fetch_add(1, Ordering::Relaxed) + 1, n)));
    let loo = method.leave_one_out_reporting(&pairs.q_fixed, &pairs.p_moving, box_fixed, Parallelism::Rayon, &refitted);
    let loo_values: Vec<f64> = loo.iter().flatten().copied().collect();

    stage(STAGES[4]);
    let fg = subject.foreground_box;
    let jacobian_dims = fg.size().map(|s| ((s / JACOBIAN_CELL_MM).ceil() as usize).clamp(1, JACOBIAN_MAX_CELLS));
    let jacobian = jacobian_determinants(&moving_from_fixed, &fg, jacobian_dims, Parallelism::Rayon);

    stage(STAGES[5]);
    let control = fit::control_texture(&moving_from_fixed, box_fixed, opts.grid).map_err(Failure::BadInput)?;
    let recovered = subject.recover(&truth.moving, &control)?;
    let after = subject.agreement(&recovered);

    Ok(EvalReport {
        schema: report::EVAL_SCHEMA,
        volume: subject.summary(),
        warp: report::WarpSummary {
            kind: truth.warp.kind().name(),
            amplitude_mm: truth.warp.amplitude_mm(),
            seed: truth.warp.seed(),
        },
        method: method.to_string(),
        landmarks: report::LandmarkSummary {
            count: n,
            placement: if opts.on_features { "features" } else { "random" },
        },
        tre_mm: report::Stats::from(&stats(&tre, "TRE")?),
        leave_one_out_mm: ErrorStats::of(&loo_values).map(|s| report::Stats::from(&s)),
        leave_one_out_failed: loo.len() - loo_values.len(),
        inverse_consistency_mm: report::Stats::from(&stats(&consistency, "inverse consistency")?),
        jacobian: report::JacobianSummary {
            min_det: jacobian.min_det,
            max_det: jacobian.max_det,
            folding_percent: 100.0 * jacobian.fraction_folded,
            grid: jacobian_dims,
            box_min_mm: fg.min.coords(),
            box_max_mm: fg.max.coords(),
        },
        image: report::ImageSummary {
            control_grid: opts.grid,
            voxels: subject.foreground.len(),
            recovered: after,
            before: truth.before,
            true_warp: truth.ideal,
            true_warp_inverse_consistency_mm: truth.inverse_consistency,
        },
        gate: None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn subject() -> Subject {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/nifti/avg152T1_LR_nifti.nii");
        Subject::load(&path, true).expect("fixture")
    }

    /// V at a continuous index by trilinear interpolation (None outside the voxel-centre hull).
    fn trilinear(v: &Volume, values: &[f32], idx: [f64; 3]) -> Option<f64> {
        if (0..3).any(|a| idx[a] < 0.0 || idx[a] > (v.dims[a] - 1) as f64) {
            return None;
        }
        let base = idx.map(|c| c.floor() as usize);
        let mut acc = 0.0;
        for corner in 0..8 {
            let mut w = 1.0;
            let mut at = [0; 3];
            for a in 0..3 {
                let up = corner >> a & 1 == 1;
                let f = idx[a] - base[a] as f64;
                at[a] = (base[a] + usize::from(up)).min(v.dims[a] - 1);
                w *= if up { f } else { 1.0 - f };
            }
            acc += w * f64::from(values[at[0] + v.dims[0] * (at[1] + v.dims[1] * at[2])]);
        }
        Some(acc)
    }

    /// Every stage of a case is announced as it starts, in order, so that a long one (a large N) names itself on the
    /// progress bar; and the leave-one-out errors of a TPS (in closed form) are those of N refits.
    #[test]
    fn an_evaluation_reports_its_stages_and_the_tps_leave_one_out_matches_refits() {
        let s = subject();
        let mut opts = EvalArgs::new(s.path.clone());
        opts.grid = 4;
        opts.landmarks = 30;
        let truth = Truth::new(&s, SyntheticKind::Sine, &opts).expect("truth");
        let pairs = truth.landmarks(&s, opts.landmarks, &opts).expect("landmarks");
        let method = Method::from_name("tps").expect("tps");
        let seen = std::sync::Mutex::new(Vec::new());
        let record = |stage: &'static str, count: Option<(usize, usize)>| {
            seen.lock().expect("not poisoned").push((stage, count));
        };
        let report = evaluate(&s, &truth, &pairs, &method, &opts, &record).expect("evaluate");
        let seen = seen.into_inner().expect("not poisoned");
        assert_eq!(seen, STAGES.map(|stage| (stage, None)), "a TPS does not refit");
        // A method that refits reports each refit, and reaches N.
        let rigid = Method::from_name("rigid").expect("rigid");
        let seen = std::sync::Mutex::new(Vec::new());
        let record = |stage: &'static str, count: Option<(usize, usize)>| {
            seen.lock().expect("not poisoned").push((stage, count));
        };
        evaluate(&s, &truth, &pairs, &rigid, &opts, &record).expect("evaluate");
        let seen = seen.into_inner().expect("not poisoned");
        let stages: Vec<&str> = seen.iter().filter(|(_, c)| c.is_none()).map(|(s, _)| *s).collect();
        assert_eq!(stages, STAGES);
        let mut counts: Vec<usize> = seen
            .iter()
            .filter_map(|(_, c)| {
                c.map(|(done, total)| {
                    assert_eq!(total, 30);
                    done
                })
            })
            .collect();
        counts.sort_unstable();
        assert_eq!(counts, (1..=30).collect::<Vec<_>>());

        let refits = warpbench_solver::diagnostics::leave_one_out(
            &pairs.q_fixed,
            &pairs.p_moving,
            |q: &[Point3<Fixed>], p: &[Point3<Moving>]| method.fit(q, p, s.box_fixed),
            Parallelism::Sequential,
        );
        let refit_values: Vec<f64> = refits.iter().flatten().copied().collect();
        assert_eq!(refit_values.len(), 30);
        let expected = ErrorStats::of(&refit_values).expect("finite");
        let got = report.leave_one_out_mm.expect("leave-one-out");
        assert!(
            (got.mean - expected.mean).abs() < 1e-6 && (got.max - expected.max).abs() < 1e-6,
            "{got:?} vs {expected:?}"
        );
    }

    /// The moving volume is V(d(y)) at every voxel y: the d texture's texel centres are the voxel centres.
    #[test]
    fn the_moving_volume_is_the_volume_pulled_through_d() {
        let s = subject();
        let mut opts = EvalArgs::new(s.path.clone());
        opts.grid = 4;
        let truth = Truth::new(&s, SyntheticKind::Twist, &opts).expect("truth");
        let index_from_lps = s.volume.lps_from_index.inverse().expect("invertible");
        let (mut worst, mut checked) = (0.0f64, 0);
        let mut rng = SplitMix64::new(9, 0);
        for _ in 0..2000 {
            let i = rng.below(s.values.len());
            let y = sampling::voxel_centre(&s.volume, i);
            let x = truth.warp.apply_raw(y);
            let idx = index_from_lps.apply_point(Point3::from_array(x)).coords();
            if let Some(expected) = trilinear(&s.volume, &s.values, idx) {
                worst = worst.max((expected - f64::from(truth.moving[i])).abs());
                checked += 1;
            }
        }
        assert!(checked > 1500, "only {checked} voxels map inside");
        // f32 positions: ~1e-5 voxel times gradients of ≤ 255 per voxel (measured 2.4e-4; half a voxel off gives tens).
        assert!(worst < 0.01, "moving volume differs from V(d(y)) by {worst}");
        // The held-out points come with their exact pre-images.
        for (x, u) in truth.x_fixed.iter().zip(&truth.u_true) {
            assert!(truth.warp.apply(*u).distance(x) < 1e-8);
        }
        assert!(truth.before.ncc < truth.ideal.ncc, "{:?} vs {:?}", truth.before, truth.ideal);
    }
}
