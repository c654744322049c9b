//! Tests of stage 2 on a tiny slab "face" (a few hundred elements: every solve and adjoint
//! takes milliseconds), with per-element warp rotations and skin partly blended onto the jaw
//! so every term of the chain rule is exercised.

use crate::generative::NetworkSet;
use nalgebra::{Point3, Rotation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::generative_face::FaceWarp;
use super::loss::{LossWorkspace, zero_grads};
use super::nets::{CanonicalFrame, GenerativeNets};
use super::stage2::{
    SkinPoint, Stage2Data, Stage2Face, Stage2Pose, Stage2Settings, Stage2Trainer, pose_loss,
    stage2_loss,
};
use super::tests::{bits, tiny};
use super::train::Stage1Config;
use crate::drive::Codes;
use crate::rig::test_support::temp_dir;
use crate::rig::{ExpressionCode, StyleCode};
use crate::sim::{Bone, SimConfig, Simulator, SolveSettings};
use crate::slab::{SLAB_SIZE, SlabScene};

fn slab_frame() -> CanonicalFrame {
    CanonicalFrame {
        center: [0.5 * SLAB_SIZE.x, 0.5 * SLAB_SIZE.y, 0.5 * SLAB_SIZE.z],
        scale: 0.5 * SLAB_SIZE.x,
    }
}

/// Tight solves: the gradient is as exact as the equilibrium.
fn tight() -> Stage2Settings {
    Stage2Settings {
        solve: SolveSettings {
            audit_crossings: true,
            tolerance: 1e-11,
            max_iterations: 5000,
            history: 8,
            contact: false,
        },
        stalled_factor: 100.0,
        max_adjoint_residual: 1e-9,
    }
}

/// The slab with random warp rotations, 60 skin points (every fourth blended onto the
/// jaw), and `poses` random codes whose targets are the rest skin moved by a smooth field.
fn slab_data(poses: usize, settings: Stage2Settings) -> Stage2Data {
    let scene = SlabScene::with_cells([4, 4, 2], 0.25, 3).unwrap();
    let sim = Simulator::new(
        scene.mesh.clone(),
        scene.attachments.clone(),
        SimConfig {
            jaw_pivot: scene.jaw_pivot,
            ..SimConfig::default()
        },
    )
    .unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let frame = slab_frame();
    let mesh = &scene.mesh;
    let centroid = |t: &[u32; 4]| {
        Point3::from(
            t.iter()
                .map(|&v| mesh.vertices[v as usize].coords)
                .sum::<Vector3<f64>>()
                / 4.0,
        )
    };
    let warp = FaceWarp {
        canonical: mesh
            .tets
            .iter()
            .map(|t| frame.normalize(&centroid(t)))
            .collect(),
        rotations: Some(
            (0..mesh.tets.len())
                .map(|_| {
                    let a = Vector3::new(rng.random(), rng.random(), rng.random()) * 0.6;
                    Rotation3::new(a).into_inner()
                })
                .collect(),
        ),
    };
    let skin: Vec<SkinPoint> = (0..60)
        .map(|i| {
            let e = rng.random_range(0..mesh.tets.len());
            let mut w = [0.0; 4].map(|_| rng.random_range(0.1..1.0));
            let s: f64 = w.iter().sum();
            w.iter_mut().for_each(|v| *v /= s);
            let tet = mesh.tets[e];
            let rest = tet
                .iter()
                .zip(w)
                .map(|(&v, w)| w * mesh.vertices[v as usize].coords)
                .sum::<Vector3<f64>>();
            SkinPoint {
                tet,
                weights: w,
                share: if i % 4 == 0 { 0.6 } else { 1.0 },
                bone: Bone::Jaw,
                rest: Point3::from(rest),
            }
        })
        .collect();
    let start: Vec<f64> = mesh.vertices.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    let poses = (0..poses)
        .map(|p| {
            let mut expression = ExpressionCode::NEUTRAL;
            for v in expression.0.iter_mut() {
                *v = rng.random_range(0.0..1.0);
            }
            let style = StyleCode([0; 4].map(|_| rng.random_range(-1.0..1.0)));
            let amp = 0.1 + 0.05 * p as f64;
            Stage2Pose {
                codes: Codes { expression, style },
                start: start.clone(),
                start_jaw: [0.0; 6],
                target: skin
                    .iter()
                    .map(|s| {
                        let q = s.rest;
                        q + amp * Vector3::new((0.7 * q.y).sin(), (0.5 * q.x).cos(), 0.3)
                    })
                    .collect(),
            }
        })
        .collect();
    let face = Stage2Face::new("slab".into(), sim, scene.jaw_pivot, warp, skin, poses).unwrap();
    Stage2Data::new(vec![face], settings).unwrap()
}

fn config(iterations: u64, seed: u64) -> Stage1Config {
    Stage1Config {
        architecture: tiny(),
        iterations,
        batch_poses: 2,
        elements_per_pose: 0,
        learning_rate: 2e-3,
        seed,
        chunk_rows: 32,
        lanes: 4,
        ..Stage1Config::default()
    }
}

/// Small networks whose actuations move the slab visibly (the last layer scaled up).
fn nets(seed: u64) -> GenerativeNets {
    let mut n = GenerativeNets::new(tiny(), slab_frame(), seed).unwrap();
    let count = n.actuation.num_params();
    let last = 6 * (tiny().actuation_width + 1);
    for p in &mut n.actuation.params_mut()[count - last..] {
        *p *= 3.0;
    }
    n
}

/// The whole stage-2 gradient — solve, surface loss, adjoint, exp′, warp, N_A, N_B, tanh,
/// encoders, regularizers — against central differences of the batch loss (each evaluation
/// re-solves from the same start to 1e-11).
#[test]
#[allow(clippy::needless_range_loop)] // n indexes the networks and their gradients alike
fn stage2_gradient_matches_central_differences() {
    let data = slab_data(3, tight());
    let cfg = config(1, 4);
    let mut nets = nets(2);
    let mut ws = LossWorkspace::new(32, 4).unwrap();
    let mut grads = zero_grads(&nets);
    let parts = stage2_loss(&nets, &data, &cfg, 0, &mut ws, &mut grads).unwrap();
    assert_eq!(parts.skipped, 0);
    assert!(parts.fit > 1e-3, "{parts:?}");
    // The loss is only as exact as the equilibrium (relative residual 1e-11): with this step
    // the differences agree to ~1e-7 absolute (gradients here are 4e-3 to 2.5).
    let h = 1e-4;
    for n in 0..4 {
        let count = nets.nets()[n].num_params();
        let mut checked = 0;
        for p in (0..count).step_by((count / 4).max(1)) {
            let mut f = |delta: f64| {
                let keep = nets.nets()[n].params()[p];
                nets.nets_mut()[n].params_mut()[p] = keep + delta;
                let mut g = zero_grads(&nets);
                let parts = stage2_loss(&nets, &data, &cfg, 0, &mut ws, &mut g).unwrap();
                nets.nets_mut()[n].params_mut()[p] = keep;
                assert_eq!(parts.skipped, 0);
                parts.total
            };
            let fd = (f(h) - f(-h)) / (2.0 * h);
            let an = grads[n][p];
            assert!(
                (fd - an).abs() <= 1e-5 * fd.abs() + 5e-6,
                "network {n} param {p}: analytic {an} vs central difference {fd}"
            );
            checked += 1;
        }
        assert!(checked >= 4);
    }
}

/// A few stage-2 iterations lower the surface loss of every pose (from the stage the
/// networks start in), and the run is deterministic: the same seed gives bitwise the same
/// networks and rows, another seed other ones; stopped, saved, loaded and resumed it is
/// bitwise the uninterrupted run; other data settings are refused.
#[test]
fn stage2_lowers_the_loss_deterministically_and_resumes_bitwise() {
    let settings = Stage2Settings::default();
    let data = slab_data(3, settings);
    let start = nets(2);
    let total = |n: &GenerativeNets| -> f64 {
        let f = &data.faces[0];
        f.poses
            .iter()
            .map(|p| pose_loss(n, f, p, &settings).unwrap().unwrap())
            .sum()
    };
    let run = |seed: u64, iterations: u64| {
        let mut t =
            Stage2Trainer::from_nets(&data, config(iterations, seed), start.clone()).unwrap();
        let mut rows = Vec::new();
        while !t.done() {
            rows.push(t.step().unwrap());
        }
        (t.into_nets(), rows)
    };
    let (a, rows_a) = run(5, 12);
    assert!(rows_a.iter().all(|r| r.parts.skipped == 0));
    let (before, after) = (total(&start), total(&a));
    assert!(after < 0.7 * before, "surface loss {before} → {after}");

    let (b, rows_b) = run(5, 12);
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(rows_a, rows_b);
    let (c, _) = run(6, 12);
    assert_ne!(bits(&a), bits(&c));

    let mut t = Stage2Trainer::from_nets(&data, config(12, 5), start.clone()).unwrap();
    for _ in 0..5 {
        t.step().unwrap();
    }
    let path = temp_dir("stage2-resume").join("checkpoint.nn");
    t.checkpoint().save(&path).unwrap();
    drop(t);
    let ck = crate::nn::Checkpoint::load(&path).unwrap();
    let mut resumed = Stage2Trainer::resume(&data, config(12, 5), &ck).unwrap();
    assert_eq!(resumed.iteration(), 5);
    let mut rows = Vec::new();
    while !resumed.done() {
        rows.push(resumed.step().unwrap());
    }
    assert_eq!(bits(resumed.nets()), bits(&a));
    assert_eq!(rows, rows_a[5..]);
    // Other solve settings are other data: refused.
    let other = slab_data(
        3,
        Stage2Settings {
            max_adjoint_residual: 1e-7,
            ..settings
        },
    );
    assert!(Stage2Trainer::resume(&other, config(12, 5), &ck).is_err());
    // Sampled elements are refused: the solve needs the whole field.
    let mut sampled = config(12, 5);
    sampled.elements_per_pose = 16;
    let mut t = Stage2Trainer::from_nets(&data, sampled, start).unwrap();
    assert!(t.step().is_err());
}

/// Poses whose solve stops short of an equilibrium are left out and counted, not used.
#[test]
fn unconverged_poses_are_skipped_and_counted() {
    let mut settings = tight();
    settings.solve.max_iterations = 2;
    let data = slab_data(3, settings);
    let nets = nets(2);
    let mut ws = LossWorkspace::new(32, 4).unwrap();
    let mut grads = zero_grads(&nets);
    let parts = stage2_loss(&nets, &data, &config(1, 4), 0, &mut ws, &mut grads).unwrap();
    assert_eq!(parts.skipped, 2);
    assert_eq!(parts.fit, 0.0);
    assert!(parts.total.is_finite());
    // Only the Lipschitz bounds get a gradient.
    assert!(
        grads[0]
            .iter()
            .chain(&grads[1])
            .chain(&grads[3])
            .all(|&g| g == 0.0)
    );
}

/// On a sample face with poses fitted to the rig: the loss vertices are the render vertices
/// eval measures and sit where `render_positions` puts them; the fitted state is much closer
/// to the targets than the rest; the bundled stage-1 networks give a usable gradient
/// (converged solve and adjoint, finite, nonzero) of a larger loss.
#[test]
fn sample_face_stage2_data() {
    use super::data::{FacePoses, PoseSettings};
    use super::stage2::{pose_gradient, skin_points};
    use crate::rig::test_support::rig;
    let s = super::tests::sample();
    let f = &s.faces[1];
    let settings = PoseSettings {
        single_weights: vec![],
        combinations: 1,
        styled_singles: 0,
        seed: 4,
    };
    let poses = FacePoses::generate(rig(), &f.model, f.style, 1, &settings, &|_, _| {}).unwrap();
    let frame = super::tests::frame();
    let face = Stage2Face::from_sample(rig(), &f.model, f.mapping.as_ref(), &frame, &poses, false)
        .unwrap();
    let (index, _) = skin_points(&f.model);
    let embedded = f
        .model
        .render
        .bindings
        .iter()
        .filter(|b| b.element().is_some())
        .count();
    assert_eq!(index.len(), embedded);
    let pose = &face.poses[1];
    let bones = super::stage2::bones_of(pose.start_jaw);
    let render = f.model.render_positions(&pose.start, &bones);
    for (&i, p) in index.iter().zip(&face.skin) {
        assert!((p.position(&pose.start, &bones, &f.model.jaw_pivot) - render[i]).norm() < 1e-12);
    }
    let (fitted, _) = face.surface_loss(pose, &pose.start, &bones, None);
    // The fitted state pulls the simulation skin onto the rig's (to 0.01 mm here) but not
    // every render vertex: a tail of embedded vertices the fit cannot follow stays
    // centimetres off (up to 2.6 cm on this pose), so the loss falls by a factor, not to 0.
    let rest: Vec<f64> = f
        .model
        .mesh
        .vertices
        .iter()
        .flat_map(|p| [p.x, p.y, p.z])
        .collect();
    let (at_rest, _) = face.surface_loss(pose, &rest, &bones, None);
    assert!(
        fitted < 0.5 * at_rest,
        "surface loss: fitted state {fitted}, rest {at_rest} cm²"
    );
    let nets = GenerativeNets::load(&s.dir.join(super::SAMPLE_NETWORKS)).unwrap();
    let u = nets.modulation(std::slice::from_ref(&pose.codes)).unwrap();
    let u: Vec<f64> = (0..u.ncols()).map(|k| u[(0, k)]).collect();
    let g = pose_gradient(&nets, &face, pose, &u, &Stage2Settings::default())
        .unwrap()
        .unwrap();
    assert!(g.loss > fitted && g.loss.is_finite());
    assert!(g.logs.iter().flatten().all(|v| v.is_finite()));
    assert!(g.logs.iter().flatten().any(|v| *v != 0.0));
}

/// The bundled stage-2 networks load, share the stage-1 networks' architecture and frame,
/// differ from them, and drive every sample face with SPD tensors and a finite jaw.
#[test]
fn bundled_stage2_networks_drive_every_sample_face() {
    use std::sync::Arc;
    let s = super::tests::sample();
    let stage1 = GenerativeNets::load(&s.dir.join(super::SAMPLE_NETWORKS)).unwrap();
    let stage2 = GenerativeNets::load(&s.dir.join(super::stage2::SAMPLE_STAGE2_NETWORKS)).unwrap();
    assert_eq!(stage2.architecture, stage1.architecture);
    assert_eq!(stage2.frame, stage1.frame);
    assert_ne!(bits(&stage2), bits(&stage1));
    let models = super::sample_actuations(s, Arc::new(stage2)).unwrap();
    for (m, f) in models.iter().zip(&s.faces) {
        let open = Codes {
            expression: ExpressionCode::single("jawOpen", 1.0).unwrap(),
            style: f.style,
        };
        let a = m.actuate(&open).unwrap();
        assert_eq!(a.tensors.len(), f.model.mesh.element_count());
        assert!(a.tensors.iter().all(|t| t.validate().is_ok()));
        assert!(a.jaw.rotation.x > 0.05, "{}: {:?}", f.name, a.jaw);
    }
}
