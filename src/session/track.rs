//! Animation tracks: keyframed codes over time, written by the editor's timeline (record,
//! keyframes) and read by `facesim export`.
//!
//! File format (JSON, version 1):
//!
//! ```json
//! { "format": "facesim-track", "version": 1, "face": "identity000",
//!   "keys": [ { "time": 0.0, "codes": { "expression": [19 weights], "style": [4 values] } }, … ] }
//! ```
//!
//! `time` is in seconds, strictly increasing; `expression` follows
//! [`ExpressionCode::NAMES`](crate::rig::ExpressionCode::NAMES), `style`
//! [`StyleCode::NAMES`](crate::rig::style::StyleCode::NAMES). Between keys the codes are
//! interpolated linearly; before the first and after the last key they hold. `face` names the
//! face the track was made on (a sample face name; informative, the exporter may retarget).

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::drive::Codes;

pub const TRACK_FORMAT: &str = "facesim-track";
pub const TRACK_VERSION: u32 = 1;

/// One keyframe.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Key {
    pub time: f64,
    pub codes: Codes,
}

/// A keyframed animation (module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Track {
    pub format: String,
    pub version: u32,
    pub face: String,
    pub keys: Vec<Key>,
}

#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    #[error("reading track {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("track {path} is not valid JSON of the track format: {source}")]
    Parse {
        path: String,
        source: serde_json::Error,
    },
    #[error("not a facesim track (format '{0}', expected '{TRACK_FORMAT}')")]
    Format(String),
    #[error("track version {0} is not supported (this build reads version {TRACK_VERSION})")]
    Version(u32),
    #[error("key {index}: {reason}")]
    BadKey { index: usize, reason: String },
}

impl Track {
    pub fn new(face: &str) -> Self {
        Track {
            format: TRACK_FORMAT.into(),
            version: TRACK_VERSION,
            face: face.into(),
            keys: Vec::new(),
        }
    }

    /// Inserts (or replaces, at the same time) a key, keeping keys sorted.
    pub fn set_key(&mut self, time: f64, codes: Codes) {
        match self.keys.iter().position(|k| k.time >= time) {
            Some(i) if self.keys[i].time == time => self.keys[i].codes = codes,
            Some(i) => self.keys.insert(i, Key { time, codes }),
            None => self.keys.push(Key { time, codes }),
        }
    }

    pub fn remove_key_near(&mut self, time: f64, tolerance: f64) -> bool {
        let before = self.keys.len();
        self.keys.retain(|k| (k.time - time).abs() > tolerance);
        self.keys.len() != before
    }

    pub fn duration(&self) -> f64 {
        self.keys.last().map_or(0.0, |k| k.time)
    }

    /// The codes at `time` (module doc); `None` for an empty track.
    pub fn sample(&self, time: f64) -> Option<Codes> {
        let first = self.keys.first()?;
        if time <= first.time {
            return Some(first.codes);
        }
        let i = self.keys.partition_point(|k| k.time <= time);
        if i == self.keys.len() {
            return Some(self.keys[i - 1].codes);
        }
        let (a, b) = (&self.keys[i - 1], &self.keys[i]);
        let t = (time - a.time) / (b.time - a.time);
        let mut c = a.codes;
        for (x, y) in c.expression.0.iter_mut().zip(b.codes.expression.0) {
            *x += (y - *x) * t;
        }
        for (x, y) in c.style.0.iter_mut().zip(b.codes.style.0) {
            *x += (y - *x) * t;
        }
        Some(c)
    }

    pub fn validate(&self) -> Result<(), TrackError> {
        if self.format != TRACK_FORMAT {
            return Err(TrackError::Format(self.format.clone()));
        }
        if self.version != TRACK_VERSION {
            return Err(TrackError::Version(self.version));
        }
        for (index, k) in self.keys.iter().enumerate() {
            let bad = |reason: String| TrackError::BadKey { index, reason };
            if !(k.time >= 0.0) || !k.time.is_finite() {
                return Err(bad(format!("time {} must be finite and ≥ 0", k.time)));
            }
            if index > 0 && !(k.time > self.keys[index - 1].time) {
                return Err(bad("times must strictly increase".into()));
            }
            k.codes.validate().map_err(|e| bad(e.to_string()))?;
        }
        Ok(())
    }

    pub fn load(path: &Path) -> Result<Self, TrackError> {
        let p = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| TrackError::Io {
            path: p.clone(),
            source,
        })?;
        // Check the header first so a newer file says "version", not a field error.
        #[derive(Deserialize)]
        struct Header {
            format: String,
            version: u32,
        }
        let header: Header = serde_json::from_str(&text).map_err(|source| TrackError::Parse {
            path: p.clone(),
            source,
        })?;
        if header.format != TRACK_FORMAT {
            return Err(TrackError::Format(header.format));
        }
        if header.version != TRACK_VERSION {
            return Err(TrackError::Version(header.version));
        }
        let track: Track =
            serde_json::from_str(&text).map_err(|source| TrackError::Parse { path: p, source })?;
        track.validate()?;
        Ok(track)
    }

    pub fn save(&self, path: &Path) -> Result<(), TrackError> {
        self.validate()?;
        let text = serde_json::to_string_pretty(self).expect("tracks serialize");
        std::fs::write(path, text).map_err(|source| TrackError::Io {
            path: path.display().to_string(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rig::ExpressionCode;

    fn codes(jaw: f64) -> Codes {
        Codes {
            expression: ExpressionCode::single("jawOpen", jaw).unwrap(),
            ..Codes::default()
        }
    }

    #[test]
    fn samples_interpolate_between_keys_and_hold_outside() {
        let mut t = Track::new("neutral");
        t.set_key(1.0, codes(1.0));
        t.set_key(0.0, codes(0.0));
        assert_eq!(t.keys[0].time, 0.0);
        let mid = t.sample(0.25).unwrap();
        assert!((mid.expression.get("jawOpen").unwrap() - 0.25).abs() < 1e-12);
        assert_eq!(t.sample(5.0).unwrap(), codes(1.0));
        assert_eq!(t.sample(-1.0).unwrap(), codes(0.0));
        t.set_key(1.0, codes(0.5));
        assert_eq!(t.keys.len(), 2);
        assert!(t.remove_key_near(1.0, 1e-3));
        assert_eq!(t.keys.len(), 1);
    }

    #[test]
    fn files_round_trip_and_bad_files_are_rejected() {
        let dir = std::env::temp_dir().join(format!("facesim-track-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.json");
        let mut t = Track::new("identity000");
        t.set_key(0.0, codes(0.0));
        t.set_key(0.5, codes(0.7));
        t.save(&path).unwrap();
        assert_eq!(Track::load(&path).unwrap(), t);

        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::write(&path, text.replace("\"version\": 1", "\"version\": 9")).unwrap();
        assert!(matches!(Track::load(&path), Err(TrackError::Version(9))));
        let mut bad = t.clone();
        bad.keys[1].time = 0.0;
        assert!(matches!(
            bad.save(&path),
            Err(TrackError::BadKey { index: 1, .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
