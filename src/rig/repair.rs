//! Repairing a rest surface that intersects itself (the rig's closed lips overlap near the
//! mouth corners): move few vertices little, smoothly, so that the surface has no
//! edge–triangle intersection and a gap of at least `d̂` where it intersected.
//!
//! Method: every vertex `i` may only *retract* along its rest normal `nᵢ` (area-weighted,
//! outward): `xᵢ = x⁰ᵢ − hᵢ·nᵢ` with a depth `hᵢ ≥ 0`. The lips face each other, so retracting
//! both opens the gap between them without sliding the skin sideways. Each iteration
//! 1. finds the violations: intersecting (edge, triangle) pairs, and pairs of non-adjacent
//!    parts closer than `d̂` at the former intersections ([`close_pairs`]);
//! 2. for each, the separation `δ` still missing along a direction `w` (from the other part
//!    towards this one): for an edge through a triangle, its endpoint behind the triangle
//!    (signed distance `s = n̂·(x − a) < 0`, `n̂` the triangle's unit normal) needs
//!    `δ = (1 + margin)·d̂ − s` along `w = n̂`; a point–triangle or edge–edge pair at distance
//!    `d` needs `δ = (1 + margin)·d̂ − d` along the line between their closest points. Each
//!    side takes half, at most `d̂` per iteration, so a vertex needs depth
//!    `hᵢ + min(δ/2, d̂) / cos`, `cos = −nᵢ·w` (vertices whose retraction does not help,
//!    `cos < 0.5`, are left to the other side). The required depths `rᵢ` only grow;
//! 3. sets `h` to the smallest "membrane" over the requirements: `hᵢ = max(rᵢ, mean_{j∼i} hⱼ)`
//!    on the vertices within `smoothing_radius` (along the surface) of a vertex with a
//!    requirement, `h = 0` elsewhere (Gauss–Seidel to convergence). The displacement then
//!    varies slowly over the mesh, so tiny triangles (the mouth corners have 0.06 mm edges
//!    against corrections of ~0.3 mm) are not folded over.
//!
//! Only vertices within `smoothing_radius` of a violation move. The iteration runs on the
//! triangles within `working_radius` of the intersections; the result is checked on the
//! whole surface.

use nalgebra::{Point3, Vector3};

use super::gap::{GapQuery, GapWitness, close_pairs, closest_point_on_triangle};
use super::intersect::{self_intersections, vertices_of};
use super::surface::{Adjacency, SurfaceTopology};
use crate::geometry::bvh::{Box3, BoxTree};

/// How to repair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RepairSettings {
    /// The gap to reach at the former intersections (cm), e.g. `0.001 ×` the face diameter.
    pub d_hat: f64,
    /// Parts within this distance along the surface are neighbours, not a gap (cm); see
    /// [`GapQuery::exclusion_radius`].
    pub exclusion_radius: f64,
    /// Corrections aim at `(1 + margin)·d̂`.
    pub margin: f64,
    /// How far (along the surface, cm) a correction spreads to smooth the displacement.
    pub smoothing_radius: f64,
    pub max_iterations: usize,
    /// Enforce the gap wherever non-adjacent parts are closer than `d̂` (for the rig's closed
    /// lips: the whole lip line), not only at the former intersections.
    pub whole_surface: bool,
    /// The iteration works on the triangles within this distance of the intersecting
    /// vertices (cm) — far more than any vertex moves; the result is checked on the whole
    /// surface.
    pub working_radius: f64,
}

impl RepairSettings {
    /// `d̂` as given, exclusion radius `4·d̂`, 10 % margin, smoothing radius `4·d̂`,
    /// 100 iterations, working radius `max(1 cm, 20·d̂)`.
    pub fn new(d_hat: f64) -> Self {
        Self {
            d_hat,
            exclusion_radius: 4.0 * d_hat,
            margin: 0.1,
            smoothing_radius: 4.0 * d_hat,
            max_iterations: 100,
            whole_surface: true,
            working_radius: (20.0 * d_hat).max(1.0),
        }
    }
}

/// What a repair did.
#[derive(Clone, Debug, PartialEq)]
pub struct RepairReport {
    /// Intersecting (edge, triangle) pairs of the whole surface before and after.
    pub intersections_before: usize,
    pub intersections_after: usize,
    /// The vertices that moved, sorted.
    pub moved_vertices: Vec<u32>,
    /// Largest vertex displacement (cm).
    pub max_displacement: f64,
    /// Largest rotation of a triangle's normal (degrees), over triangles with a moved vertex.
    /// Near 90° for the slivers that bridge the two lips at a mouth corner: opening the
    /// corner by `d̂` turns them to span the new gap (their quality improves).
    pub max_normal_rotation_deg: f64,
    /// Smallest ratio `q_after / q_before` of triangle quality `q = 4√3·area / Σ edge²`
    /// (1 for an equilateral triangle), over triangles with a moved vertex: how much the
    /// repair degrades the worst triangle (1 when nothing moved).
    pub min_quality_ratio: f64,
    /// The smallest distance between non-adjacent parts at the former intersections after
    /// the repair, if below `d̂` (cm); `None` when the gap is at least `d̂`.
    pub gap_below_d_hat: Option<f64>,
    pub iterations: usize,
}

/// Why a repair failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RepairError {
    #[error(
        "repair did not converge in {iterations} iterations: {intersections} intersecting \
         pairs and {close_pairs} pairs closer than d̂ remain"
    )]
    NotConverged {
        iterations: usize,
        intersections: usize,
        close_pairs: usize,
    },
    #[error("d̂ must be positive and finite, got {0}")]
    BadTolerance(f64),
}

/// Repairs `positions` (full rig vertex array) so that `surface` has no self-intersection and
/// a gap ≥ `d̂` at its former intersections, and with [`RepairSettings::whole_surface`]
/// wherever non-adjacent parts were closer than `d̂` (module doc). Returns the repaired
/// positions and a report; a surface with neither is returned unchanged.
pub fn repair_self_intersections(
    positions: &[Point3<f64>],
    surface: &SurfaceTopology,
    settings: &RepairSettings,
) -> Result<(Vec<Point3<f64>>, RepairReport), RepairError> {
    let d_hat = settings.d_hat;
    if !(d_hat > 0.0 && d_hat.is_finite()) {
        return Err(RepairError::BadTolerance(d_hat));
    }
    let target = (1.0 + settings.margin) * d_hat;
    // A side moves at most d̂ more per iteration (an edge crossing a triangle at a grazing
    // angle can have its far endpoint deep behind the triangle's plane).
    let max_step = d_hat;
    let query = GapQuery {
        search_radius: d_hat,
        exclusion_radius: settings.exclusion_radius,
    };
    let initial = self_intersections(positions, surface);
    let mut watched = vertices_of(surface, &initial);
    if settings.whole_surface {
        let everything = surface.vertices();
        for gap in close_pairs(positions, surface, &everything, &query)
            .into_iter()
            .filter(|g| g.distance < d_hat)
        {
            match gap.witness {
                GapWitness::PointTriangle { vertex, triangle } => {
                    watched.push(vertex);
                    watched.extend(surface_triangle(surface, triangle));
                }
                GapWitness::EdgeEdge { a, b } => watched.extend(a.into_iter().chain(b)),
            }
        }
        watched.sort_unstable();
        watched.dedup();
    }
    let part = working_part(positions, surface, &watched, settings.working_radius);
    let adjacency = part.adjacency();
    let normals = vertex_normals(positions, &part);

    let n = positions.len();
    let mut depth = vec![0.0; n];
    let mut required = vec![0.0f64; n];
    let mut region = Region::new(n);
    let mut x = positions.to_vec();
    let mut iterations = 0;
    loop {
        let pairs = self_intersections(&x, &part);
        let close: Vec<_> = close_pairs(&x, &part, &watched, &query)
            .into_iter()
            .filter(|g| g.distance < d_hat)
            .collect();
        if pairs.is_empty() && close.is_empty() {
            break;
        }
        if iterations == settings.max_iterations {
            return Err(RepairError::NotConverged {
                iterations,
                intersections: pairs.len(),
                close_pairs: close.len(),
            });
        }
        iterations += 1;

        // Required depths: each side of a violation takes half of the missing separation.
        let p = |v: u32| x[v as usize];
        let unit_normal = |t: [u32; 3]| {
            (p(t[1]) - p(t[0]))
                .cross(&(p(t[2]) - p(t[0])))
                .try_normalize(0.0)
        };
        let mut require = |v: u32, w: Vector3<f64>, half: f64| {
            let i = v as usize;
            let cos = -normals[i].dot(&w);
            if cos >= 0.5 {
                required[i] = required[i].max(depth[i] + half / cos);
                region.add_seed(v, &adjacency, positions, settings.smoothing_radius);
            }
        };
        for pair in &pairs {
            let t = surface_triangle(&part, pair.triangle);
            let Some(nt) = unit_normal(t) else { continue };
            let s = pair.edge.map(|v| nt.dot(&(p(v) - p(t[0]))));
            let (v, s) = if s[0] < s[1] {
                (pair.edge[0], s[0])
            } else {
                (pair.edge[1], s[1])
            };
            let half = ((target - s) / 2.0).min(max_step);
            require(v, nt, half);
            for u in t {
                require(u, -nt, half);
            }
        }
        for gap in &close {
            match gap.witness {
                GapWitness::PointTriangle { vertex, triangle } => {
                    let t = surface_triangle(&part, triangle);
                    let c = closest_point_on_triangle(&p(vertex), &p(t[0]), &p(t[1]), &p(t[2]));
                    let w = match (p(vertex) - c).try_normalize(1e-12) {
                        Some(w) => w,
                        None => match unit_normal(t) {
                            Some(nt) => nt,
                            None => continue,
                        },
                    };
                    let half = ((target - gap.distance) / 2.0).min(max_step);
                    require(vertex, w, half);
                    for u in t {
                        require(u, -w, half);
                    }
                }
                GapWitness::EdgeEdge { a, b } => {
                    let (ca, cb) = closest_points(p(a[0]), p(a[1]), p(b[0]), p(b[1]));
                    let Some(w) = (ca - cb).try_normalize(1e-12) else {
                        continue;
                    };
                    let half = ((target - gap.distance) / 2.0).min(max_step);
                    for v in a {
                        require(v, w, half);
                    }
                    for v in b {
                        require(v, -w, half);
                    }
                }
            }
        }

        region.solve_membrane(&adjacency, &required, &mut depth);
        for &v in &region.vertices {
            let i = v as usize;
            x[i] = positions[i] - normals[i] * depth[i];
        }
    }

    let moved_vertices: Vec<u32> = (0..n as u32)
        .filter(|&v| x[v as usize] != positions[v as usize])
        .collect();
    let max_displacement = moved_vertices
        .iter()
        .map(|&v| (x[v as usize] - positions[v as usize]).norm())
        .fold(0.0, f64::max);
    // The gap is local to the former intersections, which lie well inside the working part.
    let gap_below_d_hat = close_pairs(&x, &part, &watched, &query)
        .first()
        .map(|g| g.distance)
        .filter(|&d| d < d_hat);
    let max_normal_rotation_deg = surface
        .triangles
        .iter()
        .filter(|t| t.iter().any(|&v| x[v as usize] != positions[v as usize]))
        .map(|t| {
            let normal = |p: &[Point3<f64>]| {
                let [a, b, c] = t.map(|v| p[v as usize]);
                (b - a).cross(&(c - a))
            };
            normal(positions).angle(&normal(&x)).to_degrees()
        })
        .fold(0.0, f64::max);
    let min_quality_ratio = surface
        .triangles
        .iter()
        .filter(|t| t.iter().any(|&v| x[v as usize] != positions[v as usize]))
        .map(|t| triangle_quality(&x, *t) / triangle_quality(positions, *t))
        .fold(1.0, f64::min);
    let report = RepairReport {
        intersections_before: initial.len(),
        intersections_after: self_intersections(&x, surface).len(),
        moved_vertices,
        max_displacement,
        max_normal_rotation_deg,
        min_quality_ratio,
        gap_below_d_hat,
        iterations,
    };
    Ok((x, report))
}

/// `4√3·area / Σ edge²`: 1 for an equilateral triangle, 0 for a degenerate one.
fn triangle_quality(positions: &[Point3<f64>], t: [u32; 3]) -> f64 {
    let [a, b, c] = t.map(|v| positions[v as usize]);
    let area2 = (b - a).cross(&(c - a)).norm();
    let sum = (b - a).norm_squared() + (c - b).norm_squared() + (a - c).norm_squared();
    if sum == 0.0 {
        return 0.0;
    }
    2.0 * 3f64.sqrt() * area2 / sum
}

fn surface_triangle(surface: &SurfaceTopology, t: u32) -> [u32; 3] {
    surface.triangles[t as usize]
}

/// Area-weighted unit vertex normals `nᵢ ∝ Σ_{t ∋ i} (b − a) × (c − a)` (zero for vertices
/// not on `surface`), indexed by global vertex id.
fn vertex_normals(positions: &[Point3<f64>], surface: &SurfaceTopology) -> Vec<Vector3<f64>> {
    let mut normals = vec![Vector3::zeros(); positions.len()];
    for t in &surface.triangles {
        let [a, b, c] = t.map(|v| positions[v as usize]);
        let n = (b - a).cross(&(c - a));
        for v in t {
            normals[*v as usize] += n;
        }
    }
    for n in &mut normals {
        *n = n.try_normalize(0.0).unwrap_or_else(Vector3::zeros);
    }
    normals
}

/// The vertices allowed to move: within the smoothing radius of a seed (a vertex with a
/// required depth).
struct Region {
    inside: Vec<bool>,
    seeded: Vec<bool>,
    /// Sorted.
    vertices: Vec<u32>,
}

impl Region {
    fn new(n: usize) -> Self {
        Self {
            inside: vec![false; n],
            seeded: vec![false; n],
            vertices: Vec::new(),
        }
    }

    fn add_seed(&mut self, v: u32, adjacency: &Adjacency, rest: &[Point3<f64>], radius: f64) {
        if std::mem::replace(&mut self.seeded[v as usize], true) {
            return;
        }
        let mut added = false;
        for u in adjacency.geodesic_ball(rest, v, radius) {
            if !std::mem::replace(&mut self.inside[u as usize], true) {
                self.vertices.push(u);
                added = true;
            }
        }
        if added {
            self.vertices.sort_unstable();
        }
    }

    /// `hᵢ = max(rᵢ, mean_{j∼i} hⱼ)` on the region, `h = 0` outside (Gauss–Seidel in vertex
    /// order until no value changes by more than 1e-9 cm, at most 10,000 sweeps).
    fn solve_membrane(&self, adjacency: &Adjacency, required: &[f64], depth: &mut [f64]) {
        for _ in 0..10_000 {
            let mut change = 0.0f64;
            for &v in &self.vertices {
                let i = v as usize;
                let nb = adjacency.of(v);
                let mean = if nb.is_empty() {
                    0.0
                } else {
                    nb.iter()
                        .map(|&j| {
                            if self.inside[j as usize] {
                                depth[j as usize]
                            } else {
                                0.0
                            }
                        })
                        .sum::<f64>()
                        / nb.len() as f64
                };
                let h = required[i].max(mean);
                change = change.max((h - depth[i]).abs());
                depth[i] = h;
            }
            if change < 1e-9 {
                break;
            }
        }
    }
}

/// The triangles of `surface` with a vertex within `radius` of one of `centres`.
fn working_part(
    positions: &[Point3<f64>],
    surface: &SurfaceTopology,
    centres: &[u32],
    radius: f64,
) -> SurfaceTopology {
    if centres.is_empty() {
        return surface.subset(|_| false);
    }
    let boxes: Vec<Box3> = centres
        .iter()
        .map(|&c| Box3::around(&[positions[c as usize]], radius))
        .collect();
    let tree = BoxTree::new(&boxes);
    let mut found = Vec::new();
    let mut inside = vec![false; positions.len()];
    for v in surface.vertices() {
        let p = positions[v as usize];
        tree.overlapping(&Box3::around(&[p], 0.0), &mut found);
        inside[v as usize] = found
            .iter()
            .any(|&c| (positions[centres[c as usize] as usize] - p).norm() <= radius);
    }
    surface.subset(|i| surface.triangles[i].iter().any(|&v| inside[v as usize]))
}

/// Closest points of segments `p1q1` and `p2q2` (same clamping as
/// [`segment_segment_distance`](crate::geometry::distance::segment_segment_distance)).
fn closest_points(
    p1: Point3<f64>,
    q1: Point3<f64>,
    p2: Point3<f64>,
    q2: Point3<f64>,
) -> (Point3<f64>, Point3<f64>) {
    let (s, t) = crate::geometry::distance::segment_segment_params(&p1, &q1, &p2, &q2);
    (p1 + (q1 - p1) * s, p2 + (q2 - p2) * t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::regions::Region;
    use crate::rig::surface::EdgeSet;

    #[test]
    fn separates_two_crossing_sheets_and_leaves_a_clean_surface_alone() {
        // Two 4 × 4 sheets facing each other (lower normal +z, upper normal −z); a bump of
        // the upper sheet pokes 0.05 through the lower one.
        let mut pos = Vec::new();
        let mut tris = Vec::new();
        for (s, z) in [0.0, 0.2].into_iter().enumerate() {
            let off = (s * 25) as u32;
            for j in 0..5 {
                for i in 0..5 {
                    pos.push(Point3::new(i as f64, j as f64, z));
                }
            }
            for j in 0..4 {
                for i in 0..4 {
                    let v = off + j * 5 + i;
                    let quad = [v, v + 1, v + 6, v + 5];
                    if s == 0 {
                        tris.push(quad);
                    } else {
                        tris.push([quad[0], quad[3], quad[2], quad[1]]);
                    }
                }
            }
        }
        let faces = crate::rig::obj::Polygons::from_lists(&tris);
        let surf = SurfaceTopology::from_all_faces(&faces, EdgeSet::Triangle);
        let settings = RepairSettings::new(0.02);
        let (same, report) = repair_self_intersections(&pos, &surf, &settings).unwrap();
        assert_eq!(same, pos);
        assert_eq!(report.intersections_before, 0);
        assert!(report.moved_vertices.is_empty());

        let bump = 25 + 2 * 5 + 2; // the upper sheet's centre vertex
        pos[bump].z = -0.05;
        let (fixed, report) = repair_self_intersections(&pos, &surf, &settings).unwrap();
        assert!(report.intersections_before > 0);
        assert_eq!(report.intersections_after, 0);
        assert!(self_intersections(&fixed, &surf).is_empty());
        assert_eq!(report.gap_below_d_hat, None);
        // Only the bump's 3 × 3 neighbourhood and the lower sheet's vertices under it move.
        assert!(report.moved_vertices.contains(&(bump as u32)));
        for &v in &report.moved_vertices {
            let (i, j) = ((v % 25) % 5, (v % 25) / 5);
            assert!(i.abs_diff(2) <= 1 && j.abs_diff(2) <= 1, "{report:?}");
        }
        // The bump is pushed up, the lower sheet under it down, at least d̂ apart.
        let below = 2 * 5 + 2;
        assert!(
            fixed[bump].z > fixed[below].z + settings.d_hat,
            "{report:?}"
        );
        assert!(report.max_normal_rotation_deg < 45.0, "{report:?}");
        assert!(report.min_quality_ratio > 0.5, "{report:?}");
        assert!(report.max_displacement < 0.1, "{report:?}");
    }

    #[test]
    fn rejects_a_bad_tolerance() {
        let surf = SurfaceTopology::from_all_faces(
            &crate::rig::obj::Polygons::from_lists(&[[0, 1, 2]]),
            EdgeSet::Triangle,
        );
        let pos = [Point3::origin(); 3];
        for d in [0.0, -1.0, f64::NAN] {
            assert!(matches!(
                repair_self_intersections(&pos, &surf, &RepairSettings::new(d)),
                Err(RepairError::BadTolerance(_))
            ));
        }
    }

    #[test]
    fn repairs_the_lips_of_the_neutral_and_every_identity() {
        let rig = crate::rig::test_support::rig();
        let skin =
            SurfaceTopology::from_regions(rig.faces(), &[Region::FaceSkin], EdgeSet::Triangle);
        let around_mouth = SurfaceTopology::from_regions(
            rig.faces(),
            &[Region::FaceSkin, Region::HeadAndNeck, Region::MouthSocket],
            EdgeSet::Triangle,
        );
        let d_hat = 1e-3 * skin.diameter(rig.neutral());
        let settings = RepairSettings::new(d_hat);
        for identity in std::iter::once(None).chain((0..rig.identity_count()).map(Some)) {
            let rest = rig.base(identity);
            let t0 = std::time::Instant::now();
            let (fixed, report) = repair_self_intersections(rest, &skin, &settings).unwrap();
            eprintln!(
                "repair {identity:?} ({:.0} ms): {} → {} intersecting pairs, {} vertices moved, max {:.4} cm, normals turn ≤ {:.1}°, quality ratio ≥ {:.2}, {} iterations",
                t0.elapsed().as_secs_f64() * 1e3,
                report.intersections_before,
                report.intersections_after,
                report.moved_vertices.len(),
                report.max_displacement,
                report.max_normal_rotation_deg,
                report.min_quality_ratio,
                report.iterations
            );
            assert!(report.intersections_before > 0);
            assert_eq!(report.intersections_after, 0);
            assert_eq!(report.gap_below_d_hat, None);
            // Nowhere on the skin are non-adjacent parts closer than d̂ (the whole lip line).
            let query = GapQuery {
                search_radius: d_hat,
                exclusion_radius: settings.exclusion_radius,
            };
            let everywhere = super::super::gap::min_gap(&fixed, &skin, &skin.vertices(), &query);
            assert!(
                everywhere.as_ref().is_none_or(|g| g.distance >= d_hat),
                "{identity:?}: {:?}",
                everywhere.map(|g| g.distance)
            );
            // Skin, head and mouth socket together stay free of intersections.
            assert!(self_intersections(&fixed, &around_mouth).is_empty());
            // Only the lips move, and by less than a millimetre.
            assert!(report.max_displacement < 0.1, "{report:?}");
            assert!(report.min_quality_ratio > 0.5, "{report:?}");
            for &v in &report.moved_vertices {
                let p = rest[v as usize];
                assert!(
                    p.x.abs() < 3.0 && p.y > -4.5 && p.y < -2.5 && p.z > 9.0,
                    "vertex {v} at {p}"
                );
            }
        }
    }
}
