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
        Ok(Self::from_boxes(mesh, |ids: &[u32]| {
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
        check_swept(mesh, x, dx, inflation)?;
        Ok(Self::from_boxes(mesh, swept_box(x, dx, inflation)))
    }

    /// Total number of pairs.
    pub fn len(&self) -> usize {
        self.point_triangle.len() + self.edge_edge.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn from_boxes(mesh: &ContactMesh, box_of: impl Fn(&[u32]) -> Box3 + Sync) -> Self {
        // Fixed primitives built from the same boxes: nothing extra to grow by.
        let fixed = FixedTrees::new(mesh, &box_of);
        Self::from_split(mesh, &box_of, &fixed, 0.0)
    }

    /// The broad phase over the moving primitives (`box_of`, rebuilt) and the fixed ones
    /// (`fixed`, whose boxes are grown by `extra` more at query time).
    ///
    /// With groups split into touch-all (soft tissue) and touch-only-those (rigid pieces), a
    /// primitive is *open* when all its vertices touch all, *fixed* when none does (it can
    /// only meet open primitives), *mixed* otherwise (it can only meet open ones too). Pairs
    /// are then open–open and open–mixed (the moving trees), open–fixed (the fixed trees).
    /// Without such a split every primitive is open and nothing is fixed.
    fn from_split(
        mesh: &ContactMesh,
        box_of: &(impl Fn(&[u32]) -> Box3 + Sync),
        fixed: &FixedTrees,
        extra: f64,
    ) -> Self {
        let split = mesh.groups_split_by_universal();
        let universal = |v: u32| !split || mesh.touches_all(v);
        let faces = mesh.faces();
        let edges = mesh.edges();
        // Moving primitives: at least one touch-all vertex (ascending ids).
        let moving_faces: Vec<u32> = (0..faces.len() as u32)
            .filter(|&f| faces[f as usize].iter().any(|&v| universal(v)))
            .collect();
        let moving_edges: Vec<u32> = (0..edges.len() as u32)
            .filter(|&e| edges[e as usize].iter().any(|&v| universal(v)))
            .collect();
        let face_boxes: Vec<Box3> = moving_faces
            .par_iter()
            .map(|&f| box_of(&faces[f as usize]))
            .collect();
        let edge_boxes: Vec<Box3> = moving_edges
            .par_iter()
            .map(|&e| box_of(&edges[e as usize]))
            .collect();
        let face_tree = BoxTree::new(&face_boxes);
        let edge_tree = BoxTree::new(&edge_boxes);
        let has_fixed = !fixed.is_empty();
        let map = |ids: &[u32], out: &mut [u32]| {
            for i in out.iter_mut() {
                *i = ids[*i as usize];
            }
        };

        // Point–triangle, from the touch-all vertices: moving faces and fixed faces.
        let universal_vertices: Vec<u32> = mesh
            .vertices()
            .iter()
            .copied()
            .filter(|&v| universal(v))
            .collect();
        let keep_pt = |v: u32, f: u32| {
            let tri = faces[f as usize];
            !tri.contains(&v)
                && tri.iter().all(|&t| mesh.can_touch(v, t))
                && !mesh.excludes_point_triangle(v, f)
        };
        let mut point_triangle: Vec<PointTriangleCandidate> = universal_vertices
            .par_chunks(CHUNK)
            .flat_map_iter(|verts| {
                let (mut found, mut more) = (Vec::new(), Vec::new());
                let mut out = Vec::new();
                for &v in verts {
                    let b = box_of(std::slice::from_ref(&v));
                    face_tree.overlapping(&b, &mut found);
                    map(&moving_faces, &mut found);
                    if has_fixed {
                        fixed.face_tree.overlapping(&b.grown(extra), &mut more);
                        map(&fixed.faces, &mut more);
                        found.append(&mut more);
                        found.sort_unstable();
                    }
                    out.extend(
                        found
                            .iter()
                            .filter(|&&f| keep_pt(v, f))
                            .map(|&f| PointTriangleCandidate { vertex: v, face: f }),
                    );
                }
                out
            })
            .collect();
        // Fixed vertices against open faces, from the faces' side, merged in.
        if has_fixed && !fixed.vertices.is_empty() {
            let open_faces: Vec<(u32, Box3)> = moving_faces
                .iter()
                .zip(&face_boxes)
                .filter(|(f, _)| faces[**f as usize].iter().all(|&v| universal(v)))
                .map(|(&f, b)| (f, *b))
                .collect();
            let mut cross: Vec<PointTriangleCandidate> = open_faces
                .par_chunks(CHUNK)
                .flat_map_iter(|chunk| {
                    let mut found = Vec::new();
                    let mut out = Vec::new();
                    for (f, b) in chunk {
                        fixed.vertex_tree.overlapping(&b.grown(extra), &mut found);
                        map(&fixed.vertices, &mut found);
                        out.extend(found.iter().filter(|&&v| keep_pt(v, *f)).map(|&v| {
                            PointTriangleCandidate {
                                vertex: v,
                                face: *f,
                            }
                        }));
                    }
                    out
                })
                .collect();
            cross.par_sort_unstable();
            point_triangle = merge_sorted(point_triangle, cross);
        }

        // Edge–edge: moving edges against moving edges (each pair once, from its lower
        // edge), open edges against fixed edges (merged in).
        let keep_ee = |ea: u32, eb: u32| {
            let [a0, a1] = edges[ea as usize];
            let [b0, b1] = edges[eb as usize];
            let shares = a0 == b0 || a0 == b1 || a1 == b0 || a1 == b1;
            !shares
                && [a0, a1]
                    .iter()
                    .all(|&p| mesh.can_touch(p, b0) && mesh.can_touch(p, b1))
                && !mesh.excludes_edge_edge(ea.min(eb), ea.max(eb))
        };
        let open_edge = |e: u32| edges[e as usize].iter().all(|&v| universal(v));
        let (mut edge_edge, cross): (Vec<EdgeEdgeCandidate>, Vec<EdgeEdgeCandidate>) =
            moving_edges
                .par_chunks(CHUNK)
                .zip(edge_boxes.par_chunks(CHUNK))
                .map(|(ids, boxes)| {
                    let mut found = Vec::new();
                    let (mut out, mut cross) = (Vec::new(), Vec::new());
                    for (&ea, b) in ids.iter().zip(boxes) {
                        edge_tree.overlapping(b, &mut found);
                        map(&moving_edges, &mut found);
                        out.extend(found.iter().filter(|&&eb| eb > ea && keep_ee(ea, eb)).map(
                            |&eb| EdgeEdgeCandidate {
                                edge_a: ea,
                                edge_b: eb,
                            },
                        ));
                        if has_fixed && open_edge(ea) {
                            fixed.edge_tree.overlapping(&b.grown(extra), &mut found);
                            map(&fixed.edges, &mut found);
                            cross.extend(found.iter().filter(|&&eb| keep_ee(ea, eb)).map(|&eb| {
                                EdgeEdgeCandidate {
                                    edge_a: ea.min(eb),
                                    edge_b: ea.max(eb),
                                }
                            }));
                        }
                    }
                    (out, cross)
                })
                .reduce(
                    || (Vec::new(), Vec::new()),
                    |(mut a, mut c), (b, d)| {
                        a.extend(b);
                        c.extend(d);
                        (a, c)
                    },
                );
        if !cross.is_empty() {
            let mut cross = cross;
            cross.par_sort_unstable();
            edge_edge = merge_sorted(edge_edge, cross);
        }
        // Chunks are visited in order and each query is sorted: the lists are sorted.
        debug_assert!(point_triangle.windows(2).all(|w| w[0] < w[1]));
        debug_assert!(edge_edge.windows(2).all(|w| w[0] < w[1]));
        Self {
            point_triangle,
            edge_edge,
        }
    }
}

/// Two sorted lists with no common element, merged.
fn merge_sorted<T: Ord + Copy>(a: Vec<T>, b: Vec<T>) -> Vec<T> {
    if b.is_empty() {
        return a;
    }
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        if a[i] <= b[j] {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// Trees over the fixed primitives (see `Candidates::from_split`): faces and
/// edges with no touch-all vertex, and the vertices outside the touch-all groups.
struct FixedTrees {
    faces: Vec<u32>,
    face_tree: BoxTree,
    edges: Vec<u32>,
    edge_tree: BoxTree,
    vertices: Vec<u32>,
    vertex_tree: BoxTree,
}

impl FixedTrees {
    fn new(mesh: &ContactMesh, box_of: &(impl Fn(&[u32]) -> Box3 + Sync)) -> Self {
        let split = mesh.groups_split_by_universal();
        let fixed = |v: &u32| split && !mesh.touches_all(*v);
        let faces: Vec<u32> = (0..mesh.faces().len() as u32)
            .filter(|&f| mesh.faces()[f as usize].iter().all(fixed))
            .collect();
        let edges: Vec<u32> = (0..mesh.edges().len() as u32)
            .filter(|&e| mesh.edges()[e as usize].iter().all(fixed))
            .collect();
        let vertices: Vec<u32> = mesh.vertices().iter().copied().filter(fixed).collect();
        let tree = |boxes: Vec<Box3>| BoxTree::new(&boxes);
        Self {
            face_tree: tree(
                faces
                    .par_iter()
                    .map(|&f| box_of(&mesh.faces()[f as usize]))
                    .collect(),
            ),
            edge_tree: tree(
                edges
                    .par_iter()
                    .map(|&e| box_of(&mesh.edges()[e as usize]))
                    .collect(),
            ),
            vertex_tree: tree(
                vertices
                    .par_iter()
                    .map(|v| box_of(std::slice::from_ref(v)))
                    .collect(),
            ),
            faces,
            edges,
            vertices,
        }
    }

    fn is_empty(&self) -> bool {
        self.faces.is_empty() && self.edges.is_empty() && self.vertices.is_empty()
    }
}

/// The broad phase's trees over the primitives that do not move (every vertex outside the
/// touch-all groups, e.g. the teeth during a solve at a fixed bone pose), built once at
/// their positions and reused by every later candidate build while they stay there: only
/// the moving primitives' trees are rebuilt ([`Candidates::build_with`],
/// [`Candidates::build_swept_with`]).
pub struct FixedPrimitives {
    trees: FixedTrees,
    /// Positions of the fixed vertices when the trees were built (to check reuse).
    positions: Vec<f64>,
}

impl FixedPrimitives {
    /// Trees over the fixed primitives at positions `x` (exact boxes: queries grow theirs).
    pub fn new(mesh: &ContactMesh, x: &[f64]) -> Result<Self, ContactError> {
        mesh.check_positions(x)?;
        let trees = FixedTrees::new(mesh, &|ids: &[u32]| {
            Box3::around_iter(ids.iter().map(|&i| Point3::from(vertex(x, i))), 0.0)
        });
        let positions = trees
            .vertices
            .iter()
            .flat_map(|&v| vertex(x, v).into_iter().copied().collect::<Vec<_>>())
            .collect();
        Ok(Self { trees, positions })
    }

    /// Number of fixed vertices.
    pub fn vertex_count(&self) -> usize {
        self.trees.vertices.len()
    }

    /// The fixed vertices must be where the trees were built and must not move.
    fn check(&self, x: &[f64], dx: Option<&[f64]>) -> Result<(), ContactError> {
        for (k, &v) in self.trees.vertices.iter().enumerate() {
            let p = vertex(x, v);
            let moved = (0..3).any(|c| p[c] != self.positions[3 * k + c]);
            let moving = dx.is_some_and(|d| vertex(d, v) != nalgebra::Vector3::zeros());
            if moved || moving {
                return Err(ContactError::InvalidParameter(format!(
                    "fixed contact vertex {v} moved since its broad-phase trees were built"
                )));
            }
        }
        Ok(())
    }
}

impl Candidates {
    /// [`Candidates::build`] with the fixed primitives' trees built beforehand (`fixed` must
    /// have been built for this mesh at the same positions of the fixed vertices).
    pub fn build_with(
        mesh: &ContactMesh,
        fixed: &FixedPrimitives,
        x: &[f64],
        inflation: f64,
    ) -> Result<Self, ContactError> {
        mesh.check_positions(x)?;
        check_inflation(inflation)?;
        fixed.check(x, None)?;
        let box_of = |ids: &[u32]| {
            Box3::around_iter(
                ids.iter().map(|&i| Point3::from(vertex(x, i))),
                0.5 * inflation,
            )
        };
        Ok(Self::from_split(
            mesh,
            &box_of,
            &fixed.trees,
            0.5 * inflation,
        ))
    }

    /// [`Candidates::build_swept`] with the fixed primitives' trees built beforehand: the
    /// step must not move the fixed vertices.
    pub fn build_swept_with(
        mesh: &ContactMesh,
        fixed: &FixedPrimitives,
        x: &[f64],
        dx: &[f64],
        inflation: f64,
    ) -> Result<Self, ContactError> {
        check_swept(mesh, x, dx, inflation)?;
        fixed.check(x, Some(dx))?;
        Ok(Self::from_split(
            mesh,
            &swept_box(x, dx, inflation),
            &fixed.trees,
            0.5 * inflation,
        ))
    }
}

fn check_swept(
    mesh: &ContactMesh,
    x: &[f64],
    dx: &[f64],
    inflation: f64,
) -> Result<(), ContactError> {
    mesh.check_positions(x)?;
    mesh.check_positions(dx)?;
    check_inflation(inflation)
}

/// The box of a primitive (its vertex ids) over the step `x → x + dx`, grown by
/// `inflation/2`: a vertex moves on a segment, so both ends bound its path.
fn swept_box<'a>(
    x: &'a [f64],
    dx: &'a [f64],
    inflation: f64,
) -> impl Fn(&[u32]) -> Box3 + Sync + 'a {
    move |ids: &[u32]| {
        let ends = ids.iter().flat_map(|&i| {
            let p = Point3::from(vertex(x, i));
            [p, p + vertex(dx, i)]
        });
        Box3::around_iter(ends, 0.5 * inflation)
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
