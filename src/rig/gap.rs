//! Gaps: the minimum distance between non-adjacent parts of a surface near some vertices, as
//! a contact barrier sees it (IPC: point–triangle and edge–edge pairs that share no vertex).
//!
//! `gap(S, V) = min( min_{v ∈ V, t ∌ v} d(x_v, t), min_{e ∋ some v ∈ V, e' ∩ e = ∅} d(e, e') )`
//! over the surface's triangles `t` and triangulation edges `e, e'` (cm). Used to check that
//! a rest surface keeps `gap ≥ d̂` (e.g. `d̂ = 0.001 ×` the face's diameter) where it once
//! intersected itself. The gap of an intersecting surface is not 0 in general: check
//! [`self_intersections`](super::intersect::self_intersections) first.

use nalgebra::Point3;
use rayon::prelude::*;

use super::surface::SurfaceTopology;
use crate::geometry::bvh::{Box3, BoxTree};
pub use crate::geometry::distance::{
    closest_point_on_triangle, point_triangle_distance, segment_segment_distance,
    segment_segment_params,
};

/// The pair realising a gap.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum GapWitness {
    /// A vertex and a triangle (index into the surface's triangles) not containing it.
    PointTriangle { vertex: u32, triangle: u32 },
    /// Two triangulation edges without a common vertex (each `[a, b]` with `a < b`).
    EdgeEdge { a: [u32; 2], b: [u32; 2] },
}

/// The minimum distance between non-adjacent parts of a surface and where it is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Gap {
    /// cm.
    pub distance: f64,
    pub witness: GapWitness,
}

/// Which pairs count as "non-adjacent parts" and how far to look.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GapQuery {
    /// Pairs farther apart than this are not reported (cm).
    pub search_radius: f64,
    /// Pairs whose vertices are within this distance of each other along the surface's
    /// edges are neighbours, not separate parts, and are skipped (cm). `0` skips only pairs
    /// sharing a vertex (IPC's rule). A finely meshed region (the lip corners have 0.06 mm
    /// edges) needs a radius of a few `d̂` so that a sheet's own neighbouring elements do not
    /// count as a gap.
    pub exclusion_radius: f64,
}

/// Every pair (point–triangle with the point in `near`, edge–edge with an edge touching
/// `near`) of non-adjacent parts (see [`GapQuery`]) at most `query.search_radius` apart, each
/// reported once, sorted by distance then witness.
pub fn close_pairs(
    positions: &[Point3<f64>],
    surface: &SurfaceTopology,
    near: &[u32],
    query: &GapQuery,
) -> Vec<Gap> {
    let pos = |v: u32| &positions[v as usize];
    let radius = query.search_radius;
    let adjacency = surface.adjacency();
    let ball = |v: u32| adjacency.geodesic_ball(positions, v, query.exclusion_radius);
    let mut near: Vec<u32> = near.to_vec();
    near.sort_unstable();
    near.dedup();
    let is_near = |v: u32| near.binary_search(&v).is_ok();

    // Point–triangle.
    let tri_boxes: Vec<Box3> = surface
        .triangles
        .iter()
        .map(|t| Box3::around(&t.map(|v| *pos(v)), 0.0))
        .collect();
    let tri_tree = BoxTree::new(&tri_boxes);
    let mut pairs: Vec<Gap> = near
        .par_iter()
        .map_init(Vec::new, |found, &v| {
            let p = pos(v);
            tri_tree.overlapping(&Box3::around(&[*p], radius), found);
            let mut out = Vec::new();
            if found.is_empty() {
                return out;
            }
            let excluded = ball(v);
            for &ti in found.iter() {
                let t = surface.triangles[ti as usize];
                if t.iter().any(|u| excluded.binary_search(u).is_ok()) {
                    continue;
                }
                let d = point_triangle_distance(p, pos(t[0]), pos(t[1]), pos(t[2]));
                if d <= radius {
                    out.push(Gap {
                        distance: d,
                        witness: GapWitness::PointTriangle {
                            vertex: v,
                            triangle: ti,
                        },
                    });
                }
            }
            out
        })
        .flatten()
        .collect();

    // Edge–edge, over the triangulation's edges.
    let mut edges: Vec<[u32; 2]> = surface
        .triangles
        .iter()
        .flat_map(|t| (0..3).map(move |k| sorted(t[k], t[(k + 1) % 3])))
        .collect();
    edges.sort_unstable();
    edges.dedup();
    let edge_boxes: Vec<Box3> = edges
        .iter()
        .map(|e| Box3::around(&[*pos(e[0]), *pos(e[1])], 0.0))
        .collect();
    let edge_tree = BoxTree::new(&edge_boxes);
    let mut edge_pairs: Vec<Gap> = edges
        .par_iter()
        .filter(|e| is_near(e[0]) || is_near(e[1]))
        .map_init(Vec::new, |found, &e| {
            edge_tree.overlapping(&Box3::around(&[*pos(e[0]), *pos(e[1])], radius), found);
            let mut out = Vec::new();
            if found.len() <= 1 {
                return out;
            }
            let mut excluded = ball(e[0]);
            excluded.extend(ball(e[1]));
            excluded.sort_unstable();
            for &ei in found.iter() {
                let f = edges[ei as usize];
                if f.iter().any(|u| excluded.binary_search(u).is_ok()) {
                    continue;
                }
                // Each pair once: when both edges touch `near`, only from the smaller one.
                if (is_near(f[0]) || is_near(f[1])) && f < e {
                    continue;
                }
                let d = segment_segment_distance(pos(e[0]), pos(e[1]), pos(f[0]), pos(f[1]));
                if d <= radius {
                    let (a, b) = if e < f { (e, f) } else { (f, e) };
                    out.push(Gap {
                        distance: d,
                        witness: GapWitness::EdgeEdge { a, b },
                    });
                }
            }
            out
        })
        .flatten()
        .collect();
    pairs.append(&mut edge_pairs);
    pairs.sort_by(|x, y| {
        x.distance
            .total_cmp(&y.distance)
            .then(x.witness.cmp(&y.witness))
    });
    pairs
}

/// The gap near `near`: the closest of [`close_pairs`], or `None` when no pair of
/// non-adjacent parts is within `query.search_radius` (the gap is larger).
pub fn min_gap(
    positions: &[Point3<f64>],
    surface: &SurfaceTopology,
    near: &[u32],
    query: &GapQuery,
) -> Option<Gap> {
    close_pairs(positions, surface, near, query)
        .into_iter()
        .next()
}

fn sorted(a: u32, b: u32) -> [u32; 2] {
    if a < b { [a, b] } else { [b, a] }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::obj::Polygons;
    use crate::rig::surface::EdgeSet;
    use rand::{Rng, SeedableRng};

    #[test]
    fn point_triangle_distance_matches_sampling() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let pt = |rng: &mut rand_chacha::ChaCha8Rng| {
            Point3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            )
        };
        for _ in 0..200 {
            let (p, a, b, c) = (pt(&mut rng), pt(&mut rng), pt(&mut rng), pt(&mut rng));
            let d = point_triangle_distance(&p, &a, &b, &c);
            // No sample of the triangle is closer; a fine sampling gets within its spacing.
            let n = 60;
            let mut sampled = f64::INFINITY;
            for i in 0..=n {
                for j in 0..=n - i {
                    let (u, v) = (i as f64 / n as f64, j as f64 / n as f64);
                    let x = a + (b - a) * u + (c - a) * v;
                    sampled = sampled.min((p - x).norm());
                }
            }
            assert!(d <= sampled + 1e-12, "{d} > {sampled}");
            assert!(sampled - d < 0.05, "{d} vs {sampled}");
        }
    }

    #[test]
    fn segment_distance_cases() {
        let p = |x, y, z| Point3::new(x, y, z);
        // Skew, closest inside both.
        let d = segment_segment_distance(
            &p(-1., 0., 0.),
            &p(1., 0., 0.),
            &p(0., -1., 2.),
            &p(0., 1., 2.),
        );
        assert!((d - 2.0).abs() < 1e-15);
        // Parallel, overlapping.
        let d = segment_segment_distance(
            &p(0., 0., 0.),
            &p(2., 0., 0.),
            &p(1., 0.5, 0.),
            &p(3., 0.5, 0.),
        );
        assert!((d - 0.5).abs() < 1e-15);
        // Collinear, apart.
        let d = segment_segment_distance(
            &p(0., 0., 0.),
            &p(1., 0., 0.),
            &p(3., 0., 0.),
            &p(2., 0., 0.),
        );
        assert!((d - 1.0).abs() < 1e-15);
        // Endpoint to interior.
        let d = segment_segment_distance(
            &p(0., 0., 0.),
            &p(0., 0., 1.),
            &p(-1., 0.3, 2.),
            &p(1., 0.3, 2.),
        );
        assert!((d - (0.09f64 + 1.0).sqrt()).abs() < 1e-15);
        // Degenerate segment.
        let d = segment_segment_distance(
            &p(0., 0., 0.),
            &p(0., 0., 0.),
            &p(-1., 1., 0.),
            &p(1., 1., 0.),
        );
        assert!((d - 1.0).abs() < 1e-15);
    }

    #[test]
    fn gap_between_two_stacked_sheets() {
        // Two 3 × 3 quad sheets at z = 0 and z = 0.25; vertex-on-triangle gap 0.25.
        let mut pos = Vec::new();
        let mut quads = Vec::new();
        for (s, z) in [0.0, 0.25].into_iter().enumerate() {
            let off = (s * 16) as u32;
            for j in 0..4 {
                for i in 0..4 {
                    pos.push(Point3::new(i as f64, j as f64, z));
                }
            }
            for j in 0..3 {
                for i in 0..3 {
                    let v = off + j * 4 + i;
                    quads.push([v, v + 1, v + 5, v + 4]);
                }
            }
        }
        let faces = Polygons::from_lists(&quads);
        let surf = SurfaceTopology::from_all_faces(&faces, EdgeSet::Polygon);
        let near: Vec<u32> = (0..16).collect();
        let query = |search_radius, exclusion_radius| GapQuery {
            search_radius,
            exclusion_radius,
        };
        let g = min_gap(&pos, &surf, &near, &query(1.0, 0.0)).unwrap();
        assert!((g.distance - 0.25).abs() < 1e-12, "{g:?}");
        // Within a sheet, parts sharing no vertex are ≥ 0.7 apart, so a small search radius
        // finds nothing.
        assert!(min_gap(&pos, &surf, &near, &query(0.2, 0.0)).is_none());
        // Within a sheet only (the upper sheet moved away): diagonal neighbours at 1/√2,
        // excluded once they are within the geodesic exclusion radius.
        let mut apart = pos.clone();
        for p in &mut apart[16..] {
            p.z += 10.0;
        }
        let g = min_gap(&apart, &surf, &near, &query(1.0, 0.0)).unwrap();
        assert!((g.distance - 0.5f64.sqrt()).abs() < 1e-12, "{g:?}");
        let g = min_gap(&apart, &surf, &near, &query(3.0, 1.5)).unwrap();
        assert!(g.distance >= 1.0 - 1e-12, "{g:?}");
        // Every close pair once, sorted.
        let all = close_pairs(&pos, &surf, &near, &query(0.3, 0.0));
        assert!(all.windows(2).all(|w| w[0].distance <= w[1].distance));
        let mut witnesses: Vec<_> = all.iter().map(|g| g.witness).collect();
        witnesses.sort();
        witnesses.dedup();
        assert_eq!(witnesses.len(), all.len());
        // Deterministic witness: the smallest of the equal-distance pairs.
        let g = min_gap(&pos, &surf, &near, &query(1.0, 0.0)).unwrap();
        assert_eq!(
            g.witness,
            GapWitness::PointTriangle {
                vertex: 0,
                triangle: 18
            }
        );
    }
}
