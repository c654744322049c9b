//! Solver-level properties: rest preservation, rigid invariance, monotone energy, derivative
//! checks against finite differences, extreme inputs and determinism.

use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::slab::SlabScene;

fn scene() -> SlabScene {
    SlabScene::with_cells([4, 4, 2], 0.25, 3).unwrap()
}

fn simulator(scene: &SlabScene) -> Simulator {
    let config = SimConfig {
        jaw_pivot: scene.jaw_pivot,
        ..SimConfig::default()
    };
    Simulator::new(scene.mesh.clone(), scene.attachments.clone(), config).unwrap()
}

/// A small slab simulator for unit tests elsewhere in `sim`.
pub(crate) fn small_simulator() -> Simulator {
    simulator(&scene())
}

fn tight() -> SolveSettings {
    SolveSettings {
        audit_crossings: true,
        tolerance: 1e-11,
        max_iterations: 5000,
        history: 8,
        contact: true,
    }
}

fn identity(n: usize) -> Vec<SymTensor> {
    vec![SymTensor::IDENTITY; n]
}

fn max_distance(a: &[Point3<f64>], b: &[Point3<f64>]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max)
}

/// A random symmetric tensor with eigenvalues in `[lo, hi]` and random axes.
fn random_actuation(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> SymTensor {
    let q = Rotation3::from_scaled_axis(Vector3::from_fn(|_, _| rng.random_range(-3.0..3.0)))
        .into_inner();
    let d = Matrix3::from_diagonal(&Vector3::from_fn(|_, _| rng.random_range(lo..hi)));
    SymTensor::from_matrix(&(q * d * q.transpose()))
}

#[test]
fn identity_actuation_keeps_the_rest_shape_exactly() {
    let scene = scene();
    let sim = simulator(&scene);
    let act = identity(sim.element_count());
    let mut state = sim.rest_state();
    let stats = sim
        .solve(&act, &BonePose::default(), &mut state, &tight())
        .unwrap();
    assert_eq!(stats.iterations, 0);
    assert!(stats.residual < 1e-13, "rest residual {}", stats.residual);
    assert_eq!(state.positions(), scene.mesh.vertices);

    // From a perturbed start it comes back to rest.
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let moved: Vec<_> = scene
        .mesh
        .vertices
        .iter()
        .map(|p| p + Vector3::from_fn(|_, _| rng.random_range(-0.2..0.2)))
        .collect();
    let mut state = sim.state_at(&moved).unwrap();
    let stats = sim
        .solve(&act, &BonePose::default(), &mut state, &tight())
        .unwrap();
    assert!(stats.converged(), "{stats:?}");
    assert!(max_distance(&state.positions(), &scene.mesh.vertices) < 1e-8);
}

#[test]
fn rigid_motion_of_all_bones_moves_the_tissue_rigidly() {
    let scene = scene();
    let sim = simulator(&scene);
    let skull = RigidMotion {
        rotation: Vector3::new(0.3, -0.8, 0.5),
        translation: Vector3::new(2.0, -1.0, 3.0),
    };
    let moved = BonePose {
        skull,
        jaw: RigidMotion::IDENTITY,
    };
    let transform = |p: &Point3<f64>| moved.target(Bone::Skull, &Point3::origin(), p);

    // Identity actuation: the rest shape, moved.
    let mut state = sim.rest_state();
    sim.solve(&identity(sim.element_count()), &moved, &mut state, &tight())
        .unwrap();
    let expected: Vec<_> = scene.mesh.vertices.iter().map(transform).collect();
    assert!(max_distance(&state.positions(), &expected) < 1e-8);

    // A real actuation field, jaw open: the solution moves with the bones (rotation invariance).
    let act = scene.actuations(0.4);
    let jaw = RigidMotion {
        rotation: Vector3::new(0.15, 0.0, 0.0),
        translation: Vector3::zeros(),
    };
    let mut fixed = sim.rest_state();
    sim.solve(
        &act,
        &BonePose {
            skull: RigidMotion::IDENTITY,
            jaw,
        },
        &mut fixed,
        &tight(),
    )
    .unwrap();
    let mut rotated = sim.rest_state();
    sim.solve(&act, &BonePose { skull, jaw }, &mut rotated, &tight())
        .unwrap();
    let expected: Vec<_> = fixed.positions().iter().map(transform).collect();
    assert!(
        max_distance(&rotated.positions(), &expected) < 1e-7,
        "{}",
        max_distance(&rotated.positions(), &expected)
    );
}

#[test]
fn energy_never_increases_along_iterations() {
    let scene = scene();
    let sim = simulator(&scene);
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let act: Vec<_> = (0..sim.element_count())
        .map(|_| random_actuation(&mut rng, 0.6, 1.5))
        .collect();
    let jaw = RigidMotion {
        rotation: Vector3::new(0.3, 0.05, 0.0),
        translation: Vector3::new(0.0, -0.3, 0.1),
    };
    for history in [0, 5] {
        let mut state = sim.rest_state();
        let settings = SolveSettings {
            audit_crossings: true,
            tolerance: 1e-9,
            max_iterations: 3000,
            history,
            contact: true,
        };
        let stats = sim
            .solve(
                &act,
                &BonePose {
                    skull: RigidMotion::IDENTITY,
                    jaw,
                },
                &mut state,
                &settings,
            )
            .unwrap();
        assert!(stats.iterations > 3, "too easy to test: {stats:?}");
        for pair in stats.energy_history.windows(2) {
            // Strictly by the Armijo rule, except in the round-off regime where the energy
            // cannot resolve a step (then the change is below 1e-13 relative).
            assert!(
                pair[1] <= pair[0] * (1.0 + 1e-13),
                "energy rose: {} -> {}",
                pair[0],
                pair[1]
            );
        }
        assert!(stats.energy_history.last() < stats.energy_history.first());
    }
}

#[test]
fn lbfgs_needs_fewer_iterations_than_plain_projective_dynamics() {
    let scene = SlabScene::with_cells([8, 8, 3], 0.2, 5).unwrap();
    let sim = simulator(&scene);
    let act = scene.actuations(0.4);
    let run = |history| {
        let mut state = sim.rest_state();
        sim.solve(
            &act,
            &BonePose::default(),
            &mut state,
            &SolveSettings {
                audit_crossings: true,
                tolerance: 1e-8,
                max_iterations: 5000,
                history,
                contact: true,
            },
        )
        .unwrap()
    };
    let (pd, lbfgs) = (run(0), run(8));
    assert!(pd.converged() && lbfgs.converged());
    assert!(
        lbfgs.iterations * 2 < pd.iterations,
        "L-BFGS {} vs PD {}",
        lbfgs.iterations,
        pd.iterations
    );
}

/// A state away from equilibrium with a non-trivial actuation, for derivative checks.
fn deformed_state(sim: &Simulator, scene: &SlabScene, rng: &mut ChaCha8Rng) -> SimState {
    let moved: Vec<_> = scene
        .mesh
        .vertices
        .iter()
        .map(|p| p + Vector3::from_fn(|_, _| rng.random_range(-0.15..0.15)))
        .collect();
    let mut state = sim.state_at(&moved).unwrap();
    // One local sweep sets consistent rotations for the warm start.
    let act = identity(sim.element_count());
    let settings = SolveSettings {
        audit_crossings: true,
        tolerance: 0.0,
        max_iterations: 0,
        history: 0,
        contact: true,
    };
    sim.solve(&act, &BonePose::default(), &mut state, &settings)
        .unwrap();
    state
}

#[test]
fn gradient_and_hessian_products_match_finite_differences() {
    let scene = scene();
    let sim = simulator(&scene);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let act: Vec<_> = (0..sim.element_count())
        .map(|_| random_actuation(&mut rng, 0.5, 2.0))
        .collect();
    let bones = BonePose {
        skull: RigidMotion::IDENTITY,
        jaw: RigidMotion::from_params([0.2, 0.1, -0.1, 0.1, -0.2, 0.3]),
    };
    let state = deformed_state(&sim, &scene, &mut rng);
    let (_, g) = sim.energy_gradient(&act, &bones, &state).unwrap();
    let dim = g.len();
    let shifted = |dir: &[f64], h: f64| {
        let moved: Vec<_> = state
            .positions()
            .iter()
            .enumerate()
            .map(|(v, p)| p + Vector3::new(dir[3 * v], dir[3 * v + 1], dir[3 * v + 2]) * h)
            .collect();
        let mut s = sim.state_at(&moved).unwrap();
        s.steps = state.steps.clone();
        s
    };
    for _ in 0..5 {
        let dir: Vec<f64> = (0..dim).map(|_| rng.random_range(-1.0..1.0)).collect();
        let h = 1e-6;
        let (ep, gp) = sim
            .energy_gradient(&act, &bones, &shifted(&dir, h))
            .unwrap();
        let (em, gm) = sim
            .energy_gradient(&act, &bones, &shifted(&dir, -h))
            .unwrap();
        let fd = (ep - em) / (2.0 * h);
        let analytic: f64 = g.iter().zip(&dir).map(|(a, b)| a * b).sum();
        assert!(
            (fd - analytic).abs() < 1e-6 * (1.0 + analytic.abs()),
            "gradient: fd {fd} vs {analytic}"
        );

        let hv = sim
            .hessian_vector_product(&act, &bones, &state, &dir)
            .unwrap();
        let err: f64 = (0..dim)
            .map(|i| ((gp[i] - gm[i]) / (2.0 * h) - hv[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        let size: f64 = hv.iter().map(|v| v * v).sum::<f64>().sqrt();
        assert!(
            err < 1e-6 * (1.0 + size),
            "Hessian product: error {err} of {size}"
        );
    }
}

#[test]
fn sensitivities_match_finite_differences_of_the_solve() {
    let scene = scene();
    let sim = simulator(&scene);
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let act: Vec<_> = (0..sim.element_count())
        .map(|_| random_actuation(&mut rng, 0.7, 1.4))
        .collect();
    let bones = BonePose {
        skull: RigidMotion::IDENTITY,
        jaw: RigidMotion::from_params([0.15, 0.05, 0.0, 0.0, -0.1, 0.1]),
    };
    // Loss ℓ(u) = ½‖u − u_target‖² against an arbitrary target.
    let target: Vec<f64> = scene
        .mesh
        .vertices
        .iter()
        .flat_map(|p| [p.x + 0.3, p.y - 0.2, p.z + 0.1])
        .collect();
    let solve = |act: &[SymTensor], bones: &BonePose| {
        let mut state = sim.rest_state();
        sim.solve(act, bones, &mut state, &tight()).unwrap();
        state
    };
    let loss = |state: &SimState| -> f64 {
        state
            .flat_positions()
            .iter()
            .zip(&target)
            .map(|(u, t)| 0.5 * (u - t).powi(2))
            .sum()
    };
    let state = solve(&act, &bones);
    let dloss: Vec<f64> = state
        .flat_positions()
        .iter()
        .zip(&target)
        .map(|(u, t)| u - t)
        .collect();
    let sens = sim.sensitivities(&act, &bones, &state, &dloss).unwrap();
    assert!(sens.residual < 1e-9);

    let h = 1e-5;
    for element in [0, 17, sim.element_count() - 1] {
        for k in 0..6 {
            let mut plus = act.clone();
            plus[element].0[k] += h;
            let mut minus = act.clone();
            minus[element].0[k] -= h;
            let fd = (loss(&solve(&plus, &bones)) - loss(&solve(&minus, &bones))) / (2.0 * h);
            let got = sens.actuation[element][k];
            assert!(
                (fd - got).abs() < 2e-5 * (1.0 + fd.abs()),
                "element {element} entry {k}: fd {fd} vs adjoint {got}"
            );
        }
    }
    for k in 0..6 {
        let mut p = bones.jaw.params();
        p[k] += h;
        let plus = loss(&solve(
            &act,
            &BonePose {
                jaw: RigidMotion::from_params(p),
                ..bones
            },
        ));
        p[k] -= 2.0 * h;
        let minus = loss(&solve(
            &act,
            &BonePose {
                jaw: RigidMotion::from_params(p),
                ..bones
            },
        ));
        let fd = (plus - minus) / (2.0 * h);
        assert!(
            (fd - sens.jaw[k]).abs() < 2e-5 * (1.0 + fd.abs()),
            "jaw {k}: fd {fd} vs adjoint {}",
            sens.jaw[k]
        );
    }
}

/// The contract at the extremes: finite, non-inverted, within the cap — or a clear error.
fn assert_sane(
    result: Result<SolveStats, SimError>,
    state: &SimState,
    settings: &SolveSettings,
    what: &str,
) {
    match &result {
        Ok(s) => eprintln!(
            "{what}: {:?} after {} it, residual {:.1e}",
            s.termination, s.iterations, s.residual
        ),
        Err(e) => eprintln!("{what}: {e}"),
    }
    assert!(
        state.flat_positions().iter().all(|v| v.is_finite()),
        "{what}: non-finite positions"
    );
    // The volume barrier keeps every element unfolded, whatever the inputs ask.
    let stats = result.unwrap_or_else(|e| panic!("{what}: unexpected error {e}"));
    assert!(stats.iterations <= settings.max_iterations);
    assert!(
        stats.residual.is_finite() && stats.energy.is_finite(),
        "{what}: {stats:?}"
    );
    let smallest = state
        .steps
        .iter()
        .map(|s| s.volume_ratio)
        .fold(f64::INFINITY, f64::min);
    assert!(
        smallest > 0.0,
        "{what}: an element folded (det F = {smallest})"
    );
}

#[test]
fn extreme_actuations_give_finite_unfolded_results() {
    let scene = scene();
    let sim = simulator(&scene);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let n = sim.element_count();
    let settings = Quality::Preview.settings();
    let cases: Vec<(&str, Vec<SymTensor>)> = vec![
        (
            "eigenvalues 0.2..5",
            (0..n)
                .map(|_| random_actuation(&mut rng, 0.2, 5.0))
                .collect(),
        ),
        (
            "uniform 0.2",
            vec![SymTensor([0.2, 0.2, 0.2, 0.0, 0.0, 0.0]); n],
        ),
        (
            "uniform 5",
            vec![SymTensor([5.0, 5.0, 5.0, 0.0, 0.0, 0.0]); n],
        ),
        (
            "near-singular",
            (0..n)
                .map(|_| random_actuation(&mut rng, 1e-6, 1e-5))
                .collect(),
        ),
        (
            "nearly inverted (one axis ~0)",
            (0..n)
                .map(|_| {
                    SymTensor::from_matrix(&Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 1e-9)))
                })
                .collect(),
        ),
    ];
    for (what, act) in cases {
        for quality in Quality::ALL {
            let settings = quality.settings();
            let mut state = sim.rest_state();
            let result = sim.solve(&act, &BonePose::default(), &mut state, &settings);
            assert_sane(result, &state, &settings, what);
        }
    }
    let _ = settings;
}

#[test]
fn huge_jaw_transforms_give_finite_unfolded_results() {
    let scene = scene();
    let sim = simulator(&scene);
    let act = scene.actuations(0.3);
    let settings = Quality::Preview.settings();
    for params in [
        [3.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, -100.0, 0.0],
        [1.0, 2.0, -1.5, 50.0, 20.0, -30.0],
        [0.0, 0.0, 1e3, 0.0, 0.0, 1e4],
    ] {
        let bones = BonePose {
            skull: RigidMotion::IDENTITY,
            jaw: RigidMotion::from_params(params),
        };
        let mut state = sim.rest_state();
        let result = sim.solve(&act, &bones, &mut state, &settings);
        assert_sane(result, &state, &settings, &format!("jaw {params:?}"));
    }
}

#[test]
fn bad_inputs_are_rejected_before_anything_changes() {
    let scene = scene();
    let sim = simulator(&scene);
    let n = sim.element_count();
    let mut state = sim.rest_state();
    let before = state.positions();
    let settings = Quality::Interactive.settings();
    let mut nan = identity(n);
    nan[3].0[4] = f64::NAN;
    assert!(matches!(
        sim.solve(&nan, &BonePose::default(), &mut state, &settings),
        Err(SimError::InvalidActuation { element: 3, .. })
    ));
    let mut negative = identity(n);
    negative[5] = SymTensor([1.0, -1.0, 1.0, 0.0, 0.0, 0.0]);
    let err = sim
        .solve(&negative, &BonePose::default(), &mut state, &settings)
        .unwrap_err();
    assert!(
        err.to_string().contains("element 5") && err.to_string().contains("positive definite"),
        "{err}"
    );
    assert!(matches!(
        sim.solve(
            &identity(n - 1),
            &BonePose::default(),
            &mut state,
            &settings
        ),
        Err(SimError::ActuationCount { .. })
    ));
    let bad_jaw = BonePose {
        skull: RigidMotion::IDENTITY,
        jaw: RigidMotion::from_params([0.0, f64::INFINITY, 0.0, 0.0, 0.0, 0.0]),
    };
    assert!(matches!(
        sim.solve(&identity(n), &bad_jaw, &mut state, &settings),
        Err(SimError::NonFiniteBones(_))
    ));
    assert_eq!(state.positions(), before);
}

#[test]
fn setup_errors_are_clear() {
    let scene = scene();
    let none = Attachments::default();
    let err = Simulator::new(scene.mesh.clone(), none, SimConfig::default())
        .err()
        .unwrap();
    assert!(err.to_string().contains("attached to no bone"), "{err}");
    let twice = Attachments {
        vertices: vec![0, 0],
        bones: vec![Bone::Skull, Bone::Skull],
    };
    assert!(Simulator::new(scene.mesh.clone(), twice, SimConfig::default()).is_err());
    let out_of_range = Attachments {
        vertices: vec![10_000],
        bones: vec![Bone::Skull],
    };
    assert!(Simulator::new(scene.mesh.clone(), out_of_range, SimConfig::default()).is_err());
}

#[test]
fn warm_start_from_the_previous_frame_beats_a_cold_start() {
    let scene = SlabScene::with_cells([6, 6, 2], 0.2, 8).unwrap();
    let sim = simulator(&scene);
    let settings = Quality::Preview.settings();
    let mut previous = sim.rest_state();
    sim.solve(
        &scene.actuations(0.30),
        &BonePose::default(),
        &mut previous,
        &settings,
    )
    .unwrap();
    let next = scene.actuations(0.33);
    let mut cold = sim.rest_state();
    let cold_stats = sim
        .solve(&next, &BonePose::default(), &mut cold, &settings)
        .unwrap();
    let warm_stats = sim
        .solve(&next, &BonePose::default(), &mut previous, &settings)
        .unwrap();
    assert!(
        warm_stats.iterations < cold_stats.iterations,
        "warm {} vs cold {}",
        warm_stats.iterations,
        cold_stats.iterations
    );
    assert!(max_distance(&cold.positions(), &previous.positions()) < 1e-2);
}

#[test]
fn same_inputs_give_bitwise_identical_results() {
    let scene = SlabScene::with_cells([8, 8, 2], 0.2, 2).unwrap();
    let sim = simulator(&scene);
    let act = scene.actuations(0.35);
    let run = || {
        let mut state = sim.rest_state();
        let stats = sim
            .solve(
                &act,
                &BonePose::default(),
                &mut state,
                &Quality::Final.settings(),
            )
            .unwrap();
        (state.flat_positions().to_vec(), stats.energy_history)
    };
    let first = run();
    assert_eq!(first, run());
    // Called from a thread of the pool, the solve runs there instead of being handed over.
    assert!(rayon::current_thread_index().is_none());
    assert_eq!(first, rayon::join(run, || ()).0);
}
