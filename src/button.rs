//! Push-button debouncing (D2 = P1.11 to GND, pull-up: pressed reads low).

use calib_core::math::real::Real;
use calib_core::Time;

/// Time the level must be stable to count (s).
pub const DEBOUNCE_S: Real = 0.03;
/// Hold time of a long press (s).
pub const LONG_PRESS_S: Real = 2.0;

/// A debounced button event.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Press {
    /// Pressed and released within `LONG_PRESS_S`.
    Short,
    /// Held for `LONG_PRESS_S` (reported once, while still held).
    Long,
}

/// Debouncer fed with the raw level at any rate ≥ 100 Hz.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Button {
    pressed: bool,
    raw: bool,
    raw_since: Time,
    pressed_since: Time,
    long_sent: bool,
}

impl Button {
    /// Released.
    pub const fn new() -> Self {
        Self { pressed: false, raw: false, raw_since: Time::ZERO, pressed_since: Time::ZERO, long_sent: false }
    }

    /// Feeds the raw level (`true` = pressed) at time `t`; returns a debounced event.
    pub fn update(&mut self, t: Time, raw_pressed: bool) -> Option<Press> {
        if raw_pressed != self.raw {
            self.raw = raw_pressed;
            self.raw_since = t;
        }
        let stable = t.since(self.raw_since) >= DEBOUNCE_S;
        if stable && self.raw != self.pressed {
            self.pressed = self.raw;
            if self.pressed {
                self.pressed_since = t;
                self.long_sent = false;
            } else if !self.long_sent {
                return Some(Press::Short);
            }
        }
        if self.pressed && !self.long_sent && t.since(self.pressed_since) >= LONG_PRESS_S {
            self.long_sent = true;
            return Some(Press::Long);
        }
        None
    }
}
