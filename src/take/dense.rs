//! The dense stages of a take: the LGI solve (its parameters: the pipeline's noisy preset
//! or LGI's exact settings, overridden by a TOML file) and, optionally, detail
//! enhancement.

use std::path::PathBuf;
use std::sync::Arc;

use super::TakeError;
use crate::dataset::{Dataset, DatasetSpec, MarkerLayout};
use crate::enhance::Enhancer;
use crate::lgi::LgiParams;
use crate::pipeline::PipelineConfig;
use crate::solve::Solver;

/// Default of [`SolveSpec::keyframes`]: half a second at 60 fps.
pub const DEFAULT_SOLVE_KEYFRAMES: usize = 30;

/// Settings of the pipeline's dense solve.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SolveSpec {
    /// Force the mesh through every bundle (LGI's exact settings, as `helmcap solve` uses
    /// by default) instead of the pipeline's default for triangulated bundles (LGI's noisy
    /// preset). Default false.
    pub exact_bundles: bool,
    /// LGI parameters (TOML with the fields of [`LgiParams`]); fields it leaves out keep
    /// the default of `exact_bundles`. Default `None`.
    pub lgi_params: Option<PathBuf>,
    /// The solve forgets the previous frame's shape choices (LGI's temporal preference)
    /// on frame numbers that are multiples of this (0: never), so that a chunk of a take
    /// warmed up past such a frame solves exactly as one pass over the whole take does.
    /// Default [`DEFAULT_SOLVE_KEYFRAMES`].
    pub keyframes: usize,
}

impl Default for SolveSpec {
    fn default() -> Self {
        Self {
            exact_bundles: false,
            lgi_params: None,
            keyframes: DEFAULT_SOLVE_KEYFRAMES,
        }
    }
}

impl SolveSpec {
    /// The LGI parameters of the solve stage.
    ///
    /// The default is [`LgiParams::noisy`]: bundles triangulated from the helmet cameras
    /// carry a few tenths of a millimetre of noise, and forcing the surface through each
    /// one (LGI's exact setting, §5 of the paper) spreads that noise over the face. On the
    /// demo session (bundles 0.244 mm RMS against ground truth) the mesh error drops from
    /// 0.383 mm RMS (mean 0.239 mm) to 0.136 mm (mean 0.054 mm).
    ///
    /// # Errors
    /// An unreadable file, TOML that is not LGI parameters, or a value out of range.
    pub fn lgi_params(&self) -> Result<LgiParams, TakeError> {
        let base = if self.exact_bundles {
            LgiParams::default()
        } else {
            LgiParams::noisy()
        };
        let params = match &self.lgi_params {
            None => base,
            Some(path) => {
                let shown = || path.display().to_string();
                let text =
                    std::fs::read_to_string(path).map_err(|source| TakeError::LgiParamsRead {
                        path: shown(),
                        source,
                    })?;
                let file: toml::Table =
                    toml::from_str(&text).map_err(|source| TakeError::LgiParamsToml {
                        path: shown(),
                        source,
                    })?;
                let mut merged =
                    toml::Table::try_from(base).map_err(TakeError::LgiParamsDefaults)?;
                merged.extend(file);
                merged
                    .try_into::<LgiParams>()
                    .map_err(|source| TakeError::LgiParamsFields {
                        path: shown(),
                        source,
                    })?
            }
        };
        params.validate()?;
        Ok(params)
    }
}

/// The dense stages of a run: LGI and, optionally, detail enhancement.
pub struct DenseStages {
    solver: Solver,
    enhancer: Option<Arc<Enhancer>>,
    keyframes: usize,
}

impl DenseStages {
    /// Builds the stages: the LGI solver of `ds` for `layout` with the parameters of
    /// `solve` (its index from the cache folder of `cache`, if any) and, with `enhance`,
    /// the enhancer with the dataset `cache` names as its database (default cache).
    ///
    /// # Errors
    /// Bad LGI parameters, an index or enhancer that cannot be built.
    pub fn build(
        ds: &Dataset,
        layout: &MarkerLayout,
        cache: &DatasetSpec,
        enhance: bool,
        solve: &SolveSpec,
    ) -> Result<Self, TakeError> {
        let params = solve.lgi_params()?;
        let (index, _) =
            crate::lgi::cache::load_or_build(ds, layout, &params, cache.cache_folder().as_deref())?;
        let solver = Solver::lgi(index, &params)?;
        let enhancer = if enhance {
            let params = crate::enhance::read_params(None)?;
            let (_, enhancer) = crate::enhance::build_enhancer(&cache.name, &params, true)?;
            Some(Arc::new(enhancer))
        } else {
            None
        };
        Ok(Self {
            solver,
            enhancer,
            keyframes: solve.keyframes,
        })
    }

    /// Switches the stages on in `config` (with the dataset's neutral and face vertices).
    pub fn install(self, config: &mut PipelineConfig, ds: &Dataset) {
        config.solve.solver = Some(self.solver);
        config.solve.keyframe_interval = self.keyframes;
        config.solve.neutral = Some(Arc::new(ds.neutral.clone()));
        config.solve.face_vertices = Some(ds.face_vertices.clone());
        config.enhancer = self.enhancer;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lgi_params_default_to_the_noisy_preset_and_merge_a_file() {
        assert_eq!(
            SolveSpec::default().lgi_params().unwrap(),
            LgiParams::noisy()
        );
        let exact = SolveSpec {
            exact_bundles: true,
            ..SolveSpec::default()
        };
        assert_eq!(exact.lgi_params().unwrap(), LgiParams::default());
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("lgi.toml");
        std::fs::write(&file, "max_tets_per_marker = 77\n").unwrap();
        let merged = SolveSpec {
            lgi_params: Some(file.clone()),
            ..SolveSpec::default()
        }
        .lgi_params()
        .unwrap();
        assert_eq!(merged.max_tets_per_marker, 77);
        assert_eq!(
            merged.merge_tolerance_mm,
            LgiParams::noisy().merge_tolerance_mm
        );
        std::fs::write(&file, "no_such_key = 1\n").unwrap();
        let e = SolveSpec {
            lgi_params: Some(file),
            ..SolveSpec::default()
        }
        .lgi_params()
        .unwrap_err();
        assert!(e.to_string().ends_with(": not LGI parameters"), "{e}");
    }
}
