//! `helmcap replay --rrd`: the rerun recording of a synthetic take holds every frame's
//! images, markers, bundles, head pose, mesh (with its error against ground truth) and
//! timings, on the frame and timecode timelines, and stays readable when a take stops
//! early. Also checked with `rerun rrd verify` when the `rerun` command is installed.

#![allow(clippy::unwrap_used)]

use std::collections::{BTreeMap, BTreeSet};
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use re_log_encoding::DecoderApp;
use rerun::log::{Chunk, LogMsg};

mod common;
use common::{helmcap, ok};

/// A small synthetic session with ground-truth meshes.
fn synth(dir: &Path, frames: usize) -> PathBuf {
    let s = dir.join("session");
    let n = frames.to_string();
    ok(&helmcap(&[
        "synth",
        "--out",
        s.to_str().unwrap(),
        "-n",
        &n,
        "--meshes",
    ]));
    s
}

fn replay(session: &Path, out: &Path, extra: &[&str]) -> Output {
    let cache = out.with_extension("cache");
    let mut args = vec![
        "replay",
        session.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
        "--quiet",
    ];
    args.extend_from_slice(extra);
    helmcap(&args)
}

/// Temporal rows per entity and the timelines of an `.rrd` file.
fn decode(path: &Path) -> (BTreeMap<String, usize>, BTreeSet<String>) {
    let file = std::fs::File::open(path).expect("open rrd");
    let mut rows = BTreeMap::new();
    let mut timelines = BTreeSet::new();
    for msg in DecoderApp::decode_lazy(BufReader::new(file)) {
        let LogMsg::ArrowMsg(_, arrow) = msg.expect("decode") else {
            continue;
        };
        let chunk = Chunk::from_arrow_msg(&arrow).expect("chunk");
        if !chunk.is_static() {
            *rows.entry(chunk.entity_path().to_string()).or_default() += chunk.num_rows();
            timelines.extend(chunk.timelines().keys().map(|t| t.to_string()));
        }
    }
    (rows, timelines)
}

/// `rerun rrd verify FILE` when the command exists; prints why it was skipped otherwise.
fn verify_with_rerun_cli(path: &Path) {
    match Command::new("rerun")
        .args(["rrd", "verify"])
        .arg(path)
        .output()
    {
        Ok(out) => assert!(
            out.status.success(),
            "rerun rrd verify:\n{}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
        Err(e) => eprintln!("skipped `rerun rrd verify`: no `rerun` command ({e})"),
    }
}

#[test]
fn replay_writes_a_complete_recording() {
    let dir = tempfile::tempdir().unwrap();
    let frames = 12;
    let session = synth(dir.path(), frames);
    let out = dir.path().join("out");
    let rrd = out.join("take.rrd");
    ok(&replay(
        &session,
        &out,
        &[
            "--rrd",
            rrd.to_str().unwrap(),
            "--rerun-image-every",
            "3",
            "--rerun-image-downscale",
            "2",
        ],
    ));
    let (rows, timelines) = decode(&rrd);
    // Images every third frame; everything else every frame.
    assert_eq!(rows.get("/cam0/image"), Some(&4), "{rows:?}");
    assert_eq!(rows.get("/cam1/image"), Some(&4), "{rows:?}");
    for entity in [
        "/cam0/markers",
        "/cam1/markers",
        "/world/head",
        "/world/head/bundles",
        "/world/head/mesh",
        "/accuracy/vertex_error_mean_mm",
        "/timings/track",
        "/timings/solve",
        "/timings/end_to_end",
        "/timecode",
    ] {
        assert_eq!(rows.get(entity), Some(&frames), "{entity}: {rows:?}");
    }
    for timeline in ["frame", "timecode", "capture_time"] {
        assert!(timelines.contains(timeline), "{timeline}: {timelines:?}");
    }
    verify_with_rerun_cli(&rrd);
}

#[test]
fn a_stopped_take_leaves_a_readable_recording() {
    let dir = tempfile::tempdir().unwrap();
    let session = synth(dir.path(), 10);
    std::fs::write(session.join("cam0/000006.png"), b"not a png").unwrap();
    let out = dir.path().join("out");
    let rrd = out.join("take.rrd");
    let o = replay(&session, &out, &["--rrd", rrd.to_str().unwrap()]);
    assert!(!o.status.success());
    let (rows, _) = decode(&rrd);
    assert_eq!(rows.get("/world/head/mesh"), Some(&6), "{rows:?}");
    let leftovers: Vec<_> = std::fs::read_dir(&out)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().ends_with(".partial"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
}

#[test]
fn a_bad_viewer_option_is_one_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let o = helmcap(&[
        "replay",
        dir.path().to_str().unwrap(),
        "--viewer",
        "somewhere",
    ]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("spawn"), "{err}");
    assert!(err.contains("connect=HOST:PORT"), "{err}");
}
