//! Small fixed-size types shared by the contact modules.

use nalgebra::{SMatrix, SVector, Vector3};

/// A gradient over the 4 vertices of a contact stencil, `[x0, y0, z0, …, x3, y3, z3]`.
pub type Vector12 = SVector<f64, 12>;
/// A dense Hessian over the 4 vertices of a contact stencil (same ordering as [`Vector12`]).
pub type Matrix12 = SMatrix<f64, 12, 12>;

pub(crate) type Vec3 = Vector3<f64>;

/// Vertex `i` of interleaved positions `[x0, y0, z0, x1, …]`. The caller checked the length.
#[inline]
pub(crate) fn vertex(x: &[f64], i: u32) -> Vec3 {
    let k = 3 * i as usize;
    Vec3::new(x[k], x[k + 1], x[k + 2])
}

/// The 4 stencil vertices of `ids` read from interleaved positions.
#[inline]
pub(crate) fn stencil(x: &[f64], ids: [u32; 4]) -> [Vec3; 4] {
    ids.map(|i| vertex(x, i))
}
