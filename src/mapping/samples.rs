//! The points φ is trained and measured on: surface correspondences between an identity and
//! the canonical face, and interior points of the identity's tissue.

use nalgebra::Point3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::MappingError;
use crate::geometry::TetMesh;
#[cfg(doc)]
use crate::model::Binding;
use crate::model::FaceModel;

/// Pairs (x in D_M, X in D_C) of render vertices with the same rig vertex that both faces
/// bind to their tissue (skin and lips, [`Binding::element`]: also the skin outside the tissue
/// that follows the skull, whose rest position is still a point of the material space; teeth
/// and the deep mouth ride rigidly on bones and are not part of either material space).
#[derive(Clone, Debug, PartialEq)]
pub struct Correspondences {
    /// Render-vertex index in the identity's surface.
    pub render_vertex: Vec<usize>,
    pub material: Vec<Point3<f64>>,
    pub canonical: Vec<Point3<f64>>,
}

impl Correspondences {
    pub fn between(identity: &FaceModel, canonical: &FaceModel) -> Result<Self, MappingError> {
        let canonical_of_rig = canonical_positions_by_rig_vertex(identity, canonical)?;
        let mut out = Correspondences {
            render_vertex: Vec::new(),
            material: Vec::new(),
            canonical: Vec::new(),
        };
        for (i, (&rig, binding)) in identity
            .render
            .rig_vertices
            .iter()
            .zip(&identity.render.bindings)
            .enumerate()
        {
            if let (Some(_), Some((true, target))) =
                (binding.element(), canonical_of_rig[rig as usize])
            {
                out.render_vertex.push(i);
                out.material.push(identity.render.rest[i]);
                out.canonical.push(target);
            }
        }
        if out.material.is_empty() {
            return Err(MappingError::NoCorrespondences {
                identity: identity.name.clone(),
                canonical: canonical.name.clone(),
            });
        }
        Ok(out)
    }

    pub fn len(&self) -> usize {
        self.material.len()
    }

    pub fn is_empty(&self) -> bool {
        self.material.is_empty()
    }
}

/// For every rig vertex, the canonical face's rest position of it (and whether the canonical
/// face embeds it in tissue), checking both faces come from one rig.
/// Per rig vertex: whether the canonical face embeds it, and its canonical rest position.
pub(crate) type CanonicalByRig = Vec<Option<(bool, Point3<f64>)>>;

pub(crate) fn canonical_positions_by_rig_vertex(
    identity: &FaceModel,
    canonical: &FaceModel,
) -> Result<CanonicalByRig, MappingError> {
    let max_rig = identity
        .render
        .rig_vertices
        .iter()
        .chain(&canonical.render.rig_vertices)
        .copied()
        .max()
        .unwrap_or(0) as usize;
    let mut by_rig: CanonicalByRig = vec![None; max_rig + 1];
    for ((&rig, b), p) in canonical
        .render
        .rig_vertices
        .iter()
        .zip(&canonical.render.bindings)
        .zip(&canonical.render.rest)
    {
        by_rig[rig as usize] = Some((b.element().is_some(), *p));
    }
    if canonical.identity.is_some() {
        return Err(MappingError::CanonicalIsNotNeutral(canonical.name.clone()));
    }
    Ok(by_rig)
}

/// A uniformly distributed point in tetrahedron `t` (barycentric weights from sorted
/// uniforms: the spacings of three sorted U(0,1) are Dirichlet(1,1,1,1)).
fn random_point_in(mesh: &TetMesh, t: usize, rng: &mut ChaCha8Rng) -> Point3<f64> {
    let mut u = [
        rng.random::<f64>(),
        rng.random::<f64>(),
        rng.random::<f64>(),
    ];
    u.sort_by(f64::total_cmp);
    let w = [u[0], u[1] - u[0], u[2] - u[1], 1.0 - u[2]];
    let tet = mesh.tets[t];
    let mut p = nalgebra::Vector3::zeros();
    for (k, &v) in tet.iter().enumerate() {
        p += w[k] * mesh.vertices[v as usize].coords;
    }
    Point3::from(p)
}

/// The paper's elastic-regularizer points N_e: every simulation vertex plus one uniformly
/// random point in every element (seeded).
pub fn elastic_points(mesh: &TetMesh, seed: u64) -> Vec<Point3<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut points = mesh.vertices.clone();
    points.extend((0..mesh.element_count()).map(|t| random_point_in(mesh, t, &mut rng)));
    points
}

/// `count` points distributed uniformly by volume over the tissue (element chosen with
/// probability ∝ its volume, then a uniform point in it): the statistics' interior samples.
pub fn volume_points(mesh: &TetMesh, count: usize, seed: u64) -> Vec<Point3<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let volumes = mesh.volumes();
    let mut cumulative = Vec::with_capacity(volumes.len());
    let mut total = 0.0;
    for v in &volumes {
        total += v.abs();
        cumulative.push(total);
    }
    (0..count)
        .map(|_| {
            let r = rng.random::<f64>() * total;
            let t = cumulative
                .partition_point(|&c| c <= r)
                .min(volumes.len() - 1);
            random_point_in(mesh, t, &mut rng)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::generate;

    #[test]
    fn sampled_points_lie_in_their_elements_and_repeat_with_the_seed() {
        let mesh = generate::box_mesh([4, 3, 2], nalgebra::Vector3::new(2.0, 1.5, 1.0), 0.2, 1)
            .expect("box");
        let a = elastic_points(&mesh, 7);
        assert_eq!(a.len(), mesh.vertex_count() + mesh.element_count());
        assert_eq!(a, elastic_points(&mesh, 7));
        assert_ne!(a, elastic_points(&mesh, 8));
        for (t, p) in a[mesh.vertex_count()..].iter().enumerate() {
            let w = crate::geometry::embedding::barycentric(&mesh, t, p);
            assert!(w.iter().all(|&w| w > -1e-12), "outside element {t}: {w:?}");
        }
        let b = volume_points(&mesh, 500, 3);
        assert_eq!(b.len(), 500);
        let (lo, hi) = mesh.bounds();
        assert!(
            b.iter()
                .all(|p| (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]))
        );
    }
}
