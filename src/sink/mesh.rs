//! Mesh sequence export: one OBJ or PLY per frame (`mesh/frame_NNNNNN.obj`, the neutral's
//! topology and UVs, mm, head frame), each written atomically as its frame arrives.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::mesh::{Mesh, write_obj_positions, write_ply};
use crate::pipeline::{FrameResult, Metrics, SessionMeta, Sink, SinkError};

/// File format of [`MeshSequenceSink`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ (text, with UVs).
    Obj,
    /// Binary little-endian PLY (UVs as per-face texcoords).
    Ply,
}

/// Writes one mesh file per solved frame into a folder.
#[derive(Debug)]
pub struct MeshSequenceSink {
    dir: PathBuf,
    format: MeshFormat,
    neutral: Option<Arc<Mesh>>,
    written: usize,
}

impl MeshSequenceSink {
    /// A sink writing `dir/frame_NNNNNN.<ext>`.
    pub fn new(dir: &Path, format: MeshFormat) -> Self {
        Self {
            dir: dir.to_path_buf(),
            format,
            neutral: None,
            written: 0,
        }
    }
}

impl Sink for MeshSequenceSink {
    fn name(&self) -> &str {
        match self.format {
            MeshFormat::Obj => "obj",
            MeshFormat::Ply => "ply",
        }
    }

    fn begin(&mut self, session: &SessionMeta) -> Result<(), SinkError> {
        let neutral = session.neutral.clone().ok_or_else(|| {
            SinkError::Other("mesh export needs a dataset to solve meshes with".into())
        })?;
        std::fs::create_dir_all(&self.dir).map_err(|e| SinkError::io(&self.dir, e))?;
        self.neutral = Some(neutral);
        Ok(())
    }

    fn write(&mut self, f: &FrameResult) -> Result<(), SinkError> {
        let (Some(mesh), Some(neutral)) = (&f.mesh, &self.neutral) else {
            return Ok(());
        };
        let result = match self.format {
            MeshFormat::Obj => write_obj_positions(
                &self.dir.join(format!("frame_{:06}.obj", f.index)),
                neutral,
                mesh,
            ),
            MeshFormat::Ply => write_ply(
                &self.dir.join(format!("frame_{:06}.ply", f.index)),
                neutral,
                Some(mesh),
            ),
        };
        result.map_err(|e| SinkError::Other(e.to_string()))?;
        self.written += 1;
        Ok(())
    }

    fn finish(&mut self, _metrics: &Metrics) -> Result<(), SinkError> {
        tracing::debug!("{} meshes written to {}", self.written, self.dir.display());
        Ok(())
    }
}
