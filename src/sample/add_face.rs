//! A new face from its neutral alone (`facesim add-face`): a scan on the rig's topology is
//! imported, its actuation basis fitted to the rig's shapes carried onto it, its φ trained to
//! the sample's template, and it joins the sample's manifest. No expression shape of the new
//! face is needed: the rig poses any neutral on its topology by its own deltas,
//! `x = b + Σ w·(s − n)`, as it poses its identities.

use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::{
    BuiltFace, Manifest, ManifestFace, SampleError, build_one, read_manifest, with_added_neutrals,
    write_manifest,
};
use crate::drive::basis::ActuationBasis;
use crate::mapping::{LossRow, Mapping, TrainConfig, loss_csv};
use crate::model::{FaceModel, Lod};
use crate::rig::{FaceRig, StyleCode};

/// How [`add_face`] builds the face.
#[derive(Clone, Debug)]
pub struct AddFaceOptions {
    /// The face's name in the sample (letters, digits, `-`, `_`); default: the neutral's file
    /// stem.
    pub name: Option<String>,
    /// The face's default style.
    pub style: StyleCode,
    pub lod: Lod,
    /// φ's training (as `facesim train-mapping` trains the sample's identities).
    pub mapping: TrainConfig,
}

impl Default for AddFaceOptions {
    fn default() -> Self {
        Self {
            name: None,
            style: StyleCode::NEUTRAL,
            lod: super::SAMPLE_LOD,
            mapping: TrainConfig::default(),
        }
    }
}

/// What [`add_face`] tells as it goes.
pub enum AddFaceEvent<'a> {
    /// A step starts (importing, fitting a shape, training φ, writing).
    Step(&'a str),
    /// One of φ's training iterations.
    Mapping(&'a LossRow),
}

/// What [`add_face`] built and wrote.
pub struct AddedFace {
    pub entry: ManifestFace,
    pub model: FaceModel,
    pub basis: ActuationBasis,
    pub mapping: Mapping,
    pub seconds: f64,
}

/// Adds the neutral mesh at `neutral` to the sample in `dir` as a new face: imports it as the
/// rig's next identity (repair, tissue, bindings, at `options.lod`) and fits its actuation basis
/// as `build_faces` builds the sample's faces, trains its φ into the sample's template face,
/// writes its files beside the others (the neutral itself as `<name>-neutral.obj`, so that
/// tools reach its targets) and adds it to the manifest last, so an interrupted run leaves the
/// sample as it was.
///
/// Fails with a clear error when the mesh is not on the rig's topology, the name is taken or
/// unusable, or the sample has no template face.
pub fn add_face(
    rig: &FaceRig,
    dir: &Path,
    neutral: &Path,
    options: &AddFaceOptions,
    events: &mut dyn FnMut(AddFaceEvent<'_>),
) -> Result<AddedFace, SampleError> {
    let start = Instant::now();
    let mut manifest = read_manifest(dir)?;
    let name = face_name(options.name.as_deref(), neutral, &manifest)?;
    let template = manifest
        .faces
        .iter()
        .find(|f| f.identity.is_none())
        .ok_or_else(|| SampleError::NoTemplate(dir.to_path_buf()))?;
    let template_path = dir.join(&template.face);
    let canonical = FaceModel::load(&template_path).map_err(|source| SampleError::File {
        path: template_path,
        source,
    })?;

    // The rig with the sample's earlier added faces, then this one as the next identity.
    let mut rig = with_added_neutrals(
        rig,
        manifest
            .faces
            .iter()
            .filter_map(|f| Some((f.name.as_str(), f.identity?, dir.join(f.neutral.as_ref()?)))),
    )?
    .into_owned();
    let identity = rig
        .add_identity(&name, neutral)
        .map_err(|source| SampleError::Neutral { source })?;

    let BuiltFace {
        mut entry,
        model,
        basis,
    } = {
        // The build reports through a shared closure on this thread.
        let events = RefCell::new(&mut *events);
        build_one(
            &rig,
            Some(identity),
            name.clone(),
            options.style,
            options.lod,
            &|message| (events.borrow_mut())(AddFaceEvent::Step(message)),
        )?
    };
    entry.neutral = Some(format!("{name}-neutral.obj"));
    events(AddFaceEvent::Step(&format!("training φ of {name}")));
    let (mapping, rows) = crate::mapping::train(&model, &canonical, &options.mapping, |row| {
        events(AddFaceEvent::Mapping(row))
    })
    .map_err(|source| SampleError::Mapping {
        path: dir.to_path_buf(),
        source,
    })?;

    events(AddFaceEvent::Step(&format!("writing {name}")));
    write_files(dir, neutral, &entry, &model, &basis, &mapping, &rows)?;
    manifest.faces.push(entry.clone());
    write_manifest(dir, &manifest)?;
    Ok(AddedFace {
        entry,
        model,
        basis,
        mapping,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The new face's name: chosen or the neutral's file stem, usable in file names and new to
/// the sample.
fn face_name(
    chosen: Option<&str>,
    neutral: &Path,
    manifest: &Manifest,
) -> Result<String, SampleError> {
    let name = match chosen {
        Some(n) => n.to_string(),
        None => neutral
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
    };
    let usable = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_');
    if !usable {
        return Err(SampleError::BadName(name));
    }
    if manifest.faces.iter().any(|f| f.name == name) {
        return Err(SampleError::NameTaken(name));
    }
    Ok(name)
}

/// The face's files: its neutral, model, basis, φ and φ's loss curve.
fn write_files(
    dir: &Path,
    neutral: &Path,
    entry: &ManifestFace,
    model: &FaceModel,
    basis: &ActuationBasis,
    mapping: &Mapping,
    rows: &[LossRow],
) -> Result<(), SampleError> {
    let io = |path: PathBuf| move |source| SampleError::Io { path, source };
    let file = |path: PathBuf| move |source| SampleError::File { path, source };
    let copy = dir.join(
        entry
            .neutral
            .as_deref()
            .expect("an added face has its neutral"),
    );
    // Read and written rather than copied: a copy would keep a read-only source's mode.
    let text = std::fs::read(neutral).map_err(io(neutral.to_path_buf()))?;
    std::fs::write(&copy, text).map_err(io(copy.clone()))?;
    let path = dir.join(&entry.face);
    model.save(&path).map_err(file(path.clone()))?;
    let path = dir.join(&entry.basis);
    basis.save(&path).map_err(file(path.clone()))?;
    let path = dir.join(&entry.mapping);
    mapping.save(&path).map_err(|source| SampleError::Mapping {
        path: path.clone(),
        source,
    })?;
    let path = dir.join(entry.mapping.replace(".mapping", ".loss.csv"));
    std::fs::write(&path, loss_csv(rows)).map_err(io(path.clone()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::generative::{SAMPLE_NETWORKS, load_sample_networks};
    use crate::model::target;
    use crate::rig::test_support::{rig, rig_dir, temp_dir};
    use crate::rig::{Codes, ExpressionCode};
    use crate::sample::{SAMPLE_DIR, Sample};
    use crate::sequence::solve_codes;
    use crate::sim::Quality;

    /// A sample of the bundled template face alone, with the bundled networks.
    fn template_sample() -> PathBuf {
        let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(SAMPLE_DIR);
        let dir = temp_dir("add-face");
        let mut manifest = read_manifest(&repo).unwrap();
        manifest.faces.retain(|f| f.identity.is_none());
        let template = &manifest.faces[0];
        for file in [&template.face, &template.basis, SAMPLE_NETWORKS] {
            std::fs::copy(repo.join(file), dir.join(file)).unwrap();
        }
        write_manifest(&dir, &manifest).unwrap();
        dir
    }

    /// A face never in training (identity 7 of the rig, as a user's scan) is added from its
    /// neutral alone; the sample then loads it with its φ, the rig's targets reach it, and the
    /// sample's networks drive it to an opened jaw near the rig's. A second face of the same
    /// name, or a mesh off the rig's topology, is refused and leaves the manifest as it was.
    #[test]
    fn a_face_added_from_its_neutral_alone_is_driven_by_the_networks() {
        let dir = template_sample();
        let neutral = rig_dir().join("identity007.obj");
        let options = AddFaceOptions {
            style: StyleCode([0.3, 0.0, 0.2, 0.0]),
            mapping: TrainConfig {
                iterations: 60,
                ..TrainConfig::default()
            },
            ..AddFaceOptions::default()
        };
        let (mut steps, mut rows) = (Vec::new(), 0);
        let added = add_face(rig(), &dir, &neutral, &options, &mut |event| match event {
            AddFaceEvent::Step(m) => steps.push(m.to_string()),
            AddFaceEvent::Mapping(_) => rows += 1,
        })
        .unwrap();
        assert_eq!(rows, 60);
        // The 24 shapes, then the sliders the face's style makes more than their own shape.
        let fits = 24 + added.basis.own_style_fits().count();
        assert!(fits > 24);
        assert!(
            steps
                .iter()
                .any(|s| s.contains(&format!("basis: {fits}/{fits}"))),
            "{steps:?}"
        );
        assert_eq!(added.entry.name, "identity007");
        assert_eq!(added.entry.identity, Some(10));

        let sample = Sample::load(&dir).unwrap();
        assert_eq!(sample.faces.len(), 2);
        let face = &sample.faces[1];
        assert_eq!(face.style, options.style);
        assert!(face.mapping.is_some());
        assert_eq!(face.model.name, "identity007");

        // The rig's targets reach it: the rig's own identity 7 under the same code.
        let rig_for = sample.rig_for(rig()).unwrap();
        let codes = Codes {
            expression: ExpressionCode::single("jawOpen", 0.8).unwrap(),
            style: StyleCode::NEUTRAL,
        };
        let goal = target(&rig_for, &face.model, &codes).unwrap();
        let own = rig().pose(Some(7), &codes.expression);
        let base = rig().base(Some(7));
        let render = &face.model.render;
        for ((&v, rest), p) in render
            .rig_vertices
            .iter()
            .zip(&render.rest)
            .zip(&goal.render)
        {
            let v = v as usize;
            assert!(((p - rest) - (own[v] - base[v])).norm() < 1e-9);
        }

        // The networks drive it, with its φ, to near the rig's opened jaw.
        let networks = load_sample_networks(&sample, SAMPLE_NETWORKS)
            .unwrap()
            .unwrap();
        let sim = face.model.simulator().unwrap();
        let mut solved = None;
        solve_codes(
            &sim,
            &*networks[1],
            std::slice::from_ref(&codes),
            &Quality::Interactive.settings(),
            |frame, state| {
                let stats = frame.outcome.as_ref().expect("the frame solves");
                let at = face
                    .model
                    .render_positions(state.flat_positions(), &frame.bones);
                solved = Some((stats.converged(), frame.bones.jaw.rotation.x, at));
            },
        );
        let (converged, jaw, at) = solved.unwrap();
        assert!(
            jaw > 0.5 * goal.jaw.motion.rotation.x,
            "jaw {jaw} vs {:?}",
            goal.jaw
        );
        // Over the vertices the rig moves by more than 2 mm: the mean error against the mean
        // motion.
        let (mut error, mut motion, mut count) = (0.0, 0.0, 0);
        for ((a, goal), rest) in at.iter().zip(&goal.render).zip(&render.rest) {
            let moves = 10.0 * (goal - rest).norm();
            if moves > 2.0 {
                error += 10.0 * (a - goal).norm();
                motion += moves;
                count += 1;
            }
        }
        let (error, motion) = (error / count as f64, motion / count as f64);
        eprintln!(
            "added face: {count} vertices move {motion:.2} mm on average, {error:.2} mm error, \
             converged {converged}"
        );
        assert!(
            count > 1000 && error < 0.15 * motion,
            "{error} mm off a {motion} mm motion"
        );

        let err = add_face(rig(), &dir, &neutral, &options, &mut |_| {})
            .err()
            .expect("a taken name is refused");
        assert!(matches!(err, SampleError::NameTaken(_)), "{err}");
        let bad = dir.join("not-a-face.obj");
        std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        let err = add_face(rig(), &dir, &bad, &options, &mut |_| {})
            .err()
            .expect("a mesh off the rig's topology is refused");
        let message = err.to_string();
        assert!(
            message.contains("not-a-face.obj") && message.contains("rig's topology"),
            "{message}"
        );
        assert_eq!(read_manifest(&dir).unwrap().faces.len(), 2);
    }
}
