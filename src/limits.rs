//! Limits by design: every size an input file or config declares (element counts, frame
//! numbers, vertex ranges, queue sizes, durations) is checked against one of these before
//! anything is allocated or looped over, and error messages quote at most
//! [`EXCERPT_CHARS`] characters of an offending line ([`excerpt`]). The README section
//! "Limits" lists them for users.
//!
//! Depends on nothing else in the crate (any layer may use it).

/// Most characters of an input line an error message quotes.
pub const EXCERPT_CHARS: usize = 80;

/// Largest frame number a recording (`frames.csv`), a bundles file or a mesh sequence may
/// use: 2^24 − 1 (77 hours at 60 fps; also the largest frame count C3D's float
/// `POINT:FRAMES` holds exactly).
pub const MAX_FRAME_NUMBER: u64 = (1 << 24) - 1;

/// Largest jump between consecutive frame numbers of a recording (`frames.csv`): 65,535
/// frames (18 minutes at 60 fps). A bigger hole is a damaged file, not a dropped stretch,
/// and would make the exports fill it with empty frames.
pub const MAX_FRAME_GAP: u64 = 65_535;

/// Most rows all elements of a PLY file may declare together (10^8: a 100-million-vertex
/// scan). Each element's count is also checked against the bytes the file holds.
pub const MAX_PLY_ROWS: u64 = 100_000_000;

/// Most vertices a vertex range of a dataset manifest (`face_vertices`, `[regions]`) may
/// span: 10^7, two orders of magnitude above a production face mesh. Ranges are also
/// checked against the neutral mesh's vertex count where it is known.
pub const MAX_RANGE_VERTICES: u64 = 10_000_000;

/// Most frames a queue of the live source or the recorder may hold
/// (`[live] camera_queue`, `[record] queue_frames`): 10,000 frames, under three minutes
/// at 60 fps; at 2.6 MB per 1280×1024 stereo frame that is already 26 GB.
pub const MAX_QUEUE_FRAMES: usize = 10_000;

/// Longest duration a config may set in milliseconds (timeouts, delays, retry pauses):
/// one hour.
pub const MAX_DURATION_MS: f64 = 3_600_000.0;

/// Longest take a command may be asked to run (`--seconds`): one week.
pub const MAX_TAKE_SECONDS: f64 = 7.0 * 86_400.0;

/// `line` shortened for an error message: at most [`EXCERPT_CHARS`] characters (cut on a
/// character boundary), then `…` and the line's full length when it was longer.
pub fn excerpt(line: &str) -> String {
    match line.char_indices().nth(EXCERPT_CHARS) {
        None => line.to_string(),
        Some((cut, _)) => format!(
            "{}… ({} characters in all)",
            &line[..cut],
            line.chars().count()
        ),
    }
}

/// [`excerpt`] as a quoted, escaped string (like `{:?}`), for messages that quote a
/// field.
pub fn quoted(field: &str) -> String {
    match field.char_indices().nth(EXCERPT_CHARS) {
        None => format!("{field:?}"),
        Some((cut, _)) => format!(
            "{:?}… ({} characters in all)",
            &field[..cut],
            field.chars().count()
        ),
    }
}

/// The text of an error and its chain of causes, each cause once: a cause whose text the
/// message already contains (a wrapper that prints its source too) is not repeated.
pub fn error_chain(e: &(dyn std::error::Error + 'static)) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let t = s.to_string();
        if !text.contains(&t) {
            text.push_str(": ");
            text.push_str(&t);
        }
        source = s.source();
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn excerpt_keeps_short_lines_and_cuts_long_ones() {
        assert_eq!(excerpt("a,b,c"), "a,b,c");
        let long = "é".repeat(1_000_000);
        let e = excerpt(&long);
        assert!(e.chars().count() < EXCERPT_CHARS + 40, "{}", e.len());
        assert!(e.ends_with("(1000000 characters in all)"), "{e}");
        let q = quoted(&"x".repeat(500));
        assert!(q.starts_with("\"xxx") && q.len() < 130, "{q}");
    }

    #[test]
    fn error_chain_prints_each_cause_once() {
        #[derive(Debug, thiserror::Error)]
        #[error("cannot read a.yaml: {0}")]
        struct Wrap(#[source] std::io::Error);
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file");
        let text = error_chain(&Wrap(io));
        assert_eq!(text, "cannot read a.yaml: No such file");
    }
}
