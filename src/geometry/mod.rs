//! Geometry: tetrahedral meshes and generated test meshes.

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
