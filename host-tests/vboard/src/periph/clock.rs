//! CLOCK (nRF52840 PS v1.7 §6.4): HFXO start (TASKS_HFCLKSTART → EVENTS_HFCLKSTARTED after the
//! start-up time), LFCLK, HFCLKSTAT/LFCLKSTAT. Shares its address block with POWER.
//!
//! The Arduino bootloader has already started the HFXO: at the application's entry
//! EVENTS_HFCLKSTARTED is still 1 from the bootloader's own start. A firmware that triggers
//! TASKS_HFCLKSTART and then reads that stale 1 has not waited for anything; such reads are
//! counted in [`Clock::stale_event_reads`] (clear the event first, then start, then wait).

use super::{off, Access};

/// HFXO start-up time from cold (PS: tSTART_HFXO, typical 0.36 ms with the Nano's crystal).
const HFXO_START_S: f64 = 0.36e-3;
/// A start task while the HFXO already runs: the event comes back after a few µs (model choice).
const HFXO_RESTART_S: f64 = 10e-6;
/// LFRC start-up time (PS: tSTART_LFRC, 600 µs typical).
const LFRC_START_S: f64 = 0.6e-3;

/// CLOCK state.
#[derive(Debug, Clone, Default)]
pub struct Clock {
    /// The HFXO runs (HFCLKSTAT.SRC = Xtal).
    pub hfxo_running: bool,
    /// Pending HFXO start: the event is raised at this time (s).
    hf_ready_at: Option<f64>,
    events_hfclkstarted: bool,
    /// The HFCLKSTARTED event register holds a 1 raised before the latest TASKS_HFCLKSTART.
    hf_event_stale: bool,
    /// Reads of EVENTS_HFCLKSTARTED that returned such a stale 1 after a TASKS_HFCLKSTART.
    pub stale_event_reads: u32,
    /// TASKS_HFCLKSTART triggers.
    pub hfclkstart_tasks: u32,
    /// LFCLK running, and its source (0 RC, 1 Xtal, 2 synth).
    pub lf_running: bool,
    lf_ready_at: Option<f64>,
    events_lfclkstarted: bool,
    lfclksrc: u32,
    lfclksrccopy: u32,
    inten: u32,
    hfxodebounce: u32,
    ctiv: u32,
    traceconfig: u32,
    lfrcmode: u32,
}

impl Clock {
    /// After a reset; `bootloader`: the HFXO and the LFRC already run and the HFXO start event
    /// is still set (what the Arduino bootloader leaves).
    pub fn new(bootloader: bool) -> Self {
        let mut c = Self { hfxodebounce: 0x10, ..Self::default() };
        if bootloader {
            c.hfxo_running = true;
            c.events_hfclkstarted = true;
            c.hf_event_stale = true;
            c.lf_running = true;
            c.events_lfclkstarted = true;
        }
        c
    }

    /// Completes the HFXO and LFCLK starts due by `now` (s).
    pub fn settle(&mut self, now: f64) {
        if self.hf_ready_at.is_some_and(|t| now >= t) {
            self.hf_ready_at = None;
            self.hfxo_running = true;
            self.events_hfclkstarted = true;
            self.hf_event_stale = false;
        }
        if self.lf_ready_at.is_some_and(|t| now >= t) {
            self.lf_ready_at = None;
            self.lf_running = true;
            self.events_lfclkstarted = true;
            self.lfclksrccopy = self.lfclksrc;
        }
    }

    /// INTENSET/INTENCLR (shared with POWER: bits 7–9 are POWER's USB events).
    pub fn inten(&self) -> u32 {
        self.inten
    }

    /// A register access at offset `o` of the CLOCK block.
    pub fn access(&mut self, o: u32, a: Access, now: f64) -> Result<u32, String> {
        self.settle(now);
        let ev = |e: &mut bool, a: Access| -> u32 {
            if let Access::Write(v) = a {
                *e = v & 1 != 0;
            }
            u32::from(*e)
        };
        Ok(match o {
            o if o == off!(clock, tasks_hfclkstart) => {
                if a.is_write() {
                    self.hfclkstart_tasks += 1;
                    if self.events_hfclkstarted {
                        self.hf_event_stale = true;
                    }
                    let d = if self.hfxo_running { HFXO_RESTART_S } else { HFXO_START_S };
                    self.hf_ready_at = Some(now + d);
                }
                0
            }
            o if o == off!(clock, tasks_hfclkstop) => {
                if a.is_write() {
                    self.hfxo_running = false;
                    self.hf_ready_at = None;
                }
                0
            }
            o if o == off!(clock, tasks_lfclkstart) => {
                if a.is_write() && !self.lf_running {
                    self.lf_ready_at = Some(now + LFRC_START_S);
                }
                0
            }
            o if o == off!(clock, tasks_lfclkstop) => {
                if a.is_write() {
                    self.lf_running = false;
                    self.lf_ready_at = None;
                }
                0
            }
            o if o == off!(clock, tasks_cal) || o == off!(clock, tasks_ctstart) || o == off!(clock, tasks_ctstop) => 0,
            o if o == off!(clock, events_hfclkstarted) => {
                let v = ev(&mut self.events_hfclkstarted, a);
                if a.is_write() {
                    self.hf_event_stale = false;
                } else if v == 1 && self.hf_event_stale && self.hfclkstart_tasks > 0 {
                    self.stale_event_reads += 1;
                }
                v
            }
            o if o == off!(clock, events_lfclkstarted) => ev(&mut self.events_lfclkstarted, a),
            o if o == off!(clock, events_done)
                || o == off!(clock, events_ctto)
                || o == off!(clock, events_ctstarted)
                || o == off!(clock, events_ctstopped) =>
            {
                0
            }
            o if o == off!(clock, intenset) => {
                if let Access::Write(v) = a {
                    self.inten |= v;
                }
                self.inten
            }
            o if o == off!(clock, intenclr) => {
                if let Access::Write(v) = a {
                    self.inten &= !v;
                }
                self.inten
            }
            o if o == off!(clock, hfclkrun) => u32::from(self.hfclkstart_tasks > 0),
            // STATE (bit 16): HFCLK runs (HFINT at least); SRC (bit 0): 1 = Xtal.
            o if o == off!(clock, hfclkstat) => (1 << 16) | u32::from(self.hfxo_running),
            o if o == off!(clock, lfclkrun) => u32::from(self.lf_running || self.lf_ready_at.is_some()),
            o if o == off!(clock, lfclkstat) => (u32::from(self.lf_running) << 16) | self.lfclksrccopy,
            o if o == off!(clock, lfclksrccopy) => self.lfclksrccopy,
            o if o == off!(clock, lfclksrc) => a.rw(&mut self.lfclksrc),
            o if o == off!(clock, hfxodebounce) => a.rw(&mut self.hfxodebounce),
            o if o == off!(clock, ctiv) => a.rw(&mut self.ctiv),
            o if o == off!(clock, traceconfig) => a.rw(&mut self.traceconfig),
            o if o == off!(clock, lfrcmode) => a.rw(&mut self.lfrcmode),
            _ => return Err(format!("CLOCK register 0x{o:03X}")),
        })
    }
}
