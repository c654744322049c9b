//! Contact on the real face (the ICT rig's neutral at the coarse level of detail): the jaw
//! clenching onto lips and teeth, lips pressed, pursed and rolled to and past their extremes,
//! and random sweeps. Every frame must come back without error (no inverted element, no
//! non-finite value), with zero new crossings of the lips, mouth and teeth, within the
//! preset's iteration cap.

use std::path::PathBuf;
use std::sync::OnceLock;

use facesim::contact::drive::{LipField, MouthPose, random_poses, run_sequence};
use facesim::contact::face::{FaceContact, FaceContactSettings};
use facesim::model::{FaceModel, Lod, build_face};
use facesim::rig::FaceRig;
use facesim::sim::{BonePose, Quality, SimState, Simulator, SolveSettings, SymTensor};

fn rig_dir() -> PathBuf {
    match std::env::var_os("FACESIM_RIG_DIR") {
        Some(d) => PathBuf::from(d),
        None => PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/ict-facekit")),
    }
}

/// The neutral coarse face, built once per test binary.
fn model() -> &'static FaceModel {
    static MODEL: OnceLock<FaceModel> = OnceLock::new();
    MODEL.get_or_init(|| {
        let rig = FaceRig::load(&rig_dir()).expect("the ICT rig (set FACESIM_RIG_DIR)");
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
        "contact vertices: {} (lips {skin}, mouth {socket}, upper teeth {upper}, lower teeth {lower}), faces {}, edges {}, sim region {}, rest exclusions {:?}, rest crossings {}",
        c.vertex_count(),
        c.mesh().faces().len(),
        c.mesh().edges().len(),
        c.region_sim_vertices().len(),
        c.rest_exclusions(),
        c.rest_crossing_count()
    );
    assert!(skin > 100 && socket > 100 && upper > 50 && lower > 50);
    // At rest nothing is within d̂ except the excluded pairs, so the barrier is zero.
    let mut y = vec![0.0; 3 * c.vertex_count()];
    let x: Vec<f64> = model().mesh.vertices.iter().flat_map(|p| [p.x, p.y, p.z]).collect();
    c.positions(&x, &BonePose::default(), &mut y);
    assert!(c.collisions(&y).unwrap().is_empty());
    assert!(c.new_crossings(&y).is_empty());
}

fn probe(pose: MouthPose, settings: &SolveSettings) {
    let sim = simulator();
    let mut state = sim.rest_state();
    let stats = sim.solve(&field().actuations(&pose), &pose.bones(), &mut state, settings);
    match &stats {
        Ok(s) => eprintln!(
            "{pose:?}: {} it, {:?}, residual {:.2e}, energy {:.3e}, wall {:?}, local {:?}, global {:?}\n  {:?}",
            s.iterations, s.termination, s.residual, s.energy, s.wall_time, s.local_time, s.global_time, s.contact
        ),
        Err(e) => eprintln!("{pose:?}: {e}"),
    }
}

#[test]
fn probe_jaw() {
    probe(
        MouthPose {
            jaw_open: -0.03,
            press: 1.0,
            ..MouthPose::default()
        },
        &Quality::Interactive.settings(),
    );
}
