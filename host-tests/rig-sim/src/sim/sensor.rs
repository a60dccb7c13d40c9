//! MEMS gyroscope and accelerometer (the LSM9DS1's or the BMI270's full scales): linear error
//! model, white noise, 16-bit output.

use nalgebra::{Matrix3, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;

/// Gyro full scale; the LSM9DS1's sensitivities from its datasheet (8.75 / 17.50 / 70 mdps/LSB).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GyroRange {
    /// ±245 °/s.
    Dps245,
    /// ±500 °/s.
    Dps500,
    /// ±2000 °/s.
    Dps2000,
    /// A BMI270 at ±this °/s: range/32768 °/s per LSB (Bosch's API and examples).
    Bmi270(u16),
}

impl GyroRange {
    /// Output resolution (deg/s per LSB).
    pub fn lsb_dps(self) -> f64 {
        match self {
            Self::Dps245 => 8.75e-3,
            Self::Dps500 => 17.5e-3,
            Self::Dps2000 => 70e-3,
            Self::Bmi270(dps) => dps as f64 / 32768.0,
        }
    }
}

/// Accelerometer full scale; sensitivities from the LSM9DS1 datasheet (0.061 … 0.732 mg/LSB).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AccelRange {
    /// ±2 g.
    G2,
    /// ±4 g.
    G4,
    /// ±8 g.
    G8,
    /// ±16 g.
    G16,
    /// A BMI270 at ±this g: range/32768 g per LSB.
    Bmi270(u8),
}

impl AccelRange {
    /// Output resolution (g per LSB).
    pub fn lsb_g(self) -> f64 {
        match self {
            Self::G2 => 0.061e-3,
            Self::G4 => 0.122e-3,
            Self::G8 => 0.244e-3,
            Self::G16 => 0.732e-3,
            Self::Bmi270(g) => g as f64 / 32768.0,
        }
    }
}

/// Gyroscope: `g = C_g ω_B + b(T) + n`, `C_g = (I + misalignment) · diag(scale)`, all in deg/s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GyroSensor {
    /// Full scale (saturation, quantisation).
    pub range: GyroRange,
    /// Per-axis scale factors.
    pub scale: Vector3<f64>,
    /// Small axis misalignment (rad), off-diagonal; the diagonal must be zero.
    pub misalignment: Matrix3<f64>,
    /// Zero-rate output at the rig's initial temperature (deg/s).
    pub bias_dps: Vector3<f64>,
    /// Bias change per °C away from the initial temperature (deg/s/°C).
    pub bias_tempco_dps_per_c: Vector3<f64>,
    /// Relative change of each axis' scale per °C away from the initial temperature (1/°C).
    pub scale_tempco_per_c: Vector3<f64>,
    /// White rate-noise density (deg/s/√Hz); RMS per sample = density · √(ODR/2).
    pub noise_dps_rthz: f64,
    /// Round to whole LSBs (the real output); false keeps the exact value (saturation still applies).
    pub quantize: bool,
}

impl GyroSensor {
    /// Unit scale, no misalignment, bias, noise or quantisation; ±500 dps.
    pub fn ideal() -> Self {
        Self {
            range: GyroRange::Dps500,
            scale: Vector3::repeat(1.0),
            misalignment: Matrix3::zeros(),
            bias_dps: Vector3::zeros(),
            bias_tempco_dps_per_c: Vector3::zeros(),
            scale_tempco_per_c: Vector3::zeros(),
            noise_dps_rthz: 0.0,
            quantize: false,
        }
    }

    /// Scale U(0.97, 1.03), bias U(−3, 3) deg/s, misalignment U(−0.2°, 0.2°),
    /// tempco U(−0.01, 0.01) deg/s/°C, no scale tempco, 0.008 deg/s/√Hz, quantised, ±500 dps.
    pub fn realistic(rng: &mut impl Rng) -> Self {
        Self {
            range: GyroRange::Dps500,
            scale: uniform3(rng, 0.97, 1.03),
            misalignment: misalignment(rng, 0.2),
            bias_dps: uniform3(rng, -3.0, 3.0),
            bias_tempco_dps_per_c: uniform3(rng, -0.01, 0.01),
            scale_tempco_per_c: Vector3::zeros(),
            noise_dps_rthz: 0.008,
            quantize: true,
        }
    }

    /// `C_g`: raw bias-free reading per true body rate, at the initial temperature.
    pub fn matrix(&self) -> Matrix3<f64> {
        self.matrix_at(0.0)
    }

    /// `C_g` `delta_temp_c` °C away from the initial temperature.
    pub fn matrix_at(&self, delta_temp_c: f64) -> Matrix3<f64> {
        let scale = self.scale.component_mul(&self.scale_tempco_per_c.map(|c| 1.0 + c * delta_temp_c));
        (Matrix3::identity() + self.misalignment) * Matrix3::from_diagonal(&scale)
    }

    /// Bias (deg/s) `delta_temp_c` °C away from the initial temperature.
    pub fn bias_at(&self, delta_temp_c: f64) -> Vector3<f64> {
        self.bias_dps + self.bias_tempco_dps_per_c * delta_temp_c
    }

    /// Raw reading (deg/s) and saturation flag for inertial body rate `rate_b_dps` (deg/s), with
    /// the bias `delta_temp_c` °C away from the initial temperature plus `walk_dps`.
    pub(crate) fn measure(
        &self,
        rate_b_dps: &Vector3<f64>,
        delta_temp_c: f64,
        walk_dps: &Vector3<f64>,
        odr_hz: f64,
        rng: &mut impl Rng,
    ) -> ([f32; 3], bool) {
        let noise = gaussian3(rng) * self.noise_dps_rthz * (odr_hz / 2.0).sqrt();
        let g = self.matrix_at(delta_temp_c) * rate_b_dps + self.bias_at(delta_temp_c) + walk_dps + noise;
        digitize(&g, self.range.lsb_dps(), self.quantize)
    }
}

/// Accelerometer: `a = C_a f_B + o + n`, `C_a = (I + misalignment) · diag(scale)`, all in g.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AccelSensor {
    /// Full scale (saturation, quantisation).
    pub range: AccelRange,
    /// Per-axis scale factors.
    pub scale: Vector3<f64>,
    /// Small axis misalignment (rad), off-diagonal; the diagonal must be zero.
    pub misalignment: Matrix3<f64>,
    /// Zero-g offset (g).
    pub offset_g: Vector3<f64>,
    /// White noise density (µg/√Hz); RMS per sample = density · √(ODR/2).
    pub noise_ug_rthz: f64,
    /// Round to whole LSBs (the real output); false keeps the exact value (saturation still applies).
    pub quantize: bool,
}

impl AccelSensor {
    /// Unit scale, no misalignment, offset, noise or quantisation; ±2 g.
    pub fn ideal() -> Self {
        Self {
            range: AccelRange::G2,
            scale: Vector3::repeat(1.0),
            misalignment: Matrix3::zeros(),
            offset_g: Vector3::zeros(),
            noise_ug_rthz: 0.0,
            quantize: false,
        }
    }

    /// Scale U(0.98, 1.02), offset U(−0.03, 0.03) g, misalignment U(−0.1°, 0.1°),
    /// 150 µg/√Hz, quantised, ±2 g.
    pub fn realistic(rng: &mut impl Rng) -> Self {
        Self {
            range: AccelRange::G2,
            scale: uniform3(rng, 0.98, 1.02),
            misalignment: misalignment(rng, 0.1),
            offset_g: uniform3(rng, -0.03, 0.03),
            noise_ug_rthz: 150.0,
            quantize: true,
        }
    }

    /// `C_a`: raw offset-free reading per true specific force.
    pub fn matrix(&self) -> Matrix3<f64> {
        (Matrix3::identity() + self.misalignment) * Matrix3::from_diagonal(&self.scale)
    }

    /// Raw reading (g) and saturation flag for the specific force `force_b_g` (g).
    pub(crate) fn measure(&self, force_b_g: &Vector3<f64>, odr_hz: f64, rng: &mut impl Rng) -> ([f32; 3], bool) {
        let noise = gaussian3(rng) * self.noise_ug_rthz * 1e-6 * (odr_hz / 2.0).sqrt();
        let a = self.matrix() * force_b_g + self.offset_g + noise;
        digitize(&a, self.range.lsb_g(), self.quantize)
    }
}

/// 16-bit output register: counts (rounded when `quantize`) clamped to the int16 range, back
/// in physical units; the flag is set when any axis hit the range.
fn digitize(v: &Vector3<f64>, lsb: f64, quantize: bool) -> ([f32; 3], bool) {
    let (lo, hi) = (f64::from(i16::MIN), f64::from(i16::MAX));
    let mut saturated = false;
    let out = [0, 1, 2].map(|i| {
        let counts = if quantize { (v[i] / lsb).round() } else { v[i] / lsb };
        saturated |= !(lo..=hi).contains(&counts);
        (counts.clamp(lo, hi) * lsb) as f32
    });
    (out, saturated)
}

fn uniform3(rng: &mut impl Rng, lo: f64, hi: f64) -> Vector3<f64> {
    Vector3::from_fn(|_, _| rng.random_range(lo..hi))
}

fn gaussian3(rng: &mut impl Rng) -> Vector3<f64> {
    Vector3::from_fn(|_, _| rng.sample(StandardNormal))
}

/// Off-diagonal entries U(−max_deg, max_deg), in rad.
fn misalignment(rng: &mut impl Rng, max_deg: f64) -> Matrix3<f64> {
    let m = max_deg.to_radians();
    Matrix3::from_fn(|i, j| if i == j { 0.0 } else { rng.random_range(-m..m) })
}
