//! GPIO P0/P1 (nRF52840 PS v1.7 §6.9): OUT/OUTSET/OUTCLR, IN, DIR/DIRSET/DIRCLR (the same bits as
//! PIN_CNF.DIR), LATCH, DETECTMODE and PIN_CNF[n] (DIR, INPUT, PULL, DRIVE, SENSE).
//!
//! What the Nano 33 BLE wires to them: P0.22 powers the sensors (VDD_ENV, through the pin's
//! driver: it must drive '1' with high drive, or the sensors' current drops the voltage and
//! they brown out), P1.00 feeds the I2C pull-up resistors, P1.11 (D2) is the button to GND.

use super::{off, Access};

/// PIN_CNF reset value: input, input buffer disconnected.
const PIN_CNF_RESET: u32 = 0x0000_0002;

/// PIN_CNF.DRIVE values.
pub mod drive {
    /// Standard '0', standard '1'.
    pub const S0S1: u32 = 0;
    /// High drive '0', standard '1'.
    pub const H0S1: u32 = 1;
    /// Standard '0', high drive '1'.
    pub const S0H1: u32 = 2;
    /// High drive '0', high drive '1'.
    pub const H0H1: u32 = 3;
    /// Disconnect '0', standard '1'.
    pub const D0S1: u32 = 4;
    /// Disconnect '0', high drive '1'.
    pub const D0H1: u32 = 5;
    /// Standard '0', disconnect '1' (open drain, what TWIM pins need).
    pub const S0D1: u32 = 6;
    /// High drive '0', disconnect '1'.
    pub const H0D1: u32 = 7;
}

/// One port.
#[derive(Debug, Clone)]
pub struct Port {
    /// OUT.
    pub out: u32,
    /// PIN_CNF[0..32].
    pub cnf: [u32; 32],
    latch: u32,
    detectmode: u32,
}

impl Default for Port {
    fn default() -> Self {
        Self { out: 0, cnf: [PIN_CNF_RESET; 32], latch: 0, detectmode: 0 }
    }
}

impl Port {
    /// DIR: PIN_CNF.DIR bits.
    pub fn dir(&self) -> u32 {
        (0..32).filter(|&n| self.cnf[n] & 1 != 0).fold(0, |d, n| d | (1 << n))
    }

    fn set_dir(&mut self, dir: u32) {
        for n in 0..32 {
            self.cnf[n] = (self.cnf[n] & !1) | ((dir >> n) & 1);
        }
    }
}

/// Both ports.
#[derive(Debug, Clone, Default)]
pub struct Gpio {
    /// P0, P1.
    pub port: [Port; 2],
}

impl Gpio {
    /// PIN_CNF of `port`.`pin`.
    pub fn cnf(&self, port: usize, pin: usize) -> u32 {
        self.port[port].cnf[pin]
    }

    /// The pin is an output driving `high`.
    pub fn drives(&self, port: usize, pin: usize, high: bool) -> bool {
        let p = &self.port[port];
        p.cnf[pin] & 1 != 0 && ((p.out >> pin) & 1 != 0) == high
    }

    /// PIN_CNF.DRIVE of a pin.
    pub fn drive(&self, port: usize, pin: usize) -> u32 {
        (self.cnf(port, pin) >> 8) & 7
    }

    /// VDD_ENV (P0.22) is driven high with high drive on '1' (S0H1, H0H1 or D0H1).
    pub fn vdd_env_on(&self) -> bool {
        self.drives(0, 22, true) && matches!(self.drive(0, 22), drive::S0H1 | drive::H0H1 | drive::D0H1)
    }

    /// P0.22 is driven high but with standard drive on '1': the sensors' supply sags.
    pub fn vdd_env_weak(&self) -> bool {
        self.drives(0, 22, true) && !self.vdd_env_on()
    }

    /// The I2C pull-ups (P1.00) are driven high.
    pub fn pullups_on(&self) -> bool {
        self.drives(1, 0, true)
    }

    /// IN of a port: outputs read back their OUT bit when the input buffer is connected;
    /// inputs read 1 (pulled up or idle high) unless disconnected; P1.11 reads 0 while the
    /// button is pressed.
    fn input(&self, port: usize, button: bool) -> u32 {
        let p = &self.port[port];
        let mut v = 0;
        for n in 0..32 {
            let c = p.cnf[n];
            if c & 2 != 0 {
                continue; // input buffer disconnected
            }
            let level = if c & 1 != 0 { (p.out >> n) & 1 != 0 } else { !(port == 1 && n == 11 && button) };
            v |= u32::from(level) << n;
        }
        v
    }

    /// The DETECT signal (DETECTMODE = default; PS v1.7 §6.9.2 "Pin sense mechanism"): a pin
    /// whose PIN_CNF.SENSE is high (2) reads 1, or one whose SENSE is low (3) reads 0. It wakes
    /// the chip from System OFF (PS §5.3.2), at once if already high (a level, not an edge).
    pub fn detect(&self, button: bool) -> bool {
        (0..2).any(|port| {
            let input = self.input(port, button);
            (0..32).any(|n| {
                let (c, level) = (self.port[port].cnf[n], (input >> n) & 1 != 0);
                c & 2 == 0 && matches!(((c >> 16) & 3, level), (2, true) | (3, false))
            })
        })
    }

    /// An access at offset `o` of the GPIO block (P0 at 0x000, P1 at 0x300).
    pub fn access(&mut self, o: u32, a: Access, button: bool) -> Result<u32, String> {
        let port = usize::from(o >= 0x800);
        let o = if port == 1 { o - 0x300 } else { o };
        let cnf0 = off!(p0, pin_cnf);
        let input = self.input(port, button);
        let p = &mut self.port[port];
        Ok(match (o, a) {
            (o, a) if o == off!(p0, out) => a.rw(&mut p.out),
            (o, Access::Write(v)) if o == off!(p0, outset) => {
                p.out |= v;
                p.out
            }
            (o, Access::Write(v)) if o == off!(p0, outclr) => {
                p.out &= !v;
                p.out
            }
            (o, Access::Read) if o == off!(p0, outset) || o == off!(p0, outclr) => p.out,
            (o, Access::Read) if o == off!(p0, in_) => input,
            (o, Access::Write(v)) if o == off!(p0, dir) => {
                p.set_dir(v);
                v
            }
            (o, Access::Write(v)) if o == off!(p0, dirset) => {
                let d = p.dir() | v;
                p.set_dir(d);
                d
            }
            (o, Access::Write(v)) if o == off!(p0, dirclr) => {
                let d = p.dir() & !v;
                p.set_dir(d);
                d
            }
            (o, Access::Read) if o == off!(p0, dir) || o == off!(p0, dirset) || o == off!(p0, dirclr) => p.dir(),
            (o, Access::Write(v)) if o == off!(p0, latch) => {
                p.latch &= !v;
                p.latch
            }
            (o, Access::Read) if o == off!(p0, latch) => p.latch,
            (o, a) if o == off!(p0, detectmode) => a.rw(&mut p.detectmode),
            (o, a) if (cnf0..cnf0 + 128).contains(&o) && o % 4 == 0 => a.rw(&mut p.cnf[((o - cnf0) / 4) as usize]),
            _ => return Err(format!("GPIO P{port} register 0x{o:03X}")),
        })
    }
}
