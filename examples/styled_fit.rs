//! Probe (issue 21): jawOpen at 1 in each sample face's default style, posed by the basis's
//! log-Euclidean blend and by an actuation fitted to that styled target directly (the
//! per-code upper bound), both measured against the rig as `bench shapes` does.
use facesim::bench::shapes::{MeasuredFace, measure};
use facesim::drive::{Actuation, ActuationModel, Codes, DriveError};
use facesim::model::fit::{ActuationFitter, FitSettings};
use facesim::model::target;
use facesim::rig::{ExpressionCode, FaceRig};
use facesim::sample::{SAMPLE_DIR, Sample};
use facesim::sim::{Quality, SolveSettings};

struct Fixed(Actuation, usize);
impl ActuationModel for Fixed {
    fn element_count(&self) -> usize {
        self.1
    }
    fn actuate(&self, _: &Codes) -> Result<Actuation, DriveError> {
        Ok(self.0.clone())
    }
}

fn main() {
    let rig = FaceRig::load(facesim::rig::DEFAULT_RIG_DIR).unwrap();
    let sample = Sample::load(SAMPLE_DIR).unwrap();
    let shape = std::env::args().nth(1).unwrap_or("jawOpen".into());
    let code = vec![(shape.clone(), ExpressionCode::single(&shape, 1.0).unwrap())];
    let settings = SolveSettings {
        contact: false,
        ..Quality::Final.settings()
    };
    for face in &sample.faces {
        let codes = Codes {
            expression: code[0].1,
            style: face.style,
        };
        let goal = target(&rig, &face.model, &codes).unwrap();
        let fitter = ActuationFitter::new(&face.model, FitSettings::default()).unwrap();
        let fit = fitter.fit(&goal, None).unwrap();
        let direct = Fixed(
            Actuation {
                tensors: fit.tensors.clone(),
                jaw: fit.jaw,
            },
            face.model.mesh.element_count(),
        );
        for (label, actuation) in [
            ("basis blend", face.actuation.as_ref()),
            ("direct fit", &direct as &dyn ActuationModel),
        ] {
            let measured = MeasuredFace {
                name: &face.name,
                model: &face.model,
                actuation,
                style: face.style,
            };
            let rows = measure(&rig, &measured, &code, &settings, &|_, _| {}).unwrap();
            let r = &rows[0];
            println!(
                "{} {:?} {shape} {label}: skin max {:.2} mm (rig vertex {}), p95 {:.2}, mean {:.2}; lining mean {:.2}; {:?}; fit skin max {:.2} mm",
                face.name,
                face.style.0,
                r.skin_max_mm,
                r.skin_worst_vertex,
                r.skin_p95_mm,
                r.skin_mean_mm,
                r.lining_mean_mm,
                r.termination,
                10.0 * fit.skin_max
            );
        }
    }
}
