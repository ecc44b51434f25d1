//! The enhancement database of a named dataset (a manifest or `builtin[:SEED]`) and the
//! parameters file: what `enhance`, `retime` and a take's enhance stage start from.

use std::path::Path;

use super::{EnhanceError, EnhanceParams, Enhancer, VoluntaryRegions};
use crate::dataset::actor::Actor;
use crate::dataset::{Dataset, DatasetError, DatasetLoadError, DatasetSpec, Manifest};

/// Onsets of the built-in actor's enhancement database (see
/// [`Actor::performance_dataset`]): each expression at a quarter, half and three quarters
/// of its weight joins the full-weight shapes. In the validation (`tests/enhance_validation.rs`)
/// this recovers 49 % of the high-frequency error instead of 41 %, for four times the
/// precomputation.
pub const BUILTIN_ONSETS: [f64; 3] = [0.25, 0.5, 0.75];

/// Why an enhancer could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum EnhanceSetupError {
    /// The parameters file could not be read.
    #[error("reading {path}")]
    Read {
        /// The file.
        path: String,
        /// The system's error.
        #[source]
        source: std::io::Error,
    },
    /// The parameters file is not TOML with the fields of [`EnhanceParams`].
    #[error("parsing {path}")]
    Parse {
        /// The file.
        path: String,
        /// The parser's error.
        #[source]
        source: toml::de::Error,
    },
    /// A parameter is out of range.
    #[error(transparent)]
    Params(#[from] EnhanceError),
    /// The database could not be loaded.
    #[error(transparent)]
    Dataset(#[from] DatasetLoadError),
    /// The database's manifest could not be read (for its `[regions]`).
    #[error("reading {path}")]
    Manifest {
        /// The manifest.
        path: String,
        /// What went wrong.
        #[source]
        source: DatasetError,
    },
    /// The precomputation failed.
    #[error("precomputing the enhancement database")]
    Precompute(#[source] EnhanceError),
}

/// Reads an [`EnhanceParams`] TOML file (fields it leaves out keep their defaults), or the
/// defaults; checked.
///
/// # Errors
/// An unreadable file, TOML that is not enhancement parameters, a value out of range.
pub fn read_params(path: Option<&Path>) -> Result<EnhanceParams, EnhanceSetupError> {
    let params: EnhanceParams = match path {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|source| EnhanceSetupError::Read {
                path: p.display().to_string(),
                source,
            })?;
            toml::from_str(&text).map_err(|source| EnhanceSetupError::Parse {
                path: p.display().to_string(),
                source,
            })?
        }
        None => EnhanceParams::default(),
    };
    params.validate()?;
    Ok(params)
}

/// Loads the database `database` (a manifest or `builtin[:SEED]`, default cache) and
/// precomputes the enhancer. The built-in actor uses its labelled regions and its
/// performance database (expressions along [`BUILTIN_ONSETS`]), other datasets the
/// manifest's `[regions]` or regions derived from their motion, and their shapes as they
/// are. `onsets: false` keeps the built-in actor's full-weight shapes only (what `retime`
/// uses).
///
/// # Errors
/// A database that cannot be loaded, or a precomputation that fails.
pub fn build_enhancer(
    database: &str,
    params: &EnhanceParams,
    onsets: bool,
) -> Result<(Dataset, Enhancer), EnhanceSetupError> {
    if let Some(actor_params) = crate::dataset::builtin_params(database)? {
        let actor = Actor::new(&actor_params).map_err(DatasetLoadError::Actor)?;
        let dataset = if onsets {
            actor.performance_dataset(&BUILTIN_ONSETS)
        } else {
            actor.to_dataset()
        };
        let regions = VoluntaryRegions::from_actor(&actor);
        let enhancer = Enhancer::with_regions(&dataset, params, &regions)
            .map_err(EnhanceSetupError::Precompute)?;
        return Ok((dataset, enhancer));
    }
    let dataset = DatasetSpec::new(database).load()?;
    let manifest =
        Manifest::read(Path::new(database)).map_err(|source| EnhanceSetupError::Manifest {
            path: database.to_string(),
            source,
        })?;
    let enhancer = match manifest.regions {
        Some(cores) => {
            tracing::info!("voluntary regions from the manifest's [regions]");
            Enhancer::with_regions(&dataset, params, &VoluntaryRegions { cores })
        }
        None => Enhancer::new(&dataset, params),
    }
    .map_err(EnhanceSetupError::Precompute)?;
    Ok((dataset, enhancer))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_file_errors_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("none.toml");
        let e = read_params(Some(&missing)).unwrap_err();
        assert!(e.to_string().starts_with("reading "), "{e}");
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, "patch_vertices = \"many\"\n").unwrap();
        let e = read_params(Some(&bad)).unwrap_err();
        assert!(matches!(e, EnhanceSetupError::Parse { .. }), "{e}");
        assert_eq!(read_params(None).unwrap(), EnhanceParams::default());
    }
}
