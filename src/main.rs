//! The `facesim` command line.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use facesim::table::Table;

mod cli_bench;
mod cli_generative;
mod cli_mapping;

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
    Import {
        /// The rig folder (neutral, expression and identity OBJs, vertex_indices.json).
        #[arg(long, default_value = facesim::rig::DEFAULT_RIG_DIR)]
        rig: PathBuf,
        /// Where to write the models (`<identity>-<lod>.face`).
        #[arg(long)]
        out: PathBuf,
        /// Identities to build: `neutral` (the template face), rig indices, or `all`.
        #[arg(long, value_delimiter = ',', default_values_t = ["all".to_string()])]
        identities: Vec<String>,
        /// Levels of detail.
        #[arg(long, value_delimiter = ',', default_values_t = [facesim::model::Lod::Coarse])]
        lod: Vec<facesim::model::Lod>,
    },
    /// Build the bundled sample (template + a few identities, coarse, with fitted actuation
    /// bases); then train its mappings with `train-mapping --faces OUT`.
    Sample {
        #[arg(long, default_value = facesim::rig::DEFAULT_RIG_DIR)]
        rig: PathBuf,
        #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
        out: PathBuf,
        /// Rig identities besides the template.
        #[arg(long, value_delimiter = ',', default_values_t = facesim::sample::SAMPLE_IDENTITIES)]
        identities: Vec<usize>,
    },
    /// Train the mapping networks φ (identity → canonical face) of the faces in a folder.
    TrainMapping(cli_mapping::TrainArgs),
    /// Mapping-function statistics (Fig. 3 heatmaps, CSVs, per-vertex values) and, with
    /// `--warp`, the warp-versus-naive comparison.
    Stats(cli_mapping::StatsArgs),
    /// Simulate an animation track and write it as USD, PC2, an OBJ sequence or glTF (README,
    /// "Export"; `.rrd` from the editor binary: `cargo run --release -- export …`).
    Export {
        #[command(flatten)]
        args: facesim::export::cli::ExportArgs,
        /// The sample folder the faces come from.
        #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
        sample: PathBuf,
        /// Solver preset for every frame: interactive, preview or final (default: the
        /// track's, else interactive).
        #[arg(long)]
        quality: Option<facesim::sim::Quality>,
    },
    /// Train the expression/style networks (`--stage 1`: fit the per-pose actuations and jaw
    /// motions fitted to the rig's targets; `--stage 2`: fine-tune them through the simulator
    /// against the rig's skin) or the displacement baseline (`--stage displacement`: the same
    /// poses' vertex displacements); the data is made once and cached under OUT/poses.
    Train(cli_generative::TrainArgs),
    /// Simulate held-out codes with trained networks and with the actuation basis (and pose
    /// them with a displacement baseline) and report the skin's vertex error against the rig's
    /// targets, volume change and lip crossings.
    Eval(cli_generative::EvalArgs),
    /// Measure performance (results are medians of repeated runs).
    Bench {
        #[command(subcommand)]
        target: BenchTarget,
    },
}

#[derive(Subcommand)]
enum BenchTarget {
    /// The expression/style networks' inference on the sample's faces: N_A over every
    /// element (cached first layer and not) and the whole codes → actuation step.
    Nets(cli_generative::BenchArgs),
    /// Editor latency on the sample: slider change → new frame available through the session,
    /// per quality preset (each drag step waits for its frame).
    Editor {
        #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
        sample: PathBuf,
        /// Sample faces to measure.
        #[arg(long, value_delimiter = ',', default_values_t = ["neutral".to_string()])]
        faces: Vec<String>,
        /// Sliders dragged 0 → 1 → 0, one after another.
        #[arg(long, value_delimiter = ',', default_values_t = ["jawOpen".to_string(), "mouthSmile_L".to_string(), "mouthPucker".to_string()])]
        sliders: Vec<String>,
        /// Steps per drag.
        #[arg(long, default_value_t = 20)]
        steps: usize,
        /// Also measure with lip and teeth contact on (the editor's checkbox).
        #[arg(long)]
        contact: bool,
        /// Quality presets to measure (default: all three).
        #[arg(long, value_delimiter = ',', default_values_t = facesim::sim::Quality::ALL)]
        presets: Vec<facesim::sim::Quality>,
    },
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
    /// The speed-for-accuracy trade: every mesh resolution × quality preset × contact
    /// setting on one performance, against a converged reference on the finest mesh
    /// (table, JSON and a PNG plot).
    Tradeoff(cli_bench::TradeoffArgs),
    /// Stability at the extremes: every slider 3× past its range, far styles, abrupt jumps
    /// and a long random walk, as the editor's session solves them.
    Extremes(cli_bench::ExtremesArgs),
    /// Fidelity as the artist sees it: every slider alone at weight 1 on every sample face,
    /// solved from rest, against the rig's own shape per render vertex (skin and lips, the
    /// mouth lining), with a crossing audit of the whole render surface.
    Shapes(cli_bench::ShapesArgs),
    /// Remote editing: bytes per frame and slider-to-frame latency of a drag through the
    /// remote protocol on loopback (JSON and binary geometry), beside the embedded session.
    Remote(cli_bench::RemoteArgs),
    /// Contact on a face: per-frame time with contact on and off at each quality preset,
    /// time in broad phase, barrier and CCD, low-rank update against refactoring.
    Contact {
        /// A face model file; without it the neutral coarse face is built from `--rig`.
        #[arg(long)]
        model: Option<PathBuf>,
        #[arg(long, default_value = facesim::rig::DEFAULT_RIG_DIR)]
        rig: PathBuf,
        /// Frames of the slider drag.
        #[arg(long, default_value_t = 12)]
        frames: usize,
        /// Also write the results as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Instead: solve this many seeded random expression codes (sliders in [-0.5, 1.5])
        /// on the bundled sample's neutral face, contact on, and report failures,
        /// intersections and the median frame time.
        #[arg(long)]
        sweep: Option<usize>,
        /// With `--sweep`: `contact` (on), `no-contact` (what the codes alone do) or `compare`
        /// (both from the same start each frame: which failures contact causes).
        #[arg(long, value_enum, default_value_t = SweepModeArg::Contact)]
        sweep_mode: SweepModeArg,
        /// With `--sweep`: the sliders' range, `LOW,HIGH`.
        #[arg(long, default_value = "-0.5,1.5")]
        sweep_range: SliderRange,
        /// With `--sweep`: the codes' seed (different seeds give independent sweeps, e.g. to
        /// split a long sweep over processes).
        #[arg(long, default_value_t = 1)]
        sweep_seed: u64,
    },
}

/// `--sweep-mode` (the library's `SweepMode`, named for the command line).
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum SweepModeArg {
    Contact,
    NoContact,
    Compare,
}

impl From<SweepModeArg> for facesim::bench::contact_sweep::SweepMode {
    fn from(mode: SweepModeArg) -> Self {
        match mode {
            SweepModeArg::Contact => Self::Contact,
            SweepModeArg::NoContact => Self::NoContact,
            SweepModeArg::Compare => Self::Compare,
        }
    }
}

/// `LOW,HIGH`: finite, LOW ≤ HIGH.
#[derive(Clone, Copy, Debug)]
struct SliderRange {
    low: f64,
    high: f64,
}

impl std::str::FromStr for SliderRange {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        s.split_once(',')
            .and_then(|(a, b)| Some((a.trim().parse::<f64>().ok()?, b.trim().parse::<f64>().ok()?)))
            .filter(|(a, b)| a.is_finite() && b.is_finite() && a <= b)
            .map(|(low, high)| SliderRange { low, high })
            .ok_or_else(|| format!("must be LOW,HIGH with LOW ≤ HIGH, got '{s}'"))
    }
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Import {
            rig,
            out,
            identities,
            lod,
        } => import(&rig, &out, &identities, &lod)?,
        Command::Sample {
            rig,
            out,
            identities,
        } => sample(&rig, &out, &identities)?,
        Command::TrainMapping(args) => cli_mapping::train_mapping(&args)?,
        Command::Train(args) => cli_generative::train(&args)?,
        Command::Eval(args) => cli_generative::eval(&args)?,
        Command::Bench {
            target: BenchTarget::Nets(args),
        } => cli_generative::bench(&args)?,
        Command::Stats(args) => cli_mapping::stats(&args)?,
        Command::Export {
            args,
            sample,
            quality,
        } => {
            facesim::export::cli::run(&args, &sample, quality, None)?;
        }
        Command::Bench {
            target:
                BenchTarget::Contact {
                    json,
                    sweep: Some(count),
                    sweep_mode,
                    sweep_range,
                    sweep_seed,
                    ..
                },
        } => {
            let SliderRange { low, high } = sweep_range;
            let mode = sweep_mode.into();
            let sample = facesim::sample::Sample::load(facesim::sample::SAMPLE_DIR)
                .context("loading the bundled sample (run from the repository root)")?;
            let face = sample
                .faces
                .iter()
                .find(|f| f.identity.is_none())
                .context("the sample has no neutral face")?;
            eprintln!(
                "sweeping {count} random codes (seed {sweep_seed}) in [{low}, {high}] on {} (interactive, {sweep_mode:?})…",
                face.name
            );
            let codes =
                facesim::bench::contact_sweep::random_codes_in(count, sweep_seed, low, high);
            let report = facesim::bench::contact_sweep::sweep(
                &face.model,
                face.actuation.as_ref(),
                &codes,
                facesim::sim::Quality::Interactive,
                mode,
                &mut |frame, r| {
                    let on = if r.contact { "contact" } else { "no contact" };
                    let why = r
                        .error
                        .as_deref()
                        .map(|e| format!(": {e}"))
                        .unwrap_or_default();
                    let rest = if r.from_rest { " (from rest)" } else { "" };
                    eprintln!(
                        "frame {frame} ({on}): {:?}{rest} in {:.2} s{why}",
                        r.outcome,
                        r.time.as_secs_f64()
                    );
                },
            )
            .context("contact sweep")?;
            print!("{}", report.summary());
            if let Some(path) = json {
                std::fs::write(&path, serde_json::to_string_pretty(&report)?)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
        }
        Command::Bench {
            target:
                BenchTarget::Contact {
                    model,
                    rig,
                    frames,
                    json,
                    sweep: None,
                    ..
                },
        } => {
            let face = match model {
                Some(path) => facesim::model::FaceModel::load(&path)
                    .with_context(|| format!("loading {}", path.display()))?,
                None => {
                    eprintln!("building the neutral coarse face from {}…", rig.display());
                    let rig = facesim::rig::FaceRig::load(&rig)
                        .with_context(|| format!("loading the rig from {}", rig.display()))?;
                    facesim::model::build_face(&rig, None, &facesim::model::Lod::Coarse.settings())
                        .context("building the neutral face")?
                }
            };
            eprintln!(
                "benchmarking contact on {} ({frames} frames per row)…",
                face.name
            );
            let rows =
                facesim::bench::contact::bench(&face, frames).context("contact benchmark")?;
            print!("{}", facesim::bench::contact::table(&rows));
            if let Some(path) = json {
                std::fs::write(&path, serde_json::to_string_pretty(&rows)?)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
        }
        Command::Bench {
            target: BenchTarget::Tradeoff(args),
        } => cli_bench::bench_tradeoff(&args)?,
        Command::Bench {
            target: BenchTarget::Extremes(args),
        } => cli_bench::bench_extremes(&args)?,
        Command::Bench {
            target: BenchTarget::Shapes(args),
        } => cli_bench::bench_shapes(&args)?,
        Command::Bench {
            target: BenchTarget::Remote(args),
        } => cli_bench::bench_remote(&args)?,
        Command::Bench {
            target:
                BenchTarget::Editor {
                    sample,
                    faces,
                    sliders,
                    steps,
                    contact,
                    presets,
                },
        } => bench_editor(&sample, &faces, &sliders, steps, contact, &presets)?,
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

/// `facesim bench editor`.
fn bench_editor(
    sample_dir: &std::path::Path,
    faces: &[String],
    sliders: &[String],
    steps: usize,
    contact: bool,
    presets: &[facesim::sim::Quality],
) -> Result<()> {
    cli_bench::check_sliders(sliders)?;
    let sample = facesim::sample::Sample::load(sample_dir)
        .with_context(|| format!("loading the sample from {}", sample_dir.display()))?;
    let sliders: Vec<&str> = sliders.iter().map(String::as_str).collect();
    let mut rows = Vec::new();
    for name in faces {
        let face = sample
            .session_faces()
            .into_iter()
            .find(|f| &f.name == name)
            .with_context(|| format!("the sample has no face '{name}'"))?;
        eprintln!("measuring {name}…");
        for contact in std::iter::once(false).chain(contact.then_some(true)) {
            rows.extend(facesim::bench::editor::bench_latency(
                face.clone(),
                presets,
                &sliders,
                steps,
                contact,
            )?);
        }
    }
    print!("{}", facesim::bench::editor::table(&rows));
    Ok(())
}

/// A spinner that shows the current step and the time spent.
fn spinner() -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new_spinner();
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
            .expect("valid template"),
    );
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    bar
}

/// Loads the rig, with a line of progress per file on a terminal and only the summary in a
/// log (no carriage returns or escape codes where stderr is not a terminal).
fn load_rig(rig_dir: &std::path::Path) -> Result<facesim::rig::FaceRig> {
    use std::io::IsTerminal;
    let terminal = std::io::stderr().is_terminal();
    eprintln!("loading the rig from {}…", rig_dir.display());
    let rig = facesim::rig::FaceRig::load_with_progress(rig_dir, &|p| {
        if terminal {
            eprint!("\r  {}/{} {}\x1b[K", p.done, p.total, p.file.display())
        }
    })
    .with_context(|| format!("loading the rig from {}", rig_dir.display()))?;
    let summary = format!(
        "  loaded {} shapes and {} identities in {:.2} s",
        rig.shape_names().len(),
        rig.identity_count(),
        rig.load_time().as_secs_f64()
    );
    if terminal {
        eprintln!("\r{summary}\x1b[K");
    } else {
        eprintln!("{summary}");
    }
    Ok(rig)
}

/// `facesim sample`: builds the bundled sample and prints how well each face's actuation
/// basis fits the rig.
fn sample(rig_dir: &std::path::Path, out: &std::path::Path, identities: &[usize]) -> Result<()> {
    use facesim::sample::{SAMPLE_LOD, write_sample};
    let rig = load_rig(rig_dir)?;
    let bar = spinner();
    let manifest = write_sample(&rig, out, identities, SAMPLE_LOD, &|m| {
        bar.set_message(m.to_string())
    })
    .with_context(|| format!("building the sample in {}", out.display()))?;
    bar.finish_and_clear();
    let table = Table::new(
        &[
            "face",
            "elements",
            "basis skin error (RMS / max, mm)",
            "jaw fit RMS (mm)",
            "clamped elements",
        ],
        "lrlrr",
    );
    print!("{}", table.head());
    for entry in &manifest.faces {
        let model = facesim::model::FaceModel::load(&out.join(&entry.face))?;
        let basis = facesim::drive::basis::ActuationBasis::load(&out.join(&entry.basis))?;
        let rms = basis.fits.iter().map(|f| f.skin_rms).fold(0.0, f64::max);
        let max = basis.fits.iter().map(|f| f.skin_max).fold(0.0, f64::max);
        let jaw = basis.fits.iter().map(|f| f.jaw_rms).fold(0.0, f64::max);
        let clamped: usize = basis.fits.iter().map(|f| f.clamped).sum();
        print!(
            "{}",
            table.line([
                entry.name.clone(),
                model.mesh.element_count().to_string(),
                format!("≤ {:.3} / {:.3}", 10.0 * rms, 10.0 * max),
                format!("≤ {:.3}", 10.0 * jaw),
                clamped.to_string(),
            ])
        );
    }
    eprintln!(
        "wrote {}; next: train its mappings with `train-mapping --faces {}`",
        out.display(),
        out.display()
    );
    Ok(())
}

/// `facesim import`: loads and validates the rig, builds each identity at each level of
/// detail, writes the models and prints what the importer did.
fn import(
    rig_dir: &std::path::Path,
    out: &std::path::Path,
    identities: &[String],
    lods: &[facesim::model::Lod],
) -> Result<()> {
    use facesim::model::build_face;
    let rig = load_rig(rig_dir)?;
    let mut chosen: Vec<Option<usize>> = Vec::new();
    for id in identities {
        match id.as_str() {
            "all" => {
                chosen.extend(std::iter::once(None).chain((0..rig.identity_count()).map(Some)))
            }
            "neutral" => chosen.push(None),
            n => {
                let i: usize = n
                    .parse()
                    .with_context(|| format!("identity '{n}' is not neutral, all or a number"))?;
                anyhow::ensure!(
                    i < rig.identity_count(),
                    "identity {i} is not in the rig ({} identities)",
                    rig.identity_count()
                );
                chosen.push(Some(i));
            }
        }
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let table = Table::new(
        &[
            "model",
            "elements",
            "vertices",
            "min dihedral",
            "min quality",
            "thickness (min/median/max cm)",
            "skull/jaw attached",
            "repaired (pairs → 0, vertices, max cm)",
            "seconds",
        ],
        "lrrrrlllr",
    );
    print!("{}", table.head());
    for lod in lods {
        for &identity in &chosen {
            let label = identity.map_or("neutral".to_string(), |i| format!("identity{i:03}"));
            let bar = spinner();
            bar.set_message(format!("building {label} at {} detail", lod.name()));
            let model = build_face(&rig, identity, &lod.settings())
                .with_context(|| format!("building {label}"))?;
            bar.finish_and_clear();
            let path = out.join(format!("{label}-{}.face", lod.name()));
            model.save(&path)?;
            let (q, r) = (&model.quality, &model.report);
            print!(
                "{}",
                table.line([
                    format!("{label}-{}", lod.name()),
                    q.elements.to_string(),
                    q.vertices.to_string(),
                    format!("{:.1}°", q.min_dihedral_deg),
                    format!("{:.3}", q.min_shape_quality),
                    format!(
                        "{:.2}/{:.2}/{:.2}",
                        r.thickness_min, r.thickness_median, r.thickness_max
                    ),
                    format!("{}/{}", r.skull_attached, r.jaw_attached),
                    format!(
                        "{} → {}, {}, {:.3}",
                        r.intersections_before_repair,
                        r.intersections_after_repair,
                        r.repaired_vertices,
                        r.max_repair_displacement
                    ),
                    format!("{:.1}", r.seconds),
                ])
            );
        }
    }
    Ok(())
}
