//! The importer: from a blendshape rig to a simulation-ready [`FaceModel`] for one identity.
//!
//! ```text
//! rest face ─► repair lip intersections ─► remesh the skin (edge length = level of detail)
//!   ─► inward directions + tissue thickness (rays to the mouth, teeth and far skin)
//!   ─► prism layers → tetrahedra (thinned where they would fold)
//!   ─► attachments: the inner layer under skin that no lower-face shape moves → skull,
//!      under skin that moves with the lower teeth → jaw
//!   ─► render surface: skin and inner mouth embedded; teeth, gums and the deep mouth on bones
//! ```

use std::time::Instant;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::bindings::{
    BindingError, BindingSettings, distance_to, element_shares, fit_to_rig, render_surface,
};
use super::bone_motion::BoneMotion;
use super::face::FaceModel;
use super::fit::LINING_CONTACT;
use super::report::BuildReport;
use crate::geometry::improve::smart_smooth;
use crate::geometry::query::TriangleIndex;
use crate::geometry::remesh::{Surface, min_angles, remesh_sized};
use crate::geometry::shell::{ShellError, extrude, quality, smooth_directions, vertex_normals};
use crate::geometry::triangles::{border_vertices, compact, gather, used_count};
use crate::rig::jaw::estimate_pivot;
use crate::rig::regions::lip_line;
use crate::rig::repair::{RepairSettings, repair_self_intersections};
use crate::rig::surface::{EdgeSet, SurfaceTopology};
use crate::rig::{FaceRig, Region};
use crate::sim::{Attachments, Bone};

/// Levels of detail of the simulation mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Lod {
    /// About 5k elements: interactive on any machine.
    Coarse,
    /// About 20k elements.
    Medium,
    /// About 80k elements.
    Fine,
}

impl Lod {
    pub const ALL: [Lod; 3] = [Lod::Coarse, Lod::Medium, Lod::Fine];

    pub fn name(self) -> &'static str {
        match self {
            Lod::Coarse => "coarse",
            Lod::Medium => "medium",
            Lod::Fine => "fine",
        }
    }

    pub fn settings(self) -> BuildSettings {
        let (edge_length, layers) = match self {
            Lod::Coarse => (1.25, 2),
            Lod::Medium => (0.62, 2),
            Lod::Fine => (0.38, 3),
        };
        BuildSettings {
            edge_length,
            layers,
            ..BuildSettings::default()
        }
    }
}

impl std::fmt::Display for Lod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Lod {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Lod::ALL
            .into_iter()
            .find(|l| l.name() == s)
            .ok_or_else(|| format!("unknown level of detail '{s}' (coarse, medium or fine)"))
    }
}

/// Knobs of the importer (cm).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BuildSettings {
    /// Target edge length of the simulation skin.
    pub edge_length: f64,
    /// Prism layers through the tissue.
    pub layers: usize,
    /// Tissue thickness where nothing is closer (forehead, cheeks over bone).
    pub max_thickness: f64,
    /// Thinnest tissue allowed, as a fraction of the edge length (lip edges, nostrils).
    pub min_thickness_ratio: f64,
    /// A surface vertex moved less than this by every default expression shape is on bone.
    pub skull_motion: f64,
    /// A surface vertex is on the jaw where jawOpen moves it like the lower teeth, to within
    /// this fraction of the teeth's motion there.
    pub jaw_match: f64,
    /// Rings of skin around the moving region that are simulated too (and pinned at their
    /// outer border), so the moving skin blends into the skin that rides on the skull.
    pub margin_rings: usize,
    /// Edge length of the simulation skin at the lips (cm; never above `edge_length`): the
    /// lips roll over a radius of a few millimetres, and coarser triangles cut through them,
    /// leaving the red of the lip up to 9 mm outside the tissue.
    pub lip_edge_length: f64,
    /// Distance from the lip line (cm) within which the skin has `lip_edge_length`; beyond
    /// it the edge length grows by [`LIP_GRADING`] per cm up to `edge_length`.
    pub lip_band: f64,
    /// How the render surface is bound to the tissue and bones.
    pub bindings: BindingSettings,
}

impl Default for BuildSettings {
    fn default() -> Self {
        Self {
            edge_length: 0.62,
            layers: 2,
            max_thickness: 1.2,
            min_thickness_ratio: 0.3,
            skull_motion: 0.05,
            jaw_match: 0.1,
            margin_rings: 2,
            lip_edge_length: 0.3,
            lip_band: 1.0,
            bindings: BindingSettings::default(),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum BuildError {
    #[error("identity {0} is not in the rig ({1} identities)")]
    NoSuchIdentity(usize, usize),
    #[error("repairing the rest face: {0}")]
    Repair(#[from] crate::rig::repair::RepairError),
    #[error("estimating the jaw: {0}")]
    Jaw(#[from] crate::rig::jaw::JawError),
    #[error("building the tissue layer: {0}")]
    Shell(#[from] ShellError),
    #[error("the simulation mesh is unusable: {0}")]
    Simulator(#[from] crate::sim::SimError),
    #[error("binding the render surface: {0}")]
    Bindings(#[from] BindingError),
}

/// Builds the simulation model of `identity` (`None`: the neutral, i.e. the template face).
pub fn build_face(
    rig: &FaceRig,
    identity: Option<usize>,
    settings: &BuildSettings,
) -> Result<FaceModel, BuildError> {
    let start = Instant::now();
    if let Some(i) = identity
        && i >= rig.identity_count()
    {
        return Err(BuildError::NoSuchIdentity(i, rig.identity_count()));
    }
    let mut report = BuildReport::default();
    let faces = rig.faces();
    let skin = SurfaceTopology::from_regions(faces, &[Region::FaceSkin], EdgeSet::Triangle);
    let d_hat = 1e-3 * skin.diameter(rig.base(identity));

    // 1. An intersection-free rest face.
    let (rest, repair) =
        repair_self_intersections(rig.base(identity), &skin, &RepairSettings::new(d_hat))?;
    report.intersections_before_repair = repair.intersections_before;
    report.intersections_after_repair = repair.intersections_after;
    report.repaired_vertices = repair.moved_vertices.len();
    report.max_repair_displacement = repair.max_displacement;

    // 2. The simulation skin: remeshed to the level of detail (finer at the lips), projected
    //    onto the real skin.
    let skin_index = TriangleIndex::new(&rest, &skin.triangles);
    let lip_line: Vec<Point3<f64>> = lip_line(rig.faces()).iter().map(|&v| rest[v]).collect();
    let remeshed = remesh_sized(
        &Surface {
            vertices: rest.clone(),
            triangles: skin.triangles.clone(),
        },
        6,
        &|p| skin_edge_length(settings, distance_to(&lip_line, p)),
        &|p| skin_index.closest_point(p).map_or(*p, |(q, _)| q),
    );

    // 3. Only the skin that the expression shapes move (and a margin, pinned at its border to
    //    the bone its skin follows) gets tissue: the rest of the face rides on the skull.
    let pivot = estimate_pivot(rig, identity)?;
    report.jaw_pivot_rms_motion = pivot.rms_pivot_motion;
    let motion = BoneMotion::new(
        rig,
        identity,
        pivot.pivot,
        settings.skull_motion,
        settings.jaw_match,
    )?;
    report.jaw_fit_rms = motion.jaw_fit_rms;
    let origin: Vec<usize> = remeshed
        .vertices
        .iter()
        .map(|p| nearest_rig_vertex(&skin_index, &rest, &skin, p))
        .collect();
    let mut active: Vec<bool> = origin
        .iter()
        .map(|&v| motion.max_motion[v] >= settings.skull_motion)
        .collect();
    for _ in 0..settings.margin_rings {
        let mut grown = active.clone();
        for t in &remeshed.triangles {
            if t.iter().any(|&v| active[v as usize]) {
                for &v in t {
                    grown[v as usize] = true;
                }
            }
        }
        active = grown;
    }
    let cropped: Vec<[u32; 3]> = remeshed
        .triangles
        .iter()
        .copied()
        .filter(|t| t.iter().all(|&v| active[v as usize]))
        .collect();
    // Only the crop's own border is pinned: not the skin's borders (mouth slit, eyes, rim),
    // nor holes left later where the layer cannot be extruded.
    let skin_border = border_vertices(&remeshed.triangles, remeshed.vertices.len());
    let pinned: Vec<bool> = border_vertices(&cropped, remeshed.vertices.len())
        .iter()
        .zip(&skin_border)
        .map(|(crop, skin)| *crop && !skin)
        .collect();

    // 4. Where the tissue goes and how deep.
    let (positions, mut triangles) = (remeshed.vertices, cropped);
    let inward: Vec<Vector3<f64>> =
        smooth_directions(&vertex_normals(&positions, &triangles), &triangles, 3)
            .iter()
            .map(|n| -n)
            .collect();
    let before = triangles.len();
    triangles.retain(|t| {
        let p = t.map(|v| positions[v as usize]);
        let n = (p[1] - p[0]).cross(&(p[2] - p[0]));
        t.iter().all(|&v| n.dot(&inward[v as usize]) < 0.0)
    });
    report.dropped_triangles = before - triangles.len();
    let (mut triangles, kept) = compact(&triangles, positions.len());
    let (positions, inward, origin, pinned) = (
        gather(&positions, &kept),
        gather(&inward, &kept),
        gather(&origin, &kept),
        gather(&pinned, &kept),
    );
    let mut thickness = tissue_thickness(rig, &rest, &positions, &inward, settings);
    limit_slope(&positions, &triangles, &mut thickness, MAX_THICKNESS_SLOPE);

    // 5. The tissue layer, thinned where prisms fold or their inner side crowds together
    //    (never below the minimum thickness); triangles that fold even then are left out.
    let min_thickness = settings.min_thickness_ratio * settings.edge_length;
    let thin = |vertices: &mut dyn Iterator<Item = u32>, thickness: &mut [f64]| {
        for v in vertices {
            thickness[v as usize] = (thickness[v as usize] * 0.85).max(min_thickness);
        }
    };
    let shell = loop {
        let rounds_left = report.thinning_rounds < MAX_THINNING_ROUNDS;
        match extrude(&positions, &triangles, &inward, &thickness, settings.layers) {
            Ok(shell) => {
                let crowded: Vec<usize> = (0..triangles.len())
                    .filter(|&t| {
                        area_ratio(&shell, &triangles[t]) < MIN_AREA_RATIO
                            && triangles[t]
                                .iter()
                                .any(|&v| thickness[v as usize] > min_thickness)
                    })
                    .collect();
                if crowded.is_empty() || !rounds_left {
                    break shell;
                }
                report.thinning_rounds += 1;
                thin(
                    &mut crowded.iter().flat_map(|&t| triangles[t]),
                    &mut thickness,
                );
            }
            Err(ShellError::Folded(folded)) => {
                // Folds that thinning cannot undo: leave those triangles out of the layer.
                let stuck: Vec<usize> = folded
                    .iter()
                    .copied()
                    .filter(|&t| {
                        !rounds_left
                            || triangles[t]
                                .iter()
                                .all(|&v| thickness[v as usize] <= min_thickness)
                    })
                    .collect();
                if stuck.is_empty() {
                    report.thinning_rounds += 1;
                    thin(
                        &mut folded.iter().flat_map(|&t| triangles[t]),
                        &mut thickness,
                    );
                } else {
                    report.dropped_triangles += stuck.len();
                    let mut index = 0;
                    triangles.retain(|_| {
                        index += 1;
                        !stuck.contains(&(index - 1))
                    });
                }
            }
            Err(e) => return Err(e.into()),
        }
    };
    // Dropped triangles may leave vertices without tissue: compact and extrude once more.
    let (shell, positions, triangles, thickness, origin, pinned) =
        if shell.mesh.vertex_count() == (shell.layers + 1) * used_count(&triangles) {
            (shell, positions, triangles, thickness, origin, pinned)
        } else {
            // Keep the vertices' relative order: prisms split by vertex index, so a new order
            // would split them differently from the extrusion that just succeeded (and fold).
            let (_, mut kept) = compact(&triangles, positions.len());
            kept.sort_unstable();
            let mut index = vec![u32::MAX; positions.len()];
            for (new, &old) in kept.iter().enumerate() {
                index[old] = new as u32;
            }
            let t: Vec<[u32; 3]> = triangles
                .iter()
                .map(|t| t.map(|v| index[v as usize]))
                .collect();
            let (p, d) = (gather(&positions, &kept), gather(&inward, &kept));
            let shell = extrude(&p, &t, &d, &gather(&thickness, &kept), settings.layers)?;
            (
                shell,
                p,
                t,
                gather(&thickness, &kept),
                gather(&origin, &kept),
                gather(&pinned, &kept),
            )
        };
    // Untangle the crowded spots: smooth the tissue's interior (the skin layer stays put).
    let mut shell = shell;
    let movable: Vec<bool> = (0..shell.mesh.vertex_count())
        .map(|v| v >= shell.surface_vertices)
        .collect();
    report.improvement = Some(smart_smooth(&mut shell.mesh, &movable, 30));
    let mut sorted = thickness.clone();
    sorted.sort_by(f64::total_cmp);
    (
        report.thickness_min,
        report.thickness_median,
        report.thickness_max,
    ) = (
        sorted[0],
        sorted[sorted.len() / 2],
        sorted[sorted.len() - 1],
    );
    report.skin_vertices = positions.len();
    report.skin_triangles = triangles.len();
    report.skin_min_angle_deg = min_angles(&Surface {
        vertices: positions.clone(),
        triangles: triangles.clone(),
    })
    .into_iter()
    .fold(180.0, f64::min);

    // 6. Attachments: the inner layer under skin that rides on a bone; the whole column at
    //    the border of the simulated region, where it meets skin that rides on a bone (the
    //    skull, or the jaw under the chin). Never where the inner layer lies on the mouth
    //    lining: that is the inside of a lip, soft tissue, which the fit pulls onto the
    //    lining (`fit::LINING_CONTACT`); and on the jaw only where it lies on no part of the
    //    mouth (lining, gums, teeth): the lower lip follows jawOpen like the teeth, but in
    //    front of the gums it is free to roll and protrude, and held on the jaw it shears
    //    through itself (folded elements in the funnel's and the lip rolls' fits).
    let (lining, mouth) = (
        surface_index(rig, &rest, &[Region::MouthSocket]),
        surface_index(rig, &rest, &MOUTH),
    );
    let within = |index: &TriangleIndex, p: &Point3<f64>, reach: f64| {
        index
            .closest_point(p)
            .is_some_and(|(q, _)| (q - p).norm() <= reach)
    };
    let mut bone: Vec<Option<Bone>> = (0..positions.len())
        .map(|v| {
            let inner = shell.mesh.vertices[shell.vertex(shell.layers, v)];
            match motion.bone_of(origin[v]) {
                _ if pinned[v] => Some(
                    motion
                        .bone_of(origin[v])
                        .unwrap_or(motion.nearest_bone(origin[v])),
                ),
                _ if within(&lining, &inner, LINING_CONTACT) => None,
                Some(Bone::Jaw) if within(&mouth, &inner, ON_MOUTH) => None,
                b => b,
            }
        })
        .collect();
    // Tissue between skull and jaw must stay free to stretch: where the two bones' regions
    // come within `BONE_GAP_RINGS` edges of each other, neither holds the tissue. This holds
    // on the crop's pinned border too: a prism column pinned to the skull beside one pinned
    // to the jaw is torn apart (its elements invert) as soon as the jaw opens.
    for _ in 0..BONE_GAP_RINGS {
        let mut next = bone.clone();
        for t in &triangles {
            let has = |b: Bone| t.iter().any(|&v| bone[v as usize] == Some(b));
            if has(Bone::Skull) && has(Bone::Jaw) {
                for &v in t {
                    next[v as usize] = None;
                }
            }
        }
        bone = next;
    }
    hold_loose_islands(&triangles, &origin, &motion, &mut bone);
    let mut attachments = Attachments::default();
    for (v, b) in bone.iter().enumerate() {
        if let Some(b) = *b {
            let layers = if pinned[v] {
                0..=shell.layers
            } else {
                shell.layers..=shell.layers
            };
            for l in layers {
                attachments.vertices.push(shell.vertex(l, v) as u32);
                attachments.bones.push(b);
            }
        }
    }
    report.skull_attached = attachments
        .bones
        .iter()
        .filter(|b| **b == Bone::Skull)
        .count();
    report.jaw_attached = attachments
        .bones
        .iter()
        .filter(|b| **b == Bone::Jaw)
        .count();

    // 7. The artist's surface, bound to the tissue and bones.
    let element_share = element_shares(&shell, &origin, &motion);
    let render = render_surface(
        rig,
        &rest,
        &shell,
        &element_share,
        &motion,
        &settings.bindings,
    );
    let skin_triangles = triangles;
    let mesh = shell.mesh;
    let mut model = FaceModel {
        identity,
        name: identity.map_or_else(
            || "neutral".to_string(),
            |i| rig.identity_names()[i].clone(),
        ),
        quality: quality(&mesh),
        mesh,
        skin_triangles,
        attachments,
        jaw_pivot: pivot.pivot,
        d_hat,
        render,
        report,
    };
    // The simulator must accept it (every part attached, matrix positive definite).
    model.simulator()?;
    model.report.bindings =
        fit_to_rig(&mut model, rig, &element_share, &motion, &settings.bindings)?;
    model.report.seconds = start.elapsed().as_secs_f64();
    Ok(model)
}

/// How fast the simulation skin's edge length grows away from the lips (cm per cm): slow
/// enough that neighbouring triangles stay alike.
pub const LIP_GRADING: f64 = 0.4;

/// The simulation skin's target edge length at `distance` (cm) from the lip line.
fn skin_edge_length(settings: &BuildSettings, distance: f64) -> f64 {
    let lip = settings.lip_edge_length.min(settings.edge_length);
    (lip + LIP_GRADING * (distance - settings.lip_band).max(0.0)).min(settings.edge_length)
}

/// Columns of skin an island of the simulation skin holds on its bone when nothing else
/// does (see [`hold_loose_islands`]).
const ISLAND_HOLDS: usize = 3;

/// Gives every connected piece of the simulation skin some attachment: a piece the rules
/// above left free (a patch between the lips and the lining, cut off where triangles were
/// dropped) would float, and the simulator refuses a mesh part no bone holds. Its
/// [`ISLAND_HOLDS`] least-moving skin vertices hold their column on their nearest bone.
fn hold_loose_islands(
    triangles: &[[u32; 3]],
    origin: &[usize],
    motion: &BoneMotion,
    bone: &mut [Option<Bone>],
) {
    let n = bone.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut v: usize) -> usize {
        while parent[v] != v {
            parent[v] = parent[parent[v]];
            v = parent[v];
        }
        v
    }
    for t in triangles {
        for k in 1..3 {
            let (a, b) = (
                root(&mut parent, t[0] as usize),
                root(&mut parent, t[k] as usize),
            );
            parent[a.max(b)] = a.min(b);
        }
    }
    let mut members: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for v in 0..n {
        let r = root(&mut parent, v);
        members.entry(r).or_default().push(v);
    }
    for island in members.values() {
        if island.iter().any(|&v| bone[v].is_some()) {
            continue;
        }
        let mut still = island.clone();
        still.sort_by(|&a, &b| {
            motion.max_motion[origin[a]]
                .total_cmp(&motion.max_motion[origin[b]])
                .then(a.cmp(&b))
        });
        for &v in still.iter().take(ISLAND_HOLDS) {
            bone[v] = Some(motion.nearest_bone(origin[v]));
        }
    }
}

/// The inside of the mouth: what the tissue layer stops short of (see [`tissue_thickness`]).
const MOUTH: [Region; 4] = [
    Region::MouthSocket,
    Region::GumsAndTongue,
    Region::UpperTeeth,
    Region::LowerTeeth,
];

/// An inner-layer vertex this close (cm) to the inside of the mouth lies on it: the tissue
/// layer stops at 0.95 of the way there (≤ 0.06 cm short at the 1.2 cm maximum depth).
const ON_MOUTH: f64 = 0.15;

/// The triangles of the rig's `regions` at rest, for closest-point queries.
fn surface_index(rig: &FaceRig, rest: &[Point3<f64>], regions: &[Region]) -> TriangleIndex {
    let surface = SurfaceTopology::from_regions(rig.faces(), regions, EdgeSet::Triangle);
    TriangleIndex::new(rest, &surface.triangles)
}

/// Rings of skin left free between the skull's and the jaw's attachment regions.
const BONE_GAP_RINGS: usize = 2;

/// Rounds of thinning before the importer leaves the still-folding triangles out.
const MAX_THINNING_ROUNDS: usize = 60;

/// Neighbouring prisms may differ in depth by at most this much per unit of distance along
/// the skin; steeper steps shear the prisms into slivers.
const MAX_THICKNESS_SLOPE: f64 = 0.5;

/// Lowers `thickness` until `t_v ≤ t_u + slope·‖p_u − p_v‖` along every edge (a one-sided
/// Lipschitz limit, computed like a distance transform by relaxing edges to a fixed point).
fn limit_slope(
    positions: &[Point3<f64>],
    triangles: &[[u32; 3]],
    thickness: &mut [f64],
    slope: f64,
) {
    let mut changed = true;
    while changed {
        changed = false;
        for t in triangles {
            for i in 0..3 {
                let (a, b) = (t[i] as usize, t[(i + 1) % 3] as usize);
                let limit = slope * (positions[a] - positions[b]).norm();
                for (x, y) in [(a, b), (b, a)] {
                    if thickness[x] > thickness[y] + limit {
                        thickness[x] = thickness[y] + limit;
                        changed = true;
                    }
                }
            }
        }
    }
}

/// The inner side of a prism may shrink to this fraction of the skin triangle's area; where
/// it crowds more (the focal region of a concave spot) the elements come out as slivers.
const MIN_AREA_RATIO: f64 = 0.4;

/// Signed area of a triangle's innermost copy over its skin area (projected on the skin
/// normal, so a fold is negative).
fn area_ratio(shell: &crate::geometry::shell::Shell, t: &[u32; 3]) -> f64 {
    let normal = |layer: usize| {
        let p = t.map(|v| shell.mesh.vertices[shell.vertex(layer, v as usize)]);
        (p[1] - p[0]).cross(&(p[2] - p[0]))
    };
    let outer = normal(0);
    normal(shell.layers).dot(&outer) / outer.norm_squared()
}

/// Tissue thickness under each skin vertex: up to `max_thickness`, stopping just short of the
/// inner mouth, gums and teeth, and at half the way to skin on the far side (the nose's
/// other wall); then smoothed so neighbouring prisms are alike.
fn tissue_thickness(
    rig: &FaceRig,
    rest: &[Point3<f64>],
    positions: &[Point3<f64>],
    inward: &[Vector3<f64>],
    settings: &BuildSettings,
) -> Vec<f64> {
    let faces = rig.faces();
    let inner = SurfaceTopology::from_regions(faces, &MOUTH, EdgeSet::Triangle);
    let skin = SurfaceTopology::from_regions(faces, &[Region::FaceSkin], EdgeSet::Triangle);
    let (inner, skin) = (
        TriangleIndex::new(rest, &inner.triangles),
        TriangleIndex::new(rest, &skin.triangles),
    );
    let min = settings.min_thickness_ratio * settings.edge_length;
    // Skin hits nearer than this are the skin under the vertex itself, not the far side.
    let self_hit = 0.5 * settings.edge_length;
    positions
        .iter()
        .zip(inward)
        .map(|(p, d)| {
            let mut limit = settings.max_thickness;
            if let Some((s, _)) = inner.first_hit(p, d, 0.0, settings.max_thickness / 0.95) {
                limit = limit.min(0.95 * s);
            }
            if let Some((s, _)) = skin.first_hit(p, d, self_hit, 2.0 * settings.max_thickness) {
                limit = limit.min(0.5 * s);
            }
            limit.max(min)
        })
        .collect()
}

/// The rig vertex of the skin closest to `p`: the nearest corner of the nearest skin triangle.
fn nearest_rig_vertex(
    index: &TriangleIndex,
    rest: &[Point3<f64>],
    skin: &SurfaceTopology,
    p: &Point3<f64>,
) -> usize {
    let Some((_, t)) = index.closest_point(p) else {
        return 0;
    };
    skin.triangles[t as usize]
        .iter()
        .map(|&v| v as usize)
        .min_by(|&a, &b| (rest[a] - p).norm().total_cmp(&(rest[b] - p).norm()))
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::embedding::distance_to_tet;
    use crate::model::Binding;
    use crate::rig::test_support::{rig, temp_dir};
    use crate::sim::{BonePose, Quality, SymTensor};

    fn neutral_coarse() -> &'static FaceModel {
        crate::model::test_support::coarse_face(None)
    }

    #[test]
    fn the_neutral_builds_into_a_valid_intersection_free_model() {
        let model = neutral_coarse();
        let (q, r) = (&model.quality, &model.report);
        assert!(
            (8_000..11_000).contains(&q.elements),
            "{} elements",
            q.elements
        );
        assert_eq!(q.inverted, 0);
        assert_eq!(
            (r.intersections_before_repair, r.intersections_after_repair),
            (126, 0)
        );
        // No skin of the ICT rig rides on the jaw through every shape (see `JAW_SLIP`).
        assert!(r.skull_attached > 0, "{r:?}");
        // The render surface follows the rig's shapes on the fitted tissue: every moving
        // skin vertex within 2 mm in every shape, the lining within 1.1 mm on average (1.02
        // at jawOpen, where the rig moves the floor of the mouth through the lower gum and the
        // bones keep it off).
        assert!(r.bindings.skin_max_error <= 0.2, "{:?}", r.bindings);
        assert!(r.bindings.lining_mean_error <= 0.11, "{:?}", r.bindings);
        assert!(r.skin_min_angle_deg > 5.0, "{r:?}");
        assert!(r.thickness_max <= Lod::Coarse.settings().max_thickness + 1e-12);
        assert!((model.d_hat - 0.029).abs() < 0.001, "d̂ = {}", model.d_hat);
        // The jaw pivot sits behind and above the lower teeth.
        let teeth = Region::LowerTeeth.vertices();
        let centroid = rig().neutral()[teeth.clone()]
            .iter()
            .map(|p| p.coords)
            .sum::<Vector3<f64>>()
            / teeth.len() as f64;
        assert!(
            model.jaw_pivot.z < centroid.z - 3.0 && model.jaw_pivot.y > centroid.y,
            "{:?}",
            model.jaw_pivot
        );
    }

    /// The face solved under identity actuations and bones at rest, which must take no
    /// iteration: the simulator, the state and the actuations.
    fn solved_at_rest(
        model: &FaceModel,
    ) -> (crate::sim::Simulator, crate::sim::SimState, Vec<SymTensor>) {
        let sim = model.simulator().unwrap();
        let mut state = sim.rest_state();
        let rest = vec![SymTensor::IDENTITY; sim.element_count()];
        let stats = sim
            .solve(
                &rest,
                &BonePose::default(),
                &mut state,
                &Quality::Final.settings(),
            )
            .unwrap();
        assert_eq!(stats.iterations, 0, "{}", model.name);
        (sim, state, rest)
    }

    #[test]
    fn identity_actuation_keeps_the_face_at_rest_and_the_render_surface_follows() {
        let model = neutral_coarse();
        let (sim, mut state, rest) = solved_at_rest(model);
        let render = model.render_positions(state.flat_positions(), &BonePose::default());
        let worst = render
            .iter()
            .zip(&model.render.rest)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0, f64::max);
        assert!(worst < 1e-9, "render surface moved by {worst} cm at rest");
        // Opening the jaw a little moves the chin down with it and keeps the forehead.
        let bones = BonePose {
            jaw: crate::sim::RigidMotion::from_params([0.08, 0.0, 0.0, 0.0, 0.0, 0.0]),
            ..BonePose::default()
        };
        sim.solve(&rest, &bones, &mut state, &Quality::Preview.settings())
            .unwrap();
        let moved = model.render_positions(state.flat_positions(), &bones);
        let chin = model
            .render
            .rig_vertices
            .iter()
            .position(|&v| v as usize == Region::LowerTeeth.vertices().start)
            .unwrap();
        assert!(moved[chin].y < model.render.rest[chin].y - 0.1);
    }

    /// Skin far outside the tissue (forehead, scalp, ears, neck: nothing the rig moves) follows
    /// the skull exactly, also when the jaw opens and the head turns; skin in the blend band
    /// mixes the tissue's and the skull's motion by its share.
    #[test]
    fn skin_far_outside_the_tissue_follows_the_skull() {
        let model = neutral_coarse();
        let render = &model.render;
        let settings = Lod::Coarse.settings().bindings;
        let outside = |i: usize| match render.bindings[i] {
            Binding::Blended { element, .. } => {
                distance_to_tet(&model.mesh, element as usize, &render.rest[i])
            }
            _ => 0.0,
        };
        let blended = |on_bone: bool| -> Vec<usize> {
            (0..render.rest.len())
                .filter(|&i| matches!(render.bindings[i], Binding::Blended { embedded, .. } if (embedded == 0.0) == on_bone))
                .collect()
        };
        let (far, band) = (blended(true), blended(false));
        assert!(far.len() > 500, "{} skin vertices far out", far.len());
        assert!(
            far.iter()
                .all(|&i| outside(i) >= settings.skin_rigid_distance)
        );
        assert!(band.len() > 100, "{} blended skin vertices", band.len());
        assert_eq!(model.report.bindings.skin_on_bone_vertices, far.len());
        assert_eq!(model.report.bindings.blended_vertices, band.len());
        assert!(model.report.bindings.max_embed_distance < settings.skin_rigid_distance);

        // The jaw opens (the tissue between jaw and skull stretches and turns) and the head
        // turns 0.3 rad and moves.
        let sim = model.simulator().unwrap();
        let mut state = sim.rest_state();
        let rest = vec![SymTensor::IDENTITY; sim.element_count()];
        let bones = BonePose {
            jaw: crate::sim::RigidMotion::from_params([0.12, 0.0, 0.0, 0.0, 0.0, 0.0]),
            skull: crate::sim::RigidMotion::from_params([0.0, 0.3, 0.05, 1.0, -0.5, 0.2]),
        };
        sim.solve(&rest, &bones, &mut state, &Quality::Preview.settings())
            .unwrap();
        let x = state.flat_positions();
        let moved = model.render_positions(x, &bones);
        let on_skull = |i: usize| bones.target(Bone::Skull, &model.jaw_pivot, &render.rest[i]);
        for &i in &far {
            assert!(
                (moved[i] - on_skull(i)).norm() < 1e-9,
                "far skin vertex {i} ({:.2} cm out) is {} cm off the skull",
                outside(i),
                (moved[i] - on_skull(i)).norm()
            );
        }
        for &i in &band {
            let Binding::Blended {
                element,
                weights,
                embedded,
                ..
            } = render.bindings[i]
            else {
                unreachable!()
            };
            let soft = crate::geometry::embedding::interpolate(
                &model.mesh.tets[element as usize],
                &weights,
                x,
            );
            let expected = on_skull(i) + (soft - on_skull(i)) * embedded;
            assert!((moved[i] - expected).norm() < 1e-12);
            let d = outside(i);
            assert!(d > settings.embed_distance && d < settings.skin_rigid_distance);
        }
    }

    /// A face file written before skin could blend onto the skull (format version 1) fails
    /// to load, saying which versions.
    #[test]
    fn version_one_face_files_fail_with_a_versioned_error() {
        let dir = temp_dir("face-v1");
        let path = dir.join("old.face");
        let v1 = crate::model::file::Format {
            kind: "face",
            version: 1,
        };
        crate::model::file::write(&path, v1, neutral_coarse()).unwrap();
        let err = FaceModel::load(&path).unwrap_err().to_string();
        assert!(
            err.contains("version 1") && err.contains("reads version 4"),
            "{err}"
        );
    }

    #[test]
    fn models_round_trip_through_files_and_reject_damage() {
        let model = neutral_coarse();
        let dir = temp_dir("face-model");
        let path = dir.join("neutral.face");
        model.save(&path).unwrap();
        assert_eq!(&FaceModel::load(&path).unwrap(), model);
        let mut bytes = std::fs::read(&path).unwrap();
        let middle = bytes.len() / 2;
        bytes[middle] ^= 1;
        std::fs::write(&path, &bytes).unwrap();
        let err = FaceModel::load(&path).unwrap_err();
        assert!(err.to_string().contains("corrupt"), "{err}");
        std::fs::write(&path, &bytes[..100]).unwrap();
        assert!(
            FaceModel::load(&path)
                .unwrap_err()
                .to_string()
                .contains("truncated")
        );
    }

    #[test]
    fn identities_get_their_own_meshes() {
        let a = build_face(rig(), Some(0), &Lod::Coarse.settings()).unwrap();
        let b = build_face(rig(), Some(7), &Lod::Coarse.settings()).unwrap();
        assert_ne!(a.mesh.vertices.len(), 0);
        assert!(a.mesh != b.mesh && a.mesh != neutral_coarse().mesh);
        assert_eq!(a.report.intersections_after_repair, 0);
        assert_eq!(b.report.intersections_after_repair, 0);
        assert!(matches!(
            build_face(rig(), Some(99), &Lod::Coarse.settings()),
            Err(BuildError::NoSuchIdentity(99, 10))
        ));
    }

    #[test]
    fn every_identity_imports_valid_and_stays_at_rest_under_identity_actuation() {
        let faces: Vec<&FaceModel> = std::iter::once(None)
            .chain((0..rig().identity_count()).map(Some))
            .map(crate::model::test_support::coarse_face)
            .collect();
        assert_eq!(faces.len(), 11);
        for model in faces {
            let (q, r) = (&model.quality, &model.report);
            assert_eq!(r.intersections_after_repair, 0, "{}", model.name);
            assert_eq!(q.inverted, 0, "{}", model.name);
            assert!(q.min_dihedral_deg > 2.0, "{}: {q:?}", model.name);
            assert!(
                (8_000..11_000).contains(&q.elements),
                "{}: {q:?}",
                model.name
            );
            assert!(
                r.bindings.skin_max_error <= 0.5,
                "{}: {:?}",
                model.name,
                r.bindings
            );
            let (_, state, _) = solved_at_rest(model);
            assert_eq!(state.positions(), model.mesh.vertices, "{}", model.name);
        }
    }
}
