//! Which rig vertices ride on which bone, from how the rig's own shapes move them: the
//! skull under skin no lower-face shape moves, the jaw where jawOpen moves the skin like the
//! lower teeth, and how much of the jaw's motion each vertex
//! follows (the side of the mouth slit it is on, and how the deep mouth moves between the
//! bones).

use nalgebra::{Matrix3, Point3, Vector3};

use super::face::Binding;
use crate::rig::jaw::{JawError, fit_rigid};
use crate::rig::{ExpressionCode, FaceRig, Region};
use crate::sim::{Bone, BonePose};

/// How the rig moves each of its vertices relative to the bones (module doc).
pub(super) struct BoneMotion {
    /// Largest displacement of each rig vertex under any default shape at weight 1 (cm).
    pub(super) max_motion: Vec<f64>,
    /// Each vertex's jawOpen displacement minus the lower teeth's rigid motion there, over
    /// the latter (0: moves exactly with the jaw).
    pub(super) jaw_mismatch: Vec<f64>,
    pub(super) jaw_motion: Vec<f64>,
    /// How far each vertex moves relative to the jaw in the shape that moves it most so
    /// (cm): `maxₖ ‖dₖ − jₖ‖` over the default shapes, `jₖ` the jaw's rigid motion there.
    jaw_slip: Vec<f64>,
    /// How much of the jaw's motion each rig vertex follows: the least-squares `β` of
    /// `dₖ ≈ β·jₖ` over the jaw shapes `k` (`dₖ` the vertex's displacement, `jₖ` the lower
    /// teeth's rigid motion there), clamped to [0, 1]: 0 on the skull, 1 on the jaw.
    pub(super) jaw_share: Vec<f64>,
    /// The linear map `M` of the jaw's motion onto each vertex's, `dₖ ≈ M·jₖ` by least
    /// squares over the jaw shapes (regularized toward `β·I` with β the jaw share): the deep
    /// mouth lining stretches between the gums along its own directions, which no mix of the
    /// two rigid motions gives (jawOpen: 4.4 mm mean error for the mix, 0.06 mm for `M`, on
    /// the template's lining).
    pub(super) jaw_map: Vec<Matrix3<f64>>,
    /// The jaw's rigid motion `jₖ` at each vertex in each jaw shape (cm).
    jaw_motions: Vec<Vec<Vector3<f64>>>,
    pub(super) jaw_fit_rms: f64,
    skull_motion: f64,
    jaw_match: f64,
}

impl BoneMotion {
    /// Measures the rig's `identity` (`None`: the template) about the jaw `pivot`; skin moved
    /// less than `skull_motion` (cm) by every shape rides on the skull, skin that jawOpen
    /// moves like the teeth to within `jaw_match` of their motion on the jaw.
    pub(super) fn new(
        rig: &FaceRig,
        identity: Option<usize>,
        pivot: Point3<f64>,
        skull_motion: f64,
        jaw_match: f64,
    ) -> Result<Self, JawError> {
        let base = rig.base(identity);
        let n = base.len();
        let teeth = Region::LowerTeeth.vertices();
        let mut max_motion = vec![0.0f64; n];
        let (mut moved, mut jaw) = (vec![Matrix3::zeros(); n], vec![Matrix3::zeros(); n]);
        let (mut jaw_mismatch, mut jaw_motion) = (vec![f64::INFINITY; n], vec![0.0; n]);
        let mut jaw_fit_rms = 0.0;
        let mut jaw_slip = vec![0.0f64; n];
        let mut jaw_motions = vec![Vec::new(); n];
        for name in ExpressionCode::NAMES {
            let Some(code) = ExpressionCode::single(name, 1.0) else {
                continue;
            };
            let posed = rig.pose(identity, &code);
            for v in 0..n {
                let d = (posed[v] - base[v]).norm();
                max_motion[v] = max_motion[v].max(d);
            }
            let fit = fit_rigid(&base[teeth.clone()], &posed[teeth.clone()], &pivot)?;
            let pose = BonePose {
                jaw: fit.motion,
                ..BonePose::default()
            };
            for v in 0..n {
                let rigid = pose.target(Bone::Jaw, &pivot, &base[v]) - base[v];
                jaw_slip[v] = jaw_slip[v].max(((posed[v] - base[v]) - rigid).norm());
            }
            if !name.starts_with("jaw") {
                continue;
            }
            for v in 0..n {
                let rigid = pose.target(Bone::Jaw, &pivot, &base[v]) - base[v];
                moved[v] += (posed[v] - base[v]) * rigid.transpose();
                jaw[v] += rigid * rigid.transpose();
                jaw_motions[v].push(rigid);
                if name == "jawOpen" {
                    jaw_motion[v] = rigid.norm();
                    jaw_mismatch[v] =
                        ((posed[v] - base[v]) - rigid).norm() / rigid.norm().max(1e-9);
                }
            }
            if name == "jawOpen" {
                jaw_fit_rms = fit.rms_error;
            }
        }
        let jaw_share: Vec<f64> = moved
            .iter()
            .zip(&jaw)
            .map(|(m, j)| {
                if j.trace() > 0.0 {
                    (m.trace() / j.trace()).clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        let jaw_map = (0..n)
            .map(|v| {
                let prior = Matrix3::identity() * (JAW_MAP_PRIOR * jaw_share[v]);
                (jaw[v] + Matrix3::identity() * JAW_MAP_PRIOR)
                    .try_inverse()
                    .map_or(prior, |inverse| (moved[v] + prior) * inverse)
            })
            .collect();
        Ok(Self {
            max_motion,
            jaw_mismatch,
            jaw_motion,
            jaw_slip,
            jaw_share,
            jaw_map,
            jaw_motions,
            jaw_fit_rms,
            skull_motion,
            jaw_match,
        })
    }

    /// The bone under rig vertex `v`, if its skin rides on one.
    pub(super) fn bone_of(&self, v: usize) -> Option<Bone> {
        if self.on_skull(v) {
            Some(Bone::Skull)
        } else if self.jaw_mismatch[v] < self.jaw_match
            && self.jaw_motion[v] > 0.5
            && self.jaw_slip[v] < JAW_SLIP
        {
            Some(Bone::Jaw)
        } else {
            None
        }
    }

    /// Whether no default shape moves rig vertex `v` (its skin rides on the skull).
    pub(super) fn on_skull(&self, v: usize) -> bool {
        self.max_motion[v] < self.skull_motion
    }

    /// The bone a pinned border vertex follows: the jaw if jawOpen moves it like the lower
    /// teeth, else the skull.
    pub(super) fn nearest_bone(&self, v: usize) -> Bone {
        if self.jaw_mismatch[v] < 0.5 {
            Bone::Jaw
        } else {
            Bone::Skull
        }
    }

    /// How a render vertex that no tissue carries follows the bones: rigidly with one where
    /// its jaw map is within [`SNAP_TO_BONE`] of none or all of the jaw's motion, else by its
    /// jaw map ([`Binding::Bones`]).
    pub(super) fn bone_binding(&self, v: usize) -> Binding {
        Self::snapped(self.jaw_map[v])
    }

    /// [`BoneMotion::bone_binding`] for a vertex `gap` (cm) from `bone`'s surface at rest, in
    /// direction `away` (unit, from the surface to the vertex): its jaw map drawn toward the
    /// bone's own (`M_b = I` for the jaw, `0` for the skull) just enough that in no jaw shape
    /// does it move toward that surface by more than half the gap, relative to the bone:
    /// `M' = s·M + (1 − s)·M_b` moves it by `s·(M − M_b)·jₖ`, so
    /// `s = min(1, minₖ ½·gap / max(0, −away·(M − M_b)·jₖ))`. The rig's lining behind the
    /// lower incisors (`M ≈ 1.1·I`) goes through the gum from 0.15–0.4 cm away; the lining
    /// that stretches away from the gums as the mouth opens keeps the rig's motion.
    pub(super) fn bone_binding_near(
        &self,
        v: usize,
        bone: Bone,
        gap: f64,
        away: &Vector3<f64>,
    ) -> Binding {
        let own = match bone {
            Bone::Skull => Matrix3::zeros(),
            Bone::Jaw => Matrix3::identity(),
        };
        let m = self.jaw_map[v];
        let s = self.jaw_motions[v]
            .iter()
            .map(|j| -away.dot(&((m - own) * j)))
            .filter(|&toward| toward > 0.0)
            .map(|toward| 0.5 * gap / toward)
            .fold(1.0, f64::min);
        Self::snapped(m * s + own * (1.0 - s))
    }

    fn snapped(m: Matrix3<f64>) -> Binding {
        if m.norm() <= SNAP_TO_BONE {
            Binding::Rigid(Bone::Skull)
        } else if (m - Matrix3::identity()).norm() <= SNAP_TO_BONE {
            Binding::Rigid(Bone::Jaw)
        } else {
            Binding::Bones { jaw: m }
        }
    }
}

/// Skin that some shape moves by more than this (cm) relative to the jaw is not held on it:
/// the lower lip and chin follow jawOpen like the teeth, but the mouth shapes roll and push
/// them by 1–3 cm while the teeth stay, and tissue held on the jaw beneath is sheared through
/// itself (folded elements in the fits of mouthFunnel and mouthPucker). On the ICT rig no
/// skin qualifies: the jaw then moves the tissue through the teeth's contact and the deep
/// mouth it carries, and the actuations move the chin.
const JAW_SLIP: f64 = 0.3;

/// Tikhonov weight (cm²) pulling a jaw map toward `β·I` where the jaw shapes leave it free; the
/// jaw shapes move the teeth by 0.5–4 cm, so their `Σ jₖ·jₖᵀ` outweighs it by 25–1,600×.
const JAW_MAP_PRIOR: f64 = 0.01;

/// A vertex whose jaw map is this close (Frobenius) to 0 or `I` rides on that bone alone.
const SNAP_TO_BONE: f64 = 0.02;
