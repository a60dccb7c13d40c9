//! LED patterns: the phase and the error class without a probe.
//!
//! | pattern | D13 (yellow) | RGB |
//! |---|---|---|
//! | idle, waiting for the button | off | green blink 0.1 s every 2 s |
//! | busy in phase n | n flashes, then a pause (every 2 s up to 4) | blue on |
//! | user action needed: hand-held poses | off | yellow (red + green) blink 2 Hz |
//! | user action needed: re-clamp and press | on | yellow (red + green) blink 2 Hz |
//! | done: calibration stored and applied | on | green on |
//! | error of class n | n flashes, then a pause (every 2 s up to 4) | red on |
//!
//! Phase numbers: wait-rest 1, bias 2, accelerometer poses (hand-held or tilt servo) 3,
//! reattach 4, rig-poses 5, spin 6, storing the record 7.
//! Error classes: sensor 1, motion 2, servo 3, geometry 4, result 5, timeout 6, storage 7.

use calib_core::procedure::{ErrorClass, Led, Phase};

/// On/off state of the four LEDs (logical: `true` = lit).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Lights {
    /// D13 (P0.13).
    pub d13: bool,
    /// Red (P0.24).
    pub red: bool,
    /// Green (P0.16).
    pub green: bool,
    /// Blue (P0.06).
    pub blue: bool,
}

fn phase_number(p: Phase) -> u8 {
    match p {
        Phase::WaitRest => 1,
        Phase::Bias => 2,
        Phase::HandHeld => 3,
        Phase::Reattach => 4,
        Phase::RigPoses => 5,
        Phase::Spin => 6,
        Phase::Store => 7,
        Phase::Idle | Phase::Done | Phase::Failed => 0,
    }
}

fn class_number(c: ErrorClass) -> u8 {
    match c {
        ErrorClass::Sensor => 1,
        ErrorClass::Motion => 2,
        ErrorClass::Servo => 3,
        ErrorClass::Geometry => 4,
        ErrorClass::Result => 5,
        ErrorClass::Timeout => 6,
        ErrorClass::Storage => 7,
    }
}

/// `n` flashes of 150 ms on / 150 ms off, then at least 0.8 s off: a cycle of 2 s up to 4
/// flashes, longer beyond (7 flashes in 2 s left 50 ms between two groups: uncountable).
fn flashes(n: u8, t_ms: u32) -> bool {
    let x = t_ms % (n as u32 * 300 + 800).max(2000);
    x / 300 < n as u32 && x % 300 < 150
}

/// The LED states of a pattern at time `t_ms` (ms, wrapping at 2³²: a beat is skipped once in
/// 49.7 days; 32-bit arithmetic, no 64-bit division linked).
pub fn render(led: Led, t_ms: u32) -> Lights {
    let blink = |period: u32, on: u32| t_ms % period < on;
    match led {
        Led::Idle => Lights { green: blink(2000, 100), ..Lights::default() },
        Led::Busy(p) => Lights { d13: flashes(phase_number(p), t_ms), blue: true, ..Lights::default() },
        Led::WaitUser(p) => {
            let on = blink(500, 250);
            Lights { d13: p == Phase::Reattach, red: on, green: on, ..Lights::default() }
        }
        Led::Done => Lights { d13: true, green: true, ..Lights::default() },
        Led::Error(c) => Lights { d13: flashes(class_number(c), t_ms), red: true, ..Lights::default() },
    }
}
