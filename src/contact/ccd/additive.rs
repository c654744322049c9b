//! Additive continuous collision detection (ACCD; Li et al. 2021, "Codimensional Incremental
//! Potential Contact", §5, Alg. 1) for one point–triangle or edge–edge pair over the linear
//! step `x(t) = x₀ + t·Δx`, `t ∈ [0, t_max]`.
//!
//! After removing the stencil's mean displacement (distance is translation invariant), the
//! distance can shrink at most at the rate `l = ‖Δp‖ + maxᵢ‖Δtᵢ‖` (point–triangle) or
//! `l = maxᵢ‖Δeaᵢ‖ + maxⱼ‖Δebⱼ‖` (edge–edge): the closest point of a triangle or edge is a
//! convex combination of its vertices. So from a state at distance `d`, advancing by
//! `t_l = η·(d − ξ)/l` keeps the distance above `ξ + (1 − η)(d − ξ)`. ACCD repeats such
//! advances until either `t` passes `t_max` (no impact) or the distance falls below the gap
//! `g = (1 − η)(d₀ − ξ)` above `ξ`, and then returns the time reached **before** that last
//! advance, where the distance is at least `ξ + g`. Every returned time is therefore safe in
//! exact arithmetic whatever the iteration count; the gap absorbs rounding in the distances.

use crate::contact::distance::{edge_edge_distance, point_triangle_distance};
use crate::contact::math::Vec3;

use super::{CcdOptions, CcdOutcome};

/// The result of one narrow-phase query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NarrowPhase {
    /// A step fraction in `[0, t_max]` at which the pair is at least `ξ + g` apart and that the
    /// linear path reaches without the distance ever dropping to `ξ`.
    pub toi: f64,
    pub outcome: CcdOutcome,
    /// Advances taken.
    pub iterations: u64,
}

/// ACCD for the point–triangle pair with start positions `x0 = [p, t0, t1, t2]` and
/// displacements `dx` over `t ∈ [0, tmax]`.
pub fn point_triangle_ccd(
    x0: &[Vec3; 4],
    dx: &[Vec3; 4],
    tmax: f64,
    opts: &CcdOptions,
) -> NarrowPhase {
    let mut d = *dx;
    subtract_mean(&mut d);
    let rate = d[0].norm() + d[1].norm().max(d[2].norm()).max(d[3].norm());
    additive_ccd(x0, &d, rate, tmax, opts, |x| {
        point_triangle_distance(&x[0], &x[1], &x[2], &x[3])
    })
}

/// ACCD for the edge–edge pair with start positions `x0 = [ea0, ea1, eb0, eb1]` and
/// displacements `dx` over `t ∈ [0, tmax]`.
pub fn edge_edge_ccd(x0: &[Vec3; 4], dx: &[Vec3; 4], tmax: f64, opts: &CcdOptions) -> NarrowPhase {
    let mut d = *dx;
    subtract_mean(&mut d);
    let rate = d[0].norm().max(d[1].norm()) + d[2].norm().max(d[3].norm());
    additive_ccd(x0, &d, rate, tmax, opts, |x| {
        edge_edge_distance(&x[0], &x[1], &x[2], &x[3])
    })
}

fn subtract_mean(d: &mut [Vec3; 4]) {
    let mean = (d[0] + d[1] + d[2] + d[3]) / 4.0;
    for v in d.iter_mut() {
        *v -= mean;
    }
}

/// Algorithm 1 of Li et al. 2021 with an explicit `t_max`, an iteration cap (the time reached so
/// far is returned: still safe) and a refusal to certify any motion when the initial gap is
/// within rounding of `ξ`.
fn additive_ccd(
    x0: &[Vec3; 4],
    dx: &[Vec3; 4],
    rate: f64,
    tmax: f64,
    opts: &CcdOptions,
    distance_squared: impl Fn(&[Vec3; 4]) -> f64,
) -> NarrowPhase {
    let xi = opts.min_distance;
    let eta = opts.conservative_rescaling;
    let d0 = distance_squared(x0).sqrt();
    // Rounding in a squared distance of points at scale L is ~ε·L²; in d it is ~ε·L²/d.
    let scale = x0
        .iter()
        .map(|p| p.amax())
        .fold(0.0, f64::max)
        .max(f64::MIN_POSITIVE);
    let noise = 64.0 * f64::EPSILON * scale;
    if !(d0 > xi) || d0 - xi <= noise {
        return NarrowPhase {
            toi: 0.0,
            outcome: CcdOutcome::TooClose,
            iterations: 0,
        };
    }
    if rate == 0.0 {
        // Rigid translation of the whole stencil (or no motion): the distance is constant.
        return NarrowPhase {
            toi: tmax,
            outcome: CcdOutcome::Clear,
            iterations: 0,
        };
    }
    let gap = (1.0 - eta) * (d0 - xi);
    let mut x = *x0;
    let mut d = d0;
    let mut toi = 0.0;
    let mut iterations = 0;
    while iterations < opts.max_iterations {
        iterations += 1;
        let step = eta * (d - xi) / rate;
        for (xi_, dxi) in x.iter_mut().zip(dx) {
            *xi_ += step * dxi;
        }
        d = distance_squared(&x).sqrt();
        if toi > 0.0 && !(d - xi >= gap) {
            return NarrowPhase {
                toi,
                outcome: CcdOutcome::Hit,
                iterations,
            };
        }
        toi += step;
        if toi > tmax {
            return NarrowPhase {
                toi: tmax,
                outcome: CcdOutcome::Clear,
                iterations,
            };
        }
    }
    NarrowPhase {
        toi,
        outcome: CcdOutcome::IterationCap,
        iterations,
    }
}
