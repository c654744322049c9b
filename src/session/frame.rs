//! A solved frame as the viewers see it: render-surface geometry, overlays and solver
//! figures. Everything here is finite (checked when built); a failed solve becomes a frame
//! that keeps the last good geometry and carries the error.

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::crosses::{CrossArm, actuation_crosses};
use super::heatmap::{FieldInput, FieldSource, ScalarField};
use crate::drive::{Actuation, Codes};
use crate::model::FaceModel;
use crate::model::deep_lining::{DeepLining, DeepLiningStats, LiningMemory};
use crate::sim::{Quality, RigidMotion, SolveStats, Termination};

/// Solver figures of one frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameStats {
    pub iterations: usize,
    pub residual: f64,
    pub termination: Termination,
    /// The solve reached its preset's tolerance. A frame that did not (it ran out of
    /// iterations, or stalled at round-off above the tolerance) is shown as far as the
    /// solver got and marked so in the editor, the protocol and the export report.
    #[serde(default)]
    pub converged: bool,
    /// The solve from the last frame found no equilibrium and this one is from rest.
    #[serde(default)]
    pub from_rest: bool,
    /// Time in the solver, ms.
    pub solve_ms: f64,
    /// Codes → frame ready (actuation, solve, geometry, overlays), ms.
    pub total_ms: f64,
    /// Active contact pairs, where the solver handles contact (`None`: no contact in play).
    pub contacts: Option<usize>,
    /// The contact solve was skipped: the contact-free result was certified to be the
    /// equilibrium with contact (see `sim::contact_gate`).
    #[serde(default)]
    pub contact_skipped: bool,
    /// Contact candidate lists (Verlet lists over the contact region) the solve built: the
    /// re-detections a frame paid for (`None`: no contact solve ran).
    #[serde(default)]
    pub contact_lists: Option<usize>,
    /// No solve ran: the inputs were those the face's state was already solved for (a
    /// display change, a repeated slider value), so the frame reuses that solve.
    #[serde(default)]
    pub reused: bool,
    /// The deep lining's contact pass, where it ran (final frames with contact,
    /// [`crate::model::deep_lining::runs_at`]).
    #[serde(default)]
    pub lining: Option<DeepLiningStats>,
}

impl FrameStats {
    pub fn from_solve(stats: &SolveStats, total_ms: f64) -> Self {
        FrameStats {
            iterations: stats.iterations,
            residual: stats.residual,
            termination: stats.termination,
            converged: stats.converged(),
            from_rest: stats.from_rest || stats.contact.as_ref().is_some_and(|c| c.from_rest),
            solve_ms: stats.wall_time.as_secs_f64() * 1e3,
            total_ms,
            contacts: stats.contact.as_ref().map(|c| c.active_pairs),
            contact_skipped: stats.contact.as_ref().is_some_and(|c| c.gate.skipped()),
            contact_lists: stats.contact.as_ref().map(|c| c.candidate_builds),
            reused: false,
            lining: None,
        }
    }
}

/// One frame (module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Increases by one with every frame the session publishes.
    pub index: u64,
    /// The request generation this frame answers (see `Session::submit`).
    pub generation: u64,
    pub face: usize,
    pub codes: Codes,
    /// The preset this frame was solved to (refinement raises it while inputs rest).
    pub quality: Quality,
    /// Render-surface positions and unit normals, cm.
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    /// Simulation-mesh positions (for the wireframe).
    pub mesh_positions: Vec<[f32; 3]>,
    /// Actuation crosses (empty unless the display asks for them).
    pub crosses: Vec<CrossArm>,
    /// Heatmaps (empty unless the display asks for them).
    pub heatmaps: Vec<ScalarField>,
    pub jaw: RigidMotion,
    pub stats: FrameStats,
    /// Why this frame's inputs could not be solved; the geometry is then the last good one.
    pub error: Option<String>,
}

/// Solved geometry before it becomes a [`Frame`].
pub struct Solved<'a> {
    pub model: &'a FaceModel,
    pub x: &'a [f64],
    pub actuation: &'a Actuation,
}

/// The deep lining's contact pass for a frame and its warm start.
pub struct LiningPass<'a> {
    pub pass: &'a DeepLining,
    pub memory: &'a mut LiningMemory,
}

/// What to compute besides geometry.
#[derive(Clone, Copy, Debug)]
pub struct Overlays {
    pub crosses: bool,
    pub heatmaps: bool,
}

/// Geometry and overlays of a solved state; `None` if anything came out non-finite.
pub struct Geometry {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub mesh_positions: Vec<[f32; 3]>,
    pub crosses: Vec<super::crosses::CrossArm>,
    pub heatmaps: Vec<ScalarField>,
    pub lining: Option<DeepLiningStats>,
}

/// The frame's geometry: render positions (the deep lining moved off the teeth by `lining`
/// when given), normals and the overlays.
pub fn geometry(
    solved: &Solved<'_>,
    overlays: Overlays,
    sources: &[Box<dyn FieldSource>],
    lining: Option<LiningPass<'_>>,
) -> Option<Geometry> {
    let model = solved.model;
    let bones = solved.actuation.bones();
    let mut positions = model.render_positions(solved.x, &bones);
    let lining = lining.map(|l| l.pass.apply(&mut positions, l.memory));
    let normals = vertex_normals(&positions, &model.render.triangles);
    let crosses = if overlays.crosses {
        actuation_crosses(&model.mesh, solved.x, &solved.actuation.tensors)
    } else {
        Vec::new()
    };
    let heatmaps = if overlays.heatmaps {
        let volume_ratio = volume_ratios(model, solved.x);
        let input = FieldInput {
            model,
            positions: &positions,
            mesh_x: solved.x,
            volume_ratio: &volume_ratio,
        };
        sources.iter().map(|s| s.compute(&input)).collect()
    } else {
        Vec::new()
    };
    let to32 = |p: &Point3<f64>| [p.x as f32, p.y as f32, p.z as f32];
    let g = Geometry {
        positions: positions.iter().map(to32).collect(),
        normals,
        mesh_positions: solved
            .x
            .chunks_exact(3)
            .map(|p| [p[0] as f32, p[1] as f32, p[2] as f32])
            .collect(),
        crosses,
        heatmaps,
        lining,
    };
    let finite = |v: &[[f32; 3]]| v.iter().flatten().all(|c| c.is_finite());
    let ok = finite(&g.positions)
        && finite(&g.normals)
        && finite(&g.mesh_positions)
        && g.heatmaps
            .iter()
            .all(|h| h.values.iter().all(|v| v.is_finite()))
        && g.crosses
            .iter()
            .all(|a| a.from.iter().chain(&a.to).all(|c| c.is_finite()));
    ok.then_some(g)
}

/// Area-weighted vertex normals (zero-area neighbourhoods get +z, never NaN).
pub fn vertex_normals(positions: &[Point3<f64>], triangles: &[[u32; 3]]) -> Vec<[f32; 3]> {
    let mut acc = vec![Vector3::zeros(); positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let n = (b - a).cross(&(c - a));
        for i in t {
            acc[*i as usize] += n;
        }
    }
    acc.iter()
        .map(|n| {
            let len = n.norm();
            if len > 0.0 && len.is_finite() {
                [(n.x / len) as f32, (n.y / len) as f32, (n.z / len) as f32]
            } else {
                [0.0, 0.0, 1.0]
            }
        })
        .collect()
}

/// Deformed over rest volume of every element.
pub fn volume_ratios(model: &FaceModel, x: &[f64]) -> Vec<f64> {
    let p = |v: u32| {
        let v = v as usize;
        Vector3::new(x[3 * v], x[3 * v + 1], x[3 * v + 2])
    };
    model
        .mesh
        .tets
        .iter()
        .enumerate()
        .map(|(e, t)| {
            let [a, b, c, d] = t.map(p);
            let v = (b - a).cross(&(c - a)).dot(&(d - a)) / 6.0;
            v / model.mesh.signed_volume(e)
        })
        .collect()
}
