//! Host-side companions of calib-core: a physical simulator of the calibration rig, the paper's
//! own simulation model, and the statistics the benchmarks print.

pub mod csvlog;
pub mod lsm_model;
pub mod moments;
pub mod nor;
pub mod offline;
pub mod paper_model;
pub mod servo_protocol;
pub mod session;
pub mod sim;
