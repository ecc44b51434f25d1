//! One stereo frame at a time: detection in both cameras (in parallel) where the labeler
//! expects its markers, then labeling.

use super::{DetectParams, Detection, LabeledFrame, Labeler, MarkerDetector};
use crate::capture::GrayImage;
use crate::frame_index::FrameIndex;

/// Detection and labeling of a stereo stream: the entry type of the track stage.
///
/// Each camera's detector looks where the labeler expects markers next: in one window
/// around each predicted marker while tracking ([`Labeler::predicted_windows`]), in the
/// predicted region of interest after an unsteady frame ([`Labeler::predicted_rois`]),
/// and in the whole image (or [`DetectParams::roi`]) while acquiring. In the windows, only
/// the blobs that can be a marker's candidates are measured
/// ([`Labeler::predicted_centres`]): a window's other detections are not reported.
#[derive(Debug, Clone)]
pub struct StereoTracker {
    labeler: Labeler,
    detectors: [MarkerDetector; 2],
    detect: DetectParams,
}

/// The result of [`StereoTracker::track`].
#[derive(Debug, Clone)]
pub struct TrackedFrame {
    /// The labels, per layout marker.
    pub labeled: LabeledFrame,
    /// The detections of each camera.
    pub detections: [Vec<Detection>; 2],
}

impl StereoTracker {
    /// A tracker that labels with `labeler` what the detector finds with `detect`.
    pub fn new(labeler: Labeler, detect: DetectParams) -> Self {
        Self {
            labeler,
            detectors: [MarkerDetector::new(), MarkerDetector::new()],
            detect,
        }
    }

    /// The labeler.
    pub fn labeler(&self) -> &Labeler {
        &self.labeler
    }

    /// Starts labeling again from `labeler` (a fresh one: tracking restarts from nothing).
    pub fn restart(&mut self, labeler: Labeler) {
        self.labeler = labeler;
    }

    /// Detects and labels frame `index` of the stream (cam0, cam1).
    pub fn track(&mut self, index: FrameIndex, images: &[GrayImage; 2]) -> TrackedFrame {
        let rois = self.labeler.predicted_rois();
        let windows = self.labeler.predicted_windows();
        let centres = self.labeler.predicted_centres();
        let detect = &self.detect;
        let [det0, det1] = &mut self.detectors;
        let find = |det: &mut MarkerDetector, c: usize| {
            if windows[c].is_empty() {
                let params = DetectParams {
                    roi: rois[c].or(detect.roi),
                    ..detect.clone()
                };
                det.detect(&images[c], &params)
            } else {
                det.detect_in_windows_near(&images[c], detect, windows[c], centres[c])
            }
        };
        let (d0, d1) = rayon::join(|| find(det0, 0), || find(det1, 1));
        let labeled = self.labeler.process(index, [&d0, &d1]);
        TrackedFrame {
            labeled,
            detections: [d0, d1],
        }
    }
}
