//! RTC0–2 (nRF52840 PS v1.7 §6.22): a 24-bit counter at 32768 / (PRESCALER + 1) Hz from the
//! LFCLK, START/STOP/CLEAR, CC[n], EVTEN, INTEN. The Arduino bootloader leaves RTC1 running
//! (its interrupts masked in the NVIC). Events are not raised (nothing in the firmware waits on
//! them); the counter reads true time.

use super::{off, Access};

/// One RTC instance.
#[derive(Debug, Clone, Default)]
pub struct Rtc {
    /// The counter runs.
    pub running: bool,
    t0: f64,
    base: u32,
    prescaler: u32,
    cc: [u32; 4],
    evten: u32,
    inten: u32,
}

impl Rtc {
    /// After a reset; `running`: started at time `t`.
    pub fn new(running: bool, t: f64) -> Self {
        Self { running, t0: t, ..Self::default() }
    }

    fn counter(&self, t: f64) -> u32 {
        let ticks = if self.running { ((t - self.t0) * 32768.0 / (self.prescaler as f64 + 1.0)) as u64 } else { 0 };
        ((self.base as u64 + ticks) & 0xFF_FFFF) as u32
    }

    /// A register access at offset `o` at time `t`.
    pub fn access(&mut self, o: u32, a: Access, t: f64) -> Result<u32, String> {
        let (ev, cc) = (off!(rtc0, events_compare), off!(rtc0, cc));
        Ok(match o {
            o if o == off!(rtc0, tasks_start) => {
                if a.is_write() && !self.running {
                    self.running = true;
                    self.t0 = t;
                }
                0
            }
            o if o == off!(rtc0, tasks_stop) => {
                if a.is_write() && self.running {
                    self.base = self.counter(t);
                    self.running = false;
                }
                0
            }
            o if o == off!(rtc0, tasks_clear) => {
                if a.is_write() {
                    self.base = 0;
                    self.t0 = t;
                }
                0
            }
            o if o == off!(rtc0, tasks_trigovrflw) => {
                if a.is_write() {
                    self.base = 0xFF_FFF0;
                    self.t0 = t;
                }
                0
            }
            o if o == off!(rtc0, events_tick) || o == off!(rtc0, events_ovrflw) || (ev..ev + 16).contains(&o) => 0,
            o if o == off!(rtc0, intenset) => {
                if let Access::Write(v) = a {
                    self.inten |= v;
                }
                self.inten
            }
            o if o == off!(rtc0, intenclr) => {
                if let Access::Write(v) = a {
                    self.inten &= !v;
                }
                self.inten
            }
            o if o == off!(rtc0, evten) => a.rw(&mut self.evten),
            o if o == off!(rtc0, evtenset) => {
                if let Access::Write(v) = a {
                    self.evten |= v;
                }
                self.evten
            }
            o if o == off!(rtc0, evtenclr) => {
                if let Access::Write(v) = a {
                    self.evten &= !v;
                }
                self.evten
            }
            o if o == off!(rtc0, counter) => self.counter(t),
            o if o == off!(rtc0, prescaler) => {
                if a.is_write() && self.running {
                    return Err("RTC PRESCALER written while the RTC runs (the PS allows it only when stopped)".into());
                }
                a.rw(&mut self.prescaler)
            }
            o if (cc..cc + 16).contains(&o) => a.rw(&mut self.cc[((o - cc) / 4) as usize]),
            _ => return Err(format!("RTC register 0x{o:03X}")),
        })
    }
}
