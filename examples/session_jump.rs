//! Jumps in the session with contact on (the editor's default), interactive preset: from the
//! neutral to a pose and back (the "reset" button), for a few poses; prints each frame's time,
//! iterations and whether it converged.
//!
//! `RAYON_NUM_THREADS=1 cargo run --release -p facesim --example session_jump`

use std::time::{Duration, Instant};

use facesim::rig::ExpressionCode;
use facesim::session::{Request, Session};
use facesim::sim::Quality;

fn main() -> anyhow::Result<()> {
    let sample = facesim::sample::Sample::load(facesim::sample::SAMPLE_DIR)?;
    let face = sample
        .session_faces()
        .into_iter()
        .find(|f| f.name == "neutral")
        .expect("the sample has the neutral face");
    let session = Session::new(vec![face], Quality::Interactive)?;
    session.submit(Request::Refine(false))?;
    let wait = Duration::from_secs(600);
    session.wait_newer(None, wait).expect("the first frame");
    println!("| jump | ms | iterations | converged |");
    println!("|---|---:|---:|---|");
    for pairs in [
        vec![("jawOpen", 1.0)],
        vec![("mouthSmile_L", 1.0), ("mouthSmile_R", 1.0)],
        vec![
            ("jawOpen", 0.5),
            ("mouthSmile_L", 0.8),
            ("mouthPucker", 0.3),
        ],
        vec![("mouthRollLower", 1.0)],
        vec![("mouthClose", 1.0)],
    ] {
        let mut code = ExpressionCode::default();
        for &(n, w) in &pairs {
            code.0[ExpressionCode::index_of(n).expect("a slider")] = w;
        }
        for (name, code) in [
            (format!("{pairs:?}"), code),
            ("back to neutral".into(), ExpressionCode::default()),
        ] {
            let t = Instant::now();
            let g = session.submit(Request::Expression(code))?;
            let f = session.wait_generation(g, wait).expect("a frame");
            println!(
                "| {name} | {:.0} | {} | {} |",
                t.elapsed().as_secs_f64() * 1e3,
                f.stats.iterations,
                f.stats.converged
            );
        }
    }
    Ok(())
}
