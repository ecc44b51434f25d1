//! Drives `helmcap solve` on the built-in actor: every method writes one mesh per frame
//! that passes through the bundles (LGI, RBF), and bad input gets one clear error line.

use std::path::Path;

use helmcap::bundles::{FrameBundles, write_bundles};
use helmcap::dataset::actor::{Actor, ActorParams};
use helmcap::dataset::markers::{LayoutParams, generate_layout};
use helmcap::mesh::read_obj_positions;

mod common;
use common::helmcap_cached;

#[test]
fn solve_writes_frames_through_the_bundles() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let actor = Actor::new(&ActorParams::default()).unwrap();
    let ds = actor.to_dataset();
    let layout = generate_layout(&ds, &LayoutParams::default()).unwrap();
    let markers = dir.join("markers.csv");
    layout.write_csv(&markers).unwrap();
    let n = actor.expression_names().len();
    let frames: Vec<FrameBundles> = (0..3)
        .map(|f| {
            let mut w = vec![0.0; n];
            w[actor.expression_index("jawOpen").unwrap()] = 0.2 * f as f64;
            w[actor.expression_index("mouthSmile_R").unwrap()] = 0.5;
            let p = actor.evaluate(&w).positions;
            let mut b = FrameBundles::full(
                helmcap::frame_index::FrameIndex::new(10 + f),
                &layout
                    .markers
                    .iter()
                    .map(|m| p[m.vertex as usize])
                    .collect::<Vec<_>>(),
            );
            if f == 1 {
                b.positions[4] = None;
            }
            b
        })
        .collect();
    let bundles = dir.join("bundles.csv");
    write_bundles(&bundles, &layout, &frames).unwrap();
    let cache = dir.join("cache");
    for (method, format) in [("lgi", "obj"), ("rbf", "obj"), ("blendshape", "ply")] {
        let out = dir.join(method);
        let o = helmcap_cached(
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
                "--method",
                method,
                "--format",
                format,
            ],
            &cache,
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{method}: {err}");
        assert!(String::from_utf8_lossy(&o.stdout).contains("wrote 3 frames"));
        for f in &frames {
            let file = out.join(format!("frame_{:06}.{format}", f.frame));
            assert!(file.exists(), "{}", file.display());
            if format == "obj" {
                let p = read_obj_positions(&file).unwrap();
                assert_eq!(p.len(), ds.vertex_count());
                for (m, b) in layout.markers.iter().zip(&f.positions) {
                    if let Some(b) = b {
                        // OBJ text keeps about 1e-6 relative precision.
                        assert!((p[m.vertex as usize] - b).norm() < 1e-3, "{method}");
                    }
                }
            }
        }
    }
    // The second LGI run reads the cached index.
    let out = dir.join("lgi2");
    let o = helmcap_cached(
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
            "--smooth",
            "1",
        ],
        &cache,
    );
    assert!(o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("from cache"));

    // Bad input: one clear error line, no panic.
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, "frame,marker,x,y,z\n0,M001,1,2,3\n0,M001,1,2,3\n").unwrap();
    let o = helmcap_cached(
        &[
            "solve",
            "--dataset",
            "builtin",
            "--markers",
            markers.to_str().unwrap(),
            "--bundles",
            bad.to_str().unwrap(),
            "--out",
            dir.join("x").to_str().unwrap(),
        ],
        &cache,
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && !err.contains("panicked"), "{err}");
    assert!(err.contains("bad.csv:3") && err.contains("twice"), "{err}");
}

/// `dataset build --markers` builds and caches the LGI index, printing its statistics; the
/// next run reads it back.
#[test]
fn dataset_build_caches_the_lgi_index() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let markers = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/markers/builtin-actor.csv");
    let args = [
        "dataset",
        "build",
        "--dataset",
        "builtin",
        "--markers",
        markers.to_str().unwrap(),
    ];
    let o = helmcap_cached(&args, &cache);
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("tetrahedra kept of"), "{out}");
    assert!(out.contains("written to"), "{out}");
    let files: Vec<_> = std::fs::read_dir(&cache)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with("lgi-"))
        .collect();
    assert_eq!(files.len(), 1);
    let o = helmcap_cached(&args, &cache);
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("read from"), "{out}");
    // A layout that does not fit the dataset: one clear error line.
    let bad = tmp.path().join("bad.csv");
    std::fs::write(&bad, "name,vertex,stabilize_weight\nM1,99999999,1\n").unwrap();
    let o = helmcap_cached(
        &[
            "dataset",
            "build",
            "-d",
            "builtin",
            "-k",
            bad.to_str().unwrap(),
        ],
        &cache,
    );
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("error:"));
}
