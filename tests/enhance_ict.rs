//! Validation of the detail enhancement (Bermano et al. 2014 §7) on ICT-FaceKit, when its
//! data is present: combinations of expressions that are not database shapes are
//! low-passed, enhanced and compared with the originals. Run with `--nocapture` for the
//! figures.
#![allow(clippy::unwrap_used)]

use std::path::Path;

use helmcap::dataset::{LoadOptions, load_dataset};
use helmcap::enhance::{EnhanceParams, Enhancer};
use nalgebra::Point3;

fn rms(a: &[Point3<f64>], b: &[Point3<f64>], vs: &[usize]) -> f64 {
    (vs.iter()
        .map(|&v| (a[v] - b[v]).norm_squared())
        .sum::<f64>()
        / vs.len() as f64)
        .sqrt()
}

#[test]
fn ict_low_passed_combinations_get_their_details_back() {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/datasets/ict-facekit.toml");
    let options = LoadOptions {
        no_cache: true,
        ..Default::default()
    };
    let dataset = match load_dataset(&manifest, &options) {
        Ok(d) => d,
        Err(e) => {
            println!("skipping the ICT validation: {e}");
            return;
        }
    };
    let enhancer = Enhancer::new(&dataset, &EnhanceParams::default()).unwrap();
    let face: Vec<usize> = dataset.face_vertex_indices().collect();
    let neutral = &dataset.neutral.positions;
    let combos = [
        [("browInnerUp_L", 0.6), ("mouthSmile_R", 0.7)],
        [("eyeSquint_L", 0.5), ("jawOpen", 0.4)],
    ];
    let (mut before, mut after) = (0.0, 0.0);
    for combo in combos {
        let mut truth = neutral.clone();
        for (name, w) in combo {
            let Some(k) = dataset.shape_index(name) else {
                println!("skipping {name}: not in the dataset");
                continue;
            };
            for (t, (s, n)) in truth
                .iter_mut()
                .zip(dataset.shapes[k].positions.iter().zip(neutral))
            {
                *t += (s - n) * w;
            }
        }
        let input = enhancer.low_pass().apply(&truth).unwrap();
        let out = enhancer.enhance(&input).unwrap();
        let (b, a) = (rms(&input, &truth, &face), rms(&out, &truth, &face));
        println!(
            "ICT {combo:?}: face RMS {b:.3} -> {a:.3} mm ({:.0} % recovered)",
            100.0 * (1.0 - a / b)
        );
        before += b;
        after += a;
    }
    assert!(after < 0.9 * before, "{after} vs {before}");
}
