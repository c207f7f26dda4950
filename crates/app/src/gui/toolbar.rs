//! The toolbar along the top of the window: the tools (Select, Add pair, Brush, Leafer, Lens, Suggest, Auto-align),
//! each a button with its icon and name and a tooltip that gives its shortcut, the active ones shown pressed; then
//! Undo, Redo, Reset camera, the views' Back, Forward and named views ([`super::places`]) and the layout of the views. It reads the window's state through [`ToolStates`] and
//! returns what it asks for as [`Command`]s; the same shortcuts reach the same commands from the keyboard
//! ([`shortcut_commands`]).

use eframe::egui;

use super::leafer::{DEFAULT_ANGLE_DEG, Leafer};
use super::open::Side;
use super::{Command, Placing};
use crate::settings::Layout;

/// A tool of the toolbar.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tool {
    /// The pointer selects, drags landmarks and turns the view.
    Select,
    /// Clicks place a pair: its moving point, then its fixed point.
    AddPair,
    /// Drags displace the deformed moving volume.
    Brush,
    /// The 3-D view cut along the line of sight and opened like a book.
    Leafer,
    /// A pulsing lens about the selected pair in the 3-D view.
    Lens,
    /// The selected pair's target searched again by intensities.
    Suggest,
    /// The moving volume aligned rigidly to the fixed one by mutual information.
    AutoAlign,
}

impl Tool {
    pub const ALL: [Self; 7] =
        [Self::Select, Self::AddPair, Self::Brush, Self::Leafer, Self::Lens, Self::Suggest, Self::AutoAlign];

    /// Its name on its button.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Select => "Select",
            Self::AddPair => "Add pair",
            Self::Brush => "Brush",
            Self::Leafer => "Leafer",
            Self::Lens => "Lens",
            Self::Suggest => "Suggest",
            Self::AutoAlign => "Auto-align",
        }
    }

    /// Its key, without modifiers.
    #[must_use]
    pub fn key(self) -> egui::Key {
        match self {
            Self::Select => egui::Key::Escape,
            Self::AddPair => egui::Key::Space,
            Self::Brush => egui::Key::B,
            Self::Leafer => egui::Key::L,
            Self::Lens => egui::Key::P,
            Self::Suggest => egui::Key::T,
            Self::AutoAlign => egui::Key::A,
        }
    }

    /// What it does, as its tooltip says before the shortcut.
    #[must_use]
    pub fn hint(self) -> &'static str {
        match self {
            Self::Select => "Select and drag landmarks, turn the views (Esc also drops a suggestion and stops adding)",
            Self::AddPair => "Add a pair: click its point on the moving volume, then its partner on the fixed one",
            Self::Brush => "Drag the deformed moving volume in the 3-D view or a slice",
            Self::Leafer => "Cut the 3-D view along the line of sight through the crosshair and open it like a book",
            Self::Lens => "Pulse a lens about the selected pair in the 3-D view",
            Self::Suggest => "Search again for the selected pair's target around where the warp puts its moving point",
            Self::AutoAlign => "Align the moving volume to the fixed one by mutual information (rigid; MR to CT works)",
        }
    }

    /// Its tooltip: what it does and its shortcut.
    #[must_use]
    pub fn tooltip(self) -> String {
        format!("{} ({})", self.hint(), self.key().symbol_or_name())
    }

    /// Draws its icon in `rect` with `colour`: strokes only, so that no glyph the fonts lack is needed.
    fn paint_icon(self, painter: &egui::Painter, rect: egui::Rect, colour: egui::Color32) {
        let stroke = egui::Stroke::new(1.5, colour);
        let c = rect.center();
        let r = rect.width() * 0.5;
        let at = |x: f32, y: f32| c + egui::vec2(x * r, y * r);
        match self {
            Self::Select => {
                let arrow = vec![at(-0.6, -0.9), at(0.6, 0.2), at(0.0, 0.25), at(0.35, 0.9), at(-0.6, 0.5)];
                painter.add(egui::Shape::convex_polygon(arrow, colour, egui::Stroke::NONE));
            }
            Self::AddPair => {
                painter.circle_stroke(at(-0.5, 0.45), 0.3 * r, stroke);
                painter.line_segment([at(-0.3, 0.25), at(0.3, -0.25)], stroke);
                painter.line_segment([at(0.5, -0.9), at(0.5, -0.1)], stroke);
                painter.line_segment([at(0.1, -0.5), at(0.9, -0.5)], stroke);
            }
            Self::Brush => {
                painter.circle_stroke(c, 0.8 * r, stroke);
                painter.arrow(at(-0.4, 0.0), egui::vec2(0.9 * r, 0.0), stroke);
            }
            Self::Leafer => {
                painter.line_segment([at(0.0, -0.7), at(0.0, 0.8)], stroke);
                painter.add(egui::Shape::closed_line(
                    vec![at(0.0, -0.7), at(-0.9, -0.9), at(-0.9, 0.6), at(0.0, 0.8)],
                    stroke,
                ));
                painter.add(egui::Shape::closed_line(
                    vec![at(0.0, -0.7), at(0.9, -0.9), at(0.9, 0.6), at(0.0, 0.8)],
                    stroke,
                ));
            }
            Self::Lens => {
                painter.circle_stroke(at(-0.2, -0.2), 0.6 * r, stroke);
                painter.line_segment([at(0.25, 0.25), at(0.9, 0.9)], egui::Stroke::new(2.5, colour));
            }
            Self::Suggest => {
                painter.circle_stroke(c, 0.85 * r, stroke);
                painter.circle_stroke(c, 0.45 * r, stroke);
                painter.circle_filled(c, 0.12 * r, colour);
            }
            Self::AutoAlign => {
                let square = |dx: f32, dy: f32| egui::Rect::from_center_size(at(dx, dy), egui::vec2(1.0 * r, 1.0 * r));
                painter.rect_stroke(square(-0.3, -0.3), 1.0, stroke, egui::StrokeKind::Middle);
                painter.rect_stroke(square(0.3, 0.3), 1.0, stroke, egui::StrokeKind::Middle);
            }
        }
    }
}

/// What the toolbar needs to know of the window: which tools are on, which can be used now, and what the view
/// buttons act on.
#[derive(Clone, Copy, Debug)]
pub struct ToolStates {
    pub placing: Placing,
    pub sculpting: bool,
    pub leafer: Leafer,
    pub lens_on: bool,
    /// The pair selected, if one is.
    pub selected: Option<usize>,
    /// Whether an alignment is running.
    pub aligning: bool,
    pub history: UndoRedo,
    pub layout: Layout,
}

/// Whether there is a step to undo and one to redo.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UndoRedo {
    pub undo: bool,
    pub redo: bool,
}

impl ToolStates {
    /// What the toolbar shows of `ready`.
    #[must_use]
    pub fn of(ready: &super::Ready) -> Self {
        Self {
            placing: ready.placing(),
            sculpting: ready.sculpting(),
            leafer: ready.view.leafer,
            lens_on: ready.view.attention.is_on(),
            selected: ready.pointer.selected,
            aligning: ready.aligning(),
            history: UndoRedo { undo: ready.history.can_undo(), redo: ready.history.can_redo() },
            layout: ready.view.layout,
        }
    }

    /// Whether `tool` is on (its button shown pressed). Select is on when no other tool takes the pointer.
    #[must_use]
    pub fn is_active(&self, tool: Tool) -> bool {
        match tool {
            Tool::Select => self.placing == Placing::Idle && !self.sculpting,
            Tool::AddPair => self.placing != Placing::Idle,
            Tool::Brush => self.sculpting,
            Tool::Leafer => self.leafer.is_open(),
            Tool::Lens => self.lens_on,
            Tool::Suggest => false,
            Tool::AutoAlign => self.aligning,
        }
    }

    /// Whether `tool` can be used now: Suggest needs a selected pair while none is being added, Auto-align waits for
    /// the running alignment.
    #[must_use]
    pub fn is_enabled(&self, tool: Tool) -> bool {
        match tool {
            Tool::Suggest => self.selected.is_some() && self.placing == Placing::Idle,
            Tool::AutoAlign => !self.aligning,
            _ => true,
        }
    }

    /// What choosing `tool` asks for (its button or its key), if it can be used now.
    #[must_use]
    pub fn command(&self, tool: Tool) -> Option<Command> {
        if !self.is_enabled(tool) {
            return None;
        }
        Some(match tool {
            Tool::Select => Command::UseSelect,
            Tool::AddPair => Command::ToggleAdding,
            Tool::Brush => Command::ToggleSculpting,
            Tool::Leafer => Command::SetLeafer(if self.leafer.is_open() {
                Leafer::Closed
            } else {
                Leafer::Open { side: Side::Moving, angle_deg: DEFAULT_ANGLE_DEG }
            }),
            Tool::Lens => Command::TogglePulse,
            Tool::Suggest => Command::RefinePair(self.selected?),
            Tool::AutoAlign => Command::AutoAlign(warpbench_solver::align::AlignKind::Rigid),
        })
    }
}

/// The toolbar; what its buttons asked for. The views' Back, Forward and named views change `places` in place only
/// for the name being typed.
pub fn toolbar_ui(ui: &mut egui::Ui, states: &ToolStates, places: &mut super::places::Places) -> Vec<Command> {
    let mut commands = Vec::new();
    egui::Panel::top("toolbar").show(ui, |ui| {
        ui.horizontal_wrapped(|ui| {
            for tool in Tool::ALL {
                if tool_button(ui, tool, states.is_active(tool), states.is_enabled(tool)).clicked() {
                    commands.extend(states.command(tool));
                }
            }
            ui.separator();
            if ui.add_enabled(states.history.undo, egui::Button::new("Undo")).on_hover_text("Ctrl+Z").clicked() {
                commands.push(Command::Undo);
            }
            if ui.add_enabled(states.history.redo, egui::Button::new("Redo")).on_hover_text("Ctrl+Shift+Z").clicked() {
                commands.push(Command::Redo);
            }
            if ui.button("Reset camera").on_hover_text("R").clicked() {
                commands.push(Command::ResetCamera);
            }
            commands.extend(super::places::places_ui(ui, places).map(Command::Place));
            ui.separator();
            commands.extend(super::panels::layout_ui(ui, states.layout));
        });
    });
    commands
}

/// The commands of the tools' keys pressed this frame (Esc is [`Command::Cancel`], which also drops a suggestion);
/// none while a text field has the keyboard.
pub fn shortcut_commands(ui: &mut egui::Ui, states: &ToolStates) -> Vec<Command> {
    if ui.ctx().egui_wants_keyboard_input() {
        return Vec::new();
    }
    let mut commands = Vec::new();
    for tool in Tool::ALL {
        if ui.input_mut(|i| i.consume_key(egui::Modifiers::NONE, tool.key())) {
            commands.extend(if tool == Tool::Select { Some(Command::Cancel) } else { states.command(tool) });
        }
    }
    commands
}

/// A tool's button: its icon and name, pressed while `active`, greyed out unless `enabled`, its tooltip with the
/// shortcut. Screen readers (and tests) find it by its name, toggled while active.
fn tool_button(ui: &mut egui::Ui, tool: Tool, active: bool, enabled: bool) -> egui::Response {
    let text = egui::WidgetText::from(tool.name()).into_galley(
        ui,
        Some(egui::TextWrapMode::Extend),
        f32::INFINITY,
        egui::TextStyle::Button,
    );
    let pad = ui.spacing().button_padding;
    let icon = ui.spacing().icon_width;
    let gap = ui.spacing().icon_spacing;
    let height = (icon.max(text.size().y) + 2.0 * pad.y).max(ui.spacing().interact_size.y);
    let size = egui::vec2(2.0 * pad.x + icon + gap + text.size().x, height);
    let sense = if enabled { egui::Sense::click() } else { egui::Sense::hover() };
    let (rect, response) = ui.allocate_exact_size(size, sense);
    response.widget_info(|| egui::WidgetInfo::selected(egui::Role::Button, enabled, active, tool.name()));
    if ui.is_rect_visible(rect) {
        let visuals = ui.style().interact_selectable(&response, active);
        let painter = ui.painter();
        if active || response.hovered() {
            painter.rect(
                rect,
                visuals.corner_radius,
                visuals.weak_bg_fill,
                visuals.bg_stroke,
                egui::StrokeKind::Inside,
            );
        }
        let colour = if enabled { visuals.text_color() } else { ui.visuals().weak_text_color() };
        let icon_rect = egui::Rect::from_min_size(
            egui::pos2(rect.min.x + pad.x, rect.center().y - icon * 0.5),
            egui::vec2(icon, icon),
        );
        tool.paint_icon(painter, icon_rect, colour);
        let text_pos = egui::pos2(icon_rect.max.x + gap, rect.center().y - text.size().y * 0.5);
        painter.galley(text_pos, text, colour);
    }
    response.on_hover_text(tool.tooltip()).on_disabled_hover_text(tool.tooltip())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn idle() -> ToolStates {
        ToolStates {
            placing: Placing::Idle,
            sculpting: false,
            leafer: Leafer::Closed,
            lens_on: false,
            selected: None,
            aligning: false,
            history: UndoRedo::default(),
            layout: Layout::FourUp,
        }
    }

    #[test]
    fn each_tool_has_its_own_key_and_says_it_in_its_tooltip() {
        let keys: std::collections::HashSet<_> = Tool::ALL.iter().map(|t| t.key()).collect();
        assert_eq!(keys.len(), Tool::ALL.len(), "no two tools share a key");
        for tool in Tool::ALL {
            let tip = tool.tooltip();
            assert!(tip.ends_with(&format!("({})", tool.key().symbol_or_name())), "{tip}");
        }
    }

    #[test]
    fn select_is_on_exactly_when_no_other_tool_takes_the_pointer_and_suggest_needs_a_pair() {
        let s = idle();
        assert!(s.is_active(Tool::Select) && !s.is_active(Tool::AddPair));
        let adding = ToolStates { placing: Placing::Source, ..s };
        assert!(!adding.is_active(Tool::Select) && adding.is_active(Tool::AddPair));
        let brushing = ToolStates { sculpting: true, ..s };
        assert!(!brushing.is_active(Tool::Select) && brushing.is_active(Tool::Brush));
        assert!(s.command(Tool::Suggest).is_none(), "no pair selected");
        let selected = ToolStates { selected: Some(2), ..s };
        assert!(matches!(selected.command(Tool::Suggest), Some(Command::RefinePair(2))));
        let aligning = ToolStates { aligning: true, ..s };
        assert!(aligning.command(Tool::AutoAlign).is_none() && aligning.is_active(Tool::AutoAlign));
        let open = s.command(Tool::Leafer);
        assert!(matches!(open, Some(Command::SetLeafer(l)) if l.is_open()));
        let opened = ToolStates { leafer: Leafer::Open { side: Side::Fixed, angle_deg: 20.0 }, ..s };
        assert!(matches!(opened.command(Tool::Leafer), Some(Command::SetLeafer(Leafer::Closed))));
    }
}
