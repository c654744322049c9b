//! Pose stages of a contact solve: how the tissue and the rigid contact surfaces (teeth) get
//! from the bone pose a state was solved under to the next one without any surface crossing.
//!
//! Moving only the teeth while the tissue stands still makes them run into lips that are
//! themselves attached to the jaw and would have moved out of the way: random codes swing
//! the jaw far, and such frames needed more than 64 stages. So a stage first *carries* the
//! tissue with the bones by the first-order change of the equilibrium,
//!
//! `Δx = H⁻¹·(K_a·Δtarget − Wᵀ[∇²B]₊·Δy_teeth)`,
//!
//! with `H` the step matrix of the solver at the current state (the prefactored PD matrix `L`
//! plus, by the same low-rank update, the curvature of the contact barrier and of the volume
//! barrier): the attachments pull the tissue along (exact for a translation; a jaw-attached
//! region moves by the bone's own affine motion), lips pressed against each other move
//! together instead of into each other, and lips the teeth press on are pushed along. The
//! carried state is used when the straight path of the whole contact surface (soft and
//! rigid) to it is certified by CCD; where the prediction would take an element past the
//! volume barrier's step limit ([`STEP_VOLUME_KEPT`] of its volume) it is shortened to stay
//! within it. So a stage never starts crossed or folded. When no carry is certified, only
//! the teeth move (the tissue stays), and failing that the caller shortens the stage.

use super::attachment::BonePose;
use super::contact::{ContactModel, ContactSolve};
use super::low_rank::StepInverse;
use super::shape_targeting::{LocalStep, STEP_VOLUME_KEPT, volume_step_limit};
use super::simulator::{SimError, Simulator};
use super::tensor::SymTensor;

/// A carry that would take some element past the volume limit is shortened to this fraction
/// of the limit (so no element starts a stage at the limit itself).
const CARRY_SHORTENING: f64 = 0.9;

/// The linearized response of the tissue at one state to bone-pose changes: `H` (the PD
/// matrix plus the curvature of the contact barrier and of the volume barrier there) and the
/// contact state that gives the teeth's push.
pub(crate) struct Carrier<'a> {
    contact: ContactSolve<'a>,
    inverse: StepInverse,
    from: BonePose,
    targets: Vec<f64>,
    y: Vec<f64>,
}

impl Simulator {
    /// Linearizes the tissue at `x` under pose `from` and `actuations` (`steps`: the local
    /// steps of the last solve, the rotations' warm start).
    pub(crate) fn carrier<'a>(
        &self,
        model: &'a ContactModel,
        actuations: &[SymTensor],
        x: &[f64],
        steps: &[LocalStep],
        from: &BonePose,
    ) -> Result<Carrier<'a>, SimError> {
        let frame = self.frame(actuations, from)?;
        let mut fresh = steps.to_vec();
        self.local_sweep(&frame, x, Some(steps), &mut fresh);
        let mut g = vec![0.0; x.len()];
        self.gradient(&frame, x, &fresh, &mut g);
        let mut contact = ContactSolve::start(model, x, from, &g)?;
        let (inverse, _) = self.step_inverse(&fresh, Some(&mut contact))?;
        let mut y = vec![0.0; 3 * model.face.vertex_count()];
        model.face.positions(x, from, &mut y);
        Ok(Carrier {
            contact,
            inverse,
            from: *from,
            targets: frame.targets,
            y,
        })
    }

    /// The tissue's predicted displacement when the bones go from the carrier's pose to `b`:
    /// `H⁻¹·(K_a·Δtarget − [∇²B]·Δy_teeth)`, the first-order change of the equilibrium.
    pub(crate) fn carried_displacement(
        &self,
        carrier: &Carrier,
        x: &[f64],
        b: &BonePose,
    ) -> Result<Vec<f64>, SimError> {
        let model = carrier.contact.model();
        let tb = self.attachment_targets(b);
        let mut yb = vec![0.0; carrier.y.len()];
        model.face.positions(x, b, &mut yb);
        let dy: Vec<f64> = yb.iter().zip(&carrier.y).map(|(q, p)| q - p).collect();
        let mut dx = carrier.contact.push(&dy, self.vertex_count())?;
        for (i, (p, q)) in carrier.targets.iter().zip(&tb).enumerate() {
            dx[i] += self.stiffness[i / 3] * (q - p);
        }
        carrier
            .inverse
            .apply(&self.global, &mut dx, &mut self.solve_scratch());
        Ok(dx)
    }

    /// The longest fraction of the move `x → x + dx` that keeps every element above
    /// [`STEP_VOLUME_KEPT`] of its volume at `x` (0 if an element is already folded at `x`).
    pub(crate) fn volume_path_limit(&self, x: &[f64], dx: &[f64]) -> f64 {
        use rayon::prelude::*;
        (0..self.element_count())
            .into_par_iter()
            .with_min_len(512)
            .map(|e| {
                volume_step_limit(
                    &self.deformation_gradient(x, e),
                    &self.deformation_gradient(dx, e),
                    STEP_VOLUME_KEPT,
                )
            })
            .reduce(|| 1.0, f64::min)
    }

    /// The smallest distance between contact surfaces within d̂ at pose `a` with the tissue
    /// at `x` (d̂ when none is that close).
    pub(crate) fn obstacle_gap(
        &self,
        model: &ContactModel,
        x: &[f64],
        a: &BonePose,
    ) -> Result<f64, SimError> {
        let mut ya = vec![0.0; 3 * model.face.vertex_count()];
        model.face.positions(x, a, &mut ya);
        Ok(model.face.collisions(&ya)?.min_distance_squared().sqrt())
    }

    /// Whether the straight move of every contact vertex from (tissue `x`, pose `a`) to
    /// (tissue `x + dx`, pose `b`) crosses no surface and brings no pair closer than half of
    /// `gap` (the closest distance at the start, so the barrier a stage starts with stays
    /// moderate). `dx = None` keeps the tissue where it is (only the teeth move).
    pub(crate) fn stage_path_free(
        &self,
        model: &ContactModel,
        x: &[f64],
        dx: Option<&[f64]>,
        a: &BonePose,
        b: &BonePose,
        gap: f64,
    ) -> Result<bool, SimError> {
        let m = 3 * model.face.vertex_count();
        let (mut ya, mut yb) = (vec![0.0; m], vec![0.0; m]);
        model.face.positions(x, a, &mut ya);
        match dx {
            Some(dx) => {
                let moved: Vec<f64> = x.iter().zip(dx).map(|(p, d)| p + d).collect();
                model.face.positions(&moved, b, &mut yb);
            }
            None => model.face.positions(x, b, &mut yb),
        }
        let dy: Vec<f64> = yb.iter().zip(&ya).map(|(p, q)| p - q).collect();
        let report = crate::contact::collision_free_step(
            model.face.mesh(),
            &ya,
            &dy,
            &crate::contact::CcdOptions {
                min_distance: 0.5 * gap,
                max_iterations: 1000,
                ..crate::contact::CcdOptions::default()
            },
        )?;
        Ok(report.step >= 1.0)
    }

    /// Whether the carried state (tissue `x + dx`, pose `b`) passes the after-solve crossing
    /// check. CCD certifies every pair that contact tracks, but pairs left out because they
    /// are within d̂ at rest are not tracked; a carry moves the tissue much farther in one go
    /// than a line-search step (capped at 0.1 cm), so the crossing check guards those too.
    fn crossing_free(&self, model: &ContactModel, x: &[f64], dx: &[f64], b: &BonePose) -> bool {
        let moved: Vec<f64> = x.iter().zip(dx).map(|(p, d)| p + d).collect();
        let mut y = vec![0.0; 3 * model.face.vertex_count()];
        model.face.positions(&moved, b, &mut y);
        model.face.new_crossings(&y).is_empty()
    }

    /// How a stage from the carrier's pose to pose `b` may start (`None` when no move is
    /// certified: the caller shortens the stage).
    pub(crate) fn stage_start(
        &self,
        carrier: &Carrier,
        x: &[f64],
        b: &BonePose,
        gap: f64,
    ) -> Result<Option<StageStart>, SimError> {
        let a = &carrier.from;
        let model = carrier.contact.model();
        if a == b {
            return Ok(Some(StageStart::TeethOnly));
        }
        let mut dx = self.carried_displacement(carrier, x, b)?;
        if dx.iter().all(|v| v.is_finite()) {
            // Where the linear prediction would squeeze some element past the volume
            // barrier's step limit, carry the tissue only that far (the solve does the rest).
            let volume = self.volume_path_limit(x, &dx);
            if volume < 1.0 {
                dx.iter_mut().for_each(|v| *v *= CARRY_SHORTENING * volume);
            }
            if volume > 0.0
                && self.stage_path_free(model, x, Some(&dx), a, b, gap)?
                && self.crossing_free(model, x, &dx, b)
            {
                return Ok(Some(StageStart::Carried(dx)));
            }
        }
        if self.stage_path_free(model, x, None, a, b, gap)? {
            return Ok(Some(StageStart::TeethOnly));
        }
        Ok(None)
    }
}

/// A certified start of a pose stage.
#[derive(Debug)]
pub(crate) enum StageStart {
    /// Move the tissue by this displacement along with the bones.
    Carried(Vec<f64>),
    /// Move only the teeth; the tissue stays.
    TeethOnly,
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use crate::bench::contact_sweep::random_codes;
    use crate::contact::face::{FaceContact, FaceContactSettings};
    use crate::sim::{BonePose, Quality};

    /// The first two codes of the random sweep (`bench contact --sweep`, seed 1) on the
    /// bundled sample: the jaw swings 0.14 and then 0.24 rad (with 0.45 cm translations),
    /// and the second frame used to fail with "more than 64 collision-free stages" after
    /// 78 s. Both must solve with contact, crossing- and fold-free, in a few stages that
    /// carry the tissue along. On the way: the carry of a pure translation of the head is
    /// that translation, contact curvature and the teeth's push included.
    #[test]
    fn large_jaw_swings_solve_in_few_carried_stages() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let sample = crate::sample::Sample::load(root.join(crate::sample::SAMPLE_DIR)).unwrap();
        let face = sample.faces.iter().find(|f| f.identity.is_none()).unwrap();
        let mut sim = face.model.simulator().unwrap();
        let contact = FaceContact::new(&face.model, &FaceContactSettings::default()).unwrap();
        sim.set_contact(contact).unwrap();
        let settings = Quality::Interactive.settings();
        let mut state = sim.rest_state();
        for (frame, code) in random_codes(2, 1).iter().enumerate() {
            let a = face.actuation.actuate(code).unwrap();
            let bones = a.bones();
            let stats = sim
                .solve(&a.tensors, &bones, &mut state, &settings)
                .unwrap_or_else(|e| panic!("frame {frame}: {e}"));
            let c = stats.contact.as_ref().expect("contact ran");
            eprintln!(
                "frame {frame}: {} stages ({} carried), {} iterations, {:.1} s",
                c.pose_stages,
                c.carried_stages,
                stats.iterations,
                stats.wall_time.as_secs_f64()
            );
            assert!(
                c.pose_stages <= 16,
                "frame {frame}: {} stages",
                c.pose_stages
            );
            assert!(
                c.carried_stages >= 1,
                "frame {frame}: the tissue was never carried"
            );
            assert_eq!(state.bones, bones);
            // Checked independently of the solver's own final check.
            let model = sim.contact.as_ref().unwrap();
            let mut y = vec![0.0; 3 * model.face.vertex_count()];
            model.face.positions(&state.x, &bones, &mut y);
            assert!(model.face.new_crossings(&y).is_empty(), "frame {frame}");
            assert!(
                state.steps.iter().all(|s| s.volume_ratio > 0.0),
                "frame {frame}"
            );

            if frame == 0 {
                // Contact is active here (lips pressed, teeth close): translate the head.
                assert!(c.active_pairs > 0);
                let shift = Vector3::new(0.3, -0.2, 0.1);
                let moved = BonePose {
                    skull: crate::sim::RigidMotion {
                        translation: bones.skull.translation + shift,
                        ..bones.skull
                    },
                    ..bones
                };
                let carrier = sim
                    .carrier(model, &a.tensors, &state.x, &state.steps, &bones)
                    .unwrap();
                let dx = sim
                    .carried_displacement(&carrier, &state.x, &moved)
                    .unwrap();
                let worst = dx
                    .chunks_exact(3)
                    .map(|d| (Vector3::new(d[0], d[1], d[2]) - shift).norm())
                    .fold(0.0, f64::max);
                assert!(worst < 1e-6 * shift.norm(), "worst deviation {worst:e} cm");
            }
        }
    }
}
