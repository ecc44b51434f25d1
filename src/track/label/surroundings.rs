//! A marker's surroundings: the blobs that stood beside its dot at its last label
//! ([`Labeler::stood_beside`]'s memory), looked for again around a candidate, with the
//! candidate taken as the dot and as each of those blobs in turn.
//!
//! A mole that stood 20 px below a lip dot is still 20 px below it when the lip has carried
//! both elsewhere, and a freckle beside them is still beside them: the skin around a dot
//! moves with it. Where the dot is, the blobs that stood beside it stand beside it again;
//! where the mole is, the dot stands at the mole's remembered offset back from it, and the
//! rest of what stood beside the dot stands beside that place. Counting which of the two
//! layouts the frame's blobs fill tells the dot from a blob beside it wherever the two now
//! are, where the offsets from a prediction ([`Labeler::stood_beside`]) cannot: the
//! prediction of a marker coming back after a gap may be off by as much as the mole is.
//!
//! Only blobs found count, never places where none was: the detector reports blobs only
//! around the markers' predictions while tracking, so a blob not found where it would be
//! is no evidence (see `SeenBefore::nothing_near` for the other way to ask).

use nalgebra::{Point2, Vector2};

use super::Labeler;

/// A frame's blob centres per camera, by column: whether a blob lies near a place.
#[derive(Debug, Clone, Default)]
pub(super) struct FrameBlobs {
    /// Per camera, the finite detection centres sorted by `x`.
    by_column: [Vec<Point2<f64>>; 2],
}

impl FrameBlobs {
    /// The blobs of a frame's detections (`None`: a detection not used).
    pub(super) fn new(pixels: &[Vec<Option<Point2<f64>>>; 2]) -> Self {
        Self {
            by_column: [0, 1].map(|c| {
                let mut v: Vec<Point2<f64>> = pixels[c].iter().flatten().copied().collect();
                v.sort_by(|a, b| a.x.total_cmp(&b.x));
                v
            }),
        }
    }

    /// Whether camera `c` has a blob within `tolerance_px` of `at`.
    pub(super) fn any_near(&self, c: usize, at: Point2<f64>, tolerance_px: f64) -> bool {
        let v = &self.by_column[c];
        let first = v.partition_point(|p| p.x < at.x - tolerance_px);
        v[first..]
            .iter()
            .take_while(|p| p.x <= at.x + tolerance_px)
            .any(|p| (p - at).norm() <= tolerance_px)
    }
}

/// How a candidate's surroundings in one camera fit it as marker `i`'s dot and as a blob
/// that stood beside the dot (see the module docs): counts of the remembered blobs found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct SurroundingsFit {
    /// With the candidate as the dot: the remembered blobs found at their offsets from it.
    pub(super) as_dot: usize,
    /// With the candidate as the remembered blob that fits best: the dot found at that
    /// blob's offset back from it (one), and the other remembered blobs found at their
    /// offsets from there. Zero with nothing remembered.
    pub(super) as_beside: usize,
    /// As `as_beside`, over the remembered blobs whose dot's place holds a blob.
    pub(super) as_beside_of_a_blob: usize,
}

impl Labeler {
    /// How far a blob may lie from a remembered offset `b` and still be the blob that
    /// stood there, pixels: `min(g/2 + |b|/10, |b|/2)` (`g` the tight gate; the tenth for
    /// the skin's stretch and the head's turn since, the half so that the place is nearer
    /// to the remembered blob's than to the dot's). See [`Labeler::stood_beside`].
    pub(super) fn beside_tolerance_px(&self, b: &Vector2<f64>) -> f64 {
        let n = b.norm();
        (0.5 * self.params.gate_px + 0.1 * n).min(0.5 * n)
    }

    /// How the blobs of this frame around `x` in camera `c` fit it as marker `i`'s dot and
    /// as a blob that stood beside the dot at its last label (the module docs).
    pub(super) fn surroundings_fit(&self, i: usize, c: usize, x: Point2<f64>) -> SurroundingsFit {
        let Some(offsets) = self.beside.get(i).map(|b| &b[c]) else {
            return SurroundingsFit {
                as_dot: 0,
                as_beside: 0,
                as_beside_of_a_blob: 0,
            };
        };
        let now = &self.blobs_now;
        // The remembered blobs found around a dot at `dot`, but for the one at `skip`.
        let found_around = |dot: Point2<f64>, skip: Option<usize>| {
            offsets
                .iter()
                .enumerate()
                .filter(|&(j, b)| {
                    Some(j) != skip && now.any_near(c, dot + b, self.beside_tolerance_px(b))
                })
                .count()
        };
        let as_dot = found_around(x, None);
        let (mut as_beside, mut as_beside_of_a_blob) = (0, 0);
        for (k, b) in offsets.iter().enumerate() {
            let dot = x - b;
            let dot_found = now.any_near(c, dot, self.beside_tolerance_px(b));
            let fit = usize::from(dot_found) + found_around(dot, Some(k));
            as_beside = as_beside.max(fit);
            if dot_found {
                as_beside_of_a_blob = as_beside_of_a_blob.max(fit);
            }
        }
        SurroundingsFit {
            as_dot,
            as_beside,
            as_beside_of_a_blob,
        }
    }

    /// Whether the blobs at `x` (cam0, cam1), refused as a blob that stood beside marker
    /// `i`'s dot ([`Labeler::stood_beside`]), are its dot by their surroundings: in both
    /// cameras more of the blobs that stood beside the dot stand around them as around the
    /// dot than around any place they would put the dot as one of those blobs. A lip dot
    /// back from a 9-frame gap 17 px from where its neighbours put it, with the mole that
    /// stood 19 px below it still 19 px below it (lip-press seed 1501's M054), sits at the
    /// mole's offset from that prediction; a mole beside a wiped dot does not have the
    /// mole's offset and the dot's other neighbours around it.
    pub(super) fn dot_by_its_surroundings(&self, i: usize, x: [Option<Point2<f64>>; 2]) -> bool {
        (0..2).all(|c| {
            x[c].is_some_and(|x| {
                let fit = self.surroundings_fit(i, c, x);
                fit.as_dot > fit.as_beside
            })
        })
    }

    /// Whether the blobs at `x` (cam0, cam1), candidates of marker `i` coming back after
    /// a gap, are a blob that stood beside its dot, with the dot found at that blob's
    /// offset back from them: in both cameras the blobs that stood beside the dot fit that
    /// place as the dot better than they fit `x`. The mole that stood below a lip dot,
    /// carried with the lip to where the dot was last labeled, lies where the pass that
    /// looks there finds it (lip-press seed 1501's M054, taken on the mole for 55 frames);
    /// the dot stands at the mole's offset back from it, and the freckle that stood beside
    /// the dot beside that.
    pub(super) fn beside_its_dot_found(&self, i: usize, x: [Option<Point2<f64>>; 2]) -> bool {
        self.tracks[i].frames_since_seen.is_some_and(|n| n > 0)
            && (0..2).all(|c| {
                x[c].is_some_and(|x| {
                    let fit = self.surroundings_fit(i, c, x);
                    fit.as_beside_of_a_blob > fit.as_dot
                })
            })
    }
}
