//! The TCP side of the remote protocol: one thread per client, each answering its lines in
//! order against the shared session (see [`super::protocol`]).
//!
//! Safe by default:
//! - **A token.** A client's first line must be `{"op":"hello","token":"…"}` with the
//!   session's [`Token`]; anything else is refused and the connection closed.
//! - **Loopback unless told otherwise.** Listening beyond loopback needs a token the operator
//!   chose ([`ServerSettings::for_listen`]), never only a generated one nobody shared on purpose.
//! - **Timeouts.** A connection that has not authenticated within
//!   [`ServerSettings::handshake_timeout`], a client silent for `idle_timeout` (a half-open one
//!   among them), and a client that does not take a reply within `write_timeout` are closed.
//! - **Idle connections cannot lock anyone out.** At most [`MAX_PENDING`] connections wait to
//!   authenticate; a new one pushes out the oldest, so a client that sends its hello at once
//!   gets in past any number of silent ones. Authenticated clients are at most [`MAX_CLIENTS`].
//! - **Bounded memory per client.** A client's requests are read one line (≤ [`MAX_LINE`]) at
//!   a time and answered before the next is read (a client that does not read its replies
//!   stalls only itself until the write timeout closes it), and setting requests merge into
//!   the session's latest-wins inputs.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::protocol::{MAX_LINE, Message, Peer, Reply, handle, handle_line};
use super::token::{Token, TokenError};
use super::worker::Session;

/// Most authenticated clients served at once; more are told so and closed.
pub const MAX_CLIENTS: usize = 32;
/// Most connections waiting to authenticate; a new one closes the oldest.
pub const MAX_PENDING: usize = 16;

/// Who may talk to the server and how long it waits on them.
#[derive(Clone, Debug)]
pub struct ServerSettings {
    pub token: Token,
    /// A new connection must have sent its hello within this.
    pub handshake_timeout: Duration,
    /// An authenticated client that sends nothing for this long is closed.
    pub idle_timeout: Duration,
    /// A reply the client has not taken within this closes it.
    pub write_timeout: Duration,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AccessError {
    #[error(
        "{0} is not a loopback address: serving beyond this machine needs a token you choose \
         and share (--token or $FACESIM_TOKEN); the protocol is not encrypted, so beyond a \
         trusted network keep it on loopback and reach it through an SSH tunnel"
    )]
    PublicWithoutToken(SocketAddr),
    #[error(transparent)]
    Token(#[from] TokenError),
}

impl ServerSettings {
    /// Default timeouts: 5 s to authenticate, 5 min of silence, 10 s to take a reply.
    pub fn new(token: Token) -> Self {
        ServerSettings {
            token,
            handshake_timeout: Duration::from_secs(5),
            idle_timeout: Duration::from_secs(300),
            write_timeout: Duration::from_secs(10),
        }
    }

    /// Settings for listening on `addr`: the given token, or a generated one on loopback
    /// (module doc). The flag says whether the token was generated (and must be shown).
    pub fn for_listen(addr: SocketAddr, given: Option<&str>) -> Result<(Self, bool), AccessError> {
        match given {
            Some(text) => Ok((ServerSettings::new(Token::new(text)?), false)),
            None if addr.ip().is_loopback() => Ok((ServerSettings::new(Token::generate()), true)),
            None => Err(AccessError::PublicWithoutToken(addr)),
        }
    }
}

/// Connections not yet authenticated, oldest first, and the count of authenticated ones.
#[derive(Default)]
struct Gate {
    pending: Mutex<VecDeque<(u64, TcpStream)>>,
    clients: AtomicUsize,
    next_id: AtomicU64,
}

impl Gate {
    /// Registers a new connection, closing the oldest waiting one when all slots are taken.
    fn admit(&self, stream: &TcpStream) -> std::io::Result<u64> {
        let id = self.next_id.fetch_add(1, Ordering::SeqCst);
        let handle = stream.try_clone()?;
        let mut pending = self.pending.lock().unwrap_or_else(|e| e.into_inner());
        if pending.len() >= MAX_PENDING
            && let Some((_, oldest)) = pending.pop_front()
        {
            let _ = oldest.shutdown(Shutdown::Both);
        }
        pending.push_back((id, handle));
        Ok(id)
    }

    fn leave_pending(&self, id: u64) {
        self.pending
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .retain(|(i, _)| *i != id);
    }
}

/// An authenticated client's slot, given back when its thread ends.
struct Slot<'a>(&'a Gate);

impl Drop for Slot<'_> {
    fn drop(&mut self) {
        self.0.clients.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Serves clients on `listener` until the process ends.
pub fn serve(
    listener: TcpListener,
    session: Arc<Session>,
    settings: ServerSettings,
) -> std::io::Result<()> {
    let gate = Arc::new(Gate::default());
    let settings = Arc::new(settings);
    for stream in listener.incoming() {
        let Ok(stream) = stream else { continue };
        let Ok(id) = gate.admit(&stream) else {
            continue;
        };
        let (session, settings, gate) = (session.clone(), settings.clone(), gate.clone());
        std::thread::spawn(move || {
            // A disconnect, timeout or I/O error ends this client only.
            let _ = serve_client(stream, id, &session, &settings, &gate);
            gate.leave_pending(id);
        });
    }
    Ok(())
}

/// Writes the reply line, and a binary frame's payload after it.
fn send(stream: &mut TcpStream, reply: &Reply) -> std::io::Result<()> {
    let mut line = serde_json::to_vec(reply).expect("replies serialize");
    line.push(b'\n');
    if let Reply::FrameData { payload, .. } = reply {
        line.extend_from_slice(payload);
    }
    stream.write_all(&line)
}

/// One request line as read.
enum Line {
    Closed,
    TooLong,
    Text(String),
    NotUtf8,
}

fn read_line(reader: &mut BufReader<TcpStream>, buffer: &mut Vec<u8>) -> std::io::Result<Line> {
    loop {
        buffer.clear();
        let n = reader
            .by_ref()
            .take(MAX_LINE as u64 + 1)
            .read_until(b'\n', buffer)?;
        if n == 0 {
            return Ok(Line::Closed);
        }
        if buffer.last() != Some(&b'\n') && n > MAX_LINE {
            return Ok(Line::TooLong);
        }
        match std::str::from_utf8(buffer) {
            Ok(text) if text.trim().is_empty() => continue,
            Ok(text) => return Ok(Line::Text(text.trim().to_string())),
            Err(_) => return Ok(Line::NotUtf8),
        }
    }
}

/// Whether an I/O error is a read timeout (the platform says either).
fn timed_out(e: &std::io::Error) -> bool {
    matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut)
}

/// Authenticates one client, then answers its lines until it disconnects or times out.
fn serve_client(
    stream: TcpStream,
    id: u64,
    session: &Session,
    settings: &ServerSettings,
    gate: &Gate,
) -> std::io::Result<()> {
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(settings.handshake_timeout))?;
    stream.set_write_timeout(Some(settings.write_timeout))?;
    let mut out = stream.try_clone()?;
    let mut reader = BufReader::new(stream);
    let mut buffer = Vec::new();
    let refuse = |out: &mut TcpStream, why: &str| send(out, &Reply::error(why));
    let first = match read_line(&mut reader, &mut buffer) {
        Ok(Line::Text(text)) => text,
        Ok(Line::Closed) => return Ok(()),
        Ok(Line::TooLong | Line::NotUtf8) => {
            return refuse(&mut out, "the first request must be a hello with the token");
        }
        Err(e) if timed_out(&e) => {
            let secs = settings.handshake_timeout.as_secs_f64();
            return refuse(&mut out, &format!("no hello within {secs} s; closing"));
        }
        Err(e) => return Err(e),
    };
    let hello = match serde_json::from_str::<Message>(&first) {
        Ok(Message::Hello { token: Some(token) }) if settings.token.accepts(&token) => {
            Message::Hello { token: None }
        }
        Ok(Message::Hello { token: Some(_) }) => {
            return refuse(&mut out, "wrong token; closing");
        }
        _ => {
            return refuse(
                &mut out,
                "authenticate first: the first request is {\"op\":\"hello\",\"token\":\"…\"} \
                 with the token the server printed; closing",
            );
        }
    };
    gate.leave_pending(id);
    if gate.clients.fetch_add(1, Ordering::SeqCst) >= MAX_CLIENTS {
        gate.clients.fetch_sub(1, Ordering::SeqCst);
        return refuse(
            &mut out,
            &format!("the server is full ({MAX_CLIENTS} clients)"),
        );
    }
    let _slot = Slot(gate);
    reader
        .get_ref()
        .set_read_timeout(Some(settings.idle_timeout))?;
    let mut peer = Peer::default();
    send(&mut out, &handle(session, &mut peer, hello))?;
    loop {
        let reply = match read_line(&mut reader, &mut buffer) {
            Ok(Line::Text(text)) => handle_line(session, &mut peer, &text),
            Ok(Line::Closed) => return Ok(()),
            Ok(Line::NotUtf8) => Reply::error("request is not UTF-8"),
            Ok(Line::TooLong) => {
                return refuse(
                    &mut out,
                    &format!("request line longer than {MAX_LINE} bytes; closing"),
                );
            }
            Err(e) if timed_out(&e) => {
                let secs = settings.idle_timeout.as_secs_f64();
                return refuse(&mut out, &format!("no request for {secs} s; closing"));
            }
            Err(e) => return Err(e),
        };
        send(&mut out, &reply)?;
    }
}
