//! Remote editing cost (`facesim bench remote`): bytes per frame and slider-to-frame latency
//! of a drag through the remote protocol on loopback, with JSON geometry, with binary deltas
//! ([`crate::session::wire`]) and with deflated binary deltas (what a client off this machine
//! asks for), beside the same drag on the embedded session.
//!
//! One session serves all three in turn (refinement off, so each step's frame is the one the
//! step asked for; contact off, so the frame's solve is the few milliseconds that leave the
//! transport's cost to be seen). A remote step is `set_codes`, then `get_frame` until the frame of that
//! request has arrived and been decoded (binary: normals rebuilt), as the editor's client
//! does. Bytes are those of the reply as sent: the JSON line, and the binary payload after it.
//! Loopback has no bandwidth limit, so on a network the bytes matter more than these times.

use std::net::TcpListener;
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::Serialize;

use super::editor::drag;
use super::{median, percentile};
use crate::session::client::{ClientError, Connection, FrameAssembler};
use crate::session::protocol::{Encoding, Entries, Message, Reply};
use crate::session::server::{ServerSettings, serve};
use crate::session::{Request, Session, SessionError, SessionFace, Token};
use crate::sim::Quality;
use crate::table::Table;

#[derive(Clone, Debug, Serialize)]
pub struct RemoteRow {
    /// `embedded`, `remote json`, `remote binary` or `remote binary deflate`.
    pub transport: String,
    pub samples: usize,
    /// Bytes of one frame's reply (0 for the embedded session).
    pub median_bytes: f64,
    pub max_bytes: usize,
    /// Bytes of the drag's first frame (binary: a full frame, no base yet).
    pub first_bytes: usize,
    pub median_ms: f64,
    pub p95_ms: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum RemoteBenchError {
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error(transparent)]
    Client(#[from] ClientError),
    #[error("starting the loopback server: {0}")]
    Listen(#[from] std::io::Error),
    #[error("the server answered {0}")]
    Unexpected(String),
}

const WAIT: Duration = Duration::from_secs(600);

/// The four rows for a drag of `slider` (0 → 1 → 0 in `steps` moves) on `face`.
pub fn bench_remote(
    face: SessionFace,
    quality: Quality,
    slider: &str,
    steps: usize,
) -> Result<Vec<RemoteRow>, RemoteBenchError> {
    let session = Arc::new(Session::new(vec![face], quality)?);
    session.submit_all(&[Request::Refine(false), Request::Contact(false)])?;
    let timed_out = || SessionError::TimedOut {
        seconds: WAIT.as_secs(),
    };
    session.wait_newer(None, WAIT).ok_or_else(timed_out)?;
    let codes = drag(slider, steps);
    let mut ms = Vec::new();
    for code in &codes {
        let start = Instant::now();
        let g = session.submit(Request::Expression(*code))?;
        session.wait_generation(g, WAIT).ok_or_else(timed_out)?;
        ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    let mut rows = vec![row("embedded", &ms, &[])];

    let listener = TcpListener::bind("127.0.0.1:0")?;
    let addr = listener.local_addr()?.to_string();
    let token = Token::generate();
    let settings = ServerSettings::new(token.clone());
    let served = session.clone();
    std::thread::spawn(move || serve(listener, served, settings));
    let mut conn = Connection::open(&addr, None)?;
    conn.hello(token.reveal())?;
    let unexpected = |r: Reply| RemoteBenchError::Unexpected(format!("{r:?}"));
    let topology = match conn.request(&Message::GetTopology { face: 0 })? {
        Reply::Topology { topology, .. } => topology,
        r => return Err(unexpected(r)),
    };
    for (name, encoding) in [
        ("remote json", Encoding::Json),
        ("remote binary", Encoding::Binary),
        ("remote binary deflate", Encoding::BinaryDeflate),
    ] {
        let mut assembler = FrameAssembler::default();
        let (mut ms, mut bytes) = (Vec::new(), Vec::new());
        let mut after = session.latest().map(|f| f.index);
        for code in &codes {
            let start = Instant::now();
            let generation = match conn.request(&Message::SetCodes {
                expression: Some(Entries::All(code.0.to_vec())),
                style: None,
            })? {
                Reply::Ok { generation } => generation,
                r => return Err(unexpected(r)),
            };
            loop {
                let reply = conn.request(&Message::GetFrame {
                    after,
                    timeout_ms: Some(10_000),
                    geometry: None,
                    encoding: Some(encoding),
                    base: assembler.base(),
                })?;
                let line = serde_json::to_vec(&reply).expect("replies serialize").len() + 1;
                let frame = match reply {
                    Reply::Frame { frame } => {
                        bytes.push(line);
                        *frame
                    }
                    Reply::FrameData {
                        frame,
                        payload,
                        bytes: sent,
                        ..
                    } => {
                        bytes.push(line + sent);
                        assembler.assemble(*frame, &payload, &topology)?
                    }
                    r => return Err(unexpected(r)),
                };
                after = Some(frame.index);
                if frame.generation >= generation {
                    break;
                }
            }
            ms.push(start.elapsed().as_secs_f64() * 1e3);
        }
        rows.push(row(name, &ms, &bytes));
    }
    Ok(rows)
}

fn row(transport: &str, ms: &[f64], bytes: &[usize]) -> RemoteRow {
    let b: Vec<f64> = bytes.iter().map(|&b| b as f64).collect();
    RemoteRow {
        transport: transport.into(),
        samples: ms.len(),
        median_bytes: if b.is_empty() { 0.0 } else { median(&b) },
        max_bytes: bytes.iter().copied().max().unwrap_or(0),
        first_bytes: bytes.first().copied().unwrap_or(0),
        median_ms: median(ms),
        p95_ms: percentile(ms, 0.95),
    }
}

/// A markdown table of `rows`, with each transport's bytes against the JSON's.
pub fn table(rows: &[RemoteRow]) -> String {
    let json = rows
        .iter()
        .find(|r| r.transport == "remote json")
        .map_or(f64::NAN, |r| r.median_bytes);
    let mut t = Table::new(
        &[
            "transport",
            "frames",
            "median bytes/frame",
            "first frame's bytes",
            "max bytes",
            "of JSON's",
            "median ms",
            "p95 ms",
        ],
        "lrrrrrrr",
    );
    for r in rows {
        let share = if r.median_bytes > 0.0 {
            format!("{:.1} %", 100.0 * r.median_bytes / json)
        } else {
            "–".into()
        };
        t.row([
            r.transport.clone(),
            r.samples.to_string(),
            format!("{:.0}", r.median_bytes),
            r.first_bytes.to_string(),
            r.max_bytes.to_string(),
            share,
            format!("{:.1}", r.median_ms),
            format!("{:.1}", r.p95_ms),
        ]);
    }
    t.to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::tests::test_face;

    /// The drag arrives through all encodings, binary frames cost under a tenth of the JSON's
    /// bytes, and deflated ones less again.
    #[test]
    fn a_remote_drag_is_measured_and_binary_frames_are_small() {
        let rows = bench_remote(test_face("a"), Quality::Interactive, "jawOpen", 6).unwrap();
        assert_eq!(rows.len(), 4);
        assert!(rows.iter().all(|r| r.samples == 6 && r.median_ms > 0.0));
        let (json, binary) = (&rows[1], &rows[2]);
        assert!(json.median_bytes > 0.0);
        assert!(
            binary.median_bytes * 10.0 < json.median_bytes,
            "{}",
            table(&rows)
        );
        assert!(
            rows[3].median_bytes < binary.median_bytes,
            "{}",
            table(&rows)
        );
        assert!(table(&rows).contains("| remote binary | 6 |"));
    }
}
