//! C3D marker files as bundles: the motion-capture industry's binary marker format
//! (C3D.ORG, "The C3D File Format User Guide"), read with the `c3dio` crate.
//!
//! - Labels from `POINT:LABELS`, continued in `LABELS2`, `LABELS3`, ... (more than 255
//!   points); a label with a subject prefix (`Actor:LBrow`, as Vicon writes) matches the
//!   layout marker after the last `:` when the whole label does not.
//! - Units from `POINT:UNITS` (`mm`, `cm`, `m`; case and surrounding blanks ignored),
//!   converted to millimetres. Integer files are scaled by `POINT:SCALE`, float files
//!   (negative scale) are not: both are handled by `c3dio`.
//! - Frame `f` of the file (C3D frames are 1-based, from the header's first frame) is
//!   bundles frame `f − 1`, so helmcap's own `bundles.c3d` (which starts at C3D frame
//!   `index + 1`) reads back with its frame numbers.
//! - A point whose residual is negative is missing in that frame (the C3D convention for
//!   an invalid point); so is one with a non-finite coordinate (counted like a `nan` CSV
//!   row).
//! - Intel, DEC and SGI/MIPS processor types (byte orders and float formats).
//!
//! The points are taken as they are: helmcap writes them in the head frame. A file from
//! an optical system is in the capture volume's frame; stabilize it to the head frame
//! before solving.

use std::collections::HashMap;

use nalgebra::Point3;

use super::{BundlesError, FrameBundles, LabelMap, ReadReport};
use crate::dataset::MarkerLayout;
use crate::frame_index::FrameIndex;

/// What a C3D file said about itself, for the caller to report.
#[derive(Debug, Clone, PartialEq)]
pub struct C3dInfo {
    /// `POINT:RATE` (the header's rate), frames per second.
    pub rate_hz: f64,
    /// `POINT:UNITS` as written (`mm`, `cm`, `m`).
    pub units: String,
    /// The first C3D frame (1-based).
    pub first_frame: u64,
    /// Points per frame in the file.
    pub points: usize,
    /// Whether the data are floats (negative `POINT:SCALE`) or scaled integers.
    pub float_data: bool,
}

/// True when `bytes` look like a C3D file: the header's second byte is the C3D key 0x50
/// and the first names the parameter section's block (C3D.ORG, header word 1).
pub(crate) fn is_c3d(bytes: &[u8]) -> bool {
    bytes.len() >= 512 && bytes[1] == 0x50 && bytes[0] >= 2
}

/// Parses C3D bytes into bundles for `layout`; `name` stands for the file in errors.
pub(crate) fn parse_c3d(
    bytes: &[u8],
    name: &str,
    layout: &MarkerLayout,
    label_map: Option<&LabelMap>,
) -> Result<(Vec<FrameBundles>, ReadReport), BundlesError> {
    let err = |message: String| BundlesError::Mismatch {
        path: name.to_string(),
        message: format!("C3D: {message}"),
    };
    check_header(bytes).map_err(&err)?;
    // `c3dio` indexes without checks in a few places: a malformed file must still be one
    // error line, not a crash.
    let parsed = std::panic::catch_unwind(|| c3dio::C3d::from_bytes(bytes).map_err(Box::new))
        .map_err(|_| err("malformed file (the C3D parser gave up)".into()))?;
    let c3d = parsed.map_err(|e| err(format!("not a readable C3D file ({e:?})")))?;
    let points = &c3d.points;
    let units: String = points.units.iter().collect::<String>().trim().to_string();
    let to_mm = match units.to_ascii_lowercase().as_str() {
        "mm" => 1.0,
        "cm" => 10.0,
        "m" => 1000.0,
        other => {
            return Err(err(format!(
                "POINT:UNITS is {other:?}; expected mm, cm or m"
            )));
        }
    };
    let mut labels: Vec<String> = points.labels.clone();
    for k in 2.. {
        let Some(p) = c3d.parameters.get("POINT", &format!("LABELS{k}")) else {
            break;
        };
        let more: Vec<String> = p
            .try_into()
            .map_err(|e| err(format!("POINT:LABELS{k} is not text ({e:?})")))?;
        labels.extend(more);
    }
    let (rows, cols) = points.points.size();
    if labels.len() < cols {
        return Err(err(format!(
            "{cols} points per frame but POINT:LABELS (and LABELS2, ...) name {}",
            labels.len()
        )));
    }
    let index: HashMap<&str, usize> = layout
        .markers
        .iter()
        .enumerate()
        .map(|(i, m)| (m.name.as_str(), i))
        .collect();
    let lookup = |label: &str| -> Option<usize> {
        let mapped = label_map.and_then(|m| m.get(label)).unwrap_or(label);
        index.get(mapped).copied().or_else(|| {
            let (_, short) = label.rsplit_once(':')?;
            let mapped = label_map.and_then(|m| m.get(short)).unwrap_or(short);
            index.get(mapped).copied()
        })
    };
    // Column of each layout marker; unknown labels are counted per frame they appear in.
    let mut column_of = vec![None; layout.len()];
    let mut report = ReadReport::default();
    let mut unknown_columns = Vec::new();
    for (c, label) in labels.iter().take(cols).enumerate() {
        match lookup(label) {
            Some(m) => {
                if let Some(prev) = column_of[m] {
                    return Err(err(format!(
                        "points {} ({:?}) and {} ({label:?}) both map to marker {}; \
                         fix POINT:LABELS or the label map",
                        prev + 1,
                        labels[prev],
                        c + 1,
                        layout.markers[m].name
                    )));
                }
                column_of[m] = Some(c);
            }
            None => unknown_columns.push(c),
        }
    }
    if column_of.iter().all(Option::is_none) && cols > 0 {
        let some: Vec<&str> = labels.iter().take(3).map(String::as_str).collect();
        return Err(err(format!(
            "no point label names a marker of the layout (file has e.g. {}; layout has e.g. \
             {}): wrong marker layout, or give --label-map CSV (c3d_label,marker)",
            some.join(", "),
            super::layout_examples(layout)
        )));
    }
    let first = u64::from(points.first_frame.max(1));
    let mut frames = Vec::with_capacity(rows);
    for r in 0..rows {
        let mut positions = vec![None; layout.len()];
        for (m, c) in column_of.iter().enumerate() {
            let Some(p) = c.and_then(|c| points.points.get(r, c)) else {
                continue;
            };
            report.rows += 1;
            if p.residual < 0.0 {
                continue;
            }
            let xyz = p.point.map(|x| f64::from(x) * to_mm);
            if xyz.iter().all(|x| x.is_finite()) {
                positions[m] = Some(Point3::from(xyz));
            } else {
                report.non_finite_rows += 1;
            }
        }
        for &c in &unknown_columns {
            if points.points.get(r, c).is_some_and(|p| p.residual >= 0.0) {
                *report.unknown_markers.entry(labels[c].clone()).or_default() += 1;
            }
        }
        frames.push(FrameBundles {
            frame: FrameIndex::new(first - 1 + r as u64),
            positions,
        });
    }
    report.c3d = Some(C3dInfo {
        rate_hz: f64::from(points.frame_rate),
        units,
        first_frame: first,
        points: cols,
        float_data: matches!(points.format, c3dio::DataFormat::Float),
    });
    Ok((frames, report))
}

/// Checks what `c3dio` takes on trust: the processor type and a frame range that does
/// not run backwards.
fn check_header(bytes: &[u8]) -> Result<(), String> {
    let param_block = usize::from(bytes[0]);
    let proc_at = (param_block - 1) * 512 + 3;
    let Some(&processor) = bytes.get(proc_at) else {
        return Err(format!(
            "the parameter section (block {param_block}) is past the end of the file"
        ));
    };
    let word = |i: usize| -> u16 {
        let b = [bytes[2 * i], bytes[2 * i + 1]];
        match processor {
            86 => u16::from_be_bytes(b),
            _ => u16::from_le_bytes(b),
        }
    };
    if !(84..=86).contains(&processor) {
        return Err(format!(
            "unknown processor type {processor} (expected 84 Intel, 85 DEC or 86 SGI/MIPS)"
        ));
    }
    // Header words 4 and 5 (1-based): first and last frame.
    let (first, last) = (word(3), word(4));
    if last < first {
        return Err(format!(
            "the header's last frame {last} is before its first frame {first}"
        ));
    }
    Ok(())
}
