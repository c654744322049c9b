//! `facesim-editor`: the interactive editor (`cargo run --release` at the repository root),
//! and `serve`, the headless session for remote editors and scripts.

use std::net::TcpListener;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use facesim::session::SessionHandle;
use facesim::session::client::RemoteSession;
use facesim::session::server::ServerSettings;
use facesim::session::tls::{ClientTls, ServerTls};
use facesim::sim::Quality;

use facesim_ui::rerun_log::{RerunLogger, RerunTarget};
use facesim_ui::{app, faces};

#[derive(Parser)]
#[command(
    name = "facesim-editor",
    about = "Edit a physically simulated face with expression and style sliders"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// The sample directory to open.
    #[arg(long, default_value = faces::SAMPLE_DIR, global = true)]
    sample: PathBuf,
    /// Talk to a `facesim-editor serve` session at this address instead of simulating here.
    #[arg(long)]
    remote: Option<String>,
    /// With `--remote`: speak TLS and trust this PEM certificate (the server's own, or the CA
    /// that signed it); the certificate must name the host of `--remote`.
    #[arg(long, requires = "remote")]
    tls_ca: Option<PathBuf>,
    /// The remote session's token (`serve` prints it), or set $FACESIM_TOKEN. With `serve`:
    /// the token clients must give (default: a generated one, on loopback only).
    #[arg(long, global = true)]
    token: Option<String>,
    /// Also stream frames to rerun: `spawn`, `connect [URL]` or `save FILE.rrd`.
    #[arg(long, global = true, num_args = 1..=2, value_names = ["MODE", "ARG"])]
    rerun: Vec<String>,
    /// Quality preset to start with (interactive if not given; `export` takes the track's, else final).
    #[arg(long, global = true)]
    quality: Option<Quality>,
    /// What the sliders drive: the fitted per-shape bases or the trained networks.
    #[arg(long, value_enum, default_value_t = faces::Actuation::Basis, global = true)]
    actuation: faces::Actuation,
}

#[derive(Subcommand)]
enum Command {
    /// Run the session headless and serve the remote protocol (README, "Remote mode").
    Serve {
        /// Address to listen on. Beyond loopback it needs `--token` (README, "Remote mode").
        #[arg(long, default_value = "127.0.0.1:7878")]
        listen: String,
        /// Also serve the browser editor (a page and its WebSocket) at this address, e.g.
        /// 127.0.0.1:8080; open the URL it prints.
        #[arg(long)]
        web: Option<String>,
        /// Serve both inside TLS with this PEM certificate (chain), for use beyond a trusted
        /// network (README, "Remote mode"); needs `--tls-key`.
        #[arg(long, requires = "tls_key")]
        tls_cert: Option<PathBuf>,
        /// The certificate's PEM private key.
        #[arg(long, requires = "tls_cert")]
        tls_key: Option<PathBuf>,
    },
    /// Simulate an animation track and write it out: the core formats (usd, pc2, obj, gltf)
    /// plus rrd, a rerun recording (README, "Export"). `--sample` and `--quality` apply.
    Export(facesim_cli::export::ExportArgs),
}

/// Logs every frame of `session` to rerun.
fn attach_rerun(session: &dyn SessionHandle, target: &RerunTarget) -> Result<()> {
    let logger = Arc::new(RerunLogger::new(target)?);
    let topologies: Vec<_> = (0..session.face_infos().len())
        .filter_map(|i| session.topology(i))
        .collect();
    session.on_new_frame(Box::new(move |frame| {
        if let Some(t) = topologies.get(frame.face)
            && let Err(e) = logger.log(frame, t)
        {
            eprintln!("rerun: {e:#}");
        }
    }));
    Ok(())
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let token = cli
        .token
        .clone()
        .or_else(|| std::env::var(facesim::session::token::TOKEN_ENV).ok());
    let rerun = match cli.rerun.as_slice() {
        [] => None,
        words => Some(
            words
                .join("=")
                .parse::<RerunTarget>()
                .map_err(anyhow::Error::msg)?,
        ),
    };
    match cli.command {
        Some(Command::Export(args)) => {
            facesim_cli::export::run(
                &args,
                &cli.sample,
                cli.quality,
                cli.actuation,
                Some(&facesim_ui::export_rrd::RrdFactory),
            )?;
            Ok(())
        }
        Some(Command::Serve {
            listen,
            web,
            tls_cert,
            tls_key,
        }) => {
            let listener =
                TcpListener::bind(&listen).with_context(|| format!("listening on {listen}"))?;
            let addr = listener.local_addr()?;
            let web = match &web {
                Some(w) => {
                    let l = TcpListener::bind(w).with_context(|| format!("listening on {w}"))?;
                    let a = l.local_addr()?;
                    Some((l, a))
                }
                None => None,
            };
            let addrs: Vec<_> = std::iter::once(addr)
                .chain(web.as_ref().map(|w| w.1))
                .collect();
            let (settings, generated) = ServerSettings::for_listen(&addrs, token.as_deref())?;
            let tls = match (&tls_cert, &tls_key) {
                (Some(cert), Some(key)) => Some(ServerTls::from_pem_files(cert, key)?),
                _ => None,
            };
            let secure = tls.is_some();
            let settings = settings.with_tls(tls);
            let session = Arc::new(faces::open_sample_session(
                &cli.sample,
                cli.quality.unwrap_or(Quality::Interactive),
                cli.actuation,
            )?);
            if let Some(t) = &rerun {
                attach_rerun(session.as_ref(), t)?;
            }
            let tls_note = if secure { " (TLS)" } else { "" };
            eprintln!("facesim session listening on {addr}{tls_note}");
            if generated {
                let ca = match &tls_cert {
                    Some(cert) => format!(" --tls-ca {}", cert.display()),
                    None => String::new(),
                };
                eprintln!(
                    "connect with: facesim-editor --remote {addr} --token {}{ca}",
                    settings.token.reveal()
                );
            }
            if let Some((web, web_addr)) = web {
                let fragment = if generated {
                    format!("#token={}", settings.token.reveal())
                } else {
                    "#token=<your token>".into()
                };
                let scheme = settings.page_scheme();
                eprintln!("browser editor: {scheme}://{web_addr}/{fragment}");
                let (session, settings) = (session.clone(), settings.clone());
                std::thread::spawn(move || {
                    facesim::session::web::serve_web(web, session, settings)
                        .map_err(|e| eprintln!("the browser editor stopped: {e}"))
                });
            }
            facesim::session::server::serve(listener, session, settings)?;
            Ok(())
        }
        None => {
            let session: Arc<dyn SessionHandle> = match &cli.remote {
                Some(addr) => {
                    let token = token
                        .context("--remote needs the session's token: --token or $FACESIM_TOKEN")?;
                    let tls = match &cli.tls_ca {
                        Some(ca) => Some(ClientTls::trusting(ca)?),
                        None => None,
                    };
                    Arc::new(RemoteSession::connect(addr, &token, tls.as_ref())?)
                }
                None => Arc::new(faces::open_sample_session(
                    &cli.sample,
                    cli.quality.unwrap_or(Quality::Interactive),
                    cli.actuation,
                )?),
            };
            if let Some(t) = &rerun {
                attach_rerun(session.as_ref(), t)?;
            }
            let options = eframe::NativeOptions {
                viewport: egui::ViewportBuilder::default()
                    .with_title("facesim")
                    .with_inner_size([1400.0, 900.0]),
                ..Default::default()
            };
            eframe::run_native(
                "facesim",
                options,
                Box::new(move |cc| Ok(Box::new(app::EditorApp::new(cc, session)))),
            )
            .map_err(|e| anyhow::anyhow!("the editor window failed: {e}"))
        }
    }
}
