//! Closest-feature classification: which pair of sub-features (vertex, edge interior, face
//! interior) realizes the distance between a point and a triangle or between two edges.
//!
//! The decision rules are ipc-toolkit's (`point_triangle_distance_type`,
//! `edge_edge_distance_type`, `edge_edge_parallel_distance_type`), so the two libraries pick
//! the same type away from ties; on a tie (a point exactly over a region boundary) both types
//! give the same distance. Degenerate inputs get a type whose distance is finite: a
//! zero-length edge is treated as its first vertex, a collinear triangle as its three edges.

use crate::contact::math::Vec3;

/// Closest feature of an edge `(e0, e1)` to a point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum PointEdgeDistanceType {
    /// The point is closest to `e0` (ipctk `P_E0`).
    Vertex0,
    /// The point is closest to `e1` (ipctk `P_E1`).
    Vertex1,
    /// The point projects inside the edge (ipctk `P_E`).
    Edge,
}

/// Closest feature of a triangle `(t0, t1, t2)` to a point. Edge `i` joins `tᵢ` and `tᵢ₊₁`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum PointTriangleDistanceType {
    /// ipctk `P_T0`.
    Vertex0,
    /// ipctk `P_T1`.
    Vertex1,
    /// ipctk `P_T2`.
    Vertex2,
    /// Edge `t0 t1` (ipctk `P_E0`).
    Edge0,
    /// Edge `t1 t2` (ipctk `P_E1`).
    Edge1,
    /// Edge `t2 t0` (ipctk `P_E2`).
    Edge2,
    /// The point projects inside the triangle (ipctk `P_T`).
    Face,
}

/// Closest features of edges `a = (ea0, ea1)` and `b = (eb0, eb1)`; `Ea` / `Eb` is the
/// interior of an edge, `Ea0` etc. an end point.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum EdgeEdgeDistanceType {
    Ea0Eb0,
    Ea0Eb1,
    Ea1Eb0,
    Ea1Eb1,
    /// Point `eb0` to the line of `a`.
    EaEb0,
    /// Point `eb1` to the line of `a`.
    EaEb1,
    /// Point `ea0` to the line of `b`.
    Ea0Eb,
    /// Point `ea1` to the line of `b`.
    Ea1Eb,
    /// Line to line (the closest points are inside both edges).
    EaEb,
}

impl PointTriangleDistanceType {
    /// ipc-toolkit's name for this type.
    pub fn ipctk_name(self) -> &'static str {
        match self {
            Self::Vertex0 => "P_T0",
            Self::Vertex1 => "P_T1",
            Self::Vertex2 => "P_T2",
            Self::Edge0 => "P_E0",
            Self::Edge1 => "P_E1",
            Self::Edge2 => "P_E2",
            Self::Face => "P_T",
        }
    }
}

impl EdgeEdgeDistanceType {
    /// ipc-toolkit's name for this type.
    pub fn ipctk_name(self) -> &'static str {
        match self {
            Self::Ea0Eb0 => "EA0_EB0",
            Self::Ea0Eb1 => "EA0_EB1",
            Self::Ea1Eb0 => "EA1_EB0",
            Self::Ea1Eb1 => "EA1_EB1",
            Self::EaEb0 => "EA_EB0",
            Self::EaEb1 => "EA_EB1",
            Self::Ea0Eb => "EA0_EB",
            Self::Ea1Eb => "EA1_EB",
            Self::EaEb => "EA_EB",
        }
    }
}

/// Edges count as parallel when `sin²θ < PARALLEL_THRESHOLD`, i.e. `‖u × v‖² <
/// PARALLEL_THRESHOLD·‖u‖²‖v‖²` (θ < 1.6e-8 rad): the line–line distance is then
/// ill-conditioned and the parallel rule below is used instead (ipc-toolkit's threshold).
pub const PARALLEL_THRESHOLD: f64 = 2.5e-16;

/// A triangle is degenerate (treated as its three edges) when `‖n‖² ≤ DEGENERATE_TRIANGLE ·
/// ℓ⁴` with `n = (t1 − t0) × (t2 − t0)` and `ℓ` its longest edge: below this the normal's
/// direction is rounding noise.
pub const DEGENERATE_TRIANGLE: f64 = 1e-24;

/// Closest feature of the edge `(e0, e1)` to `p`: with `s = (p − e0)·(e1 − e0)/‖e1 − e0‖²`,
/// `Vertex0` if `s < 0`, `Vertex1` if `s > 1`, else `Edge`. A zero-length edge gives `Vertex0`.
pub fn point_edge_distance_type(p: &Vec3, e0: &Vec3, e1: &Vec3) -> PointEdgeDistanceType {
    let e = e1 - e0;
    let ee = e.norm_squared();
    if ee == 0.0 {
        return PointEdgeDistanceType::Vertex0;
    }
    let s = e.dot(&(p - e0)) / ee;
    if s < 0.0 {
        PointEdgeDistanceType::Vertex0
    } else if s > 1.0 {
        PointEdgeDistanceType::Vertex1
    } else {
        PointEdgeDistanceType::Edge
    }
}

/// Whether the triangle is too thin to have a reliable normal ([`DEGENERATE_TRIANGLE`]).
pub fn is_degenerate_triangle(t0: &Vec3, t1: &Vec3, t2: &Vec3) -> bool {
    let n = (t1 - t0).cross(&(t2 - t0));
    let l2 = (t1 - t0)
        .norm_squared()
        .max((t2 - t1).norm_squared())
        .max((t0 - t2).norm_squared());
    !(n.norm_squared() > DEGENERATE_TRIANGLE * l2 * l2)
}

/// Closest feature of the triangle `(t0, t1, t2)` to `p`.
///
/// For each edge `i` (from `tᵢ` to `tᵢ₊₁`, direction `e`), with `n` the triangle normal:
/// `sᵢ = e·(p − tᵢ)/‖e‖²` is the position along the edge and `(e × n)·(p − tᵢ) ≥ 0` says `p`
/// lies on the outer side of the edge's line. Edge `i` is closest if `0 < sᵢ < 1` and `p` is
/// outside it; else vertex 0 if `s₀ ≤ 0` and `s₂ ≥ 1` (cyclically for vertices 1, 2); else
/// the face. Degenerate triangles ([`is_degenerate_triangle`]) use the closest of their three
/// edges.
pub fn point_triangle_distance_type(
    p: &Vec3,
    t0: &Vec3,
    t1: &Vec3,
    t2: &Vec3,
) -> PointTriangleDistanceType {
    use PointTriangleDistanceType as T;
    if is_degenerate_triangle(t0, t1, t2) {
        return degenerate_triangle_type(p, t0, t1, t2);
    }
    let n = (t1 - t0).cross(&(t2 - t0));
    let corners = [t0, t1, t2];
    let mut s = [0.0; 3];
    for i in 0..3 {
        let a = corners[i];
        let e = corners[(i + 1) % 3] - a;
        let r = p - a;
        s[i] = e.dot(&r) / e.norm_squared();
        let outside = e.cross(&n).dot(&r) >= 0.0;
        if s[i] > 0.0 && s[i] < 1.0 && outside {
            return [T::Edge0, T::Edge1, T::Edge2][i];
        }
    }
    if s[0] <= 0.0 && s[2] >= 1.0 {
        T::Vertex0
    } else if s[1] <= 0.0 && s[0] >= 1.0 {
        T::Vertex1
    } else if s[2] <= 0.0 && s[1] >= 1.0 {
        T::Vertex2
    } else {
        T::Face
    }
}

/// A degenerate triangle is a segment (or a point): the type of the nearest of its three
/// edges (first one on ties), never `Face`.
fn degenerate_triangle_type(
    p: &Vec3,
    t0: &Vec3,
    t1: &Vec3,
    t2: &Vec3,
) -> PointTriangleDistanceType {
    use PointTriangleDistanceType as T;
    let corners = [t0, t1, t2];
    let mut best = (f64::INFINITY, T::Vertex0);
    for i in 0..3 {
        let (a, b) = (corners[i], corners[(i + 1) % 3]);
        let (d, ty) = match point_edge_distance_type(p, a, b) {
            PointEdgeDistanceType::Vertex0 => ((p - a).norm_squared(), i),
            PointEdgeDistanceType::Vertex1 => ((p - b).norm_squared(), (i + 1) % 3),
            PointEdgeDistanceType::Edge => (super::primitives::point_line_distance(p, a, b), 3 + i),
        };
        if d < best.0 {
            best = (
                d,
                [
                    T::Vertex0,
                    T::Vertex1,
                    T::Vertex2,
                    T::Edge0,
                    T::Edge1,
                    T::Edge2,
                ][ty],
            );
        }
    }
    best.1
}

/// Closest features of edges `a = (ea0, ea1)` and `b = (eb0, eb1)`.
///
/// With `u = ea1 − ea0`, `v = eb1 − eb0`, `w = ea0 − eb0`, the closest points of the lines
/// are `ea0 + s·u` and `eb0 + t·v` with `s = (b·e − c·d)/D`, `t = (a·e − b·d)/D` (`a = u·u`,
/// `b = u·v`, `c = v·v`, `d = u·w`, `e = v·w`, `D = ac − b²`). `s` is clamped to `[0, 1]` first
/// (choosing an end of `a`), then `t` given `s`, then `s` is re-solved given the clamped `t`
/// (Eberly's segment–segment algorithm). Zero-length edges are points; parallel edges
/// ([`PARALLEL_THRESHOLD`]) go to [`edge_edge_parallel_distance_type`].
pub fn edge_edge_distance_type(
    ea0: &Vec3,
    ea1: &Vec3,
    eb0: &Vec3,
    eb1: &Vec3,
) -> EdgeEdgeDistanceType {
    use EdgeEdgeDistanceType as T;
    let u = ea1 - ea0;
    let v = eb1 - eb0;
    let w = ea0 - eb0;
    let a = u.norm_squared();
    let b = u.dot(&v);
    let c = v.norm_squared();
    let d = u.dot(&w);
    let e = v.dot(&w);
    let big_d = a * c - b * b;
    if a == 0.0 && c == 0.0 {
        return T::Ea0Eb0;
    } else if a == 0.0 {
        return T::Ea0Eb;
    } else if c == 0.0 {
        return T::EaEb0;
    }
    if u.cross(&v).norm_squared() < PARALLEL_THRESHOLD * a * c {
        return edge_edge_parallel_distance_type(ea0, ea1, eb0, eb1);
    }

    // Clamp s: an end of `a` may be the closest feature, with t solved for that end.
    let s_num = b * e - c * d;
    let (t_num, t_den, interior) = if s_num <= 0.0 {
        (e, c, T::Ea0Eb)
    } else if s_num >= big_d {
        (e + b, c, T::Ea1Eb)
    } else {
        (a * e - b * d, big_d, T::EaEb)
    };
    // Clamp t, and re-solve s for the chosen end of `b`.
    if t_num <= 0.0 {
        if -d <= 0.0 {
            T::Ea0Eb0
        } else if -d >= a {
            T::Ea1Eb0
        } else {
            T::EaEb0
        }
    } else if t_num >= t_den {
        if b - d <= 0.0 {
            T::Ea0Eb1
        } else if b - d >= a {
            T::Ea1Eb1
        } else {
            T::EaEb1
        }
    } else {
        interior
    }
}

/// Closest features of two parallel edges: with `α`, `β` the positions of `eb0`, `eb1` along
/// `a` (`(ebᵢ − ea0)·u/‖u‖²`), the end points of `b` inside `[0, 1]` see the interior of `a`,
/// and otherwise the nearest end points face each other (or `b` spans `a` entirely, when an end
/// of `a` sees the interior of `b`). Requires `‖ea1 − ea0‖ > 0`.
pub fn edge_edge_parallel_distance_type(
    ea0: &Vec3,
    ea1: &Vec3,
    eb0: &Vec3,
    eb1: &Vec3,
) -> EdgeEdgeDistanceType {
    use EdgeEdgeDistanceType as T;
    let u = ea1 - ea0;
    let uu = u.norm_squared();
    let alpha = (eb0 - ea0).dot(&u) / uu;
    let beta = (eb1 - ea0).dot(&u) / uu;
    let beta_inside = (0.0..=1.0).contains(&beta);
    // Closest feature of a: 0 = ea0, 1 = ea1, 2 = interior; of b: 0 = eb0, 1 = eb1, 2 = interior.
    let (fa, fb) = if alpha < 0.0 {
        let fa = if beta_inside { 2 } else { 0 };
        let fb = if beta <= alpha {
            0
        } else if beta <= 1.0 {
            1
        } else {
            2
        };
        (fa, fb)
    } else if alpha > 1.0 {
        let fa = if beta_inside { 2 } else { 1 };
        let fb = if beta >= alpha {
            0
        } else if beta >= 0.0 {
            1
        } else {
            2
        };
        (fa, fb)
    } else {
        (2, 0)
    };
    match (fa, fb) {
        (0, 0) => T::Ea0Eb0,
        (0, 1) => T::Ea0Eb1,
        (1, 0) => T::Ea1Eb0,
        (1, 1) => T::Ea1Eb1,
        (2, 0) => T::EaEb0,
        (2, 1) => T::EaEb1,
        (0, 2) => T::Ea0Eb,
        (1, 2) => T::Ea1Eb,
        // Both interiors can only face each other for non-parallel lines.
        _ => T::EaEb0,
    }
}
