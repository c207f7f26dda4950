//! Atomic output: every file warpbench writes goes through [`write_atomic`] (a DICOM series through
//! [`StagingDir`]). The data goes to a temporary beside the destination that is renamed onto it only once it is
//! complete and flushed, so a failed or interrupted write never leaves a half-written output.
//!
//! - **Modes.** A new output gets the permissions any new file gets under the user's umask (`0666 & !umask`, a
//!   folder `0777 & !umask`); an overwritten file (or an empty folder a series replaces) keeps its mode.
//! - **Temporaries** are named `.warpbench-partial-<host>-<pid>-<random>.<destination name>`, so what a killed
//!   process leaves says what it is and whose it was. Each is removed on every error path (and when a panic
//!   unwinds); [`remove_temporaries_before_exit`] removes the live ones from a SIGINT/SIGTERM handler (the CLI
//!   installs one). What a SIGKILL leaves is removed by the next write into that folder: a temporary whose process
//!   is gone from this host, or any one older than [`STALE_AFTER`]; never one another live process is writing.
//! - **Errors** name the destination the caller asked for, never the temporary.
//! - **Test hook.** `WARPBENCH_TEST_PAUSE_BEFORE_PERSIST=<ms>[:<destination file name>]` sleeps before each rename
//!   onto a destination (only that one, when named). It exists for tests that signal a process mid-write; nothing
//!   else sets it.

use std::ffi::OsStr;
use std::fs::{self, File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard, OnceLock, PoisonError};
use std::time::Duration;

use crate::error::{Error, Result};

/// How every temporary's name starts.
pub const PARTIAL_PREFIX: &str = ".warpbench-partial-";

/// A temporary older than this is removed by the next write into its folder whoever made it: no write takes a day.
pub const STALE_AFTER: Duration = Duration::from_hours(24);

/// The test hook's variable (see the module docs).
pub const TEST_PAUSE_VAR: &str = "WARPBENCH_TEST_PAUSE_BEFORE_PERSIST";

/// The longest file name the common file systems take, in bytes.
const MAX_NAME_BYTES: usize = 255;

/// The temporaries this process has live. Creating, renaming and removing one happens under this lock, so a signal
/// handler holding it sees every temporary that exists and none appears after it.
static LIVE: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn live() -> MutexGuard<'static, Vec<PathBuf>> {
    LIVE.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Writes `path` through `fill`; the file appears only once `fill` succeeded and the data is flushed.
pub fn write_atomic(path: &Path, fill: impl FnOnce(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    let dir = parent_dir(path);
    // Inside a staging folder (a series' files) there is nothing to clean and nothing to pause for.
    let nested = is_partial_name(dir.file_name());
    if !nested {
        remove_stale_leftovers(dir);
    }
    let (tmp, file) = Temporary::create(path, false, |p| OpenOptions::new().write(true).create_new(true).open(p))?;
    {
        let mut w = BufWriter::new(&file);
        fill(&mut w).map_err(|e| Error::io(path, e))?;
        w.flush().map_err(|e| Error::io(path, e))?;
    }
    keep_mode(path, &file)?;
    file.sync_all().map_err(|e| Error::io(path, e))?;
    drop(file);
    if !nested {
        test_pause(path);
    }
    tmp.persist(path)
}

/// A folder beside a destination folder, filled and then renamed onto it: how a DICOM series appears atomically.
/// Its name and its cleanup are a temporary file's (module docs); dropping it unpersisted removes it with its
/// contents. Write its files with [`write_atomic`] into [`Self::path`].
#[derive(Debug)]
pub struct StagingDir(Temporary);

impl StagingDir {
    /// Creates the staging folder beside `dest` (mode `0777 & !umask`), after removing stale leftovers there.
    pub fn new_beside(dest: &Path) -> Result<Self> {
        remove_stale_leftovers(parent_dir(dest));
        let (tmp, ()) = Temporary::create(dest, true, |p| fs::create_dir(p))?;
        Ok(Self(tmp))
    }

    /// The staging folder.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.0.path
    }

    /// Renames the staging folder onto `dest`, which must not exist or be an empty folder (whose mode it keeps).
    pub fn persist(self, dest: &Path) -> Result<()> {
        if let Ok(meta) = fs::symlink_metadata(dest)
            && meta.is_dir()
        {
            fs::set_permissions(self.path(), meta.permissions()).map_err(|e| Error::io(dest, e))?;
            // POSIX rename replaces an empty folder; elsewhere it has to go first.
            #[cfg(not(unix))]
            fs::remove_dir(dest).map_err(|e| Error::io(dest, e))?;
        }
        test_pause(dest);
        self.0.persist(dest)
    }

    /// Puts the staging folder in the place of the existing folder `dest` (whose mode it keeps) and removes the old
    /// one. On Linux the two names are exchanged in one step, so `dest` is at every moment the old folder or the new
    /// one. Where the system or the file system cannot exchange names, the old folder is renamed aside (to a
    /// temporary's name) first, and a crash between the two renames leaves it there and no `dest`. The caller
    /// decides that `dest` may be replaced.
    pub fn persist_replacing(self, dest: &Path) -> Result<()> {
        let meta = fs::symlink_metadata(dest).map_err(|e| Error::io(dest, e))?;
        fs::set_permissions(self.path(), meta.permissions()).map_err(|e| Error::io(dest, e))?;
        test_pause(dest);
        let staged = self.0;
        {
            let _live = live();
            exchange(&staged.path, dest).map_err(|e| Error::io(dest, e))?;
        }
        // The staging folder's name now holds the old folder, which dropping the temporary removes.
        drop(staged);
        Ok(())
    }
}

/// Exchanges the folders `staged` (a temporary) and `dest`: in one step where the system can, else by renaming
/// `dest` aside, `staged` onto `dest`, and the old one to `staged`'s name (`dest` put back if the second fails).
fn exchange(staged: &Path, dest: &Path) -> std::io::Result<()> {
    #[cfg(target_os = "linux")]
    {
        use rustix::fs::{CWD, RenameFlags, renameat_with};
        use rustix::io::Errno;
        match renameat_with(CWD, staged, CWD, dest, RenameFlags::EXCHANGE) {
            Ok(()) => return Ok(()),
            // A file system or kernel without the exchange: rename in steps.
            Err(e) if e == Errno::INVAL || e == Errno::NOSYS || e == Errno::NOTSUP => {}
            Err(e) => return Err(e.into()),
        }
    }
    exchange_in_steps(staged, dest)
}

/// [`exchange`] in three renames, for systems without an exchange.
fn exchange_in_steps(staged: &Path, dest: &Path) -> std::io::Result<()> {
    let dest_name = dest.file_name().unwrap_or_else(|| OsStr::new("output"));
    let aside = parent_dir(dest).join(partial_name(dest_name, &random_tag()));
    fs::rename(dest, &aside)?;
    if let Err(e) = fs::rename(staged, dest) {
        let _ = fs::rename(&aside, dest);
        return Err(e);
    }
    fs::rename(&aside, staged)
}

/// Removes every temporary this process has live and keeps any other thread from creating or renaming one from then
/// on (they block): for a SIGINT/SIGTERM handler that ends the process right after. Never call it otherwise.
pub fn remove_temporaries_before_exit() {
    let mut live = live();
    // Files inside a staging folder were registered after it: remove them first.
    for path in live.drain(..).rev() {
        remove_path(&path);
    }
    // The process ends next: holding the lock until then is the point (no temporary appears after this).
    std::mem::forget(live);
}

/// One temporary file or folder, registered in [`LIVE`] while it exists. Dropped unpersisted, it is removed.
#[derive(Debug)]
struct Temporary {
    path: PathBuf,
    persisted: bool,
}

impl Temporary {
    /// Creates a temporary beside `dest` with `make` (which must fail with `AlreadyExists` on a taken name).
    fn create<T>(dest: &Path, folder: bool, make: impl Fn(&Path) -> std::io::Result<T>) -> Result<(Self, T)> {
        let Some(dest_name) = dest.file_name() else {
            return Err(Error::invalid(dest, "the output path names no file"));
        };
        let dir = parent_dir(dest);
        for _ in 0..64 {
            let path = dir.join(partial_name(dest_name, &random_tag()));
            let mut live = live();
            match make(&path) {
                Ok(made) => {
                    live.push(path.clone());
                    return Ok((Self { path, persisted: false }, made));
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
                Err(e) => return Err(Error::io(dest, e)),
            }
        }
        let what = if folder { "folder" } else { "file" };
        Err(Error::io(dest, std::io::Error::other(format!("no free name for a temporary {what} beside it"))))
    }

    fn persist(mut self, dest: &Path) -> Result<()> {
        let mut live = live();
        fs::rename(&self.path, dest).map_err(|e| Error::io(dest, e))?;
        live.retain(|p| p != &self.path);
        self.persisted = true;
        Ok(())
    }
}

impl Drop for Temporary {
    fn drop(&mut self) {
        if !self.persisted {
            let mut live = live();
            remove_path(&self.path);
            live.retain(|p| p != &self.path);
        }
    }
}

/// The folder `path` is in (`.` for a bare name).
fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// Gives the temporary `file` an overwritten destination's mode (permission bits only).
fn keep_mode(dest: &Path, file: &File) -> Result<()> {
    let Ok(meta) = fs::metadata(dest) else { return Ok(()) };
    if !meta.is_file() {
        return Ok(());
    }
    #[cfg(unix)]
    let permissions = {
        use std::os::unix::fs::PermissionsExt;
        fs::Permissions::from_mode(meta.permissions().mode() & 0o777)
    };
    #[cfg(not(unix))]
    let permissions = meta.permissions();
    file.set_permissions(permissions).map_err(|e| Error::io(dest, e))
}

/// Removes a file, or a folder with its contents; never follows a symbolic link. Best effort: a temporary that is
/// already gone, or cannot be removed, is left to the next run.
fn remove_path(path: &Path) {
    let Ok(meta) = fs::symlink_metadata(path) else { return };
    let _ = if meta.is_dir() { fs::remove_dir_all(path) } else { fs::remove_file(path) };
}

/// `.warpbench-partial-<host>-<pid>-<tag>.<dest name>`, the destination's name shortened (and made UTF-8) where
/// the whole would be too long.
fn partial_name(dest_name: &OsStr, tag: &str) -> String {
    let head = format!("{PARTIAL_PREFIX}{}-{}-{tag}.", host_tag(), std::process::id());
    let room = MAX_NAME_BYTES.saturating_sub(head.len());
    let name = dest_name.to_string_lossy();
    let mut end = name.len().min(room);
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    format!("{head}{}", &name[..end])
}

/// The host and the pid in a temporary's name, or `None` when `name` is not one.
fn parse_partial_name(name: &str) -> Option<(&str, u32)> {
    let rest = name.strip_prefix(PARTIAL_PREFIX)?;
    let (host, rest) = rest.split_once('-')?;
    let (pid, rest) = rest.split_once('-')?;
    let (tag, _dest) = rest.split_once('.')?;
    let alnum = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_alphanumeric());
    if !alnum(host) || tag.len() != TAG_LEN || !alnum(tag) || !pid.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    Some((host, pid.parse().ok()?))
}

fn is_partial_name(name: Option<&OsStr>) -> bool {
    name.and_then(OsStr::to_str).is_some_and(|n| parse_partial_name(n).is_some())
}

/// What warpbench versions before these names left: `.warpbench-XXXXXX.partial` and `.warpbench-series-XXXXXX`.
/// Whose they are cannot be told, so only their age makes them stale.
fn is_legacy_temporary(name: &str) -> bool {
    let random = |s: &str| s.len() == 6 && s.bytes().all(|b| b.is_ascii_alphanumeric());
    name.strip_prefix(".warpbench-series-").is_some_and(random)
        || name.strip_prefix(".warpbench-").and_then(|r| r.strip_suffix(".partial")).is_some_and(random)
}

/// Removes the temporaries in `dir` that no live process is writing: those of a process gone from this host, and
/// any older than [`STALE_AFTER`]. Best effort: a folder that cannot be listed is left alone.
fn remove_stale_leftovers(dir: &Path) {
    let Ok(entries) = fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        let owner = parse_partial_name(name);
        if owner.is_none() && !is_legacy_temporary(name) {
            continue;
        }
        // `DirEntry::metadata` does not follow a symbolic link.
        let Ok(meta) = entry.metadata() else { continue };
        let old = meta.modified().ok().and_then(|t| t.elapsed().ok()).is_some_and(|age| age > STALE_AFTER);
        let orphan =
            owner.is_some_and(|(host, pid)| host == host_tag() && pid != std::process::id() && !process_alive(pid));
        let path = entry.path();
        if (old || orphan) && !live().contains(&path) {
            remove_path(&path);
        }
    }
}

/// Whether process `pid` runs on this host. Where that cannot be told (no `/proc`), it is taken to run.
fn process_alive(pid: u32) -> bool {
    let proc = Path::new("/proc");
    if !proc.join("self").exists() {
        return true;
    }
    match fs::read_to_string(proc.join(pid.to_string()).join("stat")) {
        // The state follows the parenthesised command name: a zombie (Z) or a dead (X) process writes nothing.
        Ok(stat) => {
            !stat.rsplit_once(')').is_some_and(|(_, rest)| matches!(rest.trim_start().chars().next(), Some('Z' | 'X')))
        }
        Err(_) => proc.join(pid.to_string()).exists(),
    }
}

/// This host's name, letters and digits only, at most 16 (`host` when it cannot be read).
fn host_tag() -> &'static str {
    static HOST: OnceLock<String> = OnceLock::new();
    HOST.get_or_init(|| {
        let raw = fs::read_to_string("/proc/sys/kernel/hostname")
            .or_else(|_| fs::read_to_string("/etc/hostname"))
            .ok()
            .or_else(|| std::env::var("HOSTNAME").ok())
            .or_else(|| std::env::var("COMPUTERNAME").ok())
            .unwrap_or_default();
        let tag: String = raw.trim().chars().filter(char::is_ascii_alphanumeric).take(16).collect();
        if tag.is_empty() { "host".into() } else { tag }
    })
}

const TAG_LEN: usize = 6;

/// Six random letters and digits: the temporaries' names differ within one process and across processes.
fn random_tag() -> String {
    use std::collections::hash_map::RandomState;
    use std::hash::{BuildHasher, Hasher};
    const ALPHABET: &[u8] = b"0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz";
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let mut h = RandomState::new().build_hasher();
    h.write_u64(COUNTER.fetch_add(1, Ordering::Relaxed));
    h.write_u128(std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos()));
    let mut x = h.finish();
    (0..TAG_LEN)
        .map(|_| {
            let c = ALPHABET[(x % ALPHABET.len() as u64) as usize];
            x /= ALPHABET.len() as u64;
            char::from(c)
        })
        .collect()
}

/// The test hook (module docs).
fn test_pause(dest: &Path) {
    let Ok(spec) = std::env::var(TEST_PAUSE_VAR) else { return };
    let (ms, only) = match spec.split_once(':') {
        Some((ms, name)) => (ms, Some(name)),
        None => (spec.as_str(), None),
    };
    if only.is_some_and(|name| dest.file_name() != Some(OsStr::new(name))) {
        return;
    }
    if let Ok(ms) = ms.parse::<u64>() {
        std::thread::sleep(Duration::from_millis(ms));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .expect("ls")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn failed_write_leaves_nothing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("out.bin");
        let r = write_atomic(&out, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("boom"))
        });
        assert!(r.is_err());
        assert!(!out.exists());
        assert_eq!(std::fs::read_dir(dir.path()).expect("ls").count(), 0, "temporary file was not removed");
        write_atomic(&out, |w| w.write_all(b"done")).expect("write");
        assert_eq!(std::fs::read(&out).expect("read"), b"done");
    }

    /// A rename that fails (the destination is a folder) names the destination once, not the temporary, and leaves
    /// no temporary (the command line refuses a folder before this; the library keeps the promise on its own).
    #[test]
    fn a_failed_rename_names_the_destination_and_leaves_nothing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("folder.nii");
        fs::create_dir(&out).expect("mkdir");
        fs::write(out.join("inside"), b"x").expect("write");
        let e = write_atomic(&out, |w| w.write_all(b"data")).expect_err("onto a folder");
        let text = e.to_string();
        assert_eq!(text.matches("folder.nii").count(), 1, "{text}");
        assert!(!text.contains(PARTIAL_PREFIX), "{text}");
        assert_eq!(names(dir.path()), ["folder.nii"]);
    }

    /// Both ways of exchanging a staging folder with an existing one leave the new folder in its place, the old one
    /// under the staging folder's name, and nothing else.
    #[test]
    fn a_folder_is_replaced_whole_in_one_step_or_in_three() {
        for steps in [false, true] {
            let dir = tempfile::tempdir().expect("tempdir");
            let dest = dir.path().join("out.zarr");
            fs::create_dir(&dest).expect("mkdir");
            fs::write(dest.join("old"), b"old").expect("write");
            let staging = StagingDir::new_beside(&dest).expect("staging");
            fs::write(staging.path().join("new"), b"new").expect("write");
            let staged = staging.path().to_owned();
            if steps {
                exchange_in_steps(&staged, &dest).expect("exchange");
                assert!(staged.join("old").is_file(), "the old folder under the staging name");
                drop(staging);
            } else {
                staging.persist_replacing(&dest).expect("replace");
            }
            assert_eq!(names(&dest), ["new"]);
            assert_eq!(names(dir.path()), ["out.zarr"], "steps {steps}");
        }
    }

    #[cfg(unix)]
    fn mode(p: &Path) -> u32 {
        use std::os::unix::fs::PermissionsExt;
        fs::metadata(p).expect("stat").permissions().mode() & 0o7777
    }

    /// Whatever this process's umask is, an output gets the mode a plain new file gets (the umask itself is set in
    /// a child process by the app's tests: it is process-wide and these tests run threaded).
    #[cfg(unix)]
    #[test]
    fn a_new_output_gets_the_mode_of_any_new_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let plain = dir.path().join("plain.bin");
        File::create(&plain).expect("create");
        let out = dir.path().join("out.bin");
        write_atomic(&out, |w| w.write_all(b"x")).expect("write");
        assert_eq!(mode(&out), mode(&plain), "{:o} vs {:o}", mode(&out), mode(&plain));
        let series = dir.path().join("series");
        let plain_dir = dir.path().join("plain_dir");
        fs::create_dir(&plain_dir).expect("mkdir");
        let staging = StagingDir::new_beside(&series).expect("staging");
        write_atomic(&staging.path().join("IM1.dcm"), |w| w.write_all(b"x")).expect("write");
        staging.persist(&series).expect("persist");
        assert_eq!(mode(&series), mode(&plain_dir));
        assert_eq!(mode(&series.join("IM1.dcm")), mode(&plain));
    }

    #[cfg(unix)]
    #[test]
    fn an_overwritten_output_keeps_its_mode() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("out.bin");
        fs::write(&out, b"old").expect("write");
        fs::set_permissions(&out, fs::Permissions::from_mode(0o640)).expect("chmod");
        write_atomic(&out, |w| w.write_all(b"new")).expect("write");
        assert_eq!(fs::read(&out).expect("read"), b"new");
        assert_eq!(mode(&out), 0o640);
        // An empty folder a series replaces keeps its mode too.
        let series = dir.path().join("series");
        fs::create_dir(&series).expect("mkdir");
        fs::set_permissions(&series, fs::Permissions::from_mode(0o750)).expect("chmod");
        let staging = StagingDir::new_beside(&series).expect("staging");
        write_atomic(&staging.path().join("IM1.dcm"), |w| w.write_all(b"x")).expect("write");
        staging.persist(&series).expect("persist");
        assert_eq!(mode(&series), 0o750);
        assert_eq!(names(&series), ["IM1.dcm"]);
    }

    #[test]
    fn errors_name_the_destination_not_the_temporary() {
        let dir = tempfile::tempdir().expect("tempdir");
        let file = dir.path().join("file");
        fs::write(&file, b"x").expect("write");
        // Creating the temporary fails: its folder is a file.
        let under_a_file = file.join("out.nii");
        let e = write_atomic(&under_a_file, |w| w.write_all(b"x")).expect_err("not a folder");
        assert_eq!(e.path, under_a_file);
        let text = e.to_string();
        assert!(!text.contains(PARTIAL_PREFIX) && !text.contains(".partial"), "{text}");
        assert_eq!(text.matches("os error").count(), 1, "{text}");
        // Renaming it fails: the destination is a folder. The temporary is removed.
        let folder = dir.path().join("folder.nii");
        fs::create_dir(&folder).expect("mkdir");
        let e = write_atomic(&folder, |w| w.write_all(b"x")).expect_err("a folder");
        assert_eq!(e.path, folder);
        assert!(!e.to_string().contains(PARTIAL_PREFIX), "{e}");
        assert_eq!(names(dir.path()), ["file", "folder.nii"]);
        // A staging folder that cannot replace a non-empty folder is removed, and the error names the folder.
        fs::write(folder.join("keep"), b"x").expect("write");
        let staging = StagingDir::new_beside(&folder).expect("staging");
        let e = staging.persist(&folder).expect_err("not empty");
        assert_eq!(e.path, folder);
        assert_eq!(names(dir.path()), ["file", "folder.nii"]);
    }

    #[test]
    fn temporaries_say_what_they_are_and_whose() {
        let name = partial_name(OsStr::new("mr_in_ct.nii.gz"), "Ab12Cd");
        assert!(name.starts_with(PARTIAL_PREFIX) && name.ends_with("-Ab12Cd.mr_in_ct.nii.gz"), "{name}");
        assert_eq!(parse_partial_name(&name), Some((host_tag(), std::process::id())));
        let long = "é".repeat(200);
        let name = partial_name(OsStr::new(&long), "Ab12Cd");
        assert!(name.len() <= MAX_NAME_BYTES, "{}", name.len());
        assert!(parse_partial_name(&name).is_some());
        for not_ours in
            [".warpbench-partial-", ".warpbench-partial-h-12-abc.x", "warpbench-partial-h-1-Ab12Cd.x", "notes"]
        {
            assert_eq!(parse_partial_name(not_ours), None, "{not_ours}");
        }
        assert!(is_legacy_temporary(".warpbench-6EqQR5.partial") && is_legacy_temporary(".warpbench-series-a1B2c3"));
        assert!(!is_legacy_temporary(".warpbench-notes.partial") && !is_legacy_temporary(".warpbench-series-x"));
    }

    /// A pid that no process has: a child that has exited and been reaped.
    fn dead_pid() -> u32 {
        let mut child = std::process::Command::new("true").spawn().expect("spawn true");
        let pid = child.id();
        child.wait().expect("wait");
        pid
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn the_next_write_removes_what_dead_processes_left_and_nothing_else() {
        let dir = tempfile::tempdir().expect("tempdir");
        let host = host_tag();
        let dead = dead_pid();
        let put = |name: &str, folder: bool| {
            let p = dir.path().join(name);
            if folder {
                fs::create_dir(&p).expect("mkdir");
                fs::write(p.join("IM00001.dcm"), b"x").expect("write");
            } else {
                fs::write(&p, b"x").expect("write");
            }
            p
        };
        let day_old = |p: &Path| {
            let t = std::time::SystemTime::now() - STALE_AFTER - Duration::from_mins(1);
            File::open(p).expect("open").set_modified(t).expect("set mtime");
        };
        let dead_file = format!("{PARTIAL_PREFIX}{host}-{dead}-aaaaaa.out.nii.gz");
        let dead_folder = format!("{PARTIAL_PREFIX}{host}-{dead}-bbbbbb.series");
        let alive = format!("{PARTIAL_PREFIX}{host}-{}-cccccc.other.nii.gz", std::process::id());
        let other_host = format!("{PARTIAL_PREFIX}elsewhere{host}-{dead}-dddddd.x.nii");
        let other_host_old = format!("{PARTIAL_PREFIX}elsewhere{host}-{dead}-eeeeee.y.nii");
        let legacy_old = ".warpbench-Ab12Cd.partial";
        let legacy_fresh = ".warpbench-series-Zz9Yy8";
        for (name, folder) in [(&*dead_file, false), (&*dead_folder, true), (&*alive, false), (&*other_host, false)] {
            put(name, folder);
        }
        day_old(&put(&other_host_old, false));
        day_old(&put(legacy_old, false));
        put(legacy_fresh, true);
        put(".warpbench-notes", false);
        write_atomic(&dir.path().join("new.nii"), |w| w.write_all(b"x")).expect("write");
        let mut expected =
            vec![alive, other_host, legacy_fresh.to_owned(), ".warpbench-notes".to_owned(), "new.nii".into()];
        expected.sort();
        assert_eq!(names(dir.path()), expected);
    }
}
