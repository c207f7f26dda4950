//! Exit codes: 0 ok; 2 bad input or usage (the message names the file and the problem);
//! 1 internal error; 3 an accuracy gate failed (used by `eval`); 141, without a message, when the reader of standard
//! output closed it first (`warpbench info … | head`), as a command that SIGPIPE ends. [`Failure::Cancelled`] (130, as for an interrupted
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

    /// Whether it failed only because the reader of what it wrote went away (a closed pipe, `… | head`): then there
    /// is no one to tell, and the exit code is 141, a shell's for a command that SIGPIPE ends ([`Self::exit_code`]).
    #[must_use]
    pub fn is_broken_pipe(&self) -> bool {
        self.error().chain().any(|cause| {
            cause.downcast_ref::<std::io::Error>().is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe)
        })
    }

    /// The process's exit code, and the message for stderr (none for a closed pipe).
    #[must_use]
    pub fn exit_code(&self) -> (ExitCode, Option<String>) {
        if self.is_broken_pipe() { (ExitCode::from(141), None) } else { (self.code(), Some(self.message())) }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A report that could not be written because its reader closed the pipe ends quietly, whatever wraps it; an
    /// I/O error of another kind still speaks.
    #[test]
    fn a_closed_pipe_is_quiet_and_other_write_errors_are_not() {
        let closed = std::io::Error::from(std::io::ErrorKind::BrokenPipe);
        let failure = Failure::Internal(anyhow::Error::from(closed).context("writing the output"));
        assert!(failure.is_broken_pipe());
        assert_eq!(failure.exit_code(), (ExitCode::from(141), None));
        let full = std::io::Error::from(std::io::ErrorKind::StorageFull);
        let failure = Failure::Internal(anyhow::Error::from(full).context("writing the output"));
        assert!(!failure.is_broken_pipe());
        assert_eq!(failure.exit_code().0, ExitCode::from(1));
        assert!(failure.exit_code().1.is_some_and(|m| m.contains("writing the output")));
    }
}
