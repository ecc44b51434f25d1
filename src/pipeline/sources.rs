//! Frame source adapters for benchmarks and tests: [`PacedSource`] delivers another
//! source's frames on a live camera's clock (and lets the pipeline drop them), and
//! [`LoopSource`] repeats a few frames held in memory for a soak run of any length.

use std::time::{Duration, Instant};

use crate::camera::StereoRig;
use crate::capture::{CaptureError, FrameSource, StereoFrame};

/// Delivers the frames of an inner source no faster than `fps`, as a camera would: frame
/// `k` becomes available at `start + k / fps`, and the source reports itself as live, so
/// the pipeline drops frames instead of blocking it when it falls behind.
pub struct PacedSource {
    inner: Box<dyn FrameSource>,
    fps: f64,
    start: Option<Instant>,
    delivered: u64,
}

impl PacedSource {
    /// Paces `inner` at `fps` frames per second.
    pub fn new(inner: Box<dyn FrameSource>, fps: f64) -> Self {
        Self {
            inner,
            fps,
            start: None,
            delivered: 0,
        }
    }
}

impl FrameSource for PacedSource {
    fn next_frame(&mut self) -> Option<Result<StereoFrame, CaptureError>> {
        // Read (decode) first, then wait for the frame's time: a camera delivers a
        // finished image at its exposure time.
        let frame = self.inner.next_frame()?;
        let start = *self.start.get_or_insert_with(Instant::now);
        let due = start + Duration::from_secs_f64(self.delivered as f64 / self.fps);
        let now = Instant::now();
        if due > now {
            std::thread::sleep(due - now);
        }
        self.delivered += 1;
        Some(frame)
    }

    fn fps(&self) -> f64 {
        self.fps
    }

    fn is_live(&self) -> bool {
        true
    }

    fn rig(&self) -> Option<&StereoRig> {
        self.inner.rig()
    }

    fn gaps(&self) -> usize {
        self.inner.gaps()
    }
}

/// Repeats `frames` (held in memory) until `total` frames were delivered, numbering them
/// consecutively and advancing the timestamps at `fps`; timecodes are dropped.
pub struct LoopSource {
    frames: Vec<StereoFrame>,
    fps: f64,
    total: usize,
    next: usize,
    rig: Option<StereoRig>,
}

impl LoopSource {
    /// Reads every frame of `inner` into memory, to be repeated up to `total` frames.
    ///
    /// # Errors
    /// The first error of `inner`.
    pub fn new(mut inner: Box<dyn FrameSource>, total: usize) -> Result<Self, CaptureError> {
        let mut frames = Vec::new();
        while let Some(f) = inner.next_frame() {
            frames.push(f?);
        }
        Ok(Self::from_frames(
            frames,
            inner.fps(),
            total,
            inner.rig().cloned(),
        ))
    }

    /// Repeats `frames` at `fps` up to `total` frames.
    pub fn from_frames(
        frames: Vec<StereoFrame>,
        fps: f64,
        total: usize,
        rig: Option<StereoRig>,
    ) -> Self {
        Self {
            frames,
            fps,
            total,
            next: 0,
            rig,
        }
    }
}

impl FrameSource for LoopSource {
    fn next_frame(&mut self) -> Option<Result<StereoFrame, CaptureError>> {
        if self.next >= self.total || self.frames.is_empty() {
            return None;
        }
        let src = &self.frames[self.next % self.frames.len()];
        let frame = StereoFrame {
            index: self.next.into(),
            timestamp_ns: (self.next as f64 * 1e9 / self.fps) as u64,
            timecode: None,
            images: src.images.clone(),
        };
        self.next += 1;
        Some(Ok(frame))
    }

    fn fps(&self) -> f64 {
        self.fps
    }

    fn is_live(&self) -> bool {
        false
    }

    fn rig(&self) -> Option<&StereoRig> {
        self.rig.as_ref()
    }

    fn gaps(&self) -> usize {
        0
    }
}
