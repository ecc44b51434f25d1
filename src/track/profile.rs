//! The capture profile: how a rig's markers look and every detection and labeling setting,
//! in one TOML file (DESIGN.md §4, "Capture profile").
//!
//! ```toml
//! dot_diameter_mm = 2.4          # painted dot diameter
//! polarity = "dark"              # "dark" ink on skin, or "bright" (retroreflective, UV, white)
//! # color = [40, 170, 70]        # colour cameras: the dots' RGB colour (8-bit levels)
//! # channel = "green"            # colour cameras: read one channel instead of luma
//! camera_distance_mm = [100, 300] # nearest and farthest dot from the cameras
//! [detect]                       # fields of DetectParams
//! [label]                        # fields of LabelParams
//! ```
//!
//! Keys left out keep their defaults. The dot size range the detector looks for
//! ([`DetectParams::min_dot_px`], [`DetectParams::max_dot_px`]) is derived from the dot
//! diameter, the camera distances and the calibration's focal lengths unless `[detect]`
//! sets it. An unknown key, or a value out of range, is an error naming the file and key.

use std::path::{Path, PathBuf};

use crate::camera::StereoRig;
use crate::capture::GrayConversion;
use crate::param_error::ParamError;

use super::{DetectParams, LabelParams};

/// Whether the dots are darker or brighter than the skin around them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Polarity {
    /// Dark ink on skin (the default).
    #[default]
    Dark,
    /// Bright dots: retroreflective, UV-fluorescent, or white on dark make-up.
    Bright,
}

/// A colour channel of a colour camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    /// Red.
    Red,
    /// Green.
    Green,
    /// Blue.
    Blue,
}

/// Why a profile cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    /// The file cannot be read.
    #[error("capture profile {path}: {message}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The file is not a valid profile (unknown key, wrong type, value out of range).
    #[error("capture profile {path}: {message}")]
    Invalid {
        /// The file.
        path: PathBuf,
        /// What is wrong, naming the key.
        message: String,
    },
}

/// The capture profile (module docs).
#[derive(Debug, Clone, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(default, deny_unknown_fields)]
pub struct CaptureProfile {
    /// Painted dot diameter, mm. Default 2.4.
    pub dot_diameter_mm: f64,
    /// Dark or bright dots. Default dark.
    pub polarity: Polarity,
    /// Colour cameras: the dots' colour (RGB, 8-bit levels); the detector then reads the
    /// difference of hue from it (`GrayConversion::DotColor`), so the dots appear dark
    /// whatever the polarity and the light on them. Default none.
    pub color: Option<[f64; 3]>,
    /// Colour cameras: read this channel instead of luma. Default none.
    pub channel: Option<Channel>,
    /// Nearest and farthest distance of a dot from the cameras, mm (with the dot diameter
    /// and the focal length this gives the dot sizes in pixels). Default 100 to 300.
    pub camera_distance_mm: (f64, f64),
    /// Detection settings.
    pub detect: DetectParams,
    /// Labeling settings.
    pub label: LabelParams,
    /// Whether `[detect]` set the dot size range itself (then it is not derived).
    #[serde(skip)]
    dot_size_given: bool,
    /// Whether `[label.pair.triangulate]` set the depth range itself.
    #[serde(skip)]
    depth_range_given: bool,
}

impl Default for CaptureProfile {
    fn default() -> Self {
        Self {
            dot_diameter_mm: 2.4,
            polarity: Polarity::Dark,
            color: None,
            channel: None,
            camera_distance_mm: (100.0, 300.0),
            detect: DetectParams::default(),
            label: LabelParams::default(),
            dot_size_given: false,
            depth_range_given: false,
        }
    }
}

impl CaptureProfile {
    /// Reads and checks a profile file.
    ///
    /// # Errors
    /// [`ProfileError`] naming the file and the key.
    pub fn load(path: &Path) -> Result<Self, ProfileError> {
        let text = std::fs::read_to_string(path).map_err(|e| ProfileError::Io {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        Self::parse(&text, path)
    }

    /// Parses and checks a profile's text (`path` for messages).
    ///
    /// # Errors
    /// [`ProfileError::Invalid`] naming the key.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ProfileError> {
        let invalid = |message: String| ProfileError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let mut profile: Self = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].lines().count().max(1));
            let message = e.message().trim().to_string();
            invalid(match line {
                Some(l) => format!("line {l}: {message}"),
                None => message,
            })
        })?;
        let table: toml::Table = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
        profile.dot_size_given = table
            .get("detect")
            .and_then(|d| d.as_table())
            .is_some_and(|d| d.contains_key("min_dot_px") || d.contains_key("max_dot_px"));
        profile.depth_range_given = table
            .get("label")
            .and_then(|l| l.get("pair"))
            .and_then(|p| p.get("triangulate"))
            .and_then(|t| t.as_table())
            .is_some_and(|t| t.contains_key("depth_range_mm"));
        if table
            .get("label")
            .and_then(|d| d.as_table())
            .is_some_and(|d| d.contains_key("dot_diameter_mm"))
        {
            return Err(invalid(
                "[label] dot_diameter_mm: set `dot_diameter_mm` at the top level instead".into(),
            ));
        }
        if table
            .get("detect")
            .and_then(|d| d.as_table())
            .is_some_and(|d| d.contains_key("bright"))
        {
            return Err(invalid(
                "[detect] bright: set `polarity = \"bright\"` at the top level instead".into(),
            ));
        }
        profile.validate().map_err(|e| invalid(e.to_string()))?;
        Ok(profile)
    }

    /// Checks every field.
    ///
    /// # Errors
    /// [`ParamError`] naming the key (`detect.…` and `label.…` for the sections).
    pub fn validate(&self) -> Result<(), ParamError> {
        if !(self.dot_diameter_mm.is_finite()
            && self.dot_diameter_mm > 0.0
            && self.dot_diameter_mm <= 50.0)
        {
            return Err(ParamError::new(
                "dot_diameter_mm",
                format!("= {} must be a number in (0, 50]", self.dot_diameter_mm),
            ));
        }
        let (near, far) = self.camera_distance_mm;
        if !(near.is_finite() && far.is_finite() && near > 0.0 && near < far && far <= 10_000.0) {
            return Err(ParamError::new(
                "camera_distance_mm",
                format!("= [{near}, {far}] must be 0 < near < far <= 10000"),
            ));
        }
        if let Some(c) = self.color
            && !c.iter().all(|v| v.is_finite() && (0.0..=255.0).contains(v))
        {
            return Err(ParamError::new("color", "must be three levels in 0..=255"));
        }
        if self.color.is_some() && self.channel.is_some() {
            return Err(ParamError::new(
                "color",
                "and channel cannot both be set: set one",
            ));
        }
        self.detect.validate().map_err(|e| e.within("detect"))?;
        self.label.validate().map_err(|e| e.within("label"))?;
        Ok(())
    }

    /// How colour images become the grey image the detector reads.
    pub fn gray_conversion(&self) -> GrayConversion {
        match (self.color, self.channel) {
            (Some(c), _) => GrayConversion::DotColor(c),
            (None, Some(Channel::Red)) => GrayConversion::Channel(0),
            (None, Some(Channel::Green)) => GrayConversion::Channel(1),
            (None, Some(Channel::Blue)) => GrayConversion::Channel(2),
            (None, None) => GrayConversion::Luma,
        }
    }

    /// The labeling settings: `[label]` with the profile's dot diameter, and, unless
    /// `[label.pair.triangulate]` sets it, a triangulation depth range from the camera
    /// distances (from 0.3 × the nearest, for dots far off the axis of a wide lens, to
    /// 2 × the farthest).
    pub fn label_params(&self) -> LabelParams {
        let mut p = self.label.clone();
        p.dot_diameter_mm = self.dot_diameter_mm;
        if !self.depth_range_given {
            let (near, far) = self.camera_distance_mm;
            p.pair.triangulate.depth_range_mm = (0.3 * near, 2.0 * far);
        }
        p
    }

    /// The detection settings for a rig: polarity from the profile (a dot colour makes
    /// the dots dark in the converted image), and, unless `[detect]` set it, the dot size
    /// range from the dot diameter seen at the camera distances through the rig's focal
    /// lengths (see [`dot_size_range_px`]).
    pub fn detect_params(&self, rig: Option<&StereoRig>) -> DetectParams {
        let mut p = self.detect.clone();
        p.bright = self.color.is_none() && self.polarity == Polarity::Bright;
        if !self.dot_size_given
            && let Some(rig) = rig
        {
            let f_min = rig.cam0.fx().min(rig.cam1.fx());
            let f_max = rig.cam0.fx().max(rig.cam1.fx());
            let (lo, hi) =
                dot_size_range_px(self.dot_diameter_mm, self.camera_distance_mm, f_min, f_max);
            p.min_dot_px = lo;
            p.max_dot_px = hi;
        }
        p
    }
}

/// The range of dot diameters in pixels for dots of `diameter_mm` between `near` and `far`
/// mm from cameras of focal lengths `f_min..f_max` (pixels): from a dot at the far
/// distance seen through the shorter lens to one at the near distance through the longer,
/// widened by a quarter either way (lens distortion, blur, the antialiased rim). The lower
/// end never goes below 2 px (a narrower blob is not resolved as a shape).
pub fn dot_size_range_px(
    diameter_mm: f64,
    (near, far): (f64, f64),
    f_min: f64,
    f_max: f64,
) -> (f64, f64) {
    let lo = (0.75 * diameter_mm * f_min / far).max(2.0);
    let hi = (1.25 * diameter_mm * f_max / near).max(lo + 1.0);
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<CaptureProfile, ProfileError> {
        CaptureProfile::parse(text, Path::new("rig.toml"))
    }

    #[test]
    fn empty_profile_is_the_default() {
        assert_eq!(parse("").unwrap(), CaptureProfile::default());
    }

    #[test]
    fn reads_every_section_and_keeps_other_defaults() {
        let p = parse(
            "dot_diameter_mm = 3.0\npolarity = \"bright\"\n[detect]\nmin_contrast_dn = 12\n\
             [label]\ngate_px = 9.0\n[label.pair.triangulate]\nsigma_px = 0.7\n",
        )
        .unwrap();
        assert_eq!(p.dot_diameter_mm, 3.0);
        assert_eq!(p.polarity, Polarity::Bright);
        assert_eq!(p.detect.min_contrast_dn, 12);
        assert_eq!(p.detect.min_area_px, DetectParams::default().min_area_px);
        assert_eq!(p.label.gate_px, 9.0);
        assert_eq!(p.label.pair.triangulate.sigma_px, 0.7);
        assert_eq!(
            p.label.pair.triangulate.depth_range_mm,
            LabelParams::default().pair.triangulate.depth_range_mm
        );
        assert!(p.detect_params(None).bright);
    }

    #[test]
    fn unknown_keys_and_bad_values_name_the_key() {
        for (text, needle) in [
            ("dot_diameter = 2.0", "dot_diameter"),
            ("[detect]\nwindow_radius = 3", "window_radius"),
            ("[label]\ngate = 3", "gate"),
            ("dot_diameter_mm = 0.0", "dot_diameter_mm"),
            ("dot_diameter_mm = nan", "dot_diameter_mm"),
            ("polarity = \"grey\"", "grey"),
            ("camera_distance_mm = [300, 100]", "camera_distance_mm"),
            ("[detect]\nmin_area_px = 0", "detect.min_area_px"),
            ("[label]\ngate_px = -1.0", "label.gate_px"),
            (
                "[label]\nnormal_slack_deg = 120.0",
                "label.normal_slack_deg",
            ),
            (
                "[label]\nmin_roundness_ratio = 1.5",
                "label.min_roundness_ratio",
            ),
            ("color = [0, 300, 0]", "color"),
        ] {
            let e = parse(text).unwrap_err().to_string();
            assert!(e.contains(needle), "{text}: {e}");
            assert!(e.contains("rig.toml"), "{e}");
        }
    }

    #[test]
    fn shipped_profile_lists_the_defaults() {
        let text = include_str!("../../configs/profiles/default.toml");
        let shipped = parse(text).unwrap();
        // Every setting is written out, with its default value.
        let keys = |t: &toml::Table| -> Vec<String> {
            fn walk(prefix: &str, t: &toml::Table, out: &mut Vec<String>) {
                for (k, v) in t {
                    match v.as_table() {
                        Some(sub) => walk(&format!("{prefix}{k}."), sub, out),
                        None => out.push(format!("{prefix}{k}")),
                    }
                }
            }
            let mut out = Vec::new();
            walk("", t, &mut out);
            out.sort();
            out
        };
        let written: toml::Table = toml::from_str(text).unwrap();
        let all: toml::Table =
            toml::from_str(&toml::to_string(&CaptureProfile::default()).unwrap()).unwrap();
        assert_eq!(keys(&written), keys(&all));
        assert_eq!(shipped.detect, DetectParams::default());
        assert_eq!(shipped.label, LabelParams::default());
        assert_eq!(shipped.dot_diameter_mm, 2.4);
    }

    /// The `Default …` each field's documentation states, as `(field, value)`: the field
    /// names of `pub struct name` in `source`, with the words after "Default" in the doc
    /// comment above each (None when it states none).
    fn documented_defaults(source: &str, name: &str) -> Vec<(String, Option<String>)> {
        let start = source
            .find(&format!("pub struct {name} {{"))
            .unwrap_or_else(|| panic!("no struct {name}"));
        let body = &source[start..];
        let body = &body[..body.find("\n}").unwrap()];
        let mut out = Vec::new();
        let mut doc = String::new();
        for line in body.lines().skip(1) {
            let line = line.trim();
            if let Some(text) = line.strip_prefix("///") {
                doc.push(' ');
                doc.push_str(text.trim());
            } else if let Some(field) = line.strip_prefix("pub ") {
                let field = field.split(':').next().unwrap().trim().to_string();
                let stated = doc
                    .find("Default ")
                    .map(|i| doc[i + "Default ".len()..].trim().to_string());
                out.push((field, stated));
                doc.clear();
            } else if !line.starts_with("#[") {
                doc.clear();
            }
        }
        out
    }

    /// Whether the words `stated` after "Default" begin with `value` (a TOML number, a
    /// boolean, or a pair written "a to b").
    fn states(stated: &str, value: &toml::Value) -> bool {
        let number = |word: &str| -> Option<f64> {
            word.trim_end_matches(['.', ',', ':', ';']).parse().ok()
        };
        let mut words = stated.split_whitespace();
        let as_f64 = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
        match value {
            toml::Value::Boolean(b) => {
                words.next().map(|w| w.trim_end_matches(['.', ',', ':'])) == Some(&b.to_string())
            }
            toml::Value::Array(pair) if pair.len() == 2 => {
                let (a, to, b) = (words.next(), words.next(), words.next());
                to == Some("to")
                    && a.and_then(number) == as_f64(&pair[0])
                    && b.and_then(number) == as_f64(&pair[1])
            }
            v => words
                .next()
                .and_then(number)
                .is_some_and(|n| Some(n) == as_f64(v)),
        }
    }

    #[test]
    fn documented_defaults_are_the_defaults() {
        // Each setting's documentation states its default; a default changed in code and
        // not in the documentation (or the other way) is caught here, setting by setting.
        let cases = [
            (
                include_str!("detect.rs"),
                "DetectParams",
                toml::Value::try_from(DetectParams::default()).unwrap(),
            ),
            (
                include_str!("label/mod.rs"),
                "LabelParams",
                toml::Value::try_from(LabelParams::default()).unwrap(),
            ),
        ];
        let mut checked = 0;
        for (source, name, defaults) in cases {
            let fields = documented_defaults(source, name);
            assert!(fields.len() >= 10, "{name}: {fields:?}");
            for (field, stated) in fields {
                // Settings a profile does not write (set from elsewhere), and those whose
                // default is another type's.
                let Some(value) = defaults.get(&field) else {
                    continue;
                };
                let stated = stated.unwrap_or_else(|| panic!("{name}::{field} states no default"));
                if value.is_table() || stated.starts_with('[') {
                    continue;
                }
                assert!(
                    states(&stated, value),
                    "{name}::{field}: documented \"Default {stated}\", is {value}"
                );
                checked += 1;
            }
        }
        assert!(checked >= 40, "{checked}");
    }

    #[test]
    fn dot_sizes_follow_the_rig() {
        // 2.4 mm dots, 100-300 mm, a 700 px lens: 4.2 to 21 px.
        let (lo, hi) = dot_size_range_px(2.4, (100.0, 300.0), 700.0, 700.0);
        assert!(
            (lo - 4.2).abs() < 1e-9 && (hi - 21.0).abs() < 1e-9,
            "{lo} {hi}"
        );
        // Tiny dots far away never ask for blobs under 2 px.
        assert_eq!(dot_size_range_px(1.0, (200.0, 900.0), 300.0, 300.0).0, 2.0);
    }
}
