//! Small contact scenes for the unit tests: two lip-like sheets facing each other.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::mesh::ContactMesh;

/// Two `n×n`-vertex grid sheets of width 1 cm: the lower one at z = 0, the upper one at
/// z = `gap`, shifted in the plane by `shift` and rotated by `angle` about z, every vertex
/// jittered by up to `noise` (cm). Returns interleaved positions and the triangles.
pub fn two_sheets(
    n: usize,
    gap: f64,
    shift: [f64; 2],
    angle: f64,
    noise: f64,
    seed: u64,
) -> (Vec<f64>, Vec<[u32; 3]>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut x = Vec::new();
    let mut faces = Vec::new();
    let h = 1.0 / (n - 1) as f64;
    for sheet in 0..2 {
        let base = (sheet * n * n) as u32;
        let (c, s) = (angle.cos(), angle.sin());
        for j in 0..n {
            for i in 0..n {
                let (u, v) = (i as f64 * h - 0.5, j as f64 * h - 0.5);
                let (px, py, pz) = if sheet == 0 {
                    (u, v, 0.0)
                } else {
                    (c * u - s * v + shift[0], s * u + c * v + shift[1], gap)
                };
                let mut jitter = || {
                    if noise > 0.0 {
                        rng.random_range(-noise..noise)
                    } else {
                        0.0
                    }
                };
                x.extend([px + jitter(), py + jitter(), pz + jitter()]);
            }
        }
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let v = |a: usize, b: usize| base + (b * n + a) as u32;
                let (a, b, c, d) = (v(i, j), v(i + 1, j), v(i + 1, j + 1), v(i, j + 1));
                if (i + j) % 2 == 0 {
                    faces.push([a, b, c]);
                    faces.push([a, c, d]);
                } else {
                    faces.push([a, b, d]);
                    faces.push([b, c, d]);
                }
            }
        }
    }
    (x, faces)
}

/// The mesh of [`two_sheets`] with self-contact allowed.
pub fn two_sheet_mesh(x: &[f64], faces: &[[u32; 3]]) -> ContactMesh {
    ContactMesh::new(x, faces.to_vec()).expect("valid test mesh")
}

/// [`two_sheets`] (9 × 9, 0.03 apart) with every third vertex rigid on one of two bones
/// (groups 1 and 2 touch only the soft group 0, as the face's teeth do): positions, mesh
/// and groups.
pub fn striped_sheets() -> (Vec<f64>, ContactMesh, Vec<u16>) {
    let (x, faces) = two_sheets(9, 0.03, [0.013, -0.021], 0.3, 0.01, 7);
    let group: Vec<u16> = (0..x.len() / 3).map(|v| (v % 3) as u16).collect();
    let matrix = [
        vec![true, true, true],
        vec![true, false, false],
        vec![true, false, false],
    ];
    let mesh = ContactMesh::with_groups(&x, faces, group.clone(), &matrix).unwrap();
    (x, mesh, group)
}
