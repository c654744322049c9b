//! Probe (issue 21): a slider at weight 1 (or `WEIGHT`) in each sample face's default style,
//! posed (final, contact off, from rest) by four actuations and measured against the rig as
//! `bench shapes` does:
//! - the face's basis (the blend `exp(Σ wₖ·log Aₖ)` of shapes fitted at weight 1 when the
//!   probe was written; since the basis also fits each slider in the face's own style, the
//!   same as the direct fit at weight 1);
//! - a two-weight blend: shapes the style pushes past 1 interpolate `log A` between their
//!   fits at 1 and at `W2` (default 1.5) instead of extrapolating the fit at 1;
//! - jaw correctives: the blend plus `w_jawOpen·wₖ·(log A(jawOpen, k) − log A_jawOpen − log Aₖ)`
//!   for every shape `k` posed with jawOpen, each pair fitted at weights (1, 1);
//! - an actuation fitted to the styled target directly (the per-code upper bound).
//!
//! For the direct fit it also prints the worst vertex at the fit's own positions (what the
//! bindings alone leave) and how far forward solves of the fitted actuation land from the
//! fit, from rest and along a path of intermediate actuations.
//!
//! `cargo run --release -p facesim --example styled_fit [SHAPE]`, with `FACE=NAME` to measure
//! one face, `MIN_STRETCH` for the fit's clamp (default 0.3) and `TOL` for the solves'.
use facesim::bench::shapes::{MeasuredFace, measure};
use facesim::drive::{Actuation, ActuationModel, Codes, DriveError};
use facesim::model::fit::{ActuationFitter, FitSettings};
use facesim::model::{shape_target, target};
use facesim::rig::{ExpressionCode, FaceRig};
use facesim::sample::{SAMPLE_DIR, Sample};
use facesim::sim::{Quality, RigidMotion, SolveSettings, SymTensor};
use nalgebra::{Matrix3, SymmetricEigen};

struct Fixed(Actuation, usize);
impl ActuationModel for Fixed {
    fn element_count(&self) -> usize {
        self.1
    }
    fn actuate(&self, _: &Codes) -> Result<Actuation, DriveError> {
        Ok(self.0.clone())
    }
}
fn log_m(t: &SymTensor) -> Matrix3<f64> {
    let e = SymmetricEigen::new(t.to_matrix());
    e.eigenvectors
        * Matrix3::from_diagonal(&e.eigenvalues.map(f64::ln))
        * e.eigenvectors.transpose()
}
fn exp_m(m: &Matrix3<f64>) -> SymTensor {
    let e = SymmetricEigen::new(*m);
    SymTensor::from_matrix(
        &(e.eigenvectors
            * Matrix3::from_diagonal(&e.eigenvalues.map(f64::exp))
            * e.eigenvectors.transpose()),
    )
}

fn main() {
    let rig = FaceRig::load(facesim::rig::DEFAULT_RIG_DIR).unwrap();
    let sample = Sample::load(SAMPLE_DIR).unwrap();
    let shape = std::env::args().nth(1).unwrap_or("jawOpen".into());
    let w2: f64 = std::env::var("W2")
        .ok()
        .map(|w| w.parse().unwrap())
        .unwrap_or(1.5);
    let weight: f64 = std::env::var("WEIGHT")
        .ok()
        .map(|w| w.parse().unwrap())
        .unwrap_or(1.0);
    let code = vec![(
        shape.clone(),
        ExpressionCode::single(&shape, weight).unwrap(),
    )];
    let settings = SolveSettings {
        contact: false,
        tolerance: std::env::var("TOL")
            .ok()
            .map_or(Quality::Final.settings().tolerance, |v| v.parse().unwrap()),
        max_iterations: 5000,
        ..Quality::Final.settings()
    };
    for face in sample
        .faces
        .iter()
        .filter(|f| std::env::var("FACE").map_or(true, |n| n == f.name))
    {
        let codes = Codes {
            expression: code[0].1,
            style: face.style,
        };
        let fit_settings = FitSettings {
            min_stretch: std::env::var("MIN_STRETCH")
                .ok()
                .map_or(FitSettings::default().min_stretch, |v| v.parse().unwrap()),
            ..FitSettings::default()
        };
        let fitter = ActuationFitter::new(&face.model, fit_settings).unwrap();
        let n = face.model.mesh.element_count();
        let weights = face.style.shape_weights(&codes.expression);
        println!("{} weights {:?}", face.name, weights);
        let mut logs = vec![Matrix3::<f64>::zeros(); n];
        let mut jaw = [0.0; 6];
        for &(name, w) in &weights {
            let f1 = fitter
                .fit(
                    &shape_target(&rig, &face.model, &[(name, 1.0)]).unwrap(),
                    None,
                )
                .unwrap();
            let (l1, j1): (Vec<_>, _) = (f1.tensors.iter().map(log_m).collect(), f1.jaw.params());
            let (l2, j2) = if w > 1.0 {
                let f2 = fitter
                    .fit(
                        &shape_target(&rig, &face.model, &[(name, w2)]).unwrap(),
                        None,
                    )
                    .unwrap();
                (
                    Some(f2.tensors.iter().map(log_m).collect::<Vec<_>>()),
                    Some(f2.jaw.params()),
                )
            } else {
                (None, None)
            };
            for e in 0..n {
                logs[e] += match &l2 {
                    Some(l2) => l1[e] + (l2[e] - l1[e]) * ((w - 1.0) / (w2 - 1.0)),
                    None => l1[e] * w,
                };
            }
            for k in 0..6 {
                jaw[k] += match j2 {
                    Some(j2) => j1[k] + (j2[k] - j1[k]) * ((w - 1.0) / (w2 - 1.0)),
                    None => w * j1[k],
                };
            }
        }
        // Pairwise jaw correctives: C_k = L(jawOpen=1, k=1) - L_jawOpen - L_k, weighted w_jO * w_k.
        let mut corr_logs = vec![Matrix3::<f64>::zeros(); n];
        let mut corr_jaw = [0.0; 6];
        let single = |name: &'static str| {
            let f = fitter
                .fit(
                    &shape_target(&rig, &face.model, &[(name, 1.0)]).unwrap(),
                    None,
                )
                .unwrap();
            (
                f.tensors.iter().map(log_m).collect::<Vec<_>>(),
                f.jaw.params(),
            )
        };
        let (ljo, jjo) = single("jawOpen");
        let wjo = weights
            .iter()
            .find(|p| p.0 == "jawOpen")
            .map_or(0.0, |p| p.1);
        for &(name, w) in &weights {
            let (lk, jk) = single(name);
            for e in 0..n {
                corr_logs[e] += lk[e] * w;
            }
            for q in 0..6 {
                corr_jaw[q] += w * jk[q];
            }
            if name != "jawOpen" && wjo != 0.0 {
                let f = fitter
                    .fit(
                        &shape_target(&rig, &face.model, &[("jawOpen", 1.0), (name, 1.0)]).unwrap(),
                        None,
                    )
                    .unwrap();
                let pair: Vec<_> = f.tensors.iter().map(log_m).collect();
                let pj = f.jaw.params();
                for e in 0..n {
                    corr_logs[e] += (pair[e] - ljo[e] - lk[e]) * (wjo * w);
                }
                for q in 0..6 {
                    corr_jaw[q] += (pj[q] - jjo[q] - jk[q]) * (wjo * w);
                }
            }
        }
        let corrective = Fixed(
            Actuation {
                tensors: corr_logs.iter().map(exp_m).collect(),
                jaw: RigidMotion::from_params(corr_jaw),
            },
            n,
        );
        let two = Fixed(
            Actuation {
                tensors: logs.iter().map(exp_m).collect(),
                jaw: RigidMotion::from_params(jaw),
            },
            n,
        );
        let goal = target(&rig, &face.model, &codes).unwrap();
        let fit = fitter.fit(&goal, None).unwrap();
        let direct = Fixed(
            Actuation {
                tensors: fit.tensors.clone(),
                jaw: fit.jaw,
            },
            n,
        );
        for (label, actuation) in [
            ("basis", face.actuation.as_ref()),
            ("two-weight", &two as &dyn ActuationModel),
            ("jaw correctives", &corrective),
            ("direct fit", &direct),
        ] {
            let measured = MeasuredFace {
                name: &face.name,
                model: &face.model,
                actuation,
                style: face.style,
            };
            let r = &measure(&rig, &measured, &code, &settings, false, &|_, _| {}).unwrap()[0];
            println!(
                "{} {shape}@{weight} {label}: skin max {:.2} mm (rig vertex {}), p95 {:.2}; lining mean {:.2}; {:?}",
                face.name,
                r.skin_max_mm,
                r.skin_worst_vertex,
                r.skin_p95_mm,
                r.lining_mean_mm,
                r.termination
            );
            if label == "direct fit" {
                // The same render vertex at the fit's own positions (no forward solve): what
                // the bindings alone leave.
                let bones = direct.0.bones();
                let at_fit = face.model.render_positions(&fit.positions, &bones);
                let i = face
                    .model
                    .render
                    .rig_vertices
                    .iter()
                    .position(|&v| v == r.skin_worst_vertex)
                    .unwrap();
                println!(
                    "{} {shape}@{weight} the fit's own positions: {:.2} mm at rig vertex {} ({} clamped elements)",
                    face.name,
                    10.0 * (at_fit[i] - goal.render[i]).norm(),
                    r.skin_worst_vertex,
                    fit.clamped
                );
                // Forward solves of the fitted actuation: from rest, and along a path of
                // intermediate actuations exp(t·log Â), t = 0.25 … 1, each from the last.
                let sim = face.model.simulator().unwrap();
                let logs: Vec<Matrix3<f64>> = fit.tensors.iter().map(log_m).collect();
                let gap = |x: &[f64]| {
                    x.chunks_exact(3)
                        .zip(fit.positions.chunks_exact(3))
                        .map(|(a, b)| {
                            10.0 * ((a[0] - b[0]).powi(2)
                                + (a[1] - b[1]).powi(2)
                                + (a[2] - b[2]).powi(2))
                            .sqrt()
                        })
                        .fold(0.0, f64::max)
                };
                let mut state = sim.rest_state();
                let stats = sim
                    .solve(&fit.tensors, &bones, &mut state, &settings)
                    .unwrap();
                println!(
                    "  from rest: {} iterations, farthest simulation vertex from the fit {:.2} mm",
                    stats.iterations,
                    gap(state.flat_positions())
                );
                let mut state = sim.rest_state();
                for t in [0.25, 0.5, 0.75, 1.0] {
                    let tensors: Vec<SymTensor> = logs.iter().map(|l| exp_m(&(l * t))).collect();
                    let jaw = RigidMotion::from_params(fit.jaw.params().map(|p| p * t));
                    let a = Actuation { tensors, jaw };
                    sim.solve(&a.tensors, &a.bones(), &mut state, &settings)
                        .unwrap();
                }
                println!(
                    "  along the path: farthest simulation vertex from the fit {:.2} mm",
                    gap(state.flat_positions())
                );
            }
        }
    }
}
