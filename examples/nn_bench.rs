//! Batched-pass timings of the nn kit:
//! `cargo run --release --example nn_bench [points] [quick]` (`quick`: N_A width 128 only).
//!
//! N_A-shaped network: 3 → SIREN (ω0 = 5) → 3 × GeLU (Lipschitz, 64-d code concatenated)
//! → 6, widths 128 and 64; a φ-shaped SIREN (3 → 4 × SIREN 128 → 3) for the Jacobian passes.
//! Each line: wall-clock median and minimum over repeated runs, and (Linux) the process CPU
//! time per run, which is less sensitive to other load on the machine.

use facesim::nn::bench::{Timing, actuation_like_spec, time_cached, time_chunked, time_passes};
use facesim::nn::{Mlp, MlpSpec, NnError, Pass};
use faer::Par;

/// Process CPU seconds (user + system) from /proc/self/stat, if available.
fn cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let after = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = after.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn show(
    name: &str,
    runs: usize,
    f: impl FnOnce() -> Result<Timing, NnError>,
) -> Result<(), NnError> {
    let c0 = cpu_seconds();
    let t = f()?;
    let cpu = match (c0, cpu_seconds()) {
        (Some(a), Some(b)) => format!("{:7.1} ms cpu/run", (b - a) * 1e3 / (runs + 1) as f64),
        _ => String::new(),
    };
    let what = match (t.cached, t.with_backward) {
        (true, _) => "Value, point cache".to_string(),
        (false, true) => format!("{:?} + backward", t.pass),
        (false, false) => format!("{:?}", t.pass),
    };
    println!(
        "{name:<22} {:>6} pts {} {} thr  {what:<20} {:>8.2} ms median {:>8.2} ms min {cpu}",
        t.points, t.dtype, t.threads, t.median_ms, t.min_ms
    );
    Ok(())
}

fn main() -> Result<(), NnError> {
    let points: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_000);
    let quick = std::env::args().nth(2).is_some_and(|a| a == "quick");
    let runs = 21;
    let pars = [Par::Seq, Par::rayon(2)];
    let widths: &[usize] = if quick { &[128] } else { &[128, 64] };
    for &width in widths {
        let spec = actuation_like_spec(width, 3, 64);
        let name = format!("N_A w{width}");
        let na64 = Mlp::<f64>::new(spec.clone(), 1)?;
        let na32 = Mlp::<f32>::new(spec, 1)?;
        for par in pars {
            show(&name, runs, || {
                time_passes(&na32, points, Pass::Value, false, par, runs)
            })?;
            show(&name, runs, || {
                time_passes(&na64, points, Pass::Value, false, par, runs)
            })?;
            show(&name, runs, || time_cached(&na32, points, par, runs))?;
            show(&name, runs, || time_cached(&na64, points, par, runs))?;
        }
    }
    if quick {
        return Ok(());
    }
    let few = 5;
    let na = Mlp::<f64>::new(actuation_like_spec(128, 3, 64), 1)?;
    for par in pars {
        show("N_A w128 whole batch", few, || {
            time_passes(&na, points, Pass::Gradient, true, par, few)
        })?;
        show("N_A w128 chunked", few, || {
            time_chunked(&na, points, Pass::Gradient, 1024, par, few)
        })?;
    }
    let phi = Mlp::<f64>::new(MlpSpec::siren(3, 128, 4, 5.0, 3), 1)?;
    for par in pars {
        show("phi w128", runs, || {
            time_passes(&phi, points, Pass::Value, false, par, runs)
        })?;
        show("phi w128", few, || {
            time_passes(&phi, points, Pass::Jacobian, false, par, few)
        })?;
        show("phi w128 whole batch", few, || {
            time_passes(&phi, points, Pass::Jacobian, true, par, few)
        })?;
        show("phi w128 chunked", few, || {
            time_chunked(&phi, points, Pass::Jacobian, 1024, par, few)
        })?;
    }
    Ok(())
}
