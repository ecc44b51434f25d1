//! Temporal enhancement: sequence projection (Bermano et al. 2014 §6.1, Eq. 5-6) and
//! temporally driven keyframe interpolation (§6.2).
//!
//! # Sequence format
//! A database sequence is an ordered list of frames in the database topology, sampled
//! uniformly in time (the paper's captures go from the neutral to an extreme and back). On
//! disk (`helmcap retime --sequences DIR`) it is one sub-folder per sequence holding OBJ
//! frames, ordered by file name. [`builtin_sequences`] makes such sequences from the
//! built-in actor.

use nalgebra::{DVector, Point3};

use super::{EnhanceError, Enhancer};
use crate::dataset::actor::Actor;

/// One database sequence: frames (#V positions each, mm), uniformly sampled in time.
pub type Sequence = Vec<Vec<Point3<f64>>>;

/// Projection of `a` on the segment `{b0, b1}` (Eq. 5): the weight `t ∈ [0, 1]` of `b0`
/// minimizing ‖a − (t b0 + (1 − t) b1)‖ (the two-frame case of the convex projection of
/// §5.3, in closed form) and the distance left.
pub fn project_on_segment(a: &DVector<f64>, b0: &DVector<f64>, b1: &DVector<f64>) -> (f64, f64) {
    let d = b0 - b1;
    let dd = d.norm_squared();
    let t = if dd > 0.0 {
        ((a - b1).dot(&d) / dd).clamp(0.0, 1.0)
    } else {
        0.5
    };
    let err = (a - (b0 * t + b1 * (1.0 - t))).norm();
    (t, err)
}

/// The result of [`sequence_projection`].
#[derive(Debug, Clone, PartialEq)]
pub struct SequenceProjection {
    /// For each input frame, the segment index j (segment {β_j, β_j+1}).
    pub segments: Vec<usize>,
    /// For each input frame, the weight T_ij of β_j on its segment.
    pub weights: Vec<f64>,
    /// Σ_i E_i,P(i), the objective of Eq. (6).
    pub error: f64,
}

impl SequenceProjection {
    /// Continuous timeline position of input frame `i` on β: `j + (1 − t)` (§6.2).
    pub fn timestamp(&self, i: usize) -> f64 {
        self.segments[i] as f64 + (1.0 - self.weights[i])
    }
}

/// Projects the sequence `alpha` (m frames) on the sequence `beta` (n ≥ 2 frames) (§6.1):
/// T and E of Eq. (5) for every frame and segment, then the order-preserving assignment
/// P minimizing Σ_i E_i,P(i) subject to P(i₁) ≤ P(i₂) for i₁ < i₂ (Eq. 6), by dynamic
/// programming over prefix minima in O(m n). `None` when `beta` has fewer than 2 frames or
/// `alpha` is empty.
pub fn sequence_projection(
    alpha: &[DVector<f64>],
    beta: &[DVector<f64>],
) -> Option<SequenceProjection> {
    let m = alpha.len();
    let segs = beta.len().checked_sub(1)?;
    if m == 0 || segs == 0 {
        return None;
    }
    let mut t = vec![vec![0.0; segs]; m];
    let mut e = vec![vec![0.0; segs]; m];
    for i in 0..m {
        for j in 0..segs {
            let (w, err) = project_on_segment(&alpha[i], &beta[j], &beta[j + 1]);
            t[i][j] = w;
            e[i][j] = err;
        }
    }
    // cost[i][j]: best total for frames 0..=i with P(i) = j; arg[i][j]: best P(i−1).
    let mut cost = e[0].clone();
    let mut arg = vec![vec![0usize; segs]; m];
    for i in 1..m {
        let mut best = f64::INFINITY;
        let mut best_j = 0;
        let mut next = vec![0.0; segs];
        for j in 0..segs {
            if cost[j] < best {
                best = cost[j];
                best_j = j;
            }
            next[j] = e[i][j] + best;
            arg[i][j] = best_j;
        }
        cost = next;
    }
    let (mut j, error) = cost
        .iter()
        .copied()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(&b.1))?;
    let mut segments = vec![0; m];
    for i in (0..m).rev() {
        segments[i] = j;
        j = arg[i][j];
    }
    let weights = segments.iter().enumerate().map(|(i, &j)| t[i][j]).collect();
    Some(SequenceProjection {
        segments,
        weights,
        error,
    })
}

/// A retimed keyframe interpolation.
#[derive(Debug, Clone, PartialEq)]
pub struct Retimed {
    /// The frames (m × #V, mm): `(1 − g_k) α₀ + g_k α_m−1`.
    pub frames: Vec<Vec<Point3<f64>>>,
    /// The interpolation fraction g_k of each frame (0 at the first keyframe, 1 at the last).
    pub fractions: Vec<f64>,
    /// Index of the database sequence whose timing was used.
    pub sequence: usize,
}

/// Temporal enhancement against database sequences (Bermano et al. 2014 §6). Holds the
/// compressed shape-space vectors of every sequence frame, encoded once.
///
/// # Deviations
/// The projection runs on the whole-face compressed vector rather than per region (the
/// paper applies it per region); one timing for the whole face keeps the keyframes'
/// expression coherent, which is what an animator asking for "the actor's timing" wants.
#[derive(Debug)]
pub struct Retimer {
    sequences: Vec<Vec<DVector<f64>>>,
}

impl Retimer {
    /// Encodes `sequences` (each a list of frames, #V positions each) with `enhancer`.
    ///
    /// # Errors
    /// [`EnhanceError::Shape`] for a frame not in the database topology or a sequence
    /// shorter than 2 frames.
    pub fn new(enhancer: &Enhancer, sequences: &[Sequence]) -> Result<Self, EnhanceError> {
        let mut out = Vec::with_capacity(sequences.len());
        for s in sequences {
            if s.len() < 2 {
                return Err(EnhanceError::Shape {
                    what: "frames in a retiming sequence (at least 2)",
                    expected: 2,
                    got: s.len(),
                });
            }
            out.push(
                s.iter()
                    .map(|f| enhancer.shape_space_code(f))
                    .collect::<Result<Vec<_>, _>>()?,
            );
        }
        if out.is_empty() {
            return Err(EnhanceError::Shape {
                what: "retiming sequences",
                expected: 1,
                got: 0,
            });
        }
        Ok(Self { sequences: out })
    }

    /// Interpolates keyframes `first` and `last` over `frames` frames with the timing of
    /// the closest database subsequence (§6.2): project {α₀, α_m−1} on every sequence and
    /// keep the best; with `extend`, widen the subsequence to the sequence's whole motion
    /// from its start to its extreme (the frame farthest from its first); sample the
    /// subsequence β; project the uniform interpolation β̂ of its ends on β to get each
    /// frame's timestamp; give the linear keyframe interpolation α̂ those timestamps and
    /// resample it uniformly in time.
    ///
    /// # Errors
    /// [`EnhanceError::Shape`] for wrong vertex counts or `frames < 2`.
    pub fn retime(
        &self,
        enhancer: &Enhancer,
        first: &[Point3<f64>],
        last: &[Point3<f64>],
        frames: usize,
        extend: bool,
    ) -> Result<Retimed, EnhanceError> {
        if frames < 2 {
            return Err(EnhanceError::Shape {
                what: "retimed frames (at least 2)",
                expected: 2,
                got: frames,
            });
        }
        if first.len() != last.len() {
            return Err(EnhanceError::Shape {
                what: "keyframe vertices",
                expected: first.len(),
                got: last.len(),
            });
        }
        let keys = [
            enhancer.shape_space_code(first)?,
            enhancer.shape_space_code(last)?,
        ];
        let mut best: Option<(usize, SequenceProjection)> = None;
        for (s, seq) in self.sequences.iter().enumerate() {
            if let Some(p) = sequence_projection(&keys, seq)
                && best.as_ref().is_none_or(|b| p.error < b.1.error)
            {
                best = Some((s, p));
            }
        }
        let (sequence, proj) = best.ok_or(EnhanceError::Shape {
            what: "retiming sequences",
            expected: 1,
            got: 0,
        })?;
        let seq = &self.sequences[sequence];
        let (mut t0, mut t1) = (proj.timestamp(0), proj.timestamp(1));
        if extend {
            let far = (0..seq.len())
                .max_by(|&a, &b| {
                    (&seq[a] - &seq[0])
                        .norm()
                        .total_cmp(&(&seq[b] - &seq[0]).norm())
                })
                .unwrap_or(seq.len() - 1);
            t0 = 0.0;
            t1 = t1.max(far as f64);
        }
        let fractions = if t1 - t0 < 1e-9 {
            (0..frames)
                .map(|k| k as f64 / (frames - 1) as f64)
                .collect()
        } else {
            timing_fractions(seq, t0, t1, frames)
        };
        let out = fractions
            .iter()
            .map(|&g| {
                first
                    .iter()
                    .zip(last)
                    .map(|(a, b)| a + (b - a) * g)
                    .collect()
            })
            .collect();
        Ok(Retimed {
            frames: out,
            fractions,
            sequence,
        })
    }
}

/// Sample of `seq` at continuous time `tau` (linear between frames).
fn sample(seq: &[DVector<f64>], tau: f64) -> DVector<f64> {
    let j = (tau.floor().max(0.0) as usize).min(seq.len() - 2);
    let f = (tau - j as f64).clamp(0.0, 1.0);
    &seq[j] * (1.0 - f) + &seq[j + 1] * f
}

/// §6.2: the fraction of the way from the first to the last keyframe at each of `frames`
/// uniform times, following the timing of `seq` between times `t0` and `t1`.
fn timing_fractions(seq: &[DVector<f64>], t0: f64, t1: f64, frames: usize) -> Vec<f64> {
    // β: the subsequence, at its integer frames plus its ends.
    let mut times = vec![t0];
    let mut k = t0.floor() + 1.0;
    while k < t1 - 1e-9 {
        times.push(k);
        k += 1.0;
    }
    times.push(t1);
    let beta: Vec<DVector<f64>> = times.iter().map(|&t| sample(seq, t)).collect();
    let (b0, b1) = (&beta[0], &beta[beta.len() - 1]);
    let hat: Vec<DVector<f64>> = (0..frames)
        .map(|i| {
            let f = i as f64 / (frames - 1) as f64;
            b0 * (1.0 - f) + b1 * f
        })
        .collect();
    let Some(proj) = sequence_projection(&hat, &beta) else {
        return (0..frames)
            .map(|k| k as f64 / (frames - 1) as f64)
            .collect();
    };
    // Timestamps of α̂_i on β, normalized to [0, 1], made non-decreasing.
    let span = (beta.len() - 1) as f64;
    let mut stamps: Vec<f64> = (0..frames).map(|i| proj.timestamp(i) / span).collect();
    stamps[0] = 0.0;
    stamps[frames - 1] = 1.0;
    for i in 1..frames {
        stamps[i] = stamps[i].max(stamps[i - 1]);
    }
    // Resample the curve (time stamps[i] ↦ fraction i/(m−1)) at uniform times.
    (0..frames)
        .map(|k| {
            let u = k as f64 / (frames - 1) as f64;
            let i = stamps.partition_point(|&s| s <= u).clamp(1, frames - 1);
            let (s0, s1) = (stamps[i - 1], stamps[i]);
            let f0 = (i - 1) as f64 / (frames - 1) as f64;
            let f1 = i as f64 / (frames - 1) as f64;
            if s1 - s0 < 1e-12 {
                f1
            } else {
                f0 + (f1 - f0) * ((u - s0) / (s1 - s0)).clamp(0.0, 1.0)
            }
        })
        .collect()
}

/// Animated sequences of the built-in actor for retiming: for each of a few expressions, a
/// ramp from the neutral to the expression at full weight over `frames` frames with the
/// ease-out timing of a real onset, weight(t) = 1 − (1 − t)³ for t = k/(frames − 1)
/// (fast start, slow settle). Returns the sequences and their expression names.
pub fn builtin_sequences(actor: &Actor, frames: usize) -> (Vec<Sequence>, Vec<&'static str>) {
    let names = ["mouthSmile_L", "browInnerUp", "jawOpen", "mouthPucker"];
    let n = frames.max(2);
    let seqs = names
        .iter()
        .map(|name| {
            (0..n)
                .map(|k| {
                    let t = k as f64 / (n - 1) as f64;
                    let w = 1.0 - (1.0 - t).powi(3);
                    actor.evaluate(&actor.weights(&[(name, w)])).positions
                })
                .collect()
        })
        .collect();
    (seqs, names.to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequence_projection_is_monotone_and_exact_on_samples() {
        // β: a curve in R²; α: some of its samples, in order.
        let beta: Vec<DVector<f64>> = (0..10)
            .map(|k| {
                let x = k as f64;
                DVector::from_vec(vec![x, (x * 0.5).sin()])
            })
            .collect();
        let alpha = vec![
            beta[1].clone(),
            (&beta[4] + &beta[5]) * 0.5,
            beta[8].clone(),
        ];
        let p = sequence_projection(&alpha, &beta).unwrap();
        assert!(p.error < 1e-12);
        assert!((p.timestamp(0) - 1.0).abs() < 1e-9);
        assert!((p.timestamp(1) - 4.5).abs() < 1e-9);
        assert!((p.timestamp(2) - 8.0).abs() < 1e-9);
        assert!(p.segments.windows(2).all(|w| w[0] <= w[1]));
        assert!(sequence_projection(&alpha, &beta[..1]).is_none());
    }

    #[test]
    fn timing_follows_a_nonuniform_sequence() {
        // A straight path walked with ease-out timing: fraction(t) = 1 − (1 − t)³.
        let n = 25;
        let seq: Vec<DVector<f64>> = (0..n)
            .map(|k| {
                let t = k as f64 / (n - 1) as f64;
                DVector::from_vec(vec![1.0 - (1.0 - t).powi(3), 0.0])
            })
            .collect();
        let g = timing_fractions(&seq, 0.0, (n - 1) as f64, n);
        for (k, &gk) in g.iter().enumerate() {
            let t = k as f64 / (n - 1) as f64;
            assert!((gk - (1.0 - (1.0 - t).powi(3))).abs() < 0.03, "{k}: {gk}");
        }
    }
}
