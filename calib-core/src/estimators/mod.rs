//! The estimators: the accelerometer, the gyro's bias, rest detection, one-axis and speed-free
//! scale factors (the paper's and the sweep), the full 3×3 `K` from rotations, the magnetometer.

pub mod accel;
pub mod axis;
pub mod bias;
pub mod frame;
pub mod full;
pub mod gyro;
pub mod mag;
pub mod paper;
pub mod rest;
pub mod rotation;
pub mod sweep;
