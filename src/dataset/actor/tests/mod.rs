//! Tests of the synthetic actor, with small private mesh helpers (edge maps, boundary
//! loops, uniform Laplacian smoothing) and a preview writer.

use std::collections::{HashMap, HashSet};
use std::sync::OnceLock;

use nalgebra::Point3;

use super::*;

mod preview;

/// The default actor, built once for all tests.
fn actor() -> &'static Actor {
    static A: OnceLock<Actor> = OnceLock::new();
    A.get_or_init(|| Actor::new(&ActorParams::default()).unwrap())
}

fn disp(a: &[Point3<f64>], b: &[Point3<f64>], v: usize) -> f64 {
    (a[v] - b[v]).norm()
}

fn pose(a: &Actor, named: &[(&str, f64)]) -> Vec<Point3<f64>> {
    a.evaluate(&a.weights(named)).positions
}

/// Use count of each undirected edge, and every directed polygon edge.
type Edges = (HashMap<(u32, u32), usize>, Vec<(u32, u32)>);

/// Directed polygon edges of the vertices in `range`, with how many polygons use each
/// undirected edge.
fn edge_use(mesh: &Mesh, keep: impl Fn(u32) -> bool) -> Edges {
    let mut count = HashMap::new();
    let mut directed = Vec::new();
    for f in mesh.faces() {
        if !f.iter().all(|&v| keep(v)) {
            continue;
        }
        for k in 0..f.len() {
            let (a, b) = (f[k], f[(k + 1) % f.len()]);
            directed.push((a, b));
            *count.entry((a.min(b), a.max(b))).or_insert(0) += 1;
        }
    }
    (count, directed)
}

/// Boundary loops (as vertex lists) of the polygons whose vertices all pass `keep`.
/// Panics if the boundary is not a set of simple loops.
fn boundary_loops(mesh: &Mesh, keep: impl Fn(u32) -> bool) -> Vec<Vec<u32>> {
    let (_, directed) = edge_use(mesh, keep);
    let set: HashSet<(u32, u32)> = directed.iter().copied().collect();
    assert_eq!(
        set.len(),
        directed.len(),
        "a directed edge is used twice: inconsistent orientation"
    );
    let mut next: HashMap<u32, u32> = HashMap::new();
    for &(a, b) in &directed {
        if !set.contains(&(b, a)) {
            // Boundary half-edge b -> a on the hole side; store the polygon's a -> b.
            assert!(
                next.insert(a, b).is_none(),
                "vertex {a} has two outgoing boundary edges"
            );
        }
    }
    let mut seen = HashSet::new();
    let mut loops = Vec::new();
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort_unstable();
    for s in starts {
        if seen.contains(&s) {
            continue;
        }
        let mut lp = vec![s];
        seen.insert(s);
        let mut v = next[&s];
        while v != s {
            assert!(seen.insert(v), "boundary is not a simple loop at {v}");
            lp.push(v);
            v = next[&v];
        }
        loops.push(lp);
    }
    loops
}

/// Uniform-Laplacian smoothing (`x ← x + λ (mean of neighbours − x)`) of a per-vertex
/// vector field over the polygon adjacency.
fn smooth(mesh: &Mesh, field: &[Vector3<f64>], iterations: usize) -> Vec<Vector3<f64>> {
    let mut nbrs: Vec<Vec<u32>> = vec![Vec::new(); mesh.vertex_count()];
    for f in mesh.faces() {
        for k in 0..f.len() {
            let (a, b) = (f[k], f[(k + 1) % f.len()]);
            if !nbrs[a as usize].contains(&b) {
                nbrs[a as usize].push(b);
                nbrs[b as usize].push(a);
            }
        }
    }
    let mut x = field.to_vec();
    for _ in 0..iterations {
        let prev = x.clone();
        for (i, n) in nbrs.iter().enumerate() {
            if n.is_empty() {
                continue;
            }
            let mean = n.iter().map(|&j| prev[j as usize]).sum::<Vector3<f64>>() / n.len() as f64;
            x[i] = prev[i] + 0.5 * (mean - prev[i]);
        }
    }
    x
}

/// RMS over `verts` of the high-frequency part of a displacement field along the
/// neutral normal: `n · (d − smooth(d))`, with 5 smoothing iterations (which keep most of
/// a smooth expression field and remove most of a 6–10 mm wrinkle pattern).
fn high_frequency_rms(a: &Actor, field: &[Vector3<f64>], verts: &[usize]) -> f64 {
    let low = smooth(a.neutral(), field, 5);
    let n = a.neutral_normals();
    let sum: f64 = verts
        .iter()
        .map(|&v| n[v].dot(&(field[v] - low[v])).powi(2))
        .sum();
    (sum / verts.len() as f64).sqrt()
}

fn region_vertices(a: &Actor, r: &[Region]) -> Vec<usize> {
    (0..a.neutral().vertex_count())
        .filter(|&v| r.contains(&a.regions()[v]))
        .collect()
}

#[test]
fn vertex_count_and_face_first_order() {
    let a = actor();
    let n = a.neutral().vertex_count();
    println!(
        "vertices {n}, polygons {}, triangles {}, face vertices {}",
        a.neutral().face_count(),
        a.neutral().triangles.len(),
        a.face_vertex_count()
    );
    assert!((10_000..=20_000).contains(&n), "{n} vertices");
    let face = a.face_vertex_count();
    assert!(face > 7_000 && face < n);
    for (v, r) in a.regions().iter().enumerate() {
        assert_eq!(r.is_face(), v < face, "vertex {v} is {r:?}");
    }
    let d = a.to_dataset();
    assert_eq!(d.face_vertices, 0..=(face as u32 - 1));
    assert!(a.regions()[a.eyeball_vertices()[0].start] == Region::EyeballL);
    assert!(a.regions()[n - 1] == Region::EyeballR);
}

#[test]
fn face_edges_are_about_two_millimetres() {
    let a = actor();
    let m = a.neutral();
    let (count, _) = edge_use(m, |v| (v as usize) < a.face_vertex_count());
    let mut len: Vec<f64> = count
        .keys()
        .map(|&(i, j)| (m.positions[i as usize] - m.positions[j as usize]).norm())
        .collect();
    len.sort_by(f64::total_cmp);
    let q = |p: f64| len[((len.len() as f64 * p) as usize).min(len.len() - 1)];
    println!(
        "face edge length mm: p05 {:.2} median {:.2} p95 {:.2}",
        q(0.05),
        q(0.5),
        q(0.95)
    );
    assert!(q(0.5) > 1.5 && q(0.5) < 2.3);
    assert!(q(0.95) < 3.5);
}

#[test]
fn identities_share_topology_and_differ() {
    let base = actor();
    let b = base.neutral();
    for seed in [1u64, 2, 3] {
        let params = ActorParams::from_seed(seed);
        assert_eq!(
            params,
            ActorParams::from_seed(seed),
            "from_seed is deterministic"
        );
        let other = Actor::new(&params).unwrap();
        let o = other.neutral();
        assert_eq!(o.face_offsets, b.face_offsets);
        assert_eq!(o.face_vertices, b.face_vertices);
        assert_eq!(o.face_uvs, b.face_uvs);
        assert_eq!(o.triangles.len(), b.triangles.len());
        assert_eq!(other.face_vertex_count(), base.face_vertex_count());
        assert_eq!(other.landmarks(), base.landmarks());
        let face = base.face_vertex_count();
        let mean = (0..face)
            .map(|v| disp(&o.positions, &b.positions, v))
            .sum::<f64>()
            / face as f64;
        println!("seed {seed}: mean face distance to the default {mean:.2} mm");
        assert!(
            mean > 2.0,
            "seed {seed} is too close to the default ({mean} mm)"
        );
    }
}

#[test]
fn invalid_params_are_rejected_with_the_field_name() {
    let cases: Vec<(&str, ActorParams)> = vec![
        (
            "nose_length_mm",
            ActorParams {
                nose_length_mm: f64::NAN,
                ..Default::default()
            },
        ),
        (
            "head_width_mm",
            ActorParams {
                head_width_mm: -3.0,
                ..Default::default()
            },
        ),
        (
            "wrinkle_depth_scale",
            ActorParams {
                wrinkle_depth_scale: f64::INFINITY,
                ..Default::default()
            },
        ),
        (
            "lip_width_mm",
            ActorParams {
                lip_width_mm: 62.0,
                jaw_width_mm: 90.0,
                ..Default::default()
            },
        ),
        (
            "eye_spacing_mm",
            ActorParams {
                eye_spacing_mm: 74.0,
                head_width_mm: 125.0,
                ..Default::default()
            },
        ),
    ];
    for (field, p) in cases {
        match Actor::new(&p) {
            Err(ActorError::InvalidParam { field: f, .. }) => assert_eq!(f, field),
            other => panic!("expected an error naming {field}, got {other:?}"),
        }
    }
}

#[test]
fn extreme_valid_params_build() {
    for lo in [true, false] {
        let p = if lo {
            ActorParams {
                head_width_mm: 130.0,
                head_height_mm: 200.0,
                head_depth_mm: 165.0,
                face_length_mm: 100.0,
                nose_length_mm: 35.0,
                nose_protrusion_mm: 14.0,
                nose_width_mm: 26.0,
                jaw_width_mm: 90.0,
                lip_width_mm: 40.0,
                eye_spacing_mm: 56.0,
                brow_prominence_mm: 0.0,
                cheek_fullness_mm: 0.0,
                chin_prominence_mm: 0.0,
                lip_fullness_mm: 1.0,
                wrinkle_depth_scale: 0.0,
                seed: 9,
            }
        } else {
            ActorParams {
                head_width_mm: 185.0,
                head_height_mm: 270.0,
                head_depth_mm: 230.0,
                face_length_mm: 140.0,
                nose_length_mm: 56.0,
                nose_protrusion_mm: 28.0,
                nose_width_mm: 44.0,
                jaw_width_mm: 135.0,
                lip_width_mm: 62.0,
                eye_spacing_mm: 74.0,
                brow_prominence_mm: 10.0,
                cheek_fullness_mm: 10.0,
                chin_prominence_mm: 9.0,
                lip_fullness_mm: 8.0,
                wrinkle_depth_scale: 3.0,
                seed: u64::MAX,
            }
        };
        let a = Actor::new(&p).unwrap();
        check_uv_chart(&a);
        let w = vec![1.0; a.expression_names().len()];
        assert!(
            a.evaluate(&w)
                .positions
                .iter()
                .all(|p| p.coords.iter().all(|c| c.is_finite()))
        );
    }
}

#[test]
fn eyeballs_are_closed_and_separate() {
    let a = actor();
    let m = a.neutral();
    for range in a.eyeball_vertices() {
        let inside = |v: u32| range.contains(&(v as usize));
        let (count, _) = edge_use(m, inside);
        assert!(!count.is_empty());
        assert!(
            count.values().all(|&c| c == 2),
            "an eyeball edge is not used by exactly 2 faces"
        );
        // No polygon mixes eyeball and other vertices.
        for f in m.faces() {
            let k = f.iter().filter(|&&v| inside(v)).count();
            assert!(k == 0 || k == f.len());
        }
        assert!(boundary_loops(m, inside).is_empty());
        let c = a.eyeball_centres()[if range.start == a.eyeball_vertices()[0].start {
            0
        } else {
            1
        }];
        for v in range {
            assert!(((m.positions[v] - c).norm() - 12.0).abs() < 1e-9);
        }
    }
}

#[test]
fn head_boundary_is_eyes_mouth_and_neck() {
    let a = actor();
    let m = a.neutral();
    let skin_end = a.eyeball_vertices()[0].start as u32;
    let (count, _) = edge_use(m, |v| v < skin_end);
    assert!(count.values().all(|&c| c <= 2), "non-manifold edge");
    let loops = boundary_loops(m, |v| v < skin_end);
    assert_eq!(
        loops.len(),
        4,
        "loops of sizes {:?}",
        loops.iter().map(Vec::len).collect::<Vec<_>>()
    );
    let l = a.landmarks();
    let find = |v: u32| loops.iter().position(|lp| lp.contains(&v));
    let eye_l = find(l.eye_inner_l).unwrap();
    let eye_r = find(l.eye_inner_r).unwrap();
    let mouth = find(l.mouth_corner_l).unwrap();
    for (v, lp) in [
        (l.eye_outer_l, eye_l),
        (l.upper_lid_l, eye_l),
        (l.lower_lid_l, eye_l),
        (l.eye_outer_r, eye_r),
        (l.mouth_corner_r, mouth),
        (l.upper_lip_centre, mouth),
        (l.lower_lip_centre, mouth),
    ] {
        assert_eq!(find(v), Some(lp));
    }
    let mut distinct = vec![eye_l, eye_r, mouth];
    distinct.sort_unstable();
    distinct.dedup();
    assert_eq!(distinct.len(), 3);
    // The fourth loop is the neck: every vertex of it is a neck vertex.
    let neck = (0..4).find(|i| !distinct.contains(i)).unwrap();
    assert!(
        loops[neck]
            .iter()
            .all(|&v| a.regions()[v as usize] == Region::Neck)
    );
    // The skin is one connected component.
    let mut parent: Vec<u32> = (0..skin_end).collect();
    fn root(p: &mut [u32], mut v: u32) -> u32 {
        while p[v as usize] != v {
            p[v as usize] = p[p[v as usize] as usize];
            v = p[v as usize];
        }
        v
    }
    for &(i, j) in count.keys() {
        let (ri, rj) = (root(&mut parent, i), root(&mut parent, j));
        parent[ri as usize] = rj;
    }
    let r0 = root(&mut parent, 0);
    assert!((0..skin_end).all(|v| root(&mut parent, v) == r0));
}

/// Every face triangle has the same UV orientation and a non-degenerate UV area.
fn check_uv_chart(a: &Actor) {
    let m = a.neutral();
    let face = a.face_vertex_count() as u32;
    let (mut pos, mut neg, mut min_area) = (0, 0, f64::INFINITY);
    for (t, tuv) in m.triangles.iter().zip(&m.triangle_uvs) {
        if !t.iter().all(|&v| v < face) {
            continue;
        }
        let [p, q, r] = tuv.map(|i| m.uvs[i as usize]);
        let area = 0.5 * ((q - p).perp(&(r - p)));
        if area > 0.0 {
            pos += 1;
        } else {
            neg += 1;
        }
        min_area = min_area.min(area.abs());
    }
    assert!(pos > 10_000);
    assert_eq!(neg, 0, "{neg} flipped face triangles in UV space");
    // A 2 mm face cell is about 1e-5 in UV units; 1e-9 is far below any real triangle.
    assert!(min_area > 1e-9, "degenerate UV triangle (area {min_area})");
}

#[test]
fn face_uv_chart_has_no_flips() {
    check_uv_chart(actor());
    // Face triangles in 3D are not degenerate either.
    let m = actor().neutral();
    let face = actor().face_vertex_count() as u32;
    let areas = crate::mesh::triangle_areas(m);
    let min = m
        .triangles
        .iter()
        .zip(&areas)
        .filter(|(t, _)| t.iter().all(|&v| v < face))
        .map(|(_, &a)| a)
        .fold(f64::INFINITY, f64::min);
    println!("smallest face triangle {min:.4} mm²");
    assert!(min > 0.01);
}

#[test]
fn eye_blink_closes_the_left_eye_only() {
    let a = actor();
    let n = &a.neutral().positions;
    let p = pose(a, &[("eyeBlink_L", 1.0)]);
    let upper_l = region_vertices(a, &[Region::EyelidUpperL]);
    let max_upper = upper_l.iter().map(|&v| disp(&p, n, v)).fold(0.0, f64::max);
    let max_elsewhere = (0..n.len())
        .filter(|v| {
            !matches!(
                a.regions()[*v],
                Region::EyelidUpperL | Region::EyelidLowerL | Region::BrowL
            )
        })
        .map(|v| disp(&p, n, v))
        .fold(0.0, f64::max);
    let right = region_vertices(
        a,
        &[Region::EyelidUpperR, Region::EyelidLowerR, Region::BrowR],
    );
    let max_right = right.iter().map(|&v| disp(&p, n, v)).fold(0.0, f64::max);
    println!(
        "blink: upper lid max {max_upper:.2} mm, elsewhere {max_elsewhere:.3}, right eye {max_right}"
    );
    assert!(max_upper > 6.0);
    assert!(max_upper > 3.0 * max_elsewhere);
    assert!(max_right < 1e-9);
    // The opening closes: every upper margin vertex is within 1 mm of the lower one.
    let topo = &a.canon.topology;
    let nc = topo.cols.len();
    for (e, name) in [(0, "eyeBlink_L"), (1, "eyeBlink_R")] {
        let q = pose(a, &[(name, 1.0)]);
        let s = &topo.openings.eyes[e];
        let mut worst: f64 = 0.0;
        let mut open: f64 = 0.0;
        for c in s.c0 + 1..s.c1 {
            let lo = topo.grid_to_vertex[s.row * nc + c] as usize;
            let up = topo.grid_to_vertex[(s.row + 1) * nc + c] as usize;
            worst = worst.max((q[up] - q[lo]).norm());
            open = open.max((n[up] - n[lo]).norm());
        }
        println!("{name}: neutral opening {open:.2} mm, closed gap {worst:.3} mm");
        assert!(open > 8.0);
        assert!(worst < 1.0);
    }
}

#[test]
fn smile_moves_the_left_corner_out_and_up() {
    let a = actor();
    let n = &a.neutral().positions;
    let l = a.landmarks();
    let p = pose(a, &[("mouthSmile_L", 1.0)]);
    let d = p[l.mouth_corner_l as usize] - n[l.mouth_corner_l as usize];
    println!(
        "smile_L corner displacement {:?} ({:.1} mm)",
        d.as_slice(),
        d.norm()
    );
    assert!(d.x > 3.0 && d.y > 4.0);
    assert!(d.norm() > 8.0 && d.norm() < 12.0);
    assert!(disp(&p, n, l.mouth_corner_r as usize) < 0.5);
    let p = pose(a, &[("mouthSmile_R", 1.0)]);
    let d = p[l.mouth_corner_r as usize] - n[l.mouth_corner_r as usize];
    assert!(d.x < -3.0 && d.y > 4.0);
}

#[test]
fn jaw_open_rotates_the_jaw_and_leaves_the_forehead() {
    let a = actor();
    let n = &a.neutral().positions;
    let l = a.landmarks();
    let out = a.evaluate(&a.weights(&[("jawOpen", 1.0)]));
    let p = &out.positions;
    let chin = p[l.chin as usize] - n[l.chin as usize];
    println!("jawOpen: chin {:?}, pose {:?}", chin.as_slice(), out.jaw);
    assert!(chin.y < -20.0);
    assert!((out.jaw.open_rad.to_degrees() - 17.2).abs() < 0.5);
    let forehead = region_vertices(a, &[Region::Forehead, Region::BrowL, Region::BrowR]);
    let max_forehead = forehead.iter().map(|&v| disp(p, n, v)).fold(0.0, f64::max);
    assert!(max_forehead < 0.01, "forehead moved {max_forehead} mm");
    assert!(disp(p, n, l.nose_tip as usize) < 0.01);
    // The lips part: lower lip margin well below the upper one.
    let gap = p[l.upper_lip_centre as usize].y - p[l.lower_lip_centre as usize].y;
    assert!(gap > 15.0, "lip gap {gap}");
    // Sideways and forward jaw poses.
    let left = a.evaluate(&a.weights(&[("jawLeft", 1.0)]));
    assert!(left.positions[l.chin as usize].x - n[l.chin as usize].x > 5.0);
    assert!(left.jaw.lateral_rad > 0.0);
    let fwd = a.evaluate(&a.weights(&[("jawForward", 1.0)]));
    assert!(fwd.positions[l.chin as usize].z - n[l.chin as usize].z > 4.0);
}

#[test]
fn brows_move_their_regions() {
    let a = actor();
    let n = &a.neutral().positions;
    let mean_dy = |p: &[Point3<f64>], verts: &[usize]| {
        verts.iter().map(|&v| p[v].y - n[v].y).sum::<f64>() / verts.len() as f64
    };
    let brows = region_vertices(a, &[Region::BrowL, Region::BrowR]);
    let inner: Vec<usize> = brows
        .iter()
        .copied()
        .filter(|&v| n[v].x.abs() < 25.0)
        .collect();
    let up = pose(a, &[("browInnerUp", 1.0)]);
    println!(
        "browInnerUp: inner brows rise {:.2} mm",
        mean_dy(&up, &inner)
    );
    assert!(mean_dy(&up, &inner) > 4.0);
    assert!(
        up[a.landmarks().forehead_centre as usize].y - n[a.landmarks().forehead_centre as usize].y
            > 2.0
    );
    let down = pose(a, &[("browDown_L", 1.0)]);
    let left: Vec<usize> = region_vertices(a, &[Region::BrowL])
        .into_iter()
        .filter(|&v| n[v].x < 40.0)
        .collect();
    let right: Vec<usize> = region_vertices(a, &[Region::BrowR]);
    assert!(mean_dy(&down, &left) < -2.0);
    assert!(mean_dy(&down, &right).abs() < 0.05);
    let outer = pose(a, &[("browOuterUp_R", 1.0)]);
    assert!(
        outer[a.landmarks().brow_outer_r as usize].y - n[a.landmarks().brow_outer_r as usize].y
            > 3.0
    );
}

#[test]
fn every_expression_moves_only_skin() {
    let a = actor();
    let n = &a.neutral().positions;
    let eyes: Vec<usize> = a.eyeball_vertices().into_iter().flatten().collect();
    for (i, name) in a.expression_names().iter().enumerate() {
        let s = a.expression_shape(i).unwrap();
        assert_eq!(&s.name, name);
        let max = (0..n.len())
            .map(|v| disp(&s.positions, n, v))
            .fold(0.0, f64::max);
        assert!(max > 2.0 && max < 60.0, "{name} moves {max} mm at most");
        assert!(
            eyes.iter().all(|&v| s.positions[v] == n[v]),
            "{name} moves an eyeball"
        );
    }
    assert!(a.expression_shape(a.expression_names().len()).is_none());
}

#[test]
fn wrinkles_add_fine_detail_on_the_forehead() {
    let a = actor();
    let smooth_actor = Actor::new(&ActorParams {
        wrinkle_depth_scale: 0.0,
        ..Default::default()
    })
    .unwrap();
    let forehead = region_vertices(a, &[Region::Forehead]);
    let hf = |act: &Actor, named: &[(&str, f64)]| {
        let n = &act.neutral().positions;
        let p = pose(act, named);
        let d: Vec<Vector3<f64>> = p.iter().zip(n).map(|(p, q)| p - q).collect();
        high_frequency_rms(act, &d, &forehead)
    };
    let with = hf(a, &[("browInnerUp", 1.0)]);
    let without = hf(&smooth_actor, &[("browInnerUp", 1.0)]);
    let neutral = hf(a, &[]);
    println!(
        "forehead high-frequency RMS: browInnerUp {with:.3} mm, no wrinkles {without:.3} mm, neutral {neutral}"
    );
    assert!(with > 0.07);
    assert!(with > 3.0 * without);
    assert_eq!(neutral, 0.0);
    // Depth saturates: activation above 1 adds nothing.
    let both = pose(
        a,
        &[
            ("browInnerUp", 1.0),
            ("browOuterUp_L", 1.0),
            ("browOuterUp_R", 1.0),
        ],
    );
    assert!(both.iter().all(|p| p.coords.iter().all(|c| c.is_finite())));
    // Other patterns exist where they should: compare within a few millimetres of the
    // pattern, with and without wrinkles.
    let n = &a.neutral().positions;
    let l = a.landmarks();
    let around = |c: Point3<f64>, r: f64| -> Vec<usize> {
        (0..a.face_vertex_count())
            .filter(|&v| (n[v] - c).norm() < r)
            .collect()
    };
    let at = |v: u32| n[v as usize];
    let mut checks = Vec::new();
    let between_brows = Point3::from((at(l.brow_inner_l).coords + at(l.brow_inner_r).coords) * 0.5);
    for (name, verts) in [
        ("browDown_L", around(between_brows, 12.0)),
        (
            "eyeSquint_L",
            around(at(l.eye_outer_l) + Vector3::new(10.0, 0.0, -6.0), 10.0),
        ),
        (
            "noseSneer_L",
            around(at(l.nose_bridge) + Vector3::new(6.0, 6.0, -3.0), 8.0),
        ),
        ("mouthShrugLower", around(at(l.chin), 9.0)),
    ] {
        assert!(verts.len() > 10, "{name}");
        let h = |act: &Actor| {
            let n = &act.neutral().positions;
            let p = pose(act, &[(name, 1.0)]);
            let d: Vec<Vector3<f64>> = p.iter().zip(n).map(|(p, q)| p - q).collect();
            high_frequency_rms(act, &d, &verts)
        };
        let (w, wo) = (h(a), h(&smooth_actor));
        println!("{name}: high-frequency RMS {w:.3} mm, without wrinkles {wo:.3} mm");
        checks.push((name, w, wo));
    }
    for (name, w, wo) in checks {
        // The smooth fields of these expressions have some high-frequency residue of
        // their own (sharp curvature under the chin, uneven spacing), so the bar is
        // lower than on the forehead.
        assert!(w > 0.04 && w > 1.5 * wo, "{name}: {w} vs {wo}");
    }
}

#[test]
fn combinations_are_nonlinear() {
    let a = actor();
    let n = &a.neutral().positions;
    for (x, y) in [
        ("mouthSmile_L", "jawOpen"),
        ("eyeBlink_L", "eyeSquint_L"),
        ("mouthFunnel", "jawOpen"),
        ("browDown_L", "browInnerUp"),
    ] {
        let px = pose(a, &[(x, 1.0)]);
        let py = pose(a, &[(y, 1.0)]);
        let pxy = pose(a, &[(x, 1.0), (y, 1.0)]);
        let err = (0..n.len())
            .map(|v| (pxy[v] - (px[v] + (py[v] - n[v]))).norm())
            .fold(0.0, f64::max);
        println!("{x} + {y}: largest departure from the sum of deltas {err:.2} mm");
        assert!(err > 1.0, "{x} + {y} is nearly linear ({err} mm)");
    }
    // Half weights are not half deltas either (jaw rotation, lid sliding, wrinkle ramp).
    let full = pose(a, &[("jawOpen", 1.0)]);
    let half = pose(a, &[("jawOpen", 0.5)]);
    let err = (0..n.len())
        .map(|v| (half[v] - (n[v] + 0.5 * (full[v] - n[v]))).norm())
        .fold(0.0, f64::max);
    assert!(err > 0.3, "{err}");
}

#[test]
fn dataset_matches_evaluate_and_unskins() {
    let a = actor();
    let d = a.to_dataset();
    assert_eq!(d.name, "builtin-actor");
    assert_eq!(&d.neutral, a.neutral());
    assert_eq!(d.shapes.len(), a.expression_names().len());
    let rig = d.jaw.as_ref().unwrap();
    assert_eq!(rig, a.jaw_rig());
    for (i, s) in d.shapes.iter().enumerate() {
        let mut w = vec![0.0; d.shapes.len()];
        w[i] = 1.0;
        let p = a.evaluate(&w);
        assert_eq!(s.name, a.expression_names()[i]);
        assert_eq!(s.positions, p.positions);
        assert_eq!(s.jaw, Some(p.jaw));
    }
    let open = &d.shapes[d.shape_index("jawOpen").unwrap()];
    let pose = open.jaw.unwrap();
    let unskinned = rig.unskin(&pose, &open.positions);
    let back = rig.skin(&pose, &unskinned);
    let worst = back
        .iter()
        .zip(&open.positions)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, f64::max);
    assert!(worst < 1e-9, "skin(unskin(x)) differs by {worst}");
    // Unskinned, only the soft-tissue part remains near the chin.
    let chin = a.landmarks().chin as usize;
    let n = &a.neutral().positions;
    println!(
        "jawOpen chin: skinned {:.1} mm, unskinned {:.2} mm",
        (open.positions[chin] - n[chin]).norm(),
        (unskinned[chin] - n[chin]).norm()
    );
    assert!((unskinned[chin] - n[chin]).norm() < 3.0);
    assert!((open.positions[chin] - n[chin]).norm() > 20.0);
    assert!(rig.weights.iter().all(|w| (0.0..=1.0).contains(w)));
    assert_eq!(rig.weights[a.landmarks().nose_tip as usize], 0.0);
    assert_eq!(rig.weights[chin], 1.0);
}

#[test]
fn weights_are_sanitized() {
    let a = actor();
    let n = a.expression_names().len();
    let mut w = vec![0.0; n + 3];
    w[0] = f64::NAN;
    w[4] = 7.0;
    w[n + 1] = 1.0;
    let p = a.evaluate(&w);
    let q = a.evaluate(&a.weights(&[("mouthSmile_L", 1.0)]));
    assert_eq!(p, q);
    assert_eq!(a.evaluate(&[]).positions, a.neutral().positions);
    assert_eq!(a.evaluate(&[-1.0; 3]).positions, a.neutral().positions);
}

#[test]
fn landmarks_sit_where_they_say() {
    let a = actor();
    let p = &a.neutral().positions;
    let l = a.landmarks();
    let at = |v: u32| p[v as usize];
    let face = a.face_vertex_count();
    let max_z = (0..face).map(|v| p[v].z).fold(f64::MIN, f64::max);
    assert!(
        at(l.nose_tip).z > max_z - 1.0,
        "nose tip is not the front-most point"
    );
    assert!(at(l.nose_tip).z - at(l.subnasale).z > 15.0);
    assert!(at(l.eye_outer_l).x > at(l.eye_inner_l).x && at(l.eye_inner_l).x > 0.0);
    assert!(at(l.eye_outer_r).x < at(l.eye_inner_r).x && at(l.eye_inner_r).x < 0.0);
    assert!(at(l.mouth_corner_l).x > 20.0 && at(l.mouth_corner_r).x < -20.0);
    assert!(at(l.forehead_centre).y > at(l.nasion).y && at(l.nasion).y > at(l.nose_tip).y);
    assert!(at(l.nose_tip).y > at(l.upper_lip_centre).y && at(l.lower_lip_centre).y > at(l.chin).y);
    assert!(at(l.temple_l).x > 45.0 && at(l.temple_r).x < -45.0);
    let width = at(l.cheek_l).x - at(l.cheek_r).x;
    let face_height = at(l.forehead_centre).y - at(l.chin).y;
    println!("cheek width {width:.0} mm, forehead-to-chin {face_height:.0} mm");
    let named = l.named();
    let distinct: HashSet<u32> = named.iter().map(|&(_, v)| v).collect();
    assert_eq!(distinct.len(), named.len());
    assert!(named.iter().all(|&(_, v)| (v as usize) < face));
    assert_eq!(a.regions()[l.nose_tip as usize], Region::Nose);
    assert_eq!(a.regions()[l.upper_lid_l as usize], Region::EyelidUpperL);
    assert_eq!(a.regions()[l.lower_lid_r as usize], Region::EyelidLowerR);
}

#[test]
#[ignore = "timing; run in release: cargo test --release --lib actor_build_timing -- --ignored --nocapture"]
fn actor_build_timing() {
    let t0 = std::time::Instant::now();
    let first = Actor::new(&ActorParams::from_seed(11))
        .unwrap()
        .to_dataset();
    let cold = t0.elapsed();
    let mut times = Vec::new();
    for seed in 0..5u64 {
        let t = std::time::Instant::now();
        let a = Actor::new(&ActorParams::from_seed(seed)).unwrap();
        let d = a.to_dataset();
        times.push(t.elapsed().as_secs_f64() * 1e3);
        assert_eq!(d.shapes.len(), first.shapes.len());
    }
    times.sort_by(f64::total_cmp);
    let a = actor();
    let w = a.weights(&[
        ("jawOpen", 0.5),
        ("mouthSmile_L", 0.7),
        ("eyeBlink_R", 1.0),
        ("browInnerUp", 0.4),
    ]);
    let t = std::time::Instant::now();
    for _ in 0..20 {
        std::hint::black_box(a.evaluate(&w));
    }
    let eval_ms = t.elapsed().as_secs_f64() * 1e3 / 20.0;
    println!(
        "Actor::new + to_dataset: first in process {:.0} ms (includes the shared layout), median of 5 {:.0} ms; evaluate {:.2} ms",
        cold.as_secs_f64() * 1e3,
        times[2],
        eval_ms
    );
}

#[test]
fn many_random_identities_build_cleanly() {
    for seed in 100..112u64 {
        let a = Actor::new(&ActorParams::from_seed(seed)).unwrap();
        check_uv_chart(&a);
        let m = a.neutral();
        let skin_end = a.eyeball_vertices()[0].start as u32;
        assert_eq!(boundary_loops(m, |v| v < skin_end).len(), 4);
        let w = vec![0.6; a.expression_names().len()];
        assert!(
            a.evaluate(&w)
                .positions
                .iter()
                .all(|p| p.coords.iter().all(|c| c.is_finite()))
        );
    }
}

#[test]
fn actor_is_shareable_across_threads() {
    fn send_sync<T: Send + Sync>() {}
    send_sync::<Actor>();
    let a = actor();
    assert_eq!(a.eyeball_vertices()[0].len(), 314);
    assert_eq!(
        a.neutral().vertex_count(),
        18_355,
        "update the module docs' counts"
    );
    let names: HashSet<&str> = a.wrinkle_depths(&[]).iter().map(|&(n, _)| n).collect();
    assert_eq!(names.len(), 12);
    assert!(a.wrinkle_depths(&a.weights(&[("browInnerUp", 1.0)]))[0].1 == 1.0);
}

#[test]
fn any_accepted_params_build_or_fail_cleanly() {
    // Proportions drawn anywhere in their accepted ranges (wider than `from_seed`).
    let mut rng = crate::numeric::SplitMix64::new(42);
    let (mut built, mut rejected) = (0, 0);
    for _ in 0..24 {
        let mut u = |lo: f64, hi: f64| rng.uniform(lo, hi);
        let p = ActorParams {
            head_width_mm: u(120.0, 185.0),
            head_height_mm: u(190.0, 270.0),
            head_depth_mm: u(160.0, 230.0),
            face_length_mm: u(100.0, 140.0),
            nose_length_mm: u(34.0, 56.0),
            nose_protrusion_mm: u(14.0, 28.0),
            nose_width_mm: u(26.0, 44.0),
            jaw_width_mm: u(85.0, 135.0),
            lip_width_mm: u(40.0, 62.0),
            lip_fullness_mm: u(1.0, 8.0),
            eye_spacing_mm: u(54.0, 74.0),
            brow_prominence_mm: u(0.0, 10.0),
            cheek_fullness_mm: u(0.0, 10.0),
            chin_prominence_mm: u(0.0, 9.0),
            wrinkle_depth_scale: u(0.0, 3.0),
            seed: 3,
        };
        match Actor::new(&p) {
            Ok(a) => {
                check_uv_chart(&a);
                built += 1;
            }
            Err(ActorError::InvalidParam { .. }) => rejected += 1,
            Err(e) => panic!("accepted parameters failed to build: {e} ({p:?})"),
        }
    }
    println!("{built} built, {rejected} rejected as inconsistent");
    assert!(built > 10);
}
