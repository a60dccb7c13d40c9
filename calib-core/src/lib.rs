//! Field calibration of a triaxial MEMS gyroscope (and the accelerometer it leans on) from a
//! hobby-servo rig: pure, `no_std`, allocation-free math shared by the firmware and the PC.
//!
//! Conventions (DESIGN §4; every `DESIGN §n` refers to `calib-core/DESIGN.md`): sensor frame
//! B = sensor axes; raw gyro `g` in °/s, raw accel `a` in g; gyro model `ω = K (g − b)`;
//! accelerometer model `f = M (a − o)`. Every estimator keeps
//! O(1) or bounded state (sums, normal equations, pose means), never sample buffers; sums are
//! kept in `f64` so that `f32` inputs give results within 1e-5 of an `f64` reference.
//!
//! - [`lsq`]: weighted least squares by normal equations (every linear solve goes through it).
//! - [`stats`], [`rest`]: Welford statistics and the stillness detector.
//! - [`bias`]: gyro bias at rest. [`accel`]: 6- and 9-parameter accelerometer calibration.
//! - [`axis`]: static poses, the rotation axis, turn angles and geometry checks.
//! - [`paper`]: the paper's estimator; [`sweep`]: the speed-free sweep estimator.
//! - [`full`]: the full 9-parameter `K` (scale and cross-axis) from moves about non-coplanar axes.
//! - [`procedure`]: the whole calibration as a sans-IO state machine; [`record`]: the flash record.
//! - [`pipeline`]: the decisions the procedure and the offline tool share (fit choice, gates).
//! - [`log`]: the recorded log's format (the firmware's raw-log mode and the offline tool).
//!
//! ```
//! use calib_core::axis::{GeometryLimits, Poses};
//! use calib_core::sweep::{self, Moves};
//!
//! // Axis u in the sensor frame, tilted 45° from vertical; e1, e2 span the plane ⟂ u.
//! let (s, h) = (1.0f32 / 3f32.sqrt(), 1.0f32 / 2f32.sqrt());
//! let (u, e1, e2) = ([s, s, s], [h, -h, 0.0], [s * h, s * h, -2.0 * s * h]);
//! let k_true = [1.02f32, 0.97, 1.01];
//! let mut poses = Poses::new();
//! for i in 0..7 {
//!     // Turning the shaft by +θ turns gravity by −θ about u, as seen by the sensor.
//!     let th = -(30.0 * i as f32).to_radians();
//!     let a: [f32; 3] = core::array::from_fn(|k| h * u[k] + h * (e1[k] * th.cos() + e2[k] * th.sin()));
//!     poses.push(a).unwrap();
//! }
//! let mut moves = Moves::new();
//! for i in 0..6u8 {
//!     // The raw gyro integral of a +30° move: Γ = K⁻¹ Δθ u.
//!     let gamma: [f64; 3] = core::array::from_fn(|k| (30.0 * u[k] / k_true[k]) as f64);
//!     moves.push(i, i + 1, gamma).unwrap();
//! }
//! let cal = sweep::solve(&poses, &moves, &GeometryLimits::default()).unwrap();
//! for k in 0..3 {
//!     assert!((cal.k[k][k] - k_true[k]).abs() < 1e-4);
//! }
//! ```
#![no_std]
#![deny(missing_docs)]
// Matrix code reads best with indices; `!(x > 0.0)` is a deliberate NaN-rejecting test.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

pub mod accel;
pub mod axis;
pub mod bias;
mod error;
pub mod export;
pub mod frame;
pub mod full;
pub mod gyro;
mod linalg;
pub mod log;
pub mod lsq;
pub mod mag;
pub mod paper;
pub mod pipeline;
pub mod procedure;
pub mod protocol;
pub mod record;
pub mod region;
pub mod rest;
pub mod rotation;
pub mod stats;
pub mod sweep;
#[cfg(test)]
mod test_noise;
pub mod text;
pub mod vec3;

pub use error::Error;

/// A 3-vector in the sensor frame (unit stated where used).
pub type Vec3 = [f32; 3];
/// A 3×3 matrix, row-major.
pub type Mat3 = [[f32; 3]; 3];
