//! The actor's fixed topology: the parameter grid of the head skin, its openings, the
//! crown pole, the two eyeballs, the vertex order and the UV layout.
//!
//! The grid has periodic columns `u` (the back seam at `u = ±πR0`) and rows `v` from the
//! neck opening up to just below the crown pole, spaced by a target edge length (about
//! 1.9 mm on the face, coarser toward the back of the head, the neck and the crown)
//! divided by the canonical surface's stretch. The layout depends only on the canonical
//! (default) identity, never on the identity being built.

use nalgebra::{Point2, Point3, Vector3};

use super::ActorError;
use super::openings::{LidState, Openings, SlitWarp};
use super::surface::{Layout, Surface, U_SEAM, V_MIN, V_POLE, smoothstep};

/// Target face edge length, mm.
const FACE_EDGE_MM: f64 = 2.0;

/// What a skin vertex is in the grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum GridKind {
    /// An ordinary grid vertex.
    Grid,
    /// A merged corner of an opening (canthus, mouth corner).
    Corner,
    /// The crown pole.
    Pole,
}

/// Parameter data of one skin vertex.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SkinVertex {
    /// Canonical `u`.
    pub u: f64,
    /// Canonical grid `v` before the opening warp.
    pub v_grid: f64,
    /// Canonical `v` after the neutral opening warp.
    pub v: f64,
    /// Grid row (the lower row for a merged corner; `rows.len()` for the pole).
    pub row: usize,
    /// Kind of vertex.
    pub kind: GridKind,
}

/// The whole fixed topology.
#[derive(Debug, Clone)]
pub(crate) struct Topology {
    /// Column parameters `u` (ascending, first at `−U_SEAM`).
    pub cols: Vec<f64>,
    /// Eye and mouth slits.
    pub openings: Openings,
    /// Skin vertices in final vertex order (the face first).
    pub skin: Vec<SkinVertex>,
    /// Number of face vertices (they come first).
    pub face_count: usize,
    /// Final vertex index of each grid vertex `row * cols + col` (merged corners map to
    /// their corner vertex).
    pub grid_to_vertex: Vec<u32>,
    /// First vertex of each eyeball (left, right) and the vertex count of one eyeball.
    pub eyeball_first: [usize; 2],
    /// Vertices per eyeball.
    pub eyeball_len: usize,
    /// Unit directions of one eyeball's vertices from its centre.
    pub eyeball_dirs: Vec<Vector3<f64>>,
    /// Polygons (vertex indices).
    pub polygons: Vec<Vec<u32>>,
    /// Polygon UV indices.
    pub polygon_uvs: Vec<Vec<u32>>,
    /// UV pool.
    pub uvs: Vec<Point2<f64>>,
}

/// Longitudes and latitude bands of an eyeball sphere.
const EYE_LON: usize = 24;
const EYE_LAT: usize = 14;

/// Places samples on `[a, b]` (both ends included) so that their local density is
/// `density(x)` samples per unit.
fn place(a: f64, b: f64, density: &dyn Fn(f64) -> f64) -> Vec<f64> {
    let steps = 1200;
    let h = (b - a) / steps as f64;
    let mut cum = vec![0.0; steps + 1];
    let mut prev = density(a);
    for i in 1..=steps {
        let d = density(a + i as f64 * h);
        cum[i] = cum[i - 1] + 0.5 * (prev + d) * h;
        prev = d;
    }
    let total = cum[steps];
    let n = total.round().max(1.0) as usize;
    let mut out = Vec::with_capacity(n + 1);
    let mut k = 0;
    for s in 0..=n {
        let target = total * s as f64 / n as f64;
        while k < steps - 1 && cum[k + 1] < target {
            k += 1;
        }
        let span = cum[k + 1] - cum[k];
        let t = if span > 0.0 {
            ((target - cum[k]) / span).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push(a + (k as f64 + t) * h);
    }
    out[0] = a;
    out[n] = b;
    out
}

/// Mean stretch `|∂P/∂x|` of the canonical surface along one parameter, over a few
/// sample lines of the other.
fn stretch(canon: &Surface, x: f64, along_u: bool, others: &[f64]) -> f64 {
    let h = 0.25;
    let mut sum = 0.0;
    for &o in others {
        let (a, b) = if along_u {
            (canon.point(x - h, o), canon.point(x + h, o))
        } else {
            (canon.point(o, x - h), canon.point(o, x + h))
        };
        sum += (b - a).norm() / (2.0 * h);
    }
    sum / others.len() as f64
}

/// Index of the value in `xs` nearest to `x`.
fn nearest(xs: &[f64], x: f64) -> usize {
    let mut best = 0;
    for (i, &y) in xs.iter().enumerate() {
        if (y - x).abs() < (xs[best] - x).abs() {
            best = i;
        }
    }
    best
}

/// Whether canonical parameter point `(u, v)` is on the face (the reconstruction region).
pub(crate) fn is_face(l: &Layout, u: f64, v: f64) -> bool {
    let au = u.abs();
    au <= 100.0 && v <= l.v_hair + 8.0 && v >= l.v_chin - 3.0 + 30.0 * (au / 100.0).powi(2)
}

impl Topology {
    /// Lays out the topology on the canonical surface.
    pub(crate) fn new(canon: &Surface) -> Result<Self, ActorError> {
        let l = canon.layout;
        // Columns: symmetric about u = 0, which is a column.
        let sample_rows = [
            l.v_hair - 10.0,
            l.v_brow + 10.0,
            l.v_eye - 14.0,
            l.v_tip - 10.0,
            l.v_mouth + 8.0,
            l.v_mouth - 12.0,
            l.v_chin + 8.0,
        ];
        let col_density = |u: f64| {
            let target =
                FACE_EDGE_MM + 0.7 * smoothstep(60.0, 100.0, u) + 9.0 * smoothstep(100.0, 175.0, u);
            stretch(canon, u, true, &sample_rows) / target
        };
        let half = place(0.0, U_SEAM, &col_density);
        let n_half = half.len() - 1;
        let mut cols: Vec<f64> = (1..=n_half).rev().map(|k| -half[k]).collect();
        cols.extend_from_slice(&half[..n_half]);
        // Rows: from the neck opening to the pole (the pole itself is no row).
        let sample_cols = [0.0, 15.0, -15.0, 30.0, -30.0, 45.0, -45.0, 60.0, -60.0];
        let row_density = |v: f64| {
            let below = 1.0 - smoothstep(l.v_chin - 12.0, l.v_chin + 2.0, v);
            let neck = 1.0 - smoothstep(V_MIN, (l.v_chin - 12.0).max(V_MIN + 5.0), v);
            let above = smoothstep(l.v_hair + 2.0, l.v_hair + 32.0, v);
            let target = FACE_EDGE_MM + 1.5 * below + 7.0 * neck + 9.0 * above;
            stretch(canon, v, false, &sample_cols) / target
        };
        let mut rows = place(V_MIN, V_POLE, &row_density);
        rows.pop();
        let (nc, nr) = (cols.len(), rows.len());
        if nc < 16 || nr < 16 {
            return Err(ActorError::Geometry("parameter grid is degenerate".into()));
        }

        // Slits.
        let mid_row = |v: f64| {
            (0..nr - 1)
                .min_by(|&a, &b| {
                    let da = (0.5 * (rows[a] + rows[a + 1]) - v).abs();
                    let db = (0.5 * (rows[b] + rows[b + 1]) - v).abs();
                    da.total_cmp(&db)
                })
                .unwrap_or(0)
        };
        let eye_row = mid_row(l.v_eye);
        let mouth_row = mid_row(l.v_mouth);
        let mirror = |c: usize| nc - c; // column of −u (u = 0 is column nc/2)
        let left_inner = nearest(&cols, l.u_eye - l.a_eye);
        let left_outer = nearest(&cols, l.u_eye + l.a_eye);
        let corner = nearest(&cols, l.u_corner);
        let eyes = [
            SlitWarp::eye(1.0, eye_row, left_inner, left_outer, &cols, &rows, &l),
            SlitWarp::eye(
                -1.0,
                eye_row,
                mirror(left_outer),
                mirror(left_inner),
                &cols,
                &rows,
                &l,
            ),
        ];
        let mouth = SlitWarp::mouth(mouth_row, mirror(corner), corner, &cols, &rows, &l);
        let openings = Openings { eyes, mouth };
        let slits: Vec<&SlitWarp> = openings.eyes.iter().chain([&openings.mouth]).collect();
        if slits.iter().any(|s| s.c1 < s.c0 + 4) || cols[nc / 2] != 0.0 {
            return Err(ActorError::Geometry("openings do not fit the grid".into()));
        }

        // Grid vertices (before ordering), with merged corners.
        let gid = |i: usize, j: usize| j * nc + i;
        let mut alias: Vec<usize> = (0..nc * nr).collect();
        for s in &slits {
            for c in [s.c0, s.c1] {
                alias[gid(c, s.row + 1)] = gid(c, s.row);
            }
        }
        let neutral = [LidState::default(); 2];
        let mut grid_vertices: Vec<Option<SkinVertex>> = vec![None; nc * nr];
        for (j, &row_v) in rows.iter().enumerate() {
            for (i, &u) in cols.iter().enumerate() {
                let g = gid(i, j);
                if alias[g] != g {
                    continue;
                }
                let merged = slits.iter().any(|s| s.row == j && (i == s.c0 || i == s.c1));
                let v_grid = if merged {
                    0.5 * (rows[j] + rows[j + 1])
                } else {
                    row_v
                };
                grid_vertices[g] = Some(SkinVertex {
                    u,
                    v_grid,
                    v: v_grid + openings.delta(u, v_grid, &neutral),
                    row: j,
                    kind: if merged {
                        GridKind::Corner
                    } else {
                        GridKind::Grid
                    },
                });
            }
        }

        // Final order: face vertices first, then the rest of the skin, then the pole.
        let mut order: Vec<usize> = Vec::with_capacity(nc * nr);
        let is_face_g = |sv: &SkinVertex| is_face(&l, sv.u, sv.v);
        for pass in [true, false] {
            for (g, sv) in grid_vertices.iter().enumerate() {
                if let Some(sv) = sv
                    && is_face_g(sv) == pass
                {
                    order.push(g);
                }
            }
            if pass && order.is_empty() {
                return Err(ActorError::Geometry("no face vertices".into()));
            }
        }
        let face_count = grid_vertices
            .iter()
            .flatten()
            .filter(|sv| is_face_g(sv))
            .count();
        let mut grid_to_vertex = vec![u32::MAX; nc * nr];
        let mut skin = Vec::with_capacity(order.len() + 1);
        for (k, &g) in order.iter().enumerate() {
            grid_to_vertex[g] = k as u32;
            if let Some(sv) = grid_vertices[g] {
                skin.push(sv);
            }
        }
        for g in 0..nc * nr {
            grid_to_vertex[g] = grid_to_vertex[alias[g]];
        }
        let pole = skin.len() as u32;
        skin.push(SkinVertex {
            u: 0.0,
            v_grid: V_POLE,
            v: V_POLE,
            row: nr,
            kind: GridKind::Pole,
        });

        // UV pool: the head chart in V ∈ [0.5, 0.95], scaled isotropically.
        let scale = 1.0 / (2.0 * U_SEAM);
        let head_uv = |u: f64, v: f64| Point2::new((u + U_SEAM) * scale, 0.5 + (v - V_MIN) * scale);
        let mut uvs: Vec<Point2<f64>> = Vec::new();
        let mut uv_of: Vec<Option<u32>> = vec![None; (nc + 1) * nr];
        let mut uv_id = |i: usize, j: usize, uvs: &mut Vec<Point2<f64>>| -> u32 {
            // Column nc is column 0 seen from across the back seam; merged corners
            // share one UV.
            let g = alias[gid(i % nc, j)];
            let key = if i == nc {
                j * (nc + 1) + nc
            } else {
                (g / nc) * (nc + 1) + g % nc
            };
            if let Some(id) = uv_of[key] {
                return id;
            }
            let (u, v) = match grid_vertices[g] {
                Some(sv) => (if i == nc { U_SEAM } else { sv.u }, sv.v),
                None => (cols[i % nc], rows[j]),
            };
            let id = uvs.len() as u32;
            uvs.push(head_uv(u, v));
            uv_of[key] = Some(id);
            id
        };

        let mut polygons: Vec<Vec<u32>> = Vec::new();
        let mut polygon_uvs: Vec<Vec<u32>> = Vec::new();
        for j in 0..nr - 1 {
            for i in 0..nc {
                if slits.iter().any(|s| s.row == j && i >= s.c0 && i < s.c1) {
                    continue;
                }
                let corners = [(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)];
                let mut poly: Vec<u32> = Vec::with_capacity(4);
                let mut puv: Vec<u32> = Vec::with_capacity(4);
                for (ci, cj) in corners {
                    let vtx = grid_to_vertex[gid(ci % nc, cj)];
                    if poly.contains(&vtx) {
                        continue;
                    }
                    poly.push(vtx);
                    puv.push(uv_id(ci, cj, &mut uvs));
                }
                polygons.push(poly);
                polygon_uvs.push(puv);
            }
        }
        // Crown: a fan of triangles around the pole, each with its own pole UV.
        let top = nr - 1;
        for i in 0..nc {
            let a = grid_to_vertex[gid(i, top)];
            let b = grid_to_vertex[gid((i + 1) % nc, top)];
            let ua = uv_id(i, top, &mut uvs);
            let ub = uv_id(i + 1, top, &mut uvs);
            let u_mid = 0.5 * (cols[i] + if i + 1 == nc { U_SEAM } else { cols[i + 1] });
            let up = uvs.len() as u32;
            uvs.push(head_uv(u_mid, V_POLE));
            polygons.push(vec![a, b, pole]);
            polygon_uvs.push(vec![ua, ub, up]);
        }

        // Eyeballs: latitude-longitude spheres with their poles on the gaze axis (+z),
        // so the iris is a disc around the front pole.
        let mut eyeball_dirs = vec![Vector3::z()];
        for k in 1..EYE_LAT {
            let alpha = std::f64::consts::PI * k as f64 / EYE_LAT as f64;
            for m in 0..EYE_LON {
                let beta = 2.0 * std::f64::consts::PI * m as f64 / EYE_LON as f64;
                eyeball_dirs.push(Vector3::new(
                    alpha.sin() * beta.cos(),
                    alpha.sin() * beta.sin(),
                    alpha.cos(),
                ));
            }
        }
        eyeball_dirs.push(-Vector3::z());
        let eyeball_len = eyeball_dirs.len();
        let first_l = skin.len();
        let eyeball_first = [first_l, first_l + eyeball_len];
        for (e, &first) in eyeball_first.iter().enumerate() {
            let u0 = 0.03 + 0.5 * e as f64;
            let uv_base = uvs.len() as u32;
            for k in 0..=EYE_LAT {
                for m in 0..=EYE_LON {
                    uvs.push(Point2::new(
                        u0 + 0.44 * m as f64 / EYE_LON as f64,
                        0.02 + 0.43 * (1.0 - k as f64 / EYE_LAT as f64),
                    ));
                }
            }
            let uv = |k: usize, m: usize| uv_base + (k * (EYE_LON + 1) + m) as u32;
            let vid = |k: usize, m: usize| -> u32 {
                (first
                    + match k {
                        0 => 0,
                        k if k == EYE_LAT => eyeball_len - 1,
                        k => 1 + (k - 1) * EYE_LON + m % EYE_LON,
                    }) as u32
            };
            for k in 0..EYE_LAT {
                for m in 0..EYE_LON {
                    let corners = [(k, m), (k + 1, m), (k + 1, m + 1), (k, m + 1)];
                    let mut poly = Vec::with_capacity(4);
                    let mut puv = Vec::with_capacity(4);
                    for (ck, cm) in corners {
                        let v = vid(ck, cm);
                        if !poly.contains(&v) {
                            poly.push(v);
                            puv.push(uv(ck, cm));
                        }
                    }
                    polygons.push(poly);
                    polygon_uvs.push(puv);
                }
            }
        }

        Ok(Self {
            cols,
            openings,
            skin,
            face_count,
            grid_to_vertex,
            eyeball_first,
            eyeball_len,
            eyeball_dirs,
            polygons,
            polygon_uvs,
            uvs,
        })
    }

    /// Canonical parameters `(u, v)` of a skin vertex with the eyelids in `lids`.
    pub(crate) fn skin_param(&self, sv: &SkinVertex, lids: &[LidState; 2]) -> (f64, f64) {
        match sv.kind {
            GridKind::Pole => (0.0, V_POLE),
            _ => (sv.u, sv.v_grid + self.openings.delta(sv.u, sv.v_grid, lids)),
        }
    }

    /// Neutral positions of identity `surface`: the skin, then both eyeballs.
    pub(crate) fn positions(&self, surface: &Surface) -> Vec<Point3<f64>> {
        let neutral = [LidState::default(); 2];
        let mut out: Vec<Point3<f64>> = self
            .skin
            .iter()
            .map(|sv| {
                let (u, v) = self.skin_param(sv, &neutral);
                surface.point(u, v)
            })
            .collect();
        for c in &surface.eye_centres {
            for d in &self.eyeball_dirs {
                out.push(Point3::from(c + super::surface::EYEBALL_RADIUS_MM * d));
            }
        }
        out
    }
}
