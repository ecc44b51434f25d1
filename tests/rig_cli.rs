//! `helmcap rig build` end to end on built-in actors: the template is one identity, the
//! actor's neutral and example poses come from another.

#![allow(clippy::unwrap_used)]

use helmcap::dataset::actor::{Actor, ActorParams};
use helmcap::dataset::{LoadOptions, load_dataset};
use helmcap::mesh::write_obj_positions;

mod common;
use common::helmcap;

#[test]
fn rig_build_writes_a_dataset_that_reproduces_the_examples() {
    let dir = tempfile::tempdir().unwrap();
    let actor = Actor::new(&ActorParams::from_seed(12)).unwrap();
    let neutral = dir.path().join("b0.obj");
    write_obj_positions(&neutral, actor.neutral(), &actor.neutral().positions).unwrap();
    let poses: [(&str, &[(&str, f64)]); 2] = [
        ("smile", &[("mouthSmile_L", 1.0), ("mouthSmile_R", 1.0)]),
        ("open", &[("jawOpen", 0.8), ("mouthFunnel", 0.5)]),
    ];
    let mut toml = String::from("exclusive = [[\"mouthLeft\", \"mouthRight\"]]\n");
    for (name, w) in poses {
        let p = actor.evaluate(&actor.weights(w)).positions;
        write_obj_positions(&dir.path().join(format!("{name}.obj")), actor.neutral(), &p).unwrap();
        let weights: Vec<String> = w
            .iter()
            .map(|(n, x)| format!("{n} = {}", x * 0.8))
            .collect();
        toml += &format!(
            "\n[[example]]\nfile = \"{name}.obj\"\nweights = {{ {} }}\n",
            weights.join(", ")
        );
    }
    let examples = dir.path().join("examples.toml");
    std::fs::write(&examples, &toml).unwrap();
    let out_dir = dir.path().join("rig");
    let out = helmcap(&[
        "rig",
        "build",
        "--template",
        "builtin:11",
        "--neutral",
        neutral.to_str().unwrap(),
        "--examples",
        examples.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
        "--alternations",
        "3",
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    // Fit per example and alternation is printed.
    assert!(stdout.contains("alternation 3/3"), "{stdout}");
    assert!(
        stdout.contains("smile") && stdout.contains("rms"),
        "{stdout}"
    );
    let rig = load_dataset(
        &out_dir.join("manifest.toml"),
        &LoadOptions {
            no_cache: true,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(rig.shapes.len(), actor.expression_names().len());
    assert_eq!(rig.neutral.positions, actor.neutral().positions);
    let weights = std::fs::read_to_string(out_dir.join("example_weights.csv")).unwrap();
    assert_eq!(weights.lines().count(), 3);
    // The rig's smile shapes reproduce the smile example within a millimetre RMS.
    let smile = actor.evaluate(&actor.weights(poses[0].1)).positions;
    let l = rig.shape_index("mouthSmile_L").unwrap();
    let r = rig.shape_index("mouthSmile_R").unwrap();
    let row: Vec<f64> = weights
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .skip(1)
        .map(|x| x.parse().unwrap())
        .collect();
    let sq: f64 = smile
        .iter()
        .enumerate()
        .map(|(v, s)| {
            let b0 = rig.neutral.positions[v];
            let p = b0
                + (rig.shapes[l].positions[v] - b0) * row[l]
                + (rig.shapes[r].positions[v] - b0) * row[r];
            (p - s).norm_squared()
        })
        .sum();
    let rms = (sq / smile.len() as f64).sqrt();
    println!("smile reproduced with {rms:.3} mm RMS from the two smile shapes");
    assert!(rms < 1.0, "{rms}");

    // Bad input: an unknown shape name is one clear error line.
    std::fs::write(
        &examples,
        "[[example]]\nfile = \"smile.obj\"\nweights = { smileBig = 1.0 }\n",
    )
    .unwrap();
    let out = helmcap(&[
        "rig",
        "build",
        "--template",
        "builtin:11",
        "--neutral",
        neutral.to_str().unwrap(),
        "--examples",
        examples.to_str().unwrap(),
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("smileBig"), "{stderr}");
}

#[test]
fn rig_from_lgi_writes_blendshapes_and_combinations() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("lgi-rig");
    let out = helmcap(&[
        "rig",
        "from-lgi",
        "--template",
        "builtin:11",
        "--dataset",
        "builtin:12",
        "--combinations",
        "mouthSmile_L+mouthSmile_R,jawOpen*0.5+mouthFunnel",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let rig = load_dataset(
        &out_dir.join("manifest.toml"),
        &LoadOptions {
            no_cache: true,
            ..Default::default()
        },
    )
    .unwrap();
    let actor = Actor::new(&ActorParams::from_seed(12)).unwrap();
    assert_eq!(rig.shapes.len(), actor.expression_names().len() + 2);
    assert!(rig.shape_index("mouthSmile_L+mouthSmile_R").is_some());
    assert!(rig.shape_index("jawOpen_w0.5+mouthFunnel").is_some());
    // The smile blendshape lands near the actor's true smile (LGI from its own shapes).
    let i = rig.shape_index("mouthSmile_L").unwrap();
    let truth = &actor.to_dataset().shapes[i].positions;
    let face = actor.face_vertex_count();
    let rms = (rig.shapes[i].positions[..face]
        .iter()
        .zip(&truth[..face])
        .map(|(a, b)| (a - b).norm_squared())
        .sum::<f64>()
        / face as f64)
        .sqrt();
    println!("from-lgi smile: {rms:.3} mm RMS from the truth");
    assert!(rms < 0.5, "{rms}");
    let bad = helmcap(&[
        "rig",
        "from-lgi",
        "--template",
        "builtin:11",
        "--dataset",
        "builtin:12",
        "--combinations",
        "nope+mouthFunnel",
        "--out",
        out_dir.to_str().unwrap(),
    ]);
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("nope"));
}
