//! Hobby-servo shaft dynamics driven by a PWM pulse width (µs), 50 Hz frames (DESIGN §2).

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::TAU;

/// The servo latches the latest pulse width once per 20 ms PWM frame.
const PWM_FRAME_S: f64 = 0.02;
/// Positional servo gain: 1000–2000 µs spans 0–180°.
const DEG_PER_US: f64 = 0.18;
/// Shaft rate (deg/s) above which the gear train vibrates.
const MOVING_DPS: f64 = 1.0;

/// Gear-train vibration while the shaft moves: a shaft-angle jitter about the shaft axis, a
/// damped oscillator driven by white noise (so band-limited around `freq_hz`), which rings down
/// when the shaft stops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Vibration {
    /// Stationary RMS jitter angle while moving (deg).
    pub rms_deg: f64,
    /// Resonance frequency (Hz); keep well below the 8 kHz integration rate.
    pub freq_hz: f64,
    /// Damping ratio (dimensionless).
    pub damping: f64,
}

impl Vibration {
    /// No vibration.
    pub const NONE: Self = Self { rms_deg: 0.0, freq_hz: 40.0, damping: 0.2 };

    /// 0.01–0.04° RMS at 20–50 Hz, damping 0.1–0.3.
    pub fn realistic(rng: &mut impl Rng) -> Self {
        Self { rms_deg: rng.random_range(0.01..0.04), freq_hz: rng.random_range(20.0..50.0), damping: rng.random_range(0.1..0.3) }
    }
}

/// Positional (0–180°) hobby servo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionalServo {
    /// Shaft angle at a 1000 µs pulse (deg).
    pub offset_deg: f64,
    /// Relative error of the nominal 0.18 °/µs pulse-to-angle gain.
    pub scale_error: f64,
    /// Position-loop time constant (s): the commanded rate is error / `tau_s`.
    pub tau_s: f64,
    /// Motor mechanical time constant (s): the rate follows the commanded rate with this lag.
    pub motor_tau_s: f64,
    /// Slew-rate limit (deg/s).
    pub max_rate_dps: f64,
    /// Half-width of the dead band (µs of pulse): no drive while the error is smaller.
    pub deadband_us: f64,
    /// Shaft vibration while driven.
    pub vibration: Vibration,
}

impl PositionalServo {
    /// Exact gain and offset, no dead band, no vibration; 50 ms loop, 10 ms motor, 300 °/s.
    pub fn ideal() -> Self {
        Self {
            offset_deg: 0.0,
            scale_error: 0.0,
            tau_s: 0.05,
            motor_tau_s: 0.01,
            max_rate_dps: 300.0,
            deadband_us: 0.0,
            vibration: Vibration::NONE,
        }
    }

    /// SG90/MG90S-class servo at 4.8–5 V with a light load.
    pub fn realistic(rng: &mut impl Rng) -> Self {
        Self {
            offset_deg: rng.random_range(-5.0..5.0),
            scale_error: rng.random_range(-0.03..0.03),
            tau_s: rng.random_range(0.03..0.08),
            motor_tau_s: rng.random_range(0.005..0.015),
            max_rate_dps: rng.random_range(300.0..450.0),
            deadband_us: rng.random_range(1.0..3.0),
            vibration: Vibration::realistic(rng),
        }
    }

    /// Shaft angle (deg) the servo settles at for a pulse of `us` µs (dead band aside):
    /// `offset + (1 + scale_error) · (us − 1000) · 0.18`.
    pub fn target_deg(&self, us: f64) -> f64 {
        self.offset_deg + (1.0 + self.scale_error) * (us - 1000.0) * DEG_PER_US
    }
}

/// Continuous-rotation servo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContinuousServo {
    /// Rate 500 µs away from neutral (deg/s); the rate saturates there.
    pub max_rate_dps: f64,
    /// Stop pulse minus 1500 µs (µs).
    pub neutral_offset_us: f64,
    /// Half-width of the stop band around the stop pulse (µs).
    pub deadband_us: f64,
    /// Time constant of the rate response (s).
    pub tau_s: f64,
    /// Shaft vibration while turning.
    pub vibration: Vibration,
}

impl ContinuousServo {
    /// 300 °/s, exact neutral, no dead band, 50 ms lag, no vibration.
    pub fn ideal() -> Self {
        Self { max_rate_dps: 300.0, neutral_offset_us: 0.0, deadband_us: 0.0, tau_s: 0.05, vibration: Vibration::NONE }
    }

    /// FS90R-class servo: untrimmed neutral, a stop band of 5–15 µs.
    pub fn realistic(rng: &mut impl Rng) -> Self {
        Self {
            max_rate_dps: rng.random_range(250.0..450.0),
            neutral_offset_us: rng.random_range(-20.0..20.0),
            deadband_us: rng.random_range(5.0..15.0),
            tau_s: rng.random_range(0.03..0.1),
            vibration: Vibration::realistic(rng),
        }
    }

    /// Steady rate (deg/s) for a pulse of `us` µs:
    /// `max_rate · (us − 1500 − neutral_offset) / 500`, zero inside the stop band, saturated.
    pub fn rate_dps(&self, us: f64) -> f64 {
        let x = us - 1500.0 - self.neutral_offset_us;
        if x.abs() <= self.deadband_us {
            0.0
        } else {
            self.max_rate_dps * (x / 500.0).clamp(-1.0, 1.0)
        }
    }
}

/// The rotation servo: positional (angle commands) or continuous-rotation (speed commands).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ServoModel {
    /// A positional servo.
    Positional(PositionalServo),
    /// A continuous-rotation servo.
    Continuous(ContinuousServo),
}

impl ServoModel {
    pub(crate) fn vibration(&self) -> &Vibration {
        match self {
            Self::Positional(p) => &p.vibration,
            Self::Continuous(c) => &c.vibration,
        }
    }
}

/// Shaft state. Angles in rad, true time in s. The shaft starts at 0 with no pulse (motor idle).
#[derive(Clone)]
pub(crate) struct Servo {
    model: ServoModel,
    stalled: bool,
    pulse_cmd_us: Option<f64>,
    pulse_us: Option<f64>,
    frame: u64,
    t_s: f64,
    angle: f64,
    rate: f64,
    accel: f64,
    jitter: f64,
    jitter_rate: f64,
    jitter_accel: f64,
    rng: ChaCha8Rng,
}

impl Servo {
    pub fn new(model: ServoModel, rng: ChaCha8Rng) -> Self {
        Self {
            model,
            stalled: false,
            pulse_cmd_us: None,
            pulse_us: None,
            frame: 0,
            t_s: 0.0,
            angle: 0.0,
            rate: 0.0,
            accel: 0.0,
            jitter: 0.0,
            jitter_rate: 0.0,
            jitter_accel: 0.0,
            rng,
        }
    }

    /// The same servo with its shaft at `deg` (°) instead of 0.
    pub fn starting_at(mut self, deg: f64) -> Self {
        self.angle = deg.to_radians();
        self
    }

    /// New pulse width; the servo picks it up at the next PWM frame.
    pub fn set_pulse_us(&mut self, us: f64) {
        self.pulse_cmd_us = Some(us);
    }

    /// Stops the pulses from the next PWM frame on: the motor idles.
    pub fn pulse_off(&mut self) {
        self.pulse_cmd_us = None;
    }

    pub fn stall(&mut self, stalled: bool) {
        self.stalled = stalled;
    }

    /// Shaft angle seen by the board, vibration included (rad).
    pub fn angle(&self) -> f64 {
        self.angle + self.jitter
    }

    /// Shaft rate, vibration included (rad/s).
    pub fn rate(&self) -> f64 {
        self.rate + self.jitter_rate
    }

    /// Shaft angular acceleration, vibration included (rad/s²).
    pub fn accel(&self) -> f64 {
        self.accel + self.jitter_accel
    }

    /// Advance by `h` seconds (one integration substep).
    pub fn step(&mut self, h: f64) {
        self.t_s += h;
        let frame = (self.t_s / PWM_FRAME_S) as u64;
        if frame != self.frame {
            self.frame = frame;
            self.pulse_us = self.pulse_cmd_us;
        }

        let rate = if self.stalled {
            0.0
        } else {
            let (cmd, lag_s) = self.commanded_rate();
            cmd + (self.rate - cmd) * (-h / lag_s).exp()
        };
        self.accel = (rate - self.rate) / h;
        self.angle += 0.5 * (rate + self.rate) * h;
        self.rate = rate;

        let v = self.model.vibration();
        let w0 = TAU * v.freq_hz;
        let sigma = v.rms_deg.to_radians();
        // Stationary variance of x'' + 2ζω0 x' + ω0² x = w is q / (4ζω0³) for white w of intensity q.
        let q = 4.0 * v.damping * w0.powi(3) * sigma * sigma;
        let drive = if rate.to_degrees().abs() > MOVING_DPS { (q * h).sqrt() } else { 0.0 };
        self.jitter_accel = -w0 * w0 * self.jitter - 2.0 * v.damping * w0 * self.jitter_rate;
        self.jitter_rate += self.jitter_accel * h + drive * self.rng.sample::<f64, _>(StandardNormal);
        self.jitter += self.jitter_rate * h;
    }

    /// Rate the drive aims at (rad/s) and the lag with which the shaft follows it (s).
    fn commanded_rate(&self) -> (f64, f64) {
        match (&self.model, self.pulse_us) {
            (ServoModel::Positional(p), Some(us)) => {
                let error = p.target_deg(us).to_radians() - self.angle;
                let band = (p.deadband_us * DEG_PER_US * (1.0 + p.scale_error)).to_radians();
                let max = p.max_rate_dps.to_radians();
                let cmd = if error.abs() <= band { 0.0 } else { (error / p.tau_s).clamp(-max, max) };
                (cmd, p.motor_tau_s)
            }
            (ServoModel::Continuous(c), Some(us)) => (c.rate_dps(us).to_radians(), c.tau_s),
            (ServoModel::Positional(p), None) => (0.0, p.motor_tau_s),
            (ServoModel::Continuous(c), None) => (0.0, c.tau_s),
        }
    }
}
