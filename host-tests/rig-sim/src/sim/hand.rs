//! A person's hand holding the board: postural sway with physiological tremor on top.
//!
//! Physiological tremor is an 8–12 Hz oscillation present in every healthy hand held against
//! gravity (Elble & Koller, *Tremor*, Johns Hopkins University Press 1990; McAuley & Marsden,
//! "Physiological and pathological tremors and rhythmic central motor control", Brain 123,
//! 2000); under it the arm sways slowly. For a board held in the air (issue 31): sway of
//! 0.1–0.3° at 0.3–1.5 Hz, tremor on top, a gyro rate RMS up to ≈ 2 °/s and linear
//! accelerations up to ≈ 0.01 g during a "still" pose; braced on a table (the wrist resting),
//! about a quarter of that. Each component is a sinusoid about (or along) a random direction, so
//! the attitude and the position stay bounded.

use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;
use std::f64::consts::TAU;

/// How the board is held.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HandLevel {
    /// Wrist or forearm resting on a table: a quarter of the free hand's motion.
    Braced,
    /// Held in the air.
    Free,
}

impl HandLevel {
    /// Its name in options and tables.
    pub fn name(self) -> &'static str {
        match self {
            HandLevel::Braced => "braced",
            HandLevel::Free => "free",
        }
    }

    /// A hand by its name (`braced`, `free`), `none` for a perfectly still one: for command
    /// lines (`simulate --hand`, `rotation-bench --hand`).
    pub fn parse(name: &str) -> Result<Option<HandLevel>, String> {
        match name {
            "braced" => Ok(Some(HandLevel::Braced)),
            "free" => Ok(Some(HandLevel::Free)),
            "none" => Ok(None),
            _ => Err(format!("{name:?}: one of braced, free, none")),
        }
    }

    fn gain(self) -> f64 {
        match self {
            HandLevel::Braced => 0.25,
            HandLevel::Free => 1.0,
        }
    }
}

/// Sway components (0.3–1.5 Hz) and tremor components (8–12 Hz), each for the attitude and for
/// the position.
const SWAY_PARTS: usize = 3;
const TREMOR_PARTS: usize = 3;
/// Time for the hand's motion to set in when it takes the board, and to fade when it lets go (s).
const ONSET_S: f64 = 0.5;

/// One sinusoid: unit direction, amplitude, angular frequency (rad/s), phase (rad).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Part {
    dir: Vector3<f64>,
    amp: f64,
    w: f64,
    phase: f64,
}

impl Part {
    fn draw(rng: &mut impl Rng, amp: f64, hz: std::ops::Range<f64>) -> Self {
        let dir = Vector3::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal)).normalize();
        Part { dir, amp, w: TAU * rng.random_range(hz), phase: rng.random_range(0.0..TAU) }
    }

    fn at(&self, t: f64) -> Vector3<f64> {
        self.dir * (self.amp * (self.w * t + self.phase).sin())
    }
}

/// A hand's motion, drawn once per rig.
#[derive(Clone, Debug, PartialEq)]
pub struct Hand {
    /// Rotation-vector components (rad, body frame).
    turn: [Part; SWAY_PARTS + TREMOR_PARTS],
    /// Linear-acceleration components (g, world frame).
    accel: [Part; SWAY_PARTS + TREMOR_PARTS],
}

impl Hand {
    /// A hand of `level` drawn from `rng`. Free hand: each sway component 0.06–0.17° (together
    /// 0.1–0.3°), each tremor component 0.006–0.015° (≈ 0.4–0.9 °/s at 10 Hz); the hand's
    /// position sways 0.3–0.6 mm per component at 1 Hz, falling as 1/f (a steady sway speed: 1–2
    /// mm at 0.3 Hz), and trembles 5–10 µm, so linear accelerations reach ≈ 0.01 g, mostly the
    /// tremor's. Braced: all of it × 0.25.
    pub fn new(level: HandLevel, rng: &mut impl Rng) -> Self {
        let k = level.gain();
        let mut draw = |sway: std::ops::Range<f64>, tremor: std::ops::Range<f64>, to_amp: &dyn Fn(f64, f64, bool) -> f64| {
            core::array::from_fn(|i| {
                let is_sway = i < SWAY_PARTS;
                let (range, hz) = if is_sway { (sway.clone(), 0.3..1.5) } else { (tremor.clone(), 8.0..12.0) };
                let size = rng.random_range(range);
                let mut p = Part::draw(rng, 0.0, hz);
                p.amp = k * to_amp(size, p.w, is_sway);
                p
            })
        };
        let turn = draw(0.06..0.17, 0.006..0.015, &|deg, _, _| deg.to_radians());
        // Displacement amplitude (mm; the sway's at 1 Hz, as 1/f) → acceleration amplitude ω² x (g).
        let accel = draw(0.3..0.6, 0.005..0.01, &|mm, w, is_sway| {
            let x_m = if is_sway { mm * 1e-3 * TAU / w } else { mm * 1e-3 };
            w * w * x_m / super::G0
        });
        Hand { turn, accel }
    }

    /// How far the hand's motion has set in at `t_s`, the board taken at `since_s` and (if
    /// so) let go at `until_s` (0–1, smooth).
    pub fn envelope(t_s: f64, since_s: f64, until_s: Option<f64>) -> f64 {
        let on = super::kinematics::smoothstep((t_s - since_s) / ONSET_S);
        let off = until_s.map_or(1.0, |u| 1.0 - super::kinematics::smoothstep((t_s - u) / ONSET_S));
        on * off
    }

    /// The hand's turn at true time `t_s` scaled by `gain` (body frame, applied after the
    /// attitude it holds).
    pub fn rotation(&self, t_s: f64, gain: f64) -> UnitQuaternion<f64> {
        UnitQuaternion::from_scaled_axis(self.turn.iter().map(|p| p.at(t_s)).sum::<Vector3<f64>>() * gain)
    }

    /// The hand's linear acceleration at true time `t_s` scaled by `gain` (g, world frame).
    pub fn accel_g(&self, t_s: f64, gain: f64) -> Vector3<f64> {
        self.accel.iter().map(|p| p.at(t_s)).sum::<Vector3<f64>>() * gain
    }
}
