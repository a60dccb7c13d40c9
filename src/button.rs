//! Push-button debouncing (D2 = P1.11 to GND, pull-up: pressed reads low).

/// Time the level must be stable to count (s).
pub const DEBOUNCE_S: f64 = 0.03;
/// Hold time of a long press (s).
pub const LONG_PRESS_S: f64 = 2.0;

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
    raw_since: f64,
    pressed_since: f64,
    long_sent: bool,
}

impl Button {
    /// Released.
    pub const fn new() -> Self {
        Self { pressed: false, raw: false, raw_since: 0.0, pressed_since: 0.0, long_sent: false }
    }

    /// Feeds the raw level (`true` = pressed) at time `t_s`; returns a debounced event.
    pub fn update(&mut self, t_s: f64, raw_pressed: bool) -> Option<Press> {
        if raw_pressed != self.raw {
            self.raw = raw_pressed;
            self.raw_since = t_s;
        }
        let stable = t_s - self.raw_since >= DEBOUNCE_S;
        if stable && self.raw != self.pressed {
            self.pressed = self.raw;
            if self.pressed {
                self.pressed_since = t_s;
                self.long_sent = false;
            } else if !self.long_sent {
                return Some(Press::Short);
            }
        }
        if self.pressed && !self.long_sent && t_s - self.pressed_since >= LONG_PRESS_S {
            self.long_sent = true;
            return Some(Press::Long);
        }
        None
    }
}
