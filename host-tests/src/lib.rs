//! Host-side companions of calib-core: a physical simulator of the calibration rig.

pub mod sim;
