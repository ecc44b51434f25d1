//! Step 1, per image: the calibration target's points found by OpenCV's chessboard
//! detector or the AprilTag library, AprilTag corners refined on the tag edges, and the
//! checks that drop an unusable view.

use nalgebra::{Matrix2, Point2, Vector2};
use opencv::core::{Mat, Point2f, Size, TermCriteria, TermCriteria_Type, Vector};

use super::super::target::{Aprilgrid, CalibrationTarget, Chessboard};
use super::{CalibrateError, CalibrateParams, DropReason};
use crate::gray_image::GrayImage;

/// Target points found in one image: point ids (see [`crate::camera::target`]) and pixels
/// (OpenCV convention: pixel centres at integer coordinates).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TargetObservation {
    /// Point id of each detection.
    pub ids: Vec<usize>,
    /// Pixel of each detection.
    pub pixels: Vec<Point2<f64>>,
}

/// Finds the target in one image. An `Err(DropReason)` says why the image cannot be used.
///
/// # Errors
/// [`CalibrateError::OpenCv`] or [`CalibrateError::Failed`] when a detector fails to run
/// (not when it finds nothing).
pub fn detect_target(
    image: &GrayImage,
    target: &CalibrationTarget,
    params: &CalibrateParams,
) -> Result<Result<TargetObservation, DropReason>, CalibrateError> {
    let found = match target {
        CalibrationTarget::Chessboard(b) => detect_chessboard(image, b, params)?,
        CalibrationTarget::Aprilgrid(g) => detect_aprilgrid(image, g, params)?,
    };
    Ok(found.and_then(|obs| check_view(&obs, image, target, params).map(|()| obs)))
}

/// Rejects views with too few points, nearly collinear board points, or a footprint too
/// small in the image.
fn check_view(
    obs: &TargetObservation,
    image: &GrayImage,
    target: &CalibrationTarget,
    params: &CalibrateParams,
) -> Result<(), DropReason> {
    let n = obs.ids.len();
    if n < params.min_points_per_view {
        return Err(DropReason::TooFewPoints {
            found: n,
            needed: params.min_points_per_view,
        });
    }
    let points = target.points();
    // Spread of the board points: the smaller principal axis against the larger.
    let board: Vec<Vector2<f64>> = obs
        .ids
        .iter()
        .filter_map(|&id| points.get(id).map(|p| Vector2::new(p.x, p.y)))
        .collect();
    let mean = board.iter().sum::<Vector2<f64>>() / board.len().max(1) as f64;
    let cov = board.iter().fold(Matrix2::zeros(), |a, p| {
        a + (p - mean) * (p - mean).transpose()
    });
    let eig = cov.symmetric_eigenvalues();
    let (lo, hi) = (eig.min(), eig.max());
    if hi.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) || lo / hi < 1e-2 {
        return Err(DropReason::Degenerate(
            "target points nearly collinear".into(),
        ));
    }
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for p in &obs.pixels {
        x0 = x0.min(p.x);
        y0 = y0.min(p.y);
        x1 = x1.max(p.x);
        y1 = y1.max(p.y);
    }
    let coverage = (x1 - x0) * (y1 - y0) / (f64::from(image.width) * f64::from(image.height));
    if coverage < params.min_image_coverage {
        return Err(DropReason::Degenerate(format!(
            "target covers {:.2} % of the image (need {:.2} %)",
            100.0 * coverage,
            100.0 * params.min_image_coverage
        )));
    }
    Ok(())
}

/// Chessboard corners by OpenCV, refined to subpixel and put in canonical order.
fn detect_chessboard(
    image: &GrayImage,
    board: &Chessboard,
    params: &CalibrateParams,
) -> Result<Result<TargetObservation, DropReason>, CalibrateError> {
    let cv = |e: opencv::Error| CalibrateError::OpenCv {
        stage: "chessboard detection".into(),
        message: e.message,
    };
    let mat = Mat::new_rows_cols_with_data(image.height as i32, image.width as i32, &image.data)
        .map_err(cv)?;
    let pattern = Size::new(board.cols as i32, board.rows as i32);
    let mut corners = Vector::<Point2f>::new();
    let found = opencv::calib3d::find_chessboard_corners(
        &mat,
        pattern,
        &mut corners,
        opencv::calib3d::CALIB_CB_ADAPTIVE_THRESH
            | opencv::calib3d::CALIB_CB_NORMALIZE_IMAGE
            | opencv::calib3d::CALIB_CB_FAST_CHECK,
    )
    .map_err(cv)?;
    let n = (board.cols * board.rows) as usize;
    if !found || corners.len() != n {
        return Ok(Err(DropReason::TargetNotFound));
    }
    let criteria = TermCriteria::new(
        TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
        100,
        1e-4,
    )
    .map_err(cv)?;
    let half = params.subpix_half_window_px;
    opencv::imgproc::corner_sub_pix(
        &mat,
        &mut corners,
        Size::new(half, half),
        Size::new(-1, -1),
        criteria,
    )
    .map_err(cv)?;
    let pixels: Vec<Point2<f64>> = corners
        .iter()
        .map(|p| Point2::new(f64::from(p.x), f64::from(p.y)))
        .collect();
    Ok(
        canonical_chessboard_order(image, board, pixels).map(|pixels| TargetObservation {
            ids: (0..n).collect(),
            pixels,
        }),
    )
}

/// Puts OpenCV's corner list (row by row) in the board's order: board x and y axes
/// right-handed in the image (as seen from the printed side; mirrored otherwise), and
/// the black square at the board origin before corner 0 (rotated by a half turn
/// otherwise).
fn canonical_chessboard_order(
    image: &GrayImage,
    board: &Chessboard,
    mut px: Vec<Point2<f64>>,
) -> Result<Vec<Point2<f64>>, DropReason> {
    let (cols, rows) = (board.cols as usize, board.rows as usize);
    let at = |px: &[Point2<f64>], c: usize, r: usize| px[r * cols + c];
    let ex = at(&px, cols - 1, 0) - at(&px, 0, 0);
    let ey = at(&px, 0, rows - 1) - at(&px, 0, 0);
    if ex.x * ey.y - ex.y * ey.x < 0.0 {
        for row in px.chunks_mut(cols) {
            row.reverse();
        }
    }
    let origin_square = at(&px, 0, 0) + (at(&px, 0, 0) - at(&px, 1, 1)) * 0.5;
    let far_square = at(&px, cols - 1, rows - 1)
        + (at(&px, cols - 1, rows - 1) - at(&px, cols - 2, rows - 2)) * 0.5;
    let (Some(a), Some(b)) = (
        mean_around(image, origin_square),
        mean_around(image, far_square),
    ) else {
        return Err(DropReason::Degenerate(
            "the board's corner squares are outside the image".into(),
        ));
    };
    if a > b {
        px.reverse();
    }
    Ok(px)
}

/// Mean intensity in a 5×5 window around a pixel, `None` when it leaves the image.
fn mean_around(image: &GrayImage, p: Point2<f64>) -> Option<f64> {
    let (x, y) = (p.x.round() as i64, p.y.round() as i64);
    let (w, h) = (i64::from(image.width), i64::from(image.height));
    if x < 2 || y < 2 || x + 2 >= w || y + 2 >= h {
        return None;
    }
    let mut sum = 0.0;
    for yy in y - 2..=y + 2 {
        for xx in x - 2..=x + 2 {
            sum += f64::from(*image.data.get((yy * w + xx) as usize)?);
        }
    }
    Some(sum / 25.0)
}

/// AprilTag grid corners: tag36h11 detections with ids on the grid, each corner refined.
fn detect_aprilgrid(
    image: &GrayImage,
    grid: &Aprilgrid,
    params: &CalibrateParams,
) -> Result<Result<TargetObservation, DropReason>, CalibrateError> {
    let fail = |e: apriltag::Error| CalibrateError::Failed {
        stage: "AprilTag detection".into(),
        message: e.to_string(),
    };
    let (w, h) = (image.width as usize, image.height as usize);
    let mut at_image = apriltag::Image::zeros_with_stride(w, h, w).map_err(fail)?;
    let stride = at_image.stride();
    for (dst, src) in at_image
        .as_slice_mut()
        .chunks_mut(stride)
        .zip(image.data.chunks(w))
    {
        dst[..w].copy_from_slice(src);
    }
    let mut detector = apriltag::Detector::builder()
        .add_family_bits(apriltag::Family::tag_36h11(), params.max_tag_hamming)
        .build()
        .map_err(fail)?;
    detector.set_decimation(1.0);
    detector.set_refine_edges(true);
    let detections = detector.detect(&at_image);
    let mut tags: Vec<(usize, [Point2<f64>; 4])> = Vec::new();
    let mut duplicated = Vec::new();
    for d in &detections {
        let id = d.id();
        if id >= grid.tag_count() || d.hamming() > params.max_tag_hamming {
            continue;
        }
        if tags.iter().any(|(t, _)| *t == id) {
            duplicated.push(id);
            continue;
        }
        // The library puts pixel centres at +0.5; OpenCV and helmcap at integers.
        let c = d.corners();
        tags.push((id, c.map(|[x, y]| Point2::new(x - 0.5, y - 0.5))));
    }
    tags.retain(|(id, _)| !duplicated.contains(id));
    if tags.is_empty() {
        return Ok(Err(DropReason::TargetNotFound));
    }
    tags.sort_by_key(|t| t.0);
    let mut obs = TargetObservation::default();
    for (id, corners) in &tags {
        let refined = if params.refine_tag_corners {
            refine_tag_corners(image, corners)
        } else {
            *corners
        };
        for (k, p) in refined.iter().enumerate() {
            obs.ids.push(4 * id + k);
            obs.pixels.push(*p);
        }
    }
    Ok(Ok(obs))
}

/// Refines the four corners of a detected tag. The library intersects straight lines
/// fitted along whole tag edges, which lens distortion bends; here each corner is the
/// intersection of two lines fitted to the edge points found on the two edges that meet at
/// it, sampled only over the third of each edge nearest to the corner. An edge point is the
/// gradient-weighted centroid of the intensity profile across the edge. A corner whose
/// fit fails (too few edge samples) keeps the library's position.
pub fn refine_tag_corners(image: &GrayImage, corners: &[Point2<f64>; 4]) -> [Point2<f64>; 4] {
    let mut out = *corners;
    for k in 0..4 {
        let p = corners[k];
        let next = corners[(k + 1) % 4];
        let prev = corners[(k + 3) % 4];
        let (Some(la), Some(lb)) = (fit_edge_near(image, p, next), fit_edge_near(image, p, prev))
        else {
            continue;
        };
        if let Some(x) = intersect(&la, &lb)
            && (x - p).norm() < 3.0
        {
            out[k] = x;
        }
    }
    out
}

/// A line `n·x = c` with unit normal `n`.
struct Line {
    n: Vector2<f64>,
    c: f64,
}

/// Fits a line to the edge from corner `a` toward corner `b`, using edge points found
/// between 8 % and 35 % of the way (away from the corner's blur, near enough to be nearly
/// straight).
fn fit_edge_near(image: &GrayImage, a: Point2<f64>, b: Point2<f64>) -> Option<Line> {
    let d = b - a;
    let len = d.norm();
    if len < 12.0 {
        return None;
    }
    let t = d / len;
    let normal = Vector2::new(-t.y, t.x);
    let samples = ((0.27 * len) as usize).clamp(4, 40);
    // Stay within the tag's black border and its white ring (one cell, len / 8, each).
    let half_width = (0.4 * len / 8.0).clamp(1.0, 3.0);
    let steps = (4.0 * half_width).round() as i32;
    let mut pts: Vec<Point2<f64>> = Vec::with_capacity(samples);
    for s in 0..samples {
        let f = 0.08 + 0.27 * (s as f64 + 0.5) / samples as f64;
        let centre = a + d * f;
        // Gradient magnitude across the edge in quarter-pixel steps; its centroid is the
        // edge.
        let mut prev: Option<f64> = None;
        let (mut wsum, mut osum) = (0.0, 0.0);
        for j in -steps..=steps {
            let o = f64::from(j) * 0.25;
            let p = centre + normal * o;
            let v = image.bilinear(p.x, p.y)?;
            if let Some(pv) = prev {
                let g = (v - pv).abs();
                wsum += g;
                osum += g * (o - 0.125);
            }
            prev = Some(v);
        }
        if wsum > 20.0 {
            pts.push(centre + normal * (osum / wsum));
        }
    }
    if pts.len() < 4 {
        return None;
    }
    // Total least squares line through the points.
    let mean = pts.iter().map(|p| p.coords).sum::<Vector2<f64>>() / pts.len() as f64;
    let cov = pts.iter().fold(Matrix2::zeros(), |acc, p| {
        let q = p.coords - mean;
        acc + q * q.transpose()
    });
    let eig = cov.symmetric_eigen();
    let i = if eig.eigenvalues[0] < eig.eigenvalues[1] {
        0
    } else {
        1
    };
    let n: Vector2<f64> = eig.eigenvectors.column(i).into_owned();
    Some(Line { n, c: n.dot(&mean) })
}

/// Intersection of two lines, `None` when nearly parallel.
fn intersect(a: &Line, b: &Line) -> Option<Point2<f64>> {
    let m = Matrix2::new(a.n.x, a.n.y, b.n.x, b.n.y);
    if m.determinant().abs() < 0.1 {
        return None;
    }
    m.try_inverse()
        .map(|inv| Point2::from(inv * Vector2::new(a.c, b.c)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_with_collinear_or_tiny_targets_are_degenerate() {
        let target = CalibrationTarget::parse("aprilgrid:6x6:30:0.3").unwrap();
        let image = GrayImage {
            width: 1000,
            height: 1000,
            data: vec![0; 1_000_000],
        };
        let params = CalibrateParams::default();
        // One row of tags: 24 collinear-ish corners (two rows of points, 30 mm apart over
        // 225 mm: spread ratio ≈ 0.02²) — use only the tags' top corners: collinear.
        let ids: Vec<usize> = (0..6).flat_map(|t| [4 * t + 2, 4 * t + 3]).collect();
        let ids: Vec<usize> = ids.iter().chain(ids.iter()).copied().take(16).collect();
        let pixels = (0..ids.len())
            .map(|i| Point2::new(100.0 + 40.0 * i as f64, 300.0 + 20.0 * i as f64))
            .collect();
        let obs = TargetObservation { ids, pixels };
        assert!(matches!(
            check_view(&obs, &image, &target, &params),
            Err(DropReason::Degenerate(_))
        ));
        // Four whole tags but only 20 px across in the image.
        let ids: Vec<usize> = (0..16).collect();
        let pixels = (0..16)
            .map(|i| {
                Point2::new(
                    500.0 + f64::from(i % 4) * 5.0,
                    500.0 + f64::from(i / 4) * 5.0,
                )
            })
            .collect();
        let obs = TargetObservation { ids, pixels };
        let r = check_view(&obs, &image, &target, &params);
        assert!(matches!(r, Err(DropReason::Degenerate(ref m)) if m.contains("% of the image")));
        // Too few points.
        let obs = TargetObservation {
            ids: vec![0, 1, 2, 3],
            pixels: vec![Point2::origin(); 4],
        };
        assert_eq!(
            check_view(&obs, &image, &target, &params),
            Err(DropReason::TooFewPoints {
                found: 4,
                needed: 16
            })
        );
    }
}
