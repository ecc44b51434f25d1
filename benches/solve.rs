//! Accuracy and speed of the solve methods on held-out performances (see
//! `helmcap::bench::solve`; `helmcap bench solve` runs the same from the command line).
//! Run with `cargo bench --bench solve`; prints a Markdown table on stdout and progress on
//! stderr.
//!
//! Environment: `HELMCAP_BENCH_FRAMES` (static frames per condition, default 60),
//! `HELMCAP_BENCH_RUNS` (timed runs per take, median reported, default 5),
//! `HELMCAP_BENCH_ONLY` (comma-separated substrings of the dataset names to run, e.g.
//! `all 53,actor`), `HELMCAP_BENCH_CONDITIONS` (comma-separated substrings of the
//! condition names, e.g. `exact,missing`), `HELMCAP_BENCH_SMOOTH` (half-width of LGI's centred smoothing on the
//! animated take, default 2), `HELMCAP_BENCH_RBF` (`thin_plate` or `biharmonic`: the RBF
//! baseline's kernel), `HELMCAP_BENCH_METHODS` (comma-separated methods to run),
//! `HELMCAP_BENCH_LGI` (LGI parameters as comma-separated TOML assignments).

use std::path::Path;

use helmcap::bench::solve::{BenchConfig, format_table, run_benchmark};
use helmcap::solve::Method;

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut config = BenchConfig::for_repository(root);
    config.frames = env_usize("HELMCAP_BENCH_FRAMES", config.frames);
    config.runs = env_usize("HELMCAP_BENCH_RUNS", config.runs).max(1);
    config.smooth = env_usize("HELMCAP_BENCH_SMOOTH", config.smooth);
    if let Ok(v) = std::env::var("HELMCAP_BENCH_ONLY") {
        config.only = v.split(',').map(|x| x.trim().to_string()).collect();
    }
    if let Ok(v) = std::env::var("HELMCAP_BENCH_CONDITIONS") {
        config.conditions = v.split(',').map(|x| x.trim().to_string()).collect();
    }
    if let Ok(v) = std::env::var("HELMCAP_BENCH_METHODS") {
        config.methods = v
            .split(',')
            .filter_map(|m| m.trim().parse::<Method>().ok())
            .collect();
    }
    if let Ok(v) = std::env::var("HELMCAP_BENCH_LGI") {
        // TOML keys of LgiParams, e.g. "min_tet_quality=0.02,temporal_weight_mm=0.1".
        let text = v.replace(',', "\n");
        config.params.lgi = toml::from_str(&text).expect("HELMCAP_BENCH_LGI: LgiParams TOML keys");
    }
    if let Ok(v) = std::env::var("HELMCAP_BENCH_RBF") {
        for part in v.split(',') {
            match part.trim() {
                "thin_plate" => config.params.rbf.kernel = helmcap::baseline::RbfKernel::ThinPlate,
                "biharmonic" => config.params.rbf.kernel = helmcap::baseline::RbfKernel::Biharmonic,
                _ => {}
            }
        }
    }
    match run_benchmark(&config) {
        Ok(rows) => println!("{}", format_table(&rows)),
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    }
}
