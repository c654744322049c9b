//! The mappings of a folder of faces (`<name>.face`, with `<name>.mapping` beside it once
//! trained): training every identity's φ to the canonical face, and the mapping statistics as
//! the paper's Fig. 3 (what `facesim train-mapping` and `facesim stats` run).

use std::path::{Path, PathBuf};
use std::time::Instant;

use super::plot::{Panel, heatmap_figure};
use super::stats::{BinRange, heatmap_csv, histogram, summary_csv};
use super::{
    HeatmapKind, IdentityStats, LossRow, Mapping, MappingError, RingField, Summary, TrainConfig,
    TrainingRecord, WarpComparison, loss_csv, train, vertex_values,
};
use crate::model::FaceModel;
use crate::table::Table;

/// Loads `<dir>/<stem>.face`.
pub fn load_face(dir: &Path, stem: &str) -> Result<FaceModel, MappingError> {
    Ok(FaceModel::load(&dir.join(format!("{stem}.face")))?)
}

/// File stems of `*.<ext>` in `dir`, sorted.
pub fn stems(dir: &Path, ext: &str) -> Result<Vec<String>, MappingError> {
    let io = |source| MappingError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).map_err(io)? {
        let p = e.map_err(io)?.path();
        if p.extension().and_then(|x| x.to_str()) == Some(ext)
            && let Some(s) = p.file_stem().and_then(|s| s.to_str())
        {
            out.push(s.to_string());
        }
    }
    out.sort();
    Ok(out)
}

fn write(path: &Path, text: &str) -> Result<(), MappingError> {
    std::fs::write(path, text).map_err(|source| MappingError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// `chosen`, or else every `*.<ext>` in `dir` but `canonical`; an error if that is none.
fn names(
    dir: &Path,
    ext: &str,
    canonical: &str,
    chosen: &[String],
) -> Result<Vec<String>, MappingError> {
    let names: Vec<String> = if chosen.is_empty() {
        stems(dir, ext)?
            .into_iter()
            .filter(|s| s != canonical)
            .collect()
    } else {
        chosen.to_vec()
    };
    if names.is_empty() {
        return Err(MappingError::Config(format!(
            "no faces with a .{ext} file in {}",
            dir.display()
        )));
    }
    Ok(names)
}

/// What [`train_folder`] tells as it goes.
pub enum TrainEvent<'a> {
    Started { face: &'a str },
    Iteration { face: &'a str, row: &'a LossRow },
    Finished(&'a TrainedFace),
}

/// One face's trained φ.
pub struct TrainedFace {
    pub name: String,
    pub record: TrainingRecord,
    pub seconds: f64,
}

/// Trains the mapping of each of `identities` (default: every other face in `dir`) to
/// `canonical` and writes `<name>.mapping` and `<name>.loss.csv` beside it.
pub fn train_folder(
    dir: &Path,
    canonical: &str,
    identities: &[String],
    config: &TrainConfig,
    events: &mut dyn FnMut(TrainEvent<'_>),
) -> Result<Vec<TrainedFace>, MappingError> {
    let canonical_face = load_face(dir, canonical)?;
    let mut trained = Vec::new();
    for name in names(dir, "face", canonical, identities)? {
        let face = load_face(dir, &name)?;
        events(TrainEvent::Started { face: &name });
        let start = Instant::now();
        let (mapping, rows) = train(&face, &canonical_face, config, |row| {
            events(TrainEvent::Iteration { face: &name, row })
        })?;
        let seconds = start.elapsed().as_secs_f64();
        mapping.save(&dir.join(format!("{name}.mapping")))?;
        write(&dir.join(format!("{name}.loss.csv")), &loss_csv(&rows))?;
        let done = TrainedFace {
            record: mapping
                .record
                .clone()
                .expect("a trained mapping keeps its record"),
            name,
            seconds,
        };
        events(TrainEvent::Finished(&done));
        trained.push(done);
    }
    Ok(trained)
}

/// The columns of [`trained_line`].
pub fn trained_table() -> Table {
    Table::new(
        &[
            "face",
            "correspondences",
            "elastic points",
            "vertex RMS (mm)",
            "elastic ‖J−R‖²",
            "seconds",
        ],
        "lrrrrr",
    )
}

/// One trained face's line of [`trained_table`].
pub fn trained_line(table: &Table, t: &TrainedFace) -> String {
    let r = &t.record;
    table.line([
        t.name.clone(),
        r.surface_points.to_string(),
        r.elastic_points.to_string(),
        format!("{:.3}", r.final_vertex_mse_mm2.sqrt()),
        format!("{:.5}", r.final_elastic),
        format!("{:.0}", t.seconds),
    ])
}

/// The warp-versus-naive comparison of [`stats_folder`].
#[derive(Clone, Copy, Debug)]
pub struct WarpCheck {
    /// Peak contraction of the canonical test field (1 − stretch at its centre).
    pub strength: f64,
    /// Rotation of the face copy in the equivariance check (degrees about the vertical axis).
    pub rotation_deg: f64,
}

/// What [`stats_folder`] measured and wrote.
pub struct FolderStats {
    pub summaries: Vec<Summary>,
    pub comparisons: Vec<WarpComparison>,
    /// The Fig. 3 heatmaps.
    pub figure: PathBuf,
}

/// The mapping statistics of `identities` (default: every face with a `.mapping` in
/// `dir`): per-vertex values (`<name>.vertex-heatmaps.csv`), the summary and heatmap CSVs
/// and the Fig. 3 figure (`mapping-stats.png`) in `out`; with `warp`, the warp comparison
/// too (`warp-comparison.json`; each face simulated four times).
pub fn stats_folder(
    dir: &Path,
    canonical: &str,
    identities: &[String],
    out: &Path,
    seed: u64,
    warp: Option<WarpCheck>,
    progress: &dyn Fn(&str),
) -> Result<FolderStats, MappingError> {
    let canonical_face = load_face(dir, canonical)?;
    std::fs::create_dir_all(out).map_err(|source| MappingError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let (mut all, mut comparisons) = (Vec::new(), Vec::new());
    for name in names(dir, "mapping", canonical, identities)? {
        let face = load_face(dir, &name)?;
        let phi = Mapping::load(&dir.join(format!("{name}.mapping")))?;
        progress(&format!("sampling the mapping of {name}"));
        let st = IdentityStats::sample(&face, &canonical_face, &phi, seed)?;
        let cols = HeatmapKind::ALL
            .iter()
            .map(|&kind| vertex_values(&face, &canonical_face, &phi, kind))
            .collect::<Result<Vec<_>, _>>()?;
        let mut csv = String::from("render_vertex,rig_vertex,det,condition,vertex_error_mm\n");
        for (i, rig) in face.render.rig_vertices.iter().enumerate() {
            csv.push_str(&format!(
                "{i},{rig},{:.6},{:.6},{:.6}\n",
                cols[0][i], cols[1][i], cols[2][i]
            ));
        }
        write(&out.join(format!("{name}.vertex-heatmaps.csv")), &csv)?;
        if let Some(w) = warp {
            progress(&format!("comparing warps on {name}"));
            let field = RingField::around_mouth(&canonical_face, w.strength, 2.0)?;
            comparisons.push(super::warp::compare(&face, &phi, &field, w.rotation_deg)?);
        }
        all.push(st);
    }
    let summaries: Vec<_> = all.iter().map(|s| s.summary()).collect();
    write(&out.join("mapping-summary.csv"), &summary_csv(&summaries))?;
    let titles = [
        (HeatmapKind::Determinant, "det J"),
        (HeatmapKind::Condition, "σmax / σmin"),
        (HeatmapKind::VertexError, "vertex error (mm)"),
    ];
    let mut panels = Vec::new();
    for (kind, title) in titles {
        let range = BinRange::default_for(kind);
        write(
            &out.join(format!("mapping-{}.csv", kind.name())),
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
    let figure = out.join("mapping-stats.png");
    heatmap_figure(&rows, &panels)?.write_png(&figure)?;
    if warp.is_some() {
        let json = serde_json::to_string_pretty(&comparisons)
            .map_err(|e| MappingError::Config(format!("warp comparison JSON: {e}")))?;
        write(&out.join("warp-comparison.json"), &json)?;
    }
    Ok(FolderStats {
        summaries,
        comparisons,
        figure,
    })
}

/// The summaries as a Markdown table.
pub fn summary_table(summaries: &[Summary]) -> String {
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
    for m in summaries {
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
    table.to_string()
}

/// The warp comparisons as a Markdown table (`rotation_deg` as in [`WarpCheck`]).
pub fn warp_table(comparisons: &[WarpComparison], rotation_deg: f64) -> String {
    let rotated = format!("rotated {rotation_deg}°: warp / naive off (mm)");
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
    for c in comparisons {
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
    table.to_string()
}
