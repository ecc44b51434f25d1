//! Images of a planar chessboard calibration target seen by a stereo rig, with the board
//! poses as ground truth, so calibration can be checked against known parameters.
//!
//! Each pixel's ray is intersected with the board plane (exact lens model); the checker
//! pattern is box-filtered over the pixel footprint per board axis (the filtered square wave
//! `q(u) = q_k · min(1, 2·e/w_u)`, `e` the distance to the nearest square edge, `w_u` the
//! footprint in squares), which gives sharp, alias-free edges with correct subpixel
//! positions.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{IsometryMatrix3, Point3, Rotation3, Translation3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use super::{SynthError, quaternion_wxyz, raster, to_gray8, write_png_gray};
use crate::camera::{Camera, StereoRig};

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
    /// [`SynthError::Params`] with the expected form.
    pub fn parse(spec: &str) -> Result<Self, SynthError> {
        let bad = || {
            SynthError::Params(format!(
                "target {spec:?}: expected chessboard:COLSxROWS:SQUARE_MM, e.g. chessboard:9x6:20"
            ))
        };
        let rest = spec.strip_prefix("chessboard:").ok_or_else(bad)?;
        let (size, square) = rest.split_once(':').ok_or_else(bad)?;
        let (c, r) = size.split_once('x').ok_or_else(bad)?;
        let board = Self {
            cols: c.parse().map_err(|_| bad())?,
            rows: r.parse().map_err(|_| bad())?,
            square_mm: square.parse().map_err(|_| bad())?,
        };
        if board.cols < 2 || board.rows < 2 || board.square_mm.is_nan() || board.square_mm <= 0.0 {
            return Err(bad());
        }
        Ok(board)
    }

    /// Inner corners in the board frame (z = 0), row by row, mm, as OpenCV orders them
    /// (x fastest).
    pub fn corners(&self) -> Vec<Point3<f64>> {
        let mut out = Vec::new();
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
}

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

/// Renders one view of the board: 8-bit radiance before noise.
pub fn render_board(
    camera: &Camera,
    board: &Chessboard,
    cam_from_board: &IsometryMatrix3<f64>,
) -> Vec<f32> {
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    let board_from_cam = cam_from_board.inverse();
    let origin = board_from_cam.translation.vector;
    // Board coordinates (in squares) of each pixel centre's ray, NaN where it misses.
    let uv: Vec<[f64; 2]> = (0..w * h)
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
            [p.x / board.square_mm, p.y / board.square_mm]
        })
        .collect();
    let (nu, nv) = (f64::from(board.cols + 1), f64::from(board.rows + 1));
    let border = 0.6;
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let [u, v] = uv[i];
            if !u.is_finite() {
                return 60.0;
            }
            let (x, y) = (i % w, i / w);
            let neighbour = |j: usize| uv.get(j).copied().filter(|q| q[0].is_finite());
            let dx = neighbour(if x + 1 < w { i + 1 } else { i - 1 });
            let dy = neighbour(if y + 1 < h { i + w } else { i - w });
            let (wu, wv) = match (dx, dy) {
                (Some(a), Some(b)) => (
                    (a[0] - u).abs() + (b[0] - u).abs(),
                    (a[1] - v).abs() + (b[1] - v).abs(),
                ),
                _ => (0.05, 0.05),
            };
            if u < -border || v < -border || u > nu + border || v > nv + border {
                return 60.0;
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
            (130.0 + 95.0 * value) as f32
        })
        .collect()
}

/// A random board pose in front of the rig with every corner inside both images (at
/// least 20 px from the border), or `None` after many tries.
fn random_pose(
    rng: &mut StdRng,
    rig: &StereoRig,
    board: &Chessboard,
    params: &TargetParams,
) -> Option<IsometryMatrix3<f64>> {
    let axis1 = rig.cam1_from_cam0.rotation.inverse() * Vector3::z();
    let axis = (Vector3::z() + axis1).normalize();
    let mid = rig.cam1_centre_in_cam0().coords * 0.5;
    let corners = board.corners();
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
            IsometryMatrix3::from_parts(Translation3::from(centre - r * board.centre().coords), r);
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

/// Renders `params.views` image pairs of `board` seen by `rig` into `out/cam0/NNNNNN.png`
/// and `out/cam1/NNNNNN.png`, with `out/calibration.yaml` (the true rig) and
/// `out/gt/board_poses.csv` (`view,qw,qx,qy,qz,tx,ty,tz`: board → cam0, mm).
///
/// # Errors
/// [`SynthError`] for a board that cannot be placed in view of both cameras, or a file
/// that cannot be written.
pub fn render_targets(
    rig: &StereoRig,
    board: &Chessboard,
    params: &TargetParams,
    out: &Path,
) -> Result<(), SynthError> {
    let mut rng = StdRng::seed_from_u64(params.seed);
    let mut poses = Vec::new();
    for _ in 0..params.views {
        poses.push(random_pose(&mut rng, rig, board, params).ok_or_else(|| {
            SynthError::Params(
                "the board does not fit in both images: use a smaller board or a larger distance"
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
            let mut img = render_board(cam, board, &(from0 * pose));
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
        let pose = random_pose(&mut rng, &rig, &board, &TargetParams::default()).unwrap();
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
        let pose = random_pose(&mut rng, &rig, &board, &params).unwrap();
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
