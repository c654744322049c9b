//! `facesim bench solver`: factorization, per-iteration cost against its floor, and time to
//! tolerance from rest and warm-started, on generated slabs of given element counts.

use std::time::{Duration, Instant};

use serde::Serialize;

use super::median;
use crate::sim::global_matrix::GlobalMatrix;
use crate::sim::{BonePose, SimConfig, SimError, SimState, Simulator, SolveSettings, SymTensor};
use crate::slab::SlabScene;
use crate::table::Table;

/// Contraction of the benchmark's actuation field, and its change for warm-started solves.
const STRENGTH: f64 = 0.3;
const SMALL_CHANGE: f64 = 0.05;

#[derive(Clone, Debug)]
pub struct SolverBenchOptions {
    pub elements: Vec<usize>,
    /// Timing samples per measurement (the median is reported).
    pub samples: usize,
}

/// Iterations and median wall time to reach a tolerance.
#[derive(Clone, Debug, Serialize)]
pub struct ToTolerance {
    pub tolerance: f64,
    pub iterations: usize,
    pub median_ms: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct SolverBenchRow {
    pub elements: usize,
    pub vertices: usize,
    pub factor_nonzeros: usize,
    pub factor_ms: f64,
    pub iteration_ms: f64,
    pub bare_solve_ms: f64,
    pub local_sweep_ms: f64,
    /// `iteration / (bare solve + local sweep)`: 1.0 is the method's floor.
    pub floor_ratio: f64,
    pub from_rest: Vec<ToTolerance>,
    pub warm: Vec<ToTolerance>,
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn median_time(samples: usize, mut f: impl FnMut() -> Duration) -> f64 {
    median(&(0..samples.max(1)).map(|_| ms(f())).collect::<Vec<_>>())
}

/// Runs the benchmark for one mesh size.
pub fn bench_size(elements: usize, samples: usize) -> Result<SolverBenchRow, SimError> {
    let scene = SlabScene::new(elements, 0.2, 1).map_err(|e| SimError::Setup(e.to_string()))?;
    let config = SimConfig {
        jaw_pivot: scene.jaw_pivot,
        ..SimConfig::default()
    };
    let sim = Simulator::new(scene.mesh.clone(), scene.attachments.clone(), config)?;
    let bones = BonePose::default();
    let actuation = scene.actuations(STRENGTH);
    let changed = scene.actuations(STRENGTH + SMALL_CHANGE);

    let stiffness = sim.stiffness.clone();
    let factor_ms = median_time(samples, || {
        let t = Instant::now();
        let _ = GlobalMatrix::factor(&sim.mesh.tets, &sim.ops, &sim.element_weights, &stiffness);
        t.elapsed()
    });

    // A converged solution to start warm solves and iteration timings from.
    let mut solved = sim.rest_state();
    sim.solve(
        &actuation,
        &bones,
        &mut solved,
        &SolveSettings {
            tolerance: 1e-9,
            max_iterations: 5000,
            history: 8,
            contact: true,
            audit_crossings: true,
        },
    )?;

    // Iteration cost and its floor, sampled interleaved so that machine noise hits both alike.
    // The floor is one bare solve with the factor plus PD's local step: every element's
    // projection and the assembly of the right-hand side (here the gradient gather, the same sum).
    let frame = sim.frame(&changed, &bones)?;
    let mut scratch = sim.solve_scratch();
    let mut rhs = solved.x.clone();
    let mut out = solved.steps.clone();
    let mut gradient = vec![0.0; solved.x.len()];
    const TIMED_ITERATIONS: usize = 10;
    let fixed = SolveSettings {
        tolerance: 0.0,
        max_iterations: TIMED_ITERATIONS,
        ..SolveSettings::default()
    };
    let (mut iteration, mut bare_solve, mut local_step) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..samples.max(1) {
        let mut state = solved.clone();
        let stats = sim.solve(&changed, &bones, &mut state, &fixed)?;
        iteration.push(ms(stats.iteration_time) / stats.iterations.max(1) as f64);
        for _ in 0..3 {
            rhs.copy_from_slice(&solved.x);
            let t = Instant::now();
            sim.global.solve_in_place(&mut rhs, &mut scratch);
            bare_solve.push(ms(t.elapsed()));
            let t = Instant::now();
            sim.local_sweep(&frame, &solved.x, Some(&solved.steps), &mut out);
            sim.gradient(&frame, &solved.x, &out, &mut gradient);
            local_step.push(ms(t.elapsed()));
        }
    }
    let (iteration_ms, bare_solve_ms, local_sweep_ms) =
        (median(&iteration), median(&bare_solve), median(&local_step));

    let to_tolerance =
        |start: &SimState, target: &[SymTensor], tolerance: f64| -> Result<ToTolerance, SimError> {
            let settings = SolveSettings {
                tolerance,
                max_iterations: 5000,
                ..SolveSettings::default()
            };
            let mut iterations = 0;
            let mut times = Vec::new();
            for _ in 0..samples.max(1) {
                let mut state = start.clone();
                let stats = sim.solve(target, &bones, &mut state, &settings)?;
                iterations = stats.iterations;
                times.push(ms(stats.wall_time));
            }
            Ok(ToTolerance {
                tolerance,
                iterations,
                median_ms: median(&times),
            })
        };
    let rest = sim.rest_state();
    let tolerances = [1e-3, 1e-5];
    let from_rest = tolerances
        .iter()
        .map(|&t| to_tolerance(&rest, &actuation, t))
        .collect::<Result<_, _>>()?;
    let warm = tolerances
        .iter()
        .map(|&t| to_tolerance(&solved, &changed, t))
        .collect::<Result<_, _>>()?;

    Ok(SolverBenchRow {
        elements: sim.element_count(),
        vertices: sim.vertex_count(),
        factor_nonzeros: sim.global.factor_nonzeros(),
        factor_ms,
        iteration_ms,
        bare_solve_ms,
        local_sweep_ms,
        floor_ratio: iteration_ms / (bare_solve_ms + local_sweep_ms),
        from_rest,
        warm,
    })
}

/// The benchmark as a Markdown table.
pub fn table(rows: &[SolverBenchRow]) -> String {
    let mut t = Table::new(
        &[
            "elements",
            "vertices",
            "factor",
            "iteration",
            "floor (solve + local step)",
            "ratio",
            "rest→1e-3",
            "rest→1e-5",
            "warm→1e-3",
            "warm→1e-5",
        ],
        "rrrrrrrrrr",
    );
    let cell = |t: &ToTolerance| format!("{} it, {:.1} ms", t.iterations, t.median_ms);
    for r in rows {
        t.row([
            r.elements.to_string(),
            r.vertices.to_string(),
            format!("{:.1} ms", r.factor_ms),
            format!("{:.2} ms", r.iteration_ms),
            format!("{:.2} + {:.2} ms", r.bare_solve_ms, r.local_sweep_ms),
            format!("{:.2}", r.floor_ratio),
            cell(&r.from_rest[0]),
            cell(&r.from_rest[1]),
            cell(&r.warm[0]),
            cell(&r.warm[1]),
        ]);
    }
    t.to_string()
}
