//! A record's calibration for data read another way than raw. A record maps its part's raw
//! sensor axes in datasheet units ([`crate::formats::record::Sensor`]); a BMI270 read through Bosch's
//! BMI270_SensorAPI has its factory z→x trim applied (`x − GYR_CAS · z / 512`, gyro only), and
//! through Arduino_BMI270_BMM150 (1.2.3 on the Nano 33 BLE) that and then its axis remap
//! `x = −y, y = −x` (a reflection, gyro and accelerometer alike).
//!
//! With the data `g' = A g`, `a' = B a` and the outputs in the same axes as the data (`ω' = T ω`,
//! `f' = T f`): `K' = T K A⁻¹`, `b' = A b`, `M' = T M B⁻¹`, `o' = B o`, the bias tempco `A c`;
//! each element's 1σ is propagated as from independent elements. Sources: `docs/rev2-sources.md`
//! §2.9 (CAS) and §4 (the remap).

use crate::formats::record::{Record, Sensor};
use crate::{Mat3, Vec3};

/// How the data a calibration is applied to were read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DataFrame {
    /// Raw sensor axes, datasheet units: what the record holds.
    Raw,
    /// A BMI270 through Bosch's API: GYR_CAS applied, sensor axes.
    BoschApi,
    /// A BMI270 through Arduino_BMI270_BMM150: GYR_CAS applied, then `x = −y, y = −x`.
    ArduinoBmi270,
}

impl DataFrame {
    /// What the data are, for an export's header.
    pub fn describe(self) -> &'static str {
        match self {
            DataFrame::Raw => "raw sensor axes, datasheet units (nothing applied)",
            DataFrame::BoschApi => "BMI270 as Bosch's API returns it: GYR_CAS applied (x - cas z / 512), sensor axes",
            DataFrame::ArduinoBmi270 => "Arduino_BMI270_BMM150's readings: GYR_CAS applied, then its axes x = -y, y = -x",
        }
    }
}

/// A frame the record's part has no such reading for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NotThisPart;

impl core::fmt::Display for NotThisPart {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("that data frame is a BMI270's; the record was made with an LSM9DS1")
    }
}

type M3 = nalgebra::Matrix3<f32>;

/// Arduino_BMI270_BMM150's remap (its own inverse).
fn remap() -> M3 {
    M3::new(0.0, -1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 1.0)
}

fn m3(m: &Mat3) -> M3 {
    M3::from_fn(|r, c| m[r][c])
}

fn mat(m: &M3) -> Mat3 {
    core::array::from_fn(|r| core::array::from_fn(|c| m[(r, c)]))
}

fn vec(a: &M3, v: &Vec3) -> Vec3 {
    (a * nalgebra::Vector3::from(*v)).into()
}

/// The 1σ of `T X U` from independent elements' 1σ `s`: `σ'ᵢⱼ² = Σ Tᵢₖ² σₖₗ² Uₗⱼ²`.
fn sigma(t: &M3, s: &Mat3, u: &M3) -> Mat3 {
    let sq = |m: &M3| m.component_mul(m);
    mat(&(sq(t) * sq(&m3(s)) * sq(u)).map(libm::sqrtf))
}

impl Record {
    /// This record's calibration for data read as `frame`.
    pub fn in_frame(&self, frame: DataFrame) -> Result<Record, NotThisPart> {
        let cas = match (frame, self.setup.sensor) {
            (DataFrame::Raw, _) => return Ok(*self),
            (_, Sensor::Lsm9ds1) => return Err(NotThisPart),
            (_, Sensor::Bmi270 { gyr_cas, .. }) => gyr_cas as f32 / 512.0,
        };
        // Bosch's correction C (x −= cas z) and its inverse.
        let mut c = M3::identity();
        c[(0, 2)] = -cas;
        let mut c_inv = M3::identity();
        c_inv[(0, 2)] = cas;
        let t = if frame == DataFrame::ArduinoBmi270 { remap() } else { M3::identity() };
        // Gyro data A = T C (A⁻¹ = C⁻¹ T), accelerometer data B = T (B⁻¹ = T).
        let (a, a_inv) = (t * c, c_inv * t);
        Ok(Record {
            gyro_k: mat(&(t * m3(&self.gyro_k) * a_inv)),
            gyro_bias_dps: vec(&a, &self.gyro_bias_dps),
            sigma_k: sigma(&t, &self.sigma_k, &a_inv),
            accel_m: mat(&(t * m3(&self.accel_m) * t)),
            accel_offset_g: vec(&t, &self.accel_offset_g),
            tempco: self.tempco.map(|mut tc| {
                tc.dps_per_c = vec(&a, &tc.dps_per_c);
                // As for independent elements: σ'ᵢ² = Σ Aᵢₖ² σₖ².
                let s2 = vec(&a.component_mul(&a), &tc.sigma_dps_per_c.map(|x| x * x));
                tc.sigma_dps_per_c = s2.map(libm::sqrtf);
                tc
            }),
            ..*self
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::record::tests::sample;
    use crate::formats::record::SensorSetup;

    /// Bosch's CAS on raw counts, then Arduino's remap (`bmi2.c`'s `comp_gyro_cross_axis_sensitivity`,
    /// `BMI270.cpp`'s readGyroscope) — in °/s, without the integer truncation.
    fn arduino_reading(g: Vec3, cas: i8) -> Vec3 {
        let x = g[0] - cas as f32 * g[2] / 512.0;
        [-g[1], -x, g[2]]
    }

    #[test]
    fn the_calibration_in_another_frame_gives_the_same_rate_in_its_axes() {
        let sensor = Sensor::Bmi270 { gyr_cas: -23, user_gain: false };
        let mut rec = Record { setup: SensorSetup { sensor, ..SensorSetup::DEFAULT }, ..sample() };
        rec.gyro_k[0][2] = 0.004;
        rec.gyro_k[2][1] = -0.003;
        let raw = [12.0, -40.0, 75.0];
        let omega = rec.apply_gyro(raw);
        let bosch = rec.in_frame(DataFrame::BoschApi).unwrap();
        let via_bosch = bosch.apply_gyro([raw[0] + 23.0 * raw[2] / 512.0, raw[1], raw[2]]);
        let ard = rec.in_frame(DataFrame::ArduinoBmi270).unwrap();
        let via_ard = ard.apply_gyro(arduino_reading(raw, -23));
        for i in 0..3 {
            assert!((via_bosch[i] - omega[i]).abs() < 1e-4, "{via_bosch:?} {omega:?}");
        }
        // Arduino's axes: x = −y, y = −x.
        let expect = [-omega[1], -omega[0], omega[2]];
        for i in 0..3 {
            assert!((via_ard[i] - expect[i]).abs() < 1e-4, "{via_ard:?} {expect:?}");
        }
        // The accelerometer likewise (no CAS on it).
        let a = [0.3, -0.5, 0.8];
        let f = rec.accel().apply(a);
        let f_ard = ard.accel().apply([-a[1], -a[0], a[2]]);
        for i in 0..3 {
            assert!((f_ard[i] - [-f[1], -f[0], f[2]][i]).abs() < 1e-6);
        }
        // The remap moves the 1σ with the elements.
        assert!((ard.sigma_k[0][0] - rec.sigma_k[1][1]).abs() < 1e-9 && (ard.sigma_k[1][0] - rec.sigma_k[0][1]).abs() < 1e-9);
        assert_eq!(rec.in_frame(DataFrame::Raw), Ok(rec));
    }

    #[test]
    fn an_lsm9ds1_record_has_no_bmi270_frame() {
        assert_eq!(sample().in_frame(DataFrame::BoschApi), Err(NotThisPart));
        assert_eq!(sample().in_frame(DataFrame::ArduinoBmi270), Err(NotThisPart));
    }
}
