//! Mutation fuzzing of every input parser, video containers included: seed files (valid
//! inputs of each format) are mutated at random (bytes flipped, inserted, deleted,
//! repeated; numbers swapped for extreme ones; megabyte-long lines; cut files) and each
//! parser must end every case with a value or a clean error: no panic, no case slower than [`MAX_CASE_SECS`], and the
//! process's peak memory under [`MAX_PEAK_RSS_MB`] (a parser that allocates what a
//! header declares aborts the process or blows that bound).
//!
//! `cargo test --test fuzz_parsers` runs a short pass (a few seconds per parser).
//! The long run: `cargo test --release --test fuzz_parsers -- --ignored --test-threads=1`
//! (`HELMCAP_FUZZ_CASES` sets the cases per parser, default 20,000; `HELMCAP_FUZZ_ONLY`
//! a comma-separated list of the parsers to run, by their names in that test); each parser
//! prints one line with its cases, time, slowest case and peak memory.
//! A failing case is written to `$TMPDIR/helmcap-fuzz-<parser>-<case>.bin`.

#![allow(clippy::unwrap_used)]

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::time::Instant;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use helmcap::bundles::{parse_bundles, read_bundles};
use helmcap::camera::parse_rig;
use helmcap::capture::syncbox::{LineParser, format_line};
use helmcap::capture::{GrayConversion, LiveConfig, Replay, ReplayParams, decode_gray};
use helmcap::dataset::{Manifest, MarkerLayout};
use helmcap::mesh::{read_obj_str, read_ply_bytes, write_obj, write_ply};
use helmcap::sink::usd_read::parse_usda_sequence;
use helmcap::timecode::Timecode;
use helmcap::track::CaptureProfile;

/// Slowest a single case may be, seconds (inputs are at most a few MB).
const MAX_CASE_SECS: f64 = 5.0;
/// Peak resident memory of the whole test process, MB.
const MAX_PEAK_RSS_MB: f64 = 2048.0;
/// Cases per parser in the short run.
const SHORT_CASES: usize = 150;

/// Numbers that break naive parsers: overflow, huge counts, non-finite, negative.
const EXTREMES: &[&str] = &[
    "0",
    "-1",
    "1e300",
    "-1e300",
    "nan",
    "inf",
    "1e-320",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "18446744073709551615",
    "1000000000000000000",
    "1000000000000",
    "16777215",
    "65535",
    "2147483648",
    "0..4000000000",
    "99999999999999999999999",
];

/// Tokens that matter to one format or another.
const TOKENS: &[&str] = &[
    ",", "\n", "\r\n", "..", "[", "]", "{", "}", "=", "\"", ":", "$", "*", "#", "\0", "é", " ",
    "\t", "(", ")", ";", "@", "-",
];

/// One random mutation of `seed`, 1 to 4 edits.
fn mutate(rng: &mut StdRng, seed: &[u8]) -> Vec<u8> {
    let mut b = seed.to_vec();
    for _ in 0..rng.random_range(1..=4) {
        let len = b.len();
        let at = if len == 0 {
            0
        } else {
            rng.random_range(0..len)
        };
        match rng.random_range(0..10) {
            0 if len > 0 => b[at] ^= 1 << rng.random_range(0..8),
            1 => b.insert(at, rng.random()),
            2 if len > 0 => {
                let end = (at + rng.random_range(1..64)).min(len);
                b.drain(at..end);
            }
            3 if len > 0 => {
                let end = (at + rng.random_range(1..256)).min(len);
                let chunk = b[at..end].to_vec();
                for _ in 0..rng.random_range(1..8) {
                    b.splice(at..at, chunk.iter().copied());
                }
            }
            4 | 5 => {
                // A run of digits (or any place) becomes an extreme number.
                let start = b[..at]
                    .iter()
                    .rposition(|c| !c.is_ascii_digit() && *c != b'.')
                    .map_or(0, |p| p + 1);
                let end = b[at..]
                    .iter()
                    .position(|c| !c.is_ascii_digit() && *c != b'.')
                    .map_or(len, |p| at + p);
                let n = EXTREMES[rng.random_range(0..EXTREMES.len())];
                b.splice(start..end.max(start), n.bytes());
            }
            6 if rng.random_range(0..8) == 0 => {
                // A long line (up to 1 MB).
                let n = 1 << rng.random_range(10..20);
                let c = [b'9', b'x', b',', b' '][rng.random_range(0..4)];
                b.splice(at..at, std::iter::repeat_n(c, n));
            }
            7 => b.truncate(at),
            8 => {
                let t = TOKENS[rng.random_range(0..TOKENS.len())];
                b.splice(at..at, t.bytes());
            }
            _ => {
                // Swap two lines.
                let text = String::from_utf8_lossy(&b).into_owned();
                let mut lines: Vec<&str> = text.split('\n').collect();
                if lines.len() > 2 {
                    let i = rng.random_range(0..lines.len());
                    let j = rng.random_range(0..lines.len());
                    lines.swap(i, j);
                    b = lines.join("\n").into_bytes();
                }
            }
        }
    }
    b
}

/// Peak resident memory of the process so far, MB (Linux `VmHWM`; 0 elsewhere).
fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        })
        .map_or(0.0, |kb| kb / 1024.0)
}

/// Resets the peak (Linux 4.0+: `5` to `clear_refs`), so each parser's peak is its own
/// when the tests run one at a time.
fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

fn cases(long: bool) -> usize {
    if long {
        std::env::var("HELMCAP_FUZZ_CASES")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(20_000)
    } else {
        SHORT_CASES
    }
}

/// Runs `parse` on `cases` mutants of the seeds (and on the seeds themselves) and checks
/// the properties of the module docs. `parse` returns whether the input was accepted.
fn fuzz(name: &str, seeds: &[Vec<u8>], cases: usize, parse: impl Fn(&[u8]) -> bool) {
    reset_peak_rss();
    let mut rng = StdRng::seed_from_u64(name.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
    }));
    let started = Instant::now();
    let (mut slowest, mut accepted, mut crashes) = (0.0f64, 0usize, Vec::new());
    for (k, seed) in seeds.iter().enumerate() {
        assert!(parse(seed), "{name}: seed {k} must parse");
    }
    for case in 0..cases {
        let seed = &seeds[rng.random_range(0..seeds.len())];
        let input = mutate(&mut rng, seed);
        let t = Instant::now();
        let result = catch_unwind(AssertUnwindSafe(|| parse(&input)));
        let secs = t.elapsed().as_secs_f64();
        slowest = slowest.max(secs);
        match result {
            Ok(ok) => accepted += usize::from(ok),
            Err(_) => {
                let path = std::env::temp_dir().join(format!("helmcap-fuzz-{name}-{case}.bin"));
                let _ = std::fs::write(&path, &input);
                crashes.push(path);
            }
        }
        if secs > MAX_CASE_SECS {
            let path = std::env::temp_dir().join(format!("helmcap-fuzz-{name}-{case}-slow.bin"));
            let _ = std::fs::write(&path, &input);
            panic!(
                "{name}: case {case} took {secs:.1} s (input saved to {})",
                path.display()
            );
        }
    }
    let peak = peak_rss_mb();
    println!(
        "fuzz {name}: {cases} cases in {:.2} s ({accepted} accepted), slowest case {:.1} ms, \
         peak RSS {peak:.0} MB, {} crashes",
        started.elapsed().as_secs_f64(),
        slowest * 1e3,
        crashes.len()
    );
    assert!(crashes.is_empty(), "{name}: panics on {crashes:?}");
    assert!(peak < MAX_PEAK_RSS_MB, "{name}: peak RSS {peak:.0} MB");
}

fn text(bytes: &[u8]) -> std::borrow::Cow<'_, str> {
    String::from_utf8_lossy(bytes)
}

fn layout() -> MarkerLayout {
    MarkerLayout::parse_csv(
        "name,vertex,stabilize_weight\nbrow_l,0,1\nbrow_r,1,1\nnose,2,1\nchin,3,0\n",
        "layout.csv",
    )
    .unwrap()
}

// ---------------------------------------------------------------- the parsers

fn calibration(cases: usize) {
    let seeds = [
        include_bytes!("../calib/helmet-fisheye.yaml").to_vec(),
        include_bytes!("../calib/helmet-pinhole.yaml").to_vec(),
    ];
    fuzz("calibration", &seeds, cases, |b| {
        parse_rig(Path::new("rig.yaml"), &text(b)).is_ok()
    });
}

fn manifest(cases: usize) {
    let dir = tempfile::tempdir().unwrap();
    let mesh = helmcap::mesh::Mesh::new(
        vec![
            nalgebra::Point3::new(0.0, 0.0, 0.0),
            nalgebra::Point3::new(1.0, 0.0, 0.0),
            nalgebra::Point3::new(0.0, 1.0, 0.0),
            nalgebra::Point3::new(1.0, 1.0, 0.0),
        ],
        &[vec![0, 1, 3, 2]],
        Vec::new(),
        None,
    )
    .unwrap();
    write_obj(&dir.path().join("neutral.obj"), &mesh).unwrap();
    write_obj(&dir.path().join("jawOpen.obj"), &mesh).unwrap();
    let seeds = [
        b"units = \"cm\"\nneutral = \"neutral.obj\"\nface_vertices = \"0..3\"\n\
          [[shape]]\nname = \"jawOpen\"\nfile = \"jawOpen.obj\"\n\
          [[shape]]\nname = \"half\"\ncombine = { jawOpen = 0.5 }\n\
          [regions]\nmouth_l = \"0\"\nmouth_r = \"1\"\nbrow_l = \"2..3\"\nbrow_r = \"3\"\n"
            .to_vec(),
        b"units = \"mm\"\nneutral = \"neutral.obj\"\nshapes_glob = \"*.obj\"\n".to_vec(),
    ];
    let path = dir.path().join("manifest.toml");
    fuzz("manifest", &seeds, cases, |b| {
        Manifest::parse(&text(b), &path).is_ok()
    });
}

fn markers(cases: usize) {
    let seeds = [
        include_bytes!("../configs/markers/builtin-actor.csv").to_vec(),
        b"name,vertex,stabilize_weight\nbrow_l,0,1\nchin,3,\n".to_vec(),
    ];
    fuzz("markers", &seeds, cases, |b| {
        MarkerLayout::parse_csv(&text(b), "markers.csv").is_ok()
    });
}

fn bundles(cases: usize) {
    let layout = layout();
    let mut seed = String::from("frame,marker,x,y,z,confidence,status,timecode\n");
    for f in 0..6 {
        for (k, m) in layout.markers.iter().enumerate() {
            seed.push_str(&format!(
                "{f},{},{:.3},{:.3},{:.3},0.9,observed,01:00:00:0{f}.0@30\n",
                m.name,
                10.0 * k as f64,
                -5.5 + f as f64,
                80.25
            ));
        }
    }
    seed.push_str("6,chin,nan,nan,nan,0,dropped,\n");
    fuzz("bundles_csv", &[seed.into_bytes()], cases, |b| {
        parse_bundles(&text(b), "bundles.csv", &layout).is_ok()
    });
}

fn obj(cases: usize) {
    let seed = b"# quad and triangle\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\n\
                 vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n\
                 f 1/1 2/2 3/3 4/4\nf 2/2 5/5 3/3\n"
        .to_vec();
    fuzz("obj", &[seed], cases, |b| {
        read_obj_str(&text(b), "m.obj").is_ok()
    });
}

fn ply(cases: usize) {
    let dir = tempfile::tempdir().unwrap();
    let mesh = helmcap::mesh::read_obj_str(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n\
         f 1/1 2/2 3/3 4/4\nf 2/2 5/5 3/3\n",
        "m.obj",
    )
    .unwrap();
    let path = dir.path().join("m.ply");
    write_ply(&path, &mesh, None).unwrap();
    let binary = std::fs::read(&path).unwrap();
    let ascii = b"ply\nformat ascii 1.0\ncomment scan\nelement vertex 4\nproperty double x\n\
                  property double y\nproperty double z\nproperty uchar red\n\
                  element face 2\nproperty list uchar int vertex_indices\nend_header\n\
                  0 0 0 255\n1 0 0 0\n0 1 0.5 9\n1 1 1 3\n3 0 1 2\n3 1 3 2\n"
        .to_vec();
    fuzz("ply", &[binary, ascii], cases, |b| {
        read_ply_bytes(b, "m.ply").is_ok()
    });
}

fn usd(cases: usize) {
    let seed = b"#usda 1.0\n(\n    customLayerData = {\n        int frames = 2\n    }\n    \
                 timeCodesPerSecond = 60\n)\n\ndef Xform \"Face\"\n{\n    def Mesh \"face\"\n    {\n        \
                 int[] faceVertexCounts = [3, 3]\n        int[] faceVertexIndices = [0, 1, 2, 0, 2, 3]\n        \
                 point3f[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]\n        \
                 point3f[] points.timeSamples = {\n            0: [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)],\n            \
                 1: [(0, 0, 0.5), (1, 0, 0), (1, 1.5, 0), (0, 1, 0)]\n        }\n    }\n}\n"
        .to_vec();
    fuzz("usd", &[seed], cases, |b| {
        parse_usda_sequence(b, "mesh.usda").is_ok()
    });
}

fn profile(cases: usize) {
    let seed = b"dot_diameter_mm = 2.4\npolarity = \"dark\"\ncamera_distance_mm = [100, 300]\n\
                 [detect]\nthreshold_k = 2.5\n[label]\n"
        .to_vec();
    let plain = b"dot_diameter_mm = 3\npolarity = \"bright\"\n".to_vec();
    let path = Path::new("profile.toml");
    let ok = |b: &[u8]| CaptureProfile::parse(&text(b), path).is_ok();
    // The first seed's [detect] key may not exist in this version: keep only seeds that
    // parse.
    let seeds: Vec<Vec<u8>> = [seed, plain].into_iter().filter(|s| ok(s)).collect();
    fuzz("profile", &seeds, cases, ok);
}

fn live_config(cases: usize) {
    let dir = tempfile::tempdir().unwrap();
    let seed = include_str!("../configs/live.toml")
        .replace("../calib/helmet-fisheye.yaml", "rig.yaml")
        .into_bytes();
    let path = dir.path().join("live.toml");
    fuzz("live_toml", &[seed], cases, |b| {
        std::fs::write(&path, b).unwrap();
        LiveConfig::load(&path).is_ok()
    });
}

/// Image decoding by content: 8-bit grey, 16-bit grey and RGB PNGs, a JPEG and a TIFF
/// (what cameras and other tools write), mutated (headers that declare huge sizes, cut
/// files, flipped bits in compressed data).
fn images(cases: usize) {
    use image::{ImageFormat, Luma, Rgb};
    let (w, h) = (40u32, 30u32);
    let level = |x: u32, y: u32| ((x * 7 + y * 13) % 256) as u8;
    let gray = image::ImageBuffer::from_fn(w, h, |x, y| Luma([level(x, y)]));
    let gray16 = image::ImageBuffer::from_fn(w, h, |x, y| Luma([u16::from(level(x, y)) * 257]));
    let rgb = image::ImageBuffer::from_fn(w, h, |x, y| {
        Rgb([level(x, y), level(y, x), level(x + y, 3)])
    });
    let encode = |img: &image::DynamicImage, format: ImageFormat| {
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, format).unwrap();
        out.into_inner()
    };
    let seeds = vec![
        encode(
            &image::DynamicImage::ImageLuma8(gray.clone()),
            ImageFormat::Png,
        ),
        encode(&image::DynamicImage::ImageLuma16(gray16), ImageFormat::Png),
        encode(&image::DynamicImage::ImageRgb8(rgb), ImageFormat::Png),
        encode(
            &image::DynamicImage::ImageLuma8(gray.clone()),
            ImageFormat::Jpeg,
        ),
        encode(&image::DynamicImage::ImageLuma8(gray), ImageFormat::Tiff),
    ];
    fuzz("image", &seeds, cases, |b| {
        decode_gray(b, GrayConversion::Luma).is_ok()
    });
}

/// C3D marker files (read by content wherever bundles are): our own writer's file as the
/// seed; mutated headers, parameter sections and point data.
fn c3d(cases: usize) {
    use helmcap::pipeline::{BundleStatus, FrameResult, MarkerResult, Metrics, SessionMeta, Sink};
    use helmcap::sink::c3d::C3dSink;
    use std::sync::Arc;
    let layout = layout();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bundles.c3d");
    let mut sink = C3dSink::new(&path);
    sink.begin(&SessionMeta {
        name: "fuzz".into(),
        fps: 60.0,
        timecode_rate: None,
        first_frame: helmcap::frame_index::FrameIndex::new(0),
        frame_count: None,
        layout: Arc::new(layout.clone()),
        neutral_markers_head: Arc::new(Vec::new()),
        neutral: None,
        face_vertices: None,
        rig: None,
        image_size: None,
    })
    .unwrap();
    for index in 0..6 {
        let image = helmcap::capture::GrayImage {
            width: 1,
            height: 1,
            data: vec![0],
        };
        let mut f = FrameResult::new(
            helmcap::frame_index::FrameIndex::new(index),
            0,
            None,
            [image.clone(), image],
            layout.len(),
        );
        for (k, m) in f.markers.iter_mut().enumerate() {
            // One marker is missing in every other frame.
            if k == 3 && index % 2 == 1 {
                continue;
            }
            *m = MarkerResult {
                status: BundleStatus::Observed,
                point_in_head: Some(nalgebra::Point3::new(10.0 * k as f64, index as f64, 80.0)),
                ..MarkerResult::MISSING
            };
        }
        sink.write(&f).unwrap();
    }
    sink.finish(&Metrics::default()).unwrap();
    let seed = std::fs::read(&path).unwrap();
    let case_path = dir.path().join("case.c3d");
    fuzz("c3d", &[seed], cases, |b| {
        std::fs::write(&case_path, b).unwrap();
        read_bundles(&case_path, &layout).is_ok()
    });
}

/// Video containers and their frames, decoded by OpenCV's FFmpeg backend (the `[video]`
/// sessions): an FFV1 Matroska file (lossless, what `ingest` and the tests use) and an
/// MJPEG AVI (what many camera recorders write), 6 frames of 48×32 each, mutated (headers
/// that declare huge frames or frame counts, cut files, flipped bits in the packets). Each
/// case opens the file and decodes its first frames. FFmpeg is C: a crash in it would end
/// the whole test process rather than be caught, which is a failure too.
fn video(cases: usize) {
    use helmcap::capture::video::VideoReader;
    use opencv::core::{Mat, Size};
    use opencv::prelude::*;
    use opencv::videoio;

    let dir = tempfile::tempdir().unwrap();
    for (name, fourcc) in [("mkv", ['F', 'F', 'V', '1']), ("avi", ['M', 'J', 'P', 'G'])] {
        let seed_path = dir.path().join(format!("seed.{name}"));
        let code =
            videoio::VideoWriter::fourcc(fourcc[0], fourcc[1], fourcc[2], fourcc[3]).unwrap();
        let mut writer = videoio::VideoWriter::new_with_backend(
            seed_path.to_str().unwrap(),
            videoio::CAP_FFMPEG,
            code,
            60.0,
            Size::new(48, 32),
            false,
        )
        .unwrap();
        if !writer.is_opened().unwrap() {
            println!("fuzz video_{name}: skipped, OpenCV's FFmpeg backend cannot write {fourcc:?}");
            continue;
        }
        for k in 0..6u32 {
            let pixels: Vec<u8> = (0..48 * 32u32)
                .map(|i| ((i % 48) * 5 + (i / 48) * 3 + k * 20) as u8)
                .collect();
            let mat = Mat::new_rows_cols_with_data(32, 48, &pixels)
                .unwrap()
                .try_clone()
                .unwrap();
            writer.write(&mat).unwrap();
        }
        writer.release().unwrap();
        let seed = std::fs::read(&seed_path).unwrap();
        let case_path = dir.path().join(format!("case.{name}"));
        fuzz(&format!("video_{name}"), &[seed], cases, |b| {
            std::fs::write(&case_path, b).unwrap();
            let Ok(mut reader) = VideoReader::open(&case_path) else {
                return false;
            };
            (0..reader.frame_count().min(8)).all(|i| reader.read_at(i).is_ok())
        });
    }
}

fn session(cases: usize) {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    for cam in ["cam0", "cam1"] {
        std::fs::create_dir_all(root.join(cam)).unwrap();
    }
    let toml_seed =
        b"fps = 60.0\ncameras = [\"cam0\", \"cam1\"]\n[timecode]\nrate = \"30\"\n".to_vec();
    let mut frames_seed = String::from("frame,timestamp_ns,timecode\n");
    for f in 0..8u64 {
        frames_seed.push_str(&format!("{f},{},01:00:00:{:02}\n", f * 16_666_667, f / 2));
    }
    let frames_seed = frames_seed.into_bytes();
    std::fs::write(root.join("frames.csv"), &frames_seed).unwrap();
    fuzz(
        "session_toml",
        std::slice::from_ref(&toml_seed),
        cases,
        |b| {
            std::fs::write(root.join("session.toml"), b).unwrap();
            Replay::open(root, ReplayParams::default()).is_ok()
        },
    );
    std::fs::write(root.join("session.toml"), &toml_seed).unwrap();
    fuzz("frames_csv", &[frames_seed], cases, |b| {
        std::fs::write(root.join("frames.csv"), b).unwrap();
        Replay::open(root, ReplayParams::default()).is_ok()
    });
}

fn syncbox(cases: usize) {
    let mut seed = Vec::new();
    for k in 0..20u64 {
        let tc: Timecode = format!("01:00:00:{:02}@30", k % 30).parse().unwrap();
        seed.extend_from_slice(format_line(&tc, 1000 + 2 * k).as_bytes());
    }
    fuzz("syncbox_lines", &[seed], cases, |b| {
        let mut p = LineParser::new();
        let mut ok = 0;
        for chunk in b.chunks(7) {
            p.push(chunk, |l| ok += usize::from(l.is_ok()));
        }
        ok > 0
    });
}

// ---------------------------------------------------------------- short runs (CI)

#[test]
fn fuzz_calibration_yaml() {
    calibration(cases(false));
}
#[test]
fn fuzz_manifest_toml() {
    manifest(cases(false));
}
#[test]
fn fuzz_markers_csv() {
    markers(cases(false));
}
#[test]
fn fuzz_bundles_csv() {
    bundles(cases(false));
}
#[test]
fn fuzz_obj() {
    obj(cases(false));
}
#[test]
fn fuzz_ply() {
    ply(cases(false));
}
#[test]
fn fuzz_usd_reader() {
    usd(cases(false));
}
#[test]
fn fuzz_capture_profile_toml() {
    profile(cases(false));
}
#[test]
fn fuzz_live_toml() {
    live_config(cases(false));
}
#[test]
fn fuzz_session_toml_and_frames_csv() {
    session(cases(false));
}
#[test]
fn fuzz_syncbox_lines() {
    syncbox(cases(false));
}
#[test]
fn fuzz_images() {
    images(cases(false));
}
#[test]
fn fuzz_c3d() {
    c3d(cases(false));
}
#[test]
fn fuzz_video() {
    video(cases(false));
}

// ---------------------------------------------------------------- the long run

/// A parser's name in `HELMCAP_FUZZ_ONLY` and its fuzz run (cases → checks).
type Parser = (&'static str, fn(usize));

#[test]
#[ignore = "long fuzz run: cargo test --release -- --ignored"]
fn long_fuzz_every_parser() {
    let n = cases(true);
    let only = std::env::var("HELMCAP_FUZZ_ONLY").ok();
    let parsers: [Parser; 14] = [
        ("calibration", calibration),
        ("manifest", manifest),
        ("markers", markers),
        ("bundles", bundles),
        ("obj", obj),
        ("ply", ply),
        ("usd", usd),
        ("profile", profile),
        ("live", live_config),
        ("session", session),
        ("syncbox", syncbox),
        ("images", images),
        ("c3d", c3d),
        ("video", video),
    ];
    for (name, run) in parsers {
        if only
            .as_deref()
            .is_none_or(|o| o.split(',').any(|x| x.trim() == name))
        {
            run(n);
        }
    }
}
