//! Stage-1 training (no simulator): fit the networks to the per-pose actuations and jaw
//! motions of [`super::data`] with the loss of [`super::loss`].
//!
//! Adam per network, the learning rate constant for the first half and then decaying
//! linearly to 0 (the paper's shape). Iteration i draws its batch (poses, then elements per
//! pose) from a stream seeded by (seed, i) alone, and the optimizer state is checkpointed with
//! the networks, so a run resumed from a checkpoint is bitwise the run that never stopped.

use faer::{Mat, Par};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::GenerativeError;
use super::data::FacePoses;
use super::generative_face::FaceWarp;
use super::loss::{Batch, Grads, LossParts, LossWeights, LossWorkspace, batch_loss};
use super::nets::{Architecture, CanonicalFrame, GenerativeNets, NET_NAMES, from_hex, to_hex};
use crate::drive::Codes;
use crate::nn::{Adam, AdamConfig, Checkpoint, LrSchedule, Mlp};

/// Stage-1 settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Stage1Config {
    pub architecture: Architecture,
    pub iterations: u64,
    /// Poses per batch (the paper: 6).
    pub batch_poses: usize,
    /// Elements sampled per pose (0: all of the face's elements).
    pub elements_per_pose: usize,
    /// Peak learning rate.
    pub learning_rate: f64,
    /// Fraction of the iterations at the peak before the linear decay (the paper: 0.5).
    pub decay_start_fraction: f64,
    pub weights: LossWeights,
    pub seed: u64,
    /// Rows per chunk and lanes of the data-parallel gradient (fix the summation order).
    pub chunk_rows: usize,
    pub lanes: usize,
}

impl Default for Stage1Config {
    fn default() -> Self {
        Stage1Config {
            architecture: Architecture::default(),
            iterations: 6000,
            batch_poses: 6,
            elements_per_pose: 1024,
            learning_rate: 1e-3,
            decay_start_fraction: 0.5,
            weights: LossWeights::default(),
            seed: 1,
            chunk_rows: 256,
            lanes: 8,
        }
    }
}

/// One pose's labels in canonical space.
#[derive(Clone, Debug)]
pub struct PoseSample {
    pub codes: Codes,
    pub jaw: [f64; 6],
    /// Canonical `log A` per element.
    pub logs: Vec<[f32; 6]>,
}

/// One face's elements and poses.
#[derive(Clone, Debug)]
pub struct FaceData {
    pub name: String,
    pub warp: FaceWarp,
    pub poses: Vec<PoseSample>,
}

/// Everything stage 1 trains on.
#[derive(Clone, Debug)]
pub struct Stage1Data {
    pub faces: Vec<FaceData>,
    /// (face, pose) of every training pose.
    index: Vec<(usize, usize)>,
}

impl Stage1Data {
    /// Rotates each face's material-space labels into canonical space with its warp.
    pub fn new(faces: Vec<(FaceWarp, FacePoses)>) -> Result<Self, GenerativeError> {
        let mut out = Vec::with_capacity(faces.len());
        for (warp, poses) in faces {
            if poses.element_count != warp.len() {
                return Err(GenerativeError::Config(format!(
                    "poses of {} have {} elements, its warp {}",
                    poses.face,
                    poses.element_count,
                    warp.len()
                )));
            }
            let samples = poses
                .poses
                .iter()
                .map(|p| PoseSample {
                    codes: p.codes,
                    jaw: p.jaw,
                    logs: p
                        .logs
                        .iter()
                        .enumerate()
                        .map(|(e, l)| warp.to_canonical(e, &l.map(f64::from)).map(|v| v as f32))
                        .collect(),
                })
                .collect();
            out.push(FaceData {
                name: poses.face,
                warp,
                poses: samples,
            });
        }
        let index = pose_index(out.iter().map(|d| d.poses.len()))?;
        Ok(Stage1Data { faces: out, index })
    }

    pub fn pose_count(&self) -> usize {
        self.index.len()
    }

    /// The batch of iteration `it` (module docs).
    pub fn batch(&self, config: &Stage1Config, it: u64) -> Batch {
        let (mut codes, mut counts, mut targets, mut jaw, mut rows) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (f, p, elements) in batch_picks(config, it, &self.index, |f| self.faces[f].warp.len()) {
            let face = &self.faces[f];
            let pose = &face.poses[p];
            codes.push(pose.codes);
            counts.push(elements.len());
            jaw.push(pose.jaw);
            for e in elements {
                targets.push(pose.logs[e].map(f64::from));
                rows.push(face.warp.canonical[e]);
            }
        }
        Batch {
            codes,
            x: Mat::from_fn(rows.len(), 3, |i, k| rows[i][k]),
            counts,
            targets,
            jaw,
        }
    }
}

/// `(face, pose)` for every pose of faces with `pose_counts` poses, in order (the list
/// [`batch_picks`] draws from); an error when there is none.
pub(crate) fn pose_index(
    pose_counts: impl Iterator<Item = usize>,
) -> Result<Vec<(usize, usize)>, GenerativeError> {
    let index: Vec<(usize, usize)> = pose_counts
        .enumerate()
        .flat_map(|(f, n)| (0..n).map(move |p| (f, p)))
        .collect();
    if index.is_empty() {
        return Err(GenerativeError::Config("no training poses".into()));
    }
    Ok(index)
}

/// The poses and rows of iteration `it`'s batch: `config.batch_poses` distinct (face, pose)
/// entries of `index`, then for each `config.elements_per_pose` distinct rows (sorted) of
/// its face (`rows_of(face)` rows; all when 0 or more), all from one stream seeded by
/// (seed, it) alone. Shared by every model [`ModelTrainer`] trains, so they see the same
/// poses in the same order for a seed.
pub fn batch_picks(
    config: &Stage1Config,
    it: u64,
    index: &[(usize, usize)],
    rows_of: impl Fn(usize) -> usize,
) -> Vec<(usize, usize, Vec<usize>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(
        config.seed ^ 0xba7c_4e55 ^ it.wrapping_mul(0x9e37_79b9_7f4a_7c15),
    );
    let b = config.batch_poses.min(index.len());
    let picks = rand::seq::index::sample(&mut rng, index.len(), b).into_vec();
    picks
        .into_iter()
        .map(|i| {
            let (f, p) = index[i];
            let n = rows_of(f);
            let m = config.elements_per_pose;
            let mut rows = if m == 0 || m >= n {
                (0..n).collect()
            } else {
                rand::seq::index::sample(&mut rng, n, m).into_vec()
            };
            rows.sort_unstable();
            (f, p, rows)
        })
        .collect()
}

/// One iteration of the loss curve.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LossRow {
    pub iteration: u64,
    pub learning_rate: f64,
    pub parts: LossParts,
}

/// The CSV header of the loss curve.
pub const LOSS_CSV_HEADER: &str =
    "iteration,learning_rate,fit,jaw_cm2,act,lipschitz_product,total,skipped_poses";

impl LossRow {
    /// One CSV line (no newline).
    pub fn csv(&self) -> String {
        let p = &self.parts;
        format!(
            "{},{:e},{:e},{:e},{:e},{:e},{:e},{}",
            self.iteration, self.learning_rate, p.fit, p.jaw, p.act, p.lip, p.total, p.skipped
        )
    }
}

/// A set of networks [`ModelTrainer`] optimizes: their names, deterministic initialization,
/// parameters and checkpoint form (the expression/style networks, the displacement baseline).
pub trait NetworkSet: Sized {
    /// Names of the networks in a checkpoint, in [`NetworkSet::networks`] order.
    fn names() -> &'static [&'static str];
    /// Fresh networks, initialized deterministically from `seed`.
    fn init(
        architecture: Architecture,
        frame: CanonicalFrame,
        seed: u64,
    ) -> Result<Self, GenerativeError>;
    fn networks(&self) -> Vec<&Mlp<f64>>;
    fn networks_mut(&mut self) -> Vec<&mut Mlp<f64>>;
    fn to_checkpoint(&self) -> Checkpoint;
    fn from_checkpoint(ck: &Checkpoint) -> Result<Self, GenerativeError>;

    /// Writes the networks as a checkpoint file.
    fn save(&self, path: &std::path::Path) -> Result<(), GenerativeError> {
        Ok(self.to_checkpoint().save(path)?)
    }

    /// Reads networks saved by [`NetworkSet::save`].
    fn load(path: &std::path::Path) -> Result<Self, GenerativeError> {
        Self::from_checkpoint(&Checkpoint::load(path)?)
    }
}

/// What [`ModelTrainer`] trains on: data with a batch loss for its networks (stage 1's and
/// stage 2's data for the expression/style networks, the baseline's for the displacement
/// networks). The trainer owns everything else (Adam per network, the schedule, seeded
/// batches, checkpoints and resume), so every model trains alike.
pub trait TrainingData {
    /// The networks the loss differentiates.
    type Nets: NetworkSet;
    /// Settings of the data that a resumed run must share with the saved one (beyond the
    /// [`Stage1Config`]), as a string; `None` when the data has none.
    fn settings(&self) -> Option<String> {
        None
    }
    /// The loss of iteration `it`'s batch; **adds** each network's gradient into `grads`.
    fn batch_loss(
        &self,
        nets: &Self::Nets,
        config: &Stage1Config,
        it: u64,
        ws: &mut LossWorkspace,
        grads: &mut [Vec<f64>],
    ) -> Result<LossParts, GenerativeError>;
}

impl NetworkSet for GenerativeNets {
    fn names() -> &'static [&'static str] {
        &NET_NAMES
    }

    fn init(
        architecture: Architecture,
        frame: CanonicalFrame,
        seed: u64,
    ) -> Result<Self, GenerativeError> {
        GenerativeNets::new(architecture, frame, seed)
    }

    fn networks(&self) -> Vec<&Mlp<f64>> {
        self.nets().to_vec()
    }

    fn networks_mut(&mut self) -> Vec<&mut Mlp<f64>> {
        self.nets_mut().into_iter().collect()
    }

    fn to_checkpoint(&self) -> Checkpoint {
        GenerativeNets::to_checkpoint(self)
    }

    fn from_checkpoint(ck: &Checkpoint) -> Result<Self, GenerativeError> {
        GenerativeNets::from_checkpoint(ck)
    }
}

impl TrainingData for Stage1Data {
    type Nets = GenerativeNets;

    fn batch_loss(
        &self,
        nets: &GenerativeNets,
        config: &Stage1Config,
        it: u64,
        ws: &mut LossWorkspace,
        grads: &mut [Vec<f64>],
    ) -> Result<LossParts, GenerativeError> {
        let batch = self.batch(config, it);
        batch_loss(
            nets,
            &batch,
            &config.weights,
            ws,
            as_grads(grads)?,
            Par::rayon(0),
        )
    }
}

/// The four expression/style networks' gradients as [`Grads`].
pub(crate) fn as_grads(grads: &mut [Vec<f64>]) -> Result<&mut Grads, GenerativeError> {
    grads
        .try_into()
        .map_err(|_| GenerativeError::Config("gradients of 4 networks expected".into()))
}

/// The training state: networks, optimizers, next iteration.
pub struct ModelTrainer<'a, D: TrainingData> {
    data: &'a D,
    config: Stage1Config,
    schedule: LrSchedule,
    nets: D::Nets,
    adams: Vec<Adam>,
    iteration: u64,
    ws: LossWorkspace,
}

/// The stage-1 trainer of the expression/style networks.
pub type Trainer<'a> = ModelTrainer<'a, Stage1Data>;

const CONFIG_KEY: &str = "stage1_config";
const ITERATION_KEY: &str = "stage1_iteration";
const DATA_SETTINGS_KEY: &str = "data_settings";

impl<'a, D: TrainingData> ModelTrainer<'a, D> {
    /// A fresh run: networks initialized from the seed.
    pub fn new(
        data: &'a D,
        config: Stage1Config,
        frame: CanonicalFrame,
    ) -> Result<Self, GenerativeError> {
        let nets = D::Nets::init(config.architecture, frame, config.seed)?;
        Self::from_nets(data, config, nets)
    }

    /// A fresh run (fresh optimizers, iteration 0) from given networks: fine-tuning, such as
    /// stage 2 from the stage-1 weights.
    pub fn from_nets(
        data: &'a D,
        config: Stage1Config,
        nets: D::Nets,
    ) -> Result<Self, GenerativeError> {
        let adams = nets
            .networks()
            .iter()
            .map(|n| Adam::new(n.num_params(), AdamConfig::default()))
            .collect::<Result<_, _>>()?;
        Self::assemble(data, config, nets, adams, 0)
    }

    /// Continues the run saved in `ck` (by [`ModelTrainer::checkpoint`]); the configuration
    /// must be the saved one.
    pub fn resume(
        data: &'a D,
        config: Stage1Config,
        ck: &Checkpoint,
    ) -> Result<Self, GenerativeError> {
        let meta = ck.metadata();
        let saved: Stage1Config = meta
            .get(CONFIG_KEY)
            .ok_or_else(|| {
                GenerativeError::Checkpoint("no stage-1 settings in the checkpoint".into())
            })
            .and_then(|s| {
                serde_json::from_str(s)
                    .map_err(|e| GenerativeError::Checkpoint(format!("stage-1 settings: {e}")))
            })?;
        if saved != config {
            return Err(GenerativeError::Checkpoint(format!(
                "the checkpoint was made with other settings: {saved:?}, now {config:?}"
            )));
        }
        let (saved, now) = (meta.get(DATA_SETTINGS_KEY), data.settings());
        if saved != now.as_ref() {
            return Err(GenerativeError::Checkpoint(format!(
                "the checkpoint was made with other data settings: {saved:?}, now {now:?}"
            )));
        }
        let iteration: u64 = meta
            .get(ITERATION_KEY)
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| GenerativeError::Checkpoint("no iteration in the checkpoint".into()))?;
        let nets = D::Nets::from_checkpoint(ck)?;
        let adams = D::Nets::names()
            .iter()
            .map(|n| {
                let hex = meta.get(&format!("adam_{n}")).ok_or_else(|| {
                    GenerativeError::Checkpoint(format!("no optimizer state for {n}"))
                })?;
                from_hex::<Adam>(hex).map_err(|e| {
                    GenerativeError::Checkpoint(format!("optimizer state of {n}: {e}"))
                })
            })
            .collect::<Result<_, _>>()?;
        Self::assemble(data, config, nets, adams, iteration)
    }

    fn assemble(
        data: &'a D,
        config: Stage1Config,
        nets: D::Nets,
        adams: Vec<Adam>,
        iteration: u64,
    ) -> Result<Self, GenerativeError> {
        if config.batch_poses == 0 {
            return Err(GenerativeError::Config("batch of 0 poses".into()));
        }
        let w = &config.weights;
        if !(w.lambda_act >= 0.0 && w.lambda_lip >= 0.0 && w.jaw_lever_cm > 0.0) {
            return Err(GenerativeError::Config(format!("loss weights {w:?}")));
        }
        Ok(ModelTrainer {
            data,
            schedule: LrSchedule::linear_decay(
                config.learning_rate,
                config.iterations,
                config.decay_start_fraction,
            )?,
            ws: LossWorkspace::new(config.chunk_rows, config.lanes)?,
            config,
            nets,
            adams,
            iteration,
        })
    }

    /// The next iteration to run.
    pub fn iteration(&self) -> u64 {
        self.iteration
    }

    pub fn done(&self) -> bool {
        self.iteration >= self.config.iterations
    }

    pub fn nets(&self) -> &D::Nets {
        &self.nets
    }

    pub fn into_nets(self) -> D::Nets {
        self.nets
    }

    /// Runs one iteration.
    pub fn step(&mut self) -> Result<LossRow, GenerativeError> {
        let it = self.iteration;
        let mut grads: Vec<Vec<f64>> = self
            .nets
            .networks()
            .iter()
            .map(|n| vec![0.0; n.num_params()])
            .collect();
        let parts = self
            .data
            .batch_loss(&self.nets, &self.config, it, &mut self.ws, &mut grads)?;
        if !parts.total.is_finite() || grads.iter().flatten().any(|g| !g.is_finite()) {
            return Err(GenerativeError::Diverged(it));
        }
        let lr = self.schedule.lr_at(it);
        for ((net, adam), g) in self
            .nets
            .networks_mut()
            .into_iter()
            .zip(&mut self.adams)
            .zip(&grads)
        {
            adam.step(net.params_mut(), g, lr)?;
        }
        self.iteration += 1;
        Ok(LossRow {
            iteration: it,
            learning_rate: lr,
            parts,
        })
    }

    /// Networks, optimizer states, settings and the next iteration.
    pub fn checkpoint(&self) -> Checkpoint {
        let mut ck = self.nets.to_checkpoint();
        let meta = ck.metadata_mut();
        // Optimizer states as exact bits (see `nets::to_hex`), not the kit's JSON numbers.
        for (name, adam) in D::Nets::names().iter().zip(&self.adams) {
            meta.insert(format!("adam_{name}"), to_hex(adam));
        }
        meta.insert(
            CONFIG_KEY.into(),
            serde_json::to_string(&self.config).expect("serializable"),
        );
        meta.insert(ITERATION_KEY.into(), self.iteration.to_string());
        if let Some(s) = self.data.settings() {
            meta.insert(DATA_SETTINGS_KEY.into(), s);
        }
        ck
    }
}

/// Trains from scratch to the end; `progress` sees every row.
pub fn train_stage1(
    data: &Stage1Data,
    config: Stage1Config,
    frame: CanonicalFrame,
    progress: impl FnMut(&LossRow),
) -> Result<(GenerativeNets, Vec<LossRow>), GenerativeError> {
    train_model(data, config, frame, progress)
}

/// Trains the networks of any [`TrainingData`] from scratch to the end; `progress` sees every
/// row.
pub fn train_model<D: TrainingData>(
    data: &D,
    config: Stage1Config,
    frame: CanonicalFrame,
    mut progress: impl FnMut(&LossRow),
) -> Result<(D::Nets, Vec<LossRow>), GenerativeError> {
    let mut t = ModelTrainer::new(data, config, frame)?;
    let mut rows = Vec::new();
    while !t.done() {
        let row = t.step()?;
        progress(&row);
        rows.push(row);
    }
    Ok((t.into_nets(), rows))
}
