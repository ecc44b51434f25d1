//! Name maps: a rig's shape names mapped to a target convention (CSV `shape,target`),
//! and Apple's 52 ARKit blendshape names.

use crate::dataset::Dataset;
use crate::file_error::FileError;
use crate::name_pairs::{NamePairsFormat, parse_name_pairs};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// Apple's 52 ARKit face blendshape names (`ARFaceAnchor.BlendShapeLocation`), in
/// Apple's order: left eye, right eye, mouth and jaw, eyebrows, cheeks, nose, tongue.
/// The same order is the index order of Live Link Face's curves.
pub const ARKIT_NAMES: [&str; 52] = [
    "eyeBlinkLeft",
    "eyeLookDownLeft",
    "eyeLookInLeft",
    "eyeLookOutLeft",
    "eyeLookUpLeft",
    "eyeSquintLeft",
    "eyeWideLeft",
    "eyeBlinkRight",
    "eyeLookDownRight",
    "eyeLookInRight",
    "eyeLookOutRight",
    "eyeLookUpRight",
    "eyeSquintRight",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawRight",
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthLeft",
    "mouthRight",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
];

/// The shipped built-in actor → ARKit map.
const BUILTIN_ARKIT: &str = include_str!("../../configs/namemaps/builtin-arkit.csv");
/// The shipped ICT-FaceKit → ARKit map.
const ICT_ARKIT: &str = include_str!("../../configs/namemaps/ict-arkit.csv");

/// Errors reading a name map.
#[derive(Debug, thiserror::Error)]
pub enum NameMapError {
    /// The file could not be read or written, or a line of it is malformed.
    #[error(transparent)]
    File(#[from] FileError),
}

/// A map from a rig's shape names to target names (CSV `shape,target`).
///
/// Several shapes may map to one target (the ICT-FaceKit's `browInnerUp_L` and
/// `browInnerUp_R` both to ARKit's `browInnerUp`): the target's value is then the mean of
/// their weights. A shape absent from the map is *unmapped*: [`ResolvedMap::apply`] reports
/// it, it is not dropped silently.
#[derive(Debug, Clone, PartialEq)]
pub struct NameMap {
    /// (shape, target) rows in file order.
    rows: Vec<(String, String)>,
}

/// A name map resolved against one rig and one target list.
#[derive(Debug, Clone, PartialEq)]
pub struct ResolvedMap {
    /// Per target (target order), the rig shape indices that feed it (empty: always 0).
    pub sources: Vec<Vec<usize>>,
    /// Rig shapes the map does not mention, by name.
    pub unmapped_shapes: Vec<String>,
    /// Map rows whose shape the rig does not have, or whose target is not in the list.
    pub unused_rows: Vec<(String, String)>,
}

impl ResolvedMap {
    /// Target values from rig weights (rig order).
    pub fn apply(&self, weights: &[f64]) -> Vec<f64> {
        self.sources
            .iter()
            .map(|s| {
                if s.is_empty() {
                    0.0
                } else {
                    s.iter()
                        .map(|&i| weights.get(i).copied().unwrap_or(0.0))
                        .sum::<f64>()
                        / s.len() as f64
                }
            })
            .collect()
    }
}

impl NameMap {
    /// The map from (shape, target) pairs.
    pub fn new(rows: Vec<(String, String)>) -> Self {
        Self { rows }
    }

    /// The map for `rig` when none is given: the shipped built-in or ICT map when the
    /// rig's shapes are theirs, the identity when they are ARKit names already (the
    /// candidate that leaves the fewest shapes unmapped).
    pub fn default_for(rig: &Dataset) -> Self {
        let names: Vec<&str> = rig.shapes.iter().map(|s| s.name.as_str()).collect();
        let covered = |m: &NameMap| m.resolve(&names, &ARKIT_NAMES).unmapped_shapes.len();
        let candidates = [
            NameMap::builtin_arkit(),
            NameMap::ict_arkit(),
            NameMap::identity(&ARKIT_NAMES),
        ];
        candidates
            .into_iter()
            .min_by_key(covered)
            .unwrap_or_else(|| NameMap::identity(&ARKIT_NAMES))
    }

    /// The shipped map from the built-in actor's expression names to ARKit's
    /// (`configs/namemaps/builtin-arkit.csv`).
    pub fn builtin_arkit() -> Self {
        Self::parse_csv(BUILTIN_ARKIT, "builtin-arkit.csv")
            .unwrap_or_else(|_| Self::new(Vec::new()))
    }

    /// The shipped map from the ICT-FaceKit's shape names to ARKit's
    /// (`configs/namemaps/ict-arkit.csv`).
    pub fn ict_arkit() -> Self {
        Self::parse_csv(ICT_ARKIT, "ict-arkit.csv").unwrap_or_else(|_| Self::new(Vec::new()))
    }

    /// The identity map of `names` (each shape to itself).
    pub fn identity<S: AsRef<str>>(names: &[S]) -> Self {
        Self {
            rows: names
                .iter()
                .map(|n| (n.as_ref().to_string(), n.as_ref().to_string()))
                .collect(),
        }
    }

    /// Reads a name map CSV (header `shape,target`; `#` comments and blank lines allowed).
    ///
    /// # Errors
    /// [`NameMapError`] naming the file (and line): unreadable, wrong header, a row
    /// without two names, a shape listed twice.
    pub fn read_csv(path: &Path) -> Result<Self, NameMapError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| {
            NameMapError::File(FileError::Io {
                path: name.clone(),
                source,
            })
        })?;
        Self::parse_csv(&text, &name)
    }

    /// Parses name map CSV text; `name` stands for the file in errors.
    ///
    /// # Errors
    /// As [`NameMap::read_csv`].
    pub fn parse_csv(text: &str, name: &str) -> Result<Self, NameMapError> {
        let format = NamePairsFormat {
            columns: ["shape", "target"],
            what: "shape",
            extra_columns: false,
        };
        let rows = parse_name_pairs(text, &format).map_err(|(line, message)| {
            NameMapError::File(FileError::Parse {
                path: name.to_string(),
                line,
                message,
            })
        })?;
        Ok(Self { rows })
    }

    /// Resolves the map for a rig's shape names and a target list.
    pub fn resolve<S: AsRef<str>, T: AsRef<str>>(
        &self,
        shapes: &[S],
        targets: &[T],
    ) -> ResolvedMap {
        let shape_index: HashMap<&str, usize> = shapes
            .iter()
            .enumerate()
            .map(|(i, s)| (s.as_ref(), i))
            .collect();
        let target_index: HashMap<&str, usize> = targets
            .iter()
            .enumerate()
            .map(|(i, s)| (s.as_ref(), i))
            .collect();
        let mut sources = vec![Vec::new(); targets.len()];
        let mut mapped = vec![false; shapes.len()];
        let mut unused_rows = Vec::new();
        for (shape, target) in &self.rows {
            match (
                shape_index.get(shape.as_str()),
                target_index.get(target.as_str()),
            ) {
                (Some(&s), Some(&t)) => {
                    sources[t].push(s);
                    mapped[s] = true;
                }
                _ => unused_rows.push((shape.clone(), target.clone())),
            }
        }
        ResolvedMap {
            sources,
            unmapped_shapes: shapes
                .iter()
                .zip(&mapped)
                .filter(|(_, m)| !**m)
                .map(|(s, _)| s.as_ref().to_string())
                .collect(),
            unused_rows,
        }
    }

    /// Targets and the shapes mapped to each (sorted by target), for reports.
    pub fn by_target(&self) -> BTreeMap<&str, Vec<&str>> {
        let mut out: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
        for (s, t) in &self.rows {
            out.entry(t.as_str()).or_default().push(s.as_str());
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn configs() -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/namemaps")
    }

    /// The shipped maps: every target is an ARKit name; every built-in actor expression
    /// is mapped; the ICT map covers every ICT shape of the shipped manifest.
    #[test]
    fn shipped_maps_are_complete() {
        let actor_names =
            crate::dataset::actor::Actor::new(&crate::dataset::actor::ActorParams::default())
                .unwrap()
                .expression_names()
                .to_vec();
        for (file, shapes) in [
            (
                "builtin-arkit.csv",
                actor_names
                    .iter()
                    .map(|s| s.to_string())
                    .collect::<Vec<_>>(),
            ),
            ("ict-arkit.csv", ict_manifest_shapes()),
        ] {
            let map = NameMap::read_csv(&configs().join(file)).unwrap();
            let r = map.resolve(&shapes, &ARKIT_NAMES);
            assert!(r.unused_rows.is_empty(), "{file}: {:?}", r.unused_rows);
            assert!(
                r.unmapped_shapes.is_empty(),
                "{file}: {:?}",
                r.unmapped_shapes
            );
            for t in map.by_target().keys() {
                assert!(ARKIT_NAMES.contains(t), "{file}: {t}");
            }
        }
    }

    fn ict_manifest_shapes() -> Vec<String> {
        let text = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/datasets/ict-facekit.toml"),
        )
        .unwrap();
        text.lines()
            .filter_map(|l| l.trim().strip_prefix("name = \""))
            .map(|l| l.trim_end_matches('"').to_string())
            .collect()
    }

    #[test]
    fn several_shapes_to_one_target_average_and_errors_name_lines() {
        let map = NameMap::parse_csv(
            "shape,target\n# brows\nbIU_L,browInnerUp\nbIU_R,browInnerUp\nx,jawOpen\n",
            "m.csv",
        )
        .unwrap();
        let r = map.resolve(&["bIU_L", "bIU_R", "extra"], &ARKIT_NAMES);
        assert_eq!(r.unmapped_shapes, vec!["extra".to_string()]);
        assert_eq!(r.unused_rows.len(), 1);
        let v = r.apply(&[1.0, 0.0, 0.5]);
        assert_eq!(v[43], 0.5);
        assert_eq!(v.iter().sum::<f64>(), 0.5);
        let e = NameMap::parse_csv("shape,target\na,b\na,c\n", "m.csv").unwrap_err();
        assert!(e.to_string().starts_with("m.csv:3:"), "{e}");
        let e = NameMap::parse_csv("name,arkit\n", "m.csv").unwrap_err();
        assert!(e.to_string().contains("shape,target"), "{e}");
    }
}
