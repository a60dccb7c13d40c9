//! Benchmarks: the paper's own simulation model ([`paper_model`]), the hobby-servo comparison
//! of both estimators through the firmware's procedure ([`hobby_servo`]), the statistics
//! they print ([`moments`]) and the simulated sensor they choose ([`setup`]).
#![deny(missing_docs)]

pub mod hobby_servo;
pub mod logs;
pub mod moments;
pub mod paper_model;
pub mod setup;
