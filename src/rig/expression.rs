//! Expression shape names and the default 19-d expression code (SPEC.md §3).

use serde::{Deserialize, Serialize};

/// The rig's 53 expression shapes: Apple ARKit's blendshapes as ICT-FaceKit names them
/// (`Left`/`Right` written `_L`/`_R`; `browInnerUp` and `cheekPuff` split into sides; no
/// `tongueOut`). A shape named in `vertex_indices.json` must be one of these.
pub const SHAPE_NAMES: [&str; 53] = [
    "browDown_L",
    "browDown_R",
    "browInnerUp_L",
    "browInnerUp_R",
    "browOuterUp_L",
    "browOuterUp_R",
    "cheekPuff_L",
    "cheekPuff_R",
    "cheekSquint_L",
    "cheekSquint_R",
    "eyeBlink_L",
    "eyeBlink_R",
    "eyeLookDown_L",
    "eyeLookDown_R",
    "eyeLookIn_L",
    "eyeLookIn_R",
    "eyeLookOut_L",
    "eyeLookOut_R",
    "eyeLookUp_L",
    "eyeLookUp_R",
    "eyeSquint_L",
    "eyeSquint_R",
    "eyeWide_L",
    "eyeWide_R",
    "jawForward",
    "jawLeft",
    "jawOpen",
    "jawRight",
    "mouthClose",
    "mouthDimple_L",
    "mouthDimple_R",
    "mouthFrown_L",
    "mouthFrown_R",
    "mouthFunnel",
    "mouthLeft",
    "mouthLowerDown_L",
    "mouthLowerDown_R",
    "mouthPress_L",
    "mouthPress_R",
    "mouthPucker",
    "mouthRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthSmile_L",
    "mouthSmile_R",
    "mouthStretch_L",
    "mouthStretch_R",
    "mouthUpperUp_L",
    "mouthUpperUp_R",
    "noseSneer_L",
    "noseSneer_R",
];

/// Whether `name` is one of [`SHAPE_NAMES`].
pub fn is_known_shape(name: &str) -> bool {
    SHAPE_NAMES.contains(&name)
}

/// The default expression code: weights of 19 lower-face shapes, in this order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ExpressionCode(pub [f64; ExpressionCode::LEN]);

impl ExpressionCode {
    pub const LEN: usize = 19;

    /// The shapes the code's entries weight (SPEC.md §3), in order.
    pub const NAMES: [&'static str; ExpressionCode::LEN] = [
        "jawOpen",
        "jawLeft",
        "jawRight",
        "jawForward",
        "mouthClose",
        "mouthSmile_L",
        "mouthSmile_R",
        "mouthFrown_L",
        "mouthFrown_R",
        "mouthPucker",
        "mouthFunnel",
        "mouthStretch_L",
        "mouthStretch_R",
        "mouthRollLower",
        "mouthRollUpper",
        "mouthPress_L",
        "mouthPress_R",
        "mouthUpperUp_L",
        "mouthUpperUp_R",
    ];

    /// The sliders grouped by the part of the face they move, as the editors show them.
    pub const GROUPS: [(&'static str, &'static [&'static str]); 4] = [
        ("Jaw", &["jawOpen", "jawLeft", "jawRight", "jawForward"]),
        (
            "Lips",
            &[
                "mouthClose",
                "mouthPucker",
                "mouthFunnel",
                "mouthRollLower",
                "mouthRollUpper",
                "mouthPress_L",
                "mouthPress_R",
            ],
        ),
        (
            "Mouth corners",
            &[
                "mouthSmile_L",
                "mouthSmile_R",
                "mouthFrown_L",
                "mouthFrown_R",
                "mouthStretch_L",
                "mouthStretch_R",
            ],
        ),
        ("Upper lip", &["mouthUpperUp_L", "mouthUpperUp_R"]),
    ];

    /// The neutral expression (all weights 0).
    pub const NEUTRAL: ExpressionCode = ExpressionCode([0.0; ExpressionCode::LEN]);

    /// Position of `name` in [`Self::NAMES`].
    pub fn index_of(name: &str) -> Option<usize> {
        Self::NAMES.iter().position(|n| *n == name)
    }

    /// A code with one named weight set; `None` for a name not in the code.
    pub fn single(name: &str, weight: f64) -> Option<Self> {
        let mut c = Self::NEUTRAL;
        c.0[Self::index_of(name)?] = weight;
        Some(c)
    }

    /// The weight of `name`; `None` for a name not in the code.
    pub fn get(&self, name: &str) -> Option<f64> {
        Self::index_of(name).map(|i| self.0[i])
    }

    /// `(name, weight)` pairs in code order.
    pub fn iter(&self) -> impl Iterator<Item = (&'static str, f64)> + '_ {
        Self::NAMES.iter().copied().zip(self.0.iter().copied())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_code_names_are_known_distinct_shapes() {
        for (i, n) in ExpressionCode::NAMES.iter().enumerate() {
            assert!(is_known_shape(n), "{n}");
            assert_eq!(ExpressionCode::index_of(n), Some(i));
        }
        let mut sorted = SHAPE_NAMES.to_vec();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), SHAPE_NAMES.len());
        assert!(!is_known_shape("tongueOut"));
    }

    #[test]
    fn the_groups_hold_every_slider_once() {
        let mut grouped: Vec<&str> = ExpressionCode::GROUPS
            .iter()
            .flat_map(|(_, names)| names.iter().copied())
            .collect();
        grouped.sort_unstable();
        let mut names = ExpressionCode::NAMES.to_vec();
        names.sort_unstable();
        assert_eq!(grouped, names);
    }

    #[test]
    fn single_and_get() {
        let c = ExpressionCode::single("mouthPucker", 0.7).unwrap();
        assert_eq!(c.get("mouthPucker"), Some(0.7));
        assert_eq!(c.0[9], 0.7);
        assert_eq!(c.iter().filter(|(_, w)| *w != 0.0).count(), 1);
        assert!(ExpressionCode::single("eyeBlink_L", 1.0).is_none());
        assert_eq!(c.get("eyeBlink_L"), None);
    }
}
