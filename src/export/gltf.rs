//! glTF 2.0 output as one binary file (`.glb`): the render surface as a base mesh (rest pose)
//! with **one morph target per frame** (position and normal offsets from the rest pose) and an
//! animation of the morph weights: at frame `k`'s time the weight of target `k` is 1 and all
//! others 0, interpolated linearly between frames, so a player shows exactly the simulated
//! frames and blends linearly between them.
//!
//! Why morph targets: glTF has no vertex-cache animation; per-frame morph targets are the valid
//! way to carry arbitrary per-vertex motion, and every glTF viewer plays weight animations.
//! Limits: the file grows as `24·V` bytes per frame (positions and normals, `f32`) plus the
//! `N × N` weight keys (`4·N²` bytes, 0.4 MB at 300 frames, 13 MB at 1,800); GLB caps the
//! whole file at 4 GiB (checked before simulating), and some real-time engines limit how many
//! morph targets a mesh may have (use USD or PC2 for long shots). Each part (the rig's
//! material groups) is a primitive with a material of its name (no shading parameters); the
//! primitives share the vertices and morph targets.
//!
//! Texture coordinates: glTF has one UV per vertex, so a render vertex on a UV seam becomes
//! one glTF vertex per chart it lies in (`TEXCOORD_0`, `v` flipped to glTF's top-left origin);
//! each copy takes its render vertex's position and normal in every frame, so the seams
//! never open.
//!
//! Units: metres (glTF's unit; the simulator's centimetres × 0.01), Y up.
//!
//! Streaming: the targets are written to a scratch file as frames arrive (with each target's
//! bounds, which glTF requires); `finish` writes the JSON (which needs the bounds), then the
//! binary chunk, copying the targets in.

use std::io::Write as _;
use std::path::{Path, PathBuf};

use serde_json::{Value, json};

use super::{ExportError, ExportMesh, Format, FrameSink, Out, check_sizes};
use crate::geometry::bounds_f32 as bounds;
use crate::model::Part;
use crate::session::Frame;

/// Centimetres → metres.
const TO_METRES: f32 = 0.01;

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;

type Bounds = [[f32; 3]; 2];

/// Exactly the `f32` value as a JSON number (so the validator's min/max comparison is exact).
fn num3(v: [f32; 3]) -> Value {
    json!([v[0] as f64, v[1] as f64, v[2] as f64])
}

fn metres(p: &[f32; 3]) -> [f32; 3] {
    p.map(|c| c * TO_METRES)
}

/// The byte layout of the binary chunk.
struct Layout {
    indices: u64,
    base: u64,
    uvs: u64,
    targets: u64,
    times: u64,
    weights: u64,
    total: u64,
}

impl Layout {
    fn new(triangles: usize, vertices: usize, uvs: bool, frames: usize) -> Self {
        let (t, v, n) = (triangles as u64, vertices as u64, frames as u64);
        let indices = 12 * t;
        let base = 24 * v;
        let uvs = if uvs { 8 * v } else { 0 };
        let targets = 24 * v * n;
        let times = 4 * n;
        let weights = 4 * n * n;
        Layout {
            indices,
            base,
            uvs,
            targets,
            times,
            weights,
            total: indices + base + uvs + targets + times + weights,
        }
    }
}

/// The render surface as glTF vertices: split along UV seams (module doc).
struct SplitMesh {
    /// The render vertex each glTF vertex copies.
    source: Vec<u32>,
    triangles: Vec<[u32; 3]>,
    rest_normals: Vec<[f32; 3]>,
    /// `TEXCOORD_0` per glTF vertex; empty without UVs.
    uvs: Vec<[f32; 2]>,
}

impl SplitMesh {
    fn new(mesh: &ExportMesh) -> Self {
        let Some(uv) = &mesh.uv else {
            return SplitMesh {
                source: (0..mesh.vertex_count() as u32).collect(),
                triangles: mesh.triangles.clone(),
                rest_normals: mesh.rest_normals.clone(),
                uvs: Vec::new(),
            };
        };
        let mut index = std::collections::HashMap::new();
        let (mut source, mut uvs) = (Vec::new(), Vec::new());
        let triangles = mesh
            .triangles
            .iter()
            .zip(&uv.triangles)
            .map(|(t, c)| {
                std::array::from_fn(|k| {
                    *index.entry((t[k], c[k])).or_insert_with(|| {
                        source.push(t[k]);
                        let [u, v] = uv.coords[c[k] as usize];
                        uvs.push([u, 1.0 - v]);
                        source.len() as u32 - 1
                    })
                })
            })
            .collect();
        SplitMesh {
            rest_normals: source
                .iter()
                .map(|&v| mesh.rest_normals[v as usize])
                .collect(),
            source,
            triangles,
            uvs,
        }
    }

    fn vertex_count(&self) -> usize {
        self.source.len()
    }

    fn gather<'a>(&'a self, values: &'a [[f32; 3]]) -> impl Iterator<Item = [f32; 3]> + 'a {
        self.source.iter().map(move |&v| values[v as usize])
    }
}

/// Streams frames into a `.glb`.
pub struct GltfWriter {
    path: PathBuf,
    scratch: Out,
    scratch_path: PathBuf,
    /// Render vertices a frame has.
    points: usize,
    mesh: SplitMesh,
    parts: Vec<Part>,
    /// The first frame's number: frame `first + k` plays at `(first + k) / fps`.
    first: usize,
    rest_m: Vec<[f32; 3]>,
    frames: usize,
    fps: f64,
    generator: String,
    target_bounds: Vec<Bounds>,
    buf: Vec<u8>,
}

impl GltfWriter {
    /// Plans a file of `frames` frames; fails at once if it would pass GLB's 4 GiB.
    pub fn create(
        path: &Path,
        scratch: &Path,
        mesh: &ExportMesh,
        first: usize,
        frames: usize,
        fps: f64,
        generator: &str,
    ) -> Result<Self, ExportError> {
        let split = SplitMesh::new(mesh);
        let layout = Layout::new(
            split.triangles.len(),
            split.vertex_count(),
            !split.uvs.is_empty(),
            frames,
        );
        // Room for the header, chunk headers and the JSON (≈ 200 bytes per frame).
        let limit = u32::MAX as u64 - 28 - 4096 - 256 * frames as u64;
        if layout.total > limit {
            return Err(ExportError::TooLarge {
                format: Format::Gltf,
                reason: format!(
                    "{frames} frames of {} vertices need {:.2} GB, over GLB's 4 GiB: export fewer \
                     frames (a lower --fps or a shorter track) or use usd/pc2",
                    split.vertex_count(),
                    layout.total as f64 / 1e9
                ),
            });
        }
        Ok(GltfWriter {
            path: path.to_path_buf(),
            scratch: Out::create(scratch)?,
            scratch_path: scratch.to_path_buf(),
            rest_m: split.gather(&mesh.rest).map(|p| metres(&p)).collect(),
            points: mesh.vertex_count(),
            parts: mesh.parts.clone(),
            first,
            buf: Vec::with_capacity(24 * split.vertex_count()),
            mesh: split,
            frames,
            fps,
            generator: generator.to_string(),
            target_bounds: Vec::with_capacity(frames),
        })
    }

    pub fn write_frame(
        &mut self,
        positions: &[[f32; 3]],
        normals: &[[f32; 3]],
    ) -> Result<(), ExportError> {
        check_sizes(Format::Gltf, self.points, positions, normals)?;
        if self.target_bounds.len() >= self.frames {
            return Err(ExportError::Writer {
                format: Format::Gltf,
                reason: format!("more than the {} frames announced", self.frames),
            });
        }
        let deltas: Vec<[f32; 3]> = self
            .mesh
            .gather(positions)
            .zip(&self.rest_m)
            .map(|(p, r)| {
                let p = metres(&p);
                [p[0] - r[0], p[1] - r[1], p[2] - r[2]]
            })
            .collect();
        self.target_bounds.push(bounds(deltas.iter().copied()));
        self.buf.clear();
        for c in deltas.iter().flatten() {
            self.buf.extend_from_slice(&c.to_le_bytes());
        }
        for (n, r) in self.mesh.gather(normals).zip(&self.mesh.rest_normals) {
            for c in 0..3 {
                self.buf.extend_from_slice(&(n[c] - r[c]).to_le_bytes());
            }
        }
        let buf = std::mem::take(&mut self.buf);
        let r = self.scratch.write_all(&buf);
        self.buf = buf;
        r
    }

    fn json(&self, layout: &Layout) -> Value {
        let (v, n) = (self.mesh.vertex_count(), self.frames);
        // Several accessors share the vertex views, which glTF then requires to state a stride.
        let mut views = vec![
            json!({"buffer": 0, "byteOffset": 0, "byteLength": layout.indices, "target": ELEMENT_ARRAY_BUFFER}),
            json!({"buffer": 0, "byteOffset": layout.indices, "byteLength": layout.base, "byteStride": 12, "target": ARRAY_BUFFER}),
        ];
        let uv_view = (layout.uvs > 0).then(|| {
            views.push(json!({"buffer": 0, "byteOffset": layout.indices + layout.base, "byteLength": layout.uvs, "target": ARRAY_BUFFER}));
            views.len() - 1
        });
        let targets_offset = layout.indices + layout.base + layout.uvs;
        let targets_view = views.len();
        if n > 0 {
            views.push(json!({"buffer": 0, "byteOffset": targets_offset, "byteLength": layout.targets, "byteStride": 12, "target": ARRAY_BUFFER}));
        }
        let anim_offset = targets_offset + layout.targets;
        views.push(json!({"buffer": 0, "byteOffset": anim_offset, "byteLength": layout.times}));
        views.push(json!({"buffer": 0, "byteOffset": anim_offset + layout.times, "byteLength": layout.weights}));
        let (times_view, weights_view) = (views.len() - 2, views.len() - 1);

        // One primitive per part (the rig's material groups), each with its run of the index
        // buffer; they share the vertices, the morph targets and so the animation.
        let whole = [Part {
            name: String::new(),
            triangles: 0..self.mesh.triangles.len() as u32,
        }];
        let parts = if self.parts.is_empty() {
            &whole[..]
        } else {
            &self.parts[..]
        };
        let mut accessors: Vec<Value> = parts
            .iter()
            .map(|p| {
                json!({"bufferView": 0, "byteOffset": 12 * p.triangles.start, "componentType": UNSIGNED_INT,
                       "count": 3 * p.triangles.len(), "type": "SCALAR"})
            })
            .collect();
        let rest_bounds = bounds(self.rest_m.iter().copied());
        let position = accessors.len();
        accessors.push(json!({"bufferView": 1, "byteOffset": 0, "componentType": FLOAT, "count": v, "type": "VEC3",
                              "min": num3(rest_bounds[0]), "max": num3(rest_bounds[1])}));
        accessors.push(json!({"bufferView": 1, "byteOffset": 12 * v, "componentType": FLOAT, "count": v, "type": "VEC3"}));
        let mut attributes = json!({"POSITION": position, "NORMAL": position + 1});
        if let Some(view) = uv_view {
            attributes["TEXCOORD_0"] = json!(accessors.len());
            accessors.push(
                json!({"bufferView": view, "componentType": FLOAT, "count": v, "type": "VEC2"}),
            );
        }
        let mut targets = Vec::with_capacity(n);
        for (k, b) in self.target_bounds.iter().enumerate() {
            let offset = 24 * v * k;
            targets.push(json!({"POSITION": accessors.len(), "NORMAL": accessors.len() + 1}));
            accessors.push(
                json!({"bufferView": targets_view, "byteOffset": offset, "componentType": FLOAT, "count": v,
                                  "type": "VEC3", "min": num3(b[0]), "max": num3(b[1])}),
            );
            accessors.push(
                json!({"bufferView": targets_view, "byteOffset": offset + 12 * v, "componentType": FLOAT,
                                  "count": v, "type": "VEC3"}),
            );
        }
        let time = |k: usize| ((self.first + k) as f64 / self.fps) as f32;
        let times_accessor = accessors.len();
        accessors.push(
            json!({"bufferView": times_view, "componentType": FLOAT, "count": n, "type": "SCALAR",
                              "min": [time(0) as f64], "max": [time(n.max(1) - 1) as f64]}),
        );
        accessors.push(json!({"bufferView": weights_view, "componentType": FLOAT, "count": n * n, "type": "SCALAR"}));
        let mut weights = vec![0.0; n];
        if let Some(w) = weights.first_mut() {
            *w = 1.0;
        }
        let primitives: Vec<Value> = (0..parts.len())
            .map(|k| {
                let mut p =
                    json!({"attributes": attributes, "indices": k, "mode": 4, "targets": targets});
                if !self.parts.is_empty() {
                    p["material"] = json!(k);
                }
                p
            })
            .collect();
        let materials: Vec<Value> = self.parts.iter().map(|p| json!({"name": p.name})).collect();
        let mut gltf = json!({
            "asset": {"version": "2.0", "generator": self.generator},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [{"name": "Face", "mesh": 0}],
            "meshes": [{
                "name": "Surface",
                "primitives": primitives,
                "weights": weights,
            }],
            "animations": [{
                "name": "track",
                "channels": [{"sampler": 0, "target": {"node": 0, "path": "weights"}}],
                "samplers": [{"input": times_accessor, "output": times_accessor + 1, "interpolation": "LINEAR"}],
            }],
            "buffers": [{"byteLength": layout.total}],
            "bufferViews": views,
            "accessors": accessors,
        });
        if !materials.is_empty() {
            gltf["materials"] = json!(materials);
        }
        gltf
    }

    pub fn finish(self) -> Result<(), ExportError> {
        let n = self.frames;
        if self.target_bounds.len() != n || n == 0 {
            return Err(ExportError::Writer {
                format: Format::Gltf,
                reason: format!("{} of {n} frames written", self.target_bounds.len()),
            });
        }
        let layout = Layout::new(
            self.mesh.triangles.len(),
            self.mesh.vertex_count(),
            !self.mesh.uvs.is_empty(),
            n,
        );
        let mut json = serde_json::to_vec(&self.json(&layout)).expect("JSON serializes");
        self.scratch.close()?;
        while !json.len().is_multiple_of(4) {
            json.push(b' ');
        }
        let total = 12 + 8 + json.len() as u64 + 8 + layout.total;
        let total = u32::try_from(total).map_err(|_| ExportError::TooLarge {
            format: Format::Gltf,
            reason: format!("{total} bytes is over GLB's 4 GiB"),
        })?;
        let mut out = Out::create(&self.path)?;
        let mut head = Vec::with_capacity(20);
        head.extend_from_slice(b"glTF");
        head.extend_from_slice(&2u32.to_le_bytes());
        head.extend_from_slice(&total.to_le_bytes());
        head.extend_from_slice(&(json.len() as u32).to_le_bytes());
        head.extend_from_slice(b"JSON");
        out.write_all(&head)?;
        out.write_all(&json)?;
        let mut bin = Vec::with_capacity(
            8 + layout.indices as usize + layout.base as usize + layout.uvs as usize,
        );
        bin.extend_from_slice(&(layout.total as u32).to_le_bytes());
        bin.extend_from_slice(b"BIN\0");
        for i in self.mesh.triangles.iter().flatten() {
            bin.extend_from_slice(&i.to_le_bytes());
        }
        for c in self.rest_m.iter().chain(&self.mesh.rest_normals).flatten() {
            bin.extend_from_slice(&c.to_le_bytes());
        }
        for c in self.mesh.uvs.iter().flatten() {
            bin.extend_from_slice(&c.to_le_bytes());
        }
        out.write_all(&bin)?;
        let mut scratch = std::fs::File::open(&self.scratch_path)
            .map_err(|e| ExportError::io(&self.scratch_path, e))?;
        let copied =
            std::io::copy(&mut scratch, &mut out.w).map_err(|e| ExportError::io(&self.path, e))?;
        if copied != layout.targets {
            return Err(ExportError::Writer {
                format: Format::Gltf,
                reason: format!("{copied} bytes of targets, expected {}", layout.targets),
            });
        }
        let mut row = Vec::with_capacity(4 * n);
        for k in 0..n {
            row.extend_from_slice(&(((self.first + k) as f64 / self.fps) as f32).to_le_bytes());
        }
        out.write_all(&row)?;
        for k in 0..n {
            row.clear();
            for j in 0..n {
                row.extend_from_slice(&(if j == k { 1.0f32 } else { 0.0 }).to_le_bytes());
            }
            out.write_all(&row)?;
        }
        out.w.flush().map_err(|e| ExportError::io(&self.path, e))?;
        out.close()
    }
}

impl FrameSink for GltfWriter {
    fn frame(&mut self, _index: usize, frame: &Frame) -> Result<(), ExportError> {
        self.write_frame(&frame.positions, &frame.normals)
    }
    fn finish(self: Box<Self>) -> Result<(), ExportError> {
        GltfWriter::finish(*self)
    }
}

/// Reads a `.glb`'s JSON chunk and binary chunk (checks the header and chunk lengths).
pub fn read_glb(path: &Path) -> Result<(Value, Vec<u8>), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let u32_at = |o: usize| -> Result<u32, String> {
        bytes
            .get(o..o + 4)
            .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")))
            .ok_or_else(|| "truncated".to_string())
    };
    if bytes.get(..4) != Some(b"glTF") || u32_at(4)? != 2 {
        return Err("not a glTF 2.0 binary".into());
    }
    if u32_at(8)? as usize != bytes.len() {
        return Err(format!(
            "header length {} != file length {}",
            u32_at(8)?,
            bytes.len()
        ));
    }
    let json_len = u32_at(12)? as usize;
    if bytes.get(16..20) != Some(b"JSON") {
        return Err("first chunk is not JSON".into());
    }
    let json: Value =
        serde_json::from_slice(&bytes[20..20 + json_len]).map_err(|e| e.to_string())?;
    let bin_at = 20 + json_len;
    let bin_len = u32_at(bin_at)? as usize;
    if bytes.get(bin_at + 4..bin_at + 8) != Some(b"BIN\0") || bin_at + 8 + bin_len != bytes.len() {
        return Err("bad binary chunk".into());
    }
    Ok((json, bytes[bin_at + 8..].to_vec()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::test_mesh;

    fn f32_at(bin: &[u8], o: usize) -> f32 {
        f32::from_le_bytes(bin[o..o + 4].try_into().unwrap())
    }

    #[test]
    fn a_glb_has_one_morph_target_per_frame_and_a_weight_animation() {
        let dir = std::env::temp_dir().join(format!("facesim-gltf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (path, scratch) = (dir.join("a.glb"), dir.join("a.targets"));
        let mesh = test_mesh::square();
        let mut w = GltfWriter::create(&path, &scratch, &mesh, 0, 3, 10.0, "test").unwrap();
        for k in 0..3 {
            let (p, n) = test_mesh::frame(&mesh, k);
            w.write_frame(&p, &n).unwrap();
        }
        w.finish().unwrap();
        let (json, bin) = read_glb(&path).unwrap();
        assert_eq!(
            bin.len() as u64,
            json["buffers"][0]["byteLength"].as_u64().unwrap()
        );
        let prim = &json["meshes"][0]["primitives"][0];
        assert_eq!(prim["targets"].as_array().unwrap().len(), 3);
        // One primitive per part, named by its material, sharing vertices and targets.
        let primitives = json["meshes"][0]["primitives"].as_array().unwrap();
        assert_eq!(primitives.len(), 2);
        assert_eq!(
            json["materials"],
            json!([{"name": "M_Front"}, {"name": "M_Back"}])
        );
        assert_eq!(primitives[1]["material"], 1);
        assert_eq!(primitives[1]["attributes"], prim["attributes"]);
        assert_eq!(primitives[1]["targets"], prim["targets"]);
        let back = &json["accessors"][primitives[1]["indices"].as_u64().unwrap() as usize];
        assert_eq!(
            (back["byteOffset"].as_u64(), back["count"].as_u64()),
            (Some(12), Some(3))
        );
        assert_eq!(json["meshes"][0]["weights"], json!([1.0, 0.0, 0.0]));
        let accessor = |i: &Value| json["accessors"][i.as_u64().unwrap() as usize].clone();
        let view_offset = |a: &Value| {
            json["bufferViews"][a["bufferView"].as_u64().unwrap() as usize]["byteOffset"]
                .as_u64()
                .unwrap()
                + a["byteOffset"].as_u64().unwrap_or(0)
        };
        // The UV seam splits render vertex 0 in two: glTF vertices 0 and 3 are its copies,
        // render vertex 3 is glTF vertex 4.
        let uv = accessor(&prim["attributes"]["TEXCOORD_0"]);
        assert_eq!(uv["count"], 5);
        let uv_at = |k: usize| {
            let o = view_offset(&uv) as usize + 8 * k;
            [f32_at(&bin, o), f32_at(&bin, o + 4)]
        };
        assert_eq!(uv_at(3), [0.75, 0.0], "v flipped to glTF's top-left origin");
        assert_eq!(uv_at(0), [0.0, 1.0]);
        // Target 2: render vertex 3 lifted 2 cm = 0.02 m in z, both copies of vertex 0 by
        // 0.5 cm, so the seam stays closed.
        let t2 = accessor(&prim["targets"][2]["POSITION"]);
        let z = |k: usize| f32_at(&bin, view_offset(&t2) as usize + k * 12 + 8);
        assert!((z(4) - 0.02).abs() < 1e-7);
        assert_eq!(t2["max"][2].as_f64().unwrap(), z(4) as f64);
        assert_eq!(z(0), z(3));
        assert!((z(0) - 0.005).abs() < 1e-7);
        // Base positions in metres.
        let base = accessor(&prim["attributes"]["POSITION"]);
        assert!((f32_at(&bin, view_offset(&base) as usize + 12) - 0.01).abs() < 1e-9);
        // Keys at 0, 0.1, 0.2 s; at key 1 only target 1 is on.
        let sampler = &json["animations"][0]["samplers"][0];
        let times = accessor(&sampler["input"]);
        assert_eq!(times["count"], 3);
        assert!((f32_at(&bin, view_offset(&times) as usize + 4) - 0.1).abs() < 1e-7);
        let weights = accessor(&sampler["output"]);
        assert_eq!(weights["count"], 9);
        let row: Vec<f32> = (0..3)
            .map(|j| f32_at(&bin, view_offset(&weights) as usize + 4 * (3 + j)))
            .collect();
        assert_eq!(row, [0.0, 1.0, 0.0]);

        // A track that would pass 4 GiB is refused before anything is simulated.
        let big = GltfWriter::create(&path, &scratch, &mesh, 0, 40_000, 30.0, "test");
        assert!(matches!(big, Err(ExportError::TooLarge { .. })));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
