//! Reading back the `mesh.usda` that [`UsdSink`](super::UsdSink) writes: one `Mesh` prim
//! with `faceVertexCounts`, `faceVertexIndices` and time-sampled `points`, as a frame
//! sequence (e.g. the input of `helmcap enhance`).
//!
//! This is a reader for that one layout of USD's text format, not a general USD parser:
//! binary crate files (`.usdc`), several meshes, meshes without time-sampled points,
//! and time samples of differing vertex counts are refused with an error naming the file
//! and line.

use std::path::Path;

use nalgebra::Point3;

/// A mesh sequence read from a `mesh.usda`.
#[derive(Debug, Clone, PartialEq)]
pub struct UsdMeshSequence {
    /// Vertices per face (`faceVertexCounts`).
    pub face_vertex_counts: Vec<u32>,
    /// Face corners (`faceVertexIndices`), vertex indices.
    pub face_vertex_indices: Vec<u32>,
    /// The time samples of `points` in file order: time code and positions (the file's
    /// units; helmcap writes millimetres).
    pub frames: Vec<(f64, Vec<Point3<f64>>)>,
}

/// Why a `mesh.usda` could not be read.
#[derive(Debug, thiserror::Error)]
pub enum UsdReadError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The system's error.
        source: std::io::Error,
    },
    /// The file is not the layout helmcap writes. Fix: give a `mesh.usda` written by
    /// helmcap (`--export usd`), or export the sequence as OBJ files.
    #[error("{path}:{line}: {message}")]
    Format {
        /// The file.
        path: String,
        /// 1-based line of the problem.
        line: usize,
        /// What is wrong.
        message: String,
    },
}

/// Reads the mesh sequence of a `mesh.usda` written by [`UsdSink`](super::UsdSink).
///
/// # Errors
/// [`UsdReadError::Io`] when the file cannot be read; [`UsdReadError::Format`] for a
/// binary USD file, a file without exactly one `Mesh` prim, missing topology or
/// `points.timeSamples`, malformed numbers, an index past the points, or time samples
/// with different vertex counts.
pub fn read_usda_sequence(path: &Path) -> Result<UsdMeshSequence, UsdReadError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| UsdReadError::Io {
        path: name.clone(),
        source,
    })?;
    parse_usda_sequence(&bytes, &name)
}

/// [`read_usda_sequence`] on the file's bytes; `name` is used in errors.
///
/// # Errors
/// As [`read_usda_sequence`].
pub fn parse_usda_sequence(bytes: &[u8], name: &str) -> Result<UsdMeshSequence, UsdReadError> {
    let err = |offset: usize, message: String| UsdReadError::Format {
        path: name.to_string(),
        line: 1 + bytes[..offset.min(bytes.len())]
            .iter()
            .filter(|&&b| b == b'\n')
            .count(),
        message,
    };
    if bytes.starts_with(b"PXR-USDC") {
        return Err(err(
            0,
            "binary USD (usdc) is not supported; give the text file (.usda)".into(),
        ));
    }
    if !bytes.starts_with(b"#usda") {
        return Err(err(0, "not a USD text file (no `#usda` header)".into()));
    }
    let text =
        std::str::from_utf8(bytes).map_err(|e| err(e.valid_up_to(), "not UTF-8 text".into()))?;
    let meshes: Vec<usize> = text.match_indices("def Mesh ").map(|(i, _)| i).collect();
    match meshes.len() {
        0 => return Err(err(0, "no `def Mesh` prim".into())),
        1 => {}
        _ => {
            return Err(err(
                meshes[1],
                format!(
                    "{} `def Mesh` prims; only a file with one mesh is read",
                    meshes.len()
                ),
            ));
        }
    }
    let find = |key: &str| -> Result<usize, UsdReadError> {
        text.find(key).map(|i| i + key.len()).ok_or_else(|| {
            err(
                meshes[0],
                format!(
                    "the mesh has no `{}`",
                    key.trim_end_matches([' ', '=', '[', '{'])
                ),
            )
        })
    };
    let mut cursor = Cursor { text, pos: 0 };
    cursor.pos = find("int[] faceVertexCounts = ")?;
    let face_vertex_counts = cursor.int_array().map_err(|(at, m)| err(at, m))?;
    cursor.pos = find("int[] faceVertexIndices = ")?;
    let face_vertex_indices = cursor.int_array().map_err(|(at, m)| err(at, m))?;
    let corners: u64 = face_vertex_counts.iter().map(|&c| u64::from(c)).sum();
    if corners != face_vertex_indices.len() as u64 {
        return Err(err(
            cursor.pos,
            format!(
                "faceVertexCounts sum to {corners} corners but faceVertexIndices has {}",
                face_vertex_indices.len()
            ),
        ));
    }
    cursor.pos = find("point3f[] points.timeSamples = ")?;
    cursor.expect('{').map_err(|(at, m)| err(at, m))?;
    let mut frames: Vec<(f64, Vec<Point3<f64>>)> = Vec::new();
    // Time code (bits) -> byte offset of its sample, to refuse a time code used twice (one
    // sample would silently replace the other in any USD reader).
    let mut seen: std::collections::HashMap<u64, usize> = std::collections::HashMap::new();
    loop {
        cursor.skip_space();
        if cursor.eat('}') {
            break;
        }
        if !frames.is_empty() {
            cursor.expect(',').map_err(|(at, m)| err(at, m))?;
            cursor.skip_space();
            if cursor.eat('}') {
                break;
            }
        }
        let at = cursor.pos;
        let time = cursor.number().map_err(|(at, m)| err(at, m))?;
        if let Some(&before) = seen.get(&(time + 0.0).to_bits()) {
            let first_line = 1 + bytes[..before].iter().filter(|&&b| b == b'\n').count();
            return Err(err(
                at,
                format!(
                    "time code {time} has a second sample (the first is on line {first_line}); \
                     each time code may have one"
                ),
            ));
        }
        seen.insert((time + 0.0).to_bits(), at);
        cursor.expect(':').map_err(|(at, m)| err(at, m))?;
        let points = cursor.point_array().map_err(|(at, m)| err(at, m))?;
        if let Some((_, first)) = frames.first()
            && first.len() != points.len()
        {
            return Err(err(
                at,
                format!(
                    "time sample {time} has {} points, the first one {}",
                    points.len(),
                    first.len()
                ),
            ));
        }
        frames.push((time, points));
    }
    let Some((_, first)) = frames.first() else {
        return Err(err(cursor.pos, "`points.timeSamples` is empty".into()));
    };
    if let Some(&v) = face_vertex_indices
        .iter()
        .find(|&&v| v as usize >= first.len())
    {
        return Err(err(
            0,
            format!(
                "faceVertexIndices uses vertex {v} but the points have {}",
                first.len()
            ),
        ));
    }
    Ok(UsdMeshSequence {
        face_vertex_counts,
        face_vertex_indices,
        frames,
    })
}

/// A position in the text; errors are (byte offset, message).
struct Cursor<'a> {
    text: &'a str,
    pos: usize,
}

impl Cursor<'_> {
    fn skip_space(&mut self) {
        let rest = &self.text[self.pos..];
        self.pos += rest.len() - rest.trim_start().len();
    }

    fn eat(&mut self, c: char) -> bool {
        if self.text[self.pos..].starts_with(c) {
            self.pos += c.len_utf8();
            true
        } else {
            false
        }
    }

    fn expect(&mut self, c: char) -> Result<(), (usize, String)> {
        self.skip_space();
        if self.eat(c) {
            Ok(())
        } else {
            Err((self.pos, format!("expected `{c}`")))
        }
    }

    fn number(&mut self) -> Result<f64, (usize, String)> {
        self.skip_space();
        let rest = &self.text[self.pos..];
        let len = rest
            .find(|c: char| !(c.is_ascii_digit() || matches!(c, '-' | '+' | '.' | 'e' | 'E')))
            .unwrap_or(rest.len());
        let token = &rest[..len];
        let value: f64 = token.parse().map_err(|_| {
            (
                self.pos,
                format!("expected a number, found {:?}", first_word(rest)),
            )
        })?;
        if !value.is_finite() {
            return Err((self.pos, format!("non-finite number {token}")));
        }
        self.pos += len;
        Ok(value)
    }

    fn int_array(&mut self) -> Result<Vec<u32>, (usize, String)> {
        self.expect('[')?;
        let mut out = Vec::new();
        loop {
            self.skip_space();
            if self.eat(']') {
                return Ok(out);
            }
            if !out.is_empty() {
                self.expect(',')?;
            }
            let at = self.pos;
            let v = self.number()?;
            if v < 0.0 || v.fract() != 0.0 || v > f64::from(u32::MAX) {
                return Err((at, format!("expected a non-negative integer, found {v}")));
            }
            out.push(v as u32);
        }
    }

    fn point_array(&mut self) -> Result<Vec<Point3<f64>>, (usize, String)> {
        self.expect('[')?;
        let mut out = Vec::new();
        loop {
            self.skip_space();
            if self.eat(']') {
                return Ok(out);
            }
            if !out.is_empty() {
                self.expect(',')?;
            }
            self.expect('(')?;
            let x = self.number()?;
            self.expect(',')?;
            let y = self.number()?;
            self.expect(',')?;
            let z = self.number()?;
            self.expect(')')?;
            out.push(Point3::new(x, y, z));
        }
    }
}

/// The text up to the next white space or delimiter, for error messages.
fn first_word(s: &str) -> &str {
    let end = s
        .find(|c: char| c.is_whitespace() || matches!(c, ',' | ')' | ']' | '}'))
        .unwrap_or(s.len())
        .min(40);
    s.get(..end).unwrap_or("")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::GrayImage;
    use crate::pipeline::{FrameResult, Metrics, SessionMeta, Sink};
    use std::sync::Arc;

    /// The session the sink tests write: `neutral` as the mesh, at `fps` from `first_frame`.
    fn session(neutral: &Arc<crate::mesh::Mesh>, fps: f64, first_frame: usize) -> SessionMeta {
        SessionMeta {
            name: "t".into(),
            fps,
            timecode_rate: None,
            first_frame: first_frame.into(),
            frame_count: None,
            layout: Arc::new(Default::default()),
            neutral_markers_head: Arc::new(Vec::new()),
            neutral: Some(neutral.clone()),
            face_vertices: None,
            rig: None,
            image_size: None,
        }
    }

    /// A head pose that turns and moves with the frame index.
    fn head_pose(index: usize) -> nalgebra::Isometry3<f64> {
        let k = index as f64;
        nalgebra::Isometry3::new(
            nalgebra::Vector3::new(2.0 * k, -1.0, 150.0 + k),
            nalgebra::Vector3::new(0.01 * k, -0.02 * k, 0.005),
        )
    }

    #[test]
    fn reads_back_what_the_usd_sink_writes() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mesh.usda");
        let neutral = Arc::new(crate::mesh::test_meshes::grid(4, 2.0));
        let mut sink = crate::sink::UsdSink::new(&path);
        sink.begin(&session(&neutral, 60.0, 3)).unwrap();
        let mut written = Vec::new();
        for index in 3..6 {
            let image = GrayImage {
                width: 1,
                height: 1,
                data: vec![0],
            };
            let mut fr = FrameResult::new(index.into(), 0, None, [image.clone(), image], 0);
            let points: Vec<Point3<f64>> = neutral
                .positions
                .iter()
                .map(|p| p + nalgebra::Vector3::new(0.25 * index as f64, -1.5, 0.125))
                .collect();
            fr.mesh = Some(Arc::new(points.clone()));
            // Frame 4 has no head pose (labels lost).
            fr.cam0_from_head = (index != 4).then(|| head_pose(index));
            sink.write(&fr).unwrap();
            written.push((index as f64, points));
        }
        sink.finish(&Metrics::default()).unwrap();
        // `/Face` carries the head pose relative to the first frame's, on the frames
        // that have one.
        let text = std::fs::read_to_string(&path).unwrap();
        let origin = head_pose(3).inverse();
        let samples = text
            .split("matrix4d xformOp:transform.timeSamples = {")
            .nth(1)
            .unwrap();
        let samples = &samples[..samples.find('}').unwrap()];
        let expected = format!(
            "\n        3: {},\n        5: {},\n    ",
            crate::sink::usd::usd_matrix(&(origin * head_pose(3))),
            crate::sink::usd::usd_matrix(&(origin * head_pose(5)))
        );
        assert_eq!(samples, expected);
        assert!(text.contains("uniform token[] xformOpOrder = [\"xformOp:transform\"]\n}\n"));
        let read = read_usda_sequence(&path).unwrap();
        assert_eq!(read.face_vertex_indices, neutral.face_vertices);
        assert_eq!(read.face_vertex_counts.len(), neutral.face_count());
        assert_eq!(read.frames.len(), 3);
        for ((t, p), (tw, pw)) in read.frames.iter().zip(&written) {
            assert_eq!(t, tw);
            assert_eq!(p.len(), pw.len());
            // The sink writes single precision.
            for (a, b) in p.iter().zip(pw) {
                assert!(
                    (a - b).norm() < 1e-5 * (1.0 + b.coords.norm()),
                    "{a} vs {b}"
                );
            }
        }
    }

    /// The sink's file after a failed write (part of a frame written, then cut back) reads
    /// with the complete frames, and the metadata written into its room says how many.
    #[test]
    fn a_failed_frame_is_cut_and_the_rest_published() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mesh.usda");
        let neutral = Arc::new(crate::mesh::test_meshes::grid(3, 1.0));
        let mut sink = crate::sink::UsdSink::new(&path);
        sink.begin(&session(&neutral, 30.0, 0)).unwrap();
        let image = GrayImage {
            width: 1,
            height: 1,
            data: vec![0],
        };
        for index in 0..4 {
            let mut fr = FrameResult::new(
                crate::frame_index::FrameIndex::new(index),
                0,
                None,
                [image.clone(), image.clone()],
                0,
            );
            fr.mesh = Some(Arc::new(neutral.positions.clone()));
            sink.write(&fr).unwrap();
        }
        sink.simulate_failed_write();
        let stopped = Metrics {
            stopped: Some("sink usd failed at frame 4: No space left on device".into()),
            ..Metrics::default()
        };
        sink.finish(&stopped).unwrap();
        let read = read_usda_sequence(&path).unwrap();
        assert_eq!(read.frames.len(), 4);
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("int frames = 4"), "{text}");
        assert!(text.contains("endTimeCode = 3"));
        assert!(text.contains("string stopped = \"sink usd failed"));
    }

    #[test]
    fn refuses_other_usd_files_with_the_line() {
        let name = "x.usda";
        let e = parse_usda_sequence(b"PXR-USDC\0\0", name).unwrap_err();
        assert!(e.to_string().contains("binary USD"), "{e}");
        let e = parse_usda_sequence(b"hello", name).unwrap_err();
        assert!(e.to_string().contains("not a USD text file"), "{e}");
        let two = "#usda 1.0\ndef Mesh \"a\" {}\ndef Mesh \"b\" {}\n";
        let e = parse_usda_sequence(two.as_bytes(), name).unwrap_err();
        assert_eq!(
            e.to_string(),
            "x.usda:3: 2 `def Mesh` prims; only a file with one mesh is read"
        );
        let still = "#usda 1.0\ndef Mesh \"a\" {\n int[] faceVertexCounts = [3]\n \
                     int[] faceVertexIndices = [0, 1, 2]\n point3f[] points = [(0, 0, 0)]\n}\n";
        let e = parse_usda_sequence(still.as_bytes(), name).unwrap_err();
        assert!(e.to_string().contains("points.timeSamples"), "{e}");
        let ragged = "#usda 1.0\ndef Mesh \"a\" {\n int[] faceVertexCounts = [3]\n \
                      int[] faceVertexIndices = [0, 1, 2]\n point3f[] points.timeSamples = {\n \
                      0: [(0, 0, 0), (1, 0, 0), (0, 1, 0)],\n 1: [(0, 0, 0), (1, 0, 0)]\n }\n}\n";
        let e = parse_usda_sequence(ragged.as_bytes(), name).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("x.usda:7: time sample 1 has 2 points"),
            "{e}"
        );
        let bad = ragged.replace("(1, 0, 0), (0, 1, 0)", "(1, zero, 0), (0, 1, 0)");
        let e = parse_usda_sequence(bad.as_bytes(), name).unwrap_err();
        assert!(
            e.to_string().contains("expected a number, found \"zero\""),
            "{e}"
        );
        let fine = ragged.replace(",\n 1: [(0, 0, 0), (1, 0, 0)]", "");
        let ok = parse_usda_sequence(fine.as_bytes(), name).unwrap();
        assert_eq!(ok.frames.len(), 1);
        assert_eq!(ok.frames[0].1[2], Point3::new(0.0, 1.0, 0.0));
    }

    /// Two samples at one time code: one would replace the other (enhance used to report
    /// 5 frames and write 4); refused with both lines.
    #[test]
    fn refuses_a_time_code_with_two_samples() {
        let text = "#usda 1.0\ndef Mesh \"a\" {\n int[] faceVertexCounts = [3]\n \
                    int[] faceVertexIndices = [0, 1, 2]\n point3f[] points.timeSamples = {\n \
                    0: [(0, 0, 0), (1, 0, 0), (0, 1, 0)],\n 1: [(0, 0, 0), (1, 0, 0), (0, 1, 0)],\n \
                    1.0: [(0, 0, 0), (1, 0, 0), (0, 1, 1)]\n }\n}\n";
        let e = parse_usda_sequence(text.as_bytes(), "x.usda").unwrap_err();
        assert_eq!(
            e.to_string(),
            "x.usda:8: time code 1 has a second sample (the first is on line 7); \
             each time code may have one"
        );
    }
}
