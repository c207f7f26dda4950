//! `warpbench suggest`: suggested targets for automation (issue 18, item 2). For each moving point of a list, the
//! fixed point the current warp predicts, refined by the local similarity search of
//! [`warpbench_solver::suggest`] (normalised gradient fields, so a second modality works), with a confidence.
//!
//! The current warp is the forward map d = `fixed_from_moving` of the landmarks given (`--landmarks`, a session,
//! with `--method` and `--initial` as for every pair subcommand), the starting transform alone (`--initial` with too
//! few pairs), or the identity without either. The output is a BigWarp file of pairs (moving point, suggested fixed
//! point), named as the input's points; a low-confidence suggestion is written inactive, so a tool that reads the
//! file fits only the confident ones until a person has looked. A point whose suggestion fails (its patch leaves a
//! volume, a flat patch) is written with no fixed point and its reason is in `--json`.

use std::io::Write;
use std::path::PathBuf;

use anyhow::anyhow;
use rayon::prelude::*;
use serde::Serialize;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_io::landmarks::{LandmarkPair, PointFileOptions, read_point_file, write_landmark_pairs};
use warpbench_solver::image::Image;
use warpbench_solver::linear::AffineWarp;
use warpbench_solver::method::FittedWarp;
use warpbench_solver::spaces::{Fixed, Moving, as_moving};
use warpbench_solver::suggest::{SuggestParams, suggest};
use warpbench_solver::warp::{Parallelism, Warp};

use crate::args::{PairArgs, ReportArgs, VolumePairArgs, help};
use crate::exit::Failure;
use crate::fit;
use crate::inputs::{self, LandmarkWarp, OutputFile};
use crate::project::stack::StackForward;

/// The `--json` schema name.
pub const SCHEMA: &str = "warpbench-suggest/1";

/// What `warpbench suggest --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Suggest the fixed point of each moving point of a list: the current warp's prediction, refined by a local
search for the best match of the moving point's surroundings (normalised gradient fields, so an MRI point
finds its CT target), with a confidence.

The current warp is the landmarks' (--landmarks or --session, with --method and --initial as for warp),
the starting transform alone (--initial), or the identity. The output is a BigWarp file of pairs (moving
point, suggested fixed point); a suggestion of low confidence is written inactive, one that failed (a patch
outside a volume) without a fixed point. --json gives each point's suggestion, prediction, confidence and
search radius. Examples:

    warpbench suggest --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --points mr_points.csv --out suggested.csv --json
    warpbench suggest --fixed ct.nii.gz --moving mr.nii.gz --initial start.tfm --points mr_points.csv --out suggested.csv";

/// The arguments of `warpbench suggest`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[command(mut_args(help(&[
    ("fixed", "The fixed volume (NIfTI, NRRD or a DICOM series folder), where the targets are searched"),
    ("moving", "The moving volume, where the points are"),
])))]
#[command(mut_args(crate::args::or_session))]
pub struct SuggestArgs {
    #[command(flatten)]
    pub volumes: VolumePairArgs,
    #[command(flatten)]
    pub pairs: PairArgs,
    /// The moving points: a CSV point list (x,y,z and an optional name; LPS mm, or RAS with --ras), a Slicer
    /// .mrk.json or .fcsv, a BigWarp file of pairs (its moving points are read), or an elastix point file (point:
    /// LPS mm; index: voxel indices of the moving volume).
    #[arg(long, value_name = "FILE")]
    pub points: PathBuf,
    /// The pairs (moving point, suggested fixed point) as BigWarp CSV, or BigWarp JSON for a .json name.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// The radius searched around each prediction, mm.
    #[arg(long, default_value_t = SuggestParams::default().search_radius_mm)]
    pub search_radius_mm: f64,
    /// The CSV point list or BigWarp file is in RAS mm, not LPS.
    #[arg(long)]
    pub ras: bool,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// One point's suggestion in `--json`.
#[derive(Clone, Debug, Serialize)]
pub struct SuggestedPoint {
    pub name: String,
    pub moving_lps: [f64; 3],
    /// The suggestion; null when the search failed (`problem` says why).
    pub fixed_lps: Option<[f64; 3]>,
    /// The current warp's prediction d(p).
    pub predicted_lps: [f64; 3],
    /// In [0, 1]: how far the best match stands above any other match farther than a few millimetres.
    pub confidence: f64,
    /// Below the threshold: written inactive in the output.
    pub low_confidence: bool,
    /// |suggestion − prediction|, mm.
    pub shift_mm: f64,
    pub search_radius_mm: f64,
    pub problem: Option<String>,
}

/// The `--json` document, schema `warpbench-suggest/1` (docs/cli.md).
#[derive(Clone, Debug, Serialize)]
pub struct SuggestReport {
    pub schema: &'static str,
    pub out: String,
    /// What predicts the targets: `tps on start.tfm`, `identity`, ...
    pub prediction: String,
    pub points: Vec<SuggestedPoint>,
    pub low_confidence: usize,
    pub failed: usize,
}

/// Runs `warpbench suggest`.
pub fn run(args: SuggestArgs, out: &mut dyn Write) -> Result<SuggestReport, Failure> {
    let SuggestArgs { volumes, pairs, points, out: out_path, search_radius_mm, ras, report } = args;
    let ReportArgs { json, force, quiet } = report;
    let params = SuggestParams { search_radius_mm, ..SuggestParams::default() };
    params.validate().map_err(|e| Failure::BadInput(anyhow!("--search-radius-mm: {e}")))?;
    let given = LandmarkWarp::try_from(pairs).map_err(Failure::BadInput)?;
    let volumes = given.volumes(volumes, quiet).map_err(Failure::BadInput)?;
    let mut input_paths = vec![volumes.fixed.as_path(), volumes.moving.as_path(), points.as_path()];
    input_paths.extend(given.paths());
    OutputFile { path: out_path.clone(), force }.check(&input_paths).map_err(Failure::BadInput)?;
    if !given.warp.brush.is_empty() {
        return Err(Failure::BadInput(anyhow!(
            "the session's brush strokes: suggest predicts from the landmark warp alone; save the session without \
             them"
        )));
    }
    given.warp.check_start().map_err(Failure::BadInput)?;
    let file = read_point_file(&points, PointFileOptions { ras })?;
    let (fixed_volume, moving_volume) = inputs::load_pair(&volumes, quiet).map_err(Failure::BadInput)?;
    let inputs::VolumePair { fixed, moving, .. } = volumes;
    let start = given.warp.start(&fixed_volume, &moving_volume).map_err(Failure::BadInput)?;
    let moving_points: Vec<(String, Point3<Lps>)> =
        crate::points::input_points(&points, &file, crate::points::Side::Moving, Some(&moving_volume))?
            .into_iter()
            .filter_map(|(name, p)| Some((name, p?)))
            .collect();
    if moving_points.is_empty() {
        return Err(Failure::BadInput(anyhow!("{}: no moving points to suggest targets for", points.display())));
    }

    // The current warp's forward map.
    let (forward, prediction): (StackForward, String) = match &given.landmarks {
        Some(landmarks) => {
            let method = given.method().map_err(Failure::BadInput)?;
            let c = inputs::correspondences(
                &landmarks.source,
                landmarks.pairs().map_err(Failure::BadInput)?,
                &moving_volume,
                &fixed_volume,
                given.warp.min_pairs(&method),
            )
            .map_err(Failure::BadInput)?;
            let mut layers = crate::project::stack::Layers::new(start.clone(), None);
            layers.field = given.warp.field(&fixed_volume, &moving_volume).map_err(Failure::BadInput)?;
            crate::inputs::note_field_warnings(layers.field.as_deref(), quiet);
            let d = fit::forward_stack(&method, &c, inputs::volume_box::<Moving>(&moving_volume), layers)
                .map_err(Failure::BadInput)?;
            (d, crate::start::describe(&method, inputs::min_pairs(&method), c.moving.len(), start.as_ref()))
        }
        None => match &start {
            Some(s) => {
                (StackForward::folded(FittedWarp::Linear(*s.fixed_from_moving())), format!("{} alone", s.origin))
            }
            None => (
                StackForward::folded(FittedWarp::Linear(AffineWarp::identity())),
                "identity (no landmarks, no --initial)".to_owned(),
            ),
        },
    };
    let fixed_image = Image::<Fixed>::from_volume(&fixed_volume, Parallelism::Rayon)
        .map_err(|e| Failure::BadInput(anyhow!("{}: {e}", fixed.display())))?;
    let moving_image = Image::<Moving>::from_volume(&moving_volume, Parallelism::Rayon)
        .map_err(|e| Failure::BadInput(anyhow!("{}: {e}", moving.display())))?;
    drop((fixed_volume, moving_volume));

    // Each point's search is its own (one thread each): the points are shared out over rayon's pool, the results
    // kept in their order.
    let suggested: Vec<SuggestedPoint> = moving_points
        .par_iter()
        .enumerate()
        .map(|(i, (name, p))| {
            let p = as_moving(*p);
            let predicted = forward.apply(p).coords();
            let name = if name.is_empty() { format!("Pt-{i}") } else { name.clone() };
            match suggest(&moving_image, &fixed_image, &forward, p, &params) {
                Ok(s) => SuggestedPoint {
                    name,
                    moving_lps: p.coords(),
                    fixed_lps: Some(s.fixed.coords()),
                    predicted_lps: predicted,
                    confidence: s.confidence,
                    low_confidence: s.low_confidence,
                    shift_mm: s.shift_mm,
                    search_radius_mm: s.search_radius_mm,
                    problem: None,
                },
                Err(e) => SuggestedPoint {
                    name,
                    moving_lps: p.coords(),
                    fixed_lps: None,
                    predicted_lps: predicted,
                    confidence: 0.0,
                    low_confidence: true,
                    shift_mm: 0.0,
                    search_radius_mm: params.search_radius_mm,
                    problem: Some(format!("point {} of {}: {e}", i + 1, points.display())),
                },
            }
        })
        .collect();
    let pairs_out: Vec<LandmarkPair> = suggested
        .iter()
        .map(|s| LandmarkPair {
            active: !s.low_confidence,
            fixed: s.fixed_lps.map(Point3::from_array),
            ..LandmarkPair::new(&s.name, Point3::from_array(s.moving_lps), Point3::from_array(s.predicted_lps))
        })
        .collect();
    write_landmark_pairs(&out_path, &pairs_out)?;
    let summary = SuggestReport {
        schema: SCHEMA,
        out: out_path.display().to_string(),
        prediction,
        low_confidence: suggested.iter().filter(|s| s.low_confidence && s.problem.is_none()).count(),
        failed: suggested.iter().filter(|s| s.problem.is_some()).count(),
        points: suggested,
    };
    if json {
        crate::exit::print_json(out, &summary, "the JSON report")?;
    } else if !quiet {
        for s in summary.points.iter().filter_map(|s| s.problem.as_ref()) {
            eprintln!("warpbench: warning: {s}");
        }
        eprintln!(
            "wrote {} ({} pairs, {} of low confidence written inactive, {} without a suggestion; predicted by {})",
            summary.out,
            summary.points.len(),
            summary.low_confidence,
            summary.failed,
            summary.prediction
        );
    }
    Ok(summary)
}
