//! Many shots on Ray: `tools/ray/export_shots.py` on a local Ray cluster (PyPI `ray==2.60.0`,
//! required: the test FAILS, saying what to install, without it) exports two short tracks as
//! two Ray tasks, gathers their reports, skips them when run again, reports a broken shot
//! without stopping the others, and splits shots into ranges of frames, a task each.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The repository's root (the CLI crate is `cli/`).
fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn python() -> String {
    std::env::var("FACESIM_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn write_track(path: &Path, jaw: f64) {
    let mut open = vec![0.0; 19];
    open[0] = jaw;
    let key = |t: f64, e: &Vec<f64>| serde_json::json!({"time": t, "codes": {"expression": e, "style": [0.0, 0.0, 0.0, 0.0]}});
    let track = serde_json::json!({
        "format": "facesim-track", "version": 2, "face": "neutral", "quality": "interactive",
        "keys": [key(0.0, &vec![0.0; 19]), key(0.2, &open)],
    });
    std::fs::write(path, track.to_string()).unwrap();
}

fn farm(shots: &Path, out: &Path, extra: &[&str]) -> (Output, serde_json::Value) {
    let run = Command::new(python())
        .arg(root().join("tools/ray/export_shots.py"))
        .arg(shots)
        .arg("--out")
        .arg(out)
        .args(extra)
        .args(["--format", "pc2", "--fps", "10", "--facesim"])
        .arg(env!("CARGO_BIN_EXE_facesim"))
        .arg("--sample")
        .arg(root().join(facesim::sample::SAMPLE_DIR))
        .output()
        .unwrap();
    let report = std::fs::read_to_string(out.join("farm-report.json"))
        .map(|t| serde_json::from_str(&t).unwrap())
        .unwrap_or(serde_json::Value::Null);
    (run, report)
}

/// Fails, saying what to install, without Ray for Python.
fn needs_ray() {
    let check = Command::new(python()).args(["-c", "import ray"]).output();
    assert!(
        check.is_ok_and(|o| o.status.success()),
        "the farm test needs Ray for Python: pip install ray==2.60.0"
    );
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn shots_export_as_ray_tasks_and_a_rerun_continues_where_it_stopped() {
    needs_ray();
    let dir = std::env::temp_dir().join(format!("facesim-ray-{}", std::process::id()));
    let (shots, out) = (dir.join("shots"), dir.join("out"));
    std::fs::create_dir_all(&shots).unwrap();
    write_track(&shots.join("open.json"), 0.4);
    write_track(&shots.join("smile.json"), 0.2);

    let (run, report) = farm(&shots, &out, &[]);
    assert!(run.status.success(), "{}", text(&run));
    assert_eq!(
        (report["done"].as_u64(), report["failed"].as_u64()),
        (Some(2), Some(0))
    );
    for shot in report["shots"].as_array().unwrap() {
        assert_eq!(shot["status"], "done", "{shot}");
        assert_eq!(shot["frames"], 3);
        assert_eq!(shot["quality"], "interactive", "the track's preset");
        let name = shot["shot"].as_str().unwrap();
        for file in [".pc2", ".obj", ".report.json"] {
            assert!(out.join(name).join(format!("{name}{file}")).is_file());
        }
    }
    let cache = out.join("open/open.pc2");
    let written = std::fs::metadata(&cache).unwrap().modified().unwrap();

    // Run again with a broken shot beside: the finished ones are skipped, the broken one is
    // reported as failed, and the exit code says so.
    std::fs::write(shots.join("broken.json"), "{ not a track").unwrap();
    let (run, report) = farm(&shots, &out, &[]);
    assert!(!run.status.success(), "{}", text(&run));
    assert_eq!(
        (report["skipped"].as_u64(), report["failed"].as_u64()),
        (Some(2), Some(1)),
        "{}",
        text(&run)
    );
    assert_eq!(
        std::fs::metadata(&cache).unwrap().modified().unwrap(),
        written
    );
    assert!(text(&run).contains("broken failed"), "{}", text(&run));

    // A long shot split into ranges, one task each: frames keep their numbers.
    std::fs::remove_file(shots.join("broken.json")).unwrap();
    let chunked = dir.join("chunked");
    let (run, report) = farm(&shots, &chunked, &["--chunk", "2", "--lead-in", "2"]);
    assert!(run.status.success(), "{}", text(&run));
    assert_eq!(
        report["done"].as_u64(),
        Some(4),
        "two shots of frames 0..2 and 2..3"
    );
    let (header, samples) =
        facesim::export::pc2::read(&chunked.join("open/frames-2-3/open.pc2")).unwrap();
    assert_eq!((header.start_frame, samples.len()), (2.0, 1));
    let (whole, _) = facesim::export::pc2::read(&out.join("open/open.pc2")).unwrap();
    assert_eq!(whole.samples, 3);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The contact sweep as Ray shards (`tools/ray/contact_sweep.py`): two shards of two codes
/// each, merged; each shard is the sweep that seed gives when run alone (same outcomes), a
/// rerun skips the shards that are done, and bad arguments are refused.
#[test]
fn the_contact_sweep_runs_as_ray_shards_and_merges_them() {
    needs_ray();
    let dir = std::env::temp_dir().join(format!("facesim-ray-sweep-{}", std::process::id()));
    let sweep = |extra: &[&str]| {
        let run = Command::new(python())
            .arg(root().join("tools/ray/contact_sweep.py"))
            .arg("--out")
            .arg(&dir)
            // Weights up to 0.3: contact frames over the full range cost seconds each.
            .args(["--shards", "2", "--codes", "2", "--first-seed", "7"])
            .args(["--range", "0,0.3", "--root"])
            .arg(root())
            .arg("--facesim")
            .arg(env!("CARGO_BIN_EXE_facesim"))
            .args(extra)
            .output()
            .unwrap();
        let report = std::fs::read_to_string(dir.join("sweep-report.json"))
            .map(|t| serde_json::from_str::<serde_json::Value>(&t).unwrap())
            .unwrap_or(serde_json::Value::Null);
        (run, report)
    };
    let (run, report) = sweep(&[]);
    assert!(run.status.success(), "{}", text(&run));
    assert_eq!(
        (report["done"].as_u64(), report["failed"].as_u64()),
        (Some(2), Some(0))
    );
    let on = &report["contact"];
    assert_eq!(on["frames"], 4, "{report}");
    assert_eq!(on["intersecting"], 0, "{report}");
    assert!(on["frame_ms"]["median"].as_f64().unwrap() > 0.0, "{report}");
    assert!(report["no_contact"].is_null(), "contact mode only");

    // Shard seed 8 is the sweep seed 8 gives alone.
    let alone = dir.join("alone.json");
    let direct = Command::new(env!("CARGO_BIN_EXE_facesim"))
        .current_dir(root())
        .args(["bench", "contact", "--sweep", "2", "--sweep-seed", "8"])
        .args(["--sweep-range", "0,0.3", "--json"])
        .arg(&alone)
        .output()
        .unwrap();
    assert!(direct.status.success(), "{}", text(&direct));
    let outcomes = |path: &Path| {
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        r["outcomes"].clone()
    };
    assert_eq!(
        outcomes(&dir.join("shard-contact-0_0.3-n2-seed8.json")),
        outcomes(&alone)
    );

    // Run again: both shards are done and skipped; the merged counts are the same.
    let (run, again) = sweep(&[]);
    assert!(run.status.success(), "{}", text(&run));
    assert_eq!(again["skipped"], 2, "{}", text(&run));
    assert_eq!(again["contact"]["frames"], 4);
    let (run, _) = sweep(&["--range", "1,0"]);
    assert!(!run.status.success());
    assert!(text(&run).contains("LOW <= HIGH"), "{}", text(&run));
    std::fs::remove_dir_all(&dir).unwrap();
}
