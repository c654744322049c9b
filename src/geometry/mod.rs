//! Geometry: tetrahedral meshes and generated test meshes.

pub mod bones;
pub mod bvh;
pub mod crossing;
pub mod distance;
pub mod embedding;
pub mod generate;
pub mod improve;
pub mod query;
pub mod remesh;
pub mod rigid;
pub mod shell;
pub mod tet_mesh;
pub mod triangles;

pub use tet_mesh::{MeshError, TetMesh};

/// The axis-aligned bounds `[min, max]` of `points` (f32, as frames and exports hold them);
/// `[+∞, −∞]` per axis for none.
pub fn bounds_f32(points: impl IntoIterator<Item = [f32; 3]>) -> [[f32; 3]; 2] {
    let mut b = [[f32::INFINITY; 3], [f32::NEG_INFINITY; 3]];
    for p in points {
        for c in 0..3 {
            b[0][c] = b[0][c].min(p[c]);
            b[1][c] = b[1][c].max(p[c]);
        }
    }
    b
}
