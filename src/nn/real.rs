//! The scalar types the networks run in: `f64` (training, gradient checks) and `f32` (fast
//! inference). Both implement [`Real`], which also carries branch-free, auto-vectorizable
//! `exp` and `sin_cos` kernels used by the activation loops.
//!
//! # Fast kernels
//! - `exp_fast(x)`: x is clamped to ±`EXP_CLAMP`; k = round(x·log₂e) by the magic-number
//!   trick, r = x − k·ln2 (two-part Cody–Waite), eʳ by its Taylor series (degree 13 in f64,
//!   7 in f32, |r| ≤ ln2/2), and 2ᵏ assembled from exponent bits. Relative error ≲ 2 ulp.
//!   NaN propagates.
//! - `sin_cos_fast(x)`: k = round(x·2/π), r = x − k·π/2 (three-part Cody–Waite), sin r and
//!   cos r by Taylor series on |r| ≤ π/4, swapped and sign-flipped by the quadrant k mod 4.
//!   Accurate to a few ulp for |x| ≤ `SIN_COS_LIMIT`; callers fall back to `std` beyond it.

// The reduction constants are fdlibm's and Cephes' exact splits, written as published.
#![allow(clippy::excessive_precision)]

use std::fmt;
use std::iter::Sum;
use std::ops::{Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Sub, SubAssign};

mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for f64 {}
}

/// A floating-point scalar the networks are generic over (`f32` or `f64`).
pub trait Real:
    faer::traits::ComplexField
    + Copy
    + Send
    + Sync
    + Default
    + PartialOrd
    + fmt::Debug
    + fmt::Display
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
    + DivAssign
    + Sum
    + 'static
    + sealed::Sealed
{
    const ZERO: Self;
    const ONE: Self;
    /// `"f32"` or `"f64"`.
    const NAME: &'static str;
    /// |x| above which `sin_cos_fast` loses accuracy and `std` must be used instead.
    const SIN_COS_LIMIT: Self;

    /// Converts from `f64` (rounding to nearest for `f32`).
    fn of(x: f64) -> Self;
    fn to_f64(self) -> f64;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    fn exp(self) -> Self;
    fn ln(self) -> Self;
    fn ln_1p(self) -> Self;
    fn exp_m1(self) -> Self;
    fn tanh(self) -> Self;
    fn sin(self) -> Self;
    fn cos(self) -> Self;
    fn max(self, other: Self) -> Self;
    fn min(self, other: Self) -> Self;
    fn is_finite(self) -> bool;
    /// −1, 0 or +1 (0 for ±0 and NaN): the derivative of |x| used by the Lipschitz
    /// normalization (subgradient 0 at 0).
    fn sign(self) -> Self;

    /// Vectorizable eˣ (see the module docs); no `std` call, safe for every input.
    fn exp_fast(self) -> Self;
    /// Vectorizable (sin x, cos x); valid for |x| ≤ `SIN_COS_LIMIT` (see the module docs).
    fn sin_cos_fast(self) -> (Self, Self);
}

macro_rules! impl_real {
    (
        $t:ty, $bits:ty, $name:literal,
        mantissa_bits = $mb:literal, exp_bias = $bias:literal, magic = $magic:expr,
        exp_clamp = $clamp:expr, ln2 = ($ln2hi:expr, $ln2lo:expr),
        pio2 = ($p1:expr, $p2:expr, $p3:expr), sin_cos_limit = $lim:expr,
        exp_terms = $et:literal, sin_terms = $st:literal, cos_terms = $ct:literal
    ) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            const NAME: &'static str = $name;
            const SIN_COS_LIMIT: Self = $lim;

            #[inline(always)]
            fn of(x: f64) -> Self {
                x as $t
            }
            #[inline(always)]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline(always)]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline(always)]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline(always)]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline(always)]
            fn ln(self) -> Self {
                <$t>::ln(self)
            }
            #[inline(always)]
            fn ln_1p(self) -> Self {
                <$t>::ln_1p(self)
            }
            #[inline(always)]
            fn exp_m1(self) -> Self {
                <$t>::exp_m1(self)
            }
            #[inline(always)]
            fn tanh(self) -> Self {
                <$t>::tanh(self)
            }
            #[inline(always)]
            fn sin(self) -> Self {
                <$t>::sin(self)
            }
            #[inline(always)]
            fn cos(self) -> Self {
                <$t>::cos(self)
            }
            #[inline(always)]
            fn max(self, other: Self) -> Self {
                <$t>::max(self, other)
            }
            #[inline(always)]
            fn min(self, other: Self) -> Self {
                <$t>::min(self, other)
            }
            #[inline(always)]
            fn is_finite(self) -> bool {
                <$t>::is_finite(self)
            }
            #[inline(always)]
            fn sign(self) -> Self {
                if self > 0.0 {
                    1.0
                } else if self < 0.0 {
                    -1.0
                } else {
                    0.0
                }
            }

            #[inline(always)]
            fn exp_fast(self) -> Self {
                const LOG2E: $t = std::f64::consts::LOG2_E as $t;
                const MAGIC: $t = $magic;
                let x = self.clamp(-$clamp, $clamp);
                let t = x * LOG2E + MAGIC;
                let k = t - MAGIC;
                let r = (x - k * $ln2hi) - k * $ln2lo;
                // Horner on Σ rⁱ/i!, i = 0..=exp_terms.
                let mut p: $t = 1.0;
                let mut i = $et;
                while i > 0 {
                    p = p * r * (1.0 / i as $t) + 1.0;
                    i -= 1;
                }
                let scale = <$t>::from_bits(t.to_bits().wrapping_add($bias) << $mb);
                p * scale
            }

            #[inline(always)]
            fn sin_cos_fast(self) -> (Self, Self) {
                const FRAC_2_PI: $t = std::f64::consts::FRAC_2_PI as $t;
                const MAGIC: $t = $magic;
                const SIGN_SHIFT: u32 = <$bits>::BITS - 2;
                let x = self;
                let t = x * FRAC_2_PI + MAGIC;
                let k = t - MAGIC;
                let q = t.to_bits() & 3;
                let r = ((x - k * $p1) - k * $p2) - k * $p3;
                let r2 = r * r;
                // sin r = r·Σ (−r²)ⁱ/(2i+1)!, cos r = Σ (−r²)ⁱ/(2i)!, by Horner from the top.
                let mut s: $t = 1.0;
                let mut i = $st;
                while i > 0 {
                    s = 1.0 - s * r2 * (1.0 / ((2 * i) * (2 * i + 1)) as $t);
                    i -= 1;
                }
                let s = s * r;
                let mut c: $t = 1.0;
                let mut i = $ct;
                while i > 0 {
                    c = 1.0 - c * r2 * (1.0 / ((2 * i - 1) * (2 * i)) as $t);
                    i -= 1;
                }
                // Quadrant q: (sin, cos) = (s, c), (c, −s), (−s, −c), (−c, s).
                let swap = (q & 1) != 0;
                let (sv, cv) = if swap { (c, s) } else { (s, c) };
                let sin_sign = (q & 2) << SIGN_SHIFT;
                let cos_sign = (q.wrapping_add(1) & 2) << SIGN_SHIFT;
                (
                    <$t>::from_bits(sv.to_bits() ^ sin_sign),
                    <$t>::from_bits(cv.to_bits() ^ cos_sign),
                )
            }
        }
    };
}

impl_real!(
    f64,
    u64,
    "f64",
    mantissa_bits = 52,
    exp_bias = 1023,
    magic = 6755399441055744.0, // 1.5·2⁵²
    exp_clamp = 708.0,
    ln2 = (6.93147180369123816490e-01, 1.90821492927058770002e-10),
    pio2 = (
        1.57079632673412561417e+00,
        6.07710050630396597660e-11,
        2.02226624871116645580e-21
    ),
    sin_cos_limit = 1.0e5,
    exp_terms = 13,
    sin_terms = 8,
    cos_terms = 9
);

impl_real!(
    f32,
    u32,
    "f32",
    mantissa_bits = 23,
    exp_bias = 127,
    magic = 12582912.0, // 1.5·2²³
    exp_clamp = 87.0,
    ln2 = (0.693359375, -2.12194440e-4),
    pio2 = (1.5703125, 4.837512969970703125e-4, 7.54978995489188216e-8),
    sin_cos_limit = 4.0e3,
    exp_terms = 7,
    sin_terms = 6,
    cos_terms = 6
);

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn rel_err(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs().max(1e-300)
    }

    #[test]
    fn exp_fast_matches_std_f64() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut worst = 0.0f64;
        for i in 0..200_000 {
            let x = if i % 2 == 0 {
                rng.random_range(-700.0..700.0)
            } else {
                rng.random_range(-5.0..5.0)
            };
            worst = worst.max(rel_err(x.exp_fast(), x.exp()));
        }
        assert!(worst < 4e-16, "worst relative error {worst:e}");
        assert_eq!(0.0f64.exp_fast(), 1.0);
        assert!(f64::NAN.exp_fast().is_nan());
        assert!(1e6f64.exp_fast().is_finite() && (-1e6f64).exp_fast() >= 0.0);
    }

    #[test]
    fn exp_fast_matches_std_f32() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let mut worst = 0.0f64;
        for _ in 0..200_000 {
            let x: f32 = rng.random_range(-80.0..80.0);
            worst = worst.max(rel_err(x.exp_fast() as f64, (x as f64).exp()));
        }
        assert!(worst < 3e-7, "worst relative error {worst:e}");
    }

    #[test]
    fn sin_cos_fast_matches_std() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (mut ws, mut wc) = (0.0f64, 0.0f64);
        for i in 0..200_000 {
            let x: f64 = if i % 2 == 0 {
                rng.random_range(-1.0e5..1.0e5)
            } else {
                rng.random_range(-10.0..10.0)
            };
            let (s, c) = x.sin_cos_fast();
            ws = ws.max((s - x.sin()).abs());
            wc = wc.max((c - x.cos()).abs());
        }
        assert!(ws < 1e-15 && wc < 1e-15, "abs errors {ws:e} {wc:e}");
        let (mut ws, mut wc) = (0.0f64, 0.0f64);
        for _ in 0..200_000 {
            let x: f32 = rng.random_range(-4.0e3..4.0e3);
            let (s, c) = x.sin_cos_fast();
            let xd = x as f64;
            ws = ws.max((s as f64 - xd.sin()).abs());
            wc = wc.max((c as f64 - xd.cos()).abs());
        }
        assert!(ws < 5e-7 && wc < 5e-7, "f32 abs errors {ws:e} {wc:e}");
        // Every quadrant boundary and sign.
        for k in -8..=8 {
            let x = k as f64 * std::f64::consts::FRAC_PI_4;
            let (s, c) = x.sin_cos_fast();
            assert!(
                (s - x.sin()).abs() < 1e-15 && (c - x.cos()).abs() < 1e-15,
                "x = {x}"
            );
        }
        assert!(f64::NAN.sin_cos_fast().0.is_nan());
    }

    #[test]
    fn sign_and_conversions() {
        assert_eq!(Real::sign(-2.0f64), -1.0);
        assert_eq!(Real::sign(0.0f32), 0.0);
        assert_eq!(Real::sign(f64::NAN), 0.0);
        assert_eq!(<f32 as Real>::of(0.5).to_f64(), 0.5);
    }
}
