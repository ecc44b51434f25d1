//! Rig solve and animation exports (issue 18) through the real binary: `helmcap animate`
//! on the ground-truth meshes of a synthetic take recovers the built-in actor's
//! ground-truth weights; `replay --rig --export livelink-csv` writes `rig_weights.csv`
//! and a Live Link Face CSV whose timecodes match `frames.csv`; the ICT-FaceKit rig
//! recovers held-out combinations (skipped without the ICT data); a mesh in metres is
//! refused with the likely cause.
//!
//! Tolerances: the actor's expression model is nonlinear (correctives, saturating
//! wrinkles, eyelid warps, a rotating jaw), so a linear rig of its full-weight
//! expressions cannot reproduce it exactly; the issue's bound, 0.05 RMS over all weights
//! and frames, is what is asserted.

#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

mod common;
use common::{blender_python, helmcap, ok, python_with};

/// Header and rows of a CSV.
fn csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut lines = text.lines().filter(|l| !l.is_empty());
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    let rows = lines
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    (header, rows)
}

/// Per frame, weights by name.
fn weights_by_frame(path: &Path) -> HashMap<usize, HashMap<String, f64>> {
    let (header, rows) = csv(path);
    rows.iter()
        .map(|r| {
            let frame = r[0].parse().unwrap();
            let w = header
                .iter()
                .zip(r)
                .filter(|(h, _)| !["frame", "timecode", "residual_mm"].contains(&h.as_str()))
                .map(|(h, v)| (h.clone(), v.parse().unwrap()))
                .collect();
            (frame, w)
        })
        .collect()
}

/// A synthetic take of `frames` frames whose expression weights (`--weights`) mix 2–4
/// of the actor's expressions per frame at weights in [0.2, 1], changing smoothly: a
/// performance that uses the whole rig, not a neutral face.
fn synth(dir: &Path, frames: usize) -> PathBuf {
    let names = helmcap::dataset::actor::Actor::new(&Default::default())
        .unwrap()
        .expression_names()
        .to_vec();
    let n = names.len();
    let mut rng = helmcap::numeric::SplitMix64::new(7);
    let mut rand = || rng.next_f64();
    // Keyframes every 4 frames, linear in between.
    let keys: Vec<Vec<f64>> = (0..frames / 4 + 2)
        .map(|_| {
            let mut w = vec![0.0; n];
            for _ in 0..2 + (rand() * 3.0) as usize {
                w[(rand() * n as f64) as usize % n] = 0.2 + 0.8 * rand();
            }
            w
        })
        .collect();
    let mut text = format!("frame,{}\n", names.join(","));
    for f in 0..frames {
        let (k, t) = (f / 4, (f % 4) as f64 / 4.0);
        let w: Vec<String> = (0..n)
            .map(|i| format!("{:.6}", keys[k][i] * (1.0 - t) + keys[k + 1][i] * t))
            .collect();
        text.push_str(&format!("{f},{}\n", w.join(",")));
    }
    let weights = dir.join("weights.csv");
    std::fs::write(&weights, text).unwrap();
    let s = dir.join("session");
    ok(&helmcap(&[
        "synth",
        "--out",
        s.to_str().unwrap(),
        "--weights",
        weights.to_str().unwrap(),
        "--meshes",
    ]));
    s
}

/// RMS of (solved − true) over every weight of every frame in `solved`.
fn weight_rms(solved: &Path, truth: &Path) -> (f64, usize) {
    let solved = weights_by_frame(solved);
    let truth = weights_by_frame(truth);
    let (mut sq, mut n) = (0.0, 0);
    for (f, w) in &solved {
        for (name, v) in w {
            let t = truth[f][name];
            sq += (v - t).powi(2);
            n += 1;
        }
    }
    ((sq / n as f64).sqrt(), solved.len())
}

/// `animate` on the ground-truth meshes: the weights are the truth's within 0.05 RMS
/// and every frame's fit residual is reported; a mesh in metres is refused.
#[test]
fn animate_recovers_the_actors_weights() {
    let dir = tempfile::tempdir().unwrap();
    let frames = 24;
    let session = synth(dir.path(), frames);
    let out = dir.path().join("anim");
    let o = helmcap(&[
        "animate",
        "--rig",
        "builtin",
        "--input",
        session.join("gt/mesh").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--export",
        "livelink-csv",
        "--no-cache",
    ]);
    ok(&o);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains(&format!("animated {frames} frames")),
        "{stdout}"
    );
    let (rms, n) = weight_rms(
        &out.join("rig_weights.csv"),
        &session.join("gt/weights.csv"),
    );
    assert_eq!(n, frames);
    println!("weights vs truth: RMS {rms:.4} over {frames} frames");
    assert!(rms < 0.05, "weight RMS {rms}");
    let (header, rows) = csv(&out.join("rig_weights.csv"));
    assert_eq!(header.last().unwrap(), "residual_mm");
    assert_eq!(header[..2], ["frame", "timecode"]);
    for r in &rows {
        let res: f64 = r.last().unwrap().parse().unwrap();
        assert!((0.0..2.0).contains(&res), "residual {res}");
    }
    let (ll_header, ll_rows) = csv(&out.join("livelink.csv"));
    assert_eq!(ll_header.len(), 63);
    assert_eq!(ll_rows.len(), frames);

    // The same meshes in metres, read as millimetres: refused with the cause.
    let metres = dir.path().join("metres");
    std::fs::create_dir_all(&metres).unwrap();
    let src = std::fs::read_to_string(session.join("gt/mesh/frame_000000.obj")).unwrap();
    let scaled: String = src
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(rest) => {
                let v: Vec<f64> = rest
                    .split_whitespace()
                    .map(|x| x.parse().unwrap())
                    .collect();
                format!("v {} {} {}\n", v[0] / 1000.0, v[1] / 1000.0, v[2] / 1000.0)
            }
            None => format!("{l}\n"),
        })
        .collect();
    std::fs::write(metres.join("frame_000000.obj"), scaled).unwrap();
    let o = helmcap(&[
        "animate",
        "--rig",
        "builtin",
        "--input",
        metres.to_str().unwrap(),
        "--out",
        dir.path().join("x").to_str().unwrap(),
        "--no-cache",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && !err.contains("panicked"), "{err}");
    assert!(
        err.contains("--units m") && err.contains("(frame 0)"),
        "{err}"
    );
    // Stating the unit makes it work.
    ok(&helmcap(&[
        "animate",
        "--rig",
        "builtin",
        "--input",
        metres.to_str().unwrap(),
        "--units",
        "m",
        "--out",
        dir.path().join("y").to_str().unwrap(),
        "--no-cache",
    ]));
}

/// `replay --rig builtin --export livelink-csv`: rig weights from the pipeline's own
/// meshes (LGI on triangulated bundles) within 0.1 RMS of the truth; the Live Link CSV
/// has exactly Apple's 52 curves plus the fixed columns, one row per frame, timecodes
/// matching frames.csv.
#[test]
fn replay_writes_rig_weights_and_livelink_csv() {
    let dir = tempfile::tempdir().unwrap();
    let frames = 16;
    let session = synth(dir.path(), frames);
    let out = dir.path().join("out");
    ok(&helmcap(&[
        "replay",
        session.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        dir.path().join("cache").to_str().unwrap(),
        "--quiet",
        "--rig",
        "builtin",
        "--export",
        "livelink-csv",
    ]));
    let (rms, n) = weight_rms(
        &out.join("rig_weights.csv"),
        &session.join("gt/weights.csv"),
    );
    println!("pipeline weights vs truth: RMS {rms:.4} over {n} frames");
    assert_eq!(n, frames);
    // The pipeline's meshes (LGI from triangulated bundles) are within ~0.4 mm of the
    // true surface (README, accuracy benchmark); on the small shapes (brows, cheeks,
    // nose: 2–5 mm of motion at full weight) that is a weight error of 0.05–0.1, so the
    // bound here is 0.1 (measured: 0.063 on this take). On the true meshes the bound is
    // the issue's 0.05 (`animate_recovers_the_actors_weights`).
    assert!(rms < 0.1, "weight RMS {rms}");
    // The weights are solved in a pipeline stage of their own (timed as `rig`), not on the
    // sinks' thread.
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("metrics.json")).unwrap()).unwrap();
    let rig_ms = &metrics["latency_ms"]["rig"];
    assert!(
        rig_ms["mean"].as_f64().is_some_and(|ms| ms > 0.0),
        "no rig stage in {}",
        metrics["latency_ms"]
    );

    let (header, rows) = csv(&out.join("livelink.csv"));
    let arkit = helmcap::animation::ARKIT_NAMES;
    assert_eq!(header.len(), 2 + 52 + 9);
    assert_eq!(header[..2], ["Timecode", "BlendShapeCount"]);
    for (h, a) in header[2..54].iter().zip(arkit) {
        assert!(h.eq_ignore_ascii_case(a) && h[1..] == a[1..], "{h} vs {a}");
    }
    assert_eq!(
        header[54..],
        [
            "HeadYaw",
            "HeadPitch",
            "HeadRoll",
            "LeftEyeYaw",
            "LeftEyePitch",
            "LeftEyeRoll",
            "RightEyeYaw",
            "RightEyePitch",
            "RightEyeRoll"
        ]
    );
    assert_eq!(rows.len(), frames);
    let (_, session_frames) = csv(&session.join("frames.csv"));
    for (r, f) in rows.iter().zip(&session_frames) {
        assert_eq!(r.len(), header.len());
        assert_eq!(r[1], "61");
        // frames.csv: 01:00:00:00.0 (60 fps cameras on 30 fps code, sub-frame .0/.1);
        // Live Link: HH:MM:SS:FF.mmm with the sub-frame as thousandths.
        let (label, sub) = f[2].split_once('.').unwrap_or((&f[2], "0"));
        let frac = if sub == "1" { "500" } else { "000" };
        assert_eq!(r[0], format!("{label}.{frac}"), "frame {}", f[0]);
        for v in &r[2..54] {
            let v: f64 = v.parse().unwrap();
            assert!((0.0..=1.0).contains(&v));
        }
    }
    // Head angles: the slip-free synthetic helmet keeps them near 0.
    for r in &rows {
        let yaw: f64 = r[54].parse().unwrap();
        assert!(yaw.abs() < 0.05, "yaw {yaw}");
    }
}

/// The ICT-FaceKit rig on held-out combinations of its own shapes (not in the fit's
/// data): weights recovered within 0.05 RMS.
#[test]
fn ict_rig_recovers_held_out_combinations() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ict-facekit");
    if !root.join("generic_neutral_mesh.obj").exists() {
        println!("skipping: no ICT-FaceKit data at {}", root.display());
        return;
    }
    use helmcap::animation::{RigSolveParams, RigSolver};
    use helmcap::dataset::{LoadOptions, load_dataset};
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/datasets/ict-facekit.toml");
    let ds = load_dataset(
        &manifest,
        &LoadOptions {
            cache_dir: None,
            no_cache: true,
            progress: false,
        },
    )
    .unwrap();
    let mut solver = RigSolver::new(&ds, &RigSolveParams::default()).unwrap();
    let n = ds.shapes.len();
    let mut rng = helmcap::numeric::SplitMix64::new(12345);
    let mut rand = || rng.next_f64();
    let (mut sq, mut count) = (0.0, 0);
    for _ in 0..6 {
        // A combination of 6 random shapes at random weights.
        let mut truth = vec![0.0; n];
        for _ in 0..6 {
            let i = (rand() * n as f64) as usize % n;
            truth[i] = 0.2 + 0.8 * rand();
        }
        let mesh = solver.evaluate(&truth);
        solver.reset();
        let fit = solver.solve(&mesh).unwrap();
        assert!(fit.residual_mm < 0.05, "residual {} mm", fit.residual_mm);
        for (a, b) in fit.weights.iter().zip(&truth) {
            sq += (a - b).powi(2);
            count += 1;
        }
    }
    let rms = (sq / count as f64).sqrt();
    println!("ICT held-out combinations: weight RMS {rms:.5}");
    assert!(rms < 0.05, "{rms}");
}

/// A synthetic take of `frames` frames animated with the built-in rig into `<dir>/anim`
/// with `--export usd-skel`; returns that folder.
fn animate_usd_skel(dir: &Path, frames: usize) -> PathBuf {
    let session = synth(dir, frames);
    let out = dir.join("anim");
    ok(&helmcap(&[
        "animate",
        "--rig",
        "builtin",
        "--input",
        session.join("gt/mesh").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--export",
        "usd-skel",
        "--no-cache",
    ]));
    out
}

/// `face_skel.usda`: no errors from USD's validators, and UsdSkel's baked points at
/// every frame equal the rig evaluated at that frame's weights within 1e-4 mm.
#[test]
fn usd_skel_bakes_to_the_rig() {
    let dir = tempfile::tempdir().unwrap();
    let frames = 6;
    let out = animate_usd_skel(dir.path(), frames);
    let usd = out.join("face_skel.usda");
    assert!(usd.exists());
    let py = match python_with("pxr") {
        Ok(p) => p,
        Err(why) => {
            println!("skipping the UsdSkel check: {why}");
            return;
        }
    };
    let baked = dir.path().join("baked.txt");
    let script = format!(
        r#"
from pxr import Usd, UsdSkel, UsdGeom, Gf
stage = Usd.Stage.Open({usd:?})
assert stage.GetFramesPerSecond() == stage.GetTimeCodesPerSecond() == 60
errors = []
try:
    from pxr import UsdValidation
    reg = UsdValidation.ValidationRegistry()
    ctx = UsdValidation.ValidationContext(reg.GetOrLoadAllValidators())
    for e in ctx.Validate(stage):
        if e.GetType() == UsdValidation.ValidationErrorType.Error:
            errors.append(e.GetMessage())
    print("validators ran")
except ImportError:
    print("no UsdValidation module")
assert not errors, errors
root = UsdSkel.Root(stage.GetPrimAtPath("/Face"))
assert root
mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Face/face"))
binding = UsdSkel.BindingAPI(mesh.GetPrim())
assert len(binding.GetBlendShapeTargetsRel().GetTargets()) == 36
assert UsdSkel.BakeSkinning(root, Gf.Interval(0, {last}))
with open({baked:?}, "w") as f:
    for t in range({frames}):
        pts = mesh.GetPointsAttr().Get(t)
        f.write(" ".join("%.9g %.9g %.9g" % (p[0], p[1], p[2]) for p in pts) + "\n")
print("baked")
"#,
        usd = usd.to_str().unwrap(),
        baked = baked.to_str().unwrap(),
        last = frames - 1,
    );
    let o = Command::new(&py).args(["-c", &script]).output().unwrap();
    assert!(
        o.status.success(),
        "pxr: {}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    println!("{}", String::from_utf8_lossy(&o.stdout));
    use helmcap::animation::{RigSolveParams, RigSolver};
    use helmcap::dataset::actor::{Actor, ActorParams};
    let ds = Actor::new(&ActorParams::default()).unwrap().to_dataset();
    let solver = RigSolver::new(&ds, &RigSolveParams::default()).unwrap();
    let weights = weights_by_frame(&out.join("rig_weights.csv"));
    let text = std::fs::read_to_string(&baked).unwrap();
    let mut worst: f64 = 0.0;
    for (t, line) in text.lines().enumerate() {
        let w: Vec<f64> = solver.names().iter().map(|n| weights[&t][n]).collect();
        let expected = solver.evaluate(&w);
        let got: Vec<f64> = line.split(' ').map(|x| x.parse().unwrap()).collect();
        assert_eq!(got.len(), 3 * expected.len());
        for (p, g) in expected.iter().zip(got.chunks_exact(3)) {
            for k in 0..3 {
                worst = worst.max((p[k] - g[k]).abs());
            }
        }
    }
    println!("UsdSkel baked points vs rig: worst {worst:e} mm");
    // rig_weights.csv has 6 decimals (5e-7 per weight, a few µm on the largest shapes)
    // and USD stores f32: 1e-4 mm holds with margin.
    assert!(worst < 1e-4, "worst {worst} mm");
}

/// Blender (its `bpy` module) imports `face_skel.usda` as a mesh with one shape key per
/// rig shape whose animated values are the frame's weights (rig_weights.csv, within f32
/// rounding), and the head pose as an animated transform (a transform cache) on the root.
#[test]
fn blender_imports_usd_skel_with_shape_keys_and_animation() {
    let py = match blender_python() {
        Ok(p) => p,
        Err(why) => {
            println!("skipping the Blender check: {why}");
            return;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let frames = 6;
    let out = animate_usd_skel(dir.path(), frames);
    let values = dir.path().join("blender.txt");
    let script = format!(
        r#"
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
assert bpy.ops.wm.usd_import(filepath={usd:?}) == {{"FINISHED"}}
meshes = [o for o in bpy.data.objects if o.type == "MESH"]
assert len(meshes) == 1, meshes
keys = meshes[0].data.shape_keys
assert keys is not None and keys.animation_data and keys.animation_data.action
root = meshes[0].parent
while root.parent:
    root = root.parent
assert any(c.type == "TRANSFORM_CACHE" for c in root.constraints), root.constraints
scene = bpy.context.scene
with open({values:?}, "w") as f:
    for t in range({frames}):
        scene.frame_set(t)
        f.write(" ".join("%s=%.9g" % (b.name, b.value) for b in keys.key_blocks[1:]) + "\n")
"#,
        usd = out.join("face_skel.usda").to_str().unwrap(),
        values = values.to_str().unwrap(),
    );
    let o = Command::new(&py).args(["-c", &script]).output().unwrap();
    assert!(
        o.status.success(),
        "Blender: {}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let weights = weights_by_frame(&out.join("rig_weights.csv"));
    let text = std::fs::read_to_string(&values).unwrap();
    let mut worst: f64 = 0.0;
    for (t, line) in text.lines().enumerate() {
        let keys: Vec<(&str, f64)> = line
            .split(' ')
            .map(|kv| {
                let (k, v) = kv.split_once('=').unwrap();
                (k, v.parse().unwrap())
            })
            .collect();
        assert_eq!(
            keys.len(),
            weights[&t].len(),
            "frame {t}: shape keys {keys:?}"
        );
        for (name, value) in keys {
            worst = worst.max((value - weights[&t][name]).abs());
        }
    }
    assert_eq!(text.lines().count(), frames);
    println!("Blender shape-key values vs rig_weights.csv: worst {worst:e}");
    assert!(worst < 1e-6, "worst {worst}");
}

/// `replay --livelink 127.0.0.1:PORT`: pylivelinkface (an independent decoder of the Live
/// Link Face UDP format) decodes every packet: subject, frame numbers (the take's
/// timecode frames), curve values (those of livelink.csv).
#[test]
fn livelink_udp_decodes_with_pylivelinkface() {
    use std::io::{BufRead, BufReader};
    let py = match python_with("pylivelinkface") {
        Ok(p) => p,
        Err(why) => {
            println!("skipping the Live Link UDP check: {why}");
            return;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let frames = 8;
    let session = synth(dir.path(), frames);
    let decoded = dir.path().join("decoded.txt");
    let script = format!(
        r#"
import socket, sys
from pylivelinkface import PyLiveLinkFace
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
s.settimeout(60)
print(s.getsockname()[1], flush=True)
with open({decoded:?}, "w") as f:
    for _ in range({frames}):
        data, _ = s.recvfrom(4096)
        ok, face = PyLiveLinkFace.decode(data)
        assert ok
        f.write("%s %d %s\n" % (face.name, face._frames, " ".join("%.7g" % v for v in face._blend_shapes)))
"#,
        decoded = decoded.to_str().unwrap(),
    );
    let mut receiver = Command::new(&py)
        .args(["-c", &script])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut port = String::new();
    BufReader::new(receiver.stdout.take().unwrap())
        .read_line(&mut port)
        .unwrap();
    let target = format!("127.0.0.1:{}", port.trim());
    let out = dir.path().join("out");
    ok(&helmcap(&[
        "replay",
        session.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        dir.path().join("cache").to_str().unwrap(),
        "--quiet",
        "--rig",
        "builtin",
        "--export",
        "livelink-csv",
        "--livelink",
        &target,
    ]));
    let status = receiver.wait_with_output().unwrap();
    assert!(
        status.status.success(),
        "receiver: {}",
        String::from_utf8_lossy(&status.stderr)
    );
    let (_, csv_rows) = csv(&out.join("livelink.csv"));
    let (_, session_frames) = csv(&session.join("frames.csv"));
    let text = std::fs::read_to_string(&decoded).unwrap();
    let packets: Vec<&str> = text.lines().collect();
    assert_eq!(packets.len(), frames);
    for ((p, row), sf) in packets.iter().zip(&csv_rows).zip(&session_frames) {
        let f: Vec<&str> = p.split(' ').collect();
        assert_eq!(f[0], "helmcap");
        // Timecode frames since midnight at 30 fps: HH:MM:SS:FF of frames.csv.
        let label = sf[2].split('.').next().unwrap();
        let t: Vec<u64> = label.split(':').map(|x| x.parse().unwrap()).collect();
        let expected = ((t[0] * 60 + t[1]) * 60 + t[2]) * 30 + t[3];
        assert_eq!(f[1].parse::<u64>().unwrap(), expected, "{p}");
        let values: Vec<f64> = f[2..].iter().map(|x| x.parse().unwrap()).collect();
        assert_eq!(values.len(), 61);
        for (v, c) in values.iter().zip(&row[2..54]) {
            let c: f64 = c.parse().unwrap();
            assert!((v - c).abs() < 1e-6, "{v} vs {c}");
        }
    }
}
