//! A small software rasterizer for the contact sheet: a solved mesh seen from the front
//! (orthographic, along −z of the head frame: y up, z out of the face), z-buffered, grey
//! Lambert shading from face normals.
//!
//! It exists so that a report needs no GPU, no window and no external renderer; it is
//! meant for thumbnails of a few hundred pixels, not for look development.

use image::{Rgb, RgbImage};
use nalgebra::{Point3, Vector3};

/// Background of a render (dark grey, so a grey face stands out).
pub const BACKGROUND: Rgb<u8> = Rgb([32, 34, 38]);

/// Direction towards the light in the head frame (normalized when used): from the front,
/// a little above and to the viewer's left.
const LIGHT: [f64; 3] = [-0.35, 0.45, 1.0];

/// Share of the light that reaches every face, lit or not.
const AMBIENT: f64 = 0.15;

/// An orthographic front view: head-frame `x` to the right, `y` up; pixels per
/// millimetre and the head-frame point at the image centre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrthoView {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Pixels per millimetre.
    pub scale: f64,
    /// Head-frame `x`, `y` (mm) shown at the image centre.
    pub centre: [f64; 2],
}

impl OrthoView {
    /// The view of a `width × height` image that shows every point of `points` (their
    /// `x`, `y` bounding box), with `margin` (a share of the image, e.g. 0.05) free on the
    /// tighter side. `None` when there is no finite point.
    pub fn fit<'a>(
        points: impl IntoIterator<Item = &'a Point3<f64>>,
        width: u32,
        height: u32,
        margin: f64,
    ) -> Option<Self> {
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in points {
            if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
                continue;
            }
            lo = [lo[0].min(p.x), lo[1].min(p.y)];
            hi = [hi[0].max(p.x), hi[1].max(p.y)];
        }
        if !(lo[0] <= hi[0] && lo[1] <= hi[1]) {
            return None;
        }
        let span = [(hi[0] - lo[0]).max(1e-6), (hi[1] - lo[1]).max(1e-6)];
        let usable = 1.0 - 2.0 * margin.clamp(0.0, 0.45);
        let scale = (f64::from(width) * usable / span[0]).min(f64::from(height) * usable / span[1]);
        Some(Self {
            width,
            height,
            scale,
            centre: [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0],
        })
    }

    /// Pixel coordinates (column, row; continuous, pixel centres at +0.5) of a head-frame
    /// point.
    pub fn project(&self, p: &Point3<f64>) -> [f64; 2] {
        [
            f64::from(self.width) / 2.0 + (p.x - self.centre[0]) * self.scale,
            f64::from(self.height) / 2.0 - (p.y - self.centre[1]) * self.scale,
        ]
    }
}

/// Renders the triangles `triangles` (vertex indices into `positions`, head frame, mm) as
/// seen by `view`: nearest surface per pixel (largest `z`), shaded grey by the angle
/// between its face normal and the light (both sides of a face are lit alike), on
/// [`BACKGROUND`]. Triangles with an index out of range or a non-finite corner are
/// skipped.
pub fn render_mesh(
    positions: &[Point3<f64>],
    triangles: &[[u32; 3]],
    view: &OrthoView,
) -> RgbImage {
    let (w, h) = (view.width as usize, view.height as usize);
    let mut image = RgbImage::from_pixel(view.width, view.height, BACKGROUND);
    let mut depth = vec![f64::NEG_INFINITY; w * h];
    let light = Vector3::from(LIGHT).normalize();
    for tri in triangles {
        let Some(corners) = tri
            .iter()
            .map(|&i| positions.get(i as usize).copied())
            .collect::<Option<Vec<_>>>()
        else {
            continue;
        };
        let (a, b, c) = (corners[0], corners[1], corners[2]);
        if !corners
            .iter()
            .all(|p| p.coords.iter().all(|v| v.is_finite()))
        {
            continue;
        }
        let normal = (b - a).cross(&(c - a));
        let Some(normal) = normal.try_normalize(1e-12) else {
            continue;
        };
        let lambert = normal.dot(&light).abs();
        let level = (255.0 * (AMBIENT + (1.0 - AMBIENT) * lambert))
            .round()
            .clamp(0.0, 255.0) as u8;
        let shade = Rgb([level, level, level]);
        let (pa, pb, pc) = (view.project(&a), view.project(&b), view.project(&c));
        fill_triangle([pa, pb, pc], [a.z, b.z, c.z], shade, &mut image, &mut depth);
    }
    image
}

/// Fills one projected triangle (pixel coordinates `p`, depths `z`, larger is nearer):
/// every pixel whose centre lies inside it (or on an edge) and in front of what the
/// z-buffer holds.
fn fill_triangle(
    p: [[f64; 2]; 3],
    z: [f64; 3],
    shade: Rgb<u8>,
    image: &mut RgbImage,
    depth: &mut [f64],
) {
    let (w, h) = (image.width() as usize, image.height() as usize);
    // Twice the signed area; the edge functions below are divided by it, so either
    // winding works.
    let area = edge(p[0], p[1], p[2]);
    if area.abs() < 1e-12 {
        return;
    }
    let min_x = p
        .iter()
        .map(|q| q[0])
        .fold(f64::INFINITY, f64::min)
        .floor()
        .max(0.0);
    let max_x = p
        .iter()
        .map(|q| q[0])
        .fold(f64::NEG_INFINITY, f64::max)
        .ceil()
        .min(w as f64 - 1.0);
    let min_y = p
        .iter()
        .map(|q| q[1])
        .fold(f64::INFINITY, f64::min)
        .floor()
        .max(0.0);
    let max_y = p
        .iter()
        .map(|q| q[1])
        .fold(f64::NEG_INFINITY, f64::max)
        .ceil()
        .min(h as f64 - 1.0);
    if !(min_x <= max_x && min_y <= max_y) {
        return;
    }
    for y in min_y as usize..=max_y as usize {
        for x in min_x as usize..=max_x as usize {
            let q = [x as f64 + 0.5, y as f64 + 0.5];
            let w0 = edge(p[1], p[2], q) / area;
            let w1 = edge(p[2], p[0], q) / area;
            let w2 = edge(p[0], p[1], q) / area;
            if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                continue;
            }
            let d = w0 * z[0] + w1 * z[1] + w2 * z[2];
            let k = y * w + x;
            if d > depth[k] {
                depth[k] = d;
                image.put_pixel(x as u32, y as u32, shade);
            }
        }
    }
}

/// Twice the signed area of the triangle `a`, `b`, `c` (positive when counter-clockwise in
/// a y-up frame).
fn edge(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Splits polygons given as corner counts and flat corner indices (USD's
/// `faceVertexCounts`, `faceVertexIndices`) into triangles, fanning from each polygon's
/// first corner. Polygons with fewer than 3 corners, and a tail of indices shorter than
/// its count, are skipped.
pub fn fan_triangles(counts: &[u32], indices: &[u32]) -> Vec<[u32; 3]> {
    let mut triangles = Vec::with_capacity(indices.len());
    let mut start = 0usize;
    for &n in counts {
        let n = n as usize;
        let Some(face) = indices.get(start..start + n) else {
            break;
        };
        start += n;
        for k in 1..n.saturating_sub(1) {
            triangles.push([face[0], face[k], face[k + 1]]);
        }
    }
    triangles
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 100 × 100 image of the triangle (0,0), (100,0), (0,100) in mm at 1 px/mm, centred
    /// on (50, 50): the lower-left half of the image, lit straight on.
    #[test]
    fn fills_a_known_triangle() {
        let positions = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(100.0, 0.0, 0.0),
            Point3::new(0.0, 100.0, 0.0),
        ];
        let view = OrthoView {
            width: 100,
            height: 100,
            scale: 1.0,
            centre: [50.0, 50.0],
        };
        let image = render_mesh(&positions, &[[0, 1, 2]], &view);
        let covered = image.pixels().filter(|p| **p != BACKGROUND).count();
        // Half the image, give or take the diagonal's pixels.
        assert!((4900..=5100).contains(&covered), "{covered} pixels filled");
        // Image row 0 is y = 100 mm: its left end is inside (x + y < 100), the right
        // end outside; the bottom-left corner is inside.
        assert_ne!(*image.get_pixel(2, 90), BACKGROUND);
        assert_eq!(*image.get_pixel(97, 2), BACKGROUND);
        assert_ne!(*image.get_pixel(10, 97), BACKGROUND);
        // Facing the viewer, the light's angle sets a mid-to-bright grey.
        let level = image.get_pixel(10, 90)[0];
        let expected = 255.0 * (AMBIENT + (1.0 - AMBIENT) * Vector3::from(LIGHT).normalize().z);
        assert!(
            (f64::from(level) - expected).abs() <= 1.0,
            "{level} vs {expected}"
        );
    }

    /// The nearer of two overlapping triangles wins whatever the drawing order, and a
    /// face seen edge-on draws nothing.
    #[test]
    fn z_buffer_keeps_the_nearest_face() {
        let quad = |z: f64| {
            vec![
                Point3::new(-10.0, -10.0, z),
                Point3::new(10.0, -10.0, z),
                Point3::new(-10.0, 10.0, z),
            ]
        };
        // A tilted far triangle (darker) and a flat near one.
        let mut positions = quad(0.0);
        positions.extend(quad(5.0));
        positions[0].z = -8.0;
        let view = OrthoView::fit(&positions, 40, 40, 0.0).unwrap();
        let near_first = render_mesh(&positions, &[[3, 4, 5], [0, 1, 2]], &view);
        let far_first = render_mesh(&positions, &[[0, 1, 2], [3, 4, 5]], &view);
        assert_eq!(near_first, far_first);
        let flat_only = render_mesh(&positions, &[[3, 4, 5]], &view);
        assert_eq!(near_first, flat_only);
        let edge_on = vec![
            Point3::new(0.0, -10.0, -10.0),
            Point3::new(0.0, 10.0, -10.0),
            Point3::new(0.0, 0.0, 10.0),
        ];
        let image = render_mesh(&edge_on, &[[0, 1, 2]], &view);
        assert!(image.pixels().all(|p| *p == BACKGROUND));
    }

    #[test]
    fn fit_keeps_the_margin_and_fan_splits_polygons() {
        let pts = [Point3::new(0.0, 0.0, 0.0), Point3::new(200.0, 100.0, 0.0)];
        let view = OrthoView::fit(&pts, 100, 100, 0.1).unwrap();
        assert!((view.scale - 0.4).abs() < 1e-12);
        let [x, y] = view.project(&pts[1]);
        assert!(
            (x - 90.0).abs() < 1e-9 && (y - 30.0).abs() < 1e-9,
            "{x} {y}"
        );
        assert!(OrthoView::fit(&[], 10, 10, 0.1).is_none());
        let tris = fan_triangles(&[4, 3, 2], &[0, 1, 2, 3, 4, 5, 6, 7, 8]);
        assert_eq!(tris, vec![[0, 1, 2], [0, 2, 3], [4, 5, 6]]);
    }
}
