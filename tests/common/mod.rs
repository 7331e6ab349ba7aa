//! Helpers shared by the workspace-level tests in `tests/`.
//!
//! The tests themselves live in `tests/*.rs`; the statistics they use (KS, chi-square,
//! z-scores) come from `scatter_sim::stats`, the same code `stcvae eval` uses.
