//! What the session needs of one face: its model, its actuation model, and the static
//! topology the viewers draw with (sent once, not with every frame).

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::drive::ActuationModel;
use crate::model::FaceModel;
use crate::model::face::Binding;
use crate::rig::Region;
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
    /// Per render vertex: the mouth's inside moved by the bones alone (teeth, gums, the deep
    /// mouth) rather than embedded in the tissue. The "teeth" toggle hides triangles made
    /// only of these.
    pub rigid: Vec<bool>,
    /// Per render vertex, its base colour (sRGB): skin, the mouth's inside and teeth, the
    /// eyes' sclera, iris and lashes ([`vertex_colors`]).
    pub colors: Vec<[u8; 3]>,
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
        let render = &model.render;
        let overlay = |t: usize| {
            render.parts.iter().any(|p| {
                p.triangles.contains(&(t as u32)) && OVERLAY_PARTS.contains(&p.name.as_str())
            })
        };
        let rigid: Vec<bool> = render
            .bindings
            .iter()
            .zip(&render.rig_vertices)
            .map(|(b, &v)| {
                matches!(b, Binding::Rigid(_) | Binding::Bones { .. })
                    && matches!(
                        Region::of_vertex(v as usize),
                        Some(
                            Region::MouthSocket
                                | Region::GumsAndTongue
                                | Region::UpperTeeth
                                | Region::LowerTeeth
                        )
                    )
            })
            .collect();
        FaceTopology {
            name: name.to_string(),
            triangles: (0..render.triangles.len())
                .filter(|&t| !overlay(t))
                .map(|t| render.triangles[t])
                .collect(),
            colors: vertex_colors(model, &rigid),
            rigid,
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

/// The rig's see-through shading layers over the eyes (tear film, the blend and occlusion
/// shells): drawn opaque they would hide the eyes, so the viewers leave them out (exports
/// keep them, as parts an artist gives transparent materials).
pub const OVERLAY_PARTS: [&str; 3] = ["M_LacrimalFluid", "M_EyeBlend", "M_EyeOcclusion"];

/// Base colours of the viewers, sRGB.
pub const SKIN_COLOR: [u8; 3] = [222, 178, 153];
pub const INNER_COLOR: [u8; 3] = [237, 232, 217];
const SCLERA_COLOR: [u8; 3] = [240, 238, 232];
const IRIS_COLOR: [u8; 3] = [74, 52, 36];
const LASH_COLOR: [u8; 3] = [38, 30, 26];
const PUPIL_COLOR: [u8; 3] = [12, 10, 10];

/// Per render vertex, its base colour: the mouth's inside and teeth (`rigid`) light, the
/// eyes by their part (sclera, iris, lashes), the rest skin.
pub fn vertex_colors(model: &FaceModel, rigid: &[bool]) -> Vec<[u8; 3]> {
    let render = &model.render;
    let mut colors: Vec<[u8; 3]> = rigid
        .iter()
        .map(|&r| if r { INNER_COLOR } else { SKIN_COLOR })
        .collect();
    let vertices_of = |name: &str| -> Vec<usize> {
        let mut v: Vec<usize> = render
            .parts
            .iter()
            .filter(|p| p.name == name)
            .flat_map(|p| p.triangles.clone())
            .flat_map(|t| render.triangles[t as usize])
            .map(|v| v as usize)
            .collect();
        v.sort_unstable();
        v.dedup();
        v
    };
    for v in vertices_of("M_EyeLashes") {
        colors[v] = LASH_COLOR;
    }
    // The rig's iris lies under the eyeball's clear front (its material is see-through
    // there), so an opaque eyeball hides it: paint the eyeball where it covers the iris.
    for side in ["Left", "Right"] {
        let (sclera, iris) = (
            vertices_of(&format!("M_Sclera{side}")),
            vertices_of(&format!("M_Iris{side}")),
        );
        for &v in &sclera {
            colors[v] = SCLERA_COLOR;
        }
        for &v in &iris {
            colors[v] = IRIS_COLOR;
        }
        let centre = |vs: &[usize]| {
            vs.iter()
                .map(|&v| render.rest[v].coords)
                .sum::<nalgebra::Vector3<f64>>()
                / vs.len().max(1) as f64
        };
        let (eye, disc) = (centre(&sclera), centre(&iris));
        let Some(axis) = (disc - eye).try_normalize(1e-9) else {
            continue;
        };
        let lateral = |v: usize| {
            let d = render.rest[v].coords - disc;
            (d - axis * d.dot(&axis)).norm()
        };
        let radius = iris.iter().map(|&v| lateral(v)).fold(0.0, f64::max);
        for v in sclera {
            let in_front = (render.rest[v].coords - eye).dot(&axis) > 0.0;
            let r = lateral(v);
            if in_front && r < radius {
                colors[v] = if r < 0.3 * radius {
                    PUPIL_COLOR
                } else {
                    IRIS_COLOR
                };
            }
        }
    }
    colors
}
