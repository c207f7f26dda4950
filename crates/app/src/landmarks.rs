//! `warpbench landmarks`: reads landmark pairs in any format warpbench knows and lists them (`--json`) or writes
//! them in another: BigWarp CSV ↔ BigWarp JSON ↔ a Slicer pair (`NAME_moving.mrk.json` + `NAME_fixed.mrk.json`, or
//! `.fcsv`) ↔ plain CSV ([`warpbench_io::landmarks`] has each format's conventions).
//!
//! Inside, every point is LPS mm; a file is converted at reading and writing only. The coordinate system of a file
//! is taken from the file where it says it (Slicer's `coordinateSystem` and `CoordinateSystem`, the plain CSV's
//! column names) and from `--ras` / `--out-ras` for BigWarp's files, which have no such field (LPS by default, as
//! everywhere in warpbench). Slicer files are written in LPS, which they declare.
//!
//! Every output is checked before anything is read (not an input, not an existing file without `--force`) and
//! written atomically; a Slicer pair is rendered in full before either file is written.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use serde::Serialize;
use warpbench_io::landmarks::{
    self, BigWarpCsvOptions, CsvCoordinates, LandmarkFileFormat, LandmarkPair, read_landmark_pairs_with,
    read_slicer_pair, write_bigwarp_csv_with, write_bigwarp_json_with, write_mni_tag, write_plain_csv,
    write_slicer_pair,
};

use crate::args::ReportArgs;
use crate::exit::Failure;
use crate::inputs;

/// The `--json` schema name.
pub const SCHEMA: &str = "warpbench-landmarks/1";

/// The formats of a single file of pairs that `--to` names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PairFileFormat {
    /// BigWarp's landmarks CSV (no header; name, active, moving x y z, fixed x y z).
    BigwarpCsv,
    /// BigWarp's landmarks JSON (`"type": "BigWarpLandmarks"`).
    BigwarpJson,
    /// A CSV with a header naming its columns and coordinate system.
    PlainCsv,
    /// An MNI tag point file (MINC's `register`, `tagtoxfm`): volume 1 the fixed points, volume 2 the moving ones,
    /// RAS mm.
    MniTag,
}

impl PairFileFormat {
    /// The format of an output named `path` when `--to` is not given: `.json` is BigWarp JSON, `.csv` BigWarp CSV,
    /// `.tag` an MNI tag file.
    #[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
    pub fn from_name(path: &Path) -> Result<Self, Failure> {
        let lower = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
        if lower.ends_with(".mrk.json") || lower.ends_with(".fcsv") {
            return Err(Failure::BadInput(anyhow!(
                "{}: a Slicer point list holds one side of the pairs; write the two lists with --out-moving and \
                 --out-fixed",
                path.display()
            )));
        }
        match Path::new(&lower).extension().and_then(|e| e.to_str()) {
            Some("json") => Ok(Self::BigwarpJson),
            Some("csv") => Ok(Self::BigwarpCsv),
            Some("tag") => Ok(Self::MniTag),
            _ => Err(Failure::BadInput(anyhow!(
                "{}: cannot tell the format from the name; end it in .csv (BigWarp CSV), .json (BigWarp JSON) or .tag \
                 (MNI tag file), or give --to bigwarp-csv, bigwarp-json, plain-csv or mni-tag",
                path.display()
            ))),
        }
    }
}

/// What to write.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LandmarkOutput {
    /// One file of pairs.
    Pairs { path: PathBuf, format: PairFileFormat },
    /// A Slicer pair: the moving and the fixed list (`.mrk.json` or `.fcsv` each).
    SlicerPair { moving: PathBuf, fixed: PathBuf },
}

impl LandmarkOutput {
    fn paths(&self) -> Vec<&Path> {
        match self {
            Self::Pairs { path, .. } => vec![path],
            Self::SlicerPair { moving, fixed } => vec![moving, fixed],
        }
    }
}

/// One pair in the `--json` listing, LPS mm.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ListedPair {
    /// 1-based, in file order.
    pub number: usize,
    pub name: String,
    pub active: bool,
    /// The point on the moving volume, or null when not placed.
    pub moving: Option<[f64; 3]>,
    /// The point on the fixed volume, or null when not placed.
    pub fixed: Option<[f64; 3]>,
}

/// The `--json` document, schema `warpbench-landmarks/1` (docs/cli.md).
#[derive(Clone, Debug, Serialize)]
pub struct LandmarksListing {
    pub schema: &'static str,
    /// The files read.
    pub inputs: Vec<String>,
    /// Their format: `bigwarp-csv`, `bigwarp-json`, `plain-csv`, or `slicer-pair`.
    pub format: String,
    /// Always `LPS`: the listing's coordinate system, whatever the file's.
    pub coordinate_system: &'static str,
    /// Always `mm`.
    pub units: &'static str,
    /// Pairs in the file; active ones; ones with both points; active ones with both points (what a warp uses).
    pub count: usize,
    pub active: usize,
    pub complete: usize,
    pub usable: usize,
    pub pairs: Vec<ListedPair>,
    /// The files written, if any.
    pub written: Vec<String>,
}

/// Runs `warpbench landmarks`: checks the outputs, reads, writes, and prints the listing (`--json`) or a table (when
/// nothing is written) to `out`, and a line per file written to stderr unless `--json` or `--quiet`.
pub fn run(args: LandmarksArgs, out: &mut dyn Write) -> Result<LandmarksListing, Failure> {
    let LandmarksArgs {
        input,
        moving_points,
        fixed_points,
        ras,
        out: out_path,
        to,
        out_moving,
        out_fixed,
        out_ras,
        report: ReportArgs { json, force, quiet },
    } = args;
    let input = inputs::LandmarkSource::from_args(input, moving_points, fixed_points)
        .map_err(Failure::BadInput)?
        .ok_or_else(|| Failure::BadInput(anyhow!("give a file of pairs, or --moving-points with --fixed-points")))?;
    let output = match (out_path, out_moving, out_fixed) {
        (Some(path), None, None) => {
            let format = match to {
                Some(f) => f,
                None => PairFileFormat::from_name(&path)?,
            };
            Some(LandmarkOutput::Pairs { path, format })
        }
        (None, Some(moving), Some(fixed)) => Some(LandmarkOutput::SlicerPair { moving, fixed }),
        (None, None, None) => None,
        _ => return Err(Failure::BadInput(anyhow!("give --out, or --out-moving with --out-fixed"))),
    };
    if output.is_none() && out_ras {
        return Err(Failure::BadInput(anyhow!("--out-ras applies to --out")));
    }
    let input_paths = input.paths();
    if let Some(output) = &output {
        let paths = output.paths();
        if paths.len() == 2 && paths[0] == paths[1] {
            return Err(Failure::BadInput(anyhow!(
                "{}: --out-moving and --out-fixed are the same file",
                paths[0].display()
            )));
        }
        for p in &paths {
            inputs::check_output(p, &input_paths, force).map_err(Failure::BadInput)?;
        }
        if let LandmarkOutput::SlicerPair { moving, fixed } = output {
            for p in [moving, fixed] {
                check_slicer_name(p)?;
            }
            if out_ras {
                return Err(Failure::BadInput(anyhow!(
                    "--out-ras: Slicer point lists are written in LPS and say so (coordinateSystem / CoordinateSystem), \
                     so Slicer reads them right; --out-ras is for BigWarp and plain CSV output"
                )));
            }
        }
    }
    let (pairs, format) = read_pairs(&input, ras)?;
    let mut written = Vec::new();
    if let Some(output) = &output {
        write_pairs(output, &pairs, out_ras)?;
        written = output.paths().iter().map(|p| p.display().to_string()).collect();
    }
    let listing = listing(&input, format, &pairs, written);
    if json {
        crate::exit::print_json(out, &listing, "the JSON listing")?;
    } else if output.is_none() {
        write_table(&listing, out).context("writing the listing").map_err(Failure::Internal)?;
    }
    if !quiet && !json {
        for w in &listing.written {
            eprintln!("wrote {w} ({} pairs)", listing.count);
        }
    }
    Ok(listing)
}

/// A one-side output must be named `.mrk.json` or `.fcsv` (Slicer), or `.txt` (an elastix point set): the name picks
/// the format.
#[allow(clippy::case_sensitive_file_extension_comparisons, reason = "the name is lowercased first")]
fn check_slicer_name(path: &Path) -> Result<(), Failure> {
    let lower = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    if lower.ends_with(".mrk.json") || lower.ends_with(".fcsv") || lower.ends_with(".txt") {
        Ok(())
    } else {
        Err(Failure::BadInput(anyhow!(
            "{}: a Slicer point list is named .mrk.json (Slicer 5 markups) or .fcsv (legacy), an elastix point set \
             .txt",
            path.display()
        )))
    }
}

/// Reads the pairs as `warpbench landmarks` does (BigWarp files in RAS with `ras`) and names their format.
pub fn read_pairs(input: &inputs::LandmarkSource, ras: bool) -> Result<(Vec<LandmarkPair>, String), Failure> {
    match input {
        inputs::LandmarkSource::Pairs(path) => {
            let format = landmarks::detect_landmark_file(path).map_err(|e| Failure::BadInput(e.into()))?;
            if !format.holds_pairs() {
                let what = if format == LandmarkFileFormat::ElastixPoints {
                    "an elastix point file"
                } else {
                    "a Slicer point list"
                };
                return Err(Failure::BadInput(anyhow!(
                    "{}: {what} holds one side of the pairs; give the moving and the fixed list with --moving-points \
                     and --fixed-points",
                    path.display()
                )));
            }
            if ras && format == LandmarkFileFormat::ItkThinPlateSpline {
                return Err(Failure::BadInput(anyhow!(
                    "{}: --ras is for BigWarp files; an ITK transform file is in LPS mm, as every ITK file",
                    path.display()
                )));
            }
            if ras && format == LandmarkFileFormat::MniTag {
                return Err(Failure::BadInput(anyhow!(
                    "{}: --ras is for BigWarp files; an MNI tag file is in RAS mm, as every MINC file",
                    path.display()
                )));
            }
            if ras && format == LandmarkFileFormat::PlainCsv {
                return Err(Failure::BadInput(anyhow!(
                    "{}: --ras is for BigWarp files; a plain CSV's header states its coordinate system (moving_l/p/s \
                     for LPS, moving_r/a/s for RAS)",
                    path.display()
                )));
            }
            let pairs =
                read_landmark_pairs_with(path, BigWarpCsvOptions { ras }).map_err(|e| Failure::BadInput(e.into()))?;
            Ok((pairs, format.name().to_string()))
        }
        inputs::LandmarkSource::Session(path) => {
            let pairs = crate::project::session::load(path).map_err(Failure::BadInput)?.document.pairs;
            Ok((pairs, "warpbench session".to_string()))
        }
        inputs::LandmarkSource::SlicerPair { moving, fixed } => {
            if ras {
                return Err(Failure::BadInput(anyhow!(
                    "--ras is for BigWarp files; a Slicer point list states its own coordinate system"
                )));
            }
            let pairs = read_slicer_pair(moving, fixed).map_err(|e| Failure::BadInput(e.into()))?;
            let elastix =
                |p: &Path| landmarks::detect_landmark_file(p).is_ok_and(|f| f == LandmarkFileFormat::ElastixPoints);
            let format = if elastix(moving) && elastix(fixed) { "elastix-pair" } else { "slicer-pair" };
            Ok((pairs, format.to_string()))
        }
    }
}

/// Writes `pairs` as `warpbench landmarks --out` does (BigWarp and plain CSV in RAS with `out_ras`), atomically.
pub fn write_pairs(output: &LandmarkOutput, pairs: &[LandmarkPair], out_ras: bool) -> Result<(), Failure> {
    let bigwarp = BigWarpCsvOptions { ras: out_ras };
    let result = match output {
        LandmarkOutput::Pairs { path, format: PairFileFormat::BigwarpCsv } => {
            write_bigwarp_csv_with(path, pairs, bigwarp)
        }
        LandmarkOutput::Pairs { path, format: PairFileFormat::BigwarpJson } => {
            write_bigwarp_json_with(path, pairs, bigwarp)
        }
        LandmarkOutput::Pairs { path, format: PairFileFormat::PlainCsv } => {
            write_plain_csv(path, pairs, if out_ras { CsvCoordinates::Ras } else { CsvCoordinates::Lps })
        }
        LandmarkOutput::Pairs { path, format: PairFileFormat::MniTag } => write_mni_tag(path, pairs),
        LandmarkOutput::SlicerPair { moving, fixed } => write_slicer_pair(moving, fixed, pairs),
    };
    result.map_err(|e| Failure::BadInput(e.into()))
}

fn listing(
    input: &inputs::LandmarkSource,
    format: String,
    pairs: &[LandmarkPair],
    written: Vec<String>,
) -> LandmarksListing {
    let listed: Vec<ListedPair> = pairs
        .iter()
        .enumerate()
        .map(|(i, p)| ListedPair {
            number: i + 1,
            name: p.name.clone(),
            active: p.active,
            moving: p.moving.map(|m| m.coords()),
            fixed: p.fixed.map(|f| f.coords()),
        })
        .collect();
    LandmarksListing {
        schema: SCHEMA,
        inputs: input.paths().iter().map(|p| p.display().to_string()).collect(),
        format,
        coordinate_system: "LPS",
        units: "mm",
        count: pairs.len(),
        active: pairs.iter().filter(|p| p.active).count(),
        complete: pairs.iter().filter(|p| p.is_complete()).count(),
        usable: pairs.iter().filter(|p| p.active && p.is_complete()).count(),
        pairs: listed,
        written,
    }
}

/// The listing as a table for people: one line per pair, LPS mm.
fn write_table(l: &LandmarksListing, out: &mut dyn Write) -> std::io::Result<()> {
    writeln!(
        out,
        "{} ({}): {} pairs, {} active, {} with both points, {} used by a warp; LPS mm",
        l.inputs.join(" + "),
        l.format,
        l.count,
        l.active,
        l.complete,
        l.usable
    )?;
    let point = |p: Option<[f64; 3]>| match p {
        Some([x, y, z]) => format!("({x:.3}, {y:.3}, {z:.3})"),
        None => "(not placed)".to_string(),
    };
    for p in &l.pairs {
        writeln!(
            out,
            "{:>5}  {:<20} {:<8} moving {}  fixed {}",
            p.number,
            p.name,
            if p.active { "active" } else { "inactive" },
            point(p.moving),
            point(p.fixed)
        )?;
    }
    Ok(())
}

/// What `warpbench landmarks --help` says above the options; its first paragraph is the summary that `-h` and
/// `warpbench --help` show.
const HELP: &str = "\
Convert and list landmark pairs: BigWarp CSV ↔ BigWarp JSON ↔ a Slicer pair (.mrk.json or .fcsv, moving and
fixed) ↔ plain CSV ↔ MNI tag files (.tag: MINC's register) ↔ elastix point sets (.txt, moving and fixed; transformix's outputpoints.txt in); --json
lists the pairs (name, active, moving, fixed, LPS mm) for scripts.

Without --out (or --out-moving/--out-fixed) and --json it prints the pairs as a table. The coordinate system
comes from the file where it says it (Slicer files, the plain CSV's header); BigWarp files are LPS unless
--ras (input) or --out-ras (output). Examples:

    warpbench landmarks pairs.csv --json
    warpbench landmarks pairs.csv --out pairs.json
    warpbench landmarks pairs.json --out-moving case_moving.mrk.json --out-fixed case_fixed.mrk.json
    warpbench landmarks --moving-points case_moving.fcsv --fixed-points case_fixed.fcsv --out pairs.csv --to plain-csv
    warpbench landmarks pairs.csv --out-moving moving_points.txt --out-fixed fixed_points.txt";

/// The command line of `warpbench landmarks`.
#[derive(Debug, clap::Args)]
#[command(about = crate::args::summary(HELP), long_about = HELP)]
#[allow(clippy::struct_excessive_bools, reason = "one bool per command-line flag")]
pub struct LandmarksArgs {
    /// A file of pairs: BigWarp CSV, BigWarp JSON (also a BigWarp settings file), plain CSV, an MNI tag file or
    /// transformix's outputpoints.txt, told apart by content. For a Slicer pair or elastix point sets give --moving-points and
    /// --fixed-points instead.
    #[arg(required_unless_present = "moving_points")]
    pub input: Option<PathBuf>,
    /// The moving volume's Slicer point list (.mrk.json or .fcsv), elastix `point` file or MNI tag file of one volume,
    /// with --fixed-points; paired by order.
    #[arg(long, requires = "fixed_points", conflicts_with = "input")]
    pub moving_points: Option<PathBuf>,
    /// The fixed volume's Slicer point list, with --moving-points.
    #[arg(long, requires = "moving_points")]
    pub fixed_points: Option<PathBuf>,
    /// The input BigWarp file's coordinates are RAS (default LPS; Slicer and plain CSV files say it themselves).
    #[arg(long)]
    pub ras: bool,
    /// Write the pairs to this file: BigWarp CSV for .csv, BigWarp JSON for .json, or as --to says.
    #[arg(long, conflicts_with_all = ["out_moving", "out_fixed"])]
    pub out: Option<PathBuf>,
    /// The format of --out when its name does not say it (a plain CSV is a .csv too).
    #[arg(long, value_enum, requires = "out")]
    pub to: Option<PairFileFormat>,
    /// Write the moving points as a Slicer point list (.mrk.json or .fcsv), with --out-fixed; or, both named .txt, the
    /// active pairs with both points as elastix point sets.
    #[arg(long, requires = "out_fixed")]
    pub out_moving: Option<PathBuf>,
    /// Write the fixed points as a Slicer point list, with --out-moving.
    #[arg(long, requires = "out_moving")]
    pub out_fixed: Option<PathBuf>,
    /// Write BigWarp or plain-CSV output in RAS (default LPS).
    #[arg(long)]
    pub out_ras: bool,
    #[command(flatten)]
    pub report: ReportArgs,
}
