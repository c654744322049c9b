//! The facesim editor: the eframe app, its viewport, and rerun streaming. The session it
//! drives lives in the core library (`facesim::session`).

pub mod app;
pub mod export_rrd;
pub mod faces;
pub mod rerun_log;
pub mod scene;
pub mod viewport;
