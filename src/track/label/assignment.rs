//! Optimal assignment of markers to detections in one camera: the Hungarian method on
//! each connected component of the gated candidate graph, on squared pixel distances.

use crate::stereo::assign_sparse;

/// Optimal assignment of markers to detections: `candidates[marker]` lists the detections
/// within its gate with their distances (pixels); the cost is the squared distance.
/// Returns (marker, detection) pairs.
pub(super) fn assign_components(
    candidates: &[Vec<(usize, f64)>],
    dets: usize,
) -> Vec<(usize, usize)> {
    let squared: Vec<Vec<(usize, f64)>> = candidates
        .iter()
        .map(|c| c.iter().map(|&(a, e)| (a, e * e)).collect())
        .collect();
    assign_sparse(&squared, dets)
}
