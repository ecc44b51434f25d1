//! Region labels, named landmark vertices and the lip-side / jaw weight fields, all
//! defined on the canonical parameters so every identity shares them.

use serde::{Deserialize, Serialize};

use super::surface::{Layout, V_MIN, smoothstep};
use super::topology::{GridKind, SkinVertex, Topology, is_face};

/// Anatomical region of a vertex. `L` is the actor's left (+x), `R` the right.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Region {
    /// Forehead, between the brows and the hairline (with the glabella).
    Forehead,
    /// Left brow.
    BrowL,
    /// Right brow.
    BrowR,
    /// Left upper eyelid.
    EyelidUpperL,
    /// Right upper eyelid.
    EyelidUpperR,
    /// Left lower eyelid.
    EyelidLowerL,
    /// Right lower eyelid.
    EyelidLowerR,
    /// Nose, from the bridge to the nostrils.
    Nose,
    /// Left cheek.
    CheekL,
    /// Right cheek.
    CheekR,
    /// Upper lip with the philtrum.
    UpperLip,
    /// Lower lip.
    LowerLip,
    /// Chin.
    Chin,
    /// Jaw: the lower face beside and below the mouth, out to the jaw line.
    Jaw,
    /// Temples (both sides).
    Temple,
    /// Scalp and the back and sides of the head outside the face.
    BackOfHead,
    /// Under the jaw and the neck.
    Neck,
    /// Left eyeball.
    EyeballL,
    /// Right eyeball.
    EyeballR,
}

impl Region {
    /// Whether the region is part of the face skin (the reconstruction region).
    pub fn is_face(self) -> bool {
        !matches!(
            self,
            Region::BackOfHead | Region::Neck | Region::EyeballL | Region::EyeballR
        )
    }
}

/// Named landmark vertices of the actor (indices into the mesh), the same for every
/// identity. `_l` is the actor's left (+x).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Landmarks {
    /// Tip of the nose (pronasale).
    pub nose_tip: u32,
    /// Middle of the nose bridge.
    pub nose_bridge: u32,
    /// Root of the nose between the eyes (nasion).
    pub nasion: u32,
    /// Base of the nose above the lip (subnasale).
    pub subnasale: u32,
    /// Left nostril wing.
    pub nose_ala_l: u32,
    /// Right nostril wing.
    pub nose_ala_r: u32,
    /// Most forward point of the chin (pogonion).
    pub chin: u32,
    /// Left mouth corner (a vertex of the mouth opening).
    pub mouth_corner_l: u32,
    /// Right mouth corner.
    pub mouth_corner_r: u32,
    /// Middle of the upper lip's margin.
    pub upper_lip_centre: u32,
    /// Middle of the lower lip's margin.
    pub lower_lip_centre: u32,
    /// Left eye inner corner (medial canthus).
    pub eye_inner_l: u32,
    /// Left eye outer corner (lateral canthus).
    pub eye_outer_l: u32,
    /// Right eye inner corner.
    pub eye_inner_r: u32,
    /// Right eye outer corner.
    pub eye_outer_r: u32,
    /// Middle of the left upper eyelid margin.
    pub upper_lid_l: u32,
    /// Middle of the left lower eyelid margin.
    pub lower_lid_l: u32,
    /// Middle of the right upper eyelid margin.
    pub upper_lid_r: u32,
    /// Middle of the right lower eyelid margin.
    pub lower_lid_r: u32,
    /// Left brow, inner end.
    pub brow_inner_l: u32,
    /// Left brow, outer end.
    pub brow_outer_l: u32,
    /// Right brow, inner end.
    pub brow_inner_r: u32,
    /// Right brow, outer end.
    pub brow_outer_r: u32,
    /// Centre of the forehead.
    pub forehead_centre: u32,
    /// Left temple.
    pub temple_l: u32,
    /// Right temple.
    pub temple_r: u32,
    /// Left cheekbone.
    pub cheek_l: u32,
    /// Right cheekbone.
    pub cheek_r: u32,
    /// Left jaw angle (on the face edge).
    pub jaw_l: u32,
    /// Right jaw angle.
    pub jaw_r: u32,
}

impl Landmarks {
    /// Every landmark with its name, in declaration order.
    pub fn named(&self) -> Vec<(&'static str, u32)> {
        vec![
            ("nose_tip", self.nose_tip),
            ("nose_bridge", self.nose_bridge),
            ("nasion", self.nasion),
            ("subnasale", self.subnasale),
            ("nose_ala_l", self.nose_ala_l),
            ("nose_ala_r", self.nose_ala_r),
            ("chin", self.chin),
            ("mouth_corner_l", self.mouth_corner_l),
            ("mouth_corner_r", self.mouth_corner_r),
            ("upper_lip_centre", self.upper_lip_centre),
            ("lower_lip_centre", self.lower_lip_centre),
            ("eye_inner_l", self.eye_inner_l),
            ("eye_outer_l", self.eye_outer_l),
            ("eye_inner_r", self.eye_inner_r),
            ("eye_outer_r", self.eye_outer_r),
            ("upper_lid_l", self.upper_lid_l),
            ("lower_lid_l", self.lower_lid_l),
            ("upper_lid_r", self.upper_lid_r),
            ("lower_lid_r", self.lower_lid_r),
            ("brow_inner_l", self.brow_inner_l),
            ("brow_outer_l", self.brow_outer_l),
            ("brow_inner_r", self.brow_inner_r),
            ("brow_outer_r", self.brow_outer_r),
            ("forehead_centre", self.forehead_centre),
            ("temple_l", self.temple_l),
            ("temple_r", self.temple_r),
            ("cheek_l", self.cheek_l),
            ("cheek_r", self.cheek_r),
            ("jaw_l", self.jaw_l),
            ("jaw_r", self.jaw_r),
        ]
    }
}

/// Side of the lip line of a skin vertex: +1 on the jaw side (rows at or below the
/// mouth's lower margin), −1 above, 0 for a mouth corner.
pub(crate) fn lip_row_sign(topo: &Topology, sv: &SkinVertex) -> f64 {
    let m = &topo.openings.mouth;
    if sv.kind == GridKind::Corner && sv.row == m.row {
        0.0
    } else if sv.row <= m.row {
        1.0
    } else {
        -1.0
    }
}

/// Share of the jaw side of the lip line, 0 (upper face) to 1 (lower lip, chin): a step
/// across the mouth opening, 0.5 at the mouth corners, and beyond them a smooth
/// transition along a line rising from the corner toward the ear.
pub(crate) fn lower_share(l: &Layout, u: f64, v: f64, row_sign: f64) -> f64 {
    let au = u.abs();
    let inside = 1.0 - smoothstep(l.u_corner - 9.0, l.u_corner, au);
    let out = (au - l.u_corner).max(0.0);
    let boundary = l.v_mouth + 0.42 * out;
    let width = 5.0 + 0.3 * out;
    let ramp = 2.0 * smoothstep(-1.0, 1.0, (boundary - v) / width) - 1.0;
    0.5 + 0.5 * (inside * row_sign + (1.0 - inside) * ramp)
}

/// Jaw skinning weight of a skin vertex at canonical `(u, v)`: the jaw side of the lip
/// line, faded out behind the jaw toward the ear and down the neck.
pub(crate) fn jaw_weight(l: &Layout, u: f64, v: f64, row_sign: f64) -> f64 {
    let side = lower_share(l, u, v, row_sign);
    let lateral = 1.0 - smoothstep(90.0, 140.0, u.abs());
    let neck = smoothstep(V_MIN + 2.0, l.v_chin - 1.0, v);
    side * lateral * neck
}

/// Region of a skin vertex.
pub(crate) fn skin_region(topo: &Topology, l: &Layout, sv: &SkinVertex) -> Region {
    let (u, v) = (sv.u, sv.v);
    let au = u.abs();
    let left = u >= 0.0;
    let pick = |a: Region, b: Region| if left { a } else { b };
    if !is_face(l, u, v) {
        return if v < l.v_chin + 15.0 {
            Region::Neck
        } else {
            Region::BackOfHead
        };
    }
    let eye = &topo.openings.eyes[0];
    let du_e = au - l.u_eye;
    if du_e.abs() <= l.a_eye + 3.0 && v >= l.v_eye - 9.0 && v <= l.v_eye + 11.0 {
        let upper = sv.row > eye.row || (sv.kind == GridKind::Corner && sv.row == eye.row);
        return if upper {
            pick(Region::EyelidUpperL, Region::EyelidUpperR)
        } else {
            pick(Region::EyelidLowerL, Region::EyelidLowerR)
        };
    }
    if v >= l.v_brow - 6.0 && v <= l.v_brow + 7.0 && au >= 7.0 && au <= l.u_eye + 26.0 {
        return pick(Region::BrowL, Region::BrowR);
    }
    if au >= l.u_eye + 22.0 && v >= l.v_eye - 6.0 {
        return Region::Temple;
    }
    if v > l.v_brow + 7.0 || (au < 7.0 && v > l.v_nasion + 3.0) {
        return Region::Forehead;
    }
    if v <= l.v_nasion + 3.0 && v >= l.v_sub - 1.0 {
        let t = ((l.v_nasion - v) / (l.v_nasion - l.v_tip)).clamp(0.0, 1.0);
        let half = 9.0 + (l.u_ala + 3.0 - 9.0) * t * t;
        if au <= half {
            return Region::Nose;
        }
    }
    let sign = lip_row_sign(topo, sv);
    if sign <= 0.0 && v <= l.v_sub && au <= l.u_corner + 8.0 - 0.3 * (v - l.v_mouth).max(0.0) {
        return Region::UpperLip;
    }
    if sign >= 0.0 && v >= l.v_mouth - 11.0 && au <= l.u_corner + 6.0 {
        return Region::LowerLip;
    }
    if v < l.v_mouth - 11.0 && au < 28.0 {
        return Region::Chin;
    }
    if v < l.v_mouth + 2.0 {
        return Region::Jaw;
    }
    pick(Region::CheekL, Region::CheekR)
}

/// Landmarks on the canonical layout.
pub(crate) fn landmarks(topo: &Topology, l: &Layout) -> Landmarks {
    let nc = topo.cols.len();
    let g = |i: usize, j: usize| topo.grid_to_vertex[j * nc + i];
    // Nearest grid vertex to a canonical parameter point.
    let near = |u: f64, v: f64| -> u32 {
        let mut best = (f64::INFINITY, 0u32);
        for (k, sv) in topo.skin.iter().enumerate() {
            if sv.kind == GridKind::Pole {
                continue;
            }
            let d = (sv.u - u).powi(2) + (sv.v - v).powi(2);
            if d < best.0 {
                best = (d, k as u32);
            }
        }
        best.1
    };
    let [eye_l, eye_r] = &topo.openings.eyes;
    let mouth = &topo.openings.mouth;
    let centre_col = nc / 2;
    let lid_col = |u: f64| {
        let mut best = 0;
        for (i, &c) in topo.cols.iter().enumerate() {
            if (c - u).abs() < (topo.cols[best] - u).abs() {
                best = i;
            }
        }
        best
    };
    let (cl, cr) = (lid_col(l.u_eye), lid_col(-l.u_eye));
    Landmarks {
        nose_tip: near(0.0, l.v_tip),
        nose_bridge: near(0.0, 0.5 * (l.v_nasion + l.v_tip)),
        nasion: near(0.0, l.v_nasion),
        subnasale: near(0.0, l.v_sub),
        nose_ala_l: near(l.u_ala - 2.0, l.v_tip - 5.0),
        nose_ala_r: near(-(l.u_ala - 2.0), l.v_tip - 5.0),
        chin: near(0.0, l.v_pog),
        mouth_corner_l: g(mouth.c1, mouth.row),
        mouth_corner_r: g(mouth.c0, mouth.row),
        upper_lip_centre: g(centre_col, mouth.row + 1),
        lower_lip_centre: g(centre_col, mouth.row),
        eye_inner_l: g(eye_l.c0, eye_l.row),
        eye_outer_l: g(eye_l.c1, eye_l.row),
        eye_inner_r: g(eye_r.c1, eye_r.row),
        eye_outer_r: g(eye_r.c0, eye_r.row),
        upper_lid_l: g(cl, eye_l.row + 1),
        lower_lid_l: g(cl, eye_l.row),
        upper_lid_r: g(cr, eye_r.row + 1),
        lower_lid_r: g(cr, eye_r.row),
        brow_inner_l: near(12.0, l.v_brow),
        brow_outer_l: near(l.u_eye + 18.0, l.v_brow),
        brow_inner_r: near(-12.0, l.v_brow),
        brow_outer_r: near(-(l.u_eye + 18.0), l.v_brow),
        forehead_centre: near(0.0, 0.5 * (l.v_brow + l.v_hair)),
        temple_l: near(l.u_eye + 36.0, l.v_brow + 6.0),
        temple_r: near(-(l.u_eye + 36.0), l.v_brow + 6.0),
        cheek_l: near(l.u_eye + 12.0, l.v_eye - 22.0),
        cheek_r: near(-(l.u_eye + 12.0), l.v_eye - 22.0),
        jaw_l: near(88.0, l.v_chin + 27.0),
        jaw_r: near(-88.0, l.v_chin + 27.0),
    }
}
