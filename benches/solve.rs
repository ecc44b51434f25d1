//! Accuracy and speed of the solve methods on held-out performances (see
//! `helmcap::solve::benchmark`). Run with `cargo bench --bench solve`; prints a Markdown
//! table on stdout and progress on stderr.
//!
//! Environment: `HELMCAP_BENCH_FRAMES` (static frames per condition, default 60),
//! `HELMCAP_BENCH_ONLY` (comma-separated substrings of the dataset names to run, e.g.
//! `all 53,actor`), `HELMCAP_BENCH_SMOOTH` (half-width of LGI's centred smoothing on the
//! animated take, default 2), `HELMCAP_BENCH_RBF` (`thin_plate` or `biharmonic`: the RBF
//! baseline's kernel), `HELMCAP_BENCH_METHODS` (comma-separated methods to run),
//! `HELMCAP_BENCH_LGI` (LGI parameters as comma-separated TOML assignments).

use std::path::Path;

use helmcap::dataset::markers::{LayoutParams, generate_layout};
use helmcap::dataset::{LoadOptions, MarkerLayout, actor, load_dataset};
use helmcap::lgi::TemporalParams;
use helmcap::solve::SolveParams;
use helmcap::solve::benchmark::{
    Rng, animated_weights, format_table, ict_variants, linear_face, overlapping_pairs,
    random_weights, run_dataset, takes,
};

fn env_usize(name: &str, default: usize) -> usize {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The repository's default layout `configs/markers/NAME` (120 markers), or a generated
/// one when it is missing.
fn layout_for(root: &Path, name: &str, ds: &helmcap::dataset::Dataset) -> MarkerLayout {
    let path = root.join("configs/markers").join(name);
    match MarkerLayout::read_csv(&path) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("{e}: generating a layout instead");
            generate_layout(ds, &LayoutParams::default()).expect("marker layout")
        }
    }
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    let frames = env_usize("HELMCAP_BENCH_FRAMES", 60);
    let smooth = env_usize("HELMCAP_BENCH_SMOOTH", 2);
    let only: Vec<String> = std::env::var("HELMCAP_BENCH_ONLY")
        .map(|s| s.split(',').map(|x| x.trim().to_string()).collect())
        .unwrap_or_default();
    let wanted = |name: &str| only.is_empty() || only.iter().any(|o| name.contains(o.as_str()));
    let mut params = SolveParams::default();
    if let Ok(v) = std::env::var("HELMCAP_BENCH_LGI") {
        // TOML keys of LgiParams, e.g. "min_tet_quality=0.02,temporal_weight_mm=0.1".
        let text = v.replace(',', "\n");
        params.lgi = toml::from_str(&text).expect("HELMCAP_BENCH_LGI: LgiParams TOML keys");
    }
    if let Ok(v) = std::env::var("HELMCAP_BENCH_RBF") {
        for part in v.split(',') {
            match part.trim() {
                "thin_plate" => params.rbf.kernel = helmcap::baseline::RbfKernel::ThinPlate,
                "biharmonic" => params.rbf.kernel = helmcap::baseline::RbfKernel::Biharmonic,
                _ => {}
            }
        }
    }
    let smoothing = TemporalParams::centered(smooth);
    let mut rows = Vec::new();

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let ict_data = root.join("../shared/data/ict-facekit/generic_neutral_mesh.obj");
    if ict_data.exists() {
        let base = load_dataset(
            &root.join("configs/datasets/ict-facekit.toml"),
            &LoadOptions::default(),
        )
        .expect("loading ICT-FaceKit");
        let layout = layout_for(root, "ict-facekit.csv", &base);
        let mut rng = Rng::new(1);
        let n = base.shapes.len();
        let x0 = &base.neutral.positions;
        let stat: Vec<_> = (0..frames)
            .map(|_| linear_face(x0, &base.shapes, &random_weights(&mut rng, n)))
            .collect();
        let anim: Vec<_> = animated_weights(&mut rng, n, 120, 15)
            .iter()
            .map(|w| linear_face(x0, &base.shapes, w))
            .collect();
        let t = takes(&layout, &stat, &anim, 2);
        for (name, ds) in ict_variants(&base) {
            let name = format!("ICT {name}");
            if !wanted(&name) {
                continue;
            }
            match run_dataset(&name, &ds, &layout, &params, &t, smoothing) {
                Ok(r) => rows.extend(r),
                Err(e) => eprintln!("{e}"),
            }
        }
    } else {
        eprintln!("ICT-FaceKit data not found beside the repository: ICT rows skipped");
    }

    if wanted("actor") {
        let a = actor::Actor::new(&actor::ActorParams::default()).expect("built-in actor");
        let ds = a.to_dataset();
        let layout = layout_for(root, "builtin-actor.csv", &ds);
        let mut rng = Rng::new(3);
        let n = a.expression_names().len();
        let stat: Vec<_> = (0..frames)
            .map(|_| a.evaluate(&random_weights(&mut rng, n)).positions)
            .collect();
        let anim: Vec<_> = animated_weights(&mut rng, n, 120, 15)
            .iter()
            .map(|w| a.evaluate(w).positions)
            .collect();
        let t = takes(&layout, &stat, &anim, 4);
        match run_dataset("actor", &ds, &layout, &params, &t, smoothing) {
            Ok(r) => rows.extend(r),
            Err(e) => eprintln!("{e}"),
        }
        // The actor with 80 captured pair combinations (its true nonlinear model, jaw pose
        // included), as a capture session would add them.
        let mut more = ds.clone();
        for (i, j) in overlapping_pairs(&ds, 80) {
            let mut w = vec![0.0; n];
            w[i] = 1.0;
            w[j] = 1.0;
            let pose = a.evaluate(&w);
            more.shapes.push(helmcap::dataset::Shape {
                name: format!("{}+{}", ds.shapes[i].name, ds.shapes[j].name),
                positions: pose.positions,
                jaw: Some(pose.jaw),
            });
        }
        match run_dataset("actor + pairs", &more, &layout, &params, &t, smoothing) {
            Ok(r) => rows.extend(r),
            Err(e) => eprintln!("{e}"),
        }
    }
    println!("{}", format_table(&rows));
}
