//! Marker layouts: where the painted dots sit on the neutral face, read from and written to
//! the layout CSV, and generated automatically for a dataset.
//!
//! CSV contract: header `name,vertex,stabilize_weight`; one row per marker on a vertex of
//! the neutral mesh; `stabilize_weight` (0..1, optional, default 0) is how much the marker
//! counts for head stabilization.

use std::collections::HashSet;
use std::io::Write;
use std::path::Path;

use nalgebra::{Point3, Vector3};

use super::Dataset;
use crate::atomic_file::write_atomically;
use crate::file_error::FileError;
use crate::mesh::{Topology, vertex_normals};
use crate::mesh::{edge_graph_distances, update_edge_graph_distances};

/// Errors from reading, writing or generating a marker layout.
#[derive(Debug, thiserror::Error)]
pub enum MarkerError {
    /// The file could not be read or written, or a line of it is malformed.
    #[error(transparent)]
    File(#[from] FileError),
    /// The layout does not fit the dataset, or generation is impossible.
    #[error("{0}")]
    Invalid(String),
}

/// One painted marker.
#[derive(Debug, Clone, PartialEq)]
pub struct Marker {
    /// Unique name (the label in every output).
    pub name: String,
    /// Vertex of the neutral mesh the marker sits on.
    pub vertex: u32,
    /// Weight in head stabilization, 0 (ignored) to 1 (rigid with the skull).
    pub stabilize_weight: f64,
}

/// An ordered set of markers with unique names and vertices.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MarkerLayout {
    /// The markers, in file order.
    pub markers: Vec<Marker>,
}

impl MarkerLayout {
    /// Number of markers.
    pub fn len(&self) -> usize {
        self.markers.len()
    }

    /// Whether the layout has no markers.
    pub fn is_empty(&self) -> bool {
        self.markers.is_empty()
    }

    /// Number of markers that count for head stabilization with weight at least 0.5.
    pub fn stabilizing_count(&self) -> usize {
        self.markers
            .iter()
            .filter(|m| m.stabilize_weight >= 0.5)
            .count()
    }

    /// Index of the marker called `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.markers.iter().position(|m| m.name == name)
    }

    /// The layout shipped for the built-in actor (`configs/markers/builtin-actor.csv`).
    ///
    /// # Errors
    /// As [`MarkerLayout::parse_csv`] (none for the shipped file).
    pub fn builtin_actor() -> Result<Self, MarkerError> {
        Self::parse_csv(
            include_str!("../../configs/markers/builtin-actor.csv"),
            "builtin-actor.csv",
        )
    }

    /// Reads a layout CSV.
    ///
    /// # Errors
    /// [`MarkerError`] naming the file and line: missing or wrong header, a row with the
    /// wrong number of fields, a vertex that is not a non-negative integer, a weight outside
    /// 0..1 or not a number, a duplicate name or vertex, an empty layout.
    pub fn read_csv(path: &Path) -> Result<Self, MarkerError> {
        let text = std::fs::read_to_string(path).map_err(|source| {
            MarkerError::File(FileError::Io {
                path: path.display().to_string(),
                source,
            })
        })?;
        Self::parse_csv(&text, &path.display().to_string())
    }

    /// Parses layout CSV text; `name` stands for the file in errors.
    ///
    /// # Errors
    /// As [`MarkerLayout::read_csv`].
    pub fn parse_csv(text: &str, name: &str) -> Result<Self, MarkerError> {
        let err = |line: usize, message: String| {
            MarkerError::File(FileError::Parse {
                path: name.to_string(),
                line,
                message,
            })
        };
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
        let (hline, header) = lines.next().ok_or_else(|| {
            err(
                1,
                "empty file: expected header name,vertex,stabilize_weight".into(),
            )
        })?;
        let cols: Vec<&str> = header.split(',').map(str::trim).collect();
        if cols.len() < 2 || cols[0] != "name" || cols[1] != "vertex" {
            return Err(err(
                hline,
                format!(
                    "header {} should be name,vertex,stabilize_weight",
                    crate::limits::quoted(header)
                ),
            ));
        }
        let weight_col = cols.iter().position(|c| *c == "stabilize_weight");
        let mut markers = Vec::new();
        let mut names = HashSet::new();
        let mut vertices = HashSet::new();
        for (line, row) in lines {
            let fields: Vec<&str> = row.split(',').map(str::trim).collect();
            if fields.len() < 2 || fields.len() > cols.len() {
                return Err(err(
                    line,
                    format!("expected {} fields, found {}", cols.len(), fields.len()),
                ));
            }
            let name = fields[0];
            if name.is_empty() {
                return Err(err(line, "empty marker name".into()));
            }
            let vertex: u32 = fields[1].parse().map_err(|_| {
                err(
                    line,
                    format!(
                        "vertex {} is not a vertex index",
                        crate::limits::quoted(fields[1])
                    ),
                )
            })?;
            let stabilize_weight = match weight_col.and_then(|c| fields.get(c)) {
                None | Some(&"") => 0.0,
                Some(w) => match w.parse::<f64>() {
                    Ok(x) if (0.0..=1.0).contains(&x) => x,
                    _ => {
                        return Err(err(
                            line,
                            format!(
                                "stabilize_weight {} is not a number in 0..1",
                                crate::limits::quoted(w)
                            ),
                        ));
                    }
                },
            };
            if !names.insert(name.to_string()) {
                return Err(err(
                    line,
                    format!("marker name {} appears twice", crate::limits::quoted(name)),
                ));
            }
            if !vertices.insert(vertex) {
                return Err(err(line, format!("vertex {vertex} carries two markers")));
            }
            markers.push(Marker {
                name: name.to_string(),
                vertex,
                stabilize_weight,
            });
        }
        if markers.is_empty() {
            return Err(err(hline, "the layout has no markers".into()));
        }
        Ok(MarkerLayout { markers })
    }

    /// Writes the layout CSV atomically.
    ///
    /// # Errors
    /// [`FileError::Io`] when the file cannot be written.
    pub fn write_csv(&self, path: &Path) -> Result<(), MarkerError> {
        write_atomically(path, |w| {
            writeln!(w, "name,vertex,stabilize_weight")?;
            for m in &self.markers {
                writeln!(w, "{},{},{}", m.name, m.vertex, m.stabilize_weight)?;
            }
            Ok(())
        })
        .map_err(|source| {
            MarkerError::File(FileError::Io {
                path: path.display().to_string(),
                source,
            })
        })
    }

    /// The unit normal of `dataset`'s neutral face at each marker (head frame, layout
    /// order), from the mesh's vertex normals: how round each painted dot can look from a
    /// camera ([`crate::track::Labeler::set_marker_normals`]). A marker on a vertex
    /// without a normal gets the zero vector (its roundness is then not checked).
    pub fn neutral_normals(&self, dataset: &Dataset) -> Vec<Vector3<f64>> {
        let normals = vertex_normals(&dataset.neutral);
        self.markers
            .iter()
            .map(|m| {
                normals
                    .get(m.vertex as usize)
                    .copied()
                    .unwrap_or_else(Vector3::zeros)
            })
            .collect()
    }

    /// The markers' positions (head frame, layout order) on each of `dataset`'s shapes,
    /// and half-way between the neutral and each shape: the expressions marker labeling
    /// may find the face in when it starts from nothing
    /// ([`crate::track::Labeler::set_expression_templates`]). Markers on vertices the
    /// shapes do not have are left at their neutral positions.
    pub fn expression_templates(&self, dataset: &Dataset) -> Vec<Vec<Point3<f64>>> {
        let neutral = &dataset.neutral.positions;
        let at = |positions: &[Point3<f64>], v: u32| {
            positions
                .get(v as usize)
                .or_else(|| neutral.get(v as usize))
                .copied()
                .unwrap_or_else(Point3::origin)
        };
        let mut out = Vec::with_capacity(2 * dataset.shapes.len());
        for shape in &dataset.shapes {
            let full: Vec<Point3<f64>> = self
                .markers
                .iter()
                .map(|m| at(&shape.positions, m.vertex))
                .collect();
            let half = self
                .markers
                .iter()
                .zip(&full)
                .map(|(m, q)| at(neutral, m.vertex) + (q - at(neutral, m.vertex)) * 0.5)
                .collect();
            out.push(half);
            out.push(full);
        }
        out
    }

    /// Checks that every marker sits on a face vertex of `dataset`.
    ///
    /// # Errors
    /// [`MarkerError::Invalid`] naming the first marker that does not.
    pub fn validate_for(&self, dataset: &Dataset) -> Result<(), MarkerError> {
        for m in &self.markers {
            if m.vertex as usize >= dataset.vertex_count() {
                return Err(MarkerError::Invalid(format!(
                    "marker {} is on vertex {} but dataset {} has {} vertices",
                    m.name,
                    m.vertex,
                    dataset.name,
                    dataset.vertex_count()
                )));
            }
            if !dataset.is_face_vertex(m.vertex) {
                return Err(MarkerError::Invalid(format!(
                    "marker {} is on vertex {}, outside the face vertices {}..{} of dataset {}",
                    m.name,
                    m.vertex,
                    dataset.face_vertices.start(),
                    dataset.face_vertices.end(),
                    dataset.name
                )));
            }
        }
        Ok(())
    }
}

/// Parameters of [`generate_layout`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LayoutParams {
    /// Number of markers. Default 120 (a typical helmet-capture layout).
    pub count: usize,
    /// Smallest distance along the mesh from the edge of the face region (eyelid margins,
    /// inner lips, the outer border of the face area), millimetres: dots cannot be painted
    /// or tracked there. Default 5 mm.
    pub min_border_distance_mm: f64,
    /// Largest angle between a marker's normal and the forward axis (+z of the head frame,
    /// toward the helmet cameras), degrees: dots facing away are foreshortened to slivers or
    /// not seen at all. Default 60° (a dot seen at 60° is still half as wide as it is tall).
    pub max_view_angle_deg: f64,
    /// Motion scale σ of the stabilization weight `w = exp(−(m/σ)²)`, where `m` is the
    /// root-mean-square displacement of the marker's vertex over the dataset's shapes,
    /// millimetres; weights under 0.05 become 0. With the default 1 mm, the nose bridge and
    /// temples (moved by almost nothing) get about 1, the forehead (moved only by the brow
    /// shapes) 0.5 to 1, cheeks and lips low, and chin and jaw (moved by the jaw shapes) 0.
    /// Default 1 mm.
    pub stabilize_scale_mm: f64,
    /// Vertices markers may go on (inclusive range), within the dataset's face vertices;
    /// `None` means all face vertices. For ICT-FaceKit, `0..=6705` is the face without ears
    /// and neck. Default `None`.
    pub region: Option<std::ops::RangeInclusive<u32>>,
}

impl Default for LayoutParams {
    fn default() -> Self {
        Self {
            count: 120,
            min_border_distance_mm: 5.0,
            max_view_angle_deg: 60.0,
            stabilize_scale_mm: 1.0,
            region: None,
        }
    }
}

impl LayoutParams {
    /// Checks every field's range.
    ///
    /// # Errors
    /// [`MarkerError::Invalid`] naming the field.
    pub fn validate(&self) -> Result<(), MarkerError> {
        let bad =
            |f: &str, v: String| Err(MarkerError::Invalid(format!("{f} = {v} is out of range")));
        if self.count == 0 {
            return bad("count", "0".into());
        }
        if !(self.min_border_distance_mm >= 0.0 && self.min_border_distance_mm.is_finite()) {
            return bad(
                "min_border_distance_mm",
                self.min_border_distance_mm.to_string(),
            );
        }
        if !(self.max_view_angle_deg > 0.0 && self.max_view_angle_deg <= 180.0) {
            return bad("max_view_angle_deg", self.max_view_angle_deg.to_string());
        }
        if !(self.stabilize_scale_mm > 0.0 && self.stabilize_scale_mm.is_finite()) {
            return bad("stabilize_scale_mm", self.stabilize_scale_mm.to_string());
        }
        Ok(())
    }
}

/// Vertices where a marker may be painted: face vertices (within `params.region` when
/// given) used by a triangle, at least
/// `min_border_distance_mm` along the mesh from the face region's border, facing the
/// cameras within `max_view_angle_deg`. Returned ascending.
///
/// The face region's border is every face vertex on a mesh boundary edge or joined by an
/// edge to a non-face vertex: eyelid margins, the lip line (or where the lips turn into the
/// mouth socket), and the outer border of the face area.
pub fn paintable_vertices(
    dataset: &Dataset,
    topology: &Topology,
    params: &LayoutParams,
) -> Vec<u32> {
    let mesh = &dataset.neutral;
    let n = mesh.vertex_count();
    let mut used = vec![false; n];
    for t in &mesh.triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    let on_boundary = topology.boundary_vertex_mask();
    let mut border = Vec::new();
    for v in dataset.face_vertex_indices() {
        if !used[v] {
            continue;
        }
        let on_border = on_boundary[v]
            || topology
                .neighbors(v as u32)
                .iter()
                .any(|&u| !dataset.is_face_vertex(u));
        if on_border {
            border.push(v as u32);
        }
    }
    let dist = edge_graph_distances(mesh, topology, &border, f64::INFINITY);
    let normals = vertex_normals(mesh);
    let cos_max = params.max_view_angle_deg.to_radians().cos();
    let forward = Vector3::z();
    dataset
        .face_vertex_indices()
        .filter(|&v| {
            used[v]
                && params
                    .region
                    .as_ref()
                    .is_none_or(|r| r.contains(&(v as u32)))
                && dist[v] >= params.min_border_distance_mm
                && normals[v].dot(&forward) >= cos_max
        })
        .map(|v| v as u32)
        .collect()
}

/// Generates a marker layout for `dataset`: `params.count` markers spread evenly over the
/// paintable face (see [`paintable_vertices`]) by farthest-point sampling with distances
/// along the mesh edges, each weighted for stabilization by how little it moves across the
/// dataset's shapes.
///
/// Deterministic: sampling starts at the paintable vertex nearest the paintable area's
/// centroid and ties go to the lower vertex index. Markers are named `M001`, `M002`, ...
/// from the top of the face down (then from the actor's right to left).
///
/// # Errors
/// [`MarkerError::Invalid`] when `params` is invalid or fewer than `params.count` vertices
/// are paintable.
pub fn generate_layout(
    dataset: &Dataset,
    params: &LayoutParams,
) -> Result<MarkerLayout, MarkerError> {
    params.validate()?;
    let mesh = &dataset.neutral;
    let topology = Topology::new(mesh);
    let candidates = paintable_vertices(dataset, &topology, params);
    if candidates.len() < params.count {
        return Err(MarkerError::Invalid(format!(
            "only {} paintable vertices in dataset {} for {} markers (lower --count or \
             --min-border-distance)",
            candidates.len(),
            dataset.name,
            params.count
        )));
    }
    let centroid = candidates
        .iter()
        .map(|&v| mesh.positions[v as usize].coords)
        .sum::<Vector3<f64>>()
        / candidates.len() as f64;
    let first = candidates
        .iter()
        .copied()
        .min_by(|&a, &b| {
            let da = (mesh.positions[a as usize].coords - centroid).norm_squared();
            let db = (mesh.positions[b as usize].coords - centroid).norm_squared();
            da.total_cmp(&db).then(a.cmp(&b))
        })
        .ok_or_else(|| MarkerError::Invalid("no paintable vertex".into()))?;
    let mut chosen = vec![first];
    let mut dist = vec![f64::INFINITY; mesh.vertex_count()];
    update_edge_graph_distances(mesh, &topology, first, &mut dist);
    while chosen.len() < params.count {
        // Farthest candidate from everything chosen; unreachable candidates (another
        // component) count as farthest, so every component gets markers.
        let mut best = None;
        let mut best_d = -1.0;
        for &c in &candidates {
            let d = dist[c as usize];
            if d > best_d {
                best_d = d;
                best = Some(c);
            }
        }
        let Some(next) = best.filter(|_| best_d > 0.0) else {
            break;
        };
        chosen.push(next);
        update_edge_graph_distances(mesh, &topology, next, &mut dist);
    }

    let motion = vertex_motion(dataset);
    let mut markers: Vec<(u32, f64)> = chosen
        .into_iter()
        .map(|v| {
            let m = motion[v as usize];
            let w = (-(m / params.stabilize_scale_mm).powi(2)).exp();
            let w = if w < 0.05 {
                0.0
            } else {
                (w * 100.0).round() / 100.0
            };
            (v, w)
        })
        .collect();
    markers.sort_by(|a, b| {
        let pa = mesh.positions[a.0 as usize];
        let pb = mesh.positions[b.0 as usize];
        pb.y.total_cmp(&pa.y).then(pa.x.total_cmp(&pb.x))
    });
    Ok(MarkerLayout {
        markers: markers
            .into_iter()
            .enumerate()
            .map(|(i, (vertex, stabilize_weight))| Marker {
                name: format!("M{:03}", i + 1),
                vertex,
                stabilize_weight,
            })
            .collect(),
    })
}

/// How much each vertex moves with expression: the root-mean-square over the dataset's
/// shapes of its displacement from the neutral, millimetres (#V). Zero for a dataset
/// without shapes.
pub fn vertex_motion(dataset: &Dataset) -> Vec<f64> {
    let n = dataset.vertex_count();
    let k = dataset.shapes.len();
    if k == 0 {
        return vec![0.0; n];
    }
    (0..n)
        .map(|v| {
            let sum: f64 = dataset
                .shapes
                .iter()
                .map(|s| (s.positions[v] - dataset.neutral.positions[v]).norm_squared())
                .sum();
            (sum / k as f64).sqrt()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_round_trip_and_errors() {
        let text = "name,vertex,stabilize_weight\nA,3,0.5\nB,7,\nC,9,1\n";
        let l = MarkerLayout::parse_csv(text, "t.csv").unwrap();
        assert_eq!(l.len(), 3);
        assert_eq!(l.markers[1].stabilize_weight, 0.0);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("m.csv");
        l.write_csv(&p).unwrap();
        assert_eq!(MarkerLayout::read_csv(&p).unwrap(), l);

        let no_weight = MarkerLayout::parse_csv("name,vertex\nA,1\n", "t").unwrap();
        assert_eq!(no_weight.markers[0].stabilize_weight, 0.0);

        for (bad, line, what) in [
            ("", 1, "empty"),
            ("vertex,name\nA,1\n", 1, "header"),
            ("name,vertex\nA,x\n", 2, "vertex"),
            ("name,vertex,stabilize_weight\nA,1,1.5\n", 2, "0..1"),
            ("name,vertex,stabilize_weight\nA,1,nan\n", 2, "0..1"),
            ("name,vertex\nA,1\nA,2\n", 3, "twice"),
            ("name,vertex\nA,1\nB,1\n", 3, "two markers"),
            ("name,vertex\n", 1, "no markers"),
        ] {
            let e = MarkerLayout::parse_csv(bad, "t.csv").unwrap_err();
            let msg = e.to_string();
            assert!(msg.contains(&format!("t.csv:{line}:")), "{msg}");
            assert!(msg.contains(what), "{msg} should mention {what}");
        }
    }

    #[test]
    fn params_are_validated() {
        assert!(LayoutParams::default().validate().is_ok());
        let p = LayoutParams {
            stabilize_scale_mm: 0.0,
            ..Default::default()
        };
        assert!(
            p.validate()
                .unwrap_err()
                .to_string()
                .contains("stabilize_scale_mm")
        );
    }
}

#[cfg(test)]
mod ict_tests {
    use super::*;
    use crate::dataset::{LoadOptions, load_dataset};

    /// The ICT-FaceKit dataset, or `None` (with the reason printed) when the data is absent.
    fn ict() -> Option<Dataset> {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        if !root
            .join("../shared/data/ict-facekit/generic_neutral_mesh.obj")
            .is_file()
        {
            eprintln!("skipped: ICT-FaceKit data not found at ../shared/data/ict-facekit");
            return None;
        }
        let manifest = root.join("configs/datasets/ict-facekit.toml");
        Some(
            load_dataset(
                &manifest,
                &LoadOptions {
                    no_cache: true,
                    ..Default::default()
                },
            )
            .unwrap(),
        )
    }

    #[test]
    fn ict_layout_is_deterministic_spread_and_weighted_by_motion() {
        let Some(ds) = ict() else { return };
        let params = LayoutParams {
            region: Some(0..=6705),
            ..LayoutParams::default()
        };
        let a = generate_layout(&ds, &params).unwrap();
        let b = generate_layout(&ds, &params).unwrap();
        assert_eq!(a, b, "generation must be deterministic");
        assert_eq!(a.len(), 120);
        a.validate_for(&ds).unwrap();

        // Exclusions: every marker is paintable (far from the face border, facing forward).
        let topo = Topology::new(&ds.neutral);
        let paintable = paintable_vertices(&ds, &topo, &params);
        for m in &a.markers {
            assert!(
                paintable.binary_search(&m.vertex).is_ok(),
                "{} not paintable",
                m.name
            );
        }
        // ... and the border really is avoided: no marker within 5 mm of the lip line or an
        // eyelid margin, measured independently from the mesh boundary + non-face vertices.
        let mut border = Vec::new();
        let mask = topo.boundary_vertex_mask();
        for v in ds.face_vertex_indices() {
            if mask[v]
                || topo
                    .neighbors(v as u32)
                    .iter()
                    .any(|&u| !ds.is_face_vertex(u))
            {
                border.push(v as u32);
            }
        }
        let d = edge_graph_distances(&ds.neutral, &topo, &border, f64::INFINITY);
        for m in &a.markers {
            assert!(d[m.vertex as usize] >= 5.0 - 1e-9);
        }

        // Spread: nearest-neighbour spacing along the mesh is even (no clumps). Distances
        // are along the surface: an upper-lip and a lower-lip marker may be close in space.
        let nn: Vec<f64> = a
            .markers
            .iter()
            .map(|m| {
                let d = edge_graph_distances(&ds.neutral, &topo, &[m.vertex], f64::INFINITY);
                a.markers
                    .iter()
                    .filter(|o| o.vertex != m.vertex)
                    .map(|o| d[o.vertex as usize])
                    .fold(f64::INFINITY, f64::min)
            })
            .collect();
        let mean_nn = nn.iter().sum::<f64>() / nn.len() as f64;
        let min_nn = nn.iter().copied().fold(f64::INFINITY, f64::min);
        eprintln!("ICT layout: nearest-neighbour spacing mean {mean_nn:.1} mm, min {min_nn:.1} mm");
        assert!(
            min_nn > 0.6 * mean_nn,
            "markers clump: min {min_nn} vs mean {mean_nn}"
        );
        let (lo, hi) = a.markers.iter().fold(
            (ds.neutral.positions[0], ds.neutral.positions[0]),
            |(lo, hi), m| {
                let p = ds.neutral.positions[m.vertex as usize];
                (lo.inf(&p), hi.sup(&p))
            },
        );
        eprintln!("ICT layout: markers span {lo:?} to {hi:?}");

        // Weights follow motion: stable markers barely move, and the stable set sits above
        // the mouth (forehead, nose bridge, temples) while the mouth markers get 0.
        let motion = vertex_motion(&ds);
        let stable: Vec<&Marker> = a
            .markers
            .iter()
            .filter(|m| m.stabilize_weight >= 0.5)
            .collect();
        let zero: Vec<&Marker> = a
            .markers
            .iter()
            .filter(|m| m.stabilize_weight == 0.0)
            .collect();
        eprintln!(
            "ICT layout: {} stable, {} zero-weight markers",
            stable.len(),
            zero.len()
        );
        assert!(
            stable.len() >= 10,
            "too few stabilizing markers: {}",
            stable.len()
        );
        assert!(!zero.is_empty());
        for m in &stable {
            assert!(motion[m.vertex as usize] < 1.5);
        }
        let mean_y = |ms: &[&Marker]| {
            ms.iter()
                .map(|m| ds.neutral.positions[m.vertex as usize].y)
                .sum::<f64>()
                / ms.len() as f64
        };
        assert!(mean_y(&stable) > mean_y(&zero) + 20.0);
    }
}

#[cfg(test)]
mod actor_tests {
    use super::*;
    use crate::dataset::actor::{Actor, ActorParams, Region};
    use crate::mesh::edge_graph_distances;

    #[test]
    fn builtin_actor_layout_respects_count_exclusions_and_motion() {
        let actor = Actor::new(&ActorParams::default()).unwrap();
        let ds = actor.to_dataset();
        let params = LayoutParams::default();
        let layout = generate_layout(&ds, &params).unwrap();
        assert_eq!(layout.len(), params.count);
        assert_eq!(layout, generate_layout(&ds, &params).unwrap());
        layout.validate_for(&ds).unwrap();

        // No marker within 5 mm (along the mesh) of the eye and mouth openings.
        let topo = Topology::new(&ds.neutral);
        let mask = topo.boundary_vertex_mask();
        let openings: Vec<u32> = ds
            .face_vertex_indices()
            .filter(|&v| mask[v])
            .map(|v| v as u32)
            .collect();
        let d = edge_graph_distances(&ds.neutral, &topo, &openings, f64::INFINITY);
        let regions = actor.regions();
        for m in &layout.markers {
            assert!(
                d[m.vertex as usize] >= 5.0,
                "{} is {} mm from an opening",
                m.name,
                d[m.vertex as usize]
            );
            assert!(regions[m.vertex as usize].is_face());
        }

        // Weights by region: skull-rigid regions high, mouth and jaw zero.
        let mean_weight = |wanted: &[Region]| {
            let w: Vec<f64> = layout
                .markers
                .iter()
                .filter(|m| wanted.contains(&regions[m.vertex as usize]))
                .map(|m| m.stabilize_weight)
                .collect();
            assert!(!w.is_empty(), "no marker in {wanted:?}");
            w.iter().sum::<f64>() / w.len() as f64
        };
        let rigid = mean_weight(&[Region::Temple, Region::Nose]);
        let forehead = mean_weight(&[Region::Forehead]);
        let mouth = mean_weight(&[Region::UpperLip, Region::LowerLip, Region::Chin]);
        let jaw = mean_weight(&[Region::Jaw]);
        eprintln!(
            "builtin layout weights: temple+nose {rigid:.2}, forehead {forehead:.2}, \
             lips+chin {mouth:.2}, jaw {jaw:.2}"
        );
        assert!(rigid > 0.8, "{rigid}");
        assert!(forehead > 0.4, "{forehead}");
        assert!(mouth < 0.3, "{mouth}");
        // The weight follows the motion rule exactly, marker by marker.
        let motion = vertex_motion(&ds);
        for m in &layout.markers {
            let rms = motion[m.vertex as usize];
            if rms > 2.0 {
                assert_eq!(m.stabilize_weight, 0.0, "{} moves {rms} mm", m.name);
            }
            if rms < 0.1 {
                assert!(m.stabilize_weight >= 0.99, "{} moves {rms} mm", m.name);
            }
        }
        assert_eq!(jaw, 0.0, "the jaw moves with every jaw shape");
    }
}
