//! The checks both magnetometer drivers ([`crate::lsm9ds1_mag`], [`crate::bmm150`]) make of a
//! part's readings: no new one for too long (stopped), or the same counts too many times in a
//! row (stuck: a live part's noise moves the last digits of every reading).

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
