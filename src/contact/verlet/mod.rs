//! Verlet lists for the line search: candidate pairs together with their exact distance
//! where the list was built, and a per-step filter that keeps only the pairs that can come
//! within d̂ during the step. CCD and the barrier of every line-search trial then run over
//! those few pairs instead of every pair whose boxes overlap (on the face, most overlapping
//! pairs are neighbours along the finely tessellated surface that move together).
//!
//! The filter rests on distances being 1-Lipschitz in *relative* motion. With `u` the
//! displacement of every vertex since the list's positions `y₀`:
//! - point–triangle: `d(y) ≥ d(y₀) − maxᵢ ‖u_p − u_tᵢ‖`;
//! - edge–edge: `d(y) ≥ d(y₀) − max_{i,j} ‖u_aᵢ − u_bⱼ‖`
//!
//! (the closest points move by a convex combination of those differences). Along a linear
//! step `u` is affine in the step fraction, so the bound's worst case is at the step's ends.
//! A pair left out can therefore neither touch nor enter the barrier's range during the step.

use rayon::prelude::*;

use super::ContactError;
use super::candidates::{Candidates, FixedPrimitives};
use super::collisions::CollisionKind;
use super::math::{Vec3, stencil, vertex};
use super::mesh::ContactMesh;

/// Candidate pairs and their distances at the positions `y₀` they were built at.
#[derive(Clone, Debug)]
pub struct VerletList {
    y0: Vec<f64>,
    /// The list holds every pair that can come within d̂ while each vertex stays within
    /// `slack` (Euclidean, cm) of `y₀`; `None`: built for one swept step only.
    slack: Option<f64>,
    /// The list holds every pair closer than this at `y₀` (cm; `dhat + 2·slack`).
    reach: f64,
    candidates: Candidates,
    /// `d(y₀)` per point–triangle and edge–edge pair (cm).
    pt_distance: Vec<f64>,
    ee_distance: Vec<f64>,
}

impl VerletList {
    /// Every pair that can come within `dhat` while each vertex stays within `slack` of
    /// `y` (cm): the pairs closer than `dhat + 2·slack` at `y`.
    pub fn build(
        mesh: &ContactMesh,
        fixed: &FixedPrimitives,
        y: &[f64],
        dhat: f64,
        slack: f64,
    ) -> Result<Self, ContactError> {
        let reach = dhat + 2.0 * slack;
        let boxes = Candidates::build_with(mesh, fixed, y, reach)?;
        Ok(Self::with_distances(
            mesh,
            boxes,
            y,
            Some(slack),
            reach,
            |_, d| d < reach,
        ))
    }

    /// Every pair that can come within `dhat` during the step `y → y + dy` (valid for this
    /// step only): swept boxes, then the relative-motion bound.
    pub fn build_swept(
        mesh: &ContactMesh,
        fixed: &FixedPrimitives,
        y: &[f64],
        dy: &[f64],
        dhat: f64,
    ) -> Result<Self, ContactError> {
        let boxes = Candidates::build_swept_near(mesh, fixed, y, dy, dhat)?;
        Ok(Self::with_distances(
            mesh,
            boxes,
            y,
            None,
            dhat,
            |ids, d| d - relative_motion(ids, dy) < dhat,
        ))
    }

    fn with_distances(
        mesh: &ContactMesh,
        boxes: Candidates,
        y: &[f64],
        slack: Option<f64>,
        reach: f64,
        keep: impl Fn(&Stencil, f64) -> bool + Sync,
    ) -> Self {
        let faces = mesh.faces();
        let edges = mesh.edges();
        let pt: Vec<(_, f64)> = boxes
            .point_triangle
            .par_iter()
            .filter_map(|c| {
                let f = faces[c.face as usize];
                let ids = Stencil::PointTriangle([c.vertex, f[0], f[1], f[2]]);
                let d = ids.distance(y);
                keep(&ids, d).then_some((*c, d))
            })
            .collect();
        let ee: Vec<(_, f64)> = boxes
            .edge_edge
            .par_iter()
            .filter_map(|c| {
                let [a0, a1] = edges[c.edge_a as usize];
                let [b0, b1] = edges[c.edge_b as usize];
                let ids = Stencil::EdgeEdge([a0, a1, b0, b1]);
                let d = ids.distance(y);
                keep(&ids, d).then_some((*c, d))
            })
            .collect();
        let (point_triangle, pt_distance) = pt.into_iter().unzip();
        let (edge_edge, ee_distance) = ee.into_iter().unzip();
        Self {
            y0: y.to_vec(),
            slack,
            reach,
            candidates: Candidates {
                point_triangle,
                edge_edge,
            },
            pt_distance,
            ee_distance,
        }
    }

    /// The pairs held (sorted), as built.
    pub fn candidates(&self) -> &Candidates {
        &self.candidates
    }

    /// Pairs held (all that the list can ever return).
    pub fn len(&self) -> usize {
        self.candidates.len()
    }

    pub fn is_empty(&self) -> bool {
        self.candidates.is_empty()
    }

    /// Whether the list holds every pair that can come within d̂ during `y → y + dy`: both
    /// ends of every vertex's move within the slack of `y₀` (a swept list covers no other
    /// step than its own).
    pub fn covers(&self, y: &[f64], dy: &[f64]) -> bool {
        let Some(slack) = self.slack else {
            return false;
        };
        within(&self.y0, y, dy, slack)
    }

    /// Whether both ends of every vertex's move `y → y + dy` are within `distance` of `y₀`
    /// (false for a swept list).
    pub fn moved_within(&self, y: &[f64], dy: &[f64], distance: f64) -> bool {
        self.slack.is_some() && within(&self.y0, y, dy, distance)
    }

    /// The pairs that can come within `dhat` during `y → y + dy` (a subset of the list,
    /// in its order), for CCD and the barrier along the step. The caller checked
    /// [`VerletList::covers`] (or built the list for this step).
    pub fn near(
        &self,
        mesh: &ContactMesh,
        y: &[f64],
        dy: &[f64],
        dhat: f64,
    ) -> Result<Candidates, ContactError> {
        let (start, end) = self.moves(mesh, y, dy)?;
        Ok(self.listed_near(mesh, &start, &end, dhat))
    }

    /// The pairs that can come within `dhat` during `y → y + dy`, whether or not the list
    /// covers the step (a list built with a slack, i.e. by [`VerletList::build`]): the
    /// list's pairs that can ([`VerletList::near`]), and the pairs beyond the list's reach
    /// that can, found from the relative motion since `y₀` with the same bound
    /// (`Candidates::build_moved`: cheap while the surface moves smoothly since `y₀`, as
    /// neighbours moving together are never visited). Returns them (sorted) and how many
    /// came from beyond the list. `fixed` must be the trees the list was built with.
    pub fn near_beyond(
        &self,
        mesh: &ContactMesh,
        fixed: &FixedPrimitives,
        y: &[f64],
        dy: &[f64],
        dhat: f64,
    ) -> Result<(Candidates, usize), ContactError> {
        if self.slack.is_none() {
            return Err(ContactError::InvalidParameter(
                "a swept Verlet list covers its own step only".into(),
            ));
        }
        let (start, end) = self.moves(mesh, y, dy)?;
        let listed = self.listed_near(mesh, &start, &end, dhat);
        let beyond =
            Candidates::build_moved(mesh, fixed, &self.y0, &start, &end, dhat, self.reach)?;
        let faces = mesh.faces();
        let edges = mesh.edges();
        let closest = |ids: Stencil| {
            ids.distance(&self.y0) - relative_motion(&ids, &start).max(relative_motion(&ids, &end))
        };
        let point_triangle: Vec<_> = beyond
            .point_triangle
            .into_par_iter()
            .filter(|c| {
                let f = faces[c.face as usize];
                self.candidates.point_triangle.binary_search(c).is_err()
                    && activates(
                        closest(Stencil::PointTriangle([c.vertex, f[0], f[1], f[2]])),
                        dhat,
                        || mesh.point_triangle_activation(c.vertex, c.face),
                    )
            })
            .collect();
        let edge_edge: Vec<_> = beyond
            .edge_edge
            .into_par_iter()
            .filter(|c| {
                let [a0, a1] = edges[c.edge_a as usize];
                let [b0, b1] = edges[c.edge_b as usize];
                self.candidates.edge_edge.binary_search(c).is_err()
                    && activates(closest(Stencil::EdgeEdge([a0, a1, b0, b1])), dhat, || {
                        mesh.edge_edge_activation(c.edge_a, c.edge_b)
                    })
            })
            .collect();
        let extra = point_triangle.len() + edge_edge.len();
        Ok((
            Candidates {
                point_triangle: merge_sorted(listed.point_triangle, point_triangle),
                edge_edge: merge_sorted(listed.edge_edge, edge_edge),
            },
            extra,
        ))
    }

    /// Displacements since `y₀` at the step's start and end.
    fn moves(
        &self,
        mesh: &ContactMesh,
        y: &[f64],
        dy: &[f64],
    ) -> Result<(Vec<f64>, Vec<f64>), ContactError> {
        mesh.check_positions(y)?;
        mesh.check_positions(dy)?;
        let start: Vec<f64> = y.par_iter().zip(&self.y0).map(|(p, q)| p - q).collect();
        let end: Vec<f64> = start.par_iter().zip(dy).map(|(u, d)| u + d).collect();
        Ok((start, end))
    }

    /// The list's pairs that can come within `dhat` while the displacements since `y₀`
    /// go from `start` to `end`.
    fn listed_near(&self, mesh: &ContactMesh, start: &[f64], end: &[f64], dhat: f64) -> Candidates {
        let faces = mesh.faces();
        let edges = mesh.edges();
        let closest = |ids: Stencil, d0: f64| {
            d0 - relative_motion(&ids, start).max(relative_motion(&ids, end))
        };
        let point_triangle = self
            .candidates
            .point_triangle
            .par_iter()
            .zip(&self.pt_distance)
            .filter(|(c, d0)| {
                let f = faces[c.face as usize];
                activates(
                    closest(Stencil::PointTriangle([c.vertex, f[0], f[1], f[2]]), **d0),
                    dhat,
                    || mesh.point_triangle_activation(c.vertex, c.face),
                )
            })
            .map(|(c, _)| *c)
            .collect();
        let edge_edge = self
            .candidates
            .edge_edge
            .par_iter()
            .zip(&self.ee_distance)
            .filter(|(c, d0)| {
                let [a0, a1] = edges[c.edge_a as usize];
                let [b0, b1] = edges[c.edge_b as usize];
                activates(
                    closest(Stencil::EdgeEdge([a0, a1, b0, b1]), **d0),
                    dhat,
                    || mesh.edge_edge_activation(c.edge_a, c.edge_b),
                )
            })
            .map(|(c, _)| *c)
            .collect();
        Candidates {
            point_triangle,
            edge_edge,
        }
    }
}

/// Whether a pair whose distance stays at least `closest` during the step can reach its
/// activation distance: `dhat`, or its own (smaller) one for a pair close at rest, looked
/// up only for the few pairs that pass the first test. (A pair that cannot reach its
/// activation distance can neither touch nor enter the barrier, so CCD and the barrier
/// both skip it: close pairs would otherwise pass every step, being within d̂ from the
/// start.)
fn activates(closest: f64, dhat: f64, own: impl Fn() -> Option<f64>) -> bool {
    closest < dhat && own().is_none_or(|a| a > 0.0 && closest < a)
}

/// Whether both ends of every vertex's move `y → y + dy` are within `distance` of `y0`.
fn within(y0: &[f64], y: &[f64], dy: &[f64], distance: f64) -> bool {
    let d2 = distance * distance;
    y.par_chunks_exact(3)
        .zip(dy.par_chunks_exact(3))
        .zip(y0.par_chunks_exact(3))
        .all(|((p, d), q)| {
            let (mut a, mut b) = (0.0, 0.0);
            for k in 0..3 {
                a += (p[k] - q[k]).powi(2);
                b += (p[k] + d[k] - q[k]).powi(2);
            }
            a <= d2 && b <= d2
        })
}

/// Two sorted lists with no common element, merged.
fn merge_sorted<T: Ord + Copy>(a: Vec<T>, b: Vec<T>) -> Vec<T> {
    if b.is_empty() {
        return a;
    }
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        if a[i] <= b[j] {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// The four vertices of a pair, by kind.
#[derive(Clone, Copy)]
enum Stencil {
    PointTriangle([u32; 4]),
    EdgeEdge([u32; 4]),
}

impl Stencil {
    fn distance(&self, y: &[f64]) -> f64 {
        match *self {
            Stencil::PointTriangle(ids) => {
                CollisionKind::PointTriangle.distance_squared(&stencil(y, ids))
            }
            Stencil::EdgeEdge(ids) => CollisionKind::EdgeEdge.distance_squared(&stencil(y, ids)),
        }
        .sqrt()
    }
}

/// The largest relative displacement between the pair's two sides under displacements `u`
/// (module doc): how much closer the pair can have come.
fn relative_motion(ids: &Stencil, u: &[f64]) -> f64 {
    let diff = |a: u32, b: u32| -> f64 {
        let d: Vec3 = vertex(u, a) - vertex(u, b);
        d.norm_squared()
    };
    match *ids {
        Stencil::PointTriangle([p, t0, t1, t2]) => diff(p, t0).max(diff(p, t1)).max(diff(p, t2)),
        Stencil::EdgeEdge([a0, a1, b0, b1]) => diff(a0, b0)
            .max(diff(a0, b1))
            .max(diff(a1, b0))
            .max(diff(a1, b1)),
    }
    .sqrt()
}

#[cfg(test)]
mod tests;
