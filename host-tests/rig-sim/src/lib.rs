//! The rig, simulated: a physical simulation of the servo rig and the board's sensors
//! ([`sim`]), register-level models of the LSM9DS1 ([`lsm_model`]) and its magnetometer ([`lsm_mag_model`]), of the Rev2 board's BMI270
//! ([`bmi_model`]) and BMM150 magnetometer ([`bmm_model`]), and of the NOR flash
//! ([`nor`]) that the firmware's drivers run against, rig presets ([`variant`]), a scripted
//! pan/tilt protocol of another tool ([`pan_tilt`]), and the
//! harness that drives calib-core's procedure on a simulated rig with a simulated operator
//! ([`harness`]).
#![deny(missing_docs)]

pub mod bmi_model;
pub mod bmm_model;
pub mod harness;
pub mod heading;
pub mod lsm_mag_model;
pub mod lsm_model;
pub mod nor;
pub mod pan_tilt;
pub mod sim;
pub mod variant;
