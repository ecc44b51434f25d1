//! Software rendering of a triangle mesh through a (distorted) camera: a depth-buffered
//! rasterizer in image space, Lambert + Blinn-Phong shading under a light at the camera,
//! painted marker discs, sensor noise and blur.
//!
//! Triangles are projected vertex by vertex with the full lens model and rasterized as
//! straight-edged triangles in the distorted image: the face's triangles cover a few pixels,
//! where the lens curvature across a triangle is far below a pixel.

use nalgebra::{Point2, Point3, Vector3};

use crate::camera::Camera;

/// Per-pixel result of rasterization: nearest triangle and its barycentric coordinates.
pub struct Fragments {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Depth (camera z, mm) of the nearest surface, `f32::INFINITY` where none.
    pub depth: Vec<f32>,
    /// Triangle index of the nearest surface, `u32::MAX` where none.
    pub triangle: Vec<u32>,
    /// Barycentric weights of corners 1 and 2 (corner 0 is `1 − b1 − b2`).
    pub bary: Vec<[f32; 2]>,
}

/// No triangle at this pixel.
pub const NO_TRIANGLE: u32 = u32::MAX;

impl Fragments {
    /// Rasterizes `triangles` over vertices given in the camera frame (mm) with their
    /// projected pixels (`None` for vertices behind the camera: their triangles are
    /// skipped). Pixel centres are at integer coordinates.
    pub fn rasterize(
        camera: &Camera,
        points_in_cam: &[Point3<f64>],
        pixels: &[Option<Point2<f64>>],
        triangles: &[[u32; 3]],
    ) -> Self {
        let width = camera.width_px as usize;
        let height = camera.height_px as usize;
        let n = width * height;
        let mut out = Self {
            width,
            height,
            depth: vec![f32::INFINITY; n],
            triangle: vec![NO_TRIANGLE; n],
            bary: vec![[0.0; 2]; n],
        };
        for (t, tri) in triangles.iter().enumerate() {
            let [Some(p0), Some(p1), Some(p2)] = tri.map(|v| pixels[v as usize]) else {
                continue;
            };
            let z = tri.map(|v| points_in_cam[v as usize].z);
            let area = (p1.x - p0.x) * (p2.y - p0.y) - (p1.y - p0.y) * (p2.x - p0.x);
            if area.abs() < 1e-12 {
                continue;
            }
            let min_x = p0.x.min(p1.x).min(p2.x).ceil().max(0.0);
            let max_x = p0.x.max(p1.x).max(p2.x).floor().min(width as f64 - 1.0);
            let min_y = p0.y.min(p1.y).min(p2.y).ceil().max(0.0);
            let max_y = p0.y.max(p1.y).max(p2.y).floor().min(height as f64 - 1.0);
            if min_x > max_x || min_y > max_y {
                continue;
            }
            let inv_area = 1.0 / area;
            for y in min_y as usize..=max_y as usize {
                let py = y as f64;
                for x in min_x as usize..=max_x as usize {
                    let px = x as f64;
                    let w1 = ((px - p0.x) * (p2.y - p0.y) - (py - p0.y) * (p2.x - p0.x)) * inv_area;
                    let w2 = ((p1.x - p0.x) * (py - p0.y) - (p1.y - p0.y) * (px - p0.x)) * inv_area;
                    let w0 = 1.0 - w1 - w2;
                    // Half-open edges: a small negative slack so shared edges leave no cracks.
                    if w0 < -1e-9 || w1 < -1e-9 || w2 < -1e-9 {
                        continue;
                    }
                    let d = (w0 * z[0] + w1 * z[1] + w2 * z[2]) as f32;
                    let i = y * width + x;
                    if d < out.depth[i] {
                        out.depth[i] = d;
                        out.triangle[i] = t as u32;
                        out.bary[i] = [w1 as f32, w2 as f32];
                    }
                }
            }
        }
        out
    }

    /// The surface point (camera frame) and interpolated vertex normal at pixel `i`, or
    /// `None` where no triangle was drawn.
    pub fn surface(
        &self,
        i: usize,
        triangles: &[[u32; 3]],
        points_in_cam: &[Point3<f64>],
        normals_in_cam: &[Vector3<f64>],
    ) -> Option<(u32, Point3<f64>, Vector3<f64>)> {
        let t = *self.triangle.get(i)?;
        let tri = triangles.get(t as usize)?;
        let [b1, b2] = self.bary[i].map(f64::from);
        let b = [1.0 - b1 - b2, b1, b2];
        let mut p = Vector3::zeros();
        let mut n = Vector3::zeros();
        for (k, &v) in tri.iter().enumerate() {
            p += points_in_cam[v as usize].coords * b[k];
            n += normals_in_cam[v as usize] * b[k];
        }
        Some((t, Point3::from(p), n.try_normalize(1e-12).unwrap_or(n)))
    }
    /// The point at pixel `i` on the mesh with vertex positions `positions` (for example
    /// the rest pose: where a skin texture is looked up); the origin where no triangle
    /// was drawn.
    pub fn rest_point(
        &self,
        i: usize,
        triangles: &[[u32; 3]],
        positions: &[Point3<f64>],
    ) -> Point3<f64> {
        let (Some(&t), Some(bary)) = (self.triangle.get(i), self.bary.get(i)) else {
            return Point3::origin();
        };
        let Some(tri) = triangles.get(t as usize) else {
            return Point3::origin();
        };
        let [b1, b2] = bary.map(f64::from);
        let b = [1.0 - b1 - b2, b1, b2];
        let mut p = Vector3::zeros();
        for (k, &v) in tri.iter().enumerate() {
            if let Some(q) = positions.get(v as usize) {
                p += q.coords * b[k];
            }
        }
        Point3::from(p)
    }
}

/// Separable Gaussian blur of a float image (σ in pixels; no-op for σ ≤ 0).
pub fn gaussian_blur(image: &mut [f32], width: usize, height: usize, sigma_px: f64) {
    if sigma_px <= 0.0 || width == 0 || height == 0 {
        return;
    }
    let radius = (3.0 * sigma_px).ceil() as isize;
    let kernel: Vec<f32> = (-radius..=radius)
        .map(|i| (-(i as f64).powi(2) / (2.0 * sigma_px * sigma_px)).exp() as f32)
        .collect();
    let sum: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / sum).collect();
    let mut tmp = vec![0.0f32; image.len()];
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    for y in 0..height {
        for x in 0..width {
            let mut acc = 0.0;
            for (k, w) in kernel.iter().enumerate() {
                let xx = clamp(x as isize + k as isize - radius, width);
                acc += w * image[y * width + xx];
            }
            tmp[y * width + x] = acc;
        }
    }
    for y in 0..height {
        for x in 0..width {
            let mut acc = 0.0;
            for (k, w) in kernel.iter().enumerate() {
                let yy = clamp(y as isize + k as isize - radius, height);
                acc += w * tmp[yy * width + x];
            }
            image[y * width + x] = acc;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Distortion;

    #[test]
    fn square_covers_its_pixels_once_and_nearest_wins() {
        let cam = Camera::new(
            64,
            48,
            [50.0, 50.0, 32.0, 24.0],
            Distortion::Pinhole {
                k: [0.0; 3],
                p: [0.0; 2],
            },
        );
        // A 20 mm square at z = 100 (10 px) and a smaller one in front at z = 50.
        let pts: Vec<Point3<f64>> = vec![
            Point3::new(-10.0, -10.0, 100.0),
            Point3::new(10.0, -10.0, 100.0),
            Point3::new(10.0, 10.0, 100.0),
            Point3::new(-10.0, 10.0, 100.0),
            Point3::new(-2.0, -2.0, 50.0),
            Point3::new(2.0, -2.0, 50.0),
            Point3::new(0.0, 2.0, 50.0),
        ];
        let px: Vec<_> = pts.iter().map(|p| cam.project(&p.coords)).collect();
        let tris = [[0, 1, 2], [0, 2, 3], [4, 5, 6]];
        let f = Fragments::rasterize(&cam, &pts, &px, &tris);
        let covered = f.triangle.iter().filter(|&&t| t != NO_TRIANGLE).count();
        // Pixel centres 27..=37 × 19..=29 lie inside the closed square: 11 × 11.
        assert_eq!(covered, 121);
        assert_eq!(f.triangle[24 * 64 + 32], 2);
        assert!((f.depth[24 * 64 + 32] - 50.0).abs() < 1e-4);
        let normals = vec![Vector3::new(0.0, 0.0, -1.0); pts.len()];
        let (_, p, _) = f.surface(20 * 64 + 30, &tris, &pts, &normals).unwrap();
        assert!((p - Point3::new(-4.0, -8.0, 100.0)).norm() < 1e-5);
    }

    #[test]
    fn blur_keeps_the_mean() {
        let mut img = vec![0.0f32; 30 * 20];
        img[10 * 30 + 15] = 100.0;
        gaussian_blur(&mut img, 30, 20, 1.5);
        let sum: f32 = img.iter().sum();
        assert!((sum - 100.0).abs() < 1e-3);
        assert!(img[10 * 30 + 15] < 10.0);
    }
}
