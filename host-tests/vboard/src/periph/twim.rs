//! TWIM0 with EasyDMA (nRF52840 PS v1.7 §6.31), against the bus's devices (the LSM9DS1 model).
//!
//! What the part does and the model enforces:
//! - tasks do nothing unless ENABLE = 6 (a driver then waits forever: the watchdog resets);
//! - a transfer drives the pins PSEL.SCL/PSEL.SDA select; on the Nano 33 BLE the sensor bus is
//!   SCL = P0.15, SDA = P0.14 and those pins must be inputs with the input buffer connected and
//!   DRIVE = S0D1 (PS "Master mode pin configuration"); anything else reaches no device: the
//!   address is not acknowledged;
//! - FREQUENCY must be one of the PS values (K100 0x01980000, K250 0x04000000, K400 0x06400000)
//!   or the erratum-219 value 0x06200000; any other value stops the run;
//! - after an error (address NACK) the master does not stop by itself: it holds the bus until
//!   TASKS_STOP, which then raises STOPPED; a start task meanwhile does nothing;
//! - a STOP while no transfer is in progress leaves the peripheral broken for a short while
//!   (embassy-rs/embassy#6722): a transfer started within two byte times ends at once with
//!   STOPPED and nothing transferred (AMOUNT = 0, no ERROR);
//! - STOP while suspended is ignored (PS: "cannot be stopped while suspended");
//! - the CPU is charged the bus time of every transfer (9 bits per byte at the set frequency).

use super::{off, Access, Dma};
use embedded_hal::i2c::Operation;

/// No device acknowledged the address (or a data byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Nack;

/// The bus's devices, seen by the TWIM.
pub trait Bus {
    /// One I2C transaction; `Err` = address not acknowledged.
    fn transaction(&mut self, address: u8, ops: &mut [Operation<'_>]) -> Result<(), Nack>;
    /// Whether a device acknowledges `address` now (the address phase of a write that a
    /// repeated-start read will complete).
    fn acks(&mut self, address: u8) -> bool;
}

/// ENABLE value for TWIM.
pub const ENABLED: u32 = 6;
/// FREQUENCY values the PS allows, with their bus rate (Hz).
pub const FREQUENCIES: [(u32, f64); 4] = [(0x0198_0000, 100e3), (0x0400_0000, 250e3), (0x0640_0000, 400e3), (0x0620_0000, 390e3)];

/// State between tasks.
#[derive(Debug, Clone, PartialEq)]
pub enum State {
    /// No transfer.
    Idle,
    /// Suspended after a write (LASTTX_SUSPEND): a read with a repeated start may follow.
    Suspended(Vec<u8>),
    /// An error occurred; the bus is held until TASKS_STOP.
    ErrorHeld,
    /// A STOP came while idle: transfers started before this time fail (s).
    Broken(f64),
}

/// TWIM0 state.
#[derive(Debug, Clone)]
pub struct Twim {
    /// ENABLE.
    pub enable: u32,
    /// PSEL.SCL, PSEL.SDA.
    pub psel: [u32; 2],
    /// FREQUENCY.
    pub frequency: u32,
    address: u32,
    shorts: u32,
    inten: u32,
    rxd: [u32; 4],
    txd: [u32; 4],
    errorsrc: u32,
    events: u32,
    /// State between tasks.
    pub state: State,
    /// Fault injection: SCL held low: no transfer ever ends.
    pub hang: bool,
    /// Bytes of traffic (address + data) so far.
    pub bytes: u64,
    /// Transfers that failed because of a STOP issued while idle.
    pub broken_transfers: u32,
    /// STOP tasks issued while idle.
    pub idle_stops: u32,
}

// Event bits in `events`.
const STOPPED: u32 = 1 << 0;
const ERROR: u32 = 1 << 1;
const SUSPENDED: u32 = 1 << 2;
const RXSTARTED: u32 = 1 << 3;
const TXSTARTED: u32 = 1 << 4;
const LASTRX: u32 = 1 << 5;
const LASTTX: u32 = 1 << 6;

// SHORTS bits (PS).
const LASTTX_STARTRX: u32 = 1 << 7;
const LASTTX_SUSPEND: u32 = 1 << 8;
const LASTTX_STOP: u32 = 1 << 9;
const LASTRX_STARTTX: u32 = 1 << 10;
const LASTRX_SUSPEND: u32 = 1 << 11;
const LASTRX_STOP: u32 = 1 << 12;

impl Default for Twim {
    fn default() -> Self {
        Self::new()
    }
}

/// What the pins and the board look like to a transfer.
pub struct Wiring {
    /// PIN_CNF of P0.15 (SCL) and P0.14 (SDA).
    pub scl_sda_cnf: [u32; 2],
}

impl Twim {
    /// After a reset.
    pub fn new() -> Self {
        Self {
            enable: 0,
            psel: [0xFFFF_FFFF; 2],
            frequency: 0x0400_0000,
            address: 0,
            shorts: 0,
            inten: 0,
            rxd: [0; 4],
            txd: [0; 4],
            errorsrc: 0,
            events: 0,
            state: State::Idle,
            hang: false,
            bytes: 0,
            broken_transfers: 0,
            idle_stops: 0,
        }
    }

    /// The bus frequency FREQUENCY selects (Hz).
    pub fn bus_hz(&self) -> Result<f64, String> {
        FREQUENCIES
            .iter()
            .find(|f| f.0 == self.frequency)
            .map(|f| f.1)
            .ok_or_else(|| format!("TWIM FREQUENCY 0x{:08X} is not a value the PS allows", self.frequency))
    }

    /// The pins reach the sensor bus: PSEL.SCL = P0.15, PSEL.SDA = P0.14 (connected), both
    /// inputs with the input buffer connected and DRIVE = S0D1.
    fn wired(&self, w: &Wiring) -> bool {
        let pins_ok = self.psel == [15, 14];
        let cnf_ok = w.scl_sda_cnf.iter().all(|&c| c & 1 == 0 && c & 2 == 0 && (c >> 8) & 7 == super::gpio::drive::S0D1);
        pins_ok && cnf_ok
    }

    /// A register access at offset `o`; returns the value read and the bus time to charge (s).
    pub fn access(&mut self, o: u32, a: Access, t: f64, bus: &mut dyn Bus, w: &Wiring, mem: &mut dyn Dma) -> Result<(u32, f64), String> {
        let ev = |tw: &mut Twim, bit: u32, a: Access| -> u32 {
            if let Access::Write(v) = a {
                if v & 1 != 0 {
                    tw.events |= bit;
                } else {
                    tw.events &= !bit;
                }
            }
            u32::from(tw.events & bit != 0)
        };
        let (rxd, txd) = (off!(twim0, rxd), off!(twim0, txd));
        let mut bus_s = 0.0;
        let v = match o {
            o if o == off!(twim0, tasks_starttx) || o == off!(twim0, tasks_startrx) => {
                if a.is_write() && self.enable == ENABLED && !self.hang {
                    bus_s = self.start(o == off!(twim0, tasks_starttx), t, bus, w, mem)?;
                }
                0
            }
            o if o == off!(twim0, tasks_stop) => {
                if a.is_write() && self.enable == ENABLED && !self.hang {
                    match self.state {
                        State::ErrorHeld => {
                            self.state = State::Idle;
                            self.events |= STOPPED;
                        }
                        State::Suspended(_) => {} // cannot be stopped while suspended
                        State::Idle | State::Broken(_) => {
                            self.idle_stops += 1;
                            let byte_s = 9.0 / self.bus_hz().unwrap_or(100e3);
                            self.state = State::Broken(t + 2.0 * byte_s);
                            self.events |= STOPPED;
                        }
                    }
                }
                0
            }
            o if o == off!(twim0, tasks_suspend) => {
                if a.is_write() && self.enable == ENABLED {
                    self.events |= SUSPENDED;
                }
                0
            }
            o if o == off!(twim0, tasks_resume) => {
                if a.is_write() && matches!(self.state, State::Suspended(_)) && self.events & SUSPENDED == 0 {
                    // RESUME without a new start: the suspended write simply ends (no read
                    // follows); the state stays until a start or STOP.
                }
                0
            }
            o if o == off!(twim0, events_stopped) => ev(self, STOPPED, a),
            o if o == off!(twim0, events_error) => ev(self, ERROR, a),
            o if o == off!(twim0, events_suspended) => ev(self, SUSPENDED, a),
            o if o == off!(twim0, events_rxstarted) => ev(self, RXSTARTED, a),
            o if o == off!(twim0, events_txstarted) => ev(self, TXSTARTED, a),
            o if o == off!(twim0, events_lastrx) => ev(self, LASTRX, a),
            o if o == off!(twim0, events_lasttx) => ev(self, LASTTX, a),
            o if o == off!(twim0, shorts) => a.rw(&mut self.shorts),
            o if o == off!(twim0, inten) => a.rw(&mut self.inten),
            o if o == off!(twim0, intenset) => {
                if let Access::Write(v) = a {
                    self.inten |= v;
                }
                self.inten
            }
            o if o == off!(twim0, intenclr) => {
                if let Access::Write(v) = a {
                    self.inten &= !v;
                }
                self.inten
            }
            o if o == off!(twim0, errorsrc) => {
                if let Access::Write(v) = a {
                    self.errorsrc &= !v; // write 1 to clear
                }
                self.errorsrc
            }
            o if o == off!(twim0, enable) => a.rw(&mut self.enable),
            o if o == off!(twim0, psel.scl) || o == off!(twim0, psel.sda) => {
                let i = usize::from(o == off!(twim0, psel.sda));
                if a.is_write() && self.enable == ENABLED {
                    return Err("TWIM PSEL written while enabled (the PS requires ENABLE = 0)".into());
                }
                a.rw(&mut self.psel[i])
            }
            o if o == off!(twim0, frequency) => a.rw(&mut self.frequency),
            o if o == off!(twim0, address) => a.rw(&mut self.address),
            o if (rxd..rxd + 16).contains(&o) => a.easydma(&mut self.rxd, ((o - rxd) / 4) as usize),
            o if (txd..txd + 16).contains(&o) => a.easydma(&mut self.txd, ((o - txd) / 4) as usize),
            _ => return Err(format!("TWIM0 register 0x{o:03X}")),
        };
        Ok((v, bus_s))
    }

    /// STARTTX / STARTRX: the whole transfer at once (EasyDMA); returns its bus time.
    fn start(&mut self, tx: bool, t: f64, bus: &mut dyn Bus, w: &Wiring, mem: &mut dyn Dma) -> Result<f64, String> {
        let hz = self.bus_hz()?;
        match self.state {
            State::ErrorHeld => return Ok(0.0), // the bus is held: nothing happens
            State::Broken(until) if t < until => {
                self.broken_transfers += 1;
                self.state = State::Idle;
                if tx {
                    self.txd[2] = 0;
                } else {
                    self.rxd[2] = 0;
                }
                self.events |= STOPPED;
                return Ok(0.0);
            }
            _ => {}
        }
        let addr = self.address as u8;
        let (ptr, max) = if tx { (self.txd[0], self.txd[1]) } else { (self.rxd[0], self.rxd[1]) };
        let mut buf = vec![0u8; max as usize];
        let wired = self.wired(w);
        let pending = match std::mem::replace(&mut self.state, State::Idle) {
            State::Suspended(p) => Some(p),
            _ => None,
        };
        self.events |= if tx { TXSTARTED } else { RXSTARTED };
        let result = if !wired {
            Err(Nack)
        } else if tx {
            mem.read(ptr as u64, &mut buf);
            if self.shorts & (LASTTX_SUSPEND | LASTTX_STARTRX) != 0 {
                // A read follows with a repeated start: the write is done together with it.
                if bus.acks(addr) {
                    Ok(())
                } else {
                    Err(Nack)
                }
            } else {
                bus.transaction(addr, &mut [Operation::Write(&buf)])
            }
        } else {
            let r = match &pending {
                Some(w) => bus.transaction(addr, &mut [Operation::Write(w), Operation::Read(&mut buf)]),
                None => bus.transaction(addr, &mut [Operation::Read(&mut buf)]),
            };
            if r.is_ok() {
                mem.write(ptr as u64, &buf);
            }
            r
        };
        let bytes = 1 + max as u64;
        self.bytes += bytes;
        let bus_s = bytes as f64 * 9.0 / hz;
        match result {
            Ok(()) if tx => {
                self.txd[2] = max;
                self.events |= LASTTX;
                if self.shorts & (LASTTX_SUSPEND | LASTTX_STARTRX) != 0 {
                    self.state = State::Suspended(buf);
                    if self.shorts & LASTTX_SUSPEND != 0 {
                        self.events |= SUSPENDED;
                    }
                    if self.shorts & LASTTX_STARTRX != 0 {
                        return Ok(bus_s + self.start(false, t, bus, w, mem)?);
                    }
                } else if self.shorts & LASTTX_STOP != 0 {
                    self.events |= STOPPED;
                }
            }
            Ok(()) => {
                self.rxd[2] = max;
                self.events |= LASTRX;
                if self.shorts & LASTRX_STOP != 0 {
                    self.events |= STOPPED;
                } else if self.shorts & LASTRX_SUSPEND != 0 {
                    self.state = State::Suspended(vec![]);
                    self.events |= SUSPENDED;
                } else if self.shorts & LASTRX_STARTTX != 0 {
                    return Err("TWIM SHORTS LASTRX_STARTTX is not modelled".into());
                }
            }
            Err(Nack) => {
                // Address NACK: ERROR, and the master holds the bus until STOP.
                self.errorsrc |= 1 << 1; // ANACK
                self.events |= ERROR;
                self.state = State::ErrorHeld;
                if tx {
                    self.txd[2] = 0;
                } else {
                    self.rxd[2] = 0;
                }
                return Ok(9.0 / hz);
            }
        }
        Ok(bus_s)
    }
}
