//! Streaming frames to a rerun viewer (spawned, over gRPC) or into an `.rrd` file.
//!
//! Entities: `face/skin` (a mesh: static triangles and base colours, per-frame positions and normals),
//! `face/heatmaps/<field>` (the same mesh with that field's vertex colours), `face/crosses`
//! (actuation crosses as line strips), `face/jaw` (the jaw's rigid transform about its
//! pivot), and `solver/{iterations,residual,solve_ms,frame_ms}` scalars; all per-frame data on
//! the `frame` timeline (the session's frame index). The rig's view coordinates (y up) and a
//! default blueprint ([`layout`], with the first face) go first, so a recording opens with the
//! face upright, large and seen from the front.

use std::sync::Mutex;

use anyhow::{Context, Result};
use facesim::session::{FaceTopology, Frame};
use rerun::EntityPath;
use rerun::blueprint::{
    Blueprint, BlueprintActivation, ContainerLike, Horizontal, Spatial3DView, Tabs, TimeSeriesView,
    Vertical,
};
use rerun::components::{Color, Plane3D, Position3D, TriangleIndices, Vector3D};
use rerun::external::re_sdk_types::blueprint::archetypes::{EyeControls3D, LineGrid3D};

/// Where to stream.
#[derive(Clone, Debug, PartialEq)]
pub enum RerunTarget {
    Spawn,
    Connect(String),
    Save(std::path::PathBuf),
}

impl std::str::FromStr for RerunTarget {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s == "spawn" {
            Ok(RerunTarget::Spawn)
        } else if let Some(url) = s.strip_prefix("connect=") {
            Ok(RerunTarget::Connect(url.into()))
        } else if s == "connect" {
            Ok(RerunTarget::Connect(
                "rerun+http://127.0.0.1:9876/proxy".into(),
            ))
        } else if let Some(path) = s.strip_prefix("save=") {
            Ok(RerunTarget::Save(path.into()))
        } else {
            Err(format!(
                "unknown rerun target '{s}' (expected spawn, connect, connect=URL or save=FILE)"
            ))
        }
    }
}

/// The default blueprint: tabs of 3D views (the face with its crosses and jaw; the heatmaps,
/// one selectable entity each) over three quarters of the width, the solver's plots beside;
/// and the blueprint paths of the two 3D views (for their eyes, [`send_layout`]).
fn layout() -> (Blueprint, [EntityPath; 2]) {
    let view_path = |view: &ContainerLike| match view {
        ContainerLike::View(v) => v.blueprint_path(),
        _ => unreachable!("a 3D view"),
    };
    let face: ContainerLike = Spatial3DView::new("face")
        .with_origin("/")
        .with_contents(["+ /face/**", "- /face/heatmaps/**"])
        .into();
    let heatmaps: ContainerLike = Spatial3DView::new("heatmaps")
        .with_origin("/")
        .with_contents(["+ /face/heatmaps/**"])
        .into();
    let views = [view_path(&face), view_path(&heatmaps)];
    let plot = |name: &str, entities: &[&str]| -> ContainerLike {
        TimeSeriesView::new(name)
            .with_origin("/solver")
            .with_contents(entities.iter().map(|e| format!("/solver/{e}")))
            .into()
    };
    let plots = Vertical::new([
        plot("iterations", &["iterations"]),
        plot("residual", &["residual"]),
        plot("time (ms)", &["solve_ms", "frame_ms"]),
    ]);
    let blueprint = Blueprint::new(
        Horizontal::new([Tabs::new([face, heatmaps]).into(), plots.into()])
            .with_column_shares([3.0, 1.0]),
    );
    (blueprint, views)
}

/// The viewer's vertical field of view, degrees (rerun's default eye).
const VIEWER_FOV_Y_DEG: f32 = 55.0;

/// A 3D view's framing of a face from its rest bounds: an eye in front of it (+z in the rig)
/// looking at the centre from far enough that the head's height fills ~90 % of the view at
/// the centre's depth (d = ½h·1.1 / tan(½·fov)), and the grid as a floor under the chin
/// (rerun's planes are n·p − d = 0).
fn framing(rest: &[[f32; 3]]) -> (EyeControls3D, LineGrid3D) {
    let [lo, hi] = facesim::geometry::bounds_f32(rest.iter().copied());
    let centre: [f32; 3] = std::array::from_fn(|k| 0.5 * (lo[k] + hi[k]));
    let half_height = 0.5 * (hi[1] - lo[1]);
    let distance = half_height * 1.1 / (0.5 * VIEWER_FOV_Y_DEG.to_radians()).tan();
    let eye = EyeControls3D::new()
        .with_position(Position3D::new(centre[0], centre[1], centre[2] + distance))
        .with_look_target(Position3D::new(centre[0], centre[1], centre[2]))
        .with_eye_up(Vector3D::from((0.0, 1.0, 0.0)));
    let floor = LineGrid3D::new().with_plane(Plane3D::new((0.0, 1.0, 0.0), lo[1]));
    (eye, floor)
}

/// Sends the default blueprint with both 3D views framed on the face ([`framing`]).
///
/// rerun 0.36's Rust `Spatial3DView` has no eye setting (Python's has `eye_controls`), so the
/// blueprint's messages are taken from an in-memory stream and the eye is logged into the same
/// blueprint store, at `<view>/EyeControls3D`, as the viewer reads a view's property.
fn send_layout(rec: &rerun::RecordingStream, rest: &[[f32; 3]]) -> Result<()> {
    use rerun::external::re_log_types::{BlueprintActivationCommand, StoreKind};
    use rerun::log::LogMsg;
    let (blueprint, views) = layout();
    let (relay, relayed) = rerun::RecordingStreamBuilder::new("facesim").memory()?;
    blueprint.send(&relay, BlueprintActivation::default())?;
    let mut messages: Vec<LogMsg> = relayed
        .take()
        .into_iter()
        .filter(|m| {
            m.store_id().kind() == StoreKind::Blueprint
                && !matches!(m, LogMsg::BlueprintActivationCommand(_))
        })
        .collect();
    let store = messages
        .first()
        .context("the blueprint sent no messages")?
        .store_id()
        .clone();
    let (eyes, eyes_out) = rerun::RecordingStreamBuilder::new("facesim")
        .recording_id(store.recording_id().clone())
        .blueprint()
        .memory()?;
    eyes.set_time_sequence("blueprint", 0);
    let (eye, floor) = framing(rest);
    for view in &views {
        eyes.log(format!("{view}/EyeControls3D"), &eye)?;
        eyes.log(format!("{view}/LineGrid3D"), &floor)?;
    }
    messages.extend(
        eyes_out
            .take()
            .into_iter()
            .filter(|m| !matches!(m, LogMsg::SetStoreInfo(_))),
    );
    rec.send_blueprint(
        messages,
        BlueprintActivationCommand {
            blueprint_id: store,
            make_active: true,
            make_default: true,
        },
    );
    Ok(())
}

/// Logs frames to one recording.
pub struct RerunLogger {
    rec: rerun::RecordingStream,
    /// Face whose static triangles were logged last.
    static_face: Mutex<Option<usize>>,
}

fn pos(p: &[f32; 3]) -> Position3D {
    Position3D::new(p[0], p[1], p[2])
}

impl RerunLogger {
    pub fn new(target: &RerunTarget) -> Result<Self> {
        let builder = rerun::RecordingStreamBuilder::new("facesim");
        let rec = match target {
            RerunTarget::Spawn => builder.spawn().context(
                "spawning the rerun viewer (is `rerun` on PATH? pip install rerun-sdk==0.36.3)",
            )?,
            RerunTarget::Connect(url) => builder
                .connect_grpc_opts(url.clone())
                .with_context(|| format!("connecting to the rerun viewer at {url}"))?,
            RerunTarget::Save(path) => builder
                .save(path)
                .with_context(|| format!("creating {}", path.display()))?,
        };
        // The rig's axes (x right, y up, z toward the viewer), so the viewer's camera starts
        // upright; the layout goes with the first face (its eye frames that face).
        rec.log_static("/", &rerun::ViewCoordinates::RIGHT_HAND_Y_UP())?;
        Ok(RerunLogger {
            rec,
            static_face: Mutex::new(None),
        })
    }

    /// Logs one frame (and the face's static triangles when the face changes) on the `frame`
    /// timeline at the session's frame index.
    pub fn log(&self, frame: &Frame, topology: &FaceTopology) -> Result<()> {
        self.log_at(frame, topology, frame.index as i64, None)
    }

    /// As [`RerunLogger::log`], at frame number `sequence` and, with `seconds`, also at that
    /// time on the `time` timeline (exports: frame numbers 0, 1, … and the track's time).
    pub fn log_at(
        &self,
        frame: &Frame,
        topology: &FaceTopology,
        sequence: i64,
        seconds: Option<f64>,
    ) -> Result<()> {
        let rec = &self.rec;
        let tris: Vec<TriangleIndices> = topology
            .triangles
            .iter()
            .map(|t| TriangleIndices::from((t[0], t[1], t[2])))
            .collect();
        {
            let mut face = self.static_face.lock().unwrap_or_else(|e| e.into_inner());
            if *face != Some(frame.face) {
                if face.is_none() {
                    send_layout(rec, &topology.rest)?;
                }
                let colors: Vec<Color> = topology
                    .colors
                    .iter()
                    .map(|&[r, g, b]| Color::from_rgb(r, g, b))
                    .collect();
                rec.log_static(
                    "face/skin",
                    &rerun::Mesh3D::update_fields()
                        .with_triangle_indices(tris.clone())
                        .with_vertex_colors(colors),
                )?;
                for h in &frame.heatmaps {
                    rec.log_static(
                        format!("face/heatmaps/{}", entity_name(&h.name)),
                        &rerun::Mesh3D::update_fields().with_triangle_indices(tris.clone()),
                    )?;
                }
                *face = Some(frame.face);
            }
        }
        rec.set_time_sequence("frame", sequence);
        if let Some(t) = seconds {
            rec.set_duration_secs("time", t);
        }
        let positions: Vec<Position3D> = frame.positions.iter().map(pos).collect();
        let normals: Vec<Vector3D> = frame
            .normals
            .iter()
            .map(|n| Vector3D::from((n[0], n[1], n[2])))
            .collect();
        rec.log(
            "face/skin",
            &rerun::Mesh3D::update_fields()
                .with_vertex_positions(positions.clone())
                .with_vertex_normals(normals.clone()),
        )?;
        for h in &frame.heatmaps {
            let colors: Vec<Color> = h
                .colors()
                .into_iter()
                .map(|[r, g, b]| Color::from_rgb(r, g, b))
                .collect();
            rec.log(
                format!("face/heatmaps/{}", entity_name(&h.name)),
                &rerun::Mesh3D::update_fields()
                    .with_vertex_positions(positions.clone())
                    .with_vertex_normals(normals.clone())
                    .with_vertex_colors(colors),
            )?;
        }
        let strips: Vec<Vec<[f32; 3]>> = frame.crosses.iter().map(|a| vec![a.from, a.to]).collect();
        rec.log("face/crosses", &rerun::LineStrips3D::new(strips))?;
        let r = frame.jaw.rotation_matrix();
        let cols: [[f32; 3]; 3] =
            std::array::from_fn(|c| std::array::from_fn(|k| r[(k, c)] as f32));
        // p ↦ R(p − pivot) + pivot + t, as one affine map: translation pivot + t − R·pivot.
        let pivot = nalgebra::Vector3::from(topology.jaw_pivot.map(f64::from));
        let t = pivot + frame.jaw.translation - r * pivot;
        rec.log(
            "face/jaw",
            &rerun::Transform3D::from_translation_mat3x3(
                (t.x as f32, t.y as f32, t.z as f32),
                cols,
            ),
        )?;
        let s = &frame.stats;
        for (name, v) in [
            ("iterations", s.iterations as f64),
            ("residual", s.residual),
            ("solve_ms", s.solve_ms),
            ("frame_ms", s.total_ms),
        ] {
            rec.log(format!("solver/{name}"), &rerun::Scalars::new([v]))?;
        }
        Ok(())
    }

    pub fn flush(&self) {
        let _ = self.rec.flush_blocking();
    }
}

/// An entity path part from a field name ("volume ratio det F" → "volume_ratio_det_F").
pub fn entity_name(name: &str) -> String {
    name.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}
