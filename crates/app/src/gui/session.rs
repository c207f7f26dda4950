//! Sessions: `.warpbench.json` project files (schema `warpbench-session/1`) with the input paths, the landmark pairs,
//! the warp and view settings, each volume's look, the camera and the slice positions; and the autosave that keeps
//! every placed landmark across a crash.
//!
//! The window autosaves every 30 s and on exit to [`autosave_path`], with `clean_exit` false while it runs and true
//! after a normal exit. A start that finds an autosave with `clean_exit` false offers to recover it. Every file is
//! written atomically (temporary file, then rename), so a crash never leaves half a session.

use std::path::{Path, PathBuf};

use anyhow::{Context as _, anyhow, bail};
use serde::{Deserialize, Serialize};
use warpbench_io::geometry::Point3;
use warpbench_io::landmarks::LandmarkPair;

/// The schema name written into every session file; a file with another one is refused.
pub const SCHEMA: &str = "warpbench-session/1";

/// One pair, LPS mm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionPair {
    pub name: String,
    pub active: bool,
    pub moving_lps: Option<[f64; 3]>,
    pub fixed_lps: Option<[f64; 3]>,
}

impl SessionPair {
    #[must_use]
    pub fn from_pair(p: &LandmarkPair) -> Self {
        Self {
            name: p.name.clone(),
            active: p.active,
            moving_lps: p.moving.map(|m| m.coords()),
            fixed_lps: p.fixed.map(|f| f.coords()),
        }
    }

    #[must_use]
    pub fn to_pair(&self) -> LandmarkPair {
        LandmarkPair {
            name: self.name.clone(),
            active: self.active,
            moving: self.moving_lps.map(Point3::from_array),
            fixed: self.fixed_lps.map(Point3::from_array),
        }
    }
}

/// The view and warp settings, by name (stable across versions of the menus).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionSettings {
    pub blend: String,
    pub mix_weight: f32,
    pub checker_mm: f32,
    pub shading: String,
    pub samples_per_voxel: f32,
    pub method: String,
    pub stiffness: f64,
    pub bspline_levels: usize,
    pub control_texels: usize,
    pub show_landmarks: bool,
    /// Per slice view (axial, coronal, sagittal): oblique or not, tilt and spin in degrees. Optional: files written
    /// before it existed open with straight slices.
    #[serde(default)]
    pub oblique: [SessionOblique; 3],
}

/// A slice view's oblique mode.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SessionOblique {
    pub on: bool,
    pub tilt_deg: f32,
    pub spin_deg: f32,
}

/// One volume's look.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionLayer {
    pub preset: String,
    pub window_low: f32,
    pub window_high: f32,
    pub visible: bool,
}

/// The camera: orbit angles in degrees, zoom, and the point it looks at (ref mm).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionCamera {
    pub azimuth_deg: f32,
    pub elevation_deg: f32,
    pub zoom: f32,
    pub target_lps: [f32; 3],
}

/// A whole session.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionFile {
    pub schema: String,
    /// `None` with `moving` `None`: the demo pair.
    pub fixed: Option<PathBuf>,
    pub moving: Option<PathBuf>,
    pub landmarks: Vec<SessionPair>,
    pub settings: SessionSettings,
    /// Fixed, then moving.
    pub layers: [SessionLayer; 2],
    pub camera: SessionCamera,
    /// Axial (S), coronal (P) and sagittal (L) slice positions, mm.
    pub slice_mm: [f64; 3],
    /// False while the window that wrote it runs (an autosave); true after a normal exit or for a saved project.
    pub clean_exit: bool,
}

/// Writes `session` to `path` atomically, as pretty JSON.
pub fn save(path: &Path, session: &SessionFile) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(session).context("encoding the session")?;
    warpbench_io::atomic::write_atomic(path, |out| out.write_all(text.as_bytes()))?;
    Ok(())
}

/// Reads a session file; errors name the file and the problem.
pub fn load(path: &Path) -> anyhow::Result<SessionFile> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}: cannot read the session", path.display()))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).with_context(|| format!("{}: not a JSON session file", path.display()))?;
    match value.get("schema").and_then(serde_json::Value::as_str) {
        Some(SCHEMA) => {}
        Some(other) => bail!("{}: session schema {other:?}; this version reads {SCHEMA:?}", path.display()),
        None => bail!("{}: no \"schema\": not a warpbench session", path.display()),
    }
    let session: SessionFile =
        serde_json::from_value(value).with_context(|| format!("{}: malformed session", path.display()))?;
    let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
    if let Some(i) = session
        .landmarks
        .iter()
        .position(|p| !p.moving_lps.is_none_or(|m| finite(&m)) || !p.fixed_lps.is_none_or(|f| finite(&f)))
    {
        return Err(anyhow!("{}: landmark {} has a coordinate that is not a number", path.display(), i + 1));
    }
    Ok(session)
}

/// Where the window autosaves: `$WARPBENCH_STATE_DIR`, else `$XDG_STATE_HOME/warpbench`, else
/// `~/.local/state/warpbench`, then `autosave.warpbench.json`.
#[must_use]
pub fn autosave_path() -> PathBuf {
    let dir = std::env::var_os("WARPBENCH_STATE_DIR").map_or_else(
        || {
            std::env::var_os("XDG_STATE_HOME")
                .map(PathBuf::from)
                .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/state")))
                .unwrap_or_else(std::env::temp_dir)
                .join("warpbench")
        },
        PathBuf::from,
    );
    dir.join("autosave.warpbench.json")
}

/// Writes `session` to `path`, creating its folder (the autosave).
pub fn save_creating_folder(path: &Path, session: &SessionFile) -> anyhow::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the folder", dir.display()))?;
    }
    save(path, session)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refuses_other_schemas_bad_json_and_nan_landmarks_naming_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("s.warpbench.json");
        std::fs::write(&path, "{\"schema\": \"warpbench-session/99\"}").expect("write");
        let err = format!("{:#}", load(&path).expect_err("schema"));
        assert!(err.contains("s.warpbench.json") && err.contains("warpbench-session/99"), "{err}");
        std::fs::write(&path, "not json").expect("write");
        assert!(format!("{:#}", load(&path).expect_err("json")).contains("not a JSON session"));
        let pair =
            SessionPair { name: "a".into(), active: true, moving_lps: Some([f64::NAN, 0.0, 0.0]), fixed_lps: None };
        let mut v = serde_json::json!({"schema": SCHEMA});
        v["landmarks"] = serde_json::to_value([&pair]).expect("pair");
        std::fs::write(&path, v.to_string()).expect("write");
        // NaN is not valid JSON (serde writes null), so the pair is refused as malformed or non-finite.
        assert!(load(&path).is_err());
    }

    #[test]
    fn oblique_slices_round_trip_and_older_files_open_with_straight_slices() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("s.warpbench.json");
        let layer = SessionLayer { preset: "mr-t1".into(), window_low: 0.0, window_high: 100.0, visible: true };
        let mut file = SessionFile {
            schema: SCHEMA.into(),
            fixed: None,
            moving: None,
            landmarks: Vec::new(),
            settings: SessionSettings {
                blend: "mix".into(),
                mix_weight: 0.5,
                checker_mm: 16.0,
                shading: "dvr".into(),
                samples_per_voxel: 1.0,
                method: "tps".into(),
                stiffness: 0.0,
                bspline_levels: 4,
                control_texels: 48,
                show_landmarks: true,
                oblique: [SessionOblique::default(); 3],
            },
            layers: [layer.clone(), layer],
            camera: SessionCamera { azimuth_deg: 30.0, elevation_deg: 10.0, zoom: 1.0, target_lps: [0.0; 3] },
            slice_mm: [0.0; 3],
            clean_exit: true,
        };
        file.settings.oblique[2] = SessionOblique { on: true, tilt_deg: 12.5, spin_deg: -30.0 };
        save(&path, &file).expect("save");
        assert_eq!(load(&path).expect("load"), file);
        // A file from before oblique slices: no `oblique` key.
        let mut v: serde_json::Value = serde_json::to_value(&file).expect("json");
        v["settings"].as_object_mut().expect("settings").remove("oblique");
        std::fs::write(&path, v.to_string()).expect("write");
        assert_eq!(load(&path).expect("older file").settings.oblique, [SessionOblique::default(); 3]);
    }
}
