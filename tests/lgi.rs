//! Local geometric indexing on real data (ICT-FaceKit): the paper's verification experiment
//! (Cong et al. 2019 §7), interpolation of the bundles, and bad input.
//!
//! Skips with a message when the ICT-FaceKit data is not checked out beside the repository.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use helmcap::bundles::FrameBundles;
use helmcap::dataset::markers::{LayoutParams, generate_layout};
use helmcap::dataset::{Dataset, LoadOptions, MarkerLayout, load_dataset};
use helmcap::lgi::{LgiParams, LgiSolver};
use nalgebra::Point3;

fn manifest() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/datasets/ict-facekit.toml")
}

/// ICT with all 53 expressions and a 120-marker layout, loaded once per test binary.
fn ict() -> Option<&'static (Dataset, MarkerLayout)> {
    static ICT: OnceLock<Option<(Dataset, MarkerLayout)>> = OnceLock::new();
    ICT.get_or_init(|| {
        let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ict-facekit");
        if !data.join("generic_neutral_mesh.obj").exists() {
            return None;
        }
        let ds = load_dataset(&manifest(), &LoadOptions::default()).unwrap();
        let layout = generate_layout(&ds, &LayoutParams::default()).unwrap();
        Some((ds, layout))
    })
    .as_ref()
}

macro_rules! ict_or_skip {
    ($name:literal) => {
        match ict() {
            Some(x) => x,
            None => {
                eprintln!(
                    "skipping {}: ICT-FaceKit data not found at ../shared/data/ict-facekit \
                     beside the repository",
                    $name
                );
                return;
            }
        }
    };
}

fn solver() -> Option<&'static std::sync::Mutex<LgiSolver>> {
    static S: OnceLock<Option<std::sync::Mutex<LgiSolver>>> = OnceLock::new();
    S.get_or_init(|| {
        let (ds, layout) = ict()?;
        Some(std::sync::Mutex::new(
            LgiSolver::new(ds, layout, &LgiParams::default()).unwrap(),
        ))
    })
    .as_ref()
}

fn bundles_of(layout: &MarkerLayout, positions: &[Point3<f64>], frame: u64) -> FrameBundles {
    let p: Vec<Point3<f64>> = layout
        .markers
        .iter()
        .map(|m| positions[m.vertex as usize])
        .collect();
    FrameBundles::full(frame, &p)
}

fn face_error(ds: &Dataset, a: &[Point3<f64>], b: &[Point3<f64>]) -> (f64, f64) {
    let mut sum = 0.0;
    let mut max: f64 = 0.0;
    let mut n = 0;
    for v in ds.face_vertex_indices() {
        let e = (a[v] - b[v]).norm();
        sum += e;
        max = max.max(e);
        n += 1;
    }
    (sum / n as f64, max)
}

#[test]
fn verification_every_shape_gives_itself_back() {
    let (ds, layout) = ict_or_skip!("verification_every_shape_gives_itself_back");
    let mut s = solver().unwrap().lock().unwrap();
    println!("{}", s.index().stats);
    let mut worst_mean: f64 = 0.0;
    let mut worst_marker: f64 = 0.0;
    let mut total = 0.0;
    for (i, shape) in ds.shapes.iter().enumerate() {
        s.reset();
        let out = s
            .solve(&bundles_of(layout, &shape.positions, i as u64))
            .unwrap();
        let (mean, _) = face_error(ds, &out, &shape.positions);
        for m in &layout.markers {
            let v = m.vertex as usize;
            worst_marker = worst_marker.max((out[v] - shape.positions[v]).norm());
        }
        worst_mean = worst_mean.max(mean);
        total += mean;
    }
    println!(
        "verification: mean {:.6} mm, worst shape {:.6} mm, worst marker {:.2e} mm",
        total / ds.shapes.len() as f64,
        worst_mean,
        worst_marker
    );
    let mean = total / ds.shapes.len() as f64;
    assert!(mean < 0.001, "mean error {mean} mm");
    assert!(
        worst_mean < 0.01,
        "worst shape's mean error {worst_mean} mm"
    );
    assert!(worst_marker < 1e-6, "worst marker error {worst_marker} mm");
}
