//! Wavefront OBJ reading and writing for the face rig: positions, polygon faces (quads kept),
//! texture coordinates with per-corner indices and `usemtl` material groups.
//!
//! The reader keeps the file's vertex order exactly (vertex `i` of the mesh is the `i`-th `v`
//! line), which the rig relies on: every shape of a blendshape rig is the same vertex list in
//! the same order. General-purpose loaders such as `tobj` re-index vertices per object/material
//! in order of first use and drop unused ones, so they cannot be used here.
//!
//! Supported: `v x y z [w]` (extra values such as vertex colours ignored), `vt u v [w]`,
//! `f` with `v`, `v/vt`, `v//vn` or `v/vt/vn` corners (1-based or negative, relative indices),
//! `usemtl`, `mtllib`. Normals (`vn`), groups (`g`, `o`), smoothing (`s`), comments and unknown
//! keywords are ignored. Either every face corner has a texture index or none does.

use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};

use nalgebra::Point3;

/// What is wrong with an OBJ file, and where.
#[derive(Debug, thiserror::Error)]
pub enum ObjError {
    #[error("{path}: cannot read: {source}", path = path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: cannot write: {source}", path = path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}, line {line}: {problem}", path = path.display())]
    Syntax {
        path: PathBuf,
        line: usize,
        problem: ObjProblem,
    },
}

/// A problem on one line of an OBJ file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ObjProblem {
    #[error("`{keyword}` needs {needed} numbers, found {found}")]
    TooFewValues {
        keyword: &'static str,
        needed: usize,
        found: usize,
    },
    #[error("`{token}` is not a number")]
    BadNumber { token: String },
    #[error("non-finite value `{token}`")]
    NonFinite { token: String },
    #[error("`{token}` is not a face corner (v, v/vt, v//vn or v/vt/vn)")]
    BadCorner { token: String },
    #[error("a face needs at least 3 corners, found {found}")]
    FaceTooSmall { found: usize },
    #[error("face repeats vertex {vertex}")]
    RepeatedVertex { vertex: usize },
    #[error("{what} index {index} is out of range (the file has {count})")]
    IndexOutOfRange {
        what: &'static str,
        index: i64,
        count: usize,
    },
    #[error("some faces have texture coordinates and some do not")]
    MixedTextureIndices,
    #[error("the file is not valid UTF-8")]
    NotUtf8,
}

/// Polygons in compressed-row form: polygon `i` is `indices[offsets[i]..offsets[i + 1]]`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Polygons {
    offsets: Vec<u32>,
    indices: Vec<u32>,
}

impl Polygons {
    pub fn new() -> Self {
        Self {
            offsets: vec![0],
            indices: Vec::new(),
        }
    }

    /// Polygons from a list of corner lists (each of length ≥ 3).
    pub fn from_lists<P: AsRef<[u32]>>(lists: &[P]) -> Self {
        let mut p = Self::new();
        for l in lists {
            p.push(l.as_ref());
        }
        p
    }

    pub fn push(&mut self, corners: &[u32]) {
        self.indices.extend_from_slice(corners);
        self.offsets.push(self.indices.len() as u32);
    }

    /// Number of polygons.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn get(&self, i: usize) -> &[u32] {
        &self.indices[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    pub fn iter(&self) -> impl ExactSizeIterator<Item = &[u32]> + '_ {
        self.offsets
            .windows(2)
            .map(|w| &self.indices[w[0] as usize..w[1] as usize])
    }

    /// All corners of all polygons, in order.
    pub fn corners(&self) -> &[u32] {
        &self.indices
    }

    /// Offset of polygon `i`'s first corner in [`Self::corners`].
    pub fn offset(&self, i: usize) -> usize {
        self.offsets[i] as usize
    }

    /// Fan triangulation `(c0, c_k, c_{k+1})`, k = 1..n−2, of every polygon: a quad `abcd`
    /// becomes `abc` and `acd`. The split depends only on the topology, so every pose of a rig
    /// is triangulated identically. Returns the triangles and, for each, its polygon's index.
    pub fn triangulate(&self) -> (Vec<[u32; 3]>, Vec<u32>) {
        let mut tris = Vec::with_capacity(self.indices.len());
        let mut source = Vec::with_capacity(self.indices.len());
        for (f, poly) in self.iter().enumerate() {
            for k in 1..poly.len().saturating_sub(1) {
                tris.push([poly[0], poly[k], poly[k + 1]]);
                source.push(f as u32);
            }
        }
        (tris, source)
    }
}

/// A `usemtl` material group: faces `first_face..` up to the next group's first face.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MaterialGroup {
    pub name: String,
    pub first_face: usize,
}

/// A polygon mesh as stored in an OBJ file (units as in the file; the rig uses cm).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ObjMesh {
    /// Vertex positions in file order.
    pub positions: Vec<Point3<f64>>,
    /// Texture coordinates `(u, v)` in file order.
    pub uvs: Vec<[f64; 2]>,
    /// Faces as 0-based vertex indices, corners in file order.
    pub faces: Polygons,
    /// Per-corner 0-based texture indices aligned with `faces.corners()`; `None` when the file
    /// has none.
    pub corner_uvs: Option<Vec<u32>>,
    pub material_groups: Vec<MaterialGroup>,
    /// The `mtllib` file name, if any.
    pub mtllib: Option<String>,
}

impl ObjMesh {
    /// Reads and parses an OBJ file.
    pub fn read(path: impl AsRef<Path>) -> Result<Self, ObjError> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|source| ObjError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let text = std::str::from_utf8(&bytes).map_err(|e| {
            let line = 1 + bytes[..e.valid_up_to()]
                .iter()
                .filter(|&&b| b == b'\n')
                .count();
            ObjError::Syntax {
                path: path.to_path_buf(),
                line,
                problem: ObjProblem::NotUtf8,
            }
        })?;
        Self::parse(text).map_err(|(line, problem)| ObjError::Syntax {
            path: path.to_path_buf(),
            line,
            problem,
        })
    }

    /// Parses OBJ text; an error carries its 1-based line number.
    pub fn parse(text: &str) -> Result<Self, (usize, ObjProblem)> {
        let mut mesh = ObjMesh {
            faces: Polygons::new(),
            ..Default::default()
        };
        let mut corner_uvs: Vec<u32> = Vec::new();
        // Whether faces carry texture indices, fixed by the first face.
        let mut faces_have_uvs: Option<bool> = None;
        // Line of each face, to report out-of-range indices found after the whole file is read
        // (positive indices may refer to vertices defined later).
        let mut face_lines: Vec<u32> = Vec::new();
        let mut corner = Vec::with_capacity(8);
        let mut corner_uv = Vec::with_capacity(8);

        for (line_idx, raw) in text.lines().enumerate() {
            let line_no = line_idx + 1;
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let mut tokens = line.split_ascii_whitespace();
            let Some(keyword) = tokens.next() else {
                continue;
            };
            let err = |p| (line_no, p);
            match keyword {
                "v" => {
                    let xyz = parse_numbers::<3>(&mut tokens, "v").map_err(err)?;
                    mesh.positions.push(Point3::from(xyz));
                }
                "vt" => {
                    let uv = parse_numbers::<2>(&mut tokens, "vt").map_err(err)?;
                    mesh.uvs.push(uv);
                }
                "f" => {
                    corner.clear();
                    corner_uv.clear();
                    for token in tokens {
                        let (v, vt) = parse_corner(token).map_err(err)?;
                        corner.push(resolve_index(v, mesh.positions.len(), "vertex").map_err(err)?);
                        if let Some(vt) = vt {
                            corner_uv
                                .push(resolve_index(vt, mesh.uvs.len(), "texture").map_err(err)?);
                        }
                    }
                    if corner.len() < 3 {
                        return Err(err(ObjProblem::FaceTooSmall {
                            found: corner.len(),
                        }));
                    }
                    let has_uvs = !corner_uv.is_empty();
                    if has_uvs && corner_uv.len() != corner.len() {
                        return Err(err(ObjProblem::MixedTextureIndices));
                    }
                    match faces_have_uvs {
                        None => faces_have_uvs = Some(has_uvs),
                        Some(h) if h != has_uvs => {
                            return Err(err(ObjProblem::MixedTextureIndices));
                        }
                        Some(_) => {}
                    }
                    for i in 0..corner.len() {
                        if corner[i + 1..].contains(&corner[i]) {
                            return Err(err(ObjProblem::RepeatedVertex {
                                vertex: corner[i] as usize,
                            }));
                        }
                    }
                    mesh.faces.push(&corner);
                    corner_uvs.extend_from_slice(&corner_uv);
                    face_lines.push(line_no as u32);
                }
                "usemtl" => mesh.material_groups.push(MaterialGroup {
                    name: rest_of_line(line, keyword),
                    first_face: mesh.faces.len(),
                }),
                "mtllib" => mesh.mtllib = Some(rest_of_line(line, keyword)),
                _ => {}
            }
        }

        // Positive indices were only checked to be ≥ 1; check them against the final counts.
        for (f, poly) in mesh.faces.iter().enumerate() {
            let line = face_lines[f] as usize;
            let start = mesh.faces.offset(f);
            for (k, &v) in poly.iter().enumerate() {
                if v as usize >= mesh.positions.len() {
                    return Err((
                        line,
                        ObjProblem::IndexOutOfRange {
                            what: "vertex",
                            index: v as i64 + 1,
                            count: mesh.positions.len(),
                        },
                    ));
                }
                if let Some(&t) = corner_uvs.get(start + k)
                    && t as usize >= mesh.uvs.len()
                {
                    return Err((
                        line,
                        ObjProblem::IndexOutOfRange {
                            what: "texture",
                            index: t as i64 + 1,
                            count: mesh.uvs.len(),
                        },
                    ));
                }
            }
        }
        if faces_have_uvs == Some(true) {
            mesh.corner_uvs = Some(corner_uvs);
        }
        Ok(mesh)
    }

    /// Triangles of [`Self::faces`] (see [`Polygons::triangulate`]).
    pub fn triangles(&self) -> Vec<[u32; 3]> {
        self.faces.triangulate().0
    }

    /// Writes the mesh as OBJ text: `mtllib`, `v`, `vt`, then faces (`f v/vt` when texture
    /// indices exist) with `usemtl` lines at the group starts. Coordinates are printed in
    /// Rust's shortest round-trip form, so reading the text back gives identical numbers.
    pub fn to_obj_string(&self, header: &str) -> String {
        let mut s = String::with_capacity(64 * (self.positions.len() + self.uvs.len()));
        for l in header.lines() {
            let _ = writeln!(s, "# {l}");
        }
        if let Some(lib) = &self.mtllib {
            let _ = writeln!(s, "mtllib {lib}");
        }
        for p in &self.positions {
            let _ = writeln!(s, "v {} {} {}", p.x, p.y, p.z);
        }
        for t in &self.uvs {
            let _ = writeln!(s, "vt {} {}", t[0], t[1]);
        }
        let mut groups = self.material_groups.iter().peekable();
        for (f, poly) in self.faces.iter().enumerate() {
            while let Some(g) = groups.next_if(|g| g.first_face <= f) {
                let _ = writeln!(s, "usemtl {}", g.name);
            }
            s.push('f');
            let start = self.faces.offset(f);
            for (k, &v) in poly.iter().enumerate() {
                match &self.corner_uvs {
                    Some(t) => {
                        let _ = write!(s, " {}/{}", v + 1, t[start + k] + 1);
                    }
                    None => {
                        let _ = write!(s, " {}", v + 1);
                    }
                }
            }
            s.push('\n');
        }
        for g in groups {
            let _ = writeln!(s, "usemtl {}", g.name);
        }
        s
    }

    /// Writes the mesh to `path` (see [`Self::to_obj_string`]).
    pub fn write(&self, path: impl AsRef<Path>, header: &str) -> Result<(), ObjError> {
        let path = path.as_ref();
        let write_err = |source| ObjError::Write {
            path: path.to_path_buf(),
            source,
        };
        let mut file = std::io::BufWriter::new(std::fs::File::create(path).map_err(write_err)?);
        file.write_all(self.to_obj_string(header).as_bytes())
            .map_err(write_err)?;
        file.flush().map_err(write_err)
    }
}

fn rest_of_line(line: &str, keyword: &str) -> String {
    line[keyword.len()..].trim().to_string()
}

/// The first `N` numbers after a keyword (more are allowed and ignored).
fn parse_numbers<'a, const N: usize>(
    tokens: &mut impl Iterator<Item = &'a str>,
    keyword: &'static str,
) -> Result<[f64; N], ObjProblem> {
    let mut out = [0.0; N];
    for (i, slot) in out.iter_mut().enumerate() {
        let Some(token) = tokens.next() else {
            return Err(ObjProblem::TooFewValues {
                keyword,
                needed: N,
                found: i,
            });
        };
        let value: f64 = token.parse().map_err(|_| ObjProblem::BadNumber {
            token: token.to_string(),
        })?;
        if !value.is_finite() {
            return Err(ObjProblem::NonFinite {
                token: token.to_string(),
            });
        }
        *slot = value;
    }
    Ok(out)
}

/// Splits a face corner `v[/vt[/vn]]` into its (signed, 1-based) vertex and texture indices.
fn parse_corner(token: &str) -> Result<(i64, Option<i64>), ObjProblem> {
    let bad = || ObjProblem::BadCorner {
        token: token.to_string(),
    };
    let bytes = token.as_bytes();
    let (v, rest) = parse_int(bytes).ok_or_else(bad)?;
    let Some(rest) = rest.strip_prefix(b"/") else {
        return if rest.is_empty() {
            Ok((v, None))
        } else {
            Err(bad())
        };
    };
    // `v//vn`: no texture index.
    let (vt, rest) = if rest.first() == Some(&b'/') {
        (None, rest)
    } else {
        let (vt, rest) = parse_int(rest).ok_or_else(bad)?;
        (Some(vt), rest)
    };
    match rest.strip_prefix(b"/") {
        None if rest.is_empty() => Ok((v, vt)),
        Some(vn) if parse_int(vn).is_some_and(|(_, r)| r.is_empty()) => Ok((v, vt)),
        _ => Err(bad()),
    }
}

/// A leading optionally signed decimal integer and the bytes after it.
fn parse_int(bytes: &[u8]) -> Option<(i64, &[u8])> {
    let (negative, digits) = match bytes.first() {
        Some(b'-') => (true, &bytes[1..]),
        Some(b'+') => (false, &bytes[1..]),
        _ => (false, bytes),
    };
    let len = digits.iter().take_while(|b| b.is_ascii_digit()).count();
    if len == 0 || len > 18 {
        return None;
    }
    let value = digits[..len]
        .iter()
        .fold(0i64, |acc, &d| acc * 10 + i64::from(d - b'0'));
    Some((if negative { -value } else { value }, &digits[len..]))
}

/// OBJ index → 0-based: `i − 1` for `i ≥ 1`, `count + i` for `i < 0` (relative to the
/// elements defined so far). Positive indices are range-checked after the whole file is read.
fn resolve_index(index: i64, count_so_far: usize, what: &'static str) -> Result<u32, ObjProblem> {
    let out_of_range = || ObjProblem::IndexOutOfRange {
        what,
        index,
        count: count_so_far,
    };
    let resolved = if index > 0 {
        index - 1
    } else if index < 0 {
        count_so_far as i64 + index
    } else {
        return Err(out_of_range());
    };
    if resolved < 0 || resolved > u32::MAX as i64 {
        return Err(out_of_range());
    }
    Ok(resolved as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    const SQUARE: &str = "\
# a unit square made of a quad and a triangle
mtllib m.mtl
v 0 0 0
v 1 0 0
v 1 1 0 0.5 0.5 0.5
v 0 1 0
v 2 0.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
usemtl A
f 1/1/1 2/2/1 3/3/1 4/4/1
usemtl B
f 2/2 5/3 -3/4
";

    #[test]
    fn parses_positions_quads_uvs_and_groups_in_file_order() {
        let m = ObjMesh::parse(SQUARE).unwrap();
        assert_eq!(m.positions.len(), 5);
        assert_eq!(m.positions[2], Point3::new(1.0, 1.0, 0.0));
        assert_eq!(m.positions[4], Point3::new(2.0, 0.5, 0.0));
        assert_eq!(m.uvs.len(), 4);
        assert_eq!(m.faces.len(), 2);
        assert_eq!(m.faces.get(0), &[0, 1, 2, 3]);
        // `-3` is relative to the 5 vertices defined so far: vertex 3 (0-based 2).
        assert_eq!(m.faces.get(1), &[1, 4, 2]);
        assert_eq!(m.corner_uvs.as_deref(), Some(&[0, 1, 2, 3, 1, 2, 3][..]));
        assert_eq!(m.mtllib.as_deref(), Some("m.mtl"));
        assert_eq!(
            m.material_groups,
            vec![
                MaterialGroup {
                    name: "A".into(),
                    first_face: 0
                },
                MaterialGroup {
                    name: "B".into(),
                    first_face: 1
                }
            ]
        );
    }

    #[test]
    fn fan_triangulation_keeps_polygon_sources() {
        let m = ObjMesh::parse(SQUARE).unwrap();
        let (tris, src) = m.faces.triangulate();
        assert_eq!(tris, vec![[0, 1, 2], [0, 2, 3], [1, 4, 2]]);
        assert_eq!(src, vec![0, 0, 1]);
    }

    #[test]
    fn write_then_read_round_trips_exactly() {
        let mut m = ObjMesh::parse(SQUARE).unwrap();
        m.positions[1].x = 0.1 + 0.2; // not exactly representable in short decimal form
        let text = m.to_obj_string("test\nsecond line");
        let back = ObjMesh::parse(&text).unwrap();
        assert_eq!(back, m);

        let no_uv = ObjMesh {
            corner_uvs: None,
            uvs: vec![],
            ..m.clone()
        };
        let back = ObjMesh::parse(&no_uv.to_obj_string("")).unwrap();
        assert_eq!(back, no_uv);
    }

    #[test]
    fn write_to_file_and_read_back() {
        let dir = crate::rig::test_support::temp_dir("obj_write");
        let path = dir.join("square.obj");
        let m = ObjMesh::parse(SQUARE).unwrap();
        m.write(&path, "facesim test").unwrap();
        assert_eq!(ObjMesh::read(&path).unwrap(), m);
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn problem(text: &str) -> (usize, ObjProblem) {
        ObjMesh::parse(text).unwrap_err()
    }

    #[test]
    fn errors_name_the_line_and_problem() {
        assert!(matches!(
            problem("v 0 0 0\nv 1 x 0\n"),
            (2, ObjProblem::BadNumber { token }) if token == "x"
        ));
        assert!(matches!(
            problem("v 0 0\n"),
            (
                1,
                ObjProblem::TooFewValues {
                    keyword: "v",
                    needed: 3,
                    found: 2
                }
            )
        ));
        assert!(matches!(
            problem("v 0 0 nan\n"),
            (1, ObjProblem::NonFinite { .. })
        ));
        assert_eq!(
            problem("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n"),
            (
                4,
                ObjProblem::IndexOutOfRange {
                    what: "vertex",
                    index: 4,
                    count: 3
                }
            )
        );
        assert!(matches!(
            problem("v 0 0 0\nv 1 0 0\nf 1 2\n"),
            (3, ObjProblem::FaceTooSmall { found: 2 })
        ));
        assert!(matches!(
            problem("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 0 2\n"),
            (4, ObjProblem::IndexOutOfRange { .. })
        ));
        assert!(matches!(
            problem("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\nf 1 2 3\n"),
            (6, ObjProblem::MixedTextureIndices)
        ));
        assert!(matches!(
            problem("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1\n"),
            (4, ObjProblem::RepeatedVertex { vertex: 0 })
        ));
        for corner in ["1/a", "1/1/x", "x", "1/1/1/1", "1x", "/1", "1/"] {
            assert!(
                matches!(
                    problem(&format!("v 0 0 0\nf {corner} 1 1\n")),
                    (2, ObjProblem::BadCorner { .. })
                ),
                "{corner}"
            );
        }
        assert_eq!(parse_corner("12"), Ok((12, None)));
        assert_eq!(parse_corner("-3/7"), Ok((-3, Some(7))));
        assert_eq!(parse_corner("4//9"), Ok((4, None)));
        assert_eq!(parse_corner("4/5/9"), Ok((4, Some(5))));
    }

    #[test]
    fn read_errors_name_the_file() {
        let dir = crate::rig::test_support::temp_dir("obj_errors");
        let path = dir.join("broken.obj");
        std::fs::write(&path, "v 0 0 0\nv 0 0\n").unwrap();
        let msg = ObjMesh::read(&path).unwrap_err().to_string();
        assert!(
            msg.contains("broken.obj") && msg.contains("line 2"),
            "{msg}"
        );
        let missing = ObjMesh::read(dir.join("missing.obj")).unwrap_err();
        assert!(missing.to_string().contains("missing.obj"));
        std::fs::write(&path, b"v 0 0 0\n\xff\n").unwrap();
        let msg = ObjMesh::read(&path).unwrap_err().to_string();
        assert!(msg.contains("line 2") && msg.contains("UTF-8"), "{msg}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
