//! UARTE0 (nRF52840 PS v1.7 §6.34) as the Arduino bootloader leaves it: ENABLE = 8, RX on P1.10,
//! TX on P1.03, 115200 baud, the receiver started (it keeps the HFCLK requested and draws
//! current until stopped). TASKS_STOPRX stops it: EVENTS_RXTO follows after one character time.
//! The PS asks for RX (and TX) to be stopped before ENABLE = 0; disabling a receiver that has
//! not reported RXTO is recorded ([`Uarte::disabled_while_receiving`]).

use super::{off, Access};

/// UARTE ENABLE value.
pub const ENABLED: u32 = 8;

/// Receiver state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rx {
    /// Stopped (or never started).
    Idle,
    /// Receiving into RXD.PTR.
    Receiving,
    /// STOPRX issued; RXTO at this time (s).
    Stopping(f64),
}

/// UARTE0 state.
#[derive(Debug, Clone)]
pub struct Uarte {
    /// ENABLE.
    pub enable: u32,
    /// The receiver.
    pub rx: Rx,
    /// ENABLE was cleared while the receiver ran (before RXTO).
    pub disabled_while_receiving: bool,
    psel: [u32; 4],
    baudrate: u32,
    config: u32,
    rxd: [u32; 3],
    txd: [u32; 3],
    shorts: u32,
    inten: u32,
    errorsrc: u32,
    events_rxstarted: bool,
    events_rxto: bool,
    events_endrx: bool,
    events_txstarted: bool,
    events_endtx: bool,
    events_txstopped: bool,
    events_error: bool,
}

impl Uarte {
    /// After a reset; `bootloader`: enabled and receiving.
    pub fn new(bootloader: bool) -> Self {
        let mut u = Self {
            enable: 0,
            rx: Rx::Idle,
            disabled_while_receiving: false,
            psel: [0xFFFF_FFFF; 4],
            baudrate: 0x0400_0000,
            config: 0,
            rxd: [0; 3],
            txd: [0; 3],
            shorts: 0,
            inten: 0,
            errorsrc: 0,
            events_rxstarted: false,
            events_rxto: false,
            events_endrx: false,
            events_txstarted: false,
            events_endtx: false,
            events_txstopped: false,
            events_error: false,
        };
        if bootloader {
            u.enable = ENABLED;
            u.psel = [0xFFFF_FFFF, super::pwm::psel(1, 3), 0xFFFF_FFFF, super::pwm::psel(1, 10)];
            u.baudrate = 0x01D7_E000; // 115200
            u.rxd = [0x2000_0000, 64, 0];
            u.rx = Rx::Receiving;
            u.events_rxstarted = true;
        }
        u
    }

    fn char_time(&self) -> f64 {
        // BAUDRATE ≈ baud × 2^32 / 16 MHz.
        let baud = (self.baudrate as f64 * 16e6 / 4294967296.0).max(1200.0);
        10.0 / baud
    }

    fn settle(&mut self, now: f64) {
        if let Rx::Stopping(t) = self.rx {
            if now >= t {
                self.rx = Rx::Idle;
                self.events_endrx = true;
                self.events_rxto = true;
            }
        }
    }

    /// The receiver runs (started and no RXTO yet).
    pub fn receiving(&self) -> bool {
        self.rx != Rx::Idle
    }

    /// A register access at offset `o` at time `t`.
    pub fn access(&mut self, o: u32, a: Access, t: f64) -> Result<u32, String> {
        self.settle(t);
        let ev = |e: &mut bool, a: Access| -> u32 {
            if let Access::Write(v) = a {
                *e = v & 1 != 0;
            }
            u32::from(*e)
        };
        let on = self.enable == ENABLED;
        let (psel, rxd, txd) = (off!(uarte0, psel), off!(uarte0, rxd), off!(uarte0, txd));
        Ok(match o {
            o if o == off!(uarte0, tasks_startrx) => {
                if a.is_write() && on {
                    self.rx = Rx::Receiving;
                    self.events_rxstarted = true;
                }
                0
            }
            o if o == off!(uarte0, tasks_stoprx) => {
                if a.is_write() && self.rx == Rx::Receiving {
                    self.rx = Rx::Stopping(t + self.char_time());
                }
                0
            }
            o if o == off!(uarte0, tasks_starttx) => {
                if a.is_write() && on {
                    self.events_txstarted = true;
                    self.events_endtx = true;
                    self.txd[2] = self.txd[1];
                }
                0
            }
            o if o == off!(uarte0, tasks_stoptx) => {
                if a.is_write() {
                    self.events_txstopped = true;
                }
                0
            }
            o if o == off!(uarte0, tasks_flushrx) => 0,
            o if o == off!(uarte0, events_rxstarted) => ev(&mut self.events_rxstarted, a),
            o if o == off!(uarte0, events_rxto) => ev(&mut self.events_rxto, a),
            o if o == off!(uarte0, events_endrx) => ev(&mut self.events_endrx, a),
            o if o == off!(uarte0, events_txstarted) => ev(&mut self.events_txstarted, a),
            o if o == off!(uarte0, events_endtx) => ev(&mut self.events_endtx, a),
            o if o == off!(uarte0, events_txstopped) => ev(&mut self.events_txstopped, a),
            o if o == off!(uarte0, events_error) => ev(&mut self.events_error, a),
            o if o == off!(uarte0, events_cts)
                || o == off!(uarte0, events_ncts)
                || o == off!(uarte0, events_rxdrdy)
                || o == off!(uarte0, events_txdrdy) =>
            {
                0
            }
            o if o == off!(uarte0, shorts) => a.rw(&mut self.shorts),
            o if o == off!(uarte0, inten) => a.rw(&mut self.inten),
            o if o == off!(uarte0, intenset) => {
                if let Access::Write(v) = a {
                    self.inten |= v;
                }
                self.inten
            }
            o if o == off!(uarte0, intenclr) => {
                if let Access::Write(v) = a {
                    self.inten &= !v;
                }
                self.inten
            }
            o if o == off!(uarte0, errorsrc) => {
                if let Access::Write(v) = a {
                    self.errorsrc &= !v;
                }
                self.errorsrc
            }
            o if o == off!(uarte0, enable) => {
                if let Access::Write(v) = a {
                    if v != ENABLED && self.receiving() {
                        self.disabled_while_receiving = true;
                        self.rx = Rx::Idle;
                    }
                }
                a.rw(&mut self.enable)
            }
            o if (psel..psel + 16).contains(&o) => a.rw(&mut self.psel[((o - psel) / 4) as usize]),
            o if o == off!(uarte0, baudrate) => a.rw(&mut self.baudrate),
            o if o == off!(uarte0, config) => a.rw(&mut self.config),
            o if (rxd..rxd + 12).contains(&o) => a.easydma(&mut self.rxd, ((o - rxd) / 4) as usize),
            o if (txd..txd + 12).contains(&o) => a.easydma(&mut self.txd, ((o - txd) / 4) as usize),
            _ => return Err(format!("UARTE0 register 0x{o:03X}")),
        })
    }
}
