//! Exit codes: 0 ok; 2 bad input or usage (the message names the file and the problem);
//! 1 internal error; 3 an accuracy gate failed (used by `eval`). [`Failure::Cancelled`] (130, as for an interrupted
//! command) comes only from the in-memory cores when their caller (the window's cancel button) stops them; no
//! subcommand cancels.
//!
//! [`Failure`] belongs to `main.rs` and the subcommands. The modules they share with the window (`inputs`, `scene`,
//! `fit`) return `anyhow` errors that name the file and the problem; every one of those is about the input, and the
//! subcommands wrap it as [`Failure::BadInput`].

use std::io::Write;
use std::process::ExitCode;

use anyhow::Context;

/// A failure that knows which exit code it maps to.
#[derive(Debug)]
pub enum Failure {
    /// Bad input or usage: exit code 2.
    BadInput(anyhow::Error),
    /// A bug or an environment problem: exit code 1.
    Internal(anyhow::Error),
    /// An accuracy gate failed (`eval --max-tre-mm`): exit code 3.
    AccuracyGate(anyhow::Error),
    /// The caller's progress callback asked to stop; nothing was written: exit code 130.
    Cancelled(anyhow::Error),
}

impl Failure {
    #[must_use]
    pub fn code(&self) -> ExitCode {
        match self {
            Self::BadInput(_) => ExitCode::from(2),
            Self::Internal(_) => ExitCode::from(1),
            Self::AccuracyGate(_) => ExitCode::from(3),
            Self::Cancelled(_) => ExitCode::from(130),
        }
    }
    #[must_use]
    pub fn error(&self) -> &anyhow::Error {
        match self {
            Self::BadInput(e) | Self::Internal(e) | Self::AccuracyGate(e) | Self::Cancelled(e) => e,
        }
    }

    /// The message for stderr: the error and its causes joined with ": ", each once. (An error that shows its
    /// source in its own text, as an I/O error does with the OS error, would otherwise print it twice.)
    #[must_use]
    pub fn message(&self) -> String {
        let mut text = String::new();
        for cause in self.error().chain() {
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
}

/// Prints `value` as pretty JSON and a newline to `out`: a subcommand's `--json` report (`what` names it in the error,
/// e.g. "the JSON summary"). A failure to write is internal (exit code 1).
pub fn print_json(out: &mut dyn Write, value: &impl serde::Serialize, what: &str) -> Result<(), Failure> {
    serde_json::to_writer_pretty(&mut *out, value)
        .map_err(std::io::Error::from)
        .and_then(|()| writeln!(out))
        .with_context(|| format!("writing {what}"))
        .map_err(Failure::Internal)
}

/// A reader or writer error is about the input (exit code 2): it names the file and the problem.
impl From<warpbench_io::Error> for Failure {
    fn from(e: warpbench_io::Error) -> Self {
        Self::BadInput(e.into())
    }
}
