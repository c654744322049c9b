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
