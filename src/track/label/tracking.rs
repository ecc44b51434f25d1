//! Tracking from the last frame's state: prediction of the head pose and the markers,
//! per-camera gated assignment, left/right pairing under the epipolar and 3D gates, and the
//! head pose of the frame (module docs of [`super`], "Tracking").

use nalgebra::{Isometry3, Matrix2, Point2, Point3, Vector2, Vector3};

use super::assignment::assign_components;
use super::{BlobShape, Label, Labeler, Lobes, PassResult, Prediction};
use crate::align::horn_alignment;
use crate::camera::Camera;
use crate::stereo::{Bundle, TriangulateParams, triangulate};

/// After this many labels in a row on blobs smaller than a first sighting may be
/// ([`Labeler::smaller_than_a_whole_dot`]) a marker is labeled only on a blob of a whole
/// dot's size: a dot hidden in part by a lip or a hair is small for a few frames (on every
/// synth preset and on seven set-ups nothing was tuned on, three at most, on cluttered
/// skin where hair cuts dots), a freckle where a dot was wiped off stays small.
pub(super) const SMALL_BLOB_FRAMES: usize = 4;

/// How far beyond its gate a first sighting's rival pair is looked for, as a multiple of
/// the gate (in the images and in 3D; see `Labeler::label_pass`). A marker coming back is
/// put by its neighbours, off by several pixels where they are far: on cluttered seed 21 a
/// chin dot 11-15 px from that place had a mole of its size 4-7 px from it.
const BEYOND_GATE: f64 = 2.0;

/// The epipolar gate of a worn dot's pair of blobs, as a multiple of a dot's
/// ([`crate::track::EpipolarGate`]). A smear's ink is uneven and its blob is faint, cut
/// by the threshold where the skin's shading and sheen differ between the two views: its
/// centres in the two images agree less than a crisp dot's (cluttered seed 77's M062,
/// smudged, 45° from its normal: 0.63-0.67 px against a gate of 0.60 in every other
/// frame, its neighbours putting it within 1.1 and 0.7 px). A worn dot is still taken
/// only within the worn tolerance of where its neighbours put it in both cameras, and its
/// point within the 3D gate. Over the 42 replay sessions of every preset (120 frames), 2
/// labeled 0.04-0.50 % more of the detectable marker-frames on the eight cluttered ones
/// (1.5: −0.01 to +0.50 %; 3: at most 0.04 % more than 2) and changed no other preset by
/// more than one marker-frame, with no wrong label and the bundle RMS within 0.001 mm; on
/// a cluttered set-up made afterwards (seed 404) 96.48 → 97.91 %, smudged dots that had
/// been lost for most of the take.
const WORN_EPIPOLAR_FACTOR: f64 = 2.0;

/// What a smear's length adds to the epipolar gate of a worn dot's pair of blobs
/// ([`WORN_EPIPOLAR_FACTOR`]), as a share of its length beyond a whole dot's (the longer
/// of the two cameras'). The threshold takes a long smear's faint ends differently in the
/// two views, so its centres move apart along its length: cluttered seed 92's M100, a dot
/// smeared to 37 and 42 px where the dot is 17-20 px, measured 2.2-2.8 px against a gate
/// of 1.2 in every frame of the take (it stays unlabeled still: in one camera the smear's
/// centre is 8 px from the dot, beyond the worn tolerance). Over the 48 replay sessions
/// kept for comparison, lip-press seed 3's M012 was labeled in 32 more frames (as worn
/// dots are, 1.3 px from the dot on average, 2.6 at most), no other marker changed by
/// more than a frame, and no label was wrong.
pub(super) const WORN_SMEAR_EPIPOLAR_SHARE: f64 = 0.1;

/// A tracked marker's blob beyond the tight gate of its prediction must be at least this
/// share of its last frame's as long (see `Labeler::a_piece_off_its_blob`): a dot that
/// jumps keeps its length (motion blur only adds to it), a piece of a long blob that split
/// does not (on cluttered seed 77 a smudged dot 24-26 px
/// long split into pieces of 10-11 px, one of them 7 px from the smear's centre, 10 px
/// from the dot's).
const WHOLE_BLOB_MIN_LENGTH_RATIO: f64 = 0.7;

/// A tracked marker's blob that became longer than this share of the largest a whole dot
/// there can look, and [`MERGED_GROWTH`] times its last frame's blob, is the dot merged
/// with something beside it (see `Labeler::grew_past_a_dot`).
const MERGED_DOT_RATIO: f64 = 1.25;

/// See [`MERGED_DOT_RATIO`]: a dot coming out from under a lip grows up to twice from a
/// half, but not past a whole dot; a smeared dot is long but stays so.
const MERGED_GROWTH: f64 = 1.5;

/// See `Labeler::grew_past_a_dot` and `Labeler::a_piece_off_its_blob`: a blob that grew
/// or shrank by `g` on one side has its centre `g/2` off where it was.
const MERGED_SHIFT: f64 = 0.25;

/// A marker tracked at a lobe of its blob in a camera whose blob there shows no lobes
/// now, but is at least this share of its last frame's length, is still merged (see
/// `Labeler::still_merged`): its lobes' reading is near its limits, as the lobes' spread
/// and the expected dot's shape change a little from frame to frame; a dot parted from the
/// blob beside it is a dot's length, at most 1/(1 + 2·[`LOBE_MIN_OFFSET_RATIO`]) of the
/// merged blob's.
const STILL_MERGED_LENGTH_RATIO: f64 = 0.9;

/// Longest gap, frames, after which a marker last labeled at a merged blob's lobe is looked
/// for at that lobe again ([`Labeler::back_at_its_lobe`]). Over a longer one the skin
/// moves under its last place: with no limit, lip-press seed 904's M107, back after 15
/// frames of a lip press that moved it 6 px, was taken at the lobe on the mole's side (33
/// more wrong labels).
const BACK_AT_LOBE_MAX_GAP: usize = 3;

/// How far either side of its centre, as a share of the dot's major axis, the lobes of a
/// labeled blob must be for it to be taken for a dot merged with a blob beside it (see
/// `Labeler::far_lobe`): a lone dot 10 % larger than the profile says looks like lobes
/// 0.05 either side, a dot and a mole of its size half a dot apart are 0.25.
const LOBE_MIN_OFFSET_RATIO: f64 = 0.1;

/// How wide, across the line through its lobes, a blob must be for it to be taken for a
/// dot merged with a blob beside it (see `Labeler::lobe_split`), as the ratio of its
/// second moment across that line to a lone dot's there. Two discs of a dot's size
/// merged are 1.0-1.09 of one (by numerical integration, as for [`TWO_DISCS_SPREAD`]);
/// a dot smudged along the skin is narrower (its ink spread over a longer, thinner
/// ellipse), and read as two discs its "lobe" is wherever the neighbours' prediction
/// leans (cluttered seed 92's M101 was moved 5 px off its dot for the last 39 frames).
/// On eight cluttered sessions the labels read as lobes measured 0.44-8.5 when the dot
/// was not smudged (0.8 % of 6,271 below 0.6: lip dots partly hidden) and 0.27-0.78 when
/// it was (90 % of 6,633 below 0.6).
const LOBE_MIN_ACROSS_RATIO: f64 = 0.6;

/// The shortest gap, frames, after which a marker coming back must find a blob of about
/// its dot's last size ([`super::LabelParams::returning_max_size_change`]). Over shorter
/// gaps the dot may still be in what took it away (a hair across it, a blink, a smear
/// being wiped), its size changing frame to frame: on nine cluttered and wiped-moles
/// set-ups, eyebrow dots back after 1-4 frames measured 0.72-1.46 of their last size
/// alike in both cameras. Back after 10 frames or more, the 53 right returns measured
/// within 10 % of it in one camera at least.
const SIZE_MEMORY_MIN_GAP_FRAMES: usize = 10;

/// The fewest labels of markers tracked from the last frame that tell a frame's change of
/// light ([`Labeler::change_of_light`]); with fewer, contrast is not checked.
const LIGHT_MIN_LABELS: usize = 5;

/// A label's blob is remembered as its dot's size ([`Labeler::whole_dot_sizes`]) only
/// when at least this share of its neighbours' dots' in both cameras: as a never-seen
/// marker's blob must be in one ([`super::LabelParams::never_seen_min_relative_size`]'s
/// default; the acquisition's right labels measured 0.81 or more in the larger camera).
const REMEMBERED_MIN_RELATIVE_SIZE: f64 = 0.75;

/// `√a(s)` at `s = 0, 0.05, …, 1`: the second moment `a(s)` that two discs of diameter 1
/// whose centres are `s` apart add along the line through them to one disc's (`1/16`),
/// their overlap counted once (by numerical integration; the `union_of_two_discs` test
/// checks it). Without the overlap it would be `s/2`; with it, more (the lens between
/// the discs is missing from the union's middle).
const TWO_DISCS_SPREAD: [f64; 21] = [
    0.0, 0.0827, 0.1187, 0.1476, 0.1729, 0.1963, 0.2182, 0.2391, 0.2595, 0.2793, 0.2988, 0.3181,
    0.3373, 0.3565, 0.3757, 0.3951, 0.4148, 0.4349, 0.4556, 0.4770, 0.5,
];

/// Half the distance between two discs of diameter 1 whose union has the spread `spread`
/// ([`TWO_DISCS_SPREAD`], inverted by linear interpolation); None beyond two discs that
/// touch.
fn two_discs_half_apart(spread: f64) -> Option<f64> {
    if !(0.0..=0.5).contains(&spread) {
        return None;
    }
    let k = TWO_DISCS_SPREAD
        .partition_point(|&v| v < spread)
        .clamp(1, 20);
    let (a, b) = (TWO_DISCS_SPREAD[k - 1], TWO_DISCS_SPREAD[k]);
    let t = (spread - a) / (b - a);
    Some(0.025 * ((k - 1) as f64 + t))
}

/// How much larger than the dot (its equivalent radius, `√(ab)` of its ellipse's
/// semi-axes) a disc merged with it must read for [`dot_beside_a_larger_disc`]: a disc of
/// about the dot's size is [`two_discs_half_apart`]'s case. (The thresholded blob reads
/// each disc about a pixel smaller than it is: on the 640×480 cluttered set-up a 14 px
/// mole beside a 9 px dot read 1.3 times the dot's radius.)
const LARGER_DISC_MIN_RATIO: f64 = 1.15;

/// How much farther apart than touching (pixels) [`dot_beside_a_larger_disc`] still takes
/// a dot and a disc to be one blob: the threshold leaves out each one's rim, so the
/// moments read both smaller than they are, not their distance.
const LARGER_DISC_TOUCH_SLACK_PX: f64 = 2.0;

/// A blob whose second moments are `major²` along `axis` and `minor²` across it
/// (pixels²) read as a dot of covariance `expected` merged with a larger disc
/// ([`LARGER_DISC_MIN_RATIO`]) whose centre lies along `axis`: the axis and the distance of
/// the dot's centre from the blob's centroid, pixels. None when no such disc explains the
/// moments, or when it would hold the dot or lie apart from it.
///
/// The union is taken as the two shapes side by side, their overlap counted in both: with
/// the dot's area `A_d = 4π√det Σ_d` and the disc's `A_m = πr²` (covariance `r²/4·I`),
/// `A = A_d + A_m`, the moment across the axis is `(A_d Σ_d,vv + A_m r²/4) / A`, which
/// gives `r` (it grows with `r` beyond the dot's size: bisection), and along it
/// `(A_d Σ_d,uu + A_m r²/4) / A + A_d A_m D² / A²`, which gives the centres' distance `D`;
/// the dot's centre lies `A_m D / A` from the centroid, away from the disc. Against the
/// exact union of a 4.3 px dot and a disc 1.3-2.1 times its radius, overlapping it by up to
/// a third of the dot, the dot's offset comes within 0.5 px (test
/// `a_dot_beside_a_larger_disc_is_found_at_its_offset`): the overlap counted twice weighs
/// both centres alike. Which end of the axis the dot is at is for the prediction to tell
/// ([`Labeler::far_lobe`]).
fn dot_beside_a_larger_disc(
    axis: Vector2<f64>,
    major: f64,
    minor: f64,
    expected: &Matrix2<f64>,
) -> Option<(Vector2<f64>, f64)> {
    let across = Vector2::new(-axis.y, axis.x);
    let (m_u, m_v) = (major * major, minor * minor);
    let (d_uu, d_vv) = (
        (axis.transpose() * expected * axis)[0],
        (across.transpose() * expected * across)[0],
    );
    let det = expected.determinant();
    if !(det > 0.0 && m_u.is_finite() && m_v.is_finite()) {
        return None;
    }
    let area_dot = 4.0 * std::f64::consts::PI * det.sqrt();
    let r_dot = 2.0 * det.sqrt().sqrt();
    let across_moment = |r: f64| {
        let area_disc = std::f64::consts::PI * r * r;
        (area_dot * d_vv + area_disc * r * r / 4.0) / (area_dot + area_disc)
    };
    let (mut lo, mut hi) = (LARGER_DISC_MIN_RATIO * r_dot, 8.0 * r_dot);
    if across_moment(lo) > m_v || across_moment(hi) < m_v {
        return None;
    }
    for _ in 0..50 {
        let mid = 0.5 * (lo + hi);
        if across_moment(mid) > m_v {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let r = 0.5 * (lo + hi);
    let area_disc = std::f64::consts::PI * r * r;
    let area = area_dot + area_disc;
    let spread = m_u - (area_dot * d_uu + area_disc * r * r / 4.0) / area;
    let apart = (spread * area * area / (area_dot * area_disc))
        .max(0.0)
        .sqrt();
    // The dot's rim lies outside the disc, and the two touch.
    (apart > r - r_dot && apart <= r + r_dot + LARGER_DISC_TOUCH_SLACK_PX)
        .then_some((axis, area_disc * apart / area))
}

/// On how many consecutive labels a marker's blob must have had about the same lobes
/// before its far lobe is refused (see `Labeler::in_far_lobe`): a dot merged with a mole
/// stays so, a lip dot squeezed or blurred for a frame does not.
const LOBE_MIN_FRAMES: usize = 3;

/// What a pair of detections passed as a marker's label.
#[derive(Debug, Clone, Copy)]
enum Fit {
    /// A dot's shape and size.
    Dot,
    /// A worn dot where the neighbours put the marker ([`Labeler::worn_dot`]).
    Worn,
    /// A dot merged with a blob beside it, at the dot's lobe (pixels, per camera;
    /// [`Labeler::merged_dot`]).
    Merged([Point2<f64>; 2]),
}

impl Fit {
    /// The label of marker `i` on detections `det` so fitted.
    fn label(self, i: usize, det: [usize; 2], bundle: Bundle, confident: bool) -> Label {
        Label {
            marker: i,
            det,
            bundle,
            confident,
            worn: matches!(self, Fit::Worn),
            at: match self {
                Fit::Merged(at) => Some(at),
                _ => None,
            },
        }
    }
}

impl Labeler {
    /// Whether detections `det` (cam0, cam1) at `point` are, in either camera, smaller
    /// than a first sighting may be ([`super::LabelParams::first_sighting_size_ratio`]'s
    /// lower bound, by [`Labeler::dot_sized`]): a partly hidden dot, or not the dot.
    pub(super) fn smaller_than_a_whole_dot(&self, point: &Point3<f64>, det: [usize; 2]) -> bool {
        let lo = self.params.first_sighting_size_ratio.0;
        !self.dot_sized(point, det, [0.0; 2], (lo, f64::INFINITY))
    }

    /// Whether detections `det` (cam0, cam1) are the size of a painted dot at `point` (cam0
    /// frame, mm).
    ///
    /// A disc of diameter `D` seen from any angle has a major axis between `D·σ₂` and
    /// `D·σ₁` pixels, where `σ₁ ≥ σ₂` are the singular values of the projection's Jacobian
    /// at the point (pixels per mm): the disc always holds a diameter perpendicular to the
    /// line of sight (magnified at least `σ₂`), and no displacement is magnified more than
    /// `σ₁`. On the optical axis both are `f/z`; off it, a wide pinhole lens magnifies
    /// radially by up to `1/cos²θ` and a fisheye tangentially by `θ/sin θ`, so the bounds
    /// follow the lens instead of one ratio for the whole image. The measured major axis
    /// ([`crate::track::Detection::diameter_px`]) must lie within the ratios `(lo, hi)`
    /// of that range ([`super::LabelParams::dot_size_ratio`] or, for a first sighting,
    /// [`super::LabelParams::first_sighting_size_ratio`]), widened by 2 px either way (the
    /// antialiased rim and defocus) and, at the top, by `motion_px` (a dot that moved that
    /// far since the last frame is smeared along its motion by up to that much).
    pub(super) fn dot_sized(
        &self,
        point: &Point3<f64>,
        det: [usize; 2],
        motion_px: [f64; 2],
        range: (f64, f64),
    ) -> bool {
        (0..2).all(|c| self.dot_sized_in(c, point, det[c], motion_px[c], range))
    }

    /// [`Labeler::dot_sized`] in camera `c` alone, for its detection `det`.
    fn dot_sized_in(
        &self,
        c: usize,
        point: &Point3<f64>,
        det: usize,
        motion_px: f64,
        (lo, hi): (f64, f64),
    ) -> bool {
        // A detector that does not measure sizes gives NaN: no size check.
        let Some(measured) = self.blobs[c].get(det).map(|b| b.diameter_px) else {
            return true;
        };
        if !measured.is_finite() {
            return true;
        }
        let (cam, p) = self.in_camera(point, c);
        let Some((_, j)) = cam.project_with_jacobian(&p) else {
            return false;
        };
        let (s1, s2) = singular_values(&j);
        let d = self.params.dot_diameter_mm;
        measured >= lo * d * s2 - 2.0 && measured <= hi * d * s1 + 2.0 + motion_px
    }

    /// Each camera's blob diameter ([`crate::track::Detection::diameter_px`]) of detections
    /// `det` over the largest major axis a dot at `point` (cam0 frame) can have through the
    /// lens (its diameter at the largest magnification there, as in [`Labeler::dot_sized`]);
    /// None where a size is unknown or the point does not project.
    pub(super) fn size_over_expected(
        &self,
        point: &Point3<f64>,
        det: [usize; 2],
    ) -> Option<[f64; 2]> {
        let mut out = [0.0; 2];
        for c in 0..2 {
            let measured = self.blobs[c].get(det[c])?.diameter_px;
            let ratio = measured / self.dot_major_axis_px(point, c)?;
            if !(ratio.is_finite() && ratio > 0.0) {
                return None;
            }
            out[c] = ratio;
        }
        Some(out)
    }

    /// Whether detections `det` at `point` are sized like marker `i`'s neighbours' dots, as
    /// a marker never labeled since the acquisition must be
    /// ([`super::LabelParams::never_seen_min_relative_size`],
    /// [`super::LabelParams::never_seen_max_relative_size`]), its neighbours' taken at
    /// their labels in the last frame ([`Labeler::sized_like_a_never_seen_dot`]).
    pub(super) fn sized_like_neighbours(
        &self,
        i: usize,
        point: &Point3<f64>,
        det: [usize; 2],
    ) -> bool {
        let theirs: Vec<[f64; 2]> = self.neighbours[i]
            .iter()
            .map(|&(j, _)| &self.tracks[j])
            .filter(|t| t.frames_since_seen == Some(0))
            .filter_map(|t| t.size_over_expected)
            .collect();
        self.size_over_expected(point, det)
            .is_none_or(|own| self.sized_like_a_never_seen_dot(own, &theirs))
    }

    /// Whether a blob of [`Labeler::size_over_expected`] `own` may be the dot of a marker
    /// never labeled since the acquisition, its neighbours' dots measuring `theirs`: at
    /// least [`super::LabelParams::never_seen_min_relative_size`] of theirs in one camera
    /// at least ([`sized_like`]), and not larger than
    /// [`super::LabelParams::never_seen_max_relative_size`] of theirs in both
    /// ([`larger_than_neighbours`]).
    fn sized_like_a_never_seen_dot(&self, own: [f64; 2], theirs: &[[f64; 2]]) -> bool {
        let p = &self.params;
        sized_like(own, theirs, p.never_seen_min_relative_size, false)
            && !larger_than_neighbours(own, theirs, p.never_seen_max_relative_size)
    }

    /// Drops from an acquisition's `labels` those sized unlike the dots of their
    /// neighbours labeled with them ([`sized_like`]): at the acquisition every marker is
    /// seen for the first time, and a mole where a wiped-off dot should be is as likely
    /// taken there as later. Returns how many were dropped.
    pub(super) fn drop_sized_unlike_neighbours(&self, labels: &mut Vec<Label>) -> usize {
        let sizes = self.label_sizes(labels, |l| !l.worn && l.at.is_none());
        let before = labels.len();
        labels.retain(|l| {
            sizes[l.marker].is_none_or(|own| {
                let theirs = neighbours_sizes(&self.neighbours[l.marker], &sizes);
                self.sized_like_a_never_seen_dot(own, &theirs)
            })
        });
        before - labels.len()
    }

    /// The sizes ([`Labeler::size_over_expected`]) of this frame's `labels` worth
    /// remembering as their dots' (per marker, None for the others): labels on a whole
    /// dot's blob (not a worn dot, not a lobe, not smaller than a first sighting may be)
    /// at least [`REMEMBERED_MIN_RELATIVE_SIZE`] of their neighbours' in both cameras
    /// (with fewer than two neighbours labeled, any). A dot sinking behind the lip is
    /// labeled while its sliver is half a dot or more; remembered at that size, the whole
    /// dot coming back would be refused as a blob too large
    /// ([`Labeler::sized_like_its_dot`]).
    pub(super) fn whole_dot_sizes(
        &self,
        labels: &[Label],
        small: &[bool],
    ) -> Vec<Option<[f64; 2]>> {
        let sizes = self.label_sizes(labels, |l| !l.worn && l.at.is_none() && !small[l.marker]);
        (0..sizes.len())
            .map(|i| {
                sizes[i].filter(|&own| {
                    let theirs = neighbours_sizes(&self.neighbours[i], &sizes);
                    sized_like(own, &theirs, REMEMBERED_MIN_RELATIVE_SIZE, true)
                })
            })
            .collect()
    }

    /// [`Labeler::size_over_expected`] of each of `labels` that `measured` picks, per
    /// marker (None for the others).
    fn label_sizes(
        &self,
        labels: &[Label],
        measured: impl Fn(&Label) -> bool,
    ) -> Vec<Option<[f64; 2]>> {
        let mut sizes = vec![None; self.tracks.len()];
        for l in labels.iter().filter(|l| measured(l)) {
            sizes[l.marker] = self.size_over_expected(&l.bundle.point_in_cam0, l.det);
        }
        sizes
    }

    /// Whether detections `det` at `point` may be marker `i`'s dot coming back after a gap
    /// of [`SIZE_MEMORY_MIN_GAP_FRAMES`] or more: not larger, nor smaller, than its dot
    /// at its last label on a whole dot ([`Labeler::size_over_expected`], which allows for
    /// the lens) by more than [`super::LabelParams::returning_max_size_change`] in both
    /// cameras alike. True for a marker not back from such a gap, or with no such label
    /// since the acquisition.
    pub(super) fn sized_like_its_dot(
        &self,
        i: usize,
        point: &Point3<f64>,
        det: [usize; 2],
    ) -> bool {
        let change = self.params.returning_max_size_change;
        let t = &self.tracks[i];
        if change <= 0.0
            || t.frames_since_seen
                .is_none_or(|n| n < SIZE_MEMORY_MIN_GAP_FRAMES)
        {
            return true;
        }
        let (Some(last), Some(own)) = (t.size_over_expected, self.size_over_expected(point, det))
        else {
            return true;
        };
        let k = 1.0 + change;
        let r = [own[0] / last[0], own[1] / last[1]];
        let larger = r.iter().all(|&r| r > k);
        let smaller = r.iter().all(|&r| r * k < 1.0);
        !(larger || smaller)
    }

    /// Per camera, the median ratio of the contrast of `labels`' blobs to their markers'
    /// at their labels in the last frame ([`Track::contrast_dn`] times the last frame's
    /// light), over the labels on a dot's own blob of markers labeled in the last frame:
    /// the frame's change of light (see [`super::LabelParams::kept_contrast_ratio`]). NaN
    /// with fewer than [`LIGHT_MIN_LABELS`] such labels.
    pub(super) fn change_of_light(&self, labels: &[Label]) -> [f64; 2] {
        [0, 1].map(|c| {
            let mut ratios: Vec<f64> = labels
                .iter()
                .filter(|l| !l.worn && l.at.is_none())
                .filter_map(|l| {
                    let t = &self.tracks[l.marker];
                    let last = t.contrast_dn.filter(|_| t.frames_since_seen == Some(0))?[c];
                    let now = self.blobs[c].get(l.det[c])?.contrast_dn;
                    let r = now / (last * self.light[c]);
                    (r.is_finite() && r > 0.0).then_some(r)
                })
                .collect();
            if ratios.len() < LIGHT_MIN_LABELS {
                return f64::NAN;
            }
            ratios.sort_by(f64::total_cmp);
            let n = ratios.len();
            0.5 * (ratios[(n - 1) / 2] + ratios[n / 2])
        })
    }

    /// Whether detections `det` (cam0, cam1) at `point` keep the ink of marker `i`'s dot,
    /// as [`super::LabelParams::kept_contrast_ratio`] asks of a marker labeled within the
    /// last [`SIZE_MEMORY_MIN_GAP_FRAMES`] frames: not both fainter than that share of
    /// its dot's contrast at its last label, times the change of light since
    /// (`Labeler::light`), in both cameras, and smaller than a first sighting may be
    /// ([`Labeler::smaller_than_a_whole_dot`]). A dot in a shadow that fell on part of
    /// the face is fainter but whole; a dot partly hidden is smaller but dark. True for
    /// other markers, while this frame's change of light is not known (the pose pass, the
    /// acquisition, too few markers tracked), and where contrast is not measured.
    pub(super) fn kept_its_contrast(&self, i: usize, point: &Point3<f64>, det: [usize; 2]) -> bool {
        let share = self.params.kept_contrast_ratio;
        let t = &self.tracks[i];
        let Some(last) = t.contrast_dn else {
            return true;
        };
        if share <= 0.0
            || !self.light_measured
            || t.frames_since_seen
                .is_none_or(|n| n >= SIZE_MEMORY_MIN_GAP_FRAMES)
        {
            return true;
        }
        let fainter = |c: usize| {
            let light = self.light[c];
            self.blobs[c]
                .get(det[c])
                .map(|b| b.contrast_dn)
                .is_some_and(|now| {
                    (now * last[c] * light).is_finite() && now < share * light * last[c]
                })
        };
        !(fainter(0) && fainter(1) && self.smaller_than_a_whole_dot(point, det))
    }

    /// Whether detections `det` (cam0, cam1) are as round as a dot at `point` with the
    /// skin's normal `normal` (both cam0 frame) can look from each camera: at least
    /// [`super::LabelParams::min_roundness_ratio`] of `cos(θ + slack)`, θ the angle between
    /// the line of sight and the normal (a disc seen at θ has minor/major axes `cos θ`; the
    /// detector's blobs are, if anything, rounder, since blur widens thin ones). True
    /// without a normal.
    pub(super) fn round_enough(
        &self,
        point: &Point3<f64>,
        normal: Option<&Vector3<f64>>,
        det: [usize; 2],
    ) -> bool {
        (0..2).all(|c| self.round_enough_in(c, point, normal, det[c]))
    }

    /// [`Labeler::round_enough`] in camera `c` alone, for its detection `det`.
    fn round_enough_in(
        &self,
        c: usize,
        point: &Point3<f64>,
        normal: Option<&Vector3<f64>>,
        det: usize,
    ) -> bool {
        let p = &self.params;
        let Some(normal) = normal else {
            return true;
        };
        if p.min_roundness_ratio <= 0.0 {
            return true;
        }
        let Some(roundness) = self.blobs[c].get(det).map(|b| b.roundness) else {
            return true;
        };
        let (sight, n) = if c == 0 {
            (point.coords, *normal)
        } else {
            (
                (self.rig.cam1_from_cam0 * point).coords,
                self.rig.cam1_from_cam0.rotation * normal,
            )
        };
        let cos = (n.dot(&sight) / (n.norm() * sight.norm())).abs();
        if !(roundness.is_finite() && cos.is_finite()) {
            return true;
        }
        let angle = cos.min(1.0).acos() + p.normal_slack_deg.to_radians();
        roundness >= p.min_roundness_ratio * angle.min(std::f64::consts::FRAC_PI_2).cos()
    }

    /// Whether detections `det` (cam0, cam1) both fill their ellipses as a dot does
    /// ([`super::LabelParams::first_sighting_min_fill`]); true for a blob whose fill was
    /// not measured.
    pub(super) fn filled_like_a_dot(&self, det: [usize; 2]) -> bool {
        (0..2).all(|c| self.filled_like_a_dot_in(c, det[c]))
    }

    /// [`Labeler::filled_like_a_dot`] in camera `c` alone, for its detection `det`.
    fn filled_like_a_dot_in(&self, c: usize, det: usize) -> bool {
        let min = self.params.first_sighting_min_fill;
        self.blobs[c]
            .get(det)
            .is_none_or(|b| !b.fill.is_finite() || b.fill >= min)
    }

    /// How far, pixels, a worn dot's centre may be in camera `c` from where the marker's
    /// neighbours put it at `point` (cam0 frame): 1 px and
    /// [`super::LabelParams::worn_dot_centre_tolerance`] of the dot's largest diameter
    /// there. None when the point does not project.
    pub(super) fn worn_dot_tolerance_px(&self, point: &Point3<f64>, c: usize) -> Option<f64> {
        let tolerance = self.params.worn_dot_centre_tolerance;
        self.largest_dot_px(point, c, 1.0)
            .map(|dot| 1.0 + tolerance * (dot - 2.0))
    }

    /// Whether detections `det` (cam0, cam1) at pixels `x` are a worn dot of the marker
    /// predicted by `pr` ([`super::LabelParams::worn_dots`]): in both cameras, the blob's
    /// minor axis at least [`super::LabelParams::worn_dot_min_width_ratio`] of the dot's
    /// smallest diameter there foreshortened as in [`Labeler::round_enough`], and its
    /// centre within [`Labeler::worn_dot_tolerance_px`] of the neighbours' pixel; its
    /// major axis within [`super::LabelParams::worn_dot_size_ratio`] of a dot's where the
    /// neighbours put the marker (as in [`Labeler::dot_sized`]) in one camera at least,
    /// and in the other, if not, at least as long as a whole dot
    /// ([`super::LabelParams::first_sighting_size_ratio`]'s lower bound): a smear along
    /// one camera's line of sight is seen end-on there, about a dot long.
    pub(super) fn worn_dot(&self, pr: &Prediction, det: [usize; 2], x: [Point2<f64>; 2]) -> bool {
        let p = &self.params;
        let Some((point, pixels)) = pr.vouched.filter(|_| pr.may_be_worn) else {
            return false;
        };
        let in_cam1 = self.rig.cam1_from_cam0 * point;
        let normal = pr.normal.map(|n| [n, self.rig.cam1_from_cam0.rotation * n]);
        let cams = [
            (&self.rig.cam0, point.coords),
            (&self.rig.cam1, in_cam1.coords),
        ];
        let d = p.dot_diameter_mm;
        let (lo, hi) = p.worn_dot_size_ratio;
        let whole = p.first_sighting_size_ratio.0;
        // Per camera: None when the blob is not the worn dot's, else whether it is longer
        // than a dot.
        let views = [0, 1].map(|c| {
            let (Some(blob), Some(at)) = (self.blobs[c].get(det[c]), pixels[c]) else {
                return None;
            };
            if !(blob.diameter_px.is_finite() && blob.roundness.is_finite()) {
                return None;
            }
            let (cam, q) = &cams[c];
            let (_, j) = cam.project_with_jacobian(q)?;
            let (s1, s2) = singular_values(&j);
            let cos = normal.map_or(1.0, |n| {
                let n = n[c];
                let c = (n.dot(q) / (n.norm() * q.norm())).abs().min(1.0);
                let angle = c.acos() + p.normal_slack_deg.to_radians();
                angle.min(std::f64::consts::FRAC_PI_2).cos()
            });
            let major = blob.diameter_px;
            let minor = major * blob.roundness;
            let tolerance = 1.0 + p.worn_dot_centre_tolerance * d * s1;
            (major >= whole * d * s2 - 2.0
                && major <= hi * d * s1 + 2.0 + pr.motion_px[c]
                && minor >= p.worn_dot_min_width_ratio * d * s2 * cos
                && (x[c] - at).norm() <= tolerance)
                .then_some(major >= lo * d * s1 + 2.0)
        });
        views.iter().all(Option::is_some) && views.contains(&Some(true))
    }

    /// The major axis, pixels, of the largest blob a dot at `point` (cam0 frame) may make
    /// in camera `c` at the size ratio `hi` (its largest magnification through the lens,
    /// as in [`Labeler::dot_sized`]); None when the point does not project.
    pub(super) fn largest_dot_px(&self, point: &Point3<f64>, c: usize, hi: f64) -> Option<f64> {
        Some(hi * self.dot_major_axis_px(point, c)? + 2.0)
    }

    /// Camera `c` and `point` (cam0 frame) in its frame.
    fn in_camera(&self, point: &Point3<f64>, c: usize) -> (&Camera, Vector3<f64>) {
        if c == 0 {
            (&self.rig.cam0, point.coords)
        } else {
            (&self.rig.cam1, (self.rig.cam1_from_cam0 * point).coords)
        }
    }

    /// The largest major axis a dot of the profile's diameter at `point` (cam0 frame) can
    /// have in camera `c`, pixels: its diameter at the lens's largest magnification there;
    /// None when the point does not project.
    fn dot_major_axis_px(&self, point: &Point3<f64>, c: usize) -> Option<f64> {
        let (cam, p) = self.in_camera(point, c);
        let (_, j) = cam.project_with_jacobian(&p)?;
        Some(singular_values(&j).0 * self.params.dot_diameter_mm)
    }

    /// Whether marker `i`'s blobs `det` (at `x`, cam0 and cam1) grew past a whole dot on
    /// one side since the last frame, where the marker was labeled, predicted at `pr`: in
    /// either camera, longer than [`MERGED_DOT_RATIO`] of the largest a dot there can look
    /// and than [`MERGED_GROWTH`] times its last blob, plus its image motion (a blur), with
    /// its centre off the prediction or off the last label along its axis by at least
    /// [`MERGED_SHIFT`] of the growth (and 2 px): a blob that touched the mole a frame
    /// early pulls the label and, through the velocity, the prediction after it towards
    /// the mole (lip-press seed 7's M060: a 15 px dot became a 30 px streak 3.6 px off
    /// its prediction, 5.3 px off its last label). Such a blob is the dot merged with
    /// something at its side (a mole, a lash, an eyelid's edge; on wide-mixed seed 1 a
    /// dot 19 px long became a 34 px blob for two frames, its centre 5 px off the dot's):
    /// its centre is not the dot's, and the marker is labeled at the dot's lobe
    /// ([`Labeler::merged_dot`]) or not at all. A blob that grew about its centre (a hair
    /// across it) is still centred on the dot.
    pub(super) fn grew_past_a_dot(
        &self,
        i: usize,
        pr: &Prediction,
        det: [usize; 2],
        x: [Point2<f64>; 2],
    ) -> bool {
        let last = self.last_labels(i);
        self.against_last_blob(i, pr, det, |c, blob, q, was| {
            let (is, motion) = (blob.diameter_px, pr.motion_px[c]);
            let grew = is - was;
            let shift = blob.axis.map_or(0.0, |u| {
                let off = |from: Point2<f64>| (x[c] - from).dot(&u).abs();
                last.map_or(off(q), |last| off(q).max(off(last[c])))
            });
            // The lens's Jacobian last: most blobs did not grow.
            is > MERGED_GROWTH * was + motion
                && shift >= (MERGED_SHIFT * grew).max(2.0)
                && self
                    .largest_dot_px(&pr.point, c, MERGED_DOT_RATIO)
                    .is_some_and(|whole| is > whole + motion)
        })
    }

    /// Marker `i`'s label in the last frame (pixels, cam0 and cam1), if it had one.
    fn last_labels(&self, i: usize) -> Option<[Point2<f64>; 2]> {
        self.seen_before
            .as_ref()
            .and_then(|b| b.markers.get(i).copied().flatten())
    }

    /// The major axes (pixels, cam0 and cam1) of this frame's detections `det`, None where
    /// one is not among them.
    pub(super) fn blob_lengths(&self, det: [usize; 2]) -> Option<[f64; 2]> {
        let length = |c: usize| self.blobs[c].get(det[c]).map(|b| b.diameter_px);
        Some([length(0)?, length(1)?])
    }

    /// The major axes (pixels, cam0 and cam1) of marker `i`'s blobs at its label in the
    /// last frame, if it had one.
    fn last_blob_lengths(&self, i: usize) -> Option<[f64; 2]> {
        self.seen_before
            .as_ref()
            .and_then(|b| b.marker_blobs_px.get(i).copied().flatten())
    }

    /// Whether marker `i`'s blobs `det` (at `x`), where it was labeled in the last frame
    /// and is predicted at `pr`, are in either camera a piece of its last blob off its
    /// place: shorter than [`WHOLE_BLOB_MIN_LENGTH_RATIO`] of the last blob, and beyond
    /// the tight gate of the prediction (inside the marker's gate only as that gate was
    /// widened by its motion or a merged blob's lobes) or off the last label by at least
    /// [`MERGED_SHIFT`] of the length lost (and 2 px): it shrank on one side, as a blob
    /// that grew on one side grew ([`Labeler::grew_past_a_dot`]). A long blob (a smeared
    /// dot) that split leaves pieces up to half its length off the ink's centre; on
    /// cluttered seed 77 one 10 px off a 25 px smear was taken. On lip-press seed 3, M076's
    /// dot and a mole beside it, both seen 81° from cam0, made one 22 px blob there that
    /// the marker was tracked at; when they parted, the mole alone, 4 px from the last
    /// label, was taken for four frames, 8-9 px off the dot.
    pub(super) fn a_piece_off_its_blob(
        &self,
        i: usize,
        pr: &Prediction,
        det: [usize; 2],
        x: [Point2<f64>; 2],
    ) -> bool {
        let last = self.last_labels(i);
        self.against_last_blob(i, pr, det, |c, blob, q, was| {
            let is = blob.diameter_px;
            let shift = last.map_or(0.0, |last| (x[c] - last[c]).norm());
            is < WHOLE_BLOB_MIN_LENGTH_RATIO * was
                && ((x[c] - q).norm() > self.params.gate_px
                    || shift >= (MERGED_SHIFT * (was - is)).max(2.0))
        })
    }

    /// Whether `test(c, blob, q, was)` holds in either camera `c` for marker `i`'s blob
    /// there (of detections `det`), predicted at `q` (`pr`'s pixel), `was` the major axis
    /// of its blob there in the last frame; false when the marker was not labeled then.
    fn against_last_blob(
        &self,
        i: usize,
        pr: &Prediction,
        det: [usize; 2],
        test: impl Fn(usize, &BlobShape, Point2<f64>, f64) -> bool,
    ) -> bool {
        let Some(was) = self.last_blob_lengths(i) else {
            return false;
        };
        (0..2).any(|c| match (self.blobs[c].get(det[c]), pr.pixels[c]) {
            (Some(blob), Some(q)) => test(c, blob, q, was[c]),
            _ => false,
        })
    }

    /// Constant-velocity prediction of the head pose `steps` frames after the last one.
    pub(super) fn predicted_pose(&self, steps: usize) -> Option<Isometry3<f64>> {
        let pose = self.pose?;
        let Some(prev) = self.prev_pose else {
            return Some(pose);
        };
        let delta = pose * prev.inverse();
        let mut p = pose;
        for _ in 0..steps {
            p = delta * p;
        }
        Some(p)
    }

    /// Predictions of all markers under `pose`, with the gates of the final pass plus
    /// `extra_gate_px`; `steps` frames of expression motion are carried.
    pub(super) fn predictions(
        &self,
        pose: &Isometry3<f64>,
        steps: usize,
        extra_gate_px: f64,
    ) -> Vec<Prediction> {
        self.predictions_from(pose, steps, extra_gate_px, Returning::FromNeighbours)
    }

    /// [`Labeler::predictions`], with markers not labeled in the last frame placed as
    /// `returning` says.
    pub(super) fn predictions_from(
        &self,
        pose: &Isometry3<f64>,
        steps: usize,
        extra_gate_px: f64,
        returning: Returning,
    ) -> Vec<Prediction> {
        let p = &self.params;
        let f = self.rig.cam0.fx().min(self.rig.cam1.fx()).max(1e-9);
        self.tracks
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let motion = t.velocity * (p.velocity_damping * steps as f64);
                let neighbours_head =
                    if t.frames_since_seen == Some(0) || returning == Returning::WhereLastSeen {
                        None
                    } else {
                        self.head_from_neighbours(i)
                    };
                let head = neighbours_head.unwrap_or(t.head);
                let point = pose * (head + motion);
                let pixels = self.project_both(&point);
                let depth = point.coords.norm().max(1.0);
                let motion_px = motion.norm() * f / depth;
                let gap_gate = match t.frames_since_seen {
                    Some(0) => p.gate_px,
                    Some(n) => (p.gate_px + p.gate_growth_px_per_frame * n as f64)
                        .min(p.max_gap_gate_px.max(p.gate_px)),
                    None => p.max_gap_gate_px.max(p.gate_px),
                };
                // A dot merged with a blob beside it is labeled at its lobe, the blob's
                // centre that much away.
                let lobe_px = if t.frames_since_seen == Some(0) {
                    t.lobe_px
                } else {
                    0.0
                };
                let gate_px =
                    gap_gate + p.velocity_gate_factor * motion_px + extra_gate_px + lobe_px;
                let gate_mm = p.gate_3d_factor * gate_px * depth / f;
                // Where the marker was (or would have been) in the last frame.
                let before = self.pose.map(|last| self.project_both(&(last * t.head)));
                let motion_px = [0, 1].map(|c| match (before.and_then(|b| b[c]), pixels[c]) {
                    (Some(a), Some(b)) => (b - a).norm(),
                    _ => 0.0,
                });
                let first_sighting = t.frames_since_seen != Some(0);
                // A blob too long for a dot is taken only where the neighbours put it.
                let may_be_worn = p.worn_dots
                    && (first_sighting || t.worn)
                    && !(first_sighting && returning == Returning::WhereLastSeen);
                let vouched = if !may_be_worn {
                    None
                } else if first_sighting {
                    // The prediction is the neighbours' already (no motion carried).
                    neighbours_head.map(|_| (point, pixels))
                } else {
                    self.head_from_neighbours(i).map(|h| {
                        let point = pose * h;
                        (point, self.project_both(&point))
                    })
                };
                let last_seen = matches!(t.frames_since_seen, Some(n) if n > 0)
                    .then(|| self.project_both(&(pose * t.head)));
                Prediction {
                    last_seen,
                    from_neighbours: neighbours_head.is_some(),
                    neighbours_place: None,
                    merged: t.frames_since_seen == Some(0) && t.lobe_px > 0.0,
                    point,
                    pixels,
                    gate_px,
                    gate_mm,
                    motion_px,
                    first_sighting,
                    normal: self
                        .normals
                        .get(i)
                        .filter(|n| n.norm() > 0.0)
                        .map(|n| pose.rotation * n),
                    vouched,
                    may_be_worn,
                }
            })
            .collect()
    }

    /// Head-frame position of a marker not labeled in the last frame: its neutral
    /// position moved like its neighbours that were (inverse-distance weights); None
    /// with fewer than two such neighbours. With three or more, the weighted median of
    /// their displacements, per axis: one neighbour moving unlike the rest (a lip corner
    /// in a smile beside still cheek markers) does not drag the place, where a weighted
    /// mean moved it by a sixth of that motion or more.
    pub(super) fn head_from_neighbours(&self, i: usize) -> Option<Point3<f64>> {
        let moved: Vec<(Vector3<f64>, f64)> = self.neighbours[i]
            .iter()
            .filter(|&&(j, _)| self.tracks[j].frames_since_seen == Some(0))
            .map(|&(j, d)| (self.tracks[j].head - self.neutral[j], 1.0 / (d + 5.0)))
            .collect();
        if moved.len() < 2 {
            return None;
        }
        if moved.len() == 2 {
            let wsum = moved[0].1 + moved[1].1;
            return Some(
                self.neutral[i] + (moved[0].0 * moved[0].1 + moved[1].0 * moved[1].1) / wsum,
            );
        }
        let median = Vector3::from_fn(|a, _| {
            let mut v: Vec<(f64, f64)> = moved.iter().map(|(m, w)| (m[a], *w)).collect();
            v.sort_by(|x, y| x.0.total_cmp(&y.0));
            let half = 0.5 * v.iter().map(|x| x.1).sum::<f64>();
            let mut acc = 0.0;
            v.iter()
                .find(|x| {
                    acc += x.1;
                    acc >= half
                })
                .map_or(0.0, |x| x.0)
        });
        Some(self.neutral[i] + median)
    }

    /// How far the neighbours' displacements disagree with the one they give marker `i`
    /// ([`Labeler::head_from_neighbours`]): the largest distance of a labeled neighbour's
    /// displacement from it, mm. None where they give none.
    pub(super) fn neighbours_disagreement_mm(&self, i: usize) -> Option<f64> {
        let guess = self.head_from_neighbours(i)? - self.neutral[i];
        self.neighbours[i]
            .iter()
            .filter(|&&(j, _)| self.tracks[j].frames_since_seen == Some(0))
            .map(|&(j, _)| (self.tracks[j].head - self.neutral[j] - guess).norm())
            .reduce(f64::max)
    }

    /// Pixels of a cam0 point in both cameras (None behind a camera or outside its image).
    pub(super) fn project_both(&self, point: &Point3<f64>) -> [Option<Point2<f64>>; 2] {
        let p0 = self
            .rig
            .cam0
            .project(&point.coords)
            .filter(|q| self.rig.cam0.contains(q));
        let p1 = self
            .rig
            .cam1
            .project(&(self.rig.cam1_from_cam0 * point).coords)
            .filter(|q| self.rig.cam1.contains(q));
        [p0, p1]
    }

    /// Tracking from the last frame's state: the two passes of the module docs. None when
    /// the frame cannot be labeled from the tracks (re-acquire).
    pub(super) fn track(
        &mut self,
        pixels: &[Vec<Option<Point2<f64>>>; 2],
        steps: usize,
    ) -> Option<(Isometry3<f64>, PassResult)> {
        let predicted = self.predicted_pose(steps)?;
        // Pass 1: wide gates, labels used only to estimate the head pose of this frame
        // and its change of light.
        let wide = self.predictions(&predicted, steps, self.params.pose_pass_extra_gate_px);
        self.light_measured = false;
        let first = self.label_pass(&wide, pixels);
        let change = self.change_of_light(&first.labels);
        self.light_measured = change.iter().all(|c| c.is_finite());
        if self.light_measured {
            for (light, change) in self.light.iter_mut().zip(change) {
                let next = *light * change;
                *light = if next.is_finite() && next > 0.0 {
                    next
                } else {
                    1.0
                };
            }
        }
        let pose = self
            .estimate_pose(&first.labels)
            .map_or(predicted, |(pose, _)| pose);
        // Pass 2: tight gates around predictions under the estimated pose.
        let tight = self.predictions(&pose, steps, 0.0);
        let mut second = self.label_pass(&tight, pixels);
        self.label_sudden_moves(&first, &wide, &tight, pixels, &mut second);
        self.label_where_last_seen(&pose, steps, &tight, pixels, &mut second);
        let final_pose = match self.estimate_pose(&second.labels) {
            Some((pose, rms)) if rms <= self.params.max_pose_rms_mm => pose,
            Some((_, rms)) => {
                tracing::debug!(rms, "head pose does not fit the labels: frame dropped");
                second.rejected += second.labels.len();
                second.labels.clear();
                pose
            }
            None => pose,
        };
        Some((final_pose, second))
    }

    /// Markers that started moving fast: labeled in the last frame, found by the pose
    /// pass (wide gates) but beyond their tight gate (a lip corner still in one frame and
    /// moving 8 px the next; its prediction keeps the last frame's velocity). The pose
    /// pass's label of such a marker is taken when
    /// - it was confident (no rival candidate in either camera at the wide gate), or its
    ///   rivals are told from it by its dot's size ([`Labeler::doubt_told_by_size`]); not
    ///   on a worn dot, and its detections are still free;
    /// - the dot left its place: no blob within the tight gate of the prediction in
    ///   either camera;
    /// - its blob is whole: not a piece of the last frame's blob off its place
    ///   ([`Labeler::a_piece_off_its_blob`]);
    /// - its blob is new where it is: in each camera where it lies beyond the tight
    ///   gate, the last frame had no blob within half a tight gate of the place the blob
    ///   came from if it were skin (moved as the prediction moved since the last frame),
    ///   where the detector looked. A mole or a freckle beside a marker that vanished
    ///   (hidden by the lip, smudged) was there the frame before; a moving dot was not.
    fn label_sudden_moves(
        &self,
        first: &PassResult,
        wide: &[Prediction],
        tight: &[Prediction],
        pixels: &[Vec<Option<Point2<f64>>>; 2],
        labeled: &mut PassResult,
    ) {
        let Some(before) = &self.seen_before else {
            return;
        };
        let mut done = vec![false; tight.len()];
        let mut used: [Vec<bool>; 2] = [vec![false; pixels[0].len()], vec![false; pixels[1].len()]];
        for l in &labeled.labels {
            done[l.marker] = true;
            used[0][l.det[0]] = true;
            used[1][l.det[1]] = true;
        }
        for l in &first.labels {
            let (i, pr) = (l.marker, &tight[l.marker]);
            if l.worn
                || done[i]
                || pr.first_sighting
                || self.tracks[i].frames_since_seen != Some(0)
                || used[0][l.det[0]]
                || used[1][l.det[1]]
            {
                continue;
            }
            let Some(last) = before.markers.get(i).copied().flatten() else {
                continue;
            };
            if !l.confident && !self.doubt_told_by_size(l, wide, pixels, &done) {
                continue;
            }
            if !self.kept_its_contrast(i, &l.bundle.point_in_cam0, l.det) {
                continue;
            }
            if let (Some(x0), Some(x1)) = (pixels[0][l.det[0]], pixels[1][l.det[1]])
                && self.a_piece_off_its_blob(i, pr, l.det, [x0, x1])
            {
                continue;
            }
            let mut moved_away = false;
            let mut ok = true;
            for c in 0..2 {
                let (Some(q), Some(x)) = (pr.pixels[c], pixels[c][l.det[c]]) else {
                    ok = false;
                    break;
                };
                let left = pixels[c]
                    .iter()
                    .flatten()
                    .all(|p| (p - q).norm() > pr.gate_px);
                if !left {
                    ok = false;
                    break;
                }
                if (x - q).norm() > pr.gate_px {
                    moved_away = true;
                    let came_from = x - (q - last[c]);
                    if !before.nothing_near(c, came_from, 0.5 * pr.gate_px) {
                        ok = false;
                        break;
                    }
                }
            }
            if ok && moved_away {
                tracing::debug!(marker = i, "labeled after a sudden move");
                used[0][l.det[0]] = true;
                used[1][l.det[1]] = true;
                done[i] = true;
                labeled.labels.push(*l);
            }
        }
    }

    /// Whether the pose pass's label `l` of a marker, in doubt, is told from its rivals by
    /// the size of the marker's dot: in each camera, its blob is within
    /// [`super::LabelParams::returning_max_size_change`] of the dot's size at its last
    /// label on a whole dot, and every other detection that rivals it (within the wide
    /// gate of its prediction `wide` and nearer to it than the ambiguity limit, as in
    /// [`Labeler::label_pass`]) is further off that size than that; and no marker not
    /// labeled (`done` false) has the blob within its own wide gate. Sizes are taken as
    /// [`Labeler::size_over_expected`] at the label's point, so that the lens's
    /// magnification there cancels. A lip dot and the mole beside it, carried 7 px together
    /// by a lip press, are each other's rivals, the mole 1.3 times the dot's size in both
    /// cameras (lip-press seed 2's M053, lost for that frame, was then taken on the mole
    /// from where it was last seen and followed on it for eight frames). A dot whose size
    /// changed (a hair across it, the lip over it) stays in doubt, as it was.
    fn doubt_told_by_size(
        &self,
        l: &Label,
        wide: &[Prediction],
        pixels: &[Vec<Option<Point2<f64>>>; 2],
        done: &[bool],
    ) -> bool {
        let p = &self.params;
        let i = l.marker;
        let Some(last) = self.tracks[i].size_over_expected else {
            return false;
        };
        let change = p.returning_max_size_change;
        let point = l.bundle.point_in_cam0;
        change > 0.0
            && (0..2).all(|c| {
                let (Some(q), Some(x)) = (wide[i].pixels[c], pixels[c][l.det[c]]) else {
                    return false;
                };
                let Some(largest) = self.dot_major_axis_px(&point, c) else {
                    return false;
                };
                let like_its_dot = |det: usize| {
                    self.blobs[c].get(det).is_some_and(|b| {
                        let r = b.diameter_px / largest / last[c];
                        r.is_finite() && r <= 1.0 + change && r * (1.0 + change) >= 1.0
                    })
                };
                let limit = p.ambiguity_ratio * (x - q).norm() + p.ambiguity_margin_px;
                let rivals_unlike = pixels[c].iter().enumerate().all(|(b, d)| {
                    let Some(d) = d else { return true };
                    let e = (d - q).norm();
                    b == l.det[c]
                        || e > wide[i].gate_px
                        || e >= limit
                        || (self.blobs[c].get(b).is_some() && !like_its_dot(b))
                });
                let claimed = wide.iter().enumerate().any(|(j, w)| {
                    j != i && !done[j] && w.pixels[c].is_some_and(|qj| (x - qj).norm() <= w.gate_px)
                });
                like_its_dot(l.det[c]) && rivals_unlike && !claimed
            })
    }

    /// How far from a marker's dot the blobs beside it are remembered, pixels: as far as
    /// any of its gates reaches (the gap gate at its largest and the pose pass's extra),
    /// and a tight gate more for the prediction's own error.
    pub(super) fn beside_reach_px(&self) -> f64 {
        let p = &self.params;
        p.max_gap_gate_px.max(p.gate_px) + p.pose_pass_extra_gate_px + p.gate_px
    }

    /// Remembers, for each marker labeled in this frame (under `pose`), the other blobs
    /// beside its dot (see [`Labeler::stood_beside`]) and the lobes of a blob that is its
    /// dot and a mole in one ([`Labeler::far_lobe`]); the memory of a marker not labeled is
    /// kept.
    pub(super) fn remember_beside(
        &mut self,
        labels: &[Label],
        pixels: &[Vec<Option<Point2<f64>>>; 2],
        pose: &Isometry3<f64>,
        reacquired: &[bool],
    ) {
        let (near, reach) = (self.params.gate_px, self.beside_reach_px());
        for l in labels {
            // Where the neighbours put the marker, asked only of a blob with lobes.
            let point = &l.bundle.point_in_cam0;
            let normal = self.normals.get(l.marker).map(|n| pose.rotation * n);
            let split =
                [0, 1].map(|c| normal.and_then(|n| self.lobe_split(point, &n, c, l.det[c])));
            let neighbours = split
                .iter()
                .any(Option::is_some)
                .then(|| self.head_from_neighbours(l.marker))
                .flatten()
                .map(|h| self.project_both(&(pose * h)));
            for (c, dets) in pixels.iter().enumerate() {
                let Some(centre) = dets.get(l.det[c]).copied().flatten() else {
                    continue;
                };
                let x = l.at.map_or(centre, |at| at[c]);
                let far = split[c]
                    .zip(neighbours.and_then(|q| q[c]))
                    .and_then(|(split, q)| self.far_side(split, centre, q));
                // The far lobe from the label's pixel (the blob's centre, or the dot's lobe).
                let lobes = far.map(|far| Lobes {
                    from_label: centre + far - x,
                    apart: 2.0 * far,
                    frames: 1,
                });
                // Counted over consecutive labels with about the same lobes.
                let before = self.lobes[l.marker][c].filter(|_| !reacquired[l.marker]);
                self.lobes[l.marker][c] = lobes.map(|mut new| {
                    new.frames = before
                        .filter(|old| (old.apart - new.apart).norm() <= 0.25 * new.apart.norm())
                        .map_or(1, |old| old.frames + 1);
                    new
                });
                let list = &mut self.beside[l.marker][c];
                list.clear();
                list.extend(
                    dets.iter()
                        .enumerate()
                        .filter(|&(a, _)| a != l.det[c])
                        .filter_map(|(_, p)| p.map(|p| p - x))
                        .filter(|o| o.norm() >= near && o.norm() <= reach),
                );
            }
        }
    }

    /// The far lobe of blob `det` in camera `c` at `x`, as an offset from `x`, when the
    /// blob is a dot at `point` with the skin's `normal` (both cam0 frame) merged with
    /// another blob beside it (a mole, a freckle) and the dot is expected at `q`.
    ///
    /// Two blobs of a dot's shape whose centres are `s` apart along `u` make one blob whose
    /// second moments are a dot's plus `a·u·uᵀ` (and a little across it), `√a` a function
    /// of `s` over the dot's diameter along `u` ([`TWO_DISCS_SPREAD`]; `s/2` without the
    /// overlap). So the blob's covariance (from [`crate::track::Detection::diameter_px`],
    /// its roundness and [`crate::track::Detection::axis_rad`], less the antialiased rim)
    /// less that of the dot expected there (the disc through the lens at the skin's
    /// normal, [`Labeler::expected_dot_covariance`]) is about rank one: its largest
    /// eigenvalue `λ₁ = a` with eigenvector `u` puts the lobes `s/2` either side of the
    /// centre along `u`. Taken when `s/2` is at least [`LOBE_MIN_OFFSET_RATIO`] of the
    /// dot's major axis, the two discs overlap, the other eigenvalue is at most half of
    /// `λ₁` (not a dot merely larger than expected), the blob is about as wide across
    /// `u` as the dot ([`LOBE_MIN_ACROSS_RATIO`]: not a smear), and `q` is within a gate
    /// of one lobe and at least halfway to it from the centre: that lobe is the dot, the
    /// other the far one. (Two thin dots side by side at an oblique view merge across
    /// their minor axes into a round blob: the expected shape tells, not a length.)
    pub(super) fn far_lobe(
        &self,
        point: &Point3<f64>,
        normal: &Vector3<f64>,
        c: usize,
        det: usize,
        x: Point2<f64>,
        q: Point2<f64>,
    ) -> Option<Vector2<f64>> {
        self.far_side(self.lobe_split(point, normal, c, det)?, x, q)
    }

    /// The far lobe's offset from `x` of a blob at `x` with lobes `(u, half_apart)`
    /// ([`Labeler::lobe_split`]), the dot expected at `q` (the side rule of
    /// [`Labeler::far_lobe`]).
    fn far_side(
        &self,
        (u, half_apart): (Vector2<f64>, f64),
        x: Point2<f64>,
        q: Point2<f64>,
    ) -> Option<Vector2<f64>> {
        let along = (q - x).dot(&u);
        let off_axis = (q - x - along * u).norm();
        let near_lobe = (along.abs() - half_apart).hypot(off_axis);
        (along.abs() >= 0.5 * half_apart && near_lobe <= self.params.gate_px)
            .then(|| -along.signum() * half_apart * u)
    }

    /// The direction `u` (unit) and half the distance (pixels) of the lobes of blob `det`
    /// in camera `c`, when its second moments are those of a dot at `point` with the
    /// skin's `normal` merged with another ([`Labeler::far_lobe`]); failing that, merged
    /// with a larger disc ([`dot_beside_a_larger_disc`]): then the "lobes" lie the dot's
    /// distance from the centroid either side of it, the dot's where the prediction leans,
    /// the far one a point past the disc's centre (which lies nearer the centroid), standing
    /// in for the disc wherever the far lobe is looked at.
    pub(super) fn lobe_split(
        &self,
        point: &Point3<f64>,
        normal: &Vector3<f64>,
        c: usize,
        det: usize,
    ) -> Option<(Vector2<f64>, f64)> {
        let blob = self.blobs[c].get(det)?;
        let axis = blob.axis?;
        let (expected, dot_major) = self.expected_dot_covariance(point, normal, c)?;
        let (major, minor) = (
            (blob.diameter_px - 1.0).max(0.0) / 4.0,
            (blob.diameter_px * blob.roundness - 1.0).max(0.0) / 4.0,
        );
        if !(major.is_finite() && minor.is_finite()) {
            return None;
        }
        let across = Vector2::new(-axis.y, axis.x);
        let measured = axis * axis.transpose() * (major * major)
            + across * across.transpose() * (minor * minor);
        let eig = (measured - expected).symmetric_eigen();
        let k = usize::from(eig.eigenvalues[1] > eig.eigenvalues[0]);
        let (l1, l2) = (eig.eigenvalues[k], eig.eigenvalues[1 - k]);
        let u = eig.eigenvectors.column(k).into_owned();
        let dot_along = 4.0 * (u.transpose() * expected * u)[0].max(0.0).sqrt();
        // A dot merged with a disc of another size than its own: beside a larger one.
        let larger = || {
            dot_beside_a_larger_disc(axis, major, minor, &expected)
                .filter(|&(_, offset)| offset >= LOBE_MIN_OFFSET_RATIO * dot_major)
        };
        let Some(half_apart) =
            two_discs_half_apart(l1.max(0.0).sqrt() / dot_along).map(|s| s * dot_along)
        else {
            return larger();
        };
        // Across the lobes' line the union of two discs is at least as wide as one disc;
        // a smear is narrower (`LOBE_MIN_ACROSS_RATIO`).
        let v = eig.eigenvectors.column(1 - k).into_owned();
        let across = (v.transpose() * measured * v)[0] / (v.transpose() * expected * v)[0];
        (half_apart >= LOBE_MIN_OFFSET_RATIO * dot_major
            && l2 <= 0.5 * l1
            && across >= LOBE_MIN_ACROSS_RATIO)
            .then_some((u, half_apart))
            .or_else(larger)
    }

    /// Whether detections `det` at `point`, predicted by `pr`, read in both cameras as a
    /// dot merged with a blob beside it ([`Labeler::lobe_split`]), lobes farther apart than
    /// the image motion since the last frame could smear one dot: not one dot, whatever its
    /// size. A first sighting, or a marker tracked at a lobe of such a blob, is not taken
    /// at its centre, between the dot and the blob beside it (lip-press seed 1401's M085,
    /// half hidden by the lip and merged with a mole of its size, was labeled there, 6-8 px
    /// off, in 9 frames), but at a lobe or not at all ([`Labeler::merged_dot`]).
    pub(super) fn two_discs_in_both(
        &self,
        point: &Point3<f64>,
        pr: &Prediction,
        det: [usize; 2],
    ) -> bool {
        let Some(normal) = pr.normal else {
            return false;
        };
        (0..2).all(|c| {
            self.lobe_split(point, &normal, c, det[c])
                .is_some_and(|(_, half_apart)| {
                    half_apart > 0.5 * self.params.gate_px && 2.0 * half_apart > pr.motion_px[c]
                })
        })
    }

    /// Moves the tracks of markers labeled at the centre of a blob that has had about the
    /// same lobes for [`LOBE_MIN_FRAMES`] labels ([`Labeler::far_lobe`]: a dot that a mole
    /// came to touch, a first sighting before the neighbours were tracked) onto the dot's
    /// lobe (under head pose `pose`): from the next frame they are tracked there
    /// ([`Labeler::merged_dot`]), not between the dot and the mole.
    pub(super) fn move_onto_lobes(
        &mut self,
        labels: &[Label],
        pixels: &[Vec<Option<Point2<f64>>>; 2],
        pose: &Isometry3<f64>,
    ) {
        let inverse = pose.inverse();
        for l in labels.iter().filter(|l| l.at.is_none()) {
            let i = l.marker;
            let lobes = self.lobes[i];
            let at = [0, 1].map(|c| {
                let far = lobes[c].filter(|lobe| lobe.frames >= LOBE_MIN_FRAMES)?;
                Some((pixels[c][l.det[c]]? - far.from_label, far.from_label.norm()))
            });
            let [Some((at0, lobe0)), Some((at1, lobe1))] = at else {
                continue;
            };
            let Ok(bundle) = triangulate(&self.rig, &at0, &at1, &self.params.pair.triangulate)
            else {
                continue;
            };
            tracing::debug!(marker = i, "tracked on its dot's lobe from the next frame");
            // The far lobe is now seen from the dot's lobe.
            for lobe in self.lobes[i].iter_mut().flatten() {
                lobe.from_label = lobe.apart;
            }
            let lengths = self.blob_lengths(l.det);
            let track = &mut self.tracks[i];
            track.head = inverse * bundle.point_in_cam0;
            track.lobe_px = lobe0.max(lobe1);
            track.lobe_blob_px = lengths;
        }
    }

    /// The dot's lobe in each camera when detections `det` at `x` are marker `pr`'s dot
    /// merged with a blob beside it ([`Labeler::far_lobe`]): for a first sighting (with
    /// worn dots on, [`super::LabelParams::worn_dots`]: a blob that is not a dot's shape is
    /// taken only there) the lobe within [`Labeler::worn_dot_tolerance_px`] of where the
    /// neighbours put the marker; for a marker tracked on such a blob, within the tight
    /// gate of its prediction; for one back at the lobe it was last labeled at
    /// ([`Labeler::back_at_its_lobe`]), within its gate of its prediction. The label is at
    /// the lobes, not at the blob's centre between the dot and the mole. None without the
    /// skin's normal, for a first sighting of a marker last labeled on a worn dot's smear
    /// ([`Labeler::back_on_its_smear`]), for a first sighting whose
    /// far lobe is, in both cameras, within the reach of a rival beyond the gate (as in
    /// `Labeler::label_pass`) of where the neighbours put the marker, that reach narrowed
    /// to a rival's inside the gate (`ambiguity_ratio · e + ambiguity_margin_px`) with `e`
    /// grown by how far the neighbours' own displacements disagree with that place
    /// ([`Labeler::neighbours_disagreement_mm`]): where they all moved alike (a forehead
    /// dot beside a mole of its size on the 640×480 cluttered set-up, its far lobe 6 px
    /// off, never labeled before) the place is no guess; across a moving lip or jaw it is
    /// (lip-press seed 901's M054 and wiped-moles seed 1301's M102, put 17 and 30 px off,
    /// were taken at a mole's lobe with the narrower reach alone). And none for a marker
    /// tracked at a lobe whose blob shows no lobes in a camera but is still one with the
    /// blob beside the dot there ([`Labeler::still_merged`]).
    ///
    /// The dot and the mole may touch in one camera only (seen from the other, the mole
    /// lies beyond the dot's rim, or the two cameras' foreshortening differ): in the other
    /// camera the blob must be a whole dot by itself ([`Labeler::whole_dot_in`]), within
    /// the same tolerance, and is taken at its centre. The stereo gates then check the
    /// lobe against that dot; the marker, first sighting or tracked, is in doubt when the
    /// far lobe is within a rival's reach and pairs with the dot as well (the two lobes
    /// along the epipolar line, at depths the 3D gate allows). On lip-press seed 1201,
    /// M103's dot, seen 39° from both cameras, touched a mole in cam0 only and was never
    /// labeled in 60 frames.
    pub(super) fn merged_dot(
        &self,
        i: usize,
        pr: &Prediction,
        det: [usize; 2],
        x: [Point2<f64>; 2],
    ) -> Option<[Point2<f64>; 2]> {
        let normal = pr.normal?;
        if pr.first_sighting && self.back_on_its_smear(i) {
            return None;
        }
        let back_at_its_lobe = pr.first_sighting && self.back_at_its_lobe(i);
        let (point, anchor) = match pr.vouched.filter(|_| pr.may_be_worn) {
            Some(vouched) if pr.first_sighting => vouched,
            _ if pr.first_sighting && !back_at_its_lobe => return None,
            _ => (pr.point, pr.pixels),
        };
        let p = &self.params;
        let mut at = [Point2::origin(); 2];
        let mut far_lobes = [None; 2];
        // Per camera, whether the far lobe is within a rival's reach of where the marker
        // is expected (`Labeler::label_pass`), and that reach.
        let mut far_in_reach = [(false, 0.0); 2];
        for c in 0..2 {
            let q = anchor[c]?;
            let far = self.far_lobe(&point, &normal, c, det[c], x[c], q);
            if far.is_none()
                && (self.still_merged(i, pr, c, det[c])
                    || !self.whole_dot_in(c, &point, &normal, det[c], pr))
            {
                return None;
            }
            let near = x[c] - far.unwrap_or_else(Vector2::zeros);
            let e = (near - q).norm();
            let tolerance = if back_at_its_lobe {
                pr.gate_px
            } else if pr.first_sighting {
                self.worn_dot_tolerance_px(&point, c)?
            } else {
                p.gate_px
            };
            if e > tolerance {
                return None;
            }
            let reach = (p.ambiguity_ratio * e + p.ambiguity_margin_px)
                .clamp(pr.gate_px, BEYOND_GATE * pr.gate_px);
            // A first sighting's far lobe is a rival within `ambiguity_ratio · (e + s) +
            // ambiguity_margin_px` (at most `reach`), `s` how far the neighbours'
            // displacements disagree with the place they give the marker
            // ([`Labeler::neighbours_disagreement_mm`], in pixels at its depth): as a rival
            // blob within the gate is, the place being a guess that far.
            let rival_reach = match self.neighbours_disagreement_mm(i) {
                Some(spread) if pr.first_sighting => {
                    let px_per_mm = p.gate_3d_factor * pr.gate_px / pr.gate_mm.max(1e-9);
                    let guess_px = spread * px_per_mm;
                    (p.ambiguity_ratio * (e + guess_px) + p.ambiguity_margin_px).min(reach)
                }
                _ => reach,
            };
            far_in_reach[c] = (
                far.is_some_and(|far| {
                    let d = (x[c] + far - q).norm();
                    if rival_reach < reach {
                        d < rival_reach
                    } else {
                        d <= reach
                    }
                }),
                reach,
            );
            far_lobes[c] = far;
            at[c] = near;
        }
        match far_lobes {
            [None, None] => None,
            // A first sighting whose far lobe could be the dot too, as a rival blob beyond
            // the gate could (`Labeler::label_pass`), is in doubt: where the neighbours put
            // the marker is a guess. (Not a marker back at its lobe: the side it was
            // tracked on tells.)
            [Some(_), Some(_)] => (!(pr.first_sighting
                && !back_at_its_lobe
                && far_in_reach[0].0
                && far_in_reach[1].0))
                .then_some(at),
            // Merged in one camera: in doubt when its far lobe is in reach and pairs with
            // the other camera's dot within the marker's gates widened as for a rival
            // (the two lobes lie along the epipolar line, at depths the gate allows), for
            // a tracked marker too: its prediction follows its lobe, and a lobe put off
            // the dot by a mole of another size than the dot's leads it onto the mole.
            [_, far1] => {
                let c = usize::from(far1.is_some());
                let (in_reach, reach) = far_in_reach[c];
                let far_pair = [0, 1].map(|k| x[k] + far_lobes[k].unwrap_or_else(Vector2::zeros));
                let tri = TriangulateParams {
                    max_reprojection_px: self
                        .gate
                        .gate_px()
                        .max(p.pair.triangulate.max_reprojection_px),
                    ..p.pair.triangulate.clone()
                };
                let reach_3d = reach / pr.gate_px.max(1e-9) * pr.gate_mm;
                let far_pairs = in_reach
                    && triangulate(&self.rig, &far_pair[0], &far_pair[1], &tri)
                        .is_ok_and(|b| (b.point_in_cam0 - point).norm() <= reach_3d);
                (!far_pairs).then_some(at)
            }
        }
    }

    /// Whether marker `i`, tracked at a lobe of its blob in camera `c` in the last frame
    /// (`pr.merged`, and a far lobe remembered there), has in detection `det` a blob at
    /// least [`STILL_MERGED_LENGTH_RATIO`] of that blob's length: the dot and the blob
    /// beside it are still one, even where its lobes are not read this frame: the blob is
    /// not a whole dot there ([`Labeler::merged_dot`]), nor a dot at its centre
    /// (`Labeler::label_pass`). Taken at its centre, such a blob puts the label between the
    /// two (lip-press seed 1401's M085, its blob 26.8 px long in both frames, was labeled
    /// 8 px off in cam0 for two frames when its lobes were not read there), and the
    /// prediction after it onto the mole (lip-press seed 1501's M102, 3.8 px off at the
    /// centre, then followed on the mole 8 px off for 11 frames; seed 1402's M076, at the
    /// silhouette, for 31).
    pub(super) fn still_merged(&self, i: usize, pr: &Prediction, c: usize, det: usize) -> bool {
        pr.merged && self.as_long_as_merged(i, c, det, self.last_blob_lengths(i))
    }

    /// Whether marker `i`, not labeled in the last frame, was last labeled at the dot's lobe
    /// of a merged blob, at most [`BACK_AT_LOBE_MAX_GAP`] frames ago: coming back, it is
    /// looked for at that lobe again, as a tracked marker is ([`Labeler::merged_dot`],
    /// within its gate of its prediction), and not in doubt for a far lobe within its
    /// gate (the side of the dot is the one it was tracked on).
    pub(super) fn back_at_its_lobe(&self, i: usize) -> bool {
        self.frames_gone_from_a_lobe(i)
            .is_some_and(|n| n <= BACK_AT_LOBE_MAX_GAP)
    }

    /// Whether marker `i`, not labeled in the last frame, was last labeled on a worn dot's
    /// smear: coming back, after any gap (a smudge does not heal), it is not taken at a
    /// lobe of a blob read as a dot merged with another ([`Labeler::merged_dot`]), but as
    /// the smear it was, or not at all. One smudged dot in ten is wide enough to read as
    /// two discs side by side (see `LOBE_MIN_ACROSS_RATIO`): cluttered seed 2001's M049, a
    /// smear a hair touches, labeled at its centre as a worn dot, was taken at the lobe
    /// toward its lower end, 5.3-5.8 px off, after gaps of one frame and of four (4 wrong
    /// labels; with the rule limited to gaps of up to three frames, 1).
    pub(super) fn back_on_its_smear(&self, i: usize) -> bool {
        self.tracks
            .get(i)
            .is_some_and(|t| t.worn && t.frames_since_seen.is_some_and(|n| n > 0))
    }

    /// For marker `i`, not labeled in the last frame and last labeled at a dot's lobe, the
    /// frames since that label.
    fn frames_gone_from_a_lobe(&self, i: usize) -> Option<usize> {
        let t = self.tracks.get(i)?;
        t.frames_since_seen.filter(|&n| n > 0 && t.lobe_px > 0.0)
    }

    /// Whether detection `det` in camera `c`, a candidate of marker `i` coming back (`pr`
    /// a first sighting) after its last label was at a dot's lobe, is the blob it was
    /// then, still the dot and the blob beside it in one: it reads as two discs
    /// ([`Labeler::lobe_split`]) and is at least [`STILL_MERGED_LENGTH_RATIO`] of that
    /// label's blob's length ([`Track::lobe_blob_px`](super::Track)). It is not taken at
    /// its centre (`Labeler::label_pass`), as [`Labeler::still_merged`] tells for a marker
    /// tracked at a lobe: the gap did not part the dot and the mole. Nor is it taken as a
    /// worn dot's smear where it is so in both cameras (in one, the lobes may be a hair
    /// across a dot: cluttered seed 903's M100 lost 17 right labels to that). Lip-press seed 1601's
    /// M030, an edge-on dot tracked at its lobe and lost for three frames where the lobes
    /// were not read in cam1, came back at the blob's centre, 5 px from the dot and 2.5 px
    /// from the mole, and was tracked there for 42 frames.
    pub(super) fn back_on_its_merged_blob(
        &self,
        i: usize,
        pr: &Prediction,
        c: usize,
        det: usize,
    ) -> bool {
        let Some(track) = self.tracks.get(i) else {
            return false;
        };
        pr.first_sighting
            && self.frames_gone_from_a_lobe(i).is_some()
            && pr
                .normal
                .and_then(|n| self.lobe_split(&pr.point, &n, c, det))
                .is_some()
            && self.as_long_as_merged(i, c, det, track.lobe_blob_px)
    }

    /// Whether marker `i` has a far lobe remembered in camera `c` and detection `det` there
    /// is at least [`STILL_MERGED_LENGTH_RATIO`] of `last[c]`, the length of a merged blob
    /// it was labeled at.
    fn as_long_as_merged(&self, i: usize, c: usize, det: usize, last: Option<[f64; 2]>) -> bool {
        self.lobes.get(i).is_some_and(|l| l[c].is_some())
            && match (last, self.blobs[c].get(det)) {
                (Some(last), Some(blob)) => blob.diameter_px >= STILL_MERGED_LENGTH_RATIO * last[c],
                _ => false,
            }
    }

    /// Whether detection `det` in camera `c` is, by itself, a whole dot of the marker
    /// predicted by `pr` at `point` with the skin's `normal` (cam0 frame), by a first
    /// sighting's standard whether or not the marker is tracked (nothing else says it is
    /// not merged with something too, and a tracked dot's range, up to 1.8 dots, holds a
    /// dot and a mole): sized as a dot there within
    /// [`super::LabelParams::first_sighting_size_ratio`] ([`Labeler::dot_sized`]), as round
    /// ([`Labeler::round_enough`]), and filling its ellipse
    /// ([`Labeler::filled_like_a_dot`]).
    fn whole_dot_in(
        &self,
        c: usize,
        point: &Point3<f64>,
        normal: &Vector3<f64>,
        det: usize,
        pr: &Prediction,
    ) -> bool {
        let range = self.params.first_sighting_size_ratio;
        self.dot_sized_in(c, point, det, pr.motion_px[c], range)
            && self.round_enough_in(c, point, Some(normal), det)
            && self.filled_like_a_dot_in(c, det)
    }

    /// Whether the blob at `x` in camera `c`, a candidate of marker `i`, lies where the far
    /// lobe of the marker's last label was ([`Labeler::far_lobe`]), seen from `q`: where its
    /// neighbours put the dot (`from_neighbours`), or where the marker was last labeled or
    /// is tracked to. Within half the lobe's offset: nearer to the far lobe than to the
    /// blob's centre or the dot's own place.
    ///
    /// Such a label sits between the dot and the mole. When the dot is smudged off the
    /// mole is left, its centre that far from where the marker was labeled: it is not
    /// taken for the marker, like a blob that stood beside its dot ([`Labeler::stood_beside`]).
    pub(super) fn in_far_lobe(
        &self,
        i: usize,
        c: usize,
        x: Point2<f64>,
        q: Point2<f64>,
        from_neighbours: bool,
    ) -> bool {
        self.lobes.get(i).and_then(|l| l[c]).is_some_and(|l| {
            l.frames >= LOBE_MIN_FRAMES && {
                let offset = if from_neighbours {
                    l.apart
                } else {
                    l.from_label
                };
                ((x - q) - offset).norm() <= 0.25 * l.apart.norm()
            }
        })
    }

    /// The covariance (second moments, pixels²) of the blob a dot at `point` with the
    /// skin's `normal` (both cam0 frame) makes in camera `c`, and its major axis (pixels):
    /// the disc's image through the lens's Jacobian (without the antialiased rim that
    /// [`crate::track::Detection::diameter_px`] adds). None when the point does not
    /// project.
    pub(super) fn expected_dot_covariance(
        &self,
        point: &Point3<f64>,
        normal: &Vector3<f64>,
        c: usize,
    ) -> Option<(Matrix2<f64>, f64)> {
        let (cam, p, n) = if c == 0 {
            (&self.rig.cam0, point.coords, *normal)
        } else {
            (
                &self.rig.cam1,
                (self.rig.cam1_from_cam0 * point).coords,
                self.rig.cam1_from_cam0.rotation * normal,
            )
        };
        let n = n.try_normalize(1e-12)?;
        let (_, j) = cam.project_with_jacobian(&p)?;
        let e1 = n
            .cross(&Vector3::x())
            .try_normalize(1e-6)
            .unwrap_or_else(|| n.cross(&Vector3::y()).normalize());
        let e2 = n.cross(&e1);
        let m = j * nalgebra::Matrix3x2::from_columns(&[e1, e2]);
        let svd = m.svd(true, false);
        let u = svd.u?;
        let d = self.params.dot_diameter_mm;
        let axes = svd.singular_values.map(|s| d * s / 4.0);
        let cov = u * Matrix2::from_diagonal(&axes.component_mul(&axes)) * u.transpose();
        Some((cov, 4.0 * axes.max()))
    }

    /// Whether the blob at `x` in camera `c`, a candidate of marker `i` predicted at `q`,
    /// is one that stood beside the marker's dot the last time the marker was labeled: its
    /// offset from the prediction (`Labeler::label_pass` also asks with `q` where a marker
    /// coming back was last labeled, under this frame's pose: its neighbours' place may be
    /// off by more than the tolerance) is within `min(g/2 + |b|/10, |b|/2)` of a remembered
    /// offset `b` (`g` the tight gate; the tenth for the skin's stretch and the head's turn
    /// since, the half so that the blob is nearer to where the mole was than to the dot's
    /// own place). A mole, a freckle or a neighbour's dot that the marker's dot had beside
    /// it is not the marker when the dot vanishes (hidden by the lip, smudged off), however
    /// dot-like it is and however far the gate of a marker coming back has grown. Only a
    /// label is refused: the blob still counts as a rival, and a pair with it as one of a
    /// marker in doubt, so the rule never makes a label more certain (a wrong label cannot
    /// keep its marker's real dot away as a blob that stood beside it).
    pub(super) fn stood_beside(&self, i: usize, c: usize, x: Point2<f64>, q: Point2<f64>) -> bool {
        let o = x - q;
        self.beside.get(i).is_some_and(|b| {
            b[c].iter()
                .any(|b| (o - b).norm() <= self.beside_tolerance_px(b))
        })
    }

    /// Whether detections at `x` (cam0, cam1), candidates of marker `i` predicted at `pr`
    /// and coming back after a gap shorter than [`SIZE_MEMORY_MIN_GAP_FRAMES`] with the
    /// label `label` (at a merged blob's lobe, or its centre), are a blob that lay beside
    /// the place where its dot went missing rather than the dot: the label beyond the
    /// marker's gate of where it was last labeled (`pr.last_seen`) in a camera, and the
    /// blob in both there in the last frame already (a blob within half a tight gate of
    /// where it came from, moved back with the head's motion since, or a place the detector
    /// did not look at). A dot back after a short gap is where it was: of the 5,265 right
    /// returns after gaps of 1-9 frames on 104 set-ups of every preset, all but three were
    /// within 6 px of their last label (the farthest, 58 px, a lip dot out from behind the
    /// lip: a new blob), and the rule refuses none of the three. Where its neighbours put
    /// it may be far off by then (a chin dot under a jaw opening while the neighbours hold
    /// still), and the gate of a marker coming back grows frame by frame onto a mole that
    /// was beside the dot all along (wiped-moles seed 1301's M102, whose paint was wiped
    /// off, taken from four frames later on a mole 22 px from its dot for the rest of the
    /// take). Such a blob is still a rival, as a blob that stood beside the dot
    /// ([`Labeler::stood_beside`]) is.
    pub(super) fn stayed_while_gone(
        &self,
        i: usize,
        pr: &Prediction,
        label: &Bundle,
        x: [Option<Point2<f64>>; 2],
    ) -> bool {
        let t = &self.tracks[i];
        if !t
            .frames_since_seen
            .is_some_and(|n| n > 0 && n < SIZE_MEMORY_MIN_GAP_FRAMES)
        {
            return false;
        }
        let (Some(before), Some(last_pose), Some(last_seen)) =
            (self.seen_before.as_ref(), self.pose, pr.last_seen)
        else {
            return false;
        };
        let then = self.project_both(&(last_pose * t.head));
        let at = self.project_both(&label.point_in_cam0);
        let mut beyond = false;
        for c in 0..2 {
            let (Some(x), Some(at), Some(now), Some(then)) = (x[c], at[c], last_seen[c], then[c])
            else {
                return false;
            };
            if before.nothing_near(c, x - (now - then), 0.5 * self.params.gate_px) {
                return false;
            }
            beyond |= (at - now).norm() > pr.gate_px;
        }
        beyond
    }

    /// Pass 3: markers coming back after a gap, not labeled where their neighbours put them
    /// (`tight`), looked for where they were last seen, when that is more than half a gate
    /// away. Neighbours that were lost with the marker (a row of chin dots leaving the
    /// image together) leave the interpolation to farther ones, whose motion may differ by
    /// a lip's; a marker that left one camera's image and stayed whole in the other is
    /// often still where it was. The pass labels among the detections left free, with the
    /// other markers not labeled as rivals, and takes its labels of those markers only; a
    /// blob that stood beside the marker's dot is refused from either place.
    fn label_where_last_seen(
        &self,
        pose: &Isometry3<f64>,
        steps: usize,
        tight: &[Prediction],
        pixels: &[Vec<Option<Point2<f64>>>; 2],
        labeled: &mut PassResult,
    ) {
        if !self.any_returning() {
            return;
        }
        let mut done = vec![false; tight.len()];
        for l in &labeled.labels {
            done[l.marker] = true;
        }
        let mut alt = self.predictions_from(pose, steps, 0.0, Returning::WhereLastSeen);
        let retry: Vec<bool> = (0..tight.len())
            .map(|i| !done[i] && self.worth_looking_where_last_seen(i, &alt[i], &tight[i]))
            .collect();
        if !retry.iter().any(|&r| r) {
            return;
        }
        for (i, pr) in alt.iter_mut().enumerate() {
            if done[i] {
                pr.pixels = [None, None];
            } else if !retry[i] {
                *pr = tight[i];
            } else if tight[i].from_neighbours {
                pr.neighbours_place = Some(tight[i].pixels);
            }
        }
        let mut free = pixels.clone();
        for l in &labeled.labels {
            free[0][l.det[0]] = None;
            free[1][l.det[1]] = None;
        }
        let third = self.label_pass(&alt, &free);
        for l in third.labels {
            if retry[l.marker] {
                tracing::debug!(marker = l.marker, "labeled where last seen");
                labeled.labels.push(l);
            }
        }
    }

    /// Whether any marker labeled before was not labeled in the last frame (one that may
    /// come back where it was last seen).
    pub(super) fn any_returning(&self) -> bool {
        self.tracks
            .iter()
            .any(|t| t.frames_since_seen.is_some_and(|n| n > 0))
    }

    /// Whether marker `i`, predicted at `from_neighbours` and (last seen) at
    /// `where_last_seen`, is worth a look at the latter: it comes back after a gap, was
    /// labeled before, and the two places are more than half a gate apart in a camera.
    pub(super) fn worth_looking_where_last_seen(
        &self,
        i: usize,
        where_last_seen: &Prediction,
        from_neighbours: &Prediction,
    ) -> bool {
        let apart = (0..2).any(
            |c| match (where_last_seen.pixels[c], from_neighbours.pixels[c]) {
                (Some(x), Some(y)) => (x - y).norm() > 0.5 * from_neighbours.gate_px,
                _ => false,
            },
        );
        from_neighbours.first_sighting && self.tracks[i].frames_since_seen.is_some() && apart
    }

    /// Weighted robust Horn fit of the head pose to labels: sources are the neutral
    /// positions weighted by the layout's stabilizing weights (drift-free); with too
    /// little stabilizing weight labeled, the tracks' head positions with unit weights.
    /// Returns the pose and the weighted RMS residual of the inliers, mm.
    pub(super) fn estimate_pose(&self, labels: &[Label]) -> Option<(Isometry3<f64>, f64)> {
        if labels.len() < 3 {
            return None;
        }
        let stab: f64 = labels.iter().map(|l| self.stabilize[l.marker]).sum();
        let use_neutral = stab >= 3.0;
        let src: Vec<Point3<f64>> = labels
            .iter()
            .map(|l| {
                if use_neutral {
                    self.neutral[l.marker]
                } else {
                    self.tracks[l.marker].head
                }
            })
            .collect();
        let dst: Vec<Point3<f64>> = labels.iter().map(|l| l.bundle.point_in_cam0).collect();
        let base: Vec<f64> = labels
            .iter()
            .map(|l| {
                if use_neutral {
                    self.stabilize[l.marker]
                } else {
                    1.0
                }
            })
            .collect();
        trimmed_horn(&src, &dst, &base)
    }

    /// One labeling pass: per-camera gated optimal assignment, then left/right pairing
    /// under the epipolar constraint and the 3D gate (steps 2-3 of the module docs).
    pub(super) fn label_pass(
        &self,
        preds: &[Prediction],
        pixels: &[Vec<Option<Point2<f64>>>; 2],
    ) -> PassResult {
        let p = &self.params;
        let m = preds.len();
        // Per camera: candidates (within the gate) of every marker, and the assignment.
        let mut candidates: [Vec<Vec<(usize, f64)>>; 2] =
            [vec![Vec::new(); m], vec![Vec::new(); m]];
        let mut assigned: [Vec<Option<(usize, bool)>>; 2] = [vec![None; m], vec![None; m]];
        for c in 0..2 {
            let dets = &pixels[c];
            // The detections by column, so that a marker looks only at those in the band
            // of columns its gate spans.
            let mut by_column: Vec<(f64, usize)> = dets
                .iter()
                .enumerate()
                .filter_map(|(a, d)| d.map(|d| (d.x, a)))
                .collect();
            by_column.sort_by(|x, y| x.0.total_cmp(&y.0));
            for (i, pr) in preds.iter().enumerate() {
                let Some(q) = pr.pixels[c] else { continue };
                let first = by_column.partition_point(|&(x, _)| x < q.x - pr.gate_px);
                for &(x, a) in &by_column[first..] {
                    if x > q.x + pr.gate_px {
                        break;
                    }
                    let Some(d) = dets[a] else { continue };
                    let e = (d - q).norm();
                    if e <= pr.gate_px {
                        candidates[c][i].push((a, e));
                    }
                }
                // Nearest first; detections equally near in the order they came.
                candidates[c][i].sort_by(|x, y| x.1.total_cmp(&y.1).then(x.0.cmp(&y.0)));
            }
            // Markers per detection (for column rivals).
            let mut by_det: Vec<Vec<(usize, f64)>> = vec![Vec::new(); dets.len()];
            for (i, cands) in candidates[c].iter().enumerate() {
                for &(a, e) in cands {
                    by_det[a].push((i, e));
                }
            }
            for (i, a) in assign_components(&candidates[c], dets.len()) {
                let e = candidates[c][i]
                    .iter()
                    .find(|x| x.0 == a)
                    .map_or(f64::INFINITY, |x| x.1);
                let limit = p.ambiguity_ratio * e + p.ambiguity_margin_px;
                let row_rival = candidates[c][i].iter().any(|&(b, eb)| b != a && eb < limit);
                let col_rival = by_det[a].iter().any(|&(j, ej)| j != i && ej < limit);
                assigned[c][i] = Some((a, row_rival || col_rival));
            }
        }
        let tri = TriangulateParams {
            max_reprojection_px: self.gate.gate_px(),
            ..p.pair.triangulate.clone()
        };
        let tri_worn = TriangulateParams {
            max_reprojection_px: WORN_EPIPOLAR_FACTOR * self.gate.gate_px(),
            ..p.pair.triangulate.clone()
        };
        // The checks of a pair (a, b) for marker i with its 3D gate times `reach`.
        let check_within = |i: usize, a: usize, b: usize, reach: f64| -> Option<(Bundle, Fit)> {
            let (Some(x0), Some(x1)) = (pixels[0][a], pixels[1][b]) else {
                return None;
            };
            let pr = &preds[i];
            let gated_with = |at: [Point2<f64>; 2], tri: &TriangulateParams| {
                triangulate(&self.rig, &at[0], &at[1], tri)
                    .ok()
                    .filter(|b| (b.point_in_cam0 - pr.point).norm() <= reach * pr.gate_mm)
            };
            let gated = |at: [Point2<f64>; 2]| gated_with(at, &tri);
            // A streak thinner than any dot is a worn dot's blob or nothing.
            if [(0, a), (1, b)]
                .iter()
                .any(|&(c, d)| self.blobs[c].get(d).is_some_and(|s| s.streak))
            {
                return gated_with([x0, x1], &tri_worn)
                    .filter(|_| self.worn_dot(pr, [a, b], [x0, x1]))
                    .map(|bundle| (bundle, Fit::Worn));
            }
            // A dot merged with a blob beside it is labeled at its lobe: at a first sighting
            // where the neighbours put it, and then as it is tracked there; a tracked dot
            // whose blob grew on one side, as soon as it did, or not at all.
            let grew = !pr.first_sighting && self.grew_past_a_dot(i, pr, [a, b], [x0, x1]);
            if (pr.merged || pr.first_sighting || grew)
                && let Some(at) = self.merged_dot(i, pr, [a, b], [x0, x1])
                && let Some(bundle) = gated(at)
            {
                return Some((bundle, Fit::Merged(at)));
            }
            if grew || (!pr.first_sighting && self.a_piece_off_its_blob(i, pr, [a, b], [x0, x1])) {
                return None;
            }
            // One triangulation for both gates: a dot's, and a worn dot's wider one (wider
            // still for a long smear).
            let smear_excess_px = if pr.may_be_worn {
                [(0, a), (1, b)]
                    .iter()
                    .filter_map(|&(c, d)| {
                        let whole = self.largest_dot_px(&pr.point, c, 1.0)?;
                        let blob = self.blobs[c].get(d)?.diameter_px;
                        blob.is_finite().then_some(blob - whole)
                    })
                    .fold(0.0, f64::max)
            } else {
                0.0
            };
            let tri_smear = TriangulateParams {
                max_reprojection_px: tri_worn.max_reprojection_px
                    + WORN_SMEAR_EPIPOLAR_SHARE * smear_excess_px,
                ..tri_worn.clone()
            };
            let bundle = gated_with([x0, x1], &tri_smear)?;
            // A marker coming back to the merged blob it was tracked at a lobe of is not
            // taken at the blob's centre.
            let back_merged = || (0..2).any(|c| self.back_on_its_merged_blob(i, pr, c, [a, b][c]));
            if bundle.reprojection_px <= tri.max_reprojection_px {
                // A marker tracked on a merged blob's lobe that is not found there now is
                // taken off its last label (beyond the tight gate) only on a blob of a
                // whole dot's size: not at the merged blob's centre, between the dot and
                // the mole (on lip-press seed 902, M044 was labeled 10 px off its dot for
                // three frames). A dot with a hair across, read as lobes, stays where it was.
                let moved_off_a_lobe = pr.merged
                    && self.last_labels(i).is_some_and(|last| {
                        (0..2).any(|c| ([x0, x1][c] - last[c]).norm() > p.gate_px)
                    });
                let dot = self.dot_sized(
                    &bundle.point_in_cam0,
                    [a, b],
                    pr.motion_px,
                    if pr.first_sighting || moved_off_a_lobe {
                        p.first_sighting_size_ratio
                    } else {
                        p.dot_size_ratio
                    },
                ) && self.round_enough(&bundle.point_in_cam0, pr.normal.as_ref(), [a, b])
                    && (!pr.first_sighting || self.filled_like_a_dot([a, b]))
                    && !((pr.first_sighting || pr.merged)
                        && self.two_discs_in_both(&bundle.point_in_cam0, pr, [a, b]))
                    && (self.tracks[i].frames_since_seen.is_some()
                        || self.sized_like_neighbours(i, &bundle.point_in_cam0, [a, b]))
                    && self.sized_like_its_dot(i, &bundle.point_in_cam0, [a, b])
                    && self.kept_its_contrast(i, &bundle.point_in_cam0, [a, b])
                    && !(0..2).any(|c| self.still_merged(i, pr, c, [a, b][c]))
                    && !back_merged();
                if dot {
                    return Some((bundle, Fit::Dot));
                }
            }
            // Nor is a blob that is so in both cameras a worn dot's smear.
            let back_merged_in_both =
                || (0..2).all(|c| self.back_on_its_merged_blob(i, pr, c, [a, b][c]));
            (self.worn_dot(pr, [a, b], [x0, x1]) && !back_merged_in_both())
                .then_some((bundle, Fit::Worn))
        };
        let check = |i: usize, a: usize, b: usize| check_within(i, a, b, 1.0);
        // Whether detections (a, b) are never marker i's label, but still a pair that makes
        // its label ambiguous: they stood beside its dot ([`Labeler::stood_beside`]) and
        // their surroundings do not make them the dot
        // ([`Labeler::dot_by_its_surroundings`]), their surroundings put the dot of a
        // marker coming back on another blob ([`Labeler::beside_its_dot_found`]), they
        // stayed while it was gone ([`Labeler::stayed_while_gone`]), lie in a far lobe
        // ([`Labeler::in_far_lobe`]), or the marker's blobs have been small for long and
        // so are these.
        let refused = |i: usize, a: usize, b: usize, bundle: &Bundle| {
            let small_for_long = self.tracks[i].small_blob_frames >= SMALL_BLOB_FRAMES
                && self.smaller_than_a_whole_dot(&bundle.point_in_cam0, [a, b]);
            let last_seen = preds[i].last_seen.unwrap_or_default();
            let neighbours_place = preds[i].neighbours_place.unwrap_or_default();
            let from_neighbours = preds[i].from_neighbours;
            let x = [pixels[0][a], pixels[1][b]];
            let stood_beside = || {
                x.iter()
                    .zip(preds[i].pixels.iter().zip(last_seen))
                    .enumerate()
                    .any(|(c, (x, (q, l)))| {
                        x.is_some_and(|x| {
                            [*q, l, neighbours_place[c]]
                                .iter()
                                .flatten()
                                .any(|&q| self.stood_beside(i, c, x, q))
                        })
                    })
                    && !self.dot_by_its_surroundings(i, x)
            };
            small_for_long
                || self.stayed_while_gone(i, &preds[i], bundle, x)
                || stood_beside()
                || self.beside_its_dot_found(i, x)
                || x.iter()
                    .zip(preds[i].pixels.iter().zip(last_seen))
                    .enumerate()
                    .any(|(c, (x, (q, l)))| {
                        x.is_some_and(|x| {
                            q.is_some_and(|q| self.in_far_lobe(i, c, x, q, from_neighbours))
                                || l.is_some_and(|l| self.in_far_lobe(i, c, x, l, false))
                        })
                    })
        };
        // Whether a first sighting on detections (a, b) has a rival pair beyond the gate:
        // another pair, one of its detections beyond the gate and both within the
        // ambiguity limit of the label's own distance (`ambiguity_ratio · e +
        // ambiguity_margin_px`, at most twice the gate), that passes the marker's checks.
        // A first sighting's gate is a guess (where the neighbours put a marker coming
        // back is off by several pixels where they are far, at the chin under an open
        // jaw): a dot just beyond it and a mole of its size inside are two blobs that each
        // could be the marker.
        let rival_beyond_gate = |i: usize, a: usize, b: usize, taken: &[Vec<bool>; 2]| {
            let own = [a, b];
            let pr = &preds[i];
            if !pr.first_sighting {
                return false;
            }
            let (Some(q0), Some(q1), Some(x0), Some(x1)) =
                (pr.pixels[0], pr.pixels[1], pixels[0][a], pixels[1][b])
            else {
                return false;
            };
            let reach = |q: Point2<f64>, x: Point2<f64>| {
                (p.ambiguity_ratio * (x - q).norm() + p.ambiguity_margin_px)
                    .clamp(pr.gate_px, BEYOND_GATE * pr.gate_px)
            };
            let near = |c: usize, q: Point2<f64>, r: f64| -> Vec<(usize, bool)> {
                pixels[c]
                    .iter()
                    .enumerate()
                    .filter(|&(k, _)| k == own[c] || !taken[c][k])
                    .filter_map(|(k, d)| {
                        let e = (d.as_ref()? - q).norm();
                        (e <= r).then_some((k, e > pr.gate_px))
                    })
                    .collect()
            };
            let (r0, r1) = (reach(q0, x0), reach(q1, x1));
            let (n0, n1) = (near(0, q0, r0), near(1, q1, r1));
            let reach_3d = r0.max(r1) / pr.gate_px.max(1e-9);
            n0.iter().any(|&(a2, out0)| {
                n1.iter().any(|&(b2, out1)| {
                    (out0 || out1)
                        && (a2, b2) != (a, b)
                        && check_within(i, a2, b2, reach_3d)
                            .is_some_and(|(bundle, _)| !refused(i, a2, b2, &bundle))
                })
            })
        };
        let mut labels = Vec::new();
        let mut used: [Vec<bool>; 2] = [vec![false; pixels[0].len()], vec![false; pixels[1].len()]];
        let mut paired = 0;
        let mut rejected = 0;
        let mut in_doubt = Vec::new();
        for i in 0..m {
            if candidates[0][i].is_empty() || candidates[1][i].is_empty() {
                continue;
            }
            paired += 1;
            match (assigned[0][i], assigned[1][i]) {
                (Some((a, false)), Some((b, false))) => match check(i, a, b) {
                    Some((bundle, _)) if refused(i, a, b, &bundle) => {
                        tracing::trace!(
                            marker = i,
                            "a blob that stood beside the dot, or small for long, refused"
                        );
                        rejected += 1;
                    }
                    Some((bundle, fit)) => {
                        used[0][a] = true;
                        used[1][b] = true;
                        labels.push(fit.label(i, [a, b], bundle, true));
                    }
                    None => rejected += 1,
                },
                _ => in_doubt.push(i),
            }
        }
        // A first sighting's one passing pair that leaves, in a camera, a free blob of a
        // dot's size nearer to where the neighbours put the marker: that blob may be the
        // dot, with no partner in the other camera because that camera sees the dot
        // edge-on, and the pair a mole beside it that both cameras see (lip-press seed
        // 901's M018: its dot found 0.6 px from its place in cam0 and not in cam1, seen
        // 81° from it; the mole's pair taken, 7 px off in cam0).
        let nearer_dot_left_out = |i: usize, l: &Label, used: &[Vec<bool>; 2]| {
            preds[i].first_sighting
                && (0..2).any(|c| {
                    let own = l.det[c];
                    let Some(e_own) = candidates[c][i].iter().find(|x| x.0 == own).map(|x| x.1)
                    else {
                        return false;
                    };
                    candidates[c][i].iter().any(|&(a2, e2)| {
                        a2 != own
                            && !used[c][a2]
                            && e2 < e_own
                            && self.dot_sized_in(
                                c,
                                &l.bundle.point_in_cam0,
                                a2,
                                0.0,
                                p.first_sighting_size_ratio,
                            )
                    })
                })
        };
        // Markers in doubt in a camera: exactly one candidate pair among free detections
        // must pass the epipolar and 3D gates.
        let mut tentative: Vec<Label> = Vec::new();
        for &i in &in_doubt {
            let mut found: Option<Label> = None;
            let mut count = 0;
            for &(a, _) in candidates[0][i].iter().take(4) {
                if used[0][a] {
                    continue;
                }
                for &(b, _) in candidates[1][i].iter().take(4) {
                    if used[1][b] {
                        continue;
                    }
                    if let Some((bundle, fit)) = check(i, a, b) {
                        count += 1;
                        if refused(i, a, b, &bundle) {
                            continue;
                        }
                        found = Some(fit.label(i, [a, b], bundle, false));
                    }
                }
            }
            match (count, found) {
                (1, Some(l)) if !nearer_dot_left_out(i, &l, &used) => tentative.push(l),
                _ => rejected += 1,
            }
        }
        // A detection claimed by two markers in doubt labels neither.
        let mut claims: [Vec<u32>; 2] = [vec![0; pixels[0].len()], vec![0; pixels[1].len()]];
        for l in &tentative {
            claims[0][l.det[0]] += 1;
            claims[1][l.det[1]] += 1;
        }
        for l in tentative {
            if claims[0][l.det[0]] == 1 && claims[1][l.det[1]] == 1 {
                labels.push(l);
            } else {
                rejected += 1;
            }
        }
        // First sightings with a rival pair beyond the gate, among their own detections and
        // those no other label took, are dropped (not replaced: the rival, beyond the gate,
        // is no label either).
        let mut taken: [Vec<bool>; 2] =
            [vec![false; pixels[0].len()], vec![false; pixels[1].len()]];
        for l in &labels {
            taken[0][l.det[0]] = true;
            taken[1][l.det[1]] = true;
        }
        let before = labels.len();
        labels.retain(|l| {
            let doubt = rival_beyond_gate(l.marker, l.det[0], l.det[1], &taken);
            if doubt {
                tracing::trace!(
                    marker = l.marker,
                    "a first sighting with a rival beyond the gate"
                );
            }
            !doubt
        });
        rejected += before - labels.len();
        PassResult {
            labels,
            paired,
            rejected,
        }
    }
}

/// The known `sizes` (per marker) of `neighbours` (a marker's, with their distances).
fn neighbours_sizes(neighbours: &[(usize, f64)], sizes: &[Option<[f64; 2]>]) -> Vec<[f64; 2]> {
    neighbours.iter().filter_map(|&(j, _)| sizes[j]).collect()
}

/// Whether a blob of [`Labeler::size_over_expected`] `own` is at least `share` of the
/// median of its neighbours' dots' (`theirs`) in one camera at least (see
/// [`super::LabelParams::never_seen_min_relative_size`]), or with `in_both` in both;
/// true with fewer than two neighbours or a share of 0.
fn sized_like(own: [f64; 2], theirs: &[[f64; 2]], share: f64, in_both: bool) -> bool {
    let Some(median) = median_sizes(theirs).filter(|_| share > 0.0) else {
        return true;
    };
    let like = |c: usize| own[c] >= share * median[c];
    if in_both {
        like(0) && like(1)
    } else {
        like(0) || like(1)
    }
}

/// Whether a blob of [`Labeler::size_over_expected`] `own` is larger than `share` times
/// the median of its neighbours' dots' (`theirs`) in both cameras (see
/// [`super::LabelParams::never_seen_max_relative_size`]); false with fewer than two
/// neighbours or a share of 0.
fn larger_than_neighbours(own: [f64; 2], theirs: &[[f64; 2]], share: f64) -> bool {
    median_sizes(theirs)
        .filter(|_| share > 0.0)
        .is_some_and(|median| (0..2).all(|c| own[c] > share * median[c]))
}

/// Per camera, the median of `sizes`; None for fewer than two.
fn median_sizes(sizes: &[[f64; 2]]) -> Option<[f64; 2]> {
    (sizes.len() >= 2).then(|| {
        [0, 1].map(|c| {
            let mut v: Vec<f64> = sizes.iter().map(|s| s[c]).collect();
            v.sort_by(f64::total_cmp);
            let n = v.len();
            0.5 * (v[(n - 1) / 2] + v[n / 2])
        })
    })
}

/// The singular values `σ₁ ≥ σ₂` of a 2×3 matrix (square roots of the eigenvalues of
/// `J·Jᵀ`).
fn singular_values(j: &nalgebra::Matrix2x3<f64>) -> (f64, f64) {
    let m = j * j.transpose();
    let (a, b, c) = (m[(0, 0)], m[(1, 1)], m[(0, 1)]);
    let mean = 0.5 * (a + b);
    let spread = (0.25 * (a - b).powi(2) + c * c).sqrt();
    (
        (mean + spread).max(0.0).sqrt(),
        (mean - spread).max(0.0).sqrt(),
    )
}

/// Weighted Horn with hard outlier rejection (not `align::robust_horn`'s reweighting):
/// residuals above `max(3·median, 1 mm)` are dropped, twice. Returns the pose and the
/// weighted RMS residual of the kept points.
fn trimmed_horn(
    src: &[Point3<f64>],
    dst: &[Point3<f64>],
    base: &[f64],
) -> Option<(Isometry3<f64>, f64)> {
    let mut w = base.to_vec();
    let mut t = horn_alignment(src, dst, &w).ok()?;
    for _ in 0..2 {
        let res: Vec<f64> = src
            .iter()
            .zip(dst)
            .map(|(s, d)| (t * s - d).norm())
            .collect();
        let mut kept: Vec<f64> = res
            .iter()
            .zip(base)
            .filter(|(_, b)| **b > 0.0)
            .map(|(r, _)| *r)
            .collect();
        if kept.len() < 3 {
            break;
        }
        let mid = kept.len() / 2;
        let median = *kept.select_nth_unstable_by(mid, f64::total_cmp).1;
        let limit = (3.0 * median).max(1.0);
        w = base
            .iter()
            .zip(&res)
            .map(|(b, r)| if *r <= limit { *b } else { 0.0 })
            .collect();
        if w.iter().filter(|x| **x > 0.0).count() < 3 {
            return None;
        }
        t = horn_alignment(src, dst, &w).ok()?;
    }
    let (mut num, mut den) = (0.0, 0.0);
    for ((s, d), wi) in src.iter().zip(dst).zip(&w) {
        num += wi * (t * s - d).norm_squared();
        den += wi;
    }
    (den > 0.0).then(|| (t, (num / den).sqrt()))
}

/// Where a pass predicts a marker not labeled in the last frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Returning {
    /// Moved like its neighbours that were labeled (see [`Labeler::head_from_neighbours`]).
    FromNeighbours,
    /// Where it was last labeled, in the head's frame.
    WhereLastSeen,
}

#[cfg(test)]
mod tests {
    use super::{
        TWO_DISCS_SPREAD, dot_beside_a_larger_disc, singular_values, two_discs_half_apart,
    };
    use nalgebra::{Matrix2, Matrix2x3, Rotation2, Rotation3, Vector2, Vector3};

    /// The union of a disc of radius `r_dot` at the origin and one of radius `r_disc` at
    /// `(apart, 0)`, by counting the points of a grid of step 0.02 px: the centroid's `x`
    /// (the dot's offset from it, negated) and the second moments along and across the
    /// line through the centres.
    fn union_moments(r_dot: f64, r_disc: f64, apart: f64) -> (f64, f64, f64) {
        let h = 0.02;
        let (x0, x1) = (-r_dot - 1.0, apart + r_disc + 1.0);
        let half_height = r_dot.max(r_disc) + 1.0;
        let (mut n, mut sx, mut sxx, mut syy) = (0.0, 0.0, 0.0, 0.0);
        let mut x = x0;
        while x < x1 {
            let mut y = -half_height;
            while y < half_height {
                if x * x + y * y <= r_dot * r_dot || (x - apart).powi(2) + y * y <= r_disc * r_disc
                {
                    n += 1.0;
                    sx += x;
                    sxx += x * x;
                    syy += y * y;
                }
                y += h;
            }
            x += h;
        }
        let cx = sx / n;
        (cx, sxx / n - cx * cx, syy / n)
    }

    #[test]
    fn a_dot_beside_a_larger_disc_is_found_at_its_offset() {
        // A 4.3 px dot (a 2.6 mm dot through the 640x480 rig, seen face-on) merged with a
        // disc 1.3-2.1 times its radius, touching it or overlapping it by up to a third of
        // the dot: the dot's offset from the union's centroid within 0.5 px, along the
        // line through the two; nothing read from a lone dot, two discs of the dot's
        // size, a disc apart from the dot, or a dot inside the disc.
        let r_dot = 4.3;
        let expected = Matrix2::identity() * (r_dot * r_dot / 4.0);
        let axis = Vector2::new(1.0, 0.0);
        for (r_disc, apart) in [(5.5, 7.0), (5.6, 9.9), (7.0, 8.7), (7.0, 11.0), (9.0, 10.0)] {
            let (cx, along, across) = union_moments(r_dot, r_disc, apart);
            let (u, offset) =
                dot_beside_a_larger_disc(axis, along.sqrt(), across.sqrt(), &expected)
                    .unwrap_or_else(|| panic!("disc {r_disc} px {apart} px away: not read"));
            assert_eq!(u, axis);
            assert!(
                (offset - cx).abs() <= 0.5,
                "disc {r_disc} px {apart} px away: offset {offset:.2} px, truth {cx:.2}"
            );
        }
        let read = |r_disc: f64, apart: f64| {
            let (_, along, across) = union_moments(r_dot, r_disc, apart);
            dot_beside_a_larger_disc(axis, along.sqrt(), across.sqrt(), &expected)
        };
        assert_eq!(read(r_dot, 0.0), None, "a lone dot");
        assert_eq!(read(r_dot, 6.0), None, "two dots");
        assert_eq!(read(9.0, 1.0), None, "a dot inside a disc");
        // Apart (two blobs to the detector): the moments of the two together.
        assert_eq!(read(7.0, 16.0), None, "a disc apart from the dot");
    }

    /// The singular values do not change under rotations on either side.
    #[test]
    fn union_of_two_discs() {
        // The spread of two overlapping discs of diameter 1, by counting the points of a
        // fine grid in their union, against the table, and the table's inverse; and
        // across the line through them, the union is at least as wide as one disc
        // (second moment 1/16), far above `LOBE_MIN_ACROSS_RATIO`.
        let n = 1500;
        for k in [2usize, 5, 10, 15, 19] {
            let s = 0.05 * k as f64;
            let (mut count, mut sum, mut sum2, mut across2) = (0.0, 0.0, 0.0, 0.0);
            for i in 0..n {
                for j in 0..n {
                    let x = -1.0 + 2.0 * (i as f64 + 0.5) / n as f64;
                    let y = -1.0 + 2.0 * (j as f64 + 0.5) / n as f64;
                    let inside = |c: f64| (x - c).powi(2) + y * y <= 0.25;
                    if inside(0.5 * s) || inside(-0.5 * s) {
                        count += 1.0;
                        sum += x;
                        sum2 += x * x;
                        across2 += y * y;
                    }
                }
            }
            let spread = (sum2 / count - (sum / count).powi(2) - 1.0 / 16.0).sqrt();
            assert!(
                (spread - TWO_DISCS_SPREAD[k]).abs() < 2e-3,
                "s = {s}: {spread}"
            );
            let across = across2 / count * 16.0;
            assert!((1.0..1.1).contains(&across), "s = {s}: across {across}");
            let half = two_discs_half_apart(spread).unwrap();
            assert!((half - 0.5 * s).abs() < 3e-3, "s = {s}: half {half}");
        }
        assert_eq!(two_discs_half_apart(0.0), Some(0.0));
        assert_eq!(two_discs_half_apart(0.5), Some(0.5));
        assert_eq!(two_discs_half_apart(0.51), None);
        assert_eq!(two_discs_half_apart(f64::NAN), None);
    }

    #[test]
    fn singular_values_of_a_rotated_scaling() {
        let scaling = Matrix2x3::new(3.0, 0.0, 0.0, 0.0, 2.0, 0.0);
        let left = Rotation2::new(0.7).into_inner();
        let right = Rotation3::from_axis_angle(&Vector3::y_axis(), 0.4).into_inner();
        let (s1, s2) = singular_values(&(left * scaling * right));
        assert!(
            (s1 - 3.0).abs() < 1e-12 && (s2 - 2.0).abs() < 1e-12,
            "{s1} {s2}"
        );
        // Rank one: a projection that sees only one direction.
        let (s1, s2) = singular_values(&Matrix2x3::new(1.0, 2.0, 2.0, 0.0, 0.0, 0.0));
        assert!((s1 - 3.0).abs() < 1e-12 && s2.abs() < 1e-6, "{s1} {s2}");
    }
}
