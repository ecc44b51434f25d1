//! Units sanity check of mesh inputs: a mesh in the dataset's topology whose size is off
//! the dataset neutral's by a power of ten was almost certainly read in the wrong unit
//! (metres or centimetres taken as millimetres), and everything solved from it would be
//! meaningless. The check compares RMS radii about the centroid.

use nalgebra::Point3;

/// Size ratios within this factor of 1 pass (faces differ in size, and expressions
/// move vertices, by far less).
pub const SCALE_TOLERANCE: f64 = 2.0;

/// A mesh whose size does not match the reference's.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct ScaleMismatch {
    /// Input size / reference size (RMS radius about the centroid).
    pub ratio: f64,
    /// The explanation, with the likely cause and the fix.
    pub message: String,
}

/// RMS distance of the points to their centroid.
pub fn rms_radius(points: &[Point3<f64>]) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let n = points.len() as f64;
    let c = points
        .iter()
        .fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords)
        / n;
    (points
        .iter()
        .map(|p| (p.coords - c).norm_squared())
        .sum::<f64>()
        / n)
        .sqrt()
}

/// Checks that `input` (mm, after any stated unit conversion) has the size of
/// `reference` (the dataset's neutral, mm) within [`SCALE_TOLERANCE`].
///
/// # Errors
/// [`ScaleMismatch`] naming the ratio and, when it is near 10, 100 or 1000 (or their
/// inverses), the unit the file is probably in and the `--units` value that states it.
pub fn check_mesh_scale(
    input: &[Point3<f64>],
    reference: &[Point3<f64>],
) -> Result<(), ScaleMismatch> {
    let (a, b) = (rms_radius(input), rms_radius(reference));
    if b <= 0.0 {
        return Ok(());
    }
    let ratio = a / b;
    if ratio.is_finite() && (1.0 / SCALE_TOLERANCE..=SCALE_TOLERANCE).contains(&ratio) {
        return Ok(());
    }
    let likely = [
        (
            1e-3,
            "it is probably in metres read as millimetres: add --units m",
        ),
        (1e-2, "it is probably in decimetres read as millimetres"),
        (
            1e-1,
            "it is probably in centimetres read as millimetres: add --units cm",
        ),
        (
            1e1,
            "it is 10× too large: a wrong --units (cm for a file in mm?)",
        ),
        (
            1e2,
            "it is 100× too large: a wrong --units (m for a file in cm?)",
        ),
        (
            1e3,
            "it is 1000× too large: a wrong --units (m for a file in mm?)",
        ),
    ]
    .iter()
    .find(|(k, _): &&(f64, &str)| ratio > 0.0 && (ratio.log10() - k.log10()).abs() < 0.3)
    .map(|(_, why)| *why);
    let message = match likely {
        Some(why) => format!(
            "the mesh is {ratio:.3}× the size of the dataset's neutral (RMS radius \
             {a:.4} vs {b:.1} mm): {why}"
        ),
        None => format!(
            "the mesh is {ratio:.3}× the size of the dataset's neutral (RMS radius \
             {a:.4} vs {b:.1} mm): not the same face, or not in millimetres (state the \
             file's unit with --units mm|cm|m)"
        ),
    };
    Err(ScaleMismatch { ratio, message })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn powers_of_ten_are_caught_with_the_cause() {
        let face: Vec<Point3<f64>> = (0..100)
            .map(|i| {
                let t = i as f64 * 0.1;
                Point3::new(80.0 * t.cos(), 100.0 * t.sin(), 30.0 * (2.0 * t).cos())
            })
            .collect();
        assert!(check_mesh_scale(&face, &face).is_ok());
        let smiling: Vec<_> = face.iter().map(|p| p * 1.05).collect();
        assert!(check_mesh_scale(&smiling, &face).is_ok());
        let metres: Vec<_> = face.iter().map(|p| p * 1e-3).collect();
        let e = check_mesh_scale(&metres, &face).unwrap_err();
        assert!(e.message.contains("--units m"), "{e}");
        let cm: Vec<_> = face.iter().map(|p| p * 0.1).collect();
        let e = check_mesh_scale(&cm, &face).unwrap_err();
        assert!(e.message.contains("--units cm"), "{e}");
        let big: Vec<_> = face.iter().map(|p| p * 10.0).collect();
        assert!(
            check_mesh_scale(&big, &face)
                .unwrap_err()
                .message
                .contains("10×")
        );
        let odd: Vec<_> = face.iter().map(|p| p * 4.0).collect();
        assert!(check_mesh_scale(&odd, &face).is_err());
    }
}
