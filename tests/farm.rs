//! Dailies on a farm through the real binary: chunked replays (`replay --frames
//! --warm-up`) joined by `farm merge` equal a single pass over the take, on a take with
//! helmet slip, a marker occluded across a chunk boundary and a blink across a boundary;
//! merge refuses chunks that do not make the take; and the OpenJD job bundle `farm job`
//! writes passes `openjd check` and runs end to end under `openjd run` as a farm worker
//! would run it (skipped with a printed reason when openjd-cli is not installed).

#![allow(clippy::unwrap_used)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;
use common::{helmcap, ok};

/// JSON values equal but for the last bits of floating-point sums (summed in another
/// order when chunks are merged).
fn same_json(a: &serde_json::Value, b: &serde_json::Value) -> bool {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            (x - y).abs() <= 1e-12 * x.abs().max(y.abs()).max(1.0)
        }
        (Value::Object(x), Value::Object(y)) => {
            x.len() == y.len()
                && x.iter()
                    .all(|(k, v)| y.get(k).is_some_and(|w| same_json(v, w)))
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(v, w)| same_json(v, w))
        }
        _ => a == b,
    }
}

/// A temporary folder (removed when the returned guard drops, also on failure).
fn tmp() -> (tempfile::TempDir, PathBuf) {
    let guard = tempfile::tempdir().unwrap();
    let dir = guard.path().to_path_buf();
    (guard, dir)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Frames of the take in the tests, chunk size and warm-up.
const FRAMES: usize = 240;
const CHUNK: usize = 80;
const OVERLAP: usize = 60;
/// The replay options of a chunked take's single pass: labeling restarts where each
/// chunk's warm-up starts (`farm job` passes the same to every chunk).
const RELABEL: [&str; 4] = ["--relabel-every", "80", "--relabel-lead", "60"];

fn synth(dir: &Path, name: &str, extra: &[&str]) -> PathBuf {
    let session = dir.join(name);
    let mut args = vec!["synth", "--out", s(&session), "-n"];
    let n = FRAMES.to_string();
    args.push(&n);
    args.extend_from_slice(extra);
    ok(&helmcap(&args));
    session
}

fn replay(session: &Path, out: &Path, cache: &Path, extra: &[&str]) {
    let mut args = vec![
        "replay",
        s(session),
        "--out",
        s(out),
        "--cache-dir",
        s(cache),
        "--quiet",
        "--overwrite",
        "--export",
        "usd",
        "--export",
        "c3d",
        "--export",
        "obj",
    ];
    args.extend_from_slice(extra);
    ok(&helmcap(&args));
}

/// Replays `session` in chunks of [`CHUNK`] frames warmed up by [`OVERLAP`] into
/// `chunks/<start>`.
fn replay_chunks(session: &Path, chunks: &Path, cache: &Path) {
    for start in (0..FRAMES).step_by(CHUNK) {
        let range = format!("{start}..{}", start + CHUNK);
        let overlap = OVERLAP.to_string();
        replay(
            session,
            &chunks.join(start.to_string()),
            cache,
            &[
                &["--frames", &range, "--warm-up", &overlap][..],
                &RELABEL[..],
            ]
            .concat(),
        );
    }
}

/// `bundles.csv` as (frame, marker) → (x, y, z, status).
fn bundles(dir: &Path) -> BTreeMap<(usize, String), (f64, f64, f64, String)> {
    let text = std::fs::read_to_string(dir.join("bundles.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            (
                (c[0].parse().unwrap(), c[1].to_string()),
                (
                    c[2].parse().unwrap(),
                    c[3].parse().unwrap(),
                    c[4].parse().unwrap(),
                    c[6].to_string(),
                ),
            )
        })
        .collect()
}

/// The vertices of an OBJ file.
fn obj_vertices(path: &Path) -> Vec<[f64; 3]> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter_map(|l| l.strip_prefix("v "))
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

/// Paints over marker `marker`'s dot in both cameras on `frames` (from the ground truth's
/// projections) with the mean of a ring of skin around it: the dot is occluded there.
fn occlude(session: &Path, marker: &str, frames: std::ops::Range<usize>) {
    let text = std::fs::read_to_string(session.join("gt/projections.csv")).unwrap();
    for line in text.lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        let frame: usize = c[0].parse().unwrap();
        if c[2] != marker || !frames.contains(&frame) {
            continue;
        }
        let (u, v): (f64, f64) = (c[3].parse().unwrap(), c[4].parse().unwrap());
        let path = session.join(format!("{}/{frame:06}.png", c[1]));
        let mut img = image::open(&path).unwrap().into_luma8();
        let (w, h) = img.dimensions();
        let (r_in, r_out) = (9.0, 12.0);
        let mut ring = Vec::new();
        for y in (v - r_out) as i64..=(v + r_out) as i64 {
            for x in (u - r_out) as i64..=(u + r_out) as i64 {
                let d = ((x as f64 - u).powi(2) + (y as f64 - v).powi(2)).sqrt();
                if x >= 0 && y >= 0 && (x as u32) < w && (y as u32) < h && d > r_in && d <= r_out {
                    ring.push(f64::from(img.get_pixel(x as u32, y as u32).0[0]));
                }
            }
        }
        if ring.is_empty() {
            continue;
        }
        let fill = (ring.iter().sum::<f64>() / ring.len() as f64).round() as u8;
        for y in (v - r_in) as i64..=(v + r_in) as i64 {
            for x in (u - r_in) as i64..=(u + r_in) as i64 {
                let d = ((x as f64 - u).powi(2) + (y as f64 - v).powi(2)).sqrt();
                if x >= 0 && y >= 0 && (x as u32) < w && (y as u32) < h && d <= r_in {
                    img.put_pixel(x as u32, y as u32, image::Luma([fill]));
                }
            }
        }
        img.save(&path).unwrap();
    }
}

/// Expression weights for [`FRAMES`] frames: the jaw, smile and brows moving all the
/// time, and a blink (closed at 0.5 s in, 0.27 s long) centred on each of `blinks_at`.
fn performance(path: &Path, blinks_at: &[usize]) -> PathBuf {
    let mut csv =
        String::from("frame,jawOpen,mouthSmile_L,mouthSmile_R,browInnerUp,eyeBlink_L,eyeBlink_R\n");
    for f in 0..FRAMES {
        let t = f as f64 / 60.0;
        let jaw = 0.5 * (1.0 - (t * 2.1).cos());
        let smile = 0.4 * (1.0 - (t * 1.3 + 1.0).cos()) / 2.0;
        let brow = 0.6 * (t * 0.9).sin().max(0.0);
        let blink = blinks_at
            .iter()
            .map(|&b| (1.0 - (f as f64 - b as f64).abs() / 8.0).max(0.0))
            .fold(0.0, f64::max);
        csv.push_str(&format!(
            "{f},{jaw:.4},{smile:.4},{smile:.4},{brow:.4},{blink:.4},{blink:.4}\n"
        ));
    }
    std::fs::write(path, csv).unwrap();
    path.to_path_buf()
}

/// A marker of the moving face (low stabilization weight) that both cameras see on every
/// frame of `frames`: occluding it makes a real gap.
fn moving_marker(session: &Path, frames: std::ops::Range<usize>) -> String {
    let layout = std::fs::read_to_string(session.join("gt/markers.csv")).unwrap();
    let text = std::fs::read_to_string(session.join("gt/projections.csv")).unwrap();
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    for line in text.lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        let frame: usize = c[0].parse().unwrap();
        let detectable = matches!(c[9].trim(), "1" | "true");
        if frames.contains(&frame) && detectable {
            *seen.entry(c[2].to_string()).or_default() += 1;
        }
    }
    layout
        .lines()
        .skip(1)
        .map(|l| l.split(',').collect::<Vec<_>>())
        .find(|c| {
            c[2].parse::<f64>().unwrap() < 0.3 && seen.get(c[0]).copied() == Some(2 * frames.len())
        })
        .map(|c| c[0].to_string())
        .expect("a moving marker both cameras see")
}

/// Frames where the ground-truth blink weight (both eyes) passes 0.5.
fn blink_frames(session: &Path) -> Vec<usize> {
    let text = std::fs::read_to_string(session.join("gt/weights.csv")).unwrap();
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = head.iter().position(|c| *c == "eyeBlink_L").unwrap();
    lines
        .filter_map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            let w: f64 = c[col].parse().unwrap();
            (w > 0.5).then(|| c[0].parse().unwrap())
        })
        .collect()
}

#[test]
fn merged_chunks_equal_a_single_pass_across_slip_occlusion_and_blink() {
    let (_guard, dir) = tmp();
    let cache = dir.join("cache");
    // Helmet slip throughout, a performance with the jaw, smile and brows moving, and a
    // blink across each chunk boundary.
    let boundaries: Vec<usize> = (CHUNK..FRAMES).step_by(CHUNK).collect();
    let weights = performance(&dir.join("weights.csv"), &boundaries);
    let session = synth(
        &dir,
        "take_slip",
        &[
            "--slip-mm",
            "1.5",
            "--slip-deg",
            "1.5",
            "--weights",
            s(&weights),
        ],
    );
    let blinks = blink_frames(&session);
    // A marker of the moving face occluded for 20 frames around the first boundary.
    let b = boundaries[0];
    let marker = moving_marker(&session, b - 10..b + 10);
    occlude(&session, &marker, b - 10..b + 10);
    let single = dir.join("single");
    replay(&session, &single, &cache, &RELABEL);
    let chunks = dir.join("chunks");
    replay_chunks(&session, &chunks, &cache);
    let merged = dir.join("merged");
    ok(&helmcap(&[
        "farm",
        "merge",
        s(&chunks),
        "--out",
        s(&merged),
    ]));

    // The occlusion took: the marker is not observed there in the single pass.
    let a = bundles(&single);
    let occluded = (b - 5..b + 5)
        .filter(|f| {
            a.get(&(*f, marker.clone()))
                .is_some_and(|r| r.3 == "observed")
        })
        .count();
    assert_eq!(occluded, 0, "the painted-over marker was still observed");
    for b in &boundaries {
        assert!(
            blinks.contains(&(b - 1)) && blinks.contains(b),
            "no blink across boundary {b}: {blinks:?}"
        );
    }

    // Every bundle of the single pass is in the merged take, at the same place (0.01 mm)
    // and with the same status, and no other.
    let m = bundles(&merged);
    assert_eq!(a.len(), m.len(), "bundle rows differ");
    let mut worst = 0.0f64;
    for (key, (x, y, z, status)) in &a {
        let (mx, my, mz, ms) = m
            .get(key)
            .unwrap_or_else(|| panic!("frame {} marker {} missing in the merge", key.0, key.1));
        assert_eq!(status, ms, "frame {} marker {}", key.0, key.1);
        if x.is_finite() {
            let d = ((x - mx).powi(2) + (y - my).powi(2) + (z - mz).powi(2)).sqrt();
            worst = worst.max(d);
        }
    }
    println!("largest bundle difference {worst:.2e} mm");
    assert!(worst <= 0.01, "bundles differ by up to {worst} mm");

    // Every mesh vertex within 0.01 mm, frame by frame.
    let mut worst = 0.0f64;
    for f in 0..FRAMES {
        let name = format!("mesh/frame_{f:06}.obj");
        let (p, q) = (single.join(&name), merged.join(&name));
        assert_eq!(p.exists(), q.exists(), "{name}");
        if !p.exists() {
            continue;
        }
        for (u, v) in obj_vertices(&p).iter().zip(obj_vertices(&q)) {
            let d = ((u[0] - v[0]).powi(2) + (u[1] - v[1]).powi(2) + (u[2] - v[2]).powi(2)).sqrt();
            worst = worst.max(d);
        }
    }
    println!("largest mesh vertex difference {worst:.2e} mm");
    assert!(worst <= 0.01, "meshes differ by up to {worst} mm");

    // The other outputs are the single pass's, byte for byte, but for the figures that
    // measure time.
    for file in ["head_pose.csv", "tracks.csv", "bundles.csv", "bundles.c3d"] {
        assert!(
            std::fs::read(single.join(file)).unwrap() == std::fs::read(merged.join(file)).unwrap(),
            "{file} differs from the single pass"
        );
    }
    let usd = |dir: &Path| std::fs::read_to_string(dir.join("mesh.usda")).unwrap();
    assert!(usd(&single) == usd(&merged), "mesh.usda differs");
    let metrics = |dir: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(dir.join("metrics.json")).unwrap()).unwrap()
    };
    let (ms, mm) = (metrics(&single), metrics(&merged));
    // `reacquired` counts a marker seen again after a gap; a chunk cannot know of a
    // sighting before its warm-up, so a gap longer than the warm-up counts in the single
    // pass only (the README says so).
    let mut labeling = mm["labeling"].clone();
    labeling["reacquired"] = ms["labeling"]["reacquired"].clone();
    assert_eq!(ms["labeling"], labeling, "metrics.json labeling");
    let (a, b) = (
        ms["labeling"]["reacquired"].as_u64().unwrap(),
        mm["labeling"]["reacquired"].as_u64().unwrap(),
    );
    assert!(
        b <= a && a - b <= 10,
        "reacquired: {a} single pass, {b} merged"
    );
    for key in [
        "frames_in",
        "frames_out",
        "frames_dropped",
        "gaps",
        "timecode",
        "frame_range",
        "accuracy",
        "warnings",
    ] {
        assert!(
            same_json(&ms[key], &mm[key]),
            "metrics.json {key}: {} single pass, {} merged",
            ms[key],
            mm[key]
        );
    }
    assert_eq!(
        mm["latency_ms"]["end_to_end"]["count"].as_u64(),
        Some(FRAMES as u64)
    );
    assert_eq!(mm["warm_up_frames"].as_u64(), Some(2 * OVERLAP as u64));

    // The merged layer opens in Pixar's USD as one time-sampled mesh.
    match common::python_with("pxr") {
        Err(why) => println!("skipping the USD check: {why}"),
        Ok(py) => {
            let script = format!(
                "from pxr import Usd, UsdGeom\n\
                 s = Usd.Stage.Open({:?})\n\
                 m = UsdGeom.Mesh(s.GetPrimAtPath('/Face/face'))\n\
                 t = m.GetPointsAttr().GetTimeSamples()\n\
                 assert len(t) == {FRAMES}, len(t)\n\
                 assert s.GetStartTimeCode() == 0 and s.GetEndTimeCode() == {}\n\
                 print('usd ok', len(t))\n",
                s(&merged.join("mesh.usda")),
                FRAMES - 1
            );
            ok(&Command::new(py).args(["-c", &script]).output().unwrap());
        }
    }
}

#[test]
fn merge_refuses_missing_foreign_and_half_written_chunks() {
    let (_guard, dir) = tmp();
    let cache = dir.join("cache");
    let take = synth(&dir, "take_a", &[]);
    let other = synth(&dir, "take_b", &["--seed", "3"]);
    let chunks = dir.join("chunks");
    replay_chunks(&take, &chunks, &cache);
    let out = dir.join("merged");
    let refuse = |dirs: &[PathBuf], expect: &str| {
        let mut args = vec!["farm".to_string(), "merge".to_string()];
        args.extend(dirs.iter().map(|d| s(d).to_string()));
        args.extend(["--out".to_string(), s(&out).to_string()]);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = helmcap(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "merge accepted: {args:?}");
        assert!(err.contains(expect), "expected {expect:?} in:\n{err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!out.exists(), "a refused merge published {}", out.display());
        let partial: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(Result::ok)
            .filter(|e| e.file_name().to_string_lossy().contains("merging"))
            .collect();
        assert!(partial.is_empty(), "a staging folder was left behind");
    };
    let c = |start: usize| chunks.join(start.to_string());
    // A missing chunk (the middle one).
    refuse(&[c(0), c(160)], "a chunk is missing");
    // The end of the take missing.
    refuse(&[c(0), c(80)], "chunks are missing");
    // A chunk of another take.
    let foreign = dir.join("foreign");
    replay(
        &other,
        &foreign,
        &cache,
        &[
            &["--frames", "80..160", "--warm-up", "60"][..],
            &RELABEL[..],
        ]
        .concat(),
    );
    refuse(&[c(0), foreign.clone(), c(160)], "another take");
    // Overlapping chunks.
    let overlap = dir.join("overlap");
    replay(
        &take,
        &overlap,
        &cache,
        &[&["--frames", "60..160"][..], &RELABEL[..]].concat(),
    );
    refuse(&[c(0), overlap, c(160)], "overlap");
    // A half-written chunk: its run was killed (no take.json), or a file was cut after.
    let killed = dir.join("killed");
    copy_dir(&c(80), &killed);
    std::fs::remove_file(killed.join("take.json")).unwrap();
    refuse(&[c(0), killed.clone(), c(160)], "did not finish");
    let cut = dir.join("cut");
    copy_dir(&c(80), &cut);
    let bytes = std::fs::read(cut.join("bundles.csv")).unwrap();
    std::fs::write(cut.join("bundles.csv"), &bytes[..bytes.len() / 2]).unwrap();
    refuse(&[c(0), cut, c(160)], "bytes");
    // The complete set merges; a second merge into the same folder needs --overwrite.
    ok(&helmcap(&["farm", "merge", s(&chunks), "--out", s(&out)]));
    let again = helmcap(&["farm", "merge", s(&chunks), "--out", s(&out)]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--overwrite"));
    ok(&helmcap(&[
        "farm",
        "merge",
        s(&chunks),
        "--out",
        s(&out),
        "--overwrite",
    ]));
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let p = e.path();
        if p.is_dir() {
            copy_dir(&p, &to.join(e.file_name()));
        } else {
            std::fs::copy(&p, to.join(e.file_name())).unwrap();
        }
    }
}

/// The `openjd` command of the cross-check environment, or why not.
fn openjd() -> Result<PathBuf, String> {
    let py = common::python_with("openjd")?;
    let bin = py.with_file_name("openjd");
    if bin.is_file() {
        Ok(bin)
    } else {
        Err(format!(
            "{} is missing (run scripts/setup.sh)",
            bin.display()
        ))
    }
}

/// The `-p NAME=VALUE` arguments of a bundle's `parameter_values.yaml`.
fn job_params(bundle: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(bundle.join("parameter_values.yaml")).unwrap();
    let mut out = Vec::new();
    let mut name = None;
    for line in text.lines() {
        if let Some(n) = line.strip_prefix("- name: ") {
            name = Some(n.to_string());
        } else if let Some(v) = line.strip_prefix("  value: ") {
            let v = v.trim_matches('\'').replace("''", "'");
            out.push("-p".to_string());
            out.push(format!("{}={v}", name.take().unwrap()));
        }
    }
    out
}

#[test]
fn openjd_checks_and_runs_a_two_take_job() {
    let (_guard, dir) = tmp();
    let days = dir.join("day");
    std::fs::create_dir_all(&days).unwrap();
    let a = synth(&days, "take_01", &["--seed", "1"]);
    let _b = synth(&days, "take_02", &["--seed", "2", "--slip-mm", "1"]);
    let bundle = dir.join("bundle");
    let results = dir.join("results");
    ok(&helmcap(&[
        "farm",
        "job",
        "--takes",
        s(&days),
        "--out",
        s(&bundle),
        "--results",
        s(&results),
        "--chunk",
        &CHUNK.to_string(),
        "--overlap",
        &OVERLAP.to_string(),
        "--export",
        "usd",
    ]));
    let template = std::fs::read_to_string(bundle.join("template.yaml")).unwrap();
    assert!(template.contains("'Chunks take_01'") && template.contains("'Chunks take_02'"));
    assert!(
        !template.contains(s(&dir)),
        "an absolute path in the template"
    );
    let openjd = match openjd() {
        Ok(b) => b,
        Err(why) => {
            println!("skipping openjd check/run: {why}");
            return;
        }
    };
    ok(&Command::new(&openjd)
        .args(["check", s(&bundle.join("template.yaml"))])
        .output()
        .unwrap());
    let mut args = vec![
        "run".to_string(),
        s(&bundle.join("template.yaml")).to_string(),
    ];
    args.extend(job_params(&bundle));
    let run = Command::new(&openjd)
        .args(&args)
        .env("HELMCAP_CACHE_DIR", dir.join("cache"))
        .output()
        .unwrap();
    ok(&run);
    let log = String::from_utf8_lossy(&run.stdout);
    assert!(log.contains("Session ended successfully"), "{log}");
    // Each take merged, equal to a single pass of it.
    let single = dir.join("single");
    replay(&a, &single, &dir.join("cache"), &RELABEL);
    for file in ["bundles.csv", "head_pose.csv", "tracks.csv"] {
        assert!(
            std::fs::read(single.join(file)).unwrap()
                == std::fs::read(results.join("take_01").join(file)).unwrap(),
            "{file} of the farm's take_01 differs from a single pass"
        );
    }
    for take in ["take_01", "take_02"] {
        let starts: Vec<String> = std::fs::read_dir(results.join("chunks").join(take))
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(starts.len(), FRAMES / CHUNK, "{take}: {starts:?}");
        assert!(results.join(take).join("mesh.usda").is_file());
    }
    assert!(results.join("report/index.html").is_file());
}
