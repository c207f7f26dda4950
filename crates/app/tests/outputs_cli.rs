//! What the headless commands leave on disk and on stderr, with the real binary:
//!
//! - outputs (NIfTI, a DICOM series and its files, `.tfm`) get the mode any new file gets under the user's umask
//!   (set with `sh -c 'umask …; exec …'`: the umask is process-wide and tests run threaded), and an overwritten
//!   file keeps its mode;
//! - a `warp` stopped by SIGTERM or SIGINT in the middle of a write leaves only what was there before, a SIGKILL
//!   leaves a temporary named for what it is, which the next write into that folder removes, and a temporary that
//!   another live warpbench is writing survives that;
//! - an I/O error names the destination once, with the OS error once and no temporary's path;
//! - a successful run prints nothing with `--quiet`, also without `XDG_RUNTIME_DIR` (no windowing library's
//!   complaints from probing for a GPU adapter).
//!
//! The mid-write signals are deterministic: `WARPBENCH_TEST_PAUSE_BEFORE_PERSIST` (a test-only hook of
//! `warpbench_io::atomic`) holds the writer just before its rename, with the temporary complete.
#![cfg(unix)]

mod common;

use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{assert_ok, deformed_pairs, mri, utf8};
use warpbench_io::atomic::{PARTIAL_PREFIX, TEST_PAUSE_VAR};

const BIN: &str = env!("CARGO_BIN_EXE_warpbench");

/// `warp` of the MRI fixture onto itself through `pairs`, on the CPU, quiet, writing `out` (and `extra` args).
fn warp_args(pairs: &Path, out: &Path, extra: &[&str]) -> Vec<String> {
    let m = mri();
    let mut args: Vec<String> = ["warp", "--fixed", utf8(&m), "--moving", utf8(&m), "--landmarks", utf8(pairs)]
        .iter()
        .map(|s| (*s).to_owned())
        .collect();
    args.extend(["--backend", "cpu", "--quiet", "--out", utf8(out)].map(str::to_owned));
    args.extend(extra.iter().map(|s| (*s).to_owned()));
    args
}

/// Runs the binary under `umask`, through the shell (so the umask is the child's alone).
fn run_with_umask(umask: &str, args: &[String]) -> Output {
    Command::new("sh")
        .arg("-c")
        .arg(format!("umask {umask}; exec \"$0\" \"$@\""))
        .arg(BIN)
        .args(args)
        .output()
        .expect("run sh")
}

fn mode(p: &Path) -> u32 {
    std::fs::metadata(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())).permissions().mode() & 0o7777
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .expect("ls")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn is_dicom_name(name: &str) -> bool {
    Path::new(name).extension().is_some_and(|e| e == "dcm")
}

fn temporaries(dir: &Path) -> Vec<String> {
    names(dir).into_iter().filter(|n| n.starts_with(".warpbench")).collect()
}

#[test]
fn outputs_get_the_umask_mode_and_an_overwritten_file_keeps_its_mode() {
    for (umask, file_mode, dir_mode) in [("022", 0o644, 0o755), ("077", 0o600, 0o700), ("002", 0o664, 0o775)] {
        let dir = tempfile::tempdir().expect("tempdir");
        let pairs = deformed_pairs(dir.path(), false);
        let (out, series) = (dir.path().join("out.nii.gz"), dir.path().join("series"));
        let run = run_with_umask(umask, &warp_args(&pairs, &out, &["--out-dicom", utf8(&series)]));
        assert_ok(&run);
        assert_eq!(mode(&out), file_mode, "umask {umask}: {}", out.display());
        assert_eq!(mode(&series), dir_mode, "umask {umask}: the series folder");
        let files = names(&series);
        assert!(!files.is_empty() && files.iter().all(|n| is_dicom_name(n)), "{files:?}");
        for name in &files {
            assert_eq!(mode(&series.join(name)), file_mode, "umask {umask}: {name}");
        }
        // `field` writes the displacement field and the ITK transform the same way.
        let (field, tfm) = (dir.path().join("field.nii.gz"), dir.path().join("affine.tfm"));
        let m = mri();
        let args: Vec<String> = [
            "field",
            "--fixed",
            utf8(&m),
            "--moving",
            utf8(&m),
            "--landmarks",
            utf8(&pairs),
            "--method",
            "affine",
            "--tfm",
            utf8(&tfm),
            "--quiet",
            "--out",
            utf8(&field),
        ]
        .map(str::to_owned)
        .to_vec();
        assert_ok(&run_with_umask(umask, &args));
        assert_eq!((mode(&field), mode(&tfm)), (file_mode, file_mode), "umask {umask}: field, tfm");
        assert!(temporaries(dir.path()).is_empty(), "{:?}", names(dir.path()));
    }

    // Overwritten with --force, an output keeps its mode whatever the umask.
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = deformed_pairs(dir.path(), false);
    let out = dir.path().join("out.nii.gz");
    std::fs::write(&out, b"an older result").expect("write");
    std::fs::set_permissions(&out, std::fs::Permissions::from_mode(0o640)).expect("chmod");
    assert_ok(&run_with_umask("022", &warp_args(&pairs, &out, &["--force"])));
    assert_eq!(mode(&out), 0o640);
    assert!(warpbench_io::open(&out).is_ok(), "the output was replaced by a readable NIfTI");
}

/// Starts a paused `warp` (the hook holds the rename onto `pause_on`), its output discarded.
fn spawn_paused(args: &[String], pause_on: &str) -> Child {
    Command::new(BIN)
        .args(args)
        .env(TEST_PAUSE_VAR, format!("120000:{pause_on}"))
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn warpbench")
}

/// Waits until `ready` says the child is where the test wants it (a minute at most; the child must not exit).
fn wait_until(child: &mut Child, what: &str, ready: impl Fn() -> bool) {
    let start = Instant::now();
    while !ready() {
        if let Some(status) = child.try_wait().expect("try_wait") {
            let mut err = String::new();
            if let Some(mut e) = child.stderr.take() {
                std::io::Read::read_to_string(&mut e, &mut err).expect("stderr");
            }
            panic!("warpbench exited ({status}) before {what}: {err}");
        }
        assert!(start.elapsed() < Duration::from_mins(1), "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn kill(child: &Child, signal: &str) {
    let status = Command::new("kill").args([format!("-{signal}"), child.id().to_string()]).status().expect("kill");
    assert!(status.success(), "kill -{signal}");
}

/// The one temporary in `dir`, once it exists.
fn the_partial(dir: &Path) -> Option<PathBuf> {
    let found: Vec<PathBuf> =
        names(dir).into_iter().filter(|n| n.starts_with(PARTIAL_PREFIX)).map(|n| dir.join(n)).collect();
    let [p] = found.as_slice() else { return None };
    Some(p.clone())
}

/// The one temporary in `dir` once it is a staging folder with DICOM files in it and no temporary of their own:
/// for a one-file series, the writer is then held before the folder's rename (for a series of many files it may
/// be between two files; a signal at any point must leave nothing).
fn the_staged_series(dir: &Path) -> Option<PathBuf> {
    let p = the_partial(dir).filter(|p| p.is_dir())?;
    let files = names(&p);
    (!files.is_empty() && files.iter().all(|n| is_dicom_name(n))).then_some(p)
}

#[test]
fn sigterm_and_sigint_mid_write_leave_only_what_was_there() {
    for (signal, number) in [("TERM", 15), ("INT", 2)] {
        // The NIfTI: killed with its temporary complete, just before the rename.
        let dir = tempfile::tempdir().expect("tempdir");
        let pairs = deformed_pairs(dir.path(), false);
        let before = names(dir.path());
        let out = dir.path().join("out.nii.gz");
        let mut child = spawn_paused(&warp_args(&pairs, &out, &[]), "out.nii.gz");
        wait_until(&mut child, "the temporary NIfTI", || the_partial(dir.path()).is_some());
        kill(&child, signal);
        let status = child.wait().expect("wait");
        assert_eq!(status.signal(), Some(number), "SIG{signal}: {status}");
        assert_eq!(names(dir.path()), before, "SIG{signal} left something");

        // The DICOM series: killed with its staging folder full (every slice written), just before the rename.
        let series = dir.path().join("series");
        let mut child = spawn_paused(&warp_args(&pairs, &out, &["--out-dicom", utf8(&series)]), "series");
        wait_until(&mut child, "the staging folder with the whole series", || the_staged_series(dir.path()).is_some());
        kill(&child, signal);
        let status = child.wait().expect("wait");
        assert_eq!(status.signal(), Some(number), "SIG{signal}: {status}");
        // The NIfTI was complete before the series began: it stays; nothing of the series does.
        let mut expected = before.clone();
        expected.push("out.nii.gz".into());
        expected.sort();
        assert_eq!(names(dir.path()), expected, "SIG{signal} left something of the series");
    }
}

#[test]
fn what_sigkill_leaves_is_named_and_the_next_run_removes_it_but_not_a_live_writers() {
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = deformed_pairs(dir.path(), false);
    let (out, series) = (dir.path().join("out.nii.gz"), dir.path().join("series"));

    // SIGKILL cannot be handled: the staging folder stays, named for what it is.
    let mut child = spawn_paused(&warp_args(&pairs, &out, &["--out-dicom", utf8(&series)]), "series");
    wait_until(&mut child, "the staging folder with the whole series", || the_staged_series(dir.path()).is_some());
    kill(&child, "KILL");
    let killed_pid = child.id();
    assert_eq!(child.wait().expect("wait").signal(), Some(9));
    let leftover = the_staged_series(dir.path()).expect("the staging folder is left");
    let name = leftover.file_name().expect("name").to_string_lossy().into_owned();
    assert!(name.ends_with(".series") && name.contains(&format!("-{killed_pid}-")), "{name}");

    // Another warpbench writing into the same folder, alive: its temporary must survive the next run's cleanup.
    let live_out = dir.path().join("live.nii.gz");
    let mut live = spawn_paused(&warp_args(&pairs, &live_out, &[]), "live.nii.gz");
    let live_partial =
        || names(dir.path()).into_iter().find(|n| n.starts_with(PARTIAL_PREFIX) && n.ends_with(".live.nii.gz"));
    wait_until(&mut live, "the live writer's temporary", || live_partial().is_some());

    // The next run that writes there removes the dead process's leftover, and leaves the live one's.
    let again = dir.path().join("again.nii.gz");
    let run = Command::new(BIN).args(warp_args(&pairs, &again, &["--force"])).output().expect("run");
    assert_ok(&run);
    assert!(!leftover.exists(), "the SIGKILL leftover {name} is still there");
    assert!(live_partial().is_some(), "the live writer's temporary was removed: {:?}", names(dir.path()));

    kill(&live, "TERM");
    assert_eq!(live.wait().expect("wait").signal(), Some(15));
    assert!(temporaries(dir.path()).is_empty(), "{:?}", names(dir.path()));
    assert!(!series.exists() && !live_out.exists());
}

/// Asserts an I/O failure's message: exit 2, `dest` named once, the OS error once, no temporary's path.
fn assert_names_destination_once(run: &Output, dest: &Path, os_error: &str) {
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.matches(utf8(dest)).count(), 1, "the destination once: {stderr}");
    assert_eq!(stderr.matches(os_error).count(), 1, "{os_error:?} once: {stderr}");
    assert_eq!(stderr.matches("os error").count(), 1, "one OS error: {stderr}");
    assert!(!stderr.contains(".partial") && !stderr.contains(".warpbench"), "a temporary's path: {stderr}");
}

#[test]
fn io_errors_name_the_destination_once_without_the_temporary() {
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = deformed_pairs(dir.path(), false);

    // The temporary cannot be created: the folder is a file.
    let under_a_file = pairs.join("out.nii.gz");
    let run = Command::new(BIN).args(warp_args(&pairs, &under_a_file, &[])).output().expect("run");
    assert_names_destination_once(&run, &under_a_file, "Not a directory (os error 20)");

    // --out is a folder (with --force): refused before anything is written, named once, no temporary left (the
    // rename onto a folder, which would fail, is not reached).
    let folder = dir.path().join("folder.nii.gz");
    std::fs::create_dir(&folder).expect("mkdir");
    let run = Command::new(BIN).args(warp_args(&pairs, &folder, &["--force"])).output().expect("run");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.matches(utf8(&folder)).count(), 1, "the destination once: {stderr}");
    assert!(stderr.contains("a folder that warpbench does not replace"), "{stderr}");
    assert!(temporaries(dir.path()).is_empty(), "{:?}", names(dir.path()));

    // A read-only folder (where permissions apply: root writes anyway).
    let read_only = dir.path().join("read-only");
    std::fs::create_dir(&read_only).expect("mkdir");
    std::fs::set_permissions(&read_only, std::fs::Permissions::from_mode(0o555)).expect("chmod");
    if std::fs::write(read_only.join("probe"), b"x").is_err() {
        let out = read_only.join("out.nii.gz");
        let run = Command::new(BIN).args(warp_args(&pairs, &out, &[])).output().expect("run");
        assert_names_destination_once(&run, &out, "Permission denied (os error 13)");
    }
    std::fs::set_permissions(&read_only, std::fs::Permissions::from_mode(0o755)).expect("chmod");
}

#[test]
fn a_successful_headless_run_prints_nothing_without_xdg_runtime_dir() {
    let dir = tempfile::tempdir().expect("tempdir");
    let pairs = deformed_pairs(dir.path(), false);
    let m = mri();
    let out = dir.path().join("out.nii.gz");
    // The default backend (auto) probes for a GPU adapter.
    let mut warp = warp_args(&pairs, &out, &[]);
    let at = warp.iter().position(|a| a == "--backend").expect("--backend");
    warp.drain(at..at + 2);
    let field = dir.path().join("field.nii.gz");
    let png = dir.path().join("view.png");
    let runs: [Vec<String>; 3] = [
        warp,
        [
            "field",
            "--fixed",
            utf8(&m),
            "--moving",
            utf8(&m),
            "--landmarks",
            utf8(&pairs),
            "--quiet",
            "--out",
            utf8(&field),
        ]
        .map(str::to_owned)
        .to_vec(),
        ["render", "--fixed", utf8(&m), "--size", "64x64", "--quiet", "--out", utf8(&png)].map(str::to_owned).to_vec(),
    ];
    for args in runs {
        let run = Command::new(BIN).args(&args).env_remove("XDG_RUNTIME_DIR").output().expect("run");
        let stderr = String::from_utf8_lossy(&run.stderr);
        if args[0] == "render" && run.status.code() == Some(1) && stderr.contains("no GPU adapter") {
            assert!(std::env::var_os("REQUIRE_GPU_ADAPTER").is_none(), "no GPU adapter: {stderr}");
            continue;
        }
        assert_ok(&run);
        assert_eq!(stderr, "", "{} printed on stderr", args[0]);
        assert!(run.stdout.is_empty(), "{} printed on stdout", args[0]);
    }
}
