//! Frame geometry in binary for the remote protocol: quantized, and only what moved.
//!
//! A frame's geometry as JSON text is ~2.2 MB (26,719 render vertices, the whole head:
//! positions and normals). Here:
//! - positions (render surface and simulation mesh) are quantized to [`QUANTUM`] = 0.001 cm
//!   (0.01 mm, below what the artist can see) as integers `q = round(p / QUANTUM)`;
//! - heatmap values (which only colour the skin) travel as IEEE half floats (11 significant
//!   bits), as integers ordered like the values;
//! - normals are not sent: the client recomputes them from the positions and the topology it
//!   fetched once ([`super::frame::vertex_normals`]);
//! - a full encoding stores each integer as a zigzag varint of its difference to the previous
//!   vertex's (neighbouring vertices lie close, so most take 1–2 bytes);
//! - a delta against a base the client holds stores only the vertices whose integers changed:
//!   the index gap to the previous changed vertex and the differences to the base, all
//!   varints. Values are exact integers, so decoding a delta on its base gives bitwise the same
//!   integers as a full encoding (no drift over a long drag).
//!
//! Layout (little-endian): `b"FSG1"`, `u8` kind (0 full, 1 delta), `u64` base frame index
//! (delta only), `u32` render vertex count, `u32` mesh vertex count, `u32` heatmap count, then
//! the streams: render positions, mesh positions, each heatmap.
//!
//! Off the server's machine a client asks for the payload deflated ([`deflate`]: zlib format
//! at the fastest level, which browsers inflate natively): on a jaw drag 64 % of the bytes
//! (141 → 90 KB median) for +0.3 ms a frame (`facesim bench remote`), so it pays on links
//! slower than ~1 Gbit/s and not on loopback.

use half::f16;

/// Quantization step of positions, cm (0.01 mm).
pub const QUANTUM: f64 = 1e-3;

const MAGIC: &[u8; 4] = b"FSG1";

/// One frame's geometry as integers: render and mesh positions (in [`QUANTUM`]s) and heatmap
/// values (half floats, ordered).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct QuantizedGeometry {
    pub index: u64,
    pub positions: Vec<[i32; 3]>,
    pub mesh_positions: Vec<[i32; 3]>,
    pub fields: Vec<Vec<i32>>,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum WireError {
    #[error("not a facesim geometry payload (bad magic)")]
    Magic,
    #[error("the payload ends early")]
    Truncated,
    #[error("unknown payload kind {0}")]
    Kind(u8),
    #[error("a delta on frame {wanted}, but the client holds {held:?}")]
    WrongBase { wanted: u64, held: Option<u64> },
    #[error("the payload's sizes do not match its base or its heatmaps")]
    Sizes,
    #[error("a value is out of range")]
    Range,
    #[error("{0} bytes left over after the payload")]
    Trailing(usize),
    #[error("the deflated payload is corrupt")]
    Inflate,
    #[error("the deflated payload inflates beyond {0} bytes")]
    TooLarge(usize),
}

/// `payload` deflated (zlib, RFC 1950) at the fastest level.
pub fn deflate(payload: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
    z.write_all(payload).expect("writing to memory");
    z.finish().expect("writing to memory")
}

/// A [`deflate`]d payload inflated, refused past `limit` bytes (no zip bomb).
pub fn inflate(data: &[u8], limit: usize) -> Result<Vec<u8>, WireError> {
    use std::io::Read;
    let mut out = Vec::new();
    flate2::read::ZlibDecoder::new(data)
        .take(limit as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|_| WireError::Inflate)?;
    if out.len() > limit {
        return Err(WireError::TooLarge(limit));
    }
    Ok(out)
}

fn quantize(p: &[f32; 3]) -> Result<[i32; 3], WireError> {
    let mut q = [0i32; 3];
    for (q, &x) in q.iter_mut().zip(p) {
        let v = (x as f64 / QUANTUM).round();
        if !v.is_finite() || v.abs() > i32::MAX as f64 {
            return Err(WireError::Range);
        }
        *q = v as i32;
    }
    Ok(q)
}

/// A half float's bits as an integer ordered like the value (sign and magnitude); −0 → 0.
fn ordered_half(v: f32) -> i32 {
    let bits = f16::from_f32(v).to_bits() as i32;
    if bits & 0x8000 != 0 {
        -(bits & 0x7fff)
    } else {
        bits
    }
}

fn half_value(q: i32) -> f32 {
    let bits = if q < 0 { 0x8000 | (-q) } else { q };
    f16::from_bits(bits as u16).to_f32()
}

impl QuantizedGeometry {
    /// Quantizes a frame's positions (cm) and heatmap values. Fails on non-finite or absurd
    /// coordinates (beyond ±21 km) and on heatmaps of another length than the positions.
    pub fn new(
        index: u64,
        positions: &[[f32; 3]],
        mesh_positions: &[[f32; 3]],
        fields: &[&[f32]],
    ) -> Result<Self, WireError> {
        if fields.iter().any(|f| f.len() != positions.len()) {
            return Err(WireError::Sizes);
        }
        Ok(QuantizedGeometry {
            index,
            positions: positions.iter().map(quantize).collect::<Result<_, _>>()?,
            mesh_positions: mesh_positions
                .iter()
                .map(quantize)
                .collect::<Result<_, _>>()?,
            fields: fields
                .iter()
                .map(|f| f.iter().map(|&v| ordered_half(v)).collect())
                .collect(),
        })
    }

    /// Positions back in cm (f32, as frames carry them).
    pub fn positions_cm(&self) -> Vec<[f32; 3]> {
        dequantize(&self.positions)
    }

    pub fn mesh_positions_cm(&self) -> Vec<[f32; 3]> {
        dequantize(&self.mesh_positions)
    }

    /// Heatmap `k`'s values.
    pub fn field_values(&self, k: usize) -> Vec<f32> {
        self.fields[k].iter().map(|&q| half_value(q)).collect()
    }

    fn same_sizes(&self, other: &QuantizedGeometry) -> bool {
        self.positions.len() == other.positions.len()
            && self.mesh_positions.len() == other.mesh_positions.len()
            && self.fields.len() == other.fields.len()
    }

    /// Every stream, flat, with its stride.
    fn streams(&self) -> Vec<(&[i32], usize)> {
        let mut s = vec![
            (self.positions.as_flattened(), 3),
            (self.mesh_positions.as_flattened(), 3),
        ];
        s.extend(self.fields.iter().map(|f| (f.as_slice(), 1)));
        s
    }

    /// The payload for a client holding `base` (a delta when its sizes match, else full).
    pub fn encode(&self, base: Option<&QuantizedGeometry>) -> Vec<u8> {
        let base = base.filter(|b| b.same_sizes(self));
        let mut out = Vec::with_capacity(64 + 4 * self.positions.len());
        out.extend_from_slice(MAGIC);
        match base {
            Some(b) => {
                out.push(1);
                out.extend_from_slice(&b.index.to_le_bytes());
            }
            None => out.push(0),
        }
        for n in [
            self.positions.len(),
            self.mesh_positions.len(),
            self.fields.len(),
        ] {
            out.extend_from_slice(&(n as u32).to_le_bytes());
        }
        let then = base.map(|b| b.streams());
        for (k, (now, stride)) in self.streams().into_iter().enumerate() {
            match &then {
                Some(then) => encode_changes(now, then[k].0, stride, &mut out),
                None => encode_all(now, stride, &mut out),
            }
        }
        out
    }

    /// Decodes a payload for frame `index`; a delta needs the base it was made on.
    pub fn decode(
        index: u64,
        bytes: &[u8],
        held: Option<&QuantizedGeometry>,
    ) -> Result<Self, WireError> {
        let mut r = Reader { bytes, at: 0 };
        if r.take(4)? != MAGIC {
            return Err(WireError::Magic);
        }
        let base = match r.take(1)?[0] {
            0 => None,
            1 => {
                let wanted = u64::from_le_bytes(r.take(8)?.try_into().expect("8 bytes"));
                match held {
                    Some(h) if h.index == wanted => Some(h),
                    _ => {
                        return Err(WireError::WrongBase {
                            wanted,
                            held: held.map(|h| h.index),
                        });
                    }
                }
            }
            k => return Err(WireError::Kind(k)),
        };
        let mut count = || -> Result<usize, WireError> {
            Ok(u32::from_le_bytes(r.take(4)?.try_into().expect("4 bytes")) as usize)
        };
        let (n, m, f) = (count()?, count()?, count()?);
        // Every stream takes at least a byte.
        if f > bytes.len() - r.at {
            return Err(WireError::Truncated);
        }
        let sizes = std::iter::once((n, 3))
            .chain(std::iter::once((m, 3)))
            .chain(std::iter::repeat_n((n, 1), f));
        let mut streams = Vec::with_capacity(2 + f);
        match base {
            Some(b) => {
                let then = b.streams();
                if then.len() != 2 + f || then[0].0.len() != 3 * n || then[1].0.len() != 3 * m {
                    return Err(WireError::Sizes);
                }
                for (then, stride) in then {
                    streams.push(decode_changes(&mut r, then, stride)?);
                }
            }
            None => {
                for (len, stride) in sizes {
                    streams.push(decode_all(&mut r, len * stride, stride)?);
                }
            }
        }
        if r.at != bytes.len() {
            return Err(WireError::Trailing(bytes.len() - r.at));
        }
        let mut streams = streams.into_iter();
        let triples = |s: Option<Vec<i32>>| -> Vec<[i32; 3]> {
            s.expect("two position streams")
                .chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect()
        };
        let positions = triples(streams.next());
        let mesh_positions = triples(streams.next());
        Ok(QuantizedGeometry {
            index,
            positions,
            mesh_positions,
            fields: streams.collect(),
        })
    }
}

fn dequantize(q: &[[i32; 3]]) -> Vec<[f32; 3]> {
    q.iter()
        .map(|v| v.map(|c| (c as f64 * QUANTUM) as f32))
        .collect()
}

fn put_varint(mut v: u64, out: &mut Vec<u8>) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn unzigzag(v: u64) -> i64 {
    (v >> 1) as i64 ^ -((v & 1) as i64)
}

/// Every integer as the difference to the previous vertex's (same component).
fn encode_all(now: &[i32], stride: usize, out: &mut Vec<u8>) {
    for (i, &v) in now.iter().enumerate() {
        let previous = if i >= stride { now[i - stride] } else { 0 };
        put_varint(zigzag(v as i64 - previous as i64), out);
    }
}

/// The changed vertices: their count, then per vertex the index gap and the differences.
fn encode_changes(now: &[i32], then: &[i32], stride: usize, out: &mut Vec<u8>) {
    let vertices = now.len() / stride;
    let changed: Vec<usize> = (0..vertices)
        .filter(|&i| now[i * stride..(i + 1) * stride] != then[i * stride..(i + 1) * stride])
        .collect();
    put_varint(changed.len() as u64, out);
    let mut previous = 0;
    for i in changed {
        put_varint((i - previous) as u64, out);
        previous = i;
        for c in i * stride..(i + 1) * stride {
            put_varint(zigzag(now[c] as i64 - then[c] as i64), out);
        }
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], WireError> {
        let end = self.at.checked_add(n).ok_or(WireError::Truncated)?;
        let s = self.bytes.get(self.at..end).ok_or(WireError::Truncated)?;
        self.at = end;
        Ok(s)
    }

    fn varint(&mut self) -> Result<u64, WireError> {
        let mut v = 0u64;
        for shift in (0..64).step_by(7) {
            let b = self.take(1)?[0];
            v |= ((b & 0x7f) as u64) << shift;
            if b < 0x80 {
                return Ok(v);
            }
        }
        Err(WireError::Range)
    }

    fn value(&mut self, from: i32) -> Result<i32, WireError> {
        let v = from as i64 + unzigzag(self.varint()?);
        i32::try_from(v).map_err(|_| WireError::Range)
    }
}

fn decode_all(r: &mut Reader, len: usize, stride: usize) -> Result<Vec<i32>, WireError> {
    // Every integer takes at least a byte: a count beyond that is a lie, not an allocation.
    if len > r.bytes.len() - r.at {
        return Err(WireError::Truncated);
    }
    let mut out: Vec<i32> = Vec::with_capacity(len);
    for i in 0..len {
        let previous = if i >= stride { out[i - stride] } else { 0 };
        out.push(r.value(previous)?);
    }
    Ok(out)
}

fn decode_changes(r: &mut Reader, then: &[i32], stride: usize) -> Result<Vec<i32>, WireError> {
    let mut out = then.to_vec();
    let vertices = then.len() / stride;
    let count = r.varint()?;
    let mut i = 0usize;
    for k in 0..count {
        let gap = r.varint()? as usize;
        if k > 0 && gap == 0 {
            return Err(WireError::Range);
        }
        i = i.checked_add(gap).ok_or(WireError::Range)?;
        if i >= vertices {
            return Err(WireError::Range);
        }
        for c in i * stride..(i + 1) * stride {
            out[c] = r.value(then[c])?;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn cloud(n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| [(); 3].map(|_| rng.random_range(-15.0f32..15.0)))
            .collect()
    }

    #[test]
    fn deflated_payloads_inflate_back_and_bad_ones_are_refused() {
        let payload: Vec<u8> = (0..50_000u32).map(|i| (i % 7) as u8).collect();
        let small = deflate(&payload);
        assert!(small.len() * 10 < payload.len());
        assert_eq!(inflate(&small, payload.len()).unwrap(), payload);
        assert_eq!(
            inflate(&small, payload.len() - 1),
            Err(WireError::TooLarge(payload.len() - 1))
        );
        assert_eq!(inflate(&payload[..100], 1 << 20), Err(WireError::Inflate));
        assert_eq!(
            inflate(&small[..small.len() / 2], 1 << 20),
            Err(WireError::Inflate)
        );
    }

    #[test]
    fn a_full_payload_round_trips_within_half_a_quantum() {
        let (p, m) = (cloud(500, 1), cloud(80, 2));
        let heat: Vec<f32> = p.iter().map(|v| v[0] - 3.0).collect();
        let q = QuantizedGeometry::new(7, &p, &m, &[&heat]).unwrap();
        let back = QuantizedGeometry::decode(7, &q.encode(None), None).unwrap();
        assert_eq!(back, q);
        for (a, b) in p.iter().chain(&m).zip(
            back.positions_cm()
                .into_iter()
                .chain(back.mesh_positions_cm()),
        ) {
            for c in 0..3 {
                // Half a quantum, plus f32 rounding of coordinates up to 15 cm.
                assert!(
                    (a[c] - b[c]).abs() as f64 <= 0.5 * QUANTUM + 2e-6,
                    "{a:?} {b:?}"
                );
            }
        }
        // Half floats: 11 significant bits, signs kept.
        for (a, b) in heat.iter().zip(back.field_values(0)) {
            assert!((a - b).abs() <= a.abs() / 2048.0, "{a} {b}");
            assert_eq!(a.signum(), b.signum());
        }
    }

    #[test]
    fn a_delta_carries_only_what_moved_and_decodes_exactly() {
        let (p, m) = (cloud(2000, 3), cloud(300, 4));
        let heat = vec![1.0f32; 2000];
        let base = QuantizedGeometry::new(1, &p, &m, &[&heat]).unwrap();
        let mut moved = p.clone();
        let mut warmer = heat.clone();
        for (v, h) in moved.iter_mut().zip(&mut warmer).step_by(10) {
            v[1] -= 0.05; // 0.5 mm
            *h = 1.2;
        }
        let now = QuantizedGeometry::new(2, &moved, &m, &[&warmer]).unwrap();
        let delta = now.encode(Some(&base));
        let full = now.encode(None);
        assert!(
            delta.len() * 5 < full.len(),
            "{} vs {}",
            delta.len(),
            full.len()
        );
        assert_eq!(
            QuantizedGeometry::decode(2, &delta, Some(&base)).unwrap(),
            now
        );
        // Nothing moved: a few bytes.
        assert!(base.encode(Some(&base)).len() < 32);
        // A delta needs its base.
        assert_eq!(
            QuantizedGeometry::decode(2, &delta, None),
            Err(WireError::WrongBase {
                wanted: 1,
                held: None
            })
        );
        assert_eq!(
            QuantizedGeometry::decode(2, &delta, Some(&now)),
            Err(WireError::WrongBase {
                wanted: 1,
                held: Some(2)
            })
        );
    }

    #[test]
    fn bad_payloads_are_errors_not_panics() {
        let q = QuantizedGeometry::new(1, &cloud(50, 5), &cloud(5, 6), &[&[0.5; 50]]).unwrap();
        let bytes = q.encode(None);
        assert_eq!(
            QuantizedGeometry::decode(1, b"nope", None),
            Err(WireError::Magic)
        );
        for cut in [3, 5, 12, bytes.len() - 1] {
            assert!(QuantizedGeometry::decode(1, &bytes[..cut], None).is_err());
        }
        let mut long = bytes.clone();
        long.push(0);
        assert_eq!(
            QuantizedGeometry::decode(1, &long, None),
            Err(WireError::Trailing(1))
        );
        assert_eq!(
            QuantizedGeometry::new(1, &cloud(50, 5), &[], &[&[0.5; 49]]),
            Err(WireError::Sizes)
        );
        let mut huge = bytes.clone();
        huge[5..9].copy_from_slice(&u32::MAX.to_le_bytes());
        assert_eq!(
            QuantizedGeometry::decode(1, &huge, None),
            Err(WireError::Truncated)
        );
        assert_eq!(
            QuantizedGeometry::new(1, &[[f32::NAN, 0.0, 0.0]], &[], &[]),
            Err(WireError::Range)
        );
        // Random bytes after a valid header never panic.
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for _ in 0..200 {
            let mut junk = bytes[..13].to_vec();
            junk.extend((0..rng.random_range(0..64)).map(|_| rng.random::<u8>()));
            let _ = QuantizedGeometry::decode(1, &junk, None);
        }
    }
}
