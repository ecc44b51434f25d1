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
        for band in rows.windows(2) {
            let (ya, yb) = (band[0], band[1]);
            row_spans.clear();
            row_spans.extend(
                clipped
                    .iter()
                    .filter(|r| r.1 <= ya && ya < r.3)
                    .map(|r| (r.0, r.2)),
            );
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

#[cfg(test)]
mod tests {
    use super::*;

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
    fn empty_and_clipped_away_rectangles_give_no_spans() {
        let w = SearchWindows::new(&[(50, 50, 60, 60), (5, 5, 5, 9)], (0, 0, 40, 40));
        assert_eq!(w.bounds(), None);
        assert_eq!(w.area(), 0);
        assert!(w.row(55).is_empty() && w.row(6).is_empty());
    }
}
