//! The sessions opened or saved most recently, newest first: the window's File > Open recent session. The list is
//! kept in `recent.json` beside the autosave, written atomically on every change; one that cannot be read starts
//! empty (it is a convenience, not the user's work).

use std::path::{Path, PathBuf};

use anyhow::Context as _;
use serde::{Deserialize, Serialize};

/// How many sessions the list keeps.
pub const MAX_SESSIONS: usize = 8;

/// `recent.json` as stored.
#[derive(Debug, Default, Serialize, Deserialize)]
struct Stored {
    sessions: Vec<PathBuf>,
}

/// The list and the file it is kept in.
#[derive(Debug)]
pub struct Recent {
    file: PathBuf,
    sessions: Vec<PathBuf>,
}

impl Recent {
    /// The list kept in `file` (empty where there is none or it cannot be read).
    #[must_use]
    pub fn load(file: PathBuf) -> Self {
        let stored = std::fs::read(&file).ok().and_then(|bytes| serde_json::from_slice::<Stored>(&bytes).ok());
        Self { file, sessions: stored.unwrap_or_default().sessions }
    }

    /// The sessions, newest first.
    #[must_use]
    pub fn sessions(&self) -> &[PathBuf] {
        &self.sessions
    }

    /// Puts `session` first (as an absolute path; once), keeps [`MAX_SESSIONS`] and writes the list.
    ///
    /// # Errors
    /// The list cannot be written (named).
    pub fn note(&mut self, session: &Path) -> anyhow::Result<()> {
        let session = std::path::absolute(session).unwrap_or_else(|_| session.to_path_buf());
        self.sessions.retain(|s| s != &session);
        self.sessions.insert(0, session);
        self.sessions.truncate(MAX_SESSIONS);
        if let Some(folder) = self.file.parent() {
            std::fs::create_dir_all(folder)
                .with_context(|| format!("{}: cannot create the folder", folder.display()))?;
        }
        let text = serde_json::to_vec_pretty(&Stored { sessions: self.sessions.clone() })?;
        warpbench_io::atomic::write_atomic(&self.file, |out| std::io::Write::write_all(out, &text))?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_newest_comes_first_once_the_list_keeps_eight_and_survives_a_restart() {
        let dir = tempfile::tempdir().expect("tempdir");
        let file = dir.path().join("state/recent.json");
        let mut recent = Recent::load(file.clone());
        assert!(recent.sessions().is_empty(), "no file yet");
        for n in 0..10 {
            recent.note(&dir.path().join(format!("s{n}.warpbench.json"))).expect("note");
        }
        recent.note(&dir.path().join("s5.warpbench.json")).expect("note");
        let names: Vec<String> =
            recent.sessions().iter().map(|p| p.file_name().expect("name").to_string_lossy().into_owned()).collect();
        let want = ["s5", "s9", "s8", "s7", "s6", "s4", "s3", "s2"].map(|s| format!("{s}.warpbench.json"));
        assert_eq!(names, want);
        assert_eq!(Recent::load(file.clone()).sessions(), recent.sessions(), "read back after a restart");
        std::fs::write(&file, b"not json").expect("write");
        assert!(Recent::load(file).sessions().is_empty(), "an unreadable list starts empty");
    }
}
