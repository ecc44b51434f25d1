//! Benchmark harnesses: the accuracy and speed benchmark of the solve methods ([`solve`])
//! and what the host reports about this process while one runs ([`host`]: CPU time,
//! resident memory, load average).
//!
//! Depends on [`crate::solve`], [`crate::lgi`], [`crate::dataset`] and [`crate::bundles`].

pub mod host;
pub mod solve;
