//! Steps filtered by division planes: the largest fraction `t ∈ [0, 1]` of a linear update
//! `x → x + t·Δx` after which every candidate pair is still apart, by at least a set share of
//! the distance it started at. The "Planar-DAT" filter of ipc-toolkit
//! (`ogc::TrustRegion::planar_filter_step`; Chen et al. 2025, "Offset Geometric Contact", and
//! the divide-and-truncate framework it cites), here as one step fraction for the whole
//! surface, which is what the solver's line search and the pose stages need.
//!
//! **The bound.** Take a pair of primitives `A`, `B` (a point and a triangle, or two edges) at
//! distance `d > 0`, with closest points `c_A ∈ A`, `c_B ∈ B` and `n = (c_A − c_B)/d`. Both are
//! convex, so the plane through `c_B` normal to `n` has all of `B` on its far side and the one
//! through `c_A` all of `A` on its near side: `(x − c_A)·n ≥ 0` for every `x ∈ A` and
//! `(x − c_B)·n ≤ 0` for every `x ∈ B`. Put the division plane between them, through
//! `p = c_B + λ·(c_A − c_B)` with `λ = δ_B/(δ_A + δ_B)`, where `δ_A = maxᵤ∈A max(0, −Δxᵤ·n)`
//! and `δ_B = maxᵤ∈B max(0, Δxᵤ·n)` are how fast each side approaches it (`½` when neither
//! does): vertex `u` of `A` starts `sᵤ = (xᵤ − p)·n ≥ (1 − λ)·d` from the plane, one of `B`
//! `sᵤ = (p − xᵤ)·n ≥ λ·d`. Each vertex moving toward the plane may cover at most
//! `(1 − keep)·sᵤ` of that along `n`, so `t ≤ (1 − keep)·sᵤ/mᵤ` with `mᵤ` its approach per
//! unit step. Along the straight motion every vertex of `A` then stays at least
//! `keep·(1 − λ)·d` on its side and every vertex of `B` at least `keep·λ·d` on its own; the
//! primitives are the convex hulls of their vertices, so all of `A` and all of `B` stay on
//! their sides and the pair stays at least `keep·d` apart at every `t' ≤ t`. Motion along the
//! plane (lips sliding over each other, however close) costs nothing, which is what makes
//! this cheaper than conservative advancement (additive CCD advances a sliding pair by about
//! its distance per iteration).
//!
//! **Which pairs.** The bound covers the pairs it is given: the caller passes candidates that
//! hold every pair whose swept boxes can meet along the step (the solver's Verlet list with
//! its slack, or [`Candidates::build_swept`]), as for CCD. A pair that starts touching
//! (`d = 0`) allows no step.

use nalgebra::Point3;
use rayon::prelude::*;

use super::ContactError;
use super::candidates::Candidates;
use super::collisions::CollisionKind;
use super::math::{Vec3, stencil};
use super::mesh::ContactMesh;
use crate::geometry::distance::{closest_point_on_triangle, segment_segment_params};

/// The share of each pair's starting distance that a filtered step keeps (`keep ∈ (0, 1)`);
/// 0.1 matches additive CCD's default (`η = 0.9`) and ipc-toolkit's relaxed radius scaling.
pub const DEFAULT_KEEP: f64 = 0.1;

/// The filtered step of one whole surface.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanarReport {
    /// The step fraction `t ∈ [0, 1]`.
    pub step: f64,
    /// The pair that limits it (`None` when the full step is kept).
    pub limiting: Option<(CollisionKind, [u32; 4])>,
    /// Candidate pairs checked.
    pub candidates: usize,
}

fn check_keep(keep: f64) -> Result<(), ContactError> {
    if keep > 0.0 && keep < 1.0 {
        Ok(())
    } else {
        Err(ContactError::InvalidParameter(format!(
            "the share of the gap a filtered step keeps must be in (0, 1), got {keep}"
        )))
    }
}

/// The closest points of a stencil: `(c_A, c_B)` with `A` the point (edge `a`) and `B` the
/// triangle (edge `b`).
fn closest_points(kind: CollisionKind, x: &[Vec3; 4]) -> (Vec3, Vec3) {
    let [p0, p1, p2, p3] = x.map(Point3::from);
    match kind {
        CollisionKind::PointTriangle => {
            (x[0], closest_point_on_triangle(&p0, &p1, &p2, &p3).coords)
        }
        CollisionKind::EdgeEdge => {
            let (s, t) = segment_segment_params(&p0, &p1, &p2, &p3);
            (x[0] + (x[1] - x[0]) * s, x[2] + (x[3] - x[2]) * t)
        }
    }
}

/// Gaps below this share of the coordinates' magnitude count as touching (a few ulps: the
/// closest points are computed to about that).
const TOUCHING: f64 = 64.0 * f64::EPSILON;

/// How many of the stencil's vertices belong to side `A` (the point, or edge `a`).
fn side_a(kind: CollisionKind) -> usize {
    match kind {
        CollisionKind::PointTriangle => 1,
        CollisionKind::EdgeEdge => 2,
    }
}

/// The largest `t ∈ [0, 1]` of the step `x → x + t·dx` of one pair that keeps every vertex on
/// its side of the pair's division plane with `keep` of its distance to it (module doc), and
/// each vertex's own bound (1 where it does not approach the plane). 0 for a pair that starts
/// touching.
pub fn pair_vertex_steps(
    kind: CollisionKind,
    x: &[Vec3; 4],
    dx: &[Vec3; 4],
    keep: f64,
) -> [f64; 4] {
    let (ca, cb) = closest_points(kind, x);
    let gap = ca - cb;
    let d = gap.norm();
    // Closer than rounding can tell from touching: the plane's normal means nothing there.
    let scale = x.iter().map(|p| p.amax()).fold(0.0, f64::max);
    if !(d > TOUCHING * scale) {
        return [0.0; 4];
    }
    let n = gap / d;
    let a = side_a(kind);
    // Approach of each vertex toward the other side (positive: toward it).
    let approach = |u: usize| {
        let along = dx[u].dot(&n);
        if u < a { -along } else { along }
    };
    let (mut delta_a, mut delta_b) = (0.0f64, 0.0f64);
    for u in 0..4 {
        if u < a {
            delta_a = delta_a.max(approach(u));
        } else {
            delta_b = delta_b.max(approach(u));
        }
    }
    if delta_a + delta_b == 0.0 {
        return [1.0; 4];
    }
    let lambda = delta_b / (delta_a + delta_b);
    let p = cb + gap * lambda;
    let mut out = [1.0; 4];
    for u in 0..4 {
        let m = approach(u);
        if !(m > 0.0) {
            continue;
        }
        let along = (x[u] - p).dot(&n);
        // Rounding may put the closest vertex a hair past the plane: clamp to it.
        let s = if u < a { along } else { -along }.max(0.0);
        out[u] = ((1.0 - keep) * s / m).min(1.0);
    }
    out
}

/// [`pair_vertex_steps`] reduced to the pair's step.
pub fn pair_step(kind: CollisionKind, x: &[Vec3; 4], dx: &[Vec3; 4], keep: f64) -> f64 {
    pair_vertex_steps(kind, x, dx, keep)
        .into_iter()
        .fold(1.0, f64::min)
}

/// Every candidate pair's own filtered step along `x → x + dx` (kind, vertex ids, `t`),
/// point–triangle pairs first, each list in candidate order.
pub fn pair_steps(
    mesh: &ContactMesh,
    candidates: &Candidates,
    x: &[f64],
    dx: &[f64],
    keep: f64,
) -> Result<Vec<(CollisionKind, [u32; 4], f64)>, ContactError> {
    check_keep(keep)?;
    mesh.check_positions(x)?;
    mesh.check_positions(dx)?;
    let faces = mesh.faces();
    let edges = mesh.edges();
    let pt = candidates.point_triangle.par_iter().map(|c| {
        let f = faces[c.face as usize];
        let ids = [c.vertex, f[0], f[1], f[2]];
        let t = pair_step(
            CollisionKind::PointTriangle,
            &stencil(x, ids),
            &stencil(dx, ids),
            keep,
        );
        (CollisionKind::PointTriangle, ids, t)
    });
    let ee = candidates.edge_edge.par_iter().map(|c| {
        let [a0, a1] = edges[c.edge_a as usize];
        let [b0, b1] = edges[c.edge_b as usize];
        let ids = [a0, a1, b0, b1];
        let t = pair_step(
            CollisionKind::EdgeEdge,
            &stencil(x, ids),
            &stencil(dx, ids),
            keep,
        );
        (CollisionKind::EdgeEdge, ids, t)
    });
    let mut results: Vec<_> = pt.collect();
    results.extend(ee.collect::<Vec<_>>());
    Ok(results)
}

/// The filtered step of the whole surface over `candidates` (which must hold every pair whose
/// swept boxes can meet along the step): the smallest pair step. Deterministic: pairs are
/// checked in parallel and reduced in candidate order.
pub fn planar_step_over(
    mesh: &ContactMesh,
    candidates: &Candidates,
    x: &[f64],
    dx: &[f64],
    keep: f64,
) -> Result<PlanarReport, ContactError> {
    let results = pair_steps(mesh, candidates, x, dx, keep)?;
    let mut report = PlanarReport {
        step: 1.0,
        limiting: None,
        candidates: results.len(),
    };
    for (kind, ids, t) in results {
        if t < report.step {
            report.step = t;
            report.limiting = Some((kind, ids));
        }
    }
    Ok(report)
}

/// Each contact vertex's own bound over `candidates` (the smallest over the pairs it is in;
/// 1 for vertices no pair limits): ipc-toolkit's per-vertex truncation ratios
/// (`planar_filter_step` scales each vertex's displacement by this).
pub fn vertex_steps(
    mesh: &ContactMesh,
    candidates: &Candidates,
    x: &[f64],
    dx: &[f64],
    keep: f64,
) -> Result<Vec<f64>, ContactError> {
    check_keep(keep)?;
    mesh.check_positions(x)?;
    mesh.check_positions(dx)?;
    let mut out = vec![1.0f64; x.len() / 3];
    let faces = mesh.faces();
    let edges = mesh.edges();
    let stencils = candidates
        .point_triangle
        .iter()
        .map(|c| {
            let f = faces[c.face as usize];
            (CollisionKind::PointTriangle, [c.vertex, f[0], f[1], f[2]])
        })
        .chain(candidates.edge_edge.iter().map(|c| {
            let [a0, a1] = edges[c.edge_a as usize];
            let [b0, b1] = edges[c.edge_b as usize];
            (CollisionKind::EdgeEdge, [a0, a1, b0, b1])
        }));
    for (kind, ids) in stencils {
        let t = pair_vertex_steps(kind, &stencil(x, ids), &stencil(dx, ids), keep);
        for (u, &v) in ids.iter().enumerate() {
            out[v as usize] = out[v as usize].min(t[u]);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests;
