//! Models of the nRF52840 peripherals the firmware touches, in one MMIO dispatcher, with
//! virtual time. Register offsets from the nRF52840 Product Specification v1.7.
//!
//! Modelled: CLOCK/POWER (clock start events), GPIO P0/P1 (LEDs, sensor power, pull-up enable,
//! button), TWIM0 with EasyDMA (transfers against the LSM9DS1 register model; the CPU is charged
//! the 400 kHz transfer time), PWM0 (sequence values → servo pulses), TIMER0–4 (1 MHz counters,
//! compare events and interrupts), NVMC (page erase and word writes on a NOR flash model with
//! injectable power cuts), WDT (reload, timeout → reset), FICR/UICR reads, and the SCS registers
//! the firmware uses (NVIC enable/pending, VTOR, SCR, AIRCR reset, CPACR). Any other address
//! stops the run with the address and PC.

use embedded_hal::i2c::{I2c, Operation};
use embedded_storage::nor_flash::NorFlash;
use host_tests::lsm_model::Lsm9ds1Model;
use host_tests::nor::NorSim;
use std::cell::Cell;
use std::rc::Rc;

/// EasyDMA access to the emulated RAM.
pub trait Dma {
    /// Reads RAM into `buf`.
    fn read(&mut self, addr: u64, buf: &mut [u8]);
    /// Writes `data` to RAM.
    fn write(&mut self, addr: u64, data: &[u8]);
}

/// CPU clock (Hz): virtual time is instructions / CPU_HZ plus time skipped while asleep.
pub const CPU_HZ: f64 = 64e6;
/// Storage region of the firmware (flash addresses).
pub const STORAGE: (u64, u64) = (0xF8000, 0x100000);
/// WDT reload value.
const WDT_RELOAD: u32 = 0x6E52_4635;

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
    events: u32,
    /// Time of the last compare event already raised (s).
    last_event: f64,
}

impl Timer {
    fn hz(&self) -> f64 {
        16e6 / (1u64 << self.prescaler.min(9)) as f64
    }

    fn counter(&self, t: f64) -> u64 {
        if !self.running {
            return 0;
        }
        let ticks = ((t - self.t0) * self.hz()).max(0.0) as u64;
        // SHORTS COMPARE0_CLEAR: the counter runs 0..CC0.
        if self.shorts & 1 != 0 && self.cc[0] > 0 {
            ticks % self.cc[0] as u64
        } else {
            ticks & 0xFFFF_FFFF
        }
    }

    /// Time of the next COMPARE0 event after `t` (periodic timers only).
    fn next_compare0(&self, t: f64) -> Option<f64> {
        if !self.running || self.cc[0] == 0 {
            return None;
        }
        let period = self.cc[0] as f64 / self.hz();
        let k = ((t - self.t0) / period).floor() + 1.0;
        Some(self.t0 + k * period)
    }
}

/// TWIM state between its tasks.
#[derive(Debug, Clone, Default)]
struct Twim {
    regs: std::collections::HashMap<u32, u32>,
    pending_tx: Option<Vec<u8>>,
    events: u32,
    errorsrc: u32,
    tx_amount: u32,
    rx_amount: u32,
}

/// Everything outside the CPU.
#[derive(Clone)]
pub struct Periph {
    /// Instructions executed since power-on (counted by the CPU's code hook).
    pub instructions: Rc<Cell<u64>>,
    /// Virtual time skipped while the CPU slept or waited for EasyDMA (s).
    pub skipped_s: f64,
    /// The sensor on TWIM0 (and through it the rig).
    pub sensor: Lsm9ds1Model,
    /// The storage region's NOR flash.
    pub flash: NorSim,
    /// Button on P1.11 pressed.
    pub button: bool,
    /// GPIO output registers P0, P1.
    pub gpio_out: [u32; 2],
    /// Last servo pulse per PWM channel (µs, 0 = none).
    pub pwm_pulse_us: [u16; 4],
    /// Interrupts enabled in the NVIC (bit n = IRQ n).
    pub nvic_enabled: u64,
    /// Interrupts pending.
    pub nvic_pending: u64,
    /// SCB VTOR.
    pub vtor: u32,
    /// AIRCR SYSRESETREQ written.
    pub reset_request: bool,
    /// The watchdog fired.
    pub watchdog_reset: bool,
    /// A fatal modelling error (unmodelled address).
    pub fault: Option<String>,
    /// The flash lost power (injected cut): the run stops.
    pub power_cut: bool,
    /// Program counter of the current instruction (for fault messages).
    pub pc: u64,
    timers: [Timer; 5],
    twim: Twim,
    pwm_regs: std::collections::HashMap<u32, u32>,
    nvmc_config: u32,
    wdt_running: bool,
    wdt_crv: u32,
    wdt_last_pet: f64,
    clock_regs: std::collections::HashMap<u32, u32>,
    gpio_dir: [u32; 2],
    /// Bytes of TWIM traffic (address + data) so far.
    pub twim_bytes: u64,
    /// Fault injection: the I2C bus hangs (SCL held low): no TWIM transfer ever ends.
    pub twim_hang: bool,
}

fn bit(n: u32) -> u32 {
    1 << n
}

impl Periph {
    /// Peripherals at power-on with this sensor and flash.
    pub fn new(sensor: Lsm9ds1Model, flash: NorSim, instructions: Rc<Cell<u64>>) -> Self {
        Self {
            instructions,
            skipped_s: 0.0,
            sensor,
            flash,
            button: false,
            gpio_out: [0; 2],
            pwm_pulse_us: [0; 4],
            nvic_enabled: 0,
            nvic_pending: 0,
            vtor: 0,
            reset_request: false,
            watchdog_reset: false,
            fault: None,
            power_cut: false,
            pc: 0,
            timers: [Timer::default(); 5],
            twim: Twim::default(),
            pwm_regs: Default::default(),
            nvmc_config: 0,
            wdt_running: false,
            wdt_crv: 0xFFFF_FFFF,
            wdt_last_pet: 0.0,
            clock_regs: Default::default(),
            gpio_dir: [0; 2],
            twim_bytes: 0,
            twim_hang: false,
        }
    }

    /// Virtual time since power-on (s).
    pub fn now(&self) -> f64 {
        self.instructions.get() as f64 / CPU_HZ + self.skipped_s
    }

    /// Resets the MCU's peripherals (not the flash, the sensor, the rig or the time).
    pub fn reset(&mut self) {
        self.gpio_out = [0; 2];
        self.gpio_dir = [0; 2];
        self.pwm_pulse_us = [0; 4];
        self.nvic_enabled = 0;
        self.nvic_pending = 0;
        self.vtor = 0;
        self.reset_request = false;
        self.watchdog_reset = false;
        self.power_cut = false;
        self.fault = None;
        self.timers = [Timer::default(); 5];
        self.twim = Twim::default();
        self.pwm_regs.clear();
        self.nvmc_config = 0;
        self.wdt_running = false;
        self.wdt_crv = 0xFFFF_FFFF;
        self.clock_regs.clear();
        self.sensor.rig_mut().servo_off();
    }

    /// Time of the next event that needs the CPU (s): a timer interrupt or the watchdog.
    pub fn next_event(&self) -> Option<f64> {
        let t = self.now();
        let mut next: Option<f64> = None;
        for (i, tm) in self.timers.iter().enumerate() {
            if tm.inten & bit(16) != 0 && self.nvic_enabled & (1 << timer_irq(i)) != 0 {
                if let Some(e) = tm.next_compare0(t) {
                    next = Some(next.map_or(e, |n: f64| n.min(e)));
                }
            }
        }
        if self.wdt_running {
            let d = self.wdt_last_pet + self.wdt_crv as f64 / 32768.0;
            next = Some(next.map_or(d, |n: f64| n.min(d)));
        }
        next
    }

    /// Raises timer compare events and interrupts, and the watchdog, up to now.
    pub fn update(&mut self) {
        let t = self.now();
        for i in 0..5 {
            let tm = &mut self.timers[i];
            if !tm.running || tm.cc[0] == 0 || tm.shorts & 1 == 0 {
                continue;
            }
            let period = tm.cc[0] as f64 / tm.hz();
            let k = ((t - tm.t0) / period).floor();
            let last = tm.t0 + k * period;
            if k >= 1.0 && last > tm.last_event {
                tm.last_event = last;
                tm.events |= 1;
                if tm.inten & bit(16) != 0 {
                    self.nvic_pending |= 1 << timer_irq(i);
                }
            }
        }
        if self.wdt_running && t > self.wdt_last_pet + self.wdt_crv as f64 / 32768.0 {
            self.watchdog_reset = true;
        }
        self.sensor.advance_to(t);
    }

    fn unmodelled(&mut self, addr: u64, what: &str) {
        if self.fault.is_none() {
            self.fault = Some(format!("unmodelled {what} at 0x{addr:08X} (PC 0x{:08X})", self.pc));
        }
    }

    /// An MMIO read.
    pub fn read(&mut self, addr: u64) -> u64 {
        let a = addr as u32;
        let off = a & 0xFFF;
        match a & !0xFFF {
            0x4000_0000 => match off {
                0x100 | 0x104 => 1,                      // EVENTS_HFCLKSTARTED / LFCLKSTARTED
                0x40C => (bit(16) | 1) as u64,           // HFCLKSTAT: running, xtal
                0x418 => (bit(16) | 1) as u64,           // LFCLKSTAT
                _ => *self.clock_regs.get(&off).unwrap_or(&0) as u64,
            },
            0x5000_0000 => {
                let port = usize::from(off >= 0x800);
                let o = if port == 1 { off - 0x300 } else { off };
                match o {
                    0x504 | 0x508 | 0x50C => self.gpio_out[port] as u64,
                    0x510 => {
                        // IN: outputs read back; P1.11 low while the button is pressed.
                        let mut v = self.gpio_out[port] | !self.gpio_dir[port];
                        if port == 1 && self.button {
                            v &= !bit(11);
                        }
                        v as u64
                    }
                    0x514 | 0x518 | 0x51C => self.gpio_dir[port] as u64,
                    _ => 0,
                }
            }
            0x4000_3000 => {
                let tw = &self.twim;
                (match off {
                    0x104 => u32::from(tw.events & bit(1) != 0),  // STOPPED
                    0x124 => u32::from(tw.events & bit(9) != 0),  // ERROR
                    0x148 => u32::from(tw.events & bit(18) != 0), // SUSPENDED
                    0x15C => u32::from(tw.events & bit(23) != 0), // LASTRX
                    0x160 => u32::from(tw.events & bit(24) != 0), // LASTTX
                    0x4C4 => tw.errorsrc,
                    0x53C => tw.rx_amount,
                    0x54C => tw.tx_amount,
                    _ => *tw.regs.get(&off).unwrap_or(&0),
                }) as u64
            }
            0x4000_8000 | 0x4000_9000 | 0x4000_A000 | 0x4001_A000 | 0x4001_B000 => {
                let tm = &self.timers[timer_index(a)];
                (match off {
                    0x140..=0x154 => u32::from(tm.events & bit((off - 0x140) / 4) != 0),
                    0x200 => tm.shorts,
                    0x304 | 0x308 => tm.inten,
                    0x510 => tm.prescaler,
                    0x540..=0x554 => tm.cc[((off - 0x540) / 4) as usize],
                    _ => 0,
                }) as u64
            }
            0x4001_C000 => (match off {
                0x104..=0x11C => 1, // every PWM event: done at once
                _ => *self.pwm_regs.get(&off).unwrap_or(&0),
            }) as u64,
            0x4001_E000 => (match off {
                0x400 | 0x408 => 1, // READY, READYNEXT
                0x504 => self.nvmc_config,
                _ => 0,
            }) as u64,
            0x4001_0000 => (match off {
                0x400 => u32::from(self.wdt_running),
                0x404 => 1,
                0x504 => self.wdt_crv,
                0x508 => 1,
                _ => 0,
            }) as u64,
            0x1000_0000 => match off {
                0x100 => 0x52840,   // INFO.PART
                0x104 => 0x41414430, // INFO.VARIANT "AAD0"
                _ => 0xFFFF_FFFF,
            },
            0x1000_1000 => 0xFFFF_FFFF,
            0xE000_E000 => match off {
                0x100 | 0x104 => (self.nvic_enabled >> (32 * ((off - 0x100) / 4))) as u32 as u64,
                0x200 | 0x204 => (self.nvic_pending >> (32 * ((off - 0x200) / 4))) as u32 as u64,
                0xD00 => 0x410F_C241, // CPUID Cortex-M4 r0p1
                0xD08 => self.vtor as u64,
                0xD88 => 0x00F0_0000, // CPACR: CP10/CP11 full access
                _ => 0,
            },
            _ => {
                if (STORAGE.0..STORAGE.1).contains(&addr) {
                    return 0; // served by the flash mapping
                }
                self.unmodelled(addr, "read");
                0
            }
        }
    }

    /// An MMIO write.
    pub fn write(&mut self, addr: u64, value: u64, mem: &mut dyn Dma) {
        let t = self.now();
        let a = addr as u32;
        let off = a & 0xFFF;
        let v = value as u32;
        match a & !0xFFF {
            0x4000_0000 => {
                self.clock_regs.insert(off, v);
            }
            0x5000_0000 => {
                let port = usize::from(off >= 0x800);
                let o = if port == 1 { off - 0x300 } else { off };
                match o {
                    0x504 => self.gpio_out[port] = v,
                    0x508 => self.gpio_out[port] |= v,
                    0x50C => self.gpio_out[port] &= !v,
                    0x514 => self.gpio_dir[port] = v,
                    0x518 => self.gpio_dir[port] |= v,
                    0x51C => self.gpio_dir[port] &= !v,
                    0x700..=0x77C => {
                        // PIN_CNF: DIR bit 0.
                        let pin = (o - 0x700) / 4;
                        if v & 1 != 0 {
                            self.gpio_dir[port] |= bit(pin);
                        } else {
                            self.gpio_dir[port] &= !bit(pin);
                        }
                    }
                    _ => {}
                }
            }
            0x4000_3000 => self.twim_write(off, v, mem),
            0x4000_8000 | 0x4000_9000 | 0x4000_A000 | 0x4001_A000 | 0x4001_B000 => {
                let i = timer_index(a);
                let tm = &mut self.timers[i];
                match off {
                    0x000 if !tm.running => {
                        tm.running = true;
                        tm.t0 = t;
                        tm.last_event = t;
                    }
                    0x000 => {}
                    0x004 | 0x010 => tm.running = false,
                    0x00C => {
                        tm.t0 = t;
                        tm.last_event = t;
                    }
                    0x040..=0x054 => {
                        let n = ((off - 0x040) / 4) as usize;
                        tm.cc[n] = tm.counter(t) as u32;
                    }
                    0x140..=0x154 if v == 0 => tm.events &= !bit((off - 0x140) / 4),
                    0x140..=0x154 => {}
                    0x200 => tm.shorts = v,
                    0x304 => tm.inten |= v,
                    0x308 => tm.inten &= !v,
                    0x504 | 0x508 => {}
                    0x510 => tm.prescaler = v,
                    0x540..=0x554 => tm.cc[((off - 0x540) / 4) as usize] = v,
                    _ => {}
                }
            }
            0x4001_C000 => {
                self.pwm_regs.insert(off, v);
                if off == 0x008 {
                    // SEQSTART[0]: channel values (u16, bit 15 = polarity) from RAM at SEQ[0].PTR.
                    let ptr = *self.pwm_regs.get(&0x520).unwrap_or(&0) as u64;
                    let mut buf = [0u8; 8];
                    mem.read(ptr, &mut buf);
                    let top = *self.pwm_regs.get(&0x508).unwrap_or(&0x7FFF);
                    let prescaler = *self.pwm_regs.get(&0x50C).unwrap_or(&0);
                    let us_per_tick = (1u32 << prescaler) as f64 / 16.0;
                    for ch in 0..4 {
                        let raw = u16::from_le_bytes([buf[2 * ch], buf[2 * ch + 1]]);
                        // Bit 15 set: falling edge first, i.e. HIGH for `value` ticks.
                        let high = if raw & 0x8000 != 0 { raw & 0x7FFF } else { (top as u16).saturating_sub(raw) };
                        let us = (high as f64 * us_per_tick).round() as u16;
                        self.pwm_pulse_us[ch] = us;
                    }
                    let rig = self.sensor.rig_mut();
                    match self.pwm_pulse_us[0] {
                        0 => rig.servo_off(),
                        us => rig.set_pulse_us(us as f64),
                    }
                    if self.pwm_pulse_us[1] > 0 {
                        rig.set_tilt_pulse_us(self.pwm_pulse_us[1] as f64);
                    }
                }
            }
            0x4001_E000 => match off {
                0x504 => self.nvmc_config = v,
                0x508 => {
                    // ERASEPAGE: the page's start address.
                    let page = v as u64;
                    if (STORAGE.0..STORAGE.1).contains(&page) && self.nvmc_config == 2 {
                        let o = (page - STORAGE.0) as u32;
                        if self.flash.erase(o, o + 4096).is_err() {
                            self.power_cut = true;
                        }
                        self.skipped_s += 0.085; // page erase time: the CPU stalls
                    } else {
                        self.unmodelled(addr, "page erase outside the storage region");
                    }
                }
                0x540 => {}
                _ => self.unmodelled(addr, "NVMC write"),
            },
            0x4001_0000 => match off {
                0x000 => {
                    self.wdt_running = true;
                    self.wdt_last_pet = t;
                }
                0x504 => self.wdt_crv = v.max(15),
                0x508 | 0x50C | 0x304 | 0x308 => {}
                0x600..=0x61C => {
                    if v == WDT_RELOAD {
                        self.wdt_last_pet = t;
                    }
                }
                _ => self.unmodelled(addr, "WDT write"),
            },
            0xE000_E000 => match off {
                0x100 | 0x104 => self.nvic_enabled |= (v as u64) << (32 * ((off - 0x100) / 4)),
                0x180 | 0x184 => self.nvic_enabled &= !((v as u64) << (32 * ((off - 0x180) / 4))),
                0x200 | 0x204 => self.nvic_pending |= (v as u64) << (32 * ((off - 0x200) / 4)),
                0x280 | 0x284 => self.nvic_pending &= !((v as u64) << (32 * ((off - 0x280) / 4))),
                0x400..=0x4FF => {} // priorities: one level modelled
                0xD08 => self.vtor = v,
                0xD0C => {
                    if v >> 16 == 0x05FA && v & bit(2) != 0 {
                        self.reset_request = true;
                    }
                }
                0xD10 | 0xD14 | 0xD88 | 0xD24 | 0xDFC | 0xF34 | 0xF38 => {}
                _ => self.unmodelled(addr, "SCS write"),
            },
            _ => {
                if (STORAGE.0..STORAGE.1).contains(&addr) {
                    return;
                }
                self.unmodelled(addr, "write");
            }
        }
    }

    fn twim_write(&mut self, off: u32, v: u32, mem: &mut dyn Dma) {
        let reg = |tw: &Twim, o: u32| *tw.regs.get(&o).unwrap_or(&0);
        match off {
            0x008 | 0x000 if self.twim_hang => {}
            0x008 | 0x000 => {
                // STARTTX / STARTRX: do the DMA now; charge the bus time to the clock.
                let tx = off == 0x008;
                let addr = reg(&self.twim, 0x588) as u8;
                let shorts = reg(&self.twim, 0x200);
                let (ptr, max) = if tx { (reg(&self.twim, 0x544), reg(&self.twim, 0x548)) } else { (reg(&self.twim, 0x534), reg(&self.twim, 0x538)) };
                let mut buf = vec![0u8; max as usize];
                let result = if tx {
                    mem.read(ptr as u64, &mut buf);
                    let r = self.sensor.transaction(addr, &mut [Operation::Write(&buf)]);
                    if r.is_ok() && shorts & bit(8) != 0 {
                        self.twim.pending_tx = Some(buf.clone()); // LASTTX_SUSPEND: a read follows
                    } else {
                        self.twim.pending_tx = None;
                    }
                    r
                } else {
                    let r = match self.twim.pending_tx.take() {
                        Some(w) => self.sensor.transaction(addr, &mut [Operation::Write(&w), Operation::Read(&mut buf)]),
                        None => self.sensor.transaction(addr, &mut [Operation::Read(&mut buf)]),
                    };
                    if r.is_ok() {
                        mem.write(ptr as u64, &buf);
                    }
                    r
                };
                let bytes = 1 + max as u64;
                self.twim_bytes += bytes;
                self.skipped_s += bytes as f64 * 9.0 / 390e3;
                match result {
                    Ok(()) => {
                        if tx {
                            self.twim.tx_amount = max;
                            self.twim.events |= bit(24); // LASTTX
                            if shorts & bit(8) != 0 {
                                self.twim.events |= bit(18); // SUSPENDED
                            }
                            if shorts & bit(9) != 0 {
                                self.twim.events |= bit(1); // STOPPED
                            }
                        } else {
                            self.twim.rx_amount = max;
                            self.twim.events |= bit(23); // LASTRX
                            if shorts & bit(12) != 0 {
                                self.twim.events |= bit(1);
                            }
                        }
                    }
                    Err(_) => {
                        self.twim.errorsrc |= bit(1); // ANACK
                        self.twim.events |= bit(9); // ERROR
                        if tx { self.twim.tx_amount = 0 } else { self.twim.rx_amount = 0 }
                    }
                }
            }
            0x014 if !self.twim_hang => self.twim.events |= bit(1), // STOP → STOPPED
            0x01C => self.twim.events |= bit(18),
            0x020 => {}                           // RESUME
            0x104 if v == 0 => self.twim.events &= !bit(1),
            0x124 if v == 0 => self.twim.events &= !bit(9),
            0x148 if v == 0 => self.twim.events &= !bit(18),
            0x15C if v == 0 => self.twim.events &= !bit(23),
            0x160 if v == 0 => self.twim.events &= !bit(24),
            0x4C4 => self.twim.errorsrc &= !v, // write 1 to clear
            _ => {
                self.twim.regs.insert(off, v);
            }
        }
    }
}

fn timer_index(a: u32) -> usize {
    match a & !0xFFF {
        0x4000_8000 => 0,
        0x4000_9000 => 1,
        0x4000_A000 => 2,
        0x4001_A000 => 3,
        _ => 4,
    }
}

fn timer_irq(i: usize) -> u32 {
    [8, 9, 10, 26, 27][i]
}

impl Periph {
    /// A CPU read of the storage flash (NVMC region).
    pub fn flash_read(&mut self, addr: u64, size: usize) -> u64 {
        use embedded_storage::nor_flash::ReadNorFlash;
        let mut b = [0u8; 8];
        let o = (addr - STORAGE.0) as u32;
        if self.flash.read(o, &mut b[..size]).is_err() {
            self.power_cut = true;
        }
        u64::from_le_bytes(b)
    }

    /// A CPU write to the storage flash: a word program when NVMC.CONFIG = WEN.
    pub fn flash_write(&mut self, addr: u64, size: usize, value: u64) {
        if self.nvmc_config != 1 || size != 4 || !addr.is_multiple_of(4) {
            self.unmodelled(addr, "flash write without NVMC write enable or unaligned");
            return;
        }
        let o = (addr - STORAGE.0) as u32;
        if self.flash.write(o, &(value as u32).to_le_bytes()).is_err() {
            self.power_cut = true;
        }
        self.skipped_s += 41e-6; // word write time
    }
}
