//! What reusing a solve saves in the session: a display change (overlays toggled) with the
//! same codes, contact on, interactive preset. Prints the display-change latency (the frame
//! reuses the solve) and the time of the warm-started re-solve of the same inputs that it
//! replaces, both medians over repeats, for a few codes.
//!
//! `cargo run --release -p facesim --example session_reuse` (from the repository root).

use std::time::{Duration, Instant};

use facesim::contact::surface::FaceContact;
use facesim::drive::Codes;
use facesim::model::contact_region::FaceContactSettings;
use facesim::rig::ExpressionCode;
use facesim::session::{Display, Request, Session};
use facesim::sim::{Quality, SolveSettings};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> anyhow::Result<()> {
    let sample = facesim::sample::Sample::load(facesim::sample::SAMPLE_DIR)?;
    let faces = sample.session_faces();
    let face = faces
        .iter()
        .find(|f| f.name == "neutral")
        .expect("the sample has the neutral face")
        .clone();
    let session = Session::new(vec![face.clone()], Quality::Interactive)?;
    session.submit_all(&[Request::Refine(false), Request::Contact(true)])?;
    let wait = Duration::from_secs(300);
    let mut sim = face.model.simulator()?;
    sim.set_contact(FaceContact::new(
        &face.model,
        &FaceContactSettings::default(),
    )?)?;
    let settings = SolveSettings {
        contact: true,
        ..Quality::Interactive.settings()
    };
    println!(
        "| code | display change, reused (ms) | re-solve of the same inputs (ms) | re-solve iterations |"
    );
    println!("|---|---:|---:|---:|");
    for pairs in [
        vec![],
        vec![("mouthSmile_L", 0.3), ("mouthSmile_R", 0.3)],
        vec![("mouthPress_L", 0.7), ("mouthPress_R", 0.7)],
    ] {
        let mut code = ExpressionCode::default();
        for &(n, w) in &pairs {
            code.0[ExpressionCode::index_of(n).expect("a slider")] = w;
        }
        let g = session.submit(Request::Expression(code))?;
        let first = session.wait_generation(g, wait).expect("a frame");
        anyhow::ensure!(first.error.is_none(), "{:?}", first.error);
        let mut reused = Vec::new();
        for k in 0..6 {
            let t = Instant::now();
            let g = session.submit(Request::Display(Display {
                crosses: k % 2 == 0,
                heatmaps: true,
            }))?;
            let f = session.wait_generation(g, wait).expect("a frame");
            reused.push(t.elapsed().as_secs_f64() * 1e3);
            anyhow::ensure!(f.stats.reused, "the display change must reuse the solve");
        }
        // What the display change cost before: actuation and a warm-started solve of the
        // same inputs from their own solution.
        let codes = Codes {
            expression: code,
            ..first.codes
        };
        let mut state = sim.rest_state();
        let a = face.actuation.actuate(&codes)?;
        sim.solve(&a.tensors, &a.bones(), &mut state, &settings)?;
        let (mut resolve, mut iterations) = (Vec::new(), Vec::new());
        for _ in 0..6 {
            let t = Instant::now();
            let a = face.actuation.actuate(&codes)?;
            let s = sim.solve(&a.tensors, &a.bones(), &mut state, &settings)?;
            resolve.push(t.elapsed().as_secs_f64() * 1e3);
            iterations.push(s.iterations as f64);
        }
        println!(
            "| {pairs:?} | {:.1} | {:.1} | {:.0} |",
            median(reused),
            median(resolve),
            median(iterations)
        );
    }
    Ok(())
}
