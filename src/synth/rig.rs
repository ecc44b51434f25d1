//! Helmet rigs made from a few numbers: field of view, image size, lens model, baseline
//! and the distance at which the two cameras' axes cross.

use nalgebra::{IsometryMatrix3, Matrix3, Rotation3, Translation3, Vector3};

use super::SynthError;
use crate::camera::{Camera, Distortion, StereoRig};

/// The lens model of a generated rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LensModel {
    /// Perspective lens with mild barrel distortion (OpenCV radial-tangential).
    Pinhole,
    /// Fisheye lens (OpenCV fisheye / Kannala-Brandt, close to equidistant).
    Fisheye,
}

/// A stereo helmet rig: two identical cameras stacked vertically (cam1 below cam0), both
/// toed in so their optical axes cross in front of the face.
#[derive(Debug, Clone, PartialEq)]
pub struct RigParams {
    /// Image width, pixels. Default 1280.
    pub width_px: u32,
    /// Image height, pixels. Default 1024.
    pub height_px: u32,
    /// Horizontal field of view, degrees (60 to 160; a pinhole lens at most 120).
    /// Default 104 (the shipped helmet rig).
    pub fov_deg: f64,
    /// Lens model. Default fisheye.
    pub lens: LensModel,
    /// Distance between the two optical centres, mm. Default 70.
    pub baseline_mm: f64,
    /// Distance from the midpoint of the cameras at which the optical axes cross, mm
    /// (normally the distance to the face). Default 225.
    pub convergence_mm: f64,
}

impl Default for RigParams {
    fn default() -> Self {
        Self {
            width_px: 1280,
            height_px: 1024,
            fov_deg: 104.0,
            lens: LensModel::Fisheye,
            baseline_mm: 70.0,
            convergence_mm: 225.0,
        }
    }
}

/// Fisheye distortion of the generated lenses (Kannala-Brandt k1..k4; like the shipped rig).
const FISHEYE_K: [f64; 4] = [0.03, -0.012, 0.004, -0.001];
/// Radial distortion of the generated perspective lenses (OpenCV k1, k2, k3): mild barrel.
const PINHOLE_K: [f64; 3] = [-0.06, 0.008, 0.0];

impl RigParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`SynthError::Params`] naming the field.
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |m: String| Err(SynthError::Params(format!("rig: {m}")));
        if !(64..=8192).contains(&self.width_px) || !(48..=8192).contains(&self.height_px) {
            return bad(format!(
                "image size {}x{} out of range (64x48 to 8192x8192)",
                self.width_px, self.height_px
            ));
        }
        let max_fov = match self.lens {
            LensModel::Pinhole => 120.0,
            LensModel::Fisheye => 170.0,
        };
        if !(self.fov_deg >= 20.0 && self.fov_deg <= max_fov) {
            return bad(format!(
                "fov_deg {} out of range (20 to {max_fov} for this lens)",
                self.fov_deg
            ));
        }
        if !(self.baseline_mm > 0.0 && self.baseline_mm < 1000.0) {
            return bad(format!("baseline_mm {} out of range", self.baseline_mm));
        }
        if !(self.convergence_mm > 10.0 && self.convergence_mm < 10_000.0) {
            return bad(format!(
                "convergence_mm {} out of range",
                self.convergence_mm
            ));
        }
        Ok(())
    }

    /// The focal length in pixels that gives the horizontal field of view: for the fisheye
    /// the distorted angle `θ_d(θ) = θ(1 + k1θ² + …)` of the half field maps to half the
    /// width; for the pinhole `tan(θ)` after the radial distortion does.
    pub fn focal_px(&self) -> f64 {
        let half = 0.5 * self.fov_deg.to_radians();
        let half_w = 0.5 * f64::from(self.width_px);
        match self.lens {
            LensModel::Fisheye => {
                let t2 = half * half;
                let k = FISHEYE_K;
                half_w / (half * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))))
            }
            LensModel::Pinhole => {
                let r = half.tan();
                let r2 = r * r;
                let k = PINHOLE_K;
                half_w / (r * (1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[2]))))
            }
        }
    }

    /// Builds the rig.
    ///
    /// # Errors
    /// [`SynthError::Params`] for invalid parameters.
    pub fn build(&self) -> Result<StereoRig, SynthError> {
        self.validate()?;
        let f = self.focal_px();
        let (w, h) = (f64::from(self.width_px), f64::from(self.height_px));
        let distortion = match self.lens {
            LensModel::Fisheye => Distortion::Fisheye { k: FISHEYE_K },
            LensModel::Pinhole => Distortion::Pinhole {
                k: PINHOLE_K,
                p: [0.0; 2],
            },
        };
        // Principal points a little off centre, as real lenses are mounted; the two
        // cameras differ slightly.
        let cam = |dx: f64, dy: f64, df: f64| {
            Camera::new(
                self.width_px,
                self.height_px,
                [
                    f * (1.0 + df),
                    f * (1.0 + df) * 0.9995,
                    0.5 * (w - 1.0) + dx * w,
                    0.5 * (h - 1.0) + dy * h,
                ],
                distortion,
            )
        };
        let cam0 = cam(0.002, -0.003, 0.0);
        let cam1 = cam(-0.004, 0.004, -0.004);
        // Rig frame: x right, y down, z toward the face; cam0 at y = −b/2, cam1 at +b/2,
        // each turned about x to look at (0, 0, convergence).
        let half_b = 0.5 * self.baseline_mm;
        let theta = half_b.atan2(self.convergence_mm);
        let rig_from_cam = |tilt: f64, y: f64| {
            let z = Vector3::new(0.0, tilt.sin(), tilt.cos());
            let x = Vector3::x();
            let yy = z.cross(&x);
            IsometryMatrix3::from_parts(
                Translation3::new(0.0, y, 0.0),
                Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, yy, z])),
            )
        };
        let rig_from_cam0 = rig_from_cam(theta, -half_b);
        let rig_from_cam1 = rig_from_cam(-theta, half_b);
        let rig = StereoRig {
            cam0,
            cam1,
            cam1_from_cam0: rig_from_cam1.inverse() * rig_from_cam0,
            rms_px: 0.0,
        };
        rig.validate()
            .map_err(|e| SynthError::Params(format!("rig: {e}")))?;
        Ok(rig)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point3;

    #[test]
    fn field_of_view_and_convergence() {
        for lens in [LensModel::Fisheye, LensModel::Pinhole] {
            let p = RigParams {
                lens,
                fov_deg: 90.0,
                baseline_mm: 60.0,
                convergence_mm: 150.0,
                ..RigParams::default()
            };
            let rig = p.build().unwrap();
            // A point at the edge of the field, 45° right of cam0's axis, lands on the
            // image's right edge (up to the principal point's offset).
            let right = Vector3::new(1.0, 0.0, 1.0);
            let px = rig.cam0.project(&right).unwrap();
            assert!((px.x - 1279.5).abs() < 0.01 * 1280.0, "{lens:?} {px}");
            // The axes cross at the convergence point, in the middle of both images.
            let c1 = rig.cam1_centre_in_cam0();
            // The baseline is 60 mm, vertical, and cam1 sits a little behind cam0 along
            // cam0's axis where the rig toes in.
            assert!(
                (c1.coords.norm() - 60.0).abs() < 1e-6 && c1.x.abs() < 1e-9 && c1.y > 55.0,
                "{c1}"
            );
            // The point on cam0's axis where the axes cross is on cam1's axis too.
            let on_axis = Point3::new(0.0, 0.0, 150.0f64.hypot(30.0));
            let p1 = rig
                .cam1
                .project(&(rig.cam1_from_cam0 * on_axis).coords)
                .unwrap();
            let pp1 = (rig.cam1.k[(0, 2)], rig.cam1.k[(1, 2)]);
            assert!(
                (p1.x - pp1.0).abs() < 1e-6 && (p1.y - pp1.1).abs() < 1e-6,
                "{p1}"
            );
        }
    }

    #[test]
    fn bad_rigs_name_the_field() {
        let e = RigParams {
            lens: LensModel::Pinhole,
            fov_deg: 150.0,
            ..RigParams::default()
        }
        .build()
        .unwrap_err();
        assert!(e.to_string().contains("fov_deg"), "{e}");
        assert!(
            RigParams {
                width_px: 0,
                ..RigParams::default()
            }
            .build()
            .is_err()
        );
        assert!(
            RigParams {
                baseline_mm: f64::NAN,
                ..RigParams::default()
            }
            .build()
            .is_err()
        );
    }
}
