//! What the size of the contact region buys: the interactive drag of `facesim bench contact`
//! (gate off, as `contact_drag`) solved with contact regions of several lip reaches, each
//! frame then checked for crossings on the *full* region (the default reach, 1.5 cm). The
//! drag's poses depend only on the lip line, so every row solves the same frames.
//!
//! Prints, per reach: contact vertices, median frame time (two passes of 8 frames), its
//! ratio to the contact-free frame, and the frames (of 16) with crossings on the full region.
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p facesim --example contact_region_size`
//! (from the repository root; reads `sample_models/ict/neutral-coarse.face`).

use anyhow::{Context, Result};
use facesim::bench::mouth_poses::LipField;
use facesim::contact::surface::FaceContact;
use facesim::model::FaceModel;
use facesim::model::contact_region::FaceContactSettings;
use facesim::sim::{ContactGate, Quality, SolveSettings};

const FRAMES: usize = 8;
const PASSES: usize = 2;
const REACHES: [f64; 5] = [1.5, 1.0, 0.6, 0.3, 0.1];

/// Median frame (ms) and frames with crossings on `full`, over `PASSES` runs of the drag.
fn drag(
    model: &FaceModel,
    field: &LipField,
    contact: Option<FaceContact>,
    full: &FaceContact,
) -> Result<(f64, usize)> {
    let mut sim = model.simulator()?;
    let settings = SolveSettings {
        contact: contact.is_some(),
        ..Quality::Interactive.settings()
    };
    if let Some(contact) = contact {
        sim.set_contact(contact)?;
        sim.set_contact_gate(ContactGate::Always);
    }
    let mut ms = Vec::new();
    let mut crossing_frames = 0;
    let mut y = vec![0.0; 3 * full.vertex_count()];
    for _ in 0..PASSES {
        let mut state = sim.rest_state();
        for k in 0..FRAMES {
            let pose = facesim::bench::contact::drag_pose(k, FRAMES);
            let bones = pose.bones();
            let stats = sim
                .solve(&field.actuations(&pose), &bones, &mut state, &settings)
                .with_context(|| format!("frame {k}"))?;
            ms.push(stats.wall_time.as_secs_f64() * 1e3);
            full.positions(state.flat_positions(), &bones, &mut y);
            if !full.new_crossings(&y).is_empty() {
                crossing_frames += 1;
            }
        }
    }
    ms.sort_by(f64::total_cmp);
    Ok((ms[ms.len() / 2], crossing_frames))
}

fn main() -> Result<()> {
    let path = std::path::Path::new("sample_models/ict/neutral-coarse.face");
    let model = FaceModel::load(path)
        .with_context(|| format!("loading {} (run from the repository root)", path.display()))?;
    let full = FaceContact::new(&model, &FaceContactSettings::default())?;
    let field = LipField::new(&model, &full, 1.5);
    let (off, off_crossing) = drag(&model, &field, None, &full)?;
    println!(
        "contact off: median frame {off:.1} ms, {off_crossing} of {} frames cross",
        FRAMES * PASSES
    );
    println!(
        "| lip reach (cm) | contact vertices | median frame (ms) | × contact-free | frames crossing (full region) |"
    );
    println!("|---:|---:|---:|---:|---:|");
    for reach in REACHES {
        let settings = FaceContactSettings {
            lip_reach: reach,
            lining_reach: reach,
            ..FaceContactSettings::default()
        };
        let contact = FaceContact::new(&model, &settings)?;
        let vertices = contact.vertex_count();
        let (frame, crossing) = drag(&model, &field, Some(contact), &full)?;
        println!(
            "| {reach} | {vertices} | {frame:.1} | {:.1} | {crossing} of {} |",
            frame / off,
            FRAMES * PASSES
        );
    }
    Ok(())
}
