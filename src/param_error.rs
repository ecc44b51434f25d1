//! The error of a parameter set with a value out of range: which key, and what it must be.
//! The `validate()` of the tracking and alignment parameters returns it, nested sections
//! prefixing their keys ([`ParamError::within`]), so a config file's reader names the key
//! as the file writes it.

/// A parameter value outside its valid range.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{key} {requirement}")]
pub struct ParamError {
    /// The key as a config file writes it, dotted below the top level
    /// (`window_radius_px`, `horn.min_sigma_mm`, `label.epipolar_gate.floor_px`).
    pub key: String,
    /// What the value must be, with the value where that helps (`must be in 1..=100`).
    pub requirement: String,
}

impl ParamError {
    /// `key` fails `requirement`.
    pub fn new(key: impl Into<String>, requirement: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            requirement: requirement.into(),
        }
    }

    /// The same error for parameters nested under `section`: the key becomes
    /// `section.key`.
    #[must_use]
    pub fn within(self, section: &str) -> Self {
        Self {
            key: format!("{section}.{}", self.key),
            requirement: self.requirement,
        }
    }
}

/// `Ok` when `value` is finite and above 0, else the error for `key`.
///
/// # Errors
/// [`ParamError`] naming `key`.
pub fn positive(value: f64, key: &str) -> Result<(), ParamError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(ParamError::new(key, "must be positive and finite"))
    }
}

/// `Ok` when `value` is finite and at least 0, else the error for `key`.
///
/// # Errors
/// [`ParamError`] naming `key`.
pub fn non_negative(value: f64, key: &str) -> Result<(), ParamError> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(ParamError::new(key, "must be non-negative and finite"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_nest_under_their_sections() {
        let e = ParamError::new("floor_px", "must be positive")
            .within("epipolar_gate")
            .within("label");
        assert_eq!(e.key, "label.epipolar_gate.floor_px");
        assert_eq!(
            e.to_string(),
            "label.epipolar_gate.floor_px must be positive"
        );
        assert!(positive(1.0, "a").is_ok());
        assert_eq!(positive(f64::NAN, "a").unwrap_err().key, "a");
        assert!(positive(0.0, "a").is_err());
        assert!(non_negative(0.0, "b").is_ok());
        assert!(non_negative(-1e-9, "b").is_err());
        assert!(non_negative(f64::INFINITY, "b").is_err());
    }
}
