//! Expression curves for synthetic performances: smooth random curves with blinks, or
//! weights read from a CSV file.

use std::path::Path;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::SynthError;

/// Parameters of the random performance.
#[derive(Debug, Clone, PartialEq)]
pub struct AnimationParams {
    /// Seed of the random curves. Default 1.
    pub seed: u64,
    /// Mean time between expression keys, seconds. Default 0.8.
    pub key_interval_secs: f64,
    /// Probability that an expression is active at a key. Default 0.12.
    pub active_probability: f64,
    /// Largest weight of a random key. Default 0.8.
    pub max_weight: f64,
    /// Cap on the sum of all random weights at a key (keeps poses plausible). Default 2.0.
    pub max_weight_sum: f64,
    /// Time at neutral before expressions fade in, seconds (a real take starts near
    /// neutral). Default 0.5.
    pub neutral_lead_secs: f64,
    /// Mean time between blinks, seconds (0: no blinks). Default 2.5.
    pub blink_interval_secs: f64,
    /// Duration of one blink (close and open), seconds. Default 0.25.
    pub blink_duration_secs: f64,
    /// Mean time between lip presses (`mouthPress_L`/`_R` with `mouthRollLower`, the
    /// lips squeezed together: lip contact), seconds (0: none beyond the random keys).
    /// Default 0.
    pub lip_press_interval_secs: f64,
    /// Duration of one lip press (in and out), seconds. Default 0.6.
    pub lip_press_duration_secs: f64,
}

impl Default for AnimationParams {
    fn default() -> Self {
        Self {
            seed: 1,
            key_interval_secs: 0.8,
            active_probability: 0.12,
            max_weight: 0.8,
            max_weight_sum: 2.0,
            neutral_lead_secs: 0.5,
            blink_interval_secs: 2.5,
            blink_duration_secs: 0.25,
            lip_press_interval_secs: 0.0,
            lip_press_duration_secs: 0.6,
        }
    }
}

impl AnimationParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`SynthError::Params`] naming the field.
    pub fn validate(&self) -> Result<(), SynthError> {
        let bad = |field: &str| {
            Err(SynthError::Params(format!(
                "animation: {field} out of range"
            )))
        };
        if not_positive(self.key_interval_secs) {
            return bad("key_interval_secs");
        }
        if !(0.0..=1.0).contains(&self.active_probability) {
            return bad("active_probability");
        }
        if !(0.0..=1.0).contains(&self.max_weight) {
            return bad("max_weight");
        }
        if not_positive(self.max_weight_sum) {
            return bad("max_weight_sum");
        }
        if not_non_negative(self.neutral_lead_secs) {
            return bad("neutral_lead_secs");
        }
        if not_non_negative(self.blink_interval_secs) {
            return bad("blink_interval_secs");
        }
        if not_positive(self.blink_duration_secs) {
            return bad("blink_duration_secs");
        }
        if not_non_negative(self.lip_press_interval_secs) {
            return bad("lip_press_interval_secs");
        }
        if not_positive(self.lip_press_duration_secs) {
            return bad("lip_press_duration_secs");
        }
        Ok(())
    }
}

/// True unless `v > 0` (NaN included).
fn not_positive(v: f64) -> bool {
    v.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater)
}

/// True unless `v ≥ 0` (NaN included).
fn not_non_negative(v: f64) -> bool {
    v.is_nan() || v < 0.0
}

/// `3s² − 2s³` on [0, 1], clamped outside.
fn smoothstep(s: f64) -> f64 {
    let s = s.clamp(0.0, 1.0);
    s * s * (3.0 - 2.0 * s)
}

/// Weights per frame (frames × expressions), smooth random curves: keys at jittered
/// intervals, each expression active with some probability, eased between keys with
/// smoothstep; blinks (both eyes, `eyeBlink_L` / `eyeBlink_R` when the names have them)
/// at random intervals; everything faded in after a neutral lead.
pub fn random_curves(
    names: &[&str],
    frame_count: usize,
    fps: f64,
    params: &AnimationParams,
) -> Vec<Vec<f64>> {
    let mut rng = StdRng::seed_from_u64(params.seed);
    let duration = frame_count as f64 / fps;
    let blink: Vec<usize> = names
        .iter()
        .enumerate()
        .filter(|(_, n)| n.starts_with("eyeBlink"))
        .map(|(i, _)| i)
        .collect();
    // Keys: (time, weights).
    let mut keys: Vec<(f64, Vec<f64>)> = vec![(0.0, vec![0.0; names.len()])];
    let mut t = params.neutral_lead_secs;
    keys.push((t, vec![0.0; names.len()]));
    while t <= duration {
        t += params.key_interval_secs * rng.random_range(0.6..1.4);
        let mut w: Vec<f64> = (0..names.len())
            .map(|i| {
                if blink.contains(&i) || !rng.random_bool(params.active_probability) {
                    0.0
                } else {
                    rng.random_range(0.15..=params.max_weight.max(0.15))
                }
            })
            .collect();
        let sum: f64 = w.iter().sum();
        if sum > params.max_weight_sum {
            w.iter_mut().for_each(|x| *x *= params.max_weight_sum / sum);
        }
        keys.push((t, w));
    }
    let mut blinks = Vec::new();
    if params.blink_interval_secs > 0.0 && !blink.is_empty() {
        let mut tb = params.neutral_lead_secs + rng.random_range(0.2..1.0);
        while tb < duration {
            blinks.push(tb);
            tb += params.blink_interval_secs * rng.random_range(0.5..1.5);
        }
    }
    // Lip presses are drawn after the blinks so that sessions without them keep their
    // exact curves.
    let press: Vec<(usize, f64)> = names
        .iter()
        .enumerate()
        .filter_map(|(i, n)| match *n {
            "mouthPress_L" | "mouthPress_R" => Some((i, 0.9)),
            "mouthRollLower" => Some((i, 0.5)),
            _ => None,
        })
        .collect();
    let mut presses = Vec::new();
    if params.lip_press_interval_secs > 0.0 && !press.is_empty() {
        let mut tp = params.neutral_lead_secs + rng.random_range(0.3..1.0);
        while tp < duration {
            presses.push(tp);
            tp += params.lip_press_interval_secs * rng.random_range(0.5..1.5);
        }
    }
    (0..frame_count)
        .map(|f| {
            let t = f as f64 / fps;
            let k = keys.partition_point(|(kt, _)| *kt <= t).max(1);
            let (t0, w0) = &keys[k - 1];
            let mut w = match keys.get(k) {
                Some((t1, w1)) => {
                    let s = smoothstep((t - t0) / (t1 - t0));
                    w0.iter().zip(w1).map(|(a, b)| a + (b - a) * s).collect()
                }
                None => w0.clone(),
            };
            let closure = blinks
                .iter()
                .map(|&tb| {
                    let s = (t - tb) / params.blink_duration_secs;
                    if (0.0..=1.0).contains(&s) {
                        smoothstep(1.0 - (2.0 * s - 1.0).abs())
                    } else {
                        0.0
                    }
                })
                .fold(0.0, f64::max);
            for &i in &blink {
                w[i] = closure;
            }
            let pressed = presses
                .iter()
                .map(|&tp| {
                    let s = (t - tp) / params.lip_press_duration_secs;
                    if (0.0..=1.0).contains(&s) {
                        smoothstep(2.0 * (1.0 - (2.0 * s - 1.0).abs()))
                    } else {
                        0.0
                    }
                })
                .fold(0.0, f64::max);
            for &(i, peak) in &press {
                w[i] = w[i].max(peak * pressed);
            }
            w
        })
        .collect()
}

/// Reads weights from a CSV file: header `frame,<expression>,...`, one row per frame,
/// frames 0, 1, 2, ... in order. Columns not in `names` are an error; expressions without a
/// column stay 0.
///
/// # Errors
/// [`SynthError::Weights`] naming the file and line.
pub fn read_weights_csv(path: &Path, names: &[&str]) -> Result<Vec<Vec<f64>>, SynthError> {
    let err = |line: usize, message: String| SynthError::Weights {
        path: path.to_path_buf(),
        line,
        message,
    };
    let text = std::fs::read_to_string(path).map_err(|e| err(0, e.to_string()))?;
    let mut lines = text.lines().enumerate();
    let header = lines
        .next()
        .map(|(_, h)| h)
        .ok_or_else(|| err(1, "empty file".into()))?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    if cols.first() != Some(&"frame") {
        return Err(err(1, "the header must start with `frame`".into()));
    }
    let index: Vec<usize> = cols[1..]
        .iter()
        .map(|c| {
            names
                .iter()
                .position(|n| n == c)
                .ok_or_else(|| err(1, format!("unknown expression `{c}`")))
        })
        .collect::<Result<_, _>>()?;
    let mut out = Vec::new();
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != cols.len() {
            return Err(err(
                i + 1,
                format!("{} fields, header has {}", fields.len(), cols.len()),
            ));
        }
        let frame: usize = fields[0].parse().map_err(|_| {
            err(
                i + 1,
                format!("frame {:?} is not a whole number", fields[0]),
            )
        })?;
        if frame != out.len() {
            return Err(err(
                i + 1,
                format!("expected frame {}, found {frame}", out.len()),
            ));
        }
        let mut w = vec![0.0; names.len()];
        for (&k, s) in index.iter().zip(&fields[1..]) {
            w[k] = s
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| err(i + 1, format!("{s:?} is not a number")))?;
        }
        out.push(w);
    }
    if out.is_empty() {
        return Err(err(2, "no frames".into()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const NAMES: [&str; 4] = ["jawOpen", "eyeBlink_L", "eyeBlink_R", "mouthSmile_L"];

    #[test]
    fn curves_start_neutral_are_smooth_and_blink() {
        let p = AnimationParams::default();
        let w = random_curves(&NAMES, 600, 60.0, &p);
        assert_eq!(w.len(), 600);
        assert!(w[0].iter().all(|&x| x == 0.0));
        assert!(w[20].iter().all(|&x| x == 0.0), "neutral lead");
        let max_step = w
            .windows(2)
            .flat_map(|p| {
                p[0].iter()
                    .zip(&p[1])
                    .map(|(a, b)| (a - b).abs())
                    .collect::<Vec<_>>()
            })
            .fold(0.0, f64::max);
        // A blink closes in 0.125 s = 7.5 frames: steps stay below 0.5.
        assert!(max_step < 0.5, "{max_step}");
        assert!(w.iter().any(|x| x[1] > 0.99 && x[2] > 0.99), "a full blink");
        assert!(
            w.iter().any(|x| x[0] > 0.1 || x[3] > 0.1),
            "some expression"
        );
    }

    #[test]
    fn lip_presses_when_asked() {
        let names = ["jawOpen", "mouthPress_L", "mouthPress_R", "mouthRollLower"];
        let off = random_curves(&names, 600, 60.0, &AnimationParams::default());
        let p = AnimationParams {
            lip_press_interval_secs: 2.0,
            ..Default::default()
        };
        let on = random_curves(&names, 600, 60.0, &p);
        let pressed = |w: &Vec<Vec<f64>>| w.iter().filter(|x| x[1] > 0.85 && x[2] > 0.85).count();
        assert!(pressed(&on) >= 20, "{}", pressed(&on));
        assert!(pressed(&on) > pressed(&off));
        assert!(on[20].iter().all(|&x| x == 0.0), "neutral lead");
    }

    #[test]
    fn weights_csv() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.csv");
        std::fs::write(&path, "frame,jawOpen,eyeBlink_L\n0,0.5,0\n1,0.25,1\n").unwrap();
        let w = read_weights_csv(&path, &NAMES).unwrap();
        assert_eq!(w, vec![vec![0.5, 0.0, 0.0, 0.0], vec![0.25, 1.0, 0.0, 0.0]]);
        std::fs::write(&path, "frame,jawClose\n0,0.5\n").unwrap();
        let e = read_weights_csv(&path, &NAMES).unwrap_err().to_string();
        assert!(e.contains("jawClose") && e.contains(":1"), "{e}");
        std::fs::write(&path, "frame,jawOpen\n0,0.5\n2,x\n").unwrap();
        let e = read_weights_csv(&path, &NAMES).unwrap_err().to_string();
        assert!(e.contains(":3"), "{e}");
    }
}
