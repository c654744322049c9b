//! Animation tracks: keyframed codes over time, written by the editor's timeline (record,
//! keyframes) and read by `facesim export`.
//!
//! File format (JSON, version 2):
//!
//! ```json
//! { "format": "facesim-track", "version": 2, "face": "identity000",
//!   "quality": "final", "contact": true,
//!   "keys": [ { "time": 0.0, "codes": { "expression": [19 weights], "style": [4 values] } }, … ] }
//! ```
//!
//! `time` is in seconds, strictly increasing; `expression` follows
//! [`ExpressionCode::NAMES`](crate::rig::ExpressionCode::NAMES), `style`
//! [`StyleCode::NAMES`](crate::rig::style::StyleCode::NAMES). Between keys the codes are
//! interpolated linearly; before the first and after the last key they hold. `face` names the
//! face the track was made on (a sample face name; informative, the exporter may retarget).
//! `quality` (interactive, preview or final) and `contact` say how the track asks to be
//! rendered; both are optional, and the exporter's flags override them. Version 1 (the same
//! without `quality` and `contact`) still loads.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::drive::Codes;
use crate::sim::Quality;

pub const TRACK_FORMAT: &str = "facesim-track";
/// The version this build writes; it reads [`OLDEST_TRACK_VERSION`] up to this one.
pub const TRACK_VERSION: u32 = 2;
pub const OLDEST_TRACK_VERSION: u32 = 1;

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
    /// The solver preset the track asks to be rendered at (version 2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quality: Option<Quality>,
    /// Whether the track asks for lip and teeth contact (version 2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact: Option<bool>,
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
    #[error(
        "track version {0} is not supported (this build reads versions {OLDEST_TRACK_VERSION} to \
         {TRACK_VERSION})"
    )]
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
            quality: None,
            contact: None,
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
        if !(OLDEST_TRACK_VERSION..=TRACK_VERSION).contains(&self.version) {
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
        if !(OLDEST_TRACK_VERSION..=TRACK_VERSION).contains(&header.version) {
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
        assert!(
            !text.contains("quality") && !text.contains("contact"),
            "{text}"
        );
        std::fs::write(&path, text.replace("\"version\": 2", "\"version\": 9")).unwrap();
        assert!(matches!(Track::load(&path), Err(TrackError::Version(9))));
        let mut bad = t.clone();
        bad.keys[1].time = 0.0;
        assert!(matches!(
            bad.save(&path),
            Err(TrackError::BadKey { index: 1, .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Version 2 carries the preset and contact; version 1 files (without them) still load.
    #[test]
    fn version_two_carries_how_to_render_and_version_one_still_loads() {
        let dir = std::env::temp_dir().join(format!("facesim-track2-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("b.json");
        let mut t = Track::new("neutral");
        t.quality = Some(Quality::Final);
        t.contact = Some(true);
        t.set_key(0.0, codes(0.2));
        t.save(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("\"quality\": \"final\"") && text.contains("\"contact\": true"));
        assert_eq!(Track::load(&path).unwrap(), t);
        let v1 = r#"{"format": "facesim-track", "version": 1, "face": "neutral",
            "keys": [{"time": 0.0, "codes": {"expression": [0.5, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0], "style": [0, 0, 0, 0]}}]}"#;
        std::fs::write(&path, v1).unwrap();
        let old = Track::load(&path).unwrap();
        assert_eq!((old.version, old.quality, old.contact), (1, None, None));
        assert_eq!(
            old.sample(0.0).unwrap().expression.get("jawOpen"),
            Some(0.5)
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
