//! The stage-1 loss of a batch of poses and its gradient through all four networks.
//!
//! For B poses with codes c_b, each with M_b sampled elements (canonical positions X̂ and
//! canonical target logs ℓ* = R_φ log A_fit R_φᵀ) and the fitted jaw j*_b:
//!
//!   L_fit = (1/R) Σ_rows ‖ℓ(X̂; u_b) − ℓ*‖²_F          (R = Σ M_b; Frobenius of the
//!                                                        symmetric matrix: off-diagonals twice)
//!   L_jaw = (1/B) Σ_b Σ_k w_k (N_B(u_b)_k − j*_b,k)²     (w = r² for the rotation entries,
//!                                                        1 for the translation: cm²)
//!   L_act = (1/R) Σ_rows ‖ℓ(X̂; u_b)‖²_F                (the actuation regularizer: pulls
//!                                                        unconstrained tensors toward A = I)
//!   L = L_fit + L_jaw + λ_act L_act + λ_lip Π_i softplus(c_i)   (N_A's Lipschitz bounds)
//!
//! with u_b = tanh([E_x(expression_b); E_s(style_b)]). The paper (Sec. 2 of the supplemental)
//! gives λ_act = 1e-3 and λ_lip = 1e-6 for its Eq. 7 and says L_act is evaluated on the
//! sampled actuation tensors; the regularizer form (squared log distance from the identity) is
//! our reading. The jaw's rotation is weighted by a lever arm r (cm) so both jaw terms are
//! squared displacements near the chin.
//!
//! Backward: N_A's code gradient ∂L/∂u (per pose, from the chunked pass) plus N_B's input
//! gradient, times tanh′ = 1 − u², split into the two encoders' output gradients.

use std::sync::Mutex;

use faer::{Mat, Par};
use serde::{Deserialize, Serialize};

use super::GenerativeError;
use super::nets::{Architecture, GenerativeNets};
use crate::drive::Codes;
use crate::nn::{ChunkedGradient, CodeBatch, Mlp, Pass, Tape};

/// Frobenius weights of the 6 stored entries `[xx, yy, zz, xy, xz, yz]`.
pub const FROBENIUS: [f64; 6] = [1.0, 1.0, 1.0, 2.0, 2.0, 2.0];

/// Weights of the loss terms.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LossWeights {
    /// λ_act (the paper: 1e-3).
    pub lambda_act: f64,
    /// λ_lip (the paper: 1e-6).
    pub lambda_lip: f64,
    /// r: jaw rotation errors count as r·θ (cm).
    pub jaw_lever_cm: f64,
}

impl Default for LossWeights {
    fn default() -> Self {
        LossWeights {
            lambda_act: 1e-3,
            lambda_lip: 1e-6,
            jaw_lever_cm: 8.0,
        }
    }
}

/// One batch of poses (module docs).
#[derive(Clone, Debug)]
pub struct Batch {
    pub codes: Vec<Codes>,
    /// Canonical normalized positions, the rows of pose b after those of poses < b.
    pub x: Mat<f64>,
    /// Rows per pose.
    pub counts: Vec<usize>,
    /// Canonical target log per row.
    pub targets: Vec<[f64; 6]>,
    /// Fitted jaw per pose.
    pub jaw: Vec<[f64; 6]>,
}

/// The loss terms of a batch (unweighted, except `total`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LossParts {
    pub fit: f64,
    pub jaw: f64,
    pub act: f64,
    /// Π softplus(cᵢ) (before λ_lip).
    pub lip: f64,
    pub total: f64,
    /// Poses of the batch left out of the loss (stage 2: solves or adjoints that did not
    /// converge; always 0 in stage 1).
    #[serde(default)]
    pub skipped: usize,
}

/// Per-network gradients in [`super::nets::NET_NAMES`] order.
pub type Grads = [Vec<f64>; 4];

/// Zeroed gradients for `nets`.
pub fn zero_grads(nets: &GenerativeNets) -> Grads {
    nets.nets().map(|n| vec![0.0; n.num_params()])
}

/// Scratch reused across iterations.
pub struct LossWorkspace {
    chunked: ChunkedGradient<f64>,
    tapes: [Tape<f64>; 3],
}

impl LossWorkspace {
    /// `chunk_rows` and `lanes` fix the summation order (never the thread count).
    pub fn new(chunk_rows: usize, lanes: usize) -> Result<Self, GenerativeError> {
        Ok(LossWorkspace {
            chunked: ChunkedGradient::new(chunk_rows, lanes)?,
            tapes: [Tape::new(), Tape::new(), Tape::new()],
        })
    }

    /// The three tapes (encoders and N_B here; the displacement baseline uses two).
    pub(crate) fn tapes_mut(&mut self) -> &mut [Tape<f64>; 3] {
        &mut self.tapes
    }

    pub(crate) fn chunked_mut(&mut self) -> &mut ChunkedGradient<f64> {
        &mut self.chunked
    }
}

/// The loss of `batch` (module docs); **adds** each network's parameter gradient into
/// `grads`.
pub fn batch_loss(
    nets: &GenerativeNets,
    batch: &Batch,
    w: &LossWeights,
    ws: &mut LossWorkspace,
    grads: &mut Grads,
    par: Par,
) -> Result<LossParts, GenerativeError> {
    let b_count = batch.codes.len();
    let rows: usize = batch.counts.iter().sum();
    if b_count == 0
        || batch.counts.len() != b_count
        || batch.jaw.len() != b_count
        || batch.x.nrows() != rows
        || batch.targets.len() != rows
        || rows == 0
    {
        return Err(GenerativeError::Config(format!(
            "inconsistent batch: {b_count} poses, {} counts, {} jaws, {} rows, {} targets",
            batch.counts.len(),
            batch.jaw.len(),
            batch.x.nrows(),
            batch.targets.len()
        )));
    }
    let objective = Objective::Fit {
        targets: &batch.targets,
        jaw: &batch.jaw,
    };
    networks_loss(
        nets,
        &batch.codes,
        &batch.x,
        &batch.counts,
        &objective,
        w,
        ws,
        grads,
        par,
    )
}

/// What N_A's rows and N_B's outputs are compared with.
pub(crate) enum Objective<'a> {
    /// Stage 1: canonical target logs per row and fitted jaws per pose (`L_fit`, `L_jaw`).
    Fit {
        targets: &'a [[f64; 6]],
        jaw: &'a [[f64; 6]],
    },
    /// Stage 2 ([`super::stage2`]): an outer loss already differentiated by the simulator:
    /// `∂L/∂y` per row of N_A's output (canonical log, stored values) and `∂L/∂[θ; t]` per
    /// pose, and that loss's value (reported as `fit`; `jaw` is 0).
    Gradient {
        logs: &'a [[f64; 6]],
        jaw: &'a [[f64; 6]],
        value: f64,
    },
}

/// The loss of the rows `x` (pose `b`'s `counts[b]` rows after those of poses < b) against
/// `objective`, plus `λ_act·L_act` and `λ_lip·Π softplus(cᵢ)`; **adds** each network's
/// parameter gradient into `grads`. The one backward pass of both training stages.
#[allow(clippy::too_many_arguments)] // the batch's parts and the pass's scratch
pub(crate) fn networks_loss(
    nets: &GenerativeNets,
    codes_in: &[Codes],
    x: &Mat<f64>,
    counts: &[usize],
    objective: &Objective<'_>,
    w: &LossWeights,
    ws: &mut LossWorkspace,
    grads: &mut Grads,
    par: Par,
) -> Result<LossParts, GenerativeError> {
    let rows = x.nrows();
    let arch = &nets.architecture;
    let [tape_e, tape_s, tape_b] = &mut ws.tapes;

    // Encoders → u = tanh(z).
    let (u, codes) = encode(
        &nets.expression,
        &nets.style,
        arch,
        codes_in,
        counts,
        tape_e,
        tape_s,
    )?;

    // N_A: fit and regularizer terms.
    let inv_r = 1.0 / rows as f64;
    let lambda_act = w.lambda_act;
    let parts: Mutex<Vec<(usize, f64, f64)>> = Mutex::new(Vec::new());
    let [grad_e, grad_s, grad_a, grad_b] = grads;
    nets.actuation.gradient_chunked(
        x.as_ref(),
        Some(&codes),
        Pass::Gradient,
        &mut ws.chunked,
        grad_a,
        par,
        |range, tape, mut dy, _| {
            let y = tape.output().expect("outputs");
            let (mut fit, mut act) = (0.0, 0.0);
            for (i, g) in range.clone().enumerate() {
                for k in 0..6 {
                    act += FROBENIUS[k] * y[(i, k)] * y[(i, k)];
                    let reg = 2.0 * FROBENIUS[k] * lambda_act * y[(i, k)] * inv_r;
                    dy[(i, k)] = match objective {
                        Objective::Fit { targets, .. } => {
                            let r = y[(i, k)] - targets[g][k];
                            fit += FROBENIUS[k] * r * r;
                            2.0 * FROBENIUS[k] * r * inv_r + reg
                        }
                        Objective::Gradient { logs, .. } => logs[g][k] + reg,
                    };
                }
            }
            parts.lock().expect("no panics while held").push((
                range.start,
                fit * inv_r,
                act * inv_r,
            ));
            (fit + lambda_act * act) * inv_r
        },
    )?;
    let mut parts = parts.into_inner().expect("no panics while held");
    parts.sort_by_key(|p| p.0);
    let act: f64 = parts.iter().map(|p| p.2).sum();
    let mut du: Vec<f64> = ws.chunked.code_grad().to_vec();

    // N_B: jaw term.
    let (fit, jaw) = match objective {
        Objective::Fit { jaw: targets, .. } => (
            parts.iter().map(|p| p.1).sum(),
            jaw_term(
                &nets.jaw,
                &u,
                targets,
                w.jaw_lever_cm,
                tape_b,
                grad_b,
                &mut du,
            )?,
        ),
        Objective::Gradient { jaw, value, .. } => {
            nets.jaw
                .forward(u.as_ref(), None, Pass::Gradient, tape_b, Par::Seq)?;
            let dyj = Mat::from_fn(u.nrows(), 6, |b, k| jaw[b][k]);
            jaw_backward(&nets.jaw, &u, dyj, tape_b, grad_b, &mut du)?;
            (*value, 0.0)
        }
    };

    // tanh and the encoders.
    encode_backward(
        &nets.expression,
        &nets.style,
        arch,
        &u,
        &du,
        [tape_e, tape_s],
        [grad_e, grad_s],
    )?;

    // Lipschitz bounds of N_A.
    let lip_weighted = nets
        .actuation
        .lipschitz_loss(w.lambda_lip, Some(grad_a.as_mut_slice()))?;
    let lip = nets.actuation.lipschitz_loss(1.0, None)?;
    Ok(LossParts {
        fit,
        jaw,
        act,
        lip,
        total: fit + jaw + lambda_act * act + lip_weighted,
        skipped: 0,
    })
}

/// The encoders' forward pass with gradient tapes: the modulation `u = tanh(z)`
/// (B × code_dim) and its rows as a code batch, code `b` for the next `counts[b]` points.
/// Shared by the physics networks' and the displacement baseline's losses.
pub(crate) fn encode(
    expression: &Mlp<f64>,
    style: &Mlp<f64>,
    arch: &Architecture,
    codes: &[Codes],
    counts: &[usize],
    tape_e: &mut Tape<f64>,
    tape_s: &mut Tape<f64>,
) -> Result<(Mat<f64>, CodeBatch<f64>), GenerativeError> {
    let (de, cd) = (arch.expression_dim, arch.code_dim());
    let (xe, xs) = GenerativeNets::inputs(codes);
    expression.forward(xe.as_ref(), None, Pass::Gradient, tape_e, Par::Seq)?;
    style.forward(xs.as_ref(), None, Pass::Gradient, tape_s, Par::Seq)?;
    let (e, s) = (
        tape_e.output().expect("outputs"),
        tape_s.output().expect("outputs"),
    );
    let u = Mat::from_fn(codes.len(), cd, |b, k| {
        (if k < de { e[(b, k)] } else { s[(b, k - de)] }).tanh()
    });
    let u_rows: Vec<f64> = (0..codes.len())
        .flat_map(|b| (0..cd).map(move |k| (b, k)))
        .map(|(b, k)| u[(b, k)])
        .collect();
    let batch = CodeBatch::segments(cd, u_rows, counts.to_vec())?;
    Ok((u, batch))
}

/// Back through tanh and the encoders of [`encode`] from `du` (`∂L/∂u`, row-major
/// B × code_dim); **adds** their parameter gradients into `grads`.
pub(crate) fn encode_backward(
    expression: &Mlp<f64>,
    style: &Mlp<f64>,
    arch: &Architecture,
    u: &Mat<f64>,
    du: &[f64],
    [tape_e, tape_s]: [&mut Tape<f64>; 2],
    [grad_e, grad_s]: [&mut Vec<f64>; 2],
) -> Result<(), GenerativeError> {
    let (de, cd) = (arch.expression_dim, arch.code_dim());
    let dz = |b: usize, k: usize| du[b * cd + k] * (1.0 - u[(b, k)] * u[(b, k)]);
    let dye = Mat::from_fn(u.nrows(), de, &dz);
    let dys = Mat::from_fn(u.nrows(), cd - de, |b, k| dz(b, de + k));
    expression.backward(tape_e, Some(dye.as_ref()), None, grad_e, Par::Seq)?;
    style.backward(tape_s, Some(dys.as_ref()), None, grad_s, Par::Seq)?;
    Ok(())
}

/// `L_jaw` of N_B on the modulation rows `u` (B × code_dim) against the fitted jaws; **adds**
/// N_B's parameter gradient into `grad` and its input gradient into `du` (row-major B ×
/// code_dim). Shared by the physics networks and the displacement baseline (same jaw).
pub(crate) fn jaw_term(
    jaw_net: &Mlp<f64>,
    u: &Mat<f64>,
    targets: &[[f64; 6]],
    jaw_lever_cm: f64,
    tape: &mut Tape<f64>,
    grad: &mut [f64],
    du: &mut [f64],
) -> Result<f64, GenerativeError> {
    let b_count = u.nrows();
    jaw_net.forward(u.as_ref(), None, Pass::Gradient, tape, Par::Seq)?;
    let yj = tape.output().expect("outputs");
    let r2 = jaw_lever_cm * jaw_lever_cm;
    let jw = [r2, r2, r2, 1.0, 1.0, 1.0];
    let inv_b = 1.0 / b_count as f64;
    let mut jaw = 0.0;
    let dyj = Mat::from_fn(b_count, 6, |b, k| {
        let r = yj[(b, k)] - targets[b][k];
        jaw += jw[k] * r * r * inv_b;
        2.0 * jw[k] * r * inv_b
    });
    jaw_backward(jaw_net, u, dyj, tape, grad, du)?;
    Ok(jaw)
}

/// N_B backward from its output gradient `dyj` (B × 6) after a gradient pass on `tape`;
/// **adds** its parameter gradient into `grad` and its input gradient into `du`.
fn jaw_backward(
    jaw_net: &Mlp<f64>,
    u: &Mat<f64>,
    dyj: Mat<f64>,
    tape: &mut Tape<f64>,
    grad: &mut [f64],
    du: &mut [f64],
) -> Result<(), GenerativeError> {
    let (b_count, cd) = (u.nrows(), u.ncols());
    jaw_net.backward(tape, Some(dyj.as_ref()), None, grad, Par::Seq)?;
    let dub = tape.input_grad().expect("after backward");
    for b in 0..b_count {
        for k in 0..cd {
            du[b * cd + k] += dub[(b, k)];
        }
    }
    Ok(())
}
