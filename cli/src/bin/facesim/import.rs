//! `facesim import` and `facesim sample`: face models and the bundled sample from the rig.

use std::path::PathBuf;

use anyhow::{Context, Result};
use facesim::table::Table;
use facesim_cli::progress::{load_rig, spinner};

#[derive(clap::Args)]
pub struct ImportArgs {
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
}

#[derive(clap::Args)]
pub struct SampleArgs {
    #[arg(long, default_value = facesim::rig::DEFAULT_RIG_DIR)]
    rig: PathBuf,
    #[arg(long, default_value = facesim::sample::SAMPLE_DIR)]
    out: PathBuf,
    /// Rig identities besides the template.
    #[arg(long, value_delimiter = ',', default_values_t = facesim::sample::SAMPLE_IDENTITIES)]
    identities: Vec<usize>,
}

/// `facesim sample`: builds the bundled sample and prints how well each face's actuation
/// basis fits the rig.
pub fn sample(args: &SampleArgs) -> Result<()> {
    use facesim::sample::{SAMPLE_LOD, write_sample};
    let (out, identities) = (&args.out, &args.identities);
    let rig = load_rig(&args.rig)?;
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
            BASIS_COLUMNS[0],
            BASIS_COLUMNS[1],
            BASIS_COLUMNS[2],
        ],
        "lrlrr",
    );
    print!("{}", table.head());
    for entry in &manifest.faces {
        let model = facesim::model::FaceModel::load(&out.join(&entry.face))?;
        let basis = facesim::drive::basis::ActuationBasis::load(&out.join(&entry.basis))?;
        let [skin, jaw, clamped] = basis_cells(&basis);
        print!(
            "{}",
            table.line([
                entry.name.clone(),
                model.mesh.element_count().to_string(),
                skin,
                jaw,
                clamped,
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
pub fn import(args: &ImportArgs) -> Result<()> {
    use facesim::model::build_face;
    let (out, identities, lods) = (&args.out, &args.identities, &args.lod);
    let rig = load_rig(&args.rig)?;
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

/// The columns of [`basis_cells`].
const BASIS_COLUMNS: [&str; 3] = [
    "basis skin error (RMS / max, mm)",
    "jaw fit RMS (mm)",
    "clamped elements",
];

/// A fitted basis's worst fit (its shapes and its sliders in the face's own style): skin RMS
/// / max and jaw RMS (mm), and its clamped elements over all fits.
fn basis_cells(basis: &facesim::drive::basis::ActuationBasis) -> [String; 3] {
    let fits = || basis.fits.iter().chain(basis.own_style_fits());
    let worst =
        |of: fn(&facesim::drive::basis::ShapeFit) -> f64| fits().map(of).fold(0.0, f64::max);
    let clamped: usize = fits().map(|f| f.clamped).sum();
    [
        format!(
            "≤ {:.3} / {:.3}",
            10.0 * worst(|f| f.skin_rms),
            10.0 * worst(|f| f.skin_max)
        ),
        format!("≤ {:.3}", 10.0 * worst(|f| f.jaw_rms)),
        clamped.to_string(),
    ]
}

#[derive(clap::Args)]
pub struct AddFaceArgs {
    /// The new face's neutral: an OBJ on the rig's topology (the vertices and faces of the
    /// rig's generic_neutral_mesh.obj, in its order), in cm like the rig.
    neutral: PathBuf,
    /// The sample folder to add it to (it needs a template face).
    #[arg(long)]
    sample: PathBuf,
    /// The face's name (letters, digits, '-', '_'); default: the OBJ's file stem.
    #[arg(long)]
    name: Option<String>,
    /// The face's default style: intensity,asymmetry,jaw,dimple (e.g. `-0.5,0.2,0,0.6`).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, default_values_t = [0.0; 4])]
    style: Vec<f64>,
    #[arg(long, default_value_t = facesim::sample::SAMPLE_LOD)]
    lod: facesim::model::Lod,
    /// The rig whose expression shapes pose the new face.
    #[arg(long, default_value = facesim::rig::DEFAULT_RIG_DIR)]
    rig: PathBuf,
    /// φ's training, as `train-mapping` trains it.
    #[command(flatten)]
    training: crate::mapping::TrainingArgs,
}

/// `facesim add-face`: a new face from its neutral alone, imported, fitted, mapped and added
/// to a sample.
pub fn add_face(args: &AddFaceArgs) -> Result<()> {
    use facesim::sample::{AddFaceEvent, AddFaceOptions};
    let options = AddFaceOptions {
        name: args.name.clone(),
        style: facesim::rig::StyleCode(
            args.style
                .clone()
                .try_into()
                .map_err(|_| anyhow::anyhow!("--style takes 4 numbers"))?,
        ),
        lod: args.lod,
        mapping: args.training.config(),
    };
    let rig = load_rig(&args.rig)?;
    let bar = spinner();
    let training = facesim_cli::progress::bar(
        options.mapping.iterations,
        "training φ [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {msg}",
    );
    let added =
        facesim::sample::add_face(&rig, &args.sample, &args.neutral, &options, &mut |event| {
            match event {
                AddFaceEvent::Step(message) => bar.set_message(message.to_string()),
                AddFaceEvent::Mapping(row) => {
                    bar.finish_and_clear();
                    training.set_position(row.iteration + 1);
                    training.set_message(format!("vertex MSE {:.4} mm²", row.vertex_mse_mm2));
                }
            }
        })
        .with_context(|| {
            format!(
                "adding {} to the sample in {}",
                args.neutral.display(),
                args.sample.display()
            )
        })?;
    bar.finish_and_clear();
    training.finish_and_clear();
    let table = Table::new(
        &[
            "face",
            "rig identity",
            "elements",
            BASIS_COLUMNS[0],
            BASIS_COLUMNS[1],
            BASIS_COLUMNS[2],
            "φ vertex RMS (mm)",
            "seconds",
        ],
        "lrrlrrrr",
    );
    let [skin, jaw, clamped] = basis_cells(&added.basis);
    let record = added.mapping.record.as_ref();
    print!("{}", table.head());
    print!(
        "{}",
        table.line([
            added.entry.name.clone(),
            added.entry.identity.map_or("-".into(), |i| i.to_string()),
            added.model.mesh.element_count().to_string(),
            skin,
            jaw,
            clamped,
            record.map_or("-".into(), |r| format!(
                "{:.3}",
                r.final_vertex_mse_mm2.sqrt()
            )),
            format!("{:.0}", added.seconds),
        ])
    );
    eprintln!(
        "added {} to {}; open it with `cargo run --release -- --sample {}` \
         (`--actuation networks` drives it with the sample's networks)",
        added.entry.name,
        args.sample.display(),
        args.sample.display()
    );
    Ok(())
}
