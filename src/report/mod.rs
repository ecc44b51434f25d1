//! Dailies reports (`helmcap report`): self-contained HTML pages for film supervisors, one
//! per take and one for the day, from take output folders (what `helmcap replay --out` or
//! `helmcap farm merge` writes; DESIGN.md §4 "Pipeline outputs").
//!
//! A take page shows the take's timecode range, frame counts, drops and gaps, the labeled
//! share and each marker's coverage over time, bundle confidence, the head pose's source,
//! the solve residual, latencies per stage, and a contact sheet (camera image with its
//! labeled points beside a render of the solved mesh, for a few evenly spaced frames). The
//! day page tables every take and links to its page.
//!
//! Pages load nothing from anywhere: plots are inline SVG ([`plotters`]), images inline
//! `data:` PNG, styles inline, and there is no script. Every file is written atomically.
//! A take folder that lacks a file still gets its page, which says what is missing and
//! what that hides; a folder without `metrics.json` is not a take and is refused.
//!
//! - [`take`]: loading and aggregating one take ([`TakeSummary`]).
//! - [`sheet`]: the contact sheet ([`ContactSheet`]).
//! - [`render`]: the software rasterizer of the mesh renders.
//! - `plots`, `html`: the SVG plots and the pages.

mod html;
mod plots;
pub mod render;
pub mod sheet;
pub mod take;

use std::collections::HashSet;
use std::io::Write;
use std::path::{Path, PathBuf};

pub use render::{OrthoView, fan_triangles, render_mesh};
pub use sheet::{ContactSheet, SheetFrame};
pub use take::{Coverage, PoseRun, Residual, TakeSummary, bin_coverage, pick_frames};

/// Errors of the report.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The folder has no `metrics.json`, so it is not a take's output. Fix: give the
    /// `--out` folder of `helmcap replay` (or of `helmcap farm merge`).
    #[error(
        "{}: not a take folder (no metrics.json); give a folder written by `helmcap replay --out` or `helmcap farm merge`",
        .0.display()
    )]
    NotATake(PathBuf),
    /// A file or folder could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The system's error.
        source: std::io::Error,
    },
    /// A file the page cannot do without (`metrics.json`) is malformed.
    #[error("{}: {message}", path.display())]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A plot or an image could not be drawn or encoded (a bug rather than bad input).
    #[error("{what}: {message}")]
    Draw {
        /// Which plot or image.
        what: String,
        /// The drawing library's message.
        message: String,
    },
}

impl ReportError {
    fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

/// Report settings.
#[derive(Debug, Clone, PartialEq)]
pub struct ReportParams {
    /// Frames on each take's contact sheet (evenly spaced over the take; 0: no sheet).
    pub frames_per_sheet: usize,
    /// Most time bins of the coverage heat-map (fewer when the take is shorter).
    pub coverage_bins: usize,
    /// Width of the camera images on the contact sheet, pixels (smaller images keep
    /// their size).
    pub sheet_width: u32,
    /// Width and height of the mesh renders, pixels.
    pub render_size: u32,
}

impl Default for ReportParams {
    fn default() -> Self {
        Self {
            frames_per_sheet: 4,
            coverage_bins: 60,
            sheet_width: 480,
            render_size: 320,
        }
    }
}

/// One take's line on the day page.
#[derive(Debug, Clone, PartialEq)]
pub struct DayRow {
    /// Take name.
    pub name: String,
    /// File name of the take's page in the report folder.
    pub page: String,
    /// First and last timecode (`None` without timecode).
    pub timecode: Option<(String, String)>,
    /// First and last frame index.
    pub frame_range: Option<(usize, usize)>,
    /// Frames through the pipeline, and taken from the source.
    pub frames: (u64, u64),
    /// Frames a live source dropped.
    pub dropped: u64,
    /// Frames skipped at the source, with a held pose, without a pose, without a mesh.
    pub gaps: [u64; 4],
    /// Labeled share of the marker-frames (0..1).
    pub labeled: f64,
    /// End-to-end p99 latency, ms.
    pub end_to_end_p99: Option<f64>,
    /// Files missing or unreadable in the take folder (notes of the take page and of its
    /// contact sheet).
    pub missing: usize,
    /// Why the take stopped early, if it did.
    pub stopped: Option<String>,
}

/// A dailies report being written into a folder: [`DailiesReport::add_take`] writes each
/// take's page, [`DailiesReport::finish`] the day page (`index.html`).
#[derive(Debug)]
pub struct DailiesReport {
    dir: PathBuf,
    day: String,
    params: ReportParams,
    rows: Vec<DayRow>,
    pages: HashSet<String>,
}

impl DailiesReport {
    /// A report titled `day` into `dir` (created when missing).
    ///
    /// # Errors
    /// [`ReportError::Io`] when the folder cannot be created.
    pub fn new(dir: &Path, day: &str, params: ReportParams) -> Result<Self, ReportError> {
        std::fs::create_dir_all(dir).map_err(|e| ReportError::io(dir, e))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            day: day.to_string(),
            params,
            rows: Vec::new(),
            pages: HashSet::from(["index.html".to_string()]),
        })
    }

    /// Loads the take in `take_dir`, writes its page (`<take>.html`, made unique among the
    /// report's pages) and returns the page's path.
    ///
    /// # Errors
    /// [`ReportError::NotATake`] for a folder without `metrics.json`, [`ReportError`]
    /// for a malformed `metrics.json`, and write errors. Missing or malformed other files
    /// are not errors: the page says what is missing.
    pub fn add_take(&mut self, take_dir: &Path) -> Result<PathBuf, ReportError> {
        let take = TakeSummary::load(take_dir, &self.params)?;
        let sheet = ContactSheet::build(&take, &self.params)?;
        let page = self.page_name(&take.name);
        let text = html::take_page(&take, &sheet, &self.day)?;
        let path = self.dir.join(&page);
        write_text(&path, &text)?;
        self.rows.push(DayRow::new(&take, &sheet, page));
        Ok(path)
    }

    /// The takes added so far, in order.
    pub fn rows(&self) -> &[DayRow] {
        &self.rows
    }

    /// Writes the day page, `index.html`, and returns its path.
    ///
    /// # Errors
    /// Write errors, and [`ReportError::Draw`] when the summary plot fails.
    pub fn finish(&self) -> Result<PathBuf, ReportError> {
        let text = html::day_page(&self.day, &self.rows)?;
        let path = self.dir.join("index.html");
        write_text(&path, &text)?;
        Ok(path)
    }

    /// A page file name for take `name` that no other page of the report has.
    fn page_name(&mut self, name: &str) -> String {
        let stem: String = name
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        let stem = stem.trim_start_matches('.');
        let stem = if stem.is_empty() { "take" } else { stem };
        let mut page = format!("{stem}.html");
        let mut n = 2;
        while self.pages.contains(&page.to_ascii_lowercase()) {
            page = format!("{stem}-{n}.html");
            n += 1;
        }
        self.pages.insert(page.to_ascii_lowercase());
        page
    }
}

impl DayRow {
    fn new(take: &TakeSummary, sheet: &ContactSheet, page: String) -> Self {
        let m = &take.metrics;
        Self {
            name: take.name.clone(),
            page,
            timecode: m
                .timecode
                .as_ref()
                .map(|t| (t.first.clone(), t.last.clone())),
            frame_range: take.frame_range,
            frames: (m.frames_out, m.frames_in),
            dropped: m.frames_dropped,
            gaps: [
                m.gaps.source as u64,
                m.gaps.pose_held,
                m.gaps.pose_missing,
                m.gaps.mesh_missing,
            ],
            labeled: m.labeling.labeled_fraction,
            end_to_end_p99: m
                .latency_ms
                .get("end_to_end")
                .map(|s| s.p99)
                .filter(|v| v.is_finite()),
            missing: take.notes.len() + sheet.notes.len(),
            stopped: m.stopped.clone(),
        }
    }
}

/// Checks that `dir` is a take folder (has `metrics.json`), before any work is done.
///
/// # Errors
/// [`ReportError::NotATake`].
pub fn check_take_dir(dir: &Path) -> Result<(), ReportError> {
    if dir.join("metrics.json").is_file() {
        Ok(())
    } else {
        Err(ReportError::NotATake(dir.to_path_buf()))
    }
}

/// Writes `text` to `path` atomically.
fn write_text(path: &Path, text: &str) -> Result<(), ReportError> {
    crate::atomic_file::write_atomically(path, |w| w.write_all(text.as_bytes()))
        .map_err(|e| ReportError::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn page_names_are_unique_and_safe() {
        let dir = tempfile::tempdir().unwrap();
        let mut report = DailiesReport::new(dir.path(), "day", ReportParams::default()).unwrap();
        assert_eq!(report.page_name("take 1/a"), "take_1_a.html");
        assert_eq!(report.page_name("take 1/a"), "take_1_a-2.html");
        assert_eq!(report.page_name("index"), "index-2.html");
        assert_eq!(report.page_name("..."), "take.html");
    }

    #[test]
    fn a_folder_without_metrics_is_not_a_take() {
        let dir = tempfile::tempdir().unwrap();
        let err = check_take_dir(dir.path()).unwrap_err();
        assert!(err.to_string().contains("not a take folder"), "{err}");
        let mut report =
            DailiesReport::new(&dir.path().join("r"), "d", ReportParams::default()).unwrap();
        assert!(matches!(
            report.add_take(dir.path()),
            Err(ReportError::NotATake(_))
        ));
    }
}
