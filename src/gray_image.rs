//! The 8-bit grey image every stage that reads pixels shares (the capture's frames, the
//! calibration's target images, the detector's input), and its bilinear sampling. Files are
//! read and converted into it by [`crate::capture::read_gray`].

/// An 8-bit grayscale image, row-major.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GrayImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `width × height` values, row by row.
    pub data: Vec<u8>,
}

impl GrayImage {
    /// The value at column `x`, row `y`, or `None` outside the image.
    pub fn get(&self, x: u32, y: u32) -> Option<u8> {
        if x < self.width && y < self.height {
            self.data
                .get(y as usize * self.width as usize + x as usize)
                .copied()
        } else {
            None
        }
    }

    /// The value at `(x, y)` interpolated bilinearly (pixel centres at integers), or `None`
    /// outside the square of pixel centres.
    pub fn bilinear(&self, x: f64, y: f64) -> Option<f64> {
        let (w, h) = (self.width as usize, self.height as usize);
        if w < 2 || h < 2 || self.data.len() != w * h {
            return None;
        }
        if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
            return None;
        }
        let (i, j) = ((x as usize).min(w - 2), (y as usize).min(h - 2));
        let (fx, fy) = (x - i as f64, y - j as f64);
        let p = |i: usize, j: usize| f64::from(self.data[j * w + i]);
        Some(
            (p(i, j) * (1.0 - fx) + p(i + 1, j) * fx) * (1.0 - fy)
                + (p(i, j + 1) * (1.0 - fx) + p(i + 1, j + 1) * fx) * fy,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_is_exact_on_a_plane_and_none_outside() {
        // A plane 3x + 5y + 7 (integer at every pixel): interpolation reproduces it.
        let (w, h) = (6u32, 4u32);
        let data = (0..h)
            .flat_map(|y| (0..w).map(move |x| (3 * x + 5 * y + 7) as u8))
            .collect();
        let image = GrayImage {
            width: w,
            height: h,
            data,
        };
        for &(x, y) in &[(0.0, 0.0), (2.25, 1.5), (4.9, 2.99), (5.0, 3.0)] {
            let v = image.bilinear(x, y).unwrap();
            assert!(
                (v - (3.0 * x + 5.0 * y + 7.0)).abs() < 1e-9,
                "({x}, {y}): {v}"
            );
        }
        for &(x, y) in &[(-0.1, 1.0), (5.01, 1.0), (1.0, 3.2), (f64::NAN, 1.0)] {
            assert_eq!(image.bilinear(x, y), None, "({x}, {y})");
        }
    }
}
