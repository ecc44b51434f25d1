//! The `helmcap` command line.
fn main() {}
