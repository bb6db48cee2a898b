//! Batches of tests on all cores (parameter studies, campaigns): `crate::batch::par_map`.
use super::config::{ExecMode, Outcome, TestConfig};
use super::run_test;
use crate::error::Result;

/// Run many tests on `threads` worker threads (0 = all cores); results in input order.
pub fn run_batch(cfgs: &[TestConfig], mode: ExecMode, threads: usize) -> Vec<Result<Outcome>> {
    crate::batch::par_map(cfgs, threads, |c| run_test(c, mode, None, None))
}
