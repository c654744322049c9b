//! Batched-pass timings of the nn kit: `cargo run --release --example nn_bench [points]`.
//!
//! N_A-shaped network: 3 → SIREN 128 (ω0 = 5) → 3 × GeLU 128 (Lipschitz, 64-d code
//! concatenated) → 6, and the same with width 64; a φ-shaped SIREN (3 → 4 × SIREN 128 → 3)
//! for the Jacobian passes. Each line: median and minimum of repeated runs.

use facesim::nn::bench::{Timing, actuation_like_spec, time_cached, time_passes};
use facesim::nn::{Mlp, MlpSpec, NnError, Pass};
use faer::Par;

fn show(name: &str, t: &Timing) {
    let what = match (t.cached, t.with_backward) {
        (true, _) => "Value (point cache)".to_string(),
        (false, true) => format!("{:?} + backward", t.pass),
        (false, false) => format!("{:?}", t.pass),
    };
    println!(
        "{name:<16} {:>6} pts  {}  {} thread(s)  {what:<22} {:>8.2} ms median {:>8.2} ms min",
        t.points, t.dtype, t.threads, t.median_ms, t.min_ms
    );
}

fn main() -> Result<(), NnError> {
    let points: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_000);
    let runs = 21;
    let pars = [Par::Seq, Par::rayon(2)];
    for width in [128, 64] {
        let spec = actuation_like_spec(width, 3, 64);
        let name = format!("N_A w{width}");
        let na64 = Mlp::<f64>::new(spec.clone(), 1)?;
        let na32 = Mlp::<f32>::new(spec, 1)?;
        for par in pars {
            show(
                &name,
                &time_passes(&na32, points, Pass::Value, false, par, runs)?,
            );
            show(
                &name,
                &time_passes(&na64, points, Pass::Value, false, par, runs)?,
            );
            show(&name, &time_cached(&na32, points, par, runs)?);
            show(&name, &time_cached(&na64, points, par, runs)?);
        }
    }
    let na = Mlp::<f32>::new(actuation_like_spec(128, 3, 64), 1)?;
    for par in pars {
        show(
            "N_A w128",
            &time_passes(&na, points, Pass::Gradient, true, par, 5)?,
        );
    }
    let phi = Mlp::<f64>::new(MlpSpec::siren(3, 128, 4, 5.0, 3), 1)?;
    for par in pars {
        show(
            "phi w128",
            &time_passes(&phi, points, Pass::Value, false, par, runs)?,
        );
        show(
            "phi w128",
            &time_passes(&phi, points, Pass::Jacobian, false, par, 5)?,
        );
        show(
            "phi w128",
            &time_passes(&phi, points, Pass::Jacobian, true, par, 5)?,
        );
    }
    Ok(())
}
