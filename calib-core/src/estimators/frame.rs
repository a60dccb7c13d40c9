//! A record's calibration for data read another way than this firmware reads them. A record
//! (version 6) maps readings in the board frame ([`crate::board`]) in datasheet units to rates,
//! specific force and field in the board frame. Other readers return the part's own axes:
//! Arduino_LSM9DS1 the LSM9DS1's raw axes (a left-handed triad); Bosch's BMI270_SensorAPI the
//! BMI270's axes with its factory z→x trim applied (`x − GYR_CAS · z / 512`, gyro only);
//! Arduino_BMI270_BMM150 (1.1.0 on, on the Nano 33 BLE) that, then its remap `x = −y, y = −x`
//! (which gives the LSM9DS1's raw axes); both Bosch readers return the BMM150 in its own axes.
//!
//! With the data `d = D x` for a board-frame reading `x` (`D_g`, `D_a`, `D_m` for the gyro, the
//! accelerometer and the magnetometer) and the outputs kept in the board frame: `K' = K D_g⁻¹`,
//! `b' = D_g b`, `M' = M D_a⁻¹`, `o' = D_a o`, the bias tempco `D_g c`, the magnetometer's
//! `A' = A D_m⁻¹`, `o_m' = D_m o_m`; each element's 1σ is propagated as from independent
//! elements. Sources: `docs/frames.md` (the maps), `docs/rev2-sources.md` §2.9 (CAS) and §4 (the
//! remap).

use crate::board::{self, AxisMap};
use crate::estimators::bias::TempCo;
use crate::estimators::mag::MagCal;
use crate::formats::record::{Record, Sensor};
use crate::{Mat3, Vec3};

/// How the data a calibration is applied to were read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DataFrame {
    /// The board frame, datasheet units: this firmware's readings and logs, what the record holds.
    Board,
    /// An LSM9DS1 through Arduino_LSM9DS1 (1.1.x): its raw axes, in datasheet units (GyroCal's
    /// `gyrocal_from_arduino_lsm9ds1` rescales the library's readings to them).
    ArduinoLsm9ds1,
    /// A BMI270 through Bosch's API (and Arduino_BMI270_BMM150 1.0.x): GYR_CAS applied, Bosch's
    /// axes; the BMM150 in its own.
    BoschApi,
    /// A BMI270 through Arduino_BMI270_BMM150 1.1.0 on: GYR_CAS applied, then `x = −y, y = −x`;
    /// the BMM150 in its own axes.
    ArduinoBmi270,
}

impl DataFrame {
    /// What the data are, for an export's header.
    pub fn describe(self) -> &'static str {
        match self {
            DataFrame::Board => "the board frame (x towards USB, z out of the component side), datasheet units",
            DataFrame::ArduinoLsm9ds1 => "Arduino_LSM9DS1's readings: the LSM9DS1's raw axes (board x = -x), datasheet units",
            DataFrame::BoschApi => "BMI270 as Bosch's API returns it: GYR_CAS applied (x - cas z / 512), Bosch's axes; BMM150 its own",
            DataFrame::ArduinoBmi270 => {
                "Arduino_BMI270_BMM150 >= 1.1.0's readings: GYR_CAS applied, then its axes x = -y, y = -x; BMM150 its own"
            }
        }
    }
}

/// A frame the record's part has no such reading for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NotThisPart;

impl core::fmt::Display for NotThisPart {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("that data frame is another part's than the record's")
    }
}

type M3 = nalgebra::Matrix3<f32>;

fn m3(m: &Mat3) -> M3 {
    M3::from_fn(|r, c| m[r][c])
}

fn mat(m: &M3) -> Mat3 {
    core::array::from_fn(|r| core::array::from_fn(|c| m[(r, c)]))
}

fn vec(a: &M3, v: &Vec3) -> Vec3 {
    (a * nalgebra::Vector3::from(*v)).into()
}

/// A map's matrix and its inverse.
fn pair(m: AxisMap) -> (M3, M3) {
    (m3(&m.matrix()), m3(&m.inverse().matrix()))
}

/// The 1σ of `T X U` from independent elements' 1σ `s`: `σ'ᵢⱼ² = Σ Tᵢₖ² σₖₗ² Uₗⱼ²`.
fn sigma(t: &M3, s: &Mat3, u: &M3) -> Mat3 {
    let sq = |m: &M3| m.component_mul(m);
    mat(&(sq(t) * sq(&m3(s)) * sq(u)).map(crate::math::vec3::sqrtf))
}

/// A linear map of the data and the outputs: each as a matrix and its inverse.
struct Maps {
    /// Outputs (rates, specific force, field).
    out: M3,
    gyro: (M3, M3),
    accel: (M3, M3),
    mag: (M3, M3),
}

impl Record {
    /// This record's calibration for data read as `frame` (outputs in the board frame).
    pub fn in_frame(&self, frame: DataFrame) -> Result<Record, NotThisPart> {
        let (pl, pb, q) = (pair(board::LSM9DS1_AG), pair(board::BMI270), pair(board::BMM150));
        let cas = match (frame, self.setup.sensor) {
            (DataFrame::Board, _) => return Ok(*self),
            (DataFrame::ArduinoLsm9ds1, Sensor::Lsm9ds1) => {
                // The raw axes: d = P⁻¹ x (the LSM9DS1's map is its own inverse); the field as read.
                let raw = (pl.1, pl.0);
                let id = (M3::identity(), M3::identity());
                return Ok(self.mapped(&Maps { out: M3::identity(), gyro: raw, accel: raw, mag: id }));
            }
            (DataFrame::ArduinoLsm9ds1, _) | (_, Sensor::Lsm9ds1) => return Err(NotThisPart),
            (_, Sensor::Bmi270 { gyr_cas, .. }) => gyr_cas as f32 / 512.0,
        };
        // Bosch's correction C (x −= cas z, Bosch's axes) and its inverse.
        let mut c = M3::identity();
        c[(0, 2)] = -cas;
        let mut c_inv = M3::identity();
        c_inv[(0, 2)] = cas;
        // Arduino's remap (its own inverse).
        let t = if frame == DataFrame::ArduinoBmi270 { M3::new(0.0, -1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0) } else { M3::identity() };
        // Bosch's axes from the board's: P_B⁻¹; gyro data D_g = T C P_B⁻¹, accelerometer T P_B⁻¹.
        let gyro = (t * c * pb.1, pb.0 * c_inv * t);
        let accel = (t * pb.1, pb.0 * t);
        Ok(self.mapped(&Maps { out: M3::identity(), gyro, accel, mag: (q.1, q.0) }))
    }

    /// A record of version 1–5 (the part's raw axes) in the board frame: by the part's map `P`,
    /// `K' = P K Pᵀ`, `b' = P b`, the accelerometer alike, each 1σ moved with its element; the
    /// magnetometer's `A' = P A Qᵀ`, `o' = Q o` with `Q` the map of its old input frame (the
    /// LSM9DS1's accelerometer axes; the BMM150's own, taken as the BMI270's). Signed
    /// permutations only: moves and negations (the firmware loads old records with it).
    #[inline(never)]
    pub fn from_part_axes(&self) -> Record {
        let (p, q) = match self.setup.sensor {
            Sensor::Lsm9ds1 => (board::LSM9DS1_AG, board::LSM9DS1_AG),
            Sensor::Bmi270 { .. } => (board::BMI270, board::BMM150),
        };
        // `P M Qᵀ`: element (i, j) is ± M[from_i][from_j].
        let conj = |m: &Mat3, q: &AxisMap, signed: bool| -> Mat3 {
            core::array::from_fn(|i| {
                core::array::from_fn(|j| {
                    let v = m[p.from[i] as usize][q.from[j] as usize];
                    if signed && p.negate[i] != q.negate[j] {
                        -v
                    } else {
                        v
                    }
                })
            })
        };
        Record {
            gyro_k: conj(&self.gyro_k, &p, true),
            gyro_bias_dps: p.apply(self.gyro_bias_dps),
            sigma_k: conj(&self.sigma_k, &p, false),
            accel_m: conj(&self.accel_m, &p, true),
            accel_offset_g: p.apply(self.accel_offset_g),
            tempco: self.tempco.map(|tc| TempCo {
                dps_per_c: p.apply(tc.dps_per_c),
                sigma_dps_per_c: p.apply(tc.sigma_dps_per_c).map(f32::abs),
                ..tc
            }),
            mag: self.mag.map(|mc| MagCal { a: conj(&mc.a, &q, true), offset_ut: q.apply(mc.offset_ut), ..mc }),
            ..*self
        }
    }

    /// The record for data `d = D x` and outputs `T y`: `K' = T K D⁻¹`, `b' = D b`, and so on.
    fn mapped(&self, m: &Maps) -> Record {
        let (t, (g, g_inv), (a, a_inv), (q, q_inv)) = (&m.out, &m.gyro, &m.accel, &m.mag);
        Record {
            gyro_k: mat(&(t * m3(&self.gyro_k) * g_inv)),
            gyro_bias_dps: vec(g, &self.gyro_bias_dps),
            sigma_k: sigma(t, &self.sigma_k, g_inv),
            accel_m: mat(&(t * m3(&self.accel_m) * a_inv)),
            accel_offset_g: vec(a, &self.accel_offset_g),
            tempco: self.tempco.map(|mut tc| {
                tc.dps_per_c = vec(g, &tc.dps_per_c);
                // As for independent elements: σ'ᵢ² = Σ Dᵢₖ² σₖ².
                let s2 = vec(&g.component_mul(g), &tc.sigma_dps_per_c.map(|x| x * x));
                tc.sigma_dps_per_c = s2.map(crate::math::vec3::sqrtf);
                tc
            }),
            mag: self.mag.map(|mut mc| {
                mc.a = mat(&(t * m3(&mc.a) * q_inv));
                mc.offset_ut = vec(q, &mc.offset_ut);
                mc
            }),
            ..*self
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::record::tests::sample;
    use crate::formats::record::SensorSetup;

    fn close(a: Vec3, b: Vec3, tol: f32) {
        assert!((0..3).all(|i| (a[i] - b[i]).abs() < tol), "{a:?} {b:?}");
    }

    /// A record with cross terms everywhere a part could have them.
    fn skewed(sensor: Sensor) -> Record {
        let mut rec = Record { setup: SensorSetup { sensor, ..SensorSetup::DEFAULT }, ..sample() };
        rec.gyro_k[0][2] = 0.004;
        rec.gyro_k[2][1] = -0.003;
        rec.accel_m[1][0] = 0.002;
        rec.mag.as_mut().unwrap().a[0][1] = 0.05;
        rec
    }

    #[test]
    fn each_readers_data_give_the_board_frames_outputs() {
        let sensor = Sensor::Bmi270 { gyr_cas: -23, user_gain: false };
        let rec = skewed(sensor);
        let (x, a, m) = ([12.0, -40.0, 75.0], [0.3, -0.5, 0.8], [20.0, -5.0, 40.0]);
        let (omega, f, field) = (rec.apply_gyro(x), rec.accel().apply(a), rec.mag.unwrap().apply(m));
        // Bosch's axes of the part, Bosch's CAS on the gyro (`bmi2.c`'s
        // `comp_gyro_cross_axis_sensitivity`, without the integer truncation), Arduino's remap
        // (`BMI270.cpp` 1.1.0 on), the BMM150 in its own axes.
        let bosch_axes = board::BMI270.inverse();
        let cas = |g: Vec3| [g[0] + 23.0 * g[2] / 512.0, g[1], g[2]];
        let remap = |v: Vec3| [-v[1], -v[0], v[2]];
        let bmm = board::BMM150.inverse().apply(m);
        let bosch = rec.in_frame(DataFrame::BoschApi).unwrap();
        close(bosch.apply_gyro(cas(bosch_axes.apply(x))), omega, 1e-4);
        close(bosch.accel().apply(bosch_axes.apply(a)), f, 1e-6);
        close(bosch.mag.unwrap().apply(bmm), field, 1e-4);
        let ard = rec.in_frame(DataFrame::ArduinoBmi270).unwrap();
        close(ard.apply_gyro(remap(cas(bosch_axes.apply(x)))), omega, 1e-4);
        close(ard.accel().apply(remap(bosch_axes.apply(a))), f, 1e-6);
        close(ard.mag.unwrap().apply(bmm), field, 1e-4);
        // Arduino's remap of the BMI270 gives the LSM9DS1's raw axes: board x = −x.
        close(remap(bosch_axes.apply(a)), [-a[0], a[1], a[2]], 1e-9);
        // The axes move the 1σ with the elements (no CAS in the accelerometer's).
        assert!((ard.sigma_k[0][0] - rec.sigma_k[0][0]).abs() < 1e-9);
        assert_eq!(rec.in_frame(DataFrame::Board), Ok(rec));
        assert_eq!(rec.in_frame(DataFrame::ArduinoLsm9ds1), Err(NotThisPart));

        let lsm = skewed(Sensor::Lsm9ds1);
        let raw = |v: Vec3| [-v[0], v[1], v[2]];
        let ard = lsm.in_frame(DataFrame::ArduinoLsm9ds1).unwrap();
        close(ard.apply_gyro(raw(x)), lsm.apply_gyro(x), 1e-4);
        close(ard.accel().apply(raw(a)), lsm.accel().apply(a), 1e-6);
        // Arduino_LSM9DS1's magnetometer reads the part's raw axes: the board's.
        close(ard.mag.unwrap().apply(m), lsm.mag.unwrap().apply(m), 1e-4);
        assert_eq!(lsm.in_frame(DataFrame::BoschApi), Err(NotThisPart));
        assert_eq!(lsm.in_frame(DataFrame::ArduinoBmi270), Err(NotThisPart));
    }

    #[test]
    fn a_record_in_part_axes_gives_the_same_calibration_in_the_board_frame() {
        for (sensor, part, mag_old) in [
            (Sensor::Lsm9ds1, board::LSM9DS1_AG, board::LSM9DS1_AG),
            (Sensor::Bmi270 { gyr_cas: 5, user_gain: false }, board::BMI270, board::BMM150),
        ] {
            // Version 5: part axes in, part axes out; its magnetometer read in `mag_old⁻¹` of the board's.
            let old = skewed(sensor);
            let new = old.from_part_axes();
            let (d, a, m_old) = ([12.0, -40.0, 75.0], [0.3, -0.5, 0.8], [20.0, -5.0, 40.0]);
            close(new.apply_gyro(part.apply(d)), part.apply(old.apply_gyro(d)), 1e-4);
            close(new.accel().apply(part.apply(a)), part.apply(old.accel().apply(a)), 1e-6);
            close(new.mag.unwrap().apply(mag_old.apply(m_old)), part.apply(old.mag.unwrap().apply(m_old)), 1e-4);
            let tc = |r: &Record| r.tempco.unwrap().dps_per_c;
            close(tc(&new), part.apply(tc(&old)), 1e-7);
            // The 1σ moves with its element.
            let to = |i: usize| part.from.iter().position(|&f| f as usize == i).unwrap();
            assert_eq!(new.sigma_k[to(0)][to(2)], old.sigma_k[0][2]);
        }
    }
}
