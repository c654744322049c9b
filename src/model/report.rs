//! What the importer reports: how the build went ([`BuildReport`]) and how well the render
//! surface's bindings follow the rig ([`BindingReport`]). Plain data, kept apart from the
//! steps that fill it so that the face model can carry it without depending on them.

use serde::{Deserialize, Serialize};

use crate::geometry::improve::ImproveReport;

/// What the importer did and measured, for the user and the README.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BuildReport {
    pub intersections_before_repair: usize,
    pub intersections_after_repair: usize,
    pub repaired_vertices: usize,
    pub max_repair_displacement: f64,
    pub skin_vertices: usize,
    pub skin_triangles: usize,
    /// Smallest angle of any simulation skin triangle, degrees.
    pub skin_min_angle_deg: f64,
    /// Skin triangles left out of the tissue layer because it cannot be extruded there (the
    /// surface folds back on itself).
    pub dropped_triangles: usize,
    /// Thinning rounds needed so that no prism folds.
    pub thinning_rounds: usize,
    pub thickness_min: f64,
    pub thickness_median: f64,
    pub thickness_max: f64,
    pub skull_attached: usize,
    pub jaw_attached: usize,
    pub jaw_pivot_rms_motion: f64,
    /// Rigid fit error of the lower teeth under jawOpen (cm).
    pub jaw_fit_rms: f64,
    /// How the render surface is bound, and how well it follows the rig.
    pub bindings: BindingReport,
    /// The interior smoothing pass (worst dihedral angle before and after).
    pub improvement: Option<ImproveReport>,
    pub seconds: f64,
}

/// How the render surface is bound and how well it reproduces the rig.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct BindingReport {
    /// Render vertices the tissue alone moves.
    pub embedded_vertices: usize,
    /// Skin vertices the tissue and the skull share (`0 < s < 1`, [`Binding::Blended`](super::face::Binding::Blended)).
    pub blended_vertices: usize,
    /// Skin vertices outside the tissue that follow the skull alone (`s = 0`).
    pub skin_on_bone_vertices: usize,
    /// Render vertices one bone alone moves (teeth, the gums on one bone).
    pub rigid_vertices: usize,
    /// Render vertices between the bones ([`Binding::Bones`](super::face::Binding::Bones): the deep lining, the tongue).
    pub between_bones_vertices: usize,
    /// Largest distance outside the tissue of a render vertex the tissue moves, fully or
    /// blended (cm): how far its position is extrapolated.
    pub max_embed_distance: f64,
    /// Vertices whose binding the rig's shapes changed (step 2 of the module doc).
    pub rebound_vertices: usize,
    /// Largest distance of a moving skin vertex from the rig over the basis shapes (cm),
    /// where on the rig and in which shape.
    pub skin_max_error: f64,
    pub skin_worst_vertex: u32,
    pub skin_worst_shape: String,
    /// The 95th percentile over moving skin vertices of each one's largest distance (cm).
    pub skin_p95_error: f64,
    /// The mouth lining's mean distance from the rig in its worst shape (cm), and that shape.
    pub lining_mean_error: f64,
    pub lining_worst_shape: String,
    /// The shapes fitted for the choice.
    pub shapes: usize,
}
