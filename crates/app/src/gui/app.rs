//! The eframe app: the window's phases (loading, failed, a pair shown), the volume reads for File > Open and drops,
//! the open dialogs, the recovery offer, the autosave, and the frame once a pair is shown (keyboard, side panel,
//! status bar, slices, 3-D view, then the undo step).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, TryRecvError};

use anyhow::{Context as _, anyhow};
use eframe::egui;
use warpbench_gpu::{OrbitCamera, Projection};
use warpbench_io::Volume;

use super::files::{Files, save_png};
use super::history::{History, Snapshot};
use super::load::{Loaded, LoadedPair, Opened};
use super::viewer::{DeviceFacts, LayerData, Viewer};
use super::{
    Command, Fitter, GuiOptions, Ready, autosave, files, landmark_panel, open, side_panel, status, toolbar, views,
};
use crate::project::document::Document;
use crate::project::session;

/// A volume read (and maybe prepared) for one side while the other is still being read.
#[derive(Debug)]
struct Pending {
    volume: Arc<Volume>,
    source: open::VolumeSource,
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
    /// `--frame-log`: one line per frame.
    frame_log: Option<super::frame_log::FrameLog>,
    /// The sessions opened or saved most recently (File > Open recent session), kept beside the autosave.
    recent: crate::project::recent::Recent,
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
        let mut recent = crate::project::recent::Recent::load(autosave_path.with_file_name("recent.json"));
        if let Some(path) = &opts.session {
            note_recent(&mut recent, path);
        }
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
            frame_log: None,
            recent,
        }
    }

    /// Writes one line per frame to `log` ([`super::frame_log`]).
    #[must_use]
    pub fn with_frame_log(mut self, log: Option<super::frame_log::FrameLog>) -> Self {
        self.frame_log = log;
        self
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
        if let Phase::Ready(ready) = &mut self.phase {
            autosave_changes(&mut self.autosave, ctx, ready);
            if let Some(path) = ready.files.saved_session.take() {
                note_recent(&mut self.recent, &path);
            }
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

    fn poll_loading(&mut self, ctx: &egui::Context) {
        let Phase::Loading { rx, .. } = &self.phase else { return };
        let loaded = match rx.try_recv() {
            Ok(result) => result,
            Err(TryRecvError::Empty) => return,
            Err(TryRecvError::Disconnected) => Err(anyhow!("the loading thread stopped")),
        };
        self.phase = match loaded.and_then(|l| self.upload(ctx, l)) {
            Ok(ready) => Phase::Ready(Box::new(ready)),
            Err(e) => Phase::Failed(format!("{e:#}")),
        };
    }

    /// Starts reading a volume for one side of the pair (File > Open, a drop, the series or frame chooser); a read
    /// already running for that side is cancelled.
    pub fn open_volume(&mut self, ctx: &egui::Context, side: open::Side, source: open::VolumeSource) {
        for job in self.jobs.iter().filter(|j| j.side == side) {
            job.watch.cancel();
        }
        self.jobs.retain(|j| j.side != side);
        self.jobs.push(open::VolumeJob::start(ctx, side, source, self.facts));
    }

    /// The volume reads still running (for tests).
    #[must_use]
    pub fn reading(&self) -> usize {
        self.jobs.len()
    }

    /// Takes finished reads: a volume replaces its side of the shown pair, or waits for the other side when no
    /// pair is shown; a failure opens the error dialog, or the series or frame chooser.
    fn poll_volume_jobs(&mut self, ctx: &egui::Context) {
        let mut finished = Vec::new();
        self.jobs.retain(|job| match job.poll() {
            Some(result) => {
                finished.push((job.side, job.source.clone(), result));
                false
            }
            None => true,
        });
        for (side, source, result) in finished {
            let (volume, layer) = match result {
                Ok(open::ReadVolume { layer: Some(Err(e)), .. }) => {
                    self.dialogs.error = Some(format!("{}: {e:#}", source.path.display()));
                    continue;
                }
                Ok(open::ReadVolume { volume, layer }) => (Arc::new(volume), layer.and_then(Result::ok)),
                Err(e) => {
                    self.dialogs.failed(side, &source.path, &e);
                    continue;
                }
            };
            if let Phase::Ready(ready) = &mut self.phase {
                if let Err(e) = ready.replace_volume(side, volume, layer, source) {
                    self.dialogs.error = Some(format!("{e:#}"));
                }
                continue;
            }
            self.pending[side as usize] = Some(Pending { volume, source, layer });
            if let [Some(_), Some(_)] = &self.pending {
                let [Some(fixed), Some(moving)] = std::mem::take(&mut self.pending) else { continue };
                let layers = fixed.layer.zip(moving.layer).map(|(f, m)| [f, m]);
                let title = format!("{} -> {}", fixed.source.name(), moving.source.name());
                let paths = [Some(fixed.source.path), Some(moving.source.path)];
                let mut document = Document::new(paths, [&fixed.volume, &moving.volume], Vec::new());
                (document.fixed_part, document.moving_part) = (fixed.source.part, moving.source.part);
                let loaded = Loaded { title, fixed: fixed.volume, moving: moving.volume };
                let opened = Opened { loaded, document, view: None };
                self.phase = match self.upload(ctx, LoadedPair { opened, layers }) {
                    Ok(ready) => Phase::Ready(Box::new(ready)),
                    Err(e) => Phase::Failed(format!("{e:#}")),
                };
            }
        }
    }

    /// Acts on what the menu, a dialog, a drop or a chooser asked for.
    fn handle(&mut self, ctx: &egui::Context, event: open::OpenEvent) {
        use open::OpenEvent;
        match event {
            OpenEvent::Volume { side, source } => self.open_volume(ctx, side, source),
            OpenEvent::OpenSession(path) => {
                note_recent(&mut self.recent, &path);
                self.phase =
                    Self::start_loading(ctx, GuiOptions { session: Some(path), ..GuiOptions::default() }, self.facts);
            }
            OpenEvent::Demo => self.phase = Self::start_loading(ctx, GuiOptions::default(), self.facts),
            OpenEvent::Dialog(purpose) => self.dialogs.dialog = Some(open::DialogJob::start(ctx, purpose)),
            OpenEvent::ImportLandmarks(path) => match &mut self.phase {
                Phase::Ready(ready) => ready.apply(Command::File(files::FileAction::ImportLandmarks(path))),
                _ => self.dialogs.error = Some("Open a pair of volumes before importing landmarks.".into()),
            },
            OpenEvent::UseField(path) => match &mut self.phase {
                Phase::Ready(ready) => ready.apply(Command::File(files::FileAction::UseField(path))),
                _ => {
                    self.dialogs.error =
                        Some("Open a pair of volumes before using a displacement field under the landmarks.".into());
                }
            },
            OpenEvent::Chosen(purpose, path) => {
                let Phase::Ready(ready) = &mut self.phase else { return };
                if let Some(action) = files::chosen(purpose, path) {
                    ready.apply(Command::File(action));
                }
            }
        }
    }

    fn upload(&self, ctx: &egui::Context, pair: LoadedPair) -> anyhow::Result<Ready> {
        let rs = self.render_state.as_ref().context("the window has no wgpu renderer")?;
        let LoadedPair { opened: Opened { loaded, document, view }, layers } = pair;
        let gpu = Viewer::context(rs);
        let viewer = match layers {
            Some([fixed, moving]) => Viewer::from_layers(gpu, &fixed, &moving)?,
            None => Viewer::with_context(gpu, &loaded.fixed, &loaded.moving)?,
        };
        let (lo, hi) = viewer.scene_box();
        // Placed by `reset_camera` below.
        let camera = OrbitCamera::fit(lo, hi, Projection::Perspective { fov_y_rad: 0.6 });
        let mid = (lo + hi) * 0.5;
        let first = Snapshot { document: document.clone(), volumes: [&loaded.fixed, &loaded.moving].map(Arc::clone) };
        let mut ready = Ready {
            loaded,
            document,
            history: History::new(first),
            viewer,
            view: super::View::new(camera, [f64::from(mid.z), f64::from(mid.y), f64::from(mid.x)]),
            fit: Fitter::default(),
            pointer: super::Pointer::default(),
            assist: super::Assist { refined_dir: self.autosave.path().with_file_name("refined"), ..Default::default() },
            files: Files::default(),
            ctx: ctx.clone(),
        };
        ready.reset_camera();
        if let Some(view) = &view {
            ready.apply_view(view);
        }
        ready.refit();
        Ok(ready)
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
        let started = std::time::Instant::now();
        self.frame(ui);
        // The frame's work is done (egui paints next): the refinement may go on.
        if let Phase::Ready(ready) = &self.phase {
            ready.hold_refinement(false);
        }
        if let Some(log) = &mut self.frame_log {
            let (phase, view) = match &self.phase {
                Phase::Loading { .. } => ("loading", "none".to_owned()),
                Phase::Failed(_) => ("failed", "none".to_owned()),
                Phase::Ready(ready) => ("ready", ready.view_state_name()),
            };
            let released = ui.input(|i| i.pointer.any_released());
            let ui_ms = started.elapsed().as_secs_f64() * 1e3;
            log.frame(&super::frame_log::FrameLine { started, phase, view, released, ui_ms });
        }
    }
}

impl Workbench {
    /// One frame of the window ([`eframe::App::ui`]).
    fn frame(&mut self, ui: &mut egui::Ui) {
        let ctx = ui.ctx().clone();
        self.poll_loading(&ctx);
        self.poll_volume_jobs(&ctx);
        let mut events = Vec::new();
        egui::Panel::top("menu").show(ui, |ui| {
            egui::MenuBar::new().ui(ui, |ui| {
                let ready = matches!(self.phase, Phase::Ready(_));
                events.extend(open::file_menu(ui, ready, self.dialogs.dialog.is_some(), self.recent.sessions()));
            });
        });
        if !self.jobs.is_empty() {
            egui::Panel::top("reading").show(ui, |ui| {
                for job in &self.jobs {
                    ui.label(format!("Opening {} as the {} volume", job.source.name(), job.side.name()));
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
        let rendered = matches!(&self.phase, Phase::Ready(r) if !r.needs_render() && !r.diagnostics_pending());
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
            || (self.exit_after_frames.is_some()
                && !matches!(&self.phase, Phase::Ready(r) if r.refining_in_background()))
        {
            ui.ctx().request_repaint();
        }
    }
}

/// Puts `session` first in the recent sessions (a list that cannot be written is said on stderr: it is a
/// convenience, not the user's work).
fn note_recent(recent: &mut crate::project::recent::Recent, session: &std::path::Path) {
    if let Err(e) = recent.note(session) {
        eprintln!("warpbench: the recent sessions: {e:#}");
    }
}

/// Hands the document as it is now to the autosave ([`autosave::Autosave::observe`]), coalescing while the pointer
/// is held.
fn autosave_changes(autosave: &mut autosave::Autosave, ctx: &egui::Context, ready: &Ready) {
    let file = ready.to_session(false);
    let held = ctx.input(|i| i.pointer.any_down()) || ready.drag().is_some();
    if let Some(wait) = autosave.observe(std::time::Instant::now(), &file, held) {
        ctx.request_repaint_after(wait);
    }
}

/// The keyboard shortcuts, as in BigWarp and Slicer where they have one: Ctrl+Z / Ctrl+Shift+Z undo and redo, the
/// tools' keys ([`toolbar::Tool::key`]: Esc cancels adding, drops a suggestion or clears the selection, Space adds a
/// pair, B brush, L leafer, P lens, T suggest, A auto-align), Enter takes a suggestion, Delete removes the selected
/// pair, R resets the camera, W shows the worst pair, Alt+Left and Alt+Right move the views back and forward through
/// their history ([`super::places`]). The single keys only act while no text field has the keyboard.
fn keyboard(ui: &mut egui::Ui, ready: &Ready, tools: &toolbar::ToolStates) -> Vec<Command> {
    let mut commands = Vec::new();
    // Redo first: Ctrl+Shift+Z also matches Ctrl+Z logically.
    let redo = egui::KeyboardShortcut::new(egui::Modifiers::COMMAND | egui::Modifiers::SHIFT, egui::Key::Z);
    let undo = egui::KeyboardShortcut::new(egui::Modifiers::COMMAND, egui::Key::Z);
    if ui.input_mut(|i| i.consume_shortcut(&redo)) {
        commands.push(Command::Redo);
    } else if ui.input_mut(|i| i.consume_shortcut(&undo)) {
        commands.push(Command::Undo);
    }
    if ui.ctx().egui_wants_keyboard_input() {
        return commands;
    }
    commands.extend(toolbar::shortcut_commands(ui, tools));
    let key = |ui: &mut egui::Ui, k: egui::Key| ui.input_mut(|i| i.consume_key(egui::Modifiers::NONE, k));
    if key(ui, egui::Key::Enter) && ready.suggestion().is_some() {
        commands.push(Command::AcceptSuggestion);
    }
    if (key(ui, egui::Key::Delete) || key(ui, egui::Key::Backspace))
        && let Some(i) = ready.pointer.selected
    {
        commands.push(Command::DeletePair(i));
    }
    if key(ui, egui::Key::R) {
        commands.push(Command::ResetCamera);
    }
    if key(ui, egui::Key::W) {
        commands.push(Command::ShowWorstPair);
    }
    commands.extend(super::places::place_keys(ui).map(Command::Place));
    commands
}

/// The window once the pair is loaded: toolbar, status bar, settings and landmark panels, and the views' panes.
fn workbench_ui(
    ui: &mut egui::Ui,
    ready: &mut Ready,
    render_state: Option<&eframe::egui_wgpu::RenderState>,
    autosave: &mut autosave::Autosave,
) {
    ready.view.frame_rate.tick(std::time::Instant::now());
    // No refinement band starts while this frame is worked on (the window answers its input first).
    ready.hold_refinement(true);
    ready.poll_diagnostics();
    ready.poll_alignment();
    ready.poll_intensities();
    if let Some(job) = &ready.files.export {
        match job.poll() {
            Some(result) => {
                ready.files.message = Some(result.unwrap_or_else(|e| e));
                ready.files.export = None;
            }
            None => ui.ctx().request_repaint_after(std::time::Duration::from_millis(100)),
        }
    }
    // The toolbar and the status bar span the window's width; the settings and landmark panels take its sides.
    let tools = toolbar::ToolStates::of(ready);
    let mut commands = keyboard(ui, ready, &tools);
    commands.extend(toolbar::toolbar_ui(ui, &tools, &mut ready.view.places));
    for command in commands {
        ready.apply(command);
    }
    status::status_bar(ui, ready);
    let mut commands = side_panel::side_panel(ui, ready);
    let panel_input = landmark_panel::PanelInput {
        pairs: &ready.document.pairs,
        errors: &ready.fit.pair_errors,
        selected: ready.pointer.selected,
        pairs_in_fit: ready.fit_pairs().0.len(),
    };
    commands.extend(landmark_panel::landmark_panel(ui, &panel_input, &mut ready.view.landmarks));
    for command in commands {
        ready.apply(command);
    }
    // What the panels changed reaches the disk before the 3-D view renders (a second on a CPU driver).
    autosave_changes(autosave, ui.ctx(), ready);
    // The attention lens moves every frame: the 3-D view is drawn again at the display's rate while it pulses.
    if ready.view_lens(std::time::Instant::now()).is_some() {
        ready.invalidate_view();
    }
    views::panes::show(ui, ready, render_state);
    // A change becomes an undo step once it has settled (a slider drag is one step); a move of the views, a step of
    // their history.
    let held = ui.input(|i| i.pointer.any_down());
    ready.settle(held);
    let now = std::time::Duration::from_secs_f64(ui.input(|i| i.time).max(0.0));
    if let Some(wait) = ready.observe_place(held, now) {
        ui.ctx().request_repaint_after(wait);
    }
    if ready.refining_in_background() {
        // The refining thread wakes the window when the view is done; until then only the progress changes.
        ui.ctx().request_repaint_after(REFINE_PROGRESS_EVERY);
    } else if ready.needs_render() {
        ui.ctx().request_repaint();
    }
}

/// How often the status bar's refinement progress is drawn while a thread refines the 3-D view: on a CPU driver
/// each frame of the window takes the CPU from the refinement.
const REFINE_PROGRESS_EVERY: std::time::Duration = std::time::Duration::from_secs(1);
