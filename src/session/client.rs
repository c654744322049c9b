//! The client side of the remote protocol: a [`SessionHandle`] backed by a server.
//!
//! Slider changes merge into a local copy of the inputs (latest wins); one thread sends the
//! changed inputs and polls for frames over a single connection, so a fast-moving slider
//! never queues messages.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::sync::{Arc, Condvar, Mutex};

use nalgebra::Point3;

use super::frame::{Frame, vertex_normals};
use super::handle::{FrameObserver, SessionHandle};
use super::protocol::{Encoding, Entries, FaceInfo, FaceRef, Message, Reply};
use super::session_face::FaceTopology;
use super::tls::{ClientTls, Duplex, TlsError};
use super::wire::{QuantizedGeometry, inflate};
use super::worker::{Inputs, Request, SessionError, apply_requests};
use crate::rig::style::StyleCode;

#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("connecting to {addr}: {source}")]
    Connect {
        addr: String,
        source: std::io::Error,
    },
    #[error("talking to the server: {0}")]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Tls(#[from] TlsError),
    #[error("the server sent a line that is not a reply: {0}")]
    BadReply(String),
    #[error("the server refused: {0}")]
    Refused(String),
}

/// Largest binary frame payload accepted, bytes (a full frame of the sample is ~0.3 MB).
pub const MAX_PAYLOAD: usize = 64 << 20;

/// Longest wait for one reply.
pub const REPLY_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(20);

/// One request/reply round trip.
pub struct Connection {
    /// Replies are read through the buffer; requests are written to the stream beneath it.
    stream: BufReader<Box<dyn Duplex>>,
    /// The server is on this machine (deflating frames would cost more than it saves).
    loopback: bool,
}

impl Connection {
    /// Connects to `addr` (`host:port`), inside TLS when `tls` is given (the server's
    /// certificate must then be trusted by it and name `host`).
    pub fn open(addr: &str, tls: Option<&ClientTls>) -> Result<Self, ClientError> {
        let stream = TcpStream::connect(addr).map_err(|source| ClientError::Connect {
            addr: addr.into(),
            source,
        })?;
        stream.set_nodelay(true)?;
        // A server that vanished without closing (half-open) must not hang the editor: no
        // reply takes longer than the longest `get_frame` wait (10 s).
        stream.set_read_timeout(Some(REPLY_TIMEOUT))?;
        let loopback = stream.peer_addr()?.ip().is_loopback();
        let stream: Box<dyn Duplex> = match tls {
            Some(tls) => tls.connect(addr, stream)?,
            None => Box::new(stream),
        };
        Ok(Connection {
            stream: BufReader::new(stream),
            loopback,
        })
    }

    /// The binary encoding worth asking for: deflated unless the server is on loopback
    /// ([`super::wire`]).
    pub fn binary_encoding(&self) -> Encoding {
        if self.loopback {
            Encoding::Binary
        } else {
            Encoding::BinaryDeflate
        }
    }

    /// The connection's first request: `hello` with the session's `token`; the faces and the
    /// session's current inputs, or the server's refusal.
    pub fn hello(&mut self, token: &str) -> Result<(Vec<FaceInfo>, Inputs), ClientError> {
        match self.request(&Message::Hello {
            token: Some(token.to_string()),
        })? {
            Reply::Hello { faces, inputs, .. } => Ok((faces, *inputs)),
            Reply::Error { message } => Err(ClientError::Refused(message)),
            other => Err(ClientError::BadReply(format!("{other:?}"))),
        }
    }

    /// Sends `message` and reads its reply (with a binary frame's payload, inflated when it
    /// came deflated).
    pub fn request(&mut self, message: &Message) -> Result<Reply, ClientError> {
        let mut line = serde_json::to_vec(message).expect("messages serialize");
        line.push(b'\n');
        let out = self.stream.get_mut();
        out.write_all(&line)?;
        out.flush()?;
        let mut text = String::new();
        if self.stream.read_line(&mut text)? == 0 {
            return Err(ClientError::Io(std::io::ErrorKind::UnexpectedEof.into()));
        }
        let mut reply: Reply = serde_json::from_str(&text)
            .map_err(|e| ClientError::BadReply(format!("{e}: {text}")))?;
        if let Reply::FrameData {
            bytes,
            payload,
            deflated,
            ..
        } = &mut reply
        {
            if *bytes > MAX_PAYLOAD {
                return Err(ClientError::BadReply(format!(
                    "a {bytes}-byte frame payload (at most {MAX_PAYLOAD})"
                )));
            }
            payload.resize(*bytes, 0);
            self.stream.read_exact(payload)?;
            if *deflated {
                *payload = inflate(payload, MAX_PAYLOAD)
                    .map_err(|e| ClientError::BadReply(e.to_string()))?;
            }
        }
        Ok(reply)
    }
}

/// Rebuilds whole frames from binary replies ([`super::wire`]), keeping the geometry last
/// decoded as the base of the next delta.
#[derive(Default)]
pub struct FrameAssembler {
    held: Option<QuantizedGeometry>,
}

impl FrameAssembler {
    /// The frame whose geometry this client holds (what `get_frame`'s `base` says).
    pub fn base(&self) -> Option<u64> {
        self.held.as_ref().map(|h| h.index)
    }

    /// `frame` (a `frame_data` reply's) with the geometry of `payload`, and normals from
    /// `topology`'s triangles as the server computes them.
    pub fn assemble(
        &mut self,
        mut frame: Frame,
        payload: &[u8],
        topology: &FaceTopology,
    ) -> Result<Frame, ClientError> {
        let bad = |what: String| ClientError::BadReply(format!("frame {}: {what}", frame.index));
        let geometry = QuantizedGeometry::decode(frame.index, payload, self.held.as_ref());
        // Whatever went wrong, the next request asks for a full frame.
        self.held = None;
        let geometry = geometry.map_err(|e| bad(e.to_string()))?;
        if geometry.positions.len() != topology.rest.len()
            || geometry.fields.len() != frame.heatmaps.len()
        {
            return Err(bad("its geometry does not fit its face's topology".into()));
        }
        frame.positions = geometry.positions_cm();
        let points: Vec<Point3<f64>> = frame
            .positions
            .iter()
            .map(|p| Point3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect();
        frame.normals = vertex_normals(&points, &topology.triangles);
        frame.mesh_positions = geometry.mesh_positions_cm();
        for (k, h) in frame.heatmaps.iter_mut().enumerate() {
            h.values = geometry.field_values(k);
        }
        self.held = Some(geometry);
        Ok(frame)
    }
}

struct State {
    inputs: Inputs,
    dirty: bool,
    latest: Option<Arc<Frame>>,
    status: String,
    notify: Vec<FrameObserver>,
    closed: bool,
}

/// A remote session (module doc).
pub struct RemoteSession {
    addr: String,
    faces: Vec<FaceInfo>,
    topologies: Vec<Arc<FaceTopology>>,
    state: Arc<(Mutex<State>, Condvar)>,
}

impl RemoteSession {
    /// Connects to `addr` (inside TLS with `tls`) and authenticates with `token` (what
    /// `serve` printed).
    pub fn connect(addr: &str, token: &str, tls: Option<&ClientTls>) -> Result<Self, ClientError> {
        let mut conn = Connection::open(addr, tls)?;
        let (faces, inputs) = conn.hello(token)?;
        let mut topologies = Vec::new();
        for f in &faces {
            match conn.request(&Message::GetTopology { face: f.index })? {
                Reply::Topology { topology, .. } => topologies.push(Arc::new(*topology)),
                Reply::Error { message } => return Err(ClientError::Refused(message)),
                other => return Err(ClientError::BadReply(format!("{other:?}"))),
            }
        }
        let state = Arc::new((
            Mutex::new(State {
                inputs,
                dirty: false,
                latest: None,
                status: format!("connected to {addr}"),
                notify: Vec::new(),
                closed: false,
            }),
            Condvar::new(),
        ));
        let (thread_state, thread_topologies) = (state.clone(), topologies.clone());
        std::thread::Builder::new()
            .name("facesim-remote".into())
            .spawn(move || pump(conn, thread_topologies, thread_state))
            .expect("spawning the client thread");
        Ok(RemoteSession {
            addr: addr.into(),
            faces,
            topologies,
            state,
        })
    }
}

impl Drop for RemoteSession {
    fn drop(&mut self) {
        self.state
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .closed = true;
        self.state.1.notify_all();
    }
}

/// Sends changed inputs and fetches frames until the connection or the session closes.
fn pump(
    mut conn: Connection,
    topologies: Vec<Arc<FaceTopology>>,
    state: Arc<(Mutex<State>, Condvar)>,
) {
    let mut after = None;
    let mut assembler = FrameAssembler::default();
    let result = (|| -> Result<(), ClientError> {
        loop {
            let send = {
                let mut s = state.0.lock().unwrap_or_else(|e| e.into_inner());
                if s.closed {
                    return Ok(());
                }
                std::mem::take(&mut s.dirty).then_some(s.inputs)
            };
            if let Some(inputs) = send {
                let messages = [
                    Message::SetFace {
                        face: FaceRef::Index(inputs.face),
                    },
                    Message::SetCodes {
                        expression: Some(Entries::All(inputs.codes.expression.0.to_vec())),
                        style: Some(Entries::All(inputs.codes.style.0.to_vec())),
                    },
                    Message::SetQuality {
                        quality: inputs.quality,
                        refine: Some(inputs.refine),
                        contact: Some(inputs.contact),
                    },
                    Message::SetDisplay {
                        crosses: Some(inputs.display.crosses),
                        heatmaps: Some(inputs.display.heatmaps),
                    },
                ];
                for m in &messages {
                    if let Reply::Error { message } = conn.request(m)? {
                        state.0.lock().unwrap_or_else(|e| e.into_inner()).status =
                            format!("server refused: {message}");
                    }
                }
            }
            let reply = conn.request(&Message::GetFrame {
                after,
                // Requests are answered in order, so changed inputs wait for this: short.
                timeout_ms: Some(20),
                geometry: Some(true),
                encoding: Some(conn.binary_encoding()),
                base: assembler.base(),
            })?;
            if let Reply::FrameData { frame, payload, .. } = reply {
                after = Some(frame.index);
                let Some(topology) = topologies.get(frame.face) else {
                    return Err(ClientError::BadReply(format!(
                        "a frame of face {}",
                        frame.face
                    )));
                };
                let frame = Arc::new(assembler.assemble(*frame, &payload, topology)?);
                let mut s = state.0.lock().unwrap_or_else(|e| e.into_inner());
                s.latest = Some(frame.clone());
                for n in &s.notify {
                    n(&frame);
                }
            }
        }
    })();
    let mut s = state.0.lock().unwrap_or_else(|e| e.into_inner());
    s.status = match result {
        Ok(()) => "closed".into(),
        Err(e) => format!("disconnected: {e}"),
    };
}

impl SessionHandle for RemoteSession {
    fn face_infos(&self) -> Vec<FaceInfo> {
        self.faces.clone()
    }
    fn topology(&self, face: usize) -> Option<Arc<FaceTopology>> {
        self.topologies.get(face).cloned()
    }
    fn inputs(&self) -> Inputs {
        self.state
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .inputs
    }
    fn submit(&self, requests: &[Request]) -> Result<(), SessionError> {
        let styles: Vec<StyleCode> = self.faces.iter().map(|f| f.default_style).collect();
        let mut s = self.state.0.lock().unwrap_or_else(|e| e.into_inner());
        let inputs = apply_requests(s.inputs, requests, &styles)?;
        if inputs != s.inputs {
            s.inputs = inputs;
            s.dirty = true;
        }
        Ok(())
    }
    fn latest(&self) -> Option<Arc<Frame>> {
        self.state
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .latest
            .clone()
    }
    fn on_new_frame(&self, notify: FrameObserver) {
        self.state
            .0
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .notify
            .push(notify);
    }
    fn describe(&self) -> String {
        let s = self.state.0.lock().unwrap_or_else(|e| e.into_inner());
        format!("remote {}: {}", self.addr, s.status)
    }
}
