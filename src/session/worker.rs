//! The session's worker thread: latest-wins inputs, warm-started solves, refinement while
//! the inputs rest, and the published latest frame.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::frame::{Frame, FrameStats, LiningPass, Overlays, Solved, geometry};
use super::heatmap::{FieldSource, builtin_sources};
use super::session_face::{FaceTopology, SessionFace};
use crate::contact::ContactError;
use crate::contact::surface::FaceContact;
use crate::drive::{Codes, DriveError};
use crate::model::contact_region::FaceContactSettings;
use crate::model::deep_lining::{self, DeepLining, LiningMemory};
use crate::rig::ExpressionCode;
use crate::rig::style::StyleCode;
use crate::sequence::{FrameFailure, Sequence};
use crate::sim::{Quality, RigidMotion, SimError, Simulator, SolveSettings};

/// How long the inputs must rest before the frame is refined to the next preset.
pub const REST_BEFORE_REFINING: Duration = Duration::from_millis(150);
/// Refinement solves in chunks of this many iterations, so a new request interrupts it.
const REFINE_CHUNK: usize = 20;

/// Overlays the frames carry (computing them costs time, so only when shown).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Display {
    pub crosses: bool,
    pub heatmaps: bool,
}

impl Default for Display {
    fn default() -> Self {
        Display {
            crosses: false,
            heatmaps: true,
        }
    }
}

/// Everything a frame depends on.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Inputs {
    pub face: usize,
    pub codes: Codes,
    pub quality: Quality,
    /// Refine toward [`Quality::Final`] when the inputs rest.
    pub refine: bool,
    pub display: Display,
    /// Lip and teeth contact in the solve (IPC barrier, collision-checked steps): lips never
    /// cross, at several times the cost of a contact-free frame. On when a session opens.
    #[serde(default)]
    pub contact: bool,
}

/// One change to the inputs. Requests merge into the pending inputs; only the latest
/// inputs are solved.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum Request {
    Codes(Codes),
    Expression(ExpressionCode),
    /// Some expression entries `(index in ExpressionCode::NAMES, weight)`; the rest keep.
    ExpressionEntries(Vec<(usize, f64)>),
    Style(StyleCode),
    /// Some style entries `(index in StyleCode::NAMES, value)`; the rest keep.
    StyleEntries(Vec<(usize, f64)>),
    /// Switches face; the style is reset to the new face's default.
    Face(usize),
    Quality(Quality),
    Refine(bool),
    Display(Display),
    Contact(bool),
}

#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("a session needs at least one face")]
    NoFaces,
    #[error("face {index} is out of range: the session has {count} faces")]
    FaceOutOfRange { index: usize, count: usize },
    #[error("face '{face}': the actuation model drives {model} elements, the mesh has {mesh}")]
    ElementMismatch {
        face: String,
        model: usize,
        mesh: usize,
    },
    #[error("code entry {index} is out of range: the code has {len} entries")]
    EntryOutOfRange { index: usize, len: usize },
    #[error(transparent)]
    Code(#[from] DriveError),
    #[error("the session's worker has stopped")]
    Stopped,
    #[error("no frame within {seconds} s (the solve is still running)")]
    TimedOut { seconds: u64 },
}

/// Why a frame could not be solved: it becomes an error frame saying so.
#[derive(Debug, thiserror::Error)]
enum FrameError {
    #[error(transparent)]
    Actuation(#[from] DriveError),
    #[error(transparent)]
    Simulator(#[from] SimError),
    #[error("contact surfaces: {0}")]
    Contact(#[from] ContactError),
    #[error("the solve failed: {0}")]
    Solve(SimError),
    #[error("the solve produced non-finite geometry")]
    NonFinite,
}

struct Pending {
    inputs: Inputs,
    /// Bumped by every accepted request.
    generation: u64,
    shutdown: bool,
}

type Observer = Box<dyn Fn(&Arc<Frame>) + Send + Sync>;

struct Shared {
    pending: Mutex<Pending>,
    wake: Condvar,
    latest: Mutex<Option<Arc<Frame>>>,
    published: Condvar,
    observers: Mutex<Vec<Observer>>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panicking observer must not take the session down with a poisoned lock.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The running session (module doc of [`crate::session`]).
pub struct Session {
    shared: Arc<Shared>,
    faces: Vec<SessionFace>,
    topologies: Vec<Arc<FaceTopology>>,
    worker: Option<JoinHandle<()>>,
}

impl Session {
    /// Starts the worker on `faces[0]` at its default style, neutral expression.
    pub fn new(faces: Vec<SessionFace>, quality: Quality) -> Result<Session, SessionError> {
        Self::with_field_sources(faces, quality, builtin_sources())
    }

    /// As [`Session::new`], with the heatmaps computed by `sources`.
    pub fn with_field_sources(
        faces: Vec<SessionFace>,
        quality: Quality,
        sources: Vec<Box<dyn FieldSource>>,
    ) -> Result<Session, SessionError> {
        let first = faces.first().ok_or(SessionError::NoFaces)?;
        for f in &faces {
            let (model, mesh) = (f.actuation.element_count(), f.model.mesh.tets.len());
            if model != mesh {
                return Err(SessionError::ElementMismatch {
                    face: f.name.clone(),
                    model,
                    mesh,
                });
            }
        }
        let inputs = Inputs {
            face: 0,
            codes: Codes {
                expression: ExpressionCode::NEUTRAL,
                style: first.default_style,
            },
            quality,
            refine: true,
            display: Display::default(),
            contact: true,
        };
        let shared = Arc::new(Shared {
            pending: Mutex::new(Pending {
                inputs,
                generation: 1,
                shutdown: false,
            }),
            wake: Condvar::new(),
            latest: Mutex::new(None),
            published: Condvar::new(),
            observers: Mutex::new(Vec::new()),
        });
        let topologies = faces
            .iter()
            .map(|f| Arc::new(FaceTopology::of(&f.name, &f.model)))
            .collect();
        let worker = {
            let shared = shared.clone();
            let faces = faces.clone();
            std::thread::Builder::new()
                .name("facesim-session".into())
                .spawn(move || Worker::new(faces, sources, shared).run())
                .expect("spawning the session thread")
        };
        Ok(Session {
            shared,
            faces,
            topologies,
            worker: Some(worker),
        })
    }

    pub fn faces(&self) -> &[SessionFace] {
        &self.faces
    }

    pub fn topology(&self, face: usize) -> Option<Arc<FaceTopology>> {
        self.topologies.get(face).cloned()
    }

    /// The current (pending or solved) inputs.
    pub fn inputs(&self) -> Inputs {
        lock(&self.shared.pending).inputs
    }

    /// Validates and merges `request` into the pending inputs; returns the new generation.
    /// A rejected request changes nothing.
    pub fn submit(&self, request: Request) -> Result<u64, SessionError> {
        self.submit_all(std::slice::from_ref(&request))
    }

    /// Several requests as one change (one generation, at most one solve).
    pub fn submit_all(&self, requests: &[Request]) -> Result<u64, SessionError> {
        let mut pending = lock(&self.shared.pending);
        if pending.shutdown {
            return Err(SessionError::Stopped);
        }
        let styles: Vec<StyleCode> = self.faces.iter().map(|f| f.default_style).collect();
        let inputs = apply_requests(pending.inputs, requests, &styles)?;
        if inputs != pending.inputs {
            pending.inputs = inputs;
            pending.generation += 1;
            self.shared.wake.notify_all();
        }
        Ok(pending.generation)
    }

    /// The newest published frame.
    pub fn latest(&self) -> Option<Arc<Frame>> {
        lock(&self.shared.latest).clone()
    }

    /// Waits until a frame newer than `after` (a frame index) is published.
    pub fn wait_newer(&self, after: Option<u64>, timeout: Duration) -> Option<Arc<Frame>> {
        self.wait_until(timeout, |f| after.is_none_or(|a| f.index > a))
    }

    /// Waits until a frame answering generation `generation` (or a later one) is published.
    pub fn wait_generation(&self, generation: u64, timeout: Duration) -> Option<Arc<Frame>> {
        self.wait_until(timeout, |f| f.generation >= generation)
    }

    fn wait_until(&self, timeout: Duration, done: impl Fn(&Frame) -> bool) -> Option<Arc<Frame>> {
        let deadline = Instant::now() + timeout;
        let mut latest = lock(&self.shared.latest);
        loop {
            if let Some(f) = latest.as_ref().filter(|f| done(f)) {
                return Some(f.clone());
            }
            let left = deadline.checked_duration_since(Instant::now())?;
            latest = self
                .shared
                .published
                .wait_timeout(latest, left)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    /// Calls `observer` on the worker thread with every frame published from now on (keep
    /// it quick: the next solve waits for it).
    pub fn on_frame(&self, observer: impl Fn(&Arc<Frame>) + Send + Sync + 'static) {
        lock(&self.shared.observers).push(Box::new(observer));
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        lock(&self.shared.pending).shutdown = true;
        self.shared.wake.notify_all();
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}

/// `inputs` with `requests` applied in order (faces have `default_styles`), validated; the
/// error names the first bad request or code entry.
pub fn apply_requests(
    mut inputs: Inputs,
    requests: &[Request],
    default_styles: &[StyleCode],
) -> Result<Inputs, SessionError> {
    for r in requests {
        match r {
            Request::Codes(c) => inputs.codes = *c,
            Request::Expression(e) => inputs.codes.expression = *e,
            Request::ExpressionEntries(entries) => {
                for &(i, w) in entries {
                    *inputs.codes.expression.0.get_mut(i).ok_or(
                        SessionError::EntryOutOfRange {
                            index: i,
                            len: ExpressionCode::LEN,
                        },
                    )? = w;
                }
            }
            Request::Style(s) => inputs.codes.style = *s,
            Request::StyleEntries(entries) => {
                for &(i, v) in entries {
                    *inputs
                        .codes
                        .style
                        .0
                        .get_mut(i)
                        .ok_or(SessionError::EntryOutOfRange {
                            index: i,
                            len: StyleCode::LEN,
                        })? = v;
                }
            }
            Request::Face(i) => {
                let style = default_styles.get(*i).ok_or(SessionError::FaceOutOfRange {
                    index: *i,
                    count: default_styles.len(),
                })?;
                inputs.face = *i;
                inputs.codes.style = *style;
            }
            Request::Quality(q) => inputs.quality = *q,
            Request::Refine(r) => inputs.refine = *r,
            Request::Display(d) => inputs.display = *d,
            Request::Contact(c) => inputs.contact = *c,
        }
    }
    inputs.codes.validate().map_err(DriveError::from)?;
    Ok(inputs)
}

/// Per-face simulation state, built on first use.
struct FaceSim {
    /// The face's frames so far: the warm start, the last good frame, contact's start.
    sequence: Sequence<Simulator>,
    /// What the sequence's state holds the solve of (`None` after a failed or interrupted
    /// solve).
    last: Option<LastSolve>,
    /// The deep lining's contact pass and its last configuration (final frames with contact).
    lining: DeepLining,
    lining_memory: LiningMemory,
}

/// The inputs a face's state was solved for and that solve's results: identical inputs at
/// the same or a lower preset reuse it instead of solving again.
struct LastSolve {
    codes: Codes,
    contact: bool,
    quality: Quality,
    actuation: crate::drive::Actuation,
    stats: crate::sim::SolveStats,
}

impl LastSolve {
    fn answers(&self, inputs: &Inputs, quality: Quality) -> bool {
        self.codes == inputs.codes
            && self.contact == inputs.contact
            && rank(self.quality) >= rank(quality)
    }
}

/// Presets from the fastest to the most accurate.
fn rank(q: Quality) -> usize {
    Quality::ALL.iter().position(|&p| p == q).unwrap_or(0)
}

struct Worker {
    faces: Vec<SessionFace>,
    sources: Vec<Box<dyn FieldSource>>,
    shared: Arc<Shared>,
    sims: Vec<Option<FaceSim>>,
    index: u64,
    last_good: Option<Arc<Frame>>,
}

/// What the worker does next.
enum Job {
    Solve(Inputs, u64),
    Refine(Inputs, u64, Quality),
    Stop,
}

fn next_quality(q: Quality) -> Option<Quality> {
    match q {
        Quality::Interactive => Some(Quality::Preview),
        Quality::Preview => Some(Quality::Final),
        Quality::Final => None,
    }
}

impl Worker {
    fn new(
        faces: Vec<SessionFace>,
        sources: Vec<Box<dyn FieldSource>>,
        shared: Arc<Shared>,
    ) -> Self {
        let sims = faces.iter().map(|_| None).collect();
        Worker {
            faces,
            sources,
            shared,
            sims,
            index: 0,
            last_good: None,
        }
    }

    fn run(mut self) {
        let mut solved_generation = 0;
        // The preset the current generation was last solved to.
        let mut solved_quality = Quality::Interactive;
        loop {
            match self.next_job(solved_generation, solved_quality) {
                Job::Stop => return,
                Job::Solve(inputs, generation) => {
                    solved_generation = generation;
                    solved_quality = inputs.quality;
                    let settings = inputs.quality.settings();
                    self.solve(&inputs, generation, inputs.quality, settings, None);
                }
                Job::Refine(inputs, generation, quality) => {
                    solved_quality = quality;
                    let settings = SolveSettings {
                        max_iterations: REFINE_CHUNK,
                        ..quality.settings()
                    };
                    let budget = quality.settings().max_iterations;
                    self.solve(&inputs, generation, quality, settings, Some(budget));
                }
            }
        }
    }

    fn next_job(&self, solved_generation: u64, solved_quality: Quality) -> Job {
        let mut pending = lock(&self.shared.pending);
        let mut rest_since = Instant::now();
        loop {
            if pending.shutdown {
                return Job::Stop;
            }
            if pending.generation != solved_generation {
                return Job::Solve(pending.inputs, pending.generation);
            }
            let refine = pending
                .inputs
                .refine
                .then(|| next_quality(solved_quality))
                .flatten();
            match refine {
                Some(q) => {
                    let waited = rest_since.elapsed();
                    if waited >= REST_BEFORE_REFINING {
                        return Job::Refine(pending.inputs, pending.generation, q);
                    }
                    pending = self
                        .shared
                        .wake
                        .wait_timeout(pending, REST_BEFORE_REFINING - waited)
                        .unwrap_or_else(|e| e.into_inner())
                        .0;
                    if pending.generation != solved_generation {
                        rest_since = Instant::now();
                    }
                }
                None => {
                    pending = self
                        .shared
                        .wake
                        .wait(pending)
                        .unwrap_or_else(|e| e.into_inner());
                }
            }
        }
    }

    /// Solves `inputs` and publishes the frame. With `budget`, solves in chunks of
    /// `settings.max_iterations` up to `budget` iterations and gives up (publishing
    /// nothing) as soon as newer inputs arrive.
    fn solve(
        &mut self,
        inputs: &Inputs,
        generation: u64,
        quality: Quality,
        settings: SolveSettings,
        budget: Option<usize>,
    ) {
        let start = Instant::now();
        let face = &self.faces[inputs.face];
        // Identical inputs (a display change, a repeated value): reuse the solve.
        let reused = self.sims[inputs.face]
            .as_ref()
            .and_then(|fs| fs.last.as_ref())
            .filter(|last| last.answers(inputs, quality))
            .map(|last| {
                let mut stats = last.stats.clone();
                stats.iterations = 0;
                stats.evaluations = 0;
                stats.wall_time = Duration::ZERO;
                (last.actuation.clone(), stats, last.quality)
            });
        let quality = reused.as_ref().map_or(quality, |r| r.2);
        let result = (|| -> Result<_, FrameError> {
            if let Some((actuation, stats, _)) = reused.clone() {
                return Ok(Some((actuation, stats)));
            }
            let actuation = face.actuation.actuate(&inputs.codes)?;
            if self.sims[inputs.face].is_none() {
                let mut sim = face.model.simulator()?;
                let surfaces = FaceContact::new(&face.model, &FaceContactSettings::default())?;
                let lining = DeepLining::new(&face.model, &surfaces)?;
                sim.set_contact(surfaces)?;
                self.sims[inputs.face] = Some(FaceSim {
                    sequence: Sequence::new(sim),
                    last: None,
                    lining,
                    lining_memory: LiningMemory::default(),
                });
            }
            let fs = self.sims[inputs.face].as_mut().expect("built above");
            // The state is about to change: until this solve succeeds it answers nothing.
            fs.last = None;
            let settings = SolveSettings {
                contact: inputs.contact,
                ..settings
            };
            let bones = actuation.bones();
            let mut stats = fs.sequence.solve(&actuation.tensors, &bones, &settings);
            if let Some(budget) = budget {
                let mut total = 0;
                while let Ok(s) = &stats {
                    total += s.iterations;
                    if s.termination != crate::sim::Termination::IterationCap || total >= budget {
                        break;
                    }
                    let p = lock(&self.shared.pending);
                    let newer = p.generation != generation || p.shutdown;
                    drop(p);
                    if newer {
                        return Ok(None);
                    }
                    let more = fs.sequence.solve(&actuation.tensors, &bones, &settings);
                    stats = more.map(|mut m| {
                        m.iterations += total;
                        m
                    });
                    total = 0;
                }
            }
            match stats {
                Ok(stats) => Ok(Some((actuation, stats))),
                Err(FrameFailure::Actuation(e)) => Err(FrameError::Actuation(e)),
                Err(FrameFailure::Solve(e)) => Err(FrameError::Solve(e)),
                Err(FrameFailure::NonFinite) => Err(FrameError::NonFinite),
            }
        })();
        let frame = match result {
            Ok(None) => return,
            Ok(Some((actuation, stats))) => {
                let fs = self.sims[inputs.face].as_mut().expect("solved above");
                let overlays = Overlays {
                    crosses: inputs.display.crosses,
                    heatmaps: inputs.display.heatmaps,
                };
                let solved = Solved {
                    model: &face.model,
                    x: fs.sequence.state().flat_positions(),
                    actuation: &actuation,
                };
                let lining = deep_lining::runs_at(quality, inputs.contact).then_some(LiningPass {
                    pass: &fs.lining,
                    memory: &mut fs.lining_memory,
                });
                match geometry(&solved, overlays, &self.sources, lining) {
                    Some(g) => {
                        let mut frame_stats = FrameStats::from_solve(&stats, 0.0);
                        frame_stats.reused = reused.is_some();
                        frame_stats.lining = g.lining;
                        if reused.is_none() {
                            fs.last = Some(LastSolve {
                                codes: inputs.codes,
                                contact: inputs.contact,
                                quality,
                                actuation: actuation.clone(),
                                stats,
                            });
                        }
                        let total_ms = start.elapsed().as_secs_f64() * 1e3;
                        self.index += 1;
                        Frame {
                            index: self.index,
                            generation,
                            face: inputs.face,
                            codes: inputs.codes,
                            quality,
                            positions: g.positions,
                            normals: g.normals,
                            mesh_positions: g.mesh_positions,
                            crosses: g.crosses,
                            heatmaps: g.heatmaps,
                            jaw: actuation.jaw,
                            stats: FrameStats {
                                total_ms,
                                ..frame_stats
                            },
                            error: None,
                        }
                    }
                    None => self.error_frame(inputs, generation, quality, FrameError::NonFinite),
                }
            }
            Err(error) => self.error_frame(inputs, generation, quality, error),
        };
        let frame = Arc::new(frame);
        if frame.error.is_none() {
            self.last_good = Some(frame.clone());
        }
        *lock(&self.shared.latest) = Some(frame.clone());
        self.shared.published.notify_all();
        for o in lock(&self.shared.observers).iter() {
            o(&frame);
        }
    }

    /// A frame that keeps the last good geometry of the same face (or the rest pose) and
    /// says why the requested inputs could not be solved.
    fn error_frame(
        &mut self,
        inputs: &Inputs,
        generation: u64,
        quality: Quality,
        error: FrameError,
    ) -> Frame {
        self.index += 1;
        let base = self.last_good.as_ref().filter(|f| f.face == inputs.face);
        let face = &self.faces[inputs.face];
        let (positions, normals, mesh_positions) = match base {
            Some(f) => (
                f.positions.clone(),
                f.normals.clone(),
                f.mesh_positions.clone(),
            ),
            None => {
                let rest = &face.model.render.rest;
                let to32 = |p: &nalgebra::Point3<f64>| [p.x as f32, p.y as f32, p.z as f32];
                (
                    rest.iter().map(to32).collect(),
                    super::frame::vertex_normals(rest, &face.model.render.triangles),
                    face.model.mesh.vertices.iter().map(to32).collect(),
                )
            }
        };
        Frame {
            index: self.index,
            generation,
            face: inputs.face,
            codes: base.map_or(inputs.codes, |f| f.codes),
            quality,
            positions,
            normals,
            mesh_positions,
            crosses: Vec::new(),
            heatmaps: Vec::new(),
            jaw: base.map_or(RigidMotion::IDENTITY, |f| f.jaw),
            stats: FrameStats {
                iterations: 0,
                residual: 0.0,
                termination: crate::sim::Termination::Stalled,
                converged: false,
                from_rest: false,
                solve_ms: 0.0,
                total_ms: 0.0,
                contacts: None,
                contact_skipped: false,
                contact_lists: None,
                reused: false,
                lining: None,
            },
            error: Some(error.to_string()),
        }
    }
}
