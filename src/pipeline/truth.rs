//! Ground truth of a synthetic session (`gt/` of `helmcap synth`), for accuracy figures:
//! the true marker positions in the head frame per frame (`gt/bundles.csv`) and, when the
//! session was rendered with `--meshes`, the true surface (`gt/mesh/frame_NNNNNN.obj`).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::Point3;

use crate::bundles::{BundlesError, read_bundles};
use crate::dataset::MarkerLayout;
use crate::frame_index::FrameIndex;
use crate::mesh::read_obj_positions;

/// Ground truth of one session.
#[derive(Debug, Clone)]
pub struct GroundTruth {
    bundles: HashMap<FrameIndex, Vec<Option<Point3<f64>>>>,
    mesh_dir: Option<PathBuf>,
}

impl GroundTruth {
    /// Loads `session/gt/` for `layout`; None when the session has no `gt/bundles.csv`.
    ///
    /// # Errors
    /// [`BundlesError`] when the file exists but cannot be read.
    pub fn load(session: &Path, layout: &MarkerLayout) -> Result<Option<Self>, BundlesError> {
        let path = session.join("gt").join("bundles.csv");
        if !path.is_file() {
            return Ok(None);
        }
        let (frames, _) = read_bundles(&path, layout)?;
        let bundles = frames.into_iter().map(|f| (f.frame, f.positions)).collect();
        let mesh_dir = session.join("gt").join("mesh");
        Ok(Some(Self {
            bundles,
            mesh_dir: mesh_dir.is_dir().then_some(mesh_dir),
        }))
    }

    /// Ground truth from memory (tests, wrappers that renumber frames).
    pub fn from_bundles(bundles: HashMap<FrameIndex, Vec<Option<Point3<f64>>>>) -> Self {
        Self {
            bundles,
            mesh_dir: None,
        }
    }

    /// Whether true meshes are available.
    pub fn has_meshes(&self) -> bool {
        self.mesh_dir.is_some()
    }

    /// RMS distance (mm) between `bundles_in_head` (per layout marker, None: not
    /// observed) and the truth of `frame`; None when the frame has no truth or no bundle
    /// to compare.
    pub fn bundle_rms_mm(
        &self,
        frame: FrameIndex,
        bundles_in_head: &[Option<Point3<f64>>],
    ) -> Option<f64> {
        let truth = self.bundles.get(&frame)?;
        let (mut sum, mut n) = (0.0, 0usize);
        for (b, t) in bundles_in_head.iter().zip(truth) {
            if let (Some(b), Some(t)) = (b, t) {
                sum += (b - t).norm_squared();
                n += 1;
            }
        }
        (n > 0).then(|| (sum / n as f64).sqrt())
    }

    /// Per-vertex distance (mm) between `mesh` and the true mesh of `frame`; None when
    /// there is no true mesh for the frame or its vertex count differs (logged).
    pub fn mesh_error_mm(&self, frame: FrameIndex, mesh: &[Point3<f64>]) -> Option<Vec<f32>> {
        let path = self
            .mesh_dir
            .as_ref()?
            .join(format!("frame_{frame:06}.obj"));
        if !path.is_file() {
            return None;
        }
        match read_obj_positions(&path) {
            Ok(truth) if truth.len() == mesh.len() => Some(
                mesh.iter()
                    .zip(&truth)
                    .map(|(a, b)| (a - b).norm() as f32)
                    .collect(),
            ),
            Ok(truth) => {
                tracing::warn!(
                    "{}: {} vertices, the solved mesh has {}; not compared",
                    path.display(),
                    truth.len(),
                    mesh.len()
                );
                None
            }
            Err(e) => {
                tracing::warn!("ground truth {}: {e}", path.display());
                None
            }
        }
    }
}
