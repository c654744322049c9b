//! The rigid motion that best maps one point set onto another (Kabsch, no scale).
//!
//! Given rest points `pᵢ` and posed points `qᵢ`, the rotation `R` and translation `t`
//! minimising `Σᵢ ‖R·pᵢ + t − qᵢ‖²`: with centroids `p̄, q̄` and
//! `H = Σᵢ (pᵢ − p̄)(qᵢ − q̄)ᵀ = U·Σ·Vᵀ`, `R = V·diag(1, 1, d)·Uᵀ` with `d = sign det(V·Uᵀ)`
//! (never a reflection) and `t = q̄ − R·p̄`.

use nalgebra::{Matrix3, Point3, Rotation3, UnitQuaternion, Vector3};

/// `x ↦ R·x + t` and how well it maps the rest points onto the posed ones.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kabsch {
    /// `R` as a rotation vector (axis × angle, rad).
    pub rotation: Vector3<f64>,
    pub matrix: Matrix3<f64>,
    pub translation: Vector3<f64>,
    /// `sqrt(mean ‖R·pᵢ + t − qᵢ‖²)`, in the points' unit.
    pub rms_error: f64,
    /// `max ‖R·pᵢ + t − qᵢ‖`.
    pub max_error: f64,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum KabschError {
    #[error("rigid fit needs the same number of rest and posed points (got {rest} and {posed})")]
    LengthMismatch { rest: usize, posed: usize },
    #[error("rigid fit needs at least 3 points, got {0}")]
    TooFewPoints(usize),
    #[error("a rigid fit got or produced a non-finite value")]
    NonFinite,
}

/// The Kabsch fit of `posed ≈ R·rest + t` (module doc).
pub fn kabsch(rest: &[Point3<f64>], posed: &[Point3<f64>]) -> Result<Kabsch, KabschError> {
    if rest.len() != posed.len() {
        return Err(KabschError::LengthMismatch {
            rest: rest.len(),
            posed: posed.len(),
        });
    }
    if rest.len() < 3 {
        return Err(KabschError::TooFewPoints(rest.len()));
    }
    let finite = |p: &Point3<f64>| p.coords.iter().all(|c| c.is_finite());
    if !rest.iter().chain(posed).all(finite) {
        return Err(KabschError::NonFinite);
    }
    let n = rest.len() as f64;
    let p_bar = rest.iter().fold(Vector3::zeros(), |s, p| s + p.coords) / n;
    let q_bar = posed.iter().fold(Vector3::zeros(), |s, q| s + q.coords) / n;
    let mut h = Matrix3::zeros();
    for (p, q) in rest.iter().zip(posed) {
        h += (p.coords - p_bar) * (q.coords - q_bar).transpose();
    }
    let r = kabsch_rotation(&h);
    let t = q_bar - r * p_bar;
    let (mut sum2, mut max) = (0.0, 0.0f64);
    for (p, q) in rest.iter().zip(posed) {
        let e = (r * p.coords + t - q.coords).norm();
        sum2 += e * e;
        max = max.max(e);
    }
    // Via the quaternion (Shepperd's method): robust for rotations near the identity, where
    // the trace-based angle of `Rotation3::scaled_axis` can be NaN from rounding.
    let rotation =
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)).scaled_axis();
    if !rotation.iter().chain(t.iter()).all(|c| c.is_finite()) {
        return Err(KabschError::NonFinite);
    }
    Ok(Kabsch {
        rotation,
        matrix: r,
        translation: t,
        rms_error: (sum2 / n).sqrt(),
        max_error: max,
    })
}

/// The proper rotation maximising `tr(R·H)`: `V·diag(1, 1, sign det(V·Uᵀ))·Uᵀ` for
/// `H = U·Σ·Vᵀ`.
fn kabsch_rotation(h: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = h.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        unreachable!("SVD computed with U and Vᵀ requested");
    };
    let v = v_t.transpose();
    let d = (v * u.transpose()).determinant().signum();
    v * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose()
}
