//! A face's contact surfaces bound to its simulation: the lips, the inside of the mouth and the
//! teeth, taken from the artist's full-resolution render surface (what the user sees is what
//! must not intersect); which part of the face takes part is the model's choice
//! (`model::contact_region` builds a [`FaceContact`] from a face model).
//!
//! Contact vertex `i` is either embedded, `yᵢ = Σⱼ wⱼ·x_{tet[j]}` (linear in the simulation
//! positions `x`: `y = W·x`, so gradients pull back by `Wᵀ` and Hessians by `Wᵀ·H·W`), or
//! rigid with a bone (teeth, the deep mouth), an obstacle the bone pose moves.
//!
//! Pairs the simulation cannot influence are left out by groups (rigid–rigid: the teeth
//! against each other are the jaw pose's business). Pairs already within d̂ at rest
//! (neighbours along the finely tessellated surface, e.g. where the mouth socket turns from
//! embedded to rigid; on the sample 0.38–1 d̂ apart) get their own activation distance, half
//! their rest distance ([`CLOSE_PAIR_ACTIVATION`], [`FaceContact::close_pairs`]): the barrier
//! is zero at rest, weighted to act at that scale as the plain one does at d̂
//! (`Collision::weight`), and CCD tracks them like every other pair. Pairs closer than
//! [`ATTACHED_AT_REST`]·d̂ (the rig's lining lying on its gum) are attached: neither. Left
//! out of contact altogether, as they were, a lip edge slid through the jaw-bound mouth lining it rests
//! against (3 of ~1,000 random codes ended with crossings the after-solve check caught).
//! Pairs of primitives each wholly inside one simulation element, the same one or two
//! sharing a face, are left out of contact and of the solver's after-solve crossing check
//! ([`FaceContact::new_crossings_of_solve`]; [`ContactMesh::kept_apart`]): they move by
//! one-to-one maps while the solver keeps the elements at positive volume, so they can never
//! meet.
//! Edge–triangle crossings present at rest (the rig's own, between pieces the importer does
//! not repair: the lining behind the lower incisors passes through the gum) are recorded, and
//! their edges and triangles are left out of the after-solve check, as in the independent
//! audit (`model::audit`): an interpenetration there from the start slides to the
//! neighbouring triangle as the lining moves (it is then a new pair, not a new crossing).

use nalgebra::{Matrix3, Point3};
use rayon::prelude::*;

use super::ContactError;
use super::candidates::{Candidates, EdgeFaceLayouts};
use super::collisions::Collisions;
use super::math::vertex;
pub use super::mesh::NO_CELL;
use super::mesh::{Cells, ContactMesh};
use crate::geometry::bones::{Bone, BonePose};
use crate::geometry::crossing::segment_crosses_triangle;

/// How a contact vertex moves.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ContactBinding {
    /// `y = Σⱼ wⱼ·x_{tet[j]}`.
    Embedded { tet: [u32; 4], weights: [f64; 4] },
    /// With a bone, from its rest position.
    Rigid { bone: Bone, rest: Point3<f64> },
    /// Between the bones (the deep mouth lining), by its jaw map
    /// ([`BonePose::between_bones`]).
    Bones {
        jaw: Matrix3<f64>,
        rest: Point3<f64>,
    },
}

impl ContactBinding {
    /// The bone that moves the vertex most, for a vertex no tissue moves.
    pub fn bone(&self) -> Option<Bone> {
        match *self {
            ContactBinding::Embedded { .. } => None,
            ContactBinding::Rigid { bone, .. } => Some(bone),
            ContactBinding::Bones { jaw, .. } => Some(if jaw.trace() >= 1.5 {
                Bone::Jaw
            } else {
                Bone::Skull
            }),
        }
    }

    /// `F` with `∂y/∂(jaw pose) = F·∂T_jaw(rest)/∂(jaw pose)`: `I` on the jaw, the jaw map
    /// turned with the head between the bones, 0 on the skull or in the tissue.
    pub fn jaw_factor(&self, bones: &BonePose) -> Matrix3<f64> {
        match *self {
            ContactBinding::Rigid {
                bone: Bone::Jaw, ..
            } => Matrix3::identity(),
            ContactBinding::Bones { jaw, .. } => {
                let turn = bones.skull.rotation_matrix();
                turn * jaw * turn.transpose()
            }
            _ => Matrix3::zeros(),
        }
    }
}

/// A pair within d̂ at rest is activated at this fraction of its rest distance.
pub const CLOSE_PAIR_ACTIVATION: f64 = 0.5;

/// A pair closer than this fraction of d̂ at rest is attached, not in contact: its
/// activation distance is 0, so neither the barrier nor CCD takes it. (The rig's mouth
/// lining lies on, and through, the lower gum: pairs 1e-5 cm apart at rest would otherwise
/// get an activation of 5e-6 cm, and CCD, keeping a share of that gap, cuts every step that
/// moves the lining to a sliver.)
pub const ATTACHED_AT_REST: f64 = 0.1;

/// Vertex groups: who may touch whom.
const SOFT: u16 = 0;
const ON_SKULL: u16 = 1;
const ON_JAW: u16 = 2;
const BETWEEN_BONES: u16 = 3;

/// What a face gives for its contact surface ([`FaceContact::from_parts`]), in the contact
/// surface's own vertex numbering.
#[derive(Clone, Debug)]
pub struct SurfaceParts {
    /// Render-surface index of every contact vertex.
    pub render_vertices: Vec<u32>,
    /// Rest positions, interleaved (cm).
    pub rest: Vec<f64>,
    pub faces: Vec<[u32; 3]>,
    pub bindings: Vec<ContactBinding>,
    /// Per vertex, the simulation element it lies in ([`NO_CELL`] for one the bones carry) and
    /// whether it lies inside it (all barycentric weights ≥ 0).
    pub cells: Vec<(u32, bool)>,
    /// The barrier's activation distance (cm).
    pub dhat: f64,
    pub jaw_pivot: Point3<f64>,
    pub sim_vertex_count: usize,
    /// Counts per piece, for reports: lips/skin, mouth socket, upper teeth, lower teeth.
    pub piece_counts: [usize; 4],
    /// Rest positions of the lip line.
    pub lip_line: Vec<Point3<f64>>,
}

/// The contact surfaces of one face, in their own vertex numbering (contact vertices).
#[derive(Clone, Debug)]
pub struct FaceContact {
    /// Render-surface index of every contact vertex.
    render_vertices: Vec<u32>,
    bindings: Vec<ContactBinding>,
    mesh: ContactMesh,
    dhat: f64,
    jaw_pivot: Point3<f64>,
    sim_vertex_count: usize,
    /// How many edge–triangle crossings are already present at rest.
    rest_crossing_count: usize,
    /// Their edges and faces, sorted (left out of the crossing check).
    rest_crossing_edges: Vec<u32>,
    rest_crossing_faces: Vec<u32>,
    /// The simulation vertices the embedded contact vertices depend on, sorted.
    region_sim_vertices: Vec<u32>,
    /// Counts per piece, for reports: lips/skin, mouth socket, upper teeth, lower teeth.
    piece_counts: [usize; 4],
    /// Rest positions of the lip line.
    lip_line: Vec<Point3<f64>>,
    /// The crossing check's trees (laid out at rest, refit per check).
    crossing_layouts: EdgeFaceLayouts,
}

impl FaceContact {
    /// The contact surface of `parts`, bound to a simulation of tetrahedra `tets`: groups by
    /// binding (only the tissue moves against what the bones carry), the pairs within d̂ at rest
    /// with their own activation distance, the elements primitives lie in, and the crossings
    /// already there at rest.
    pub fn from_parts(parts: SurfaceParts, tets: &[[u32; 4]]) -> Result<Self, ContactError> {
        let SurfaceParts {
            render_vertices,
            rest,
            faces,
            bindings,
            cells: of_vertex_inside,
            dhat,
            jaw_pivot,
            sim_vertex_count,
            piece_counts,
            lip_line,
        } = parts;
        let n = render_vertices.len();
        if rest.len() != 3 * n || bindings.len() != n || of_vertex_inside.len() != n {
            return Err(ContactError::InvalidMesh(format!(
                "{n} contact vertices with {} rest values, {} bindings and {} cells",
                rest.len(),
                bindings.len(),
                of_vertex_inside.len()
            )));
        }
        let group: Vec<u16> = bindings
            .iter()
            .map(|b| match b {
                ContactBinding::Embedded { .. } => SOFT,
                ContactBinding::Rigid {
                    bone: Bone::Skull, ..
                } => ON_SKULL,
                ContactBinding::Rigid {
                    bone: Bone::Jaw, ..
                } => ON_JAW,
                ContactBinding::Bones { .. } => BETWEEN_BONES,
            })
            .collect();
        // Only the tissue can move against what the bones carry.
        let can_touch = [
            vec![true, true, true, true],
            vec![true, false, false, false],
            vec![true, false, false, false],
            vec![true, false, false, false],
        ];
        let mesh = with_rest_close_pairs(
            ContactMesh::with_groups(&rest, faces, group, &can_touch)?,
            &rest,
            dhat,
            ATTACHED_AT_REST,
        )?;
        let (of_vertex, inside): (Vec<u32>, Vec<bool>) = of_vertex_inside.into_iter().unzip();
        let cells = Cells {
            face_neighbours: face_neighbours(tets, &of_vertex),
            of_vertex,
            inside,
        };
        let mesh = mesh.with_cells(cells)?;
        let mut region_sim_vertices: Vec<u32> = bindings
            .iter()
            .filter_map(|b| match b {
                ContactBinding::Embedded { tet, .. } => Some(*tet),
                ContactBinding::Rigid { .. } | ContactBinding::Bones { .. } => None,
            })
            .flatten()
            .collect();
        region_sim_vertices.sort_unstable();
        region_sim_vertices.dedup();
        let crossing_layouts = EdgeFaceLayouts::new(&mesh, &rest);
        let mut contact = Self {
            render_vertices,
            bindings,
            mesh,
            dhat,
            jaw_pivot,
            sim_vertex_count,
            rest_crossing_count: 0,
            rest_crossing_edges: Vec::new(),
            rest_crossing_faces: Vec::new(),
            region_sim_vertices,
            piece_counts,
            lip_line,
            crossing_layouts,
        };
        let rest_crossings = contact.crossings(&rest, false);
        let sorted = |mut v: Vec<u32>| {
            v.sort_unstable();
            v.dedup();
            v
        };
        contact.rest_crossing_edges = sorted(rest_crossings.iter().map(|p| p.0).collect());
        contact.rest_crossing_faces = sorted(rest_crossings.iter().map(|p| p.1).collect());
        contact.rest_crossing_count = rest_crossings.len();
        Ok(contact)
    }

    /// Rest positions of the lip line (skin vertices shared with the mouth socket).
    pub fn lip_line(&self) -> &[Point3<f64>] {
        &self.lip_line
    }

    /// The contact surface over contact vertices.
    pub fn mesh(&self) -> &ContactMesh {
        &self.mesh
    }

    /// Activation distance d̂ (cm).
    pub fn dhat(&self) -> f64 {
        self.dhat
    }

    pub fn vertex_count(&self) -> usize {
        self.bindings.len()
    }

    pub fn bindings(&self) -> &[ContactBinding] {
        &self.bindings
    }

    /// Render-surface index of every contact vertex.
    pub fn render_vertices(&self) -> &[u32] {
        &self.render_vertices
    }

    /// Simulation vertices the embedded contact vertices depend on (sorted).
    pub fn region_sim_vertices(&self) -> &[u32] {
        &self.region_sim_vertices
    }

    /// Simulation vertex count this surface was built for.
    pub fn sim_vertex_count(&self) -> usize {
        self.sim_vertex_count
    }

    /// Contact vertices per piece: `[lips and skin, mouth socket, upper teeth, lower teeth]`.
    pub fn piece_counts(&self) -> [usize; 4] {
        self.piece_counts
    }

    /// Pairs within d̂ at rest, with their own activation distance: (point–triangle,
    /// edge–edge).
    pub fn close_pairs(&self) -> (usize, usize) {
        self.mesh.close_pair_counts()
    }

    /// Edge–triangle crossings present at rest (their edges and faces are left out of
    /// [`FaceContact::new_crossings`]).
    pub fn rest_crossing_count(&self) -> usize {
        self.rest_crossing_count
    }

    /// Contact positions `y` (interleaved, `3·vertex_count`) for simulation positions `x`.
    pub fn positions(&self, x: &[f64], bones: &BonePose, y: &mut [f64]) {
        y.par_chunks_mut(3)
            .zip(&self.bindings)
            .for_each(|(out, b)| out.copy_from_slice(self.position(b, x, bones).coords.as_slice()));
    }

    fn position(&self, b: &ContactBinding, x: &[f64], bones: &BonePose) -> Point3<f64> {
        match b {
            ContactBinding::Embedded { tet, weights } => {
                crate::geometry::embedding::interpolate(tet, weights, x)
            }
            ContactBinding::Rigid { bone, rest } => bones.target(*bone, &self.jaw_pivot, rest),
            ContactBinding::Bones { jaw, rest } => bones.between_bones(jaw, &self.jaw_pivot, rest),
        }
    }

    /// `W·dx`: how a simulation displacement moves the contact vertices (rigid ones stay).
    pub fn displacement(&self, dx: &[f64], dy: &mut [f64]) {
        dy.par_chunks_mut(3)
            .zip(&self.bindings)
            .for_each(|(out, b)| match b {
                ContactBinding::Embedded { tet, weights } => out.copy_from_slice(
                    crate::geometry::embedding::interpolate(tet, weights, dx)
                        .coords
                        .as_slice(),
                ),
                ContactBinding::Rigid { .. } | ContactBinding::Bones { .. } => out.fill(0.0),
            });
    }

    /// `gx += Wᵀ·gy`: a contact-space gradient pulled back to the simulation vertices (in
    /// contact-vertex order: deterministic).
    pub fn add_pulled_back(&self, gy: &[f64], gx: &mut [f64]) {
        for (i, b) in self.bindings.iter().enumerate() {
            if let ContactBinding::Embedded { tet, weights } = b {
                for (&v, &w) in tet.iter().zip(weights) {
                    for k in 0..3 {
                        gx[3 * v as usize + k] += w * gy[3 * i + k];
                    }
                }
            }
        }
    }

    /// Active pairs (closer than d̂) at contact positions `y`.
    pub fn collisions(&self, y: &[f64]) -> Result<Collisions, ContactError> {
        Collisions::build(&self.mesh, y, self.dhat)
    }

    /// Edge–triangle crossings of the contact surface at `y` that were not there at rest,
    /// `(edge, face)` sorted. Rigid–rigid pairs (teeth against teeth: the jaw pose's
    /// business) and pairs sharing a vertex are not checked.
    pub fn new_crossings(&self, y: &[f64]) -> Vec<(u32, u32)> {
        self.crossings(y, false)
    }

    /// [`FaceContact::new_crossings`] for positions `y` of a solver state, `y` =
    /// [`FaceContact::positions`] of tissue positions whose elements are all non-inverted:
    /// pairs the cells keep apart ([`ContactMesh::kept_apart`]) cannot cross, so they are
    /// skipped (not so for positions from elsewhere, e.g. a rig's targets or a displacement
    /// field, which may fold inside an element).
    pub fn new_crossings_of_solve(&self, y: &[f64]) -> Vec<(u32, u32)> {
        self.crossings(y, true)
    }

    /// The new crossings at `y`; `skip_cells`: leave out the pairs the cells keep apart (see
    /// [`FaceContact::new_crossings_of_solve`]).
    fn crossings(&self, y: &[f64], skip_cells: bool) -> Vec<(u32, u32)> {
        let faces = self.mesh.faces();
        let edges = self.mesh.edges();
        let mut out = self
            .crossing_layouts
            .overlapping(&self.mesh, y, skip_cells, &|e, f, out| {
                let [a, b] = edges[e as usize];
                let t = faces[f as usize];
                if t.contains(&a) || t.contains(&b) {
                    return;
                }
                if !self.mesh.primitives_may_touch(&[a, b], &t) {
                    return;
                }
                let (pa, pb) = (Point3::from(vertex(y, a)), Point3::from(vertex(y, b)));
                let tp = t.map(|v| Point3::from(vertex(y, v)));
                if segment_crosses_triangle(&pa, &pb, [&tp[0], &tp[1], &tp[2]], t)
                    && self.rest_crossing_edges.binary_search(&e).is_err()
                    && self.rest_crossing_faces.binary_search(&f).is_err()
                {
                    out.push((e, f));
                }
            });
        out.sort_unstable();
        out
    }
}

/// `mesh` with the pairs that are within d̂ at `rest` given their own activation distance:
/// half their rest distance ([`CLOSE_PAIR_ACTIVATION`]), or 0 (attached: out of the barrier
/// and CCD) for pairs closer than `attached_below`·d̂ (the solver's [`ATTACHED_AT_REST`]).
/// Pairs within d̂ at rest are neighbours along a finely tessellated surface, or pieces the
/// rig lays on each other (the lining on its gums, through its back teeth): their barrier
/// acts only once they have closed half their rest gap.
pub fn with_rest_close_pairs(
    mesh: ContactMesh,
    rest: &[f64],
    dhat: f64,
    attached_below: f64,
) -> Result<ContactMesh, ContactError> {
    let candidates = Candidates::build(&mesh, rest, dhat)?;
    let own = |kind: super::CollisionKind, ids: [u32; 4]| {
        let d = kind
            .distance_squared(&super::math::stencil(rest, ids))
            .sqrt();
        (d < dhat).then_some(if d < attached_below * dhat {
            0.0
        } else {
            CLOSE_PAIR_ACTIVATION * d
        })
    };
    let close_pt: Vec<((u32, u32), f64)> = candidates
        .point_triangle
        .iter()
        .filter_map(|c| {
            let f = mesh.faces()[c.face as usize];
            let ids = [c.vertex, f[0], f[1], f[2]];
            own(super::CollisionKind::PointTriangle, ids).map(|a| ((c.vertex, c.face), a))
        })
        .collect();
    let close_ee: Vec<((u32, u32), f64)> = candidates
        .edge_edge
        .iter()
        .filter_map(|c| {
            let [a0, a1] = mesh.edges()[c.edge_a as usize];
            let [b0, b1] = mesh.edges()[c.edge_b as usize];
            own(super::CollisionKind::EdgeEdge, [a0, a1, b0, b1]).map(|a| ((c.edge_a, c.edge_b), a))
        })
        .collect();
    Ok(mesh.with_close_pairs(close_pt, close_ee))
}

/// The pairs of `cells` (elements of `tets`, [`NO_CELL`] skipped) that share a face.
fn face_neighbours(tets: &[[u32; 4]], cells: &[u32]) -> Vec<(u32, u32)> {
    let mut used: Vec<u32> = cells.iter().copied().filter(|&c| c != NO_CELL).collect();
    used.sort_unstable();
    used.dedup();
    let mut faces: Vec<([u32; 3], u32)> = used
        .iter()
        .flat_map(|&c| {
            let t = tets[c as usize];
            [
                [t[0], t[1], t[2]],
                [t[0], t[1], t[3]],
                [t[0], t[2], t[3]],
                [t[1], t[2], t[3]],
            ]
            .map(|mut f| {
                f.sort_unstable();
                (f, c)
            })
        })
        .collect();
    faces.sort_unstable();
    faces
        .windows(2)
        .filter(|w| w[0].0 == w[1].0)
        .map(|w| (w[0].1, w[1].1))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tooth (two rigid triangles sharing the diagonal 1–2 of the unit square at z = 0) and a
    /// lining triangle: `a` in the tissue, `b` and `c` on the jaw, its edge a–b through the
    /// tooth's first triangle at rest (as the rig's lining passes through its gum).
    fn lining_through_a_tooth() -> (FaceContact, Vec<f64>) {
        let rest = vec![
            0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, // tooth
            0.5, 0.4, -0.5, 0.5, 0.4, 0.5, 2.0, 0.4, 0.5, // lining a, b, c
        ];
        let jaw = |v: usize| ContactBinding::Rigid {
            bone: Bone::Jaw,
            rest: Point3::new(rest[3 * v], rest[3 * v + 1], rest[3 * v + 2]),
        };
        let mut bindings: Vec<ContactBinding> = (0..7).map(jaw).collect();
        bindings[4] = ContactBinding::Embedded {
            tet: [0, 1, 2, 3],
            weights: [1.0, 0.0, 0.0, 0.0],
        };
        let mut cells = vec![(NO_CELL, false); 7];
        cells[4] = (0, true);
        let parts = SurfaceParts {
            render_vertices: (0..7).collect(),
            rest: rest.clone(),
            faces: vec![[0, 1, 2], [1, 3, 2], [4, 5, 6]],
            bindings,
            cells,
            dhat: 0.01,
            jaw_pivot: Point3::origin(),
            sim_vertex_count: 4,
            piece_counts: [0, 3, 0, 4],
            lip_line: vec![Point3::new(0.5, 0.4, 0.5)],
        };
        (
            FaceContact::from_parts(parts, &[[0, 1, 2, 3]]).unwrap(),
            rest,
        )
    }

    /// The named crossings at `y`: (edge's vertices, face's vertices).
    fn crossings_at(contact: &FaceContact, y: &[f64]) -> Vec<([u32; 2], [u32; 3])> {
        let mesh = contact.mesh();
        contact
            .new_crossings(y)
            .into_iter()
            .map(|(e, f)| (mesh.edges()[e as usize], mesh.faces()[f as usize]))
            .collect()
    }

    #[test]
    fn a_crossing_there_at_rest_may_slide_and_a_new_one_is_found() {
        let (contact, rest) = lining_through_a_tooth();
        assert!(contact.rest_crossing_count() > 0);
        assert!(crossings_at(&contact, &rest).is_empty());
        // `a` moves so that a–b passes through the tooth's other triangle: the same
        // interpenetration, slid across the shared edge, is not new.
        let mut slid = rest.clone();
        slid[13] = 0.7;
        assert!(crossings_at(&contact, &slid).is_empty());
        // The jaw-bound end `c` of a–c brought over the tooth: a–c (half in the tissue) now
        // crosses the second triangle, which crossed nothing at rest.
        let mut new = rest.clone();
        new[18..21].copy_from_slice(&[1.0, 0.9, 0.5]);
        assert_eq!(crossings_at(&contact, &new), vec![([4, 6], [1, 3, 2])]);
    }
}
