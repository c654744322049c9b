//! What the evaluation measures on one posed face besides the vertex error: how the tissue's
//! volume changed and whether the lips crossed.
//!
//! - [`VolumeChange`]: per element `det F = V(x)/V(X)` (exact for linear tetrahedra), the mean
//!   `|det F − 1|`, the whole tissue's `ΣV(x)/ΣV(X) − 1`, and the inverted elements
//!   (`det F ≤ 0`). Shape targeting asks every element for the volume of its actuation, so
//!   the physics keeps volume where the actuations do; a displacement field has no such term.
//! - [`lip_crossings`]: edge–triangle crossings of the render surface's lips, mouth and teeth
//!   ([`FaceContact::new_crossings`]: new since rest; rigid–rigid pairs left out).

use serde::{Deserialize, Serialize};

use crate::contact::surface::FaceContact;
use crate::geometry::TetMesh;
use crate::sim::BonePose;

/// Volume change of a posed tet mesh (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VolumeChange {
    /// Mean over elements of `|det F − 1|`.
    pub mean_abs_det_change: f64,
    /// `Σ V(x) / Σ V(X) − 1` (signed).
    pub total_change: f64,
    /// Elements with `det F ≤ 0`.
    pub inverted: usize,
}

impl VolumeChange {
    /// Of `mesh` posed at `x` (interleaved, `3 × vertex count`).
    pub fn of(mesh: &TetMesh, x: &[f64]) -> Self {
        assert_eq!(
            x.len(),
            3 * mesh.vertex_count(),
            "positions of the mesh's vertices"
        );
        let p = |v: u32| {
            let i = 3 * v as usize;
            nalgebra::Vector3::new(x[i], x[i + 1], x[i + 2])
        };
        let (mut sum_abs, mut v_rest, mut v_posed, mut inverted) = (0.0, 0.0, 0.0, 0);
        for (e, t) in mesh.tets.iter().enumerate() {
            let [a, b, c, d] = t.map(p);
            let posed = (b - a).cross(&(c - a)).dot(&(d - a)) / 6.0;
            let rest = mesh.signed_volume(e);
            let det = posed / rest;
            sum_abs += (det - 1.0).abs();
            inverted += usize::from(det <= 0.0);
            v_rest += rest;
            v_posed += posed;
        }
        VolumeChange {
            mean_abs_det_change: sum_abs / mesh.tets.len().max(1) as f64,
            total_change: v_posed / v_rest - 1.0,
            inverted,
        }
    }
}

/// New edge–triangle crossings of the contact surfaces (lips, mouth, teeth) for simulation
/// positions `x` and bone pose `bones` (module docs).
pub fn lip_crossings(contact: &FaceContact, x: &[f64], bones: &BonePose) -> usize {
    let mut y = vec![0.0; 3 * contact.vertex_count()];
    contact.positions(x, bones, &mut y);
    contact.new_crossings(&y).len()
}

/// New crossings of the contact surfaces placed at render-surface positions `render` (e.g.
/// the rig's target for a code: every contact vertex is a render vertex).
pub fn target_crossings(contact: &FaceContact, render: &[nalgebra::Point3<f64>]) -> usize {
    let y: Vec<f64> = contact
        .render_vertices()
        .iter()
        .flat_map(|&v| {
            let p = render[v as usize];
            [p.x, p.y, p.z]
        })
        .collect();
    contact.new_crossings(&y).len()
}
