//! [`Time`]: an instant on the MCU's clock, in whole microseconds.
//!
//! Exact integer time on both sides: the board's timer counts microseconds, the log writes them
//! (6 decimals of a second) and the PC parses them back to the very same `Time`, so a replay
//! sees the instants the board saw. Differences are taken in integers and only then turned into
//! `f32` seconds ([`Time::since`]): no rounding grows with the time since boot, and the Cortex-M4F
//! needs no software `f64` for it.

use crate::math::real::Real;
use core::fmt;

/// An instant (µs since an arbitrary origin: the board's boot, a log's clock).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Time(i64);

impl Time {
    /// The origin.
    pub const ZERO: Time = Time(0);
    /// The earliest instant (before anything happened).
    pub const MIN: Time = Time(i64::MIN / 2);

    /// The instant `us` µs after the origin.
    pub const fn from_us(us: i64) -> Time {
        Time(us)
    }

    /// µs since the origin.
    pub const fn us(self) -> i64 {
        self.0
    }

    /// The instant `s` seconds after the origin, to the nearest µs; `None` for a NaN, an infinity
    /// or beyond ±1e12 s.
    pub fn from_s(s: f64) -> Option<Time> {
        let us = s * 1e6;
        // Half away from zero, without libm.
        (us.abs() < 1e18).then_some(Time(if us >= 0.0 { (us + 0.5) as i64 } else { (us - 0.5) as i64 }))
    }

    /// Seconds since the origin (the PC's arithmetic; the firmware takes differences).
    pub fn s(self) -> f64 {
        self.0 as f64 * 1e-6
    }

    /// Seconds (negative when `earlier` is later) from `earlier` to `self`.
    #[inline(never)] // one copy (flash): an i64 difference, its conversion and a product
    pub fn since(self, earlier: Time) -> Real {
        self.0.saturating_sub(earlier.0) as Real * 1e-6
    }

    /// The instant `s` seconds later (earlier when negative; a NaN adds nothing).
    #[inline(never)] // one copy (flash)
    pub fn plus_s(self, s: Real) -> Time {
        let us = s * 1e6;
        let us = if us >= 0.0 {
            (us + 0.5) as i64
        } else if us < 0.0 {
            (us - 0.5) as i64
        } else {
            0
        };
        Time(self.0.saturating_add(us))
    }

    /// `(self + other) / 2` (rounded towards zero).
    pub fn midpoint(self, other: Time) -> Time {
        Time(self.0.midpoint(other.0))
    }

    /// Seconds written with `decimals` (≤ 6) decimals, in integers: `12.345678`, `-0.5`.
    pub fn display(self, decimals: u32) -> impl fmt::Display {
        Secs(self, decimals.min(6))
    }
}

/// As seconds (`f64`): the PC's JSON.
#[cfg(feature = "serde")]
impl serde::Serialize for Time {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(self.s())
    }
}

/// [`Time::display`].
struct Secs(Time, u32);

impl fmt::Display for Secs {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let Secs(Time(us), decimals) = *self;
        let unit = 10u64.pow(6 - decimals);
        // Rounded half away from zero to the last decimal written.
        let m = (us.unsigned_abs() + unit / 2) / unit;
        crate::formats::log::decimal(f, us < 0 && m > 0, m, decimals)
    }
}

/// `s` seconds after the origin (the unit tests' times).
#[cfg(test)]
pub(crate) fn secs(s: f64) -> Time {
    Time::from_s(s).expect("a test's time within ±1e12 s")
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::string::ToString;

    #[test]
    fn seconds_round_trip_to_the_microsecond() {
        for s in [0.0, 1e-6, 12345.678901, -0.5, 3600.0 * 24.0 * 365.0] {
            let t = Time::from_s(s).unwrap();
            assert!((t.s() - s).abs() <= 0.5e-6, "{s}");
        }
        assert_eq!(Time::from_s(1.0000004).unwrap().us(), 1_000_000);
        assert_eq!(Time::from_s(-1.0000006).unwrap().us(), -1_000_001);
        assert!(Time::from_s(f64::NAN).is_none());
        assert!(Time::from_s(f64::INFINITY).is_none());
        assert!(Time::from_s(2e12).is_none());
    }

    #[test]
    fn differences_are_exact_whatever_the_time_since_boot() {
        // A day after boot, one 952 Hz period: f32 seconds would round it to 4 ms.
        let t0 = Time::from_us(86_400_000_000);
        let t1 = Time::from_us(86_400_001_050);
        assert_eq!(t1.since(t0), 1050.0 * 1e-6);
        assert_eq!(t0.since(t1), -1050.0 * 1e-6);
        assert_eq!(t0.plus_s(1.05e-3), t1);
        assert_eq!(t1.plus_s(-1.05e-3), t0);
        assert_eq!(t0.plus_s(Real::NAN), t0);
        assert_eq!(t0.midpoint(t1).us(), 86_400_000_525);
    }

    #[test]
    fn written_in_integers_rounded_half_away() {
        let t = Time::from_us(12_345_678);
        assert_eq!(t.display(6).to_string(), "12.345678");
        assert_eq!(t.display(3).to_string(), "12.346");
        assert_eq!(t.display(0).to_string(), "12");
        assert_eq!(Time::from_us(-500_000).display(1).to_string(), "-0.5");
        assert_eq!(Time::from_us(-400).display(3).to_string(), "0.000");
        assert_eq!(Time::from_us(999_999_500).display(3).to_string(), "1000.000");
    }
}
