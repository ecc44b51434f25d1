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
//! to deliver leaves a hole in the indices and is counted in [`FrameSource::gaps`]: every
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
//! [`LiveParams::camera_lost_ms`], ends the source with [`CaptureError::CameraLost`] naming
//! it. One camera alone cannot triangulate, so going on would record a take the pipeline
//! cannot use while looking healthy; the operator is better served by a clear stop, with
//! everything up to the last stereo frame recorded and valid, and can restart at once.
//! Short stalls (under the timeout) and bad frames only leave counted gaps.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError};

use super::syncbox::{
    SyncBox, SyncBoxConfig, SyncCounters, SyncHealth, TimecodeAnchor, stamp_from_anchor,
    time_of_day_timecode,
};
use super::{CaptureError, FrameSource, GrayConversion, GrayImage, StereoFrame, read_gray};
use crate::camera::StereoRig;
use crate::timecode::{Timecode, TimecodeRate};

/// One image from a camera and the host time it arrived.
#[derive(Debug, Clone, PartialEq)]
pub struct CapturedImage {
    /// 8-bit grayscale image.
    pub image: GrayImage,
    /// Host time of capture (when the driver handed the frame over, or the trigger time
    /// for cameras that report it).
    pub captured_at: Instant,
}

/// Why a camera gave no image.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CameraError {
    /// One bad frame (cannot be decoded, wrong size); the camera goes on.
    #[error("bad frame: {0}")]
    BadFrame(String),
    /// The device is gone (unplugged, stream closed); the camera stops.
    #[error("device lost: {0}")]
    Lost(String),
    /// A test camera played all its frames: the end of input.
    #[error("end of input")]
    Ended,
}

/// A camera: something that delivers grayscale images at its own pace.
pub trait CameraDevice: Send {
    /// A name for messages, e.g. `cam0 (/dev/video0)`.
    fn name(&self) -> &str;
    /// Blocks until the next frame (about one frame interval) and returns it.
    ///
    /// # Errors
    /// [`CameraError`]: a bad frame (counted, the camera goes on), a lost device or the end
    /// of a test camera's input (both stop the camera).
    fn grab(&mut self) -> Result<CapturedImage, CameraError>;
}

/// Pixel formats a camera can be asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum PixelFormat {
    /// 8-bit luminance (machine-vision cameras).
    Gray,
    /// YUYV 4:2:2 (the luminance bytes are taken as they are).
    Yuyv,
    /// Motion JPEG (decoded, then averaged to gray).
    Mjpeg,
    /// NV12 (converted to gray).
    Nv12,
    /// Packed 8-bit RGB (averaged to gray).
    Rgb,
}

/// One camera of `configs/live.toml` (`[[camera]]`).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// Device index (`/dev/videoN` on Linux).
    pub device: u32,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Pixel format asked of the camera. Default `gray`.
    #[serde(default = "default_pixel_format")]
    pub pixel_format: PixelFormat,
}

fn default_pixel_format() -> PixelFormat {
    PixelFormat::Gray
}

/// A camera through nokhwa (V4L2 on Linux): opened with the exact resolution, rate and
/// pixel format asked for, streaming from [`NokhwaCamera::open`] on.
pub struct NokhwaCamera {
    name: String,
    camera: nokhwa::Camera,
    width: u32,
    height: u32,
}

impl std::fmt::Debug for NokhwaCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NokhwaCamera")
            .field("name", &self.name)
            .field("width", &self.width)
            .field("height", &self.height)
            .finish_non_exhaustive()
    }
}

impl NokhwaCamera {
    /// Opens camera `config.device` at `fps` and starts its stream.
    ///
    /// # Errors
    /// [`CaptureError::Device`] naming the device when it does not exist or refuses the
    /// format.
    pub fn open(name: &str, config: &CameraConfig, fps: u32) -> Result<Self, CaptureError> {
        use nokhwa::pixel_format::LumaFormat;
        use nokhwa::utils::{
            CameraFormat, CameraIndex, FrameFormat, RequestedFormat, RequestedFormatType,
        };
        let label = format!("{name} (device {})", config.device);
        let err = |message: String| CaptureError::Device {
            device: label.clone(),
            message,
        };
        let format = match config.pixel_format {
            PixelFormat::Gray => FrameFormat::GRAY,
            PixelFormat::Yuyv => FrameFormat::YUYV,
            PixelFormat::Mjpeg => FrameFormat::MJPEG,
            PixelFormat::Nv12 => FrameFormat::NV12,
            PixelFormat::Rgb => FrameFormat::RAWRGB,
        };
        let wanted = CameraFormat::new_from(config.width, config.height, format, fps);
        let request = RequestedFormat::new::<LumaFormat>(RequestedFormatType::Exact(wanted));
        let mut camera = nokhwa::Camera::new(CameraIndex::Index(config.device), request)
            .map_err(|e| err(format!("cannot open: {e}")))?;
        camera
            .open_stream()
            .map_err(|e| err(format!("cannot start streaming: {e}")))?;
        let got = camera.camera_format();
        if got.resolution().width_x != config.width || got.resolution().height_y != config.height {
            return Err(err(format!(
                "delivers {}×{}, the config asks for {}×{}",
                got.resolution().width_x,
                got.resolution().height_y,
                config.width,
                config.height
            )));
        }
        tracing::info!("{label}: streaming {got}");
        Ok(Self {
            name: label,
            camera,
            width: config.width,
            height: config.height,
        })
    }
}

impl CameraDevice for NokhwaCamera {
    fn name(&self) -> &str {
        &self.name
    }

    fn grab(&mut self) -> Result<CapturedImage, CameraError> {
        use nokhwa::utils::FrameFormat;
        let buffer = self.camera.frame().map_err(|e| {
            let text = e.to_string();
            // V4L reports an unplugged device as ENODEV ("No such device").
            if text.contains("No such device") || text.contains("not open") {
                CameraError::Lost(text)
            } else {
                CameraError::BadFrame(text)
            }
        })?;
        let captured_at = Instant::now();
        let (w, h) = (self.width, self.height);
        let pixels = w as usize * h as usize;
        let raw = buffer.buffer();
        let data = match buffer.source_frame_format() {
            FrameFormat::GRAY if raw.len() >= pixels => raw[..pixels].to_vec(),
            FrameFormat::YUYV if raw.len() >= 2 * pixels => {
                raw.iter().step_by(2).copied().take(pixels).collect()
            }
            _ => buffer
                .decode_image::<nokhwa::pixel_format::LumaFormat>()
                .map_err(|e| CameraError::BadFrame(e.to_string()))?
                .into_raw(),
        };
        if data.len() != pixels {
            return Err(CameraError::BadFrame(format!(
                "{} bytes for a {w}×{h} image",
                data.len()
            )));
        }
        Ok(CapturedImage {
            image: GrayImage {
                width: w,
                height: h,
                data,
            },
            captured_at,
        })
    }
}

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

/// Counters of one camera.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct CameraStats {
    /// The camera's name.
    pub name: String,
    /// Images grabbed.
    pub delivered: u64,
    /// Bad frames (decode errors, wrong size).
    pub bad_frames: u64,
    /// Images dropped because the queue to the source was full (consumer behind).
    pub overflow: u64,
    /// Images without a partner from the other camera (dropped).
    pub unpaired: u64,
}

#[derive(Debug, Default)]
struct CameraCounters {
    delivered: AtomicU64,
    bad_frames: AtomicU64,
    overflow: AtomicU64,
}

enum CameraMsg {
    Image(CapturedImage),
    Lost(String),
    Ended,
}

/// Live source settings (`[live]` of `configs/live.toml`).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct LiveParams {
    /// Frames each camera thread may hold for the source. Default 4.
    pub camera_queue: usize,
    /// Two cameras' frames pair when their capture times differ by at most this fraction
    /// of a frame interval. Default 0.5.
    pub pair_tolerance: f64,
    /// A camera that delivers nothing for this long is lost and ends the source, ms.
    /// Default 2000.
    pub camera_lost_ms: u64,
}

impl Default for LiveParams {
    fn default() -> Self {
        Self {
            camera_queue: 4,
            pair_tolerance: 0.5,
            camera_lost_ms: 2000,
        }
    }
}

/// Which clock stamped a frame's timecode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StampClock {
    /// The sync box (healthy).
    SyncBox,
    /// The local clock (no sync box, or it is lost).
    Local,
}

impl std::fmt::Display for StampClock {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::SyncBox => "syncbox",
            Self::Local => "local",
        })
    }
}

/// A stereo frame with how it was stamped.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveFrame {
    /// The frame (index, timestamp from the first frame, timecode, images).
    pub frame: StereoFrame,
    /// The sync box's trigger pulse of the frame, when stamped from the box.
    pub trigger: Option<u64>,
    /// The clock that stamped the timecode.
    pub clock: StampClock,
}

/// Counters of a live source.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct LiveStats {
    /// Stereo frames delivered.
    pub frames_out: u64,
    /// Frame indices skipped (a camera failed to deliver, a frame was dropped or bad).
    pub gaps: u64,
    /// Per camera.
    pub cameras: [CameraStats; 2],
    /// Frames stamped from the sync box.
    pub stamped_syncbox: u64,
    /// Frames stamped from the local clock.
    pub stamped_local: u64,
    /// Switches between the sync box and the local clock.
    pub clock_switches: u64,
    /// Frame indices after the last stereo frame that only one camera delivered before the
    /// other ended its input (test cameras): `frames_out + gaps + trailing_unpaired` covers
    /// every index either camera reached.
    pub trailing_unpaired: u64,
    /// Frames of a size other than the first frame's (dropped).
    pub wrong_size: u64,
    /// The sync box's counters, when there is one.
    pub syncbox: Option<SyncCounters>,
}

/// The timecode settings of the live source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiveTimecode {
    /// The timecode rate (the sync box must send this rate; lines at another rate are
    /// ignored and counted).
    pub rate: TimecodeRate,
    /// Camera frame delay against the sync line of the same pulse.
    pub frame_delay: Duration,
}

/// Stereo frames from two live cameras, stamped with timecode; see the module docs.
pub struct LiveSource {
    names: [String; 2],
    receivers: [Receiver<CameraMsg>; 2],
    counters: [Arc<CameraCounters>; 2],
    threads: Vec<std::thread::JoinHandle<()>>,
    heads: [Option<CapturedImage>; 2],
    last_seen: [Instant; 2],
    fps: f64,
    params: LiveParams,
    rig: Option<StereoRig>,
    sync: Option<SyncBox>,
    timecode: LiveTimecode,
    anchor: Option<TimecodeAnchor>,
    clock: Option<StampClock>,
    stop: Arc<AtomicBool>,
    camera_stop: Arc<AtomicBool>,
    first: Option<(Instant, usize)>,
    last: Option<(Instant, usize)>,
    size: Option<(u32, u32)>,
    stats: LiveStats,
    rate_mismatch_logged: bool,
    done: bool,
}

impl std::fmt::Debug for LiveSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveSource")
            .field("cameras", &self.names)
            .field("fps", &self.fps)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl LiveSource {
    /// Starts one thread per camera and (optionally) uses `sync` for timecode.
    ///
    /// # Errors
    /// [`CaptureError::Device`] when a thread cannot be started or a setting is invalid.
    pub fn new(
        cameras: [Box<dyn CameraDevice>; 2],
        fps: f64,
        params: LiveParams,
        rig: Option<StereoRig>,
        sync: Option<SyncBox>,
        timecode: LiveTimecode,
    ) -> Result<Self, CaptureError> {
        let bad = |message: String| CaptureError::Device {
            device: "live source".into(),
            message,
        };
        if !(fps > 0.0 && fps.is_finite()) {
            return Err(bad(format!("fps {fps} must be positive")));
        }
        let queue_ok = (1..=crate::limits::MAX_QUEUE_FRAMES).contains(&params.camera_queue);
        let tolerance_ok = params.pair_tolerance > 0.0 && params.pair_tolerance < 1.0;
        if !(queue_ok && tolerance_ok) {
            return Err(bad(format!(
                "`camera_queue` must be 1 to {} and `pair_tolerance` in (0, 1)",
                crate::limits::MAX_QUEUE_FRAMES
            )));
        }
        let camera_stop = Arc::new(AtomicBool::new(false));
        let mut names: [String; 2] = Default::default();
        let mut threads = Vec::new();
        let mut receivers = Vec::new();
        let mut counters = Vec::new();
        for (i, cam) in cameras.into_iter().enumerate() {
            let name = cam.name().to_string();
            let (tx, rx) = crossbeam_channel::bounded(params.camera_queue);
            let c = Arc::new(CameraCounters::default());
            let (c2, stop2) = (c.clone(), camera_stop.clone());
            let handle = std::thread::Builder::new()
                .name(format!("helmcap:cam{i}"))
                .spawn(move || camera_loop(cam, &tx, &c2, &stop2))
                .map_err(|e| bad(format!("cannot start the thread of {name}: {e}")))?;
            if let Some(n) = names.get_mut(i) {
                n.clone_from(&name);
            }
            threads.push(handle);
            receivers.push(rx);
            counters.push(c);
        }
        let (Ok(receivers), Ok(counters)) = (
            <[Receiver<CameraMsg>; 2]>::try_from(receivers),
            <[Arc<CameraCounters>; 2]>::try_from(counters),
        ) else {
            return Err(bad("expected two cameras".into()));
        };
        let now = Instant::now();
        if sync.is_none() {
            tracing::info!("no sync box configured: timecode from the local clock");
        }
        let mut stats = LiveStats::default();
        for (s, n) in stats.cameras.iter_mut().zip(&names) {
            s.name.clone_from(n);
        }
        Ok(Self {
            names,
            receivers,
            counters,
            threads,
            heads: [None, None],
            last_seen: [now, now],
            fps,
            params,
            rig,
            sync,
            timecode,
            anchor: None,
            clock: None,
            stop: Arc::new(AtomicBool::new(false)),
            camera_stop,
            first: None,
            last: None,
            size: None,
            stats,
            rate_mismatch_logged: false,
            done: false,
        })
    }

    /// A flag that ends the source (the next call returns `None`) when set, e.g. from a
    /// Ctrl-C handler. Checked at least every 50 ms while waiting for a camera.
    pub fn stop_flag(&self) -> Arc<AtomicBool> {
        self.stop.clone()
    }

    /// Uses `flag` (e.g. set by a Ctrl-C handler) instead of the source's own stop flag.
    pub fn set_stop_flag(&mut self, flag: Arc<AtomicBool>) {
        self.stop = flag;
    }

    /// Counters so far.
    pub fn stats(&self) -> LiveStats {
        let mut s = self.stats.clone();
        for (cs, c) in s.cameras.iter_mut().zip(&self.counters) {
            cs.delivered = c.delivered.load(Ordering::Relaxed);
            cs.bad_frames = c.bad_frames.load(Ordering::Relaxed);
            cs.overflow = c.overflow.load(Ordering::Relaxed);
        }
        s.syncbox = self.sync.as_ref().map(|b| b.status().counters);
        s
    }

    /// The timecode rate frames are stamped at.
    pub fn timecode_rate(&self) -> TimecodeRate {
        self.timecode.rate
    }

    /// Waits for camera `cam`'s next image. `Ok(false)`: the camera ended its input (or
    /// the source was stopped).
    fn fill(&mut self, cam: usize) -> Result<bool, CaptureError> {
        let lost_after = Duration::from_millis(self.params.camera_lost_ms);
        while self.heads[cam].is_none() {
            if self.stop.load(Ordering::Relaxed) {
                return Ok(false);
            }
            match self.receivers[cam].recv_timeout(Duration::from_millis(50)) {
                Ok(CameraMsg::Image(img)) => {
                    self.last_seen[cam] = Instant::now();
                    self.heads[cam] = Some(img);
                }
                Ok(CameraMsg::Ended) => return Ok(false),
                Ok(CameraMsg::Lost(message)) => {
                    return Err(CaptureError::CameraLost {
                        camera: self.names[cam].clone(),
                        message,
                    });
                }
                Err(RecvTimeoutError::Timeout) => {
                    let silent = self.last_seen[cam].elapsed();
                    if silent >= lost_after {
                        return Err(CaptureError::CameraLost {
                            camera: self.names[cam].clone(),
                            message: format!("no frame for {:.1} s", silent.as_secs_f64()),
                        });
                    }
                }
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(CaptureError::CameraLost {
                        camera: self.names[cam].clone(),
                        message: "its thread ended".into(),
                    });
                }
            }
        }
        Ok(true)
    }

    /// At the end of input (camera `1 - other` ended): the frames `other` still delivers
    /// have no partner; their indices after the last stereo frame are counted in
    /// [`LiveStats::trailing_unpaired`], so every index up to the last frame either camera
    /// delivered is accounted for.
    fn count_trailing(&mut self, other: usize) {
        let Some((last_t, last_i)) = self.last else {
            return;
        };
        let interval = 1.0 / self.fps;
        let index_of =
            |t: Instant| last_i + (signed_secs(t, last_t) / interval).round().max(0.0) as usize;
        let mut max_index = last_i;
        let heads: Vec<Instant> = self
            .heads
            .iter_mut()
            .filter_map(Option::take)
            .map(|h| h.captured_at)
            .collect();
        for t in heads {
            max_index = max_index.max(index_of(t));
        }
        let deadline = Instant::now() + Duration::from_millis(self.params.camera_lost_ms);
        while let Ok(CameraMsg::Image(img)) = self.receivers[other].recv_deadline(deadline) {
            self.stats.cameras[other].unpaired += 1;
            max_index = max_index.max(index_of(img.captured_at));
        }
        let trailing = (max_index - last_i) as u64;
        if trailing > 0 {
            tracing::debug!("{trailing} frames after the last stereo frame had no pair");
            self.stats.trailing_unpaired += trailing;
        }
    }

    /// The next stereo frame with its stamp; `None` at the end of input or after a stop.
    /// After an error, the source is finished (the next call returns `None`).
    pub fn next_stamped(&mut self) -> Option<Result<LiveFrame, CaptureError>> {
        if self.done {
            return None;
        }
        let result = self.pair();
        match result {
            Ok(Some(frame)) => Some(Ok(frame)),
            Ok(None) => {
                self.done = true;
                None
            }
            Err(e) => {
                self.done = true;
                Some(Err(e))
            }
        }
    }

    fn pair(&mut self) -> Result<Option<LiveFrame>, CaptureError> {
        let interval = 1.0 / self.fps;
        loop {
            for cam in 0..2 {
                if !self.fill(cam)? {
                    if !self.stop.load(Ordering::Relaxed) {
                        self.count_trailing(1 - cam);
                    }
                    return Ok(None);
                }
            }
            let (Some(a), Some(b)) = (&self.heads[0], &self.heads[1]) else {
                continue;
            };
            let dt = signed_secs(a.captured_at, b.captured_at);
            if dt.abs() > self.params.pair_tolerance * interval {
                // The older frame's twin never came: drop it.
                let older = usize::from(dt > 0.0);
                self.heads[older] = None;
                self.stats.cameras[older].unpaired += 1;
                tracing::debug!("{}: a frame without its pair dropped", self.names[older]);
                continue;
            }
            let (Some(a), Some(b)) = (self.heads[0].take(), self.heads[1].take()) else {
                continue;
            };
            let captured = a.captured_at.min(b.captured_at);
            let size = (a.image.width, a.image.height);
            if (b.image.width, b.image.height) != size || self.size.is_some_and(|s| s != size) {
                self.stats.wrong_size += 1;
                tracing::warn!(
                    "a stereo frame of {}×{} and {}×{} dropped (expected {:?})",
                    a.image.width,
                    a.image.height,
                    b.image.width,
                    b.image.height,
                    self.size.unwrap_or(size)
                );
                continue;
            }
            if self.size.is_none() {
                if let Some(rig) = &self.rig
                    && size != (rig.cam0.width_px, rig.cam0.height_px)
                {
                    return Err(CaptureError::Device {
                        device: self.names[0].clone(),
                        message: format!(
                            "delivers {}×{} images, the calibration expects {}×{}",
                            size.0, size.1, rig.cam0.width_px, rig.cam0.height_px
                        ),
                    });
                }
                self.size = Some(size);
            }
            let index = match self.last {
                None => 0,
                Some((t, i)) => {
                    let steps = (signed_secs(captured, t) / interval).round().max(1.0) as usize;
                    self.stats.gaps += (steps - 1) as u64;
                    if steps > 1 {
                        tracing::debug!("frames {}..{} missing", i + 1, i + steps - 1);
                    }
                    i + steps
                }
            };
            self.last = Some((captured, index));
            let first = *self.first.get_or_insert((captured, index));
            let timestamp_ns = (signed_secs(captured, first.0).max(0.0) * 1e9).round() as u64;
            let (timecode, trigger, clock) = self.stamp(captured);
            self.stats.frames_out += 1;
            return Ok(Some(LiveFrame {
                frame: StereoFrame {
                    index,
                    timestamp_ns,
                    timecode: Some(timecode),
                    images: [a.image, b.image],
                },
                trigger,
                clock,
            }));
        }
    }

    /// Stamps a frame captured at `captured`: from the sync box when healthy, else from the
    /// local clock (free-running from the last anchor). Logs and counts clock switches.
    fn stamp(&mut self, captured: Instant) -> (Timecode, Option<u64>, StampClock) {
        let mut clock = StampClock::Local;
        let mut reason = String::from("no sync box configured");
        if let Some(sync) = &self.sync {
            let status = sync.status();
            reason = format!("sync box {}", status.health);
            if status.health == SyncHealth::Healthy
                && let Some(sample) = status.latest
            {
                if sample.line.timecode.rate == self.timecode.rate {
                    self.anchor = Some(TimecodeAnchor::from_sample(
                        &sample,
                        self.timecode.frame_delay,
                    ));
                    clock = StampClock::SyncBox;
                } else {
                    reason = format!(
                        "the sync box sends {} timecode, the config says {}",
                        sample.line.timecode.rate, self.timecode.rate
                    );
                    if !self.rate_mismatch_logged {
                        tracing::warn!("{reason}: its lines are ignored");
                        self.rate_mismatch_logged = true;
                    }
                }
            }
        }
        let anchor = *self.anchor.get_or_insert_with(|| TimecodeAnchor {
            timecode: time_of_day_timecode(self.timecode.rate),
            trigger: None,
            at: captured,
        });
        let anchor = if clock == StampClock::Local {
            TimecodeAnchor {
                trigger: None,
                ..anchor
            }
        } else {
            anchor
        };
        let (timecode, trigger) = stamp_from_anchor(&anchor, captured, self.fps);
        if self.clock != Some(clock) {
            match (self.clock, clock) {
                (_, StampClock::SyncBox) => {
                    tracing::info!("timecode: from the sync box from {timecode} on");
                }
                (Some(StampClock::SyncBox), StampClock::Local) => tracing::warn!(
                    "timecode: {reason}: from the local clock (free-running) from {timecode} on"
                ),
                (_, StampClock::Local) => {
                    tracing::info!("timecode: {reason}: from the local clock from {timecode} on");
                }
            }
            if self.clock.is_some() {
                self.stats.clock_switches += 1;
            }
            self.clock = Some(clock);
        }
        match clock {
            StampClock::SyncBox => self.stats.stamped_syncbox += 1,
            StampClock::Local => self.stats.stamped_local += 1,
        }
        (timecode, trigger, clock)
    }
}

fn signed_secs(a: Instant, b: Instant) -> f64 {
    if a >= b {
        (a - b).as_secs_f64()
    } else {
        -(b - a).as_secs_f64()
    }
}

fn camera_loop(
    mut cam: Box<dyn CameraDevice>,
    tx: &Sender<CameraMsg>,
    counters: &CameraCounters,
    stop: &AtomicBool,
) {
    let mut logged_bad = 0u32;
    while !stop.load(Ordering::Relaxed) {
        let msg = match cam.grab() {
            Ok(img) => {
                counters.delivered.fetch_add(1, Ordering::Relaxed);
                CameraMsg::Image(img)
            }
            Err(CameraError::BadFrame(m)) => {
                let n = counters.bad_frames.fetch_add(1, Ordering::Relaxed) + 1;
                if logged_bad < 10 {
                    logged_bad += 1;
                    tracing::warn!("{}: bad frame ({m}); {n} so far", cam.name());
                }
                // A camera that fails at once on every call must not spin.
                std::thread::sleep(Duration::from_millis(2));
                continue;
            }
            Err(CameraError::Lost(m)) => CameraMsg::Lost(m),
            Err(CameraError::Ended) => CameraMsg::Ended,
        };
        let last = !matches!(msg, CameraMsg::Image(_));
        match tx.try_send(msg) {
            Ok(()) => {}
            Err(TrySendError::Full(msg)) => {
                if last {
                    // The end must get through: wait for room (or for the source to go).
                    if tx.send(msg).is_err() {
                        return;
                    }
                } else {
                    counters.overflow.fetch_add(1, Ordering::Relaxed);
                }
            }
            Err(TrySendError::Disconnected(_)) => return,
        }
        if last {
            return;
        }
    }
}

impl Drop for LiveSource {
    fn drop(&mut self) {
        self.camera_stop.store(true, Ordering::Relaxed);
        // Unblock camera threads waiting to hand over an end message.
        let receivers = std::mem::replace(
            &mut self.receivers,
            [crossbeam_channel::never(), crossbeam_channel::never()],
        );
        drop(receivers);
        // A camera stuck in its driver is left to finish on its own rather than hang the
        // program: wait at most a second for the threads.
        let deadline = Instant::now() + Duration::from_secs(1);
        for t in self.threads.drain(..) {
            while !t.is_finished() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(5));
            }
            if t.is_finished() {
                let _ = t.join();
            } else {
                tracing::warn!("a camera thread did not stop within 1 s; left running");
            }
        }
    }
}

impl FrameSource for LiveSource {
    fn next_frame(&mut self) -> Option<Result<StereoFrame, CaptureError>> {
        self.next_stamped().map(|r| r.map(|f| f.frame))
    }

    fn fps(&self) -> f64 {
        self.fps
    }

    fn is_live(&self) -> bool {
        true
    }

    fn rig(&self) -> Option<&StereoRig> {
        self.rig.as_ref()
    }

    fn gaps(&self) -> usize {
        self.stats.gaps as usize
    }
}

/// Largest camera width or height a config may ask for, pixels.
pub const MAX_CAMERA_SIDE_PX: u32 = 16_384;

/// Largest `[syncbox] frame_delay_ms`: a camera frame reaching the host a second after
/// its trigger pulse's sync line is a misconfiguration, not a delay.
pub const MAX_FRAME_DELAY_MS: f64 = 1_000.0;

/// Largest `[syncbox] baud` (USB serial adapters stop at a few Mbaud).
pub const MAX_BAUD: u32 = 4_000_000;

/// Most `[record] writers` threads.
pub const MAX_WRITERS: usize = 64;

/// The 1-based line of `key` in `[table]` of a TOML text (`camera N` for the N-th
/// `[[camera]]`), or 0 when it is not written there (a default, or inline tables).
fn key_line(text: &str, table: &str, key: &str) -> usize {
    let (name, nth) = match table.split_once(' ') {
        Some((n, k)) => (n, k.parse::<usize>().unwrap_or(0)),
        None => (table, 0),
    };
    let mut in_table = false;
    let mut seen = 0usize;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if t.starts_with('[') {
            let header = t.trim_start_matches('[').trim_end_matches(']').trim();
            in_table = header == name && {
                seen += 1;
                seen == nth + 1
            };
            continue;
        }
        if in_table
            && let Some(rest) = t.strip_prefix(key)
            && rest.trim_start().starts_with('=')
        {
            return i + 1;
        }
    }
    0
}

/// `[timecode]` of `configs/live.toml`.
#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct TimecodeConfig {
    /// Timecode rate (must match the sync box's). Default: the camera rate when it is a
    /// standard timecode rate of at most 30 fps, else half of it when that is (60 fps
    /// cameras: 30 fps code with two sub-frames), else 30.
    pub rate: Option<TimecodeRate>,
}

/// `[test]` of `configs/live.toml`: test cameras instead of hardware.
#[derive(Debug, Clone, PartialEq, Default, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct TestSourceConfig {
    /// A recording session replayed at real-time pace (relative to the config file);
    /// without it, a synthetic pattern of the cameras' configured size.
    pub session: Option<PathBuf>,
    /// Frames of the pattern (ignored with a session: all its frames). Default 600.
    pub frames: Option<usize>,
    /// Faults injected into cam0.
    pub cam0: TestFaults,
    /// Faults injected into cam1.
    pub cam1: TestFaults,
}

/// `[record]` of `configs/live.toml`.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct RecordConfig {
    /// Frames the recorder's queue holds before it drops (and counts) frames. Default 120
    /// (two seconds at 60 fps; about 2.6 MB per 1280×1024 stereo frame).
    pub queue_frames: usize,
    /// PNG writer threads. Default 2.
    pub writers: usize,
}

impl Default for RecordConfig {
    fn default() -> Self {
        Self {
            queue_frames: 120,
            writers: 2,
        }
    }
}

/// `configs/live.toml`: cameras, sync box, queues. See the README section "Live capture
/// and recording".
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct LiveConfig {
    /// Camera frames per second (both cameras).
    pub fps: f64,
    /// Stereo calibration YAML (relative to the config file), copied into recordings.
    #[serde(default)]
    pub calibration: Option<PathBuf>,
    /// The two cameras, cam0 first.
    pub camera: Vec<CameraConfig>,
    /// The sync box; without it, timecode comes from the local clock.
    #[serde(default)]
    pub syncbox: Option<SyncBoxConfig>,
    /// Timecode settings.
    #[serde(default)]
    pub timecode: TimecodeConfig,
    /// Live source settings.
    #[serde(default)]
    pub live: LiveParams,
    /// Recorder settings.
    #[serde(default)]
    pub record: RecordConfig,
    /// Test cameras instead of hardware.
    #[serde(default)]
    pub test: Option<TestSourceConfig>,
}

impl LiveConfig {
    /// Reads and checks a config; relative paths become relative to the file's folder.
    ///
    /// # Errors
    /// [`CaptureError::Io`] or [`CaptureError::Format`] naming the file (and line).
    pub fn load(path: &Path) -> Result<Self, CaptureError> {
        let text = std::fs::read_to_string(path).map_err(|e| CaptureError::Io {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let format_err = |line: usize, message: String| CaptureError::Format {
            path: path.to_path_buf(),
            line,
            message,
        };
        let mut config: Self = toml::from_str(&text).map_err(|e| {
            let line = e
                .span()
                .map(|s| {
                    text.as_bytes()[..s.start.min(text.len())]
                        .iter()
                        .filter(|&&b| b == b'\n')
                        .count()
                        + 1
                })
                .unwrap_or(0);
            format_err(line, e.message().to_string())
        })?;
        if config.camera.len() != 2 {
            return Err(format_err(
                0,
                format!("{} [[camera]] tables, expected 2", config.camera.len()),
            ));
        }
        if !(config.fps > 0.0 && config.fps <= 1000.0) {
            return Err(format_err(
                0,
                format!("fps {} must be in (0, 1000]", config.fps),
            ));
        }
        config
            .check_ranges(&text)
            .map_err(|(line, m)| format_err(line, m))?;
        let dir = path.parent().unwrap_or(Path::new("."));
        if let Some(c) = &mut config.calibration {
            *c = dir.join(&*c);
        }
        if let Some(t) = &mut config.test
            && let Some(s) = &mut t.session
        {
            *s = dir.join(&*s);
        }
        Ok(config)
    }

    /// Range-checks every number of the config against the limits of
    /// [`crate::limits`] (README "Limits"); the error is `(line, message)` naming the key
    /// (`text` is the file, to find the key's line; 0 when not found).
    fn check_ranges(&self, text: &str) -> Result<(), (usize, String)> {
        use crate::limits::{MAX_DURATION_MS, MAX_QUEUE_FRAMES};
        let check = |table: &str, key: &str, ok: bool, value: String, range: &str| {
            if ok {
                Ok(())
            } else {
                Err((
                    key_line(text, table, key),
                    format!("[{table}] {key} = {value} is out of range: {range}"),
                ))
            }
        };
        let ms = |v: u64| v >= 1 && v as f64 <= MAX_DURATION_MS;
        let ms_range = format!("1 to {MAX_DURATION_MS} ms");
        for (i, c) in self.camera.iter().enumerate() {
            let table = format!("camera {i}");
            for (key, v) in [("width", c.width), ("height", c.height)] {
                check(
                    &table,
                    key,
                    (1..=MAX_CAMERA_SIDE_PX).contains(&v),
                    v.to_string(),
                    &format!("1 to {MAX_CAMERA_SIDE_PX} pixels"),
                )?;
            }
        }
        if let Some(sb) = &self.syncbox {
            check(
                "syncbox",
                "frame_delay_ms",
                (0.0..=MAX_FRAME_DELAY_MS).contains(&sb.frame_delay_ms),
                format!("{:?}", sb.frame_delay_ms),
                &format!("0 to {MAX_FRAME_DELAY_MS} ms"),
            )?;
            check(
                "syncbox",
                "timeout_ms",
                ms(sb.timeout_ms),
                sb.timeout_ms.to_string(),
                &ms_range,
            )?;
            check(
                "syncbox",
                "retry_ms",
                ms(sb.retry_ms),
                sb.retry_ms.to_string(),
                &ms_range,
            )?;
            check(
                "syncbox",
                "baud",
                (1..=MAX_BAUD).contains(&sb.baud),
                sb.baud.to_string(),
                &format!("1 to {MAX_BAUD}"),
            )?;
        }
        let l = &self.live;
        check(
            "live",
            "camera_queue",
            (1..=MAX_QUEUE_FRAMES).contains(&l.camera_queue),
            l.camera_queue.to_string(),
            &format!("1 to {MAX_QUEUE_FRAMES} frames"),
        )?;
        check(
            "live",
            "pair_tolerance",
            l.pair_tolerance > 0.0 && l.pair_tolerance < 1.0,
            format!("{:?}", l.pair_tolerance),
            "above 0 and below 1 (a fraction of a frame interval)",
        )?;
        check(
            "live",
            "camera_lost_ms",
            ms(l.camera_lost_ms),
            l.camera_lost_ms.to_string(),
            &ms_range,
        )?;
        let r = &self.record;
        check(
            "record",
            "queue_frames",
            (1..=MAX_QUEUE_FRAMES).contains(&r.queue_frames),
            r.queue_frames.to_string(),
            &format!("1 to {MAX_QUEUE_FRAMES} frames"),
        )?;
        check(
            "record",
            "writers",
            (1..=MAX_WRITERS).contains(&r.writers),
            r.writers.to_string(),
            &format!("1 to {MAX_WRITERS} threads"),
        )?;
        if let Some(t) = &self.test {
            let frames = t.frames.unwrap_or(0) as u64;
            check(
                "test",
                "frames",
                frames <= crate::limits::MAX_FRAME_NUMBER,
                frames.to_string(),
                &format!("0 to {}", crate::limits::MAX_FRAME_NUMBER),
            )?;
        }
        Ok(())
    }

    /// The timecode rate: `[timecode] rate`, else derived from the camera rate (see
    /// [`TimecodeConfig::rate`]).
    pub fn timecode_rate(&self) -> TimecodeRate {
        self.timecode.rate.unwrap_or_else(|| {
            TimecodeRate::from_fps(self.fps)
                .filter(|r| r.fps() <= 30.5)
                .or_else(|| TimecodeRate::from_fps(self.fps / 2.0))
                .unwrap_or(TimecodeRate::FPS_30)
        })
    }

    /// Opens the live source: the configured cameras (or test cameras when `[test]` is
    /// set or `test_session` is given: a session replayed at real-time pace), and the sync
    /// box if configured.
    ///
    /// # Errors
    /// [`CaptureError`] naming the device, session or setting.
    pub fn open_source(&self, test_session: Option<&Path>) -> Result<LiveSource, CaptureError> {
        let mut fps = self.fps;
        let mut rig = self
            .calibration
            .as_ref()
            .map(|p| crate::camera::read_rig(p))
            .transpose()?;
        let cameras: [Box<dyn CameraDevice>; 2] = if test_session.is_some() || self.test.is_some() {
            let test = self.test.clone().unwrap_or_default();
            let session = test_session.map(Path::to_path_buf).or(test.session.clone());
            let start = Instant::now() + Duration::from_millis(100);
            let faults = [test.cam0.clone(), test.cam1.clone()];
            match session {
                Some(root) => {
                    let replay = super::Replay::open(&root, super::ReplayParams::default())?;
                    let info = replay.info();
                    fps = info.fps;
                    if rig.is_none() {
                        rig = replay.rig().cloned();
                    }
                    let frames = info.frames.iter().map(|f| f.0 + 1).max().unwrap_or(0);
                    let mk = |i: usize| -> Box<dyn CameraDevice> {
                        let camera = info.cameras.get(i).cloned().unwrap_or_default();
                        Box::new(TestCamera::new(
                            &format!("test {camera} ({})", root.display()),
                            TestImages::Session {
                                root: root.clone(),
                                camera,
                                frames,
                            },
                            fps,
                            start,
                            faults.get(i).cloned().unwrap_or_default(),
                        ))
                    };
                    [mk(0), mk(1)]
                }
                None => {
                    let frames = test.frames.unwrap_or(600);
                    let mk = |i: usize| -> Box<dyn CameraDevice> {
                        let c = self.camera.get(i);
                        Box::new(TestCamera::new(
                            &format!("test cam{i}"),
                            TestImages::Pattern {
                                width: c.map_or(64, |c| c.width),
                                height: c.map_or(48, |c| c.height),
                                frames,
                                camera: i as u8,
                            },
                            fps,
                            start,
                            faults.get(i).cloned().unwrap_or_default(),
                        ))
                    };
                    [mk(0), mk(1)]
                }
            }
        } else {
            let rate = fps.round() as u32;
            let (Some(c0), Some(c1)) = (self.camera.first(), self.camera.get(1)) else {
                return Err(CaptureError::Device {
                    device: "cameras".into(),
                    message: "two [[camera]] tables are needed".into(),
                });
            };
            [
                Box::new(NokhwaCamera::open("cam0", c0, rate)?),
                Box::new(NokhwaCamera::open("cam1", c1, rate)?),
            ]
        };
        let sync = self
            .syncbox
            .clone()
            .map(SyncBox::start)
            .transpose()
            .map_err(|e| CaptureError::Device {
                device: "sync box".into(),
                message: e.to_string(),
            })?;
        let frame_delay_ms = self.syncbox.as_ref().map_or(0.0, |s| s.frame_delay_ms);
        LiveSource::new(
            cameras,
            fps,
            self.live.clone(),
            rig,
            sync,
            LiveTimecode {
                rate: self.timecode_rate(),
                // Range-checked at load; a config built in code falls back to no delay.
                frame_delay: Duration::try_from_secs_f64(frame_delay_ms / 1000.0)
                    .unwrap_or_default(),
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FPS: f64 = 100.0;

    fn cameras(frames: usize, faults: [TestFaults; 2]) -> [Box<dyn CameraDevice>; 2] {
        let start = Instant::now() + Duration::from_millis(20);
        let [f0, f1] = faults;
        let mk = |i: u8, f: TestFaults| -> Box<dyn CameraDevice> {
            Box::new(TestCamera::new(
                &format!("test cam{i}"),
                TestImages::Pattern {
                    width: 16,
                    height: 8,
                    frames,
                    camera: i,
                },
                FPS,
                start,
                f,
            ))
        };
        [mk(0, f0), mk(1, f1)]
    }

    fn source(frames: usize, faults: [TestFaults; 2], params: LiveParams) -> LiveSource {
        LiveSource::new(
            cameras(frames, faults),
            FPS,
            params,
            None,
            None,
            LiveTimecode {
                rate: TimecodeRate::FPS_50,
                frame_delay: Duration::ZERO,
            },
        )
        .unwrap()
    }

    /// A queue long enough that a loaded test machine never overflows it.
    fn roomy() -> LiveParams {
        LiveParams {
            camera_queue: 1000,
            ..Default::default()
        }
    }

    fn frame_of(image: &GrayImage) -> usize {
        let mut b = [0u8; 8];
        b[..7].copy_from_slice(&image.data[..7]);
        u64::from_le_bytes(b) as usize
    }

    #[test]
    fn pairs_every_frame_in_order_with_local_timecode() {
        let mut src = source(40, Default::default(), roomy());
        let frames: Vec<LiveFrame> = std::iter::from_fn(|| src.next_stamped())
            .map(Result::unwrap)
            .collect();
        assert_eq!(frames.len(), 40);
        for (i, f) in frames.iter().enumerate() {
            assert_eq!(f.frame.index, i);
            assert_eq!(f.frame.images[0], test_pattern(16, 8, i, 0));
            assert_eq!(f.frame.images[1], test_pattern(16, 8, i, 1));
            assert_eq!(f.frame.timestamp_ns, i as u64 * 10_000_000);
            assert_eq!(f.clock, StampClock::Local);
            assert_eq!(f.trigger, None);
        }
        // 100 fps cameras on 50 fps code: sub-frames 0 and 1, consecutive.
        let t0 = frames[0].frame.timecode.unwrap();
        for (i, f) in frames.iter().enumerate() {
            let t = f.frame.timecode.unwrap();
            let cam_frames = (t.frame_count as i64 - t0.frame_count as i64) * 2
                + i64::from(t.subframe)
                - i64::from(t0.subframe);
            assert_eq!(cam_frames, i as i64, "{t}");
            assert_eq!(t.subframes, 2);
        }
        let stats = src.stats();
        assert_eq!(
            (stats.frames_out, stats.gaps, stats.stamped_local),
            (40, 0, 40)
        );
        assert_eq!(stats.cameras[1].delivered, 40);
        assert!(src.is_live());
        assert!(src.next_stamped().is_none());
    }

    #[test]
    fn corrupt_and_stalled_frames_are_counted_gaps() {
        let faults = [
            TestFaults {
                corrupt: vec![3],
                ..Default::default()
            },
            TestFaults {
                corrupt: vec![5],
                stall: Some([10, 3]),
                ..Default::default()
            },
        ];
        let mut src = source(30, faults, roomy());
        let indices: Vec<usize> = std::iter::from_fn(|| src.next_stamped())
            .map(|f| {
                let f = f.unwrap();
                assert_eq!(frame_of(&f.frame.images[0]), f.frame.index);
                assert_eq!(frame_of(&f.frame.images[1]), f.frame.index);
                f.frame.index
            })
            .collect();
        let expected: Vec<usize> = (0..30)
            .filter(|i| ![3, 5, 10, 11, 12].contains(i))
            .collect();
        assert_eq!(indices, expected);
        let stats = src.stats();
        assert_eq!(stats.gaps, 5);
        assert_eq!(
            stats.frames_out + stats.gaps,
            30,
            "every frame delivered or counted"
        );
        assert_eq!(stats.cameras[0].bad_frames, 1);
        assert_eq!(stats.cameras[1].bad_frames, 1);
        assert_eq!(stats.cameras[0].unpaired, 4);
        assert_eq!(stats.cameras[1].unpaired, 1);
    }

    #[test]
    fn a_vanished_camera_ends_the_source_with_its_name() {
        let faults = [
            TestFaults::default(),
            TestFaults {
                vanish_at: Some(12),
                ..Default::default()
            },
        ];
        let mut src = source(100, faults, roomy());
        let mut n = 0;
        let err = loop {
            match src.next_stamped() {
                Some(Ok(_)) => n += 1,
                Some(Err(e)) => break e.to_string(),
                None => panic!("ended without an error"),
            }
        };
        assert_eq!(n, 12);
        assert!(
            err.contains("test cam1") && err.contains("vanished"),
            "{err}"
        );
        assert!(src.next_stamped().is_none());
    }

    #[test]
    fn a_silent_camera_is_lost_after_the_timeout_and_stop_ends_the_source() {
        let faults = [
            TestFaults {
                stall: Some([5, 10_000]),
                ..Default::default()
            },
            TestFaults::default(),
        ];
        let params = LiveParams {
            camera_lost_ms: 300,
            ..roomy()
        };
        let mut src = source(20_000, faults, params);
        let mut n = 0;
        let err = loop {
            match src.next_stamped() {
                Some(Ok(_)) => n += 1,
                Some(Err(e)) => break e.to_string(),
                None => panic!("ended without an error"),
            }
        };
        assert_eq!(n, 5);
        assert!(
            err.contains("test cam0") && err.contains("no frame for"),
            "{err}"
        );

        let mut src = source(20_000, Default::default(), roomy());
        assert!(src.next_stamped().unwrap().is_ok());
        src.stop_flag().store(true, Ordering::Relaxed);
        assert!(src.next_stamped().is_none());
    }

    #[test]
    fn overflowing_camera_queues_leave_counted_gaps() {
        let params = LiveParams {
            camera_queue: 1,
            ..Default::default()
        };
        let mut src = source(60, Default::default(), params);
        let mut last = 0;
        while let Some(f) = src.next_stamped() {
            last = f.unwrap().frame.index;
            std::thread::sleep(Duration::from_millis(25)); // a consumer at 40 fps
        }
        let stats = src.stats();
        assert!(stats.cameras[0].overflow > 0 && stats.gaps > 0, "{stats:?}");
        assert_eq!(stats.frames_out + stats.gaps, last as u64 + 1);
    }

    #[test]
    fn config_loads_resolves_paths_and_rejects_mistakes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("live.toml");
        let shipped = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/live.toml"),
        )
        .unwrap();
        std::fs::write(&path, &shipped).unwrap();
        let c = LiveConfig::load(&path).unwrap();
        assert_eq!(c.camera.len(), 2);
        assert_eq!(c.camera[1].device, 2);
        assert_eq!(c.timecode_rate(), TimecodeRate::FPS_30);
        assert_eq!(c.syncbox.as_ref().unwrap().baud, 115_200);
        assert_eq!(
            c.calibration.unwrap(),
            dir.path().join("../calib/helmet-fisheye.yaml")
        );
        std::fs::write(
            &path,
            shipped.replace("pixel_format = \"gray\"", "pixel_fromat = \"gray\""),
        )
        .unwrap();
        let e = LiveConfig::load(&path).unwrap_err().to_string();
        assert!(
            e.contains("live.toml:") && e.contains("pixel_fromat"),
            "{e}"
        );
        std::fs::write(
            &path,
            "fps = 60.0\n[[camera]]\ndevice = 0\nwidth = 8\nheight = 8\n",
        )
        .unwrap();
        let e = LiveConfig::load(&path).unwrap_err().to_string();
        assert!(e.contains("1 [[camera]]"), "{e}");
    }
}
