//! ARCHITECTURE.md's "never" rules, checked mechanically:
//! - the core crate depends on no UI or viewer crate (egui, eframe, wgpu, winit, rerun) and no
//!   command-line crate (clap, indicatif, anyhow);
//! - modules import only modules of lower layers (the IPC kit nothing face-specific, the solver
//!   no face, rig or session).
//!
//! Imports are the `crate::<module>` paths of non-test code (a file's text up to its first
//! `#[cfg(test)]`; `tests.rs` and `test_support` files are test code).

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The layers, lowest first; a module imports only from lower layers.
const LAYERS: &[&[&str]] = &[
    &["geometry", "nn", "plot", "stats", "table"],
    &["contact"],
    &["sim"],
    &["slab", "rig"],
    &["model"],
    &["drive", "mapping"],
    &["sequence"],
    &["session"],
    &["sample"],
    &["generative"],
    &["export"],
    &["bench"],
];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|l| l.contains(&module))
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The crate modules `text` names as `crate::<module>`.
fn imported(text: &str) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for (at, _) in text.match_indices("crate::") {
        let before = text[..at].chars().next_back();
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue; // `facesim_crate::` and the like
        }
        let name: String = text[at + 7..]
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        found.insert(name);
    }
    found
}

#[test]
fn modules_import_only_from_lower_layers() {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut against = Vec::new();
    for file in &files {
        let rel = file
            .strip_prefix(&src)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        let name = file.file_name().unwrap().to_string_lossy();
        if name == "tests.rs" || name.starts_with("test_support") || rel.contains("/tests/") {
            continue;
        }
        let module = rel.split('/').next().unwrap().trim_end_matches(".rs");
        let Some(own) = layer_of(module) else {
            continue; // lib.rs, the CLI's files: the top
        };
        let text = std::fs::read_to_string(file).unwrap();
        let code = text.split("#[cfg(test)]").next().unwrap();
        for target in imported(code) {
            let Some(theirs) = layer_of(&target) else {
                continue;
            };
            if target == module || theirs < own {
                continue;
            }
            against.push(format!("{rel} imports crate::{target}"));
        }
    }
    assert!(
        against.is_empty(),
        "imports against the layers (ARCHITECTURE.md):\n{}",
        against.join("\n")
    );
}

#[test]
fn the_core_depends_on_no_ui_viewer_or_command_line_crate() {
    let out = Command::new(env!("CARGO"))
        .args([
            "tree",
            "-p",
            "facesim",
            "-e",
            "normal,build",
            "--prefix",
            "none",
        ])
        .args(["--format", "{p}"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("cargo tree");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let tree = String::from_utf8_lossy(&out.stdout);
    assert!(tree.lines().any(|l| l.starts_with("nalgebra ")), "{tree}");
    // UI and viewer crates live in `ui/`; arguments, progress bars and error context in the
    // binaries (`cli/`).
    let banned = [
        "egui",
        "eframe",
        "wgpu",
        "winit",
        "rerun",
        "re_sdk",
        "clap",
        "indicatif",
        "anyhow",
    ];
    let found: BTreeSet<&str> = tree
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .filter(|name| {
            banned
                .iter()
                .any(|b| name == b || name.starts_with(&format!("{b}-")))
        })
        .collect();
    assert!(found.is_empty(), "the core crate depends on {found:?}");
}
