//! Stage 2: fine-tune the expression/style networks through the simulator.
//!
//! Stage 1 fits N_A to per-element actuations that a passive fit of the rig's skin produced;
//! what matters is the skin the *simulation* of those actuations gives. Stage 2 closes that
//! gap with the paper's second stage: per training pose of the batch (the same seeded
//! [`batch_picks`] as stage 1, every element of the face),
//!
//! 1. `u = tanh z` from the encoders, N_A over every element (f64), `Ã = R_φᵀ exp(log A) R_φ`,
//!    the jaw from N_B;
//! 2. a quasistatic solve warm-started from the pose's cached fitted state (always that state,
//!    not the last stage-2 one: a run is then a function of the networks and the seed alone, so
//!    checkpoints stay small and a resumed run is bitwise the uninterrupted one; from rest
//!    where the fitted state has folded elements, which the solver refuses as a start);
//! 3. the surface loss `ℓ = mean over the embedded render vertices of ‖x_render − target‖²`
//!    (cm²; the skin and lips the tissue carries, the vertices [`super::eval`] measures), with
//!    `target` the rig's skin for the pose ([`crate::model::target`]);
//! 4. `dℓ/dÃ`, `dℓ/d[θ; t]` by [`crate::sim::Simulator::sensitivities`] (implicit
//!    differentiation at the equilibrium; plus the direct jaw term of skin blended onto the
//!    jaw), then `dℓ/d log A = R_φ·exp′(L̃)*[dℓ/dÃ]·R_φᵀ` ([`super::expm::exp_sym_adjoint`]);
//! 5. the stage-1 backward ([`super::loss::networks_loss`]) from those per-element and jaw
//!    gradients, with the stage-1 regularizers `λ_act·L_act` and `λ_lip·Π softplus(cᵢ)`.
//!
//! The batch loss is `L = (1/B') Σ ℓ_b + λ_act L_act + λ_lip Π softplus(cᵢ)` over the `B'`
//! poses whose solve converged and whose adjoint solve reached its tolerance; the others are
//! left out (the adjoint needs an equilibrium) and counted in [`LossParts::skipped`].
//! [`ModelTrainer`] (via [`TrainingData`] for [`Stage2Data`]) does the rest: Adam, schedule, checkpoints, resume.

use faer::{Mat, Par};
use nalgebra::{Matrix3, Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::GenerativeError;
use super::data::FacePoses;
use super::expm::{exp_sym, exp_sym_adjoint};
use super::generative_face::FaceWarp;
use super::loss::{Grads, LossParts, LossWorkspace, Objective, networks_loss};
use super::nets::{CanonicalFrame, GenerativeNets};
use super::train::{ModelTrainer, Stage1Config, TrainingData, as_grads, batch_picks, pose_index};
use crate::contact::surface::FaceContact;
use crate::drive::Codes;
use crate::mapping::Mapping;
use crate::model::FaceModel;
use crate::model::contact_region::FaceContactSettings;
use crate::model::face::Binding;
use crate::nn::{CodeBatch, Pass, Tape};
use crate::rig::FaceRig;
use crate::sim::{
    Bone, BonePose, Quality, RigidMotion, SimError, SimState, Simulator, SolveSettings, SolveStats,
    SymTensor, Termination, on_worker,
};

/// The stage-2 networks' file name in a sample folder, next to the stage-1
/// [`super::SAMPLE_NETWORKS`] (same format; `eval --model` and `GenerativeNets::load` take it).
pub const SAMPLE_STAGE2_NETWORKS: &str = "generative-stage2.nn";

/// How stage 2 solves and when it trusts a solve.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stage2Settings {
    /// The quasistatic solve (tolerance, iteration cap, L-BFGS history, contact).
    pub solve: SolveSettings,
    /// A solve counts as an equilibrium when it converged, or stalled at the round-off floor
    /// with a residual at most this many times the tolerance.
    pub stalled_factor: f64,
    /// The largest relative residual of the adjoint solve whose sensitivities are used.
    pub max_adjoint_residual: f64,
}

impl Default for Stage2Settings {
    /// The final preset's tolerance (1e-6) without contact: contact solves cost seconds each
    /// (README, "Stage 2"), which a 60-minute budget cannot pay for enough iterations.
    fn default() -> Self {
        Stage2Settings {
            solve: SolveSettings {
                contact: false,
                ..Quality::Final.settings()
            },
            stalled_factor: 10.0,
            max_adjoint_residual: 1e-6,
        }
    }
}

/// One render vertex of the loss: where it sits in the tissue and how much of it the tissue
/// moves (`share`; the rest rides `bone` from `rest`, as [`FaceModel::render_positions`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SkinPoint {
    pub tet: [u32; 4],
    pub weights: [f64; 4],
    pub share: f64,
    pub bone: Bone,
    pub rest: Point3<f64>,
}

impl SkinPoint {
    pub(crate) fn position(&self, x: &[f64], bones: &BonePose, pivot: &Point3<f64>) -> Point3<f64> {
        let mut soft = Vector3::zeros();
        for (v, w) in self.tet.iter().zip(self.weights) {
            let i = 3 * *v as usize;
            soft += w * Vector3::new(x[i], x[i + 1], x[i + 2]);
        }
        if self.share == 1.0 {
            return Point3::from(soft);
        }
        let rigid = bones.target(self.bone, pivot, &self.rest);
        rigid + (Point3::from(soft) - rigid) * self.share
    }
}

/// The render vertices the loss (and [`super::eval`]) measures: every embedded or blended
/// one (skin and lips), with their indices in the render surface.
pub fn skin_points(face: &FaceModel) -> (Vec<usize>, Vec<SkinPoint>) {
    let mut index = Vec::new();
    let mut points = Vec::new();
    for (i, (b, rest)) in face
        .render
        .bindings
        .iter()
        .zip(&face.render.rest)
        .enumerate()
    {
        let (element, weights, share, bone) = match *b {
            Binding::Embedded { element, weights } => (element, weights, 1.0, Bone::Skull),
            Binding::Blended {
                element,
                weights,
                bone,
                embedded,
            } => (element, weights, embedded, bone),
            Binding::Rigid(_) | Binding::Bones { .. } => continue,
        };
        index.push(i);
        points.push(SkinPoint {
            tet: face.mesh.tets[element as usize],
            weights,
            share,
            bone,
            rest: *rest,
        });
    }
    (index, points)
}

/// One training pose: its codes, the fitted state the solve starts from, the target skin.
#[derive(Clone, Debug)]
pub struct Stage2Pose {
    pub codes: Codes,
    /// Interleaved simulation positions of the fitted state.
    pub start: Vec<f64>,
    /// The jaw the fitted state was solved under.
    pub start_jaw: [f64; 6],
    /// Per [`SkinPoint`] of the face, the rig's target position.
    pub target: Vec<Point3<f64>>,
}

/// One face: its simulator, canonical positions, loss vertices and poses.
pub struct Stage2Face {
    pub name: String,
    pub sim: Simulator,
    pub jaw_pivot: Point3<f64>,
    pub warp: FaceWarp,
    /// N_A's input rows (the warp's canonical positions).
    input: Mat<f64>,
    pub skin: Vec<SkinPoint>,
    pub poses: Vec<Stage2Pose>,
}

impl Stage2Face {
    /// Checks the parts agree (element, vertex and skin-point counts).
    pub fn new(
        name: String,
        sim: Simulator,
        jaw_pivot: Point3<f64>,
        warp: FaceWarp,
        skin: Vec<SkinPoint>,
        poses: Vec<Stage2Pose>,
    ) -> Result<Self, GenerativeError> {
        let n = 3 * sim.vertex_count();
        if warp.len() != sim.element_count()
            || skin.is_empty()
            || skin
                .iter()
                .any(|s| s.tet.iter().any(|&v| 3 * v as usize >= n))
            || poses
                .iter()
                .any(|p| p.start.len() != n || p.target.len() != skin.len())
        {
            return Err(GenerativeError::Config(format!(
                "stage-2 face {name}: {} elements and {} canonical positions, {} skin points, \
                 poses of the wrong size",
                sim.element_count(),
                warp.len(),
                skin.len()
            )));
        }
        Ok(Stage2Face {
            name,
            input: warp.input::<f64>(),
            sim,
            jaw_pivot,
            warp,
            skin,
            poses,
        })
    }

    /// A sample face with its cached stage-1 poses: the fitted states (rest plus the
    /// stored displacements) and the rig's targets; contact surfaces when `contact`.
    pub fn from_sample(
        rig: &FaceRig,
        face: &FaceModel,
        mapping: Option<&Mapping>,
        frame: &CanonicalFrame,
        poses: &FacePoses,
        contact: bool,
    ) -> Result<Self, GenerativeError> {
        let warp = FaceWarp::new(face, mapping, frame)?;
        let mut sim = face.simulator()?;
        if contact {
            let c = FaceContact::new(face, &FaceContactSettings::default()).map_err(|e| {
                GenerativeError::Config(format!("contact surfaces of {}: {e}", face.name))
            })?;
            sim.set_contact(c)?;
        }
        let (index, skin) = skin_points(face);
        let n = face.mesh.vertex_count();
        let poses = poses
            .poses
            .iter()
            .map(|p| {
                if p.displacements.len() != n {
                    return Err(GenerativeError::Config(format!(
                        "poses of {} have no fitted states (regenerate the pose cache)",
                        face.name
                    )));
                }
                let target = crate::model::target(rig, face, &p.codes).map_err(|source| {
                    GenerativeError::Target {
                        face: face.name.clone(),
                        source,
                    }
                })?;
                Ok(Stage2Pose {
                    codes: p.codes,
                    start: face
                        .mesh
                        .vertices
                        .iter()
                        .zip(&p.displacements)
                        .flat_map(|(r, d)| [0, 1, 2].map(|k| r[k] + f64::from(d[k])))
                        .collect(),
                    start_jaw: p.jaw,
                    target: index.iter().map(|&i| target.render[i]).collect(),
                })
            })
            .collect::<Result<Vec<_>, GenerativeError>>()?;
        Stage2Face::new(face.name.clone(), sim, face.jaw_pivot, warp, skin, poses)
    }

    /// `ℓ` at simulation positions `x` and bones, and when `grad` is given, **adds**
    /// `∂ℓ/∂x` into it and returns `∂ℓ/∂[θ; t]` of the skin that rides the jaw directly.
    pub(crate) fn surface_loss(
        &self,
        pose: &Stage2Pose,
        x: &[f64],
        bones: &BonePose,
        grad: Option<&mut [f64]>,
    ) -> (f64, [f64; 6]) {
        let inv_n = 1.0 / self.skin.len() as f64;
        let mut loss = 0.0;
        let mut jaw = [0.0; 6];
        let mut grad = grad;
        for (s, t) in self.skin.iter().zip(&pose.target) {
            let r = s.position(x, bones, &self.jaw_pivot) - t;
            loss += r.norm_squared() * inv_n;
            let Some(g) = grad.as_deref_mut() else {
                continue;
            };
            let dr = 2.0 * inv_n * r;
            for (v, w) in s.tet.iter().zip(s.weights) {
                let i = 3 * *v as usize;
                for k in 0..3 {
                    g[i + k] += s.share * w * dr[k];
                }
            }
            if s.share < 1.0 && s.bone == Bone::Jaw {
                let j = bones
                    .jaw_target_jacobian(&self.jaw_pivot, &s.rest)
                    .transpose()
                    * ((1.0 - s.share) * dr);
                for k in 0..6 {
                    jaw[k] += j[k];
                }
            }
        }
        (loss, jaw)
    }
}

/// Why a pose was left out of a batch.
#[derive(Clone, Debug, PartialEq)]
pub enum Skip {
    /// The solve failed (folded, intersecting, …).
    SolveFailed(String),
    /// It stopped away from an equilibrium.
    NotConverged {
        termination: Termination,
        residual: f64,
    },
    /// The adjoint solve failed or stopped above its tolerance.
    Adjoint(String),
}

/// One pose's surface loss and its gradients (what a batch sums).
#[derive(Clone, Debug)]
pub struct PoseGradient {
    /// `ℓ` (cm²).
    pub loss: f64,
    /// `∂ℓ/∂y` per element, `y` N_A's output (canonical `log A`, stored values).
    pub logs: Vec<[f64; 6]>,
    /// `∂ℓ/∂[θ; t]` of N_B's output.
    pub jaw: [f64; 6],
    pub solve_iterations: usize,
    pub adjoint_iterations: usize,
}

/// The stored-value gradient of a symmetric matrix as the symmetric matrix `G` with
/// `⟨G, dM⟩ = Σ g·ds` (off-diagonal stored values count twice).
fn grad_matrix(g: &[f64; 6]) -> Matrix3<f64> {
    SymTensor([g[0], g[1], g[2], 0.5 * g[3], 0.5 * g[4], 0.5 * g[5]]).to_matrix()
}

/// The inverse of [`grad_matrix`].
fn grad_stored(m: &[f64; 6]) -> [f64; 6] {
    [m[0], m[1], m[2], 2.0 * m[3], 2.0 * m[4], 2.0 * m[5]]
}

/// Each element's material `log Ã` and `Ã`, and the jaw `[θ; t]`.
type Actuated = (Vec<[f64; 6]>, Vec<SymTensor>, [f64; 6]);

/// The actuations and jaw the networks give face `face` for one modulation row `u`.
fn actuate(
    nets: &GenerativeNets,
    face: &Stage2Face,
    u: &[f64],
) -> Result<Actuated, GenerativeError> {
    let mut tape = Tape::new();
    nets.actuation.forward(
        face.input.as_ref(),
        Some(&CodeBatch::shared(u)),
        Pass::Value,
        &mut tape,
        Par::Seq,
    )?;
    let y = tape.output().expect("a value pass has outputs");
    let logs: Vec<[f64; 6]> = (0..y.nrows())
        .map(|e| {
            face.warp
                .to_material(e, &[0, 1, 2, 3, 4, 5].map(|k| y[(e, k)]))
        })
        .collect();
    let tensors: Vec<SymTensor> = logs.iter().map(exp_sym).collect();
    if let Some(e) = tensors.iter().position(|t| t.validate().is_err()) {
        return Err(GenerativeError::NonFinite(format!(
            "actuation of element {e} on {}: {:?} from log {:?}",
            face.name, tensors[e], logs[e]
        )));
    }
    let jaw = nets.jaw_params(u)?;
    if jaw.iter().any(|v| !v.is_finite()) {
        return Err(GenerativeError::NonFinite(format!("jaw {jaw:?}")));
    }
    Ok((logs, tensors, jaw))
}

pub(crate) fn bones_of(jaw: [f64; 6]) -> BonePose {
    BonePose {
        skull: RigidMotion::IDENTITY,
        jaw: RigidMotion::from_params(jaw),
    }
}

/// Pose `pose` of `face` driven by the networks at modulation row `u`: solve, surface loss,
/// sensitivities, gradients in N_A's and N_B's output spaces (module docs, steps 1–4);
/// `Ok(Err(skip))` when the pose cannot be used.
pub fn pose_gradient(
    nets: &GenerativeNets,
    face: &Stage2Face,
    pose: &Stage2Pose,
    u: &[f64],
    settings: &Stage2Settings,
) -> Result<Result<PoseGradient, Skip>, GenerativeError> {
    let (logs, tensors, jaw) = actuate(nets, face, u)?;
    let bones = bones_of(jaw);
    let (state, stats) = match solve_pose(face, pose, &tensors, &bones, settings)? {
        Ok(s) => s,
        Err(e) => return Ok(Err(Skip::SolveFailed(e.to_string()))),
    };
    let equilibrium = match stats.termination {
        Termination::Converged => true,
        Termination::Stalled => {
            stats.residual <= settings.stalled_factor * settings.solve.tolerance
        }
        Termination::IterationCap => false,
    };
    if !equilibrium {
        return Ok(Err(Skip::NotConverged {
            termination: stats.termination,
            residual: stats.residual,
        }));
    }
    let x = state.flat_positions();
    let mut dx = vec![0.0; x.len()];
    let (loss, direct_jaw) = face.surface_loss(pose, x, &bones, Some(&mut dx));
    let sens = match face.sim.sensitivities(&tensors, &bones, &state, &dx) {
        Ok(s) if s.residual <= settings.max_adjoint_residual => s,
        Ok(s) => {
            return Ok(Err(Skip::Adjoint(format!(
                "residual {:.1e} after {} iterations",
                s.residual, s.iterations
            ))));
        }
        Err(e) => return Ok(Err(Skip::Adjoint(e.to_string()))),
    };
    let logs = logs
        .iter()
        .zip(&sens.actuation)
        .enumerate()
        .map(|(e, (l, g))| {
            let material = SymTensor::from_matrix(&exp_sym_adjoint(l, &grad_matrix(g)));
            grad_stored(&face.warp.to_canonical(e, &material.0))
        })
        .collect();
    let mut jaw_grad = sens.jaw;
    for k in 0..6 {
        jaw_grad[k] += direct_jaw[k];
    }
    Ok(Ok(PoseGradient {
        loss,
        logs,
        jaw: jaw_grad,
        solve_iterations: stats.iterations,
        adjoint_iterations: sens.iterations,
    }))
}

/// Solves pose `pose` from its fitted state under its fitted jaw (from rest with contact on,
/// or when that state has folded elements (the passive fit clamps stretches but can leave a few folded where
/// the rig's target crushes tissue; the solver refuses such starts)). `Ok(Err)`: the solve
/// failed.
fn solve_pose(
    face: &Stage2Face,
    pose: &Stage2Pose,
    tensors: &[SymTensor],
    bones: &BonePose,
    settings: &Stage2Settings,
) -> Result<Result<(SimState, SolveStats), SimError>, GenerativeError> {
    let points: Vec<Point3<f64>> = pose
        .start
        .chunks_exact(3)
        .map(|p| Point3::new(p[0], p[1], p[2]))
        .collect();
    let mut state = face.sim.state_at(&points)?;
    state.bones = bones_of(pose.start_jaw);
    if settings.solve.contact {
        // The fitted state follows the rig's skin, whose lips may cross (the rig knows no
        // contact): contact must start from a crossing-free state, the rest.
        state = face.sim.rest_state();
    }
    match face.sim.solve(tensors, bones, &mut state, &settings.solve) {
        Err(SimError::FoldedStart(_)) => {
            let mut state = face.sim.rest_state();
            Ok(face
                .sim
                .solve(tensors, bones, &mut state, &settings.solve)
                .map(|s| (state, s)))
        }
        r => Ok(r.map(|s| (state, s))),
    }
}

/// The surface loss of one pose driven by the networks (no gradient), `None` when its solve
/// did not reach an equilibrium; for checks and tests.
pub fn pose_loss(
    nets: &GenerativeNets,
    face: &Stage2Face,
    pose: &Stage2Pose,
    settings: &Stage2Settings,
) -> Result<Option<f64>, GenerativeError> {
    let u = nets.modulation(std::slice::from_ref(&pose.codes))?;
    let u: Vec<f64> = (0..u.ncols()).map(|k| u[(0, k)]).collect();
    let (_, tensors, jaw) = actuate(nets, face, &u)?;
    let bones = bones_of(jaw);
    match solve_pose(face, pose, &tensors, &bones, settings)? {
        Ok((state, s)) if s.termination != Termination::IterationCap => Ok(Some(
            face.surface_loss(pose, state.flat_positions(), &bones, None)
                .0,
        )),
        _ => Ok(None),
    }
}

/// Everything stage 2 trains on.
pub struct Stage2Data {
    pub faces: Vec<Stage2Face>,
    pub settings: Stage2Settings,
    /// (face, pose) of every training pose.
    index: Vec<(usize, usize)>,
}

impl Stage2Data {
    pub fn new(faces: Vec<Stage2Face>, settings: Stage2Settings) -> Result<Self, GenerativeError> {
        if !(settings.solve.tolerance > 0.0
            && settings.stalled_factor >= 1.0
            && settings.max_adjoint_residual > 0.0)
        {
            return Err(GenerativeError::Config(format!(
                "stage-2 settings {settings:?}"
            )));
        }
        let index = pose_index(faces.iter().map(|f| f.poses.len()))?;
        Ok(Stage2Data {
            faces,
            settings,
            index,
        })
    }

    pub fn pose_count(&self) -> usize {
        self.index.len()
    }
}

/// The stage-2 loss of iteration `it`'s batch (module docs); **adds** each network's
/// parameter gradient into `grads`.
pub fn stage2_loss(
    nets: &GenerativeNets,
    data: &Stage2Data,
    config: &Stage1Config,
    it: u64,
    ws: &mut LossWorkspace,
    grads: &mut Grads,
) -> Result<LossParts, GenerativeError> {
    if config.elements_per_pose != 0 {
        return Err(GenerativeError::Config(
            "stage 2 actuates every element: elements_per_pose must be 0".into(),
        ));
    }
    let picks = batch_picks(config, it, &data.index, |_| 0);
    let codes: Vec<Codes> = picks
        .iter()
        .map(|&(f, p, _)| data.faces[f].poses[p].codes)
        .collect();
    let u = nets.modulation(&codes)?;
    let mut used = Vec::new();
    let mut skipped = 0;
    for (b, &(f, p, _)) in picks.iter().enumerate() {
        let row: Vec<f64> = (0..u.ncols()).map(|k| u[(b, k)]).collect();
        let face = &data.faces[f];
        // The solve and its adjoint on one thread: apart, the adjoint's triangular solves
        // find the factor in the other core's cache.
        let gradient =
            on_worker(|| pose_gradient(nets, face, &face.poses[p], &row, &data.settings));
        match gradient? {
            Ok(g) => used.push((f, codes[b], g)),
            Err(_) => skipped += 1,
        }
    }
    let w = &config.weights;
    if used.is_empty() {
        // Nothing to fit: only the Lipschitz term moves.
        let lip_weighted = nets
            .actuation
            .lipschitz_loss(w.lambda_lip, Some(grads[2].as_mut_slice()))?;
        return Ok(LossParts {
            lip: nets.actuation.lipschitz_loss(1.0, None)?,
            total: lip_weighted,
            skipped,
            ..LossParts::default()
        });
    }
    let inv_b = 1.0 / used.len() as f64;
    let counts: Vec<usize> = used
        .iter()
        .map(|(f, _, _)| data.faces[*f].warp.len())
        .collect();
    let rows: usize = counts.iter().sum();
    let mut x = Mat::zeros(rows, 3);
    let mut logs = Vec::with_capacity(rows);
    let mut r = 0;
    for (f, _, g) in &used {
        let input = &data.faces[*f].input;
        for e in 0..input.nrows() {
            for k in 0..3 {
                x[(r, k)] = input[(e, k)];
            }
            r += 1;
        }
        logs.extend(g.logs.iter().map(|l| l.map(|v| v * inv_b)));
    }
    let jaw: Vec<[f64; 6]> = used
        .iter()
        .map(|(_, _, g)| g.jaw.map(|v| v * inv_b))
        .collect();
    let value = used.iter().map(|(_, _, g)| g.loss).sum::<f64>() * inv_b;
    let codes: Vec<Codes> = used.iter().map(|(_, c, _)| *c).collect();
    let objective = Objective::Gradient {
        logs: &logs,
        jaw: &jaw,
        value,
    };
    let mut parts = networks_loss(
        nets,
        &codes,
        &x,
        &counts,
        &objective,
        w,
        ws,
        grads,
        Par::rayon(0),
    )?;
    parts.skipped = skipped;
    Ok(parts)
}

impl TrainingData for Stage2Data {
    type Nets = GenerativeNets;

    fn settings(&self) -> Option<String> {
        let faces: Vec<(&str, usize)> = self
            .faces
            .iter()
            .map(|f| (f.name.as_str(), f.poses.len()))
            .collect();
        Some(serde_json::json!({ "stage2": self.settings, "faces": faces }).to_string())
    }

    fn batch_loss(
        &self,
        nets: &GenerativeNets,
        config: &Stage1Config,
        it: u64,
        ws: &mut LossWorkspace,
        grads: &mut [Vec<f64>],
    ) -> Result<LossParts, GenerativeError> {
        stage2_loss(nets, self, config, it, ws, as_grads(grads)?)
    }
}

/// The stage-2 trainer: fine-tunes given (stage-1) networks.
pub type Stage2Trainer<'a> = ModelTrainer<'a, Stage2Data>;
