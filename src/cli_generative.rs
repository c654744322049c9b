//! `facesim train`, `facesim eval` and `facesim bench nets`: the command-line side of
//! `facesim::generative` (data cache, progress bar, loss curve, checkpoints, tables).

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use facesim::drive::ActuationModel;
use facesim::generative::data::FacePoses;
use facesim::generative::eval::{EvalFace, EvalModel};
use facesim::generative::face::FaceWarp;
use facesim::generative::run::{
    self, DISPLACEMENT_FILES, RunError, RunEvent, RunPlan, STAGE1_FILES, STAGE2_FILES, write_atomic,
};
use facesim::generative::transfer::NearestElementTransfer;
use facesim::generative::{
    CanonicalFrame, DisplacementData, DisplacementFace, DisplacementNets, GenerativeFace,
    GenerativeNets, NetworkSet, PoseSettings, Stage1Config, Stage1Data, Stage2Data, Stage2Face,
    Stage2Settings, TrainingData, held_out_codes,
};
use facesim::rig::FaceRig;
use facesim::sample::Sample;
use facesim::stats::median;
use facesim::table::Table;

/// What `facesim train` trains.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Stage {
    /// Stage 1: fit the expression/style networks to the stage-1 actuations and jaw motions.
    #[value(name = "1")]
    One,
    /// Stage 2: fine-tune the networks of `--init` through the simulator (surface loss
    /// against the rig's skin, sensitivities by implicit differentiation).
    #[value(name = "2")]
    Two,
    /// The displacement baseline: fit N_D to the same poses' vertex displacements.
    Displacement,
}

#[derive(clap::Args)]
pub struct TrainArgs {
    /// What to train: `1` (stage 1 of the expression/style networks → generative.nn), `2`
    /// (stage 2: fine-tune `--init` through the simulator → generative-stage2.nn) or
    /// `displacement` (the no-physics baseline → displacement.nn).
    #[arg(long)]
    stage: Stage,
    /// The sample folder (faces, mappings).
    #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
    sample: PathBuf,
    /// The rig (needed to make missing stage-1 data, and by stage 2 for its targets).
    #[arg(long, default_value = facesim::rig::DEFAULT_RIG_DIR)]
    rig: PathBuf,
    /// Output folder: generative.nn, checkpoint.nn, loss.csv, train.json, poses/ (stage 2:
    /// generative-stage2.nn, stage2-checkpoint.nn, stage2-loss.csv, stage2-train.json; the
    /// displacement stage: displacement.nn, displacement-checkpoint.nn, displacement-loss.csv,
    /// displacement-train.json; the same poses/ cache).
    #[arg(long)]
    out: PathBuf,
    /// Stage 2: the networks to fine-tune (default: the sample's generative.nn).
    #[arg(long)]
    init: Option<PathBuf>,
    /// Stage 2: solve with lip and teeth contact (through the contact gate; much slower).
    #[arg(long)]
    contact: bool,
    #[arg(long, default_value_t = Stage1Config::default().seed)]
    seed: u64,
    /// Iterations (default: 6000; stage 2: 800).
    #[arg(long)]
    iterations: Option<u64>,
    /// Peak learning rate, constant for the first half, then linear decay to 0 (default:
    /// 1e-3; stage 2: 1e-4).
    #[arg(long)]
    lr: Option<f64>,
    /// Poses per batch.
    #[arg(long, default_value_t = Stage1Config::default().batch_poses)]
    batch: usize,
    /// Elements sampled per pose (0: all; stage 2 always uses all).
    #[arg(long, default_value_t = Stage1Config::default().elements_per_pose)]
    elements_per_pose: usize,
    /// Write the checkpoint every this many iterations, and at the end (default: 500;
    /// stage 2: 5).
    #[arg(long)]
    checkpoint_every: Option<u64>,
    /// Continue from the checkpoint in OUT (same settings) instead of starting over.
    #[arg(long)]
    resume: bool,
    /// Random combinations per face in the stage-1 data.
    #[arg(long, default_value_t = PoseSettings::default().combinations)]
    combinations: usize,
}

#[derive(clap::Args)]
pub struct EvalArgs {
    #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
    sample: PathBuf,
    #[arg(long, default_value = facesim::rig::DEFAULT_RIG_DIR)]
    rig: PathBuf,
    /// The trained networks (generative.nn).
    #[arg(long)]
    model: PathBuf,
    /// A trained displacement baseline (displacement.nn) to evaluate on the same poses.
    #[arg(long)]
    displacement: Option<PathBuf>,
    /// Solve the physics models with lip and teeth contact (tens of times slower).
    #[arg(long)]
    contact: bool,
    /// Also evaluate style transfer: each identity B driven in the next identity A's style
    /// (networks, A's actuation basis carried to B by nearest element, B's own basis, and
    /// the baseline) against the rig's target of B in A's style; writes transfer.md/.json.
    #[arg(long)]
    transfer: bool,
    /// Where to write eval.csv, eval.json and eval.md.
    #[arg(long)]
    out: PathBuf,
    /// Held-out expression codes per face.
    #[arg(long, default_value_t = 8)]
    held_out: usize,
    /// Seed of the held-out codes.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(clap::Args)]
pub struct BenchArgs {
    #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
    sample: PathBuf,
    /// Trained networks; without it, untrained networks of the default architecture (the
    /// cost is the same).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Timing samples per measurement.
    #[arg(long, default_value_t = 30)]
    samples: usize,
}

fn sample(dir: &Path) -> Result<Sample> {
    Sample::load(dir).with_context(|| format!("loading the sample in {}", dir.display()))
}

fn canonical_frame(sample: &Sample) -> Result<CanonicalFrame> {
    let canonical = sample
        .faces
        .iter()
        .find(|f| f.identity.is_none())
        .context("the sample has no template (canonical) face")?;
    Ok(CanonicalFrame::of(&canonical.model))
}

/// The stage-1 poses of every sample face: cached ones, the rest fitted (and cached); `rig`
/// is loaded from `rig_dir` when first needed (and kept for the caller).
fn stage1_poses(
    sample: &Sample,
    rig_dir: &Path,
    rig: &mut Option<FaceRig>,
    dir: &Path,
    settings: &PoseSettings,
) -> Result<Vec<FacePoses>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut out = Vec::new();
    for (i, f) in sample.faces.iter().enumerate() {
        let path = dir.join(format!("{}.poses", f.name));
        if let Some(p) = FacePoses::load_matching(&path, &f.model, settings)
            .with_context(|| format!("reading {}", path.display()))?
        {
            eprintln!(
                "{}: {} cached poses ({})",
                f.name,
                p.poses.len(),
                path.display()
            );
            out.push(p);
            continue;
        }
        if rig.is_none() {
            *rig = Some(crate::load_rig(rig_dir)?);
        }
        let bar = indicatif::ProgressBar::new(0);
        bar.set_style(indicatif::ProgressStyle::with_template(
            "{msg:>24} [{bar:30}] {pos}/{len} {elapsed_precise}",
        )?);
        bar.set_message(format!("fitting {}", f.name));
        let start = Instant::now();
        let p = FacePoses::generate(
            rig.as_ref().expect("loaded"),
            &f.model,
            f.style,
            i as u64,
            settings,
            &|done, total| {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            },
        )
        .with_context(|| format!("making the stage-1 data of {}", f.name))?;
        bar.finish_and_clear();
        let clamped: usize = p.poses.iter().map(|p| p.clamped).sum();
        let worst = p.poses.iter().map(|p| p.skin_rms).fold(0.0, f64::max);
        eprintln!(
            "{}: fitted {} poses in {:.1} s (worst skin RMS {:.3} mm, {clamped} clamped elements)",
            f.name,
            p.poses.len(),
            start.elapsed().as_secs_f64(),
            10.0 * worst
        );
        p.save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        out.push(p);
    }
    Ok(out)
}

/// Each sample face's warp (`warp_of`: its elements' or its vertices' canonical positions)
/// with its poses.
fn warped(
    sample: &Sample,
    frame: &CanonicalFrame,
    poses: Vec<FacePoses>,
    warp_of: impl Fn(
        &facesim::model::FaceModel,
        Option<&facesim::mapping::Mapping>,
        &CanonicalFrame,
    ) -> Result<FaceWarp, facesim::generative::GenerativeError>,
) -> Result<Vec<(FaceWarp, FacePoses)>> {
    sample
        .faces
        .iter()
        .zip(poses)
        .map(|(f, p)| {
            let warp = warp_of(&f.model, f.mapping.as_ref(), frame)
                .with_context(|| format!("canonical positions of {}", f.name))?;
            Ok((warp, p))
        })
        .collect()
}

pub fn train(a: &TrainArgs) -> Result<()> {
    let sample = sample(&a.sample)?;
    let frame = canonical_frame(&sample)?;
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let settings = PoseSettings {
        combinations: a.combinations,
        ..PoseSettings::default()
    };
    let mut rig = None;
    let poses = stage1_poses(&sample, &a.rig, &mut rig, &a.out.join("poses"), &settings)?;
    let stage2 = a.stage == Stage::Two;
    let defaults = if stage2 {
        stage2_defaults()
    } else {
        Stage1Config::default()
    };
    let config = Stage1Config {
        iterations: a.iterations.unwrap_or(defaults.iterations),
        learning_rate: a.lr.unwrap_or(defaults.learning_rate),
        batch_poses: a.batch,
        elements_per_pose: if stage2 { 0 } else { a.elements_per_pose },
        seed: a.seed,
        ..defaults
    };
    let checkpoint_every = a.checkpoint_every.unwrap_or(if stage2 { 5 } else { 500 });
    let pose_settings = serde_json::to_value(&settings)?;
    let run = |config: Stage1Config, files| RunPlan {
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
            let data = Stage1Data::new(warped(&sample, &frame, poses, FaceWarp::new)?)?;
            run_training(&run(config, &STAGE1_FILES), &data, data.pose_count(), None)
        }
        Stage::Displacement => {
            let data = DisplacementData::new(warped(&sample, &frame, poses, FaceWarp::vertices)?)?;
            run_training(
                &run(config, &DISPLACEMENT_FILES),
                &data,
                data.pose_count(),
                None,
            )
        }
        Stage::Two => {
            let init = a
                .init
                .clone()
                .unwrap_or_else(|| a.sample.join(facesim::generative::SAMPLE_NETWORKS));
            let nets = GenerativeNets::load(&init).with_context(|| {
                format!("loading the networks to fine-tune, {}", init.display())
            })?;
            anyhow::ensure!(
                nets.frame == frame,
                "{} was trained for another canonical frame than this sample's",
                init.display()
            );
            let config = Stage1Config {
                architecture: nets.architecture,
                ..config
            };
            let rig = match rig {
                Some(r) => r,
                None => crate::load_rig(&a.rig)?,
            };
            let stage2 = Stage2Settings {
                solve: facesim::sim::SolveSettings {
                    contact: a.contact,
                    ..Stage2Settings::default().solve
                },
                ..Stage2Settings::default()
            };
            let start = Instant::now();
            let faces = sample
                .faces
                .iter()
                .zip(&poses)
                .map(|(f, p)| {
                    Stage2Face::from_sample(
                        &rig,
                        &f.model,
                        f.mapping.as_ref(),
                        &frame,
                        p,
                        a.contact,
                    )
                    .with_context(|| format!("stage-2 data of {}", f.name))
                })
                .collect::<Result<Vec<_>>>()?;
            let data = Stage2Data::new(faces, stage2)?;
            eprintln!(
                "stage 2: targets and simulators of {} faces in {:.1} s; contact {}, init {}",
                data.faces.len(),
                start.elapsed().as_secs_f64(),
                if a.contact { "on" } else { "off" },
                init.display()
            );
            run_training(
                &run(config, &STAGE2_FILES),
                &data,
                data.pose_count(),
                Some(nets),
            )
        }
    }
}

/// Stage 2's defaults where they differ from stage 1's: every element, a learning rate a
/// tenth of stage 1's (the networks start trained: Adam's first steps move every weight by
/// about the learning rate, and stage 1's 1e-3 would undo much of stage 1 before the
/// moments settle), and iterations that fit the 60-minute budget on this machine.
fn stage2_defaults() -> Stage1Config {
    Stage1Config {
        iterations: 800,
        learning_rate: 1e-4,
        elements_per_pose: 0,
        ..Stage1Config::default()
    }
}

/// Runs `data`'s training as `plan` says, with a progress bar, and prints how it went.
fn run_training<D: TrainingData>(
    plan: &RunPlan<'_>,
    data: &D,
    pose_count: usize,
    init: Option<D::Nets>,
) -> Result<()> {
    let (config, files) = (plan.config, plan.files);
    let bar = indicatif::ProgressBar::new(config.iterations);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "[{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {msg}",
        )?
        .progress_chars("=> "),
    );
    let report = run::run_training(plan, data, pose_count, init, &mut |event| match event {
        RunEvent::Started { from } => {
            eprintln!(
                "{}: {pose_count} poses, {} iterations from {from}, batch {} × {} {}, seed {}",
                files.label,
                config.iterations,
                config.batch_poses,
                config.elements_per_pose,
                files.rows,
                config.seed
            );
            bar.set_position(from);
            ControlFlow::Continue(())
        }
        RunEvent::Step { row, skipped } => {
            if row.iteration % 10 == 0 || config.elements_per_pose == 0 {
                bar.set_message(format!(
                    "fit {:.4} jaw {:.4} cm² total {:.4}, {skipped} poses skipped",
                    row.parts.fit, row.parts.jaw, row.parts.total
                ));
            }
            bar.inc(1);
            ControlFlow::Continue(())
        }
    });
    bar.finish_and_clear();
    let report = report.map_err(|e| match e {
        RunError::Exists(path) => anyhow::anyhow!(
            "{} exists: pass --resume to continue that run, or remove it",
            path.display()
        ),
        e => e.into(),
    })?;
    let ms = report.median_ms_per_iteration;
    println!(
        "trained {} iterations in {:.1} s (median {ms:.1} ms per iteration; {} iterations would take {:.1} min); wrote {}",
        report.iterations_run,
        report.seconds,
        config.iterations,
        ms * config.iterations as f64 / 60e3,
        report.model.display()
    );
    if let Some(r) = report.last {
        println!(
            "last batch: fit {:.5}, jaw {:.5} cm², act {:.4}, Π softplus(c) {:.3}, total {:.5}; {} poses skipped in all",
            r.parts.fit, r.parts.jaw, r.parts.act, r.parts.lip, r.parts.total, report.skipped
        );
    }
    Ok(())
}

pub fn eval(a: &EvalArgs) -> Result<()> {
    let sample = sample(&a.sample)?;
    let nets = Arc::new(
        GenerativeNets::load(&a.model).with_context(|| format!("loading {}", a.model.display()))?,
    );
    let rig = crate::load_rig(&a.rig)?;
    let generative: Vec<GenerativeFace> = sample
        .faces
        .iter()
        .map(|f| {
            GenerativeFace::new(nets.clone(), &f.model, f.mapping.as_ref())
                .with_context(|| format!("binding the networks to {}", f.name))
        })
        .collect::<Result<_>>()?;
    let displacement: Option<Vec<DisplacementFace>> = match &a.displacement {
        None => None,
        Some(path) => {
            let nets = Arc::new(
                DisplacementNets::load(path)
                    .with_context(|| format!("loading {}", path.display()))?,
            );
            Some(
                sample
                    .faces
                    .iter()
                    .map(|f| {
                        DisplacementFace::new(nets.clone(), &f.model, f.mapping.as_ref())
                            .with_context(|| format!("binding the baseline to {}", f.name))
                    })
                    .collect::<Result<_>>()?,
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
    let codes = held_out_codes(a.held_out, a.seed);
    let bar = crate::spinner();
    let report = facesim::generative::evaluate(&rig, &faces, &codes, a.contact, &|m| {
        bar.set_message(m.to_string())
    })?;
    bar.finish_and_clear();
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    write_atomic(&a.out.join("eval.csv"), report.csv().as_bytes())?;
    let md = format!(
        "All posed codes:\n\n{}\nOnly the codes every model of the face posed:\n\n{}\n{}",
        report.table(),
        report.common_table(),
        report.target_table()
    );
    write_atomic(&a.out.join("eval.md"), md.as_bytes())?;
    write_atomic(
        &a.out.join("eval.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    print!("{md}");
    if a.transfer {
        let ids: Vec<usize> = (0..sample.faces.len())
            .filter(|&i| sample.faces[i].identity.is_some())
            .collect();
        anyhow::ensure!(
            ids.len() >= 2,
            "style transfer needs two identities in the sample"
        );
        let transfers: Vec<NearestElementTransfer> = ids
            .iter()
            .enumerate()
            .map(|(k, &b)| {
                let src = ids[(k + 1) % ids.len()];
                NearestElementTransfer::new(
                    sample.faces[src].actuation.clone(),
                    &sample.faces[src].model,
                    &sample.faces[b].model,
                )
                .with_context(|| {
                    format!(
                        "carrying {} to {}",
                        sample.faces[src].name, sample.faces[b].name
                    )
                })
            })
            .collect::<Result<_>>()?;
        let names: Vec<String> = ids
            .iter()
            .enumerate()
            .map(|(k, _)| format!("{} basis on B", sample.faces[ids[(k + 1) % ids.len()]].name))
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
                if let Some(d) = &displacement {
                    models.push(("displacement", EvalModel::Displacement(&d[b])));
                }
                EvalFace {
                    face: &f.model,
                    style: sample.faces[ids[(k + 1) % ids.len()]].style,
                    own_style: Some(f.style),
                    models,
                }
            })
            .collect();
        let bar = crate::spinner();
        let t = facesim::generative::evaluate(&rig, &faces, &codes, a.contact, &|m| {
            bar.set_message(format!("transfer: {m}"))
        })?;
        bar.finish_and_clear();
        let md = format!(
            "Style transfer (face B in the next identity's style A):\n\n{}\nOnly the codes every model posed:\n\n{}\nB's geometry and A's style kept apart (each code also posed in B's own style):\n\n{}",
            t.table(),
            t.common_table(),
            t.style_table()
        );
        write_atomic(&a.out.join("transfer.md"), md.as_bytes())?;
        write_atomic(
            &a.out.join("transfer.json"),
            serde_json::to_string_pretty(&t)?.as_bytes(),
        )?;
        print!("\n{md}");
    }
    for p in report.poses.iter().filter(|p| p.error.is_some()) {
        eprintln!(
            "{} / {} / code {}: {}",
            p.face,
            p.model,
            p.code,
            p.error.as_deref().unwrap_or("")
        );
    }
    Ok(())
}

pub fn bench(a: &BenchArgs) -> Result<()> {
    let sample = sample(&a.sample)?;
    let nets = Arc::new(match &a.model {
        Some(p) => GenerativeNets::load(p).with_context(|| format!("loading {}", p.display()))?,
        None => GenerativeNets::new(Default::default(), canonical_frame(&sample)?, 1)?,
    });
    let table = Table::new(
        &[
            "face",
            "elements",
            "N_A, cached first layer (median ms)",
            "N_A, no cache (median ms)",
            "actuate: codes → tensors + jaw (median ms)",
        ],
        "lrrrr",
    );
    print!("{}", table.head());
    let codes = facesim::drive::Codes {
        expression: facesim::rig::ExpressionCode::single("jawOpen", 0.6).expect("a code shape"),
        style: Default::default(),
    };
    for f in &sample.faces {
        let g = GenerativeFace::new(nets.clone(), &f.model, f.mapping.as_ref())?;
        let u = nets.modulation(std::slice::from_ref(&codes))?;
        let u: Vec<f64> = (0..u.ncols()).map(|k| u[(0, k)]).collect();
        let u32: Vec<f32> = u.iter().map(|&v| v as f32).collect();
        let mut tape = facesim::nn::Tape::new();
        let na32: facesim::nn::Mlp<f32> = nets.actuation.cast();
        let warp = FaceWarp::new(&f.model, f.mapping.as_ref(), &nets.frame)?;
        let x = warp.input::<f32>();
        let (mut cached, mut full, mut actuate) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..a.samples {
            let t = Instant::now();
            g.canonical_logs(&u, &mut tape)?;
            cached.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            na32.forward(
                x.as_ref(),
                Some(&facesim::nn::CodeBatch::shared(&u32)),
                facesim::nn::Pass::Value,
                &mut tape,
                faer::Par::Seq,
            )?;
            full.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            let act = g.actuate(&codes)?;
            actuate.push(t.elapsed().as_secs_f64() * 1e3);
            std::hint::black_box(act);
        }
        print!(
            "{}",
            table.line([
                f.name.clone(),
                g.element_count().to_string(),
                format!("{:.2}", median(&cached)),
                format!("{:.2}", median(&full)),
                format!("{:.2}", median(&actuate)),
            ])
        );
    }
    Ok(())
}
