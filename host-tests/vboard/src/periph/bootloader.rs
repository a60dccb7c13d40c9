//! A stand-in for the stock Nano 33 BLE bootloader (0x0..0x10000), built from the facts of a
//! disassembly of ArduinoCore-mbed's `bootloaders/nano33ble/bootloader.elf` (a Zephyr-based
//! SAM-BA loader) and of the core's `_ontouch1200bps_` (variants/ARDUINO_NANO33BLE/variant.cpp):
//!
//! - After every reset it waits [`DOUBLE_TAP_S`] for a second press of the reset button (a pin
//!   reset within that window is the double tap: SAM-BA mode).
//! - Then: GPREGRET (0x4000051C) = [`DFU_MAGIC_SERIAL_ONLY`] (what the core's 1200-baud touch
//!   writes before its reset) is cleared and it stays in SAM-BA mode; an erased reset vector at
//!   0x10004 (no application) also keeps it there; otherwise it jumps to the application at
//!   0x10000.
//! - In SAM-BA mode it enumerates as [`VID_PID`] and waits for bossac for ever. Its image has no
//!   WDT code: a watchdog left running by the application is never fed, and resets the chip when
//!   it expires.
//!
//! Not emulated: the bootloader's own code (its state is this model's), its USB stack (the host
//! sees a device with [`VID_PID`] and the strings below, [`crate::usb_host::Host::stand_in`]),
//! the SAM-BA protocol, its LED. What it leaves the application at the jump is
//! [`super::Periph::reset`]'s hand-over state.

/// The double-tap window after every reset (s).
pub const DOUBLE_TAP_S: f64 = 0.5;
/// GPREGRET value that keeps the bootloader in SAM-BA mode (`DFU_MAGIC_SERIAL_ONLY_RESET`).
pub const DFU_MAGIC_SERIAL_ONLY: u32 = 0xB0;
/// The bootloader's USB VID:PID in SAM-BA mode.
pub const VID_PID: (u16, u16) = (0x2341, 0x005A);
/// Its manufacturer and product strings.
pub const STRINGS: (&str, &str) = ("Arduino", "Arduino Nano 33 BLE");

/// Where the bootloader is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stage {
    /// The double-tap wait, until this time (s).
    Waiting {
        /// End of the wait (s).
        until: f64,
    },
    /// SAM-BA mode since this time (s).
    SamBa {
        /// When it entered SAM-BA mode (s).
        since: f64,
    },
    /// The application runs.
    App,
}

/// What the bootloader decides at the end of its wait.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    /// Still waiting.
    Wait,
    /// Stay in SAM-BA mode.
    SamBa,
    /// Jump to the application.
    Jump,
}

/// The stand-in's state (kept across resets: it counts them).
#[derive(Debug, Clone)]
pub struct StockBootloader {
    /// Where it is.
    pub stage: Stage,
    /// SAM-BA mode entries so far.
    pub samba_entries: u32,
}

impl Default for StockBootloader {
    fn default() -> Self {
        Self { stage: Stage::App, samba_entries: 0 }
    }
}

impl StockBootloader {
    /// The chip reset at `t` (s): the wait starts again; a pin reset during the wait is the
    /// double tap.
    pub fn reset(&mut self, t: f64, pin: bool) {
        if pin && matches!(self.stage, Stage::Waiting { .. }) {
            self.enter_samba(t);
        } else {
            self.stage = Stage::Waiting { until: t + DOUBLE_TAP_S };
        }
    }

    fn enter_samba(&mut self, t: f64) {
        self.stage = Stage::SamBa { since: t };
        self.samba_entries += 1;
    }

    /// At `t` (s), with GPREGRET (cleared here when it holds the magic) and whether an
    /// application is present: what the bootloader does.
    pub fn decide(&mut self, t: f64, gpregret: &mut u32, app_present: bool) -> Decision {
        match self.stage {
            Stage::Waiting { until } if t >= until => {
                if *gpregret == DFU_MAGIC_SERIAL_ONLY || !app_present {
                    if *gpregret == DFU_MAGIC_SERIAL_ONLY {
                        *gpregret = 0;
                    }
                    self.enter_samba(t);
                    Decision::SamBa
                } else {
                    self.stage = Stage::App;
                    Decision::Jump
                }
            }
            Stage::Waiting { .. } => Decision::Wait,
            Stage::SamBa { .. } => Decision::SamBa,
            Stage::App => Decision::Jump,
        }
    }

    /// In SAM-BA mode.
    pub fn in_samba(&self) -> bool {
        matches!(self.stage, Stage::SamBa { .. })
    }

    /// How long it has been in SAM-BA mode at `now` (s), 0 if not.
    pub fn held_s(&self, now: f64) -> f64 {
        match self.stage {
            Stage::SamBa { since } => now - since,
            _ => 0.0,
        }
    }

    /// The end of the wait, if waiting (s).
    pub fn wait_until(&self) -> Option<f64> {
        match self.stage {
            Stage::Waiting { until } => Some(until),
            _ => None,
        }
    }
}
