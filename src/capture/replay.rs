//! Replay of a recorded session folder: image folders (`<camera>/NNNNNN.png`, any format
//! [`read_gray`] reads) or one video file per camera (`[video]` in `session.toml`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::video::{VideoReader, probe_timecode};
use super::{CaptureError, GrayConversion, GrayImage, read_gray};
use crate::camera::{StereoRig, read_rig};
use crate::frame_index::FrameIndex;
use crate::timecode::{Timecode, TimecodeClock, TimecodeRate};

/// Replay settings.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ReplayParams {
    /// Go on past bad frames (missing, unreadable or wrongly sized images): each is
    /// counted in [`ReplayStats::gaps`] and logged as a warning. Default false: the first
    /// bad frame is an error.
    pub skip_bad_frames: bool,
    /// Calibration to use instead of the one `session.toml` names.
    pub calibration: Option<PathBuf>,
    /// How colour frames become grey (the capture profile's choice). Default Rec. 601
    /// luma.
    pub gray_conversion: GrayConversion,
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
    /// For a video session without `frames.csv` the timestamps here are nominal
    /// (`index / fps`); the frames delivered carry the container's.
    pub frames: Vec<(FrameIndex, u64, Option<Timecode>)>,
    /// The capture profile `session.toml` names (`profile = "..."`, relative to the
    /// session folder), if any.
    pub profile: Option<PathBuf>,
    /// The video files of the stereo pair (cam0, cam1) for a video session.
    pub videos: Option<[PathBuf; 2]>,
}

/// One stereo frame.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoFrame {
    /// Frame index (as in `frames.csv`).
    pub index: FrameIndex,
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
    profile: Option<String>,
    video: Option<BTreeMap<String, String>>,
}

#[derive(serde::Deserialize)]
struct TimecodeToml {
    rate: Option<TimecodeRate>,
    start: Option<String>,
}

/// Where the frames come from.
#[derive(Debug)]
enum Media {
    /// `<camera>/NNNNNN.png` files.
    Images,
    /// One video per camera of the pair; `container_timestamps`: the frames' timestamps
    /// are the containers' (no `frames.csv`).
    Videos {
        readers: Box<[VideoReader; 2]>,
        container_timestamps: bool,
    },
}

/// Reads a recording session frame by frame. Iterate with [`Replay::next_frame`] (or as an
/// [`Iterator`]).
#[derive(Debug)]
pub struct Replay {
    info: SessionInfo,
    rig: Option<StereoRig>,
    params: ReplayParams,
    media: Media,
    next: usize,
    stats: ReplayStats,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> CaptureError {
    CaptureError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

/// Parses `frames.csv`; fills `timecode_rate` from the first timecode when it is unset.
fn read_frames_csv(
    frames_path: &Path,
    fps: f64,
    timecode_rate: &mut Option<TimecodeRate>,
) -> Result<Vec<(FrameIndex, u64, Option<Timecode>)>, CaptureError> {
    let frames_text = std::fs::read_to_string(frames_path).map_err(|e| io_err(frames_path, e))?;
    let ferr = |line: usize, message: String| CaptureError::Format {
        path: frames_path.to_path_buf(),
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
    let mut frames: Vec<(FrameIndex, u64, Option<Timecode>)> = Vec::new();
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if f.len() < 2 {
            return Err(ferr(i + 1, "expected frame,timestamp_ns,timecode".into()));
        }
        let index: u64 = f[0].parse().map_err(|_| {
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
        if index > crate::limits::MAX_FRAME_NUMBER {
            return Err(ferr(
                i + 1,
                format!(
                    "frame {index} is above the largest frame number, {}",
                    crate::limits::MAX_FRAME_NUMBER
                ),
            ));
        }
        let previous = frames.last().map_or(0, |(p, _, _)| p.get());
        if index > previous + crate::limits::MAX_FRAME_GAP {
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
            && (index <= prev.get() || ts < *prev_ts)
        {
            return Err(ferr(i + 1, format!("frame {index} is out of order")));
        }
        let label = f.get(2).copied().unwrap_or("");
        let timecode = if label.is_empty() {
            None
        } else {
            let rate = match *timecode_rate {
                Some(r) => r,
                None => {
                    let r = rate_for_label(fps, label).ok_or_else(|| {
                        ferr(
                            i + 1,
                            "session.toml needs `[timecode] rate` to read timecodes".into(),
                        )
                    })?;
                    *timecode_rate = Some(r);
                    r
                }
            };
            Some(Timecode::parse_at(label, rate).map_err(|e| ferr(i + 1, e.to_string()))?)
        };
        frames.push((FrameIndex::new(index), ts, timecode));
    }
    if frames.is_empty() {
        return Err(ferr(2, "no frames".into()));
    }
    Ok(frames)
}

/// The timecode rate of a label at camera rate `fps` (when that is a standard rate):
/// drop-frame when the label uses `;`.
fn rate_for_label(fps: f64, label: &str) -> Option<TimecodeRate> {
    let r = TimecodeRate::from_fps(fps)?;
    TimecodeRate::new(r.nominal, r.ntsc, label.contains(';') && r.ntsc).ok()
}

/// Reads one image of a frame and checks its size against the calibration.
fn load_image(
    root: &Path,
    camera: &str,
    index: FrameIndex,
    rig: Option<&StereoRig>,
    conversion: GrayConversion,
) -> Result<GrayImage, CaptureError> {
    let path = root.join(camera).join(format!("{index:06}.png"));
    if !path.is_file() {
        return Err(CaptureError::MissingImage { frame: index, path });
    }
    let img = read_gray(&path, conversion).map_err(|e| CaptureError::Decode {
        frame: index,
        path: path.clone(),
        message: e.message,
    })?;
    check_size(index, path, img, rig)
}

/// The image when its size is the calibration's, else [`CaptureError::Size`].
fn check_size(
    index: FrameIndex,
    path: PathBuf,
    img: GrayImage,
    rig: Option<&StereoRig>,
) -> Result<GrayImage, CaptureError> {
    if let Some(rig) = rig
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

/// Opens the two videos of the stereo pair and checks them against each other and the
/// session's frame rate.
fn open_videos(
    root: &Path,
    toml_path: &Path,
    fps: f64,
    cameras: &[String],
    video: &BTreeMap<String, String>,
) -> Result<[VideoReader; 2], CaptureError> {
    let file_of = |camera: &String| {
        video.get(camera).ok_or_else(|| CaptureError::Format {
            path: toml_path.to_path_buf(),
            line: 0,
            message: format!("[video] names no file for camera {camera:?}"),
        })
    };
    let pair = super::video::open_pair(
        &root.join(file_of(&cameras[0])?),
        &root.join(file_of(&cameras[1])?),
    )?;
    for v in &pair {
        if (v.fps() - fps).abs() > 1e-3 * fps {
            return Err(io_err(
                v.path(),
                format!(
                    "the video runs at {} fps, session.toml says fps = {fps}",
                    v.fps()
                ),
            ));
        }
    }
    Ok(pair)
}

impl Replay {
    /// Opens and checks a session: `session.toml` (fps, cameras, optional calibration,
    /// optional `[video]`), `frames.csv` (consecutive frames from 0; optional for a video
    /// session), the camera folders or videos, and the calibration (image sizes are then
    /// checked against it frame by frame).
    ///
    /// A video session's timecode: `frames.csv`'s where it has one; else the timecode
    /// track of cam0's video (read with `ffprobe` when it is installed); else `[timecode]
    /// start` of `session.toml`; else none.
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
        if !(session.fps > 0.0 && session.fps.is_finite()) {
            return Err(format_err(
                0,
                format!("fps {} must be positive", session.fps),
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
        }
        let videos = match &session.video {
            Some(video) => Some(open_videos(
                root,
                &toml_path,
                session.fps,
                &session.cameras,
                video,
            )?),
            None => {
                for cam in &session.cameras {
                    let dir = root.join(cam);
                    if !dir.is_dir() {
                        return Err(io_err(&dir, "camera folder is missing"));
                    }
                }
                None
            }
        };
        let calib_path = params
            .calibration
            .clone()
            .or_else(|| session.calibration.as_ref().map(|c| root.join(c)));
        let rig = calib_path.map(|p| read_rig(&p)).transpose()?;
        let frames_path = root.join("frames.csv");
        let mut timecode_rate = session.timecode.as_ref().and_then(|t| t.rate);
        let frames = match &videos {
            Some([v0, _]) if !frames_path.exists() => {
                let start = probe_timecode(v0.path())
                    .map(|label| (label, v0.path().to_path_buf()))
                    .or_else(|| {
                        session
                            .timecode
                            .as_ref()
                            .and_then(|t| t.start.clone())
                            .map(|label| (label, toml_path.clone()))
                    });
                let clock = match start {
                    Some((label, from)) => {
                        let rate = timecode_rate
                            .or_else(|| rate_for_label(session.fps, &label))
                            .ok_or_else(|| {
                                format_err(
                                    0,
                                    format!(
                                        "timecode {label} of {}: session.toml needs \
                                         `[timecode] rate` to read it",
                                        from.display()
                                    ),
                                )
                            })?;
                        timecode_rate = Some(rate);
                        let start = Timecode::parse_at(&label, rate).map_err(|e| {
                            format_err(0, format!("timecode of {}: {e}", from.display()))
                        })?;
                        Some(TimecodeClock::new(start, session.fps))
                    }
                    None => None,
                };
                (0..v0.frame_count())
                    .map(|i| {
                        (
                            FrameIndex::from(i),
                            (i as f64 * 1e9 / session.fps).round() as u64,
                            clock.map(|c| c.stamp(i as u64)),
                        )
                    })
                    .collect()
            }
            _ => {
                let frames = read_frames_csv(&frames_path, session.fps, &mut timecode_rate)?;
                if let (Some([v0, _]), Some((last, _, _))) = (&videos, frames.last())
                    && last.as_usize() >= v0.frame_count()
                {
                    return Err(CaptureError::Format {
                        path: frames_path,
                        line: 0,
                        message: format!(
                            "names frame {last}, but {} has {} frames",
                            v0.path().display(),
                            v0.frame_count()
                        ),
                    });
                }
                frames
            }
        };
        let media = match videos {
            Some(readers) => Media::Videos {
                readers: Box::new(readers),
                container_timestamps: !frames_path.exists(),
            },
            None => Media::Images,
        };
        let video_paths = match &media {
            Media::Videos { readers, .. } => Some([
                readers[0].path().to_path_buf(),
                readers[1].path().to_path_buf(),
            ]),
            Media::Images => None,
        };
        Ok(Self {
            info: SessionInfo {
                root: root.to_path_buf(),
                fps: session.fps,
                cameras: session.cameras,
                timecode_rate,
                frames,
                profile: session.profile.map(|p| root.join(p)),
                videos: video_paths,
            },
            rig,
            params,
            media,
            next: 0,
            stats: ReplayStats::default(),
        })
    }

    /// How colour images become grey from now on (a capture profile named in
    /// `session.toml` is only known once the session is open).
    pub fn set_gray_conversion(&mut self, conversion: GrayConversion) {
        self.params.gray_conversion = conversion;
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
    pub fn select_frames(&mut self, range: std::ops::RangeInclusive<FrameIndex>) -> usize {
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

    /// Both images of frame `index` (and the container's timestamp for a video session
    /// without `frames.csv`).
    fn load_pair(
        &mut self,
        index: FrameIndex,
    ) -> Result<([GrayImage; 2], Option<u64>), CaptureError> {
        let conversion = self.params.gray_conversion;
        let rig = self.rig.as_ref();
        let (first, second, second_path, timestamp) = match &mut self.media {
            Media::Images => {
                let root = &self.info.root;
                let cameras = &self.info.cameras;
                // One after the other, on the caller's thread: in a pipeline that is
                // the source's thread, which reads ahead at a lower priority than the
                // track stage and so decodes while the cores would otherwise idle (see
                // `pipeline::priority`); side by side in the shared thread pool the
                // decoding took the cores from the detection instead.
                let a = load_image(root, &cameras[0], index, rig, conversion);
                let b = load_image(root, &cameras[1], index, rig, conversion);
                (
                    a,
                    b,
                    root.join(&cameras[1]).join(format!("{index:06}.png")),
                    None,
                )
            }
            Media::Videos {
                readers,
                container_timestamps,
            } => {
                let [r0, r1] = &mut **readers;
                let path1 = r1.path().to_path_buf();
                // One after the other, as the images above.
                let a = r0.read_at(index.as_usize());
                let b = r1.read_at(index.as_usize());
                let timestamp = match (&a, *container_timestamps) {
                    (Ok(f), true) => Some(f.timestamp_ns),
                    _ => None,
                };
                let gray = |r: &VideoReader, f: Result<super::video::VideoFrame, CaptureError>| {
                    f.and_then(|f| {
                        check_size(index, r.path().to_path_buf(), f.into_gray(conversion), rig)
                    })
                };
                (gray(r0, a), gray(r1, b), path1, timestamp)
            }
        };
        let (a, b) = (first?, second?);
        if (a.width, a.height) != (b.width, b.height) {
            return Err(CaptureError::Size {
                frame: index,
                path: second_path,
                width: b.width,
                height: b.height,
                expected_width: a.width,
                expected_height: a.height,
            });
        }
        Ok(([a, b], timestamp))
    }

    /// The next frame, `None` at the end. With `skip_bad_frames`, bad frames are counted,
    /// logged and skipped; otherwise the first one is returned as an error (and the replay
    /// moves past it).
    pub fn next_frame(&mut self) -> Option<Result<StereoFrame, CaptureError>> {
        loop {
            let (index, ts, tc) = *self.info.frames.get(self.next)?;
            self.next += 1;
            match self.load_pair(index) {
                Ok((images, container_ts)) => {
                    self.stats.frames_out += 1;
                    return Some(Ok(StereoFrame {
                        index,
                        timestamp_ns: container_ts.unwrap_or(ts),
                        timecode: tc,
                        images,
                    }));
                }
                Err(e) => {
                    // A video that ended early: the rest of the take is gone too.
                    if matches!(e, CaptureError::VideoEnded { .. }) {
                        let rest = self.info.frames.len() - self.next;
                        self.next = self.info.frames.len();
                        if self.params.skip_bad_frames {
                            self.stats.gaps += 1 + rest;
                            tracing::warn!("skipping the last {} frames: {e}", 1 + rest);
                            return None;
                        }
                        return Some(Err(e));
                    }
                    if self.params.skip_bad_frames {
                        self.stats.gaps += 1;
                        tracing::warn!("skipping {e}");
                    } else {
                        return Some(Err(e));
                    }
                }
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
        let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
        let mut enc = png::Encoder::new(file, w, h);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header().unwrap().write_image_data(&data).unwrap();
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
        let rig = crate::camera::default_helmet_rig().unwrap();
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
