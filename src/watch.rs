//! The checks both magnetometer drivers ([`crate::lsm9ds1_mag`], [`crate::bmm150`]) make of a
//! part's readings: no new one for too long (stopped), or the same counts too many times in a
//! row (stuck: a live part's noise moves the last digits of every reading); and the words for
//! the failures they share.

use crate::lsm9ds1::BusFault;
use calib_core::formats::text::{Hex, Int, Text};
use core::fmt;

/// A failure both magnetometer drivers have (each driver's error holds these and its own).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Shared {
    /// An I2C transfer failed.
    Bus(BusFault),
    /// Register `reg` read `read` after `wrote` was written.
    ConfigMismatch { reg: u8, wrote: u8, read: u8 },
    /// No new reading for `ms` (limit `limit_ms`).
    Stalled { ms: u32, limit_ms: u32 },
    /// `readings` new readings in a row with the same counts.
    Stuck { readings: u16 },
}

impl Shared {
    /// The failure in words, for the part named `part` at I2C address `addr`.
    pub(crate) fn write(self, f: &mut fmt::Formatter<'_>, part: &str, addr: u8) -> fmt::Result {
        let part = Text(part);
        match self {
            Shared::Bus(BusFault::Nack) => write!(f, "{part}: nothing acknowledges 0x{}", Hex(addr.into(), 2)),
            Shared::Bus(b) => write!(f, "{part} I2C: {b:?}"),
            Shared::ConfigMismatch { reg, wrote, read } => {
                write!(
                    f,
                    "{part}: register 0x{} reads 0x{} after writing 0x{}",
                    Hex(reg.into(), 2),
                    Hex(read.into(), 2),
                    Hex(wrote.into(), 2)
                )
            }
            Shared::Stalled { ms, limit_ms } => {
                write!(f, "{part}: no new reading for {} ms (limit {} ms): stopped", Int(ms.into()), Int(limit_ms.into()))
            }
            Shared::Stuck { readings } => write!(f, "{part}: {} readings in a row with the same counts: stuck", Int(readings.into())),
        }
    }
}

/// The last new reading's counts, how many in a row had them, and when it came.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Watch {
    last: [i16; 4],
    same: u16,
    /// MCU time of the last new reading (µs).
    last_new_us: u64,
}

impl Watch {
    /// Watching from MCU time `now_us` (µs).
    pub const fn new(now_us: u64) -> Self {
        Self { last: [0; 4], same: 0, last_new_us: now_us }
    }

    /// No new reading at `now_us`: `Err(ms)` since the last one when that exceeds `stall_ms`.
    pub fn idle(&self, now_us: u64, stall_ms: u32) -> Result<(), u32> {
        let ms = now_us.saturating_sub(self.last_new_us).min(u32::MAX as u64) as u32 / 1000;
        if ms > stall_ms {
            Err(ms)
        } else {
            Ok(())
        }
    }

    /// A new reading's `counts` at `now_us`: `Err(readings)` once `stuck_readings` in a row had
    /// the same counts.
    pub fn reading(&mut self, counts: [i16; 4], now_us: u64, stuck_readings: u16) -> Result<(), u16> {
        self.last_new_us = now_us;
        self.same = if counts == self.last { self.same.saturating_add(1) } else { 1 };
        self.last = counts;
        if self.same >= stuck_readings {
            Err(self.same)
        } else {
            Ok(())
        }
    }
}
