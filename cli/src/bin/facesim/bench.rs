//! `facesim bench …`: each benchmark's arguments, its run in `facesim::bench`, its table.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result};
use clap::Subcommand;
use facesim::bench::tradeoff::{TradeoffFace, measure, plot, table};
use facesim::generative::{GenerativeNets, NetworkSet};
use facesim::model::Lod;
use facesim_cli::progress::{self, load_rig, spinner};

/// The benchmarks' progress bar.
const BAR: &str = "{msg} [{bar:30}] {pos}/{len} eta {eta}";

#[derive(Subcommand)]
pub enum BenchTarget {
    /// The expression/style networks' inference on the sample's faces: N_A over every
    /// element (cached first layer and not) and the whole codes → actuation step.
    Nets(NetsArgs),
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
    Tradeoff(TradeoffArgs),
    /// Stability at the extremes: every slider 3× past its range, far styles, abrupt jumps
    /// and a long random walk, as the editor's session solves them.
    Extremes(ExtremesArgs),
    /// Fidelity as the artist sees it: every slider alone at weight 1 on every sample face,
    /// solved from rest, against the rig's own shape per render vertex (skin and lips, the
    /// mouth lining), with a crossing audit of the whole render surface.
    Shapes(ShapesArgs),
    /// Remote editing: bytes per frame and slider-to-frame latency of a drag through the
    /// remote protocol on loopback (JSON and binary geometry), beside the embedded session.
    Remote(RemoteArgs),
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
pub enum SweepModeArg {
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
pub struct SliderRange {
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

#[derive(clap::Args)]
pub struct TradeoffArgs {
    /// Levels of detail, coarsest first; the last one also solves the reference.
    #[arg(long, value_delimiter = ',', default_values_t = [Lod::Coarse, Lod::Medium, Lod::Fine])]
    lods: Vec<Lod>,
    /// Frames of the performance.
    #[arg(long, default_value_t = 9)]
    frames: usize,
    /// The coarse face comes from the sample.
    #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
    sample: PathBuf,
    /// Finer faces are built from the rig once and kept here (`neutral-<lod>.face/.basis`).
    #[arg(long, default_value = "target/facesim-lods")]
    models: PathBuf,
    #[arg(long, default_value = facesim::rig::DEFAULT_RIG_DIR)]
    rig: PathBuf,
    /// Where to write `tradeoff.md`, `tradeoff.json` and `tradeoff.png`.
    #[arg(long, default_value = "tradeoff")]
    out: PathBuf,
    /// Solve nothing: redraw `tradeoff.md` and `tradeoff.png` in `--out` from this saved
    /// `tradeoff.json`.
    #[arg(long)]
    replot: Option<PathBuf>,
}

pub fn bench_tradeoff(args: &TradeoffArgs) -> Result<()> {
    if let Some(json) = &args.replot {
        let text =
            std::fs::read_to_string(json).with_context(|| format!("reading {}", json.display()))?;
        let rows: Vec<facesim::bench::tradeoff::TradeRow> = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a tradeoff.json", json.display()))?;
        return write_trade(&args.out, &rows, false);
    }
    anyhow::ensure!(args.frames >= 2, "--frames must be at least 2");
    anyhow::ensure!(!args.lods.is_empty(), "--lods is empty");
    let loaded = args
        .lods
        .iter()
        .map(|&lod| {
            let bar = spinner();
            let face = facesim::bench::tradeoff::neutral_face(
                lod,
                &args.sample,
                &args.models,
                &|| load_rig(&args.rig),
                &|m| bar.set_message(m.to_string()),
            );
            bar.finish_and_clear();
            face.with_context(|| format!("the neutral face at {}", lod.name()))
        })
        .collect::<Result<Vec<_>>>()?;
    let faces: Vec<TradeoffFace> = args
        .lods
        .iter()
        .zip(&loaded)
        .map(|(&lod, (model, basis))| TradeoffFace {
            lod,
            model,
            actuation: basis,
        })
        .collect();
    let bar = spinner();
    let (rows, reference) = measure(&faces, args.frames, &|m| bar.set_message(m.to_string()))
        .context("measuring the trade")?;
    bar.finish_and_clear();
    anyhow::ensure!(
        reference.errors.is_empty(),
        "the reference failed on {} frame(s): {:?}",
        reference.errors.len(),
        reference.errors
    );
    write_trade(&args.out, &rows, true)?;
    eprintln!(
        "wrote {} (reference: {} iterations in all)",
        args.out.display(),
        reference.iterations.iter().sum::<usize>()
    );
    Ok(())
}

/// Prints the trade table and writes it, its plot and (`json`) its rows to `out`.
fn write_trade(out: &Path, rows: &[facesim::bench::tradeoff::TradeRow], json: bool) -> Result<()> {
    let md = table(rows);
    print!("{md}");
    for r in rows.iter().filter(|r| !r.errors.is_empty()) {
        println!(
            "{} {} contact {}: {}",
            r.lod.name(),
            r.quality.name(),
            facesim::bench::tradeoff::contact_label(r.gate),
            r.errors.join("; ")
        );
    }
    write(out, "tradeoff.md", md.as_bytes())?;
    if json {
        write(
            out,
            "tradeoff.json",
            serde_json::to_string_pretty(rows)?.as_bytes(),
        )?;
    }
    let png = out.join("tradeoff.png");
    plot(rows)?
        .write_png(&png)
        .with_context(|| format!("writing {}", png.display()))
}

fn write(dir: &Path, name: &str, bytes: &[u8]) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = dir.join(name);
    std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))
}

#[derive(clap::Args)]
pub struct ExtremesArgs {
    #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
    sample: PathBuf,
    /// The sample face to drive.
    #[arg(long, default_value = "neutral")]
    face: String,
    /// Frames of the long random walk.
    #[arg(long, default_value_t = 10_000)]
    long: usize,
    #[arg(long, default_value_t = facesim::sim::Quality::Interactive)]
    quality: facesim::sim::Quality,
    /// Lip and teeth contact in the solve.
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    contact: bool,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Also write the reports as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn bench_extremes(args: &ExtremesArgs) -> Result<()> {
    use facesim::bench::extremes;
    let sample = facesim::sample::Sample::load(&args.sample)
        .with_context(|| format!("loading the sample from {}", args.sample.display()))?;
    let face = sample
        .face(&args.face)
        .with_context(|| format!("the sample has no face '{}'", args.face))?;
    let settings = facesim::sim::SolveSettings {
        contact: args.contact,
        ..args.quality.settings()
    };
    let bar = progress::bar(0, BAR);
    let reports = extremes::run(
        &face.model,
        face.actuation.as_ref(),
        &extremes::cases(args.long, args.seed),
        &settings,
        &|name, done, total| {
            bar.set_message(name.to_string());
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        },
    )
    .context("the extreme sweep")?;
    bar.finish_and_clear();
    print!("{}", extremes::table(&reports));
    for r in &reports {
        for e in &r.examples {
            println!("{}: {e}", r.name);
        }
    }
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&reports)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    anyhow::ensure!(
        reports.iter().all(|r| r.non_finite == 0),
        "a frame had non-finite positions"
    );
    Ok(())
}

/// Contact settings a fidelity run measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ContactRuns {
    Off,
    On,
    Both,
}

#[derive(clap::Args)]
pub struct ShapesArgs {
    #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
    sample: PathBuf,
    #[arg(long, default_value = facesim::rig::DEFAULT_RIG_DIR)]
    rig: PathBuf,
    /// Sample faces to measure (default: all).
    #[arg(long, value_delimiter = ',')]
    faces: Vec<String>,
    /// Expression sliders to measure, each alone at weight 1 (default: all 19).
    #[arg(long, value_delimiter = ',')]
    shapes: Vec<String>,
    #[arg(long, default_value_t = facesim::sim::Quality::Final)]
    quality: facesim::sim::Quality,
    /// Lip and teeth contact in the solve.
    #[arg(long, value_enum, default_value_t = ContactRuns::Both)]
    contact: ContactRuns,
    /// Drive the faces with these networks (a `generative.nn` file) instead of the sample's
    /// actuation bases.
    #[arg(long)]
    networks: Option<PathBuf>,
    /// Also write the rows as JSON here.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(clap::Args)]
pub struct RemoteArgs {
    #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
    sample: PathBuf,
    /// The sample face to edit.
    #[arg(long, default_value = "neutral")]
    face: String,
    #[arg(long, default_value_t = facesim::sim::Quality::Interactive)]
    quality: facesim::sim::Quality,
    /// The slider dragged 0 → 1 → 0.
    #[arg(long, default_value = "jawOpen")]
    slider: String,
    /// Steps of the drag.
    #[arg(long, default_value_t = 20)]
    steps: usize,
}

pub fn bench_remote(args: &RemoteArgs) -> Result<()> {
    check_sliders(std::slice::from_ref(&args.slider))?;
    let sample = facesim::sample::Sample::load(&args.sample)
        .with_context(|| format!("loading the sample from {}", args.sample.display()))?;
    let face = sample
        .session_faces()
        .into_iter()
        .find(|f| f.name == args.face)
        .with_context(|| format!("the sample has no face '{}'", args.face))?;
    let rows = facesim::bench::remote::bench_remote(face, args.quality, &args.slider, args.steps)?;
    print!("{}", facesim::bench::remote::table(&rows));
    Ok(())
}

/// Refuses any name that is not one of the expression sliders.
pub fn check_sliders(names: &[String]) -> Result<()> {
    use facesim::rig::ExpressionCode;
    match names.iter().find(|s| ExpressionCode::index_of(s).is_none()) {
        Some(unknown) => anyhow::bail!(
            "unknown expression slider '{unknown}' (expected one of {})",
            ExpressionCode::NAMES.join(", ")
        ),
        None => Ok(()),
    }
}

pub fn bench_shapes(args: &ShapesArgs) -> Result<()> {
    use facesim::bench::shapes;
    check_sliders(&args.shapes)?;
    let mut codes = shapes::single_shapes();
    if !args.shapes.is_empty() {
        codes.retain(|(name, _)| args.shapes.contains(name));
    }
    let sample = facesim::sample::Sample::load(&args.sample)
        .with_context(|| format!("loading the sample from {}", args.sample.display()))?;
    let rig = facesim::rig::FaceRig::load(&args.rig)
        .with_context(|| format!("loading the rig from {}", args.rig.display()))?;
    let rig = sample.rig_for(&rig)?;
    if let Some(unknown) = args
        .faces
        .iter()
        .find(|name| !sample.faces.iter().any(|f| &f.name == *name))
    {
        anyhow::bail!("the sample has no face '{unknown}'");
    }
    let networks = match &args.networks {
        Some(path) => {
            use facesim::generative::train::NetworkSet;
            let nets = facesim::generative::nets::GenerativeNets::load(path)
                .with_context(|| format!("loading {}", path.display()))?;
            Some(facesim::generative::generative_face::sample_actuations(
                &sample,
                std::sync::Arc::new(nets),
            )?)
        }
        None => None,
    };
    let contacts: &[bool] = match args.contact {
        ContactRuns::Off => &[false],
        ContactRuns::On => &[true],
        ContactRuns::Both => &[false, true],
    };
    let mut rows = Vec::new();
    for (i, face) in sample.faces.iter().enumerate() {
        if !args.faces.is_empty() && !args.faces.contains(&face.name) {
            continue;
        }
        let actuation = networks
            .as_ref()
            .map_or(face.actuation.as_ref(), |n| n[i].as_ref());
        let measured = shapes::MeasuredFace {
            name: &face.name,
            model: &face.model,
            actuation,
            style: face.style,
        };
        for &contact in contacts {
            let settings = facesim::sim::SolveSettings {
                contact,
                ..args.quality.settings()
            };
            let lining = facesim::model::deep_lining::runs_at(args.quality, contact);
            let bar = progress::bar(0, BAR);
            bar.set_message(format!(
                "{} with contact {}",
                face.name,
                if contact { "on" } else { "off" }
            ));
            rows.extend(
                shapes::measure(
                    &rig,
                    &measured,
                    &codes,
                    &settings,
                    lining,
                    &|done, total| {
                        bar.set_length(total as u64);
                        bar.set_position(done as u64);
                    },
                )
                .with_context(|| format!("measuring {}", face.name))?,
            );
            bar.finish_and_clear();
        }
    }
    print!("{}", shapes::table(&rows));
    println!("\nPer face (skin over the converged shapes, mouthClose aside):\n");
    print!("{}", shapes::summary_table(&rows));
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&rows)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// Runs one benchmark.
pub fn run(target: BenchTarget) -> Result<()> {
    match target {
        BenchTarget::Nets(args) => bench_nets(&args),
        BenchTarget::Editor {
            sample,
            faces,
            sliders,
            steps,
            contact,
            presets,
        } => bench_editor(&sample, &faces, &sliders, steps, contact, &presets),
        BenchTarget::Solver {
            elements,
            samples,
            json,
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
            Ok(())
        }
        BenchTarget::Tradeoff(args) => bench_tradeoff(&args),
        BenchTarget::Extremes(args) => bench_extremes(&args),
        BenchTarget::Shapes(args) => bench_shapes(&args),
        BenchTarget::Remote(args) => bench_remote(&args),
        BenchTarget::Contact {
            json,
            sweep: Some(count),
            sweep_mode,
            sweep_range,
            sweep_seed,
            ..
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
            Ok(())
        }
        BenchTarget::Contact {
            model,
            rig,
            frames,
            json,
            sweep: None,
            ..
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
            Ok(())
        }
    }
}

#[derive(clap::Args)]
pub struct NetsArgs {
    #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
    sample: PathBuf,
    /// Trained networks (default: fresh ones with the default architecture; the inference
    /// cost is the same).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Timing samples per measurement.
    #[arg(long, default_value_t = 30)]
    samples: usize,
}

fn bench_nets(a: &NetsArgs) -> Result<()> {
    let sample = facesim::sample::Sample::load(&a.sample)
        .with_context(|| format!("loading the sample in {}", a.sample.display()))?;
    let nets = Arc::new(match &a.model {
        Some(p) => GenerativeNets::load(p).with_context(|| format!("loading {}", p.display()))?,
        None => GenerativeNets::new(
            Default::default(),
            facesim::generative::pipeline::canonical_frame(&sample)?,
            1,
        )?,
    });
    let rows = facesim::bench::nets::bench(&sample, nets, a.samples)?;
    print!("{}", facesim::bench::nets::table(&rows));
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
    check_sliders(sliders)?;
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
