//! The quasistatic face simulator: a tetrahedral mesh with shape-targeting elements and bone
//! attachments, its prefactored global matrix, and the per-iteration kernels (local sweep,
//! gradient, Hessian products) that the solver and the adjoint build on.
//!
//! Total energy `E(x) = Σₑ (w·Vₑ/2)·‖Fₑ − R*ₑ·Aₑ‖² + Σₐ (kₐ/2)·‖xₐ − T(pₐ)‖²`.

use nalgebra::{Matrix3, Point3, UnitQuaternion, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::attachment::{Attachments, Bone, BonePose};
use super::deformation::ElementOperator;
use super::global_matrix::{FactorError, GlobalMatrix, SolveScratch};
use super::low_rank::{Curvature, InverseColumns};
use super::shape_targeting::{
    BARRIER_VOLUME, Linearized, LocalStep, STEP_VOLUME_KEPT, barrier_curvature, local_step,
    volume_step_limit,
};
use super::tensor::{SymTensor, TensorError};
use crate::geometry::TetMesh;

/// Elements per parallel task: large enough to amortize scheduling, small enough to balance.
const CHUNK: usize = 512;

#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("invalid simulator setup: {0}")]
    Setup(String),
    #[error(transparent)]
    Factor(#[from] FactorError),
    #[error("got {got} actuation tensors for a mesh of {expected} elements")]
    ActuationCount { expected: usize, got: usize },
    #[error("actuation of element {element} {reason}")]
    InvalidActuation { element: usize, reason: TensorError },
    #[error("bone pose has a non-finite value: {0:?}")]
    NonFiniteBones(BonePose),
    #[error("state does not belong to this mesh ({got} positions for {expected} vertices)")]
    StateMismatch { expected: usize, got: usize },
    #[error(
        "the starting state has {0} folded element(s); start from the rest state or a frame \
         that solved"
    )]
    FoldedStart(usize),
    #[error("state has a non-finite position at vertex {0}")]
    NonFiniteState(usize),
    #[error(
        "solve ended with {count} inverted element(s) (first: {first}) after {} iterations; \
         the inputs ask for more deformation than the tissue can take without folding",
        stats.iterations
    )]
    Inverted {
        count: usize,
        first: usize,
        stats: Box<super::solver::SolveStats>,
    },
    #[error(
        "the Hessian is not positive definite at this state (curvature {0:e}); sensitivities need a converged minimum"
    )]
    IndefiniteHessian(f64),
    #[error("loss gradient has {got} entries, expected {expected} (3 per vertex)")]
    LossGradientSize { expected: usize, got: usize },
    #[error("contact: {0}")]
    Contact(#[from] crate::contact::ContactError),
    /// The bone pose could not be reached from the starting state in collision-free stages
    /// (a solve from a frame other than rest then tries again from rest: see
    /// [`Simulator::solve`]).
    #[error("the bone pose could not be reached without crossing: {0}")]
    PoseUnreachable(String),
    /// The solve ran out of iterations far from any equilibrium, also from rest (see
    /// [`super::solver::FAILED_FACTOR`]).
    #[error(
        "no equilibrium found: the solve stopped at its iteration cap with residual {residual:.3e}, \
         orders of magnitude above its tolerance, also when started from rest; the inputs ask \
         for a shape the tissue cannot take"
    )]
    NoEquilibrium {
        residual: f64,
        stats: Box<super::solver::SolveStats>,
    },
    #[error(
        "the contact surfaces intersect after the solve ({count} edge–triangle crossings): \
         a bug, since every step is collision-checked"
    )]
    Intersecting {
        count: usize,
        stats: Box<super::solver::SolveStats>,
    },
}

/// Material and attachment settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimConfig {
    /// Shape-targeting stiffness `w`, the same for every element.
    pub stiffness: f64,
    /// Attachment stiffness relative to a vertex's elastic stiffness: `kₐ = ratio·L_aa`. Large
    /// values pin harder; the factored matrix absorbs them, so convergence does not suffer.
    pub attachment_ratio: f64,
    /// The point the jaw rotates about.
    pub jaw_pivot: Point3<f64>,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            stiffness: 1.0,
            attachment_ratio: 100.0,
            jaw_pivot: Point3::origin(),
        }
    }
}

/// A mesh ready to simulate: element operators, attachments and the factored global matrix.
pub struct Simulator {
    pub(crate) mesh: TetMesh,
    pub(crate) ops: Vec<ElementOperator>,
    /// `w·V` per element.
    pub(crate) element_weights: Vec<f64>,
    pub(crate) attachments: Attachments,
    /// `kₐ` per vertex (zero where free).
    pub(crate) stiffness: Vec<f64>,
    pub(crate) global: GlobalMatrix,
    /// For each vertex, the (element, corner) pairs that touch it, CSR-style.
    incidence_offsets: Vec<u32>,
    incidence: Vec<(u32, u8)>,
    pub(crate) config: SimConfig,
    /// Contact surfaces and their precomputed data, if set up.
    pub(crate) contact: Option<super::contact::ContactModel>,
    /// Columns of `L⁻¹` for the vertices that stiff terms (contact, the volume barrier) have
    /// touched: the low-rank step updates read them ([`super::low_rank`]).
    pub(crate) inverse_columns: InverseColumns,
}

/// The simulated configuration, reused as the warm start of the next solve.
#[derive(Clone, Debug)]
pub struct SimState {
    /// Interleaved positions `[x0, y0, z0, x1, …]`.
    pub(crate) x: Vec<f64>,
    /// Per-element local-step results at `x` (rotations warm-start the next local step).
    pub(crate) steps: Vec<LocalStep>,
    /// The solver's curvature memory from the last solve (L-BFGS pairs), reused as a warm start.
    pub(crate) history: Option<super::solver::History>,
    /// Trial buffer for the line search, kept so solves do not reallocate it.
    pub(crate) spare: Vec<LocalStep>,
    /// The bone pose `x` was solved under (the rest pose for a fresh state): contact moves
    /// the teeth from here to the next pose without crossing the lips.
    pub(crate) bones: BonePose,
    /// The barrier stiffness κ the last contact solve ended with (`None`: solved without
    /// contact); part of the energy that sensitivities differentiate.
    pub(crate) contact_stiffness: Option<f64>,
    /// When the contact gate tries contact-free again after refusals
    /// ([`super::contact_gate::Backoff`]).
    pub(crate) gate_backoff: super::contact_gate::Backoff,
    /// The broad phase the last contact solve ended with, the next one's start
    /// ([`super::contact::ContactCache`]).
    pub(crate) contact_cache: Option<super::contact::ContactCache>,
}

impl SimState {
    pub fn position(&self, vertex: usize) -> Point3<f64> {
        Point3::new(
            self.x[3 * vertex],
            self.x[3 * vertex + 1],
            self.x[3 * vertex + 2],
        )
    }

    pub fn positions(&self) -> Vec<Point3<f64>> {
        self.x
            .chunks_exact(3)
            .map(|p| Point3::new(p[0], p[1], p[2]))
            .collect()
    }

    pub fn flat_positions(&self) -> &[f64] {
        &self.x
    }

    pub fn vertex_count(&self) -> usize {
        self.x.len() / 3
    }
}

/// Per-solve data derived from the inputs.
pub(crate) struct Frame {
    pub actuations: Vec<Matrix3<f64>>,
    /// Interleaved attachment targets (zero where free).
    pub targets: Vec<f64>,
}

impl Simulator {
    pub fn new(
        mesh: TetMesh,
        attachments: Attachments,
        config: SimConfig,
    ) -> Result<Self, SimError> {
        let n = mesh.vertex_count();
        if attachments.vertices.len() != attachments.bones.len() {
            return Err(SimError::Setup(
                "attachments need one bone per vertex".into(),
            ));
        }
        if !(config.stiffness > 0.0 && config.stiffness.is_finite()) {
            return Err(SimError::Setup(format!(
                "stiffness must be positive and finite, got {}",
                config.stiffness
            )));
        }
        if !(config.attachment_ratio > 0.0 && config.attachment_ratio.is_finite()) {
            return Err(SimError::Setup(format!(
                "attachment ratio must be positive, got {}",
                config.attachment_ratio
            )));
        }
        let mut attached = vec![false; n];
        for &v in &attachments.vertices {
            let slot = attached.get_mut(v as usize).ok_or_else(|| {
                SimError::Setup(format!(
                    "attached vertex {v} is not in the mesh ({n} vertices)"
                ))
            })?;
            if *slot {
                return Err(SimError::Setup(format!("vertex {v} is attached twice")));
            }
            *slot = true;
        }
        if let Some(vertex) = unattached_component(&mesh, &attached) {
            return Err(SimError::Setup(format!(
                "the part of the mesh containing vertex {vertex} is attached to no bone, so its position is undetermined"
            )));
        }

        let ops = ElementOperator::for_mesh(&mesh);
        let element_weights: Vec<f64> = ops
            .iter()
            .map(|o| config.stiffness * o.rest_volume)
            .collect();
        let mut elastic_diagonal = vec![0.0; n];
        for ((tet, op), wv) in mesh.tets.iter().zip(&ops).zip(&element_weights) {
            for i in 0..4 {
                elastic_diagonal[tet[i] as usize] += wv * op.grads[i].norm_squared();
            }
        }
        let mut stiffness = vec![0.0; n];
        for &v in &attachments.vertices {
            stiffness[v as usize] = config.attachment_ratio * elastic_diagonal[v as usize];
        }
        let global = GlobalMatrix::factor(&mesh.tets, &ops, &element_weights, &stiffness)?;

        let mut counts = vec![0u32; n + 1];
        for tet in &mesh.tets {
            for &v in tet {
                counts[v as usize + 1] += 1;
            }
        }
        for v in 0..n {
            counts[v + 1] += counts[v];
        }
        let mut fill = counts.clone();
        let mut incidence = vec![(0u32, 0u8); 4 * mesh.element_count()];
        for (e, tet) in mesh.tets.iter().enumerate() {
            for (corner, &v) in tet.iter().enumerate() {
                incidence[fill[v as usize] as usize] = (e as u32, corner as u8);
                fill[v as usize] += 1;
            }
        }
        Ok(Self {
            mesh,
            ops,
            element_weights,
            attachments,
            stiffness,
            global,
            incidence_offsets: counts,
            incidence,
            config,
            contact: None,
            inverse_columns: InverseColumns::default(),
        })
    }

    /// Sets up contact on `face`'s surfaces (precomputes the block of `L⁻¹` over the
    /// simulation vertices they touch). Solves use it while [`SolveSettings::contact`] is on.
    ///
    /// [`SolveSettings::contact`]: super::SolveSettings::contact
    pub fn set_contact(
        &mut self,
        face: crate::contact::surface::FaceContact,
    ) -> Result<(), SimError> {
        if face.sim_vertex_count() != self.vertex_count() {
            return Err(SimError::Setup(format!(
                "contact surfaces built for {} simulation vertices, the mesh has {}",
                face.sim_vertex_count(),
                self.vertex_count()
            )));
        }
        self.contact = Some(super::contact::ContactModel::new(face, &self.global));
        // The contact region's columns of L⁻¹, once, before the first solve needs them.
        if let Some(c) = &self.contact {
            self.inverse_columns
                .get(&self.global, c.face.region_sim_vertices());
        }
        Ok(())
    }

    /// Chooses how contact-aware steps bring in the barrier's curvature (the default is the
    /// faster low-rank update; `facesim bench contact` compares).
    pub fn set_contact_step(&mut self, step: super::contact::ContactStep) {
        if let Some(c) = self.contact.as_mut() {
            c.step = step;
        }
    }

    /// The contact surfaces, if set up.
    pub fn contact(&self) -> Option<&crate::contact::surface::FaceContact> {
        self.contact.as_ref().map(|c| &c.face)
    }

    pub fn mesh(&self) -> &TetMesh {
        &self.mesh
    }

    pub fn attachments(&self) -> &Attachments {
        &self.attachments
    }

    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    pub fn global_matrix(&self) -> &GlobalMatrix {
        &self.global
    }

    pub fn element_count(&self) -> usize {
        self.mesh.element_count()
    }

    pub fn vertex_count(&self) -> usize {
        self.mesh.vertex_count()
    }

    /// Whether `state` is the rest state's configuration (rest positions, rest bone pose).
    pub(crate) fn at_rest(&self, state: &SimState) -> bool {
        state.bones == BonePose::default()
            && self
                .mesh
                .vertices
                .iter()
                .zip(state.x.chunks_exact(3))
                .all(|(p, x)| x == [p.x, p.y, p.z])
    }

    /// The rest configuration with identity rotations: the cold start.
    pub fn rest_state(&self) -> SimState {
        let x = self
            .mesh
            .vertices
            .iter()
            .flat_map(|p| [p.x, p.y, p.z])
            .collect();
        let step = LocalStep {
            rotation: UnitQuaternion::identity(),
            stress: Matrix3::zeros(),
            energy: 0.0,
            volume_ratio: 1.0,
            deformation: Matrix3::identity(),
        };
        SimState {
            x,
            steps: vec![step; self.element_count()],
            history: None,
            spare: Vec::new(),
            bones: BonePose::default(),
            contact_stiffness: None,
            gate_backoff: Default::default(),
            contact_cache: None,
        }
    }

    /// A state at the given positions (for warm starts from elsewhere, and for tests), taken
    /// to be solved under the rest bone pose.
    pub fn state_at(&self, positions: &[Point3<f64>]) -> Result<SimState, SimError> {
        if positions.len() != self.vertex_count() {
            return Err(SimError::StateMismatch {
                expected: self.vertex_count(),
                got: positions.len(),
            });
        }
        let mut state = self.rest_state();
        state.x = positions.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
        Ok(state)
    }

    pub(crate) fn check_state(&self, state: &SimState) -> Result<(), SimError> {
        let expected = self.vertex_count();
        if state.x.len() != 3 * expected || state.steps.len() != self.element_count() {
            return Err(SimError::StateMismatch {
                expected,
                got: state.x.len() / 3,
            });
        }
        if let Some(i) = state.x.iter().position(|v| !v.is_finite()) {
            return Err(SimError::NonFiniteState(i / 3));
        }
        Ok(())
    }

    /// Validates the inputs of one frame and derives what the kernels need.
    pub(crate) fn frame(
        &self,
        actuations: &[SymTensor],
        bones: &BonePose,
    ) -> Result<Frame, SimError> {
        if actuations.len() != self.element_count() {
            return Err(SimError::ActuationCount {
                expected: self.element_count(),
                got: actuations.len(),
            });
        }
        for (element, a) in actuations.iter().enumerate() {
            a.validate()
                .map_err(|reason| SimError::InvalidActuation { element, reason })?;
        }
        if !bones.skull.is_finite() || !bones.jaw.is_finite() {
            return Err(SimError::NonFiniteBones(*bones));
        }
        Ok(Frame {
            actuations: actuations.iter().map(SymTensor::to_matrix).collect(),
            targets: self.attachment_targets(bones),
        })
    }

    /// Interleaved attachment targets under `bones` (zero where a vertex is free).
    pub(crate) fn attachment_targets(&self, bones: &BonePose) -> Vec<f64> {
        let mut targets = vec![0.0; 3 * self.vertex_count()];
        for (&v, &bone) in self
            .attachments
            .vertices
            .iter()
            .zip(&self.attachments.bones)
        {
            let t = bones.target(
                bone,
                &self.config.jaw_pivot,
                &self.mesh.vertices[v as usize],
            );
            targets[3 * v as usize..3 * v as usize + 3].copy_from_slice(t.coords.as_slice());
        }
        targets
    }

    #[inline]
    fn corners(&self, x: &[f64], element: usize) -> [Vector3<f64>; 4] {
        self.mesh.tets[element].map(|v| {
            let i = 3 * v as usize;
            Vector3::new(x[i], x[i + 1], x[i + 2])
        })
    }

    pub(crate) fn deformation_gradient(&self, x: &[f64], element: usize) -> Matrix3<f64> {
        self.ops[element].deformation_gradient(&self.corners(x, element))
    }

    /// The longest fraction of the step `x → x + d` that leaves every element at least
    /// [`STEP_VOLUME_KEPT`] of its volume (1 if the whole step does); `steps` are the local
    /// steps at `x` (their `F`).
    pub(crate) fn volume_step_limit(&self, steps: &[LocalStep], d: &[f64]) -> f64 {
        (0..self.element_count())
            .into_par_iter()
            .with_min_len(CHUNK)
            .map(|e| {
                let df = self.deformation_gradient(d, e);
                volume_step_limit(&steps[e].deformation, &df, STEP_VOLUME_KEPT)
            })
            .reduce(|| 1.0, f64::min)
    }

    /// The volume barrier's curvature at the state of `steps` for the step solver: one
    /// rank-one term per element near folding (`J < Ĵ`, see [`barrier_curvature`]), on its
    /// four corners.
    pub(crate) fn volume_barrier_curvature(&self, steps: &[LocalStep]) -> Curvature {
        let terms = steps
            .iter()
            .enumerate()
            .filter(|(_, s)| s.volume_ratio < BARRIER_VOLUME)
            .filter_map(|(e, s)| {
                let (c, cof) = barrier_curvature(&s.deformation, self.element_weights[e])?;
                let tet = self.mesh.tets[e];
                let column = (0..4)
                    .map(|k| (tet[k], cof * self.ops[e].grads[k]))
                    .collect();
                Some((c, column))
            })
            .collect();
        Curvature::from_rank_one(terms)
    }

    /// The local step for every element at `x` (parallel), warm-started from the rotations
    /// in `warm`, or from those already in `out` (an in-place update).
    /// Returns the total energy, attachments included.
    pub(crate) fn local_sweep(
        &self,
        frame: &Frame,
        x: &[f64],
        warm: Option<&[LocalStep]>,
        out: &mut [LocalStep],
    ) -> f64 {
        out.par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(chunk, steps)| {
                for (j, step) in steps.iter_mut().enumerate() {
                    let e = chunk * CHUNK + j;
                    let f = self.deformation_gradient(x, e);
                    let guess = warm.map_or(step.rotation, |w| w[e].rotation);
                    *step = local_step(&f, &frame.actuations[e], self.element_weights[e], &guess);
                }
            });
        // Summed in a fixed order so results do not depend on thread scheduling.
        out.iter().map(|s| s.energy).sum::<f64>() + self.attachment_energy(frame, x)
    }

    fn attachment_energy(&self, frame: &Frame, x: &[f64]) -> f64 {
        self.attachments
            .vertices
            .iter()
            .map(|&v| {
                let i = 3 * v as usize;
                let d = Vector3::new(
                    x[i] - frame.targets[i],
                    x[i + 1] - frame.targets[i + 1],
                    x[i + 2] - frame.targets[i + 2],
                );
                0.5 * self.stiffness[v as usize] * d.norm_squared()
            })
            .sum()
    }

    /// `∇E(x) = Σₑ stressₑ·gᵢ + k·(x − target)`, gathered per vertex (parallel, deterministic).
    pub(crate) fn gradient(&self, frame: &Frame, x: &[f64], steps: &[LocalStep], g: &mut [f64]) {
        self.gather(
            g,
            |e, corner| steps[e].stress * self.ops[e].grads[corner],
            |v| {
                let i = 3 * v;
                let k = self.stiffness[v];
                Vector3::new(
                    k * (x[i] - frame.targets[i]),
                    k * (x[i + 1] - frame.targets[i + 1]),
                    k * (x[i + 2] - frame.targets[i + 2]),
                )
            },
        );
    }

    /// Sums per-vertex contributions of every incident element corner plus a per-vertex term.
    fn gather(
        &self,
        out: &mut [f64],
        corner: impl Fn(usize, usize) -> Vector3<f64> + Sync,
        vertex: impl Fn(usize) -> Vector3<f64> + Sync,
    ) {
        out.par_chunks_mut(3 * CHUNK)
            .enumerate()
            .for_each(|(chunk, values)| {
                for (j, value) in values.chunks_exact_mut(3).enumerate() {
                    let v = chunk * CHUNK + j;
                    let mut sum = vertex(v);
                    let range =
                        self.incidence_offsets[v] as usize..self.incidence_offsets[v + 1] as usize;
                    for &(e, c) in &self.incidence[range] {
                        sum += corner(e as usize, c as usize);
                    }
                    value.copy_from_slice(sum.as_slice());
                }
            });
    }

    /// Per-element linearizations at a state, for Hessian products. The rotations are
    /// re-derived for these actuations (warm-started from the state's), so a state solved
    /// under other inputs still gives the exact Hessian.
    pub(crate) fn linearize(&self, frame: &Frame, state: &SimState) -> Vec<Linearized> {
        (0..self.element_count())
            .into_par_iter()
            .with_min_len(CHUNK)
            .map(|e| {
                let f = self.deformation_gradient(&state.x, e);
                let (a, wv) = (&frame.actuations[e], self.element_weights[e]);
                let step = local_step(&f, a, wv, &state.steps[e].rotation);
                Linearized::new(&f, a, wv, &step.rotation)
            })
            .collect()
    }

    /// `H·v`, the exact Hessian of the total energy applied to an interleaved vector.
    pub(crate) fn hessian_product(&self, lin: &[Linearized], v: &[f64], out: &mut [f64]) {
        let stress: Vec<Matrix3<f64>> = (0..self.element_count())
            .into_par_iter()
            .with_min_len(CHUNK)
            .map(|e| lin[e].stress_differential(&self.deformation_gradient(v, e)))
            .collect();
        self.gather(
            out,
            |e, corner| stress[e] * self.ops[e].grads[corner],
            |i| Vector3::new(v[3 * i], v[3 * i + 1], v[3 * i + 2]) * self.stiffness[i],
        );
    }

    /// `sqrt(Σₑ Σᵢ ‖w·Vₑ·Aₑ·gᵢ‖²)`: the size of the element forces in play, against which
    /// the net force `‖∇E‖` is measured (the relative residual). It depends only on the mesh
    /// and the actuations, so it is the same from any start and under rigid motions.
    pub(crate) fn force_scale(&self, frame: &Frame) -> f64 {
        let sum: f64 = (0..self.element_count())
            .map(|e| {
                let a = &frame.actuations[e];
                self.ops[e]
                    .grads
                    .iter()
                    .map(|g| (a * g).norm_squared())
                    .sum::<f64>()
                    * self.element_weights[e].powi(2)
            })
            .sum();
        sum.sqrt()
    }

    pub(crate) fn solve_scratch(&self) -> SolveScratch {
        self.global.scratch()
    }

    /// Vertices attached to the given bone.
    pub fn attached_to(&self, bone: Bone) -> impl Iterator<Item = usize> + '_ {
        self.attachments
            .vertices
            .iter()
            .zip(&self.attachments.bones)
            .filter(move |(_, b)| **b == bone)
            .map(|(v, _)| *v as usize)
    }
}

/// A vertex of some connected part of the mesh that has no attached vertex, if any.
fn unattached_component(mesh: &TetMesh, attached: &[bool]) -> Option<usize> {
    let n = mesh.vertex_count();
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(parent: &mut [usize], mut v: usize) -> usize {
        while parent[v] != v {
            parent[v] = parent[parent[v]];
            v = parent[v];
        }
        v
    }
    for tet in &mesh.tets {
        for &w in &tet[1..] {
            let (a, b) = (
                find(&mut parent, tet[0] as usize),
                find(&mut parent, w as usize),
            );
            parent[a] = b;
        }
    }
    let mut root_attached = vec![false; n];
    for (v, _) in attached.iter().enumerate().filter(|(_, a)| **a) {
        let r = find(&mut parent, v);
        root_attached[r] = true;
    }
    // An unreferenced vertex is its own part: it needs an attachment too.
    (0..n).find(|&v| !root_attached[find(&mut parent, v)])
}
