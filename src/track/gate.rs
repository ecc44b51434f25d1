//! The stereo (epipolar) gate of the labeler, scaled with the measured centroid noise.
//!
//! A marker's two detections triangulate with an RMS reprojection error `e` over the two
//! images ([`crate::stereo::Bundle::reprojection_px`]). At the optimum the residual is the
//! epipolar distance `d` shared between the two images (`e = |d|/2` for equal pixel scales),
//! a one-dimensional error: with Gaussian centroid noise `e` is half-normal with scale `s`
//! (`s ≈ σ/√2` for a centroid noise `σ` per coordinate in each image). The scale is
//! estimated robustly from the residuals of confidently labeled markers (no rival in
//! either camera): `ŝ = 1.4826 · median(e)` (the median of a half-normal is `0.6745·s`),
//! over a window of the latest residuals, so that it follows the noise as frames come in.
//! The gate is `clamp(k·ŝ, floor, ceiling)`: with `k = 4` a true pair fails it with
//! probability `6·10⁻⁵`. The floor keeps the gate from collapsing on very clean images
//! (and covers the start, before any residual is known); residuals cut off by a gate
//! below the truth bias the median low only until the next update widens it.

use crate::param_error::{ParamError, positive};

/// Settings of the adaptive epipolar gate.
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct EpipolarGateParams {
    /// Scale the gate with the measured noise (false: the gate stays at the floor).
    /// Default true.
    pub adaptive: bool,
    /// `k`: the gate is `k` robust standard deviations of the residuals. Default 4.
    pub sigma_factor: f64,
    /// Smallest gate, pixels (also the gate before any residual is measured). Default 0.6.
    pub floor_px: f64,
    /// Largest gate, pixels: beyond it epipolar pairing no longer separates neighbouring
    /// dots (about a third of their 15 px spacing in the images). Default 3.
    pub ceiling_px: f64,
    /// Residuals kept for the estimate (about 20 frames of 100 markers). Default 2000.
    pub window: usize,
    /// Fewest residuals before the estimate is used. Default 30.
    pub min_samples: usize,
}

impl Default for EpipolarGateParams {
    fn default() -> Self {
        Self {
            adaptive: true,
            sigma_factor: 4.0,
            floor_px: 0.6,
            ceiling_px: 3.0,
            window: 2000,
            min_samples: 30,
        }
    }
}

impl EpipolarGateParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`ParamError`] naming the field (relative to `epipolar_gate`).
    pub fn validate(&self) -> Result<(), ParamError> {
        positive(self.sigma_factor, "sigma_factor")?;
        positive(self.floor_px, "floor_px")?;
        if !(self.ceiling_px.is_finite() && self.ceiling_px >= self.floor_px) {
            return Err(ParamError::new("ceiling_px", "must be at least floor_px"));
        }
        if self.window == 0 || self.min_samples == 0 || self.min_samples > self.window {
            return Err(ParamError::new(
                "min_samples",
                "must be positive and at most window",
            ));
        }
        Ok(())
    }
}

/// The running estimate of the residual scale and the gate it gives (module docs).
#[derive(Debug, Clone)]
pub struct EpipolarGate {
    params: EpipolarGateParams,
    /// Ring buffer of the latest residuals, pixels.
    residuals: Vec<f64>,
    /// Next slot of the ring buffer once it is full.
    next: usize,
    /// Robust scale `ŝ` of the residuals, pixels (None until `min_samples`).
    sigma: Option<f64>,
    /// Scratch for the median.
    scratch: Vec<f64>,
}

impl EpipolarGate {
    /// A gate at its floor with no residuals yet.
    pub fn new(params: EpipolarGateParams) -> Self {
        Self {
            params,
            residuals: Vec::new(),
            next: 0,
            sigma: None,
            scratch: Vec::new(),
        }
    }

    /// Adds the residuals (RMS reprojection errors, pixels) of one frame's confidently
    /// labeled markers and updates the estimate. Non-finite values are ignored.
    pub fn update(&mut self, residuals: impl IntoIterator<Item = f64>) {
        let cap = self.params.window.max(1);
        for e in residuals.into_iter().filter(|e| e.is_finite() && *e >= 0.0) {
            if self.residuals.len() < cap {
                self.residuals.push(e);
            } else {
                self.residuals[self.next] = e;
                self.next = (self.next + 1) % cap;
            }
        }
        if self.residuals.len() < self.params.min_samples {
            return;
        }
        self.scratch.clear();
        self.scratch.extend_from_slice(&self.residuals);
        let mid = self.scratch.len() / 2;
        let median = *self.scratch.select_nth_unstable_by(mid, f64::total_cmp).1;
        self.sigma = Some(1.4826 * median);
    }

    /// The robust scale `ŝ` of the residuals, pixels; None until enough are known.
    pub fn sigma_px(&self) -> Option<f64> {
        self.sigma
    }

    /// The current gate on the RMS reprojection error, pixels.
    pub fn gate_px(&self) -> f64 {
        let p = &self.params;
        match self.sigma {
            Some(s) if p.adaptive => (p.sigma_factor * s).clamp(p.floor_px, p.ceiling_px),
            _ => p.floor_px,
        }
    }

    /// Forgets every residual (the gate returns to its floor).
    pub fn clear(&mut self) {
        self.residuals.clear();
        self.next = 0;
        self.sigma = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Half-normal samples `|N(0, s²)|` (seeded generator + Box-Muller).
    fn half_normal(n: usize, s: f64, seed: u64) -> Vec<f64> {
        let mut rng: rand::rngs::StdRng = rand::SeedableRng::seed_from_u64(seed);
        let mut uniform = || rand::Rng::random::<f64>(&mut rng);
        (0..n)
            .map(|_| {
                let (u1, u2) = (uniform().max(1e-300), uniform());
                s * ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()).abs()
            })
            .collect()
    }

    #[test]
    fn gate_follows_the_noise_with_floor_and_ceiling() {
        let mut gate = EpipolarGate::new(EpipolarGateParams::default());
        assert_eq!(gate.gate_px(), 0.6);
        assert_eq!(gate.sigma_px(), None);
        // Too few residuals: still the floor.
        gate.update(half_normal(10, 0.4, 1));
        assert_eq!(gate.gate_px(), 0.6);
        // Scale 0.4 px: ŝ within 5 % of it, gate 4·ŝ ≈ 1.6 px.
        gate.update(half_normal(2000, 0.4, 2));
        let s = gate.sigma_px().unwrap();
        assert!((s - 0.4).abs() < 0.02, "{s}");
        assert!((gate.gate_px() - 4.0 * s).abs() < 1e-12);
        // Outliers (wrong pairs) in a tenth of the residuals move it by about 14 %.
        let mut mixed = half_normal(1800, 0.4, 3);
        mixed.extend(std::iter::repeat_n(5.0, 200));
        gate.update(mixed);
        let s = gate.sigma_px().unwrap();
        assert!((s - 0.4).abs() < 0.1, "{s}");
        // Clean images: the floor. The window forgets the old residuals.
        gate.update(half_normal(2000, 0.05, 4));
        assert_eq!(gate.gate_px(), 0.6);
        // Very noisy: the ceiling.
        gate.update(half_normal(2000, 2.0, 5));
        assert_eq!(gate.gate_px(), 3.0);
        // Non-adaptive: always the floor.
        let mut fixed = EpipolarGate::new(EpipolarGateParams {
            adaptive: false,
            ..Default::default()
        });
        fixed.update(half_normal(2000, 0.4, 6));
        assert_eq!(fixed.gate_px(), 0.6);
        assert!(fixed.sigma_px().is_some());
        gate.clear();
        assert_eq!(gate.gate_px(), 0.6);
    }

    #[test]
    fn a_gate_cut_below_the_noise_widens_within_a_few_updates() {
        // Noise scale 0.5 px but the gate starts at 0.6 px: only the residuals below the
        // current gate come back (as from the labeler), and the gate still converges.
        let mut gate = EpipolarGate::new(EpipolarGateParams::default());
        for round in 0..6 {
            let g = gate.gate_px();
            gate.update(
                half_normal(400, 0.5, 10 + round)
                    .into_iter()
                    .filter(|&e| e <= g),
            );
        }
        let s = gate.sigma_px().unwrap();
        assert!((s - 0.5).abs() < 0.05, "{s}");
    }

    #[test]
    fn validate_names_bad_fields() {
        assert!(EpipolarGateParams::default().validate().is_ok());
        let bad = EpipolarGateParams {
            ceiling_px: 0.1,
            ..Default::default()
        };
        assert_eq!(bad.validate().unwrap_err().key, "ceiling_px");
        let bad = EpipolarGateParams {
            min_samples: 0,
            ..Default::default()
        };
        assert!(bad.validate().is_err());
    }
}
