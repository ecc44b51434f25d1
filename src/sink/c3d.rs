//! C3D export of the labeled bundles (`bundles.c3d`), the motion-capture industry's marker
//! format, written by hand after the C3D specification (C3D.ORG, "The C3D File Format
//! User Guide"): Intel byte order, floating-point data, one 512-byte header block, the
//! parameter section from block 2, then the 3D data frame after frame.
//!
//! - Points: the layout's markers in layout order, labelled with their names
//!   (`POINT:LABELS`, more than 255 markers continue in `LABELS2`, ...), millimetres in the
//!   head frame (`POINT:UNITS = "mm"`), `POINT:RATE` = the camera rate.
//! - Frame numbers are 1-based in C3D: the first frame written is C3D frame `index + 1`
//!   (header word 4, and `TRIAL:ACTUAL_START_FIELD`). Frames missing from the take (source
//!   gaps) are written with every point invalid, so C3D frame numbers stay consecutive.
//! - Per point, the fourth word holds the camera mask (high byte) and the residual (low
//!   byte, in units of |`POINT:SCALE`| = 0.1 mm): observed bundles are seen by cameras 1
//!   and 2 with the triangulation's reprojection error converted to mm at the marker's
//!   depth (at least 1 unit); gap-filled bundles have residual 0 and no camera (the C3D
//!   convention for interpolated points); dropped and missing markers are invalid (the
//!   word is −1, coordinates 0).
//! - Timecode, when the take has one, in the `TIMECODE` group: `START` (the first frame's
//!   timecode with its rate, `01:00:00:00.0@30`), `RATE` (`30`, `29.97df`, ...),
//!   `DROP_FRAMES` (0/1), `SUBFRAMES_PER_FRAME` (camera frames per timecode frame) and
//!   `FIRST_FRAME` (the C3D frame the start timecode belongs to, two 16-bit words: low,
//!   high).
//!
//! - Long takes (C3D.ORG, "Maintaining C3D frame count compatibility"): the header's
//!   16-bit frame range cannot pass 65,535. Beyond it the header says 1 to 65,535 (what
//!   older readers expect), `POINT:FRAMES` holds the count as a float (it is an integer up
//!   to 32,767), `POINT:LONG_FRAMES` holds it too, and `TRIAL:ACTUAL_START_FIELD` /
//!   `ACTUAL_END_FIELD` (always written, two 16-bit words: low, high) give the true
//!   range. At 60 fps 65,535 frames are 18 minutes; the float count is exact to 16.7
//!   million frames (77 hours).
//!
//! The file is written in place as frames arrive: a temporary file beside `bundles.c3d`
//! starts with the header block and room for the parameter section (sized at the start
//! for the worst case: a long take with timecode), then the frames; after every frame the
//! data is padded to a block boundary and marked complete. [`Sink::finish`] writes header
//! and parameters into their room and publishes the file atomically. No step needs more
//! disk space than the frames themselves: when a write fails (disk full), the file is cut
//! back to the last complete frame and published with the frames before it.

use std::io::{Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use super::staged_file::StagedFile;
use crate::pipeline::{BundleStatus, FrameResult, Metrics, SessionMeta, Sink, SinkError};
use crate::timecode::Timecode;

/// `POINT:SCALE`: negative = floating-point data; its magnitude is the residual unit, mm.
const POINT_SCALE: f32 = -0.1;
/// Processor type of the parameter section: Intel.
const PROCESSOR_INTEL: u8 = 84;
/// Largest C3D frame number the 16-bit header fields hold.
const MAX_HEADER_FRAME: usize = 65_535;
/// Largest frame number of the two-word `TRIAL` fields, and largest count a float
/// `POINT:FRAMES` holds exactly (2^24).
const MAX_FRAME: usize = 1 << 24;

/// A parameter value.
#[derive(Clone)]
enum Value {
    Int(Vec<i16>),
    Float(Vec<f32>),
    /// One string.
    Text(String),
    /// Several strings padded to one length (a 2D char array).
    Texts(Vec<String>),
}

/// Serializes the parameter section (groups, then parameters), padded to whole blocks.
struct ParameterWriter {
    groups: Vec<(String, String)>,
    params: Vec<(usize, String, String, Value)>,
}

impl ParameterWriter {
    fn new() -> Self {
        Self {
            groups: Vec::new(),
            params: Vec::new(),
        }
    }

    fn group(&mut self, name: &str, description: &str) -> usize {
        self.groups.push((name.into(), description.into()));
        self.groups.len()
    }

    fn param(&mut self, group: usize, name: &str, description: &str, value: Value) {
        self.params
            .push((group, name.into(), description.into(), value));
    }

    /// The records; `Err` names what does not fit the format's byte-sized fields.
    fn bytes(&self) -> Result<Vec<u8>, String> {
        let mut records: Vec<Vec<u8>> = Vec::new();
        let short = |s: &str, what: &str| -> Result<u8, String> {
            u8::try_from(s.len())
                .ok()
                .filter(|&n| n <= 127)
                .ok_or_else(|| format!("{what} {s:?} is too long for C3D"))
        };
        for (id, (name, desc)) in self.groups.iter().enumerate() {
            let mut r = vec![short(name, "group name")?, (-(id as i8 + 1)) as u8];
            r.extend(name.to_ascii_uppercase().bytes());
            let desc_len = u8::try_from(desc.len()).map_err(|_| "description too long")?;
            r.extend(((3 + desc.len()) as u16).to_le_bytes());
            r.push(desc_len);
            r.extend(desc.bytes());
            records.push(r);
        }
        for (group, name, desc, value) in &self.params {
            let mut body: Vec<u8> = Vec::new();
            match value {
                Value::Int(v) => {
                    body.push(2);
                    push_dims(&mut body, &scalar_or_vector(v.len()))?;
                    v.iter().for_each(|x| body.extend(x.to_le_bytes()));
                }
                Value::Float(v) => {
                    body.push(4);
                    push_dims(&mut body, &scalar_or_vector(v.len()))?;
                    v.iter().for_each(|x| body.extend(x.to_le_bytes()));
                }
                Value::Text(s) => {
                    body.push(0xFF); // −1: char
                    push_dims(&mut body, &[s.len()])?;
                    body.extend(s.bytes());
                }
                Value::Texts(v) => {
                    let len = v.iter().map(String::len).max().unwrap_or(1).max(1);
                    body.push(0xFF);
                    push_dims(&mut body, &[len, v.len()])?;
                    for s in v {
                        body.extend(s.bytes());
                        body.extend(std::iter::repeat_n(b' ', len - s.len()));
                    }
                }
            }
            let desc_len = u8::try_from(desc.len()).map_err(|_| "description too long")?;
            body.push(desc_len);
            body.extend(desc.bytes());
            let mut r = vec![short(name, "parameter name")?, *group as u8];
            r.extend(name.to_ascii_uppercase().bytes());
            let offset = u16::try_from(2 + body.len())
                .map_err(|_| format!("parameter {name} is too large for C3D"))?;
            r.extend(offset.to_le_bytes());
            r.extend(body);
            records.push(r);
        }
        // The last record's offset is 0: the end of the parameters.
        if let Some(last) = records.last_mut() {
            let name_len = usize::from(last[0]);
            last[2 + name_len] = 0;
            last[3 + name_len] = 0;
        }
        let body: Vec<u8> = records.concat();
        let blocks = (4 + body.len()).div_ceil(512);
        let mut out = vec![
            1,
            0x50,
            u8::try_from(blocks).map_err(|_| "too many parameters")?,
            PROCESSOR_INTEL,
        ];
        out.extend(body);
        out.resize(blocks * 512, 0);
        Ok(out)
    }
}

/// Dimensions of a numeric parameter: none for one value, else one.
fn scalar_or_vector(len: usize) -> Vec<usize> {
    if len == 1 { Vec::new() } else { vec![len] }
}

fn push_dims(body: &mut Vec<u8>, dims: &[usize]) -> Result<(), String> {
    body.push(dims.len() as u8);
    for &d in dims {
        body.push(u8::try_from(d).map_err(|_| format!("dimension {d} is above 255"))?);
    }
    Ok(())
}

/// Writes `bundles.c3d` (see the module docs).
#[derive(Debug)]
pub struct C3dSink {
    path: PathBuf,
    fps: f64,
    labels: Vec<String>,
    focal_px: f64,
    data: Option<StagedFile>,
    first_frame: Option<usize>,
    next_frame: usize,
    first_timecode: Option<(usize, Timecode)>,
    /// Parameter blocks reserved after the header.
    param_blocks: usize,
    /// Bytes of frame data written (complete frames), not counting the padding.
    data_len: u64,
    /// `first_frame`, `next_frame`, `first_timecode` and `data_len` of the complete frames
    /// (for a roll-back).
    complete: (Option<usize>, usize, Option<(usize, Timecode)>, u64),
}

impl C3dSink {
    /// A sink writing `path` (e.g. `<out>/bundles.c3d`).
    pub fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            fps: 0.0,
            labels: Vec::new(),
            focal_px: f64::NAN,
            data: None,
            first_frame: None,
            next_frame: 0,
            first_timecode: None,
            param_blocks: 0,
            data_len: 0,
            complete: (None, 0, None, 0),
        }
    }

    /// Byte offset of the 3D data: the header block and the reserved parameter blocks.
    fn data_start(&self) -> u64 {
        512 * (1 + self.param_blocks as u64)
    }

    /// Pads the data to a block boundary with zeros and marks it complete; the writer then
    /// stands at the end of the data again (the next frame overwrites the padding).
    fn pad_and_mark(&mut self) -> Result<(), SinkError> {
        let data_end = self.data_start() + self.data_len;
        let pad = (data_end.div_ceil(512) * 512 - data_end) as usize;
        let data = self
            .data
            .as_mut()
            .ok_or_else(|| SinkError::Other("c3d sink written before begin".into()))?;
        data.write_with(|w| w.write_all(&vec![0u8; pad]))?;
        data.mark_complete()?;
        data.write_with(|w| w.seek(SeekFrom::Start(data_end)).map(drop))
    }

    /// After a failed write: back to the last complete frame (padding rewritten).
    fn roll_back(&mut self) -> Result<(), SinkError> {
        (
            self.first_frame,
            self.next_frame,
            self.first_timecode,
            self.data_len,
        ) = self.complete;
        let data_end = self.data_start() + self.data_len;
        let data = self
            .data
            .as_mut()
            .ok_or_else(|| SinkError::Other("c3d sink written before begin".into()))?;
        data.roll_back()?;
        let complete = data.complete_len().unwrap_or(0);
        // The padding's bytes exist on disk (no new space): zero them again.
        data.write_with(|w| {
            w.seek(SeekFrom::Start(data_end))?;
            w.write_all(&vec![0u8; complete.saturating_sub(data_end) as usize])?;
            w.flush()?;
            w.seek(SeekFrom::Start(data_end)).map(drop)
        })
    }

    fn invalid_frame(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.labels.len() * 16);
        for _ in &self.labels {
            for v in [0.0f32, 0.0, 0.0, -1.0] {
                out.extend(v.to_le_bytes());
            }
        }
        out
    }
}

impl Sink for C3dSink {
    fn name(&self) -> &str {
        "c3d"
    }

    fn begin(&mut self, session: &SessionMeta) -> Result<(), SinkError> {
        if let Some(dir) = self.path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| SinkError::io(dir, e))?;
        }
        self.labels = session
            .layout
            .markers
            .iter()
            .map(|m| m.name.clone())
            .collect();
        if let Some(l) = self.labels.iter().find(|l| l.len() > 255 || !l.is_ascii()) {
            return Err(SinkError::Other(format!(
                "marker name {l:?} cannot be a C3D label (ASCII, at most 255 characters)"
            )));
        }
        self.fps = session.fps;
        self.focal_px = session.rig.as_ref().map_or(f64::NAN, |r| r.cam0.fx());
        // Room for the parameters: their size without the optional ones, plus one block
        // for LONG_FRAMES and the TIMECODE group (a few hundred bytes).
        // (`base` is the header block and the parameter blocks: one block more than those.)
        let base = self.header_and_params(0)?;
        self.param_blocks = base.len() / 512;
        let mut data = StagedFile::create(&self.path)?;
        let start = vec![0u8; 512 * (1 + self.param_blocks)];
        data.write_with(|w| w.write_all(&start))?;
        self.data = Some(data);
        self.data_len = 0;
        self.pad_and_mark()
    }

    fn write(&mut self, f: &FrameResult) -> Result<(), SinkError> {
        let result = self.append(f).and_then(|()| self.pad_and_mark());
        match result {
            Ok(()) => {
                self.complete = (
                    self.first_frame,
                    self.next_frame,
                    self.first_timecode,
                    self.data_len,
                );
                Ok(())
            }
            Err(e) => {
                if let Err(r) = self.roll_back() {
                    tracing::error!(
                        "{}: cannot go back to the last frame: {r}",
                        self.path.display()
                    );
                    // Unpublishable: dropping the staged file removes it.
                    self.data = None;
                }
                Err(e)
            }
        }
    }

    fn finish(&mut self, _metrics: &Metrics) -> Result<(), SinkError> {
        let Some(mut data) = self.data.take() else {
            return Ok(());
        };
        let head = self.header_and_params(self.param_blocks)?;
        // Header and parameters go into their reserved room: no new space is needed.
        let written = data.write_with(|w| {
            w.seek(SeekFrom::Start(0))?;
            w.write_all(&head)
        });
        if written.is_err() {
            // The reserved room exists on disk; a failure here is a failing device.
            data.roll_back()?;
        }
        written?;
        data.commit()
    }
}

/// A chunk's `bundles.c3d` to join: the file and the first and last frame it holds (the
/// first and last frame its run wrote; the sink writes every frame between them).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct C3dPart {
    /// The file.
    pub path: PathBuf,
    /// First frame index in it.
    pub first_frame: usize,
    /// Last frame index in it.
    pub last_frame: usize,
}

/// Joins the `bundles.c3d` files of consecutive chunks of a take into one file at `out`:
/// what one [`C3dSink`] over all their frames writes. The frame data are copied as they
/// are, frames between two parts (source gaps) are written with every point invalid, and
/// the header and parameters are made for the whole range, with `labels` (the layout's
/// markers), `fps`, and the take's first timecode (frame index and timecode).
///
/// # Errors
/// A part that is not a C3D file of `labels.len()` float points holding its frames, parts
/// out of order, a file that cannot be read or written.
pub fn join_c3d(
    out: &Path,
    parts: &[C3dPart],
    labels: Vec<String>,
    fps: f64,
    first_timecode: Option<(usize, Timecode)>,
) -> Result<(), SinkError> {
    let mut sink = C3dSink::new(out);
    sink.labels = labels;
    sink.fps = fps;
    let base = sink.header_and_params(0)?;
    sink.param_blocks = base.len() / 512;
    let mut data = StagedFile::create(out)?;
    data.write_with(|w| w.write_all(&vec![0u8; 512 * (1 + sink.param_blocks)]))?;
    sink.data = Some(data);
    let frame_bytes = sink.labels.len() * 16;
    for part in parts {
        let bad = |m: String| SinkError::Other(format!("{}: {m}", part.path.display()));
        let bytes = std::fs::read(&part.path).map_err(|e| SinkError::io(&part.path, e))?;
        if bytes.len() < 512 || bytes[1] != 0x50 {
            return Err(bad("not a C3D file".into()));
        }
        let word = |i: usize| u16::from_le_bytes([bytes[2 * i], bytes[2 * i + 1]]) as usize;
        if word(1) != sink.labels.len() {
            return Err(bad(format!(
                "{} points per frame, the take has {} markers",
                word(1),
                sink.labels.len()
            )));
        }
        let start = word(8).saturating_sub(1) * 512;
        if part.last_frame < part.first_frame {
            return Err(bad("holds no frame".into()));
        }
        let n = part.last_frame - part.first_frame + 1;
        let end = start + n * frame_bytes;
        if start < 512 || end > bytes.len() {
            return Err(bad(format!(
                "holds fewer than the {n} frames its run wrote (cut short?)"
            )));
        }
        if sink.first_frame.is_none() {
            sink.first_frame = Some(part.first_frame);
            sink.next_frame = part.first_frame;
        }
        if part.first_frame < sink.next_frame {
            return Err(bad(format!(
                "starts at frame {}, before the end of the parts before it (frame {})",
                part.first_frame,
                sink.next_frame - 1
            )));
        }
        let missing = (part.first_frame - sink.next_frame) as u64;
        let gap = sink.invalid_frame();
        let chunk = &bytes[start..end];
        let data = sink
            .data
            .as_mut()
            .ok_or_else(|| SinkError::Other("c3d join without a file".into()))?;
        data.write_with(|w| {
            for _ in 0..missing {
                w.write_all(&gap)?;
            }
            w.write_all(chunk)
        })?;
        sink.data_len += missing * gap.len() as u64 + chunk.len() as u64;
        sink.next_frame = part.last_frame + 1;
    }
    sink.first_timecode = first_timecode;
    sink.pad_and_mark()?;
    sink.finish(&Metrics::default())
}

impl C3dSink {
    /// Appends frame `f` (and empty frames for a gap before it) to the data.
    fn append(&mut self, f: &FrameResult) -> Result<(), SinkError> {
        // C3D numbers frames from 1 in a 32-bit field: the index is an array position here.
        let index = f.index.as_usize();
        if self.first_frame.is_none() {
            self.first_frame = Some(index);
            self.next_frame = index;
        }
        if index < self.next_frame {
            return Err(SinkError::Other(format!(
                "frame {} arrived after frame {}",
                index,
                self.next_frame - 1
            )));
        }
        let first = self.first_frame.unwrap_or(index);
        if index + 1 > MAX_FRAME || index - first + 1 > MAX_FRAME {
            return Err(SinkError::Other(format!(
                "C3D frame numbers end at {MAX_FRAME}; split the take (--frames)"
            )));
        }
        let missing = (index - self.next_frame) as u64;
        if missing > crate::limits::MAX_FRAME_GAP {
            return Err(SinkError::Other(format!(
                "frame {} follows frame {}: a gap of {missing} frames is above the limit of {} \
                 (C3D would fill it with empty frames)",
                index,
                self.next_frame.saturating_sub(1),
                crate::limits::MAX_FRAME_GAP
            )));
        }
        // Missing frames are streamed one by one: a gap never sits in memory whole.
        if missing > 0 {
            let gap = self.invalid_frame();
            let data = self
                .data
                .as_mut()
                .ok_or_else(|| SinkError::Other("c3d sink written before begin".into()))?;
            data.write_with(|w| {
                for _ in 0..missing {
                    w.write_all(&gap)?;
                }
                Ok(())
            })?;
            self.data_len += missing * gap.len() as u64;
        }
        let mut bytes = Vec::with_capacity(f.markers.len() * 16);
        for r in &f.markers {
            let (p, word) = match (r.status, r.point_in_head) {
                (BundleStatus::Observed, Some(p)) => {
                    let depth = r.point_in_cam0.map_or(f64::NAN, |c| c.z);
                    let mm = r.reprojection_px * depth / self.focal_px;
                    let units = if mm.is_finite() {
                        (mm / f64::from(POINT_SCALE.abs()))
                            .round()
                            .clamp(1.0, 127.0)
                    } else {
                        1.0
                    };
                    // Cameras 1 and 2 (bits 0 and 1 of the high byte), residual low byte.
                    (p, f32::from((0b11i16 << 8) | units as i16))
                }
                (BundleStatus::GapFilled, Some(p)) => (p, 0.0),
                _ => (nalgebra::Point3::origin(), -1.0),
            };
            for v in [p.x as f32, p.y as f32, p.z as f32, word] {
                bytes.extend(v.to_le_bytes());
            }
        }
        if let Some(tc) = f.timecode {
            self.first_timecode.get_or_insert((index, tc));
        }
        self.next_frame = index + 1;
        self.data_len += bytes.len() as u64;
        match &mut self.data {
            Some(d) => d.write_with(|w| w.write_all(&bytes)),
            None => Err(SinkError::Other("c3d sink written before begin".into())),
        }
    }

    /// The header block and the parameter section for the frames written so far, the
    /// parameters padded to at least `min_param_blocks` blocks.
    fn header_and_params(&self, min_param_blocks: usize) -> Result<Vec<u8>, SinkError> {
        let points = self.labels.len();
        let first = self.first_frame.unwrap_or(0) + 1;
        let frames = self.first_frame.map_or(0, |f| self.next_frame - f);
        let last = first + frames.max(1) - 1;
        // Past the header's 16-bit range, the header says 1..=65,535 and the TRIAL
        // fields carry the true range (see the module docs).
        let (first16, last16) = match (u16::try_from(first), u16::try_from(last)) {
            (Ok(a), Ok(b)) => (a, b),
            _ => (1, frames.clamp(1, MAX_HEADER_FRAME) as u16),
        };
        let long_take = frames > MAX_HEADER_FRAME;
        let frames_value = match i16::try_from(frames) {
            Ok(n) => Value::Int(vec![n]),
            Err(_) => Value::Float(vec![frames as f32]),
        };
        let points16 = i16::try_from(points)
            .map_err(|_| SinkError::Other(format!("{points} markers do not fit C3D")))?;
        let rate = self.fps as f32;
        let other = |e: String| SinkError::Other(format!("{}: {e}", self.path.display()));
        // The parameter section's size does not depend on DATA_START's value: build it
        // once to size it, then with the right value.
        let build = |data_start: u16| -> Result<Vec<u8>, String> {
            let mut p = ParameterWriter::new();
            let point = p.group("POINT", "3D point parameters");
            p.param(
                point,
                "USED",
                "markers per frame",
                Value::Int(vec![points16]),
            );
            p.param(point, "FRAMES", "frames", frames_value.clone());
            if long_take {
                p.param(
                    point,
                    "LONG_FRAMES",
                    "frames (more than 65535)",
                    Value::Float(vec![frames as f32]),
                );
            }
            p.param(
                point,
                "DATA_START",
                "first block of 3D data",
                Value::Int(vec![data_start as i16]),
            );
            p.param(
                point,
                "SCALE",
                "negative: float data; residual unit, mm",
                Value::Float(vec![POINT_SCALE]),
            );
            p.param(point, "RATE", "frames per second", Value::Float(vec![rate]));
            p.param(
                point,
                "UNITS",
                "millimetres, head frame",
                Value::Text("mm".into()),
            );
            for (k, chunk) in self.labels.chunks(255).enumerate() {
                let suffix = if k == 0 {
                    String::new()
                } else {
                    (k + 1).to_string()
                };
                p.param(
                    point,
                    &format!("LABELS{suffix}"),
                    "marker names",
                    Value::Texts(chunk.to_vec()),
                );
                p.param(
                    point,
                    &format!("DESCRIPTIONS{suffix}"),
                    "",
                    Value::Texts(chunk.iter().map(|_| "helmcap bundle".to_string()).collect()),
                );
            }
            let analog = p.group("ANALOG", "analog data");
            p.param(analog, "USED", "analog channels", Value::Int(vec![0]));
            p.param(
                analog,
                "RATE",
                "analog samples per second (none)",
                Value::Float(vec![0.0]),
            );
            let trial = p.group("TRIAL", "trial");
            let split = |n: usize| vec![(n & 0xFFFF) as u16 as i16, (n >> 16) as u16 as i16];
            p.param(
                trial,
                "ACTUAL_START_FIELD",
                "first frame",
                Value::Int(split(first)),
            );
            p.param(
                trial,
                "ACTUAL_END_FIELD",
                "last frame",
                Value::Int(split(last)),
            );
            p.param(
                trial,
                "CAMERA_RATE",
                "camera frames per second",
                Value::Float(vec![rate]),
            );
            let manufacturer = p.group("MANUFACTURER", "writer");
            p.param(manufacturer, "COMPANY", "", Value::Text("helmcap".into()));
            p.param(manufacturer, "SOFTWARE", "", Value::Text("helmcap".into()));
            p.param(
                manufacturer,
                "VERSION_LABEL",
                "",
                Value::Text(env!("CARGO_PKG_VERSION").into()),
            );
            if let Some((index, tc)) = self.first_timecode {
                let g = p.group("TIMECODE", "SMPTE timecode of the take");
                // The timecode of the first C3D frame (frames before the first stamped one
                // have none: count back from it).
                p.param(
                    g,
                    "START",
                    "timecode of FIRST_FRAME, with rate",
                    Value::Text(tc.to_string_with_rate()),
                );
                p.param(g, "RATE", "timecode rate", Value::Text(tc.rate.to_string()));
                p.param(
                    g,
                    "DROP_FRAMES",
                    "1: drop-frame",
                    Value::Int(vec![i16::from(tc.rate.drop_frame)]),
                );
                p.param(
                    g,
                    "SUBFRAMES_PER_FRAME",
                    "camera frames per timecode frame",
                    Value::Int(vec![tc.subframes.max(1) as i16]),
                );
                p.param(
                    g,
                    "FIRST_FRAME",
                    "C3D frame of START (low, high 16-bit words)",
                    Value::Int(split(index + 1)),
                );
            }
            p.bytes()
        };
        let sized = build(0).map_err(other)?;
        let param_blocks = (sized.len() / 512).max(min_param_blocks);
        let data_start = 2 + param_blocks;
        let data_start16 =
            u16::try_from(data_start).map_err(|_| other("parameters too large".into()))?;
        let mut params = build(data_start16).map_err(other)?;
        if params.len() / 512 < param_blocks {
            // Padded to the reserved room; the section header counts its blocks.
            params.resize(param_blocks * 512, 0);
            params[2] =
                u8::try_from(param_blocks).map_err(|_| other("too many parameters".into()))?;
        }
        if params.len() / 512 != param_blocks {
            return Err(other(format!(
                "the parameters need {} blocks, {param_blocks} were reserved",
                params.len() / 512
            )));
        }
        let mut header = vec![0u8; 512];
        header[0] = 2;
        header[1] = 0x50;
        header[2..4].copy_from_slice(&(points as u16).to_le_bytes());
        header[4..6].copy_from_slice(&0u16.to_le_bytes());
        header[6..8].copy_from_slice(&first16.to_le_bytes());
        header[8..10].copy_from_slice(&last16.to_le_bytes());
        header[10..12].copy_from_slice(&10u16.to_le_bytes());
        header[12..16].copy_from_slice(&POINT_SCALE.to_le_bytes());
        header[16..18].copy_from_slice(&data_start16.to_le_bytes());
        header[18..20].copy_from_slice(&0u16.to_le_bytes());
        header[20..24].copy_from_slice(&rate.to_le_bytes());
        header.extend(params);
        Ok(header)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use nalgebra::Point3;

    use super::*;
    use crate::capture::GrayImage;
    use crate::dataset::{Marker, MarkerLayout};
    use crate::pipeline::MarkerResult;

    fn session(first_frame: usize) -> SessionMeta {
        let markers = ["brow_l", "chin"]
            .iter()
            .enumerate()
            .map(|(k, n)| Marker {
                name: (*n).into(),
                vertex: k as u32,
                stabilize_weight: 1.0,
            })
            .collect();
        SessionMeta {
            name: "long".into(),
            fps: 60.0,
            timecode_rate: None,
            first_frame: first_frame.into(),
            frame_count: None,
            layout: Arc::new(MarkerLayout { markers }),
            neutral_markers_head: Arc::new(Vec::new()),
            neutral: None,
            face_vertices: None,
            rig: None,
            image_size: None,
        }
    }

    /// A frame where the first marker is gap-filled at a position coding the frame index
    /// and the second is missing.
    fn frame(index: usize) -> FrameResult {
        let image = GrayImage {
            width: 1,
            height: 1,
            data: vec![0],
        };
        let mut f = FrameResult::new(index.into(), 0, None, [image.clone(), image], 2);
        f.markers[0] = MarkerResult {
            status: BundleStatus::GapFilled,
            point_in_head: Some(Point3::new(index as f64, 1.0, 2.0)),
            ..MarkerResult::MISSING
        };
        f
    }

    /// A take longer than the header's 16-bit frame range (70,000 frames at 60 fps,
    /// starting at frame 5, with one source gap) is written whole, and c3dio reads every
    /// frame back in place.
    #[test]
    fn takes_longer_than_65535_frames_are_written_whole() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bundles.c3d");
        let mut sink = C3dSink::new(&path);
        sink.begin(&session(5)).unwrap();
        let (first, count, gap) = (5usize, 70_000usize, 40_000usize);
        for index in (first..first + count).filter(|&i| i != gap) {
            sink.write(&frame(index)).unwrap();
        }
        sink.finish(&Metrics::default()).unwrap();
        let c3d = c3dio::C3d::load(path.to_str().unwrap()).expect("c3dio reads it");
        assert_eq!(c3d.points.rows(), count);
        // The header holds the compatibility range; the true one is in TRIAL.
        assert_eq!(c3d.points.first_frame, 1);
        for index in [
            first,
            first + 1,
            gap - 1,
            gap + 1,
            65_540,
            first + count - 1,
        ] {
            let p = c3d.points[index - first][0];
            assert_eq!(f64::from(p.point[0]), index as f64, "frame {index}");
            assert_eq!(p.residual, 0.0, "frame {index} is gap-filled");
            assert!(
                c3d.points[index - first][1].residual < 0.0,
                "missing marker"
            );
        }
        assert!(c3d.points[gap - first][0].residual < 0.0, "source gap");
    }

    /// The parameter section of a long take: FRAMES as a float, LONG_FRAMES, and the
    /// two-word TRIAL range.
    #[test]
    fn long_take_parameters_follow_the_c3d_org_convention() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bundles.c3d");
        let mut sink = C3dSink::new(&path);
        sink.begin(&session(70_000)).unwrap();
        for index in 70_000..70_000 + 40_000 {
            sink.write(&frame(index)).unwrap();
        }
        sink.finish(&Metrics::default()).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(u16::from_le_bytes([bytes[6], bytes[7]]), 1, "header first");
        assert_eq!(
            u16::from_le_bytes([bytes[8], bytes[9]]),
            40_000,
            "header last"
        );
        let c3d = c3dio::C3d::load(path.to_str().unwrap()).expect("c3dio reads it");
        assert_eq!(c3d.points.rows(), 40_000);
        assert_eq!(f64::from(c3d.points[39_999][0].point[0]), 109_999.0);
    }

    /// A write that fails halfway through a frame (disk full) leaves the file at the last
    /// complete frame, and it is published that way.
    #[test]
    fn a_failed_frame_is_cut_and_the_rest_published() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bundles.c3d");
        let mut sink = C3dSink::new(&path);
        sink.begin(&session(3)).unwrap();
        for index in 3..8 {
            sink.write(&frame(index)).unwrap();
        }
        // What a failing write leaves: part of a frame in the file, none of it marked.
        sink.data
            .as_mut()
            .unwrap()
            .write_with(|w| w.write_all(&[0x55; 700]))
            .unwrap();
        sink.next_frame = 9;
        sink.roll_back().unwrap();
        sink.finish(&Metrics::default()).unwrap();
        let c3d = c3dio::C3d::load(path.to_str().unwrap()).expect("c3dio reads it");
        assert_eq!(c3d.points.rows(), 5);
        assert_eq!(f64::from(c3d.points[4][0].point[0]), 7.0);
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len() % 512, 0);
        assert!(
            bytes[bytes.len() - 100..].iter().all(|&b| b == 0),
            "padding zeroed"
        );
    }

    /// Frames 0, 1 and 16777215 (the frames.csv): the gap is refused without
    /// allocating it.
    #[test]
    fn a_huge_gap_is_an_error_not_an_allocation() {
        let dir = tempfile::tempdir().unwrap();
        let mut sink = C3dSink::new(&dir.path().join("bundles.c3d"));
        sink.begin(&session(0)).unwrap();
        sink.write(&frame(0)).unwrap();
        sink.write(&frame(1)).unwrap();
        let err = sink.write(&frame(16_777_215)).unwrap_err().to_string();
        assert!(err.contains("a gap of 16777213 frames"), "{err}");
        sink.finish(&Metrics::default()).unwrap();
        let c3d = c3dio::C3d::load(dir.path().join("bundles.c3d").to_str().unwrap()).unwrap();
        assert_eq!(c3d.points.rows(), 2);
    }

    #[test]
    fn frame_numbers_past_the_float_range_are_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let mut sink = C3dSink::new(&dir.path().join("bundles.c3d"));
        sink.begin(&session(MAX_FRAME)).unwrap();
        let err = sink.write(&frame(MAX_FRAME)).unwrap_err();
        assert!(err.to_string().contains("split the take"), "{err}");
    }
}
