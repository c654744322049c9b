//! Small operations on triangle lists shared by remeshing and the importer: borders,
//! compaction of the vertices in use, and carrying per-vertex data through it.

/// Vertices on the border of a triangle surface.
pub fn border_vertices(triangles: &[[u32; 3]], n: usize) -> Vec<bool> {
    let mut edges = std::collections::BTreeMap::new();
    for t in triangles {
        for i in 0..3 {
            let (a, b) = (t[i].min(t[(i + 1) % 3]), t[i].max(t[(i + 1) % 3]));
            *edges.entry((a, b)).or_insert(0) += 1;
        }
    }
    let mut border = vec![false; n];
    for ((a, b), count) in edges {
        if count == 1 {
            border[a as usize] = true;
            border[b as usize] = true;
        }
    }
    border
}

/// How many distinct vertices the triangles use.
pub fn used_count(triangles: &[[u32; 3]]) -> usize {
    let mut v: Vec<u32> = triangles.iter().flatten().copied().collect();
    v.sort_unstable();
    v.dedup();
    v.len()
}

/// Renumbers the vertices the triangles use, in order of first use: the new triangles and,
/// for each new vertex, its old index (to carry per-vertex data along).
pub fn compact(triangles: &[[u32; 3]], vertex_count: usize) -> (Vec<[u32; 3]>, Vec<usize>) {
    let mut map = vec![u32::MAX; vertex_count];
    let mut kept = Vec::new();
    let triangles = triangles
        .iter()
        .map(|t| {
            t.map(|v| {
                if map[v as usize] == u32::MAX {
                    map[v as usize] = kept.len() as u32;
                    kept.push(v as usize);
                }
                map[v as usize]
            })
        })
        .collect();
    (triangles, kept)
}

/// Like [`compact`], but the kept vertices in the order of their old indices (a subset's
/// numbering that does not depend on the triangles' order): the new triangles and each new
/// vertex's old index.
pub fn compact_in_index_order(
    triangles: &[[u32; 3]],
    vertex_count: usize,
) -> (Vec<[u32; 3]>, Vec<u32>) {
    let mut map = vec![u32::MAX; vertex_count];
    for &v in triangles.iter().flatten() {
        map[v as usize] = 0;
    }
    let mut kept = Vec::new();
    for (i, slot) in map.iter_mut().enumerate() {
        if *slot == 0 {
            *slot = kept.len() as u32;
            kept.push(i as u32);
        }
    }
    let triangles = triangles
        .iter()
        .map(|t| t.map(|v| map[v as usize]))
        .collect();
    (triangles, kept)
}

/// `values` of the kept vertices, in their new order (see [`compact`]).
pub fn gather<T: Copy>(values: &[T], kept: &[usize]) -> Vec<T> {
    kept.iter().map(|&v| values[v]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn compaction_keeps_order_of_first_use_and_borders_are_found() {
        // Two triangles sharing edge (2, 5); vertex 0 and 4 unused.
        let triangles = [[5, 2, 3], [2, 5, 1]];
        let (t, kept) = compact(&triangles, 6);
        assert_eq!(kept, vec![5, 2, 3, 1]);
        assert_eq!(t, vec![[0, 1, 2], [1, 0, 3]]);
        let (by_index, kept_by_index) = compact_in_index_order(&triangles, 6);
        assert_eq!(kept_by_index, vec![1, 2, 3, 5]);
        assert_eq!(by_index, vec![[3, 1, 2], [1, 3, 0]]);
        assert_eq!(
            gather(&[10, 11, 12, 13, 14, 15], &kept),
            vec![15, 12, 13, 11]
        );
        assert_eq!(used_count(&triangles), 4);
        // Every used vertex is on the border of two triangles; the unused ones are not.
        assert_eq!(
            border_vertices(&triangles, 6),
            vec![false, true, true, true, false, true]
        );
    }
}
