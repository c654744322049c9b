//! Broad phase: a bounding-volume hierarchy over boxes given in f64, built with parry3d's
//! [`Bvh`](parry3d::partitioning::Bvh).
//!
//! parry3d stores f32 boxes; every f64 bound is rounded outwards (minima down, maxima up to
//! the next f32), so a box always contains the f64 box it stands for and the broad phase never
//! misses a pair. The exact tests are done afterwards in f64.

use nalgebra::Point3;
use parry3d::bounding_volume::Aabb;
use parry3d::math::Vector;
use parry3d::partitioning::{Bvh, BvhBuildStrategy};

/// An axis-aligned box in f64 (cm).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Box3 {
    pub min: Point3<f64>,
    pub max: Point3<f64>,
}

impl Box3 {
    /// The smallest box holding `points`, grown by `margin` on every side (an empty, inverted
    /// box for no points).
    pub fn around(points: &[Point3<f64>], margin: f64) -> Self {
        let mut min = Point3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY);
        let mut max = -min;
        for p in points {
            min = min.inf(p);
            max = max.sup(p);
        }
        let m = nalgebra::Vector3::repeat(margin);
        Self {
            min: min - m,
            max: max + m,
        }
    }

    /// The smallest box holding `points` (at least one), grown by `margin` on every side.
    pub fn around_iter(points: impl IntoIterator<Item = Point3<f64>>, margin: f64) -> Self {
        let mut it = points.into_iter();
        let first = it.next().unwrap_or_else(Point3::origin);
        let (mut min, mut max) = (first, first);
        for p in it {
            min = min.inf(&p);
            max = max.sup(&p);
        }
        let m = nalgebra::Vector3::repeat(margin);
        Self {
            min: min - m,
            max: max + m,
        }
    }

    /// This box grown by `margin` on every side.
    pub fn grown(&self, margin: f64) -> Self {
        let m = nalgebra::Vector3::repeat(margin);
        Self {
            min: self.min - m,
            max: self.max + m,
        }
    }

    /// Whether two boxes overlap (touching counts).
    pub fn overlaps(&self, other: &Box3) -> bool {
        (0..3).all(|k| self.min[k] <= other.max[k] && other.min[k] <= self.max[k])
    }

    /// The f32 box containing this one.
    fn to_parry(self) -> Aabb {
        let down = |x: f64| {
            let y = x as f32;
            if (y as f64) > x { y.next_down() } else { y }
        };
        let up = |x: f64| {
            let y = x as f32;
            if (y as f64) < x { y.next_up() } else { y }
        };
        Aabb::new(
            Vector::new(down(self.min.x), down(self.min.y), down(self.min.z)),
            Vector::new(up(self.max.x), up(self.max.y), up(self.max.z)),
        )
    }
}

/// A BVH over numbered boxes (leaf `i` is the `i`-th box given).
pub struct BoxTree {
    /// `None` for an empty set of boxes (parry's tree needs at least one leaf).
    bvh: Option<Bvh>,
}

impl BoxTree {
    /// Binned SAH build: parry's PLOC build made the contact bench's broad phase ~1.45×
    /// slower (`facesim bench contact`, interleaved runs).
    pub fn new(boxes: &[Box3]) -> Self {
        let leaves: Vec<Aabb> = boxes.iter().map(|b| b.to_parry()).collect();
        Self {
            bvh: (!leaves.is_empty()).then(|| Bvh::from_leaves(BvhBuildStrategy::Binned, &leaves)),
        }
    }

    /// Indices of the boxes that overlap `query` (touching counts), ascending, into `out`
    /// (cleared first).
    pub fn overlapping(&self, query: &Box3, out: &mut Vec<u32>) {
        out.clear();
        if let Some(bvh) = &self.bvh {
            out.extend(bvh.intersect_aabb(&query.to_parry()));
        }
        out.sort_unstable();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn rounding_outwards_contains_the_f64_box() {
        let b = Box3 {
            min: Point3::new(0.1, -0.3, 1e-9),
            max: Point3::new(0.1 + 1e-12, 0.7, 2.0 / 3.0),
        };
        let a = b.to_parry();
        for k in 0..3 {
            assert!((a.mins[k] as f64) <= b.min[k]);
            assert!((a.maxs[k] as f64) >= b.max[k]);
        }
    }

    #[test]
    fn overlap_queries_match_brute_force() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let random_box = |rng: &mut rand_chacha::ChaCha8Rng| {
            let c = Point3::new(
                rng.random_range(0.0..10.0),
                rng.random_range(0.0..10.0),
                rng.random_range(0.0..10.0),
            );
            Box3::around(&[c], rng.random_range(0.0..0.8))
        };
        let boxes: Vec<Box3> = (0..500).map(|_| random_box(&mut rng)).collect();
        let tree = BoxTree::new(&boxes);
        let mut found = Vec::new();
        for _ in 0..200 {
            let q = random_box(&mut rng);
            tree.overlapping(&q, &mut found);
            found.sort_unstable();
            let expected: Vec<u32> = (0..boxes.len() as u32)
                .filter(|&i| {
                    let b = &boxes[i as usize];
                    (0..3).all(|k| b.min[k] <= q.max[k] && q.min[k] <= b.max[k])
                })
                .collect();
            assert_eq!(found, expected);
        }
    }

    #[test]
    fn an_empty_tree_finds_nothing() {
        let mut found = vec![7];
        BoxTree::new(&[]).overlapping(&Box3::around(&[Point3::origin()], 1.0), &mut found);
        assert!(found.is_empty());
    }
}
