//! `facesim-editor serve` as the remote guide runs it: with a certificate from
//! `scripts/self-signed-cert.sh` it speaks TLS, prints the command that connects (token and
//! `--tls-ca`), and a remote session trusting the certificate edits the face; a plain client
//! gets nowhere, and a certificate without its key is refused before anything loads.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use facesim::rig::ExpressionCode;
use facesim::session::client::RemoteSession;
use facesim::session::tls::ClientTls;
use facesim::session::{Request, SessionHandle};

/// Kills the server when the test ends, passed or not.
struct Server(std::process::Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn serve_with_a_certificate_speaks_tls_to_clients_that_trust_it() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let dir = std::env::temp_dir().join(format!("facesim-serve-tls-{}", std::process::id()));
    let made = Command::new("sh")
        .arg(root.join("scripts/self-signed-cert.sh"))
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        made.status.success(),
        "scripts/self-signed-cert.sh needs openssl"
    );
    let (cert, key) = (dir.join("cert.pem"), dir.join("key.pem"));
    let editor = env!("CARGO_BIN_EXE_facesim-editor");

    let refused = Command::new(editor)
        .current_dir(&root)
        .args(["serve", "--tls-cert"])
        .arg(&cert)
        .output()
        .unwrap();
    assert!(!refused.status.success());
    assert!(String::from_utf8_lossy(&refused.stderr).contains("--tls-key"));

    let mut server = Server(
        Command::new(editor)
            .current_dir(&root)
            .args(["serve", "--listen", "127.0.0.1:0", "--tls-cert"])
            .arg(&cert)
            .arg("--tls-key")
            .arg(&key)
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    // "connect with: facesim-editor --remote ADDR --token TOKEN --tls-ca CERT"
    let mut lines = BufReader::new(server.0.stderr.take().unwrap()).lines();
    let said = lines
        .by_ref()
        .map(|l| l.unwrap())
        .find(|l| l.starts_with("connect with:"))
        .expect("serve prints how to connect");
    let words: Vec<&str> = said.split_whitespace().collect();
    let after = |flag: &str| words[words.iter().position(|w| *w == flag).unwrap() + 1];
    let (addr, token) = (after("--remote"), after("--token"));
    assert_eq!(PathBuf::from(after("--tls-ca")), cert);

    assert!(RemoteSession::connect(addr, token, None).is_err());
    let trust = ClientTls::trusting(&cert).unwrap();
    let session = RemoteSession::connect(addr, token, Some(&trust)).unwrap();
    assert!(!session.face_infos().is_empty());
    let jaw = ExpressionCode::single("jawOpen", 0.5).unwrap();
    session.submit(&[Request::Expression(jaw)]).unwrap();
    let start = Instant::now();
    while !session
        .latest()
        .is_some_and(|f| f.codes.expression.get("jawOpen") == Some(0.5))
    {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "no jawOpen frame over TLS"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
