//! Training targets: what the rig says a face looks like for given codes (SPEC.md §3: an
//! expression target is a blendshape combination, the jaw transform is the lower teeth's
//! rigid motion).

use nalgebra::Point3;

use super::face::FaceModel;
use crate::rig::FaceRig;
use crate::rig::codes::{CodeError, Codes};
use crate::rig::jaw::{JawError, RigidFit, fit_jaw};

/// The rig's answer for one face and one pair of codes.
#[derive(Clone, Debug, PartialEq)]
pub struct Target {
    /// Target positions of the face's render surface (cm), with the importer's rest repair
    /// carried along (so zero codes give exactly the model's rest).
    pub render: Vec<Point3<f64>>,
    /// The jaw's rigid motion about the face's pivot, fitted to the lower teeth, with its
    /// fit error (exact on the neutral; on identities the neutral's expression deltas make
    /// the teeth move almost rigidly, to about 0.05 mm RMS).
    pub jaw: RigidFit,
}

#[derive(Debug, thiserror::Error)]
pub enum TargetError {
    #[error(transparent)]
    Code(#[from] CodeError),
    #[error("the face '{face}' was built from another rig: {reason}")]
    RigMismatch { face: String, reason: String },
    #[error("the rig has no shape '{0}', which the style needs")]
    MissingShape(&'static str),
    #[error("fitting the jaw: {0}")]
    Jaw(#[from] JawError),
}

/// The target of `codes` (expression performed in the style) on `face`.
pub fn target(rig: &FaceRig, face: &FaceModel, codes: &Codes) -> Result<Target, TargetError> {
    codes.validate()?;
    shape_target(rig, face, &codes.style.shape_weights(&codes.expression))
}

/// The target of weights on named rig shapes (any of the rig's shapes) on `face`.
pub fn shape_target(
    rig: &FaceRig,
    face: &FaceModel,
    weights: &[(&'static str, f64)],
) -> Result<Target, TargetError> {
    let mismatch = |reason: String| TargetError::RigMismatch {
        face: face.name.clone(),
        reason,
    };
    if let Some(i) = face.identity
        && i >= rig.identity_count()
    {
        return Err(mismatch(format!(
            "identity {i}, the rig has {}",
            rig.identity_count()
        )));
    }
    let base = rig.base(face.identity);
    if let Some(v) = face
        .render
        .rig_vertices
        .iter()
        .find(|&&v| v as usize >= base.len())
    {
        return Err(mismatch(format!(
            "render vertex {v}, the rig has {}",
            base.len()
        )));
    }
    let weights = weights
        .iter()
        .map(|&(name, w)| {
            Ok((
                rig.shape_index(name)
                    .ok_or(TargetError::MissingShape(name))?,
                w,
            ))
        })
        .collect::<Result<Vec<_>, TargetError>>()?;
    let posed = rig.pose_shapes(face.identity, &weights);
    let jaw = fit_jaw(base, &posed, &face.jaw_pivot)?;
    let render = face
        .render
        .rig_vertices
        .iter()
        .zip(&face.render.rest)
        .map(|(&v, rest)| posed[v as usize] + (rest - base[v as usize]))
        .collect();
    Ok(Target { render, jaw })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::test_support::coarse_face;
    use crate::rig::test_support::rig;
    use crate::rig::{ExpressionCode, Region, StyleCode};

    #[test]
    fn zero_codes_give_the_rest_and_no_jaw_motion() {
        let face = coarse_face(Some(0));
        let t = target(rig(), face, &Codes::default()).unwrap();
        assert_eq!(t.render, face.render.rest);
        assert!(t.jaw.motion.rotation.norm() < 1e-12 && t.jaw.motion.translation.norm() < 1e-12);
    }

    #[test]
    fn jaw_is_recovered_from_the_teeth_and_carries_them() {
        let face = coarse_face(Some(0));
        for (name, w) in [("jawOpen", 1.0), ("jawLeft", 0.7), ("jawForward", 1.0)] {
            let codes = Codes {
                expression: ExpressionCode::single(name, w).unwrap(),
                style: StyleCode::NEUTRAL,
            };
            let t = target(rig(), face, &codes).unwrap();
            // Expression deltas are the neutral's, added to the identity's teeth, so they are
            // not exactly rigid there: the fit is good to a tenth of a millimetre.
            assert!(t.jaw.rms_error < 0.01, "{name}: rms {}", t.jaw.rms_error);
            let render = &face.render;
            for ((v, rest), p) in render.rig_vertices.iter().zip(&render.rest).zip(&t.render) {
                if Region::of_vertex(*v as usize) == Some(Region::LowerTeeth) {
                    let moved = t.jaw.motion.apply_about(&face.jaw_pivot, rest);
                    assert!((moved - p).norm() < 0.03, "{name}: {}", (moved - p).norm());
                }
            }
        }
        let open = Codes {
            expression: ExpressionCode::single("jawOpen", 1.0).unwrap(),
            style: StyleCode::NEUTRAL,
        };
        let t = target(rig(), face, &open).unwrap();
        // Opening rotates the jaw down (about +x) by a clearly visible angle.
        assert!(t.jaw.motion.rotation.x > 0.1, "{:?}", t.jaw.motion.rotation);
    }

    #[test]
    fn style_changes_the_target_and_bad_codes_are_rejected() {
        let face = coarse_face(Some(1));
        let smile = ExpressionCode::single("mouthSmile_L", 1.0).unwrap();
        let plain = target(
            rig(),
            face,
            &Codes {
                expression: smile,
                style: StyleCode::NEUTRAL,
            },
        )
        .unwrap();
        let styled = target(
            rig(),
            face,
            &Codes {
                expression: smile,
                style: StyleCode([0.0, 0.0, 0.0, 1.0]),
            },
        )
        .unwrap();
        let moved = plain
            .render
            .iter()
            .zip(&styled.render)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(moved > 0.1, "the dimple style moves the skin by {moved} cm");
        let mut bad = Codes::default();
        bad.expression.0[3] = f64::NAN;
        assert!(matches!(
            target(rig(), face, &bad),
            Err(TargetError::Code(CodeError::NonFinite {
                name: "jawForward",
                ..
            }))
        ));
    }
}
