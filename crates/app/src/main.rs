//! `warpbench`: parses arguments and hands them to the library (see `warpbench_app`).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand, ValueEnum};
use warpbench_app::exit::Failure;
use warpbench_app::info::{self, InfoOptions};
use warpbench_app::inputs::{LandmarkSource, OutputFile};
use warpbench_app::render::{self, CameraSpec, RenderOptions, SliceSpec};
use warpbench_app::warp::{self, Backend, PullBackMode, WarpOptions};
use warpbench_gpu::ShadingMode;
use warpbench_gpu::export::Interpolation;

/// Landmark-based registration of two 3D medical volumes (MRI, CT), live on the GPU.
#[derive(Debug, Parser)]
#[command(name = "warpbench", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Print what a volume holds: dims, spacing, lps_from_index, geometry source, dtype, value range,
    /// modality and series.
    ///
    /// Reads NIfTI-1/2 (.nii, .nii.gz), NRRD (.nrrd, .nhdr), a DICOM series folder or one DICOM file.
    /// A folder with several series lists them. Example:
    ///
    ///     warpbench info tests/data/nifti/ch2.nii.gz --json
    #[command(verbatim_doc_comment)]
    Info {
        /// A volume file or a DICOM series folder.
        path: PathBuf,
        /// Machine-readable output (schema warpbench-info/1, see docs/cli.md).
        #[arg(long)]
        json: bool,
        /// For a 4-D NIfTI: the frame (t index) to read.
        #[arg(long)]
        frame: Option<usize>,
        /// For a folder with several DICOM series: the SeriesInstanceUID to read.
        #[arg(long)]
        series: Option<String>,
        /// No progress bar.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Resample the moving volume into the fixed volume's grid through the landmark warp, and write a NIfTI
    /// (and, with --out-dicom, a DICOM series) with the fixed grid's geometry.
    ///
    /// The pull-back u = moving_from_fixed is sampled into a --grid³ control texture over the output grid (what the
    /// app shows), or evaluated exactly per voxel with --exact (TPS). Examples:
    ///
    ///     warpbench warp --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --out mr_in_ct.nii.gz
    ///     warpbench warp --fixed ct.nii.gz --moving mr.nii.gz --moving-points mr.mrk.json --fixed-points ct.mrk.json --method rigid --interp cubic --out mr_rigid.nii.gz
    #[command(verbatim_doc_comment)]
    Warp(Box<WarpArgs>),
    /// Render one frame of the fixed volume, or of the fixed and the deformed moving volume blended, to PNG,
    /// headless, with the app's renderer.
    ///
    /// With --moving and landmarks the moving volume is pulled back through the fitted warp and the landmark pairs
    /// are drawn (fixed points blue, moving points orange where the warp shows them). --slice draws a slice of
    /// the fixed grid instead of the 3-D view. Examples:
    ///
    ///     warpbench render --fixed ct.nii.gz --out ct.png
    ///     warpbench render --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --blend checkerboard --out pair.png
    ///     warpbench render --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --slice axial:40 --out ax.png
    #[command(verbatim_doc_comment)]
    Render(Box<RenderArgs>),
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum InterpArg {
    Nearest,
    Linear,
    Cubic,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum BackendArg {
    Auto,
    Cpu,
    Gpu,
}

#[derive(Debug, clap::Args)]
#[allow(clippy::struct_excessive_bools, reason = "one bool per command-line flag")]
struct WarpArgs {
    /// The fixed volume: its grid is the output grid. NIfTI, NRRD or a DICOM series folder.
    #[arg(long)]
    fixed: PathBuf,
    /// The moving volume, resampled.
    #[arg(long)]
    moving: PathBuf,
    /// Landmark pairs (BigWarp CSV, moving then fixed coordinates, LPS mm).
    #[arg(long)]
    landmarks: Option<PathBuf>,
    /// Slicer point list (.mrk.json or .fcsv) of the moving points; with --fixed-points.
    #[arg(long)]
    moving_points: Option<PathBuf>,
    /// Slicer point list of the fixed points, matched to --moving-points by order.
    #[arg(long)]
    fixed_points: Option<PathBuf>,
    /// The warp: tps, hbspline, affine, similarity or rigid.
    #[arg(long, default_value = "tps")]
    method: String,
    /// TPS stiffness λ ≥ 0 (0 interpolates the landmarks).
    #[arg(long, default_value_t = 0.0)]
    stiffness: f64,
    /// Hierarchical B-spline levels.
    #[arg(long)]
    levels: Option<usize>,
    /// Control-texture texels per axis over the output grid (2..=256).
    #[arg(long, default_value_t = 64, conflicts_with = "exact")]
    grid: usize,
    /// Evaluate the pull-back exactly at every voxel (TPS, and the linear warps) instead of a control texture.
    #[arg(long)]
    exact: bool,
    /// Interpolation: nearest, linear (trilinear) or cubic (Catmull-Rom).
    #[arg(long, value_enum, default_value = "linear")]
    interp: InterpArg,
    /// Where to resample: auto (GPU when available), cpu or gpu.
    #[arg(long, value_enum, default_value = "auto")]
    backend: BackendArg,
    /// Write f32 samples instead of the moving volume's type (rounded half to even and clamped).
    #[arg(long)]
    float: bool,
    /// Another volume whose grid the output takes instead of the fixed volume's.
    #[arg(long)]
    reference: Option<PathBuf>,
    /// The value of voxels that map outside the moving volume (default −1024 for a CT, else 0).
    #[arg(long, allow_hyphen_values = true)]
    outside: Option<f64>,
    /// The NIfTI to write (.nii or .nii.gz).
    #[arg(long)]
    out: PathBuf,
    /// Also write the result as a DICOM series (new UIDs) into this new folder.
    #[arg(long)]
    out_dicom: Option<PathBuf>,
    /// Print a JSON report (schema warpbench-warp/1) to stdout.
    #[arg(long)]
    json: bool,
    /// Overwrite --out if it exists.
    #[arg(long)]
    force: bool,
    /// No progress bars or messages.
    #[arg(long, short)]
    quiet: bool,
}

fn run_warp(a: WarpArgs) -> Result<(), Failure> {
    let landmarks = LandmarkSource::from_args(a.landmarks, a.moving_points, a.fixed_points)?.ok_or_else(|| {
        Failure::BadInput(anyhow::anyhow!("give --landmarks, or --moving-points with --fixed-points"))
    })?;
    let opts = WarpOptions {
        fixed: a.fixed,
        moving: a.moving,
        landmarks,
        method: a.method,
        stiffness: a.stiffness,
        levels: a.levels,
        pullback: if a.exact { PullBackMode::Exact } else { PullBackMode::Grid(a.grid) },
        interpolation: match a.interp {
            InterpArg::Nearest => Interpolation::Nearest,
            InterpArg::Linear => Interpolation::Trilinear,
            InterpArg::Cubic => Interpolation::CatmullRom,
        },
        backend: match a.backend {
            BackendArg::Auto => Backend::Auto,
            BackendArg::Cpu => Backend::Cpu,
            BackendArg::Gpu => Backend::Gpu,
        },
        float: a.float,
        reference: a.reference,
        outside_value: a.outside,
        out: OutputFile { path: a.out, force: a.force },
        out_dicom: a.out_dicom,
        quiet: a.quiet,
    };
    let report = warp::run(&opts)?;
    if a.json {
        let text = serde_json::to_string_pretty(&report).map_err(|e| Failure::Internal(e.into()))?;
        println!("{text}");
    } else if !opts.quiet {
        eprintln!(
            "wrote {} ({}×{}×{} {}, {} pairs, {}, {})",
            report.out,
            report.dims[0],
            report.dims[1],
            report.dims[2],
            report.dtype,
            report.pairs,
            report.pullback,
            report.backend
        );
    }
    Ok(())
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum ShadingArg {
    None,
    Dvr,
    Iso,
}

#[derive(Debug, clap::Args)]
#[allow(clippy::struct_excessive_bools, reason = "one bool per command-line flag")]
struct RenderArgs {
    /// The fixed volume (the render space): NIfTI, NRRD or a DICOM series folder.
    #[arg(long)]
    fixed: PathBuf,
    /// The moving volume, shown deformed by the landmark warp.
    #[arg(long)]
    moving: Option<PathBuf>,
    /// Landmark pairs (BigWarp CSV, moving then fixed coordinates, LPS mm).
    #[arg(long)]
    landmarks: Option<PathBuf>,
    /// Slicer point list (.mrk.json or .fcsv) of the moving points; with --fixed-points.
    #[arg(long)]
    moving_points: Option<PathBuf>,
    /// Slicer point list of the fixed points, matched to --moving-points by order.
    #[arg(long)]
    fixed_points: Option<PathBuf>,
    /// The warp: tps, hbspline, affine, similarity or rigid.
    #[arg(long, default_value = "tps")]
    method: String,
    /// TPS stiffness λ ≥ 0 (0 interpolates the landmarks).
    #[arg(long, default_value_t = 0.0)]
    stiffness: f64,
    /// Hierarchical B-spline levels.
    #[arg(long)]
    levels: Option<usize>,
    /// Control-texture texels per axis over the fixed box (2..=256).
    #[arg(long, default_value_t = 64)]
    grid: usize,
    /// mix, additive, difference, checkerboard, red-cyan, fixed-only or moving-only.
    #[arg(long, default_value = "mix")]
    blend: String,
    /// Moving weight of the mix blend (0..1).
    #[arg(long, default_value_t = 0.5)]
    mix_weight: f32,
    /// Checkerboard cell size (mm).
    #[arg(long, default_value_t = 12.0)]
    checker_mm: f32,
    /// Fixed volume preset: ct-bone, ct-soft-tissue, mr-t1 or grey-ramp (default: from the data).
    #[arg(long)]
    preset: Option<String>,
    /// Moving volume preset (default: from the data).
    #[arg(long)]
    moving_preset: Option<String>,
    /// Lighting: none, dvr (shaded volume rendering) or iso (first surface).
    #[arg(long, value_enum, default_value = "dvr")]
    shading: ShadingArg,
    /// Camera as az,el or az,el,dist: degrees about the superior axis and above the horizon, distance in mm.
    #[arg(long)]
    camera: Option<CameraSpec>,
    /// Perspective projection (default orthographic).
    #[arg(long)]
    perspective: bool,
    /// Image size WxH (3-D view; a slice has its grid's size).
    #[arg(long, default_value = "512x512", value_parser = render::parse_size)]
    size: (u32, u32),
    /// Samples per voxel along each ray.
    #[arg(long, default_value_t = 1.0)]
    samples_per_voxel: f32,
    /// A slice of the fixed grid instead of the 3-D view: axial, coronal or sagittal, optionally with :POS in mm
    /// (e.g. axial:40; default the centre).
    #[arg(long)]
    slice: Option<SliceSpec>,
    /// Leave out the landmark glyphs.
    #[arg(long)]
    no_glyphs: bool,
    /// The PNG to write.
    #[arg(long)]
    out: PathBuf,
    /// Overwrite --out if it exists.
    #[arg(long)]
    force: bool,
    /// No progress bars or messages.
    #[arg(long, short)]
    quiet: bool,
}

fn run_render(a: RenderArgs) -> Result<(), Failure> {
    let landmarks = LandmarkSource::from_args(a.landmarks, a.moving_points, a.fixed_points)?;
    let opts = RenderOptions {
        fixed: a.fixed,
        moving: a.moving,
        landmarks,
        method: a.method,
        stiffness: a.stiffness,
        levels: a.levels,
        grid: a.grid,
        blend: a.blend,
        mix_weight: a.mix_weight,
        checker_mm: a.checker_mm,
        preset: a.preset,
        moving_preset: a.moving_preset,
        shading: match a.shading {
            ShadingArg::None => ShadingMode::None,
            ShadingArg::Dvr => ShadingMode::Dvr,
            ShadingArg::Iso => ShadingMode::Iso,
        },
        camera: a.camera,
        perspective: a.perspective,
        size: a.size,
        samples_per_voxel: a.samples_per_voxel,
        slice: a.slice,
        glyphs: !a.no_glyphs,
        out: OutputFile { path: a.out, force: a.force },
        quiet: a.quiet,
    };
    let done = render::run(&opts)?;
    if !opts.quiet {
        eprintln!(
            "wrote {} ({}×{}, {} landmark pairs, {})",
            opts.out.path.display(),
            done.size.0,
            done.size.1,
            done.pairs,
            done.adapter
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info { path, json, frame, series, quiet } => {
            info::run(&InfoOptions { path, json, frame, series, quiet }, &mut std::io::stdout().lock())
        }
        Command::Warp(args) => run_warp(*args),
        Command::Render(args) => run_render(*args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            eprintln!("warpbench: {:#}", f.error());
            f.code()
        }
    }
}
