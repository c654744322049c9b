//! The remote protocol: line-delimited JSON over TCP (`facesim-editor serve`).
//!
//! Every line a client sends is one JSON object with an `"op"`; every line gets exactly one
//! reply line, in order. The first line of a connection is `hello` with the session's token
//! ([`super::server`] refuses anything else). Replies are `{"reply":"ok","generation":N}`,
//! `{"reply":"error","message":"…"}` (the request changed nothing), or the data asked for.
//!
//! | op | fields | reply |
//! |---|---|---|
//! | `hello` | `token` (first request only) | `hello`: protocol version, faces, code names and ranges, current inputs |
//! | `set_codes` | `expression`: 19 weights or `{name: weight}` (others keep); `style`: 4 values or `{name: value}` | `ok` |
//! | `set_face` | `face`: index or name (the style resets to the face's default) | `ok` |
//! | `set_quality` | `quality`: `interactive`/`preview`/`final`; optional `refine`, `contact`: bool | `ok` |
//! | `set_display` | optional `crosses`, `heatmaps`: bool (overlays the frames carry) | `ok` |
//! | `get_frame` | optional `after` (frame index: wait for a newer one), `timeout_ms` (≤ 10000, default 2000), `geometry` (default true), `encoding` (`json`/`binary`/`binary_deflate`), `base` (binary: the frame the client holds) | `frame`, or `frame_data` and its binary payload (deflated on request) (or `error` on timeout) |
//! | `get_topology` | `face`: index | `topology`: triangles (without the eyes' see-through layers), rigid flags, base colours, mesh edges, rest positions |
//!
//! Expression weights must lie in [0, 1] and style values in [-1, 1] (the sliders' ranges);
//! everything must be finite. Lines are at most [`MAX_LINE`] bytes. Setting requests merge
//! into the session's pending inputs (latest wins), so a flood of them costs one solve.

use std::collections::BTreeMap;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use super::frame::Frame;
use super::session_face::FaceTopology;
use super::wire::QuantizedGeometry;
use super::worker::{Display, Inputs, Request, Session};
use crate::rig::ExpressionCode;
use crate::rig::style::StyleCode;
use crate::sim::Quality;

pub const PROTOCOL_VERSION: u32 = 2;
/// Longest accepted request line, bytes.
pub const MAX_LINE: usize = 64 * 1024;
const MAX_WAIT_MS: u64 = 10_000;

/// Code entries, all in order or some by name.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Entries {
    All(Vec<f64>),
    Named(BTreeMap<String, f64>),
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum FaceRef {
    Index(usize),
    Name(String),
}

/// A client's request (module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case", deny_unknown_fields)]
pub enum Message {
    /// The first request of every connection, with the session's token (the server refuses
    /// anything else first); later hellos need none.
    Hello {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        token: Option<String>,
    },
    SetCodes {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        expression: Option<Entries>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        style: Option<Entries>,
    },
    SetFace {
        face: FaceRef,
    },
    SetQuality {
        quality: Quality,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        refine: Option<bool>,
        /// Lip and teeth contact in the solve.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        contact: Option<bool>,
    },
    SetDisplay {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        crosses: Option<bool>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        heatmaps: Option<bool>,
    },
    GetFrame {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        after: Option<u64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        timeout_ms: Option<u64>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        geometry: Option<bool>,
        /// How the geometry travels (default JSON).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        encoding: Option<Encoding>,
        /// Binary only: the frame whose binary geometry this client holds (the server sends
        /// a delta on it when it is the last one it sent this connection).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        base: Option<u64>,
    },
    GetTopology {
        face: usize,
    },
}

/// How a frame's geometry travels: in the JSON reply, or as a binary payload after it
/// ([`super::wire`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Encoding {
    Json,
    Binary,
    /// Binary, its payload deflated ([`super::wire::deflate`]): for slow links.
    BinaryDeflate,
}

/// What `hello` says about a face.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FaceInfo {
    pub index: usize,
    pub name: String,
    pub identity: Option<usize>,
    pub default_style: StyleCode,
}

/// A server's reply (module doc).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "reply", rename_all = "snake_case")]
pub enum Reply {
    Hello {
        version: u32,
        faces: Vec<FaceInfo>,
        expression_names: Vec<String>,
        /// The sliders grouped as the editors show them: `(group, names)`.
        #[serde(default)]
        expression_groups: Vec<(String, Vec<String>)>,
        style_names: Vec<String>,
        inputs: Box<Inputs>,
    },
    Ok {
        generation: u64,
    },
    Frame {
        frame: Box<Frame>,
    },
    /// A frame whose geometry (positions, mesh positions, heatmap values; normals left for
    /// the client) follows the reply line as `bytes` bytes of [`super::wire`] payload.
    FrameData {
        frame: Box<Frame>,
        /// The payload's length as sent.
        bytes: usize,
        /// The payload as sent is deflated (asked for with `binary_deflate`).
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        deflated: bool,
        #[serde(skip)]
        payload: Vec<u8>,
    },
    Topology {
        face: usize,
        topology: Box<FaceTopology>,
    },
    Error {
        message: String,
    },
}

impl Reply {
    pub fn error(message: impl Into<String>) -> Self {
        Reply::Error {
            message: message.into(),
        }
    }
}

/// What the server remembers of one connection: the binary geometry it last sent, the base
/// of the next delta.
#[derive(Default)]
pub struct Peer {
    sent: Option<QuantizedGeometry>,
}

/// Parses and answers one request line against `session`.
pub fn handle_line(session: &Session, peer: &mut Peer, line: &str) -> Reply {
    match serde_json::from_str::<Message>(line) {
        Ok(m) => handle(session, peer, m),
        Err(e) => Reply::error(format!("malformed request: {e}")),
    }
}

/// `frame` with its geometry moved into a binary payload, a delta on what `peer` holds when
/// the client says it holds it.
fn binary_frame(peer: &mut Peer, mut frame: Frame, base: Option<u64>, deflated: bool) -> Reply {
    let fields: Vec<&[f32]> = frame.heatmaps.iter().map(|h| h.values.as_slice()).collect();
    let geometry = match QuantizedGeometry::new(
        frame.index,
        &frame.positions,
        &frame.mesh_positions,
        &fields,
    ) {
        Ok(g) => g,
        Err(e) => return Reply::error(format!("frame {}: {e}", frame.index)),
    };
    let held = peer.sent.as_ref().filter(|s| Some(s.index) == base);
    let mut payload = geometry.encode(held);
    if deflated {
        payload = super::wire::deflate(&payload);
    }
    peer.sent = Some(geometry);
    frame.positions.clear();
    frame.normals.clear();
    frame.mesh_positions.clear();
    for h in &mut frame.heatmaps {
        h.values.clear();
    }
    Reply::FrameData {
        frame: Box::new(frame),
        bytes: payload.len(),
        deflated,
        payload,
    }
}

fn entries(
    e: &Entries,
    names: &[&'static str],
    range: (f64, f64),
    what: &str,
) -> Result<Vec<(usize, f64)>, String> {
    let pairs: Vec<(usize, &str, f64)> = match e {
        Entries::All(v) => {
            if v.len() != names.len() {
                return Err(format!(
                    "{what} needs {} values, got {}",
                    names.len(),
                    v.len()
                ));
            }
            v.iter()
                .enumerate()
                .map(|(i, x)| (i, names[i], *x))
                .collect()
        }
        Entries::Named(m) => m
            .iter()
            .map(|(k, x)| {
                names
                    .iter()
                    .position(|n| n == k)
                    .map(|i| (i, names[i], *x))
                    .ok_or_else(|| {
                        format!("unknown {what} entry '{k}' (known: {})", names.join(", "))
                    })
            })
            .collect::<Result<_, _>>()?,
    };
    for (_, name, x) in &pairs {
        if !x.is_finite() || *x < range.0 || *x > range.1 {
            return Err(format!(
                "{what} entry {name} = {x} is outside [{}, {}]",
                range.0, range.1
            ));
        }
    }
    Ok(pairs.into_iter().map(|(i, _, x)| (i, x)).collect())
}

/// Answers one parsed request.
pub fn handle(session: &Session, peer: &mut Peer, message: Message) -> Reply {
    let submit = |requests: Vec<Request>| match session.submit_all(&requests) {
        Ok(generation) => Reply::Ok { generation },
        Err(e) => Reply::error(e.to_string()),
    };
    match message {
        Message::Hello { .. } => Reply::Hello {
            version: PROTOCOL_VERSION,
            faces: session
                .faces()
                .iter()
                .enumerate()
                .map(|(index, f)| FaceInfo {
                    index,
                    name: f.name.clone(),
                    identity: f.identity,
                    default_style: f.default_style,
                })
                .collect(),
            expression_names: ExpressionCode::NAMES
                .iter()
                .map(|s| s.to_string())
                .collect(),
            expression_groups: ExpressionCode::GROUPS
                .iter()
                .map(|(g, names)| (g.to_string(), names.iter().map(|n| n.to_string()).collect()))
                .collect(),
            style_names: StyleCode::NAMES.iter().map(|s| s.to_string()).collect(),
            inputs: Box::new(session.inputs()),
        },
        Message::SetCodes { expression, style } => {
            let mut requests = Vec::new();
            if let Some(e) = &expression {
                match entries(e, &ExpressionCode::NAMES, (0.0, 1.0), "expression") {
                    Ok(v) => requests.push(Request::ExpressionEntries(v)),
                    Err(m) => return Reply::error(m),
                }
            }
            if let Some(s) = &style {
                match entries(s, &StyleCode::NAMES, StyleCode::RANGE, "style") {
                    Ok(v) => requests.push(Request::StyleEntries(v)),
                    Err(m) => return Reply::error(m),
                }
            }
            if requests.is_empty() {
                return Reply::error("set_codes needs `expression` and/or `style`");
            }
            submit(requests)
        }
        Message::SetFace { face } => {
            let index = match &face {
                FaceRef::Index(i) => Some(*i),
                FaceRef::Name(n) => session.faces().iter().position(|f| &f.name == n),
            };
            match index {
                Some(i) => submit(vec![Request::Face(i)]),
                None => Reply::error(format!(
                    "no face {face:?} (faces: {})",
                    session
                        .faces()
                        .iter()
                        .map(|f| f.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )),
            }
        }
        Message::SetQuality {
            quality,
            refine,
            contact,
        } => {
            let mut r = vec![Request::Quality(quality)];
            r.extend(refine.map(Request::Refine));
            r.extend(contact.map(Request::Contact));
            submit(r)
        }
        Message::SetDisplay { crosses, heatmaps } => {
            let now = session.inputs().display;
            submit(vec![Request::Display(Display {
                crosses: crosses.unwrap_or(now.crosses),
                heatmaps: heatmaps.unwrap_or(now.heatmaps),
            })])
        }
        Message::GetFrame {
            after,
            timeout_ms,
            geometry,
            encoding,
            base,
        } => {
            let wait = timeout_ms.unwrap_or(2000);
            if wait > MAX_WAIT_MS {
                return Reply::error(format!(
                    "timeout_ms {wait} is over the limit of {MAX_WAIT_MS}"
                ));
            }
            match session.wait_newer(after, Duration::from_millis(wait)) {
                Some(f)
                    if geometry != Some(false)
                        && matches!(encoding, Some(Encoding::Binary | Encoding::BinaryDeflate)) =>
                {
                    let deflated = encoding == Some(Encoding::BinaryDeflate);
                    binary_frame(peer, (*f).clone(), base, deflated)
                }
                Some(f) => {
                    let mut frame = (*f).clone();
                    if geometry == Some(false) {
                        frame.positions.clear();
                        frame.normals.clear();
                        frame.mesh_positions.clear();
                        frame.crosses.clear();
                        frame.heatmaps.clear();
                    }
                    Reply::Frame {
                        frame: Box::new(frame),
                    }
                }
                None => Reply::error(format!("no new frame within {wait} ms")),
            }
        }
        Message::GetTopology { face } => match session.topology(face) {
            Some(t) => Reply::Topology {
                face,
                topology: Box::new((*t).clone()),
            },
            None => Reply::error(format!(
                "face {face} is out of range: the session has {} faces",
                session.faces().len()
            )),
        },
    }
}
