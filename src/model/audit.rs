//! The crossing audit of what the artist sees: edge–triangle crossings of the skin and the
//! mouth lining, among themselves and with the teeth, at given positions.
//!
//! It is independent of the contact solver's own check, which covers only the contact region
//! (the lips and the front teeth) and leaves out pairs that its simulation cells keep apart:
//! the audit tests every edge against every triangle of the skin, the lining and the teeth with
//! the exact segment–triangle predicate of [`crate::rig::intersect`], and reports the pieces
//! that cross. Left out: the gums and tongue (the rig's gums pass through its teeth and
//! lining at rest, 2,780 pairs on the template), tooth against tooth (the jaw pose's
//! business), and every edge and triangle that already crosses something at rest (the rig's
//! lining passes through its back teeth: 304 pairs on the template), so that a region
//! interpenetrating from the start does not count again as it slides.

use nalgebra::Point3;

use super::face::FaceModel;
use crate::rig::Region;
use crate::rig::intersect::{EdgeTrianglePair, self_intersections};
use crate::rig::surface::SurfaceTopology;

/// The audit of one face's render surface (its topology and the crossings at rest).
#[derive(Clone, Debug)]
pub struct CrossingAudit {
    /// The skin, lining and teeth (render-vertex indices).
    surface: SurfaceTopology,
    /// The rig piece of every render vertex.
    pieces: Vec<Option<Region>>,
    /// Edges and triangles (of `surface`) that cross something at rest, sorted.
    rest_edges: Vec<[u32; 2]>,
    rest_triangles: Vec<u32>,
    rest: usize,
}

/// Crossings found by the audit, and between which pieces.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Crossings {
    /// New edge–triangle crossings.
    pub pairs: usize,
    /// Per pair of pieces (`"face skin / mouth socket"`, names sorted), their count, sorted.
    pub by_pieces: Vec<(String, usize)>,
    /// A render vertex of the first crossing's edge, as a rig vertex index (to find it).
    pub first_rig_vertex: Option<u32>,
}

impl CrossingAudit {
    pub fn new(face: &FaceModel) -> Self {
        let render = &face.render;
        let pieces: Vec<Option<Region>> = render
            .rig_vertices
            .iter()
            .map(|&v| Region::of_vertex(v as usize))
            .collect();
        let audited = |v: u32| {
            matches!(
                pieces[v as usize],
                Some(
                    Region::FaceSkin
                        | Region::MouthSocket
                        | Region::UpperTeeth
                        | Region::LowerTeeth
                )
            )
        };
        let triangles: Vec<[u32; 3]> = render
            .triangles
            .iter()
            .copied()
            .filter(|t| t.iter().all(|&v| audited(v)))
            .collect();
        let mut edges: Vec<[u32; 2]> = triangles
            .iter()
            .flat_map(|t| (0..3).map(move |k| [t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3])]))
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let surface = SurfaceTopology {
            source_faces: (0..triangles.len() as u32).collect(),
            triangles,
            edges,
        };
        let mut audit = Self {
            surface,
            pieces,
            rest_edges: Vec::new(),
            rest_triangles: Vec::new(),
            rest: 0,
        };
        let at_rest = audit.crossing_pairs(&render.rest);
        audit.rest = at_rest.len();
        audit.rest_edges = at_rest.iter().map(|p| p.edge).collect();
        audit.rest_triangles = at_rest.iter().map(|p| p.triangle).collect();
        audit.rest_edges.sort_unstable();
        audit.rest_edges.dedup();
        audit.rest_triangles.sort_unstable();
        audit.rest_triangles.dedup();
        audit
    }

    /// Crossings of the audited surface at rest (their edges and triangles are left out).
    pub fn rest_crossings(&self) -> usize {
        self.rest
    }

    fn is_tooth(&self, v: u32) -> bool {
        matches!(
            self.pieces[v as usize],
            Some(Region::UpperTeeth | Region::LowerTeeth)
        )
    }

    /// Every crossing of the audited surface at `positions` but tooth against tooth.
    fn crossing_pairs(&self, positions: &[Point3<f64>]) -> Vec<EdgeTrianglePair> {
        self_intersections(positions, &self.surface)
            .into_iter()
            .filter(|p| {
                !(self.is_tooth(p.edge[0])
                    && self.is_tooth(self.surface.triangles[p.triangle as usize][0]))
            })
            .collect()
    }

    /// The crossing pairs [`Self::audit`] counts: edges and triangles (render-vertex indices)
    /// that crossed nothing at rest and cross at `positions`.
    pub fn new_crossings(&self, positions: &[Point3<f64>]) -> Vec<([u32; 2], [u32; 3])> {
        self.crossing_pairs(positions)
            .into_iter()
            .filter(|p| {
                self.rest_edges.binary_search(&p.edge).is_err()
                    && self.rest_triangles.binary_search(&p.triangle).is_err()
            })
            .map(|p| (p.edge, self.surface.triangles[p.triangle as usize]))
            .collect()
    }

    /// The crossings of the skin and lining (among themselves and with the teeth) at
    /// `positions` (render-vertex order) by edges and triangles that crossed nothing at rest.
    pub fn audit(&self, face: &FaceModel, positions: &[Point3<f64>]) -> Crossings {
        let rig = &face.render.rig_vertices;
        let new = self.new_crossings(positions);
        let mut by_pieces: Vec<(String, usize)> = Vec::new();
        for (edge, t) in &new {
            let name = |v: u32| self.pieces[v as usize].map_or("other", |r| r.name());
            let mut names = [name(edge[0]), name(t[0])];
            names.sort_unstable();
            let key = format!("{} / {}", names[0], names[1]);
            match by_pieces.iter_mut().find(|(k, _)| *k == key) {
                Some(entry) => entry.1 += 1,
                None => by_pieces.push((key, 1)),
            }
        }
        by_pieces.sort();
        Crossings {
            pairs: new.len(),
            by_pieces,
            first_rig_vertex: new.first().map(|(edge, _)| rig[edge[0] as usize]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::test_support::coarse_face;

    #[test]
    fn the_rest_is_clean_and_a_lip_pushed_through_the_other_is_found() {
        let face = coarse_face(None);
        let audit = CrossingAudit::new(face);
        let render = &face.render;
        assert_eq!(audit.audit(face, &render.rest).pairs, 0);
        // Push the lower lip's skin 3 mm up, through the upper lip.
        let moved: Vec<Point3<f64>> = render
            .rest
            .iter()
            .zip(&render.rig_vertices)
            .map(|(p, &v)| {
                let lower_lip = Region::of_vertex(v as usize) == Some(Region::FaceSkin)
                    && p.x.abs() < 1.0
                    && (-4.0..-3.3).contains(&p.y)
                    && p.z > 10.8;
                if lower_lip {
                    p + nalgebra::Vector3::new(0.0, 0.3, 0.0)
                } else {
                    *p
                }
            })
            .collect();
        let found = audit.audit(face, &moved);
        assert!(found.pairs > 0, "{found:?}");
        assert!(
            found.by_pieces.iter().any(|(k, _)| k.contains("face skin")),
            "{found:?}"
        );
    }
}
