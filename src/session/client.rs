//! The client side of the remote protocol: a [`SessionHandle`] backed by a server.
//!
//! Slider changes merge into a local copy of the inputs (latest wins); one thread sends the
//! changed inputs and polls for frames over a single connection, so a fast-moving slider
//! never queues messages.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::sync::{Arc, Condvar, Mutex};

use super::face::FaceTopology;
use super::frame::Frame;
use super::handle::{FrameObserver, SessionHandle};
use super::protocol::{Entries, FaceInfo, FaceRef, Message, Reply};
use super::worker::{Inputs, Request, apply_requests};
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
    #[error("the server sent a line that is not a reply: {0}")]
    BadReply(String),
    #[error("the server refused: {0}")]
    Refused(String),
}

/// One request/reply round trip.
pub struct Connection {
    out: TcpStream,
    input: BufReader<TcpStream>,
}

impl Connection {
    pub fn open(addr: &str) -> Result<Self, ClientError> {
        let stream = TcpStream::connect(addr).map_err(|source| ClientError::Connect {
            addr: addr.into(),
            source,
        })?;
        stream.set_nodelay(true)?;
        Ok(Connection {
            out: stream.try_clone()?,
            input: BufReader::new(stream),
        })
    }

    pub fn request(&mut self, message: &Message) -> Result<Reply, ClientError> {
        let mut line = serde_json::to_vec(message).expect("messages serialize");
        line.push(b'\n');
        self.out.write_all(&line)?;
        let mut reply = String::new();
        if self.input.read_line(&mut reply)? == 0 {
            return Err(ClientError::Io(std::io::ErrorKind::UnexpectedEof.into()));
        }
        serde_json::from_str(&reply).map_err(|e| ClientError::BadReply(format!("{e}: {reply}")))
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
    pub fn connect(addr: &str) -> Result<Self, ClientError> {
        let mut conn = Connection::open(addr)?;
        let (faces, inputs) = match conn.request(&Message::Hello)? {
            Reply::Hello { faces, inputs, .. } => (faces, *inputs),
            Reply::Error { message } => return Err(ClientError::Refused(message)),
            other => return Err(ClientError::BadReply(format!("{other:?}"))),
        };
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
        let thread_state = state.clone();
        std::thread::Builder::new()
            .name("facesim-remote".into())
            .spawn(move || pump(conn, thread_state))
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
fn pump(mut conn: Connection, state: Arc<(Mutex<State>, Condvar)>) {
    let mut after = None;
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
                timeout_ms: Some(50),
                geometry: Some(true),
            })?;
            if let Reply::Frame { frame } = reply {
                after = Some(frame.index);
                let mut s = state.0.lock().unwrap_or_else(|e| e.into_inner());
                let frame = Arc::new(*frame);
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
    fn submit(&self, requests: &[Request]) -> Result<(), String> {
        let styles: Vec<StyleCode> = self.faces.iter().map(|f| f.default_style).collect();
        let mut s = self.state.0.lock().unwrap_or_else(|e| e.into_inner());
        let inputs = apply_requests(s.inputs, requests, &styles).map_err(|e| e.to_string())?;
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
