//! TLS for the remote protocol and the browser editor (rustls with ring): the server's
//! identity from PEM files (`serve --tls-cert CERT.pem --tls-key KEY.pem`), and a client that
//! trusts a given certificate (`--remote ADDR --tls-ca CERT.pem`), so a session can be used
//! beyond a trusted network without a tunnel. The token still authenticates every client;
//! TLS keeps it, the codes and the frames private and unaltered on the wire.
//!
//! Both sides hand out a [`Duplex`]: a plain socket or TLS over one, read and written as one
//! object (a TLS session cannot be split into two socket clones).

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::sync::Arc;

use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, ServerName};
use rustls::{ClientConfig, ClientConnection, RootCertStore, ServerConfig, ServerConnection};

/// A byte stream both ways: a TCP socket, or TLS over one.
pub trait Duplex: Read + Write + Send {}
impl<T: Read + Write + Send> Duplex for T {}

#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    #[error("reading {path}: {why}")]
    Pem { path: String, why: String },
    #[error("{0} holds no PEM certificate")]
    NoCertificate(String),
    #[error("TLS setup: {0}")]
    Setup(#[from] rustls::Error),
    #[error("{0} is not a host name or IP address a certificate can name")]
    BadName(String),
}

fn pem_error(path: &Path) -> impl Fn(rustls::pki_types::pem::Error) -> TlsError + '_ {
    move |e| TlsError::Pem {
        path: path.display().to_string(),
        why: e.to_string(),
    }
}

/// The certificates of a PEM file (a chain, the server's first).
fn certificates(path: &Path) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let certs = CertificateDer::pem_file_iter(path)
        .map_err(pem_error(path))?
        .collect::<Result<Vec<_>, _>>()
        .map_err(pem_error(path))?;
    if certs.is_empty() {
        return Err(TlsError::NoCertificate(path.display().to_string()));
    }
    Ok(certs)
}

fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// The server's TLS identity: its certificate chain and private key.
#[derive(Clone)]
pub struct ServerTls(Arc<ServerConfig>);

impl std::fmt::Debug for ServerTls {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ServerTls(..)")
    }
}

impl ServerTls {
    /// Loads a PEM certificate chain and its PEM private key (PKCS#8, PKCS#1 or SEC1), and
    /// checks that they belong together.
    pub fn from_pem_files(cert: &Path, key: &Path) -> Result<Self, TlsError> {
        let chain = certificates(cert)?;
        let key = PrivateKeyDer::from_pem_file(key).map_err(pem_error(key))?;
        let config = ServerConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()?
            .with_no_client_auth()
            .with_single_cert(chain, key)?;
        Ok(ServerTls(Arc::new(config)))
    }

    /// TLS over an accepted socket; the handshake runs on the first read, under the socket's
    /// timeouts.
    pub fn accept(&self, stream: TcpStream) -> std::io::Result<Box<dyn Duplex>> {
        let session = ServerConnection::new(self.0.clone()).map_err(std::io::Error::other)?;
        Ok(Box::new(rustls::StreamOwned::new(session, stream)))
    }
}

/// A client's TLS settings: the certificates it trusts for the server.
#[derive(Clone)]
pub struct ClientTls(Arc<ClientConfig>);

impl ClientTls {
    /// Trusts the certificates of a PEM file (the server's own self-signed one, or the CA that
    /// signed it), and nothing else.
    pub fn trusting(ca: &Path) -> Result<Self, TlsError> {
        let mut roots = RootCertStore::empty();
        for cert in certificates(ca)? {
            roots.add(cert)?;
        }
        let config = ClientConfig::builder_with_provider(provider())
            .with_safe_default_protocol_versions()?
            .with_root_certificates(roots)
            .with_no_client_auth();
        Ok(ClientTls(Arc::new(config)))
    }

    /// TLS over a connected socket to `addr` (`host:port`); the certificate must name `host`.
    pub fn connect(&self, addr: &str, stream: TcpStream) -> Result<Box<dyn Duplex>, TlsError> {
        let host = addr
            .rsplit_once(':')
            .map_or(addr, |(host, _)| host)
            .trim_start_matches('[')
            .trim_end_matches(']');
        let name = ServerName::try_from(host.to_string())
            .map_err(|_| TlsError::BadName(host.to_string()))?;
        let session = ClientConnection::new(self.0.clone(), name)?;
        Ok(Box::new(rustls::StreamOwned::new(session, stream)))
    }
}

/// A self-signed certificate and key for `localhost` and `127.0.0.1` in `dir`, made by
/// `scripts/self-signed-cert.sh` as the remote guide says (tests only).
#[cfg(test)]
pub(crate) fn test_identity(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/self-signed-cert.sh");
    let out = std::process::Command::new("sh")
        .arg(script)
        .arg(dir)
        .output()
        .expect("sh");
    assert!(
        out.status.success(),
        "scripts/self-signed-cert.sh (needs openssl): {}",
        String::from_utf8_lossy(&out.stderr)
    );
    (dir.join("cert.pem"), dir.join("key.pem"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_client_trusting_the_certificate_talks_to_the_server_and_others_are_refused() {
        let dir = std::env::temp_dir().join(format!("facesim-tls-{}", std::process::id()));
        let (cert, key) = test_identity(&dir);
        let server = ServerTls::from_pem_files(&cert, &key).unwrap();
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap().to_string();
        std::thread::spawn(move || {
            for stream in listener.incoming().flatten() {
                let mut tls = server.accept(stream).unwrap();
                let mut line = [0u8; 5];
                if tls.read_exact(&mut line).is_ok() {
                    tls.write_all(b"pong\n").unwrap();
                    tls.flush().unwrap();
                }
            }
        });
        let client = ClientTls::trusting(&cert).unwrap();
        let mut tls = client
            .connect(&addr, TcpStream::connect(&addr).unwrap())
            .unwrap();
        tls.write_all(b"ping\n").unwrap();
        let mut reply = [0u8; 5];
        tls.read_exact(&mut reply).unwrap();
        assert_eq!(&reply, b"pong\n");

        // A certificate that names another host, and a client trusting another certificate.
        let wrong_host = format!("localhost.invalid:{}", addr.rsplit_once(':').unwrap().1);
        let mut tls = client
            .connect(&wrong_host, TcpStream::connect(&addr).unwrap())
            .unwrap();
        assert!(tls.write_all(b"ping\n").and_then(|()| tls.flush()).is_err());
        let (other, _) = test_identity(&dir.join("other"));
        let stranger = ClientTls::trusting(&other).unwrap();
        let mut tls = stranger
            .connect(&addr, TcpStream::connect(&addr).unwrap())
            .unwrap();
        assert!(tls.write_all(b"ping\n").and_then(|()| tls.flush()).is_err());

        // Bad files are clear errors.
        assert!(matches!(
            ServerTls::from_pem_files(&key, &key),
            Err(TlsError::NoCertificate(_))
        ));
        assert!(matches!(
            ServerTls::from_pem_files(&cert, &dir.join("missing.pem")),
            Err(TlsError::Pem { .. })
        ));
        let (_, other_key) = (other, dir.join("other/key.pem"));
        assert!(matches!(
            ServerTls::from_pem_files(&cert, &other_key),
            Err(TlsError::Setup(_))
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
