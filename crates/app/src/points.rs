//! `warpbench points`: the landmark warp applied to a list of points, written back in the list's own format.
//!
//! The points are in one of the two volumes, and `--from` says which:
//!
//! ```text
//! --from moving:  y = d(p),  d = fixed_from_moving, fitted on the pairs pᵢ → qᵢ over the moving volume's box
//! --from fixed:   y = u(x),  u = moving_from_fixed, fitted on the pairs qᵢ → pᵢ over the fixed volume's box
//! ```
//!
//! (pᵢ the moving, qᵢ the fixed landmarks; [`fit::forward_stack`], [`fit::pullback_stack`].) So a point on the moving
//! volume comes out where the warped volume (`warpbench warp`, v'(x) = v(u(x))) shows it, and a point on the fixed
//! volume comes out at the moving point the warped volume shows there. d and u are fitted separately: u(d(p)) = p
//! only to within the warp's inverse consistency. (ANTs's `antsApplyTransformsToPoints` takes the inverse of the
//! transform that resamples the image, because a resampling transform maps fixed points to moving ones; here one
//! names the volume the points are in, and that is all.) A point outside its volume's box is mapped all the same,
//! by extrapolation (a TPS is affine far from its landmarks), with a warning.
//!
//! Point files ([`warpbench_io::landmarks::read_point_file`]): a plain CSV point list `x,y,z[,name]` (LPS mm, or
//! RAS with `--ras`), a Slicer `.mrk.json` or `.fcsv` (in the coordinate system its header names), a BigWarp
//! CSV or JSON file of pairs (LPS, or RAS with `--ras`), or an elastix point file (`point`: LPS mm; `index`: voxel
//! indices of the `--from` volume in, written as voxel indices of the other volume). The output has the input's
//! format and coordinate convention. For pairs, the `--from` side is the input and the other side is replaced by its
//! image: with `--from moving`, each pair's fixed point becomes d(moving point) (missing where the moving point is
//! missing), names and active flags kept.
//!
//! `--json` prints [`PointsReport`] (schema [`SCHEMA`]) to stdout. The output is written atomically, never over an
//! input, and over an existing file only with `--force`.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::anyhow;
use serde::Serialize;
use warpbench_io::Volume;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_io::landmarks::{
    ElastixPointKind, PointFile, PointFileFormat, PointFileOptions, read_point_file, write_point_file,
};
use warpbench_solver::spaces::{Fixed, Moving};
use warpbench_solver::warp::Warp;

use crate::args::{PairArgs, ReportArgs, VolumePairArgs, help};
use crate::exit::Failure;
use crate::fit;
use crate::inputs::{self, OutputFile, PairInputs, PairVolumes};

/// The `--json` schema name.
pub const SCHEMA: &str = "warpbench-points/1";

/// The most out-of-box points named one by one on stderr; the rest are counted.
const NAMED_OUTSIDE_WARNINGS: usize = 10;

/// Which volume the points are in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// Points on the moving volume, mapped into the fixed volume's space by d = fixed_from_moving.
    Moving,
    /// Points on the fixed volume, mapped into the moving volume's space by u = moving_from_fixed.
    Fixed,
}

impl Side {
    fn name(self) -> &'static str {
        match self {
            Self::Moving => "moving",
            Self::Fixed => "fixed",
        }
    }

    fn other(self) -> Self {
        match self {
            Self::Moving => Self::Fixed,
            Self::Fixed => Self::Moving,
        }
    }

    /// The map that takes points of this side to the other, in the transform naming of the code.
    fn map(self) -> &'static str {
        match self {
            Self::Moving => "fixed_from_moving",
            Self::Fixed => "moving_from_fixed",
        }
    }
}

/// What `warpbench points --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Map a list of points through the landmark warp, from the volume they are in to the other one, and write them
in the input's format (CSV point list: x,y,z and an optional name, Slicer .mrk.json/.fcsv, BigWarp CSV/JSON,
elastix point file).

Say which volume the points are in, and that is all: --from moving maps a point p of the moving volume by
d = fixed_from_moving to where the warped volume (`warpbench warp`) shows it; --from fixed maps a point x of
the fixed volume by u = moving_from_fixed to the moving point the warped volume shows at x. (ANTs's
antsApplyTransformsToPoints needs the inverse of the transform that resamples the image; here there is none
to choose.) d and u are fitted separately, so u(d(p)) = p only to within the warp's inverse consistency.
Points outside their volume's box are mapped by extrapolation, with a warning. CSV point lists and BigWarp
files are LPS mm unless --ras; Slicer files say their own coordinate system, which the output keeps. An elastix
`point` file is LPS mm; an elastix `index` file holds voxel indices of the --from volume and is written as voxel
indices of the other one. In a BigWarp file of pairs the --from side is read and the other side replaced by its
image. Example: a lesion
marked at (12.5, -30, 8) mm LPS on the moving MRI, line `12.5,-30,8,lesion` of lesion_mr.csv:

    warpbench points --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --from moving --in lesion_mr.csv --out lesion_ct.csv
    warpbench points --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --from fixed --in targets_ct.mrk.json --out targets_mr.mrk.json --json

lesion_ct.csv then holds the lesion where it lies in the CT (and in mr_in_ct.nii.gz from `warpbench warp`).";

/// The arguments of `warpbench points`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[command(mut_args(help(&[
    ("fixed", "The fixed volume (NIfTI, NRRD or a DICOM series folder): its box checks the landmarks and, with --from fixed, the points"),
    ("moving", "The moving volume: its box checks the landmarks and, with --from moving, the points"),
])))]
#[command(mut_args(crate::args::or_session))]
pub struct PointsArgs {
    #[command(flatten)]
    pub volumes: VolumePairArgs,
    #[command(flatten)]
    pub pairs: PairArgs,
    /// The volume the points are in: moving (mapped by d = fixed_from_moving into the fixed space) or fixed
    /// (mapped by u = moving_from_fixed into the moving space).
    #[arg(long, value_enum)]
    pub from: Side,
    /// The points: a CSV point list (x,y,z and an optional name), a Slicer .mrk.json or .fcsv, a BigWarp CSV or JSON of pairs
    /// (the --from side is read, the other side replaced), or an elastix point file (point: LPS mm; index: voxel indices
    /// of the --from volume).
    #[arg(long = "in", value_name = "FILE")]
    pub input: PathBuf,
    /// The mapped points, in the input's format and coordinate convention.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// The CSV point list or BigWarp file is in RAS mm (x and y negated), not LPS; Slicer files say it themselves.
    #[arg(long)]
    pub ras: bool,
    #[command(flatten)]
    pub report: ReportArgs,
}

/// The `--json` document, schema `warpbench-points/1` (docs/cli.md).
#[derive(Clone, Debug, Serialize)]
pub struct PointsReport {
    pub schema: &'static str,
    /// The point file read and the one written.
    #[serde(rename = "in")]
    pub input: String,
    pub out: String,
    /// `point-list`, `bigwarp-csv`, `bigwarp-json`, `slicer-mrk-json`, `slicer-fcsv` or `elastix-points`, both
    /// files'.
    pub format: &'static str,
    /// `LPS` or `RAS`: the coordinates in both files (the JSON's are LPS always); `index` for an elastix index file
    /// (voxel indices of the --from volume in, of the other volume out).
    pub file_coordinates: &'static str,
    /// The volume the input points are in, and the one the output points are in.
    pub from: Side,
    pub to: Side,
    /// `fixed_from_moving` (the forward map d) or `moving_from_fixed` (the pull-back u).
    pub map: &'static str,
    /// The method as fitted, e.g. `tps`, `tps(λ=0.5)`, `affine`.
    pub method: String,
    /// Landmark pairs used (active, with both points).
    pub pairs: usize,
    /// One entry per point of the file, in file order.
    pub points: Vec<MappedPoint>,
    /// How many points lie outside the --from volume's box.
    pub outside: usize,
    /// What was printed as warnings on stderr (the fit's, and the points outside the box).
    pub warnings: Vec<String>,
}

/// One point of the file and its image.
#[derive(Clone, Debug, Serialize)]
pub struct MappedPoint {
    /// 1-based, in file order.
    pub index: usize,
    pub name: String,
    /// LPS mm; null for a point without a position (a Slicer point not placed, a pair's missing half).
    pub input_lps: Option<[f64; 3]>,
    pub output_lps: Option<[f64; 3]>,
    /// Whether the input lies outside the --from volume's box (mapped by extrapolation).
    pub outside: bool,
}

/// Runs `warpbench points`: checks the output, reads the points, loads the pair, fits, maps, writes; prints the
/// JSON report to `out` with `--json`, else a line on stderr unless `--quiet`.
pub fn run(args: PointsArgs, out: &mut dyn Write) -> Result<PointsReport, Failure> {
    let PointsArgs { volumes, pairs, from, input, out: out_path, ras, report: ReportArgs { json, force, quiet } } =
        args;
    let inputs = PairInputs::new(volumes, pairs, None, quiet).map_err(Failure::BadInput)?;
    let mut input_paths = inputs.paths();
    input_paths.push(&input);
    OutputFile { path: out_path.clone(), force }.check(&input_paths).map_err(Failure::BadInput)?;
    let method = inputs.method().map_err(Failure::BadInput)?;
    inputs.warp.check_start().map_err(Failure::BadInput)?;

    let options = PointFileOptions { ras };
    let mut file = read_point_file(&input, options)?;
    check_out_name(&out_path, &input, file.format())?;
    if !has_points(&file, from) {
        return Err(Failure::BadInput(anyhow!("{}: no {} points to map", input.display(), from.name())));
    }

    let PairVolumes { fixed, moving, .. } = inputs.load_volumes(quiet).map_err(Failure::BadInput)?;
    let start = inputs.start(&fixed, &moving).map_err(Failure::BadInput)?;
    let (from_volume, to_volume) = match from {
        Side::Moving => (&moving, &fixed),
        Side::Fixed => (&fixed, &moving),
    };
    let sources = input_points(&input, &file, from, Some(from_volume))?;
    let c = inputs::check_pairs(
        &inputs.landmarks.describe(),
        inputs.pairs().map_err(Failure::BadInput)?,
        &moving,
        &fixed,
        inputs.warp.min_pairs(&method),
    )
    .map_err(Failure::BadInput)?;
    let mut warnings = fit::fit_warnings(&method, &c);

    let xs: Vec<[f64; 3]> = sources.iter().filter_map(|(_, p)| p.map(|p| p.coords())).collect();
    let mut ys = vec![[0.0; 3]; xs.len()];
    // The stack: a starting transform under the landmark fit, a session's brush on top (b ∘ d from the moving side,
    // u ∘ b⁻¹ from the fixed side).
    let brushed = inputs.brushed().map_err(Failure::BadInput)?;
    let mut layers = crate::project::stack::Layers::new(start.clone(), brushed);
    layers.field = inputs.warp.field(&fixed, &moving).map_err(Failure::BadInput)?;
    crate::inputs::note_field_warnings(layers.field.as_deref(), quiet);
    let (source_volume, source_path) = match from {
        Side::Moving => {
            let fixed_from_moving = fit::forward_stack(&method, &c, inputs::volume_box::<Moving>(&moving), layers)
                .map_err(Failure::BadInput)?;
            fixed_from_moving.apply_batch_raw(&xs, &mut ys);
            (&moving, &inputs.volumes.moving)
        }
        Side::Fixed => {
            let moving_from_fixed = fit::pullback_stack(&method, &c, inputs::volume_box::<Fixed>(&fixed), layers)
                .map_err(Failure::BadInput)?;
            moving_from_fixed.apply_batch_raw(&xs, &mut ys);
            (&fixed, &inputs.volumes.fixed)
        }
    };
    if let Some(k) = ys.iter().position(|y| !y.iter().all(|v| v.is_finite())) {
        return Err(Failure::Internal(anyhow!(
            "the {method} warp is not finite at {:?} mm LPS (point {} of {})",
            xs[k],
            k + 1,
            input.display()
        )));
    }

    let mut images = ys.iter().map(|&y| Point3::<Lps>::from_array(y));
    let mut points = Vec::with_capacity(sources.len());
    let mut outside_named = Vec::new();
    for (i, (name, p)) in sources.iter().enumerate() {
        let output = p.and_then(|_| images.next());
        let outside = p.is_some_and(|p| !inside(source_volume, p));
        if outside {
            outside_named.push(format!(
                "{}: point {}{} at {:?} mm LPS is outside the {} volume ({}): mapped by extrapolation",
                input.display(),
                i + 1,
                if name.is_empty() { String::new() } else { format!(" ({name})") },
                p.map(|p| p.coords()).unwrap_or_default(),
                from.name(),
                source_path.display()
            ));
        }
        points.push(MappedPoint {
            index: i + 1,
            name: name.clone(),
            input_lps: p.map(|p| p.coords()),
            output_lps: output.map(|p| p.coords()),
            outside,
        });
    }
    let outside = outside_named.len();
    if outside > NAMED_OUTSIDE_WARNINGS {
        let rest = outside - NAMED_OUTSIDE_WARNINGS;
        outside_named.truncate(NAMED_OUTSIDE_WARNINGS);
        outside_named.push(format!(
            "{}: {rest} more points outside the {} volume, mapped by extrapolation",
            input.display(),
            from.name()
        ));
    }
    warnings.extend(outside_named);
    if !quiet {
        for w in &warnings {
            eprintln!("warpbench: warning: {w}");
        }
    }

    set_outputs(&out_path, &mut file, from, &points, to_volume)?;
    write_point_file(&out_path, &file, options)?;

    let report = PointsReport {
        schema: SCHEMA,
        input: input.display().to_string(),
        out: out_path.display().to_string(),
        format: file.format().name(),
        file_coordinates: file_coordinates(&file, ras),
        from,
        to: from.other(),
        map: from.map(),
        method: crate::start::describe(&method, inputs::min_pairs(&method), c.moving.len(), start.as_ref()),
        pairs: c.moving.len(),
        points,
        outside,
        warnings,
    };
    if json {
        crate::exit::print_json(out, &report, "the JSON report")?;
    } else if !quiet {
        eprintln!(
            "wrote {} ({} points, {} → {} by {}, {}, {} landmark pairs)",
            report.out,
            xs.len(),
            from.name(),
            from.other().name(),
            report.map,
            report.method,
            report.pairs
        );
    }
    Ok(report)
}

/// Refuses an output name whose ending says another format than the input's, which the output has.
fn check_out_name(out: &Path, input: &Path, format: PointFileFormat) -> Result<(), Failure> {
    match PointFileFormat::named_by(out) {
        Some(named) if !named.contains(&format) => Err(Failure::BadInput(anyhow!(
            "{}: the name says {}, but the output has the format of the input {} ({}); give it that file's ending",
            out.display(),
            named.iter().map(|f| f.name()).collect::<Vec<_>>().join(" or "),
            input.display(),
            format.name()
        ))),
        _ => Ok(()),
    }
}

/// Whether the file has a `from`-side point to map (read before any volume is loaded).
fn has_points(file: &PointFile, from: Side) -> bool {
    match file {
        PointFile::List(list) => !list.points.is_empty(),
        PointFile::BigWarp { pairs, .. } => {
            pairs.iter().any(|p| if from == Side::Moving { p.moving.is_some() } else { p.fixed.is_some() })
        }
        PointFile::Slicer(list) => list.points.iter().any(|p| p.position.is_some()),
        PointFile::Elastix(e) => !e.rows.is_empty(),
    }
}

/// A point of a file: its name and its position (LPS mm), if it has one.
pub(crate) type NamedPoint = (String, Option<Point3<Lps>>);

/// Each point of the file (`path`): its name and its `from`-side position (LPS mm), in file order. An elastix `index`
/// file's voxel indices are placed by `volume` (the volume the points are in), and refused without one.
pub(crate) fn input_points(
    path: &Path,
    file: &PointFile,
    from: Side,
    volume: Option<&Volume>,
) -> Result<Vec<NamedPoint>, Failure> {
    Ok(match file {
        PointFile::List(list) => list.points.iter().map(|p| (p.name.clone(), Some(p.position))).collect(),
        PointFile::BigWarp { pairs, .. } => {
            pairs.iter().map(|p| (p.name.clone(), if from == Side::Moving { p.moving } else { p.fixed })).collect()
        }
        PointFile::Slicer(list) => list.points.iter().map(|p| (p.label.clone(), p.position)).collect(),
        PointFile::Elastix(e) => {
            e.to_lps(path, volume.map(|v| &v.lps_from_index))?.into_iter().map(|p| (String::new(), Some(p))).collect()
        }
    })
}

/// Puts the images into the file (`path`, the output): a list's and a Slicer file's positions are replaced; a pair's
/// other side is; an elastix file's rows are, as voxel indices of `to_volume` for an `index` file.
fn set_outputs(
    path: &Path,
    file: &mut PointFile,
    from: Side,
    points: &[MappedPoint],
    to_volume: &Volume,
) -> Result<(), Failure> {
    let image = |m: &MappedPoint| m.output_lps.map(Point3::from_array);
    match file {
        PointFile::List(list) => {
            for (p, m) in list.points.iter_mut().zip(points) {
                if let Some(y) = image(m) {
                    p.position = y;
                }
            }
        }
        PointFile::BigWarp { pairs, .. } => {
            for (p, m) in pairs.iter_mut().zip(points) {
                match from {
                    Side::Moving => p.fixed = image(m),
                    Side::Fixed => p.moving = image(m),
                }
            }
        }
        PointFile::Slicer(list) => {
            for (p, m) in list.points.iter_mut().zip(points) {
                p.position = image(m);
            }
        }
        PointFile::Elastix(e) => {
            let mapped: Vec<Point3<Lps>> = points.iter().filter_map(image).collect();
            let index_from_lps = to_volume.lps_from_index.inverse();
            e.set_lps(path, &mapped, index_from_lps.as_ref())?;
        }
    }
    Ok(())
}

/// What the report's `file_coordinates` says: `RAS` or `LPS`, `index` for an elastix index file.
fn file_coordinates(file: &PointFile, ras: bool) -> &'static str {
    let is_ras = match file {
        PointFile::Slicer(list) => list.ras,
        PointFile::Elastix(e) if e.kind == ElastixPointKind::Index => return "index",
        PointFile::Elastix(_) => false,
        PointFile::List(_) | PointFile::BigWarp { .. } => ras,
    };
    if is_ras { "RAS" } else { "LPS" }
}

/// Whether `p` lies in the voxel-edge box of `v`, in its index space (exact on oblique grids).
fn inside(v: &Volume, p: Point3<Lps>) -> bool {
    let Some(index_from_lps) = v.lps_from_index.inverse() else { return false };
    let idx = index_from_lps.apply_point(p).coords();
    (0..3).all(|a| idx[a] >= -0.5 && idx[a] <= v.dims[a] as f64 - 0.5)
}
