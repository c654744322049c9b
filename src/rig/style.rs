//! Per-identity styles: how a person performs an expression.
//!
//! The rig has one generic expression set, so every identity would smile the same way. A
//! [`StyleCode`] (the paper's 4-d style code) changes that: it turns the 19 expression weights
//! into weights on the rig's shapes (the 19 and a few lower-face shapes outside the code) with
//!
//! | entry | name | effect (for `s` in [-1, 1]) |
//! |---|---|---|
//! | 0 | `intensity` | every mouth shape (not the jaw) scaled by `1 + 0.35·s` |
//! | 1 | `asymmetry` | left shapes scaled by `1 + 0.35·s`, right ones by `1 − 0.35·s` |
//! | 2 | `jaw` | jaw shapes scaled by `1 + 0.3·s`; `s > 0` also drops the lower lip with the jaw (`mouthLowerDown` at `0.5·s·jawOpen`) |
//! | 3 | `dimple` | `s > 0`: smiles dimple (`mouthDimple` at `0.6·s·smile`) and lift the upper lip (`mouthUpperUp` `+0.3·s·smile`); `s < 0`: smiles stay closed, pushing the lower lip up (`mouthShrugLower` at `0.5·|s|·smile`) |
//!
//! Gains never go below zero, so codes beyond the range stay valid (weights ≥ 0 where the
//! code's are). Each identity of the rig has its own default style ([`identity_style`]); the
//! template (neutral) face has the zero style, under which weights pass through unchanged.

use serde::{Deserialize, Serialize};

use super::expression::ExpressionCode;

/// The 4-d style code (module doc).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StyleCode(pub [f64; StyleCode::LEN]);

impl StyleCode {
    pub const LEN: usize = 4;
    pub const NAMES: [&'static str; StyleCode::LEN] = ["intensity", "asymmetry", "jaw", "dimple"];
    /// The range a style slider covers; codes beyond it are valid, just stronger.
    pub const RANGE: (f64, f64) = (-1.0, 1.0);
    /// The template face's style: expression weights pass through unchanged.
    pub const NEUTRAL: StyleCode = StyleCode([0.0; StyleCode::LEN]);

    /// Weights on rig shapes (by name) for an expression performed in this style, zeros left
    /// out, in a fixed order.
    pub fn shape_weights(&self, expression: &ExpressionCode) -> Vec<(&'static str, f64)> {
        let [intensity, asymmetry, jaw, dimple] = self.0;
        let gain = |g: f64| g.max(0.0);
        let mut out: Vec<(&'static str, f64)> = expression
            .iter()
            .map(|(name, w)| {
                let side = if name.ends_with("_L") {
                    1.0
                } else if name.ends_with("_R") {
                    -1.0
                } else {
                    0.0
                };
                let base = if name.starts_with("jaw") {
                    gain(1.0 + 0.3 * jaw)
                } else {
                    gain(1.0 + 0.35 * intensity)
                };
                (name, w * base * gain(1.0 + 0.35 * asymmetry * side))
            })
            .collect();
        let weight = |out: &[(&str, f64)], name: &str| {
            out.iter().find(|(n, _)| *n == name).map_or(0.0, |p| p.1)
        };
        let jaw_open = weight(&out, "jawOpen").max(0.0);
        let mut extra: Vec<(&'static str, f64)> = Vec::new();
        if jaw > 0.0 {
            extra.push(("mouthLowerDown_L", 0.5 * jaw * jaw_open));
            extra.push(("mouthLowerDown_R", 0.5 * jaw * jaw_open));
        }
        for side in ["_L", "_R"] {
            let smile = weight(&out, &format!("mouthSmile{side}")).max(0.0);
            let (dimple_name, up_name, shrug_name) = match side {
                "_L" => ("mouthDimple_L", "mouthUpperUp_L", "mouthShrugLower"),
                _ => ("mouthDimple_R", "mouthUpperUp_R", "mouthShrugLower"),
            };
            if dimple > 0.0 {
                extra.push((dimple_name, 0.6 * dimple * smile));
                extra.push((up_name, 0.3 * dimple * smile));
            } else if dimple < 0.0 {
                // One shrug shape for both sides: each side's smile contributes half.
                extra.push((shrug_name, 0.25 * -dimple * smile));
            }
        }
        for (name, w) in extra {
            match out.iter_mut().find(|(n, _)| *n == name) {
                Some(slot) => slot.1 += w,
                None => out.push((name, w)),
            }
        }
        out.retain(|(_, w)| *w != 0.0);
        out
    }

    pub fn is_finite(&self) -> bool {
        self.0.iter().all(|v| v.is_finite())
    }
}

/// The shapes a style may add beyond the expression code's 19.
pub const STYLE_SHAPES: [&str; 5] = [
    "mouthLowerDown_L",
    "mouthLowerDown_R",
    "mouthDimple_L",
    "mouthDimple_R",
    "mouthShrugLower",
];

/// The default style of the rig's identity `i` (`None`: the template face, zero style).
///
/// Chosen to be far apart (every pair differs by ≥ 0.8 in some entry) and to use both signs of
/// every entry, so styles are told apart and transfer visibly. Identities beyond the
/// table (rigs with more than ten) cycle through it with the signs flipped.
pub fn identity_style(identity: Option<usize>) -> StyleCode {
    const TABLE: [[f64; 4]; 10] = [
        [-0.7, 0.8, 0.8, 0.7],
        [0.4, -0.2, 0.6, -0.2],
        [0.2, 0.7, 0.6, 0.9],
        [-0.8, -0.3, -0.6, 0.6],
        [0.8, 0.6, -0.9, 0.9],
        [0.0, -0.5, -0.8, -0.3],
        [0.8, 0.8, 0.6, -0.9],
        [0.5, -0.2, 0.5, 0.6],
        [-0.6, 0.8, -0.2, -0.9],
        [0.3, 0.4, -0.7, -0.7],
    ];
    match identity {
        None => StyleCode::NEUTRAL,
        Some(i) => {
            let sign = if (i / TABLE.len()).is_multiple_of(2) {
                1.0
            } else {
                -1.0
            };
            StyleCode(TABLE[i % TABLE.len()].map(|v| sign * v))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::expression::is_known_shape;

    fn code(pairs: &[(&str, f64)]) -> ExpressionCode {
        let mut c = ExpressionCode::NEUTRAL;
        for (n, w) in pairs {
            c.0[ExpressionCode::index_of(n).unwrap()] = *w;
        }
        c
    }

    #[test]
    fn neutral_style_passes_weights_through() {
        let c = code(&[
            ("jawOpen", 0.7),
            ("mouthSmile_L", 0.4),
            ("mouthPucker", 1.0),
        ]);
        let w = StyleCode::NEUTRAL.shape_weights(&c);
        assert_eq!(
            w,
            vec![
                ("jawOpen", 0.7),
                ("mouthSmile_L", 0.4),
                ("mouthPucker", 1.0)
            ]
        );
        assert!(
            StyleCode::NEUTRAL
                .shape_weights(&ExpressionCode::NEUTRAL)
                .is_empty()
        );
    }

    #[test]
    fn each_entry_does_what_the_table_says() {
        let c = code(&[
            ("jawOpen", 1.0),
            ("mouthSmile_L", 1.0),
            ("mouthSmile_R", 1.0),
        ]);
        let get = |s: StyleCode, name: &str| {
            s.shape_weights(&c)
                .iter()
                .find(|(n, _)| *n == name)
                .map_or(0.0, |p| p.1)
        };
        let s = |v: [f64; 4]| StyleCode(v);
        assert!((get(s([1.0, 0.0, 0.0, 0.0]), "mouthSmile_L") - 1.35).abs() < 1e-12);
        assert!((get(s([1.0, 0.0, 0.0, 0.0]), "jawOpen") - 1.0).abs() < 1e-12);
        assert!(get(s([0.0, 1.0, 0.0, 0.0]), "mouthSmile_L") > 1.3);
        assert!(get(s([0.0, 1.0, 0.0, 0.0]), "mouthSmile_R") < 0.7);
        assert!((get(s([0.0, 0.0, 1.0, 0.0]), "jawOpen") - 1.3).abs() < 1e-12);
        assert!(get(s([0.0, 0.0, 1.0, 0.0]), "mouthLowerDown_L") > 0.6);
        assert!(get(s([0.0, 0.0, 0.0, 1.0]), "mouthDimple_R") > 0.5);
        assert!(get(s([0.0, 0.0, 0.0, -1.0]), "mouthShrugLower") > 0.4);
        assert_eq!(get(s([0.0, 0.0, 0.0, -1.0]), "mouthDimple_R"), 0.0);
    }

    #[test]
    fn styles_beyond_range_keep_weights_non_negative_and_finite() {
        let c = code(&[
            ("jawOpen", 1.0),
            ("mouthSmile_L", 1.0),
            ("mouthFrown_R", 1.0),
        ]);
        for v in [-3.0, -1.0, 1.0, 3.0] {
            for k in 0..StyleCode::LEN {
                let mut s = StyleCode::NEUTRAL;
                s.0[k] = v;
                for (name, w) in s.shape_weights(&c) {
                    assert!(is_known_shape(name), "{name}");
                    assert!(w.is_finite() && w >= 0.0, "{name} {w} at style {k}={v}");
                }
            }
        }
    }

    #[test]
    fn identity_styles_are_distinct_and_in_range() {
        let styles: Vec<StyleCode> = (0..10).map(|i| identity_style(Some(i))).collect();
        for (i, a) in styles.iter().enumerate() {
            assert!(a.0.iter().all(|v| (-1.0..=1.0).contains(v)));
            for b in &styles[i + 1..] {
                let gap =
                    a.0.iter()
                        .zip(&b.0)
                        .map(|(x, y)| (x - y).abs())
                        .fold(0.0, f64::max);
                assert!(gap >= 0.8, "{a:?} vs {b:?}");
            }
        }
        assert_eq!(identity_style(None), StyleCode::NEUTRAL);
        for name in STYLE_SHAPES {
            assert!(is_known_shape(name));
        }
    }
}
