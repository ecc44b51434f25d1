//! The dataset manifest (TOML) and loading a [`Dataset`] from it.
//!
//! The manifest format is a file contract (see the README's "File formats"):
//!
//! ```toml
//! units = "cm"                                  # unit of the mesh files: "mm", "cm" or "m"
//! root = "data"                                 # optional: folder the paths are relative to
//! neutral = "neutral.obj"                       # relative paths: relative to root / this file
//! face_vertices = "0..9408"                     # optional: vertices to reconstruct (inclusive)
//! shapes_glob = "expressions/*.obj"             # optional: every match is a shape
//! [[shape]]                                     # optional, repeatable: one shape from a file
//! name = "jawOpen"
//! file = "jawOpen.obj"
//! jaw = { open_rad = 0.3 }                      # optional: the shape's jaw pose
//! [[shape]]                                     # optional, repeatable: a derived shape
//! name = "jawOpen_half+smileL"
//! combine = { jawOpen = 0.5, mouthSmile_L = 1.0 }
//! [jaw]                                         # optional: jaw rig (linear blend skinning)
//! pivot = [0.0, -2.5, -1.0]                     # manifest units
//! open_axis = [1.0, 0.0, 0.0]
//! lateral_axis = [0.0, 1.0, 0.0]
//! forward = [0.0, 0.0, 1.0]
//! weights = "jaw_weights.txt"                   # one skinning weight per vertex and line
//! [regions]                                     # optional: enhancement's voluntary regions
//! mouth_l = "1200..1350, 1402"                  # core vertices: indices and inclusive ranges
//! mouth_r = "1351..1401"
//! brow_l = "300..360"
//! brow_r = "361..420"
//! ```
//!
//! `[regions]` gives the cores of the four voluntary regions of detail enhancement
//! (Bermano et al. 2014 §4.3: the actor's left and right mouth and brow); without it they
//! are derived from how the shapes move (`enhance::VoluntaryRegions::from_motion`).
//!
//! `root`, `[jaw]`, `[regions]` and a shape's `jaw` are helmcap extensions of the contract; a manifest
//! without them means exactly what the contract says.

use std::collections::{BTreeMap, HashMap};
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};

use nalgebra::{Point3, Unit, Vector3};
use rayon::prelude::*;
use serde::Deserialize;

use super::{Dataset, JawPose, JawRig, Shape};
use crate::mesh::{MeshError, read_obj, read_obj_positions};

/// Errors from reading a manifest or the files it names.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file involved.
        path: String,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The manifest is not valid TOML or has a key of the wrong type or an unknown key.
    #[error("{path}: {message}")]
    Syntax {
        /// The manifest.
        path: String,
        /// The TOML parser's message (with line and column).
        message: String,
    },
    /// The manifest is well-formed but says something impossible.
    #[error("{path}: {message}")]
    Invalid {
        /// The manifest (or the file it names).
        path: String,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// A mesh file named by the manifest could not be read.
    #[error(transparent)]
    Mesh(#[from] MeshError),
    /// A shape's vertex count differs from the neutral's.
    #[error("{file}: shape has {found} vertices but the neutral has {expected}")]
    VertexCount {
        /// The shape file.
        file: String,
        /// The neutral's vertex count.
        expected: usize,
        /// This file's vertex count.
        found: usize,
    },
}

impl DatasetError {
    fn invalid(path: &Path, message: impl Into<String>) -> Self {
        DatasetError::Invalid {
            path: path.display().to_string(),
            message: message.into(),
        }
    }
}

/// Length unit of the mesh files named by a manifest.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Units {
    /// Millimetres.
    Millimetres,
    /// Centimetres.
    Centimetres,
    /// Metres.
    Metres,
}

impl Units {
    /// Parses `"mm"`, `"cm"` or `"m"`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "mm" => Some(Units::Millimetres),
            "cm" => Some(Units::Centimetres),
            "m" => Some(Units::Metres),
            _ => None,
        }
    }

    /// Factor that converts a length in this unit to millimetres.
    pub fn to_mm(self) -> f64 {
        match self {
            Units::Millimetres => 1.0,
            Units::Centimetres => 10.0,
            Units::Metres => 1000.0,
        }
    }

    /// The manifest spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Units::Millimetres => "mm",
            Units::Centimetres => "cm",
            Units::Metres => "m",
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ManifestToml {
    units: String,
    #[serde(default)]
    root: Option<String>,
    neutral: String,
    #[serde(default)]
    face_vertices: Option<String>,
    #[serde(default)]
    shapes_glob: Option<String>,
    #[serde(default)]
    shape: Vec<ShapeToml>,
    #[serde(default)]
    jaw: Option<JawToml>,
    #[serde(default)]
    regions: Option<RegionsToml>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RegionsToml {
    mouth_l: String,
    mouth_r: String,
    brow_l: String,
    brow_r: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ShapeToml {
    name: String,
    #[serde(default)]
    file: Option<String>,
    #[serde(default)]
    combine: Option<BTreeMap<String, f64>>,
    #[serde(default)]
    jaw: Option<JawPoseToml>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct JawPoseToml {
    #[serde(default)]
    open_rad: f64,
    #[serde(default)]
    lateral_rad: f64,
    #[serde(default)]
    forward_mm: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct JawToml {
    pivot: [f64; 3],
    open_axis: [f64; 3],
    lateral_axis: [f64; 3],
    forward: [f64; 3],
    weights: String,
}

/// Where one shape comes from.
#[derive(Debug, Clone, PartialEq)]
pub enum ShapeSource {
    /// A mesh file (absolute path).
    File(PathBuf),
    /// `neutral + Σ weight · (shape − neutral)` over earlier shapes, by name.
    Combine(Vec<(String, f64)>),
}

/// One shape entry of a validated manifest.
#[derive(Debug, Clone, PartialEq)]
pub struct ShapeEntry {
    /// Shape name.
    pub name: String,
    /// Where its positions come from.
    pub source: ShapeSource,
    /// Its jaw pose, when given.
    pub jaw: Option<JawPose>,
}

/// Jaw rig section of a validated manifest (lengths still in manifest units).
#[derive(Debug, Clone, PartialEq)]
pub struct JawEntry {
    /// Pivot, manifest units.
    pub pivot: Point3<f64>,
    /// Opening axis.
    pub open_axis: Unit<Vector3<f64>>,
    /// Sideways axis.
    pub lateral_axis: Unit<Vector3<f64>>,
    /// Protrusion direction.
    pub forward: Unit<Vector3<f64>>,
    /// Weights file (absolute path).
    pub weights: PathBuf,
}

/// A parsed and validated dataset manifest, paths resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct Manifest {
    /// The manifest file.
    pub path: PathBuf,
    /// Unit of the mesh files.
    pub units: Units,
    /// The neutral mesh file.
    pub neutral: PathBuf,
    /// Vertices to reconstruct, when given.
    pub face_vertices: Option<RangeInclusive<u32>>,
    /// Shapes in order: glob matches first (sorted by file name), then `[[shape]]` entries.
    pub shapes: Vec<ShapeEntry>,
    /// Jaw rig, when given.
    pub jaw: Option<JawEntry>,
    /// Core vertices of the four voluntary regions (`mouth_l`, `mouth_r`, `brow_l`,
    /// `brow_r`), when given (checked against the vertex count when the dataset loads).
    pub regions: Option<[Vec<u32>; 4]>,
}

impl Manifest {
    /// Reads and validates a manifest. Files it names are checked for existence here; their
    /// contents are checked when the dataset is loaded.
    ///
    /// # Errors
    /// A [`DatasetError`] naming the manifest and what is wrong with it.
    pub fn read(path: &Path) -> Result<Self, DatasetError> {
        let text = std::fs::read_to_string(path).map_err(|source| DatasetError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses manifest text; `path` locates relative paths and names the file in errors.
    ///
    /// # Errors
    /// As [`Manifest::read`].
    pub fn parse(text: &str, path: &Path) -> Result<Self, DatasetError> {
        let raw: ManifestToml = toml::from_str(text).map_err(|e| DatasetError::Syntax {
            path: path.display().to_string(),
            message: e.to_string().trim_end().replace('\n', " "),
        })?;
        let units = Units::parse(raw.units.trim()).ok_or_else(|| {
            DatasetError::invalid(
                path,
                format!(
                    "unknown unit {:?} (expected \"mm\", \"cm\" or \"m\")",
                    raw.units
                ),
            )
        })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let root = match &raw.root {
            Some(r) => dir.join(r),
            None => dir.to_path_buf(),
        };
        let resolve = |p: &str| root.join(p);
        let must_exist = |p: PathBuf, what: &str| -> Result<PathBuf, DatasetError> {
            if p.is_file() {
                Ok(p)
            } else {
                Err(DatasetError::invalid(
                    path,
                    format!("{what} file {} does not exist", p.display()),
                ))
            }
        };
        let neutral = must_exist(resolve(&raw.neutral), "neutral")?;
        let face_vertices = match &raw.face_vertices {
            Some(s) => Some(parse_vertex_range(s).ok_or_else(|| {
                DatasetError::invalid(
                    path,
                    format!(
                        "face_vertices {} is not an inclusive range like \"0..9408\"",
                        crate::limits::quoted(s)
                    ),
                )
            })?),
            None => None,
        };

        let mut shapes = Vec::new();
        if let Some(pattern) = &raw.shapes_glob {
            let full = resolve(pattern);
            let full_str = full.to_string_lossy().into_owned();
            let paths = glob::glob(&full_str).map_err(|e| {
                DatasetError::invalid(path, format!("shapes_glob {pattern:?}: {e}"))
            })?;
            let mut matched: Vec<PathBuf> = paths.filter_map(Result::ok).collect();
            matched.sort();
            let neutral_canon = neutral.canonicalize().ok();
            for p in matched {
                // The neutral is not a shape of itself, even when the glob matches it.
                if p.canonicalize().ok() == neutral_canon {
                    continue;
                }
                let name = p
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                shapes.push(ShapeEntry {
                    name,
                    source: ShapeSource::File(p),
                    jaw: None,
                });
            }
            if shapes.is_empty() {
                return Err(DatasetError::invalid(
                    path,
                    format!("shapes_glob {pattern:?} matches no file"),
                ));
            }
        }
        for s in raw.shape {
            let source = match (s.file, s.combine) {
                (Some(f), None) => {
                    ShapeSource::File(must_exist(resolve(&f), &format!("shape {:?}", s.name))?)
                }
                (None, Some(c)) => {
                    if c.is_empty() {
                        return Err(DatasetError::invalid(
                            path,
                            format!("shape {:?}: combine is empty", s.name),
                        ));
                    }
                    for (other, w) in &c {
                        if !w.is_finite() {
                            return Err(DatasetError::invalid(
                                path,
                                format!("shape {:?}: weight of {other:?} is not finite", s.name),
                            ));
                        }
                        if !shapes.iter().any(|e: &ShapeEntry| &e.name == other) {
                            return Err(DatasetError::invalid(
                                path,
                                format!(
                                    "shape {:?}: combine names unknown shape {other:?} (a \
                                     combined shape may use shapes defined before it)",
                                    s.name
                                ),
                            ));
                        }
                    }
                    ShapeSource::Combine(c.into_iter().collect())
                }
                (Some(_), Some(_)) => {
                    return Err(DatasetError::invalid(
                        path,
                        format!("shape {:?} has both file and combine: give one", s.name),
                    ));
                }
                (None, None) => {
                    return Err(DatasetError::invalid(
                        path,
                        format!("shape {:?} has neither file nor combine", s.name),
                    ));
                }
            };
            if s.name.trim().is_empty() {
                return Err(DatasetError::invalid(path, "a shape has an empty name"));
            }
            if shapes.iter().any(|e| e.name == s.name) {
                return Err(DatasetError::invalid(
                    path,
                    format!("shape name {:?} is used twice", s.name),
                ));
            }
            let jaw = s.jaw.map(|j| JawPose {
                open_rad: j.open_rad,
                lateral_rad: j.lateral_rad,
                forward_mm: j.forward_mm,
            });
            if let Some(j) = &jaw
                && ![j.open_rad, j.lateral_rad, j.forward_mm]
                    .iter()
                    .all(|x| x.is_finite())
            {
                return Err(DatasetError::invalid(
                    path,
                    format!("shape {:?}: jaw pose is not finite", s.name),
                ));
            }
            shapes.push(ShapeEntry {
                name: s.name,
                source,
                jaw,
            });
        }

        let jaw = match raw.jaw {
            None => None,
            Some(j) => {
                let axis = |v: [f64; 3], what: &str| {
                    Unit::try_new(Vector3::from(v), 1e-12)
                        .filter(|_| v.iter().all(|x| x.is_finite()))
                        .ok_or_else(|| {
                            DatasetError::invalid(path, format!("jaw {what} is not a direction"))
                        })
                };
                if !j.pivot.iter().all(|x| x.is_finite()) {
                    return Err(DatasetError::invalid(path, "jaw pivot is not finite"));
                }
                Some(JawEntry {
                    pivot: Point3::from(j.pivot),
                    open_axis: axis(j.open_axis, "open_axis")?,
                    lateral_axis: axis(j.lateral_axis, "lateral_axis")?,
                    forward: axis(j.forward, "forward")?,
                    weights: must_exist(resolve(&j.weights), "jaw weights")?,
                })
            }
        };

        let regions = match &raw.regions {
            None => None,
            Some(r) => {
                let mut cores: [Vec<u32>; 4] = Default::default();
                for (slot, (name, text)) in cores.iter_mut().zip([
                    ("mouth_l", &r.mouth_l),
                    ("mouth_r", &r.mouth_r),
                    ("brow_l", &r.brow_l),
                    ("brow_r", &r.brow_r),
                ]) {
                    *slot = parse_vertex_list(text).ok_or_else(|| {
                        DatasetError::invalid(
                            path,
                            format!(
                                "regions.{name} {} is not a list of vertex indices and \
                                 inclusive ranges like \"10..20, 25\" of at most {} vertices",
                                crate::limits::quoted(text),
                                crate::limits::MAX_RANGE_VERTICES
                            ),
                        )
                    })?;
                    if slot.is_empty() {
                        return Err(DatasetError::invalid(
                            path,
                            format!("regions.{name} is empty"),
                        ));
                    }
                }
                Some(cores)
            }
        };

        Ok(Manifest {
            path: path.to_path_buf(),
            units,
            neutral,
            face_vertices,
            shapes,
            jaw,
            regions,
        })
    }

    /// Every file the manifest depends on (itself included), for cache invalidation.
    pub fn input_files(&self) -> Vec<PathBuf> {
        let mut files = vec![self.path.clone(), self.neutral.clone()];
        for s in &self.shapes {
            if let ShapeSource::File(p) = &s.source {
                files.push(p.clone());
            }
        }
        if let Some(j) = &self.jaw {
            files.push(j.weights.clone());
        }
        files
    }

    /// Short dataset name: the manifest's file stem.
    pub fn name(&self) -> String {
        self.path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "dataset".into())
    }

    /// Loads every file and builds the dataset in millimetres (no cache).
    ///
    /// Shape files are read in parallel. `progress` is called with (files done, total).
    ///
    /// # Errors
    /// The first [`DatasetError`] met: unreadable or malformed mesh (file and line named),
    /// a shape whose vertex count differs from the neutral (file named), a face range or
    /// jaw weights that do not fit the mesh.
    pub fn load(&self, progress: &(dyn Fn(usize, usize) + Sync)) -> Result<Dataset, DatasetError> {
        let scale = self.units.to_mm();
        let file_shapes: Vec<(usize, &PathBuf)> = self
            .shapes
            .iter()
            .enumerate()
            .filter_map(|(i, s)| match &s.source {
                ShapeSource::File(p) => Some((i, p)),
                ShapeSource::Combine(_) => None,
            })
            .collect();
        let total = file_shapes.len() + 1;
        let done = std::sync::atomic::AtomicUsize::new(0);
        let tick = || {
            let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            progress(d, total);
        };

        let mut neutral = read_obj(&self.neutral)?;
        neutral.scale(scale);
        tick();
        let nv = neutral.vertex_count();

        let loaded: Vec<(usize, Vec<Point3<f64>>)> = file_shapes
            .par_iter()
            .map(|&(i, p)| {
                let mut pos = read_obj_positions(p)?;
                if pos.len() != nv {
                    return Err(DatasetError::VertexCount {
                        file: p.display().to_string(),
                        expected: nv,
                        found: pos.len(),
                    });
                }
                for x in &mut pos {
                    x.coords *= scale;
                }
                tick();
                Ok((i, pos))
            })
            .collect::<Result<_, DatasetError>>()?;
        let mut positions: Vec<Option<Vec<Point3<f64>>>> = vec![None; self.shapes.len()];
        for (i, pos) in loaded {
            positions[i] = Some(pos);
        }
        let mut by_name: HashMap<&str, usize> = HashMap::new();
        let mut shapes = Vec::with_capacity(self.shapes.len());
        for (i, entry) in self.shapes.iter().enumerate() {
            let pos = match (&entry.source, positions[i].take()) {
                (ShapeSource::File(_), Some(p)) => p,
                (ShapeSource::Combine(terms), _) => {
                    let mut out = neutral.positions.clone();
                    for (name, w) in terms {
                        let j = by_name.get(name.as_str()).copied().ok_or_else(|| {
                            DatasetError::invalid(
                                &self.path,
                                format!("shape {:?}: unknown shape {name:?}", entry.name),
                            )
                        })?;
                        let other: &Shape = &shapes[j];
                        for ((o, s), n) in
                            out.iter_mut().zip(&other.positions).zip(&neutral.positions)
                        {
                            o.coords += (s - n) * *w;
                        }
                    }
                    out
                }
                (ShapeSource::File(p), None) => {
                    return Err(DatasetError::invalid(
                        &self.path,
                        format!("shape file {} was not loaded", p.display()),
                    ));
                }
            };
            by_name.insert(entry.name.as_str(), shapes.len());
            shapes.push(Shape {
                name: entry.name.clone(),
                positions: pos,
                jaw: entry.jaw,
            });
        }

        let face_vertices = match &self.face_vertices {
            Some(r) => {
                if *r.end() as usize >= nv {
                    return Err(DatasetError::invalid(
                        &self.path,
                        format!(
                            "face_vertices {}..{} goes past the neutral's {nv} vertices",
                            r.start(),
                            r.end()
                        ),
                    ));
                }
                r.clone()
            }
            None => 0..=u32::try_from(nv.saturating_sub(1)).unwrap_or(u32::MAX),
        };
        if let Some(cores) = &self.regions
            && let Some(v) = cores.iter().flatten().find(|&&v| v as usize >= nv)
        {
            return Err(DatasetError::invalid(
                &self.path,
                format!("regions: vertex {v} is past the neutral's {nv} vertices"),
            ));
        }

        let jaw = match &self.jaw {
            None => None,
            Some(j) => {
                let weights = read_weights(&j.weights, nv)?;
                Some(JawRig {
                    pivot: Point3::from(j.pivot.coords * scale),
                    open_axis: j.open_axis,
                    lateral_axis: j.lateral_axis,
                    forward: j.forward,
                    weights,
                })
            }
        };

        Ok(Dataset {
            name: self.name(),
            neutral,
            shapes,
            face_vertices,
            jaw,
        })
    }
}

/// Parses an inclusive vertex range `"a..b"` (also accepts `"a..=b"`).
pub fn parse_vertex_range(s: &str) -> Option<RangeInclusive<u32>> {
    let (a, b) = s.trim().split_once("..")?;
    let b = b.strip_prefix('=').unwrap_or(b);
    let a: u32 = a.trim().parse().ok()?;
    let b: u32 = b.trim().parse().ok()?;
    (a <= b).then_some(a..=b)
}

/// Parses a comma-separated list of vertex indices and inclusive ranges (`"3, 10..20"`),
/// sorted and without repeats; `None` on any malformed item, and when the list would
/// hold more than [`crate::limits::MAX_RANGE_VERTICES`] entries (checked before
/// anything is allocated: `"0..4000000000"` is refused, not expanded).
pub fn parse_vertex_list(s: &str) -> Option<Vec<u32>> {
    let mut out = Vec::new();
    let mut total = 0u64;
    for item in s.split(',').map(str::trim).filter(|i| !i.is_empty()) {
        if item.contains("..") {
            let r = parse_vertex_range(item)?;
            total += u64::from(r.end() - r.start()) + 1;
            if total > crate::limits::MAX_RANGE_VERTICES {
                return None;
            }
            out.extend(r);
        } else {
            total += 1;
            if total > crate::limits::MAX_RANGE_VERTICES {
                return None;
            }
            out.push(item.parse().ok()?);
        }
    }
    out.sort_unstable();
    out.dedup();
    Some(out)
}

/// Reads one skinning weight per line (blank lines and `#` comments skipped).
fn read_weights(path: &Path, expected: usize) -> Result<Vec<f64>, DatasetError> {
    let text = std::fs::read_to_string(path).map_err(|source| DatasetError::Io {
        path: path.display().to_string(),
        source,
    })?;
    let mut out = Vec::with_capacity(expected);
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        match line.parse::<f64>() {
            Ok(w) if (0.0..=1.0).contains(&w) => out.push(w),
            _ => {
                return Err(DatasetError::Invalid {
                    path: format!("{}:{}", path.display(), i + 1),
                    message: format!("{line:?} is not a weight in 0..1"),
                });
            }
        }
    }
    if out.len() != expected {
        return Err(DatasetError::invalid(
            path,
            format!("{} weights for a neutral of {expected} vertices", out.len()),
        ));
    }
    Ok(out)
}

/// Writes `dataset` as a manifest (`manifest.toml`, units mm), `neutral.obj`, one OBJ per
/// shape under `shapes/` and, with a jaw rig, `jaw_weights.txt`. Returns the manifest path.
///
/// Every file is written atomically; the folder is created when missing. Loading the
/// manifest back gives the same dataset (positions bit-identical).
///
/// # Errors
/// [`DatasetError`] naming the file that could not be written, or a shape name that cannot
/// be a file name.
pub fn write_dataset(dataset: &Dataset, dir: &Path) -> Result<PathBuf, DatasetError> {
    use std::fmt::Write as _;
    let io = |path: &Path| {
        let path = path.display().to_string();
        move |source| DatasetError::Io { path, source }
    };
    std::fs::create_dir_all(dir.join("shapes")).map_err(io(dir))?;
    crate::mesh::write_obj(&dir.join("neutral.obj"), &dataset.neutral)?;
    let mut toml = String::new();
    let _ = writeln!(toml, "# Dataset {} written by helmcap.", dataset.name);
    let _ = writeln!(toml, "units = \"mm\"");
    let _ = writeln!(toml, "neutral = \"neutral.obj\"");
    let _ = writeln!(
        toml,
        "face_vertices = \"{}..{}\"",
        dataset.face_vertices.start(),
        dataset.face_vertices.end()
    );
    if let Some(j) = &dataset.jaw {
        let weights = dir.join("jaw_weights.txt");
        crate::atomic_file::write_atomically(&weights, |w| {
            use std::io::Write as _;
            for x in &j.weights {
                writeln!(w, "{x}")?;
            }
            Ok(())
        })
        .map_err(io(&weights))?;
        let v = |x: &Vector3<f64>| format!("[{}, {}, {}]", x.x, x.y, x.z);
        let _ = writeln!(toml, "\n[jaw]");
        let _ = writeln!(toml, "pivot = {}", v(&j.pivot.coords));
        let _ = writeln!(toml, "open_axis = {}", v(&j.open_axis));
        let _ = writeln!(toml, "lateral_axis = {}", v(&j.lateral_axis));
        let _ = writeln!(toml, "forward = {}", v(&j.forward));
        let _ = writeln!(toml, "weights = \"jaw_weights.txt\"");
    }
    for s in &dataset.shapes {
        if s.name.is_empty()
            || !s
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-+.".contains(c))
        {
            return Err(DatasetError::invalid(
                dir,
                format!("shape name {:?} cannot be a file name", s.name),
            ));
        }
        let file = format!("shapes/{}.obj", s.name);
        crate::mesh::write_obj_positions(&dir.join(&file), &dataset.neutral, &s.positions)?;
        let _ = writeln!(
            toml,
            "\n[[shape]]\nname = \"{}\"\nfile = \"{file}\"",
            s.name
        );
        if let Some(j) = &s.jaw {
            let _ = writeln!(
                toml,
                "jaw = {{ open_rad = {}, lateral_rad = {}, forward_mm = {} }}",
                j.open_rad, j.lateral_rad, j.forward_mm
            );
        }
    }
    let manifest = dir.join("manifest.toml");
    crate::atomic_file::write_atomically(&manifest, |w| {
        use std::io::Write as _;
        w.write_all(toml.as_bytes())
    })
    .map_err(io(&manifest))?;
    Ok(manifest)
}

#[cfg(test)]
mod tests {
    use super::*;
    // The cached load (cache.rs) of the manifests these tests write.
    use crate::dataset::{LoadOptions, load_dataset};

    const TRI: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n";

    /// A folder with a neutral quad and two shapes, in centimetres.
    fn fixture() -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("neutral.obj"), TRI).unwrap();
        std::fs::create_dir(dir.path().join("expr")).unwrap();
        std::fs::write(
            dir.path().join("expr/up.obj"),
            "v 0 0 1\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n",
        )
        .unwrap();
        std::fs::write(
            dir.path().join("expr/side.obj"),
            "v 0 0 0\nv 2 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n",
        )
        .unwrap();
        dir
    }

    fn write_manifest(dir: &Path, text: &str) -> PathBuf {
        let p = dir.join("m.toml");
        std::fs::write(&p, text).unwrap();
        p
    }

    fn load_err(dir: &Path, text: &str) -> String {
        let p = write_manifest(dir, text);
        match Manifest::read(&p).and_then(|m| m.load(&|_, _| {})) {
            Ok(_) => panic!("manifest should fail:\n{text}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn loads_glob_files_and_combinations_in_millimetres() {
        let dir = fixture();
        let p = write_manifest(
            dir.path(),
            "units = \"cm\"\nneutral = \"neutral.obj\"\nface_vertices = \"0..2\"\n\
             shapes_glob = \"expr/*.obj\"\n\
             [[shape]]\nname = \"mix\"\ncombine = { up = 0.5, side = 2.0 }\n",
        );
        let ds = Manifest::read(&p).unwrap().load(&|_, _| {}).unwrap();
        let names: Vec<_> = ds.shapes.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, ["side", "up", "mix"]);
        assert_eq!(ds.neutral.positions[3], Point3::new(10.0, 10.0, 0.0));
        assert_eq!(ds.shapes[1].positions[0], Point3::new(0.0, 0.0, 10.0));
        // mix = neutral + 0.5·(up − n) + 2·(side − n): vertex 0 up 5 mm, vertex 1 +20 mm in x.
        assert_eq!(ds.shapes[2].positions[0], Point3::new(0.0, 0.0, 5.0));
        assert_eq!(ds.shapes[2].positions[1], Point3::new(30.0, 0.0, 0.0));
        assert_eq!(ds.face_vertices, 0..=2);
        assert_eq!(parse_vertex_list(" 7, 1..3,2 ,"), Some(vec![1, 2, 3, 7]));
        assert_eq!(parse_vertex_list("1..x"), None);
        assert_eq!(parse_vertex_list("-1"), None);
        // A huge range is refused before it is expanded (it used to allocate 16 GB).
        assert_eq!(parse_vertex_list("0..4000000000"), None);
        assert_eq!(parse_vertex_list(&"0..9000000, ".repeat(3)), None);
        let with_regions = write_manifest(
            dir.path(),
            "units = \"mm\"\nneutral = \"neutral.obj\"\n[regions]\nmouth_l = \"0\"\n\
             mouth_r = \"1\"\nbrow_l = \"2..3\"\nbrow_r = \"3\"\n",
        );
        let m = Manifest::read(&with_regions).unwrap();
        assert_eq!(m.regions, Some([vec![0], vec![1], vec![2, 3], vec![3]]));
        assert!(m.load(&|_, _| {}).is_ok());
        assert!(!ds.is_face_vertex(3));
    }

    #[test]
    fn each_bad_manifest_has_its_own_error() {
        let dir = fixture();
        let d = dir.path();
        std::fs::write(d.join("small.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        std::fs::write(
            d.join("nan.obj"),
            "v 0 0 nan\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n",
        )
        .unwrap();
        let cases = [
            (
                "units = \"inch\"\nneutral = \"neutral.obj\"\n",
                "unknown unit",
            ),
            (
                "units = \"mm\"\nneutral = \"missing.obj\"\n",
                "does not exist",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\n[[shape]]\nname = \"s\"\nfile = \"small.obj\"\n",
                "small.obj: shape has 3 vertices but the neutral has 4",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\n[[shape]]\nname = \"c\"\ncombine = { nope = 1.0 }\n",
                "unknown shape \"nope\"",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\n[[shape]]\nname = \"s\"\nfile = \"nan.obj\"\n",
                "nan.obj:1",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\nface_vertices = \"0..99\"\n",
                "goes past",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\nface_vertices = \"5-9\"\n",
                "inclusive range",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\nshape_glob = \"*.obj\"\n",
                "unknown field",
            ),
            ("units = \"mm\"\n", "missing field"),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\n[regions]\nmouth_l = \"0\"\nmouth_r = \"1\"\nbrow_l = \"2\"\nbrow_r = \"9\"\n",
                "regions: vertex 9 is past",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\n[regions]\nmouth_l = \"0\"\nmouth_r = \"1\"\nbrow_l = \"a\"\nbrow_r = \"3\"\n",
                "regions.brow_l \"a\" is not a list",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\n[regions]\nmouth_l = \"0..4000000000\"\nmouth_r = \"1\"\nbrow_l = \"2\"\nbrow_r = \"3\"\n",
                "regions.mouth_l \"0..4000000000\" is not a list",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\n[regions]\nmouth_l = \"0\"\n",
                "missing field",
            ),
            (
                "units = \"mm\"\nneutral = \"neutral.obj\"\n[[shape]]\nname = \"a\"\nfile = \"neutral.obj\"\n[[shape]]\nname = \"a\"\nfile = \"neutral.obj\"\n",
                "used twice",
            ),
        ];
        for (text, expected) in cases {
            let msg = load_err(d, text);
            assert!(
                msg.contains(expected),
                "{msg:?} should contain {expected:?}"
            );
        }
    }

    #[test]
    fn root_moves_relative_paths() {
        let dir = fixture();
        let sub = dir.path().join("configs");
        std::fs::create_dir(&sub).unwrap();
        let p = write_manifest(
            &sub,
            "units = \"mm\"\nroot = \"..\"\nneutral = \"neutral.obj\"\n",
        );
        let ds = Manifest::read(&p).unwrap().load(&|_, _| {}).unwrap();
        assert_eq!(ds.vertex_count(), 4);
        assert_eq!(ds.name, "m");
    }

    #[test]
    fn cache_round_trips_and_rebuilds_when_an_input_changes() {
        let dir = fixture();
        let cache = dir.path().join("cache");
        let p = write_manifest(
            dir.path(),
            "units = \"cm\"\nneutral = \"neutral.obj\"\nshapes_glob = \"expr/*.obj\"\n",
        );
        let opts = LoadOptions {
            cache_dir: Some(cache.clone()),
            ..Default::default()
        };
        let first = load_dataset(&p, &opts).unwrap();
        assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 1);
        let cached = load_dataset(&p, &opts).unwrap();
        assert_eq!(cached, first);
        // Change a shape file (new size, so the key differs even within one mtime tick).
        std::fs::write(
            dir.path().join("expr/up.obj"),
            "v 0 0 3.5\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\n",
        )
        .unwrap();
        let rebuilt = load_dataset(&p, &opts).unwrap();
        assert_eq!(rebuilt.shapes[1].positions[0], Point3::new(0.0, 0.0, 35.0));
        // A corrupt cache is ignored with a warning, not an error.
        let file = std::fs::read_dir(&cache)
            .unwrap()
            .next()
            .unwrap()
            .unwrap()
            .path();
        let mut bytes = std::fs::read(&file).unwrap();
        bytes.truncate(bytes.len() - 5);
        std::fs::write(&file, bytes).unwrap();
        assert_eq!(load_dataset(&p, &opts).unwrap(), rebuilt);
    }

    #[test]
    fn written_dataset_loads_back_identically() {
        let dir = fixture();
        let p = write_manifest(
            dir.path(),
            "units = \"cm\"\nneutral = \"neutral.obj\"\nshapes_glob = \"expr/*.obj\"\n",
        );
        let mut ds = Manifest::read(&p).unwrap().load(&|_, _| {}).unwrap();
        ds.jaw = Some(JawRig {
            pivot: Point3::new(0.1, -2.0, -3.0),
            open_axis: Vector3::x_axis(),
            lateral_axis: Vector3::y_axis(),
            forward: Vector3::z_axis(),
            weights: vec![0.0, 0.25, 1.0, 0.5],
        });
        ds.shapes[0].jaw = Some(JawPose {
            open_rad: 0.3,
            lateral_rad: -0.01,
            forward_mm: 1.5,
        });
        let out = dir.path().join("written");
        let manifest = write_dataset(&ds, &out).unwrap();
        let back = Manifest::read(&manifest).unwrap().load(&|_, _| {}).unwrap();
        assert_eq!(back.neutral.positions, ds.neutral.positions);
        assert_eq!(back.shapes, ds.shapes);
        assert_eq!(back.jaw, ds.jaw);
        assert_eq!(back.face_vertices, ds.face_vertices);
    }
}
