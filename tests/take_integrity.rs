//! Take integrity through the real binary: an output folder holds one take (a re-run needs
//! `--overwrite`, which clears the old frames), and a take that fails because the disk is
//! full publishes every output valid up to the frames it completed.
//!
//! The disk-full tests mount a small tmpfs (root only; they skip with a printed reason
//! when the mount fails). Its size is 45 % of what the take writes on a normal disk, so the
//! take fails about halfway whatever the output sizes are.

#![allow(clippy::unwrap_used)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

mod common;
use common::{helmcap, ok};

fn synth(dir: &Path, frames: usize) -> PathBuf {
    let s = dir.join("session");
    ok(&helmcap(&[
        "synth",
        "--out",
        s.to_str().unwrap(),
        "-n",
        &frames.to_string(),
    ]));
    s
}

fn replay(session: &Path, out: &Path, cache: &Path, extra: &[&str]) -> Output {
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

/// The frame numbers (first column) of a CSV output.
fn frames_of(path: &Path) -> BTreeSet<usize> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .skip(1)
        .filter(|l| !l.is_empty())
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect()
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|r| {
            r.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

#[test]
fn a_take_folder_holds_one_take() {
    let dir = tempfile::tempdir().unwrap();
    let session = synth(dir.path(), 16);
    let out = dir.path().join("out");
    let cache = dir.path().join("cache");
    ok(&replay(&session, &out, &cache, &["--export", "obj"]));
    assert_eq!(files_in(&out.join("mesh")).len(), 16);
    // A second run into the same folder is refused, naming the way out.
    let o = replay(
        &session,
        &out,
        &cache,
        &["--export", "obj", "--frames", "0..6"],
    );
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("already holds a take") && err.contains("--overwrite"),
        "{err}"
    );
    assert_eq!(files_in(&out.join("mesh")).len(), 16, "nothing touched");
    // --overwrite replaces it: no old frame is left beside the new ones.
    ok(&replay(
        &session,
        &out,
        &cache,
        &["--export", "obj", "--frames", "0..6", "--overwrite"],
    ));
    let meshes = files_in(&out.join("mesh"));
    assert_eq!(meshes.len(), 6, "{meshes:?}");
    assert_eq!(frames_of(&out.join("bundles.csv")), (0..6).collect());
}

/// Unmounts on drop (also when an assertion fails).
struct Mount(PathBuf);

impl Drop for Mount {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

fn mount_tmpfs(at: &Path, bytes: u64) -> Option<Mount> {
    std::fs::create_dir_all(at).unwrap();
    let size = format!("size={}k", bytes.div_ceil(4096) * 4);
    let status = Command::new("mount")
        .args(["-t", "tmpfs", "-o", &size, "tmpfs", at.to_str().unwrap()])
        .output();
    match status {
        Ok(o) if o.status.success() => Some(Mount(at.to_path_buf())),
        Ok(o) => {
            println!(
                "skipping the disk-full test: cannot mount a tmpfs ({})",
                String::from_utf8_lossy(&o.stderr).trim()
            );
            None
        }
        Err(e) => {
            println!("skipping the disk-full test: cannot run mount ({e})");
            None
        }
    }
}

fn du(dir: &Path) -> u64 {
    let mut total = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let e = e.unwrap();
        let m = e.metadata().unwrap();
        total += if m.is_dir() { du(&e.path()) } else { m.len() };
    }
    total
}

/// Runs a take onto a disk that fills halfway and checks what is published; returns the
/// frames each output kept, for the behaviour table.
fn disk_full(exports: &[&str], flags: &[&str]) -> Option<Vec<(String, usize)>> {
    let dir = tempfile::tempdir().unwrap();
    let frames = 40;
    let session = synth(dir.path(), frames);
    let cache = dir.path().join("cache");
    let mut extra: Vec<&str> = flags.to_vec();
    for e in exports {
        extra.extend(["--export", e]);
    }
    let full = dir.path().join("full");
    ok(&replay(&session, &full, &cache, &extra));
    let mount = mount_tmpfs(&dir.path().join("small"), du(&full) * 45 / 100)?;
    let out = mount.0.join("out");
    let o = replay(&session, &out, &cache, &extra);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(!o.status.success(), "the take should fail: {err}");
    assert!(
        err.contains("No space left") || err.contains("os error 28"),
        "{err}"
    );
    assert!(
        err.contains("hold the frames completed before the error"),
        "{err}"
    );
    assert_eq!(
        err.lines().filter(|l| l.starts_with("error:")).count(),
        1,
        "{err}"
    );
    let names = files_in(&out);
    assert!(
        !names
            .iter()
            .any(|n| n.ends_with(".partial") || n.ends_with(".tmp")),
        "temporaries left: {names:?}"
    );
    let mut kept = Vec::new();
    // The CSVs hold the same frames, 0 to k − 1.
    let bundles = frames_of(&out.join("bundles.csv"));
    let k = bundles.len();
    assert!(k > 0 && k < frames, "{k} frames kept");
    assert_eq!(bundles, (0..k).collect(), "contiguous from 0");
    assert_eq!(frames_of(&out.join("head_pose.csv")), bundles);
    let tracks = frames_of(&out.join("tracks.csv"));
    assert!(tracks.is_subset(&bundles) && tracks.last() == bundles.last());
    kept.push(("bundles.csv, head_pose.csv, tracks.csv".to_string(), k));
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    assert!(
        metrics["stopped"]
            .as_str()
            .unwrap()
            .contains("No space left")
    );
    kept.push((
        "metrics.json frames_out".into(),
        metrics["frames_out"].as_u64().unwrap() as usize,
    ));
    if exports.contains(&"c3d") {
        let path = out.join("bundles.c3d");
        let c3d = c3dio::C3d::load(path.to_str().unwrap()).expect("c3dio reads bundles.c3d");
        let n = c3d.points.rows();
        assert!(n > 0 && n.abs_diff(k) <= 1, "c3d {n} frames, csv {k}");
        kept.push(("bundles.c3d".into(), n));
    }
    if exports.contains(&"usd") {
        let seq =
            helmcap::sink::read_usda_sequence(&out.join("mesh.usda")).expect("mesh.usda reads");
        let n = seq.frames.len();
        assert!(n > 0 && n.abs_diff(k) <= 1, "usd {n} frames, csv {k}");
        let times: Vec<usize> = seq.frames.iter().map(|(t, _)| *t as usize).collect();
        assert_eq!(times, (0..n).collect::<Vec<_>>());
        check_with_pxr(&out.join("mesh.usda"), n);
        kept.push(("mesh.usda".into(), n));
    }
    if exports.contains(&"obj") {
        let n = files_in(&out.join("mesh")).len();
        assert!(n > 0 && n.abs_diff(k) <= 1, "obj {n} frames, csv {k}");
        kept.push(("mesh/frame_*.obj".into(), n));
    }
    println!("disk full with --export {exports:?}: {kept:?} of {frames} frames");
    drop(mount);
    Some(kept)
}

/// Opens the file with Pixar's USD when the project's Python environment has it.
fn check_with_pxr(path: &Path, frames: usize) {
    let env = std::env::var("HELMCAP_PYTHON_ENV")
        .map(PathBuf::from)
        .unwrap_or_else(|_| {
            PathBuf::from(std::env::var("HOME").unwrap_or_default()).join(".cache/helmcap-python")
        });
    let python = env.join("bin/python");
    let script = format!(
        "from pxr import Usd, UsdGeom\ns = Usd.Stage.Open({:?})\nm = UsdGeom.Mesh(s.GetPrimAtPath('/Face/face'))\n\
         assert len(m.GetPointsAttr().GetTimeSamples()) == {frames}\n",
        path.to_str().unwrap()
    );
    match Command::new(&python).args(["-c", &script]).output() {
        Ok(o) if o.status.success() => {}
        Ok(o) if String::from_utf8_lossy(&o.stderr).contains("No module named 'pxr'") => {
            println!("skipping the pxr check: no usd-core in {}", env.display());
        }
        Ok(o) => panic!(
            "pxr cannot read {}: {}",
            path.display(),
            String::from_utf8_lossy(&o.stderr)
        ),
        Err(e) => println!("skipping the pxr check: {} ({e})", python.display()),
    }
}

#[test]
fn disk_full_with_csv_only_publishes_every_completed_frame() {
    // Bundles only (no dense solve): the CSVs are the whole take.
    disk_full(&[], &["--no-solve"]);
}

#[test]
fn disk_full_with_every_export_publishes_every_completed_frame() {
    disk_full(&["obj", "usd", "c3d"], &[]);
}
