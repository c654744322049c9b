//! Isotropic surface remeshing (Botsch & Kobbelt 2004, "A remeshing approach to
//! multiresolution modeling"): split edges longer than `4/3·L`, collapse edges shorter than
//! `4/5·L`, flip edges toward valence 6 (4 on borders), relax vertices tangentially and project
//! them back onto the input surface. The result has near-equilateral triangles of edge length
//! about `L`, which is what prism layers need to become well-shaped tetrahedra. `L` may vary
//! over the surface ([`remesh_sized`]: `L(p)` at each edge's midpoint), so curved parts such as
//! the lips get small triangles and flat parts large ones.
//!
//! Borders are kept: border vertices only move along the border, border edges are only split
//! or collapsed along the border, and interior edges joining two border vertices are never
//! collapsed, so slits (the mouth) and holes (the eyes) survive at every resolution.

use std::collections::BTreeMap;

use nalgebra::{Point3, Vector3};

use super::triangles::{border_vertices, compact, gather};

/// A triangle surface being remeshed.
#[derive(Clone, Debug)]
pub struct Surface {
    pub vertices: Vec<Point3<f64>>,
    pub triangles: Vec<[u32; 3]>,
}

/// Remeshing settings.
#[derive(Clone, Copy, Debug)]
pub struct RemeshSettings {
    /// Target edge length `L` (same units as the surface).
    pub edge_length: f64,
    pub iterations: usize,
}

/// Remeshes `surface`; `project` maps a point to the closest point of the original surface
/// (border vertices are projected onto the original borders here).
pub fn remesh(
    surface: &Surface,
    settings: RemeshSettings,
    project: &dyn Fn(&Point3<f64>) -> Point3<f64>,
) -> Surface {
    remesh_sized(
        surface,
        settings.iterations,
        &|_| settings.edge_length,
        project,
    )
}

/// Remeshes `surface` toward the edge length `size(p)` (cm) around each point `p`; otherwise
/// as [`remesh`]. `size` should change slowly (by much less than 1 per unit of distance) so
/// that neighbouring triangles stay alike.
pub fn remesh_sized(
    surface: &Surface,
    iterations: usize,
    size: &dyn Fn(&Point3<f64>) -> f64,
    project: &dyn Fn(&Point3<f64>) -> Point3<f64>,
) -> Surface {
    let mut s = surface.clone();
    let borders: Vec<[Point3<f64>; 2]> = edge_map(&surface.triangles)
        .into_iter()
        .filter(|(_, t)| t.len() == 1)
        .map(|((a, b), _)| [surface.vertices[a as usize], surface.vertices[b as usize]])
        .collect();
    let project_border = |p: &Point3<f64>| closest_on_segments(&borders, p);
    let high = |p: &Point3<f64>| 4.0 / 3.0 * size(p);
    let low = |p: &Point3<f64>| 4.0 / 5.0 * size(p);
    for _ in 0..iterations {
        split_long_edges(&mut s, &high);
        collapse_short_edges(&mut s, &low, &high);
        flip_edges(&mut s);
        relax(&mut s, project, &project_border);
    }
    compact_surface(&mut s);
    s
}

/// Edge → the triangles using it (1 on a border, 2 inside).
fn edge_map(triangles: &[[u32; 3]]) -> BTreeMap<(u32, u32), Vec<usize>> {
    let mut edges: BTreeMap<(u32, u32), Vec<usize>> = BTreeMap::new();
    for (t, tri) in triangles.iter().enumerate() {
        for i in 0..3 {
            let (a, b) = (tri[i], tri[(i + 1) % 3]);
            edges.entry((a.min(b), a.max(b))).or_default().push(t);
        }
    }
    edges
}

/// Splits every edge longer than `high` at its midpoint, repeatedly, with the conforming
/// 1-, 2- and 3-edge refinement patterns of each triangle.
fn split_long_edges(s: &mut Surface, high: &dyn Fn(&Point3<f64>) -> f64) {
    for _ in 0..8 {
        let mut midpoint: BTreeMap<(u32, u32), u32> = BTreeMap::new();
        for tri in &s.triangles {
            for i in 0..3 {
                let (a, b) = (tri[i], tri[(i + 1) % 3]);
                let key = (a.min(b), a.max(b));
                let (pa, pb) = (s.vertices[a as usize], s.vertices[b as usize]);
                let m = Point3::from((pa.coords + pb.coords) * 0.5);
                if !midpoint.contains_key(&key) && (pa - pb).norm() > high(&m) {
                    midpoint.insert(key, s.vertices.len() as u32);
                    s.vertices.push(m);
                }
            }
        }
        if midpoint.is_empty() {
            return;
        }
        let mut out = Vec::with_capacity(s.triangles.len() * 2);
        for tri in &s.triangles {
            let mid = |i: usize| {
                let (a, b) = (tri[i], tri[(i + 1) % 3]);
                midpoint.get(&(a.min(b), a.max(b))).copied()
            };
            let m = [mid(0), mid(1), mid(2)];
            match m.iter().filter(|x| x.is_some()).count() {
                0 => out.push(*tri),
                1 => {
                    let i = m.iter().position(Option::is_some).unwrap_or(0);
                    let (a, b, c) = (tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]);
                    let mab = m[i].unwrap_or(a);
                    out.push([a, mab, c]);
                    out.push([mab, b, c]);
                }
                2 => {
                    // The unsplit edge is i; split edges are i+1 and i+2.
                    let i = m.iter().position(Option::is_none).unwrap_or(0);
                    let (a, b, c) = (tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]);
                    let (mbc, mca) = (m[(i + 1) % 3].unwrap_or(b), m[(i + 2) % 3].unwrap_or(c));
                    out.push([mbc, c, mca]);
                    // Cut the remaining quad a-b-mbc-mca along its shorter diagonal.
                    let p = |v: u32| s.vertices[v as usize];
                    if (p(a) - p(mbc)).norm() < (p(b) - p(mca)).norm() {
                        out.push([a, b, mbc]);
                        out.push([a, mbc, mca]);
                    } else {
                        out.push([a, b, mca]);
                        out.push([b, mbc, mca]);
                    }
                }
                _ => {
                    let (a, b, c) = (tri[0], tri[1], tri[2]);
                    let (mab, mbc, mca) = (m[0].unwrap_or(a), m[1].unwrap_or(b), m[2].unwrap_or(c));
                    out.extend([[a, mab, mca], [mab, b, mbc], [mca, mbc, c], [mab, mbc, mca]]);
                }
            }
        }
        s.triangles = out;
    }
}

/// Vertex → incident triangles.
fn incidence(s: &Surface) -> Vec<Vec<usize>> {
    let mut inc = vec![Vec::new(); s.vertices.len()];
    for (t, tri) in s.triangles.iter().enumerate() {
        for &v in tri {
            inc[v as usize].push(t);
        }
    }
    inc
}

fn normal(p: [Point3<f64>; 3]) -> Vector3<f64> {
    (p[1] - p[0]).cross(&(p[2] - p[0]))
}

/// Collapses edges shorter than `low` (at their midpoint) where the result keeps the surface
/// valid: the link condition holds, no new edge exceeds `high` (at its midpoint), no triangle
/// flips or degenerates, and borders are respected (see the module docs).
fn collapse_short_edges(
    s: &mut Surface,
    low: &dyn Fn(&Point3<f64>) -> f64,
    high: &dyn Fn(&Point3<f64>) -> f64,
) {
    let border = border_vertices(&s.triangles, s.vertices.len());
    let border_edges: std::collections::BTreeSet<(u32, u32)> = edge_map(&s.triangles)
        .into_iter()
        .filter(|(_, t)| t.len() == 1)
        .map(|(e, _)| e)
        .collect();
    let mut inc = incidence(s);
    let mut alive = vec![true; s.triangles.len()];
    let edges: Vec<(u32, u32)> = edge_map(&s.triangles).into_keys().collect();
    for (a0, b0) in edges {
        // Both ends still in use, and still an edge?
        let (a, b) = (a0 as usize, b0 as usize);
        if inc[a].is_empty() || inc[b].is_empty() {
            continue;
        }
        let shared: Vec<usize> = inc[a]
            .iter()
            .copied()
            .filter(|t| inc[b].contains(t))
            .collect();
        let middle = Point3::from((s.vertices[a].coords + s.vertices[b].coords) * 0.5);
        if shared.is_empty() || (s.vertices[a] - s.vertices[b]).norm() >= low(&middle) {
            continue;
        }
        // Decide which end survives.
        let on_border_edge = border_edges.contains(&(a0.min(b0), a0.max(b0)));
        let (keep, gone) = match (border[a], border[b]) {
            (true, true) if !on_border_edge => continue,
            (true, true) => (a, b),
            (true, false) => (a, b),
            (false, true) => (b, a),
            (false, false) => (a, b),
        };
        // Link condition: the common neighbours are exactly the opposite vertices.
        let neighbours = |v: usize| -> Vec<u32> {
            let mut n: Vec<u32> = inc[v]
                .iter()
                .flat_map(|&t| s.triangles[t])
                .filter(|&w| w as usize != v)
                .collect();
            n.sort_unstable();
            n.dedup();
            n
        };
        let (na, nb) = (neighbours(keep), neighbours(gone));
        let common = na.iter().filter(|w| nb.contains(w)).count();
        if common != shared.len() {
            continue;
        }
        // Where the surviving vertex goes: midpoint inside, stays on a border.
        let target = if border[keep] == border[gone] && !border[keep] {
            Point3::from((s.vertices[keep].coords + s.vertices[gone].coords) * 0.5)
        } else {
            s.vertices[keep]
        };
        if nb.iter().any(|&w| {
            let p = s.vertices[w as usize];
            (p - target).norm() > high(&Point3::from((p.coords + target.coords) * 0.5))
        }) {
            continue;
        }
        // No triangle of `gone` (besides the removed ones) may flip or degenerate.
        let mut ok = true;
        for &t in &inc[gone] {
            if shared.contains(&t) {
                continue;
            }
            let before = normal(s.triangles[t].map(|v| s.vertices[v as usize]));
            let after = normal(s.triangles[t].map(|v| {
                if v as usize == gone {
                    target
                } else {
                    s.vertices[v as usize]
                }
            }));
            if before.dot(&after) <= 0.2 * before.norm() * after.norm()
                || after.norm() < 1e-3 * before.norm()
            {
                ok = false;
                break;
            }
        }
        if !ok {
            continue;
        }
        for &t in &shared {
            alive[t] = false;
            for v in s.triangles[t] {
                inc[v as usize].retain(|&x| x != t);
            }
        }
        let moved: Vec<usize> = std::mem::take(&mut inc[gone]);
        for &t in &moved {
            for v in &mut s.triangles[t] {
                if *v as usize == gone {
                    *v = keep as u32;
                }
            }
            inc[keep].push(t);
        }
        s.vertices[keep] = target;
    }
    s.triangles = s
        .triangles
        .iter()
        .zip(&alive)
        .filter(|(_, a)| **a)
        .map(|(t, _)| *t)
        .collect();
}

/// Flips interior edges when that brings the four vertices' valences closer to 6 (4 on a
/// border), unless the flip would fold the surface.
fn flip_edges(s: &mut Surface) {
    let border = border_vertices(&s.triangles, s.vertices.len());
    let mut valence = vec![0i32; s.vertices.len()];
    for (a, b) in edge_map(&s.triangles).into_keys() {
        valence[a as usize] += 1;
        valence[b as usize] += 1;
    }
    let target = |v: usize| if border[v] { 4 } else { 6 };
    let edges: Vec<(u32, u32)> = edge_map(&s.triangles).into_keys().collect();
    let mut inc = incidence(s);
    for (a, b) in edges {
        let (a, b) = (a as usize, b as usize);
        let shared: Vec<usize> = inc[a]
            .iter()
            .copied()
            .filter(|t| inc[b].contains(t))
            .collect();
        if shared.len() != 2 {
            continue;
        }
        let opposite = |t: usize| {
            s.triangles[t]
                .iter()
                .copied()
                .find(|&v| v as usize != a && v as usize != b)
        };
        let (Some(c), Some(d)) = (opposite(shared[0]), opposite(shared[1])) else {
            continue;
        };
        let (c, d) = (c as usize, d as usize);
        if c == d
            || inc[c]
                .iter()
                .any(|t| inc[d].contains(t) && !shared.contains(t))
            || already_edge(&inc, s, c, d)
        {
            continue;
        }
        let dev = |v: usize, delta: i32| (valence[v] + delta - target(v)).pow(2);
        let before = dev(a, 0) + dev(b, 0) + dev(c, 0) + dev(d, 0);
        let after = dev(a, -1) + dev(b, -1) + dev(c, 1) + dev(d, 1);
        if after >= before {
            continue;
        }
        // Orient the new triangles like the old ones: t0 = (a, b, c) in its winding.
        let t0 = s.triangles[shared[0]];
        let forward = (0..3).any(|i| t0[i] as usize == a && t0[(i + 1) % 3] as usize == b);
        let (a32, b32, c32, d32) = (a as u32, b as u32, c as u32, d as u32);
        let (n0, n1) = if forward {
            ([c32, a32, d32], [d32, b32, c32])
        } else {
            ([a32, c32, d32], [b32, d32, c32])
        };
        let p = |t: [u32; 3]| t.map(|v| s.vertices[v as usize]);
        let (old0, old1) = (
            normal(p(s.triangles[shared[0]])),
            normal(p(s.triangles[shared[1]])),
        );
        let (new0, new1) = (normal(p(n0)), normal(p(n1)));
        let reference = old0 + old1;
        if new0.dot(&reference) <= 0.0
            || new1.dot(&reference) <= 0.0
            || new0.dot(&new1) <= 0.5 * new0.norm() * new1.norm()
        {
            continue;
        }
        for (slot, tri) in [(shared[0], n0), (shared[1], n1)] {
            for v in s.triangles[slot] {
                inc[v as usize].retain(|&x| x != slot);
            }
            s.triangles[slot] = tri;
            for v in tri {
                inc[v as usize].push(slot);
            }
        }
        valence[a] -= 1;
        valence[b] -= 1;
        valence[c] += 1;
        valence[d] += 1;
    }
}

fn already_edge(inc: &[Vec<usize>], s: &Surface, c: usize, d: usize) -> bool {
    inc[c].iter().any(|&t| s.triangles[t].contains(&(d as u32)))
}

/// Tangential relaxation toward the area-weighted centroid of the one-ring, then projection:
/// interior vertices onto the surface, border vertices onto the border.
fn relax(
    s: &mut Surface,
    project: &dyn Fn(&Point3<f64>) -> Point3<f64>,
    project_border: &dyn Fn(&Point3<f64>) -> Point3<f64>,
) {
    let n = s.vertices.len();
    let mut border = vec![false; n];
    let mut border_sum = vec![Vector3::zeros(); n];
    let mut border_count = vec![0usize; n];
    for ((a, b), tris) in edge_map(&s.triangles) {
        if tris.len() == 1 {
            let (a, b) = (a as usize, b as usize);
            border[a] = true;
            border[b] = true;
            border_sum[a] += s.vertices[b].coords;
            border_sum[b] += s.vertices[a].coords;
            border_count[a] += 1;
            border_count[b] += 1;
        }
    }
    let mut centroid = vec![Vector3::zeros(); n];
    let mut weight = vec![0.0; n];
    let mut normals = vec![Vector3::zeros(); n];
    for tri in &s.triangles {
        let p = tri.map(|v| s.vertices[v as usize]);
        let nrm = normal(p);
        let area = 0.5 * nrm.norm();
        let c = (p[0].coords + p[1].coords + p[2].coords) / 3.0;
        for &v in tri {
            centroid[v as usize] += c * area;
            weight[v as usize] += area;
            normals[v as usize] += nrm;
        }
    }
    let mut next = s.vertices.clone();
    for v in 0..n {
        if weight[v] == 0.0 {
            continue;
        }
        let p = s.vertices[v];
        if border[v] {
            // Slide toward the midpoint of its border neighbours, staying on the border. A
            // vertex where borders meet (more than two neighbours) is a corner: it stays.
            if border_count[v] == 2 {
                next[v] = project_border(&(p + (border_sum[v] / 2.0 - p.coords) * 0.5));
            }
            continue;
        }
        let nrm = normals[v].normalize();
        let delta = centroid[v] / weight[v] - p.coords;
        next[v] = project(&(p + (delta - nrm * nrm.dot(&delta)) * 0.5));
    }
    s.vertices = next;
}

/// The closest point to `p` on a set of segments.
fn closest_on_segments(segments: &[[Point3<f64>; 2]], p: &Point3<f64>) -> Point3<f64> {
    let mut best = (f64::INFINITY, *p);
    for [a, b] in segments {
        let ab = b - a;
        let t = ((p - a).dot(&ab) / ab.norm_squared().max(f64::MIN_POSITIVE)).clamp(0.0, 1.0);
        let q = a + ab * t;
        let d = (q - p).norm_squared();
        if d < best.0 {
            best = (d, q);
        }
    }
    best.1
}

/// Drops unreferenced vertices and renumbers.
fn compact_surface(s: &mut Surface) {
    let (triangles, kept) = compact(&s.triangles, s.vertices.len());
    s.vertices = gather(&s.vertices, &kept);
    s.triangles = triangles;
}

/// Smallest interior angle of every triangle, degrees.
pub fn min_angles(s: &Surface) -> Vec<f64> {
    s.triangles
        .iter()
        .map(|t| {
            let p = t.map(|v| s.vertices[v as usize]);
            (0..3)
                .map(|k| {
                    (p[(k + 1) % 3] - p[k])
                        .angle(&(p[(k + 2) % 3] - p[k]))
                        .to_degrees()
                })
                .fold(180.0, f64::min)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A coarse, badly shaped disc with a slit: long thin triangles fanning from the centre.
    fn fan_with_slit() -> Surface {
        let mut vertices = vec![Point3::new(0.0, 0.0, 0.0)];
        let k = 24;
        for i in 0..k {
            let a = i as f64 / k as f64 * std::f64::consts::TAU;
            vertices.push(Point3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.0));
        }
        // Leave out triangle 0 so the fan has a slit-like notch (a border through the centre).
        let triangles = (1..k).map(|i| [0, i as u32, (i % k + 1) as u32]).collect();
        Surface {
            vertices,
            triangles,
        }
    }

    #[test]
    fn remeshing_gives_well_shaped_triangles_of_the_target_size_and_keeps_borders() {
        let surface = fan_with_slit();
        let flat = |p: &Point3<f64>| Point3::new(p.x, p.y, 0.0);
        let out = remesh(
            &surface,
            RemeshSettings {
                edge_length: 0.4,
                iterations: 8,
            },
            &flat,
        );
        let mut angles = min_angles(&out);
        angles.sort_by(f64::total_cmp);
        // The notch's 15° corner forces one small angle; everything else is well shaped.
        assert!(angles[0] > 8.0, "worst angle {}", angles[0]);
        assert!(
            angles[angles.len() / 100] > 25.0,
            "1st percentile {}",
            angles[angles.len() / 100]
        );
        assert!(angles[angles.len() / 2] > 40.0);
        let edges = edge_map(&out.triangles);
        let mean: f64 = edges
            .keys()
            .map(|&(a, b)| (out.vertices[a as usize] - out.vertices[b as usize]).norm())
            .sum::<f64>()
            / edges.len() as f64;
        assert!((mean - 0.4).abs() < 0.12, "mean edge {mean}");
        // Borders stay where they were: every border vertex lies on the original outline
        // (the 23 chords of the circle and the two radii of the notch).
        let outline: Vec<[Point3<f64>; 2]> = edge_map(&surface.triangles)
            .into_iter()
            .filter(|(_, t)| t.len() == 1)
            .map(|((a, b), _)| [surface.vertices[a as usize], surface.vertices[b as usize]])
            .collect();
        for (&(a, b), t) in &edges {
            if t.len() == 1 {
                for v in [a, b] {
                    let p = out.vertices[v as usize];
                    assert!(
                        (closest_on_segments(&outline, &p) - p).norm() < 1e-12,
                        "border vertex {p} left the outline"
                    );
                }
            }
        }
        // Still one connected disc with its notch: Euler characteristic 1.
        let (v, e, f) = (
            out.vertices.len() as i64,
            edges.len() as i64,
            out.triangles.len() as i64,
        );
        assert_eq!(v - e + f, 1);
    }
}
