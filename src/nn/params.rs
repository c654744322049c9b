//! A versioned parameter file holding named networks (and optionally optimizer states).
//!
//! JSON document:
//! ```json
//! { "format": "facesim-nn", "version": 1,
//!   "networks": { "phi": { "spec": {..}, "num_params": 50307, "dtype": "f64",
//!                          "data": "<hex of little-endian f64>", "fnv1a64": "<hex>" } },
//!   "optimizers": { "phi": {..Adam state..} }, "metadata": { "key": "value" } }
//! ```
//! Parameters are stored as the bytes of f64 values (hex), so a save/load round trip is
//! bit-exact (f32 networks widen exactly). Loading checks the format tag, the version, each
//! spec, the parameter count, and a checksum, and reports the first mismatch as an error.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::adam::Adam;
use super::error::NnError;
use super::layer::MlpSpec;
use super::mlp::Mlp;
use super::real::Real;

/// The format tag of a parameter file.
pub const FORMAT: &str = "facesim-nn";
/// The file version this build writes and reads.
pub const VERSION: u32 = 1;

/// One stored network.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct StoredNetwork {
    spec: MlpSpec,
    num_params: usize,
    dtype: String,
    data: String,
    fnv1a64: String,
}

/// Named networks, optimizer states and metadata, saved together (keys sorted).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Checkpoint {
    format: String,
    version: u32,
    networks: BTreeMap<String, StoredNetwork>,
    #[serde(default)]
    optimizers: BTreeMap<String, Adam>,
    #[serde(default)]
    metadata: BTreeMap<String, String>,
}

impl Default for Checkpoint {
    fn default() -> Self {
        Checkpoint::new()
    }
}

impl Checkpoint {
    pub fn new() -> Self {
        Checkpoint {
            format: FORMAT.into(),
            version: VERSION,
            networks: BTreeMap::new(),
            optimizers: BTreeMap::new(),
            metadata: BTreeMap::new(),
        }
    }

    /// Stores (or replaces) a network under `name`.
    pub fn insert_network<T: Real>(&mut self, name: &str, net: &Mlp<T>) {
        let bytes: Vec<u8> = net
            .params()
            .iter()
            .flat_map(|p| p.to_f64().to_le_bytes())
            .collect();
        let stored = StoredNetwork {
            spec: net.spec().clone(),
            num_params: net.num_params(),
            dtype: "f64".into(),
            fnv1a64: format!("{:016x}", fnv1a64(&bytes)),
            data: to_hex(&bytes),
        };
        self.networks.insert(name.to_string(), stored);
    }

    /// The network stored under `name`, in scalar type `T`.
    pub fn network<T: Real>(&self, name: &str) -> Result<Mlp<T>, NnError> {
        let s = self
            .networks
            .get(name)
            .ok_or_else(|| NnError::UnknownNetwork(name.to_string()))?;
        let params = decode(name, s)?;
        Mlp::from_params(s.spec.clone(), params.into_iter().map(T::of).collect())
    }

    /// Names of the stored networks, sorted.
    pub fn network_names(&self) -> Vec<&str> {
        self.networks.keys().map(String::as_str).collect()
    }

    /// Stores an optimizer state under `name`.
    pub fn insert_optimizer(&mut self, name: &str, adam: &Adam) {
        self.optimizers.insert(name.to_string(), adam.clone());
    }

    pub fn optimizer(&self, name: &str) -> Option<&Adam> {
        self.optimizers.get(name)
    }

    pub fn metadata(&self) -> &BTreeMap<String, String> {
        &self.metadata
    }

    pub fn metadata_mut(&mut self) -> &mut BTreeMap<String, String> {
        &mut self.metadata
    }

    /// Writes the JSON document.
    pub fn to_writer(&self, w: impl Write) -> Result<(), NnError> {
        serde_json::to_writer(w, self)?;
        Ok(())
    }

    /// Reads and checks a JSON document (format, version, every network).
    pub fn from_reader(r: impl Read) -> Result<Self, NnError> {
        let value: serde_json::Value = serde_json::from_reader(r)?;
        let format = value.get("format").and_then(|v| v.as_str()).unwrap_or("");
        if format != FORMAT {
            return Err(NnError::Format(format.to_string()));
        }
        let version = value
            .get("version")
            .and_then(|v| v.as_u64())
            .ok_or_else(|| NnError::Corrupt("missing version".into()))?;
        if version != u64::from(VERSION) {
            return Err(NnError::Version {
                expected: VERSION,
                found: u32::try_from(version).unwrap_or(u32::MAX),
            });
        }
        let ck: Checkpoint = serde_json::from_value(value)?;
        for (name, s) in &ck.networks {
            let params = decode(name, s)?;
            Mlp::from_params(s.spec.clone(), params)?;
        }
        Ok(ck)
    }

    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), NnError> {
        let f = std::fs::File::create(path)?;
        let mut w = std::io::BufWriter::new(f);
        self.to_writer(&mut w)?;
        w.flush()?;
        Ok(())
    }

    pub fn load(path: impl AsRef<Path>) -> Result<Self, NnError> {
        let f = std::fs::File::open(path)?;
        Checkpoint::from_reader(std::io::BufReader::new(f))
    }
}

fn decode(name: &str, s: &StoredNetwork) -> Result<Vec<f64>, NnError> {
    let corrupt = |m: String| NnError::Corrupt(format!("network {name:?}: {m}"));
    if s.dtype != "f64" {
        return Err(corrupt(format!("unknown dtype {:?}", s.dtype)));
    }
    s.spec.validate()?;
    let expected = s.spec.num_params();
    if s.num_params != expected {
        return Err(NnError::ParamCount {
            expected,
            found: s.num_params,
        });
    }
    let bytes = from_hex(&s.data).ok_or_else(|| corrupt("parameter data is not hex".into()))?;
    if bytes.len() != 8 * expected {
        return Err(NnError::ParamCount {
            expected,
            found: bytes.len() / 8,
        });
    }
    if format!("{:016x}", fnv1a64(&bytes)) != s.fnv1a64 {
        return Err(corrupt("checksum mismatch".into()));
    }
    Ok(bytes
        .chunks_exact(8)
        .map(|c| {
            let mut b = [0u8; 8];
            b.copy_from_slice(c);
            f64::from_le_bytes(b)
        })
        .collect())
}

/// FNV-1a, 64-bit.
fn fnv1a64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

fn to_hex(bytes: &[u8]) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(2 * bytes.len());
    for &b in bytes {
        s.push(DIGITS[usize::from(b >> 4)] as char);
        s.push(DIGITS[usize::from(b & 15)] as char);
    }
    s
}

fn from_hex(s: &str) -> Option<Vec<u8>> {
    let nib = |c: u8| match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    };
    let b = s.as_bytes();
    if !b.len().is_multiple_of(2) {
        return None;
    }
    b.chunks_exact(2)
        .map(|p| Some((nib(p[0])? << 4) | nib(p[1])?))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::{AdamConfig, LayerSpec};

    fn net() -> Mlp<f64> {
        let spec = MlpSpec::new(3)
            .with_code_dim(2)
            .layer(LayerSpec::siren_first(6, 5.0))
            .layer(LayerSpec::gelu(5).lipschitz().with_code())
            .layer(LayerSpec::linear(4));
        Mlp::new(spec, 9).unwrap()
    }

    #[test]
    fn round_trip_is_bit_exact() {
        let a = net();
        let mut ck = Checkpoint::new();
        ck.insert_network("n_a", &a);
        ck.insert_network(
            "phi",
            &Mlp::<f32>::new(MlpSpec::siren(3, 8, 4, 5.0, 3), 1).unwrap(),
        );
        ck.insert_optimizer(
            "n_a",
            &Adam::new(a.num_params(), AdamConfig::default()).unwrap(),
        );
        ck.metadata_mut().insert("note".into(), "test".into());
        let mut buf = Vec::new();
        ck.to_writer(&mut buf).unwrap();
        let back = Checkpoint::from_reader(buf.as_slice()).unwrap();
        assert_eq!(back, ck);
        assert_eq!(back.network_names(), vec!["n_a", "phi"]);
        let b: Mlp<f64> = back.network("n_a").unwrap();
        assert_eq!(b.spec(), a.spec());
        assert!(
            a.params()
                .iter()
                .zip(b.params())
                .all(|(x, y)| x.to_bits() == y.to_bits())
        );
        let phi32: Mlp<f32> = back.network("phi").unwrap();
        let phi32_orig = Mlp::<f32>::new(MlpSpec::siren(3, 8, 4, 5.0, 3), 1).unwrap();
        assert_eq!(phi32, phi32_orig);
        assert!(matches!(
            back.network::<f64>("nope"),
            Err(NnError::UnknownNetwork(_))
        ));
        // Also through a file.
        let dir = std::env::temp_dir().join(format!("facesim-nn-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("ck.json");
        ck.save(&path).unwrap();
        assert_eq!(Checkpoint::load(&path).unwrap(), ck);
        std::fs::remove_dir_all(&dir).ok();
    }

    fn doc() -> serde_json::Value {
        let mut ck = Checkpoint::new();
        ck.insert_network("n", &net());
        serde_json::to_value(&ck).unwrap()
    }

    fn load(v: &serde_json::Value) -> Result<Checkpoint, NnError> {
        Checkpoint::from_reader(serde_json::to_vec(v).unwrap().as_slice())
    }

    #[test]
    fn mismatched_files_fail_with_clear_errors() {
        let mut v = doc();
        v["version"] = 2.into();
        let e = load(&v).unwrap_err();
        assert!(
            matches!(
                e,
                NnError::Version {
                    expected: 1,
                    found: 2
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("version 2"));

        let mut v = doc();
        v["format"] = "something-else".into();
        assert!(matches!(load(&v), Err(NnError::Format(_))));

        let mut v = doc();
        let data = v["networks"]["n"]["data"].as_str().unwrap().to_string();
        v["networks"]["n"]["data"] = data[..data.len() - 16].into();
        assert!(matches!(load(&v), Err(NnError::ParamCount { .. })));

        let mut v = doc();
        let mut data = v["networks"]["n"]["data"].as_str().unwrap().to_string();
        let flipped = if data.ends_with('0') { "1" } else { "0" };
        data.replace_range(data.len() - 1.., flipped);
        v["networks"]["n"]["data"] = data.into();
        let e = load(&v).unwrap_err();
        assert!(e.to_string().contains("checksum"), "{e}");

        // A spec that no longer matches the stored parameter count.
        let mut v = doc();
        v["networks"]["n"]["spec"]["layers"][0]["width"] = 7.into();
        assert!(matches!(load(&v), Err(NnError::ParamCount { .. })));

        assert!(matches!(
            Checkpoint::from_reader(&b"{not json"[..]),
            Err(NnError::Json(_))
        ));
    }
}
