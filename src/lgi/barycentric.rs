//! Barycentric coordinates in tetrahedra and closest points on simplices (Cong et al. 2019
//! §4: "we compute the convex barycentric weights (w_i, w_j, w_k, w_l) of the bundle
//! position"; outside every tetrahedron, "the barycentric coordinates for the closest point
//! on the associated tetrahedralized volume").

use nalgebra::{Matrix3, Point3, Vector3};

/// Barycentric coordinates of `x` in the tetrahedron `p`: `w` with `Σ w = 1` and
/// `Σ w_n p_n = x`. `None` when the tetrahedron is degenerate (zero volume).
pub fn tet_barycentric(p: &[Point3<f64>; 4], x: &Point3<f64>) -> Option<[f64; 4]> {
    let m = Matrix3::from_columns(&[p[1] - p[0], p[2] - p[0], p[3] - p[0]]);
    let inv = m.try_inverse()?;
    let w = inv * (x - p[0]);
    Some([1.0 - w.x - w.y - w.z, w.x, w.y, w.z])
}

/// Signed volume (times 6) of the tetrahedron `a b c d`: `det[b − a, c − a, d − a]`.
pub fn orient(a: &Point3<f64>, b: &Point3<f64>, c: &Point3<f64>, d: &Point3<f64>) -> f64 {
    (b - a).dot(&(c - a).cross(&(d - a)))
}

/// The points `[i, j, k]` of every triple index below [`NARROW_CODES`] (the inverse of
/// [`triple_index`], the same for every cloud), built once.
fn narrow_triples() -> &'static [[u8; 3]] {
    static TABLE: std::sync::OnceLock<Vec<[u8; 3]>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut out = Vec::with_capacity(NARROW_CODES);
        'fill: for k in 2..=255u8 {
            for j in 1..k {
                for i in 0..j {
                    if out.len() == NARROW_CODES {
                        break 'fill;
                    }
                    out.push([i, j, k]);
                }
            }
        }
        out
    })
}

/// The corners (ascending) of the tetrahedron with face triples `faces` (see
/// [`TripleTable::faces`]): `(a, b, c)` from the last face and `d` from the first, by
/// table look-up when the triples are below [`NARROW_CODES`]; `None` otherwise.
#[inline]
pub fn corners_from_faces(faces: &[u32; 4]) -> Option<[u16; 4]> {
    let table = narrow_triples();
    let abc = table.get(faces[3] as usize)?;
    let bcd = table.get(faces[0] as usize)?;
    Some([
        u16::from(abc[0]),
        u16::from(abc[1]),
        u16::from(abc[2]),
        u16::from(bcd[2]),
    ])
}

/// Index of the triple `i < j < k` in the combinatorial order of [`TripleTable`].
#[inline]
pub fn triple_index(i: usize, j: usize, k: usize) -> usize {
    k * (k - 1) * (k - 2) / 6 + j * (j - 1) / 2 + i
}

/// Orientations `T(i, j, k) = det[p_i − x, p_j − x, p_k − x]` of a query point `x` against
/// every triple of a point cloud, so that the barycentric coordinates of `x` in any
/// tetrahedron `a < b < c < d` of the cloud are four look-ups:
///
/// `w = (T(b,c,d), −T(a,c,d), T(a,b,d), −T(a,b,c)) / det[b − a, c − a, d − a]`.
///
/// For the all-combinations tetrahedralization of §4.1 this is far cheaper than a
/// per-tetrahedron solve: `C(n, 3)` determinants per frame serve `C(n, 4)` tetrahedra.
#[derive(Debug, Default, Clone)]
pub struct TripleTable {
    values: Vec<f64>,
    rel: Vec<nalgebra::Vector3<f64>>,
    /// Sign codes of `values` ([`SIGN_POS`], [`SIGN_NEG`] or 0 near zero), filled by
    /// [`TripleTable::fill_used_coded`].
    codes: Vec<u8>,
    /// `rel` by coordinate, for the vectorized full fill (kept to reuse the memory).
    rel_by_axis: [Vec<f64>; 3],
}

/// Sign code of a triple value clearly above zero (see [`TetScan`]).
pub const SIGN_POS: u8 = 1;
/// Sign code of a triple value clearly below zero (see [`TetScan`]).
pub const SIGN_NEG: u8 = 2;

/// A compact form of a marker's tetrahedra for the per-frame containment scan: each
/// tetrahedron's four face triples (16-bit when the cloud is small enough, so the scan
/// streams 8 bytes per tetrahedron) and a sign mask. A tetrahedron can contain the query
/// only if none of its face orientations has the wrong sign by more than `tolerance`;
/// that pre-test reads one byte per face from [`TripleTable`]'s sign codes, and only the
/// tetrahedra passing it get the exact test ([`TripleTable::inside`]). `tolerance` is
/// twice `1e-9` times the largest `|det|` of the marker's tetrahedra, so every tetrahedron
/// the exact test (slack `−1e-9` on the barycentric weights) accepts passes the pre-test:
/// the scan finds exactly what a full scan finds, in the same order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TetScan {
    /// Face triples as 16-bit indices (empty when `wide` is used).
    narrow: Vec<[u16; 4]>,
    /// Face triples as 32-bit indices (clouds with more than 65 536 triples).
    wide: Vec<[u32; 4]>,
    /// Per tetrahedron: the sign codes that rule out containment on its even faces (bits
    /// 0–1) and odd faces (bits 2–3); 0 for a degenerate tetrahedron (always tested).
    masks: Vec<u8>,
    /// Orientation values within this of zero count as either sign.
    pub tolerance: f64,
}

impl TetScan {
    /// The scan form of tetrahedra with face triples `faces` and `inv_volume`
    /// (`1 / det`, 0 when degenerate).
    pub fn new(faces: &[[u32; 4]], inv_volume: &[f64]) -> Self {
        let max_det = inv_volume
            .iter()
            .filter(|&&iv| iv != 0.0)
            .map(|iv| (1.0 / iv).abs())
            .fold(0.0, f64::max);
        let masks = inv_volume
            .iter()
            .map(|&iv| {
                if iv > 0.0 {
                    // w0, w2 = +T · inv must not be negative; w1, w3 = −T · inv likewise.
                    SIGN_NEG | (SIGN_POS << 2)
                } else if iv < 0.0 {
                    SIGN_POS | (SIGN_NEG << 2)
                } else {
                    0
                }
            })
            .collect();
        let largest = faces.iter().flatten().copied().max().unwrap_or(0);
        let (narrow, wide) = if largest <= u32::from(u16::MAX) {
            let narrow = faces
                .iter()
                .map(|f| f.map(|x| u16::try_from(x).unwrap_or(u16::MAX)))
                .collect();
            (narrow, Vec::new())
        } else {
            (Vec::new(), faces.to_vec())
        };
        Self {
            narrow,
            wide,
            masks,
            tolerance: 2e-9 * max_det,
        }
    }

    /// Number of tetrahedra.
    pub fn len(&self) -> usize {
        self.masks.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.masks.is_empty()
    }

    /// The face triples of tetrahedron `t` (see [`TripleTable::faces`]).
    #[inline]
    pub fn faces(&self, t: usize) -> [u32; 4] {
        if self.wide.is_empty() {
            self.narrow[t].map(u32::from)
        } else {
            self.wide[t]
        }
    }

    /// Whether tetrahedron `t` passes the sign pre-test against `codes`.
    #[inline]
    pub fn may_contain(&self, codes: &[u8], t: usize) -> bool {
        let m = self.masks[t];
        let f = self.faces(t).map(|x| x as usize);
        sign_ok(codes, f, m)
    }

    /// Calls `hit(t, faces)` with every tetrahedron `t` passing the pre-test against
    /// `codes`, ascending, and its face triples.
    ///
    /// The pre-test runs branch-free over blocks of 64 tetrahedra into a bit mask, and
    /// only the set bits are visited: most tetrahedra fail, and a branch per tetrahedron
    /// mispredicts often. With 16-bit triples and at least [`NARROW_CODES`] codes (as
    /// [`TripleTable::fill_used_coded`] leaves them), the look-ups need no bounds checks.
    #[inline]
    pub fn for_each_candidate(&self, codes: &[u8], mut hit: impl FnMut(usize, [u32; 4])) {
        if self.wide.is_empty() {
            if let Some(codes) = codes
                .get(..NARROW_CODES)
                .and_then(|c| <&[u8; NARROW_CODES]>::try_from(c).ok())
            {
                for_each_in_blocks(&self.narrow, &self.masks, &mut hit, |f, m| {
                    let even = (codes[usize::from(f[0])] | codes[usize::from(f[2])]) & m;
                    let odd = (codes[usize::from(f[1])] | codes[usize::from(f[3])]) & (m >> 2);
                    even | odd == 0
                });
            } else {
                for_each_in_blocks(&self.narrow, &self.masks, &mut hit, |f, m| {
                    sign_ok(codes, f.map(usize::from), m)
                });
            }
        } else {
            for_each_in_blocks(&self.wide, &self.masks, &mut hit, |f, m| {
                sign_ok(codes, f.map(|x| x as usize), m)
            });
        }
    }
}

/// Codes a [`TripleTable`] keeps at least, so that any 16-bit triple index is in range.
pub const NARROW_CODES: usize = 1 << 16;

/// Runs `pass` over `faces` and `masks` in blocks of 64 into a bit mask, then calls `hit`
/// for the set bits (see [`TetScan::for_each_candidate`]).
#[inline(always)]
fn for_each_in_blocks<F: FaceTriples>(
    faces: &[F],
    masks: &[u8],
    hit: &mut impl FnMut(usize, [u32; 4]),
    pass: impl Fn(F, u8) -> bool,
) {
    for (block, (fb, mb)) in faces.chunks(64).zip(masks.chunks(64)).enumerate() {
        let mut bits = 0u64;
        for (k, (&f, &m)) in fb.iter().zip(mb).enumerate() {
            bits |= u64::from(pass(f, m)) << k;
        }
        while bits != 0 {
            let k = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            hit(block * 64 + k, fb[k].widen());
        }
    }
}

/// A tetrahedron's face triples at either width, as [`TetScan`] stores them.
trait FaceTriples: Copy {
    fn widen(self) -> [u32; 4];
}

impl FaceTriples for [u16; 4] {
    #[inline(always)]
    fn widen(self) -> [u32; 4] {
        self.map(u32::from)
    }
}

impl FaceTriples for [u32; 4] {
    #[inline(always)]
    fn widen(self) -> [u32; 4] {
        self
    }
}

/// The sign pre-test of one tetrahedron (see [`TetScan`]).
#[inline(always)]
fn sign_ok(codes: &[u8], f: [usize; 4], mask: u8) -> bool {
    let c = |i: usize| codes.get(i).copied().unwrap_or(0);
    let even = (c(f[0]) | c(f[2])) & mask;
    let odd = (c(f[1]) | c(f[3])) & (mask >> 2);
    even | odd == 0
}

impl TripleTable {
    /// Fills the table for `points` and query `x`.
    pub fn fill(&mut self, points: &[Point3<f64>], x: &Point3<f64>) {
        let n = points.len();
        self.rel.clear();
        self.rel.extend(points.iter().map(|p| p - x));
        self.values.clear();
        self.values
            .resize(n * n.saturating_sub(1) * n.saturating_sub(2) / 6, 0.0);
        for k in 2..n {
            for j in 1..k {
                let c = self.rel[j].cross(&self.rel[k]);
                let base = triple_index(0, j, k);
                for i in 0..j {
                    self.values[base + i] = self.rel[i].dot(&c);
                }
            }
        }
    }

    /// Fills only the `used` triples ([`UsedTriples`]) for
    /// `points` and query `x`; the other entries keep stale values and must not be read.
    pub fn fill_used(&mut self, points: &[Point3<f64>], x: &Point3<f64>, used: &UsedTriples) {
        let n = points.len();
        self.rel.clear();
        self.rel.extend(points.iter().map(|p| p - x));
        let size = n * n.saturating_sub(1) * n.saturating_sub(2) / 6;
        // Grown, never cleared: only the entries filled here are read.
        if self.values.len() < size {
            self.values.resize(size, 0.0);
        }
        let (rel, values) = (&self.rel, &mut self.values);
        used.for_each_group(|j, k, is| {
            let c = rel[j].cross(&rel[k]);
            let base = triple_index(0, j, k);
            for &i in is {
                values[base + usize::from(i)] = rel[usize::from(i)].dot(&c);
            }
        });
    }

    /// [`TripleTable::fill_used`], and the sign codes of the filled values: [`SIGN_POS`]
    /// above `tolerance`, [`SIGN_NEG`] below `−tolerance`, else 0 (see [`TetScan`]).
    pub fn fill_used_coded(
        &mut self,
        points: &[Point3<f64>],
        x: &Point3<f64>,
        used: &UsedTriples,
        tolerance: f64,
    ) {
        self.fill_with_codes(points, x, used, |_, v| {
            if v > tolerance {
                SIGN_POS
            } else if v < -tolerance {
                SIGN_NEG
            } else {
                0
            }
        });
    }

    /// [`TripleTable::fill_used`], with sign codes that mark a value only when the query
    /// is more than `tol_mm` from the triple's plane (`|value| · inv_area2[triple]`, see
    /// [`triple_inv_area2`]). With these codes the [`TetScan`] pre-test passes exactly
    /// the tetrahedra `TripleTable::near` (the tests' reference) accepts with the same `tol_mm`.
    pub fn fill_used_coded_near(
        &mut self,
        points: &[Point3<f64>],
        x: &Point3<f64>,
        used: &UsedTriples,
        inv_area2: &[f64],
        tol_mm: f64,
    ) {
        self.fill_with_codes(points, x, used, |idx, v| {
            let far = v.abs() * inv_area2.get(idx).copied().unwrap_or(0.0) > tol_mm;
            if !far {
                0
            } else if v > 0.0 {
                SIGN_POS
            } else {
                SIGN_NEG
            }
        });
    }

    /// Fills the `used` values and their codes (`code(index, value)`); the codes keep at
    /// least [`NARROW_CODES`] entries. When most triples are used, fills every triple
    /// instead, in the table's own order: a straight loop over `i` the compiler
    /// vectorizes, faster than following the list.
    #[inline(always)]
    fn fill_with_codes(
        &mut self,
        points: &[Point3<f64>],
        x: &Point3<f64>,
        used: &UsedTriples,
        code: impl Fn(usize, f64) -> u8,
    ) {
        let n = points.len();
        self.rel.clear();
        self.rel.extend(points.iter().map(|p| p - x));
        let size = n * n.saturating_sub(1) * n.saturating_sub(2) / 6;
        // Grown, never cleared: only the entries filled here are read.
        if self.values.len() < size {
            self.values.resize(size, 0.0);
        }
        if self.codes.len() < size.max(NARROW_CODES) {
            self.codes.resize(size.max(NARROW_CODES), 0);
        }
        if used.len() * 4 >= size * 3 {
            for (axis, coords) in self.rel_by_axis.iter_mut().enumerate() {
                coords.clear();
                coords.extend(self.rel.iter().map(|r| r[axis]));
            }
            let [xs, ys, zs] = &self.rel_by_axis;
            for k in 2..n {
                for j in 1..k {
                    let c = self.rel[j].cross(&self.rel[k]);
                    let base = triple_index(0, j, k);
                    let vals = &mut self.values[base..base + j];
                    for (((v, &px), &py), &pz) in vals.iter_mut().zip(xs).zip(ys).zip(zs) {
                        *v = px * c.x + py * c.y + pz * c.z;
                    }
                    for (i, (cd, &v)) in self.codes[base..base + j]
                        .iter_mut()
                        .zip(vals.iter())
                        .enumerate()
                    {
                        *cd = code(base + i, v);
                    }
                }
            }
            return;
        }
        let (rel, values, codes) = (&self.rel, &mut self.values, &mut self.codes);
        used.for_each_group(|j, k, is| {
            let c = rel[j].cross(&rel[k]);
            let base = triple_index(0, j, k);
            for &i in is {
                let idx = base + usize::from(i);
                let v = rel[usize::from(i)].dot(&c);
                values[idx] = v;
                codes[idx] = code(idx, v);
            }
        });
    }

    /// Barycentric coordinates of the query in the tetrahedron with face triples `faces`
    /// ([`TripleTable::faces`]), from the table alone: the four face values, signed as in
    /// [`TripleTable::inside`], over their sum (which is `det[b − a, c − a, d − a]`).
    /// Not finite for a degenerate tetrahedron.
    #[inline]
    pub fn weights(&self, faces: &[u32; 4]) -> [f64; 4] {
        let v = &self.values;
        let t = faces.map(|f| v.get(f as usize).copied().unwrap_or(f64::NAN));
        let w = [t[0], -t[1], t[2], -t[3]];
        let inv = 1.0 / (w[0] + w[1] + w[2] + w[3]);
        w.map(|x| x * inv)
    }

    /// The distance bound of `TripleTable::near` for weights `w` of the tetrahedron with
    /// face triples `faces`: the largest distance of the query outside one of its face
    /// planes (0 inside).
    #[inline]
    pub fn outside_distance(&self, faces: &[u32; 4], w: &[f64; 4], inv_area2: &[f64]) -> f64 {
        // Branch-free: the sign of each weight is as good as random here.
        let mut d: f64 = 0.0;
        for k in 0..4 {
            let f = faces[k] as usize;
            let t = self.values.get(f).copied().unwrap_or(0.0);
            let outside = f64::from(u8::from(w[k] < 0.0));
            d = d.max(outside * t.abs() * inv_area2.get(f).copied().unwrap_or(0.0));
        }
        d
    }

    /// The sign codes of the last [`TripleTable::fill_used_coded`].
    pub fn codes(&self) -> &[u8] {
        &self.codes
    }

    /// The four face triples of tetrahedron `t` (corners ascending) in the order the
    /// barycentric coordinates need them (see [`TripleTable::inside`]).
    pub fn faces(t: &[u16; 4]) -> [u32; 4] {
        let (a, b, c, d) = (t[0] as usize, t[1] as usize, t[2] as usize, t[3] as usize);
        [
            triple_index(b, c, d) as u32,
            triple_index(a, c, d) as u32,
            triple_index(a, b, d) as u32,
            triple_index(a, b, c) as u32,
        ]
    }

    /// Barycentric coordinates of the query in the tetrahedron with face triples `faces`
    /// ([`TripleTable::faces`]) and `inv_volume = 1 / det[b − a, c − a, d − a]`, or `None`
    /// as soon as one is below `slack` (the query is outside).
    #[inline]
    pub fn inside(&self, faces: &[u32; 4], inv_volume: f64, slack: f64) -> Option<[f64; 4]> {
        // Branch-free: the four look-ups, then one test (most tetrahedra fail it, and an
        // early exit per coordinate mispredicts often).
        let v = &self.values;
        let t0 = v.get(faces[0] as usize).copied().unwrap_or(f64::NAN);
        let t1 = v.get(faces[1] as usize).copied().unwrap_or(f64::NAN);
        let t2 = v.get(faces[2] as usize).copied().unwrap_or(f64::NAN);
        let t3 = v.get(faces[3] as usize).copied().unwrap_or(f64::NAN);
        let w = [
            t0 * inv_volume,
            -t1 * inv_volume,
            t2 * inv_volume,
            -t3 * inv_volume,
        ];
        let lo = w[0].min(w[1]).min(w[2].min(w[3]));
        (lo >= slack).then_some(w)
    }

    /// Barycentric coordinates of the query in the tetrahedron with face triples `faces`
    /// and a lower bound of its distance to the tetrahedron (the largest distance outside
    /// one of its face planes; 0 inside), or `None` when that bound exceeds `tol_mm`.
    /// `inv_area2[f]` is `1 / (2 · area)` of triple `f`'s triangle.
    ///
    /// The reference the per-frame scan's near codes reproduce
    /// ([`TripleTable::fill_used_coded_near`]); only the tests call it.
    #[cfg(test)]
    pub fn near(
        &self,
        faces: &[u32; 4],
        inv_volume: f64,
        inv_area2: &[f64],
        tol_mm: f64,
    ) -> Option<([f64; 4], f64)> {
        let v = &self.values;
        let mut w = [0.0; 4];
        let mut d: f64 = 0.0;
        for k in 0..4 {
            let t = v[faces[k] as usize];
            w[k] = if k % 2 == 0 { t } else { -t } * inv_volume;
            if w[k] < 0.0 {
                d = d.max(t.abs() * inv_area2[faces[k] as usize]);
                if d > tol_mm {
                    return None;
                }
            }
        }
        Some((w, d))
    }

    /// Barycentric coordinates of the query in tetrahedron `t` (corners ascending) with
    /// `inv_volume = 1 / det[b − a, c − a, d − a]`.
    #[inline]
    pub fn barycentric(&self, t: &[u16; 4], inv_volume: f64) -> [f64; 4] {
        let (a, b, c, d) = (t[0] as usize, t[1] as usize, t[2] as usize, t[3] as usize);
        let v = &self.values;
        [
            v[triple_index(b, c, d)] * inv_volume,
            -v[triple_index(a, c, d)] * inv_volume,
            v[triple_index(a, b, d)] * inv_volume,
            -v[triple_index(a, b, c)] * inv_volume,
        ]
    }
}

/// The distinct face triples of a set of tetrahedra: all a [`TripleTable`] needs for
/// them. Grouped by their two largest points `(j, k)` (one cross product per group), with
/// the smallest points `i` of a group stored as 16-bit numbers: two bytes per triple, so
/// a frame streams little memory even for large clouds.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct UsedTriples {
    /// Per group: `(j, k, end)`, ascending by triple index; the group's `i` are
    /// `smallest[previous end..end]`.
    groups: Vec<(u16, u16, u32)>,
    /// The smallest points of every group's triples, ascending within a group.
    smallest: Vec<u16>,
}

impl UsedTriples {
    /// The face triples of `tets` (corners ascending).
    pub fn new(tets: &[[u16; 4]]) -> Self {
        let mut all: Vec<(u32, [u16; 3])> = tets
            .iter()
            .flat_map(|t| {
                let (a, b, c, d) = (t[0], t[1], t[2], t[3]);
                [[b, c, d], [a, c, d], [a, b, d], [a, b, c]]
            })
            .map(|f| {
                (
                    triple_index(f[0] as usize, f[1] as usize, f[2] as usize) as u32,
                    f,
                )
            })
            .collect();
        all.sort_unstable_by_key(|e| e.0);
        all.dedup_by_key(|e| e.0);
        let mut out = Self::default();
        for (_, [i, j, k]) in all {
            if out.groups.last().is_none_or(|g| (g.0, g.1) != (j, k)) {
                out.groups.push((j, k, out.smallest.len() as u32));
            }
            out.smallest.push(i);
            if let Some(g) = out.groups.last_mut() {
                g.2 = out.smallest.len() as u32;
            }
        }
        out
    }

    /// Number of triples.
    pub fn len(&self) -> usize {
        self.smallest.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.smallest.is_empty()
    }

    /// Calls `f(j, k, is)` for every group, ascending.
    #[inline]
    fn for_each_group(&self, mut f: impl FnMut(usize, usize, &[u16])) {
        let mut start = 0usize;
        for &(j, k, end) in &self.groups {
            let end = end as usize;
            f(usize::from(j), usize::from(k), &self.smallest[start..end]);
            start = end;
        }
    }
}

/// `1 / (2 · area)` of the triangle of every triple of `points`, in [`triple_index`]
/// order (0 for degenerate triangles).
pub fn triple_inv_area2(points: &[Point3<f64>]) -> Vec<f64> {
    let n = points.len();
    let mut out = vec![0.0; n * n.saturating_sub(1) * n.saturating_sub(2) / 6];
    for k in 2..n {
        for j in 1..k {
            for i in 0..j {
                let a2 = (points[j] - points[i])
                    .cross(&(points[k] - points[i]))
                    .norm();
                out[triple_index(i, j, k)] = if a2 > 0.0 { 1.0 / a2 } else { 0.0 };
            }
        }
    }
    out
}

/// Closest point to `x` on the triangle `a b c` (Ericson, Real-Time Collision Detection
/// §5.1.5), as barycentric weights `(wa, wb, wc)`, convex. Works for degenerate triangles.
pub fn closest_on_triangle(
    a: &Point3<f64>,
    b: &Point3<f64>,
    c: &Point3<f64>,
    x: &Point3<f64>,
) -> [f64; 3] {
    let ab = b - a;
    let ac = c - a;
    let ap = x - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return [1.0, 0.0, 0.0];
    }
    let bp = x - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return [0.0, 1.0, 0.0];
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return [1.0 - v, v, 0.0];
    }
    let cp = x - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return [0.0, 0.0, 1.0];
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return [1.0 - w, 0.0, w];
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return [0.0, 1.0 - w, w];
    }
    let denom = va + vb + vc;
    if denom.abs() <= f64::MIN_POSITIVE {
        // Degenerate (collinear) triangle: best of its three edges.
        let edges = [(a, b, [0, 1]), (b, c, [1, 2]), (a, c, [0, 2])];
        let mut best = [1.0, 0.0, 0.0];
        let mut best_d = f64::INFINITY;
        for (p, q, [i, j]) in edges {
            let t = closest_on_segment(p, q, x);
            let y = p + (q - p) * t;
            let d = (y - x).norm_squared();
            if d < best_d {
                best_d = d;
                best = [0.0; 3];
                best[i] = 1.0 - t;
                best[j] = t;
            }
        }
        return best;
    }
    let v = vb / denom;
    let w = vc / denom;
    [1.0 - v - w, v, w]
}

/// Parameter `t ∈ [0, 1]` of the closest point `a + t (b − a)` to `x` on segment `a b`.
pub fn closest_on_segment(a: &Point3<f64>, b: &Point3<f64>, x: &Point3<f64>) -> f64 {
    let d = b - a;
    let l2 = d.norm_squared();
    if l2 <= 0.0 {
        return 0.0;
    }
    ((x - a).dot(&d) / l2).clamp(0.0, 1.0)
}

/// Closest point to `x` on the simplex with `corners` (1 to 4 points), as convex weights
/// over the corners (unused entries 0). Inside a tetrahedron the weights are `x`'s own
/// barycentric coordinates.
pub fn closest_on_simplex(corners: &[Point3<f64>], x: &Point3<f64>) -> [f64; 4] {
    match corners {
        [a] => {
            let _ = a;
            [1.0, 0.0, 0.0, 0.0]
        }
        [a, b] => {
            let t = closest_on_segment(a, b, x);
            [1.0 - t, t, 0.0, 0.0]
        }
        [a, b, c] => {
            let w = closest_on_triangle(a, b, c, x);
            [w[0], w[1], w[2], 0.0]
        }
        [a, b, c, d] => {
            let p = [*a, *b, *c, *d];
            if let Some(w) = tet_barycentric(&p, x)
                && w.iter().all(|&v| v >= 0.0)
            {
                return w;
            }
            let faces = [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]];
            let mut best = [1.0, 0.0, 0.0, 0.0];
            let mut best_d = f64::INFINITY;
            for f in faces {
                let w = closest_on_triangle(&p[f[0]], &p[f[1]], &p[f[2]], x);
                let y = Point3::from(
                    p[f[0]].coords * w[0] + p[f[1]].coords * w[1] + p[f[2]].coords * w[2],
                );
                let dd = (y - x).norm_squared();
                if dd < best_d {
                    best_d = dd;
                    best = [0.0; 4];
                    for k in 0..3 {
                        best[f[k]] = w[k];
                    }
                }
            }
            best
        }
        _ => [1.0, 0.0, 0.0, 0.0],
    }
}

/// The point with convex `weights` over `corners`.
pub fn combine(corners: &[Point3<f64>], weights: &[f64; 4]) -> Point3<f64> {
    let mut v = Vector3::zeros();
    for (p, w) in corners.iter().zip(weights) {
        v += p.coords * *w;
    }
    Point3::from(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tet() -> [Point3<f64>; 4] {
        [
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(2.0, 0.0, 0.0),
            Point3::new(0.0, 3.0, 0.0),
            Point3::new(0.0, 0.0, 4.0),
        ]
    }

    #[test]
    fn barycentric_reproduces_point() {
        let p = tet();
        let x = Point3::new(0.3, 0.5, 0.7);
        let w = tet_barycentric(&p, &x).unwrap();
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!((combine(&p, &w) - x).norm() < 1e-12);
        assert!(w.iter().all(|&v| v > 0.0));
        let flat = [p[0], p[1], p[2], Point3::new(1.0, 1.0, 0.0)];
        assert!(tet_barycentric(&flat, &x).is_none());
    }

    #[test]
    fn triple_table_gives_barycentrics() {
        let pts = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(2.0, 0.1, 0.0),
            Point3::new(0.3, 3.0, 0.0),
            Point3::new(0.0, 0.2, 4.0),
            Point3::new(1.0, 1.0, 1.0),
        ];
        let x = Point3::new(0.4, 0.6, 0.5);
        let mut table = TripleTable::default();
        table.fill(&pts, &x);
        for t in [[0u16, 1, 2, 3], [0, 1, 2, 4], [1, 2, 3, 4], [0, 2, 3, 4]] {
            let p = [
                pts[t[0] as usize],
                pts[t[1] as usize],
                pts[t[2] as usize],
                pts[t[3] as usize],
            ];
            let inv = 1.0 / orient(&p[0], &p[1], &p[2], &p[3]);
            let w = table.barycentric(&t, inv);
            let expect = tet_barycentric(&p, &x).unwrap();
            for k in 0..4 {
                assert!(
                    (w[k] - expect[k]).abs() < 1e-12,
                    "{t:?}: {w:?} vs {expect:?}"
                );
            }
        }
    }

    /// The sign pre-test passes every tetrahedron the exact test accepts.
    #[test]
    fn scan_pretest_keeps_every_containing_tet() {
        let mut pts = Vec::new();
        for i in 0..9u32 {
            let f = f64::from(i);
            pts.push(Point3::new(
                (f * 1.7).sin() * 3.0,
                (f * 2.3).cos() * 2.0,
                (f * 0.9).sin() * (f * 0.4).cos() * 4.0,
            ));
        }
        // Some points coplanar with others, so values near zero occur.
        pts.push(Point3::from((pts[0].coords + pts[1].coords) * 0.5));
        let mut tets = Vec::new();
        for a in 0..pts.len() as u16 {
            for b in a + 1..pts.len() as u16 {
                for c in b + 1..pts.len() as u16 {
                    for d in c + 1..pts.len() as u16 {
                        tets.push([a, b, c, d]);
                    }
                }
            }
        }
        let faces: Vec<[u32; 4]> = tets.iter().map(TripleTable::faces).collect();
        let inv: Vec<f64> = tets
            .iter()
            .map(|t| {
                let o = orient(
                    &pts[t[0] as usize],
                    &pts[t[1] as usize],
                    &pts[t[2] as usize],
                    &pts[t[3] as usize],
                );
                if o != 0.0 { 1.0 / o } else { 0.0 }
            })
            .collect();
        let scan = TetScan::new(&faces, &inv);
        let used = UsedTriples::new(&tets);
        // Near-flat tetrahedra (the index drops them) are left out of the comparisons of
        // weights: theirs are huge and the two ways of computing them agree only roughly.
        let max_det = inv
            .iter()
            .filter(|&&v| v != 0.0)
            .map(|v| 1.0 / v.abs())
            .fold(0.0, f64::max);
        let flat = |t: usize| inv[t] == 0.0 || 1.0 / inv[t].abs() < 1e-6 * max_det;
        let mut table = TripleTable::default();
        let (mut found, mut pruned) = (0, 0);
        for q in 0..200u32 {
            let f = f64::from(q);
            // Queries include the points themselves and points on faces.
            let x = if q % 10 == 0 {
                pts[(q / 10) as usize % pts.len()]
            } else {
                Point3::new(
                    (f * 0.37).sin() * 3.0,
                    (f * 0.71).cos() * 2.0,
                    (f * 0.13).sin(),
                )
            };
            table.fill_used_coded(&pts, &x, &used, scan.tolerance);
            let mut fast = Vec::new();
            scan.for_each_candidate(table.codes(), |t, f| {
                assert_eq!(f, faces[t]);
                assert_eq!(corners_from_faces(&f), Some(tets[t]));
                let w = table.weights(&f);
                if !flat(t) && w.iter().all(|&v| v >= -1e-9) {
                    fast.push(t);
                    let exact = table.inside(&faces[t], inv[t], -1e-9).unwrap();
                    for k in 0..4 {
                        let tol = 1e-9 * exact[k].abs().max(1.0);
                        assert!((w[k] - exact[k]).abs() < tol, "query {q}, tet {t}");
                    }
                }
            });
            let full: Vec<usize> = (0..tets.len())
                .filter(|&t| !flat(t))
                .filter(|&t| table.inside(&faces[t], inv[t], -1e-9).is_some())
                .collect();
            assert_eq!(fast, full, "query {q}");
            found += full.len();
            let mut cands = 0;
            scan.for_each_candidate(table.codes(), |_, _| cands += 1);
            pruned += tets.len() - cands;
            // With the near codes the pre-test passes exactly what `near` accepts.
            let area = triple_inv_area2(&pts);
            for tol in [0.05, 0.5] {
                table.fill_used_coded_near(&pts, &x, &used, &area, tol);
                let mut passed = Vec::new();
                scan.for_each_candidate(table.codes(), |t, f| {
                    if flat(t) {
                        return;
                    }
                    let w = table.weights(&f);
                    let (wn, d) = table.near(&faces[t], inv[t], &area, tol).unwrap();
                    assert!((table.outside_distance(&f, &w, &area) - d).abs() < 1e-9);
                    assert!((0..4).all(|k| (w[k] - wn[k]).abs() < 1e-9 * wn[k].abs().max(1.0)));
                    passed.push(t);
                });
                let near: Vec<usize> = (0..tets.len())
                    .filter(|&t| !flat(t))
                    .filter(|&t| table.near(&faces[t], inv[t], &area, tol).is_some())
                    .collect();
                assert_eq!(passed, near, "query {q}, tolerance {tol}");
            }
        }
        assert!(found > 0 && pruned > 0, "{found} found, {pruned} pruned");
    }

    #[test]
    fn closest_points_are_closest() {
        let p = tet();
        // Brute force over a fine sampling of the tetrahedron's faces for a few outside points.
        for x in [
            Point3::new(3.0, 3.0, 3.0),
            Point3::new(-1.0, -1.0, -1.0),
            Point3::new(1.0, 1.0, -2.0),
            Point3::new(0.5, 5.0, 0.5),
        ] {
            let w = closest_on_simplex(&p, &x);
            assert!(w.iter().all(|&v| v >= -1e-12));
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            let d = (combine(&p, &w) - x).norm();
            let n = 40;
            let mut brute = f64::INFINITY;
            for i in 0..=n {
                for j in 0..=n - i {
                    for k in 0..=n - i - j {
                        let (a, b, c) = (
                            i as f64 / n as f64,
                            j as f64 / n as f64,
                            k as f64 / n as f64,
                        );
                        let y = combine(&p, &[1.0 - a - b - c, a, b, c]);
                        brute = brute.min((y - x).norm());
                    }
                }
            }
            assert!(d <= brute + 1e-9, "{d} > {brute}");
            assert!(d > brute - 0.2, "{d} far below sampled {brute}");
        }
        // Inside: the point itself.
        let x = Point3::new(0.2, 0.2, 0.2);
        assert!((combine(&p, &closest_on_simplex(&p, &x)) - x).norm() < 1e-12);
        // Segments and points.
        let s = [Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 0.0, 0.0)];
        let w = closest_on_simplex(&s, &Point3::new(2.0, 1.0, 0.0));
        assert_eq!(w, [0.0, 1.0, 0.0, 0.0]);
        let tri = [s[0], s[1], Point3::new(2.0, 0.0, 0.0)];
        let w = closest_on_simplex(&tri, &Point3::new(1.5, 1.0, 0.0));
        assert!((combine(&tri, &w) - Point3::new(1.5, 0.0, 0.0)).norm() < 1e-12);
    }
}
