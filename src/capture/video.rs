//! Video files as camera streams (DESIGN.md §4, "Recording session": `[video]`), decoded by
//! OpenCV's videoio with its FFmpeg backend: any container and codec the installed FFmpeg
//! reads (tested: FFV1 in Matroska, lossless). Frame N is the N-th decoded frame; its
//! timestamp is the container's presentation time (`CAP_PROP_POS_MSEC`). The timecode
//! track, where the container has one, is read with `ffprobe` when it is installed
//! ([`probe_timecode`]).

use std::path::{Path, PathBuf};

use opencv::core::{Mat, MatTraitConst};
use opencv::prelude::*;
use opencv::videoio;

use super::{CaptureError, GrayConversion, GrayImage};
use crate::limits::MAX_FRAME_NUMBER;

/// The pixels of one decoded video frame, 8 bits per sample.
#[derive(Debug, Clone, PartialEq)]
pub enum VideoPixels {
    /// Grey, one byte per pixel (every pixel of the frame had R = G = B, or the decoder
    /// delivered one channel).
    Gray(Vec<u8>),
    /// RGB, three bytes per pixel.
    Rgb(Vec<u8>),
}

/// One decoded video frame.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoFrame {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// The pixels, row by row.
    pub pixels: VideoPixels,
    /// Presentation time in the container, ns (the nominal `index / fps` when the container
    /// gives none).
    pub timestamp_ns: u64,
}

impl VideoFrame {
    /// The frame as 8-bit grey; colour through `conversion`.
    pub fn into_gray(self, conversion: GrayConversion) -> GrayImage {
        let data = match self.pixels {
            VideoPixels::Gray(g) => g,
            VideoPixels::Rgb(rgb) => rgb
                .chunks_exact(3)
                .map(|p| conversion.convert([p[0], p[1], p[2]]))
                .collect(),
        };
        GrayImage {
            width: self.width,
            height: self.height,
            data,
        }
    }
}

/// Reads one video file frame by frame.
pub struct VideoReader {
    path: PathBuf,
    capture: videoio::VideoCapture,
    fps: f64,
    frame_count: usize,
    width: u32,
    height: u32,
    position: usize,
    mat: Mat,
}

impl std::fmt::Debug for VideoReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VideoReader")
            .field("path", &self.path)
            .field("fps", &self.fps)
            .field("frame_count", &self.frame_count)
            .field("width", &self.width)
            .field("height", &self.height)
            .field("position", &self.position)
            .finish_non_exhaustive()
    }
}

fn video_err(path: &Path, message: impl std::fmt::Display) -> CaptureError {
    CaptureError::Io {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

fn open_capture(path: &Path) -> Result<videoio::VideoCapture, CaptureError> {
    if !path.is_file() {
        return Err(video_err(path, "video file is missing"));
    }
    let name = path
        .to_str()
        .ok_or_else(|| video_err(path, "the path is not valid UTF-8"))?;
    let capture = videoio::VideoCapture::from_file(name, videoio::CAP_FFMPEG)
        .map_err(|e| video_err(path, format!("cannot open as a video: {e}")))?;
    if !capture.is_opened().unwrap_or(false) {
        return Err(video_err(
            path,
            "cannot open as a video (not a container and codec the FFmpeg backend of OpenCV reads)",
        ));
    }
    Ok(capture)
}

impl VideoReader {
    /// Opens a video file and reads its frame rate, size and frame count (from the
    /// container; counted by decoding when the container does not say).
    ///
    /// # Errors
    /// [`CaptureError::Io`] naming the file: missing, unreadable, or without frames or
    /// frame rate.
    pub fn open(path: &Path) -> Result<Self, CaptureError> {
        let capture = open_capture(path)?;
        let get = |prop: i32| capture.get(prop).unwrap_or(f64::NAN);
        let fps = get(videoio::CAP_PROP_FPS);
        if !(fps.is_finite() && fps > 0.0) {
            return Err(video_err(path, "the video has no frame rate"));
        }
        let (w, h) = (
            get(videoio::CAP_PROP_FRAME_WIDTH),
            get(videoio::CAP_PROP_FRAME_HEIGHT),
        );
        if !(w >= 1.0 && h >= 1.0 && w <= 65535.0 && h <= 65535.0) {
            return Err(video_err(
                path,
                format!("the video's frame size {w}×{h} is invalid"),
            ));
        }
        // A decoded frame is at most three bytes a pixel: the image limits hold for video
        // frames too, checked before the first frame is decoded.
        super::image::check_size(w as u32, h as u32, 3)
            .map_err(|e| video_err(path, format!("the video's frames: {e}")))?;
        let most_frames = MAX_FRAME_NUMBER as usize + 1;
        let declared = get(videoio::CAP_PROP_FRAME_COUNT);
        let frame_count = if declared.is_finite() && declared >= 1.0 {
            if declared > most_frames as f64 {
                return Err(video_err(
                    path,
                    format!(
                        "the container declares {declared} frames, more than the \
                         {most_frames} a recording may have"
                    ),
                ));
            }
            declared.round() as usize
        } else {
            // The container does not say: count by decoding (once, on a second reader).
            let mut counter = open_capture(path)?;
            let mut n = 0usize;
            while counter.grab().unwrap_or(false) {
                n += 1;
                if n > most_frames {
                    return Err(video_err(
                        path,
                        format!(
                            "the video has more than the {most_frames} frames a recording may have"
                        ),
                    ));
                }
            }
            n
        };
        if frame_count == 0 {
            return Err(video_err(path, "the video has no frames"));
        }
        Ok(Self {
            path: path.to_path_buf(),
            capture,
            fps,
            frame_count,
            width: w as u32,
            height: h as u32,
            position: 0,
            mat: Mat::default(),
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Frames per second (the container's).
    pub fn fps(&self) -> f64 {
        self.fps
    }

    /// Frames in the video (the container's figure).
    pub fn frame_count(&self) -> usize {
        self.frame_count
    }

    /// Frame size, pixels.
    pub fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    /// The next frame to be decoded.
    pub fn position(&self) -> usize {
        self.position
    }

    fn ended(&self, index: usize) -> CaptureError {
        CaptureError::VideoEnded {
            frame: index.into(),
            path: self.path.clone(),
            decoded: self.position,
            declared: self.frame_count,
        }
    }

    /// Decodes frame `index` (frames before it are skipped; a frame already passed cannot
    /// be read again).
    ///
    /// # Errors
    /// [`CaptureError::VideoEnded`] when the video ended before it; [`CaptureError::Decode`]
    /// naming the file and frame when it was passed already or the decoder failed.
    pub fn read_at(&mut self, index: usize) -> Result<VideoFrame, CaptureError> {
        let decode_err = |message: String| CaptureError::Decode {
            frame: index.into(),
            path: self.path.clone(),
            message,
        };
        if index < self.position {
            return Err(decode_err(format!(
                "frame {index} was passed already (the reader is at frame {})",
                self.position
            )));
        }
        while self.position < index {
            let grabbed = self.capture.grab().map_err(|e| decode_err(e.to_string()))?;
            if !grabbed {
                return Err(self.ended(index));
            }
            self.position += 1;
        }
        let read = self
            .capture
            .read(&mut self.mat)
            .map_err(|e| decode_err(e.to_string()))?;
        if !read || self.mat.empty() {
            return Err(self.ended(index));
        }
        self.position += 1;
        let msec = self
            .capture
            .get(videoio::CAP_PROP_POS_MSEC)
            .unwrap_or(f64::NAN);
        let timestamp_ns = if msec.is_finite() && msec >= 0.0 {
            (msec * 1e6).round() as u64
        } else {
            (index as f64 * 1e9 / self.fps).round() as u64
        };
        let (width, height) = (self.mat.cols() as u32, self.mat.rows() as u32);
        let channels = self.mat.channels();
        if self.mat.depth() != opencv::core::CV_8U || !(channels == 1 || channels == 3) {
            return Err(decode_err(format!(
                "decoded a frame of OpenCV type {}, expected 8-bit grey or BGR",
                self.mat.typ()
            )));
        }
        let bytes = if self.mat.is_continuous() {
            self.mat
                .data_bytes()
                .map_err(|e| decode_err(e.to_string()))?
        } else {
            return Err(decode_err("decoded frame is not contiguous".into()));
        };
        if bytes.len() != width as usize * height as usize * channels as usize {
            return Err(decode_err(format!(
                "decoded {} bytes for {width}×{height} pixels",
                bytes.len()
            )));
        }
        let pixels = if channels == 1 {
            VideoPixels::Gray(bytes.to_vec())
        } else if let Some(grey) = grey_of_bgr(bytes) {
            VideoPixels::Gray(grey)
        } else {
            VideoPixels::Rgb(
                bytes
                    .chunks_exact(3)
                    .flat_map(|p| [p[2], p[1], p[0]])
                    .collect(),
            )
        };
        Ok(VideoFrame {
            width,
            height,
            pixels,
            timestamp_ns,
        })
    }
}

/// The grey level of each BGR pixel when every pixel has B = G = R (a grey video, decoded
/// to BGR), else None. One pass, sixteen pixels at a time from fixed-size arrays (a grey
/// 1280×1024 frame: 0.7-0.9 ms, against 2.2-3.1 ms for a check of every pixel, then a
/// copy of one channel, then a copy of that).
fn grey_of_bgr(bgr: &[u8]) -> Option<Vec<u8>> {
    const PIXELS: usize = 16;
    let mut grey = vec![0u8; bgr.len() / 3];
    let mut colour = 0u8;
    let (blocks, rest) = bgr.as_chunks::<{ 3 * PIXELS }>();
    let (grey_blocks, grey_rest) = grey.as_chunks_mut::<PIXELS>();
    for (block, out) in blocks.iter().zip(grey_blocks.iter_mut()) {
        for (i, level) in out.iter_mut().enumerate() {
            let (b, g, r) = (block[3 * i], block[3 * i + 1], block[3 * i + 2]);
            colour |= (b ^ g) | (g ^ r);
            *level = g;
        }
    }
    for (p, level) in rest.chunks_exact(3).zip(grey_rest.iter_mut()) {
        colour |= (p[0] ^ p[1]) | (p[1] ^ p[2]);
        *level = p[1];
    }
    (colour == 0).then_some(grey)
}

/// Opens the two videos of a stereo pair and checks that they match: the same frame rate,
/// length and frame size.
///
/// # Errors
/// [`CaptureError::Io`] naming the file that cannot be read or differs from the first.
pub fn open_pair(video0: &Path, video1: &Path) -> Result<[VideoReader; 2], CaptureError> {
    let a = VideoReader::open(video0)?;
    let b = VideoReader::open(video1)?;
    if (a.fps() - b.fps()).abs() > 1e-6 * a.fps() {
        return Err(video_err(
            b.path(),
            format!(
                "the video runs at {} fps, {} at {} fps: the two videos of a session must \
                 have the same frame rate",
                b.fps(),
                a.path().display(),
                a.fps()
            ),
        ));
    }
    if a.frame_count() != b.frame_count() {
        return Err(video_err(
            b.path(),
            format!(
                "the video has {} frames, {} has {}: the two videos of a session must have \
                 the same length",
                b.frame_count(),
                a.path().display(),
                a.frame_count()
            ),
        ));
    }
    if a.size() != b.size() {
        let (w, h) = b.size();
        let (ew, eh) = a.size();
        return Err(video_err(
            b.path(),
            format!("the video is {w}×{h}, {} is {ew}×{eh}", a.path().display()),
        ));
    }
    Ok([a, b])
}

/// The start timecode of a video's timecode track (or container tag), e.g. `01:00:00:00`,
/// read with `ffprobe`; `None` when the file has none or `ffprobe` is not installed.
pub fn probe_timecode(path: &Path) -> Option<String> {
    let out = std::process::Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-show_entries",
            "format_tags=timecode:stream_tags=timecode",
            "-of",
            "default=noprint_wrappers=1:nokey=1",
        ])
        .arg(path)
        .stdin(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .output();
    let out = match out {
        Ok(o) if o.status.success() => o,
        Ok(_) => return None,
        Err(e) => {
            tracing::debug!(
                "ffprobe not run ({e}): no container timecode for {}",
                path.display()
            );
            return None;
        }
    };
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(str::trim)
        .find(|l| {
            l.len() >= 11
                && l.split([':', ';', '.'])
                    .all(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()))
        })
        .map(str::to_string)
}

/// Whether `ffprobe` can be run.
pub fn ffprobe_available() -> bool {
    std::process::Command::new("ffprobe")
        .arg("-version")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_grey_frame_decoded_to_bgr_gives_its_levels_and_any_colour_gives_none() {
        // 16 pixels a block: 100 pixels leave 4 outside the blocks.
        for pixels in [0, 5, 16, 100] {
            let levels: Vec<u8> = (0..pixels).map(|i| (i * 37 % 251) as u8).collect();
            let bgr: Vec<u8> = levels.iter().flat_map(|&v| [v, v, v]).collect();
            assert_eq!(grey_of_bgr(&bgr).as_ref(), Some(&levels), "{pixels} pixels");
            // One sample off by one, in every position (in a block and after them).
            for k in 0..bgr.len() {
                let mut coloured = bgr.clone();
                coloured[k] ^= 1;
                assert_eq!(grey_of_bgr(&coloured), None, "{pixels} pixels, sample {k}");
            }
        }
    }
}
