//! `facesim export` as a user runs it, with its files checked by other tools' readers: the
//! USD layer by Pixar's USD (`pip install usd-core==26.11`, `tests/python/check_usd.py`) and the
//! glTF file by the Khronos glTF validator (`npm ci --prefix tests/gltf`, `tests/gltf/validate.js`),
//! and the PC2 cache with its OBJ and the glTF file by Blender (Debian's `blender` and
//! `python3-numpy`, `tests/blender/check_export.py`). All are required: the test FAILS, saying
//! what to install, when they are missing (CI installs them in .ci/run).

use std::path::{Path, PathBuf};
use std::process::Command;

/// The repository's root (the CLI crate is `cli/`).
fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn python() -> String {
    std::env::var("FACESIM_PYTHON").unwrap_or_else(|_| "python3".into())
}

fn run(cmd: &mut Command, what: &str, install: &str) -> String {
    let out = match cmd.output() {
        Ok(o) => o,
        Err(e) => panic!("cannot run {what} ({e}); {install}"),
    };
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{what} failed:\n{text}");
    text
}

fn require_usd() {
    let out = Command::new(python())
        .args(["-c", "from pxr import Usd, UsdGeom"])
        .output();
    let install = "the USD check needs Pixar's USD for Python: pip install usd-core==26.11";
    match out {
        Ok(o) if o.status.success() => {}
        Ok(o) => panic!(
            "{install} (`{} -c \"from pxr import Usd, UsdGeom\"` failed:\n{})",
            python(),
            String::from_utf8_lossy(&o.stderr)
        ),
        Err(e) => panic!("cannot run `{}` ({e}); {install}", python()),
    }
}

fn require_gltf_validator() -> PathBuf {
    let install = "the glTF check needs Node.js (node) and the Khronos validator: \
                   npm ci --prefix tests/gltf";
    if Command::new("node").arg("--version").output().is_err() {
        panic!("cannot run `node`; {install}");
    }
    let module = root().join("tests/gltf/node_modules/gltf-validator");
    assert!(
        module.exists(),
        "{} is missing; {install}",
        module.display()
    );
    root().join("tests/gltf/validate.js")
}

fn require_blender() {
    let install = "the Blender check needs Blender and numpy for its Python: \
                   apt-get install blender python3-numpy";
    match Command::new("blender").arg("--version").output() {
        Ok(o) if o.status.success() => {}
        Ok(o) => panic!("`blender --version` failed ({}); {install}", o.status),
        Err(e) => panic!("cannot run `blender` ({e}); {install}"),
    }
}

fn write_track(path: &Path) {
    let zero = vec![0.0; 19];
    let mut open = zero.clone();
    open[0] = 0.4; // jawOpen
    open[5] = 0.5; // mouthSmile_L
    let key = |t: f64, e: &Vec<f64>| serde_json::json!({"time": t, "codes": {"expression": e, "style": [0.0, 0.0, 0.0, 0.0]}});
    let track = serde_json::json!({
        "format": "facesim-track", "version": 1, "face": "neutral",
        "keys": [key(0.0, &zero), key(0.3, &open)],
    });
    std::fs::write(path, track.to_string()).unwrap();
}

#[test]
fn exported_usd_gltf_and_pc2_pass_their_reference_readers() {
    require_usd();
    require_blender();
    let validate_js = require_gltf_validator();
    let dir = std::env::temp_dir().join(format!("facesim-export-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let track = dir.join("blink.json");
    write_track(&track);
    let out = dir.join("out");
    let text = run(
        Command::new(env!("CARGO_BIN_EXE_facesim"))
            .current_dir(root())
            .arg("export")
            .arg(&track)
            .arg("--out")
            .arg(&out)
            .args([
                "--format",
                "usd,pc2,gltf",
                "--fps",
                "10",
                "--quality",
                "interactive",
                "--contact",
                "on",
            ]),
        "facesim export",
        "build it with cargo",
    );
    assert!(text.contains("4 frames in"), "{text}");
    assert!(
        text.contains("contact on") && text.contains("of 4 frames unconverged"),
        "{text}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("blink.report.json")).unwrap())
            .unwrap();
    assert_eq!(report["contact"], true);
    assert_eq!(report["frames"].as_array().unwrap().len(), 4);
    let (header, _) = facesim::export::pc2::read(&out.join("blink.pc2")).unwrap();
    let topology = facesim::rig::obj::ObjMesh::read(out.join("blink.obj")).unwrap();
    assert_eq!(header.samples, 4);
    assert_eq!(header.points as usize, topology.positions.len());

    let usd = run(
        Command::new(python())
            .arg(root().join("tests/python/check_usd.py"))
            .arg(out.join("blink.usda"))
            .arg("4")
            .arg(header.points.to_string())
            .arg(topology.triangles().len().to_string())
            .arg("10"),
        "the USD check",
        "pip install usd-core==26.11",
    );
    assert!(usd.contains("ok"), "{usd}");

    let gltf = run(
        Command::new("node")
            .arg(&validate_js)
            .arg(out.join("blink.glb")),
        "the glTF validator",
        "npm ci --prefix tests/gltf",
    );
    assert!(gltf.contains(" 0 errors"), "{gltf}");

    let blender = run(
        Command::new("blender")
            .args([
                "--background",
                "--factory-startup",
                "--python-exit-code",
                "1",
                "--python",
            ])
            .arg(root().join("tests/blender/check_export.py"))
            .arg("--")
            .arg(out.join("blink.obj"))
            .arg(out.join("blink.pc2"))
            .arg(out.join("blink.glb"))
            .arg("4"),
        "the Blender check",
        "apt-get install blender python3-numpy",
    );
    assert!(blender.contains("\nok: "), "{blender}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_core_binary_sends_rrd_exports_to_the_editor() {
    let out = Command::new(env!("CARGO_BIN_EXE_facesim"))
        .args([
            "export",
            "missing.json",
            "--out",
            "unused",
            "--format",
            "usd,rrd",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("editor binary") && err.contains("cargo run --release -- export"),
        "{err}"
    );
}
