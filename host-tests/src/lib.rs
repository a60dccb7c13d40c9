//! Host-side companions of calib-core: a physical simulator of the calibration rig, the paper's
//! own simulation model, and the statistics the benchmarks print.

#![deny(missing_docs)]

pub mod csvlog;
pub mod lsm_model;
pub mod moments;
pub mod nor;
pub mod offline;
pub mod paper_model;
pub mod servo_protocol;
pub mod session;
pub mod sim;

/// The process arguments for a clap parser, without a leading `--`: the cargo aliases
/// (`cargo paper-tables`, `cargo demo`, …) already end with one, so `cargo demo -- --seed 2`
/// and `cargo demo --seed 2` mean the same.
pub fn cli_args() -> Vec<String> {
    let mut a: Vec<String> = std::env::args().collect();
    if a.get(1).is_some_and(|s| s == "--") {
        a.remove(1);
    }
    a
}
