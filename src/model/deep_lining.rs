//! The deep mouth lining kept off the teeth and off itself: a contact pass over the render
//! vertices that the solver's contact surface leaves out.
//!
//! The solver's contact ([`super::contact_region`]) holds the lips and the lining within
//! `lining_reach` of the lip line. The lining deeper in the mouth (the cheeks' inside, the floor
//! of the mouth, the lining along the gums) is no simulation vertex: it follows the tissue with
//! long levers or the bones by the rig's jaw maps, and those kinematic bindings carry it through
//! the teeth as the jaw moves (the rig's own shapes do too). This pass moves only those *free*
//! vertices, after the solve, to where they are crossing-free:
//!
//! `min_p  ½·Σᵢ wᵢ‖pᵢ − bᵢ‖² + κ·B(p)`
//!
//! over the free lining and its *obstacles* (the teeth, the solver's contact lining and the
//! lip-line skin), where `bᵢ` is where the bindings put vertex `i` (cm), `B` the IPC barrier
//! over the pass's surface (free against free and free against obstacles; obstacles do not
//! meet each other here, the solver and the jaw pose keep them apart), `wᵢ = 1` for a free
//! vertex and [`OBSTACLE_WEIGHT`] for an obstacle. It starts at rest (crossing-free but for
//! the rig's own crossings at rest, which are attached and left alone,
//! [`crate::contact::surface::with_rest_close_pairs`]) and takes projected-Newton steps
//! `(W + [∇²B]₊)·d = −∇E` ([`solve_spd`]) cut by CCD, so no configuration it passes through
//! crosses. The obstacles, pulled by a spring `10⁶` times stiffer, end within `F/w` of where
//! the solve put them (µm, up to 0.3 mm where the lining is pressed hard); the pass then puts
//! them back exactly, in CCD-certified rounds that let the lining make way
//! ([`DeepLining::put_obstacles_back`]). A free vertex moves only as far as the teeth push
//! it: where nothing is near, `pᵢ = bᵢ`.

use std::time::Instant;

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::FaceModel;
use crate::contact::barrier_first_derivative;
use crate::contact::potential::HessianBlock;
use crate::contact::surface::{FaceContact, with_rest_close_pairs};
use crate::contact::{
    BarrierPotential, Candidates, CcdOptions, Collisions, ContactError, ContactMesh, Projection,
    collision_free_step_over,
};
use crate::geometry::triangles::compact_in_index_order;
use crate::rig::Region;
use crate::sim::Quality;

/// The obstacles' spring, relative to the free lining's: they end within `F/w` of their
/// bound positions, which the last, certified move closes.
pub const OBSTACLE_WEIGHT: f64 = 1e6;

/// Newton stops once no vertex's step is longer than this (cm).
const STEP_TOLERANCE: f64 = 1e-4;

/// Newton iterations before the pass gives up (its positions are then crossing-free but not
/// at the minimum, and the stats say so).
const MAX_ITERATIONS: usize = 200;

/// Rounds of the obstacles' certified return ([`DeepLining::put_obstacles_back`]) before the
/// pass gives up with [`DeepLiningError::ObstaclesBlocked`] (it gives up sooner once a round
/// frees no more of the way than the one before).
const PUT_BACK_ROUNDS: usize = 20;

/// Newton steps the free lining takes in each round of the obstacles' return to make way
/// (the last round's, once they are back, run to convergence).
const MAKE_WAY_ITERATIONS: usize = 30;

/// The farthest (cm) the barrier must be able to hold a free vertex from where its binding
/// puts it, at half of d̂ from what it meets: it sets the barrier's stiffness.
const HOLD: f64 = 1.0;

/// A pair closer than this share of d̂, and still closing, doubles κ (up to 10⁴ times its
/// start), as ipc-toolkit's update does.
const TIGHT: f64 = 0.01;

/// `(κ, κ_max)`: `κ·|∂b/∂d|` at `d = d̂/2` is the pull of a free vertex [`HOLD`] from its
/// binding (unit weight), `b(d², d̂²)` the barrier of squared distances, so
/// `∂b/∂d = 2d·b′(d²)`.
fn stiffness(dhat: f64) -> (f64, f64) {
    let d = 0.5 * dhat;
    let force = (2.0 * d * barrier_first_derivative(d * d, dhat * dhat)).abs();
    let kappa = HOLD / force;
    (kappa, 1e4 * kappa)
}

/// Pairs closer than this fraction of d̂ at rest are attached (neither barrier nor CCD
/// takes them): the rig's lining lying on its gum (1e-5 cm). The solver's
/// [`crate::contact::surface::ATTACHED_AT_REST`], 0.1, also leaves out lining edges 1.3–1.7e-3
/// cm (0.05–0.06 d̂) from a tooth's edge at rest, and the lining the pass moves, or its
/// tissue-bound neighbour, slid through the tooth there (a jaw sideways, a lip press); 0.01
/// took those in too but slowed the pass threefold.
const ATTACHED_AT_REST: f64 = 0.04;

/// Vertex groups of the pass's contact mesh.
const FREE: u16 = 0;
const OBSTACLE: u16 = 1;

/// What the pass did for one frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DeepLiningStats {
    /// Newton steps taken.
    pub iterations: usize,
    /// Whether Newton reached its tolerance (the positions are crossing-free either way).
    pub converged: bool,
    /// Active pairs (closer than d̂) at the end.
    pub active_pairs: usize,
    /// How far the pass moved the farthest free vertex from where its binding put it (cm).
    pub largest_push: f64,
    pub ms: f64,
    /// Why the pass failed, if it did: the frame then shows the lining where its bindings
    /// put it.
    #[serde(default)]
    pub error: Option<String>,
}

/// Whether frames solved at `quality` with `contact` get the pass: final frames with contact
/// (the editor's refined frame once the sliders rest, and exports). From rest it costs a
/// median 0.4 s per pose on the sample (11 s at worst, a lower lip rolled in), warm-started
/// from the last frame much less; the interactive and preview presets leave it out.
pub fn runs_at(quality: Quality, contact: bool) -> bool {
    contact && quality == Quality::Final
}

/// The pass's last configuration (crossing-free, obstacles where that frame's solve put
/// them) and its barrier stiffness: the next frame starts from them instead of from rest.
#[derive(Clone, Debug, Default)]
pub struct LiningMemory {
    x: Option<Vec<f64>>,
    kappa: Option<f64>,
}

/// Errors of the pass.
#[derive(Debug, thiserror::Error)]
pub enum DeepLiningError {
    #[error("deep lining contact: {0}")]
    Contact(#[from] ContactError),
    #[error(
        "deep lining contact: {count} render positions given, the pass needs at least {expected}"
    )]
    Positions { count: usize, expected: usize },
    #[error(
        "deep lining contact: the obstacles could not be put back where the solve put them without crossing the lining (step {step:.3})"
    )]
    ObstaclesBlocked { step: f64 },
}

/// The pass of one face (module doc): its surface and who is free.
#[derive(Clone, Debug)]
pub struct DeepLining {
    /// Render index of every pass vertex.
    render: Vec<u32>,
    /// Whether each pass vertex is free lining (else an obstacle).
    free: Vec<bool>,
    mesh: ContactMesh,
    /// Rest positions, interleaved (cm).
    rest: Vec<f64>,
    dhat: f64,
}

impl DeepLining {
    /// The pass for `model` beside the solver's contact surface `solver`: the free vertices
    /// are the mouth lining it leaves out.
    pub fn new(model: &FaceModel, solver: &FaceContact) -> Result<Self, ContactError> {
        let render = &model.render;
        let mut in_solver = vec![false; render.rest.len()];
        for &r in solver.render_vertices() {
            in_solver[r as usize] = true;
        }
        let region: Vec<Option<Region>> = render
            .rig_vertices
            .iter()
            .map(|&v| Region::of_vertex(v as usize))
            .collect();
        let free_render =
            |i: u32| region[i as usize] == Some(Region::MouthSocket) && !in_solver[i as usize];
        let taken = |i: u32| {
            matches!(
                region[i as usize],
                Some(
                    Region::MouthSocket
                        | Region::UpperTeeth
                        | Region::LowerTeeth
                        | Region::FaceSkin
                )
            )
        };
        // The lining's and teeth's triangles (the lining's reach the lip-line skin).
        let triangles: Vec<[u32; 3]> = render
            .triangles
            .iter()
            .filter(|t| {
                t.iter().all(|&v| taken(v))
                    && t.iter()
                        .any(|&v| region[v as usize] != Some(Region::FaceSkin))
            })
            .copied()
            .collect();
        let (faces, vertices) = compact_in_index_order(&triangles, render.rest.len());
        let free: Vec<bool> = vertices.iter().map(|&v| free_render(v)).collect();
        let group: Vec<u16> = free
            .iter()
            .map(|&f| if f { FREE } else { OBSTACLE })
            .collect();
        let rest: Vec<f64> = vertices
            .iter()
            .flat_map(|&v| {
                let p = render.rest[v as usize];
                [p.x, p.y, p.z]
            })
            .collect();
        let can_touch = [vec![true, true], vec![true, false]];
        let mesh = with_rest_close_pairs(
            ContactMesh::with_groups(&rest, faces, group, &can_touch)?,
            &rest,
            model.d_hat,
            ATTACHED_AT_REST,
        )?;
        Ok(Self {
            render: vertices,
            free,
            mesh,
            rest,
            dhat: model.d_hat,
        })
    }

    /// `candidates` without the pairs attached at rest (activation 0: the rig lays them on
    /// each other, and neither the barrier nor CCD takes them).
    fn unattached(&self, mut candidates: Candidates) -> Candidates {
        let mesh = &self.mesh;
        candidates
            .point_triangle
            .retain(|c| mesh.point_triangle_activation(c.vertex, c.face) != Some(0.0));
        candidates
            .edge_edge
            .retain(|c| mesh.edge_edge_activation(c.edge_a, c.edge_b) != Some(0.0));
        candidates
    }

    /// Moves the free lining of `posed` (every render vertex, where the bindings put it) to
    /// where it crosses neither the teeth, the rest of the lining nor itself (module doc).
    /// It starts from `memory` (or from rest) and leaves its result there; on an error
    /// `posed` is unchanged and the next frame starts from rest.
    ///
    /// [`Self::apply`] is the same with the error in the stats.
    pub fn resolve(
        &self,
        posed: &mut [Point3<f64>],
        memory: &mut LiningMemory,
    ) -> Result<DeepLiningStats, DeepLiningError> {
        let start = memory.x.take();
        let mut x = match start {
            Some(x) if x.len() == self.rest.len() => x,
            _ => self.rest.clone(),
        };
        let (stats, kappa) = self.minimize(posed, &mut x, memory.kappa.take())?;
        memory.x = Some(x);
        memory.kappa = Some(kappa);
        Ok(stats)
    }

    /// [`Self::resolve`], a failure reported in the stats (`error`, not converged) with
    /// `posed` left where the bindings put it.
    pub fn apply(&self, posed: &mut [Point3<f64>], memory: &mut LiningMemory) -> DeepLiningStats {
        self.resolve(posed, memory)
            .unwrap_or_else(|e| DeepLiningStats {
                error: Some(e.to_string()),
                ..DeepLiningStats::default()
            })
    }

    /// [`Self::resolve`] from the crossing-free configuration `x` (the pass's vertices,
    /// interleaved), which it leaves at the result, and the barrier stiffness `kappa` (its
    /// start when `None`), which it returns where it ended.
    fn minimize(
        &self,
        posed: &mut [Point3<f64>],
        x: &mut [f64],
        kappa: Option<f64>,
    ) -> Result<(DeepLiningStats, f64), DeepLiningError> {
        let start = Instant::now();
        let expected = posed.len();
        if let Some(&v) = self.render.iter().find(|&&v| v as usize >= expected) {
            return Err(DeepLiningError::Positions {
                count: expected,
                expected: v as usize + 1,
            });
        }
        let target: Vec<f64> = self
            .render
            .iter()
            .flat_map(|&v| {
                let p = posed[v as usize];
                [p.x, p.y, p.z]
            })
            .collect();
        let mut stats = DeepLiningStats::default();
        let mut descent = Descent::new(self.dhat, kappa);
        stats.converged =
            self.descend(x, &target, false, MAX_ITERATIONS, &mut descent, &mut stats)?;
        if self.put_obstacles_back(x, &target, &mut descent, &mut stats)? {
            stats.converged =
                self.descend(x, &target, true, MAX_ITERATIONS, &mut descent, &mut stats)?;
        }
        stats.active_pairs = Collisions::build(&self.mesh, x, self.dhat)?.len();
        for (i, &v) in self.render.iter().enumerate() {
            if self.free[i] {
                let p = Point3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
                stats.largest_push = stats.largest_push.max((p - posed[v as usize]).norm());
                posed[v as usize] = p;
            }
        }
        stats.ms = start.elapsed().as_secs_f64() * 1e3;
        Ok((stats, descent.kappa))
    }

    /// Moves the obstacles of `x` exactly onto `target`, certified collision-free: each round
    /// moves them as far toward it as CCD allows, then lets the free lining make way (a few
    /// Newton steps with the obstacles pinned), until the whole remaining move is clear; a
    /// round whose step is no longer than the last one's ends it with an error. Whether it
    /// took more than one round (the free lining then needs to settle). The stiff spring
    /// leaves the obstacles within `F/w` of `target`, but a free vertex the barrier holds
    /// closer than that to one (a lining pressed between teeth and lip) would be crossed by a
    /// single move.
    fn put_obstacles_back(
        &self,
        x: &mut [f64],
        target: &[f64],
        descent: &mut Descent,
        stats: &mut DeepLiningStats,
    ) -> Result<bool, DeepLiningError> {
        let ccd = CcdOptions::default();
        let mut step = 0.0;
        for round in 0..PUT_BACK_ROUNDS {
            let last = step;
            let back: Vec<f64> = (0..x.len())
                .map(|j| {
                    if self.free[j / 3] {
                        0.0
                    } else {
                        target[j] - x[j]
                    }
                })
                .collect();
            let candidates = self.unattached(Candidates::build_swept(&self.mesh, x, &back, 0.0)?);
            step = collision_free_step_over(&self.mesh, &candidates, x, &back, &ccd)?.step;
            if step >= 1.0 {
                for (x, b) in x.iter_mut().zip(&back) {
                    *x += b;
                }
                return Ok(round > 0);
            }
            if step <= last {
                // The lining made no more room than last round: it is caught between the
                // obstacles (or an obstacle and its own binding), and no round will.
                break;
            }
            for (x, b) in x.iter_mut().zip(&back) {
                *x += step * b;
            }
            self.descend(x, target, true, MAKE_WAY_ITERATIONS, descent, stats)?;
        }
        Err(DeepLiningError::ObstaclesBlocked { step })
    }

    /// Projected Newton on the pass's energy from the crossing-free `x` (module doc), every
    /// step cut by CCD; with `pinned` the obstacles stay where they are. Whether it reached
    /// [`STEP_TOLERANCE`].
    fn descend(
        &self,
        x: &mut [f64],
        target: &[f64],
        pinned: bool,
        max_iterations: usize,
        descent: &mut Descent,
        stats: &mut DeepLiningStats,
    ) -> Result<bool, DeepLiningError> {
        let n = self.render.len();
        let weight: Vec<f64> = self
            .free
            .iter()
            .map(|&f| if f { 1.0 } else { OBSTACLE_WEIGHT })
            .collect();
        let moving: Vec<bool> = self.free.iter().map(|&f| f || !pinned).collect();
        let spring = |x: &[f64]| -> f64 {
            (0..n)
                .filter(|&i| moving[i])
                .map(|i| {
                    let d2: f64 = (0..3)
                        .map(|k| (x[3 * i + k] - target[3 * i + k]).powi(2))
                        .sum();
                    0.5 * weight[i] * d2
                })
                .sum()
        };
        let mut collisions = Collisions::build(&self.mesh, x, self.dhat)?;
        let mut min_d2 = collisions.min_distance_squared();
        let ccd = CcdOptions::default();
        for _ in 0..max_iterations {
            let barrier = BarrierPotential::new(self.dhat, descent.kappa)?;
            let mut gradient: Vec<f64> = (0..3 * n)
                .map(|j| weight[j / 3] * (x[j] - target[j]))
                .collect();
            barrier.add_gradient(&collisions, x, &mut gradient)?;
            let blocks = barrier.hessian(&collisions, x, Projection::ClampEigenvalues)?;
            let rhs: Vec<f64> = gradient.iter().map(|g| -g).collect();
            let direction = solve_spd(&weight, &moving, &blocks, &rhs);
            let longest = (0..n)
                .map(|i| {
                    (0..3)
                        .map(|k| direction[3 * i + k].powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .fold(0.0, f64::max);
            if longest <= STEP_TOLERANCE {
                return Ok(true);
            }
            let candidates = self.unattached(Candidates::build_swept(
                &self.mesh, x, &direction, self.dhat,
            )?);
            let mut alpha =
                collision_free_step_over(&self.mesh, &candidates, x, &direction, &ccd)?.step;
            if alpha <= 0.0 {
                // A pair at round-off distance blocks every motion: stop where it is
                // (crossing-free, not at the minimum).
                return Ok(false);
            }
            let energy = spring(x) + barrier.value(&collisions, x)?;
            let mut trial = x.to_vec();
            loop {
                for j in 0..3 * n {
                    trial[j] = x[j] + alpha * direction[j];
                }
                // A trial may bring a pair to round-off distance (`Touching`): shorten it.
                if let Ok(c) =
                    Collisions::from_candidates(&self.mesh, &candidates, &trial, self.dhat)
                {
                    let e = spring(&trial) + barrier.value(&c, &trial)?;
                    if e <= energy || alpha < 1e-12 {
                        collisions = c;
                        break;
                    }
                }
                alpha *= 0.5;
            }
            // The swept candidates hold every pair within d̂ anywhere along the step, so
            // `collisions` (from them, at the accepted trial) is the whole active set there.
            x.copy_from_slice(&trial);
            let d2 = collisions.min_distance_squared();
            if d2 < (TIGHT * self.dhat).powi(2) && d2 < min_d2 {
                descent.kappa = (2.0 * descent.kappa).min(descent.kappa_max);
            }
            min_d2 = d2;
            stats.iterations += 1;
        }
        Ok(false)
    }
}

/// The barrier's stiffness as the pass goes (it only grows, [`TIGHT`]).
struct Descent {
    kappa: f64,
    kappa_max: f64,
}

impl Descent {
    /// From `kappa` (where the last frame's pass left it), or from [`stiffness`]'s start.
    fn new(dhat: f64, kappa: Option<f64>) -> Self {
        let (start, kappa_max) = stiffness(dhat);
        Self {
            kappa: kappa.unwrap_or(start).clamp(start, kappa_max),
            kappa_max,
        }
    }
}

/// `(diag(w)⊗I₃ + Σ blocks)·d = rhs` (the blocks PSD, the weights positive) over the vertices
/// that are `moving`, `d = 0` on the others (the system restricted to the moving ones). A
/// vertex that no block touches is uncoupled, `d = rhs/w`; the few the active pairs couple
/// are solved by conjugate gradients with the diagonal as preconditioner, to a relative
/// residual of [`CG_TOLERANCE`] (a Newton direction needs no more).
fn solve_spd(weight: &[f64], moving: &[bool], blocks: &[HessianBlock], rhs: &[f64]) -> Vec<f64> {
    let mut d: Vec<f64> = (0..rhs.len())
        .map(|j| {
            if moving[j / 3] {
                rhs[j] / weight[j / 3]
            } else {
                0.0
            }
        })
        .collect();
    let mut local = vec![u32::MAX; weight.len()];
    let mut coupled: Vec<u32> = Vec::new();
    for &v in blocks.iter().flat_map(|b| &b.vertices) {
        if local[v as usize] == u32::MAX {
            local[v as usize] = coupled.len() as u32;
            coupled.push(v);
        }
    }
    if coupled.is_empty() {
        return d;
    }
    let blocks: Vec<HessianBlock> = blocks
        .iter()
        .map(|b| HessianBlock {
            vertices: b.vertices.map(|v| local[v as usize]),
            matrix: b.matrix,
        })
        .collect();
    let m = 3 * coupled.len();
    let w = |j: usize| weight[coupled[j / 3] as usize];
    let mut diagonal: Vec<f64> = (0..m).map(w).collect();
    for b in &blocks {
        for (a, &v) in b.vertices.iter().enumerate() {
            for k in 0..3 {
                diagonal[3 * v as usize + k] += b.matrix[(3 * a + k, 3 * a + k)];
            }
        }
    }
    let moves = |j: usize| moving[coupled[j / 3] as usize];
    // The restricted operator: pinned entries of `v` are 0 and those of `out` are zeroed.
    let apply = |v: &[f64], out: &mut [f64]| {
        for j in 0..m {
            out[j] = w(j) * v[j];
        }
        crate::contact::add_hessian_product(&blocks, v, out);
        for (j, o) in out.iter_mut().enumerate() {
            if !moves(j) {
                *o = 0.0;
            }
        }
    };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let b: Vec<f64> = (0..m)
        .map(|j| {
            if moves(j) {
                rhs[3 * coupled[j / 3] as usize + j % 3]
            } else {
                0.0
            }
        })
        .collect();
    let mut x = vec![0.0; m];
    let mut r = b.clone();
    let mut z: Vec<f64> = r.iter().zip(&diagonal).map(|(r, g)| r / g).collect();
    let mut p = z.clone();
    let mut rz = dot(&r, &z);
    let tolerance = CG_TOLERANCE * CG_TOLERANCE * rz;
    let mut ap = vec![0.0; m];
    for _ in 0..m {
        if rz <= tolerance {
            break;
        }
        apply(&p, &mut ap);
        let alpha = rz / dot(&p, &ap);
        for j in 0..m {
            x[j] += alpha * p[j];
            r[j] -= alpha * ap[j];
            z[j] = r[j] / diagonal[j];
        }
        let rz_next = dot(&r, &z);
        let beta = rz_next / rz;
        rz = rz_next;
        for j in 0..m {
            p[j] = z[j] + beta * p[j];
        }
    }
    for (i, &v) in coupled.iter().enumerate() {
        d[3 * v as usize..3 * v as usize + 3].copy_from_slice(&x[3 * i..3 * i + 3]);
    }
    d
}

/// The conjugate gradients' relative residual (preconditioned norm) for a Newton direction.
const CG_TOLERANCE: f64 = 1e-8;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::Codes;
    use crate::model::audit::CrossingAudit;
    use crate::model::contact_region::FaceContactSettings;
    use crate::rig::ExpressionCode;
    use crate::sample::{SAMPLE_DIR, Sample};

    /// Sample face `face` with `shape` at full weight, solved from rest at the final preset
    /// with contact, and its render surface where the bindings put it.
    fn posed(face: usize, shape: &str) -> (Sample, Vec<Point3<f64>>) {
        let sample =
            Sample::load(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(SAMPLE_DIR))
                .unwrap();
        let face = &sample.faces[face];
        let mut sim = face.model.simulator().unwrap();
        sim.set_contact(FaceContact::new(&face.model, &FaceContactSettings::default()).unwrap())
            .unwrap();
        let codes = Codes {
            expression: ExpressionCode::single(shape, 1.0).unwrap(),
            style: face.style,
        };
        let actuation = face.actuation.actuate(&codes).unwrap();
        let bones = actuation.bones();
        let mut state = sim.rest_state();
        let settings = crate::sim::SolveSettings {
            contact: true,
            ..Quality::Final.settings()
        };
        let stats = sim
            .solve(&actuation.tensors, &bones, &mut state, &settings)
            .unwrap();
        assert!(stats.converged(), "{stats:?}");
        let posed = face.model.render_positions(state.flat_positions(), &bones);
        (sample, posed)
    }

    /// The template smiling: the lips are kept apart by the solve, the cheeks' inside (deep
    /// lining) is carried through the lower teeth.
    fn smile() -> (Sample, Vec<Point3<f64>>) {
        posed(0, "mouthSmile_L")
    }

    /// The lower lip rolled in on two identities presses the deep lining hardest; the pass
    /// leaves both crossing-free. On the first the obstacles end 10 µm off where the solve
    /// put them, closer than the lining they press, and a single certified move back was
    /// refused (the pass failed, 31 pairs crossing). On the second the pass moved a
    /// gum-bound lining edge that lies 17 µm from a tooth's edge at rest through the tooth
    /// (4 pairs), while such pairs were attached.
    #[test]
    fn pressed_lining_is_resolved_and_left_crossing_free() {
        for face in [1, 2] {
            let shape = "mouthRollLower";
            let (sample, bound) = posed(face, shape);
            let model = &sample.faces[face].model;
            let solver = FaceContact::new(model, &FaceContactSettings::default()).unwrap();
            let pass = DeepLining::new(model, &solver).unwrap();
            let mut posed = bound.clone();
            let stats = pass
                .resolve(&mut posed, &mut LiningMemory::default())
                .unwrap();
            assert!(stats.converged, "{} {shape}: {stats:?}", model.name);
            let crossings = CrossingAudit::new(model).audit(model, &posed);
            assert_eq!(crossings.pairs, 0, "{} {shape}: {crossings:?}", model.name);
        }
    }

    /// The pass takes the deep lining off the teeth (the independent audit finds no crossing
    /// left), moves nothing but the deep lining, and moves most of it not at all; it is
    /// deterministic, and warm-started from its own result (and stiffness) it stays there.
    #[test]
    fn the_deep_lining_is_kept_off_the_teeth_and_nothing_else_moves() {
        let (sample, bound) = smile();
        let model = &sample.faces[0].model;
        let audit = CrossingAudit::new(model);
        let before = audit.audit(model, &bound);
        assert!(
            before
                .by_pieces
                .iter()
                .any(|(k, _)| k.contains("teeth / mouth socket")),
            "{before:?}"
        );
        let solver = FaceContact::new(model, &FaceContactSettings::default()).unwrap();
        let pass = DeepLining::new(model, &solver).unwrap();
        let mut memory = LiningMemory::default();
        let mut posed = bound.clone();
        let stats = pass.resolve(&mut posed, &mut memory).unwrap();
        assert!(stats.converged && stats.largest_push > 0.05, "{stats:?}");
        assert_eq!(audit.audit(model, &posed).pairs, 0);

        let mut moved = Vec::new();
        for (i, (p, b)) in posed.iter().zip(&bound).enumerate() {
            let free = pass
                .render
                .iter()
                .position(|&v| v as usize == i)
                .is_some_and(|k| pass.free[k]);
            if free {
                moved.push((p - b).norm());
            } else {
                assert_eq!(p, b, "render vertex {i} is no free lining and moved");
            }
        }
        moved.sort_by(f64::total_cmp);
        assert!(
            moved[moved.len() / 2] < 1e-4,
            "median push {}",
            moved[moved.len() / 2]
        );

        let mut again = bound.clone();
        pass.resolve(&mut again, &mut LiningMemory::default())
            .unwrap();
        assert_eq!(again, posed, "same input, same output");

        let mut warm = bound.clone();
        let stats = pass.resolve(&mut warm, &mut memory).unwrap();
        assert!(stats.converged && stats.iterations <= 2, "{stats:?}");
        let drift = warm
            .iter()
            .zip(&posed)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(drift < 1e-3, "warm start drifted {drift} cm");
    }
}
