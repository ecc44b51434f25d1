//! Replay of a recorded session folder.

use std::path::{Path, PathBuf};

use super::{CaptureError, GrayImage, read_png_gray};
use crate::camera::{StereoRig, read_rig};
use crate::timecode::{Timecode, TimecodeRate};

/// Replay settings.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ReplayParams {
    /// Go on past bad frames (missing, unreadable or wrongly sized images): each is
    /// counted in [`ReplayStats::gaps`] and logged as a warning. Default false: the first
    /// bad frame is an error.
    pub skip_bad_frames: bool,
    /// Calibration to use instead of the one `session.toml` names.
    pub calibration: Option<PathBuf>,
}

/// The session description (`session.toml` + `frames.csv`).
#[derive(Debug, Clone, PartialEq)]
pub struct SessionInfo {
    /// Session folder.
    pub root: PathBuf,
    /// Frames per second.
    pub fps: f64,
    /// Camera folder names (at least two; the first two form the stereo pair).
    pub cameras: Vec<String>,
    /// Timecode rate (`[timecode] rate` of `session.toml`; else the camera rate when it is
    /// a standard one, drop-frame when the labels use `;`).
    pub timecode_rate: Option<TimecodeRate>,
    /// Per frame: index, timestamp (ns) and timecode (None where `frames.csv` has none).
    pub frames: Vec<(usize, u64, Option<Timecode>)>,
}

/// One stereo frame.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoFrame {
    /// Frame index (as in `frames.csv`).
    pub index: usize,
    /// Capture timestamp, ns.
    pub timestamp_ns: u64,
    /// Timecode, when the source has one.
    pub timecode: Option<Timecode>,
    /// The two images (cam0, cam1).
    pub images: [GrayImage; 2],
}

/// Counts of a replay so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReplayStats {
    /// Frames delivered.
    pub frames_out: usize,
    /// Frames skipped as gaps.
    pub gaps: usize,
}

#[derive(serde::Deserialize)]
struct SessionToml {
    fps: f64,
    cameras: Vec<String>,
    calibration: Option<String>,
    timecode: Option<TimecodeToml>,
}

#[derive(serde::Deserialize)]
struct TimecodeToml {
    rate: Option<TimecodeRate>,
}

/// Reads a recording session frame by frame. Iterate with [`Replay::next_frame`] (or as an
/// [`Iterator`]).
#[derive(Debug)]
pub struct Replay {
    info: SessionInfo,
    rig: Option<StereoRig>,
    params: ReplayParams,
    next: usize,
    stats: ReplayStats,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> CaptureError {
    CaptureError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

impl Replay {
    /// Opens and checks a session: `session.toml` (fps, cameras, optional calibration),
    /// `frames.csv` (consecutive frames from 0), the camera folders, and the calibration
    /// (image sizes are then checked against it frame by frame).
    ///
    /// # Errors
    /// [`CaptureError`] naming the file and line.
    pub fn open(root: &Path, params: ReplayParams) -> Result<Self, CaptureError> {
        let toml_path = root.join("session.toml");
        let text = std::fs::read_to_string(&toml_path).map_err(|e| io_err(&toml_path, e))?;
        let session: SessionToml = toml::from_str(&text).map_err(|e| CaptureError::Format {
            path: toml_path.clone(),
            line: e
                .span()
                .map(|s| text[..s.start.min(text.len())].lines().count().max(1))
                .unwrap_or(0),
            message: e.message().to_string(),
        })?;
        let format_err = |line: usize, message: String| CaptureError::Format {
            path: toml_path.clone(),
            line,
            message,
        };
        if !(session.fps > 0.0 && session.fps <= 1000.0) {
            return Err(format_err(
                0,
                format!(
                    "fps = {} is out of range: above 0, at most 1000",
                    session.fps
                ),
            ));
        }
        if session.cameras.len() < 2 {
            return Err(format_err(
                0,
                "`cameras` must name at least two cameras".into(),
            ));
        }
        for (k, cam) in session.cameras.iter().enumerate() {
            if session.cameras[..k].contains(cam) {
                return Err(format_err(
                    0,
                    format!(
                        "`cameras` names {} twice: each camera needs its own folder",
                        crate::limits::quoted(cam)
                    ),
                ));
            }
            let dir = root.join(cam);
            if !dir.is_dir() {
                return Err(io_err(&dir, "camera folder is missing"));
            }
        }
        let calib_path = params
            .calibration
            .clone()
            .or_else(|| session.calibration.as_ref().map(|c| root.join(c)));
        let rig = calib_path.map(|p| read_rig(&p)).transpose()?;
        let frames_path = root.join("frames.csv");
        let frames_text =
            std::fs::read_to_string(&frames_path).map_err(|e| io_err(&frames_path, e))?;
        let ferr = |line: usize, message: String| CaptureError::Format {
            path: frames_path.clone(),
            line,
            message,
        };
        let mut lines = frames_text.lines().enumerate();
        match lines.next() {
            Some((_, h)) if h.trim().starts_with("frame,timestamp_ns,timecode") => {}
            _ => {
                return Err(ferr(
                    1,
                    "header must be `frame,timestamp_ns,timecode`".into(),
                ));
            }
        }
        let mut timecode_rate = session.timecode.as_ref().and_then(|t| t.rate);
        let mut frames = Vec::new();
        for (i, line) in lines {
            if line.trim().is_empty() {
                continue;
            }
            let f: Vec<&str> = line.split(',').map(str::trim).collect();
            if f.len() < 2 {
                return Err(ferr(i + 1, "expected frame,timestamp_ns,timecode".into()));
            }
            let index: usize = f[0].parse().map_err(|_| {
                ferr(
                    i + 1,
                    format!(
                        "frame {} is not a whole number",
                        crate::limits::quoted(f[0])
                    ),
                )
            })?;
            let ts: u64 = f[1].parse().map_err(|_| {
                ferr(
                    i + 1,
                    format!(
                        "timestamp {} is not a whole number",
                        crate::limits::quoted(f[1])
                    ),
                )
            })?;
            if index as u64 > crate::limits::MAX_FRAME_NUMBER {
                return Err(ferr(
                    i + 1,
                    format!(
                        "frame {index} is above the largest frame number, {}",
                        crate::limits::MAX_FRAME_NUMBER
                    ),
                ));
            }
            let previous = frames.last().map_or(0, |(p, _, _)| *p as u64);
            if index as u64 > previous + crate::limits::MAX_FRAME_GAP {
                return Err(ferr(
                    i + 1,
                    format!(
                        "frame {index} follows frame {previous}: a gap of more than {} frames \
                         (a damaged frames.csv?)",
                        crate::limits::MAX_FRAME_GAP
                    ),
                ));
            }
            if let Some((prev, prev_ts, _)) = frames.last()
                && (index <= *prev || ts < *prev_ts)
            {
                return Err(ferr(i + 1, format!("frame {index} is out of order")));
            }
            let label = f.get(2).copied().unwrap_or("");
            let timecode = if label.is_empty() {
                None
            } else {
                let rate = match timecode_rate {
                    Some(r) => r,
                    None => {
                        let r = TimecodeRate::from_fps(session.fps)
                            .ok_or_else(|| {
                                ferr(
                                    i + 1,
                                    "session.toml needs `[timecode] rate` to read timecodes".into(),
                                )
                            })
                            .and_then(|r| {
                                let df = label.contains(';');
                                TimecodeRate::new(r.nominal, r.ntsc, df)
                                    .map_err(|e| ferr(i + 1, e.to_string()))
                            })?;
                        timecode_rate = Some(r);
                        r
                    }
                };
                Some(Timecode::parse_at(label, rate).map_err(|e| ferr(i + 1, e.to_string()))?)
            };
            frames.push((index, ts, timecode));
        }
        if frames.is_empty() {
            return Err(ferr(2, "no frames".into()));
        }
        Ok(Self {
            info: SessionInfo {
                root: root.to_path_buf(),
                fps: session.fps,
                cameras: session.cameras,
                timecode_rate,
                frames,
            },
            rig,
            params,
            next: 0,
            stats: ReplayStats::default(),
        })
    }

    /// The session description.
    pub fn info(&self) -> &SessionInfo {
        &self.info
    }

    /// The calibration named by the session (or the params), if any.
    pub fn rig(&self) -> Option<&StereoRig> {
        self.rig.as_ref()
    }

    /// Keeps only the frames whose number (as in `frames.csv`) lies in `range`, from the
    /// start of the replay (to split a long take); returns how many remain.
    pub fn select_frames(&mut self, range: std::ops::RangeInclusive<usize>) -> usize {
        self.info
            .frames
            .retain(|(index, _, _)| range.contains(index));
        self.next = 0;
        self.info.frames.len()
    }

    /// Counts so far.
    pub fn stats(&self) -> ReplayStats {
        self.stats
    }

    fn load(&self, index: usize, camera: &str) -> Result<GrayImage, CaptureError> {
        let path = self.info.root.join(camera).join(format!("{index:06}.png"));
        if !path.is_file() {
            return Err(CaptureError::MissingImage { frame: index, path });
        }
        let img = read_png_gray(&path).map_err(|message| CaptureError::Decode {
            frame: index,
            path: path.clone(),
            message,
        })?;
        if let Some(rig) = &self.rig
            && (img.width, img.height) != (rig.cam0.width_px, rig.cam0.height_px)
        {
            return Err(CaptureError::Size {
                frame: index,
                path,
                width: img.width,
                height: img.height,
                expected_width: rig.cam0.width_px,
                expected_height: rig.cam0.height_px,
            });
        }
        Ok(img)
    }

    /// The next frame, `None` at the end. With `skip_bad_frames`, bad frames are counted,
    /// logged and skipped; otherwise the first one is returned as an error (and the replay
    /// moves past it).
    pub fn next_frame(&mut self) -> Option<Result<StereoFrame, CaptureError>> {
        loop {
            let (index, ts, tc) = *self.info.frames.get(self.next)?;
            self.next += 1;
            // The two images decode side by side: PNG decoding is a large part of a frame's
            // cost, and the replay source is one stage thread.
            let (first, second) = rayon::join(
                || self.load(index, &self.info.cameras[0]),
                || self.load(index, &self.info.cameras[1]),
            );
            let result = first.and_then(|a| {
                second.and_then(|b| {
                    if (a.width, a.height) != (b.width, b.height) {
                        Err(CaptureError::Size {
                            frame: index,
                            path: self
                                .info
                                .root
                                .join(&self.info.cameras[1])
                                .join(format!("{index:06}.png")),
                            width: b.width,
                            height: b.height,
                            expected_width: a.width,
                            expected_height: a.height,
                        })
                    } else {
                        Ok([a, b])
                    }
                })
            });
            match result {
                Ok(images) => {
                    self.stats.frames_out += 1;
                    return Some(Ok(StereoFrame {
                        index,
                        timestamp_ns: ts,
                        timecode: tc,
                        images,
                    }));
                }
                Err(e) if self.params.skip_bad_frames => {
                    self.stats.gaps += 1;
                    tracing::warn!("skipping {e}");
                }
                Err(e) => return Some(Err(e)),
            }
        }
    }
}

impl Iterator for Replay {
    type Item = Result<StereoFrame, CaptureError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_frame()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write_png(path: &Path, w: u32, h: u32) {
        let data: Vec<u8> = (0..w * h).map(|i| (i % 251) as u8).collect();
        crate::synth::write_png_gray(path, w, h, &data).unwrap();
    }

    /// A 3-frame session of 8×6 images without calibration.
    fn session(dir: &Path) {
        std::fs::write(
            dir.join("session.toml"),
            "fps = 60.0\ncameras = [\"cam0\", \"cam1\"]\n",
        )
        .unwrap();
        std::fs::write(
            dir.join("frames.csv"),
            "frame,timestamp_ns,timecode\n0,0,01:00:00:00\n1,16666667,\n2,33333333,01:00:00:01\n",
        )
        .unwrap();
        for c in ["cam0", "cam1"] {
            std::fs::create_dir_all(dir.join(c)).unwrap();
            for f in 0..3 {
                write_png(&dir.join(format!("{c}/{f:06}.png")), 8, 6);
            }
        }
    }

    #[test]
    fn replays_every_frame_in_order() {
        let dir = tempfile::tempdir().unwrap();
        session(dir.path());
        let replay = Replay::open(dir.path(), ReplayParams::default()).unwrap();
        let frames: Vec<StereoFrame> = replay.map(Result::unwrap).collect();
        assert_eq!(frames.len(), 3);
        assert_eq!(frames[1].timestamp_ns, 16_666_667);
        assert_eq!(
            frames[2].timecode.map(|t| t.to_string()).as_deref(),
            Some("01:00:00:01")
        );
        assert_eq!(frames[1].timecode, None);
        assert_eq!(frames[0].images[1].get(3, 0), Some(3));
    }

    #[test]
    fn bad_frames_are_errors_or_counted_gaps() {
        let dir = tempfile::tempdir().unwrap();
        session(dir.path());
        std::fs::write(dir.path().join("cam1/000001.png"), b"not a png").unwrap();
        std::fs::remove_file(dir.path().join("cam0/000002.png")).unwrap();
        let mut replay = Replay::open(dir.path(), ReplayParams::default()).unwrap();
        assert!(replay.next_frame().unwrap().is_ok());
        let e = replay.next_frame().unwrap().unwrap_err().to_string();
        assert!(
            e.contains("frame 1") && e.contains("000001.png") && e.contains("decode"),
            "{e}"
        );
        let e = replay.next_frame().unwrap().unwrap_err().to_string();
        assert!(e.contains("frame 2") && e.contains("missing"), "{e}");
        let params = ReplayParams {
            skip_bad_frames: true,
            ..Default::default()
        };
        let mut replay = Replay::open(dir.path(), params).unwrap();
        assert_eq!(replay.by_ref().count(), 1);
        assert_eq!(
            replay.stats(),
            ReplayStats {
                frames_out: 1,
                gaps: 2
            }
        );
    }

    #[test]
    fn wrong_size_and_missing_folder_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        session(dir.path());
        let rig = crate::synth::default_rig().unwrap();
        let calib = dir.path().join("rig.yaml");
        crate::camera::write_rig(&calib, &rig).unwrap();
        let params = ReplayParams {
            calibration: Some(calib),
            ..Default::default()
        };
        let mut replay = Replay::open(dir.path(), params).unwrap();
        let e = replay.next_frame().unwrap().unwrap_err().to_string();
        assert!(e.contains("8×6") && e.contains("1280×1024"), "{e}");
        std::fs::remove_dir_all(dir.path().join("cam1")).unwrap();
        let e = Replay::open(dir.path(), ReplayParams::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("cam1") && e.contains("missing"), "{e}");
        std::fs::write(dir.path().join("session.toml"), "fps = \"x\"\n").unwrap();
        let e = Replay::open(dir.path(), ReplayParams::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("session.toml:1"), "{e}");
    }
}
