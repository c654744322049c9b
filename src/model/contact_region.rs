//! Which part of a face takes part in contact (the *contact region*), and the face's contact
//! surface built from it ([`FaceContact::new`]):
//! - the **lip line**: skin vertices that the mouth socket shares (the inner edge of the lips);
//! - **lips and inner mouth**: face-skin vertices within `lip_reach` (cm, at rest) of the lip
//!   line, and mouth-socket (lining) vertices within `lining_reach`;
//! - **teeth**: upper- and lower-teeth vertices within `teeth_reach` of those (the front teeth
//!   the lips can reach; molars stay out).
//!
//! Each contact vertex is bound to the simulation as its render vertex is.

use nalgebra::Point3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{Binding, FaceModel};
use crate::contact::ContactError;
use crate::contact::surface::{ContactBinding, FaceContact, NO_CELL, SurfaceParts};
use crate::geometry::triangles::compact_in_index_order;
use crate::rig::Region;

/// Which part of the face takes part in contact.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FaceContactSettings {
    /// Skin vertices within this distance of the lip line (cm, at rest).
    pub lip_reach: f64,
    /// Mouth-socket (lining) vertices within this distance of the lip line (cm, at rest).
    #[serde(default = "default_lining_reach")]
    pub lining_reach: f64,
    /// Teeth vertices within this distance of the soft contact vertices (cm, at rest).
    pub teeth_reach: f64,
}

impl Default for FaceContactSettings {
    fn default() -> Self {
        Self {
            lip_reach: super::bindings::TISSUE_LINING_REACH,
            lining_reach: default_lining_reach(),
            teeth_reach: 0.8,
        }
    }
}

/// The lining the lips roll and press, all of it carried by the tissue
/// ([`super::bindings::TISSUE_LINING_REACH`]). Deeper lining reaches the teeth too: a lip press
/// pushes the lining behind the lower incisors (2–3 cm from the lip line) through them, as the
/// rig's own shape does, and a smile's jaw opening carries the cheeks' inside (to 4.9 cm) through
/// the lower molars. With the lining on the gums riding on their bones
/// ([`super::bindings::ON_GUM`]), 6 cm (every tooth's lining) exports the smile crossing-free,
/// but the random sweeps' large jaw swings still fail (crossings after the solve, or more than
/// 64 stages; docs/performance/contact.md).
fn default_lining_reach() -> f64 {
    super::bindings::TISSUE_LINING_REACH
}

impl FaceContact {
    /// The contact surface of `model`'s contact region (see the module doc).
    pub fn new(model: &FaceModel, settings: &FaceContactSettings) -> Result<Self, ContactError> {
        let reaches = [settings.lip_reach, settings.lining_reach];
        let finite = reaches.iter().all(|r| r.is_finite()) && settings.teeth_reach.is_finite();
        if !(reaches.iter().all(|&r| r > 0.0) && settings.teeth_reach >= 0.0 && finite) {
            return Err(ContactError::InvalidParameter(format!(
                "contact region reaches must be finite and positive, got {settings:?}"
            )));
        }
        let render = &model.render;
        let region: Vec<Option<Region>> = render
            .rig_vertices
            .iter()
            .map(|&v| Region::of_vertex(v as usize))
            .collect();
        let is = |i: u32, r: Region| region[i as usize] == Some(r);
        // The lip line: skin vertices used by mouth-socket triangles.
        let mut lip_line = vec![false; render.rest.len()];
        for t in &render.triangles {
            if t.iter().any(|&v| is(v, Region::MouthSocket)) {
                for &v in t.iter().filter(|&&v| is(v, Region::FaceSkin)) {
                    lip_line[v as usize] = true;
                }
            }
        }
        let line_points: Vec<Point3<f64>> = (0..render.rest.len())
            .filter(|&i| lip_line[i])
            .map(|i| render.rest[i])
            .collect();
        if line_points.is_empty() {
            return Err(ContactError::InvalidMesh(
                "the render surface has no lip line (no skin vertex shared with the mouth socket)"
                    .into(),
            ));
        }
        let near = |p: &Point3<f64>, points: &[Point3<f64>], r: f64| {
            let r2 = r * r;
            points.iter().any(|q| (p - q).norm_squared() <= r2)
        };
        let soft: Vec<bool> = (0..render.rest.len())
            .into_par_iter()
            .map(|i| {
                let reach = match region[i] {
                    Some(Region::FaceSkin) => settings.lip_reach,
                    Some(Region::MouthSocket) => settings.lining_reach,
                    _ => return false,
                };
                near(&render.rest[i], &line_points, reach)
            })
            .collect();
        let soft_points: Vec<Point3<f64>> = (0..render.rest.len())
            .filter(|&i| soft[i])
            .map(|i| render.rest[i])
            .collect();
        let chosen: Vec<bool> = (0..render.rest.len())
            .into_par_iter()
            .map(|i| {
                soft[i]
                    || (matches!(region[i], Some(Region::UpperTeeth | Region::LowerTeeth))
                        && near(&render.rest[i], &soft_points, settings.teeth_reach))
            })
            .collect();
        let triangles: Vec<[u32; 3]> = render
            .triangles
            .iter()
            .filter(|t| t.iter().all(|&v| chosen[v as usize]))
            .copied()
            .collect();
        let (faces, render_vertices) = compact_in_index_order(&triangles, render.rest.len());
        let bindings: Vec<ContactBinding> = render_vertices
            .iter()
            .map(|&r| match render.bindings[r as usize] {
                Binding::Embedded { element, weights } => Ok(ContactBinding::Embedded {
                    tet: model.mesh.tets[element as usize],
                    weights,
                }),
                Binding::Rigid(bone) => Ok(ContactBinding::Rigid {
                    bone,
                    rest: render.rest[r as usize],
                }),
                Binding::Bones { jaw } => Ok(ContactBinding::Bones {
                    jaw,
                    rest: render.rest[r as usize],
                }),
                // Only skin far from the mouth, on the skull, is blended; a contact surface
                // reaching it would need an affine binding with a pose-dependent offset.
                Binding::Blended { .. } => Err(ContactError::InvalidMesh(format!(
                    "render vertex {r} of the contact region is blended between the tissue and \
                     the skull (skin outside the tissue); contact takes embedded or rigid \
                     vertices only: lower lip_reach/lining_reach/teeth_reach"
                ))),
            })
            .collect::<Result<_, _>>()?;
        let rest: Vec<f64> = render_vertices
            .iter()
            .flat_map(|&r| {
                let p = render.rest[r as usize];
                [p.x, p.y, p.z]
            })
            .collect();
        let cells: Vec<(u32, bool)> = render_vertices
            .iter()
            .map(|&r| match render.bindings[r as usize] {
                Binding::Embedded { element, weights } => {
                    (element, weights.iter().all(|&w| w >= 0.0))
                }
                _ => (NO_CELL, false),
            })
            .collect();
        let mut piece_counts = [0; 4];
        for &r in &render_vertices {
            let k = match region[r as usize] {
                Some(Region::FaceSkin) => 0,
                Some(Region::MouthSocket) => 1,
                Some(Region::UpperTeeth) => 2,
                _ => 3,
            };
            piece_counts[k] += 1;
        }
        FaceContact::from_parts(
            SurfaceParts {
                render_vertices,
                rest,
                faces,
                bindings,
                cells,
                dhat: model.d_hat,
                jaw_pivot: model.jaw_pivot,
                sim_vertex_count: model.mesh.vertex_count(),
                piece_counts,
                lip_line: line_points,
            },
            &model.mesh.tets,
        )
    }
}
