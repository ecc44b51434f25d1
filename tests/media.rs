//! Real image and video sources: calibration from lossless TIFF and 16-bit PNG copies of
//! a target set equals the 8-bit PNGs' result; a session of two lossless videos (FFV1 in
//! Matroska, written here with OpenCV's VideoWriter) replays to the same bundles and tracks
//! as the same frames as PNGs; `helmcap ingest` turns the videos back into the PNG session;
//! bad videos get one clear error line naming the file.

#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use helmcap::capture::video::{VideoReader, ffprobe_available};
use helmcap::capture::{GrayConversion, Replay, ReplayParams, read_gray};
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::videoio;

mod common;
use common::helmcap;

fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The error output of a failed run: one line naming every needle.
fn one_error_line(out: &Output, needles: &[&str]) -> String {
    assert!(!out.status.success(), "expected a failure");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!stderr.contains("panicked"), "{stderr}");
    let line = stderr
        .lines()
        .find(|l| l.starts_with("Error") || l.starts_with("error"))
        .unwrap_or_else(|| panic!("no error line in {stderr}"));
    for n in needles {
        assert!(stderr.contains(n), "{n:?} missing from {stderr}");
    }
    line.to_string()
}

fn sorted_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    files.sort();
    files
}

/// The calibration YAML's numbers, key by key (matrices flattened).
fn yaml_numbers(path: &Path) -> Vec<(String, f64)> {
    let rig = helmcap::camera::read_rig(path).unwrap();
    let mut v = Vec::new();
    for (c, cam) in [&rig.cam0, &rig.cam1].into_iter().enumerate() {
        for (i, k) in cam.k.iter().enumerate() {
            v.push((format!("K{c}[{i}]"), *k));
        }
        for (i, d) in cam.distortion.coefficients().iter().enumerate() {
            v.push((format!("D{c}[{i}]"), *d));
        }
    }
    let t = rig.cam1_from_cam0.translation.vector;
    for (i, x) in t.iter().enumerate() {
        v.push((format!("T[{i}]"), *x));
    }
    let r = rig.cam1_from_cam0.rotation;
    for (i, x) in r.matrix().iter().enumerate() {
        v.push((format!("R[{i}]"), *x));
    }
    v
}

fn printed_rms(stdout: &str) -> [f64; 3] {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("RMS reprojection error:"))
        .unwrap();
    let nums: Vec<f64> = line
        .split_whitespace()
        .filter_map(|w| w.parse().ok())
        .collect();
    [nums[0], nums[1], nums[2]]
}

fn calibrate(dir: &Path, ext: &str, spec: &str) -> (String, PathBuf) {
    let out = dir.join(format!("rig-{ext}.yaml"));
    let stdout = ok(&helmcap(&[
        "calibrate",
        "--target",
        spec,
        "--model",
        "pinhole",
        "--cam0",
        &format!("{}/cam0-{ext}/*", dir.display()),
        "--cam1",
        &format!("{}/cam1-{ext}/*", dir.display()),
        "--out",
        out.to_str().unwrap(),
    ]));
    (stdout, out)
}

#[test]
fn tiff_and_16_bit_png_copies_calibrate_like_the_8_bit_pngs() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let spec = "chessboard:9x6:20";
    ok(&helmcap(&[
        "synth",
        "--target",
        spec,
        "--views",
        "8",
        "--calib",
        "calib/helmet-pinhole.yaml",
        "--out",
        dir.to_str().unwrap(),
    ]));
    for cam in ["cam0", "cam1"] {
        for ext in ["png8", "tif", "png16"] {
            std::fs::create_dir_all(dir.join(format!("{cam}-{ext}"))).unwrap();
        }
        for file in sorted_files(&dir.join(cam)) {
            let stem = file.file_stem().unwrap().to_string_lossy().into_owned();
            let img = image::open(&file).unwrap().into_luma8();
            std::fs::copy(&file, dir.join(format!("{cam}-png8/{stem}.png"))).unwrap();
            // Lossless TIFF under a misleading extension: read by content.
            img.save_with_format(
                dir.join(format!("{cam}-tif/{stem}.png")),
                image::ImageFormat::Tiff,
            )
            .unwrap();
            let wide = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(
                img.width(),
                img.height(),
                |x, y| image::Luma([u16::from(img.get_pixel(x, y)[0]) * 257]),
            );
            wide.save(dir.join(format!("{cam}-png16/{stem}.png")))
                .unwrap();
        }
    }
    let (base_out, base) = calibrate(dir, "png8", spec);
    let base_rms = printed_rms(&base_out);
    let base_numbers = yaml_numbers(&base);
    println!("8-bit PNG: RMS {base_rms:?}");
    for ext in ["tif", "png16"] {
        let (stdout, path) = calibrate(dir, ext, spec);
        let rms = printed_rms(&stdout);
        println!("{ext}: RMS {rms:?}");
        for (a, b) in rms.iter().zip(&base_rms) {
            assert!((a - b).abs() <= 1e-6, "{ext}: RMS {rms:?} vs {base_rms:?}");
        }
        for ((key, a), (_, b)) in yaml_numbers(&path).iter().zip(&base_numbers) {
            assert!(
                (a - b).abs() <= 1e-6 * b.abs().max(1.0),
                "{ext}: {key} {a} vs {b}"
            );
        }
    }
}

/// Renders a small synthetic session.
fn synth_session(dir: &Path, frames: usize) {
    ok(&helmcap(&[
        "synth",
        "--out",
        dir.to_str().unwrap(),
        "-n",
        &frames.to_string(),
        "--noise",
        "1",
    ]));
}

/// Writes the PNG frames of `images` (a session's camera folder) as a lossless video:
/// FFV1 in Matroska, grey.
fn write_video(images: &Path, path: &Path, fps: f64, frames: Option<usize>) {
    let files = sorted_files(images);
    let first = read_gray(&files[0], GrayConversion::Luma).unwrap();
    let fourcc = videoio::VideoWriter::fourcc('F', 'F', 'V', '1').unwrap();
    let mut writer = videoio::VideoWriter::new_with_backend(
        path.to_str().unwrap(),
        videoio::CAP_FFMPEG,
        fourcc,
        fps,
        Size::new(first.width as i32, first.height as i32),
        false,
    )
    .unwrap();
    assert!(writer.is_opened().unwrap(), "no FFV1 writer");
    for file in files.iter().take(frames.unwrap_or(usize::MAX)) {
        let g = read_gray(file, GrayConversion::Luma).unwrap();
        let mat = Mat::new_rows_cols_with_data(g.height as i32, g.width as i32, &g.data)
            .unwrap()
            .try_clone()
            .unwrap();
        writer.write(&mat).unwrap();
    }
    writer.release().unwrap();
}

/// A video session beside `png_session`: session.toml with `[video]`, the calibration,
/// no frames.csv.
fn video_session(png_session: &Path, dir: &Path, fps: f64) {
    std::fs::create_dir_all(dir).unwrap();
    for cam in ["cam0", "cam1"] {
        write_video(
            &png_session.join(cam),
            &dir.join(format!("{cam}.mkv")),
            fps,
            None,
        );
    }
    std::fs::copy(
        png_session.join("calibration.yaml"),
        dir.join("calibration.yaml"),
    )
    .unwrap();
    std::fs::write(
        dir.join("session.toml"),
        format!(
            "fps = {fps:?}\ncameras = [\"cam0\", \"cam1\"]\ncalibration = \"calibration.yaml\"\n\n\
             [video]\ncam0 = \"cam0.mkv\"\ncam1 = \"cam1.mkv\"\n"
        ),
    )
    .unwrap();
}

/// Rows of a CSV keyed by its first `key_cols` columns, the next `value_cols` as numbers.
fn csv_rows(path: &Path, key_cols: usize, value_cols: usize) -> HashMap<Vec<String>, Vec<f64>> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .skip(1)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (
                f[..key_cols].iter().map(|s| s.to_string()).collect(),
                f[key_cols..key_cols + value_cols]
                    .iter()
                    .map(|s| s.parse().unwrap())
                    .collect(),
            )
        })
        .collect()
}

fn assert_same_rows(a: &Path, b: &Path, key_cols: usize, value_cols: usize, tol: f64) {
    let (ra, rb) = (
        csv_rows(a, key_cols, value_cols),
        csv_rows(b, key_cols, value_cols),
    );
    assert!(!ra.is_empty(), "{} is empty", a.display());
    assert_eq!(ra.len(), rb.len(), "{} vs {}", a.display(), b.display());
    let mut worst: f64 = 0.0;
    for (k, va) in &ra {
        let vb = rb
            .get(k)
            .unwrap_or_else(|| panic!("{k:?} missing from {}", b.display()));
        for (x, y) in va.iter().zip(vb) {
            worst = worst.max((x - y).abs());
        }
    }
    println!(
        "{}: {} rows, largest difference {worst:e}",
        a.file_name().unwrap().to_string_lossy(),
        ra.len()
    );
    assert!(worst <= tol, "{} differs by {worst}", a.display());
}

fn replay(session: &Path, out: &Path, cache: &Path) -> String {
    ok(&helmcap(&[
        "replay",
        session.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--no-solve",
        "--cache-dir",
        cache.to_str().unwrap(),
    ]))
}

#[test]
fn video_session_replays_like_the_png_session_and_ingests_back() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let (png, video, cache) = (dir.join("png"), dir.join("video"), dir.join("cache"));
    let frames = 12;
    synth_session(&png, frames);
    video_session(&png, &video, 60.0);

    // The decoded frames are the PNGs, bit for bit; timestamps are the container's.
    let mut reader = VideoReader::open(&video.join("cam0.mkv")).unwrap();
    assert_eq!(reader.frame_count(), frames);
    assert_eq!(reader.size(), (1280, 1024));
    let f3 = reader.read_at(3).unwrap();
    let want = read_gray(&png.join("cam0/000003.png"), GrayConversion::Luma).unwrap();
    assert_eq!(f3.timestamp_ns, 50_000_000);
    assert_eq!(f3.into_gray(GrayConversion::Luma), want);

    let replayed: Vec<_> = Replay::open(&video, ReplayParams::default())
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(replayed.len(), frames);
    assert_eq!(replayed[6].timestamp_ns, 100_000_000);
    assert!(replayed.iter().all(|f| f.timecode.is_none()));

    let (out_png, out_video) = (dir.join("out-png"), dir.join("out-video"));
    replay(&png, &out_png, &cache);
    replay(&video, &out_video, &cache);
    assert_same_rows(
        &out_png.join("bundles.csv"),
        &out_video.join("bundles.csv"),
        2,
        3,
        0.01,
    );
    assert_same_rows(
        &out_png.join("tracks.csv"),
        &out_video.join("tracks.csv"),
        3,
        2,
        0.01,
    );

    // ingest: the videos back into a PNG session, identical frames, refusing to overwrite.
    let ingested = dir.join("ingested");
    let stdout = ok(&helmcap(&[
        "ingest",
        "--video0",
        video.join("cam0.mkv").to_str().unwrap(),
        "--video1",
        video.join("cam1.mkv").to_str().unwrap(),
        "--out",
        ingested.to_str().unwrap(),
        "--calib",
        png.join("calibration.yaml").to_str().unwrap(),
    ]));
    assert!(stdout.contains("12 frames of 1280×1024"), "{stdout}");
    for cam in ["cam0", "cam1"] {
        let files = sorted_files(&ingested.join(cam));
        assert_eq!(files.len(), frames);
        for (i, f) in files.iter().enumerate() {
            assert_eq!(
                f.file_name().unwrap().to_string_lossy(),
                format!("{i:06}.png")
            );
            let a = read_gray(f, GrayConversion::Luma).unwrap();
            let b = read_gray(
                &png.join(cam).join(format!("{i:06}.png")),
                GrayConversion::Luma,
            )
            .unwrap();
            assert!(a == b, "{} differs", f.display());
        }
    }
    // Timestamps from the container (Matroska stores milliseconds).
    let csv = std::fs::read_to_string(ingested.join("frames.csv")).unwrap();
    assert!(
        csv.starts_with("frame,timestamp_ns,timecode\n0,0,\n"),
        "{csv}"
    );
    for (i, line) in csv.lines().skip(1).enumerate() {
        let ts: f64 = line.split(',').nth(1).unwrap().parse().unwrap();
        assert!((ts - i as f64 * 1e9 / 60.0).abs() <= 0.5e6, "{line}");
    }
    let replay_ingested: Vec<_> = Replay::open(&ingested, ReplayParams::default())
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(replay_ingested.len(), frames);
    assert!(
        replay_ingested
            .iter()
            .zip(&replayed)
            .all(|(a, b)| a.images == b.images)
    );
    assert!(
        !dir.read_dir().unwrap().any(|e| e
            .unwrap()
            .file_name()
            .to_string_lossy()
            .contains("ingest-")),
        "a temporary folder was left behind"
    );
    let again = helmcap(&[
        "ingest",
        "--video0",
        video.join("cam0.mkv").to_str().unwrap(),
        "--video1",
        video.join("cam1.mkv").to_str().unwrap(),
        "--out",
        ingested.to_str().unwrap(),
    ]);
    one_error_line(&again, &["ingested", "not an empty folder"]);
}

#[test]
fn bad_videos_get_one_clear_error_line() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let png = dir.join("png");
    synth_session(&png, 4);
    let s = dir.join("s");
    std::fs::create_dir_all(&s).unwrap();
    std::fs::copy(png.join("calibration.yaml"), s.join("calibration.yaml")).unwrap();
    let toml = "fps = 60.0\ncameras = [\"cam0\", \"cam1\"]\ncalibration = \"calibration.yaml\"\n\
                [video]\ncam0 = \"cam0.mkv\"\ncam1 = \"cam1.mkv\"\n";
    std::fs::write(s.join("session.toml"), toml).unwrap();
    let cache = dir.join("cache");
    let replay_err = |needles: &[&str]| {
        let out = helmcap(&[
            "replay",
            s.to_str().unwrap(),
            "--out",
            dir.join("out").to_str().unwrap(),
            "--no-solve",
            "--cache-dir",
            cache.to_str().unwrap(),
        ]);
        one_error_line(&out, needles)
    };
    // Missing, then unreadable.
    write_video(&png.join("cam0"), &s.join("cam0.mkv"), 60.0, None);
    replay_err(&["cam1.mkv", "missing"]);
    std::fs::write(s.join("cam1.mkv"), b"not a video at all").unwrap();
    replay_err(&["cam1.mkv", "cannot open as a video"]);
    // A shorter cam1.
    write_video(&png.join("cam1"), &s.join("cam1.mkv"), 60.0, Some(3));
    replay_err(&["cam1.mkv", "3 frames", "4", "same length"]);
    let out = helmcap(&[
        "ingest",
        "--video0",
        s.join("cam0.mkv").to_str().unwrap(),
        "--video1",
        s.join("cam1.mkv").to_str().unwrap(),
        "--out",
        dir.join("ingested").to_str().unwrap(),
    ]);
    one_error_line(&out, &["cam1.mkv", "same length"]);
    assert!(!dir.join("ingested").exists());
    // Another frame rate.
    write_video(&png.join("cam1"), &s.join("cam1.mkv"), 30.0, None);
    replay_err(&["cam1.mkv", "30 fps", "same frame rate"]);
    // A camera the [video] table does not name.
    write_video(&png.join("cam1"), &s.join("cam1.mkv"), 60.0, None);
    std::fs::write(s.join("session.toml"), toml.replace("cam1 = ", "camX = ")).unwrap();
    replay_err(&["session.toml", "[video] names no file for camera \"cam1\""]);
    // The same session, right: it replays.
    std::fs::write(s.join("session.toml"), toml).unwrap();
    let frames = Replay::open(&s, ReplayParams::default())
        .unwrap()
        .map(Result::unwrap)
        .count();
    assert_eq!(frames, 4);
}

#[test]
fn video_timecode_from_the_container_or_session_toml() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let png = dir.join("png");
    synth_session(&png, 3);
    let s = dir.join("s");
    video_session(&png, &s, 60.0);
    // Without a timecode track: `[timecode] start` of session.toml.
    let toml = std::fs::read_to_string(s.join("session.toml")).unwrap();
    std::fs::write(
        s.join("session.toml"),
        format!("{toml}\n[timecode]\nrate = \"30\"\nstart = \"10:00:00:00\"\n"),
    )
    .unwrap();
    let labels = |s: &Path| -> Vec<String> {
        Replay::open(s, ReplayParams::default())
            .unwrap()
            .map(|f| f.unwrap().timecode.unwrap().to_string())
            .collect()
    };
    assert_eq!(
        labels(&s),
        ["10:00:00:00.0", "10:00:00:00.1", "10:00:00:01.0"]
    );
    if !ffprobe_available() || Command::new("ffmpeg").arg("-version").output().is_err() {
        println!("skipped the timecode-track half: ffmpeg/ffprobe are not installed");
        return;
    }
    // A timecode track (Matroska tag written by ffmpeg) wins over session.toml.
    for cam in ["cam0", "cam1"] {
        let src = s.join(format!("{cam}.mkv"));
        let dst = s.join(format!("{cam}-tc.mkv"));
        let st = Command::new("ffmpeg")
            .args(["-v", "error", "-y", "-i"])
            .arg(&src)
            .args(["-c", "copy", "-timecode", "01:02:03:04"])
            .arg(&dst)
            .status()
            .unwrap();
        assert!(st.success());
        std::fs::rename(&dst, &src).unwrap();
    }
    assert_eq!(
        labels(&s),
        ["01:02:03:04.0", "01:02:03:04.1", "01:02:03:05.0"]
    );
}
