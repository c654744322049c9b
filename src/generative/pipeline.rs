//! A sample's training and evaluation runs, as `facesim train` and `facesim eval` start them:
//! the stage-1 poses of every face (fitted once, cached in `OUT/poses`), each stage's data and
//! defaults, the networks bound to every face, and the style-transfer pairs.

use std::borrow::Cow;
use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use super::data::FacePoses;
use super::eval::{EvalFace, EvalModel, EvalReport, evaluate};
use super::generative_face::FaceWarp;
use super::run::{
    DISPLACEMENT_FILES, RunError, RunEvent, RunFiles, RunPlan, RunReport, STAGE1_FILES,
    STAGE2_FILES, run_training, write_atomic,
};
use super::transfer::NearestElementTransfer;
use super::{
    CanonicalFrame, DisplacementData, DisplacementFace, DisplacementNets, GenerativeError,
    GenerativeFace, GenerativeNets, NetworkSet, PoseSettings, SAMPLE_NETWORKS, Stage1Config,
    Stage1Data, Stage2Data, Stage2Face, Stage2Settings, TrainingData,
};
use crate::drive::ActuationModel;
use crate::rig::{ExpressionCode, FaceRig, RigError};
use crate::sample::Sample;

/// What a training run trains.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Stage 1: the expression/style networks fitted to the stage-1 actuations and jaw motions.
    One,
    /// Stage 2: networks fine-tuned through the simulator against the rig's skin.
    Two,
    /// The displacement baseline, fitted to the same poses' vertex displacements.
    Displacement,
}

/// A training run's settings; `None` takes the stage's default.
#[derive(Clone, Debug)]
pub struct TrainOptions {
    pub stage: Stage,
    /// The run's folder (created if missing); the pose cache is `out/poses`.
    pub out: PathBuf,
    /// Stage 2: the networks to fine-tune (default: the sample's `generative.nn`).
    pub init: Option<PathBuf>,
    /// Stage 2: solve with lip and teeth contact.
    pub contact: bool,
    pub seed: u64,
    pub iterations: Option<u64>,
    pub learning_rate: Option<f64>,
    pub batch_poses: usize,
    /// Elements sampled per pose (0: all; stage 2 always uses all).
    pub elements_per_pose: usize,
    pub checkpoint_every: Option<u64>,
    /// Continue the run whose checkpoint is in `out`.
    pub resume: bool,
    /// Random combinations per face in the stage-1 data.
    pub combinations: usize,
}

/// Stage 2's defaults where they differ from stage 1's: every element, a learning rate a
/// tenth of stage 1's (the networks start trained: Adam's first steps move every weight by
/// about the learning rate, and stage 1's 1e-3 would undo much of stage 1 before the
/// moments settle), and iterations that fit the 60-minute budget on this machine.
pub fn stage2_defaults() -> Stage1Config {
    Stage1Config {
        iterations: 800,
        learning_rate: 1e-4,
        elements_per_pose: 0,
        ..Stage1Config::default()
    }
}

/// What [`train_sample`] tells as it goes.
pub enum TrainEvent<'a> {
    /// A face's stage-1 poses came from the cache.
    PosesCached {
        face: &'a str,
        poses: usize,
        path: &'a Path,
    },
    /// Fitting a face's stage-1 poses: `done` of `total`.
    FittingPoses {
        face: &'a str,
        done: usize,
        total: usize,
    },
    /// A face's stage-1 poses are fitted and cached; `worst_skin_rms` in cm.
    PosesFitted {
        face: &'a str,
        poses: usize,
        seconds: f64,
        worst_skin_rms: f64,
        clamped: usize,
    },
    /// Stage 2's targets and simulators are built.
    Stage2Ready {
        faces: usize,
        seconds: f64,
        init: &'a Path,
    },
    /// The training loop starts at iteration `from` over `poses` poses.
    Started {
        files: &'a RunFiles,
        config: &'a Stage1Config,
        poses: usize,
        from: u64,
    },
    /// One iteration done (see [`RunEvent::Step`]).
    Step {
        row: &'a super::train::LossRow,
        skipped: usize,
    },
}

/// How a training run ended, with the settings it ran with.
pub struct TrainOutcome {
    pub report: RunReport,
    pub config: Stage1Config,
}

/// The stage-1 poses of every sample face: cached ones from `dir`, the rest fitted (the rig
/// from `rig`, loaded when first needed) and cached.
fn stage1_poses(
    sample: &Sample,
    rig: &mut LazyRig<'_>,
    dir: &Path,
    settings: &PoseSettings,
    events: &mut dyn FnMut(TrainEvent<'_>) -> ControlFlow<()>,
) -> Result<Vec<FacePoses>, RunError> {
    std::fs::create_dir_all(dir).map_err(|source| RunError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut out = Vec::new();
    for (i, f) in sample.faces.iter().enumerate() {
        let path = dir.join(format!("{}.poses", f.name));
        let in_face = |source| RunError::Face {
            face: f.name.clone(),
            source: Box::new(source),
        };
        if let Some(p) = FacePoses::load_matching(&path, &f.model, settings).map_err(in_face)? {
            let _ = events(TrainEvent::PosesCached {
                face: &f.name,
                poses: p.poses.len(),
                path: &path,
            });
            out.push(p);
            continue;
        }
        let start = Instant::now();
        let fitted = {
            let progress = std::cell::RefCell::new(&mut *events);
            FacePoses::generate(
                rig.get()?,
                &f.model,
                f.style,
                i as u64,
                settings,
                &|done, total| {
                    let _ = (progress.borrow_mut())(TrainEvent::FittingPoses {
                        face: &f.name,
                        done,
                        total,
                    });
                },
            )
            .map_err(in_face)?
        };
        let _ = events(TrainEvent::PosesFitted {
            face: &f.name,
            poses: fitted.poses.len(),
            seconds: start.elapsed().as_secs_f64(),
            worst_skin_rms: fitted.poses.iter().map(|p| p.skin_rms).fold(0.0, f64::max),
            clamped: fitted.poses.iter().map(|p| p.clamped).sum(),
        });
        fitted.save(&path).map_err(in_face)?;
        out.push(fitted);
    }
    Ok(out)
}

/// The rig as the sample's faces need it (`Sample::rig_for`), loaded on first use.
struct LazyRig<'a> {
    load: &'a dyn Fn() -> Result<FaceRig, RigError>,
    sample: &'a Sample,
    rig: Option<FaceRig>,
}

impl LazyRig<'_> {
    fn get(&mut self) -> Result<&FaceRig, RunError> {
        if self.rig.is_none() {
            let rig = (self.load)()?;
            let rig = match self.sample.rig_for(&rig).map_err(Box::new)? {
                Cow::Owned(extended) => extended,
                Cow::Borrowed(_) => rig,
            };
            self.rig = Some(rig);
        }
        Ok(self.rig.as_ref().expect("loaded above"))
    }
}

/// Each sample face's warp (`warp_of`: its elements' or its vertices' canonical positions)
/// with its poses.
fn warped(
    sample: &Sample,
    frame: &CanonicalFrame,
    poses: Vec<FacePoses>,
    warp_of: impl Fn(
        &crate::model::FaceModel,
        Option<&crate::mapping::Mapping>,
        &CanonicalFrame,
    ) -> Result<FaceWarp, GenerativeError>,
) -> Result<Vec<(FaceWarp, FacePoses)>, RunError> {
    sample
        .faces
        .iter()
        .zip(poses)
        .map(|(f, p)| {
            let warp =
                warp_of(&f.model, f.mapping.as_ref(), frame).map_err(|source| RunError::Face {
                    face: f.name.clone(),
                    source: Box::new(source),
                })?;
            Ok((warp, p))
        })
        .collect()
}

/// The canonical frame of `sample`: its template face's.
pub fn canonical_frame(sample: &Sample) -> Result<CanonicalFrame, GenerativeError> {
    let canonical = sample
        .faces
        .iter()
        .find(|f| f.identity.is_none())
        .ok_or_else(|| {
            GenerativeError::Config("the sample has no template (canonical) face".into())
        })?;
    Ok(CanonicalFrame::of(&canonical.model))
}

/// Trains `options.stage` on `sample` (from `sample_dir`) in `options.out`: the stage-1 poses
/// (cached), the stage's data, then the resumable loop of [`run_training`]. `load_rig` is
/// called when the rig is needed (missing poses, stage 2's targets). `events` hears of each
/// step; breaking stops the run at a checkpoint.
pub fn train_sample(
    sample: &Sample,
    sample_dir: &Path,
    load_rig: &dyn Fn() -> Result<FaceRig, RigError>,
    options: &TrainOptions,
    events: &mut dyn FnMut(TrainEvent<'_>) -> ControlFlow<()>,
) -> Result<TrainOutcome, RunError> {
    let a = options;
    let frame = canonical_frame(sample)?;
    std::fs::create_dir_all(&a.out).map_err(|source| RunError::Io {
        path: a.out.clone(),
        source,
    })?;
    let settings = PoseSettings {
        combinations: a.combinations,
        ..PoseSettings::default()
    };
    let mut rig = LazyRig {
        load: load_rig,
        sample,
        rig: None,
    };
    let poses = stage1_poses(sample, &mut rig, &a.out.join("poses"), &settings, events)?;
    let stage2 = a.stage == Stage::Two;
    let defaults = if stage2 {
        stage2_defaults()
    } else {
        Stage1Config::default()
    };
    let config = Stage1Config {
        iterations: a.iterations.unwrap_or(defaults.iterations),
        learning_rate: a.learning_rate.unwrap_or(defaults.learning_rate),
        batch_poses: a.batch_poses,
        elements_per_pose: if stage2 { 0 } else { a.elements_per_pose },
        seed: a.seed,
        ..defaults
    };
    let checkpoint_every = a.checkpoint_every.unwrap_or(if stage2 { 5 } else { 500 });
    let pose_settings = serde_json::to_value(&settings)
        .map_err(|e| GenerativeError::Config(format!("pose settings: {e}")))?;
    let plan = |config: Stage1Config, files| RunPlan {
        out: &a.out,
        resume: a.resume,
        config,
        frame,
        files,
        checkpoint_every,
        pose_settings: pose_settings.clone(),
    };
    match a.stage {
        Stage::One => {
            let data = Stage1Data::new(warped(sample, &frame, poses, FaceWarp::new)?)?;
            run(
                &plan(config, &STAGE1_FILES),
                &data,
                data.pose_count(),
                None,
                events,
            )
        }
        Stage::Displacement => {
            let data = DisplacementData::new(warped(sample, &frame, poses, FaceWarp::vertices)?)?;
            run(
                &plan(config, &DISPLACEMENT_FILES),
                &data,
                data.pose_count(),
                None,
                events,
            )
        }
        Stage::Two => {
            let init = a
                .init
                .clone()
                .unwrap_or_else(|| sample_dir.join(SAMPLE_NETWORKS));
            let nets = GenerativeNets::load(&init).map_err(|source| RunError::Init {
                path: init.clone(),
                source: Box::new(source),
            })?;
            if nets.frame != frame {
                return Err(RunError::Init {
                    path: init,
                    source: Box::new(GenerativeError::Config(
                        "trained for another canonical frame than this sample's".into(),
                    )),
                });
            }
            let config = Stage1Config {
                architecture: nets.architecture,
                ..config
            };
            let solve = crate::sim::SolveSettings {
                contact: a.contact,
                ..Stage2Settings::default().solve
            };
            let start = Instant::now();
            let rig = rig.get()?;
            let faces = sample
                .faces
                .iter()
                .zip(&poses)
                .map(|(f, p)| {
                    Stage2Face::from_sample(rig, &f.model, f.mapping.as_ref(), &frame, p, a.contact)
                        .map_err(|source| RunError::Face {
                            face: f.name.clone(),
                            source: Box::new(source),
                        })
                })
                .collect::<Result<Vec<_>, _>>()?;
            let data = Stage2Data::new(
                faces,
                Stage2Settings {
                    solve,
                    ..Stage2Settings::default()
                },
            )?;
            let _ = events(TrainEvent::Stage2Ready {
                faces: data.faces.len(),
                seconds: start.elapsed().as_secs_f64(),
                init: &init,
            });
            run(
                &plan(config, &STAGE2_FILES),
                &data,
                data.pose_count(),
                Some(nets),
                events,
            )
        }
    }
}

/// [`run_training`] with its events told as [`TrainEvent`]s.
fn run<D: TrainingData>(
    plan: &RunPlan<'_>,
    data: &D,
    poses: usize,
    init: Option<D::Nets>,
    events: &mut dyn FnMut(TrainEvent<'_>) -> ControlFlow<()>,
) -> Result<TrainOutcome, RunError> {
    let report = run_training(plan, data, poses, init, &mut |event| match event {
        RunEvent::Started { from } => events(TrainEvent::Started {
            files: plan.files,
            config: &plan.config,
            poses,
            from,
        }),
        RunEvent::Step { row, skipped } => events(TrainEvent::Step { row, skipped }),
    })?;
    Ok(TrainOutcome {
        report,
        config: plan.config,
    })
}

/// What [`evaluate_sample`] evaluates.
#[derive(Clone, Debug)]
pub struct EvalOptions {
    /// The trained expression/style networks.
    pub networks: PathBuf,
    /// A trained displacement baseline to pose the same codes with.
    pub displacement: Option<PathBuf>,
    /// Solve the physics models with lip and teeth contact.
    pub contact: bool,
    /// Also each identity B in the next identity A's style (networks, A's basis carried to
    /// B, B's own basis, the baseline).
    pub transfer: bool,
    /// Held-out expression codes.
    pub codes: Vec<ExpressionCode>,
    /// Where `eval.{csv,md,json}` (and `transfer.{md,json}`) go.
    pub out: PathBuf,
}

/// What [`evaluate_sample`] measured; its Markdown is also in the written files.
pub struct SampleEval {
    pub report: EvalReport,
    pub markdown: String,
    pub transfer: Option<(EvalReport, String)>,
}

/// Evaluates the networks (and the basis, and the baseline) on every sample face's held-out
/// codes against the rig's targets, and with `transfer` the style transfer between
/// identities; writes the reports to `options.out`.
pub fn evaluate_sample(
    sample: &Sample,
    rig: &FaceRig,
    options: &EvalOptions,
    progress: &dyn Fn(&str),
) -> Result<SampleEval, RunError> {
    let rig = &*sample.rig_for(rig).map_err(Box::new)?;
    let nets =
        Arc::new(
            GenerativeNets::load(&options.networks).map_err(|source| RunError::Init {
                path: options.networks.clone(),
                source: Box::new(source),
            })?,
        );
    let in_face = |name: &str| {
        let face = name.to_string();
        move |source| RunError::Face {
            face,
            source: Box::new(source),
        }
    };
    let generative: Vec<GenerativeFace> = sample
        .faces
        .iter()
        .map(|f| {
            GenerativeFace::new(nets.clone(), &f.model, f.mapping.as_ref())
                .map_err(in_face(&f.name))
        })
        .collect::<Result<_, _>>()?;
    let displacement: Option<Vec<DisplacementFace>> = match &options.displacement {
        None => None,
        Some(path) => {
            let nets = Arc::new(
                DisplacementNets::load(path).map_err(|source| RunError::Init {
                    path: path.clone(),
                    source: Box::new(source),
                })?,
            );
            Some(
                sample
                    .faces
                    .iter()
                    .map(|f| {
                        DisplacementFace::new(nets.clone(), &f.model, f.mapping.as_ref())
                            .map_err(in_face(&f.name))
                    })
                    .collect::<Result<_, _>>()?,
            )
        }
    };
    let faces: Vec<EvalFace<'_>> = sample
        .faces
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let mut models = vec![
                (
                    "networks",
                    EvalModel::Physics(&generative[i] as &dyn ActuationModel),
                ),
                ("basis", EvalModel::Physics(f.actuation.as_ref())),
            ];
            if let Some(d) = &displacement {
                models.push(("displacement", EvalModel::Displacement(&d[i])));
            }
            EvalFace {
                face: &f.model,
                style: f.style,
                own_style: None,
                models,
            }
        })
        .collect();
    let report = evaluate(rig, &faces, &options.codes, options.contact, progress)?;
    let out = &options.out;
    std::fs::create_dir_all(out).map_err(|source| RunError::Io {
        path: out.clone(),
        source,
    })?;
    write_atomic(&out.join("eval.csv"), report.csv().as_bytes())?;
    let markdown = format!(
        "All posed codes:\n\n{}\nOnly the codes every model of the face posed:\n\n{}\n{}",
        report.table(),
        report.common_table(),
        report.target_table()
    );
    write_atomic(&out.join("eval.md"), markdown.as_bytes())?;
    write_atomic(&out.join("eval.json"), &json(&report)?)?;
    let transfer = if options.transfer {
        let t = evaluate_transfer(
            sample,
            rig,
            &generative,
            displacement.as_deref(),
            options,
            progress,
        )?;
        Some(t)
    } else {
        None
    };
    Ok(SampleEval {
        report,
        markdown,
        transfer,
    })
}

fn json(value: &impl serde::Serialize) -> Result<Vec<u8>, RunError> {
    serde_json::to_vec_pretty(value)
        .map_err(|e| RunError::Train(GenerativeError::Config(format!("JSON: {e}"))))
}

/// Each identity B in the next identity A's style: the networks, A's basis carried to B by
/// nearest element, B's own basis and the baseline, against the rig's B in A's style.
fn evaluate_transfer(
    sample: &Sample,
    rig: &FaceRig,
    generative: &[GenerativeFace],
    displacement: Option<&[DisplacementFace]>,
    options: &EvalOptions,
    progress: &dyn Fn(&str),
) -> Result<(EvalReport, String), RunError> {
    let ids: Vec<usize> = (0..sample.faces.len())
        .filter(|&i| sample.faces[i].identity.is_some())
        .collect();
    if ids.len() < 2 {
        return Err(GenerativeError::Config(
            "style transfer needs two identities in the sample".into(),
        )
        .into());
    }
    let source_of = |k: usize| ids[(k + 1) % ids.len()];
    let transfers: Vec<NearestElementTransfer> = ids
        .iter()
        .enumerate()
        .map(|(k, &b)| {
            let a = &sample.faces[source_of(k)];
            NearestElementTransfer::new(a.actuation.clone(), &a.model, &sample.faces[b].model)
                .map_err(|source| RunError::Face {
                    face: format!("{} carried to {}", a.name, sample.faces[b].name),
                    source: Box::new(source.into()),
                })
        })
        .collect::<Result<_, _>>()?;
    let names: Vec<String> = (0..ids.len())
        .map(|k| format!("{} basis on B", sample.faces[source_of(k)].name))
        .collect();
    let faces: Vec<EvalFace<'_>> = ids
        .iter()
        .enumerate()
        .map(|(k, &b)| {
            let f = &sample.faces[b];
            let mut models = vec![
                (
                    "networks",
                    EvalModel::Physics(&generative[b] as &dyn ActuationModel),
                ),
                (
                    names[k].as_str(),
                    EvalModel::Physics(&transfers[k] as &dyn ActuationModel),
                ),
                ("B's own basis", EvalModel::Physics(f.actuation.as_ref())),
            ];
            if let Some(d) = displacement {
                models.push(("displacement", EvalModel::Displacement(&d[b])));
            }
            EvalFace {
                face: &f.model,
                style: sample.faces[source_of(k)].style,
                own_style: Some(f.style),
                models,
            }
        })
        .collect();
    let t = evaluate(rig, &faces, &options.codes, options.contact, &|m| {
        progress(&format!("transfer: {m}"))
    })?;
    let markdown = format!(
        "Style transfer (face B in the next identity's style A):\n\n{}\nOnly the codes every model posed:\n\n{}\nB's geometry and A's style kept apart (each code also posed in B's own style):\n\n{}",
        t.table(),
        t.common_table(),
        t.style_table()
    );
    write_atomic(&options.out.join("transfer.md"), markdown.as_bytes())?;
    write_atomic(&options.out.join("transfer.json"), &json(&t)?)?;
    Ok((t, markdown))
}
