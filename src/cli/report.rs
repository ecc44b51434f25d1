//! `helmcap report`: a dailies report (self-contained HTML pages with plots) for one or
//! more take output folders.

use std::path::PathBuf;

use anyhow::Context;
use helmcap::report::{DailiesReport, ReportParams, check_take_dir};

/// Arguments of `helmcap report`.
#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    /// Take output folders (written by `helmcap replay --out` or `helmcap farm merge`), in
    /// the order the day page lists them.
    #[arg(value_name = "OUT", required = true, num_args = 1..)]
    pub takes: Vec<PathBuf>,
    /// Report folder: `index.html` (the day) and one `<take>.html` per take.
    #[arg(long, short, value_name = "REPORT_DIR", default_value = "out/report")]
    pub out: PathBuf,
    /// Title of the day page (default: today's date, UTC).
    #[arg(long, value_name = "NAME")]
    pub day: Option<String>,
    /// Frames on each take's contact sheet, evenly spaced (0: no contact sheet).
    #[arg(long, default_value_t = ReportParams::default().frames_per_sheet)]
    pub frames_per_sheet: usize,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// Runs `helmcap report`.
pub fn run(args: ReportArgs) -> anyhow::Result<()> {
    // Every folder is checked before anything is written.
    for t in &args.takes {
        check_take_dir(t)?;
    }
    let day = args.day.clone().unwrap_or_else(today);
    let params = ReportParams {
        frames_per_sheet: args.frames_per_sheet,
        ..ReportParams::default()
    };
    let mut report = DailiesReport::new(&args.out, &day, params)
        .with_context(|| format!("creating the report folder {}", args.out.display()))?;
    let bar = if args.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(args.takes.len() as u64)
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("report [{bar:30}] {pos}/{len} takes {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    for t in &args.takes {
        bar.set_message(t.display().to_string());
        report
            .add_take(t)
            .with_context(|| format!("take {}", t.display()))?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let index = report.finish()?;
    for row in report.rows() {
        println!(
            "{}: {} frames, {:.1} % labeled -> {}",
            row.name,
            row.frames.0,
            100.0 * row.labeled,
            args.out.join(&row.page).display()
        );
    }
    println!(
        "report of {} take{} ({day}): {}",
        report.rows().len(),
        if report.rows().len() == 1 { "" } else { "s" },
        index.display()
    );
    Ok(())
}

/// Today's date (UTC) as `YYYY-MM-DD`, or `dailies` when the clock is before 1970.
fn today() -> String {
    match std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH) {
        Ok(d) => {
            let (y, m, day) = civil_from_days((d.as_secs() / 86_400) as i64);
            format!("{y:04}-{m:02}-{day:02}")
        }
        Err(_) => "dailies".into(),
    }
}

/// The proleptic Gregorian date of `days` since 1970-01-01 (H. Hinnant's
/// `civil_from_days`).
fn civil_from_days(days: i64) -> (i64, u32, u32) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn civil_dates() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(59), (1970, 3, 1));
        assert_eq!(civil_from_days(11_016), (2000, 2, 29));
        assert_eq!(civil_from_days(19_723), (2024, 1, 1));
    }
}
