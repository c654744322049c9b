//! Broad phase: axis-aligned boxes in f64 and a bounding-volume hierarchy over them, built
//! with parry3d's [`Bvh`](parry3d::partitioning::Bvh).
//!
//! parry3d stores f32 boxes; every f64 bound is rounded outwards (minima down, maxima up to
//! the next f32), so an f32 box always contains the f64 box it stands for and the broad phase
//! never misses a pair. Overlap counts touching boxes. The exact tests come afterwards in f64.

use parry3d::bounding_volume::Aabb as ParryAabb;
use parry3d::math::Vector as ParryVector;
use parry3d::partitioning::{Bvh, BvhBuildStrategy};

use super::math::Vec3;

/// An axis-aligned box in f64 (cm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Aabb {
    /// The smallest box holding `points`, grown by `margin ≥ 0` on every side.
    pub fn around(points: &[Vec3], margin: f64) -> Self {
        let mut min = points[0];
        let mut max = points[0];
        for p in &points[1..] {
            min = min.inf(p);
            max = max.sup(p);
        }
        let m = Vec3::repeat(margin);
        Self {
            min: min - m,
            max: max + m,
        }
    }

    /// The smallest box holding the points of a non-empty iterator, grown by `margin`.
    pub fn around_iter(points: impl IntoIterator<Item = Vec3>, margin: f64) -> Self {
        let mut it = points.into_iter();
        let first = it.next().unwrap_or_else(Vec3::zeros);
        let (mut min, mut max) = (first, first);
        for p in it {
            min = min.inf(&p);
            max = max.sup(&p);
        }
        let m = Vec3::repeat(margin);
        Self {
            min: min - m,
            max: max + m,
        }
    }

    /// Whether the boxes overlap or touch.
    pub fn overlaps(&self, other: &Aabb) -> bool {
        (0..3).all(|k| self.min[k] <= other.max[k] && other.min[k] <= self.max[k])
    }

    /// The f32 box containing this one.
    fn to_parry(self) -> ParryAabb {
        let down = |x: f64| {
            let y = x as f32;
            if (y as f64) > x { y.next_down() } else { y }
        };
        let up = |x: f64| {
            let y = x as f32;
            if (y as f64) < x { y.next_up() } else { y }
        };
        ParryAabb::new(
            ParryVector::new(down(self.min.x), down(self.min.y), down(self.min.z)),
            ParryVector::new(up(self.max.x), up(self.max.y), up(self.max.z)),
        )
    }
}

/// A BVH over numbered boxes (leaf `i` is the `i`-th box given).
pub struct BoxTree {
    bvh: Option<Bvh>,
}

impl BoxTree {
    /// Builds the tree (binned SAH). Building is deterministic for the same boxes.
    pub fn new(boxes: &[Aabb]) -> Self {
        if boxes.is_empty() {
            return Self { bvh: None };
        }
        let leaves: Vec<ParryAabb> = boxes.iter().map(|b| b.to_parry()).collect();
        Self {
            bvh: Some(Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves)),
        }
    }

    /// Appends to `out` the indices of the boxes that may overlap `query` (a superset of the
    /// exact f64 overlaps, never missing one), sorted ascending.
    pub fn overlapping(&self, query: &Aabb, out: &mut Vec<u32>) {
        let start = out.len();
        if let Some(bvh) = &self.bvh {
            let q = query.to_parry();
            out.extend(bvh.intersect_aabb(&q));
        }
        out[start..].sort_unstable();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn rounding_outwards_contains_the_f64_box() {
        let b = Aabb {
            min: Vec3::new(0.1, -0.3, 1e-9),
            max: Vec3::new(0.1 + 1e-12, 0.7, 2.0 / 3.0),
        };
        let a = b.to_parry();
        for k in 0..3 {
            assert!((a.mins[k] as f64) <= b.min[k]);
            assert!((a.maxs[k] as f64) >= b.max[k]);
        }
    }

    #[test]
    fn queries_find_every_overlap() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let random_box = |rng: &mut rand_chacha::ChaCha8Rng| {
            let c = Vec3::new(
                rng.random_range(0.0..5.0),
                rng.random_range(0.0..5.0),
                rng.random_range(0.0..5.0),
            );
            Aabb::around(&[c], rng.random_range(0.0..0.4))
        };
        let boxes: Vec<Aabb> = (0..400).map(|_| random_box(&mut rng)).collect();
        let tree = BoxTree::new(&boxes);
        let mut found = Vec::new();
        for _ in 0..200 {
            let q = random_box(&mut rng);
            found.clear();
            tree.overlapping(&q, &mut found);
            let exact: Vec<u32> = (0..boxes.len() as u32)
                .filter(|&i| boxes[i as usize].overlaps(&q))
                .collect();
            // Superset (f32 rounding may add touching neighbours), never missing one.
            assert!(exact.iter().all(|i| found.contains(i)));
            assert!(found.windows(2).all(|w| w[0] < w[1]));
        }
        // Touching boxes count as overlapping.
        let t = BoxTree::new(&[Aabb::around(&[Vec3::zeros()], 1.0)]);
        found.clear();
        t.overlapping(&Aabb::around(&[Vec3::new(2.0, 0.0, 0.0)], 1.0), &mut found);
        assert_eq!(found, vec![0]);
        found.clear();
        BoxTree::new(&[]).overlapping(&q_unit(), &mut found);
        assert!(found.is_empty());
    }

    fn q_unit() -> Aabb {
        Aabb::around(&[Vec3::zeros()], 1.0)
    }
}
