//! The broad phase's bounding-volume hierarchy: a layout (which primitives share a node)
//! built once from positions, boxes refit from the primitives at every candidate build, and
//! a tree-against-tree traversal that reports every pair of overlapping primitives once.
//!
//! Why not a fresh tree and one query per primitive (as [`crate::geometry::bvh::BoxTree`]
//! does): the contact surface's topology never changes and it deforms smoothly, so the
//! grouping found at the start of a solve stays good for the whole solve. Refitting is linear,
//! and the simultaneous descent of two trees visits each pair of nearby nodes once instead of
//! descending from the root for every primitive. Rebuilding parry trees and querying them per
//! primitive was most of the contact time (`facesim bench contact`).
//!
//! Boxes are f64 throughout (no rounding to f32), and the same test decides at inner nodes
//! and at primitives: a test that is monotone in the boxes (a larger box never passes less)
//! then prunes nothing it should report.

use nalgebra::Point3;
use rayon::prelude::*;

use crate::geometry::bvh::Box3;

/// Primitives per leaf at most.
const LEAF_SIZE: usize = 4;
/// Node pairs the traversal splits into before it runs them in parallel.
const PARALLEL_PAIRS: usize = 64;

/// What a node or a primitive is bounded by: at least a box (the traversal descends into the
/// node with the larger one), and the union of two bounds must bound both.
pub(crate) trait Bound: Copy + Send + Sync {
    fn union(&self, other: &Self) -> Self;
    fn extent(&self) -> f64;
}

impl Bound for Box3 {
    #[inline]
    fn union(&self, other: &Self) -> Self {
        Box3 {
            min: self.min.inf(&other.min),
            max: self.max.sup(&other.max),
        }
    }

    #[inline]
    fn extent(&self) -> f64 {
        (self.max - self.min).sum()
    }
}

/// The tree's shape: nodes in preorder (an inner node's left child follows it).
#[derive(Clone, Debug)]
pub(crate) struct Layout {
    nodes: Vec<Node>,
    /// The primitive (index into the caller's list) of every leaf slot.
    items: Vec<u32>,
}

#[derive(Clone, Copy, Debug)]
struct Node {
    /// A leaf's first slot in `items`; an inner node's right child.
    first_or_right: u32,
    /// A leaf's primitive count; 0 for an inner node.
    count: u32,
}

impl Node {
    fn is_leaf(&self) -> bool {
        self.count > 0
    }
}

impl Layout {
    /// A layout over primitives with these centres: split at the median along the longest
    /// axis of the centres' box (ties by index: deterministic) down to [`LEAF_SIZE`].
    pub(crate) fn new(centres: &[Point3<f64>]) -> Self {
        let mut items: Vec<u32> = (0..centres.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * centres.len() / LEAF_SIZE + 1);
        if !items.is_empty() {
            split(centres, &mut items, 0, &mut nodes);
        }
        Self { nodes, items }
    }

    /// Bounds of every node from the primitives' bounds (indexed like the centres).
    pub(crate) fn fit<B: Bound>(&self, items: &[B]) -> Vec<B> {
        debug_assert_eq!(items.len(), self.items.len());
        let mut bounds: Vec<B> = Vec::with_capacity(self.nodes.len());
        // Children come after their parent: fill from the back (placeholders first).
        if let Some(&first) = items.first() {
            bounds.resize(self.nodes.len(), first);
        }
        for (i, node) in self.nodes.iter().enumerate().rev() {
            bounds[i] = if node.is_leaf() {
                let slots = &self.items[node.first_or_right as usize..][..node.count as usize];
                slots[1..].iter().fold(items[slots[0] as usize], |b, &s| {
                    b.union(&items[s as usize])
                })
            } else {
                bounds[i + 1].union(&bounds[node.first_or_right as usize])
            };
        }
        bounds
    }
}

fn split(centres: &[Point3<f64>], items: &mut [u32], offset: usize, nodes: &mut Vec<Node>) {
    let at = nodes.len();
    if items.len() <= LEAF_SIZE {
        nodes.push(Node {
            first_or_right: offset as u32,
            count: items.len() as u32,
        });
        return;
    }
    nodes.push(Node {
        first_or_right: 0,
        count: 0,
    });
    let first = centres[items[0] as usize];
    let (lo, hi) = items[1..].iter().fold((first, first), |(lo, hi), &i| {
        let c = centres[i as usize];
        (lo.inf(&c), hi.sup(&c))
    });
    let axis = (hi - lo).imax();
    let mid = items.len() / 2;
    items.select_nth_unstable_by(mid, |&a, &b| {
        centres[a as usize][axis]
            .total_cmp(&centres[b as usize][axis])
            .then(a.cmp(&b))
    });
    let (left, right) = items.split_at_mut(mid);
    split(centres, left, offset, nodes);
    nodes[at].first_or_right = nodes.len() as u32;
    split(centres, right, offset + mid, nodes);
}

/// A layout with its bounds: per node and per primitive.
pub(crate) struct Fitted<'a, B> {
    pub(crate) layout: &'a Layout,
    pub(crate) nodes: &'a [B],
    pub(crate) items: &'a [B],
}

impl<B> Clone for Fitted<'_, B> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<B> Copy for Fitted<'_, B> {}

impl<B: Bound> Fitted<'_, B> {
    fn is_empty(&self) -> bool {
        self.layout.nodes.is_empty()
    }

    fn node(&self, i: u32) -> Node {
        self.layout.nodes[i as usize]
    }

    fn slots(&self, node: Node) -> &[u32] {
        &self.layout.items[node.first_or_right as usize..][..node.count as usize]
    }
}

/// Every pair `(i, j)` of primitives of `a` and `b` whose bounds pass `test`, handed to
/// `emit` (which may drop it or push something into the task's output). `same`: `a` and `b`
/// are the same tree; each unordered pair `i ≠ j` is handed over once (in some order).
/// The output's order depends on the traversal only: deterministic, but callers sort.
pub(crate) fn pairs<A: Bound, B: Bound, T: Send>(
    a: Fitted<A>,
    b: Fitted<B>,
    same: bool,
    test: &(impl Fn(&A, &B) -> bool + Sync),
    emit: &(impl Fn(u32, u32, &mut Vec<T>) + Sync),
) -> Vec<T> {
    if a.is_empty() || b.is_empty() {
        return Vec::new();
    }
    // Split the top of the descent into independent node pairs, then run them in parallel.
    let mut frontier = vec![(0u32, 0u32)];
    let mut out = Vec::new();
    while !frontier.is_empty() && frontier.len() < PARALLEL_PAIRS {
        let mut next = Vec::with_capacity(4 * frontier.len());
        for &(i, j) in &frontier {
            step(a, b, same, test, emit, i, j, &mut next, &mut out);
        }
        frontier = next;
    }
    let rest: Vec<Vec<T>> = frontier
        .par_iter()
        .map(|&(i, j)| {
            let mut found = Vec::new();
            let mut stack = vec![(i, j)];
            while let Some((i, j)) = stack.pop() {
                step(a, b, same, test, emit, i, j, &mut stack, &mut found);
            }
            found
        })
        .collect();
    out.extend(rest.into_iter().flatten());
    out
}

/// One node pair: dropped, expanded into its children's pairs (pushed to `next`), or, for
/// two leaves, their primitives' pairs tested and emitted.
#[allow(clippy::too_many_arguments)]
#[inline]
fn step<A: Bound, B: Bound, T>(
    a: Fitted<A>,
    b: Fitted<B>,
    same: bool,
    test: &impl Fn(&A, &B) -> bool,
    emit: &impl Fn(u32, u32, &mut Vec<T>),
    i: u32,
    j: u32,
    next: &mut Vec<(u32, u32)>,
    out: &mut Vec<T>,
) {
    let (ni, nj) = (a.node(i), b.node(j));
    if same && i == j {
        // A node against itself: its children against themselves and each other.
        if ni.is_leaf() {
            let slots = a.slots(ni);
            for (k, &p) in slots.iter().enumerate() {
                for &q in &slots[k + 1..] {
                    if test(&a.items[p as usize], &b.items[q as usize]) {
                        emit(p, q, out);
                    }
                }
            }
        } else {
            let (l, r) = (i + 1, ni.first_or_right);
            next.extend([(l, l), (r, r), (l, r)]);
        }
        return;
    }
    if !test(&a.nodes[i as usize], &b.nodes[j as usize]) {
        return;
    }
    match (ni.is_leaf(), nj.is_leaf()) {
        (true, true) => {
            for &p in a.slots(ni) {
                let bp = &a.items[p as usize];
                for &q in b.slots(nj) {
                    if test(bp, &b.items[q as usize]) {
                        emit(p, q, out);
                    }
                }
            }
        }
        (false, true) => next.extend([(i + 1, j), (ni.first_or_right, j)]),
        (true, false) => next.extend([(i, j + 1), (i, nj.first_or_right)]),
        (false, false) => {
            if a.nodes[i as usize].extent() >= b.nodes[j as usize].extent() {
                next.extend([(i + 1, j), (ni.first_or_right, j)]);
            } else {
                next.extend([(i, j + 1), (i, nj.first_or_right)]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn random_boxes(n: usize, seed: u64) -> Vec<Box3> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let c = Point3::new(
                    rng.random_range(0.0..4.0),
                    rng.random_range(0.0..4.0),
                    rng.random_range(0.0..1.0),
                );
                Box3::around(&[c], rng.random_range(0.0..0.3))
            })
            .collect()
    }

    fn centres(boxes: &[Box3]) -> Vec<Point3<f64>> {
        boxes
            .iter()
            .map(|b| nalgebra::center(&b.min, &b.max))
            .collect()
    }

    /// Tree against tree and a tree against itself find exactly the overlapping pairs that
    /// brute force finds, each once, also after the boxes moved away from where the layout
    /// was built (refit).
    #[test]
    fn pairs_match_brute_force_before_and_after_refit() {
        let a = random_boxes(700, 1);
        let b = random_boxes(300, 2);
        let (la, lb) = (Layout::new(&centres(&a)), Layout::new(&centres(&b)));
        let test = |p: &Box3, q: &Box3| p.overlaps(q);
        let emit = |i: u32, j: u32, out: &mut Vec<(u32, u32)>| out.push((i, j));
        // The same layouts over boxes shuffled around: a poor but valid tree.
        let moved_a = random_boxes(700, 3);
        for (a, b) in [(&a, &b), (&moved_a, &b)] {
            let (na, nb) = (la.fit(a), lb.fit(b));
            let fa = Fitted {
                layout: &la,
                nodes: &na,
                items: a,
            };
            let fb = Fitted {
                layout: &lb,
                nodes: &nb,
                items: b,
            };
            let mut got = pairs(fa, fb, false, &test, &emit);
            got.sort_unstable();
            let mut want = Vec::new();
            for (i, p) in a.iter().enumerate() {
                for (j, q) in b.iter().enumerate() {
                    if p.overlaps(q) {
                        want.push((i as u32, j as u32));
                    }
                }
            }
            assert!(want.len() > 100);
            assert_eq!(got, want);
            let mut got: Vec<(u32, u32)> = pairs(fa, fa, true, &test, &emit)
                .into_iter()
                .map(|(i, j)| (i.min(j), i.max(j)))
                .collect();
            got.sort_unstable();
            let mut want = Vec::new();
            for i in 0..a.len() {
                for j in i + 1..a.len() {
                    if a[i].overlaps(&a[j]) {
                        want.push((i as u32, j as u32));
                    }
                }
            }
            assert!(want.len() > 100);
            assert_eq!(got, want);
        }
    }

    #[test]
    fn empty_and_single_trees() {
        let one = random_boxes(1, 4);
        let (le, l1) = (Layout::new(&[]), Layout::new(&centres(&one)));
        let (ne, n1) = (le.fit::<Box3>(&[]), l1.fit(&one));
        let empty = Fitted {
            layout: &le,
            nodes: &ne,
            items: &[],
        };
        let single = Fitted {
            layout: &l1,
            nodes: &n1,
            items: &one,
        };
        let test = |p: &Box3, q: &Box3| p.overlaps(q);
        let emit = |i: u32, j: u32, out: &mut Vec<(u32, u32)>| out.push((i, j));
        assert!(pairs(empty, single, false, &test, &emit).is_empty());
        assert!(pairs(single, single, true, &test, &emit).is_empty());
        assert_eq!(pairs(single, single, false, &test, &emit), vec![(0, 0)]);
    }
}
