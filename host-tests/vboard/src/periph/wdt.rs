//! WDT (nRF52840 PS v1.7 §6.36): started by TASKS_START, times out (CRV + 1) / 32768 s after the
//! last reload; a reload happens when every RR[n] enabled in RREN has been written 0x6E524635
//! (RR[n] of a channel not enabled in RREN does nothing); CRV, RREN and CONFIG are locked while
//! it runs (writes ignored, counted). It is reset only by power-on, brown-out, pin reset, wake
//! from System OFF and its own timeout, not by a soft reset or a CPU lock-up: after
//! AIRCR.SYSRESETREQ it keeps running with its configuration.

use super::{off, Access};

/// RR reload value.
pub const RELOAD: u32 = 0x6E52_4635;
/// LFCLK frequency.
const LF_HZ: f64 = 32768.0;

/// WDT state.
#[derive(Debug, Clone)]
pub struct Wdt {
    /// RUNSTATUS.
    pub running: bool,
    /// CRV.
    pub crv: u32,
    /// RREN.
    pub rren: u32,
    /// CONFIG.
    pub config: u32,
    /// REQSTATUS: enabled RR registers not yet written since the last reload.
    reqstatus: u32,
    /// Time of the last reload (or the start) (s).
    pub last_reload: f64,
    /// Reloads so far.
    pub reloads: u64,
    /// Writes to CRV/RREN/CONFIG ignored because the watchdog runs.
    pub locked_writes: u32,
    /// RR writes to channels not enabled in RREN (ignored).
    pub disabled_rr_writes: u32,
    events_timeout: bool,
    inten: u32,
}

impl Default for Wdt {
    fn default() -> Self {
        Self::new()
    }
}

impl Wdt {
    /// Reset values (CRV 0xFFFFFFFF, RREN 1, CONFIG 1).
    pub fn new() -> Self {
        Self {
            running: false,
            crv: 0xFFFF_FFFF,
            rren: 1,
            config: 1,
            reqstatus: 1,
            last_reload: 0.0,
            reloads: 0,
            locked_writes: 0,
            disabled_rr_writes: 0,
            events_timeout: false,
            inten: 0,
        }
    }

    /// Time of the timeout (s), when running.
    pub fn deadline(&self) -> Option<f64> {
        self.running.then(|| self.last_reload + (self.crv as f64 + 1.0) / LF_HZ)
    }

    /// A register access at offset `o` at time `t`.
    pub fn access(&mut self, o: u32, a: Access, t: f64) -> Result<u32, String> {
        let rr = off!(wdt, rr);
        let locked = |w: &mut Wdt, a: Access, f: fn(&mut Wdt) -> &mut u32| -> u32 {
            if let Access::Write(v) = a {
                if w.running {
                    w.locked_writes += 1;
                } else {
                    *f(w) = v;
                }
            }
            *f(w)
        };
        Ok(match o {
            o if o == off!(wdt, tasks_start) => {
                if a.is_write() && !self.running {
                    self.running = true;
                    self.last_reload = t;
                    self.reqstatus = self.rren;
                }
                0
            }
            o if o == off!(wdt, events_timeout) => {
                if let Access::Write(v) = a {
                    self.events_timeout = v & 1 != 0;
                }
                u32::from(self.events_timeout)
            }
            o if o == off!(wdt, intenset) => {
                if let Access::Write(v) = a {
                    self.inten |= v & 1;
                }
                self.inten
            }
            o if o == off!(wdt, intenclr) => {
                if let Access::Write(v) = a {
                    self.inten &= !v;
                }
                self.inten
            }
            o if o == off!(wdt, runstatus) => u32::from(self.running),
            o if o == off!(wdt, reqstatus) => {
                if self.running {
                    self.reqstatus
                } else {
                    self.rren
                }
            }
            o if o == off!(wdt, crv) => {
                if let Access::Write(v) = a {
                    if v < 0xF && !self.running {
                        return Err(format!("WDT.CRV = {v}: the PS requires at least 15"));
                    }
                }
                locked(self, a, |w| &mut w.crv)
            }
            o if o == off!(wdt, rren) => locked(self, a, |w| &mut w.rren),
            o if o == off!(wdt, config) => locked(self, a, |w| &mut w.config),
            o if (rr..rr + 32).contains(&o) => {
                let b = 1 << ((o - rr) / 4);
                if let Access::Write(v) = a {
                    if self.rren & b == 0 {
                        self.disabled_rr_writes += 1;
                    } else if v == RELOAD && self.running {
                        self.reqstatus &= !b;
                        if self.reqstatus & self.rren == 0 {
                            self.last_reload = t;
                            self.reloads += 1;
                            self.reqstatus = self.rren;
                        }
                    }
                }
                0
            }
            _ => return Err(format!("WDT register 0x{o:03X}")),
        })
    }
}
