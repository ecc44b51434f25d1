//! Dots a band of light crosses: the two pieces a dot is found in, reported whole.
//!
//! A specular highlight on wet skin (or, for bright dots, a shadow) that crosses a dot
//! leaves its ink under the band as bright as the skin beside the dot, or brighter: the
//! local-contrast threshold of [`super::detect`] finds the dot as two blobs either side
//! of the band, each centred a third of a dot or more from the dot's centre. Two blobs
//! are taken for the pieces of one dot when they are as dark as each other, face each
//! other across a gap narrower than the dot, make together a blob no longer than a dot,
//! and the band that makes the gap goes on past the dot on both sides, clearly brighter
//! than the skin around (darker, for bright dots): two dots, or a dot and a freckle,
//! with skin between them are not joined. The dot is then reported whole as well,
//! beside its pieces (the labeler chooses, as it does between a smeared dot and its
//! pieces): along the line between the pieces, midway between their far ends; across
//! it, at their area-weighted mean.

use nalgebra::{Matrix2, Point2, Vector2};

use super::detect::{DetectParams, Detection};
use crate::capture::GrayImage;

/// Smallest peak contrast of a piece, in units of
/// [`DetectParams::min_peak_contrast_dn`]: ink, not a freckle or a crease fragment.
const PIECE_MIN_CONTRAST_FACTOR: f64 = 2.0;

/// The fainter piece's contrast at least this share of the darker one's: the same ink.
const PIECES_CONTRAST_RATIO: f64 = 0.5;

/// Widest gap between the pieces, as a share of the larger piece's length: a band that
/// leaves the dot in two pieces, not two dots or a dot and a mole apart.
const MAX_GAP_RATIO: f64 = 0.6;

/// How much brighter than the skin around the pieces the band must be beside the dot, in
/// units of [`DetectParams::min_peak_contrast_dn`] (darker, for bright dots).
const BAND_MIN_CONTRAST_FACTOR: f64 = 1.0;

/// Points sampled either side of the dot, a pixel apart from a pixel beyond its side, for
/// the band's level there.
const BAND_SAMPLES: usize = 8;

/// Points of the ring the skin level around two pieces is the median of.
const RING_SAMPLES: usize = 48;

/// The whole dots of pieces in `found` (see the module docs), each once, but for those
/// `found` holds whole already (a blob around both pieces); `params` as `found` was
/// detected with.
pub(super) fn dots_across_bands(
    image: &GrayImage,
    params: &DetectParams,
    found: &[Detection],
) -> Vec<Detection> {
    let min_contrast = PIECE_MIN_CONTRAST_FACTOR * params.min_peak_contrast_dn;
    let longest = 1.25 * params.max_dot_px.clamp(1.0, 400.0);
    // The pieces a dot can be in, with their covariances, in order of their centres' x.
    let mut pieces: Vec<(usize, Matrix2<f64>)> = found
        .iter()
        .enumerate()
        .filter(|(_, d)| {
            !d.streak
                && d.contrast_dn >= min_contrast
                && d.centre_px.x.is_finite()
                && d.centre_px.y.is_finite()
                && d.diameter_px.is_finite()
                && d.roundness.is_finite()
                && d.axis_rad.is_finite()
        })
        .map(|(i, d)| (i, covariance(d)))
        .collect();
    pieces.sort_by(|a, b| found[a.0].centre_px.x.total_cmp(&found[b.0].centre_px.x));
    let mut whole = Vec::new();
    for (k, &(i, ca)) in pieces.iter().enumerate() {
        let a = Piece {
            blob: &found[i],
            covariance: ca,
        };
        for &(j, cb) in &pieces[k + 1..] {
            let b = Piece {
                blob: &found[j],
                covariance: cb,
            };
            if b.blob.centre_px.x - a.blob.centre_px.x > longest {
                break;
            }
            if (b.blob.centre_px.y - a.blob.centre_px.y).abs() > longest {
                continue;
            }
            // A dot found whole already (a blob around both) is not found again.
            let around_both = |c: &Detection| {
                let r = 0.5 * c.diameter_px;
                (c.centre_px - a.blob.centre_px).norm() <= r
                    && (c.centre_px - b.blob.centre_px).norm() <= r
            };
            if let Some(d) = joined(image, params, &a, &b, longest)
                && !found
                    .iter()
                    .enumerate()
                    .any(|(k, c)| k != i && k != j && around_both(c))
            {
                whole.push(d);
            }
        }
    }
    whole
}

/// A blob that may be a piece of a dot, and the covariance of its pixels.
struct Piece<'a> {
    blob: &'a Detection,
    covariance: Matrix2<f64>,
}

/// The covariance of a detection's pixels, from its length, roundness and axis.
fn covariance(d: &Detection) -> Matrix2<f64> {
    let (l1, l2) = (
        (d.diameter_px / 4.0).powi(2),
        (d.diameter_px * d.roundness / 4.0).powi(2),
    );
    let e = Vector2::new(d.axis_rad.cos(), d.axis_rad.sin());
    let n = Vector2::new(-e.y, e.x);
    e * e.transpose() * l1 + n * n.transpose() * l2
}

/// The dot of which `a` and `b` are the pieces, if they are (see the module docs).
fn joined(
    image: &GrayImage,
    params: &DetectParams,
    a: &Piece,
    b: &Piece,
    longest: f64,
) -> Option<Detection> {
    let (ca, cb) = (a.covariance, b.covariance);
    let (a, b) = (a.blob, b.blob);
    let ab = b.centre_px - a.centre_px;
    let s = ab.norm();
    if !(s >= 1.0 && s <= longest) {
        return None;
    }
    if a.contrast_dn.min(b.contrast_dn) < PIECES_CONTRAST_RATIO * a.contrast_dn.max(b.contrast_dn) {
        return None;
    }
    let u = ab / s;
    let v = Vector2::new(-u.y, u.x);
    // Each piece's reach from its centre along a direction (a disc's radius).
    let reach = |c: &Matrix2<f64>, dir: &Vector2<f64>| 2.0 * dir.dot(&(c * dir)).max(0.0).sqrt();
    let (ra, rb) = (reach(&ca, &u), reach(&cb, &u));
    let gap = s - ra - rb;
    let length = s + ra + rb;
    if gap < 1.0 || gap > MAX_GAP_RATIO * a.diameter_px.max(b.diameter_px) || length > longest {
        return None;
    }
    // The band: brighter than the skin around the pieces (darker, for bright dots) on
    // both sides of the dot, along the gap (over the ink it need not be: a highlight
    // multiplies the light, and ink under it can look like bare skin).
    let sign = if params.bright { -1.0 } else { 1.0 };
    let value = |p: Point2<f64>| -> Option<f64> {
        let (x, y) = (p.x.round(), p.y.round());
        let (w, h) = (f64::from(image.width), f64::from(image.height));
        (x >= 0.0 && y >= 0.0 && x < w && y < h)
            .then(|| f64::from(image.data[y as usize * image.width as usize + x as usize]))
    };
    let span = 2.0 * reach(&ca, &v).max(reach(&cb, &v));
    let in_gap = a.centre_px + u * (ra + 0.5 * gap);
    let beside = |side: f64| -> Option<f64> {
        (0..BAND_SAMPLES)
            .map(|k| value(in_gap + v * (side * (0.5 * span + 1.0 + k as f64))).map(|x| sign * x))
            .try_fold(f64::MIN, |m, x| Some(m.max(x?)))
    };
    let band = beside(1.0)?.min(beside(-1.0)?);
    let middle = a.centre_px + ab * 0.5;
    let radius = 0.5 * length + 3.0;
    let mut ring: Vec<f64> = (0..RING_SAMPLES)
        .filter_map(|k| {
            let t = std::f64::consts::TAU * k as f64 / RING_SAMPLES as f64;
            value(middle + Vector2::new(t.cos(), t.sin()) * radius)
        })
        .collect();
    if ring.len() < RING_SAMPLES / 2 {
        return None;
    }
    ring.sort_by(f64::total_cmp);
    let skin = sign * ring[ring.len() / 2];
    if band - skin < BAND_MIN_CONTRAST_FACTOR * params.min_peak_contrast_dn {
        return None;
    }
    // The dot: along the line, midway between the pieces' far ends (the band need not
    // cross at the dot's middle, and the larger piece would pull an area-weighted
    // centre); across it, the pieces' area-weighted mean.
    let (na, nb) = (a.area_px as f64, b.area_px as f64);
    let ends = (a.centre_px - u * ra).coords + (b.centre_px + u * rb).coords;
    let across = (na * v.dot(&a.centre_px.coords) + nb * v.dot(&b.centre_px.coords)) / (na + nb);
    let centre = Point2::from(u * (0.5 * u.dot(&ends)) + v * across);
    // Shape: the two pieces' pixels and a strip of the gap as wide as the narrower piece.
    let width = 2.0 * reach(&ca, &v).min(reach(&cb, &v));
    let ng = gap * width;
    let strip = u * u.transpose() * (gap * gap / 12.0) + v * v.transpose() * (width * width / 12.0);
    let n = na + nb + ng;
    // Each part's mean off the dot's centre.
    let (da, db, mg) = (a.centre_px - centre, b.centre_px - centre, in_gap - centre);
    let cov = (ca * na
        + cb * nb
        + strip * ng
        + da * da.transpose() * na
        + db * db.transpose() * nb
        + mg * mg.transpose() * ng)
        / n;
    let eig = cov.symmetric_eigen();
    let (k1, k2) = if eig.eigenvalues[0] >= eig.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    let (l1, l2) = (eig.eigenvalues[k1].max(0.0), eig.eigenvalues[k2].max(0.0));
    let axis = eig.eigenvectors.column(k1);
    let mut axis_rad = axis.y.atan2(axis.x);
    if axis_rad > std::f64::consts::FRAC_PI_2 {
        axis_rad -= std::f64::consts::PI;
    } else if axis_rad < -std::f64::consts::FRAC_PI_2 {
        axis_rad += std::f64::consts::PI;
    }
    let roundness = if l1 > 0.0 { (l2 / l1).sqrt() } else { 0.0 };
    let contrast_dn = a.contrast_dn.max(b.contrast_dn);
    Some(Detection {
        centre_px: centre,
        area_px: n.round() as usize,
        roundness,
        contrast_dn,
        quality: (roundness * (contrast_dn / (contrast_dn + 40.0))).clamp(0.0, 1.0),
        diameter_px: 4.0 * l1.sqrt(),
        axis_rad,
        streak: false,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::detect::{detect_markers, pgm_image};

    /// A light band across the image: the line through `(x, y)` at `angle_rad` from +x,
    /// `width` pixels wide, multiplying the light by `1 + gain` (soft edges).
    #[derive(Clone, Copy)]
    struct Band {
        x: f64,
        y: f64,
        angle_rad: f64,
        width: f64,
        gain: f64,
    }

    impl Band {
        fn light(&self, px: f64, py: f64) -> f64 {
            let d = (py - self.y) * self.angle_rad.cos() - (px - self.x) * self.angle_rad.sin();
            1.0 + self.gain * (0.5 * self.width - d.abs() + 0.5).clamp(0.0, 1.0)
        }
    }

    /// A 240×160 image of skin (130 levels, a gentle gradient) with ink discs `(cx, cy,
    /// r)` of 0.55 the skin's albedo, lit through `bands` (4×4 samples per pixel). Ink under
    /// a band of gain 0.82 is as bright as the skin beside it: the case of a highlight on
    /// wet skin across a dot (the `cluttered` preset's M100 in cam1).
    fn image_with_bands(dots: &[(f64, f64, f64)], bands: &[Band]) -> GrayImage {
        let (w, h) = (240usize, 160usize);
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let mut sum = 0.0;
                for k in 0..16 {
                    let px = x + (f64::from(k % 4) + 0.5) / 4.0 - 0.5;
                    let py = y + (f64::from(k / 4) + 0.5) / 4.0 - 0.5;
                    let inked = dots
                        .iter()
                        .any(|&(cx, cy, r)| (px - cx).powi(2) + (py - cy).powi(2) <= r * r);
                    let albedo = if inked { 0.55 } else { 1.0 };
                    let light: f64 = bands.iter().map(|b| b.light(px, py)).product();
                    sum += (125.0 + 10.0 * px / w as f64) * albedo * light;
                }
                (sum / 16.0).clamp(0.0, 255.0).round() as u8
            })
            .collect();
        GrayImage {
            width: w as u32,
            height: h as u32,
            data,
        }
    }

    fn params() -> DetectParams {
        DetectParams {
            max_dot_px: 24.0,
            ..DetectParams::default()
        }
    }

    fn nearest(found: &[Detection], at: Point2<f64>) -> f64 {
        found
            .iter()
            .map(|d| (d.centre_px - at).norm())
            .fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn a_dot_a_highlight_crosses_is_found_whole_beside_its_pieces() {
        // Dots 12-20 px across, each crossed by a band 4-6 px wide through its middle or
        // off it by up to 0.35 radii, at several angles; dark dots under a highlight,
        // and bright ones under a shadow.
        let cases: [(f64, f64, f64, f64, f64, f64); 6] = [
            (40.0, 40.0, 6.0, 0.0, 0.0, 4.0),
            (120.0, 40.0, 8.0, 0.3, 2.5, 5.0),
            (200.0, 40.0, 10.0, -0.2, -3.5, 6.0),
            (40.0, 120.0, 7.0, 1.2, 1.5, 4.5),
            (120.0, 120.0, 9.0, -0.9, 0.0, 5.0),
            (200.0, 120.0, 8.0, 0.6, -2.0, 4.0),
        ];
        for &(cx, cy, r, angle_rad, offset, width) in &cases {
            let band = Band {
                x: cx - offset * angle_rad.sin(),
                y: cy + offset * angle_rad.cos(),
                angle_rad,
                width,
                gain: 0.82,
            };
            let dark = image_with_bands(&[(cx, cy, r)], &[band]);
            // Its negative: a bright dot (retroreflective, or white on dark make-up) a
            // shadow crosses.
            let bright = GrayImage {
                data: dark.data.iter().map(|v| 255 - v).collect(),
                ..dark.clone()
            };
            for (image, p) in [
                (dark, params()),
                (
                    bright,
                    DetectParams {
                        bright: true,
                        ..params()
                    },
                ),
            ] {
                let found = detect_markers(&image, &p);
                let at = Point2::new(cx, cy);
                // The band splits the dot: two pieces, neither centred on it, and the whole.
                let (whole, pieces): (Vec<Detection>, Vec<Detection>) = found
                    .iter()
                    .filter(|d| (d.centre_px - at).norm() <= r)
                    .partition(|d| (d.centre_px - at).norm() <= 1.5);
                assert_eq!(pieces.len(), 2, "dot at {at}: {found:?}");
                // The whole is the pieces', within half a pixel of the dot's centre (0.01-0.2
                // px measured: the pieces' far ends are as sharp as the dot's rim).
                assert_eq!(dots_across_bands(&image, &p, &pieces), whole, "dot at {at}");
                assert_eq!(whole.len(), 1, "dot at {at}: {found:?}");
                let error = (whole[0].centre_px - at).norm();
                assert!(error <= 0.5, "dot at {at}: {:?} off by {error}", whole[0]);
                // As long as the dot with its antialiased rim (about a pixel; the labeler's
                // size rules allow 2 px either way).
                let d = whole[0].diameter_px;
                assert!(d >= 2.0 * r && d <= 2.0 * r + 2.0, "{:?}", whole[0]);
                assert!(whole[0].roundness >= 0.8, "{:?}", whole[0]);
            }
        }
    }

    #[test]
    fn a_smudged_dot_a_highlight_crosses_on_rendered_skin_is_found_whole() {
        // An 84×84 crop of the `cluttered` preset's cam1, frame 0 (default seed), around
        // M100: a smudged dot about 20 px across on freckled skin, a band of sheen across
        // its lower half. The detector finds it in two pieces, 6.3 and 8.6 px from its
        // centre, (41.93, 42.02) in the crop; the labeler took neither, and M100 was
        // missed in 60 of its 60 frames.
        let image = pgm_image(include_bytes!("testdata/highlight_across_a_dot.pgm"), 84);
        let at = Point2::new(41.93, 42.02);
        let p = DetectParams::default();
        let found = detect_markers(&image, &p);
        let whole: Vec<&Detection> = found
            .iter()
            .filter(|d| (d.centre_px - at).norm() <= 1.0)
            .collect();
        assert_eq!(whole.len(), 1, "{found:?}");
        let pieces = found
            .iter()
            .filter(|d| (d.centre_px - at).norm() <= 10.0 && d.contrast_dn >= 30.0)
            .count();
        assert_eq!(pieces, 3, "the two pieces and the whole: {found:?}");
    }

    #[test]
    fn dots_with_skin_between_or_beside_a_band_are_not_joined() {
        let p = params();
        // Two dots close together, no band: skin between them.
        let image = image_with_bands(&[(100.0, 80.0, 7.0), (117.0, 80.0, 7.0)], &[]);
        let found = detect_markers(&image, &p);
        assert!(
            dots_across_bands(&image, &p, &found).is_empty(),
            "{found:?}"
        );
        // A band beside a dot, not across it; and a band between two dots that lie
        // farther apart than a band could split one.
        let band = Band {
            x: 0.0,
            y: 80.0,
            angle_rad: 0.0,
            width: 5.0,
            gain: 0.82,
        };
        let image = image_with_bands(
            &[(60.0, 69.0, 7.0), (160.0, 68.0, 6.0), (160.0, 92.0, 6.0)],
            &[band],
        );
        let found = detect_markers(&image, &p);
        assert!(
            dots_across_bands(&image, &p, &found).is_empty(),
            "{found:?}"
        );
        assert!(nearest(&found, Point2::new(60.0, 69.0)) <= 0.3);
    }
}
