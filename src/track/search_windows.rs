//! Search windows: the union of the rectangles a detector looks in (one around each
//! predicted marker while tracking), held as merged column spans per band of rows so that
//! the detector's row loop finds a row's spans in `O(log bands)`.

use nalgebra::Point2;

/// A rectangle `(x0, y0, x1, y1)`, pixels, end exclusive.
pub type Rect = (u32, u32, u32, u32);

/// Whether `p` (pixel centres at integers) lies in one of `rects`.
pub fn in_any(rects: &[Rect], p: Point2<f64>) -> bool {
    rects.iter().any(|&(x0, y0, x1, y1)| {
        p.x >= f64::from(x0) && p.x < f64::from(x1) && p.y >= f64::from(y0) && p.y < f64::from(y1)
    })
}

/// The union of rectangles, clipped to a region (see the module docs).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SearchWindows {
    /// Bands of rows `(y0, y1, first, end)`: rows `y0..y1` hold the spans
    /// `spans[first..end]`. Increasing and disjoint; rows between bands hold no window.
    bands: Vec<(usize, usize, usize, usize)>,
    /// Column spans `(x0, x1)`, end exclusive, sorted and disjoint within a band.
    spans: Vec<(usize, usize)>,
    /// Bounding box of the union `(x0, y0, x1, y1)`.
    bounds: Option<(usize, usize, usize, usize)>,
}

impl SearchWindows {
    /// The union of `rects`, each clipped to `clip = (x0, y0, x1, y1)` (end exclusive).
    pub fn new(rects: &[Rect], clip: (usize, usize, usize, usize)) -> Self {
        let clipped: Vec<(usize, usize, usize, usize)> = rects
            .iter()
            .map(|&(a, b, c, d)| {
                (
                    (a as usize).max(clip.0),
                    (b as usize).max(clip.1),
                    (c as usize).min(clip.2),
                    (d as usize).min(clip.3),
                )
            })
            .filter(|r| r.0 < r.2 && r.1 < r.3)
            .collect();
        let mut rows: Vec<usize> = clipped.iter().flat_map(|r| [r.1, r.3]).collect();
        rows.sort_unstable();
        rows.dedup();
        let mut out = Self::default();
        let mut row_spans: Vec<(usize, usize)> = Vec::new();
        // A sweep down the bands: the rectangles in order of their first row, and those
        // over the current band (a band's rows lie in a rectangle or not at all).
        let mut by_top: Vec<usize> = (0..clipped.len()).collect();
        by_top.sort_unstable_by_key(|&i| clipped[i].1);
        let mut next = 0;
        let mut over: Vec<usize> = Vec::new();
        for band in rows.windows(2) {
            let (ya, yb) = (band[0], band[1]);
            while let Some(&i) = by_top.get(next).filter(|&&i| clipped[i].1 <= ya) {
                over.push(i);
                next += 1;
            }
            over.retain(|&i| ya < clipped[i].3);
            row_spans.clear();
            row_spans.extend(over.iter().map(|&i| (clipped[i].0, clipped[i].2)));
            if row_spans.is_empty() {
                continue;
            }
            row_spans.sort_unstable();
            let first = out.spans.len();
            for &(a, b) in &row_spans {
                let merge = out.spans.len() > first;
                match out.spans.last_mut() {
                    Some(last) if merge && a <= last.1 => last.1 = last.1.max(b),
                    _ => out.spans.push((a, b)),
                }
            }
            // Adjacent bands with the same spans are one band.
            if let Some(prev) = out.bands.last_mut()
                && prev.1 == ya
                && out.spans[prev.2..prev.3] == out.spans[first..]
            {
                prev.1 = yb;
                out.spans.truncate(first);
                continue;
            }
            out.bands.push((ya, yb, first, out.spans.len()));
        }
        out.bounds = out.bands.first().map(|&(y0, ..)| {
            let (x0, x1) = out
                .spans
                .iter()
                .fold((usize::MAX, 0), |(a, b), s| (a.min(s.0), b.max(s.1)));
            (x0, y0, x1, out.bands[out.bands.len() - 1].1)
        });
        out
    }

    /// Bounding box `(x0, y0, x1, y1)` of the union, None when it is empty.
    pub fn bounds(&self) -> Option<(usize, usize, usize, usize)> {
        self.bounds
    }

    /// The column spans of row `y` (empty outside every window).
    pub fn row(&self, y: usize) -> &[(usize, usize)] {
        let i = self.bands.partition_point(|b| b.1 <= y);
        match self.bands.get(i) {
            Some(&(y0, _, first, end)) if y0 <= y => &self.spans[first..end],
            _ => &[],
        }
    }

    /// Whether the pixels `x0..x1` of row `y` all lie in one of the union's spans.
    pub fn covers(&self, y: usize, x0: usize, x1: usize) -> bool {
        self.row(y).iter().any(|&(a, b)| a <= x0 && x1 <= b)
    }

    /// Whether the box `(x0, y0, x1, y1)` (inclusive) grown by a pixel, within an image
    /// of `width × height` pixels, lies in the union: a blob inside the box has no pixel
    /// next to one the windows leave out (where nothing was looked for), so it cannot be
    /// part of a larger blob beyond them.
    pub fn hold_with_border(
        &self,
        (x0, y0, x1, y1): (usize, usize, usize, usize),
        (width, height): (usize, usize),
    ) -> bool {
        let (a, b) = (x0.saturating_sub(1), (x1 + 2).min(width));
        (y0.saturating_sub(1)..(y1 + 2).min(height)).all(|y| self.covers(y, a, b))
    }

    /// Number of pixels in the union.
    pub fn area(&self) -> usize {
        self.bands
            .iter()
            .map(|&(y0, y1, first, end)| {
                (y1 - y0)
                    * self.spans[first..end]
                        .iter()
                        .map(|s| s.1 - s.0)
                        .sum::<usize>()
            })
            .sum()
    }
}

/// Rectangles bucketed in square cells, to ask whether a box meets any of them in time
/// that grows with the rectangles near the box, not with all of them (a detector asks it
/// of every blob in the windows, with a hundred rectangles a camera).
#[derive(Debug, Clone)]
pub struct RectGrid<'a> {
    rects: &'a [Rect],
    /// Corner of cell (0, 0), pixels.
    origin: (i64, i64),
    /// Cells per row and per column.
    size: (usize, usize),
    /// Rectangles of cell `k`: `members[offsets[k]..offsets[k + 1]]`.
    offsets: Vec<usize>,
    members: Vec<u32>,
}

impl<'a> RectGrid<'a> {
    /// Side of a cell, pixels.
    const CELL_PX: i64 = 32;

    /// The grid of `rects`.
    pub fn new(rects: &'a [Rect]) -> Self {
        // Each rectangle's cells: those over its columns `a..c` and rows `b..d`, and for
        // an empty or inverted one, over `c − 1..=a` (the columns every box that
        // `meets_any` counts as meeting it holds; likewise rows).
        let span = |a: u32, c: u32| {
            let (a, last) = (i64::from(a), i64::from(c) - 1);
            (a.min(last), a.max(last))
        };
        let spans: Vec<((i64, i64), (i64, i64))> = rects
            .iter()
            .map(|&(a, b, c, d)| (span(a, c), span(b, d)))
            .collect();
        let origin = spans.iter().fold((i64::MAX, i64::MAX), |o, (x, y)| {
            (o.0.min(x.0), o.1.min(y.0))
        });
        let end = spans.iter().fold((i64::MIN, i64::MIN), |e, (x, y)| {
            (e.0.max(x.1), e.1.max(y.1))
        });
        let mut grid = Self {
            rects,
            origin,
            size: (0, 0),
            offsets: vec![0],
            members: Vec::new(),
        };
        if spans.is_empty() {
            return grid;
        }
        let cells = |lo: i64, hi: i64| ((hi - lo) / Self::CELL_PX + 1) as usize;
        grid.size = (cells(origin.0, end.0), cells(origin.1, end.1));
        let cell_range = |(lo, hi): (i64, i64), o: i64| {
            ((lo - o) / Self::CELL_PX) as usize..=((hi - o) / Self::CELL_PX) as usize
        };
        let mut counts = vec![0usize; grid.size.0 * grid.size.1 + 1];
        for (x, y) in &spans {
            for cy in cell_range(*y, origin.1) {
                for cx in cell_range(*x, origin.0) {
                    counts[cy * grid.size.0 + cx + 1] += 1;
                }
            }
        }
        for k in 1..counts.len() {
            counts[k] += counts[k - 1];
        }
        grid.members = vec![0; counts[counts.len() - 1]];
        let mut fill = counts.clone();
        for (i, (x, y)) in spans.iter().enumerate() {
            for cy in cell_range(*y, origin.1) {
                for cx in cell_range(*x, origin.0) {
                    let k = cy * grid.size.0 + cx;
                    grid.members[fill[k]] = i as u32;
                    fill[k] += 1;
                }
            }
        }
        grid.offsets = counts;
        grid
    }

    /// Whether the box of columns `x0..=x1` and rows `y0..=y1` meets one of the rectangles
    /// `(a, b, c, d)`: `x0 < c`, `x1 ≥ a`, `y0 < d` and `y1 ≥ b`.
    pub fn meets_any(&self, (x0, y0, x1, y1): (i64, i64, i64, i64)) -> bool {
        let (cols, rows) = self.size;
        if cols == 0 || x1 < x0 || y1 < y0 {
            return false;
        }
        let clamp = |v: i64, o: i64, n: usize| ((v - o).max(0) / Self::CELL_PX).min(n as i64 - 1);
        let (cx0, cx1) = (
            clamp(x0, self.origin.0, cols),
            clamp(x1, self.origin.0, cols),
        );
        let (cy0, cy1) = (
            clamp(y0, self.origin.1, rows),
            clamp(y1, self.origin.1, rows),
        );
        (cy0..=cy1).any(|cy| {
            (cx0..=cx1).any(|cx| {
                let k = cy as usize * cols + cx as usize;
                self.members[self.offsets[k]..self.offsets[k + 1]]
                    .iter()
                    .any(|&i| {
                        let (a, b, c, d) = self.rects[i as usize];
                        x0 < i64::from(c)
                            && x1 >= i64::from(a)
                            && y0 < i64::from(d)
                            && y1 >= i64::from(b)
                    })
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    use super::*;

    #[test]
    fn the_grid_tells_boxes_that_meet_a_rectangle_as_brute_force() {
        let mut rects: Vec<Rect> = vec![(40, 40, 40, 40), (90, 10, 80, 12), (0, 0, 1, 1)];
        let mut rng = StdRng::seed_from_u64(7);
        let mut next = |n: u32| rng.random_range(0..n);
        for _ in 0..60 {
            let (x, y) = (next(300), next(200));
            rects.push((x, y, x + next(50), y + next(50)));
        }
        let grid = RectGrid::new(&rects);
        let mut met = 0;
        for _ in 0..20_000 {
            let (x0, y0) = (i64::from(next(400)) - 40, i64::from(next(300)) - 40);
            let b = (x0, y0, x0 + i64::from(next(30)), y0 + i64::from(next(30)));
            let brute = rects.iter().any(|&(a, bb, c, d)| {
                b.0 < i64::from(c)
                    && b.2 >= i64::from(a)
                    && b.1 < i64::from(d)
                    && b.3 >= i64::from(bb)
            });
            assert_eq!(grid.meets_any(b), brute, "{b:?}");
            met += usize::from(brute);
        }
        assert!(met > 2_000 && met < 18_000, "{met} boxes met a rectangle");
        assert!(!RectGrid::new(&[]).meets_any((0, 0, 10, 10)));
    }

    /// Membership by brute force.
    fn inside(rects: &[Rect], clip: (usize, usize, usize, usize), x: usize, y: usize) -> bool {
        x >= clip.0
            && y >= clip.1
            && x < clip.2
            && y < clip.3
            && rects.iter().any(|&(a, b, c, d)| {
                x >= a as usize && x < c as usize && y >= b as usize && y < d as usize
            })
    }

    #[test]
    fn union_of_overlapping_rectangles_equals_brute_force() {
        let rects: Vec<Rect> = vec![
            (10, 10, 30, 30),
            (25, 20, 50, 40),
            (60, 5, 70, 15),
            (0, 45, 100, 47),
            (69, 0, 80, 12),
            (5, 90, 200, 120),
        ];
        let clip = (2, 3, 95, 100);
        let w = SearchWindows::new(&rects, clip);
        let mut area = 0;
        for y in 0..130 {
            let spans = w.row(y);
            assert!(
                spans.windows(2).all(|p| p[0].1 < p[1].0),
                "row {y}: {spans:?}"
            );
            for x in 0..210 {
                let in_span = spans.iter().any(|s| x >= s.0 && x < s.1);
                assert_eq!(in_span, inside(&rects, clip, x, y), "({x}, {y})");
                area += usize::from(in_span);
            }
        }
        assert_eq!(w.area(), area);
        assert_eq!(w.bounds(), Some((2, 3, 95, 100)));
    }

    #[test]
    fn many_random_rectangles_give_each_row_their_union() {
        let mut rng = StdRng::seed_from_u64(23);
        for round in 0..60 {
            let size = [40, 300, 900][round % 3];
            let rects: Vec<Rect> = (0..rng.random_range(0..120))
                .map(|_| {
                    let (x, y) = (rng.random_range(0..size), rng.random_range(0..size));
                    let (w, h) = (rng.random_range(0..60), rng.random_range(0..60));
                    (x, y, x + w, y + h)
                })
                .collect();
            let clip = (3, 5, size as usize - 2, size as usize - 7);
            let w = SearchWindows::new(&rects, clip);
            for y in (0..size as usize + 70).step_by(1 + round % 7) {
                let spans = w.row(y);
                assert!(
                    spans.windows(2).all(|p| p[0].1 < p[1].0),
                    "row {y}: {spans:?}"
                );
                for x in 0..size as usize + 70 {
                    let in_span = spans.iter().any(|s| x >= s.0 && x < s.1);
                    assert_eq!(
                        in_span,
                        inside(&rects, clip, x, y),
                        "round {round} ({x}, {y})"
                    );
                }
            }
        }
    }

    #[test]
    fn a_box_is_held_when_its_border_lies_in_the_windows_or_off_the_image() {
        // Two windows sharing an edge: rows 10..20 span 10..50, rows 20..30 span 10..30.
        let w = SearchWindows::new(&[(10, 10, 30, 30), (30, 10, 50, 20)], (0, 0, 100, 100));
        let image = (100, 100);
        assert!(w.hold_with_border((11, 11, 28, 28), image));
        // Grown by a pixel, it reaches row 30 or column 30 below row 20: outside.
        assert!(!w.hold_with_border((11, 11, 28, 29), image));
        assert!(!w.hold_with_border((11, 11, 29, 28), image));
        // Across the shared edge, above row 19: inside.
        assert!(w.hold_with_border((11, 11, 48, 18), image));
        assert!(!w.hold_with_border((11, 11, 48, 19), image));
        // The image's edges are no border: a window up to them holds a box that touches them.
        let edge = SearchWindows::new(&[(0, 0, 20, 20)], (0, 0, 20, 20));
        assert!(edge.hold_with_border((0, 0, 19, 19), (20, 20)));
        assert!(!edge.hold_with_border((0, 0, 19, 19), (21, 20)));
    }

    #[test]
    fn empty_and_clipped_away_rectangles_give_no_spans() {
        let w = SearchWindows::new(&[(50, 50, 60, 60), (5, 5, 5, 9)], (0, 0, 40, 40));
        assert_eq!(w.bounds(), None);
        assert_eq!(w.area(), 0);
        assert!(w.row(55).is_empty() && w.row(6).is_empty());
    }
}
