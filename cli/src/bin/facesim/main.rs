//! The `facesim` command line: arguments and printing; what each command runs is in the
//! `facesim` library.

use std::path::PathBuf;

use anyhow::Result;
use clap::{Parser, Subcommand};

mod bench;
mod generative;
mod import;
mod mapping;

#[derive(Parser)]
#[command(
    name = "facesim",
    version,
    about = "Physics-based facial animation: an implicit physical face model"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build simulation-ready face models from a blendshape rig laid out like ICT-FaceKit.
    Import(import::ImportArgs),
    /// Build the bundled sample (template + a few identities, coarse, with fitted actuation
    /// bases); then train its mappings with `train-mapping --faces OUT`.
    Sample(import::SampleArgs),
    /// Add a new face to a sample from its neutral alone (an OBJ on the rig's topology):
    /// imported, its actuation basis fitted, its φ trained to the template, listed in the
    /// manifest; the editor, eval, export and serve then drive it.
    AddFace(import::AddFaceArgs),
    /// Train the mapping networks φ (identity → canonical face) of the faces in a folder.
    TrainMapping(mapping::TrainArgs),
    /// Mapping-function statistics (Fig. 3 heatmaps, CSVs, per-vertex values) and, with
    /// `--warp`, the warp-versus-naive comparison.
    Stats(mapping::StatsArgs),
    /// Simulate an animation track and write it as USD, PC2, an OBJ sequence or glTF (README,
    /// "Export"; `.rrd` from the editor binary: `cargo run --release -- export …`).
    Export {
        #[command(flatten)]
        args: facesim_cli::export::ExportArgs,
        /// The sample folder the faces come from.
        #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
        sample: PathBuf,
        /// Solver preset for every frame: interactive, preview or final (default: the
        /// track's, else final).
        #[arg(long)]
        quality: Option<facesim::sim::Quality>,
        /// What drives the face: its fitted basis, or the sample's networks through its φ.
        #[arg(long, value_enum, default_value_t)]
        actuation: facesim_cli::actuation::Actuation,
    },
    /// Train the expression/style networks (`--stage 1`: fit the per-pose actuations and jaw
    /// motions fitted to the rig's targets; `--stage 2`: fine-tune them through the simulator
    /// against the rig's skin) or the displacement baseline (`--stage displacement`: the same
    /// poses' vertex displacements); the data is made once and cached under OUT/poses.
    Train(generative::TrainArgs),
    /// Simulate held-out codes with trained networks and with the actuation basis (and pose
    /// them with a displacement baseline) and report the skin's vertex error against the rig's
    /// targets, volume change and lip crossings.
    Eval(generative::EvalArgs),
    /// Measure performance (results are medians of repeated runs).
    Bench {
        #[command(subcommand)]
        target: bench::BenchTarget,
    },
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Import(args) => import::import(&args),
        Command::Sample(args) => import::sample(&args),
        Command::AddFace(args) => import::add_face(&args),
        Command::TrainMapping(args) => mapping::train_mapping(&args),
        Command::Stats(args) => mapping::stats(&args),
        Command::Train(args) => generative::train(&args),
        Command::Eval(args) => generative::eval(&args),
        Command::Export {
            args,
            sample,
            quality,
            actuation,
        } => facesim_cli::export::run(&args, &sample, quality, actuation, None).map(drop),
        Command::Bench { target } => bench::run(target),
    }
}
