//! Training φ for one identity (`facesim train-mapping`).
//!
//! Loss per iteration, on a random batch of the surface correspondences (xᵢ, Xᵢ) and of the
//! elastic points N_e (the simulation vertices plus one random point per element):
//!
//!   L = (1/B_s) Σᵢ ‖φ(xᵢ) − Xᵢ‖²  [mm²]  +  λ_e (1/B_e) Σⱼ ‖∂φ/∂x(xⱼ) − R(∂φ/∂x(xⱼ))‖²_F
//!
//! The elastic term is the as-rigid-as-possible energy density of φ: zero exactly where φ is
//! locally a rotation, so it penalizes stretch, shear and volume change alike and keeps
//! ∂φ/∂x invertible (its rotation is R_φ, the one the warp uses). The supplemental gives only
//! its weight (λ_e = 10) and its points; we measure vertex errors in millimetres (the unit of
//! the paper's Fig. 3), which sets the balance between the two terms. Its gradient needs no
//! derivative of R: at the closest rotation, ∂‖J − R(J)‖²/∂J = 2(J − R) (envelope theorem).
//!
//! Schedule: Adam, constant learning rate for the first half, then linear decay to 0 (the
//! paper's shape), deterministic from the seed (initialization, elastic points, batches).

use faer::{Mat, MatMut, Par};
use nalgebra::Matrix3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::MappingError;
use super::network::{Architecture, Mapping, TrainingRecord, rotation_of};
use super::samples::{Correspondences, elastic_points};
use crate::model::FaceModel;
use crate::nn::{Adam, AdamConfig, ChunkedGradient, LrSchedule, Mlp, Pass, Tape};

/// Millimetres per centimetre (model units are cm, vertex errors are reported in mm).
pub const MM_PER_CM: f64 = 10.0;

/// Training settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainConfig {
    pub architecture: Architecture,
    pub iterations: u64,
    /// Peak learning rate lr₀ (the paper: 1e-4 over 100k iterations).
    pub learning_rate: f64,
    /// Fraction of the iterations at lr₀ before the linear decay (the paper: 0.5).
    pub decay_start_fraction: f64,
    /// λ_e (the paper: 10).
    pub lambda_elastic: f64,
    /// Correspondences per iteration (0: all).
    pub surface_batch: usize,
    /// Elastic points per iteration (0: all).
    pub elastic_batch: usize,
    pub seed: u64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            architecture: Architecture::default(),
            iterations: 8000,
            learning_rate: 1e-3,
            decay_start_fraction: 0.5,
            lambda_elastic: 10.0,
            surface_batch: 1024,
            elastic_batch: 1024,
            seed: 1,
        }
    }
}

/// One iteration's batch losses (the loss curve).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LossRow {
    pub iteration: u64,
    pub learning_rate: f64,
    /// Mean squared vertex error of the batch, mm².
    pub vertex_mse_mm2: f64,
    /// Mean ‖J − R‖²_F of the batch.
    pub elastic: f64,
    /// vertex_mse_mm2 + λ_e · elastic.
    pub total: f64,
}

/// The loss curve as CSV (header and one row per iteration).
pub fn loss_csv(rows: &[LossRow]) -> String {
    let mut s = String::from("iteration,learning_rate,vertex_mse_mm2,elastic,total\n");
    for r in rows {
        s.push_str(&format!(
            "{},{:e},{:e},{:e},{:e}\n",
            r.iteration, r.learning_rate, r.vertex_mse_mm2, r.elastic, r.total
        ));
    }
    s
}

/// Chunk size and lanes of the data-parallel gradient (results depend on these, never on the
/// thread count).
const CHUNK_ROWS: usize = 128;
const LANES: usize = 8;

/// Rows `idx` of `points` (normalized) as an N × 3 matrix.
fn rows_of(points: &[[f64; 3]], idx: &[usize]) -> Mat<f64> {
    Mat::from_fn(idx.len(), 3, |i, k| points[idx[i]][k])
}

/// A batch of `batch` distinct indices below `n` (all of them, in order, when `batch` is 0 or
/// not smaller than `n`).
fn batch_indices(n: usize, batch: usize, rng: &mut ChaCha8Rng) -> Vec<usize> {
    if batch == 0 || batch >= n {
        (0..n).collect()
    } else {
        rand::seq::index::sample(rng, n, batch).into_vec()
    }
}

/// ∂φ/∂x at point `i` of a chunk of `m` points: I + ∂y/∂x̂ from the tape.
fn jacobian_at(tape: &Tape<f64>, i: usize, m: usize) -> Matrix3<f64> {
    let jac = tape.jacobian().expect("a Jacobian pass");
    Matrix3::from_fn(|r, k| f64::from(u8::from(r == k)) + jac[(k * m + i, r)])
}

/// One iteration's points: normalized surface points and their normalized targets, elastic
/// points, the mm² per normalized unit², and λ_e.
struct Batch<'a> {
    surface: faer::MatRef<'a, f64>,
    targets: &'a [[f64; 3]],
    elastic: faer::MatRef<'a, f64>,
    mm2: f64,
    lambda: f64,
}

/// The batch's vertex term and λ_e × elastic term (module docs); **adds** their parameter
/// gradient into `grad`.
fn batch_loss(
    net: &Mlp<f64>,
    b: &Batch<'_>,
    ws: &mut ChunkedGradient<f64>,
    grad: &mut [f64],
) -> Result<(f64, f64), MappingError> {
    let (bs, be) = (b.surface.nrows() as f64, b.elastic.nrows() as f64);
    let (xs, targets, mm2, lambda) = (b.surface, b.targets, b.mm2, b.lambda);
    // Vertex term: r = x̂ + y − X̂ (normalized), error² = mm2·‖r‖².
    let vertex = net.gradient_chunked(
        xs,
        None,
        Pass::Gradient,
        ws,
        grad,
        Par::rayon(0),
        |range, tape, mut dy: MatMut<'_, f64>, _| {
            let y = tape.output().expect("outputs");
            let mut loss = 0.0;
            for (i, g) in range.clone().enumerate() {
                for k in 0..3 {
                    let r = xs[(g, k)] + y[(i, k)] - targets[g][k];
                    loss += mm2 * r * r / bs;
                    dy[(i, k)] = 2.0 * mm2 * r / bs;
                }
            }
            loss
        },
    )?;
    if !(lambda > 0.0) || b.elastic.nrows() == 0 {
        return Ok((vertex, 0.0));
    }
    // Elastic term: λ_e ‖J − R‖² / B_e, gradient 2λ_e (J − R) / B_e.
    let elastic = net.gradient_chunked(
        b.elastic,
        None,
        Pass::Jacobian,
        ws,
        grad,
        Par::rayon(0),
        |range, tape, _, dj| {
            let mut dj = dj.expect("a Jacobian pass");
            let m = range.len();
            let mut loss = 0.0;
            for i in 0..m {
                let j = jacobian_at(tape, i, m);
                let d = j - rotation_of(&j);
                loss += lambda * d.norm_squared() / be;
                for r in 0..3 {
                    for k in 0..3 {
                        dj[(k * m + i, r)] = 2.0 * lambda * d[(r, k)] / be;
                    }
                }
            }
            loss
        },
    )?;
    Ok((vertex, elastic))
}

/// Trains φ for `identity` against `canonical`. `progress` sees every iteration's losses.
pub fn train(
    identity: &FaceModel,
    canonical: &FaceModel,
    config: &TrainConfig,
    mut progress: impl FnMut(&LossRow),
) -> Result<(Mapping, Vec<LossRow>), MappingError> {
    if !(config.lambda_elastic.is_finite() && config.lambda_elastic >= 0.0) {
        return Err(MappingError::Config(format!(
            "λ_e = {} must be ≥ 0",
            config.lambda_elastic
        )));
    }
    let schedule = LrSchedule::linear_decay(
        config.learning_rate,
        config.iterations,
        config.decay_start_fraction,
    )?;
    let mut mapping = Mapping::new(identity, canonical, config.architecture, config.seed)?;
    let frame = mapping.frame;
    let pairs = Correspondences::between(identity, canonical)?;
    let surface_x: Vec<[f64; 3]> = pairs
        .material
        .iter()
        .map(|p| frame.normalize_material(p))
        .collect();
    let surface_target: Vec<[f64; 3]> = pairs
        .canonical
        .iter()
        .map(|p| frame.normalize_canonical(p))
        .collect();
    let elastic: Vec<[f64; 3]> = elastic_points(&identity.mesh, config.seed ^ 0x5eed_e1a5)
        .iter()
        .map(|p| frame.normalize_material(p))
        .collect();

    let n_params = mapping.network().num_params();
    let mut adam = Adam::new(n_params, AdamConfig::default())?;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed ^ 0x0ba7_c4e5);
    let mut ws = ChunkedGradient::new(CHUNK_ROWS, LANES)?;
    let mut grad = vec![0.0; n_params];
    let mm2 = (MM_PER_CM * frame.scale).powi(2);
    let lambda = config.lambda_elastic;
    let mut rows = Vec::with_capacity(config.iterations as usize);
    for it in 0..config.iterations {
        let si = batch_indices(surface_x.len(), config.surface_batch, &mut rng);
        let ei = batch_indices(elastic.len(), config.elastic_batch, &mut rng);
        let xs = rows_of(&surface_x, &si);
        let targets: Vec<[f64; 3]> = si.iter().map(|&i| surface_target[i]).collect();
        let xe = rows_of(&elastic, &ei);
        grad.iter_mut().for_each(|g| *g = 0.0);
        let (vertex, elastic_loss) = batch_loss(
            mapping.network(),
            &Batch {
                surface: xs.as_ref(),
                targets: &targets,
                elastic: xe.as_ref(),
                mm2,
                lambda,
            },
            &mut ws,
            &mut grad,
        )?;
        let lr = schedule.lr_at(it);
        let row = LossRow {
            iteration: it,
            learning_rate: lr,
            vertex_mse_mm2: vertex,
            elastic: if lambda > 0.0 {
                elastic_loss / lambda
            } else {
                0.0
            },
            total: vertex + elastic_loss,
        };
        if !row.total.is_finite() || grad.iter().any(|g| !g.is_finite()) {
            return Err(MappingError::Diverged(it));
        }
        adam.step(mapping.network_mut().params_mut(), &grad, lr)?;
        progress(&row);
        rows.push(row);
    }

    // Final losses over all points.
    let mapped = mapping.evaluate(&pairs.material)?;
    let vertex_mse_mm2 = mapped
        .iter()
        .zip(&pairs.canonical)
        .map(|(m, t)| ((m.canonical - t).norm() * MM_PER_CM).powi(2))
        .sum::<f64>()
        / pairs.len() as f64;
    let all_elastic = elastic_points(&identity.mesh, config.seed ^ 0x5eed_e1a5);
    let mapped = mapping.evaluate(&all_elastic)?;
    let elastic_mean = mapped
        .iter()
        .map(|m| (m.jacobian - rotation_of(&m.jacobian)).norm_squared())
        .sum::<f64>()
        / mapped.len() as f64;
    mapping.record = Some(TrainingRecord {
        seed: config.seed,
        iterations: config.iterations,
        learning_rate: config.learning_rate,
        lambda_elastic: lambda,
        surface_batch: config.surface_batch,
        elastic_batch: config.elastic_batch,
        surface_points: pairs.len(),
        elastic_points: elastic.len(),
        final_vertex_mse_mm2: vertex_mse_mm2,
        final_elastic: elastic_mean,
    });
    Ok((mapping, rows))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::MlpSpec;

    /// The batch loss gradient (vertex term through the outputs, elastic term through the
    /// Jacobian and its closest rotation) agrees with central differences.
    #[test]
    fn batch_loss_gradient_matches_central_differences() {
        let mut net = Mlp::<f64>::new(MlpSpec::siren(3, 8, 2, 5.0, 3), 3).unwrap();
        let xs = Mat::from_fn(7, 3, |i, k| ((i * 5 + k * 3) % 11) as f64 / 5.5 - 1.0);
        let targets: Vec<[f64; 3]> = (0..7)
            .map(|i| [0.1 * i as f64, -0.05 * i as f64, 0.3])
            .collect();
        let xe = Mat::from_fn(9, 3, |i, k| ((i * 7 + k * 2) % 13) as f64 / 6.5 - 1.0);
        let b = Batch {
            surface: xs.as_ref(),
            targets: &targets,
            elastic: xe.as_ref(),
            mm2: 3.0,
            lambda: 10.0,
        };
        let mut ws = ChunkedGradient::new(4, 3).unwrap();
        let mut grad = vec![0.0; net.num_params()];
        batch_loss(&net, &b, &mut ws, &mut grad).unwrap();
        let h = 1e-6;
        for p in (0..net.num_params()).step_by(5) {
            let mut f = |delta: f64| {
                let keep = net.params()[p];
                net.params_mut()[p] = keep + delta;
                let mut g = vec![0.0; net.num_params()];
                let (v, e) = batch_loss(&net, &b, &mut ws, &mut g).unwrap();
                net.params_mut()[p] = keep;
                v + e
            };
            let fd = (f(h) - f(-h)) / (2.0 * h);
            assert!(
                (fd - grad[p]).abs() <= 1e-6 * (1.0 + fd.abs()),
                "param {p}: analytic {} vs central difference {fd}",
                grad[p]
            );
        }
    }
}
