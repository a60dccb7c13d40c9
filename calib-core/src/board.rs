//! The board frame and each part's map into it ([docs/frames.md](../../docs/frames.md)).
//!
//! Every record (from version 6), log, JSON and export holds its vectors in one right-handed
//! frame, the same on the Rev1 and the Rev2: `z` out of the component side, `x` along the board
//! towards the USB connector, `y = z × x`. Each driver maps its part's readings into it, so
//! nothing downstream knows a part:
//!
//! - LSM9DS1 accelerometer and gyro: `(−x, y, z)` of its raw axes, which form a left-handed triad
//!   (recordings of real boards, `host-tests/calib/tests/real_boards.rs`; ArduPilot and PX4 flip
//!   one axis of both);
//! - LSM9DS1 magnetometer: its raw axes (the datasheet's `(−x, y, z)` between its axes and the
//!   accelerometer's; PX4: "sensor X is aligned with −X of lsm9ds1 accel/gyro");
//! - BMI270: `(y, −x, z)` of Bosch's axes (Arduino_BMI270_BMM150 ≥ 1.1.0 remaps them to the
//!   LSM9DS1's raw axes with `x = −y, y = −x`);
//! - BMM150: `(−y, −x, −z)` of its axes (a turn of 180° about `x` from the BMI270's: Bosch's note
//!   for the two parts side by side; UNVERIFIED on a Nano 33 BLE, docs/limits.md).

use crate::{Mat3, Vec3};

/// A signed permutation of axes: `out[i] = sign[i] · in[from[i]]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AxisMap {
    /// The input axis each output axis takes.
    pub from: [u8; 3],
    /// Whether each output axis is negated.
    pub negate: [bool; 3],
}

impl AxisMap {
    /// Nothing moved.
    pub const IDENTITY: AxisMap = AxisMap { from: [0, 1, 2], negate: [false; 3] };

    /// The map applied to `v` (inlined: with a constant map it folds to moves and negations).
    #[inline(always)]
    pub fn apply(&self, v: Vec3) -> Vec3 {
        let pick = |i: usize| {
            let x = match self.from[i] {
                0 => v[0],
                1 => v[1],
                _ => v[2],
            };
            if self.negate[i] {
                -x
            } else {
                x
            }
        };
        [pick(0), pick(1), pick(2)]
    }

    /// The map back.
    pub fn inverse(&self) -> AxisMap {
        let mut inv = AxisMap::IDENTITY;
        for i in 0..3 {
            let j = self.from[i] as usize;
            inv.from[j] = i as u8;
            inv.negate[j] = self.negate[i];
        }
        inv
    }

    /// Its matrix `P` (`apply(v) = P v`).
    pub fn matrix(&self) -> Mat3 {
        core::array::from_fn(|i| {
            core::array::from_fn(|j| match (self.from[i] as usize == j, self.negate[i]) {
                (false, _) => 0.0,
                (true, false) => 1.0,
                (true, true) => -1.0,
            })
        })
    }

    /// Whether it turns (determinant +1) rather than mirrors.
    pub fn is_rotation(&self) -> bool {
        let p = self.matrix();
        let det = p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1]) - p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0])
            + p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0]);
        det > 0.0
    }
}

/// LSM9DS1 accelerometer and gyro raw axes → board.
pub const LSM9DS1_AG: AxisMap = AxisMap { from: [0, 1, 2], negate: [true, false, false] };
/// LSM9DS1 magnetometer raw axes → board.
pub const LSM9DS1_MAG: AxisMap = AxisMap::IDENTITY;
/// BMI270 (Bosch's axes) → board.
pub const BMI270: AxisMap = AxisMap { from: [1, 0, 2], negate: [false, true, false] };
/// BMM150 (its own axes) → board.
pub const BMM150: AxisMap = AxisMap { from: [1, 0, 2], negate: [true, true, true] };

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_maps_and_their_inverses() {
        for m in [LSM9DS1_AG, LSM9DS1_MAG, BMI270, BMM150] {
            let v = [0.25, -0.5, 2.0];
            assert_eq!(m.inverse().apply(m.apply(v)), v);
            let p = m.matrix();
            let pv: Vec3 = core::array::from_fn(|i| (0..3).map(|j| p[i][j] * v[j]).sum());
            assert_eq!(pv, m.apply(v));
        }
        assert_eq!(LSM9DS1_AG.apply([1.0, 2.0, 3.0]), [-1.0, 2.0, 3.0]);
        assert_eq!(BMI270.apply([1.0, 2.0, 3.0]), [2.0, -1.0, 3.0]);
        assert_eq!(BMM150.apply([1.0, 2.0, 3.0]), [-2.0, -1.0, -3.0]);
        // The LSM9DS1's accel/gyro triad is mirrored; the BMI270's and the BMM150's are turned.
        assert!(!LSM9DS1_AG.is_rotation());
        assert!(LSM9DS1_MAG.is_rotation() && BMI270.is_rotation() && BMM150.is_rotation());
        // Arduino_BMI270_BMM150's remap of the BMI270 (x = −y, y = −x) gives the LSM9DS1's raw
        // axes: board = LSM9DS1_AG of them.
        let lib = |b: Vec3| [-b[1], -b[0], b[2]];
        assert_eq!(LSM9DS1_AG.apply(lib([1.0, 2.0, 3.0])), BMI270.apply([1.0, 2.0, 3.0]));
    }
}
