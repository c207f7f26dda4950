//! The workbench window (eframe/egui): the fixed and the deformed moving volume in a 3-D view and three slice views
//! of the fixed grid, rendered by `warpbench_gpu` on eframe's own wgpu device, with the landmark glyphs, the warp
//! method and the view settings in a side panel.
//!
//! Bare `warpbench` opens the demo pair ([`demo`]). Loading runs on a worker thread; the window stays responsive
//! and shows an error (naming the file) instead of the views when it fails. Frames are rendered only when something
//! changed, at the interaction sample rate while the camera is being dragged ([`warpbench_gpu::Quality`]).

pub mod autosave;
pub mod demo;
pub mod export;
pub mod history;
pub mod open;
pub mod pacing;
pub mod panels;
pub mod placement;
pub mod session;
pub mod viewer;

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, TryRecvError};

use anyhow::{Context as _, anyhow};
use eframe::egui;
use warpbench_gpu::PickTarget;
use warpbench_gpu::glam::Vec3;
use warpbench_gpu::{
    GlyphInstance, GlyphPair, GlyphStyle, OrbitCamera, Projection, Quality, SlicePlane, pair_glyphs,
};
use warpbench_io::Volume;
use warpbench_io::geometry::{Lps, Point3};
use warpbench_io::landmarks::LandmarkPair;
use warpbench_solver::diagnostics::{jacobian_determinants, residuals};
use warpbench_solver::spaces::{Fixed, Moving, as_fixed, as_moving};
use warpbench_solver::warp::{Parallelism, Warp};

use crate::inputs::{self, LandmarkSource};
use history::{History, LayerLook, Snapshot, VolumeRef};
use pacing::{Refine, interactive_size};
use panels::ViewSettings;
use viewer::{DeviceFacts, LayerData, Shown, Viewer};

/// What the window opens with.
#[derive(Clone, Debug, Default)]
pub struct GuiOptions {
    /// `None` (with `moving` `None`): the demo pair.
    pub fixed: Option<PathBuf>,
    pub moving: Option<PathBuf>,
    pub landmarks: Option<LandmarkSource>,
    /// Save a screenshot of the window here after `exit_after_frames` frames with the pair shown and fully rendered,
    /// then close.
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
    pub fixed: Arc<Volume>,
    pub moving: Arc<Volume>,
    pub pairs: Vec<LandmarkPair>,
    /// e.g. "cranium_ct.nii.gz -> ch2.nii.gz (demo)".
    pub title: String,
    /// The input paths (`None` for the demo pair), for sessions.
    pub fixed_path: Option<PathBuf>,
    pub moving_path: Option<PathBuf>,
    /// The session whose settings apply once the pair is shown.
    pub session: Option<session::SessionFile>,
}

/// A loaded pair and, when the window's device was known, both volumes prepared for it ([`LayerData::prepare`]), all
/// made on the loading thread.
#[derive(Debug)]
pub struct LoadedPair {
    pub loaded: Loaded,
    /// Fixed, moving.
    pub layers: Option<[LayerData; 2]>,
}

impl LoadedPair {
    /// Loads what `opts` names ([`load`]) and prepares both volumes for a device like `facts`.
    pub fn load(opts: &GuiOptions, watch: &Arc<open::Watch>, facts: Option<DeviceFacts>) -> anyhow::Result<Self> {
        let loaded = load(opts, watch)?;
        let layers = match facts {
            Some(facts) => {
                Some([LayerData::prepare(&loaded.fixed, facts)?, LayerData::prepare(&loaded.moving, facts)?])
            }
            None => None,
        };
        Ok(Self { loaded, layers })
    }
}

/// Loads what `opts` names: a session, two volumes (with landmarks), or the demo pair when it names nothing,
/// reporting each file's progress to `watch` and stopping when it is cancelled.
pub fn load(opts: &GuiOptions, watch: &Arc<open::Watch>) -> anyhow::Result<Loaded> {
    let read = |p: &std::path::Path| watch.load_options(p).open(p).map(Arc::new);
    let name =
        |p: &std::path::Path| p.file_name().map_or_else(|| p.display().to_string(), |n| n.to_string_lossy().into());
    if let Some(path) = &opts.session {
        let file = session::load(path)?;
        let mut loaded = load(
            &GuiOptions { fixed: file.fixed.clone(), moving: file.moving.clone(), ..GuiOptions::default() },
            watch,
        )?;
        loaded.pairs = file.landmarks.iter().map(session::SessionPair::to_pair).collect();
        loaded.title = format!("{} ({})", loaded.title, name(path));
        loaded.session = Some(file);
        return Ok(loaded);
    }
    match (&opts.fixed, &opts.moving) {
        (Some(f), Some(m)) => {
            let fixed = read(f)?;
            let moving = read(m)?;
            let pairs = match &opts.landmarks {
                Some(source) => source.read().map_err(|e| anyhow!("{e:#}"))?,
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
                (format!("{} -> {} (demo)", name(&f), name(&m)), read(&f)?, read(&m)?)
            } else {
                let fixed = Arc::new(demo::phantom(96, 2.0, [0.0; 3], true));
                let moving = Arc::new(demo::phantom(96, 2.0, [6.0, -4.0, 3.0], false));
                ("phantom CT -> phantom MR (demo)".to_owned(), fixed, moving)
            };
            let pairs = demo::demo_landmarks(&fixed, &moving);
            Ok(Loaded { title, fixed, moving, pairs, fixed_path: None, moving_path: None, session: None })
        }
        _ => Err(anyhow!("give both a fixed and a moving volume, or neither for the demo pair")),
    }
}

pub use crate::fit::{Fitted, fit_warp, fit_warp_on_gpu, gpu_evaluates};

/// Where the window makes the control texture after a fit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ControlEval {
    /// A TPS or a B-spline on the GPU when the adapter is a real GPU; otherwise on the CPU (a CPU driver runs the
    /// compute pass slower than the solver's sampling on rayon).
    #[default]
    Auto,
    Cpu,
    /// A TPS or a B-spline on the GPU whatever the adapter (the linear methods on the CPU).
    Gpu,
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

/// Which point of a pair.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum End {
    /// The source, on the moving volume (drawn where the warp shows it).
    Moving,
    /// The target, on the fixed volume.
    Fixed,
}

/// Where a landmark is being dragged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DragView {
    /// Along the visible surface of the 3-D view (a pick per drag event).
    ThreeD,
    /// Within the plane of slice view 0 (axial), 1 (coronal) or 2 (sagittal).
    Slice(usize),
}

/// A landmark point being dragged.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DragPoint {
    pub pair: usize,
    pub end: End,
    pub view: DragView,
}

/// How close (points) a press must be to a landmark glyph to grab it.
const GRAB_RADIUS: f32 = 8.0;

/// How far (mm) from a slice plane a landmark is still drawn on, and grabbed from, that slice.
const SLICE_SLAB_MM: f64 = 3.0;

/// The window's state once the pair is on the GPU.
#[derive(Debug)]
pub struct Ready {
    pub loaded: Loaded,
    pub viewer: Viewer,
    pub settings: ViewSettings,
    pub camera: OrbitCamera,
    /// Slice positions (mm along S, P, L through the fixed grid).
    pub slice_mm: [f64; 3],
    /// The rendered images and what needs rendering again.
    images: Images,
    fitted: Option<Fitted>,
    /// The last fit's problem, shown in the status bar.
    pub fit_error: Option<String>,
    dragging: bool,
    pub last_render_ms: f64,
    /// The window's frame rate, for the status bar.
    frame_rate: pacing::FrameRate,
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
    /// What the pointer is over in a slice view (the fixed point and the moving point shown there), for the status
    /// bar; a click there stores exactly these points ([`placement`]).
    pub cursor: Option<placement::Cursor>,
    /// Why the last click or drag did not place its point (outside its volume), shown in the status bar until the
    /// next point is placed.
    pub notice: Option<String>,
    /// The pair selected in the table or by clicking its glyph.
    pub selected: Option<usize>,
    /// A landmark point being dragged.
    pub drag: Option<DragPoint>,
    /// The export running on a worker thread.
    pub export: Option<export::ExportJob>,
    /// The export section's fields.
    pub export_fields: export::ExportFields,
    /// Where the control texture is made.
    pub control_eval: ControlEval,
    /// A change asked for a fit at the end of the frame ([`Self::refit_soon`]).
    fit_pending: bool,
    /// What the last fit found suspicious in the pairs (a pair given twice, a nearly flat set), numbered as the
    /// table's rows.
    pub fit_warnings: Vec<String>,
}

/// The 3-D view's and the slices' images as egui shows them, and what needs rendering again.
#[derive(Debug)]
struct Images {
    view: Option<Shown>,
    slices: [Option<Shown>; 3],
    view_dirty: bool,
    slices_dirty: bool,
    /// The 3-D view shown is reduced (interaction rate and size): a full one is to follow.
    view_reduced: bool,
    /// On a CPU driver, the full view being rendered band by band ([`pacing`]).
    refine: Option<Refine>,
    /// Measured cost of the 3-D view on a CPU driver (ms per pixel, full quality), for the interaction size and the
    /// bands.
    view_ms_per_px: Option<f64>,
}

impl Default for Images {
    fn default() -> Self {
        Self {
            view: None,
            slices: [None, None, None],
            view_dirty: true,
            slices_dirty: true,
            view_reduced: false,
            refine: None,
            view_ms_per_px: None,
        }
    }
}

/// A volume read (and maybe prepared) for one side while the other is still being read.
#[derive(Debug)]
struct Pending {
    volume: Arc<Volume>,
    path: PathBuf,
    layer: Option<LayerData>,
}

#[derive(Debug)]
enum Phase {
    Loading { rx: Receiver<anyhow::Result<LoadedPair>>, watch: Arc<open::Watch> },
    Failed(String),
    Ready(Box<Ready>),
}

/// The eframe app.
pub struct Workbench {
    phase: Phase,
    /// Every change of the document reaches the autosave file ([`autosave`]).
    autosave: autosave::Autosave,
    /// A copy of the autosave a crashed window left, offered for recovery.
    pub recovery: Option<PathBuf>,
    render_state: Option<eframe::egui_wgpu::RenderState>,
    screenshot: Option<PathBuf>,
    exit_after_frames: Option<u32>,
    ready_frames: u32,
    screenshot_requested: bool,
    /// Volumes being read for File > Open and drops.
    jobs: Vec<open::VolumeJob>,
    /// Volumes read while no pair is shown, waiting for the other side.
    pending: [Option<Pending>; 2],
    /// The window's device, as the loading threads prepare volumes for it.
    facts: Option<DeviceFacts>,
    /// The open dialogs: error, series chooser, dropped volume, native dialog.
    pub dialogs: open::OpenDialogs,
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
            let bytes = std::fs::read(&autosave_path).ok()?;
            warpbench_io::atomic::write_atomic(&copy, |w| std::io::Write::write_all(w, &bytes)).ok().map(|()| copy)
        });
        let facts = cc.wgpu_render_state.as_ref().map(|rs| DeviceFacts::of(&Viewer::context(rs)));
        Self {
            phase: Self::start_loading(&cc.egui_ctx, opts.clone(), facts),
            facts,
            autosave: autosave::Autosave::new(autosave_path),
            recovery,
            render_state: cc.wgpu_render_state.clone(),
            screenshot: opts.screenshot,
            exit_after_frames: opts.exit_after_frames,
            ready_frames: 0,
            screenshot_requested: false,
            jobs: Vec::new(),
            pending: [None, None],
            dialogs: open::OpenDialogs::default(),
        }
    }

    fn start_loading(ctx: &egui::Context, opts: GuiOptions, facts: Option<DeviceFacts>) -> Phase {
        let (tx, rx) = std::sync::mpsc::channel();
        let ctx = ctx.clone();
        let watch = Arc::new(open::Watch::default());
        let worker_watch = Arc::clone(&watch);
        std::thread::spawn(move || {
            let _ = tx.send(LoadedPair::load(&opts, &worker_watch, facts));
            ctx.request_repaint();
        });
        Phase::Loading { rx, watch }
    }

    /// Saves the session to the autosave file now and waits until it is on disk (`clean_exit`: this is the last
    /// save of a normal exit).
    pub fn autosave_now(&mut self, clean_exit: bool) {
        let Phase::Ready(ready) = &self.phase else { return };
        let file = ready.to_session(clean_exit);
        self.autosave.write_and_wait(&file);
    }

    /// The autosave's last write error, if it failed.
    #[must_use]
    pub fn autosave_error(&self) -> Option<String> {
        self.autosave.error()
    }

    /// Hands the document as it is at the end of this frame to the autosave.
    fn autosave_changes(&mut self, ctx: &egui::Context) {
        if let Phase::Ready(ready) = &self.phase {
            autosave_changes(&mut self.autosave, ctx, ready);
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
        let Phase::Loading { rx, .. } = &self.phase else { return };
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

    /// Starts reading a volume for one side of the pair (File > Open, a drop, the series chooser); a read already
    /// running for that side is cancelled.
    pub fn open_volume(&mut self, ctx: &egui::Context, side: open::Side, path: PathBuf, series: Option<String>) {
        for job in self.jobs.iter().filter(|j| j.side == side) {
            job.watch.cancel();
        }
        self.jobs.retain(|j| j.side != side);
        self.jobs.push(open::VolumeJob::start(ctx, side, path, series, self.facts));
    }

    /// The volume reads still running (for tests).
    #[must_use]
    pub fn reading(&self) -> usize {
        self.jobs.len()
    }

    /// Takes finished reads: a volume replaces its side of the shown pair, or waits for the other side when no
    /// pair is shown; a failure opens the error dialog or the series chooser.
    fn poll_volume_jobs(&mut self) {
        let mut finished = Vec::new();
        self.jobs.retain(|job| match job.poll() {
            Some(result) => {
                finished.push((job.side, job.path.clone(), result));
                false
            }
            None => true,
        });
        for (side, path, result) in finished {
            let (volume, layer) = match result {
                Ok(open::ReadVolume { layer: Some(Err(e)), .. }) => {
                    self.dialogs.error = Some(format!("{}: {e:#}", path.display()));
                    continue;
                }
                Ok(open::ReadVolume { volume, layer }) => (Arc::new(volume), layer.and_then(Result::ok)),
                Err(e) => {
                    self.dialogs.failed(side, &path, &e);
                    continue;
                }
            };
            if let Phase::Ready(ready) = &mut self.phase {
                if let Err(e) = ready.replace_volume(side, volume, layer, path) {
                    self.dialogs.error = Some(format!("{e:#}"));
                }
                continue;
            }
            self.pending[side as usize] = Some(Pending { volume, path, layer });
            if let [Some(_), Some(_)] = &self.pending {
                let [Some(fixed), Some(moving)] = std::mem::take(&mut self.pending) else { continue };
                let layers = fixed.layer.zip(moving.layer).map(|(f, m)| [f, m]);
                let loaded = Loaded {
                    title: format!("{} -> {}", open::file_name(&fixed.path), open::file_name(&moving.path)),
                    fixed: fixed.volume,
                    moving: moving.volume,
                    pairs: Vec::new(),
                    fixed_path: Some(fixed.path),
                    moving_path: Some(moving.path),
                    session: None,
                };
                self.phase = match self.upload(LoadedPair { loaded, layers }) {
                    Ok(ready) => Phase::Ready(Box::new(ready)),
                    Err(e) => Phase::Failed(format!("{e:#}")),
                };
            }
        }
    }

    /// Acts on what the menu, a dialog, a drop or a chooser asked for.
    fn handle(&mut self, ctx: &egui::Context, event: open::OpenEvent) {
        use open::{OpenEvent, Purpose};
        match event {
            OpenEvent::Volume { side, path, series } => self.open_volume(ctx, side, path, series),
            OpenEvent::OpenSession(path) => {
                self.phase =
                    Self::start_loading(ctx, GuiOptions { session: Some(path), ..GuiOptions::default() }, self.facts);
            }
            OpenEvent::Demo => self.phase = Self::start_loading(ctx, GuiOptions::default(), self.facts),
            OpenEvent::Dialog(purpose) => self.dialogs.dialog = Some(open::DialogJob::start(ctx, purpose)),
            OpenEvent::ImportLandmarks(path) => match &mut self.phase {
                Phase::Ready(ready) => ready.file_action(ctx, panels::FileAction::ImportLandmarks(path)),
                _ => self.dialogs.error = Some("Open a pair of volumes before importing landmarks.".into()),
            },
            OpenEvent::Save(purpose, path) => {
                let Phase::Ready(ready) = &mut self.phase else { return };
                let action = match purpose {
                    Purpose::SaveSession => panels::FileAction::SaveSession(path),
                    Purpose::ExportLandmarks => panels::FileAction::ExportLandmarks(path),
                    Purpose::Screenshot => panels::FileAction::Screenshot(path),
                    Purpose::ExportWarped => panels::FileAction::ExportWarped(path),
                    Purpose::ExportField => panels::FileAction::ExportField(path),
                    Purpose::OpenFile(_) | Purpose::OpenFolder(_) | Purpose::OpenSession | Purpose::ImportLandmarks => {
                        return;
                    }
                };
                ready.file_action(ctx, action);
            }
        }
    }

    fn upload(&self, pair: LoadedPair) -> anyhow::Result<Ready> {
        let rs = self.render_state.as_ref().context("the window has no wgpu renderer")?;
        let LoadedPair { loaded, layers } = pair;
        let placeholder_volumes =
            [&loaded.fixed, &loaded.moving].map(|v| VolumeRef { volume: Arc::clone(v), path: None });
        let ctx = Viewer::context(rs);
        let viewer = match layers {
            Some([fixed, moving]) => Viewer::from_layers(ctx, &fixed, &moving)?,
            None => Viewer::with_context(ctx, &loaded.fixed, &loaded.moving)?,
        };
        let (lo, hi) = viewer.scene_box();
        // Placed by `reset_camera` below.
        let camera = OrbitCamera::fit(lo, hi, Projection::Perspective { fov_y_rad: 0.6 });
        let mid = (lo + hi) * 0.5;
        let mut ready = Ready {
            loaded,
            viewer,
            settings: ViewSettings::default(),
            camera,
            slice_mm: [f64::from(mid.z), f64::from(mid.y), f64::from(mid.x)],
            images: Images::default(),
            fitted: None,
            fit_error: None,
            dragging: false,
            last_render_ms: 0.0,
            frame_rate: pacing::FrameRate::default(),
            placing: Placing::Idle,
            errors: Vec::new(),
            files: panels::FileFields::default(),
            file_message: None,
            jacobian: None,
            cursor: None,
            notice: None,
            fit_pending: false,
            fit_warnings: Vec::new(),
            selected: None,
            drag: None,
            export: None,
            export_fields: export::ExportFields::default(),
            control_eval: ControlEval::Auto,
            // Replaced just below by the real first state, which needs the rest of `ready`.
            history: History::new(Snapshot {
                pairs: Vec::new(),
                settings: ViewSettings::default(),
                layers: [LayerLook {
                    preset: warpbench_gpu::Preset::GreyRamp,
                    window: warpbench_gpu::Window::from_range(0.0, 1.0),
                    visible: true,
                }; 2],
                volumes: placeholder_volumes,
            }),
        };
        ready.reset_camera();
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
    /// than the method needs, the moving volume is shown unwarped and the status bar says why. Then the diagnostics:
    /// residuals, leave-one-out errors and folding.
    pub fn refit(&mut self) {
        self.fit(true);
    }

    /// Fits again once this frame is over ([`Self::refit`]): a change of the document reaches the autosave
    /// before the fit and its diagnostics (many fits on a CPU) run, so what a crash can take is only the time of
    /// the write.
    pub fn refit_soon(&mut self) {
        self.fit_pending = true;
        self.invalidate();
    }

    /// Runs the fit [`Self::refit_soon`] asked for; true when there was one.
    pub fn fit_if_pending(&mut self) -> bool {
        let pending = std::mem::take(&mut self.fit_pending);
        if pending {
            self.refit();
        }
        pending
    }

    /// The fit of [`Self::refit`] without leave-one-out and folding (N more fits and a Jacobian grid): what a drag
    /// event runs, so that the warp follows the pointer; the diagnostics follow when the drag ends.
    pub fn refit_interactive(&mut self) {
        self.fit(false);
    }

    fn fit(&mut self, diagnostics: bool) {
        self.invalidate();
        let method = self.settings.method();
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
        if diagnostics {
            self.errors = vec![None; self.loaded.pairs.len()];
        }
        // The pairs are checked once here, so that refusals and warnings number them as the table does (the
        // fits below check them again, numbered among the pairs they get).
        let row = |n: usize| used.get(n.wrapping_sub(1)).map_or(n, |&i| i + 1);
        match method.check(&fixed, &moving) {
            Ok(warnings) => {
                self.fit_warnings = warnings.into_iter().map(|w| w.renumber(row).to_string()).collect();
            }
            Err(e) => {
                self.viewer.set_control(None);
                self.fitted = None;
                self.jacobian = None;
                self.fit_warnings.clear();
                self.fit_error = Some(format!("{method}: {}", e.renumber(row)));
                return;
            }
        }
        let boxes = (fixed_box, moving_box);
        let on_gpu = gpu_evaluates(&method)
            && match self.control_eval {
                ControlEval::Auto => !self.viewer.ctx.is_cpu_driver(),
                ControlEval::Cpu => false,
                ControlEval::Gpu => true,
            };
        let result = if on_gpu {
            fit_warp_on_gpu(&method, &fixed, &moving, boxes, self.settings.grid_n, &mut self.viewer)
        } else {
            let filterable = self.viewer.ctx.capabilities.float32_filterable;
            fit_warp(&method, &fixed, &moving, boxes, self.settings.grid_n, filterable).map(|(f, prepared)| {
                self.viewer.set_control(Some(&prepared));
                f
            })
        };
        match result {
            Ok(fitted) if !diagnostics => {
                // Keep the last diagnostics until the drag ends.
                self.errors.resize(self.loaded.pairs.len(), None);
                self.fitted = Some(fitted);
                self.fit_error = None;
            }
            Ok(fitted) => {
                // Residuals of the pull-back at the targets, and leave-one-out errors (refits without each pair).
                let residuals = residuals(fitted.pullback.as_ref(), &fixed, &moving);
                // TPS in closed form from the one fit; the other methods refit without each pair.
                let loo = method.leave_one_out(&fixed, &moving, fixed_box, Parallelism::Rayon);
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

    /// Carries out a file action of the side panel or the File menu; the outcome goes to `file_message`.
    pub fn file_action(&mut self, ctx: &egui::Context, action: panels::FileAction) {
        use panels::FileAction;
        match action {
            FileAction::None => {}
            FileAction::SaveSession(path) => {
                let file = self.to_session(true);
                self.file_message = Some(match session::save(&path, &file) {
                    Ok(()) => format!("saved {}", path.display()),
                    Err(e) => format!("{e:#}"),
                });
            }
            FileAction::ExportLandmarks(path) => {
                self.file_message = Some(match panels::export_landmarks(&path, &self.loaded.pairs) {
                    Ok(()) => format!("wrote {}", path.display()),
                    Err(e) => format!("{e:#}"),
                });
            }
            FileAction::Screenshot(path) => {
                // The window as it is drawn this frame, saved when the integration hands the pixels over.
                ctx.request_screenshot(move |image| {
                    if let Err(e) = save_png(&path, &image) {
                        eprintln!("warpbench: {e:#}");
                    }
                });
                self.file_message = Some("screenshot requested".into());
            }
            FileAction::ImportLandmarks(path) => match panels::import_landmarks(&path) {
                Ok(pairs) => {
                    self.file_message = Some(format!("read {} pairs from {}", pairs.len(), path.display()));
                    self.loaded.pairs = pairs;
                    self.refit_soon();
                }
                Err(e) => self.file_message = Some(format!("{e:#}")),
            },
            FileAction::ExportWarped(path) => self.start_export(ctx, export::ExportKind::Warped { dicom: None }, path),
            FileAction::ExportField(path) => self.start_export(ctx, export::ExportKind::Field, path),
        }
    }

    /// Starts exporting the warped moving volume or the displacement field to `out` on a worker thread (one
    /// export at a time), with the current pairs and method.
    pub fn start_export(&mut self, ctx: &egui::Context, kind: export::ExportKind, out: PathBuf) {
        if self.export.is_some() {
            self.file_message = Some("an export is running: wait for it or cancel it".into());
            return;
        }
        let input = export::ExportInput {
            fixed: Arc::clone(&self.loaded.fixed),
            moving: Arc::clone(&self.loaded.moving),
            fixed_path: self.loaded.fixed_path.clone(),
            moving_path: self.loaded.moving_path.clone(),
            pairs: self.loaded.pairs.clone(),
            method: self.settings.method(),
        };
        match export::ExportJob::start(ctx, kind, out, input) {
            Ok(job) => {
                self.file_message = None;
                self.export = Some(job);
            }
            Err(e) => self.file_message = Some(e),
        }
    }

    /// Replaces one side of the pair with `volume` read from `path` (`layer`: prepared for the GPU on the reading
    /// thread, else here): that side's GPU resources, the views re-centred on a new fixed volume, and the warp fitted
    /// again. The landmarks stay (their points are in patient space).
    pub fn replace_volume(
        &mut self,
        side: open::Side,
        volume: Arc<Volume>,
        layer: Option<LayerData>,
        path: PathBuf,
    ) -> anyhow::Result<()> {
        self.swap_volume(side, VolumeRef { volume, path: Some(path) }, layer)?;
        self.refit_soon();
        Ok(())
    }

    /// Shows `to` on `side` (prepared as `layer`, else here) without fitting again: the GPU layer (with the volume's
    /// automatic look), the title, and for the fixed side the camera and slices re-centred.
    fn swap_volume(&mut self, side: open::Side, to: VolumeRef, layer: Option<LayerData>) -> anyhow::Result<()> {
        let layer = match layer {
            Some(layer) => layer,
            None => LayerData::prepare(&to.volume, DeviceFacts::of(&self.viewer.ctx))?,
        };
        self.viewer.replace_layer(side == open::Side::Fixed, &layer)?;
        match side {
            open::Side::Fixed => (self.loaded.fixed, self.loaded.fixed_path) = (to.volume, to.path),
            open::Side::Moving => (self.loaded.moving, self.loaded.moving_path) = (to.volume, to.path),
        }
        let name = |p: &Option<PathBuf>| p.as_deref().map_or_else(|| "(demo)".to_owned(), open::file_name);
        self.loaded.title = format!("{} -> {}", name(&self.loaded.fixed_path), name(&self.loaded.moving_path));
        if side == open::Side::Fixed {
            let (lo, hi) = self.viewer.scene_box();
            let (azimuth, elevation) = (self.camera.azimuth_rad, self.camera.elevation_rad);
            self.camera = OrbitCamera::fit(lo, hi, self.camera.projection);
            (self.camera.azimuth_rad, self.camera.elevation_rad) = (azimuth, elevation);
            let mid = (lo + hi) * 0.5;
            self.slice_mm = [f64::from(mid.z), f64::from(mid.y), f64::from(mid.x)];
        }
        self.images = Images::default();
        Ok(())
    }

    /// Where pair `i`'s `end` is drawn, ref mm: the fixed point as is, the moving point through the forward warp
    /// (where the deformed moving volume shows it).
    #[must_use]
    pub fn glyph_ref(&self, i: usize, end: End) -> Option<[f64; 3]> {
        let p = self.loaded.pairs.get(i)?;
        match end {
            End::Fixed => p.fixed.map(|q| q.coords()),
            End::Moving => p.moving.map(|m| match &self.fitted {
                Some(f) => f.forward.apply(as_moving(m)).coords(),
                None => m.coords(),
            }),
        }
    }

    /// The landmark glyph nearest `pointer` within [`GRAB_RADIUS`], given where each glyph lands on screen
    /// (`screen`: ref mm to screen points, `None` when not shown there).
    fn grab(&self, pointer: egui::Pos2, screen: impl Fn([f64; 3]) -> Option<egui::Pos2>) -> Option<(usize, End)> {
        let mut best: Option<(f32, usize, End)> = None;
        for i in 0..self.loaded.pairs.len() {
            for end in [End::Fixed, End::Moving] {
                let Some(at) = self.glyph_ref(i, end).and_then(&screen) else { continue };
                let d = at.distance(pointer);
                if d <= GRAB_RADIUS && best.is_none_or(|(b, ..)| d < b) {
                    best = Some((d, i, end));
                }
            }
        }
        best.map(|(_, i, end)| (i, end))
    }

    /// Moves the dragged point so that it is shown at `x_ref`: the fixed point to x_ref, the moving point to
    /// u(x_ref) (the moving point the warp shows there) unless a pick gives it (`moving_lps`). Refits interactively.
    fn drag_to(&mut self, x_ref: [f64; 3], moving_lps: Option<[f64; 3]>) {
        let Some(drag) = self.drag else { return };
        let moving = moving_lps.unwrap_or_else(|| self.moving_shown_at(x_ref));
        let (volume, p) = match drag.end {
            End::Fixed => (&self.loaded.fixed, x_ref),
            End::Moving => (&self.loaded.moving, moving),
        };
        // Off its volume the point stays where it was.
        if let Some(message) = placement::outside_message(drag.end, volume, p) {
            self.notice = Some(message);
            return;
        }
        self.notice = None;
        let Some(pair) = self.loaded.pairs.get_mut(drag.pair) else { return };
        match drag.end {
            End::Fixed => pair.fixed = Some(Point3::from_array(x_ref)),
            End::Moving => pair.moving = Some(Point3::from_array(moving)),
        }
        self.refit_interactive();
    }

    /// Ends a drag: the full fit with its diagnostics.
    fn end_drag(&mut self) {
        if self.drag.take().is_some() {
            self.refit_soon();
        }
    }

    /// A drag event in the 3-D view at framebuffer point `pixel`: the dragged point follows the surface under the
    /// pointer (the volume it belongs to, picked with the current probe); off the volume it stays.
    fn drag_in_view(&mut self, pixel: [f32; 2]) {
        let Some(drag) = self.drag else { return };
        let Some(size) = self.images.view.as_ref().map(|v| (v.target.width, v.target.height)) else { return };
        let target = match drag.end {
            End::Moving => PickTarget::Moving,
            End::Fixed => PickTarget::Fixed,
        };
        let settings = self.settings.render_settings();
        match self.viewer.pick(&self.camera, &settings, size, pixel, target, self.settings.probe()) {
            Ok(Some(hit)) => {
                let moving = matches!(target, PickTarget::Moving).then(|| hit.p_lps.map(f64::from));
                self.drag_to(hit.x_ref.map(f64::from), moving);
            }
            Ok(None) => {}
            Err(e) => self.fit_error = Some(format!("picking: {e:#}")),
        }
    }

    /// Number of pairs the current warp was fitted on.
    #[must_use]
    pub fn fitted_pairs(&self) -> usize {
        self.fitted.as_ref().map_or(0, |f| f.pairs)
    }

    /// The landmark glyphs drawn over the views (none when landmarks are hidden).
    #[must_use]
    pub fn glyphs(&self) -> Vec<GlyphInstance> {
        if !self.settings.show_landmarks {
            return Vec::new();
        }
        let to_vec = |c: [f64; 3]| Vec3::from_array(c.map(|v| v as f32));
        let pairs: Vec<GlyphPair> = self
            .loaded
            .pairs
            .iter()
            .enumerate()
            .map(|(i, p)| GlyphPair {
                moving_ref: p.moving.map(|m| match &self.fitted {
                    Some(f) => to_vec(f.forward.apply(as_moving(m)).coords()),
                    None => to_vec(m.coords()),
                }),
                fixed_ref: p.fixed.map(|q| to_vec(q.coords())),
                selected: self.selected == Some(i),
                active: p.active,
            })
            .collect();
        pair_glyphs(&pairs, &GlyphStyle::default())
    }

    /// Slice view `a`'s plane (0 axial, 1 coronal, 2 sagittal).
    #[must_use]
    pub fn slice_plane(&self, a: usize) -> SlicePlane {
        self.slice_planes()[a.min(2)]
    }

    /// The three slice planes: grid planes of the fixed volume through the crosshair, or oblique planes turned
    /// about it (same pixel size and image size as the grid plane).
    fn slice_planes(&self) -> [SlicePlane; 3] {
        let f = &self.loaded.fixed;
        let m = f.lps_from_index.rows();
        let grid = [
            SlicePlane::axial(&m, f.dims, self.slice_mm[0]),
            SlicePlane::coronal(&m, f.dims, self.slice_mm[1]),
            SlicePlane::sagittal(&m, f.dims, self.slice_mm[2]),
        ];
        let crosshair = [self.slice_mm[2], self.slice_mm[1], self.slice_mm[0]];
        std::array::from_fn(|a| {
            let (plane, o) = (grid[a], self.settings.oblique[a]);
            if !o.on {
                return plane;
            }
            oblique_plane(&plane, crosshair, o).unwrap_or(plane)
        })
    }

    /// Renders what changed (the 3-D view at `view_px`, the slices) and hands the images to egui.
    ///
    /// On a GPU a changed view is drawn again at once: at the interaction sample rate while the user interacts
    /// (`interacting`: a button is held), fully otherwise. On a CPU driver a changed view is drawn reduced (the
    /// interaction rate, at a size that renders in about [`pacing::INTERACTIVE_BUDGET_MS`]), and then each frame
    /// renders one band of the full view until it is done and shown ([`pacing`]).
    fn render(
        &mut self,
        rs: &eframe::egui_wgpu::RenderState,
        view_px: (u32, u32),
        interacting: bool,
    ) -> anyhow::Result<()> {
        let cpu = self.viewer.ctx.is_cpu_driver();
        let shown_size = self.images.view.as_ref().map(|v| (v.target.width, v.target.height));
        let refine_size = self.images.refine.as_ref().map(Refine::size);
        let stale = self.images.view_dirty
            || (shown_size != Some(view_px) && !self.images.view_reduced)
            || refine_size.is_some_and(|s| s != view_px);
        let refine = self.images.view_reduced && (cpu || !interacting);
        if !stale && !refine && !self.images.slices_dirty {
            return Ok(());
        }
        let start = std::time::Instant::now();
        self.viewer.begin_frame();
        self.viewer.sync_presets();
        let glyphs = self.glyphs();
        let settings = self.settings.render_settings();
        if stale {
            self.images.refine = None;
            let (quality, px) = if interacting || cpu {
                let measured = self.images.view_ms_per_px.or(Some(pacing::CPU_GUESS_MS_PER_PX));
                (Quality::Interactive, interactive_size(view_px, if cpu { measured } else { None }))
            } else {
                (Quality::Full, view_px)
            };
            let target = self.viewer.render_view(&self.camera, &settings, quality, px, &glyphs)?;
            self.images.view = Some(viewer::show(rs, target, self.images.view.take()));
            self.images.view_reduced = quality != Quality::Full;
            self.images.view_dirty = false;
        } else if refine && !cpu {
            let target = self.viewer.render_view(&self.camera, &settings, Quality::Full, view_px, &glyphs)?;
            self.images.view = Some(viewer::show(rs, target, self.images.view.take()));
            self.images.view_reduced = false;
        } else if refine {
            self.refine_band(rs, view_px, &settings, &glyphs)?;
        }
        if self.images.slices_dirty {
            let planes = self.slice_planes();
            for (slot, plane) in self.images.slices.iter_mut().zip(planes) {
                let target = self.viewer.render_slice(&plane, &settings, &glyphs)?;
                *slot = Some(viewer::show(rs, target, slot.take()));
            }
            self.images.slices_dirty = false;
        }
        self.viewer.ctx.check_errors().map_err(|e| anyhow!("{e}"))?;
        self.last_render_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }

    /// Renders the next band of the full 3-D view on a CPU driver, waits for it (so that it is measured and the UI
    /// frame does not queue behind more than one band), and shows the view once the last band is done.
    fn refine_band(
        &mut self,
        rs: &eframe::egui_wgpu::RenderState,
        view_px: (u32, u32),
        settings: &warpbench_gpu::RenderSettings,
        glyphs: &[warpbench_gpu::GlyphInstance],
    ) -> anyhow::Result<()> {
        let refine = self.images.refine.get_or_insert_with(|| Refine::new(self.viewer.view_target(view_px)));
        let band = refine.bands.next(self.images.view_ms_per_px);
        let band_start = std::time::Instant::now();
        self.viewer.render_view_rows(&self.camera, settings, Quality::Full, &refine.target, band.clone())?;
        self.viewer.ctx.wait_idle().map_err(|e| anyhow!("{e}"))?;
        refine.bands.rendered(&band, band_start.elapsed().as_secs_f64() * 1e3);
        if refine.bands.done()
            && let Some(done) = self.images.refine.take()
        {
            self.images.view_ms_per_px = done.bands.ms_per_px();
            self.viewer.draw_view_glyphs(&self.camera, &done.target, glyphs)?;
            self.images.view = Some(viewer::show(rs, done.target, self.images.view.take()));
            self.images.view_reduced = false;
        }
        Ok(())
    }

    /// On a CPU driver, how much of the full 3-D view is rendered while it is rendered band by band (0..1).
    #[must_use]
    pub fn view_refine_progress(&self) -> Option<f32> {
        self.images.refine.as_ref().map(|r| r.bands.progress())
    }

    /// The 3-D view's image shown now, read back (premultiplied RGBA8, rows top to bottom).
    pub fn read_view(&self) -> anyhow::Result<Vec<u8>> {
        let shown = self.images.view.as_ref().context("no 3-D view is shown")?;
        shown.target.read_back(&self.viewer.ctx).map_err(|e| anyhow!("{e}"))
    }

    /// The size of the 3-D view's image shown now, and whether it is the full-quality one.
    #[must_use]
    pub fn view_shown(&self) -> Option<((u32, u32), bool)> {
        let v = self.images.view.as_ref()?;
        Some(((v.target.width, v.target.height), !self.images.view_reduced))
    }

    /// Starts adding a pair (the next pick is its source), or stops (a placed source is dropped).
    pub fn toggle_adding(&mut self) {
        self.placing = if self.placing == Placing::Idle { Placing::Source } else { Placing::Idle };
    }

    /// Deletes pair `i` and fits the warp again.
    pub fn delete_pair(&mut self, i: usize) {
        if i < self.loaded.pairs.len() {
            self.loaded.pairs.remove(i);
            self.selected = None;
            self.refit_soon();
        }
    }

    /// Puts the camera back: the whole fixed volume in view, from the front-left, slightly above.
    pub fn reset_camera(&mut self) {
        let (lo, hi) = self.viewer.scene_box();
        self.camera = OrbitCamera::fit(lo, hi, self.camera.projection);
        self.camera.azimuth_rad = 0.6;
        self.camera.elevation_rad = 0.25;
        self.invalidate_view();
    }

    /// Places the point at ref position `x_ref` (a click in a slice, or a pick in the 3-D view, already in ref
    /// space): the source through the warp's pull-back (the moving volume's point shown there) unless the pick gives
    /// it (`moving_lps`), the target as is. A completed pair is appended, active, and the warp is fitted again.
    ///
    /// A point outside its volume is refused: nothing is stored, the step stays, and [`Self::notice`] says why.
    pub fn place_at_ref(&mut self, x_ref: [f64; 3], moving_lps: Option<[f64; 3]>) {
        match self.placing {
            Placing::Idle => {}
            Placing::Source => {
                let p = moving_lps.unwrap_or_else(|| self.moving_shown_at(x_ref));
                if let Some(message) = placement::outside_message(End::Moving, &self.loaded.moving, p) {
                    self.notice = Some(message);
                    return;
                }
                self.notice = None;
                self.placing = Placing::Target { moving: Point3::from_array(p) };
            }
            Placing::Target { moving } => {
                if let Some(message) = placement::outside_message(End::Fixed, &self.loaded.fixed, x_ref) {
                    self.notice = Some(message);
                    return;
                }
                self.notice = None;
                let name = format!("Pt-{}", self.loaded.pairs.len() + 1);
                self.loaded.pairs.push(LandmarkPair::new(name, moving, Point3::from_array(x_ref)));
                self.placing = Placing::Idle;
                self.refit_soon();
            }
        }
        self.invalidate();
    }

    /// The moving point the warp shows at ref point `x_ref`: u(x_ref) through the pull-back (the identity before a
    /// warp is fitted).
    #[must_use]
    pub fn moving_shown_at(&self, x_ref: [f64; 3]) -> [f64; 3] {
        match &self.fitted {
            Some(f) => f.pullback.apply_raw(x_ref),
            None => x_ref,
        }
    }

    /// What the status bar shows for ref point `x_ref` under the pointer.
    #[must_use]
    pub fn cursor_at(&self, x_ref: [f64; 3]) -> placement::Cursor {
        placement::Cursor { fixed_lps: x_ref, moving_lps: self.moving_shown_at(x_ref) }
    }

    /// A click at framebuffer point `pixel` of the 3-D view: picks the volume the placing step asks for.
    fn pick_in_view(&mut self, pixel: [f32; 2]) {
        let target = match self.placing {
            Placing::Idle => return,
            Placing::Source => PickTarget::Moving,
            Placing::Target { .. } => PickTarget::Fixed,
        };
        let Some(size) = self.images.view.as_ref().map(|v| (v.target.width, v.target.height)) else { return };
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
        self.selected = Some(i);
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
                oblique: s.oblique.map(|o| session::SessionOblique {
                    on: o.on,
                    tilt_deg: o.tilt_deg,
                    spin_deg: o.spin_deg,
                }),
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
        s.oblique = st.oblique.map(|o| panels::Oblique {
            on: o.on,
            tilt_deg: o.tilt_deg.clamp(-75.0, 75.0),
            spin_deg: o.spin_deg.clamp(-75.0, 75.0),
        });
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
        let volume = |v: &Arc<Volume>, path: &Option<PathBuf>| VolumeRef { volume: Arc::clone(v), path: path.clone() };
        Snapshot {
            pairs: self.loaded.pairs.clone(),
            settings: self.settings.clone(),
            layers: [look(&self.viewer.fixed), look(&self.viewer.moving)],
            volumes: [
                volume(&self.loaded.fixed, &self.loaded.fixed_path),
                volume(&self.loaded.moving, &self.loaded.moving_path),
            ],
        }
    }

    /// Puts `s` back: the volumes (prepared again for the GPU when they differ), pairs, settings and looks; fits
    /// the warp again.
    fn restore(&mut self, s: &Snapshot) {
        let now = self.snapshot();
        for (side, (was, is)) in
            [open::Side::Fixed, open::Side::Moving].into_iter().zip(s.volumes.iter().zip(&now.volumes))
        {
            if was != is
                && let Err(e) = self.swap_volume(side, was.clone(), None)
            {
                self.file_message = Some(format!("restoring the {} volume: {e:#}", side.name()));
            }
        }
        self.loaded.pairs.clone_from(&s.pairs);
        self.settings = s.settings.clone();
        for (layer, look) in [&mut self.viewer.fixed, &mut self.viewer.moving].into_iter().zip(s.layers) {
            (layer.preset, layer.window, layer.visible) = (look.preset, look.window, look.visible);
        }
        self.placing = Placing::Idle;
        self.refit_soon();
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

    /// Marks the 3-D view and the slices for re-rendering.
    pub fn invalidate(&mut self) {
        self.images.view_dirty = true;
        self.images.slices_dirty = true;
    }

    /// Marks the 3-D view only (the camera moved).
    pub fn invalidate_view(&mut self) {
        self.images.view_dirty = true;
    }

    /// Marks the slices only (a slice moved or turned).
    pub fn invalidate_slices(&mut self) {
        self.images.slices_dirty = true;
    }

    /// Whether something waits to be rendered.
    #[must_use]
    pub fn needs_render(&self) -> bool {
        self.images.view_dirty || self.images.slices_dirty || self.images.view_reduced
    }
}

impl eframe::App for Workbench {
    fn on_exit(&mut self) {
        if let Phase::Ready(ready) = &self.phase {
            let file = ready.to_session(true);
            self.autosave.finish(&file);
        }
    }

    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.poll_loading();
        self.poll_volume_jobs();
        let ctx = ui.ctx().clone();
        let mut events = Vec::new();
        egui::Panel::top("menu").show(ui, |ui| {
            egui::MenuBar::new().ui(ui, |ui| {
                let ready = matches!(self.phase, Phase::Ready(_));
                events.extend(open::file_menu(ui, ready, self.dialogs.dialog.is_some()));
            });
        });
        if !self.jobs.is_empty() {
            egui::Panel::top("reading").show(ui, |ui| {
                for job in &self.jobs {
                    ui.label(format!("Opening {} as the {} volume", open::file_name(&job.path), job.side.name()));
                    open::progress_ui(ui, &job.watch);
                }
            });
        }
        events.extend(self.dialogs.take_dropped(&ctx));
        events.extend(self.dialogs.ui(&ctx));
        for event in events {
            self.handle(&ctx, event);
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
                    self.phase = Self::start_loading(&ctx, opts, self.facts);
                }
                Some(false) => self.recovery = None,
                None => {}
            }
        }
        let render_state = self.render_state.clone();
        let mut open_demo = false;
        match &mut self.phase {
            Phase::Loading { watch, .. } => {
                egui::CentralPanel::default().show(ui, |ui| {
                    ui.label("Loading the volumes...");
                    open::progress_ui(ui, watch);
                });
            }
            Phase::Failed(message) => {
                egui::CentralPanel::default().show(ui, |ui| {
                    ui.heading("No volumes are open");
                    ui.label(message.as_str());
                    ui.label("Open a fixed and a moving volume from the File menu, drop them on the window, or:");
                    open_demo = ui.button("Open the demo pair").clicked();
                });
            }
            Phase::Ready(ready) => {
                workbench_ui(ui, ready, render_state.as_ref(), &mut self.autosave);
                self.ready_frames += 1;
            }
        }
        if open_demo {
            self.phase = Self::start_loading(&ctx, GuiOptions::default(), self.facts);
        }
        self.autosave_changes(&ctx);
        if let Phase::Ready(ready) = &mut self.phase
            && ready.fit_if_pending()
        {
            ctx.request_repaint();
        }
        // Counted once the views are rendered fully (on a CPU driver the 3-D view is refined over many frames).
        let rendered = matches!(&self.phase, Phase::Ready(r) if !r.needs_render());
        if let (Some(n), false) = (self.exit_after_frames, self.screenshot_requested)
            && self.ready_frames >= n
            && rendered
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
        if matches!(self.phase, Phase::Loading { .. })
            || !self.jobs.is_empty()
            || self.dialogs.dialog.is_some()
            || self.exit_after_frames.is_some()
        {
            ui.ctx().request_repaint();
        }
    }
}

/// Hands the document as it is now to the autosave ([`autosave::Autosave::observe`]), coalescing while the pointer
/// is held.
fn autosave_changes(autosave: &mut autosave::Autosave, ctx: &egui::Context, ready: &Ready) {
    let file = ready.to_session(false);
    let held = ctx.input(|i| i.pointer.any_down()) || ready.drag.is_some();
    if let Some(wait) = autosave.observe(std::time::Instant::now(), &file, held) {
        ctx.request_repaint_after(wait);
    }
}

/// The keyboard shortcuts, as in BigWarp and Slicer where they have one: Ctrl+Z / Ctrl+Shift+Z undo and redo,
/// Space starts or stops adding a pair, Esc cancels it (or clears the selection), Delete removes the selected pair,
/// R resets the camera. The single keys only act while no text field has the keyboard.
fn keyboard(ui: &mut egui::Ui, ready: &mut Ready) {
    // Redo first: Ctrl+Shift+Z also matches Ctrl+Z logically.
    let redo = egui::KeyboardShortcut::new(egui::Modifiers::COMMAND | egui::Modifiers::SHIFT, egui::Key::Z);
    let undo = egui::KeyboardShortcut::new(egui::Modifiers::COMMAND, egui::Key::Z);
    if ui.input_mut(|i| i.consume_shortcut(&redo)) {
        ready.redo();
    } else if ui.input_mut(|i| i.consume_shortcut(&undo)) {
        ready.undo();
    }
    if ui.ctx().egui_wants_keyboard_input() {
        return;
    }
    let key = |ui: &mut egui::Ui, k: egui::Key| ui.input_mut(|i| i.consume_key(egui::Modifiers::NONE, k));
    if key(ui, egui::Key::Space) {
        ready.toggle_adding();
    }
    if key(ui, egui::Key::Escape) {
        if ready.placing == Placing::Idle {
            ready.selected = None;
        } else {
            ready.placing = Placing::Idle;
        }
        ready.invalidate();
    }
    if (key(ui, egui::Key::Delete) || key(ui, egui::Key::Backspace))
        && let Some(i) = ready.selected
    {
        ready.delete_pair(i);
    }
    if key(ui, egui::Key::R) {
        ready.reset_camera();
    }
}

/// The window once the pair is loaded: side panel, status bar, slice strip and the 3-D view.
fn workbench_ui(
    ui: &mut egui::Ui,
    ready: &mut Ready,
    render_state: Option<&eframe::egui_wgpu::RenderState>,
    autosave: &mut autosave::Autosave,
) {
    ready.frame_rate.tick(std::time::Instant::now());
    if let Some(job) = &ready.export {
        match job.poll() {
            Some(result) => {
                ready.file_message = Some(result.unwrap_or_else(|e| e));
                ready.export = None;
            }
            None => ui.ctx().request_repaint_after(std::time::Duration::from_millis(100)),
        }
    }
    keyboard(ui, ready);
    egui::Panel::left("settings").resizable(true).default_size(260.0).show(ui, |ui| {
        egui::ScrollArea::vertical().show(ui, |ui| {
            ui.heading(ready.loaded.title.as_str());
            ui.horizontal(|ui| {
                if ui.add_enabled(ready.history.can_undo(), egui::Button::new("Undo")).on_hover_text("Ctrl+Z").clicked()
                {
                    ready.undo();
                }
                let redo = egui::Button::new("Redo");
                if ui.add_enabled(ready.history.can_redo(), redo).on_hover_text("Ctrl+Shift+Z").clicked() {
                    ready.redo();
                }
                if ui.button("Reset camera").on_hover_text("R").clicked() {
                    ready.reset_camera();
                }
            });
            let change = panels::settings_ui(ui, &mut ready.settings);
            if change.refit {
                ready.refit_soon();
            } else if change.redraw {
                ready.invalidate();
            }
            ui.separator();
            if panels::layers_ui(ui, &mut ready.viewer.fixed, &mut ready.viewer.moving) {
                ready.invalidate();
            }
            panels::volume_warnings_ui(ui, &ready.loaded.fixed, &ready.loaded.moving);
            ui.separator();
            ui.horizontal(|ui| {
                let adding = ready.placing != Placing::Idle;
                if ui.selectable_label(adding, "Add pair").on_hover_text("Space; Esc cancels").clicked() {
                    ready.toggle_adding();
                }
                match ready.placing {
                    Placing::Idle => ui.label(""),
                    Placing::Source => ui.label("click the point on the moving volume"),
                    Placing::Target { .. } => ui.label("click its partner on the fixed volume"),
                };
            });
            match panels::landmarks_ui(ui, &mut ready.loaded.pairs, &ready.errors, ready.selected) {
                panels::LandmarkAction::None => {}
                panels::LandmarkAction::Refit => ready.refit_soon(),
                panels::LandmarkAction::Delete(i) => ready.delete_pair(i),
                panels::LandmarkAction::Jump(i) => ready.jump_to(i),
                panels::LandmarkAction::Select(i) => {
                    ready.selected = Some(i);
                    ready.invalidate();
                }
            }
            for w in &ready.fit_warnings {
                ui.colored_label(egui::Color32::from_rgb(240, 200, 80), format!("Warning: {w}"));
            }
            ui.separator();
            if let Some(i) = panels::accuracy_ui(ui, &ready.loaded.pairs, &ready.errors) {
                ready.jump_to(i);
            }
            ui.separator();
            let action = panels::files_ui(ui, &mut ready.files);
            ready.file_action(ui.ctx(), action);
            ui.separator();
            if let Some((kind, out)) = export::export_ui(ui, &mut ready.export_fields, ready.export.as_ref()) {
                ready.start_export(ui.ctx(), kind, out);
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
            ui.label(format!("last frame {:.0} ms", ready.last_render_ms))
                .on_hover_text("What the views took to render in the last frame that rendered them");
            ui.separator();
            ui.label(ready.frame_rate.fps().map_or_else(|| "idle".to_owned(), |f| format!("{f:.0} fps")))
                .on_hover_text("Frames the window drew in the last second (none while nothing changes)");
            // An idle window draws nothing: one more frame once this second is over shows it idle.
            if let Some(wait) = ready.frame_rate.redraw_to_idle_in(std::time::Instant::now()) {
                ui.ctx().request_repaint_after(wait);
            }
            ui.separator();
            if let Some(done) = ready.view_refine_progress() {
                ui.label(format!("refining the 3-D view: {:.0} %", 100.0 * done));
                ui.separator();
            }
            if let Some(c) = ready.cursor {
                let ([l, p, s], [ml, mp, ms]) = (c.fixed_lps, c.moving_lps);
                ui.label(format!(
                    "cursor LPS fixed ({l:.1}, {p:.1}, {s:.1}) mm, moving ({ml:.1}, {mp:.1}, {ms:.1}) mm"
                ))
                .on_hover_text("The fixed point under the pointer, and the moving point the warp shows there");
                ui.separator();
            }
            if let Some(n) = &ready.notice {
                ui.colored_label(egui::Color32::from_rgb(240, 200, 80), n.as_str());
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
        ready.cursor = None;
        ui.columns(3, |columns| {
            let names = ["Axial", "Coronal", "Sagittal"];
            for (a, col) in columns.iter_mut().enumerate() {
                col.label(names[a]);
                let before = ready.slice_mm[a];
                // Narrow columns: the slider leaves room for its value field; its name is for screen readers.
                col.spacing_mut().slider_width = (col.available_width() - 64.0).max(40.0);
                let slider = col.add(egui::Slider::new(&mut ready.slice_mm[a], -150.0..=150.0).suffix(" mm"));
                let slider_name = format!("{} position", names[a]);
                slider.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Slider, true, &slider_name));
                if (ready.slice_mm[a] - before).abs() > f64::EPSILON {
                    ready.invalidate_slices();
                }
                if panels::oblique_ui(col, names[a], &mut ready.settings.oblique[a]) {
                    ready.invalidate_slices();
                }
                if let Some(shown) = &ready.images.slices[a] {
                    let avail = col.available_size();
                    let (w, h) = (shown.target.width as f32, shown.target.height as f32);
                    let scale = (avail.x / w).min(avail.y.max(64.0) / h);
                    // The image exactly fills the rect the response reports, so that pointer positions map to
                    // pixels one to one.
                    let size = egui::vec2(w, h) * scale;
                    // (Not justified: the response covers the image and nothing more.)
                    let (rect, response) = col
                        .with_layout(egui::Layout::top_down(egui::Align::Min), |ui| {
                            ui.allocate_exact_size(size, egui::Sense::click_and_drag())
                        })
                        .inner;
                    egui::Image::new(egui::load::SizedTexture::new(shown.texture_id, size)).paint_at(col, rect);
                    let label = format!("{} slice", names[a]);
                    response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, &label));
                    // The ref point under a window position, only when it is over the image ([`placement`]).
                    let image_rect = response.rect;
                    let to_ref = |pos: egui::Pos2| placement::slice_point(&planes[a], image_rect, scale, pos);
                    if let Some(x_ref) = response.hover_pos().and_then(to_ref) {
                        ready.cursor = Some(ready.cursor_at(x_ref));
                    }
                    // Dragging a landmark within this plane: grab the glyph under the press.
                    let plane = planes[a];
                    let on_screen = |p_ref: [f64; 3]| {
                        plane
                            .pixel_from_ref(p_ref)
                            .filter(|q| q[2].abs() <= SLICE_SLAB_MM)
                            .map(|q| placement::slice_screen(image_rect, scale, q))
                    };
                    if response.drag_started()
                        && ready.placing == Placing::Idle
                        && let Some(press) = col.input(|i| i.pointer.press_origin())
                        && let Some((pair, end)) = ready.grab(press, on_screen)
                    {
                        ready.drag = Some(DragPoint { pair, end, view: DragView::Slice(a) });
                        ready.selected = Some(pair);
                    }
                    let dragging_here = ready.drag.is_some_and(|d| d.view == DragView::Slice(a));
                    if dragging_here && response.dragged() {
                        ready.dragging = true;
                        // Off the image the point stays where it was.
                        if let Some(x_ref) = response.interact_pointer_pos().and_then(to_ref) {
                            ready.drag_to(x_ref, None);
                        }
                    }
                    if dragging_here && response.drag_stopped() {
                        ready.dragging = false;
                        ready.end_drag();
                    }
                    if response.clicked()
                        && let Some(x_ref) = response.interact_pointer_pos().and_then(to_ref)
                    {
                        if ready.placing == Placing::Idle {
                            // Linked navigation: the other two slices move through the clicked point.
                            ready.slice_mm = [x_ref[2], x_ref[1], x_ref[0]];
                            ready.invalidate_slices();
                        } else {
                            ready.place_at_ref(x_ref, None);
                        }
                    }
                    // The crosshair: where the other two planes cut this one.
                    let centre = [ready.slice_mm[2], ready.slice_mm[1], ready.slice_mm[0]];
                    if let Some(q) = planes[a].pixel_from_ref(centre) {
                        let p = placement::slice_screen(image_rect, scale, q);
                        let stroke = egui::Stroke::new(1.0, egui::Color32::from_rgba_unmultiplied(255, 230, 90, 160));
                        let painter = col.painter_at(response.rect);
                        painter.hline(response.rect.x_range(), p.y, stroke);
                        painter.vline(p.x, response.rect.y_range(), stroke);
                    }
                }
            }
        });
    });
    // What the panels changed reaches the disk before the 3-D view renders (a second on a CPU driver).
    autosave_changes(autosave, ui.ctx(), ready);
    egui::CentralPanel::default().show(ui, |ui| {
        let avail = ui.available_size();
        let ppp = ui.ctx().pixels_per_point();
        // A GPU renders the view at the screen's pixels; a CPU driver (about 1 Mpixel·step per second) at most at
        // 1024² so that its reduced view (a quarter per side at least) still fits the frame budget.
        let cap = if ready.viewer.ctx.is_cpu_driver() { 1024.0 } else { 8192.0 };
        let px = (avail * ppp).min(egui::vec2(cap, cap)).max(egui::vec2(32.0, 32.0));
        let view_px = (px.x as u32, px.y as u32);
        let interacting = ui.input(|i| i.pointer.any_down()) || ready.dragging;
        if let Some(rs) = render_state
            && let Err(e) = ready.render(rs, view_px, interacting)
        {
            ready.fit_error = Some(format!("rendering: {e:#}"));
        }
        if let Some(shown) = &ready.images.view {
            let response = ui.add(
                egui::Image::new(egui::load::SizedTexture::new(shown.texture_id, avail))
                    .sense(egui::Sense::click_and_drag()),
            );
            response.widget_info(|| egui::WidgetInfo::labeled(egui::Role::Image, true, "3-D view"));
            let (w, h) = (shown.target.width as f32, shown.target.height as f32);
            let to_pixel = |pos: egui::Pos2| {
                let f = (pos - response.rect.min) / response.rect.size();
                [f.x * w, f.y * h]
            };
            if response.clicked()
                && let Some(pos) = response.interact_pointer_pos()
            {
                ready.pick_in_view(to_pixel(pos));
            }
            // A press on a landmark glyph drags it along the surface; elsewhere a drag orbits the camera.
            let clip_from_ref = ready.camera.clip_from_ref(w / h);
            let rect = response.rect;
            let on_screen = |p_ref: [f64; 3]| {
                let c = clip_from_ref * Vec3::from_array(p_ref.map(|v| v as f32)).extend(1.0);
                (c.w > 0.0).then(|| {
                    let (x, y) = (c.x / c.w, c.y / c.w);
                    rect.min + egui::vec2((x * 0.5 + 0.5) * rect.width(), (0.5 - y * 0.5) * rect.height())
                })
            };
            if response.drag_started()
                && ready.placing == Placing::Idle
                && let Some(press) = ui.input(|i| i.pointer.press_origin())
                && let Some((pair, end)) = ready.grab(press, on_screen)
            {
                ready.drag = Some(DragPoint { pair, end, view: DragView::ThreeD });
                ready.selected = Some(pair);
            }
            let landmark_drag = ready.drag.is_some_and(|d| d.view == DragView::ThreeD);
            if landmark_drag {
                if response.dragged()
                    && response.drag_delta() != egui::Vec2::ZERO
                    && let Some(pos) = response.interact_pointer_pos()
                {
                    ready.dragging = true;
                    ready.drag_in_view(to_pixel(pos));
                }
                if response.drag_stopped() {
                    ready.dragging = false;
                    ready.end_drag();
                }
            }
            let drag = if landmark_drag { egui::Vec2::ZERO } else { response.drag_delta() };
            let was_dragging = ready.dragging;
            ready.dragging = response.dragged();
            if drag != egui::Vec2::ZERO {
                ready.camera.azimuth_rad -= drag.x * 0.01;
                ready.camera.elevation_rad = (ready.camera.elevation_rad + drag.y * 0.01).clamp(-1.5, 1.5);
                ready.invalidate_view();
            }
            if was_dragging && !ready.dragging {
                // Back to the full sample rate once the drag ends.
                ready.invalidate_view();
            }
            if response.hovered() {
                let scroll = ui.input(|i| i.smooth_scroll_delta.y);
                if scroll != 0.0 {
                    ready.camera.zoom = (ready.camera.zoom * (1.0 + scroll * 0.002)).clamp(0.2, 20.0);
                    ready.invalidate_view();
                }
            }
        }
    });
    // A change becomes an undo step once it has settled (a slider drag is one step).
    if ready.placing == Placing::Idle && !ui.input(|i| i.pointer.any_down()) {
        let now = ready.snapshot();
        ready.history.record(&now);
    }
    if ready.needs_render() {
        ui.ctx().request_repaint();
    }
}

/// `plane` turned about `centre_ref` by the oblique view's tilt (about the image's horizontal axis) and spin (about
/// its vertical axis), keeping its pixel size and image size; `None` for a degenerate plane.
fn oblique_plane(plane: &SlicePlane, centre_ref: [f64; 3], o: panels::Oblique) -> Option<SlicePlane> {
    use warpbench_gpu::glam::{DQuat, DVec3};
    let u = DVec3::from_array(plane.u_ref);
    let up = -DVec3::from_array(plane.v_ref);
    let normal = DVec3::from_array(plane.normal_ref()?);
    let turn = DQuat::from_axis_angle(u.try_normalize()?, f64::from(o.tilt_deg).to_radians())
        * DQuat::from_axis_angle(up.try_normalize()?, f64::from(o.spin_deg).to_radians());
    SlicePlane::oblique(centre_ref, (turn * normal).to_array(), (turn * up).to_array(), u.length(), plane.size).ok()
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
