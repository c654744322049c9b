//! Held-out evaluation: codes no training pose used, posed by each model, measured against
//! the rig's target and for volume and lip crossings.
//!
//! Per face and model, every held-out expression code (in the face's default style) is posed:
//! a physics model ([`EvalModel::Physics`]: actuations and a jaw) is solved from rest at the
//! final preset without contact; the displacement baseline ([`EvalModel::Displacement`]) is
//! read out directly. Then on the same footing for both:
//! - vertex error: the embedded render vertices (skin and lips: what the tissue carries; rigid
//!   teeth and the skull-bound parts are left out) against [`crate::model::target`], pooled
//!   over the vertices of all posed codes (mean, 95th percentile, max, in mm);
//! - volume ([`VolumeChange`]): mean `|det F − 1|` over the elements of all posed codes, the
//!   tissue's total volume change (mean and largest magnitude over codes), inverted elements;
//! - lip crossings ([`lip_crossings`]): new edge–triangle crossings of the lips, mouth and
//!   teeth; codes with any, and the total.
//!
//! Style transfer ([`EvalFace::own_style`] set: face B posed in identity A's style): every
//! code is also posed in B's own style, and the *style change* a model makes (its pose in A's
//! style minus its pose in B's) is compared with the rig's (B's target in A's style minus in
//! its own), per embedded vertex ([`StyleRow`]). The vertex error in A's style mixes B's
//! geometry and A's style; this splits them: the own-style error says how well B's geometry is
//! kept, the style-change error and the share of the rig's style change reproduced
//! (`1 − Σ‖δ − δ*‖² / Σ‖δ*‖²`) say how well A's style is.
//!
//! Codes that fail (a physics solve that folds elements, a non-finite output) are counted, not
//! hidden; their metrics are left out of the pooled ones, so rows of models that failed on
//! different codes pool different codes. The common rows pool only the codes every model of
//! the face posed (like for like); the per-code records say which failed.

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use super::GenerativeError;
use super::displacement::DisplacementFace;
use super::metrics::{VolumeChange, lip_crossings, target_crossings};
use crate::contact::surface::FaceContact;
use crate::drive::{ActuationModel, Codes};
use crate::mapping::warp::quantile;
use crate::model::FaceModel;
use crate::model::contact_region::FaceContactSettings;
use crate::rig::{ExpressionCode, FaceRig, StyleCode};
use crate::sequence::Sequence;
use crate::sim::{BonePose, Quality, Simulator};
use crate::table::Table;

/// Millimetres per model unit (cm).
const MM: f64 = 10.0;

/// One face and one model over all held-out codes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalRow {
    pub face: String,
    pub model: String,
    pub poses: usize,
    pub failed: usize,
    /// `None` when no pose solved.
    pub mean_mm: Option<f64>,
    pub p95_mm: Option<f64>,
    pub max_mm: Option<f64>,
    /// Where the largest error is: the rig vertex index and the held-out code.
    #[serde(default)]
    pub worst_vertex: Option<u32>,
    #[serde(default)]
    pub worst_code: Option<usize>,
    /// Mean `|det F − 1|` over the elements of the posed codes.
    pub mean_abs_det_change: Option<f64>,
    /// Mean and largest `|ΣV(x)/ΣV(X) − 1|` over the posed codes.
    pub mean_abs_volume_change: Option<f64>,
    pub max_abs_volume_change: Option<f64>,
    /// Inverted elements summed over the posed codes.
    pub inverted: usize,
    /// Posed codes with lip crossings, and the crossings summed over them.
    pub crossing_poses: usize,
    pub crossings: usize,
}

/// One face, model and code.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalPose {
    pub face: String,
    pub model: String,
    pub code: usize,
    /// `None` when the pose solved.
    pub error: Option<String>,
    pub mean_mm: Option<f64>,
    pub max_mm: Option<f64>,
    /// Solver iterations (0 for the displacement baseline).
    pub iterations: usize,
    pub volume: Option<VolumeChange>,
    pub crossings: Option<usize>,
}

/// The rig's own targets for the held-out codes: how many of them already have crossing
/// lips (the rig blends shapes linearly and knows nothing of contact), the reference for the
/// models' crossing counts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TargetCrossings {
    pub face: String,
    pub poses: usize,
    pub crossing_poses: usize,
    pub crossings: usize,
}

/// One face and model in another identity's style (style transfer, module docs), pooled over
/// the codes it posed in both styles.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StyleRow {
    pub face: String,
    pub model: String,
    /// Codes posed in both styles.
    pub poses: usize,
    /// Mean vertex error (mm) in the face's own style: how well its geometry is kept.
    pub own_style_mean_mm: Option<f64>,
    /// Mean length (mm) of the rig's style change `δ*` per vertex: the scale of what is
    /// transferred.
    pub rig_style_change_mm: Option<f64>,
    /// Mean `‖δ − δ*‖` (mm) per vertex: the error of the model's style change.
    pub style_change_error_mm: Option<f64>,
    /// `1 − Σ‖δ − δ*‖² / Σ‖δ*‖²`: 1 reproduces the rig's style change exactly, 0 is no better
    /// than ignoring the style.
    pub style_kept: Option<f64>,
}

/// The whole evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub codes: Vec<ExpressionCode>,
    /// Whether the physics models were solved with lip and teeth contact.
    pub contact: bool,
    /// Per face and model, over every code it posed.
    pub rows: Vec<EvalRow>,
    /// The same over only the codes every model of the face posed (the like-for-like
    /// comparison when some model failed on some code).
    pub common_rows: Vec<EvalRow>,
    pub poses: Vec<EvalPose>,
    pub targets: Vec<TargetCrossings>,
    /// Per face and model, for faces posed in another identity's style (else empty).
    pub style_rows: Vec<StyleRow>,
}

/// How a model poses a face.
#[derive(Clone, Copy)]
pub enum EvalModel<'a> {
    /// Actuations and a jaw, solved (no contact).
    Physics(&'a dyn ActuationModel),
    /// Vertex positions straight from the displacement network.
    Displacement(&'a DisplacementFace),
}

/// A face to evaluate: the model, its default style and the models to compare (name, model).
pub struct EvalFace<'a> {
    pub face: &'a FaceModel,
    pub style: StyleCode,
    /// The face's own style when `style` is another identity's (style transfer): each code is
    /// then also posed in it and the style change measured ([`StyleRow`]).
    pub own_style: Option<StyleCode>,
    pub models: Vec<(&'a str, EvalModel<'a>)>,
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".to_string(), |v| format!("{v:.digits$}"))
}

impl EvalReport {
    /// The table as Markdown (over every posed code).
    pub fn table(&self) -> String {
        Self::markdown(&self.rows)
    }

    /// The table over the codes every model of a face posed.
    pub fn common_table(&self) -> String {
        Self::markdown(&self.common_rows)
    }

    fn markdown(rows: &[EvalRow]) -> String {
        let mut t = Table::new(
            &[
                "face",
                "model",
                "poses solved",
                "vertex error max (mm)",
                "worst (rig vertex, code)",
                "p95 (mm)",
                "mean (mm)",
                "mean \\|det F − 1\\|",
                "volume change mean / max (%)",
                "inverted elements",
                "poses with lip crossings (crossings)",
            ],
            "llrrlrrrrrr",
        );
        let pct = |v: Option<f64>| opt(v.map(|v| 100.0 * v), 2);
        for r in rows {
            t.row([
                r.face.clone(),
                r.model.clone(),
                format!("{}/{}", r.poses - r.failed, r.poses),
                opt(r.max_mm, 3),
                match (r.worst_vertex, r.worst_code) {
                    (Some(v), Some(c)) => format!("{v}, {c}"),
                    _ => "-".into(),
                },
                opt(r.p95_mm, 3),
                opt(r.mean_mm, 3),
                opt(r.mean_abs_det_change, 4),
                format!(
                    "{} / {}",
                    pct(r.mean_abs_volume_change),
                    pct(r.max_abs_volume_change)
                ),
                r.inverted.to_string(),
                format!("{} ({})", r.crossing_poses, r.crossings),
            ]);
        }
        t.to_string()
    }

    /// The rig targets' crossings as Markdown.
    pub fn target_table(&self) -> String {
        let mut t = Table::new(
            &["face", "rig targets with lip crossings (crossings)"],
            "lr",
        );
        for r in &self.targets {
            t.row([
                r.face.clone(),
                format!("{}/{} ({})", r.crossing_poses, r.poses, r.crossings),
            ]);
        }
        t.to_string()
    }

    /// The style-transfer rows as Markdown (empty without any).
    pub fn style_table(&self) -> String {
        if self.style_rows.is_empty() {
            return String::new();
        }
        let mut t = Table::new(
            &[
                "face",
                "model",
                "codes posed in both styles",
                "own-style error (mm)",
                "rig's style change (mm)",
                "style-change error (mm)",
                "style kept",
            ],
            "llrrrrr",
        );
        for r in &self.style_rows {
            t.row([
                r.face.clone(),
                r.model.clone(),
                r.poses.to_string(),
                opt(r.own_style_mean_mm, 3),
                opt(r.rig_style_change_mm, 3),
                opt(r.style_change_error_mm, 3),
                opt(r.style_kept, 3),
            ]);
        }
        t.to_string()
    }

    /// The rows as CSV.
    pub fn csv(&self) -> String {
        let mut s = String::from(
            "face,model,poses,failed,mean_mm,p95_mm,max_mm,mean_abs_det_change,mean_abs_volume_change,max_abs_volume_change,inverted,crossing_poses,crossings\n",
        );
        let v = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
        for r in &self.rows {
            s.push_str(&format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                r.face,
                r.model,
                r.poses,
                r.failed,
                v(r.mean_mm),
                v(r.p95_mm),
                v(r.max_mm),
                v(r.mean_abs_det_change),
                v(r.mean_abs_volume_change),
                v(r.max_abs_volume_change),
                r.inverted,
                r.crossing_poses,
                r.crossings
            ));
        }
        s
    }
}

/// Simulation positions and bones of one code with one model, or why it failed.
fn pose(
    model: EvalModel<'_>,
    sim: &Simulator,
    contact: bool,
    codes: &Codes,
) -> Result<(Vec<f64>, BonePose, usize), String> {
    match model {
        EvalModel::Physics(m) => {
            let mut settings = Quality::Final.settings();
            settings.contact = contact;
            let a = m.actuate(codes).map_err(|e| e.to_string())?;
            // Every code from rest: the error belongs to the code, not to the codes before it.
            let mut from_rest = Sequence::new(sim);
            let stats = from_rest
                .solve(&a.tensors, &a.bones(), &settings)
                .map_err(|e| e.to_string())?;
            let positions = from_rest.state().flat_positions().to_vec();
            Ok((positions, a.bones(), stats.iterations))
        }
        EvalModel::Displacement(d) => {
            let p = d.pose(codes).map_err(|e| e.to_string())?;
            Ok((p.positions, p.bones, 0))
        }
    }
}

/// Evaluates every face's models on `codes` (module docs); with `contact_on`, the physics
/// models are solved with lip and teeth contact (IPC), which costs tens of times more.
pub fn evaluate(
    rig: &FaceRig,
    faces: &[EvalFace<'_>],
    codes: &[ExpressionCode],
    contact_on: bool,
    progress: &dyn Fn(&str),
) -> Result<EvalReport, GenerativeError> {
    let mut rows = Vec::new();
    let mut poses = Vec::new();
    let mut target_rows = Vec::new();
    let mut common_rows = Vec::new();
    let mut style_rows = Vec::new();
    for f in faces {
        let face = f.face;
        let mut sim = face.simulator()?;
        let contact = FaceContact::new(face, &FaceContactSettings::default()).map_err(|e| {
            GenerativeError::Config(format!("contact surfaces of {}: {e}", face.name))
        })?;
        if contact_on {
            sim.set_contact(contact.clone())?;
        }
        let embedded: Vec<usize> = face
            .render
            .bindings
            .iter()
            .enumerate()
            .filter(|(_, b)| b.element().is_some())
            .map(|(i, _)| i)
            .collect();
        let targets_in = |style: StyleCode| {
            codes
                .iter()
                .map(|&expression| {
                    crate::model::target(rig, face, &Codes { expression, style }).map_err(
                        |source| GenerativeError::Target {
                            face: face.name.clone(),
                            source,
                        },
                    )
                })
                .collect::<Result<Vec<_>, _>>()
        };
        let targets = targets_in(f.style)?;
        let own_targets = f.own_style.map(targets_in).transpose()?;
        let mut target_row = TargetCrossings {
            face: face.name.clone(),
            poses: targets.len(),
            crossing_poses: 0,
            crossings: 0,
        };
        for t in &targets {
            let n = target_crossings(&contact, &t.render);
            target_row.crossing_poses += usize::from(n > 0);
            target_row.crossings += n;
        }
        target_rows.push(target_row);
        // Per model, per code: the vertex errors, volume and crossings of a posed code.
        let mut results: Vec<Vec<Option<Posed>>> = Vec::new();
        for &(name, model) in &f.models {
            progress(&format!("{} with {name}", face.name));
            let mut per_code = Vec::new();
            let mut style_samples = Vec::new();
            for (c, (&expression, target)) in codes.iter().zip(&targets).enumerate() {
                let codes = Codes {
                    expression,
                    style: f.style,
                };
                let mut record = EvalPose {
                    face: face.name.clone(),
                    model: name.to_string(),
                    code: c,
                    error: None,
                    mean_mm: None,
                    max_mm: None,
                    iterations: 0,
                    volume: None,
                    crossings: None,
                };
                match pose(model, &sim, contact_on, &codes) {
                    Ok((x, bones, iterations)) => {
                        let render = face.render_positions(&x, &bones);
                        let errors: Vec<f64> = embedded
                            .iter()
                            .map(|&v| MM * (render[v] - target.render[v]).norm())
                            .collect();
                        let volume = VolumeChange::of(&face.mesh, &x);
                        let crossings = lip_crossings(&contact, &x, &bones);
                        record.mean_mm =
                            Some(errors.iter().sum::<f64>() / errors.len().max(1) as f64);
                        record.max_mm = Some(errors.iter().copied().fold(0.0, f64::max));
                        record.iterations = iterations;
                        record.volume = Some(volume);
                        record.crossings = Some(crossings);
                        if let (Some(own), Some(own_targets)) = (f.own_style, &own_targets) {
                            let own_codes = Codes {
                                expression,
                                style: own,
                            };
                            style_samples.push(pose(model, &sim, contact_on, &own_codes).ok().map(
                                |(x_own, bones_own, _)| {
                                    StyleSample::of(
                                        &embedded,
                                        [&render, &face.render_positions(&x_own, &bones_own)],
                                        [&target.render, &own_targets[c].render],
                                    )
                                },
                            ));
                        }
                        per_code.push(Some(Posed {
                            errors,
                            volume,
                            crossings,
                        }));
                    }
                    Err(msg) => {
                        record.error = Some(msg);
                        per_code.push(None);
                        style_samples.push(None);
                    }
                }
                poses.push(record);
            }
            results.push(per_code);
            if f.own_style.is_some() {
                style_rows.push(StyleSample::pooled(&face.name, name, &style_samples));
            }
        }
        let common: Vec<bool> = (0..codes.len())
            .map(|c| results.iter().all(|r| r[c].is_some()))
            .collect();
        for (&(name, _), per_code) in f.models.iter().zip(&results) {
            let all = vec![true; codes.len()];
            let rig_of: Vec<u32> = embedded
                .iter()
                .map(|&i| face.render.rig_vertices[i])
                .collect();
            rows.push(pooled_row(
                &face.name,
                name,
                face.mesh.tets.len(),
                &rig_of,
                per_code,
                &all,
            ));
            common_rows.push(pooled_row(
                &face.name,
                name,
                face.mesh.tets.len(),
                &rig_of,
                per_code,
                &common,
            ));
        }
    }
    Ok(EvalReport {
        codes: codes.to_vec(),
        contact: contact_on,
        rows,
        common_rows,
        poses,
        targets: target_rows,
        style_rows,
    })
}

/// One code posed in both styles by one model: per embedded vertex, the error of its style
/// change and the rig's style change (mm), and its error in the own style.
struct StyleSample {
    change_errors: Vec<f64>,
    rig_changes: Vec<f64>,
    own_errors: Vec<f64>,
}

impl StyleSample {
    /// From render positions `[in the other style, in the own style]` of the model and of the
    /// rig's targets.
    fn of(embedded: &[usize], posed: [&[Point3<f64>]; 2], target: [&[Point3<f64>]; 2]) -> Self {
        let mut sample = StyleSample {
            change_errors: Vec::with_capacity(embedded.len()),
            rig_changes: Vec::with_capacity(embedded.len()),
            own_errors: Vec::with_capacity(embedded.len()),
        };
        for &v in embedded {
            let model_change = posed[0][v] - posed[1][v];
            let rig_change = target[0][v] - target[1][v];
            sample
                .change_errors
                .push(MM * (model_change - rig_change).norm());
            sample.rig_changes.push(MM * rig_change.norm());
            sample
                .own_errors
                .push(MM * (posed[1][v] - target[1][v]).norm());
        }
        sample
    }

    /// One model's [`StyleRow`] over the codes it posed in both styles.
    fn pooled(face: &str, model: &str, samples: &[Option<StyleSample>]) -> StyleRow {
        let posed: Vec<&StyleSample> = samples.iter().flatten().collect();
        let all = |f: fn(&StyleSample) -> &[f64]| -> Vec<f64> {
            posed.iter().flat_map(|s| f(s).iter().copied()).collect()
        };
        let (change, rig, own) = (
            all(|s| &s.change_errors),
            all(|s| &s.rig_changes),
            all(|s| &s.own_errors),
        );
        let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        let squares = |v: &[f64]| v.iter().map(|e| e * e).sum::<f64>();
        let rig_squares = squares(&rig);
        StyleRow {
            face: face.to_string(),
            model: model.to_string(),
            poses: posed.len(),
            own_style_mean_mm: mean(&own),
            rig_style_change_mm: mean(&rig),
            style_change_error_mm: mean(&change),
            style_kept: (rig_squares > 0.0).then(|| 1.0 - squares(&change) / rig_squares),
        }
    }
}

/// What one posed code gave.
struct Posed {
    errors: Vec<f64>,
    volume: VolumeChange,
    crossings: usize,
}

/// One model's row pooled over the codes `keep` selects (`poses` counts those, `failed`
/// those of them that did not pose).
fn pooled_row(
    face: &str,
    model: &str,
    elements: usize,
    rig_of: &[u32],
    per_code: &[Option<Posed>],
    keep: &[bool],
) -> EvalRow {
    let mut worst: Option<(f64, u32, usize)> = None;
    for (c, posed) in per_code.iter().enumerate() {
        let Some(p) = posed.as_ref().filter(|_| keep[c]) else {
            continue;
        };
        for (e, &v) in p.errors.iter().zip(rig_of) {
            if worst.is_none_or(|w| *e > w.0) {
                worst = Some((*e, v, c));
            }
        }
    }
    let kept: Vec<&Option<Posed>> = per_code
        .iter()
        .zip(keep)
        .filter(|(_, k)| **k)
        .map(|(p, _)| p)
        .collect();
    let posed: Vec<&Posed> = kept.iter().filter_map(|p| p.as_ref()).collect();
    let errors: Vec<f64> = posed
        .iter()
        .flat_map(|p| p.errors.iter().copied())
        .collect();
    let changes: Vec<f64> = posed.iter().map(|p| p.volume.total_change.abs()).collect();
    let some = |v: f64| (!posed.is_empty()).then_some(v);
    EvalRow {
        face: face.to_string(),
        model: model.to_string(),
        poses: kept.len(),
        failed: kept.len() - posed.len(),
        mean_mm: some(errors.iter().sum::<f64>() / errors.len().max(1) as f64),
        p95_mm: some(quantile(&errors, 0.95)),
        max_mm: some(errors.iter().copied().fold(0.0, f64::max)),
        worst_vertex: worst.map(|w| w.1),
        worst_code: worst.map(|w| w.2),
        mean_abs_det_change: some(
            posed
                .iter()
                .map(|p| p.volume.mean_abs_det_change * elements as f64)
                .sum::<f64>()
                / (elements * posed.len()).max(1) as f64,
        ),
        mean_abs_volume_change: some(changes.iter().sum::<f64>() / changes.len().max(1) as f64),
        max_abs_volume_change: some(changes.iter().copied().fold(0.0, f64::max)),
        inverted: posed.iter().map(|p| p.volume.inverted).sum(),
        crossing_poses: posed.iter().filter(|p| p.crossings > 0).count(),
        crossings: posed.iter().map(|p| p.crossings).sum(),
    }
}
