//! `facesim-editor export --format rrd,pc2`: the editor binary writes the core formats and a
//! rerun recording of the same frames; the `.rrd` is read back with the rerun Python SDK
//! (`rerun-sdk==0.36.3`, `ui/tests/check_export_rrd.py`).

use std::path::PathBuf;
use std::process::Command;

#[test]
fn the_editor_binary_exports_an_rrd_that_reads_back() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let dir = std::env::temp_dir().join(format!("facesim-export-rrd-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let track = dir.join("nod.json");
    let mut open = vec![0.0; 19];
    open[0] = 0.3;
    let key = |t: f64, e: &Vec<f64>| serde_json::json!({"time": t, "codes": {"expression": e, "style": [0.0, 0.0, 0.0, 0.0]}});
    std::fs::write(
        &track,
        serde_json::json!({"format": "facesim-track", "version": 1, "face": "neutral",
                           "keys": [key(0.0, &vec![0.0; 19]), key(0.2, &open)]})
        .to_string(),
    )
    .unwrap();
    let out = dir.join("out");
    let run = Command::new(env!("CARGO_BIN_EXE_facesim-editor"))
        .arg("export")
        .arg(&track)
        .arg("--out")
        .arg(&out)
        .args(["--format", "rrd,pc2", "--fps", "10", "--sample"])
        .arg(root.join(facesim::sample::SAMPLE_DIR))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{text}");
    let (header, _) = facesim::export::pc2::read(&out.join("nod.pc2")).unwrap();
    let topology = facesim::rig::obj::ObjMesh::read(out.join("nod.obj")).unwrap();
    assert_eq!(header.samples, 3);
    let check = Command::new("python3")
        .arg(root.join("ui/tests/check_export_rrd.py"))
        .arg(out.join("nod.rrd"))
        .arg("3")
        .arg(header.points.to_string())
        .arg(drawn_triangles(&topology).to_string())
        .arg("10")
        .output()
        .expect("python3 (with rerun-sdk==0.36.3, see .ci/run)");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&check.stdout),
        String::from_utf8_lossy(&check.stderr)
    );
    assert!(check.status.success() && text.contains("ok"), "{text}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The triangles the recording draws: the topology OBJ's, less the eyes' see-through layers
/// (its `usemtl` parts named in `OVERLAY_PARTS`), which the viewers leave out.
fn drawn_triangles(obj: &facesim::rig::obj::ObjMesh) -> usize {
    let total = obj.faces.len();
    let groups = &obj.material_groups;
    let overlay: usize = groups
        .iter()
        .enumerate()
        .filter(|(_, g)| facesim::session::session_face::OVERLAY_PARTS.contains(&g.name.as_str()))
        .map(|(k, g)| groups.get(k + 1).map_or(total, |n| n.first_face) - g.first_face)
        .sum();
    assert!(overlay > 0, "the export names the rig's parts");
    total - overlay
}
