//! `warpbench info` on the hostile inputs of issue 13 (items 4 to 7 and 17), through the real binary: a pipe
//! never blocks it, a stream that inflates past the address space is exit 2 naming the file and the size (not an
//! abort), an implausible spacing or a disagreeing sform/qform is a warning on stderr and in `--json`, and a 4-D
//! file's message speaks of `--frame`.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use warpbench_io::geometry::Transform;
use warpbench_io::nrrd::{self, NrrdWriteOptions};
use warpbench_io::{GeometrySource, Volume, VoxelData};

/// The same limit as `bad_input.rs`: less than the 2·10⁹ bytes the inflating files need.
const ADDRESS_SPACE_LIMIT_KIB: u64 = 1024 * 1024;
/// A run longer than this is taken to hang.
const HANG_LIMIT: Duration = Duration::from_secs(30);

/// Runs `warpbench info --quiet <args>` under the address-space limit, killing it if it hangs.
fn info(args: &[&str]) -> Output {
    let mut child = Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {ADDRESS_SPACE_LIMIT_KIB} && exec \"$0\" info --quiet \"$@\""))
        .arg(env!("CARGO_BIN_EXE_warpbench"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run warpbench");
    let start = Instant::now();
    while child.try_wait().expect("wait").is_none() {
        if start.elapsed() > HANG_LIMIT {
            let _ = child.kill();
            let out = child.wait_with_output().expect("output");
            panic!("warpbench info {args:?} hangs: killed after {HANG_LIMIT:?}; stderr: {}", text(&out.stderr));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().expect("output")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn path_arg(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 temporary path")
}

#[test]
fn a_named_pipe_or_a_pipe_as_data_file_is_exit_2_not_a_hang() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fifo = dir.path().join("volume.nii.gz");
    assert!(Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
    let header = dir.path().join("zero.nhdr");
    std::fs::write(
        &header,
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 8 8 8\nencoding: gzip\nline skip: 1\ndata file: /dev/zero\n\n",
    )
    .expect("write");
    for (arg, named) in [(fifo.as_path(), "volume.nii.gz"), (header.as_path(), "/dev/zero")] {
        let out = info(&[path_arg(arg)]);
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains(named) && stderr.contains("not a regular file"), "{stderr}");
    }
}

/// 2000 × 1000 × 1000 u8: the shape, 2·10⁹ bytes.
const HUGE_BYTES: u64 = 2_000_000_000;
const MEMBER_BYTES: usize = 16 << 20;

/// One gzip member holding [`MEMBER_BYTES`] of mostly-zero samples (a byte set every 2 KiB keeps the ratio
/// under deflate's bound), cut from a NRRD that warpbench's own writer compressed.
fn gzip_member(dir: &Path) -> Vec<u8> {
    let samples: Vec<u8> =
        (0..MEMBER_BYTES).map(|i| if i % 2048 == 0 { (i / 2048 % 251) as u8 + 1 } else { 0 }).collect();
    let v = Volume::new(
        Path::new("member"),
        [MEMBER_BYTES, 1, 1],
        VoxelData::U8(samples),
        Transform::identity(),
        GeometrySource::NrrdSpacings,
    )
    .expect("volume");
    let p = dir.join("member.nrrd");
    nrrd::write_with(&p, &v, NrrdWriteOptions { gzip: true }).expect("write");
    let bytes = std::fs::read(&p).expect("read");
    let start = bytes.windows(2).position(|w| w == b"\n\n").expect("the header's blank line") + 2;
    bytes[start..].to_vec()
}

#[test]
fn a_stream_that_inflates_past_the_address_space_is_exit_2_naming_the_file_and_size() {
    let dir = tempfile::tempdir().expect("tempdir");
    let member = gzip_member(dir.path());
    let path: PathBuf = dir.path().join("inflates.nrrd");
    let mut f = std::io::BufWriter::new(std::fs::File::create(&path).expect("create"));
    f.write_all(b"NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2000 1000 1000\nspacings: 1 1 1\nencoding: gzip\n\n")
        .expect("write");
    for _ in 0..HUGE_BYTES.div_ceil(MEMBER_BYTES as u64) {
        f.write_all(&member).expect("write");
    }
    drop(f);
    let len = std::fs::metadata(&path).expect("stat").len();
    assert!(len * 1032 > HUGE_BYTES, "{len} bytes: the compression-ratio bound would refuse it first");
    let out = info(&[path_arg(&path)]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("inflates.nrrd") && stderr.contains("not enough memory"), "{stderr}");
    assert!(stderr.contains("2000000000 bytes"), "{stderr}");
}

/// A NIfTI-1 file (little-endian, u8) with `dim` and `pixdim`, and the sform and qform given (codes 0 = unset).
fn nifti(dim: [i16; 8], pixdim: [f32; 8], sform: Option<[[f32; 4]; 3]>, qoffset: Option<[f32; 3]>) -> Vec<u8> {
    let mut h = vec![0u8; 352];
    h[0..4].copy_from_slice(&348i32.to_le_bytes());
    for i in 0..8 {
        h[40 + 2 * i..42 + 2 * i].copy_from_slice(&dim[i].to_le_bytes());
        h[76 + 4 * i..80 + 4 * i].copy_from_slice(&pixdim[i].to_le_bytes());
    }
    h[70..72].copy_from_slice(&2i16.to_le_bytes());
    h[72..74].copy_from_slice(&8i16.to_le_bytes());
    h[108..112].copy_from_slice(&352f32.to_le_bytes());
    h[112..116].copy_from_slice(&1f32.to_le_bytes());
    if let Some(q) = qoffset {
        h[252..254].copy_from_slice(&1i16.to_le_bytes());
        for (i, v) in q.iter().enumerate() {
            h[268 + 4 * i..272 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
    }
    if let Some(rows) = sform {
        h[254..256].copy_from_slice(&1i16.to_le_bytes());
        for (r, row) in rows.iter().enumerate() {
            for (c, v) in row.iter().enumerate() {
                h[280 + 16 * r + 4 * c..284 + 16 * r + 4 * c].copy_from_slice(&v.to_le_bytes());
            }
        }
    }
    h[344..348].copy_from_slice(b"n+1\0");
    let n: usize = dim[1..=dim[0] as usize].iter().map(|&d| d as usize).product();
    h.resize(352 + n, 0);
    h
}

#[test]
fn a_four_d_file_asks_for_the_frame_option() {
    let dir = tempfile::tempdir().expect("tempdir");
    let p = dir.path().join("four_d.nii");
    std::fs::write(&p, nifti([4, 2, 2, 2, 3, 1, 1, 1], [1.0; 8], None, None)).expect("write");
    let out = info(&[path_arg(&p)]);
    let stderr = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("four_d.nii") && stderr.contains("3 frames") && stderr.contains("--frame"), "{stderr}");
    assert!(!stderr.contains("LoadOptions"), "{stderr}");
    // And the option it names works.
    let out = info(&[path_arg(&p), "--frame", "2"]);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
}

#[test]
fn implausible_spacing_and_disagreeing_transforms_are_warnings_on_stderr_and_in_json() {
    let dir = tempfile::tempdir().expect("tempdir");
    let spaced = dir.path().join("spacing.nii");
    std::fs::write(&spaced, nifti([3, 2, 2, 2, 1, 1, 1, 1], [1.0, 1.0, 1.0, 2e4, 1.0, 1.0, 1.0, 1.0], None, None))
        .expect("write");
    let sform = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]];
    let apart = dir.path().join("apart.nii");
    std::fs::write(&apart, nifti([3, 2, 2, 2, 1, 1, 1, 1], [1.0; 8], Some(sform), Some([0.0, 40.0, 0.0])))
        .expect("write");
    for (p, needle) in [(&spaced, "implausible voxel spacing"), (&apart, "40.00 mm apart")] {
        let out = info(&[path_arg(p), "--json"]);
        let stderr = text(&out.stderr);
        assert_eq!(out.status.code(), Some(0), "{stderr}");
        assert!(stderr.contains("warning") && stderr.contains(needle), "{}: {stderr}", p.display());
        let doc: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
        let warnings = doc["warnings"].as_array().expect("warnings");
        assert!(warnings.iter().any(|w| w.as_str().is_some_and(|w| w.contains(needle))), "{warnings:?}");
    }
    // A plain volume: no warning anywhere.
    let plain = dir.path().join("plain.nii");
    std::fs::write(&plain, nifti([3, 2, 2, 2, 1, 1, 1, 1], [1.0; 8], Some(sform), Some([0.0; 3]))).expect("write");
    let out = info(&[path_arg(&plain), "--json"]);
    assert_eq!(out.status.code(), Some(0));
    assert!(text(&out.stderr).trim().is_empty(), "{}", text(&out.stderr));
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(doc["warnings"], serde_json::json!([]));
}
