//! Live capture: cameras ([`CameraDevice`]: V4L/AVFoundation/MSMF devices through nokhwa,
//! or a [`TestCamera`] that behaves like one), and [`LiveSource`], which pairs the two
//! cameras' frames and stamps them with the sync box's timecode.
//!
//! # Threads and pairing
//! Each camera runs on its own thread (`helmcap:cam0`, `helmcap:cam1`) that grabs frames
//! as fast as the camera delivers them and hands them over through a bounded queue
//! ([`LiveParams::camera_queue`] frames). When the consumer falls behind and a queue is
//! full, the new frame is dropped and counted ([`CameraStats::overflow`]). [`LiveSource`]
//! takes the oldest frame of each camera; two frames captured within
//! [`LiveParams::pair_tolerance`] of a frame interval of each other form a stereo frame,
//! otherwise the older one has no partner (its twin was lost) and is dropped and counted.
//!
//! # Frame index and gaps
//! The first stereo frame is index 0; each next one advances by the number of frame
//! intervals between their capture times (rounded, at least 1), so a frame a camera failed
//! to deliver leaves a hole in the indices and is counted in [`FrameSource::gaps`](crate::capture::FrameSource::gaps): every
//! index up to the last one is either delivered or counted.
//!
//! # Timecode
//! While the sync box is healthy, frames are stamped from its latest line (see
//! [`super::syncbox`]); otherwise from the local clock, which free-runs from the last sync
//! line (or, if the box was never heard, from the host's time of day, UTC). Each switch is
//! logged once and counted, and every frame's clock is counted.
//!
//! # A camera that stops
//! A camera that reports its device gone, or delivers nothing for
//! [`LiveParams::camera_lost_ms`], ends the source with [`CaptureError::CameraLost`](crate::capture::CaptureError::CameraLost) naming
//! it. One camera alone cannot triangulate, so going on would record a take the pipeline
//! cannot use while looking healthy; the operator is better served by a clear stop, with
//! everything up to the last stereo frame recorded and valid, and can restart at once.
//! Short stalls (under the timeout) and bad frames only leave counted gaps.
//!
//! The parts: the camera interface and the nokhwa driver (`device`), the test camera and
//! its patterns (`test_camera`), [`LiveSource`] (`source`), and the `configs/live.toml`
//! reader (`config`).

mod config;
mod device;
mod source;
mod test_camera;

pub use config::{
    LiveConfig, MAX_BAUD, MAX_CAMERA_SIDE_PX, MAX_FRAME_DELAY_MS, MAX_WRITERS, RecordConfig,
    TestSourceConfig, TimecodeConfig,
};
pub use device::{
    CameraConfig, CameraDevice, CameraError, CapturedImage, NokhwaCamera, PixelFormat,
};
pub use source::{
    CameraStats, LiveFrame, LiveParams, LiveSource, LiveStats, LiveTimecode, StampClock,
};
pub use test_camera::{TestCamera, TestFaults, TestImages, test_pattern};
