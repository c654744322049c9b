//! The crease audit of what the artist sees: edges of the skin and the mouth lining whose two
//! triangles have turned onto each other (a crease or a crumple of the render surface; not an
//! inverted element of the tissue), at given positions.
//!
//! An edge is creased when its two triangles' normals are more than 120° apart
//! (`n₁·n₂ < cos 120° = −½`) where they were less than 90° apart at rest (`n₁·n₂ > 0`): the
//! surface there has turned back on itself. The crossing audit ([`super::audit`]) does not
//! see this, since a creased edge need not pass through anything. The rig's own shapes crease
//! in places (its jawForward creases 16 skin edges on the template), so the audit is read
//! against the rig's target for the same code.

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};

use super::face::FaceModel;
use crate::rig::Region;

/// `n₁·n₂` below which an edge counts as creased: its triangles are more than 120° apart.
pub const CREASED_COS: f64 = -0.5;

/// The audit of one face's render surface: its skin and lining edges between two triangles
/// less than 90° apart at rest (the sharper ones are the rig's own creases).
#[derive(Clone, Debug)]
pub struct CreaseAudit {
    /// `(edge, its two triangles, the edge's piece)`, for edges that were not creased at rest.
    edges: Vec<([u32; 2], [usize; 2], Region)>,
    triangles: Vec<[u32; 3]>,
    rig_vertices: Vec<u32>,
}

/// Creased edges found by the audit.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Creases {
    /// Creased skin and lining edges.
    pub edges: usize,
    /// Per piece (`"face skin"`, `"mouth socket"`), their count, largest first.
    pub by_piece: Vec<(String, usize)>,
    /// A rig vertex of the most creased edge (to find it).
    pub worst_rig_vertex: Option<u32>,
}

impl CreaseAudit {
    pub fn new(face: &FaceModel) -> Self {
        let render = &face.render;
        let piece = |v: u32| Region::of_vertex(render.rig_vertices[v as usize] as usize);
        let audited = |v: u32| matches!(piece(v), Some(Region::FaceSkin | Region::MouthSocket));
        let mut sides: HashMap<[u32; 2], Vec<usize>> = HashMap::new();
        for (t, tri) in render.triangles.iter().enumerate() {
            if !tri.iter().all(|&v| audited(v)) {
                continue;
            }
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                sides.entry([a.min(b), a.max(b)]).or_default().push(t);
            }
        }
        let rest = normals(&render.rest, &render.triangles);
        let mut edges: Vec<_> = sides
            .into_iter()
            .filter_map(|(edge, ts)| {
                let [t1, t2] = ts[..] else { return None };
                let lining = edge.iter().any(|&v| piece(v) == Some(Region::MouthSocket));
                let region = if lining {
                    Region::MouthSocket
                } else {
                    Region::FaceSkin
                };
                (rest[t1].dot(&rest[t2]) > 0.0).then_some((edge, [t1, t2], region))
            })
            .collect();
        edges.sort_unstable_by_key(|e| e.0);
        Self {
            edges,
            triangles: render.triangles.clone(),
            rig_vertices: render.rig_vertices.clone(),
        }
    }

    /// The creased edges at render positions `positions`, in edge order.
    pub fn creased(&self, positions: &[Point3<f64>]) -> Vec<CreasedEdge> {
        let n = normals(positions, &self.triangles);
        self.edges
            .iter()
            .filter_map(|&(edge, triangles, piece)| {
                let cos = n[triangles[0]].dot(&n[triangles[1]]);
                (cos < CREASED_COS).then_some(CreasedEdge {
                    edge,
                    triangles,
                    cos,
                    piece,
                })
            })
            .collect()
    }

    /// [`CreaseAudit::creased`], counted by pieces.
    pub fn audit(&self, positions: &[Point3<f64>]) -> Creases {
        self.count(&self.creased(positions))
    }

    /// Creased edges counted by pieces.
    pub fn count(&self, creased: &[CreasedEdge]) -> Creases {
        let mut counts: Vec<(Region, usize)> = Vec::new();
        for c in creased {
            match counts.iter_mut().find(|(r, _)| *r == c.piece) {
                Some(entry) => entry.1 += 1,
                None => counts.push((c.piece, 1)),
            }
        }
        counts.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        Creases {
            edges: creased.len(),
            by_piece: counts
                .into_iter()
                .map(|(r, c)| (r.name().to_string(), c))
                .collect(),
            worst_rig_vertex: creased
                .iter()
                .min_by(|a, b| a.cos.total_cmp(&b.cos))
                .map(|c| self.rig_vertices[c.edge[0] as usize]),
        }
    }
}

/// The edges of `creased` that are not in `known` (the creases of the rig's own shape for
/// the same code); both as [`CreaseAudit::creased`] gives them, in edge order.
pub fn beyond(creased: &[CreasedEdge], known: &[CreasedEdge]) -> Vec<CreasedEdge> {
    creased
        .iter()
        .filter(|c| known.binary_search_by_key(&c.edge, |k| k.edge).is_err())
        .copied()
        .collect()
}

/// One creased edge (render-vertex indices).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CreasedEdge {
    pub edge: [u32; 2],
    /// Its two triangles (indices into the render surface's triangles).
    pub triangles: [usize; 2],
    /// `n₁·n₂` of their normals (below [`CREASED_COS`]).
    pub cos: f64,
    /// The lining when either end is lining, else the skin.
    pub piece: Region,
}

/// Unit normals of `triangles` (zero for a degenerate one, which then creases nothing).
fn normals(p: &[Point3<f64>], triangles: &[[u32; 3]]) -> Vec<Vector3<f64>> {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|v| p[v as usize]);
            (b - a)
                .cross(&(c - a))
                .try_normalize(0.0)
                .unwrap_or_else(Vector3::zeros)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::test_support::coarse_face;

    /// Nothing is creased at rest; a skin vertex moved across the opposite edge of one of its
    /// triangles turns that triangle over onto its neighbour, a crease of skin edges named by
    /// a rig vertex there; rigid motion creases nothing.
    #[test]
    fn a_triangle_turned_over_creases_its_edge() {
        let face = coarse_face(None);
        let audit = CreaseAudit::new(face);
        let render = &face.render;
        let rest = &render.rest;
        assert_eq!(audit.audit(rest), Creases::default());
        let skin = |v: u32| {
            Region::of_vertex(render.rig_vertices[v as usize] as usize) == Some(Region::FaceSkin)
        };
        // A skin triangle near the middle of the skin's list, its first corner reflected
        // through the midpoint of the opposite edge (in the triangle's plane).
        let skin_triangles: Vec<&[u32; 3]> = render
            .triangles
            .iter()
            .filter(|t| t.iter().all(|&v| skin(v)))
            .collect();
        let [v, a, b] = *skin_triangles[skin_triangles.len() / 2];
        let mut posed = rest.clone();
        posed[v as usize] = Point3::from(rest[a as usize].coords + rest[b as usize].coords)
            - rest[v as usize].coords;
        let creases = audit.audit(&posed);
        assert!(creases.edges >= 1, "{creases:?}");
        assert_eq!(
            creases.by_piece,
            vec![("face skin".to_string(), creases.edges)]
        );
        let worst = creases.worst_rig_vertex.unwrap();
        let near = render
            .triangles
            .iter()
            .filter(|t| t.contains(&v))
            .flatten()
            .any(|&u| render.rig_vertices[u as usize] == worst);
        assert!(near, "the worst edge is at the moved vertex");
        let creased = audit.creased(&posed);
        assert_eq!(
            audit.count(&beyond(&creased, &audit.creased(rest))),
            creases
        );
        assert!(beyond(&creased, &creased).is_empty());
        let turn = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.5);
        let moved: Vec<_> = rest
            .iter()
            .map(|p| turn * p + Vector3::new(1.0, 2.0, 3.0))
            .collect();
        assert_eq!(audit.audit(&moved).edges, 0);
    }
}
