//! Contact inside the solve: the IPC barrier `κ·B(y(x))` on the face's contact surfaces
//! ([`FaceContact`], `y = W·x` for embedded vertices, bone-driven for rigid ones) added to the
//! elastic energy, with a collision-checked line search and contact-aware steps.
//!
//! - **Energy and gradient**: `E(x) + κ·B(y)`, gradient `∇E + κ·Wᵀ∇B`.
//! - **Steps**: the step's initial inverse Hessian becomes `(L + K)⁻¹` with
//!   `K = Wᵀ·[∇²B]₊·W` (the barrier Hessian's dominant PSD part, pulled back to the
//!   simulation), so the barrier's stiffness is in every step. `K` lives on the few
//!   simulation vertices the active pairs touch, as about one sparse factor column per pair
//!   ([`DOMINANT_CURVATURE`]), so the prefactored `L` is kept and `K` enters as a low-rank
//!   (Woodbury) update ([`super::low_rank`]): two solves with `L` a step and a small dense
//!   Cholesky factor, rebuilt at every accepted step while any pair is active. A step after which the
//!   active pairs changed is `(L + K)⁻¹g` alone, without L-BFGS's pairs (see the solver).
//!   [`ContactStep::Refactor`] instead factors the full `3n × 3n` matrix `L⊗I₃ + K` whenever
//!   `K` is recomputed: `facesim bench contact` measures both (the low-rank update is the
//!   default because it is faster).
//! - **Line search**: each step's candidate pairs come from a Verlet list
//!   ([`crate::contact::VerletList`]: pairs with their distance where the list was built;
//!   a step leaving the slack adds the pairs beyond the list's reach that the relative
//!   motion since then can bring close; rebuilt once a vertex has moved far), filtered to
//!   the pairs whose distance minus their relative motion is below d̂ — on the face a few
//!   thousand of the ~10⁵ pairs whose boxes overlap. The step filter of
//!   [`crate::contact::refined`] over them caps the step so that every pair keeps a tenth of
//!   its distance: each pair by the better of its division-plane bound (motion along the
//!   plane, lips sliding over each other, is free) and, for the pairs that limit that,
//!   additive CCD (a pair sliding around a curved lip leaves its plane early), and the
//!   barrier of every
//!   trial is evaluated over the same pairs (so no pair that comes within d̂ during the step
//!   is missed). The broad-phase trees ([`crate::contact::FixedPrimitives`]) are prepared
//!   once per pose: the teeth's (the bones are fixed during a solve) and the layout of the
//!   soft primitives' trees, whose boxes are refit at every build. The list a solve ends
//!   with is the next one's start ([`ContactCache`], kept in the state).
//! - **Stiffness**: κ starts where the barrier gradient balances the elastic one (ipc-toolkit's
//!   rule, with the mean diagonal of `L` over the contact region as the stiffness scale) and
//!   doubles while the closest pair keeps approaching at a tiny distance.

use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::attachment::BonePose;
use super::global_matrix::GlobalMatrix;
use super::low_rank::{Curvature, SparseColumn};
use crate::contact::barrier::{initial_barrier_stiffness, update_barrier_stiffness};
use crate::contact::planar::DEFAULT_KEEP;
use crate::contact::surface::{ContactBinding, FaceContact};
use crate::contact::{
    BarrierPotential, Candidates, Collisions, ContactError, FixedPrimitives, HessianFactors,
    VerletList, refined_step_over,
};

/// Longest move of a contact vertex in one line-search step (cm, ≈ 3.4·d̂ on the neutral
/// face). Shorter than the 0.25 it was: the swept boxes of long steps overlap so many
/// primitives that the broad phase and the step filter cost more than the extra steps
/// (`facesim bench contact`: interactive 124× → 71× the contact-free frame, 30 → 15
/// iterations; 0.05 stalls the interactive solve). Re-measured with the filtered Verlet
/// lists: 0.05 left an interactive frame failing, 0.2 doubled the frame time.
const MAX_CONTACT_MOVE: f64 = 0.1;
/// Verlet-list slack δ, in units of d̂. Measured with the filtered lists (interactive
/// preset): 0.5 and 1 are alike, 2 is 1.5× and 3.5 or 6 are 4× slower per frame (the
/// list's reach `d̂ + 2δ` holds many more neighbouring pairs to enumerate).
const VERLET_SLACK: f64 = 1.0;
/// How far (in units of the slack δ) a vertex may have moved from where the Verlet list was
/// built before a step that leaves the slack rebuilds it rather than adding the pairs
/// beyond the list's reach from the relative motion ([`VerletList::near_beyond`]).
const VERLET_REUSE: f64 = 4.0;

/// How far (in units of the slack δ) a vertex may have moved since the list was built for
/// a frame's start to keep the last frame's Verlet list: a frame starts with every pair
/// within reach re-measured, so a list older than this costs more in pairs beyond it than
/// one rebuild.
const START_REUSE: f64 = 2.0;

/// Short steps (within the slack) that leave the Verlet list's slack take the pairs beyond
/// the list from the relative motion ([`VerletList::near_beyond`]) this many times; the next
/// one rebuilds the list. A rebuild costs about as much as three such steps (interactive
/// drag: 18 against 5 ms), so renting before buying keeps the cost within twice the best
/// choice: rebuilding at every such step took 4 rebuilds a drag frame, never rebuilding made
/// the final preset (many short steps) 1.5× slower.
const SHORT_STEPS_BEYOND: usize = 3;

/// The share of a stencil's largest curvature below which the step's `K` leaves an
/// eigenpair out ([`crate::contact::psd::positive_part_factors`]): `K` keeps each pair's
/// dominant direction (the pair's normal), so the low-rank update has about one column per
/// active pair instead of up to twelve. `K` stays PSD and the preconditioner positive
/// definite; what it leaves out is a lower bound's gap, the line search covers it. Measured
/// (`facesim bench editor --contact`, interactive, one thread): keeping every positive
/// eigenpair gave 480–980 columns for 120–200 simulation vertices and a 449 ms linear
/// algebra share a frame; keeping above 0.1, 0.5 or 0.99 of the largest took 120–140 ms with
/// the same iterations, 0.5 the fastest frame.
const DOMINANT_CURVATURE: f64 = 0.5;

/// How contact-aware steps bring in the barrier's curvature.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ContactStep {
    /// Keep the prefactored `L`; add the barrier Hessian as a low-rank (Woodbury) update, or
    /// factor `L⊗I₃ + K` afresh when `K` has more columns than that costs
    /// ([`super::solver`]'s `REFACTOR_COLUMNS_PER_VERTEX`).
    #[default]
    LowRankUpdate,
    /// Factor `L⊗I₃ + K` from scratch at every step (the reference it is measured against).
    Refactor,
}

/// What contact did during a solve.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ContactStats {
    /// Active pairs (closer than d̂) at the end.
    pub active_pairs: usize,
    /// Smallest distance between contact surfaces at the end (cm; d̂ when none is active).
    pub min_distance: f64,
    /// Barrier stiffness at the end.
    pub stiffness: f64,
    /// Line-search steps that the step filter ([`crate::contact::refined`]) shortened.
    pub filter_limited_steps: usize,
    /// Bone-pose stages (1 unless moving the teeth straight to the new pose would cross a
    /// surface; then the pose is reached in collision-free stages).
    pub pose_stages: usize,
    /// Of those, stages that carried the tissue with the bones before solving (the rest
    /// moved only the teeth; see [`super::staging`]).
    #[serde(default)]
    pub carried_stages: usize,
    /// Whether the solve started over from rest: the bone pose lay nearer rest than the
    /// starting state's, or could not be reached from it ([`super::SimError::PoseUnreachable`]).
    #[serde(default)]
    pub from_rest: bool,
    /// Edge–triangle crossings of the contact surface after the solve that were not there at
    /// rest, when the solve audited them (`SolveSettings::audit_crossings`): always `Some(0)`
    /// in a returned result (anything else is [`super::SimError::Intersecting`]); `None`
    /// when not audited.
    #[serde(default)]
    pub new_crossings: Option<usize>,
    /// Candidate lists built (the rest of the steps reused one).
    pub candidate_builds: usize,
    /// Pairs that the step filter and the line-search barrier checked, summed over steps (the pairs
    /// that can come within d̂ during each step).
    #[serde(default)]
    pub candidate_pairs: usize,
    /// Time building Verlet lists (BVH over grown boxes, the pairs' distances), checking
    /// they still cover the step, and filtering each step's pairs from them.
    pub broad_phase_time: Duration,
    /// Time evaluating the barrier (active sets, value, gradient, Hessian, PSD projection).
    pub barrier_time: Duration,
    /// Time filtering steps (division planes, CCD on the pairs that limit them:
    /// [`crate::contact::refined`]).
    pub filter_time: Duration,
    /// Time in contact-aware linear algebra (the Woodbury LU or the refactorization, the
    /// extra solves).
    pub linear_time: Duration,
    /// Time moving the bones to the new pose: linearizing the tissue for the carried start
    /// and certifying each stage's path free of crossings ([`super::staging`]).
    #[serde(default)]
    pub staging_time: Duration,
    /// Time in the after-solve crossing check.
    #[serde(default)]
    pub check_time: Duration,
    /// Whether the contact gate skipped the contact machinery for this solve, or why not
    /// ([`super::contact_gate`]).
    #[serde(default)]
    pub gate: super::contact_gate::GateOutcome,
    /// Time in the gate's contact-free attempt and its checks (the whole solve when it was
    /// kept; wasted when refused).
    #[serde(default)]
    pub gate_time: Duration,
}

/// Contact set up for a simulator: the face's surfaces and the stiffness scale for κ. (The
/// columns of `L⁻¹` over the region the low-rank steps read live in the simulator's
/// [`super::low_rank::InverseColumns`], filled when contact is set up.)
pub(crate) struct ContactModel {
    pub(crate) face: FaceContact,
    /// Mean diagonal of `L` over the region: the stiffness scale for κ.
    pub(crate) stiffness_scale: f64,
    pub(crate) step: ContactStep,
    pub(crate) gate: super::contact_gate::ContactGate,
    /// Most bone-pose stages a solve may take ([`super::solver::MAX_POSE_STAGES`]; tests
    /// lower it).
    pub(crate) stage_limit: usize,
    /// Shortest stage a warm start tries ([`super::solver::SHORTEST_WARM_STAGE`]; tests
    /// raise it).
    pub(crate) shortest_warm_stage: f64,
}

impl ContactModel {
    pub(crate) fn new(face: FaceContact, global: &GlobalMatrix) -> Self {
        let region = face.region_sim_vertices();
        let stiffness_scale = if region.is_empty() {
            1.0
        } else {
            region
                .iter()
                .map(|&v| global.diagonal()[v as usize])
                .sum::<f64>()
                / region.len() as f64
        };
        Self {
            face,
            stiffness_scale,
            step: ContactStep::default(),
            gate: super::contact_gate::ContactGate::default(),
            stage_limit: super::solver::MAX_POSE_STAGES,
            shortest_warm_stage: super::solver::SHORTEST_WARM_STAGE,
        }
    }
}

/// A Verlet list with the trees over the teeth it was built with: the broad phase a contact
/// solve ended with, kept in the [`super::SimState`] so the next solve starts from it, and
/// the pairs within d̂ where that solve ended. A start there (the next frame's first
/// linearization, or a solve with the bones unchanged) takes its active set from those
/// pairs, with no broad phase of its own; a start elsewhere reads it from the list. The next
/// solve keeps the list while every contact vertex, teeth included, stays within
/// [`VERLET_REUSE`]·δ of where it was built. Any list is sound for any later positions: the
/// pairs beyond it come from the relative motion since, the teeth's motion to a new pose
/// included ([`VerletList::near_beyond`]).
#[derive(Clone)]
pub(crate) struct ContactCache {
    fixed: Arc<FixedPrimitives>,
    list: Arc<VerletList>,
    ended: Option<Arc<Ended>>,
}

/// Where a contact solve ended: the contact positions and pairs that hold every pair within
/// d̂ there (its last step's candidates, or its start's active set).
struct Ended {
    y: Vec<f64>,
    pairs: Candidates,
}

/// How far (cm) a start's contact positions may be from where the last solve ended to take
/// that solve's active set. Recomputed from the tissue, the same state's positions differ
/// from the solve's own (advanced step by step) by rounding (~10⁻¹⁵ cm); a pair that is
/// within d̂ at one and not at the other is then within ~10⁻⁹ cm of d̂, where its barrier
/// (∝ (d − d̂)²) is nil.
const ENDED_HERE: f64 = 1e-9;

impl std::fmt::Debug for ContactCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContactCache")
            .field("fixed_vertices", &self.fixed.vertex_count())
            .field("pairs", &self.list.len())
            .finish()
    }
}

/// The trees over the teeth at `y`'s pose: `fixed` if built already, else built now (and
/// kept there).
fn trees_here(
    fixed: &mut Option<Arc<FixedPrimitives>>,
    mesh: &crate::contact::ContactMesh,
    y: &[f64],
) -> Result<Arc<FixedPrimitives>, ContactError> {
    if fixed.is_none() {
        *fixed = Some(Arc::new(FixedPrimitives::new(mesh, y)?));
    }
    Ok(fixed.clone().expect("set above"))
}

/// `K = Wᵀ·[∇²B]₊·W` as factor columns: each stencil's factor `g` (`[∇²B]₊ = Σ ggᵀ`) pulled
/// back through the bindings, `u = Wᵀg`. A contact vertex embedded with weights `wⱼ` in a
/// tetrahedron spreads its 3-vector over the tet's four vertices; one the bones carry adds
/// nothing (the bones are fixed during a solve).
fn pull_back(face: &FaceContact, stencils: &[HessianFactors]) -> Curvature {
    let bindings = face.bindings();
    let mut columns = Vec::new();
    for s in stencils {
        for g in &s.factors {
            let mut column: SparseColumn = Vec::with_capacity(16);
            for (p, &cv) in s.vertices.iter().enumerate() {
                if let ContactBinding::Embedded { tet, weights } = bindings[cv as usize] {
                    let gp = g.fixed_rows::<3>(3 * p).into_owned();
                    for (&v, &w) in tet.iter().zip(&weights) {
                        column.push((v, w * gp));
                    }
                }
            }
            column.sort_unstable_by_key(|e| e.0);
            column.dedup_by(|later, kept| {
                let same = later.0 == kept.0;
                if same {
                    kept.1 += later.1;
                }
                same
            });
            if !column.is_empty() {
                columns.push(column);
            }
        }
    }
    Curvature::from_columns(columns)
}

/// Per-solve contact state: positions, the active set, κ, the step's candidates and solver.
pub(crate) struct ContactSolve<'a> {
    model: &'a ContactModel,
    pub(crate) potential: BarrierPotential,
    kappa_max: f64,
    bbox: f64,
    /// Contact positions at the current `x`, the active set there, and pairs that hold it
    /// (the last accepted step's candidates, or the start's active set).
    y: Vec<f64>,
    collisions: Collisions,
    holding: Candidates,
    /// Unit-stiffness barrier `Σ m·b` at the current `x`.
    barrier: f64,
    prev_min_distance2: f64,
    /// The current step: `W·d`, its candidates, the trial positions and active set.
    dy: Vec<f64>,
    candidates: Candidates,
    /// The Verlet list the step's candidates are filtered from (built at this solve's pose
    /// or taken over from the last solve's).
    verlet: Option<ContactCache>,
    /// Short steps that left the list's slack since it was built (see
    /// [`SHORT_STEPS_BEYOND`]).
    short_beyond_since_build: usize,
    /// Broad-phase trees over the rigid primitives (the teeth) at this solve's pose, built
    /// once (when a list is first built at it): the bones are fixed during a solve, so only
    /// the soft primitives' trees are refit per build.
    fixed: Option<Arc<FixedPrimitives>>,
    y_trial: Vec<f64>,
    trial_collisions: Collisions,
    trial_barrier: f64,
    curvature: Curvature,
    /// The barrier's dominant curvature per active pair at the current `x` (what
    /// `curvature` is pulled back from; `push` reads it too).
    stencils: Vec<HessianFactors>,
    /// Whether the last accepted step changed `curvature` (it is recomputed at every step
    /// while any pair is active, and once when the last pair leaves).
    curvature_refreshed: bool,
    /// Whether the last accepted step changed the set of active pairs.
    active_set_changed: bool,
    pub(crate) stats: ContactStats,
}

impl<'a> ContactSolve<'a> {
    /// Starts at `x`: the active set, and κ balanced against the elastic gradient `g_el`
    /// (for one linearization: no line search will follow, so no Verlet list is built).
    pub(crate) fn start(
        model: &'a ContactModel,
        x: &[f64],
        bones: &BonePose,
        g_el: &[f64],
        cache: Option<&ContactCache>,
    ) -> Result<Self, ContactError> {
        Self::start_with(model, x, bones, g_el, false, cache)
    }

    /// [`ContactSolve::start`] for a solve: the Verlet list the first line-search step needs
    /// is built here and the active set read from it (one broad phase instead of two).
    pub(crate) fn start_solve(
        model: &'a ContactModel,
        x: &[f64],
        bones: &BonePose,
        g_el: &[f64],
        cache: Option<&ContactCache>,
    ) -> Result<Self, ContactError> {
        Self::start_with(model, x, bones, g_el, true, cache)
    }

    /// `cache`: the broad phase of the solve that left the state (see [`ContactCache`]).
    fn start_with(
        model: &'a ContactModel,
        x: &[f64],
        bones: &BonePose,
        g_el: &[f64],
        with_list: bool,
        cache: Option<&ContactCache>,
    ) -> Result<Self, ContactError> {
        let m = model.face.vertex_count();
        let mut y = vec![0.0; 3 * m];
        model.face.positions(x, bones, &mut y);
        let dhat = model.face.dhat();
        let t = Instant::now();
        let mesh = model.face.mesh();
        let still = vec![0.0; 3 * m];
        let slack = VERLET_SLACK * dhat;
        let mut fixed = cache.filter(|c| c.fixed.holds(&y)).map(|c| c.fixed.clone());
        let ended_here = cache.and_then(|c| {
            let ended = c.ended.as_ref()?;
            let here = ended
                .y
                .iter()
                .zip(&y)
                .all(|(a, b)| (a - b).abs() <= ENDED_HERE);
            here.then(|| (c, ended.pairs.clone()))
        });
        let kept = || cache.filter(|c| c.list.moved_within(&y, &still, START_REUSE * slack));
        let (verlet, close, built) = match ended_here {
            // Where the last solve ended: its active set.
            Some((c, close)) => (Some(c.clone()), close, false),
            // Near where the last solve's list was built: the active set from it (the pairs
            // a broad phase finds).
            None if let Some(c) = kept() => {
                let close = c.list.near_beyond(mesh, &c.fixed, &y, &still, dhat)?.0;
                (Some(c.clone()), close, false)
            }
            None => {
                let trees = trees_here(&mut fixed, mesh, &y)?;
                if with_list {
                    let list = VerletList::build(mesh, &trees, &y, dhat, slack)?;
                    let close = list.near(mesh, &y, &still, dhat)?;
                    let list = Arc::new(list);
                    let cache = ContactCache {
                        fixed: trees,
                        list,
                        ended: None,
                    };
                    (Some(cache), close, true)
                } else {
                    (None, Candidates::build_with(mesh, &trees, &y, dhat)?, false)
                }
            }
        };
        let collisions = Collisions::from_candidates(mesh, &close, &y, dhat)?;
        let broad = t.elapsed();
        let t = Instant::now();
        let unit = BarrierPotential::new(dhat, 1.0)?;
        let mut gb_y = vec![0.0; 3 * m];
        unit.add_gradient(&collisions, &y, &mut gb_y)?;
        let mut gb = vec![0.0; g_el.len()];
        model.face.add_pulled_back(&gb_y, &mut gb);
        let bbox = model.face.mesh().bbox_diagonal(&y);
        let (kappa, kappa_max) =
            initial_barrier_stiffness(bbox, dhat, model.stiffness_scale, g_el, &gb, 1e11);
        let barrier = unit.value(&collisions, &y)?;
        let potential = BarrierPotential::new(dhat, kappa)?;
        let stats = ContactStats {
            stiffness: kappa,
            broad_phase_time: broad,
            barrier_time: t.elapsed(),
            pose_stages: 1,
            candidate_builds: usize::from(built),
            ..ContactStats::default()
        };
        let prev_min_distance2 = collisions.min_distance_squared();
        let mut solve = Self {
            model,
            potential,
            kappa_max,
            bbox,
            y,
            collisions,
            holding: close,
            barrier,
            prev_min_distance2,
            dy: vec![0.0; 3 * m],
            candidates: Candidates::default(),
            verlet,
            short_beyond_since_build: 0,
            fixed,
            y_trial: vec![0.0; 3 * m],
            trial_collisions: Collisions::default(),
            trial_barrier: 0.0,
            curvature: Curvature::default(),
            stencils: Vec::new(),
            curvature_refreshed: true,
            active_set_changed: true,
            stats,
        };
        solve.update_curvature()?;
        Ok(solve)
    }

    /// The smallest distance between contact surfaces at the current `x` among the pairs
    /// within d̂ (d̂ when none is that close).
    pub(crate) fn min_distance(&self) -> f64 {
        self.collisions.min_distance_squared().sqrt()
    }

    /// `κ·B` at the current `x`.
    pub(crate) fn energy(&self) -> f64 {
        self.potential.stiffness * self.barrier
    }

    /// `g += κ·Wᵀ∇B` at the current `x`.
    pub(crate) fn add_gradient(&mut self, g: &mut [f64]) -> Result<(), ContactError> {
        let t = Instant::now();
        let gy = self.potential.gradient(&self.collisions, &self.y)?;
        self.model.face.add_pulled_back(&gy, g);
        self.stats.barrier_time += t.elapsed();
        Ok(())
    }

    /// `g += κ·Wᵀ∇B` at the trial point.
    pub(crate) fn add_trial_gradient(&mut self, g: &mut [f64]) -> Result<(), ContactError> {
        let t = Instant::now();
        let gy = self
            .potential
            .gradient(&self.trial_collisions, &self.y_trial)?;
        self.model.face.add_pulled_back(&gy, g);
        self.stats.barrier_time += t.elapsed();
        Ok(())
    }

    /// Prepares the step `x → x + α·d`: its candidate pairs and the largest collision-free
    /// `α ∈ [0, 1]`. Steps that would move a contact vertex farther than
    /// [`MAX_CONTACT_MOVE`] are shortened first (a trust region that keeps the broad phase
    /// local).
    ///
    /// Candidates are kept between steps (a Verlet list): they are built at positions `y₀`
    /// (pairs closer than `d̂ + 2δ`, with their distances), which covers every pair that can
    /// come within d̂ while each vertex stays within `δ` of `y₀`. A step within that uses the
    /// list's pairs that can come within d̂ along it; a step leaving it adds the pairs beyond
    /// the list's reach that the relative motion since `y₀` can bring within d̂
    /// ([`VerletList::near_beyond`]: neighbours moving together are never visited). The list
    /// is rebuilt when some vertex has moved farther than [`VERLET_REUSE`]·δ from `y₀`. The
    /// step filter and the trials' barrier then use only those pairs.
    pub(crate) fn max_step(&mut self, d: &[f64]) -> Result<f64, ContactError> {
        self.model.face.displacement(d, &mut self.dy);
        let longest = self
            .dy
            .chunks_exact(3)
            .map(|v| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt())
            .fold(0.0, f64::max);
        let cap = if longest > MAX_CONTACT_MOVE {
            MAX_CONTACT_MOVE / longest
        } else {
            1.0
        };
        let swept: Vec<f64> = self.dy.iter().map(|v| cap * v).collect();
        let mesh = self.model.face.mesh();
        let dhat = self.potential.dhat;
        let t = Instant::now();
        let slack = VERLET_SLACK * dhat;
        // A step longer than the slack keeps the list and adds the pairs beyond its reach
        // (cheap while the surface has moved smoothly since the list was built) until some
        // vertex has gone farther than VERLET_REUSE·δ. Short steps leaving the slack do so
        // too, up to SHORT_STEPS_BEYOND of them; the next rebuilds the list (the steps
        // after it are likely covered again).
        let long_step = cap * longest > slack;
        let beyond_allowed = long_step || self.short_beyond_since_build < SHORT_STEPS_BEYOND;
        let rebuild = self.verlet.as_ref().is_none_or(|c| {
            let reusable = c.list.covers(&self.y, &swept)
                || (beyond_allowed && c.list.moved_within(&self.y, &swept, VERLET_REUSE * slack));
            !reusable
        });
        if rebuild {
            let fixed = trees_here(&mut self.fixed, mesh, &self.y)?;
            let list = VerletList::build(mesh, &fixed, &self.y, dhat, slack)?;
            self.verlet = Some(ContactCache {
                fixed,
                list: Arc::new(list),
                ended: None,
            });
            self.stats.candidate_builds += 1;
            self.short_beyond_since_build = 0;
        }
        let ContactCache { fixed, list, .. } = self.verlet.as_ref().expect("built above");
        self.candidates = if list.covers(&self.y, &swept) {
            list.near(mesh, &self.y, &swept, dhat)?
        } else {
            if !long_step {
                self.short_beyond_since_build += 1;
            }
            list.near_beyond(mesh, fixed, &self.y, &swept, dhat)?.0
        };
        self.stats.candidate_pairs += self.candidates.len();
        self.stats.broad_phase_time += t.elapsed();
        let t = Instant::now();
        let report = refined_step_over(mesh, &self.candidates, &self.y, &swept, DEFAULT_KEEP)?;
        self.stats.filter_time += t.elapsed();
        if report.step < 1.0 {
            self.stats.filter_limited_steps += 1;
        }
        Ok(cap * report.step)
    }

    /// `κ·B` at the trial point `x + α·d` of the prepared step.
    pub(crate) fn trial_energy(&mut self, alpha: f64) -> Result<f64, ContactError> {
        let t = Instant::now();
        for ((yt, y), dy) in self.y_trial.iter_mut().zip(&self.y).zip(&self.dy) {
            *yt = y + alpha * dy;
        }
        let mesh = self.model.face.mesh();
        self.trial_collisions = Collisions::from_candidates(
            mesh,
            &self.candidates,
            &self.y_trial,
            self.potential.dhat,
        )?;
        let unit = BarrierPotential::new(self.potential.dhat, 1.0)?;
        self.trial_barrier = unit.value(&self.trial_collisions, &self.y_trial)?;
        self.stats.barrier_time += t.elapsed();
        Ok(self.potential.stiffness * self.trial_barrier)
    }

    /// `κ·B` at the last trial point.
    pub(crate) fn trial_energy_value(&self) -> f64 {
        self.potential.stiffness * self.trial_barrier
    }

    /// Moves to the accepted trial point; updates κ and the step solver. Returns the new
    /// `κ·B` (κ may have changed).
    pub(crate) fn accept(&mut self) -> Result<f64, ContactError> {
        std::mem::swap(&mut self.y, &mut self.y_trial);
        std::mem::swap(&mut self.collisions, &mut self.trial_collisions);
        self.holding.clone_from(&self.candidates);
        self.barrier = self.trial_barrier;
        let min_d2 = self.collisions.min_distance_squared();
        let kappa = update_barrier_stiffness(
            self.prev_min_distance2,
            min_d2,
            self.kappa_max,
            self.potential.stiffness,
            self.bbox,
            1e-9,
        );
        self.prev_min_distance2 = min_d2;
        self.potential.stiffness = kappa;
        let (now, before) = (
            &self.collisions.collisions,
            &self.trial_collisions.collisions,
        );
        self.active_set_changed = now.len() != before.len()
            || now
                .iter()
                .zip(before)
                .any(|(a, b)| a.kind != b.kind || a.vertices != b.vertices);
        if !self.stencils.is_empty() || !self.collisions.is_empty() {
            self.update_curvature()?;
        } else {
            self.curvature_refreshed = false;
        }
        Ok(self.energy())
    }

    /// Whether the last [`ContactSolve::accept`] changed the curvature (the step's
    /// preconditioner is then rebuilt).
    pub(crate) fn curvature_refreshed(&self) -> bool {
        self.curvature_refreshed
    }

    /// Whether the step's L-BFGS pairs no longer describe the energy: the step's curvature
    /// holds pairs, and the last accepted step changed which pairs are active (the solver
    /// then takes the step `(L + K)⁻¹g` alone, see `Simulator::solve_with_contact`).
    pub(crate) fn contact_changed(&self) -> bool {
        !self.curvature.columns.is_empty() && self.active_set_changed
    }

    /// The barrier's curvature at the current `x`, pulled back to the simulation vertices.
    fn update_curvature(&mut self) -> Result<(), ContactError> {
        self.curvature_refreshed = true;
        if self.collisions.is_empty() {
            self.curvature = Curvature::default();
            self.stencils.clear();
            return Ok(());
        }
        let t = Instant::now();
        self.stencils =
            self.potential
                .hessian_factors(&self.collisions, &self.y, DOMINANT_CURVATURE)?;
        self.curvature = pull_back(&self.model.face, &self.stencils);
        self.stats.barrier_time += t.elapsed();
        Ok(())
    }

    /// `K = Wᵀ·[∇²B]₊·W` at the current `x` (empty without active pairs), for the step.
    pub(crate) fn curvature(&self) -> &Curvature {
        &self.curvature
    }

    /// Broad-phase layouts of the contact surface (of whichever trees this solve holds: the
    /// layouts group the soft primitives, at any pose).
    pub(crate) fn layouts(&self) -> &FixedPrimitives {
        match (&self.fixed, &self.verlet) {
            (Some(trees), _) => trees,
            (None, Some(c)) => &c.fixed,
            (None, None) => unreachable!("a contact solve starts with trees or a list"),
        }
    }

    /// Every pair that can come within `within` (cm) while the contact vertices move
    /// straight from `y` to `y + dy` (the teeth with their bones included), from the Verlet
    /// list this state holds ([`VerletList::near_beyond`]: the list's pairs by their
    /// distance where it was built less their relative motion since, and the pairs beyond it
    /// that the relative motion can bring that close); `None` when the state holds no list
    /// (the caller then runs a swept broad phase). Pairs with an activation distance of their
    /// own below their closest approach are left out: they cannot touch.
    pub(crate) fn pairs_along(
        &self,
        y: &[f64],
        dy: &[f64],
        within: f64,
    ) -> Result<Option<Candidates>, ContactError> {
        let Some(ContactCache { fixed, list, .. }) = &self.verlet else {
            return Ok(None);
        };
        let mesh = self.model.face.mesh();
        Ok(Some(list.near_beyond(mesh, fixed, y, dy, within)?.0))
    }

    /// The contact model this solve runs on.
    pub(crate) fn model(&self) -> &'a ContactModel {
        self.model
    }

    /// How steps bring the curvature in.
    pub(crate) fn step_mode(&self) -> ContactStep {
        self.model.step
    }

    /// `−Wᵀ·[∇²B]₊·dy`, with `K`'s dominant part of `[∇²B]₊`: the barrier force on the
    /// simulation vertices, to first order, when the contact vertices move by `dy` (the pose
    /// stages pass the teeth's motion, so the lips they press on are predicted to move
    /// along; see [`super::staging`]).
    pub(crate) fn push(&self, dy: &[f64], n: usize) -> Result<Vec<f64>, ContactError> {
        // The same dominant factors as the step's `K` (kept current with the active set by
        // `update_curvature`), so that a rigid move of everything (teeth and tissue) is
        // balanced: `K·Δx + push(Δy) = 0`.
        let mut fy = vec![0.0; dy.len()];
        for s in &self.stencils {
            let v = nalgebra::SVector::<f64, 12>::from_iterator(
                s.vertices
                    .iter()
                    .flat_map(|&i| (0..3).map(move |k| dy[3 * i as usize + k])),
            );
            for g in &s.factors {
                let gv = g.dot(&v);
                for (slot, &i) in s.vertices.iter().enumerate() {
                    for k in 0..3 {
                        fy[3 * i as usize + k] -= g[3 * slot + k] * gv;
                    }
                }
            }
        }
        let mut fx = vec![0.0; 3 * n];
        self.model.face.add_pulled_back(&fy, &mut fx);
        Ok(fx)
    }

    /// Fills the end-of-solve statistics; the broad phase to keep for the next solve (none
    /// without a line search), with where this one ended.
    pub(crate) fn finish(mut self) -> (ContactStats, Option<ContactCache>) {
        self.stats.active_pairs = self.collisions.len();
        self.stats.min_distance = self.collisions.min_distance_squared().sqrt();
        self.stats.stiffness = self.potential.stiffness;
        let cache = self.verlet.map(|c| ContactCache {
            ended: Some(Arc::new(Ended {
                y: self.y,
                pairs: self.holding,
            })),
            ..c
        });
        (self.stats, cache)
    }
}

#[cfg(test)]
mod tests {
    use super::ContactStats;
    use crate::bench::mouth_poses::{LipField, MouthPose};
    use crate::contact::surface::FaceContact;
    use crate::model::contact_region::FaceContactSettings;
    use crate::sim::{BonePose, Quality, SimState, Simulator, SymTensor};

    /// The coarse neutral with contact, solved with the lips pressed and pursed so that
    /// contact is active: the simulator, the solved state, the actuations, the bones and the
    /// contact stats.
    fn pressed_lips() -> (Simulator, SimState, Vec<SymTensor>, BonePose, ContactStats) {
        let model = crate::model::test_support::coarse_face(None);
        let face = FaceContact::new(model, &FaceContactSettings::default()).unwrap();
        let field = LipField::new(model, &face, 1.5);
        let mut sim = model.simulator().unwrap();
        sim.set_contact(face).unwrap();
        let pose = MouthPose {
            press: 1.0,
            purse: 0.5,
            ..MouthPose::default()
        };
        let (act, bones) = (field.actuations(&pose), pose.bones());
        let mut state = sim.rest_state();
        let stats = sim
            .solve(&act, &bones, &mut state, &Quality::Interactive.settings())
            .unwrap();
        let contact = stats.contact.unwrap();
        assert!(contact.active_pairs > 0, "the test needs active contact");
        (sim, state, act, bones, contact)
    }

    /// The next solve starts from the broad phase the last one ended with (kept in the
    /// state): at the same pose it builds no list while the surface stays near it, the next
    /// frame's pose change still moves the teeth to a crossing-free result, and a state
    /// without the cache builds its list as before.
    #[test]
    fn next_solve_starts_from_the_last_solves_list() {
        let model = crate::model::test_support::coarse_face(None);
        let face = FaceContact::new(model, &FaceContactSettings::default()).unwrap();
        let field = LipField::new(model, &face, 1.5);
        let mut sim = model.simulator().unwrap();
        sim.set_contact(face).unwrap();
        sim.set_contact_gate(crate::sim::ContactGate::Always);
        let settings = crate::sim::SolveSettings {
            audit_crossings: true,
            ..Quality::Preview.settings()
        };
        let pose = |press: f64, jaw_open: f64| MouthPose {
            press,
            purse: 0.5,
            jaw_open,
            ..MouthPose::default()
        };
        let solve = |m: &MouthPose, state: &mut SimState| {
            sim.solve(&field.actuations(m), &m.bones(), state, &settings)
                .unwrap()
                .contact
                .unwrap()
        };
        // A firm press, solved to convergence (the second solve continues the first).
        let mut state = sim.rest_state();
        solve(&pose(0.3, 0.0), &mut state);
        let settled = sim
            .solve(
                &field.actuations(&pose(0.3, 0.0)),
                &pose(0.3, 0.0).bones(),
                &mut state,
                &settings,
            )
            .unwrap();
        assert!(settled.converged(), "{:?}", settled.termination);
        assert!(state.contact_cache.is_some());
        let solved = state.clone();
        let next = pose(0.303, 0.0);
        let contact = solve(&next, &mut state);
        assert!(contact.active_pairs > 0, "the test needs active contact");
        assert_eq!(contact.candidate_builds, 0, "the last solve's list serves");
        let mut cold = SimState {
            contact_cache: None,
            ..solved
        };
        assert!(solve(&next, &mut cold).candidate_builds > 0);
        // The jaw moves on: the list built at the last pose serves the carried start and
        // the solve, and the result is crossing-free (checked by the solve).
        assert_eq!(solve(&pose(0.303, 0.02), &mut state).new_crossings, Some(0));
    }

    /// The after-solve crossing check is an audit: an interactive solve leaves it out (its
    /// steps and stages are certified), an audited one runs it and reports what it found.
    #[test]
    fn the_crossing_check_runs_only_when_audited() {
        let (sim, mut state, act, bones, contact) = pressed_lips();
        assert_eq!(contact.new_crossings, None);
        assert_eq!(contact.check_time, std::time::Duration::ZERO);
        let audited = crate::sim::SolveSettings {
            audit_crossings: true,
            ..Quality::Interactive.settings()
        };
        let stats = sim.solve(&act, &bones, &mut state, &audited).unwrap();
        assert_eq!(stats.contact.unwrap().new_crossings, Some(0));
        assert!(Quality::Final.settings().audit_crossings);
    }

    /// Where the last solve ended (the next frame's linearization), a start takes its active
    /// set from the pairs the solve ended with: the same set a broad phase finds there. It
    /// takes them only there: with the ended pairs emptied, a start there finds no pair, and
    /// one 10⁻⁶ cm away finds them all again (from the list).
    #[test]
    fn a_start_where_the_last_solve_ended_takes_its_active_set() {
        use super::{ContactCache, ContactSolve, Ended};
        use crate::contact::Candidates;
        use std::sync::Arc;
        let (sim, state, _, bones, _) = pressed_lips();
        let model = sim.contact.as_ref().unwrap();
        let cache = state.contact_cache.as_ref().unwrap();
        let ended = cache.ended.as_ref().expect("the solve says where it ended");
        let g = vec![0.0; state.x.len()];
        let start = |x: &[f64], cache: Option<&ContactCache>| {
            ContactSolve::start(model, x, &bones, &g, cache)
                .unwrap()
                .collisions
        };
        let fresh = start(&state.x, None);
        assert!(!fresh.is_empty());
        assert_eq!(start(&state.x, Some(cache)), fresh);
        let emptied = ContactCache {
            ended: Some(Arc::new(Ended {
                y: ended.y.clone(),
                pairs: Candidates::default(),
            })),
            ..cache.clone()
        };
        assert!(start(&state.x, Some(&emptied)).is_empty());
        let nudged: Vec<f64> = state.x.iter().map(|v| v + 1e-6).collect();
        assert_eq!(start(&nudged, Some(&emptied)), start(&nudged, None));
    }

    /// The barrier is part of the energy that sensitivities differentiate: at a solved state
    /// with active contact, `H·v` (elastic + exact barrier Hessian) matches central finite
    /// differences of `∇E` (elastic + barrier gradient).
    #[test]
    fn barrier_hessian_and_gradient_match_finite_differences() {
        let (sim, state, act, bones, contact) = pressed_lips();
        // A direction on the simulation vertices that the contact surface depends on.
        let region = sim.contact().unwrap().region_sim_vertices().to_vec();
        let mut v = vec![0.0; state.x.len()];
        for (k, &r) in region.iter().enumerate() {
            for c in 0..3 {
                v[3 * r as usize + c] = (((7 * k + 3 * c) % 11) as f64 - 5.0) / 5.0;
            }
        }
        let shifted = |h: f64| {
            let mut s = state.clone();
            for (x, d) in s.x.iter_mut().zip(&v) {
                *x += h * d;
            }
            s
        };
        // Small enough to stay on one side of every pair's d̂ and closest-feature boundary.
        let h = 1e-4 * contact.min_distance;
        let (_, gp) = sim.energy_gradient(&act, &bones, &shifted(h)).unwrap();
        let (_, gm) = sim.energy_gradient(&act, &bones, &shifted(-h)).unwrap();
        let hv = sim
            .hessian_vector_product(&act, &bones, &state, &v)
            .unwrap();
        let fd: Vec<f64> = gp
            .iter()
            .zip(&gm)
            .map(|(p, m)| (p - m) / (2.0 * h))
            .collect();
        let norm = |a: &[f64]| a.iter().map(|x| x * x).sum::<f64>().sqrt();
        let diff: Vec<f64> = hv.iter().zip(&fd).map(|(a, b)| a - b).collect();
        let rel = norm(&diff) / norm(&fd);
        assert!(rel < 1e-5, "H·v vs finite differences: {rel:e}");
        // Without the barrier's Hessian the product would be off: the check can fail.
        let mut plain = state.clone();
        plain.contact_stiffness = None;
        let hv_plain = sim
            .hessian_vector_product(&act, &bones, &plain, &v)
            .unwrap();
        let off: Vec<f64> = hv_plain.iter().zip(&fd).map(|(a, b)| a - b).collect();
        assert!(norm(&off) / norm(&fd) > 1e3 * rel);
    }

    /// `∇E·v` (elastic + `κ·Wᵀ∇B`) matches central differences of `E` (elastic + `κ·B`)
    /// with contact active, at the solved state and at a state off equilibrium (another
    /// active set). The barrier's share of the slope is far above the tolerance, so a barrier
    /// gradient that disagreed with its value (κ, mollifier, embedding) would fail.
    #[test]
    fn energy_gradient_with_contact_matches_finite_differences_of_the_energy() {
        let (sim, state, act, bones, contact) = pressed_lips();
        let region = sim.contact().unwrap().region_sim_vertices().to_vec();
        let direction = |a: usize, b: usize| {
            let mut v = vec![0.0; state.x.len()];
            for (k, &r) in region.iter().enumerate() {
                for c in 0..3 {
                    v[3 * r as usize + c] = (((a * k + b * c) % 11) as f64 - 5.0) / 5.0;
                }
            }
            v
        };
        let shifted = |s: &crate::sim::SimState, v: &[f64], h: f64| {
            let mut s = s.clone();
            for (x, d) in s.x.iter_mut().zip(v) {
                *x += h * d;
            }
            s
        };
        let off_equilibrium = shifted(&state, &direction(5, 2), 0.2 * contact.min_distance);
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p * q).sum::<f64>();
        for (s, v) in [
            (&state, direction(7, 3)),
            (&off_equilibrium, direction(3, 7)),
        ] {
            let (_, g) = sim.energy_gradient(&act, &bones, s).unwrap();
            let face = sim.contact().unwrap();
            let mut y = vec![0.0; 3 * face.vertex_count()];
            face.positions(&s.x, &bones, &mut y);
            assert!(
                !face.collisions(&y).unwrap().is_empty(),
                "contact must be active"
            );
            // Small enough to stay on one side of every pair's d̂ and feature boundary,
            // large enough for the energy difference to be well above round-off.
            let h = 1e-4 * contact.min_distance;
            let (ep, _) = sim
                .energy_gradient(&act, &bones, &shifted(s, &v, h))
                .unwrap();
            let (em, _) = sim
                .energy_gradient(&act, &bones, &shifted(s, &v, -h))
                .unwrap();
            let fd = (ep - em) / (2.0 * h);
            let slope = dot(&g, &v);
            let tol = 1e-4 * slope.abs();
            assert!(
                (slope - fd).abs() <= tol,
                "∇E·v = {slope:e}, finite differences {fd:e}"
            );
            let mut plain = s.clone();
            plain.contact_stiffness = None;
            let (_, g_plain) = sim.energy_gradient(&act, &bones, &plain).unwrap();
            let barrier_slope = slope - dot(&g_plain, &v);
            assert!(
                barrier_slope.abs() > 100.0 * tol,
                "the barrier's share of the slope ({barrier_slope:e}) must dominate the tolerance"
            );
        }
    }
}
