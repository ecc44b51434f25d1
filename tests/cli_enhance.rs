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
