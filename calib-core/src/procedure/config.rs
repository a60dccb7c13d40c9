//! The one configuration of the calibration procedure, with defaults for a positional hobby
//! servo on the Nano 33 BLE.

use crate::estimators::axis::GeometryLimits;
use crate::estimators::bias::BiasLimits;
use crate::estimators::full::FullLimits;
use crate::estimators::rest::RestConfig;
use crate::estimators::rotation::RotationLimits;
use crate::formats::record::SensorSetup;
use crate::procedure::pipeline::{Acceptance, SteadyRate};

/// Tilt settings of the pan/tilt plan (each one pan axis; with the hinge, five axes).
pub const TILT_SETTINGS: usize = 4;

/// The rotation servo.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ServoKind {
    /// Positional servo: pulse `pulse_min_us..pulse_max_us` ↔ angle `angle_min_deg..angle_max_deg`.
    Positional,
    /// Continuous-rotation servo: `neutral_us ± span_us` ↔ full speed either way.
    Continuous {
        /// Pulse of zero speed (µs).
        neutral_us: u16,
        /// Pulse offset of full speed (µs).
        span_us: u16,
        /// Speed used for moves and the spin, as a fraction of full speed.
        speed: f32,
        /// Nominal shaft rate at `speed` (°/s), only for the stall check.
        nominal_rate_dps: f32,
        /// Duration of one move between poses (s).
        move_s: f32,
    },
}

impl ServoKind {
    /// A continuous-rotation servo at 20 % speed (≈ 60 °/s for a 300 °/s servo), 1 s moves.
    pub const CONTINUOUS: ServoKind =
        ServoKind::Continuous { neutral_us: 1500, span_us: 500, speed: 0.2, nominal_rate_dps: 60.0, move_s: 1.0 };
}

/// Procedure configuration. Angles in degrees, times in seconds, pulses in µs.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// The rotation servo.
    pub servo: ServoKind,
    /// Safe pulse range: every servo command is clamped to it.
    pub pulse_min_us: u16,
    /// See `pulse_min_us`.
    pub pulse_max_us: u16,
    /// Nominal angle at `pulse_min_us` (positional).
    pub angle_min_deg: f32,
    /// Nominal angle at `pulse_max_us` (positional).
    pub angle_max_deg: f32,
    /// Static rig poses per pass (≥ 4), spread from `pose_first_deg` to `pose_last_deg`.
    pub pose_count: u8,
    /// First pose angle (positional).
    pub pose_first_deg: f32,
    /// Last pose angle (positional).
    pub pose_last_deg: f32,
    /// Passes there and back over the poses.
    pub round_trips: u8,
    /// Commanded rate of the moves between poses (°/s, positional).
    pub move_rate_dps: f32,
    /// Commanded rate of the paper's constant-rate spin (°/s); 0 skips it.
    pub spin_rate_dps: f32,
    /// The part of that rotation averaged, and what a log's steady run must meet.
    pub steady: SteadyRate,
    /// Duration of the spin with a continuous servo (s).
    pub spin_s: f32,
    /// Still time averaged per rig pose (s).
    pub pose_average_s: f32,
    /// Quasi-static time averaged per hand-held pose (s): longer than the rig's, since a hand's
    /// sway (0.3–1.5 Hz) averages out of the pose's gravity only over a few of its periods.
    pub hand_pose_s: f32,
    /// Still time averaged for the bias (s).
    pub bias_s: f32,
    /// Hand-held accelerometer poses to capture (≥ 6; ≥ 9 fits 9 parameters).
    pub accel_poses: u8,
    /// The hand-held step goes on past `accel_poses` (each further pose adds a move, not an
    /// accelerometer pose) until its moves alone give every element of `K` this 1σ
    /// ([`crate::estimators::rotation::Rotations::add_last_at_identity`]), or it holds `max_hand_poses`.
    pub hand_k_sigma: f32,
    /// Most hand-held poses: the bias between the rests that bound the step is predicted, and
    /// its error grows with the step's length. At most
    /// [`crate::estimators::rotation::MAX_ROTATION_POSES`] (32): a pose beyond the store fails
    /// the calibration with [`crate::Error::CapacityExceeded`].
    pub max_hand_poses: u8,
    /// Smallest angle between two hand-held poses (°).
    pub accel_min_separation_deg: f32,
    /// Pan/tilt bracket (firmware feature `tilt-servo`): a tilt servo on channel 1 rides on the
    /// rotation servo (its angle is the tilt plus 90°, mapped like the rotation servo's). The rig
    /// poses are then taken at every `tilt_settings_deg`, with the tilt moves between them at pan
    /// `pose_first_deg`; they give the full 3×3 `K` and, spread over pan × tilt, the
    /// accelerometer (no hand-held step). Needs a positional rotation servo.
    pub pan_tilt: bool,
    /// Tilt settings of the pan/tilt plan (°, 0 = level), in the order visited.
    pub tilt_settings_deg: [f32; TILT_SETTINGS],
    /// The full-`K` estimator's requirements (pan/tilt plan, and the rig's axis with the
    /// hand-held rotations).
    pub full: FullLimits,
    /// The rotation constraints of the moves between hand-held poses.
    pub rotation: RotationLimits,
    /// Stillness thresholds of the rig's rests (a servo holding still) and the bias.
    pub rest: RestConfig,
    /// Stillness thresholds of the hand-held poses (a person's hand sways and trembles).
    pub hand_rest: RestConfig,
    /// Bias limits.
    pub bias: BiasLimits,
    /// Rig geometry requirements.
    pub geometry: GeometryLimits,
    /// Retakes of a disturbed pose (or bias) before giving up.
    pub pose_retries: u8,
    /// Time to reach rest in a static phase (s).
    pub rest_timeout_s: f32,
    /// Time for all hand-held poses (s).
    pub handheld_timeout_s: f32,
    /// Time to put the board back on the shaft and press the button (s).
    pub reattach_timeout_s: f32,
    /// Longest gap between sensor samples (s).
    pub sample_timeout_s: f32,
    /// A move must turn the gyro by at least this fraction of the commanded angle.
    pub min_turn_fraction: f32,
    /// The sensor's ODR and full scales, stored in the record; samples at 98 % of a full scale
    /// are saturated.
    pub setup: SensorSetup,
    /// What a result must meet to be stored.
    pub acceptance: Acceptance,
}

impl Config {
    /// SG90-class positional servo on D9, LSM9DS1 at ±2 g / ±500 °/s: 7 poses over 0–180°
    /// there and back at 30 °/s, then a 20 °/s rotation; 12 hand-held accelerometer poses.
    /// The defaults (also as `Default`).
    pub const DEFAULT: Config = Config {
        servo: ServoKind::Positional,
        pulse_min_us: 1000,
        pulse_max_us: 2000,
        angle_min_deg: 0.0,
        angle_max_deg: 180.0,
        pose_count: 7,
        pose_first_deg: 0.0,
        pose_last_deg: 180.0,
        round_trips: 1,
        move_rate_dps: 30.0,
        spin_rate_dps: 20.0,
        steady: SteadyRate::DEFAULT,
        spin_s: 10.0,
        pose_average_s: 1.0,
        hand_pose_s: 2.0,
        bias_s: 2.0,
        accel_poses: 12,
        hand_k_sigma: 1.6e-4,
        max_hand_poses: 20,
        accel_min_separation_deg: 30.0,
        pan_tilt: false,
        tilt_settings_deg: [-60.0, -20.0, 20.0, 60.0],
        full: FullLimits::DEFAULT,
        rotation: RotationLimits::DEFAULT,
        rest: RestConfig::DEFAULT,
        hand_rest: RestConfig::HAND,
        bias: BiasLimits::DEFAULT,
        geometry: GeometryLimits::DEFAULT,
        pose_retries: 3,
        rest_timeout_s: 20.0,
        handheld_timeout_s: 300.0,
        reattach_timeout_s: 300.0,
        sample_timeout_s: 0.5,
        min_turn_fraction: 0.5,
        setup: SensorSetup::DEFAULT,
        acceptance: Acceptance { k_min: 0.8, k_max: 1.2, max_sigma_k: 0.005, max_accel_rms_g: 0.01 },
    };
}

impl Config {
    /// The pan/tilt plan (firmware feature `tilt-servo`): at each of the four tilt settings, rig
    /// poses at 0–180° every 45° there and back, tilt moves at pan 0 up through the settings and
    /// back down (moves at 60 °/s), no paper spin; the full `K` from the 32 pan and 6 tilt
    /// moves, the accelerometer from the 20 distinct poses. Each pose is averaged for 3 s (the
    /// default's 1 s triples the noise in the accelerometer, which has no hand-held poses here,
    /// and in the rest biases that bound the moves: `full-k-bench` measures both).
    pub const PAN_TILT: Config =
        Config { pan_tilt: true, pose_count: 5, move_rate_dps: 60.0, spin_rate_dps: 0.0, pose_average_s: 3.0, ..Config::DEFAULT };
}

impl Default for Config {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl Config {
    /// Pulse (µs) for a nominal positional angle (°), clamped to the safe range.
    pub fn pulse_for_deg(&self, deg: f32) -> u16 {
        let span = self.angle_max_deg - self.angle_min_deg;
        let x = if span != 0.0 { (deg - self.angle_min_deg) / span } else { 0.0 };
        let us = self.pulse_min_us as f32 + x * (self.pulse_max_us as f32 - self.pulse_min_us as f32);
        self.clamp_pulse(us)
    }

    /// Clamps a pulse (µs) to `pulse_min_us..=pulse_max_us`.
    pub fn clamp_pulse(&self, us: f32) -> u16 {
        let us = if us.is_finite() { us } else { self.pulse_min_us as f32 };
        (libm::roundf(us) as i32).clamp(self.pulse_min_us as i32, self.pulse_max_us as i32) as u16
    }

    /// Rig steps (static poses) at one rotation axis: there and back `round_trips` times.
    pub fn rig_steps(&self) -> u16 {
        1 + 2 * (self.pose_count.max(2) as u16 - 1) * self.round_trips.max(1) as u16
    }

    /// The servo this build drives: the `servo` field, a positional one when calib-core is
    /// built with `positional-only` (the firmware's builds: the continuous servo's code is not
    /// linked).
    pub const fn servo(&self) -> ServoKind {
        if cfg!(feature = "positional-only") {
            ServoKind::Positional
        } else {
            self.servo
        }
    }

    /// The plan this build runs: [`Self::pan_tilt`], unless calib-core is built for one plan
    /// alone (features `pan-tilt-only`, which wins, or `one-servo-only`: the firmware's builds),
    /// whose code alone is then linked.
    pub const fn is_pan_tilt(&self) -> bool {
        if cfg!(feature = "pan-tilt-only") {
            true
        } else if cfg!(feature = "one-servo-only") {
            false
        } else {
            self.pan_tilt
        }
    }

    /// Rig steps in one run: with the pan/tilt plan `rig_steps` at every tilt setting, then the
    /// tilt moves back through the settings at pan `pose_first_deg` (the return half of the
    /// hinge's back-and-forth pairs).
    pub fn plan_steps(&self) -> u16 {
        if self.is_pan_tilt() {
            self.rig_steps() * TILT_SETTINGS as u16 + TILT_SETTINGS as u16 - 1
        } else {
            self.rig_steps()
        }
    }

    /// Tilt setting (index) and step within it of run step `k` (the setting is 0 without a tilt
    /// servo). Step 0 of a setting, after the first, is reached by a tilt move; so is every step
    /// of the return (step 0 of the settings in reverse order).
    pub fn plan_at(&self, k: u16) -> (usize, u16) {
        let (per, n) = (self.rig_steps(), TILT_SETTINGS as u16);
        match self.is_pan_tilt() {
            false => (0, k),
            true if k < per * n => ((k / per) as usize, k % per),
            true => ((n - 2).saturating_sub(k - per * n) as usize, 0),
        }
    }

    /// Pose slot (0..pose_count) visited at rig step `k`.
    pub fn pose_slot(&self, k: u16) -> u16 {
        let n = self.pose_count.max(2) as u16;
        let p = k % (2 * (n - 1));
        if p < n {
            p
        } else {
            2 * (n - 1) - p
        }
    }

    /// Commanded angle (°) of rig step `k` (positional).
    pub fn step_deg(&self, k: u16) -> f32 {
        let n = self.pose_count.max(2) as f32;
        self.pose_first_deg + (self.pose_last_deg - self.pose_first_deg) * self.pose_slot(k) as f32 / (n - 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_goes_there_and_back() {
        let c = Config { pose_count: 4, ..Config::default() };
        assert_eq!(c.rig_steps(), 7);
        let slots: [u16; 7] = core::array::from_fn(|k| c.pose_slot(k as u16));
        assert_eq!(slots, [0, 1, 2, 3, 2, 1, 0]);
        assert_eq!(c.step_deg(3), 180.0);
    }

    #[test]
    fn the_pan_tilt_plan_sweeps_every_setting_and_tilts_at_pan_0() {
        let c = Config::PAN_TILT;
        assert_eq!(c.plan_steps(), 39);
        assert_eq!(c.plan_at(8), (0, 8));
        // The return: tilt moves back to settings 2, 1, 0.
        assert_eq!([c.plan_at(35), c.plan_at(36), c.plan_at(37), c.plan_at(38)], [(3, 8), (2, 0), (1, 0), (0, 0)]);
        assert_eq!(c.plan_at(9), (1, 0));
        assert_eq!(c.step_deg(c.plan_at(9).1), 0.0);
        assert_eq!(c.step_deg(c.plan_at(13).1), 180.0);
        assert_eq!(Config::DEFAULT.plan_at(13), (0, 13));
    }

    #[test]
    fn pulses_are_clamped_to_the_safe_range() {
        let c = Config::default();
        assert_eq!(c.pulse_for_deg(90.0), 1500);
        assert_eq!(c.pulse_for_deg(500.0), 2000);
        assert_eq!(c.pulse_for_deg(-50.0), 1000);
        assert_eq!(c.clamp_pulse(f32::NAN), 1000);
    }
}
