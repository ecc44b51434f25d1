//! Robust absolute orientation: Horn's closed form (Horn 1987) inside iteratively
//! reweighted least squares, so that a few markers that moved (expression) or were
//! mislabeled do not pull the head pose.
//!
//! Each iteration solves the weighted problem of [`horn_similarity`]
//! `min Σᵢ wᵢ ρ(rᵢ)`, `rᵢ = ‖s·R·pᵢ + t − qᵢ‖`, by weighted Horn with the weights
//! `wᵢ · ψ(rᵢ)/rᵢ` of the previous residuals (IRLS), where `ρ` is the Tukey biweight
//! (redescending: a residual above the cut-off gets weight 0) or the Huber loss (convex:
//! far points keep a weight falling as `1/r`). The cut-off `c` adapts to the data:
//! `c = k · max(σ̂, σ_min)`, `σ̂ = 1.4826 · median(rᵢ)` (the normalized median absolute
//! residual, consistent for Gaussian noise), with `k = 4.685` for Tukey and `k = 1.345` for
//! Huber (95 % efficiency on Gaussian noise), floored by [`RobustHornParams::min_sigma_mm`]
//! so that exact data does not make the cut-off vanish. The first iterations use Huber
//! (convex, so it moves away from the contaminated plain fit safely) and the rest Tukey
//! (which ignores gross outliers entirely).

use nalgebra::{Isometry3, Point3, Translation3, Vector3};

use super::horn::{HornError, horn_alignment};
use crate::numeric::upper_median;
use crate::param_error::{ParamError, non_negative, positive};

/// Robust loss of [`robust_horn`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RobustLoss {
    /// Plain weighted least squares (one Horn solve, no reweighting).
    None,
    /// Huber loss, `k = 1.345` (convex; outliers down-weighted as `c/r`).
    Huber,
    /// Huber for the first [`RobustHornParams::huber_iterations`], then Tukey's biweight,
    /// `k = 4.685` (redescending: residuals above the cut-off get weight 0).
    Tukey,
}

/// Settings of [`robust_horn`].
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobustHornParams {
    /// Loss. Default [`RobustLoss::Tukey`].
    pub loss: RobustLoss,
    /// Also estimate a uniform scale `s` (Horn 1987 §2.E, symmetric form). Default false:
    /// a head does not change size, and a free scale absorbs depth errors.
    pub estimate_scale: bool,
    /// Floor of the residual scale σ used for the cut-off, in the points' unit (mm).
    /// Default 0.3 mm: about the triangulation noise of a helmet rig, so the Tukey cut-off
    /// is at least 1.4 mm and never rejects markers for noise alone.
    pub min_sigma_mm: f64,
    /// Reweighting iterations at most. Default 20.
    pub max_iterations: usize,
    /// Of those, how many use Huber before Tukey takes over. Default 3.
    pub huber_iterations: usize,
    /// Stop when the transform moves every point by less than this, mm. Default 1e-7.
    pub tolerance_mm: f64,
}

impl Default for RobustHornParams {
    fn default() -> Self {
        Self {
            loss: RobustLoss::Tukey,
            estimate_scale: false,
            min_sigma_mm: 0.3,
            max_iterations: 20,
            huber_iterations: 3,
            tolerance_mm: 1e-7,
        }
    }
}

impl RobustHornParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`ParamError`] naming the field.
    pub fn validate(&self) -> Result<(), ParamError> {
        positive(self.min_sigma_mm, "min_sigma_mm")?;
        if self.max_iterations == 0 {
            return Err(ParamError::new("max_iterations", "must be at least 1"));
        }
        non_negative(self.tolerance_mm, "tolerance_mm")?;
        Ok(())
    }
}

/// Result of [`robust_horn`]: the model, which points it trusts, and how well it fits.
#[derive(Debug, Clone, PartialEq)]
pub struct RobustFit {
    /// The rigid part, `target_from_source` (with `scale`: `q ≈ scale · R·p + t`, this
    /// holds `R` and `t`).
    pub target_from_source: Isometry3<f64>,
    /// Uniform scale (1 unless [`RobustHornParams::estimate_scale`]).
    pub scale: f64,
    /// Final robust weight of each point, 0..1 (0: rejected).
    pub robust_weights: Vec<f64>,
    /// Points whose final robust weight is above 0.5.
    pub inlier_count: usize,
    /// Residual of each point, ‖s·R·p + t − q‖.
    pub residuals: Vec<f64>,
    /// Weighted RMS residual over the inliers.
    pub inlier_rms: f64,
    /// The final cut-off `c`.
    pub cutoff: f64,
    /// Reweighting iterations run.
    pub iterations: usize,
}

impl RobustFit {
    /// Maps a source point into the target frame (scale included).
    pub fn apply(&self, p: &Point3<f64>) -> Point3<f64> {
        let r = self.target_from_source.rotation * p.coords * self.scale;
        Point3::from(r + self.target_from_source.translation.vector)
    }
}

/// Weighted Horn with an optional uniform scale (Horn 1987 §2.E, the symmetric scale
/// `s = √(Σ wᵢ‖q′ᵢ‖² / Σ wᵢ‖p′ᵢ‖²)` over centred points, which makes the rotation
/// independent of the scale): returns `(R, t, s)` minimizing Σ wᵢ ‖s·R·pᵢ + t − qᵢ‖² (for
/// the rotation; the scale is the symmetric one).
///
/// # Errors
/// As [`horn_alignment`].
pub fn horn_similarity(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    weights: &[f64],
    estimate_scale: bool,
) -> Result<(Isometry3<f64>, f64), HornError> {
    let rigid = horn_alignment(source, target, weights)?;
    if !estimate_scale {
        return Ok((rigid, 1.0));
    }
    let w = |i: usize| weights.get(i).copied().unwrap_or(1.0);
    let total: f64 = (0..source.len()).map(w).sum();
    let cs = (0..source.len())
        .map(|i| source[i].coords * w(i))
        .sum::<Vector3<f64>>()
        / total;
    let ct = (0..target.len())
        .map(|i| target[i].coords * w(i))
        .sum::<Vector3<f64>>()
        / total;
    let (mut ss, mut st) = (0.0, 0.0);
    for i in 0..source.len() {
        ss += w(i) * (source[i].coords - cs).norm_squared();
        st += w(i) * (target[i].coords - ct).norm_squared();
    }
    let scale = if ss > 0.0 { (st / ss).sqrt() } else { 1.0 };
    let t = ct - rigid.rotation * cs * scale;
    Ok((
        Isometry3::from_parts(Translation3::from(t), rigid.rotation),
        scale,
    ))
}

/// Robust weighted absolute orientation (see the module docs): finds `target_from_source`
/// (and a scale on request) mapping `source` onto `target`, with `weights` (#P,
/// non-negative, or empty for all ones) the prior confidence of each pair.
///
/// # Errors
/// As [`horn_alignment`] (lengths, weights); [`HornError::Weights`] also when the robust
/// weights leave nothing to fit.
pub fn robust_horn(
    source: &[Point3<f64>],
    target: &[Point3<f64>],
    weights: &[f64],
    params: &RobustHornParams,
) -> Result<RobustFit, HornError> {
    let n = source.len();
    let prior: Vec<f64> = if weights.is_empty() {
        vec![1.0; n]
    } else {
        weights.to_vec()
    };
    let (mut pose, mut scale) = horn_similarity(source, target, &prior, params.estimate_scale)?;
    let residuals_of = |pose: &Isometry3<f64>, scale: f64| -> Vec<f64> {
        source
            .iter()
            .zip(target)
            .map(|(p, q)| {
                let mapped = pose.rotation * p.coords * scale + pose.translation.vector;
                (mapped - q.coords).norm()
            })
            .collect()
    };
    let mut residuals = residuals_of(&pose, scale);
    let mut robust = vec![1.0; n];
    let mut cutoff = f64::INFINITY;
    let mut iterations = 0;
    if params.loss != RobustLoss::None {
        for it in 0..params.max_iterations {
            let tukey = params.loss == RobustLoss::Tukey && it >= params.huber_iterations;
            // Scale of the residuals among the points that count at all.
            let counted: Vec<f64> = residuals
                .iter()
                .zip(&prior)
                .filter(|&(_, &w)| w > 0.0)
                .map(|(&r, _)| r)
                .collect();
            // (No counted point: a median of 0, so σ is the floor.)
            let sigma = (1.4826 * upper_median(&counted).unwrap_or(0.0)).max(params.min_sigma_mm);
            cutoff = sigma * if tukey { 4.685 } else { 1.345 };
            for (w, &r) in robust.iter_mut().zip(&residuals) {
                *w = if tukey {
                    if r < cutoff {
                        let u = r / cutoff;
                        (1.0 - u * u).powi(2)
                    } else {
                        0.0
                    }
                } else if r <= cutoff {
                    1.0
                } else {
                    cutoff / r
                };
            }
            let combined: Vec<f64> = robust.iter().zip(&prior).map(|(a, b)| a * b).collect();
            let (next, next_scale) =
                horn_similarity(source, target, &combined, params.estimate_scale)?;
            iterations = it + 1;
            let moved = source
                .iter()
                .map(|p| {
                    let a = pose.rotation * p.coords * scale + pose.translation.vector;
                    let b = next.rotation * p.coords * next_scale + next.translation.vector;
                    (a - b).norm()
                })
                .fold(0.0, f64::max);
            pose = next;
            scale = next_scale;
            residuals = residuals_of(&pose, scale);
            if moved < params.tolerance_mm && tukey == (params.loss == RobustLoss::Tukey) {
                break;
            }
        }
    }
    let (mut sum, mut wsum) = (0.0, 0.0);
    let mut inlier_count = 0;
    for i in 0..n {
        if robust[i] > 0.5 {
            inlier_count += 1;
            sum += prior[i] * residuals[i] * residuals[i];
            wsum += prior[i];
        }
    }
    let inlier_rms = if wsum > 0.0 {
        (sum / wsum).sqrt()
    } else {
        f64::NAN
    };
    Ok(RobustFit {
        target_from_source: pose,
        scale,
        robust_weights: robust,
        inlier_count,
        residuals,
        inlier_rms,
        cutoff,
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::numeric::{SplitMix64, standard_normal};

    /// Deterministic pseudo-random numbers: uniform in [-1, 1) and standard normal.
    struct Rng(SplitMix64);
    impl Rng {
        fn new(seed: u64) -> Self {
            Self(SplitMix64::new(seed))
        }
        fn next(&mut self) -> f64 {
            self.0.uniform(-1.0, 1.0)
        }
        fn gauss(&mut self) -> f64 {
            standard_normal(&mut self.0)
        }
    }

    fn cloud(n: usize, rng: &mut Rng) -> Vec<Point3<f64>> {
        (0..n)
            .map(|_| Point3::new(rng.next() * 60.0, rng.next() * 70.0, rng.next() * 30.0))
            .collect()
    }

    fn truth() -> Isometry3<f64> {
        Isometry3::new(
            Vector3::new(12.0, -40.0, 230.0),
            Vector3::new(0.3, -2.2, 0.5),
        )
    }

    #[test]
    fn exact_data_recovered_to_1e9() {
        let mut rng = Rng::new(1);
        let p = cloud(30, &mut rng);
        let t = truth();
        let q: Vec<_> = p.iter().map(|x| t * x).collect();
        for loss in [RobustLoss::None, RobustLoss::Huber, RobustLoss::Tukey] {
            let params = RobustHornParams {
                loss,
                ..RobustHornParams::default()
            };
            let fit = robust_horn(&p, &q, &[], &params).unwrap();
            assert!(
                (fit.target_from_source.translation.vector - t.translation.vector).norm() < 1e-9
            );
            assert!(fit.target_from_source.rotation.angle_to(&t.rotation) < 1e-9);
            assert_eq!(fit.scale, 1.0);
            assert_eq!(fit.inlier_count, 30);
        }
    }

    #[test]
    fn weights_decide_between_two_motions() {
        // Half the points follow `truth`, half another motion; with weight 0 on the second
        // half the first motion is recovered exactly, and with tiny weights nearly so.
        let mut rng = Rng::new(2);
        let p = cloud(20, &mut rng);
        let t = truth();
        let other = Isometry3::new(Vector3::new(5.0, 5.0, 200.0), Vector3::new(0.0, 0.4, 0.0));
        let q: Vec<_> = p
            .iter()
            .enumerate()
            .map(|(i, x)| if i < 10 { t * x } else { other * x })
            .collect();
        let w: Vec<f64> = (0..20).map(|i| if i < 10 { 1.0 } else { 0.0 }).collect();
        let params = RobustHornParams {
            loss: RobustLoss::None,
            ..RobustHornParams::default()
        };
        let fit = robust_horn(&p, &q, &w, &params).unwrap();
        for x in &p[..10] {
            assert!((fit.apply(x) - t * x).norm() < 1e-9);
        }
        // Weighted and unweighted fits differ: the weights matter.
        let plain = robust_horn(&p, &q, &[], &params).unwrap();
        assert!((plain.apply(&p[0]) - t * p[0]).norm() > 1.0);
    }

    #[test]
    fn scale_is_estimated_only_on_request() {
        let mut rng = Rng::new(3);
        let p = cloud(15, &mut rng);
        let t = truth();
        let q: Vec<_> = p
            .iter()
            .map(|x| t * Point3::from(x.coords * 1.07))
            .collect();
        let params = RobustHornParams {
            estimate_scale: true,
            ..RobustHornParams::default()
        };
        let fit = robust_horn(&p, &q, &[], &params).unwrap();
        assert!((fit.scale - 1.07).abs() < 1e-9, "{}", fit.scale);
        for (x, y) in p.iter().zip(&q) {
            assert!((fit.apply(x) - y).norm() < 1e-9);
        }
        let rigid = robust_horn(&p, &q, &[], &RobustHornParams::default()).unwrap();
        assert_eq!(rigid.scale, 1.0);
    }

    #[test]
    fn twenty_percent_outliers_stay_within_the_noise() {
        let mut rng = Rng::new(4);
        let n = 50;
        let p = cloud(n, &mut rng);
        let t = truth();
        let sigma = 0.2;
        let mut q: Vec<_> = p
            .iter()
            .map(|x| t * x + Vector3::new(rng.gauss(), rng.gauss(), rng.gauss()) * sigma)
            .collect();
        // 20 % gross outliers: displaced by 5 to 25 mm in random directions.
        for qi in q.iter_mut().take(n / 5) {
            let d = Vector3::new(rng.next(), rng.next(), rng.next()).normalize();
            *qi += d * (15.0 + 10.0 * rng.next());
        }
        let plain = robust_horn(
            &p,
            &q,
            &[],
            &RobustHornParams {
                loss: RobustLoss::None,
                ..RobustHornParams::default()
            },
        )
        .unwrap();
        let fit = robust_horn(&p, &q, &[], &RobustHornParams::default()).unwrap();
        // Error of the fitted transform over the cloud, against the truth.
        let err = |f: &RobustFit| {
            p.iter()
                .map(|x| (f.apply(x) - t * x).norm())
                .fold(0.0, f64::max)
        };
        // The noise-only bound: a fit to 40 inliers with σ = 0.2 mm moves points by well
        // under σ; allow σ itself.
        assert!(err(&fit) < sigma, "robust error {} mm", err(&fit));
        assert!(err(&plain) > 3.0 * sigma, "plain error {} mm", err(&plain));
        // Every outlier is rejected and nearly every inlier kept.
        assert!(fit.robust_weights[..n / 5].iter().all(|&w| w == 0.0));
        assert!(fit.inlier_count >= n - n / 5 - 1, "{}", fit.inlier_count);
    }

    #[test]
    fn bad_input_is_an_error() {
        let p = [Point3::origin(); 3];
        assert!(robust_horn(&p, &p[..2], &[], &RobustHornParams::default()).is_err());
        assert!(robust_horn(&p, &p, &[0.0; 3], &RobustHornParams::default()).is_err());
    }
}
