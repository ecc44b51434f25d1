//! Unreal's Live Link Face layouts: the CSV the iPhone app records (and Unreal's Live
//! Link Face importer reads) and the UDP packet it streams.
//!
//! # CSV
//! Header `Timecode,BlendShapeCount,` then the 52 ARKit curves in Apple's order
//! ([`ARKIT_NAMES`], with a capital first letter as the app writes
//! them: `EyeBlinkLeft`, ...), then `HeadYaw,HeadPitch,HeadRoll,LeftEyeYaw,LeftEyePitch,
//! LeftEyeRoll,RightEyeYaw,RightEyePitch,RightEyeRoll`. `BlendShapeCount` is 61 (52 curves
//! + 9 angles). `Timecode` is `HH:MM:SS:FF.mmm`: the timecode frame, then the position
//!   within it in thousandths (a 60 fps camera on 30 fps code writes `.000` and `.500`).
//!   Curves are written with 8 decimals; angles in radians.
//!
//! The app itself writes `JawRight` before `JawLeft` and `MouthRight` before `MouthLeft`;
//! importers match columns by name, and Apple's order is kept here.
//!
//! # UDP (version 6, the app's format, as decoded by `pylivelinkface`)
//! `u32` LE version 6, the subject's id (`$` + 36-character UUID, 37 bytes), `i32` BE
//! length of the subject name and its UTF-8 bytes, the frame time (`i32` BE frame number,
//! `f32` BE sub-frame), the frame rate (`i32` BE numerator and denominator), `u8` 61, and
//! 61 `f32` BE values in the CSV's order (52 curves, then the 9 angles).

use crate::timecode::Timecode;

use super::ARKIT_NAMES;

/// Values after the curves: head yaw, pitch, roll, left eye yaw, pitch, roll, right eye
/// yaw, pitch, roll (radians).
pub const ANGLE_NAMES: [&str; 9] = [
    "HeadYaw",
    "HeadPitch",
    "HeadRoll",
    "LeftEyeYaw",
    "LeftEyePitch",
    "LeftEyeRoll",
    "RightEyeYaw",
    "RightEyePitch",
    "RightEyeRoll",
];

/// Number of values per frame (52 curves + 9 angles).
pub const VALUE_COUNT: usize = 61;

/// A curve name as the app writes it (`eyeBlinkLeft` → `EyeBlinkLeft`).
pub fn pascal(name: &str) -> String {
    let mut c = name.chars();
    match c.next() {
        Some(f) => f.to_ascii_uppercase().to_string() + c.as_str(),
        None => String::new(),
    }
}

/// The CSV header line (without a line break).
pub fn csv_header() -> String {
    let mut cols = vec!["Timecode".to_string(), "BlendShapeCount".to_string()];
    cols.extend(ARKIT_NAMES.iter().map(|n| pascal(n)));
    cols.extend(ANGLE_NAMES.iter().map(|n| n.to_string()));
    cols.join(",")
}

/// A timecode as the app writes it: `HH:MM:SS:FF.mmm` (thousandths of the frame).
pub fn csv_timecode(tc: &Timecode) -> String {
    let p = tc.parts();
    let frac = if tc.subframes > 1 {
        (f64::from(tc.subframe) / f64::from(tc.subframes) * 1000.0).round() as u32
    } else {
        0
    };
    format!(
        "{:02}:{:02}:{:02}:{:02}.{frac:03}",
        p.hours, p.minutes, p.seconds, p.frames
    )
}

/// One CSV row: `timecode` (as [`csv_timecode`] writes it), the 52 curves (ARKit order)
/// and the 9 angles.
pub fn csv_row(timecode: &str, curves: &[f64; 52], angles: &[f64; 9]) -> String {
    let mut row = format!("{timecode},{VALUE_COUNT}");
    for v in curves.iter().chain(angles) {
        row.push_str(&format!(",{v:.8}"));
    }
    row
}

/// One Live Link Face UDP packet (see the module docs).
///
/// `subject_id` is sent as `$` + its first 36 characters (padded with `0`); `frame`
/// and `subframe` are the frame time at `fps_numerator / fps_denominator`.
pub fn udp_packet(
    subject_id: &str,
    subject_name: &str,
    frame: i32,
    subframe: f32,
    fps_numerator: i32,
    fps_denominator: i32,
    values: &[f32; VALUE_COUNT],
) -> Vec<u8> {
    let mut id: String = subject_id
        .chars()
        .filter(|c| c.is_ascii())
        .take(36)
        .collect();
    while id.len() < 36 {
        id.push('0');
    }
    let mut out = Vec::with_capacity(4 + 37 + 4 + subject_name.len() + 17 + 4 * VALUE_COUNT);
    out.extend_from_slice(&6u32.to_le_bytes());
    out.push(b'$');
    out.extend_from_slice(id.as_bytes());
    let name = subject_name.as_bytes();
    out.extend_from_slice(&(name.len() as i32).to_be_bytes());
    out.extend_from_slice(name);
    out.extend_from_slice(&frame.to_be_bytes());
    out.extend_from_slice(&subframe.to_be_bytes());
    out.extend_from_slice(&fps_numerator.to_be_bytes());
    out.extend_from_slice(&fps_denominator.to_be_bytes());
    out.push(VALUE_COUNT as u8);
    for v in values {
        out.extend_from_slice(&v.to_be_bytes());
    }
    out
}

/// Yaw, pitch and roll (radians) of a rotation in the head frame (y up, z forward out of
/// the face, x to the actor's left): yaw about y, pitch about x, roll about z, applied
/// roll, then pitch, then yaw (`R = R_y(yaw) · R_x(pitch) · R_z(roll)`).
pub fn yaw_pitch_roll(r: &nalgebra::Rotation3<f64>) -> [f64; 3] {
    let m = r.matrix();
    // R = Ry Rx Rz: m[1][2] = −sin(pitch).
    let pitch = (-m[(1, 2)]).clamp(-1.0, 1.0).asin();
    let yaw = m[(0, 2)].atan2(m[(2, 2)]);
    let roll = m[(1, 0)].atan2(m[(1, 1)]);
    [yaw, pitch, roll]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::timecode::{Timecode, TimecodeRate};
    use nalgebra::{Rotation3, Vector3};

    #[test]
    fn header_has_61_values_in_apples_order() {
        let h = csv_header();
        let cols: Vec<&str> = h.split(',').collect();
        assert_eq!(cols.len(), 2 + 61);
        assert_eq!(
            cols[..4],
            [
                "Timecode",
                "BlendShapeCount",
                "EyeBlinkLeft",
                "EyeLookDownLeft"
            ]
        );
        assert_eq!(cols[2 + 17], "JawOpen");
        assert_eq!(cols[2 + 51], "TongueOut");
        assert_eq!(cols[62], "RightEyeRoll");
    }

    #[test]
    fn timecode_with_subframes() {
        let rate = TimecodeRate::FPS_30;
        let mut tc = Timecode::from_frame_count(rate, 30 * 3600 + 7);
        assert_eq!(csv_timecode(&tc), "01:00:00:07.000");
        tc.subframes = 2;
        tc.subframe = 1;
        assert_eq!(csv_timecode(&tc), "01:00:00:07.500");
    }

    #[test]
    fn packet_layout() {
        let mut v = [0.0f32; VALUE_COUNT];
        v[17] = 0.5;
        let p = udp_packet("abc", "helmcap", 42, 0.5, 60, 1, &v);
        assert_eq!(p.len(), 4 + 37 + 4 + 7 + 17 + 4 * 61);
        assert_eq!(&p[..4], &[6, 0, 0, 0]);
        assert_eq!(p[4], b'$');
        assert_eq!(&p[41..45], &7i32.to_be_bytes());
        let at = 45 + 7;
        assert_eq!(&p[at..at + 4], &42i32.to_be_bytes());
        assert_eq!(p[at + 16], 61);
        let jaw = at + 17 + 4 * 17;
        assert_eq!(&p[jaw..jaw + 4], &0.5f32.to_be_bytes());
    }

    #[test]
    fn angles_round_trip() {
        let (yaw, pitch, roll) = (0.3, -0.2, 0.1);
        let r = Rotation3::from_axis_angle(&Vector3::y_axis(), yaw)
            * Rotation3::from_axis_angle(&Vector3::x_axis(), pitch)
            * Rotation3::from_axis_angle(&Vector3::z_axis(), roll);
        let a = yaw_pitch_roll(&r);
        for (x, y) in a.iter().zip([yaw, pitch, roll]) {
            assert!((x - y).abs() < 1e-12, "{a:?}");
        }
    }
}
