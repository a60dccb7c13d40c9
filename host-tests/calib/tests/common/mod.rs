//! Helpers shared by the test files: simulated logs of the firmware's procedure.
#![allow(dead_code)] // each test file uses some of them

use calib_core::procedure::{Config, Procedure};
use rig_sim::harness::{record_log, Faults};
use rig_sim::sim::{Rig, RigConfig};
use std::process::Command;

/// Runs the procedure on `cfg` and returns the log text and the true K diagonal.
pub fn simulated_log(cfg: RigConfig) -> (String, [f64; 3]) {
    let mut rig = Rig::new(cfg, 3);
    let mut p = Procedure::new(Config::default(), None);
    let (text, _) = record_log(&mut rig, &mut p, Faults::default(), "# test log\n");
    let k = rig.truth().gyro_k;
    (text, [k[(0, 0)], k[(1, 1)], k[(2, 2)]])
}

/// Runs the `calib` binary: exit code, stdout, stderr.
pub fn calib(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_gyrocal-calib")).args(args).output().unwrap();
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}
