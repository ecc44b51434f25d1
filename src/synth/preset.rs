//! Named set-ups of synthetic footage spanning what real helmet rigs give: lens, image
//! size and bit depth, distance, dot size and look, skin and lighting (`helmcap synth
//! --preset NAME`).

use super::{
    BitDepth, ColorParams, LensModel, Polarity, ProfileOutput, RigParams, SkinParams, SynthParams,
};

/// A named set-up: rendering parameters and the rig.
#[derive(Debug, Clone, PartialEq)]
pub struct Preset {
    /// Name (`--preset NAME`).
    pub name: &'static str,
    /// One line on what it is.
    pub summary: &'static str,
    /// Mean time between lip presses of the expression curves, seconds (0: none; see
    /// [`super::AnimationParams::lip_press_interval_secs`]).
    pub lip_press_interval_secs: f64,
    /// Rendering parameters (every preset writes a capture profile).
    pub params: SynthParams,
    /// The rig, generated; `None`: the shipped helmet rig (`calib/helmet-fisheye.yaml`).
    pub rig: Option<RigParams>,
}

/// The preset names, in the order `--list-presets` shows them.
pub const PRESET_NAMES: [&str; 10] = [
    "clean-far",
    "near-face",
    "wide-mixed",
    "cluttered",
    "wiped-moles",
    "lip-press",
    "bright-dots",
    "color-dots",
    "mono16",
    "vga",
];

/// Every preset, in [`PRESET_NAMES`] order.
pub fn presets() -> Vec<Preset> {
    PRESET_NAMES.iter().filter_map(|n| preset(n)).collect()
}

/// The near rig shared by `near-face` and `cluttered`: 1280×1024 fisheye at 85°, 50 mm
/// baseline, 120 mm from the face.
fn near_rig() -> RigParams {
    RigParams {
        width_px: 1280,
        height_px: 1024,
        fov_deg: 85.0,
        lens: LensModel::Fisheye,
        baseline_mm: 50.0,
        convergence_mm: 120.0,
    }
}

/// The near rig's rendering: 2.6 mm dots 120 mm away (about 15 to 25 px across), 2 mm
/// and 1° of helmet slip.
fn near_params() -> SynthParams {
    SynthParams {
        face_distance_mm: 120.0,
        marker_radius_mm: 1.3,
        slip_mm: 2.0,
        slip_deg: 1.0,
        profile: ProfileOutput::Generated,
        ..SynthParams::default()
    }
}

/// The preset called `name`, or `None`.
pub fn preset(name: &str) -> Option<Preset> {
    let generated = SynthParams {
        profile: ProfileOutput::Generated,
        ..SynthParams::default()
    };
    let p = match name {
        "clean-far" => Preset {
            name: "clean-far",
            summary: "the default rendering: shipped 1280x1024 fisheye rig, face 225 mm away, \
                      2.4 mm dark dots about 7 px across, clean skin",
            lip_press_interval_secs: 0.0,
            params: generated,
            rig: None,
        },
        "near-face" => Preset {
            name: "near-face",
            summary: "face-filling near rig: 1280x1024 fisheye at 85 deg, 120 mm, 2.6 mm dots \
                      15-25 px across, 2 mm / 1 deg helmet slip",
            lip_press_interval_secs: 0.0,
            params: near_params(),
            rig: Some(near_rig()),
        },
        "wide-mixed" => Preset {
            name: "wide-mixed",
            summary: "wide 150 deg fisheye 100 mm from the face, 1600x1200: 3.5 mm dots from \
                      about 4 px (far cheek, slanted) to 30 px (nose tip) in one image",
            lip_press_interval_secs: 0.0,
            params: SynthParams {
                face_distance_mm: 100.0,
                marker_radius_mm: 1.75,
                ..generated
            },
            rig: Some(RigParams {
                width_px: 1600,
                height_px: 1200,
                fov_deg: 150.0,
                lens: LensModel::Fisheye,
                baseline_mm: 60.0,
                convergence_mm: 100.0,
            }),
        },
        "cluttered" => Preset {
            name: "cluttered",
            summary: "near-face with real skin and light: freckles, moles (some beside dots), \
                      hair across dots, pores, wet sheen, 100 Hz light flicker, boom shadow, \
                      smudged and wiped dots, defocus and motion blur",
            lip_press_interval_secs: 0.0,
            params: SynthParams {
                specular: 0.35,
                blur_px: 0.7,
                motion_blur_samples: 3,
                skin: SkinParams {
                    freckles: 400,
                    moles: 12,
                    moles_beside_dots: 0.5,
                    hair_strokes: 90,
                    hair_across_dots: 0.15,
                    pores: 0.08,
                    sheen: 1.2,
                    flicker_amplitude: 0.3,
                    flicker_hz: 100.0,
                    boom_shadow: 0.5,
                    smudged_dots: 6,
                    wiped_dots: 3,
                    ..SkinParams::default()
                },
                ..near_params()
            },
            rig: Some(near_rig()),
        },
        "wiped-moles" => Preset {
            name: "wiped-moles",
            summary: "near-face with 8 dots wiped off, one from the first frame and the others \
                      at frames up to 40 (mid-take, after they were tracked), and a mole as dark as the ink beside each \
                      (0.2-1.5 mm from where its rim was), among freckles: a missing marker \
                      must stay missing",
            lip_press_interval_secs: 0.0,
            params: SynthParams {
                skin: SkinParams {
                    freckles: 200,
                    wiped_dots: 8,
                    moles_beside_wiped_dots: true,
                    wipe_frames: (0, 40),
                    ..SkinParams::default()
                },
                ..near_params()
            },
            rig: Some(near_rig()),
        },
        "lip-press" => Preset {
            name: "lip-press",
            summary: "near-face with the lips pressed together about every half second, \
                      hiding the dots on them for up to half a second, and a mole as dark as \
                      the ink beside one dot in three (0.2-1.5 mm from its rim), among \
                      freckles: a dot back from behind the lip must not be a mole",
            lip_press_interval_secs: 0.5,
            params: SynthParams {
                skin: SkinParams {
                    freckles: 200,
                    moles: 40,
                    moles_beside_dots: 1.0,
                    ..SkinParams::default()
                },
                ..near_params()
            },
            rig: Some(near_rig()),
        },
        "bright-dots" => Preset {
            name: "bright-dots",
            summary: "retroreflective 3 mm dots under the ring light, bright on darker skin \
                      (shipped rig, 200 mm)",
            lip_press_interval_secs: 0.0,
            params: SynthParams {
                face_distance_mm: 200.0,
                marker_radius_mm: 1.5,
                polarity: Polarity::Bright,
                exposure_dn: 150.0,
                ..generated
            },
            rig: None,
        },
        "color-dots" => Preset {
            name: "color-dots",
            summary: "RGB camera (1280x1024 pinhole at 90 deg, 180 mm), skin-coloured face, \
                      green 2.4 mm dots",
            lip_press_interval_secs: 0.0,
            params: SynthParams {
                face_distance_mm: 180.0,
                color: Some(ColorParams::default()),
                ..generated
            },
            rig: Some(RigParams {
                fov_deg: 90.0,
                lens: LensModel::Pinhole,
                baseline_mm: 60.0,
                convergence_mm: 180.0,
                ..RigParams::default()
            }),
        },
        "mono16" => Preset {
            name: "mono16",
            summary: "machine-vision 2448x2048 monochrome camera, 12-bit data in 16-bit PNG, \
                      pinhole at 100 deg, 200 mm",
            lip_press_interval_secs: 0.0,
            params: SynthParams {
                face_distance_mm: 200.0,
                bit_depth: BitDepth::Twelve,
                ..generated
            },
            rig: Some(RigParams {
                width_px: 2448,
                height_px: 2048,
                fov_deg: 100.0,
                lens: LensModel::Pinhole,
                baseline_mm: 70.0,
                convergence_mm: 200.0,
            }),
        },
        "vga" => Preset {
            name: "vga",
            summary: "low-resolution 640x480 pinhole camera at 80 deg, 180 mm, 3 mm dots about \
                      6 px across",
            lip_press_interval_secs: 0.0,
            params: SynthParams {
                face_distance_mm: 180.0,
                marker_radius_mm: 1.5,
                ..generated
            },
            rig: Some(RigParams {
                width_px: 640,
                height_px: 480,
                fov_deg: 80.0,
                lens: LensModel::Pinhole,
                baseline_mm: 60.0,
                convergence_mm: 180.0,
            }),
        },
        _ => return None,
    };
    Some(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_preset_is_valid_and_named() {
        let all = presets();
        assert_eq!(all.len(), PRESET_NAMES.len());
        for p in &all {
            p.params.validate().unwrap();
            if let Some(r) = &p.rig {
                r.build().unwrap();
                assert_eq!(r.convergence_mm, p.params.face_distance_mm, "{}", p.name);
            }
            assert_eq!(p.params.profile, ProfileOutput::Generated);
        }
        assert!(preset("nope").is_none());
    }

    #[test]
    fn clean_far_is_the_default_rendering() {
        let p = preset("clean-far").unwrap();
        assert_eq!(
            SynthParams {
                profile: ProfileOutput::None,
                ..p.params
            },
            SynthParams::default()
        );
        assert!(p.rig.is_none());
    }

    #[test]
    fn rigs_span_real_ones() {
        // Sizes, lenses and dot sizes from the brief: 640x480 to 2448x2048, 60-160 deg,
        // 1.5-4 mm dots, 100-250 mm.
        let all = presets();
        let sizes: Vec<(u32, u32)> = all
            .iter()
            .filter_map(|p| p.rig.as_ref().map(|r| (r.width_px, r.height_px)))
            .collect();
        assert!(sizes.contains(&(640, 480)) && sizes.contains(&(2448, 2048)));
        for p in &all {
            let d = p.params.dot_diameter_mm();
            assert!((1.5..=4.0).contains(&d), "{} {d}", p.name);
            assert!((100.0..=250.0).contains(&p.params.face_distance_mm));
            if let Some(r) = &p.rig {
                assert!((60.0..=160.0).contains(&r.fov_deg));
            }
        }
    }
}
