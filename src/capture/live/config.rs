//! `configs/live.toml`: the cameras, sync box, timecode, live source, recorder and test
//! tables ([`LiveConfig`]), read with the line of every mistake, range-checked, and opened
//! as a [`LiveSource`].

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::device::{CameraConfig, CameraDevice, NokhwaCamera};
use super::source::{LiveParams, LiveSource, LiveTimecode};
use super::test_camera::{TestCamera, TestFaults, TestImages};
use crate::capture::CaptureError;
use crate::capture::syncbox::{SyncBox, SyncBoxConfig};
use crate::timecode::TimecodeRate;

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
                    let replay = crate::capture::Replay::open(
                        &root,
                        crate::capture::ReplayParams::default(),
                    )?;
                    let info = replay.info();
                    fps = info.fps;
                    if rig.is_none() {
                        rig = replay.rig().cloned();
                    }
                    let frames = info
                        .frames
                        .iter()
                        .map(|f| f.0.as_usize() + 1)
                        .max()
                        .unwrap_or(0);
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
