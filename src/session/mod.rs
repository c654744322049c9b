//! The editing session: codes in, simulated frames out, on a worker thread.
//!
//! `Session` owns the simulators of a set of faces and solves on its own thread. Requests
//! (codes, style, face, quality, display) merge into one pending input (latest wins), so a
//! flood of slider moves costs one solve, not one per move. Each solve warm-starts from the
//! last frame's state; when the inputs rest, the frame is refined toward the final preset.
//! The app, the remote server and the exporter all drive this one type.

pub mod client;
pub mod crosses;
pub mod frame;
pub mod handle;
pub mod heatmap;
pub mod protocol;
pub mod server;
pub mod session_face;
pub mod tls;
pub mod token;
pub mod track;
pub mod web;
pub mod wire;
pub mod worker;

pub use frame::{Frame, FrameStats};
pub use handle::SessionHandle;
pub use heatmap::{FieldSource, Legend, ScalarField};
pub use session_face::{FaceTopology, SessionFace};
pub use token::Token;
pub use worker::{Display, Inputs, Request, Session, SessionError};

#[cfg(test)]
pub(crate) mod tests;
