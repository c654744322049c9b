//! Continuous collision detection: the largest step fraction `t ∈ [0, 1]` of a linear update
//! `x → x + t·Δx` that a line search may take without any pair of the contact surface
//! reaching distance `ξ` (`min_distance`, 0 by default) — the "collision-aware line search"
//! of IPC (Li et al. 2020, §4.4).
//!
//! Broad phase: candidates whose swept boxes (both ends of the step, grown by `ξ/2`) overlap.
//! Narrow phase: additive CCD ([`additive`]) for each, the minimum over all candidates. The
//! returned step is conservative by construction — it is a sum of advances each bounded by the
//! pair's current distance over its largest possible approach speed — and leaves every pair at
//! least `(1 − η)` of its initial gap apart, so the barrier stays finite and well-conditioned.

pub mod additive;

use rayon::prelude::*;

use super::ContactError;
use super::candidates::Candidates;
use super::collisions::CollisionKind;
use super::math::stencil;
use super::mesh::ContactMesh;

pub use additive::{NarrowPhase, edge_edge_ccd, point_triangle_ccd};

/// Settings of the additive CCD.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CcdOptions {
    /// η ∈ (0, 1): each advance covers the fraction η of the distance the pair can safely
    /// travel, and the march stops once a pair is within `(1 − η)·(d₀ − ξ)` of `ξ`: the
    /// returned step leaves at least that gap (ipc-toolkit's default 0.9; smaller is more
    /// cautious and takes more iterations).
    pub conservative_rescaling: f64,
    /// ξ (cm): the distance no pair may reach (0 for plain non-penetration).
    pub min_distance: f64,
    /// Cap on the advances of one pair; when hit, the time reached so far (still safe) is used.
    pub max_iterations: u64,
}

impl Default for CcdOptions {
    fn default() -> Self {
        Self {
            conservative_rescaling: 0.9,
            min_distance: 0.0,
            max_iterations: 1_000_000,
        }
    }
}

impl CcdOptions {
    fn validate(&self) -> Result<(), ContactError> {
        let eta = self.conservative_rescaling;
        if !(eta > 0.0 && eta < 1.0) {
            return Err(ContactError::InvalidParameter(format!(
                "CCD conservative rescaling must be in (0, 1), got {eta}"
            )));
        }
        if !(self.min_distance >= 0.0) || !self.min_distance.is_finite() {
            return Err(ContactError::InvalidParameter(format!(
                "CCD minimum distance must be finite and ≥ 0, got {}",
                self.min_distance
            )));
        }
        if self.max_iterations == 0 {
            return Err(ContactError::InvalidParameter(
                "CCD needs max_iterations ≥ 1".into(),
            ));
        }
        Ok(())
    }
}

/// How a narrow-phase query ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CcdOutcome {
    /// No impact before `t_max`: the whole interval is safe.
    Clear,
    /// The pair approaches: the step is cut where it is still `(1 − η)·(d₀ − ξ)` from `ξ`.
    Hit,
    /// The iteration cap was reached (a pair sliding very close): the time reached is kept.
    IterationCap,
    /// The pair starts at (or within rounding of) `ξ`: no motion can be certified, `t = 0`.
    TooClose,
}

/// The safe step for a whole surface.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    /// The step fraction `t ∈ [0, 1]`.
    pub step: f64,
    /// The pair that limits it (`None` when the full step is safe).
    pub limiting: Option<(CollisionKind, [u32; 4], CcdOutcome)>,
    /// Candidate pairs checked.
    pub candidates: usize,
    /// Pairs that hit the iteration cap.
    pub capped: usize,
}

/// The largest safe fraction `t ∈ [0, 1]` of the step `x → x + dx` (interleaved, cm).
///
/// Deterministic: pairs are checked in parallel but reduced in candidate order.
pub fn collision_free_step(
    mesh: &ContactMesh,
    x: &[f64],
    dx: &[f64],
    opts: &CcdOptions,
) -> Result<StepReport, ContactError> {
    opts.validate()?;
    let candidates = Candidates::build_swept(mesh, x, dx, opts.min_distance)?;
    collision_free_step_over(mesh, &candidates, x, dx, opts)
}

/// [`collision_free_step`] over candidates the caller already has: they must cover every pair
/// whose swept boxes (grown by `ξ/2`) overlap, e.g. [`Candidates::build_swept`] with an
/// inflation ≥ ξ (the solver builds them once per step with `d̂` and uses them for the
/// barrier along the line search too).
pub fn collision_free_step_over(
    mesh: &ContactMesh,
    candidates: &Candidates,
    x: &[f64],
    dx: &[f64],
    opts: &CcdOptions,
) -> Result<StepReport, ContactError> {
    let results = pair_steps(mesh, candidates, x, dx, opts)?;
    let mut report = StepReport {
        step: 1.0,
        limiting: None,
        candidates: results.len(),
        capped: 0,
    };
    for (kind, ids, r) in results {
        if r.outcome == CcdOutcome::IterationCap {
            report.capped += 1;
        }
        if r.toi < report.step {
            report.step = r.toi;
            report.limiting = Some((kind, ids, r.outcome));
        }
    }
    Ok(report)
}

/// Every candidate pair's own CCD along the step `x → x + dx` (kind, vertex ids, result),
/// point–triangle pairs first, each list in candidate order: [`collision_free_step_over`]
/// takes the earliest; a caller that needs every pair stopping short filters them.
pub fn pair_steps(
    mesh: &ContactMesh,
    candidates: &Candidates,
    x: &[f64],
    dx: &[f64],
    opts: &CcdOptions,
) -> Result<Vec<(CollisionKind, [u32; 4], NarrowPhase)>, ContactError> {
    opts.validate()?;
    mesh.check_positions(x)?;
    mesh.check_positions(dx)?;
    let faces = mesh.faces();
    let edges = mesh.edges();
    let pt = candidates.point_triangle.par_iter().map(|c| {
        let f = faces[c.face as usize];
        let ids = [c.vertex, f[0], f[1], f[2]];
        let r = point_triangle_ccd(&stencil(x, ids), &stencil(dx, ids), 1.0, opts);
        (CollisionKind::PointTriangle, ids, r)
    });
    let ee = candidates.edge_edge.par_iter().map(|c| {
        let [a0, a1] = edges[c.edge_a as usize];
        let [b0, b1] = edges[c.edge_b as usize];
        let ids = [a0, a1, b0, b1];
        let r = edge_edge_ccd(&stencil(x, ids), &stencil(dx, ids), 1.0, opts);
        (CollisionKind::EdgeEdge, ids, r)
    });
    let mut results: Vec<_> = pt.collect();
    results.extend(ee.collect::<Vec<_>>());
    Ok(results)
}

#[cfg(test)]
mod tests;
