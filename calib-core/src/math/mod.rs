//! The numerics every estimator shares: linear algebra, least squares, streaming statistics,
//! 3-vector helpers, `atan2`.

pub(crate) mod linalg;
pub mod lsq;
pub mod real;
pub mod stats;
#[cfg(test)]
pub(crate) mod test_noise;
pub mod trig;
pub mod vec3;
pub mod wide;
