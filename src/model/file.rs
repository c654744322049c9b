//! The container every facesim file uses: a header that says what the file is, its format
//! version, the payload's length and its checksum, then the payload (serde, postcard-encoded).
//!
//! ```text
//! magic "FACESIM\0" | kind (8 bytes, NUL-padded) | version u32 LE | length u64 LE | xxh3-64 u64 LE | payload
//! ```
//!
//! Reading checks each in turn, so a file that is not ours, of another kind, of another
//! version, truncated or corrupted fails with an error that says which. Writing goes to a
//! temporary file in the same folder that is renamed over the target only when complete, so
//! an interrupted write never leaves a half-written file behind.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;
use serde::de::DeserializeOwned;

const MAGIC: [u8; 8] = *b"FACESIM\0";
const HEADER: usize = 8 + 8 + 4 + 8 + 8;

#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: not a facesim file")]
    NotOurs { path: PathBuf },
    #[error("{path}: is a {found} file, expected a {expected} file")]
    WrongKind {
        path: PathBuf,
        expected: String,
        found: String,
    },
    #[error(
        "{path}: {kind} format version {found}, this build reads version {supported}; rebuild the file with this version's tools"
    )]
    Version {
        path: PathBuf,
        kind: String,
        found: u32,
        supported: u32,
    },
    #[error("{path}: truncated (payload of {expected} bytes, {got} present)")]
    Truncated {
        path: PathBuf,
        expected: u64,
        got: u64,
    },
    #[error("{path}: corrupt (checksum mismatch)")]
    Corrupt { path: PathBuf },
    #[error("{path}: cannot decode the {kind} payload: {message}")]
    Decode {
        path: PathBuf,
        kind: String,
        message: String,
    },
    #[error("cannot encode the {kind} payload: {message}")]
    Encode { kind: String, message: String },
}

/// What a file holds, and the format version this build writes and reads.
#[derive(Clone, Copy, Debug)]
pub struct Format {
    /// Up to 8 ASCII bytes, e.g. `"model"`.
    pub kind: &'static str,
    pub version: u32,
}

impl Format {
    fn kind_bytes(&self) -> [u8; 8] {
        let mut out = [0u8; 8];
        let bytes = self.kind.as_bytes();
        assert!(
            bytes.len() <= 8 && bytes.is_ascii(),
            "file kind must be at most 8 ASCII bytes"
        );
        out[..bytes.len()].copy_from_slice(bytes);
        out
    }
}

/// Encodes `value` into a complete file image.
pub fn encode<T: Serialize>(format: Format, value: &T) -> Result<Vec<u8>, FileError> {
    let payload = postcard::to_allocvec(value).map_err(|e| FileError::Encode {
        kind: format.kind.into(),
        message: e.to_string(),
    })?;
    let mut out = Vec::with_capacity(HEADER + payload.len());
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&format.kind_bytes());
    out.extend_from_slice(&format.version.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&xxhash_rust::xxh3::xxh3_64(&payload).to_le_bytes());
    out.extend_from_slice(&payload);
    Ok(out)
}

/// Decodes a file image; `path` only names the file in errors.
pub fn decode<T: DeserializeOwned>(
    format: Format,
    bytes: &[u8],
    path: &Path,
) -> Result<T, FileError> {
    let path = path.to_path_buf();
    if bytes.len() < HEADER || bytes[..8] != MAGIC {
        return Err(FileError::NotOurs { path });
    }
    let kind = &bytes[8..16];
    if kind != format.kind_bytes() {
        let found = String::from_utf8_lossy(kind)
            .trim_end_matches('\0')
            .to_string();
        return Err(FileError::WrongKind {
            path,
            expected: format.kind.into(),
            found,
        });
    }
    let word = |range: std::ops::Range<usize>| {
        bytes[range]
            .iter()
            .rev()
            .fold(0u64, |acc, &b| (acc << 8) | b as u64)
    };
    let version = word(16..20) as u32;
    if version != format.version {
        return Err(FileError::Version {
            path,
            kind: format.kind.into(),
            found: version,
            supported: format.version,
        });
    }
    let (length, checksum) = (word(20..28), word(28..36));
    let payload = &bytes[HEADER..];
    if (payload.len() as u64) < length {
        return Err(FileError::Truncated {
            path,
            expected: length,
            got: payload.len() as u64,
        });
    }
    let payload = &payload[..length as usize];
    if xxhash_rust::xxh3::xxh3_64(payload) != checksum {
        return Err(FileError::Corrupt { path });
    }
    postcard::from_bytes(payload).map_err(|e| FileError::Decode {
        path,
        kind: format.kind.into(),
        message: e.to_string(),
    })
}

/// Writes `value` to `path` atomically (temporary file in the same folder, then rename).
pub fn write<T: Serialize>(path: &Path, format: Format, value: &T) -> Result<(), FileError> {
    let bytes = encode(format, value)?;
    let io = |source| FileError::Io {
        path: path.to_path_buf(),
        source,
    };
    let name = path
        .file_name()
        .ok_or_else(|| io(std::io::Error::other("not a file path")))?;
    let temporary = path.with_file_name(format!(
        ".{}.{}.partial",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut file = std::fs::File::create(&temporary)?;
        file.write_all(&bytes)?;
        file.sync_all()?;
        std::fs::rename(&temporary, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    result.map_err(io)
}

/// Reads a file written by [`write`] with the same format.
pub fn read<T: DeserializeOwned>(path: &Path, format: Format) -> Result<T, FileError> {
    let bytes = std::fs::read(path).map_err(|source| FileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    decode(format, &bytes, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    const FORMAT: Format = Format {
        kind: "test",
        version: 3,
    };

    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    struct Payload {
        name: String,
        values: Vec<f64>,
    }

    fn payload() -> Payload {
        Payload {
            name: "face".into(),
            values: (0..100).map(|i| i as f64 * 0.25).collect(),
        }
    }

    fn temp(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("facesim-file-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn round_trips_atomically() {
        let dir = temp("roundtrip");
        let path = dir.join("a.bin");
        write(&path, FORMAT, &payload()).unwrap();
        assert_eq!(read::<Payload>(&path, FORMAT).unwrap(), payload());
        let leftovers: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(leftovers, vec![std::ffi::OsString::from("a.bin")]);
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn every_kind_of_damage_is_named() {
        let good = encode(FORMAT, &payload()).unwrap();
        let path = Path::new("x.bin");
        let err = |bytes: &[u8]| decode::<Payload>(FORMAT, bytes, path).unwrap_err();
        assert!(matches!(err(b"hello"), FileError::NotOurs { .. }));
        let mut other_kind = good.clone();
        other_kind[8] = b'm';
        assert!(matches!(err(&other_kind), FileError::WrongKind { .. }));
        let old = encode(
            Format {
                version: 2,
                ..FORMAT
            },
            &payload(),
        )
        .unwrap();
        let e = err(&old);
        assert!(
            matches!(
                e,
                FileError::Version {
                    found: 2,
                    supported: 3,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("version 2"));
        assert!(matches!(
            err(&good[..good.len() - 10]),
            FileError::Truncated { .. }
        ));
        let mut flipped = good.clone();
        let last = flipped.len() - 1;
        flipped[last] ^= 0x40;
        assert!(matches!(err(&flipped), FileError::Corrupt { .. }));
        let mismatched = encode(FORMAT, &"just a string").unwrap();
        assert!(matches!(err(&mismatched), FileError::Decode { .. }));
    }

    #[test]
    fn a_failed_write_leaves_nothing() {
        let dir = temp("failed");
        let missing = dir.join("no/such/folder/a.bin");
        assert!(matches!(
            write(&missing, FORMAT, &payload()),
            Err(FileError::Io { .. })
        ));
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        std::fs::remove_dir_all(dir).ok();
    }
}
