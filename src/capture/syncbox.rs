//! The serial sync box: its line protocol, a parser robust to line noise, a reader thread
//! that keeps the latest timecode and trigger counter, and the stamping of camera frames
//! from them.
//!
//! # Protocol
//! The box drives the cameras' trigger inputs and counts the pulses. At the start of every
//! timecode frame it sends one ASCII line on its serial port (NMEA 0183 style):
//!
//! ```text
//! $HCSYNC,<timecode>,<rate>,<trigger_counter>*<checksum>\r\n
//! $HCSYNC,01:00:00:00,30,1200*1B\r\n
//! ```
//!
//! - `<timecode>`: the label of the timecode frame that starts now, `HH:MM:SS:FF`
//!   (`HH:MM:SS;FF` at drop-frame rates), no sub-frame;
//! - `<rate>`: the timecode rate as [`TimecodeRate`] writes it: `23.976`, `24`, `25`,
//!   `29.97`, `29.97df`, `30`, `50`, `59.94`, `59.94df`, `60`;
//! - `<trigger_counter>`: the number of camera trigger pulses sent since the box started,
//!   counting the pulse that coincides with the start of this timecode frame (decimal,
//!   up to 20 digits; it only grows, a smaller value means the box restarted);
//! - `<checksum>`: two hex digits (either case), the XOR of every byte between `$` and `*`.
//!
//! A line is at most [`MAX_LINE_BYTES`] bytes from `$` to `\n`; `\r` before `\n` is
//! optional. Anything outside `$…\n` is noise.
//!
//! # Robustness
//! [`LineParser`] takes bytes as they come (any split), resynchronises on `$`, and counts
//! every kind of bad input instead of failing: bytes outside a line, a line cut short by a
//! new `$` or by the device going away, overlong lines, lines that are not UTF-8, bad
//! checksums, and lines with a good checksum whose fields do not parse. [`SyncBox`] runs
//! the parser on a reader thread, declares the box lost when no valid line came for
//! [`SyncBoxConfig::timeout_ms`] or the device fails (read error, unplugged), and tries to
//! open it again every [`SyncBoxConfig::retry_ms`] until it is back.
//!
//! # Stamping camera frames
//! A line received at host time `t_line` says: the trigger pulse number `c` started
//! timecode frame `T`. A camera frame that reached the host at `t_cap` was exposed on pulse
//! `c + n`, with `n = round((t_cap − t_line − d) · f_cam)` (`f_cam` the camera rate, `d`
//! [`SyncBoxConfig::frame_delay_ms`]: how much later a frame reaches the host than the line
//! of the same pulse). Its timecode is then `T` advanced by `n` camera frames: with 60 fps
//! cameras on 30 fps code, every timecode frame has two camera frames, sub-frames 0 and 1
//! (see [`crate::timecode::TimecodeClock`]). `n` may be negative (a frame that arrives just
//! before the line of its own timecode frame is stamped from the previous one). See
//! [`stamp_from_anchor`].
//!
//! Depends on [`crate::timecode`].

use std::io::Read;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::timecode::{Timecode, TimecodeClock, TimecodeRate};

/// The sentence name after `$`.
pub const SENTENCE: &str = "HCSYNC";

/// Longest accepted line, `$` to `\n` inclusive. A valid line is at most about 60 bytes.
pub const MAX_LINE_BYTES: usize = 96;

/// One valid line of the sync box.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncLine {
    /// The timecode frame that starts with this line (no sub-frame).
    pub timecode: Timecode,
    /// Trigger pulses sent since the box started, counting the one that starts `timecode`.
    pub trigger_counter: u64,
}

/// XOR of `payload`'s bytes: the checksum of the bytes between `$` and `*`.
pub fn checksum(payload: &[u8]) -> u8 {
    payload.iter().fold(0, |acc, b| acc ^ b)
}

/// The line the box sends for `timecode` (its sub-frame is ignored) and `trigger_counter`,
/// `\r\n` included.
pub fn format_line(timecode: &Timecode, trigger_counter: u64) -> String {
    let label = Timecode {
        subframe: 0,
        subframes: 1,
        ..*timecode
    };
    let payload = format!("{SENTENCE},{label},{},{trigger_counter}", timecode.rate);
    format!("${payload}*{:02X}\r\n", checksum(payload.as_bytes()))
}

/// Why a line was rejected.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LineError {
    /// The line is longer than [`MAX_LINE_BYTES`].
    #[error("line longer than {MAX_LINE_BYTES} bytes")]
    Overlong,
    /// The line is not valid UTF-8.
    #[error("line is not UTF-8")]
    NotUtf8,
    /// The checksum is missing, not hex, or does not match.
    #[error("bad checksum: {0}")]
    Checksum(String),
    /// The checksum matches but the fields do not parse.
    #[error("malformed line {line:?}: {reason}")]
    Malformed {
        /// The line without `\r\n`.
        line: String,
        /// What is wrong.
        reason: String,
    },
}

/// Counts of what the parser saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ParserCounts {
    /// Valid lines.
    pub lines_ok: u64,
    /// Bytes outside any `$…\n` line (line ends between lines are not counted).
    pub garbage_bytes: u64,
    /// Lines cut short by a new `$` or by the device going away.
    pub partial_lines: u64,
    /// Lines longer than [`MAX_LINE_BYTES`].
    pub overlong_lines: u64,
    /// Lines that are not UTF-8.
    pub non_utf8_lines: u64,
    /// Lines whose checksum is missing or wrong.
    pub bad_checksums: u64,
    /// Lines with a good checksum whose fields do not parse.
    pub malformed_lines: u64,
}

impl ParserCounts {
    /// Every rejected line (partial, overlong, not UTF-8, bad checksum, malformed).
    pub fn bad_lines(&self) -> u64 {
        self.partial_lines
            + self.overlong_lines
            + self.non_utf8_lines
            + self.bad_checksums
            + self.malformed_lines
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ParseState {
    /// Between lines: waiting for `$`.
    Idle,
    /// Inside a line (the buffer holds it from `$`).
    InLine,
    /// Skipping the rest of an overlong line.
    Discard,
}

/// Incremental parser of the sync box's byte stream; see the module docs.
#[derive(Debug, Clone)]
pub struct LineParser {
    buf: Vec<u8>,
    state: ParseState,
    counts: ParserCounts,
}

impl Default for LineParser {
    fn default() -> Self {
        Self::new()
    }
}

impl LineParser {
    /// An empty parser.
    pub fn new() -> Self {
        Self {
            buf: Vec::with_capacity(MAX_LINE_BYTES),
            state: ParseState::Idle,
            counts: ParserCounts::default(),
        }
    }

    /// Counts so far.
    pub fn counts(&self) -> ParserCounts {
        self.counts
    }

    /// Feeds bytes (any split of the stream); `on_line` gets every complete line, valid or
    /// not, in order. Rejected lines are also counted.
    pub fn push(&mut self, bytes: &[u8], mut on_line: impl FnMut(Result<SyncLine, LineError>)) {
        for &b in bytes {
            match (self.state, b) {
                (ParseState::Idle, b'$') => {
                    self.buf.clear();
                    self.buf.push(b);
                    self.state = ParseState::InLine;
                }
                (ParseState::Idle, b'\r' | b'\n') => {}
                (ParseState::Idle, _) => self.counts.garbage_bytes += 1,
                (ParseState::InLine, b'$') => {
                    // The previous line never ended: start over at this `$`.
                    self.counts.partial_lines += 1;
                    self.buf.clear();
                    self.buf.push(b);
                }
                (ParseState::InLine, b'\n') => {
                    let result = self.finish_line();
                    self.state = ParseState::Idle;
                    on_line(result);
                }
                (ParseState::InLine, _) => {
                    self.buf.push(b);
                    if self.buf.len() >= MAX_LINE_BYTES {
                        self.counts.overlong_lines += 1;
                        self.buf.clear();
                        self.state = ParseState::Discard;
                        on_line(Err(LineError::Overlong));
                    }
                }
                (ParseState::Discard, b'\n') => self.state = ParseState::Idle,
                (ParseState::Discard, b'$') => {
                    self.buf.clear();
                    self.buf.push(b);
                    self.state = ParseState::InLine;
                }
                (ParseState::Discard, _) => {}
            }
        }
    }

    /// Forgets a line in progress (the device went away); counts it as partial.
    pub fn reset(&mut self) {
        if self.state == ParseState::InLine {
            self.counts.partial_lines += 1;
        }
        self.buf.clear();
        self.state = ParseState::Idle;
    }

    fn finish_line(&mut self) -> Result<SyncLine, LineError> {
        let raw = std::mem::take(&mut self.buf);
        let result = parse_line(&raw);
        self.buf = raw;
        self.buf.clear();
        match &result {
            Ok(_) => self.counts.lines_ok += 1,
            Err(LineError::Overlong) => self.counts.overlong_lines += 1,
            Err(LineError::NotUtf8) => self.counts.non_utf8_lines += 1,
            Err(LineError::Checksum(_)) => self.counts.bad_checksums += 1,
            Err(LineError::Malformed { .. }) => self.counts.malformed_lines += 1,
        }
        result
    }
}

/// Parses one line from `$` up to (without) `\n`; a trailing `\r` is allowed.
///
/// # Errors
/// [`LineError`] saying what is wrong.
pub fn parse_line(raw: &[u8]) -> Result<SyncLine, LineError> {
    let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
    if raw.len() >= MAX_LINE_BYTES {
        return Err(LineError::Overlong);
    }
    let text = std::str::from_utf8(raw).map_err(|_| LineError::NotUtf8)?;
    let body = text.strip_prefix('$').unwrap_or(text);
    let (payload, sum) = body
        .rsplit_once('*')
        .ok_or_else(|| LineError::Checksum("no `*` before the checksum".into()))?;
    let expected = checksum(payload.as_bytes());
    let found = (sum.len() == 2)
        .then(|| u8::from_str_radix(sum, 16).ok())
        .flatten()
        .ok_or_else(|| LineError::Checksum(format!("{sum:?} is not two hex digits")))?;
    if found != expected {
        return Err(LineError::Checksum(format!(
            "line says {found:02X}, bytes give {expected:02X}"
        )));
    }
    let malformed = |reason: String| LineError::Malformed {
        line: text.to_string(),
        reason,
    };
    let fields: Vec<&str> = payload.split(',').collect();
    let [name, label, rate, counter] = fields.as_slice() else {
        return Err(malformed(format!("{} fields, expected 4", fields.len())));
    };
    if *name != SENTENCE {
        return Err(malformed(format!("sentence {name:?}, expected {SENTENCE}")));
    }
    let rate: TimecodeRate = rate.parse().map_err(|e| malformed(format!("{e}")))?;
    let timecode = Timecode::parse_at(label, rate).map_err(|e| malformed(e.to_string()))?;
    if timecode.subframes > 1 {
        return Err(malformed("the box sends no sub-frame".into()));
    }
    let trigger_counter = counter
        .parse()
        .ok()
        .filter(|_| counter.bytes().all(|c| c.is_ascii_digit()))
        .ok_or_else(|| malformed(format!("trigger counter {counter:?} is not a whole number")))?;
    Ok(SyncLine {
        timecode,
        trigger_counter,
    })
}

/// Sync box settings (`[syncbox]` of `configs/live.toml`).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct SyncBoxConfig {
    /// Serial device, e.g. `/dev/ttyUSB0` or a stable `/dev/serial/by-id/…` link. Default
    /// `/dev/ttyUSB0`.
    pub port: String,
    /// Baud rate. Default 115200.
    pub baud: u32,
    /// The box counts as lost when no valid line came for this long, ms. Default 500 (the
    /// box sends one line per timecode frame, 24 to 60 a second).
    pub timeout_ms: u64,
    /// Pause between attempts to open the device again, ms. Default 1000.
    pub retry_ms: u64,
    /// How much later a camera frame reaches the host than the sync line sent on the same
    /// trigger pulse, ms (camera readout and transfer minus the line's transfer). Measure
    /// once per rig by filming a timecode slate. At least 0; default 0.
    pub frame_delay_ms: f64,
}

impl Default for SyncBoxConfig {
    fn default() -> Self {
        Self {
            port: "/dev/ttyUSB0".into(),
            baud: 115_200,
            timeout_ms: 500,
            retry_ms: 1000,
            frame_delay_ms: 0.0,
        }
    }
}

/// State of the sync box as seen by the host.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SyncHealth {
    /// The device is open and a valid line came within the timeout.
    Healthy,
    /// Not opened yet (or never opened): retrying.
    Connecting,
    /// The device is open but no valid line came within the timeout (cable, garbage,
    /// wrong baud rate).
    Silent,
    /// The device failed (read error, unplugged): retrying to open it.
    Disconnected,
}

impl std::fmt::Display for SyncHealth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Healthy => "healthy",
            Self::Connecting => "not connected yet",
            Self::Silent => "silent (no valid line)",
            Self::Disconnected => "disconnected",
        })
    }
}

/// Counters of the reader thread.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SyncCounters {
    /// What the parser saw.
    pub parser: ParserCounts,
    /// Successful opens of the device (the first one included).
    pub opens: u64,
    /// Failed attempts to open it.
    pub open_failures: u64,
    /// Read errors (each closes the device; it is then reopened).
    pub read_errors: u64,
    /// Times the trigger counter went backwards (the box restarted).
    pub counter_resets: u64,
    /// Times the box went from healthy to lost (silent or disconnected).
    pub losses: u64,
    /// Times the port sent more than [`MAX_BYTES_PER_SEC`] (a flood: wrong device, wrong
    /// baud rate, a loop-back): the reader then drops input instead of parsing it.
    pub floods: u64,
    /// Bytes dropped unparsed during floods.
    pub flood_bytes: u64,
}

/// Most bytes a second the reader parses. A box sends one line of at most
/// [`MAX_LINE_BYTES`] per timecode frame (under 6 KB/s at 60 fps): beyond 16 KB/s the
/// input is a flood, and parsing it would take CPU from the capture pipeline (a 40 MB/s
/// flood halved its frame rate). During a flood the reader drops what it reads and pauses
/// for the rest of each 100 ms window, until a whole window is back under the limit; the
/// sync box counts as silent meanwhile.
pub const MAX_BYTES_PER_SEC: usize = 16 * 1024;

/// Window of the flood limit.
const FLOOD_WINDOW: Duration = Duration::from_millis(100);

/// The latest valid line and when it arrived.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyncSample {
    /// The line.
    pub line: SyncLine,
    /// Host time it was received.
    pub received: Instant,
}

/// A snapshot of the sync box: health, latest line, counters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyncStatus {
    /// Health now.
    pub health: SyncHealth,
    /// The latest valid line (kept after the box is lost).
    pub latest: Option<SyncSample>,
    /// Counters.
    pub counters: SyncCounters,
}

#[derive(Debug)]
struct Shared {
    latest: Option<SyncSample>,
    open: bool,
    ever_opened: bool,
    counters: SyncCounters,
}

/// Errors of the sync box.
#[derive(Debug, thiserror::Error)]
pub enum SyncBoxError {
    /// The reader thread could not be started.
    #[error("cannot start the sync box reader thread: {0}")]
    Thread(std::io::Error),
    /// A setting is invalid.
    #[error("sync box config: {0}")]
    Config(String),
}

/// The sync box reader: a thread (`helmcap:syncbox`) reading the serial port, parsing
/// lines and keeping the latest valid one. Opening failures and read errors are logged,
/// counted and retried; they never stop the thread.
///
/// # Shutdown
/// Dropping the handle stops the thread (within one read timeout, 50 ms) and joins it.
#[derive(Debug)]
pub struct SyncBox {
    config: SyncBoxConfig,
    shared: Arc<Mutex<Shared>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

/// How long one read waits for bytes before checking the stop flag.
const READ_TIMEOUT: Duration = Duration::from_millis(50);

/// Log at most this many rejected lines one by one; the rest are only counted.
const LOGGED_BAD_LINES: u64 = 10;

fn lock(shared: &Mutex<Shared>) -> MutexGuard<'_, Shared> {
    // A poisoned lock only means a panic elsewhere; the counters are still usable.
    shared
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl SyncBox {
    /// Starts the reader thread on `config.port`. The device need not exist yet: it is
    /// opened (and reopened after a failure) every `retry_ms`.
    ///
    /// # Errors
    /// [`SyncBoxError::Config`] for a zero baud rate or timeout, [`SyncBoxError::Thread`]
    /// when the thread cannot be spawned.
    pub fn start(config: SyncBoxConfig) -> Result<Self, SyncBoxError> {
        if config.baud == 0 || config.timeout_ms == 0 || config.port.is_empty() {
            return Err(SyncBoxError::Config(
                "`port` must be set, `baud` and `timeout_ms` above 0".into(),
            ));
        }
        if !(0.0..=1000.0).contains(&config.frame_delay_ms)
            || config.timeout_ms as f64 > crate::limits::MAX_DURATION_MS
            || config.retry_ms as f64 > crate::limits::MAX_DURATION_MS
        {
            return Err(SyncBoxError::Config(format!(
                "`frame_delay_ms` must be 0 to 1000, `timeout_ms` and `retry_ms` at most {} ms",
                crate::limits::MAX_DURATION_MS
            )));
        }
        let shared = Arc::new(Mutex::new(Shared {
            latest: None,
            open: false,
            ever_opened: false,
            counters: SyncCounters::default(),
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (config, shared, stop) = (config.clone(), shared.clone(), stop.clone());
            std::thread::Builder::new()
                .name("helmcap:syncbox".into())
                .spawn(move || reader_loop(&config, &shared, &stop))
                .map_err(SyncBoxError::Thread)?
        };
        Ok(Self {
            config,
            shared,
            stop,
            thread: Some(thread),
        })
    }

    /// The settings.
    pub fn config(&self) -> &SyncBoxConfig {
        &self.config
    }

    /// Health, latest line and counters now.
    pub fn status(&self) -> SyncStatus {
        let s = lock(&self.shared);
        SyncStatus {
            health: health_of(&s, self.config.timeout_ms, Instant::now()),
            latest: s.latest,
            counters: s.counters,
        }
    }
}

fn health_of(s: &Shared, timeout_ms: u64, now: Instant) -> SyncHealth {
    if !s.open {
        return if s.ever_opened {
            SyncHealth::Disconnected
        } else {
            SyncHealth::Connecting
        };
    }
    match s.latest {
        Some(l)
            if now.saturating_duration_since(l.received) <= Duration::from_millis(timeout_ms) =>
        {
            SyncHealth::Healthy
        }
        _ => SyncHealth::Silent,
    }
}

impl Drop for SyncBox {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            // The thread never panics by design; a panic would already have been printed.
            let _ = t.join();
        }
    }
}

/// Sleeps `total`, waking every 20 ms to check `stop`.
fn sleep_unless_stopped(total: Duration, stop: &AtomicBool) {
    let end = Instant::now() + total;
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        if now >= end {
            return;
        }
        std::thread::sleep((end - now).min(Duration::from_millis(20)));
    }
}

fn reader_loop(config: &SyncBoxConfig, shared: &Mutex<Shared>, stop: &AtomicBool) {
    let retry = Duration::from_millis(config.retry_ms.max(1));
    let mut parser = LineParser::new();
    let mut port: Option<Box<dyn serialport::SerialPort>> = None;
    let mut failing_since_log = false;
    let mut logged_bad = 0u64;
    let mut buf = [0u8; 512];
    let mut health = SyncHealth::Connecting;
    let budget = MAX_BYTES_PER_SEC / 10; // per FLOOD_WINDOW
    let (mut window_start, mut window_bytes, mut flooding) = (Instant::now(), 0usize, false);
    while !stop.load(Ordering::Relaxed) {
        {
            let mut s = lock(shared);
            let now = health_of(&s, config.timeout_ms, Instant::now());
            if now != health {
                if health == SyncHealth::Healthy {
                    s.counters.losses += 1;
                }
                if now == SyncHealth::Healthy {
                    tracing::info!("sync box: {} healthy", config.port);
                } else if health == SyncHealth::Healthy {
                    tracing::warn!("sync box: {} {now}", config.port);
                }
                health = now;
            }
        }
        let Some(p) = port.as_mut() else {
            match serialport::new(&config.port, config.baud)
                .timeout(READ_TIMEOUT)
                .open()
            {
                Ok(p) => {
                    tracing::info!("sync box: {} open at {} baud", config.port, config.baud);
                    failing_since_log = false;
                    let mut s = lock(shared);
                    s.open = true;
                    s.ever_opened = true;
                    s.counters.opens += 1;
                    port = Some(p);
                }
                Err(e) => {
                    if !failing_since_log {
                        tracing::warn!(
                            "sync box: cannot open {}: {e}; retrying every {} ms",
                            config.port,
                            retry.as_millis()
                        );
                        failing_since_log = true;
                    }
                    lock(shared).counters.open_failures += 1;
                    sleep_unless_stopped(retry, stop);
                }
            }
            continue;
        };
        let lost = match p.read(&mut buf) {
            Ok(0) => Some("end of stream".to_string()),
            Ok(n)
                if {
                    let now = Instant::now();
                    if now.saturating_duration_since(window_start) >= FLOOD_WINDOW {
                        if window_bytes <= budget {
                            flooding = false;
                        }
                        window_start = now;
                        window_bytes = 0;
                    }
                    window_bytes += n;
                    // Once flooding, everything is dropped until a whole window is calm.
                    flooding || window_bytes > budget
                } =>
            {
                // A flood: drop the bytes unparsed and sit out the rest of the window.
                {
                    let mut s = lock(shared);
                    s.counters.flood_bytes += n as u64;
                    if !flooding {
                        s.counters.floods += 1;
                        tracing::warn!(
                            "sync box: {} sends more than {MAX_BYTES_PER_SEC} bytes/s; input \
                             dropped until it calms down (wrong device or baud rate?)",
                            config.port
                        );
                    }
                }
                flooding = true;
                parser.reset();
                let rest = (window_start + FLOOD_WINDOW).saturating_duration_since(Instant::now());
                sleep_unless_stopped(rest, stop);
                None
            }
            Ok(n) => {
                let mut lines = Vec::new();
                parser.push(buf.get(..n).unwrap_or_default(), |l| lines.push(l));
                let mut s = lock(shared);
                // A silence that this read ends is a loss too, even when no turn of the
                // loop saw it (the read was already waiting when the timeout passed).
                let before = health_of(&s, config.timeout_ms, Instant::now());
                if health == SyncHealth::Healthy && before != SyncHealth::Healthy {
                    s.counters.losses += 1;
                    tracing::warn!("sync box: {} {before}", config.port);
                    health = before;
                }
                for line in lines {
                    match line {
                        Ok(line) => {
                            if let Some(prev) = s.latest
                                && line.trigger_counter < prev.line.trigger_counter
                            {
                                s.counters.counter_resets += 1;
                                tracing::warn!(
                                    "sync box: trigger counter went back from {} to {} (the box restarted?)",
                                    prev.line.trigger_counter,
                                    line.trigger_counter
                                );
                            }
                            s.latest = Some(SyncSample {
                                line,
                                received: Instant::now(),
                            });
                        }
                        Err(e) => {
                            logged_bad += 1;
                            if logged_bad <= LOGGED_BAD_LINES {
                                tracing::warn!("sync box: rejected a line: {e}");
                                if logged_bad == LOGGED_BAD_LINES {
                                    tracing::warn!(
                                        "sync box: further rejected lines are counted, not logged"
                                    );
                                }
                            }
                        }
                    }
                }
                s.counters.parser = parser.counts();
                None
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::Interrupted
                ) =>
            {
                None
            }
            Err(e) => Some(e.to_string()),
        };
        if let Some(reason) = lost {
            tracing::warn!(
                "sync box: {} lost ({reason}); reopening every {} ms",
                config.port,
                retry.as_millis()
            );
            port = None;
            parser.reset();
            {
                let mut s = lock(shared);
                s.open = false;
                s.counters.read_errors += 1;
                s.counters.parser = parser.counts();
            }
            failing_since_log = true;
            sleep_unless_stopped(retry, stop);
        }
    }
}

/// A timecode reference: timecode frame `timecode` started at host time `at` with trigger
/// pulse `trigger` (None on the local clock).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimecodeAnchor {
    /// The timecode frame that starts at `at` (no sub-frame).
    pub timecode: Timecode,
    /// The trigger pulse that starts it, when known (from the sync box).
    pub trigger: Option<u64>,
    /// Host time.
    pub at: Instant,
}

impl TimecodeAnchor {
    /// The anchor of a sync line: the line arrived `frame_delay` before the camera frames
    /// of the same pulse do.
    pub fn from_sample(sample: &SyncSample, frame_delay: Duration) -> Self {
        Self {
            timecode: sample.line.timecode,
            trigger: Some(sample.line.trigger_counter),
            at: sample.received + frame_delay,
        }
    }
}

/// The timecode and trigger pulse of a camera frame that reached the host at `captured`,
/// for cameras at `camera_fps` (see the module docs): `n = round((captured − anchor.at) ·
/// camera_fps)` camera frames after the anchor, negative when before it.
pub fn stamp_from_anchor(
    anchor: &TimecodeAnchor,
    captured: Instant,
    camera_fps: f64,
) -> (Timecode, Option<u64>) {
    let secs = if captured >= anchor.at {
        (captured - anchor.at).as_secs_f64()
    } else {
        -(anchor.at - captured).as_secs_f64()
    };
    let n = (secs * camera_fps).round() as i64;
    let trigger = anchor.trigger.map(|c| c.saturating_add_signed(n));
    (advance(anchor.timecode, camera_fps, n), trigger)
}

/// `start` advanced by `n` camera frames at `camera_fps` (negative: back), with sub-frames
/// when the camera rate is a whole multiple of the timecode rate.
pub fn advance(start: Timecode, camera_fps: f64, n: i64) -> Timecode {
    let clock = TimecodeClock::new(start, camera_fps);
    if n >= 0 {
        return clock.stamp(n.unsigned_abs());
    }
    let day = start.rate.frames_per_day() as i64;
    let k = i64::from(clock.subframes);
    let (frames_back, subframe) = if k > 1 {
        let total = n; // negative camera frames from the start of `start`
        (total.div_euclid(k), total.rem_euclid(k))
    } else {
        (
            (n as f64 * start.rate.fps() / camera_fps - 1e-9).floor() as i64,
            0,
        )
    };
    let count = (clock.start.frame_count as i64 + frames_back).rem_euclid(day);
    Timecode {
        frame_count: count as u64,
        subframe: subframe as u32,
        ..clock.start
    }
}

/// The timecode label of the host's time of day (UTC) at `rate`: the local clock's start
/// when no sync box has been heard yet.
pub fn time_of_day_timecode(rate: TimecodeRate) -> Timecode {
    let since_epoch = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    let secs = since_epoch.as_secs() % 86_400;
    let frames = (f64::from(since_epoch.subsec_nanos()) * 1e-9 * f64::from(rate.nominal)) as u32;
    let parts = crate::timecode::TimecodeParts {
        hours: (secs / 3600) as u32,
        minutes: ((secs / 60) % 60) as u32,
        seconds: (secs % 60) as u32,
        frames: frames.min(rate.nominal.saturating_sub(1)),
    };
    // A label that drop-frame counting skips: take the first one that exists.
    Timecode::from_parts(rate, parts)
        .or_else(|_| {
            Timecode::from_parts(
                rate,
                crate::timecode::TimecodeParts {
                    frames: rate.nominal / 15,
                    ..parts
                },
            )
        })
        .unwrap_or_else(|_| Timecode::from_frame_count(rate, 0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn tc(text: &str) -> Timecode {
        text.parse().unwrap()
    }

    fn parse_all(bytes: &[u8], chunk: usize) -> (Vec<SyncLine>, Vec<LineError>, ParserCounts) {
        let mut p = LineParser::new();
        let (mut ok, mut bad) = (Vec::new(), Vec::new());
        for c in bytes.chunks(chunk) {
            p.push(c, |l| match l {
                Ok(l) => ok.push(l),
                Err(e) => bad.push(e),
            });
        }
        (ok, bad, p.counts())
    }

    #[test]
    fn formats_and_parses_lines_at_every_rate() {
        for text in [
            "01:00:00:00@30",
            "13:59:59;29@29.97df",
            "23:59:59:23@23.976",
            "00:10:00;00@59.94df",
            "07:00:01:24@25",
        ] {
            let t = tc(text);
            let line = format_line(&t, 987_654_321);
            assert!(
                line.starts_with("$HCSYNC,") && line.ends_with("\r\n"),
                "{line}"
            );
            let (ok, bad, _) = parse_all(line.as_bytes(), 7);
            assert!(bad.is_empty(), "{bad:?}");
            assert_eq!(
                ok,
                vec![SyncLine {
                    timecode: t,
                    trigger_counter: 987_654_321
                }]
            );
        }
        // The documented example.
        assert_eq!(
            format_line(&tc("01:00:00:00@30"), 1200),
            "$HCSYNC,01:00:00:00,30,1200*1B\r\n"
        );
        // Lower-case checksum and a missing `\r` are fine.
        let (ok, _, _) = parse_all(b"$HCSYNC,01:00:00:00,30,1200*1b\n", 100);
        assert_eq!(ok.len(), 1);
    }

    #[test]
    fn counts_garbage_partial_overlong_non_utf8_bad_checksum_and_malformed() {
        let good = format_line(&tc("01:00:00:00@30"), 5);
        let good2 = format_line(&tc("01:00:00:01@30"), 7);
        let mut stream = Vec::new();
        stream.extend_from_slice(b"\x00\xffnoise"); // 7 garbage bytes
        stream.extend_from_slice(good.as_bytes());
        stream.extend_from_slice(b"$HCSYNC,01:00"); // cut short by the next `$`
        stream.extend_from_slice(good2.as_bytes());
        stream.extend_from_slice(b"$HCSYNC,01:00:00:02,30,9*00\r\n"); // bad checksum
        stream.push(b'$');
        stream.extend(std::iter::repeat_n(b'A', 200)); // overlong
        stream.extend_from_slice(b"\r\n");
        stream.extend_from_slice(b"$HC\xc3\x28SYNC*00\r\n"); // not UTF-8
        let payload = "HCSYNC,25:00:00:00,30,1";
        stream.extend_from_slice(
            format!("${payload}*{:02X}\r\n", checksum(payload.as_bytes())).as_bytes(),
        );
        let payload = "HCSYNC,01:00:00:00,31.5,1";
        stream.extend_from_slice(
            format!("${payload}*{:02X}\r\n", checksum(payload.as_bytes())).as_bytes(),
        );
        stream.extend_from_slice(b"$HCSYNC,01:00:00:03,30,11\r\n"); // no checksum
        stream.extend_from_slice(good2.as_bytes());
        for chunk in [1, 3, 64, 4096] {
            let (ok, bad, counts) = parse_all(&stream, chunk);
            assert_eq!(ok.len(), 3, "chunk {chunk}");
            assert_eq!(ok[1].trigger_counter, 7);
            assert_eq!(
                counts,
                ParserCounts {
                    lines_ok: 3,
                    garbage_bytes: 7,
                    partial_lines: 1,
                    overlong_lines: 1,
                    non_utf8_lines: 1,
                    bad_checksums: 2,
                    malformed_lines: 2,
                },
                "chunk {chunk}"
            );
            assert_eq!(bad.len() as u64, counts.bad_lines() - counts.partial_lines);
        }
    }

    #[test]
    fn never_panics_on_random_bytes() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut p = LineParser::new();
        for _ in 0..2000 {
            let n = rng.random_range(0..64);
            let bytes: Vec<u8> = (0..n)
                .map(|_| match rng.random_range(0..6) {
                    0 => b'$',
                    1 => b'\n',
                    2 => b'*',
                    3 => b',',
                    _ => rng.random(),
                })
                .collect();
            p.push(&bytes, |_| {});
        }
        let good = format_line(&tc("01:00:00:00@30"), 1);
        let mut got = 0;
        p.push(format!("\n{good}").as_bytes(), |l| {
            got += usize::from(l.is_ok())
        });
        assert_eq!(got, 1, "the parser resynchronises after noise");
    }

    #[test]
    fn stamps_camera_frames_with_subframes_and_before_the_line() {
        let t0 = Instant::now();
        let anchor = TimecodeAnchor {
            timecode: tc("01:00:00:10@30"),
            trigger: Some(1000),
            at: t0,
        };
        let at = |ms: f64| t0 + Duration::from_secs_f64(ms / 1000.0);
        // 60 fps cameras on 30 fps code: two sub-frames per timecode frame.
        let (t, trig) = stamp_from_anchor(&anchor, at(0.4), 60.0);
        assert_eq!((t.to_string(), trig), ("01:00:00:10.0".into(), Some(1000)));
        let (t, trig) = stamp_from_anchor(&anchor, at(16.9), 60.0);
        assert_eq!((t.to_string(), trig), ("01:00:00:10.1".into(), Some(1001)));
        let (t, trig) = stamp_from_anchor(&anchor, at(50.0), 60.0);
        assert_eq!((t.to_string(), trig), ("01:00:00:11.1".into(), Some(1003)));
        // A frame that arrives before the line of its timecode frame.
        let before = t0.checked_sub(Duration::from_micros(16_700)).unwrap();
        let (t, trig) = stamp_from_anchor(&anchor, before, 60.0);
        assert_eq!((t.to_string(), trig), ("01:00:00:09.1".into(), Some(999)));
        // Cameras at the code rate: no sub-frames; 24 fps code under 60 fps cameras: the
        // timecode frame in effect.
        let (t, _) = stamp_from_anchor(&anchor, at(100.0), 30.0);
        assert_eq!(t.to_string(), "01:00:00:13");
        let a24 = TimecodeAnchor {
            timecode: tc("01:00:00:10@24"),
            ..anchor
        };
        let (t, _) = stamp_from_anchor(&a24, at(100.0), 60.0);
        assert_eq!(t.to_string(), "01:00:00:12");
        // Across midnight, backwards.
        let a = TimecodeAnchor {
            timecode: tc("00:00:00:00@30"),
            ..anchor
        };
        let (t, _) = stamp_from_anchor(&a, before, 60.0);
        assert_eq!(t.to_string(), "23:59:59:29.1");
        // Drop-frame: forwards across a dropping minute.
        let a = TimecodeAnchor {
            timecode: tc("00:00:59;29@29.97df"),
            ..anchor
        };
        let (t, _) = stamp_from_anchor(&a, at(1000.0 / 29.97), 29.97);
        assert_eq!(t.to_string(), "00:01:00;02");
    }

    #[test]
    fn time_of_day_is_a_valid_label() {
        for rate in [
            TimecodeRate::FPS_29_97_DF,
            TimecodeRate::FPS_25,
            TimecodeRate::FPS_60,
        ] {
            let t = time_of_day_timecode(rate);
            assert_eq!(Timecode::parse_at(&t.to_string(), rate).unwrap(), t);
        }
    }

    fn wait_for(what: &str, timeout: Duration, mut cond: impl FnMut() -> bool) {
        let end = Instant::now() + timeout;
        while !cond() {
            assert!(Instant::now() < end, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// A pseudo-terminal pair whose slave end is reachable through a symbolic link, as a
    /// udev `/dev/serial/by-id` link would be.
    fn pty(link: &Path) -> (serialport::TTYPort, serialport::TTYPort) {
        let (master, slave) = serialport::TTYPort::pair().unwrap();
        let _ = std::fs::remove_file(link);
        std::os::unix::fs::symlink(serialport::SerialPort::name(&slave).unwrap(), link).unwrap();
        (master, slave)
    }

    use std::path::Path;

    #[test]
    fn reads_a_pseudo_terminal_through_garbage_loss_and_reconnection() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("syncbox");
        let (mut master, slave) = pty(&link);
        let config = SyncBoxConfig {
            port: link.to_string_lossy().into_owned(),
            timeout_ms: 300,
            retry_ms: 50,
            ..Default::default()
        };
        let sync = SyncBox::start(config).unwrap();
        wait_for("open", Duration::from_secs(5), || {
            sync.status().counters.opens == 1
        });
        let start = tc("10:00:00:00@30");
        let mut counter = 0u64;
        let mut send = |m: &mut serialport::TTYPort, n: usize, extra: &[u8]| {
            for _ in 0..n {
                let t = start.add_frames(counter / 2);
                m.write_all(extra).unwrap();
                m.write_all(format_line(&t, counter).as_bytes()).unwrap();
                counter += 2;
            }
        };
        send(&mut master, 3, b"");
        wait_for("three lines", Duration::from_secs(5), || {
            sync.status().counters.parser.lines_ok == 3
        });
        assert_eq!(sync.status().health, SyncHealth::Healthy);
        assert_eq!(sync.status().latest.unwrap().line.trigger_counter, 4);
        // Garbage and a bad checksum.
        send(&mut master, 1, b"\xfe\xffjunk");
        master
            .write_all(b"$HCSYNC,10:00:00:09,30,18*00\r\n")
            .unwrap();
        wait_for("the rejected line", Duration::from_secs(5), || {
            sync.status().counters.parser.bad_checksums == 1
        });
        let c = sync.status().counters;
        assert_eq!((c.parser.lines_ok, c.parser.garbage_bytes), (4, 6));
        // Silence: the box is lost after the timeout, and back with the next line.
        wait_for("silence", Duration::from_secs(5), || {
            sync.status().health == SyncHealth::Silent
        });
        send(&mut master, 1, b"");
        wait_for("recovery", Duration::from_secs(5), || {
            sync.status().health == SyncHealth::Healthy
        });
        // The device vanishes mid-line.
        master.write_all(b"$HCSYNC,10:00").unwrap();
        std::thread::sleep(Duration::from_millis(50));
        drop(master);
        drop(slave);
        wait_for("the loss", Duration::from_secs(5), || {
            sync.status().health != SyncHealth::Healthy
        });
        wait_for("a read error", Duration::from_secs(5), || {
            sync.status().counters.read_errors >= 1
        });
        assert_eq!(sync.status().latest.unwrap().line.trigger_counter, 8);
        // A new device behind the same link: reopened, lines again.
        let (mut master, _slave) = pty(&link);
        wait_for("the reopening", Duration::from_secs(5), || {
            sync.status().counters.opens >= 2
        });
        send(&mut master, 2, b"");
        wait_for("lines again", Duration::from_secs(5), || {
            sync.status().health == SyncHealth::Healthy
                && sync.status().latest.unwrap().line.trigger_counter == 12
        });
        let c = sync.status().counters;
        assert_eq!(c.parser.lines_ok, 7);
        assert!(c.parser.partial_lines >= 1, "{c:?}");
        assert!(c.losses >= 2, "{c:?}");
    }

    /// A flood of garbage (the issue's 40 MB/s serial flood) is detected and dropped
    /// unparsed at a bounded rate; lines parse again once it stops.
    #[test]
    fn a_serial_flood_is_rate_limited_and_counted() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("syncbox");
        let (mut master, _slave) = pty(&link);
        let sync = SyncBox::start(SyncBoxConfig {
            port: link.to_string_lossy().into_owned(),
            timeout_ms: 300,
            retry_ms: 50,
            ..Default::default()
        })
        .unwrap();
        wait_for("open", Duration::from_secs(5), || {
            sync.status().counters.opens == 1
        });
        serialport::SerialPort::set_timeout(&mut master, Duration::from_millis(5)).unwrap();
        let flood = vec![b'x'; 4096];
        let t = Instant::now();
        let mut sent = 0usize;
        while t.elapsed() < Duration::from_millis(600) {
            // The pty's buffer fills while the reader sits out its windows: writes time out.
            if let Ok(n) = master.write(&flood) {
                sent += n;
            }
        }
        let c = sync.status().counters;
        assert!(c.floods >= 1 && c.flood_bytes > 0, "{c:?}");
        // Parsed input stays within the limit (plus one window's budget and a read).
        let parsed = c.parser.garbage_bytes;
        assert!(
            parsed as f64 <= MAX_BYTES_PER_SEC as f64 * 0.8 + 2048.0,
            "{parsed} bytes parsed of {sent} sent"
        );
        // Calm again (once the backlog is read): lines at the box's pace parse.
        let before = sync.status().counters.parser.lines_ok;
        let end = Instant::now() + Duration::from_secs(10);
        let mut k = 0u64;
        while sync.status().counters.parser.lines_ok < before + 3 {
            assert!(Instant::now() < end, "no line parsed after the flood");
            let line = format_line(&tc("10:00:00:00@30").add_frames(k), 2 * k);
            let _ = master.write_all(line.as_bytes());
            k += 1;
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    #[test]
    fn a_missing_device_is_retried_not_fatal() {
        let sync = SyncBox::start(SyncBoxConfig {
            port: "/nonexistent/ttyUSB9".into(),
            retry_ms: 20,
            ..Default::default()
        })
        .unwrap();
        wait_for("retries", Duration::from_secs(5), || {
            sync.status().counters.open_failures >= 2
        });
        assert_eq!(sync.status().health, SyncHealth::Connecting);
        assert!(
            SyncBox::start(SyncBoxConfig {
                baud: 0,
                ..Default::default()
            })
            .is_err()
        );
    }
}
