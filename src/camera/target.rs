//! Planar calibration targets: their spec strings and the positions of their points in the
//! board frame.
//!
//! Board frame (both targets): x to the right and y down as the printed board is read, z
//! into the board (away from a camera that sees its printed side), millimetres, z = 0 on
//! the board.
//!
//! - `chessboard:COLSxROWS:SQUARE_MM`: `COLS × ROWS` inner corners, squares of `SQUARE_MM`.
//!   Corner `(c, r)` (0-based) is at `((c + 1)·s, (r + 1)·s)` and has point id `r·COLS + c`.
//!   The square at the origin (diagonally beyond corner 0) is black.
//! - `aprilgrid:COLSxROWS:TAG_MM:SPACING_RATIO`: a Kalibr-style grid of `COLS × ROWS`
//!   tag36h11 tags, ids `row·COLS + col` from 0 at the top left, row by row. `TAG_MM` is the
//!   side of a tag's black square (8 of the family's 10 cells: a 6×6 data area inside a
//!   1-cell black border; the 1-cell white border lies outside it), the gap between two
//!   tags is `SPACING_RATIO · TAG_MM`. The top-left corner of tag `(col, row)` is at
//!   `(col·p, row·p)` with pitch `p = TAG_MM·(1 + SPACING_RATIO)`; its corners `k = 0..4`
//!   are bottom-left, bottom-right, top-right, top-left (the AprilTag library's order), with
//!   point id `4·id + k`.
//!
//! # Deviations
//! Kalibr prints its tags with a 2-cell black border and puts small black squares at the
//! crossings of the gaps; the AprilTag 3 detector finds neither (it needs the 1-cell border
//! and an unbroken white ring around each tag), so helmcap's aprilgrid uses standard
//! tag36h11 tags with no gap squares, in Kalibr's layout.

use std::fmt;
use std::str::FromStr;

use nalgebra::Point3;

/// A target spec string could not be parsed or describes an impossible target.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("target {spec:?}: {message}")]
pub struct TargetSpecError {
    /// The spec as given.
    pub spec: String,
    /// What is wrong, with the expected form.
    pub message: String,
}

/// A chessboard: `cols × rows` inner corners, squares of `square_mm`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Chessboard {
    /// Inner corners along the board's x axis.
    pub cols: u32,
    /// Inner corners along the board's y axis.
    pub rows: u32,
    /// Side of a square, mm.
    pub square_mm: f64,
}

impl Chessboard {
    /// Parses `chessboard:COLSxROWS:SQUARE_MM`, for example `chessboard:9x6:20`.
    ///
    /// # Errors
    /// [`TargetSpecError`] with the expected form.
    pub fn parse(spec: &str) -> Result<Self, TargetSpecError> {
        let bad = |m: &str| TargetSpecError {
            spec: spec.to_string(),
            message: format!(
                "{m}; expected chessboard:COLSxROWS:SQUARE_MM, e.g. chessboard:9x6:20"
            ),
        };
        let rest = spec
            .strip_prefix("chessboard:")
            .ok_or_else(|| bad("not a chessboard"))?;
        let parts: Vec<&str> = rest.split(':').collect();
        let [size, square] = parts.as_slice() else {
            return Err(bad("wrong number of fields"));
        };
        let (cols, rows) = parse_size(size).ok_or_else(|| bad("bad COLSxROWS"))?;
        let square_mm: f64 = square.parse().map_err(|_| bad("bad SQUARE_MM"))?;
        if cols < 2 || rows < 2 {
            return Err(bad("a chessboard needs at least 2×2 inner corners"));
        }
        if !(square_mm.is_finite() && square_mm > 0.0) {
            return Err(bad("the square size must be positive"));
        }
        Ok(Self {
            cols,
            rows,
            square_mm,
        })
    }

    /// Inner corners in the board frame (z = 0), row by row, mm, as OpenCV orders them
    /// (x fastest): index = point id.
    pub fn corners(&self) -> Vec<Point3<f64>> {
        let mut out = Vec::with_capacity((self.cols * self.rows) as usize);
        for r in 1..=self.rows {
            for c in 1..=self.cols {
                out.push(Point3::new(
                    f64::from(c) * self.square_mm,
                    f64::from(r) * self.square_mm,
                    0.0,
                ));
            }
        }
        out
    }

    /// Centre of the board, board frame, mm.
    pub fn centre(&self) -> Point3<f64> {
        Point3::new(
            f64::from(self.cols + 1) * self.square_mm / 2.0,
            f64::from(self.rows + 1) * self.square_mm / 2.0,
            0.0,
        )
    }

    /// True when a half turn maps the board onto itself (`cols + rows` even: both far
    /// corner squares black), so that the corner order of a view is ambiguous.
    pub fn is_half_turn_symmetric(&self) -> bool {
        (self.cols + self.rows).is_multiple_of(2)
    }
}

/// A Kalibr-style grid of tag36h11 AprilTags (see the module docs for the layout).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aprilgrid {
    /// Tags along the board's x axis.
    pub cols: u32,
    /// Tags along the board's y axis.
    pub rows: u32,
    /// Side of a tag's black square, mm.
    pub tag_mm: f64,
    /// Gap between neighbouring tags as a fraction of `tag_mm`.
    pub spacing_ratio: f64,
}

/// Cells across a tag36h11 tag's black square (6 data cells and a 1-cell black border).
pub const TAG36H11_BLACK_CELLS: u32 = 8;

impl Aprilgrid {
    /// Parses `aprilgrid:COLSxROWS:TAG_MM:SPACING_RATIO`, for example
    /// `aprilgrid:6x6:30:0.3`.
    ///
    /// # Errors
    /// [`TargetSpecError`] with the expected form.
    pub fn parse(spec: &str) -> Result<Self, TargetSpecError> {
        let bad = |m: &str| TargetSpecError {
            spec: spec.to_string(),
            message: format!(
                "{m}; expected aprilgrid:COLSxROWS:TAG_MM:SPACING_RATIO, e.g. aprilgrid:6x6:30:0.3"
            ),
        };
        let rest = spec
            .strip_prefix("aprilgrid:")
            .ok_or_else(|| bad("not an aprilgrid"))?;
        let parts: Vec<&str> = rest.split(':').collect();
        let [size, tag, ratio] = parts.as_slice() else {
            return Err(bad("wrong number of fields"));
        };
        let (cols, rows) = parse_size(size).ok_or_else(|| bad("bad COLSxROWS"))?;
        let tag_mm: f64 = tag.parse().map_err(|_| bad("bad TAG_MM"))?;
        let spacing_ratio: f64 = ratio.parse().map_err(|_| bad("bad SPACING_RATIO"))?;
        if cols == 0 || rows == 0 {
            return Err(bad("the grid needs at least one tag"));
        }
        let tags = u64::from(cols) * u64::from(rows);
        if tags > super::tag36h11::TAG36H11_CODES.len() as u64 {
            return Err(bad(&format!(
                "{tags} tags, but tag36h11 has only {}",
                super::tag36h11::TAG36H11_CODES.len()
            )));
        }
        if !(tag_mm.is_finite() && tag_mm > 0.0) {
            return Err(bad("the tag size must be positive"));
        }
        // Each tag needs its 1-cell white border: the gap is at least one cell.
        let min_ratio = 1.0 / f64::from(TAG36H11_BLACK_CELLS);
        if !(spacing_ratio.is_finite() && spacing_ratio >= min_ratio && spacing_ratio <= 4.0) {
            return Err(bad(&format!(
                "the spacing ratio must lie in [{min_ratio}, 4] (a tag needs a white border of one cell)"
            )));
        }
        Ok(Self {
            cols,
            rows,
            tag_mm,
            spacing_ratio,
        })
    }

    /// Number of tags.
    pub fn tag_count(&self) -> usize {
        (self.cols * self.rows) as usize
    }

    /// Distance between the top-left corners of neighbouring tags, mm.
    pub fn pitch_mm(&self) -> f64 {
        self.tag_mm * (1.0 + self.spacing_ratio)
    }

    /// Side of one code cell, mm.
    pub fn cell_mm(&self) -> f64 {
        self.tag_mm / f64::from(TAG36H11_BLACK_CELLS)
    }

    /// The tag corners in the board frame (z = 0), mm: index = point id `4·id + k`.
    pub fn corners(&self) -> Vec<Point3<f64>> {
        let (p, s) = (self.pitch_mm(), self.tag_mm);
        let mut out = Vec::with_capacity(4 * self.tag_count());
        for row in 0..self.rows {
            for col in 0..self.cols {
                let (x0, y0) = (f64::from(col) * p, f64::from(row) * p);
                out.push(Point3::new(x0, y0 + s, 0.0));
                out.push(Point3::new(x0 + s, y0 + s, 0.0));
                out.push(Point3::new(x0 + s, y0, 0.0));
                out.push(Point3::new(x0, y0, 0.0));
            }
        }
        out
    }

    /// Centre of the grid, board frame, mm.
    pub fn centre(&self) -> Point3<f64> {
        let p = self.pitch_mm();
        Point3::new(
            (f64::from(self.cols - 1) * p + self.tag_mm) / 2.0,
            (f64::from(self.rows - 1) * p + self.tag_mm) / 2.0,
            0.0,
        )
    }

    /// Whether the board point `(x, y)` (mm) is black: inside a tag's black border or on a
    /// black data cell. Everything else, gaps and margins included, is white.
    pub fn is_black(&self, x_mm: f64, y_mm: f64) -> bool {
        let p = self.pitch_mm();
        let (col, row) = ((x_mm / p).floor(), (y_mm / p).floor());
        if col < 0.0 || row < 0.0 || col >= f64::from(self.cols) || row >= f64::from(self.rows) {
            return false;
        }
        let (lx, ly) = (x_mm - col * p, y_mm - row * p);
        if lx >= self.tag_mm || ly >= self.tag_mm {
            return false;
        }
        let cell = self.cell_mm();
        let n = TAG36H11_BLACK_CELLS - 1;
        let cx = ((lx / cell).floor() as u32).min(n);
        let cy = ((ly / cell).floor() as u32).min(n);
        if cx == 0 || cy == 0 || cx == n || cy == n {
            return true;
        }
        let id = row as usize * self.cols as usize + col as usize;
        !super::tag36h11::cell_is_white(id, cx as u8, cy as u8)
    }
}

/// A calibration target: what `--target` names.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CalibrationTarget {
    /// A chessboard (inner corners found by OpenCV).
    Chessboard(Chessboard),
    /// A grid of AprilTags (found by the AprilTag library).
    Aprilgrid(Aprilgrid),
}

impl CalibrationTarget {
    /// Parses `chessboard:COLSxROWS:SQUARE_MM` or `aprilgrid:COLSxROWS:TAG_MM:SPACING_RATIO`.
    ///
    /// # Errors
    /// [`TargetSpecError`] with the expected forms.
    pub fn parse(spec: &str) -> Result<Self, TargetSpecError> {
        if spec.starts_with("chessboard:") {
            Chessboard::parse(spec).map(Self::Chessboard)
        } else if spec.starts_with("aprilgrid:") {
            Aprilgrid::parse(spec).map(Self::Aprilgrid)
        } else {
            Err(TargetSpecError {
                spec: spec.to_string(),
                message: "unknown target; expected chessboard:COLSxROWS:SQUARE_MM or \
                          aprilgrid:COLSxROWS:TAG_MM:SPACING_RATIO"
                    .into(),
            })
        }
    }

    /// Every point of the target in the board frame (mm), indexed by point id.
    pub fn points(&self) -> Vec<Point3<f64>> {
        match self {
            Self::Chessboard(b) => b.corners(),
            Self::Aprilgrid(g) => g.corners(),
        }
    }

    /// Centre of the target, board frame, mm.
    pub fn centre(&self) -> Point3<f64> {
        match self {
            Self::Chessboard(b) => b.centre(),
            Self::Aprilgrid(g) => g.centre(),
        }
    }
}

impl FromStr for CalibrationTarget {
    type Err = TargetSpecError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::parse(s)
    }
}

impl fmt::Display for CalibrationTarget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Chessboard(b) => write!(f, "chessboard:{}x{}:{}", b.cols, b.rows, b.square_mm),
            Self::Aprilgrid(g) => write!(
                f,
                "aprilgrid:{}x{}:{}:{}",
                g.cols, g.rows, g.tag_mm, g.spacing_ratio
            ),
        }
    }
}

/// `COLSxROWS` as two positive numbers.
fn parse_size(s: &str) -> Option<(u32, u32)> {
    let (c, r) = s.split_once('x')?;
    Some((c.parse().ok()?, r.parse().ok()?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_both_specs_and_rejects_bad_ones() {
        let b = Chessboard::parse("chessboard:9x6:20").unwrap();
        assert_eq!((b.cols, b.rows, b.square_mm), (9, 6, 20.0));
        assert_eq!(b.corners().len(), 54);
        assert!(!b.is_half_turn_symmetric());
        let g = Aprilgrid::parse("aprilgrid:6x5:30:0.3").unwrap();
        assert_eq!(
            (g.cols, g.rows, g.tag_mm, g.spacing_ratio),
            (6, 5, 30.0, 0.3)
        );
        assert_eq!(g.corners().len(), 120);
        let t: CalibrationTarget = "aprilgrid:6x6:30:0.3".parse().unwrap();
        assert_eq!(t.to_string(), "aprilgrid:6x6:30:0.3");
        for bad in [
            "chessboard:9x6",
            "chessboard:1x6:20",
            "chessboard:9x6:-2",
            "aprilgrid:6x6:30",
            "aprilgrid:6x6:30:0.05",
            "aprilgrid:30x30:30:0.3",
            "aprilgrid:0x6:30:0.3",
            "circles:4x4:10",
        ] {
            assert!(CalibrationTarget::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn aprilgrid_corners_bound_the_black_squares() {
        let g = Aprilgrid::parse("aprilgrid:3x2:40:0.25").unwrap();
        let pts = g.corners();
        let eps = 0.01;
        for (i, p) in pts.iter().enumerate() {
            // Just inside the tag (toward its centre) is black, just outside is white.
            let tag = i / 4;
            let c = pts[4 * tag..4 * tag + 4]
                .iter()
                .fold(nalgebra::Vector3::zeros(), |a, q| a + q.coords)
                / 4.0;
            let d = (c - p.coords).normalize();
            assert!(g.is_black(p.x + d.x * eps, p.y + d.y * eps), "{i}");
            assert!(!g.is_black(p.x - d.x * eps, p.y - d.y * eps), "{i}");
        }
        // Corner order: bottom-left, bottom-right, top-right, top-left (y down).
        assert_eq!(pts[0], Point3::new(0.0, 40.0, 0.0));
        assert_eq!(pts[1], Point3::new(40.0, 40.0, 0.0));
        assert_eq!(pts[3], Point3::new(0.0, 0.0, 0.0));
        // Tag 1 sits one pitch to the right.
        assert_eq!(pts[7], Point3::new(50.0, 0.0, 0.0));
        assert!((g.centre().x - 70.0).abs() < 1e-12);
    }
}
