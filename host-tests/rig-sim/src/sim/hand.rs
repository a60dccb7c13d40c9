//! A person's hand holding the board: postural sway with physiological tremor on top, as a
//! family of hands.
//!
//! Physiological tremor is an 8–12 Hz oscillation present in every healthy hand held against
//! gravity (Elble & Koller, *Tremor*, Johns Hopkins University Press 1990; McAuley & Marsden,
//! "Physiological and pathological tremors and rhythmic central motor control", Brain 123,
//! 2000); under it the arm sways slowly. For a board held in the air (issue 31): sway of
//! 0.1–0.3° at 0.3–1.5 Hz, tremor on top, a gyro rate RMS up to ≈ 2 °/s and linear
//! accelerations up to ≈ 0.01 g during a "still" pose; braced on a table (the wrist resting),
//! about a quarter of that. Each component is a sinusoid about (or along) a direction, so the
//! attitude and the position stay bounded.
//!
//! The family (issue 48): the hand turns the board about a pivot at the sensor or at a wrist,
//! an elbow or a shoulder (a lever arm `r`, body frame, from the pivot to the sensor), so the
//! sensor also feels the turn's own linear acceleration `α × r + ω × (ω × r)`; its sway's
//! amplitude, band and axes differ from hand to hand. What the estimator must not assume away.

use nalgebra::{UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;
use std::f64::consts::TAU;
use std::ops::Range;

/// How the board is held: members of the hand family ([`HandLevel::spec`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HandLevel {
    /// Wrist or forearm resting on a table: a quarter of the free hand's motion, pivoting at
    /// the sensor.
    Braced,
    /// Held in the air, pivoting at the sensor.
    Free,
    /// Forearm resting, the hand turning at the wrist 8–15 cm from the sensor: sway ≈ 0.05°
    /// at 0.4–1.5 Hz.
    Wrist,
    /// Held in the air, the forearm turning at the elbow 20–40 cm from the sensor: sway ≈ 0.15°
    /// at 0.4–1.5 Hz.
    Arm,
    /// Held in the air, nodding slowly (0.15–0.5 Hz) about one axis at the elbow 25–40 cm away.
    Nod,
}

/// Every member of the family, for tests and benchmarks that run across it.
pub const HANDS: [HandLevel; 5] = [HandLevel::Braced, HandLevel::Free, HandLevel::Wrist, HandLevel::Arm, HandLevel::Nod];

/// What a hand is made of: each of its sway and tremor components' amplitude range (° of
/// turn) and band (Hz), the lever arm from its pivot to the sensor (m), how its components'
/// axes are drawn and its own translation (mm per sway component at 1 Hz, falling as 1/f; µm
/// per tremor component).
#[derive(Clone, Debug, PartialEq)]
pub struct HandSpec {
    /// A sway component's amplitude (° of turn).
    pub sway_deg: Range<f64>,
    /// Its frequency (Hz).
    pub sway_hz: Range<f64>,
    /// A tremor component's amplitude (°).
    pub tremor_deg: Range<f64>,
    /// Its frequency (Hz).
    pub tremor_hz: Range<f64>,
    /// Distance of the pivot from the sensor (m; 0: it turns about the sensor).
    pub lever_m: Range<f64>,
    /// Largest angle (°) of a sway component's axis from the hand's main axis (90: any axis).
    pub axis_spread_deg: f64,
    /// The hand's own translation per sway component (mm at 1 Hz, falling as 1/f).
    pub translation_mm: Range<f64>,
    /// Its translation per tremor component (µm).
    pub translation_tremor_um: Range<f64>,
}

impl HandLevel {
    /// Its name in options and tables.
    pub fn name(self) -> &'static str {
        match self {
            HandLevel::Braced => "braced",
            HandLevel::Free => "free",
            HandLevel::Wrist => "wrist",
            HandLevel::Arm => "arm",
            HandLevel::Nod => "nod",
        }
    }

    /// A hand by its name ([`Self::name`]), `none` for a perfectly still one: for command lines
    /// (`simulate --hand`, `rotation-bench --hand`).
    pub fn parse(name: &str) -> Result<Option<HandLevel>, String> {
        match HANDS.into_iter().find(|h| h.name() == name) {
            Some(h) => Ok(Some(h)),
            None if name == "none" => Ok(None),
            None => Err(format!("{name:?}: one of braced, free, wrist, arm, nod, none")),
        }
    }

    /// What this hand is made of. Free: each sway component 0.06–0.17° (together 0.1–0.3°) at
    /// 0.3–1.5 Hz, each tremor component 0.006–0.015° (≈ 0.4–0.9 °/s at 10 Hz); the hand's
    /// position sways 0.3–0.6 mm per component at 1 Hz, falling as 1/f (a steady sway speed:
    /// 1–2 mm at 0.3 Hz), and trembles 5–10 µm, so linear accelerations reach ≈ 0.01 g, mostly
    /// the tremor's. Braced: all of it × 0.25.
    pub fn spec(self) -> HandSpec {
        let free = HandSpec {
            sway_deg: 0.06..0.17,
            sway_hz: 0.3..1.5,
            tremor_deg: 0.006..0.015,
            tremor_hz: 8.0..12.0,
            lever_m: 0.0..0.0,
            axis_spread_deg: 90.0,
            translation_mm: 0.3..0.6,
            translation_tremor_um: 5.0..10.0,
        };
        let quarter = |r: Range<f64>| r.start * 0.25..r.end * 0.25;
        match self {
            HandLevel::Free => free,
            HandLevel::Braced => HandSpec {
                sway_deg: quarter(free.sway_deg),
                tremor_deg: quarter(free.tremor_deg),
                translation_mm: quarter(free.translation_mm),
                translation_tremor_um: quarter(free.translation_tremor_um),
                ..free
            },
            HandLevel::Wrist => HandSpec {
                sway_deg: 0.02..0.04,
                sway_hz: 0.4..1.5,
                tremor_deg: 0.003..0.006,
                lever_m: 0.08..0.15,
                translation_mm: 0.0..0.0,
                translation_tremor_um: 0.0..0.0,
                ..free
            },
            HandLevel::Arm => HandSpec {
                sway_deg: 0.05..0.1,
                sway_hz: 0.4..1.5,
                lever_m: 0.2..0.4,
                translation_mm: 0.0..0.0,
                translation_tremor_um: 0.0..0.0,
                ..free
            },
            HandLevel::Nod => HandSpec {
                sway_deg: 0.05..0.1,
                sway_hz: 0.15..0.5,
                lever_m: 0.25..0.4,
                axis_spread_deg: 20.0,
                translation_mm: 0.0..0.0,
                translation_tremor_um: 0.0..0.0,
                ..free
            },
        }
    }
}

/// Sway components and tremor components, each for the attitude and for the position.
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

fn random_dir(rng: &mut impl Rng) -> Vector3<f64> {
    Vector3::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal)).normalize()
}

impl Part {
    /// A component about a direction within `spread_deg` of `main`, at a frequency in `hz`.
    fn draw(rng: &mut impl Rng, main: &Vector3<f64>, spread_deg: f64, hz: Range<f64>) -> Self {
        let dir = loop {
            let d = random_dir(rng);
            if spread_deg >= 90.0 || d.dot(main).abs() >= spread_deg.to_radians().cos() {
                break d;
            }
        };
        Part { dir, amp: 0.0, w: TAU * rng.random_range(hz), phase: rng.random_range(0.0..TAU) }
    }

    /// Its value and its first two time derivatives at `t`.
    fn at(&self, t: f64) -> [Vector3<f64>; 3] {
        let (s, c) = (self.w * t + self.phase).sin_cos();
        [s, self.w * c, -self.w * self.w * s].map(|k| self.dir * (self.amp * k))
    }
}

fn range(rng: &mut impl Rng, r: &Range<f64>) -> f64 {
    if r.is_empty() {
        r.start
    } else {
        rng.random_range(r.clone())
    }
}

/// A hand's motion, drawn once per rig.
#[derive(Clone, Debug, PartialEq)]
pub struct Hand {
    /// Rotation-vector components (rad, body frame).
    turn: [Part; SWAY_PARTS + TREMOR_PARTS],
    /// Translation components (m, world frame).
    shift: [Part; SWAY_PARTS + TREMOR_PARTS],
    /// From the pivot to the sensor (m, body frame).
    lever_m: Vector3<f64>,
}

impl Hand {
    /// A hand of `level` ([`HandLevel::spec`]) drawn from `rng`.
    pub fn new(level: HandLevel, rng: &mut impl Rng) -> Self {
        let s = level.spec();
        let main = random_dir(rng);
        let turn = core::array::from_fn(|i| {
            let (deg, hz, spread) =
                if i < SWAY_PARTS { (&s.sway_deg, &s.sway_hz, s.axis_spread_deg) } else { (&s.tremor_deg, &s.tremor_hz, 90.0) };
            let mut p = Part::draw(rng, &main, spread, hz.clone());
            p.amp = range(rng, deg).to_radians();
            p
        });
        let shift = core::array::from_fn(|i| {
            let is_sway = i < SWAY_PARTS;
            let hz = if is_sway { s.sway_hz.clone() } else { s.tremor_hz.clone() };
            let mut p = Part::draw(rng, &main, 90.0, hz);
            // The sway's displacement is given at 1 Hz and falls as 1/f.
            p.amp = if is_sway { range(rng, &s.translation_mm) * 1e-3 * TAU / p.w } else { range(rng, &s.translation_tremor_um) * 1e-6 };
            p
        });
        let lever_m = random_dir(rng) * range(rng, &s.lever_m);
        Hand { turn, shift, lever_m }
    }

    /// How far the hand's motion has set in at `t_s`, the board taken at `since_s` and (if
    /// so) let go at `until_s` (0–1, smooth).
    pub fn envelope(t_s: f64, since_s: f64, until_s: Option<f64>) -> f64 {
        let on = super::kinematics::smoothstep((t_s - since_s) / ONSET_S);
        let off = until_s.map_or(1.0, |u| 1.0 - super::kinematics::smoothstep((t_s - u) / ONSET_S));
        on * off
    }

    fn sum(parts: &[Part], t_s: f64, gain: f64) -> [Vector3<f64>; 3] {
        parts.iter().fold([Vector3::zeros(); 3], |acc, p| {
            let v = p.at(t_s);
            [acc[0] + v[0] * gain, acc[1] + v[1] * gain, acc[2] + v[2] * gain]
        })
    }

    /// The hand's turn at true time `t_s` scaled by `gain` (body frame, applied after the
    /// attitude it holds).
    pub fn rotation(&self, t_s: f64, gain: f64) -> UnitQuaternion<f64> {
        UnitQuaternion::from_scaled_axis(Self::sum(&self.turn, t_s, gain)[0])
    }

    /// The hand's linear acceleration at true time `t_s` scaled by `gain` (g): its own
    /// translation's (world frame) and its sway's turn about the pivot, `α × r + ω × (ω × r)`
    /// (body frame; small-angle rates).
    pub fn accel_g(&self, t_s: f64, gain: f64) -> (Vector3<f64>, Vector3<f64>) {
        let world = Self::sum(&self.shift, t_s, gain)[2] / super::G0;
        // The tremor is the hand's own (it turns about the wrist, near the sensor); the sway
        // turns the arm about its pivot.
        let [_, w, a] = Self::sum(&self.turn[..SWAY_PARTS], t_s, gain);
        let r = &self.lever_m;
        (world, (a.cross(r) + w.cross(&w.cross(r))) / super::G0)
    }
}
