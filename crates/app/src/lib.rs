//! # warpbench-app
//!
//! The `warpbench` binary's library. `main.rs` only parses arguments and dispatches; each subcommand lives here as a
//! module that owns its clap `Args` (its flags, their help, its `--help` text) and a `run` that takes them and writes
//! to the given output, so tests can call it.
//!
//! - [`info`]: `warpbench info <file-or-dir> [--json]`, what a volume holds and where it sits in LPS.
//! - [`render`]: `warpbench render`, one frame (3-D view or slice) of the fixed and the deformed moving volume, with
//!   landmark glyphs, to PNG.
//! - [`warp`](mod@warp): `warpbench warp`, the moving volume resampled into the fixed grid through the pull-back, to
//!   NIfTI (and DICOM), on the GPU or the CPU.
//! - [`eval`]: `warpbench eval`, a known synthetic warp of a real volume recovered from sampled landmarks: TRE,
//!   leave-one-out, inverse consistency, folding, NCC/RMSE, an accuracy gate (exit 3), and the `--suite` grid.
//! - [`field`]: `warpbench field`, the pull-back as a NIfTI displacement field (ITK/ANTs/Slicer convention) and,
//!   for linear warps, an ITK `.tfm`.
//! - [`landmarks`](mod@landmarks): `warpbench landmarks`, landmark pairs converted between BigWarp CSV/JSON, a Slicer
//!   pair and plain CSV, or listed (`--json`).
//! - [`points`]: `warpbench points`, a point list (CSV, Slicer, BigWarp) mapped through the warp: from the moving
//!   volume by d = fixed_from_moving, from the fixed one by u = moving_from_fixed, written in the input's format.
//! - [`transform`]: `warpbench transform` (and `field --tfm`), the pull-back as the ITK transform file that holds it
//!   exactly (thin-plate spline, B-spline, affine).
//! - [`register`](mod@register): `warpbench register`, a deformable registration by intensities under the landmarks,
//!   written as a displacement field (and the warped volume).
//! - [`inputs`]: loading the pair, reading landmarks and checking them against the volumes (shared by the pair
//!   subcommands).
//! - [`gpu_samples`]: the GPU as the reader of a registration's samples, and `--backend`'s rule for it.
//! - [`fit`]: the one way to fit: pairs and a method give the pull-back and the forward warp, and what the GPU takes
//!   of them (control texture, TPS, B-spline lattice), for the subcommands, the window and the drag bench.
//! - [`project`]: the model under the window and the command line: the document and its session file.
//! - [`scene`]: volumes, presets, windows and control textures as the renderer takes them.
//! - [`settings`]: the named choices (blend, warp method, probe, shading, preset) shared by the window, the sessions
//!   and the command line.
//! - [`gui`]: the workbench window (eframe): the deformed pair in a 3-D view and three slice views, the warp method
//!   and view settings, the landmark table; the demo pair when no files are given.
//! - [`cli`]: the headless subcommands as one enum ([`cli::Command`]) and one dispatch ([`cli::run`]), shared by the
//!   binary and the Python package.
//! - [`args`]: the command-line argument groups several subcommands share (the volume pair, the landmarks, the warp
//!   method, the report flags, the render settings), parsed once into the model's types by [`inputs`].
//! - [`exit`]: the exit-code convention shared by every subcommand; the shared modules (`inputs`, `scene`, `fit`)
//!   return `anyhow` errors, which the subcommands classify.

pub mod align;
pub mod args;
pub mod brushed;
pub mod cli;
pub mod eval;
pub mod exit;
pub mod field;
pub mod fit;
pub mod gpu_samples;
#[cfg(feature = "window")]
pub mod gui;
pub mod info;
pub mod inputs;
pub mod jacobian;
pub mod landmarks;
pub mod points;
pub mod procedural;
pub mod progress;
pub mod project;
pub mod register;
pub mod render;
pub mod scene;
pub mod settings;
pub mod start;
pub mod suggest;
pub mod transform;
pub mod warp;
