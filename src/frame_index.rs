//! The number of a frame in a take, as its source numbers it: one type for every stage,
//! file and sink (the frames of a session's `frames.csv`, of a video, of a C3D file, of
//! the bundles CSV), so that no stage counts frames as `usize` and another as `u64`.

use std::fmt;

/// A frame number (see the module docs). Ordered; serialized as a bare integer.
#[derive(
    Debug,
    Clone,
    Copy,
    PartialEq,
    Eq,
    PartialOrd,
    Ord,
    Hash,
    Default,
    serde::Serialize,
    serde::Deserialize,
)]
#[serde(transparent)]
pub struct FrameIndex(pub u64);

impl FrameIndex {
    /// Frame `n`.
    pub const fn new(n: u64) -> Self {
        Self(n)
    }

    /// The number.
    pub const fn get(self) -> u64 {
        self.0
    }

    /// The number as an index into per-frame arrays (saturating where `usize` is
    /// narrower than 64 bits).
    pub fn as_usize(self) -> usize {
        usize::try_from(self.0).unwrap_or(usize::MAX)
    }

    /// The frame `n` frames later (saturating).
    #[must_use]
    pub const fn after(self, n: u64) -> Self {
        Self(self.0.saturating_add(n))
    }

    /// Frames from `earlier` to this one; None when `earlier` comes after it.
    pub const fn since(self, earlier: FrameIndex) -> Option<u64> {
        self.0.checked_sub(earlier.0)
    }
}

impl From<u64> for FrameIndex {
    fn from(n: u64) -> Self {
        Self(n)
    }
}

impl From<usize> for FrameIndex {
    fn from(n: usize) -> Self {
        Self(n as u64)
    }
}

impl From<FrameIndex> for u64 {
    fn from(f: FrameIndex) -> Self {
        f.0
    }
}

impl fmt::Display for FrameIndex {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(&self.0, f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_and_orders_frames() {
        let a = FrameIndex::new(41);
        assert_eq!(a.after(2), FrameIndex::from(43usize));
        assert_eq!(a.after(2).since(a), Some(2));
        assert_eq!(a.since(a.after(1)), None);
        assert!(a < a.after(1));
        assert_eq!(a.to_string(), "41");
        assert_eq!(FrameIndex::new(u64::MAX).after(1).get(), u64::MAX);
        assert_eq!(serde_json::to_string(&a).ok().as_deref(), Some("41"));
    }
}
