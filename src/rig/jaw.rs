//! The jaw: its rigid transform for a pose, recovered from the lower teeth (SPEC.md §3), and
//! its pivot.
//!
//! **Fit.** Given the lower teeth at rest `pᵢ` and posed `qᵢ` (cm), the rotation `R` and
//! translation `t` minimising `Σᵢ ‖R·pᵢ + t − qᵢ‖²` (Kabsch, no scale): with centroids `p̄, q̄`
//! and `H = Σᵢ (pᵢ − p̄)(qᵢ − q̄)ᵀ = U·Σ·Vᵀ`, `R = V·diag(1, 1, d)·Uᵀ` with
//! `d = sign det(V·Uᵀ)` (never a reflection) and `t = q̄ − R·p̄`. Expressed about a pivot `c`
//! as a [`RigidMotion`] (`x ↦ R·(x − c) + c + t_c`): `t_c = t + R·c − c`.
//!
//! **Pivot.** Over fitted motions `(R_k, t_k)` (about the origin) of several jaw poses, the
//! pivot is the point that moves least in the least-squares sense:
//! `c* = argmin_c Σ_k ‖(R_k − I)·c + t_k‖²`, a linear least-squares problem `A·c = b` with
//! `A` the stacked `R_k − I` and `b` the stacked `−t_k`. Directions the motions cannot
//! determine (e.g. along the axis of a pure hinge) are taken from a reference point `c₀`
//! (the lower teeth's rest centroid): `c* = c₀ + A⁺·(b − A·c₀)`, with the pseudo-inverse
//! dropping singular values below `1e-6 × σ_max`.
//!
//! Blending shapes linearly moves the teeth along straight lines, which is not a rigid
//! motion for a rotating jaw, so partial weights give non-zero fit errors: they are reported.

use nalgebra::{Matrix3, Point3, Vector3};

use super::expression::ExpressionCode;
use super::face_rig::FaceRig;
use super::regions::Region;
use crate::geometry::rigid::KabschError;

pub use crate::sim::attachment::RigidFit;

/// Why a rigid fit could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum JawError {
    #[error("rigid fit needs the same number of rest and posed points (got {rest} and {posed})")]
    LengthMismatch { rest: usize, posed: usize },
    #[error("rigid fit needs at least 3 points, got {0}")]
    TooFewPoints(usize),
    #[error("a rigid fit or pivot got or produced a non-finite value")]
    NonFinite,
    #[error("jaw pivot needs at least one motion")]
    NoMotions,
    #[error("`{0}` is not a shape of the default expression code")]
    UnknownShape(String),
}

/// Kabsch fit of `posed ≈ R·rest + t` (module doc, [`crate::geometry::rigid`]), returned
/// as a motion about `pivot`.
pub fn fit_rigid(
    rest: &[Point3<f64>],
    posed: &[Point3<f64>],
    pivot: &Point3<f64>,
) -> Result<RigidFit, JawError> {
    RigidFit::fit(rest, posed, pivot).map_err(|e| match e {
        KabschError::LengthMismatch { rest, posed } => JawError::LengthMismatch { rest, posed },
        KabschError::TooFewPoints(n) => JawError::TooFewPoints(n),
        KabschError::NonFinite => JawError::NonFinite,
    })
}

/// The point that moves least over `motions` (each about the origin: `x ↦ R_k·x + t_k`), in
/// the least-squares sense, with undetermined directions taken from `reference` (module doc).
/// Also returns the singular values of the stacked `R_k − I` (largest first), which say how
/// well each direction is determined.
pub fn least_moving_point(
    motions: &[(Matrix3<f64>, Vector3<f64>)],
    reference: &Point3<f64>,
) -> Result<(Point3<f64>, Vector3<f64>), JawError> {
    if motions.is_empty() {
        return Err(JawError::NoMotions);
    }
    if !motions
        .iter()
        .all(|(r, t)| r.iter().chain(t.iter()).all(|c| c.is_finite()))
        || !reference.coords.iter().all(|c| c.is_finite())
    {
        return Err(JawError::NonFinite);
    }
    // Normal equations of A·c = b: (AᵀA)·c = Aᵀb, solved by eigen-decomposition of AᵀA
    // (3 × 3, symmetric) so small directions can be dropped: c = c₀ + (AᵀA)⁺·Aᵀ(b − A·c₀).
    let mut ata = Matrix3::zeros();
    let mut atr = Vector3::zeros();
    for (r, t) in motions {
        let a = r - Matrix3::identity();
        let residual = -t - a * reference.coords;
        ata += a.transpose() * a;
        atr += a.transpose() * residual;
    }
    let eig = ata.symmetric_eigen();
    let max = eig.eigenvalues.max();
    let mut delta = Vector3::zeros();
    for k in 0..3 {
        let lambda = eig.eigenvalues[k];
        // Singular values of A are sqrt(λ); drop σ < 1e-6·σ_max ⇔ λ < 1e-12·λ_max.
        if lambda > 1e-12 * max {
            let e = eig.eigenvectors.column(k);
            delta += e * (e.dot(&atr) / lambda);
        }
    }
    let mut sigma: Vec<f64> = eig.eigenvalues.iter().map(|l| l.max(0.0).sqrt()).collect();
    sigma.sort_by(|a, b| b.total_cmp(a));
    Ok((
        reference + delta,
        Vector3::new(sigma[0], sigma[1], sigma[2]),
    ))
}

/// The jaw transform of a pose: the rigid fit of the lower teeth from the identity's rest to
/// the posed positions (full rig vertex arrays), about `pivot`.
pub fn fit_jaw(
    rest: &[Point3<f64>],
    posed: &[Point3<f64>],
    pivot: &Point3<f64>,
) -> Result<RigidFit, JawError> {
    let teeth = Region::LowerTeeth.vertices();
    if rest.len() < teeth.end || posed.len() < teeth.end {
        return Err(JawError::TooFewPoints(rest.len().min(posed.len())));
    }
    fit_rigid(&rest[teeth.clone()], &posed[teeth], pivot)
}

/// The jaw shapes and weights the pivot is estimated from.
pub const PIVOT_SHAPES: [&str; 4] = ["jawOpen", "jawLeft", "jawRight", "jawForward"];
pub const PIVOT_WEIGHTS: [f64; 4] = [0.25, 0.5, 0.75, 1.0];

/// The estimated jaw pivot of an identity, and the data behind it.
#[derive(Clone, Debug, PartialEq)]
pub struct PivotEstimate {
    /// cm.
    pub pivot: Point3<f64>,
    /// Singular values of the stacked `R_k − I` (largest first): near-zero ones mean a
    /// direction the jaw shapes do not determine (filled from the teeth's rest centroid).
    pub singular_values: Vector3<f64>,
    /// RMS over the poses of the pivot's displacement `‖(R_k − I)·c + t_k‖` (cm).
    pub rms_pivot_motion: f64,
}

/// Estimates the jaw pivot of `identity` from the lower teeth's fitted motions under
/// [`PIVOT_SHAPES`] at [`PIVOT_WEIGHTS`] (module doc).
pub fn estimate_pivot(rig: &FaceRig, identity: Option<usize>) -> Result<PivotEstimate, JawError> {
    estimate_pivot_from(rig, identity, &PIVOT_SHAPES, &PIVOT_WEIGHTS)
}

/// [`estimate_pivot`] from the given default-code shapes at the given weights. Shapes not in
/// the default code are an error ([`JawError::UnknownShape`]).
pub fn estimate_pivot_from(
    rig: &FaceRig,
    identity: Option<usize>,
    shapes: &[&str],
    weights: &[f64],
) -> Result<PivotEstimate, JawError> {
    let rest = rig.base(identity);
    let teeth = Region::LowerTeeth.vertices();
    let centroid = Point3::from(
        rest[teeth.clone()]
            .iter()
            .fold(Vector3::zeros(), |s, p| s + p.coords)
            / teeth.len() as f64,
    );
    let mut motions = Vec::new();
    for &name in shapes {
        for &w in weights {
            let code = ExpressionCode::single(name, w)
                .ok_or_else(|| JawError::UnknownShape(name.to_string()))?;
            let posed = rig.pose(identity, &code);
            let fit = fit_jaw(rest, &posed, &Point3::origin())?;
            motions.push((fit.motion.rotation_matrix(), fit.motion.translation));
        }
    }
    let (pivot, singular_values) = least_moving_point(&motions, &centroid)?;
    let sum2: f64 = motions
        .iter()
        .map(|(r, t)| ((r - Matrix3::identity()) * pivot.coords + t).norm_squared())
        .sum();
    Ok(PivotEstimate {
        pivot,
        singular_values,
        rms_pivot_motion: (sum2 / motions.len() as f64).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::RigidMotion;
    use nalgebra::Rotation3;
    use rand::{Rng, SeedableRng};

    fn random_points(n: usize, seed: u64) -> Vec<Point3<f64>> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                Point3::new(
                    rng.random_range(-3.0..3.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-2.0..2.0),
                )
            })
            .collect()
    }

    #[test]
    fn recovers_a_known_motion_about_any_pivot() {
        let rest = random_points(50, 1);
        let pivot = Point3::new(0.0, -1.5, -8.0);
        let truth = RigidMotion {
            rotation: Vector3::new(0.3, -0.1, 0.05),
            translation: Vector3::new(0.2, -0.4, 0.1),
        };
        let posed: Vec<_> = rest.iter().map(|p| truth.apply_about(&pivot, p)).collect();
        let fit = fit_rigid(&rest, &posed, &pivot).unwrap();
        assert!((fit.motion.rotation - truth.rotation).norm() < 1e-12);
        assert!((fit.motion.translation - truth.translation).norm() < 1e-12);
        assert!(fit.rms_error < 1e-12 && fit.max_error < 1e-12);
        // The same motion about another pivot moves the points identically.
        let other = fit_rigid(&rest, &posed, &Point3::origin()).unwrap();
        for p in &rest {
            let a = fit.motion.apply_about(&fit.pivot, p);
            let b = other.motion.apply_about(&Point3::origin(), p);
            assert!((a - b).norm() < 1e-12);
        }
    }

    #[test]
    fn never_returns_a_reflection() {
        // Mirrored points: the best proper rotation, not the mirror.
        let rest = random_points(30, 2);
        let posed: Vec<_> = rest.iter().map(|p| Point3::new(-p.x, p.y, p.z)).collect();
        let fit = fit_rigid(&rest, &posed, &Point3::origin()).unwrap();
        let r = fit.motion.rotation_matrix();
        assert!((r.determinant() - 1.0).abs() < 1e-12);
        assert!(fit.rms_error > 0.1);
    }

    #[test]
    fn rejects_bad_input() {
        let p = random_points(3, 3);
        assert_eq!(
            fit_rigid(&p, &p[..2], &Point3::origin()),
            Err(JawError::LengthMismatch { rest: 3, posed: 2 })
        );
        assert_eq!(
            fit_rigid(&p[..2], &p[..2], &Point3::origin()),
            Err(JawError::TooFewPoints(2))
        );
        let mut bad = p.clone();
        bad[1].y = f64::NAN;
        assert_eq!(
            fit_rigid(&p, &bad, &Point3::origin()),
            Err(JawError::NonFinite)
        );
        assert_eq!(
            least_moving_point(&[], &Point3::origin()),
            Err(JawError::NoMotions)
        );
    }

    #[test]
    fn least_moving_point_finds_a_hinge_and_keeps_the_reference_along_its_axis() {
        let pivot = Point3::new(0.5, -1.0, -7.0);
        let motion = |rot: Vector3<f64>| {
            let r = Rotation3::from_scaled_axis(rot).into_inner();
            (r, pivot.coords - r * pivot.coords)
        };
        // Pure hinge about x: x is undetermined and comes from the reference.
        let hinge = [
            motion(Vector3::new(0.1, 0.0, 0.0)),
            motion(Vector3::new(0.3, 0.0, 0.0)),
        ];
        let reference = Point3::new(2.0, 0.0, 0.0);
        let (c, sigma) = least_moving_point(&hinge, &reference).unwrap();
        assert!((c - Point3::new(2.0, -1.0, -7.0)).norm() < 1e-9, "{c}");
        assert!(sigma[2] < 1e-9 && sigma[1] > 0.05);
        // Add a rotation about y: fully determined.
        let both = [hinge[0], hinge[1], motion(Vector3::new(0.0, 0.2, 0.0))];
        let (c, sigma) = least_moving_point(&both, &reference).unwrap();
        assert!((c - pivot).norm() < 1e-9, "{c}");
        assert!(sigma[2] > 0.05);
    }

    #[test]
    fn jaw_open_fits_and_pivot_on_the_ict_rig() {
        let rig = crate::rig::test_support::rig();
        let est = estimate_pivot(rig, None).unwrap();
        let c = est.pivot;
        eprintln!(
            "jaw pivot (neutral): ({:.3}, {:.3}, {:.3}) cm, σ = {:.4?}, rms pivot motion {:.4} cm",
            c.x, c.y, c.z, est.singular_values, est.rms_pivot_motion
        );
        // Behind and below the teeth, on the mid-plane, near where a mandible's condyles sit.
        assert!(c.x.abs() < 0.2, "{c}");
        let teeth = Region::LowerTeeth.vertices();
        let rest = rig.neutral();
        let front_z = rest[teeth.clone()]
            .iter()
            .map(|p| p.z)
            .fold(f64::MIN, f64::max);
        assert!(
            c.z < front_z - 4.0,
            "pivot {c} not behind the teeth (front z {front_z})"
        );
        assert!(est.singular_values[2] > 1e-3, "{:?}", est.singular_values);

        let mut rms = Vec::new();
        for w in [0.25, 0.5, 1.0] {
            let posed = rig.pose(None, &ExpressionCode::single("jawOpen", w).unwrap());
            let fit = fit_jaw(rest, &posed, &c).unwrap();
            eprintln!(
                "jawOpen {w}: rotation {:.4?} rad ({:.2}°), translation {:.4?} cm, rms {:.5} cm, max {:.5} cm",
                fit.motion.rotation,
                fit.motion.rotation.norm().to_degrees(),
                fit.motion.translation,
                fit.rms_error,
                fit.max_error
            );
            // The jaw opens about x (mouth opening: the chin goes down, i.e. rotation about +x
            // moves points below and in front of the pivot towards −y).
            assert!(fit.motion.rotation.x > 0.0);
            let r = fit.motion.rotation;
            assert!(r.x > 5.0 * r.y.hypot(r.z), "{r}");
            rms.push(fit.rms_error);
        }
        // Full weight is the shape itself (nearly rigid in the rig); half weight is a linear
        // blend of a rotation and the least rigid.
        assert!(rms[2] < rms[1], "{rms:?}");
        assert!(rms[1] > rms[0], "{rms:?}");

        // jawOpen alone is a hinge about x: its least-moving line, at the teeth's x.
        let hinge = estimate_pivot_from(rig, None, &["jawOpen"], &PIVOT_WEIGHTS).unwrap();
        eprintln!(
            "jawOpen-only hinge: y = {:.3}, z = {:.3} cm (x undetermined, σ = {:.4?}), rms pivot motion {:.4} cm",
            hinge.pivot.y, hinge.pivot.z, hinge.singular_values, hinge.rms_pivot_motion
        );
        assert!(hinge.singular_values[2] < 1e-3 * hinge.singular_values[0]);
        assert!(matches!(
            estimate_pivot_from(rig, None, &["eyeBlink_L"], &[1.0]),
            Err(JawError::UnknownShape(_))
        ));
        for i in 0..rig.identity_count() {
            let e = estimate_pivot(rig, Some(i)).unwrap();
            let p = e.pivot;
            eprintln!(
                "jaw pivot identity {i}: ({:.3}, {:.3}, {:.3}) cm, σ = {:.4?}",
                p.x, p.y, p.z, e.singular_values
            );
            assert!((p - c).norm() < 1.0, "{p} vs {c}");
            assert!(e.singular_values[2] > 1e-3, "{:?}", e.singular_values);
        }
    }
}
