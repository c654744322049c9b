//! Candidate pairs: point–triangle and edge–edge pairs whose boxes overlap, excluding pairs
//! that share a vertex or whose groups may not touch. A superset of the pairs that can be
//! closer than the inflation distance (static) or meet during a step (swept).

use rayon::prelude::*;

use super::ContactError;
use super::math::vertex;
use super::mesh::{ContactMesh, NO_CELL};
use crate::geometry::bvh::Box3;
use tree::{Bound, Fitted, Layout, pairs};

mod tree;
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

impl Candidates {
    /// Pairs closer than `inflation` (cm) may be missed never: every primitive's box at `x`
    /// is grown by `inflation/2` (for the barrier, `inflation = d̂`).
    pub fn build(mesh: &ContactMesh, x: &[f64], inflation: f64) -> Result<Self, ContactError> {
        mesh.check_positions(x)?;
        check_inflation(inflation)?;
        let boxes = point_boxes(x, 0.5 * inflation);
        Ok(Self::from_boxes(mesh, x, |ids: &[u32]| boxes.of(ids)))
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
        let boxes = swept_boxes(x, dx, inflation);
        Ok(Self::from_boxes(mesh, x, |ids: &[u32]| boxes.of(ids)))
    }

    /// Total number of pairs.
    pub fn len(&self) -> usize {
        self.point_triangle.len() + self.edge_edge.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The pairs split into the mesh's close pairs (with their own activation distance,
    /// [`ContactMesh::with_close_pairs`]) and the others, each in order: (close, others).
    pub fn split_close(&self, mesh: &ContactMesh) -> (Self, Self) {
        let (close_pt, pt) = self
            .point_triangle
            .iter()
            .partition(|c| mesh.point_triangle_activation(c.vertex, c.face).is_some());
        let (close_ee, ee) = self
            .edge_edge
            .iter()
            .partition(|c| mesh.edge_edge_activation(c.edge_a, c.edge_b).is_some());
        (
            Self {
                point_triangle: close_pt,
                edge_edge: close_ee,
            },
            Self {
                point_triangle: pt,
                edge_edge: ee,
            },
        )
    }

    /// [`Candidates::build_swept`] on the moving primitives' layouts of `prepared` (which
    /// group primitives only: any grouping finds every pair, one from nearby positions finds
    /// them fast). The fixed primitives may move along this step: their trees are built for
    /// it. The pose stages' certificates use the layouts of the solve before them.
    pub fn build_swept_on(
        mesh: &ContactMesh,
        prepared: &FixedPrimitives,
        x: &[f64],
        dx: &[f64],
        inflation: f64,
    ) -> Result<Self, ContactError> {
        check_swept(mesh, x, dx, inflation)?;
        let boxes = swept_boxes(x, dx, inflation);
        Ok(Self::from_layouts(
            mesh,
            &prepared.moving,
            |ids: &[u32]| boxes.of(ids),
        ))
    }

    fn from_boxes(mesh: &ContactMesh, x: &[f64], box_of: impl Fn(&[u32]) -> Box3 + Sync) -> Self {
        Self::from_layouts(mesh, &MovingLayouts::new(mesh, x), box_of)
    }

    fn from_layouts(
        mesh: &ContactMesh,
        moving: &MovingLayouts,
        box_of: impl Fn(&[u32]) -> Box3 + Sync,
    ) -> Self {
        // Fixed primitives built from the same boxes: nothing extra to grow by.
        let fixed = FixedTrees::new(mesh, &box_of);
        Self::from_split(
            mesh,
            moving,
            &box_of,
            &fixed,
            fixed.fits(),
            &|a: &Box3, b: &Box3| a.overlaps(b),
            &|a: &Box3, b: &Box3| a.overlaps(b),
        )
    }

    /// The broad phase over the moving primitives (bounded by `bound_of`, their trees refit
    /// on `moving`'s layouts) and the fixed ones (`fixed`): every pair whose bounds pass
    /// `test` (moving against moving) or `test_fixed` (moving against a fixed box) and may
    /// touch.
    ///
    /// With groups split into touch-all (soft tissue) and touch-only-those (rigid pieces), a
    /// primitive is *moving* when some vertex touches all and *fixed* when none does. A pair
    /// may touch only if it has a touch-all vertex ([`ContactMesh::primitives_may_touch`]),
    /// so pairs are moving–moving (the moving trees) and moving–fixed (against the fixed
    /// trees); fixed–fixed pairs never touch. Without such a split every primitive is moving
    /// and nothing is fixed.
    fn from_split<B: Bound, F: Bound>(
        mesh: &ContactMesh,
        moving: &MovingLayouts,
        bound_of: &(impl Fn(&[u32]) -> B + Sync),
        fixed: &FixedTrees,
        fixed_fits: FixedFits<'_, F>,
        test: &(impl Fn(&B, &B) -> bool + Sync),
        test_fixed: &(impl Fn(&B, &F) -> bool + Sync),
    ) -> Self {
        let faces = mesh.faces();
        let edges = mesh.edges();
        let celled = |ids: &[u32]| Celled {
            bound: bound_of(ids),
            cell: mesh.cell_of(ids),
        };
        let vertex_bounds: Vec<Celled<B>> = moving
            .vertices
            .par_iter()
            .map(|v| celled(std::slice::from_ref(v)))
            .collect();
        let face_bounds: Vec<Celled<B>> = moving
            .faces
            .par_iter()
            .map(|&f| celled(&faces[f as usize]))
            .collect();
        let edge_bounds: Vec<Celled<B>> = moving
            .edges
            .par_iter()
            .map(|&e| celled(&edges[e as usize]))
            .collect();
        let (vertex_nodes, face_nodes, edge_nodes) = (
            moving.vertex.fit(&vertex_bounds),
            moving.face.fit(&face_bounds),
            moving.edge.fit(&edge_bounds),
        );
        let fitted = |layout, nodes, items| Fitted {
            layout,
            nodes,
            items,
        };
        let vertex_tree = fitted(&moving.vertex, &vertex_nodes, &vertex_bounds);
        let face_tree = fitted(&moving.face, &face_nodes, &face_bounds);
        let edge_tree = fitted(&moving.edge, &edge_nodes, &edge_bounds);
        // Moving against moving: pairs the cells keep apart are dropped a whole subtree pair
        // at a time (the same test at nodes and primitives, monotone in both).
        let test = |a: &Celled<B>, b: &Celled<B>| {
            test(&a.bound, &b.bound) && !mesh.cells_keep_apart(a.cell, b.cell)
        };
        let test_fixed = |a: &Celled<B>, b: &F| test_fixed(&a.bound, b);
        let flipped = |a: &F, b: &Celled<B>| test_fixed(b, a);

        // Point–triangle: touch-all vertices against moving and fixed faces, fixed vertices
        // against moving faces.
        let keep_pt = |v: u32, f: u32| {
            let tri = faces[f as usize];
            !tri.contains(&v) && mesh.primitives_may_touch(&[v], &tri)
        };
        let push_pt = |v: u32, f: u32, out: &mut Vec<PointTriangleCandidate>| {
            if keep_pt(v, f) {
                out.push(PointTriangleCandidate { vertex: v, face: f });
            }
        };
        let mut point_triangle = pairs(vertex_tree, face_tree, false, &test, &|i, j, out| {
            push_pt(moving.vertices[i as usize], moving.faces[j as usize], out)
        });
        point_triangle.extend(pairs(
            vertex_tree,
            fixed_fits.face,
            false,
            &test_fixed,
            &|i, j, out| push_pt(moving.vertices[i as usize], fixed.faces[j as usize], out),
        ));
        point_triangle.extend(pairs(
            fixed_fits.vertex,
            face_tree,
            false,
            &flipped,
            &|i, j, out| push_pt(fixed.vertices[i as usize], moving.faces[j as usize], out),
        ));

        // Edge–edge: moving edges against each other (each pair once) and against fixed
        // edges.
        let keep_ee = |ea: u32, eb: u32| {
            let [a0, a1] = edges[ea as usize];
            let [b0, b1] = edges[eb as usize];
            let shares = a0 == b0 || a0 == b1 || a1 == b0 || a1 == b1;
            !shares && mesh.primitives_may_touch(&[a0, a1], &[b0, b1])
        };
        let push_ee = |ea: u32, eb: u32, out: &mut Vec<EdgeEdgeCandidate>| {
            if keep_ee(ea, eb) {
                out.push(EdgeEdgeCandidate {
                    edge_a: ea.min(eb),
                    edge_b: ea.max(eb),
                });
            }
        };
        let mut edge_edge = pairs(edge_tree, edge_tree, true, &test, &|i, j, out| {
            push_ee(moving.edges[i as usize], moving.edges[j as usize], out)
        });
        edge_edge.extend(pairs(
            edge_tree,
            fixed_fits.edge,
            false,
            &test_fixed,
            &|i, j, out| push_ee(moving.edges[i as usize], fixed.edges[j as usize], out),
        ));
        // Each pair was found once (the trees hold disjoint primitives): sorting makes the
        // lists independent of the traversal.
        point_triangle.par_sort_unstable();
        edge_edge.par_sort_unstable();
        debug_assert!(point_triangle.windows(2).all(|w| w[0] < w[1]));
        debug_assert!(edge_edge.windows(2).all(|w| w[0] < w[1]));
        Self {
            point_triangle,
            edge_edge,
        }
    }
}

/// Trees over every edge and every face of a surface, laid out once (e.g. at rest) and refit
/// at each query: the after-solve crossing audit runs on every audited solve, and building a fresh
/// tree and querying it edge by edge cost as much as a candidate build.
#[derive(Clone, Debug)]
pub(crate) struct EdgeFaceLayouts {
    edge: Layout,
    face: Layout,
}

impl EdgeFaceLayouts {
    /// Layouts from the edges' and faces' centres at `x`.
    pub(crate) fn new(mesh: &ContactMesh, x: &[f64]) -> Self {
        Self {
            edge: layout_of(x, mesh.edges().iter().map(|e| &e[..])),
            face: layout_of(x, mesh.faces().iter().map(|f| &f[..])),
        }
    }

    /// Every `(edge, face)` whose exact boxes at `y` overlap, handed to `emit` (which keeps
    /// what it wants); with `skip_kept_apart`, not the pairs the cells keep apart
    /// ([`ContactMesh::kept_apart`]: whole subtrees at once). The output's order depends on
    /// the traversal only.
    pub(crate) fn overlapping<T: Send>(
        &self,
        mesh: &ContactMesh,
        y: &[f64],
        skip_kept_apart: bool,
        emit: &(impl Fn(u32, u32, &mut Vec<T>) + Sync),
    ) -> Vec<T> {
        let boxes = point_boxes(y, 0.0);
        let bound_of = |ids: &[u32]| Celled {
            bound: boxes.of(ids),
            cell: mesh.cell_of(ids),
        };
        let edge_bounds: Vec<_> = mesh.edges().par_iter().map(|e| bound_of(e)).collect();
        let face_bounds: Vec<_> = mesh.faces().par_iter().map(|f| bound_of(f)).collect();
        let (edge_nodes, face_nodes) = (self.edge.fit(&edge_bounds), self.face.fit(&face_bounds));
        pairs(
            Fitted {
                layout: &self.edge,
                nodes: &edge_nodes,
                items: &edge_bounds,
            },
            Fitted {
                layout: &self.face,
                nodes: &face_nodes,
                items: &face_bounds,
            },
            false,
            &|a: &Celled<Box3>, b: &Celled<Box3>| {
                a.bound.overlaps(&b.bound)
                    && !(skip_kept_apart && mesh.cells_keep_apart(a.cell, b.cell))
            },
            emit,
        )
    }
}

/// The moving primitives (with at least one touch-all vertex; see
/// `Candidates::from_split`) and the layouts of their trees, whose boxes are refit at every
/// build.
#[derive(Clone, Debug)]
struct MovingLayouts {
    /// Touch-all vertices, moving faces and moving edges, ascending.
    vertices: Vec<u32>,
    faces: Vec<u32>,
    edges: Vec<u32>,
    vertex: Layout,
    face: Layout,
    edge: Layout,
}

impl MovingLayouts {
    /// Layouts from the primitives' centres at `x`.
    fn new(mesh: &ContactMesh, x: &[f64]) -> Self {
        let split = mesh.groups_split_by_universal();
        let universal = |v: u32| !split || mesh.touches_all(v);
        let faces: Vec<u32> = (0..mesh.faces().len() as u32)
            .filter(|&f| mesh.faces()[f as usize].iter().any(|&v| universal(v)))
            .collect();
        let edges: Vec<u32> = (0..mesh.edges().len() as u32)
            .filter(|&e| mesh.edges()[e as usize].iter().any(|&v| universal(v)))
            .collect();
        let vertices: Vec<u32> = mesh
            .vertices()
            .iter()
            .copied()
            .filter(|&v| universal(v))
            .collect();
        Self {
            vertex: layout_of(x, vertices.iter().map(std::slice::from_ref)),
            face: layout_of(x, faces.iter().map(|&f| &mesh.faces()[f as usize][..])),
            edge: layout_of(x, edges.iter().map(|&e| &mesh.edges()[e as usize][..])),
            vertices,
            faces,
            edges,
        }
    }
}

/// A tree over fixed boxes: layout, node boxes and the boxes themselves.
struct FixedTree {
    layout: Layout,
    nodes: Vec<Box3>,
    boxes: Vec<Box3>,
}

impl FixedTree {
    fn new(boxes: Vec<Box3>) -> Self {
        let centres: Vec<Point3<f64>> = boxes
            .iter()
            .map(|b| nalgebra::center(&b.min, &b.max))
            .collect();
        let layout = Layout::new(&centres);
        let nodes = layout.fit(&boxes);
        Self {
            layout,
            nodes,
            boxes,
        }
    }

    fn fitted(&self) -> Fitted<'_, Box3> {
        Fitted {
            layout: &self.layout,
            nodes: &self.nodes,
            items: &self.boxes,
        }
    }
}

/// The fixed trees' node and primitive bounds for one query.
struct FixedFits<'a, F> {
    vertex: Fitted<'a, F>,
    face: Fitted<'a, F>,
    edge: Fitted<'a, F>,
}

/// Per-query bounds of the fixed primitives and of their trees' nodes (on the trees'
/// layouts): e.g. their boxes where the trees were built with their displacements since.
struct FixedBounds<F> {
    vertex: (Vec<F>, Vec<F>),
    face: (Vec<F>, Vec<F>),
    edge: (Vec<F>, Vec<F>),
}

impl<F: Bound> FixedBounds<F> {
    fn fits<'a>(&'a self, trees: &'a FixedTrees) -> FixedFits<'a, F> {
        let fitted = |tree: &'a FixedTree, (nodes, items): &'a (Vec<F>, Vec<F>)| Fitted {
            layout: &tree.layout,
            nodes,
            items,
        };
        FixedFits {
            vertex: fitted(&trees.vertex, &self.vertex),
            face: fitted(&trees.face, &self.face),
            edge: fitted(&trees.edge, &self.edge),
        }
    }
}

/// Trees over the fixed primitives (see `Candidates::from_split`): faces and
/// edges with no touch-all vertex, and the vertices outside the touch-all groups.
struct FixedTrees {
    faces: Vec<u32>,
    face: FixedTree,
    edges: Vec<u32>,
    edge: FixedTree,
    vertices: Vec<u32>,
    vertex: FixedTree,
}

impl FixedTrees {
    /// The trees' own boxes (where they were built).
    fn fits(&self) -> FixedFits<'_, Box3> {
        FixedFits {
            vertex: self.vertex.fitted(),
            face: self.face.fitted(),
            edge: self.edge.fitted(),
        }
    }

    /// Bounds `bound(vertices, box where built)` of every fixed primitive, and of the
    /// trees' nodes by refitting them on the trees' layouts.
    fn moved_bounds<F: Bound>(
        &self,
        mesh: &ContactMesh,
        bound: impl Fn(&[u32], &Box3) -> F + Sync,
    ) -> FixedBounds<F> {
        fn of<'m, F: Bound>(
            tree: &FixedTree,
            ids: &'m [u32],
            stencil: impl Fn(&'m u32) -> &'m [u32] + Sync,
            bound: &(impl Fn(&[u32], &Box3) -> F + Sync),
        ) -> (Vec<F>, Vec<F>) {
            let items: Vec<F> = ids
                .par_iter()
                .zip(&tree.boxes)
                .map(|(i, at)| bound(stencil(i), at))
                .collect();
            (tree.layout.fit(&items), items)
        }
        let (faces, edges) = (mesh.faces(), mesh.edges());
        FixedBounds {
            vertex: of(&self.vertex, &self.vertices, std::slice::from_ref, &bound),
            face: of(&self.face, &self.faces, |&f| &faces[f as usize][..], &bound),
            edge: of(&self.edge, &self.edges, |&e| &edges[e as usize][..], &bound),
        }
    }

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
        Self {
            face: FixedTree::new(
                faces
                    .par_iter()
                    .map(|&f| box_of(&mesh.faces()[f as usize]))
                    .collect(),
            ),
            edge: FixedTree::new(
                edges
                    .par_iter()
                    .map(|&e| box_of(&mesh.edges()[e as usize]))
                    .collect(),
            ),
            vertex: FixedTree::new(
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
}

/// The broad phase's trees prepared at the start of a solve and reused by every later
/// candidate build ([`Candidates::build_with`], [`Candidates::build_swept_with`],
/// [`super::VerletList`]):
/// - over the primitives that do not move (every vertex outside the touch-all groups, e.g.
///   the teeth during a solve at a fixed bone pose): built once at their positions, reused
///   while they stay there;
/// - over the moving ones: the layout (which primitives share a node), whose boxes are
///   refit at every build (the surface deforms smoothly, so the grouping stays good).
pub struct FixedPrimitives {
    trees: FixedTrees,
    moving: MovingLayouts,
    /// Positions of the fixed vertices when the trees were built (to check reuse).
    positions: Vec<f64>,
}

impl FixedPrimitives {
    /// Trees over the fixed primitives at positions `x` (exact boxes: queries grow theirs),
    /// and the moving primitives' layouts from their positions at `x`.
    pub fn new(mesh: &ContactMesh, x: &[f64]) -> Result<Self, ContactError> {
        mesh.check_positions(x)?;
        let boxes = point_boxes(x, 0.0);
        let trees = FixedTrees::new(mesh, &|ids: &[u32]| boxes.of(ids));
        let positions = trees
            .vertices
            .iter()
            .flat_map(|&v| vertex(x, v).into_iter().copied().collect::<Vec<_>>())
            .collect();
        Ok(Self {
            trees,
            moving: MovingLayouts::new(mesh, x),
            positions,
        })
    }

    /// Number of fixed vertices.
    pub fn vertex_count(&self) -> usize {
        self.trees.vertices.len()
    }

    /// Whether the fixed vertices are at `x` where the trees were built (so the trees, and
    /// lists built with them, serve a solve at `x`'s bone pose).
    pub fn holds(&self, x: &[f64]) -> bool {
        self.check(x, None).is_ok()
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
        let boxes = point_boxes(x, 0.5 * inflation);
        let box_of = |ids: &[u32]| boxes.of(ids);
        Ok(Self::from_split(
            mesh,
            &fixed.moving,
            &box_of,
            &fixed.trees,
            fixed.trees.fits(),
            &|a: &Box3, b: &Box3| a.overlaps(b),
            &grown_overlap(0.5 * inflation),
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
        let boxes = swept_boxes(x, dx, inflation);
        Ok(Self::from_split(
            mesh,
            &fixed.moving,
            &|ids: &[u32]| boxes.of(ids),
            &fixed.trees,
            fixed.trees.fits(),
            &|a: &Box3, b: &Box3| a.overlaps(b),
            &grown_overlap(0.5 * inflation),
        ))
    }

    /// The pairs of [`Candidates::build_swept_with`] (`inflation = dhat`) that may come
    /// within `dhat` during the step by the relative-motion bound (see
    /// [`super::VerletList`]), and maybe a few more: whole subtrees are left out whose
    /// boxes at `x` are farther apart than `dhat` plus the most their vertices can move
    /// relative to each other. Neighbours along the surface that move together are never
    /// visited pair by pair; the caller applies the exact bound to what is left.
    pub(crate) fn build_swept_near(
        mesh: &ContactMesh,
        fixed: &FixedPrimitives,
        x: &[f64],
        dx: &[f64],
        dhat: f64,
    ) -> Result<Self, ContactError> {
        check_swept(mesh, x, dx, dhat)?;
        fixed.check(x, Some(dx))?;
        let bounds = VertexBounds::new(x, |i| {
            let p = Point3::from(vertex(x, i));
            let d = Point3::from(vertex(dx, i));
            SweptBound {
                swept: Box3::around(&[p, p + d.coords], 0.5 * dhat),
                at: Box3::around(&[p], 0.0),
                moved: Box3::around(&[d], 0.0),
            }
        });
        let bound_of = |ids: &[u32]| bounds.of(ids);
        let grown = grown_overlap(0.5 * dhat);
        let no_move = Box3::around(&[Point3::origin()], 0.0);
        Ok(Self::from_split(
            mesh,
            &fixed.moving,
            &bound_of,
            &fixed.trees,
            fixed.trees.fits(),
            &|a: &SweptBound, b: &SweptBound| {
                a.swept.overlaps(&b.swept) && !apart(&a.at, &a.moved, &b.at, &b.moved, dhat)
            },
            &|a: &SweptBound, b: &Box3| {
                grown(&a.swept, b) && !apart(&a.at, &a.moved, b, &no_move, dhat)
            },
        ))
    }
    /// The pairs that may come within `dhat` while every vertex moves from `x0 + start` to
    /// `x0 + end` (displacements from `x0`, linearly), among those farther apart than
    /// `listed` at `x0` (the pairs closer than that are the caller's, e.g. a
    /// [`super::VerletList`] built at `x0` with reach `listed`), and maybe a few more.
    ///
    /// A pair can come closer by at most its largest relative displacement, so the pairs
    /// farther than `listed` can reach `dhat` only where some vertices move by more than
    /// `listed − dhat` relative to each other: whole subtrees that move together (the
    /// neighbours along the surface) are left out, and so are those whose boxes at `x0` are
    /// farther apart than `dhat` plus their relative motion. The caller applies the exact
    /// bound to what is left. `fixed`'s trees must be those built at `x0`; its vertices may
    /// have moved since (a list built at one bone pose serves the next).
    pub(crate) fn build_moved(
        mesh: &ContactMesh,
        fixed: &FixedPrimitives,
        x0: &[f64],
        start: &[f64],
        end: &[f64],
        dhat: f64,
        listed: f64,
    ) -> Result<Self, ContactError> {
        check_swept(mesh, x0, start, dhat)?;
        mesh.check_positions(end)?;
        fixed.check(x0, None)?;
        let bounds = VertexBounds::new(x0, |i| MovedBound {
            at: Box3::around(&[Point3::from(vertex(x0, i))], 0.0),
            moved: Box3::around(
                &[Point3::from(vertex(start, i)), Point3::from(vertex(end, i))],
                0.0,
            ),
        });
        let bound_of = |ids: &[u32]| bounds.of(ids);
        // The fixed primitives' trees keep their layout and their boxes at `x0`; their
        // vertices may have moved since (the bones' next pose): each primitive and node gets
        // the box of its own vertices' displacements, so the teeth moving with the jaw are
        // bounded relative to the lip moving with it (one box of every fixed vertex's
        // displacement made each lip vertex near the lower teeth a candidate of every tooth
        // while the jaw moved).
        let fixed_bounds = fixed.trees.moved_bounds(mesh, |ids: &[u32], at: &Box3| {
            let moved = Box3::around_iter(
                ids.iter()
                    .flat_map(|&v| [Point3::from(vertex(start, v)), Point3::from(vertex(end, v))]),
                0.0,
            );
            MovedBound { at: *at, moved }
        });
        let together = listed - dhat - APART_TOLERANCE;
        let may_meet = |a: &MovedBound, b: &MovedBound| {
            let (gap, far) = gap_and_reach(&a.at, &a.moved, &b.at, &b.moved);
            far > together && gap - far <= dhat + APART_TOLERANCE
        };
        Ok(Self::from_split(
            mesh,
            &fixed.moving,
            &bound_of,
            &fixed.trees,
            fixed_bounds.fits(&fixed.trees),
            &may_meet,
            &may_meet,
        ))
    }
}

/// A moving primitive's (or node's) bound with the cell it lies in wholly
/// ([`ContactMesh::cell_of`]; a node's: its primitives' common cell, if any).
#[derive(Clone, Copy)]
struct Celled<B> {
    bound: B,
    cell: (u32, bool),
}

impl<B: Bound> Bound for Celled<B> {
    #[inline]
    fn union(&self, other: &Self) -> Self {
        let (ca, ia) = self.cell;
        let (cb, ib) = other.cell;
        Self {
            bound: self.bound.union(&other.bound),
            cell: if ca == cb {
                (ca, ia && ib)
            } else {
                (NO_CELL, false)
            },
        }
    }

    #[inline]
    fn extent(&self) -> f64 {
        self.bound.extent()
    }
}

/// A moving primitive (or node): its box at the reference positions and the box of its
/// vertices' displacements from there (at both ends of a step).
#[derive(Clone, Copy)]
struct MovedBound {
    at: Box3,
    moved: Box3,
}

impl Bound for MovedBound {
    #[inline]
    fn union(&self, other: &Self) -> Self {
        Self {
            at: self.at.union(&other.at),
            moved: self.moved.union(&other.moved),
        }
    }

    #[inline]
    fn extent(&self) -> f64 {
        self.at.extent()
    }
}

/// A moving primitive (or node) along a step: its swept box grown by d̂/2, its box at the
/// step's start and the box of its vertices' displacements.
#[derive(Clone, Copy)]
struct SweptBound {
    swept: Box3,
    at: Box3,
    moved: Box3,
}

impl Bound for SweptBound {
    #[inline]
    fn union(&self, other: &Self) -> Self {
        Self {
            swept: self.swept.union(&other.swept),
            at: self.at.union(&other.at),
            moved: self.moved.union(&other.moved),
        }
    }

    #[inline]
    fn extent(&self) -> f64 {
        self.swept.extent()
    }
}

/// Slack on the relative-motion bound: far above the rounding of the exact test that
/// follows (cm), far below d̂.
const APART_TOLERANCE: f64 = 1e-8;

/// Whether every pair of a primitive in (`at_a`, `moved_a`) and one in (`at_b`, `moved_b`)
/// stays farther than `dhat` from each other during the step: their distance at the start
/// is at least the gap between the boxes, and the pair comes closer by at most the largest
/// relative displacement, which the farthest points of the displacement boxes bound.
#[inline]
fn apart(at_a: &Box3, moved_a: &Box3, at_b: &Box3, moved_b: &Box3, dhat: f64) -> bool {
    let (gap, far) = gap_and_reach(at_a, moved_a, at_b, moved_b);
    gap - far > dhat + APART_TOLERANCE
}

/// The distance between two boxes of positions, and the largest distance between two
/// displacements in two boxes of displacements (how much closer two primitives in them can
/// come).
#[inline]
fn gap_and_reach(at_a: &Box3, moved_a: &Box3, at_b: &Box3, moved_b: &Box3) -> (f64, f64) {
    let (mut gap, mut far) = (0.0, 0.0);
    for k in 0..3 {
        let g = (at_a.min[k] - at_b.max[k]).max(at_b.min[k] - at_a.max[k]);
        if g > 0.0 {
            gap += g * g;
        }
        let f = (moved_a.max[k] - moved_b.min[k]).max(moved_b.max[k] - moved_a.min[k]);
        far += f * f;
    }
    (f64::sqrt(gap), f64::sqrt(far))
}

/// A tree layout over primitives (their vertex lists) from their centres at `x`.
fn layout_of<'a>(x: &[f64], primitives: impl Iterator<Item = &'a [u32]>) -> Layout {
    Layout::new(&primitives.map(|ids| centre(x, ids)).collect::<Vec<_>>())
}

/// The centre of a primitive (its vertex ids) at `x`: what a tree layout sorts by.
fn centre(x: &[f64], ids: &[u32]) -> Point3<f64> {
    Point3::from(ids.iter().map(|&i| vertex(x, i)).sum::<super::math::Vec3>() / ids.len() as f64)
}

/// Overlap of a moving box grown by `extra` with a fixed one.
fn grown_overlap(extra: f64) -> impl Fn(&Box3, &Box3) -> bool + Sync {
    move |a: &Box3, b: &Box3| a.grown(extra).overlaps(b)
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

/// Every vertex's box over the step `x → x + dx`, grown by `inflation/2`: a vertex moves on
/// a segment, so both ends bound its path (and a primitive's union of them, its path).
fn swept_boxes(x: &[f64], dx: &[f64], inflation: f64) -> VertexBounds<Box3> {
    VertexBounds::new(x, move |i| {
        let p = Point3::from(vertex(x, i));
        Box3::around(&[p, p + vertex(dx, i)], 0.5 * inflation)
    })
}

/// Every vertex's box at `x` grown by `margin`.
fn point_boxes(x: &[f64], margin: f64) -> VertexBounds<Box3> {
    VertexBounds::new(x, move |i| {
        Box3::around(&[Point3::from(vertex(x, i))], margin)
    })
}

/// Every vertex's bound, a primitive's being the union of its vertices' (recomputing each
/// primitive's from the positions was a fifth of a `VerletList::near_beyond`). Unions of
/// boxes are exact: the bounds are the same.
struct VertexBounds<B>(Vec<B>);

impl<B: Bound> VertexBounds<B> {
    /// `of(vertex)` for every vertex of positions `x`.
    fn new(x: &[f64], of: impl Fn(u32) -> B + Sync + Send) -> Self {
        Self((0..(x.len() / 3) as u32).into_par_iter().map(of).collect())
    }

    /// The bound of the primitive with these vertices.
    #[inline]
    fn of(&self, ids: &[u32]) -> B {
        let b = &self.0;
        ids[1..]
            .iter()
            .fold(b[ids[0] as usize], |u, &i| u.union(&b[i as usize]))
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
