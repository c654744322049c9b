//! Generated tetrahedral meshes for tests and benchmarks (the face meshes come from the rig
//! importer; these are the controlled, resolution-exact stand-ins).

use nalgebra::{Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::tet_mesh::{MeshError, TetMesh};

/// A box of `cells` cubes split into 6 tetrahedra each (Kuhn subdivision, conforming across
/// cells), spanning `size` from the origin. `jitter` moves interior vertices by up to that
/// fraction of a cell, reproducibly from `seed`, so tests do not depend on a perfectly regular grid.
pub fn box_mesh(
    cells: [usize; 3],
    size: Vector3<f64>,
    jitter: f64,
    seed: u64,
) -> Result<TetMesh, MeshError> {
    let [nx, ny, nz] = cells;
    let h = Vector3::new(size.x / nx as f64, size.y / ny as f64, size.z / nz as f64);
    let index = |i: usize, j: usize, k: usize| (i + (nx + 1) * (j + (ny + 1) * k)) as u32;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut vertices = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                let mut p = Point3::new(i as f64 * h.x, j as f64 * h.y, k as f64 * h.z);
                let interior = [(i, nx), (j, ny), (k, nz)]
                    .iter()
                    .all(|&(a, n)| a > 0 && a < n);
                if jitter > 0.0 && interior {
                    let r = Vector3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                    );
                    p += r.component_mul(&h) * jitter;
                }
                vertices.push(p);
            }
        }
    }
    // The 6 Kuhn tetrahedra follow the monotone paths from corner 000 to corner 111.
    const AXIS_ORDERS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut tets = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for order in AXIS_ORDERS {
                    let mut corner = [i, j, k];
                    let mut tet = [index(i, j, k); 4];
                    for (slot, axis) in order.iter().enumerate() {
                        corner[*axis] += 1;
                        tet[slot + 1] = index(corner[0], corner[1], corner[2]);
                    }
                    tets.push(tet);
                }
            }
        }
    }
    orient_positively(&vertices, &mut tets);
    TetMesh::new(vertices, tets)
}

/// Swaps two vertices of every negatively oriented element.
fn orient_positively(vertices: &[Point3<f64>], tets: &mut [[u32; 4]]) {
    for tet in tets {
        let [a, b, c, d] = tet.map(|v| vertices[v as usize]);
        if (b - a).dot(&(c - a).cross(&(d - a))) < 0.0 {
            tet.swap(2, 3);
        }
    }
}

/// Cell counts giving roughly `elements` tetrahedra in a face-like slab of proportions 4:4:1.
pub fn slab_cells_for(elements: usize) -> [usize; 3] {
    let cells = (elements as f64 / 6.0).max(1.0);
    let nz = (cells / 16.0).cbrt().round().max(1.0);
    let nxy = (cells / nz).sqrt().round().max(1.0) as usize;
    [nxy, nxy, nz as usize]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_mesh_fills_the_box_exactly() {
        let size = Vector3::new(2.0, 3.0, 1.5);
        let mesh = box_mesh([3, 4, 2], size, 0.2, 7).unwrap();
        assert_eq!(mesh.element_count(), 6 * 3 * 4 * 2);
        assert_eq!(mesh.vertex_count(), 4 * 5 * 3);
        let total: f64 = mesh.volumes().iter().sum();
        assert!(
            (total - size.x * size.y * size.z).abs() < 1e-12,
            "volume {total}"
        );
        assert!(mesh.volumes().iter().all(|&v| v > 0.0));
    }

    #[test]
    fn slab_sizes_match_the_requested_element_count() {
        for target in [5_000, 20_000, 80_000] {
            let [a, b, c] = slab_cells_for(target);
            let got = 6 * a * b * c;
            assert!(
                (got as f64 / target as f64 - 1.0).abs() < 0.15,
                "{target} -> {got}"
            );
        }
    }
}
