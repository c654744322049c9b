//! The per-shape actuation basis: one fitted actuation field and jaw motion per rig shape,
//! blended by the shape weights of the codes.
//!
//! Tensors blend log-Euclidean, `A = exp(Σₖ wₖ·log Aₖ)`: symmetric positive definite for
//! any weights (also beyond the sliders' ranges and negative ones), exactly `I` when every
//! weight is zero, and `Aₖ` at a single weight of one. Jaw parameters `[θ; t]` blend
//! linearly. This is the per-identity model without a canonical space (each face has its
//! own basis): the editor's driver until the networks are trained, and their baseline.
//!
//! **The face's own style.** A style turns a slider into several rig shapes at weights other
//! than one (identity000's jawOpen is jawOpen 1.24 with mouthLowerDown 0.5 on both sides), and
//! the blend of their fits misses that combination: the rig adds the shapes' displacements in
//! the world, the blend adds their strains in the rest frame, and the lower lip has turned
//! with the jaw in between (10.9 mm off the rig at the lower lip for identity000's jawOpen).
//! So each slider is also fitted as the face performs it, in the style the basis was fitted
//! for (`style`, the face's default), and its residual against the blend is kept:
//!
//! `log A(w, s) = Σⱼ rⱼ(w, s)·log Aⱼ + Σₖ wₖ|wₖ|·Δₖ`, `Δₖ = log Âₖ − Σⱼ rⱼ(eₖ, s₀)·log Aⱼ`,
//!
//! with `r(w, s)` the rig weights of the code (`StyleCode::shape_weights`), `Âₖ` slider `k`'s
//! fit at weight one in the face's style `s₀`, and the jaw's `[θ; t]` the same way. The
//! residual grows as `wₖ|wₖ|` (a cross term of two motions linear in `wₖ`:
//! `residual_weight`). At the face's own style a slider at weight one gives its own fit `Âₖ`
//! exactly; another style still changes the frame by what it changes in the rig's shapes; a
//! style under which a slider is its own shape at weight one (the template's zero style) has
//! no residual.

use nalgebra::{Matrix3, SymmetricEigen};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{Actuation, ActuationModel, Codes, DriveError};
use crate::model::file::{self, FileError, Format};
use crate::model::fit::{ActuationFitter, FitError, FitSettings};
use crate::model::{FaceModel, TargetError, shape_target};
use crate::rig::style::STYLE_SHAPES;
use crate::rig::{ExpressionCode, FaceRig, StyleCode};
use crate::sim::{RigidMotion, SymTensor};

/// The file format of actuation bases; bump `version` when [`ActuationBasis`] changes shape.
pub const BASIS_FORMAT: Format = Format {
    kind: "basis",
    version: 2,
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
    /// The style the sliders' residuals were fitted in (the face's default).
    pub style: StyleCode,
    /// Per expression slider (code order), its residual `Δₖ` in `style` (module doc); `None`
    /// where the style makes the slider its own shape at weight one.
    residuals: Vec<Option<SliderResidual>>,
}

/// What the blend of the shapes' fits misses of one slider performed in the basis's style
/// (module doc): `Δ = log Â − Σⱼ rⱼ·log Aⱼ` for the elements where it is not negligible, and
/// the jaw's the same way.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct SliderResidual {
    logs: Vec<(u32, [f32; 6])>,
    jaw: [f64; 6],
    /// How well the slider's own fit matched the rig in that style.
    fit: ShapeFit,
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
    /// Fits every basis shape at weight one on `face`, then every slider at weight one in
    /// `style` (the face's default) for its residual; `progress(done, total, what)`.
    pub fn fit(
        rig: &FaceRig,
        face: &FaceModel,
        style: StyleCode,
        progress: &dyn Fn(usize, usize, &str),
    ) -> Result<Self, BasisError> {
        let fitter = ActuationFitter::new(face, FitSettings::default())?;
        let shapes = basis_shapes();
        let sliders: Vec<_> = ExpressionCode::NAMES
            .iter()
            .map(|&name| {
                let weights = style.shape_weights(&ExpressionCode::single(name, 1.0).unwrap());
                let own = weights.len() == 1 && weights[0] == (name, 1.0);
                (name, (!own).then_some(weights))
            })
            .collect();
        let total = shapes.len() + sliders.iter().filter(|s| s.1.is_some()).count();
        let fit_one = |what: String, weights: &[(&'static str, f64)]| {
            let target = shape_target(rig, face, weights).map_err(|source| BasisError::Target {
                shape: what.clone(),
                source,
            })?;
            let fit = fitter
                .fit(&target, None)
                .map_err(|source| BasisError::Fit {
                    shape: what.clone(),
                    source,
                })?;
            let logs: Vec<[f64; 6]> = fit
                .tensors
                .iter()
                .map(|t| log_tensor(t).map(f64::from))
                .collect();
            let summary = ShapeFit {
                shape: what,
                skin_rms: fit.skin_rms,
                skin_max: fit.skin_max,
                jaw_rms: target.jaw.rms_error,
                iterations: fit.iterations,
                clamped: fit.clamped,
            };
            Ok::<_, BasisError>((logs, fit.jaw.params(), summary))
        };
        let mut basis = Self {
            face: face.name.clone(),
            element_count: face.mesh.element_count(),
            shapes: shapes.iter().map(|s| s.to_string()).collect(),
            logs: Vec::new(),
            jaw: Vec::new(),
            fits: Vec::new(),
            style,
            residuals: Vec::new(),
        };
        for (k, &shape) in shapes.iter().enumerate() {
            progress(k, total, shape);
            let (logs, jaw, fit) = fit_one(shape.to_string(), &[(shape, 1.0)])?;
            basis.logs.push(sparse(logs.into_iter()));
            basis.jaw.push(jaw);
            basis.fits.push(fit);
        }
        let mut done = shapes.len();
        for (name, weights) in sliders {
            let Some(weights) = weights else {
                basis.residuals.push(None);
                continue;
            };
            progress(done, total, name);
            done += 1;
            let (own, own_jaw, fit) = fit_one(format!("{name} (own style)"), &weights)?;
            let indexed = basis
                .indexed(&weights)
                .expect("the basis holds every shape a style names");
            let (blend, blend_jaw) = basis.blend(&indexed, None);
            let residual = own
                .iter()
                .zip(&blend)
                .map(|(o, b)| std::array::from_fn(|i| o[i] - b[i]));
            basis.residuals.push(Some(SliderResidual {
                logs: sparse(residual),
                jaw: std::array::from_fn(|i| own_jaw[i] - blend_jaw[i]),
                fit,
            }));
        }
        progress(total, total, "");
        Ok(basis)
    }

    /// The sliders' own fits in the basis's style (those with a residual), as [`ShapeFit`]s.
    pub fn own_style_fits(&self) -> impl Iterator<Item = &ShapeFit> {
        self.residuals.iter().flatten().map(|r| &r.fit)
    }

    /// Rig shape weights by name → by basis index; the unknown name otherwise.
    fn indexed(&self, weights: &[(&str, f64)]) -> Result<Vec<(usize, f64)>, String> {
        weights
            .iter()
            .map(|&(name, w)| {
                let k = self
                    .shapes
                    .iter()
                    .position(|s| s == name)
                    .ok_or_else(|| name.to_string())?;
                Ok((k, w))
            })
            .collect()
    }

    /// `Σⱼ rⱼ·log Aⱼ` per element and `Σⱼ rⱼ·jawⱼ`, plus `Σₖ wₖ|wₖ|·Δₖ` for the slider weights
    /// `expression` when given (module doc).
    fn blend(
        &self,
        weights: &[(usize, f64)],
        expression: Option<&ExpressionCode>,
    ) -> (Vec<[f64; 6]>, [f64; 6]) {
        let mut logs = vec![[0.0f64; 6]; self.element_count];
        let mut jaw = [0.0; 6];
        let mut add = |w: f64, entries: &[(u32, [f32; 6])], jaw_k: &[f64; 6]| {
            for (e, log) in entries {
                for (l, v) in logs[*e as usize].iter_mut().zip(log) {
                    *l += w * f64::from(*v);
                }
            }
            for (j, v) in jaw.iter_mut().zip(jaw_k) {
                *j += w * v;
            }
        };
        for &(k, w) in weights {
            add(w, &self.logs[k], &self.jaw[k]);
        }
        if let Some(expression) = expression {
            for (residual, &w) in self.residuals.iter().zip(&expression.0) {
                if let Some(r) = residual
                    && w != 0.0
                {
                    add(residual_weight(w), &r.logs, &r.jaw);
                }
            }
        }
        (logs, jaw)
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
        let weights = self
            .indexed(&codes.style.shape_weights(&codes.expression))
            .map_err(|name| DriveError::BadTensor {
                element: 0,
                reason: format!("the basis has no shape '{name}'"),
            })?;
        let (logs, jaw) = self.blend(&weights, Some(&codes.expression));
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
        Ok(Actuation {
            tensors,
            jaw: RigidMotion::from_params(jaw),
        })
    }
}

/// How much of a slider's residual a slider weight `w` takes: `w·|w|`. What the blend misses
/// is a cross term, the lip's own displacement turned by the jaw's rotation, and both grow
/// with `w`: so it grows as `w²` (odd in `w`, as the rest of the blend, beyond the range).
/// Exact at `w = 1`, where the residual was fitted; on held-out combinations it lies between
/// a linear weight and none on every styled face (docs/performance/fidelity.md).
fn residual_weight(w: f64) -> f64 {
    w * w.abs()
}

/// `(element, log)` for the elements whose log is not negligible (above [`NEGLIGIBLE_LOG`]),
/// rounded to f32.
fn sparse(logs: impl Iterator<Item = [f64; 6]>) -> Vec<(u32, [f32; 6])> {
    logs.enumerate()
        .map(|(e, l)| (e as u32, l.map(|v| v as f32)))
        .filter(|(_, l)| l.iter().any(|v| v.abs() > NEGLIGIBLE_LOG))
        .collect()
}

/// `log A` of a symmetric positive definite tensor.
pub(crate) fn log_tensor(a: &SymTensor) -> [f32; 6] {
    let eigen = SymmetricEigen::new(a.to_matrix());
    let m = eigen.eigenvectors
        * Matrix3::from_diagonal(&eigen.eigenvalues.map(f64::ln))
        * eigen.eigenvectors.transpose();
    SymTensor::from_matrix(&m).0.map(|v| v as f32)
}

/// The principal stretches a blend of the basis may ask of an element. The fits stretch the
/// elements at the mouth corners up to 11× on the neutral (mouthClose) and up to 32× in a
/// styled face's own sliders (identity001's mouthClose; identity000's jawOpen 23×), and
/// squeeze none below the fit's 0.3; a blend of many shapes at far slider and style values
/// would add their logs up to stretches of 10⁹ (far styles: `bench::extremes`), which no
/// tissue takes and f64 barely holds: the blend's stretches are clamped to this range, wide
/// enough for every fit.
pub const BLENDED_STRETCH: (f64, f64) = (0.05, 40.0);

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

/// `exp L` of a symmetric tensor, unclamped; exactly the identity for `L = 0`.
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
    use crate::rig::style::identity_style;
    use crate::rig::test_support::{rig, temp_dir};
    use crate::sim::Quality;
    use std::sync::OnceLock;

    fn basis() -> &'static ActuationBasis {
        static BASIS: OnceLock<ActuationBasis> = OnceLock::new();
        BASIS.get_or_init(|| {
            ActuationBasis::fit(rig(), coarse_face(None), StyleCode::NEUTRAL, &|_, _, _| {})
                .unwrap()
        })
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
            let settings = crate::sim::SolveSettings {
                audit_crossings: true,
                ..Quality::Interactive.settings()
            };
            assert!(settings.contact);
            let stats = sim
                .solve(&a.tensors, &a.bones(), &mut state, &settings)
                .unwrap_or_else(|e| panic!("{name} = 1 with contact: {e}"));
            assert!(state.flat_positions().iter().all(|v| v.is_finite()));
            let contact = stats.contact.expect("contact was on");
            assert_eq!(contact.new_crossings, Some(0));
        }
    }

    /// In the face's own style a slider at weight one is the slider's own fit to the rig
    /// (identity000's jawOpen: jawOpen 1.24 with mouthLowerDown 0.5), not the blend of the
    /// shapes' fits, which misses it (10.9 mm off at the lower lip on the sample face).
    #[test]
    fn a_slider_in_the_faces_own_style_gives_its_own_fit() {
        let (face, style) = (coarse_face(Some(0)), identity_style(Some(0)));
        let b = ActuationBasis::fit(rig(), face, style, &|_, _, _| {}).unwrap();
        assert_eq!(b.own_style_fits().count(), ExpressionCode::LEN);
        let codes = Codes {
            expression: ExpressionCode::single("jawOpen", 1.0).unwrap(),
            style,
        };
        let direct = ActuationFitter::new(face, FitSettings::default())
            .unwrap()
            .fit(&crate::model::target(rig(), face, &codes).unwrap(), None)
            .unwrap();
        let direct_logs: Vec<[f32; 6]> = direct.tensors.iter().map(log_tensor).collect();
        let farthest = |logs: &[[f64; 6]]| {
            logs.iter()
                .zip(&direct_logs)
                .flat_map(|(a, d)| a.iter().zip(d).map(|(a, d)| (a - f64::from(*d)).abs()))
                .fold(0.0f64, f64::max)
        };
        let actuated = b.actuate(&codes).unwrap();
        let actuated_logs: Vec<[f64; 6]> = actuated
            .tensors
            .iter()
            .map(|t| log_tensor(t).map(f64::from))
            .collect();
        let jaw_gap = |jaw: [f64; 6]| {
            jaw.iter()
                .zip(direct.jaw.params())
                .map(|(a, d)| (a - d).abs())
                .fold(0.0, f64::max)
        };
        // Only the sparse storage's cut-offs and f32 rounding between them.
        assert!(
            farthest(&actuated_logs) < 2e-3,
            "{}",
            farthest(&actuated_logs)
        );
        assert!(jaw_gap(actuated.jaw.params()) < 1e-9);
        let rig_weights = b.indexed(&style.shape_weights(&codes.expression)).unwrap();
        let (blend, blend_jaw) = b.blend(&rig_weights, None);
        assert!(farthest(&blend) > 0.1, "{}", farthest(&blend));
        assert!(jaw_gap(blend_jaw) > 1e-3, "{}", jaw_gap(blend_jaw));
    }

    #[test]
    fn saved_basis_loads_identically() {
        let dir = temp_dir("basis");
        let path = dir.join("neutral.basis");
        basis().save(&path).unwrap();
        assert_eq!(&ActuationBasis::load(&path).unwrap(), basis());
    }
}
