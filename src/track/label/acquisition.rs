//! Acquisition: labeling a frame with no tracks, by registering the unlabeled triangulated
//! points to the layout's neutral positions (module docs of [`super`], "Acquisition").

use nalgebra::{Isometry3, Point2, Point3, Vector3};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::{LabelStats, Labeler, PassResult};

/// Factor by which an expression template's fit must beat the neutral's to start the
/// tracks from it (see `Labeler::choose_expression`).
const TEMPLATE_MARGIN: f64 = 1.1;
use crate::align::horn_alignment;
use crate::numeric::NearestPoints;
use crate::stereo::pair_detections_where;

impl Labeler {
    /// Acquisition by registration (module docs). Returns the pose and the labels of a
    /// tracking pass under it, or None when the registration is ambiguous or too weak (or,
    /// on skin with much clutter, not decided yet: the search goes on next frame).
    pub(super) fn acquire(
        &mut self,
        pixels: &[Vec<Option<Point2<f64>>>; 2],
        stats: &mut LabelStats,
    ) -> Option<(Isometry3<f64>, PassResult)> {
        // Pair only finite detections, at most the best few hundred by quality per image,
        // remembering their original indices; never a streak (only a worn dot's blob,
        // which the neighbours of a tracked marker vouch for).
        let max = self.params.acquire_max_detections;
        let chosen: [Vec<usize>; 2] = [0, 1].map(|c| {
            let mut idx: Vec<usize> = (0..pixels[c].len())
                .filter(|&a| {
                    pixels[c][a].is_some() && self.blobs[c].get(a).is_none_or(|b| !b.streak)
                })
                .collect();
            if idx.len() > max {
                let quality = |a: usize| self.blobs[c].get(a).map_or(0.0, |b| b.quality);
                idx.sort_by(|&a, &b| quality(b).total_cmp(&quality(a)).then(a.cmp(&b)));
                idx.truncate(max);
                idx.sort_unstable();
            }
            idx
        });
        let px: [Vec<Point2<f64>>; 2] = [0, 1].map(|c| {
            chosen[c]
                .iter()
                .filter_map(|&a| pixels[c][a])
                .collect::<Vec<_>>()
        });
        // Pairs of blobs that are not the size of a dot at their depth, or do not fill
        // their ellipses as a dot does, are skin, not ink: they are not paired, and do not
        // make a dot's pairing ambiguous.
        let matches = pair_detections_where(
            &self.rig,
            &px[0],
            &px[1],
            &self.params.pair,
            |i, j, bundle| {
                let det = [chosen[0][i], chosen[1][j]];
                self.dot_sized(
                    &bundle.point_in_cam0,
                    det,
                    [0.0; 2],
                    self.params.first_sighting_size_ratio,
                ) && self.filled_like_a_dot(det)
            },
        );
        let points: Vec<Point3<f64>> = matches.iter().map(|s| s.bundle.point_in_cam0).collect();
        stats.paired = points.len();
        let p = &self.params;
        if points.len() < p.acquire_min_markers {
            self.acquisition = Search::default();
            return None;
        }
        let pose = self.register(&points)?;
        self.choose_expression(&pose, pixels);
        let p = &self.params;
        // Label with the tracking pass around the registered neutral (or expression).
        let preds = self.predictions(&pose, 1, 0.0);
        let pass = self.label_pass(&preds, pixels);
        let in_view = self.in_view(&preds);
        let needed = (p.acquire_min_inlier_fraction * in_view as f64)
            .ceil()
            .max(p.acquire_min_markers as f64) as usize;
        tracing::debug!(
            labels = pass.labels.len(),
            in_view,
            "labels under the registration"
        );
        if pass.labels.len() < needed {
            return None;
        }
        let (pose, rms) = self.estimate_pose(&pass.labels)?;
        if rms > p.max_pose_rms_mm {
            return None;
        }
        // Second pass under the refined pose.
        let preds = self.predictions(&pose, 1, 0.0);
        let mut pass = self.label_pass(&preds, pixels);
        pass.rejected += self.drop_sized_unlike_neighbours(&mut pass.labels);
        if pass.labels.len() < p.acquire_min_markers {
            return None;
        }
        self.start_confirming_new_tracks(&pose, &pass.labels, pixels);
        Some((pose, pass))
    }

    /// Starts the confirmation ([`super::CONFIRM_FRAMES`]) of the markers the
    /// acquisition's frame shows beside its labels. The acquisition takes whole dots that
    /// pair as dots on their own; a worn dot, or a dot a hair crosses, is taken only
    /// where neighbours labeled in the last frame put the marker, and the acquisition's
    /// frame has no last frame: such markers were first found in the frame after, confirmed
    /// in the one after that, and labeled two frames late. Here the tracking's pass is run
    /// on the acquisition's frame with the acquisition's `labels` as those neighbours (the
    /// tracks of their markers set as the labels leave them, `pose` the head's): a marker
    /// never labeled that it puts on a blob no label holds has been found once, and is
    /// labeled from the next frame on if found there too. Nothing more is labeled in this
    /// frame.
    fn start_confirming_new_tracks(
        &mut self,
        pose: &Isometry3<f64>,
        labels: &[super::Label],
        pixels: &[Vec<Option<Point2<f64>>>; 2],
    ) {
        let inverse = pose.inverse();
        let mut used: [Vec<bool>; 2] = [0, 1].map(|c| vec![false; pixels[c].len()]);
        for l in labels {
            let track = &mut self.tracks[l.marker];
            track.head = inverse * l.bundle.point_in_cam0;
            track.frames_since_seen = Some(0);
            for (used, &d) in used.iter_mut().zip(&l.det) {
                if let Some(u) = used.get_mut(d) {
                    *u = true;
                }
            }
        }
        let preds = self.predictions(pose, 1, 0.0);
        let pass = self.label_pass(&preds, pixels);
        for l in &pass.labels {
            let free = (0..2).all(|c| used[c].get(l.det[c]).is_some_and(|u| !u));
            let track = &mut self.tracks[l.marker];
            if free && track.frames_since_seen.is_none() {
                track.confirming = 1;
            }
        }
    }

    /// How many markers `preds` put in view of both cameras: inside both images, and
    /// with the skin's normal (when known) facing both.
    fn in_view(&self, preds: &[super::Prediction]) -> usize {
        let cam1_centre = self.rig.cam1_from_cam0.inverse() * Point3::origin();
        preds
            .iter()
            .filter(|pr| {
                pr.pixels.iter().all(Option::is_some)
                    && pr.normal.is_none_or(|n| {
                        n.dot(&(Point3::origin() - pr.point)) > 0.0
                            && n.dot(&(cam1_centre - pr.point)) > 0.0
                    })
            })
            .count()
    }

    /// RANSAC registration of unlabeled triangulated points to the neutral markers:
    /// returns `cam0_from_head`, or None when no hypothesis is both strong and unambiguous
    /// yet. At most [`super::LabelParams::acquire_iterations_per_frame`] triples are drawn
    /// per call; the best hypotheses carry over to the next frame's points (the head moves
    /// little in a frame, and ICP takes up the motion) until
    /// [`super::LabelParams::acquire_iterations`] were drawn, and the search starts over.
    pub(super) fn register(&mut self, points: &[Point3<f64>]) -> Option<Isometry3<f64>> {
        let mut search = std::mem::take(&mut self.acquisition);
        let p = &self.params;
        let m = self.neutral.len();
        let n = points.len();
        let grid = PointGrid::new(points, p.acquire_gate_mm);
        let tol = |d: f64| p.acquire_distance_tolerance_mm + p.acquire_distance_tolerance_rel * d;
        let mut rng =
            StdRng::seed_from_u64(0x6c61_6265_6c00 ^ n as u64 ^ ((search.iterations as u64) << 32));
        // Hypotheses of earlier frames, moved onto this frame's points.
        let mut top: Vec<(f64, Isometry3<f64>)> = Vec::new();
        for (_, t) in std::mem::take(&mut search.top) {
            let t = self.icp(t, &grid);
            let score = self.score(&t, &grid);
            self.keep_top(&mut top, score, t);
        }
        let (z0, z1) = p.pair.triangulate.depth_range_mm;
        let spread = p.acquire_min_spread_mm;
        let strong = 0.7 * n.min(m) as f64;
        let first = search.iterations;
        let last = (first + p.acquire_iterations_per_frame).min(p.acquire_iterations);
        // Hypotheses aligned and scored this frame: the work of an attempt, whatever the
        // number of candidate correspondences a triple brings.
        let mut hypotheses = 0usize;
        for iteration in first..last {
            // Enough evidence: a strong hypothesis and a good number of samples after it.
            if iteration >= 60 && top.first().is_some_and(|x| x.0 >= strong) {
                break;
            }
            if hypotheses >= p.acquire_hypotheses_per_frame {
                break;
            }
            search.iterations = iteration + 1;
            // A well-spread triple of observed points.
            let mut triple = None;
            for _ in 0..30 {
                let a = rng.random_range(0..n);
                let b = rng.random_range(0..n);
                let c = rng.random_range(0..n);
                if a == b || b == c || a == c {
                    continue;
                }
                let (dab, dac, dbc) = (
                    (points[a] - points[b]).norm(),
                    (points[a] - points[c]).norm(),
                    (points[b] - points[c]).norm(),
                );
                if dab >= spread && dac >= spread && dbc >= spread {
                    triple = Some((a, b, c, dab, dac, dbc));
                    break;
                }
            }
            let Some((a, b, c, dab, dac, dbc)) = triple else {
                continue;
            };
            let lo = self.pair_table.partition_point(|e| e.0 < dab - tol(dab));
            let hi = self.pair_table.partition_point(|e| e.0 <= dab + tol(dab));
            let (tac, tbc) = (tol(dac), tol(dbc));
            for &(_, i, j) in &self.pair_table[lo..hi] {
                let (i, j) = (i as usize, j as usize);
                for k in 0..m {
                    if k == i
                        || k == j
                        || (self.distances[i * m + k] - dac).abs() > tac
                        || (self.distances[j * m + k] - dbc).abs() > tbc
                    {
                        continue;
                    }
                    let Ok(t) = horn_alignment(
                        &[self.neutral[i], self.neutral[j], self.neutral[k]],
                        &[points[a], points[b], points[c]],
                        &[],
                    ) else {
                        continue;
                    };
                    // Prior: the face is in front of the cameras.
                    let centre = t * self.centroid();
                    if !(z0..=z1).contains(&centre.z) {
                        continue;
                    }
                    hypotheses += 1;
                    let score = self.score(&t, &grid);
                    self.keep_top(&mut top, score, t);
                }
            }
        }
        tracing::trace!(
            hypotheses,
            iterations = search.iterations - first,
            "acquisition samples"
        );
        // Refine the leading distinct hypotheses by ICP, then compare.
        let mut refined: Vec<(f64, usize, Isometry3<f64>)> = top
            .iter()
            .take(4)
            .map(|&(_, t)| {
                let t = self.icp(t, &grid);
                let (score, inliers) = self.score_with_inliers(&t, &grid);
                (score, inliers, t)
            })
            .collect();
        refined.sort_by(|x, y| y.0.total_cmp(&x.0));
        let Some(&(best_score, inliers, best)) = refined.first() else {
            if search.iterations < p.acquire_iterations {
                self.acquisition = search;
            }
            return None;
        };
        let rival = refined
            .iter()
            .skip(1)
            .filter(|(_, _, t)| !self.same_hypothesis(t, &best))
            .map(|x| x.0)
            .fold(0.0, f64::max);
        // How many of the points match is no measure of a registration on skin with
        // clutter (most pairs may be freckles and moles): the labeling pass under the pose
        // is (see `acquire`).
        tracing::debug!(best_score, rival, inliers, n, "registration");
        if inliers < p.acquire_min_markers || rival >= p.acquire_ambiguity_ratio * best_score {
            if search.iterations < p.acquire_iterations {
                // Not decided yet: go on next frame from these hypotheses.
                search.top = top;
                self.acquisition = search;
            }
            return None;
        }
        Some(best)
    }

    /// Starts the tracks from the expression template (or the neutral) whose predictions
    /// under `pose` the detections fit best. A face caught with its jaw wide open has chin
    /// markers 30 mm from their neutral places, where the lip markers are: labeled around
    /// the neutral, lip and chin labels swap. Each candidate is scored like the
    /// registration (MSAC: Σ `1 − (d/gate)²` over its labels, `d` the bundle's distance
    /// from its prediction); a template must beat the neutral by
    /// [`TEMPLATE_MARGIN`] to be taken, so a face near neutral never starts from an
    /// expression that explains clutter.
    fn choose_expression(&mut self, pose: &Isometry3<f64>, pixels: &[Vec<Option<Point2<f64>>>; 2]) {
        if self.templates.is_empty() {
            return;
        }
        let score = |this: &Self| -> f64 {
            let preds = this.predictions(pose, 1, 0.0);
            let pass = this.label_pass(&preds, pixels);
            pass.labels
                .iter()
                .map(|l| {
                    let pr = &preds[l.marker];
                    let d = (l.bundle.point_in_cam0 - pr.point).norm();
                    (1.0 - (d / pr.gate_mm.max(1e-9)).powi(2)).max(0.0)
                })
                .sum()
        };
        let neutral = score(self);
        let mut best: (f64, Option<usize>) = (neutral * TEMPLATE_MARGIN, None);
        let templates = std::mem::take(&mut self.templates);
        for (k, t) in templates.iter().enumerate() {
            for (track, q) in self.tracks.iter_mut().zip(t) {
                track.head = *q;
            }
            let s = score(self);
            if s > best.0 {
                best = (s, Some(k));
            }
        }
        let start = best.1.map_or(&self.neutral, |k| &templates[k]).clone();
        for (track, q) in self.tracks.iter_mut().zip(&start) {
            track.head = *q;
        }
        if let Some(k) = best.1 {
            tracing::debug!(
                template = k,
                score = best.0,
                neutral,
                "acquiring from an expression"
            );
        }
        self.templates = templates;
    }

    pub(super) fn centroid(&self) -> Point3<f64> {
        let s = self
            .neutral
            .iter()
            .fold(Vector3::zeros(), |a, q| a + q.coords);
        Point3::from(s / self.neutral.len() as f64)
    }

    /// MSAC score: Σ over neutral markers of `1 − (d/gate)²` for the nearest observed
    /// point within the gate.
    /// Gives up early (returning the partial score) when fewer than a fifth of the first
    /// 20 markers match: most hypotheses are wrong, and this keeps acquisition fast.
    pub(super) fn score(&self, t: &Isometry3<f64>, grid: &PointGrid) -> f64 {
        let g = self.params.acquire_gate_mm;
        let mut score = 0.0;
        let mut hits = 0;
        for (k, &i) in self.score_order.iter().enumerate() {
            if k == 20 && hits < 4 {
                break;
            }
            if let Some((_, d)) = grid.nearest(&(t * self.neutral[i])) {
                score += 1.0 - (d / g).powi(2);
                hits += 1;
            }
        }
        score
    }

    pub(super) fn score_with_inliers(&self, t: &Isometry3<f64>, grid: &PointGrid) -> (f64, usize) {
        let g = self.params.acquire_gate_mm;
        let mut score = 0.0;
        let mut inliers = 0;
        for q in &self.neutral {
            if let Some((_, d)) = grid.nearest(&(t * q)) {
                score += 1.0 - (d / g).powi(2);
                inliers += 1;
            }
        }
        (score, inliers)
    }

    /// Keeps up to 6 distinct hypotheses with the highest scores.
    pub(super) fn keep_top(
        &self,
        top: &mut Vec<(f64, Isometry3<f64>)>,
        score: f64,
        t: Isometry3<f64>,
    ) {
        if top.len() >= 6 && top.last().is_some_and(|x| x.0 >= score) {
            return;
        }
        if let Some(k) = top.iter().position(|(_, u)| self.same_hypothesis(u, &t)) {
            if top[k].0 >= score {
                return;
            }
            top.remove(k);
        }
        let at = top.partition_point(|x| x.0 >= score);
        top.insert(at, (score, t));
        top.truncate(6);
    }

    /// Two poses label the same way when no neutral marker moves by more than the gate.
    pub(super) fn same_hypothesis(&self, a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
        let g = self.params.acquire_gate_mm;
        self.neutral.iter().all(|q| (a * q - b * q).norm() < g)
    }

    /// Iterated closest points: mutual nearest neighbours within the gate, Horn.
    pub(super) fn icp(&self, mut t: Isometry3<f64>, grid: &PointGrid) -> Isometry3<f64> {
        for _ in 0..6 {
            let mut src = Vec::new();
            let mut dst = Vec::new();
            for q in &self.neutral {
                if let Some((k, _)) = grid.nearest(&(t * q)) {
                    src.push(*q);
                    dst.push(grid.points[k]);
                }
            }
            if src.len() < 3 {
                break;
            }
            match horn_alignment(&src, &dst, &[]) {
                Ok(u) => t = u,
                Err(_) => break,
            }
        }
        t
    }
}

/// An acquisition search under way over several frames: the best hypotheses so far and
/// the number of triples drawn.
#[derive(Debug, Clone, Default)]
pub(super) struct Search {
    top: Vec<(f64, Isometry3<f64>)>,
    iterations: usize,
}

/// Nearest-neighbour queries within a radius over the triangulated points.
///
/// Most queries of a registration are misses: a wrong hypothesis puts most neutral markers
/// where no point is. A coarse occupancy grid ([`Occupancy`]) answers those without the
/// tree, with the same answers.
pub(super) struct PointGrid {
    points: Vec<Point3<f64>>,
    radius_sq: f64,
    index: NearestPoints,
    occupancy: Option<Occupancy>,
}

impl PointGrid {
    /// Indexes `points` (non-finite ones are never found) for queries within `radius`.
    pub(super) fn new(points: &[Point3<f64>], radius: f64) -> Self {
        Self {
            points: points.to_vec(),
            radius_sq: radius * radius,
            index: NearestPoints::new(points.iter().copied()),
            occupancy: Occupancy::new(points, radius),
        }
    }

    /// Index and distance of the nearest point within the radius.
    pub(super) fn nearest(&self, q: &Point3<f64>) -> Option<(usize, f64)> {
        if self.occupancy.as_ref().is_some_and(|o| !o.may_hold(q)) {
            return None;
        }
        let (i, d2) = self.index.nearest(q)?;
        (d2 < self.radius_sq).then(|| (i, d2.sqrt()))
    }
}

/// Cubic cells, at least a query radius wide, over the bounding box of a set of points;
/// a cell is marked when it or one of its 26 neighbours holds a point. A point within the
/// radius of a query lies in the query's cell or a neighbour (the cells are wider than the
/// radius), so a query in an unmarked cell, or outside the grid, has none.
#[derive(Debug, Clone)]
struct Occupancy {
    origin: Vector3<f64>,
    cell: f64,
    dims: [usize; 3],
    marked: Vec<u64>,
}

impl Occupancy {
    /// Most cells of a grid: a wider spread of points gets wider cells (the test stays
    /// exact, it only rules out fewer queries).
    const MAX_CELLS: usize = 1 << 21;

    /// The grid of the finite `points` for queries within `radius`; None without a
    /// finite point or a positive finite radius.
    fn new(points: &[Point3<f64>], radius: f64) -> Option<Self> {
        if !(radius.is_finite() && radius > 0.0) {
            return None;
        }
        let finite = || {
            points
                .iter()
                .filter(|p| p.coords.iter().all(|v| v.is_finite()))
        };
        let lo = finite().fold(None, |acc: Option<Vector3<f64>>, p| {
            Some(acc.map_or(p.coords, |a| a.inf(&p.coords)))
        })?;
        let hi = finite().fold(lo, |a, p| a.sup(&p.coords));
        // A hair wider than the radius, so that rounding cannot put a point within the
        // radius two cells away.
        let mut cell = radius * (1.0 + 1e-9);
        let dims_for = |cell: f64| -> [usize; 3] {
            // One cell of margin either side of the points' cells.
            [0, 1, 2].map(|a| ((hi[a] - lo[a]) / cell).floor().min(1e12) as usize + 3)
        };
        let mut dims = dims_for(cell);
        while dims
            .iter()
            .try_fold(1usize, |n, &d| n.checked_mul(d))
            .is_none_or(|n| n > Self::MAX_CELLS)
        {
            cell *= 2.0;
            dims = dims_for(cell);
        }
        let mut grid = Self {
            origin: lo - Vector3::repeat(cell),
            cell,
            dims,
            marked: vec![0; (dims[0] * dims[1] * dims[2]).div_ceil(64)],
        };
        for p in finite() {
            // In 1..=dims − 2 on every axis (the margin holds the neighbours); clamped
            // there, as rounding may put a point on the box's side in the margin.
            let [x, y, z] = [0, 1, 2].map(|a| {
                let c = ((p[a] - grid.origin[a]) / cell).floor();
                (c.max(1.0) as usize).min(dims[a] - 2)
            });
            for k in z - 1..=z + 1 {
                for j in y - 1..=y + 1 {
                    for i in x - 1..=x + 1 {
                        let n = (k * dims[1] + j) * dims[0] + i;
                        grid.marked[n / 64] |= 1 << (n % 64);
                    }
                }
            }
        }
        Some(grid)
    }

    /// The cell holding `q`; None outside the grid or for a non-finite point.
    fn cell_of(&self, q: &Point3<f64>) -> Option<[usize; 3]> {
        let mut cell = [0; 3];
        for a in 0..3 {
            let c = ((q[a] - self.origin[a]) / self.cell).floor();
            if !(c >= 0.0 && c < self.dims[a] as f64) {
                return None;
            }
            cell[a] = c as usize;
        }
        Some(cell)
    }

    /// Whether a point may lie within the radius of `q` (false: none does).
    fn may_hold(&self, q: &Point3<f64>) -> bool {
        self.cell_of(q).is_some_and(|[x, y, z]| {
            let n = (z * self.dims[1] + y) * self.dims[0] + x;
            self.marked[n / 64] & (1 << (n % 64)) != 0
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The nearest point within `radius` by looking at every point.
    fn brute_force(points: &[Point3<f64>], q: &Point3<f64>, radius: f64) -> Option<(usize, f64)> {
        points
            .iter()
            .enumerate()
            .map(|(i, p)| (i, (p - q).norm_squared()))
            .filter(|&(_, d2)| d2.is_finite() && d2 < radius * radius)
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, d2)| (i, d2.sqrt()))
    }

    #[test]
    fn the_occupancy_grid_leaves_every_answer_as_the_tree_gives_it() {
        let mut rng = StdRng::seed_from_u64(7);
        let radius = 3.0;
        let mut face: Vec<Point3<f64>> = (0..120)
            .map(|_| {
                Point3::new(
                    rng.random_range(-70.0..70.0),
                    rng.random_range(-90.0..90.0),
                    rng.random_range(90.0..180.0),
                )
            })
            .collect();
        face.push(Point3::new(f64::NAN, 0.0, 120.0));
        // A mispaired blob triangulated far away widens the grid's cells.
        let mut spread = face.clone();
        spread.push(Point3::new(5e4, -3e4, 9e4));
        for points in [&face, &spread] {
            let grid = PointGrid::new(points, radius);
            let occupancy = grid.occupancy.as_ref().expect("finite points");
            assert!(occupancy.cell >= radius);
            let (mut hits, mut skipped) = (0, 0);
            for k in 0..20_000 {
                let q = if k % 2 == 0 {
                    // Near a point: at, inside and just beyond the radius.
                    let p = points[rng.random_range(0..120)];
                    let dir = Vector3::new(
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(-1.0..1.0),
                    )
                    .normalize();
                    p + dir * radius * rng.random_range(0.9..1.1)
                } else {
                    Point3::new(
                        rng.random_range(-120.0..120.0),
                        rng.random_range(-140.0..140.0),
                        rng.random_range(40.0..240.0),
                    )
                };
                let expected = brute_force(points, &q, radius);
                let found = grid.nearest(&q);
                assert_eq!(found.map(|f| f.0), expected.map(|e| e.0), "query {q}");
                if let (Some(f), Some(e)) = (found, expected) {
                    assert!((f.1 - e.1).abs() < 1e-12);
                }
                hits += usize::from(expected.is_some());
                skipped += usize::from(!occupancy.may_hold(&q));
            }
            assert!(hits > 2_000, "{hits} hits: the queries test too little");
            if std::ptr::eq(points, &face) {
                assert!(
                    skipped > 8_000,
                    "only {skipped} of 20,000 queries ruled out"
                );
            }
        }
        assert_eq!(
            PointGrid::new(&face, radius).nearest(&Point3::new(f64::NAN, 0.0, 0.0)),
            None
        );
        assert!(
            PointGrid::new(&[Point3::new(f64::NAN, 1.0, 1.0)], radius)
                .occupancy
                .is_none()
        );
    }
}
