//! Bundles: the stabilized 3D marker positions of each frame, in millimetres in the head
//! frame, read from and written to the bundles CSV.
//!
//! CSV contract: header starting `frame,marker,x,y,z`; more columns may follow and are
//! ignored (the pipeline writes a per-bundle `confidence`); a marker missing from a frame
//! simply has no row for that frame.
//!
//! # Reading policy
//! - A malformed row (too few fields, a frame that is not a non-negative integer, a
//!   coordinate that is not a number) is an error naming the file and line.
//! - A row with a non-finite coordinate (`nan`, `inf`) means the tracker lost the marker in
//!   that frame: the marker counts as missing there, and the row is counted in
//!   [`ReadReport::non_finite_rows`]. Trackers write such rows, and one lost dot must not
//!   stop a whole take.
//! - A row with a coordinate beyond [`MAX_PLAUSIBLE_MM`] (10 m) is no face marker (wrong
//!   units, corrupt data): the marker counts as missing there, counted in
//!   [`ReadReport::implausible_rows`].
//! - A frame number above [`crate::limits::MAX_FRAME_NUMBER`] is an error naming the line.
//! - A marker name that the layout does not know is skipped and counted per name in
//!   [`ReadReport::unknown_markers`] (capture files often carry helmet or stabilization dots
//!   the face layout leaves out). A file in which *no* row names a layout marker is an error:
//!   that is a wrong layout, not extra dots.
//! - The same marker twice in one frame is an error naming both lines: which of the two
//!   positions is right cannot be decided.
//!
//! Frames come out sorted by frame number; rows may come in any order.
//!
//! # C3D
//! Wherever a bundles CSV is read, a C3D marker file is read too, recognised by content
//! (not extension): see [`c3d`] for what is taken from it. A [`LabelMap`]
//! (`--label-map CSV`, header `c3d_label,marker`) renames markers whose names differ
//! from the layout's, in either format.
//!
//! Depends on [`crate::dataset`] (marker layouts) only.

pub mod c3d;

use std::collections::{BTreeMap, HashMap};
use std::io::Write;
use std::path::Path;

use nalgebra::Point3;

use crate::atomic_file::write_atomically;
use crate::dataset::MarkerLayout;
use crate::file_error::FileError;
use crate::frame_index::FrameIndex;
use crate::name_pairs::{NamePairsFormat, parse_name_pairs};

/// Errors from reading or writing a bundles CSV.
#[derive(Debug, thiserror::Error)]
pub enum BundlesError {
    /// The file could not be read or written, or a line of it is malformed.
    #[error(transparent)]
    File(#[from] FileError),
    /// The file as a whole does not fit the layout (no known marker at all, or a frame
    /// whose marker count differs from the layout when writing).
    #[error("{path}: {message}")]
    Mismatch {
        /// The file involved.
        path: String,
        /// What was wrong.
        message: String,
    },
}

/// The bundles of one frame, indexed like the marker layout.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameBundles {
    /// Frame number (as in the file).
    pub frame: FrameIndex,
    /// Position of each layout marker (millimetres, head frame); `None` when the marker is
    /// missing from the frame.
    pub positions: Vec<Option<Point3<f64>>>,
}

impl FrameBundles {
    /// A frame with every marker present.
    pub fn full(frame: FrameIndex, positions: &[Point3<f64>]) -> Self {
        Self {
            frame,
            positions: positions.iter().copied().map(Some).collect(),
        }
    }

    /// Number of markers present.
    pub fn present_count(&self) -> usize {
        self.positions.iter().filter(|p| p.is_some()).count()
    }
}

/// What [`read_bundles`] skipped, for the caller to report.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReadReport {
    /// Data rows read (header and blank lines excluded).
    pub rows: usize,
    /// Rows with a non-finite coordinate, treated as the marker missing in that frame.
    pub non_finite_rows: usize,
    /// Rows naming a marker the layout does not have, counted per name (sorted by name).
    /// For a C3D file: per label, the frames in which that point is valid.
    pub unknown_markers: BTreeMap<String, usize>,
    /// Rows with a coordinate farther than [`MAX_PLAUSIBLE_MM`] from the head frame's
    /// origin (wrong units, a corrupt file), treated as the marker missing in that frame.
    pub implausible_rows: usize,
    /// What the file said about itself when it was a C3D file (`None` for a CSV).
    pub c3d: Option<c3d::C3dInfo>,
}

/// Marker names of a capture file mapped to the layout's (CSV `c3d_label,marker`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LabelMap {
    map: HashMap<String, String>,
}

impl LabelMap {
    /// A map from (file name, layout name) pairs.
    pub fn new<I: IntoIterator<Item = (String, String)>>(pairs: I) -> Self {
        Self {
            map: pairs.into_iter().collect(),
        }
    }

    /// The layout's name for a file's marker name, when the map has one.
    pub fn get(&self, label: &str) -> Option<&str> {
        self.map.get(label).map(String::as_str)
    }

    /// Reads a label map CSV: header `c3d_label,marker`, one row per renamed marker.
    ///
    /// # Errors
    /// [`BundlesError`] naming the file (and line): unreadable file, wrong header, a row
    /// without two names, a label mapped twice.
    pub fn read_csv(path: &Path) -> Result<Self, BundlesError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| {
            BundlesError::File(FileError::Io {
                path: name.clone(),
                source,
            })
        })?;
        Self::parse_csv(&text, &name)
    }

    /// Parses label map CSV text; `name` stands for the file in errors.
    ///
    /// # Errors
    /// As [`LabelMap::read_csv`].
    pub fn parse_csv(text: &str, name: &str) -> Result<Self, BundlesError> {
        let format = NamePairsFormat {
            columns: ["c3d_label", "marker"],
            what: "label",
            extra_columns: true,
        };
        let rows = parse_name_pairs(text, &format).map_err(|(line, message)| {
            BundlesError::File(FileError::Parse {
                path: name.to_string(),
                line,
                message,
            })
        })?;
        Ok(Self::new(rows))
    }
}

/// A bundle coordinate beyond ±10 m is not on a face in the head frame (a face is about
/// 250 mm across): such rows count as missing markers and are reported
/// ([`ReadReport::implausible_rows`]), so they cannot drag a solve to 10^300 mm.
pub const MAX_PLAUSIBLE_MM: f64 = 10_000.0;

/// A frame being read: positions and the line of each marker's row (0: none yet).
type FrameRows = (Vec<Option<Point3<f64>>>, Vec<usize>);

/// Reads a bundles CSV for `layout` (see the module docs for the policy on bad rows).
///
/// # Errors
/// [`BundlesError`] naming the file (and line): unreadable file, missing or wrong header,
/// malformed row, a marker twice in a frame, no row naming a layout marker.
pub fn read_bundles(
    path: &Path,
    layout: &MarkerLayout,
) -> Result<(Vec<FrameBundles>, ReadReport), BundlesError> {
    read_bundles_with(path, layout, None)
}

/// Reads a marker file for `layout`, a bundles CSV or a C3D file (recognised by content),
/// renaming markers through `label_map` when given.
///
/// # Errors
/// As [`read_bundles`]; for a C3D file, errors name the file and say "C3D" (unreadable
/// file, unknown units, no point label naming a layout marker, two labels for one
/// marker). A file that is neither is an error saying so.
pub fn read_bundles_with(
    path: &Path,
    layout: &MarkerLayout,
    label_map: Option<&LabelMap>,
) -> Result<(Vec<FrameBundles>, ReadReport), BundlesError> {
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| {
        BundlesError::File(FileError::Io {
            path: name.clone(),
            source,
        })
    })?;
    if c3d::is_c3d(&bytes) {
        return c3d::parse_c3d(&bytes, &name, layout, label_map);
    }
    let text = String::from_utf8(bytes).map_err(|_| BundlesError::Mismatch {
        path: name.clone(),
        message: "neither a bundles CSV (not UTF-8 text) nor a C3D file (no C3D header): \
                  give a frame,marker,x,y,z CSV or a C3D marker file"
            .into(),
    })?;
    parse_bundles_with(&text, &name, layout, label_map)
}

/// Parses bundles CSV text; `name` stands for the file in errors.
///
/// # Errors
/// As [`read_bundles`].
pub fn parse_bundles(
    text: &str,
    name: &str,
    layout: &MarkerLayout,
) -> Result<(Vec<FrameBundles>, ReadReport), BundlesError> {
    parse_bundles_with(text, name, layout, None)
}

/// [`parse_bundles`] with markers renamed through `label_map`.
///
/// # Errors
/// As [`read_bundles`].
pub fn parse_bundles_with(
    text: &str,
    name: &str,
    layout: &MarkerLayout,
    label_map: Option<&LabelMap>,
) -> Result<(Vec<FrameBundles>, ReadReport), BundlesError> {
    let err = |line: usize, message: String| {
        BundlesError::File(FileError::Parse {
            path: name.to_string(),
            line,
            message,
        })
    };
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let (hline, header) = lines
        .next()
        .ok_or_else(|| err(1, "empty file: expected header frame,marker,x,y,z".into()))?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    if cols.len() < 5 || cols[..5] != ["frame", "marker", "x", "y", "z"] {
        return Err(err(
            hline,
            format!(
                "header {} should start with frame,marker,x,y,z",
                crate::limits::quoted(header)
            ),
        ));
    }
    let index: HashMap<&str, usize> = layout
        .markers
        .iter()
        .enumerate()
        .map(|(i, m)| (m.name.as_str(), i))
        .collect();
    let n = layout.len();
    let mut report = ReadReport::default();
    // frame -> (positions, line of each marker's row)
    let mut frames: BTreeMap<u64, FrameRows> = BTreeMap::new();
    let mut known_rows = 0usize;
    for (line, row) in lines {
        report.rows += 1;
        let fields: Vec<&str> = row.splitn(6, ',').map(str::trim).collect();
        if fields.len() < 5 {
            return Err(err(
                line,
                format!(
                    "{} fields, expected at least 5 (frame,marker,x,y,z)",
                    fields.len()
                ),
            ));
        }
        let frame: u64 = fields[0].parse().map_err(|_| {
            err(
                line,
                format!(
                    "frame {} is not a non-negative integer",
                    crate::limits::quoted(fields[0])
                ),
            )
        })?;
        if frame > crate::limits::MAX_FRAME_NUMBER {
            return Err(err(
                line,
                format!(
                    "frame {frame} is above the largest frame number, {}",
                    crate::limits::MAX_FRAME_NUMBER
                ),
            ));
        }
        let marker = label_map
            .and_then(|m| m.get(fields[1]))
            .unwrap_or(fields[1]);
        let mut xyz = [0.0f64; 3];
        for (k, c) in xyz.iter_mut().enumerate() {
            *c = fields[2 + k].parse().map_err(|_| {
                err(
                    line,
                    format!(
                        "{} coordinate {} is not a number",
                        ["x", "y", "z"][k],
                        crate::limits::quoted(fields[2 + k])
                    ),
                )
            })?;
        }
        let Some(&m) = index.get(marker) else {
            *report
                .unknown_markers
                .entry(marker.to_string())
                .or_default() += 1;
            continue;
        };
        known_rows += 1;
        let (positions, rows) = frames
            .entry(frame)
            .or_insert_with(|| (vec![None; n], vec![0; n]));
        if rows[m] != 0 {
            return Err(err(
                line,
                format!(
                    "marker {marker} appears twice in frame {frame} (first on line {}); \
                     keep one row per marker and frame",
                    rows[m]
                ),
            ));
        }
        rows[m] = line;
        if !xyz.iter().all(|c| c.is_finite()) {
            report.non_finite_rows += 1;
        } else if xyz.iter().any(|c| c.abs() > MAX_PLAUSIBLE_MM) {
            report.implausible_rows += 1;
        } else {
            positions[m] = Some(Point3::from(xyz));
        }
    }
    if known_rows == 0 && report.rows > 0 {
        let some: Vec<&str> = report
            .unknown_markers
            .keys()
            .take(3)
            .map(String::as_str)
            .collect();
        return Err(BundlesError::Mismatch {
            path: name.to_string(),
            message: format!(
                "no row names a marker of the layout (file has e.g. {}; layout has e.g. {}): \
                 wrong marker layout?",
                some.join(", "),
                layout_examples(layout)
            ),
        });
    }
    let frames = frames
        .into_iter()
        .map(|(frame, (positions, _))| FrameBundles {
            frame: FrameIndex::new(frame),
            positions,
        })
        .collect();
    Ok((frames, report))
}

/// Writes frames as a bundles CSV (`frame,marker,x,y,z`, millimetres), atomically.
/// Missing markers get no row. Coordinates are written with full `f64` precision.
///
/// # Errors
/// [`BundlesError::Mismatch`] when a frame's marker count differs from the layout's;
/// [`FileError::Io`] when the file cannot be written.
pub fn write_bundles(
    path: &Path,
    layout: &MarkerLayout,
    frames: &[FrameBundles],
) -> Result<(), BundlesError> {
    if let Some(f) = frames.iter().find(|f| f.positions.len() != layout.len()) {
        return Err(BundlesError::Mismatch {
            path: path.display().to_string(),
            message: format!(
                "frame {} has {} markers but the layout has {}",
                f.frame,
                f.positions.len(),
                layout.len()
            ),
        });
    }
    write_atomically(path, |w| {
        writeln!(w, "frame,marker,x,y,z")?;
        for f in frames {
            for (m, p) in layout.markers.iter().zip(&f.positions) {
                if let Some(p) = p {
                    writeln!(w, "{},{},{},{},{}", f.frame, m.name, p.x, p.y, p.z)?;
                }
            }
        }
        Ok(())
    })
    .map_err(|source| {
        BundlesError::File(FileError::Io {
            path: path.display().to_string(),
            source,
        })
    })
}

/// The first few marker names of a layout, for errors that say what was expected.
pub(crate) fn layout_examples(layout: &MarkerLayout) -> String {
    layout
        .markers
        .iter()
        .take(3)
        .map(|m| m.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::Marker;

    fn layout() -> MarkerLayout {
        MarkerLayout {
            markers: ["A", "B", "C"]
                .iter()
                .enumerate()
                .map(|(i, n)| Marker {
                    name: n.to_string(),
                    vertex: i as u32,
                    stabilize_weight: 0.0,
                })
                .collect(),
        }
    }

    #[test]
    fn round_trip_with_missing_markers() {
        let l = layout();
        let frames = vec![
            FrameBundles {
                frame: FrameIndex::new(0),
                positions: vec![
                    Some(Point3::new(1.0, 2.0, 3.0)),
                    None,
                    Some(Point3::new(0.1 + 0.2, -1e-9, 7.5)),
                ],
            },
            FrameBundles::full(FrameIndex::new(5), &[Point3::new(4.0, 5.0, 6.0); 3]),
        ];
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("b.csv");
        write_bundles(&p, &l, &frames).unwrap();
        let (back, report) = read_bundles(&p, &l).unwrap();
        assert_eq!(back, frames);
        assert_eq!(report.rows, 5);
        assert_eq!(report.non_finite_rows, 0);
        assert!(report.unknown_markers.is_empty());
    }

    #[test]
    fn extra_columns_order_nan_and_unknown() {
        let text = "frame,marker,x,y,z,confidence\n\
                    2,B,1,1,1,0.9\n\
                    1,A,0,0,0,0.5\n\
                    1,HELMET1,9,9,9,1\n\
                    1,C,nan,0,0,0\n\
                    2,HELMET1,9,9,9,1\n";
        let (frames, report) = parse_bundles(text, "t.csv", &layout()).unwrap();
        assert_eq!(frames.len(), 2);
        assert_eq!(frames[0].frame, FrameIndex::new(1));
        assert_eq!(frames[0].positions[0], Some(Point3::origin()));
        assert_eq!(frames[0].positions[2], None);
        assert_eq!(frames[1].present_count(), 1);
        assert_eq!(report.non_finite_rows, 1);
        assert_eq!(report.unknown_markers.get("HELMET1"), Some(&2));
    }

    #[test]
    fn errors_name_file_and_line() {
        for (bad, line, what) in [
            ("", 1, "empty"),
            ("marker,frame,x,y,z\n", 1, "header"),
            ("frame,marker,x,y,z\n0,A,1,2\n", 2, "5"),
            ("frame,marker,x,y,z\n-1,A,1,2,3\n", 2, "frame"),
            ("frame,marker,x,y,z\n0,A,1,two,3\n", 2, "y coordinate"),
            (
                "frame,marker,x,y,z\n0,A,1,2,3\n0,B,1,2,3\n0,A,1,2,3\n",
                4,
                "twice",
            ),
        ] {
            let e = parse_bundles(bad, "t.csv", &layout()).unwrap_err();
            let msg = e.to_string();
            assert!(msg.contains(&format!("t.csv:{line}:")), "{msg}");
            assert!(msg.contains(what), "{msg} should mention {what}");
        }
        let e = parse_bundles("frame,marker,x,y,z\n0,Q,1,2,3\n", "t.csv", &layout())
            .unwrap_err()
            .to_string();
        assert!(e.contains("wrong marker layout"), "{e}");
    }

    /// Bundles at 1e300 mm (the reproducer) count as missing markers, reported; a
    /// frame number past the limit and a megabyte field are errors that quote briefly.
    #[test]
    fn implausible_coordinates_huge_frames_and_long_fields() {
        let text = "frame,marker,x,y,z\n0,A,1e300,0,0\n0,B,1,2,3\n1,A,0,-20000,0\n";
        let (frames, report) = parse_bundles(text, "t.csv", &layout()).unwrap();
        assert_eq!(report.implausible_rows, 2);
        assert_eq!(frames[0].positions[0], None);
        assert_eq!(frames[0].positions[1], Some(Point3::new(1.0, 2.0, 3.0)));
        let e = parse_bundles("frame,marker,x,y,z\n16777216,A,0,0,0\n", "t.csv", &layout())
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("t.csv:2: frame 16777216 is above"), "{e}");
        let long = format!(
            "frame,marker,x,y,z\n0,A,{},0,0\n",
            "7".repeat(1 << 20) + "x"
        );
        let e = parse_bundles(&long, "t.csv", &layout())
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("t.csv:2: x coordinate") && e.len() < 200,
            "{e}"
        );
    }

    #[test]
    fn header_only_is_an_empty_take() {
        let (frames, report) = parse_bundles("frame,marker,x,y,z\n", "t", &layout()).unwrap();
        assert!(frames.is_empty());
        assert_eq!(report.rows, 0);
    }
}
