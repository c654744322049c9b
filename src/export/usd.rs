//! USD output as a text layer (`.usda`): one `Mesh` prim with the render surface's topology,
//! rest `points` and `normals`, the rig's texture coordinates as `primvars:st` (face-varying,
//! indexed), one `GeomSubset` per part (the rig's material groups), and time samples of `points`, `normals` and `extent` at every
//! frame (`timeCodesPerSecond` = the export's fps, time code = frame number; a range of a
//! track's frames keeps their numbers).
//!
//! Units: centimetres, declared with `metersPerUnit = 0.01`; Y is up. Points are printed to
//! 1e-5 cm (0.1 µm), normals to 1e-4.
//!
//! Streaming: `points` samples go straight to the file; `normals` samples, which USD lists after
//! all of the points' samples, go to a scratch file that is appended at the end; the extents
//! (six numbers a frame) are kept in memory.

use std::path::Path;

use super::{ExportError, ExportMesh, Format, FrameSink, Out, check_sizes};
use crate::session::Frame;

/// Streams frames into a `.usda` layer.
pub struct UsdWriter {
    out: Out,
    normals: Out,
    normals_path: std::path::PathBuf,
    vertices: usize,
    /// The first frame's number (its time code).
    first: usize,
    frames: usize,
    written: usize,
    extents: Vec<[[f32; 3]; 2]>,
    line: String,
    /// The parts' `GeomSubset` children, written after the mesh's attributes.
    subsets: String,
}

/// Appends `v` rounded to `decimals` places (`-12.34560`). Hand-rolled because float
/// formatting was most of the export's time: this is the bulk of a `.usda`.
fn push_fixed(s: &mut String, v: f32, decimals: usize) {
    const POW10: [f64; 10] = [1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9];
    let scaled = (v as f64 * POW10[decimals]).round_ties_even();
    if !scaled.is_finite() || scaled.abs() >= 9e15 {
        // Not reached for frames (finite, centimetres); kept correct anyway.
        use std::fmt::Write as _;
        let _ = write!(s, "{v:.decimals$}");
        return;
    }
    let mut n = scaled.abs() as u64;
    if scaled < 0.0 {
        s.push('-');
    }
    let mut digits = [0u8; 24];
    let mut len = 0;
    while len <= decimals + usize::from(decimals > 0) || n > 0 {
        if len == decimals && decimals > 0 {
            digits[len] = b'.';
            len += 1;
            continue;
        }
        digits[len] = b'0' + (n % 10) as u8;
        n /= 10;
        len += 1;
    }
    for &d in digits[..len].iter().rev() {
        s.push(d as char);
    }
}

fn push_vec(s: &mut String, v: &[f32; 3], decimals: usize) {
    s.push('(');
    push_fixed(s, v[0], decimals);
    s.push_str(", ");
    push_fixed(s, v[1], decimals);
    s.push_str(", ");
    push_fixed(s, v[2], decimals);
    s.push(')');
}

fn array(values: &[[f32; 3]], decimals: usize) -> String {
    let mut s = String::with_capacity(values.len() * 32 + 2);
    s.push('[');
    for (i, v) in values.iter().enumerate() {
        if i > 0 {
            s.push_str(", ");
        }
        push_vec(&mut s, v, decimals);
    }
    s.push(']');
    s
}

/// The texture coordinates as USD's `primvars:st` (face-varying, indexed by corner).
fn primvar_st(uv: &crate::model::UvLayout) -> String {
    let mut s = String::with_capacity(uv.coords.len() * 24 + uv.triangles.len() * 24 + 160);
    s.push_str("        texCoord2f[] primvars:st = [");
    for (i, [u, v]) in uv.coords.iter().enumerate() {
        if i > 0 {
            s.push_str(", ");
        }
        s.push('(');
        push_fixed(&mut s, *u, UV_DECIMALS);
        s.push_str(", ");
        push_fixed(&mut s, *v, UV_DECIMALS);
        s.push(')');
    }
    s.push_str("] (\n            interpolation = \"faceVarying\"\n        )\n");
    s.push_str("        int[] primvars:st:indices = [");
    for (i, c) in uv.triangles.iter().flatten().enumerate() {
        if i > 0 {
            s.push_str(", ");
        }
        s.push_str(&c.to_string());
    }
    s.push_str("]\n");
    s
}

/// One `GeomSubset` per part (the rig's material groups), in the `materialBind` family, so
/// an artist binds a material to each: `/Face/Surface/M_Face`, `/Face/Surface/M_Teeth`, ….
fn subsets(parts: &[crate::model::Part]) -> String {
    let mut s = String::new();
    for part in parts {
        let name: String = part
            .name
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let name = if name.starts_with(|c: char| c.is_ascii_digit()) || name.is_empty() {
            format!("_{name}")
        } else {
            name
        };
        let indices: Vec<String> = part.triangles.clone().map(|t| t.to_string()).collect();
        s.push_str(&format!(
            "\n        def GeomSubset \"{name}\"\n        {{\n            uniform token elementType = \"face\"\n            \
             uniform token familyName = \"materialBind\"\n            int[] indices = [{}]\n        }}\n",
            indices.join(", ")
        ));
    }
    s
}

/// A USD `extent`: the points' bounds.
fn extent(points: &[[f32; 3]]) -> [[f32; 3]; 2] {
    crate::geometry::bounds_f32(points.iter().copied())
}

const POINT_DECIMALS: usize = 5;
const NORMAL_DECIMALS: usize = 4;
/// Texture coordinates to 1e-6 (a 4k texture's texel is 2.4e-4).
const UV_DECIMALS: usize = 6;

impl UsdWriter {
    /// Starts the layer at `path` (the normals' scratch file at `normals_scratch`) for frames
    /// `first..first + frames` (their frame numbers are their time codes).
    pub fn create(
        path: &Path,
        normals_scratch: &Path,
        mesh: &ExportMesh,
        first: usize,
        frames: usize,
        fps: f64,
        comment: &str,
    ) -> Result<Self, ExportError> {
        let mut out = Out::create(path)?;
        let counts = vec!["3"; mesh.triangles.len()].join(", ");
        let indices = mesh
            .triangles
            .iter()
            .flatten()
            .map(|i| i.to_string())
            .collect::<Vec<_>>()
            .join(", ");
        let rest_extent = extent(&mesh.rest);
        let st = mesh.uv.as_ref().map_or(String::new(), primvar_st);
        let family = if mesh.parts.is_empty() {
            ""
        } else {
            "        uniform token subsetFamily:materialBind:familyType = \"partition\"\n"
        };
        let header = format!(
            "#usda 1.0\n(\n    defaultPrim = \"Face\"\n    doc = \"{doc}\"\n    metersPerUnit = 0.01\n    upAxis = \"Y\"\n    \
             timeCodesPerSecond = {fps}\n    framesPerSecond = {fps}\n    startTimeCode = {first}\n    endTimeCode = {end}\n)\n\n\
             def Xform \"Face\" (\n    kind = \"component\"\n)\n{{\n    def Mesh \"Surface\"\n    {{\n        \
             uniform token subdivisionScheme = \"none\"\n        uniform token orientation = \"rightHanded\"\n        \
             int[] faceVertexCounts = [{counts}]\n        int[] faceVertexIndices = [{indices}]\n        \
             float3[] extent = {rest_extent}\n{st}{family}        normal3f[] normals = {rest_normals} (\n            interpolation = \"vertex\"\n        )\n        \
             point3f[] points = {rest_points}\n        point3f[] points.timeSamples = {{\n",
            doc = comment.replace('"', "'"),
            end = (first + frames).saturating_sub(1),
            rest_extent = array(&rest_extent, POINT_DECIMALS),
            rest_normals = array(&mesh.rest_normals, NORMAL_DECIMALS),
            rest_points = array(&mesh.rest, POINT_DECIMALS),
        );
        out.write_all(header.as_bytes())?;
        Ok(UsdWriter {
            out,
            normals: Out::create(normals_scratch)?,
            normals_path: normals_scratch.to_path_buf(),
            vertices: mesh.vertex_count(),
            first,
            frames,
            written: 0,
            extents: Vec::with_capacity(frames),
            line: String::new(),
            subsets: subsets(&mesh.parts),
        })
    }

    pub fn write_frame(
        &mut self,
        positions: &[[f32; 3]],
        normals: &[[f32; 3]],
    ) -> Result<(), ExportError> {
        check_sizes(Format::Usd, self.vertices, positions, normals)?;
        if self.written >= self.frames {
            return Err(ExportError::Writer {
                format: Format::Usd,
                reason: format!("more than the {} frames announced", self.frames),
            });
        }
        let k = self.first + self.written;
        self.line.clear();
        self.line.push_str(&format!("            {k}: "));
        self.line.push_str(&array(positions, POINT_DECIMALS));
        self.line.push_str(",\n");
        let line = std::mem::take(&mut self.line);
        self.out.write_all(line.as_bytes())?;
        let normals_line = format!("            {k}: {},\n", array(normals, NORMAL_DECIMALS));
        self.normals.write_all(normals_line.as_bytes())?;
        self.line = line;
        self.extents.push(extent(positions));
        self.written += 1;
        Ok(())
    }

    pub fn finish(mut self) -> Result<(), ExportError> {
        if self.written != self.frames {
            return Err(ExportError::Writer {
                format: Format::Usd,
                reason: format!("{} of {} frames written", self.written, self.frames),
            });
        }
        self.out
            .write_all(b"        }\n        normal3f[] normals.timeSamples = {\n")?;
        self.normals.close()?;
        let mut scratch = std::fs::File::open(&self.normals_path)
            .map_err(|e| ExportError::io(&self.normals_path, e))?;
        std::io::copy(&mut scratch, &mut self.out.w)
            .map_err(|e| ExportError::io(&self.out.path, e))?;
        let mut tail = String::from("        }\n        float3[] extent.timeSamples = {\n");
        for (k, e) in self.extents.iter().enumerate() {
            let k = self.first + k;
            tail.push_str(&format!("            {k}: {},\n", array(e, POINT_DECIMALS)));
        }
        tail.push_str("        }\n");
        tail.push_str(&self.subsets);
        tail.push_str("    }\n}\n");
        self.out.write_all(tail.as_bytes())?;
        self.out.close()
    }
}

impl FrameSink for UsdWriter {
    fn frame(&mut self, _index: usize, frame: &Frame) -> Result<(), ExportError> {
        self.write_frame(&frame.positions, &frame.normals)
    }
    fn finish(self: Box<Self>) -> Result<(), ExportError> {
        UsdWriter::finish(*self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::test_mesh;

    #[test]
    fn fixed_point_numbers_match_rust_formatting() {
        for v in [
            0.0f32, 1.0, -1.0, 0.5, -0.000004, 0.000006, 12.345678, -7.89, 123456.79, 0.1,
        ] {
            for d in [0, 4, 5] {
                let mut s = String::new();
                push_fixed(&mut s, v, d);
                let expected = format!("{v:.d$}");
                let expected = if expected
                    .trim_start_matches('-')
                    .bytes()
                    .all(|b| b == b'0' || b == b'.')
                {
                    expected.trim_start_matches('-').to_string()
                } else {
                    expected
                };
                assert_eq!(s, expected, "{v} at {d} decimals");
            }
        }
    }

    #[test]
    fn a_layer_has_topology_and_one_time_sample_per_frame() {
        let dir = std::env::temp_dir().join(format!("facesim-usd-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (path, scratch) = (dir.join("a.usda"), dir.join("a.normals"));
        let mesh = test_mesh::square();
        let mut w = UsdWriter::create(&path, &scratch, &mesh, 0, 3, 24.0, "test").unwrap();
        for k in 0..3 {
            let (p, n) = test_mesh::frame(&mesh, k);
            w.write_frame(&p, &n).unwrap();
        }
        w.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        for needle in [
            "metersPerUnit = 0.01",
            "timeCodesPerSecond = 24",
            "endTimeCode = 2",
            "int[] faceVertexCounts = [3, 3]",
            "int[] faceVertexIndices = [0, 1, 2, 0, 2, 3]",
            // Frame 2, vertex 3 is lifted by 0.25·2·4 = 2 cm.
            "2: [(0.00000, 0.00000, 0.50000), (1.00000, 0.00000, 1.00000), (1.00000, 1.00000, 1.50000), (0.00000, 1.00000, 2.00000)]",
            "2: [(0.1987, 0.0000, 0.9801)",
            "2: [(0.00000, 0.00000, 0.50000), (1.00000, 1.00000, 2.00000)]",
        ] {
            assert!(text.contains(needle), "missing {needle}:\n{text}");
        }
        assert_eq!(
            text.matches("            1: ").count(),
            3,
            "points, normals, extent"
        );
        // Balanced braces: the layer closes.
        assert_eq!(text.matches('{').count(), text.matches('}').count());

        // A range of a track's frames keeps their numbers as time codes.
        let mut w = UsdWriter::create(&path, &scratch, &mesh, 10, 2, 24.0, "test").unwrap();
        for k in 10..12 {
            let (p, n) = test_mesh::frame(&mesh, k);
            w.write_frame(&p, &n).unwrap();
        }
        w.finish().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("startTimeCode = 10") && text.contains("endTimeCode = 11"));
        assert_eq!(text.matches("            11: ").count(), 3);
        assert_eq!(text.matches("            1: ").count(), 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
