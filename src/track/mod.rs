//! Marker detection in single images, and tracking and labeling of the detections of a
//! stereo pair frame after frame.
//!
//! Depends on [`crate::capture`] (images), [`crate::camera`], [`crate::stereo`],
//! [`crate::align`] and [`crate::dataset`] (marker layouts).

pub mod detect;
pub mod gate;
pub mod label;
mod pieces;
pub mod profile;
mod rim;
pub mod search_windows;
pub mod tracker;

pub use detect::{
    DetectParams, Detection, MarkerDetector, RejectReason, Rejection, detect_markers,
};
pub use gate::{EpipolarGate, EpipolarGateParams};
pub use label::{LabelError, LabelParams, LabelStats, LabeledFrame, LabeledMarker, Labeler};
pub use profile::{CaptureProfile, Polarity, ProfileError};
pub use search_windows::{Rect, SearchWindows};
pub use tracker::{StereoTracker, TrackedFrame};
