//! What a viewer needs of a session, local or remote: the app draws either through this.

use std::sync::Arc;

use super::frame::Frame;
use super::protocol::FaceInfo;
use super::session_face::FaceTopology;
use super::worker::{Inputs, Request, Session, SessionError};

/// A callback run with each new frame.
pub type FrameObserver = Box<dyn Fn(&Arc<Frame>) + Send + Sync>;

pub trait SessionHandle: Send + Sync {
    fn face_infos(&self) -> Vec<FaceInfo>;
    fn topology(&self, face: usize) -> Option<Arc<FaceTopology>>;
    /// The inputs as requested so far (what the sliders show).
    fn inputs(&self) -> Inputs;
    /// Applies `requests` (latest wins); the error says why nothing changed.
    fn submit(&self, requests: &[Request]) -> Result<(), SessionError>;
    fn latest(&self) -> Option<Arc<Frame>>;
    /// Called (from another thread) with every new frame, e.g. to repaint or to log it.
    fn on_new_frame(&self, notify: FrameObserver);
    /// A line for the status bar: "embedded" or the server's address and state.
    fn describe(&self) -> String;
}

impl SessionHandle for Session {
    fn face_infos(&self) -> Vec<FaceInfo> {
        self.faces()
            .iter()
            .enumerate()
            .map(|(index, f)| FaceInfo {
                index,
                name: f.name.clone(),
                identity: f.identity,
                default_style: f.default_style,
            })
            .collect()
    }
    fn topology(&self, face: usize) -> Option<Arc<FaceTopology>> {
        Session::topology(self, face)
    }
    fn inputs(&self) -> Inputs {
        Session::inputs(self)
    }
    fn submit(&self, requests: &[Request]) -> Result<(), SessionError> {
        self.submit_all(requests).map(|_| ())
    }
    fn latest(&self) -> Option<Arc<Frame>> {
        Session::latest(self)
    }
    fn on_new_frame(&self, notify: FrameObserver) {
        self.on_frame(move |f| notify(f));
    }
    fn describe(&self) -> String {
        "embedded session".into()
    }
}
