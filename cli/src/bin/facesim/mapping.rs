//! `facesim train-mapping` and `facesim stats`: the command-line side of `facesim::mapping`
//! (arguments, progress bars and tables; `facesim::mapping::folder` runs them).

use std::path::PathBuf;

use anyhow::{Context, Result};
use facesim::mapping::TrainConfig;
use facesim::mapping::folder::{self, TrainEvent, WarpCheck};
use facesim_cli::progress;

#[derive(clap::Args)]
pub struct TrainArgs {
    /// Folder with the face models (`<name>.face`); the mappings and loss curves go beside them.
    #[arg(long, alias = "sample")]
    faces: PathBuf,
    /// The canonical face (file stem).
    #[arg(long, default_value = "neutral-coarse")]
    canonical: String,
    /// Faces to train (file stems); default: every other `.face` in the folder.
    #[arg(long, value_delimiter = ',')]
    identities: Vec<String>,
    #[command(flatten)]
    training: TrainingArgs,
}

/// φ's training settings, as `train-mapping` and `add-face` take them.
#[derive(clap::Args)]
pub struct TrainingArgs {
    #[arg(long, default_value_t = TrainConfig::default().iterations)]
    iterations: u64,
    /// Peak learning rate (constant for the first half, then linear decay to 0).
    #[arg(long, default_value_t = TrainConfig::default().learning_rate)]
    lr: f64,
    #[arg(long, default_value_t = TrainConfig::default().seed)]
    seed: u64,
    /// Width of the SIREN layers.
    #[arg(long, default_value_t = TrainConfig::default().architecture.width)]
    width: usize,
    /// Correspondences per iteration (0: all).
    #[arg(long, default_value_t = TrainConfig::default().surface_batch)]
    surface_batch: usize,
    /// Elastic points per iteration (0: all).
    #[arg(long, default_value_t = TrainConfig::default().elastic_batch)]
    elastic_batch: usize,
    /// λ_e.
    #[arg(long, default_value_t = TrainConfig::default().lambda_elastic)]
    lambda_elastic: f64,
}

impl TrainingArgs {
    pub fn config(&self) -> TrainConfig {
        let mut config = TrainConfig {
            iterations: self.iterations,
            learning_rate: self.lr,
            seed: self.seed,
            surface_batch: self.surface_batch,
            elastic_batch: self.elastic_batch,
            lambda_elastic: self.lambda_elastic,
            ..TrainConfig::default()
        };
        config.architecture.width = self.width;
        config
    }
}

#[derive(clap::Args)]
pub struct StatsArgs {
    /// Folder with the faces and their `.mapping` files.
    #[arg(long, alias = "sample")]
    faces: PathBuf,
    #[arg(long, default_value = "neutral-coarse")]
    canonical: String,
    /// Faces to measure (file stems); default: every face with a `.mapping` beside it.
    #[arg(long, value_delimiter = ',')]
    identities: Vec<String>,
    /// Where to write the PNG and CSVs.
    #[arg(long)]
    out: PathBuf,
    /// Seed of the random interior points.
    #[arg(long, default_value_t = 2)]
    seed: u64,
    /// Also compare the warp with the naive warp (simulates each face four times).
    #[arg(long)]
    warp: bool,
    /// Peak contraction of the canonical test field (1 − stretch at its centre).
    #[arg(long, default_value_t = 0.3)]
    warp_strength: f64,
    /// Rotation of the face copy in the equivariance check, degrees about the vertical axis.
    #[arg(long, default_value_t = 30.0)]
    warp_rotation: f64,
}

pub fn train_mapping(a: &TrainArgs) -> Result<()> {
    let config = a.training.config();
    let table = folder::trained_table();
    print!("{}", table.head());
    let bar = progress::bar(
        config.iterations,
        "{msg:>20} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {prefix}",
    );
    folder::train_folder(
        &a.faces,
        &a.canonical,
        &a.identities,
        &config,
        &mut |event| match event {
            TrainEvent::Started { face } => {
                bar.reset();
                bar.set_message(face.to_string());
            }
            TrainEvent::Iteration { row, .. } => {
                if row.iteration % 20 == 0 {
                    bar.set_prefix(format!(
                        "vertex {:.3} mm² elastic {:.4}",
                        row.vertex_mse_mm2, row.elastic
                    ));
                }
                bar.inc(1);
            }
            TrainEvent::Finished(trained) => {
                bar.finish_and_clear();
                print!("{}", folder::trained_line(&table, trained));
            }
        },
    )
    .with_context(|| format!("training the mappings in {}", a.faces.display()))?;
    Ok(())
}

pub fn stats(a: &StatsArgs) -> Result<()> {
    let warp = a.warp.then_some(WarpCheck {
        strength: a.warp_strength,
        rotation_deg: a.warp_rotation,
    });
    let bar = progress::spinner();
    let stats = folder::stats_folder(
        &a.faces,
        &a.canonical,
        &a.identities,
        &a.out,
        a.seed,
        warp,
        &|m| bar.set_message(m.to_string()),
    );
    bar.finish_and_clear();
    let stats =
        stats.with_context(|| format!("the mapping statistics of {}", a.faces.display()))?;
    print!("{}", folder::summary_table(&stats.summaries));
    if a.warp {
        println!();
        print!(
            "{}",
            folder::warp_table(&stats.comparisons, a.warp_rotation)
        );
    }
    eprintln!(
        "wrote {} and the CSVs to {}",
        stats.figure.display(),
        a.out.display()
    );
    Ok(())
}
