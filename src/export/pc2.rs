//! PC2 point caches (3ds Max / Maya / Blender "Point Cache 2"): a 32-byte header, then every
//! sample's points as little-endian `f32` x, y, z.
//!
//! ```text
//! char  signature[12]   "POINTCACHE2\0"
//! i32   fileVersion     1
//! i32   numPoints       points per sample
//! f32   startFrame      the first sample's frame
//! f32   sampleRate      frames between samples (1.0: one sample per frame)
//! i32   numSamples
//! f32   points[numSamples][numPoints][3]
//! ```
//!
//! The export writes one sample per frame (`startFrame = 0`, `sampleRate = 1`), so the scene
//! that plays it must run at the export's fps. The cache has no topology: the export writes
//! `NAME.obj` beside it (rest positions, normals and triangles in the same vertex order).

use std::io::Read;
use std::path::Path;

use super::{ExportError, ExportMesh, Format, FrameSink, Out, check_sizes, obj};
use crate::session::Frame;

pub const SIGNATURE: &[u8; 12] = b"POINTCACHE2\0";
pub const VERSION: i32 = 1;
pub const HEADER_BYTES: u64 = 32;

/// The header fields.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Header {
    pub points: u32,
    pub start_frame: f32,
    pub sample_rate: f32,
    pub samples: u32,
}

impl Header {
    pub fn to_bytes(&self) -> [u8; 32] {
        let mut b = [0u8; 32];
        b[..12].copy_from_slice(SIGNATURE);
        b[12..16].copy_from_slice(&VERSION.to_le_bytes());
        b[16..20].copy_from_slice(&(self.points as i32).to_le_bytes());
        b[20..24].copy_from_slice(&self.start_frame.to_le_bytes());
        b[24..28].copy_from_slice(&self.sample_rate.to_le_bytes());
        b[28..32].copy_from_slice(&(self.samples as i32).to_le_bytes());
        b
    }

    /// Parses and checks a header (signature, version, non-negative counts).
    pub fn parse(b: &[u8; 32]) -> Result<Self, String> {
        if &b[..12] != SIGNATURE {
            return Err("not a PC2 file (the signature is not 'POINTCACHE2\\0')".into());
        }
        let i32_at = |o: usize| i32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"));
        let f32_at = |o: usize| f32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"));
        if i32_at(12) != VERSION {
            return Err(format!("PC2 version {} (expected {VERSION})", i32_at(12)));
        }
        let (points, samples) = (i32_at(16), i32_at(28));
        if points < 0 || samples < 0 {
            return Err(format!(
                "negative counts: {points} points, {samples} samples"
            ));
        }
        Ok(Header {
            points: points as u32,
            start_frame: f32_at(20),
            sample_rate: f32_at(24),
            samples: samples as u32,
        })
    }

    /// The file size the header implies.
    pub fn file_bytes(&self) -> u64 {
        HEADER_BYTES + 12 * self.points as u64 * self.samples as u64
    }
}

/// One sample's points.
pub type Samples = Vec<[f32; 3]>;

/// Reads a PC2 file: its header and all samples (checks that the size matches the header).
pub fn read(path: &Path) -> Result<(Header, Vec<Samples>), String> {
    let mut f = std::fs::File::open(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut hb = [0u8; 32];
    f.read_exact(&mut hb)
        .map_err(|e| format!("reading the header: {e}"))?;
    let header = Header::parse(&hb)?;
    let len = f.metadata().map_err(|e| e.to_string())?.len();
    if len != header.file_bytes() {
        return Err(format!(
            "the file has {len} bytes, its header implies {}",
            header.file_bytes()
        ));
    }
    let mut data = Vec::new();
    f.read_to_end(&mut data).map_err(|e| e.to_string())?;
    let samples = data
        .chunks_exact(12 * header.points.max(1) as usize)
        .map(|s| {
            s.chunks_exact(12)
                .map(|p| {
                    std::array::from_fn(|c| {
                        f32::from_le_bytes(p[4 * c..4 * c + 4].try_into().expect("4 bytes"))
                    })
                })
                .collect()
        })
        .take(header.samples as usize)
        .collect();
    Ok((header, samples))
}

/// Streams frames into a PC2 file.
pub struct Pc2Writer {
    out: Out,
    points: usize,
    frames: usize,
    written: usize,
    buf: Vec<u8>,
}

impl Pc2Writer {
    /// Writes the header of a cache of `frames` samples of `points` points, the first at frame
    /// `first`.
    pub fn create(
        path: &Path,
        points: usize,
        first: usize,
        frames: usize,
    ) -> Result<Self, ExportError> {
        let too_large = |what: &str| ExportError::TooLarge {
            format: Format::Pc2,
            reason: format!("{what} does not fit the header's 32-bit count"),
        };
        let header = Header {
            points: u32::try_from(points)
                .ok()
                .filter(|&p| p <= i32::MAX as u32)
                .ok_or_else(|| too_large("the point count"))?,
            start_frame: first as f32,
            sample_rate: 1.0,
            samples: u32::try_from(frames)
                .ok()
                .filter(|&p| p <= i32::MAX as u32)
                .ok_or_else(|| too_large("the frame count"))?,
        };
        let mut out = Out::create(path)?;
        out.write_all(&header.to_bytes())?;
        Ok(Pc2Writer {
            out,
            points,
            frames,
            written: 0,
            buf: Vec::with_capacity(12 * points),
        })
    }

    pub fn write_frame(&mut self, positions: &[[f32; 3]]) -> Result<(), ExportError> {
        if positions.len() != self.points || self.written >= self.frames {
            return Err(ExportError::Writer {
                format: Format::Pc2,
                reason: format!(
                    "frame {} of {} has {} points, the cache {}",
                    self.written,
                    self.frames,
                    positions.len(),
                    self.points
                ),
            });
        }
        self.buf.clear();
        for c in positions.iter().flatten() {
            self.buf.extend_from_slice(&c.to_le_bytes());
        }
        let buf = std::mem::take(&mut self.buf);
        let r = self.out.write_all(&buf);
        self.buf = buf;
        self.written += 1;
        r
    }

    pub fn finish(self) -> Result<(), ExportError> {
        if self.written != self.frames {
            return Err(ExportError::Writer {
                format: Format::Pc2,
                reason: format!("{} of {} frames written", self.written, self.frames),
            });
        }
        self.out.close()
    }
}

/// The PC2 sink: the cache, and the topology OBJ written at once (rest pose).
pub struct Pc2Sink {
    writer: Pc2Writer,
    vertices: usize,
}

impl Pc2Sink {
    pub fn create(
        cache: &Path,
        topology_obj: &Path,
        mesh: &ExportMesh,
        first: usize,
        frames: usize,
    ) -> Result<Self, ExportError> {
        obj::write_obj(
            topology_obj,
            "facesim export: the topology (rest pose, cm) of the PC2 cache beside it; same vertex order",
            &mesh.rest,
            &mesh.rest_normals,
            &mesh.triangles,
            mesh.uv.as_ref(),
            &mesh.parts,
        )?;
        Ok(Pc2Sink {
            writer: Pc2Writer::create(cache, mesh.vertex_count(), first, frames)?,
            vertices: mesh.vertex_count(),
        })
    }
}

impl FrameSink for Pc2Sink {
    fn frame(&mut self, _index: usize, frame: &Frame) -> Result<(), ExportError> {
        check_sizes(Format::Pc2, self.vertices, &frame.positions, &frame.normals)?;
        self.writer.write_frame(&frame.positions)
    }
    fn finish(self: Box<Self>) -> Result<(), ExportError> {
        self.writer.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::test_mesh;

    #[test]
    fn a_cache_reads_back_with_the_documented_header_and_size() {
        let dir = std::env::temp_dir().join(format!("facesim-pc2-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.pc2");
        let mesh = test_mesh::square();
        let mut w = Pc2Writer::create(&path, 4, 5, 3).unwrap();
        let frames: Vec<_> = (0..3).map(|k| test_mesh::frame(&mesh, k).0).collect();
        for f in &frames {
            w.write_frame(f).unwrap();
        }
        assert!(
            w.write_frame(&frames[0]).is_err(),
            "a fourth frame is refused"
        );
        w.finish().unwrap();

        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[..12], b"POINTCACHE2\0");
        assert_eq!(i32::from_le_bytes(bytes[12..16].try_into().unwrap()), 1);
        assert_eq!(i32::from_le_bytes(bytes[16..20].try_into().unwrap()), 4);
        // A range of a track's frames starts at its first frame's number.
        assert_eq!(f32::from_le_bytes(bytes[20..24].try_into().unwrap()), 5.0);
        assert_eq!(f32::from_le_bytes(bytes[24..28].try_into().unwrap()), 1.0);
        assert_eq!(i32::from_le_bytes(bytes[28..32].try_into().unwrap()), 3);
        assert_eq!(bytes.len(), 32 + 3 * 4 * 12);
        // Sample 2, point 3, z: little-endian f32 at 32 + (2·4 + 3)·12 + 8.
        let o = 32 + (2 * 4 + 3) * 12 + 8;
        assert_eq!(f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()), 2.0);

        let (header, samples) = read(&path).unwrap();
        assert_eq!(header.points, 4);
        assert_eq!(header.samples, 3);
        assert_eq!(samples, frames);

        // Too few frames is an error, and a truncated file fails to read.
        let w = Pc2Writer::create(&path, 4, 0, 3).unwrap();
        assert!(w.finish().is_err());
        assert!(read(&path).unwrap_err().contains("header implies"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
