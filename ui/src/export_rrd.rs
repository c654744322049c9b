//! `facesim-editor export … --format rrd`: the core exporter (`facesim::export`) with one more
//! writer, a rerun recording of the frames (the editor's [`RerunLogger`]), which the core
//! library cannot write because it does not link rerun.

use std::path::Path;

use facesim::export::{ExportError, Format, FrameSink, SinkFactory};
use facesim::session::{FaceTopology, Frame};

use crate::rerun_log::{RerunLogger, RerunTarget};

/// Frames into an `.rrd` (entities as the editor logs them; `frame` timeline = frame number,
/// `time` timeline = the track's time in seconds).
pub struct RrdSink {
    logger: RerunLogger,
    topology: FaceTopology,
    fps: f64,
}

fn writer_error(e: anyhow::Error) -> ExportError {
    ExportError::Writer {
        format: Format::Rrd,
        reason: format!("{e:#}"),
    }
}

impl FrameSink for RrdSink {
    fn frame(&mut self, index: usize, frame: &Frame) -> Result<(), ExportError> {
        self.logger
            .log_at(
                frame,
                &self.topology,
                index as i64,
                Some(index as f64 / self.fps),
            )
            .map_err(writer_error)
    }

    fn finish(self: Box<Self>) -> Result<(), ExportError> {
        let this = *self;
        this.logger.flush();
        drop(this); // closes the file before it is renamed
        Ok(())
    }
}

/// Adds `rrd` to the core formats.
pub struct RrdFactory;

impl SinkFactory for RrdFactory {
    fn create(
        &self,
        format: Format,
        temp: &Path,
        topology: &FaceTopology,
        _frames: usize,
        fps: f64,
    ) -> Result<Option<Box<dyn FrameSink>>, ExportError> {
        if format != Format::Rrd {
            return Ok(None);
        }
        let logger =
            RerunLogger::new(&RerunTarget::Save(temp.to_path_buf())).map_err(writer_error)?;
        Ok(Some(Box::new(RrdSink {
            logger,
            topology: topology.clone(),
            fps,
        })))
    }
}
