//! The rig's named geometry pieces as typed vertex and face index ranges (ICT-FaceKit's table,
//! `data/ict-facekit/README.md`), and the check that a mesh agrees with the table.
//!
//! The pieces share boundary vertices with the face skin: head/neck, mouth-socket and
//! eye-socket faces use skin vertices along their seams. Every other face references only its
//! own piece's vertices.

use std::ops::Range;

use super::obj::Polygons;

/// A named piece of the ICT face rig.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Region {
    /// The face skin (front of the head).
    FaceSkin,
    HeadAndNeck,
    /// Inner lips and cheeks (continues the skin inwards at the lips).
    MouthSocket,
    EyeSocketLeft,
    EyeSocketRight,
    GumsAndTongue,
    UpperTeeth,
    LowerTeeth,
    /// Eyeballs, lacrimal fluid, eye blend and occlusion shells, eyelashes.
    Eyes,
}

impl Region {
    pub const ALL: [Region; 9] = [
        Region::FaceSkin,
        Region::HeadAndNeck,
        Region::MouthSocket,
        Region::EyeSocketLeft,
        Region::EyeSocketRight,
        Region::GumsAndTongue,
        Region::UpperTeeth,
        Region::LowerTeeth,
        Region::Eyes,
    ];

    /// Number of vertices of the full rig mesh.
    pub const VERTEX_COUNT: usize = 26_719;
    /// Number of faces of the full rig mesh.
    pub const FACE_COUNT: usize = 26_384;

    pub fn name(self) -> &'static str {
        match self {
            Region::FaceSkin => "face skin",
            Region::HeadAndNeck => "head and neck",
            Region::MouthSocket => "mouth socket",
            Region::EyeSocketLeft => "left eye socket",
            Region::EyeSocketRight => "right eye socket",
            Region::GumsAndTongue => "gums and tongue",
            Region::UpperTeeth => "upper teeth",
            Region::LowerTeeth => "lower teeth",
            Region::Eyes => "eyes",
        }
    }

    /// The region's own vertices (0-based, half-open).
    pub fn vertices(self) -> Range<usize> {
        let (a, b) = match self {
            Region::FaceSkin => (0, 9408),
            Region::HeadAndNeck => (9409, 11247),
            Region::MouthSocket => (11248, 13293),
            Region::EyeSocketLeft => (13294, 13677),
            Region::EyeSocketRight => (13678, 14061),
            Region::GumsAndTongue => (14062, 17038),
            Region::UpperTeeth => (17039, 19246),
            Region::LowerTeeth => (19247, 21450),
            Region::Eyes => (21451, 26718),
        };
        a..b + 1
    }

    /// The region's faces (0-based, half-open). The README gives the teeth's faces as one
    /// range (17006–21495); the split between upper (17006–19249) and lower (19250–21495) is
    /// measured on the data and checked by [`check_regions`].
    pub fn faces(self) -> Range<usize> {
        let (a, b) = match self {
            Region::FaceSkin => (0, 9229),
            Region::HeadAndNeck => (9230, 11143),
            Region::MouthSocket => (11144, 13225),
            Region::EyeSocketLeft => (13226, 13629),
            Region::EyeSocketRight => (13630, 14033),
            Region::GumsAndTongue => (14034, 17005),
            Region::UpperTeeth => (17006, 19249),
            Region::LowerTeeth => (19250, 21495),
            Region::Eyes => (21496, 26383),
        };
        a..b + 1
    }

    /// Whether this region's faces may use face-skin vertices along a seam.
    pub fn shares_skin_seam(self) -> bool {
        matches!(
            self,
            Region::HeadAndNeck
                | Region::MouthSocket
                | Region::EyeSocketLeft
                | Region::EyeSocketRight
        )
    }

    /// The region that owns vertex `v`, if any.
    pub fn of_vertex(v: usize) -> Option<Region> {
        Region::ALL.into_iter().find(|r| r.vertices().contains(&v))
    }
}

/// How a mesh disagrees with the region table.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RegionMismatch {
    #[error("the mesh has {found} {what}, the region table expects {expected}")]
    Count {
        what: &'static str,
        found: usize,
        expected: usize,
    },
    #[error("face {face} of the {region} uses vertex {vertex}, which is outside it")]
    ForeignVertex {
        region: &'static str,
        face: usize,
        vertex: usize,
    },
    #[error("face {face} of the {region} has no vertex of its own")]
    NoOwnVertex { region: &'static str, face: usize },
    #[error("vertex {vertex} of the {region} is used by none of its faces")]
    UnusedVertex { region: &'static str, vertex: usize },
}

/// Checks that `faces` (over `vertex_count` vertices) matches the region table: the counts,
/// every face of a region touches one of the region's own vertices and otherwise only
/// vertices of its own region (or skin-seam vertices for the regions that have a seam), and
/// every vertex of a region is used by one of its faces.
pub fn check_regions(vertex_count: usize, faces: &Polygons) -> Result<(), RegionMismatch> {
    if vertex_count != Region::VERTEX_COUNT {
        return Err(RegionMismatch::Count {
            what: "vertices",
            found: vertex_count,
            expected: Region::VERTEX_COUNT,
        });
    }
    if faces.len() != Region::FACE_COUNT {
        return Err(RegionMismatch::Count {
            what: "faces",
            found: faces.len(),
            expected: Region::FACE_COUNT,
        });
    }
    let skin = Region::FaceSkin.vertices();
    for region in Region::ALL {
        let own = region.vertices();
        let mut used = vec![false; own.len()];
        for f in region.faces() {
            let mut has_own = false;
            for &v in faces.get(f) {
                let v = v as usize;
                if own.contains(&v) {
                    has_own = true;
                    used[v - own.start] = true;
                } else if !(region.shares_skin_seam() && skin.contains(&v)) {
                    return Err(RegionMismatch::ForeignVertex {
                        region: region.name(),
                        face: f,
                        vertex: v,
                    });
                }
            }
            if !has_own {
                return Err(RegionMismatch::NoOwnVertex {
                    region: region.name(),
                    face: f,
                });
            }
        }
        if let Some(i) = used.iter().position(|&u| !u) {
            return Err(RegionMismatch::UnusedVertex {
                region: region.name(),
                vertex: own.start + i,
            });
        }
    }
    Ok(())
}

/// The lip line: the face-skin vertices that mouth-socket faces share (the inner edge of the
/// lips, where the skin turns into the mouth), sorted rig indices.
pub fn lip_line(faces: &Polygons) -> Vec<usize> {
    let socket = Region::MouthSocket.vertices();
    let mut line: Vec<usize> = faces
        .iter()
        .filter(|f| f.iter().any(|&v| socket.contains(&(v as usize))))
        .flat_map(|f| f.iter().map(|&v| v as usize))
        .filter(|&v| Region::of_vertex(v) == Some(Region::FaceSkin))
        .collect();
    line.sort_unstable();
    line.dedup();
    line
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_tile_the_mesh_without_gaps_or_overlaps() {
        let mut v = 0;
        let mut f = 0;
        for r in Region::ALL {
            assert_eq!(r.vertices().start, v, "{r:?}");
            assert_eq!(r.faces().start, f, "{r:?}");
            v = r.vertices().end;
            f = r.faces().end;
        }
        assert_eq!(v, Region::VERTEX_COUNT);
        assert_eq!(f, Region::FACE_COUNT);
        assert_eq!(Region::of_vertex(19_247), Some(Region::LowerTeeth));
        assert_eq!(Region::of_vertex(19_246), Some(Region::UpperTeeth));
        assert_eq!(Region::of_vertex(Region::VERTEX_COUNT), None);
    }

    #[test]
    fn rig_neutral_matches_the_table() {
        let rig = crate::rig::test_support::rig();
        check_regions(rig.neutral().len(), rig.faces()).unwrap();
    }

    #[test]
    fn a_face_crossing_regions_is_reported() {
        let rig = crate::rig::test_support::rig();
        let mut lists: Vec<Vec<u32>> = rig.faces().iter().map(|p| p.to_vec()).collect();
        // A lower-teeth face that grabs an upper-tooth vertex.
        let f = Region::LowerTeeth.faces().start + 3;
        lists[f][0] = Region::UpperTeeth.vertices().start as u32;
        let err = check_regions(Region::VERTEX_COUNT, &Polygons::from_lists(&lists)).unwrap_err();
        assert!(matches!(
            err,
            RegionMismatch::ForeignVertex { face, .. } if face == f
        ));
    }
}
