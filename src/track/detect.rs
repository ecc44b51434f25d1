//! Marker detection: painted dots on skin, found by local-contrast thresholding.
//!
//! 1. Local mean `μ(x)` over a `(2r+1)²` box (running column sums), so uneven light
//!    cancels.
//! 2. Candidate pixels: `μ(x) − I(x) ≥ c` for dark dots (`I(x) − μ(x) ≥ c` for bright).
//!    With dots larger than the window handles, a second, larger window (see
//!    [`DetectParams::window_scales`]) is run on the image at half resolution; its blobs
//!    are measured in the image.
//! 3. 8-connected components of candidates, within the region of interest and mask. A
//!    component that fails the filters of step 4 (a dot touching a dark crease or the
//!    shading at the face's edge) is split by raising the contrast threshold, up to four
//!    times (the nested regions of MSER, Matas et al. 2002).
//! 4. Filters: area, roundness `√(λ_min/λ_max)` of the second moments, and contrast against
//!    the median of a ring of background around the blob (which rejects the dark halo that a
//!    specular highlight leaves in the local mean, and soft shading gradients). A dot on
//!    skin slanted far from the camera projects to a thin ellipse (minor/major = cos of the
//!    slant): a blob below the roundness limit is still kept, whole or split off a darker
//!    patch of skin, when its full axes `4√λ` say it is no longer than a dot and wide
//!    enough to be resolved, and its ink is clearly darker than a crease.
//! 5. Subpixel centre: centroid weighted by `max(0, B − I)` over the blob's pixels grown by
//!    two (per row, the columns of the blob in the rows within two, grown by two), so the
//!    antialiased rim counts but nothing else dark in the blob's box does (the black
//!    beyond the face's silhouette beside a dot seen edge-on). `B` is the ring's median for
//!    round blobs; for thin ones (roundness under 0.5: dots seen far from their normal),
//!    whose box is mostly skin, it is a plane fitted to the ring, since shading across the
//!    box would otherwise pull the centre towards its darker side (by 1–2.5 px on the
//!    `wide-mixed` preset).
//! 6. A dot cut by the image's edge has its centroid pulled inwards (a dot cut in half by
//!    0.42 radii, 3-4 px on a face-filling rig): a blob whose pull, told by its distance
//!    from the edge and its diameter, exceeds [`DetectParams::max_edge_bias_px`] is
//!    rejected.
//! 7. Two blobs a band of light (a highlight on wet skin; a shadow, for bright dots) split
//!    a dot into are also reported as the whole dot (module `pieces`).
//! 8. A dot a dark band touches (a crease, the mouth line's shadow) is one component with
//!    the band, and splits off it only in part: the ellipse its rim makes around such a
//!    part is reported as the dot too (module `rim`), in a component at least
//!    `RIM_MIN_BAND_LENGTH` (3) times as long as it, when no other detection is that dot or
//!    holds it.

use nalgebra::Point2;

use super::pieces::dots_across_bands;
use super::rim::{MIN_AREA_GAIN, dot_by_its_rim};
use super::search_windows::{Rect, RectGrid, SearchWindows, in_any};
use crate::capture::GrayImage;
use crate::numeric::{find_root, join_sets};
use crate::param_error::{self, ParamError};

/// Detection settings.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectParams {
    /// Look for bright dots instead of dark ones. Default false.
    #[serde(skip_serializing)]
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
    /// Foreshortened dots: a blob less round than [`DetectParams::min_roundness`] is still
    /// a dot when it is an ellipse no longer than a dot's diameter and wide enough to be
    /// resolved (see the `elongated_*` fields). Default true.
    pub accept_elongated: bool,
    /// Longest elongated blob accepted: the full major axis `4√λ_max` of its pixels,
    /// pixels. A dot seen edge-on is as long as its diameter (2.4 mm dots at 180-260 mm
    /// through a 700 px lens: 6.5-9.5 px, plus a pixel of antialiased rim); a crease or
    /// the mouth line is longer. Default 12.
    pub elongated_max_length_px: f64,
    /// Narrowest elongated blob accepted: the full minor axis `4√λ_min` of its pixels,
    /// pixels. Two rows of pixels give 2.3 (`4·√(1/4 + 1/12)`), one row 1.15: the default
    /// asks for a blob at least two pixels across, the least a width can be measured on
    /// (the thresholded blob is about a pixel wider than the ink). Default 2.
    pub elongated_min_width_px: f64,
    /// Smallest roundness of an elongated blob (0.15: a disc seen about 81° from its
    /// normal). Default 0.15.
    pub elongated_min_roundness: f64,
    /// Smallest peak contrast of an elongated blob, in units of
    /// [`DetectParams::min_peak_contrast_dn`] (ink is darker than a crease or a shading
    /// band). A dot seen 78-80° from its normal loses much of its contrast to the
    /// antialiased rim and blur: on the synth presets such dots measure 23-34 levels
    /// where a frontal one measures 60-100, so a factor of 2 (30 levels) dropped them
    /// about every other frame, and 1.5 (22.5 levels) in the dim phase of a light's
    /// flicker (cluttered's M036, 27 levels in the bright phase, missed two frames in
    /// three). Default 1.3: over 91 set-ups of every preset, 1.5 → 1.3 labeled up to
    /// 1.05 points more on cluttered and 0.6 on wide-mixed, less nowhere, and no label
    /// was wrong that was not before (1.0 put labels off their dots on cluttered).
    pub elongated_min_contrast_factor: f64,
    /// Smallest dot diameter to look for, pixels (a capture profile derives it from the
    /// dot size, the camera distances and the lens). Default 3.
    #[serde(skip_serializing)]
    pub min_dot_px: f64,
    /// Largest dot diameter to look for, pixels (see [`DetectParams::min_dot_px`]).
    /// Default 40.
    #[serde(skip_serializing)]
    pub max_dot_px: f64,
    /// Largest pull of a blob's centre by the image's edge, pixels: a dot cut by the edge
    /// has the centroid of its visible part pulled inwards, by an amount its distance from
    /// the edge and its diameter tell (see [`edge_cut_bias_px`]); a blob pulled more is
    /// rejected (a dot cut in half is pulled 0.42 radii, 3-4 px on a face-filling rig).
    /// Default 0.5: a few times the centroid noise of a whole dot, and what a dot of 7 px
    /// (15 px) across keeps with up to 16 % (7 %) of its area, 1.5 px (1.9 px) of its
    /// diameter, cut off.
    pub max_edge_bias_px: f64,
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
            accept_elongated: true,
            elongated_max_length_px: 12.0,
            elongated_min_width_px: 2.0,
            elongated_min_roundness: 0.15,
            elongated_min_contrast_factor: 1.3,
            min_dot_px: 3.0,
            max_dot_px: 40.0,
            max_edge_bias_px: 0.5,
            roi: None,
        }
    }
}

impl DetectParams {
    /// The settings with the size-dependent ones scaled to the dot size range: the fixed
    /// pixel values of the fields are floors, raised for larger dots so that one set of
    /// settings finds dots from [`DetectParams::min_dot_px`] to
    /// [`DetectParams::max_dot_px`] across in the same image (the local-mean windows are
    /// chosen by [`DetectParams::window_scales`]):
    /// - the largest area to a disc of `1.25 × max_dot_px` (blur and the antialiased rim);
    /// - the longest foreshortened dot to `1.25 × max_dot_px`;
    /// - the smallest area to `0.15 × min_dot_px²` (a dot of the smallest size seen 75°
    ///   from its normal), which drops pores and specks smaller than any dot.
    pub fn scaled_to_dot_sizes(&self) -> DetectParams {
        let max_dot = self.max_dot_px.clamp(1.0, 400.0);
        let min_dot = self.min_dot_px.clamp(0.0, max_dot);
        let max_area = (std::f64::consts::FRAC_PI_4 * (1.25 * max_dot).powi(2)).ceil() as usize;
        let min_area = (0.15 * min_dot * min_dot).floor() as usize;
        DetectParams {
            min_area_px: self.min_area_px.max(min_area),
            max_area_px: self
                .max_area_px
                .max(max_area)
                .max(self.min_area_px.max(min_area)),
            elongated_max_length_px: self.elongated_max_length_px.max(1.25 * max_dot),
            ..self.clone()
        }
    }

    /// The half-sizes of the local-mean windows, pixels, small first. A pixel is a
    /// candidate when it is darker than the local mean of any of them (the scale space of
    /// the detector, two levels): the small window
    /// ([`DetectParams::window_radius_px`]) keeps small dots in dark surroundings (beside a
    /// nostril, in the boom's shadow) separate from them; the large one, `0.55 ×
    /// max_dot_px`, has a large dot cover at most ~60 % of it, so that the dot's centre
    /// stays darker than its mean (the small window alone turns a large dot into a ring).
    /// One window when the two would be within 1.5× of each other.
    pub fn window_scales(&self) -> Vec<usize> {
        let small = (self.window_radius_px as usize).clamp(1, 128);
        let large = ((0.55 * self.max_dot_px.clamp(1.0, 400.0)).ceil() as usize).clamp(1, 128);
        if large as f64 > 1.5 * small as f64 {
            vec![small, large]
        } else {
            vec![small.max(large)]
        }
    }

    /// Checks every field.
    ///
    /// # Errors
    /// [`ParamError`] naming the field.
    pub fn validate(&self) -> Result<(), ParamError> {
        let err = ParamError::new;
        if self.window_radius_px == 0 || self.window_radius_px > 100 {
            return Err(err("window_radius_px", "must be in 1..=100"));
        }
        if self.min_contrast_dn == 0 || self.min_contrast_dn > 255 {
            return Err(err("min_contrast_dn", "must be in 1..=255"));
        }
        if self.min_area_px == 0 || self.min_area_px > self.max_area_px {
            return Err(err(
                "min_area_px",
                "must be positive and at most max_area_px",
            ));
        }
        if !(0.0..=1.0).contains(&self.min_roundness) {
            return Err(err("min_roundness", "must be in [0, 1]"));
        }
        if !(0.0..=1.0).contains(&self.elongated_min_roundness) {
            return Err(err("elongated_min_roundness", "must be in [0, 1]"));
        }
        param_error::positive(self.elongated_max_length_px, "elongated_max_length_px")?;
        param_error::non_negative(self.elongated_min_width_px, "elongated_min_width_px")?;
        param_error::non_negative(
            self.elongated_min_contrast_factor,
            "elongated_min_contrast_factor",
        )?;
        param_error::non_negative(self.max_edge_bias_px, "max_edge_bias_px")?;
        if !(self.min_dot_px.is_finite() && self.min_dot_px >= 0.0) {
            return Err(ParamError::new(
                "min_dot_px",
                format!("= {} must be non-negative", self.min_dot_px),
            ));
        }
        if !(self.max_dot_px.is_finite()
            && self.max_dot_px >= 1.0
            && self.max_dot_px <= 400.0
            && self.max_dot_px >= self.min_dot_px)
        {
            return Err(ParamError::new(
                "max_dot_px",
                format!("= {} must be in [max(1, min_dot_px), 400]", self.max_dot_px),
            ));
        }
        if let Some((x0, y0, x1, y1)) = self.roi
            && (x0 >= x1 || y0 >= y1)
        {
            return Err(err("roi", "must have x0 < x1 and y0 < y1"));
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
    /// The blob's scale: the full major axis `4√λ_max` of its pixels' second moments,
    /// pixels (a dot's diameter, about a pixel more for the antialiased rim, whatever its
    /// foreshortening).
    pub diameter_px: f64,
    /// Direction of that major axis, radians from the image's +x axis towards +y, in
    /// `[−π/2, π/2]` (meaningless for a round blob); NaN when not measured.
    pub axis_rad: f64,
    /// A streak thinner than any whole dot (roundness under
    /// [`DetectParams::elongated_min_roundness`]), reported as a dot seen far from its
    /// normal and smeared along its length may look: only a worn dot's blob, where the
    /// marker's neighbours put it (the labeler takes it for nothing else).
    pub streak: bool,
}

/// Why a blob of candidate pixels is not a dot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RejectReason {
    /// Larger than the largest dot, and no dot inside it.
    TooLarge,
    /// Thinner than a dot seen edge-on (a crease, a hair, the mouth line).
    NotRound,
    /// Too faint against the background around it.
    LowContrast,
    /// Cut by the image's edge: the centroid of the part in the image is pulled inwards
    /// by more than [`DetectParams::max_edge_bias_px`].
    AtImageEdge,
}

impl RejectReason {
    /// A short name for files and annotations.
    pub fn name(self) -> &'static str {
        match self {
            RejectReason::TooLarge => "too_large",
            RejectReason::NotRound => "not_round",
            RejectReason::LowContrast => "low_contrast",
            RejectReason::AtImageEdge => "at_image_edge",
        }
    }
}

/// A blob that was not taken for a dot (see [`MarkerDetector::detect_with_rejects`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rejection {
    /// Centre of its pixels, pixels.
    pub centre_px: Point2<f64>,
    /// Its area, pixels.
    pub area_px: usize,
    /// Why.
    pub reason: RejectReason,
}

/// Finds the dots in `image` (see the module docs). Allocates its working buffers on
/// every call: a loop over frames should keep a [`MarkerDetector`] instead.
pub fn detect_markers(image: &GrayImage, params: &DetectParams) -> Vec<Detection> {
    MarkerDetector::default().detect(image, params)
}

/// Marker detection with working buffers kept from call to call (one per camera, or per
/// thread): the entry type of this stage. [`MarkerDetector::detect`] gives exactly what
/// [`detect_markers`] gives.
#[derive(Debug, Default, Clone)]
pub struct MarkerDetector {
    /// Local contrast of candidate pixels over the ROI (0: not a candidate).
    mask: Vec<u8>,
    /// Whether a row of `mask` has a candidate.
    row_has_candidate: Vec<bool>,
    /// Column sums of the local-mean window (at most 201 rows × 255: fits in u16).
    col: Vec<u16>,
    /// Prefix sums of `col` along the row.
    prefix: Vec<u32>,
    /// Runs of candidates along the rows of `mask`, in raster order.
    runs: Vec<Run>,
    /// Union-find parent of each run (a root is the component's first run).
    parent: Vec<u32>,
    /// Component of each run, numbered in raster order.
    component_of_run: Vec<u32>,
    /// Pixels per component.
    sizes: Vec<usize>,
    /// Bounding box per component `(x0, y0, x1, y1)`, inclusive, ROI coordinates.
    boxes: Vec<(u32, u32, u32, u32)>,
    /// Pixels `(x, y, contrast)` of the components measured, contiguous per component.
    pixels: Vec<(usize, usize, u8)>,
    /// The image at half resolution, for the large window scale.
    half: GrayImage,
}

impl MarkerDetector {
    /// A detector with empty buffers (they grow on the first call).
    pub fn new() -> Self {
        Self::default()
    }

    /// Finds the dots in `image` (see the module docs).
    pub fn detect(&mut self, image: &GrayImage, params: &DetectParams) -> Vec<Detection> {
        self.detect_into(image, params, None, None, None)
    }

    /// Finds the dots inside the union of `windows` (rectangles `(x0, y0, x1, y1)`, end
    /// exclusive, clipped to the image and to [`DetectParams::roi`]): candidate pixels are
    /// found only there, so a dot is found whole when its window holds it whole. While
    /// tracking, one window around each predicted marker leaves out the skin between the
    /// markers, and with it most of the clutter and of the work. The local means still
    /// read the image around the windows, so a dot well inside a window gets the same
    /// candidate pixels, and the same detection, as in [`MarkerDetector::detect`].
    pub fn detect_in_windows(
        &mut self,
        image: &GrayImage,
        params: &DetectParams,
        windows: &[Rect],
    ) -> Vec<Detection> {
        self.windowed(image, params, windows, None)
    }

    /// Detection in the union of `windows`, measuring only near `centres` when given.
    fn windowed(
        &mut self,
        image: &GrayImage,
        params: &DetectParams,
        windows: &[Rect],
        centres: Option<&[Rect]>,
    ) -> Vec<Detection> {
        let (w, h) = (image.width as usize, image.height as usize);
        let clip = params.roi.map_or((0, 0, w, h), |(a, b, c, d)| {
            (
                a as usize,
                b as usize,
                (c as usize).min(w),
                (d as usize).min(h),
            )
        });
        let union = SearchWindows::new(windows, clip);
        let Some((x0, y0, x1, y1)) = union.bounds() else {
            return Vec::new();
        };
        let bounded = DetectParams {
            roi: Some((x0 as u32, y0 as u32, x1 as u32, y1 as u32)),
            ..params.clone()
        };
        self.detect_into(image, &bounded, Some((&union, windows)), centres, None)
    }

    /// The detections of [`MarkerDetector::detect_in_windows`] whose centre lies in one
    /// of `centres` (rectangles like `windows`; while tracking, where a detection can be a
    /// candidate of a window's marker), without measuring the blobs whose centre cannot
    /// (their box, grown by the rim the centroid weighs, meets none of them): most of the
    /// clutter a window holds around its marker (freckles, pores, hair) costs its candidate
    /// pixels only. At two scales, the large scale's blobs are measured within a tenth of
    /// the largest blob a dot makes ([`DetectParams::scaled_to_dot_sizes`]) of `centres`,
    /// and the small scale's inside the large blobs too, so that the rule that picks one
    /// of the two scales for a blob sees all it needs (exactly so for large blobs up to
    /// that size).
    pub fn detect_in_windows_near(
        &mut self,
        image: &GrayImage,
        params: &DetectParams,
        windows: &[Rect],
        centres: &[Rect],
    ) -> Vec<Detection> {
        let mut found = self.windowed(image, params, windows, Some(centres));
        found.retain(|d| in_any(centres, d.centre_px));
        found
    }

    /// [`MarkerDetector::detect`], and the blobs of candidate pixels that were not taken
    /// for dots, with the reason (blobs smaller than the smallest dot are not listed).
    pub fn detect_with_rejects(
        &mut self,
        image: &GrayImage,
        params: &DetectParams,
    ) -> (Vec<Detection>, Vec<Rejection>) {
        let mut rejected = Vec::new();
        let found = self.detect_into(image, params, None, None, Some(&mut rejected));
        (found, rejected)
    }

    fn detect_into(
        &mut self,
        image: &GrayImage,
        params: &DetectParams,
        windows: Option<(&SearchWindows, &[Rect])>,
        centres: Option<&[Rect]>,
        rejected: Option<&mut Vec<Rejection>>,
    ) -> Vec<Detection> {
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
        let roi = (x0, y0, x1, y1);
        let scales = params.window_scales();
        let mut by_rim = Vec::new();
        let mut found = if let [small] = scales[..] {
            let scaled = params.scaled_to_dot_sizes();
            self.threshold(image, &scaled, small, roi, windows.map(|w| w.0));
            let mut out = Vec::new();
            let measuring = Measuring::new(image, &scaled, None, 0);
            self.components(
                measuring,
                roi,
                windows.map(|w| w.0),
                centres,
                &mut out,
                rejected,
                &mut by_rim,
            );
            out
        } else {
            self.detect_two_scales(
                image,
                params,
                &scales,
                roi,
                windows,
                centres,
                rejected,
                &mut by_rim,
            )
        };
        // Dots found by their rim (module `rim`) that no other detection is, nor lies in
        // (a smear found whole, a hair across it making the pieces).
        let mut kept: Vec<Detection> = Vec::new();
        for dot in by_rim {
            if !found
                .iter()
                .chain(&kept)
                .any(|o| same_dot(o, &dot) || holds(o, &dot))
            {
                kept.push(dot);
            }
        }
        found.extend(kept);
        let whole = dots_across_bands(image, params, &found);
        found.extend(whole);
        found
    }

    /// Detection at two window scales with per-blob scale selection: the small window
    /// with the fixed-size filters (the detector for dots up to about `1.7 r` across),
    /// the large window with the filters scaled to the dot size range. A blob of the large
    /// scale wider than the small window handles ([`small_scale_limit_px`]) is kept, and the
    /// small scale's detections inside it (the ring a small window makes of a large dot)
    /// are dropped; the large scale's smaller blobs are the small scale's business (in
    /// its wider window a small dot beside a crease or a nostril merges with them).
    /// The large scale goes first: with `centres` (see
    /// [`MarkerDetector::detect_in_windows_near`]) the small scale also measures the blobs
    /// inside the large blobs it may keep, so that the rule above sees them.
    ///
    /// The large scale's candidates are found in the image at half resolution
    /// ([`half_resolution`], a window of half the size) and its blobs split there, but a
    /// blob that may be kept is measured on its own pixels in the image ([`measure_blob`]):
    /// its dots are wider than the small window handles, at least 7 pixels across at half
    /// resolution, while the clutter its wide window merges into large blobs (hair,
    /// freckles, shading) costs a quarter as much to gather and split (a fifth less
    /// detection work on the `cluttered` preset, the same labels within ±0.3 points on
    /// every preset).
    #[allow(clippy::too_many_arguments)]
    fn detect_two_scales(
        &mut self,
        image: &GrayImage,
        params: &DetectParams,
        scales: &[usize],
        roi: (usize, usize, usize, usize),
        windows: Option<(&SearchWindows, &[Rect])>,
        centres: Option<&[Rect]>,
        rejected: Option<&mut Vec<Rejection>>,
        by_rim: &mut Vec<Detection>,
    ) -> Vec<Detection> {
        let (small, large) = (scales[0], scales[scales.len() - 1]);
        let scaled = params.scaled_to_dot_sizes();
        let limit = small_scale_limit_px(small);
        // The large scale keeps round blobs (roundness ≥ 0.5) wider than `limit`
        // (`4√λ₁ > limit`). An 8-connected set of pixels spread that wide in both
        // directions has at least about 2.2·limit pixels (the sparsest such sets are thin
        // rings and crosses; a filled disc has far more). Smaller components (pores,
        // freckles, most skin texture in the large window), and so all their parts,
        // cannot be one: they are not measured (bound taken at 1.2·limit, for the pixel
        // grid and the `+1/12` of a pixel's own extent).
        let coarse_min_px = (1.2 * limit).floor() as usize;
        // A large blob kept drops the small blobs it holds, and it keeps at most one, at
        // its own centre (within a tenth of its size, or 1.5 px): a large blob that drops a
        // small one centred in `centres` has its own centre that close to them.
        let coarse_centres: Option<Vec<Rect>> = centres.map(|centres| {
            let largest = 1.25 * scaled.max_dot_px.clamp(1.0, 400.0);
            let grow = (0.1 * largest).max(1.5).ceil() as u32 + 1;
            centres
                .iter()
                .map(|&(a, b, c, d)| {
                    (
                        a.saturating_sub(grow),
                        b.saturating_sub(grow),
                        c.saturating_add(grow),
                        d.saturating_add(grow),
                    )
                })
                .collect()
        });
        let mut coarse = Vec::new();
        let mut half = std::mem::take(&mut self.half);
        let (hw, hh) = (image.width as usize / 2, image.height as usize / 2);
        let halve = |(a, b, c, d): (usize, usize, usize, usize)| {
            (a / 2, b / 2, c.div_ceil(2).min(hw), d.div_ceil(2).min(hh))
        };
        let half_roi = halve(roi);
        let r_half = large.div_ceil(2);
        if half_roi.0 < half_roi.2 && half_roi.1 < half_roi.3 {
            // What the large window reads: the ROI grown by its half-size.
            let read = (
                half_roi.0.saturating_sub(r_half),
                half_roi.1.saturating_sub(r_half),
                (half_roi.2 + r_half).min(hw),
                (half_roi.3 + r_half).min(hh),
            );
            half_resolution(image, &mut half, read);
            let half_windows = windows.map(|(_, rects)| {
                let rects: Vec<Rect> = rects
                    .iter()
                    .map(|&(a, b, c, d)| {
                        let (a, b, c, d) = halve((a as usize, b as usize, c as usize, d as usize));
                        (a as u32, b as u32, c as u32, d as u32)
                    })
                    .collect();
                SearchWindows::new(&rects, half_roi)
            });
            self.threshold(&half, &scaled, r_half, half_roi, half_windows.as_ref());
            self.components(
                Measuring {
                    min_diameter_px: BLOCKS_MIN_DIAMETER * limit,
                    ..Measuring::new(image, &scaled, Some(&half), coarse_min_px)
                },
                half_roi,
                half_windows.as_ref(),
                coarse_centres.as_deref(),
                &mut coarse,
                None,
                by_rim,
            );
        }
        self.half = half;
        let kept_if_alone =
            |c: &Detection| c.diameter_px > limit && c.roundness >= COARSE_MIN_ROUNDNESS;
        coarse.retain(kept_if_alone);
        // The small scale measures blobs up to its own limit (larger ones are the large
        // scale's), but foreshortened dots of any size in the range: a large dot seen edge-on
        // is a thin ellipse the large window does not take (it keeps round blobs only).
        let fine_params = DetectParams {
            elongated_max_length_px: scaled.elongated_max_length_px,
            min_area_px: scaled.min_area_px,
            ..params.clone()
        };
        // Where the small scale's blobs matter: `centres`, and inside every large blob.
        let fine_centres: Option<Vec<Rect>> = centres.map(|centres| {
            let reach = |c: &Detection| {
                let r = 0.5 * c.diameter_px + 1.0;
                let lo = |v: f64| (v - r).floor().max(0.0) as u32;
                let hi = |v: f64| ((v + r).ceil().max(0.0) as u32).saturating_add(1);
                let (x, y) = (c.centre_px.x, c.centre_px.y);
                (lo(x), lo(y), hi(x), hi(y))
            };
            centres
                .iter()
                .copied()
                .chain(coarse.iter().map(reach))
                .collect()
        });
        let mut fine = Vec::new();
        self.threshold(image, &fine_params, small, roi, windows.map(|w| w.0));
        self.components(
            Measuring::new(image, &fine_params, None, 0),
            roi,
            windows.map(|w| w.0),
            fine_centres.as_deref(),
            &mut fine,
            rejected,
            by_rim,
        );
        merge_scales(coarse, fine)
    }

    /// Connected components (8-connectivity) of the candidate mask over the ROI (in the
    /// grid of `measuring`: the image's, or at half resolution), each measured or split
    /// by [`split_and_measure`]; components smaller than [`Measuring::min_px`] (or than
    /// the smallest blob area) are left out, and with `centres` (image pixels), those
    /// whose detections' centres cannot lie in any of them (the centroid weighs the
    /// component's box grown by [`RIM_PX`]).
    ///
    /// The mask is read as runs of candidates along each row, joined to the runs they
    /// touch in the row above (union-find); a component's pixels are then gathered run by
    /// run. Components are measured in the raster order of their first pixel.
    #[allow(clippy::too_many_arguments)]
    fn components(
        &mut self,
        measuring: Measuring,
        (x0, y0, x1, _): (usize, usize, usize, usize),
        windows: Option<&SearchWindows>,
        centres: Option<&[Rect]>,
        out: &mut Vec<Detection>,
        mut rejected: Option<&mut Vec<Rejection>>,
        by_rim: &mut Vec<Detection>,
    ) {
        let bw = x1 - x0;
        let c = measuring.params.min_contrast_dn;
        let s = measuring.scale;
        let Self {
            mask,
            row_has_candidate,
            runs,
            parent,
            component_of_run,
            sizes,
            boxes,
            pixels,
            ..
        } = self;
        runs.clear();
        parent.clear();
        // Runs of each row, joined to the touching runs of the row above.
        let mut above = 0..0;
        let mut last_row = usize::MAX;
        for (row, _) in row_has_candidate
            .iter()
            .enumerate()
            .filter(|(_, has)| **has)
        {
            let first = runs.len();
            let line = &mask[row * bw..(row + 1) * bw];
            let mut x = 0;
            while let Some(start) = next_candidate(line, x) {
                x = end_of_run(line, start);
                runs.push(Run {
                    row: row as u32,
                    start: start as u32,
                    end: x as u32,
                });
                parent.push((runs.len() - 1) as u32);
            }
            let here = first..runs.len();
            if last_row.wrapping_add(1) == row {
                // Two-pointer sweep: runs touch (8-connectivity) when their column ranges
                // overlap after growing one of them by a pixel either way.
                let (mut i, mut j) = (here.start, above.start);
                while i < here.end && j < above.end {
                    let (a, b) = (runs[i], runs[j]);
                    if b.end < a.start {
                        j += 1;
                    } else if a.end < b.start {
                        i += 1;
                    } else {
                        join_sets(parent, i as u32, j as u32);
                        if a.end < b.end {
                            i += 1;
                        } else {
                            j += 1;
                        }
                    }
                }
            }
            above = here;
            last_row = row;
        }
        // Component of every run, numbered in raster order of their first run, and sizes.
        component_of_run.clear();
        sizes.clear();
        boxes.clear();
        for (i, run) in runs.iter().enumerate() {
            // The root is the component's first run (the smallest index).
            let root = find_root(parent, i as u32) as usize;
            let id = if root == i {
                sizes.push(0);
                boxes.push((run.start, run.row, run.end - 1, run.row));
                (sizes.len() - 1) as u32
            } else {
                component_of_run[root]
            };
            component_of_run.push(id);
            sizes[id as usize] += (run.end - run.start) as usize;
            let b = &mut boxes[id as usize];
            *b = (b.0.min(run.start), b.1, b.2.max(run.end - 1), run.row);
        }
        // Components measured: large enough, and near a centre.
        let floor = measuring
            .min_px
            .max(measuring.params.min_area_px)
            .div_ceil(s * s)
            .max(1);
        let grid = centres.map(RectGrid::new);
        let measuring = Measuring {
            near: grid.as_ref(),
            windows,
            ..measuring
        };
        if grid.is_some() {
            for (n, b) in sizes.iter_mut().zip(boxes.iter()) {
                if *n < floor {
                    continue;
                }
                let (ox, oy) = (x0 as u32, y0 as u32);
                if !measuring.near_centres((b.0 + ox, b.1 + oy, b.2 + ox, b.3 + oy)) {
                    *n = 0;
                }
            }
        }
        // Pixels of the components kept, contiguous per component.
        let mut offsets: Vec<usize> = Vec::with_capacity(sizes.len() + 1);
        let mut total = 0;
        for &n in sizes.iter() {
            offsets.push(total);
            if n >= floor {
                total += n.min(MAX_COMPONENT_PX);
            }
        }
        offsets.push(total);
        pixels.clear();
        pixels.resize(total, (0, 0, 0));
        let mut fill = offsets.clone();
        for (run, &id) in runs.iter().zip(component_of_run.iter()) {
            let id = id as usize;
            if sizes[id] < floor {
                continue;
            }
            let y = run.row as usize;
            let (start, end) = (run.start as usize, run.end as usize);
            let room = offsets[id + 1] - fill[id];
            let levels = &mask[y * bw + start..y * bw + end];
            for (x, &level) in (start..end).zip(levels).take(room) {
                pixels[fill[id]] = (x + x0, y + y0, level);
                fill[id] += 1;
            }
        }
        for id in 0..sizes.len() {
            if sizes[id] >= floor {
                split_and_measure(
                    measuring,
                    &pixels[offsets[id]..offsets[id + 1]],
                    c,
                    0,
                    out,
                    rejected.as_deref_mut(),
                    Some(&mut *by_rim),
                );
            }
        }
    }

    /// Fills `mask` (the ROI `(x0, y0, x1, y1)`, row-major) with the local contrast of
    /// candidate pixels, saturated at 255, and `row_has_candidate`; with `windows`, only
    /// inside them (0 elsewhere). Box sums over the ROI grown by `r` (clamped to the
    /// image): column sums over the window's rows, kept incrementally from row to row, and
    /// a prefix sum of them along each span of a row (grown by `r`). Away from the image's
    /// edges the window has a fixed area `A` and a pixel is a candidate when
    /// `S ≥ A·(I + c)` (dark) or `A·I ≥ S + A·c` (bright), a test the compiler vectorizes;
    /// the contrast `⌊|S − A·I| / A⌋` is computed for candidates only.
    fn threshold(
        &mut self,
        image: &GrayImage,
        params: &DetectParams,
        r: usize,
        (x0, y0, x1, y1): (usize, usize, usize, usize),
        windows: Option<&SearchWindows>,
    ) {
        let (w, h) = (image.width as usize, image.height as usize);
        let gx0 = x0.saturating_sub(r);
        let gy0 = y0.saturating_sub(r);
        let gx1 = (x1 + r).min(w);
        let gy1 = (y1 + r).min(h);
        let rw = gx1 - gx0;
        let (bw, bh) = (x1 - x0, y1 - y0);
        let c = params.min_contrast_dn;
        self.mask.clear();
        self.mask.resize(bw * bh, 0);
        self.row_has_candidate.clear();
        self.row_has_candidate.resize(bh, false);
        self.col.clear();
        self.col.resize(rw, 0);
        self.prefix.clear();
        self.prefix.resize(rw + 1, 0);
        // Interior columns: the window lies inside [gx0, gx1).
        let ia = x0.max(gx0 + r).min(x1);
        let ib = x1.min(gx1.saturating_sub(r)).max(ia);
        let whole_row = [(x0, x1)];
        let (mut ya_prev, mut yb_prev) = (gy0, gy0);
        for y in y0..y1 {
            let ya = y.saturating_sub(r).max(gy0);
            let yb = (y + r + 1).min(gy1);
            for yy in yb_prev..yb {
                let row = &image.data[yy * w + gx0..yy * w + gx1];
                self.col
                    .iter_mut()
                    .zip(row)
                    .for_each(|(s, &v)| *s = s.wrapping_add(u16::from(v)));
            }
            for yy in ya_prev..ya {
                let row = &image.data[yy * w + gx0..yy * w + gx1];
                self.col
                    .iter_mut()
                    .zip(row)
                    .for_each(|(s, &v)| *s = s.wrapping_sub(u16::from(v)));
            }
            (ya_prev, yb_prev) = (ya, yb);
            let spans = windows.map_or(&whole_row[..], |win| win.row(y));
            let rows = (yb - ya) as u32;
            let img_row = &image.data[y * w + x0..y * w + x1];
            let mask_row = &mut self.mask[(y - y0) * bw..(y - y0 + 1) * bw];
            let mut any = 0u8;
            for &(sa, sb) in spans {
                let (sa, sb) = (sa.max(x0), sb.min(x1));
                if sa >= sb {
                    continue;
                }
                // Prefix sums of the column sums over the span grown by r: `prefix[k]` is
                // the sum of columns `pa..pa + k`.
                let pa = sa.saturating_sub(r).max(gx0);
                let pb = (sb + r + 1).min(gx1);
                let mut acc = 0u32;
                for (p, &s) in self.prefix[1..=pb - pa]
                    .iter_mut()
                    .zip(&self.col[pa - gx0..pb - gx0])
                {
                    acc += u32::from(s);
                    *p = acc;
                }
                let prefix = &self.prefix;
                // Contrast of pixel x (window clamped to [gx0, gx1)), 0 below the
                // threshold.
                let level = |x: usize, v: u8| -> u8 {
                    let xa = x.saturating_sub(r).max(gx0) - pa;
                    let xb = (x + r + 1).min(gx1) - pa;
                    let area = (xb - xa) as u32 * rows;
                    let sum = prefix[xb] - prefix[xa];
                    let v = u32::from(v) * area;
                    let diff = if params.bright {
                        v.checked_sub(sum)
                    } else {
                        sum.checked_sub(v)
                    };
                    match diff {
                        Some(d) if d >= c * area => (d / area).clamp(1, 255) as u8,
                        _ => 0,
                    }
                };
                // The span's interior part [i0, i1), and its edge parts either side.
                let i0 = sa.max(ia).min(sb);
                let i1 = sb.min(ib).max(i0);
                for x in (sa..i0).chain(i1..sb) {
                    let m = level(x, img_row[x - x0]);
                    mask_row[x - x0] = m;
                    any |= m;
                }
                if i0 < i1 {
                    let n = i1 - i0;
                    let area = (2 * r + 1) as u32 * rows;
                    let lo = &prefix[i0 - r - pa..i0 - r - pa + n];
                    let hi = &prefix[i0 + r + 1 - pa..i0 + r + 1 - pa + n];
                    let vals = &img_row[i0 - x0..i1 - x0];
                    let flags = &mut mask_row[i0 - x0..i1 - x0];
                    let mut hit = 0u8;
                    if params.bright {
                        for (((f, &v), &s1), &s0) in flags.iter_mut().zip(vals).zip(hi).zip(lo) {
                            *f = u8::from(area * u32::from(v) >= s1 - s0 + area * c);
                            hit |= *f;
                        }
                    } else {
                        for (((f, &v), &s1), &s0) in flags.iter_mut().zip(vals).zip(hi).zip(lo) {
                            *f = u8::from(s1 - s0 >= area * (u32::from(v) + c));
                            hit |= *f;
                        }
                    }
                    if hit != 0 {
                        // Candidates are sparse: found a word at a time, and their
                        // contrast `⌊d / A⌋` taken by an exact reciprocal of the fixed
                        // area (see `Reciprocal`).
                        let line = &mut mask_row[i0 - x0..i1 - x0];
                        let inverse = Reciprocal::new(area);
                        let mut k = 0;
                        while let Some(i) = next_candidate(line, k) {
                            let v = area * u32::from(vals[i]);
                            let d = if params.bright {
                                v.wrapping_sub(hi[i] - lo[i])
                            } else {
                                (hi[i] - lo[i]).wrapping_sub(v)
                            };
                            line[i] = match inverse {
                                Some(inverse) => inverse.quotient(d).clamp(1, 255) as u8,
                                None => level(i0 + i, vals[i]),
                            };
                            k = i + 1;
                        }
                    }
                    any |= hit;
                }
            }
            self.row_has_candidate[y - y0] = any != 0;
        }
    }
}

/// `image` at half resolution into `half`, inside the region `(x0, y0, x1, y1)` of the
/// half-resolution image (end exclusive; the rest is left as it was): each pixel the
/// rounded mean of a 2×2 block (an odd last row or column is left out).
fn half_resolution(image: &GrayImage, half: &mut GrayImage, (x0, y0, x1, y1): Region) {
    let w = image.width as usize;
    let (hw, hh) = (w / 2, image.height as usize / 2);
    if (half.width as usize, half.height as usize) != (hw, hh) || half.data.len() != hw * hh {
        half.width = hw as u32;
        half.height = hh as u32;
        half.data.clear();
        half.data.resize(hw * hh, 0);
    }
    let (x1, y1) = (x1.min(hw), y1.min(hh));
    if x0 >= x1 {
        return;
    }
    for y in y0..y1 {
        let out = &mut half.data[y * hw + x0..y * hw + x1];
        let top = &image.data[2 * y * w + 2 * x0..2 * y * w + 2 * x1];
        let bottom = &image.data[(2 * y + 1) * w + 2 * x0..(2 * y + 1) * w + 2 * x1];
        halve_row(top, bottom, out);
    }
}

/// One row of [`half_resolution`]: `out[i]` the rounded mean of `top[2i..2i + 2]` and
/// `bottom[2i..2i + 2]`. Sixteen pixels at a time from fixed-size arrays, a form the
/// compiler vectorizes (five times faster than one block at a time), then the rest; not
/// inlined, where the vectorizer would give up.
#[inline(never)]
fn halve_row(top: &[u8], bottom: &[u8], out: &mut [u8]) {
    for ((o, t), b) in out
        .chunks_exact_mut(16)
        .zip(top.chunks_exact(32))
        .zip(bottom.chunks_exact(32))
    {
        let (o, t, b): (&mut [u8; 16], &[u8; 32], &[u8; 32]) = (
            o.try_into().expect("16 bytes"),
            t.try_into().expect("32 bytes"),
            b.try_into().expect("32 bytes"),
        );
        for (i, o) in o.iter_mut().enumerate() {
            *o = block_mean(t[2 * i], t[2 * i + 1], b[2 * i], b[2 * i + 1]);
        }
    }
    let done = out.len() / 16 * 16;
    for (i, o) in out.iter_mut().enumerate().skip(done) {
        *o = block_mean(top[2 * i], top[2 * i + 1], bottom[2 * i], bottom[2 * i + 1]);
    }
}

/// The rounded mean of the four pixels of a 2×2 block.
#[inline(always)]
fn block_mean(a: u8, b: u8, c: u8, d: u8) -> u8 {
    ((u16::from(a) + u16::from(b) + u16::from(c) + u16::from(d) + 2) >> 2) as u8
}

/// A region of an image `(x0, y0, x1, y1)`, pixels, end exclusive.
type Region = (usize, usize, usize, usize);

/// Division by a fixed divisor `a < 2¹⁵` of dividends `d < 2²⁵` (a box's contrast sum,
/// at most 255 levels over `a` pixels), as a multiplication: `⌊d·m / 2⁴⁰⌋` with
/// `m = ⌊2⁴⁰/a⌋ + 1` is `⌊d/a⌋` exactly, since `d·m/2⁴⁰` exceeds `d/a` by less than
/// `d/2⁴⁰ < 2⁻¹⁵`, and `d/a` lies at least `1/a > 2⁻¹⁵` below the next integer.
#[derive(Debug, Clone, Copy)]
struct Reciprocal(u64);

impl Reciprocal {
    const SHIFT: u32 = 40;

    /// The reciprocal of `a`, None when `a` is 0 or not below 2¹⁵.
    fn new(a: u32) -> Option<Self> {
        (a > 0 && a < 1 << 15).then(|| Self((1u64 << Self::SHIFT) / u64::from(a) + 1))
    }

    /// `⌊d/a⌋` for `d < 2²⁵`.
    fn quotient(self, d: u32) -> u32 {
        debug_assert!(d < 1 << 25);
        ((u64::from(d) * self.0) >> Self::SHIFT) as u32
    }
}

/// A run of candidate pixels along a row of the mask: columns `start..end`.
#[derive(Debug, Clone, Copy)]
struct Run {
    row: u32,
    start: u32,
    end: u32,
}

/// The eight bytes of `line` from `x` as one word, first byte lowest (None past the end).
fn word_at(line: &[u8], x: usize) -> Option<u64> {
    let bytes: [u8; 8] = line.get(x..x + 8)?.try_into().ok()?;
    Some(u64::from_le_bytes(bytes))
}

/// The first non-zero byte of `line` at or after `x`, skipping zeros a word at a time.
fn next_candidate(line: &[u8], mut x: usize) -> Option<usize> {
    while let Some(word) = word_at(line, x) {
        if word != 0 {
            return Some(x + (word.trailing_zeros() / 8) as usize);
        }
        x += 8;
    }
    (x..line.len()).find(|&i| line[i] != 0)
}

/// The end (exclusive) of the run of non-zero bytes of `line` that starts at `x`, found a
/// word at a time: the lowest byte flagged by `(w − 0x01…01) & !w & 0x80…80` is the first
/// zero byte of `w` (the flags above it may be wrong, the lowest never is).
fn end_of_run(line: &[u8], mut x: usize) -> usize {
    const ONES: u64 = 0x0101_0101_0101_0101;
    const HIGHS: u64 = 0x8080_8080_8080_8080;
    while let Some(word) = word_at(line, x) {
        let zeros = word.wrapping_sub(ONES) & !word & HIGHS;
        if zeros != 0 {
            return x + (zeros.trailing_zeros() / 8) as usize;
        }
        x += 8;
    }
    (x..line.len())
        .find(|&i| line[i] == 0)
        .unwrap_or(line.len())
}

/// The widest blob the small window of half-size `r` measures well, pixels: a dot covering
/// about 60 % of the `(2r + 1)²` window (beyond that its centre is no longer darker than the
/// window's mean and the blob becomes a ring).
pub fn small_scale_limit_px(r: usize) -> f64 {
    0.87 * (2 * r + 1) as f64
}

/// The blobs of both window scales ([`MarkerDetector::detect_two_scales`]): the large
/// scale's `coarse` blobs (round and wider than the small window handles) and the small
/// scale's `fine` ones, each dot once.
fn merge_scales(mut coarse: Vec<Detection>, mut fine: Vec<Detection>) -> Vec<Detection> {
    // The small blobs in order of their centres' x, to look up those a large blob may
    // hold (within its reach in x) instead of asking every one of them.
    let mut by_x: Vec<(f64, usize)> = fine
        .iter()
        .enumerate()
        .map(|(i, f)| (f.centre_px.x, i))
        .collect();
    by_x.sort_by(|a, b| a.0.total_cmp(&b.0));
    // A large dot is one round blob: it holds at most one of the small scale's blobs
    // (its ring). A large blob around several small ones is a patch of skin with dots
    // in it (an eyebrow, the shading beside the nose), not a dot.
    // When it holds one, the two are the same dot only if they share the centre (a
    // small dot merged with a shadow in the large window makes a large blob around it
    // whose centre is off), and if the small one is not a whole dot much smaller than
    // the large blob (a dot seen obliquely among hair strokes, which the large window
    // merges into a round patch around it): a large dot is a ring in the small window.
    let kept: Vec<bool> = coarse
        .iter()
        .map(|c| {
            let mut held = held_by(c, &fine, &by_x);
            match (held.next(), held.next()) {
                (None, _) => true,
                (Some(i), None) => {
                    let f = &fine[i];
                    (c.centre_px - f.centre_px).norm() <= (0.1 * c.diameter_px).max(1.5)
                        && !(c.diameter_px > COARSE_MAX_OVER_WHOLE * f.diameter_px
                            && ellipse_fill(f) >= WHOLE_MIN_FILL)
                }
                (Some(_), Some(_)) => false,
            }
        })
        .collect();
    // The small blobs a large blob kept holds are its ring: dropped.
    let mut dropped = vec![false; fine.len()];
    for (c, _) in coarse.iter().zip(&kept).filter(|(_, k)| **k) {
        for i in held_by(c, &fine, &by_x) {
            dropped[i] = true;
        }
    }
    let mut k = kept.iter();
    coarse.retain(|_| k.next().copied().unwrap_or(false));
    let mut d = dropped.iter();
    fine.retain(|_| !d.next().copied().unwrap_or(false));
    fine.extend(coarse);
    fine
}

/// Whether the small scale's blob `f` lies inside the large scale's blob `c` (its centre
/// within `c`'s radius and a pixel).
fn inside(c: &Detection, f: &Detection) -> bool {
    (c.centre_px - f.centre_px).norm() <= 0.5 * c.diameter_px + 1.0
}

/// The indices of the blobs of `fine` inside `c` ([`inside`]), `by_x` their centres' x
/// and indices in order of x.
fn held_by<'a>(
    c: &'a Detection,
    fine: &'a [Detection],
    by_x: &'a [(f64, usize)],
) -> impl Iterator<Item = usize> + 'a {
    // A pixel's margin over the reach in x: `norm` may round below `|dx|`.
    let reach = 0.5 * c.diameter_px + 2.0;
    let first = by_x.partition_point(|&(x, _)| x < c.centre_px.x - reach);
    by_x[first..]
        .iter()
        .take_while(move |&&(x, _)| x <= c.centre_px.x + reach)
        .map(|&(_, i)| i)
        .filter(move |&i| inside(c, &fine[i]))
}

/// How much longer than a whole dot of the small window scale (filling at least
/// [`WHOLE_MIN_FILL`] of its ellipse) a large blob around it may be and still be taken
/// for it ([`MarkerDetector::detect_two_scales`]).
const COARSE_MAX_OVER_WHOLE: f64 = 1.5;

/// The least share of its ellipse a blob of the small window scale fills to be a whole
/// dot, not a large dot's ring (a filled ellipse measures 0.85-1.05 with its rim).
const WHOLE_MIN_FILL: f64 = 0.7;

/// The share of the ellipse of its second moments that detection `d` fills.
fn ellipse_fill(d: &Detection) -> f64 {
    d.area_px as f64 / (std::f64::consts::FRAC_PI_4 * d.diameter_px * (d.diameter_px * d.roundness))
}

/// Smallest roundness of a blob of the large window scale: a large dot seen up to about 60°
/// from its normal (more slanted, it is narrow enough for the small scale).
const COARSE_MIN_ROUNDNESS: f64 = 0.5;

/// A blob of the large window scale measured on its blocks at half resolution below this
/// roundness is not measured on its image pixels (see [`measure_blob`]): at most
/// [`COARSE_MIN_ROUNDNESS`] there (blocks fill a blob's ragged rim, so they measure it
/// rounder than its pixels do).
const BLOCKS_MIN_ROUNDNESS: f64 = 0.9 * COARSE_MIN_ROUNDNESS;

/// Likewise, the least diameter measured on its blocks, in units of the widest blob the
/// small scale handles ([`small_scale_limit_px`]): blocks measure a blob at least as wide as
/// its pixels do.
const BLOCKS_MIN_DIAMETER: f64 = 0.9;

/// Below this roundness a blob's centroid is weighed against the background plane of its
/// ring (see [`background_plane`]), at and above it against the ring's median.
const THIN_BLOB_ROUNDNESS: f64 = 0.5;

/// Width of a blob's antialiased rim weighed into its centroid, pixels.
const RIM_PX: usize = 2;

/// Largest component kept whole for splitting, pixels.
const MAX_COMPONENT_PX: usize = 20_000;

/// Smallest peak contrast of a dot found by splitting a component, in units of
/// [`DetectParams::min_peak_contrast_dn`] (ink is much darker than a crease).
const SPLIT_MIN_CONTRAST_FACTOR: f64 = 2.0;

/// Smallest area of a dot found by splitting a component, in units of
/// [`DetectParams::min_area_px`].
const SPLIT_MIN_AREA_FACTOR: usize = 2;

/// Below this roundness a dot's blob is checked for hair across it ([`hair_free_core`]).
const HAIR_CHECK_BELOW_ROUNDNESS: f64 = 0.6;

/// Below this fill of its second moments' ellipse (area over `π/4 · major · minor`) a
/// thin blob is checked for hair across it: a dot, seen from any angle, fills it (0.85–1.05
/// on the synth presets); hair across one adds length and few pixels.
const HAIR_CHECK_BELOW_FILL: f64 = 0.8;

/// Smallest roundness of a dot found under hair ([`hair_free_core`]): a dot seen up to
/// about 66° from its normal (0.5, 60°, missed a dot seen 55° from its normal whose core
/// kept a stub of the hair: roundness 0.49, its centre 0.27 px from the dot's).
const HAIR_FREE_MIN_ROUNDNESS: f64 = 0.4;

/// How much rounder than its component a dot found under hair must be.
const HAIR_FREE_ROUNDNESS_GAIN: f64 = 0.2;

/// Smallest minor axis of a dot found under hair, pixels: the opening of a dot seen
/// edge-on (two or three pixels wide) can leave a short, round stub of its middle, at
/// most five pixels across (this much as a minor axis `4√λ₂`).
const HAIR_FREE_MIN_WIDTH_PX: f64 = 6.5;

/// A blob filling less of its ellipse than this is looked at for a dot under hair whatever
/// its roundness ([`split_and_measure`]); a dot fills 0.85-1.05 of it, a dot with hair
/// strokes around it (cluttered seed 77's M039: 37 px across where the dot is 19 px long,
/// roundness 0.63) 0.37.
const HAIR_CHECK_SPOKES_FILL: f64 = 0.5;

/// A dot found under hair may be no rounder than its component when it fills at least
/// this share of its ellipse (a dot seen edge-on with a hair across its end: the stroke
/// adds length and few pixels, the core is a filled ellipse; a dot fills 0.85-1.05).
const HAIR_FREE_MIN_FILL: f64 = 0.85;

/// Smallest share of its component's pixels a dot found under hair holds.
const HAIR_FREE_MIN_SHARE: f64 = 0.4;

/// What the components of a candidate mask are measured with: the image, the settings,
/// and the grid the components' pixels are in.
#[derive(Debug, Clone, Copy)]
struct Measuring<'a> {
    /// The image, at full resolution: blobs are measured in it.
    image: &'a GrayImage,
    /// The filters.
    params: &'a DetectParams,
    /// The image at half resolution when the components were found there (their pixel
    /// `(x, y)` is the image's block `[2x, 2x + 2) × [2y, 2y + 2)`), None when in the
    /// image itself.
    grid: Option<&'a GrayImage>,
    /// Side of a pixel of the components' grid, image pixels: 2 at half resolution, else 1.
    scale: usize,
    /// Smallest area of a blob or part worth measuring, image pixels (0: the filters'
    /// smallest area).
    min_px: usize,
    /// At half resolution, the smallest diameter of a blob worth measuring on its image
    /// pixels, pixels (see [`measure_blob`]).
    min_diameter_px: f64,
    /// Where a detection's centre is worth having (see
    /// [`MarkerDetector::detect_in_windows_near`]), None: anywhere. A blob or part whose
    /// box, grown by the rim the centroid weighs ([`RIM_PX`]), meets none of them is not
    /// measured.
    near: Option<&'a RectGrid<'a>>,
    /// The search windows the components were found in (in the grid of the components'
    /// pixels), None: the whole region. A blob that reaches their border may be part of a
    /// larger one beyond them ([`split_and_measure`]).
    windows: Option<&'a SearchWindows>,
}

impl<'a> Measuring<'a> {
    /// Measuring in `image` with `params` of components found in `grid` (None: in the
    /// image), none smaller than `min_px` image pixels; no diameter floor, anywhere.
    fn new(
        image: &'a GrayImage,
        params: &'a DetectParams,
        grid: Option<&'a GrayImage>,
        min_px: usize,
    ) -> Self {
        Self {
            image,
            params,
            grid,
            scale: if grid.is_some() { 2 } else { 1 },
            min_px,
            min_diameter_px: 0.0,
            near: None,
            windows: None,
        }
    }

    /// Whether a detection inside the box `(x0, y0, x1, y1)` of the grid (inclusive) can
    /// have its centre where it is worth having ([`Measuring::near`]).
    fn near_centres(&self, (x0, y0, x1, y1): (u32, u32, u32, u32)) -> bool {
        let Some(grid) = self.near else {
            return true;
        };
        let (s, rim) = (self.scale as i64, RIM_PX as i64);
        let lo = |v: u32| i64::from(v) * s - rim;
        let hi = |v: u32| i64::from(v) * s + s - 1 + rim;
        grid.meets_any((lo(x0), lo(y0), hi(x1), hi(y1)))
    }

    /// The area of `n` pixels of the grid, image pixels.
    fn area(&self, n: usize) -> usize {
        n * self.scale * self.scale
    }

    /// Smallest area of a blob or part measured, image pixels.
    fn floor_px(&self) -> usize {
        self.params.min_area_px.max(self.min_px)
    }
}

/// Measures a component of candidate pixels `(x, y, contrast)`; when it is too big or not
/// round (a dot touching a dark shading band or crease), splits it by raising the contrast
/// threshold (×1.6 per level, up to 4 levels) and measures the parts: dots inside
/// uneven shading are found like MSER regions. Parts smaller than
/// [`Measuring::floor_px`] are not measured.
fn split_and_measure(
    measuring: Measuring,
    pixels: &[(usize, usize, u8)],
    threshold: u32,
    depth: usize,
    out: &mut Vec<Detection>,
    mut rejected: Option<&mut Vec<Rejection>>,
    by_rim: Option<&mut Vec<Detection>>,
) {
    let params = measuring.params;
    let area = measuring.area(pixels.len());
    if area < measuring.floor_px() {
        return;
    }
    let mut reason = RejectReason::TooLarge;
    if area <= params.max_area_px {
        // A thin blob may be a dot with hair across it: its core without the hair, when
        // that is a rounder dot, is the dot.
        // Worth a look: a blob that does not fill its ellipse as a dot does (a stroke
        // across a dot adds length, not area), and wide enough to hold a core. The core
        // holds a share `s` of the pixels, so the blob's second moments are at least `s`
        // times the core's in every direction, and its minor axis at least `√s` times
        // the core's.
        let core_fits = |d: &Detection| {
            ellipse_fill(d) < HAIR_CHECK_BELOW_FILL
                && d.diameter_px * d.roundness
                    >= HAIR_FREE_MIN_SHARE.sqrt() * HAIR_FREE_MIN_WIDTH_PX
        };
        // Hair strokes around a dot seen obliquely may also make a rounder blob, which
        // fills far less of its ellipse than any dot: its core need not be rounder.
        let without_hair = |d: Detection| {
            if d.roundness < HAIR_CHECK_BELOW_ROUNDNESS && core_fits(&d) {
                hair_free_core(measuring, pixels, d.roundness).unwrap_or(d)
            } else if ellipse_fill(&d) < HAIR_CHECK_SPOKES_FILL && core_fits(&d) {
                hair_free_core(measuring, pixels, 0.0).unwrap_or(d)
            } else {
                d
            }
        };
        let found = if depth == 0 {
            measure_blob(measuring, pixels).map(without_hair)
        } else {
            // Parts of a split component: dots of some size and clearly dark (the
            // fragments of a crease are small and faint). A thin part is held to the
            // rules of a foreshortened dot by `measure_blob`: a dot seen edge-on in a
            // shading band is found only by splitting it off the band. A part that is a
            // dot with hair strokes about it (hair as dark as the ink stays with the dot
            // when the threshold splits off the faint skin its component also held) is
            // looked at for the dot under the hair when it fills less of its ellipse
            // than any dot or dot merged with a blob beside it does
            // ([`HAIR_CHECK_SPOKES_FILL`]) and covers its own centre (an arc of a ring,
            // the small window's view of a large dot, does not).
            measure_blob(measuring, pixels).and_then(|d| {
                if d.area_px < SPLIT_MIN_AREA_FACTOR * params.min_area_px {
                    Err(RejectReason::NotRound)
                } else if d.contrast_dn < SPLIT_MIN_CONTRAST_FACTOR * params.min_peak_contrast_dn {
                    Err(RejectReason::LowContrast)
                } else if ellipse_fill(&d) < HAIR_CHECK_SPOKES_FILL
                    && covers_its_centre(measuring, pixels, &d)
                {
                    Ok(without_hair(d))
                } else {
                    Ok(d)
                }
            })
        };
        match found {
            Ok(d) => {
                // At half resolution, a blob longer than any dot that the search windows'
                // border cuts may be a large dot and part of a band it touches beyond them
                // (the mouth line beside a lip dot): measured whole, its centre lies
                // between the two, where the whole image has one blob too large to be a
                // dot, which splits. Its parts at a higher threshold first, as that
                // blob's; the blob itself when no part is a dot. Only a blob too thin to
                // be kept as a large dot ([`COARSE_MIN_ROUNDNESS`]), one that would be
                // lost anyway: a rounder one is weighed against the small scale's blobs
                // (`merge_scales`), and splitting those too lost a frame of cluttered's
                // M100, a smudged dot at the mouth line.
                if let (Some(half), Some(windows)) = (measuring.grid, measuring.windows)
                    && d.diameter_px > params.elongated_max_length_px
                    && d.roundness < COARSE_MIN_ROUNDNESS
                    && !windows.hold_with_border(
                        grid_box(pixels),
                        (half.width as usize, half.height as usize),
                    )
                {
                    let found_before = out.len();
                    let next = (threshold as f64 * 1.6).ceil() as u32 + 1;
                    if depth < 4 && next <= 255 {
                        split_at(measuring, pixels, next, depth, out, rejected.as_deref_mut());
                    }
                    if out.len() > found_before {
                        return;
                    }
                }
                out.push(d);
                return;
            }
            Err(r) => reason = r,
        }
    }
    let found_before = out.len();
    let next = (threshold as f64 * 1.6).ceil() as u32 + 1;
    // A dot cut by the image's edge stays cut at any threshold, but its core at a higher
    // one is smaller and measures a smaller pull: it is not split.
    let cut_by_edge = reason == RejectReason::AtImageEdge;
    if depth < 4 && next <= 255 && !cut_by_edge {
        split_at(measuring, pixels, next, depth, out, rejected.as_deref_mut());
    }
    let split_end = out.len();
    // A smeared dot (sweat, a wipe) is longer than a dot and may be split in pieces, none
    // of them centred on the ink: the whole smear is reported too, when it is an ellipse
    // up to `SMEAR_MAX_LENGTH` dots long (the labeler takes such a blob only where the
    // marker's neighbours put it).
    if depth == 0
        && out.len() >= found_before + 2
        && matches!(reason, RejectReason::NotRound | RejectReason::TooLarge)
        && pieces_alike(&out[found_before..])
        && let Some(smear) = whole_smear(measuring, pixels)
    {
        out.push(smear);
    }
    // Hair as dark as the ink does not split off at any threshold: the component's core
    // without it (when the component is dark enough, and wide enough to hold one: see
    // `core_fits` above).
    if depth == 0
        && out.len() == found_before
        && reason != RejectReason::LowContrast
        && !cut_by_edge
        && HAIR_FREE_MIN_SHARE.sqrt() * HAIR_FREE_MIN_WIDTH_PX
            <= 4.0 * measuring.scale as f64 * second_moments(pixels).1.max(0.0).sqrt()
        && let Some(core) = hair_free_core(measuring, pixels, 0.0)
    {
        out.push(core);
    }
    // A dot seen far from its normal and smeared along its length is one thin streak,
    // thinner than any dot and in no pieces: reported whole when it is a filled ellipse.
    if depth == 0
        && out.len() == found_before
        && reason == RejectReason::NotRound
        && let Some(smear) = whole_smear(measuring, pixels)
    {
        out.push(smear);
    }
    // A dot a dark band touches (a crease, the mouth line's shadow) splits off it only in
    // part, its side away from the band: the dot whose rim shows around such a part is
    // reported too (module `rim`), once detection is done (`by_rim`), and only in a band
    // at least three times as long as the dot: a smear (a smudged dot with a hair across
    // it measured twice as long as the ellipse fitted to its upper half, cluttered seed
    // 33's M035) or a dot merged with a mole is the smear's and the labeler's lobes'
    // business.
    if let Some(by_rim) = by_rim
        && depth == 0
        && matches!(reason, RejectReason::NotRound | RejectReason::TooLarge)
        && split_end > found_before
    {
        let length = 4.0 * measuring.scale as f64 * second_moments(pixels).0.max(0.0).sqrt();
        // The dot is at least `MIN_AREA_GAIN` times the piece's area, so at least this long.
        let shortest = |piece: &Detection| {
            2.0 * (MIN_AREA_GAIN * piece.area_px as f64 / std::f64::consts::PI).sqrt()
        };
        for piece in &out[found_before..split_end] {
            if length >= RIM_MIN_BAND_LENGTH * shortest(piece)
                && let Some(dot) =
                    dot_by_its_rim(measuring.image, params, piece, length / RIM_MIN_BAND_LENGTH)
                && !out[found_before..].iter().any(|o| same_dot(o, &dot))
                && !by_rim.iter().any(|o| same_dot(o, &dot))
            {
                by_rim.push(dot);
            }
        }
    }
    // A blob none of whose parts is a dot is listed once, at the top of its splitting.
    if depth == 0
        && out.len() == found_before
        && let Some(list) = rejected
    {
        let n = pixels.len() as f64;
        let (sx, sy) = pixels.iter().fold((0.0, 0.0), |(a, b), &(x, y, _)| {
            (a + x as f64, b + y as f64)
        });
        // The centre of the mean grid pixel, in image pixels.
        let (s, half) = (measuring.scale as f64, 0.5 * (measuring.scale - 1) as f64);
        list.push(Rejection {
            centre_px: Point2::new(s * sx / n + half, s * sy / n + half),
            area_px: area,
            reason,
        });
    }
}

/// A component a dot is found in by its rim ([`dot_by_its_rim`]) is at least this many
/// times as long as the dot: a band the dot touches (the mouth line that cluttered's M100
/// touches in cam0 makes a component 340 px long; at twice the dot, the upper half of a
/// smudged dot a hair crosses was fitted as a dot and labeled 6.5 px off its marker).
const RIM_MIN_BAND_LENGTH: f64 = 3.0;

/// The box `(x0, y0, x1, y1)` (inclusive) of a set of pixels `(x, y, level)`.
fn grid_box(pixels: &[(usize, usize, u8)]) -> (usize, usize, usize, usize) {
    pixels.iter().fold(
        (usize::MAX, usize::MAX, 0, 0),
        |(a, b, c, d), &(x, y, _)| (a.min(x), b.min(y), c.max(x), d.max(y)),
    )
}

/// Two detections are the same dot when their centres and their diameters differ by at
/// most this share of a diameter.
const RIM_SAME_DOT: f64 = 0.25;

/// Whether `a` is the dot `b` is (see [`RIM_SAME_DOT`]).
fn same_dot(a: &Detection, b: &Detection) -> bool {
    (a.centre_px - b.centre_px).norm() <= RIM_SAME_DOT * b.diameter_px
        && (a.diameter_px - b.diameter_px).abs() <= RIM_SAME_DOT * b.diameter_px
}

/// Whether `a` is larger than `b` and `b`'s centre lies inside `a`'s ellipse.
fn holds(a: &Detection, b: &Detection) -> bool {
    if !(a.diameter_px > b.diameter_px && a.axis_rad.is_finite()) {
        return false;
    }
    let (semi_major, semi_minor) = (0.5 * a.diameter_px, 0.5 * a.diameter_px * a.roundness);
    let d = b.centre_px - a.centre_px;
    let (c, s) = (a.axis_rad.cos(), a.axis_rad.sin());
    let (u, v) = (d.x * c + d.y * s, -d.x * s + d.y * c);
    semi_minor > 0.0 && (u / semi_major).powi(2) + (v / semi_minor).powi(2) <= 1.0
}

/// How long a smeared dot reported whole beside its pieces may be, in the longest dot's
/// lengths ([`split_and_measure`]).
const SMEAR_MAX_LENGTH: f64 = 2.5;

/// The smallest share of its ellipse a smeared dot reported whole fills.
const SMEAR_MIN_FILL: f64 = 0.8;

/// Whether the two largest of the parts a component split into are alike in area (the
/// smaller at least a third of the larger): a smear breaks into pieces of its ink, a dot
/// with a hair or a crease across to a freckle into the dot and a lesser blob.
fn pieces_alike(parts: &[Detection]) -> bool {
    let mut areas: Vec<usize> = parts.iter().map(|d| d.area_px).collect();
    areas.sort_unstable_by(|a, b| b.cmp(a));
    areas.len() >= 2 && 3 * areas[1] >= areas[0]
}

/// A component measured as a smeared dot: an ellipse at most [`SMEAR_MAX_LENGTH`] times as
/// long as the longest dot, filled as an ellipse ([`SMEAR_MIN_FILL`]), and as thin as a
/// dot seen edge-on smeared to that length (roundness down to
/// [`DetectParams::elongated_min_roundness`] over the same factor); one thinner than any
/// whole dot is told as a [`Detection::streak`]. Its contrast need only be a dot's
/// ([`DetectParams::min_peak_contrast_dn`], not the elongated factor above it): a smear
/// keeps 45-75 % of the ink (cluttered's M067, seen 77° from its normal, measured 23-26
/// levels and fell under the 22.5 of a thin dot in every third frame).
fn whole_smear(measuring: Measuring, pixels: &[(usize, usize, u8)]) -> Option<Detection> {
    let params = measuring.params;
    let scale = SMEAR_MAX_LENGTH / 1.25;
    let relaxed = DetectParams {
        elongated_max_length_px: params.elongated_max_length_px * scale,
        elongated_min_roundness: params.elongated_min_roundness / scale,
        elongated_min_contrast_factor: 1.0,
        max_area_px: (params.max_area_px as f64 * scale * scale).ceil() as usize,
        ..params.clone()
    };
    if measuring.area(pixels.len()) > relaxed.max_area_px {
        return None;
    }
    let relaxed_measuring = Measuring {
        params: &relaxed,
        ..measuring
    };
    let mut d = measure_blob(relaxed_measuring, pixels).ok()?;
    d.streak = d.roundness < params.elongated_min_roundness;
    (ellipse_fill(&d) >= SMEAR_MIN_FILL).then_some(d)
}

/// Whether the grid pixel at detection `d`'s centre is one of its blob's `pixels` (in
/// the grid of `measuring`): a blob filled around its centre, not a ring or an arc.
fn covers_its_centre(measuring: Measuring, pixels: &[(usize, usize, u8)], d: &Detection) -> bool {
    let s = measuring.scale as f64;
    // Grid pixel `x` has its centre at image pixel `s·x + (s − 1)/2`.
    let at = |v: f64| (v - 0.5 * (s - 1.0)) / s;
    let (x, y) = (at(d.centre_px.x).round(), at(d.centre_px.y).round());
    x >= 0.0
        && y >= 0.0
        && pixels
            .iter()
            .any(|&(px, py, _)| px as f64 == x && py as f64 == y)
}

/// The dot inside a component of candidate pixels that hair (or any other stroke at most
/// two pixels wide) crosses or touches: the component's morphological opening by a 3×3
/// square removes such strokes and leaves whatever is at least three pixels wide whole.
/// Some when exactly one part of the opening is a dot (by [`measure_blob`]) markedly
/// rounder than the component's own `roundness` (0 when it was not measured): at least
/// [`HAIR_FREE_MIN_ROUNDNESS`] and [`HAIR_FREE_ROUNDNESS_GAIN`] above it, or filling its
/// ellipse as a dot does ([`HAIR_FREE_MIN_FILL`]; a dot seen edge-on with a hair across
/// its end is no rounder without the hair), at least
/// [`HAIR_FREE_MIN_WIDTH_PX`] wide and holding [`HAIR_FREE_MIN_SHARE`] of the component's
/// pixels: a dot seen edge-on is not turned into a piece of itself, and a freckle a hair
/// touches is not taken for the dot of a component that is mostly hair.
///
/// An eyebrow hair is about 0.1 mm wide, under a pixel on any helmet camera; the ink,
/// 1.5–4 mm across, is several pixels wide even seen at 75°.
fn hair_free_core(
    measuring: Measuring,
    pixels: &[(usize, usize, u8)],
    roundness: f64,
) -> Option<Detection> {
    let params = measuring.params;
    let min_area = SPLIT_MIN_AREA_FACTOR * params.min_area_px;
    let area = |n: usize| measuring.area(n);
    // Too small to hold a dot and hair (or a part worth measuring), or so large that its
    // share would be larger than any dot.
    if area(pixels.len()) < (2 * min_area).max(measuring.min_px)
        || HAIR_FREE_MIN_SHARE * area(pixels.len()) as f64 > params.max_area_px as f64
    {
        return None;
    }
    let min_px = (HAIR_FREE_MIN_SHARE * area(pixels.len()) as f64).ceil() as usize;
    let opened = opening_3x3(pixels);
    if area(opened.len()) < min_area.max(min_px).max(measuring.min_px)
        || opened.len() == pixels.len()
    {
        return None;
    }
    let min_roundness = HAIR_FREE_MIN_ROUNDNESS.max(roundness + HAIR_FREE_ROUNDNESS_GAIN);
    let mut found = None;
    let mut count = 0;
    for_each_part(&opened, |part| {
        // A part larger than any dot (a nostril, the mouth) is not one.
        if area(part.len()) < min_area.max(min_px) || area(part.len()) > params.max_area_px {
            return;
        }
        if let Ok(d) = measure_blob(measuring, part)
            && (d.roundness >= min_roundness
                || (ellipse_fill(&d) >= HAIR_FREE_MIN_FILL
                    && d.roundness >= params.elongated_min_roundness))
            && d.diameter_px * d.roundness >= HAIR_FREE_MIN_WIDTH_PX
        {
            count += 1;
            found = Some(d);
        }
    });
    if count == 1 { found } else { None }
}

/// The morphological opening of a set of pixels `(x, y, level)` by a 3×3 square: the
/// pixels of the set within one pixel (8-neighbourhood) of a pixel whose whole 3×3
/// neighbourhood is in the set. Worked on each row's runs, so a long thin stroke costs its
/// pixels, not its bounding box.
fn opening_3x3(pixels: &[(usize, usize, u8)]) -> Vec<(usize, usize, u8)> {
    let mut sorted;
    let pixels = if pixels.is_sorted_by_key(|p| (p.1, p.0)) {
        pixels
    } else {
        sorted = pixels.to_vec();
        sorted.sort_unstable_by_key(|p| (p.1, p.0));
        &sorted[..]
    };
    let (Some(first), Some(last)) = (pixels.first(), pixels.last()) else {
        return Vec::new();
    };
    let (y0, rows) = (first.1, last.1 - first.1 + 1);
    // Centres of three pixels in a row (each run shrunk by one at both ends), as
    // inclusive column ranges, row by row: row k's are `centres[starts[k]..starts[k + 1]]`.
    let mut centres: Vec<(usize, usize)> = Vec::new();
    let mut starts = vec![0usize; rows + 1];
    let mut run: Option<(usize, usize, usize)> = None;
    let close = |r: (usize, usize, usize), centres: &mut Vec<(usize, usize)>| {
        if r.2 >= r.1 + 2 {
            centres.push((r.1 + 1, r.2 - 1));
        }
    };
    for &(x, y, _) in pixels {
        match run {
            Some((ry, a, b)) if ry == y && x <= b + 1 => run = Some((ry, a, b.max(x))),
            _ => {
                if let Some(r) = run {
                    close(r, &mut centres);
                }
                let first_row = run.map_or(0, |r| r.0 - y0 + 1);
                starts[first_row..=y - y0].fill(centres.len());
                run = Some((y, x, x));
            }
        }
    }
    if let Some(r) = run {
        close(r, &mut centres);
    }
    starts[rows] = centres.len();
    let row = |k: usize| &centres[starts[k]..starts[k + 1]];
    // The erosion: centres of three in each of three rows; row k's are
    // `eroded[marks[k]..marks[k + 1]]`.
    let mut eroded: Vec<(usize, usize)> = Vec::new();
    let mut marks = vec![0usize; rows + 1];
    for (k, mark) in marks.iter_mut().enumerate().take(rows) {
        *mark = eroded.len();
        if k > 0 && k + 1 < rows && !row(k).is_empty() {
            let middle = intersect_ranges(row(k - 1), row(k));
            eroded.extend(intersect_ranges(&middle, row(k + 1)));
        }
    }
    marks[rows] = eroded.len();
    if eroded.is_empty() {
        return Vec::new();
    }
    // The dilation of the erosion within the set: a pixel next to an eroded one in the
    // rows around.
    pixels
        .iter()
        .copied()
        .filter(|&(x, y, _)| {
            let k = y - y0;
            (k.saturating_sub(1)..=(k + 1).min(rows - 1)).any(|j| {
                eroded[marks[j]..marks[j + 1]]
                    .iter()
                    .any(|r| r.0 <= x + 1 && x <= r.1 + 1)
            })
        })
        .collect()
}

/// The intersection of two sorted lists of disjoint inclusive ranges.
fn intersect_ranges(a: &[(usize, usize)], b: &[(usize, usize)]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        let (lo, hi) = (a[i].0.max(b[j].0), a[i].1.min(b[j].1));
        if lo <= hi {
            out.push((lo, hi));
        }
        if a[i].1 < b[j].1 {
            i += 1;
        } else {
            j += 1;
        }
    }
    out
}

/// Calls `f` with each 8-connected part of `pixels` (its pixels `(x, y, level)`, levels
/// non-zero).
fn for_each_part(pixels: &[(usize, usize, u8)], mut f: impl FnMut(&[(usize, usize, u8)])) {
    if pixels.is_empty() {
        return;
    }
    let (bx0, by0, bx1, by1) = grid_box(pixels);
    // The box with a border of empty pixels, so that every pixel of the set has all its
    // eight neighbours in the grid: pixel (x, y) at `(x − bx0 + 1, y − by0 + 1)`.
    let gw = bx1 - bx0 + 3;
    let mut grid = vec![0u8; gw * (by1 - by0 + 3)];
    let at = |x: usize, y: usize| (y - by0 + 1) * gw + (x - bx0 + 1);
    for &(x, y, lv) in pixels {
        grid[at(x, y)] = lv.max(1);
    }
    let mut stack = Vec::new();
    let mut part = Vec::new();
    for &(sx, sy, _) in pixels {
        let s0 = at(sx, sy);
        if grid[s0] == 0 {
            continue;
        }
        stack.push((sx, sy));
        part.clear();
        part.push((sx, sy, grid[s0]));
        grid[s0] = 0;
        while let Some((x, y)) = stack.pop() {
            let i = at(x, y);
            for (row, ny) in [(i - gw, y.wrapping_sub(1)), (i, y), (i + gw, y + 1)] {
                for (j, nx) in [(row - 1, x.wrapping_sub(1)), (row, x), (row + 1, x + 1)] {
                    if grid[j] != 0 {
                        part.push((nx, ny, grid[j]));
                        grid[j] = 0;
                        stack.push((nx, ny));
                    }
                }
            }
        }
        f(&part);
    }
}

/// The parts of a component above the raised contrast threshold `next`, each measured (or
/// split further) by [`split_and_measure`].
fn split_at(
    measuring: Measuring,
    pixels: &[(usize, usize, u8)],
    next: u32,
    depth: usize,
    out: &mut Vec<Detection>,
    mut rejected: Option<&mut Vec<Rejection>>,
) {
    let kept: Vec<(usize, usize, u8)> = pixels
        .iter()
        .copied()
        .filter(|p| u32::from(p.2) >= next)
        .collect();
    if measuring.area(kept.len()) < measuring.floor_px() {
        return;
    }
    for_each_part(&kept, |part| {
        let (x0, y0, x1, y1) = grid_box(part);
        if !measuring.near_centres((x0 as u32, y0 as u32, x1 as u32, y1 as u32)) {
            return;
        }
        split_and_measure(
            measuring,
            part,
            next,
            depth + 1,
            out,
            rejected.as_deref_mut(),
            None,
        );
    });
}

/// The eigenvalues `λ₁ ≥ λ₂` of the covariance of a set of pixels, each pixel counted as
/// its square (`+1/12` per axis), and the direction of `λ₁`'s eigenvector (radians from
/// +x towards +y, in `[−π/2, π/2]`).
fn second_moments(pixels: &[(usize, usize, u8)]) -> (f64, f64, f64) {
    let n = pixels.len() as f64;
    let (mut mx, mut my) = (0.0, 0.0);
    for &(x, y, _) in pixels {
        mx += x as f64;
        my += y as f64;
    }
    mx /= n;
    my /= n;
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    for &(x, y, _) in pixels {
        let dx = x as f64 - mx;
        let dy = y as f64 - my;
        sxx += dx * dx;
        syy += dy * dy;
        sxy += dx * dy;
    }
    let (a, b, cc) = (sxx / n + 1.0 / 12.0, syy / n + 1.0 / 12.0, sxy / n);
    let tr = a + b;
    let disc = ((a - b).powi(2) / 4.0 + cc * cc).sqrt();
    (
        tr / 2.0 + disc,
        tr / 2.0 - disc,
        0.5 * (2.0 * cc).atan2(a - b),
    )
}

/// Filters and measures one blob, a set of pixels of the grid of `measuring`, in the
/// image; the reason when it fails a filter. A blob found at half resolution is measured
/// on its blocks, and when that says it may be a large dot (at least
/// [`BLOCKS_MIN_ROUNDNESS`] round and wider than [`Measuring::min_diameter_px`]), again on
/// the largest connected part of its candidate pixels in the image
/// ([`full_resolution_pixels`]).
fn measure_blob(
    measuring: Measuring,
    pixels: &[(usize, usize, u8)],
) -> Result<Detection, RejectReason> {
    let Measuring {
        image,
        params,
        grid,
        ..
    } = measuring;
    let Some(half) = grid else {
        return measure_image_blob(image, pixels, params, 1, Centre::Weighted);
    };
    // Measured on its blocks first: a blob that fails there, or that cannot be a large
    // dot, is told so at a quarter of the cost (the large scale keeps only round blobs
    // wider than the small scale handles, see `MarkerDetector::detect_two_scales`). No
    // detection keeps the blocks' centre (a blob that cannot be a large dot is dropped
    // with it, one that may be is measured again below): it is measured for its shape.
    let blocks = measure_image_blob(image, pixels, params, 2, Centre::IfItDecides)?;
    if blocks.roundness < BLOCKS_MIN_ROUNDNESS || blocks.diameter_px <= measuring.min_diameter_px {
        return Ok(blocks);
    }
    let full = full_resolution_pixels(image, half, pixels, params);
    // Blobs a gap of a pixel or two keeps apart in the image may touch at half
    // resolution: the largest of the parts the image's pixels make is the blob.
    let mut largest: Vec<(usize, usize, u8)> = Vec::new();
    for_each_part(&full, |part| {
        if part.len() > largest.len() {
            largest = part.to_vec();
        }
    });
    if largest.len() < params.min_area_px.max(1) {
        return Err(RejectReason::LowContrast);
    }
    measure_image_blob(image, &largest, params, 1, Centre::Weighted)
}

/// The image pixels of a blob found at half resolution (pixels `(x, y, level)` of `half`,
/// [`half_resolution`]) that are candidates themselves: each pixel of its 2×2 block whose
/// contrast against the local mean the block's level tells (the block's value and its
/// level) is at least [`DetectParams::min_contrast_dn`], with that contrast as its level.
/// The blob so measured has the area, shape and rim the image gives it, not its blocks'.
fn full_resolution_pixels(
    image: &GrayImage,
    half: &GrayImage,
    pixels: &[(usize, usize, u8)],
    params: &DetectParams,
) -> Vec<(usize, usize, u8)> {
    let (w, hw) = (image.width as usize, half.width as usize);
    let c = params.min_contrast_dn as i32;
    let mut full = Vec::with_capacity(4 * pixels.len());
    for &(x, y, level) in pixels {
        let value = i32::from(half.data[y * hw + x]);
        let mean = if params.bright {
            value - i32::from(level)
        } else {
            value + i32::from(level)
        };
        for yy in 2 * y..2 * y + 2 {
            for xx in 2 * x..2 * x + 2 {
                let v = i32::from(image.data[yy * w + xx]);
                let contrast = if params.bright { v - mean } else { mean - v };
                if contrast >= c {
                    full.push((xx, yy, contrast.clamp(1, 255) as u8));
                }
            }
        }
    }
    full
}

/// What [`measure_image_blob`] gives as a blob's centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Centre {
    /// The weighted centroid over the blob and its rim (see [`measure_image_blob`]).
    Weighted,
    /// The weighted centroid only when it can decide whether the blob is a dot (it may
    /// find no weight, or the image's edge too close): otherwise the mean of the blob's
    /// pixels, for a blob measured for its shape, contrast and verdict only. The same
    /// verdict either way: the darkest pixel, `peak` above the background, weighs
    /// `0.9·peak > 0` against a constant background, and a centroid inside the box the
    /// weights cover is at least that box's distance from the image's edge.
    IfItDecides,
}

/// [`measure_blob`] of a set of pixels of a grid of side `s` (1: image pixels; 2: the
/// blocks of [`half_resolution`], each measured as its four image pixels), its centre as
/// `centre` asks.
fn measure_image_blob(
    image: &GrayImage,
    pixels: &[(usize, usize, u8)],
    params: &DetectParams,
    s: usize,
    centre: Centre,
) -> Result<Detection, RejectReason> {
    let (w, h) = (image.width as usize, image.height as usize);
    // A block of side s adds its own s²/12 per axis, as a pixel adds 1/12.
    let (l1, l2, axis_rad) = second_moments(pixels);
    let (l1, l2) = (l1 * (s * s) as f64, l2 * (s * s) as f64);
    let roundness = if l1 > 0.0 {
        (l2.max(0.0) / l1).sqrt()
    } else {
        0.0
    };
    let elongated = roundness < params.min_roundness;
    if elongated
        && !(params.accept_elongated
            && roundness >= params.elongated_min_roundness
            && 4.0 * l1.sqrt() <= params.elongated_max_length_px
            && 4.0 * l2.max(0.0).sqrt() >= params.elongated_min_width_px)
    {
        return Err(RejectReason::NotRound);
    }
    let (bx0, by0, bx1, by1) = grid_box(pixels);
    let (bx0, by0) = (bx0 * s, by0 * s);
    let (bx1, by1) = ((bx1 * s + s - 1).min(w - 1), (by1 * s + s - 1).min(h - 1));
    // Background ring: the border of the box grown by 3 pixels.
    let g = 3;
    let (rx0, ry0) = (bx0.saturating_sub(g), by0.saturating_sub(g));
    let (rx1, ry1) = ((bx1 + g).min(w - 1), (by1 + g).min(h - 1));
    // Its median, from a histogram of its levels.
    let mut histogram = [0u32; 256];
    let mut count = 0u32;
    for y in ry0..=ry1 {
        let row = &image.data[y * w..(y + 1) * w];
        if y == ry0 || y == ry1 {
            row[rx0..=rx1]
                .iter()
                .for_each(|&v| histogram[usize::from(v)] += 1);
            count += (rx1 - rx0 + 1) as u32;
        } else {
            histogram[usize::from(row[rx0])] += 1;
            count += 1;
            if rx1 != rx0 {
                histogram[usize::from(row[rx1])] += 1;
                count += 1;
            }
        }
    }
    let mut below = 0;
    let Some(median) = histogram.iter().position(|&n| {
        below += n;
        below > count / 2
    }) else {
        return Err(RejectReason::LowContrast);
    };
    let background = median as f64;
    let sign = if params.bright { -1.0 } else { 1.0 };
    // The least `sign × level` of a pixel (of its block's pixels): the darkest (brightest
    // for bright dots).
    let darkest = |&(x, y, _): &(usize, usize, u8)| -> f64 {
        if s == 1 {
            return sign * f64::from(image.data[y * w + x]);
        }
        let mut least = f64::MAX;
        for yy in y * s..((y + 1) * s).min(h) {
            for &v in &image.data[yy * w + x * s..yy * w + ((x + 1) * s).min(w)] {
                least = least.min(sign * f64::from(v));
            }
        }
        least
    };
    let peak = pixels
        .iter()
        .map(|p| sign * background - darkest(p))
        .fold(f64::MIN, f64::max);
    if peak < params.min_peak_contrast_dn
        || (elongated && peak < params.elongated_min_contrast_factor * params.min_peak_contrast_dn)
    {
        return Err(RejectReason::LowContrast);
    }
    // Weighted centroid over the blob grown by its rim, against the background: the ring's median,
    // or for a thin blob a plane fitted to the ring (a constant background would weigh the
    // darker side of shaded skin around a thin, foreshortened dot, and pull its centre
    // there).
    let thin = roundness < THIN_BLOB_ROUNDNESS;
    let (cx0, cy0) = (bx0.saturating_sub(RIM_PX), by0.saturating_sub(RIM_PX));
    let (cx1, cy1) = ((bx1 + RIM_PX).min(w - 1), (by1 + RIM_PX).min(h - 1));
    let diameter = 4.0 * l1.sqrt();
    let quality = (roundness * (peak / (peak + 40.0))).clamp(0.0, 1.0);
    let detection = |centre_px: Point2<f64>| Detection {
        centre_px,
        area_px: pixels.len() * s * s,
        roundness,
        contrast_dn: peak,
        quality,
        diameter_px: diameter,
        axis_rad,
        streak: false,
    };
    let box_room = (cx0 as f64 + 0.5)
        .min(cy0 as f64 + 0.5)
        .min(w as f64 - 0.5 - cx1 as f64)
        .min(h as f64 - 0.5 - cy1 as f64);
    if centre == Centre::IfItDecides && !thin && peak > 0.0 && box_room >= 0.5 * diameter {
        let n = pixels.len() as f64;
        let (sx, sy) = pixels.iter().fold((0.0, 0.0), |(a, b), &(x, y, _)| {
            (a + x as f64, b + y as f64)
        });
        // The centre of the mean grid pixel, in image pixels.
        let half = 0.5 * (s - 1) as f64;
        return Ok(detection(Point2::new(
            s as f64 * sx / n + half,
            s as f64 * sy / n + half,
        )));
    }
    let fit = thin.then(|| background_plane(image, (rx0, ry0, rx1, ry1), background));
    // Only pixels near the blob's own count: per row, the columns of the blob's pixels in
    // the rows within `RIM_PX`, grown by `RIM_PX` (its antialiased rim), not whatever else
    // is dark in its box (the black beyond the face's silhouette beside a dot seen
    // edge-on, a nostril, hair).
    let mut columns = vec![(usize::MAX, 0usize); cy1 - cy0 + 1];
    for &(x, y, _) in pixels {
        for yy in y * s..((y + 1) * s).min(h) {
            let c = &mut columns[yy - cy0];
            *c = (c.0.min(x * s), c.1.max((x * s + s - 1).min(w - 1)));
        }
    }
    // Ignore weights below a noise floor of 10 % of the peak.
    let floor = 0.1 * peak;
    let near = (cx0, cy0, cx1, cy1);
    let (sw, swx, swy) = match &fit {
        Some(plane) => weighted_sums(image, &columns, near, |x, y, v| {
            (sign * (plane(x, y) - f64::from(v)) - floor).max(0.0)
        }),
        None => weighted_sums(image, &columns, near, |_, _, v| {
            (sign * (background - f64::from(v)) - floor).max(0.0)
        }),
    };
    if sw <= 0.0 {
        return Err(RejectReason::LowContrast);
    }
    let centre = Point2::new(swx / sw, swy / sw);
    // A dot cut by the image's edge: its centroid is pulled inwards.
    let room = (centre.x + 0.5)
        .min(centre.y + 0.5)
        .min(w as f64 - 0.5 - centre.x)
        .min(h as f64 - 0.5 - centre.y);
    if edge_cut_bias_px(room, 0.5 * diameter) > params.max_edge_bias_px {
        return Err(RejectReason::AtImageEdge);
    }
    Ok(detection(centre))
}

/// The sums `Σw`, `Σw·x` and `Σw·y` of the weights `weight(x, y, level)` over the pixels
/// near a blob: per row of the box `(cx0, cy0, cx1, cy1)` (inclusive), the columns of the
/// blob's pixels in the rows within [`RIM_PX`] (`columns`, per row from `cy0`: the
/// blob's first and last column there), grown by [`RIM_PX`].
fn weighted_sums(
    image: &GrayImage,
    columns: &[(usize, usize)],
    (cx0, cy0, cx1, cy1): (usize, usize, usize, usize),
    weight: impl Fn(usize, usize, u8) -> f64,
) -> (f64, f64, f64) {
    let w = image.width as usize;
    let (mut sw, mut swx, mut swy) = (0.0, 0.0, 0.0);
    for y in cy0..=cy1 {
        let near_rows =
            &columns[y.saturating_sub(RIM_PX).max(cy0) - cy0..=(y + RIM_PX).min(cy1) - cy0];
        let (a, b) = near_rows
            .iter()
            .fold((usize::MAX, 0), |(a, b), c| (a.min(c.0), b.max(c.1)));
        if a > b {
            continue;
        }
        let xa = a.saturating_sub(RIM_PX).max(cx0);
        let row = &image.data[y * w..(y + 1) * w];
        for (x, &v) in (xa..=(b + RIM_PX).min(cx1)).zip(&row[xa..]) {
            // Branch-free: a weight of zero adds nothing.
            let wgt = weight(x, y, v);
            sw += wgt;
            swx += wgt * x as f64;
            swy += wgt * y as f64;
        }
    }
    (sw, swx, swy)
}

/// How far the image's edge pulls the centroid of a dot of radius `r` whose blob's centroid
/// is `room` pixels from the edge, pixels (0 when the dot is whole, `room ≥ r`).
///
/// A disc whose centre is `a·r` from the edge (`−1 < a < 1`) loses the cap beyond it, of
/// area `r²(acos a − a√(1−a²))` and first moment `⅔r³(1−a²)^{3/2}` about the centre: the
/// visible part's centroid is `s(a)·r` further in, `s(a) = ⅔(1−a²)^{3/2} / (π − acos a +
/// a√(1−a²))`, at `room = (a + s(a))·r`, which grows with `a` (bisection). The blob's
/// measured radius is the true one while the centre is inside (`a ≥ 0`: a cut leaves the
/// chord through the centre whole); deeper cuts shorten it, which still gives a pull far
/// above any tolerance.
pub fn edge_cut_bias_px(room: f64, r: f64) -> f64 {
    if r.is_nan() || r <= 0.0 || room.is_nan() || room >= r {
        return 0.0;
    }
    let pull = |a: f64| {
        let c = (1.0 - a * a).max(0.0);
        2.0 / 3.0 * c.powf(1.5) / (std::f64::consts::PI - a.acos() + a * c.sqrt())
    };
    let q = room / r;
    let (mut lo, mut hi) = (-1.0f64, 1.0f64);
    for _ in 0..40 {
        let mid = 0.5 * (lo + hi);
        if mid + pull(mid) < q {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    pull(0.5 * (lo + hi)) * r
}

/// The background around a blob as a plane `B(x, y) = a + b·(x − x̄) + c·(y − ȳ)`, fitted by
/// least squares to the border of the box `(x0, y0, x1, y1)` (inclusive) after dropping the
/// border pixels farther than 2.5 robust deviations from the border's `median` (other dots,
/// hair, a highlight); the median itself when too few pixels are left or the fit is
/// degenerate.
fn background_plane(
    image: &GrayImage,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    median: f64,
) -> impl Fn(usize, usize) -> f64 {
    let w = image.width as usize;
    let (xm, ym) = (0.5 * (x0 + x1) as f64, 0.5 * (y0 + y1) as f64);
    let border = || {
        (y0..=y1).flat_map(move |y| {
            // A row's border pixels: all of the first and last rows, the two ends of the
            // others.
            let step = if y == y0 || y == y1 {
                1
            } else {
                (x1 - x0).max(1)
            };
            (x0..=x1).step_by(step).map(move |x| {
                (
                    x as f64 - xm,
                    y as f64 - ym,
                    f64::from(image.data[y * w + x]),
                )
            })
        })
    };
    // The median absolute deviation from a histogram: pixels and the median are whole
    // levels, so the deviations are too (no allocation or sort per blob).
    let mut histogram = [0u32; 256];
    let mut count = 0usize;
    for (_, _, v) in border() {
        histogram[((v - median).abs() as usize).min(255)] += 1;
        count += 1;
    }
    let mut below = 0usize;
    let mad = histogram
        .iter()
        .position(|&h| {
            below += h as usize;
            below > count / 2
        })
        .map_or(0.0, |d| d as f64);
    let limit = (2.5 * 1.4826 * mad).max(2.0);
    // Normal equations of the plane over the kept border pixels.
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut r = nalgebra::Vector3::<f64>::zeros();
    let mut kept = 0usize;
    for (dx, dy, v) in border().filter(|&(_, _, v)| (v - median).abs() <= limit) {
        let q = nalgebra::Vector3::new(1.0, dx, dy);
        m += q * q.transpose();
        r += q * v;
        kept += 1;
    }
    let coef = if kept >= 8 {
        m.cholesky().map(|c| c.solve(&r))
    } else {
        None
    }
    .filter(|c| c.iter().all(|v| v.is_finite()))
    .unwrap_or_else(|| nalgebra::Vector3::new(median, 0.0, 0.0));
    move |x: usize, y: usize| coef[0] + coef[1] * (x as f64 - xm) + coef[2] * (y as f64 - ym)
}

/// A square 8-bit binary PGM (`P5`, `side × side`, maximum 255) held in memory: the crops
/// of rendered frames that tests detect in.
#[cfg(test)]
pub(super) fn pgm_image(bytes: &[u8], side: u32) -> GrayImage {
    let header = format!("P5\n{side} {side}\n255\n");
    assert_eq!(
        &bytes[..header.len()],
        header.as_bytes(),
        "not a {side}×{side} PGM"
    );
    let data = bytes[header.len()..].to_vec();
    assert_eq!(data.len(), (side * side) as usize);
    GrayImage {
        width: side,
        height: side,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A gradient-lit image with antialiased dark discs `(cx, cy, r)` at known subpixel
    /// centres.
    fn image_with_dots(dots: &[(f64, f64, f64)]) -> GrayImage {
        let discs: Vec<_> = dots
            .iter()
            .map(|&(cx, cy, r)| (cx, cy, r, r, 0.0))
            .collect();
        image_with_ellipses(&discs)
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

    /// The share of pixel `(x, y)` (pixel centres at integers) inside a region, from 8×8
    /// samples.
    fn coverage(x: u32, y: u32, inside: impl Fn(f64, f64) -> bool) -> f64 {
        let mut count = 0;
        for sy in 0..8 {
            for sx in 0..8 {
                let px = f64::from(x) - 0.4375 + 0.125 * f64::from(sx);
                let py = f64::from(y) - 0.4375 + 0.125 * f64::from(sy);
                count += u32::from(inside(px, py));
            }
        }
        f64::from(count) / 64.0
    }

    /// The position of `(px, py)` in the frame of ellipse `(cx, cy, a, b, angle)`: along
    /// its major axis and across it, pixels.
    fn ellipse_frame(
        &(cx, cy, _, _, angle): &(f64, f64, f64, f64, f64),
        px: f64,
        py: f64,
    ) -> (f64, f64) {
        let (sn, cs) = angle.sin_cos();
        let (dx, dy) = (px - cx, py - cy);
        (cs * dx + sn * dy, -sn * dx + cs * dy)
    }

    /// Whether `(px, py)` lies inside ellipse `e`.
    fn in_ellipse(e: &(f64, f64, f64, f64, f64), px: f64, py: f64) -> bool {
        let (u, t) = ellipse_frame(e, px, py);
        (u / e.2).powi(2) + (t / e.3).powi(2) < 1.0
    }

    /// A gradient-lit image with antialiased dark ellipses `(cx, cy, a, b, angle)`:
    /// semi-axes `a`, `b` (pixels), major axis at `angle` radians from the x axis.
    fn image_with_ellipses(ellipses: &[(f64, f64, f64, f64, f64)]) -> GrayImage {
        let (w, h) = (200u32, 120u32);
        let mut data = vec![0u8; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let mut v = 90.0 + 100.0 * f64::from(x) / f64::from(w);
                for e in ellipses {
                    let cov = coverage(x, y, |px, py| in_ellipse(e, px, py));
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
    fn centre_of_a_thin_dot_on_shaded_skin_is_not_pulled_by_the_shading() {
        // A dot seen ~73° from its normal (semi-axes 6 and 1.8 px) with its thin axis along
        // a steep shading gradient (4 levels per pixel).
        let (w, h) = (80u32, 60u32);
        let dot = (40.3, 30.6, 6.0, 1.8, 0.0);
        let (cx, cy) = (dot.0, dot.1);
        let mut data = vec![0u8; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let cov = coverage(x, y, |px, py| in_ellipse(&dot, px, py));
                // Faint ink (60 % of the skin's light), as on a dot that far from the
                // camera's axis.
                let skin = 60.0 + 4.0 * f64::from(y);
                data[(y * w + x) as usize] = (skin - 0.4 * skin * cov).round() as u8;
            }
        }
        let img = GrayImage {
            width: w,
            height: h,
            data,
        };
        let found = detect_markers(&img, &DetectParams::default());
        assert_eq!(found.len(), 1, "{found:?}");
        let d = &found[0];
        assert!(d.roundness < 0.5, "{d:?}");
        // The antialiasing quantized to whole levels leaves ~0.05 px; a constant
        // background put the centre 0.34 px towards the darker rows.
        let err = (d.centre_px - Point2::new(cx, cy)).norm();
        assert!(err < 0.15, "centre off by {err:.3} px: {d:?}");
    }

    #[test]
    fn finds_foreshortened_dots_but_not_creases() {
        // Dots of radius 3.75 px seen 76°, 79° and 80° from their normal (minor/major
        // 0.24, 0.19, 0.17), at subpixel centres, in three directions.
        let dots = [
            (40.3, 30.6, 3.75, 3.75 * 76f64.to_radians().cos(), 0.3),
            (100.7, 60.2, 3.75, 3.75 * 79f64.to_radians().cos(), 1.9),
            (160.45, 90.8, 3.75, 3.75 * 80f64.to_radians().cos(), 0.0),
        ];
        let img = image_with_ellipses(&dots);
        let mut found = detect_markers(&img, &DetectParams::default());
        found.sort_by(|a, b| a.centre_px.x.total_cmp(&b.centre_px.x));
        assert_eq!(found.len(), 3, "{found:?}");
        for (d, &(cx, cy, ..)) in found.iter().zip(&dots) {
            let err = (d.centre_px - Point2::new(cx, cy)).norm();
            assert!(err < 0.1, "{err} {d:?}");
        }
        // Without the elongated rule thin ones are rejected by roundness.
        let strict = DetectParams {
            accept_elongated: false,
            ..Default::default()
        };
        assert!(detect_markers(&img, &strict).len() < 3);
        // A crease-like dark streak 20 px long and 2 px wide, and a faint short one
        // (contrast of a shading band): neither is a dot (the dark one, thinner than any
        // dot, is told as a streak: a worn dot's blob at most).
        let streaks = image_with_ellipses(&[(60.0, 40.0, 10.0, 1.0, 0.5)]);
        let found = detect_markers(&streaks, &DetectParams::default());
        assert!(found.iter().all(|d| d.streak), "{found:?}");
        let mut faint = image_with_ellipses(&[]);
        let ink = image_with_ellipses(&[(120.0, 60.0, 3.75, 0.8, 0.0)]);
        for (f, i) in faint.data.iter_mut().zip(&ink.data) {
            // A fifth of the ink's darkness.
            *f = (f64::from(*f) - 0.2 * (f64::from(*f) - f64::from(*i))).round() as u8;
        }
        assert!(detect_markers(&faint, &DetectParams::default()).is_empty());
    }

    /// `base` with the ellipses `(cx, cy, a, b, angle)` darkened by `darkness` of the way
    /// to the ink of [`image_with_ellipses`] (1: full ink).
    #[test]
    fn a_large_dot_is_measured_on_its_own_pixels_beside_a_blob_half_resolution_joins() {
        // A dot 24 px across and a freckle 7 px across, 1.5 px apart: one blob at half
        // resolution (the gap is under two of its pixels), two in the image.
        let (cx, cy, r) = (100.3, 80.6, 12.0);
        let freckle = (cx + r + 1.5 + 3.5, cy + 2.0, 3.5, 70.0);
        let params = DetectParams::default();
        assert_eq!(params.window_scales().len(), 2);
        let near = |found: &[Detection]| {
            found
                .iter()
                .find(|d| (d.centre_px - Point2::new(cx, cy)).norm() < 3.0)
                .cloned()
                .unwrap_or_else(|| panic!("the large dot is not found: {found:?}"))
        };
        let alone = near(&detect_markers(
            &image_with_discs(&[(cx, cy, r, 70.0)]),
            &params,
        ));
        let beside = near(&detect_markers(
            &image_with_discs(&[(cx, cy, r, 70.0), freckle]),
            &params,
        ));
        // The dot is measured as when alone (the pair would pull its centre 1.4 px towards
        // the freckle), and as a disc of its size.
        assert!(
            (beside.centre_px - alone.centre_px).norm() < 0.05,
            "{beside:?} {alone:?}"
        );
        assert!(
            (beside.diameter_px - alone.diameter_px).abs() < 0.3,
            "{beside:?}"
        );
        assert!((beside.diameter_px - 2.0 * r).abs() < 1.0, "{beside:?}");
        assert!(beside.roundness > 0.95, "{beside:?}");
        let disc = std::f64::consts::PI * r * r;
        assert!(
            (beside.area_px as f64 - disc).abs() < 0.05 * disc,
            "{beside:?}"
        );
        assert!(
            (alone.centre_px - Point2::new(cx, cy)).norm() < 0.25,
            "{alone:?}"
        );
    }

    #[test]
    fn images_of_any_small_or_odd_size_are_detected_in_without_panic() {
        // Both window scales (the large one at half resolution) on images down to a pixel,
        // odd sides, whole and in windows reaching past the edges; a dark dot in the
        // larger ones.
        let params = DetectParams::default();
        assert_eq!(params.window_scales().len(), 2);
        let mut detector = MarkerDetector::new();
        for (w, h) in [(1, 1), (1, 7), (2, 2), (3, 5), (7, 3), (31, 17), (45, 45)] {
            let data = (0..w * h)
                .map(|i| {
                    let (x, y) = ((i % w) as f64, (i / w) as f64);
                    let r = ((x - 0.5 * w as f64).powi(2) + (y - 0.5 * h as f64).powi(2)).sqrt();
                    if r < 0.3 * w.min(h) as f64 { 40 } else { 200 }
                })
                .collect();
            let image = GrayImage {
                width: w as u32,
                height: h as u32,
                data,
            };
            let found = detector.detect(&image, &params);
            let windows = [
                (0, 0, 4, 4),
                (w as u32 / 2, h as u32 / 2, w as u32 + 9, h as u32 + 9),
            ];
            let centres = [(0, 0, w as u32 + 1, h as u32 + 1)];
            let near = detector.detect_in_windows_near(&image, &params, &windows, &centres);
            for d in found.iter().chain(&near) {
                assert!(
                    d.centre_px.x.is_finite() && d.centre_px.y.is_finite(),
                    "{d:?}"
                );
            }
            if (w, h) == (45, 45) {
                assert_eq!(found.len(), 1, "the dot in the 45 px image: {found:?}");
            }
        }
    }

    #[test]
    fn half_resolution_is_the_rounded_mean_of_each_block() {
        let image = GrayImage {
            width: 5,
            height: 3,
            data: vec![0, 1, 2, 3, 9, 4, 5, 6, 8, 9, 9, 9, 9, 9, 9],
        };
        let mut half = GrayImage::default();
        half_resolution(&image, &mut half, (0, 0, 2, 1));
        assert_eq!((half.width, half.height), (2, 1));
        // (0 + 1 + 4 + 5 + 2) / 4 = 3; (2 + 3 + 6 + 8 + 2) / 4 = 5 (19 / 4 rounds to 5).
        assert_eq!(half.data, vec![3, 5]);
    }

    #[test]
    fn half_resolution_of_any_region_is_each_blocks_rounded_mean() {
        // Widths around the sixteen-block stride, regions starting anywhere.
        for (w, h) in [(37, 5), (64, 4), (67, 7), (130, 3)] {
            let image = GrayImage {
                width: w,
                height: h,
                data: (0..w * h).map(|i| (i * 7919 % 251) as u8).collect(),
            };
            let (hw, hh) = (w as usize / 2, h as usize / 2);
            for x0 in [0, 1, 5] {
                let mut half = GrayImage::default();
                half_resolution(&image, &mut half, (x0, 0, hw, hh));
                for y in 0..hh {
                    for x in x0..hw {
                        let at = |xx: usize, yy: usize| u32::from(image.data[yy * w as usize + xx]);
                        let sum = at(2 * x, 2 * y)
                            + at(2 * x + 1, 2 * y)
                            + at(2 * x, 2 * y + 1)
                            + at(2 * x + 1, 2 * y + 1);
                        assert_eq!(
                            u32::from(half.data[y * hw + x]),
                            (sum + 2) / 4,
                            "{w}×{h} at ({x}, {y})"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn a_blob_measured_for_its_shape_gets_the_verdict_and_shape_of_a_weighted_one() {
        // Round, oblique, thin and edge-cut dots, alone and side by side, at both grids.
        let ellipses = [
            (30.3, 30.7, 8.0, 7.5, 0.2),
            (70.0, 40.2, 9.0, 3.0, 0.7),
            (110.6, 60.0, 10.0, 1.6, -0.4),
            (2.5, 80.0, 7.0, 7.0, 0.0),
            (150.0, 117.0, 6.0, 5.0, 0.3),
            (160.0, 30.0, 4.0, 3.5, 0.0),
            (168.0, 30.0, 4.0, 3.5, 0.0),
            (197.0, 5.0, 12.0, 9.0, 1.0),
        ];
        let image = image_with_ellipses(&ellipses);
        let mut half = GrayImage::default();
        half_resolution(&image, &mut half, (0, 0, 100, 60));
        let params = DetectParams::default();
        let mut compared = 0;
        for (grid, s) in [(&image, 1), (&half, 2)] {
            // Each grid's pixels darker than their row's lit skin, in connected parts.
            let (w, h) = (grid.width as usize, grid.height as usize);
            let dark: Vec<(usize, usize, u8)> = (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .filter_map(|(x, y)| {
                    let skin = 90.0 + 100.0 * (s * x) as f64 / 200.0;
                    let v = f64::from(grid.data[y * w + x]);
                    (skin - v >= 8.0).then(|| (x, y, (skin - v).min(255.0) as u8))
                })
                .collect();
            for_each_part(&dark, |part| {
                let weighted = measure_image_blob(&image, part, &params, s, Centre::Weighted);
                let shaped = measure_image_blob(&image, part, &params, s, Centre::IfItDecides);
                match (&weighted, &shaped) {
                    (Ok(a), Ok(b)) => {
                        assert_eq!(
                            (
                                a.area_px,
                                a.roundness,
                                a.diameter_px,
                                a.contrast_dn,
                                a.axis_rad
                            ),
                            (
                                b.area_px,
                                b.roundness,
                                b.diameter_px,
                                b.contrast_dn,
                                b.axis_rad
                            )
                        );
                        // The centre of a blob measured for its shape is its pixels' mean,
                        // near its weighted centroid.
                        assert!((a.centre_px - b.centre_px).norm() < 1.0 * s as f64 + 1.0);
                    }
                    (Err(a), Err(b)) => assert_eq!(a, b),
                    _ => panic!("verdicts differ: {weighted:?} against {shaped:?}"),
                }
                compared += 1;
            });
        }
        assert!(compared >= 12, "{compared} blobs compared");
    }

    /// [`merge_scales`] as first written: every large blob asks every small one.
    fn merge_scales_every_pair(
        mut coarse: Vec<Detection>,
        mut fine: Vec<Detection>,
    ) -> Vec<Detection> {
        coarse.retain(|c| {
            let mut held = fine.iter().filter(|f| inside(c, f));
            match (held.next(), held.next()) {
                (None, _) => true,
                (Some(f), None) => {
                    (c.centre_px - f.centre_px).norm() <= (0.1 * c.diameter_px).max(1.5)
                        && !(c.diameter_px > COARSE_MAX_OVER_WHOLE * f.diameter_px
                            && ellipse_fill(f) >= WHOLE_MIN_FILL)
                }
                (Some(_), Some(_)) => false,
            }
        });
        fine.retain(|f| !coarse.iter().any(|c| inside(c, f)));
        fine.extend(coarse);
        fine
    }

    #[test]
    fn the_two_scales_merge_as_when_every_pair_is_asked() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(17);
        let blob = |rng: &mut rand::rngs::StdRng, spread: f64, size: (f64, f64)| {
            let special = rng.random_range(0..40);
            let x = match special {
                0 => f64::NAN,
                1 => f64::INFINITY,
                _ => rng.random_range(0.0..spread),
            };
            let diameter_px = match special {
                2 => f64::NAN,
                3 => f64::INFINITY,
                _ => rng.random_range(size.0..size.1),
            };
            let roundness = rng.random_range(0.3..1.0);
            Detection {
                centre_px: Point2::new(x, rng.random_range(0.0..spread)),
                area_px: rng.random_range(5..400),
                roundness,
                contrast_dn: 60.0,
                quality: 0.4,
                diameter_px,
                axis_rad: 0.0,
                streak: false,
            }
        };
        let mut compared = 0;
        for round in 0..300 {
            // Dense and sparse scenes: many small blobs around few large ones, and
            // pairs that share a centre (a large dot's ring).
            let spread = [60.0, 200.0, 800.0][round % 3];
            let coarse: Vec<Detection> = (0..rng.random_range(0..30))
                .map(|_| blob(&mut rng, spread, (14.0, 40.0)))
                .collect();
            let mut fine: Vec<Detection> = (0..rng.random_range(0..120))
                .map(|_| blob(&mut rng, spread, (3.0, 16.0)))
                .collect();
            for c in coarse.iter().take(5) {
                let mut ring = blob(&mut rng, spread, (3.0, 40.0));
                ring.centre_px = c.centre_px + nalgebra::Vector2::new(0.5, -0.5);
                fine.push(ring);
            }
            let want = merge_scales_every_pair(coarse.clone(), fine.clone());
            let got = merge_scales(coarse, fine);
            assert_eq!(got.len(), want.len(), "round {round}");
            for (g, w) in got.iter().zip(&want) {
                // Bit for bit, NaN included.
                assert_eq!(
                    g.centre_px.x.to_bits(),
                    w.centre_px.x.to_bits(),
                    "round {round}"
                );
                assert_eq!(
                    g.centre_px.y.to_bits(),
                    w.centre_px.y.to_bits(),
                    "round {round}"
                );
                assert_eq!(
                    g.diameter_px.to_bits(),
                    w.diameter_px.to_bits(),
                    "round {round}"
                );
            }
            compared += got.len();
        }
        assert!(compared > 5000, "{compared} blobs compared");
    }

    #[test]
    fn the_two_scales_give_each_dot_once() {
        let blob = |x: f64, diameter_px: f64, roundness: f64, fill: f64| Detection {
            centre_px: Point2::new(x, 50.0),
            area_px: (fill * std::f64::consts::FRAC_PI_4 * diameter_px * diameter_px * roundness)
                .round() as usize,
            roundness,
            contrast_dn: 60.0,
            quality: 0.4,
            diameter_px,
            axis_rad: 0.0,
            streak: false,
        };
        let one = |coarse: Detection, fine: Detection| {
            let merged = merge_scales(vec![coarse], vec![fine]);
            assert_eq!(merged.len(), 1, "{merged:?}");
            merged[0].diameter_px
        };
        // A large dot is a ring in the small window (filling a third of its ellipse): the
        // large blob.
        assert_eq!(
            one(blob(100.5, 25.0, 0.95, 0.95), blob(100.0, 27.0, 0.9, 0.35)),
            25.0
        );
        // A large dot the small window sees whole too: the large blob.
        assert_eq!(
            one(blob(100.5, 24.0, 0.9, 0.95), blob(100.0, 20.0, 0.9, 0.95)),
            24.0
        );
        // A dot seen 60° from its normal (19 px long, half as wide, filled) in a round
        // patch of hair strokes 37 px across about it: the dot.
        assert_eq!(
            one(blob(100.5, 37.0, 0.63, 0.4), blob(100.0, 19.0, 0.5, 0.95)),
            19.0
        );
        // A small dot merged with a shadow in the large window, off its centre: the dot.
        assert_eq!(
            one(blob(106.0, 30.0, 0.8, 0.9), blob(100.0, 12.0, 0.9, 0.95)),
            12.0
        );
        // A patch around two dots: the dots.
        let merged = merge_scales(
            vec![blob(100.0, 40.0, 0.8, 0.6)],
            vec![blob(92.0, 12.0, 0.9, 0.95), blob(108.0, 12.0, 0.9, 0.95)],
        );
        assert!(merged.iter().all(|d| d.diameter_px == 12.0) && merged.len() == 2);
    }

    #[test]
    fn finds_an_oblique_dot_among_hair_strokes() {
        // A dot seen 60° from its normal (18 × 9 px) crossed by two hairs 40 px long, 1 px
        // wide, in an X about it: one blob 29 px across, 0.7 round (rounder than the dot),
        // filling 0.48 of its ellipse. Its core is the dot.
        let dot = (100.3, 60.6, 9.0, 4.5, 0.1);
        let hairs = [
            (100.3 + 2.0, 60.6 - 1.0, 20.0, 0.5, 1.1),
            (100.3 - 3.0, 60.6 + 1.5, 20.0, 0.5, -1.2),
        ];
        let found = detect_markers(
            &image_with_ellipses(&[dot, hairs[0], hairs[1]]),
            &DetectParams::default(),
        );
        let near: Vec<_> = found
            .iter()
            .filter(|d| (d.centre_px - Point2::new(dot.0, dot.1)).norm() < 12.0)
            .collect();
        assert_eq!(near.len(), 1, "{found:?}");
        let err = (near[0].centre_px - Point2::new(dot.0, dot.1)).norm();
        assert!(err < 0.3, "centre off by {err:.2} px: {:?}", near[0]);
        assert!(near[0].diameter_px < 21.0, "{:?}", near[0]);
    }

    #[test]
    fn finds_an_oblique_dot_under_hair() {
        // A dot seen about 64° from its normal (18 × 8 px) with a hair (1.3 px wide) from
        // its middle along its length, 24 px past its end, slightly off its axis, as dark
        // as the ink: the opening keeps a stub of the hair on the dot's core (roundness
        // 0.44; with a floor of 0.5 the dot and the hair were found as one blob 42 px long,
        // its centre 4.7 px off).
        let dot = (60.3, 60.6, 9.0, 4.0, 0.05);
        let hair = (60.3 + 18.0, 60.6 + 1.2, 18.0, 0.65, 0.02);
        let found = detect_markers(&image_with_ellipses(&[dot, hair]), &DetectParams::default());
        let near: Vec<_> = found
            .iter()
            .filter(|d| (d.centre_px - Point2::new(dot.0, dot.1)).norm() < 10.0)
            .collect();
        assert_eq!(near.len(), 1, "{found:?}");
        let err = (near[0].centre_px - Point2::new(dot.0, dot.1)).norm();
        assert!(err < 0.6, "centre off by {err:.2} px: {:?}", near[0]);
        assert!(near[0].diameter_px < 22.0, "{:?}", near[0]);
    }

    fn with_faint_ellipses(
        base: &GrayImage,
        ellipses: &[(f64, f64, f64, f64, f64)],
        darkness: f64,
    ) -> GrayImage {
        let plain = image_with_ellipses(&[]);
        let ink = image_with_ellipses(ellipses);
        let mut out = base.clone();
        for ((o, p), i) in out.data.iter_mut().zip(&plain.data).zip(&ink.data) {
            let drop = darkness * (f64::from(*p) - f64::from(*i));
            *o = (f64::from(*o) - drop).round().clamp(0.0, 255.0) as u8;
        }
        out
    }

    #[test]
    fn finds_a_small_dot_in_hair_strokes_that_a_faint_patch_joins_to_the_skin() {
        // A dot 10 px across (a 1.6 mm dot on a near rig) crossed by two hairs as dark as
        // the ink, 48 px long, in an X, on a faint patch of darker skin 90 px across (a
        // shadow, a blush). At the first threshold the patch holds dot and hair in one
        // component too large for a dot; split off it at a higher threshold, the dot and
        // the hair are one part, an X 35-40 px across that fills a third of its ellipse
        // (M051 of cluttered with 1.6 mm dots, seed 3101: missed in 88 of 120 frames). Its
        // core without the hair is the dot.
        let dot = (100.3, 60.6, 5.0, 5.0, 0.0);
        let hairs = [
            (100.3 + 1.0, 60.6 - 0.5, 24.0, 0.9, 0.6),
            (100.3 - 1.5, 60.6 + 1.0, 24.0, 0.9, -0.9),
        ];
        for patch in [0.3, 0.4] {
            let img = with_faint_ellipses(
                &image_with_ellipses(&[dot, hairs[0], hairs[1]]),
                &[(96.0, 58.0, 45.0, 28.0, 0.3)],
                patch,
            );
            let found = detect_markers(&img, &DetectParams::default());
            let near: Vec<_> = found
                .iter()
                .filter(|d| (d.centre_px - Point2::new(dot.0, dot.1)).norm() < 12.0)
                .collect();
            assert_eq!(near.len(), 1, "patch {patch}: {found:?}");
            let d = near[0];
            assert!((9.5..13.0).contains(&d.diameter_px), "patch {patch}: {d:?}");
            assert!(d.roundness > 0.85, "patch {patch}: {d:?}");
            let err = (d.centre_px - Point2::new(dot.0, dot.1)).norm();
            assert!(err < 0.3, "patch {patch}: centre off by {err:.2} px: {d:?}");
        }
    }

    #[test]
    fn a_disc_covers_its_centre_and_a_ring_or_an_arc_does_not() {
        // The small window sees a large dot as a ring; split at a higher threshold on
        // shaded skin, as arcs of it. Neither is looked at for a dot under hair: an arc's
        // core would stand for the dot (wide-mixed's M104 was missed in 8 more frames when
        // an arc of its ring, 28 px long and 0.42 round, stood for it). A disc is.
        let shape = |r_in: f64, r_out: f64, arc: bool| -> Vec<(usize, usize, u8)> {
            let mut px = Vec::new();
            for y in 0..60usize {
                for x in 0..60usize {
                    let (dx, dy) = (x as f64 - 30.0, y as f64 - 30.0);
                    let r = dx.hypot(dy);
                    if r >= r_in && r <= r_out && (!arc || dy < 0.0) {
                        px.push((x, y, 50));
                    }
                }
            }
            px
        };
        let params = DetectParams::default();
        for scale in [1, 2] {
            let half = (scale == 2).then(|| GrayImage {
                width: 60,
                height: 60,
                data: vec![100; 3600],
            });
            let image = GrayImage {
                width: 120,
                height: 120,
                data: vec![100; 14400],
            };
            let measuring = Measuring::new(&image, &params, half.as_ref(), 0);
            assert_eq!(measuring.scale, scale);
            // The centre as `measure_blob` reports it: grid pixel 30's, in image pixels.
            let centre = 30.0 * scale as f64 + 0.5 * (scale as f64 - 1.0);
            let at = |x: f64, y: f64| Detection {
                centre_px: Point2::new(x, y),
                area_px: 1,
                roundness: 1.0,
                contrast_dn: 50.0,
                quality: 0.5,
                diameter_px: 20.0,
                axis_rad: 0.0,
                streak: false,
            };
            let disc = shape(0.0, 12.0, false);
            let ring = shape(8.0, 12.0, false);
            assert!(covers_its_centre(measuring, &disc, &at(centre, centre)));
            assert!(!covers_its_centre(measuring, &ring, &at(centre, centre)));
            // An arc's centre (its centroid) lies inside its bend, off its pixels.
            let arc = shape(8.0, 12.0, true);
            let n = arc.len() as f64;
            let (sx, sy) = arc.iter().fold((0.0, 0.0), |(a, b), &(x, y, _)| {
                (a + x as f64, b + y as f64)
            });
            let grid = |v: f64| v * scale as f64 + 0.5 * (scale as f64 - 1.0);
            assert!(!covers_its_centre(
                measuring,
                &arc,
                &at(grid(sx / n), grid(sy / n))
            ));
            // Off the grid's top left: no pixel there.
            assert!(!covers_its_centre(measuring, &disc, &at(-5.0, -5.0)));
        }
    }

    #[test]
    fn finds_a_dot_under_hair_as_dark_as_its_ink() {
        // A dot 14 px across with one hair (0.9 px wide, 60 px long) across it 3 px off its
        // centre, and one with two hairs, one ending on the dot: an eyebrow dot. Hair is
        // as dark as the ink, so no contrast threshold splits it off.
        let dots = [(60.3, 60.6), (140.7, 58.2)];
        let hairs = [
            (
                60.3 + 3.0 * 0.6f64.sin(),
                60.6 - 3.0 * 0.6f64.cos(),
                30.0,
                0.45,
                0.6,
            ),
            (140.7, 58.2 + 2.0, 28.0, 0.45, -0.2),
            (140.7 + 12.0, 58.2 - 12.0, 17.0, 0.45, 2.3),
        ];
        let mut shapes: Vec<_> = dots.iter().map(|&(x, y)| (x, y, 7.0, 7.0, 0.0)).collect();
        shapes.extend(hairs);
        let img = image_with_ellipses(&shapes);
        let found = detect_markers(&img, &DetectParams::default());
        for &(x, y) in &dots {
            let near: Vec<_> = found
                .iter()
                .filter(|d| (d.centre_px - Point2::new(x, y)).norm() < 10.0)
                .collect();
            assert_eq!(near.len(), 1, "{found:?}");
            let d = near[0];
            // The dot itself: round, its own size (14 px and the rim), centred.
            assert!(d.roundness > 0.8, "{d:?}");
            assert!((13.0..16.5).contains(&d.diameter_px), "{d:?}");
            let err = (d.centre_px - Point2::new(x, y)).norm();
            assert!(err < 0.5, "centre off by {err:.2} px: {d:?}");
        }
        // A dot seen edge-on keeps its whole length (the opening is not applied to it).
        let thin = (100.4, 60.3, 7.0, 1.6, 0.4);
        let found = detect_markers(&image_with_ellipses(&[thin]), &DetectParams::default());
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(found[0].diameter_px > 13.0, "{:?}", found[0]);
        assert!((found[0].centre_px - Point2::new(thin.0, thin.1)).norm() < 0.1);
    }

    #[test]
    fn finds_a_dot_seen_edge_on_with_a_hair_across_its_end() {
        // Eyebrow dots seen 70° from their normal (20 × 7 px) with a hair as dark as the ink
        // (0.9 px wide) crossing one near its end or ending on it: the blob is longer and
        // no rounder than the dot (cluttered seed 120's M044, its centre pulled 2.4 px
        // off, missed in 41 of 60 frames). The core without the hair fills its ellipse as a
        // dot does; it is the dot, whole, even though it is no rounder than the blob.
        let cases = [
            // (dot centre, dot axis angle, hair centre offset, hair angle)
            ((50.3, 35.6), 0.3, (6.0, -4.0), 1.3),
            ((150.7, 35.2), 1.2, (-3.0, -9.0), 0.2),
            ((50.4, 85.5), -0.4, (9.0, 1.0), 0.9),
            ((150.2, 85.8), 0.0, (-12.0, 0.0), 1.6),
        ];
        for &((x, y), angle, (hx, hy), hair_angle) in &cases {
            let dot = (x, y, 10.0, 3.5, angle);
            let hair = (x + hx, y + hy, 30.0, 0.45, hair_angle);
            let img = image_with_ellipses(&[dot, hair]);
            let found = detect_markers(&img, &DetectParams::default());
            // Within a pixel (the hair's rim beside the dot stays in the core), where the
            // whole blob is pulled 2 px or more.
            let near: Vec<_> = found
                .iter()
                .filter(|d| (d.centre_px - Point2::new(x, y)).norm() < 1.0)
                .collect();
            assert_eq!(near.len(), 1, "dot at ({x}, {y}): {found:?}");
            // Its own length (20 px and the rim), not the hair's.
            assert!((19.0..23.0).contains(&near[0].diameter_px), "{:?}", near[0]);
        }
    }

    #[test]
    fn opening_on_runs_equals_the_opening_on_a_grid() {
        let mut rng: rand::rngs::StdRng = rand::SeedableRng::seed_from_u64(5);
        let mut next = move |below: usize| rand::Rng::random_range(&mut rng, 0..below);
        for _ in 0..200 {
            // Random discs and one-pixel strokes on a 40×40 grid.
            let (w, h) = (40usize, 40usize);
            let mut set = vec![false; w * h];
            for _ in 0..1 + next(3) {
                let (cx, cy, r) = (next(w) as f64, next(h) as f64, next(6) as f64);
                for y in 0..h {
                    for x in 0..w {
                        let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                        set[y * w + x] |= dx * dx + dy * dy <= r * r;
                    }
                }
            }
            for _ in 0..next(4) {
                let (x0, y0, x1, y1) = (next(w), next(h), next(w), next(h));
                for t in 0..=60 {
                    let f = f64::from(t) / 60.0;
                    let x = (x0 as f64 + f * (x1 as f64 - x0 as f64)).round() as usize;
                    let y = (y0 as f64 + f * (y1 as f64 - y0 as f64)).round() as usize;
                    set[y * w + x] = true;
                }
            }
            let pixels: Vec<(usize, usize, u8)> = (0..w * h)
                .filter(|&i| set[i])
                .map(|i| (i % w, i / w, 1))
                .collect();
            let inside = |x: i64, y: i64| {
                x >= 0 && y >= 0 && x < w as i64 && y < h as i64 && set[y as usize * w + x as usize]
            };
            let square = |x: i64, y: i64, f: &dyn Fn(i64, i64) -> bool| {
                (-1..=1).all(|dy| (-1..=1).all(|dx| f(x + dx, y + dy)))
            };
            let eroded = |x: i64, y: i64| square(x, y, &inside);
            let expected: Vec<(usize, usize, u8)> = pixels
                .iter()
                .copied()
                .filter(|&(x, y, _)| {
                    let (x, y) = (x as i64, y as i64);
                    (-1..=1).any(|dy| (-1..=1).any(|dx| eroded(x + dx, y + dy)))
                })
                .collect();
            assert_eq!(opening_3x3(&pixels), expected);
            // Unsorted input gives the same set (in raster order).
            let mut shuffled = pixels.clone();
            shuffled.reverse();
            assert_eq!(opening_3x3(&shuffled), expected);
        }
    }

    #[test]
    fn finds_a_faint_dot_seen_edge_on() {
        // A dot 14 px across seen 79° from its normal (2.7 px wide), whose ink keeps a
        // fifth of its darkness there: a peak contrast of 23-30 levels, what such dots
        // measure on the synth presets (a frontal one: 60-100).
        let b = 7.0 * 79f64.to_radians().cos();
        let dot = (100.4, 60.3, 7.0, b, 0.4);
        let img = with_faint_ellipses(&image_with_ellipses(&[]), &[dot], 0.2);
        let found = detect_markers(&img, &DetectParams::default());
        assert_eq!(found.len(), 1, "{found:?}");
        let d = found[0];
        assert!(d.roundness < 0.3, "{d:?}");
        assert!(
            (22.5..30.0).contains(&d.contrast_dn),
            "contrast {} outside the band this test is about",
            d.contrast_dn
        );
        assert!(
            (d.centre_px - Point2::new(dot.0, dot.1)).norm() < 0.3,
            "{d:?}"
        );
        // Twice the peak contrast floor (the old default) refuses it.
        let strict = DetectParams {
            elongated_min_contrast_factor: 2.0,
            ..Default::default()
        };
        assert!(detect_markers(&img, &strict).is_empty());
    }

    /// A dot 24 px across touching a band of shadow 7 px high that runs across the image
    /// (the mouth line under a lip dot), on even skin.
    fn dot_on_a_band(band_top: f64) -> (GrayImage, Point2<f64>) {
        let (w, h) = (200u32, 120u32);
        let (cx, cy, r) = (100.4, 50.3, 12.0);
        let mut data = vec![0u8; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let band = coverage(x, y, |_, py| py >= band_top && py < band_top + 7.0);
                let dot = coverage(x, y, |px, py| (px - cx).hypot(py - cy) <= r);
                let v = 150.0 - 40.0 * band;
                data[(y * w + x) as usize] = (v + (30.0 - v) * dot).round() as u8;
            }
        }
        let image = GrayImage {
            width: w,
            height: h,
            data,
        };
        (image, Point2::new(cx, cy))
    }

    #[test]
    fn a_dot_on_a_band_the_windows_cut_is_found_as_in_the_whole_image() {
        // The band touches the dot's lower rim. In the whole image the two make one blob
        // too large for a dot, which splits into the dot; a window around the dot cuts the
        // band to a blob that, with the dot, may pass as one (its centre between the two).
        // Windows at least 80 px wide, so that the cut band makes the blob thinner than a
        // large dot (as a lip dot's windows cut the mouth line); in narrower ones the
        // blob is round enough to be weighed against the small scale's ring of the dot,
        // which is reported (its centre right, its diameter 5 px too large).
        let params = DetectParams::default();
        for band_top in [61.5, 62.3, 63.0] {
            let (image, centre) = dot_on_a_band(band_top);
            let mut detector = MarkerDetector::new();
            let nearest = |found: &[Detection]| {
                found
                    .iter()
                    .min_by(|a, b| {
                        (a.centre_px - centre)
                            .norm()
                            .total_cmp(&(b.centre_px - centre).norm())
                    })
                    .cloned()
            };
            let whole = nearest(&detector.detect(&image, &params))
                .expect("the dot is found in the whole image");
            assert!((whole.centre_px - centre).norm() < 0.5, "{whole:?}");
            for half in [40u32, 45, 50] {
                let window = (100 - half, 50 - half, 100 + half, 50 + half);
                let found = detector.detect_in_windows(&image, &params, &[window]);
                let d = nearest(&found).expect("a detection in the window");
                assert!(
                    (d.centre_px - whole.centre_px).norm() < 0.5
                        && (d.diameter_px - whole.diameter_px).abs() < 1.0,
                    "band at {band_top}, window ±{half}: {d:?}, the whole image's {whole:?}"
                );
            }
        }
    }

    #[test]
    fn the_edge_pull_of_a_cut_disc_matches_its_visible_centroid() {
        // Centroid of a disc of radius 10 centred `d` from the edge (x = d is the edge),
        // from a fine grid over the visible part.
        for d in [-5.0, -2.0, 0.0, 3.0, 6.0, 8.0, 9.5] {
            let (mut n, mut sx) = (0.0, 0.0);
            for i in 0..2000 {
                for j in 0..2000 {
                    let (x, y) = (
                        -10.0 + 0.01 * (f64::from(i) + 0.5),
                        -10.0 + 0.01 * (f64::from(j) + 0.5),
                    );
                    if x * x + y * y <= 100.0 && x <= d {
                        n += 1.0;
                        sx += x;
                    }
                }
            }
            let pull = -sx / n;
            let room = d - (sx / n);
            let est = edge_cut_bias_px(room, 10.0);
            assert!(
                (est - pull).abs() < 0.01,
                "d {d}: pull {pull:.4}, estimated {est:.4}"
            );
        }
        assert_eq!(edge_cut_bias_px(10.0, 10.0), 0.0);
        assert_eq!(edge_cut_bias_px(3.0, 0.0), 0.0);
    }

    #[test]
    fn a_dot_cut_by_the_image_edge_is_not_a_dot() {
        // Discs of radius 4 px cut by each of the four edges, half or more outside or (the
        // last) half the radius in: its visible part's centroid is pulled 0.68 px.
        let cut = [
            (100.0, 199.0),
            (319.0, 60.0),
            (0.0, 120.0),
            (200.0, 0.5),
            (40.0, 197.5),
        ];
        // A whole disc 7 px from the bottom edge, and one cut by a pixel, whose centroid
        // is pulled about 0.3 px.
        let kept = [(160.0, 193.0), (250.0, 196.5)];
        let discs: Vec<_> = cut
            .iter()
            .chain(&kept)
            .map(|&(x, y)| (x, y, 4.0, 80.0))
            .collect();
        let img = image_with_discs(&discs);
        let (mut found, rejected) =
            MarkerDetector::default().detect_with_rejects(&img, &DetectParams::default());
        found.sort_by(|a, b| a.centre_px.x.total_cmp(&b.centre_px.x));
        assert_eq!(found.len(), kept.len(), "{found:?}");
        for (d, &(x, y)) in found.iter().zip(&kept) {
            let err = (d.centre_px - Point2::new(x, y)).norm();
            assert!(err < 0.5, "disc at ({x}, {y}) off by {err:.3} px: {d:?}");
        }
        let at_edge = rejected
            .iter()
            .filter(|r| r.reason == RejectReason::AtImageEdge)
            .count();
        assert_eq!(at_edge, cut.len(), "{rejected:?}");
    }

    #[test]
    fn finds_a_dot_seen_edge_on_beside_a_shadow() {
        // A 49×49 patch of a `mono16` synth render: a dot seen 78° from its normal (about
        // 14 px long, 2.8 px wide) on shaded skin, whose left end touches a darker patch
        // of skin. At the candidate threshold the two are one component, too large and not
        // round; raising the threshold splits the dot off as a thin part, which must still
        // be taken for a foreshortened dot. Its true centre: (24.25, 24.23).
        let img = pgm_image(include_bytes!("testdata/edge_on_dot_in_shade.pgm"), 49);
        let truth = Point2::new(24.25, 24.23);
        let found = detect_markers(&img, &DetectParams::default());
        let near: Vec<_> = found
            .iter()
            .filter(|d| (d.centre_px - truth).norm() < 1.0)
            .collect();
        assert_eq!(near.len(), 1, "{found:?}");
        assert!(near[0].roundness < 0.3, "{:?}", near[0]);
    }

    #[test]
    fn centre_of_a_dot_beside_the_silhouette_is_not_pulled_by_the_dark_beyond() {
        // A dot seen ~79° from its normal (semi-axes 7 and 1.4 px) on dim skin, along the
        // face's silhouette: 4.5 px from its axis, on the upper side, the image is black
        // (the background beyond the face). The black lies inside the blob's box.
        let (w, h) = (60u32, 40u32);
        let dot = (30.3, 20.4, 7.0, 1.4, 0.53);
        let (cx, cy) = (dot.0, dot.1);
        let mut data = vec![0u8; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                let ink = coverage(x, y, |px, py| in_ellipse(&dot, px, py));
                let beyond = coverage(x, y, |px, py| ellipse_frame(&dot, px, py).1 < -4.5);
                let skin = 28.0 + 0.3 * f64::from(y);
                let v = skin * (1.0 - beyond) + 1.0 * beyond;
                data[(y * w + x) as usize] = (v - (v - 2.0) * ink).round() as u8;
            }
        }
        let img = GrayImage {
            width: w,
            height: h,
            data,
        };
        let found = detect_markers(&img, &DetectParams::default());
        let truth = Point2::new(cx, cy);
        let near: Vec<_> = found
            .iter()
            .filter(|d| (d.centre_px - truth).norm() < 3.0)
            .collect();
        assert_eq!(near.len(), 1, "{found:?}");
        let err = (near[0].centre_px - truth).norm();
        assert!(err < 0.3, "centre off by {err:.3} px: {:?}", near[0]);
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
    fn the_reciprocal_divides_exactly() {
        // Every quotient's edges (k·a − 1, k·a, k·a + 1) up to 255 levels, for every
        // window area the thresholds use and then some.
        for a in 1..(1 << 15) {
            let inverse = Reciprocal::new(a).unwrap();
            for k in 0..=256u32 {
                for d in [k * a, (k * a).saturating_sub(1), k * a + 1] {
                    assert_eq!(inverse.quotient(d), d / a, "{d} / {a}");
                }
            }
        }
        assert!(Reciprocal::new(0).is_none() && Reciprocal::new(1 << 15).is_none());
    }

    #[test]
    fn runs_are_found_a_word_at_a_time_as_byte_by_byte() {
        use rand::Rng;
        let mut rng = crate::numeric::SplitMix64::new(7);
        for len in [0usize, 1, 7, 8, 9, 23, 64, 101] {
            for density in [0.05, 0.5, 0.95] {
                let line: Vec<u8> = (0..len)
                    .map(|_| u8::from(rng.random::<f64>() < density) * rng.random_range(1..=255))
                    .collect();
                let (mut fast, mut slow) = (Vec::new(), Vec::new());
                let mut x = 0;
                while let Some(start) = next_candidate(&line, x) {
                    x = end_of_run(&line, start);
                    fast.push((start, x));
                }
                let mut x = 0;
                while x < len {
                    if line[x] == 0 {
                        x += 1;
                        continue;
                    }
                    let start = x;
                    while x < len && line[x] != 0 {
                        x += 1;
                    }
                    slow.push((start, x));
                }
                assert_eq!(fast, slow, "{line:?}");
            }
        }
    }

    /// The local contrast of every pixel by direct summation over its clamped window.
    fn naive_mask(
        image: &GrayImage,
        params: &DetectParams,
        roi: (usize, usize, usize, usize),
    ) -> Vec<u8> {
        let (w, h) = (image.width as usize, image.height as usize);
        let r = params.window_radius_px as usize;
        let (x0, y0, x1, y1) = roi;
        let (gx0, gy0) = (x0.saturating_sub(r), y0.saturating_sub(r));
        let (gx1, gy1) = ((x1 + r).min(w), (y1 + r).min(h));
        let mut out = Vec::new();
        for y in y0..y1 {
            for x in x0..x1 {
                let (xa, xb) = (x.saturating_sub(r).max(gx0), (x + r + 1).min(gx1));
                let (ya, yb) = (y.saturating_sub(r).max(gy0), (y + r + 1).min(gy1));
                let mut sum = 0u32;
                for yy in ya..yb {
                    for xx in xa..xb {
                        sum += u32::from(image.data[yy * w + xx]);
                    }
                }
                let area = ((xb - xa) * (yb - ya)) as u32;
                let v = u32::from(image.data[y * w + x]) * area;
                let d = if params.bright {
                    v.checked_sub(sum)
                } else {
                    sum.checked_sub(v)
                };
                out.push(match d {
                    Some(d) if d >= params.min_contrast_dn * area => (d / area).clamp(1, 255) as u8,
                    _ => 0,
                });
            }
        }
        out
    }

    #[test]
    fn fast_threshold_equals_direct_summation() {
        let mut img =
            image_with_dots(&[(20.0, 10.0, 2.5), (190.0, 110.0, 3.0), (100.0, 60.0, 2.0)]);
        // Texture, so that many pixels sit near the threshold.
        let mut state = 12345u32;
        for v in &mut img.data {
            state = state.wrapping_mul(1_103_515_245).wrapping_add(12345);
            *v = v.saturating_add(((state >> 16) % 13) as u8);
        }
        let mut detector = MarkerDetector::new();
        for bright in [false, true] {
            for (roi, r) in [
                ((0, 0, 200, 120), 8),
                ((3, 2, 197, 119), 5),
                ((150, 90, 200, 120), 8),
                ((0, 0, 7, 120), 8),
                ((40, 30, 60, 45), 30),
            ] {
                let params = DetectParams {
                    bright,
                    window_radius_px: r,
                    min_contrast_dn: 4,
                    ..Default::default()
                };
                detector.threshold(&img, &params, r as usize, roi, None);
                let naive = naive_mask(&img, &params, roi);
                assert_eq!(detector.mask, naive, "bright {bright}, roi {roi:?}, r {r}");
                assert!(naive.iter().any(|&m| m != 0));
                let rows_with = naive
                    .chunks(roi.2 - roi.0)
                    .map(|row| row.iter().any(|&m| m != 0))
                    .collect::<Vec<_>>();
                assert_eq!(detector.row_has_candidate, rows_with);
            }
        }
        // In search windows (near ones, whose grown spans share prefix sums, and far
        // ones): the direct contrast inside them, nothing outside.
        let rects = [
            (10, 10, 30, 30),
            (35, 12, 50, 40),
            (52, 20, 60, 26),
            (120, 50, 140, 70),
            (20, 80, 190, 90),
        ];
        let roi = (0, 0, 200, 120);
        let windows = SearchWindows::new(&rects, roi);
        for bright in [false, true] {
            for r in [3, 8, 30] {
                let params = DetectParams {
                    bright,
                    window_radius_px: r,
                    min_contrast_dn: 4,
                    ..Default::default()
                };
                detector.threshold(&img, &params, r as usize, roi, Some(&windows));
                let mut expected = naive_mask(&img, &params, roi);
                for (i, m) in expected.iter_mut().enumerate() {
                    let (x, y) = ((i % 200) as u32, (i / 200) as u32);
                    if !rects
                        .iter()
                        .any(|&(a, b, c, d)| (a..c).contains(&x) && (b..d).contains(&y))
                    {
                        *m = 0;
                    }
                }
                assert!(expected.iter().any(|&m| m != 0));
                assert_eq!(detector.mask, expected, "windows, bright {bright}, r {r}");
            }
        }
        // A reused detector gives what a fresh one gives.
        let params = DetectParams::default();
        let fresh = detect_markers(&img, &params);
        assert_eq!(detector.detect(&img, &params), fresh);
        assert!(!fresh.is_empty());
    }

    #[test]
    fn windows_give_the_same_dots_as_the_whole_image() {
        let dots = [(30.3, 40.7, 2.5), (100.55, 60.2, 3.0), (170.8, 90.45, 2.2)];
        let img = image_with_dots(&dots);
        // Two window scales (the default dot range) and one.
        for params in [
            DetectParams::default(),
            DetectParams {
                max_dot_px: 12.0,
                ..Default::default()
            },
        ] {
            let mut detector = MarkerDetector::new();
            let whole = detector.detect(&img, &params);
            assert_eq!(whole.len(), 3, "{whole:?}");
            let all = [(0, 0, img.width, img.height)];
            assert_eq!(detector.detect_in_windows(&img, &params, &all), whole);
            // A window around each of the first two dots (overlapping ones for the first):
            // those two, measured exactly as in the whole image; the third is not looked at.
            let windows = [(20, 30, 41, 51), (25, 35, 45, 48), (90, 50, 111, 71)];
            let found = detector.detect_in_windows(&img, &params, &windows);
            assert_eq!(found, whole[..2], "{found:?}");
            // No window inside the image: nothing.
            assert!(
                detector
                    .detect_in_windows(&img, &params, &[(5000, 5000, 5010, 5010)])
                    .is_empty()
            );
        }
    }

    #[test]
    fn a_smeared_dot_split_in_pieces_is_also_found_whole() {
        // A smear 28 px long (dots here are at most 12 px), its ink uneven: two darker
        // cores 7 px either side of its centre, so the contrast threshold that splits it
        // keeps the two pieces, each off the ink's centre. The whole smear is reported
        // too, at its centre.
        let params = DetectParams {
            max_dot_px: 12.0,
            ..DetectParams::default()
        }
        .scaled_to_dot_sizes();
        let (cx, cy) = (100.3, 80.6);
        let smear = image_with_patches(&[
            (cx, cy, 14.0, 3.5, 30.0),
            (cx - 7.0, cy, 3.5, 3.0, 40.0),
            (cx + 7.0, cy, 3.5, 3.0, 40.0),
        ]);
        let found = detect_markers(&smear, &params);
        let whole: Vec<&Detection> = found.iter().filter(|d| d.diameter_px > 20.0).collect();
        assert_eq!(whole.len(), 1, "{found:?}");
        let err = (whole[0].centre_px - Point2::new(cx, cy)).norm();
        assert!(err < 0.5, "whole smear {err:.2} px off: {found:?}");
        let pieces = found
            .iter()
            .filter(|d| d.diameter_px <= 20.0 && (d.centre_px.x - cx).abs() > 4.0)
            .count();
        assert_eq!(pieces, 2, "{found:?}");
    }

    #[test]
    fn a_streak_thinner_than_any_dot_is_found_whole_and_told() {
        // A dot seen 77° from its normal and smeared along its length: 27 px long and
        // under 4 px wide (roundness about 0.13, under any whole dot's 0.15), in one piece.
        // It is reported whole, at its centre, as a streak; a dot seen edge-on beside it
        // (roundness about 0.3) is a plain dot.
        let params = DetectParams {
            max_dot_px: 20.0,
            ..DetectParams::default()
        }
        .scaled_to_dot_sizes();
        let streak = (60.3, 60.6, 13.0, 1.3, 0.4);
        let edge_on = (140.2, 60.4, 6.0, 1.6, -0.3);
        let found = detect_markers(&image_with_ellipses(&[streak, edge_on]), &params);
        let near = |x: f64, y: f64| {
            found
                .iter()
                .filter(|d| (d.centre_px - Point2::new(x, y)).norm() < 3.0)
                .collect::<Vec<_>>()
        };
        let s = near(streak.0, streak.1);
        assert_eq!(s.len(), 1, "{found:?}");
        assert!(s[0].streak && s[0].roundness < params.elongated_min_roundness);
        let err = (s[0].centre_px - Point2::new(streak.0, streak.1)).norm();
        assert!(err < 0.3, "streak {err:.2} px off: {found:?}");
        let e = near(edge_on.0, edge_on.1);
        assert_eq!(e.len(), 1, "{found:?}");
        assert!(!e[0].streak, "{:?}", e[0]);
        // A smear keeps part of the ink, and light flicker takes more: a streak 19 levels
        // dark (under the 22.5 a thin dot must reach, over the 15 of any dot) is found.
        let faint = with_faint_ellipses(&image_with_ellipses(&[]), &[streak], 0.15);
        let found = detect_markers(&faint, &params);
        let s: Vec<_> = found
            .iter()
            .filter(|d| (d.centre_px - Point2::new(streak.0, streak.1)).norm() < 0.5)
            .collect();
        assert_eq!(s.len(), 1, "{found:?}");
        assert!(s[0].streak && s[0].contrast_dn < 22.5, "{:?}", s[0]);
    }

    #[test]
    fn only_pieces_alike_in_area_make_a_smear() {
        let part = |area_px: usize| Detection {
            centre_px: Point2::origin(),
            area_px,
            roundness: 0.6,
            contrast_dn: 60.0,
            quality: 0.4,
            diameter_px: 10.0,
            axis_rad: 0.0,
            streak: false,
        };
        assert!(pieces_alike(&[part(70), part(49)]));
        assert!(pieces_alike(&[part(20), part(60), part(5)]));
        // A dot and a freckle a quarter its size, or one piece: no smear.
        assert!(!pieces_alike(&[part(80), part(20)]));
        assert!(!pieces_alike(&[part(80)]));
    }

    /// A 320×200 image of gradient-lit skin darkened by discs `(cx, cy, r, depth)`
    /// (antialiased, 4×4 samples per pixel; overlapping discs add up).
    fn image_with_discs(discs: &[(f64, f64, f64, f64)]) -> GrayImage {
        let ellipses: Vec<_> = discs.iter().map(|&(x, y, r, d)| (x, y, r, r, d)).collect();
        image_with_patches(&ellipses)
    }

    /// [`image_with_discs`] with axis-aligned ellipses `(cx, cy, rx, ry, depth)`.
    fn image_with_patches(discs: &[(f64, f64, f64, f64, f64)]) -> GrayImage {
        let (w, h) = (320usize, 200usize);
        let mut v: Vec<f64> = (0..w * h)
            .map(|i| 120.0 + 80.0 * (i % w) as f64 / w as f64)
            .collect();
        for &(cx, cy, rx, ry, depth) in discs {
            let r = rx.max(ry);
            let (x0, x1) = (
                (cx - r - 1.0).max(0.0) as usize,
                ((cx + r + 2.0) as usize).min(w),
            );
            let (y0, y1) = (
                (cy - r - 1.0).max(0.0) as usize,
                ((cy + r + 2.0) as usize).min(h),
            );
            for y in y0..y1 {
                for x in x0..x1 {
                    let mut inside = 0;
                    for k in 0..16 {
                        let px = x as f64 + (f64::from(k % 4) + 0.5) / 4.0 - 0.5;
                        let py = y as f64 + (f64::from(k / 4) + 0.5) / 4.0 - 0.5;
                        let q = ((px - cx) / rx).powi(2) + ((py - cy) / ry).powi(2);
                        inside += usize::from(q <= 1.0);
                    }
                    v[y * w + x] -= depth * inside as f64 / 16.0;
                }
            }
        }
        GrayImage {
            width: w as u32,
            height: h as u32,
            data: v
                .iter()
                .map(|x| x.clamp(0.0, 255.0).round() as u8)
                .collect(),
        }
    }

    /// [`image_with_discs`] with `n` random discs (radius 0.8-11 px, 25-150 levels of
    /// contrast, overlapping at times): dots, freckles, moles and dots merged with them.
    fn cluttered_image(seed: u64, n: usize) -> GrayImage {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let discs: Vec<(f64, f64, f64, f64)> = (0..n)
            .map(|_| {
                let (cx, cy) = (rng.random_range(0.0..320.0), rng.random_range(0.0..200.0));
                let r = if rng.random_bool(0.3) {
                    rng.random_range(5.0..11.0)
                } else {
                    rng.random_range(0.8..5.0)
                };
                (cx, cy, r, rng.random_range(25.0..150.0))
            })
            .collect();
        image_with_discs(&discs)
    }

    /// The detections of `found` whose centres lie in one of `boxes`.
    fn centred_in(found: &[Detection], boxes: &[Rect]) -> Vec<Detection> {
        found
            .iter()
            .filter(|d| in_any(boxes, d.centre_px))
            .copied()
            .collect()
    }

    #[test]
    fn a_patch_around_dots_is_dropped_near_centres_as_in_the_windows() {
        // A faint patch 26 px across (a large round blob for the large scale) with two
        // ink dots in it 9 px either side of its centre: the large scale's rule drops the
        // patch because it holds two small blobs. A centre box around the patch's centre
        // only, which neither dot's blob reaches: the dots must still be measured for the
        // rule, and the patch must not come back.
        let img = image_with_discs(&[
            (160.3, 100.6, 13.0, 35.0),
            (151.2, 100.4, 3.0, 110.0),
            (169.4, 100.9, 3.0, 110.0),
        ]);
        let params = DetectParams::default();
        assert_eq!(params.window_scales().len(), 2);
        let windows = [(110, 50, 210, 150)];
        let centres = [(159, 99, 162, 102)];
        let mut detector = MarkerDetector::new();
        let all = detector.detect_in_windows(&img, &params, &windows);
        let dots = |found: &[Detection]| {
            found
                .iter()
                .filter(|d| (d.centre_px.y - 100.6).abs() < 2.0)
                .map(|d| d.centre_px.x.round() as i64)
                .collect::<Vec<_>>()
        };
        assert_eq!(dots(&all), [151, 169], "{all:?}");
        let near = detector.detect_in_windows_near(&img, &params, &windows, &centres);
        assert!(near.is_empty(), "{near:?}");
        assert_eq!(near, centred_in(&all, &centres));
    }

    #[test]
    fn detections_near_centres_are_those_of_the_windows() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(17);
        let mut compared = 0;
        for seed in 0..6 {
            let img = cluttered_image(seed, 140);
            // Two window scales (the default dot range) and one.
            for params in [
                DetectParams::default(),
                DetectParams {
                    max_dot_px: 12.0,
                    ..Default::default()
                },
            ] {
                let mut windows = Vec::new();
                let mut centres = Vec::new();
                for _ in 0..25 {
                    let (x, y) = (rng.random_range(0..320u32), rng.random_range(0..200u32));
                    let (g, r) = (rng.random_range(12..40u32), rng.random_range(3..20u32));
                    windows.push((x.saturating_sub(g), y.saturating_sub(g), x + g, y + g));
                    centres.push((x.saturating_sub(r), y.saturating_sub(r), x + r, y + r));
                }
                let mut detector = MarkerDetector::new();
                let all = detector.detect_in_windows(&img, &params, &windows);
                let near = detector.detect_in_windows_near(&img, &params, &windows, &centres);
                let in_centres = centred_in(&all, &centres);
                let key = |d: &Detection| (d.centre_px.x.to_bits(), d.centre_px.y.to_bits());
                let mut expected = in_centres.clone();
                expected.sort_by_key(key);
                let mut got = near.clone();
                got.sort_by_key(key);
                assert_eq!(got, expected, "seed {seed}, {params:?}");
                assert!(near.len() < all.len(), "seed {seed}: nothing was left out");
                compared += near.len();
            }
        }
        assert!(compared > 100, "{compared} detections compared");
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
