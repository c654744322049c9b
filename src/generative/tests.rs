//! Tests of the expression/style networks (tiny networks, few iterations; the bundled sample's
//! faces and mappings, actuations from its bases where the rig's fits are not the point).

use crate::generative::NetworkSet;
use std::sync::{Arc, OnceLock};

use faer::Par;

use super::data::{FacePoses, PoseData, PoseSettings, held_out_codes, training_codes};
use super::displacement::{DisplacementFace, DisplacementNets};
use super::eval::{EvalFace, EvalModel, evaluate};
use super::generative_face::{FaceWarp, GenerativeFace};
use super::loss::{LossWeights, LossWorkspace, batch_loss, zero_grads};
use super::nets::{Architecture, CanonicalFrame, GenerativeNets};
use super::train::{Stage1Config, Stage1Data, Trainer, train_stage1};
use crate::drive::basis::log_tensor;
use crate::drive::{ActuationModel, Codes};
use crate::rig::test_support::{rig, temp_dir};
use crate::rig::{ExpressionCode, StyleCode};
use crate::sample::{SAMPLE_DIR, Sample};

pub(crate) fn sample() -> &'static Sample {
    static SAMPLE: OnceLock<Sample> = OnceLock::new();
    SAMPLE.get_or_init(|| Sample::load(SAMPLE_DIR).expect("the bundled sample"))
}

pub(crate) fn frame() -> CanonicalFrame {
    CanonicalFrame::of(&sample().faces[0].model)
}

pub(crate) fn tiny() -> Architecture {
    Architecture {
        expression_hidden: 8,
        expression_dim: 5,
        style_hidden: 6,
        style_dim: 3,
        actuation_width: 8,
        actuation_gelu_layers: 2,
        omega0: 10.0,
        jaw_width: 7,
    }
}

/// Poses of sample face `f` labelled by its actuation basis (cheap stand-ins for the rig's
/// fits, same shape of data; no vertex displacements: see the displacement tests).
pub(crate) fn basis_poses(f: usize, codes: &[Codes]) -> FacePoses {
    let face = &sample().faces[f];
    let poses = codes
        .iter()
        .map(|c| {
            let a = face.actuation.actuate(c).unwrap();
            PoseData {
                codes: *c,
                jaw: a.jaw.params(),
                logs: a.tensors.iter().map(log_tensor).collect(),
                displacements: Vec::new(),
                skin_rms: 0.0,
                clamped: 0,
            }
        })
        .collect();
    FacePoses {
        face: face.name.clone(),
        face_hash: super::data::face_hash(&face.model),
        element_count: face.model.mesh.element_count(),
        settings: PoseSettings::default(),
        poses,
    }
}

/// Stage-1 data on the template face and identity 0 (7 poses each).
fn small_data() -> &'static Stage1Data {
    static DATA: OnceLock<Stage1Data> = OnceLock::new();
    DATA.get_or_init(|| {
        let settings = PoseSettings {
            single_weights: vec![1.0],
            combinations: 2,
            styled_singles: 0,
            seed: 3,
        };
        let faces = [0usize, 1]
            .iter()
            .map(|&f| {
                let sf = &sample().faces[f];
                let codes: Vec<Codes> = training_codes(sf.style, &settings, f as u64)
                    .into_iter()
                    .step_by(3)
                    .collect();
                let warp = FaceWarp::new(&sf.model, sf.mapping.as_ref(), &frame()).unwrap();
                (warp, basis_poses(f, &codes))
            })
            .collect();
        Stage1Data::new(faces).unwrap()
    })
}

/// Stage-1 training settings small enough for a unit test (the tiny networks, 3 poses of
/// 64 elements a batch).
pub(crate) fn small_config(iterations: u64, seed: u64) -> Stage1Config {
    Stage1Config {
        architecture: tiny(),
        iterations,
        batch_poses: 3,
        elements_per_pose: 64,
        learning_rate: 3e-3,
        seed,
        chunk_rows: 32,
        lanes: 4,
        ..Stage1Config::default()
    }
}

/// Every parameter of `nets`, bit for bit (to test that training is deterministic).
pub(crate) fn bits(nets: &impl NetworkSet) -> Vec<u64> {
    nets.networks()
        .iter()
        .flat_map(|n| n.params().iter().map(|p| p.to_bits()))
        .collect()
}

/// The stage-1 loss gradient through N_A (fit, regularizer, Lipschitz), N_B, tanh and both
/// encoders agrees with central differences, for parameters of every network.
#[test]
#[allow(clippy::needless_range_loop)] // n indexes the networks and their gradients alike
fn stage1_loss_gradient_matches_central_differences() {
    let data = small_data();
    let config = small_config(1, 5);
    let batch = data.batch(&config, 0);
    let mut nets = GenerativeNets::new(tiny(), frame(), 9).unwrap();
    // The initial bound equals the largest row sum: that row sits on the kink of
    // min(1, softplus(c)/Σ|w|), where central differences straddle two slopes. Lower every
    // bound so the normalization is active on some rows and off on others, away from kinks.
    for i in nets.actuation.lipschitz_param_indices() {
        nets.actuation.params_mut()[i] -= 0.4;
    }
    // A Lipschitz product and λs large enough to matter at this tolerance.
    let w = LossWeights {
        lambda_act: 0.3,
        lambda_lip: 1e-2,
        jaw_lever_cm: 2.0,
    };
    let mut ws = LossWorkspace::new(16, 3).unwrap();
    let mut grads = zero_grads(&nets);
    batch_loss(&nets, &batch, &w, &mut ws, &mut grads, Par::Seq).unwrap();
    let h = 1e-6;
    for n in 0..4 {
        let count = nets.nets()[n].num_params();
        let step = (count / 12).max(1);
        let mut checked = 0;
        for p in (0..count).step_by(step) {
            let mut f = |delta: f64| {
                let keep = nets.nets()[n].params()[p];
                nets.nets_mut()[n].params_mut()[p] = keep + delta;
                let mut g = zero_grads(&nets);
                let l = batch_loss(&nets, &batch, &w, &mut ws, &mut g, Par::Seq)
                    .unwrap()
                    .total;
                nets.nets_mut()[n].params_mut()[p] = keep;
                l
            };
            let fd = (f(h) - f(-h)) / (2.0 * h);
            let an = grads[n][p];
            assert!(
                (fd - an).abs() <= 1e-5 * (1.0 + fd.abs()),
                "network {n} param {p}: analytic {an} vs central difference {fd}"
            );
            checked += 1;
        }
        assert!(checked >= 10);
    }
    // The Lipschitz bounds get a gradient.
    let lip = nets.actuation.lipschitz_param_indices();
    assert_eq!(lip.len(), 2);
    assert!(lip.iter().all(|&i| grads[2][i] != 0.0));
}

/// Every code gives symmetric positive definite tensors and a finite jaw, on the template
/// face and on an identity (through φ), also codes far beyond the sliders' ranges; zero
/// network output is exactly the rest.
#[test]
fn outputs_are_spd_for_any_code() {
    let nets = Arc::new(GenerativeNets::new(Architecture::default(), frame(), 4).unwrap());
    let s = sample();
    for f in [&s.faces[0], &s.faces[2]] {
        let g = GenerativeFace::new(nets.clone(), &f.model, f.mapping.as_ref()).unwrap();
        assert_eq!(g.element_count(), f.model.mesh.element_count());
        for scale in [0.0, 1.0, -3.0, 50.0, 1e6, -1e12] {
            let mut codes = Codes::default();
            for (k, v) in codes.expression.0.iter_mut().enumerate() {
                *v = scale * ((k % 5) as f64 - 1.5);
            }
            codes.style = StyleCode([scale, -scale, 0.5 * scale, 2.0]);
            let a = g.actuate(&codes).unwrap();
            assert_eq!(a.tensors.len(), g.element_count());
            for t in &a.tensors {
                t.validate().unwrap();
                let eig = nalgebra::SymmetricEigen::new(t.to_matrix()).eigenvalues;
                assert!(eig.iter().all(|&l| l > 0.0 && l.is_finite()), "{t:?}");
            }
            assert!(
                a.jaw
                    .params()
                    .iter()
                    .all(|v| v.is_finite() && v.abs() < 100.0)
            );
        }
        let mut bad = Codes::default();
        bad.expression.0[3] = f64::NAN;
        assert!(g.actuate(&bad).is_err());
    }
    // A network whose last layer outputs zero gives exactly A = I on an identity (the warp
    // keeps identities).
    let mut zero = GenerativeNets::new(Architecture::default(), frame(), 4).unwrap();
    let n = zero.actuation.num_params();
    let last = 6 * (Architecture::default().actuation_width + 1);
    zero.actuation.params_mut()[n - last..].fill(0.0);
    let f = &s.faces[1];
    let g = GenerativeFace::new(Arc::new(zero), &f.model, f.mapping.as_ref()).unwrap();
    let a = g.actuate(&Codes::default()).unwrap();
    assert!(
        a.tensors
            .iter()
            .all(|t| *t == crate::sim::SymTensor::IDENTITY)
    );
}

/// Same seed → bitwise the same networks; another seed → different; a run stopped, saved to a
/// checkpoint file, loaded and resumed is bitwise the uninterrupted run.
#[test]
fn training_is_deterministic_and_resumable() {
    let data = small_data();
    let (a, rows_a) = train_stage1(data, small_config(6, 11), frame(), |_| {}).unwrap();
    let (b, rows_b) = train_stage1(data, small_config(6, 11), frame(), |_| {}).unwrap();
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(rows_a, rows_b);
    let (c, _) = train_stage1(data, small_config(6, 12), frame(), |_| {}).unwrap();
    assert_ne!(bits(&a), bits(&c));

    let mut t = Trainer::new(data, small_config(6, 11), frame()).unwrap();
    for _ in 0..3 {
        t.step().unwrap();
    }
    let path = temp_dir("stage1-resume").join("checkpoint.nn");
    t.checkpoint().save(&path).unwrap();
    drop(t);
    let ck = crate::nn::Checkpoint::load(&path).unwrap();
    let mut resumed = Trainer::resume(data, small_config(6, 11), &ck).unwrap();
    assert_eq!(resumed.iteration(), 3);
    let mut rows = Vec::new();
    while !resumed.done() {
        rows.push(resumed.step().unwrap());
    }
    assert_eq!(bits(resumed.nets()), bits(&a));
    assert_eq!(rows, rows_a[3..]);
    // Other settings are refused.
    assert!(Trainer::resume(data, small_config(7, 11), &ck).is_err());
    // The final networks round-trip through their file.
    let model = path.with_file_name("generative.nn");
    a.save(&model).unwrap();
    assert_eq!(GenerativeNets::load(&model).unwrap(), a);
}

/// Training lowers the loss: the mean of the last 10 batch losses is well below the first 10
/// (same batches compared through their seeds).
#[test]
fn training_lowers_the_loss() {
    let data = small_data();
    let config = small_config(150, 2);
    let (nets, rows) = train_stage1(data, config, frame(), |_| {}).unwrap();
    let mean = |r: &[super::LossRow]| r.iter().map(|r| r.parts.total).sum::<f64>() / r.len() as f64;
    let (first, last) = (mean(&rows[..10]), mean(&rows[rows.len() - 10..]));
    assert!(last < 0.5 * first, "loss {first} → {last}");
    // On a fixed batch too.
    let batch = data.batch(&config, 0);
    let fresh = GenerativeNets::new(tiny(), frame(), config.seed).unwrap();
    let mut ws = LossWorkspace::new(32, 4).unwrap();
    let loss = |n: &GenerativeNets, ws: &mut LossWorkspace| {
        let mut g = zero_grads(n);
        batch_loss(n, &batch, &config.weights, ws, &mut g, Par::Seq)
            .unwrap()
            .total
    };
    assert!(loss(&nets, &mut ws) < 0.5 * loss(&fresh, &mut ws));
}

/// The pose cache: generated from the rig's fits, saved, loaded back identical; other
/// settings or another face are not a match.
#[test]
fn pose_cache_round_trip() {
    let s = sample();
    let face = &s.faces[1];
    let settings = PoseSettings {
        single_weights: vec![],
        combinations: 2,
        styled_singles: 0,
        seed: 4,
    };
    let poses =
        FacePoses::generate(rig(), &face.model, face.style, 1, &settings, &|_, _| {}).unwrap();
    assert_eq!(poses.poses.len(), 3);
    // Every simulation vertex gets the fit's displacement: none at rest, some otherwise.
    let n = face.model.mesh.vertex_count();
    assert!(poses.poses.iter().all(|p| p.displacements.len() == n));
    assert!(
        poses.poses[0]
            .displacements
            .iter()
            .flatten()
            .all(|v| v.abs() < 1e-3)
    );
    assert!(
        poses.poses[1]
            .displacements
            .iter()
            .flatten()
            .any(|v| v.abs() > 1e-2)
    );
    // The rest pose fits to A ≈ I, the others move something.
    assert!(poses.poses[0].logs.iter().flatten().all(|v| v.abs() < 1e-3));
    assert!(poses.poses[1].logs.iter().flatten().any(|v| v.abs() > 1e-2));
    let path = temp_dir("poses").join("f.poses");
    assert!(
        FacePoses::load_matching(&path, &face.model, &settings)
            .unwrap()
            .is_none()
    );
    poses.save(&path).unwrap();
    let back = FacePoses::load_matching(&path, &face.model, &settings)
        .unwrap()
        .unwrap();
    assert_eq!(back, poses);
    let other = PoseSettings {
        combinations: 3,
        ..settings.clone()
    };
    assert!(
        FacePoses::load_matching(&path, &face.model, &other)
            .unwrap()
            .is_none()
    );
    assert!(
        FacePoses::load_matching(&path, &s.faces[2].model, &settings)
            .unwrap()
            .is_none()
    );
    std::fs::write(&path, b"garbage").unwrap();
    assert!(FacePoses::load_matching(&path, &face.model, &settings).is_err());
}

/// Held-out codes are reproducible, none is a training code, and the evaluation runs both
/// models on them and reports finite errors for the solved poses.
#[test]
fn held_out_codes_and_eval_run() {
    let codes = held_out_codes(2, 1);
    assert_eq!(codes, held_out_codes(2, 1));
    let s = sample();
    for (i, f) in s.faces.iter().enumerate() {
        let train = training_codes(f.style, &PoseSettings::default(), i as u64);
        assert!(train.iter().all(|t| !codes.contains(&t.expression)));
    }
    let f = &s.faces[0];
    let nets = Arc::new(GenerativeNets::new(tiny(), frame(), 1).unwrap());
    let g = GenerativeFace::new(nets, &f.model, None).unwrap();
    let d = DisplacementFace::new(
        Arc::new(DisplacementNets::new(tiny(), frame(), 1).unwrap()),
        &f.model,
        None,
    )
    .unwrap();
    let report = evaluate(
        rig(),
        &[EvalFace {
            face: &f.model,
            style: f.style,
            own_style: None,
            models: vec![
                ("networks", EvalModel::Physics(&g)),
                ("basis", EvalModel::Physics(f.actuation.as_ref())),
                ("displacement", EvalModel::Displacement(&d)),
            ],
        }],
        &codes,
        false,
        &|_| {},
    )
    .unwrap();
    assert_eq!(report.rows.len(), 3);
    assert_eq!(report.targets.len(), 1);
    assert_eq!(report.common_rows.len(), 3);
    // Common rows pool exactly the codes all three models posed.
    let common = (0..2)
        .filter(|&c| {
            report
                .poses
                .iter()
                .filter(|p| p.code == c)
                .all(|p| p.error.is_none())
        })
        .count();
    assert!(
        report
            .common_rows
            .iter()
            .all(|r| r.poses == common && r.failed == 0)
    );
    assert_eq!(report.targets[0].poses, 2);
    assert_eq!(report.poses.len(), 6);
    let basis = &report.rows[1];
    assert_eq!(basis.failed, 0, "{report:?}");
    let (mean, max) = (basis.mean_mm.unwrap(), basis.max_mm.unwrap());
    assert!(mean > 0.0 && mean < 2.0 && max >= mean, "{basis:?}");
    // The solved tissue changes volume a little, folds nothing (a fold fails the solve).
    let det = basis.mean_abs_det_change.unwrap();
    assert!(det > 0.0 && det < 0.5, "{basis:?}");
    assert_eq!(basis.inverted, 0);
    assert!(basis.max_abs_volume_change.unwrap() >= basis.mean_abs_volume_change.unwrap());
    // The (untrained) baseline is read out without a solve, with the same metrics.
    let base = &report.rows[2];
    assert_eq!((base.model.as_str(), base.failed), ("displacement", 0));
    assert!(base.mean_mm.unwrap() > 0.0 && base.mean_abs_det_change.unwrap() > 0.0);
    let base_poses: Vec<_> = report
        .poses
        .iter()
        .filter(|p| p.model == "displacement")
        .collect();
    assert!(
        base_poses
            .iter()
            .all(|p| p.iterations == 0 && p.volume.is_some() && p.crossings.is_some())
    );
    assert!(
        report.table().contains("| basis | 2/2 |"),
        "{}",
        report.table()
    );
    assert!(report.table().contains("inverted elements"));
    assert!(report.style_rows.is_empty() && report.style_table().is_empty());
    assert!(report.csv().lines().count() == 4);
    let _ = ExpressionCode::LEN;
}

/// An actuation model that ignores the style code (always its face's own style): the
/// reference point of the style metric, whose style change is exactly zero.
struct StyleBlind<'a> {
    inner: &'a dyn ActuationModel,
    style: crate::rig::StyleCode,
}

impl ActuationModel for StyleBlind<'_> {
    fn element_count(&self) -> usize {
        self.inner.element_count()
    }

    fn actuate(&self, codes: &Codes) -> Result<crate::drive::Actuation, crate::drive::DriveError> {
        self.inner.actuate(&Codes {
            style: self.style,
            ..*codes
        })
    }
}

/// Style transfer's metric splits geometry from style: a model blind to the style keeps none of
/// the rig's style change (`style kept` exactly 0, its change error the rig's change), while
/// the face's own basis, fitted to the rig's shapes, keeps most of it.
#[test]
fn style_metric_separates_style_from_geometry() {
    let s = sample();
    let (b, a) = (&s.faces[0], &s.faces[1]);
    assert_ne!(a.style, b.style);
    let blind = StyleBlind {
        inner: b.actuation.as_ref(),
        style: b.style,
    };
    let codes = held_out_codes(2, 1);
    let report = evaluate(
        rig(),
        &[EvalFace {
            face: &b.model,
            style: a.style,
            own_style: Some(b.style),
            models: vec![
                ("basis", EvalModel::Physics(b.actuation.as_ref())),
                ("blind", EvalModel::Physics(&blind)),
            ],
        }],
        &codes,
        false,
        &|_| {},
    )
    .unwrap();
    let [basis, blind] = &report.style_rows[..] else {
        panic!("{report:?}")
    };
    assert_eq!((basis.poses, blind.poses), (2, 2));
    let rig_change = basis.rig_style_change_mm.unwrap();
    assert!(rig_change > 0.01, "{basis:?}");
    assert_eq!(blind.rig_style_change_mm, basis.rig_style_change_mm);
    assert_eq!(blind.style_kept, Some(0.0));
    assert!((blind.style_change_error_mm.unwrap() - rig_change).abs() < 1e-12);
    assert!(basis.style_kept.unwrap() > 0.5, "{basis:?}");
    // In the own style both are the same model: the same geometry error.
    assert_eq!(basis.own_style_mean_mm, blind.own_style_mean_mm);
    assert!(report.style_table().contains("| blind | 2 |"));
}

/// The bundled sample's trained networks load and drive every face: SPD tensors, a jaw that
/// opens with jawOpen, and actuations that differ from the rest where the code moves the face.
#[test]
fn bundled_networks_drive_every_sample_face() {
    let s = sample();
    let models = super::load_sample_networks(s, super::SAMPLE_NETWORKS)
        .unwrap()
        .expect("sample_models/ict/generative.nn");
    assert_eq!(models.len(), s.faces.len());
    for (m, f) in models.iter().zip(&s.faces) {
        assert_eq!(m.element_count(), f.model.mesh.element_count());
        let open = Codes {
            expression: ExpressionCode::single("jawOpen", 1.0).unwrap(),
            style: f.style,
        };
        let a = m.actuate(&open).unwrap();
        assert!(a.tensors.iter().all(|t| t.validate().is_ok()));
        // The basis (fitted to the rig) and the networks agree on the jaw to a few mrad.
        let b = f.actuation.actuate(&open).unwrap();
        assert!(a.jaw.rotation.x > 0.05, "{}: {:?}", f.name, a.jaw);
        assert!(
            (a.jaw.rotation - b.jaw.rotation).norm() < 0.02,
            "{}",
            f.name
        );
    }
}

/// A run kept in a folder (`generative::run`), stopped after 3 of 6 iterations and resumed,
/// ends bit for bit where an uninterrupted run ends, its loss curve holds each iteration once,
/// and a fresh run over an existing checkpoint is refused.
#[test]
fn a_stopped_run_resumes_to_the_same_networks() {
    use std::ops::ControlFlow;

    use super::run::{RunError, RunEvent, RunPlan, STAGE1_FILES, run_training};
    let data = small_data();
    let root = std::env::temp_dir().join(format!("facesim-run-{}", std::process::id()));
    let (straight, stopped) = (root.join("straight"), root.join("stopped"));
    for d in [&straight, &stopped] {
        std::fs::create_dir_all(d).unwrap();
    }
    let plan = |out, resume| RunPlan {
        out,
        resume,
        config: small_config(6, 4),
        frame: frame(),
        files: &STAGE1_FILES,
        checkpoint_every: 4,
        pose_settings: serde_json::Value::Null,
    };
    let poses = data.pose_count();
    let go = &mut |_: RunEvent<'_>| ControlFlow::Continue(());
    let whole = run_training(&plan(&straight, false), data, poses, None, go).unwrap();
    assert!(whole.finished && whole.iterations_run == 6);

    let stop_at_3 = &mut |e: RunEvent<'_>| match e {
        RunEvent::Step { row, .. } if row.iteration == 2 => ControlFlow::Break(()),
        _ => ControlFlow::Continue(()),
    };
    let first = run_training(&plan(&stopped, false), data, poses, None, stop_at_3).unwrap();
    assert!(!first.finished && first.iterations_run == 3);
    assert!(!stopped.join(STAGE1_FILES.model).exists());
    let again = run_training(&plan(&stopped, false), data, poses, None, go);
    assert!(matches!(again, Err(RunError::Exists(_))), "{again:?}");
    let rest = run_training(&plan(&stopped, true), data, poses, None, go).unwrap();
    assert!(rest.finished && rest.iterations_run == 3);

    let nets = |dir: &std::path::Path| GenerativeNets::load(&dir.join(STAGE1_FILES.model)).unwrap();
    assert_eq!(bits(&nets(&straight)), bits(&nets(&stopped)));
    let curve =
        |dir: &std::path::Path| std::fs::read_to_string(dir.join(STAGE1_FILES.loss)).unwrap();
    assert_eq!(curve(&straight).lines().count(), 1 + 6);
    let iterations: Vec<String> = curve(&stopped)
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().to_string())
        .collect();
    assert_eq!(iterations, ["0", "1", "2", "3", "4", "5"]);
    std::fs::remove_dir_all(&root).unwrap();
}
