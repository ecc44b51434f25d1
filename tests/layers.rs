//! The layer order of the library holds: every `crate::` path in the code of a module
//! (doc comments aside) names a module of its own layer or one below it, as `src/lib.rs`
//! lists them (its doc lines `//! - [`a`], [`b`]: ...`, bottom up; modules on one line
//! are one layer).

#![allow(clippy::unwrap_used)]

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The layer of each module named in `src/lib.rs`'s docs, bottom up from 0.
fn layers(src: &Path) -> BTreeMap<String, usize> {
    let lib = std::fs::read_to_string(src.join("lib.rs")).unwrap();
    let mut out = BTreeMap::new();
    let mut layer = 0;
    for line in lib.lines().filter_map(|l| l.strip_prefix("//! - ")) {
        let head = line.split(':').next().unwrap_or("");
        let names: Vec<&str> = head
            .split("[`")
            .skip(1)
            .filter_map(|p| p.split("`]").next())
            .collect();
        if names.is_empty() {
            continue;
        }
        for n in names {
            out.insert(n.to_string(), layer);
        }
        layer += 1;
    }
    out
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn no_module_uses_one_above_it() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let layers = layers(&src);
    assert!(
        layers.len() >= 20,
        "src/lib.rs lists only {} modules: {layers:?}",
        layers.len()
    );
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut violations = Vec::new();
    for file in files {
        let rel = file.strip_prefix(&src).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy()
            .trim_end_matches(".rs")
            .to_string();
        // The binary's commands and the crate root sit above every layer.
        let Some(&own) = layers.get(&top) else {
            assert!(
                ["cli", "main", "lib", "name_pairs"].contains(&top.as_str()),
                "{}: module {top} is not in src/lib.rs's list of layers",
                rel.display()
            );
            continue;
        };
        let text = std::fs::read_to_string(&file).unwrap();
        for (n, line) in text.lines().enumerate() {
            let code = line.trim_start();
            if code.starts_with("//") {
                continue;
            }
            for part in code.split("crate::").skip(1) {
                let name: String = part
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                if let Some(&used) = layers.get(&name)
                    && used > own
                {
                    violations.push(format!("{}:{}: {top} uses {name}", rel.display(), n + 1));
                }
            }
        }
    }
    assert!(
        violations.is_empty(),
        "modules using a layer above their own:\n{}",
        violations.join("\n")
    );
}
