//! Candidates against brute force: nothing within the inflation distance is ever missed.

use super::*;
use crate::contact::collisions::{Collision, CollisionKind, Collisions};
use crate::contact::distance::{edge_edge_distance, point_triangle_distance};
use crate::contact::math::{stencil, vertex};
use crate::contact::test_scenes::{striped_sheets, two_sheet_mesh, two_sheets};

fn brute_force(
    mesh: &ContactMesh,
    x: &[f64],
    within: f64,
) -> (Vec<PointTriangleCandidate>, Vec<EdgeEdgeCandidate>) {
    let w2 = within * within;
    let mut pt = Vec::new();
    for &v in mesh.vertices() {
        for (f, tri) in mesh.faces().iter().enumerate() {
            if tri.contains(&v) {
                continue;
            }
            let p = vertex(x, v);
            let [a, b, c] = tri.map(|t| vertex(x, t));
            if point_triangle_distance(&p, &a, &b, &c) < w2 {
                pt.push(PointTriangleCandidate {
                    vertex: v,
                    face: f as u32,
                });
            }
        }
    }
    let mut ee = Vec::new();
    let edges = mesh.edges();
    for (i, &[a0, a1]) in edges.iter().enumerate() {
        for (j, &[b0, b1]) in edges.iter().enumerate().skip(i + 1) {
            if a0 == b0 || a0 == b1 || a1 == b0 || a1 == b1 {
                continue;
            }
            let d = edge_edge_distance(
                &vertex(x, a0),
                &vertex(x, a1),
                &vertex(x, b0),
                &vertex(x, b1),
            );
            if d < w2 {
                ee.push(EdgeEdgeCandidate {
                    edge_a: i as u32,
                    edge_b: j as u32,
                });
            }
        }
    }
    (pt, ee)
}

#[test]
fn static_candidates_contain_every_close_pair() {
    let (x, faces) = two_sheets(9, 0.03, [0.013, -0.021], 0.3, 0.01, 7);
    let mesh = two_sheet_mesh(&x, &faces);
    let dhat = 0.05;
    let c = Candidates::build(&mesh, &x, dhat).unwrap();
    let (pt, ee) = brute_force(&mesh, &x, dhat);
    assert!(!pt.is_empty() && !ee.is_empty());
    for p in &pt {
        assert!(c.point_triangle.binary_search(p).is_ok(), "missed {p:?}");
    }
    for e in &ee {
        assert!(c.edge_edge.binary_search(e).is_ok(), "missed {e:?}");
    }
    // No pair shares a vertex.
    for p in &c.point_triangle {
        assert!(!faces[p.face as usize].contains(&p.vertex));
    }
    // Deterministic.
    assert_eq!(Candidates::build(&mesh, &x, dhat).unwrap(), c);
}

#[test]
fn swept_candidates_contain_every_pair_close_along_the_step() {
    let (x, faces) = two_sheets(7, 0.2, [0.0, 0.0], 0.1, 0.02, 8);
    let mesh = two_sheet_mesh(&x, &faces);
    let n = x.len() / 3;
    // The upper sheet moves down through the lower one.
    let mut dx = vec![0.0; x.len()];
    for v in n / 2..n {
        dx[3 * v + 2] = -0.4;
    }
    let c = Candidates::build_swept(&mesh, &x, &dx, 0.0).unwrap();
    for k in 0..=20 {
        let t = k as f64 / 20.0;
        let xt: Vec<f64> = x.iter().zip(&dx).map(|(a, b)| a + t * b).collect();
        let (pt, ee) = brute_force(&mesh, &xt, 1e-3);
        for p in &pt {
            assert!(
                c.point_triangle.binary_search(p).is_ok(),
                "missed {p:?} at t = {t}"
            );
        }
        for e in &ee {
            assert!(
                c.edge_edge.binary_search(e).is_ok(),
                "missed {e:?} at t = {t}"
            );
        }
    }
}

#[test]
fn groups_that_may_not_touch_give_no_pairs() {
    let (x, faces) = two_sheets(5, 0.01, [0.0, 0.0], 0.0, 0.0, 9);
    let n = x.len() / 3;
    let group: Vec<u16> = (0..n).map(|v| (v >= n / 2) as u16).collect();
    let same = |a: u32, b: u32| group[a as usize] == group[b as usize];
    let check = |matrix: &[Vec<bool>], want_same: bool| {
        let mesh = ContactMesh::with_groups(&x, faces.clone(), group.clone(), matrix).unwrap();
        let c = Candidates::build(&mesh, &x, 0.05).unwrap();
        assert!(!c.is_empty());
        for p in &c.point_triangle {
            let f = faces[p.face as usize];
            assert!(f.iter().all(|&t| same(p.vertex, t) == want_same), "{p:?}");
        }
        for e in &c.edge_edge {
            let [a0, a1] = mesh.edges()[e.edge_a as usize];
            let [b0, b1] = mesh.edges()[e.edge_b as usize];
            assert!(
                [a0, a1]
                    .iter()
                    .all(|&a| same(a, b0) == want_same && same(a, b1) == want_same)
            );
        }
    };
    // Each sheet with itself only, then the sheets only with each other.
    check(&[vec![true, false], vec![false, true]], true);
    check(&[vec![false, true], vec![true, false]], false);
    assert!(
        ContactMesh::with_groups(
            &x,
            faces.clone(),
            group.clone(),
            &[vec![true, false], vec![true, true]]
        )
        .is_err()
    );
}

#[test]
fn bad_inputs_are_typed_errors() {
    let (x, faces) = two_sheets(3, 0.1, [0.0, 0.0], 0.0, 0.0, 1);
    let mesh = two_sheet_mesh(&x, &faces);
    assert!(matches!(
        Candidates::build(&mesh, &x[1..], 0.1),
        Err(ContactError::PositionsLength { .. })
    ));
    let mut bad = x.clone();
    bad[4] = f64::NAN;
    assert_eq!(
        Candidates::build(&mesh, &bad, 0.1),
        Err(ContactError::NonFinite(1))
    );
    assert!(matches!(
        Candidates::build(&mesh, &x, -1.0),
        Err(ContactError::InvalidParameter(_))
    ));
    assert!(matches!(
        ContactMesh::new(&x, vec![[0, 1, 99]]),
        Err(ContactError::InvalidMesh(_))
    ));
    assert!(matches!(
        ContactMesh::new(&x, vec![[0, 1, 1]]),
        Err(ContactError::InvalidMesh(_))
    ));
}

/// Two close sheets whose vertex groups run in stripes: soft (0), rigid on one bone (1),
/// rigid on another (2); rigid touches only soft. Positions, mesh and the groups.
/// Soft tissue that touches everything and rigid pieces that touch only soft tissue (the
/// face's groups) take the broad phase's two-tree path: it must still find every allowed
/// close pair; pairs close at rest stay candidates with their own activation distance.
#[test]
fn split_groups_miss_no_allowed_pair_and_close_pairs_activate_late() {
    let (x, mesh, _) = striped_sheets();
    assert!(mesh.groups_split_by_universal());
    let dhat = 0.05;
    let (pt, ee) = brute_force(&mesh, &x, dhat);
    let edges = mesh.edges();
    let allowed_pt: Vec<_> = pt
        .into_iter()
        .filter(|p| mesh.primitives_may_touch(&[p.vertex], &mesh.faces()[p.face as usize]))
        .collect();
    let allowed_ee: Vec<_> = ee
        .into_iter()
        .filter(|e| mesh.primitives_may_touch(&edges[e.edge_a as usize], &edges[e.edge_b as usize]))
        .collect();
    assert!(!allowed_pt.is_empty() && !allowed_ee.is_empty());
    // Among them pairs of a primitive half on a bone against one wholly on a bone: the soft
    // end can cross the rigid piece, so they are candidates too.
    let rigid = |v: &u32| !mesh.touches_all(*v);
    let mixed = |e: &[u32; 2]| e.iter().any(rigid) && !e.iter().all(rigid);
    assert!(allowed_ee.iter().any(|e| {
        let (a, b) = (edges[e.edge_a as usize], edges[e.edge_b as usize]);
        (a.iter().all(rigid) && mixed(&b)) || (b.iter().all(rigid) && mixed(&a))
    }));
    let c = Candidates::build(&mesh, &x, dhat).unwrap();
    for p in &allowed_pt {
        assert!(c.point_triangle.binary_search(p).is_ok(), "missed {p:?}");
    }
    for e in &allowed_ee {
        assert!(c.edge_edge.binary_search(e).is_ok(), "missed {e:?}");
    }
    // A close pair of each kind (own activation distance, half its distance here) stays a
    // candidate, so CCD tracks it; `split_close` sets exactly those apart, and the active set
    // takes each only below its own activation distance.
    let (p0, e0) = (allowed_pt[0], allowed_ee[0]);
    let f0 = mesh.faces()[p0.face as usize];
    let ([a0, a1], [b0, b1]) = (
        mesh.edges()[e0.edge_a as usize],
        mesh.edges()[e0.edge_b as usize],
    );
    let d_pt = CollisionKind::PointTriangle
        .distance_squared(&stencil(&x, [p0.vertex, f0[0], f0[1], f0[2]]))
        .sqrt();
    let d_ee = CollisionKind::EdgeEdge
        .distance_squared(&stencil(&x, [a0, a1, b0, b1]))
        .sqrt();
    let with_close = |scale: f64| {
        mesh.clone().with_close_pairs(
            vec![((p0.vertex, p0.face), scale * d_pt)],
            vec![((e0.edge_b, e0.edge_a), scale * d_ee)],
        )
    };
    let close = with_close(0.5);
    let c2 = Candidates::build(&close, &x, dhat).unwrap();
    assert_eq!(c2, c, "close pairs stay candidates");
    let (near, others) = c2.split_close(&close);
    assert_eq!(near.point_triangle, vec![p0]);
    assert_eq!(near.edge_edge, vec![e0]);
    assert_eq!(others.len() + 2, c.len());
    let is_p0 = |k: &Collision| k.vertices == [p0.vertex, f0[0], f0[1], f0[2]];
    let is_e0 = |k: &Collision| k.vertices == [a0, a1, b0, b1];
    let plain = Collisions::from_candidates(&mesh, &c, &x, dhat).unwrap();
    assert!(plain.collisions.iter().any(is_p0) && plain.collisions.iter().any(is_e0));
    let inactive = Collisions::from_candidates(&close, &c, &x, dhat).unwrap();
    assert!(!inactive.collisions.iter().any(|k| is_p0(k) || is_e0(k)));
    assert_eq!(inactive.len() + 2, plain.len());
    let active = Collisions::from_candidates(&with_close(2.0), &c, &x, dhat).unwrap();
    let own = active.collisions.iter().find(|k| is_p0(k)).unwrap();
    assert!((own.activation2 - 4.0 * d_pt * d_pt).abs() < 1e-15);
    assert_eq!(own.weight, (dhat * dhat / own.activation2).powi(2));
    assert!(plain.collisions.iter().all(|k| k.weight == 1.0));
}

/// With the rigid stripes' trees built once ([`FixedPrimitives`]), static and swept
/// candidates are the same lists as built from scratch, and the fixed vertices may not move.
#[test]
fn fixed_trees_give_the_same_candidates_and_refuse_moved_vertices() {
    let (x, mesh, group) = striped_sheets();
    let fixed = FixedPrimitives::new(&mesh, &x).unwrap();
    assert!(fixed.vertex_count() > 0);
    let dhat = 0.05;
    let plain = Candidates::build(&mesh, &x, dhat).unwrap();
    let with = Candidates::build_with(&mesh, &fixed, &x, dhat).unwrap();
    assert!(!plain.point_triangle.is_empty() && !plain.edge_edge.is_empty());
    assert_eq!(plain, with);
    // A step that moves only the soft vertices toward the other sheet.
    let dx: Vec<f64> = (0..x.len())
        .map(|i| {
            let v = i / 3;
            if group[v] == 0 && i % 3 == 2 {
                -0.02 * ((v % 5) as f64 + 1.0)
            } else {
                0.0
            }
        })
        .collect();
    let plain = Candidates::build_swept(&mesh, &x, &dx, dhat).unwrap();
    let with = Candidates::build_swept_with(&mesh, &fixed, &x, &dx, dhat).unwrap();
    assert_eq!(plain, with);
    // Moving a fixed vertex (in the step or in the positions) is refused.
    let rigid = (0..group.len()).find(|&v| group[v] != 0).unwrap();
    let mut bad = dx.clone();
    bad[3 * rigid] = 0.01;
    assert!(Candidates::build_swept_with(&mesh, &fixed, &x, &bad, dhat).is_err());
    let mut moved = x.clone();
    moved[3 * rigid] += 0.01;
    assert!(Candidates::build_with(&mesh, &fixed, &moved, dhat).is_err());
}

/// Cells (e.g. the simulation elements render vertices are embedded in) leave out exactly
/// the pairs they keep apart ([`ContactMesh::kept_apart`]); every other close pair is still
/// found, and vertices with no cell are never left out.
#[test]
fn pairs_kept_apart_by_cells_are_left_out_and_no_other() {
    let (x, faces) = two_sheets(9, 0.03, [0.013, -0.021], 0.3, 0.01, 7);
    let n = x.len() / 3;
    let plain = two_sheet_mesh(&x, &faces);
    // Cells of 3×3 neighbouring vertices of each 9×9 sheet, those along a row sharing
    // faces; the last vertices belong to no cell.
    let of_vertex: Vec<u32> = (0..n as u32)
        .map(|v| {
            let (sheet, i, j) = (v / 81, (v % 81) / 9, v % 9);
            if (v as usize) + 7 >= n {
                crate::contact::mesh::NO_CELL
            } else {
                sheet * 9 + (i / 3) * 3 + j / 3
            }
        })
        .collect();
    let face_neighbours = (0..18u32)
        .filter(|c| c % 3 != 2)
        .map(|c| (c, c + 1))
        .collect();
    let cells = crate::contact::mesh::Cells {
        of_vertex,
        inside: vec![true; n],
        face_neighbours,
    };
    let celled = plain.clone().with_cells(cells).unwrap();
    let dhat = 0.05;
    let all = Candidates::build(&plain, &x, dhat).unwrap();
    let kept = Candidates::build(&celled, &x, dhat).unwrap();
    let want_pt: Vec<_> = all
        .point_triangle
        .iter()
        .copied()
        .filter(|p| !celled.kept_apart(&[p.vertex], &plain.faces()[p.face as usize]))
        .collect();
    let want_ee: Vec<_> = all
        .edge_edge
        .iter()
        .copied()
        .filter(|e| {
            let (a, b) = (
                plain.edges()[e.edge_a as usize],
                plain.edges()[e.edge_b as usize],
            );
            !celled.kept_apart(&a, &b)
        })
        .collect();
    assert!(want_pt.len() < all.point_triangle.len() && want_ee.len() < all.edge_edge.len());
    assert!(!want_pt.is_empty() && !want_ee.is_empty());
    assert_eq!(kept.point_triangle, want_pt);
    assert_eq!(kept.edge_edge, want_ee);
    let last = (n - 1) as u32;
    assert!(!celled.kept_apart(&[last], &[last - 1]));
}
