//! The rig: board on a servo shaft (or held by hand), sampled by the LSM9DS1 at its own ODR and
//! timestamped by the MCU clock.

use super::config::RigConfig;
use super::hand::Hand;
use super::kinematics::{lever_accel_g, perpendicular, rotation_vector_between, Transition, Wobble};
use super::mag::{MagTruth, Magnetometer};
use super::sensor::{AccelRange, GyroRange};
use super::servo::{Servo, ServoModel};
use nalgebra::{Matrix3, Unit, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Shaft dynamics integration rate (Hz): at least this many substeps per second.
const SUBSTEP_HZ: f64 = 8000.0;

/// One IMU sample as the MCU sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reading {
    /// MCU timestamp (s): crystal error and jitter included, strictly increasing.
    pub t_s: f64,
    /// Raw accelerometer (g, datasheet sensitivity applied).
    pub accel_g: [f32; 3],
    /// Raw gyroscope (deg/s, datasheet sensitivity applied).
    pub gyro_dps: [f32; 3],
    /// Temperature (°C) at the part's register resolution ([`RigConfig::temp_reading_c`]).
    pub temp_c: f32,
    /// The accelerometer reached full scale in this sample.
    pub accel_saturated: bool,
    /// The gyroscope reached full scale in this sample.
    pub gyro_saturated: bool,
    /// A new magnetometer reading (µT, board frame), at the part's own rate.
    pub mag_ut: Option<[f32; 3]>,
}

/// Ground truth after the latest sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Truth {
    /// True time of the latest sample (s).
    pub t_s: f64,
    /// True spacing from the previous sample (s).
    pub dt_s: f64,
    /// Gyro scale matrix `K = C_g⁻¹`: `ω = K (g − b)`, at the mean temperature of the samples
    /// so far ([`Rig::mean_delta_temp_c`]; the scale moves with temperature).
    pub gyro_k: Matrix3<f64>,
    /// Gyro bias at the current temperature (raw deg/s: the reading at rest).
    pub gyro_bias_dps: Vector3<f64>,
    /// Accelerometer matrix `C_a`: `a = C_a f + o` (so `M = C_a⁻¹`).
    pub accel_c: Matrix3<f64>,
    /// Accelerometer offset `o` (g).
    pub accel_offset_g: Vector3<f64>,
    /// Shaft axis in B (unit) at the current tilt, the rotation axis whenever the board is on
    /// the shaft.
    pub axis_b: Vector3<f64>,
    /// Sensor position from the shaft axis (m, in B), perpendicular to `axis_b`.
    pub lever_b_m: Vector3<f64>,
    /// Shaft angle (deg), vibration included; the board turns by +θ about the world shaft axis.
    pub shaft_deg: f64,
    /// Shaft rate (deg/s), vibration included.
    pub shaft_rate_dps: f64,
    /// Actual ODR (Hz).
    pub odr_hz: f64,
    /// Board clamped on the shaft (false while held by hand or moving on/off the shaft).
    pub attached: bool,
    /// Board attitude (body → world) at the latest sample.
    pub q_wb: UnitQuaternion<f64>,
    /// Error-free gyro input: mean body rate over the latest sample interval (deg/s, in B).
    pub rate_b_dps: Vector3<f64>,
    /// Error-free accelerometer input: specific force at the latest sample (g, in B).
    pub specific_force_b_g: Vector3<f64>,
    /// Sensor temperature (°C).
    pub temp_c: f64,
    /// The magnetometer's errors and the site's field, when simulated.
    pub mag: Option<MagTruth>,
}

/// The simulated rig: servo(s), board attitude, sensors and clocks, sample by sample.
#[derive(Clone)]
pub struct Rig {
    cfg: RigConfig,
    axis_w: Unit<Vector3<f64>>,
    axis_b: Vector3<f64>,
    lever_b: Vector3<f64>,
    servo: Servo,
    /// The tilt servo and its hinge axis in W at shaft angle 0.
    tilt: Option<(Servo, Unit<Vector3<f64>>)>,
    /// Some(resting attitude) while the board is off the shaft.
    hand: Option<UnitQuaternion<f64>>,
    /// The hand's motion (`RigConfig::hand`) and when it took the board and let it go (true s).
    tremor: Option<Hand>,
    held: Option<(f64, Option<f64>)>,
    transition: Option<Transition>,
    wobbles: Vec<Wobble>,
    k: u64,
    t_s: f64,
    dt_s: f64,
    q_wb: UnitQuaternion<f64>,
    rate_b: Vector3<f64>,
    force_b: Vector3<f64>,
    t_mcu_s: f64,
    noise_rng: ChaCha8Rng,
    clock_rng: ChaCha8Rng,
    event_rng: ChaCha8Rng,
    /// The bias random walk's state (deg/s) and its stream.
    bias_walk: Vector3<f64>,
    walk_rng: ChaCha8Rng,
    /// Sum of the temperature changes (°C) at the samples so far, and their count.
    temp_sum: (f64, u64),
    /// The magnetometer and its noise stream.
    mag: Option<Magnetometer>,
    mag_rng: ChaCha8Rng,
    /// The stream of the operator's choices ([`Rig::operator_rng`]).
    operator_rng: ChaCha8Rng,
}

impl Rig {
    /// Rig at true time 0, board on the shaft at angle 0, servo without pulse. Noise, vibration,
    /// jitter and disturbances draw from separate streams of `seed`, so switching one source off
    /// leaves the others unchanged.
    pub fn new(cfg: RigConfig, seed: u64) -> Self {
        assert!(cfg.odr_hz > 0.0 && cfg.odr_error > -1.0, "ODR must be positive");
        assert!(cfg.servo.vibration().freq_hz < SUBSTEP_HZ / 20.0, "vibration too fast for the integrator");
        let stream = |n| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(n);
            rng
        };
        let axis_w = cfg.shaft_axis_w();
        let axis_b = cfg.axis_b();
        let mut rig = Self {
            cfg,
            axis_w,
            axis_b,
            lever_b: perpendicular(&axis_b) * cfg.radius_m,
            servo: Servo::new(cfg.servo, stream(1)),
            tilt: cfg.tilt.map(|t| {
                let hinge = UnitQuaternion::from_axis_angle(&axis_w, t.hinge_deg.to_radians()) * perpendicular(&axis_w.into_inner());
                // The stage starts level (servo at 90°).
                let servo = Servo::new(ServoModel::Positional(t.servo), stream(5)).starting_at(90.0);
                (servo, Unit::new_normalize(hinge))
            }),
            hand: None,
            tremor: cfg.hand.map(|level| Hand::new(level, &mut stream(7))),
            held: None,
            transition: None,
            wobbles: Vec::new(),
            k: 0,
            t_s: 0.0,
            dt_s: 0.0,
            q_wb: cfg.mount,
            rate_b: Vector3::zeros(),
            force_b: Vector3::zeros(),
            t_mcu_s: f64::NEG_INFINITY,
            noise_rng: stream(2),
            clock_rng: stream(3),
            event_rng: stream(4),
            bias_walk: Vector3::zeros(),
            walk_rng: stream(6),
            temp_sum: (0.0, 0),
            mag: cfg.mag.map(|part| Magnetometer::draw(part, &mut stream(8))),
            mag_rng: stream(9),
            operator_rng: stream(10),
        };
        rig.force_b = rig.specific_force(&rig.q_wb, 0.0);
        rig
    }

    /// Servo pulse width (µs), picked up at the next 20 ms PWM frame.
    pub fn set_pulse_us(&mut self, us: f64) {
        self.servo.set_pulse_us(us);
    }

    /// Changes the sensor's nominal ODR (Hz) from the next sample on; the relative ODR error
    /// stays (the sensor's oscillator).
    pub fn set_odr_hz(&mut self, hz: f64) {
        if hz > 0.0 {
            self.cfg.odr_hz = hz;
        }
    }

    /// Whether the readings are rounded to the LSM9DS1's counts (false: exact, for a sensor
    /// model that quantises at its own full scales).
    pub fn set_quantized(&mut self, on: bool) {
        (self.cfg.gyro.quantize, self.cfg.accel.quantize) = (on, on);
    }

    /// Changes the sensor's full scales (saturation and quantisation) from the next sample on.
    pub fn set_ranges(&mut self, gyro: GyroRange, accel: AccelRange) {
        (self.cfg.gyro.range, self.cfg.accel.range) = (gyro, accel);
    }

    /// Tilt servo pulse width (µs); ignored without a tilt stage.
    pub fn set_tilt_pulse_us(&mut self, us: f64) {
        if let Some((tilt, _)) = &mut self.tilt {
            tilt.set_pulse_us(us);
        }
    }

    /// The magnetometer's readings from now on at `hz` (its register model's data rate). No
    /// effect without a magnetometer.
    pub fn set_mag_odr_hz(&mut self, hz: f64) {
        if let Some(m) = &mut self.mag {
            m.set_odr_hz(hz);
        }
    }

    /// A stray field at the board from now on (µT, in W; zero: none): a magnet or a laptop
    /// brought near it. No effect without a magnetometer.
    pub fn set_stray_field_ut(&mut self, field_w: Vector3<f64>) {
        if let Some(m) = &mut self.mag {
            m.stray_w = field_w;
        }
    }

    /// No more servo pulses (from the next 20 ms frame): the motor idles.
    pub fn servo_off(&mut self) {
        self.servo.pulse_off();
    }

    /// A stalled (or unplugged) servo holds its shaft whatever the command.
    pub fn stall(&mut self, stalled: bool) {
        self.servo.stall(stalled);
    }

    /// A stalled (or unplugged) tilt servo holds the stage whatever the command.
    pub fn stall_tilt(&mut self, stalled: bool) {
        if let Some((tilt, _)) = &mut self.tilt {
            tilt.stall(stalled);
        }
    }

    /// The board slips on its bracket: its mount turns by `angle_deg` about the body axis
    /// `axis_b`, smoothly over `duration_s` from now (the gyro sees the slip).
    pub fn slip(&mut self, axis_b: Vector3<f64>, angle_deg: f64, duration_s: f64) {
        let from = self.base_attitude(self.t_s);
        self.cfg.mount *= UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis_b), angle_deg.to_radians());
        self.transition = Some(Transition { from, t0_s: self.t_s, duration_s });
    }

    /// Takes the board off the shaft and moves it smoothly (slerp, smooth-step timing) from its
    /// current attitude to `q_wb` (body → world) in `transition_s`, then holds it still. The
    /// hand pivots the board about the sensor; its sway and tremor (`RigConfig::hand`) set in
    /// over 0.5 s on top. The shaft keeps running.
    pub fn detach_to(&mut self, q_wb: UnitQuaternion<f64>, transition_s: f64) {
        let from = self.base_attitude(self.t_s);
        if self.hand.is_none() {
            self.held = Some((self.t_s, None));
        }
        self.hand = Some(q_wb);
        self.transition = Some(Transition { from, t0_s: self.t_s, duration_s: transition_s });
    }

    /// Puts the board back on the shaft, moving smoothly in `attach_transition_s`.
    pub fn attach(&mut self) {
        if self.hand.is_some() {
            let from = self.base_attitude(self.t_s);
            self.hand = None;
            if let Some((_, until)) = &mut self.held {
                *until = Some(self.t_s);
            }
            self.transition = Some(Transition { from, t0_s: self.t_s, duration_s: self.cfg.attach_transition_s });
        }
    }

    /// Someone touching the rig from now on for `duration_s`: a wobble of rate amplitude
    /// ~`amplitude_dps` about a random body axis, starting and ending at rest.
    pub fn disturb(&mut self, duration_s: f64, amplitude_dps: f64) {
        let wobble = Wobble::new(&mut self.event_rng, self.t_s, duration_s, amplitude_dps);
        self.wobbles.push(wobble);
    }

    /// Advances to the next sensor sample and returns it.
    pub fn next_sample(&mut self) -> Reading {
        self.k += 1;
        let t_s = self.t_s + 1.0 / self.cfg.actual_odr_hz();
        let dt_s = t_s - self.t_s;
        let substeps = (dt_s * SUBSTEP_HZ).ceil().max(1.0);
        for _ in 0..substeps as u32 {
            self.servo.step(dt_s / substeps);
            if let Some((tilt, _)) = &mut self.tilt {
                tilt.step(dt_s / substeps);
            }
        }

        let q_wb = self.attitude(t_s);
        if self.transition.is_some_and(|tr| tr.is_over(t_s)) {
            self.transition = None;
        }
        self.wobbles.retain(|w| !w.is_over(t_s));
        self.rate_b = rotation_vector_between(&self.q_wb, &q_wb) / dt_s;
        self.force_b = self.specific_force(&q_wb, t_s);
        self.q_wb = q_wb;
        self.t_s = t_s;
        self.dt_s = dt_s;

        if self.cfg.bias_rw_dps_rtsec > 0.0 {
            let step = Vector3::from_fn(|_, _| self.walk_rng.sample::<f64, _>(StandardNormal));
            self.bias_walk += step * self.cfg.bias_rw_dps_rtsec * dt_s.sqrt();
        }
        let (cfg, rng) = (&self.cfg, &mut self.noise_rng);
        let odr = cfg.actual_odr_hz();
        let delta_temp_c = cfg.delta_temp_c(t_s);
        self.temp_sum = (self.temp_sum.0 + delta_temp_c, self.temp_sum.1 + 1);
        // Inertial rate: the rig's motion in W plus the Earth's rotation, in the body frame.
        let rate_dps = (self.rate_b + q_wb.inverse() * cfg.earth_rate_w()).map(f64::to_degrees);
        let (gyro_dps, gyro_saturated) = cfg.gyro.measure(&rate_dps, delta_temp_c, &self.bias_walk, odr, rng);
        let (accel_g, accel_saturated) = cfg.accel.measure(&self.force_b, odr, rng);

        let shaft = self.on_shaft().then(|| (self.axis_w, self.servo.angle(), q_wb * self.lever_b));
        let mag_ut = self.mag.as_mut().and_then(|m| m.measure(t_s, &q_wb, shaft, &mut self.mag_rng));

        let jitter = self.cfg.timestamp_jitter_s * self.clock_rng.sample::<f64, _>(StandardNormal);
        let t_mcu = t_s * (1.0 + self.cfg.mcu_clock_ppm * 1e-6) + jitter;
        self.t_mcu_s = t_mcu.max(self.t_mcu_s + 1e-6);

        Reading {
            t_s: self.t_mcu_s,
            accel_g,
            gyro_dps,
            temp_c: self.cfg.temp_reading_c(self.cfg.temp_c + delta_temp_c),
            accel_saturated,
            gyro_saturated,
            mag_ut,
        }
    }

    /// True time of the latest sample (s).
    pub fn time_s(&self) -> f64 {
        self.t_s
    }

    /// Mean temperature change (°C) over the samples so far: the temperature a calibration
    /// from them holds for (its scale is their average).
    pub fn mean_delta_temp_c(&self) -> f64 {
        if self.temp_sum.1 == 0 {
            0.0
        } else {
            self.temp_sum.0 / self.temp_sum.1 as f64
        }
    }

    /// The simulator's truth now: K, biases, attitude, axis (for scoring, never for the estimators).
    pub fn truth(&self) -> Truth {
        let delta_temp_c = self.cfg.delta_temp_c(self.t_s);
        Truth {
            t_s: self.t_s,
            dt_s: self.dt_s,
            gyro_k: self.cfg.gyro.matrix_at(self.mean_delta_temp_c()).try_inverse().expect("gyro matrix is singular"),
            gyro_bias_dps: self.cfg.gyro.bias_at(delta_temp_c) + self.bias_walk,
            accel_c: self.cfg.accel.matrix(),
            accel_offset_g: self.cfg.accel.offset_g,
            axis_b: self.current_axis_b(),
            lever_b_m: self.lever_b,
            shaft_deg: self.servo.angle().to_degrees(),
            shaft_rate_dps: self.servo.rate().to_degrees(),
            odr_hz: self.cfg.actual_odr_hz(),
            attached: self.on_shaft(),
            q_wb: self.q_wb,
            rate_b_dps: self.rate_b.map(f64::to_degrees),
            specific_force_b_g: self.force_b,
            temp_c: self.cfg.temp_c + delta_temp_c,
            mag: self.mag.as_ref().map(Magnetometer::truth),
        }
    }

    /// A stream of `seed` of its own for the operator's choices (which attitudes the board is
    /// held in): drawing from it leaves every other stream unchanged.
    pub fn operator_rng(&mut self) -> &mut ChaCha8Rng {
        &mut self.operator_rng
    }

    /// The rig's configuration.
    pub fn config(&self) -> &RigConfig {
        &self.cfg
    }

    fn on_shaft(&self) -> bool {
        self.hand.is_none() && self.transition.is_none()
    }

    /// Attitude at true time `t_s` (shaft state as integrated up to `t_s`), without wobbles.
    fn base_attitude(&self, t_s: f64) -> UnitQuaternion<f64> {
        let target = self
            .hand
            .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&self.axis_w, self.servo.angle()) * self.tilt_rotation() * self.cfg.mount);
        match &self.transition {
            Some(tr) => tr.attitude(t_s, &target),
            None => target,
        }
    }

    /// Rotation of the tilt stage (in W at shaft angle 0): the hinge by `angle − 90°`.
    fn tilt_rotation(&self) -> UnitQuaternion<f64> {
        self.tilt.as_ref().map_or(UnitQuaternion::identity(), |(servo, hinge)| {
            UnitQuaternion::from_axis_angle(hinge, servo.angle() - std::f64::consts::FRAC_PI_2)
        })
    }

    /// The shaft axis in B for the current tilt.
    fn current_axis_b(&self) -> Vector3<f64> {
        (self.tilt_rotation() * self.cfg.mount).inverse() * self.axis_w.into_inner()
    }

    fn attitude(&self, t_s: f64) -> UnitQuaternion<f64> {
        let held = self.wobbles.iter().fold(self.base_attitude(t_s), |q, w| q * w.rotation(t_s));
        match self.hand_gain(t_s) {
            Some((hand, gain)) => held * hand.rotation(t_s, gain),
            None => held,
        }
    }

    /// The hand and how far its motion has set in at `t_s`, while it holds (or lets go of) the
    /// board.
    fn hand_gain(&self, t_s: f64) -> Option<(&Hand, f64)> {
        let (hand, (since, until)) = (self.tremor.as_ref()?, self.held?);
        let gain = Hand::envelope(t_s, since, until);
        (gain > 0.0).then_some((hand, gain))
    }

    /// Specific force (g, in B) at true time `t_s`: gravity reaction `R_BW ẑ`, plus the lever-arm
    /// acceleration while clamped on the shaft, or the hand's linear acceleration (its translation's
    /// and its turn's about its pivot, [`Hand::accel_g`]).
    fn specific_force(&self, q_wb: &UnitQuaternion<f64>, t_s: f64) -> Vector3<f64> {
        let gravity = q_wb.inverse() * Vector3::z();
        if self.on_shaft() {
            gravity + lever_accel_g(&self.axis_b, &self.lever_b, self.servo.rate(), self.servo.accel())
        } else {
            let (world, body) = self.hand_gain(t_s).map_or((Vector3::zeros(), Vector3::zeros()), |(h, gain)| h.accel_g(t_s, gain));
            q_wb.inverse() * (Vector3::z() + world) + body
        }
    }
}
