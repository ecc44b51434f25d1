//! Calibration files: OpenCV FileStorage YAML (`%YAML:1.0`, matrices as `!!opencv-matrix`
//! with `rows`, `cols`, `dt`, `data`), readable by `cv::FileStorage` and Python's
//! `cv2.FileStorage`.
//!
//! Keys: `image_width`, `image_height`, `model0`, `K0`, `D0`, `model1`, `K1`, `D1`, `R`, `T`,
//! `rms`. `model*` is `fisheye` (D 4×1) or `pinhole` (D 5×1); `K*` and `R` are 3×3, `T` is
//! 3×1 in millimetres with `X1 = R·X0 + T`, `rms` is the reprojection RMS in pixels.
//!
//! The reader accepts the subset of YAML that OpenCV writes for such files (top-level
//! `key: value` lines, matrices whose `data` list may span several lines, `#` comments), so
//! a file written by OpenCV itself reads too.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{IsometryMatrix3, Matrix3, Rotation3, Translation3};

use super::{Camera, Distortion, StereoRig};

/// Errors reading or writing a calibration file; each names the file and, where it
/// applies, the key and line.
#[derive(Debug, thiserror::Error)]
pub enum CalibFileError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not OpenCV FileStorage YAML or a line cannot be parsed.
    #[error("{path}:{line}: {message}")]
    Syntax {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A required key is absent.
    #[error("{path}: missing key `{key}`")]
    MissingKey {
        /// The file.
        path: PathBuf,
        /// The key.
        key: &'static str,
    },
    /// A key's value is invalid (wrong type, wrong matrix size, not a rotation, ...).
    #[error("{path}:{line}: key `{key}`: {message}")]
    BadValue {
        /// The file.
        path: PathBuf,
        /// 1-based line of the key.
        line: usize,
        /// The key.
        key: String,
        /// What is wrong.
        message: String,
    },
}

/// A parsed top-level value.
#[derive(Debug)]
enum Value {
    Scalar(String),
    Matrix {
        rows: usize,
        cols: usize,
        data: Vec<f64>,
    },
}

/// Parsed file: key → (line, value).
struct Parsed {
    path: PathBuf,
    entries: HashMap<String, (usize, Value)>,
}

impl Parsed {
    fn get(&self, key: &'static str) -> Result<&(usize, Value), CalibFileError> {
        self.entries
            .get(key)
            .ok_or_else(|| CalibFileError::MissingKey {
                path: self.path.clone(),
                key,
            })
    }

    fn bad(&self, line: usize, key: &str, message: impl Into<String>) -> CalibFileError {
        CalibFileError::BadValue {
            path: self.path.clone(),
            line,
            key: key.to_string(),
            message: message.into(),
        }
    }

    fn scalar(&self, key: &'static str) -> Result<(usize, &str), CalibFileError> {
        match self.get(key)? {
            (line, Value::Scalar(s)) => Ok((*line, s.as_str())),
            (line, Value::Matrix { .. }) => {
                Err(self.bad(*line, key, "expected a scalar, found a matrix"))
            }
        }
    }

    fn string(&self, key: &'static str) -> Result<(usize, String), CalibFileError> {
        let (line, s) = self.scalar(key)?;
        Ok((line, unquote(s).to_string()))
    }

    fn real(&self, key: &'static str) -> Result<f64, CalibFileError> {
        let (line, s) = self.scalar(key)?;
        parse_real(s).filter(|v| v.is_finite()).ok_or_else(|| {
            self.bad(
                line,
                key,
                format!("{} is not a finite number", crate::limits::quoted(s)),
            )
        })
    }

    fn positive_int(&self, key: &'static str) -> Result<u32, CalibFileError> {
        let (line, s) = self.scalar(key)?;
        s.parse::<u32>().ok().filter(|&v| v > 0).ok_or_else(|| {
            self.bad(
                line,
                key,
                format!(
                    "{} is not a positive whole number",
                    crate::limits::quoted(s)
                ),
            )
        })
    }

    /// A matrix of the given size (a column vector accepts `n×1` or `1×n`).
    fn matrix(
        &self,
        key: &'static str,
        rows: usize,
        cols: usize,
    ) -> Result<(usize, Vec<f64>), CalibFileError> {
        match self.get(key)? {
            (
                line,
                Value::Matrix {
                    rows: r,
                    cols: c,
                    data,
                },
            ) => {
                let ok = (*r, *c) == (rows, cols) || (cols == 1 && (*r, *c) == (1, rows));
                if !ok {
                    return Err(self.bad(
                        *line,
                        key,
                        format!("expected a {rows}×{cols} matrix, found {r}×{c}"),
                    ));
                }
                if data.iter().any(|v| !v.is_finite()) {
                    return Err(self.bad(*line, key, "a value is not finite"));
                }
                Ok((*line, data.clone()))
            }
            (line, Value::Scalar(_)) => Err(self.bad(
                *line,
                key,
                format!("expected a {rows}×{cols} !!opencv-matrix, found a scalar"),
            )),
        }
    }

    fn camera(
        &self,
        width_px: u32,
        height_px: u32,
        model_key: &'static str,
        k_key: &'static str,
        d_key: &'static str,
    ) -> Result<Camera, CalibFileError> {
        let (model_line, model) = self.string(model_key)?;
        let n = match model.as_str() {
            "fisheye" => 4,
            "pinhole" => 5,
            other => {
                return Err(self.bad(
                    model_line,
                    model_key,
                    format!(
                        "unknown model {} (expected fisheye or pinhole)",
                        crate::limits::quoted(other)
                    ),
                ));
            }
        };
        let (k_line, k) = self.matrix(k_key, 3, 3)?;
        let (d_line, d) = self.matrix(d_key, n, 1)?;
        let distortion = Distortion::from_coefficients(&model, &d)
            .map_err(|e| self.bad(d_line, d_key, e.to_string()))?;
        let camera = Camera {
            width_px,
            height_px,
            k: Matrix3::from_row_slice(&k),
            distortion,
        };
        camera
            .validate()
            .map_err(|e| self.bad(k_line, k_key, e.to_string()))?;
        Ok(camera)
    }
}

fn unquote(s: &str) -> &str {
    let s = s.trim();
    s.strip_prefix('"')
        .and_then(|t| t.strip_suffix('"'))
        .or_else(|| s.strip_prefix('\'').and_then(|t| t.strip_suffix('\'')))
        .unwrap_or(s)
}

/// Parses a number as OpenCV writes it (`1.`, `6.4e+02`, `.Inf`, `.Nan`).
fn parse_real(s: &str) -> Option<f64> {
    let s = s.trim();
    match s {
        ".Inf" | ".inf" | "+.Inf" => Some(f64::INFINITY),
        "-.Inf" | "-.inf" => Some(f64::NEG_INFINITY),
        ".Nan" | ".nan" | ".NaN" => Some(f64::NAN),
        _ => s.parse().ok(),
    }
}

/// Removes a `#` comment outside quotes.
fn strip_comment(line: &str) -> &str {
    let mut in_quote = false;
    for (i, c) in line.char_indices() {
        match c {
            '"' => in_quote = !in_quote,
            '#' if !in_quote => return &line[..i],
            _ => {}
        }
    }
    line
}

fn parse(path: &Path, text: &str) -> Result<Parsed, CalibFileError> {
    let syntax = |line: usize, message: String| CalibFileError::Syntax {
        path: path.to_path_buf(),
        line,
        message,
    };
    let lines: Vec<&str> = text.lines().collect();
    match lines.first() {
        Some(first) if first.trim_start_matches('\u{feff}').starts_with("%YAML") => {}
        _ => {
            return Err(syntax(
                1,
                "not an OpenCV FileStorage YAML file (the first line must be `%YAML:1.0`)".into(),
            ));
        }
    }
    let mut entries = HashMap::new();
    let mut i = 1;
    while i < lines.len() {
        let line_no = i + 1;
        let raw = strip_comment(lines[i]);
        i += 1;
        if raw.trim().is_empty() || raw.trim() == "---" || raw.trim() == "..." {
            continue;
        }
        if raw.starts_with([' ', '\t']) {
            return Err(syntax(line_no, "unexpected indented line".into()));
        }
        let (key, value) = raw.split_once(':').ok_or_else(|| {
            syntax(
                line_no,
                format!(
                    "expected `key: value`, found {}",
                    crate::limits::quoted(raw)
                ),
            )
        })?;
        // Known keys are short: a longer one is kept (and quoted in errors) shortened.
        let key = crate::limits::excerpt(key.trim());
        let value = value.trim();
        let parsed = if value.starts_with("!!opencv-matrix") {
            // Indented fields follow until the next top-level line.
            let mut fields: HashMap<&str, String> = HashMap::new();
            let mut open_field: Option<&str> = None;
            while i < lines.len() {
                let sub = strip_comment(lines[i]);
                if !sub.trim().is_empty() && !sub.starts_with([' ', '\t']) {
                    break;
                }
                i += 1;
                let sub = sub.trim();
                if sub.is_empty() {
                    continue;
                }
                if let Some(name) = open_field {
                    if let Some(acc) = fields.get_mut(name) {
                        acc.push(' ');
                        acc.push_str(sub);
                    }
                    if sub.contains(']') {
                        open_field = None;
                    }
                    continue;
                }
                let (name, v) = sub.split_once(':').ok_or_else(|| {
                    syntax(
                        i,
                        format!(
                            "key `{key}`: expected `field: value`, found {}",
                            crate::limits::quoted(sub)
                        ),
                    )
                })?;
                let name = match name.trim() {
                    "rows" => "rows",
                    "cols" => "cols",
                    "dt" => "dt",
                    "data" => "data",
                    other => {
                        return Err(syntax(
                            i,
                            format!(
                                "key `{key}`: unknown matrix field {}",
                                crate::limits::quoted(other)
                            ),
                        ));
                    }
                };
                let v = v.trim().to_string();
                if name == "data" && v.starts_with('[') && !v.contains(']') {
                    open_field = Some("data");
                }
                fields.insert(name, v);
            }
            let bad = |message: String| CalibFileError::BadValue {
                path: path.to_path_buf(),
                line: line_no,
                key: key.clone(),
                message,
            };
            let dim = |name: &str| -> Result<usize, CalibFileError> {
                fields
                    .get(name)
                    .and_then(|s| s.parse().ok())
                    .ok_or_else(|| bad(format!("matrix field `{name}` missing or not a number")))
            };
            let rows = dim("rows")?;
            let cols = dim("cols")?;
            match fields.get("dt").map(|s| unquote(s)) {
                Some("d" | "f" | "i" | "u" | "s" | "c" | "w") => {}
                other => {
                    return Err(bad(format!(
                        "unsupported matrix element type {}",
                        other.map_or("none".into(), crate::limits::quoted)
                    )));
                }
            }
            let data_text = fields
                .get("data")
                .ok_or_else(|| bad("matrix field `data` missing".into()))?;
            let inner = data_text
                .trim()
                .strip_prefix('[')
                .and_then(|t| t.strip_suffix(']'))
                .ok_or_else(|| bad("matrix `data` must be a [ ... ] list".into()))?;
            let data = inner
                .split(',')
                .map(str::trim)
                .filter(|s| !s.is_empty())
                .map(|s| {
                    parse_real(s)
                        .ok_or_else(|| bad(format!("{} is not a number", crate::limits::quoted(s))))
                })
                .collect::<Result<Vec<f64>, _>>()?;
            if rows.checked_mul(cols) != Some(data.len()) {
                return Err(bad(format!(
                    "matrix declares {rows}×{cols} but has {} values",
                    data.len()
                )));
            }
            Value::Matrix { rows, cols, data }
        } else {
            Value::Scalar(value.to_string())
        };
        if entries.insert(key.clone(), (line_no, parsed)).is_some() {
            return Err(syntax(line_no, format!("key `{key}` appears twice")));
        }
    }
    Ok(Parsed {
        path: path.to_path_buf(),
        entries,
    })
}

/// Parses calibration text; `path` only names the source in errors.
///
/// # Errors
/// See [`CalibFileError`].
pub fn parse_rig(path: &Path, text: &str) -> Result<StereoRig, CalibFileError> {
    let p = parse(path, text)?;
    let width_px = p.positive_int("image_width")?;
    let height_px = p.positive_int("image_height")?;
    let cam0 = p.camera(width_px, height_px, "model0", "K0", "D0")?;
    let cam1 = p.camera(width_px, height_px, "model1", "K1", "D1")?;
    let (r_line, r) = p.matrix("R", 3, 3)?;
    let r = Matrix3::from_row_slice(&r);
    let orthogonality = (r.transpose() * r - Matrix3::identity()).abs().max();
    if orthogonality > 1e-6 || r.determinant() <= 0.0 {
        return Err(p.bad(
            r_line,
            "R",
            format!(
                "not a rotation (|RᵀR − I| = {orthogonality:.2e}, det = {:.6})",
                r.determinant()
            ),
        ));
    }
    let (_, t) = p.matrix("T", 3, 1)?;
    let rms_px = p.real("rms")?;
    Ok(StereoRig {
        cam0,
        cam1,
        cam1_from_cam0: IsometryMatrix3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            Rotation3::from_matrix_unchecked(r),
        ),
        rms_px,
    })
}

/// Reads a calibration file.
///
/// # Errors
/// See [`CalibFileError`]: unreadable file, syntax, missing key, wrong matrix size, invalid
/// camera or rotation.
pub fn read_rig(path: &Path) -> Result<StereoRig, CalibFileError> {
    let text = std::fs::read_to_string(path).map_err(|source| CalibFileError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_rig(path, &text)
}

/// Formats a number so that it parses back to the same `f64` (shortest round-trip form).
fn real(v: f64) -> String {
    format!("{v:?}")
}

fn write_matrix(out: &mut String, key: &str, rows: usize, cols: usize, data: &[f64]) {
    let values: Vec<String> = data.iter().map(|&v| real(v)).collect();
    let _ = writeln!(out, "{key}: !!opencv-matrix");
    let _ = writeln!(out, "   rows: {rows}");
    let _ = writeln!(out, "   cols: {cols}");
    let _ = writeln!(out, "   dt: d");
    let _ = writeln!(out, "   data: [ {} ]", values.join(", "));
}

/// The calibration file text for a rig.
pub fn format_rig(rig: &StereoRig) -> String {
    let mut out = String::from("%YAML:1.0\n---\n");
    let _ = writeln!(out, "image_width: {}", rig.cam0.width_px);
    let _ = writeln!(out, "image_height: {}", rig.cam0.height_px);
    for (i, cam) in [&rig.cam0, &rig.cam1].into_iter().enumerate() {
        let _ = writeln!(out, "model{i}: \"{}\"", cam.distortion.model_name());
        let k: Vec<f64> = cam.k.transpose().iter().copied().collect();
        write_matrix(&mut out, &format!("K{i}"), 3, 3, &k);
        let d = cam.distortion.coefficients();
        write_matrix(&mut out, &format!("D{i}"), d.len(), 1, &d);
    }
    let r: Vec<f64> = rig
        .cam1_from_cam0
        .rotation
        .matrix()
        .transpose()
        .iter()
        .copied()
        .collect();
    write_matrix(&mut out, "R", 3, 3, &r);
    let t = rig.cam1_from_cam0.translation.vector;
    write_matrix(&mut out, "T", 3, 1, &[t.x, t.y, t.z]);
    let _ = writeln!(out, "rms: {}", real(rig.rms_px));
    out
}

/// Writes a rig's calibration file atomically.
///
/// # Errors
/// [`CalibFileError::BadValue`] for an invalid rig (nothing is written), or
/// [`CalibFileError::Io`].
pub fn write_rig(path: &Path, rig: &StereoRig) -> Result<(), CalibFileError> {
    rig.validate().map_err(|e| CalibFileError::BadValue {
        path: path.to_path_buf(),
        line: 0,
        key: "rig".into(),
        message: e.to_string(),
    })?;
    let text = format_rig(rig);
    crate::atomic_file::write_atomically(path, |w| w.write_all(text.as_bytes())).map_err(|source| {
        CalibFileError::Io {
            path: path.to_path_buf(),
            source,
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector3, vector};

    pub(crate) fn rig() -> StereoRig {
        let cam0 = Camera::new(
            1280,
            1024,
            [520.123456789, 521.5, 641.3, 509.8],
            Distortion::Fisheye {
                k: [0.05, -0.012, 0.004, -8.123e-4],
            },
        );
        let mut cam1 = Camera::new(
            1280,
            1024,
            [905.0, 903.25, 630.1, 520.7],
            Distortion::Pinhole {
                k: [-0.28, 0.09, -0.012],
                p: [0.0012, -7e-5],
            },
        );
        cam1.k[(0, 1)] = 0.25;
        StereoRig {
            cam0,
            cam1,
            cam1_from_cam0: IsometryMatrix3::from_parts(
                Translation3::new(0.3, -69.7, 1.1),
                Rotation3::from_scaled_axis(Vector3::new(0.21, 0.012, -0.004)),
            ),
            rms_px: 0.1234,
        }
    }

    #[test]
    fn text_round_trip_is_identical() {
        let r = rig();
        let text = format_rig(&r);
        assert!(text.starts_with("%YAML:1.0\n---\n"));
        let back = parse_rig(Path::new("x.yaml"), &text).unwrap();
        assert_eq!(back, r);
    }

    #[test]
    fn reads_opencv_style_text() {
        // As OpenCV writes it: unquoted strings, `1.`, exponents, data over several lines.
        let text = "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\nmodel0: fisheye\n\
            K0: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 3.2e+02, 0., 3.2e+02, 0.,\n       3.2e+02, 2.4e+02, 0., 0., 1. ]\n\
            D0: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n   data: [ 0., 0., 0., 0. ]\n\
            model1: pinhole  # comment\nK1: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 3.2e+02, 0., 3.2e+02, 0., 3.2e+02, 2.4e+02, 0., 0., 1. ]\n\
            D1: !!opencv-matrix\n   rows: 5\n   cols: 1\n   dt: d\n   data: [ 0., 0., 0., 0., 0. ]\n\
            R: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\n\
            T: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ 0., -70., 0. ]\n\
            rms: 2.0000000000000001e-01\n";
        let r = parse_rig(Path::new("cv.yaml"), text).unwrap();
        assert_eq!(r.cam0.fx(), 320.0);
        assert_eq!(r.cam1.distortion.model_name(), "pinhole");
        assert_eq!(
            r.cam1_from_cam0.translation.vector,
            vector![0.0, -70.0, 0.0]
        );
        assert_eq!(r.rms_px, 0.2);
        assert!((r.baseline_mm() - 70.0).abs() < 1e-12);
    }

    fn err_of(text: &str) -> String {
        parse_rig(Path::new("bad.yaml"), text)
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn bad_files_name_the_key() {
        let good = format_rig(&rig());
        let e = err_of(&good.replace("image_width", "imagewidth"));
        assert!(e.contains("missing key `image_width`"), "{e}");
        let e = err_of(&good.replace("rows: 3\n   cols: 1", "rows: 2\n   cols: 1"));
        assert!(e.contains("key `T`"), "{e}");
        // A 4-coefficient D for a pinhole camera.
        let e = err_of(&good.replace("model1: \"pinhole\"", "model1: \"fisheye\""));
        assert!(e.contains("key `D1`") && e.contains("4×1"), "{e}");
        let e = err_of(&good.replace("model0: \"fisheye\"", "model0: \"kb4\""));
        assert!(e.contains("key `model0`"), "{e}");
        let e = err_of(&good.replace("rms: 0.1234", "rms: abc"));
        assert!(e.contains("key `rms`"), "{e}");
        let e = err_of(&good.replacen("%YAML:1.0", "calib:", 1));
        assert!(e.contains("bad.yaml:1"), "{e}");
        let mut not_rotation = rig();
        not_rotation.cam1_from_cam0.rotation =
            Rotation3::from_matrix_unchecked(Matrix3::identity() * 2.0);
        let e = err_of(&format_rig(&not_rotation));
        assert!(e.contains("key `R`") && e.contains("not a rotation"), "{e}");
    }

    #[test]
    fn write_then_read_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rig.yaml");
        write_rig(&path, &rig()).unwrap();
        assert_eq!(read_rig(&path).unwrap(), rig());
        let e = read_rig(&dir.path().join("none.yaml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("none.yaml"), "{e}");
    }

    /// OpenCV's own FileStorage reads the file helmcap writes, with identical values.
    #[test]
    fn opencv_filestorage_reads_written_file() {
        use opencv::core::{FileStorage, FileStorage_Mode, Mat, MatTraitConst};
        use opencv::prelude::*;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("rig.yaml");
        let r = rig();
        write_rig(&path, &r).unwrap();
        let fs =
            FileStorage::new(path.to_str().unwrap(), FileStorage_Mode::READ as i32, "").unwrap();
        assert!(fs.is_opened().unwrap());
        let mat = |key: &str| -> Vec<f64> {
            let m: Mat = fs.get(key).unwrap().mat().unwrap();
            assert_eq!(m.typ(), opencv::core::CV_64F, "{key}");
            let mut out = Vec::new();
            for i in 0..m.rows() {
                for j in 0..m.cols() {
                    out.push(*m.at_2d::<f64>(i, j).unwrap());
                }
            }
            out
        };
        assert_eq!(fs.get("image_width").unwrap().to_i32().unwrap(), 1280);
        assert_eq!(fs.get("image_height").unwrap().to_i32().unwrap(), 1024);
        assert_eq!(fs.get("model0").unwrap().to_string().unwrap(), "fisheye");
        assert_eq!(fs.get("model1").unwrap().to_string().unwrap(), "pinhole");
        let k0: Vec<f64> = r.cam0.k.transpose().iter().copied().collect();
        assert_eq!(mat("K0"), k0);
        let k1: Vec<f64> = r.cam1.k.transpose().iter().copied().collect();
        assert_eq!(mat("K1"), k1);
        assert_eq!(mat("D0"), r.cam0.distortion.coefficients());
        assert_eq!(mat("D1"), r.cam1.distortion.coefficients());
        let rot: Vec<f64> = r
            .cam1_from_cam0
            .rotation
            .matrix()
            .transpose()
            .iter()
            .copied()
            .collect();
        assert_eq!(mat("R"), rot);
        let t = r.cam1_from_cam0.translation.vector;
        assert_eq!(mat("T"), vec![t.x, t.y, t.z]);
        assert_eq!(fs.get("rms").unwrap().to_f64().unwrap(), r.rms_px);
    }
}
