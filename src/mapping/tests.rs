//! φ on real faces: the neutral and identity 0 of the ICT rig at the coarse level of detail.

use std::sync::OnceLock;

use super::*;
use crate::model::{FaceModel, Lod, build_face};
use crate::rig::test_support::{rig, temp_dir};

fn faces() -> &'static (FaceModel, FaceModel) {
    static FACES: OnceLock<(FaceModel, FaceModel)> = OnceLock::new();
    FACES.get_or_init(|| {
        let settings = Lod::Coarse.settings();
        let neutral = build_face(rig(), None, &settings).expect("neutral");
        let identity = build_face(rig(), Some(0), &settings).expect("identity 0");
        (neutral, identity)
    })
}

fn short_config(iterations: u64) -> TrainConfig {
    TrainConfig {
        iterations,
        ..TrainConfig::default()
    }
}

fn trained() -> &'static Mapping {
    static PHI: OnceLock<Mapping> = OnceLock::new();
    PHI.get_or_init(|| {
        let (neutral, identity) = faces();
        train(identity, neutral, &short_config(600), |_| {})
            .expect("training")
            .0
    })
}

#[test]
fn training_fits_the_surface_and_keeps_the_map_near_rigid() {
    let (neutral, identity) = faces();
    let phi = trained();
    let record = phi.record.as_ref().unwrap();
    let untrained = Mapping::new(identity, neutral, Architecture::default(), 1).unwrap();
    let error = |m: &Mapping| {
        IdentityStats::sample(identity, neutral, m, 5)
            .unwrap()
            .summary()
    };
    let (before, after) = (error(&untrained), error(phi));
    assert!(
        after.vertex_error_mean_mm < 1.0
            && after.vertex_error_mean_mm < 0.1 * before.vertex_error_mean_mm,
        "mean vertex error {} mm after training ({} before)",
        after.vertex_error_mean_mm,
        before.vertex_error_mean_mm
    );
    assert!(record.final_vertex_mse_mm2.sqrt() < 1.5);
    assert!(
        after.det_min > 0.0,
        "φ folds: det ∂φ/∂x down to {}",
        after.det_min
    );
    // Identity 0 is smaller than the neutral, so φ expands it (det ≈ 1.12): volume change
    // is allowed to follow the size difference, but must stay smooth across the tissue.
    assert!(
        (0.8..1.25).contains(&after.det_median),
        "median det {}",
        after.det_median
    );
    assert!(after.det_max / after.det_min < 1.5, "det spread {after:?}");
    assert!(
        after.condition_p95 < 2.0,
        "σmax/σmin p95 {}",
        after.condition_p95
    );
    assert_eq!(
        after.interior_points,
        identity.mesh.vertex_count() + identity.mesh.element_count()
    );
}

#[test]
fn training_is_deterministic_for_a_seed() {
    let (neutral, identity) = faces();
    let run = |seed| {
        let config = TrainConfig {
            seed,
            ..short_config(20)
        };
        let (phi, rows) = train(identity, neutral, &config, |_| {}).unwrap();
        (
            phi.network()
                .params()
                .iter()
                .map(|p| p.to_bits())
                .collect::<Vec<_>>(),
            rows,
        )
    };
    let (a, rows_a) = run(4);
    let (b, rows_b) = run(4);
    assert_eq!(a, b);
    assert_eq!(rows_a, rows_b);
    assert_ne!(a, run(5).0);
}

#[test]
fn the_mapping_file_round_trips_and_refuses_other_faces() {
    let (neutral, identity) = faces();
    let phi = trained();
    let dir = temp_dir("mapping");
    let path = dir.join("identity000.mapping");
    phi.save(&path).unwrap();
    let back = Mapping::load(&path).unwrap();
    assert_eq!(&back, phi);
    assert!(back.check_face(identity).is_ok());
    assert!(matches!(
        back.check_face(neutral),
        Err(MappingError::WrongFace { .. })
    ));
    // Corrupt one payload byte: the checksum catches it.
    let mut bytes = std::fs::read(&path).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0xff;
    std::fs::write(&path, &bytes).unwrap();
    assert!(matches!(Mapping::load(&path), Err(MappingError::File(_))));
    // An untrained mapping is not written.
    let untrained = Mapping::new(identity, neutral, Architecture::default(), 1).unwrap();
    assert!(matches!(
        untrained.save(&dir.join("x.mapping")),
        Err(MappingError::Untrained)
    ));
}

#[test]
fn identity_actuations_keep_the_identity_at_rest_under_the_warp() {
    let (_, identity) = faces();
    let ew = ElementWarp::new(identity, trained()).unwrap();
    // R_φ is not trivial on a real identity, yet Rᵀ I R = I.
    let angle = ew
        .rotations
        .iter()
        .map(|r| {
            nalgebra::Rotation3::from_matrix_unchecked(*r)
                .angle()
                .to_degrees()
        })
        .fold(0.0, f64::max);
    assert!(angle > 0.5, "R_φ turns by at most {angle}°");
    let actuations = ew.warped(|_| crate::sim::SymTensor::IDENTITY);
    for a in &actuations {
        let d = a.to_matrix() - nalgebra::Matrix3::identity();
        assert!(d.abs().max() < 1e-12);
    }
    let sim = identity.simulator().unwrap();
    let mut state = sim.rest_state();
    sim.solve(
        &actuations,
        &crate::sim::BonePose::default(),
        &mut state,
        &crate::sim::Quality::Final.settings(),
    )
    .unwrap();
    for (p, q) in state.positions().iter().zip(&identity.mesh.vertices) {
        assert!((p - q).norm() < 1e-9, "moved by {}", (p - q).norm());
    }
}

/// The warp turns the contraction directions with the face: a rigidly rotated copy of the
/// identity deforms as the rotated original does, while the naive warp's does not.
#[test]
fn the_warp_turns_actuations_with_the_face_and_the_naive_warp_does_not() {
    let (neutral, identity) = faces();
    let field = RingField::around_mouth(neutral, 0.3, 2.0).unwrap();
    let c = warp::compare(identity, trained(), &field, 30.0).unwrap();
    assert!(c.actuated_elements > 100);
    assert!(
        c.warp_max_displacement_mm > 0.5,
        "the field barely moves the face: {c:?}"
    );
    assert!(c.identity_actuation_max_displacement_mm < 1e-6);
    assert!(c.warp_equivariance_max_mm < 0.02, "{c:?}");
    assert!(
        c.naive_equivariance_max_mm > 20.0 * c.warp_equivariance_max_mm.max(0.01),
        "{c:?}"
    );
}

#[test]
fn vertex_values_cover_every_render_vertex() {
    let (neutral, identity) = faces();
    let phi = trained();
    let pairs = Correspondences::between(identity, neutral).unwrap();
    for kind in HeatmapKind::ALL {
        let v = vertex_values(identity, neutral, phi, kind).unwrap();
        assert_eq!(v.len(), identity.render.rest.len());
        assert!(v.iter().all(|x| x.is_finite()));
        if kind == HeatmapKind::VertexError {
            // On the correspondences it is the statistics' vertex error.
            let st = IdentityStats::sample(identity, neutral, phi, 1).unwrap();
            for (k, &i) in pairs.render_vertex.iter().enumerate() {
                assert!((v[i] - st.vertex_error_mm[k]).abs() < 1e-9);
            }
        }
    }
    assert!(vertex_values(neutral, neutral, phi, HeatmapKind::Determinant).is_err());
}
