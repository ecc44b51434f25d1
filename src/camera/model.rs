//! Camera models: OpenCV radial-tangential pinhole and OpenCV fisheye (Kannala-Brandt).
//!
//! Both map a point in the camera frame (OpenCV convention: x right, y down, z forward,
//! millimetres) to a pixel in three steps: the normalized point `(x/z, y/z)`, the lens
//! distortion to a distorted normalized point, then the intrinsic matrix `K`.

use nalgebra::{Matrix2, Matrix3, Point2, Unit, Vector2, Vector3};

use super::CameraError;

/// Lens distortion, with the coefficients in OpenCV's order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Distortion {
    /// OpenCV radial-tangential (Brown-Conrady) model, `D = (k1, k2, p1, p2, k3)`:
    /// with `r² = x² + y²`, `x_d = x·(1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2x²)`,
    /// `y_d = y·(1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2y²) + 2 p2 x y`
    /// (OpenCV `calib3d` documentation, "Camera Calibration and 3D Reconstruction").
    Pinhole {
        /// Radial coefficients `k1, k2, k3`.
        k: [f64; 3],
        /// Tangential coefficients `p1, p2`.
        p: [f64; 2],
    },
    /// OpenCV fisheye / Kannala-Brandt model, `D = (k1, k2, k3, k4)`: with `θ = atan(r)`,
    /// `θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)` and `(x_d, y_d) = (θ_d / r)·(x, y)`
    /// (Kannala and Brandt 2006; OpenCV `cv::fisheye` documentation).
    Fisheye {
        /// Coefficients `k1..k4`.
        k: [f64; 4],
    },
}

impl Distortion {
    /// The model's name in calibration files: `"pinhole"` or `"fisheye"`.
    pub fn model_name(&self) -> &'static str {
        match self {
            Distortion::Pinhole { .. } => "pinhole",
            Distortion::Fisheye { .. } => "fisheye",
        }
    }

    /// The coefficients in OpenCV's order (5 for pinhole, 4 for fisheye).
    pub fn coefficients(&self) -> Vec<f64> {
        match self {
            Distortion::Pinhole { k, p } => vec![k[0], k[1], p[0], p[1], k[2]],
            Distortion::Fisheye { k } => k.to_vec(),
        }
    }

    /// Builds a distortion from a model name and coefficients in OpenCV's order.
    ///
    /// # Errors
    /// [`CameraError::Model`] for an unknown model name or a wrong coefficient count.
    pub fn from_coefficients(model: &str, d: &[f64]) -> Result<Self, CameraError> {
        match (model, d) {
            ("pinhole", &[k1, k2, p1, p2, k3]) => Ok(Distortion::Pinhole {
                k: [k1, k2, k3],
                p: [p1, p2],
            }),
            ("fisheye", &[k1, k2, k3, k4]) => Ok(Distortion::Fisheye {
                k: [k1, k2, k3, k4],
            }),
            ("pinhole" | "fisheye", _) => Err(CameraError::Model(format!(
                "model {model:?} needs {} distortion coefficients, got {}",
                if model == "pinhole" { 5 } else { 4 },
                d.len()
            ))),
            _ => Err(CameraError::Model(format!(
                "unknown camera model {model:?} (expected \"pinhole\" or \"fisheye\")"
            ))),
        }
    }

    /// Distorts a normalized point `(x/z, y/z)` for a point in front of the camera.
    pub fn distort(&self, xy: &Vector2<f64>) -> Vector2<f64> {
        self.distort_with_jacobian(xy).0
    }

    /// The distorted normalized point and its Jacobian `∂(x_d, y_d)/∂(x, y)`.
    pub fn distort_with_jacobian(&self, xy: &Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
        let (x, y) = (xy.x, xy.y);
        match *self {
            Distortion::Pinhole { k, p } => {
                let r2 = x * x + y * y;
                let radial = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[2]));
                let d_radial_dr2 = k[0] + r2 * (2.0 * k[1] + 3.0 * r2 * k[2]);
                let xd = x * radial + 2.0 * p[0] * x * y + p[1] * (r2 + 2.0 * x * x);
                let yd = y * radial + p[0] * (r2 + 2.0 * y * y) + 2.0 * p[1] * x * y;
                let dxd_dx = radial + x * d_radial_dr2 * 2.0 * x + 2.0 * p[0] * y + p[1] * 6.0 * x;
                let dxd_dy = x * d_radial_dr2 * 2.0 * y + 2.0 * p[0] * x + p[1] * 2.0 * y;
                let dyd_dx = y * d_radial_dr2 * 2.0 * x + p[0] * 2.0 * x + 2.0 * p[1] * y;
                let dyd_dy = radial + y * d_radial_dr2 * 2.0 * y + p[0] * 6.0 * y + 2.0 * p[1] * x;
                (
                    Vector2::new(xd, yd),
                    Matrix2::new(dxd_dx, dxd_dy, dyd_dx, dyd_dy),
                )
            }
            Distortion::Fisheye { k } => {
                let r = (x * x + y * y).sqrt();
                if r < 1e-12 {
                    // θ_d/r → 1 as r → 0: the model is the identity to first order.
                    return (*xy, Matrix2::identity());
                }
                let theta = r.atan();
                let t2 = theta * theta;
                let poly = 1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])));
                let theta_d = theta * poly;
                let dtheta_d_dtheta = 1.0
                    + t2 * (3.0 * k[0] + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
                let dtheta_dr = 1.0 / (1.0 + r * r);
                let s = theta_d / r;
                let ds_dr = (dtheta_d_dtheta * dtheta_dr * r - theta_d) / (r * r);
                // ∂(s·x)/∂x = s + x·ds/dr·x/r, and so on.
                let (ux, uy) = (x / r, y / r);
                (
                    Vector2::new(s * x, s * y),
                    Matrix2::new(
                        s + x * ds_dr * ux,
                        x * ds_dr * uy,
                        y * ds_dr * ux,
                        s + y * ds_dr * uy,
                    ),
                )
            }
        }
    }
}

/// Maximum iterations of the distortion inversion.
const MAX_UNDISTORT_ITERATIONS: usize = 50;
/// Convergence threshold of the distortion inversion, on the distorted normalized point.
const UNDISTORT_TOLERANCE: f64 = 1e-14;

/// One calibrated camera: image size, intrinsic matrix `K` and lens distortion.
#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    /// Image width in pixels.
    pub width_px: u32,
    /// Image height in pixels.
    pub height_px: u32,
    /// Intrinsic matrix `[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`, pixels.
    pub k: Matrix3<f64>,
    /// Lens distortion.
    pub distortion: Distortion,
}

impl Camera {
    /// A camera with focal lengths `fx, fy` and principal point `cx, cy` (pixels), no skew.
    pub fn new(
        width_px: u32,
        height_px: u32,
        [fx, fy, cx, cy]: [f64; 4],
        distortion: Distortion,
    ) -> Self {
        Self {
            width_px,
            height_px,
            k: Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0),
            distortion,
        }
    }

    /// Checks that `K` is an upper-triangular intrinsic matrix with positive focal lengths and
    /// that every value is finite.
    ///
    /// # Errors
    /// [`CameraError::Model`] naming what is wrong.
    pub fn validate(&self) -> Result<(), CameraError> {
        let k = &self.k;
        if k.iter().any(|v| !v.is_finite())
            || self
                .distortion
                .coefficients()
                .iter()
                .any(|v| !v.is_finite())
        {
            return Err(CameraError::Model(
                "a camera parameter is not finite".into(),
            ));
        }
        if k[(1, 0)] != 0.0 || k[(2, 0)] != 0.0 || k[(2, 1)] != 0.0 || k[(2, 2)] != 1.0 {
            return Err(CameraError::Model(
                "K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]]".into(),
            ));
        }
        if k[(0, 0)] <= 0.0 || k[(1, 1)] <= 0.0 {
            return Err(CameraError::Model(
                "focal lengths fx, fy must be positive".into(),
            ));
        }
        if self.width_px == 0 || self.height_px == 0 {
            return Err(CameraError::Model("image size must be positive".into()));
        }
        Ok(())
    }

    /// Focal length `fx`, pixels.
    pub fn fx(&self) -> f64 {
        self.k[(0, 0)]
    }

    /// Focal length `fy`, pixels.
    pub fn fy(&self) -> f64 {
        self.k[(1, 1)]
    }

    /// Applies `K` to a distorted normalized point.
    fn distorted_to_pixel(&self, xy_d: &Vector2<f64>) -> Point2<f64> {
        let k = &self.k;
        Point2::new(
            k[(0, 0)] * xy_d.x + k[(0, 1)] * xy_d.y + k[(0, 2)],
            k[(1, 1)] * xy_d.y + k[(1, 2)],
        )
    }

    /// Removes `K` from a pixel: the distorted normalized point.
    fn pixel_to_distorted(&self, pixel: &Point2<f64>) -> Vector2<f64> {
        let k = &self.k;
        let y = (pixel.y - k[(1, 2)]) / k[(1, 1)];
        let x = (pixel.x - k[(0, 2)] - k[(0, 1)] * y) / k[(0, 0)];
        Vector2::new(x, y)
    }

    /// Projects a point in this camera's frame (mm) to a pixel; `None` for a point not in
    /// front of the camera (`z ≤ 0`). The pixel may lie outside the image.
    pub fn project(&self, point_in_cam: &Vector3<f64>) -> Option<Point2<f64>> {
        if point_in_cam.z <= 0.0 || !point_in_cam.iter().all(|v| v.is_finite()) {
            return None;
        }
        let xy = Vector2::new(
            point_in_cam.x / point_in_cam.z,
            point_in_cam.y / point_in_cam.z,
        );
        Some(self.distorted_to_pixel(&self.distortion.distort(&xy)))
    }

    /// Projects a point like [`Camera::project`] and also returns the 2×3 Jacobian of the
    /// pixel with respect to the point (pixels per mm).
    pub fn project_with_jacobian(
        &self,
        point_in_cam: &Vector3<f64>,
    ) -> Option<(Point2<f64>, nalgebra::Matrix2x3<f64>)> {
        if point_in_cam.z <= 0.0 {
            return None;
        }
        let z = point_in_cam.z;
        let xy = Vector2::new(point_in_cam.x / z, point_in_cam.y / z);
        let (xy_d, j_dist) = self.distortion.distort_with_jacobian(&xy);
        let j_norm = nalgebra::Matrix2x3::new(1.0 / z, 0.0, -xy.x / z, 0.0, 1.0 / z, -xy.y / z);
        let k2 = self.k.fixed_view::<2, 2>(0, 0).into_owned();
        Some((self.distorted_to_pixel(&xy_d), k2 * j_dist * j_norm))
    }

    /// The undistorted normalized point `(x/z, y/z)` seen at `pixel`: `K⁻¹` then the
    /// distortion inverted by Newton's method on the analytic Jacobian (fisheye: Newton on
    /// `θ_d(θ)`), iterated until the residual is below 1e-14.
    ///
    /// # Errors
    /// [`CameraError::NoConvergence`] when the inversion does not converge (a pixel far
    /// outside the domain where the model is invertible, or a non-monotonic model there).
    pub fn undistort_point(&self, pixel: &Point2<f64>) -> Result<Vector2<f64>, CameraError> {
        let xy_d = self.pixel_to_distorted(pixel);
        let fail = || CameraError::NoConvergence {
            u_px: pixel.x,
            v_px: pixel.y,
        };
        if !xy_d.iter().all(|v| v.is_finite()) {
            return Err(fail());
        }
        match self.distortion {
            Distortion::Fisheye { k } => {
                let theta_d = xy_d.norm();
                if theta_d < 1e-15 {
                    return Ok(xy_d);
                }
                // Solve θ (1 + k1 θ² + ...) = θ_d for θ in [0, π/2).
                let mut theta = theta_d.min(1.5);
                for _ in 0..MAX_UNDISTORT_ITERATIONS {
                    let t2 = theta * theta;
                    let f = theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
                        - theta_d;
                    let df = 1.0
                        + t2 * (3.0 * k[0]
                            + t2 * (5.0 * k[1] + t2 * (7.0 * k[2] + t2 * 9.0 * k[3])));
                    if f.abs() < UNDISTORT_TOLERANCE {
                        if !(0.0..std::f64::consts::FRAC_PI_2).contains(&theta) || df <= 0.0 {
                            return Err(fail());
                        }
                        return Ok(xy_d * (theta.tan() / theta_d));
                    }
                    if df <= 0.0 {
                        return Err(fail());
                    }
                    theta -= f / df;
                    if !theta.is_finite() {
                        return Err(fail());
                    }
                }
                Err(fail())
            }
            Distortion::Pinhole { .. } => {
                let mut xy = xy_d;
                for _ in 0..MAX_UNDISTORT_ITERATIONS {
                    let (d, j) = self.distortion.distort_with_jacobian(&xy);
                    let residual = d - xy_d;
                    if residual.norm() < UNDISTORT_TOLERANCE {
                        return Ok(xy);
                    }
                    let step = j.try_inverse().ok_or_else(fail)? * residual;
                    xy -= step;
                    if !xy.iter().all(|v| v.is_finite()) {
                        return Err(fail());
                    }
                }
                Err(fail())
            }
        }
    }

    /// The unit viewing ray (camera frame) through `pixel`.
    ///
    /// # Errors
    /// As [`Camera::undistort_point`].
    pub fn unproject(&self, pixel: &Point2<f64>) -> Result<Unit<Vector3<f64>>, CameraError> {
        let xy = self.undistort_point(pixel)?;
        Ok(Unit::new_normalize(Vector3::new(xy.x, xy.y, 1.0)))
    }

    /// Undistorts pixels to pixels of an ideal pinhole camera with intrinsics `new_k`
    /// (for example this camera's own `K`), like OpenCV's `undistortPoints` with `P`.
    ///
    /// # Errors
    /// As [`Camera::undistort_point`], for the first pixel that fails.
    pub fn undistort_pixels(
        &self,
        pixels: &[Point2<f64>],
        new_k: &Matrix3<f64>,
    ) -> Result<Vec<Point2<f64>>, CameraError> {
        pixels
            .iter()
            .map(|p| {
                let xy = self.undistort_point(p)?;
                let h = new_k * Vector3::new(xy.x, xy.y, 1.0);
                Ok(Point2::new(h.x / h.z, h.y / h.z))
            })
            .collect()
    }

    /// True when `pixel` lies inside the image (pixel centres at integer coordinates, as in
    /// OpenCV: the image spans `[-0.5, width - 0.5] × [-0.5, height - 0.5]`).
    pub fn contains(&self, pixel: &Point2<f64>) -> bool {
        pixel.x >= -0.5
            && pixel.y >= -0.5
            && pixel.x <= f64::from(self.width_px) - 0.5
            && pixel.y <= f64::from(self.height_px) - 0.5
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn fisheye() -> Camera {
        Camera::new(
            1280,
            1024,
            [520.0, 521.5, 641.3, 509.8],
            Distortion::Fisheye {
                k: [0.05, -0.012, 0.004, -0.0008],
            },
        )
    }

    pub(crate) fn pinhole() -> Camera {
        let mut c = Camera::new(
            1280,
            1024,
            [900.0, 905.0, 635.0, 515.0],
            Distortion::Pinhole {
                k: [-0.28, 0.09, -0.012],
                p: [0.0012, -0.0007],
            },
        );
        c.k[(0, 1)] = 0.3;
        c
    }

    /// Pixels on a grid over the whole image.
    fn image_grid(c: &Camera) -> Vec<Point2<f64>> {
        let mut out = Vec::new();
        for i in 0..=16 {
            for j in 0..=16 {
                out.push(Point2::new(
                    f64::from(c.width_px) * f64::from(i) / 16.0,
                    f64::from(c.height_px) * f64::from(j) / 16.0,
                ));
            }
        }
        out
    }

    #[test]
    fn pixel_round_trip_is_exact() {
        for cam in [fisheye(), pinhole()] {
            cam.validate().unwrap();
            for px in image_grid(&cam) {
                let ray = cam.unproject(&px).unwrap();
                for depth_mm in [50.0, 230.0, 4000.0] {
                    let p = ray.into_inner() * depth_mm;
                    let back = cam.project(&p).unwrap();
                    assert!((back - px).norm() < 1e-9, "{px} -> {back}");
                }
            }
        }
    }

    #[test]
    fn point_round_trip_is_exact() {
        for cam in [fisheye(), pinhole()] {
            for px in image_grid(&cam) {
                // A point on the ray of every grid pixel, then project and unproject it.
                let xy = cam.undistort_point(&px).unwrap();
                let p = Vector3::new(xy.x, xy.y, 1.0) * 187.0;
                let ray = cam.unproject(&cam.project(&p).unwrap()).unwrap();
                let err = (ray.into_inner() - p.normalize()).norm();
                assert!(err < 1e-9, "{err}");
            }
        }
    }

    #[test]
    fn jacobian_matches_finite_differences() {
        for cam in [fisheye(), pinhole()] {
            let p = Vector3::new(31.0, -42.0, 210.0);
            let (_, j) = cam.project_with_jacobian(&p).unwrap();
            for a in 0..3 {
                let mut dp = Vector3::zeros();
                dp[a] = 1e-5;
                let fd = (cam.project(&(p + dp)).unwrap() - cam.project(&(p - dp)).unwrap()) / 2e-5;
                assert!((fd - j.column(a)).norm() < 1e-5, "{fd} vs {}", j.column(a));
            }
        }
    }

    #[test]
    fn fisheye_sees_wide_angles() {
        let cam = fisheye();
        // 70° off axis still projects and comes back.
        let p = Vector3::new(70f64.to_radians().tan(), 0.0, 1.0);
        let px = cam.project(&p).unwrap();
        let ray = cam.unproject(&px).unwrap();
        assert!((ray.into_inner() - p.normalize()).norm() < 1e-9);
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn undistort_pixels_to_own_k_is_identity_without_distortion() {
        let mut cam = pinhole();
        cam.distortion = Distortion::Pinhole {
            k: [0.0; 3],
            p: [0.0; 2],
        };
        let px = vec![Point2::new(10.5, 20.25), Point2::new(1000.0, 3.0)];
        let out = cam.undistort_pixels(&px, &cam.k.clone()).unwrap();
        for (a, b) in px.iter().zip(&out) {
            assert!((a - b).norm() < 1e-9);
        }
    }

    #[test]
    fn non_convergence_is_an_error() {
        // A model that folds back (θ_d decreasing) cannot be inverted far out.
        let cam = Camera::new(
            100,
            100,
            [100.0, 100.0, 50.0, 50.0],
            Distortion::Fisheye {
                k: [-0.5, 0.0, 0.0, 0.0],
            },
        );
        assert!(cam.unproject(&Point2::new(5000.0, 50.0)).is_err());
        assert!(
            Distortion::from_coefficients("fisheye", &[0.0; 5]).is_err()
                && Distortion::from_coefficients("kb", &[0.0; 4]).is_err()
        );
    }
}
