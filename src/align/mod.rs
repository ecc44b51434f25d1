//! Rigid alignment of point sets.
//!
//! Depends on nothing above [`crate::mesh`].

pub mod horn;

pub use horn::{HornError, horn_alignment};
