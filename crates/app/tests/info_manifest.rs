//! `warpbench info --json` against the fixture manifest written by independent readers
//! (nibabel, pydicom, pynrrd; see `data-scripts/manifest.py` and `docs/fixture-manifest.md`).
//!
//! Geometry must agree to 1e-4 mm and voxel checksums exactly. Every fixture is checked and all
//! disagreements are reported together.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

/// Geometry tolerance from the issue: 1e-4 mm on every matrix entry.
const GEOMETRY_TOL_MM: f64 = 1e-4;

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data")
}

fn manifest() -> Value {
    let path = data_dir().join("manifest.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_str(&text).expect("manifest.json is valid JSON")
}

struct Run {
    code: Option<i32>,
    stdout: String,
    stderr: String,
}

fn info(fixture: &Value) -> Run {
    let path = data_dir().join(fixture["path"].as_str().expect("fixture path"));
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_warpbench"));
    cmd.arg("info").arg("--json").arg("--quiet").arg(&path);
    if let Some(t) = fixture["options"]["frame"].as_u64() {
        cmd.arg("--frame").arg(t.to_string());
    }
    if let Some(uid) = fixture["options"]["series_instance_uid"].as_str() {
        cmd.arg("--series").arg(uid);
    }
    let out = cmd.output().expect("run warpbench");
    Run {
        code: out.status.code(),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

fn as_f64s(v: &Value) -> Vec<f64> {
    match v {
        Value::Array(a) => a.iter().flat_map(as_f64s).collect(),
        Value::Number(n) => vec![n.as_f64().expect("number")],
        _ => vec![],
    }
}

/// Compares one fixture; returns the list of disagreements.
fn check(fixture: &Value) -> Vec<String> {
    let mut bad = Vec::new();
    let run = info(fixture);
    let expect_error = fixture["expect"].as_str() == Some("error");

    if let Some(series) = fixture["series"].as_array() {
        // A folder holding several series: info lists them instead of loading one.
        if run.code != Some(0) {
            return vec![format!("exit {:?} listing series: {}", run.code, run.stderr)];
        }
        let got: Value = serde_json::from_str(&run.stdout).expect("info JSON");
        let mut uids: Vec<&str> = got["series"]
            .as_array()
            .map(|a| a.iter().filter_map(|s| s["series_instance_uid"].as_str()).collect())
            .unwrap_or_default();
        let mut want: Vec<&str> = series.iter().filter_map(Value::as_str).collect();
        uids.sort_unstable();
        want.sort_unstable();
        if got["kind"] != "series_list" || uids != want {
            bad.push(format!("series list {uids:?}, expected {want:?}"));
        }
        return bad;
    }

    if expect_error {
        let needle = fixture["error_contains"].as_str().unwrap_or("");
        let msg = run.stderr.to_lowercase();
        if run.code != Some(2) {
            bad.push(format!("expected exit code 2, got {:?} (stderr: {})", run.code, run.stderr.trim()));
        }
        if !msg.contains(needle) {
            bad.push(format!("error message lacks {needle:?}: {}", run.stderr.trim()));
        }
        let file =
            Path::new(fixture["path"].as_str().unwrap_or("")).file_name().map(|f| f.to_string_lossy().into_owned());
        if let Some(file) = file
            && !run.stderr.contains(&file)
        {
            bad.push(format!("error message does not name {file}: {}", run.stderr.trim()));
        }
        return bad;
    }

    if run.code != Some(0) {
        return vec![format!("exit {:?}: {}", run.code, run.stderr.trim())];
    }
    let got: Value = serde_json::from_str(&run.stdout).expect("info JSON");
    if got["dims"] != fixture["dims"] {
        bad.push(format!("dims {} != {}", got["dims"], fixture["dims"]));
    }
    let (m_got, m_want) = (as_f64s(&got["lps_from_index"]), as_f64s(&fixture["lps_from_index"]));
    let worst = m_got.iter().zip(&m_want).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    if m_got.len() != 16 || m_want.len() != 16 || worst > GEOMETRY_TOL_MM {
        bad.push(format!("lps_from_index off by {worst:e} mm:\n  got  {m_got:?}\n  want {m_want:?}"));
    }
    if got["geometry_source"]["kind"] != fixture["geometry_source"] {
        bad.push(format!("geometry source {} != {}", got["geometry_source"]["kind"], fixture["geometry_source"]));
    }
    if got["dtype"] != fixture["dtype"] {
        bad.push(format!("dtype {} != {}", got["dtype"], fixture["dtype"]));
    }
    let exact = fixture["checksum_exact"].as_bool().unwrap_or(true);
    if exact && got["voxel_sha256"] != fixture["sha256"] {
        bad.push(format!("voxel sha256 {} != {}", got["voxel_sha256"], fixture["sha256"]));
    }
    let (r_got, r_want) = (as_f64s(&got["value_range"]), as_f64s(&fixture["value_range"]));
    let range_tol = if exact { 1e-6 } else { fixture["max_abs_diff"].as_f64().unwrap_or(0.0) };
    if r_got.len() != 2 || r_got.iter().zip(&r_want).any(|(a, b)| (a - b).abs() > range_tol * (1.0 + b.abs())) {
        bad.push(format!("value range {r_got:?} != {r_want:?}"));
    }
    if !fixture["modality"].is_null() && got["modality"] != fixture["modality"] {
        bad.push(format!("modality {} != {}", got["modality"], fixture["modality"]));
    }
    bad
}

#[test]
fn info_json_agrees_with_independent_readers_on_every_fixture() {
    let manifest = manifest();
    let fixtures = manifest["fixtures"].as_array().expect("fixtures array");
    assert!(fixtures.len() >= 20, "the manifest lists only {} fixtures", fixtures.len());
    let mut failures = Vec::new();
    for f in fixtures {
        let id = f["id"].as_str().unwrap_or("?");
        let bad = check(f);
        if bad.is_empty() {
            eprintln!("ok   {id}");
        } else {
            eprintln!("FAIL {id}");
            failures.push(format!("{id} ({}):\n  {}", f["path"], bad.join("\n  ")));
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} fixtures disagree:\n{}",
        failures.len(),
        fixtures.len(),
        failures.join("\n")
    );
}
