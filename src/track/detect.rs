//! Marker detection: painted dots on skin, found by local-contrast thresholding.
//!
//! 1. Local mean `μ(x)` over a `(2r+1)²` box (running column sums), so uneven light
//!    cancels.
//! 2. Candidate pixels: `μ(x) − I(x) ≥ c` for dark dots (`I(x) − μ(x) ≥ c` for bright).
//! 3. 8-connected components of candidates, within the region of interest and mask. A
//!    component that fails the filters of step 4 (a dot touching a dark crease or the
//!    shading at the face's edge) is split by raising the contrast threshold, up to four
//!    times (the nested regions of MSER, Matas et al. 2002).
//! 4. Filters: area, roundness `√(λ_min/λ_max)` of the second moments, and contrast against
//!    the median of a ring of background around the blob (which rejects the dark halo that a
//!    specular highlight leaves in the local mean, and soft shading gradients).
//! 5. Subpixel centre: centroid weighted by `max(0, B − I)` (`B` the ring median) over the
//!    blob's box grown by two pixels, so the antialiased rim counts.

use nalgebra::Point2;

use crate::capture::GrayImage;

/// Detection settings.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectParams {
    /// Look for bright dots instead of dark ones. Default false.
    pub bright: bool,
    /// Half-size `r` of the local-mean box, pixels. Default 8.
    pub window_radius_px: u32,
    /// Minimum local contrast `c` of a candidate pixel, 8-bit levels. Default 8.
    pub min_contrast_dn: u32,
    /// Minimum contrast of the darkest blob pixel against the background ring, levels.
    /// Default 15.
    pub min_peak_contrast_dn: f64,
    /// Smallest blob area, pixels. Default 3.
    pub min_area_px: usize,
    /// Largest blob area, pixels. Default 300.
    pub max_area_px: usize,
    /// Smallest roundness `√(λ_min/λ_max)` (1: a disc; foreshortened dots on the sides of
    /// the face reach 0.3). Default 0.3.
    pub min_roundness: f64,
    /// Region of interest `(x0, y0, x1, y1)`, pixels, end exclusive (None: whole image).
    pub roi: Option<(u32, u32, u32, u32)>,
}

impl Default for DetectParams {
    fn default() -> Self {
        Self {
            bright: false,
            window_radius_px: 8,
            min_contrast_dn: 8,
            min_peak_contrast_dn: 15.0,
            min_area_px: 3,
            max_area_px: 300,
            min_roundness: 0.3,
            roi: None,
        }
    }
}

impl DetectParams {
    /// Checks every field.
    ///
    /// # Errors
    /// A message naming the field.
    pub fn validate(&self) -> Result<(), String> {
        if self.window_radius_px == 0 || self.window_radius_px > 100 {
            return Err("window_radius_px must be in 1..=100".into());
        }
        if self.min_contrast_dn == 0 || self.min_contrast_dn > 255 {
            return Err("min_contrast_dn must be in 1..=255".into());
        }
        if self.min_area_px == 0 || self.min_area_px > self.max_area_px {
            return Err("need 0 < min_area_px <= max_area_px".into());
        }
        if !(0.0..=1.0).contains(&self.min_roundness) {
            return Err("min_roundness must be in [0, 1]".into());
        }
        if let Some((x0, y0, x1, y1)) = self.roi
            && (x0 >= x1 || y0 >= y1)
        {
            return Err("roi must have x0 < x1 and y0 < y1".into());
        }
        Ok(())
    }
}

/// One detected dot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// Subpixel centre, pixels (pixel centres at integers).
    pub centre_px: Point2<f64>,
    /// Blob area, pixels.
    pub area_px: usize,
    /// Roundness `√(λ_min/λ_max)`, 0..1.
    pub roundness: f64,
    /// Contrast of the darkest (brightest) pixel against the background ring, levels.
    pub contrast_dn: f64,
    /// Quality 0..1: roundness × contrast / (contrast + 40).
    pub quality: f64,
}

/// Finds the dots in `image` (see the module docs).
pub fn detect_markers(image: &GrayImage, params: &DetectParams) -> Vec<Detection> {
    let (w, h) = (image.width as usize, image.height as usize);
    if w == 0 || h == 0 || image.data.len() != w * h {
        return Vec::new();
    }
    let (x0, y0, x1, y1) = params.roi.map_or((0, 0, w, h), |(a, b, c, d)| {
        (
            a as usize,
            b as usize,
            (c as usize).min(w),
            (d as usize).min(h),
        )
    });
    if x0 >= x1 || y0 >= y1 {
        return Vec::new();
    }
    let r = params.window_radius_px as usize;
    // Box sums over the ROI grown by r (clamped): column sums over the window's rows, kept
    // incrementally from row to row, and a prefix sum of them along each row.
    let gx0 = x0.saturating_sub(r);
    let gy0 = y0.saturating_sub(r);
    let gx1 = (x1 + r).min(w);
    let gy1 = (y1 + r).min(h);
    let rw = gx1 - gx0;
    let bw = x1 - x0;
    let bh = y1 - y0;
    let c = params.min_contrast_dn;
    // Local contrast of candidate pixels (0: not a candidate), saturated at 255.
    let mut mask = vec![0u8; bw * bh];
    let mut col = vec![0u32; rw];
    let mut prefix = vec![0u32; rw + 1];
    let (mut ya_prev, mut yb_prev) = (gy0, gy0);
    for y in y0..y1 {
        let ya = y.saturating_sub(r).max(gy0);
        let yb = (y + r + 1).min(gy1);
        for yy in yb_prev..yb {
            let row = &image.data[yy * w + gx0..yy * w + gx1];
            col.iter_mut()
                .zip(row)
                .for_each(|(s, &v)| *s += u32::from(v));
        }
        for yy in ya_prev..ya {
            let row = &image.data[yy * w + gx0..yy * w + gx1];
            col.iter_mut()
                .zip(row)
                .for_each(|(s, &v)| *s -= u32::from(v));
        }
        (ya_prev, yb_prev) = (ya, yb);
        let mut acc = 0u32;
        for (p, &s) in prefix[1..].iter_mut().zip(&col) {
            acc += s;
            *p = acc;
        }
        let rows = (yb - ya) as u32;
        let img_row = &image.data[y * w + x0..y * w + x1];
        let mask_row = &mut mask[(y - y0) * bw..(y - y0 + 1) * bw];
        for (k, (&v, m)) in img_row.iter().zip(mask_row.iter_mut()).enumerate() {
            let x = x0 + k;
            let xa = x.saturating_sub(r).max(gx0) - gx0;
            let xb = (x + r + 1).min(gx1) - gx0;
            let area = (xb - xa) as u32 * rows;
            let sum = prefix[xb] - prefix[xa];
            let v = u32::from(v) * area;
            let diff = if params.bright {
                v.checked_sub(sum)
            } else {
                sum.checked_sub(v)
            };
            *m = match diff {
                Some(d) if d >= c * area => (d / area).clamp(1, 255) as u8,
                _ => 0,
            };
        }
    }
    // Connected components (8-connectivity) by flood fill.
    let mut out = Vec::new();
    let mut stack = Vec::new();
    let mut pixels: Vec<(usize, usize, u8)> = Vec::new();
    for start in 0..mask.len() {
        if mask[start] == 0 {
            continue;
        }
        let level = mask[start];
        mask[start] = 0;
        stack.push((start, level));
        pixels.clear();
        while let Some((i, lv)) = stack.pop() {
            let (x, y) = (i % bw, i / bw);
            if pixels.len() < MAX_COMPONENT_PX {
                pixels.push((x + x0, y + y0, lv));
            }
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let nx = x as i64 + dx;
                    let ny = y as i64 + dy;
                    if nx < 0 || ny < 0 || nx >= bw as i64 || ny >= bh as i64 {
                        continue;
                    }
                    let j = ny as usize * bw + nx as usize;
                    if mask[j] != 0 {
                        stack.push((j, mask[j]));
                        mask[j] = 0;
                    }
                }
            }
        }
        split_and_measure(image, &pixels, c, 0, params, &mut out);
    }
    out
}

/// Largest component kept whole for splitting, pixels.
const MAX_COMPONENT_PX: usize = 20_000;

/// Smallest roundness of a dot found by splitting a component.
const SPLIT_MIN_ROUNDNESS: f64 = 0.3;

/// Smallest peak contrast of a dot found by splitting a component, in units of
/// [`DetectParams::min_peak_contrast_dn`] (ink is much darker than a crease).
const SPLIT_MIN_CONTRAST_FACTOR: f64 = 2.0;

/// Smallest area of a dot found by splitting a component, in units of
/// [`DetectParams::min_area_px`].
const SPLIT_MIN_AREA_FACTOR: usize = 2;

/// Measures a component of candidate pixels `(x, y, contrast)`; when it is too big or not
/// round (a dot touching a dark shading band or crease), splits it by raising the contrast
/// threshold (×1.6 per level, up to 4 levels) and measures the parts: dots inside
/// uneven shading are found like MSER regions.
fn split_and_measure(
    image: &GrayImage,
    pixels: &[(usize, usize, u8)],
    threshold: u32,
    depth: usize,
    params: &DetectParams,
    out: &mut Vec<Detection>,
) {
    if pixels.len() < params.min_area_px {
        return;
    }
    if pixels.len() <= params.max_area_px {
        let xy: Vec<(usize, usize)> = pixels.iter().map(|&(x, y, _)| (x, y)).collect();
        let found = if depth == 0 {
            measure_blob(image, &xy, params)
        } else {
            // Parts of a split component: only clearly round dots of some size (the
            // fragments of a crease are small and thin).
            measure_blob(image, &xy, params).filter(|d| {
                d.roundness >= SPLIT_MIN_ROUNDNESS
                    && d.area_px >= SPLIT_MIN_AREA_FACTOR * params.min_area_px
                    && d.contrast_dn >= SPLIT_MIN_CONTRAST_FACTOR * params.min_peak_contrast_dn
            })
        };
        if let Some(d) = found {
            out.push(d);
            return;
        }
    }
    if depth >= 4 {
        return;
    }
    let next = (threshold as f64 * 1.6).ceil() as u32 + 1;
    if next > 255 {
        return;
    }
    let kept: Vec<(usize, usize, u8)> = pixels
        .iter()
        .copied()
        .filter(|p| u32::from(p.2) >= next)
        .collect();
    if kept.len() < params.min_area_px {
        return;
    }
    // Components of the kept pixels, on a grid over their bounding box.
    let (bx0, by0, bx1, by1) = kept.iter().fold(
        (usize::MAX, usize::MAX, 0, 0),
        |(a, b, c, d), &(x, y, _)| (a.min(x), b.min(y), c.max(x), d.max(y)),
    );
    let (gw, gh) = (bx1 - bx0 + 1, by1 - by0 + 1);
    let mut grid = vec![0u8; gw * gh];
    for &(x, y, lv) in &kept {
        grid[(y - by0) * gw + (x - bx0)] = lv;
    }
    let mut stack = Vec::new();
    let mut part = Vec::new();
    for &(sx, sy, _) in &kept {
        let s0 = (sy - by0) * gw + (sx - bx0);
        if grid[s0] == 0 {
            continue;
        }
        stack.push(s0);
        part.clear();
        part.push((sx, sy, grid[s0]));
        grid[s0] = 0;
        while let Some(i) = stack.pop() {
            let (x, y) = (i % gw, i / gw);
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let nx = x as i64 + dx;
                    let ny = y as i64 + dy;
                    if nx < 0 || ny < 0 || nx >= gw as i64 || ny >= gh as i64 {
                        continue;
                    }
                    let j = ny as usize * gw + nx as usize;
                    if grid[j] != 0 {
                        part.push((nx as usize + bx0, ny as usize + by0, grid[j]));
                        grid[j] = 0;
                        stack.push(j);
                    }
                }
            }
        }
        split_and_measure(image, &part, next, depth + 1, params, out);
    }
}

/// Filters and measures one blob; `None` when it fails a filter.
fn measure_blob(
    image: &GrayImage,
    pixels: &[(usize, usize)],
    params: &DetectParams,
) -> Option<Detection> {
    let (w, h) = (image.width as usize, image.height as usize);
    let n = pixels.len() as f64;
    let (mut mx, mut my) = (0.0, 0.0);
    for &(x, y) in pixels {
        mx += x as f64;
        my += y as f64;
    }
    mx /= n;
    my /= n;
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for &(x, y) in pixels {
        let dx = x as f64 - mx;
        let dy = y as f64 - my;
        sxx += dx * dx;
        syy += dy * dy;
        sxy += dx * dy;
    }
    // Eigenvalues of the 2×2 covariance (+1/12 per axis: a pixel's own extent).
    let (a, b, cc) = (sxx / n + 1.0 / 12.0, syy / n + 1.0 / 12.0, sxy / n);
    let tr = a + b;
    let disc = ((a - b).powi(2) / 4.0 + cc * cc).sqrt();
    let (l1, l2) = (tr / 2.0 + disc, tr / 2.0 - disc);
    let roundness = if l1 > 0.0 {
        (l2.max(0.0) / l1).sqrt()
    } else {
        0.0
    };
    if roundness < params.min_roundness {
        return None;
    }
    let (bx0, by0, bx1, by1) = pixels
        .iter()
        .fold((usize::MAX, usize::MAX, 0, 0), |(a, b, c, d), &(x, y)| {
            (a.min(x), b.min(y), c.max(x), d.max(y))
        });
    // Background ring: the border of the box grown by 3 pixels.
    let g = 3;
    let (rx0, ry0) = (bx0.saturating_sub(g), by0.saturating_sub(g));
    let (rx1, ry1) = ((bx1 + g).min(w - 1), (by1 + g).min(h - 1));
    let mut ring: Vec<u8> = Vec::new();
    for y in ry0..=ry1 {
        for x in rx0..=rx1 {
            if y == ry0 || y == ry1 || x == rx0 || x == rx1 {
                ring.push(image.data[y * w + x]);
            }
        }
    }
    if ring.is_empty() {
        return None;
    }
    let mid = ring.len() / 2;
    let background = f64::from(*ring.select_nth_unstable(mid).1);
    let sign = if params.bright { -1.0 } else { 1.0 };
    let peak = pixels
        .iter()
        .map(|&(x, y)| sign * (background - f64::from(image.data[y * w + x])))
        .fold(f64::MIN, f64::max);
    if peak < params.min_peak_contrast_dn {
        return None;
    }
    // Weighted centroid over the box grown by 2.
    let (cx0, cy0) = (bx0.saturating_sub(2), by0.saturating_sub(2));
    let (cx1, cy1) = ((bx1 + 2).min(w - 1), (by1 + 2).min(h - 1));
    let (mut sw, mut swx, mut swy) = (0.0, 0.0, 0.0);
    // Ignore weights below a noise floor of 10 % of the peak.
    let floor = 0.1 * peak;
    for y in cy0..=cy1 {
        for x in cx0..=cx1 {
            let wgt = sign * (background - f64::from(image.data[y * w + x])) - floor;
            if wgt > 0.0 {
                sw += wgt;
                swx += wgt * x as f64;
                swy += wgt * y as f64;
            }
        }
    }
    if sw <= 0.0 {
        return None;
    }
    let quality = roundness * (peak / (peak + 40.0));
    Some(Detection {
        centre_px: Point2::new(swx / sw, swy / sw),
        area_px: pixels.len(),
        roundness,
        contrast_dn: peak,
        quality: quality.clamp(0.0, 1.0),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A gradient-lit image with antialiased dark discs at known subpixel centres.
    fn image_with_dots(dots: &[(f64, f64, f64)]) -> GrayImage {
        let (w, h) = (200u32, 120u32);
        let mut data = vec![0u8; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let skin = 90.0 + 100.0 * f64::from(x) / f64::from(w);
                let mut v = skin;
                for &(cx, cy, r) in dots {
                    // 4×4 supersampled coverage.
                    let mut cov = 0.0;
                    for sy in 0..4 {
                        for sx in 0..4 {
                            let px = f64::from(x) - 0.375 + 0.25 * f64::from(sx);
                            let py = f64::from(y) - 0.375 + 0.25 * f64::from(sy);
                            if (px - cx).hypot(py - cy) < r {
                                cov += 1.0 / 16.0;
                            }
                        }
                    }
                    v = v + (15.0 - v) * cov;
                }
                data[(y * w + x) as usize] = v.round() as u8;
            }
        }
        GrayImage {
            width: w,
            height: h,
            data,
        }
    }

    #[test]
    fn finds_dots_with_subpixel_centres_under_uneven_light() {
        let dots = [(30.3, 40.7, 2.5), (100.55, 60.2, 3.0), (170.8, 90.45, 2.2)];
        let img = image_with_dots(&dots);
        let mut found = detect_markers(&img, &DetectParams::default());
        assert_eq!(found.len(), 3, "{found:?}");
        found.sort_by(|a, b| a.centre_px.x.total_cmp(&b.centre_px.x));
        for (d, &(cx, cy, _)) in found.iter().zip(&dots) {
            let err = (d.centre_px - Point2::new(cx, cy)).norm();
            assert!(err < 0.05, "{err}");
            assert!(d.quality > 0.3 && d.roundness > 0.8, "{d:?}");
        }
    }

    #[test]
    fn rejects_lines_and_respects_roi() {
        let mut img = image_with_dots(&[(50.0, 50.0, 2.5)]);
        // A dark line 1 px wide and 30 px long: not round.
        for x in 120..150 {
            img.data[80 * 200 + x] = 20;
        }
        let found = detect_markers(&img, &DetectParams::default());
        assert_eq!(found.len(), 1, "{found:?}");
        let params = DetectParams {
            roi: Some((100, 0, 200, 120)),
            ..Default::default()
        };
        assert!(detect_markers(&img, &params).is_empty());
    }

    #[test]
    fn bright_mode_finds_bright_dots() {
        let mut img = image_with_dots(&[]);
        for v in &mut img.data {
            *v = 255 - *v;
        }
        let dark = image_with_dots(&[(60.2, 30.9, 2.5)]);
        let bright = GrayImage {
            data: dark.data.iter().map(|v| 255 - v).collect(),
            ..dark
        };
        let params = DetectParams {
            bright: true,
            ..Default::default()
        };
        let found = detect_markers(&bright, &params);
        assert_eq!(found.len(), 1);
        assert!((found[0].centre_px - Point2::new(60.2, 30.9)).norm() < 0.05);
        assert!(detect_markers(&img, &params).is_empty());
    }
}
