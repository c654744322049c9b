//! Fidelity as the artist sees it (`facesim bench shapes`): every slider alone at weight 1 (or
//! any given codes) on every face, solved from rest, against the rig's own shape, vertex by
//! vertex over the whole render surface.
//!
//! Per face, code and contact setting it reports, leading with maxima:
//! - the render skin and lips (the rig's face-skin piece): largest, 95th-percentile and mean
//!   distance from the rig, and where the largest is (rig vertex index);
//! - the mouth lining (the mouth-socket piece) separately: mean and largest;
//! - crossings of the whole render surface ([`CrossingAudit`], independent of the contact
//!   solver's surface), and those of the rig's own target (where the rig itself presses the
//!   lips through each other, the target is not physical and contact decides);
//! - whether the solve converged, its iterations, residual and time;
//! - where frames get it (final with contact, [`crate::model::deep_lining::runs_at`]), the
//!   deep lining's contact pass, as the editor and exports apply it;
//! - and per face, the summary of those rows ([`summary`]): the shapes that converged, the
//!   worst skin and lining over them, the shapes above the 2 mm target, the crossings by pieces.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::contact::surface::FaceContact;
use crate::drive::{ActuationModel, Codes};
use crate::model::audit::CrossingAudit;
use crate::model::contact_region::FaceContactSettings;
use crate::model::creases::{CreaseAudit, beyond};
use crate::model::deep_lining::{DeepLining, DeepLiningStats, LiningMemory};
use crate::model::{FaceModel, target};
use crate::rig::{ExpressionCode, FaceRig, Region};
use crate::sim::{SimError, SolveSettings, Termination};
use crate::table::Table;

/// One posed code on one face.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShapeRow {
    pub face: String,
    pub code: String,
    pub contact: bool,
    /// `None` when the solve failed (then `error` says why and no distances are given).
    pub termination: Option<Termination>,
    pub error: Option<String>,
    pub iterations: usize,
    pub residual: f64,
    pub ms: f64,
    pub skin_max_mm: f64,
    pub skin_p95_mm: f64,
    pub skin_mean_mm: f64,
    /// Rig vertex index of the skin vertex farthest from the rig.
    pub skin_worst_vertex: u32,
    pub lining_mean_mm: f64,
    pub lining_max_mm: f64,
    /// New crossings of the render surface (skin, lining, gums, teeth), by pieces.
    pub crossings: usize,
    pub crossing_pieces: Vec<(String, usize)>,
    /// New crossings of the rig's own target for the code.
    pub rig_crossings: usize,
    pub rig_crossing_pieces: Vec<(String, usize)>,
    /// Creased skin and lining edges ([`crate::model::creases`]), by pieces, and a rig vertex
    /// of the most creased one.
    #[serde(default)]
    pub creases: usize,
    #[serde(default)]
    pub crease_pieces: Vec<(String, usize)>,
    #[serde(default)]
    pub crease_worst_vertex: Option<u32>,
    /// Creased edges of the rig's own target for the code.
    #[serde(default)]
    pub rig_creases: usize,
    /// Of `creases`, the edges that the rig's own target does not crease.
    #[serde(default)]
    pub creases_beyond_rig: usize,
    /// The deep lining's contact pass, where it ran.
    #[serde(default)]
    pub lining: Option<DeepLiningStats>,
}

impl ShapeRow {
    /// The solve reached its tolerance, and so did the lining's pass where it ran.
    pub fn converged(&self) -> bool {
        self.termination == Some(Termination::Converged)
            && self.lining.as_ref().is_none_or(|l| l.converged)
    }
}

/// Every expression slider alone at weight 1, named after it.
pub fn single_shapes() -> Vec<(String, crate::rig::ExpressionCode)> {
    ExpressionCode::NAMES
        .iter()
        .filter_map(|&n| Some((n.to_string(), ExpressionCode::single(n, 1.0)?)))
        .collect()
}

/// A face to measure: its model, how it is driven, and its default style.
pub struct MeasuredFace<'a> {
    pub name: &'a str,
    pub model: &'a FaceModel,
    pub actuation: &'a dyn ActuationModel,
    pub style: crate::rig::StyleCode,
}

/// Poses every code on `face` from rest with `settings` (contact as `settings.contact`) and
/// measures it against `rig` (module doc); `lining`: with the deep lining's contact pass, as
/// frames get it at the final preset with contact ([`deep_lining::runs_at`]).
/// `progress(done, total)` after each.
pub fn measure(
    rig: &FaceRig,
    face: &MeasuredFace,
    codes: &[(String, ExpressionCode)],
    settings: &SolveSettings,
    lining: bool,
    progress: &dyn Fn(usize, usize),
) -> Result<Vec<ShapeRow>, SimError> {
    let model = face.model;
    let mut sim = model.simulator()?;
    let mut pass = None;
    if settings.contact {
        let surfaces = FaceContact::new(model, &FaceContactSettings::default())
            .map_err(|e| SimError::Setup(format!("contact surfaces of {}: {e}", face.name)))?;
        if lining {
            pass = Some(DeepLining::new(model, &surfaces).map_err(|e| {
                SimError::Setup(format!("the deep lining's contact of {}: {e}", face.name))
            })?);
        }
        sim.set_contact(surfaces)?;
    }
    let audit = CrossingAudit::new(model);
    let crease_audit = CreaseAudit::new(model);
    let region: Vec<Option<Region>> = model
        .render
        .rig_vertices
        .iter()
        .map(|&v| Region::of_vertex(v as usize))
        .collect();
    let mut rows = Vec::new();
    let total = codes.len();
    for (k, (name, expression)) in codes.iter().enumerate() {
        let codes = Codes {
            expression: *expression,
            style: face.style,
        };
        let goal = target(rig, model, &codes)
            .map_err(|e| SimError::Setup(format!("the rig's target for {name}: {e}")))?;
        let mut row = ShapeRow {
            face: face.name.to_string(),
            code: name.clone(),
            contact: settings.contact,
            termination: None,
            error: None,
            iterations: 0,
            residual: f64::NAN,
            ms: 0.0,
            skin_max_mm: f64::NAN,
            skin_p95_mm: f64::NAN,
            skin_mean_mm: f64::NAN,
            skin_worst_vertex: 0,
            lining_mean_mm: f64::NAN,
            lining_max_mm: f64::NAN,
            crossings: 0,
            crossing_pieces: Vec::new(),
            rig_crossings: 0,
            rig_crossing_pieces: Vec::new(),
            creases: 0,
            crease_pieces: Vec::new(),
            crease_worst_vertex: None,
            rig_creases: 0,
            creases_beyond_rig: 0,
            lining: None,
        };
        let rig_creased = crease_audit.creased(&goal.render);
        row.rig_creases = rig_creased.len();
        let rig_crossings = audit.audit(model, &goal.render);
        (row.rig_crossings, row.rig_crossing_pieces) =
            (rig_crossings.pairs, rig_crossings.by_pieces);
        let actuation = face
            .actuation
            .actuate(&codes)
            .map_err(|e| SimError::Setup(format!("actuating {name}: {e}")))?;
        let bones = actuation.bones();
        let mut state = sim.rest_state();
        let start = Instant::now();
        let solved = sim.solve(&actuation.tensors, &bones, &mut state, settings);
        row.ms = start.elapsed().as_secs_f64() * 1e3;
        match solved {
            Ok(stats) => {
                row.termination = Some(stats.termination);
                row.iterations = stats.iterations;
                row.residual = stats.residual;
                let mut posed = model.render_positions(state.flat_positions(), &bones);
                // Each code is posed from rest, and so is its lining.
                row.lining = pass
                    .as_ref()
                    .map(|l| l.apply(&mut posed, &mut LiningMemory::default()));
                let distances: Vec<f64> = posed
                    .iter()
                    .zip(&goal.render)
                    .map(|(p, q)| 10.0 * (p - q).norm())
                    .collect();
                let of = |piece: Region| -> Vec<(f64, usize)> {
                    (0..distances.len())
                        .filter(|&i| region[i] == Some(piece))
                        .map(|i| (distances[i], i))
                        .collect()
                };
                let mut skin = of(Region::FaceSkin);
                skin.sort_by(|a, b| a.0.total_cmp(&b.0));
                if let Some(&(worst, i)) = skin.last() {
                    row.skin_max_mm = worst;
                    row.skin_worst_vertex = model.render.rig_vertices[i];
                    row.skin_p95_mm = skin[(skin.len() - 1) * 95 / 100].0;
                    row.skin_mean_mm = skin.iter().map(|s| s.0).sum::<f64>() / skin.len() as f64;
                }
                let lining = of(Region::MouthSocket);
                if !lining.is_empty() {
                    row.lining_mean_mm =
                        lining.iter().map(|s| s.0).sum::<f64>() / lining.len() as f64;
                    row.lining_max_mm = lining.iter().map(|s| s.0).fold(0.0, f64::max);
                }
                let crossings = audit.audit(model, &posed);
                row.crossings = crossings.pairs;
                row.crossing_pieces = crossings.by_pieces;
                let creased = crease_audit.creased(&posed);
                let creases = crease_audit.count(&creased);
                (row.creases, row.crease_pieces, row.crease_worst_vertex) =
                    (creases.edges, creases.by_piece, creases.worst_rig_vertex);
                row.creases_beyond_rig = beyond(&creased, &rig_creased).len();
            }
            Err(e) => row.error = Some(e.to_string()),
        }
        rows.push(row);
        progress(k + 1, total);
    }
    Ok(rows)
}

/// The rows as a Markdown table, maxima first.
pub fn table(rows: &[ShapeRow]) -> String {
    let mut t = Table::new(
        &[
            "face",
            "code",
            "contact",
            "skin max (mm)",
            "skin p95",
            "skin mean",
            "worst rig vertex",
            "lining mean (mm)",
            "lining max",
            "crossings",
            "rig's own crossings",
            "creases beyond the rig (all / rig's own)",
            "converged",
            "iterations",
            "ms",
        ],
        "lllrrrrrrrrrlrr",
    );
    for r in rows {
        let solve = match (&r.termination, &r.error) {
            (Some(Termination::Converged), _) => "yes".to_string(),
            (Some(t), _) => format!("**no ({t:?}, residual {:.1e})**", r.residual),
            (None, Some(e)) => format!("**failed: {e}**"),
            (None, None) => "?".to_string(),
        };
        let solve = match &r.lining {
            Some(DeepLiningStats { error: Some(e), .. }) => {
                format!("**lining pass failed: {e}**")
            }
            Some(l) if !l.converged => {
                format!("**lining pass stopped short ({} steps)**", l.iterations)
            }
            _ => solve,
        };
        t.row([
            r.face.clone(),
            r.code.clone(),
            if r.contact { "on" } else { "off" }.to_string(),
            format!("{:.2}", r.skin_max_mm),
            format!("{:.2}", r.skin_p95_mm),
            format!("{:.2}", r.skin_mean_mm),
            r.skin_worst_vertex.to_string(),
            format!("{:.2}", r.lining_mean_mm),
            format!("{:.2}", r.lining_max_mm),
            r.crossings.to_string(),
            r.rig_crossings.to_string(),
            format!(
                "{} ({} / {})",
                r.creases_beyond_rig, r.creases, r.rig_creases
            ),
            solve,
            r.iterations.to_string(),
            format!("{:.0}", r.ms),
        ]);
    }
    t.to_string()
}

/// One face's rows at one contact setting, summed up (see [`summary`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FaceSummary {
    pub face: String,
    pub contact: bool,
    pub shapes: usize,
    pub converged: usize,
    /// The largest skin maximum over the converged shapes the rig poses physically (mouthClose
    /// aside: the rig presses the lips through each other there, contact decides), and its shape.
    pub skin_max_mm: f64,
    pub skin_worst_shape: String,
    /// Those shapes with a skin maximum above [`SKIN_MAX_TARGET_MM`], with it (mm).
    pub skin_over_target: Vec<(String, f64)>,
    /// The largest lining mean over the converged shapes (mm), and its shape.
    pub lining_mean_mm: f64,
    pub lining_worst_shape: String,
    /// Shapes whose pose crosses anywhere, their crossing pairs, and the pairs by pieces.
    pub crossing_shapes: usize,
    pub crossings: usize,
    pub crossing_pieces: Vec<(String, usize)>,
    /// Converged shapes that crease skin and lining edges the rig's own shape does not, and
    /// those edges summed.
    #[serde(default)]
    pub creasing_shapes: usize,
    #[serde(default)]
    pub creases_beyond_rig: usize,
}

/// The skin maximum the mouth's fidelity aims at (mm, per vertex against the rig).
pub const SKIN_MAX_TARGET_MM: f64 = 2.0;

/// Per face and contact setting, in the rows' order: how many shapes converged, the worst skin
/// and lining over them (leading with maxima), and the crossings by pieces.
pub fn summary(rows: &[ShapeRow]) -> Vec<FaceSummary> {
    let unphysical =
        |r: &ShapeRow| crate::model::bindings::UNPHYSICAL_SHAPES.contains(&r.code.as_str());
    let mut out: Vec<FaceSummary> = Vec::new();
    for r in rows {
        let index = match out
            .iter()
            .position(|s| s.face == r.face && s.contact == r.contact)
        {
            Some(i) => i,
            None => {
                out.push(FaceSummary {
                    face: r.face.clone(),
                    contact: r.contact,
                    shapes: 0,
                    converged: 0,
                    skin_max_mm: 0.0,
                    skin_worst_shape: String::new(),
                    skin_over_target: Vec::new(),
                    lining_mean_mm: 0.0,
                    lining_worst_shape: String::new(),
                    crossing_shapes: 0,
                    crossings: 0,
                    crossing_pieces: Vec::new(),
                    creasing_shapes: 0,
                    creases_beyond_rig: 0,
                });
                out.len() - 1
            }
        };
        let s = &mut out[index];
        s.shapes += 1;
        s.crossing_shapes += usize::from(r.crossings > 0);
        s.crossings += r.crossings;
        for (piece, pairs) in &r.crossing_pieces {
            match s.crossing_pieces.iter_mut().find(|(p, _)| p == piece) {
                Some(entry) => entry.1 += pairs,
                None => s.crossing_pieces.push((piece.clone(), *pairs)),
            }
        }
        if !r.converged() {
            continue;
        }
        s.converged += 1;
        if r.creases_beyond_rig > 0 {
            s.creasing_shapes += 1;
            s.creases_beyond_rig += r.creases_beyond_rig;
        }
        if r.lining_mean_mm > s.lining_mean_mm {
            (s.lining_mean_mm, s.lining_worst_shape) = (r.lining_mean_mm, r.code.clone());
        }
        if unphysical(r) {
            continue;
        }
        if r.skin_max_mm > s.skin_max_mm {
            (s.skin_max_mm, s.skin_worst_shape) = (r.skin_max_mm, r.code.clone());
        }
        if r.skin_max_mm > SKIN_MAX_TARGET_MM {
            s.skin_over_target.push((r.code.clone(), r.skin_max_mm));
        }
    }
    for s in &mut out {
        s.crossing_pieces
            .sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    }
    out
}

/// [`summary`] as a Markdown table.
pub fn summary_table(rows: &[ShapeRow]) -> String {
    let over_target = format!("shapes over {SKIN_MAX_TARGET_MM} mm");
    let mut t = Table::new(
        &[
            "face",
            "contact",
            "converged",
            "skin max (mm), worst shape",
            &over_target,
            "lining mean, worst (mm)",
            "shapes crossing (pairs)",
            "crossings by pieces",
            "shapes creasing beyond the rig (edges)",
        ],
        "llrlllrlr",
    );
    let list = |items: Vec<String>| {
        if items.is_empty() {
            "none".to_string()
        } else {
            items.join(", ")
        }
    };
    for s in summary(rows) {
        t.row([
            s.face,
            if s.contact { "on" } else { "off" }.to_string(),
            format!("{} of {}", s.converged, s.shapes),
            format!("{:.2}, {}", s.skin_max_mm, s.skin_worst_shape),
            list(
                s.skin_over_target
                    .iter()
                    .map(|(c, m)| format!("{c} {m:.1}"))
                    .collect(),
            ),
            format!("{:.2}, {}", s.lining_mean_mm, s.lining_worst_shape),
            format!("{} ({})", s.crossing_shapes, s.crossings),
            list(
                s.crossing_pieces
                    .iter()
                    .map(|(p, n)| format!("{p} {n}"))
                    .collect(),
            ),
            format!("{} ({})", s.creasing_shapes, s.creases_beyond_rig),
        ]);
    }
    t.to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(face: &str, code: &str, skin: f64, lining: f64, converged: bool) -> ShapeRow {
        ShapeRow {
            face: face.into(),
            code: code.into(),
            contact: true,
            termination: Some(if converged {
                Termination::Converged
            } else {
                Termination::IterationCap
            }),
            error: None,
            iterations: 10,
            residual: 0.0,
            ms: 1.0,
            skin_max_mm: skin,
            skin_p95_mm: skin / 2.0,
            skin_mean_mm: skin / 4.0,
            skin_worst_vertex: 7,
            lining_mean_mm: lining,
            lining_max_mm: lining * 3.0,
            crossings: 0,
            crossing_pieces: Vec::new(),
            rig_crossings: 0,
            rig_crossing_pieces: Vec::new(),
            creases: 0,
            crease_pieces: Vec::new(),
            crease_worst_vertex: None,
            rig_creases: 0,
            creases_beyond_rig: 0,
            lining: None,
        }
    }

    /// The summary leads with the worst converged shape, leaves mouthClose's skin out (the
    /// rig presses the lips through each other there), lists the shapes over the target and
    /// sums the crossings by pieces, per face.
    #[test]
    fn the_summary_leads_with_the_worst_converged_physical_shape() {
        let mut crossing = row("a", "jawOpen", 3.0, 1.2, true);
        crossing.crossings = 5;
        crossing.crossing_pieces = vec![
            ("lower teeth / mouth socket".into(), 4),
            ("face skin / face skin".into(), 1),
        ];
        (
            crossing.creases,
            crossing.rig_creases,
            crossing.creases_beyond_rig,
        ) = (10, 2, 8);
        let mut smile = row("a", "mouthSmile_L", 1.5, 0.4, true);
        smile.crossings = 2;
        smile.crossing_pieces = vec![("lower teeth / mouth socket".into(), 2)];
        // Creasing only where the rig does, and an unconverged crease: neither counts.
        (smile.creases, smile.rig_creases) = (3, 3);
        let mut pucker = row("a", "mouthPucker", 12.0, 3.0, false);
        (pucker.creases, pucker.creases_beyond_rig) = (50, 50);
        let rows = vec![
            crossing,
            smile,
            row("a", "mouthClose", 9.0, 2.0, true),
            pucker,
            row("b", "jawOpen", 1.0, 0.3, true),
        ];
        let s = summary(&rows);
        assert_eq!(s.len(), 2);
        let a = &s[0];
        assert_eq!((a.shapes, a.converged), (4, 3));
        assert_eq!(
            (a.skin_max_mm, a.skin_worst_shape.as_str()),
            (3.0, "jawOpen")
        );
        assert_eq!(a.skin_over_target, vec![("jawOpen".to_string(), 3.0)]);
        assert_eq!(
            (a.lining_mean_mm, a.lining_worst_shape.as_str()),
            (2.0, "mouthClose")
        );
        assert_eq!((a.crossing_shapes, a.crossings), (2, 7));
        assert_eq!(
            a.crossing_pieces,
            vec![
                ("lower teeth / mouth socket".to_string(), 6),
                ("face skin / face skin".to_string(), 1)
            ]
        );
        assert_eq!((a.creasing_shapes, a.creases_beyond_rig), (1, 8));
        assert!(s[1].skin_over_target.is_empty());
        let table = summary_table(&rows);
        assert!(table.contains("| shapes over 2 mm |"), "{table}");
        assert!(
            table.contains(
                "| a | on | 3 of 4 | 3.00, jawOpen | jawOpen 3.0 | 2.00, mouthClose | 2 (7) |"
            ),
            "{table}"
        );
        assert!(table.contains("| 1 (8) |"), "{table}");
        assert!(
            table.contains("| b | on | 1 of 1 | 1.00, jawOpen | none |"),
            "{table}"
        );
    }
}
