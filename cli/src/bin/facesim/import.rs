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
