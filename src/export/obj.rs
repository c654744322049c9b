//! Wavefront OBJ output: positions, normals, the rig's texture coordinates and triangles
//! (`f a/ta/a b/tb/b c/tc/c`, or `f a//a …` without UVs) under a `usemtl` line per part (the
//! rig's material names; one object, so the vertex order stays the PC2 cache's), one file per
//! frame for OBJ sequences and the rest pose beside PC2 caches. Numbers are printed in their
//! shortest round-trip form, so reading a file back gives the frame's exact `f32` values.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use super::{ExportError, ExportMesh, Format, FrameSink, Out, check_sizes};
use crate::model::{Part, UvLayout};
use crate::session::Frame;

/// Writes one OBJ file (cm; `comment` becomes `#` lines at the top).
pub fn write_obj(
    path: &Path,
    comment: &str,
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    triangles: &[[u32; 3]],
    uv: Option<&UvLayout>,
    parts: &[Part],
) -> Result<(), ExportError> {
    let mut s = String::with_capacity(40 * (3 * positions.len() + triangles.len()));
    for line in comment.lines() {
        let _ = writeln!(s, "# {line}");
    }
    for p in positions {
        let _ = writeln!(s, "v {} {} {}", p[0], p[1], p[2]);
    }
    for n in normals {
        let _ = writeln!(s, "vn {} {} {}", n[0], n[1], n[2]);
    }
    if let Some(uv) = uv {
        for [u, v] in &uv.coords {
            let _ = writeln!(s, "vt {u} {v}");
        }
    }
    let mut parts = parts.iter().peekable();
    for (k, t) in triangles.iter().enumerate() {
        if let Some(part) = parts.next_if(|p| p.triangles.start as usize == k) {
            let _ = writeln!(s, "usemtl {}", part.name);
        }
        let [a, b, c] = t.map(|i| i + 1);
        match uv {
            Some(uv) => {
                let [ta, tb, tc] = uv.triangles[k].map(|i| i + 1);
                let _ = writeln!(s, "f {a}/{ta}/{a} {b}/{tb}/{b} {c}/{tc}/{c}");
            }
            None => {
                let _ = writeln!(s, "f {a}//{a} {b}//{b} {c}//{c}");
            }
        }
    }
    let mut out = Out::create(path)?;
    out.write_all(s.as_bytes())?;
    out.close()
}

/// The name of frame `index`'s file: `NAME_0007.obj` (at least 4 digits, more when `frames`
/// needs them, so the names sort in frame order).
pub fn frame_file_name(name: &str, index: usize, frames: usize) -> String {
    let digits = (frames.saturating_sub(1)).to_string().len().max(4);
    format!("{name}_{index:0digits$}.obj")
}

/// One OBJ per frame into a folder.
pub struct ObjSequenceSink {
    dir: PathBuf,
    name: String,
    frames: usize,
    triangles: Vec<[u32; 3]>,
    uv: Option<UvLayout>,
    parts: Vec<Part>,
    vertices: usize,
    fps: f64,
}

impl ObjSequenceSink {
    pub fn create(
        dir: &Path,
        name: &str,
        mesh: &ExportMesh,
        frames: usize,
        fps: f64,
    ) -> Result<Self, ExportError> {
        std::fs::create_dir_all(dir).map_err(|e| ExportError::io(dir, e))?;
        Ok(ObjSequenceSink {
            dir: dir.to_path_buf(),
            name: name.to_string(),
            frames,
            triangles: mesh.triangles.clone(),
            uv: mesh.uv.clone(),
            parts: mesh.parts.clone(),
            vertices: mesh.vertex_count(),
            fps,
        })
    }
}

impl FrameSink for ObjSequenceSink {
    fn frame(&mut self, index: usize, frame: &Frame) -> Result<(), ExportError> {
        check_sizes(Format::Obj, self.vertices, &frame.positions, &frame.normals)?;
        let path = self
            .dir
            .join(frame_file_name(&self.name, index, self.frames));
        let comment = format!(
            "facesim export: frame {index} of {}, t = {:.6} s, cm",
            self.frames,
            index as f64 / self.fps
        );
        write_obj(
            &path,
            &comment,
            &frame.positions,
            &frame.normals,
            &self.triangles,
            self.uv.as_ref(),
            &self.parts,
        )
    }
    fn finish(self: Box<Self>) -> Result<(), ExportError> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::test_mesh;
    use crate::rig::obj::ObjMesh;

    #[test]
    fn an_obj_reads_back_exactly_with_the_rig_reader() {
        let dir = std::env::temp_dir().join(format!("facesim-obj-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(frame_file_name("a", 3, 12));
        assert!(path.ends_with("a_0003.obj"));
        assert_eq!(frame_file_name("a", 7, 12_000), "a_00007.obj");
        let mesh = test_mesh::square();
        let (p, n) = test_mesh::frame(&mesh, 3);
        write_obj(&path, "two\nlines", &p, &n, &mesh.triangles, None, &[]).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("# two\n# lines\n"));
        assert_eq!(text.matches("\nvn ").count(), 4);
        assert!(text.contains("f 1//1 3//3 4//4"));
        assert!(!text.contains("\nvt "));
        let back = ObjMesh::read(&path).unwrap();
        assert_eq!(back.triangles(), mesh.triangles);
        for (a, b) in back.positions.iter().zip(&p) {
            assert_eq!([a.x as f32, a.y as f32, a.z as f32], *b);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn texture_coordinates_and_parts_read_back_corner_by_corner() {
        let dir = std::env::temp_dir().join(format!("facesim-obj-uv-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("uv.obj");
        let mesh = test_mesh::square();
        let uv = mesh.uv.as_ref().unwrap();
        write_obj(
            &path,
            "",
            &mesh.rest,
            &mesh.rest_normals,
            &mesh.triangles,
            Some(uv),
            &mesh.parts,
        )
        .unwrap();
        let back = ObjMesh::read(&path).unwrap();
        let groups: Vec<(&str, usize)> = back
            .material_groups
            .iter()
            .map(|g| (g.name.as_str(), g.first_face))
            .collect();
        assert_eq!(groups, [("M_Front", 0), ("M_Back", 1)]);
        assert_eq!(back.triangles(), mesh.triangles);
        let uvs: Vec<[f32; 2]> = back.uvs.iter().map(|c| c.map(|v| v as f32)).collect();
        assert_eq!(uvs, uv.coords);
        let corners: Vec<u32> = uv.triangles.iter().flatten().copied().collect();
        assert_eq!(back.corner_uvs.unwrap(), corners);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
