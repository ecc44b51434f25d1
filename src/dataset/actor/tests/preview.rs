//! Preview output for looking at the actor: OBJ text and shaded PPM renders written to
//! the system temp folder by an ignored test.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::{Point3, Vector3};

use super::*;

/// Minimal OBJ text (positions, UVs, polygons).
pub(super) fn obj_text(mesh: &Mesh, positions: &[Point3<f64>]) -> String {
    let mut s = String::new();
    for p in positions {
        let _ = writeln!(s, "v {:.4} {:.4} {:.4}", p.x, p.y, p.z);
    }
    for t in &mesh.uvs {
        let _ = writeln!(s, "vt {:.6} {:.6}", t.x, t.y);
    }
    for f in 0..mesh.face_count() {
        s.push('f');
        for (v, t) in mesh.face(f).iter().zip(mesh.face_uv(f)) {
            let _ = write!(s, " {}/{}", v + 1, t + 1);
        }
        s.push('\n');
    }
    s
}

/// Orthographic z-buffered Lambert render; `view` is the direction from the object to
/// the camera, `colour` an optional per-vertex tint.
pub(super) fn render(
    mesh: &Mesh,
    positions: &[Point3<f64>],
    view: Vector3<f64>,
    colour: Option<&dyn Fn(usize) -> [f64; 3]>,
    size: usize,
    centre: Point3<f64>,
    px_per_mm: f64,
) -> Vec<u8> {
    let fwd = -view.normalize();
    let up0 = Vector3::y();
    let right = fwd.cross(&up0).normalize();
    let up = right.cross(&fwd);
    let mut depth = vec![f64::INFINITY; size * size];
    let mut img = vec![30u8; size * size * 3];
    let proj = |p: &Point3<f64>| {
        let d = p - centre;
        (
            size as f64 * 0.5 + d.dot(&right) * px_per_mm,
            size as f64 * 0.5 - d.dot(&up) * px_per_mm,
            d.dot(&fwd),
        )
    };
    let light = (view.normalize() + 0.4 * up + 0.3 * right).normalize();
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let n = (b - a).cross(&(c - a));
        let Some(n) = n.try_normalize(1e-12) else {
            continue;
        };
        let shade = n.dot(&light).max(0.0) * 0.85 + 0.15;
        let back = n.dot(&view) < 0.0;
        let tint = match colour {
            Some(f) => {
                let ca = f(t[0] as usize);
                [ca[0], ca[1], ca[2]]
            }
            None => [0.93, 0.78, 0.68],
        };
        let pa = proj(&a);
        let pb = proj(&b);
        let pc = proj(&c);
        let minx = pa.0.min(pb.0).min(pc.0).floor().max(0.0) as usize;
        let maxx = (pa.0.max(pb.0).max(pc.0).ceil() as usize).min(size - 1);
        let miny = pa.1.min(pb.1).min(pc.1).floor().max(0.0) as usize;
        let maxy = (pa.1.max(pb.1).max(pc.1).ceil() as usize).min(size - 1);
        let area = (pb.0 - pa.0) * (pc.1 - pa.1) - (pc.0 - pa.0) * (pb.1 - pa.1);
        if area.abs() < 1e-12 {
            continue;
        }
        for y in miny..=maxy {
            for x in minx..=maxx {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                let w0 = ((pb.0 - px) * (pc.1 - py) - (pc.0 - px) * (pb.1 - py)) / area;
                let w1 = ((pc.0 - px) * (pa.1 - py) - (pa.0 - px) * (pc.1 - py)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * pa.2 + w1 * pb.2 + w2 * pc.2;
                let k = y * size + x;
                if z < depth[k] {
                    depth[k] = z;
                    let s = if back { 0.25 } else { shade };
                    for ch in 0..3 {
                        img[3 * k + ch] = (255.0 * (tint[ch] * s).clamp(0.0, 1.0)) as u8;
                    }
                }
            }
        }
    }
    img
}

/// Writes an RGB image as binary PPM.
pub(super) fn write_ppm(path: &Path, img: &[u8], size: usize) {
    let mut data = format!("P6\n{size} {size}\n255\n").into_bytes();
    data.extend_from_slice(img);
    std::fs::write(path, data).unwrap();
}

fn region_colour(r: Region) -> [f64; 3] {
    match r {
        Region::Forehead => [0.9, 0.8, 0.6],
        Region::BrowL | Region::BrowR => [0.6, 0.4, 0.2],
        Region::EyelidUpperL | Region::EyelidUpperR => [0.9, 0.5, 0.9],
        Region::EyelidLowerL | Region::EyelidLowerR => [0.6, 0.4, 0.9],
        Region::Nose => [0.9, 0.4, 0.3],
        Region::CheekL => [0.5, 0.9, 0.5],
        Region::CheekR => [0.3, 0.7, 0.3],
        Region::UpperLip => [0.9, 0.2, 0.3],
        Region::LowerLip => [0.7, 0.1, 0.2],
        Region::Chin => [0.9, 0.9, 0.3],
        Region::Jaw => [0.5, 0.7, 0.9],
        Region::Temple => [0.4, 0.9, 0.9],
        Region::BackOfHead => [0.5, 0.5, 0.5],
        Region::Neck => [0.7, 0.7, 0.9],
        Region::EyeballL | Region::EyeballR => [1.0, 1.0, 1.0],
    }
}

#[test]
#[ignore = "writes preview files to the temp folder"]
fn write_preview() {
    let dir = std::env::temp_dir().join("actor_preview");
    std::fs::create_dir_all(&dir).unwrap();
    let seed: u64 = std::env::var("ACTOR_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    let params = if seed == 0 {
        ActorParams::default()
    } else {
        ActorParams::from_seed(seed)
    };
    let actor = Actor::new(&params).unwrap();
    let mesh = actor.neutral();
    let size = 700;
    let views = [
        ("front", Vector3::new(0.0, 0.0, 1.0)),
        ("side", Vector3::new(1.0, 0.0, 0.0)),
        ("threeq", Vector3::new(0.7, 0.15, 1.0)),
        ("below", Vector3::new(0.0, -0.6, 1.0)),
    ];
    let list: Vec<String> = std::env::var("ACTOR_EXPR")
        .unwrap_or_else(|_| "neutral".into())
        .split(',')
        .map(str::to_string)
        .collect();
    for name in &list {
        let positions = if name == "neutral" {
            mesh.positions.clone()
        } else {
            let pairs: Vec<(&str, f64)> = name.split('+').map(|n| (n, 1.0)).collect();
            actor.evaluate(&actor.weights(&pairs)).positions
        };
        std::fs::write(dir.join(format!("{name}.obj")), obj_text(mesh, &positions)).unwrap();
        for (vn, view) in &views {
            let img = render(
                mesh,
                &positions,
                *view,
                None,
                size,
                Point3::new(0.0, -10.0, 0.0),
                2.4,
            );
            write_ppm(&dir.join(format!("{name}_{vn}.ppm")), &img, size);
        }
        if name == "neutral" {
            let regions = actor.regions().to_vec();
            let col = move |v: usize| region_colour(regions[v]);
            let img = render(
                mesh,
                &positions,
                Vector3::z(),
                Some(&col),
                size,
                Point3::new(0.0, -10.0, 0.0),
                2.4,
            );
            write_ppm(&dir.join("regions_front.ppm"), &img, size);
            let w = actor.jaw_rig().weights.clone();
            let col = move |v: usize| [w[v], 0.3, 1.0 - w[v]];
            let img = render(
                mesh,
                &positions,
                Vector3::new(1.0, 0.0, 0.6),
                Some(&col),
                size,
                Point3::new(0.0, -10.0, 0.0),
                2.4,
            );
            write_ppm(&dir.join("jaw_weights.ppm"), &img, size);
        }
    }
}
