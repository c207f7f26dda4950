//! # warpbench-app
//!
//! The `warpbench` binary's library. `main.rs` only parses arguments; each subcommand lives here
//! as a function that takes parsed options and writes to the given output, so tests can call it.
//!
//! - [`info`]: `warpbench info <file-or-dir> [--json]`, what a volume holds and where it sits in LPS.
//! - [`exit`]: the exit-code convention shared by every subcommand.

pub mod exit;
pub mod info;
pub mod progress;
