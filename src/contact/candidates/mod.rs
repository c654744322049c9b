//! Candidate pairs: point–triangle and edge–edge pairs whose boxes overlap, excluding pairs
//! that share a vertex or whose groups may not touch. A superset of the pairs that can be
//! closer than the inflation distance (static) or meet during a step (swept).

use rayon::prelude::*;

use super::ContactError;
use super::math::vertex;
use super::mesh::ContactMesh;
use crate::geometry::bvh::{Box3, BoxTree};
use nalgebra::Point3;

/// A vertex and a face that does not contain it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct PointTriangleCandidate {
    pub vertex: u32,
    pub face: u32,
}

/// Two edges (indices into [`ContactMesh::edges`], `edge_a < edge_b`) sharing no vertex.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct EdgeEdgeCandidate {
    pub edge_a: u32,
    pub edge_b: u32,
}

/// Candidate pairs, each list sorted (so everything downstream is deterministic).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Candidates {
    pub point_triangle: Vec<PointTriangleCandidate>,
    pub edge_edge: Vec<EdgeEdgeCandidate>,
}

/// Vertices per parallel task.
const CHUNK: usize = 256;

impl Candidates {
    /// Pairs closer than `inflation` (cm) may be missed never: every primitive's box at `x`
    /// is grown by `inflation/2` (for the barrier, `inflation = d̂`).
    pub fn build(mesh: &ContactMesh, x: &[f64], inflation: f64) -> Result<Self, ContactError> {
        mesh.check_positions(x)?;
        check_inflation(inflation)?;
        Ok(Self::from_boxes(mesh, |ids| {
            Box3::around_iter(
                ids.iter().map(|&i| Point3::from(vertex(x, i))),
                0.5 * inflation,
            )
        }))
    }

    /// Pairs that may come closer than `inflation` during the linear step `x → x + dx`: every
    /// primitive's box covers its positions at both ends of the step (a vertex moves on a
    /// segment, so its swept path is inside), grown by `inflation/2`. For CCD,
    /// `inflation = min_distance`.
    pub fn build_swept(
        mesh: &ContactMesh,
        x: &[f64],
        dx: &[f64],
        inflation: f64,
    ) -> Result<Self, ContactError> {
        mesh.check_positions(x)?;
        mesh.check_positions(dx)?;
        check_inflation(inflation)?;
        Ok(Self::from_boxes(mesh, |ids| {
            let ends = ids.iter().flat_map(|&i| {
                let p = Point3::from(vertex(x, i));
                [p, p + vertex(dx, i)]
            });
            Box3::around_iter(ends, 0.5 * inflation)
        }))
    }

    /// Total number of pairs.
    pub fn len(&self) -> usize {
        self.point_triangle.len() + self.edge_edge.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn from_boxes(mesh: &ContactMesh, box_of: impl Fn(&[u32]) -> Box3 + Sync) -> Self {
        let face_boxes: Vec<Box3> = mesh.faces().par_iter().map(|f| box_of(f)).collect();
        let edge_boxes: Vec<Box3> = mesh.edges().par_iter().map(|e| box_of(e)).collect();
        let vertex_boxes: Vec<Box3> = mesh
            .vertices()
            .par_iter()
            .map(|v| box_of(std::slice::from_ref(v)))
            .collect();
        // With groups split into touch-all and touch-only-those (soft tissue and rigid
        // pieces), a primitive with a vertex outside the touch-all groups can only meet
        // primitives entirely inside them: it queries the smaller tree of those ("open").
        let split = mesh.groups_split_by_universal();
        let open_faces: Vec<u32> = (0..mesh.faces().len() as u32)
            .filter(|&f| {
                !split
                    || mesh.faces()[f as usize]
                        .iter()
                        .all(|&v| mesh.touches_all(v))
            })
            .collect();
        let open_edges: Vec<u32> = (0..mesh.edges().len() as u32)
            .filter(|&e| {
                !split
                    || mesh.edges()[e as usize]
                        .iter()
                        .all(|&v| mesh.touches_all(v))
            })
            .collect();
        let subset_boxes = |ids: &[u32], boxes: &[Box3]| {
            ids.iter().map(|&i| boxes[i as usize]).collect::<Vec<_>>()
        };
        let face_tree = BoxTree::new(&face_boxes);
        let open_face_tree = BoxTree::new(&subset_boxes(&open_faces, &face_boxes));
        let edge_tree = BoxTree::new(&edge_boxes);
        let open_edge_tree = BoxTree::new(&subset_boxes(&open_edges, &edge_boxes));
        // Queries an open tree and maps its (sorted) local indices back (order is kept).
        let query = |all: &BoxTree,
                     open: &BoxTree,
                     ids: &[u32],
                     universal: bool,
                     b: &Box3,
                     out: &mut Vec<u32>| {
            if universal {
                all.overlapping(b, out);
            } else {
                open.overlapping(b, out);
                for i in out.iter_mut() {
                    *i = ids[*i as usize];
                }
            }
        };

        let faces = mesh.faces();
        let point_triangle: Vec<PointTriangleCandidate> = mesh
            .vertices()
            .par_chunks(CHUNK)
            .zip(vertex_boxes.par_chunks(CHUNK))
            .flat_map_iter(|(verts, boxes)| {
                let mut found = Vec::new();
                let mut out = Vec::new();
                for (&v, b) in verts.iter().zip(boxes) {
                    found.clear();
                    query(
                        &face_tree,
                        &open_face_tree,
                        &open_faces,
                        !split || mesh.touches_all(v),
                        b,
                        &mut found,
                    );
                    for &f in &found {
                        let tri = faces[f as usize];
                        if !tri.contains(&v)
                            && tri.iter().all(|&t| mesh.can_touch(v, t))
                            && !mesh.excludes_point_triangle(v, f)
                        {
                            out.push(PointTriangleCandidate { vertex: v, face: f });
                        }
                    }
                }
                out
            })
            .collect();

        let edges = mesh.edges();
        let edge_edge: Vec<EdgeEdgeCandidate> = edge_boxes
            .par_chunks(CHUNK)
            .enumerate()
            .flat_map_iter(|(chunk, boxes)| {
                let mut found = Vec::new();
                let mut out = Vec::new();
                for (k, b) in boxes.iter().enumerate() {
                    let ea = (chunk * CHUNK + k) as u32;
                    let [a0, a1] = edges[ea as usize];
                    found.clear();
                    let universal = !split || (mesh.touches_all(a0) && mesh.touches_all(a1));
                    query(
                        &edge_tree,
                        &open_edge_tree,
                        &open_edges,
                        universal,
                        b,
                        &mut found,
                    );
                    for &eb in found.iter().filter(|&&eb| eb > ea) {
                        let [b0, b1] = edges[eb as usize];
                        let shares = a0 == b0 || a0 == b1 || a1 == b0 || a1 == b1;
                        let touch = [a0, a1]
                            .iter()
                            .all(|&p| mesh.can_touch(p, b0) && mesh.can_touch(p, b1));
                        if !shares && touch && !mesh.excludes_edge_edge(ea, eb) {
                            out.push(EdgeEdgeCandidate {
                                edge_a: ea,
                                edge_b: eb,
                            });
                        }
                    }
                }
                out
            })
            .collect();
        // Chunks are visited in order and each query is sorted: the lists are already sorted.
        debug_assert!(point_triangle.windows(2).all(|w| w[0] < w[1]));
        debug_assert!(edge_edge.windows(2).all(|w| w[0] < w[1]));
        Self {
            point_triangle,
            edge_edge,
        }
    }
}

fn check_inflation(inflation: f64) -> Result<(), ContactError> {
    if !(inflation >= 0.0) || !inflation.is_finite() {
        return Err(ContactError::InvalidParameter(format!(
            "box inflation must be finite and ≥ 0, got {inflation}"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests;
