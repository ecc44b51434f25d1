//! [`LiveSource`]: one thread per camera, the pairing of their frames into stereo frames,
//! and the timecode stamping (see the docs of [`crate::capture::live`]).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError};

use super::device::{CameraDevice, CameraError, CapturedImage};
use crate::camera::StereoRig;
use crate::capture::syncbox::{
    SyncBox, SyncCounters, SyncHealth, TimecodeAnchor, stamp_from_anchor, time_of_day_timecode,
};
use crate::capture::{CaptureError, FrameSource, StereoFrame};
use crate::timecode::{Timecode, TimecodeRate};

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
                    index: index.into(),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::GrayImage;
    use crate::capture::live::{TestCamera, TestFaults, TestImages, test_pattern};

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
            assert_eq!(f.frame.index.as_usize(), i);
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
                assert_eq!(frame_of(&f.frame.images[0]), f.frame.index.as_usize());
                assert_eq!(frame_of(&f.frame.images[1]), f.frame.index.as_usize());
                f.frame.index.as_usize()
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
            last = f.unwrap().frame.index.as_usize();
            std::thread::sleep(Duration::from_millis(25)); // a consumer at 40 fps
        }
        let stats = src.stats();
        assert!(stats.cameras[0].overflow > 0 && stats.gaps > 0, "{stats:?}");
        assert_eq!(stats.frames_out + stats.gaps, last as u64 + 1);
    }
}
