//! The actor's dataset of face shapes: manifest loading, unit conversion, caching, jaw
//! skinning, marker layouts and the built-in synthetic actor; a dataset named by a user
//! (a manifest or `builtin[:SEED]`, [`DatasetSpec`]).
//!
//! A [`Dataset`] is the neutral mesh plus named shapes sharing its topology, all in
//! millimetres in the head frame (the neutral's frame). It may carry a [`JawRig`] and per
//! shape [`JawPose`]s, which local geometric indexing uses to unskin the jaw (Cong et al.
//! 2019 §6).
//!
//! Depends on [`crate::mesh`] only.

pub mod actor;
pub mod cache;
pub mod manifest;
pub mod markers;
pub mod scale_check;
pub mod spec;

pub use cache::{LoadOptions, load_dataset};
pub use manifest::{DatasetError, Manifest, Units, write_dataset};
pub use markers::{Marker, MarkerLayout};
pub use scale_check::{ScaleMismatch, check_mesh_scale};
pub use spec::{DatasetLoadError, DatasetSpec, builtin_params};

use std::ops::RangeInclusive;

use nalgebra::{Isometry3, Matrix3, Point3, Translation3, Unit, UnitQuaternion, Vector3};

use crate::mesh::Mesh;

/// One shape of the dataset: the actor's face in one expression, in the neutral's topology.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Shape {
    /// Name of the shape (file stem, or the name given in the manifest).
    pub name: String,
    /// Vertex positions (#V), millimetres, head frame.
    pub positions: Vec<Point3<f64>>,
    /// Jaw pose of this shape when the dataset has a jaw rig and the pose is known.
    pub jaw: Option<JawPose>,
}

/// Pose of the jaw relative to the skull (Cong et al. 2019 §6: the jaw parameters θ).
///
/// The jaw transform is: rotate by `open_rad` about the rig's open axis and by
/// `lateral_rad` about its lateral axis, both through the pivot, then translate by
/// `forward_mm` along the rig's forward direction.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct JawPose {
    /// Opening rotation, radians (positive opens the mouth).
    pub open_rad: f64,
    /// Sideways rotation, radians (positive moves the chin toward the actor's left, +x).
    pub lateral_rad: f64,
    /// Protrusion, millimetres (positive moves the jaw forward).
    pub forward_mm: f64,
}

/// Linear-blend-skinned jaw: a rigid jaw transform mixed with the identity per vertex.
///
/// A vertex `x` with weight `w` moves to `T(θ)·x = (1 − w)·x + w·J(θ)·x`, where `J(θ)` is
/// the rigid jaw transform of [`JawPose`]. `T(θ)` is an affine map per vertex, invertible
/// for the poses a face makes, which is what unskinning (Cong et al. 2019 §6, the step
/// `b*_n = T(θ_n)^{-1} b_n`) needs.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct JawRig {
    /// Pivot of the jaw (the condyles' midpoint), millimetres, head frame.
    pub pivot: Point3<f64>,
    /// Axis of the opening rotation (right-handed; positive angle opens the mouth).
    pub open_axis: Unit<Vector3<f64>>,
    /// Axis of the sideways rotation.
    pub lateral_axis: Unit<Vector3<f64>>,
    /// Direction of protrusion.
    pub forward: Unit<Vector3<f64>>,
    /// Skinning weight of each vertex (#V), 0 (skull) to 1 (jaw).
    pub weights: Vec<f64>,
}

impl JawRig {
    /// The rigid jaw transform `J(θ)` in the head frame.
    pub fn jaw_transform(&self, pose: &JawPose) -> Isometry3<f64> {
        let rotation = UnitQuaternion::from_axis_angle(&self.lateral_axis, pose.lateral_rad)
            * UnitQuaternion::from_axis_angle(&self.open_axis, pose.open_rad);
        let about_pivot = Translation3::from(self.pivot.coords)
            * rotation
            * Translation3::from(-self.pivot.coords);
        Translation3::from(self.forward.into_inner() * pose.forward_mm) * about_pivot
    }

    /// The per-vertex affine skinning map `T(θ)` of vertex weight `w`, as (linear part,
    /// translation).
    fn blended(&self, jaw: &Isometry3<f64>, w: f64) -> (Matrix3<f64>, Vector3<f64>) {
        let r = jaw.rotation.to_rotation_matrix().into_inner();
        let a = Matrix3::identity() * (1.0 - w) + r * w;
        (a, jaw.translation.vector * w)
    }

    /// Skins `positions` (#V, unskinned) by `pose`: `T(θ)·x` per vertex.
    pub fn skin(&self, pose: &JawPose, positions: &[Point3<f64>]) -> Vec<Point3<f64>> {
        let jaw = self.jaw_transform(pose);
        positions
            .iter()
            .zip(&self.weights)
            .map(|(x, &w)| self.skin_point(&jaw, w, x))
            .collect()
    }

    /// Unskins `positions` (#V, skinned by `pose`): `T(θ)^{-1}·x` per vertex.
    ///
    /// Vertices whose blended map is singular (only possible for extreme poses) are left
    /// where they are.
    pub fn unskin(&self, pose: &JawPose, positions: &[Point3<f64>]) -> Vec<Point3<f64>> {
        let jaw = self.jaw_transform(pose);
        positions
            .iter()
            .zip(&self.weights)
            .map(|(x, &w)| self.unskin_point(&jaw, w, x))
            .collect()
    }

    /// `T(θ)·x` for one point with skinning weight `w`, given `J(θ)` from
    /// [`JawRig::jaw_transform`].
    pub fn skin_point(&self, jaw: &Isometry3<f64>, w: f64, x: &Point3<f64>) -> Point3<f64> {
        let (a, t) = self.blended(jaw, w);
        Point3::from(a * x.coords + t)
    }

    /// `T(θ)^{-1}·x` for one point with skinning weight `w`; `x` unchanged when singular.
    pub fn unskin_point(&self, jaw: &Isometry3<f64>, w: f64, x: &Point3<f64>) -> Point3<f64> {
        let (a, t) = self.blended(jaw, w);
        match a.try_inverse() {
            Some(inv) => Point3::from(inv * (x.coords - t)),
            None => *x,
        }
    }
}

/// A dataset of the actor's face shapes, all in millimetres in the head frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    /// Short name (manifest file stem, or `builtin-actor`).
    pub name: String,
    /// The neutral face (positions in millimetres), with its topology and UVs.
    pub neutral: Mesh,
    /// The shapes, in manifest order; each has the neutral's vertex count.
    pub shapes: Vec<Shape>,
    /// Vertices to reconstruct (inclusive range); the whole mesh when the manifest says
    /// nothing.
    pub face_vertices: RangeInclusive<u32>,
    /// Jaw rig, when the dataset provides one.
    pub jaw: Option<JawRig>,
}

impl Dataset {
    /// The dataset with every mesh subdivided `levels` times by the same stencil
    /// ([`crate::mesh::subdivide`]): for resolution studies, e.g. the ICT face at about
    /// 400k vertices. Original vertices keep their indices (marker layouts stay valid);
    /// the face region becomes the whole refined mesh, since the new vertices are numbered
    /// after the old ones; the jaw rig (per-vertex skinning weights) is not carried over.
    ///
    /// # Errors
    /// [`crate::mesh::MeshError`] when the neutral's topology cannot be refined.
    pub fn subdivided(
        &self,
        levels: usize,
        scheme: crate::mesh::SubdivisionScheme,
    ) -> Result<Self, crate::mesh::MeshError> {
        let steps = crate::mesh::subdivide_levels(&self.neutral, levels, scheme)?;
        let refine =
            |p: &[Point3<f64>]| steps.iter().fold(p.to_vec(), |acc, step| step.apply(&acc));
        let neutral = steps
            .last()
            .map_or_else(|| self.neutral.clone(), |s| s.mesh.clone());
        let shapes = self
            .shapes
            .iter()
            .map(|s| Shape {
                name: s.name.clone(),
                positions: refine(&s.positions),
                jaw: s.jaw,
            })
            .collect();
        let last = neutral.vertex_count().saturating_sub(1) as u32;
        Ok(Self {
            name: format!("{}-subdivided{levels}", self.name),
            face_vertices: if levels == 0 {
                self.face_vertices.clone()
            } else {
                0..=last
            },
            neutral,
            shapes,
            jaw: if levels == 0 { self.jaw.clone() } else { None },
        })
    }

    /// Number of vertices of the neutral (and of every shape).
    pub fn vertex_count(&self) -> usize {
        self.neutral.vertex_count()
    }

    /// Index of the shape called `name`.
    pub fn shape_index(&self, name: &str) -> Option<usize> {
        self.shapes.iter().position(|s| s.name == name)
    }

    /// Whether vertex `v` is one of the vertices to reconstruct.
    pub fn is_face_vertex(&self, v: u32) -> bool {
        self.face_vertices.contains(&v)
    }

    /// Displacement statistics of shape `i` against the neutral over the face vertices.
    ///
    /// # Panics
    /// If `i` is out of range (a caller bug).
    pub fn displacement_stats(&self, i: usize) -> DisplacementStats {
        let shape = &self.shapes[i];
        let mut d: Vec<f64> = self
            .face_vertex_indices()
            .map(|v| (shape.positions[v] - self.neutral.positions[v]).norm())
            .collect();
        DisplacementStats::from_distances(&mut d)
    }

    /// Iterates over the face vertices as `usize` indices (clipped to the mesh).
    pub fn face_vertex_indices(&self) -> impl Iterator<Item = usize> + '_ {
        let end = (*self.face_vertices.end() as usize).min(self.vertex_count().saturating_sub(1));
        (*self.face_vertices.start() as usize)..=end
    }
}

/// Summary of vertex displacements, millimetres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DisplacementStats {
    /// Mean displacement.
    pub mean_mm: f64,
    /// 95th percentile.
    pub p95_mm: f64,
    /// Largest displacement.
    pub max_mm: f64,
    /// Number of vertices that move more than 0.01 mm.
    pub moving: usize,
}

impl DisplacementStats {
    /// Statistics of a list of distances (reordered in place).
    pub fn from_distances(d: &mut [f64]) -> Self {
        if d.is_empty() {
            return Self {
                mean_mm: 0.0,
                p95_mm: 0.0,
                max_mm: 0.0,
                moving: 0,
            };
        }
        d.sort_by(f64::total_cmp);
        let n = d.len();
        Self {
            mean_mm: d.iter().sum::<f64>() / n as f64,
            p95_mm: d[((n as f64 * 0.95) as usize).min(n - 1)],
            max_mm: d[n - 1],
            moving: d.iter().filter(|&&x| x > 0.01).count(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rig() -> JawRig {
        JawRig {
            pivot: Point3::new(0.0, -20.0, -60.0),
            open_axis: Vector3::x_axis(),
            lateral_axis: Vector3::y_axis(),
            forward: Vector3::z_axis(),
            weights: vec![0.0, 0.3, 1.0],
        }
    }

    #[test]
    fn skin_then_unskin_is_identity() {
        let rig = rig();
        let pose = JawPose {
            open_rad: 0.25,
            lateral_rad: -0.05,
            forward_mm: 2.0,
        };
        let pts = vec![
            Point3::new(1.0, 2.0, 3.0),
            Point3::new(10.0, -40.0, 30.0),
            Point3::new(-5.0, -70.0, 20.0),
        ];
        let skinned = rig.skin(&pose, &pts);
        assert_eq!(skinned[0], pts[0]);
        assert!((skinned[2] - pts[2]).norm() > 5.0);
        let back = rig.unskin(&pose, &skinned);
        for (a, b) in back.iter().zip(&pts) {
            assert!((a - b).norm() < 1e-9);
        }
    }

    #[test]
    fn jaw_rotation_keeps_pivot() {
        let rig = rig();
        let j = rig.jaw_transform(&JawPose {
            open_rad: 0.3,
            lateral_rad: 0.1,
            forward_mm: 0.0,
        });
        assert!((j * rig.pivot - rig.pivot).norm() < 1e-12);
    }
}
