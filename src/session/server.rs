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
//! - **TLS when given a certificate** ([`ServerSettings::tls`], [`super::tls`]): the same
//!   protocol inside TLS, for use beyond a trusted network.
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
use super::tls::{Duplex, ServerTls};
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
    /// Serve inside TLS with this identity; plain TCP when `None`.
    pub tls: Option<ServerTls>,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum AccessError {
    #[error(
        "{0} is not a loopback address: serving beyond this machine needs a token you choose \
         and share (--token or $FACESIM_TOKEN), and beyond a trusted network a TLS certificate \
         (--tls-cert and --tls-key) or an SSH tunnel to loopback"
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
            tls: None,
        }
    }

    /// The same settings, served inside TLS with `tls`.
    pub fn with_tls(self, tls: Option<ServerTls>) -> Self {
        ServerSettings { tls, ..self }
    }

    /// The browser page's scheme: `https` inside TLS, else `http`.
    pub fn page_scheme(&self) -> &'static str {
        if self.tls.is_some() { "https" } else { "http" }
    }

    /// Settings for listening on `addrs`: the given token, or a generated one when all are
    /// loopback (module doc). The flag says whether the token was generated (and must be
    /// shown).
    pub fn for_listen(
        addrs: &[SocketAddr],
        given: Option<&str>,
    ) -> Result<(Self, bool), AccessError> {
        match (given, addrs.iter().find(|a| !a.ip().is_loopback())) {
            (Some(text), _) => Ok((ServerSettings::new(Token::new(text)?), false)),
            (None, None) => Ok((ServerSettings::new(Token::generate()), true)),
            (None, Some(public)) => Err(AccessError::PublicWithoutToken(*public)),
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
    accept_each(listener, session, settings, |stream, client| {
        let mut channel = LineChannel {
            stream: BufReader::new(client.secure(stream)?),
            buffer: Vec::new(),
        };
        client.serve(&mut channel)
    })
}

/// Admits each connection of `listener` through a shared [`Gate`] and runs `serve_one` on it
/// on its own thread (a disconnect, timeout or I/O error ends that client only).
pub(crate) fn accept_each(
    listener: TcpListener,
    session: Arc<Session>,
    settings: ServerSettings,
    serve_one: impl Fn(TcpStream, &Client) -> std::io::Result<()> + Send + Sync + 'static,
) -> std::io::Result<()> {
    let gate = Arc::new(Gate::default());
    let settings = Arc::new(settings);
    let serve_one = Arc::new(serve_one);
    for stream in listener.incoming() {
        let Ok(stream) = stream else { continue };
        let Ok(id) = gate.admit(&stream) else {
            continue;
        };
        let client = Client {
            id,
            session: session.clone(),
            settings: settings.clone(),
            gate: gate.clone(),
            control: match stream.try_clone() {
                Ok(c) => c,
                Err(_) => continue,
            },
        };
        let serve_one = serve_one.clone();
        std::thread::spawn(move || {
            let _ = client.prepare().and_then(|()| serve_one(stream, &client));
            client.gate.leave_pending(client.id);
        });
    }
    Ok(())
}

/// One request as a channel delivers it.
pub(crate) enum Incoming {
    Closed,
    TooLong,
    Text(String),
    /// Bytes that are not a UTF-8 text request.
    NotText,
}

/// A client's transport: requests in, replies out (a line protocol or WebSocket messages).
pub(crate) trait Channel {
    fn receive(&mut self) -> std::io::Result<Incoming>;
    fn send(&mut self, reply: &Reply) -> std::io::Result<()>;
}

/// The TCP line protocol: a JSON line per request and per reply, a binary frame's payload
/// right after its reply line.
struct LineChannel {
    /// Requests are read through the buffer; replies are written to the stream beneath it.
    stream: BufReader<Box<dyn Duplex>>,
    buffer: Vec<u8>,
}

impl Channel for LineChannel {
    fn receive(&mut self) -> std::io::Result<Incoming> {
        loop {
            self.buffer.clear();
            let n = self
                .stream
                .by_ref()
                .take(MAX_LINE as u64 + 1)
                .read_until(b'\n', &mut self.buffer)?;
            if n == 0 {
                return Ok(Incoming::Closed);
            }
            if self.buffer.last() != Some(&b'\n') && n > MAX_LINE {
                return Ok(Incoming::TooLong);
            }
            match std::str::from_utf8(&self.buffer) {
                Ok(text) if text.trim().is_empty() => continue,
                Ok(text) => return Ok(Incoming::Text(text.trim().to_string())),
                Err(_) => return Ok(Incoming::NotText),
            }
        }
    }

    fn send(&mut self, reply: &Reply) -> std::io::Result<()> {
        let mut line = serde_json::to_vec(reply).expect("replies serialize");
        line.push(b'\n');
        if let Reply::FrameData { payload, .. } = reply {
            line.extend_from_slice(payload);
        }
        let out = self.stream.get_mut();
        out.write_all(&line)?;
        out.flush()
    }
}

/// Whether an I/O error is a read timeout (the platform says either).
pub(crate) fn timed_out(e: &std::io::Error) -> bool {
    matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut)
}

/// One admitted connection: what it is served from and under which rules.
pub(crate) struct Client {
    id: u64,
    session: Arc<Session>,
    settings: Arc<ServerSettings>,
    gate: Arc<Gate>,
    /// The socket, for its timeouts.
    control: TcpStream,
}

impl Client {
    /// Handshake and write timeouts on the fresh socket.
    fn prepare(&self) -> std::io::Result<()> {
        self.control.set_nodelay(true)?;
        self.control
            .set_read_timeout(Some(self.settings.handshake_timeout))?;
        self.control
            .set_write_timeout(Some(self.settings.write_timeout))
    }

    /// The accepted socket as this server speaks on it: inside TLS when it has a certificate.
    pub(crate) fn secure(&self, stream: TcpStream) -> std::io::Result<Box<dyn Duplex>> {
        match &self.settings.tls {
            Some(tls) => tls.accept(stream),
            None => Ok(Box::new(stream)),
        }
    }

    /// The browser page's scheme ([`ServerSettings::page_scheme`]).
    pub(crate) fn page_scheme(&self) -> &'static str {
        self.settings.page_scheme()
    }

    /// Authenticates the client on `channel`, then answers its requests until it
    /// disconnects or times out.
    pub(crate) fn serve(&self, channel: &mut impl Channel) -> std::io::Result<()> {
        let settings = &self.settings;
        let refuse = |channel: &mut dyn Channel, why: &str| channel.send(&Reply::error(why));
        let first = match channel.receive() {
            Ok(Incoming::Text(text)) => text,
            Ok(Incoming::Closed) => return Ok(()),
            Ok(Incoming::TooLong | Incoming::NotText) => {
                return refuse(channel, "the first request must be a hello with the token");
            }
            Err(e) if timed_out(&e) => {
                let secs = settings.handshake_timeout.as_secs_f64();
                return refuse(channel, &format!("no hello within {secs} s; closing"));
            }
            Err(e) => return Err(e),
        };
        let hello = match serde_json::from_str::<Message>(&first) {
            Ok(Message::Hello { token: Some(token) }) if settings.token.accepts(&token) => {
                Message::Hello { token: None }
            }
            Ok(Message::Hello { token: Some(_) }) => {
                return refuse(channel, "wrong token; closing");
            }
            _ => {
                return refuse(
                    channel,
                    "authenticate first: the first request is {\"op\":\"hello\",\"token\":\"…\"} \
                     with the token the server printed; closing",
                );
            }
        };
        let gate = &self.gate;
        gate.leave_pending(self.id);
        if gate.clients.fetch_add(1, Ordering::SeqCst) >= MAX_CLIENTS {
            gate.clients.fetch_sub(1, Ordering::SeqCst);
            return refuse(
                channel,
                &format!("the server is full ({MAX_CLIENTS} clients)"),
            );
        }
        let _slot = Slot(gate);
        self.control.set_read_timeout(Some(settings.idle_timeout))?;
        let session = &self.session;
        let mut peer = Peer::default();
        channel.send(&handle(session, &mut peer, hello))?;
        loop {
            let reply = match channel.receive() {
                Ok(Incoming::Text(text)) => handle_line(session, &mut peer, &text),
                Ok(Incoming::Closed) => return Ok(()),
                Ok(Incoming::NotText) => Reply::error("a request is JSON text"),
                Ok(Incoming::TooLong) => {
                    return refuse(
                        channel,
                        &format!("request longer than {MAX_LINE} bytes; closing"),
                    );
                }
                Err(e) if timed_out(&e) => {
                    let secs = settings.idle_timeout.as_secs_f64();
                    return refuse(channel, &format!("no request for {secs} s; closing"));
                }
                Err(e) => return Err(e),
            };
            channel.send(&reply)?;
        }
    }
}
