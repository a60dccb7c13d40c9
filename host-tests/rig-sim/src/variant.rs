//! Rig presets: random but seeded realistic rigs, as drawn for the benchmarks and the tests.

use crate::sim::{RigConfig, ServoModel};
use nalgebra::Matrix3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// The rig variants of the benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variant {
    /// Hobby servo as drawn (angle-scale error U(−3, 3) %, offset), sensors without cross-axis
    /// misalignment: the 6-parameter world of the paper.
    Hobby,
    /// The same rigs with an exact servo (no scale error, no offset).
    ExactServo,
    /// Hobby servo and cross-axis misalignment (gyro ±0.2°, accel ±0.1°), which a diagonal `K`
    /// from one rotation axis cannot separate from scale.
    HobbyMisaligned,
}

impl Variant {
    /// Its name in tables and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Variant::Hobby => "hobby_servo",
            Variant::ExactServo => "exact_servo",
            Variant::HobbyMisaligned => "hobby_servo_misaligned",
        }
    }

    /// The rig of run `run` under this variant (same draw for every variant).
    pub fn config(self, seed: u64, run: usize) -> RigConfig {
        let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(1000).wrapping_add(run as u64));
        let mut cfg = RigConfig::realistic(&mut rng);
        if self != Variant::HobbyMisaligned {
            cfg.gyro.misalignment = Matrix3::zeros();
            cfg.accel.misalignment = Matrix3::zeros();
        }
        if let (Variant::ExactServo, ServoModel::Positional(p)) = (self, &mut cfg.servo) {
            p.scale_error = 0.0;
            p.offset_deg = 0.0;
        }
        cfg
    }
}
