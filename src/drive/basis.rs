//! The per-shape actuation basis: one fitted actuation field and jaw motion per rig shape,
//! blended by the shape weights of the codes.
//!
//! Tensors blend log-Euclidean, `A = exp(Σₖ wₖ·log Aₖ)`: symmetric positive definite for
//! any weights (also beyond the sliders' ranges and negative ones), exactly `I` when every
//! weight is zero, and `Aₖ` at a single weight of one. Jaw parameters `[θ; t]` blend
//! linearly. This is the per-identity model without a canonical space (each face has its
//! own basis): the editor's driver until the networks are trained, and their baseline.

use nalgebra::{Matrix3, SymmetricEigen};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{Actuation, ActuationModel, Codes, DriveError};
use crate::model::file::{self, FileError, Format};
use crate::model::fit::{ActuationFitter, FitError, FitSettings};
use crate::model::{FaceModel, TargetError, shape_target};
use crate::rig::style::STYLE_SHAPES;
use crate::rig::{ExpressionCode, FaceRig};
use crate::sim::{RigidMotion, SymTensor};

/// The file format of actuation bases; bump `version` when [`ActuationBasis`] changes shape.
pub const BASIS_FORMAT: Format = Format {
    kind: "basis",
    version: 1,
};

/// Log-actuation entries below this are left out (`A` within `5e-4` of `I` there: strains
/// far below what the fit resolves).
pub const NEGLIGIBLE_LOG: f32 = 5e-4;

/// How well one shape was fitted.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShapeFit {
    pub shape: String,
    /// Simulation skin against the rig's target, RMS and max (cm).
    pub skin_rms: f64,
    pub skin_max: f64,
    /// The lower teeth against the fitted jaw motion, RMS (cm).
    pub jaw_rms: f64,
    pub iterations: usize,
    /// Elements whose stretch had to be clamped.
    pub clamped: usize,
}

/// Fitted actuation fields of one face (module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ActuationBasis {
    /// The face this basis drives (its name), to catch mismatched files.
    pub face: String,
    pub element_count: usize,
    /// Rig shape names, in basis order.
    pub shapes: Vec<String>,
    /// `log Aₖ` per shape, as `(element, [xx, yy, zz, xy, xz, yz])` for the elements the
    /// shape moves (entries above [`NEGLIGIBLE_LOG`]); the others keep `A = I`. f32: the fit
    /// is far coarser than its rounding, and the bundled sample stays small.
    logs: Vec<Vec<(u32, [f32; 6])>>,
    /// Jaw parameters `[θ; t]` per shape.
    jaw: Vec<[f64; 6]>,
    pub fits: Vec<ShapeFit>,
}

#[derive(Debug, thiserror::Error)]
pub enum BasisError {
    #[error("target of shape {shape}: {source}")]
    Target { shape: String, source: TargetError },
    #[error("fitting shape {shape}: {source}")]
    Fit { shape: String, source: FitError },
    #[error(transparent)]
    Setup(#[from] FitError),
}

/// The shapes a basis holds: the expression code's and those styles add.
pub fn basis_shapes() -> Vec<&'static str> {
    ExpressionCode::NAMES
        .iter()
        .chain(STYLE_SHAPES.iter())
        .copied()
        .collect()
}

impl ActuationBasis {
    /// Fits every basis shape at weight one on `face`; `progress(done, total, shape)`.
    pub fn fit(
        rig: &FaceRig,
        face: &FaceModel,
        progress: &dyn Fn(usize, usize, &str),
    ) -> Result<Self, BasisError> {
        let fitter = ActuationFitter::new(face, FitSettings::default())?;
        let shapes = basis_shapes();
        let (mut logs, mut jaw, mut fits) = (Vec::new(), Vec::new(), Vec::new());
        for (k, &shape) in shapes.iter().enumerate() {
            progress(k, shapes.len(), shape);
            let target =
                shape_target(rig, face, &[(shape, 1.0)]).map_err(|source| BasisError::Target {
                    shape: shape.to_string(),
                    source,
                })?;
            let fit = fitter
                .fit(&target, None)
                .map_err(|source| BasisError::Fit {
                    shape: shape.to_string(),
                    source,
                })?;
            logs.push(
                fit.tensors
                    .iter()
                    .map(log_tensor)
                    .enumerate()
                    .filter(|(_, l)| l.iter().any(|v| v.abs() > NEGLIGIBLE_LOG))
                    .map(|(e, l)| (e as u32, l))
                    .collect(),
            );
            jaw.push(fit.jaw.params());
            fits.push(ShapeFit {
                shape: shape.to_string(),
                skin_rms: fit.skin_rms,
                skin_max: fit.skin_max,
                jaw_rms: target.jaw.rms_error,
                iterations: fit.iterations,
                clamped: fit.clamped,
            });
        }
        progress(shapes.len(), shapes.len(), "");
        Ok(Self {
            face: face.name.clone(),
            element_count: face.mesh.element_count(),
            shapes: shapes.iter().map(|s| s.to_string()).collect(),
            logs,
            jaw,
            fits,
        })
    }

    pub fn save(&self, path: &std::path::Path) -> Result<(), FileError> {
        file::write(path, BASIS_FORMAT, self)
    }

    pub fn load(path: &std::path::Path) -> Result<Self, FileError> {
        file::read(path, BASIS_FORMAT)
    }
}

impl ActuationModel for ActuationBasis {
    fn element_count(&self) -> usize {
        self.element_count
    }

    fn actuate(&self, codes: &Codes) -> Result<Actuation, DriveError> {
        codes.validate()?;
        let weights: Vec<(usize, f64)> = codes
            .style
            .shape_weights(&codes.expression)
            .into_iter()
            .map(|(name, w)| {
                let k = self.shapes.iter().position(|s| s == name).ok_or_else(|| {
                    DriveError::BadTensor {
                        element: 0,
                        reason: format!("the basis has no shape '{name}'"),
                    }
                })?;
                Ok((k, w))
            })
            .collect::<Result<_, DriveError>>()?;
        let mut logs = vec![[0.0f64; 6]; self.element_count];
        for &(k, w) in &weights {
            for (e, log) in &self.logs[k] {
                for (l, v) in logs[*e as usize].iter_mut().zip(log) {
                    *l += w * *v as f64;
                }
            }
        }
        let tensors: Vec<SymTensor> = logs
            .par_iter()
            .with_min_len(256)
            .map(|log| exp_tensor_within(log, BLENDED_STRETCH))
            .collect();
        if let Some(e) = tensors.iter().position(|t| t.validate().is_err()) {
            return Err(DriveError::BadTensor {
                element: e,
                reason: format!("{:?} (weights too extreme for f64)", tensors[e]),
            });
        }
        let mut jaw = [0.0; 6];
        for &(k, w) in &weights {
            for (j, v) in jaw.iter_mut().zip(self.jaw[k]) {
                *j += w * v;
            }
        }
        Ok(Actuation {
            tensors,
            jaw: RigidMotion::from_params(jaw),
        })
    }
}

/// `log A` of a symmetric positive definite tensor.
pub(crate) fn log_tensor(a: &SymTensor) -> [f32; 6] {
    let eigen = SymmetricEigen::new(a.to_matrix());
    let m = eigen.eigenvectors
        * Matrix3::from_diagonal(&eigen.eigenvalues.map(f64::ln))
        * eigen.eigenvectors.transpose();
    SymTensor::from_matrix(&m).0.map(|v| v as f32)
}

/// `exp L` of a symmetric tensor; exactly the identity for `L = 0`.
/// The principal stretches a blend of the basis may ask of an element. The fits stretch the
/// elements at the mouth corners up to 11× (jawOpen, mouthClose) and squeeze none below the
/// fit's 0.3; a blend of many shapes at far slider and style values would add their logs up
/// to stretches of 10⁹ (far styles: `bench::extremes`), which no tissue takes and f64
/// barely holds: the blend's stretches are clamped to this range.
pub const BLENDED_STRETCH: (f64, f64) = (0.05, 20.0);

/// `exp` of a symmetric log with its eigenvalues clamped to `[ln lo, ln hi]`.
fn exp_tensor_within(log: &[f64; 6], (lo, hi): (f64, f64)) -> SymTensor {
    if log.iter().all(|&v| v == 0.0) {
        return SymTensor::IDENTITY;
    }
    let eigen = SymmetricEigen::new(SymTensor(*log).to_matrix());
    let (lo, hi) = (lo.ln(), hi.ln());
    let m = eigen.eigenvectors
        * Matrix3::from_diagonal(&eigen.eigenvalues.map(|l| l.clamp(lo, hi).exp()))
        * eigen.eigenvectors.transpose();
    SymTensor::from_matrix(&m)
}

#[cfg(test)]
pub(crate) fn exp_tensor(log: &[f64; 6]) -> SymTensor {
    if log.iter().all(|&v| v == 0.0) {
        return SymTensor::IDENTITY;
    }
    let eigen = SymmetricEigen::new(SymTensor(*log).to_matrix());
    let m = eigen.eigenvectors
        * Matrix3::from_diagonal(&eigen.eigenvalues.map(f64::exp))
        * eigen.eigenvectors.transpose();
    SymTensor::from_matrix(&m)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::test_support::coarse_face;
    use crate::rig::StyleCode;
    use crate::rig::test_support::{rig, temp_dir};
    use crate::sim::Quality;
    use std::sync::OnceLock;

    fn basis() -> &'static ActuationBasis {
        static BASIS: OnceLock<ActuationBasis> = OnceLock::new();
        BASIS.get_or_init(|| ActuationBasis::fit(rig(), coarse_face(None), &|_, _, _| {}).unwrap())
    }

    #[test]
    fn log_and_exp_invert_each_other() {
        let a = SymTensor([1.3, 0.7, 0.9, 0.1, -0.05, 0.2]);
        let back = exp_tensor(&log_tensor(&a).map(|v| v as f64));
        for (x, y) in a.0.iter().zip(back.0) {
            assert!((x - y).abs() < 1e-6, "{a:?} {back:?}");
        }
        assert_eq!(exp_tensor(&[0.0; 6]), SymTensor::IDENTITY);
    }

    #[test]
    fn neutral_codes_give_identity_and_single_shapes_give_their_fit() {
        let b = basis();
        assert_eq!(b.shapes.len(), ExpressionCode::LEN + STYLE_SHAPES.len());
        let rest = b.actuate(&Codes::default()).unwrap();
        assert!(rest.tensors.iter().all(|t| *t == SymTensor::IDENTITY));
        assert_eq!(rest.jaw, RigidMotion::IDENTITY);
        let open = Codes {
            expression: ExpressionCode::single("jawOpen", 1.0).unwrap(),
            style: StyleCode::NEUTRAL,
        };
        let a = b.actuate(&open).unwrap();
        assert!(a.jaw.rotation.x > 0.1, "{:?}", a.jaw);
        let k = b.shapes.iter().position(|s| s == "jawOpen").unwrap();
        assert!(
            b.logs[k].len() > 100,
            "jawOpen moves {} elements",
            b.logs[k].len()
        );
        for (e, log) in &b.logs[k] {
            let fitted = exp_tensor(&log.map(|v| v as f64));
            let t = a.tensors[*e as usize];
            assert!(t.0.iter().zip(fitted.0).all(|(x, y)| (x - y).abs() < 1e-12));
        }
        for fit in &b.fits {
            assert!(fit.skin_rms < 0.05, "{fit:?}");
        }
    }

    #[test]
    fn every_slider_at_and_beyond_its_range_gives_a_valid_solvable_frame() {
        let b = basis();
        let face = coarse_face(None);
        let sim = face.simulator().unwrap();
        for k in 0..ExpressionCode::LEN {
            for w in [-1.0, 1.0, 2.0] {
                let mut codes = Codes::default();
                codes.expression.0[k] = w;
                let a = b.actuate(&codes).unwrap();
                assert!(a.tensors.iter().all(|t| t.validate().is_ok()));
                let mut state = sim.rest_state();
                let result = sim.solve(
                    &a.tensors,
                    &a.bones(),
                    &mut state,
                    &Quality::Interactive.settings(),
                );
                let name = ExpressionCode::NAMES[k];
                match result {
                    Ok(_) => assert!(state.flat_positions().iter().all(|v| v.is_finite())),
                    // Beyond the range, and at full mouthClose or mouthRollLower (the rig presses
                    // the lips into each other and the teeth; without contact nothing stops
                    // them), the tissue may be asked to fold: that must be a loud error, never
                    // a silent bad frame.
                    Err(crate::sim::SimError::Inverted { .. })
                        if !(0.0..=1.0).contains(&w)
                            || ["mouthClose", "mouthRollLower"].contains(&name) => {}
                    Err(e) => panic!("{name} = {w}: {e}"),
                }
            }
        }
        let mut bad = Codes::default();
        bad.style.0[2] = f64::INFINITY;
        assert!(matches!(
            b.actuate(&bad),
            Err(DriveError::NonFiniteCode { name: "jaw", .. })
        ));
    }

    /// The two sliders that press the lips into each other (exempted above: without contact
    /// the tissue folds) solve to a valid, intersection-free frame with contact on: no element
    /// inverts and no surface crosses (at the interactive cap of 30 iterations neither is
    /// converged yet: residuals 1.0 and 0.03).
    #[test]
    fn lip_pressing_sliders_at_full_weight_solve_with_contact() {
        use crate::contact::surface::FaceContact;
        use crate::model::contact_region::FaceContactSettings;
        let b = basis();
        let face = coarse_face(None);
        let mut sim = face.simulator().unwrap();
        sim.set_contact(FaceContact::new(face, &FaceContactSettings::default()).unwrap())
            .unwrap();
        for name in ["mouthClose", "mouthRollLower"] {
            let k = ExpressionCode::NAMES
                .iter()
                .position(|&n| n == name)
                .unwrap();
            let mut codes = Codes::default();
            codes.expression.0[k] = 1.0;
            let a = b.actuate(&codes).unwrap();
            let mut state = sim.rest_state();
            let settings = Quality::Interactive.settings();
            assert!(settings.contact);
            let stats = sim
                .solve(&a.tensors, &a.bones(), &mut state, &settings)
                .unwrap_or_else(|e| panic!("{name} = 1 with contact: {e}"));
            assert!(state.flat_positions().iter().all(|v| v.is_finite()));
            let contact = stats.contact.expect("contact was on");
            assert_eq!(contact.new_crossings, 0);
        }
    }

    #[test]
    fn saved_basis_loads_identically() {
        let dir = temp_dir("basis");
        let path = dir.join("neutral.basis");
        basis().save(&path).unwrap();
        assert_eq!(&ActuationBasis::load(&path).unwrap(), basis());
    }
}
