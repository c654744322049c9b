//! The browser editor (`facesim-editor serve --web ADDR`): an HTTP page and a WebSocket on one
//! port, speaking the remote protocol ([`super::protocol`]) with the same rules as the TCP
//! server ([`super::server`]).
//!
//! - `GET /` is the page (`web/index.html`, self-contained: sliders, stats and a WebGL
//!   viewport). It holds no secret: the token travels in the URL's fragment
//!   (`http://ADDR/#token=…`), which the browser never sends to the server, and the page
//!   sends it in its first message.
//! - `GET /ws` upgrades to a WebSocket. Each text message is one request or reply of the
//!   protocol; a `frame_data` reply is followed by one binary message, its payload.
//! - Drive-by protection: the upgrade needs an `Origin` that is this page's own (`http://`,
//!   or `https://` inside TLS, + the `Host` asked for), and on a loopback listener a `Host`
//!   that names loopback (`127.0.0.1`, `localhost`, `[::1]` at this port), so a page of
//!   another site, or one reached through a rebound DNS name, cannot open the socket even
//!   before the token.
//! - Messages are at most [`MAX_LINE`] bytes, and the timeouts, token and client limits are
//!   the TCP server's.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;

use tungstenite::handshake::server::{ErrorResponse, Request, Response};
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message as WsMessage, WebSocket};

use super::protocol::{MAX_LINE, Reply};
use super::server::{Channel, Client, Incoming, ServerSettings, accept_each};
use super::tls::Duplex;
use super::worker::Session;

/// The page, served as is.
pub const PAGE: &str = include_str!("web/index.html");

/// Longest HTTP request head read, bytes.
const MAX_HEAD: usize = 8 * 1024;

/// Serves the page and its WebSocket on `listener` until the process ends.
pub fn serve_web(
    listener: TcpListener,
    session: Arc<Session>,
    settings: ServerSettings,
) -> std::io::Result<()> {
    let local = listener.local_addr()?;
    accept_each(listener, session, settings, move |stream, client| {
        serve_http(stream, local, client)
    })
}

/// An HTTP request head read from a stream (its bytes kept, to hand the WebSocket upgrade to
/// tungstenite as if unread).
struct Head {
    bytes: Vec<u8>,
    /// The request line's path for a GET; `None` for anything else.
    path: Option<String>,
}

/// Reads up to the head's blank line (at most [`MAX_HEAD`] bytes; the read timeout bounds
/// the wait).
fn read_head(stream: &mut dyn Duplex) -> std::io::Result<Head> {
    let mut bytes = Vec::new();
    let mut chunk = [0u8; 1024];
    let end = loop {
        if let Some(end) = bytes.windows(4).position(|w| w == b"\r\n\r\n") {
            break end;
        }
        let n = stream.read(&mut chunk)?;
        if n == 0 || bytes.len() >= MAX_HEAD {
            return Ok(Head { bytes, path: None });
        }
        bytes.extend_from_slice(&chunk[..n]);
    };
    let text = String::from_utf8_lossy(&bytes[..end]);
    let mut words = text.lines().next().unwrap_or("").split_whitespace();
    let path = match (words.next(), words.next()) {
        (Some("GET"), Some(path)) => Some(path.split(['?', '#']).next().unwrap_or("").to_string()),
        _ => None,
    };
    Ok(Head { bytes, path })
}

/// A stream whose first bytes read are `head` (already read from `stream`).
struct Replay {
    head: std::io::Cursor<Vec<u8>>,
    stream: Box<dyn Duplex>,
}

impl Read for Replay {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self.head.read(buf)? {
            0 => self.stream.read(buf),
            n => Ok(n),
        }
    }
}

impl Write for Replay {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.stream.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.flush()
    }
}

fn respond(stream: &mut dyn Duplex, status: &str, kind: &str, body: &[u8]) -> std::io::Result<()> {
    let head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\n\
         Cache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\n\
         Content-Security-Policy: default-src 'none'; script-src 'unsafe-inline'; \
         style-src 'unsafe-inline'; connect-src 'self'\r\nConnection: close\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes())?;
    stream.write_all(body)?;
    stream.flush()
}

fn serve_http(stream: TcpStream, local: SocketAddr, client: &Client) -> std::io::Result<()> {
    let mut stream = client.secure(stream)?;
    let head = read_head(&mut *stream)?;
    let origin = Origin {
        local,
        scheme: client.page_scheme(),
    };
    match head.path.as_deref() {
        Some("/ws") => {
            let stream = Replay {
                head: std::io::Cursor::new(head.bytes),
                stream,
            };
            serve_socket(stream, origin, client)
        }
        Some("/" | "/index.html") => respond(
            &mut *stream,
            "200 OK",
            "text/html; charset=utf-8",
            PAGE.as_bytes(),
        ),
        Some(_) => respond(&mut *stream, "404 Not Found", "text/plain", b"not found\n"),
        None => respond(&mut *stream, "400 Bad Request", "text/plain", b"GET only\n"),
    }
}

/// Where this server's page comes from: the listener's address and the page's scheme.
#[derive(Clone, Copy)]
pub struct Origin {
    pub local: SocketAddr,
    /// `http`, or `https` when served inside TLS.
    pub scheme: &'static str,
}

/// Whether an upgrade request comes from this server's own page (module doc).
pub fn same_origin(request: &Request, origin: Origin) -> Result<(), String> {
    let local = origin.local;
    let header = |name: &str| {
        request
            .headers()
            .get(name)
            .and_then(|v| v.to_str().ok())
            .map(str::to_string)
    };
    let host = header("host").ok_or("no Host header")?;
    if local.ip().is_loopback() {
        let port = local.port();
        let allowed = [
            format!("127.0.0.1:{port}"),
            format!("localhost:{port}"),
            format!("[::1]:{port}"),
        ];
        if !allowed.contains(&host.to_ascii_lowercase()) {
            return Err(format!("Host {host} is not this loopback server"));
        }
    }
    match header("origin") {
        Some(page) if page.eq_ignore_ascii_case(&format!("{}://{host}", origin.scheme)) => Ok(()),
        Some(page) => Err(format!("Origin {page} is not this server's page")),
        None => Err("no Origin header".into()),
    }
}

fn serve_socket(stream: Replay, origin: Origin, client: &Client) -> std::io::Result<()> {
    let config = WebSocketConfig::default()
        .max_message_size(Some(MAX_LINE))
        .max_frame_size(Some(MAX_LINE));
    // The callback's signature is tungstenite's (`Callback`), its error type included.
    #[allow(clippy::result_large_err)]
    let check = |request: &Request, response: Response| -> Result<Response, ErrorResponse> {
        same_origin(request, origin)
            .map(|()| response)
            .map_err(|why| {
                let mut refusal = ErrorResponse::new(Some(why));
                *refusal.status_mut() = tungstenite::http::StatusCode::FORBIDDEN;
                refusal
            })
    };
    let ws = tungstenite::accept_hdr_with_config(stream, check, Some(config))
        .map_err(|e| std::io::Error::other(format!("WebSocket handshake: {e}")))?;
    client.serve(&mut SocketChannel { ws })
}

/// The protocol over WebSocket messages (module doc).
struct SocketChannel {
    ws: WebSocket<Replay>,
}

impl Channel for SocketChannel {
    fn receive(&mut self) -> std::io::Result<Incoming> {
        use tungstenite::Error;
        loop {
            return match self.ws.read() {
                Ok(WsMessage::Text(text)) => Ok(Incoming::Text(text.as_str().trim().to_string())),
                Ok(WsMessage::Binary(_)) => Ok(Incoming::NotText),
                Ok(WsMessage::Close(_)) => Ok(Incoming::Closed),
                Ok(_) => continue, // pings are answered by tungstenite
                Err(Error::ConnectionClosed | Error::AlreadyClosed) => Ok(Incoming::Closed),
                Err(Error::Capacity(_)) => Ok(Incoming::TooLong),
                Err(Error::Io(e)) => Err(e),
                Err(e) => Err(std::io::Error::other(e)),
            };
        }
    }

    fn send(&mut self, reply: &Reply) -> std::io::Result<()> {
        let text = serde_json::to_string(reply).expect("replies serialize");
        let result = self.ws.send(WsMessage::text(text)).and_then(|()| {
            if let Reply::FrameData { payload, .. } = reply {
                self.ws.send(WsMessage::binary(payload.clone()))
            } else {
                Ok(())
            }
        });
        result.map_err(|e| match e {
            tungstenite::Error::Io(e) => e,
            e => std::io::Error::other(e),
        })
    }
}

#[cfg(test)]
mod tests {
    use std::io::{BufRead, BufReader};

    use tungstenite::client::IntoClientRequest;

    use super::*;
    use crate::session::Token;
    use crate::session::tests::test_face;
    use crate::sim::Quality;

    const TOKEN: &str = "a-test-token-0123456789";

    fn server() -> SocketAddr {
        let session = Arc::new(Session::new(vec![test_face("a")], Quality::Interactive).unwrap());
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let settings = ServerSettings::new(Token::new(TOKEN).unwrap());
        std::thread::spawn(move || serve_web(listener, session, settings));
        addr
    }

    fn get(addr: SocketAddr, path: &str) -> (String, String) {
        let mut s = TcpStream::connect(addr).unwrap();
        write!(s, "GET {path} HTTP/1.1\r\nHost: {addr}\r\n\r\n").unwrap();
        let mut reply = String::new();
        BufReader::new(s).read_to_string(&mut reply).unwrap();
        let (head, body) = reply.split_once("\r\n\r\n").unwrap();
        (head.lines().next().unwrap().to_string(), body.to_string())
    }

    fn socket(
        addr: SocketAddr,
        host: &str,
        origin: Option<&str>,
    ) -> Result<WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>, tungstenite::Error> {
        let mut request = format!("ws://{addr}/ws").into_client_request().unwrap();
        request.headers_mut().insert("host", host.parse().unwrap());
        if let Some(o) = origin {
            request.headers_mut().insert("origin", o.parse().unwrap());
        }
        tungstenite::connect(request).map(|(ws, _)| ws)
    }

    #[test]
    fn the_page_is_served_and_nothing_else() {
        let addr = server();
        let (status, body) = get(addr, "/");
        assert_eq!(status, "HTTP/1.1 200 OK");
        assert_eq!(body, PAGE);
        assert!(body.contains("slider-") && body.contains("get_frame"));
        assert_eq!(get(addr, "/index.html#token=x").0, "HTTP/1.1 200 OK");
        assert_eq!(get(addr, "/../Cargo.toml").0, "HTTP/1.1 404 Not Found");
        let mut s = TcpStream::connect(addr).unwrap();
        s.write_all(b"POST / HTTP/1.1\r\n\r\n").unwrap();
        let mut line = String::new();
        BufReader::new(s).read_line(&mut line).unwrap();
        assert!(line.starts_with("HTTP/1.1 400"), "{line}");
    }

    /// The page's own origin gets a socket that speaks the protocol (token first, binary
    /// frames as a text message and a binary one); another site's page, a missing Origin or
    /// a rebound host name get 403 before any message.
    #[test]
    fn only_the_pages_own_origin_opens_the_socket() {
        let addr = server();
        let host = addr.to_string();
        let page = format!("http://{host}");
        let mut ws = socket(addr, &host, Some(&page)).unwrap();
        let ask = |ws: &mut WebSocket<_>, text: &str| {
            ws.send(WsMessage::text(text)).unwrap();
            let reply = ws.read().unwrap();
            serde_json::from_str::<serde_json::Value>(reply.to_text().unwrap()).unwrap()
        };
        let hello = ask(&mut ws, &format!(r#"{{"op":"hello","token":"{TOKEN}"}}"#));
        assert_eq!(hello["reply"], "hello");
        assert_eq!(hello["expression_groups"].as_array().unwrap().len(), 4);
        let frame = ask(
            &mut ws,
            r#"{"op":"get_frame","timeout_ms":5000,"encoding":"binary"}"#,
        );
        assert_eq!(frame["reply"], "frame_data", "{frame}");
        let WsMessage::Binary(payload) = ws.read().unwrap() else {
            panic!("the payload")
        };
        assert_eq!(payload.len() as u64, frame["bytes"].as_u64().unwrap());
        assert_eq!(ask(&mut ws, "{nope")["reply"], "error");

        for (host, origin) in [
            (host.clone(), Some("http://evil.example")),
            (host.clone(), None),
            (
                format!("rebound.example:{}", addr.port()),
                Some(format!("http://rebound.example:{}", addr.port()).as_str()),
            ),
        ] {
            match socket(addr, &host, origin) {
                Err(tungstenite::Error::Http(response)) => {
                    assert_eq!(response.status(), 403, "{host} {origin:?}")
                }
                other => panic!("{host} {origin:?}: {:?}", other.map(|_| "a socket")),
            }
        }
        // The loopback names all work.
        let local = format!("localhost:{}", addr.port());
        assert!(socket(addr, &local, Some(&format!("http://{local}"))).is_ok());
    }

    /// Inside TLS the page comes over https and the socket over wss, and its Origin must be
    /// the https page's.
    #[test]
    fn the_page_and_socket_work_inside_tls() {
        use crate::session::tls::{ClientTls, ServerTls, test_identity};
        let dir = std::env::temp_dir().join(format!("facesim-tls-web-{}", std::process::id()));
        let (cert, key) = test_identity(&dir);
        let session = Arc::new(Session::new(vec![test_face("a")], Quality::Interactive).unwrap());
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let tls = ServerTls::from_pem_files(&cert, &key).unwrap();
        let settings = ServerSettings::new(Token::new(TOKEN).unwrap()).with_tls(Some(tls));
        std::thread::spawn(move || serve_web(listener, session, settings));
        let trust = ClientTls::trusting(&cert).unwrap();
        let host = addr.to_string();
        let open = || {
            trust
                .connect(&host, TcpStream::connect(addr).unwrap())
                .unwrap()
        };

        let mut page = open();
        write!(page, "GET / HTTP/1.1\r\nHost: {host}\r\n\r\n").unwrap();
        page.flush().unwrap();
        let mut reply = Vec::new();
        let _ = page.read_to_end(&mut reply); // the server closes without close_notify
        let reply = String::from_utf8_lossy(&reply);
        assert!(
            reply.starts_with("HTTP/1.1 200 OK") && reply.contains("wss"),
            "{reply}"
        );

        let socket = |origin: &str| {
            let mut request = format!("wss://{host}/ws").into_client_request().unwrap();
            request
                .headers_mut()
                .insert("origin", origin.parse().unwrap());
            // The refusal's HTTP status, if any.
            tungstenite::client(request, open())
                .map(|(ws, _)| ws)
                .map_err(|e| match e {
                    tungstenite::HandshakeError::Failure(tungstenite::Error::Http(r)) => {
                        Some(r.status())
                    }
                    _ => None,
                })
        };
        let mut ws = socket(&format!("https://{host}")).unwrap();
        ws.send(WsMessage::text(format!(
            r#"{{"op":"hello","token":"{TOKEN}"}}"#
        )))
        .unwrap();
        let hello = ws.read().unwrap();
        assert!(hello.to_text().unwrap().contains(r#""reply":"hello""#));
        let refusal = socket(&format!("http://{host}")).map(|_| "a socket");
        assert_eq!(refusal, Err(Some(tungstenite::http::StatusCode::FORBIDDEN)));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_wrong_token_closes_the_socket() {
        let addr = server();
        let host = addr.to_string();
        let mut ws = socket(addr, &host, Some(&format!("http://{host}"))).unwrap();
        ws.send(WsMessage::text(
            r#"{"op":"hello","token":"guess-guess-guess-guess"}"#,
        ))
        .unwrap();
        let reply = ws.read().unwrap();
        assert!(reply.to_text().unwrap().contains("wrong token"));
        assert!(matches!(ws.read(), Err(_) | Ok(WsMessage::Close(_))));
    }
}
