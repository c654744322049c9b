//! Editor latency: slider change → new frame available, through the [`Session`] the editor
//! uses (actuation, warm-started solve, render surface, normals, heatmaps), per quality preset.
//!
//! The slider path is a deterministic sweep of one expression slider (and its partner on the
//! other side) in small steps, as a drag produces; each step waits for its frame before the
//! next (refinement off), so every sample is one full slider-to-frame latency.

use std::time::{Duration, Instant};

use serde::Serialize;

use crate::rig::ExpressionCode;
use crate::session::{Request, Session, SessionError, SessionFace};
use crate::sim::Quality;
use crate::table::Table;

use super::percentile;

#[derive(Clone, Debug, Serialize)]
pub struct LatencyRow {
    pub face: String,
    pub quality: Quality,
    /// Lip and teeth contact on.
    pub contact: bool,
    pub samples: usize,
    pub median_ms: f64,
    pub p95_ms: f64,
    /// Median solver iterations per frame.
    pub median_iterations: usize,
    /// Median contact candidate lists built per frame (`None` with contact off): how often a
    /// frame re-detected contact pairs over the region.
    pub median_lists: Option<usize>,
    /// Frames whose solve failed (reported, never hidden).
    pub errors: usize,
}

/// The slider steps of one drag: `slider` from 0 to 1 and back in `steps` moves.
pub fn drag(slider: &str, steps: usize) -> Vec<ExpressionCode> {
    (0..steps)
        .map(|k| {
            let t = k as f64 / (steps / 2).max(1) as f64;
            let w = if t <= 1.0 { t } else { 2.0 - t };
            ExpressionCode::single(slider, w.clamp(0.0, 1.0)).expect("a code slider")
        })
        .collect()
}

/// How long one frame may take before the benchmark gives up (a final-preset contact frame
/// has taken over 100 s).
const FRAME_TIMEOUT_S: u64 = 600;

/// Latency rows for `face` at each of `presets`, contact on or off; `sliders` are dragged
/// one after another.
pub fn bench_latency(
    face: SessionFace,
    presets: &[Quality],
    sliders: &[&str],
    steps: usize,
    contact: bool,
) -> Result<Vec<LatencyRow>, SessionError> {
    let name = face.name.clone();
    let mut rows = Vec::new();
    for &quality in presets {
        let session = Session::new(vec![face.clone()], quality)?;
        session.submit(Request::Refine(false))?;
        session.submit(Request::Contact(contact))?;
        let timeout = Duration::from_secs(FRAME_TIMEOUT_S);
        let timed_out = || SessionError::TimedOut {
            seconds: FRAME_TIMEOUT_S,
        };
        session.wait_newer(None, timeout).ok_or_else(timed_out)?;
        let (mut ms, mut iterations, mut lists, mut errors) =
            (Vec::new(), Vec::new(), Vec::new(), 0);
        for slider in sliders {
            for code in drag(slider, steps) {
                let start = Instant::now();
                let g = session.submit(Request::Expression(code))?;
                let frame = session.wait_generation(g, timeout).ok_or_else(timed_out)?;
                ms.push(start.elapsed().as_secs_f64() * 1e3);
                iterations.push(frame.stats.iterations);
                lists.extend(frame.stats.contact_lists);
                errors += usize::from(frame.error.is_some());
            }
        }
        ms.sort_by(f64::total_cmp);
        iterations.sort_unstable();
        lists.sort_unstable();
        rows.push(LatencyRow {
            face: name.clone(),
            quality,
            contact,
            samples: ms.len(),
            median_ms: percentile(&ms, 0.5),
            p95_ms: percentile(&ms, 0.95),
            median_iterations: iterations[iterations.len() / 2],
            median_lists: (!lists.is_empty()).then(|| lists[lists.len() / 2]),
            errors,
        });
    }
    Ok(rows)
}

/// A markdown table of `rows`.
pub fn table(rows: &[LatencyRow]) -> String {
    let mut t = Table::new(
        &[
            "face",
            "preset",
            "contact",
            "samples",
            "median ms",
            "p95 ms",
            "median iterations",
            "median lists built",
            "failed",
        ],
        "lllrrrrrr",
    );
    for r in rows {
        t.row([
            r.face.clone(),
            r.quality.to_string(),
            if r.contact { "on" } else { "off" }.to_string(),
            r.samples.to_string(),
            format!("{:.1}", r.median_ms),
            format!("{:.1}", r.p95_ms),
            r.median_iterations.to_string(),
            r.median_lists.map_or("-".into(), |n| n.to_string()),
            r.errors.to_string(),
        ]);
    }
    t.to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_drag_goes_up_to_one_and_back() {
        let d = drag("jawOpen", 10);
        let w: Vec<f64> = d.iter().map(|c| c.get("jawOpen").unwrap()).collect();
        assert_eq!(w[0], 0.0);
        assert_eq!(w[5], 1.0);
        assert!((w[9] - 0.2).abs() < 1e-12);
    }

    #[test]
    fn latency_rows_cover_every_preset() {
        let face = crate::session::tests::test_face("neutral");
        let rows = bench_latency(face, &Quality::ALL, &["jawOpen"], 4, false).unwrap();
        assert_eq!(rows.len(), 3);
        assert!(rows.iter().all(|r| r.samples == 4
            && r.errors == 0
            && r.median_ms > 0.0
            && r.median_lists.is_none()));
        assert!(table(&rows).contains("| neutral | interactive | off | 4 |"));
    }

    /// With contact on, every frame of the drag comes back valid and the rows say contact was
    /// on, with the lists each frame built. The editor's own preset only: contact on the
    /// format-3 face costs seconds a frame at the others (see docs/performance/contact.md).
    #[test]
    fn latency_rows_with_contact_on() {
        let face = crate::session::tests::test_face("neutral");
        let rows =
            bench_latency(face, &[Quality::Interactive], &["mouthSmile_L"], 4, true).unwrap();
        assert_eq!(rows.len(), 1);
        assert!(
            rows.iter()
                .all(|r| r.contact && r.samples == 4 && r.errors == 0 && r.median_lists.is_some())
        );
        assert!(table(&rows).contains("| neutral | interactive | on | 4 |"));
    }
}
