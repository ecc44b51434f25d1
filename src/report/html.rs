//! The report's HTML: a take page and the day page, each one self-contained file (inline
//! styles, inline SVG plots, images as `data:` URLs, no script, no link outside the
//! report folder).

use std::fmt::Write as _;

use super::plots;
use super::sheet::ContactSheet;
use super::take::{Residual, TakeSummary};
use super::{DayRow, ReportError};

/// The pages' style sheet.
const STYLE: &str = "
body { font-family: system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif; margin: 24px auto;
       max-width: 1000px; padding: 0 16px; color: #1d1f23; background: #fff; }
h1 { margin-bottom: 4px; } h2 { margin-top: 32px; border-bottom: 1px solid #ddd; padding-bottom: 4px; }
.sub { color: #666; margin-top: 0; }
table { border-collapse: collapse; margin: 8px 0; }
th, td { padding: 4px 10px; border-bottom: 1px solid #eee; text-align: left; vertical-align: top; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; }
tr.total td { font-weight: 600; border-top: 2px solid #ccc; }
.kv th { color: #555; font-weight: 500; }
.plot svg { max-width: 100%; height: auto; display: block; }
.note { background: #fff6e0; border-left: 4px solid #f0a020; padding: 8px 12px; margin: 12px 0; }
.note ul { margin: 4px 0; padding-left: 20px; }
.bad { color: #b00020; font-weight: 600; }
.legend span.sw { display: inline-block; width: 14px; height: 10px; margin: 0 4px 0 12px;
                  vertical-align: middle; border: 1px solid #999; }
.sheet { display: flex; flex-wrap: wrap; gap: 16px; }
.sheet figure { margin: 0; border: 1px solid #ddd; padding: 8px; background: #fafafa; }
.sheet .pair { display: flex; gap: 8px; align-items: flex-start; }
.sheet img { display: block; max-width: 100%; }
.sheet .empty { width: 200px; height: 150px; display: flex; align-items: center; justify-content: center;
                color: #888; background: #eee; font-size: 13px; text-align: center; }
figcaption { font-size: 13px; color: #444; margin-top: 6px; }
nav a { text-decoration: none; }
";

/// Standard base64 (RFC 4648, with padding) of `bytes`.
pub fn base64(bytes: &[u8]) -> String {
    const ALPHABET: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            chunk.get(1).copied().unwrap_or(0),
            chunk.get(2).copied().unwrap_or(0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for (i, shift) in [18, 12, 6, 0].into_iter().enumerate() {
            if i <= chunk.len() {
                out.push(char::from(ALPHABET[((n >> shift) & 63) as usize]));
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// `s` with the characters HTML gives a meaning escaped (for text and attribute values).
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// A share (0..1) as a percentage.
fn pct(share: f64) -> String {
    if share.is_finite() {
        format!("{:.1} %", 100.0 * share)
    } else {
        "–".into()
    }
}

/// Milliseconds, or a dash.
fn ms(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.2}")
    } else {
        "–".into()
    }
}

/// The page's head and the start of its body.
fn open_page(out: &mut String, title: &str) {
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <meta name=\"generator\" content=\"helmcap {}\">\n<title>{}</title>\n<style>{STYLE}</style>\n\
         </head>\n<body>\n",
        env!("CARGO_PKG_VERSION"),
        escape(title)
    );
}

/// A PNG as an `<img>` with a `data:` URL.
fn img(png: &[u8], alt: &str) -> String {
    format!(
        "<img alt=\"{}\" src=\"data:image/png;base64,{}\">",
        escape(alt),
        base64(png)
    )
}

/// A legend swatch.
fn swatch(rgb: [u8; 3], label: &str) -> String {
    format!(
        "<span class=\"sw\" style=\"background:#{:02x}{:02x}{:02x}\"></span>{}",
        rgb[0],
        rgb[1],
        rgb[2],
        escape(label)
    )
}

/// The page of one take.
///
/// # Errors
/// [`ReportError::Draw`] when a plot fails.
pub fn take_page(
    take: &TakeSummary,
    sheet: &ContactSheet,
    day: &str,
) -> Result<String, ReportError> {
    let m = &take.metrics;
    let mut out = String::new();
    open_page(&mut out, &format!("{} · {day}", take.name));
    let _ = writeln!(
        out,
        "<nav><a href=\"index.html\">← {}</a></nav>\n<h1>{}</h1>\n<p class=\"sub\">{}</p>",
        escape(day),
        escape(&take.name),
        escape(
            &take
                .dir
                .canonicalize()
                .as_deref()
                .unwrap_or(&take.dir)
                .display()
                .to_string()
        )
    );
    if !(take.notes.is_empty() && sheet.notes.is_empty()) {
        out.push_str("<div class=\"note\"><b>Missing or unreadable:</b><ul>");
        for n in take.notes.iter().chain(&sheet.notes) {
            let _ = write!(out, "<li>{}</li>", escape(n));
        }
        out.push_str("</ul></div>\n");
    }
    if let Some(why) = &m.stopped {
        let _ = writeln!(
            out,
            "<div class=\"note\"><b>The take stopped early:</b> {}</div>",
            escape(why)
        );
    }

    // Summary.
    out.push_str("<h2>Summary</h2>\n<table class=\"kv\">\n");
    let mut row = |k: &str, v: String| {
        let _ = writeln!(out, "<tr><th>{}</th><td>{v}</td></tr>", escape(k));
    };
    row(
        "Timecode",
        match &m.timecode {
            Some(t) => format!(
                "{} – {} <span class=\"sub\">({})</span>",
                escape(&t.first),
                escape(&t.last),
                escape(&t.rate)
            ),
            None => "none".into(),
        },
    );
    row(
        "Frames",
        match take.frame_range {
            Some((a, z)) => format!("{a} – {z}: {} out of {} in", m.frames_out, m.frames_in),
            None => format!("{} out of {} in", m.frames_out, m.frames_in),
        },
    );
    row(
        "Dropped",
        if m.frames_dropped > 0 {
            format!(
                "<span class=\"bad\">{}</span> frames (live source)",
                m.frames_dropped
            )
        } else {
            "0".into()
        },
    );
    row(
        "Gaps",
        format!(
            "{} skipped at the source · {} with a held head pose · {} without a head pose · {} without a mesh",
            m.gaps.source, m.gaps.pose_held, m.gaps.pose_missing, m.gaps.mesh_missing
        ),
    );
    let l = &m.labeling;
    row(
        "Labeled",
        format!(
            "<b>{}</b> of the marker-frames ({} markers): {} observed, {} gap-filled, {} dropped, {} missing; {} reacquired",
            pct(l.labeled_fraction),
            l.markers,
            l.observed,
            l.gap_filled,
            l.dropped,
            l.missing,
            l.reacquired
        ),
    );
    row(
        "Throughput",
        format!(
            "{:.1} frames/s for a {:.1} fps source ({:.1} s)",
            m.throughput_fps, m.source_fps, m.wall_secs
        ),
    );
    let w = &m.warnings;
    let mut warnings = Vec::new();
    if w.bundles_far_outside_face > 0 {
        warnings.push(format!(
            "{} bundles far outside the face",
            w.bundles_far_outside_face
        ));
    }
    if w.meshes_far_outside_face > 0 {
        warnings.push(format!(
            "{} meshes far outside the face",
            w.meshes_far_outside_face
        ));
    }
    if w.nothing_labeled_at_start {
        warnings.push(
            "nothing labeled at the start (cameras swapped or not the calibration's?)".into(),
        );
    }
    if w.timecode_repeats > 0 {
        warnings.push(format!("{} repeated timecodes", w.timecode_repeats));
    }
    if w.timecode_jumps > 0 {
        warnings.push(format!("{} timecode jumps", w.timecode_jumps));
    }
    row(
        "Warnings",
        if warnings.is_empty() {
            "none".into()
        } else {
            format!(
                "<span class=\"bad\">{}</span>",
                escape(&warnings.join("; "))
            )
        },
    );
    row(
        "Session",
        match &take.session {
            Some(s) => escape(&s.display().to_string()),
            None => "not named (no take.json)".into(),
        },
    );
    out.push_str("</table>\n");

    // Coverage.
    out.push_str("<h2>Marker coverage</h2>\n");
    match &take.coverage {
        Some(c) => {
            let lengths = c.bins.iter().map(|b| b.1 - b.0 + 1);
            let (short, long) = (
                lengths.clone().min().unwrap_or(1),
                lengths.max().unwrap_or(1),
            );
            let per_bin = if short == long {
                format!("{short} frame{}", if short == 1 { "" } else { "s" })
            } else {
                format!("{short}–{long} frames")
            };
            let _ = writeln!(
                out,
                "<p>Share of the frames in which each marker is observed (labeled in both cameras and triangulated), in {} time bins of {per_bin}.</p>",
                c.bins.len()
            );
            let _ = writeln!(
                out,
                "<p class=\"legend\">{}{}{}{}{}</p>",
                swatch(plots::viridis(0.0), "0 %"),
                swatch(plots::viridis(0.25), "25 %"),
                swatch(plots::viridis(0.5), "50 %"),
                swatch(plots::viridis(0.75), "75 %"),
                swatch(plots::viridis(1.0), "100 %")
            );
            let _ = writeln!(out, "<div class=\"plot\">{}</div>", plots::coverage(c)?);
        }
        None => out.push_str("<p>Not shown: no usable <code>bundles.csv</code>.</p>\n"),
    }

    // Confidence.
    out.push_str("<h2>Bundle confidence</h2>\n");
    match (take.confidence.is_empty(), take.frame_range) {
        (false, Some(range)) => {
            out.push_str(
                "<p>Mean confidence of each frame's observed and gap-filled bundles.</p>\n",
            );
            let svg = plots::frame_series(
                "confidence plot",
                &take.confidence,
                range,
                "confidence",
                0.0,
                Some(1.0),
            )?;
            let _ = writeln!(out, "<div class=\"plot\">{svg}</div>");
        }
        _ => out.push_str("<p>Not shown: no bundles with a confidence.</p>\n"),
    }

    // Head pose.
    out.push_str("<h2>Head pose</h2>\n");
    match (&take.pose, take.frame_range, take.pose_counts()) {
        (Some(runs), Some(range), Some([estimated, held, none])) => {
            let _ = writeln!(
                out,
                "<p class=\"legend\">{} ({estimated} frames){} ({held}){} ({none})</p>",
                swatch(
                    [
                        plots::POSE_ESTIMATED.0,
                        plots::POSE_ESTIMATED.1,
                        plots::POSE_ESTIMATED.2
                    ],
                    "estimated"
                ),
                swatch(
                    [plots::POSE_HELD.0, plots::POSE_HELD.1, plots::POSE_HELD.2],
                    "held from an earlier frame"
                ),
                swatch(
                    [plots::POSE_NONE.0, plots::POSE_NONE.1, plots::POSE_NONE.2],
                    "none"
                ),
            );
            let _ = writeln!(
                out,
                "<div class=\"plot\">{}</div>",
                plots::pose_strip(runs, range)?
            );
        }
        _ => out.push_str("<p>Not shown: no usable <code>head_pose.csv</code>.</p>\n"),
    }
    let _ = writeln!(
        out,
        "<p>metrics.json: {} frames held the previous pose, {} had none.</p>",
        m.gaps.pose_held, m.gaps.pose_missing
    );

    // Residual.
    out.push_str("<h2>Solve residual</h2>\n");
    match &take.residual {
        Residual::PerFrame(points) if !points.is_empty() => {
            let mean = points.iter().map(|p| p.1).sum::<f64>() / points.len() as f64;
            let max = points.iter().map(|p| p.1).fold(0.0, f64::max);
            let _ = writeln!(
                out,
                "<p>Rig solve residual per frame (<code>rig_weights.csv</code>): mean {mean:.3} mm, largest {max:.3} mm over {} frames.</p>",
                points.len()
            );
            let range = take.frame_range.unwrap_or((points[0].0, points[points.len() - 1].0));
            let svg = plots::frame_series("residual plot", points, range, "residual (mm)", 0.0, None)?;
            let _ = writeln!(out, "<div class=\"plot\">{svg}</div>");
        }
        Residual::PerFrame(_) => out.push_str("<p><code>rig_weights.csv</code> has no frames.</p>\n"),
        Residual::Accuracy(a) if a.bundle_frames > 0 || a.mesh_frames > 0 => {
            out.push_str("<p>Against the session's ground truth (metrics.json <code>accuracy</code>):</p>\n<table class=\"kv\">\n");
            if a.bundle_frames > 0 {
                let _ = writeln!(
                    out,
                    "<tr><th>Bundles</th><td>{:.3} mm RMS over {} frames</td></tr>",
                    a.bundle_rms_mm, a.bundle_frames
                );
            }
            if a.mesh_frames > 0 {
                let _ = writeln!(
                    out,
                    "<tr><th>Mesh</th><td>{:.3} mm RMS, {:.3} mm mean, {:.3} mm largest over {} frames</td></tr>",
                    a.mesh_rms_mm, a.mesh_mean_mm, a.mesh_max_mm, a.mesh_frames
                );
            }
            out.push_str("</table>\n");
        }
        Residual::Accuracy(_) | Residual::NotRecorded => out.push_str(
            "<p>Not recorded: no <code>rig_weights.csv</code> with a <code>residual_mm</code> column (replay with <code>--rig</code>) and no ground truth in metrics.json.</p>\n",
        ),
    }

    // Latency.
    out.push_str("<h2>Latency</h2>\n");
    if m.latency_ms.is_empty() {
        out.push_str("<p>Not recorded.</p>\n");
    } else {
        out.push_str("<table>\n<tr><th>stage</th><th class=\"num\">mean (ms)</th><th class=\"num\">p50</th><th class=\"num\">p99</th><th class=\"num\">max</th><th class=\"num\">frames</th></tr>\n");
        let order = crate::pipeline::Stage::ALL.map(crate::pipeline::Stage::name);
        let mut stages: Vec<(&String, _)> = m
            .latency_ms
            .iter()
            .filter(|(k, _)| *k != "end_to_end")
            .collect();
        stages.sort_by_key(|(k, _)| order.iter().position(|o| o == k).unwrap_or(order.len()));
        let e2e = m.latency_ms.get_key_value("end_to_end");
        for (name, s) in stages.into_iter().chain(e2e) {
            let class = if name == "end_to_end" {
                " class=\"total\""
            } else {
                ""
            };
            let _ = writeln!(
                out,
                "<tr{class}><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td></tr>",
                escape(&name.replace('_', " ")),
                ms(s.mean),
                ms(s.p50),
                ms(s.p99),
                ms(s.max),
                s.count
            );
        }
        out.push_str("</table>\n");
    }

    // Contact sheet.
    out.push_str("<h2>Contact sheet</h2>\n");
    if !sheet.notes.is_empty() {
        // Repeated here, beside what they explain.
        out.push_str("<div class=\"note\"><ul>");
        for n in &sheet.notes {
            let _ = write!(out, "<li>{}</li>", escape(n));
        }
        out.push_str("</ul></div>\n");
    }
    if sheet.frames.is_empty() {
        out.push_str("<p>No frames to show.</p>\n");
    } else {
        let camera = sheet.camera.as_deref().unwrap_or("first camera");
        let _ = writeln!(
            out,
            "<p>Left: {} image with the frame's labeled points (rings). Right: the solved mesh, front view (head frame).</p>\n<div class=\"sheet\">",
            escape(camera)
        );
        for f in &sheet.frames {
            out.push_str("<figure><div class=\"pair\">");
            match &f.camera_png {
                Some(png) => out.push_str(&img(png, &format!("frame {} {camera}", f.frame))),
                None => out.push_str("<div class=\"empty\">no camera image</div>"),
            }
            match &f.mesh_png {
                Some(png) => out.push_str(&img(png, &format!("frame {} mesh", f.frame))),
                None => out.push_str("<div class=\"empty\">no mesh</div>"),
            }
            let tc = f
                .timecode
                .as_deref()
                .map(|t| format!(" · {}", escape(t)))
                .unwrap_or_default();
            let points = if f.camera_png.is_some() {
                format!(" · {} labeled points", f.points)
            } else {
                String::new()
            };
            let _ = writeln!(
                out,
                "</div><figcaption>frame {}{tc}{points}</figcaption></figure>",
                f.frame
            );
        }
        out.push_str("</div>\n");
    }
    out.push_str("</body>\n</html>\n");
    Ok(out)
}

/// The day page: a table of every take (linking to its page) and summary plots.
///
/// # Errors
/// [`ReportError::Draw`] when a plot fails.
pub fn day_page(day: &str, rows: &[DayRow]) -> Result<String, ReportError> {
    let mut out = String::new();
    open_page(&mut out, &format!("Dailies · {day}"));
    let frames: u64 = rows.iter().map(|r| r.frames.0).sum();
    let _ = writeln!(
        out,
        "<h1>Dailies · {}</h1>\n<p class=\"sub\">{} take{}, {frames} frames</p>",
        escape(day),
        rows.len(),
        if rows.len() == 1 { "" } else { "s" }
    );
    if !rows.is_empty() {
        let names: Vec<String> = rows.iter().map(|r| r.name.clone()).collect();
        let labeled: Vec<f64> = rows.iter().map(|r| 100.0 * r.labeled).collect();
        let p99: Vec<f64> = rows
            .iter()
            .map(|r| r.end_to_end_p99.unwrap_or(f64::NAN))
            .collect();
        let _ = writeln!(
            out,
            "<div class=\"sheet\"><div class=\"plot\">{}</div><div class=\"plot\">{}</div></div>",
            plots::take_bars("labeled plot", &names, &labeled, "labeled (%)", Some(100.0))?,
            plots::take_bars("latency plot", &names, &p99, "end-to-end p99 (ms)", None)?
        );
    }
    out.push_str(
        "<h2>Takes</h2>\n<table>\n<tr><th>take</th><th>timecode</th><th>frames</th>\
         <th class=\"num\">drops</th><th class=\"num\">gaps</th><th class=\"num\">labeled</th>\
         <th class=\"num\">end-to-end p99 (ms)</th><th>notes</th></tr>\n",
    );
    for r in rows {
        let tc = match &r.timecode {
            Some((a, z)) => format!("{} – {}", escape(a), escape(z)),
            None => "–".into(),
        };
        let frames = match r.frame_range {
            Some((a, z)) => format!("{} ({a}–{z})", r.frames.0),
            None => r.frames.0.to_string(),
        };
        let [source, held, no_pose, no_mesh] = r.gaps;
        let gaps = source + no_pose + no_mesh;
        let gap_title = format!(
            "{source} skipped at the source, {held} with a held head pose, {no_pose} without a head pose, {no_mesh} without a mesh"
        );
        let mut notes = Vec::new();
        if let Some(s) = &r.stopped {
            notes.push(format!("stopped early: {s}"));
        }
        if r.missing > 0 {
            notes.push(format!(
                "{} missing or unreadable file{}",
                r.missing,
                if r.missing == 1 { "" } else { "s" }
            ));
        }
        let drops = if r.dropped > 0 {
            format!("<span class=\"bad\">{}</span>", r.dropped)
        } else {
            "0".into()
        };
        let _ = writeln!(
            out,
            "<tr><td><a href=\"{}\">{}</a></td><td>{tc}</td><td>{frames}</td><td class=\"num\">{drops}</td>\
             <td class=\"num\" title=\"{}\">{gaps}{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td></tr>",
            escape(&r.page),
            escape(&r.name),
            escape(&gap_title),
            if held > 0 {
                format!(" (+{held} held)")
            } else {
                String::new()
            },
            pct(r.labeled),
            r.end_to_end_p99.map_or_else(|| "–".into(), ms),
            escape(&notes.join("; "))
        );
    }
    out.push_str("</table>\n<p class=\"sub\">Gaps: frames skipped at the source, without a head pose or without a mesh; frames that held the previous head pose in parentheses.</p>\n</body>\n</html>\n");
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame_index::FrameIndex;
    use crate::pipeline::{LatencyStats, Metrics};
    use crate::report::sheet::SheetFrame;
    use crate::report::take::bin_coverage;

    #[test]
    fn base64_matches_rfc_4648_vectors() {
        for (plain, encoded) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(plain.as_bytes()), encoded);
        }
        assert_eq!(base64(&[0xff, 0xfe, 0xfd]), "//79");
    }

    #[test]
    fn escape_covers_markup() {
        assert_eq!(
            escape("<a href=\"x\">&'"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;"
        );
    }

    /// A take with everything: plots, a sheet frame with both images, notes; its page and
    /// the day page hold no URL and no script, and escape the take's name.
    #[test]
    fn pages_are_self_contained() {
        let mut metrics = Metrics {
            frames_in: 10,
            frames_out: 10,
            frame_range: Some((FrameIndex::new(0), FrameIndex::new(9))),
            ..Metrics::default()
        };
        let stats = LatencyStats {
            mean: 1.0,
            p50: 1.0,
            p99: 2.0,
            max: 3.0,
            count: 10,
        };
        metrics.latency_ms.insert("track".into(), stats);
        metrics.latency_ms.insert("end_to_end".into(), stats);
        let markers = vec!["M001".to_string(), "M002".to_string()];
        let take = TakeSummary {
            name: "take <1> & http://example.com".into(),
            dir: "/tmp/t".into(),
            session: None,
            metrics,
            frame_range: Some((0, 9)),
            coverage: Some(bin_coverage(0, 9, &markers, &[(0, 0), (5, 1)], 60)),
            confidence: (0..10).map(|f| (f, 0.8)).collect(),
            timecodes: Default::default(),
            frames_seen: (0..10).collect(),
            pose: None,
            residual: Residual::PerFrame((0..10).map(|f| (f, 0.1 * f as f64)).collect()),
            notes: vec!["tracks.csv: missing".into()],
        };
        let png = crate::report::sheet::encode_png(&image::RgbImage::new(4, 4), "t").unwrap();
        let sheet = ContactSheet {
            frames: vec![SheetFrame {
                frame: 3,
                timecode: Some("01:00:00:03@30".into()),
                camera_png: Some(png.clone()),
                points: 5,
                mesh_png: Some(png),
            }],
            camera: Some("cam0".into()),
            notes: vec![],
        };
        let page = take_page(&take, &sheet, "day 1").unwrap();
        let day = day_page(
            "day 1",
            &[super::super::DayRow::new(&take, &sheet, "t.html".into())],
        )
        .unwrap();
        for p in [&page, &day] {
            let lower = p.to_ascii_lowercase();
            assert!(!lower.contains("<script"), "script in page");
            for attr in [
                "src=\"http",
                "href=\"http",
                "url(http",
                "src=\"//",
                "href=\"//",
            ] {
                assert!(!lower.contains(attr), "{attr} in page");
            }
            assert!(p.contains("take &lt;1&gt; &amp; http://example.com"));
            assert!(!p.contains("<1>"));
        }
        assert_eq!(
            page.matches("<svg").count(),
            3,
            "coverage, confidence, residual"
        );
        assert_eq!(page.matches("src=\"data:image/png;base64,").count(), 2);
        assert!(page.contains("tracks.csv: missing"));
        assert!(day.contains("href=\"t.html\"") && day.matches("<svg").count() == 2);
    }
}
