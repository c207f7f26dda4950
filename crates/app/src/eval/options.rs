//! The arguments of `warpbench eval` and its `--suite` grid.

use std::path::PathBuf;

use warpbench_solver::synthetic::SyntheticKind;

use crate::settings::MethodKind;

/// The fewest held-out points (the default too).
pub const MIN_HELD_OUT: usize = 1000;

/// Which TRE statistic `--max-tre-mm` gates on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum TreStatistic {
    Mean,
    Median,
    #[default]
    P95,
    Max,
}

impl TreStatistic {
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Mean => "mean",
            Self::Median => "median",
            Self::P95 => "p95",
            Self::Max => "max",
        }
    }
}

impl std::str::FromStr for TreStatistic {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        [Self::Mean, Self::Median, Self::P95, Self::Max]
            .into_iter()
            .find(|t| t.name() == s)
            .ok_or_else(|| format!("unknown TRE statistic {s:?}; use mean, median, p95 or max"))
    }
}

/// The grid of `--suite`: every combination of these.
#[derive(Clone, Debug, PartialEq)]
pub struct SuiteOptions {
    /// Warp kinds by name (`--suite-kinds`).
    pub kinds: Vec<String>,
    /// Landmark counts (`--suite-n`).
    pub landmark_counts: Vec<usize>,
    /// Methods (`--suite-methods`), each with the evaluation's `stiffness` and `levels`.
    pub methods: Vec<MethodKind>,
    /// The markdown file whose generated section is replaced (created, or appended to, when absent); `None` prints
    /// the section to the output.
    pub markdown: Option<PathBuf>,
    /// How the machine is described in the markdown (default: "N threads").
    pub machine: Option<String>,
}

impl SuiteOptions {
    /// The standard grid: the six kinds × N ∈ {10, 20, 50, 100, 200} × the five methods.
    #[must_use]
    pub fn standard() -> Self {
        Self {
            kinds: SyntheticKind::ALL.iter().map(|k| k.name().to_owned()).collect(),
            landmark_counts: vec![10, 20, 50, 100, 200],
            methods: MethodKind::ALL.to_vec(),
            markdown: None,
            machine: None,
        }
    }
}

/// What `warpbench eval --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Measure how well a landmark warp recovers a known synthetic deformation of a real volume: TRE at held-out
foreground points, leave-one-out, inverse consistency, folding, and NCC/RMSE against the ground truth.

The volume is deformed by a seeded synthetic warp, landmark pairs are sampled in its foreground, the warp is
fitted, and the fit is compared with the truth (docs/accuracy.md has the definitions). --max-tre-mm gates
the result (exit 3); --suite runs the grid kinds × N × methods. Examples:

    warpbench eval --volume tests/data/nifti/avg152T1_LR_nifti.nii --kind sine --amplitude-mm 5 --landmarks 50
    warpbench eval --volume mr.nii.gz --kind bump --landmarks 20 --on-features --max-tre-mm 2 --json eval.json
    warpbench eval --volume mr.nii.gz --suite --suite-md docs/accuracy.md --json suite.json";

/// The arguments of `warpbench eval`, which the evaluation takes as they are.
#[derive(Clone, Debug, PartialEq, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[allow(clippy::struct_excessive_bools, reason = "one bool per command-line flag")]
pub struct EvalArgs {
    /// The real volume to deform (NIfTI, NRRD or a DICOM series folder); it is also the ground truth.
    #[arg(long)]
    pub volume: PathBuf,
    /// The synthetic warp: sine, twist, bend, bump, tps-random or bspline-random.
    #[arg(long, default_value = "sine")]
    pub kind: String,
    /// The warp's largest displacement, mm.
    #[arg(long, default_value_t = 10.0)]
    pub amplitude_mm: f64,
    /// Landmark pairs N.
    #[arg(long, default_value_t = 50)]
    pub landmarks: usize,
    /// The fitted warp.
    #[arg(long, value_enum, default_value_t)]
    pub method: MethodKind,
    /// TPS stiffness λ ≥ 0 (0 interpolates the landmarks).
    #[arg(long, default_value_t = 0.0)]
    pub stiffness: f64,
    /// Hierarchical B-spline levels.
    #[arg(long)]
    pub levels: Option<usize>,
    /// Seed of the warp, the landmarks and the held-out points.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Place landmarks on strong-gradient voxels (at least a spacing apart) instead of at random.
    #[arg(long)]
    pub on_features: bool,
    /// Held-out foreground points for the TRE (at least 1000).
    #[arg(long, default_value_t = MIN_HELD_OUT)]
    pub held_out: usize,
    /// Control-texture texels per axis for the recovered volume (2..=256).
    #[arg(long, default_value_t = 64)]
    pub grid: usize,
    /// Write the report as JSON (schema warpbench-eval/1, or warpbench-eval-suite/1 with --suite; docs/cli.md).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Overwrite --json if it exists.
    #[arg(long)]
    pub force: bool,
    /// Exit with code 3 when the TRE statistic (--gate-statistic) exceeds this, mm.
    #[arg(long)]
    pub max_tre_mm: Option<f64>,
    /// The TRE statistic --max-tre-mm gates: mean, median, p95 or max.
    #[arg(long, default_value = "p95")]
    pub gate_statistic: TreStatistic,
    #[command(flatten)]
    pub suite: SuiteArgs,
    /// No progress bars.
    #[arg(long, short)]
    pub quiet: bool,
}

/// `--suite` and the grid it runs ([`SuiteOptions`]).
#[derive(Clone, Debug, Default, PartialEq, clap::Args)]
pub struct SuiteArgs {
    /// Run the grid kinds × N × methods instead of one evaluation.
    #[arg(long)]
    pub suite: bool,
    /// Suite kinds (comma-separated; default all six).
    #[arg(long, value_delimiter = ',', requires = "suite")]
    pub suite_kinds: Option<Vec<String>>,
    /// Suite landmark counts (comma-separated; default 10,20,50,100,200).
    #[arg(long, value_delimiter = ',', requires = "suite")]
    pub suite_n: Option<Vec<usize>>,
    /// Suite methods (comma-separated; default all five).
    #[arg(long, value_enum, value_delimiter = ',', requires = "suite")]
    pub suite_methods: Option<Vec<MethodKind>>,
    /// Markdown file whose generated suite section is replaced (default: print the section).
    #[arg(long, requires = "suite")]
    pub suite_md: Option<PathBuf>,
    /// How the suite's markdown describes the machine (default: the thread count).
    #[arg(long, requires = "suite")]
    pub machine: Option<String>,
}

impl SuiteArgs {
    /// The grid `--suite` runs, the standard one ([`SuiteOptions::standard`]) where a list is not given; `None`
    /// without `--suite`.
    #[must_use]
    pub fn options(&self) -> Option<SuiteOptions> {
        self.suite.then(|| {
            let standard = SuiteOptions::standard();
            SuiteOptions {
                kinds: self.suite_kinds.clone().unwrap_or(standard.kinds),
                landmark_counts: self.suite_n.clone().unwrap_or(standard.landmark_counts),
                methods: self.suite_methods.clone().unwrap_or(standard.methods),
                markdown: self.suite_md.clone(),
                machine: self.machine.clone(),
            }
        })
    }
}

impl EvalArgs {
    /// The arguments of a single evaluation with the defaults of the command line.
    #[must_use]
    pub fn new(volume: PathBuf) -> Self {
        Self {
            volume,
            kind: "sine".into(),
            amplitude_mm: 10.0,
            landmarks: 50,
            method: MethodKind::Tps,
            stiffness: 0.0,
            levels: None,
            seed: 1,
            on_features: false,
            held_out: MIN_HELD_OUT,
            grid: 64,
            json: None,
            force: false,
            max_tre_mm: None,
            gate_statistic: TreStatistic::P95,
            suite: SuiteArgs::default(),
            quiet: false,
        }
    }
}
