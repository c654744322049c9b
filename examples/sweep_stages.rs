//! Per-frame view of the random-code sweep with contact on (`facesim bench contact --sweep`
//! keeps only outcomes): for codes `FROM..TO` of the seeded sweep (seed `SEED`, 1 by default,
//! as `--sweep-seed`; sliders in `[-0.5, 1.5]`, the interactive preset unless `QUALITY` names
//! another, warm-started, a failed frame restarts the next from rest), each frame's outcome,
//! pose stages (and how many carried the tissue), iterations, wall time and where its contact
//! time went, whether it started from rest, its smallest element volume (`det F`), the render
//! surface's creased edges and those the rig's own shape at that code does not crease
//! ([`facesim::model::creases`])
//! and how far the jaw moved from the previous frame.
//!
//! `cargo run --release -p facesim --example sweep_stages -- 0 30 [SEED [QUALITY]]` (from the
//! repository root; frames before `FROM` are solved too, so the chain is the sweep's, but not
//! printed).

use anyhow::{Context, Result, bail};
use facesim::bench::contact_sweep::random_codes;
use facesim::contact::surface::FaceContact;
use facesim::model::contact_region::FaceContactSettings;
use facesim::session::frame::volume_ratios;
use facesim::sim::{BonePose, Quality};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let quality: Quality = match args.get(3) {
        Some(q) => q.parse().map_err(anyhow::Error::msg)?,
        None => Quality::Interactive,
    };
    let numbers: Vec<usize> = args
        .iter()
        .take(3)
        .map(|a| {
            a.parse()
                .with_context(|| format!("'{a}' is not a frame index"))
        })
        .collect::<Result<_>>()?;
    let (from, to, seed) = match numbers[..] {
        [from, to] => (from, to, 1),
        [from, to, seed] => (from, to, seed as u64),
        _ => bail!(
            "usage: sweep_stages FROM TO [SEED [QUALITY]] (frame indices, FROM < TO; seed 1 and \
             the interactive preset by default)"
        ),
    };
    if from >= to {
        bail!("FROM ({from}) must be below TO ({to})");
    }
    let sample = facesim::sample::Sample::load(facesim::sample::SAMPLE_DIR)
        .context("loading the bundled sample (run from the repository root)")?;
    let face = sample
        .faces
        .iter()
        .find(|f| f.identity.is_none())
        .context("the sample has no neutral face")?;
    let mut sim = face.model.simulator()?;
    sim.set_contact(FaceContact::new(
        &face.model,
        &FaceContactSettings::default(),
    )?)?;
    let settings = facesim::sim::SolveSettings {
        audit_crossings: true,
        ..quality.settings()
    };
    let rig = facesim::rig::FaceRig::load(facesim::rig::DEFAULT_RIG_DIR)
        .context("loading the rig (run from the repository root)")?;
    let creases = facesim::model::creases::CreaseAudit::new(&face.model);
    let mut state = sim.rest_state();
    let mut previous = BonePose::default();
    for (i, code) in random_codes(to, seed).iter().enumerate() {
        let a = face.actuation.actuate(code)?;
        let bones = a.bones();
        let (p, q) = (previous.jaw.params(), bones.jaw.params());
        let norm = |r: std::ops::Range<usize>| r.map(|k| (q[k] - p[k]).powi(2)).sum::<f64>().sqrt();
        let jaw = format!("jaw moved {:.3} rad, {:.3} cm", norm(0..3), norm(3..6));
        let result = sim.solve(&a.tensors, &bones, &mut state, &settings);
        if i >= from {
            match &result {
                Ok(s) => {
                    let c = s.contact.as_ref();
                    let creased = creases
                        .creased(&face.model.render_positions(state.flat_positions(), &bones));
                    let rig_creased =
                        creases.creased(&facesim::model::target(&rig, &face.model, code)?.render);
                    println!(
                        "frame {i}: ok ({:?}), {} stages ({} carried), {} iterations, {:.2} s \
                         (staging {:.2} s, broad phase {:.2} s, barrier {:.2} s, filter {:.2} s, linear {:.2} s), from rest {}, gate {:?}, smallest volume ratio {:.1e}, creases {} ({} not in the rig's shape), {jaw}",
                        s.termination,
                        c.map_or(0, |c| c.pose_stages),
                        c.map_or(0, |c| c.carried_stages),
                        s.iterations,
                        s.wall_time.as_secs_f64(),
                        c.map_or(0.0, |c| c.staging_time.as_secs_f64()),
                        c.map_or(0.0, |c| c.broad_phase_time.as_secs_f64()),
                        c.map_or(0.0, |c| c.barrier_time.as_secs_f64()),
                        c.map_or(0.0, |c| c.filter_time.as_secs_f64()),
                        c.map_or(0.0, |c| c.linear_time.as_secs_f64()),
                        c.is_some_and(|c| c.from_rest),
                        c.map(|c| c.gate),
                        volume_ratios(&face.model, state.flat_positions())
                            .into_iter()
                            .fold(f64::INFINITY, f64::min),
                        creased.len(),
                        facesim::model::creases::beyond(&creased, &rig_creased).len(),
                    );
                }
                Err(facesim::sim::SimError::Intersecting { count, stats }) => {
                    let c = stats.contact.as_ref();
                    println!(
                        "frame {i}: error: {count} crossings after {} stages ({} carried), {jaw}",
                        c.map_or(0, |c| c.pose_stages),
                        c.map_or(0, |c| c.carried_stages),
                    );
                }
                Err(e) => println!("frame {i}: error: {e}, {jaw}"),
            }
        }
        if result.is_err() {
            state = sim.rest_state();
            previous = BonePose::default();
        } else {
            previous = bones;
        }
    }
    Ok(())
}
