//! `facesim bench tradeoff` (loads, or builds once and keeps, the neutral face at each level
//! of detail with its actuation basis; writes the table, JSON and plot) and
//! `facesim bench extremes`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use facesim::bench::tradeoff::{TradeoffFace, measure, plot, table};
use facesim::drive::basis::ActuationBasis;
use facesim::model::{FaceModel, Lod, build_face};

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
}

/// The neutral face at `lod` and its basis: from the sample (coarse), from `models`, or built
/// from the rig and saved into `models`.
fn face_at(args: &TradeoffArgs, lod: Lod) -> Result<(FaceModel, ActuationBasis)> {
    let dir = if lod == facesim::sample::SAMPLE_LOD {
        args.sample.as_path()
    } else {
        args.models.as_path()
    };
    let (face_path, basis_path) = (
        dir.join(format!("neutral-{}.face", lod.name())),
        dir.join(format!("neutral-{}.basis", lod.name())),
    );
    if face_path.exists() && basis_path.exists() {
        let face = FaceModel::load(&face_path)
            .with_context(|| format!("loading {}", face_path.display()))?;
        let basis = ActuationBasis::load(&basis_path)
            .with_context(|| format!("loading {}", basis_path.display()))?;
        return Ok((face, basis));
    }
    let rig = crate::load_rig(&args.rig)?;
    let bar = crate::spinner();
    bar.set_message(format!("building the neutral face at {}", lod.name()));
    let face = build_face(&rig, None, &lod.settings())
        .with_context(|| format!("building the neutral face at {}", lod.name()))?;
    let basis = ActuationBasis::fit(&rig, &face, &|done, total, shape| {
        bar.set_message(format!("fitting {}: {done}/{total} {shape}", lod.name()))
    })
    .with_context(|| format!("fitting the basis at {}", lod.name()))?;
    bar.finish_and_clear();
    std::fs::create_dir_all(&args.models)
        .with_context(|| format!("creating {}", args.models.display()))?;
    face.save(&face_path)?;
    basis.save(&basis_path)?;
    Ok((face, basis))
}

pub fn bench_tradeoff(args: &TradeoffArgs) -> Result<()> {
    anyhow::ensure!(args.frames >= 2, "--frames must be at least 2");
    anyhow::ensure!(!args.lods.is_empty(), "--lods is empty");
    let loaded = args
        .lods
        .iter()
        .map(|&lod| face_at(args, lod))
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
    let bar = crate::spinner();
    let (rows, reference) = measure(&faces, args.frames, &|m| bar.set_message(m.to_string()))
        .context("measuring the trade")?;
    bar.finish_and_clear();
    anyhow::ensure!(
        reference.errors.is_empty(),
        "the reference failed on {} frame(s): {:?}",
        reference.errors.len(),
        reference.errors
    );
    let md = table(&rows);
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
    write(&args.out, "tradeoff.md", md.as_bytes())?;
    write(
        &args.out,
        "tradeoff.json",
        serde_json::to_string_pretty(&rows)?.as_bytes(),
    )?;
    let png = args.out.join("tradeoff.png");
    plot(&rows)
        .map_err(anyhow::Error::msg)?
        .write_png(&png)
        .with_context(|| format!("writing {}", png.display()))?;
    eprintln!(
        "wrote {} (reference: {} iterations in all)",
        args.out.display(),
        reference.iterations.iter().sum::<usize>()
    );
    Ok(())
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
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} eta {eta}")
            .expect("valid template"),
    );
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
            Some(facesim::generative::face::sample_actuations(
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
            let bar = progress_bar(&format!(
                "{} with contact {}",
                face.name,
                if contact { "on" } else { "off" }
            ));
            rows.extend(
                shapes::measure(&rig, &measured, &codes, &settings, &|done, total| {
                    bar.set_length(total as u64);
                    bar.set_position(done as u64);
                })
                .with_context(|| format!("measuring {}", face.name))?,
            );
            bar.finish_and_clear();
        }
    }
    print!("{}", shapes::table(&rows));
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&rows)?)
            .with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// A progress bar on standard error (hidden when it is not a terminal).
fn progress_bar(message: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} eta {eta}")
            .expect("valid template"),
    );
    bar.set_message(message.to_string());
    bar
}
