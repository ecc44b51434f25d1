//! `helmcap ingest`: a pair of camera videos -> a recording session folder of PNG frames
//! (DESIGN.md §4 "Recording session"), written atomically.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use helmcap::capture::video::{VideoPixels, open_pair, probe_timecode};
use helmcap::timecode::{Timecode, TimecodeClock, TimecodeRate};
use indicatif::{ProgressBar, ProgressStyle};

/// Arguments of `helmcap ingest`.
#[derive(Debug, clap::Args)]
pub struct IngestArgs {
    /// cam0's video (any container and codec the FFmpeg backend of OpenCV reads).
    #[arg(long, value_name = "FILE")]
    video0: PathBuf,
    /// cam1's video: the same frame rate, length and frame size as cam0's.
    #[arg(long, value_name = "FILE")]
    video1: PathBuf,
    /// Session folder to create; it must not exist or be empty.
    #[arg(long, short, value_name = "SESSION")]
    out: PathBuf,
    /// Calibration YAML to copy into the session (as `calibration.yaml`); its image size
    /// must be the videos'.
    #[arg(long, value_name = "FILE")]
    calib: Option<PathBuf>,
    /// Capture profile to copy into the session (as `profile.toml`).
    #[arg(long, value_name = "FILE")]
    profile: Option<PathBuf>,
}

/// Removes a half-written folder unless disarmed.
struct TempDir(Option<PathBuf>);

impl Drop for TempDir {
    fn drop(&mut self) {
        if let Some(dir) = self.0.take() {
            let _ = std::fs::remove_dir_all(dir);
        }
    }
}

/// Writes one 8-bit PNG (grey or RGB), fast compression: an ingest of a long take is
/// bound by compression.
fn write_png(path: &Path, width: u32, height: u32, pixels: &VideoPixels) -> anyhow::Result<()> {
    let file = std::fs::File::create(path).with_context(|| path.display().to_string())?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    let data = match pixels {
        VideoPixels::Gray(g) => {
            enc.set_color(png::ColorType::Grayscale);
            g
        }
        VideoPixels::Rgb(rgb) => {
            enc.set_color(png::ColorType::Rgb);
            rgb
        }
    };
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut writer = enc
        .write_header()
        .with_context(|| path.display().to_string())?;
    writer
        .write_image_data(data)
        .with_context(|| path.display().to_string())?;
    writer
        .finish()
        .with_context(|| path.display().to_string())?;
    Ok(())
}

pub fn run(args: IngestArgs) -> anyhow::Result<()> {
    if args.out.exists() {
        let empty = args.out.is_dir()
            && std::fs::read_dir(&args.out)
                .with_context(|| args.out.display().to_string())?
                .next()
                .is_none();
        if !empty {
            bail!(
                "--out {} exists and is not an empty folder; ingest writes a new session",
                args.out.display()
            );
        }
    }
    let [mut v0, mut v1] = open_pair(&args.video0, &args.video1)?;
    let (fps, frames, (width, height)) = (v0.fps(), v0.frame_count(), v0.size());
    if let Some(calib) = &args.calib {
        let rig = helmcap::camera::read_rig(calib)?;
        if (rig.cam0.width_px, rig.cam0.height_px) != (width, height) {
            bail!(
                "{}: the calibration is for {}×{} images, the videos are {width}×{height}",
                calib.display(),
                rig.cam0.width_px,
                rig.cam0.height_px
            );
        }
    }
    if let Some(profile) = &args.profile {
        helmcap::track::CaptureProfile::load(profile)?;
    }
    // The timecode track of cam0's video, when ffprobe finds one.
    let clock = match probe_timecode(v0.path()) {
        Some(label) => {
            let rate = TimecodeRate::from_fps(fps).and_then(|r| {
                TimecodeRate::new(r.nominal, r.ntsc, label.contains(';') && r.ntsc).ok()
            });
            match rate.map(|r| Timecode::parse_at(&label, r)) {
                Some(Ok(start)) => Some(TimecodeClock::new(start, fps)),
                Some(Err(e)) => bail!("{}: timecode {label}: {e}", v0.path().display()),
                None => {
                    tracing::warn!(
                        "{}: timecode {label} ignored: {fps} fps is not a timecode rate",
                        v0.path().display()
                    );
                    None
                }
            }
        }
        None => None,
    };

    let parent = match args.out.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = args
        .out
        .file_name()
        .with_context(|| format!("--out {} names no folder", args.out.display()))?
        .to_string_lossy()
        .into_owned();
    let tmp_path = parent.join(format!(".{name}.ingest-{}", std::process::id()));
    if tmp_path.exists() {
        std::fs::remove_dir_all(&tmp_path).with_context(|| tmp_path.display().to_string())?;
    }
    let mut tmp = TempDir(Some(tmp_path.clone()));
    for cam in ["cam0", "cam1"] {
        std::fs::create_dir_all(tmp_path.join(cam))
            .with_context(|| tmp_path.join(cam).display().to_string())?;
    }

    let bar = ProgressBar::new(frames as u64);
    bar.set_style(
        ProgressStyle::with_template("ingesting {bar:40} {pos}/{len} frames {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    let mut csv = String::from("frame,timestamp_ns,timecode\n");
    for i in 0..frames {
        let (a, b) = rayon::join(|| v0.read_at(i), || v1.read_at(i));
        let (a, b) = (a?, b?);
        let (wa, wb) = rayon::join(
            || {
                write_png(
                    &tmp_path.join(format!("cam0/{i:06}.png")),
                    a.width,
                    a.height,
                    &a.pixels,
                )
            },
            || {
                write_png(
                    &tmp_path.join(format!("cam1/{i:06}.png")),
                    b.width,
                    b.height,
                    &b.pixels,
                )
            },
        );
        wa?;
        wb?;
        let tc = clock
            .map(|c| c.stamp(i as u64).to_string())
            .unwrap_or_default();
        csv.push_str(&format!("{i},{},{tc}\n", a.timestamp_ns));
        bar.inc(1);
    }
    bar.finish_and_clear();

    let mut toml = format!(
        "# Recording session ingested by helmcap ingest from {} and {}.\nfps = {fps:?}\n\
         cameras = [\"cam0\", \"cam1\"]\n",
        args.video0.display(),
        args.video1.display()
    );
    if let Some(calib) = &args.calib {
        std::fs::copy(calib, tmp_path.join("calibration.yaml"))
            .with_context(|| calib.display().to_string())?;
        toml.push_str("calibration = \"calibration.yaml\"\n");
    }
    if let Some(profile) = &args.profile {
        std::fs::copy(profile, tmp_path.join("profile.toml"))
            .with_context(|| profile.display().to_string())?;
        toml.push_str("profile = \"profile.toml\"\n");
    }
    if let Some(c) = &clock {
        toml.push_str(&format!(
            "\n[timecode]\nrate = \"{}\"\nstart = \"{}\"\n",
            c.start.rate, c.start
        ));
    }
    for (file, text) in [("frames.csv", csv), ("session.toml", toml)] {
        let path = tmp_path.join(file);
        std::fs::File::create(&path)
            .and_then(|mut f| f.write_all(text.as_bytes()))
            .with_context(|| path.display().to_string())?;
    }
    if args.out.exists() {
        // Checked empty above.
        std::fs::remove_dir(&args.out).with_context(|| args.out.display().to_string())?;
    }
    std::fs::rename(&tmp_path, &args.out)
        .with_context(|| format!("moving {} to {}", tmp_path.display(), args.out.display()))?;
    tmp.0 = None;
    println!(
        "wrote {} ({frames} frames of {width}×{height} at {fps} fps{})",
        args.out.display(),
        clock.map_or(String::new(), |c| format!(", timecode from {}", c.start))
    );
    Ok(())
}
