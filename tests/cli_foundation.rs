//! Drives the `helmcap` binary: datasets, the built-in actor, marker layouts, bad input.

use std::process::Output;

mod common;
use common::helmcap_cached;

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A failed run: non-zero exit, one `error:` line that contains `expected`, no panic.
fn assert_clean_error(o: &Output, expected: &str) {
    let err = stderr(o);
    assert!(!o.status.success(), "should fail: {err}");
    assert!(!err.contains("panicked"), "panic: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one error line expected, got:\n{err}");
    assert!(lines[0].starts_with("error: "), "{err}");
    assert!(
        lines[0].contains(expected),
        "{err:?} should mention {expected:?}"
    );
}

#[test]
fn every_command_has_help() {
    let tmp = tempfile::tempdir().unwrap();
    for args in [
        vec!["--help"],
        vec!["demo", "--help"],
        vec!["dataset", "info", "--help"],
        vec!["dataset", "build", "--help"],
        vec!["dataset", "synth", "--help"],
        vec!["markers", "generate", "--help"],
        vec!["solve", "--help"],
        vec!["synth", "--help"],
        vec!["calibrate", "--help"],
        vec!["replay", "--help"],
        vec!["live", "--help"],
        vec!["record", "--help"],
        vec!["enhance", "--help"],
        vec!["retime", "--help"],
        vec!["rig", "build", "--help"],
        vec!["rig", "from-lgi", "--help"],
        vec!["register", "--help"],
        vec!["bench", "pipeline", "--help"],
    ] {
        let o = helmcap_cached(&args, tmp.path());
        assert!(o.status.success(), "{args:?}: {}", stderr(&o));
        assert!(stdout(&o).contains("Usage"), "{args:?}");
    }
}

#[test]
fn synth_dataset_info_and_markers() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let ds = tmp.path().join("actor");
    let o = helmcap_cached(&["dataset", "synth", "--out", ds.to_str().unwrap()], &cache);
    assert!(o.status.success(), "{}", stderr(&o));
    let manifest = ds.join("manifest.toml");
    assert!(manifest.is_file());
    assert!(ds.join("jaw_weights.txt").is_file());

    let o = helmcap_cached(
        &["dataset", "info", "--dataset", manifest.to_str().unwrap()],
        &cache,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let out = stdout(&o);
    assert!(out.contains("jawOpen"), "{out}");
    assert!(out.contains("jaw rig      pivot"), "{out}");
    // The first load wrote the cache; the second reads it and says the same.
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 1);
    let again = helmcap_cached(
        &["dataset", "info", "--dataset", manifest.to_str().unwrap()],
        &cache,
    );
    let strip = |s: String| {
        s.lines()
            .filter(|l| !l.starts_with("loaded in"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(strip(stdout(&again)), strip(out));

    let csv = tmp.path().join("markers.csv");
    let o = helmcap_cached(
        &[
            "markers",
            "generate",
            "--dataset",
            manifest.to_str().unwrap(),
            "--count",
            "60",
            "--out",
            csv.to_str().unwrap(),
        ],
        &cache,
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let text = std::fs::read_to_string(&csv).unwrap();
    assert!(text.starts_with("name,vertex,stabilize_weight\n"));
    assert_eq!(text.lines().count(), 61);
}

#[test]
fn builtin_dataset_names_work_everywhere() {
    let tmp = tempfile::tempdir().unwrap();
    let o = helmcap_cached(&["dataset", "info", "--dataset", "builtin:7"], tmp.path());
    assert!(o.status.success(), "{}", stderr(&o));
    let o = helmcap_cached(&["dataset", "info", "--dataset", "builtin:x"], tmp.path());
    assert_clean_error(&o, "seed");
}

#[test]
fn bad_input_gives_one_clear_error_line() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let cache = d.join("cache");
    let missing = d.join("missing.toml");
    assert_clean_error(
        &helmcap_cached(
            &["dataset", "info", "--dataset", missing.to_str().unwrap()],
            &cache,
        ),
        "missing.toml",
    );

    std::fs::write(d.join("bad.obj"), "v 0 0 0\nv 1 0 zero\nv 0 1 0\nf 1 2 3\n").unwrap();
    std::fs::write(
        d.join("bad.toml"),
        "units = \"mm\"\nneutral = \"bad.obj\"\n",
    )
    .unwrap();
    assert_clean_error(
        &helmcap_cached(
            &[
                "dataset",
                "info",
                "--dataset",
                d.join("bad.toml").to_str().unwrap(),
            ],
            &cache,
        ),
        "bad.obj:2",
    );

    std::fs::write(
        d.join("unit.toml"),
        "units = \"furlong\"\nneutral = \"bad.obj\"\n",
    )
    .unwrap();
    assert_clean_error(
        &helmcap_cached(
            &[
                "dataset",
                "info",
                "--dataset",
                d.join("unit.toml").to_str().unwrap(),
            ],
            &cache,
        ),
        "unknown unit",
    );

    let o = helmcap_cached(
        &[
            "markers",
            "generate",
            "--dataset",
            "builtin",
            "--count",
            "100000",
            "--out",
            d.join("m.csv").to_str().unwrap(),
        ],
        &cache,
    );
    assert_clean_error(&o, "paintable");
    assert!(!d.join("m.csv").exists(), "nothing written on failure");
}
