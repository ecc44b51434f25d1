//! Marker detection in single images (tracking and labeling build on it).
//!
//! Depends on [`crate::capture`] (images) and [`crate::camera`].

pub mod detect;

pub use detect::{DetectParams, Detection, detect_markers};
