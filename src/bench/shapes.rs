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
//! - whether the solve converged, its iterations, residual and time.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::contact::surface::FaceContact;
use crate::drive::{ActuationModel, Codes};
use crate::model::audit::CrossingAudit;
use crate::model::contact_region::FaceContactSettings;
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
}

impl ShapeRow {
    pub fn converged(&self) -> bool {
        self.termination == Some(Termination::Converged)
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
/// measures it against `rig` (module doc). `progress(done, total)` after each.
pub fn measure(
    rig: &FaceRig,
    face: &MeasuredFace,
    codes: &[(String, ExpressionCode)],
    settings: &SolveSettings,
    progress: &dyn Fn(usize, usize),
) -> Result<Vec<ShapeRow>, SimError> {
    let model = face.model;
    let mut sim = model.simulator()?;
    if settings.contact {
        let contact = FaceContact::new(model, &FaceContactSettings::default())
            .map_err(|e| SimError::Setup(format!("contact surfaces of {}: {e}", face.name)))?;
        sim.set_contact(contact)?;
    }
    let audit = CrossingAudit::new(model);
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
        };
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
                let posed = model.render_positions(state.flat_positions(), &bones);
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
            "converged",
            "iterations",
            "ms",
        ],
        "lllrrrrrrrrlrr",
    );
    for r in rows {
        let solve = match (&r.termination, &r.error) {
            (Some(Termination::Converged), _) => "yes".to_string(),
            (Some(t), _) => format!("**no ({t:?}, residual {:.1e})**", r.residual),
            (None, Some(e)) => format!("**failed: {e}**"),
            (None, None) => "?".to_string(),
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
            solve,
            r.iterations.to_string(),
            format!("{:.0}", r.ms),
        ]);
    }
    t.to_string()
}
