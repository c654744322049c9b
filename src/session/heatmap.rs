//! Heatmaps: named scalar fields over the render vertices, each with the legend that maps
//! values to colours.
//!
//! A [`FieldSource`] computes one field from a solved frame. The session ships the fields it
//! can compute from the simulation alone (displacement from rest, volume ratio det F); the
//! mapping φ's fields (det ∂φ/∂x, σmax/σmin, vertex error) plug in as further sources
//! through [`crate::session::Session::with_field_sources`] without the UI changing.

use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::model::FaceModel;

/// How values map to colours.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Legend {
    /// Values at the ends of the colour ramp (clamped outside).
    pub min: f32,
    pub max: f32,
    /// `Some(c)`: a diverging ramp (blue below `c`, white at `c`, red above), for ratios
    /// around 1; `None`: a sequential ramp (dark → bright).
    pub center: Option<f32>,
}

impl Legend {
    /// sRGB colour of `value`.
    pub fn color(&self, value: f32) -> [u8; 3] {
        let value = if value.is_nan() { self.min } else { value };
        let span = (self.max - self.min).max(f32::MIN_POSITIVE);
        match self.center {
            Some(c) => {
                let t = if value >= c {
                    ((value - c) / (self.max - c).max(f32::MIN_POSITIVE)).clamp(0.0, 1.0)
                } else {
                    -((c - value) / (c - self.min).max(f32::MIN_POSITIVE)).clamp(0.0, 1.0)
                };
                let w = 1.0 - t.abs();
                let (r, g, b) = if t >= 0.0 { (1.0, w, w) } else { (w, w, 1.0) };
                [(r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8]
            }
            None => {
                let t = ((value - self.min) / span).clamp(0.0, 1.0);
                // A compact viridis-like ramp: purple → teal → yellow.
                let stops = [
                    [68.0, 1.0, 84.0],
                    [33.0, 145.0, 140.0],
                    [253.0, 231.0, 37.0],
                ];
                let s = t * 2.0;
                let i = (s.floor() as usize).min(1);
                let f = s - i as f32;
                let mix = |k: usize| stops[i][k] + (stops[i + 1][k] - stops[i][k]) * f;
                [mix(0) as u8, mix(1) as u8, mix(2) as u8]
            }
        }
    }
}

/// One heatmap: a value per render vertex.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ScalarField {
    pub name: String,
    pub unit: String,
    pub values: Vec<f32>,
    pub legend: Legend,
}

impl ScalarField {
    /// Vertex colours under the field's legend.
    pub fn colors(&self) -> Vec<[u8; 3]> {
        self.values.iter().map(|v| self.legend.color(*v)).collect()
    }
}

/// What a field source sees of a solved frame.
pub struct FieldInput<'a> {
    pub model: &'a FaceModel,
    /// Render-surface positions of this frame.
    pub positions: &'a [Point3<f64>],
    /// Simulation-mesh positions, interleaved.
    pub mesh_x: &'a [f64],
    /// Per element: deformed over rest volume (det F).
    pub volume_ratio: &'a [f64],
}

/// A computable heatmap (module doc).
pub trait FieldSource: Send + Sync {
    fn name(&self) -> &str;
    fn compute(&self, input: &FieldInput<'_>) -> ScalarField;
}

/// Distance of each render vertex from its rest position, cm.
pub struct Displacement;

impl FieldSource for Displacement {
    fn name(&self) -> &str {
        "displacement"
    }
    fn compute(&self, input: &FieldInput<'_>) -> ScalarField {
        let values: Vec<f32> = input
            .positions
            .iter()
            .zip(&input.model.render.rest)
            .map(|(p, r)| (p - r).norm() as f32)
            .collect();
        let max = values.iter().copied().fold(0.0f32, f32::max).max(1e-3);
        ScalarField {
            name: self.name().into(),
            unit: "cm".into(),
            values,
            legend: Legend {
                min: 0.0,
                max,
                center: None,
            },
        }
    }
}

/// det F of the element each render vertex is embedded in (1 for bone-bound vertices, blended
/// toward 1 by the bone's share for skin blended onto the skull): where the tissue is
/// compressed (< 1) or stretched (> 1).
pub struct VolumeRatio;

impl FieldSource for VolumeRatio {
    fn name(&self) -> &str {
        "volume ratio det F"
    }
    fn compute(&self, input: &FieldInput<'_>) -> ScalarField {
        let values: Vec<f32> = input
            .model
            .render
            .bindings
            .iter()
            .map(|b| match b.element() {
                Some(e) => {
                    let s = b.embedded_share();
                    (s * input.volume_ratio[e as usize] + (1.0 - s)) as f32
                }
                None => 1.0,
            })
            .collect();
        let dev = values
            .iter()
            .map(|v| (v - 1.0).abs())
            .fold(0.0f32, f32::max)
            .max(0.01);
        ScalarField {
            name: self.name().into(),
            unit: "".into(),
            values,
            legend: Legend {
                min: 1.0 - dev,
                max: 1.0 + dev,
                center: Some(1.0),
            },
        }
    }
}

/// A field that does not change with the frame: one value per render vertex of each face,
/// computed once (φ's statistics at the rest shape). A face it has no values for gets
/// `fallback` everywhere (the canonical face's φ is the identity: det 1, no error).
pub struct PerFaceField {
    pub name: String,
    pub unit: String,
    pub legend: Legend,
    pub fallback: f32,
    pub values: std::collections::HashMap<String, Vec<f32>>,
}

impl FieldSource for PerFaceField {
    fn name(&self) -> &str {
        &self.name
    }
    fn compute(&self, input: &FieldInput<'_>) -> ScalarField {
        let n = input.positions.len();
        let values = match self.values.get(&input.model.name) {
            Some(v) if v.len() == n => v.clone(),
            _ => vec![self.fallback; n],
        };
        ScalarField {
            name: self.name.clone(),
            unit: self.unit.clone(),
            values,
            legend: self.legend,
        }
    }
}

/// The sources every session computes.
pub fn builtin_sources() -> Vec<Box<dyn FieldSource>> {
    vec![Box::new(Displacement), Box::new(VolumeRatio)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diverging_legend_is_white_at_center_and_saturates() {
        let l = Legend {
            min: 0.5,
            max: 1.5,
            center: Some(1.0),
        };
        assert_eq!(l.color(1.0), [255, 255, 255]);
        assert_eq!(l.color(2.0), [255, 0, 0]);
        assert_eq!(l.color(0.0), [0, 0, 255]);
    }

    #[test]
    fn sequential_legend_runs_from_dark_to_bright() {
        let l = Legend {
            min: 0.0,
            max: 1.0,
            center: None,
        };
        assert_eq!(l.color(0.0), [68, 1, 84]);
        assert_eq!(l.color(1.0), [253, 231, 37]);
        assert_eq!(l.color(f32::NAN), l.color(0.0), "NaN shows as the minimum");
    }
}
