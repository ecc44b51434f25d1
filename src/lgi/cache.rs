//! The on-disk cache of [`LgiIndex`]: built once per dataset, layout and index parameters,
//! then reloaded by `helmcap solve` (and built explicitly by `helmcap dataset build
//! --markers`).
//!
//! # Format
//! bincode of the index's stored part (see [`LgiIndex`]: what is cheap to recompute is
//! rebuilt on load, bit for bit), in `DIR/lgi-KEY.bin`, where `KEY` hashes the format
//! version, every position of the dataset, its shape names and jaw data, the marker
//! vertices and the parameters that shape the index. Any change gives another file; an
//! unreadable file is ignored with a warning and rebuilt.

use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::{LgiError, LgiIndex, LgiParams};
use crate::dataset::{Dataset, MarkerLayout};

/// Where an index came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IndexSource {
    /// Read from the cache file.
    Cache,
    /// Built now (and written to the cache when one was given).
    Built,
}

/// The cache file of the index of `dataset` for `layout` and `params` inside `dir`.
pub fn cache_path(
    dir: &Path,
    dataset: &Dataset,
    layout: &MarkerLayout,
    params: &LgiParams,
) -> PathBuf {
    dir.join(format!(
        "lgi-{:016x}.bin",
        index_key(dataset, layout, params)
    ))
}

/// The index from `cache_dir` when it holds one built from the same inputs, else built
/// (and written there; a write failure is logged and otherwise ignored). `None` neither
/// reads nor writes a cache.
///
/// # Errors
/// As [`LgiIndex::build`].
pub fn load_or_build(
    dataset: &Dataset,
    layout: &MarkerLayout,
    params: &LgiParams,
    cache_dir: Option<&Path>,
) -> Result<(Arc<LgiIndex>, IndexSource), LgiError> {
    let path = cache_dir.map(|d| cache_path(d, dataset, layout, params));
    if let Some(path) = &path
        && path.exists()
    {
        match read_index(path) {
            Ok(index) => {
                tracing::info!("LGI index from cache {}", path.display());
                return Ok((Arc::new(index), IndexSource::Cache));
            }
            Err(e) => tracing::warn!(
                "ignoring unreadable LGI index cache {}: {e}",
                path.display()
            ),
        }
    }
    let index = LgiIndex::build(dataset, layout, params)?;
    if let Some(path) = &path
        && let Err(e) = write_index(path, &index)
    {
        tracing::warn!("could not write LGI index cache {}: {e}", path.display());
    }
    Ok((Arc::new(index), IndexSource::Built))
}

/// Writes `index` to `path` atomically (creating the folder).
///
/// # Errors
/// I/O and encoding errors.
pub fn write_index(path: &Path, index: &LgiIndex) -> std::io::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    crate::atomic_file::write_atomically(path, |w| {
        bincode::serialize_into(w, index).map_err(std::io::Error::other)
    })
}

/// Reads an index written by [`write_index`], recomputing its derived data.
///
/// # Errors
/// I/O and decoding errors.
pub fn read_index(path: &Path) -> std::io::Result<LgiIndex> {
    let bytes = std::fs::read(path)?;
    bincode::deserialize::<LgiIndex>(&bytes).map_err(std::io::Error::other)
}

/// Key of an index: everything it is built from (dataset positions and jaw, marker
/// vertices, the parameters that shape the index), and the format version.
pub fn index_key(dataset: &Dataset, layout: &MarkerLayout, params: &LgiParams) -> u64 {
    let mut h = std::collections::hash_map::DefaultHasher::new();
    "lgi-index-v2".hash(&mut h);
    dataset.vertex_count().hash(&mut h);
    for p in dataset
        .neutral
        .positions
        .iter()
        .chain(dataset.shapes.iter().flat_map(|s| s.positions.iter()))
    {
        p.x.to_bits().hash(&mut h);
        p.y.to_bits().hash(&mut h);
        p.z.to_bits().hash(&mut h);
    }
    for s in &dataset.shapes {
        s.name.hash(&mut h);
        format!("{:?}", s.jaw).hash(&mut h);
    }
    format!(
        "{:?}",
        dataset
            .jaw
            .as_ref()
            .map(|j| (&j.pivot, &j.open_axis, &j.weights))
    )
    .hash(&mut h);
    dataset.face_vertices.hash(&mut h);
    dataset.neutral.uvs.len().hash(&mut h);
    for m in &layout.markers {
        m.vertex.hash(&mut h);
    }
    // Only the build parameters matter; the per-frame ones are neutralized.
    format!("{:?}", params.index_params()).hash(&mut h);
    h.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bundles::FrameBundles;
    use crate::dataset::markers::{LayoutParams, generate_layout};
    use crate::lgi::LgiSolver;

    /// A cached index solves exactly like the one it was written from.
    #[test]
    fn cached_index_solves_bit_for_bit() {
        let a = crate::dataset::actor::Actor::new(&Default::default()).unwrap();
        let ds = a.to_dataset();
        let layout = generate_layout(&ds, &LayoutParams::default()).unwrap();
        let params = LgiParams::default();
        let dir = tempfile::tempdir().unwrap();
        let (built, src) = load_or_build(&ds, &layout, &params, Some(dir.path())).unwrap();
        assert_eq!(src, IndexSource::Built);
        let (read, src) = load_or_build(&ds, &layout, &params, Some(dir.path())).unwrap();
        assert_eq!(src, IndexSource::Cache);
        // Per-frame settings share the index; the noisy preset's merging builds another.
        let per_frame = LgiParams {
            temporal_weight_mm: 0.2,
            bundle_tolerance_mm: 0.3,
            snap_to_bundles: false,
            ..params
        };
        let (_, src) = load_or_build(&ds, &layout, &per_frame, Some(dir.path())).unwrap();
        assert_eq!(src, IndexSource::Cache);
        let (noisy, src) =
            load_or_build(&ds, &layout, &LgiParams::noisy(), Some(dir.path())).unwrap();
        assert_eq!(src, IndexSource::Built);
        assert!(noisy.stats.points < built.stats.points);
        for (m, r) in built.markers.iter().zip(&read.markers) {
            assert_eq!(m.patch, r.patch);
            assert_eq!(m.blend, r.blend);
            assert_eq!(m.faces, r.faces);
            assert_eq!(m.inv_volume, r.inv_volume);
            assert_eq!(m.neighbor_positions, r.neighbor_positions);
            assert_eq!(m.hull_tets, r.hull_tets);
            assert_eq!(m.grid, r.grid);
        }
        let mut w = vec![0.0; a.expression_names().len()];
        w[1] = 0.7;
        w[5] = 0.4;
        let truth = a.evaluate(&w).positions;
        let mut frame = FrameBundles::full(
            crate::frame_index::FrameIndex::new(0),
            &layout
                .markers
                .iter()
                .map(|m| truth[m.vertex as usize])
                .collect::<Vec<_>>(),
        );
        frame.positions[3] = None;
        let mut s1 = LgiSolver::from_index(built, &params).unwrap();
        let mut s2 = LgiSolver::from_index(read, &params).unwrap();
        assert_eq!(s1.solve(&frame).unwrap(), s2.solve(&frame).unwrap());
    }
}
