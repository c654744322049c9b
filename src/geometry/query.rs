//! Spatial queries on a triangle surface: the closest point (for projecting onto the artist's
//! surface) and the first hit of a ray (for measuring how much tissue lies under the skin).

use nalgebra::{Point3, Vector3};

use super::bvh::{Box3, BoxTree};
use super::distance::closest_point_on_triangle;

/// A triangle surface with a BVH over its triangles.
pub struct TriangleIndex {
    vertices: Vec<Point3<f64>>,
    triangles: Vec<[u32; 3]>,
    tree: BoxTree,
    /// Typical triangle size: where the closest-point search starts.
    start_radius: f64,
}

impl TriangleIndex {
    pub fn new(vertices: &[Point3<f64>], triangles: &[[u32; 3]]) -> Self {
        let boxes: Vec<Box3> = triangles
            .iter()
            .map(|t| Box3::around(&t.map(|v| vertices[v as usize]), 0.0))
            .collect();
        let mean_extent =
            boxes.iter().map(|b| (b.max - b.min).norm()).sum::<f64>() / boxes.len().max(1) as f64;
        Self {
            vertices: vertices.to_vec(),
            triangles: triangles.to_vec(),
            tree: BoxTree::new(&boxes),
            start_radius: mean_extent.max(1e-9),
        }
    }

    fn corners(&self, t: u32) -> [Point3<f64>; 3] {
        self.triangles[t as usize].map(|v| self.vertices[v as usize])
    }

    /// The closest point of the surface to `p`, and the triangle it lies on.
    pub fn closest_point(&self, p: &Point3<f64>) -> Option<(Point3<f64>, u32)> {
        if self.triangles.is_empty() {
            return None;
        }
        let mut radius = self.start_radius;
        let mut candidates = Vec::new();
        loop {
            self.tree
                .overlapping(&Box3::around(&[*p], radius), &mut candidates);
            if !candidates.is_empty() {
                break;
            }
            radius *= 2.0;
        }
        let best = |candidates: &[u32]| {
            candidates
                .iter()
                .map(|&t| {
                    let [a, b, c] = self.corners(t);
                    let q = closest_point_on_triangle(p, &a, &b, &c);
                    ((q - p).norm(), t, q)
                })
                .min_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)))
        };
        let (mut distance, mut triangle, mut point) = best(&candidates)?;
        if distance > radius {
            // A closer triangle may sit outside the first box: search out to this distance.
            self.tree
                .overlapping(&Box3::around(&[*p], distance), &mut candidates);
            (distance, triangle, point) = best(&candidates)?;
        }
        let _ = distance;
        Some((point, triangle))
    }

    /// The first surface hit of the ray `origin + s·direction` for `s` in `(min, max]`
    /// (`direction` unit length): distance and triangle (Möller–Trumbore, both faces).
    pub fn first_hit(
        &self,
        origin: &Point3<f64>,
        direction: &Vector3<f64>,
        min: f64,
        max: f64,
    ) -> Option<(f64, u32)> {
        let end = origin + direction * max;
        let mut candidates = Vec::new();
        self.tree
            .overlapping(&Box3::around(&[*origin, end], 0.0), &mut candidates);
        // The ray's box is loose for long rays; each candidate is tested exactly.
        candidates
            .iter()
            .filter_map(|&t| {
                let [a, b, c] = self.corners(t);
                ray_triangle(origin, direction, &a, &b, &c)
                    .filter(|&s| s > min && s <= max)
                    .map(|s| (s, t))
            })
            .min_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)))
    }
}

/// Möller–Trumbore ray–triangle intersection: the ray parameter `s` of the hit, if any.
pub fn ray_triangle(
    origin: &Point3<f64>,
    direction: &Vector3<f64>,
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
) -> Option<f64> {
    let (e1, e2) = (b - a, c - a);
    let p = direction.cross(&e2);
    let det = e1.dot(&p);
    if det.abs() <= 1e-14 * e1.norm() * e2.norm() {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - a;
    let u = s.dot(&p) * inv;
    if !(0.0..=1.0).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = direction.dot(&q) * inv;
    if v < 0.0 || u + v > 1.0 {
        return None;
    }
    Some(e2.dot(&q) * inv)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A unit sphere-ish surface: an octahedron subdivided and pushed out.
    fn sphere() -> (Vec<Point3<f64>>, Vec<[u32; 3]>) {
        let mut vertices: Vec<Point3<f64>> = [
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
        ]
        .iter()
        .map(|c| Point3::new(c[0], c[1], c[2]))
        .collect();
        let mut triangles: Vec<[u32; 3]> = vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        for _ in 0..3 {
            let mut mid = std::collections::BTreeMap::new();
            let mut out = Vec::new();
            for t in &triangles {
                let mut m = [0u32; 3];
                for i in 0..3 {
                    let (a, b) = (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3]));
                    m[i] = *mid.entry((a, b)).or_insert_with(|| {
                        let p = Point3::from(
                            (vertices[a as usize].coords + vertices[b as usize].coords).normalize(),
                        );
                        vertices.push(p);
                        vertices.len() as u32 - 1
                    });
                }
                out.extend([
                    [t[0], m[0], m[2]],
                    [m[0], t[1], m[1]],
                    [m[2], m[1], t[2]],
                    [m[0], m[1], m[2]],
                ]);
            }
            triangles = out;
        }
        (vertices, triangles)
    }

    #[test]
    fn queries_match_brute_force() {
        let (v, t) = sphere();
        let index = TriangleIndex::new(&v, &t);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..200 {
            let p = Point3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
            );
            let (q, _) = index.closest_point(&p).unwrap();
            let brute = t
                .iter()
                .map(|tri| {
                    (closest_point_on_triangle(
                        &p,
                        &v[tri[0] as usize],
                        &v[tri[1] as usize],
                        &v[tri[2] as usize],
                    ) - p)
                        .norm()
                })
                .fold(f64::INFINITY, f64::min);
            assert!(((q - p).norm() - brute).abs() < 1e-12);

            let d = Vector3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            )
            .normalize();
            let hit = index
                .first_hit(&Point3::origin(), &d, 0.0, 10.0)
                .map(|h| h.0);
            let brute = t
                .iter()
                .filter_map(|tri| {
                    ray_triangle(
                        &Point3::origin(),
                        &d,
                        &v[tri[0] as usize],
                        &v[tri[1] as usize],
                        &v[tri[2] as usize],
                    )
                })
                .filter(|&s| s > 0.0)
                .fold(f64::INFINITY, f64::min);
            assert_eq!(hit, Some(brute));
            assert!(
                brute > 0.9 && brute <= 1.0,
                "inside the sphere every ray hits at ~1: {brute}"
            );
        }
    }
}
