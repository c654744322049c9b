//! The contact surface: triangles over the simulation's vertices, their unique edges, the
//! vertices they use, optional groups that may not touch each other, and the rest-shape data
//! the barrier needs (the edge–edge mollifier thresholds).

use super::ContactError;
use super::math::vertex;

/// Triangles (and their edges and vertices) that take part in contact. Vertex indices are the
/// simulation's, so positions are the solver's interleaved `[x0, y0, z0, …]` for all
/// `vertex_count` vertices; vertices no triangle uses are ignored.
#[derive(Clone, Debug)]
pub struct ContactMesh {
    vertex_count: usize,
    faces: Vec<[u32; 3]>,
    /// Unique edges `[a, b]` with `a < b`, sorted.
    edges: Vec<[u32; 2]>,
    /// The vertices the faces use, sorted.
    vertices: Vec<u32>,
    /// `‖e‖²` of every edge at rest (cm²), for `ε_x`.
    rest_edge_length2: Vec<f64>,
    /// Group of every simulation vertex (0 when no groups are given).
    group: Vec<u16>,
    /// `can_touch[g·groups + h]`.
    can_touch: Vec<bool>,
    groups: usize,
    /// Point–triangle pairs `(vertex, face)` with their own activation distance (cm),
    /// sorted by pair (see [`ContactMesh::with_close_pairs`]).
    close_point_triangle: Vec<((u32, u32), f64)>,
    /// Edge–edge pairs `(edge a, edge b)`, `a < b`, with their own activation distance,
    /// sorted by pair.
    close_edge_edge: Vec<((u32, u32), f64)>,
    /// How vertices move with cells; empty when none are given (see
    /// [`ContactMesh::with_cells`]).
    cells: Cells,
}

/// A vertex that moves with no cell.
pub const NO_CELL: u32 = u32::MAX;

/// The cells (e.g. simulation elements) contact vertices move with: each cell moves by one
/// affine map that never inverts, and cells sharing a face share it along that face.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cells {
    /// The cell of every vertex, [`NO_CELL`] for vertices that move otherwise.
    pub of_vertex: Vec<u32>,
    /// Whether every vertex lies inside its cell (non-negative barycentric weights): only
    /// such vertices share in the two-cell rule of [`ContactMesh::kept_apart`].
    pub inside: Vec<bool>,
    /// Pairs of cells that share a face, `(a, b)` in any order.
    pub face_neighbours: Vec<(u32, u32)>,
}

fn own_activation(pairs: &[((u32, u32), f64)], pair: (u32, u32)) -> Option<f64> {
    pairs
        .binary_search_by_key(&pair, |p| p.0)
        .ok()
        .map(|i| pairs[i].1)
}

impl ContactMesh {
    /// A contact surface in which every pair of primitives that shares no vertex may touch
    /// (self-contact included: the upper and lower lip are usually one connected surface).
    ///
    /// `rest` is interleaved (3 values per simulation vertex, cm). Fails on an index out of
    /// range, a triangle repeating a vertex, or a non-finite rest position.
    pub fn new(rest: &[f64], faces: Vec<[u32; 3]>) -> Result<Self, ContactError> {
        let n = rest.len() / 3;
        Self::with_groups(rest, faces, vec![0; n], &[vec![true]])
    }

    /// Like [`ContactMesh::new`], with a group per simulation vertex and a symmetric matrix
    /// `can_touch[g][h]`: a pair is considered only if some vertex of one primitive may touch
    /// some vertex of the other ([`ContactMesh::primitives_may_touch`]; e.g. upper teeth vs
    /// lower teeth off, lips vs teeth on, and a lining edge half on the jaw, half in the
    /// tissue, against a lower tooth on: its tissue end can cross the tooth).
    pub fn with_groups(
        rest: &[f64],
        faces: Vec<[u32; 3]>,
        group: Vec<u16>,
        can_touch: &[Vec<bool>],
    ) -> Result<Self, ContactError> {
        if !rest.len().is_multiple_of(3) {
            return Err(ContactError::PositionsLength {
                expected: rest.len() - rest.len() % 3,
                got: rest.len(),
            });
        }
        let vertex_count = rest.len() / 3;
        if vertex_count > u32::MAX as usize {
            return Err(ContactError::InvalidMesh("too many vertices".into()));
        }
        if let Some(i) =
            (0..vertex_count).find(|&i| !rest[3 * i..3 * i + 3].iter().all(|v| v.is_finite()))
        {
            return Err(ContactError::NonFinite(i));
        }
        if group.len() != vertex_count {
            return Err(ContactError::InvalidMesh(format!(
                "{} vertex groups for {vertex_count} vertices",
                group.len()
            )));
        }
        let groups = can_touch.len();
        if groups == 0 || can_touch.iter().any(|row| row.len() != groups) {
            return Err(ContactError::InvalidMesh(
                "can_touch must be a non-empty square matrix".into(),
            ));
        }
        for (g, row) in can_touch.iter().enumerate() {
            if let Some(h) = (0..groups).find(|&h| row[h] != can_touch[h][g]) {
                return Err(ContactError::InvalidMesh(format!(
                    "can_touch is not symmetric at ({g}, {h})"
                )));
            }
        }
        if let Some(&g) = group.iter().find(|&&g| g as usize >= groups) {
            return Err(ContactError::InvalidMesh(format!(
                "vertex group {g} out of range"
            )));
        }
        for (f, tri) in faces.iter().enumerate() {
            if tri.iter().any(|&v| v as usize >= vertex_count) {
                return Err(ContactError::InvalidMesh(format!(
                    "face {f} {tri:?} indexes past {vertex_count} vertices"
                )));
            }
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[2] == tri[0] {
                return Err(ContactError::InvalidMesh(format!(
                    "face {f} {tri:?} repeats a vertex"
                )));
            }
        }
        let mut edges: Vec<[u32; 2]> = faces
            .iter()
            .flat_map(|t| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]])
            .map(|[a, b]| [a.min(b), a.max(b)])
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let mut vertices: Vec<u32> = faces.iter().flatten().copied().collect();
        vertices.sort_unstable();
        vertices.dedup();
        let rest_edge_length2 = edges
            .iter()
            .map(|&[a, b]| (vertex(rest, a) - vertex(rest, b)).norm_squared())
            .collect();
        Ok(Self {
            vertex_count,
            faces,
            edges,
            vertices,
            rest_edge_length2,
            group,
            can_touch: can_touch.iter().flatten().copied().collect(),
            groups,
            close_point_triangle: Vec::new(),
            cells: Cells::default(),
            close_edge_edge: Vec::new(),
        })
    }

    /// The same surface with pairs that are already close at rest (e.g. neighbours along a
    /// finely tessellated surface, within d̂ of each other) given their own activation
    /// distance (cm), below their rest distance: the barrier leaves them alone at rest and
    /// near it, and keeps them from closing the rest of the way (CCD tracks them as every
    /// other pair). Indices are `(vertex, face)` and `(edge a, edge b)` into
    /// [`ContactMesh::faces`] and [`ContactMesh::edges`]; edge pairs are stored with `a < b`.
    pub fn with_close_pairs(
        mut self,
        mut point_triangle: Vec<((u32, u32), f64)>,
        edge_edge: Vec<((u32, u32), f64)>,
    ) -> Self {
        point_triangle.sort_unstable_by_key(|p| p.0);
        point_triangle.dedup_by_key(|p| p.0);
        let mut edge_edge: Vec<((u32, u32), f64)> = edge_edge
            .into_iter()
            .map(|((a, b), d)| ((a.min(b), a.max(b)), d))
            .collect();
        edge_edge.sort_unstable_by_key(|p| p.0);
        edge_edge.dedup_by_key(|p| p.0);
        self.close_point_triangle = point_triangle;
        self.close_edge_edge = edge_edge;
        self
    }

    /// The same surface with the cells its vertices move with. Two primitives whose vertices
    /// all lie in one cell, or all inside two cells sharing a face, can never meet (see
    /// [`ContactMesh::kept_apart`]), so contact leaves such pairs out: on the face they are
    /// most of the pairs within a few d̂ (neighbours along the finely tessellated surface),
    /// which the broad phase, CCD and the barrier would otherwise measure at every step.
    pub fn with_cells(mut self, mut cells: Cells) -> Result<Self, ContactError> {
        let n = self.vertex_count;
        if cells.of_vertex.len() != n || cells.inside.len() != n {
            return Err(ContactError::InvalidMesh(format!(
                "{} cells and {} inside flags for {n} vertices",
                cells.of_vertex.len(),
                cells.inside.len()
            )));
        }
        for pair in &mut cells.face_neighbours {
            *pair = (pair.0.min(pair.1), pair.0.max(pair.1));
        }
        cells.face_neighbours.sort_unstable();
        cells.face_neighbours.dedup();
        self.cells = cells;
        Ok(self)
    }

    /// Whether the cells keep primitives `a` and `b` (their vertices) from ever meeting:
    /// each lies in one cell, and either both in the same cell or both inside two cells that
    /// share a face. A cell moves by one affine map that never inverts, which is one-to-one
    /// and takes a flat primitive in it to the flat primitive between its moved vertices;
    /// two positively oriented tetrahedra sharing a face lie on opposite sides of it and
    /// agree on it, so the map is one-to-one on their union too. Primitives apart at rest
    /// then stay apart (the solver keeps every element at positive volume, along every
    /// step). Not so for a primitive spanning two cells (it is the chord between its moved
    /// vertices, not their cells' image) or for three cells (tetrahedra around an edge can
    /// wrap past a full turn).
    #[inline]
    pub fn kept_apart(&self, a: &[u32], b: &[u32]) -> bool {
        self.cells_keep_apart(self.cell_of(a), self.cell_of(b))
    }

    /// The cell a primitive (these vertices) lies in wholly ([`NO_CELL`] for none) and
    /// whether every vertex lies inside it: what [`ContactMesh::kept_apart`] compares, also
    /// for whole groups of primitives (the broad phase's tree nodes).
    #[inline]
    pub fn cell_of(&self, ids: &[u32]) -> (u32, bool) {
        let cells = &self.cells;
        if cells.of_vertex.is_empty() {
            return (NO_CELL, false);
        }
        let c = cells.of_vertex[ids[0] as usize];
        if ids[1..].iter().any(|&v| cells.of_vertex[v as usize] != c) {
            return (NO_CELL, false);
        }
        (c, ids.iter().all(|&v| cells.inside[v as usize]))
    }

    /// Whether primitives with these [`ContactMesh::cell_of`] are kept apart.
    #[inline]
    pub fn cells_keep_apart(
        &self,
        (ca, inside_a): (u32, bool),
        (cb, inside_b): (u32, bool),
    ) -> bool {
        ca != NO_CELL
            && cb != NO_CELL
            && (ca == cb
                || (inside_a
                    && inside_b
                    && self
                        .cells
                        .face_neighbours
                        .binary_search(&(ca.min(cb), ca.max(cb)))
                        .is_ok()))
    }

    /// The point–triangle pair's own activation distance (cm), if it is a close pair
    /// ([`ContactMesh::with_close_pairs`]).
    #[inline]
    pub fn point_triangle_activation(&self, vertex: u32, face: u32) -> Option<f64> {
        own_activation(&self.close_point_triangle, (vertex, face))
    }

    /// The edge–edge pair's `(a, b)`, `a < b`, own activation distance (cm), if it is a close
    /// pair.
    #[inline]
    pub fn edge_edge_activation(&self, a: u32, b: u32) -> Option<f64> {
        own_activation(&self.close_edge_edge, (a, b))
    }

    /// Number of close pairs with their own activation distance (point–triangle, edge–edge).
    pub fn close_pair_counts(&self) -> (usize, usize) {
        (self.close_point_triangle.len(), self.close_edge_edge.len())
    }

    /// Number of simulation vertices (positions have `3·vertex_count` values).
    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }

    /// Unique edges `[a, b]`, `a < b`, sorted.
    pub fn edges(&self) -> &[[u32; 2]] {
        &self.edges
    }

    /// The vertices used by the faces, sorted.
    pub fn vertices(&self) -> &[u32] {
        &self.vertices
    }

    /// The edge–edge mollifier threshold `ε_x = 10⁻³·‖ea‖²·‖eb‖²` at rest (cm⁴).
    pub fn mollifier_threshold(&self, ea: usize, eb: usize) -> f64 {
        1e-3 * self.rest_edge_length2[ea] * self.rest_edge_length2[eb]
    }

    /// Whether vertex `v`'s group may touch every group.
    #[inline]
    pub fn touches_all(&self, v: u32) -> bool {
        let g = self.group[v as usize] as usize;
        self.can_touch[g * self.groups..(g + 1) * self.groups]
            .iter()
            .all(|&t| t)
    }

    /// Whether every group either touches all groups or touches exactly the groups that do
    /// (e.g. soft tissue touching everything, rigid pieces touching only soft tissue). Then a
    /// pair can only be in contact if one of its primitives has all its vertices in
    /// touch-all groups, which lets the broad phase query a much smaller tree for the rest.
    pub fn groups_split_by_universal(&self) -> bool {
        let g = self.groups;
        let universal: Vec<bool> = (0..g)
            .map(|a| (0..g).all(|b| self.can_touch[a * g + b]))
            .collect();
        (0..g).all(|a| universal[a] || (0..g).all(|b| self.can_touch[a * g + b] == universal[b]))
    }

    /// Whether primitives (these vertices) `a` and `b` may be in contact: some vertex of one
    /// may touch some vertex of the other. With the face's groups (the tissue touches
    /// everything, what a bone carries only the tissue) that is every pair with a vertex the
    /// solver moves against the others.
    #[inline]
    pub fn primitives_may_touch(&self, a: &[u32], b: &[u32]) -> bool {
        a.iter().any(|&p| b.iter().any(|&q| self.can_touch(p, q)))
    }

    /// Whether vertices `a` and `b` may be in contact (by their groups).
    #[inline]
    pub fn can_touch(&self, a: u32, b: u32) -> bool {
        let (g, h) = (
            self.group[a as usize] as usize,
            self.group[b as usize] as usize,
        );
        self.can_touch[g * self.groups + h]
    }

    /// Diagonal of the bounding box of the contact vertices at `x` (cm), the scene size that
    /// the adaptive stiffness uses; 0 for an empty mesh. `x` must have passed
    /// [`ContactMesh::check_positions`].
    pub fn bbox_diagonal(&self, x: &[f64]) -> f64 {
        let mut pts = self.vertices.iter().map(|&v| vertex(x, v));
        let Some(first) = pts.next() else {
            return 0.0;
        };
        let (min, max) = pts.fold((first, first), |(lo, hi), p| (lo.inf(&p), hi.sup(&p)));
        (max - min).norm()
    }

    /// Checks interleaved positions (or displacements) for this mesh: length and finiteness of
    /// the contact vertices.
    pub fn check_positions(&self, x: &[f64]) -> Result<(), ContactError> {
        if x.len() != 3 * self.vertex_count {
            return Err(ContactError::PositionsLength {
                expected: 3 * self.vertex_count,
                got: x.len(),
            });
        }
        if let Some(&v) = self
            .vertices
            .iter()
            .find(|&&v| !vertex(x, v).iter().all(|c| c.is_finite()))
        {
            return Err(ContactError::NonFinite(v as usize));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One cell keeps primitives apart; two do only when they share a face, each primitive
    /// lies in one of them and every vertex lies inside its cell; vertices with no cell never
    /// are; cell lists of the wrong length are refused.
    #[test]
    fn cells_keep_apart_one_cell_or_two_sharing_a_face() {
        let rest = vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0];
        let mesh = ContactMesh::new(&rest, vec![[0, 1, 2], [1, 3, 2]]).unwrap();
        assert!(!mesh.kept_apart(&[0], &[1, 2]));
        let cells = |of_vertex: Vec<u32>, inside: Vec<bool>| Cells {
            of_vertex,
            inside,
            face_neighbours: vec![(8, 7), (7, 9)],
        };
        assert!(
            mesh.clone()
                .with_cells(cells(vec![0; 3], vec![true; 3]))
                .is_err()
        );
        assert!(
            mesh.clone()
                .with_cells(cells(vec![0; 4], vec![true; 3]))
                .is_err()
        );
        let celled = mesh
            .clone()
            .with_cells(cells(vec![7, 7, 8, NO_CELL], vec![true; 4]))
            .unwrap();
        assert!(celled.kept_apart(&[0], &[1]));
        assert!(celled.kept_apart(&[0, 1], &[2]), "7 and 8 share a face");
        assert!(
            !celled.kept_apart(&[0], &[1, 2]),
            "an edge spanning two cells"
        );
        assert!(!celled.kept_apart(&[1], &[3, 2]), "3 moves with no cell");
        assert!(!celled.kept_apart(&[3], &[3]));
        let outside = mesh
            .with_cells(cells(vec![7, 7, 8, 9], vec![true, false, true, true]))
            .unwrap();
        assert!(outside.kept_apart(&[0], &[1]), "one cell: inside or not");
        assert!(!outside.kept_apart(&[0, 1], &[2]), "1 lies outside cell 7");
        assert!(outside.kept_apart(&[0], &[3]), "7 and 9 share a face");
        assert!(!outside.kept_apart(&[2], &[3]), "8 and 9 share no face");
    }
}
