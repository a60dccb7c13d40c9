//! Rig configuration: sensors, servo, geometry, clocks.

use super::hand::HandLevel;
use super::kinematics::{rotation_between, tilted_axis};
use super::mag::MagPart;
use super::sensor::{AccelRange, AccelSensor, GyroRange, GyroSensor};
use super::servo::{PositionalServo, ServoModel};
use nalgebra::{Unit, UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;

/// Everything that defines one simulated rig: sensor, servo(s), mounting, clocks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigConfig {
    /// Nominal output data rate (Hz): 119, 238, 476 or 952 on the LSM9DS1.
    pub odr_hz: f64,
    /// Relative ODR error: actual ODR = `odr_hz · (1 + odr_error)`.
    pub odr_error: f64,
    /// The gyroscope's errors.
    pub gyro: GyroSensor,
    /// The accelerometer's errors.
    pub accel: AccelSensor,
    /// The rotation servo.
    pub servo: ServoModel,
    /// Shaft axis angle from world vertical (deg).
    pub shaft_tilt_deg: f64,
    /// Shaft axis azimuth, from world +x towards +y (deg).
    pub shaft_azimuth_deg: f64,
    /// Board attitude (body → world) at shaft angle 0; fixes the axis in B, `u_B = mount⁻¹ s_W`.
    pub mount: UnitQuaternion<f64>,
    /// Sensor distance from the shaft axis (m), along body x (or y) made perpendicular to `u_B`.
    pub radius_m: f64,
    /// MCU crystal error (ppm): timestamps run `(1 + ppm·1e-6)` times true time.
    pub mcu_clock_ppm: f64,
    /// RMS white jitter of the timestamps (s).
    pub timestamp_jitter_s: f64,
    /// Sensor temperature at t = 0 (°C).
    pub temp_c: f64,
    /// Linear temperature drift (°C/s).
    pub temp_drift_c_per_s: f64,
    /// The board's self-heating after power-on, on top of the linear drift (None: none).
    pub warmup: Option<Warmup>,
    /// Gyro bias rate random walk (deg/s/√s, each axis; 0: none): the bias wanders by this
    /// times √t.
    pub bias_rw_dps_rtsec: f64,
    /// The Earth's rotation (7.292e-5 rad/s) at this latitude (deg), W's +y north and +z up;
    /// None: not simulated. The gyro measures it in the body frame on top of the rig's motion.
    pub latitude_deg: Option<f64>,
    /// Duration of the smooth move back onto the shaft in `Rig::attach` (s).
    pub attach_transition_s: f64,
    /// Optional tilt stage of a pan/tilt gimbal between the shaft and the board.
    pub tilt: Option<TiltStage>,
    /// The hand that holds the board off the shaft (None: perfectly still, as no hand is).
    pub hand: Option<HandLevel>,
    /// The board's magnetometer (None: not simulated); its errors and the site's field are
    /// drawn by the rig from a stream of their own ([`super::mag::Magnetometer::draw`]).
    pub mag: Option<MagPart>,
}

/// A tilt servo mounted on the rotation shaft: it turns the board about a hinge perpendicular to
/// the shaft by `servo angle − 90°` (1500 µs ≈ level).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TiltStage {
    /// The tilt servo (positional).
    pub servo: PositionalServo,
    /// Direction of the hinge about the shaft, from an arbitrary perpendicular (deg).
    pub hinge_deg: f64,
}

/// Self-heating after power-on: the temperature rises by `rise_c` along 1 − e^(−t/τ) from
/// power-on, which was `since_power_on_s` before the log's t = 0.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Warmup {
    /// Total rise from power-on (°C).
    pub rise_c: f64,
    /// Time constant (s).
    pub tau_s: f64,
    /// Power-on to the log's t = 0 (s).
    pub since_power_on_s: f64,
}

/// The Earth's rotation rate (rad/s).
pub const EARTH_RATE_RAD_S: f64 = 7.292_115e-5;

/// The range a drifting rig's gyro bias rate random walk is drawn from (°/s/√s, log-uniform):
/// a quarter to four times 5e-4, the single value rigs had before (issue 35). Neither the
/// LSM9DS1's nor the BMI270's datasheet states one.
pub const BIAS_WALK_RANGE: (f64, f64) = (1.25e-4, 2e-3);
/// The LSM9DS1's relative ODR error drawn per rig (its datasheet states no tolerance: see
/// docs/limits.md).
pub const LSM9DS1_ODR_ERROR: (f64, f64) = (-0.05, -0.02);
/// The BMI270's relative ODR error drawn per rig (none found in its datasheet either).
pub const BMI270_ODR_ERROR: (f64, f64) = (-0.02, 0.02);

impl RigConfig {
    /// Temperature change from t = 0 to true time `t_s` (°C): the linear drift and the warm-up.
    pub fn delta_temp_c(&self, t_s: f64) -> f64 {
        let warm = self.warmup.map_or(0.0, |w| {
            let at = |t: f64| w.rise_c * (1.0 - (-(t + w.since_power_on_s) / w.tau_s).exp());
            at(t_s) - at(0.0)
        });
        self.temp_drift_c_per_s * t_s + warm
    }

    /// The Earth's rotation in W (rad/s), zero if not simulated.
    pub fn earth_rate_w(&self) -> Vector3<f64> {
        self.latitude_deg.map_or(Vector3::zeros(), |lat| {
            let phi = lat.to_radians();
            Vector3::new(0.0, phi.cos(), phi.sin()) * EARTH_RATE_RAD_S
        })
    }

    /// Error-free sensors (no noise, no quantisation), exact servo (`PositionalServo::ideal`),
    /// exact 119 Hz, exact clock; shaft tilted 45° at azimuth 30°, axis `u_B = (2, −3, 6)/7`.
    pub fn ideal() -> Self {
        Self {
            odr_hz: 119.0,
            odr_error: 0.0,
            gyro: GyroSensor::ideal(),
            accel: AccelSensor::ideal(),
            servo: ServoModel::Positional(PositionalServo::ideal()),
            shaft_tilt_deg: 45.0,
            shaft_azimuth_deg: 30.0,
            mount: UnitQuaternion::identity(),
            radius_m: 0.0,
            mcu_clock_ppm: 0.0,
            timestamp_jitter_s: 0.0,
            temp_c: 25.0,
            temp_drift_c_per_s: 0.0,
            warmup: None,
            bias_rw_dps_rtsec: 0.0,
            latitude_deg: None,
            attach_transition_s: 1.0,
            tilt: None,
            hand: None,
            mag: None,
        }
        .with_axis(Vector3::new(2.0, -3.0, 6.0), 25.0)
    }

    /// Nano 33 BLE (LSM9DS1 at 119 Hz) on a positional hobby servo, drawn from `rng`: see
    /// `GyroSensor::realistic`, `AccelSensor::realistic`, `PositionalServo::realistic`; ODR error
    /// U(−5 %, −2 %), shaft tilt U(20°, 70°) at a random azimuth, random mount with
    /// |u_k| ≥ 0.2 on every sensor axis, radius U(0, 2 cm), crystal U(−20, 20) ppm,
    /// 10 µs jitter, 20–30 °C; a braced hand ([`HandLevel::Braced`]) holding it off the shaft;
    /// the LSM9DS1's magnetometer; and a board just powered up ([`Self::drifting`]).
    pub fn realistic(rng: &mut impl Rng) -> Self {
        let axis_b = loop {
            let v = Vector3::<f64>::from_fn(|_, _| rng.sample(StandardNormal)).normalize();
            if v.iter().all(|c| c.abs() >= 0.2) {
                break v;
            }
        };
        let twist_deg = rng.random_range(0.0..360.0);
        Self {
            odr_hz: 119.0,
            odr_error: rng.random_range(LSM9DS1_ODR_ERROR.0..LSM9DS1_ODR_ERROR.1),
            gyro: GyroSensor::realistic(rng),
            accel: AccelSensor::realistic(rng),
            servo: ServoModel::Positional(PositionalServo::realistic(rng)),
            shaft_tilt_deg: rng.random_range(20.0..70.0),
            shaft_azimuth_deg: rng.random_range(0.0..360.0),
            mount: UnitQuaternion::identity(),
            radius_m: rng.random_range(0.0..0.02),
            mcu_clock_ppm: rng.random_range(-20.0..20.0),
            timestamp_jitter_s: 10e-6,
            temp_c: rng.random_range(20.0..30.0),
            temp_drift_c_per_s: rng.random_range(0.0..0.005),
            warmup: None,
            bias_rw_dps_rtsec: 0.0,
            latitude_deg: None,
            attach_transition_s: 1.0,
            tilt: None,
            hand: Some(HandLevel::Braced),
            mag: Some(MagPart::Lsm9ds1),
        }
        .with_axis(axis_b, twist_deg)
        .drifting(rng)
    }

    /// A gyro bias that moves as on a board just powered up (issue 19), drawn from `rng`: the
    /// board warming itself by U(2, 6) °C along 1 − e^(−t/τ), τ U(60, 150) s, the calibration
    /// starting U(5, 30) s after power-on (the user plugs the board in, then presses the
    /// button); a zero-rate tempco of U(0.03, 0.05) °/s/°C per axis with a random sign (ST's
    /// I3G4250D: ±0.03 °/s/°C; x-io measured 0.015 on a BMI088); the Earth's rotation at a
    /// latitude U(−60°, 60°); each gyro axis' scale moving by U(±0.02 %)/°C (a datasheet-class
    /// sensitivity tempco); a bias rate random walk log-uniform over [`BIAS_WALK_RANGE`] (neither
    /// part's datasheet gives one). Replaces the linear temperature drift.
    pub fn drifting(mut self, rng: &mut impl Rng) -> Self {
        self.warmup = Some(Warmup {
            rise_c: rng.random_range(2.0..6.0),
            tau_s: rng.random_range(60.0..150.0),
            since_power_on_s: rng.random_range(5.0..30.0),
        });
        self.temp_drift_c_per_s = 0.0;
        for a in 0..3 {
            let m: f64 = rng.random_range(0.03..0.05);
            self.gyro.bias_tempco_dps_per_c[a] = if rng.random_bool(0.5) { m } else { -m };
        }
        self.latitude_deg = Some(rng.random_range(-60.0..60.0));
        self.gyro.scale_tempco_per_c = Vector3::from_fn(|_, _| rng.random_range(-2e-4..2e-4));
        let (lo, hi) = BIAS_WALK_RANGE;
        self.bias_rw_dps_rtsec = lo * (hi / lo).powf(rng.random_range(0.0..1.0));
        self
    }

    /// The same rig with a Nano 33 BLE Rev2's BMI270 instead of the LSM9DS1, drawn from `rng`:
    /// 100 Hz with an ODR error U(−2 %, 2 %) (its own oscillator; the datasheet excerpts read
    /// give no figure), gyro noise 0.007 °/s/√Hz (performance mode) and accelerometer
    /// 160 µg/√Hz (BST-BMI270-DS000), counts of range/32768 at `gyro_dps` and `accel_g`, and the
    /// part's raw z→x gyro coupling that its factory trim GYR_CAS measures (the register model's
    /// part, [`crate::bmi_model::GYR_CAS`]/512, which Bosch's API subtracts): the rig's own
    /// cross-axis draw is what that correction leaves. The rest (scale, bias, its drift) as drawn
    /// for the rig.
    pub fn on_bmi270(mut self, gyro_dps: u16, accel_g: u8, rng: &mut impl Rng) -> Self {
        // Bosch's x is the board's −y and its z the board's z (`Bmi270Model::raw_axes`): raw
        // x += cas z there is the board's y −= cas z.
        self.gyro.misalignment[(1, 2)] -= crate::bmi_model::GYR_CAS as f64 / 512.0;
        self.odr_hz = 100.0;
        self.odr_error = rng.random_range(BMI270_ODR_ERROR.0..BMI270_ODR_ERROR.1);
        self.gyro.noise_dps_rthz = 0.007;
        self.accel.noise_ug_rthz = 160.0;
        self.gyro.range = GyroRange::Bmi270(gyro_dps);
        self.accel.range = AccelRange::Bmi270(accel_g);
        self.mag = self.mag.map(|_| MagPart::Bmm150);
        self
    }

    /// The same rig with a gyro bias that does not move: no warm-up, temperature drift, walk
    /// or Earth rate (a constant-bias baseline).
    pub fn constant_bias(mut self) -> Self {
        self.warmup = None;
        self.temp_drift_c_per_s = 0.0;
        self.bias_rw_dps_rtsec = 0.0;
        self.latitude_deg = None;
        self
    }

    /// Shaft axis in W (unit).
    pub fn shaft_axis_w(&self) -> Unit<Vector3<f64>> {
        tilted_axis(self.shaft_tilt_deg, self.shaft_azimuth_deg)
    }

    /// Shaft axis in B (unit): constant while the board is clamped on the shaft.
    pub fn axis_b(&self) -> Vector3<f64> {
        self.mount.inverse() * self.shaft_axis_w().into_inner()
    }

    /// Sets `mount` so that the shaft axis in B is `axis_b` (normalised), with the board then
    /// turned by `twist_deg` about the shaft (which sets where gravity lies at shaft angle 0).
    pub fn with_axis(mut self, axis_b: Vector3<f64>, twist_deg: f64) -> Self {
        let s_w = self.shaft_axis_w();
        self.mount = UnitQuaternion::from_axis_angle(&s_w, twist_deg.to_radians()) * rotation_between(&axis_b.normalize(), &s_w);
        self
    }

    /// The die temperature `temp_c` (°C) as the part's register gives it: the BMI270's
    /// TEMPERATURE_0/1 in 1/512 °C (Bosch's raw / 512 + 23), the LSM9DS1's OUT_TEMP in 1/16 °C.
    pub fn temp_reading_c(&self, temp_c: f64) -> f32 {
        let per_c = if matches!(self.gyro.range, GyroRange::Bmi270(_)) { 512.0 } else { 16.0 };
        ((temp_c * per_c).round() / per_c) as f32
    }

    /// Actual ODR (Hz).
    pub fn actual_odr_hz(&self) -> f64 {
        self.odr_hz * (1.0 + self.odr_error)
    }
}
