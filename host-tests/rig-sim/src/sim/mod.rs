//! Physical simulator of the calibration rig (DESIGN §2, §4, §6), independent of calib-core.
//!
//! World W has z up; body B = the board frame (docs/frames.md); attitudes `q_wb` map B to W. At rest the
//! accelerometer measures the specific force +1 g along world +z. On the shaft the attitude is
//! `Rot(s_W, θ) · mount`, so the rotation axis `u_B = mount⁻¹ s_W` is constant in B and turning
//! by θ rotates gravity, seen in B, by −θ about `u_B`. Everything is f64 and reproducible from
//! the seed (ChaCha8).
//!
//! The ideal gyro value of a sample is the mean body rate over the preceding sample interval,
//! taken from the attitudes themselves (rotation vector of `q_{k−1}⁻¹ q_k` over Δt), so
//! integrating it reproduces the attitude; the ideal accelerometer value is the instantaneous
//! specific force.

mod config;
mod hand;
mod kinematics;
mod mag;
mod rig;
mod sensor;
mod servo;

pub use config::{RigConfig, TiltStage, Warmup, BIAS_WALK_RANGE, BMI270_ODR_ERROR, EARTH_RATE_RAD_S, LSM9DS1_ODR_ERROR};
pub use hand::{Hand, HandLevel, HandSpec, HANDS};
pub use kinematics::{tilted_axis, G0};
pub use mag::{MagPart, MagTruth, Magnetometer};
pub use rig::{Reading, Rig, Truth};
pub use sensor::{AccelRange, AccelSensor, GyroRange, GyroSensor};
pub use servo::{ContinuousServo, PositionalServo, ServoModel, Vibration};
