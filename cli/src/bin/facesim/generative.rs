//! `facesim train` and `facesim eval`: arguments, progress and the printed summaries of
//! `facesim::generative::pipeline`'s runs.

use std::ops::ControlFlow;
use std::path::PathBuf;

use anyhow::{Context, Result};
use facesim::generative::pipeline::{
    self, EvalOptions, TrainEvent, TrainOptions, evaluate_sample, train_sample,
};
use facesim::generative::run::RunError;
use facesim::generative::{PoseSettings, Stage1Config, held_out_codes};
use facesim::sample::Sample;
use facesim_cli::progress::{bar, load_rig, spinner};

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

impl From<Stage> for pipeline::Stage {
    fn from(stage: Stage) -> Self {
        match stage {
            Stage::One => Self::One,
            Stage::Two => Self::Two,
            Stage::Displacement => Self::Displacement,
        }
    }
}

fn sample(dir: &std::path::Path) -> Result<Sample> {
    Sample::load(dir).with_context(|| format!("loading the sample in {}", dir.display()))
}

pub fn train(a: &TrainArgs) -> Result<()> {
    let sample = sample(&a.sample)?;
    let options = TrainOptions {
        stage: a.stage.into(),
        out: a.out.clone(),
        init: a.init.clone(),
        contact: a.contact,
        seed: a.seed,
        iterations: a.iterations,
        learning_rate: a.lr,
        batch_poses: a.batch,
        elements_per_pose: a.elements_per_pose,
        checkpoint_every: a.checkpoint_every,
        resume: a.resume,
        combinations: a.combinations,
    };
    let load = || load_rig(&a.rig);
    let fitting = bar(0, "{msg:>24} [{bar:30}] {pos}/{len} {elapsed_precise}");
    let training = bar(
        0,
        "[{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {msg}",
    );
    let mut every_element = false;
    let outcome = train_sample(&sample, &a.sample, &load, &options, &mut |event| {
        match event {
            TrainEvent::PosesCached { face, poses, path } => {
                eprintln!("{face}: {poses} cached poses ({})", path.display())
            }
            TrainEvent::FittingPoses { face, done, total } => {
                fitting.set_message(format!("fitting {face}"));
                fitting.set_length(total as u64);
                fitting.set_position(done as u64);
            }
            TrainEvent::PosesFitted {
                face,
                poses,
                seconds,
                worst_skin_rms,
                clamped,
            } => {
                fitting.finish_and_clear();
                eprintln!(
                    "{face}: fitted {poses} poses in {seconds:.1} s (worst skin RMS {:.3} mm, {clamped} clamped elements)",
                    10.0 * worst_skin_rms
                );
            }
            TrainEvent::Stage2Ready {
                faces,
                seconds,
                init,
            } => eprintln!(
                "stage 2: targets and simulators of {faces} faces in {seconds:.1} s; contact {}, init {}",
                if a.contact { "on" } else { "off" },
                init.display()
            ),
            TrainEvent::Started {
                files,
                config,
                poses,
                from,
            } => {
                eprintln!(
                    "{}: {poses} poses, {} iterations from {from}, batch {} × {} {}, seed {}",
                    files.label,
                    config.iterations,
                    config.batch_poses,
                    config.elements_per_pose,
                    files.rows,
                    config.seed
                );
                every_element = config.elements_per_pose == 0;
                training.set_length(config.iterations);
                training.set_position(from);
            }
            TrainEvent::Step { row, skipped } => {
                if row.iteration % 10 == 0 || every_element {
                    training.set_message(format!(
                        "fit {:.4} jaw {:.4} cm² total {:.4}, {skipped} poses skipped",
                        row.parts.fit, row.parts.jaw, row.parts.total
                    ));
                }
                training.inc(1);
            }
        }
        ControlFlow::Continue(())
    });
    training.finish_and_clear();
    let outcome = outcome.map_err(|e| match e {
        RunError::Exists(path) => anyhow::anyhow!(
            "{} exists: pass --resume to continue that run, or remove it",
            path.display()
        ),
        e => e.into(),
    })?;
    let (report, config) = (outcome.report, outcome.config);
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
    let rig = load_rig(&a.rig)?;
    let options = EvalOptions {
        networks: a.model.clone(),
        displacement: a.displacement.clone(),
        contact: a.contact,
        transfer: a.transfer,
        codes: held_out_codes(a.held_out, a.seed),
        out: a.out.clone(),
    };
    let bar = spinner();
    let result = evaluate_sample(&sample, &rig, &options, &|m| bar.set_message(m.to_string()));
    bar.finish_and_clear();
    let result = result?;
    print!("{}", result.markdown);
    if let Some((_, markdown)) = &result.transfer {
        print!("\n{markdown}");
    }
    for p in result.report.poses.iter().filter(|p| p.error.is_some()) {
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
