//! The document: everything the user edits and a session keeps. The volumes' paths and looks, the landmark pairs,
//! and the warp and view settings.
//!
//! One value serves three purposes: the window's undo history snapshots it, a session file is it plus
//! the camera and the slice positions ([`super::session::SessionFile`]), and the autosave writes that file. Its serde
//! form is the session's (schema `warpbench-session/1`): the choices by name, the pairs as `landmarks` with
//! `moving_lps`/`fixed_lps`, each look's window as `window_low`/`window_high`; fields added later read their
//! defaults from files written before them.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use warpbench_gpu::{BlendMode, RenderSettings};
use warpbench_io::geometry::Point3;
use warpbench_io::landmarks::LandmarkPair;
use warpbench_io::{Part, Volume};
use warpbench_solver::brush::BrushStroke;
use warpbench_solver::bspline::BSplineParams;
use warpbench_solver::method::Method;
use warpbench_solver::spaces::{Fixed, Moving, as_fixed, as_moving};

use crate::procedural::ProceduralSpec;
use crate::settings::{Blend, MethodKind, Metric, Overlay, Preset, Probe, Shading, or_default};

/// What the user edits: the pair's paths and looks, the landmark pairs, the warp and view settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Document {
    /// `None` with `moving` `None`: the demo pair.
    pub fixed: Option<PathBuf>,
    pub moving: Option<PathBuf>,
    /// Which volume of `fixed` was read, when it holds several: a frame of a 4-D file, a series of a DICOM folder.
    /// Sessions written before it read the file whole.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fixed_part: Option<Part>,
    /// The same for `moving`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub moving_part: Option<Part>,
    /// LPS mm; the table's rows in order.
    #[serde(rename = "landmarks", with = "pairs_lps")]
    pub pairs: Vec<LandmarkPair>,
    pub settings: ViewSettings,
    /// Fixed, then moving.
    pub layers: [Look; 2],
    /// The displacement brush's strokes on top of the landmark warp, in the order they were made
    /// ([`warpbench_solver::brush`], [`crate::brushed`]).
    #[serde(default)]
    pub brush: Vec<BrushStroke>,
    /// The starting transform under the landmark warp (Auto-align, [`crate::start`]); `None`: the landmark warp alone.
    #[serde(default)]
    pub start: Option<StartingTransform>,
    /// A displacement field under the landmark warp (`--field`'s flavours: ITK or ANTs NIfTI, Slicer NRRD, and the
    /// others; a Learn2Reg field with its grids), read from this file ([`super::field_file::FieldFile::layer`]);
    /// `None`: none. Sessions written before it open without one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field: Option<super::field_file::FieldFile>,
    /// Where Refine by intensities reads the fixed volume: only where this mask volume is not 0 (`register
    /// --fixed-mask`); `None`: everywhere.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fixed_mask: Option<PathBuf>,
    /// The same for the moving volume (`register --moving-mask`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub moving_mask: Option<PathBuf>,
}

/// Where a volume is read from: its file or folder, and which of its volumes when it holds several (the session
/// keeps both).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VolumeSource {
    pub path: PathBuf,
    pub part: Option<Part>,
}

impl VolumeSource {
    /// The whole of `path`.
    #[must_use]
    pub fn whole(path: PathBuf) -> Self {
        Self { path, part: None }
    }

    /// The name the title and messages give it: the file name, and the frame, or the end of the series' UID.
    #[must_use]
    pub fn name(&self) -> String {
        let file =
            self.path.file_name().map_or_else(|| self.path.display().to_string(), |n| n.to_string_lossy().into());
        match &self.part {
            None => file,
            Some(Part::Frame(t)) => format!("{file} [frame {t}]"),
            Some(Part::Series(uid)) => {
                let tail = uid.rsplit('.').next().unwrap_or(uid);
                format!("{file} [series ...{tail}]")
            }
        }
    }
}

/// The fixed and the moving points of the pairs a fit uses, in the same order.
pub type FitPoints = (Vec<Point3<Fixed>>, Vec<Point3<Moving>>);

/// A starting transform as the document keeps it: T₀ = `moving_from_fixed` (fixed → moving, LPS mm) and what found it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StartingTransform {
    /// The rows of [L | t]: T₀(x) = L x + t.
    pub moving_from_fixed: [[f64; 4]; 3],
    /// How the window and the reports name it, e.g. `Auto-align (rigid)`.
    pub origin: String,
}

impl StartingTransform {
    /// The transform `moving_from_fixed` (L, t) named `origin`.
    #[must_use]
    pub fn new(linear: nalgebra::Matrix3<f64>, translation: [f64; 3], origin: String) -> Self {
        Self {
            moving_from_fixed: std::array::from_fn(|r| {
                [linear[(r, 0)], linear[(r, 1)], linear[(r, 2)], translation[r]]
            }),
            origin,
        }
    }

    /// As the fits take it.
    ///
    /// # Errors
    /// When it is not finite or not invertible (a hand-edited session).
    pub fn start(&self) -> anyhow::Result<crate::start::Start> {
        let m = &self.moving_from_fixed;
        let linear = nalgebra::Matrix3::from_fn(|r, c| m[r][c]);
        crate::start::Start::new(
            warpbench_solver::linear::AffineWarp::new(linear, [m[0][3], m[1][3], m[2][3]]),
            &self.origin,
        )
    }
}

impl Document {
    /// A document on the volumes read from `fixed` and `moving` (`None`: the demo pair) with `pairs`, the default
    /// settings and each volume's automatic look.
    #[must_use]
    pub fn new(paths: [Option<PathBuf>; 2], volumes: [&Volume; 2], pairs: Vec<LandmarkPair>) -> Self {
        let [fixed, moving] = paths;
        Self {
            fixed,
            moving,
            fixed_part: None,
            moving_part: None,
            pairs,
            settings: ViewSettings::default(),
            layers: volumes.map(Look::auto),
            brush: Vec::new(),
            start: None,
            field: None,
            fixed_mask: None,
            moving_mask: None,
        }
    }

    /// Rewrites every file path the document holds (the volumes, the field under the landmarks, the masks) by `f`:
    /// how a session stores them relative to its folder and reads them back ([`super::session`]).
    pub fn map_paths(&mut self, mut f: impl FnMut(&std::path::Path) -> PathBuf) {
        let paths = [&mut self.fixed, &mut self.moving, &mut self.fixed_mask, &mut self.moving_mask];
        for path in paths.into_iter().flatten().chain(self.field.as_mut().map(|field| &mut field.path)) {
            *path = f(path);
        }
    }

    /// Where the fixed and the moving volume were read from (`None`: the demo pair's).
    #[must_use]
    pub fn sources(&self) -> [Option<VolumeSource>; 2] {
        let source = |path: &Option<PathBuf>, part: &Option<Part>| {
            path.clone().map(|path| VolumeSource { path, part: part.clone() })
        };
        [source(&self.fixed, &self.fixed_part), source(&self.moving, &self.moving_part)]
    }

    /// The file of the displacement field under the landmarks, if there is one.
    #[must_use]
    pub fn field_path(&self) -> Option<&std::path::Path> {
        self.field.as_ref().map(|f| f.path.as_path())
    }

    /// The pairs a fit uses (active, both points placed): their rows, and their fixed and moving points.
    #[must_use]
    pub fn fit_pairs(&self) -> (Vec<usize>, FitPoints) {
        let used: Vec<usize> = (0..self.pairs.len())
            .filter(|&i| {
                let p = &self.pairs[i];
                p.active && p.moving.is_some() && p.fixed.is_some()
            })
            .collect();
        let points = used
            .iter()
            .filter_map(|&i| {
                let p = &self.pairs[i];
                Some((as_fixed(p.fixed?), as_moving(p.moving?)))
            })
            .unzip();
        (used, points)
    }

    /// Keeps what a hand-edited or older file may hold within what the window offers: the control texture's size,
    /// the oblique angles; a look whose window is empty or inverted takes the volume's automatic one.
    pub fn clamp(&mut self, volumes: [&Volume; 2]) {
        self.settings.clamp();
        for (look, v) in self.layers.iter_mut().zip(volumes) {
            if look.window_high.partial_cmp(&look.window_low) != Some(std::cmp::Ordering::Greater) {
                let auto = Look::auto(v);
                (look.window_low, look.window_high) = (auto.window_low, auto.window_high);
            }
        }
    }
}

/// One volume's look: its transfer function, its window (value range mapped onto the transfer function) and
/// whether it is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Look {
    #[serde(deserialize_with = "or_default")]
    pub preset: Preset,
    pub window_low: f32,
    pub window_high: f32,
    pub visible: bool,
}

impl Look {
    /// The look a volume opens with ([`crate::scene::auto_style`]: a CT or an MR preset from its values).
    #[must_use]
    pub fn auto(v: &Volume) -> Self {
        let (preset, window) = crate::scene::auto_style(v, None);
        Self::new(Preset::of(preset), window)
    }

    #[must_use]
    pub fn new(preset: Preset, window: warpbench_gpu::Window) -> Self {
        Self { preset, window_low: window.low(), window_high: window.low() + window.width, visible: true }
    }

    /// The renderer's window.
    #[must_use]
    pub fn window(&self) -> warpbench_gpu::Window {
        warpbench_gpu::Window::from_range(self.window_low, self.window_high)
    }
}

/// What the view and the warp look like.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ViewSettings {
    #[serde(deserialize_with = "or_default")]
    pub blend: Blend,
    pub mix_weight: f32,
    pub checker_mm: f32,
    #[serde(deserialize_with = "or_default")]
    pub shading: Shading,
    pub samples_per_voxel: f32,
    #[serde(deserialize_with = "or_default")]
    pub method: MethodKind,
    pub stiffness: f64,
    pub bspline_levels: usize,
    /// Control-texture texels per axis.
    #[serde(rename = "control_texels")]
    pub grid_n: usize,
    pub show_landmarks: bool,
    /// Per slice view (axial, coronal, sagittal): oblique, and its tilt (about the image's horizontal axis) and
    /// spin (about its vertical axis), degrees, around the crosshair.
    #[serde(default)]
    pub oblique: [Oblique; 3],
    /// How a click in the 3-D view finds its point.
    #[serde(default, deserialize_with = "or_default")]
    pub pick_probe: Probe,
    /// The probe's threshold: opacity (0..1), gradient magnitude (value units per mm) or accumulated opacity.
    #[serde(default = "default_pick_threshold")]
    pub pick_threshold: f32,
    /// A procedural deformation of the moving volume, computed in the shader ([`crate::procedural`]): a view of a
    /// known synthetic deformation (eval's), which the exports leave out.
    #[serde(default)]
    pub procedural: Option<ProceduralSpec>,
    /// The displacement brush's radius for new strokes, mm.
    #[serde(default = "default_brush_radius")]
    pub brush_radius_mm: f64,
    /// Centre the slices on the pair being edited (added, moved, selected); off, the views keep their place.
    #[serde(default)]
    pub follow_pair: bool,
    /// What the slices draw over their images to show the warp ([`crate::settings::Overlay`]).
    #[serde(default, deserialize_with = "or_default")]
    pub overlay: Overlay,
    /// What Refine by intensities matches the volumes by.
    #[serde(default, deserialize_with = "or_default")]
    pub refine_metric: Metric,
}

fn default_brush_radius() -> f64 {
    20.0
}

fn default_pick_threshold() -> f32 {
    Probe::default().default_threshold()
}

/// A slice view's oblique mode.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Oblique {
    pub on: bool,
    pub tilt_deg: f32,
    pub spin_deg: f32,
}

/// The largest brush radius the window offers, mm.
pub const BRUSH_MAX_RADIUS_MM: f64 = 80.0;

/// The largest procedural amplitude the window offers, mm.
pub const PROCEDURAL_MAX_MM: f64 = 40.0;

/// The oblique controls' range of tilt and spin, degrees.
pub const OBLIQUE_MAX_DEG: f32 = 75.0;

impl Default for ViewSettings {
    fn default() -> Self {
        Self {
            blend: Blend::Mix,
            mix_weight: 0.5,
            checker_mm: 16.0,
            shading: Shading::Dvr,
            samples_per_voxel: 1.0,
            method: MethodKind::Tps,
            stiffness: 0.0,
            bspline_levels: BSplineParams::default().levels,
            grid_n: 48,
            show_landmarks: true,
            oblique: [Oblique::default(); 3],
            pick_probe: Probe::Accumulated,
            pick_threshold: default_pick_threshold(),
            procedural: None,
            brush_radius_mm: default_brush_radius(),
            follow_pair: false,
            overlay: Overlay::None,
            refine_metric: Metric::Mi,
        }
    }
}

impl ViewSettings {
    #[must_use]
    pub fn blend_mode(&self) -> BlendMode {
        self.blend.mode(self.mix_weight, self.checker_mm)
    }

    #[must_use]
    pub fn render_settings(&self) -> RenderSettings {
        RenderSettings {
            blend: self.blend_mode(),
            samples_per_voxel: self.samples_per_voxel,
            shading: warpbench_gpu::Shading::with_mode(self.shading.mode()),
            ..Default::default()
        }
    }

    #[must_use]
    pub fn probe(&self) -> warpbench_gpu::Probe {
        self.pick_probe.with_threshold(self.pick_threshold)
    }

    #[must_use]
    pub fn method(&self) -> Method {
        self.method.method(self.stiffness, self.bspline_levels)
    }

    /// See [`Document::clamp`].
    pub fn clamp(&mut self) {
        self.grid_n = self.grid_n.clamp(2, 256);
        self.brush_radius_mm =
            if self.brush_radius_mm.is_finite() { self.brush_radius_mm.clamp(2.0, BRUSH_MAX_RADIUS_MM) } else { 20.0 };
        if let Some(p) = &mut self.procedural {
            p.amplitude_mm =
                if p.amplitude_mm.is_finite() { p.amplitude_mm.clamp(0.0, PROCEDURAL_MAX_MM) } else { 0.0 };
        }
        for o in &mut self.oblique {
            o.tilt_deg = o.tilt_deg.clamp(-OBLIQUE_MAX_DEG, OBLIQUE_MAX_DEG);
            o.spin_deg = o.spin_deg.clamp(-OBLIQUE_MAX_DEG, OBLIQUE_MAX_DEG);
        }
    }
}

/// The pairs as a session stores them: `{name, active, moving_lps, fixed_lps}` each.
mod pairs_lps {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};
    use warpbench_io::geometry::Point3;
    use warpbench_io::landmarks::LandmarkPair;

    #[derive(Serialize, Deserialize)]
    struct Wire {
        name: String,
        active: bool,
        moving_lps: Option<[f64; 3]>,
        fixed_lps: Option<[f64; 3]>,
    }

    pub fn serialize<S: Serializer>(pairs: &[LandmarkPair], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(pairs.iter().map(|p| Wire {
            name: p.name.clone(),
            active: p.active,
            moving_lps: p.moving.map(|m| m.coords()),
            fixed_lps: p.fixed.map(|f| f.coords()),
        }))
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<LandmarkPair>, D::Error> {
        let wire = Vec::<Wire>::deserialize(d)?;
        let finite = |p: Option<[f64; 3]>| p.is_none_or(|c| c.iter().all(|x| x.is_finite()));
        if let Some(i) = wire.iter().position(|w| !finite(w.moving_lps) || !finite(w.fixed_lps)) {
            return Err(serde::de::Error::custom(format!("landmark {} has a coordinate that is not a number", i + 1)));
        }
        Ok(wire
            .into_iter()
            .map(|w| LandmarkPair {
                name: w.name,
                active: w.active,
                moving: w.moving_lps.map(Point3::from_array),
                fixed: w.fixed_lps.map(Point3::from_array),
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_source_is_named_with_its_part() {
        let source = |part| VolumeSource { path: PathBuf::from("/data/bold.nii.gz"), part };
        assert_eq!(source(None).name(), "bold.nii.gz");
        assert_eq!(source(Some(Part::Frame(4))).name(), "bold.nii.gz [frame 4]");
        assert_eq!(source(Some(Part::Series("1.2.840.113619.42".into()))).name(), "bold.nii.gz [series ...42]");
    }
}
