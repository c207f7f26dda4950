//! The headless subcommands as one enum and one dispatch: what the `warpbench` binary parses, and what the Python
//! package runs in process on an argument list (so both give the same reports and write the same files).

use std::io::Write;

use clap::Subcommand;

use crate::exit::Failure;
use crate::{align, eval, field, info, jacobian, landmarks, points, register, render, suggest, transform, warp};

/// The headless subcommands: each module's `Args` says what it takes and holds its help.
#[derive(Debug, Subcommand)]
pub enum Command {
    Info(info::InfoArgs),
    Warp(Box<warp::WarpArgs>),
    Eval(Box<eval::EvalArgs>),
    Render(Box<render::RenderArgs>),
    Field(Box<field::FieldArgs>),
    Jacobian(Box<jacobian::JacobianArgs>),
    Points(Box<points::PointsArgs>),
    Transform(Box<transform::TransformArgs>),
    Landmarks(Box<landmarks::LandmarksArgs>),
    Align(Box<align::AlignArgs>),
    Suggest(Box<suggest::SuggestArgs>),
    Register(Box<register::RegisterArgs>),
}

/// The subcommands alone, parsed from an argument list whose first item is the program's name (the Python
/// package's entry; the binary parses [`Command`] beside the window's flags).
#[derive(Debug, clap::Parser)]
#[command(name = "warpbench")]
pub struct Headless {
    #[command(subcommand)]
    pub command: Command,
}

/// Runs `command`, its report (`--json`, tables) written to `out`.
pub fn run(command: Command, out: &mut dyn Write) -> Result<(), Failure> {
    match command {
        Command::Info(args) => info::run(&args, out),
        Command::Warp(args) => warp::run(*args, out).map(|_| ()),
        Command::Eval(args) => eval::run(&args, out),
        Command::Render(args) => render::run(*args).map(|_| ()),
        Command::Field(args) => field::run(*args, out).map(|_| ()),
        Command::Jacobian(args) => jacobian::run(*args, out).map(|_| ()),
        Command::Points(args) => points::run(*args, out).map(|_| ()),
        Command::Transform(args) => transform::run(*args, out).map(|_| ()),
        Command::Landmarks(args) => landmarks::run(*args, out).map(|_| ()),
        Command::Align(args) => align::run(*args, out).map(|_| ()),
        Command::Suggest(args) => suggest::run(*args, out).map(|_| ()),
        Command::Register(args) => register::run(*args, out).map(|_| ()),
    }
}

#[cfg(test)]
mod tests {
    /// clap's own checks of every subcommand's arguments (unique ids, `requires` and `conflicts_with` naming
    /// arguments that exist), which it makes only when a command is parsed in a debug build.
    #[test]
    fn every_subcommand_is_well_formed() {
        use clap::CommandFactory;
        super::Headless::command().debug_assert();
    }
}
