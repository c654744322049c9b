//! Verlet lists against brute force: every pair that comes within d̂ anywhere along a step
//! is among the near pairs, and pairs that move together are filtered out.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::contact::test_scenes::{striped_sheets, two_sheet_mesh, two_sheets};

/// Allowed pairs closer than `within` at `y`, by brute force: `(true, vertex, face)` or
/// `(false, edge a, edge b)`.
fn close_pairs(mesh: &ContactMesh, y: &[f64], within: f64) -> Vec<(bool, u32, u32)> {
    let all = Candidates::build(mesh, y, 10.0).unwrap();
    let pt = all.point_triangle.iter().map(|c| (true, c.vertex, c.face));
    let ee = all.edge_edge.iter().map(|c| (false, c.edge_a, c.edge_b));
    pt.chain(ee)
        .filter(|p| stencil_of(mesh, p).distance(y) < within)
        .collect()
}

/// The four vertices of a pair as [`close_pairs`] names it.
fn stencil_of(mesh: &ContactMesh, &(is_pt, a, b): &(bool, u32, u32)) -> Stencil {
    if is_pt {
        let f = mesh.faces()[b as usize];
        Stencil::PointTriangle([a, f[0], f[1], f[2]])
    } else {
        let ([a0, a1], [b0, b1]) = (mesh.edges()[a as usize], mesh.edges()[b as usize]);
        Stencil::EdgeEdge([a0, a1, b0, b1])
    }
}

fn contains(c: &Candidates, p: &(bool, u32, u32)) -> bool {
    match p {
        (true, v, f) => c
            .point_triangle
            .binary_search(&crate::contact::PointTriangleCandidate {
                vertex: *v,
                face: *f,
            })
            .is_ok(),
        (false, a, b) => c
            .edge_edge
            .binary_search(&crate::contact::EdgeEdgeCandidate {
                edge_a: *a,
                edge_b: *b,
            })
            .is_ok(),
    }
}

#[test]
fn near_pairs_hold_every_pair_within_dhat_along_the_step() {
    let (y, faces) = two_sheets(8, 0.06, [0.011, -0.017], 0.2, 0.01, 3);
    let mesh = two_sheet_mesh(&y, &faces);
    let fixed = FixedPrimitives::new(&mesh, &y).unwrap();
    let (dhat, slack) = (0.03, 0.05);
    let list = VerletList::build(&mesh, &fixed, &y, dhat, slack).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut checked = 0;
    for trial in 0..6 {
        // Start and end of the step within the slack; the sheets pushed together.
        let mut at = y.clone();
        let mut dy = vec![0.0; y.len()];
        for (i, (p, d)) in at.iter_mut().zip(dy.iter_mut()).enumerate() {
            let toward = if i % 3 == 2 && i / 3 < 64 { 0.01 } else { 0.0 };
            *p += rng.random_range(-0.008..0.008) + toward;
            *d = rng.random_range(-0.008..0.008) + toward;
        }
        assert!(list.covers(&at, &dy), "trial {trial} leaves the slack");
        let near = list.near(&mesh, &at, &dy, dhat).unwrap();
        assert!(near.len() < list.len());
        for s in [0.0, 0.3, 0.7, 1.0] {
            let ys: Vec<f64> = at.iter().zip(&dy).map(|(p, d)| p + s * d).collect();
            for p in close_pairs(&mesh, &ys, dhat) {
                assert!(contains(&near, &p), "trial {trial}, s = {s}: missed {p:?}");
                checked += 1;
            }
        }
        // The swept list for the same step holds them too.
        let swept = VerletList::build_swept(&mesh, &fixed, &at, &dy, dhat).unwrap();
        assert!(!swept.covers(&at, &dy), "a swept list covers no other step");
        let near = swept.near(&mesh, &at, &dy, dhat).unwrap();
        for s in [0.0, 0.5, 1.0] {
            let ys: Vec<f64> = at.iter().zip(&dy).map(|(p, d)| p + s * d).collect();
            for p in close_pairs(&mesh, &ys, dhat) {
                assert!(contains(&near, &p), "swept, s = {s}: missed {p:?}");
            }
        }
    }
    assert!(checked > 0, "the scene must bring pairs within d̂");
    // A step that leaves the slack is not covered.
    let far = vec![2.0 * slack; y.len()];
    assert!(!list.covers(&y, &far));
}

/// Pairs that translate together cannot approach: only those already within d̂ are near.
#[test]
fn common_translation_keeps_only_pairs_within_dhat() {
    let (y, faces) = two_sheets(8, 0.04, [0.0, 0.0], 0.0, 0.005, 9);
    let mesh = two_sheet_mesh(&y, &faces);
    let fixed = FixedPrimitives::new(&mesh, &y).unwrap();
    let dhat = 0.05;
    let list = VerletList::build(&mesh, &fixed, &y, dhat, 0.04).unwrap();
    let dy: Vec<f64> = (0..y.len()).map(|i| [0.02, -0.01, 0.015][i % 3]).collect();
    assert!(list.covers(&y, &dy));
    let near = list.near(&mesh, &y, &dy, dhat).unwrap();
    let within = close_pairs(&mesh, &y, dhat);
    assert_eq!(near.len(), within.len());
    assert!(within.iter().all(|p| contains(&near, p)));
    assert!(list.len() > near.len());
}

/// A step far beyond the slack: the list's near pairs plus those found beyond its reach
/// from the relative motion hold every pair that comes within d̂ along the step, and some
/// of them come from beyond the list.
#[test]
fn near_beyond_holds_every_pair_within_dhat_for_steps_leaving_the_slack() {
    let (y, faces) = two_sheets(8, 0.12, [0.011, -0.017], 0.2, 0.01, 4);
    let mesh = two_sheet_mesh(&y, &faces);
    let fixed = FixedPrimitives::new(&mesh, &y).unwrap();
    let (dhat, slack) = (0.03, 0.01);
    let list = VerletList::build(&mesh, &fixed, &y, dhat, slack).unwrap();
    let n = y.len() / 3;
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let mut extra_total = 0;
    let mut checked = 0;
    for trial in 0..4 {
        // The upper sheet moves down through most of the gap, with some shear and noise.
        let mut at = y.clone();
        let mut dy = vec![0.0; y.len()];
        for v in 0..n {
            let upper = v >= n / 2;
            for k in 0..3 {
                let i = 3 * v + k;
                let push = if upper && k == 2 { -0.05 } else { 0.0 };
                at[i] += push + rng.random_range(-0.004..0.004);
                dy[i] = push + if upper && k == 0 { 0.01 } else { 0.0 };
            }
        }
        assert!(
            !list.covers(&at, &dy),
            "trial {trial} stays within the slack"
        );
        let (near, extra) = list.near_beyond(&mesh, &fixed, &at, &dy, dhat).unwrap();
        extra_total += extra;
        assert!(near.point_triangle.windows(2).all(|w| w[0] < w[1]));
        assert!(near.edge_edge.windows(2).all(|w| w[0] < w[1]));
        for s in [0.0, 0.25, 0.5, 0.75, 1.0] {
            let ys: Vec<f64> = at.iter().zip(&dy).map(|(p, d)| p + s * d).collect();
            for p in close_pairs(&mesh, &ys, dhat) {
                assert!(contains(&near, &p), "trial {trial}, s = {s}: missed {p:?}");
                checked += 1;
            }
        }
    }
    assert!(checked > 0, "the scene must bring pairs within d̂");
    assert!(
        extra_total > 0,
        "some pairs must come from beyond the list's reach"
    );
    // A swept list covers its own step only.
    let dy = vec![0.0; y.len()];
    let swept = VerletList::build_swept(&mesh, &fixed, &y, &dy, dhat).unwrap();
    assert!(swept.near_beyond(&mesh, &fixed, &y, &dy, dhat).is_err());
}

/// A list built at one bone pose serves the next: with the rigid vertices moved since (the
/// fixed primitives' trees stay as built), the list's pairs and those found beyond it hold
/// every allowed pair that comes within d̂ along a step, rigid ones included.
#[test]
fn near_beyond_holds_every_pair_after_the_rigid_vertices_moved() {
    let (y, mesh, group) = striped_sheets();
    let fixed = FixedPrimitives::new(&mesh, &y).unwrap();
    assert!(fixed.vertex_count() > 0);
    let (dhat, slack) = (0.02, 0.005);
    let list = VerletList::build(&mesh, &fixed, &y, dhat, slack).unwrap();
    let n = y.len() / 3;
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let mut checked = 0;
    let mut rigid_pairs = 0;
    for trial in 0..4 {
        // The rigid vertices of the upper sheet translate down and sideways (their next
        // pose); the soft ones jitter and move on along the step.
        let mut at = y.clone();
        let mut dy = vec![0.0; y.len()];
        for (v, &g) in group.iter().enumerate() {
            let (upper, rigid) = (v >= n / 2, g != 0);
            for k in 0..3 {
                let i = 3 * v + k;
                if rigid {
                    at[i] += if upper { [0.01, -0.004, -0.02][k] } else { 0.0 };
                } else {
                    at[i] += rng.random_range(-0.004..0.004);
                    dy[i] = if upper && k == 2 { -0.01 } else { 0.0 };
                }
            }
        }
        assert!(!fixed.holds(&at), "trial {trial}: the rigid vertices moved");
        let (near, _) = list.near_beyond(&mesh, &fixed, &at, &dy, dhat).unwrap();
        for s in [0.0, 0.5, 1.0] {
            let ys: Vec<f64> = at.iter().zip(&dy).map(|(p, d)| p + s * d).collect();
            for p in close_pairs(&mesh, &ys, dhat) {
                assert!(contains(&near, &p), "trial {trial}, s = {s}: missed {p:?}");
                checked += 1;
                let (Stencil::PointTriangle(ids) | Stencil::EdgeEdge(ids)) = stencil_of(&mesh, &p);
                rigid_pairs += usize::from(ids.iter().any(|&v| group[v as usize] != 0));
            }
        }
    }
    assert!(
        checked > 0 && rigid_pairs > 0,
        "the scene must bring rigid pairs within d̂"
    );
}

/// The swept list's pruned traversal (subtrees left out by the relative-motion bound)
/// loses nothing: it holds exactly the swept-box candidates that pass the bound.
#[test]
fn swept_list_is_the_swept_candidates_that_pass_the_bound() {
    let (y, faces) = two_sheets(9, 0.05, [0.013, -0.021], 0.3, 0.01, 7);
    let mesh = two_sheet_mesh(&y, &faces);
    let fixed = FixedPrimitives::new(&mesh, &y).unwrap();
    let dhat = 0.03;
    let n = y.len() / 3;
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let dy: Vec<f64> = (0..y.len())
        .map(|i| {
            let sheet = if i / 3 >= n / 2 { -1.0 } else { 1.0 };
            sheet * if i % 3 == 2 { 0.02 } else { 0.0 } + rng.random_range(-0.01..0.01)
        })
        .collect();
    let list = VerletList::build_swept(&mesh, &fixed, &y, &dy, dhat).unwrap();
    let boxes = Candidates::build_swept_with(&mesh, &fixed, &y, &dy, dhat).unwrap();
    let faces = mesh.faces();
    let edges = mesh.edges();
    let keep = |ids: Stencil| ids.distance(&y) - relative_motion(&ids, &dy) < dhat;
    let point_triangle: Vec<_> = boxes
        .point_triangle
        .iter()
        .filter(|c| {
            let f = faces[c.face as usize];
            keep(Stencil::PointTriangle([c.vertex, f[0], f[1], f[2]]))
        })
        .copied()
        .collect();
    let edge_edge: Vec<_> = boxes
        .edge_edge
        .iter()
        .filter(|c| {
            let [a0, a1] = edges[c.edge_a as usize];
            let [b0, b1] = edges[c.edge_b as usize];
            keep(Stencil::EdgeEdge([a0, a1, b0, b1]))
        })
        .copied()
        .collect();
    assert!(!point_triangle.is_empty() && !edge_edge.is_empty());
    assert!(point_triangle.len() + edge_edge.len() < boxes.len());
    assert_eq!(list.candidates.point_triangle, point_triangle);
    assert_eq!(list.candidates.edge_edge, edge_edge);
}

/// Pairs close at rest (own activation distance, here half their distance) are near only
/// when the step can bring them within that distance: every pair that comes within its
/// activation distance along the step is near (from the list and from beyond it), and the
/// close pairs the step cannot bring that close are left out.
#[test]
fn close_pairs_are_near_only_when_they_can_reach_their_own_activation() {
    let (y, faces) = two_sheets(8, 0.02, [0.011, -0.017], 0.2, 0.004, 3);
    let plain = two_sheet_mesh(&y, &faces);
    let (dhat, slack) = (0.03, 0.05);
    let (mut pt, mut ee) = (Vec::new(), Vec::new());
    for p in close_pairs(&plain, &y, dhat) {
        let (is_pt, a, b) = p;
        let own = 0.5 * stencil_of(&plain, &p).distance(&y);
        if is_pt {
            pt.push(((a, b), own))
        } else {
            ee.push(((a, b), own))
        }
    }
    assert!(
        !pt.is_empty() && !ee.is_empty(),
        "the scene has pairs within d̂"
    );
    let mesh = plain.clone().with_close_pairs(pt, ee);
    let fixed = FixedPrimitives::new(&mesh, &y).unwrap();
    let list = VerletList::build(&mesh, &fixed, &y, dhat, slack).unwrap();
    let plain_list = VerletList::build(&plain, &fixed, &y, dhat, slack).unwrap();
    let activation = |p: &(bool, u32, u32)| {
        match *p {
            (true, v, f) => mesh.point_triangle_activation(v, f),
            (false, a, b) => mesh.edge_edge_activation(a, b),
        }
        .unwrap_or(dhat)
    };
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (mut left_out, mut checked) = (0, 0);
    for (trial, scale) in [0.002, 0.002, 0.02, 0.1].into_iter().enumerate() {
        let mut at = y.clone();
        let mut dy = vec![0.0; y.len()];
        for (p, d) in at.iter_mut().zip(dy.iter_mut()) {
            *p += rng.random_range(-scale..scale);
            *d = rng.random_range(-scale..scale);
        }
        let near = if list.covers(&at, &dy) {
            list.near(&mesh, &at, &dy, dhat).unwrap()
        } else {
            list.near_beyond(&mesh, &fixed, &at, &dy, dhat).unwrap().0
        };
        let near_plain = plain_list
            .near_beyond(&plain, &fixed, &at, &dy, dhat)
            .unwrap()
            .0;
        left_out += near_plain.len() - near.len();
        for s in [0.0, 0.25, 0.5, 0.75, 1.0] {
            let ys: Vec<f64> = at.iter().zip(&dy).map(|(p, d)| p + s * d).collect();
            for p in close_pairs(&mesh, &ys, dhat) {
                if stencil_of(&mesh, &p).distance(&ys) < activation(&p) {
                    assert!(contains(&near, &p), "trial {trial}, s = {s}: missed {p:?}");
                    checked += 1;
                }
            }
        }
    }
    assert!(
        checked > 0,
        "some pairs must come within their activation distance"
    );
    assert!(left_out > 0, "small steps must leave close pairs out");
}

/// A pair attached at rest (activation 0, [`crate::contact::surface::ATTACHED_AT_REST`]) is
/// never a candidate, however close; a close pair is one below its own activation distance,
/// and any other pair below d̂.
#[test]
fn an_attached_pair_never_activates() {
    assert!(!activates(0.0, 1.0, || Some(0.0)));
    assert!(activates(0.1, 1.0, || Some(0.2)));
    assert!(!activates(0.3, 1.0, || Some(0.2)));
    assert!(activates(0.9, 1.0, || None));
    assert!(!activates(1.0, 1.0, || None));
}
