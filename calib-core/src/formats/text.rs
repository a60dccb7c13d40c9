//! The procedure's reports as text lines: the one wording of every line the firmware logs, over
//! RTT (as a defmt string) and over USB serial alike, and of [`crate::Error`]'s messages. The
//! lines the PC reacts to are [`crate::formats::protocol`]'s, each beside its parser: [`report`] writes
//! those through it.
//!
//! Numbers are written digit by digit ([`Fixed`]): `core::fmt`'s float code is ~6 KiB
//! of flash the firmware does not have.

use crate::estimators::rotation::Rejected;
use crate::formats::log::{decimal, fixed};
use crate::formats::protocol::{self, RecordLine};
use crate::procedure::{Phase, Report};
use crate::{Mat3, Vec3};
use core::fmt::{self, Display, Write};

/// What a dip's sign means, said beside every dip the board reports: turns cannot tell a field
/// from its negative, so the sign is what checks the magnetometer's axes against where it is.
pub const DIP_SIGN: &str = "positive: the field points down (northern hemisphere)";

/// `v` with this many decimals (≤ 9), e.g. `Fixed(1.23456, 3)` → `1.235`; NaN → `nan`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fixed(pub f32, pub u32);

impl Display for Fixed {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fixed(f, self.0, self.1)
    }
}

/// An integer, e.g. `Int(-12)` → `-12`: written by the same digit writer as [`Fixed`] (the
/// integers' `core::fmt` code is another 1.4 KiB of flash).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Int(pub i64);

impl Display for Int {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        decimal(f, self.0 < 0, self.0.unsigned_abs(), 0)
    }
}

/// An unsigned integer in upper-case hexadecimal, at least this many digits (8 at most): `Hex(0x3d, 2)` →
/// `3D` (a register's or an ID's value).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hex(pub u32, pub u32);

impl Display for Hex {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let digits = (1..8).find(|&n| self.0 >> (4 * n) == 0).unwrap_or(8).max(self.1.min(8));
        (0..digits).rev().try_for_each(|n| f.write_char(char::from(b"0123456789ABCDEF"[(self.0 >> (4 * n) & 0xF) as usize])))
    }
}

/// Words as an argument of `write!`, written as they are (a bare `&str` goes through
/// `Formatter::pad`, another 0.6 KiB of flash for widths no line uses).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Text<'a>(pub &'a str);

impl Display for Text<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.0)
    }
}

/// Three numbers in brackets with this many decimals: `[x y z]`.
pub struct V3(pub Vec3, pub u32);

impl Display for V3 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let [x, y, z] = self.0.map(|v| Fixed(v, self.1));
        write!(f, "[{x} {y} {z}]")
    }
}

/// A matrix with this many decimals, rows separated by `;`: `[a b c; d e f; g h i]`.
pub struct M3(pub Mat3, pub u32);

impl Display for M3 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, r) in self.0.iter().enumerate() {
            f.write_str(if i == 0 { "[" } else { "; " })?;
            let [x, y, z] = r.map(|v| Fixed(v, self.1));
            write!(f, "{x} {y} {z}")?;
        }
        f.write_str("]")
    }
}

/// How much a line matters (the defmt level the firmware logs it at).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// Progress and results.
    Info,
    /// Something went wrong but the calibration goes on.
    Warn,
    /// The calibration failed.
    Error,
}

/// The level of a report's line.
pub fn level(r: &Report) -> Level {
    match r {
        Report::Retake { .. } | Report::HandMove { rejected: Some(_), .. } | Report::EstimatorFailed { .. } => Level::Warn,
        Report::Failed(_) => Level::Error,
        _ => Level::Info,
    }
}

/// `; K to <σ> 1 sigma by the moves (goal <σ>)` once the hand-held moves give `K` a 1σ.
fn k_sigma_goal(w: &mut impl Write, k_sigma: f32, goal: f32) -> fmt::Result {
    match k_sigma.is_finite() {
        true => write!(w, "; K to {} 1 sigma by the moves (goal {})", Fixed(k_sigma, 6), Fixed(goal, 6)),
        false => Ok(()),
    }
}

/// Writes a report as one line (no line ending).
pub fn report(w: &mut impl Write, r: &Report) -> fmt::Result {
    match r {
        Report::Phase(p) => protocol::phase(w, *p),
        Report::Bias(b) => {
            write!(w, "gyro bias {} dps, 1 sigma {}, {} samples", V3(b.bias_dps, 4), V3(b.sigma_dps, 5), Int(b.samples.into()))
        }
        Report::AccelPose { index, accel_g } => protocol::hand_held_pose(w, *index, accel_g),
        Report::Accel(c) => write!(
            w,
            "accelerometer {}: | |a| - 1 | rms {} g -> {} g over {} poses; offset {} g",
            Text(c.model.name()),
            Fixed(c.rms_before_g, 5),
            Fixed(c.rms_after_g, 5),
            Int(c.poses.into()),
            V3(c.offset_g, 4)
        ),
        Report::Mag(c) => write!(
            w,
            "magnetometer: field {} +- {} uT at dip {} +- {} deg ({}); die turned {} +- {} deg; residual {} uT rms, {} % of the sphere, {} samples, {} poses; offset {} uT",
            Fixed(c.field_ut, 2),
            Fixed(c.sigma_field_ut, 2),
            Fixed(c.dip_deg, 2),
            Fixed(c.sigma_dip_deg, 2),
            Text(DIP_SIGN),
            Fixed(c.alignment_deg, 2),
            Fixed(c.sigma_alignment_deg, 2),
            Fixed(c.residual_ut, 3),
            Fixed(c.coverage * 100.0, 0),
            Int(c.samples.into()),
            Int(c.poses.into()),
            V3(c.offset_ut, 2)
        ),
        Report::RigPose { index, servo_deg, accel_g } => protocol::rig_pose(w, *index, *servo_deg, accel_g),
        Report::Retake { index, retries } => write!(w, "pose {} disturbed: retake {}", Int((*index).into()), Int((*retries).into())),
        Report::Move { from, to, gyro_turn_deg } => {
            write!(w, "move {} -> {}: gyro turned {} deg", Int((*from).into()), Int((*to).into()), Fixed(*gyro_turn_deg, 2))
        }
        Report::Gyro(c) => {
            let q = &c.quality;
            write!(
                w,
                "{} estimator: K = diag{} +- {} 1 sigma; invariant spread {} -> {}; cond {}; tilt {} deg, span {} deg",
                Text(c.method.name()),
                V3([c.k[0][0], c.k[1][1], c.k[2][2]], 6),
                V3(q.sigma_k, 6),
                Fixed(q.invariant_before.relative_std(), 6),
                Fixed(q.invariant_after.relative_std(), 6),
                Fixed(q.condition, 0),
                Fixed(q.tilt_deg, 1),
                Fixed(q.span_deg, 1)
            )
        }
        Report::FullK { k, sigma_k, condition, non_coplanar_deg, residual_rms_deg, axes, moves } => write!(
            w,
            "full K = {} +- {} 1 sigma; {} axes {} deg from coplanar, {} moves, residual {} deg rms, cond {}",
            M3(*k, 6),
            M3(*sigma_k, 6),
            Int((*axes).into()),
            Fixed(*non_coplanar_deg, 1),
            Int((*moves).into()),
            Fixed(*residual_rms_deg, 4),
            Fixed(*condition, 0)
        ),
        Report::HandMove { from, to, rejected: None, turn_deg, spread, need, k_sigma, goal } => {
            write!(
                w,
                "hand-held move {} -> {}: turned {} deg; axes spread {} (need {}: turn about varied axes)",
                Int((*from).into()),
                Int((*to).into()),
                Fixed(*turn_deg, 1),
                Fixed(*spread, 3),
                Fixed(*need, 3)
            )?;
            k_sigma_goal(w, *k_sigma, *goal)
        }
        Report::HandMove { from, to, rejected: Some(why), k_sigma, goal, .. } => {
            write!(w, "hand-held move {} -> {} not used: {}", Int((*from).into()), Int((*to).into()), Text(why.describe()))?;
            k_sigma_goal(w, *k_sigma, *goal)
        }
        Report::Rotations { moves, rejected: r, residual_deg } => {
            write!(w, "rotation constraints: {} moves, misfit [", Int((*moves).into()))?;
            for (i, m) in residual_deg[..(*moves as usize).min(residual_deg.len())].iter().enumerate() {
                w.write_str(if i == 0 { "" } else { " " })?;
                write!(w, "{}", Fixed(*m, 3))?;
            }
            write!(w, "] deg; rejected:")?;
            for (why, n) in Rejected::ALL.iter().zip(r) {
                write!(w, " {} {},", Int((*n).into()), Text(why.name()))?;
            }
            Ok(())
        }
        Report::TempCo(Some(c)) => write!(
            w,
            "gyro bias tempco {} dps/C, 1 sigma {}, over {}..{} C",
            V3(c.dps_per_c, 4),
            V3(c.sigma_dps_per_c, 4),
            Fixed(c.range_c[0], 2),
            Fixed(c.range_c[1], 2)
        ),
        Report::TempCo(None) => write!(
            w,
            "gyro bias tempco unknown: the rests' temperatures spanned < {} C (or were not read)",
            Fixed(crate::estimators::bias::MIN_TEMP_SPAN_C, 1)
        ),
        Report::EstimatorFailed { method, error } => write!(w, "{} estimator failed: {error}", Text(method.name())),
        Report::Done(rec) => protocol::record(w, RecordLine::CalibrationDone, rec),
        Report::Failed(e) => protocol::failed(w, e),
    }
}

impl Phase {
    /// What the user must do in this phase, if anything.
    pub fn instruction(self) -> Option<&'static str> {
        Some(match self {
            Phase::WaitRest | Phase::Bias => "keep the rig still",
            Phase::HandHeld => {
                "unclamp the board; hold it still in a new orientation each time the LED blinks yellow, about 4 s each, turning it about varied axes in between"
            }
            Phase::Reattach => "clamp the board back on the servo shaft, then press the button (or send c)",
            Phase::RigPoses | Phase::Spin => "hands off: the servos move the board",
            _ => return None,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::format;
    use std::string::String;

    #[test]
    fn integers_and_words_match_core_fmt() {
        for v in [0i64, 7, -7, 9, 10, -10, 255, 65_535, 4_294_967_295, -128, i64::MAX, i64::MIN] {
            assert_eq!(format!("{}", Int(v)), format!("{v}"));
        }
        for v in [0u32, 1, 0xA, 0x3D, 0xFF, 0x100, 0x1234, 0xABCD_EF01, u32::MAX] {
            for w in [1, 2, 8] {
                assert_eq!(format!("{}", Hex(v, w)), format!("{v:0w$X}", w = w as usize));
            }
        }
        assert_eq!(format!("{}", Hex(0x3D, 12)), "0000003D", "at most 8 digits");
        assert_eq!(format!("[{}]", Text("x y")), "[x y]");
    }

    #[test]
    fn fixed_matches_core_fmt() {
        for v in [0.0, 1.25, -3.25159, 1234.5678, 0.001, 123456789.4] {
            assert_eq!(format!("{}", Fixed(v, 3)), format!("{v:.3}"));
            assert_eq!(format!("{}", Fixed(v, 0)), format!("{v:.0}"));
        }
    }

    #[test]
    fn a_record_line_has_k_in_full() {
        let rec = crate::formats::record::Record {
            seq: 7,
            gyro_k: [[1.01, 0.002, 0.0], [0.0, 0.99, 0.0], [0.0, 0.0, 1.0]],
            ..crate::formats::record::tests::sample()
        };
        let mut s = String::new();
        protocol::record(&mut s, RecordLine::Loaded, &rec).unwrap();
        let event = protocol::Event::Record { line: RecordLine::Loaded, seq: 7, method: rec.method };
        assert_eq!(protocol::parse(&s), Some(event), "{s}");
        assert!(s.contains("K = [1.010000 0.002000 0.000000; 0.000000 0.990000"), "{s}");
    }
}
