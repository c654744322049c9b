//! Loading and validating the ICT-FaceKit blendshape rig, and posing it.
//!
//! A pose of identity `b` (the neutral or one of the PCA identities) under shape weights `w` is
//!
//! `x = b + Σₖ wₖ·(sₖ − n)` (cm),
//!
//! with `n` the generic neutral and `sₖ` expression shape `k` (both as stored in the rig).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use nalgebra::Point3;
use rayon::prelude::*;
use serde::Deserialize;

use super::expression::{ExpressionCode, is_known_shape};
use super::obj::{ObjError, ObjMesh, Polygons};
use super::regions::{RegionMismatch, check_regions};

/// File names inside a rig directory.
pub const NEUTRAL_FILE: &str = "generic_neutral_mesh.obj";
pub const INDEX_FILE: &str = "vertex_indices.json";

/// Why a rig could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    #[error("{path}: not a readable rig directory: {source}", path = path.display())]
    Directory {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Obj(#[from] ObjError),
    #[error("{path}: cannot read: {source}", path = path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: invalid index file: {source}", path = path.display())]
    IndexJson {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{path}: has {found} vertices, the neutral has {expected}", path = path.display())]
    VertexCount {
        path: PathBuf,
        found: usize,
        expected: usize,
    },
    #[error("{path}: faces differ from the neutral's (first at face {face})", path = path.display())]
    Topology { path: PathBuf, face: usize },
    #[error("{path}: vertex {vertex} has a non-finite coordinate", path = path.display())]
    NonFinite { path: PathBuf, vertex: usize },
    #[error("{path}: unknown expression shape `{name}` (not an ARKit shape name)", path = path.display())]
    UnknownShape { path: PathBuf, name: String },
    #[error("{path}: expression shape `{name}` is listed twice", path = path.display())]
    DuplicateShape { path: PathBuf, name: String },
    #[error("{path}: the default expression shape `{name}` is missing", path = path.display())]
    MissingDefaultShape { path: PathBuf, name: &'static str },
    #[error(
        "{path}: `{key}` holds index {index}, out of range (must be below {bound})",
        path = path.display()
    )]
    IndexOutOfRange {
        path: PathBuf,
        key: &'static str,
        index: usize,
        bound: usize,
    },
    #[error("{path}: does not match the rig's region table: {source}", path = path.display())]
    Regions {
        path: PathBuf,
        source: RegionMismatch,
    },
}

/// Index sets from `vertex_indices.json` (0-based vertex indices into the rig mesh).
#[derive(Clone, Debug, Default, PartialEq, Eq, Deserialize)]
pub struct RigIndices {
    /// Expression shapes of the rig, in the rig's order.
    pub expressions: Vec<String>,
    /// Shapes used for fitting.
    #[serde(default)]
    pub fitting_expressions: Vec<String>,
    /// Vertices that move rigidly with the skull.
    pub idx_to_rigid_verts: Vec<usize>,
    /// Vertices used for fitting.
    #[serde(default)]
    pub idx_to_fitting_verts: Vec<usize>,
    /// The 68 facial landmarks (Multi-PIE order).
    pub idx_to_landmark_verts: Vec<usize>,
    /// Vertices kept rigid by the rig's Laplacian fitting.
    #[serde(default)]
    pub idx_to_lap_rigid_verts: Vec<usize>,
    /// Positions in `idx_to_landmark_verts` of the landmarks that move rigidly.
    #[serde(default)]
    pub idx_to_rigid_landmark_idx: Vec<usize>,
}

/// Loading progress, reported once per file read (from worker threads, in any order).
#[derive(Clone, Copy, Debug)]
pub struct LoadProgress<'a> {
    /// Files read so far, this one included.
    pub done: usize,
    pub total: usize,
    /// The file just read.
    pub file: &'a Path,
}

/// A loaded, validated blendshape rig (positions in cm, +y up, +z out of the face).
#[derive(Clone, Debug)]
pub struct FaceRig {
    dir: PathBuf,
    /// The neutral mesh: positions, faces, UVs, material groups.
    mesh: ObjMesh,
    indices: RigIndices,
    /// Positions of the expression shapes, in `indices.expressions` order.
    shapes: Vec<Vec<Point3<f64>>>,
    identity_names: Vec<String>,
    identities: Vec<Vec<Point3<f64>>>,
    /// For each entry of the default code, its shape's index in `shapes`.
    code_shapes: [usize; ExpressionCode::LEN],
    load_time: Duration,
}

impl FaceRig {
    /// Loads a rig directory (see [`Self::load_with_progress`]).
    pub fn load(dir: impl AsRef<Path>) -> Result<Self, RigError> {
        Self::load_with_progress(dir, &|_| {})
    }

    /// Loads `generic_neutral_mesh.obj`, one `<name>.obj` per shape named in
    /// `vertex_indices.json`'s `expressions`, every `identityNNN.obj`, and the index sets; the
    /// OBJ files are parsed in parallel. Validates: every shape name is a known ARKit name
    /// and listed once, the 19 default-code shapes are present, every file has the neutral's
    /// vertex count, faces and finite coordinates, the neutral matches the region table, and
    /// every index is in range. `progress` is called after each file (from worker threads).
    ///
    /// Other OBJ files in the directory (e.g. ICT's `cheekRaiser_L/R`, which the index file
    /// does not list) are ignored.
    pub fn load_with_progress(
        dir: impl AsRef<Path>,
        progress: &(dyn Fn(LoadProgress<'_>) + Sync),
    ) -> Result<Self, RigError> {
        let start = Instant::now();
        let dir = dir.as_ref().to_path_buf();
        let index_path = dir.join(INDEX_FILE);
        let identity_names = identity_names(&dir)?;
        let index_text = std::fs::read_to_string(&index_path).map_err(|source| RigError::Read {
            path: index_path.clone(),
            source,
        })?;
        let indices: RigIndices =
            serde_json::from_str(&index_text).map_err(|source| RigError::IndexJson {
                path: index_path.clone(),
                source,
            })?;
        let code_shapes = check_shape_names(&indices, &index_path)?;

        // Every file to read: the neutral, the shapes, the identities.
        let mut files = vec![dir.join(NEUTRAL_FILE)];
        files.extend(
            indices
                .expressions
                .iter()
                .map(|n| dir.join(format!("{n}.obj"))),
        );
        files.extend(identity_names.iter().map(|n| dir.join(format!("{n}.obj"))));
        let done = AtomicUsize::new(0);
        let total = files.len();
        let meshes = files
            .par_iter()
            .map(|path| {
                let mesh = ObjMesh::read(path)?;
                let done = done.fetch_add(1, Ordering::Relaxed) + 1;
                progress(LoadProgress {
                    done,
                    total,
                    file: path,
                });
                Ok(mesh)
            })
            .collect::<Result<Vec<_>, ObjError>>()?;

        let mut meshes = meshes.into_iter();
        let Some(mesh) = meshes.next() else {
            unreachable!("the neutral is always read");
        };
        let neutral_path = &files[0];
        check_finite(neutral_path, &mesh.positions)?;
        check_regions(mesh.positions.len(), &mesh.faces).map_err(|source| RigError::Regions {
            path: neutral_path.clone(),
            source,
        })?;
        let mut others = Vec::with_capacity(total - 1);
        for (m, path) in meshes.zip(&files[1..]) {
            check_same_topology(path, &mesh, &m)?;
            check_finite(path, &m.positions)?;
            others.push(m.positions);
        }
        let identities = others.split_off(indices.expressions.len());
        let shapes = others;
        check_indices(&indices, mesh.positions.len(), &index_path)?;

        Ok(Self {
            dir,
            mesh,
            indices,
            shapes,
            identity_names,
            identities,
            code_shapes,
            load_time: start.elapsed(),
        })
    }

    /// The directory the rig was loaded from.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Wall time [`Self::load`] took.
    pub fn load_time(&self) -> Duration {
        self.load_time
    }

    /// The neutral mesh as read (positions, faces, UVs, material groups).
    pub fn mesh(&self) -> &ObjMesh {
        &self.mesh
    }

    /// Neutral positions (cm).
    pub fn neutral(&self) -> &[Point3<f64>] {
        &self.mesh.positions
    }

    /// Faces of every shape (mostly quads).
    pub fn faces(&self) -> &Polygons {
        &self.mesh.faces
    }

    pub fn indices(&self) -> &RigIndices {
        &self.indices
    }

    /// Names of the expression shapes, in the rig's order.
    pub fn shape_names(&self) -> &[String] {
        &self.indices.expressions
    }

    /// Index of the shape called `name`.
    pub fn shape_index(&self, name: &str) -> Option<usize> {
        self.indices.expressions.iter().position(|n| n == name)
    }

    /// Positions of shape `k` at full weight on the generic neutral (cm).
    ///
    /// # Panics
    /// If `k` is not below [`Self::shape_names`]`.len()`.
    pub fn shape(&self, k: usize) -> &[Point3<f64>] {
        &self.shapes[k]
    }

    pub fn identity_count(&self) -> usize {
        self.identities.len()
    }

    /// File stems of the identities (`identity000`, …), sorted.
    pub fn identity_names(&self) -> &[String] {
        &self.identity_names
    }

    /// Adds a neutral mesh on the rig's topology as the next identity, called `name`, and
    /// returns its index: the rig's expression deltas then pose it as they pose the rig's own
    /// identities (`x = b + Σ w·(s − n)`). The mesh must have the neutral's vertex count and
    /// faces and finite coordinates.
    pub fn add_identity(&mut self, name: &str, path: &Path) -> Result<usize, RigError> {
        let mesh = ObjMesh::read(path)?;
        check_same_topology(path, &self.mesh, &mesh)?;
        check_finite(path, &mesh.positions)?;
        self.identity_names.push(name.to_string());
        self.identities.push(mesh.positions);
        Ok(self.identities.len() - 1)
    }

    /// Rest positions of identity `i`, or the generic neutral for `None` (cm).
    ///
    /// # Panics
    /// If `i` is not below [`Self::identity_count`].
    pub fn base(&self, identity: Option<usize>) -> &[Point3<f64>] {
        match identity {
            None => &self.mesh.positions,
            Some(i) => {
                assert!(
                    i < self.identities.len(),
                    "identity {i} out of range: the rig has {}",
                    self.identities.len()
                );
                &self.identities[i]
            }
        }
    }

    /// Posed positions for the default expression code:
    /// `x = b + Σₖ codeₖ·(s_{shape(k)} − n)` (cm), `b` the identity's rest (neutral for `None`).
    ///
    /// # Panics
    /// If `identity` is `Some(i)` with `i` not below [`Self::identity_count`].
    pub fn pose(&self, identity: Option<usize>, code: &ExpressionCode) -> Vec<Point3<f64>> {
        let weights: Vec<(usize, f64)> = self.code_shapes.iter().copied().zip(code.0).collect();
        self.pose_shapes(identity, &weights)
    }

    /// Posed positions for arbitrary `(shape index, weight)` pairs:
    /// `x = b + Σ w·(s_shape − n)` (cm). Zero weights are skipped.
    ///
    /// # Panics
    /// If a shape index or the identity is out of range.
    pub fn pose_shapes(
        &self,
        identity: Option<usize>,
        weights: &[(usize, f64)],
    ) -> Vec<Point3<f64>> {
        let base = self.base(identity);
        let neutral = &self.mesh.positions;
        let active: Vec<(&[Point3<f64>], f64)> = weights
            .iter()
            .filter(|(_, w)| *w != 0.0)
            .map(|&(k, w)| (self.shapes[k].as_slice(), w))
            .collect();
        base.par_iter()
            .enumerate()
            .with_min_len(1024)
            .map(|(i, b)| {
                let mut x = *b;
                for (s, w) in &active {
                    x += (s[i] - neutral[i]) * *w;
                }
                x
            })
            .collect()
    }
}

/// Stems of `identity<digits>.obj` files in `dir`, sorted.
fn identity_names(dir: &Path) -> Result<Vec<String>, RigError> {
    let dir_err = |source| RigError::Directory {
        path: dir.to_path_buf(),
        source,
    };
    let mut names = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(dir_err)? {
        let entry = entry.map_err(dir_err)?;
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        if let Some(stem) = name.strip_suffix(".obj")
            && let Some(digits) = stem.strip_prefix("identity")
            && !digits.is_empty()
            && digits.bytes().all(|b| b.is_ascii_digit())
        {
            names.push(stem.to_string());
        }
    }
    names.sort();
    Ok(names)
}

/// Known, distinct shape names, with the default code's shapes among them; returns the
/// default code's shape indices.
fn check_shape_names(
    indices: &RigIndices,
    path: &Path,
) -> Result<[usize; ExpressionCode::LEN], RigError> {
    for (i, name) in indices
        .expressions
        .iter()
        .chain(&indices.fitting_expressions)
        .enumerate()
    {
        if !is_known_shape(name) {
            return Err(RigError::UnknownShape {
                path: path.to_path_buf(),
                name: name.clone(),
            });
        }
        if i < indices.expressions.len() && indices.expressions[..i].contains(name) {
            return Err(RigError::DuplicateShape {
                path: path.to_path_buf(),
                name: name.clone(),
            });
        }
    }
    let mut code_shapes = [0; ExpressionCode::LEN];
    for (slot, name) in code_shapes.iter_mut().zip(ExpressionCode::NAMES) {
        *slot = indices
            .expressions
            .iter()
            .position(|n| n == name)
            .ok_or_else(|| RigError::MissingDefaultShape {
                path: path.to_path_buf(),
                name,
            })?;
    }
    Ok(code_shapes)
}

fn check_finite(path: &Path, positions: &[Point3<f64>]) -> Result<(), RigError> {
    match positions
        .iter()
        .position(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        Some(vertex) => Err(RigError::NonFinite {
            path: path.to_path_buf(),
            vertex,
        }),
        None => Ok(()),
    }
}

fn check_same_topology(path: &Path, neutral: &ObjMesh, other: &ObjMesh) -> Result<(), RigError> {
    if other.positions.len() != neutral.positions.len() {
        return Err(RigError::VertexCount {
            path: path.to_path_buf(),
            found: other.positions.len(),
            expected: neutral.positions.len(),
        });
    }
    if other.faces != neutral.faces {
        let face = (0..neutral.faces.len().max(other.faces.len()))
            .find(|&f| {
                f >= neutral.faces.len()
                    || f >= other.faces.len()
                    || neutral.faces.get(f) != other.faces.get(f)
            })
            .unwrap_or(0);
        return Err(RigError::Topology {
            path: path.to_path_buf(),
            face,
        });
    }
    Ok(())
}

fn check_indices(indices: &RigIndices, vertex_count: usize, path: &Path) -> Result<(), RigError> {
    let sets: [(&'static str, &[usize], usize); 5] = [
        (
            "idx_to_rigid_verts",
            &indices.idx_to_rigid_verts,
            vertex_count,
        ),
        (
            "idx_to_fitting_verts",
            &indices.idx_to_fitting_verts,
            vertex_count,
        ),
        (
            "idx_to_landmark_verts",
            &indices.idx_to_landmark_verts,
            vertex_count,
        ),
        (
            "idx_to_lap_rigid_verts",
            &indices.idx_to_lap_rigid_verts,
            vertex_count,
        ),
        (
            "idx_to_rigid_landmark_idx",
            &indices.idx_to_rigid_landmark_idx,
            indices.idx_to_landmark_verts.len(),
        ),
    ];
    for (key, set, bound) in sets {
        if let Some(&index) = set.iter().find(|&&i| i >= bound) {
            return Err(RigError::IndexOutOfRange {
                path: path.to_path_buf(),
                key,
                index,
                bound,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::regions::Region;
    use crate::rig::test_support::{rig, rig_dir, temp_dir};

    #[test]
    fn loads_the_ict_rig() {
        let rig = rig();
        assert_eq!(rig.neutral().len(), 26_719);
        assert_eq!(rig.faces().len(), 26_384);
        assert_eq!(rig.shape_names().len(), 53);
        assert_eq!(rig.identity_count(), 10);
        assert_eq!(rig.identity_names()[3], "identity003");
        assert_eq!(rig.mesh().uvs.len(), 28_911);
        assert!(rig.mesh().corner_uvs.is_some());
        assert_eq!(rig.indices().idx_to_landmark_verts.len(), 68);
        // The first vertex line of the neutral file: `v 0 -2.48251 11.8387`.
        assert_eq!(rig.neutral()[0], Point3::new(0.0, -2.48251, 11.8387));
        eprintln!(
            "rig: loaded {} OBJ files in {:.3} s",
            1 + rig.shape_names().len() + rig.identity_count(),
            rig.load_time().as_secs_f64()
        );
    }

    /// A neutral on the rig's topology becomes the next identity and is posed by the rig's
    /// deltas like the rig's own; a mesh of another topology is refused, naming the file.
    #[test]
    fn an_added_identity_is_posed_like_the_rigs_own() {
        let mut added = rig().clone();
        let path = rig_dir().join("identity007.obj");
        let i = added.add_identity("scan", &path).unwrap();
        assert_eq!(i, 10);
        assert_eq!(added.identity_names()[10], "scan");
        let code = ExpressionCode::single("jawOpen", 0.7).unwrap();
        assert_eq!(added.pose(Some(10), &code), rig().pose(Some(7), &code));

        let dir = temp_dir("add-identity");
        let other = ObjMesh {
            positions: rig().neutral()[..100].to_vec(),
            faces: Polygons::from_lists(&[[0u32, 1, 2]]),
            ..ObjMesh::default()
        };
        let bad = dir.join("bad.obj");
        other.write(&bad, "").unwrap();
        let err = added.add_identity("bad", &bad).unwrap_err();
        assert!(
            matches!(err, RigError::VertexCount { found: 100, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("bad.obj"), "{err}");
        assert_eq!(added.identity_count(), 11);
    }

    #[test]
    fn pose_is_the_linear_blend() {
        let rig = rig();
        let neutral = rig.pose(None, &ExpressionCode::NEUTRAL);
        assert_eq!(neutral, rig.neutral());
        let open = rig.shape_index("jawOpen").unwrap();
        let half = rig.pose(None, &ExpressionCode::single("jawOpen", 0.5).unwrap());
        let full = rig.pose(None, &ExpressionCode::single("jawOpen", 1.0).unwrap());
        for i in [0, 5000, 19_300, 26_000] {
            assert!((full[i] - rig.shape(open)[i]).norm() < 1e-12);
            let mid = rig.neutral()[i] + (rig.shape(open)[i] - rig.neutral()[i]) * 0.5;
            assert!((half[i] - mid).norm() < 1e-12);
        }
        // jawOpen moves the lower teeth down by up to ~4 cm and leaves the skull's rigid
        // vertices alone.
        let drop = Region::LowerTeeth
            .vertices()
            .map(|i| rig.neutral()[i].y - full[i].y)
            .fold(0.0, f64::max);
        assert!((3.0..5.0).contains(&drop), "{drop}");
        // An identity's pose adds the same displacement to the identity's rest shape.
        let id = rig.pose(Some(4), &ExpressionCode::single("jawOpen", 1.0).unwrap());
        for i in [0, 19_300] {
            let expected = rig.base(Some(4))[i] + (full[i] - rig.neutral()[i]);
            assert!((id[i] - expected).norm() < 1e-12);
        }
    }

    #[test]
    fn progress_reports_every_file() {
        // A tiny rig keeps this fast: three shapes and one identity.
        let dir = temp_dir("rig_progress");
        write_tiny_rig(&dir, &["jawOpen"]);
        let seen = std::sync::Mutex::new(Vec::new());
        let rig = FaceRig::load_with_progress(&dir, &|p| {
            seen.lock().unwrap().push((p.done, p.total));
        })
        .unwrap();
        let mut seen = seen.into_inner().unwrap();
        seen.sort();
        let total = 1 + rig.shape_names().len() + rig.identity_count();
        assert_eq!(seen, (1..=total).map(|d| (d, total)).collect::<Vec<_>>());
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Writes a small rig into `dir`: the real neutral topology is too big to copy per test,
    /// so it uses the real neutral mesh for the neutral (region table checks need it) and
    /// shares it for every shape, plus one identity. `extra_shapes` are added to the 19
    /// default shapes.
    fn write_tiny_rig(dir: &Path, extra_shapes: &[&str]) {
        let neutral = std::fs::read_to_string(rig_dir().join(NEUTRAL_FILE)).unwrap();
        let mut names: Vec<&str> = ExpressionCode::NAMES.to_vec();
        for n in extra_shapes {
            if !names.contains(n) {
                names.push(n);
            }
        }
        std::fs::write(dir.join(NEUTRAL_FILE), &neutral).unwrap();
        for n in &names {
            std::fs::write(dir.join(format!("{n}.obj")), &neutral).unwrap();
        }
        std::fs::write(dir.join("identity000.obj"), &neutral).unwrap();
        write_index(dir, &names, 8786);
    }

    fn write_index(dir: &Path, names: &[&str], rigid_vertex: usize) {
        let json = serde_json::json!({
            "expressions": names,
            "fitting_expressions": names,
            "incompatibilities": [],
            "idx_to_rigid_verts": [876, rigid_vertex],
            "idx_to_landmark_verts": [0, 1, 2],
            "idx_to_rigid_landmark_idx": [0, 2],
        });
        std::fs::write(dir.join(INDEX_FILE), json.to_string()).unwrap();
    }

    #[test]
    fn corrupt_rigs_fail_with_errors_naming_file_and_problem() {
        let dir = temp_dir("rig_corrupt");
        write_tiny_rig(&dir, &[]);
        FaceRig::load(&dir).unwrap();
        let neutral = std::fs::read_to_string(dir.join(NEUTRAL_FILE)).unwrap();
        let names: Vec<&str> = ExpressionCode::NAMES.to_vec();
        let msg = |dir: &Path| FaceRig::load(dir).unwrap_err().to_string();

        // A shape with a vertex missing.
        let last_v = neutral.rfind("\nv ").unwrap();
        let end = last_v + 1 + neutral[last_v + 1..].find('\n').unwrap();
        let short = format!("{}{}", &neutral[..last_v], &neutral[end..]);
        // The last vertex removed makes faces reference a missing vertex: an OBJ error.
        std::fs::write(dir.join("mouthPucker.obj"), &short).unwrap();
        let m = msg(&dir);
        assert!(
            m.contains("mouthPucker.obj") && m.contains("out of range"),
            "{m}"
        );
        // An extra vertex: a vertex-count mismatch.
        let extra = neutral.replacen("\nv ", "\nv 1 2 3\nv ", 1);
        std::fs::write(dir.join("mouthPucker.obj"), &extra).unwrap();
        let m = msg(&dir);
        assert!(
            m.contains("mouthPucker.obj") && m.contains("26720 vertices"),
            "{m}"
        );
        // Different faces.
        let flipped = neutral.replacen(
            "\nf 874/1 12/2 871/3 873/4",
            "\nf 873/4 874/1 12/2 871/3",
            1,
        );
        assert_ne!(flipped, neutral);
        std::fs::write(dir.join("mouthPucker.obj"), &flipped).unwrap();
        let m = msg(&dir);
        assert!(m.contains("mouthPucker.obj") && m.contains("face 0"), "{m}");
        // A non-number coordinate.
        let bad = neutral.replacen("\nv 0 -2.48251 11.8387", "\nv 0 -2.48251 inf", 1);
        std::fs::write(dir.join("mouthPucker.obj"), &bad).unwrap();
        let m = msg(&dir);
        assert!(
            m.contains("mouthPucker.obj") && m.contains("non-finite"),
            "{m}"
        );
        std::fs::write(dir.join("mouthPucker.obj"), &neutral).unwrap();

        // An identity file missing its content.
        std::fs::write(dir.join("identity007.obj"), "").unwrap();
        let m = msg(&dir);
        assert!(
            m.contains("identity007.obj") && m.contains("0 vertices"),
            "{m}"
        );
        std::fs::remove_file(dir.join("identity007.obj")).unwrap();

        // A shape file listed but absent.
        std::fs::remove_file(dir.join("mouthClose.obj")).unwrap();
        let m = msg(&dir);
        assert!(
            m.contains("mouthClose.obj") && m.contains("cannot read"),
            "{m}"
        );
        std::fs::write(dir.join("mouthClose.obj"), &neutral).unwrap();

        // Index file problems: unknown name, missing default shape, index out of range, JSON.
        let mut with_unknown = names.clone();
        with_unknown.push("tongueOut");
        write_index(&dir, &with_unknown, 8786);
        let m = msg(&dir);
        assert!(m.contains(INDEX_FILE) && m.contains("tongueOut"), "{m}");
        write_index(&dir, &names[1..], 8786);
        let m = msg(&dir);
        assert!(m.contains(INDEX_FILE) && m.contains("jawOpen"), "{m}");
        let mut twice = names.clone();
        twice.push("jawOpen");
        write_index(&dir, &twice, 8786);
        assert!(msg(&dir).contains("listed twice"));
        write_index(&dir, &names, 26_719);
        let m = msg(&dir);
        assert!(
            m.contains("idx_to_rigid_verts") && m.contains("26719"),
            "{m}"
        );
        std::fs::write(dir.join(INDEX_FILE), "{\"expressions\": [").unwrap();
        let m = msg(&dir);
        assert!(
            m.contains(INDEX_FILE) && m.contains("invalid index file"),
            "{m}"
        );
        write_index(&dir, &names, 8786);

        // A neutral that does not match the region table (a skin face moved to a tooth).
        let moved = neutral.replacen(
            "\nf 874/1 12/2 871/3 873/4",
            "\nf 20000/1 12/2 871/3 873/4",
            1,
        );
        std::fs::write(dir.join(NEUTRAL_FILE), &moved).unwrap();
        let m = msg(&dir);
        assert!(
            m.contains(NEUTRAL_FILE) && m.contains("region table") && m.contains("face 0"),
            "{m}"
        );
        FaceRig::load(dir.join("no-such-dir")).unwrap_err();
        let _ = std::fs::remove_dir_all(&dir);
    }
}
