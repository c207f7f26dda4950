//! `warpbench`: parses arguments and hands them to the library (see `warpbench_app`).

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use warpbench_app::info::{self, InfoOptions};

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
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Info { path, json, frame, series, quiet } => {
            info::run(&InfoOptions { path, json, frame, series, quiet }, &mut std::io::stdout().lock())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(f) => {
            eprintln!("warpbench: {:#}", f.error());
            f.code()
        }
    }
}
