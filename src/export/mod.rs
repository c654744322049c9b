//! `facesim export`: an animation track simulated frame by frame and written as animated
//! geometry for other tools (USD, PC2 point cache, OBJ sequence, glTF; `.rrd` from the editor
//! binary, which has rerun).
//!
//! Frames stream: each is simulated ([`run`], through the same [`Session`](crate::session::Session)
//! the editor uses), handed to every format's writer, and dropped, so memory does not grow with
//! the length of the track. Every output is written under a temporary name and renamed into
//! place when the whole export succeeded ([`atomic`]), with a report of every frame's
//! convergence and crossings ([`report`]).
//!
//! Units: the simulator and the USD, PC2, OBJ and rrd outputs are in centimetres (USD says so
//! with `metersPerUnit = 0.01`); glTF is in metres, as its specification requires.

pub mod atomic;
pub mod gltf;
pub mod obj;
pub mod pc2;
pub mod report;
pub mod run;
pub mod usd;

use std::path::Path;

pub use run::{ExportJob, ExportSummary, FrameRange, SinkFactory, export};

use crate::session::track::Track;
use crate::session::{Frame, SessionFace};
use crate::sim::Quality;

/// An output format.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Format {
    /// `NAME.usda`: time-sampled points and normals.
    Usd,
    /// `NAME.pc2` point cache + `NAME.obj` topology.
    Pc2,
    /// `NAME_obj/NAME_0000.obj …`: one OBJ per frame.
    Obj,
    /// `NAME.glb`: base mesh + one morph target per frame, animated by weights.
    Gltf,
    /// `NAME.rrd`: a rerun recording (written by the editor binary only).
    Rrd,
}

impl Format {
    pub const ALL: [Format; 5] = [
        Format::Usd,
        Format::Pc2,
        Format::Obj,
        Format::Gltf,
        Format::Rrd,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Format::Usd => "usd",
            Format::Pc2 => "pc2",
            Format::Obj => "obj",
            Format::Gltf => "gltf",
            Format::Rrd => "rrd",
        }
    }
}

impl std::str::FromStr for Format {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Format::ALL
            .into_iter()
            .find(|f| f.name() == s)
            .ok_or_else(|| {
                format!("unknown export format '{s}' (expected usd, pc2, obj, gltf or rrd)")
            })
    }
}

impl std::fmt::Display for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error("writing {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error(
        "the rrd format needs rerun, which the core `facesim` binary does not link: export it with \
         the editor binary, `cargo run --release -- export TRACK.json --out DIR --format rrd` \
         (it accepts every other format too)"
    )]
    RrdNeedsEditor,
    #[error("no formats given (expected some of usd, pc2, obj, gltf, rrd)")]
    NoFormats,
    #[error("fps {0} must be finite and in (0, 1000]")]
    BadFps(f64),
    #[error("the track has no keys")]
    EmptyTrack,
    #[error("frames {first}..{end} hold none of the track's {total} frames (0..{total})")]
    EmptyRange {
        first: usize,
        end: usize,
        total: usize,
    },
    #[error("{0}")]
    Face(String),
    #[error("{format}: {reason}")]
    TooLarge { format: Format, reason: String },
    #[error("frame {frame} (t = {time:.3} s) could not be simulated: {reason}")]
    Frame {
        frame: usize,
        time: f64,
        reason: String,
    },
    #[error("{format} writer: {reason}")]
    Writer { format: Format, reason: String },
    #[error(transparent)]
    Session(#[from] crate::session::SessionError),
}

impl ExportError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        ExportError::Io {
            path: path.display().to_string(),
            source,
        }
    }
}

/// The surface every frame deforms: the face's render surface (the whole head: skin, mouth,
/// teeth, eyes), cm.
#[derive(Clone, Debug, PartialEq)]
pub struct ExportMesh {
    pub triangles: Vec<[u32; 3]>,
    pub rest: Vec<[f32; 3]>,
    pub rest_normals: Vec<[f32; 3]>,
    /// The rig's texture coordinates, per triangle corner.
    pub uv: Option<crate::model::UvLayout>,
    /// Named runs of `triangles` (the rig's material groups), covering them in order.
    pub parts: Vec<crate::model::Part>,
}

impl ExportMesh {
    pub fn of(model: &crate::model::FaceModel) -> Self {
        let to32 = |p: &nalgebra::Point3<f64>| [p.x as f32, p.y as f32, p.z as f32];
        ExportMesh {
            triangles: model.render.triangles.clone(),
            rest: model.render.rest.iter().map(to32).collect(),
            rest_normals: crate::session::frame::vertex_normals(
                &model.render.rest,
                &model.render.triangles,
            ),
            uv: model.render.uv.clone(),
            parts: model.render.parts.clone(),
        }
    }

    pub fn vertex_count(&self) -> usize {
        self.rest.len()
    }
}

/// The number of frames of a `duration`-second track at `fps`: `t = k / fps` for
/// `k = 0 … ⌊duration·fps⌋` (the last key's time is included when it falls on a frame).
pub fn frame_count(duration: f64, fps: f64) -> usize {
    (duration * fps + 1e-9).floor() as usize + 1
}

/// Where one format's frames go. `frame` is called for the export's frames in order (their
/// numbers in the track: `0, 1, …`, or a range's `first, first + 1, …`); `finish` completes
/// the (temporary) file.
pub trait FrameSink {
    fn frame(&mut self, index: usize, frame: &Frame) -> Result<(), ExportError>;
    fn finish(self: Box<Self>) -> Result<(), ExportError>;
}

/// Checks a frame's geometry against the mesh (sizes) — writers trust it after this.
pub(crate) fn check_sizes(
    format: Format,
    mesh_vertices: usize,
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
) -> Result<(), ExportError> {
    if positions.len() != mesh_vertices || normals.len() != mesh_vertices {
        return Err(ExportError::Writer {
            format,
            reason: format!(
                "a frame has {} positions and {} normals, the mesh {} vertices",
                positions.len(),
                normals.len(),
                mesh_vertices
            ),
        });
    }
    Ok(())
}

/// A buffered file writer and the error it reports.
pub(crate) struct Out {
    pub path: std::path::PathBuf,
    pub w: std::io::BufWriter<std::fs::File>,
}

impl Out {
    pub fn create(path: &Path) -> Result<Self, ExportError> {
        let file = std::fs::File::create(path).map_err(|e| ExportError::io(path, e))?;
        Ok(Out {
            path: path.to_path_buf(),
            w: std::io::BufWriter::with_capacity(1 << 20, file),
        })
    }

    pub fn err(&self, e: std::io::Error) -> ExportError {
        ExportError::io(&self.path, e)
    }

    pub fn write_all(&mut self, bytes: &[u8]) -> Result<(), ExportError> {
        use std::io::Write;
        let r = self.w.write_all(bytes);
        r.map_err(|e| self.err(e))
    }

    /// Flushes and syncs the file to disk (before it is renamed into place).
    pub fn close(self) -> Result<(), ExportError> {
        let path = self.path;
        let file = self
            .w
            .into_inner()
            .map_err(|e| ExportError::io(&path, e.into_error()))?;
        file.sync_all().map_err(|e| ExportError::io(&path, e))
    }
}

#[cfg(test)]
pub(crate) mod test_mesh {
    use super::ExportMesh;

    /// A unit square of two triangles, with a UV seam through vertex 0 (its corner in the
    /// second triangle has other coordinates), and a frame generator that lifts it in `z`.
    pub fn square() -> ExportMesh {
        ExportMesh {
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            rest: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            rest_normals: vec![[0.0, 0.0, 1.0]; 4],
            uv: Some(crate::model::UvLayout {
                coords: vec![[0.0, 0.0], [0.5, 0.0], [0.5, 0.5], [0.0, 0.5], [0.75, 1.0]],
                triangles: vec![[0, 1, 2], [4, 2, 3]],
            }),
            parts: vec![
                crate::model::Part {
                    name: "M_Front".into(),
                    triangles: 0..1,
                },
                crate::model::Part {
                    name: "M_Back".into(),
                    triangles: 1..2,
                },
            ],
        }
    }

    /// Frame `k`: vertex `i` lifted by `0.25·k·(i + 1)` cm, normals tilted with it.
    pub fn frame(mesh: &ExportMesh, k: usize) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
        let p = mesh
            .rest
            .iter()
            .enumerate()
            .map(|(i, r)| [r[0], r[1], r[2] + 0.25 * (k * (i + 1)) as f32])
            .collect();
        let s = (k as f32 * 0.1).sin();
        let c = (k as f32 * 0.1).cos();
        (p, vec![[s, 0.0, c]; mesh.rest.len()])
    }
}

#[cfg(test)]
mod tests;

/// The preset if none is given here or in the track: an export is a final render.
pub const DEFAULT_QUALITY: Quality = Quality::Final;

/// Whether frames solve with lip and teeth contact if neither the command line nor the track
/// says: yes, so exported lips do not pass through each other (the 10-second smile at the
/// final preset with contact takes 106 s on 2 cores, README "Headline numbers").
pub const DEFAULT_CONTACT: bool = true;

/// How the export renders: the command line's choice, else the track's, else the defaults
/// ([`DEFAULT_QUALITY`] with [`DEFAULT_CONTACT`]).
pub fn render_settings(
    quality: Option<Quality>,
    contact: Option<bool>,
    track: &Track,
) -> (Quality, bool) {
    (
        quality.or(track.quality).unwrap_or(DEFAULT_QUALITY),
        contact.or(track.contact).unwrap_or(DEFAULT_CONTACT),
    )
}

/// Picks the face: `--face` by name or index, else the track's face.
pub fn choose_face(
    faces: Vec<SessionFace>,
    wanted: Option<&str>,
    track: &Track,
) -> Result<SessionFace, ExportError> {
    let names: Vec<String> = faces.iter().map(|f| f.name.clone()).collect();
    let key = wanted.unwrap_or(&track.face);
    let index = names
        .iter()
        .position(|n| n == key)
        .or_else(|| key.parse::<usize>().ok().filter(|&i| i < faces.len()));
    match index {
        Some(i) => Ok(faces.into_iter().nth(i).expect("index checked")),
        None => Err(ExportError::Face(format!(
            "the sample has no face '{key}'{} (faces: {}; indices 0–{})",
            if wanted.is_none() {
                " (the track's face; choose one with --face)"
            } else {
                ""
            },
            names.join(", "),
            names.len().saturating_sub(1)
        ))),
    }
}
