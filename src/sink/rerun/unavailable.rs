//! The rerun sink of a build without the viewer SDK (cargo feature `rerun` off): every
//! option exists, and opening a recording is a clear error.

use super::{RerunFrame, RerunParams, RerunSession, RerunSinkError, RerunStats, RerunTarget};
use crate::pipeline::{FrameResult, Metrics, SessionMeta, Sink, SinkError};

/// Stands for the rerun sink in a build without the SDK: [`RerunSink::new`] checks the
/// parameters and answers [`RerunSinkError::NotBuilt`]; no value of it can exist.
#[derive(Debug)]
pub struct RerunSink {
    never: std::convert::Infallible,
}

impl RerunSink {
    /// Checks `params`, then fails: the SDK is not built in.
    ///
    /// # Errors
    /// [`RerunSinkError::Params`] for bad parameters, otherwise
    /// [`RerunSinkError::NotBuilt`].
    pub fn new(_target: RerunTarget, params: RerunParams) -> Result<Self, RerunSinkError> {
        params.validate()?;
        Err(RerunSinkError::NotBuilt)
    }

    /// Where the log goes (never called: no sink exists).
    pub fn target(&self) -> &RerunTarget {
        match self.never {}
    }

    /// Counts of what was logged (never called: no sink exists).
    pub fn stats(&self) -> RerunStats {
        match self.never {}
    }

    /// Logs the static data (never called: no sink exists).
    ///
    /// # Errors
    /// None: no sink exists.
    pub fn begin_session(&mut self, _session: &RerunSession) -> Result<(), RerunSinkError> {
        match self.never {}
    }

    /// Logs a frame (never called: no sink exists).
    ///
    /// # Errors
    /// None: no sink exists.
    pub fn log_frame(&mut self, _frame: &RerunFrame<'_>) -> Result<(), RerunSinkError> {
        match self.never {}
    }

    /// Closes the recording (never called: no sink exists).
    ///
    /// # Errors
    /// None: no sink exists.
    pub fn finish(&mut self) -> Result<RerunStats, RerunSinkError> {
        match self.never {}
    }
}

impl Sink for RerunSink {
    fn name(&self) -> &str {
        match self.never {}
    }

    fn begin(&mut self, _session: &SessionMeta) -> Result<(), SinkError> {
        match self.never {}
    }

    fn write(&mut self, _frame: &FrameResult) -> Result<(), SinkError> {
        match self.never {}
    }

    fn finish(&mut self, _metrics: &Metrics) -> Result<(), SinkError> {
        match self.never {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opening_a_recording_says_the_sdk_is_missing() {
        let err = RerunSink::new(RerunTarget::Spawn, RerunParams::default()).unwrap_err();
        assert!(matches!(err, RerunSinkError::NotBuilt), "{err}");
        assert!(err.to_string().contains("`rerun` feature"), "{err}");
        let bad = RerunParams {
            image_downscale: 0,
            ..RerunParams::default()
        };
        let err = RerunSink::new(RerunTarget::Spawn, bad).unwrap_err();
        assert!(matches!(err, RerunSinkError::Params(_)), "{err}");
    }
}
