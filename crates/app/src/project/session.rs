//! Sessions: `.warpbench.json` project files (schema `warpbench-session/1`): the [`Document`] (the input paths, the
//! landmark pairs, the warp and view settings, each volume's look) and the [`View`] (the camera, the slice
//! positions, the layout and the named views); and where the autosave that keeps every placed landmark across a
//! crash goes.
//!
//! The window autosaves every 30 s and on exit to [`autosave_path`], with `clean_exit` false while it runs and true
//! after a normal exit. A start that finds an autosave with `clean_exit` false offers to recover it. Every file is
//! written atomically (temporary file, then rename), so a crash never leaves half a session.

use std::path::{Path, PathBuf};

use anyhow::{Context as _, bail};
use serde::{Deserialize, Serialize};

use super::document::Document;

/// The schema name written into every session file; a file with another one is refused.
pub const SCHEMA: &str = "warpbench-session/1";

/// The camera: orbit angles in degrees, zoom, the point it looks at (ref mm) and its shift in the view plane.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionCamera {
    pub azimuth_deg: f32,
    pub elevation_deg: f32,
    pub zoom: f32,
    pub target_lps: [f32; 3],
    /// The target's shift in the view plane (right, up), mm; sessions written before it have none.
    #[serde(default)]
    pub pan_mm: [f32; 2],
}

/// Where the views look: not part of the document (undo leaves it), but kept by a session.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct View {
    pub camera: SessionCamera,
    /// Axial (S), coronal (P) and sagittal (L) slice positions, mm.
    pub slice_mm: [f64; 3],
    /// How the views share the window; sessions written before it open four-up.
    #[serde(default, deserialize_with = "crate::settings::or_default")]
    pub layout: crate::settings::Layout,
    /// The views the user named ("Save view"), in the order they were saved.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub named_views: Vec<NamedView>,
}

/// From the front, at zoom 1, onto the origin, unshifted.
impl Default for SessionCamera {
    fn default() -> Self {
        Self { azimuth_deg: 0.0, elevation_deg: 0.0, zoom: 1.0, target_lps: [0.0; 3], pan_mm: [0.0; 2] }
    }
}

/// The default camera, the slices through the origin, four-up, no named views.
impl Default for View {
    fn default() -> Self {
        Self {
            camera: SessionCamera::default(),
            slice_mm: [0.0; 3],
            layout: crate::settings::Layout::FourUp,
            named_views: Vec::new(),
        }
    }
}

/// A view the user named: the camera and the slices as they were when it was saved.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NamedView {
    pub name: String,
    pub camera: SessionCamera,
    pub slice_mm: [f64; 3],
}

/// A whole session: the document and the view, flat in one JSON object.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SessionFile {
    pub schema: String,
    #[serde(flatten)]
    pub document: Document,
    #[serde(flatten)]
    pub view: View,
    /// False while the window that wrote it runs (an autosave); true after a normal exit or for a saved project.
    pub clean_exit: bool,
}

impl SessionFile {
    #[must_use]
    pub fn new(document: Document, view: View, clean_exit: bool) -> Self {
        Self { schema: SCHEMA.to_owned(), document, view, clean_exit }
    }
}

/// Writes `session` to `path` atomically, as pretty JSON. A file the document names inside `path`'s folder (or
/// below it) is stored relative to that folder, so that a project folder moved or shared whole keeps its files; any
/// other is stored absolute (one given relative to the current folder included).
pub fn save(path: &Path, session: &SessionFile) -> anyhow::Result<()> {
    let folder = session_folder(path);
    let mut stored = session.clone();
    stored.document.map_paths(|p| {
        let absolute = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
        match absolute.strip_prefix(&folder) {
            Ok(inside) if !inside.as_os_str().is_empty() => inside.to_path_buf(),
            _ => absolute,
        }
    });
    let text = serde_json::to_string_pretty(&stored).context("encoding the session")?;
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
    let mut session: SessionFile =
        serde_json::from_value(value).with_context(|| format!("{}: malformed session", path.display()))?;
    // Relative paths are the session folder's ([`save`]); a session written before that kept them relative to the
    // folder the window ran in, which is taken where the session's folder has no such file.
    let folder = session_folder(path);
    session.document.map_paths(|p| {
        let inside = folder.join(p);
        if p.is_absolute() || inside.exists() || !p.exists() { inside } else { p.to_path_buf() }
    });
    let view = &mut session.view;
    for camera in std::iter::once(&mut view.camera).chain(view.named_views.iter_mut().map(|v| &mut v.camera)) {
        camera.zoom = camera.zoom.clamp(0.2, 20.0);
    }
    Ok(session)
}

/// The folder of the session file at `path`, absolute (the current folder for a bare file name).
fn session_folder(path: &Path) -> PathBuf {
    let folder = path.parent().filter(|f| !f.as_os_str().is_empty()).unwrap_or_else(|| Path::new("."));
    std::path::absolute(folder).unwrap_or_else(|_| folder.to_path_buf())
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
    use crate::project::document::{Look, Oblique};
    use crate::settings::{Blend, MethodKind, Preset, Probe};
    use warpbench_io::geometry::Point3;
    use warpbench_io::landmarks::LandmarkPair;

    /// A document with something other than a default in every field.
    fn document() -> Document {
        let volume = crate::project::demo::phantom(8, 2.0, [0.0; 3], true);
        let mut d = Document::new(
            [Some(PathBuf::from("/data/ct.nii.gz")), Some(PathBuf::from("/data/mr dir"))],
            [&volume, &volume],
            vec![
                LandmarkPair::new("nasion", Point3::new(1.0, -2.5, 3.25), Point3::new(0.0, 4.0, -1e-3)),
                LandmarkPair {
                    active: false,
                    fixed: None,
                    ..LandmarkPair::new("half", Point3::new(9.0, 8.0, 7.0), Point3::new(0.0, 0.0, 0.0))
                },
            ],
        );
        let s = &mut d.settings;
        (s.blend, s.mix_weight, s.checker_mm, s.samples_per_voxel) = (Blend::Checkerboard, 0.3, 7.5, 2.0);
        (s.method, s.stiffness, s.bspline_levels, s.grid_n) = (MethodKind::BSpline, 1.5, 3, 33);
        (s.show_landmarks, s.pick_probe, s.pick_threshold) = (false, Probe::Gradient, 120.0);
        s.shading = crate::settings::Shading::Iso;
        s.oblique[2] = Oblique { on: true, tilt_deg: 12.5, spin_deg: -30.0 };
        s.procedural = Some(crate::procedural::ProceduralSpec {
            kind: crate::settings::ProceduralKind::Bend,
            amplitude_mm: 7.5,
            seed: 42,
        });
        d.layers[1] = Look { preset: Preset::CtSoftTissue, window_low: -100.0, window_high: 300.0, visible: false };
        d.start = Some(crate::project::document::StartingTransform {
            moving_from_fixed: [[0.9, -0.1, 0.05, 12.5], [0.1, 0.99, 0.0, -3.0], [0.0, 0.02, 1.01, 7.25]],
            origin: "Auto-align (rigid)".into(),
        });
        d.fixed_part = Some(warpbench_io::Part::Frame(2));
        d.moving_part = Some(warpbench_io::Part::Series("1.2.840.10008.42".into()));
        d
    }

    fn view() -> View {
        let camera = SessionCamera {
            azimuth_deg: 30.0,
            elevation_deg: 10.0,
            zoom: 1.5,
            target_lps: [1.0, 2.0, 3.0],
            pan_mm: [-2.5, 4.0],
        };
        let named = NamedView {
            name: "Tumour, from above".into(),
            camera: SessionCamera { azimuth_deg: -90.0, elevation_deg: 80.0, ..camera.clone() },
            slice_mm: [0.5, 1.5, -2.5],
        };
        View { camera, slice_mm: [4.0, -5.0, 6.0], layout: crate::settings::Layout::Slices, named_views: vec![named] }
    }

    #[test]
    fn a_saved_session_opens_equal() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("s.warpbench.json");
        let file = SessionFile::new(document(), view(), true);
        save(&path, &file).expect("save");
        assert_eq!(load(&path).expect("load"), file);
        // Which volume of each file, in the words docs/formats.md gives.
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("json");
        assert_eq!(json["fixed_part"], serde_json::json!({"frame": 2}));
        assert_eq!(json["moving_part"], serde_json::json!({"series": "1.2.840.10008.42"}));
    }

    #[test]
    fn refuses_other_schemas_bad_json_and_nan_landmarks_naming_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("s.warpbench.json");
        std::fs::write(&path, "{\"schema\": \"warpbench-session/99\"}").expect("write");
        let err = format!("{:#}", load(&path).expect_err("schema"));
        assert!(err.contains("s.warpbench.json") && err.contains("warpbench-session/99"), "{err}");
        std::fs::write(&path, "not json").expect("write");
        assert!(format!("{:#}", load(&path).expect_err("json")).contains("not a JSON session"));
        let text = serde_json::to_string(&SessionFile::new(document(), view(), true)).expect("json");
        // The second pair's moving point is (9, 8, 7).
        assert!(text.contains("[9.0,8.0,7.0]"), "{text}");
        std::fs::write(&path, text.replacen("[9.0,8.0,7.0]", "[1e999,8.0,7.0]", 1)).expect("write");
        // Out of range for f64: refused as malformed or as not a number, never read as infinity.
        assert!(load(&path).is_err());
    }

    /// A session as this version wrote it before the probe was kept and before oblique slices: every key it had,
    /// with the names it used.
    const OLDER: &str = r#"{
        "schema": "warpbench-session/1", "fixed": "/data/ct.nii.gz", "moving": null,
        "landmarks": [{"name": "a", "active": true, "moving_lps": [1.0, 2.0, 3.0], "fixed_lps": null}],
        "settings": {"blend": "red-cyan", "mix_weight": 0.5, "checker_mm": 16.0, "shading": "iso",
                     "samples_per_voxel": 1.0, "method": "similarity", "stiffness": 0.0, "bspline_levels": 4,
                     "control_texels": 999, "show_landmarks": true},
        "layers": [{"preset": "mr-t1", "window_low": 0.0, "window_high": 100.0, "visible": true},
                   {"preset": "no-such-preset", "window_low": 5.0, "window_high": 6.0, "visible": false}],
        "camera": {"azimuth_deg": 30.0, "elevation_deg": 10.0, "zoom": 100.0, "target_lps": [0.0, 0.0, 0.0]},
        "slice_mm": [1.0, 2.0, 3.0], "clean_exit": false
    }"#;

    #[test]
    fn older_files_open_with_straight_slices_the_default_probe_no_deformation_and_known_names() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("s.warpbench.json");
        std::fs::write(&path, OLDER).expect("write");
        let file = load(&path).expect("an older file");
        let d = &file.document;
        assert_eq!((d.fixed.as_deref(), d.moving.as_deref()), (Some(std::path::Path::new("/data/ct.nii.gz")), None));
        assert!(d.field.is_none(), "no displacement field before there was one");
        assert_eq!((&d.fixed_part, &d.moving_part), (&None, &None), "each file read whole before parts were kept");
        assert_eq!(file.view.layout, crate::settings::Layout::FourUp, "four-up before there were layouts");
        assert_eq!(
            d.pairs,
            [LandmarkPair {
                fixed: None,
                ..LandmarkPair::new("a", Point3::new(1.0, 2.0, 3.0), Point3::new(0.0, 0.0, 0.0))
            }]
        );
        let s = &d.settings;
        assert_eq!(
            (s.blend, s.shading, s.method),
            (Blend::RedCyan, crate::settings::Shading::Iso, MethodKind::Similarity)
        );
        assert_eq!(s.oblique, [Oblique::default(); 3]);
        assert_eq!((s.pick_probe, s.pick_threshold), (Probe::Accumulated, 0.95));
        assert_eq!(s.procedural, None, "no procedural deformation");
        assert_eq!(
            (d.layers[0].preset, d.layers[1].preset),
            (Preset::MrT1, Preset::default()),
            "an unknown name reads as the default"
        );
        assert!(!d.layers[1].visible && !file.clean_exit);
        assert!((file.view.camera.zoom - 20.0).abs() < 1e-6, "the zoom is clamped to what the window offers");
        assert!(file.view.camera.pan_mm.iter().all(|&v| v == 0.0), "no shift before it was saved");
        assert!(file.view.named_views.is_empty(), "no named views before there were any");
        // What the window offers: the control texture is clamped when the document is opened on its volumes.
        let volume = crate::project::demo::phantom(4, 1.0, [0.0; 3], false);
        let mut d = d.clone();
        d.clamp([&volume, &volume]);
        assert_eq!(d.settings.grid_n, 256);
        // Saved again, it keeps every key it had, with the same names.
        let again = serde_json::to_value(&file).expect("json");
        let older: serde_json::Value = serde_json::from_str(OLDER).expect("json");
        for key in older.as_object().expect("object").keys() {
            assert!(again.get(key).is_some(), "{key}");
        }
        for key in older["settings"].as_object().expect("object").keys() {
            assert!(again["settings"].get(key).is_some(), "settings.{key}");
        }
        assert_eq!(again["settings"]["method"], "similarity");
        assert_eq!(again["landmarks"][0]["moving_lps"], serde_json::json!([1.0, 2.0, 3.0]));
    }

    /// Files inside the session's folder are stored relative to it, so the folder moved whole opens with its files;
    /// files elsewhere are stored absolute; a session written before (a path relative to the folder the window ran
    /// in) still opens where only that file exists.
    #[test]
    fn paths_inside_the_session_folder_travel_with_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let project = dir.path().join("project");
        std::fs::create_dir_all(project.join("data")).expect("mkdir");
        for name in ["data/ct.nii.gz", "data/field.nii.gz", "mask.nii.gz"] {
            std::fs::write(project.join(name), b"x").expect("write");
        }
        let elsewhere = dir.path().join("mr.nii.gz");
        let mut file = SessionFile::new(document(), View::default(), true);
        let d = &mut file.document;
        (d.fixed, d.moving) = (Some(project.join("data/ct.nii.gz")), Some(elsewhere.clone()));
        d.fixed_mask = Some(project.join("mask.nii.gz"));
        d.field = Some(super::super::field_file::FieldFile::new(project.join("data/field.nii.gz")));
        let path = project.join("case.warpbench.json");
        save(&path, &file).expect("save");
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("read")).expect("json");
        assert_eq!(json["fixed"], "data/ct.nii.gz");
        assert_eq!(json["fixed_mask"], "mask.nii.gz");
        assert_eq!(json["field"], "data/field.nii.gz");
        assert_eq!(json["moving"], elsewhere.to_str().expect("utf-8"), "outside the folder: absolute");
        assert_eq!(load(&path).expect("load").document, file.document, "read back as they were");
        // The folder moved whole: its files follow it; the file outside stays where it was.
        let moved = dir.path().join("moved");
        std::fs::rename(&project, &moved).expect("move");
        let opened = load(&moved.join("case.warpbench.json")).expect("load").document;
        assert_eq!(opened.fixed, Some(moved.join("data/ct.nii.gz")));
        assert_eq!(opened.field.map(|f| f.path), Some(moved.join("data/field.nii.gz")));
        assert_eq!(opened.fixed_mask, Some(moved.join("mask.nii.gz")));
        assert_eq!(opened.moving, Some(elsewhere));
        // An older session's path relative to the current folder, where the session's folder has no such file.
        let mut older = json.clone();
        older["fixed"] = "Cargo.toml".into();
        let older_path = moved.join("older.warpbench.json");
        std::fs::write(&older_path, older.to_string()).expect("write");
        assert_eq!(load(&older_path).expect("load").document.fixed, Some(PathBuf::from("Cargo.toml")));
        // A relative path is the session folder's where both exist.
        std::fs::write(moved.join("Cargo.toml"), b"x").expect("write");
        assert_eq!(load(&older_path).expect("load").document.fixed, Some(moved.join("Cargo.toml")));
    }
}
