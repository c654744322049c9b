//! The TCP side of the remote protocol: one thread per client, each answering its lines in
//! order against the shared session (see [`super::protocol`]).
//!
//! Nothing queues without bound: a client's requests are read one at a time and answered
//! before the next is read (a client that does not read its replies stalls only itself), and
//! setting requests merge into the session's latest-wins inputs.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use super::protocol::{MAX_LINE, Reply, handle_line};
use super::worker::Session;

/// Most clients served at once; more are told so and closed.
pub const MAX_CLIENTS: usize = 32;

/// Serves clients on `listener` until the process ends.
pub fn serve(listener: TcpListener, session: Arc<Session>) -> std::io::Result<()> {
    let clients = Arc::new(AtomicUsize::new(0));
    for stream in listener.incoming() {
        let Ok(mut stream) = stream else { continue };
        if clients.fetch_add(1, Ordering::SeqCst) >= MAX_CLIENTS {
            clients.fetch_sub(1, Ordering::SeqCst);
            let _ = send(
                &mut stream,
                &Reply::error(format!("the server is full ({MAX_CLIENTS} clients)")),
            );
            continue;
        }
        let (session, clients) = (session.clone(), clients.clone());
        std::thread::spawn(move || {
            // A disconnect or I/O error ends this client only.
            let _ = serve_client(stream, &session);
            clients.fetch_sub(1, Ordering::SeqCst);
        });
    }
    Ok(())
}

fn send(stream: &mut TcpStream, reply: &Reply) -> std::io::Result<()> {
    let mut line = serde_json::to_vec(reply).expect("replies serialize");
    line.push(b'\n');
    stream.write_all(&line)
}

/// Answers one client's lines until it disconnects.
pub fn serve_client(stream: TcpStream, session: &Session) -> std::io::Result<()> {
    stream.set_nodelay(true)?;
    let mut out = stream.try_clone()?;
    let mut reader = BufReader::new(stream);
    let mut line = Vec::new();
    loop {
        line.clear();
        let n = reader
            .by_ref()
            .take(MAX_LINE as u64 + 1)
            .read_until(b'\n', &mut line)?;
        if n == 0 {
            return Ok(());
        }
        if line.last() != Some(&b'\n') && n > MAX_LINE {
            send(
                &mut out,
                &Reply::error(format!(
                    "request line longer than {MAX_LINE} bytes; closing"
                )),
            )?;
            return Ok(());
        }
        let reply = match std::str::from_utf8(&line) {
            Ok(text) if text.trim().is_empty() => continue,
            Ok(text) => handle_line(session, text.trim()),
            Err(_) => Reply::error("request is not UTF-8"),
        };
        send(&mut out, &reply)?;
    }
}
