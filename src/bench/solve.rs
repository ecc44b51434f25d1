//! Accuracy and speed benchmark of the solve methods on held-out performances: frames that
//! are not in the dataset (Cong et al. 2019 §7 "High-Resolution Capture Comparison" and
//! "Comparison to Other Approaches", made quantitative).
//!
//! # Datasets
//! - ICT-FaceKit: **all 53 expressions**; **+ in-betweens** (each at half weight);
//!   **+ pairs** (in-betweens and the 80 pairs of expressions whose displacement fields
//!   overlap most, the combinations a capture session would add); **symmetric only**
//!   (each `_L`/`_R` pair merged into one shape, as a FACS session delivers, while the
//!   performance stays asymmetric).
//! - The built-in actor: its 36 expressions as the dataset, performances from its
//!   nonlinear model (correctives, wrinkles, lids, skinned jaw).
//!
//! # Performances (seeded, reproducible)
//! Random combinations of 2–4 expressions with weights in [0.3, 1] (ICT: linear in its
//! shapes; the actor: its true nonlinear model), and a smooth animated sequence (keys of
//! 2–4 expressions every 15 frames, eased in between).
//!
//! # Conditions
//! Exact bundles; Gaussian noise of σ = 0.3 mm and 1 mm per coordinate; 10 % of the markers
//! missing (different ones each frame); the animated sequence, whose temporal jitter is the
//! mean vertex acceleration relative to the ground truth's.
//!
//! # Metrics
//! Mean and 95th-percentile vertex error over the face vertices, mean error at the present
//! markers, wall and thread-CPU time per frame (one thread), and the build time of each
//! method (wall time of building its solver from the loaded dataset: for LGI the whole
//! index of §4–§5, on every core).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use nalgebra::{Point3, Vector3};

use super::host::{process_cpu_seconds, thread_cpu_seconds};
use crate::bundles::FrameBundles;
use crate::dataset::{Dataset, MarkerLayout, Shape};
use crate::frame_index::FrameIndex;
use crate::lgi::{LgiParams, TemporalParams};
use crate::numeric::{SplitMix64, standard_normal};
use crate::solve::{Method, SolveParams, Solver};

/// A uniform integer in `0..n` (`n > 0`) from one uniform draw.
pub fn below(rng: &mut SplitMix64, n: usize) -> usize {
    (rng.next_f64() * n as f64) as usize % n.max(1)
}

/// Produces the ground-truth face (#V positions) of expression weights.
pub type Evaluate<'a> = dyn Fn(&[f64]) -> Vec<Point3<f64>> + 'a;

/// Random weights: 2–4 of `n` expressions at [0.3, 1].
pub fn random_weights(rng: &mut SplitMix64, n: usize) -> Vec<f64> {
    let mut w = vec![0.0; n];
    let k = 2 + below(rng, 3);
    let mut chosen = 0;
    while chosen < k.min(n) {
        let i = below(rng, n);
        if w[i] == 0.0 {
            w[i] = 0.3 + 0.7 * rng.next_f64();
            chosen += 1;
        }
    }
    w
}

/// A smooth animated sequence of `frames` weight vectors: random keys every `every`
/// frames, eased (smoothstep) in between.
pub fn animated_weights(
    rng: &mut SplitMix64,
    n: usize,
    frames: usize,
    every: usize,
) -> Vec<Vec<f64>> {
    let keys: Vec<Vec<f64>> = (0..frames / every + 2)
        .map(|k| {
            if k == 0 {
                vec![0.0; n]
            } else {
                random_weights(rng, n)
            }
        })
        .collect();
    (0..frames)
        .map(|f| {
            let k = f / every;
            let t = (f % every) as f64 / every as f64;
            let s = t * t * (3.0 - 2.0 * t);
            keys[k]
                .iter()
                .zip(&keys[k + 1])
                .map(|(a, b)| a + (b - a) * s)
                .collect()
        })
        .collect()
}

/// The linear evaluation `x₀ + Σ w_n b_n` over `shapes`.
pub fn linear_face(neutral: &[Point3<f64>], shapes: &[Shape], w: &[f64]) -> Vec<Point3<f64>> {
    let mut out = neutral.to_vec();
    for (s, &ws) in shapes.iter().zip(w) {
        if ws == 0.0 {
            continue;
        }
        for ((o, p), x) in out.iter_mut().zip(&s.positions).zip(neutral) {
            *o += (p - x) * ws;
        }
    }
    out
}

/// The `count` pairs of shapes whose displacement fields overlap most (absolute cosine over
/// the face vertices): the combinations a capture session would add.
pub fn overlapping_pairs(base: &Dataset, count: usize) -> Vec<(usize, usize)> {
    let x0 = &base.neutral.positions;
    let face: Vec<usize> = base.face_vertex_indices().collect();
    let d: Vec<Vec<Vector3<f64>>> = base
        .shapes
        .iter()
        .map(|s| face.iter().map(|&v| s.positions[v] - x0[v]).collect())
        .collect();
    let norm: Vec<f64> = d
        .iter()
        .map(|x| x.iter().map(|v| v.norm_squared()).sum::<f64>().sqrt())
        .collect();
    let mut pairs = Vec::new();
    for i in 0..d.len() {
        for j in i + 1..d.len() {
            let dot: f64 = d[i].iter().zip(&d[j]).map(|(a, b)| a.dot(b)).sum();
            pairs.push((dot.abs() / (norm[i] * norm[j]).max(1e-12), i, j));
        }
    }
    pairs.sort_by(|a, b| b.0.total_cmp(&a.0));
    pairs
        .into_iter()
        .take(count)
        .map(|(_, i, j)| (i, j))
        .collect()
}

/// ICT dataset variants of the benchmark, from the 53-expression dataset.
pub fn ict_variants(base: &Dataset) -> Vec<(String, Dataset)> {
    let x0 = &base.neutral.positions;
    let make = |name: &str, w: &[(usize, f64)]| -> Shape {
        let mut pos = x0.clone();
        for &(i, wi) in w {
            for ((o, p), x) in pos.iter_mut().zip(&base.shapes[i].positions).zip(x0) {
                *o += (p - x) * wi;
            }
        }
        Shape {
            name: name.to_string(),
            positions: pos,
            jaw: None,
        }
    };
    let with = |name: &str, extra: Vec<Shape>| -> (String, Dataset) {
        let mut ds = base.clone();
        ds.name = name.to_string();
        ds.shapes.extend(extra);
        (name.to_string(), ds)
    };
    let halves: Vec<Shape> = base
        .shapes
        .iter()
        .enumerate()
        .map(|(i, s)| make(&format!("{}_half", s.name), &[(i, 0.5)]))
        .collect();
    let pair_shapes: Vec<Shape> = overlapping_pairs(base, 80)
        .into_iter()
        .map(|(i, j)| {
            make(
                &format!("{}+{}", base.shapes[i].name, base.shapes[j].name),
                &[(i, 1.0), (j, 1.0)],
            )
        })
        .collect();
    // Symmetric: merge _L/_R pairs.
    let mut sym = base.clone();
    sym.name = "symmetric".into();
    sym.shapes.clear();
    for (i, s) in base.shapes.iter().enumerate() {
        if let Some(stem) = s.name.strip_suffix("_L") {
            if let Some(j) = base.shape_index(&format!("{stem}_R")) {
                sym.shapes.push(make(stem, &[(i, 1.0), (j, 1.0)]));
                continue;
            }
        } else if let Some(stem) = s.name.strip_suffix("_R")
            && base.shape_index(&format!("{stem}_L")).is_some()
        {
            continue;
        }
        sym.shapes.push(s.clone());
    }
    let mut all = base.clone();
    all.name = "all".into();
    let inb = halves.clone();
    let mut pr = halves;
    pr.extend(pair_shapes);
    vec![
        ("all 53".to_string(), all),
        with("+ in-betweens", inb),
        with("+ pairs", pr),
        ("symmetric only".to_string(), sym),
    ]
}

/// One line of the results table.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// Dataset variant.
    pub dataset: String,
    /// Condition (exact, noise, missing, animated).
    pub condition: String,
    /// Method (with its variant, e.g. `lgi+smooth`).
    pub method: String,
    /// Mean vertex error over the face vertices, mm.
    pub mean_mm: f64,
    /// 95th percentile vertex error, mm.
    pub p95_mm: f64,
    /// Mean error at the present markers, mm.
    pub marker_mm: f64,
    /// Mean wall time per frame, ms.
    pub ms_per_frame: f64,
    /// Mean CPU time per frame of the solving thread, ms (`None` where the platform does
    /// not report it). Unlike the wall time it does not count time the thread waited for a
    /// core, so it is the figure to compare on a loaded machine.
    pub cpu_ms_per_frame: Option<f64>,
    /// Build (precomputation) time, s.
    pub build_s: f64,
    /// Animated sequences: mean vertex acceleration relative to the ground truth's.
    pub accel_ratio: Option<f64>,
}

/// Formats rows as a Markdown table.
pub fn format_table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| dataset | condition | method | mean mm | p95 mm | marker mm | ms/frame | cpu ms/frame | build s | accel ratio |\n\
         |---|---|---|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    for r in rows {
        s.push_str(&format!(
            "| {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.2} | {} | {:.2} | {} |\n",
            r.dataset,
            r.condition,
            r.method,
            r.mean_mm,
            r.p95_mm,
            r.marker_mm,
            r.ms_per_frame,
            r.cpu_ms_per_frame.map_or("".into(), |c| format!("{c:.2}")),
            r.build_s,
            r.accel_ratio.map_or("".into(), |a| format!("{a:.2}"))
        ));
    }
    s
}

/// A set of test frames: ground truth and bundles.
pub struct Take {
    /// Condition name.
    pub condition: String,
    /// Ground-truth positions per frame.
    pub truth: Vec<Vec<Point3<f64>>>,
    /// Bundles per frame.
    pub bundles: Vec<FrameBundles>,
    /// Whether the frames form one animated sequence.
    pub animated: bool,
}

/// Held-out actor frames made of what its model does not do linearly (§6 and the
/// correctives of [`crate::dataset::actor`]): the jaw partly open (an arc, not the chord a
/// blend of the full-open shape follows), sideways in half the frames, with one of the
/// corrective pairs at strong weights. Exact bundles.
pub fn actor_nonlinear_take(
    actor: &crate::dataset::actor::Actor,
    layout: &MarkerLayout,
    rng: &mut SplitMix64,
    frames: usize,
) -> Take {
    let names = actor.expression_names();
    let ix = |name: &str| names.iter().position(|n| *n == name);
    let pairs: Vec<(usize, usize)> = [
        ("mouthSmile_L", "mouthSmile_R"),
        ("mouthSmile_L", "jawOpen"),
        ("mouthSmile_R", "jawOpen"),
        ("mouthFunnel", "jawOpen"),
        ("browDown_L", "browInnerUp"),
        ("browDown_R", "browInnerUp"),
        ("eyeBlink_L", "eyeSquint_L"),
        ("eyeBlink_R", "eyeSquint_R"),
    ]
    .iter()
    .filter_map(|(a, b)| Some((ix(a)?, ix(b)?)))
    .collect();
    let (jaw_open, jaw_left, jaw_right) = (ix("jawOpen"), ix("jawLeft"), ix("jawRight"));
    let mut truth = Vec::with_capacity(frames);
    for f in 0..frames {
        let mut w = vec![0.0; names.len()];
        if let Some(j) = jaw_open {
            w[j] = 0.2 + 0.7 * rng.next_f64();
        }
        if f % 2 == 1
            && let Some(side) = if rng.next_f64() < 0.5 {
                jaw_left
            } else {
                jaw_right
            }
        {
            w[side] = 0.6 * rng.next_f64();
        }
        if !pairs.is_empty() {
            let (a, b) = pairs[below(rng, pairs.len())];
            w[a] = w[a].max(0.5 + 0.5 * rng.next_f64());
            w[b] = w[b].max(0.5 + 0.5 * rng.next_f64());
        }
        truth.push(actor.evaluate(&w).positions);
    }
    let bundles = sample_bundles(layout, &truth, rng, 0.0, 0.0);
    Take {
        condition: "nonlinear: jaw + correctives".to_string(),
        truth,
        bundles,
        animated: false,
    }
}

/// The bundles of the `layout`'s markers on each frame of `truth`: Gaussian noise of
/// `sigma` mm per coordinate, each marker missing with probability `missing` (`rng` is
/// drawn from only for a non-zero `sigma` or `missing`).
fn sample_bundles(
    layout: &MarkerLayout,
    truth: &[Vec<Point3<f64>>],
    rng: &mut SplitMix64,
    sigma: f64,
    missing: f64,
) -> Vec<FrameBundles> {
    truth
        .iter()
        .enumerate()
        .map(|(f, t)| FrameBundles {
            frame: FrameIndex::from(f),
            positions: layout
                .markers
                .iter()
                .map(|m| {
                    let p = t[m.vertex as usize];
                    if missing > 0.0 && rng.next_f64() < missing {
                        return None;
                    }
                    Some(if sigma > 0.0 {
                        p + Vector3::new(
                            standard_normal(rng),
                            standard_normal(rng),
                            standard_normal(rng),
                        ) * sigma
                    } else {
                        p
                    })
                })
                .collect(),
        })
        .collect()
}

/// Builds the benchmark takes of a performance: `static_truth` frames under exact, noisy
/// and missing conditions, and the animated `anim_truth` with exact bundles.
pub fn takes(
    layout: &MarkerLayout,
    static_truth: &[Vec<Point3<f64>>],
    anim_truth: &[Vec<Point3<f64>>],
    seed: u64,
) -> Vec<Take> {
    let mut rng = SplitMix64::new(seed);
    let mut out = Vec::new();
    for (name, sigma, missing) in [
        ("exact", 0.0, 0.0),
        ("noise 0.3 mm", 0.3, 0.0),
        ("noise 1 mm", 1.0, 0.0),
        ("10% missing", 0.0, 0.1),
    ] {
        out.push(Take {
            condition: name.to_string(),
            truth: static_truth.to_vec(),
            bundles: sample_bundles(layout, static_truth, &mut rng, sigma, missing),
            animated: false,
        });
    }
    if !anim_truth.is_empty() {
        out.push(Take {
            condition: format!("animated {} frames", anim_truth.len()),
            truth: anim_truth.to_vec(),
            bundles: sample_bundles(layout, anim_truth, &mut rng, 0.0, 0.0),
            animated: true,
        });
    }
    out
}

/// Errors of `solved` against `truth` over the face vertices: per-vertex errors appended
/// to `all`, and the marker error summed into `marker` with its count.
fn accumulate(
    dataset: &Dataset,
    layout: &MarkerLayout,
    bundles: &FrameBundles,
    solved: &[Point3<f64>],
    truth: &[Point3<f64>],
    all: &mut Vec<f64>,
    marker: &mut (f64, usize),
) {
    for v in dataset.face_vertex_indices() {
        all.push((solved[v] - truth[v]).norm());
    }
    for (m, p) in layout.markers.iter().zip(&bundles.positions) {
        if p.is_some() {
            let v = m.vertex as usize;
            marker.0 += (solved[v] - truth[v]).norm();
            marker.1 += 1;
        }
    }
}

/// Mean vertex acceleration (second difference) over the face vertices of a sequence.
pub fn mean_acceleration(dataset: &Dataset, seq: &[Vec<Point3<f64>>]) -> f64 {
    let mut sum = 0.0;
    let mut n = 0usize;
    for t in 1..seq.len().saturating_sub(1) {
        for v in dataset.face_vertex_indices() {
            let a = seq[t + 1][v].coords - 2.0 * seq[t][v].coords + seq[t - 1][v].coords;
            sum += a.norm();
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

/// Runs every method on every take of one dataset variant.
///
/// `smoothing` is the LGI temporal smoothing reported as `lgi+smooth` on animated takes.
///
/// # Errors
/// A message naming the method and frame that failed.
pub fn run_dataset(
    name: &str,
    dataset: &Dataset,
    layout: &MarkerLayout,
    params: &SolveParams,
    takes: &[Take],
    smoothing: TemporalParams,
) -> Result<Vec<Row>, String> {
    run_dataset_with(
        name,
        dataset,
        layout,
        params,
        takes,
        smoothing,
        &Method::ALL,
        1,
    )
}

/// [`run_dataset`] for the given `methods`: each take is solved once for the errors,
/// keeping every mesh, then `runs` times for the time per frame (the median is reported),
/// dropping each mesh once solved as a streaming consumer does.
///
/// # Errors
/// A message naming the method and frame that failed.
#[allow(clippy::too_many_arguments)]
pub fn run_dataset_with(
    name: &str,
    dataset: &Dataset,
    layout: &MarkerLayout,
    params: &SolveParams,
    takes: &[Take],
    smoothing: TemporalParams,
    methods: &[Method],
    runs: usize,
) -> Result<Vec<Row>, String> {
    let mut rows = Vec::new();
    for &method in methods {
        let t0 = Instant::now();
        let cpu0 = process_cpu_seconds();
        let mut solver = Solver::new(method, dataset, layout, params)
            .map_err(|e| format!("{name}: building {}: {e}", method.name()))?;
        let build_s = t0.elapsed().as_secs_f64();
        let build_cpu = cpu0.zip(process_cpu_seconds()).map(|(a, b)| b - a);
        if let Solver::Lgi(s) = &solver {
            eprintln!("{name}: {}", s.index().stats);
        }
        if let Some(cpu) = build_cpu {
            eprintln!(
                "{name}: {} built in {build_s:.2} s wall, {cpu:.2} s CPU over all threads",
                method.name()
            );
        }
        let mut other_indexes: Vec<Arc<crate::lgi::LgiIndex>> = Vec::new();
        for take in takes {
            // LGI variants: temporal smoothing on the animated take, the
            // noisy-input preset on noisy takes.
            let mut variants: Vec<(String, Option<LgiParams>)> =
                vec![(method.name().to_string(), None)];
            if method == Method::Lgi {
                if take.animated && smoothing.is_enabled() {
                    let p = LgiParams {
                        smoothing,
                        ..params.lgi
                    };
                    variants.push(("lgi+smooth".to_string(), Some(p)));
                }
                if take.condition.starts_with("noise") {
                    let p = LgiParams {
                        smoothing: params.lgi.smoothing,
                        ..LgiParams::noisy()
                    };
                    variants.push(("lgi, noisy preset".to_string(), Some(p)));
                }
            }
            for (label, lgi_params) in variants {
                let mut times = Vec::with_capacity(runs.max(1));
                let mut cpu_times = Vec::with_capacity(runs.max(1));
                let mut variant = match (&solver, lgi_params) {
                    (Solver::Lgi(s), Some(p)) => {
                        // The same index unless the variant's build settings differ (the
                        // noisy preset merges nearby points): built once per dataset.
                        let index = if p.index_params() == s.index().params.index_params() {
                            s.index().clone()
                        } else if let Some(i) = other_indexes
                            .iter()
                            .find(|i| i.params.index_params() == p.index_params())
                        {
                            i.clone()
                        } else {
                            let i = Arc::new(
                                crate::lgi::LgiIndex::build(dataset, layout, &p)
                                    .map_err(|e| format!("{name}: {label}: {e}"))?,
                            );
                            eprintln!("{name}: {label}: {}", i.stats);
                            other_indexes.push(i.clone());
                            i
                        };
                        Some(
                            crate::lgi::LgiSolver::from_index(index, &p)
                                .map_err(|e| e.to_string())?,
                        )
                    }
                    _ => None,
                };
                // Solves the take; `keep`: returns every mesh, else drops each one once
                // solved, as a streaming consumer does.
                let mut solve_take = |keep: bool| -> Result<Vec<Vec<Point3<f64>>>, String> {
                    let mut out = Vec::with_capacity(if keep { take.bundles.len() } else { 0 });
                    let mut emit = |mesh: Vec<Point3<f64>>| {
                        if keep {
                            out.push(mesh);
                        } else {
                            std::hint::black_box(mesh);
                        }
                    };
                    match &mut variant {
                        Some(s2) if take.animated => {
                            s2.reset();
                            for mesh in s2
                                .solve_sequence(&take.bundles)
                                .map_err(|e| e.to_string())?
                            {
                                emit(mesh);
                            }
                        }
                        Some(s2) => {
                            for b in &take.bundles {
                                s2.reset();
                                emit(s2.solve(b).map_err(|e| e.to_string())?);
                            }
                        }
                        None => {
                            solver.reset();
                            for b in &take.bundles {
                                if !take.animated {
                                    solver.reset();
                                }
                                emit(solver.solve(b).map_err(|e| {
                                    format!("{name}/{}/{label}: {e}", take.condition)
                                })?);
                            }
                        }
                    }
                    Ok(out)
                };
                // The errors come from a first run that keeps every mesh; the `runs` timed
                // runs after it drop each mesh once solved (keeping them all would put
                // the cost of fresh memory, page faults, into every frame's time).
                let solved = solve_take(true)?;
                for _ in 0..runs.max(1) {
                    let t = Instant::now();
                    let cpu0 = thread_cpu_seconds();
                    solve_take(false)?;
                    let frames = take.bundles.len().max(1) as f64;
                    times.push(t.elapsed().as_secs_f64() * 1e3 / frames);
                    if let (Some(a), Some(b)) = (cpu0, thread_cpu_seconds()) {
                        cpu_times.push((b - a) * 1e3 / frames);
                    }
                }
                times.sort_by(f64::total_cmp);
                let ms = times[times.len() / 2];
                cpu_times.sort_by(f64::total_cmp);
                let cpu_ms = cpu_times.get(cpu_times.len() / 2).copied();
                let mut all = Vec::new();
                let mut marker = (0.0, 0usize);
                for ((b, s), tr) in take.bundles.iter().zip(&solved).zip(&take.truth) {
                    accumulate(dataset, layout, b, s, tr, &mut all, &mut marker);
                }
                let mean = all.iter().sum::<f64>() / all.len().max(1) as f64;
                let k = ((all.len() as f64 * 0.95) as usize).min(all.len().saturating_sub(1));
                let p95 = if all.is_empty() {
                    0.0
                } else {
                    *all.select_nth_unstable_by(k, f64::total_cmp).1
                };
                let accel_ratio = take.animated.then(|| {
                    mean_acceleration(dataset, &solved)
                        / mean_acceleration(dataset, &take.truth).max(1e-12)
                });
                rows.push(Row {
                    dataset: name.to_string(),
                    condition: take.condition.clone(),
                    method: label,
                    mean_mm: mean,
                    p95_mm: p95,
                    marker_mm: marker.0 / marker.1.max(1) as f64,
                    ms_per_frame: ms,
                    cpu_ms_per_frame: cpu_ms,
                    build_s,
                    accel_ratio,
                });
                if let Some(r) = rows.last() {
                    eprintln!(
                        "{}",
                        format_table(std::slice::from_ref(r))
                            .lines()
                            .nth(2)
                            .unwrap_or("")
                    );
                }
            }
        }
    }
    Ok(rows)
}

/// What [`run_benchmark`] runs.
#[derive(Debug, Clone)]
pub struct BenchConfig {
    /// Static frames per condition. Default 60.
    pub frames: usize,
    /// Half-width of LGI's centred smoothing on the animated take (the `lgi+smooth` rows;
    /// 0: none). Default 2.
    pub smooth: usize,
    /// Timed runs of every take; the median time per frame is reported. Default 5.
    pub runs: usize,
    /// Substrings of the dataset names to run (`all 53`, `pairs`, `actor`, ...); empty:
    /// every dataset.
    pub only: Vec<String>,
    /// Substrings of the condition names to run (`exact`, `noise 0.3`, `missing`,
    /// `animated`, ...); empty: every condition.
    pub conditions: Vec<String>,
    /// Methods to run. Default all three.
    pub methods: Vec<Method>,
    /// Parameters of every method.
    pub params: SolveParams,
    /// ICT-FaceKit manifest; `None` or missing data skips the ICT rows.
    pub ict_manifest: Option<PathBuf>,
    /// ICT marker layout (generated when `None` or unreadable).
    pub ict_layout: Option<PathBuf>,
    /// Built-in actor marker layout (generated when `None` or unreadable).
    pub actor_layout: Option<PathBuf>,
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            frames: 60,
            smooth: 2,
            runs: 5,
            only: Vec::new(),
            conditions: Vec::new(),
            methods: Method::ALL.to_vec(),
            params: SolveParams::default(),
            ict_manifest: None,
            ict_layout: None,
            actor_layout: None,
        }
    }
}

impl BenchConfig {
    /// The repository's defaults under `root`: `configs/datasets/ict-facekit.toml` and the
    /// 120-marker layouts of `configs/markers/`.
    pub fn for_repository(root: &Path) -> Self {
        Self {
            ict_manifest: Some(root.join("configs/datasets/ict-facekit.toml")),
            ict_layout: Some(root.join("configs/markers/ict-facekit.csv")),
            actor_layout: Some(root.join("configs/markers/builtin-actor.csv")),
            ..Self::default()
        }
    }

    fn wants(&self, name: &str) -> bool {
        self.only.is_empty() || self.only.iter().any(|o| name.contains(o.as_str()))
    }

    /// The takes whose condition `conditions` selects.
    fn selected(&self, mut takes: Vec<Take>) -> Vec<Take> {
        if !self.conditions.is_empty() {
            takes.retain(|t| {
                self.conditions
                    .iter()
                    .any(|c| t.condition.contains(c.as_str()))
            });
        }
        takes
    }
}

/// The layout at `path`, or one generated for `ds` when it is `None` or unreadable.
fn layout_or_generated(path: Option<&Path>, ds: &Dataset) -> Result<MarkerLayout, String> {
    if let Some(p) = path {
        match MarkerLayout::read_csv(p) {
            Ok(l) => return Ok(l),
            Err(e) => tracing::warn!("{e}: generating a layout instead"),
        }
    }
    crate::dataset::markers::generate_layout(ds, &crate::dataset::markers::LayoutParams::default())
        .map_err(|e| format!("generating a marker layout: {e}"))
}

/// Runs the whole benchmark of the module docs (the datasets `config` selects) and
/// returns the table's rows; progress goes to the log.
///
/// # Errors
/// A message when a dataset cannot be loaded or a method fails.
pub fn run_benchmark(config: &BenchConfig) -> Result<Vec<Row>, String> {
    let mut rows = Vec::new();
    let smoothing = TemporalParams::centered(config.smooth);
    let frames = config.frames.max(1);
    let ict = config.ict_manifest.as_ref().filter(|m| ict_data_present(m));
    let any_ict = [
        "ICT all 53",
        "ICT + in-betweens",
        "ICT + pairs",
        "ICT symmetric only",
    ]
    .iter()
    .any(|n| config.wants(n));
    match ict {
        Some(manifest) if any_ict => {
            let base = crate::dataset::load_dataset(manifest, &Default::default())
                .map_err(|e| format!("loading {}: {e}", manifest.display()))?;
            let layout = layout_or_generated(config.ict_layout.as_deref(), &base)?;
            let mut rng = SplitMix64::new(1);
            let n = base.shapes.len();
            let x0 = &base.neutral.positions;
            let stat: Vec<_> = (0..frames)
                .map(|_| linear_face(x0, &base.shapes, &random_weights(&mut rng, n)))
                .collect();
            let anim: Vec<_> = animated_weights(&mut rng, n, 120, 15)
                .iter()
                .map(|w| linear_face(x0, &base.shapes, w))
                .collect();
            let t = config.selected(takes(&layout, &stat, &anim, 2));
            for (name, ds) in ict_variants(&base) {
                let name = format!("ICT {name}");
                if config.wants(&name) {
                    rows.extend(run_dataset_with(
                        &name,
                        &ds,
                        &layout,
                        &config.params,
                        &t,
                        smoothing,
                        &config.methods,
                        config.runs,
                    )?);
                }
            }
        }
        _ if any_ict && config.ict_manifest.is_some() => {
            tracing::warn!("ICT-FaceKit data not found: ICT rows skipped");
        }
        _ => {}
    }
    if config.wants("actor") {
        let a = crate::dataset::actor::Actor::new(&Default::default())
            .map_err(|e| format!("built-in actor: {e}"))?;
        let ds = a.to_dataset();
        let layout = layout_or_generated(config.actor_layout.as_deref(), &ds)?;
        let mut rng = SplitMix64::new(3);
        let n = a.expression_names().len();
        let stat: Vec<_> = (0..frames)
            .map(|_| a.evaluate(&random_weights(&mut rng, n)).positions)
            .collect();
        let anim: Vec<_> = animated_weights(&mut rng, n, 120, 15)
            .iter()
            .map(|w| a.evaluate(w).positions)
            .collect();
        let mut t = takes(&layout, &stat, &anim, 4);
        t.push(actor_nonlinear_take(&a, &layout, &mut rng, frames));
        let t = config.selected(t);
        {
            rows.extend(run_dataset_with(
                "actor",
                &ds,
                &layout,
                &config.params,
                &t,
                smoothing,
                &config.methods,
                config.runs,
            )?);
        }
        {
            // The actor with 80 captured pair combinations (its true nonlinear model, jaw
            // pose included), as a capture session would add them.
            let mut more = ds.clone();
            for (i, j) in overlapping_pairs(&ds, 80) {
                let mut w = vec![0.0; n];
                w[i] = 1.0;
                w[j] = 1.0;
                let pose = a.evaluate(&w);
                more.shapes.push(Shape {
                    name: format!("{}+{}", ds.shapes[i].name, ds.shapes[j].name),
                    positions: pose.positions,
                    jaw: Some(pose.jaw),
                });
            }
            rows.extend(run_dataset_with(
                "actor + pairs",
                &more,
                &layout,
                &config.params,
                &t,
                smoothing,
                &config.methods,
                config.runs,
            )?);
        }
    }
    Ok(rows)
}

/// Whether a manifest and its neutral mesh file are there.
fn ict_data_present(manifest: &Path) -> bool {
    crate::dataset::manifest::Manifest::read(manifest).is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(cpu: Option<f64>) -> Row {
        Row {
            dataset: "d".into(),
            condition: "exact".into(),
            method: "lgi".into(),
            mean_mm: 0.1234,
            p95_mm: 0.5,
            marker_mm: 0.0,
            ms_per_frame: 12.345,
            cpu_ms_per_frame: cpu,
            build_s: 1.5,
            accel_ratio: None,
        }
    }

    #[test]
    fn table_has_a_cpu_column_left_empty_when_unknown() {
        let t = format_table(&[row(Some(6.789)), row(None)]);
        let lines: Vec<&str> = t.lines().collect();
        assert!(lines[0].contains("| ms/frame | cpu ms/frame | build s |"));
        assert_eq!(lines[0].matches('|').count(), lines[1].matches('|').count());
        assert_eq!(
            lines[2],
            "| d | exact | lgi | 0.123 | 0.500 | 0.000 | 12.35 | 6.79 | 1.50 |  |"
        );
        assert_eq!(
            lines[3],
            "| d | exact | lgi | 0.123 | 0.500 | 0.000 | 12.35 |  | 1.50 |  |"
        );
    }
}
