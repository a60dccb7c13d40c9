//! Field calibration of a triaxial MEMS gyroscope (and the accelerometer it leans on) from a
//! hobby-servo rig: pure, `no_std`, allocation-free math shared by the firmware and the PC.
//!
//! Conventions (DESIGN §4; every `DESIGN §n` refers to `calib-core/DESIGN.md`): sensor frame
//! B = sensor axes; raw gyro `g` in °/s, raw accel `a` in g; gyro model `ω = K (g − b)`;
//! accelerometer model `f = M (a − o)`. Every estimator keeps
//! O(1) or bounded state (sums, normal equations, pose means), never sample buffers; sums are
//! kept in `f64` so that `f32` inputs give results within 1e-5 of an `f64` reference.
//!
//! Three rooms by concern, and the procedure that uses them:
//! - [`math`]: [`math::lsq`] (weighted least squares by normal equations: every linear solve
//!   goes through it), [`math::stats`] (exact integer moments), [`math::vec3`].
//! - [`estimators`]: [`estimators::rest`] (stillness), [`estimators::bias`] (the gyro bias and
//!   its drift), [`estimators::accel`] (6- and 9-parameter accelerometer), [`estimators::axis`]
//!   (static poses, the rotation axis, geometry checks), [`estimators::paper`] (the paper's
//!   estimator), [`estimators::sweep`] (the speed-free one), [`estimators::full`] and
//!   [`estimators::rotation`] (the full `K` from moves about non-coplanar axes),
//!   [`estimators::mag`] (the magnetometer).
//! - [`formats`]: [`formats::log`] (the recorded log), [`formats::record`] and
//!   [`formats::region`] (the flash record and its A/B region), [`formats::protocol`] and
//!   [`formats::text`] (the console's lines), [`formats::export`] (JSON, C, Arduino).
//! - [`procedure`]: the whole calibration as a sans-IO state machine;
//!   [`procedure::pipeline`]: the decisions the procedure and the offline tool share.
//!
//! ```
//! use calib_core::estimators::axis::{GeometryLimits, Poses};
//! use calib_core::estimators::sweep::{self, Moves};
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
// Casts between `Real` and `f32` (the records) or `f64` (the normal equations' sums)
// convert in one build and are the identity in the other (`Real` is `f32` with `single`).
#![allow(clippy::unnecessary_cast)]

pub mod board;
mod error;
pub mod estimators;
pub mod formats;
pub mod math;
pub mod procedure;
pub mod time;

pub use error::{Error, DISAGREE_RATIO};
pub use time::Time;

/// A 3-vector in the sensor frame (unit stated where used).
pub type Vec3 = [f32; 3];
/// A 3×3 matrix, row-major.
pub type Mat3 = [[f32; 3]; 3];
