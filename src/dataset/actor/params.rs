//! Identity parameters of the synthetic actor and their validation.

use serde::{Deserialize, Serialize};

use super::ActorError;
use crate::numeric::SplitMix64;

/// Identity proportions of the built-in synthetic actor.
///
/// Every length is in millimetres, measured roughly as an anthropometrist would on the
/// neutral face (the generator places features from these values on a smooth base head,
/// so a measurement on the finished mesh lands within a few millimetres of the value).
/// Every identity has the same topology: only vertex positions depend on these fields.
///
/// # Example
/// ```
/// use helmcap::dataset::actor::ActorParams;
/// let params = ActorParams::from_seed(7);
/// assert!(params.validate().is_ok());
/// assert_ne!(params, ActorParams::default());
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ActorParams {
    /// Maximum head breadth (left to right), mm. Default 152.
    pub head_width_mm: f64,
    /// Head height from the chin (menton) to the crown, mm. Default 230.
    pub head_height_mm: f64,
    /// Head depth from the brow (glabella) to the back of the head, mm. Default 195.
    pub head_depth_mm: f64,
    /// Face length from the nose bridge (nasion) to the chin (menton), mm. Default 120.
    pub face_length_mm: f64,
    /// Nose length from the nasion down to the nose tip (vertical), mm. Default 44.
    pub nose_length_mm: f64,
    /// How far the nose tip stands out of the face below it, mm. Default 21.
    pub nose_protrusion_mm: f64,
    /// Width across the nostril wings (alae), mm. Default 34.
    pub nose_width_mm: f64,
    /// Width of the lower face at the jaw angles, mm. Default 108.
    pub jaw_width_mm: f64,
    /// Mouth width from corner to corner, mm. Default 50.
    pub lip_width_mm: f64,
    /// How far the lip vermilion bulges out of the mouth area, mm. Default 4.
    pub lip_fullness_mm: f64,
    /// Distance between the eye centres (interpupillary distance), mm. Default 63.
    pub eye_spacing_mm: f64,
    /// Height of the brow ridge above the surrounding forehead, mm. Default 5.
    pub brow_prominence_mm: f64,
    /// Fullness of the cheekbones and cheeks, mm. Default 5.
    pub cheek_fullness_mm: f64,
    /// Forward prominence of the chin boss, mm. Default 4.
    pub chin_prominence_mm: f64,
    /// Scale of every expression wrinkle's depth (1 = furrows of about 0.8 mm), unitless.
    /// Default 1. Zero gives an actor without fine detail.
    pub wrinkle_depth_scale: f64,
    /// Seed of the identity's wrinkle placement (spacing, phases, arches). Default 0.
    pub seed: u64,
}

impl Default for ActorParams {
    fn default() -> Self {
        Self {
            head_width_mm: 152.0,
            head_height_mm: 230.0,
            head_depth_mm: 195.0,
            face_length_mm: 120.0,
            nose_length_mm: 44.0,
            nose_protrusion_mm: 21.0,
            nose_width_mm: 34.0,
            jaw_width_mm: 108.0,
            lip_width_mm: 50.0,
            lip_fullness_mm: 4.0,
            eye_spacing_mm: 63.0,
            brow_prominence_mm: 5.0,
            cheek_fullness_mm: 5.0,
            chin_prominence_mm: 4.0,
            wrinkle_depth_scale: 1.0,
            seed: 0,
        }
    }
}

/// One numeric field: its name, accessor and the accepted closed range.
struct FieldRange {
    name: &'static str,
    get: fn(&ActorParams) -> f64,
    min: f64,
    max: f64,
}

/// Accepted ranges: roughly ±25 % around the default for proportions (a wider range
/// than [`ActorParams::from_seed`] draws from), so every accepted identity keeps the
/// generator's smooth maps monotone and the mesh free of fold-overs.
const RANGES: [FieldRange; 15] = [
    FieldRange {
        name: "head_width_mm",
        get: |p| p.head_width_mm,
        min: 120.0,
        max: 185.0,
    },
    FieldRange {
        name: "head_height_mm",
        get: |p| p.head_height_mm,
        min: 190.0,
        max: 270.0,
    },
    FieldRange {
        name: "head_depth_mm",
        get: |p| p.head_depth_mm,
        min: 160.0,
        max: 230.0,
    },
    FieldRange {
        name: "face_length_mm",
        get: |p| p.face_length_mm,
        min: 100.0,
        max: 140.0,
    },
    FieldRange {
        name: "nose_length_mm",
        get: |p| p.nose_length_mm,
        min: 34.0,
        max: 56.0,
    },
    FieldRange {
        name: "nose_protrusion_mm",
        get: |p| p.nose_protrusion_mm,
        min: 14.0,
        max: 28.0,
    },
    FieldRange {
        name: "nose_width_mm",
        get: |p| p.nose_width_mm,
        min: 26.0,
        max: 44.0,
    },
    FieldRange {
        name: "jaw_width_mm",
        get: |p| p.jaw_width_mm,
        min: 85.0,
        max: 135.0,
    },
    FieldRange {
        name: "lip_width_mm",
        get: |p| p.lip_width_mm,
        min: 40.0,
        max: 62.0,
    },
    FieldRange {
        name: "lip_fullness_mm",
        get: |p| p.lip_fullness_mm,
        min: 1.0,
        max: 8.0,
    },
    FieldRange {
        name: "eye_spacing_mm",
        get: |p| p.eye_spacing_mm,
        min: 54.0,
        max: 74.0,
    },
    FieldRange {
        name: "brow_prominence_mm",
        get: |p| p.brow_prominence_mm,
        min: 0.0,
        max: 10.0,
    },
    FieldRange {
        name: "cheek_fullness_mm",
        get: |p| p.cheek_fullness_mm,
        min: 0.0,
        max: 10.0,
    },
    FieldRange {
        name: "chin_prominence_mm",
        get: |p| p.chin_prominence_mm,
        min: 0.0,
        max: 9.0,
    },
    FieldRange {
        name: "wrinkle_depth_scale",
        get: |p| p.wrinkle_depth_scale,
        min: 0.0,
        max: 3.0,
    },
];

impl ActorParams {
    /// A plausible identity drawn deterministically from `seed`.
    ///
    /// Each proportion is the default scaled by a factor in [0.88, 1.12] (the feature
    /// amplitudes brow, cheek, chin and lip fullness in [0.7, 1.3]); the wrinkle
    /// placement uses `seed` too. The same seed always gives the same identity.
    pub fn from_seed(seed: u64) -> Self {
        let mut rng = SplitMix64::new(seed ^ 0x6163_746f_725f_6964);
        let d = Self::default();
        let mut prop = |x: f64| x * rng.uniform(0.88, 1.12);
        let head_width_mm = prop(d.head_width_mm);
        let head_height_mm = prop(d.head_height_mm);
        let head_depth_mm = prop(d.head_depth_mm);
        let face_length_mm = prop(d.face_length_mm);
        let nose_length_mm = prop(d.nose_length_mm);
        let nose_protrusion_mm = prop(d.nose_protrusion_mm);
        let nose_width_mm = prop(d.nose_width_mm);
        let jaw_width_mm = prop(d.jaw_width_mm);
        let lip_width_mm = prop(d.lip_width_mm);
        let eye_spacing_mm = prop(d.eye_spacing_mm);
        let mut amp = |x: f64| x * rng.uniform(0.7, 1.3);
        let lip_fullness_mm = amp(d.lip_fullness_mm);
        let brow_prominence_mm = amp(d.brow_prominence_mm);
        let cheek_fullness_mm = amp(d.cheek_fullness_mm);
        let chin_prominence_mm = amp(d.chin_prominence_mm);
        let wrinkle_depth_scale = amp(d.wrinkle_depth_scale);
        Self {
            head_width_mm,
            head_height_mm,
            head_depth_mm,
            face_length_mm,
            nose_length_mm,
            nose_protrusion_mm,
            nose_width_mm,
            jaw_width_mm,
            lip_width_mm,
            lip_fullness_mm,
            eye_spacing_mm,
            brow_prominence_mm,
            cheek_fullness_mm,
            chin_prominence_mm,
            wrinkle_depth_scale,
            seed,
        }
    }

    /// Checks every field against its accepted range and the proportions against each
    /// other.
    ///
    /// # Errors
    /// [`ActorError::InvalidParam`] naming the first bad field: not finite, outside its
    /// range, or inconsistent with another field (mouth wider than the jaw allows, eyes
    /// too wide for the head, nose too long for the face).
    pub fn validate(&self) -> Result<(), ActorError> {
        for r in &RANGES {
            let value = (r.get)(self);
            if !value.is_finite() {
                return Err(ActorError::invalid(r.name, value, "not a finite number"));
            }
            if value < r.min || value > r.max {
                return Err(ActorError::invalid(
                    r.name,
                    value,
                    format!("outside the accepted range [{}, {}]", r.min, r.max),
                ));
            }
        }
        if self.lip_width_mm > self.jaw_width_mm - 40.0 {
            return Err(ActorError::invalid(
                "lip_width_mm",
                self.lip_width_mm,
                format!(
                    "must be at least 40 mm less than jaw_width_mm ({})",
                    self.jaw_width_mm
                ),
            ));
        }
        if self.eye_spacing_mm > self.head_width_mm - 70.0 {
            return Err(ActorError::invalid(
                "eye_spacing_mm",
                self.eye_spacing_mm,
                format!(
                    "must be at least 70 mm less than head_width_mm ({})",
                    self.head_width_mm
                ),
            ));
        }
        if self.nose_length_mm > 0.45 * self.face_length_mm {
            return Err(ActorError::invalid(
                "nose_length_mm",
                self.nose_length_mm,
                format!(
                    "must be at most 45 % of face_length_mm ({})",
                    self.face_length_mm
                ),
            ));
        }
        if self.face_length_mm > 0.6 * self.head_height_mm {
            return Err(ActorError::invalid(
                "face_length_mm",
                self.face_length_mm,
                format!(
                    "must be at most 60 % of head_height_mm ({})",
                    self.head_height_mm
                ),
            ));
        }
        Ok(())
    }
}
