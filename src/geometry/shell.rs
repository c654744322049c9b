//! A layer of tissue under a surface: prism layers extruded along the surface's inward normals,
//! each prism split into three tetrahedra.
//!
//! The split follows the minimum-index rule (Dompierre et al. 1999): each quadrilateral side
//! of a prism is cut by the diagonal through its lowest-indexed vertex, so two prisms sharing a
//! side cut it the same way and the mesh is conforming without any global bookkeeping. Surface
//! boundaries (the mouth slit, the eyes) stay boundaries: material on either side of a slit
//! shares no element.

use nalgebra::{Point3, Vector3};

use super::tet_mesh::{MeshError, TetMesh};

/// Vertex `v` of layer `l` (layer 0 is the surface) is mesh vertex `l·n + v`.
#[derive(Clone, Debug)]
pub struct Shell {
    pub mesh: TetMesh,
    pub surface_vertices: usize,
    pub layers: usize,
}

impl Shell {
    pub fn vertex(&self, layer: usize, surface_vertex: usize) -> usize {
        layer * self.surface_vertices + surface_vertex
    }

    /// The innermost layer: where the tissue meets bone.
    pub fn inner_layer(&self) -> std::ops::Range<usize> {
        let start = self.layers * self.surface_vertices;
        start..start + self.surface_vertices
    }
}

/// Area-weighted vertex normals of a triangle surface (zero for unreferenced vertices).
pub fn vertex_normals(vertices: &[Point3<f64>], triangles: &[[u32; 3]]) -> Vec<Vector3<f64>> {
    let mut normals = vec![Vector3::zeros(); vertices.len()];
    for t in triangles {
        let [a, b, c] = t.map(|v| vertices[v as usize]);
        let n = (b - a).cross(&(c - a)); // length = 2·area
        for &v in t {
            normals[v as usize] += n;
        }
    }
    for n in &mut normals {
        let len = n.norm();
        if len > 0.0 {
            *n /= len;
        }
    }
    normals
}

/// Smooths unit directions by averaging over edge neighbours (`iterations` Jacobi sweeps),
/// which keeps offset layers from folding in concave regions.
pub fn smooth_directions(
    directions: &[Vector3<f64>],
    triangles: &[[u32; 3]],
    iterations: usize,
) -> Vec<Vector3<f64>> {
    let mut current = directions.to_vec();
    for _ in 0..iterations {
        let mut sum = current.clone();
        for t in triangles {
            for i in 0..3 {
                let (a, b) = (t[i] as usize, t[(i + 1) % 3] as usize);
                sum[a] += current[b];
                sum[b] += current[a];
            }
        }
        for (c, s) in current.iter_mut().zip(sum) {
            let len = s.norm();
            if len > 0.0 {
                *c = s / len;
            }
        }
    }
    current
}

/// Why a shell could not be built.
#[derive(Debug, thiserror::Error)]
pub enum ShellError {
    #[error("need at least one layer")]
    NoLayers,
    #[error("surface vertex {vertex} has thickness {thickness} (must be positive and finite)")]
    BadThickness { vertex: usize, thickness: f64 },
    #[error("surface vertex {0} has no direction to extrude along")]
    NoDirection(usize),
    #[error("the layer folds under {} surface triangle(s) (first: {}); thin it there", .0.len(), .0[0])]
    Folded(Vec<usize>),
    #[error("extruded mesh is invalid: {0}")]
    Mesh(#[from] MeshError),
}

/// Extrudes a triangle surface into `layers` prism layers: layer `l` of vertex `v` sits at
/// `p_v + (l / layers)·thickness_v·inward_v`, with `inward` unit vectors into the tissue and
/// triangles wound so that their normals point away from it. Where the layer would fold
/// (neighbouring directions crossing within the thickness) it fails with the triangles
/// concerned, for the caller to thin the layer there.
pub fn extrude(
    vertices: &[Point3<f64>],
    triangles: &[[u32; 3]],
    inward: &[Vector3<f64>],
    thickness: &[f64],
    layers: usize,
) -> Result<Shell, ShellError> {
    if layers == 0 {
        return Err(ShellError::NoLayers);
    }
    let n = vertices.len();
    for (vertex, &t) in thickness.iter().enumerate() {
        if !(t > 0.0 && t.is_finite()) {
            return Err(ShellError::BadThickness {
                vertex,
                thickness: t,
            });
        }
    }
    let mut used = vec![false; n];
    for t in triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    if let Some(v) = (0..n).find(|&v| used[v] && !(inward[v].norm() > 0.5)) {
        return Err(ShellError::NoDirection(v));
    }
    let mut points = Vec::with_capacity(n * (layers + 1));
    for l in 0..=layers {
        let f = l as f64 / layers as f64;
        points.extend((0..n).map(|v| vertices[v] + inward[v] * (thickness[v] * f)));
    }
    // For an unfolded prism under a triangle wound outward (normal against `inward`), each of
    // the three tetrahedra of `split_prism` has negative volume in the listed order; swapping
    // two vertices orients it positively. A non-negative one means the layer folded there.
    let mut tets = Vec::with_capacity(3 * layers * triangles.len());
    let mut folded = Vec::new();
    for (index, t) in triangles.iter().enumerate() {
        let mut ok = true;
        for l in 0..layers {
            let bottom = t.map(|v| (l * n) as u32 + v);
            let top = t.map(|v| ((l + 1) * n) as u32 + v);
            for mut tet in split_prism(bottom, top) {
                let [a, b, c, d] = tet.map(|v| points[v as usize]);
                ok &= (b - a).dot(&(c - a).cross(&(d - a))) < 0.0;
                tet.swap(2, 3);
                tets.push(tet);
            }
        }
        if !ok {
            folded.push(index);
        }
    }
    if !folded.is_empty() {
        return Err(ShellError::Folded(folded));
    }
    Ok(Shell {
        mesh: TetMesh::new(points, tets)?,
        surface_vertices: n,
        layers,
    })
}

/// Splits the prism `(a, b, c)–(a', b', c')` into 3 tetrahedra with the minimum-index rule.
/// The prism is rotated so that its lowest vertex index is on `a` or `a'`; both tetrahedra
/// through that vertex then fix the diagonals of the two sides that meet there, and the third
/// side `(b, c, c', b')` is cut through its own lowest vertex.
fn split_prism(bottom: [u32; 3], top: [u32; 3]) -> [[u32; 4]; 3] {
    // Rotate so that corner 0 holds the smallest index among all six.
    let mut k = 0;
    for i in 1..3 {
        if bottom[i].min(top[i]) < bottom[k].min(top[k]) {
            k = i;
        }
    }
    let (mut b, mut t) = (
        [bottom[k], bottom[(k + 1) % 3], bottom[(k + 2) % 3]],
        [top[k], top[(k + 1) % 3], top[(k + 2) % 3]],
    );
    // Make corner 0's bottom vertex the smallest (swap bottom and top, which mirrors the prism).
    if t[0] < b[0] {
        std::mem::swap(&mut b, &mut t);
    }
    let [a0, a1, a2] = b;
    let [b0, b1, b2] = t;
    // Tetrahedron through a0 and the whole top triangle's diagonal side.
    if a1.min(b2) < b1.min(a2) {
        // Side (1, 2) is cut by the diagonal a1–b2.
        [[a0, a1, a2, b2], [a0, a1, b2, b1], [a0, b1, b2, b0]]
    } else {
        // Side (1, 2) is cut by the diagonal b1–a2.
        [[a0, a1, a2, b1], [a0, b1, a2, b2], [a0, b1, b2, b0]]
    }
}

/// Element quality of a tetrahedral mesh, the figures the importer reports.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize, PartialEq)]
pub struct MeshQuality {
    pub elements: usize,
    pub vertices: usize,
    /// Smallest dihedral angle of any element, degrees (a regular tetrahedron has 70.5°).
    pub min_dihedral_deg: f64,
    /// Largest dihedral angle, degrees.
    pub max_dihedral_deg: f64,
    /// Mean ratio `12·(3V)^(2/3) / Σ edge²` (1 for a regular tetrahedron, 0 when flat): minimum and median.
    pub min_shape_quality: f64,
    pub median_shape_quality: f64,
    /// Largest over smallest element volume.
    pub volume_ratio: f64,
    /// Elements with non-positive volume.
    pub inverted: usize,
}

/// Measures every element of `mesh`.
pub fn quality(mesh: &TetMesh) -> MeshQuality {
    let mut min_dihedral = f64::INFINITY;
    let mut max_dihedral: f64 = 0.0;
    let mut shapes = Vec::with_capacity(mesh.element_count());
    let (mut vmin, mut vmax) = (f64::INFINITY, 0.0f64);
    let mut inverted = 0;
    for e in 0..mesh.element_count() {
        let p = mesh.tets[e].map(|v| mesh.vertices[v as usize]);
        let volume = mesh.signed_volume(e);
        if !(volume > 0.0) {
            inverted += 1;
        }
        vmin = vmin.min(volume);
        vmax = vmax.max(volume);
        shapes.push(shape_quality(&p, volume));
        for angle in dihedral_angles(&p) {
            min_dihedral = min_dihedral.min(angle);
            max_dihedral = max_dihedral.max(angle);
        }
    }
    shapes.sort_by(f64::total_cmp);
    MeshQuality {
        elements: mesh.element_count(),
        vertices: mesh.vertex_count(),
        min_dihedral_deg: min_dihedral,
        max_dihedral_deg: max_dihedral,
        min_shape_quality: shapes.first().copied().unwrap_or(0.0),
        median_shape_quality: shapes.get(shapes.len() / 2).copied().unwrap_or(0.0),
        volume_ratio: vmax / vmin,
        inverted,
    }
}

/// The mean ratio `12·(3V)^(2/3) / Σ edge²` of a tetrahedron of volume `volume`: 1 for a
/// regular one, 0 when flat (or inverted).
pub fn shape_quality(p: &[Point3<f64>; 4], volume: f64) -> f64 {
    let mut edge_sq = 0.0;
    for i in 0..4 {
        for j in i + 1..4 {
            edge_sq += (p[i] - p[j]).norm_squared();
        }
    }
    12.0 * (3.0 * volume.max(0.0)).powf(2.0 / 3.0) / edge_sq
}

/// The six interior dihedral angles of a tetrahedron, degrees.
pub fn dihedral_angles(p: &[Point3<f64>; 4]) -> [f64; 6] {
    // The angle at edge (i, j) is between the faces opposite k and l: π − angle of their normals.
    let face_normal = |skip: usize| -> Vector3<f64> {
        let idx: Vec<usize> = (0..4).filter(|&i| i != skip).collect();
        let n = (p[idx[1]] - p[idx[0]]).cross(&(p[idx[2]] - p[idx[0]]));
        // Orient outward: away from the skipped vertex.
        if n.dot(&(p[skip] - p[idx[0]])) > 0.0 {
            -n
        } else {
            n
        }
    };
    let normals = [
        face_normal(0),
        face_normal(1),
        face_normal(2),
        face_normal(3),
    ];
    let mut out = [0.0; 6];
    let mut slot = 0;
    for k in 0..4 {
        for l in k + 1..4 {
            let cos = normals[k].dot(&normals[l]) / (normals[k].norm() * normals[l].norm());
            out[slot] = 180.0 - cos.clamp(-1.0, 1.0).acos().to_degrees();
            slot += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A curved sheet of `nx × ny` quads (split in two triangles) with a slit cut along the
    /// middle row between columns 1 and nx-1: the slit's two sides have separate vertices.
    fn slit_sheet(nx: usize, ny: usize) -> (Vec<Point3<f64>>, Vec<[u32; 3]>, Vec<usize>) {
        let mut vertices = Vec::new();
        let mut index = vec![vec![0u32; nx + 1]; ny + 1];
        let mid = ny / 2;
        let mut lower_twin = vec![vec![None; nx + 1]; ny + 1];
        for j in 0..=ny {
            for i in 0..=nx {
                let (x, y) = (i as f64, j as f64);
                let p = Point3::new(x, y, 0.05 * (x - nx as f64 / 2.0).powi(2));
                index[j][i] = vertices.len() as u32;
                vertices.push(p);
                if j == mid && i > 0 && i < nx {
                    lower_twin[j][i] = Some(vertices.len() as u32);
                    vertices.push(p);
                }
            }
        }
        let mut triangles = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                // Quads below the slit use the twin copies of the slit row.
                let at = |jj: usize, ii: usize| {
                    if jj == mid && j < mid {
                        lower_twin[jj][ii].unwrap_or(index[jj][ii])
                    } else {
                        index[jj][ii]
                    }
                };
                let (a, b, c, d) = (at(j, i), at(j, i + 1), at(j + 1, i + 1), at(j + 1, i));
                triangles.push([a, b, c]);
                triangles.push([a, c, d]);
            }
        }
        let slit_lower: Vec<usize> = (1..nx)
            .filter_map(|i| lower_twin[mid][i].map(|v| v as usize))
            .collect();
        (vertices, triangles, slit_lower)
    }

    #[test]
    fn extrusion_is_conforming_positive_and_fills_the_layer() {
        let (vertices, triangles, _) = slit_sheet(8, 6);
        let normals = vertex_normals(&vertices, &triangles);
        let inward: Vec<_> = normals.iter().map(|n| -n).collect();
        let thickness = vec![0.8; vertices.len()];
        let shell = extrude(&vertices, &triangles, &inward, &thickness, 2).unwrap();
        assert_eq!(shell.mesh.element_count(), 3 * 2 * triangles.len());
        let q = quality(&shell.mesh);
        assert_eq!(q.inverted, 0);
        assert!(q.min_dihedral_deg > 5.0, "{q:?}");
        // Conforming: every interior triangular face is shared by exactly two elements, and
        // the boundary faces are the surface, the innermost layer and the sides.
        let mut faces = std::collections::BTreeMap::new();
        for tet in &shell.mesh.tets {
            for skip in 0..4 {
                let mut f: Vec<u32> = (0..4).filter(|&i| i != skip).map(|i| tet[i]).collect();
                f.sort();
                *faces.entry(f).or_insert(0) += 1;
            }
        }
        assert!(faces.values().all(|&c| c <= 2));
        let boundary = faces.values().filter(|&&c| c == 1).count();
        let surface_and_inner = 2 * triangles.len();
        assert!(boundary > surface_and_inner, "sides must be boundary too");
        // A non-conforming split would leave side quads cut twice: 4 boundary triangles
        // per interior side instead of 0. Count boundary faces against the exact expectation.
        let mut edge_count = std::collections::BTreeMap::new();
        for t in &triangles {
            for i in 0..3 {
                let (a, b) = (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3]));
                *edge_count.entry((a, b)).or_insert(0) += 1;
            }
        }
        let boundary_edges = edge_count.values().filter(|&&c| c == 1).count();
        assert_eq!(boundary, surface_and_inner + 2 * 2 * boundary_edges);
    }

    #[test]
    fn the_two_sides_of_a_slit_share_no_element() {
        let (vertices, triangles, slit_lower) = slit_sheet(8, 6);
        let inward: Vec<_> = vertex_normals(&vertices, &triangles)
            .iter()
            .map(|n| -n)
            .collect();
        let shell = extrude(
            &vertices,
            &triangles,
            &inward,
            &vec![0.5; vertices.len()],
            3,
        )
        .unwrap();
        let n = vertices.len();
        // Upper side of the slit: vertices in the slit row that are not twins.
        let upper: Vec<usize> = (0..n)
            .filter(|&v| (vertices[v].y - 3.0).abs() < 1e-9 && !slit_lower.contains(&v))
            .filter(|&v| vertices[v].x > 0.5 && vertices[v].x < 7.5)
            .collect();
        let (layers, n_surface) = (shell.layers, shell.surface_vertices);
        let column = move |v: usize| (0..=layers).map(move |l| (l * n_surface + v) as u32);
        let upper_ids: Vec<u32> = upper.iter().flat_map(|&v| column(v)).collect();
        let lower_ids: Vec<u32> = slit_lower.iter().flat_map(|&v| column(v)).collect();
        for tet in &shell.mesh.tets {
            let touches_upper = tet.iter().any(|v| upper_ids.contains(v));
            let touches_lower = tet.iter().any(|v| lower_ids.contains(v));
            assert!(
                !(touches_upper && touches_lower),
                "element {tet:?} glues the slit"
            );
        }
    }

    #[test]
    fn dihedral_angles_of_a_regular_tetrahedron() {
        let p = [
            Point3::new(1.0, 1.0, 1.0),
            Point3::new(1.0, -1.0, -1.0),
            Point3::new(-1.0, 1.0, -1.0),
            Point3::new(-1.0, -1.0, 1.0),
        ];
        for a in dihedral_angles(&p) {
            assert!((a - 70.528_779_365_509_3).abs() < 1e-9);
        }
        let mesh = TetMesh::new(p.to_vec(), vec![[0, 1, 2, 3]])
            .or_else(|_| TetMesh::new(p.to_vec(), vec![[0, 2, 1, 3]]))
            .unwrap();
        assert!((quality(&mesh).min_shape_quality - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_layer_thicker_than_a_valley_is_reported_as_folded() {
        // A V-shaped valley, 1 unit wide at the top and 0.3 deep; normals point up (out).
        let vertices = vec![
            Point3::new(-0.5, 0.0, 0.0),
            Point3::new(-0.5, 1.0, 0.0),
            Point3::new(0.0, 0.0, -0.3),
            Point3::new(0.0, 1.0, -0.3),
            Point3::new(0.5, 0.0, 0.0),
            Point3::new(0.5, 1.0, 0.0),
        ];
        let triangles = vec![[0, 2, 3], [0, 3, 1], [2, 4, 5], [2, 5, 3]];
        // Inward is down into each wall, away from the valley.
        let normals = vertex_normals(&vertices, &triangles);
        assert!(normals[2].z > 0.8, "{:?}", normals[2]);
        let inward: Vec<_> = normals.iter().map(|n| -n).collect();
        assert!(extrude(&vertices, &triangles, &inward, &[0.2; 6], 2).is_ok());
        // Tissue extruded *up* out of a ridge (the same valley seen from below) crosses over.
        let ridge: Vec<[u32; 3]> = triangles.iter().map(|t| [t[0], t[2], t[1]]).collect();
        let outward = vertex_normals(&vertices, &ridge);
        let into_ridge: Vec<_> = outward.iter().map(|n| -n).collect();
        let mut thick = vec![0.05; 6];
        thick[2] = 3.0;
        thick[3] = 3.0;
        assert!(matches!(
            extrude(&vertices, &ridge, &into_ridge, &thick, 1),
            Err(ShellError::Folded(_))
        ));
    }

    #[test]
    fn bad_thickness_is_rejected() {
        let (vertices, triangles, _) = slit_sheet(2, 2);
        let inward: Vec<_> = vertex_normals(&vertices, &triangles)
            .iter()
            .map(|n| -n)
            .collect();
        let mut t = vec![0.5; vertices.len()];
        t[3] = 0.0;
        assert!(matches!(
            extrude(&vertices, &triangles, &inward, &t, 1),
            Err(ShellError::BadThickness { vertex: 3, .. })
        ));
    }
}
