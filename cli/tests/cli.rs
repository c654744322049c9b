//! The `facesim` binary as a user runs it.

use std::process::Command;

/// The binary, run from the repository's root (the CLI crate is `cli/`), as the README runs it.
fn facesim() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_facesim"));
    command.current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    command
}

/// Runs `command`, which must succeed (its stderr is the message otherwise); its stdout.
fn stdout_of(command: &mut Command) -> String {
    let out = command.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Runs `command`, which must fail; its stderr.
fn stderr_of_failure(command: &mut Command) -> String {
    let out = command.output().unwrap();
    assert!(!out.status.success(), "{command:?} succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The face rig the training and evaluation commands read.
fn rig_dir() -> String {
    std::env::var("FACESIM_RIG_DIR").unwrap_or_else(|_| "../shared/data/ict-facekit".into())
}

#[test]
fn bench_solver_prints_a_table_and_writes_json() {
    let json = std::env::temp_dir().join(format!("facesim-bench-{}.json", std::process::id()));
    let table = stdout_of(
        facesim()
            .args([
                "bench",
                "solver",
                "--elements",
                "600",
                "--samples",
                "1",
                "--json",
            ])
            .arg(&json),
    );
    assert!(
        table.contains("| elements |") && table.lines().count() == 3,
        "{table}"
    );
    let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    std::fs::remove_file(&json).ok();
    let row = &rows[0];
    assert!(row["elements"].as_u64().unwrap() > 400);
    assert!(row["floor_ratio"].as_f64().unwrap() > 0.0);
    for key in ["from_rest", "warm"] {
        let reached = row[key].as_array().unwrap();
        assert_eq!(reached.len(), 2);
        assert!(
            reached
                .iter()
                .all(|t| t["iterations"].as_u64().unwrap() < 5000)
        );
    }
}

/// `bench tradeoff --replot` redraws the table and the plot of a saved run (the README's
/// picture comes from `docs/performance/tradeoff.json`) without solving.
#[test]
fn the_trade_plot_redraws_from_a_saved_run() {
    let out = std::env::temp_dir().join(format!("facesim-replot-{}", std::process::id()));
    let table = stdout_of(facesim().args(["bench", "tradeoff", "--replot"]).args([
        "docs/performance/tradeoff.json",
        "--out",
        out.to_str().unwrap(),
    ]));
    assert_eq!(table.lines().count(), 11, "{table}");
    assert!(
        table.contains("| coarse | 4980 | final | on (always) |"),
        "{table}"
    );
    assert_eq!(
        std::fs::read_to_string(out.join("tradeoff.md")).unwrap(),
        table
    );
    let png = std::fs::read(out.join("tradeoff.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert!(
        !out.join("tradeoff.json").exists(),
        "a replot writes no rows"
    );
    std::fs::remove_dir_all(&out).ok();
    let bad = stderr_of_failure(facesim().args(["bench", "tradeoff", "--replot", "README.md"]));
    assert!(bad.contains("is not a tradeoff.json"), "{bad}");
}

#[test]
fn bad_arguments_fail_with_a_message() {
    assert!(
        stderr_of_failure(facesim().args(["bench", "solver", "--elements", "many"]))
            .contains("invalid value")
    );
    let export = |frames: &str| {
        stderr_of_failure(facesim().args([
            "export",
            "examples/tracks/smile.json",
            "--out",
            "unused",
            "--format",
            "pc2",
            "--frames",
            frames,
        ]))
    };
    assert!(export("12").contains("is not a frame range A..B"));
    assert!(export("9..3").contains("the range 9..3 is empty"));
    assert!(export("400..500").contains("hold none of the track's 301 frames"));
}

/// `export --actuation networks` drives the face with the sample's networks through its φ: the
/// same frames as with its basis, solved from other actuations, so other positions.
#[test]
fn export_drives_the_face_with_the_chosen_actuation() {
    let dir = std::env::temp_dir().join(format!("facesim-cli-actuation-{}", std::process::id()));
    let export = |actuation: &str| {
        let out = dir.join(actuation);
        let status = facesim()
            .args(["export", "examples/tracks/smile.json", "--format", "pc2"])
            .args([
                "--frames",
                "45..47",
                "--lead-in",
                "0",
                "--face",
                "identity000",
            ])
            .args(["--actuation", actuation, "--out"])
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&status.stderr).into_owned();
        assert!(status.status.success(), "{err}");
        assert!(err.contains(&format!("actuation {actuation}")), "{err}");
        let report = std::fs::read_to_string(out.join("smile.report.json")).unwrap();
        let report: serde_json::Value = serde_json::from_str(&report).unwrap();
        assert_eq!(report["actuation"], actuation);
        // Each frame carries its crease audit.
        let frames = report["frames"].as_array().unwrap();
        assert!(
            !frames.is_empty() && frames.iter().all(|f| f["creases"].is_u64()),
            "{report}"
        );
        facesim::export::pc2::read(&out.join("smile.pc2"))
            .unwrap()
            .1
    };
    let (basis, networks) = (export("basis"), export("networks"));
    assert_eq!((basis.len(), networks.len()), (2, 2));
    let apart = basis[1]
        .iter()
        .zip(&networks[1])
        .map(|(a, b)| (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f32::max))
        .fold(0.0, f32::max);
    assert!(
        apart > 1e-3 && apart < 2.0,
        "the exports differ by up to {apart} cm"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `export` renders at the final preset with contact unless told otherwise: on a lip press
/// (mouthPress_L/R at 1 with mouthClose at 0.5, and back) every frame converges and the audit
/// finds no crossing anywhere in skin, lining and teeth, where without contact the lips pass
/// through each other in every pressed frame. (The floor of the mouth used to follow the
/// tissue and sweep through the lower incisors, 2–80 pairs a frame: the bones carry it now,
/// `model::bindings`.)
#[test]
fn export_defaults_to_final_with_contact_and_keeps_the_pressed_lips_apart() {
    let dir = std::env::temp_dir().join(format!("facesim-cli-press-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let track = dir.join("press.json");
    let mut press = vec![0.0; 19];
    (press[4], press[15], press[16]) = (0.5, 1.0, 1.0);
    let key = |t: f64, e: &Vec<f64>| serde_json::json!({"time": t, "codes": {"expression": e, "style": [0.0, 0.0, 0.0, 0.0]}});
    let rest = vec![0.0; 19];
    std::fs::write(
        &track,
        serde_json::json!({"format": "facesim-track", "version": 1, "face": "neutral",
                           "keys": [key(0.0, &rest), key(0.5, &press), key(1.0, &rest)]})
        .to_string(),
    )
    .unwrap();
    let export = |extra: &[&str]| {
        let out = dir.join(if extra.is_empty() { "default" } else { "off" });
        let run = facesim()
            .arg("export")
            .arg(&track)
            .args(["--format", "pc2", "--fps", "10"])
            .args(extra)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&run.stderr).into_owned();
        assert!(run.status.success(), "{err}");
        let report = std::fs::read_to_string(out.join("press.report.json")).unwrap();
        let report: serde_json::Value = serde_json::from_str(&report).unwrap();
        (err, report)
    };
    let pieces = |report: &serde_json::Value| -> Vec<String> {
        let mut all: Vec<String> = report["frames"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|f| f["crossing_pieces"].as_array().unwrap().clone())
            .map(|p| p[0].as_str().unwrap().to_owned())
            .collect();
        all.sort();
        all.dedup();
        all
    };

    let (text, report) = export(&[]);
    assert!(
        text.contains("at the final preset, contact on")
            && text.contains("0 of 11 frames unconverged"),
        "{text}"
    );
    assert_eq!(
        (report["quality"].as_str(), report["contact"].as_bool()),
        (Some("final"), Some(true))
    );
    assert_eq!(
        (report["crossing_frames"].as_u64(), pieces(&report)),
        (Some(0), vec![]),
        "with contact"
    );

    let (_, report) = export(&["--contact", "off"]);
    assert!(
        pieces(&report).contains(&"face skin / face skin".to_owned()),
        "without contact the pressed lips cross: {:?}",
        pieces(&report)
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `add-face` refuses a mesh off the rig's topology, naming the file and what it needs, and
/// leaves the sample as it was.
#[test]
fn add_face_refuses_a_mesh_off_the_rigs_topology() {
    let dir = std::env::temp_dir().join(format!("facesim-cli-add-face-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/../sample_models/ict");
    for file in ["sample.json", "neutral-coarse.face"] {
        std::fs::copy(format!("{sample}/{file}"), dir.join(file)).unwrap();
    }
    let scan = dir.join("scan.obj");
    std::fs::write(&scan, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let arg = std::ffi::OsStr::new;
    let rig = rig_dir();
    let message = stderr_of_failure(facesim().args([
        arg("add-face"),
        scan.as_os_str(),
        arg("--sample"),
        dir.as_os_str(),
        arg("--rig"),
        arg(&rig),
        arg("--style"),
        arg("-0.5,0.2,0,0.6"),
    ]));
    assert!(
        message.contains("scan.obj: has 3 vertices") && message.contains("rig's topology"),
        "{message}"
    );
    let style = stderr_of_failure(facesim().args([
        arg("add-face"),
        scan.as_os_str(),
        arg("--sample"),
        dir.as_os_str(),
        arg("--style"),
        arg("0.5,0.2"),
    ]));
    assert!(style.contains("--style takes 4 numbers"), "{style}");
    let manifest = std::fs::read_to_string(dir.join("sample.json")).unwrap();
    assert_eq!(
        manifest,
        std::fs::read_to_string(format!("{sample}/sample.json")).unwrap()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The displacement baseline end to end: `train --stage displacement` (a few poses per face,
/// 3 iterations) writes its networks and loss curve; `eval --displacement … --transfer` poses
/// a held-out code with it beside the physics models and writes the transfer table.
#[test]
fn train_displacement_then_eval_with_it() {
    let rig = rig_dir();
    let dir = std::env::temp_dir().join(format!("facesim-displacement-{}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    stdout_of(
        facesim()
            .args([
                "train",
                "--stage",
                "displacement",
                "--sample",
                "sample_models/ict",
                "--rig",
                &rig,
            ])
            .args([
                "--iterations",
                "3",
                "--combinations",
                "0",
                "--seed",
                "2",
                "--out",
            ])
            .arg(&dir),
    );
    let model = dir.join("displacement.nn");
    assert!(model.exists() && dir.join("displacement-checkpoint.nn").exists());
    let csv = std::fs::read_to_string(dir.join("displacement-loss.csv")).unwrap();
    assert_eq!(csv.lines().count(), 4, "{csv}");
    assert!(
        !dir.join("generative.nn").exists(),
        "stage 1's file is not written"
    );

    let eval = dir.join("eval");
    let table = stdout_of(
        facesim()
            .args(["eval", "--sample", "sample_models/ict", "--rig", &rig])
            .args([
                "--model",
                "sample_models/ict/generative.nn",
                "--held-out",
                "1",
                "--transfer",
            ])
            .arg("--displacement")
            .arg(&model)
            .arg("--out")
            .arg(&eval),
    );
    assert!(
        table.contains("| neutral | displacement | 1/1 |"),
        "{table}"
    );
    assert!(table.contains("rig targets with lip crossings"), "{table}");
    let transfer = std::fs::read_to_string(eval.join("transfer.md")).unwrap();
    assert!(transfer.contains("identity001 basis on B"), "{transfer}");
    // A stage-1 file is not a baseline.
    assert!(
        stderr_of_failure(
            facesim()
                .args([
                    "eval",
                    "--sample",
                    "sample_models/ict",
                    "--rig",
                    &rig,
                    "--held-out",
                    "1",
                ])
                .args(["--model", "sample_models/ict/generative.nn"])
                .args(["--displacement", "sample_models/ict/generative.nn", "--out"])
                .arg(&eval)
        )
        .contains("not a displacement-baseline file")
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Stage 2 end to end: `train --stage 2` (the bundled stage-1 networks, 2 iterations of 2
/// poses) writes its networks, checkpoint and loss curve with the skipped-pose column, and the
/// networks it wrote load in `eval`; a second run refuses to overwrite the checkpoint.
#[test]
fn train_stage2_then_eval_with_it() {
    let rig = rig_dir();
    let dir = std::env::temp_dir().join(format!("facesim-stage2-{}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    let train = || {
        let mut command = facesim();
        command
            .args(["train", "--stage", "2", "--sample", "sample_models/ict"])
            .args(["--init", "sample_models/ict/generative.nn", "--rig", &rig])
            .args(["--iterations", "2", "--batch", "2", "--combinations", "0"])
            .arg("--out")
            .arg(&dir);
        command
    };
    stdout_of(&mut train());
    let model = dir.join("generative-stage2.nn");
    assert!(model.exists() && dir.join("stage2-checkpoint.nn").exists());
    let csv = std::fs::read_to_string(dir.join("stage2-loss.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "{csv}");
    assert!(csv.lines().next().unwrap().ends_with(",skipped_poses"));
    stderr_of_failure(&mut train()); // the checkpoint exists

    let table = stdout_of(
        facesim()
            .args(["eval", "--sample", "sample_models/ict", "--rig", &rig])
            .args(["--held-out", "1", "--model"])
            .arg(&model)
            .arg("--out")
            .arg(dir.join("eval")),
    );
    assert!(table.contains("| neutral | networks | 1/1 |"), "{table}");
    std::fs::remove_dir_all(&dir).ok();
}

/// The random-code sweep as the acceptance run drives it (`bench contact --sweep`, on the
/// bundled sample): per-frame lines on stderr, the summary with how many frames were solved
/// from rest, and the JSON report.
#[test]
fn contact_sweep_reports_frames_and_writes_json() {
    let json = std::env::temp_dir().join(format!("facesim-sweep-{}.json", std::process::id()));
    let out = facesim()
        .args([
            "bench",
            "contact",
            "--sweep",
            "2",
            "--sweep-seed",
            "127",
            "--json",
        ])
        .arg(&json)
        .output()
        .unwrap();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("frame 1 (contact): "), "{stderr}");
    assert!(
        stdout.contains("contact on: 2 frames, 2 ok (") && stdout.contains(" from rest), "),
        "{stdout}"
    );
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    std::fs::remove_file(&json).ok();
    assert_eq!(report["contact"]["ok"], 2);
    assert_eq!(report["contact"]["intersecting"], 0);
    assert_eq!(report["contact"]["from_rest"], 0);

    // Typed arguments: a bad range or mode is refused before anything loads.
    for (flag, value, says) in [
        ("--sweep-range", "1.5,-0.5", "LOW ≤ HIGH"),
        ("--sweep-range", "0,nan", "LOW ≤ HIGH"),
        ("--sweep-mode", "sometimes", "no-contact"),
    ] {
        let stderr =
            stderr_of_failure(facesim().args(["bench", "contact", "--sweep", "1", flag, value]));
        assert!(stderr.contains(says), "{flag} {value}: {stderr}");
    }
}

/// `bench shapes` measures the chosen sliders on the chosen faces against the rig, vertex by
/// vertex, and refuses a slider or face it does not know. The neutral face's jawOpen skin
/// was 42.4 mm from the rig before the mouth's bindings took the jaw's side (face format 3).
#[test]
fn bench_shapes_measures_one_slider_against_the_rig_and_refuses_unknown_names() {
    let json = std::env::temp_dir().join(format!("facesim-shapes-{}.json", std::process::id()));
    let rig = rig_dir();
    let table = stdout_of(facesim().args([
        "bench",
        "shapes",
        "--rig",
        &rig,
        "--faces",
        "neutral,identity000",
        "--shapes",
        "jawOpen",
        "--contact",
        "off",
        "--json",
        json.to_str().unwrap(),
    ]));
    assert!(table.contains("| neutral | jawOpen | off |"), "{table}");
    // The per-face summary follows, one line per face and contact setting.
    assert!(table.contains("| neutral | off | 1 of 1 |"), "{table}");
    assert!(table.contains("| identity000 | off | 1 of 1 |"), "{table}");
    let rows: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let _ = std::fs::remove_file(&json);
    let rows = rows.as_array().unwrap();
    assert_eq!(rows.len(), 2, "{rows:?}");
    // identity000's jawOpen (with its style) squeezed the lips' corners into the volume
    // barrier and found no equilibrium before the volume floor.
    for row in rows {
        assert_eq!(row["termination"], "Converged", "{row:?}");
    }
    let max = rows[0]["skin_max_mm"].as_f64().unwrap();
    assert!(
        max <= 2.0,
        "jawOpen's skin is {max} mm from the rig at worst"
    );
    // The crease audit of the result and of the rig's own shape (which creases nothing
    // there).
    assert!(rows[0]["creases"].is_u64(), "{:?}", rows[0]);
    assert_eq!(rows[0]["rig_creases"], 0, "{:?}", rows[0]);
    assert_eq!(
        rows[0]["creases_beyond_rig"], rows[0]["creases"],
        "{:?}",
        rows[0]
    );
    assert!(table.contains("creases beyond the rig"), "{table}");

    let err = stderr_of_failure(facesim().args(["bench", "shapes", "--shapes", "jawOpenn"]));
    assert!(
        err.contains("unknown expression slider 'jawOpenn'"),
        "{err}"
    );
    let err = stderr_of_failure(facesim().args([
        "bench", "shapes", "--rig", &rig, "--faces", "nobody", "--shapes", "jawOpen",
    ]));
    assert!(err.contains("the sample has no face 'nobody'"), "{err}");
}

/// `bench editor --presets` measures only the presets asked for.
#[test]
fn bench_editor_measures_the_chosen_presets() {
    let table = stdout_of(facesim().args([
        "bench",
        "editor",
        "--sliders",
        "mouthSmile_L",
        "--steps",
        "2",
        "--presets",
        "interactive",
    ]));
    let rows: Vec<&str> = table
        .lines()
        .filter(|l| l.starts_with("| neutral"))
        .collect();
    assert_eq!(rows.len(), 1, "{table}");
    assert!(
        rows[0].starts_with("| neutral | interactive | off | 2 |"),
        "{table}"
    );
    let err = stderr_of_failure(facesim().args(["bench", "editor", "--presets", "fast"]));
    assert!(err.contains("unknown quality 'fast'"), "{err}");
    let err = stderr_of_failure(facesim().args(["bench", "editor", "--sliders", "jawOpenn"]));
    assert!(
        err.contains("unknown expression slider 'jawOpenn'"),
        "{err}"
    );
}

/// Progress written to a log (stderr not a terminal) is plain lines: no carriage returns or
/// terminal escape codes.
#[test]
fn progress_in_a_log_has_no_escape_codes() {
    let out = std::env::temp_dir().join(format!("facesim-import-{}", std::process::id()));
    let err = stderr_of_failure(facesim().args([
        "import",
        "--rig",
        &rig_dir(),
        "--out",
        out.to_str().unwrap(),
        "--identities",
        "99",
    ]));
    assert!(err.contains("loaded 53 shapes and 10 identities"), "{err}");
    assert!(err.contains("identity 99 is not in the rig"), "{err}");
    assert!(!err.contains(['\r', '\x1b']), "{err:?}");
}
