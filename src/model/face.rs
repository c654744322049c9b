//! A simulation-ready face: the tissue's tetrahedral mesh, its bone attachments, and the
//! artist's full-resolution surface bound to it.

use std::path::Path;

use nalgebra::{Matrix3, Point3};
use serde::{Deserialize, Serialize};

use super::file::{self, FileError, Format};
use super::report::BuildReport;
use crate::geometry::TetMesh;
use crate::geometry::embedding::interpolate;
use crate::geometry::shell::MeshQuality;
use crate::sim::{Attachments, Bone, SimConfig, SimError, Simulator};

/// The file format of face models; bump `version` whenever [`FaceModel`] changes shape.
/// Version 2: skin outside the tissue that the rig never moves is [`Binding::Blended`] with
/// the skull (version 1 extrapolated it from its nearest element, up to 7 cm away).
/// Version 3: the lips' tissue is finer, the render surface is bound on its side of the mouth
/// slit and chosen by the rig's shapes, and the deep mouth moves between the bones
/// ([`Binding::Bones`]); version 2 bound the lower lip to the upper lip's tissue.
/// Version 4: the render surface is the whole head (the back of the head, the eye sockets and
/// the eyes ride on the skull) and carries the rig's texture coordinates ([`UvLayout`]) and
/// material groups ([`Part`]).
pub const FACE_FORMAT: Format = Format {
    kind: "face",
    version: 4,
};

/// How one vertex of the render surface follows the simulation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Binding {
    /// Barycentric in a tetrahedron: `p = Σᵢ wᵢ·xᵢ` over its 4 vertices.
    Embedded { element: u32, weights: [f64; 4] },
    /// Rigidly with a bone (teeth, gums, the back of the mouth).
    Rigid(Bone),
    /// Skin outside the tissue that rides on a bone (forehead, scalp, ears, neck): a mix of
    /// the embedded position and the bone's, `p = s·Σᵢ wᵢ·xᵢ + (1 − s)·T_bone(rest)`, with `s`
    /// (`embedded`, in [0, 1)) falling smoothly with the distance outside the tissue. Far out,
    /// barycentric weights extrapolate: a small rotation of the element would swing the
    /// point by its distance times the angle (the "forehead wobble"); the blend keeps the
    /// skin next to the tissue following it and the skin far from it on the bone, without a
    /// seam between. `element`/`weights` stay the vertex's place in the face's material space
    /// (the mapping φ and the heatmaps use it) even where `s = 0`.
    Blended {
        element: u32,
        weights: [f64; 4],
        bone: Bone,
        embedded: f64,
    },
    /// Between the bones, where no tissue reaches (the deep mouth lining, the tongue): the
    /// skull's motion plus a linear map `M` (`jaw`, fitted to the rig's jaw shapes) of the
    /// jaw's motion relative to it, `p = T_skull(rest) + R_skull·M·R_skullᵀ·(T_jaw(rest) −
    /// T_skull(rest))`: exact at rest, and the whole head moving carries it along. The lining
    /// that joins the upper and lower gums stretches between them as the mouth opens, as the
    /// rig stretches it, instead of staying with one bone and folding through the other.
    Bones { jaw: Matrix3<f64> },
}

impl Binding {
    /// The tissue element the vertex lies in (or nearest to) at rest, for `Embedded` and
    /// `Blended` vertices: the skin and lips, whose rest positions belong to the face's
    /// material space; `None` for vertices that only a bone moves (teeth, the deep mouth).
    pub fn element(&self) -> Option<u32> {
        match self {
            Binding::Embedded { element, .. } | Binding::Blended { element, .. } => Some(*element),
            Binding::Rigid(_) | Binding::Bones { .. } => None,
        }
    }

    /// The share of the vertex's motion that the tissue gives (1 embedded, 0 rigid).
    pub fn embedded_share(&self) -> f64 {
        match self {
            Binding::Embedded { .. } => 1.0,
            Binding::Blended { embedded, .. } => *embedded,
            Binding::Rigid(_) | Binding::Bones { .. } => 0.0,
        }
    }
}

/// The rig's texture coordinates on the render surface. UVs belong to triangle corners, not
/// vertices: along a seam one vertex has a different `(u, v)` in each of its charts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct UvLayout {
    /// `(u, v)`, `v` up (OBJ's convention); the ICT rig lays its parts out on UDIM tiles
    /// side by side in `u` (the face in [0, 1]², the back of the head in [1, 2] × [0, 1], …).
    pub coords: Vec<[f32; 2]>,
    /// Per render triangle, the index into `coords` of each corner (same corner order).
    pub triangles: Vec<[u32; 3]>,
}

/// A named part of the render surface (the rig's material group: `M_Face`, `M_Teeth`,
/// `M_EyeLashes`, …): a run of its triangles, so exports can give each part its material.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Part {
    pub name: String,
    pub triangles: std::ops::Range<u32>,
}

/// The artist's surface: the rig's whole head (skin, back of the head, mouth, teeth, eyes)
/// and the faces among its vertices.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderSurface {
    /// Rig vertex index of each render vertex.
    pub rig_vertices: Vec<u32>,
    /// Rest positions (after the importer's repair), cm.
    pub rest: Vec<Point3<f64>>,
    /// Triangles over render vertices.
    pub triangles: Vec<[u32; 3]>,
    pub bindings: Vec<Binding>,
    /// Texture coordinates, when the rig has them.
    pub uv: Option<UvLayout>,
    /// The rig's material groups over `triangles`, in order, covering every triangle.
    pub parts: Vec<Part>,
}

/// One identity's simulation model.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FaceModel {
    /// `None` is the rig's neutral: the canonical (template) face.
    pub identity: Option<usize>,
    pub name: String,
    pub mesh: TetMesh,
    /// The skin: triangles of the mesh's outer layer (mesh vertex indices).
    pub skin_triangles: Vec<[u32; 3]>,
    pub attachments: Attachments,
    pub jaw_pivot: Point3<f64>,
    /// Contact distance `d̂ = 0.001 ×` the skin's diameter, cm.
    pub d_hat: f64,
    pub render: RenderSurface,
    pub quality: MeshQuality,
    pub report: BuildReport,
}

impl FaceModel {
    /// A simulator for this face (factors its global matrix).
    pub fn simulator(&self) -> Result<Simulator, SimError> {
        let config = SimConfig {
            jaw_pivot: self.jaw_pivot,
            ..SimConfig::default()
        };
        Simulator::new(self.mesh.clone(), self.attachments.clone(), config)
    }

    /// The render surface for simulated mesh positions (interleaved) and bone poses.
    pub fn render_positions(&self, x: &[f64], bones: &crate::sim::BonePose) -> Vec<Point3<f64>> {
        self.render
            .bindings
            .iter()
            .zip(&self.render.rest)
            .map(|(binding, rest)| self.bound_position(binding, rest, x, bones))
            .collect()
    }

    /// Where `binding` puts a render vertex resting at `rest`, for mesh positions `x` and bone
    /// poses `bones`.
    pub fn bound_position(
        &self,
        binding: &Binding,
        rest: &Point3<f64>,
        x: &[f64],
        bones: &crate::sim::BonePose,
    ) -> Point3<f64> {
        match binding {
            Binding::Embedded { element, weights } => {
                interpolate(&self.mesh.tets[*element as usize], weights, x)
            }
            Binding::Rigid(bone) => bones.target(*bone, &self.jaw_pivot, rest),
            Binding::Bones { jaw } => bones.between_bones(jaw, &self.jaw_pivot, rest),
            Binding::Blended {
                element,
                weights,
                bone,
                embedded,
            } => {
                let rigid = bones.target(*bone, &self.jaw_pivot, rest);
                if *embedded == 0.0 {
                    rigid
                } else {
                    let soft = interpolate(&self.mesh.tets[*element as usize], weights, x);
                    rigid + (soft - rigid) * *embedded
                }
            }
        }
    }

    pub fn save(&self, path: &Path) -> Result<(), FileError> {
        file::write(path, FACE_FORMAT, self)
    }

    pub fn load(path: &Path) -> Result<Self, FileError> {
        file::read(path, FACE_FORMAT)
    }
}
