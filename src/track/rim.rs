//! Dots a dark band touches: the rim a dot shows, fitted.
//!
//! A dot on a crease, on the mouth line's shadow or on a shading band as dark as its ink
//! is one blob with the band at every contrast threshold of [`super::detect`]: the
//! component is too long to be a dot, and raising the threshold leaves a piece of the dot
//! (its side away from the band, where the local mean is brightest), centred a third of
//! a dot or more from the dot's centre. The band hides only part of the dot's rim: the
//! rest is an edge from dark ink to brighter skin all round the dot, which the band has
//! not. From such a piece, rays are cast all round; on each, the first point where the
//! image brightens outwards by at least [`MIN_EDGE_SLOPE_DN`] levels per pixel (the dot's
//! rim, or where the ray leaves the band, far beyond it) is an edge point, and an ellipse
//! is fitted to the edge points that make one (RANSAC over five-point conics, then least
//! squares on the consensus). The ellipse is reported as a dot (beside the piece: the
//! labeler chooses) when most rays end on it ([`MIN_INLIER_SHARE`]), its points go all
//! round it (no gap wider than [`MAX_GAP_RAD`]), it is a dot's size and shape, larger
//! than the piece, and its inside is ink-dark against the skin beyond its rim.
//!
//! Rays that cross the band find its far edge, beyond the dot, or no edge: they are the
//! outliers the consensus drops. The piece lies inside the dot, so every ray starts in
//! the ink.

use nalgebra::{Matrix5, Point2, Vector5};
use rand::SeedableRng;
use rand::rngs::StdRng;

use super::detect::{DetectParams, Detection};
use crate::capture::GrayImage;

/// Roundest piece looked at: the side of a dot a band cuts off is a cap, wider than
/// deep (a half disc measures 0.53, less of a disc less); a round piece is a whole dot,
/// which the fit would only find again.
const MAX_PIECE_ROUNDNESS: f64 = 0.7;

/// Rays cast from a piece.
const RAYS: usize = 48;

/// Step along a ray, pixels.
const STEP_PX: f64 = 0.5;

/// Least outward slope of an edge point, levels per pixel, on the image smoothed by a
/// 5-tap binomial (σ = 1 px): on cluttered's M100, a smudged dot with a soft rim, rays
/// asking for 6 passed parts of its rim and the fit took the band's far edge instead;
/// with 3 it held the rim in every frame tried.
const MIN_EDGE_SLOPE_DN: f64 = 3.0;

/// How far an edge point may be from the ellipse (Sampson distance) and count for it,
/// pixels.
const INLIER_PX: f64 = 1.0;

/// Least share of the rays whose edge points lie on the ellipse.
const MIN_INLIER_SHARE: f64 = 0.6;

/// Widest gap between the ellipse's edge points around its centre, radians: the band
/// may hide a third of the rim, not more (a rim seen over less is not told from an arc of
/// something else).
const MAX_GAP_RAD: f64 = 2.0 * std::f64::consts::FRAC_PI_3;

/// Least area of the ellipse, in units of the piece's area: smaller, the piece is the dot
/// (`detect` counts on this value to skip pieces of short components).
pub(super) const MIN_AREA_GAIN: f64 = 1.5;

/// Longest ellipse, in units of the piece's diameter: a piece is a third of the dot
/// across or more. A dot narrower than the band it touches leaves a small piece, and the
/// ellipse through its rim and the band's far edge is long against it: not taken.
const MAX_LENGTH_GAIN: f64 = 2.5;

/// Shortest reach of the rays, pixels.
const MIN_REACH_PX: f64 = 8.0;

/// RANSAC draws of five edge points.
const DRAWS: usize = 64;

/// A conic that this share of the edge points lie on ends the draws.
const ENOUGH_INLIERS: f64 = 0.9;

/// Seed of the RANSAC draws: the same image gives the same dot.
const RANSAC_SEED: u64 = 0x0072_696d;

/// Least contrast of the ellipse's inside against the skin beyond its rim, in units of
/// [`DetectParams::min_peak_contrast_dn`]: ink (the mean of the inside, not its darkest
/// pixel).
const MIN_CONTRAST_FACTOR: f64 = 2.0;

/// The dot whose rim the piece `piece` (a part of a component too long or too large to be
/// a dot, split off it) lies inside, if the rim around it is a dot's (see the module
/// docs); `params` as `piece` was detected with. Dots up to `longest_px` long (and
/// `1.25 × max_dot_px`) are looked for.
pub(super) fn dot_by_its_rim(
    image: &GrayImage,
    params: &DetectParams,
    piece: &Detection,
    longest_px: f64,
) -> Option<Detection> {
    let seed = piece.centre_px;
    let looked_at = seed.x.is_finite()
        && seed.y.is_finite()
        && piece.diameter_px.is_finite()
        && piece.roundness < MAX_PIECE_ROUNDNESS;
    if !looked_at {
        return None;
    }
    let longest = (1.25 * params.max_dot_px.clamp(1.0, 400.0)).min(longest_px);
    if longest.is_nan() || longest < 2.0 {
        return None;
    }
    // The rays reach the far rim of any dot taken: the seed lies inside the dot, so no
    // point of its rim is further from it than its length (at most `MAX_LENGTH_GAIN`
    // pieces' diameters and `longest`), and an edge point on it is within `INLIER_PX` of
    // the rim.
    let reach = (MAX_LENGTH_GAIN * piece.diameter_px)
        .min(longest)
        .max(MIN_REACH_PX)
        + INLIER_PX;
    let sign = if params.bright { -1.0 } else { 1.0 };
    let slopes = Slopes::around(image, seed, reach + 2.0)?;
    let edges = edge_points(&slopes, seed, reach, sign);
    if (edges.len() as f64) < MIN_INLIER_SHARE * RAYS as f64 {
        return None;
    }
    // Conics fitted in units of the reach, centred on the seed: `A x² + B xy + C y² + D x
    // + E y = 1` (the seed, at the origin, is inside any ellipse of this form).
    let unit: Vec<(f64, f64)> = edges
        .iter()
        .map(|p| ((p.x - seed.x) / reach, (p.y - seed.y) / reach))
        .collect();
    let tolerance = INLIER_PX / reach;
    let mut rng = StdRng::seed_from_u64(RANSAC_SEED);
    let mut best: Option<(Conic, usize)> = None;
    for _ in 0..DRAWS {
        let draw = rand::seq::index::sample(&mut rng, unit.len(), 5);
        let five: Vec<(f64, f64)> = draw.iter().map(|i| unit[i]).collect();
        let Some(conic) = Conic::fit(&five) else {
            continue;
        };
        let Some(e) = conic.ellipse() else {
            continue;
        };
        if e.semi_major > 1.0 {
            continue;
        }
        let n = conic.inliers(&unit, tolerance).count();
        if best.as_ref().is_none_or(|b| n > b.1) {
            best = Some((conic, n));
        }
        if n as f64 >= ENOUGH_INLIERS * unit.len() as f64 {
            break;
        }
    }
    let (mut conic, _) = best?;
    for _ in 0..2 {
        let on: Vec<(f64, f64)> = conic.inliers(&unit, tolerance).collect();
        conic = Conic::fit(&on)?;
    }
    let on: Vec<(f64, f64)> = conic.inliers(&unit, tolerance).collect();
    let e = conic.ellipse()?;
    if (on.len() as f64) < MIN_INLIER_SHARE * RAYS as f64 {
        return None;
    }
    // Back in pixels.
    let centre = Point2::new(seed.x + e.centre.0 * reach, seed.y + e.centre.1 * reach);
    let (a, b) = (e.semi_major * reach, e.semi_minor * reach);
    let min_dot = params.min_dot_px.max(2.0);
    if !(2.0 * a <= longest && 2.0 * b >= min_dot && b >= params.min_roundness * a) {
        return None;
    }
    if std::f64::consts::PI * a * b < MIN_AREA_GAIN * piece.area_px as f64
        || 2.0 * a > MAX_LENGTH_GAIN * piece.diameter_px
    {
        return None;
    }
    let angles: Vec<f64> = on
        .iter()
        .map(|&(x, y)| (y - e.centre.1).atan2(x - e.centre.0))
        .collect();
    if widest_gap(angles) > MAX_GAP_RAD {
        return None;
    }
    let contrast_dn = inside_contrast(image, centre, &e, reach, &on, seed, sign)?;
    if contrast_dn < MIN_CONTRAST_FACTOR * params.min_peak_contrast_dn {
        return None;
    }
    let roundness = b / a;
    Some(Detection {
        centre_px: centre,
        area_px: (std::f64::consts::PI * a * b).round() as usize,
        roundness,
        contrast_dn,
        // Ranked (for the acquisition's share of detections) no higher than its piece: a
        // fit is less sure than a blob, and the fits ranked above it pushed whole dots out.
        quality: piece
            .quality
            .min((roundness * (contrast_dn / (contrast_dn + 40.0))).clamp(0.0, 1.0)),
        diameter_px: 2.0 * a,
        axis_rad: e.axis_rad,
        streak: false,
    })
}

/// The image's gradient around a point, on the image smoothed by a 5-tap binomial
/// (`[1, 4, 6, 4, 1] / 16` along each axis), by central differences: levels per pixel.
struct Slopes {
    /// The window's first column and row in the image.
    x0: usize,
    y0: usize,
    /// The window's size.
    w: usize,
    h: usize,
    /// `∂I/∂x` and `∂I/∂y`, row by row.
    gx: Vec<f32>,
    gy: Vec<f32>,
}

impl Slopes {
    /// The gradient within `radius` of `centre` (clipped to the image); None when less than
    /// 5×5 pixels of it are in the image.
    fn around(image: &GrayImage, centre: Point2<f64>, radius: f64) -> Option<Self> {
        let (iw, ih) = (image.width as usize, image.height as usize);
        let lo = |v: f64| (v - radius).floor().max(0.0) as usize;
        let hi = |v: f64, n: usize| ((v + radius).ceil().max(0.0) as usize + 1).min(n);
        let (x0, y0, x1, y1) = (
            lo(centre.x),
            lo(centre.y),
            hi(centre.x, iw),
            hi(centre.y, ih),
        );
        if x1 < x0 + 5 || y1 < y0 + 5 {
            return None;
        }
        let (w, h) = (x1 - x0, y1 - y0);
        // The smoothing of the window grown by a pixel (for the differences) reads two
        // pixels more, clamped at the image's edges: each row of that, filtered along x
        // (sums ×16), then along y (×256).
        let (gx0, gy0) = (x0 as isize - 3, y0 as isize - 3);
        let (gw, gh) = (w + 2, h + 6);
        let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
        let mut line = vec![0u16; gw + 4];
        let mut rows = vec![0u16; gw * gh];
        for y in 0..gh {
            let row = clamp(gy0 + y as isize, ih) * iw;
            if gx0 >= 0 && gx0 as usize + line.len() <= iw {
                let start = row + gx0 as usize;
                for (v, &p) in line.iter_mut().zip(&image.data[start..start + gw + 4]) {
                    *v = u16::from(p);
                }
            } else {
                for (k, v) in line.iter_mut().enumerate() {
                    *v = u16::from(image.data[row + clamp(gx0 + k as isize, iw)]);
                }
            }
            for (x, out) in rows[y * gw..(y + 1) * gw].iter_mut().enumerate() {
                let l = &line[x..x + 5];
                *out = l[0] + 4 * l[1] + 6 * l[2] + 4 * l[3] + l[4];
            }
        }
        let (sw, sh) = (gw, h + 2);
        let mut smooth = vec![0u32; sw * sh];
        for y in 0..sh {
            let r = |k: usize| &rows[(y + k) * gw..(y + k + 1) * gw];
            let (a, b, c, d, e) = (r(0), r(1), r(2), r(3), r(4));
            for (x, out) in smooth[y * sw..(y + 1) * sw].iter_mut().enumerate() {
                *out = u32::from(a[x])
                    + 4 * u32::from(b[x])
                    + 6 * u32::from(c[x])
                    + 4 * u32::from(d[x])
                    + u32::from(e[x]);
            }
        }
        // Central differences, levels per pixel.
        let scale = 0.5 / 256.0;
        let mut gx = vec![0f32; w * h];
        let mut gy = vec![0f32; w * h];
        for y in 0..h {
            let (above, here, below) = (
                &smooth[y * sw..(y + 1) * sw],
                &smooth[(y + 1) * sw..(y + 2) * sw],
                &smooth[(y + 2) * sw..(y + 3) * sw],
            );
            for x in 0..w {
                gx[y * w + x] = (here[x + 2] as f32 - here[x] as f32) * scale;
                gy[y * w + x] = (below[x + 1] as f32 - above[x + 1] as f32) * scale;
            }
        }
        Some(Self {
            x0,
            y0,
            w,
            h,
            gx,
            gy,
        })
    }

    /// The gradient at `(x, y)` (bilinear), None outside the window.
    fn at(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let (u, v) = (x - self.x0 as f64, y - self.y0 as f64);
        if !(u >= 0.0 && v >= 0.0 && u <= (self.w - 1) as f64 && v <= (self.h - 1) as f64) {
            return None;
        }
        let (i, j) = ((u as usize).min(self.w - 2), (v as usize).min(self.h - 2));
        let (fu, fv) = (u - i as f64, v - j as f64);
        let k = j * self.w + i;
        let mix = |g: &[f32]| {
            let (a, b, c, d) = (
                f64::from(g[k]),
                f64::from(g[k + 1]),
                f64::from(g[k + self.w]),
                f64::from(g[k + self.w + 1]),
            );
            (a * (1.0 - fu) + b * fu) * (1.0 - fv) + (c * (1.0 - fu) + d * fu) * fv
        };
        Some((mix(&self.gx), mix(&self.gy)))
    }
}

/// The first edge point of each ray from `seed` out to `reach` (see the module docs):
/// the first local maximum of the outward slope (times `sign`: −1 for bright dots) of at
/// least [`MIN_EDGE_SLOPE_DN`], placed at the vertex of the parabola through it and its
/// neighbours.
fn edge_points(slopes: &Slopes, seed: Point2<f64>, reach: f64, sign: f64) -> Vec<Point2<f64>> {
    let steps = (reach / STEP_PX).floor() as usize;
    let mut out = Vec::with_capacity(RAYS);
    for k in 0..RAYS {
        let t = std::f64::consts::TAU * k as f64 / RAYS as f64;
        let (dx, dy) = (t.cos(), t.sin());
        let slope = |i: usize| {
            let r = 1.0 + i as f64 * STEP_PX;
            slopes
                .at(seed.x + r * dx, seed.y + r * dy)
                .map(|(gx, gy)| sign * (gx * dx + gy * dy))
        };
        // The last three slopes along the ray, stepping out until the middle one is the
        // edge (or the ray ends).
        let (Some(mut a), Some(mut b)) = (slope(0), slope(1)) else {
            continue;
        };
        for i in 2..steps {
            let Some(c) = slope(i) else {
                break;
            };
            if b >= MIN_EDGE_SLOPE_DN && b >= a && b >= c {
                let curvature = a - 2.0 * b + c;
                let shift = if curvature < 0.0 {
                    (0.5 * (a - c) / curvature).clamp(-0.5, 0.5)
                } else {
                    0.0
                };
                let r = 1.0 + (i as f64 - 1.0 + shift) * STEP_PX;
                out.push(Point2::new(seed.x + r * dx, seed.y + r * dy));
                break;
            }
            (a, b) = (b, c);
        }
    }
    out
}

/// The widest gap between consecutive angles around the circle, radians.
fn widest_gap(mut angles: Vec<f64>) -> f64 {
    if angles.is_empty() {
        return std::f64::consts::TAU;
    }
    angles.sort_by(f64::total_cmp);
    let wrap = angles[0] + std::f64::consts::TAU - angles[angles.len() - 1];
    angles.windows(2).map(|w| w[1] - w[0]).fold(wrap, f64::max)
}

/// How much darker (`sign` −1: brighter) the ellipse's inside is than the skin beyond its
/// rim: the median of the image 1.5 px beyond each edge point on it (along its ray from
/// `seed`) less the mean over the ellipse shrunk to half its size (16 points on its rim
/// and the centre). `on` and `e` in units of `reach` around `seed`; None when a sample
/// falls outside the image.
fn inside_contrast(
    image: &GrayImage,
    centre: Point2<f64>,
    e: &Ellipse,
    reach: f64,
    on: &[(f64, f64)],
    seed: Point2<f64>,
    sign: f64,
) -> Option<f64> {
    let (ca, sa) = (e.axis_rad.cos(), e.axis_rad.sin());
    let (a, b) = (0.5 * e.semi_major * reach, 0.5 * e.semi_minor * reach);
    let mut inside = vec![image.bilinear(centre.x, centre.y)?];
    for k in 0..16 {
        let t = std::f64::consts::TAU * k as f64 / 16.0;
        let (u, v) = (a * t.cos(), b * t.sin());
        inside.push(image.bilinear(centre.x + u * ca - v * sa, centre.y + u * sa + v * ca)?);
    }
    let inside = inside.iter().sum::<f64>() / inside.len() as f64;
    let mut beyond = Vec::with_capacity(on.len());
    for &(x, y) in on {
        let r = x.hypot(y) * reach;
        if r <= 0.0 {
            continue;
        }
        let (dx, dy) = (x * reach / r, y * reach / r);
        beyond.push(image.bilinear(seed.x + (r + 1.5) * dx, seed.y + (r + 1.5) * dy)?);
    }
    if beyond.is_empty() {
        return None;
    }
    beyond.sort_by(f64::total_cmp);
    Some(sign * (beyond[beyond.len() / 2] - inside))
}

/// A conic `A x² + B xy + C y² + D x + E y = 1`.
#[derive(Debug, Clone, Copy)]
struct Conic([f64; 5]);

/// An ellipse: centre, semi-axes, direction of the major axis (radians from +x towards
/// +y, in `[−π/2, π/2]`).
#[derive(Debug, Clone, Copy)]
struct Ellipse {
    centre: (f64, f64),
    semi_major: f64,
    semi_minor: f64,
    axis_rad: f64,
}

impl Conic {
    /// The least-squares conic through at least five points (exact through five), None
    /// when they do not determine one.
    fn fit(points: &[(f64, f64)]) -> Option<Self> {
        if points.len() < 5 {
            return None;
        }
        let mut normal = Matrix5::<f64>::zeros();
        let mut rhs = Vector5::<f64>::zeros();
        for &(x, y) in points {
            let row = Vector5::new(x * x, x * y, y * y, x, y);
            normal += row * row.transpose();
            rhs += row;
        }
        let c = normal.lu().solve(&rhs)?;
        c.iter()
            .all(|v| v.is_finite())
            .then(|| Self([c[0], c[1], c[2], c[3], c[4]]))
    }

    /// The points within `tolerance` of the conic: their Sampson distance (the algebraic
    /// distance over the gradient's length, the geometric distance to first order),
    /// compared squared.
    fn inliers<'a>(
        &'a self,
        points: &'a [(f64, f64)],
        tolerance: f64,
    ) -> impl Iterator<Item = (f64, f64)> + 'a {
        let [a, b, c, d, e] = self.0;
        let squared = tolerance * tolerance;
        points.iter().copied().filter(move |&(x, y)| {
            let q = a * x * x + b * x * y + c * y * y + d * x + e * y - 1.0;
            let gx = 2.0 * a * x + b * y + d;
            let gy = b * x + 2.0 * c * y + e;
            q * q <= squared * (gx * gx + gy * gy)
        })
    }

    /// The conic as an ellipse, None when it is none (or a degenerate one).
    fn ellipse(&self) -> Option<Ellipse> {
        let [a, b, c, d, e] = self.0;
        // Quadratic form M = [[a, b/2], [b/2, c]], positive definite for an ellipse whose
        // inside (the origin's side) is where the form is below 1.
        let det = a * c - 0.25 * b * b;
        if !(a > 0.0 && det > 0.0) {
            return None;
        }
        // Centre −½ M⁻¹ (d, e).
        let (ix, iy) = ((c * d - 0.5 * b * e) / det, (a * e - 0.5 * b * d) / det);
        let centre = (-0.5 * ix, -0.5 * iy);
        // The form at the centre: 1 + ¼ (d, e)ᵀ M⁻¹ (d, e).
        let k = 1.0 + 0.25 * (d * ix + e * iy);
        let mean = 0.5 * (a + c);
        let spread = (0.25 * (a - c).powi(2) + 0.25 * b * b).sqrt();
        let (l_small, l_large) = (mean - spread, mean + spread);
        if !(l_small > 0.0 && k > 0.0) {
            return None;
        }
        let semi_major = (k / l_small).sqrt();
        let semi_minor = (k / l_large).sqrt();
        // The major axis is the eigenvector of the smaller eigenvalue.
        let mut axis_rad = if b.abs() < 1e-15 && a <= c {
            0.0
        } else if b.abs() < 1e-15 {
            std::f64::consts::FRAC_PI_2
        } else {
            (l_small - a).atan2(0.5 * b)
        };
        if axis_rad > std::f64::consts::FRAC_PI_2 {
            axis_rad -= std::f64::consts::PI;
        } else if axis_rad < -std::f64::consts::FRAC_PI_2 {
            axis_rad += std::f64::consts::PI;
        }
        (semi_major.is_finite() && semi_minor > 0.0).then_some(Ellipse {
            centre,
            semi_major,
            semi_minor,
            axis_rad,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::detect::{detect_markers, pgm_image};

    /// An image lit from above (the light falls from 200 to 120 levels down the image),
    /// with a dark band of skin (a crease: 40 % of the light, edges one pixel soft) along
    /// rows `band.0..band.1`, and ink ellipses `(cx, cy, semi-major, semi-minor, angle)`
    /// reflecting 45 % of the light; antialiased by 4×4 supersampling.
    fn image_with_band(band: (f64, f64), dots: &[(f64, f64, f64, f64, f64)]) -> GrayImage {
        let (w, h) = (200u32, 120u32);
        let mut data = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let mut sum = 0.0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let (px, py) = (
                            f64::from(x) + (f64::from(sx) + 0.5) / 4.0 - 0.5,
                            f64::from(y) + (f64::from(sy) + 0.5) / 4.0 - 0.5,
                        );
                        // The band's shadow: the light falls by half over the 12 px above it.
                        let shade = ((band.0 - py) / 12.0).clamp(0.0, 1.0);
                        let light = (200.0 - 80.0 * py / f64::from(h)) * (0.5 + 0.5 * shade);
                        let inside_band = (py - band.0).min(band.1 - py).clamp(-0.5, 0.5) + 0.5;
                        let mut reflect = 1.0 - 0.55 * inside_band;
                        for &(cx, cy, a, b, t) in dots {
                            let (dx, dy) = (px - cx, py - cy);
                            let (u, v) =
                                (dx * t.cos() + dy * t.sin(), -dx * t.sin() + dy * t.cos());
                            if (u / a).powi(2) + (v / b).powi(2) <= 1.0 {
                                reflect = reflect.min(0.45);
                            }
                        }
                        sum += light * reflect;
                    }
                }
                data.push((sum / 16.0).round().clamp(0.0, 255.0) as u8);
            }
        }
        GrayImage {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn fits_dots_a_dark_band_touches_from_a_piece_of_them() {
        let p = DetectParams::default();
        let mut found = 0;
        // Dots 10-22 px across, round and foreshortened at several angles, each reaching
        // 1.6 px into the band (rows 70-77) under the band's shadow; the piece the
        // threshold leaves is their upper side: a cap half the dot's length across
        // (roundness 0.5), centred half way to the dot's top.
        for &(a, b, t) in &[
            (9.0, 7.0, std::f64::consts::FRAC_PI_2),
            (9.0, 7.0, 0.0),
            (6.0, 5.0, 0.5),
            (11.0, 8.0, 1.2),
            (7.0, 7.0, 0.0),
            (10.0, 6.0, 2.3),
        ] {
            // How far the dot reaches down from its centre.
            let reach_y = ((a * t.sin()).powi(2) + (b * t.cos()).powi(2)).sqrt();
            let (cx, cy) = (100.3, 71.6 - reach_y);
            let image = image_with_band((70.0, 78.0), &[(cx, cy, a, b, t)]);
            let piece = Detection {
                centre_px: Point2::new(cx + 0.4, cy - 0.5 * reach_y),
                area_px: (std::f64::consts::PI * a * a / 4.0).round() as usize,
                roundness: 0.5,
                contrast_dn: 60.0,
                quality: 0.5,
                diameter_px: a,
                axis_rad: 0.0,
                streak: false,
            };
            // A round piece is a whole dot: not looked at.
            let round = Detection {
                roundness: 0.8,
                ..piece
            };
            assert!(dot_by_its_rim(&image, &p, &round, f64::INFINITY).is_none());
            // Not looked for in a band too short for it (`longest_px` under its length).
            assert!(dot_by_its_rim(&image, &p, &piece, 2.0 * a - 2.0).is_none());
            // Found at its centre, or not at all.
            if let Some(dot) = dot_by_its_rim(&image, &p, &piece, f64::INFINITY) {
                assert!(
                    (dot.centre_px - Point2::new(cx, cy)).norm() <= 0.6,
                    "dot {a}×{b} at {t} rad: {dot:?}"
                );
                assert!(
                    (dot.diameter_px - 2.0 * a).abs() <= 2.0,
                    "dot {a}×{b}: {dot:?}"
                );
                found += 1;
            }
        }
        assert!(found >= 5, "{found} of 6 found");
    }

    #[test]
    fn a_band_alone_or_with_freckles_on_its_edge_makes_no_dot() {
        let p = DetectParams::default();
        // Seeds on a plain band: no rim around them.
        let image = image_with_band((70.0, 78.0), &[]);
        for x in [40.0, 100.0, 160.0] {
            let piece = Detection {
                centre_px: Point2::new(x, 73.5),
                area_px: 20,
                roundness: 0.5,
                contrast_dn: 60.0,
                quality: 0.5,
                diameter_px: 6.0,
                axis_rad: 0.0,
                streak: false,
            };
            assert!(
                dot_by_its_rim(&image, &p, &piece, f64::INFINITY).is_none(),
                "at {x}"
            );
        }
        // Freckles 4-5 px across on the band's edge: nothing larger than them is found.
        let freckles = [
            (50.0, 69.5, 2.5, 2.0, 0.0),
            (100.0, 69.0, 2.0, 2.0, 0.0),
            (150.0, 69.8, 2.5, 2.5, 0.0),
        ];
        let image = image_with_band((70.0, 78.0), &freckles);
        // Fitted from a cap of each freckle: no dot (the freckle and the band make no
        // ellipse a dot's rim would).
        for &(x, y, a, _, _) in &freckles {
            let piece = Detection {
                centre_px: Point2::new(x, y - 0.5 * a),
                area_px: 8,
                roundness: 0.5,
                contrast_dn: 60.0,
                quality: 0.3,
                diameter_px: 2.0 * a,
                axis_rad: 0.0,
                streak: false,
            };
            assert!(
                dot_by_its_rim(&image, &p, &piece, f64::INFINITY).is_none(),
                "freckle at {x}"
            );
        }
        let found = detect_markers(&image, &p);
        assert!(found.iter().all(|d| d.diameter_px <= 8.0), "{found:?}");
    }

    #[test]
    fn finds_a_smudged_dot_touching_the_mouth_line() {
        // An 84×84 crop of the `cluttered` preset's cam0, frame 0 (default seed), around
        // M100: a smudged dot whose lower rim lies in the shadow of the mouth line, as
        // dark as its ink. Its ink spans columns 36-49 and rows 32-49 of the crop: centre
        // (42.5, 40.5); the marker's own point, (42.69, 42.03), is lower (the smudge). The
        // detector found only a piece of its upper side, 9 px across and 4.5 px off,
        // and the labeler missed M100 in its first 15 frames.
        let image = pgm_image(
            include_bytes!("testdata/dot_touching_the_mouth_line.pgm"),
            84,
        );
        let found = detect_markers(&image, &DetectParams::default());
        let ink = Point2::new(42.5, 40.5);
        let near: Vec<&Detection> = found
            .iter()
            .filter(|d| (d.centre_px - ink).norm() <= 1.0)
            .collect();
        assert_eq!(near.len(), 1, "{found:?}");
        assert!(
            (16.0..=20.0).contains(&near[0].diameter_px),
            "{:?}",
            near[0]
        );
        assert!((near[0].centre_px - Point2::new(42.69, 42.03)).norm() <= 2.5);
    }

    #[test]
    fn a_conic_through_points_of_an_ellipse_is_that_ellipse() {
        let (cx, cy, a, b, t) = (0.2, -0.1, 0.6, 0.35, 0.7_f64);
        let points: Vec<(f64, f64)> = (0..12)
            .map(|k| {
                let s = std::f64::consts::TAU * f64::from(k) / 12.0;
                let (u, v) = (a * s.cos(), b * s.sin());
                (
                    cx + u * t.cos() - v * t.sin(),
                    cy + u * t.sin() + v * t.cos(),
                )
            })
            .collect();
        let e = Conic::fit(&points).and_then(|c| c.ellipse()).unwrap();
        assert!((e.centre.0 - cx).abs() < 1e-9 && (e.centre.1 - cy).abs() < 1e-9);
        assert!((e.semi_major - a).abs() < 1e-9 && (e.semi_minor - b).abs() < 1e-9);
        assert!((e.axis_rad - t).abs() < 1e-9, "{e:?}");
        assert!(widest_gap(vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]) > 1.28);
        assert!(widest_gap(vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]) < 1.29);
    }
}
