//! The `facesim` binary as a user runs it.

use std::process::Command;

fn facesim() -> Command {
    Command::new(env!("CARGO_BIN_EXE_facesim"))
}

#[test]
fn bench_solver_prints_a_table_and_writes_json() {
    let json = std::env::temp_dir().join(format!("facesim-bench-{}.json", std::process::id()));
    let out = facesim()
        .args([
            "bench",
            "solver",
            "--elements",
            "600",
            "--samples",
            "1",
            "--json",
        ])
        .arg(&json)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8(out.stdout).unwrap();
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

#[test]
fn bad_arguments_fail_with_a_message() {
    let out = facesim()
        .args(["bench", "solver", "--elements", "many"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("invalid value"));
}

/// The displacement baseline end to end: `train --stage displacement` (a few poses per face,
/// 3 iterations) writes its networks and loss curve; `eval --displacement … --transfer` poses
/// a held-out code with it beside the physics models and writes the transfer table.
#[test]
fn train_displacement_then_eval_with_it() {
    let rig =
        std::env::var("FACESIM_RIG_DIR").unwrap_or_else(|_| "../shared/data/ict-facekit".into());
    let dir = std::env::temp_dir().join(format!("facesim-displacement-{}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    let out = facesim()
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
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
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
    let out = facesim()
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
        .arg(&eval)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8(out.stdout).unwrap();
    assert!(
        table.contains("| neutral | displacement | 1/1 |"),
        "{table}"
    );
    assert!(table.contains("rig targets with lip crossings"), "{table}");
    let transfer = std::fs::read_to_string(eval.join("transfer.md")).unwrap();
    assert!(transfer.contains("identity001 basis on B"), "{transfer}");
    // A stage-1 file is not a baseline.
    let out = facesim()
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
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a displacement-baseline file"));
    std::fs::remove_dir_all(&dir).ok();
}

/// Stage 2 end to end: `train --stage 2` (the bundled stage-1 networks, 2 iterations of 2
/// poses) writes its networks, checkpoint and loss curve with the skipped-pose column, and the
/// networks it wrote load in `eval`; a second run refuses to overwrite the checkpoint.
#[test]
fn train_stage2_then_eval_with_it() {
    let rig =
        std::env::var("FACESIM_RIG_DIR").unwrap_or_else(|_| "../shared/data/ict-facekit".into());
    let dir = std::env::temp_dir().join(format!("facesim-stage2-{}", std::process::id()));
    std::fs::remove_dir_all(&dir).ok();
    let train = || {
        facesim()
            .args(["train", "--stage", "2", "--sample", "sample_models/ict"])
            .args(["--init", "sample_models/ict/generative.nn", "--rig", &rig])
            .args(["--iterations", "2", "--batch", "2", "--combinations", "0"])
            .arg("--out")
            .arg(&dir)
            .output()
            .unwrap()
    };
    let out = train();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let model = dir.join("generative-stage2.nn");
    assert!(model.exists() && dir.join("stage2-checkpoint.nn").exists());
    let csv = std::fs::read_to_string(dir.join("stage2-loss.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "{csv}");
    assert!(csv.lines().next().unwrap().ends_with(",skipped_poses"));
    assert!(!train().status.success(), "the checkpoint exists");

    let out = facesim()
        .args(["eval", "--sample", "sample_models/ict", "--rig", &rig])
        .args(["--held-out", "1", "--model"])
        .arg(&model)
        .arg("--out")
        .arg(dir.join("eval"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let table = String::from_utf8(out.stdout).unwrap();
    assert!(table.contains("| neutral | networks | 1/1 |"), "{table}");
    std::fs::remove_dir_all(&dir).ok();
}
