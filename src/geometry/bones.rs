//! The bones and their poses: which bone a point rides on, a rigid motion `[θ; t]` about a
//! pivot, a frame's skull and jaw motions, and where they take a rest point (the simulator's
//! attachments, the render and contact surfaces' rigid vertices).

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

/// Which bone a tissue vertex is attached to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Bone {
    Skull,
    Jaw,
}

/// A rigid motion: rotation vector `θ` (axis × angle, radians) and translation `t`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RigidMotion {
    pub rotation: Vector3<f64>,
    pub translation: Vector3<f64>,
}

impl RigidMotion {
    pub const IDENTITY: RigidMotion = RigidMotion {
        rotation: Vector3::new(0.0, 0.0, 0.0),
        translation: Vector3::new(0.0, 0.0, 0.0),
    };

    /// The 6 parameters `[θx, θy, θz, tx, ty, tz]` (the jaw network's output).
    pub fn from_params(p: [f64; 6]) -> Self {
        Self {
            rotation: Vector3::new(p[0], p[1], p[2]),
            translation: Vector3::new(p[3], p[4], p[5]),
        }
    }

    pub fn params(&self) -> [f64; 6] {
        let (r, t) = (self.rotation, self.translation);
        [r.x, r.y, r.z, t.x, t.y, t.z]
    }

    pub fn rotation_matrix(&self) -> Matrix3<f64> {
        Rotation3::from_scaled_axis(self.rotation).into_inner()
    }

    /// `R·(p − pivot) + pivot + t`.
    pub fn apply_about(&self, pivot: &Point3<f64>, p: &Point3<f64>) -> Point3<f64> {
        pivot + self.rotation_matrix() * (p - pivot) + self.translation
    }

    pub fn is_finite(&self) -> bool {
        self.rotation
            .iter()
            .chain(self.translation.iter())
            .all(|v| v.is_finite())
    }
}

/// Where the bones are for one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BonePose {
    /// The head's rigid motion (about the origin); identity for a fixed head.
    pub skull: RigidMotion,
    /// The jaw's motion relative to the skull, about the jaw pivot.
    pub jaw: RigidMotion,
}

impl BonePose {
    /// Where a rest point attached to `bone` goes.
    pub fn target(&self, bone: Bone, jaw_pivot: &Point3<f64>, rest: &Point3<f64>) -> Point3<f64> {
        let on_skull = match bone {
            Bone::Skull => *rest,
            Bone::Jaw => self.jaw.apply_about(jaw_pivot, rest),
        };
        self.skull.apply_about(&Point3::origin(), &on_skull)
    }

    /// `T_skull(rest) + R_skull·M·R_skullᵀ·(T_jaw(rest) − T_skull(rest))`: a point between
    /// the bones by its jaw map `M` (the deep mouth lining: `M = I` on the jaw, `0` on the
    /// skull).
    pub fn between_bones(
        &self,
        jaw_map: &Matrix3<f64>,
        pivot: &Point3<f64>,
        rest: &Point3<f64>,
    ) -> Point3<f64> {
        let skull = self.target(Bone::Skull, pivot, rest);
        let turn = self.skull.rotation_matrix();
        skull + turn * jaw_map * turn.transpose() * (self.target(Bone::Jaw, pivot, rest) - skull)
    }
}
