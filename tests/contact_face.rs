//! Contact on the real face (the ICT rig's neutral at the coarse level of detail): the jaw
//! clenching onto lips and teeth, lips pressed, pursed and rolled to and past their extremes,
//! and random sweeps. Every frame must come back without error (no inverted element, no
//! non-finite value), with zero new crossings of the lips, mouth and teeth, within the
//! preset's iteration cap.

use std::path::PathBuf;
use std::sync::OnceLock;

use facesim::bench::mouth_poses::{LipField, MouthPose, random_poses, run_sequence};
use facesim::contact::surface::FaceContact;
use facesim::model::contact_region::FaceContactSettings;
use facesim::model::{FaceModel, Lod, build_face};
use facesim::rig::FaceRig;
use facesim::sim::{BonePose, Quality, SimState, Simulator, SolveSettings, SymTensor};

fn rig_dir() -> PathBuf {
    match std::env::var_os("FACESIM_RIG_DIR") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/data/ict-facekit"
        )),
    }
}

/// The neutral coarse face, built once per test binary.
fn model() -> &'static FaceModel {
    static MODEL: OnceLock<FaceModel> = OnceLock::new();
    MODEL.get_or_init(|| {
        let rig = FaceRig::load(rig_dir()).expect("the ICT rig (set FACESIM_RIG_DIR)");
        build_face(&rig, None, &Lod::Coarse.settings()).expect("building the neutral face")
    })
}

fn contact() -> &'static FaceContact {
    static CONTACT: OnceLock<FaceContact> = OnceLock::new();
    CONTACT.get_or_init(|| FaceContact::new(model(), &FaceContactSettings::default()).unwrap())
}

fn simulator() -> Simulator {
    let mut sim = model().simulator().unwrap();
    sim.set_contact(contact().clone()).unwrap();
    sim
}

fn field() -> &'static LipField {
    static FIELD: OnceLock<LipField> = OnceLock::new();
    FIELD.get_or_init(|| LipField::new(model(), contact(), 1.5))
}

/// Zero new crossings of the contact surface at `state` (checked independently of the
/// solver's own check).
fn assert_intersection_free(state: &SimState, bones: &BonePose) {
    let c = contact();
    let mut y = vec![0.0; 3 * c.vertex_count()];
    c.positions(state.flat_positions(), bones, &mut y);
    let crossings = c.new_crossings(&y);
    assert!(crossings.is_empty(), "{} crossings", crossings.len());
}

#[test]
fn contact_region_is_the_mouth() {
    let c = contact();
    let [skin, socket, upper, lower] = c.piece_counts();
    eprintln!(
        "contact vertices: {} (lips {skin}, mouth {socket}, upper teeth {upper}, lower teeth {lower}), faces {}, edges {}, sim region {}, close pairs {:?}, rest crossings {}",
        c.vertex_count(),
        c.mesh().faces().len(),
        c.mesh().edges().len(),
        c.region_sim_vertices().len(),
        c.close_pairs(),
        c.rest_crossing_count()
    );
    assert!(skin > 100 && socket > 100 && upper > 50 && lower > 50);
    // At rest no pair is within its activation distance (d̂, or half the rest distance of
    // a pair closer than d̂ at rest), so the barrier is zero.
    let mut y = vec![0.0; 3 * c.vertex_count()];
    let x: Vec<f64> = model()
        .mesh
        .vertices
        .iter()
        .flat_map(|p| [p.x, p.y, p.z])
        .collect();
    c.positions(&x, &BonePose::default(), &mut y);
    assert!(c.collisions(&y).unwrap().is_empty());
    assert!(c.new_crossings(&y).is_empty());
}

/// Solves `poses` in order (warm-started, interactive preset) and checks every frame: no
/// error (so no inverted element and no crossing found by the solver), finite positions,
/// zero crossings by an independent check, iterations within the cap.
fn run_poses(poses: &[MouthPose]) {
    let sim = simulator();
    let settings = SolveSettings {
        audit_crossings: true,
        ..Quality::Interactive.settings()
    };
    let mut state = sim.rest_state();
    for pose in poses {
        let bones = pose.bones();
        let stats = sim
            .solve(&field().actuations(pose), &bones, &mut state, &settings)
            .unwrap_or_else(|e| panic!("{pose:?}: {e}"));
        assert!(state.flat_positions().iter().all(|v| v.is_finite()));
        assert_intersection_free(&state, &bones);
        let contact = stats.contact.as_ref().expect("contact was on");
        assert_eq!(contact.new_crossings, Some(0));
        assert!(contact.min_distance > 0.0);
        assert!(stats.iterations <= settings.max_iterations * contact.pose_stages);
        eprintln!(
            "{pose:?}: {} it ({:?}), residual {:.1e}, {} active pairs, min gap {:.1e} cm, {:.0} ms",
            stats.iterations,
            stats.termination,
            stats.residual,
            contact.active_pairs,
            contact.min_distance,
            stats.wall_time.as_secs_f64() * 1e3
        );
    }
}

#[test]
fn jaw_closing_hard_onto_lips_and_teeth() {
    let poses: Vec<MouthPose> = [-0.01, -0.02, -0.03, -0.04]
        .iter()
        .map(|&jaw_open| MouthPose {
            jaw_open,
            press: 1.0,
            ..MouthPose::default()
        })
        .collect();
    run_poses(&poses);
}

#[test]
fn lips_pressed_pursed_and_rolled_past_their_extremes() {
    let extreme = |purse, press, roll| MouthPose {
        jaw_open: 0.0,
        purse,
        press,
        roll,
    };
    run_poses(&[
        extreme(0.0, 1.0, 0.0),
        extreme(0.0, 1.5, 0.0),
        extreme(1.5, 1.5, 1.5),
        extreme(1.5, 1.5, -1.5),
        extreme(0.0, 0.0, 1.5),
    ]);
}

#[test]
fn random_sweep_beyond_the_range() {
    run_poses(&random_poses(7, 8, 1.5, 0.05));
}

#[test]
fn contact_off_is_the_plain_solve() {
    let sim = simulator();
    let plain = model().simulator().unwrap();
    let pose = MouthPose {
        purse: 0.5,
        ..MouthPose::default()
    };
    let settings = SolveSettings {
        contact: false,
        ..Quality::Interactive.settings()
    };
    let (mut a, mut b) = (sim.rest_state(), plain.rest_state());
    let sa = sim
        .solve(&field().actuations(&pose), &pose.bones(), &mut a, &settings)
        .unwrap();
    let sb = plain
        .solve(&field().actuations(&pose), &pose.bones(), &mut b, &settings)
        .unwrap();
    assert!(sa.contact.is_none() && sb.contact.is_none());
    assert_eq!(a.flat_positions(), b.flat_positions());
    // The sequence driver records every frame.
    let outcomes = run_sequence(&sim, 2, &Quality::Interactive.settings(), |_| {
        (
            vec![SymTensor::IDENTITY; model().mesh.element_count()],
            BonePose::default(),
        )
    });
    assert!(outcomes.iter().all(|o| o.result.is_ok()));
}
