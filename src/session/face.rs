//! What the session needs of one face: its model, its actuation model, and the static
//! topology the viewers draw with (sent once, not with every frame).

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::drive::ActuationModel;
use crate::model::FaceModel;
use crate::model::face::Binding;
use crate::rig::style::StyleCode;

/// One editable face.
#[derive(Clone)]
pub struct SessionFace {
    pub name: String,
    pub identity: Option<usize>,
    /// The style the identity performs in; the style sliders start here.
    pub default_style: StyleCode,
    pub model: Arc<FaceModel>,
    pub actuation: Arc<dyn ActuationModel>,
}

/// Frame-independent drawing data of a face.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FaceTopology {
    pub name: String,
    /// Render-surface triangles (indices into a frame's `positions`).
    pub triangles: Vec<[u32; 3]>,
    /// Per render vertex: moved by the bones alone (teeth, gums, the deep mouth) rather
    /// than embedded in the tissue. The "teeth" toggle hides triangles made only of these.
    pub rigid: Vec<bool>,
    /// Unique edges of the simulation mesh's tetrahedra (indices into `mesh_positions`).
    pub mesh_edges: Vec<[u32; 2]>,
    /// Rest positions of the render surface, cm.
    pub rest: Vec<[f32; 3]>,
    /// The point the jaw's rotation is about (a frame's `jaw` motion is relative to it).
    pub jaw_pivot: [f32; 3],
}

impl FaceTopology {
    pub fn of(name: &str, model: &FaceModel) -> Self {
        let mut edges: Vec<[u32; 2]> = model
            .mesh
            .tets
            .iter()
            .flat_map(|t| {
                [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
                    .map(|(a, b)| [t[a].min(t[b]), t[a].max(t[b])])
            })
            .collect();
        edges.sort_unstable();
        edges.dedup();
        FaceTopology {
            name: name.to_string(),
            triangles: model.render.triangles.clone(),
            rigid: model
                .render
                .bindings
                .iter()
                .map(|b| matches!(b, Binding::Rigid(_) | Binding::Bones { .. }))
                .collect(),
            mesh_edges: edges,
            rest: model
                .render
                .rest
                .iter()
                .map(|p| [p.x as f32, p.y as f32, p.z as f32])
                .collect(),
            jaw_pivot: [
                model.jaw_pivot.x as f32,
                model.jaw_pivot.y as f32,
                model.jaw_pivot.z as f32,
            ],
        }
    }
}
