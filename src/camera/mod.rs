//! Camera models and stereo rigs: OpenCV radial-tangential pinhole and fisheye
//! (Kannala-Brandt) projection, unprojection and undistortion in pure Rust, and the
//! calibration file (OpenCV FileStorage YAML) that describes a helmet's stereo pair;
//! calibration targets ([`target`]).
//!
//! Depends on nothing else in helmcap.

mod calib_file;
pub mod calibrate;
mod model;
pub mod tag36h11;
pub mod target;

pub use calib_file::{CalibFileError, format_rig, parse_rig, read_rig, write_rig};
pub use model::{Camera, Distortion};

use nalgebra::{IsometryMatrix3, Point3};

/// Errors of the camera models.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    /// The camera description is invalid (bad `K`, unknown model, wrong coefficient count).
    #[error("invalid camera: {0}")]
    Model(String),
    /// The distortion inversion did not converge for this pixel: it lies outside the region
    /// where the lens model is invertible.
    #[error("undistortion did not converge at pixel ({u_px}, {v_px})")]
    NoConvergence {
        /// Pixel column.
        u_px: f64,
        /// Pixel row.
        v_px: f64,
    },
}

/// The default helmet rig (`calib/helmet-fisheye.yaml`): two fisheye cameras 1280×1024
/// stacked vertically, 70 mm apart, toed in toward a face about 225 mm away (what the
/// synthetic footage is rendered with).
///
/// # Errors
/// Only if the shipped file were broken (a bug).
pub fn default_helmet_rig() -> Result<StereoRig, CalibFileError> {
    parse_rig(
        std::path::Path::new("calib/helmet-fisheye.yaml"),
        include_str!("../../calib/helmet-fisheye.yaml"),
    )
}

/// A calibrated stereo pair: cam0 is the reference frame, and a point `X0` in cam0 maps to
/// cam1 as `X1 = R·X0 + T` (millimetres).
#[derive(Debug, Clone, PartialEq)]
pub struct StereoRig {
    /// The reference camera.
    pub cam0: Camera,
    /// The second camera.
    pub cam1: Camera,
    /// `X1 = cam1_from_cam0 · X0` (`R`, `T` of the calibration file; translation in mm).
    pub cam1_from_cam0: IsometryMatrix3<f64>,
    /// Reprojection RMS of the calibration, pixels.
    pub rms_px: f64,
}

impl StereoRig {
    /// Distance between the two optical centres, mm.
    pub fn baseline_mm(&self) -> f64 {
        self.cam1_from_cam0.translation.vector.norm()
    }

    /// Centre of cam1 in the cam0 frame, mm.
    pub fn cam1_centre_in_cam0(&self) -> Point3<f64> {
        self.cam1_from_cam0.inverse() * Point3::origin()
    }

    /// Checks both cameras, the shared image size and the finiteness of the extrinsics.
    ///
    /// # Errors
    /// [`CameraError::Model`] naming the problem.
    pub fn validate(&self) -> Result<(), CameraError> {
        self.cam0
            .validate()
            .map_err(|e| CameraError::Model(format!("cam0: {e}")))?;
        self.cam1
            .validate()
            .map_err(|e| CameraError::Model(format!("cam1: {e}")))?;
        if (self.cam0.width_px, self.cam0.height_px) != (self.cam1.width_px, self.cam1.height_px) {
            return Err(CameraError::Model(
                "both cameras must have the same image size".into(),
            ));
        }
        let m = self.cam1_from_cam0.to_homogeneous();
        if m.iter().any(|v| !v.is_finite()) || !self.rms_px.is_finite() {
            return Err(CameraError::Model("extrinsics or rms not finite".into()));
        }
        Ok(())
    }
}
