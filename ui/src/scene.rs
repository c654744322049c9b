//! Turns a session frame into what the viewport draws, under the display toggles.

use facesim::session::{FaceTopology, Frame};

use crate::viewport::{LineVertex, Scene, SurfaceVertex};

/// What is shown.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Toggles {
    pub skin: bool,
    pub wireframe: bool,
    pub teeth: bool,
    pub crosses: bool,
    /// Index into the frame's heatmaps.
    pub heatmap: Option<usize>,
}

impl Default for Toggles {
    fn default() -> Self {
        Toggles {
            skin: true,
            wireframe: false,
            teeth: true,
            crosses: false,
            heatmap: None,
        }
    }
}

const WIRE: [f32; 3] = [0.25, 0.25, 0.3];

pub fn build(frame: &Frame, topology: &FaceTopology, toggles: &Toggles) -> Scene {
    let heat = toggles
        .heatmap
        .and_then(|i| frame.heatmaps.get(i))
        .map(|h| h.colors());
    let vertices = frame
        .positions
        .iter()
        .zip(&frame.normals)
        .enumerate()
        .map(|(i, (p, n))| SurfaceVertex {
            position: *p,
            normal: *n,
            color: match &heat {
                Some(c) => c[i].map(|v| v as f32 / 255.0),
                None => topology.colors[i].map(|c| c as f32 / 255.0),
            },
        })
        .collect();
    let indices = topology
        .triangles
        .iter()
        .filter(|t| {
            let inner = t.iter().all(|&v| topology.rigid[v as usize]);
            if inner { toggles.teeth } else { toggles.skin }
        })
        .flatten()
        .copied()
        .collect();
    let mut lines = Vec::new();
    if toggles.wireframe && !frame.mesh_positions.is_empty() {
        for e in &topology.mesh_edges {
            for &v in e {
                lines.push(LineVertex {
                    position: frame.mesh_positions[v as usize],
                    color: WIRE,
                });
            }
        }
    }
    if toggles.crosses {
        for a in &frame.crosses {
            let s = a.contraction.clamp(0.0, 1.0);
            let color = [0.9, 0.2 + 0.6 * (1.0 - s), 0.1];
            lines.push(LineVertex {
                position: a.from,
                color,
            });
            lines.push(LineVertex {
                position: a.to,
                color,
            });
        }
    }
    Scene {
        vertices,
        indices,
        lines,
    }
}
