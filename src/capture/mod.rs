//! Frame sources. [`Replay`] reads a recording session folder (DESIGN.md §4): checks it
//! (missing frames or images, wrong sizes, unreadable files) and yields stereo frames in
//! order, either stopping at the first problem with an error naming the file and frame, or
//! counting and logging each bad frame as a gap and going on. [`LiveSource`] pairs two live
//! cameras' frames ([`live`]) and stamps them with the timecode of the serial sync box
//! ([`syncbox`]); [`Recorder`] writes a session folder from them ([`recorder`]).
//!
//! Depends on [`crate::camera`].

mod image;
pub mod live;
pub mod recorder;
mod replay;
pub mod syncbox;
pub mod video;

pub use image::{
    GrayConversion, GrayImage, ImageReadError, MAX_IMAGE_BYTES, MAX_IMAGE_SIDE_PX, decode_gray,
    read_gray, read_png_gray,
};
pub use live::{LiveConfig, LiveFrame, LiveSource, LiveStats, StampClock};
pub use recorder::{RecordReport, Recorder, RecorderParams};
pub use replay::{Replay, ReplayParams, ReplayStats, SessionInfo, StereoFrame};

use std::path::PathBuf;

use crate::camera::StereoRig;
use crate::frame_index::FrameIndex;

/// A source of stereo frames for the pipeline: a replayed recording or live cameras.
pub trait FrameSource: Send {
    /// The next frame; `None` at the end of input (or when a live source was stopped).
    fn next_frame(&mut self) -> Option<Result<StereoFrame, CaptureError>>;
    /// Camera frames per second.
    fn fps(&self) -> f64;
    /// A live source runs on its own clock: the pipeline drops (and counts) its frames
    /// when downstream falls behind instead of blocking it. A replay is never dropped.
    fn is_live(&self) -> bool;
    /// The stereo calibration, when the source knows it.
    fn rig(&self) -> Option<&StereoRig>;
    /// Frames lost or skipped at the source so far (bad frames of a replay, frames a
    /// camera failed to deliver).
    fn gaps(&self) -> usize;
}

impl FrameSource for Replay {
    fn next_frame(&mut self) -> Option<Result<StereoFrame, CaptureError>> {
        Replay::next_frame(self)
    }

    fn fps(&self) -> f64 {
        self.info().fps
    }

    fn is_live(&self) -> bool {
        false
    }

    fn rig(&self) -> Option<&StereoRig> {
        Replay::rig(self)
    }

    fn gaps(&self) -> usize {
        self.stats().gaps
    }
}

/// Errors of the frame sources; each names the file and, where it applies, the frame.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// A file or folder of the session is missing or unreadable.
    #[error("{path}: {message}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// `session.toml` or `frames.csv` is invalid.
    #[error("{path}:{line}: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// 1-based line (0: the whole file).
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// An image cannot be decoded.
    #[error("frame {frame}: {path}: cannot decode image: {message}")]
    Decode {
        /// Frame index.
        frame: FrameIndex,
        /// The image file.
        path: PathBuf,
        /// Decoder message.
        message: String,
    },
    /// An image's size differs from the calibration's.
    #[error(
        "frame {frame}: {path}: image is {width}×{height}, the calibration expects {expected_width}×{expected_height}"
    )]
    Size {
        /// Frame index.
        frame: FrameIndex,
        /// The image file.
        path: PathBuf,
        /// Found width.
        width: u32,
        /// Found height.
        height: u32,
        /// Expected width.
        expected_width: u32,
        /// Expected height.
        expected_height: u32,
    },
    /// A video of the session ended before the frame (shorter than its container
    /// declares); no later frame can be read either.
    #[error(
        "frame {frame}: {path}: the video ended after {decoded} frames (it declares {declared})"
    )]
    VideoEnded {
        /// Frame index.
        frame: FrameIndex,
        /// The video file.
        path: PathBuf,
        /// Frames decoded before the end.
        decoded: usize,
        /// Frames the container declares.
        declared: usize,
    },
    /// A frame's image is missing.
    #[error("frame {frame}: missing image {path}")]
    MissingImage {
        /// Frame index.
        frame: FrameIndex,
        /// The expected file.
        path: PathBuf,
    },
    /// A live device (camera, sync box) cannot be opened or used.
    #[error("{device}: {message}")]
    Device {
        /// The device, e.g. `cam0 (device 0)`.
        device: String,
        /// What went wrong.
        message: String,
    },
    /// A camera stopped delivering frames (unplugged, stalled past the timeout).
    #[error("camera {camera} lost: {message}")]
    CameraLost {
        /// The camera.
        camera: String,
        /// What happened.
        message: String,
    },
    /// The calibration file named by the session is invalid.
    #[error(transparent)]
    Calibration(#[from] crate::camera::CalibFileError),
}
