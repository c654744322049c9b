//! Tests of the displacement baseline and of the evaluation's volume and crossing metrics
//! (tiny networks; labels simulated from the sample's actuation bases).

use crate::generative::NetworkSet;
use std::sync::{Arc, OnceLock};

use faer::Par;
use nalgebra::Point3;

use super::{DisplacementData, DisplacementFace, DisplacementNets};
use crate::contact::surface::FaceContact;
use crate::drive::Codes;
use crate::generative::data::{PoseSettings, training_codes};
use crate::generative::generative_face::FaceWarp;
use crate::generative::loss::{LossWeights, LossWorkspace};
use crate::generative::metrics::{VolumeChange, lip_crossings};
use crate::generative::tests::{basis_poses, bits, frame, sample, small_config, tiny};
use crate::generative::train::{ModelTrainer, train_model};
use crate::generative::{GenerativeNets, LossRow};
use crate::geometry::TetMesh;
use crate::model::contact_region::FaceContactSettings;
use crate::rig::test_support::temp_dir;
use crate::sim::{BonePose, Quality};

/// The template face and identity 0, 5 poses each, the displacement labels from solving the
/// basis's actuations (the stand-in for the rig's fitted states).
fn data() -> &'static DisplacementData {
    static DATA: OnceLock<DisplacementData> = OnceLock::new();
    DATA.get_or_init(|| {
        let settings = PoseSettings {
            single_weights: vec![1.0],
            combinations: 2,
            styled_singles: 0,
            seed: 3,
        };
        let mut solve = Quality::Preview.settings();
        solve.contact = false;
        let faces = [0usize, 1]
            .iter()
            .map(|&f| {
                let sf = &sample().faces[f];
                let codes: Vec<Codes> = training_codes(sf.style, &settings, f as u64)
                    .into_iter()
                    .step_by(5)
                    .collect();
                let mut poses = basis_poses(f, &codes);
                let sim = sf.model.simulator().unwrap();
                // Poses whose solve folds elements are left out (as the eval counts them).
                poses.poses.retain_mut(|p| {
                    let a = sf.actuation.actuate(&p.codes).unwrap();
                    let mut state = sim.rest_state();
                    if sim
                        .solve(&a.tensors, &a.bones(), &mut state, &solve)
                        .is_err()
                    {
                        return false;
                    }
                    p.displacements = sf
                        .model
                        .mesh
                        .vertices
                        .iter()
                        .zip(state.flat_positions().chunks_exact(3))
                        .map(|(r, x)| [0, 1, 2].map(|k| (x[k] - r[k]) as f32))
                        .collect();
                    true
                });
                assert!(poses.poses.len() >= 4, "most basis poses solve");
                let warp = FaceWarp::vertices(&sf.model, sf.mapping.as_ref(), &frame()).unwrap();
                (warp, poses)
            })
            .collect();
        DisplacementData::new(faces).unwrap()
    })
}

fn zero(nets: &DisplacementNets) -> Vec<Vec<f64>> {
    nets.nets()
        .iter()
        .map(|n| vec![0.0; n.num_params()])
        .collect()
}

/// The baseline's loss gradient through N_D (fit, Lipschitz), N_B (jaw), tanh and both
/// encoders agrees with central differences for parameters of every network.
#[test]
#[allow(clippy::needless_range_loop)] // n indexes the networks and their gradients alike
fn displacement_loss_gradient_matches_central_differences() {
    let batch = data().batch(&small_config(1, 5), 0);
    assert_eq!(batch.counts, vec![64, 64, 64]);
    let mut nets = DisplacementNets::new(tiny(), frame(), 9).unwrap();
    // Off the kink of the initial Lipschitz bound (see the stage-1 gradient test).
    for i in nets.displacement.lipschitz_param_indices() {
        nets.displacement.params_mut()[i] -= 0.4;
    }
    let w = LossWeights {
        lambda_act: 0.0,
        lambda_lip: 1e-2,
        jaw_lever_cm: 2.0,
    };
    let mut ws = LossWorkspace::new(16, 3).unwrap();
    let mut grads = zero(&nets);
    let parts = nets
        .batch_loss(&batch, &w, &mut ws, &mut grads, Par::Seq)
        .unwrap();
    assert!(parts.fit > 0.0 && parts.jaw > 0.0 && parts.act == 0.0);
    let h = 1e-6;
    for n in 0..4 {
        let count = nets.nets()[n].num_params();
        let mut checked = 0;
        for p in (0..count).step_by((count / 12).max(1)) {
            let mut f = |delta: f64| {
                let keep = nets.nets()[n].params()[p];
                nets.nets_mut()[n].params_mut()[p] = keep + delta;
                let mut g = zero(&nets);
                let l = nets
                    .batch_loss(&batch, &w, &mut ws, &mut g, Par::Seq)
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
    let lip = nets.displacement.lipschitz_param_indices();
    assert!(!lip.is_empty() && lip.iter().all(|&i| grads[2][i] != 0.0));
}

/// Training the baseline with the shared trainer lowers its loss; the same seed gives bitwise
/// the same networks, another seed others; a resumed run is the uninterrupted one; the file
/// round-trips and a physics networks file is refused.
#[test]
fn displacement_training_lowers_the_loss_deterministically() {
    let data = data();
    let (nets, rows) = train_model(data, small_config(150, 2), frame(), |_| {}).unwrap();
    let mean = |r: &[LossRow]| r.iter().map(|r| r.parts.total).sum::<f64>() / r.len() as f64;
    let (first, last) = (mean(&rows[..10]), mean(&rows[rows.len() - 10..]));
    assert!(last < 0.5 * first, "loss {first} → {last}");

    let (a, rows_a) = train_model(data, small_config(6, 11), frame(), |_| {}).unwrap();
    let (b, rows_b) = train_model(data, small_config(6, 11), frame(), |_| {}).unwrap();
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(rows_a, rows_b);
    let (c, _) = train_model(data, small_config(6, 12), frame(), |_| {}).unwrap();
    assert_ne!(bits(&a), bits(&c));
    let mut t = ModelTrainer::new(data, small_config(6, 11), frame()).unwrap();
    for _ in 0..3 {
        t.step().unwrap();
    }
    let ck = t.checkpoint();
    let mut resumed = ModelTrainer::resume(data, small_config(6, 11), &ck).unwrap();
    while !resumed.done() {
        resumed.step().unwrap();
    }
    assert_eq!(bits(resumed.nets()), bits(&a));

    let dir = temp_dir("displacement-file");
    let path = dir.join("displacement.nn");
    nets.save(&path).unwrap();
    assert_eq!(DisplacementNets::load(&path).unwrap(), nets);
    let physics = dir.join("generative.nn");
    GenerativeNets::new(tiny(), frame(), 1)
        .unwrap()
        .save(&physics)
        .unwrap();
    let err = DisplacementNets::load(&physics).unwrap_err().to_string();
    assert!(err.contains("not a displacement-baseline file"), "{err}");
}

/// Bound to a face: a network with zero output leaves every vertex at rest (on an identity,
/// through R_φ); a trained one moves the face, finitely, and opens the jaw
/// for jawOpen; invalid codes are refused.
#[test]
fn displacement_face_poses_vertices_and_jaw() {
    let s = sample();
    let f = &s.faces[2];
    let mut zero = DisplacementNets::new(tiny(), frame(), 3).unwrap();
    let n = zero.displacement.num_params();
    zero.displacement.params_mut()[n - 3 * (tiny().actuation_width + 1)..].fill(0.0);
    let face = DisplacementFace::new(Arc::new(zero), &f.model, f.mapping.as_ref()).unwrap();
    let p = face.pose(&Codes::default()).unwrap();
    let rest: Vec<f64> = f
        .model
        .mesh
        .vertices
        .iter()
        .flat_map(|v| [v.x, v.y, v.z])
        .collect();
    assert_eq!(p.positions, rest);

    // Trained on the template and identity 0: on the template (φ the identity) a training
    // pose's prediction is much closer to its label than the rest is.
    let (nets, _) = train_model(data(), small_config(3000, 4), frame(), |_| {}).unwrap();
    let t = &s.faces[0];
    let face = DisplacementFace::new(Arc::new(nets), &t.model, None).unwrap();
    let labels = &data().faces[0];
    let norm2 = |d: &[f32; 3]| d.iter().map(|v| (*v as f64).powi(2)).sum::<f64>();
    let pose = labels
        .poses
        .iter()
        .max_by(|a, b| {
            let s =
                |p: &super::data::DisplacementPose| p.displacements.iter().map(norm2).sum::<f64>();
            s(a).total_cmp(&s(b))
        })
        .unwrap();
    let p = face.pose(&pose.codes).unwrap();
    assert!(p.positions.iter().all(|v| v.is_finite()));
    let rest: Vec<f64> = t
        .model
        .mesh
        .vertices
        .iter()
        .flat_map(|v| [v.x, v.y, v.z])
        .collect();
    let (mut err, mut size) = (0.0, 0.0);
    for (v, d) in pose.displacements.iter().enumerate() {
        for k in 0..3 {
            let predicted = p.positions[3 * v + k] - rest[3 * v + k];
            err += (predicted - d[k] as f64).powi(2);
            size += (d[k] as f64).powi(2);
        }
    }
    assert!(
        size > 0.0 && err < 0.5 * size,
        "error² {err} vs label² {size}"
    );
    let mut bad = pose.codes;
    bad.expression.0[0] = f64::NAN;
    assert!(face.pose(&bad).is_err());
}

/// Volume change on hand-made tetrahedra: a tet stretched to twice its volume, one pushed
/// through its base (inverted), one at rest.
#[test]
fn volume_change_of_hand_made_tets() {
    let v = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(0.0, 1.0, 0.0),
        Point3::new(0.0, 0.0, 1.0),
        Point3::new(1.0, 1.0, 1.0),
    ];
    let mesh = TetMesh::new(v.clone(), vec![[0, 1, 2, 3], [1, 2, 3, 4]]).unwrap();
    let flat = |p: &[Point3<f64>]| p.iter().flat_map(|q| [q.x, q.y, q.z]).collect::<Vec<_>>();
    let rest = VolumeChange::of(&mesh, &flat(&v));
    assert_eq!(rest.inverted, 0);
    assert!(rest.mean_abs_det_change.abs() < 1e-12 && rest.total_change.abs() < 1e-12);
    // Scale x by 2: both elements double (det F = 2).
    let doubled: Vec<Point3<f64>> = v.iter().map(|p| Point3::new(2.0 * p.x, p.y, p.z)).collect();
    let d = VolumeChange::of(&mesh, &flat(&doubled));
    assert!((d.mean_abs_det_change - 1.0).abs() < 1e-12, "{d:?}");
    assert!((d.total_change - 1.0).abs() < 1e-12);
    assert_eq!(d.inverted, 0);
    // Push vertex 3 through the base of the first tet (to z = −0.5): det F = −0.5 there; the
    // second tet (vertices 1–4) changes volume but keeps its orientation.
    let mut through = v.clone();
    through[3] = Point3::new(0.1, 0.1, -0.5);
    let t = VolumeChange::of(&mesh, &flat(&through));
    let [a, b, c, d] = [1usize, 2, 3, 4].map(|i| through[i].coords);
    let det1 = (b - a).cross(&(c - a)).dot(&(d - a)) / 6.0 / mesh.signed_volume(1);
    assert!(det1 > 0.0, "the second tet stays positive: {det1}");
    assert_eq!(t.inverted, 1);
    let expected = ((-0.5f64 - 1.0).abs() + (det1 - 1.0).abs()) / 2.0;
    assert!((t.mean_abs_det_change - expected).abs() < 1e-12, "{t:?}");
}

/// Lip crossings: none at rest on the sample's template face; pushing the lips' tissue 8 mm
/// back into the mouth drives the lips through the (rigid) front teeth.
#[test]
fn lip_crossings_found_when_lips_pass_the_teeth() {
    let f = &sample().faces[0].model;
    let contact = FaceContact::new(f, &FaceContactSettings::default()).unwrap();
    let mut x: Vec<f64> = f
        .mesh
        .vertices
        .iter()
        .flat_map(|v| [v.x, v.y, v.z])
        .collect();
    let bones = BonePose::default();
    assert_eq!(lip_crossings(&contact, &x, &bones), 0);
    for &v in contact.region_sim_vertices() {
        x[3 * v as usize + 2] -= 0.8;
    }
    let n = lip_crossings(&contact, &x, &bones);
    assert!(n > 0, "lips pushed through the teeth must cross");
}

/// The bundled baseline (`sample_models/ict/displacement.nn`) loads and poses every sample
/// face: finite positions, and for jawOpen a jaw (its N_B) within a few hundredths of a
/// radian and 2 mm of the rig-fitted basis's.
#[test]
fn bundled_displacement_baseline_poses_every_sample_face() {
    let s = sample();
    let nets = Arc::new(
        DisplacementNets::load(&s.dir.join(super::SAMPLE_DISPLACEMENT))
            .expect("the bundled baseline"),
    );
    for f in &s.faces {
        let face = DisplacementFace::new(nets.clone(), &f.model, f.mapping.as_ref()).unwrap();
        assert_eq!(face.vertex_count(), f.model.mesh.vertex_count());
        let open = Codes {
            expression: crate::rig::ExpressionCode::single("jawOpen", 1.0).unwrap(),
            style: f.style,
        };
        let p = face.pose(&open).unwrap();
        assert!(p.positions.iter().all(|v| v.is_finite()));
        let basis = f.actuation.actuate(&open).unwrap().jaw;
        assert!(
            p.bones.jaw.rotation.x > 0.05,
            "{}: {:?}",
            f.name,
            p.bones.jaw
        );
        assert!(
            (p.bones.jaw.rotation - basis.rotation).norm() < 0.02
                && (p.bones.jaw.translation - basis.translation).norm() < 0.2,
            "{}: {:?} vs basis {:?}",
            f.name,
            p.bones.jaw,
            basis
        );
    }
}

/// Style transfer without canonical space: carried onto its own face, A's basis maps every
/// element to itself and gives A's tensors; onto another identity it drives that face's
/// element count with tensors taken from A; a model of another face is refused.
#[test]
fn nearest_element_transfer_copies_the_source_actuations() {
    use crate::drive::ActuationModel;
    use crate::generative::transfer::NearestElementTransfer;
    let s = sample();
    let (a, b) = (&s.faces[1], &s.faces[2]);
    let codes = Codes {
        expression: crate::rig::ExpressionCode::single("mouthSmile_L", 1.0).unwrap(),
        style: b.style,
    };
    let same = NearestElementTransfer::new(a.actuation.clone(), &a.model, &a.model).unwrap();
    assert!(
        same.source_elements()
            .iter()
            .enumerate()
            .all(|(i, &e)| i == e)
    );
    assert_eq!(
        same.actuate(&codes).unwrap().tensors,
        a.actuation.actuate(&codes).unwrap().tensors
    );
    let t = NearestElementTransfer::new(a.actuation.clone(), &a.model, &b.model).unwrap();
    assert_eq!(t.element_count(), b.model.mesh.element_count());
    let source = a.actuation.actuate(&codes).unwrap();
    let carried = t.actuate(&codes).unwrap();
    assert_eq!(carried.jaw, source.jaw);
    for (i, &e) in t.source_elements().iter().enumerate() {
        assert_eq!(carried.tensors[i], source.tensors[e]);
    }
    assert!(NearestElementTransfer::new(a.actuation.clone(), &b.model, &a.model).is_err());
}
