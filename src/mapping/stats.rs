//! Mapping-function statistics (the paper's Fig. 3): per identity, the distributions of
//! det ∂φ/∂x and σmax/σmin over random interior points (as many as the elastic regularizer
//! uses: vertices + elements), and of the surface vertex error over the correspondences; and
//! the same quantities per render vertex, for colouring the skin.

use nalgebra::{Matrix3, Point3};
use serde::{Deserialize, Serialize};

use super::MappingError;
use super::network::Mapping;
use super::samples::{Correspondences, canonical_positions_by_rig_vertex, volume_points};
use super::train::MM_PER_CM;
use super::warp::quantile;
use crate::model::FaceModel;

/// What a heatmap shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum HeatmapKind {
    /// det ∂φ/∂x (1: volume preserved).
    Determinant,
    /// σmax/σmin of ∂φ/∂x (1: conformal).
    Condition,
    /// ‖φ(x) − X‖ to the corresponding canonical vertex, mm.
    VertexError,
}

impl HeatmapKind {
    pub const ALL: [HeatmapKind; 3] = [
        HeatmapKind::Determinant,
        HeatmapKind::Condition,
        HeatmapKind::VertexError,
    ];

    pub fn name(self) -> &'static str {
        match self {
            HeatmapKind::Determinant => "det",
            HeatmapKind::Condition => "condition",
            HeatmapKind::VertexError => "vertex_error_mm",
        }
    }

    /// The value of one Jacobian (not defined for the vertex error).
    fn of_jacobian(self, j: &Matrix3<f64>) -> f64 {
        match self {
            HeatmapKind::Determinant => j.determinant(),
            _ => condition(j),
        }
    }
}

/// σmax/σmin of a 3×3 matrix (∞ for a singular one).
pub fn condition(j: &Matrix3<f64>) -> f64 {
    let s = j.singular_values();
    s.max() / s.min()
}

/// The sampled distributions of one identity.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IdentityStats {
    pub name: String,
    pub det: Vec<f64>,
    pub condition: Vec<f64>,
    pub vertex_error_mm: Vec<f64>,
}

/// The figures the README reports per identity.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub name: String,
    pub interior_points: usize,
    pub surface_points: usize,
    pub det_min: f64,
    pub det_median: f64,
    pub det_max: f64,
    pub condition_median: f64,
    pub condition_p95: f64,
    pub vertex_error_mean_mm: f64,
    pub vertex_error_max_mm: f64,
}

impl IdentityStats {
    /// Samples φ of `face` (trained against `canonical`): N_e = vertices + elements interior
    /// points uniform by volume (from `seed`), and every surface correspondence.
    pub fn sample(
        face: &FaceModel,
        canonical: &FaceModel,
        mapping: &Mapping,
        seed: u64,
    ) -> Result<Self, MappingError> {
        mapping.check_face(face)?;
        let n = face.mesh.vertex_count() + face.mesh.element_count();
        let mapped = mapping.evaluate(&volume_points(&face.mesh, n, seed))?;
        let pairs = Correspondences::between(face, canonical)?;
        let on_surface = mapping.evaluate(&pairs.material)?;
        Ok(IdentityStats {
            name: face.name.clone(),
            det: mapped.iter().map(|m| m.jacobian.determinant()).collect(),
            condition: mapped.iter().map(|m| condition(&m.jacobian)).collect(),
            vertex_error_mm: on_surface
                .iter()
                .zip(&pairs.canonical)
                .map(|(m, t)| (m.canonical - t).norm() * MM_PER_CM)
                .collect(),
        })
    }

    pub fn values(&self, kind: HeatmapKind) -> &[f64] {
        match kind {
            HeatmapKind::Determinant => &self.det,
            HeatmapKind::Condition => &self.condition,
            HeatmapKind::VertexError => &self.vertex_error_mm,
        }
    }

    pub fn summary(&self) -> Summary {
        let e = &self.vertex_error_mm;
        Summary {
            name: self.name.clone(),
            interior_points: self.det.len(),
            surface_points: e.len(),
            det_min: quantile(&self.det, 0.0),
            det_median: quantile(&self.det, 0.5),
            det_max: quantile(&self.det, 1.0),
            condition_median: quantile(&self.condition, 0.5),
            condition_p95: quantile(&self.condition, 0.95),
            vertex_error_mean_mm: e.iter().sum::<f64>() / e.len().max(1) as f64,
            vertex_error_max_mm: quantile(e, 1.0),
        }
    }
}

/// Per render vertex of `face`, the heatmap value at its rest position (φ is evaluated at
/// every render vertex; for teeth and the deep mouth, which lie outside the tissue, that is
/// φ's smooth extension). The vertex error compares with the canonical face's rest position
/// of the same rig vertex.
pub fn vertex_values(
    face: &FaceModel,
    canonical: &FaceModel,
    mapping: &Mapping,
    kind: HeatmapKind,
) -> Result<Vec<f64>, MappingError> {
    mapping.check_face(face)?;
    let mapped = mapping.evaluate(&face.render.rest)?;
    match kind {
        HeatmapKind::VertexError => {
            let by_rig = canonical_positions_by_rig_vertex(face, canonical)?;
            face.render
                .rig_vertices
                .iter()
                .zip(&mapped)
                .map(|(&rig, m)| {
                    let (_, target): (bool, Point3<f64>) =
                        by_rig[rig as usize].ok_or(MappingError::NoCounterpart(rig))?;
                    Ok((m.canonical - target).norm() * MM_PER_CM)
                })
                .collect()
        }
        _ => Ok(mapped
            .iter()
            .map(|m| kind.of_jacobian(&m.jacobian))
            .collect()),
    }
}

/// Shares of `values` in `bins` equal bins over [lo, hi]; values outside go to the end bins.
pub fn histogram(values: &[f64], lo: f64, hi: f64, bins: usize) -> Vec<f64> {
    let mut counts = vec![0.0; bins];
    for &v in values {
        let t = ((v - lo) / (hi - lo) * bins as f64).floor();
        let b = if t.is_nan() {
            0
        } else {
            t.clamp(0.0, (bins - 1) as f64) as usize
        };
        counts[b] += 1.0;
    }
    let n = values.len().max(1) as f64;
    counts.iter().map(|c| c / n).collect()
}

/// A heatmap's bins.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BinRange {
    pub lo: f64,
    pub hi: f64,
    pub bins: usize,
}

impl BinRange {
    /// The ranges of the README's figure.
    pub fn default_for(kind: HeatmapKind) -> Self {
        match kind {
            HeatmapKind::Determinant => BinRange {
                lo: 0.7,
                hi: 1.3,
                bins: 40,
            },
            HeatmapKind::Condition => BinRange {
                lo: 1.0,
                hi: 1.6,
                bins: 40,
            },
            HeatmapKind::VertexError => BinRange {
                lo: 0.0,
                hi: 2.0,
                bins: 40,
            },
        }
    }
}

/// The heatmap table as CSV: one row per identity and bin (`identity,bin_lo,bin_hi,share`).
pub fn heatmap_csv(stats: &[IdentityStats], kind: HeatmapKind, range: &BinRange) -> String {
    let mut s = String::from("identity,bin_lo,bin_hi,share\n");
    let w = (range.hi - range.lo) / range.bins as f64;
    for st in stats {
        for (b, share) in histogram(st.values(kind), range.lo, range.hi, range.bins)
            .iter()
            .enumerate()
        {
            s.push_str(&format!(
                "{},{},{},{:.6}\n",
                st.name,
                range.lo + w * b as f64,
                range.lo + w * (b + 1) as f64,
                share
            ));
        }
    }
    s
}

/// The per-identity summary table as CSV.
pub fn summary_csv(summaries: &[Summary]) -> String {
    let mut s = String::from(
        "identity,interior_points,surface_points,det_min,det_median,det_max,condition_median,condition_p95,vertex_error_mean_mm,vertex_error_max_mm\n",
    );
    for m in summaries {
        s.push_str(&format!(
            "{},{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}\n",
            m.name,
            m.interior_points,
            m.surface_points,
            m.det_min,
            m.det_median,
            m.det_max,
            m.condition_median,
            m.condition_p95,
            m.vertex_error_mean_mm,
            m.vertex_error_max_mm
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_shares_sum_to_one_and_clamp_to_the_end_bins() {
        let h = histogram(&[-5.0, 0.05, 0.15, 0.15, 0.99, 7.0], 0.0, 1.0, 10);
        assert!((h.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert_eq!(h[0], 2.0 / 6.0);
        assert_eq!(h[1], 2.0 / 6.0);
        assert_eq!(h[9], 2.0 / 6.0);
    }

    #[test]
    fn condition_is_the_singular_value_ratio() {
        let j = Matrix3::from_diagonal(&nalgebra::Vector3::new(2.0, 0.5, 1.0));
        let r = nalgebra::Rotation3::from_euler_angles(0.3, -0.2, 0.9).into_inner();
        assert!((condition(&(r * j)) - 4.0).abs() < 1e-12);
        assert!((HeatmapKind::Determinant.of_jacobian(&(r * j)) - 1.0).abs() < 1e-12);
    }
}
