//! C3D marker files as bundles input (issue 18): helmcap's own `bundles.c3d` solves to the
//! same meshes as `bundles.csv`; a C3D from a peer writer (python-c3d) with float and
//! integer scale, cm units and missing points reads correctly; a file with no layout
//! marker is one clear error naming the file and saying "C3D".

#![allow(clippy::unwrap_used)]

use std::path::Path;
use std::process::{Command, Output};

use helmcap::bundles::{LabelMap, read_bundles, read_bundles_with};
use helmcap::dataset::actor::{Actor, ActorParams};
use helmcap::dataset::markers::{LayoutParams, generate_layout};
use helmcap::frame_index::FrameIndex;
use helmcap::mesh::read_obj_positions;
use nalgebra::Point3;

mod common;
use common::{helmcap, helmcap_cached, ok, python_with};

fn solve(bundles: &Path, markers: &Path, out: &Path, cache: &Path) -> Output {
    helmcap_cached(
        &[
            "solve",
            "--dataset",
            "builtin",
            "--markers",
            markers.to_str().unwrap(),
            "--bundles",
            bundles.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        cache,
    )
}

/// helmcap's own `bundles.c3d` (from a replay) read back gives the same meshes as
/// `bundles.csv`: same frames, same markers present, positions equal to float precision.
#[test]
fn own_c3d_solves_like_the_csv() {
    let dir = tempfile::tempdir().unwrap();
    let session = dir.path().join("session");
    ok(&helmcap(&[
        "synth",
        "--out",
        session.to_str().unwrap(),
        "-n",
        "8",
    ]));
    let out = dir.path().join("out");
    ok(&helmcap(&[
        "replay",
        session.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--cache-dir",
        dir.path().join("cache").to_str().unwrap(),
        "--quiet",
        "--export",
        "c3d",
    ]));
    let actor = Actor::new(&ActorParams::default()).unwrap();
    let layout = generate_layout(&actor.to_dataset(), &LayoutParams::default()).unwrap();
    let markers = dir.path().join("markers.csv");
    layout.write_csv(&markers).unwrap();
    let (from_csv, _) = read_bundles(&out.join("bundles.csv"), &layout).unwrap();
    let (from_c3d, report) = read_bundles(&out.join("bundles.c3d"), &layout).unwrap();
    let info = report.c3d.expect("read as C3D");
    assert_eq!((info.rate_hz, info.units.as_str()), (60.0, "mm"));
    assert_eq!(from_csv.len(), from_c3d.len());
    for (a, b) in from_csv.iter().zip(&from_c3d) {
        assert_eq!(a.frame, b.frame);
        for (p, q) in a.positions.iter().zip(&b.positions) {
            match (p, q) {
                (Some(p), Some(q)) => assert!((p - q).norm() < 1e-3, "{p} vs {q}"),
                (None, None) => {}
                _ => panic!("frame {}: presence differs", a.frame),
            }
        }
    }
    // The solve command on the C3D writes the meshes it writes for the same bundles as a
    // CSV (the C3D's float32 coordinates written out: identical input, identical
    // output), and, against the original f64 CSV, meshes that differ by LGI's response
    // to a 1e-5 mm perturbation only (a different tetrahedron can win a tie: well under
    // the method's 0.4 mm accuracy).
    let cache = dir.path().join("cache");
    let f32_csv = dir.path().join("bundles_f32.csv");
    helmcap::bundles::write_bundles(&f32_csv, &layout, &from_c3d).unwrap();
    for (file, o) in [
        (out.join("bundles.csv"), "m_csv"),
        (out.join("bundles.c3d"), "m_c3d"),
        (f32_csv, "m_f32"),
    ] {
        ok(&solve(&file, &markers, &dir.path().join(o), &cache));
    }
    let worst = |a: &str, b: &str, frame: FrameIndex| -> f64 {
        let name = format!("frame_{frame:06}.obj");
        let a = read_obj_positions(&dir.path().join(a).join(&name)).unwrap();
        let b = read_obj_positions(&dir.path().join(b).join(&name)).unwrap();
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(&b)
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max)
    };
    for f in &from_csv {
        let same = worst("m_c3d", "m_f32", f.frame);
        assert!(
            same < 1e-9,
            "frame {}: C3D and CSV of the same bundles differ by {same} mm",
            f.frame
        );
        let near = worst("m_c3d", "m_csv", f.frame);
        println!(
            "frame {}: C3D vs f64 CSV meshes: worst vertex {near:.4} mm",
            f.frame
        );
        assert!(near < 0.5, "frame {}: meshes differ by {near} mm", f.frame);
    }
}

/// Writes a C3D with python-c3d: `points[frame][marker]` in mm (None: missing), written
/// in `units` with `scale` (negative: float data).
fn write_peer_c3d(
    py: &Path,
    path: &Path,
    labels: &[String],
    points: &[Vec<Option<Point3<f64>>>],
    units: &str,
    scale: f64,
    first_frame: usize,
) {
    let per_unit = match units {
        "mm" => 1.0,
        "cm" => 10.0,
        _ => 1000.0,
    };
    let frames: Vec<String> = points
        .iter()
        .map(|f| {
            let rows: Vec<String> = f
                .iter()
                .map(|p| match p {
                    Some(p) => format!(
                        "[{},{},{},0.0,3]",
                        p.x / per_unit,
                        p.y / per_unit,
                        p.z / per_unit
                    ),
                    None => "[0,0,0,-1.0,0]".into(),
                })
                .collect();
            format!("[{}]", rows.join(","))
        })
        .collect();
    let script = format!(
        r#"
import c3d, numpy as np
w = c3d.Writer(point_rate=120.0, analog_rate=0.0, point_scale={scale}, point_units="{units:<4}")
w.set_point_labels({labels:?})
w.set_start_frame({first_frame})
frames = [{frames}]
for f in frames:
    w.add_frames([(np.array(f, dtype=np.float64), np.zeros((0, 0)))])
with open({path:?}, "wb") as h:
    w.write(h)
"#,
        frames = frames.join(","),
        path = path.to_str().unwrap(),
    );
    let o = Command::new(py).args(["-c", &script]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A peer writer's C3D (python-c3d): float and integer scale, mm and cm, missing
/// points, extra non-layout points, renamed labels through a label map.
#[test]
fn peer_c3d_reads_correctly() {
    let py = match python_with("c3d, numpy") {
        Ok(p) => p,
        Err(why) => {
            println!("skipping the peer C3D check: {why}");
            return;
        }
    };
    let dir = tempfile::tempdir().unwrap();
    let actor = Actor::new(&ActorParams::default()).unwrap();
    let layout = generate_layout(&actor.to_dataset(), &LayoutParams::default()).unwrap();
    let n = actor.expression_names().len();
    let truth: Vec<Vec<Option<Point3<f64>>>> = (0..4)
        .map(|f| {
            let mut w = vec![0.0; n];
            w[actor.expression_index("jawOpen").unwrap()] = 0.2 * f as f64;
            let p = actor.evaluate(&w).positions;
            layout
                .markers
                .iter()
                .enumerate()
                .map(|(i, m)| (i % 7 != f).then_some(p[m.vertex as usize]))
                .collect()
        })
        .collect();
    // Two points the layout does not have, and the first marker under another name.
    let mut labels: Vec<String> = layout.markers.iter().map(|m| m.name.clone()).collect();
    labels[0] = "Actor:FOREHEAD_A".into();
    labels.extend(["HELMET1".to_string(), "HELMET2".to_string()]);
    let with_extra: Vec<Vec<Option<Point3<f64>>>> = truth
        .iter()
        .map(|f| {
            let mut f = f.clone();
            f.extend([Some(Point3::new(1.0, 2.0, 3.0)), None]);
            f
        })
        .collect();
    let map = LabelMap::new([("FOREHEAD_A".to_string(), layout.markers[0].name.clone())]);
    // (units, scale, tolerance in mm): integer data is quantized to the scale.
    for (units, scale, tol) in [
        ("mm", -1.0, 1e-4),
        ("cm", -1.0, 1e-5),
        ("mm", 0.05, 0.05),
        ("cm", 0.01, 0.1),
        ("m", -1.0, 1e-3),
    ] {
        let path = dir.path().join(format!("peer_{units}_{scale}.c3d"));
        write_peer_c3d(&py, &path, &labels, &with_extra, units, scale, 11);
        let what = format!("{units} scale {scale}");
        let (frames, report) =
            read_bundles_with(&path, &layout, Some(&map)).unwrap_or_else(|e| panic!("{what}: {e}"));
        let info = report.c3d.as_ref().unwrap();
        assert_eq!(info.rate_hz, 120.0, "{what}");
        assert_eq!(info.float_data, scale < 0.0, "{what}");
        assert_eq!(report.unknown_markers.get("HELMET1"), Some(&4), "{what}");
        assert!(!report.unknown_markers.contains_key("HELMET2"), "{what}");
        assert_eq!(frames.len(), truth.len(), "{what}");
        for (f, (got, want)) in frames.iter().zip(&truth).enumerate() {
            // C3D frame 11 is bundles frame 10.
            assert_eq!(got.frame, FrameIndex::new(10 + f as u64), "{what}");
            for (m, (g, w)) in got.positions.iter().zip(want).enumerate() {
                match (g, w) {
                    (Some(g), Some(w)) => {
                        let d = (g - w).abs().max();
                        assert!(d <= tol, "{what}: frame {f} marker {m} off by {d} mm");
                    }
                    (None, None) => {}
                    _ => panic!("{what}: frame {f} marker {m}: presence {g:?} vs {w:?}"),
                }
            }
        }
    }

    // Through the binary: solve reads the cm file with the label map.
    let markers = dir.path().join("markers.csv");
    layout.write_csv(&markers).unwrap();
    let map_csv = dir.path().join("labels.csv");
    std::fs::write(
        &map_csv,
        format!("c3d_label,marker\nFOREHEAD_A,{}\n", layout.markers[0].name),
    )
    .unwrap();
    let out = dir.path().join("solved");
    let o = helmcap_cached(
        &[
            "solve",
            "--dataset",
            "builtin",
            "--markers",
            markers.to_str().unwrap(),
            "--bundles",
            dir.path().join("peer_cm_0.01.c3d").to_str().unwrap(),
            "--label-map",
            map_csv.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        &dir.path().join("cache"),
    );
    ok(&o);
    assert!(out.join("frame_000013.obj").exists());

    // No layout marker at all: one clear error naming the file and saying C3D.
    let bad = dir.path().join("helmet_only.c3d");
    let other: Vec<String> = (0..3).map(|i| format!("HELMET{i}")).collect();
    let pts = vec![vec![Some(Point3::new(1.0, 2.0, 3.0)); 3]; 2];
    write_peer_c3d(&py, &bad, &other, &pts, "mm", -1.0, 1);
    let o = solve(
        &bad,
        &markers,
        &dir.path().join("x"),
        &dir.path().join("cache"),
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && !err.contains("panicked"), "{err}");
    assert!(
        err.contains("helmet_only.c3d") && err.contains("C3D") && err.contains("--label-map"),
        "{err}"
    );
}

/// Binary garbage that is neither CSV nor C3D, and a truncated C3D: one error line each.
#[test]
fn broken_marker_files_are_one_error() {
    let dir = tempfile::tempdir().unwrap();
    let actor = Actor::new(&ActorParams::default()).unwrap();
    let layout = generate_layout(&actor.to_dataset(), &LayoutParams::default()).unwrap();
    let junk = dir.path().join("junk.bin");
    std::fs::write(&junk, [0xffu8, 0xfe, 0x00, 0x12, 0x80]).unwrap();
    let e = read_bundles(&junk, &layout).unwrap_err().to_string();
    assert!(e.contains("junk.bin") && e.contains("C3D"), "{e}");
    // A C3D header whose parameter section is missing.
    let mut truncated = vec![0u8; 512];
    truncated[0] = 2;
    truncated[1] = 0x50;
    let t = dir.path().join("truncated.c3d");
    std::fs::write(&t, &truncated).unwrap();
    let e = read_bundles(&t, &layout).unwrap_err().to_string();
    assert!(e.contains("truncated.c3d") && e.contains("C3D"), "{e}");
}
