//! `warpbench`: parses arguments and hands them to the library (see `warpbench_app`).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use warpbench_app::exit::Failure;
use warpbench_app::gui::{self, GuiOptions};
use warpbench_app::inputs::LandmarkSource;
use warpbench_app::{align, eval, field, info, landmarks, points, render, suggest, transform, warp};

/// Landmark-based registration of two 3D medical volumes (MRI, CT), live on the GPU.
///
/// Without a subcommand it opens the workbench window: with --fixed and --moving on those volumes, otherwise on the
/// demo pair (a head CT and a head MRI).
#[derive(Debug, Parser)]
#[command(name = "warpbench", version, about, args_conflicts_with_subcommands = true)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    gui: GuiArgs,
}

/// The window's options (no subcommand).
#[derive(Debug, clap::Args)]
struct GuiArgs {
    /// The fixed volume to open (with --moving).
    #[arg(long, requires = "moving")]
    fixed: Option<PathBuf>,
    /// The moving volume to open (with --fixed).
    #[arg(long, requires = "fixed")]
    moving: Option<PathBuf>,
    /// Landmark pairs (BigWarp CSV or BigWarp JSON, also a BigWarp settings file) to open with them.
    #[arg(long, requires = "fixed")]
    landmarks: Option<PathBuf>,
    /// A saved session (.warpbench.json) to open: its volumes, landmarks and settings.
    #[arg(long, conflicts_with_all = ["fixed", "moving", "landmarks"])]
    session: Option<PathBuf>,
    /// Save a screenshot of the window here, then close (with --exit-after-frames).
    #[arg(long)]
    screenshot: Option<PathBuf>,
    /// Close the window after this many frames with the volumes shown, once they are fully rendered (smoke tests).
    #[arg(long)]
    exit_after_frames: Option<u32>,
    /// Write one tab-separated line per window frame here (seconds since the window opened, the phase, what the 3-D
    /// view shows, whether a pointer button was released, the frame's UI work in ms): for measuring the window.
    #[arg(long, value_name = "FILE")]
    frame_log: Option<PathBuf>,
}

fn run_gui(a: GuiArgs) -> Result<(), Failure> {
    let opts = GuiOptions {
        fixed: a.fixed,
        moving: a.moving,
        landmarks: a.landmarks.map(LandmarkSource::Pairs),
        exit_after_frames: a.exit_after_frames.or(a.screenshot.is_some().then_some(5)),
        screenshot: a.screenshot,
        session: a.session,
        autosave: None,
        frame_log: a.frame_log,
    };
    gui::run(opts).map_err(Failure::Internal)
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
    Info(info::InfoArgs),
    /// Resample the moving volume into the fixed volume's grid through the landmark warp, or through a displacement
    /// field (--field), and write a NIfTI (and, with --out-dicom, a DICOM series) with the fixed grid's geometry.
    ///
    /// The pull-back u = moving_from_fixed is sampled into a --grid³ control texture over the output grid (what the
    /// app shows), or evaluated exactly per voxel with --exact (TPS, a field). --field takes a pull-back field in
    /// any flavour warpbench field writes (ITK NIfTI DISPVECT, ANTs NIfTI VECTOR, Slicer NRRD): u(x) = x + D(x),
    /// D interpolated trilinearly and zero outside the field's grid, as ITK's DisplacementFieldTransform. Examples:
    ///
    ///     warpbench warp --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --out mr_in_ct.nii.gz
    ///     warpbench warp --fixed ct.nii.gz --moving mr.nii.gz --moving-points mr.mrk.json --fixed-points ct.mrk.json --method rigid --interp cubic --out mr_rigid.nii.gz
    ///     warpbench warp --fixed ct.nii.gz --moving mr.nii.gz --field mr_to_ct1Warp.nii.gz --exact --out mr_in_ct.nii.gz
    #[command(verbatim_doc_comment)]
    Warp(Box<warp::WarpArgs>),
    /// Measure how well a landmark warp recovers a known synthetic deformation of a real volume: TRE at held-out
    /// foreground points, leave-one-out, inverse consistency, folding, and NCC/RMSE against the ground truth.
    ///
    /// The volume is deformed by a seeded synthetic warp, landmark pairs are sampled in its foreground, the warp is
    /// fitted, and the fit is compared with the truth (docs/accuracy.md has the definitions). --max-tre-mm gates
    /// the result (exit 3); --suite runs the grid kinds × N × methods. Examples:
    ///
    ///     warpbench eval --volume tests/data/nifti/avg152T1_LR_nifti.nii --kind sine --amplitude-mm 5 --landmarks 50
    ///     warpbench eval --volume mr.nii.gz --kind bump --landmarks 20 --on-features --max-tre-mm 2 --json eval.json
    ///     warpbench eval --volume mr.nii.gz --suite --suite-md docs/accuracy.md --json suite.json
    #[command(verbatim_doc_comment)]
    Eval(Box<eval::EvalArgs>),
    /// Render one frame of the fixed volume, or of the fixed and the deformed moving volume blended, to PNG,
    /// headless, with the app's renderer.
    ///
    /// With --moving and landmarks the moving volume is pulled back through the fitted warp and the landmark pairs
    /// are drawn (fixed points blue, moving points orange where the warp shows them); with --field instead, through
    /// that pull-back displacement field, without glyphs. --slice draws a slice of the fixed grid instead of the
    /// 3-D view. Examples:
    ///
    ///     warpbench render --fixed ct.nii.gz --out ct.png
    ///     warpbench render --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --blend checkerboard --out pair.png
    ///     warpbench render --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --slice axial:40 --out ax.png
    ///     warpbench render --fixed ct.nii.gz --moving mr.nii.gz --field mr_to_ct1Warp.nii.gz --slice axial --out ax.png
    #[command(verbatim_doc_comment)]
    Render(Box<render::RenderArgs>),
    /// Write the warp as a displacement field in the flavour ITK, ANTs or 3D Slicer reads, and optionally the exact
    /// transform as an ITK transform file.
    ///
    /// --direction pullback (default): at each voxel centre x of the fixed grid (or --reference's) the field holds
    /// u(x) − x, u = moving_from_fixed fitted on the landmarks and evaluated exactly: ITK's DisplacementFieldTransform
    /// maps fixed point x to moving point x + D(x), what resampling the moving volume needs. --direction forward: on
    /// the moving grid (or --reference's), d(y) − y, d = fixed_from_moving: a moving point y goes to y + D(y), what
    /// moving points or meshes needs.
    ///
    /// --format itk (default): NIfTI intent DISPVECT (1006), vectors in RAS, as ITK ≥ 5.3 and Slicer read it;
    /// --format ants: NIfTI intent VECTOR (1007), vectors in LPS, what antsApplyTransforms reads; --format nrrd: a NRRD
    /// vector image in LPS that Slicer reads, stating the direction (displacement field type resampling or modeling).
    /// Examples:
    ///
    ///     warpbench field --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --out field.nii.gz
    ///     warpbench field --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --format ants --out mr_to_ct1Warp.nii.gz
    ///     warpbench field --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --format nrrd --out field.nrrd --tfm mr_to_ct.tfm
    #[command(verbatim_doc_comment)]
    Field(Box<field::FieldArgs>),
    /// Map a list of points through the landmark warp, from the volume they are in to the other one, and write them
    /// in the input's format (CSV point list: x,y,z and an optional name, Slicer .mrk.json/.fcsv, BigWarp CSV/JSON).
    ///
    /// Say which volume the points are in, and that is all: --from moving maps a point p of the moving volume by
    /// d = fixed_from_moving to where the warped volume (`warpbench warp`) shows it; --from fixed maps a point x of
    /// the fixed volume by u = moving_from_fixed to the moving point the warped volume shows at x. (ANTs's
    /// antsApplyTransformsToPoints needs the inverse of the transform that resamples the image; here there is none
    /// to choose.) d and u are fitted separately, so u(d(p)) = p only to within the warp's inverse consistency.
    /// Points outside their volume's box are mapped by extrapolation, with a warning. CSV point lists and BigWarp
    /// files are LPS mm unless --ras; Slicer files say their own coordinate system, which the output keeps. In a
    /// BigWarp file of pairs the --from side is read and the other side replaced by its image. Example: a lesion
    /// marked at (12.5, -30, 8) mm LPS on the moving MRI, line `12.5,-30,8,lesion` of lesion_mr.csv:
    ///
    ///     warpbench points --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --from moving --in lesion_mr.csv --out lesion_ct.csv
    ///     warpbench points --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --from fixed --in targets_ct.mrk.json --out targets_mr.mrk.json --json
    ///
    /// lesion_ct.csv then holds the lesion where it lies in the CT (and in mr_in_ct.nii.gz from `warpbench warp`).
    #[command(verbatim_doc_comment)]
    Points(Box<points::PointsArgs>),
    /// Write the landmark warp as an ITK transform file (.tfm), the exact transform instead of a sampled field: TPS
    /// as ThinPlateSplineKernelTransform_double_3_3 (any stiffness: the file is the same function), the hierarchical
    /// B-spline as one BSplineTransform_double_3_3 (its finest lattice, exact inside the fixed volume's box; ITK is the
    /// identity outside it), affine, similarity and rigid as AffineTransform_double_3_3.
    ///
    /// The file maps fixed points to moving points (u = moving_from_fixed, LPS mm): what ITK's ResampleImageFilter,
    /// antsApplyTransforms and Slicer need to resample the moving volume onto the fixed one. SimpleITK reads the affine
    /// and B-spline files; Slicer reads all three (Data > Add data, then apply the transform to the moving volume).
    ///
    ///     warpbench transform --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --method tps --out mr_to_ct.tfm
    #[command(verbatim_doc_comment)]
    Transform(Box<transform::TransformArgs>),
    /// Convert and list landmark pairs: BigWarp CSV ↔ BigWarp JSON ↔ a Slicer pair (.mrk.json or .fcsv, moving and
    /// fixed) ↔ plain CSV; --json lists the pairs (name, active, moving, fixed, LPS mm) for scripts.
    ///
    /// Without --out (or --out-moving/--out-fixed) and --json it prints the pairs as a table. The coordinate system
    /// comes from the file where it says it (Slicer files, the plain CSV's header); BigWarp files are LPS unless
    /// --ras (input) or --out-ras (output). Examples:
    ///
    ///     warpbench landmarks pairs.csv --json
    ///     warpbench landmarks pairs.csv --out pairs.json
    ///     warpbench landmarks pairs.json --out-moving case_moving.mrk.json --out-fixed case_fixed.mrk.json
    ///     warpbench landmarks --moving-points case_moving.fcsv --fixed-points case_fixed.fcsv --out pairs.csv --to plain-csv
    #[command(verbatim_doc_comment)]
    Landmarks(Box<landmarks::LandmarksArgs>),
    /// Align the moving volume to the fixed one automatically, by intensities, and write the result as an ITK
    /// transform file.
    ///
    /// Rigid (6 parameters), or with --affine rigid then affine (12), maximising the Mattes mutual information of the
    /// two volumes (so an MRI aligns to a CT), over 3 resolution levels (--shrink 4,2,1), from their centres of mass.
    /// The file (AffineTransform_double_3_3) maps fixed points to moving points (LPS mm), as ITK's registration
    /// writes its result: SimpleITK, ANTs and Slicer resample the moving volume with it. Examples:
    ///
    ///     warpbench align --fixed ct.nii.gz --moving mr.nii.gz --out-tfm mr_to_ct.tfm
    ///     warpbench align --fixed ct.nii.gz --moving mr.nii.gz --out-tfm mr_to_ct.tfm --affine --json
    #[command(verbatim_doc_comment)]
    Align(Box<align::AlignArgs>),
    /// Suggest the fixed point of each moving point of a list: the current warp's prediction, refined by a local
    /// search for the best match of the moving point's surroundings (normalised gradient fields, so an MRI point
    /// finds its CT target), with a confidence.
    ///
    /// The current warp is the landmarks' (--landmarks or --session, with --method and --initial as for warp),
    /// the starting transform alone (--initial), or the identity. The output is a BigWarp file of pairs (moving
    /// point, suggested fixed point); a suggestion of low confidence is written inactive, one that failed (a patch
    /// outside a volume) without a fixed point. --json gives each point's suggestion, prediction, confidence and
    /// search radius. Examples:
    ///
    ///     warpbench suggest --fixed ct.nii.gz --moving mr.nii.gz --landmarks pairs.csv --points mr_points.csv --out suggested.csv --json
    ///     warpbench suggest --fixed ct.nii.gz --moving mr.nii.gz --initial start.tfm --points mr_points.csv --out suggested.csv
    #[command(verbatim_doc_comment)]
    Suggest(Box<suggest::SuggestArgs>),
}

/// The failure's message for stderr: the error and its causes joined with ": ", each once. (An error that shows
/// its source in its own text, as an I/O error does with the OS error, would otherwise print it twice.)
fn message(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let part = cause.to_string();
        if text.contains(&part) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&part);
    }
    text
}

/// Keeps a headless command's GPU probe quiet. Mesa's Vulkan device-select layer (an implicit layer the Vulkan
/// loader runs in every process) asks the Wayland compositor which GPU drives the display whenever an instance
/// enables `VK_KHR_wayland_surface`, and wgpu enables every surface extension there is. Without `XDG_RUNTIME_DIR`
/// there is no compositor to ask, and libwayland prints "error: XDG_RUNTIME_DIR is invalid or not set in the
/// environment." for each probe. A headless command has no display to match, so in exactly that case it turns the
/// layer off (`NODEVICE_SELECT=1`), unless the user chose a device through the layer or a compositor is reachable
/// another way.
#[allow(unsafe_code, reason = "std::env::set_var, before any thread exists (see the SAFETY comment)")]
fn quiet_headless_gpu_probe() {
    let var = |name: &str| std::env::var_os(name);
    let absolute = |name: &str| var(name).is_some_and(|v| std::path::Path::new(&v).is_absolute());
    let compositor_reachable =
        absolute("XDG_RUNTIME_DIR") || absolute("WAYLAND_DISPLAY") || var("WAYLAND_SOCKET").is_some();
    let user_chose = ["NODEVICE_SELECT", "MESA_VK_DEVICE_SELECT", "DRI_PRIME"].into_iter().any(|v| var(v).is_some());
    if !compositor_reachable && !user_chose {
        // SAFETY: called from `main` after parsing the arguments and before anything else: no other thread exists
        // yet, so nothing reads or writes the environment at the same time.
        unsafe { std::env::set_var("NODEVICE_SELECT", "1") };
    }
}

/// SIGINT, SIGTERM and SIGHUP in a headless command: remove the temporaries of the write in progress (so nothing
/// half-written stays beside an output), then die of the signal as if it had not been handled (a shell reports 130
/// for Ctrl-C, 143 for SIGTERM). A SIGKILL cannot be handled: the next write into that folder removes what it left
/// (`warpbench_io::atomic`).
#[cfg(unix)]
fn remove_temporaries_on_signals() {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    // Without the handler a signal kills as it always did; the next run still removes the leftovers.
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP]) else { return };
    let handler = move || {
        if let Some(signal) = signals.forever().next() {
            warpbench_io::atomic::remove_temporaries_before_exit();
            let _ = signal_hook::low_level::emulate_default_handler(signal);
            std::process::exit(128 + signal);
        }
    };
    let _ = std::thread::Builder::new().name("signals".into()).spawn(handler);
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let Some(command) = cli.command else {
        return match run_gui(cli.gui) {
            Ok(()) => ExitCode::SUCCESS,
            Err(f) => {
                eprintln!("warpbench: {}", message(f.error()));
                f.code()
            }
        };
    };
    quiet_headless_gpu_probe();
    #[cfg(unix)]
    remove_temporaries_on_signals();
    let stdout = &mut std::io::stdout().lock();
    let result = match command {
        Command::Info(args) => info::run(&args, stdout),
        Command::Warp(args) => warp::run(*args, stdout).map(|_| ()),
        Command::Eval(args) => eval::run(&args, stdout),
        Command::Render(args) => render::run(*args).map(|_| ()),
        Command::Field(args) => field::run(*args, stdout).map(|_| ()),
        Command::Points(args) => points::run(*args, stdout).map(|_| ()),
        Command::Transform(args) => transform::run(*args, stdout).map(|_| ()),
        Command::Landmarks(args) => landmarks::run(*args, stdout).map(|_| ()),
        Command::Align(args) => align::run(*args, stdout).map(|_| ()),
        Command::Suggest(args) => suggest::run(*args, stdout).map(|_| ()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            eprintln!("warpbench: {}", message(f.error()));
            f.code()
        }
    }
}
