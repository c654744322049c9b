//! The browser editor in a real browser: the bundled sample served by `session::web` on
//! loopback, driven in Debian's headless Chromium through puppeteer-core
//! (`tests/browser/drive.mjs`): the page connects with the token from its URL, the jawOpen
//! slider moved on the page changes the face the page draws, each heatmap colours it, and a
//! wrong token is refused, and the page works inside TLS (https and wss, a self-signed
//! certificate from `scripts/self-signed-cert.sh`). It
//! prints the latency of a ten-step drag through the page (`--nocapture`).
//! Needs `chromium` (Debian) and `npm ci --prefix tests/browser`.

use std::net::TcpListener;
use std::path::PathBuf;
use std::process::Command;
use std::sync::Arc;

use facesim::sample::Sample;
use facesim::session::server::ServerSettings;
use facesim::session::tls::ServerTls;
use facesim::session::web::serve_web;
use facesim::session::{Session, Token};
use facesim::sim::Quality;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn the_page_edits_the_face_in_headless_chromium() {
    let install = "the browser test needs Node.js, Debian's chromium (or $CHROMIUM) and \
                   puppeteer-core: apt-get install chromium; npm ci --prefix tests/browser";
    let module = root().join("tests/browser/node_modules/puppeteer-core");
    assert!(
        module.exists(),
        "{} is missing; {install}",
        module.display()
    );
    let chromium = std::env::var("CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    assert!(
        PathBuf::from(&chromium).exists(),
        "{chromium} is missing; {install}"
    );

    let sample = Sample::load(root().join(facesim::sample::SAMPLE_DIR)).unwrap();
    let session = Arc::new(Session::new(sample.session_faces(), Quality::Interactive).unwrap());
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let token = Token::generate();
    let settings = ServerSettings::new(token.clone());
    let tls_dir = root().join("target/browser-tls");
    let script = root().join("scripts/self-signed-cert.sh");
    let made = Command::new("sh")
        .arg(&script)
        .arg(&tls_dir)
        .output()
        .unwrap();
    assert!(made.status.success(), "{script:?} needs openssl");
    let tls = ServerTls::from_pem_files(&tls_dir.join("cert.pem"), &tls_dir.join("key.pem"));
    let secure = TcpListener::bind("127.0.0.1:0").unwrap();
    let secure_addr = secure.local_addr().unwrap();
    let secure_settings = settings.clone().with_tls(Some(tls.unwrap()));
    let secure_session = session.clone();
    std::thread::spawn(move || serve_web(secure, secure_session, secure_settings));
    std::thread::spawn(move || serve_web(listener, session, settings));

    let picture = root().join("target/browser-editor.png");
    let out = Command::new("node")
        .arg(root().join("tests/browser/drive.mjs"))
        .arg(format!("http://{addr}/#token={}", token.reveal()))
        .arg(format!("http://{addr}/#token=not-the-token-at-all"))
        .arg(&picture)
        .arg(format!(
            "https://{secure_addr}/#token={}&deflate=1",
            token.reveal()
        ))
        .output()
        .unwrap_or_else(|e| panic!("cannot run `node`: {e}; {install}"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: serde_json::Value =
        serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("{e}: {stdout}"));
    assert!(report.get("failure").is_none(), "{report:#}");
    assert_eq!(report["sliders"], 19 + 4, "{report:#}");
    assert!(
        report["frameAfter"].as_u64() > report["frameBefore"].as_u64(),
        "{report:#}"
    );
    assert!(
        report["movedCm"].as_f64().unwrap() > 0.3,
        "the jaw must move the face: {report:#}"
    );
    assert!(
        report["pixelsChanged"].as_u64().unwrap() > 500,
        "the page must draw the change: {report:#}"
    );
    assert_eq!(report["error"], "", "{report:#}");
    assert_eq!(report["consoleErrors"], serde_json::json!([]), "{report:#}");
    let heatmaps = report["heatmapPixelsChanged"].as_array().unwrap();
    assert!(
        !heatmaps.is_empty() && heatmaps.iter().all(|c| c.as_u64().unwrap() > 500),
        "every heatmap must colour the skin: {report:#}"
    );
    let mut drag: Vec<f64> = report["dragMs"]
        .as_array()
        .unwrap_or_else(|| panic!("{report:#}"))
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(drag.len(), 10, "{report:#}");
    drag.sort_by(f64::total_cmp);
    // Not a speed bound (tests do not time things): the figure, for the remote guide.
    println!(
        "browser drag, slider to frame drawn: median {:.1} ms, max {:.1} ms",
        0.5 * (drag[4] + drag[5]),
        drag[9]
    );
    println!(
        "the last frame's decoding and drawing: {}",
        report["timing"]
    );
    assert!(
        report["refused"].as_str().unwrap().contains("wrong token") && report["loginShown"] == true,
        "{report:#}"
    );
    // The same page inside TLS (serve --tls-cert): https, wss, a frame drawn; deflated frames
    // as off this machine.
    assert_eq!(report["tls"]["protocol"], "https:", "{report:#}");
    assert_eq!(report["tls"]["deflated"], true, "{report:#}");
    assert!(
        report["tls"]["socket"]
            .as_str()
            .unwrap()
            .starts_with("wss://"),
        "{report:#}"
    );
}
