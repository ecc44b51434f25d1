//! Frame sources. [`Replay`] reads a recording session folder (DESIGN.md §4): checks it
//! (missing frames or images, wrong sizes, unreadable files) and yields stereo frames in
//! order, either stopping at the first problem with an error naming the file and frame, or
//! counting and logging each bad frame as a gap and going on.
//!
//! Depends on [`crate::camera`].

mod image;
mod replay;

pub use image::{GrayImage, read_png_gray};
pub use replay::{Replay, ReplayParams, ReplayStats, SessionInfo, StereoFrame};

use std::path::PathBuf;

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
        frame: usize,
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
        frame: usize,
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
    /// A frame's image is missing.
    #[error("frame {frame}: missing image {path}")]
    MissingImage {
        /// Frame index.
        frame: usize,
        /// The expected file.
        path: PathBuf,
    },
    /// The calibration file named by the session is invalid.
    #[error(transparent)]
    Calibration(#[from] crate::camera::CalibFileError),
}
