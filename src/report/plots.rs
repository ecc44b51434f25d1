//! The report's plots, drawn with [`plotters`] into SVG text for inline use in the pages
//! (no `xmlns` attribute: HTML puts an inline `<svg>` in the SVG namespace itself, and the
//! page then holds no URL at all).
//!
//! Long takes are summarized before drawing (line plots at most [`MAX_LINE_POINTS`]
//! points, heat-map cells of equal colour merged along each row), so a page stays small
//! whatever the take's length.

use plotters::coord::Shift;
use plotters::prelude::{
    ChartBuilder, Color, DrawingArea, IntoDrawingArea, LineSeries, RGBColor, Rectangle, SVGBackend,
    ShapeStyle, WHITE,
};

use super::ReportError;
use super::take::{Coverage, PoseRun};
use crate::align::PoseSource;

/// Most points of a line plot; longer series are averaged over equal frame bins.
pub const MAX_LINE_POINTS: usize = 800;

/// Width of the take plots, pixels (the pages scale them to the window).
pub const PLOT_WIDTH: u32 = 900;

/// Colour of lines and bars.
pub const LINE: RGBColor = RGBColor(31, 119, 180);
/// Head pose estimated from the frame's markers.
pub const POSE_ESTIMATED: RGBColor = RGBColor(44, 160, 44);
/// Head pose held from an earlier frame.
pub const POSE_HELD: RGBColor = RGBColor(255, 160, 30);
/// No head pose.
pub const POSE_NONE: RGBColor = RGBColor(214, 39, 40);

/// Font of every label.
const FONT: &str = "sans-serif";

/// Levels a coverage share is rounded to before colouring (neighbouring cells of one
/// level merge into one rectangle).
const COVERAGE_LEVELS: f32 = 20.0;

/// Viridis, sampled at 0, ¼, ½, ¾ and 1.
const VIRIDIS: [[f64; 3]; 5] = [
    [68.0, 1.0, 84.0],
    [59.0, 82.0, 139.0],
    [33.0, 145.0, 140.0],
    [94.0, 201.0, 98.0],
    [253.0, 231.0, 37.0],
];

/// The colour of `t` (0..1, clamped) on the viridis scale (dark purple to yellow), as
/// the heat-map draws it and the page's legend shows it.
pub fn viridis(t: f64) -> [u8; 3] {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f64;
    let mix = |c: usize| (VIRIDIS[i][c] * (1.0 - f) + VIRIDIS[i + 1][c] * f).round() as u8;
    [mix(0), mix(1), mix(2)]
}

/// A drawing error as the report's error.
fn draw_err(what: &str) -> impl Fn(&dyn std::fmt::Display) -> ReportError + '_ {
    move |e| ReportError::Draw {
        what: what.to_string(),
        message: e.to_string(),
    }
}

/// Draws into a `width × height` SVG with `draw` and returns the SVG text.
fn svg(
    what: &str,
    width: u32,
    height: u32,
    draw: impl FnOnce(&DrawingArea<SVGBackend, Shift>) -> Result<(), ReportError>,
) -> Result<String, ReportError> {
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw_err(what)(&e))?;
        draw(&root)?;
        root.present().map_err(|e| draw_err(what)(&e))?;
    }
    Ok(text.replacen(" xmlns=\"http://www.w3.org/2000/svg\"", "", 1))
}

/// The coverage heat-map: one row per marker (first marker on top), one column per time
/// bin, coloured by the share of the bin's frames in which the marker was observed
/// ([`viridis`]).
pub fn coverage(c: &Coverage) -> Result<String, ReportError> {
    const WHAT: &str = "coverage plot";
    let n = c.markers.len().max(1);
    let row = (360 / n).clamp(2, 12) as u32;
    let height = row * n as u32 + 70;
    let (x0, x1) = match (c.bins.first(), c.bins.last()) {
        (Some(a), Some(z)) => (a.0 as f64, z.1 as f64 + 1.0),
        _ => (0.0, 1.0),
    };
    let label_every = (n / 12).max(1);
    svg(WHAT, PLOT_WIDTH, height, |root| {
        let err = draw_err(WHAT);
        let mut chart = ChartBuilder::on(root)
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            // Row i at y = i, counted from the top (a reversed axis).
            .build_cartesian_2d(x0..x1, n as f64 - 0.5..-0.5)
            .map_err(|e| err(&e))?;
        let names = |y: &f64| {
            let i = y.round();
            if (y - i).abs() < 1e-6 && i >= 0.0 {
                c.markers.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        };
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("frame")
            .y_desc("marker")
            .y_labels(n.div_ceil(label_every))
            .y_label_formatter(&names)
            .x_label_formatter(&|x| format!("{x:.0}"))
            .label_style((FONT, 12))
            .draw()
            .map_err(|e| err(&e))?;
        let mut cells = Vec::new();
        for (i, shares) in c.share.iter().enumerate() {
            let y = i as f64;
            let mut start = 0;
            // Runs of bins of one colour level.
            while start < shares.len() {
                let level = (shares[start] * COVERAGE_LEVELS).round();
                let mut end = start + 1;
                while end < shares.len() && (shares[end] * COVERAGE_LEVELS).round() == level {
                    end += 1;
                }
                let [r, g, b] = viridis(f64::from(level / COVERAGE_LEVELS));
                let (a, z) = (c.bins[start].0 as f64, c.bins[end - 1].1 as f64 + 1.0);
                cells.push(Rectangle::new(
                    [(a, y - 0.5), (z, y + 0.5)],
                    ShapeStyle::from(RGBColor(r, g, b)).filled(),
                ));
                start = end;
            }
        }
        chart.draw_series(cells).map_err(|e| err(&e))?;
        Ok(())
    })
}

/// Averages a per-frame series over equal frame bins when it has more than
/// [`MAX_LINE_POINTS`] points; series are split where frames are missing.
fn line_segments(points: &[(usize, f64)]) -> Vec<Vec<(f64, f64)>> {
    let (Some(first), Some(last)) = (points.first(), points.last()) else {
        return Vec::new();
    };
    let span = last.0.saturating_sub(first.0) + 1;
    let per_bin = span.div_ceil(MAX_LINE_POINTS).max(1);
    let mut segments: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut previous_bin = None;
    let mut acc = (0.0, 0.0, 0usize);
    // Appends the bin's mean to the current segment.
    let flush = |acc: &mut (f64, f64, usize), segments: &mut Vec<Vec<(f64, f64)>>| {
        if acc.2 > 0 {
            let point = (acc.0 / acc.2 as f64, acc.1 / acc.2 as f64);
            match segments.last_mut() {
                Some(s) => s.push(point),
                None => segments.push(vec![point]),
            }
        }
        *acc = (0.0, 0.0, 0);
    };
    for &(frame, v) in points {
        if !v.is_finite() {
            continue;
        }
        let bin = (frame - first.0) / per_bin;
        match previous_bin {
            Some(p) if p == bin => {}
            Some(p) => {
                let gap = bin > p + 1;
                flush(&mut acc, &mut segments);
                if gap {
                    segments.push(Vec::new());
                }
            }
            None => {}
        }
        previous_bin = Some(bin);
        acc.0 += frame as f64;
        acc.1 += v;
        acc.2 += 1;
    }
    flush(&mut acc, &mut segments);
    segments.retain(|s| !s.is_empty());
    segments
}

/// A line plot of a per-frame series (frame, value) with the value axis from `y_min` to
/// `y_max` (`None`: 10 % above the series' largest value).
pub fn frame_series(
    what: &str,
    points: &[(usize, f64)],
    frame_range: (usize, usize),
    y_desc: &str,
    y_min: f64,
    y_max: Option<f64>,
) -> Result<String, ReportError> {
    let segments = line_segments(points);
    let top = y_max.unwrap_or_else(|| {
        let m = segments
            .iter()
            .flatten()
            .map(|p| p.1)
            .fold(f64::NEG_INFINITY, f64::max);
        if m.is_finite() && m > y_min {
            y_min + (m - y_min) * 1.1
        } else {
            y_min + 1.0
        }
    });
    let (x0, x1) = (frame_range.0 as f64, frame_range.1 as f64 + 1.0);
    svg(what, PLOT_WIDTH, 240, |root| {
        let err = draw_err(what);
        let mut chart = ChartBuilder::on(root)
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x0..x1, y_min..top)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .y_desc(y_desc)
            .x_label_formatter(&|x| format!("{x:.0}"))
            .label_style((FONT, 12))
            .light_line_style(RGBColor(238, 238, 238))
            .draw()
            .map_err(|e| err(&e))?;
        for s in segments {
            if s.len() == 1 {
                // A lone point: a short tick so that it shows.
                let (x, y) = s[0];
                chart
                    .draw_series(LineSeries::new(
                        [(x - 0.4, y), (x + 0.4, y)],
                        LINE.stroke_width(2),
                    ))
                    .map_err(|e| err(&e))?;
            } else {
                chart
                    .draw_series(LineSeries::new(s, LINE.stroke_width(2)))
                    .map_err(|e| err(&e))?;
            }
        }
        Ok(())
    })
}

/// The head-pose strip: the frame range coloured by where each frame's pose came from
/// (estimated, held, none).
pub fn pose_strip(runs: &[PoseRun], frame_range: (usize, usize)) -> Result<String, ReportError> {
    const WHAT: &str = "head pose plot";
    let (x0, x1) = (frame_range.0 as f64, frame_range.1 as f64 + 1.0);
    svg(WHAT, PLOT_WIDTH, 90, |root| {
        let err = draw_err(WHAT);
        let mut chart = ChartBuilder::on(root)
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x0..x1, 0.0..1.0)
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .disable_mesh()
            .y_labels(0)
            .x_desc("frame")
            .x_label_formatter(&|x| format!("{x:.0}"))
            .label_style((FONT, 12))
            .draw()
            .map_err(|e| err(&e))?;
        chart
            .draw_series(runs.iter().map(|r| {
                let colour = match r.source {
                    PoseSource::Estimated => POSE_ESTIMATED,
                    PoseSource::Held => POSE_HELD,
                    PoseSource::Missing => POSE_NONE,
                };
                Rectangle::new(
                    [(r.first as f64, 0.0), (r.last as f64 + 1.0, 1.0)],
                    colour.filled(),
                )
            }))
            .map_err(|e| err(&e))?;
        Ok(())
    })
}

/// A bar chart of one value per take (`names` under the bars), value axis from 0 to
/// `y_max` (`None`: 10 % above the largest value). Values that are not finite draw no
/// bar.
pub fn take_bars(
    what: &str,
    names: &[String],
    values: &[f64],
    y_desc: &str,
    y_max: Option<f64>,
) -> Result<String, ReportError> {
    let n = names.len().max(1);
    let top = y_max.unwrap_or_else(|| {
        let m = values
            .iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        if m > 0.0 { m * 1.1 } else { 1.0 }
    });
    let width = (120 + 70 * n as u32).clamp(360, PLOT_WIDTH);
    svg(what, width, 260, |root| {
        let err = draw_err(what);
        let mut chart = ChartBuilder::on(root)
            .margin(10)
            .x_label_area_size(50)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.5..n as f64 - 0.5, 0.0..top)
            .map_err(|e| err(&e))?;
        let label = |x: &f64| {
            let i = x.round();
            match names.get(i as usize) {
                Some(name) if (x - i).abs() < 1e-6 && i >= 0.0 => short(name, 12),
                _ => String::new(),
            }
        };
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(n)
            .x_label_formatter(&label)
            .y_desc(y_desc)
            .label_style((FONT, 12))
            .light_line_style(RGBColor(238, 238, 238))
            .draw()
            .map_err(|e| err(&e))?;
        chart
            .draw_series(
                values
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| v.is_finite())
                    .map(|(i, &v)| {
                        let x = i as f64;
                        Rectangle::new([(x - 0.3, 0.0), (x + 0.3, v.min(top))], LINE.filled())
                    }),
            )
            .map_err(|e| err(&e))?;
        Ok(())
    })
}

/// `s` cut to `max` characters, with an ellipsis when cut.
fn short(s: &str, max: usize) -> String {
    if s.chars().count() <= max {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(max.saturating_sub(1)).collect();
        t.push('…');
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::take::bin_coverage;

    #[test]
    fn viridis_ends_and_middle() {
        assert_eq!(viridis(0.0), [68, 1, 84]);
        assert_eq!(viridis(1.0), [253, 231, 37]);
        assert_eq!(viridis(0.5), [33, 145, 140]);
        assert_eq!(viridis(f64::NAN), viridis(0.0));
    }

    #[test]
    fn plots_are_svg_without_urls() {
        let markers: Vec<String> = (0..30).map(|i| format!("M{i:03}")).collect();
        let obs: Vec<(usize, usize)> = (0..100)
            .flat_map(|f| {
                (0..30)
                    .filter(move |m| (f + m) % 7 != 0)
                    .map(move |m| (f, m))
            })
            .collect();
        let c = bin_coverage(0, 99, &markers, &obs, 20);
        let series: Vec<(usize, f64)> =
            (0..100).filter(|f| f % 40 != 5).map(|f| (f, 0.9)).collect();
        let runs = [PoseRun {
            first: 0,
            last: 99,
            source: PoseSource::Held,
        }];
        let names = vec!["a".to_string(), "b".to_string()];
        for svg in [
            coverage(&c).unwrap(),
            frame_series("conf", &series, (0, 99), "confidence", 0.0, Some(1.0)).unwrap(),
            pose_strip(&runs, (0, 99)).unwrap(),
            take_bars("bars", &names, &[50.0, f64::NAN], "%", Some(100.0)).unwrap(),
        ] {
            assert!(svg.starts_with("<svg"), "{}", &svg[..60.min(svg.len())]);
            assert!(svg.trim_end().ends_with("</svg>"));
            assert!(!svg.contains("http"), "{svg}");
        }
        let svg = coverage(&c).unwrap();
        assert!(svg.contains("M000") && svg.contains("<rect"));
    }

    #[test]
    fn long_series_are_averaged_and_split_at_gaps() {
        let points: Vec<(usize, f64)> = (0..8000).map(|f| (f, 1.0)).collect();
        let s = line_segments(&points);
        assert_eq!(s.len(), 1);
        assert!(s[0].len() <= MAX_LINE_POINTS, "{}", s[0].len());
        let gappy = [(0, 1.0), (1, 2.0), (5, 3.0), (6, f64::NAN), (7, 4.0)];
        let s = line_segments(&gappy);
        assert_eq!(
            s,
            vec![
                vec![(0.0, 1.0), (1.0, 2.0)],
                vec![(5.0, 3.0)],
                vec![(7.0, 4.0)]
            ]
        );
    }
}
