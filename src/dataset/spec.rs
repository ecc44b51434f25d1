//! How a dataset is named where a user names one (a command's `--dataset`, a take's
//! settings): the path of a manifest, or `builtin` / `builtin:SEED` for the built-in
//! synthetic actor (seed 0 is the standard actor); with the cache options of the load.

use std::path::{Path, PathBuf};

use super::Dataset;
use super::actor::{Actor, ActorError, ActorParams};
use super::cache::{LoadOptions, default_cache_dir, load_dataset};
use super::manifest::DatasetError;

/// Why a named dataset could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum DatasetLoadError {
    /// `builtin:SEED` with a seed that is not a whole number.
    #[error("builtin actor seed {seed:?} is not a whole number")]
    BuiltinSeed {
        /// The text after `builtin:`.
        seed: String,
        /// The parser's error.
        #[source]
        source: std::num::ParseIntError,
    },
    /// The built-in actor could not be built.
    #[error("building the built-in actor")]
    Actor(#[source] ActorError),
    /// The manifest or a file it names could not be read.
    #[error("loading dataset {path}")]
    Manifest {
        /// The manifest.
        path: String,
        /// What went wrong.
        #[source]
        source: DatasetError,
    },
}

/// The built-in actor's parameters when `name` names it: `builtin` is the standard actor,
/// `builtin:SEED` another identity; `None` for anything else (a manifest path).
///
/// # Errors
/// [`DatasetLoadError::BuiltinSeed`] for `builtin:` followed by something other than a
/// whole number.
pub fn builtin_params(name: &str) -> Result<Option<ActorParams>, DatasetLoadError> {
    match name.strip_prefix("builtin") {
        Some("") => Ok(Some(ActorParams::default())),
        Some(rest) => match rest.strip_prefix(':') {
            Some(seed) => seed
                .parse()
                .map(|seed| Some(ActorParams::from_seed(seed)))
                .map_err(|source| DatasetLoadError::BuiltinSeed {
                    seed: seed.to_string(),
                    source,
                }),
            None => Ok(None),
        },
        None => Ok(None),
    }
}

/// A dataset by name (manifest path or `builtin[:SEED]`) and the options of its cache.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DatasetSpec {
    /// A manifest path, or `builtin[:SEED]` for the built-in actor. Default `builtin`.
    pub name: String,
    /// Neither read nor write the dataset cache (nor the LGI index cache of a take).
    /// Default false.
    pub no_cache: bool,
    /// Cache folder; `None`: [`default_cache_dir`] (`$HELMCAP_CACHE_DIR`, else
    /// `~/.cache/helmcap`). Default `None`.
    pub cache_dir: Option<PathBuf>,
}

impl Default for DatasetSpec {
    fn default() -> Self {
        Self::new("builtin")
    }
}

impl DatasetSpec {
    /// The dataset `name` with the default cache (read and written in the default folder).
    pub fn new(name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            no_cache: false,
            cache_dir: None,
        }
    }

    /// Another dataset with these cache options.
    #[must_use]
    pub fn for_dataset(&self, name: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            no_cache: self.no_cache,
            cache_dir: self.cache_dir.clone(),
        }
    }

    /// The cache folder in use: `cache_dir`, else the default; `None` with `no_cache`.
    pub fn cache_folder(&self) -> Option<PathBuf> {
        (!self.no_cache).then(|| self.cache_dir.clone().unwrap_or_else(default_cache_dir))
    }

    /// Loads the dataset: the built-in actor, or the manifest through the cache, with a
    /// progress bar on the terminal while its mesh files are read.
    ///
    /// # Errors
    /// A bad seed, an actor that cannot be built, or a manifest that cannot be loaded.
    pub fn load(&self) -> Result<Dataset, DatasetLoadError> {
        if let Some(params) = builtin_params(&self.name)? {
            let actor = Actor::new(&params).map_err(DatasetLoadError::Actor)?;
            return Ok(actor.to_dataset());
        }
        let path = Path::new(&self.name);
        let options = LoadOptions {
            cache_dir: self.cache_dir.clone(),
            no_cache: self.no_cache,
            progress: true,
        };
        load_dataset(path, &options).map_err(|source| DatasetLoadError::Manifest {
            path: path.display().to_string(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_names() {
        assert_eq!(
            builtin_params("builtin").unwrap(),
            Some(ActorParams::default())
        );
        assert_eq!(
            builtin_params("builtin:7").unwrap(),
            Some(ActorParams::from_seed(7))
        );
        assert_eq!(builtin_params("builtinx").unwrap(), None);
        assert_eq!(builtin_params("a/b.toml").unwrap(), None);
        let e = builtin_params("builtin:x").unwrap_err();
        assert_eq!(
            e.to_string(),
            "builtin actor seed \"x\" is not a whole number"
        );
    }

    #[test]
    fn cache_folder_follows_the_options() {
        let mut spec = DatasetSpec::new("a.toml");
        spec.cache_dir = Some(PathBuf::from("/c"));
        assert_eq!(spec.cache_folder(), Some(PathBuf::from("/c")));
        spec.no_cache = true;
        assert_eq!(spec.cache_folder(), None);
        assert_eq!(spec.for_dataset("b.toml").cache_folder(), None);
    }
}
