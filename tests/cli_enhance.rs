//! Drives `helmcap enhance` and `helmcap retime` on the built-in actor.
#![allow(clippy::unwrap_used)]

use std::process::Command;

use helmcap::dataset::actor::{Actor, ActorParams};
use helmcap::mesh::{read_obj_positions, write_obj_positions};

#[test]
fn enhance_and_retime_write_sequences_in_the_database_topology() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in");
    std::fs::create_dir_all(&input).unwrap();
    let flat = Actor::new(&ActorParams {
        wrinkle_depth_scale: 0.0,
        ..ActorParams::default()
    })
    .unwrap();
    let poses = [
        flat.weights(&[]),
        flat.weights(&[("browInnerUp", 0.8), ("mouthSmile_L", 0.5)]),
    ];
    for (i, w) in poses.iter().enumerate() {
        let p = flat.evaluate(w).positions;
        write_obj_positions(&input.join(format!("f{i:03}.obj")), flat.neutral(), &p).unwrap();
    }
    let out = dir.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_helmcap"))
        .args(["enhance", "--database", "builtin", "--input"])
        .arg(&input)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let n = flat.neutral().vertex_count();
    for i in 0..2 {
        let p = read_obj_positions(&out.join(format!("f{i:03}.obj"))).unwrap();
        assert_eq!(p.len(), n);
    }
    let retimed = dir.path().join("retimed");
    let o = Command::new(env!("CARGO_BIN_EXE_helmcap"))
        .args([
            "retime",
            "--database",
            "builtin",
            "--frames",
            "6",
            "--extend",
            "--from",
        ])
        .arg(input.join("f000.obj"))
        .arg("--to")
        .arg(input.join("f001.obj"))
        .arg("--out")
        .arg(&retimed)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read_dir(&retimed).unwrap().count(), 6);
    // Bad input: a frame from another topology is one clear error.
    let o = Command::new(env!("CARGO_BIN_EXE_helmcap"))
        .args([
            "retime",
            "--database",
            "builtin",
            "--frames",
            "1",
            "--from",
            "a.obj",
            "--to",
            "b.obj",
            "--out",
        ])
        .arg(&retimed)
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("--frames"));
}

#[test]
fn enhance_reads_the_usd_our_sink_writes() {
    use helmcap::capture::GrayImage;
    use helmcap::pipeline::{FrameResult, Metrics, SessionMeta, Sink};
    use helmcap::sink::UsdSink;
    use std::sync::Arc;

    let dir = tempfile::tempdir().unwrap();
    let flat = Actor::new(&ActorParams {
        wrinkle_depth_scale: 0.0,
        ..ActorParams::default()
    })
    .unwrap();
    let poses = [
        flat.evaluate(&flat.weights(&[])).positions,
        flat.evaluate(&flat.weights(&[("browInnerUp", 0.8), ("mouthSmile_L", 0.5)]))
            .positions,
    ];
    // The same frames as OBJ files and as one mesh.usda from the USD sink.
    let objs = dir.path().join("objs");
    std::fs::create_dir_all(&objs).unwrap();
    let usda = dir.path().join("take").join("mesh.usda");
    let mut sink = UsdSink::new(&usda);
    sink.begin(&SessionMeta {
        name: "take".into(),
        fps: 60.0,
        timecode_rate: None,
        first_frame: helmcap::frame_index::FrameIndex::new(0),
        frame_count: Some(2),
        layout: Arc::new(Default::default()),
        neutral_markers_head: Arc::new(Vec::new()),
        neutral: Some(Arc::new(flat.neutral().clone())),
        face_vertices: None,
        rig: None,
        image_size: None,
    })
    .unwrap();
    for (i, p) in poses.iter().enumerate() {
        // What the USD file holds: the shortest decimal of each single-precision value.
        let p32: Vec<_> = p
            .iter()
            .map(|q| q.map(|x| format!("{}", x as f32).parse::<f64>().unwrap()))
            .collect();
        write_obj_positions(
            &objs.join(format!("frame_{i:06}.obj")),
            flat.neutral(),
            &p32,
        )
        .unwrap();
        let image = GrayImage {
            width: 1,
            height: 1,
            data: vec![0],
        };
        let mut fr = FrameResult::new(i.into(), 0, None, [image.clone(), image], 0);
        fr.mesh = Some(Arc::new(p.clone()));
        sink.write(&fr).unwrap();
    }
    sink.finish(&Metrics::default()).unwrap();
    let run = |input: &std::path::Path, out: &std::path::Path| {
        Command::new(env!("CARGO_BIN_EXE_helmcap"))
            .args(["enhance", "--database", "builtin", "--input"])
            .arg(input)
            .arg("--out")
            .arg(out)
            .output()
            .unwrap()
    };
    let (from_usd, from_obj) = (dir.path().join("from_usd"), dir.path().join("from_obj"));
    let o = run(&usda, &from_usd);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run(&objs, &from_obj);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for i in 0..2 {
        let name = format!("frame_{i:06}.obj");
        let a = read_obj_positions(&from_usd.join(&name)).unwrap();
        let b = read_obj_positions(&from_obj.join(&name)).unwrap();
        assert_eq!(a.len(), flat.neutral().vertex_count());
        let worst = a
            .iter()
            .zip(&b)
            .map(|(p, q)| (p - q).norm())
            .fold(0.0, f64::max);
        assert!(
            worst < 1e-9,
            "frame {i}: USD and OBJ input differ by {worst} mm"
        );
    }
    // Time samples of differing sizes, and another file type, are one clear error each.
    let text = std::fs::read_to_string(&usda).unwrap();
    let other = dir.path().join("other.usda");
    let first_sample = "points.timeSamples = {\n            0: [";
    assert!(text.contains(first_sample));
    let ragged = text.replace(first_sample, &format!("{first_sample}(1, 2, 3), "));
    std::fs::write(&other, ragged).unwrap();
    let o = run(&other, &dir.path().join("x"));
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("time sample 1 has"), "{err}");
    let o = run(&objs.join("frame_000000.obj"), &dir.path().join("x"));
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("a folder of OBJ files or a .usda file"));
}
