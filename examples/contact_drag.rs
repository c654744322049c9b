//! Per-frame time of `facesim bench contact`'s slider drag at the interactive preset, with
//! contact on (gate off) or off (`--off`), four passes in a row: a quick, steady figure for
//! comparing two builds of the contact code back to back (run it with
//! `RAYON_NUM_THREADS=1` so other work on the machine disturbs it less).
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p facesim --example contact_drag [-- --off]`
//! (from the repository root; reads `sample_models/ict/neutral-coarse.face`).

use anyhow::{Context, Result};
use facesim::bench::contact::{ContactScene, Sequence};
use facesim::sim::{ContactGate, Quality, SolveSettings};

const FRAMES: usize = 8;
const PASSES: usize = 4;

fn main() -> Result<()> {
    let contact = !std::env::args().any(|a| a == "--off");
    let path = std::path::Path::new("sample_models/ict/neutral-coarse.face");
    let model = facesim::model::FaceModel::load(path)
        .with_context(|| format!("loading {} (run from the repository root)", path.display()))?;
    let mut scene = ContactScene::new(&model)?;
    scene.sim.set_contact_gate(ContactGate::Always);
    let settings = SolveSettings {
        contact,
        ..Quality::Interactive.settings()
    };
    let mut all = Vec::new();
    for pass in 0..PASSES {
        let outcomes = scene.run(Sequence::Drag, FRAMES, &settings);
        let mut ms = Vec::new();
        for o in &outcomes {
            let stats = o
                .result
                .as_ref()
                .map_err(|e| anyhow::anyhow!("frame {}: {e}", o.frame))?;
            ms.push(stats.wall_time.as_secs_f64() * 1e3);
        }
        println!("pass {pass}: frames (ms) {:.0?}", ms);
        all.extend(ms);
    }
    all.sort_by(f64::total_cmp);
    println!(
        "contact {}: median frame {:.1} ms over {} frames",
        if contact { "on" } else { "off" },
        all[all.len() / 2],
        all.len()
    );
    Ok(())
}
