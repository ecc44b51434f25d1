//! SMPTE timecode (SMPTE ST 12-1): rates, drop-frame counting, parsing and formatting, and
//! the stamping of camera frames that run faster than the timecode (sub-frames).
//!
//! A [`Timecode`] is a frame count since midnight at a [`TimecodeRate`], plus a sub-frame
//! index when the cameras run at a multiple of the timecode rate (60 fps cameras on 30 fps
//! code give sub-frames 0 and 1). Text forms:
//!
//! - `HH:MM:SS:FF` non-drop-frame, `HH:MM:SS;FF` drop-frame (the SMPTE convention);
//! - a sub-frame suffix `.S` when the camera runs faster than the code: `01:00:00:12.1`;
//! - with the rate, wherever a timecode is written on its own: `01:00:00;12.1@29.97df`.
//!
//! Drop-frame (29.97 and 59.94 only) skips frame labels 0 and 1 (0–3 at 59.94) at the start
//! of every minute except every tenth minute, so the labels keep pace with the wall clock.

use std::fmt;
use std::str::FromStr;

/// Errors of timecode parsing.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TimecodeError {
    /// A rate the module does not know.
    #[error(
        "unknown timecode rate {} (expected 23.976, 24, 25, 29.97, 29.97df, 30, 47.952, 48, 50, 59.94, 59.94df or 60)",
        crate::limits::quoted(.0)
    )]
    Rate(String),
    /// A timecode that does not parse or names a label that does not exist at its rate.
    #[error("invalid timecode {} at {rate}: {reason}", crate::limits::quoted(.text))]
    Timecode {
        /// The text.
        text: String,
        /// The rate it was read at.
        rate: TimecodeRate,
        /// What is wrong.
        reason: String,
    },
}

/// A timecode rate: the nominal integer frame count per second, whether the real rate is
/// the NTSC one (`nominal × 1000/1001`), and drop-frame counting.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TimecodeRate {
    /// Frame labels per timecode second (24, 25, 30, 50, 60, ...).
    pub nominal: u32,
    /// The real rate is `nominal × 1000/1001` (23.976, 29.97, 59.94).
    pub ntsc: bool,
    /// Drop-frame counting (only 29.97 and 59.94).
    pub drop_frame: bool,
}

impl TimecodeRate {
    /// 23.976 fps (24 labels, NTSC pull-down), non-drop.
    pub const FPS_23_976: Self = Self::new_unchecked(24, true, false);
    /// 24 fps.
    pub const FPS_24: Self = Self::new_unchecked(24, false, false);
    /// 25 fps (PAL).
    pub const FPS_25: Self = Self::new_unchecked(25, false, false);
    /// 29.97 fps non-drop.
    pub const FPS_29_97: Self = Self::new_unchecked(30, true, false);
    /// 29.97 fps drop-frame.
    pub const FPS_29_97_DF: Self = Self::new_unchecked(30, true, true);
    /// 30 fps.
    pub const FPS_30: Self = Self::new_unchecked(30, false, false);
    /// 50 fps.
    pub const FPS_50: Self = Self::new_unchecked(50, false, false);
    /// 59.94 fps non-drop.
    pub const FPS_59_94: Self = Self::new_unchecked(60, true, false);
    /// 59.94 fps drop-frame.
    pub const FPS_59_94_DF: Self = Self::new_unchecked(60, true, true);
    /// 60 fps.
    pub const FPS_60: Self = Self::new_unchecked(60, false, false);

    const fn new_unchecked(nominal: u32, ntsc: bool, drop_frame: bool) -> Self {
        Self {
            nominal,
            ntsc,
            drop_frame,
        }
    }

    /// A rate from its parts.
    ///
    /// # Errors
    /// [`TimecodeError::Rate`] when `nominal` is 0 or above 120, or drop-frame is asked for
    /// anything but 29.97 or 59.94.
    pub fn new(nominal: u32, ntsc: bool, drop_frame: bool) -> Result<Self, TimecodeError> {
        let rate = Self::new_unchecked(nominal, ntsc, drop_frame);
        if nominal == 0 || nominal > 120 || (drop_frame && !(ntsc && matches!(nominal, 30 | 60))) {
            return Err(TimecodeError::Rate(rate.to_string()));
        }
        Ok(rate)
    }

    /// The real frame rate, frames per second.
    pub fn fps(self) -> f64 {
        if self.ntsc {
            f64::from(self.nominal) * 1000.0 / 1001.0
        } else {
            f64::from(self.nominal)
        }
    }

    /// The rate whose real fps is within 0.01 of `fps` (non-drop), e.g. for a camera rate.
    pub fn from_fps(fps: f64) -> Option<Self> {
        [
            Self::FPS_23_976,
            Self::FPS_24,
            Self::FPS_25,
            Self::FPS_29_97,
            Self::FPS_30,
            Self::new_unchecked(48, true, false),
            Self::new_unchecked(48, false, false),
            Self::FPS_50,
            Self::FPS_59_94,
            Self::FPS_60,
        ]
        .into_iter()
        .find(|r| (r.fps() - fps).abs() < 0.01)
    }

    /// Frame labels skipped at each dropping minute (0 for non-drop).
    fn dropped_per_minute(self) -> u64 {
        if self.drop_frame {
            u64::from(self.nominal / 15)
        } else {
            0
        }
    }

    /// Frames in a 24-hour day at this rate's counting.
    pub fn frames_per_day(self) -> u64 {
        let n = u64::from(self.nominal);
        n * 86_400 - self.dropped_per_minute() * 9 * 6 * 24
    }
}

impl fmt::Display for TimecodeRate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.ntsc, self.nominal) {
            (false, n) => write!(f, "{n}")?,
            (true, 24) => write!(f, "23.976")?,
            (true, 48) => write!(f, "47.952")?,
            (true, n) => write!(f, "{:.2}", f64::from(n) * 1000.0 / 1001.0)?,
        }
        if self.drop_frame {
            write!(f, "df")?;
        }
        Ok(())
    }
}

impl FromStr for TimecodeRate {
    type Err = TimecodeError;

    /// `23.976`, `24`, `25`, `29.97`, `29.97df` (also `29.97 DF`, `29.97drop`), `30`, `50`,
    /// `59.94`, `59.94df`, `60` and other whole numbers up to 120.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let lower = s.trim().to_ascii_lowercase();
        let (num, drop_frame) = match lower
            .strip_suffix("drop")
            .or_else(|| lower.strip_suffix("df"))
        {
            Some(n) => (n.trim(), true),
            None => (lower.as_str(), false),
        };
        let bad = || TimecodeError::Rate(s.to_string());
        let (nominal, ntsc) = match num {
            "23.976" | "23.98" => (24, true),
            "29.97" => (30, true),
            "47.952" | "47.95" => (48, true),
            "59.94" => (60, true),
            n => (
                n.parse::<f64>()
                    .ok()
                    .filter(|v| v.fract() == 0.0 && *v >= 1.0 && *v <= 120.0)
                    .map(|v| v as u32)
                    .ok_or_else(bad)?,
                false,
            ),
        };
        Self::new(nominal, ntsc, drop_frame).map_err(|_| bad())
    }
}

impl serde::Serialize for TimecodeRate {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

impl<'de> serde::Deserialize<'de> for TimecodeRate {
    /// A string (`"29.97df"`) or a number (`30`, `23.976`).
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(serde::Deserialize)]
        #[serde(untagged)]
        enum Repr {
            Text(String),
            Number(f64),
        }
        let text = match Repr::deserialize(d)? {
            Repr::Text(t) => t,
            Repr::Number(n) => format!("{n}"),
        };
        text.parse().map_err(serde::de::Error::custom)
    }
}

/// The components of a timecode label.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimecodeParts {
    /// Hours 0..24.
    pub hours: u32,
    /// Minutes 0..60.
    pub minutes: u32,
    /// Seconds 0..60.
    pub seconds: u32,
    /// Frame label 0..nominal.
    pub frames: u32,
}

/// A timecode: a frame count since midnight at a rate, and a sub-frame index.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Timecode {
    /// The rate.
    pub rate: TimecodeRate,
    /// Frames since midnight (real frames: drop-frame labels that are skipped are not
    /// counted), below [`TimecodeRate::frames_per_day`].
    pub frame_count: u64,
    /// Sub-frame index within the timecode frame, below `subframes`.
    pub subframe: u32,
    /// Camera frames per timecode frame (1 when the camera runs at the timecode rate).
    pub subframes: u32,
}

impl Timecode {
    /// A timecode from a frame count since midnight (wrapped at 24 hours), no sub-frames.
    pub fn from_frame_count(rate: TimecodeRate, frame_count: u64) -> Self {
        Self {
            rate,
            frame_count: frame_count % rate.frames_per_day(),
            subframe: 0,
            subframes: 1,
        }
    }

    /// A timecode from its label.
    ///
    /// # Errors
    /// [`TimecodeError::Timecode`] for fields out of range or a label that drop-frame
    /// counting skips.
    pub fn from_parts(rate: TimecodeRate, p: TimecodeParts) -> Result<Self, TimecodeError> {
        let err = |reason: &str| TimecodeError::Timecode {
            text: format!(
                "{:02}:{:02}:{:02}:{:02}",
                p.hours, p.minutes, p.seconds, p.frames
            ),
            rate,
            reason: reason.to_string(),
        };
        if p.hours >= 24 || p.minutes >= 60 || p.seconds >= 60 || p.frames >= rate.nominal {
            return Err(err("field out of range"));
        }
        let drop = rate.dropped_per_minute();
        if drop > 0 && p.seconds == 0 && u64::from(p.frames) < drop && !p.minutes.is_multiple_of(10)
        {
            return Err(err("drop-frame counting skips this label"));
        }
        let n = u64::from(rate.nominal);
        let total_minutes = 60 * u64::from(p.hours) + u64::from(p.minutes);
        let count = (total_minutes * 60 + u64::from(p.seconds)) * n + u64::from(p.frames)
            - drop * (total_minutes - total_minutes / 10);
        Ok(Self::from_frame_count(rate, count))
    }

    /// The label of this timecode (SMPTE drop-frame algorithm for drop-frame rates).
    pub fn parts(&self) -> TimecodeParts {
        let n = u64::from(self.rate.nominal);
        let drop = self.rate.dropped_per_minute();
        let mut count = self.frame_count;
        if drop > 0 {
            let per_10_minutes = n * 600 - drop * 9;
            let per_minute = n * 60 - drop;
            let tens = count / per_10_minutes;
            let rem = count % per_10_minutes;
            count += drop * 9 * tens;
            if rem > drop {
                count += drop * ((rem - drop) / per_minute);
            }
        }
        let secs = count / n;
        TimecodeParts {
            hours: ((secs / 3600) % 24) as u32,
            minutes: ((secs / 60) % 60) as u32,
            seconds: (secs % 60) as u32,
            frames: (count % n) as u32,
        }
    }

    /// Seconds since midnight on the real clock (NTSC rates run 1000/1001 slow), including
    /// the sub-frame.
    pub fn seconds(&self) -> f64 {
        (self.frame_count as f64 + f64::from(self.subframe) / f64::from(self.subframes.max(1)))
            / self.rate.fps()
    }

    /// This timecode moved by `frames` timecode frames (wrapping at 24 hours).
    pub fn add_frames(&self, frames: u64) -> Self {
        Self {
            frame_count: (self.frame_count + frames) % self.rate.frames_per_day(),
            ..*self
        }
    }

    /// Parses a label (`HH:MM:SS:FF`, `HH:MM:SS;FF`, optional `.S` sub-frame) at `rate`.
    /// A `;` or `.` before the frames asks for drop-frame and must agree with the rate.
    ///
    /// # Errors
    /// [`TimecodeError::Timecode`] naming what is wrong.
    pub fn parse_at(text: &str, rate: TimecodeRate) -> Result<Self, TimecodeError> {
        let err = |reason: &str| TimecodeError::Timecode {
            text: text.to_string(),
            rate,
            reason: reason.to_string(),
        };
        let t = text.trim();
        if t.len() < 11 || !t.is_char_boundary(11) {
            return Err(err("expected HH:MM:SS:FF"));
        }
        let (label, rest) = t.split_at(11);
        let b = label.as_bytes();
        if b[2] != b':' || b[5] != b':' || !matches!(b[8], b':' | b';') {
            return Err(err("expected HH:MM:SS:FF"));
        }
        if (b[8] == b';') != rate.drop_frame {
            return Err(err(if rate.drop_frame {
                "a drop-frame timecode separates the frames with ';'"
            } else {
                "';' marks drop-frame, but the rate is non-drop"
            }));
        }
        let field = |r: std::ops::Range<usize>| -> Result<u32, TimecodeError> {
            let s = &label[r];
            if s.bytes().all(|c| c.is_ascii_digit()) {
                s.parse().map_err(|_| err("fields must be digits"))
            } else {
                Err(err("fields must be digits"))
            }
        };
        let parts = TimecodeParts {
            hours: field(0..2)?,
            minutes: field(3..5)?,
            seconds: field(6..8)?,
            frames: field(9..11)?,
        };
        let mut tc = Self::from_parts(rate, parts).map_err(|e| match e {
            TimecodeError::Timecode { reason, .. } => err(&reason),
            other => other,
        })?;
        if let Some(sub) = rest.strip_prefix('.') {
            let s: u32 = sub
                .parse()
                .map_err(|_| err("sub-frame must be a whole number"))?;
            // The text carries the index only; the count per frame follows from the camera
            // rate (see [`TimecodeClock`]), and is at least 2 wherever there is an index.
            tc.subframe = s;
            tc.subframes = (s + 1).max(2);
        } else if !rest.is_empty() {
            return Err(err("unexpected text after the frames"));
        }
        Ok(tc)
    }

    /// The label with its rate, `01:00:00;12.1@29.97df`: the form to write wherever a
    /// timecode stands on its own.
    pub fn to_string_with_rate(&self) -> String {
        format!("{self}@{}", self.rate)
    }
}

impl fmt::Display for Timecode {
    /// `HH:MM:SS:FF` (`;` before the frames for drop-frame), `.S` when there are
    /// sub-frames.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let p = self.parts();
        let sep = if self.rate.drop_frame { ';' } else { ':' };
        write!(
            f,
            "{:02}:{:02}:{:02}{sep}{:02}",
            p.hours, p.minutes, p.seconds, p.frames
        )?;
        if self.subframes > 1 {
            write!(f, ".{}", self.subframe)?;
        }
        Ok(())
    }
}

impl FromStr for Timecode {
    type Err = TimecodeError;

    /// `LABEL@RATE`, as written by [`Timecode::to_string_with_rate`].
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (label, rate) = s.rsplit_once('@').ok_or_else(|| TimecodeError::Timecode {
            text: s.to_string(),
            rate: TimecodeRate::FPS_30,
            reason: "expected LABEL@RATE, e.g. 01:00:00:00@30".into(),
        })?;
        Self::parse_at(label, rate.parse()?)
    }
}

/// Stamps camera frames with timecode: camera frame `i` after the start is timecode frame
/// `start + ⌊i / k⌋`, sub-frame `i mod k`, where `k` = camera fps / timecode fps when that
/// is a whole number above 1 (60 fps cameras on 30 fps code: k = 2). Otherwise (cameras
/// slower than or unrelated to the code) every camera frame takes the timecode frame in
/// effect at its time, without sub-frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimecodeClock {
    /// Timecode of camera frame 0.
    pub start: Timecode,
    /// Camera frames per second.
    pub camera_fps: f64,
    /// Camera frames per timecode frame (1: no sub-frames).
    pub subframes: u32,
}

impl TimecodeClock {
    /// A clock for cameras at `camera_fps` starting at `start`.
    pub fn new(start: Timecode, camera_fps: f64) -> Self {
        let ratio = camera_fps / start.rate.fps();
        let k = ratio.round();
        let subframes = if k >= 2.0 && (ratio - k).abs() < 1e-3 {
            k as u32
        } else {
            1
        };
        Self {
            start: Timecode {
                subframe: 0,
                subframes,
                ..start
            },
            camera_fps,
            subframes,
        }
    }

    /// The timecode of camera frame `index`.
    pub fn stamp(&self, index: u64) -> Timecode {
        if self.subframes > 1 {
            let k = u64::from(self.subframes);
            let mut tc = self.start.add_frames(index / k);
            tc.subframe = (index % k) as u32;
            tc
        } else {
            let frames = (index as f64 * self.start.rate.fps() / self.camera_fps + 1e-9).floor();
            self.start.add_frames(frames as u64)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RATES: [TimecodeRate; 10] = [
        TimecodeRate::FPS_23_976,
        TimecodeRate::FPS_24,
        TimecodeRate::FPS_25,
        TimecodeRate::FPS_29_97,
        TimecodeRate::FPS_29_97_DF,
        TimecodeRate::FPS_30,
        TimecodeRate::FPS_50,
        TimecodeRate::FPS_59_94,
        TimecodeRate::FPS_59_94_DF,
        TimecodeRate::FPS_60,
    ];

    #[test]
    fn rates_parse_and_print() {
        for r in RATES {
            assert_eq!(r.to_string().parse::<TimecodeRate>().unwrap(), r, "{r}");
        }
        assert_eq!(
            "29.97 DF".parse::<TimecodeRate>().unwrap(),
            TimecodeRate::FPS_29_97_DF
        );
        assert!("25df".parse::<TimecodeRate>().is_err());
        assert!("0".parse::<TimecodeRate>().is_err());
        assert!("abc".parse::<TimecodeRate>().is_err());
        assert!((TimecodeRate::FPS_23_976.fps() - 23.976_023_976).abs() < 1e-6);
    }

    #[test]
    fn every_frame_of_a_day_round_trips() {
        for r in RATES {
            // Every frame of the first and last eleven minutes, and a stride across the day.
            let day = r.frames_per_day();
            let span = u64::from(r.nominal) * 60 * 11;
            let counts = (0..span)
                .chain(day - span..day)
                .chain((0..day).step_by(997));
            for c in counts {
                let tc = Timecode::from_frame_count(r, c);
                let text = tc.to_string();
                let back = Timecode::parse_at(&text, r).unwrap();
                assert_eq!(back.frame_count, c, "{r} {text}");
                assert_eq!(text.parse::<Timecode>().ok(), None, "needs a rate");
                assert_eq!(
                    tc.to_string_with_rate().parse::<Timecode>().unwrap(),
                    tc,
                    "{r}"
                );
            }
        }
    }

    #[test]
    fn drop_frame_labels() {
        let r = TimecodeRate::FPS_29_97_DF;
        // The frame after 00:00:59;29 is 00:01:00;02.
        let a = Timecode::parse_at("00:00:59;29", r).unwrap();
        assert_eq!(a.add_frames(1).to_string(), "00:01:00;02");
        // The tenth minute keeps its labels 0 and 1.
        let b = Timecode::parse_at("00:09:59;29", r).unwrap();
        assert_eq!(b.add_frames(1).to_string(), "00:10:00;00");
        assert!(Timecode::parse_at("00:01:00;00", r).is_err());
        assert!(Timecode::parse_at("00:01:00:02", r).is_err(), "needs ';'");
        // One hour of 29.97 DF is 107,892 frames and 3600 s × 29.97 ≈ 107,892.1.
        let h = Timecode::parse_at("01:00:00;00", r).unwrap();
        assert_eq!(h.frame_count, 107_892);
        assert!((h.seconds() - 3600.0).abs() < 0.004);
        let r60 = TimecodeRate::FPS_59_94_DF;
        let c = Timecode::parse_at("00:00:59;59", r60).unwrap();
        assert_eq!(c.add_frames(1).to_string(), "00:01:00;04");
        assert_eq!(r.frames_per_day(), 2_589_408);
    }

    #[test]
    fn bad_labels_are_errors() {
        let r = TimecodeRate::FPS_25;
        for t in [
            "",
            "1:00:00:00",
            "01:00:00:25",
            "24:00:00:00",
            "01:60:00:00",
            "01:00:00:0x",
            "01:00:00:00x",
            "01:00:00:00.x",
            "01-00-00-00",
            "01:00:00:00é",
        ] {
            assert!(Timecode::parse_at(t, r).is_err(), "{t:?}");
        }
    }

    #[test]
    fn sixty_fps_cameras_on_thirty_fps_code_get_sub_frames() {
        let start = Timecode::parse_at("01:00:00:00", TimecodeRate::FPS_30).unwrap();
        let clock = TimecodeClock::new(start, 60.0);
        assert_eq!(clock.subframes, 2);
        let labels: Vec<String> = (0..5).map(|i| clock.stamp(i).to_string()).collect();
        assert_eq!(
            labels,
            [
                "01:00:00:00.0",
                "01:00:00:00.1",
                "01:00:00:01.0",
                "01:00:00:01.1",
                "01:00:00:02.0"
            ]
        );
        // Round trip of a sub-frame timecode through its text.
        for i in 0..200 {
            let tc = clock.stamp(i);
            assert_eq!(tc.to_string_with_rate().parse::<Timecode>().unwrap(), tc);
        }
        // 59.94 cameras on 29.97 DF code.
        let df = Timecode::parse_at("00:00:59;28", TimecodeRate::FPS_29_97_DF).unwrap();
        let clock = TimecodeClock::new(df, TimecodeRate::FPS_59_94.fps());
        assert_eq!(clock.stamp(5).to_string(), "00:01:00;02.1");
        // Same rate: no sub-frames.
        let same = TimecodeClock::new(start, 30.0);
        assert_eq!(same.stamp(31).to_string(), "01:00:01:01");
        // 24 fps cameras on 30 fps code: the label in effect.
        let slow = TimecodeClock::new(start, 24.0);
        assert_eq!(slow.stamp(24).to_string(), "01:00:01:00");
        assert_eq!(slow.stamp(1).to_string(), "01:00:00:01");
    }
}
