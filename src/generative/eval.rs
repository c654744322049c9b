//! Held-out evaluation: simulate codes no training pose used with each actuation model and
//! measure the render skin against the rig's target.
//!
//! Per face and model, every held-out expression code (in the face's default style) is turned
//! into actuations and a jaw pose, solved from rest at the final preset without contact, and
//! the embedded render vertices (skin and lips: what the tissue carries; rigid teeth and the
//! skull-bound parts are left out) are compared with [`crate::model::target`]. Errors are
//! pooled over the vertices of all solved poses (mean, 95th percentile, max, in mm); solves
//! that fail (e.g. folded elements) are counted, not hidden.

use serde::{Deserialize, Serialize};

use super::GenerativeError;
use crate::drive::{ActuationModel, Codes};
use crate::mapping::warp::quantile;
use crate::model::FaceModel;
use crate::rig::{ExpressionCode, FaceRig, StyleCode};
use crate::sim::Quality;

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
    pub iterations: usize,
}

/// The whole evaluation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub codes: Vec<ExpressionCode>,
    pub rows: Vec<EvalRow>,
    pub poses: Vec<EvalPose>,
}

/// A face to evaluate: the model, its default style and the actuation models to compare
/// (name, model).
pub struct EvalFace<'a> {
    pub face: &'a FaceModel,
    pub style: StyleCode,
    pub models: Vec<(&'a str, &'a dyn ActuationModel)>,
}

impl EvalReport {
    /// The table as Markdown.
    pub fn table(&self) -> String {
        let mut s = String::from(
            "| face | model | poses solved | vertex error mean (mm) | p95 (mm) | max (mm) |\n|---|---|---:|---:|---:|---:|\n",
        );
        let mm = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
        for r in &self.rows {
            s.push_str(&format!(
                "| {} | {} | {}/{} | {} | {} | {} |\n",
                r.face,
                r.model,
                r.poses - r.failed,
                r.poses,
                mm(r.mean_mm),
                mm(r.p95_mm),
                mm(r.max_mm)
            ));
        }
        s
    }

    /// The rows as CSV.
    pub fn csv(&self) -> String {
        let mut s = String::from("face,model,poses,failed,mean_mm,p95_mm,max_mm\n");
        let mm = |v: Option<f64>| v.map_or(String::new(), |v| v.to_string());
        for r in &self.rows {
            s.push_str(&format!(
                "{},{},{},{},{},{},{}\n",
                r.face,
                r.model,
                r.poses,
                r.failed,
                mm(r.mean_mm),
                mm(r.p95_mm),
                mm(r.max_mm)
            ));
        }
        s
    }
}

/// Evaluates every face's models on `codes` (module docs).
pub fn evaluate(
    rig: &FaceRig,
    faces: &[EvalFace<'_>],
    codes: &[ExpressionCode],
    progress: &dyn Fn(&str),
) -> Result<EvalReport, GenerativeError> {
    let mut rows = Vec::new();
    let mut poses = Vec::new();
    let mut settings = Quality::Final.settings();
    settings.contact = false;
    for f in faces {
        let face = f.face;
        let sim = face.simulator()?;
        let embedded: Vec<usize> = face
            .render
            .bindings
            .iter()
            .enumerate()
            .filter(|(_, b)| b.element().is_some())
            .map(|(i, _)| i)
            .collect();
        let targets = codes
            .iter()
            .map(|&expression| {
                crate::model::target(
                    rig,
                    face,
                    &Codes {
                        expression,
                        style: f.style,
                    },
                )
                .map_err(|source| GenerativeError::Target {
                    face: face.name.clone(),
                    source,
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        for &(name, model) in &f.models {
            progress(&format!("{} with {name}", face.name));
            let mut errors = Vec::new();
            let mut failed = 0;
            for (c, (&expression, target)) in codes.iter().zip(&targets).enumerate() {
                let codes = Codes {
                    expression,
                    style: f.style,
                };
                let mut pose = EvalPose {
                    face: face.name.clone(),
                    model: name.to_string(),
                    code: c,
                    error: None,
                    mean_mm: None,
                    max_mm: None,
                    iterations: 0,
                };
                let solved = model
                    .actuate(&codes)
                    .map_err(|e| e.to_string())
                    .and_then(|a| {
                        let mut state = sim.rest_state();
                        sim.solve(&a.tensors, &a.bones(), &mut state, &settings)
                            .map(|stats| (a, state, stats))
                            .map_err(|e| e.to_string())
                    });
                match solved {
                    Ok((a, state, stats)) => {
                        let render = face.render_positions(state.flat_positions(), &a.bones());
                        let e: Vec<f64> = embedded
                            .iter()
                            .map(|&v| MM * (render[v] - target.render[v]).norm())
                            .collect();
                        pose.mean_mm = Some(e.iter().sum::<f64>() / e.len().max(1) as f64);
                        pose.max_mm = Some(e.iter().copied().fold(0.0, f64::max));
                        pose.iterations = stats.iterations;
                        errors.extend(e);
                    }
                    Err(msg) => {
                        failed += 1;
                        pose.error = Some(msg);
                    }
                }
                poses.push(pose);
            }
            let (mean, p95, max) = if errors.is_empty() {
                (None, None, None)
            } else {
                (
                    Some(errors.iter().sum::<f64>() / errors.len() as f64),
                    Some(quantile(&errors, 0.95)),
                    Some(errors.iter().copied().fold(0.0, f64::max)),
                )
            };
            rows.push(EvalRow {
                face: face.name.clone(),
                model: name.to_string(),
                poses: codes.len(),
                failed,
                mean_mm: mean,
                p95_mm: p95,
                max_mm: max,
            });
        }
    }
    Ok(EvalReport {
        codes: codes.to_vec(),
        rows,
        poses,
    })
}
