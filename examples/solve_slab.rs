//! The README's library example: solve a face-sized slab, then warm-start the next frame.
//! `cargo run --release --example solve_slab`

use facesim::sim::{BonePose, Quality, RigidMotion, SimConfig, Simulator};
use facesim::slab::SlabScene;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let scene = SlabScene::new(20_000, 0.2, 1)?;
    let config = SimConfig {
        jaw_pivot: scene.jaw_pivot,
        ..SimConfig::default()
    };
    let sim = Simulator::new(scene.mesh.clone(), scene.attachments.clone(), config)?;
    let mut frame = sim.rest_state();
    for (i, opening) in [0.0, 0.05, 0.1, 0.15].into_iter().enumerate() {
        let jaw = RigidMotion::from_params([opening, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let bones = BonePose {
            jaw,
            ..BonePose::default()
        };
        let stats = sim.solve(
            &scene.actuations(0.3),
            &bones,
            &mut frame,
            &Quality::Interactive.settings(),
        )?;
        println!(
            "frame {i}: {:?} in {} iterations, residual {:.1e}, {:.1} ms",
            stats.termination,
            stats.iterations,
            stats.residual,
            stats.wall_time.as_secs_f64() * 1e3
        );
    }
    Ok(())
}
