//! Actuations estimated from a target skin (the paper's stage-1 data): a passive simulation
//! pulls the simulation skin onto the target while the bones take the target's jaw pose,
//! then each element's actuation is its symmetric stretch `S = Rᵀ·F`.
//!
//! With `A = S` every element is at zero shape-targeting energy in the fitted configuration,
//! so simulating those actuations (same bones) lands back near the target: this is how a
//! pose of the rig becomes actuations the networks can learn.
//!
//! The passive problem, `Σₑ (w·Vₑ/2)·‖Fₑ − Rₑ‖²` plus springs `(k/2)·‖x − bone target‖²`
//! and `(k_s/2)·‖x − skin target‖²`, is solved by projective dynamics with its own factored
//! matrix (the springs on the skin change the matrix, not the simulator's).

use nalgebra::{Matrix3, Point3, SymmetricEigen, UnitQuaternion, Vector3};

use crate::geometry::query::TriangleIndex;
use crate::model::{FaceModel, Target};
use crate::rig::Region;
use crate::sim::deformation::ElementOperator;
use crate::sim::global_matrix::{FactorError, GlobalMatrix};
use crate::sim::polar::closest_rotation;
use crate::sim::{Bone, BonePose, RigidMotion, SymTensor};

/// Settings of the passive fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitSettings {
    /// Skin spring stiffness relative to a vertex's elastic stiffness (like attachments).
    pub skin_ratio: f64,
    /// Stop when `‖∇E‖` falls below this fraction of the element force scale.
    pub tolerance: f64,
    pub max_iterations: usize,
    /// Smallest principal stretch an actuation may have: elements squeezed further (or
    /// inverted) by the target are clamped here and counted.
    pub min_stretch: f64,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            skin_ratio: 100.0,
            tolerance: 1e-4,
            max_iterations: 2000,
            min_stretch: 0.3,
        }
    }
}

/// The fitted pose: actuations, where the tissue went, how close the skin got.
#[derive(Clone, Debug, PartialEq)]
pub struct FittedPose {
    pub tensors: Vec<SymTensor>,
    pub jaw: RigidMotion,
    /// Interleaved simulation positions of the fit.
    pub positions: Vec<f64>,
    /// RMS and max distance of the pulled skin vertices from their targets (cm).
    pub skin_rms: f64,
    pub skin_max: f64,
    pub iterations: usize,
    /// Relative residual reached.
    pub residual: f64,
    /// Elements whose stretch was clamped to [`FitSettings::min_stretch`].
    pub clamped: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error("the target has {got} render vertices, the face has {expected}")]
    TargetSize { expected: usize, got: usize },
    #[error("no simulation skin vertex is free to pull (every one is on a bone)")]
    NothingToPull,
    #[error("factoring the fit matrix: {0}")]
    Factor(#[from] FactorError),
    #[error("the fit diverged (non-finite positions at iteration {0})")]
    NonFinite(usize),
}

/// A skin vertex of the simulation mesh and the point of the render skin it sits on.
#[derive(Clone, Copy, Debug)]
struct SkinAnchor {
    vertex: u32,
    /// Render vertices of the triangle and barycentric weights.
    triangle: [u32; 3],
    weights: [f64; 3],
    /// The vertex's rest position minus its point on the triangle (0 on the skin, up to
    /// [`LINING_CONTACT`] off the lining), kept in every target so the rest fits exactly.
    offset: Vector3<f64>,
}

/// The fit of one face, set up once (matrix factored) and reused for every target.
pub struct ActuationFitter<'a> {
    face: &'a FaceModel,
    ops: Vec<ElementOperator>,
    element_weights: Vec<f64>,
    stiffness: Vec<f64>,
    bones: Vec<Option<Bone>>,
    anchors: Vec<SkinAnchor>,
    global: GlobalMatrix,
    settings: FitSettings,
}

impl<'a> ActuationFitter<'a> {
    pub fn new(face: &'a FaceModel, settings: FitSettings) -> Result<Self, FitError> {
        let mesh = &face.mesh;
        let n = mesh.vertex_count();
        let ops = ElementOperator::for_mesh(mesh);
        let config = crate::sim::SimConfig::default();
        let element_weights: Vec<f64> = ops
            .iter()
            .map(|o| config.stiffness * o.rest_volume)
            .collect();
        let mut diagonal = vec![0.0; n];
        for ((tet, op), wv) in mesh.tets.iter().zip(&ops).zip(&element_weights) {
            for i in 0..4 {
                diagonal[tet[i] as usize] += wv * op.grads[i].norm_squared();
            }
        }
        let mut bones = vec![None; n];
        for (&v, &b) in face
            .attachments
            .vertices
            .iter()
            .zip(&face.attachments.bones)
        {
            bones[v as usize] = Some(b);
        }
        let anchors = skin_anchors(face, &bones);
        if anchors.is_empty() {
            return Err(FitError::NothingToPull);
        }
        let mut stiffness = vec![0.0; n];
        for (v, b) in bones.iter().enumerate() {
            if b.is_some() {
                stiffness[v] = config.attachment_ratio * diagonal[v];
            }
        }
        for a in &anchors {
            stiffness[a.vertex as usize] = settings.skin_ratio * diagonal[a.vertex as usize];
        }
        let global = GlobalMatrix::factor(&mesh.tets, &ops, &element_weights, &stiffness)?;
        Ok(Self {
            face,
            ops,
            element_weights,
            stiffness,
            bones,
            anchors,
            global,
            settings,
        })
    }

    /// Simulation skin vertices pulled onto the target.
    pub fn pulled_vertices(&self) -> usize {
        self.anchors.len()
    }

    /// Fits `target`, starting from `start` (interleaved positions of a nearby earlier fit)
    /// or from rest.
    pub fn fit(&self, target: &Target, start: Option<&[f64]>) -> Result<FittedPose, FitError> {
        let face = self.face;
        if target.render.len() != face.render.rest.len() {
            return Err(FitError::TargetSize {
                expected: face.render.rest.len(),
                got: target.render.len(),
            });
        }
        let mesh = &face.mesh;
        let n = mesh.vertex_count();
        let pose = BonePose {
            skull: RigidMotion::IDENTITY,
            jaw: target.jaw.motion,
        };
        // Spring targets per vertex (zero where free).
        let mut goal = vec![0.0; 3 * n];
        for (v, b) in self.bones.iter().enumerate() {
            if let Some(b) = b {
                let p = pose.target(*b, &face.jaw_pivot, &mesh.vertices[v]);
                goal[3 * v..3 * v + 3].copy_from_slice(p.coords.as_slice());
            }
        }
        let skin_goal: Vec<Point3<f64>> = self
            .anchors
            .iter()
            .map(|a| {
                let p = (0..3).fold(a.offset, |s, k| {
                    s + target.render[a.triangle[k] as usize].coords * a.weights[k]
                });
                Point3::from(p)
            })
            .collect();
        for (a, p) in self.anchors.iter().zip(&skin_goal) {
            let v = a.vertex as usize;
            goal[3 * v..3 * v + 3].copy_from_slice(p.coords.as_slice());
        }

        let mut x: Vec<f64> = match start {
            Some(s) if s.len() == 3 * n => s.to_vec(),
            _ => mesh.vertices.iter().flat_map(|p| [p.x, p.y, p.z]).collect(),
        };
        let mut rotations = vec![UnitQuaternion::identity(); mesh.element_count()];
        let scale = self.force_scale();
        let mut scratch = self.global.scratch();
        let mut rhs = vec![0.0; 3 * n];
        let mut iterations = 0;
        let residual = loop {
            // Local step: the best rotation per element; its forces go to the right side.
            for slot in rhs.iter_mut() {
                *slot = 0.0;
            }
            let mut gradient = vec![0.0; 3 * n];
            for (e, tet) in mesh.tets.iter().enumerate() {
                let f = self.deformation_gradient(&x, e);
                rotations[e] = closest_rotation(&f, &rotations[e]);
                let r = rotations[e].to_rotation_matrix().into_inner();
                let wv = self.element_weights[e];
                for (i, &v) in tet.iter().enumerate() {
                    let g = self.ops[e].grads[i];
                    let (pull, force) = (r * g * wv, (f - r) * g * wv);
                    for c in 0..3 {
                        rhs[3 * v as usize + c] += pull[c];
                        gradient[3 * v as usize + c] += force[c];
                    }
                }
            }
            for v in 0..n {
                let k = self.stiffness[v];
                for c in 0..3 {
                    rhs[3 * v + c] += k * goal[3 * v + c];
                    gradient[3 * v + c] += k * (x[3 * v + c] - goal[3 * v + c]);
                }
            }
            let residual = gradient.iter().map(|g| g * g).sum::<f64>().sqrt() / scale;
            if !residual.is_finite() {
                return Err(FitError::NonFinite(iterations));
            }
            if residual <= self.settings.tolerance || iterations == self.settings.max_iterations {
                break residual;
            }
            // Global step: the factored matrix gives the best positions for these rotations.
            self.global.solve_in_place(&mut rhs, &mut scratch);
            std::mem::swap(&mut x, &mut rhs);
            iterations += 1;
        };

        let mut clamped = 0;
        let tensors = (0..mesh.element_count())
            .map(|e| {
                let f = self.deformation_gradient(&x, e);
                let (t, was_clamped) = stretch(&f, &rotations[e], self.settings.min_stretch);
                clamped += was_clamped as usize;
                t
            })
            .collect();
        let errors: Vec<f64> = self
            .anchors
            .iter()
            .zip(&skin_goal)
            .map(|(a, p)| {
                let v = a.vertex as usize;
                (Point3::new(x[3 * v], x[3 * v + 1], x[3 * v + 2]) - p).norm()
            })
            .collect();
        Ok(FittedPose {
            tensors,
            jaw: target.jaw.motion,
            skin_rms: (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt(),
            skin_max: errors.iter().copied().fold(0.0, f64::max),
            positions: x,
            iterations,
            residual,
            clamped,
        })
    }

    fn deformation_gradient(&self, x: &[f64], e: usize) -> Matrix3<f64> {
        let tet = &self.face.mesh.tets[e];
        self.ops[e].deformation_gradient(&tet.map(|v| {
            let i = 3 * v as usize;
            Vector3::new(x[i], x[i + 1], x[i + 2])
        }))
    }

    /// `sqrt(Σₑ Σᵢ ‖w·Vₑ·gᵢ‖²)`: the element forces' size, as in the simulator's residual.
    fn force_scale(&self) -> f64 {
        self.ops
            .iter()
            .zip(&self.element_weights)
            .map(|(op, wv)| op.grads.iter().map(|g| g.norm_squared()).sum::<f64>() * wv * wv)
            .sum::<f64>()
            .sqrt()
    }
}

/// The symmetric stretch `S = sym(Rᵀ·F)` with eigenvalues clamped to `min_stretch` (and
/// whether that was needed: inverted or crushed elements).
fn stretch(f: &Matrix3<f64>, guess: &UnitQuaternion<f64>, min_stretch: f64) -> (SymTensor, bool) {
    let r = closest_rotation(f, guess).to_rotation_matrix().into_inner();
    let s = SymTensor::from_matrix(&(r.transpose() * f)).to_matrix();
    let eigen = SymmetricEigen::new(s);
    if eigen.eigenvalues.iter().all(|&l| l >= min_stretch) {
        return (SymTensor::from_matrix(&s), false);
    }
    let clamped = eigen.eigenvalues.map(|l| l.max(min_stretch));
    let m = eigen.eigenvectors * Matrix3::from_diagonal(&clamped) * eigen.eigenvectors.transpose();
    (SymTensor::from_matrix(&m), true)
}

/// Tissue vertices this close (cm) to the mouth lining at rest sit on it: the inner side of
/// the lips and cheeks, where the tissue layer stops just short of the lining.
pub const LINING_CONTACT: f64 = 0.1;

/// The free simulation vertices the target pulls and where each sits on the render surface
/// at rest: every free skin vertex on the skin, and the free tissue vertices within
/// [`LINING_CONTACT`] of the mouth lining on the lining (so the inside of the lips rolls and
/// the cheeks' lining moves as the rig moves them, not only the outside).
fn skin_anchors(face: &FaceModel, bones: &[Option<Bone>]) -> Vec<SkinAnchor> {
    let render = &face.render;
    let triangles_of = |region: Region| -> Vec<[u32; 3]> {
        render
            .triangles
            .iter()
            .copied()
            .filter(|t| {
                t.iter().all(|&v| {
                    Region::of_vertex(render.rig_vertices[v as usize] as usize) == Some(region)
                })
            })
            .collect()
    };
    let (skin_triangles, lining_triangles) = (
        triangles_of(Region::FaceSkin),
        triangles_of(Region::MouthSocket),
    );
    let (skin, lining) = (
        TriangleIndex::new(&render.rest, &skin_triangles),
        TriangleIndex::new(&render.rest, &lining_triangles),
    );
    let mut on_skin = vec![false; face.mesh.vertex_count()];
    for t in &face.skin_triangles {
        for &v in t {
            on_skin[v as usize] = true;
        }
    }
    let anchor = |v: usize, (q, t): (Point3<f64>, u32), triangles: &[[u32; 3]]| {
        let triangle = triangles[t as usize];
        let corners = triangle.map(|i| render.rest[i as usize]);
        let weights = barycentric(&q, &corners);
        let on = (0..3).fold(Vector3::zeros(), |s, k| s + corners[k].coords * weights[k]);
        SkinAnchor {
            vertex: v as u32,
            triangle,
            weights,
            offset: face.mesh.vertices[v].coords - on,
        }
    };
    (0..face.mesh.vertex_count())
        .filter(|&v| bones[v].is_none())
        .filter_map(|v| {
            let p = face.mesh.vertices[v];
            if on_skin[v] {
                return Some(anchor(v, skin.closest_point(&p)?, &skin_triangles));
            }
            let hit = lining.closest_point(&p)?;
            ((hit.0 - p).norm() <= LINING_CONTACT).then(|| anchor(v, hit, &lining_triangles))
        })
        .collect()
}

/// Barycentric weights of a point on (or projected onto) a triangle.
fn barycentric(p: &Point3<f64>, [a, b, c]: &[Point3<f64>; 3]) -> [f64; 3] {
    let (e0, e1, ep) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (e0.dot(&e0), e0.dot(&e1), e1.dot(&e1));
    let (d20, d21) = (ep.dot(&e0), ep.dot(&e1));
    let denom = d00 * d11 - d01 * d01;
    if denom <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let v = (d11 * d20 - d01 * d21) / denom;
    let w = (d00 * d21 - d01 * d20) / denom;
    [1.0 - v - w, v, w]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::Codes;
    use crate::model::target;
    use crate::model::test_support::coarse_face;
    use crate::rig::ExpressionCode;
    use crate::rig::test_support::rig;
    use crate::sim::Quality;

    fn codes(name: &str, w: f64) -> Codes {
        Codes {
            expression: ExpressionCode::single(name, w).unwrap(),
            ..Codes::default()
        }
    }

    #[test]
    fn rest_target_fits_identity_actuations() {
        let face = coarse_face(None);
        let fitter = ActuationFitter::new(face, FitSettings::default()).unwrap();
        assert!(fitter.pulled_vertices() > 100);
        let fit = fitter
            .fit(&target(rig(), face, &Codes::default()).unwrap(), None)
            .unwrap();
        assert_eq!(fit.iterations, 0);
        for t in &fit.tensors {
            for (a, b) in t.0.iter().zip(SymTensor::IDENTITY.0) {
                assert!((a - b).abs() < 1e-9, "{t:?}");
            }
        }
    }

    #[test]
    fn simulating_fitted_actuations_reproduces_the_target() {
        let face = coarse_face(Some(2));
        let fitter = ActuationFitter::new(face, FitSettings::default()).unwrap();
        let sim = face.simulator().unwrap();
        for c in [
            codes("mouthSmile_L", 1.0),
            codes("jawOpen", 0.6),
            codes("mouthPucker", 1.0),
        ] {
            let t = target(rig(), face, &c).unwrap();
            let fit = fitter.fit(&t, None).unwrap();
            assert!(fit.residual <= 1e-4, "{c:?}: residual {}", fit.residual);
            assert!(fit.skin_rms < 0.05, "{c:?}: skin rms {} cm", fit.skin_rms);
            let bones = BonePose {
                skull: RigidMotion::IDENTITY,
                jaw: fit.jaw,
            };
            let mut state = sim.rest_state();
            sim.solve(&fit.tensors, &bones, &mut state, &Quality::Final.settings())
                .unwrap();
            let simulated = face.render_positions(state.flat_positions(), &bones);
            let fitted = face.render_positions(&fit.positions, &bones);
            let (mut moved, mut off) = (0.0f64, 0.0f64);
            for ((s, f), r) in simulated.iter().zip(&fitted).zip(&face.render.rest) {
                moved = moved.max((f - r).norm());
                off = off.max((s - f).norm());
            }
            // The pose moves the skin by centimetres; simulating its actuations lands within
            // a small fraction of that.
            assert!(
                moved > 0.3,
                "{c:?}: the target moves the skin by {moved} cm"
            );
            assert!(
                off < 0.1 * moved,
                "{c:?}: simulated {off} cm from the fit ({moved} cm)"
            );
        }
    }

    #[test]
    fn stretch_is_clamped_for_crushed_elements() {
        let f = Matrix3::from_diagonal(&Vector3::new(1.2, 0.05, 1.0));
        let (t, clamped) = stretch(&f, &UnitQuaternion::identity(), 0.2);
        assert!(clamped);
        assert!((t.0[1] - 0.2).abs() < 1e-12 && (t.0[0] - 1.2).abs() < 1e-12);
        let (t, clamped) = stretch(&Matrix3::identity(), &UnitQuaternion::identity(), 0.2);
        assert!(!clamped);
        assert_eq!(t, SymTensor::IDENTITY);
    }
}
