//! Marker tracking and labeling: which painted dot is which layout marker, frame after
//! frame, from the two cameras' unlabeled detections.
//!
//! # Acquisition
//! While no head pose is known, the detections are paired under the epipolar constraint
//! ([`crate::stereo::pair_detections_where`]: among the pairs whose blobs are the size of
//! a dot at their depth and fill their ellipses as a dot does, so that skin clutter on a
//! dot's epipolar line does not make it ambiguous; ambiguous pairs dropped) and
//! triangulated; the unlabeled 3D points are registered to the layout's neutral positions with no prior beyond "the face is in
//! front of the cameras". RANSAC over point triples with distance-invariant matching:
//! three well-spread triangulated points give three distances, and every triple of
//! neutral markers with the same three pairwise distances (within a tolerance) is a
//! hypothesis, solved by Horn's closed form ([`crate::align::horn_alignment`]) and scored by the
//! truncated quadratic (MSAC) count of neutral markers landing on a triangulated point.
//! The best hypothesis is refined by iterated closest points and accepted only when it is
//! unambiguous (no distinct hypothesis scores close to it) and most points match within a
//! tight gate.
//!
//! # Tracking
//! Each marker keeps its position in the head frame `hᵢ` (the neutral position until seen,
//! then its last triangulated position carried back by the head pose) and its velocity in
//! the head frame. Per frame:
//! 1. The rigid head pose is predicted at constant velocity and every marker is predicted
//!    at `T·(hᵢ + vᵢ)` and projected into both cameras.
//! 2. Per camera, markers are assigned to detections within a gate around their
//!    prediction by the Hungarian method ([`crate::stereo::hungarian`], per connected component of the
//!    gated bipartite graph). An assignment with a rival (another detection near the
//!    prediction, or another prediction near the detection) is in doubt.
//! 3. Left/right pairing under the epipolar constraint: a marker's two detections must
//!    triangulate within the epipolar gate ([`super::gate`]: `k` robust standard
//!    deviations of the residuals of confidently labeled markers, at least
//!    [`LabelParams::max_reprojection_px`]) and land near the 3D
//!    prediction. A marker in doubt in one camera is kept only when exactly one of its
//!    candidate pairs passes both tests, and, at its first sighting, that pair leaves no
//!    free blob of a dot's size nearer to its prediction in either camera (the dot,
//!    unpaired where the other camera sees it edge-on, beside a mole both cameras see);
//!    otherwise it is dropped for the frame (a wrong label is worse than a missing one).
//! 4. The head pose of the frame is estimated by weighted Horn (stabilizing weights of
//!    the layout, with outlier rejection) from these labels, all markers are predicted
//!    again with it, and steps 2-3 run a second time with the tight gate: this absorbs
//!    fast head motion that the constant-velocity prediction misses. A marker tracked
//!    in the last frame that the tight gate misses but step 3 with the wide gate found
//!    (a lip corner starting to move fast) keeps that label when its dot left its
//!    predicted place and the blob is new where it is (the last frame had none where
//!    the skin there came from: a mole beside a vanished marker was there before).
//!
//! Markers that come back after an occlusion are looked for where their neighbours
//! labeled in the last frame put them (their neutral position moved like those
//! neighbours), with a gate that grows with the gap; those not found there, in a third
//! pass, at their last seen head-frame position carried by the current pose, when that
//! is elsewhere (neighbours lost with the marker leave the interpolation to farther ones,
//! which may move differently), among the detections left free and with the markers not
//! labeled as rivals. The next frame's search windows cover both places. Their place is
//! a guess, so a first sighting is not labeled when another pair of free blobs just
//! beyond its gate (within the ambiguity limit of its own distance, at most twice the
//! gate) would pass the same checks: a chin dot put 10 px off by far neighbours, beside
//! a mole of its size, is two blobs that each could be the marker.
//! Spurious blobs match no prediction, or fail the epipolar and 3D gates. A blob that
//! stood beside a marker's dot the last time the marker was labeled (a mole, a freckle,
//! a neighbour's dot: its offset from the dot is remembered) is never that marker's,
//! whatever its shape: when the dot vanishes (under the lip, smudged off) the blob beside
//! it is not taken for it ([`Labeler::stood_beside`]), unless the blobs that stood beside
//! the dot stand around it as around the dot ([`Labeler::dot_by_its_surroundings`]: the
//! prediction of a marker coming back may be off by as much as the mole was); nor is a
//! blob of a marker coming back whose remembered surroundings put the dot on another blob
//! ([`Labeler::beside_its_dot_found`]: a mole the lip carried to where the dot was last
//! seen, with the dot at the mole's offset from it); nor, after a short gap, is a blob
//! beyond its gate of where the dot was last seen that was there in the last frame (a dot
//! back soon is where it was, or new: [`Labeler::stayed_while_gone`]). Nor is a mole that
//! was one blob with the dot: a blob whose second moments are a dot's plus one direction's
//! is a dot merged with a blob beside it ([`Labeler::far_lobe`]); the lobe nearer to where the
//! neighbours put the marker is the dot, where the marker is labeled (at a first
//! sighting, unless the other lobe is within a rival's reach; a marker tracked onto such
//! a blob after a few frames), and the far lobe is remembered ([`Labeler::in_far_lobe`]).
//! A marker never labeled since the acquisition is labeled only once found in
//! [`CONFIRM_FRAMES`] frames in a row ([`Labeler::confirm_new_tracks`]; the acquisition's
//! frame counts, looked at with the acquisition's labels as the neighbours), as is a marker
//! back after a gap before its track held ([`HELD_FRAMES`] labels in a row), and only on a
//! blob about the size of its neighbours' dots in one camera at least, and not larger
//! than theirs in both ([`LabelParams::never_seen_min_relative_size`],
//! [`LabelParams::never_seen_max_relative_size`]); a marker back after a long gap, only
//! on a blob about its own dot's last whole size in one camera at least
//! ([`LabelParams::returning_max_size_change`]): a mole is a whole disc of another size,
//! off alike in both cameras. A marker whose
//! blobs stay smaller
//! than a whole dot of its paint can look, frame after frame, is not on its dot (a
//! freckle where a dot was wiped off): after [`tracking::SMALL_BLOB_FRAMES`] such labels
//! it is labeled only on a blob a first sighting may have. When too few
//! markers are labeled for a few frames, or the head pose does not fit the labels, the
//! tracks are dropped and the next frame is acquired again.
//!
//! The work is split by job: [`tracking`] (prediction, gated assignment and stereo
//! checks, head pose), [`acquisition`] (registration of unlabeled points to the layout),
//! [`assignment`] (optimal per-camera assignment) and [`surroundings`] (the blobs beside a
//! dot, found again around a candidate).

mod acquisition;
mod assignment;
mod surroundings;
mod tracking;

use nalgebra::{Isometry3, Point2, Point3, Vector2, Vector3};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand::seq::SliceRandom;

use super::Detection;
use super::gate::{EpipolarGate, EpipolarGateParams};
use super::search_windows::{Rect, in_any};
use crate::camera::StereoRig;
use crate::dataset::MarkerLayout;
use crate::frame_index::FrameIndex;
use crate::param_error::{ParamError, non_negative, positive};
use crate::stereo::{Bundle, PairParams};

/// A frame that labels fewer than this share of the markers of the frame before makes the
/// next frame search the whole region of interest instead of the windows (see
/// [`Labeler::predicted_windows`]).
pub const WINDOWS_KEEP_SHARE: f64 = 0.8;

/// In how many frames in a row a marker never labeled since the acquisition must be found
/// before it is labeled (see `Labeler::confirm_new_tracks`).
pub const CONFIRM_FRAMES: usize = 2;

/// In how many frames in a row a marker must have been labeled for its track to have held
/// (`Track::held`): until then a marker back after a gap is confirmed as a new one (see
/// `Labeler::confirm_new_tracks`).
pub const HELD_FRAMES: usize = 3;

/// Labeling settings.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct LabelParams {
    /// Pairing and triangulation for acquisition (epipolar gate, depth range, ambiguity).
    /// Default [`PairParams::default`].
    pub pair: PairParams,
    /// Acquisition: absolute tolerance when matching a distance between two triangulated
    /// points with a distance between two neutral markers, mm. Default 1.5.
    pub acquire_distance_tolerance_mm: f64,
    /// Acquisition: tolerance relative to the distance, added to the absolute one.
    /// Default 0.02.
    pub acquire_distance_tolerance_rel: f64,
    /// Acquisition: smallest distance between the points of a sampled triple, mm.
    /// Default 25.
    pub acquire_min_spread_mm: f64,
    /// Acquisition: number of sampled triples. Default 300.
    pub acquire_iterations: usize,
    /// Acquisition: a neutral marker matches a triangulated point within this, mm.
    /// Default 3.
    pub acquire_gate_mm: f64,
    /// Acquisition: smallest share of the markers in view of both cameras under the
    /// registered pose (inside both images, the skin's normal facing both when known) that
    /// the labeling pass under it must label. (Not a share of the triangulated points: on
    /// skin with clutter most of them may be freckles and moles.) Default 0.6.
    pub acquire_min_inlier_fraction: f64,
    /// Acquisition: fewest matched markers. Default 8.
    pub acquire_min_markers: usize,
    /// Acquisition: the best distinct rival hypothesis must score below this share of the
    /// best. Default 0.5.
    pub acquire_ambiguity_ratio: f64,
    /// Search radius around a marker's predicted pixel when it was labeled in the previous
    /// frame, pixels. Default 6.
    pub gate_px: f64,
    /// Added to the search radius per frame of a gap (a marker coming back after an
    /// occlusion), pixels. Default 1.
    pub gate_growth_px_per_frame: f64,
    /// Largest search radius for a marker coming back after a gap, pixels. Default 10.
    pub max_gap_gate_px: f64,
    /// Added to the search radius per pixel of predicted expression motion. Default 0.5.
    pub velocity_gate_factor: f64,
    /// Extra search radius of the first pass, which only estimates the head pose,
    /// pixels. Default 10.
    pub pose_pass_extra_gate_px: f64,
    /// An assignment at distance `e` is in doubt when a rival lies within
    /// `ambiguity_ratio · e + ambiguity_margin_px`. Default 2.
    pub ambiguity_ratio: f64,
    /// See [`LabelParams::ambiguity_ratio`], pixels. Default 2.
    pub ambiguity_margin_px: f64,
    /// Largest RMS reprojection error of a labeled marker's two detections (the epipolar
    /// gate) before the centroid noise is measured, and its floor afterwards, pixels.
    /// Default 0.6.
    pub max_reprojection_px: f64,
    /// Scaling of the epipolar gate with the measured centroid noise (its `floor_px` is
    /// replaced by [`LabelParams::max_reprojection_px`]). Default
    /// [`EpipolarGateParams::default`].
    pub epipolar_gate: EpipolarGateParams,
    /// The 3D gate around the prediction, as a multiple of the pixel gate's size at the
    /// marker's depth. Default 1.5.
    pub gate_3d_factor: f64,
    /// Share of the last frame-to-frame expression motion carried into the prediction.
    /// Default 0.8.
    pub velocity_damping: f64,
    /// Tracking is lost when fewer markers than this are labeled ... Default 6.
    pub lost_min_markers: usize,
    /// ... for this many frames in a row. Default 3.
    pub lost_frames: usize,
    /// A frame's labels are dropped when the stabilizing markers fit the rigid head pose
    /// worse than this RMS, mm. Default 2.5.
    pub max_pose_rms_mm: f64,
    /// A jump of more than this many frames (or a frame number that does not increase)
    /// drops the tracks. Default 5.
    pub max_frame_gap: usize,
    /// Margin added around the predicted markers for the detector's region of interest,
    /// pixels. Default 40.
    pub roi_margin_px: f64,
    /// While tracking, detect only in one window around each marker's predicted pixel
    /// (see [`Labeler::predicted_windows`]) instead of the whole region of interest: the
    /// skin between the markers, with its freckles, moles and hair, is not searched.
    /// After a frame that labels markedly fewer markers than the one before (a jolt of the
    /// helmet, a blurred frame), the next frame searches the whole region of interest.
    /// Default true.
    pub search_windows: bool,
    /// Margin of a search window beyond the marker's gate and the largest dot it may be,
    /// pixels. Default 6.
    pub window_margin_px: f64,
    /// Painted dot diameter, mm (a capture profile sets it from its `dot_diameter_mm`).
    /// Default 2.4.
    #[serde(skip_serializing)]
    pub dot_diameter_mm: f64,
    /// A blob is consistent with a dot at its triangulated position when its measured
    /// diameter ([`Detection::diameter_px`]) lies within this range of ratios of the
    /// major axes a dot of `dot_diameter_mm` can have there through the lens (from its
    /// smallest to its largest magnification, see `Labeler::dot_sized`), widened by 2 px
    /// either way (the antialiased rim and blur). Blobs of another size (freckles, pores,
    /// moles of another size, the pupils) are not taken for markers. The range for a
    /// marker labeled in the last frame (its blob may be partly hidden by a lip or
    /// smeared by motion). Default 0.5 to 1.8.
    pub dot_size_ratio: (f64, f64),
    /// The range of [`LabelParams::dot_size_ratio`] for a marker's first sighting (in
    /// acquisition, or a marker not labeled in the last frame: one never seen, or coming
    /// back after a gap): with no track to vouch for it, the blob must look like a whole
    /// dot. Freckles and pores (too small), a dot merged with
    /// a mole beside it, or a dot smeared off its place (too large) are not taken for a
    /// marker that was never seen. Default 0.8 to 1.35 (whole dots measure 0.87 or more of
    /// the smallest size on clean skin; 0.7 let a freckle 0.65 of a dot, where a dot was
    /// wiped off, be taken at acquisition).
    pub first_sighting_size_ratio: (f64, f64),
    /// With the skin's normal at each marker ([`Labeler::set_marker_normals`]): a blob is
    /// a marker's only when its roundness is at least this share of the roundness its
    /// dot has from the camera, `cos(θ + slack)`, θ the angle between the camera's line
    /// of sight and the neutral face's normal at the marker, `slack`
    /// [`LabelParams::normal_slack_deg`] (0: no check). A sliver of a dot mostly hidden by
    /// a lip, or a piece of a smeared dot, is much thinner than the dot where the skin
    /// faces the camera, and its centre is off the dot's by up to half a diameter.
    /// Default 0.7: over the synth presets and set-ups nothing was tuned on, 0.6 left a
    /// piece of a smeared dot labeled (roundness 0.53 where the floor was 0.50), 0.8
    /// began to refuse whole dots (1 point fewer labels on one set-up), 0.7 did neither.
    pub min_roundness_ratio: f64,
    /// How far the skin at a marker may turn from the neutral face's normal (expressions
    /// roll the lips and stretch the cheeks), degrees: the roundness check of
    /// [`LabelParams::min_roundness_ratio`] assumes the dot turned that much further
    /// from the camera. Default 25.
    pub normal_slack_deg: f64,
    /// At a marker's first sighting (see [`LabelParams::first_sighting_size_ratio`]), the
    /// blob must fill at least this share of the ellipse of its second moments (its area
    /// over `π/4 · major · minor`, see [`BlobShape::fill`]); 0: no check. A dot, whole,
    /// partly hidden or seen from any angle, is a filled ellipse (0.85–1.05 on the synth
    /// presets, 1 % of dots under 0.7 on cluttered skin); a crease fragment, a smeared dot
    /// with a hair across it, or a dot with a mole at its side is not (0.40–0.53 for the
    /// wrong labels this rule removed). Default 0.6.
    pub first_sighting_min_fill: f64,
    /// A marker not labeled since the acquisition (its dot wiped off before the take, or
    /// hidden since) is taken only on blobs at least this share of the size its neighbours'
    /// dots measure, in one camera at least; 0: no check. Size here is a blob's diameter
    /// over the largest major axis a dot can have where it is (see
    /// [`LabelParams::dot_size_ratio`]), and the neighbours' the median of theirs at their
    /// labels in the last frame, or at the acquisition (where every marker is seen for the
    /// first time) in the same frame: at least two labeled as whole dots; with fewer, no
    /// check. A mole or freckle where such a marker's dot should be is a whole disc of its
    /// own size, smaller than a dot alike in both cameras; a dot partly hidden by a lip or
    /// seen at the silhouette is small in one camera more than the other. So the
    /// neighbours' dots, measured by the same lens, blur and light, set the size, where
    /// [`LabelParams::first_sighting_size_ratio`] must allow for every rig's. Default 0.75:
    /// on nine cluttered and wiped-moles set-ups, never-seen markers' right first sightings
    /// measured 0.85 or more of their neighbours' dots in one camera, the acquisition's
    /// labels 0.81 or more, a mole taken for a wiped marker 0.67 in both.
    pub never_seen_min_relative_size: f64,
    /// Nor is such a marker taken on blobs larger than this share of the size its
    /// neighbours' dots measure in both cameras (sizes as for
    /// [`LabelParams::never_seen_min_relative_size`]); 0: no check. A mole larger than a
    /// dot beside where the marker's dot should be (the dot wiped off, or seen so nearly
    /// edge-on from one camera that the mole is all that camera finds there), or the dot
    /// merged with it, is larger than the neighbours' whole dots alike in both cameras; a
    /// dot merged with a blob in one camera only is not. The first sighting's range
    /// ([`LabelParams::first_sighting_size_ratio`], with its 2 px for any rig's rim and
    /// blur) lets such a mole pass. Default 1.3: on lip-press seed 901 a 3.8 mm mole
    /// beside a dot seen at 71° and 81° from the cameras measured 1.38-1.44 of the
    /// neighbours' dots in one camera and 1.40-1.46 in the other (labeled for 56 frames);
    /// over 72 set-ups of every preset, 1.2 cost up to 0.24 points of labeled markers on
    /// four, 1.3 and 1.35 two marker-frames on one (a dot merged with a blob at the
    /// acquisition).
    pub never_seen_max_relative_size: f64,
    /// A marker coming back after a gap of 10 frames or more is not taken on a blob larger,
    /// or smaller, than its dot at its last whole label by more than this share in both
    /// cameras alike (sizes relative to the largest major axis a dot can have where each
    /// is, as for [`LabelParams::never_seen_min_relative_size`]); 0: no check. Where a
    /// marker's neighbours are far or move unlike it (a lip corner, the chin under an
    /// opening jaw), the place they predict for it stays behind the skin while it is gone,
    /// and a mole that stood beside its dot, moving with the skin, slides into the gate: a
    /// whole disc of its own size, as much off the dot's in both cameras. A dot back whole
    /// is its own size again; one still partly hidden is smaller in one camera more than
    /// the other. Default 0.15: on nine cluttered and wiped-moles set-ups, the right
    /// returns after 10 frames or more were within 10 % of the dot's last size in one
    /// camera at least, the three moles taken for wiped markers 0.75, 1.22 and 1.40 of it
    /// in both. The same share tells a tracked marker's dot that moved suddenly from a
    /// rival blob beside it (see `Labeler::doubt_told_by_size`).
    pub returning_max_size_change: f64,
    /// A marker labeled within the last 10 frames is not taken on a blob both fainter
    /// than this share of its dot's contrast at its last label
    /// ([`crate::track::Detection::contrast_dn`]: as dark, or as bright for bright dots,
    /// against the skin around it) in both cameras, and smaller than a first sighting may
    /// be ([`LabelParams::first_sighting_size_ratio`]); 0: no check. Contrast allows for
    /// the change of light since that label, followed frame by frame as the median change
    /// of the markers the pose pass found where they were labeled in the last frame (a
    /// flicker or an exposure step moves them all alike). A freckle under a dot that was
    /// just wiped off is fainter and smaller than the ink, inside the marker's gate; a dot
    /// partly hidden by a lip is small but dark, one under a shadow that fell on part of
    /// the face faint but whole. Default 0.6: see the README's "A tracked marker keeps its
    /// ink's contrast".
    pub kept_contrast_ratio: f64,
    /// Whether a marker may be labeled on a worn dot: a blob that fails the dot's shape
    /// rules ([`LabelParams::dot_size_ratio`], [`LabelParams::min_roundness_ratio`],
    /// [`LabelParams::first_sighting_min_fill`]) because sweat or a wipe smeared its ink
    /// into a longer ellipse. Such a blob is taken only where the marker's neighbours put
    /// it, not where its own track does: its major axis within
    /// [`LabelParams::worn_dot_size_ratio`] in one camera at least (in the other at
    /// least a whole dot long: a smear along that camera's line of sight), in both its
    /// minor axis at least
    /// [`LabelParams::worn_dot_min_width_ratio`] of a dot's, and its centre within
    /// [`LabelParams::worn_dot_centre_tolerance`] of the marker's position moved like its
    /// neighbours labeled in the last frame (the last pose's head frame, carried by this
    /// frame's pose; at least two such neighbours). A smear that keeps its ink around the
    /// painted spot is labeled at its centre; a dot merged with a mole or a hair, a smear
    /// dragged off to one side, or a sliver of a dot under a lip has its centre moved off
    /// the spot by a quarter of a dot or more and is not. Default true.
    pub worn_dots: bool,
    /// The range of a worn dot's major axis, as ratios of the largest major axis a dot can
    /// have there (its diameter at the largest magnification through the lens, see
    /// [`LabelParams::dot_size_ratio`]), narrowed by 2 px at the bottom and widened by 2 px
    /// and the motion blur at the top: longer than a whole dot with its antialiased rim
    /// can look (a dot's sliver, a dot seen obliquely, a small dot blurred are not worn
    /// dots), up to a smear 2.5 times the dot. Default 1.2 to 2.5.
    pub worn_dot_size_ratio: (f64, f64),
    /// A worn dot's minor axis (its major axis times its roundness) at least this share of
    /// the smallest diameter a dot has there, foreshortened as in
    /// [`LabelParams::min_roundness_ratio`] (a smear `s` times the dot's length is
    /// `1/√s` as wide: 0.67 at 2.2; a hair or a crease is far thinner). Default 0.5.
    pub worn_dot_min_width_ratio: f64,
    /// How far a worn dot's centre may be from where the neighbours put the marker, as a
    /// share of the dot's largest diameter there, plus 1 px for the error of that position
    /// (median 0.5 px for the smeared dots of the `cluttered` preset; a dot merged with a
    /// mole of its own size is off by a third of a dot). Default 0.125 (the detector's
    /// tolerance for two blobs to be concentric).
    pub worn_dot_centre_tolerance: f64,
    /// Acquisition: at most this many detections per image take part, the best by
    /// quality (bounds the time of an attempt on skin with hundreds of blobs). Default
    /// 400.
    pub acquire_max_detections: usize,
    /// Acquisition: sampled triples per frame; an acquisition that needs more samples goes
    /// on over the next frames with the hypotheses found so far (the stream never waits for
    /// it). Default 150.
    pub acquire_iterations_per_frame: usize,
    /// Acquisition: at most this many hypotheses (a triple's candidate correspondences,
    /// each aligned and scored) per frame. This, not the number of triples, is what an
    /// attempt costs: on skin with hundreds of blobs a triple brings hundreds of
    /// candidates, and each is scored against every triangulated point. The search goes on
    /// next frame. Default 8000: with 500 blobs of a dot's size added to each image of
    /// `cluttered`, an attempt takes 34 ms (median; 40 ms at most) and the search acquires
    /// in a few frames (`bench capture`); 12000 took 49 ms (57 ms) once pairs of dot-sized
    /// blobs were no longer dropped for the clutter beside them on their epipolar lines.
    pub acquire_hypotheses_per_frame: usize,
}

impl Default for LabelParams {
    fn default() -> Self {
        Self {
            pair: PairParams::default(),
            acquire_distance_tolerance_mm: 1.5,
            acquire_distance_tolerance_rel: 0.02,
            acquire_min_spread_mm: 25.0,
            acquire_iterations: 300,
            acquire_gate_mm: 3.0,
            acquire_min_inlier_fraction: 0.6,
            acquire_min_markers: 8,
            acquire_ambiguity_ratio: 0.5,
            gate_px: 6.0,
            gate_growth_px_per_frame: 1.0,
            max_gap_gate_px: 10.0,
            velocity_gate_factor: 0.5,
            pose_pass_extra_gate_px: 10.0,
            ambiguity_ratio: 2.0,
            ambiguity_margin_px: 2.0,
            max_reprojection_px: 0.6,
            epipolar_gate: EpipolarGateParams::default(),
            gate_3d_factor: 1.5,
            velocity_damping: 0.8,
            lost_min_markers: 6,
            lost_frames: 3,
            max_pose_rms_mm: 2.5,
            max_frame_gap: 5,
            roi_margin_px: 40.0,
            search_windows: true,
            window_margin_px: 6.0,
            dot_diameter_mm: 2.4,
            dot_size_ratio: (0.5, 1.8),
            first_sighting_size_ratio: (0.8, 1.35),
            min_roundness_ratio: 0.7,
            normal_slack_deg: 25.0,
            first_sighting_min_fill: 0.6,
            never_seen_min_relative_size: 0.75,
            never_seen_max_relative_size: 1.3,
            returning_max_size_change: 0.15,
            kept_contrast_ratio: 0.6,
            worn_dots: true,
            worn_dot_size_ratio: (1.2, 2.5),
            worn_dot_min_width_ratio: 0.5,
            worn_dot_centre_tolerance: 0.125,
            acquire_max_detections: 400,
            acquire_iterations_per_frame: 150,
            acquire_hypotheses_per_frame: 8_000,
        }
    }
}

impl LabelParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`ParamError`] naming the field.
    pub fn validate(&self) -> Result<(), ParamError> {
        let err = ParamError::new;
        let tp = &self.pair.triangulate;
        positive(
            tp.max_reprojection_px,
            "pair.triangulate.max_reprojection_px",
        )?;
        positive(tp.sigma_px, "pair.triangulate.sigma_px")?;
        let (z0, z1) = tp.depth_range_mm;
        if !(z0.is_finite() && z1.is_finite() && 0.0 < z0 && z0 < z1) {
            return Err(err(
                "pair.triangulate.depth_range_mm",
                "must be 0 < near < far",
            ));
        }
        non_negative(self.pair.ambiguity_margin_px, "pair.ambiguity_margin_px")?;
        non_negative(
            self.acquire_distance_tolerance_mm,
            "acquire_distance_tolerance_mm",
        )?;
        non_negative(
            self.acquire_distance_tolerance_rel,
            "acquire_distance_tolerance_rel",
        )?;
        if self.acquire_distance_tolerance_mm + self.acquire_distance_tolerance_rel <= 0.0 {
            return Err(err(
                "acquire_distance_tolerance_mm",
                "and acquire_distance_tolerance_rel cannot both be 0",
            ));
        }
        non_negative(self.acquire_min_spread_mm, "acquire_min_spread_mm")?;
        if self.acquire_iterations == 0 {
            return Err(err("acquire_iterations", "must be at least 1"));
        }
        positive(self.acquire_gate_mm, "acquire_gate_mm")?;
        if !(0.0..=1.0).contains(&self.acquire_min_inlier_fraction) {
            return Err(err("acquire_min_inlier_fraction", "must be in [0, 1]"));
        }
        if self.acquire_min_markers < 3 {
            return Err(err("acquire_min_markers", "must be at least 3"));
        }
        if !(self.acquire_ambiguity_ratio > 0.0 && self.acquire_ambiguity_ratio <= 1.0) {
            return Err(err("acquire_ambiguity_ratio", "must be in (0, 1]"));
        }
        positive(self.gate_px, "gate_px")?;
        non_negative(self.gate_growth_px_per_frame, "gate_growth_px_per_frame")?;
        positive(self.max_gap_gate_px, "max_gap_gate_px")?;
        non_negative(self.velocity_gate_factor, "velocity_gate_factor")?;
        non_negative(self.pose_pass_extra_gate_px, "pose_pass_extra_gate_px")?;
        if !(self.ambiguity_ratio.is_finite() && self.ambiguity_ratio >= 1.0) {
            return Err(err("ambiguity_ratio", "must be at least 1"));
        }
        non_negative(self.ambiguity_margin_px, "ambiguity_margin_px")?;
        positive(self.max_reprojection_px, "max_reprojection_px")?;
        EpipolarGateParams {
            floor_px: self.max_reprojection_px,
            ceiling_px: self.epipolar_gate.ceiling_px.max(self.max_reprojection_px),
            ..self.epipolar_gate.clone()
        }
        .validate()
        .map_err(|e| e.within("epipolar_gate"))?;
        positive(self.gate_3d_factor, "gate_3d_factor")?;
        if !(0.0..=1.0).contains(&self.velocity_damping) {
            return Err(err("velocity_damping", "must be in [0, 1]"));
        }
        if self.lost_min_markers < 3 {
            return Err(err("lost_min_markers", "must be at least 3"));
        }
        if self.lost_frames == 0 {
            return Err(err("lost_frames", "must be at least 1"));
        }
        positive(self.max_pose_rms_mm, "max_pose_rms_mm")?;
        if self.max_frame_gap == 0 {
            return Err(err("max_frame_gap", "must be at least 1"));
        }
        non_negative(self.roi_margin_px, "roi_margin_px")?;
        non_negative(self.window_margin_px, "window_margin_px")?;
        if !(self.dot_diameter_mm.is_finite() && self.dot_diameter_mm > 0.0) {
            return Err(err("dot_diameter_mm", "must be positive"));
        }
        for (name, (lo, hi)) in [
            ("dot_size_ratio", self.dot_size_ratio),
            ("first_sighting_size_ratio", self.first_sighting_size_ratio),
            ("worn_dot_size_ratio", self.worn_dot_size_ratio),
        ] {
            if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo < hi) {
                return Err(err(name, "must be 0 <= low < high"));
            }
        }
        if !(0.0..=1.0).contains(&self.min_roundness_ratio) {
            return Err(err("min_roundness_ratio", "must be in [0, 1]"));
        }
        if !(0.0..=1.0).contains(&self.first_sighting_min_fill) {
            return Err(err("first_sighting_min_fill", "must be in [0, 1]"));
        }
        if !(0.0..=1.0).contains(&self.never_seen_min_relative_size) {
            return Err(err("never_seen_min_relative_size", "must be in [0, 1]"));
        }
        let max_share = self.never_seen_max_relative_size;
        if !(max_share == 0.0 || (max_share.is_finite() && max_share >= 1.0)) {
            return Err(err(
                "never_seen_max_relative_size",
                "must be 0 (no check) or at least 1",
            ));
        }
        non_negative(self.returning_max_size_change, "returning_max_size_change")?;
        if !(0.0..=1.0).contains(&self.kept_contrast_ratio) {
            return Err(err("kept_contrast_ratio", "must be in [0, 1]"));
        }
        if !(0.0..=1.0).contains(&self.worn_dot_min_width_ratio) {
            return Err(err("worn_dot_min_width_ratio", "must be in [0, 1]"));
        }
        if !(0.0..=1.0).contains(&self.worn_dot_centre_tolerance) {
            return Err(err("worn_dot_centre_tolerance", "must be in [0, 1]"));
        }
        if !(0.0..=90.0).contains(&self.normal_slack_deg) {
            return Err(err("normal_slack_deg", "must be in [0, 90] degrees"));
        }
        if self.acquire_max_detections < self.acquire_min_markers {
            return Err(err(
                "acquire_max_detections",
                "must be at least acquire_min_markers",
            ));
        }
        if self.acquire_iterations_per_frame == 0 {
            return Err(err("acquire_iterations_per_frame", "must be at least 1"));
        }
        if self.acquire_hypotheses_per_frame == 0 {
            return Err(err("acquire_hypotheses_per_frame", "must be at least 1"));
        }
        Ok(())
    }
}

/// Why a [`Labeler`] cannot be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LabelError {
    /// The layout or the neutral positions are unusable.
    #[error("marker layout: {0}")]
    Layout(String),
    /// The stereo rig is invalid.
    #[error("stereo rig: {0}")]
    Rig(String),
    /// A parameter is out of range.
    #[error("label parameters: {0}")]
    Params(ParamError),
}

/// One labeled marker of a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct LabeledMarker {
    /// The triangulated position (cam0 frame, mm) with reprojection error and confidence.
    pub bundle: Bundle,
    /// The detections used, cam0 and cam1, pixels.
    pub pixels: [Point2<f64>; 2],
    /// Their indices in the input slices.
    pub detections: [usize; 2],
    /// True on the first frame the marker is labeled again after a gap.
    pub reacquired: bool,
}

/// Counts of one frame.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct LabelStats {
    /// Detections given, cam0 and cam1.
    pub detections: [usize; 2],
    /// Stereo pairs formed: unambiguous epipolar pairs while acquiring, markers with a
    /// candidate detection in both cameras while tracking.
    pub paired: usize,
    /// Markers labeled.
    pub labeled: usize,
    /// Markers labeled again after a gap.
    pub reacquired: usize,
    /// Markers with candidates that were dropped: in doubt, or failing the epipolar or
    /// 3D gate (and all labels of a frame whose head pose does not fit).
    pub rejected: usize,
    /// True when the frame was (or failed to be) labeled by acquisition.
    pub acquiring: bool,
}

/// The labels of one stereo frame.
#[derive(Debug, Clone, PartialEq)]
pub struct LabeledFrame {
    /// One entry per layout marker, in layout order: None when not labeled this frame.
    pub markers: Vec<Option<LabeledMarker>>,
    /// Counts.
    pub stats: LabelStats,
}

/// What the labeler remembers of one marker.
#[derive(Debug, Clone, PartialEq)]
struct Track {
    /// Position in the head frame, mm (the neutral position until seen).
    head: Point3<f64>,
    /// Motion in the head frame over the last frame, mm per frame.
    velocity: Vector3<f64>,
    /// Frames since the marker was last labeled (0: labeled in the last frame); None
    /// when never labeled since the last acquisition.
    frames_since_seen: Option<usize>,
    /// The marker's last label was a worn dot ([`LabelParams::worn_dots`]).
    worn: bool,
    /// When the marker's last label was a dot merged with a blob beside it (labeled at
    /// the dot's lobe, see `Labeler::merged_dot`): the largest distance, pixels, from the
    /// blob's centre to the lobe in either camera; 0 otherwise.
    lobe_px: f64,
    /// Each camera's blob diameter ([`Detection::diameter_px`]) at the marker's last label
    /// when that was at a dot's lobe (see `Labeler::back_on_its_merged_blob`); None
    /// otherwise.
    lobe_blob_px: Option<[f64; 2]>,
    /// While never labeled since the acquisition, or back after a gap before it was
    /// [`Track::held`]: the frames in a row in which the marker would have been labeled
    /// (see [`Labeler::confirm_new_tracks`]).
    confirming: usize,
    /// Frames in a row in which the marker was labeled, up to the last one (0: not labeled
    /// in the last frame).
    run: usize,
    /// The marker was labeled by the acquisition, or in [`HELD_FRAMES`] frames in a row,
    /// since the acquisition: a track that held, which a marker back after a gap resumes
    /// without confirmation.
    held: bool,
    /// Labeled frames in a row whose blobs were smaller than a first sighting may be
    /// ([`Labeler::smaller_than_a_whole_dot`]).
    small_blob_frames: usize,
    /// At the marker's last label on a whole dot's blob ([`Labeler::whole_dot_sizes`]: a
    /// dot sinking behind the lip is not remembered at its last sliver's size): each
    /// camera's blob diameter over the largest major axis a dot can have there
    /// ([`Labeler::size_over_expected`]); None before such a label since the acquisition.
    size_over_expected: Option<[f64; 2]>,
    /// Each camera's blob contrast ([`Detection::contrast_dn`]) at the marker's last label
    /// on a dot's own blob (not a worn dot, not a lobe of a merged blob), over the light of
    /// that frame (`Labeler::light`); None before such a label since the acquisition.
    contrast_dn: Option<[f64; 2]>,
}

/// Tracks and labels markers frame by frame (see the module docs).
#[derive(Debug, Clone)]
pub struct Labeler {
    rig: StereoRig,
    neutral: Vec<Point3<f64>>,
    stabilize: Vec<f64>,
    params: LabelParams,
    /// Neutral distance matrix, `m × m`.
    distances: Vec<f64>,
    /// Ordered neutral marker pairs `(distance, i, j)`, sorted by distance.
    pair_table: Vec<(f64, u32, u32)>,
    /// The markers in a fixed shuffled order (hypothesis scoring looks at a spread-out
    /// subset first).
    score_order: Vec<usize>,
    /// Per marker: up to 6 nearest other markers on the neutral within 35 mm, with their
    /// distances.
    neighbours: Vec<Vec<(usize, f64)>>,
    tracks: Vec<Track>,
    /// Head pose (head → cam0) of the last labeled frame and the one before.
    pose: Option<Isometry3<f64>>,
    prev_pose: Option<Isometry3<f64>>,
    last_frame: Option<FrameIndex>,
    lost_count: usize,
    rois: [Option<(u32, u32, u32, u32)>; 2],
    /// Per camera: the search windows of the next frame (empty: search the ROI).
    windows: [Vec<Rect>; 2],
    /// Per camera and window: where a detection's centre can be a candidate of the
    /// window's marker (see [`Labeler::predicted_centres`]).
    centres: [Vec<Rect>; 2],
    /// Markers labeled in the last processed frame.
    last_labeled: usize,
    /// The last processed frame's detections, where they were looked for and where its
    /// markers were labeled: whether a blob near a marker is new there.
    seen_before: Option<SeenBefore>,
    /// Per marker and camera, the other blobs within [`Labeler::beside_reach_px`] of the
    /// marker's dot the last time it was labeled, as offsets from it, pixels (at least a
    /// tight gate away: nearer ones are pieces of the dot). Kept while the marker is
    /// missing; see [`Labeler::stood_beside`].
    beside: Vec<[Vec<Vector2<f64>>; 2]>,
    /// Per marker and camera, the lobes of its blob the last time it was labeled, when
    /// that blob was its dot merged with another (see [`Labeler::in_far_lobe`]).
    lobes: Vec<[Option<Lobes>; 2]>,
    /// The epipolar gate, scaled with the measured residuals (kept across re-acquisition:
    /// the noise belongs to the cameras, not the tracks).
    gate: EpipolarGate,
    /// Per camera, the light of this frame relative to the acquisition's: the product of
    /// the frames' changes of light since (see `Labeler::change_of_light` and
    /// [`LabelParams::kept_contrast_ratio`]).
    light: [f64; 2],
    /// Whether this frame's change of light is known (when not, contrast is not checked).
    light_measured: bool,
    /// The shapes of the current frame's detections, per camera.
    blobs: [Vec<BlobShape>; 2],
    /// The current frame's detections' centres, for [`Labeler::surroundings_fit`].
    blobs_now: surroundings::FrameBlobs,
    /// An acquisition under way over several frames.
    acquisition: acquisition::Search,
    /// Marker positions (head frame, layout order) of expressions acquisition tries
    /// besides the neutral ([`Labeler::set_expression_templates`]).
    templates: Vec<Vec<Point3<f64>>>,
    /// Unit normals of the neutral face at the markers (head frame, layout order; empty:
    /// none, [`Labeler::set_marker_normals`]).
    normals: Vec<Vector3<f64>>,
}

/// A point's pixels in cam0 and cam1 (None: behind the camera or outside its image).
type StereoPixels = [Option<Point2<f64>>; 2];

/// A marker's prediction for one labeling pass.
#[derive(Debug, Clone, Copy)]
struct Prediction {
    point: Point3<f64>,
    pixels: StereoPixels,
    gate_px: f64,
    gate_mm: f64,
    /// Image motion since the last frame in each camera, pixels: a dot moving this much
    /// during the exposure is blurred up to this much longer.
    motion_px: [f64; 2],
    /// The marker was not labeled in the last frame (its size is held to
    /// [`LabelParams::first_sighting_size_ratio`]): a track that broke off does not
    /// vouch for a partial blob where the marker is predicted now, since that prediction
    /// rests on its neighbours and may be far from the dot (a lip that moved during the
    /// gap).
    first_sighting: bool,
    /// The skin's normal at the marker (cam0 frame), when known.
    normal: Option<Vector3<f64>>,
    /// Where the marker's neighbours put it (cam0 frame, see
    /// [`LabelParams::worn_dots`]) and its pixels; None without two neighbours labeled in
    /// the last frame, or with worn dots off.
    vouched: Option<(Point3<f64>, StereoPixels)>,
    /// A worn dot may be taken for the marker: worn dots are on and the marker was not
    /// labeled in the last frame, or was on a worn dot.
    may_be_worn: bool,
    /// For a marker coming back (labeled before, not in the last frame): the pixels of
    /// where it was last labeled, in the head's frame, under this pass's pose (see
    /// [`Labeler::stood_beside`]).
    last_seen: Option<StereoPixels>,
    /// `pixels` are where the marker's neighbours put it (not its track's place).
    from_neighbours: bool,
    /// For a marker looked for where it was last seen (the tracking's third pass): where
    /// its neighbours put it, which [`Labeler::stood_beside`] also asks from. A marker gone
    /// for long was last seen where its skin no longer is (wiped-moles seed 93's M015,
    /// 114 frames after its dot was wiped: 6.7 px off), and a mole that stood beside its
    /// dot is off its remembered offset from there, not from where the neighbours put it.
    neighbours_place: Option<StereoPixels>,
    /// The marker's last label, in the last frame, was a dot merged with a blob beside it.
    merged: bool,
}

/// The lobes of a marker's blob that is its dot merged with a blob beside it (see
/// `Labeler::far_lobe`), pixels.
#[derive(Debug, Clone, Copy)]
struct Lobes {
    /// The far lobe's centre from the label's pixel (the blob's centre, or the dot's
    /// lobe when the label is there).
    from_label: Vector2<f64>,
    /// The far lobe's centre from the near one's (the dot's).
    apart: Vector2<f64>,
    /// On how many consecutive labels the blob had about these lobes.
    frames: usize,
}

/// A frame's detections as the next frame sees them (see `Labeler::label_sudden_moves`).
#[derive(Debug, Clone, Default)]
struct SeenBefore {
    /// The detections' centres, per camera.
    pixels: [Vec<Point2<f64>>; 2],
    /// Per camera, the boxes the detector reported blobs in (empty: the whole image or
    /// region of interest).
    looked: [Vec<Rect>; 2],
    /// Each marker's pixels where it was labeled (None: not labeled).
    markers: Vec<Option<[Point2<f64>; 2]>>,
    /// The major axes of each labeled marker's blobs, pixels (NaN: not measured).
    marker_blobs_px: Vec<Option<[f64; 2]>>,
}

impl SeenBefore {
    /// Whether camera `c` had no blob within `tolerance_px` of `at`, in a place its
    /// detector looked (false where it did not look: nothing is known there).
    fn nothing_near(&self, c: usize, at: Point2<f64>, tolerance_px: f64) -> bool {
        let looked = self.looked[c].is_empty() || in_any(&self.looked[c], at);
        looked
            && self.pixels[c]
                .iter()
                .all(|p| (p - at).norm() > tolerance_px)
    }
}

/// What the labeler reads of a detection's shape.
#[derive(Debug, Clone, Copy)]
struct BlobShape {
    /// [`Detection::diameter_px`].
    diameter_px: f64,
    /// [`Detection::quality`].
    quality: f64,
    /// [`Detection::roundness`].
    roundness: f64,
    /// The share of the ellipse of its second moments the blob fills: its area over
    /// `π/4 · major · minor` with `major` [`Detection::diameter_px`] and `minor` that
    /// times [`Detection::roundness`] (a filled ellipse: 1, a filled disc's pixels about
    /// 1 with its antialiased rim); NaN when not measured.
    fill: f64,
    /// Unit vector along [`Detection::axis_rad`]; None when not measured.
    axis: Option<Vector2<f64>>,
    /// [`Detection::streak`].
    streak: bool,
    /// [`Detection::contrast_dn`].
    contrast_dn: f64,
}

impl BlobShape {
    fn of(d: &Detection) -> Self {
        let ellipse = std::f64::consts::FRAC_PI_4 * d.diameter_px * d.diameter_px * d.roundness;
        Self {
            diameter_px: d.diameter_px,
            quality: d.quality,
            roundness: d.roundness,
            fill: d.area_px as f64 / ellipse,
            axis: d
                .axis_rad
                .is_finite()
                .then(|| Vector2::new(d.axis_rad.cos(), d.axis_rad.sin())),
            streak: d.streak,
            contrast_dn: d.contrast_dn,
        }
    }
}

/// A labeled marker before it becomes output.
#[derive(Debug, Clone, Copy)]
struct Label {
    marker: usize,
    det: [usize; 2],
    bundle: Bundle,
    /// Assigned without a rival in either camera (its residual feeds the gate estimate).
    confident: bool,
    /// On a worn dot ([`LabelParams::worn_dots`]).
    worn: bool,
    /// On a dot merged with a blob beside it: the pixels of the dot's lobe, where the
    /// label is (see `Labeler::merged_dot`); None: at the detections' centres.
    at: Option<[Point2<f64>; 2]>,
}

/// Result of one labeling pass.
struct PassResult {
    labels: Vec<Label>,
    paired: usize,
    rejected: usize,
}

impl Labeler {
    /// `neutral_markers_head`: each layout marker's position on the neutral mesh (head
    /// frame, mm), in layout order.
    ///
    /// # Errors
    /// [`LabelError::Layout`] for an empty layout, a count mismatch or non-finite
    /// positions; [`LabelError::Rig`] for an invalid rig; [`LabelError::Params`].
    pub fn new(
        rig: StereoRig,
        layout: &MarkerLayout,
        neutral_markers_head: Vec<Point3<f64>>,
        params: LabelParams,
    ) -> Result<Self, LabelError> {
        params.validate().map_err(LabelError::Params)?;
        rig.validate().map_err(|e| LabelError::Rig(e.to_string()))?;
        if layout.len() < 3 {
            return Err(LabelError::Layout(format!(
                "{} markers; labeling needs at least 3",
                layout.len()
            )));
        }
        if neutral_markers_head.len() != layout.len() {
            return Err(LabelError::Layout(format!(
                "{} neutral positions for {} markers",
                neutral_markers_head.len(),
                layout.len()
            )));
        }
        if let Some(i) = neutral_markers_head
            .iter()
            .position(|p| !p.coords.iter().all(|v| v.is_finite()))
        {
            return Err(LabelError::Layout(format!(
                "neutral position of marker {} is not finite",
                layout.markers[i].name
            )));
        }
        let m = layout.len();
        let mut distances = vec![0.0; m * m];
        let mut pair_table = Vec::with_capacity(m * (m - 1));
        for i in 0..m {
            for j in 0..m {
                let d = (neutral_markers_head[i] - neutral_markers_head[j]).norm();
                distances[i * m + j] = d;
                if i != j {
                    pair_table.push((d, i as u32, j as u32));
                }
            }
        }
        pair_table.sort_by(|a, b| a.0.total_cmp(&b.0));
        let stabilize = layout
            .markers
            .iter()
            .map(|mk| {
                if mk.stabilize_weight.is_finite() {
                    mk.stabilize_weight.clamp(0.0, 1.0)
                } else {
                    0.0
                }
            })
            .collect();
        let tracks = fresh_tracks(&neutral_markers_head);
        let mut score_order: Vec<usize> = (0..m).collect();
        score_order.shuffle(&mut StdRng::seed_from_u64(0x5c0e));
        let neighbours = (0..m)
            .map(|i| {
                let mut near: Vec<(usize, f64)> = (0..m)
                    .filter(|&j| j != i && distances[i * m + j] <= 35.0)
                    .map(|j| (j, distances[i * m + j]))
                    .collect();
                near.sort_by(|a, b| a.1.total_cmp(&b.1));
                near.truncate(6);
                near
            })
            .collect();
        Ok(Self {
            rig,
            neutral: neutral_markers_head,
            stabilize,
            distances,
            pair_table,
            score_order,
            neighbours,
            tracks,
            pose: None,
            prev_pose: None,
            last_frame: None,
            lost_count: 0,
            rois: [None, None],
            windows: [Vec::new(), Vec::new()],
            centres: [Vec::new(), Vec::new()],
            last_labeled: 0,
            seen_before: None,
            beside: vec![Default::default(); m],
            lobes: vec![[None; 2]; m],
            gate: EpipolarGate::new(EpipolarGateParams {
                floor_px: params.max_reprojection_px,
                ceiling_px: params
                    .epipolar_gate
                    .ceiling_px
                    .max(params.max_reprojection_px),
                ..params.epipolar_gate.clone()
            }),
            light: [1.0; 2],
            light_measured: false,
            blobs: [Vec::new(), Vec::new()],
            blobs_now: Default::default(),
            acquisition: acquisition::Search::default(),
            params,
            templates: Vec::new(),
            normals: Vec::new(),
        })
    }

    /// The settings.
    pub fn params(&self) -> &LabelParams {
        &self.params
    }

    /// The current epipolar gate (largest RMS reprojection error of a labeled marker),
    /// pixels, and the measured robust scale of the residuals it comes from (None until
    /// enough markers were labeled).
    pub fn epipolar_gate(&self) -> (f64, Option<f64>) {
        (self.gate.gate_px(), self.gate.sigma_px())
    }

    /// The head pose (head → cam0) of the last labeled frame; None while acquiring.
    pub fn head_pose(&self) -> Option<Isometry3<f64>> {
        self.pose
    }

    /// Expressions the face may hold when acquisition starts (a take cut mid-performance,
    /// a chunk of a long take, tracking lost on a wide-open jaw): each the layout's
    /// markers' positions (head frame, mm, layout order) on one shape of the actor's
    /// dataset. Acquisition labels under the neutral and under each of these, and keeps
    /// the expression whose predictions the detections fit best (see `acquire`). Templates
    /// of another marker count or with non-finite positions are left out (their number is
    /// returned).
    pub fn set_expression_templates(&mut self, templates: Vec<Vec<Point3<f64>>>) -> usize {
        let m = self.neutral.len();
        let before = templates.len();
        self.templates = templates
            .into_iter()
            .filter(|t| t.len() == m && t.iter().all(|p| p.coords.iter().all(|v| v.is_finite())))
            .collect();
        before - self.templates.len()
    }

    /// The skin's normal at each marker on the neutral face (head frame, layout order;
    /// [`MarkerLayout::neutral_normals`]): with it, a blob much thinner than the marker's
    /// dot can look from the camera is not the marker's (see
    /// [`LabelParams::min_roundness_ratio`]). A zero vector: that marker's normal is not
    /// known (no check for it). Returns false, and keeps none, when the count is not the
    /// layout's or a normal is neither of unit length nor zero.
    pub fn set_marker_normals(&mut self, normals: Vec<Vector3<f64>>) -> bool {
        let fits = normals.len() == self.neutral.len()
            && normals.iter().all(|n| {
                n.iter().all(|v| v.is_finite())
                    && ((n.norm() - 1.0).abs() < 1e-6 || n.norm() == 0.0)
            });
        self.normals = if fits { normals } else { Vec::new() };
        fits
    }

    /// Forget all tracks (next frame re-acquires by registration).
    pub fn reset(&mut self) {
        self.tracks = fresh_tracks(&self.neutral);
        self.pose = None;
        self.prev_pose = None;
        self.last_frame = None;
        self.lost_count = 0;
        self.rois = [None, None];
        self.windows = [Vec::new(), Vec::new()];
        self.centres = [Vec::new(), Vec::new()];
        self.seen_before = None;
        self.beside.iter_mut().for_each(|b| *b = Default::default());
        self.lobes.iter_mut().for_each(|l| *l = [None; 2]);
        self.light = [1.0; 2];
        self.light_measured = false;
    }

    /// Regions of interest (x0, y0, x1, y1, end exclusive) per camera around where markers
    /// are expected next frame, None while acquiring. (For the detector's
    /// `DetectParams::roi`.)
    pub fn predicted_rois(&self) -> [Option<(u32, u32, u32, u32)>; 2] {
        self.rois
    }

    /// Search windows `(x0, y0, x1, y1)` (end exclusive) per camera around each marker's
    /// predicted pixel next frame, for the detector's
    /// [`MarkerDetector::detect_in_windows`](crate::track::MarkerDetector::detect_in_windows):
    /// each holds the marker's gate (that of the final labeling pass), grown by half the
    /// largest blob the final pass accepts for it there (its dot through the lens at the
    /// top of [`LabelParams::dot_size_ratio`], or of
    /// [`LabelParams::first_sighting_size_ratio`] for a marker not labeled this frame) and
    /// [`LabelParams::window_margin_px`], so that any detection the final pass could accept
    /// for it is found whole. The first pass, which only estimates the head pose, sees what
    /// the windows hold: its extra gate
    /// ([`LabelParams::pose_pass_extra_gate_px`]) would make the windows half again as
    /// large (39 % of the image instead of 27 % on the `cluttered` preset, 26 % more
    /// detection time) for 0.2 points of labeled markers there and none elsewhere; a pose
    /// off by more than the windows allow shows as a drop in labeled markers, and the next
    /// frame searches the whole region of interest. Empty while acquiring, when
    /// [`LabelParams::search_windows`] is off, and after a frame that labeled under
    /// [`WINDOWS_KEEP_SHARE`] of the markers of the frame before (then search
    /// [`Labeler::predicted_rois`]).
    pub fn predicted_windows(&self) -> [&[Rect]; 2] {
        [&self.windows[0], &self.windows[1]]
    }

    /// Per camera, the boxes in which a detection's centre can be a candidate of a marker
    /// in either labeling pass next frame, while [`Labeler::predicted_windows`] are
    /// given: around each marker's predicted pixel, its gate in the pose pass (the final
    /// pass's gate and [`LabelParams::pose_pass_extra_gate_px`], which also holds the
    /// final pass's gate around a prediction the pose pass moved by up to that much).
    /// Detections elsewhere in the windows are no marker's candidates: the detector need
    /// not measure them
    /// ([`MarkerDetector::detect_in_windows_near`](crate::track::MarkerDetector::detect_in_windows_near)).
    pub fn predicted_centres(&self) -> [&[Rect]; 2] {
        [&self.centres[0], &self.centres[1]]
    }

    /// Labels one stereo frame's detections (cam0, cam1). Never panics on any input.
    pub fn process(&mut self, frame: FrameIndex, detections: [&[Detection]; 2]) -> LabeledFrame {
        let m = self.neutral.len();
        let mut stats = LabelStats {
            detections: [detections[0].len(), detections[1].len()],
            ..LabelStats::default()
        };
        self.blobs = [0, 1].map(|c| detections[c].iter().map(BlobShape::of).collect());
        // Where this frame's detector reported blobs (it looked where the last frame said).
        let looked = self.centres.clone();
        // Detections with non-finite centres are never used.
        let pixels: [Vec<Option<Point2<f64>>>; 2] = [0, 1].map(|c| {
            detections[c]
                .iter()
                .map(|d| {
                    let p = d.centre_px;
                    (p.x.is_finite() && p.y.is_finite()).then_some(p)
                })
                .collect()
        });
        self.blobs_now = surroundings::FrameBlobs::new(&pixels);
        let steps = match self.last_frame {
            Some(last)
                if frame > last
                    && frame
                        .since(last)
                        .is_some_and(|n| n <= self.params.max_frame_gap as u64) =>
            {
                frame.since(last).map_or(1, |n| n as usize)
            }
            Some(_) => {
                tracing::debug!(
                    frame = frame.get(),
                    "frame gap or out of order: re-acquiring"
                );
                self.reset();
                1
            }
            None => 1,
        };
        let mut result = None;
        if self.pose.is_some() {
            result = self.track(&pixels, steps);
        }
        if result.is_none() {
            // Acquisition (also right after tracking was lost).
            self.reset();
            stats.acquiring = true;
            result = self.acquire(&pixels, &mut stats);
        }
        let mut out = vec![None; m];
        let Some((pose, mut pass)) = result else {
            self.last_frame = None;
            self.seen_before = None;
            return LabeledFrame {
                markers: out,
                stats,
            };
        };
        if !stats.acquiring {
            pass.rejected += self.confirm_new_tracks(&mut pass.labels);
        }
        stats.paired = stats.paired.max(pass.paired);
        stats.rejected += pass.rejected;
        // The epipolar gate follows the detector's centroids of whole dots: not a dot's
        // lobe, estimated from a merged blob's shape, nor a worn dot's smear (whose pair
        // has a gate of its own, wider).
        self.gate.update(
            pass.labels
                .iter()
                .filter(|l| l.confident && l.at.is_none() && !l.worn)
                .map(|l| l.bundle.reprojection_px),
        );
        let mut seen = vec![false; m];
        let mut small = vec![false; m];
        for l in &pass.labels {
            small[l.marker] = self.smaller_than_a_whole_dot(&l.bundle.point_in_cam0, l.det);
        }
        let size = self.whole_dot_sizes(&pass.labels, &small);
        let inverse = pose.inverse();
        for l in &pass.labels {
            let contrast = [0, 1].map(|c| {
                self.blobs[c]
                    .get(l.det[c])
                    .map(|b| b.contrast_dn / self.light[c])
            });
            let lobe_blob_px = l.at.and_then(|_| self.blob_lengths(l.det));
            let track = &mut self.tracks[l.marker];
            let reacquired = matches!(track.frames_since_seen, Some(n) if n > 0);
            let head = inverse * l.bundle.point_in_cam0;
            track.velocity = if track.frames_since_seen == Some(0) {
                (head - track.head) / steps as f64
            } else {
                Vector3::zeros()
            };
            track.head = head;
            track.worn = l.worn;
            track.lobe_px = l.at.map_or(0.0, |at| {
                (0..2)
                    .filter_map(|c| pixels[c][l.det[c]].map(|x| (x - at[c]).norm()))
                    .fold(0.0, f64::max)
            });
            track.lobe_blob_px = lobe_blob_px;
            if size[l.marker].is_some() {
                track.size_over_expected = size[l.marker];
            }
            if !l.worn
                && l.at.is_none()
                && let [Some(c0), Some(c1)] = contrast
            {
                track.contrast_dn = Some([c0, c1]);
            }
            track.small_blob_frames = if small[l.marker] {
                track.small_blob_frames + 1
            } else {
                0
            };
            seen[l.marker] = true;
            stats.labeled += 1;
            stats.reacquired += usize::from(reacquired);
            let px = |c: usize| {
                l.at.map(|at| at[c])
                    .or(pixels[c][l.det[c]])
                    .unwrap_or_else(Point2::origin)
            };
            out[l.marker] = Some(LabeledMarker {
                bundle: l.bundle,
                pixels: [px(0), px(1)],
                detections: l.det,
                reacquired,
            });
        }
        for (track, &s) in self.tracks.iter_mut().zip(&seen) {
            if !s {
                track.velocity = Vector3::zeros();
                track.frames_since_seen = track.frames_since_seen.map(|n| n + steps);
                track.run = 0;
            } else {
                track.run = if track.frames_since_seen == Some(0) && steps == 1 {
                    track.run + 1
                } else {
                    1
                };
                track.held |= stats.acquiring || track.run >= HELD_FRAMES;
                track.frames_since_seen = Some(0);
            }
        }
        // After the tracks: a far lobe is told from where this frame's labels put it.
        let reacquired: Vec<bool> = out
            .iter()
            .map(|m| m.as_ref().is_some_and(|m| m.reacquired))
            .collect();
        self.remember_beside(&pass.labels, &pixels, &pose, &reacquired);
        self.move_onto_lobes(&pass.labels, &pixels, &pose);
        if stats.labeled < self.params.lost_min_markers {
            self.lost_count += 1;
        } else {
            self.lost_count = 0;
        }
        if self.lost_count >= self.params.lost_frames {
            tracing::debug!(
                frame = frame.get(),
                "tracking lost: re-acquiring next frame"
            );
            self.reset();
        } else {
            self.prev_pose = if steps == 1 { self.pose } else { None };
            self.pose = Some(pose);
            self.last_frame = Some(frame);
            // Next frame's predictions with the final pass's gates (the ROI adds the pose
            // pass's extra).
            // Markers coming back after a gap are also looked for where they were last
            // seen (the tracking's third pass): their windows too.
            let preds = self.predicted_pose(1).map(|pose| {
                let mut preds = self.predictions(&pose, 1, 0.0);
                if self.any_returning() {
                    let alt =
                        self.predictions_from(&pose, 1, 0.0, tracking::Returning::WhereLastSeen);
                    for (i, a) in alt.iter().enumerate() {
                        if self.worth_looking_where_last_seen(i, a, &preds[i]) {
                            preds.push(*a);
                        }
                    }
                }
                preds
            });
            let steady = stats.labeled as f64 >= WINDOWS_KEEP_SHARE * self.last_labeled as f64;
            self.rois = preds
                .as_ref()
                .map_or([None, None], |preds| self.compute_rois(preds));
            [self.windows, self.centres] = match preds {
                Some(preds) if self.params.search_windows && steady => self.compute_windows(&preds),
                _ => Default::default(),
            };
        }
        self.last_labeled = stats.labeled;
        self.seen_before = self.last_frame.map(|_| SeenBefore {
            pixels: pixels.map(|p| p.into_iter().flatten().collect()),
            looked,
            markers: out.iter().map(|l| l.as_ref().map(|l| l.pixels)).collect(),
            marker_blobs_px: out
                .iter()
                .map(|l| {
                    l.as_ref().map(|l| {
                        [0, 1].map(|c| {
                            self.blobs[c]
                                .get(l.detections[c])
                                .map_or(f64::NAN, |b| b.diameter_px)
                        })
                    })
                })
                .collect(),
        });
        LabeledFrame {
            markers: out,
            stats,
        }
    }

    /// Drops the labels of markers never labeled since the acquisition until they have
    /// been found in [`CONFIRM_FRAMES`] frames in a row, and returns how many it dropped.
    /// A marker the acquisition did not find (out of view, hidden, or wiped off before the
    /// take) is looked for where its neighbours put it, with nothing else to go by: a mole
    /// of a dot's size there may pass every check now and then (wiped-moles seed 5's M110
    /// in a single frame; seed 7's M107 in runs of one to eight), a dot that comes into
    /// view frame after frame. A new track is confirmed before it is reported, as trackers
    /// confirm tracks by M of N detections. A marker back after a gap is confirmed alike
    /// until its track has held ([`Track::held`]: labeled by the acquisition, or in
    /// [`HELD_FRAMES`] frames in a row): a mole where a marker seen edge-on all take long
    /// is (lip-press seed 1501's M040, seen 83° from its normal, 1.6 px wide, with a mole
    /// as foreshortened as the dot 3-5 px from its place), confirmed once, came back in
    /// single frames 13 times. A marker whose track held keeps no such delay, nor do the
    /// acquisition's labels.
    fn confirm_new_tracks(&mut self, labels: &mut Vec<Label>) -> usize {
        let mut found = vec![false; self.tracks.len()];
        for l in labels.iter() {
            found[l.marker] = true;
        }
        let unconfirmed = |t: &Track| {
            t.frames_since_seen.is_none() || (t.frames_since_seen != Some(0) && !t.held)
        };
        for (track, &f) in self.tracks.iter_mut().zip(&found) {
            track.confirming = if !unconfirmed(track) {
                0
            } else if f {
                track.confirming + 1
            } else {
                0
            };
        }
        let before = labels.len();
        labels.retain(|l| {
            let t = &self.tracks[l.marker];
            !unconfirmed(t) || t.confirming >= CONFIRM_FRAMES
        });
        before - labels.len()
    }

    /// One search window per marker and camera around its predicted pixel next frame (see
    /// [`Labeler::predicted_windows`]), from the predictions with the final pass's gates,
    /// and the boxes of [`Labeler::predicted_centres`] in them.
    fn compute_windows(&self, preds: &[Prediction]) -> [[Vec<Rect>; 2]; 2] {
        let p = &self.params;
        let mut out: [[Vec<Rect>; 2]; 2] = Default::default();
        let [windows, centres] = &mut out;
        for (c, (windows, centres)) in windows.iter_mut().zip(centres.iter_mut()).enumerate() {
            let cam = if c == 0 {
                &self.rig.cam0
            } else {
                &self.rig.cam1
            };
            let (w, h) = (f64::from(cam.width_px), f64::from(cam.height_px));
            for pr in preds {
                let Some(q) = pr.pixels[c] else { continue };
                // The largest blob the final pass accepts for the marker.
                let hi = if pr.first_sighting {
                    p.first_sighting_size_ratio.1
                } else {
                    p.dot_size_ratio.1
                };
                let Some(largest_dot) = self.largest_dot_px(&pr.point, c, hi) else {
                    continue;
                };
                let mut g = pr.gate_px + 0.5 * (largest_dot + pr.motion_px[c]);
                let mut r = pr.gate_px + p.pose_pass_extra_gate_px;
                // A worn dot: its centre within the tolerance of where the neighbours put
                // the marker, its length up to the top of its size range.
                if let Some((point, Some(at))) = pr.vouched.map(|(point, px)| (point, px[c]))
                    && pr.may_be_worn
                {
                    let off = (at - q).norm();
                    if let (Some(worn), Some(tolerance)) = (
                        self.largest_dot_px(&point, c, p.worn_dot_size_ratio.1),
                        self.worn_dot_tolerance_px(&point, c),
                    ) {
                        g = g.max(off + tolerance + 0.5 * (worn + pr.motion_px[c]));
                        r = r.max(off + tolerance);
                    }
                }
                let g = g + p.window_margin_px;
                let Some(window) = pixel_rect((q.x - g, q.y - g, q.x + g, q.y + g), w, h) else {
                    continue;
                };
                let centre = pixel_rect((q.x - r, q.y - r, q.x + r, q.y + r), w, h)
                    .unwrap_or((window.0, window.1, window.0, window.1));
                windows.push(window);
                centres.push(centre);
            }
        }
        out
    }

    /// Bounding boxes of the next frame's predicted marker pixels, grown by the pose pass's
    /// gate and the margin (`preds` with the final pass's gates).
    fn compute_rois(&self, preds: &[Prediction]) -> [Option<(u32, u32, u32, u32)>; 2] {
        let grow = self.params.pose_pass_extra_gate_px + self.params.roi_margin_px;
        [0, 1].map(|c| {
            let cam = if c == 0 {
                &self.rig.cam0
            } else {
                &self.rig.cam1
            };
            let mut bb: Option<(f64, f64, f64, f64)> = None;
            for pr in preds {
                let Some(q) = pr.pixels[c] else { continue };
                let g = pr.gate_px + grow;
                let b = (q.x - g, q.y - g, q.x + g, q.y + g);
                bb = Some(match bb {
                    None => b,
                    Some(a) => (a.0.min(b.0), a.1.min(b.1), a.2.max(b.2), a.3.max(b.3)),
                });
            }
            pixel_rect(bb?, f64::from(cam.width_px), f64::from(cam.height_px))
        })
    }
}

/// The whole pixels `(x0, y0, x1, y1)` (end exclusive) covering the box `b`, clipped to a
/// `w × h` image; None when nothing is left.
fn pixel_rect(b: (f64, f64, f64, f64), w: f64, h: f64) -> Option<Rect> {
    let x0 = b.0.floor().clamp(0.0, w) as u32;
    let y0 = b.1.floor().clamp(0.0, h) as u32;
    let x1 = (b.2.ceil() + 1.0).clamp(0.0, w) as u32;
    let y1 = (b.3.ceil() + 1.0).clamp(0.0, h) as u32;
    (x0 < x1 && y0 < y1).then_some((x0, y0, x1, y1))
}

fn fresh_tracks(neutral: &[Point3<f64>]) -> Vec<Track> {
    neutral
        .iter()
        .map(|q| Track {
            head: *q,
            velocity: Vector3::zeros(),
            frames_since_seen: None,
            worn: false,
            lobe_px: 0.0,
            lobe_blob_px: None,
            confirming: 0,
            run: 0,
            held: false,
            small_blob_frames: 0,
            size_over_expected: None,
            contrast_dn: None,
        })
        .collect()
}

#[cfg(test)]
mod tests;
