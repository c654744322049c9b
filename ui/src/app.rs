//! The editor window: controls on the left, the viewport in the middle, the timeline below.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use egui::{Color32, RichText};
use facesim::drive::Codes;
use facesim::rig::ExpressionCode;
use facesim::rig::style::StyleCode;
use facesim::session::track::Track;
use facesim::session::{Display, Frame, Request, SessionHandle};
use facesim::sim::Quality;
use nalgebra::Point3;

use crate::scene::{self, Toggles};
use crate::viewport::{OrbitCamera, Scene, ViewportCallback, ViewportResources};

/// The timeline: keyframes, playback and recording of the codes.
pub struct Timeline {
    pub track: Track,
    pub time: f64,
    pub playing: Option<(Instant, f64)>,
    pub recording: Option<Instant>,
    pub path: String,
    pub message: String,
}

pub struct EditorApp {
    session: Arc<dyn SessionHandle>,
    pub toggles: Toggles,
    pub link_sides: bool,
    camera: Option<OrbitCamera>,
    scene: Arc<Scene>,
    /// (frame index, toggles) the scene was built for.
    scene_key: Option<(u64, Toggles)>,
    pub timeline: Timeline,
    /// Frame index of the last frame the UI saw, and how long UI updates take.
    pub last_frame: Option<Arc<Frame>>,
    pub ui_ms: f64,
    error: Option<String>,
}

impl EditorApp {
    pub fn new(cc: &eframe::CreationContext<'_>, session: Arc<dyn SessionHandle>) -> Self {
        if let Some(rs) = &cc.wgpu_render_state {
            ViewportResources::install(rs);
        }
        let ctx = cc.egui_ctx.clone();
        let repaint = Arc::new(AtomicBool::new(false));
        session.on_new_frame(Box::new(move |_| {
            repaint.store(true, Ordering::Relaxed);
            ctx.request_repaint();
        }));
        let face = session.inputs().face;
        let name = session.face_infos()[face].name.clone();
        EditorApp {
            session,
            toggles: Toggles::default(),
            link_sides: false,
            camera: None,
            scene: Arc::new(Scene::default()),
            scene_key: None,
            timeline: Timeline {
                track: Track::new(&name),
                time: 0.0,
                playing: None,
                recording: None,
                path: "track.json".into(),
                message: String::new(),
            },
            last_frame: None,
            ui_ms: 0.0,
            error: None,
        }
    }

    pub fn session(&self) -> &Arc<dyn SessionHandle> {
        &self.session
    }

    fn submit(&mut self, requests: &[Request]) {
        if let Err(e) = self.session.submit(requests) {
            self.error = Some(e.to_string());
        } else {
            self.error = None;
        }
    }

    fn controls(&mut self, ui: &mut egui::Ui) {
        let inputs = self.session.inputs();
        let faces = self.session.face_infos();
        ui.heading("Face");
        let mut face = inputs.face;
        egui::ComboBox::from_label("identity")
            .selected_text(faces[face].name.clone())
            .show_ui(ui, |ui| {
                for f in &faces {
                    ui.selectable_value(&mut face, f.index, f.name.as_str());
                }
            });
        if face != inputs.face {
            self.submit(&[Request::Face(face)]);
            self.camera = None;
        }
        let mut quality = inputs.quality;
        egui::ComboBox::from_label("quality")
            .selected_text(quality.name())
            .show_ui(ui, |ui| {
                for q in Quality::ALL {
                    ui.selectable_value(&mut quality, q, q.name());
                }
            });
        let mut refine = inputs.refine;
        ui.checkbox(&mut refine, "refine to final when idle");
        let mut contact = inputs.contact;
        ui.checkbox(&mut contact, "lip and teeth contact")
            .on_hover_text("lips and teeth never cross; frames take several times longer");
        if quality != inputs.quality || refine != inputs.refine || contact != inputs.contact {
            self.submit(&[
                Request::Quality(quality),
                Request::Refine(refine),
                Request::Contact(contact),
            ]);
        }

        ui.separator();
        ui.horizontal(|ui| {
            ui.heading("Expression");
            if ui.button("reset").clicked() {
                self.submit(&[Request::Expression(ExpressionCode::NEUTRAL)]);
            }
        });
        ui.checkbox(&mut self.link_sides, "link left/right");
        let mut expression = inputs.codes.expression;
        for (region, names) in ExpressionCode::GROUPS {
            ui.label(RichText::new(region).strong());
            for name in names {
                let i = ExpressionCode::index_of(name).expect("region names are code names");
                let before = expression.0[i];
                ui.add(egui::Slider::new(&mut expression.0[i], 0.0..=1.0).text(*name));
                if expression.0[i] != before && self.link_sides {
                    let other = if let Some(b) = name.strip_suffix("_L") {
                        Some(format!("{b}_R"))
                    } else {
                        name.strip_suffix("_R").map(|b| format!("{b}_L"))
                    };
                    if let Some(j) = other.and_then(|o| ExpressionCode::index_of(&o)) {
                        expression.0[j] = expression.0[i];
                    }
                }
            }
        }
        if expression != inputs.codes.expression {
            self.submit(&[Request::Expression(expression)]);
        }

        ui.separator();
        ui.horizontal(|ui| {
            ui.heading("Style");
            if ui.button("identity default").clicked() {
                self.submit(&[Request::Style(faces[inputs.face].default_style)]);
            }
        });
        let mut style = inputs.codes.style;
        for (k, name) in StyleCode::NAMES.iter().enumerate() {
            ui.add(
                egui::Slider::new(&mut style.0[k], StyleCode::RANGE.0..=StyleCode::RANGE.1)
                    .text(*name),
            );
        }
        if style != inputs.codes.style {
            self.submit(&[Request::Style(style)]);
        }

        ui.separator();
        ui.heading("Display");
        ui.checkbox(&mut self.toggles.skin, "skin");
        ui.checkbox(&mut self.toggles.teeth, "teeth and mouth");
        ui.checkbox(&mut self.toggles.wireframe, "simulation mesh");
        ui.checkbox(&mut self.toggles.crosses, "actuation crosses");
        let names: Vec<String> = self
            .last_frame
            .as_ref()
            .map(|f| f.heatmaps.iter().map(|h| h.name.clone()).collect())
            .unwrap_or_default();
        let mut heat = self.toggles.heatmap;
        egui::ComboBox::from_label("heatmap")
            .selected_text(
                heat.and_then(|i| names.get(i).cloned())
                    .unwrap_or("none".into()),
            )
            .show_ui(ui, |ui| {
                ui.selectable_value(&mut heat, None, "none");
                for (i, n) in names.iter().enumerate() {
                    ui.selectable_value(&mut heat, Some(i), n.as_str());
                }
            });
        self.toggles.heatmap = heat;
        let display = Display {
            crosses: self.toggles.crosses,
            heatmaps: inputs.display.heatmaps,
        };
        if display != inputs.display {
            self.submit(&[Request::Display(display)]);
        }
        if let Some(field) = heat.and_then(|i| self.last_frame.as_ref()?.heatmaps.get(i).cloned()) {
            legend(ui, &field);
        }

        ui.separator();
        ui.heading("Solver");
        match &self.last_frame {
            Some(f) => {
                ui.label(format!("frame {} ({})", f.index, f.quality));
                ui.label(format!(
                    "iterations {}  residual {:.2e}",
                    f.stats.iterations, f.stats.residual
                ));
                ui.label(format!(
                    "solve {:.1} ms, frame {:.1} ms",
                    f.stats.solve_ms, f.stats.total_ms
                ));
                ui.label(match f.stats.contacts {
                    _ if f.stats.contact_skipped => {
                        "contact not needed (lips apart: skipped)".into()
                    }
                    Some(c) => format!("contact pairs {c}"),
                    None => "contact off".into(),
                });
                if f.stats.reused {
                    ui.label("same inputs: the last solve reused");
                }
                match &f.stats.lining {
                    Some(l) if l.error.is_some() || !l.converged => {
                        ui.label(
                            RichText::new(format!(
                                "inner mouth lining: {}",
                                l.error
                                    .as_deref()
                                    .unwrap_or("kept off the teeth, not settled")
                            ))
                            .color(Color32::from_rgb(230, 140, 0)),
                        );
                    }
                    Some(l) => {
                        ui.label(format!(
                            "inner mouth lining kept off the teeth ({:.1} ms)",
                            l.ms
                        ));
                    }
                    None => {}
                }
                if f.error.is_none() && !f.stats.converged {
                    ui.label(
                        RichText::new(format!(
                            "not converged ({:?}): shown as far as the solver got",
                            f.stats.termination
                        ))
                        .color(Color32::from_rgb(230, 140, 0)),
                    );
                }
                if let Some(e) = &f.error {
                    ui.label(RichText::new(e).color(Color32::RED));
                }
            }
            None => {
                ui.label("solving the first frame…");
            }
        }
        ui.label(format!("UI {:.1} ms", self.ui_ms));
        ui.label(self.session.describe());
        if let Some(e) = &self.error {
            ui.label(RichText::new(e).color(Color32::RED));
        }
    }

    fn timeline(&mut self, ui: &mut egui::Ui) {
        let inputs = self.session.inputs();
        let (codes, contact) = (inputs.codes, inputs.contact);
        let t = &mut self.timeline;
        ui.horizontal(|ui| {
            let playing = t.playing.is_some();
            if ui.button(if playing { "pause" } else { "play" }).clicked() {
                t.playing = if playing {
                    None
                } else {
                    Some((Instant::now(), t.time))
                };
            }
            let recording = t.recording.is_some();
            if ui
                .button(if recording {
                    "stop recording"
                } else {
                    "record"
                })
                .clicked()
            {
                if recording {
                    t.recording = None;
                } else {
                    t.track.keys.clear();
                    t.time = 0.0;
                    t.recording = Some(Instant::now());
                }
            }
            if ui
                .button("key")
                .on_hover_text("keyframe the current codes at this time")
                .clicked()
            {
                t.track.set_key(t.time, codes);
            }
            if ui.button("delete key").clicked() {
                t.track.remove_key_near(t.time, 1.0 / 60.0);
            }
            let end = t.track.duration().max(1.0);
            ui.add(egui::Slider::new(&mut t.time, 0.0..=end).text("s"));
            ui.label(format!("{} keys", t.track.keys.len()));
            let label = ui.label("track file");
            ui.text_edit_singleline(&mut t.path).labelled_by(label.id);
            if ui
                .button("save")
                .on_hover_text("the track keeps the contact setting, for its export")
                .clicked()
            {
                t.track.contact = Some(contact);
                t.message = match t.track.save(&PathBuf::from(&t.path)) {
                    Ok(()) => format!("saved {}", t.path),
                    Err(e) => e.to_string(),
                };
            }
            if ui.button("load").clicked() {
                t.message = match Track::load(&PathBuf::from(&t.path)) {
                    Ok(track) => {
                        t.track = track;
                        format!("loaded {}", t.path)
                    }
                    Err(e) => e.to_string(),
                };
            }
            ui.label(t.message.as_str());
        });
    }

    /// Advances playback/recording; returns codes to apply.
    fn tick_timeline(&mut self) -> Option<Codes> {
        let codes = self.session.inputs().codes;
        let t = &mut self.timeline;
        if let Some(start) = t.recording {
            t.time = start.elapsed().as_secs_f64();
            if t.track.keys.last().is_none_or(|k| k.codes != codes) {
                t.track.set_key(t.time, codes);
            }
            return None;
        }
        if let Some((start, from)) = t.playing {
            t.time = from + start.elapsed().as_secs_f64();
            if t.time >= t.track.duration() {
                t.playing = None;
            }
            return t.track.sample(t.time).filter(|c| *c != codes);
        }
        None
    }

    fn viewport(&mut self, ui: &mut egui::Ui) {
        let Some(frame) = self.last_frame.clone() else {
            ui.centered_and_justified(|ui| ui.label("waiting for the first frame…"));
            return;
        };
        let Some(topology) = self.session.topology(frame.face) else {
            return;
        };
        let camera = self.camera.get_or_insert_with(|| {
            let (mut lo, mut hi) = (Point3::from([f32::MAX; 3]), Point3::from([f32::MIN; 3]));
            for p in &topology.rest {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
            OrbitCamera::framing(nalgebra::center(&lo, &hi), 0.5 * (hi - lo).norm())
        });
        let (rect, response) =
            ui.allocate_exact_size(ui.available_size(), egui::Sense::click_and_drag());
        let d = response.drag_delta();
        let pan = response.dragged_by(egui::PointerButton::Secondary)
            || response.dragged_by(egui::PointerButton::Middle)
            || (response.dragged() && ui.input(|i| i.modifiers.shift));
        if pan {
            camera.pan(d.x, d.y, rect.height());
        } else if response.dragged_by(egui::PointerButton::Primary) {
            camera.orbit(d.x, d.y);
        }
        if response.hovered() {
            let scroll = ui.input(|i| i.smooth_scroll_delta.y);
            if scroll != 0.0 {
                camera.zoom((-scroll * 0.002).exp());
            }
        }
        if response.double_clicked() {
            self.camera = None;
        }
        let key = (frame.index, self.toggles);
        let changed = self.scene_key != Some(key);
        if changed {
            self.scene = Arc::new(scene::build(&frame, &topology, &self.toggles));
            self.scene_key = Some(key);
        }
        let ppp = ui.ctx().pixels_per_point();
        let camera = self
            .camera
            .unwrap_or_else(|| OrbitCamera::framing(Point3::origin(), 10.0));
        ui.painter()
            .add(eframe::egui_wgpu::Callback::new_paint_callback(
                rect,
                ViewportCallback {
                    scene: self.scene.clone(),
                    camera,
                    size_px: [(rect.width() * ppp) as u32, (rect.height() * ppp) as u32],
                    background: [0.16, 0.17, 0.19],
                },
            ));
    }
}

fn legend(ui: &mut egui::Ui, field: &facesim::session::ScalarField) {
    let (rect, _) = ui.allocate_exact_size(egui::vec2(200.0, 14.0), egui::Sense::hover());
    let steps = 32;
    for s in 0..steps {
        let t = s as f32 / (steps - 1) as f32;
        let v = field.legend.min + t * (field.legend.max - field.legend.min);
        let [r, g, b] = field.legend.color(v);
        let x0 = rect.left() + rect.width() * s as f32 / steps as f32;
        let x1 = rect.left() + rect.width() * (s + 1) as f32 / steps as f32;
        ui.painter().rect_filled(
            egui::Rect::from_min_max(egui::pos2(x0, rect.top()), egui::pos2(x1, rect.bottom())),
            0.0,
            Color32::from_rgb(r, g, b),
        );
    }
    ui.label(format!(
        "{:.3} … {:.3} {}",
        field.legend.min, field.legend.max, field.unit
    ));
}

impl eframe::App for EditorApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let start = Instant::now();
        let ctx = ui.ctx().clone();
        if let Some(codes) = self.tick_timeline() {
            self.submit(&[Request::Codes(codes)]);
        }
        if self.timeline.playing.is_some() || self.timeline.recording.is_some() {
            ctx.request_repaint();
        }
        if let Some(f) = self.session.latest() {
            self.last_frame = Some(f);
        }
        egui::Panel::left("controls")
            .resizable(true)
            .default_size(300.0)
            .show(ui, |ui| {
                egui::ScrollArea::vertical().show(ui, |ui| self.controls(ui));
            });
        egui::Panel::bottom("timeline").show(ui, |ui| self.timeline(ui));
        egui::CentralPanel::default().show(ui, |ui| self.viewport(ui));
        self.ui_ms = start.elapsed().as_secs_f64() * 1e3;
    }
}
