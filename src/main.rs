//! The `facesim` command line.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

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
    /// Measure performance (results are medians of repeated runs).
    Bench {
        #[command(subcommand)]
        target: BenchTarget,
    },
}

#[derive(Subcommand)]
enum BenchTarget {
    /// The quasistatic solver on generated slabs: factorization, iteration cost against its
    /// floor, time to tolerance from rest and warm-started.
    Solver {
        /// Element counts of the generated meshes.
        #[arg(long, value_delimiter = ',', default_values_t = [5_000, 20_000, 80_000])]
        elements: Vec<usize>,
        /// Timing samples per measurement.
        #[arg(long, default_value_t = 7)]
        samples: usize,
        /// Also write the results as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Bench {
            target:
                BenchTarget::Solver {
                    elements,
                    samples,
                    json,
                },
        } => {
            let mut rows = Vec::new();
            for n in elements {
                eprintln!("benchmarking the solver on a ~{n}-element slab…");
                rows.push(
                    facesim::bench::solver::bench_size(n, samples)
                        .with_context(|| format!("benchmark at {n} elements"))?,
                );
            }
            print!("{}", facesim::bench::solver::table(&rows));
            if let Some(path) = json {
                std::fs::write(&path, serde_json::to_string_pretty(&rows)?)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
        }
    }
    Ok(())
}
