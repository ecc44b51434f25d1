//! Images of a planar calibration target (chessboard or AprilTag grid, see
//! [`crate::camera::target`]) seen by a stereo rig, with the board poses as ground truth, so
//! calibration can be checked against known parameters.
//!
//! Each pixel's ray is intersected with the board plane (exact lens model), and the
//! pattern is box-filtered over the pixel's footprint on the board (the bounding box, in
//! board axes, of the board points seen by the pixel and its neighbours), which gives
//! sharp, alias-free edges at unbiased subpixel positions. Chessboard: the filtered square
//! wave `q(u) = q_k · min(1, 2·e/w_u)` per axis (`e` the distance to the nearest square
//! edge, `w_u` the footprint in squares). AprilTag grid: the exact area integral of the
//! black/white cell pattern over the footprint box, cut at every cell edge inside it.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{IsometryMatrix3, Rotation3, Translation3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use super::{SynthError, quaternion_wxyz, raster, to_gray8, write_png_gray};
use crate::camera::{Camera, StereoRig};

pub use crate::camera::target::{Aprilgrid, CalibrationTarget, Chessboard};

/// Level of black target print, 8-bit scale.
const BLACK_DN: f32 = 35.0;
/// Level of white target print, 8-bit scale.
const WHITE_DN: f32 = 225.0;
/// Level of the background around the board, 8-bit scale.
const BACKGROUND_DN: f32 = 60.0;

/// Parameters of rendered target views.
#[derive(Debug, Clone, PartialEq)]
pub struct TargetParams {
    /// Number of views (image pairs). Default 15.
    pub views: usize,
    /// Board distance range from the rig, mm. Default 180 to 320.
    pub distance_mm: (f64, f64),
    /// Largest tilt of the board, degrees. Default 40.
    pub max_tilt_deg: f64,
    /// Sensor noise, 8-bit levels. Default 1.5.
    pub noise_dn: f64,
    /// Lens blur sigma, pixels. Default 0.6.
    pub blur_px: f64,
    /// Seed of poses and noise. Default 3.
    pub seed: u64,
}

impl Default for TargetParams {
    fn default() -> Self {
        Self {
            views: 15,
            distance_mm: (180.0, 320.0),
            max_tilt_deg: 40.0,
            noise_dn: 1.5,
            blur_px: 0.6,
            seed: 3,
        }
    }
}

/// Board coordinates (mm, board frame) of each pixel centre's ray, NaN where the ray
/// misses the board plane.
fn board_coordinates(camera: &Camera, cam_from_board: &IsometryMatrix3<f64>) -> Vec<[f64; 2]> {
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    let board_from_cam = cam_from_board.inverse();
    let origin = board_from_cam.translation.vector;
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let px = nalgebra::Point2::new((i % w) as f64, (i / w) as f64);
            let Ok(ray) = camera.unproject(&px) else {
                return [f64::NAN; 2];
            };
            let d = board_from_cam.rotation * ray.into_inner();
            if d.z.abs() < 1e-9 {
                return [f64::NAN; 2];
            }
            let s = -origin.z / d.z;
            if s <= 0.0 {
                return [f64::NAN; 2];
            }
            let p = origin + d * s;
            [p.x, p.y]
        })
        .collect()
}

/// Footprint of pixel `i` on the board: widths along the board's x and y axes (same unit
/// as `uv`), from the neighbouring pixels' board coordinates.
fn footprint(uv: &[[f64; 2]], i: usize, w: usize, h: usize, fallback: f64) -> (f64, f64) {
    let [u, v] = uv[i];
    let (x, y) = (i % w, i / w);
    let neighbour = |j: usize| uv.get(j).copied().filter(|q| q[0].is_finite());
    let dx = neighbour(if x + 1 < w {
        i + 1
    } else {
        i.saturating_sub(1)
    });
    let dy = neighbour(if y + 1 < h {
        i + w
    } else {
        i.saturating_sub(w)
    });
    match (dx, dy) {
        (Some(a), Some(b)) => (
            (a[0] - u).abs() + (b[0] - u).abs(),
            (a[1] - v).abs() + (b[1] - v).abs(),
        ),
        _ => (fallback, fallback),
    }
}

/// Renders one view of a target: 8-bit radiance before blur and noise.
pub fn render_target(
    camera: &Camera,
    target: &CalibrationTarget,
    cam_from_board: &IsometryMatrix3<f64>,
) -> Vec<f32> {
    match target {
        CalibrationTarget::Chessboard(b) => render_board(camera, b, cam_from_board),
        CalibrationTarget::Aprilgrid(g) => render_aprilgrid(camera, g, cam_from_board),
    }
}

/// Renders one view of the chessboard: 8-bit radiance before blur and noise.
pub fn render_board(
    camera: &Camera,
    board: &Chessboard,
    cam_from_board: &IsometryMatrix3<f64>,
) -> Vec<f32> {
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    let uv: Vec<[f64; 2]> = board_coordinates(camera, cam_from_board)
        .into_iter()
        .map(|[x, y]| [x / board.square_mm, y / board.square_mm])
        .collect();
    let (nu, nv) = (f64::from(board.cols + 1), f64::from(board.rows + 1));
    let border = 0.6;
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let [u, v] = uv[i];
            if !u.is_finite() {
                return BACKGROUND_DN;
            }
            let (wu, wv) = footprint(&uv, i, w, h, 0.05);
            if u < -border || v < -border || u > nu + border || v > nv + border {
                return BACKGROUND_DN;
            }
            let q = |t: f64, width: f64| {
                let k = t.floor();
                let e = (t - k).min(k + 1.0 - t);
                let sign = if (k as i64).rem_euclid(2) == 0 {
                    1.0
                } else {
                    -1.0
                };
                sign * (2.0 * e / width.max(1e-6)).min(1.0)
            };
            let inside = u > 0.0 && v > 0.0 && u < nu && v < nv;
            // Squares: the corner square (0, 0) is black; the margin is white.
            let value = if inside { -q(u, wu) * q(v, wv) } else { 1.0 };
            let mid = f64::from(WHITE_DN + BLACK_DN) / 2.0;
            let half = f64::from(WHITE_DN - BLACK_DN) / 2.0;
            (mid + half * value) as f32
        })
        .collect()
}

/// Renders one view of the AprilTag grid: 8-bit radiance before blur and noise. The white
/// margin around the tags is as wide as the gap between tags, and at least two cells.
pub fn render_aprilgrid(
    camera: &Camera,
    grid: &Aprilgrid,
    cam_from_board: &IsometryMatrix3<f64>,
) -> Vec<f32> {
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    let uv = board_coordinates(camera, cam_from_board);
    let (p, s, cell) = (grid.pitch_mm(), grid.tag_mm, grid.cell_mm());
    let margin = (grid.spacing_ratio * s).max(2.0 * cell);
    let x_max = f64::from(grid.cols - 1) * p + s + margin;
    let y_max = f64::from(grid.rows - 1) * p + s + margin;
    let level = |x: f64, y: f64| {
        if x < -margin || y < -margin || x > x_max || y > y_max {
            BACKGROUND_DN
        } else if grid.is_black(x, y) {
            BLACK_DN
        } else {
            WHITE_DN
        }
    };
    // Every edge of the pattern along one axis inside (a, b), plus a and b.
    let cuts = |a: f64, b: f64, n: u32, edge_max: f64| {
        let mut out = vec![a];
        for e in [-margin, edge_max] {
            if e > a && e < b {
                out.push(e);
            }
        }
        let first = (a / p).floor().max(0.0) as u32;
        let last = ((b / p).floor().max(0.0) as u32).min(n - 1);
        for k in first..=last {
            for j in 0..=crate::camera::target::TAG36H11_BLACK_CELLS {
                let e = f64::from(k) * p + f64::from(j) * cell;
                if e > a && e < b {
                    out.push(e);
                }
            }
        }
        out.push(b);
        out.sort_by(f64::total_cmp);
        out
    };
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let [u, v] = uv[i];
            if !u.is_finite() {
                return BACKGROUND_DN;
            }
            let (wu, wv) = footprint(&uv, i, w, h, 0.05 * cell);
            let (wu, wv) = (wu.max(1e-9), wv.max(1e-9));
            let xs = cuts(u - wu / 2.0, u + wu / 2.0, grid.cols, x_max);
            let ys = cuts(v - wv / 2.0, v + wv / 2.0, grid.rows, y_max);
            let mut sum = 0.0;
            for xw in xs.windows(2) {
                for yw in ys.windows(2) {
                    let area = (xw[1] - xw[0]) * (yw[1] - yw[0]);
                    if area > 0.0 {
                        let l = level(0.5 * (xw[0] + xw[1]), 0.5 * (yw[0] + yw[1]));
                        sum += area * f64::from(l);
                    }
                }
            }
            (sum / (wu * wv)) as f32
        })
        .collect()
}

/// A random board pose in front of the rig with every target point inside both images (at
/// least 20 px from the border), or `None` after many tries.
fn random_pose(
    rng: &mut StdRng,
    rig: &StereoRig,
    target: &CalibrationTarget,
    params: &TargetParams,
) -> Option<IsometryMatrix3<f64>> {
    let axis1 = rig.cam1_from_cam0.rotation.inverse() * Vector3::z();
    let axis = (Vector3::z() + axis1).normalize();
    let mid = rig.cam1_centre_in_cam0().coords * 0.5;
    let corners = target.points();
    let board_centre = target.centre();
    for _ in 0..2000 {
        let dist = rng.random_range(params.distance_mm.0..=params.distance_mm.1);
        let lateral = Vector3::new(
            rng.random_range(-0.25..0.25),
            rng.random_range(-0.2..0.2),
            0.0,
        ) * dist;
        let centre = mid + axis * dist + lateral;
        let tilt = params.max_tilt_deg.to_radians();
        // Board faces the cameras (board z toward −axis), with a random tilt and roll.
        let look = Rotation3::face_towards(&axis, &-Vector3::y());
        let r = look
            * Rotation3::from_euler_angles(
                rng.random_range(-tilt..tilt),
                rng.random_range(-tilt..tilt),
                rng.random_range(-0.3..0.3),
            );
        let cam0_from_board =
            IsometryMatrix3::from_parts(Translation3::from(centre - r * board_centre.coords), r);
        let ok = [
            (&rig.cam0, IsometryMatrix3::identity()),
            (&rig.cam1, rig.cam1_from_cam0),
        ]
        .iter()
        .all(|(cam, from0)| {
            corners.iter().all(|c| {
                let p = from0 * cam0_from_board * c;
                cam.project(&p.coords).is_some_and(|px| {
                    px.x > 20.0
                        && px.y > 20.0
                        && px.x < f64::from(cam.width_px) - 21.0
                        && px.y < f64::from(cam.height_px) - 21.0
                })
            })
        });
        if ok {
            return Some(cam0_from_board);
        }
    }
    None
}

/// Renders `params.views` image pairs of `target` seen by `rig` into `out/cam0/NNNNNN.png`
/// and `out/cam1/NNNNNN.png`, with `out/calibration.yaml` (the true rig) and
/// `out/gt/board_poses.csv` (`view,qw,qx,qy,qz,tx,ty,tz`: board → cam0, mm).
///
/// # Errors
/// [`SynthError`] for a board that cannot be placed in view of both cameras, or a file
/// that cannot be written.
pub fn render_targets(
    rig: &StereoRig,
    target: &CalibrationTarget,
    params: &TargetParams,
    out: &Path,
) -> Result<(), SynthError> {
    let mut rng = StdRng::seed_from_u64(params.seed);
    let mut poses = Vec::new();
    for _ in 0..params.views {
        poses.push(random_pose(&mut rng, rig, target, params).ok_or_else(|| {
            SynthError::Params(
                "the target does not fit in both images: use a smaller target or a larger distance"
                    .into(),
            )
        })?);
    }
    for d in ["cam0", "cam1", "gt"] {
        std::fs::create_dir_all(out.join(d)).map_err(|e| SynthError::Write {
            path: out.join(d),
            message: e.to_string(),
        })?;
    }
    for (v, pose) in poses.iter().enumerate() {
        for (c, (cam, from0)) in [
            (&rig.cam0, IsometryMatrix3::identity()),
            (&rig.cam1, rig.cam1_from_cam0),
        ]
        .into_iter()
        .enumerate()
        {
            let mut img = render_target(cam, target, &(from0 * pose));
            raster::gaussian_blur(
                &mut img,
                cam.width_px as usize,
                cam.height_px as usize,
                params.blur_px,
            );
            let gray = to_gray8(
                &img,
                params.noise_dn,
                params.seed ^ ((v as u64) << 8 | c as u64),
            );
            write_png_gray(
                &out.join(format!("cam{c}/{v:06}.png")),
                cam.width_px,
                cam.height_px,
                &gray,
            )?;
        }
    }
    let mut csv = String::from("view,qw,qx,qy,qz,tx,ty,tz\n");
    for (v, p) in poses.iter().enumerate() {
        let q = quaternion_wxyz(&p.rotation);
        let t = p.translation.vector;
        let _ = writeln!(
            csv,
            "{v},{},{},{},{},{},{},{}",
            q[0], q[1], q[2], q[3], t.x, t.y, t.z
        );
    }
    let path = out.join("gt/board_poses.csv");
    std::fs::write(&path, csv).map_err(|e| SynthError::Write {
        path: path.clone(),
        message: e.to_string(),
    })?;
    crate::camera::write_rig(&out.join("calibration.yaml"), rig).map_err(|e| SynthError::Write {
        path: out.join("calibration.yaml"),
        message: e.to_string(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    /// A rendered, blurred and noisy view of `target` in cam0 of the default rig, and its
    /// board pose.
    fn noisy_view(
        target: &CalibrationTarget,
        seed: u64,
    ) -> (
        StereoRig,
        IsometryMatrix3<f64>,
        crate::gray_image::GrayImage,
    ) {
        let rig = super::super::default_rig().unwrap();
        let params = TargetParams::default();
        let mut rng = StdRng::seed_from_u64(seed);
        let pose = random_pose(&mut rng, &rig, target, &params).unwrap();
        let (w, h) = (rig.cam0.width_px as usize, rig.cam0.height_px as usize);
        let mut img = render_target(&rig.cam0, target, &pose);
        raster::gaussian_blur(&mut img, w, h, params.blur_px);
        let pixels = to_gray8(&img, params.noise_dn, seed);
        let image = crate::gray_image::GrayImage {
            width: w as u32,
            height: h as u32,
            data: pixels,
        };
        (rig, pose, image)
    }

    /// The AprilTag detector finds every rendered tag with its corners where the camera
    /// model projects them (ids, corner order and pixel convention agree), and the corner
    /// refinement brings them to subpixel accuracy.
    #[test]
    fn apriltag_finds_rendered_tag_corners_to_subpixel_accuracy() {
        use crate::camera::calibrate::{CalibrateParams, detect_target};
        let target = CalibrationTarget::parse("aprilgrid:6x6:30:0.3").unwrap();
        let points = target.points();
        let raw_params = CalibrateParams {
            refine_tag_corners: false,
            ..CalibrateParams::default()
        };
        let (mut sum, mut sum_raw) = (0.0, 0.0);
        let mut n = 0;
        for seed in [1, 2, 3] {
            let (rig, pose, image) = noisy_view(&target, seed);
            let obs = detect_target(&image, &target, &CalibrateParams::default())
                .unwrap()
                .unwrap();
            let raw = detect_target(&image, &target, &raw_params)
                .unwrap()
                .unwrap();
            assert_eq!(obs.ids.len(), points.len(), "all 36 tags found");
            assert_eq!(obs.ids, raw.ids);
            let mut worst = 0.0f64;
            for ((id, px), px_raw) in obs.ids.iter().zip(&obs.pixels).zip(&raw.pixels) {
                let truth = rig.cam0.project(&(pose * points[*id]).coords).unwrap();
                let e = (px - truth).norm();
                worst = worst.max(e);
                sum += e * e;
                sum_raw += (px_raw - truth).norm_squared();
                n += 1;
            }
            assert!(worst < 0.5, "worst corner error {worst} px");
        }
        let rms = (sum / n as f64).sqrt();
        let rms_raw = (sum_raw / n as f64).sqrt();
        eprintln!(
            "aprilgrid corner RMS over {n} corners: {rms:.4} px refined, {rms_raw:.4} px as detected"
        );
        assert!(rms < 0.15, "corner RMS {rms} px");
        assert!(rms < rms_raw, "refinement must help: {rms} vs {rms_raw} px");
    }

    #[test]
    fn parse_spec() {
        let b = Chessboard::parse("chessboard:9x6:20").unwrap();
        assert_eq!((b.cols, b.rows, b.square_mm), (9, 6, 20.0));
        assert!(Chessboard::parse("chessboard:9x6").is_err());
        assert!(Chessboard::parse("aprilgrid:6x6:30:0.3").is_err());
        assert_eq!(b.corners().len(), 54);
    }

    #[test]
    fn board_renders_black_and_white_squares_where_projected() {
        let rig = super::super::default_rig().unwrap();
        let board = Chessboard::parse("chessboard:5x4:20").unwrap();
        let mut rng = StdRng::seed_from_u64(1);
        let target = CalibrationTarget::Chessboard(board);
        let pose = random_pose(&mut rng, &rig, &target, &TargetParams::default()).unwrap();
        let img = render_board(&rig.cam0, &board, &pose);
        let w = rig.cam0.width_px as usize;
        // Centre of square (0, 0) is black, of square (1, 0) white.
        for (sq, expect) in [((0.5, 0.5), 35.0), ((1.5, 0.5), 225.0)] {
            let p = pose * Point3::new(sq.0 * 20.0, sq.1 * 20.0, 0.0);
            let px = rig.cam0.project(&p.coords).unwrap();
            let v = img[px.y.round() as usize * w + px.x.round() as usize];
            assert!((f64::from(v) - expect).abs() < 1.0, "{v} vs {expect}");
        }
    }

    /// OpenCV's chessboard detector finds the rendered corners where the camera model
    /// projects them: the target images are fit for calibration tests.
    #[test]
    fn opencv_finds_rendered_corners_to_subpixel_accuracy() {
        use opencv::core::{Mat, Point2f, Size, TermCriteria, TermCriteria_Type, Vector};
        let rig = super::super::default_rig().unwrap();
        let board = Chessboard::parse("chessboard:9x6:20").unwrap();
        let params = TargetParams::default();
        let mut rng = StdRng::seed_from_u64(2);
        let target = CalibrationTarget::Chessboard(board);
        let pose = random_pose(&mut rng, &rig, &target, &params).unwrap();
        let (w, h) = (rig.cam0.width_px as usize, rig.cam0.height_px as usize);
        let mut img = render_board(&rig.cam0, &board, &pose);
        raster::gaussian_blur(&mut img, w, h, params.blur_px);
        let gray = to_gray8(&img, params.noise_dn, 5);
        let mat = Mat::new_rows_cols_with_data(h as i32, w as i32, &gray).unwrap();
        let mut corners = Vector::<Point2f>::new();
        let found = opencv::calib3d::find_chessboard_corners(
            &mat,
            Size::new(9, 6),
            &mut corners,
            opencv::calib3d::CALIB_CB_ADAPTIVE_THRESH | opencv::calib3d::CALIB_CB_NORMALIZE_IMAGE,
        )
        .unwrap();
        assert!(found);
        let criteria = TermCriteria::new(
            TermCriteria_Type::COUNT as i32 + TermCriteria_Type::EPS as i32,
            50,
            1e-4,
        )
        .unwrap();
        opencv::imgproc::corner_sub_pix(
            &mat,
            &mut corners,
            Size::new(5, 5),
            Size::new(-1, -1),
            criteria,
        )
        .unwrap();
        let truth: Vec<nalgebra::Point2<f64>> = board
            .corners()
            .iter()
            .map(|c| rig.cam0.project(&(pose * c).coords).unwrap())
            .collect();
        let found: Vec<nalgebra::Point2<f64>> = corners
            .iter()
            .map(|p| nalgebra::Point2::new(f64::from(p.x), f64::from(p.y)))
            .collect();
        assert_eq!(found.len(), truth.len());
        // OpenCV may report the grid from either end.
        let rms = |rev: bool| {
            let sum: f64 = (0..truth.len())
                .map(|i| {
                    let j = if rev { truth.len() - 1 - i } else { i };
                    (found[i] - truth[j]).norm_squared()
                })
                .sum();
            (sum / truth.len() as f64).sqrt()
        };
        let rms = rms(false).min(rms(true));
        assert!(rms < 0.1, "corner RMS {rms} px");
    }
}
