//! Conversions between nalgebra and OpenCV types, and the camera OpenCV's calibration
//! returns as a helmcap [`Camera`].

use nalgebra::{IsometryMatrix3, Matrix3, Point2, Point3, Rotation3, Translation3, Vector3};
use opencv::core::{Mat, Point2f, Point3f};
use opencv::prelude::*;

use super::super::{Camera, CameraError, Distortion};
use super::CameraModel;

/// Why a matrix OpenCV returned could not be read as a helmcap value.
#[derive(Debug, thiserror::Error)]
pub(super) enum CvError {
    /// OpenCV failed to copy or convert the matrix (its message).
    #[error("{0}")]
    OpenCv(String),
    /// The matrix's data is not as long as its element count says.
    #[error("matrix holds {bytes} bytes for {values} values")]
    DataSize {
        /// Bytes of data.
        bytes: usize,
        /// Values the matrix should hold.
        values: usize,
    },
    /// Not a 3×3 matrix: the number of values.
    #[error("expected a 3×3 matrix, got {0} values")]
    NotMatrix3(usize),
    /// Not a 3-vector: the number of values.
    #[error("expected 3 values, got {0}")]
    NotVector3(usize),
    /// The camera built from the values is invalid.
    #[error(transparent)]
    Camera(#[from] CameraError),
}

pub(super) fn point3f(p: &Point3<f64>) -> Point3f {
    Point3f::new(p.x as f32, p.y as f32, p.z as f32)
}

pub(super) fn point2f(p: &Point2<f64>) -> Point2f {
    Point2f::new(p.x as f32, p.y as f32)
}

/// The values of a continuous `f64` matrix, row by row.
fn mat_values(m: &Mat) -> Result<Vec<f64>, CvError> {
    let m64 = if m.depth() == opencv::core::CV_64F {
        m.try_clone().map_err(|e| CvError::OpenCv(e.message))?
    } else {
        let mut out = Mat::default();
        m.convert_to(&mut out, opencv::core::CV_64F, 1.0, 0.0)
            .map_err(|e| CvError::OpenCv(e.message))?;
        out
    };
    let m64 = if m64.is_continuous() {
        m64
    } else {
        m64.try_clone().map_err(|e| CvError::OpenCv(e.message))?
    };
    let n = m64.total() * m64.channels() as usize;
    let data = m64.data_bytes().map_err(|e| CvError::OpenCv(e.message))?;
    if data.len() != 8 * n {
        return Err(CvError::DataSize {
            bytes: data.len(),
            values: n,
        });
    }
    Ok(data
        .chunks_exact(8)
        .map(|b| f64::from_ne_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
        .collect())
}

fn mat3_from_cv(m: &Mat) -> Result<Matrix3<f64>, CvError> {
    let v = mat_values(m)?;
    if v.len() != 9 {
        return Err(CvError::NotMatrix3(v.len()));
    }
    Ok(Matrix3::from_row_slice(&v))
}

fn vec3_from_cv(m: &Mat) -> Result<Vector3<f64>, CvError> {
    let v = mat_values(m)?;
    if v.len() != 3 {
        return Err(CvError::NotVector3(v.len()));
    }
    Ok(Vector3::new(v[0], v[1], v[2]))
}

pub(super) fn isometry_from_cv(r: &Mat, t: &Mat) -> Result<IsometryMatrix3<f64>, CvError> {
    let rv = vec3_from_cv(r)?;
    let tv = vec3_from_cv(t)?;
    Ok(IsometryMatrix3::from_parts(
        Translation3::from(tv),
        Rotation3::from_scaled_axis(rv),
    ))
}

pub(super) fn camera_from_cv(
    k: &Mat,
    d: &Mat,
    width: u32,
    height: u32,
    model: CameraModel,
) -> Result<Camera, CvError> {
    let k = mat3_from_cv(k)?;
    let d = mat_values(d)?;
    let distortion = match model {
        CameraModel::Pinhole => {
            let d5: Vec<f64> = d
                .iter()
                .copied()
                .chain(std::iter::repeat(0.0))
                .take(5)
                .collect();
            Distortion::from_coefficients("pinhole", &d5)
        }
        CameraModel::Fisheye => Distortion::from_coefficients("fisheye", &d),
    }?;
    let camera = Camera {
        width_px: width,
        height_px: height,
        k,
        distortion,
    };
    camera.validate()?;
    Ok(camera)
}
