//! A camera without hardware: [`TestCamera`] plays a recording session or a synthetic
//! pattern ([`test_pattern`]) at real-time pace, with injected faults ([`TestFaults`]).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use super::device::{CameraDevice, CameraError, CapturedImage};
use crate::capture::{GrayConversion, GrayImage, read_gray};

/// Where a [`TestCamera`]'s images come from.
#[derive(Debug, Clone, PartialEq)]
pub enum TestImages {
    /// `<session>/<camera>/NNNNNN.png` for frames `0..frames` of a recording session.
    Session {
        /// Session folder.
        root: PathBuf,
        /// Camera folder name.
        camera: String,
        /// Number of frames.
        frames: usize,
    },
    /// A synthetic pattern whose pixels encode the frame and the camera ([`test_pattern`]).
    Pattern {
        /// Width, pixels.
        width: u32,
        /// Height, pixels.
        height: u32,
        /// Number of frames.
        frames: usize,
        /// Camera number (0 or 1), part of the pattern.
        camera: u8,
    },
}

impl TestImages {
    fn frames(&self) -> usize {
        match self {
            Self::Session { frames, .. } | Self::Pattern { frames, .. } => *frames,
        }
    }
}

/// The image of frame `frame` of test pattern camera `camera`: a gradient plus the frame
/// number and camera in the first row's first eight bytes (little-endian index, then the
/// camera), so tests can tell every frame apart.
pub fn test_pattern(width: u32, height: u32, frame: usize, camera: u8) -> GrayImage {
    let mut data: Vec<u8> = (0..height)
        .flat_map(|y| {
            (0..width).map(move |x| ((x + 2 * y) as usize + 3 * frame + 50 * camera as usize) as u8)
        })
        .collect();
    let tag = (frame as u64).to_le_bytes();
    for (d, t) in data.iter_mut().zip(tag.iter().take(7).chain([&camera])) {
        *d = *t;
    }
    GrayImage {
        width,
        height,
        data,
    }
}

/// Faults a [`TestCamera`] injects, by frame number.
#[derive(Debug, Clone, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct TestFaults {
    /// Frames delivered corrupt ([`CameraError::BadFrame`]).
    pub corrupt: Vec<usize>,
    /// `[first, count]`: the camera stalls, frames `first..first+count` never come.
    pub stall: Option<[usize; 2]>,
    /// The device disappears before this frame ([`CameraError::Lost`]).
    pub vanish_at: Option<usize>,
}

/// A camera for tests and demonstrations without hardware: frames at `fps` real-time pace
/// from `start` (frame `i` is due at `start + i / fps` and stamped with that time, as a
/// hardware-triggered camera would be), from a recording or a pattern, with injected
/// faults.
#[derive(Debug)]
pub struct TestCamera {
    name: String,
    images: TestImages,
    fps: f64,
    start: Instant,
    next: usize,
    faults: TestFaults,
}

impl TestCamera {
    /// A test camera; give both cameras of a pair the same `start`.
    pub fn new(
        name: &str,
        images: TestImages,
        fps: f64,
        start: Instant,
        faults: TestFaults,
    ) -> Self {
        Self {
            name: name.to_string(),
            images,
            fps,
            start,
            next: 0,
            faults,
        }
    }

    fn image(&self, frame: usize) -> Result<GrayImage, CameraError> {
        match &self.images {
            TestImages::Session { root, camera, .. } => read_gray(
                &root.join(camera).join(format!("{frame:06}.png")),
                GrayConversion::Luma,
            )
            .map_err(|e| CameraError::BadFrame(e.to_string())),
            TestImages::Pattern {
                width,
                height,
                camera,
                ..
            } => Ok(test_pattern(*width, *height, frame, *camera)),
        }
    }
}

impl CameraDevice for TestCamera {
    fn name(&self) -> &str {
        &self.name
    }

    fn grab(&mut self) -> Result<CapturedImage, CameraError> {
        loop {
            let i = self.next;
            if i >= self.images.frames() {
                return Err(CameraError::Ended);
            }
            if self.faults.vanish_at == Some(i) {
                return Err(CameraError::Lost(format!(
                    "{} vanished before frame {i}",
                    self.name
                )));
            }
            let due = self.start + Duration::from_nanos((i as f64 * 1e9 / self.fps).round() as u64);
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
            self.next += 1;
            if let Some([first, count]) = self.faults.stall
                && (first..first + count).contains(&i)
            {
                continue;
            }
            if self.faults.corrupt.contains(&i) {
                return Err(CameraError::BadFrame(format!(
                    "frame {i} is corrupt (injected)"
                )));
            }
            return Ok(CapturedImage {
                image: self.image(i)?,
                captured_at: due,
            });
        }
    }
}
