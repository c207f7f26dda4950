//! The options of `warpbench eval` and its `--suite` grid.

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

/// Options of `warpbench eval`.
#[derive(Clone, Debug, PartialEq)]
pub struct EvalOptions {
    pub volume: PathBuf,
    /// Synthetic warp kind by name (single evaluation).
    pub kind: String,
    pub amplitude_mm: f64,
    /// N (single evaluation).
    pub landmarks: usize,
    /// The method, with `stiffness` (TPS) and `levels` (hierarchical B-spline).
    pub method: MethodKind,
    pub stiffness: f64,
    pub levels: Option<usize>,
    pub seed: u64,
    /// Landmarks on strong-gradient voxels instead of random ones.
    pub on_features: bool,
    /// Held-out points (≥ [`MIN_HELD_OUT`]).
    pub held_out: usize,
    /// Control-texture texels per axis for the image metrics.
    pub grid: usize,
    /// Where to write the JSON report.
    pub json: Option<PathBuf>,
    /// Overwrite `json` if it exists.
    pub force: bool,
    pub max_tre_mm: Option<f64>,
    pub gate_statistic: TreStatistic,
    pub suite: Option<SuiteOptions>,
    pub quiet: bool,
}

impl EvalOptions {
    /// The options of a single evaluation with the defaults of the command line.
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
            suite: None,
            quiet: false,
        }
    }
}
