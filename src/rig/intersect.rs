//! Self-intersections of a triangle surface: pairs (edge, triangle) where the edge crosses the
//! triangle, excluding pairs that share a vertex.
//!
//! Broad phase: a BVH over the triangles' boxes ([`BoxTree`]), queried with each edge's box.
//! Narrow phase: [`segment_crosses_triangle`] (exact-enough orientation tests with fixed tie
//! rules, [`crate::geometry::crossing`]).

use nalgebra::Point3;
use rayon::prelude::*;

use super::surface::SurfaceTopology;
use crate::geometry::bvh::{Box3, BoxTree};
use crate::geometry::crossing::segment_crosses_triangle;

/// An edge crossing a triangle.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct EdgeTrianglePair {
    /// The edge's vertices, `edge[0] < edge[1]`.
    pub edge: [u32; 2],
    /// Index into the surface's `triangles`.
    pub triangle: u32,
}

/// All (edge, triangle) pairs of `surface` at `positions` where the edge crosses the triangle
/// and the two share no vertex, sorted. Edges are `surface.edges`, so the count depends on
/// the surface's [`EdgeSet`](super::surface::EdgeSet).
pub fn self_intersections(
    positions: &[Point3<f64>],
    surface: &SurfaceTopology,
) -> Vec<EdgeTrianglePair> {
    let tri_boxes: Vec<Box3> = surface
        .triangles
        .iter()
        .map(|t| {
            Box3::around(
                &[
                    positions[t[0] as usize],
                    positions[t[1] as usize],
                    positions[t[2] as usize],
                ],
                0.0,
            )
        })
        .collect();
    let tree = BoxTree::new(&tri_boxes);
    let mut pairs: Vec<EdgeTrianglePair> = surface
        .edges
        .par_iter()
        .map_init(Vec::new, |found, &edge| {
            let (p, q) = (&positions[edge[0] as usize], &positions[edge[1] as usize]);
            tree.overlapping(&Box3::around(&[*p, *q], 0.0), found);
            found
                .iter()
                .filter_map(|&ti| {
                    let t = surface.triangles[ti as usize];
                    if t.contains(&edge[0]) || t.contains(&edge[1]) {
                        return None;
                    }
                    let tp = t.map(|v| &positions[v as usize]);
                    segment_crosses_triangle(p, q, tp, t)
                        .then_some(EdgeTrianglePair { edge, triangle: ti })
                })
                .collect::<Vec<_>>()
        })
        .flatten()
        .collect();
    pairs.sort_unstable();
    pairs
}

/// Vertices of the edges and triangles in `pairs`, sorted and unique.
pub fn vertices_of(surface: &SurfaceTopology, pairs: &[EdgeTrianglePair]) -> Vec<u32> {
    let mut v: Vec<u32> = pairs
        .iter()
        .flat_map(|p| {
            p.edge
                .into_iter()
                .chain(surface.triangles[p.triangle as usize])
        })
        .collect();
    v.sort_unstable();
    v.dedup();
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::obj::Polygons;
    use crate::rig::regions::Region;
    use crate::rig::surface::EdgeSet;
    use rand::{Rng, SeedableRng};

    /// Reference: Möller–Trumbore with barycentric coordinates, for generic configurations.
    fn crosses_parametric(p: &Point3<f64>, q: &Point3<f64>, t: [&Point3<f64>; 3]) -> bool {
        let d = q - p;
        let e1 = t[1] - t[0];
        let e2 = t[2] - t[0];
        let h = d.cross(&e2);
        let det = e1.dot(&h);
        let s = p - t[0];
        let u = s.dot(&h) / det;
        let qv = s.cross(&e1);
        let v = d.dot(&qv) / det;
        let s_param = e2.dot(&qv) / det;
        u > 0.0 && v > 0.0 && u + v < 1.0 && s_param > 0.0 && s_param < 1.0
    }

    #[test]
    fn matches_a_parametric_test_on_random_configurations() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let pt = |rng: &mut rand_chacha::ChaCha8Rng| {
            Point3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            )
        };
        let mut hits = 0;
        for _ in 0..20_000 {
            let (p, q) = (pt(&mut rng), pt(&mut rng));
            let (a, b, c) = (pt(&mut rng), pt(&mut rng), pt(&mut rng));
            let t = [&a, &b, &c];
            let expected = crosses_parametric(&p, &q, t);
            assert_eq!(segment_crosses_triangle(&p, &q, t, [0, 1, 2]), expected);
            // Orientation of the segment and the triangle do not matter.
            assert_eq!(segment_crosses_triangle(&q, &p, t, [0, 1, 2]), expected);
            assert_eq!(
                segment_crosses_triangle(&p, &q, [&b, &c, &a], [1, 2, 0]),
                expected
            );
            hits += expected as usize;
        }
        assert!(hits > 500, "{hits}");
    }

    #[test]
    fn ties_are_counted_once_across_a_shared_edge() {
        // Two triangles sharing edge 0-1 in the z = 0 plane; segments straight through points
        // of the shared edge (exact zeros in the edge test).
        let v = [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.0, 2.0, 0.0),
            Point3::new(1.0, 1.0, 0.0),
            Point3::new(-1.0, 1.0, 0.0),
        ];
        let t1 = [0u32, 2, 1];
        let t2 = [0u32, 1, 3];
        for y in [0.5, 1.0, 1.5] {
            for dir in [1.0, -1.0] {
                let p = Point3::new(0.0, y, -dir);
                let q = Point3::new(0.0, y, dir);
                let count = [t1, t2]
                    .iter()
                    .filter(|t| segment_crosses_triangle(&p, &q, t.map(|i| &v[i as usize]), **t))
                    .count();
                assert_eq!(count, 1, "y = {y}, dir = {dir}");
            }
        }
        // An endpoint on the plane counts as just behind it (opposite the normal, +z here):
        // touching from the front crosses, from behind does not; a segment in the plane never
        // crosses.
        let t = t1.map(|i| &v[i as usize]);
        let on_plane = Point3::new(0.5, 1.0, 0.0);
        assert!(segment_crosses_triangle(
            &on_plane,
            &Point3::new(0.5, 1.0, 1.0),
            t,
            t1
        ));
        assert!(!segment_crosses_triangle(
            &on_plane,
            &Point3::new(0.5, 1.0, -1.0),
            t,
            t1
        ));
        assert!(!segment_crosses_triangle(
            &Point3::new(0.2, 1.0, 0.0),
            &on_plane,
            t,
            t1
        ));
    }

    /// A flat grid of `n × n` quads in the z = 0 plane, spacing 1.
    fn grid(n: u32, z: f64, offset: u32) -> (Vec<Point3<f64>>, Vec<[u32; 4]>) {
        let mut pos = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                pos.push(Point3::new(i as f64, j as f64, z));
            }
        }
        let mut quads = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let v = offset + j * (n + 1) + i;
                quads.push([v, v + 1, v + n + 2, v + n + 1]);
            }
        }
        (pos, quads)
    }

    #[test]
    fn flat_sheet_has_none_and_a_poked_vertex_is_found() {
        let (mut pos, quads) = grid(6, 0.0, 0);
        let faces = Polygons::from_lists(&quads);
        let surf = SurfaceTopology::from_all_faces(&faces, EdgeSet::Polygon);
        assert!(self_intersections(&pos, &surf).is_empty());
        // A second, crossing sheet: the two sheets intersect along a line.
        let (mut pos2, quads2) = grid(6, 0.0, pos.len() as u32);
        for p in &mut pos2 {
            // Rotate the copy to the plane x = 2.5 (vertical), shifted so no vertex lies on
            // the first sheet.
            *p = Point3::new(2.5, p.x - 0.3, p.y - 3.2);
        }
        pos.extend(pos2);
        let all: Vec<[u32; 4]> = quads.iter().chain(&quads2).copied().collect();
        let faces = Polygons::from_lists(&all);
        let surf = SurfaceTopology::from_all_faces(&faces, EdgeSet::Polygon);
        let pairs = self_intersections(&pos, &surf);
        // Edges of the vertical sheet crossing z = 0 (between its rows z = −0.2 and 0.8): the
        // 7 vertical edges at x' = −0.3…5.7 whose x' lies within [0, 6] of the first sheet
        // (6 of them), each crossing one triangle; plus first-sheet edges crossing the second
        // sheet along x = 2.5: the 7 horizontal edges from x = 2 to 3 at y where the vertical
        // sheet has y ∈ [−0.3, 5.7] (6 of them).
        assert_eq!(pairs.len(), 12, "{pairs:?}");
        let mut sorted = pairs.clone();
        sorted.sort();
        assert_eq!(sorted, pairs);
        // A small displacement that removes the crossing changes the count.
        for p in &mut pos[49..] {
            p.z -= 10.0;
        }
        assert!(self_intersections(&pos, &surf).is_empty());
    }

    /// The rig's face skin at `positions`, triangulated, with all triangulation edges.
    fn skin(rig: &crate::rig::FaceRig) -> SurfaceTopology {
        SurfaceTopology::from_regions(rig.faces(), &[Region::FaceSkin], EdgeSet::Triangle)
    }

    #[test]
    fn neutral_skin_has_126_intersecting_pairs_at_the_inner_upper_lip() {
        let rig = crate::rig::test_support::rig();
        let skin = skin(rig);
        let pairs = self_intersections(rig.neutral(), &skin);
        // The user's 126: the face skin alone, quads split (c0, c1, c2) + (c0, c2, c3), every
        // triangulation edge (the quads' diagonals included).
        assert_eq!(pairs.len(), 126);
        // With the quads' own edges only, or split along the other diagonal, the count differs.
        let quad_edges =
            SurfaceTopology::from_regions(rig.faces(), &[Region::FaceSkin], EdgeSet::Polygon);
        assert_eq!(self_intersections(rig.neutral(), &quad_edges).len(), 66);
        // Adding the mouth socket and the head adds nothing: it is skin against skin.
        let more = SurfaceTopology::from_regions(
            rig.faces(),
            &[Region::FaceSkin, Region::HeadAndNeck, Region::MouthSocket],
            EdgeSet::Triangle,
        );
        assert_eq!(self_intersections(rig.neutral(), &more).len(), 126);
        // Where: 90 vertices in a thin band where the lips meet, towards both mouth corners
        // (x = ±1.6…2.3 cm, y = −3.52…−3.38 cm), mirror-symmetric.
        let verts = vertices_of(&skin, &pairs);
        assert_eq!(verts.len(), 90);
        for &v in &verts {
            let p = rig.neutral()[v as usize];
            assert!(
                (1.5..2.3).contains(&p.x.abs()) && (-3.52..-3.38).contains(&p.y) && p.z > 10.0,
                "vertex {v} at {p}"
            );
        }
        let left = verts
            .iter()
            .filter(|&&v| rig.neutral()[v as usize].x < 0.0)
            .count();
        assert_eq!(2 * left, verts.len());
    }

    #[test]
    fn every_identity_intersects_at_the_lips() {
        let rig = crate::rig::test_support::rig();
        let skin = skin(rig);
        let counts: Vec<usize> = (0..rig.identity_count())
            .map(|i| self_intersections(rig.base(Some(i)), &skin).len())
            .collect();
        eprintln!("skin self-intersections per identity: {counts:?}");
        assert_eq!(counts, [70, 106, 110, 134, 138, 152, 82, 20, 146, 130]);
    }

    #[test]
    fn random_lower_face_poses_add_intersections() {
        use crate::rig::ExpressionCode;
        let rig = crate::rig::test_support::rig();
        let skin = skin(rig);
        let rest = self_intersections(rig.neutral(), &skin);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2023);
        let mut added = Vec::new();
        for _ in 0..40 {
            let mut code = ExpressionCode::NEUTRAL;
            for w in &mut code.0 {
                *w = rng.random_range(0.0..1.0);
            }
            let pairs = self_intersections(&rig.pose(None, &code), &skin);
            let new = pairs
                .iter()
                .filter(|p| rest.binary_search(p).is_err())
                .count();
            if new > 0 {
                added.push(new);
            }
        }
        added.sort_unstable();
        let median = added.get(added.len() / 2).copied().unwrap_or(0);
        eprintln!(
            "random lower-face poses: {} of 40 add intersecting pairs, median {median} added",
            added.len()
        );
        assert!(added.len() >= 30, "{added:?}");
        assert!((50..400).contains(&median), "{added:?}");
    }
}
