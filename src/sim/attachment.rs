//! Bone attachment energy: tissue vertices pulled to points that move rigidly with the skull
//! or the jaw (soft constraints, the paper's supplemental Eq. 5 with `B = I`):
//!
//! `E = Σₐ (kₐ/2)·‖xₐ − T_bone(pₐ)‖²`,
//!
//! with `pₐ` the vertex's rest position. The skull moves by `T_skull` (the head's motion,
//! identity for a fixed head); the jaw by `T_skull ∘ T_jaw`, where `T_jaw` rotates about the
//! jaw's pivot: `T_jaw(p) = R(θ)·(p − c) + c + t`.

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use super::polar::skew;
pub use crate::geometry::bones::{Bone, BonePose, RigidMotion};
use crate::geometry::rigid::{KabschError, kabsch};

/// Attached vertices and their bones.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Attachments {
    pub vertices: Vec<u32>,
    pub bones: Vec<Bone>,
}

/// A rigid motion about a pivot fitted to points, and how well it fits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigidFit {
    /// The motion about `pivot`.
    pub motion: RigidMotion,
    pub pivot: Point3<f64>,
    /// `sqrt(mean ‖R·pᵢ + t − qᵢ‖²)` (cm).
    pub rms_error: f64,
    /// `max ‖R·pᵢ + t − qᵢ‖` (cm).
    pub max_error: f64,
}

impl RigidFit {
    /// The Kabsch fit of `posed ≈ R·rest + t` ([`kabsch`]) as a motion about `pivot`
    /// (`x ↦ R·(x − c) + c + t_c` with `t_c = t + R·c − c`).
    pub fn fit(
        rest: &[Point3<f64>],
        posed: &[Point3<f64>],
        pivot: &Point3<f64>,
    ) -> Result<Self, KabschError> {
        if !pivot.coords.iter().all(|c| c.is_finite()) {
            return Err(KabschError::NonFinite);
        }
        let k = kabsch(rest, posed)?;
        Ok(RigidFit {
            motion: RigidMotion {
                rotation: k.rotation,
                translation: k.translation + k.matrix * pivot.coords - pivot.coords,
            },
            pivot: *pivot,
            rms_error: k.rms_error,
            max_error: k.max_error,
        })
    }
}

impl BonePose {
    /// `∂ target / ∂ [θ, t]` of a jaw-attached rest point: a 3×6 Jacobian.
    pub fn jaw_target_jacobian(
        &self,
        jaw_pivot: &Point3<f64>,
        rest: &Point3<f64>,
    ) -> nalgebra::Matrix3x6<f64> {
        let rs = self.skull.rotation_matrix();
        let v = rest - jaw_pivot;
        let mut jac = nalgebra::Matrix3x6::zeros();
        for k in 0..3 {
            jac.set_column(k, &(rs * rotation_derivative(&self.jaw.rotation, k) * v));
        }
        jac.fixed_view_mut::<3, 3>(0, 3).copy_from(&rs);
        jac
    }
}

/// `∂R(θ)/∂θₖ` for the rotation-vector parameterization (Gallego & Yezzi 2015):
/// `((θₖ·[θ]× + [θ × (I − R)·eₖ]×) / ‖θ‖²)·R`, and `[eₖ]×` at `θ = 0`.
pub fn rotation_derivative(theta: &Vector3<f64>, k: usize) -> Matrix3<f64> {
    let r = Rotation3::from_scaled_axis(*theta).into_inner();
    let n2 = theta.norm_squared();
    let e = Vector3::ith(k, 1.0);
    if n2 < 1e-20 {
        return skew(&e) * r;
    }
    (skew(theta) * theta[k] + skew(&theta.cross(&((Matrix3::identity() - r) * e)))) / n2 * r
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jaw_target_jacobian_matches_finite_differences() {
        let pivot = Point3::new(0.0, -2.0, -5.0);
        let rest = Point3::new(1.0, -4.0, 3.0);
        for jaw_rot in [
            Vector3::zeros(),
            Vector3::new(0.3, -0.1, 0.2),
            Vector3::new(1e-12, 0.0, 0.0),
        ] {
            let pose = BonePose {
                skull: RigidMotion {
                    rotation: Vector3::new(0.1, 0.2, -0.3),
                    translation: Vector3::new(1.0, 0.0, 2.0),
                },
                jaw: RigidMotion {
                    rotation: jaw_rot,
                    translation: Vector3::new(0.0, -0.5, 0.2),
                },
            };
            let jac = pose.jaw_target_jacobian(&pivot, &rest);
            let h = 1e-6;
            for k in 0..6 {
                let mut p = pose.jaw.params();
                p[k] += h;
                let plus = BonePose {
                    jaw: RigidMotion::from_params(p),
                    ..pose
                }
                .target(Bone::Jaw, &pivot, &rest);
                p[k] -= 2.0 * h;
                let minus = BonePose {
                    jaw: RigidMotion::from_params(p),
                    ..pose
                }
                .target(Bone::Jaw, &pivot, &rest);
                let fd = (plus - minus) / (2.0 * h);
                assert!(
                    (fd - jac.column(k)).norm() < 1e-8,
                    "k={k} fd={fd} jac={}",
                    jac.column(k)
                );
            }
        }
    }

    #[test]
    fn skull_points_follow_only_the_skull() {
        let pose = BonePose {
            skull: RigidMotion {
                rotation: Vector3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2),
                translation: Vector3::x(),
            },
            jaw: RigidMotion {
                rotation: Vector3::new(0.5, 0.0, 0.0),
                translation: Vector3::y(),
            },
        };
        let p = pose.target(Bone::Skull, &Point3::origin(), &Point3::new(1.0, 0.0, 0.0));
        assert!((p - Point3::new(1.0, 1.0, 0.0)).norm() < 1e-12);
    }
}
