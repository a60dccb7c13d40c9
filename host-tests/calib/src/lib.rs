//! The PC side of gyrocal: the recorded log read whole ([`csvlog`], over the format of
//! `calib_core::formats::log`) and calibrated with the firmware's own calib-core code ([`offline`]): a
//! log of the firmware's own run is replayed through its procedure ([`replay`]); a board
//! calibrated over its USB serial port, its log saved and cross-checked ([`port`]). The
//! binaries `gyrocal-calib` and `gyrocal-flash` are what a user installs (`cargo install --locked
//! --path host-tests/calib --target host-tuple --profile host`); [`firmware`] builds the firmware
//! they flash; [`allan`] the noise figures of a long static log; [`real`] the public sessions of
//! real IMUs that tests and benchmarks read. Nothing here depends on the
//! simulator.
#![deny(missing_docs)]

pub mod allan;
pub mod csvlog;
pub mod firmware;
pub mod offline;
pub mod port;
pub mod real;
pub mod replay;
pub mod report;

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
