//! TIMER0–4 (nRF52840 PS v1.7 §6.30): 16 MHz / 2^PRESCALER counters, CC[n], capture tasks,
//! SHORTS COMPARE0_CLEAR (periodic), COMPARE events and their interrupt line.
//!
//! Events are state: the interrupt line stays asserted while an enabled COMPARE event is set, so
//! a handler that does not clear it runs again and again. And (PS §3.? "Interrupt clearing") a
//! write of 0 to an event register takes up to four CPU cycles to take effect: a handler that
//! returns right after the write gets its interrupt again, spuriously, unless it reads the
//! register back (the read completes the write). Spurious entries are counted.

use super::{off, Access};

/// Cycles until an event clear takes effect.
const CLEAR_LATENCY: u64 = 4;

/// One TIMER instance.
#[derive(Debug, Clone, Copy, Default)]
pub struct Timer {
    running: bool,
    /// Virtual time when the counter was 0 (s).
    t0: f64,
    prescaler: u32,
    cc: [u32; 6],
    shorts: u32,
    inten: u32,
    mode: u32,
    bitmode: u32,
    events: u32,
    /// Time of the last compare event already raised (s).
    last_event: f64,
    /// Instruction count of a write that cleared a set event, until it takes effect.
    clear_at: Option<u64>,
    /// Interrupt entries caused only by the clear latency.
    pub spurious: u32,
    /// Number of CC registers (4 for TIMER0–2, 6 for TIMER3–4).
    n_cc: usize,
}

impl Timer {
    /// A timer with `n_cc` compare registers.
    pub fn new(n_cc: usize) -> Self {
        Self { n_cc, ..Self::default() }
    }

    fn hz(&self) -> f64 {
        16e6 / (1u64 << self.prescaler.min(9)) as f64
    }

    fn counter(&self, t: f64) -> u64 {
        if !self.running {
            return 0;
        }
        let ticks = ((t - self.t0) * self.hz()).max(0.0) as u64;
        // BITMODE: 16 (reset value), 8, 24 or 32 bits; SHORTS COMPARE0_CLEAR: 0..CC0.
        let mask = match self.bitmode & 3 {
            0 => 0xFFFF,
            1 => 0xFF,
            2 => 0xFF_FFFF,
            _ => 0xFFFF_FFFF,
        };
        if self.shorts & 1 != 0 && self.cc[0] > 0 {
            (ticks % self.cc[0] as u64) & mask
        } else {
            ticks & mask
        }
    }

    /// The counter at virtual time `t` (s).
    pub fn counter_at(&self, t: f64) -> u64 {
        self.counter(t)
    }

    /// Moves the counter `ticks` ahead (tests: bring a wrap of the counter near).
    pub fn advance(&mut self, ticks: u64) {
        self.t0 -= ticks as f64 / self.hz();
        self.last_event = self.last_event.min(self.t0);
    }

    /// Time of the next COMPARE0 event after `t` (periodic timers only).
    pub fn next_compare0(&self, t: f64) -> Option<f64> {
        if !self.running || self.cc[0] == 0 || self.inten & (1 << 16) == 0 {
            return None;
        }
        let period = self.cc[0] as f64 / self.hz();
        let k = ((t - self.t0) / period).floor() + 1.0;
        Some(self.t0 + k * period)
    }

    /// Raises the COMPARE0 event of a periodic timer up to `t`.
    pub fn update(&mut self, t: f64) {
        if !self.running || self.cc[0] == 0 || self.shorts & 1 == 0 {
            return;
        }
        let period = self.cc[0] as f64 / self.hz();
        let k = ((t - self.t0) / period).floor();
        let last = self.t0 + k * period;
        if k >= 1.0 && last > self.last_event {
            self.last_event = last;
            self.events |= 1;
        }
    }

    /// The interrupt line at instruction count `instr`: an enabled event is set, or was
    /// cleared less than four cycles ago.
    pub fn line(&self, instr: u64) -> bool {
        let pending_clear = self.clear_at.is_some_and(|c| instr < c + CLEAR_LATENCY);
        (self.events & (self.inten >> 16) & 0x3F) != 0 || pending_clear
    }

    /// Called when the handler returns with the line still asserted by a clear in flight.
    pub fn note_return(&mut self, instr: u64) {
        if (self.events & (self.inten >> 16) & 0x3F) == 0 && self.clear_at.is_some_and(|c| instr < c + CLEAR_LATENCY) {
            self.spurious += 1;
        }
        self.clear_at = None;
    }

    /// A register access at offset `o` at time `t`, instruction count `instr`.
    pub fn access(&mut self, o: u32, a: Access, t: f64, instr: u64) -> Result<u32, String> {
        // Any read from the peripheral completes a write still in flight.
        if !a.is_write() {
            self.clear_at = None;
        }
        let n = self.n_cc as u32;
        let (cap, ev, cc) = (off!(timer0, tasks_capture), off!(timer0, events_compare), off!(timer0, cc));
        Ok(match o {
            o if o == off!(timer0, tasks_start) => {
                if a.is_write() && !self.running {
                    self.running = true;
                    self.t0 = t;
                    self.last_event = t;
                }
                0
            }
            o if o == off!(timer0, tasks_stop) || o == off!(timer0, tasks_shutdown) => {
                if a.is_write() {
                    self.running = false;
                }
                0
            }
            o if o == off!(timer0, tasks_count) => 0,
            o if o == off!(timer0, tasks_clear) => {
                if a.is_write() {
                    self.t0 = t;
                    self.last_event = t;
                }
                0
            }
            o if (cap..cap + 4 * n).contains(&o) => {
                if a.is_write() {
                    self.cc[((o - cap) / 4) as usize] = self.counter(t) as u32;
                }
                0
            }
            o if (ev..ev + 4 * n).contains(&o) => {
                let b = 1 << ((o - ev) / 4);
                if let Access::Write(v) = a {
                    if v & 1 == 0 {
                        if self.events & b != 0 {
                            self.clear_at = Some(instr);
                        }
                        self.events &= !b;
                    } else {
                        self.events |= b;
                    }
                }
                u32::from(self.events & b != 0)
            }
            o if o == off!(timer0, shorts) => a.rw(&mut self.shorts),
            o if o == off!(timer0, intenset) => {
                if let Access::Write(v) = a {
                    self.inten |= v;
                }
                self.inten
            }
            o if o == off!(timer0, intenclr) => {
                if let Access::Write(v) = a {
                    if self.inten & v != 0 {
                        self.clear_at = Some(instr);
                    }
                    self.inten &= !v;
                }
                self.inten
            }
            o if o == off!(timer0, mode) => a.rw(&mut self.mode),
            o if o == off!(timer0, bitmode) => a.rw(&mut self.bitmode),
            o if o == off!(timer0, prescaler) => a.rw(&mut self.prescaler),
            o if (cc..cc + 4 * n).contains(&o) => a.rw(&mut self.cc[((o - cc) / 4) as usize]),
            _ => return Err(format!("TIMER register 0x{o:03X}")),
        })
    }
}
