//! `facesim train-mapping` and `facesim stats`: the command-line side of `facesim::mapping`
//! (finding the faces, the progress bar, writing the files).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use facesim::mapping::{
    self, HeatmapKind, IdentityStats, Mapping, RingField, TrainConfig,
    plot::{Panel, heatmap_figure},
    stats::{BinRange, heatmap_csv, histogram, summary_csv},
};
use facesim::model::FaceModel;
use facesim::table::Table;

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

fn load_face(dir: &Path, stem: &str) -> Result<FaceModel> {
    let path = dir.join(format!("{stem}.face"));
    FaceModel::load(&path).with_context(|| format!("loading {}", path.display()))
}

/// File stems of `*.<ext>` in `dir`, sorted.
fn stems(dir: &Path, ext: &str) -> Result<Vec<String>> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let p = e?.path();
        if p.extension().and_then(|x| x.to_str()) == Some(ext)
            && let Some(s) = p.file_stem().and_then(|s| s.to_str())
        {
            out.push(s.to_string());
        }
    }
    out.sort();
    Ok(out)
}

fn write(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}

pub fn train_mapping(a: &TrainArgs) -> Result<()> {
    let canonical = load_face(&a.faces, &a.canonical)?;
    let names = if a.identities.is_empty() {
        stems(&a.faces, "face")?
            .into_iter()
            .filter(|s| *s != a.canonical)
            .collect()
    } else {
        a.identities.clone()
    };
    anyhow::ensure!(
        !names.is_empty(),
        "no faces to train in {}",
        a.faces.display()
    );
    let mut config = TrainConfig {
        iterations: a.iterations,
        learning_rate: a.lr,
        seed: a.seed,
        surface_batch: a.surface_batch,
        elastic_batch: a.elastic_batch,
        lambda_elastic: a.lambda_elastic,
        ..TrainConfig::default()
    };
    config.architecture.width = a.width;
    let table = Table::new(
        &[
            "face",
            "correspondences",
            "elastic points",
            "vertex RMS (mm)",
            "elastic ‖J−R‖²",
            "seconds",
        ],
        "lrrrrr",
    );
    print!("{}", table.head());
    for name in &names {
        let face = load_face(&a.faces, name)?;
        let bar = indicatif::ProgressBar::new(config.iterations);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{msg:>20} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {prefix}",
            )?
            .progress_chars("=> "),
        );
        bar.set_message(name.clone());
        let start = Instant::now();
        let (mapping, rows) = mapping::train(&face, &canonical, &config, |row| {
            if row.iteration % 20 == 0 {
                bar.set_prefix(format!(
                    "vertex {:.3} mm² elastic {:.4}",
                    row.vertex_mse_mm2, row.elastic
                ));
            }
            bar.inc(1);
        })
        .with_context(|| format!("training the mapping of {name}"))?;
        bar.finish_and_clear();
        let seconds = start.elapsed().as_secs_f64();
        let path = a.faces.join(format!("{name}.mapping"));
        mapping
            .save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        write(
            &a.faces.join(format!("{name}.loss.csv")),
            &mapping::loss_csv(&rows),
        )?;
        let r = mapping.record.as_ref().expect("trained");
        print!(
            "{}",
            table.line([
                name.to_string(),
                r.surface_points.to_string(),
                r.elastic_points.to_string(),
                format!("{:.3}", r.final_vertex_mse_mm2.sqrt()),
                format!("{:.5}", r.final_elastic),
                format!("{seconds:.0}"),
            ])
        );
    }
    Ok(())
}

pub fn stats(a: &StatsArgs) -> Result<()> {
    let canonical = load_face(&a.faces, &a.canonical)?;
    let names = if a.identities.is_empty() {
        stems(&a.faces, "mapping")?
    } else {
        a.identities.clone()
    };
    anyhow::ensure!(
        !names.is_empty(),
        "no .mapping files in {}",
        a.faces.display()
    );
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut all = Vec::new();
    let mut comparisons = Vec::new();
    for name in &names {
        let face = load_face(&a.faces, name)?;
        let path = a.faces.join(format!("{name}.mapping"));
        let phi = Mapping::load(&path).with_context(|| format!("loading {}", path.display()))?;
        let st = IdentityStats::sample(&face, &canonical, &phi, a.seed)
            .with_context(|| format!("sampling the mapping of {name}"))?;
        // Per render vertex values for the viewer.
        let mut cols = Vec::new();
        for kind in HeatmapKind::ALL {
            cols.push(mapping::vertex_values(&face, &canonical, &phi, kind)?);
        }
        let mut csv = String::from("render_vertex,rig_vertex,det,condition,vertex_error_mm\n");
        for (i, rig) in face.render.rig_vertices.iter().enumerate() {
            csv.push_str(&format!(
                "{i},{rig},{:.6},{:.6},{:.6}\n",
                cols[0][i], cols[1][i], cols[2][i]
            ));
        }
        write(&a.out.join(format!("{name}.vertex-heatmaps.csv")), &csv)?;
        if a.warp {
            let field = RingField::around_mouth(&canonical, a.warp_strength, 2.0)?;
            eprintln!("comparing warps on {name}…");
            comparisons.push(
                mapping::warp::compare(&face, &phi, &field, a.warp_rotation)
                    .with_context(|| format!("warp comparison on {name}"))?,
            );
        }
        all.push(st);
    }
    let summaries: Vec<_> = all.iter().map(|s| s.summary()).collect();
    write(&a.out.join("mapping-summary.csv"), &summary_csv(&summaries))?;
    let titles = [
        (HeatmapKind::Determinant, "DET J"),
        (HeatmapKind::Condition, "SIGMA MAX / SIGMA MIN"),
        (HeatmapKind::VertexError, "VERTEX ERROR (MM)"),
    ];
    let mut panels = Vec::new();
    for (kind, title) in titles {
        let range = BinRange::default_for(kind);
        write(
            &a.out.join(format!("mapping-{}.csv", kind.name())),
            &heatmap_csv(&all, kind, &range),
        )?;
        panels.push(Panel {
            title: title.into(),
            lo: range.lo,
            hi: range.hi,
            shares: all
                .iter()
                .map(|s| histogram(s.values(kind), range.lo, range.hi, range.bins))
                .collect(),
        });
    }
    let rows: Vec<String> = all.iter().map(|s| s.name.replace("-coarse", "")).collect();
    let png = a.out.join("mapping-stats.png");
    heatmap_figure(&rows, &panels)
        .write_png(&png)
        .with_context(|| format!("writing {}", png.display()))?;
    let mut table = Table::new(
        &[
            "face",
            "interior points",
            "surface points",
            "det min / median / max",
            "σmax/σmin median / p95",
            "vertex error mean / max (mm)",
        ],
        "lrrlll",
    );
    for m in &summaries {
        table.row([
            m.name.clone(),
            m.interior_points.to_string(),
            m.surface_points.to_string(),
            format!("{:.3} / {:.3} / {:.3}", m.det_min, m.det_median, m.det_max),
            format!("{:.3} / {:.3}", m.condition_median, m.condition_p95),
            format!(
                "{:.3} / {:.3}",
                m.vertex_error_mean_mm, m.vertex_error_max_mm
            ),
        ]);
    }
    print!("{table}");
    if a.warp {
        println!();
        let rotated = format!("rotated {}°: warp / naive off (mm)", a.warp_rotation);
        let mut table = Table::new(
            &[
                "face",
                "actuated elements",
                "direction turn median / p95 / max (°)",
                "max displacement warp / naive (mm)",
                "warp − naive mean / max (mm)",
                &rotated,
                "identity actuations: max displacement (mm)",
            ],
            "lrllllr",
        );
        for c in &comparisons {
            table.row([
                c.face.clone(),
                c.actuated_elements.to_string(),
                format!(
                    "{:.2} / {:.2} / {:.2}",
                    c.angle_median_deg, c.angle_p95_deg, c.angle_max_deg
                ),
                format!(
                    "{:.3} / {:.3}",
                    c.warp_max_displacement_mm, c.naive_max_displacement_mm
                ),
                format!("{:.3} / {:.3}", c.difference_mean_mm, c.difference_max_mm),
                format!(
                    "{:.4} / {:.3}",
                    c.warp_equivariance_max_mm, c.naive_equivariance_max_mm
                ),
                format!("{:.1e}", c.identity_actuation_max_displacement_mm),
            ]);
        }
        print!("{table}");
        write(
            &a.out.join("warp-comparison.json"),
            &serde_json::to_string_pretty(&comparisons)?,
        )?;
    }
    eprintln!(
        "wrote {} and the CSVs to {}",
        png.display(),
        a.out.display()
    );
    Ok(())
}
