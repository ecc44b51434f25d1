//! `face_skel.usda`: the rig weights of a take as a UsdSkel blend-shape animation, the
//! form Unreal, Maya and Blender import as a mesh with shape keys and animated weights
//! (Pixar, "UsdSkel: Blend Shapes"):
//!
//! ```text
//! /Face                SkelRoot; head pose as a time-sampled xformOp:transform
//! /Face/Skel           Skeleton (one joint, `head`, identity bind/rest)
//! /Face/Skel/Anim      SkelAnimation: blendShapes, time-sampled blendShapeWeights
//! /Face/face           Mesh: the rig's neutral (topology, UVs), SkelBindingAPI,
//!                      skel:blendShapes / skel:blendShapeTargets, bound to the head joint
//! /Face/face/<shape>   BlendShape: offsets from the neutral at the vertices it moves
//!                      (pointIndices), mm
//! ```
//!
//! Stage metadata as `mesh.usda`: `metersPerUnit = 0.001`, `upAxis = "Y"`,
//! `timeCodesPerSecond` = `framesPerSecond` = the camera rate, time code = frame index.
//! UsdSkel's posed points at a time are the neutral plus Σ weight · offsets, i.e. the rig
//! evaluated at that frame's weights; the head pose (relative to the first posed frame,
//! as in `mesh.usda`) moves the whole SkelRoot.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Isometry3;

use super::usd::usd_matrix;
use crate::mesh::Mesh;
use crate::pipeline::SinkError;

/// Offsets below this length (mm) are left out of a blend shape's `pointIndices`.
const OFFSET_EPSILON_MM: f64 = 1e-6;

/// A shape name as a USD prim name (letters, digits, `_`; not starting with a digit).
fn prim_name(name: &str) -> String {
    let mut s: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    if s.is_empty() || s.starts_with(|c: char| c.is_ascii_digit()) {
        s.insert(0, '_');
    }
    s
}

fn float(x: f64) -> String {
    let v = x as f32;
    if v == v.trunc() && v.abs() < 1e9 {
        format!("{v:.1}")
    } else {
        format!("{v}")
    }
}

/// One frame of a skeletal animation: (frame index, weights in the rig's shape order,
/// head pose `first_from_head` when the frame has one).
pub type SkelFrame = (usize, Vec<f64>, Option<Isometry3<f64>>);

/// Writes `face_skel.usda` atomically.
///
/// `names`: the rig's shapes; `offsets(s)`: shape `s`'s displacement of every vertex
/// (flattened xyz, mm); `frames`: (frame index, weights in `names` order, head pose
/// `first_from_head` when the frame has one).
///
/// # Errors
/// [`SinkError::Io`] naming the file; [`SinkError::Other`] when no frame is given or
/// an offsets slice does not cover the mesh.
pub fn write_face_skel<'a>(
    path: &Path,
    neutral: &Mesh,
    names: &[String],
    offsets: impl Fn(usize) -> Option<&'a [f64]>,
    frames: &[SkelFrame],
    fps: f64,
) -> Result<(), SinkError> {
    let (Some(first), Some(last)) = (frames.first(), frames.last()) else {
        return Err(SinkError::Other("face_skel.usda: no frames".into()));
    };
    let prims: Vec<String> = names.iter().map(|n| prim_name(n)).collect();
    let tokens: Vec<String> = prims.iter().map(|p| format!("\"{p}\"")).collect();
    let mut o = String::new();
    let _ = writeln!(o, "#usda 1.0\n(");
    let _ = writeln!(o, "    defaultPrim = \"Face\"");
    let _ = writeln!(o, "    endTimeCode = {}", last.0);
    let _ = writeln!(o, "    framesPerSecond = {}", float(fps));
    let _ = writeln!(o, "    metersPerUnit = 0.001");
    let _ = writeln!(o, "    startTimeCode = {}", first.0);
    let _ = writeln!(o, "    timeCodesPerSecond = {}", float(fps));
    let _ = writeln!(o, "    upAxis = \"Y\"");
    let _ = writeln!(o, ")\n");
    let _ = writeln!(
        o,
        "def SkelRoot \"Face\" (\n    kind = \"component\"\n)\n{{"
    );
    let posed: Vec<_> = frames
        .iter()
        .filter_map(|(f, _, p)| p.map(|p| (*f, p)))
        .collect();
    if !posed.is_empty() {
        let _ = writeln!(o, "    matrix4d xformOp:transform.timeSamples = {{");
        for (f, p) in &posed {
            let _ = writeln!(o, "        {f}: {},", usd_matrix(p));
        }
        let _ = writeln!(o, "    }}");
        let _ = writeln!(
            o,
            "    uniform token[] xformOpOrder = [\"xformOp:transform\"]"
        );
    }
    let identity = "( (1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1) )";
    let _ = writeln!(
        o,
        "\n    def Skeleton \"Skel\" (\n        prepend apiSchemas = [\"SkelBindingAPI\"]\n    )\n    {{"
    );
    let _ = writeln!(
        o,
        "        uniform matrix4d[] bindTransforms = [{identity}]"
    );
    let _ = writeln!(o, "        uniform token[] joints = [\"head\"]");
    let _ = writeln!(
        o,
        "        uniform matrix4d[] restTransforms = [{identity}]"
    );
    let _ = writeln!(o, "        rel skel:animationSource = </Face/Skel/Anim>");
    let _ = writeln!(o, "\n        def SkelAnimation \"Anim\"\n        {{");
    let _ = writeln!(
        o,
        "            uniform token[] blendShapes = [{}]",
        tokens.join(", ")
    );
    let _ = writeln!(o, "            float[] blendShapeWeights.timeSamples = {{");
    for (f, w, _) in frames {
        let ws: Vec<String> = w.iter().map(|x| float(*x)).collect();
        let _ = writeln!(o, "                {f}: [{}],", ws.join(", "));
    }
    let _ = writeln!(o, "            }}");
    let _ = writeln!(o, "            uniform token[] joints = [\"head\"]");
    let _ = writeln!(o, "            quatf[] rotations = [(1, 0, 0, 0)]");
    let _ = writeln!(o, "            half3[] scales = [(1, 1, 1)]");
    let _ = writeln!(o, "            float3[] translations = [(0, 0, 0)]");
    let _ = writeln!(o, "        }}\n    }}\n");
    let _ = writeln!(
        o,
        "    def Mesh \"face\" (\n        prepend apiSchemas = [\"SkelBindingAPI\"]\n    )\n    {{"
    );
    let counts: Vec<String> = neutral.faces().map(|p| p.len().to_string()).collect();
    let _ = writeln!(
        o,
        "        int[] faceVertexCounts = [{}]",
        counts.join(", ")
    );
    let idx: Vec<String> = neutral.face_vertices.iter().map(u32::to_string).collect();
    let _ = writeln!(o, "        int[] faceVertexIndices = [{}]", idx.join(", "));
    if let Some((lo, hi)) = neutral.bounding_box() {
        let _ = writeln!(
            o,
            "        float3[] extent = [({}, {}, {}), ({}, {}, {})]",
            float(lo.x),
            float(lo.y),
            float(lo.z),
            float(hi.x),
            float(hi.y),
            float(hi.z)
        );
    }
    let _ = writeln!(o, "        uniform token orientation = \"rightHanded\"");
    let pts: Vec<String> = neutral
        .positions
        .iter()
        .map(|p| format!("({}, {}, {})", float(p.x), float(p.y), float(p.z)))
        .collect();
    let _ = writeln!(o, "        point3f[] points = [{}]", pts.join(", "));
    if neutral.has_uvs() {
        let uvs: Vec<String> = neutral
            .uvs
            .iter()
            .map(|t| format!("({}, {})", float(t.x), float(t.y)))
            .collect();
        let _ = writeln!(
            o,
            "        texCoord2f[] primvars:st = [{}] (\n            interpolation = \"faceVarying\"\n        )",
            uvs.join(", ")
        );
        let ui: Vec<String> = neutral.face_uvs.iter().map(u32::to_string).collect();
        let _ = writeln!(o, "        int[] primvars:st:indices = [{}]", ui.join(", "));
    }
    let _ = writeln!(
        o,
        "        matrix4d primvars:skel:geomBindTransform = {identity}"
    );
    let _ = writeln!(
        o,
        "        int[] primvars:skel:jointIndices = [0] (\n            elementSize = 1\n            interpolation = \"constant\"\n        )"
    );
    let _ = writeln!(
        o,
        "        float[] primvars:skel:jointWeights = [1] (\n            elementSize = 1\n            interpolation = \"constant\"\n        )"
    );
    let _ = writeln!(
        o,
        "        uniform token[] skel:blendShapes = [{}]",
        tokens.join(", ")
    );
    let targets: Vec<String> = prims.iter().map(|p| format!("</Face/face/{p}>")).collect();
    let _ = writeln!(
        o,
        "        rel skel:blendShapeTargets = [{}]",
        targets.join(", ")
    );
    let _ = writeln!(o, "        rel skel:skeleton = </Face/Skel>");
    let _ = writeln!(o, "        uniform token subdivisionScheme = \"none\"");
    let n = neutral.vertex_count();
    for (s, prim) in prims.iter().enumerate() {
        let d = offsets(s).filter(|d| d.len() == 3 * n).ok_or_else(|| {
            SinkError::Other(format!("shape {prim}: offsets do not cover the mesh"))
        })?;
        let mut idx = Vec::new();
        let mut off = Vec::new();
        for (v, c) in d.chunks_exact(3).enumerate() {
            if c.iter().map(|x| x * x).sum::<f64>().sqrt() > OFFSET_EPSILON_MM {
                idx.push(v.to_string());
                off.push(format!(
                    "({}, {}, {})",
                    float(c[0]),
                    float(c[1]),
                    float(c[2])
                ));
            }
        }
        let _ = writeln!(o, "\n        def BlendShape \"{prim}\"\n        {{");
        let _ = writeln!(
            o,
            "            uniform vector3f[] offsets = [{}]",
            off.join(", ")
        );
        let _ = writeln!(
            o,
            "            uniform int[] pointIndices = [{}]",
            idx.join(", ")
        );
        let _ = writeln!(o, "        }}");
    }
    let _ = writeln!(o, "    }}\n}}");
    crate::atomic_file::write_atomically(path, |w| std::io::Write::write_all(w, o.as_bytes()))
        .map_err(|e| SinkError::io(path, e))
}
