//! Which way a log's magnetometer axes lie against its accelerometer's, from the data: at every
//! still pose the angle between gravity and the field is the same (the dip), in the right
//! axes only. Of the 24 turns that map axes onto axes (signed permutations, determinant +1),
//! the one under which the poses' dips scatter least is the magnetometer's. A turn and its
//! negative (a mirror: `−R` has determinant −1) give the same scatter with the dip's sign
//! flipped (turns cannot tell a field from its negative). A magnetometer's own axes are
//! right-handed, so the one taken is the turn when the gyro follows the accelerometer by the
//! right-hand rule, the mirror when its axes are mirrored ([`MagAxes::mirror`]: the LSM9DS1's
//! raw axes, whose magnetometer reads `(−x, y, z)` of them); the dip's sign then checks it
//! against where the log was made ([`MagAxes::describe`]).

use super::magnetometer::{calibrator, mean_field};
use super::*;
use calib_core::estimators::mag::MagLimits;
use calib_core::Mat3;
use serde::Serialize;

/// A turn of the magnetometer's axes onto the accelerometer's that the data show.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct MagAxes {
    /// `m_turned = R m_logged` (row-major, entries 0 or ±1).
    pub r: [[i8; 3]; 3],
    /// The scatter (°, standard deviation) of the poses' dips in the axes as logged.
    pub dip_scatter_logged_deg: f32,
    /// The same in the turned axes.
    pub dip_scatter_turned_deg: f32,
    /// The mean dip in the turned axes (°, positive: the field points down).
    pub dip_deg: f32,
}

impl MagAxes {
    /// `R m` for a reading as logged (µT).
    pub fn apply(&self, m: [f32; 3]) -> [f32; 3] {
        core::array::from_fn(|i| (0..3).map(|j| self.r[i][j] as f32 * m[j]).sum())
    }

    /// `A` and the offset of a calibration in the turned axes (`m = A (R m_raw − o)`), for the
    /// readings as logged: `A R` and `Rᵀ o`.
    pub fn logged(&self, a: Mat3, o: [f32; 3]) -> (Mat3, [f32; 3]) {
        let ar = core::array::from_fn(|i| core::array::from_fn(|j| (0..3).map(|k| a[i][k] * self.r[k][j] as f32).sum()));
        (ar, core::array::from_fn(|j| (0..3).map(|i| self.r[i][j] as f32 * o[i]).sum()))
    }

    /// `−R`: the other reading of the same data (the mirror of a turn, the turn of a mirror),
    /// the field and its dip negated.
    pub fn mirror(&mut self) {
        self.r = self.r.map(|row| row.map(|v| -v));
        self.dip_deg = -self.dip_deg;
    }

    /// `(x, -z, y)`: which logged axis (and sign) each turned axis is.
    pub fn axes(r: &[[i8; 3]; 3]) -> String {
        let name = |row: &[i8; 3]| {
            let j = row.iter().position(|v| *v != 0).unwrap_or(0);
            format!("{}{}", if row[j] < 0 { "-" } else { "" }, ["x", "y", "z"][j])
        };
        format!("({}, {}, {})", name(&r[0]), name(&r[1]), name(&r[2]))
    }

    /// What the tool found and did, and what the dip's sign means.
    pub fn describe(&self) -> String {
        let r = &self.r;
        let (is, other, why) = if det(r) > 0 {
            ("turned", "mirrored", "a right-handed part in the right-handed axes the gyro's moves show")
        } else {
            ("mirrored", "turned", "a right-handed part in the left-handed axes the gyro's moves show")
        };
        format!(
            "the magnetometer's axes are {is} relative to the accelerometer's: it reads {} in the accelerometer's axes \
             (the poses' dips scatter by {:.1} deg as logged, {:.2} deg so), {is} rather than {other} as {why}; calibrated so, A and the offset apply to the readings as logged. The field dips {:.1} deg \
             ({}): if that is not where the log was made, the axes are {other} instead, {}, and the field the negative",
            Self::axes(r),
            self.dip_scatter_logged_deg,
            self.dip_scatter_turned_deg,
            self.dip_deg,
            if self.dip_deg >= 0.0 { "down: the northern hemisphere" } else { "up: the southern hemisphere" },
            Self::axes(&r.map(|row| row.map(|v| -v))),
        )
    }
}

/// The determinant of a signed permutation matrix: +1 a turn, −1 a mirror.
fn det(m: &[[i8; 3]; 3]) -> i8 {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// The 24 rotations among the signed permutation matrices.
fn turns() -> impl Iterator<Item = [[i8; 3]; 3]> {
    const PERMS: [[usize; 3]; 6] = [[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]];
    PERMS.into_iter().flat_map(|p| {
        (0..8u8).filter_map(move |signs| {
            let r: [[i8; 3]; 3] = core::array::from_fn(|i| {
                core::array::from_fn(|j| {
                    if p[i] == j {
                        if signs >> i & 1 == 1 {
                            -1
                        } else {
                            1
                        }
                    } else {
                        0
                    }
                })
            });
            (det(&r) == 1).then_some(r)
        })
    })
}

/// The turn of the magnetometer's axes the hand-held poses `segs` show, when it is not the
/// identity: the poses' dips scatter beyond [`MagLimits::max_dip_dev_deg`] as logged and under
/// a third of that scatter turned. `None`: the axes as logged fit (or too few poses to tell).
pub fn find(rows: &[Row], segs: &[&Segment], accel: &AccelCal) -> Option<MagAxes> {
    let cal = calibrator(rows, segs, accel)?.ok()?;
    let (a_s, o, _) = cal.fit_ellipsoid().ok()?;
    // Per pose: gravity's direction and the field's (ellipsoid-corrected, as logged).
    let poses: Vec<(Vector3<f64>, Vector3<f64>)> = segs
        .iter()
        .filter_map(|s| {
            let m = mean_field(rows, s)?;
            let g = Vector3::from(accel.apply(s.accel.mean().map(|v| v as f32))).map(|v| v as f64).normalize();
            Some((g, (a_s * (Vector3::from(m).map(|v| v as f64) - o)).normalize()))
        })
        .collect();
    if poses.len() < calib_core::estimators::mag::MIN_POSES {
        return None;
    }
    let dips = |r: &[[i8; 3]; 3]| -> (f64, f64) {
        let rm = nalgebra::Matrix3::from_fn(|i, j| r[i][j] as f64);
        let d: Vec<f64> = poses.iter().map(|(g, m)| (-(rm * m).dot(g)).clamp(-1.0, 1.0).asin().to_degrees()).collect();
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        (mean, (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (d.len() - 1) as f64).sqrt())
    };
    let identity = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
    let (_, logged) = dips(&identity);
    let (r, (dip, turned)) = turns().map(|r| (r, dips(&r))).min_by(|a, b| a.1 .1.total_cmp(&b.1 .1))?;
    let limit = MagLimits::default().max_dip_dev_deg as f64;
    (r != identity && logged > limit && turned < logged / 3.0).then_some(MagAxes {
        r,
        dip_scatter_logged_deg: logged as f32,
        dip_scatter_turned_deg: turned as f32,
        dip_deg: dip as f32,
    })
}
