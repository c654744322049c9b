//! Median time of each whole-surface contact query at a state of `facesim bench contact`'s
//! slider drag (between its frames 3 and 4, interactive preset): the queries every contact
//! frame runs one or more of, so a change to the broad phase can be measured on its own,
//! steadier than the per-frame times of `contact_drag`.
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p facesim --example contact_queries`
//! (from the repository root; reads `sample_models/ict/neutral-coarse.face`).

use std::time::Instant;

use anyhow::{Context, Result};
use facesim::bench::contact::drag_pose;
use facesim::bench::mouth_poses::LipField;
use facesim::contact::surface::FaceContact;
use facesim::contact::{Candidates, FixedPrimitives, VerletList};
use facesim::model::contact_region::FaceContactSettings;
use facesim::sim::{ContactGate, Quality, SolveSettings};

const REPEATS: usize = 21;

/// Median milliseconds of `REPEATS` runs of `query`, and what its last run returned.
fn median(mut query: impl FnMut() -> Result<usize>) -> Result<(f64, usize)> {
    let mut ms = Vec::with_capacity(REPEATS);
    let mut out = 0;
    for _ in 0..REPEATS {
        let t = Instant::now();
        out = query()?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    ms.sort_by(f64::total_cmp);
    Ok((ms[REPEATS / 2], out))
}

fn main() -> Result<()> {
    let path = std::path::Path::new("sample_models/ict/neutral-coarse.face");
    let model = facesim::model::FaceModel::load(path)
        .with_context(|| format!("loading {} (run from the repository root)", path.display()))?;
    let face = FaceContact::new(&model, &FaceContactSettings::default())?;
    let field = LipField::new(&model, &face, 1.5);
    let mut sim = model.simulator()?;
    sim.set_contact(face.clone())?;
    sim.set_contact_gate(ContactGate::Always);
    let settings = SolveSettings {
        contact: true,
        ..Quality::Interactive.settings()
    };
    // Contact positions after the drag's frames 3 and 4.
    let mut state = sim.rest_state();
    let mut frames = Vec::new();
    for k in 0..5 {
        let pose = drag_pose(k, 8);
        sim.solve(
            &field.actuations(&pose),
            &pose.bones(),
            &mut state,
            &settings,
        )?;
        let mut y = vec![0.0; 3 * face.vertex_count()];
        face.positions(state.flat_positions(), &pose.bones(), &mut y);
        frames.push(y);
    }
    let (from, to) = (&frames[3], &frames[4]);
    let motion: Vec<f64> = to.iter().zip(from).map(|(b, a)| b - a).collect();
    let (mesh, dhat) = (face.mesh(), face.dhat());
    let fixed = FixedPrimitives::new(mesh, from)?;
    let list = VerletList::build(mesh, &fixed, from, dhat, dhat)?;

    let (ms, _) = median(|| Ok(FixedPrimitives::new(mesh, from)?.vertex_count()))?;
    println!("teeth trees and layouts        {ms:6.2} ms");
    let (ms, n) = median(|| Ok(VerletList::build(mesh, &fixed, from, dhat, dhat)?.len()))?;
    println!("Verlet list (reach 3 d̂)        {ms:6.2} ms  {n} pairs");
    let (ms, n) = median(|| Ok(Candidates::build_with(mesh, &fixed, from, 3.0 * dhat)?.len()))?;
    println!("  its boxes alone                {ms:6.2} ms  {n} pairs");
    // A line-search step of 5 % of the frame's motion, after part or all of it (the pairs
    // beyond the list's reach grow with the motion since it was built).
    for part in [0.1, 0.5, 1.0, 2.0] {
        let at: Vec<f64> = from
            .iter()
            .zip(&motion)
            .map(|(a, d)| a + part * d)
            .collect();
        let step: Vec<f64> = motion.iter().map(|d| 0.05 * d).collect();
        let (ms, n) = median(|| Ok(list.near_beyond(mesh, &fixed, &at, &step, dhat)?.1))?;
        println!("near_beyond after {part:3.1}× motion   {ms:6.2} ms  {n} pairs beyond");
    }
    let (ms, n) =
        median(|| Ok(Candidates::build_swept_on(mesh, &fixed, from, &motion, 0.5 * dhat)?.len()))?;
    println!("pose-stage certificate pairs   {ms:6.2} ms  {n} pairs");
    let (ms, n) = median(|| Ok(face.new_crossings_of_solve(to).len()))?;
    println!("after-solve crossing check     {ms:6.2} ms  {n} crossings");
    Ok(())
}
