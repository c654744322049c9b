//! An `.rrd` written by the editor's rerun logger is read back with the rerun Python SDK
//! (`rerun-sdk==0.36.3`, `rerun.experimental.RrdReader`) and checked: entities, frame count,
//! vertex count, scalar values; and screenshotted by the headless viewer, where the face must
//! fill the default blueprint's 3D view.

use std::path::{Path, PathBuf};
use std::time::Duration;

use facesim::rig::ExpressionCode;
use facesim::session::{Request, Session};
use facesim::sim::Quality;
use facesim_ui::rerun_log::{RerunLogger, RerunTarget, entity_name};

#[test]
fn an_rrd_written_by_the_editor_reads_back_in_the_python_sdk() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let faces = facesim_ui::faces::load_sample(&root.join(facesim::sample::SAMPLE_DIR)).unwrap();
    let session = Session::new(faces, Quality::Interactive).unwrap();
    session.submit(Request::Refine(false)).unwrap();
    let dir = std::env::temp_dir().join(format!("facesim-rrd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rrd = dir.join("session.rrd");
    let logger = RerunLogger::new(&RerunTarget::Save(rrd.clone())).unwrap();
    let topology = session.topology(0).unwrap();
    let (mut frames, mut residuals, mut heatmaps) = (Vec::new(), Vec::new(), Vec::new());
    for w in [0.0, 0.3, 0.6, 0.9] {
        let g = session
            .submit(Request::Expression(
                ExpressionCode::single("jawOpen", w).unwrap(),
            ))
            .unwrap();
        let f = session.wait_generation(g, Duration::from_secs(60)).unwrap();
        assert!(f.error.is_none());
        logger.log(&f, &topology).unwrap();
        frames.push(f.index);
        residuals.push(f.stats.residual);
        heatmaps = f.heatmaps.iter().map(|h| entity_name(&h.name)).collect();
    }
    logger.flush();
    drop(logger); // closes the file
    let expected = dir.join("expected.json");
    std::fs::write(
        &expected,
        serde_json::json!({
            "frames": frames,
            "residuals": residuals,
            "vertices": topology.rest.len(),
            "triangles": topology.triangles.len(),
            "heatmaps": heatmaps,
        })
        .to_string(),
    )
    .unwrap();
    python_check(&root.join("ui/tests/check_rrd.py"), &[&rrd, &expected]);

    // The recording opens framed: the headless viewer's screenshot shows the face large and
    // upright and from the front in the default blueprint's 3D view.
    let picture = dir.join("viewer.png");
    let out = std::process::Command::new("python3")
        .args(["-m", "rerun"])
        .arg(&rrd)
        .args(["--headless", "--window-size", "1200x800", "--screenshot-to"])
        .arg(&picture)
        .output()
        .expect("python3 -m rerun (rerun-sdk==0.36.3, see .ci/run)");
    assert!(
        out.status.success(),
        "the headless viewer failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    python_check(&root.join("ui/tests/check_rrd_screenshot.py"), &[&picture]);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Runs a Python check script on `args`; it must succeed and say "ok".
fn python_check(script: &Path, args: &[&Path]) {
    let out = std::process::Command::new("python3")
        .arg(script)
        .args(args)
        .output()
        .expect("python3 (with rerun-sdk==0.36.3, see .ci/run)");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success() && text.contains("ok"), "{text}");
}
