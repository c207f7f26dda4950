//! The workbench window (eframe/egui): the fixed and the deformed moving volume in a 3-D view and three slice views
//! of the fixed grid, rendered by `warpbench_gpu` on eframe's own wgpu device, with the landmark glyphs, the warp
//! method and the view settings in a side panel.
//!
//! Bare `warpbench` opens the demo pair ([`demo`]). Loading runs on a worker thread; the window stays responsive
//! and shows an error (naming the file) instead of the views when it fails. Frames are rendered only when something
//! changed, at the interaction sample rate while the camera is being dragged ([`warpbench_gpu::Quality`]).

pub mod demo;
pub mod history;
pub mod panels;
pub mod session;
pub mod viewer;

use std::path::PathBuf;
use std::sync::mpsc::{Receiver, TryRecvError};

use anyhow::{Context as _, anyhow};
use eframe::egui;
use warpbench_gpu::PickTarget;
use warpbench_gpu::glam::Vec3;
use warpbench_gpu::{
    GlyphInstance, GlyphPair, GlyphStyle, OrbitCamera, PreparedControl, Projection, Quality, SlicePlane, pair_glyphs,
};
use warpbench_io::Volume;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_io::landmarks::LandmarkPair;
use warpbench_solver::diagnostics::{jacobian_determinants, leave_one_out, residuals};
use warpbench_solver::spaces::{Fixed, Moving, as_fixed, as_moving};
use warpbench_solver::warp::{Parallelism, Warp};

use crate::inputs::{self, LandmarkSource};
use crate::scene;
use history::{History, LayerLook, Snapshot};
use panels::ViewSettings;
use viewer::{Shown, Viewer};

/// What the window opens with.
#[derive(Clone, Debug, Default)]
pub struct GuiOptions {
    /// `None` (with `moving` `None`): the demo pair.
    pub fixed: Option<PathBuf>,
    pub moving: Option<PathBuf>,
    pub landmarks: Option<LandmarkSource>,
    /// Save a screenshot of the window here after `exit_after_frames` frames with the pair shown, then close.
    pub screenshot: Option<PathBuf>,
    pub exit_after_frames: Option<u32>,
    /// A `.warpbench.json` session to open (its volumes, landmarks and settings); overrides the fields above.
    pub session: Option<PathBuf>,
    /// Where to autosave (`None`: [`session::autosave_path`]).
    pub autosave: Option<PathBuf>,
}

/// The loaded inputs, before they reach the GPU.
#[derive(Debug)]
pub struct Loaded {
    pub fixed: Volume,
    pub moving: Volume,
    pub pairs: Vec<LandmarkPair>,
    /// e.g. "cranium_ct.nii.gz -> ch2.nii.gz (demo)".
    pub title: String,
    /// The input paths (`None` for the demo pair), for sessions.
    pub fixed_path: Option<PathBuf>,
    pub moving_path: Option<PathBuf>,
    /// The session whose settings apply once the pair is shown.
    pub session: Option<session::SessionFile>,
}

/// Loads what `opts` names: a session, two volumes (with landmarks), or the demo pair when it names nothing.
pub fn load(opts: &GuiOptions) -> anyhow::Result<Loaded> {
    let name =
        |p: &std::path::Path| p.file_name().map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into());
    if let Some(path) = &opts.session {
        let file = session::load(path)?;
        let mut loaded =
            load(&GuiOptions { fixed: file.fixed.clone(), moving: file.moving.clone(), ..GuiOptions::default() })?;
        loaded.pairs = file.landmarks.iter().map(session::SessionPair::to_pair).collect();
        loaded.title = format!("{} ({})", loaded.title, name(path));
        loaded.session = Some(file);
        return Ok(loaded);
    }
    match (&opts.fixed, &opts.moving) {
        (Some(f), Some(m)) => {
            let fixed = warpbench_io::open(f)?;
            let moving = warpbench_io::open(m)?;
            let pairs = match &opts.landmarks {
                Some(source) => source.read().map_err(|e| anyhow!("{:#}", e.error()))?,
                None => Vec::new(),
            };
            Ok(Loaded {
                title: format!("{} -> {}", name(f), name(m)),
                fixed,
                moving,
                pairs,
                fixed_path: Some(f.clone()),
                moving_path: Some(m.clone()),
                session: None,
            })
        }
        (None, None) => {
            let (title, fixed, moving) = if let Some((f, m)) = demo::demo_paths() {
                (format!("{} -> {} (demo)", name(&f), name(&m)), warpbench_io::open(&f)?, warpbench_io::open(&m)?)
            } else {
                let fixed = demo::phantom(96, 2.0, [0.0; 3], true);
                let moving = demo::phantom(96, 2.0, [6.0, -4.0, 3.0], false);
                ("phantom CT -> phantom MR (demo)".to_owned(), fixed, moving)
            };
            let pairs = demo::demo_landmarks(&fixed, &moving);
            Ok(Loaded { title, fixed, moving, pairs, fixed_path: None, moving_path: None, session: None })
        }
        _ => Err(anyhow!("give both a fixed and a moving volume, or neither for the demo pair")),
    }
}

/// The warp fitted on the active pairs: the pull-back the renderer uses and the forward map that places the moving
/// glyphs.
struct Fitted {
    /// u = moving_from_fixed: where a point of the deformed view comes from in the moving volume.
    pullback: Box<dyn Warp<Moving, Fixed>>,
    forward: Box<dyn Warp<Fixed, Moving>>,
    pairs: usize,
}

/// Adding a pair: the source is picked on the (deformed) moving volume, then the target on the fixed one.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Placing {
    Idle,
    /// The next click picks the source (a point of the moving volume, in moving LPS).
    Source,
    /// The next click picks the target; the source is placed.
    Target {
        moving: Point3<Lps>,
    },
}

impl std::fmt::Debug for Fitted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fitted").field("pairs", &self.pairs).finish_non_exhaustive()
    }
}

/// The window's state once the pair is on the GPU.
#[derive(Debug)]
pub struct Ready {
    pub loaded: Loaded,
    pub viewer: Viewer,
    pub settings: ViewSettings,
    pub camera: OrbitCamera,
    /// Slice positions (mm along S, P, L through the fixed grid).
    pub slice_mm: [f64; 3],
    view: Option<Shown>,
    slices: [Option<Shown>; 3],
    fitted: Option<Fitted>,
    /// The last fit's problem, shown in the status bar.
    pub fit_error: Option<String>,
    dirty: bool,
    dragging: bool,
    pub last_render_ms: f64,
    /// Adding a pair by picking.
    pub placing: Placing,
    /// Undo and redo.
    pub history: History,
    /// Per pair (aligned with `loaded.pairs`): the fit's residual and leave-one-out error, for the active pairs.
    pub errors: Vec<Option<panels::PairErrors>>,
    /// The session and landmark file fields of the side panel.
    pub files: panels::FileFields,
    /// The last message of a file action (saved, or the error), shown in the side panel.
    pub file_message: Option<String>,
    /// The pull-back's Jacobian over the fixed box after the last fit (folding where det ≤ 0).
    pub jacobian: Option<warpbench_solver::diagnostics::JacobianReport>,
    /// The LPS point under the cursor in a slice view, for the status bar.
    pub cursor_lps: Option<[f64; 3]>,
}

#[derive(Debug)]
enum Phase {
    Loading(Receiver<anyhow::Result<Loaded>>),
    Failed(String),
    Ready(Box<Ready>),
}

/// How often the window autosaves.
pub const AUTOSAVE_INTERVAL: std::time::Duration = std::time::Duration::from_secs(30);

/// The eframe app.
pub struct Workbench {
    phase: Phase,
    autosave_path: PathBuf,
    last_autosave: std::time::Instant,
    /// A copy of the autosave a crashed window left, offered for recovery.
    pub recovery: Option<PathBuf>,
    render_state: Option<eframe::egui_wgpu::RenderState>,
    screenshot: Option<PathBuf>,
    exit_after_frames: Option<u32>,
    ready_frames: u32,
    screenshot_requested: bool,
}

impl std::fmt::Debug for Workbench {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Workbench")
            .field("phase", &self.phase)
            .field("ready_frames", &self.ready_frames)
            .finish_non_exhaustive()
    }
}

impl Workbench {
    /// Starts loading `opts` on a worker thread.
    #[must_use]
    pub fn new(cc: &eframe::CreationContext<'_>, opts: GuiOptions) -> Self {
        let autosave_path = opts.autosave.clone().unwrap_or_else(session::autosave_path);
        // A crashed window's autosave is copied aside before this window's first autosave replaces it.
        let recovery = session::load(&autosave_path).ok().filter(|s| !s.clean_exit).and_then(|_| {
            let copy = autosave_path.with_file_name("autosave.recovered.warpbench.json");
            std::fs::copy(&autosave_path, &copy).ok().map(|_| copy)
        });
        Self {
            phase: Self::start_loading(&cc.egui_ctx, opts.clone()),
            autosave_path,
            last_autosave: std::time::Instant::now(),
            recovery,
            render_state: cc.wgpu_render_state.clone(),
            screenshot: opts.screenshot,
            exit_after_frames: opts.exit_after_frames,
            ready_frames: 0,
            screenshot_requested: false,
        }
    }

    fn start_loading(ctx: &egui::Context, opts: GuiOptions) -> Phase {
        let (tx, rx) = std::sync::mpsc::channel();
        let ctx = ctx.clone();
        std::thread::spawn(move || {
            let _ = tx.send(load(&opts));
            ctx.request_repaint();
        });
        Phase::Loading(rx)
    }

    /// Saves the session to the autosave file now (`clean_exit`: this is the last save of a normal exit).
    pub fn autosave_now(&mut self, clean_exit: bool) {
        self.last_autosave = std::time::Instant::now();
        let Phase::Ready(ready) = &self.phase else { return };
        let file = ready.to_session(clean_exit);
        if let Err(e) = session::save_creating_folder(&self.autosave_path, &file) {
            eprintln!("warpbench: autosave to {}: {e:#}", self.autosave_path.display());
        }
    }

    /// The state once loaded (for tests).
    #[must_use]
    pub fn ready(&self) -> Option<&Ready> {
        match &self.phase {
            Phase::Ready(r) => Some(r),
            _ => None,
        }
    }

    /// The state once loaded, to change it (for tests).
    pub fn ready_mut(&mut self) -> Option<&mut Ready> {
        match &mut self.phase {
            Phase::Ready(r) => Some(r),
            _ => None,
        }
    }

    /// The loading error, if loading failed.
    #[must_use]
    pub fn failure(&self) -> Option<&str> {
        match &self.phase {
            Phase::Failed(e) => Some(e),
            _ => None,
        }
    }

    fn poll_loading(&mut self) {
        let Phase::Loading(rx) = &self.phase else { return };
        let loaded = match rx.try_recv() {
            Ok(result) => result,
            Err(TryRecvError::Empty) => return,
            Err(TryRecvError::Disconnected) => Err(anyhow!("the loading thread stopped")),
        };
        self.phase = match loaded.and_then(|l| self.upload(l)) {
            Ok(ready) => Phase::Ready(Box::new(ready)),
            Err(e) => Phase::Failed(format!("{e:#}")),
        };
    }

    fn upload(&self, loaded: Loaded) -> anyhow::Result<Ready> {
        let rs = self.render_state.as_ref().context("the window has no wgpu renderer")?;
        let viewer = Viewer::new(rs, &loaded.fixed, &loaded.moving)?;
        let (lo, hi) = viewer.scene_box();
        let mut camera = OrbitCamera::fit(lo, hi, Projection::Perspective { fov_y_rad: 0.6 });
        camera.azimuth_rad = 0.6;
        camera.elevation_rad = 0.25;
        let mid = (lo + hi) * 0.5;
        let mut ready = Ready {
            loaded,
            viewer,
            settings: ViewSettings::default(),
            camera,
            slice_mm: [f64::from(mid.z), f64::from(mid.y), f64::from(mid.x)],
            view: None,
            slices: [None, None, None],
            fitted: None,
            fit_error: None,
            dirty: true,
            dragging: false,
            last_render_ms: 0.0,
            placing: Placing::Idle,
            errors: Vec::new(),
            files: panels::FileFields::default(),
            file_message: None,
            jacobian: None,
            cursor_lps: None,
            // Replaced just below by the real first state, which needs the rest of `ready`.
            history: History::new(Snapshot {
                pairs: Vec::new(),
                settings: ViewSettings::default(),
                layers: [LayerLook {
                    preset: warpbench_gpu::Preset::GreyRamp,
                    window: warpbench_gpu::Window::from_range(0.0, 1.0),
                    visible: true,
                }; 2],
            }),
        };
        if let Some(file) = ready.loaded.session.take() {
            ready.apply_session(&file);
        }
        ready.history = History::new(ready.snapshot());
        ready.refit();
        Ok(ready)
    }
}

impl Ready {
    /// Fits the warp to the active pairs with the current method and uploads its control texture; with fewer pairs
    /// than the method needs, the moving volume is shown unwarped and the status bar says why.
    pub fn refit(&mut self) {
        self.dirty = true;
        let method = self.settings.method();
        let name = panels::METHODS[self.settings.method.min(panels::METHODS.len() - 1)];
        let fixed_box = inputs::volume_box::<Fixed>(&self.loaded.fixed);
        let moving_box = inputs::volume_box::<Moving>(&self.loaded.moving);
        let used: Vec<usize> = (0..self.loaded.pairs.len())
            .filter(|&i| {
                let p = &self.loaded.pairs[i];
                p.active && p.moving.is_some() && p.fixed.is_some()
            })
            .collect();
        let (moving, fixed): (Vec<_>, Vec<_>) = used
            .iter()
            .filter_map(|&i| {
                let p = &self.loaded.pairs[i];
                Some((as_moving(p.moving?), as_fixed(p.fixed?)))
            })
            .unzip();
        self.errors = vec![None; self.loaded.pairs.len()];
        let result = (|| -> anyhow::Result<Fitted> {
            let need = inputs::min_pairs(&method);
            if moving.len() < need {
                return Err(anyhow!("{} active pairs; {name} needs {need}", moving.len()));
            }
            let pullback = method.fit(&fixed, &moving, fixed_box).map_err(|e| anyhow!("{name}: {e}"))?;
            let forward = method.fit(&moving, &fixed, moving_box).map_err(|e| anyhow!("{name}: {e}"))?;
            let (grid, texture) = scene::control_texture(pullback.as_ref(), fixed_box, self.settings.grid_n)
                .map_err(|e| anyhow!("{:#}", e.error()))?;
            let prepared = PreparedControl::prepare(
                &scene::control_desc(&grid, &texture),
                self.viewer.ctx.capabilities.float32_filterable,
            )
            .map_err(|e| anyhow!("{e}"))?;
            self.viewer.set_control(Some(&prepared));
            Ok(Fitted { pullback, forward, pairs: moving.len() })
        })();
        match result {
            Ok(fitted) => {
                // Residuals of the pull-back at the targets, and leave-one-out errors (refits without each pair).
                let residuals = residuals(fitted.pullback.as_ref(), &fixed, &moving);
                let loo = leave_one_out(&fixed, &moving, |f, m| method.fit(f, m, fixed_box), Parallelism::Rayon);
                for ((&i, r), l) in used.iter().zip(residuals).zip(loo) {
                    self.errors[i] = Some(panels::PairErrors { residual_mm: r, leave_one_out_mm: l });
                }
                // Folding: det ∇u on a 32³ grid of cells over the fixed volume's box.
                self.jacobian =
                    Some(jacobian_determinants(fitted.pullback.as_ref(), &fixed_box, [32; 3], Parallelism::Rayon));
                self.fitted = Some(fitted);
                self.fit_error = None;
            }
            Err(e) => {
                self.viewer.set_control(None);
                self.fitted = None;
                self.jacobian = None;
                self.fit_error = Some(format!("{e:#}"));
            }
        }
    }

    /// Number of pairs the current warp was fitted on.
    #[must_use]
    pub fn fitted_pairs(&self) -> usize {
        self.fitted.as_ref().map_or(0, |f| f.pairs)
    }

    fn glyphs(&self) -> Vec<GlyphInstance> {
        if !self.settings.show_landmarks {
            return Vec::new();
        }
        let to_vec = |c: [f64; 3]| Vec3::from_array(c.map(|v| v as f32));
        let pairs: Vec<GlyphPair> = self
            .loaded
            .pairs
            .iter()
            .map(|p| GlyphPair {
                moving_ref: p.moving.map(|m| match &self.fitted {
                    Some(f) => to_vec(f.forward.apply(as_moving(m)).coords()),
                    None => to_vec(m.coords()),
                }),
                fixed_ref: p.fixed.map(|q| to_vec(q.coords())),
                selected: false,
                active: p.active,
            })
            .collect();
        pair_glyphs(&pairs, &GlyphStyle::default())
    }

    fn slice_planes(&self) -> [SlicePlane; 3] {
        let f = &self.loaded.fixed;
        let m = f.lps_from_index.rows();
        [
            SlicePlane::axial(&m, f.dims, self.slice_mm[0]),
            SlicePlane::coronal(&m, f.dims, self.slice_mm[1]),
            SlicePlane::sagittal(&m, f.dims, self.slice_mm[2]),
        ]
    }

    /// Renders what changed (the 3-D view at `view_px`, the slices) and hands the images to egui.
    fn render(&mut self, rs: &eframe::egui_wgpu::RenderState, view_px: (u32, u32)) -> anyhow::Result<()> {
        if !self.dirty && self.view.as_ref().is_some_and(|v| (v.target.width, v.target.height) == view_px) {
            return Ok(());
        }
        let start = std::time::Instant::now();
        self.viewer.begin_frame();
        self.viewer.sync_presets();
        let glyphs = self.glyphs();
        let settings = self.settings.render_settings();
        let quality = if self.dragging { Quality::Interactive } else { Quality::Full };
        let target = self.viewer.render_view(&self.camera, &settings, quality, view_px, &glyphs)?;
        self.view = Some(viewer::show(rs, target, self.view.take()));
        let planes = self.slice_planes();
        for (slot, plane) in self.slices.iter_mut().zip(planes) {
            let target = self.viewer.render_slice(&plane, &settings, &glyphs)?;
            *slot = Some(viewer::show(rs, target, slot.take()));
        }
        self.viewer.ctx.check_errors().map_err(|e| anyhow!("{e}"))?;
        self.last_render_ms = start.elapsed().as_secs_f64() * 1e3;
        self.dirty = false;
        Ok(())
    }

    /// Places the point at ref position `x_ref` (a click in a slice, or a pick in the 3-D view, already in ref
    /// space): the source through the warp's pull-back (the moving volume's point shown there) unless the pick gives
    /// it (`moving_lps`), the target as is. A completed pair is appended, active, and the warp is fitted again.
    pub fn place_at_ref(&mut self, x_ref: [f64; 3], moving_lps: Option<[f64; 3]>) {
        match self.placing {
            Placing::Idle => {}
            Placing::Source => {
                let p = moving_lps.unwrap_or_else(|| match &self.fitted {
                    Some(f) => f.pullback.apply_raw(x_ref),
                    None => x_ref,
                });
                self.placing = Placing::Target { moving: Point3::from_array(p) };
            }
            Placing::Target { moving } => {
                let name = format!("Pt-{}", self.loaded.pairs.len() + 1);
                self.loaded.pairs.push(LandmarkPair::new(name, moving, Point3::from_array(x_ref)));
                self.placing = Placing::Idle;
                self.refit();
            }
        }
        self.invalidate();
    }

    /// A click at framebuffer point `pixel` of the 3-D view: picks the volume the placing step asks for.
    fn pick_in_view(&mut self, pixel: [f32; 2]) {
        let target = match self.placing {
            Placing::Idle => return,
            Placing::Source => PickTarget::Moving,
            Placing::Target { .. } => PickTarget::Fixed,
        };
        let Some(size) = self.view.as_ref().map(|v| (v.target.width, v.target.height)) else { return };
        let settings = self.settings.render_settings();
        match self.viewer.pick(&self.camera, &settings, size, pixel, target, self.settings.probe()) {
            Ok(Some(hit)) => {
                let x_ref = hit.x_ref.map(f64::from);
                let moving = matches!(target, PickTarget::Moving).then(|| hit.p_lps.map(f64::from));
                self.place_at_ref(x_ref, moving);
            }
            Ok(None) => self.fit_error = Some("the click hit nothing: try another point or probe".into()),
            Err(e) => self.fit_error = Some(format!("picking: {e:#}")),
        }
    }

    /// Centres the camera and the three slices on pair `i`'s fixed point.
    pub fn jump_to(&mut self, i: usize) {
        let Some(q) = self.loaded.pairs.get(i).and_then(|p| p.fixed) else { return };
        let c = q.coords();
        self.slice_mm = [c[2], c[1], c[0]];
        self.camera.target_ref = Vec3::from_array(c.map(|v| v as f32));
        self.camera.pan_mm = warpbench_gpu::glam::Vec2::ZERO;
        self.invalidate();
    }

    /// The session as it is now.
    #[must_use]
    pub fn to_session(&self, clean_exit: bool) -> session::SessionFile {
        let s = &self.settings;
        let layer = |l: &viewer::Layer| session::SessionLayer {
            preset: crate::scene::PRESET_NAMES
                [warpbench_gpu::Preset::ALL.iter().position(|p| *p == l.preset).unwrap_or(0)]
            .to_owned(),
            window_low: l.window.low(),
            window_high: l.window.low() + l.window.width,
            visible: l.visible,
        };
        session::SessionFile {
            schema: session::SCHEMA.to_owned(),
            fixed: self.loaded.fixed_path.clone(),
            moving: self.loaded.moving_path.clone(),
            landmarks: self.loaded.pairs.iter().map(session::SessionPair::from_pair).collect(),
            settings: session::SessionSettings {
                blend: warpbench_gpu::BlendMode::ALL[s.blend.min(6)].name().to_owned(),
                mix_weight: s.mix_weight,
                checker_mm: s.checker_mm,
                shading: s.shading.name().to_owned(),
                samples_per_voxel: s.samples_per_voxel,
                method: panels::METHODS[s.method.min(panels::METHODS.len() - 1)].to_owned(),
                stiffness: s.stiffness,
                bspline_levels: s.bspline_levels,
                control_texels: s.grid_n,
                show_landmarks: s.show_landmarks,
            },
            layers: [layer(&self.viewer.fixed), layer(&self.viewer.moving)],
            camera: session::SessionCamera {
                azimuth_deg: self.camera.azimuth_rad.to_degrees(),
                elevation_deg: self.camera.elevation_rad.to_degrees(),
                zoom: self.camera.zoom,
                target_lps: self.camera.target_ref.to_array(),
            },
            slice_mm: self.slice_mm,
            clean_exit,
        }
    }

    /// Applies a session's settings, looks, camera and slices (its pairs are already loaded). Unknown names keep the
    /// current choice.
    pub fn apply_session(&mut self, f: &session::SessionFile) {
        let st = &f.settings;
        let s = &mut self.settings;
        if let Some(i) = warpbench_gpu::BlendMode::ALL.iter().position(|b| b.name() == st.blend) {
            s.blend = i;
        }
        if let Some(m) = warpbench_gpu::ShadingMode::ALL.into_iter().find(|m| m.name() == st.shading) {
            s.shading = m;
        }
        if let Some(i) = panels::METHODS.iter().position(|m| *m == st.method) {
            s.method = i;
        }
        (s.mix_weight, s.checker_mm, s.samples_per_voxel) = (st.mix_weight, st.checker_mm, st.samples_per_voxel);
        (s.stiffness, s.bspline_levels, s.grid_n) = (st.stiffness, st.bspline_levels, st.control_texels.clamp(2, 256));
        s.show_landmarks = st.show_landmarks;
        for (layer, look) in [&mut self.viewer.fixed, &mut self.viewer.moving].into_iter().zip(&f.layers) {
            if let Some(i) = crate::scene::PRESET_NAMES.iter().position(|n| *n == look.preset) {
                layer.preset = warpbench_gpu::Preset::ALL[i];
            }
            if look.window_high > look.window_low {
                layer.window = warpbench_gpu::Window::from_range(look.window_low, look.window_high);
            }
            layer.visible = look.visible;
        }
        self.camera.azimuth_rad = f.camera.azimuth_deg.to_radians();
        self.camera.elevation_rad = f.camera.elevation_deg.to_radians();
        self.camera.zoom = f.camera.zoom.clamp(0.2, 20.0);
        self.camera.target_ref = Vec3::from_array(f.camera.target_lps);
        self.slice_mm = f.slice_mm;
        self.invalidate();
    }

    /// What undo restores, as it is now.
    #[must_use]
    pub fn snapshot(&self) -> Snapshot {
        let look = |l: &viewer::Layer| LayerLook { preset: l.preset, window: l.window, visible: l.visible };
        Snapshot {
            pairs: self.loaded.pairs.clone(),
            settings: self.settings.clone(),
            layers: [look(&self.viewer.fixed), look(&self.viewer.moving)],
        }
    }

    /// Puts `s` back: pairs, settings and looks; fits the warp again.
    fn restore(&mut self, s: &Snapshot) {
        self.loaded.pairs.clone_from(&s.pairs);
        self.settings = s.settings.clone();
        for (layer, look) in [&mut self.viewer.fixed, &mut self.viewer.moving].into_iter().zip(s.layers) {
            (layer.preset, layer.window, layer.visible) = (look.preset, look.window, look.visible);
        }
        self.placing = Placing::Idle;
        self.refit();
    }

    /// Undoes the last change (Ctrl+Z).
    pub fn undo(&mut self) {
        if let Some(s) = self.history.undo().cloned() {
            self.restore(&s);
        }
    }

    /// Redoes the last undone change (Ctrl+Shift+Z).
    pub fn redo(&mut self) {
        if let Some(s) = self.history.redo().cloned() {
            self.restore(&s);
        }
    }

    /// Marks the views for re-rendering.
    pub fn invalidate(&mut self) {
        self.dirty = true;
    }
}

impl eframe::App for Workbench {
    fn on_exit(&mut self) {
        self.autosave_now(true);
    }

    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.poll_loading();
        if matches!(self.phase, Phase::Ready(_)) && self.last_autosave.elapsed() >= AUTOSAVE_INTERVAL {
            self.autosave_now(false);
        }
        if let (Some(path), Phase::Ready(_)) = (self.recovery.clone(), &self.phase) {
            let mut choice = None;
            egui::Panel::top("recovery").show(ui, |ui| {
                ui.horizontal(|ui| {
                    ui.label("The last session did not end normally.");
                    if ui.button("Recover the last session").clicked() {
                        choice = Some(true);
                    }
                    if ui.button("Discard it").clicked() {
                        choice = Some(false);
                    }
                });
            });
            match choice {
                Some(true) => {
                    self.recovery = None;
                    let opts = GuiOptions { session: Some(path), ..GuiOptions::default() };
                    self.phase = Self::start_loading(ui.ctx(), opts);
                }
                Some(false) => self.recovery = None,
                None => {}
            }
        }
        let render_state = self.render_state.clone();
        match &mut self.phase {
            Phase::Loading(_) => {
                egui::CentralPanel::default().show(ui, |ui| {
                    ui.horizontal(|ui| {
                        ui.spinner();
                        ui.label("Loading the volumes...");
                    });
                });
            }
            Phase::Failed(message) => {
                egui::CentralPanel::default().show(ui, |ui| {
                    ui.heading("Could not open the volumes");
                    ui.label(message.as_str());
                });
            }
            Phase::Ready(ready) => {
                workbench_ui(ui, ready, render_state.as_ref());
                self.ready_frames += 1;
            }
        }
        if let (Some(n), false) = (self.exit_after_frames, self.screenshot_requested)
            && self.ready_frames >= n
        {
            self.screenshot_requested = true;
            if let Some(path) = self.screenshot.clone() {
                let ctx = ui.ctx().clone();
                ui.ctx().request_screenshot(move |image| {
                    if let Err(e) = save_png(&path, &image) {
                        eprintln!("warpbench: {e:#}");
                    }
                    ctx.send_viewport_cmd(egui::ViewportCommand::Close);
                    ctx.request_repaint();
                });
            } else {
                ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
            }
        }
        if matches!(self.phase, Phase::Loading(_)) || self.exit_after_frames.is_some() {
            ui.ctx().request_repaint();
        }
    }
}

/// The window once the pair is loaded: side panel, status bar, slice strip and the 3-D view.
fn workbench_ui(ui: &mut egui::Ui, ready: &mut Ready, render_state: Option<&eframe::egui_wgpu::RenderState>) {
    // Redo first: Ctrl+Shift+Z also matches Ctrl+Z logically.
    let redo = egui::KeyboardShortcut::new(egui::Modifiers::COMMAND | egui::Modifiers::SHIFT, egui::Key::Z);
    let undo = egui::KeyboardShortcut::new(egui::Modifiers::COMMAND, egui::Key::Z);
    if ui.input_mut(|i| i.consume_shortcut(&redo)) {
        ready.redo();
    } else if ui.input_mut(|i| i.consume_shortcut(&undo)) {
        ready.undo();
    }
    egui::Panel::left("settings").resizable(true).default_size(260.0).show(ui, |ui| {
        egui::ScrollArea::vertical().show(ui, |ui| {
            ui.heading(ready.loaded.title.as_str());
            ui.horizontal(|ui| {
                if ui.add_enabled(ready.history.can_undo(), egui::Button::new("Undo")).clicked() {
                    ready.undo();
                }
                if ui.add_enabled(ready.history.can_redo(), egui::Button::new("Redo")).clicked() {
                    ready.redo();
                }
            });
            let change = panels::settings_ui(ui, &mut ready.settings);
            if change.refit {
                ready.refit();
            } else if change.redraw {
                ready.invalidate();
            }
            ui.separator();
            if panels::layers_ui(ui, &mut ready.viewer.fixed, &mut ready.viewer.moving) {
                ready.invalidate();
            }
            ui.separator();
            ui.horizontal(|ui| {
                let adding = ready.placing != Placing::Idle;
                if ui.selectable_label(adding, "Add pair").clicked() {
                    ready.placing = if adding { Placing::Idle } else { Placing::Source };
                }
                match ready.placing {
                    Placing::Idle => ui.label(""),
                    Placing::Source => ui.label("click the moving volume (source)"),
                    Placing::Target { .. } => ui.label("click the fixed volume (target)"),
                };
            });
            match panels::landmarks_ui(ui, &mut ready.loaded.pairs, &ready.errors) {
                panels::LandmarkAction::None => {}
                panels::LandmarkAction::Refit => ready.refit(),
                panels::LandmarkAction::Delete(i) => {
                    ready.loaded.pairs.remove(i);
                    ready.refit();
                }
                panels::LandmarkAction::Jump(i) => ready.jump_to(i),
            }
            ui.separator();
            match panels::files_ui(ui, &mut ready.files) {
                panels::FileAction::None => {}
                panels::FileAction::SaveSession(path) => {
                    let file = ready.to_session(true);
                    ready.file_message = Some(match session::save(&path, &file) {
                        Ok(()) => format!("saved {}", path.display()),
                        Err(e) => format!("{e:#}"),
                    });
                }
                panels::FileAction::ExportLandmarks(path) => {
                    ready.file_message = Some(match panels::export_landmarks(&path, &ready.loaded.pairs) {
                        Ok(()) => format!("wrote {}", path.display()),
                        Err(e) => format!("{e:#}"),
                    });
                }
                panels::FileAction::Screenshot(path) => {
                    // The window as it is drawn this frame, saved when the integration hands the pixels over.
                    ui.ctx().request_screenshot(move |image| {
                        if let Err(e) = save_png(&path, &image) {
                            eprintln!("warpbench: {e:#}");
                        }
                    });
                    ready.file_message = Some("screenshot requested".into());
                }
                panels::FileAction::ImportLandmarks(path) => match panels::import_landmarks(&path) {
                    Ok(pairs) => {
                        ready.file_message = Some(format!("read {} pairs from {}", pairs.len(), path.display()));
                        ready.loaded.pairs = pairs;
                        ready.refit();
                    }
                    Err(e) => ready.file_message = Some(format!("{e:#}")),
                },
            }
            if let Some(m) = &ready.file_message {
                ui.label(m.as_str());
            }
        });
    });
    egui::Panel::bottom("status").show(ui, |ui| {
        ui.horizontal(|ui| {
            ui.label(format!("GPU: {}", ready.viewer.ctx.describe()));
            ui.separator();
            ui.label(format!(
                "last frame {:.0} ms ({:.1} fps)",
                ready.last_render_ms,
                1000.0 / ready.last_render_ms.max(1e-3)
            ));
            ui.separator();
            if let Some([l, p, s]) = ready.cursor_lps {
                ui.label(format!("cursor LPS ({l:.1}, {p:.1}, {s:.1}) mm"));
                ui.separator();
            }
            if let Some(j) = ready.jacobian.as_ref().filter(|j| j.min_det <= 0.0) {
                let at = j.min_at;
                ui.colored_label(
                    egui::Color32::from_rgb(235, 90, 80),
                    format!(
                        "the warp folds: {:.2} % of the box, det {:.2} at ({:.0}, {:.0}, {:.0}) mm",
                        100.0 * j.fraction_folded,
                        j.min_det,
                        at[0],
                        at[1],
                        at[2]
                    ),
                );
                ui.separator();
            }
            match &ready.fit_error {
                Some(e) => ui.colored_label(egui::Color32::LIGHT_RED, format!("warp off: {e}")),
                None => ui.label(format!(
                    "{} fitted on {} pairs",
                    panels::METHODS[ready.settings.method.min(panels::METHODS.len() - 1)],
                    ready.fitted_pairs()
                )),
            };
        });
    });
    let planes = ready.slice_planes();
    let slices_height = (ui.available_height() * 0.4).max(160.0);
    egui::Panel::bottom("slices").exact_size(slices_height).show(ui, |ui| {
        ready.cursor_lps = None;
        ui.columns(3, |columns| {
            let names = ["Axial", "Coronal", "Sagittal"];
            for (a, col) in columns.iter_mut().enumerate() {
                col.label(names[a]);
                let before = ready.slice_mm[a];
                col.add(egui::Slider::new(&mut ready.slice_mm[a], -150.0..=150.0).text(format!("{} mm", names[a])));
                if (ready.slice_mm[a] - before).abs() > f64::EPSILON {
                    ready.invalidate();
                }
                if let Some(shown) = &ready.slices[a] {
                    let avail = col.available_size();
                    let (w, h) = (shown.target.width as f32, shown.target.height as f32);
                    let scale = (avail.x / w).min(avail.y.max(64.0) / h);
                    let response = col.add(
                        egui::Image::new(egui::load::SizedTexture::new(shown.texture_id, egui::vec2(w, h) * scale))
                            .sense(egui::Sense::click()),
                    );
                    let label = format!("{} slice", names[a]);
                    response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, &label));
                    // Framebuffer coordinates of the slice image (pixel centres at i + 1/2) to ref mm.
                    let to_ref = |pos: egui::Pos2| {
                        let f = (pos - response.rect.min) / scale;
                        planes[a].ref_from_pixel(f64::from(f.x) - 0.5, f64::from(f.y) - 0.5)
                    };
                    if let Some(pos) = response.hover_pos() {
                        ready.cursor_lps = Some(to_ref(pos));
                    }
                    if response.clicked()
                        && let Some(pos) = response.interact_pointer_pos()
                    {
                        let x_ref = to_ref(pos);
                        if ready.placing == Placing::Idle {
                            // Linked navigation: the other two slices move through the clicked point.
                            ready.slice_mm = [x_ref[2], x_ref[1], x_ref[0]];
                            ready.invalidate();
                        } else {
                            ready.place_at_ref(x_ref, None);
                        }
                    }
                    // The crosshair: where the other two planes cut this one.
                    let centre = [ready.slice_mm[2], ready.slice_mm[1], ready.slice_mm[0]];
                    if let Some(q) = planes[a].pixel_from_ref(centre) {
                        let p =
                            response.rect.min + egui::vec2((q[0] as f32 + 0.5) * scale, (q[1] as f32 + 0.5) * scale);
                        let stroke = egui::Stroke::new(1.0, egui::Color32::from_rgba_unmultiplied(255, 230, 90, 160));
                        let painter = col.painter_at(response.rect);
                        painter.hline(response.rect.x_range(), p.y, stroke);
                        painter.vline(p.x, response.rect.y_range(), stroke);
                    }
                }
            }
        });
    });
    egui::CentralPanel::default().show(ui, |ui| {
        let avail = ui.available_size();
        let ppp = ui.ctx().pixels_per_point();
        // Cap the 3-D view's pixels: CPU drivers render about 1 Mpixel·step per second.
        let px = (avail * ppp).min(egui::vec2(1024.0, 1024.0)).max(egui::vec2(32.0, 32.0));
        let view_px = (px.x as u32, px.y as u32);
        if let Some(rs) = render_state
            && let Err(e) = ready.render(rs, view_px)
        {
            ready.fit_error = Some(format!("rendering: {e:#}"));
        }
        if let Some(shown) = &ready.view {
            let response = ui.add(
                egui::Image::new(egui::load::SizedTexture::new(shown.texture_id, avail))
                    .sense(egui::Sense::click_and_drag()),
            );
            response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, "3-D view"));
            if response.clicked()
                && let Some(pos) = response.interact_pointer_pos()
            {
                let f = (pos - response.rect.min) / response.rect.size();
                let (w, h) = (shown.target.width as f32, shown.target.height as f32);
                ready.pick_in_view([f.x * w, f.y * h]);
            }
            let drag = response.drag_delta();
            let was_dragging = ready.dragging;
            ready.dragging = response.dragged();
            if drag != egui::Vec2::ZERO {
                ready.camera.azimuth_rad -= drag.x * 0.01;
                ready.camera.elevation_rad = (ready.camera.elevation_rad + drag.y * 0.01).clamp(-1.5, 1.5);
                ready.invalidate();
            }
            if was_dragging && !ready.dragging {
                // Back to the full sample rate once the drag ends.
                ready.invalidate();
            }
            if response.hovered() {
                let scroll = ui.input(|i| i.smooth_scroll_delta.y);
                if scroll != 0.0 {
                    ready.camera.zoom = (ready.camera.zoom * (1.0 + scroll * 0.002)).clamp(0.2, 20.0);
                    ready.invalidate();
                }
            }
        }
    });
    // A change becomes an undo step once it has settled (a slider drag is one step).
    if ready.placing == Placing::Idle && !ui.input(|i| i.pointer.any_down()) {
        let now = ready.snapshot();
        ready.history.record(&now);
    }
    if ready.dirty {
        ui.ctx().request_repaint();
    }
}

fn save_png(path: &std::path::Path, image: &egui::ColorImage) -> anyhow::Result<()> {
    let [w, h] = image.size;
    let rgba: Vec<u8> = image.pixels.iter().flat_map(egui::Color32::to_array).collect();
    let mut png = Vec::new();
    image::write_buffer_with_format(
        &mut std::io::Cursor::new(&mut png),
        &rgba,
        w as u32,
        h as u32,
        image::ExtendedColorType::Rgba8,
        image::ImageFormat::Png,
    )
    .context("encoding the screenshot")?;
    warpbench_io::atomic::write_atomic(path, |out| out.write_all(&png))?;
    Ok(())
}

/// Opens the window and runs until it is closed.
pub fn run(opts: GuiOptions) -> anyhow::Result<()> {
    let native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default().with_inner_size([1280.0, 860.0]).with_title("warpbench"),
        renderer: eframe::Renderer::Wgpu,
        wgpu_options: wgpu_options(),
        ..Default::default()
    };
    eframe::run_native("warpbench", native, Box::new(move |cc| Ok(Box::new(Workbench::new(cc, opts)))))
        .map_err(|e| anyhow!("the window: {e}"))
}

/// eframe's wgpu set-up with the adapter's own limits and the optional features the renderer uses (the defaults
/// are WebGL2 limits on GL, without compute).
#[must_use]
pub fn wgpu_options() -> eframe::egui_wgpu::WgpuConfiguration {
    use eframe::egui_wgpu::{WgpuSetup, WgpuSetupCreateNew};
    use eframe::wgpu;
    let device_descriptor = std::sync::Arc::new(|adapter: &wgpu::Adapter| wgpu::DeviceDescriptor {
        label: Some("warpbench"),
        required_features: adapter.features() & warpbench_gpu::RaycastRenderer::OPTIONAL_FEATURES,
        required_limits: adapter.limits(),
        ..Default::default()
    });
    eframe::egui_wgpu::WgpuConfiguration {
        wgpu_setup: WgpuSetup::CreateNew(WgpuSetupCreateNew {
            device_descriptor,
            ..WgpuSetupCreateNew::without_display_handle()
        }),
        ..Default::default()
    }
}
