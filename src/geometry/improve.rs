//! Tetrahedral mesh improvement by "smart" Laplacian smoothing (Freitag, Jones & Plassmann
//! 1995): each movable vertex tries the centroid of its neighbours (and points on the way
//! there, toward the apex that would make its worst element regular, and for poor spots a
//! compass search) and moves only if the worst dihedral angle of the elements around it gets
//! better.
//! Elements never invert and the worst angle around a vertex never decreases.

use nalgebra::Point3;

use super::shell::dihedral_angles;
use super::tet_mesh::TetMesh;

/// Vertices whose worst incident dihedral angle stays below this (degrees) also get a compass
/// search (small steps along ±x, ±y, ±z at three scales).
const COMPASS_BELOW_DEG: f64 = 15.0;

/// What an improvement pass did.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImproveReport {
    pub sweeps: usize,
    pub moves: usize,
    pub min_dihedral_before: f64,
    pub min_dihedral_after: f64,
}

/// Improves `mesh` in place, moving only vertices with `movable[v]`.
pub fn smart_smooth(mesh: &mut TetMesh, movable: &[bool], sweeps: usize) -> ImproveReport {
    let n = mesh.vertex_count();
    let mut elements_of = vec![Vec::new(); n];
    let mut neighbours = vec![Vec::new(); n];
    for (e, tet) in mesh.tets.iter().enumerate() {
        for &v in tet {
            elements_of[v as usize].push(e as u32);
            neighbours[v as usize].extend(tet.iter().copied().filter(|&w| w != v));
        }
    }
    for list in &mut neighbours {
        list.sort_unstable();
        list.dedup();
    }
    let worst = |mesh: &TetMesh, elements: &[u32]| -> f64 {
        elements
            .iter()
            .map(|&e| {
                let p = mesh.tets[e as usize].map(|v| mesh.vertices[v as usize]);
                if mesh.signed_volume(e as usize) <= 0.0 {
                    return -1.0;
                }
                dihedral_angles(&p).into_iter().fold(180.0, f64::min)
            })
            .fold(180.0, f64::min)
    };
    let all: Vec<u32> = (0..mesh.element_count() as u32).collect();
    let before = worst(mesh, &all);
    let mut moves = 0;
    let mut sweeps_done = 0;
    for _ in 0..sweeps {
        sweeps_done += 1;
        let mut moved_this_sweep = 0;
        for v in 0..n {
            if !movable[v] || neighbours[v].is_empty() {
                continue;
            }
            let original = mesh.vertices[v];
            let centroid = Point3::from(
                neighbours[v]
                    .iter()
                    .map(|&w| mesh.vertices[w as usize].coords)
                    .sum::<nalgebra::Vector3<f64>>()
                    / neighbours[v].len() as f64,
            );
            let current = worst(mesh, &elements_of[v]);
            let mut best = (current, original);
            // Candidates: toward the neighbours' centroid, and toward the apex that would make
            // the worst element around the vertex regular.
            let apex = ideal_apex(mesh, &elements_of[v], v as u32);
            for target in [Some(centroid), apex].into_iter().flatten() {
                for step in [1.0, 0.5, 0.25] {
                    mesh.vertices[v] = original + (target - original) * step;
                    let q = worst(mesh, &elements_of[v]);
                    if q > best.0 {
                        best = (q, mesh.vertices[v]);
                    }
                }
            }
            // Where the worst element is still poor, a compass search around the best point.
            if best.0 < COMPASS_BELOW_DEG {
                let scale = neighbours[v]
                    .iter()
                    .map(|&w| (mesh.vertices[w as usize] - original).norm())
                    .sum::<f64>()
                    / neighbours[v].len() as f64;
                for fraction in [0.2, 0.1, 0.05] {
                    for axis in 0..3 {
                        for sign in [-1.0, 1.0] {
                            let mut step = nalgebra::Vector3::zeros();
                            step[axis] = sign * fraction * scale;
                            mesh.vertices[v] = best.1 + step;
                            let q = worst(mesh, &elements_of[v]);
                            if q > best.0 {
                                best = (q, mesh.vertices[v]);
                            }
                        }
                    }
                }
            }
            mesh.vertices[v] = best.1;
            if best.1 != original {
                moved_this_sweep += 1;
            }
        }
        moves += moved_this_sweep;
        if moved_this_sweep == 0 {
            break;
        }
    }
    ImproveReport {
        sweeps: sweeps_done,
        moves,
        min_dihedral_before: before,
        min_dihedral_after: worst(mesh, &all),
    }
}

/// For the element around `v` with the smallest dihedral angle: the point above the centroid
/// of its face opposite `v`, at the height of a regular tetrahedron over that face.
fn ideal_apex(mesh: &TetMesh, elements: &[u32], v: u32) -> Option<Point3<f64>> {
    let worst = elements.iter().min_by(|&&a, &&b| {
        let q = |e: u32| {
            dihedral_angles(&mesh.tets[e as usize].map(|w| mesh.vertices[w as usize]))
                .into_iter()
                .fold(180.0, f64::min)
        };
        q(a).total_cmp(&q(b))
    })?;
    let tet = mesh.tets[*worst as usize];
    let corner = tet.iter().position(|&w| w == v)?;
    // The opposite face, ordered so that its normal points toward v in a positive element.
    const OPPOSITE: [[usize; 3]; 4] = [[1, 3, 2], [0, 2, 3], [0, 3, 1], [0, 1, 2]];
    let f = OPPOSITE[corner].map(|i| mesh.vertices[tet[i] as usize]);
    let normal = (f[1] - f[0]).cross(&(f[2] - f[0]));
    let edge = ((f[1] - f[0]).norm() + (f[2] - f[1]).norm() + (f[0] - f[2]).norm()) / 3.0;
    let centroid = Point3::from((f[0].coords + f[1].coords + f[2].coords) / 3.0);
    Some(centroid + normal.try_normalize(1e-300)? * (edge * (2.0f64 / 3.0).sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::generate::box_mesh;
    use nalgebra::Vector3;

    #[test]
    fn smoothing_repairs_a_squashed_interior_vertex_and_never_worsens() {
        let mut mesh = box_mesh([3, 3, 3], Vector3::new(3.0, 3.0, 3.0), 0.0, 0).unwrap();
        // Push an interior vertex most of the way toward a neighbour: slivers around it.
        let v = 1 + 4 * (1 + 4); // grid vertex (1, 1, 1)
        mesh.vertices[v] += Vector3::new(0.85, 0.8, 0.0);
        let before = crate::geometry::shell::quality(&mesh).min_dihedral_deg;
        let boundary: Vec<bool> = mesh
            .vertices
            .iter()
            .map(|p| p.iter().any(|&c| c.abs() < 1e-9 || (c - 3.0).abs() < 1e-9))
            .collect();
        let movable: Vec<bool> = boundary.iter().map(|b| !b).collect();
        let report = smart_smooth(&mut mesh, &movable, 10);
        assert!((report.min_dihedral_before - before).abs() < 1e-9);
        assert!(report.min_dihedral_after > before + 10.0, "{report:?}");
        // Boundary vertices stayed put; no element inverted.
        let fresh = box_mesh([3, 3, 3], Vector3::new(3.0, 3.0, 3.0), 0.0, 0).unwrap();
        for (i, b) in boundary.iter().enumerate() {
            if *b {
                assert_eq!(mesh.vertices[i], fresh.vertices[i]);
            }
        }
        assert_eq!(crate::geometry::shell::quality(&mesh).inverted, 0);
    }
}
