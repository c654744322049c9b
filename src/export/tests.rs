//! End to end: a short track on the bundled sample through the session into every core
//! format; the files agree with each other and with the session's frames; failures leave
//! nothing under a final name.

use std::path::{Path, PathBuf};

use super::*;
use crate::rig::ExpressionCode;
use crate::sample::{SAMPLE_DIR, Sample};
use crate::session::session_face::FaceTopology;
use crate::session::track::Track;
use crate::sim::Quality;

fn short_track() -> Track {
    let mut t = Track::new("neutral");
    t.set_key(0.0, Default::default());
    let open = crate::drive::Codes {
        expression: ExpressionCode::single("jawOpen", 0.4).unwrap(),
        ..Default::default()
    };
    t.set_key(0.3, open);
    t
}

fn neutral() -> crate::session::SessionFace {
    let sample = Sample::load(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(SAMPLE_DIR)).unwrap();
    sample
        .session_faces()
        .into_iter()
        .find(|f| f.name == "neutral")
        .unwrap()
}

/// Every core format of all frames at 10 fps, interactive, without contact, into `dir`.
fn core_job(name: &str, dir: &Path) -> ExportJob {
    ExportJob {
        name: name.into(),
        out_dir: dir.to_path_buf(),
        formats: vec![Format::Usd, Format::Pc2, Format::Obj, Format::Gltf],
        fps: 10.0,
        quality: Quality::Interactive,
        contact: false,
        actuation: "basis".into(),
        range: None,
    }
}

/// What an export of the short track into every core format leaves in its folder.
const SHORT_OUTPUTS: [&str; 6] = [
    "short.glb",
    "short.obj",
    "short.pc2",
    "short.report.json",
    "short.usda",
    "short_obj",
];

fn listing(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// Fails at frame 2 (stands in for a writer or solve failure mid-export).
struct FailingFactory;
struct FailingSink;
impl FrameSink for FailingSink {
    fn frame(&mut self, index: usize, _: &crate::session::Frame) -> Result<(), ExportError> {
        if index == 2 {
            return Err(ExportError::Writer {
                format: Format::Rrd,
                reason: "disk full".into(),
            });
        }
        Ok(())
    }
    fn finish(self: Box<Self>) -> Result<(), ExportError> {
        Ok(())
    }
}
impl SinkFactory for FailingFactory {
    fn create(
        &self,
        _: Format,
        temp: &Path,
        _: &FaceTopology,
        _: usize,
        _: f64,
    ) -> Result<Option<Box<dyn FrameSink>>, ExportError> {
        std::fs::write(temp, b"partial").unwrap();
        Ok(Some(Box::new(FailingSink)))
    }
}

#[test]
fn a_short_track_exports_to_every_format_consistently() {
    let dir = std::env::temp_dir().join(format!("facesim-export-{}", std::process::id()));
    atomic::remove_any(&dir).unwrap();
    let face = neutral();
    let mesh = ExportMesh::of(&face.model);
    let track = short_track();
    let job = core_job("short", &dir);

    // rrd needs the editor binary.
    let rrd = ExportJob {
        formats: vec![Format::Rrd],
        ..job.clone()
    };
    let err = export(face.clone(), &track, &rrd, None, &mut |_, _| {}).unwrap_err();
    assert!(
        err.to_string().contains("cargo run --release -- export"),
        "{err}"
    );

    // What an interrupted run left: a stale temporary and no outputs.
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(atomic::temp_name(&dir.join("short.usda"), ""), "half").unwrap();
    let mut seen = Vec::new();
    let summary = export(face.clone(), &track, &job, None, &mut |d, n| {
        seen.push((d, n))
    })
    .unwrap();
    assert_eq!(summary.frames, 4, "0, 0.1, 0.2, 0.3 s");
    assert_eq!(seen.last(), Some(&(4, 4)));
    assert_eq!(listing(&dir), SHORT_OUTPUTS, "only final names remain");
    assert_eq!(
        listing(&dir.join("short_obj")),
        [
            "short_0000.obj",
            "short_0001.obj",
            "short_0002.obj",
            "short_0003.obj"
        ]
    );

    // PC2: the documented header and size; the frames move (the jaw opens) and match the OBJs.
    let (header, samples) = pc2::read(&dir.join("short.pc2")).unwrap();
    assert_eq!(header.points as usize, mesh.vertex_count());
    assert_eq!(
        (header.samples, header.start_frame, header.sample_rate),
        (4, 0.0, 1.0)
    );
    let moved = |k: usize| {
        samples[k]
            .iter()
            .zip(&mesh.rest)
            .map(|(p, r)| {
                ((p[0] - r[0]).powi(2) + (p[1] - r[1]).powi(2) + (p[2] - r[2]).powi(2)).sqrt()
            })
            .fold(0.0f32, f32::max)
    };
    assert!(
        moved(0) < 1e-3,
        "frame 0 is the rest pose ({} cm)",
        moved(0)
    );
    assert!(moved(3) > 0.3, "the jaw opened ({} cm)", moved(3));
    assert!(moved(1) < moved(2) && moved(2) < moved(3));
    let last = crate::rig::obj::ObjMesh::read(dir.join("short_obj/short_0003.obj")).unwrap();
    for (a, b) in last.positions.iter().zip(&samples[3]) {
        assert_eq!([a.x as f32, a.y as f32, a.z as f32], *b);
    }
    let topology = crate::rig::obj::ObjMesh::read(dir.join("short.obj")).unwrap();
    assert_eq!(topology.triangles(), mesh.triangles);

    // USD: four samples of points, the last equal to the PC2's to the printed precision.
    let usda = std::fs::read_to_string(dir.join("short.usda")).unwrap();
    assert!(usda.contains("timeCodesPerSecond = 10") && usda.contains("endTimeCode = 3"));
    let line = usda
        .lines()
        .find(|l| l.trim_start().starts_with("3: [("))
        .unwrap();
    let first: Vec<f32> = line
        .split(['(', ')'])
        .nth(1)
        .unwrap()
        .split(", ")
        .map(|v| v.parse().unwrap())
        .collect();
    for c in 0..3 {
        assert!((first[c] - samples[3][0][c]).abs() <= 1e-5);
    }

    // The report: every frame converged at the preset, and the audit found the open jaw's
    // frames free of new crossings of skin, lining and teeth.
    let report: report::ExportReport =
        serde_json::from_str(&std::fs::read_to_string(dir.join("short.report.json")).unwrap())
            .unwrap();
    assert_eq!((report.frames.len(), report.contact), (4, false));
    assert_eq!(report.quality, Quality::Interactive);
    assert_eq!(report.actuation, "basis");
    assert_eq!((report.unconverged, summary.unconverged), (0, 0));
    assert_eq!(report.crossing_frames, summary.crossing_frames);
    assert!(report.frames.iter().all(|f| f.converged), "{report:?}");
    assert_eq!(report.frames[3].time, 0.3);

    // glTF: target 3 is frame 3 in metres, relative to the rest pose.
    let (json, bin) = gltf::read_glb(&dir.join("short.glb")).unwrap();
    let targets = json["meshes"][0]["primitives"][0]["targets"]
        .as_array()
        .unwrap()
        .len();
    assert_eq!(targets, 4);
    let a = &json["accessors"][json["meshes"][0]["primitives"][0]["targets"][3]["POSITION"]
        .as_u64()
        .unwrap() as usize];
    let view = &json["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
    let o = (view["byteOffset"].as_u64().unwrap() + a["byteOffset"].as_u64().unwrap()) as usize;
    // glTF vertex 0 copies the first triangle's first corner.
    let first = mesh.triangles[0][0] as usize;
    let dy = f32::from_le_bytes(bin[o + 4..o + 8].try_into().unwrap());
    assert!((dy - (samples[3][first][1] - mesh.rest[first][1]) * 0.01).abs() < 1e-6);

    // The rig's UVs in every format: corner by corner in the OBJs, face-varying in USD,
    // and in glTF one vertex per (vertex, UV) pair, the seams split.
    let uv = mesh
        .uv
        .as_ref()
        .expect("the sample's faces carry the rig's UVs");
    let corners: Vec<u32> = uv.triangles.iter().flatten().copied().collect();
    for obj in [&topology, &last] {
        assert_eq!(obj.uvs.len(), uv.coords.len());
        assert_eq!(obj.corner_uvs.as_ref().unwrap(), &corners);
    }
    assert!(
        usda.contains("texCoord2f[] primvars:st = [(")
            && usda.contains("int[] primvars:st:indices = [")
    );
    assert!(usda.contains("interpolation = \"faceVarying\""));
    let mut pairs: Vec<(u32, u32)> = mesh
        .triangles
        .iter()
        .flatten()
        .copied()
        .zip(corners.iter().copied())
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    let prim = &json["meshes"][0]["primitives"][0];
    let texcoord = &json["accessors"][prim["attributes"]["TEXCOORD_0"].as_u64().unwrap() as usize];
    assert_eq!(texcoord["count"].as_u64().unwrap() as usize, pairs.len());
    assert!(
        pairs.len() > mesh.vertex_count(),
        "the rig's UV seams split vertices"
    );

    // A failure mid-export leaves the previous outputs untouched and no temporaries.
    let before = std::fs::read(dir.join("short.pc2")).unwrap();
    let failing = ExportJob {
        formats: vec![Format::Pc2, Format::Rrd, Format::Gltf],
        fps: 20.0,
        ..job.clone()
    };
    let err = export(
        face,
        &track,
        &failing,
        Some(&FailingFactory),
        &mut |_, _| {},
    )
    .unwrap_err();
    assert!(err.to_string().contains("disk full"), "{err}");
    assert_eq!(listing(&dir), SHORT_OUTPUTS);
    assert_eq!(std::fs::read(dir.join("short.pc2")).unwrap(), before);
    atomic::remove_any(&dir).unwrap();
}

#[test]
fn frame_counts_cover_the_track() {
    assert_eq!(frame_count(10.0, 30.0), 301);
    assert_eq!(frame_count(0.3, 10.0), 4);
    assert_eq!(frame_count(0.0, 30.0), 1);
    assert_eq!(frame_count(0.25, 10.0), 3);
}

#[test]
fn faces_are_chosen_by_name_index_or_the_track() {
    let sample = Sample::load(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(SAMPLE_DIR)).unwrap();
    let track = short_track();
    let pick =
        |w: Option<&str>| super::choose_face(sample.session_faces(), w, &track).map(|f| f.name);
    assert_eq!(pick(None).unwrap(), "neutral");
    assert_eq!(pick(Some("identity001")).unwrap(), "identity001");
    assert_eq!(pick(Some("2")).unwrap(), sample.session_faces()[2].name);
    let err = pick(Some("nobody")).unwrap_err().to_string();
    assert!(
        err.contains("no face 'nobody'") && err.contains("identity000"),
        "{err}"
    );
}

/// A frame that stopped short of the preset's tolerance is counted and marked in the report,
/// and a frame whose lips pass through each other carries its crossings.
#[test]
fn the_report_marks_unconverged_and_crossing_frames() {
    use crate::session::{Request, Session};
    let face = neutral();
    let model = face.model.clone();
    let session = Session::new(vec![face], Quality::Interactive).unwrap();
    let generation = session
        .submit_all(&[
            Request::Contact(false),
            Request::Codes(short_track().sample(0.3).unwrap()),
        ])
        .unwrap();
    let frame = session
        .wait_generation(generation, std::time::Duration::from_secs(60))
        .unwrap();
    let mut builder =
        report::ReportBuilder::new(&model, "t", 30.0, Quality::Interactive, false, "basis");
    builder.record(&model, 0, 0.0, &frame);
    let mut stopped = (*frame).clone();
    stopped.stats.converged = false;
    stopped.stats.termination = crate::sim::Termination::IterationCap;
    builder.record(&model, 1, 1.0 / 30.0, &stopped);
    // The lips around rig vertex 6502 pushed 2 cm down, through the teeth and the lining.
    let mut pressed = (*frame).clone();
    let upper_lip = model
        .render
        .rig_vertices
        .iter()
        .position(|&v| v == 6502)
        .unwrap();
    for (i, p) in pressed.positions.iter_mut().enumerate() {
        if (model.render.rest[i] - model.render.rest[upper_lip]).norm() < 0.8 {
            p[1] -= 2.0;
        }
    }
    builder.record(&model, 2, 2.0 / 30.0, &pressed);
    let report = builder.report();
    assert_eq!(report.unconverged, 1);
    assert!(!report.frames[1].converged && report.frames[0].converged);
    assert!(
        report.frames[2].crossings > report.frames[0].crossings,
        "{:?}",
        report.frames[2]
    );
    let crossing = report.frames.iter().filter(|f| f.crossings > 0).count();
    assert!(crossing >= 1 && report.crossing_frames == crossing);
}

/// A range of frames keeps their numbers, and with a lead-in back to the track's start it
/// writes exactly the frames the whole export writes (every solve warm-starts from the last,
/// so the same sequence of solves gives the same frames).
#[test]
fn a_range_of_frames_matches_the_whole_export() {
    let dir = std::env::temp_dir().join(format!("facesim-export-range-{}", std::process::id()));
    atomic::remove_any(&dir).unwrap();
    let track = short_track();
    let job = |name: &str, range: Option<FrameRange>| ExportJob {
        range,
        ..core_job(name, &dir)
    };
    let whole = export(neutral(), &track, &job("whole", None), None, &mut |_, _| {}).unwrap();
    assert_eq!((whole.first, whole.frames), (0, 4));
    let range = FrameRange {
        first: 2,
        end: 99,
        lead_in: 2,
    };
    let part = export(
        neutral(),
        &track,
        &job("part", Some(range)),
        None,
        &mut |_, _| {},
    )
    .unwrap();
    assert_eq!((part.first, part.frames), (2, 2), "frames 2 and 3 of 0..4");
    let (_, all) = pc2::read(&dir.join("whole.pc2")).unwrap();
    let (header, some) = pc2::read(&dir.join("part.pc2")).unwrap();
    assert_eq!(header.start_frame, 2.0);
    assert_eq!(some[..], all[2..], "the lead-in reproduces the warm starts");
    assert_eq!(
        listing(&dir.join("part_obj")),
        ["part_0002.obj", "part_0003.obj"]
    );
    let usda = std::fs::read_to_string(dir.join("part.usda")).unwrap();
    assert!(usda.contains("startTimeCode = 2") && usda.contains("endTimeCode = 3"));
    let report: report::ExportReport =
        serde_json::from_str(&std::fs::read_to_string(dir.join("part.report.json")).unwrap())
            .unwrap();
    let numbers: Vec<usize> = report.frames.iter().map(|f| f.frame).collect();
    assert_eq!(numbers, [2, 3]);
    let (json, _) = gltf::read_glb(&dir.join("part.glb")).unwrap();
    let times = &json["animations"][0]["samplers"][0]["input"];
    let times = &json["accessors"][times.as_u64().unwrap() as usize];
    assert_eq!(times["min"][0].as_f64().unwrap() as f32, 0.2);

    let past = FrameRange {
        first: 10,
        end: 20,
        lead_in: 0,
    };
    let err = export(
        neutral(),
        &track,
        &job("none", Some(past)),
        None,
        &mut |_, _| {},
    );
    assert!(matches!(err, Err(ExportError::EmptyRange { total: 4, .. })));
    atomic::remove_any(&dir).unwrap();
}

/// The 10-second example track (`examples/tracks/smile.json`: a smile, a jaw opening, a
/// pucker, a roll and a press) exported as `facesim export` does by default, at the final
/// preset with contact: every frame converged and none crossing anywhere in skin, mouth
/// lining and teeth by the report's independent audit of the whole render surface. At 10 fps
/// (the README's figure is the same track at 30 fps): each frame moves three times as far.
#[test]
fn the_example_track_exports_converged_and_crossing_free_with_contact() {
    let dir = std::env::temp_dir().join(format!("facesim-export-smile-{}", std::process::id()));
    atomic::remove_any(&dir).unwrap();
    let track =
        Track::load(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("examples/tracks/smile.json"))
            .unwrap();
    let job = ExportJob {
        formats: vec![Format::Pc2],
        quality: Quality::Final,
        contact: true,
        ..core_job("smile", &dir)
    };
    let summary = export(neutral(), &track, &job, None, &mut |_, _| {}).unwrap();
    assert_eq!(summary.frames, 101);
    assert_eq!(summary.unconverged, 0, "{summary:?}");
    assert_eq!(summary.crossing_frames, 0, "{summary:?}");
    atomic::remove_any(&dir).unwrap();
}
