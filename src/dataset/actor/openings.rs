//! The eye and mouth openings: slits in the parameter grid, opened by a vertical warp.
//!
//! Each opening is one row of grid cells left out between rows `j` and `j + 1`, from
//! corner column `c0` to `c1`; the two corner vertices of each end are merged into one
//! (the canthus, the mouth corner). The lower margin is row `j`, the upper row `j + 1`.
//! A warp `v ↦ v + δ(u, v)` moves the two margin rows onto the margin curves (an almond
//! for an eye, the lip line for the mouth) and drags the neighbouring rows along with a
//! smooth falloff whose slope stays below 1, so rows never cross and the parameter
//! layout (also the UV layout) stays free of fold-overs.
//!
//! The eyelids move by warping again with another [`LidState`]: the upper margin slides
//! down over the eyelid sphere to meet the lower one, so a blink closes the opening.

use super::surface::{Layout, smoothstep};

/// Eyelid configuration of one eye.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct LidState {
    /// 0 = open (neutral), 1 = upper margin down on the lower margin.
    pub close: f64,
    /// Lower lid raise as a fraction of its neutral drop below the eye axis (negative
    /// lowers it).
    pub raise: f64,
    /// Upper lid raise as a fraction of its neutral height (eyes wide open).
    pub wide: f64,
}

/// Gap between upper and lower margin of a fully closed eye, parameter mm.
const CLOSED_GAP: f64 = 0.25;

/// One slit and its warp.
#[derive(Debug, Clone)]
pub(crate) struct SlitWarp {
    /// +1 for the left eye (+u), −1 for the right eye, 0 for the mouth.
    side: f64,
    /// Grid row of the lower margin.
    pub row: usize,
    /// Corner columns (c0 < c1).
    pub c0: usize,
    /// Corner column on the +u side.
    pub c1: usize,
    u_mid: f64,
    half_width: f64,
    v_lo_row: f64,
    v_hi_row: f64,
    v_axis: f64,
    tilt: f64,
    corner_lift: f64,
    h_up: f64,
    h_lo: f64,
    gap: f64,
    fall_up: f64,
    fall_lo: f64,
    taper: f64,
}

/// Both eyes and the mouth.
#[derive(Debug, Clone)]
pub(crate) struct Openings {
    /// Left (+x) and right eye.
    pub eyes: [SlitWarp; 2],
    /// The mouth.
    pub mouth: SlitWarp,
}

impl SlitWarp {
    /// An eye slit. `side` +1 left, −1 right.
    pub(crate) fn eye(
        side: f64,
        row: usize,
        c0: usize,
        c1: usize,
        cols: &[f64],
        rows: &[f64],
        canon: &Layout,
    ) -> Self {
        Self {
            side,
            row,
            c0,
            c1,
            u_mid: 0.5 * (cols[c0] + cols[c1]),
            half_width: 0.5 * (cols[c1] - cols[c0]),
            v_lo_row: rows[row],
            v_hi_row: rows[row + 1],
            v_axis: canon.v_eye,
            tilt: 0.07,
            corner_lift: 0.0,
            h_up: 5.0,
            h_lo: 4.0,
            gap: 0.3,
            fall_up: 15.0,
            fall_lo: 10.0,
            taper: 7.0,
        }
    }

    /// The mouth slit.
    pub(crate) fn mouth(
        row: usize,
        c0: usize,
        c1: usize,
        cols: &[f64],
        rows: &[f64],
        canon: &Layout,
    ) -> Self {
        Self {
            side: 0.0,
            row,
            c0,
            c1,
            u_mid: 0.5 * (cols[c0] + cols[c1]),
            half_width: 0.5 * (cols[c1] - cols[c0]),
            v_lo_row: rows[row],
            v_hi_row: rows[row + 1],
            v_axis: canon.v_mouth,
            tilt: 0.0,
            corner_lift: 1.2,
            h_up: 0.0,
            h_lo: 0.0,
            gap: 0.4,
            fall_up: 5.0,
            fall_lo: 5.0,
            taper: 8.0,
        }
    }

    /// Height of the slit's axis (the line the margins meet on) at `u`.
    fn axis(&self, u: f64) -> f64 {
        let x = (u - self.u_mid) / self.half_width;
        self.v_axis + self.tilt * (u - self.u_mid) * self.side + self.corner_lift * x * x
    }

    /// Parameter support `(u range, v range)` of the warp.
    pub(crate) fn support(&self) -> ((f64, f64), (f64, f64)) {
        let reach = self.half_width + self.taper;
        (
            (self.u_mid - reach, self.u_mid + reach),
            (self.v_lo_row - self.fall_lo, self.v_hi_row + self.fall_up),
        )
    }

    /// Target heights of the upper and lower margins at `u` (inside the slit).
    fn margins(&self, u: f64, lid: &LidState) -> (f64, f64) {
        let x = ((u - self.u_mid) / self.half_width).clamp(-1.0, 1.0);
        let x_out = x * self.side;
        let base = (1.0 - x * x).max(0.0);
        let prof_up = base.powf(0.85) * (1.0 - 0.12 * x_out);
        let prof_lo = base.powf(1.1) * (1.0 + 0.12 * x_out);
        let axis = self.axis(u);
        let lo = axis - 0.5 * self.gap - self.h_lo * (1.0 - lid.raise) * prof_lo;
        let up_open = axis + 0.5 * self.gap + self.h_up * (1.0 + 0.5 * lid.wide) * prof_up;
        let closed = lo + CLOSED_GAP.min(self.gap);
        let close = lid.close.clamp(0.0, 1.0);
        let up = (up_open + (closed - up_open) * close).max(closed);
        (up, lo)
    }

    /// Warp `δ` at grid point `(u, v_grid)`: the parameter height of the vertex is
    /// `v_grid + δ`. Zero outside [`SlitWarp::support`].
    pub(crate) fn delta(&self, u: f64, v_grid: f64, lid: &LidState) -> f64 {
        let x = (u - self.u_mid) / self.half_width;
        let beyond = (x.abs() - 1.0).max(0.0) * self.half_width;
        if beyond >= self.taper {
            return 0.0;
        }
        let (d_hi, d_lo) = if beyond <= 0.0 {
            let (up, lo) = self.margins(u, lid);
            (up - self.v_hi_row, lo - self.v_lo_row)
        } else {
            let keep = 1.0 - smoothstep(0.0, self.taper, beyond);
            let axis = self.axis(u);
            (
                (axis + 0.5 * self.gap - self.v_hi_row) * keep,
                (axis - 0.5 * self.gap - self.v_lo_row) * keep,
            )
        };
        let eps = 1e-9;
        if v_grid >= self.v_hi_row - eps {
            d_hi * (1.0 - smoothstep(0.0, self.fall_up, v_grid - self.v_hi_row))
        } else if v_grid <= self.v_lo_row + eps {
            d_lo * (1.0 - smoothstep(0.0, self.fall_lo, self.v_lo_row - v_grid))
        } else {
            // A merged corner vertex between the two margin rows.
            self.axis(u) - v_grid
        }
    }
}

impl Openings {
    /// Total warp at `(u, v_grid)` for the given lid states (left, right).
    pub(crate) fn delta(&self, u: f64, v_grid: f64, lids: &[LidState; 2]) -> f64 {
        self.eyes[0].delta(u, v_grid, &lids[0])
            + self.eyes[1].delta(u, v_grid, &lids[1])
            + self.mouth.delta(u, v_grid, &LidState::default())
    }
}
