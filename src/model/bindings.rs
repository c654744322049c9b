//! The render surface's bindings: how every vertex of the artist's full-resolution surface
//! follows the simulation, placed on the right side of the mouth slit and then chosen and
//! checked against the rig's own shapes.
//!
//! 1. **Placed** ([`render_surface`]): skin and mouth lining are embedded in the nearest
//!    element *on their side of the mouth slit*; the teeth ride on their bones, the gums,
//!    tongue and deep lining between the bones as the rig moves them
//!    ([`BoneMotion::bone_binding`]); skin outside the tissue that the rig never moves blends
//!    onto the skull with its distance ([`skin_share`]). The side is the rig's own: the share
//!    of the jaw's motion a vertex follows ([`BoneMotion::jaw_share`]), for the render vertex
//!    and for the skin each element was extruded from. The closed lips touch across the slit,
//!    so the Euclidean nearest element of an inner lip vertex is often the other lip's; with
//!    the side, the lower lip (share ≈ 1) never rides on the upper lip's tissue (≈ 0).
//! 2. **Chosen by the rig** ([`fit_to_rig`]): the tissue is fitted to every basis shape at
//!    weight 1 (the passive fit of [`super::fit`], which the actuation basis reproduces), and
//!    each moving skin and lining vertex takes, among the elements near it on its side (and,
//!    for the lining, the bones), the binding whose positions over those fits come closest to
//!    the rig's: the smallest largest distance over the shapes. Coarse elements extrapolated
//!    to a vertex outside them, or stretched across a mouth corner, reproduce the shapes
//!    badly; the choice is measured, not guessed. The deep lining that rests on a gum
//!    ([`ON_GUM`]) has no choice: it rides on the gum's bone, so that the pair keeps its rest
//!    distance through every jaw move; the bones carry the rest of it toward the nearest gum
//!    by at most half its gap ([`BoneMotion::bone_binding_near`]). Nor has the floor of the
//!    mouth (deep lining on the tongue's side of the lower teeth, `NearGum::lingual`): the
//!    tissue lies outside the teeth, and carried by it with barycentric levers up to 4 the
//!    lining behind the lower incisors swept through them in a lip press (the rig's shapes
//!    move it there); the bones carry it. What remains is the
//!    importer's report ([`BindingReport`]), and a skin vertex still off by more than
//!    [`BindingSettings::max_skin_error`] is a build error.

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::bone_motion::BoneMotion;
use super::face::{Binding, FaceModel, Part, RenderSurface, UvLayout};
use super::fit::{ActuationFitter, FitError, FitSettings};
use super::report::BindingReport;
use super::targets::{TargetError, shape_target};
use crate::geometry::bvh::Box3;
use crate::geometry::embedding::{Embedding, barycentric, distance_to_tet, element_tree};
use crate::geometry::shell::Shell;
use crate::rig::regions::lip_line;
use crate::rig::style::STYLE_SHAPES;
use crate::rig::surface::{EdgeSet, SurfaceTopology};
use crate::rig::{ExpressionCode, FaceRig, Region};
use crate::sim::{Bone, BonePose};

/// Knobs of the bindings (cm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BindingSettings {
    /// Mouth-lining vertices farther than this from the tissue follow the bones instead; skin
    /// that rides on the skull starts to blend onto it here.
    pub embed_distance: f64,
    /// Skin that rides on the skull and lies this far or farther outside the tissue follows
    /// the skull alone; between `embed_distance` and this it blends from the tissue onto it
    /// (smoothstep, [`Binding::Blended`]).
    pub skin_rigid_distance: f64,
    /// Largest difference of jaw share between a render vertex and the tissue it is
    /// embedded in (see the module doc).
    pub side_tolerance: f64,
    /// Elements whose box lies within this distance of a vertex (and on its side) are
    /// candidates for its binding.
    pub candidate_reach: f64,
    /// A moving skin vertex whose chosen binding misses one of the rig's basis shapes by
    /// more than this is a build error.
    pub max_skin_error: f64,
}

impl Default for BindingSettings {
    fn default() -> Self {
        Self {
            embed_distance: 0.3,
            skin_rigid_distance: 1.0,
            side_tolerance: 0.4,
            candidate_reach: 0.5,
            max_skin_error: 0.5,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum BindingError {
    #[error("fitting the tissue to the rig's shapes: {0}")]
    Fit(#[from] FitError),
    #[error("the rig's shapes: {0}")]
    Target(#[from] TargetError),
    #[error(
        "the render skin does not follow the rig: rig vertex {vertex} is {error_mm:.1} mm from \
         its place in '{shape}' with the best binding the tissue offers (at most {limit_mm:.1} mm \
         allowed); the tissue does not reach it: a finer lip_edge_length or edge_length may"
    )]
    SkinOff {
        vertex: u32,
        shape: String,
        error_mm: f64,
        limit_mm: f64,
    },
}

/// Mouth lining within this distance (cm, at rest) of the lip line is always carried by the
/// tissue, never by the bones: the lips roll and press it (the default
/// `FaceContactSettings::lip_reach`), and a lining vertex the bones carry there would hold its
/// tissue neighbours' edges against the teeth.
pub const TISSUE_LINING_REACH: f64 = 1.5;

/// Mouth lining deeper than [`TISSUE_LINING_REACH`] that rests within this distance (cm, at
/// rest) of a gum rides rigidly on that gum's bone. The rig lays part of its deep lining on the
/// gums, closer than 3·d̂ of contact (d̂ = 0.029 cm). Carried by the tissue, whose motion
/// follows the jaw's only approximately, that lining met its gum at every jaw move: with the
/// lining to 3 cm in contact, the smile's jaw opening could not be staged (frame 54 ran for
/// 70 minutes). On the gum's bone the pair keeps its rest distance exactly.
pub const ON_GUM: f64 = 0.1;

/// Where a render vertex of the deep mouth lining lies against the nearest gum, at rest.
#[derive(Clone, Copy)]
struct NearGum {
    /// The bone of those teeth (with their gums).
    bone: Bone,
    /// The vertex's distance from the gum (cm).
    distance: f64,
    /// The least distance of the vertex and its neighbours along the surface (what its edges
    /// may sweep through, cm).
    ring: f64,
    /// From the gum's closest point to the vertex (unit).
    away: Vector3<f64>,
    /// Whether the vertex lies on the tongue's side of its teeth (inside the dental arch).
    lingual: bool,
}

/// Where every render vertex of the deep mouth lining lies against the nearest gum; `None` for
/// every other vertex.
fn gum_under(render: &RenderSurface, near_lips: &[bool]) -> Vec<Option<NearGum>> {
    use crate::geometry::query::TriangleIndex;
    let region: Vec<Option<Region>> = render
        .rig_vertices
        .iter()
        .map(|&v| Region::of_vertex(v as usize))
        .collect();
    let teeth = |r: Region| {
        let triangles: Vec<[u32; 3]> = render
            .triangles
            .iter()
            .filter(|t| t.iter().all(|&v| region[v as usize] == Some(r)))
            .copied()
            .collect();
        TriangleIndex::new(&render.rest, &triangles)
    };
    // Each arch's centre in the horizontal plane (x across, z forward): a tooth's outward
    // side faces away from it.
    let centre = |r: Region| {
        let points: Vec<&Point3<f64>> = render
            .rest
            .iter()
            .zip(&region)
            .filter(|(_, g)| **g == Some(r))
            .map(|(p, _)| p)
            .collect();
        points.iter().map(|p| p.coords).sum::<Vector3<f64>>() / points.len().max(1) as f64
    };
    let gums = [
        (
            Bone::Skull,
            teeth(Region::UpperTeeth),
            centre(Region::UpperTeeth),
        ),
        (
            Bone::Jaw,
            teeth(Region::LowerTeeth),
            centre(Region::LowerTeeth),
        ),
    ];
    let mut near: Vec<Option<NearGum>> = (0..render.rest.len())
        .map(|i| {
            if region[i] != Some(Region::MouthSocket) || near_lips[i] {
                return None;
            }
            let p = render.rest[i];
            gums.iter()
                .filter_map(|(bone, index, centre)| {
                    let (q, _) = index.closest_point(&p)?;
                    let distance = (p - q).norm();
                    let outward = Vector3::new(q.x - centre.x, 0.0, q.z - centre.z);
                    Some(NearGum {
                        bone: *bone,
                        distance,
                        ring: distance,
                        away: (p - q) / distance.max(1e-12),
                        lingual: (p - q).dot(&outward) < 0.0,
                    })
                })
                .min_by(|a, b| a.distance.total_cmp(&b.distance))
        })
        .collect();
    let distance: Vec<Option<(Bone, f64)>> = near
        .iter()
        .map(|n| n.map(|n| (n.bone, n.distance)))
        .collect();
    for t in &render.triangles {
        for &a in t {
            for &b in t {
                if let (Some(n), Some((bone, d))) = (&mut near[a as usize], distance[b as usize])
                    && bone == n.bone
                {
                    n.ring = n.ring.min(d);
                }
            }
        }
    }
    near
}

/// Distance from `p` to the nearest of `points` (infinite if there are none).
pub(super) fn distance_to(points: &[Point3<f64>], p: &Point3<f64>) -> f64 {
    points
        .iter()
        .map(|q| (q - p).norm_squared())
        .fold(f64::INFINITY, f64::min)
        .sqrt()
}

/// Which render vertices are mouth lining within [`TISSUE_LINING_REACH`] of the lip line.
fn lining_near_the_lips(rig: &FaceRig, render: &RenderSurface) -> Vec<bool> {
    let line: Vec<Point3<f64>> = lip_line(rig.faces())
        .iter()
        .filter_map(|&v| render.rig_vertices.binary_search(&(v as u32)).ok())
        .map(|i| render.rest[i])
        .collect();
    render
        .rig_vertices
        .iter()
        .zip(&render.rest)
        .map(|(&v, p)| {
            Region::of_vertex(v as usize) == Some(Region::MouthSocket)
                && distance_to(&line, p) <= TISSUE_LINING_REACH
        })
        .collect()
}

/// The share of the tissue in the motion of skin that rides on the skull, by its distance
/// outside the tissue: 1 up to `embed_distance`, then a smoothstep down to 0 at
/// `skin_rigid_distance` (no kink at either end, so no visible seam), 0 beyond.
pub fn skin_share(distance: f64, settings: &BindingSettings) -> f64 {
    let (near, far) = (settings.embed_distance, settings.skin_rigid_distance);
    if distance <= near {
        1.0
    } else if distance >= far {
        0.0
    } else {
        let t = (distance - near) / (far - near);
        1.0 - t * t * (3.0 - 2.0 * t)
    }
}

/// The shapes the bindings are chosen on: the expression code's and those the styles add
/// (what the actuation basis fits), each at weight 1, but for [`UNPHYSICAL_SHAPES`].
pub fn binding_shapes() -> Vec<&'static str> {
    ExpressionCode::NAMES
        .iter()
        .chain(STYLE_SHAPES.iter())
        .copied()
        .filter(|name| !UNPHYSICAL_SHAPES.contains(name))
        .collect()
}

/// Shapes the tissue cannot take: mouthClose alone presses the lips through each other (745
/// crossing pairs on the template), so its fit crushes the lips' tissue and says nothing of
/// how the surface rides on it. Contact decides that shape.
pub const UNPHYSICAL_SHAPES: [&str; 1] = ["mouthClose"];

/// The jaw share of every element: the mean over its vertices of the share of the rig vertex
/// under their column's skin vertex (`origin`, per layer-0 vertex).
pub(super) fn element_shares(shell: &Shell, origin: &[usize], motion: &BoneMotion) -> Vec<f64> {
    shell
        .mesh
        .tets
        .iter()
        .map(|t| {
            t.iter()
                .map(|&v| motion.jaw_share[origin[v as usize % shell.surface_vertices]])
                .sum::<f64>()
                / 4.0
        })
        .collect()
}

/// The render surface placed on the tissue and bones (step 1 of the module doc).
pub(super) fn render_surface(
    rig: &FaceRig,
    rest: &[Point3<f64>],
    shell: &Shell,
    element_share: &[f64],
    motion: &BoneMotion,
    settings: &BindingSettings,
) -> RenderSurface {
    let surface = SurfaceTopology::from_regions(rig.faces(), &Region::ALL, EdgeSet::Triangle);
    let rig_vertices = surface.vertices();
    let mut local = vec![u32::MAX; rest.len()];
    for (i, &v) in rig_vertices.iter().enumerate() {
        local[v as usize] = i as u32;
    }
    let points: Vec<Point3<f64>> = rig_vertices.iter().map(|&v| rest[v as usize]).collect();
    let embedding = Embedding::among(&shell.mesh, &points, &|i, e| {
        (motion.jaw_share[rig_vertices[i] as usize] - element_share[e as usize]).abs()
            <= settings.side_tolerance
    });
    let mut surface_so_far = RenderSurface {
        rig_vertices: rig_vertices.clone(),
        rest: points.clone(),
        triangles: Vec::new(),
        bindings: Vec::new(),
        uv: uv_layout(rig, &surface),
        parts: parts(rig, &surface),
    };
    let near_lips = lining_near_the_lips(rig, &surface_so_far);
    let bindings = rig_vertices
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let v = v as usize;
            let (element, weights) = (embedding.elements[i], embedding.weights[i]);
            let distance = embedding.outside_distance[i];
            match Region::of_vertex(v) {
                Some(Region::FaceSkin) if motion.on_skull(v) => {
                    let embedded = skin_share(distance, settings);
                    if embedded == 1.0 {
                        Binding::Embedded { element, weights }
                    } else {
                        Binding::Blended {
                            element,
                            weights,
                            bone: Bone::Skull,
                            embedded,
                        }
                    }
                }
                Some(Region::FaceSkin) => Binding::Embedded { element, weights },
                Some(Region::MouthSocket)
                    if near_lips[i] || distance <= settings.embed_distance =>
                {
                    Binding::Embedded { element, weights }
                }
                // The back of the head, the eye sockets and the eyes ride on the skull (the
                // rig's mouth shapes move the neck under the chin by at most 2.8 mm, the lower
                // lashes by 0.8 mm; the face skin they join still follows the tissue).
                Some(
                    Region::HeadAndNeck
                    | Region::EyeSocketLeft
                    | Region::EyeSocketRight
                    | Region::Eyes,
                ) => Binding::Rigid(Bone::Skull),
                Some(Region::UpperTeeth) => Binding::Rigid(Bone::Skull),
                Some(Region::LowerTeeth) => Binding::Rigid(Bone::Jaw),
                _ => motion.bone_binding(v),
            }
        })
        .collect();
    surface_so_far.triangles = surface
        .triangles
        .iter()
        .map(|t| t.map(|v| local[v as usize]))
        .collect();
    surface_so_far.bindings = bindings;
    surface_so_far
}

/// The rig's texture coordinates on `surface`'s triangles (corner by corner, through each
/// triangle's source polygon), with the coordinates no triangle uses left out; `None` when
/// the rig has none.
fn uv_layout(rig: &FaceRig, surface: &SurfaceTopology) -> Option<UvLayout> {
    let mesh = rig.mesh();
    let corner_uvs = mesh.corner_uvs.as_ref()?;
    let mut compact = vec![u32::MAX; mesh.uvs.len()];
    let mut coords = Vec::new();
    let triangles = surface
        .triangles
        .iter()
        .zip(&surface.source_faces)
        .map(|(t, &f)| {
            let polygon = mesh.faces.get(f as usize);
            let first = mesh.faces.offset(f as usize);
            t.map(|v| {
                let corner = polygon
                    .iter()
                    .position(|&c| c == v)
                    .expect("a surface triangle's corners are corners of its source polygon");
                let uv = corner_uvs[first + corner] as usize;
                if compact[uv] == u32::MAX {
                    compact[uv] = coords.len() as u32;
                    coords.push(mesh.uvs[uv].map(|c| c as f32));
                }
                compact[uv]
            })
        })
        .collect();
    Some(UvLayout { coords, triangles })
}

/// The rig's material groups as runs of `surface`'s triangles (each triangle takes its
/// source polygon's group; the rig lists its groups in polygon order, so each is one run).
fn parts(rig: &FaceRig, surface: &SurfaceTopology) -> Vec<Part> {
    let groups = &rig.mesh().material_groups;
    let mut parts: Vec<Part> = Vec::new();
    for (t, &f) in surface.source_faces.iter().enumerate() {
        let group = groups.partition_point(|g| g.first_face <= f as usize);
        let name = match group {
            0 => "default",
            g => groups[g - 1].name.as_str(),
        };
        match parts.last_mut() {
            Some(part) if part.name == name => part.triangles.end = t as u32 + 1,
            _ => parts.push(Part {
                name: name.to_string(),
                triangles: t as u32..t as u32 + 1,
            }),
        }
    }
    parts
}

/// The tissue fitted to each binding shape, and the rig's render surface there.
struct ShapeFits {
    names: Vec<&'static str>,
    positions: Vec<Vec<f64>>,
    bones: Vec<BonePose>,
    targets: Vec<Vec<Point3<f64>>>,
}

impl ShapeFits {
    fn new(rig: &FaceRig, face: &FaceModel) -> Result<Self, BindingError> {
        let fitter = ActuationFitter::new(face, FitSettings::default())?;
        let mut fits = Self {
            names: binding_shapes(),
            positions: Vec::new(),
            bones: Vec::new(),
            targets: Vec::new(),
        };
        for name in &fits.names {
            let target = shape_target(rig, face, &[(name, 1.0)])?;
            let fit = fitter.fit(&target, None)?;
            fits.positions.push(fit.positions);
            fits.bones.push(BonePose {
                jaw: fit.jaw,
                ..BonePose::default()
            });
            fits.targets.push(target.render);
        }
        Ok(fits)
    }

    /// Render vertex `i`'s distance from the rig in each shape with `binding` (cm).
    fn errors(&self, face: &FaceModel, i: usize, binding: &Binding) -> Vec<f64> {
        let rest = &face.render.rest[i];
        (0..self.names.len())
            .map(|k| {
                (face.bound_position(binding, rest, &self.positions[k], &self.bones[k])
                    - self.targets[k][i])
                    .norm()
            })
            .collect()
    }
}

/// Rebinds every moving skin and lining vertex of `face` to what reproduces the rig's basis
/// shapes best, and reports how well (step 2 of the module doc).
pub(super) fn fit_to_rig(
    face: &mut FaceModel,
    rig: &FaceRig,
    element_share: &[f64],
    motion: &BoneMotion,
    settings: &BindingSettings,
) -> Result<BindingReport, BindingError> {
    use rayon::prelude::*;
    let fits = ShapeFits::new(rig, face)?;
    let mesh = &face.mesh;
    let tree = element_tree(mesh);
    let render = &face.render;
    let near_lips = lining_near_the_lips(rig, render);
    let on_gum = gum_under(render, &near_lips);
    let chosen: Vec<Option<(Binding, Vec<f64>)>> = (0..render.rest.len())
        .into_par_iter()
        .map(|i| {
            let v = render.rig_vertices[i] as usize;
            let lining = match Region::of_vertex(v) {
                Some(Region::FaceSkin) if !motion.on_skull(v) => false,
                Some(Region::MouthSocket) => true,
                _ => return None,
            };
            if let Some(gum) = on_gum[i].filter(|gum| gum.distance <= ON_GUM) {
                let binding = Binding::Rigid(gum.bone);
                return Some((binding, fits.errors(face, i, &binding)));
            }
            let p = render.rest[i];
            let current = render.bindings[i];
            let mut candidates = Vec::new();
            if lining && !near_lips[i] {
                let binding = match on_gum[i] {
                    Some(gum) => motion.bone_binding_near(v, gum.bone, gum.ring, &gum.away),
                    None => motion.bone_binding(v),
                };
                // The floor of the mouth lies inside the lower arch, where no tissue reaches:
                // the bones carry it (see the module doc).
                if on_gum[i].is_some_and(|gum| gum.bone == Bone::Jaw && gum.lingual) {
                    return Some((binding, fits.errors(face, i, &binding)));
                }
                candidates.push(binding);
            }
            if !lining || current.element().is_some() {
                candidates.push(current);
            }
            let mut near = Vec::new();
            tree.overlapping(&Box3::around(&[p], settings.candidate_reach), &mut near);
            near.sort_unstable();
            let share = motion.jaw_share[v];
            for e in near {
                if (share - element_share[e as usize]).abs() > settings.side_tolerance
                    || distance_to_tet(mesh, e as usize, &p) > settings.candidate_reach
                {
                    continue;
                }
                let weights = barycentric(mesh, e as usize, &p);
                if weights.iter().map(|w| w.abs()).sum::<f64>() <= MAX_WEIGHT_SUM {
                    candidates.push(Binding::Embedded {
                        element: e,
                        weights,
                    });
                }
            }
            let worst = |e: &[f64]| e.iter().copied().fold(0.0, f64::max);
            candidates
                .iter()
                .map(|b| (*b, fits.errors(face, i, b)))
                .min_by(|a, b| worst(&a.1).total_cmp(&worst(&b.1)))
        })
        .collect();
    let mut report = BindingReport {
        shapes: fits.names.len(),
        ..BindingReport::default()
    };
    let mut skin_worst = Vec::new();
    let mut lining_sum = vec![0.0; fits.names.len()];
    let mut lining_count = 0usize;
    for (i, c) in chosen.into_iter().enumerate() {
        let Some((binding, errors)) = c else {
            continue;
        };
        report.rebound_vertices += usize::from(binding != face.render.bindings[i]);
        face.render.bindings[i] = binding;
        let v = face.render.rig_vertices[i];
        if Region::of_vertex(v as usize) == Some(Region::MouthSocket) {
            lining_count += 1;
            for (s, e) in lining_sum.iter_mut().zip(&errors) {
                *s += e;
            }
            continue;
        }
        let (k, e) = errors
            .iter()
            .enumerate()
            .fold((0, 0.0), |a, (k, &e)| if e > a.1 { (k, e) } else { a });
        skin_worst.push(e);
        if e > report.skin_max_error {
            report.skin_max_error = e;
            report.skin_worst_vertex = v;
            report.skin_worst_shape = fits.names[k].to_string();
        }
    }
    skin_worst.sort_by(f64::total_cmp);
    report.skin_p95_error = skin_worst
        .get(skin_worst.len() * 95 / 100)
        .copied()
        .unwrap_or(0.0);
    if lining_count > 0 {
        let (k, sum) = lining_sum
            .iter()
            .enumerate()
            .fold((0, 0.0), |a, (k, &s)| if s > a.1 { (k, s) } else { a });
        report.lining_mean_error = sum / lining_count as f64;
        report.lining_worst_shape = fits.names[k].to_string();
    }
    count_bindings(face, &mut report);
    if report.skin_max_error > settings.max_skin_error {
        return Err(BindingError::SkinOff {
            vertex: report.skin_worst_vertex,
            shape: report.skin_worst_shape.clone(),
            error_mm: 10.0 * report.skin_max_error,
            limit_mm: 10.0 * settings.max_skin_error,
        });
    }
    Ok(report)
}

/// Barycentric weights beyond this absolute sum extrapolate too far to be a candidate.
const MAX_WEIGHT_SUM: f64 = 4.0;

/// The counts of each kind of binding and the farthest embedded vertex.
fn count_bindings(face: &FaceModel, report: &mut BindingReport) {
    let bindings = &face.render.bindings;
    let count = |keep: &dyn Fn(&Binding) -> bool| bindings.iter().filter(|b| keep(b)).count();
    report.embedded_vertices = count(&|b| matches!(b, Binding::Embedded { .. }));
    report.blended_vertices =
        count(&|b| matches!(b, Binding::Blended { .. }) && b.embedded_share() > 0.0);
    report.skin_on_bone_vertices =
        count(&|b| matches!(b, Binding::Blended { .. }) && b.embedded_share() == 0.0);
    report.rigid_vertices = count(&|b| matches!(b, Binding::Rigid(_)));
    report.between_bones_vertices = count(&|b| matches!(b, Binding::Bones { .. }));
    report.max_embed_distance = bindings
        .iter()
        .zip(&face.render.rest)
        .filter_map(|(b, p)| match b {
            Binding::Embedded { element, .. } => {
                Some(distance_to_tet(&face.mesh, *element as usize, p))
            }
            Binding::Blended {
                element, embedded, ..
            } if *embedded > 0.0 => Some(distance_to_tet(&face.mesh, *element as usize, p)),
            _ => None,
        })
        .fold(0.0, f64::max);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::embedding::interpolate;
    use crate::model::test_support::coarse_face;
    use crate::rig::test_support::rig;

    /// A skin vertex's rig index and its errors with its binding and the nearest element's (cm).
    type SkinError = (u32, f64, f64);

    /// Every skin vertex of `face` that the rig's jawOpen opens by 3 cm or more, and how far
    /// it is from the rig on the tissue fitted to jawOpen with its own binding and with the
    /// Euclidean nearest element's (face format 2's binding), cm; and the lining's (rig vertex,
    /// cm).
    fn jaw_opening_errors(face: &FaceModel) -> (Vec<SkinError>, Vec<(u32, f64)>) {
        let render = &face.render;
        let target = shape_target(rig(), face, &[("jawOpen", 1.0)]).unwrap();
        let fit = ActuationFitter::new(face, FitSettings::default())
            .unwrap()
            .fit(&target, None)
            .unwrap();
        let bones = BonePose {
            jaw: fit.jaw,
            ..BonePose::default()
        };
        let posed = face.render_positions(&fit.positions, &bones);
        let nearest = Embedding::new(&face.mesh, &render.rest);
        let (mut skin, mut lining) = (Vec::new(), Vec::new());
        for (i, &v) in render.rig_vertices.iter().enumerate() {
            if (target.render[i] - render.rest[i]).norm() < 3.0 {
                continue;
            }
            let error = (posed[i] - target.render[i]).norm();
            match Region::of_vertex(v as usize) {
                Some(Region::FaceSkin) => {
                    let euclidean = interpolate(
                        &face.mesh.tets[nearest.elements[i] as usize],
                        &nearest.weights[i],
                        &fit.positions,
                    );
                    skin.push((v, error, (euclidean - target.render[i]).norm()));
                }
                Some(Region::MouthSocket) => lining.push((v, error)),
                _ => {}
            }
        }
        (skin, lining)
    }

    /// The lower lip and the chin, which the rig opens with the jaw by 3 cm and more (the
    /// lower lip's centre, rig vertices 6380–6513, by 4 cm), follow the rig's jawOpen on the
    /// tissue fitted to it: within 2.5 mm on the importer's face (the lining behind them
    /// within 1 mm on average). On tissue as coarse at the lips as the rest of the face
    /// (1.25 cm, face format 2's), the red of the lip lies up to 9 mm outside it, and the
    /// Euclidean nearest element of dozens of lower-lip vertices is the upper lip's, which
    /// the closed lips bring within a fraction of a millimetre: there they stay behind by
    /// 4 cm, while the side of the slit keeps them on the lower lip's tissue.
    #[test]
    fn the_lower_lip_rides_on_the_jaws_side_of_the_mouth_slit() {
        let (skin, lining) = jaw_opening_errors(coarse_face(None));
        assert!(
            skin.len() > 300,
            "{} skin vertices open with the jaw",
            skin.len()
        );
        for v in [6380, 6442, 6450, 6513] {
            assert!(skin.iter().any(|s| s.0 == v), "rig vertex {v} opens");
        }
        for &(v, error, _) in &skin {
            assert!(error < 0.25, "rig vertex {v} is {:.1} mm off", 10.0 * error);
        }
        // The lining follows the rig within 1 mm on average, but where it keeps off the gum
        // the rig moves it through (behind the lower incisors, rig vertices 11255–11924 and
        // their mirror images 12349–12735: 6–9 mm off; `the_lining_on_the_gums_keeps_off…`).
        let gums = the_lining_kept_off_the_gums();
        let (off, like_rig): (Vec<&(u32, f64)>, Vec<_>) =
            lining.iter().partition(|l| gums.contains(&l.0));
        let mean = like_rig.iter().map(|l| l.1).sum::<f64>() / like_rig.len() as f64;
        assert!(mean < 0.1, "the lining is {:.2} mm off", 10.0 * mean);
        for &&(v, error) in &off {
            assert!(error < 1.0, "rig vertex {v} is {:.1} mm off", 10.0 * error);
        }

        let mut settings = crate::model::Lod::Coarse.settings();
        settings.lip_edge_length = settings.edge_length;
        settings.bindings.max_skin_error = f64::INFINITY;
        let coarse = crate::model::build_face(rig(), None, &settings).unwrap();
        let (skin, _) = jaw_opening_errors(&coarse);
        let across = skin.iter().filter(|s| s.2 > 2.0).count();
        assert!(
            across > 10,
            "{across} vertices ride on the upper lip's tissue"
        );
        // The lower lip's centre: 3–6 mm off on its side, 37–40 mm on its nearest element.
        let centre = |v: &u32| [6380, 6442, 6513].contains(v);
        for &(v, error, euclidean) in skin.iter().filter(|s| centre(&s.0)) {
            assert!(
                euclidean > 3.0,
                "rig vertex {v}: {:.1} mm",
                10.0 * euclidean
            );
            assert!(
                error < 0.7,
                "rig vertex {v} is {:.1} mm off ({:.1} mm on its nearest element)",
                10.0 * error,
                10.0 * euclidean
            );
        }
    }

    /// The edges of the mouth lining that the bones alone carry (both ends rigid or between
    /// the bones: nothing the solver moves, so no contact can hold them) that cross a tooth or
    /// gum of `face` at some weight of a jaw shape, with the rig's jaw pose there: (rig vertices
    /// of the edge, shape, weight).
    fn bone_carried_lining_crossings(face: &FaceModel) -> Vec<([u32; 2], &'static str, f64)> {
        use crate::geometry::crossing::segment_crosses_triangle;
        let render = &face.render;
        let region = |i: u32| Region::of_vertex(render.rig_vertices[i as usize] as usize);
        let teeth = |i: u32| matches!(region(i), Some(Region::UpperTeeth | Region::LowerTeeth));
        let gums: Vec<[u32; 3]> = render
            .triangles
            .iter()
            .filter(|t| t.iter().all(|&v| teeth(v)))
            .copied()
            .collect();
        let carried = |i: u32| {
            region(i) == Some(Region::MouthSocket)
                && render.bindings[i as usize].element().is_none()
        };
        let mut edges: Vec<[u32; 2]> = render
            .triangles
            .iter()
            .flat_map(|t| (0..3).map(move |k| [t[k].min(t[(k + 1) % 3]), t[k].max(t[(k + 1) % 3])]))
            .filter(|e| e.iter().all(|&v| carried(v)))
            .collect();
        edges.sort_unstable();
        edges.dedup();
        let crossing = |y: &[Point3<f64>]| -> Vec<[u32; 2]> {
            edges
                .iter()
                .filter(|e| {
                    let (p, q) = (&y[e[0] as usize], &y[e[1] as usize]);
                    let reach = Box3::around(&[*p, *q], 0.0);
                    gums.iter().any(|t| {
                        let c = t.map(|v| &y[v as usize]);
                        reach.overlaps(&Box3::around(&c.map(|v| *v), 0.0))
                            && segment_crosses_triangle(p, q, c, *t)
                    })
                })
                .copied()
                .collect()
        };
        let at_rest = crossing(&render.rest);
        let x: Vec<f64> = face
            .mesh
            .vertices
            .iter()
            .flat_map(|p| [p.x, p.y, p.z])
            .collect();
        let teeth_rest: Vec<Point3<f64>> = rig().base(None)[Region::LowerTeeth.vertices()].to_vec();
        let mut out = Vec::new();
        for name in ["jawOpen", "jawForward", "jawLeft", "jawRight"] {
            for weight in [0.25, 0.5, 0.75, 1.0] {
                let code = ExpressionCode::single(name, weight).unwrap();
                let posed = rig().pose(None, &code);
                let fit = crate::rig::jaw::fit_rigid(
                    &teeth_rest,
                    &posed[Region::LowerTeeth.vertices()],
                    &face.jaw_pivot,
                )
                .unwrap();
                let bones = BonePose {
                    jaw: fit.motion,
                    ..BonePose::default()
                };
                let y = face.render_positions(&x, &bones);
                for e in crossing(&y) {
                    if !at_rest.contains(&e) {
                        out.push((e.map(|v| render.rig_vertices[v as usize]), name, weight));
                    }
                }
            }
        }
        out
    }

    /// How the rig moves the template's vertices relative to the bones.
    fn rig_motion(face: &FaceModel) -> BoneMotion {
        let settings = crate::model::Lod::Coarse.settings();
        BoneMotion::new(
            rig(),
            None,
            face.jaw_pivot,
            settings.skull_motion,
            settings.jaw_match,
        )
        .unwrap()
    }

    /// The rig vertices of the template's lining that the bones carry otherwise than by the
    /// rig's jaw maps: drawn onto a gum ([`ON_GUM`], [`BoneMotion::bone_binding_near`]).
    fn the_lining_kept_off_the_gums() -> Vec<u32> {
        let face = coarse_face(None);
        let motion = rig_motion(face);
        face.render
            .bindings
            .iter()
            .zip(&face.render.rig_vertices)
            .filter(|&(b, &v)| {
                Region::of_vertex(v as usize) == Some(Region::MouthSocket)
                    && b.element().is_none()
                    && *b != motion.bone_binding(v as usize)
            })
            .map(|(_, &v)| v)
            .collect()
    }

    /// The rig's jaw maps carry the lining that the bones carry through the teeth and gums
    /// in every jaw shape: 282 edges over the 16 poses below on the template (197 before the
    /// floor of the mouth left the tissue for the bones); behind the lower incisors `M ≈
    /// 1.1·I` takes rig vertex 11883, 1.5 mm from the gum, behind it at jawOpen 0.25. Drawn
    /// onto the gums, about a fifth as many edges cross (57, 36 before the floor of the
    /// mouth moved: at jawOpen 0.75–1 along the back molars and where the floor meets the
    /// lower gum, at jawLeft/jawRight 0.75–1 where the lining spans from the upper to the
    /// lower gum), none behind the incisors.
    #[test]
    fn the_lining_on_the_gums_keeps_off_them_where_the_rigs_jaw_maps_cross_them() {
        let face = coarse_face(None);
        let kept_off = bone_carried_lining_crossings(face);
        let motion = rig_motion(face);
        let mut plain = face.clone();
        for (b, &v) in plain
            .render
            .bindings
            .iter_mut()
            .zip(&plain.render.rig_vertices)
        {
            if Region::of_vertex(v as usize) == Some(Region::MouthSocket) && b.element().is_none() {
                *b = motion.bone_binding(v as usize);
            }
        }
        let rig_maps = bone_carried_lining_crossings(&plain);
        let at_11883 = |c: &[([u32; 2], &str, f64)]| c.iter().any(|c| c.0.contains(&11883));
        assert!(rig_maps.len() > 150 && at_11883(&rig_maps), "{rig_maps:?}");
        assert!(
            4 * kept_off.len() < rig_maps.len() && !at_11883(&kept_off),
            "{} crossing edges ({} with the rig's maps): {kept_off:?}",
            kept_off.len(),
            rig_maps.len()
        );
    }

    /// The blend of skin onto the skull: 1 up to `embed_distance`, 0 from
    /// `skin_rigid_distance`, falling smoothly (no jump, flat at both ends) between.
    #[test]
    fn the_skin_share_falls_smoothly_from_one_to_zero() {
        let settings = BindingSettings::default();
        let (near, far) = (settings.embed_distance, settings.skin_rigid_distance);
        assert_eq!(skin_share(0.0, &settings), 1.0);
        assert_eq!(skin_share(near, &settings), 1.0);
        assert_eq!(skin_share(far, &settings), 0.0);
        assert_eq!(skin_share(7.0, &settings), 0.0);
        assert!((skin_share(0.5 * (near + far), &settings) - 0.5).abs() < 1e-12);
        let h = 1e-6;
        let mut last = 1.0;
        for k in 0..=1000 {
            let d = near + (far - near) * k as f64 / 1000.0;
            let s = skin_share(d, &settings);
            assert!((0.0..=1.0).contains(&s) && s <= last, "{d}: {s}");
            last = s;
        }
        // Flat where it meets the embedded and the rigid skin: no kink, no visible seam.
        for d in [near, far] {
            let slope = (skin_share(d + h, &settings) - skin_share(d - h, &settings)) / (2.0 * h);
            assert!(slope.abs() < 1e-5, "slope {slope} at {d}");
        }
    }

    /// Every corner of the render surface carries the UV the rig gives that vertex in that
    /// triangle's polygon; along the rig's seams a vertex has more than one.
    #[test]
    fn the_render_surface_carries_the_rigs_uvs_corner_by_corner() {
        let face = coarse_face(None);
        let uv = face.render.uv.as_ref().expect("the ICT rig has UVs");
        assert_eq!(uv.triangles.len(), face.render.triangles.len());
        let mesh = rig().mesh();
        let corner_uvs = mesh.corner_uvs.as_ref().unwrap();
        let mut of_vertex: std::collections::HashMap<u32, Vec<[f32; 2]>> = Default::default();
        for (&v, &t) in mesh.faces.corners().iter().zip(corner_uvs) {
            of_vertex
                .entry(v)
                .or_default()
                .push(mesh.uvs[t as usize].map(|c| c as f32));
        }
        let mut seams = 0;
        for (t, c) in face.render.triangles.iter().zip(&uv.triangles) {
            for (&r, &k) in t.iter().zip(c) {
                let rig_vertex = face.render.rig_vertices[r as usize];
                let options = &of_vertex[&rig_vertex];
                assert!(
                    options.contains(&uv.coords[k as usize]),
                    "vertex {rig_vertex}"
                );
                seams += usize::from(options.iter().any(|o| o != &options[0]));
            }
        }
        assert!(seams > 0, "the face's UV layout has seams");
        // UDIM tiles side by side in u (the face, the back of the head, the mouth, …).
        assert!(
            uv.coords
                .iter()
                .all(|[u, v]| (0.0..8.0).contains(u) && (0.0..=1.0).contains(v))
        );
    }

    /// The render surface is the rig's whole head: every vertex and polygon, the parts the
    /// rig's material groups in order, and the eyes and the back of the head on the skull.
    #[test]
    fn the_render_surface_is_the_whole_head_in_the_rigs_parts() {
        let face = coarse_face(None);
        let render = &face.render;
        let mesh = rig().mesh();
        assert_eq!(render.rig_vertices.len(), mesh.positions.len());
        assert_eq!(render.triangles.len(), mesh.faces.triangulate().0.len());
        let names: Vec<&str> = render.parts.iter().map(|p| p.name.as_str()).collect();
        let groups: Vec<&str> = mesh
            .material_groups
            .iter()
            .map(|g| g.name.as_str())
            .collect();
        assert_eq!(names, groups);
        let mut next = 0;
        for part in &render.parts {
            assert_eq!(part.triangles.start, next, "{}", part.name);
            next = part.triangles.end;
        }
        assert_eq!(next as usize, render.triangles.len());
        for (b, &v) in render.bindings.iter().zip(&render.rig_vertices) {
            if matches!(
                Region::of_vertex(v as usize),
                Some(Region::Eyes | Region::HeadAndNeck | Region::EyeSocketLeft)
            ) {
                assert_eq!(*b, Binding::Rigid(Bone::Skull), "rig vertex {v}");
            }
        }
    }
}
