//! The model under the window and the command line: what a registration is, apart from how it is shown.
//!
//! - [`document`]: what the user edits (the pair's paths and looks, the landmark pairs, the warp and view settings,
//!   the brush and the starting transform); the window's undo history snapshots it.
//! - [`diagnostics`]: what follows a fit off the UI thread: residuals, leave-one-out errors, folding.
//! - [`demo`]: the demo pair, which a document without volume paths stands for.
//! - [`fitter`]: the one owner of fitting for the window ([`fitter::Fitter::fit`]): the stack fitted, its control
//!   texture made on the CPU or the GPU, a TPS drag's fast path, the brush, the diagnostics job.
//! - [`session`]: the `.warpbench.json` file that keeps a document and the view, and where the autosave goes.
//! - [`recent`]: the sessions opened or saved most recently (the window's File > Open recent session).
//!
//! - [`field_file`]: the displacement field under the landmarks as a document keeps it (its file, and a Learn2Reg
//!   field's grids).
//! - [`stack`]: the warp stack, the ordered layers that make the pull-back (a starting transform, a displacement
//!   field, the landmark fit and the brush), fitted and evaluated in one place.
//!
//! Nothing here imports the window (`gui/`); the subcommands read sessions through [`session::load`].

pub mod demo;
pub mod diagnostics;
pub mod document;
pub mod field_file;
pub mod fitter;
pub mod recent;
pub mod session;
pub mod stack;
