//! Models of the nRF52840 peripherals the firmware touches, one module per peripheral, behind
//! one MMIO dispatcher, with virtual time. Register offsets come from the `nrf52840-pac` crate
//! (the SVD of the nRF52840 Product Specification v1.7); behaviour from the PS, the Arduino
//! bootloader's hand-over state and what the parts are known to do.
//!
//! Modelled: CLOCK/POWER, GPIO P0/P1 (LEDs, sensor power, pull-up enable, button), TWIM0 with
//! EasyDMA (against the LSM9DS1 model; the CPU is charged the bus time), PWM0 (sequence values →
//! servo pulses on the pins PSEL routes them to), TIMER0–4, RTC0–2, UARTE0, NVMC (page erase and
//! word writes on a NOR flash model with injectable power cuts, ICACHECNF), WDT, FICR/UICR, USBD
//! (with the virtual USB host of [`crate::usb_host`] on its port, and POWER's VBUS detection),
//! and the SCS (NVIC, SCB, MPU, FPU). Any other register, and any access the models reject, stops
//! the run with the address and PC.
//!
//! Boot: by default the board boots as the Arduino Nano 33 BLE's bootloader hands over (see
//! [`Periph::bootloader`]); `bootloader = false` is a cold power-on straight into the application.

pub mod bootloader;
pub mod clock;
pub mod gpio;
pub mod mpu;
pub mod nvmc;
pub mod power;
pub mod pwm;
pub mod rtc;
pub mod scs;
pub mod timer;
pub mod twim;
pub mod uarte;
pub mod usbd;
pub mod wdt;

pub use power::{ResetKind, Wake};

use embedded_hal::i2c::{I2c, Operation};
use embedded_storage::nor_flash::NorFlash;
use nrf52840_pac as pac;
use rig_sim::lsm_model::Lsm9ds1Model;
use rig_sim::nor::NorSim;
use std::cell::Cell;
use std::rc::Rc;

/// Offset of a register in a PAC register block: `off!(twim0, psel.scl)`.
macro_rules! off {
    ($block:ident, $($field:tt)+) => {
        core::mem::offset_of!(nrf52840_pac::$block::RegisterBlock, $($field)+) as u32
    };
}
pub(crate) use off;

/// A register access.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// A read.
    Read,
    /// A write of this value.
    Write(u32),
}

impl Access {
    /// Whether this is a write.
    pub fn is_write(self) -> bool {
        matches!(self, Access::Write(_))
    }

    /// A plain read/write register: stores a write, returns the register's value.
    pub fn rw(self, r: &mut u32) -> u32 {
        if let Access::Write(v) = self {
            *r = v;
        }
        *r
    }

    /// Word `i` of an EasyDMA channel's registers (PTR, MAXCNT, AMOUNT[, LIST]): AMOUNT is
    /// read-only, the others read/write.
    pub fn easydma(self, regs: &mut [u32], i: usize) -> u32 {
        match i {
            2 => regs[2],
            _ => self.rw(&mut regs[i]),
        }
    }
}

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

fn base(p: *const u8) -> u32 {
    p as usize as u32
}

/// Interrupt numbers of TIMER0–4.
pub const TIMER_IRQ: [u32; 5] = [8, 9, 10, 26, 27];
/// Interrupt number of USBD.
pub const USBD_IRQ: u32 = 39;
/// Interrupt number of POWER_CLOCK.
pub const POWER_CLOCK_IRQ: u32 = 0;
/// POWER's USB events in INTEN (USBDETECTED, USBREMOVED, USBPWRRDY).
const POWER_USB_EVENTS: u32 = power::USBDETECTED | power::USBREMOVED | power::USBPWRRDY;

/// The LEDs as the operator sees them (lit = true).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Leds {
    /// D13 (P0.13, active high; lit also while a PWM channel drives it).
    pub d13: bool,
    /// Red (P0.24, active low).
    pub red: bool,
    /// Green (P0.16, active low).
    pub green: bool,
    /// Blue (P0.06, active low).
    pub blue: bool,
}

impl Leds {
    /// "Done: stored and applied": green and D13 lit, red and blue off.
    pub fn done(&self) -> bool {
        self.green && self.d13 && !self.red && !self.blue
    }
}

/// FICR.DEVICEID[0..2] of the modelled chip (a made-up unique id).
pub const FICR_DEVICEID: [u32; 2] = [0x5A5A_1234, 0xA5A5_5678];
/// FICR.DEVICEADDR[0..2] of the modelled chip (made up; DEVICEADDR[1] bits 31:16 are 1).
pub const FICR_DEVICEADDR: [u32; 2] = [0xC0FF_EE01, 0xFFFF_D00D];

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
    /// Boot through the Arduino bootloader (default): at every reset the application starts
    /// with what the stock Nano 33 BLE bootloader leaves: HFXO running with EVENTS_HFCLKSTARTED
    /// still set, LFCLK and RTC1 running, UARTE0 enabled and receiving, PWM0 enabled with OUT[0]
    /// on P0.13 (its breathing LED), the MPU enabled (flash privileged read-only/executable,
    /// SRAM execute-never), the I-cache (NVMC.ICACHECNF) and the DC/DC (POWER.DCDCEN) on, VTOR at
    /// 0x10000. `false`: a cold power-on straight into the application (VTOR 0, all at reset
    /// values).
    pub bootloader: bool,
    /// The stock bootloader's stand-in (when [`Periph::bootloader`] is set): where it is.
    pub stock: bootloader::StockBootloader,
    /// A debugger holds the chip in debug interface mode: System OFF is only emulated (PS
    /// §5.3.2): the CPU runs on after SYSTEMOFF.
    pub debug_interface: bool,
    /// In System OFF since SYSTEMOFF, with whether VBUS was present then (a rising VBUS wakes).
    pub off: Option<bool>,
    /// CLOCK.
    pub clock: clock::Clock,
    /// POWER.
    pub power: power::Power,
    /// GPIO P0/P1.
    pub gpio: gpio::Gpio,
    /// TWIM0.
    pub twim: twim::Twim,
    /// PWM0.
    pub pwm: pwm::Pwm,
    /// TIMER0–4.
    pub timers: [timer::Timer; 5],
    /// RTC0–2.
    pub rtc: [rtc::Rtc; 3],
    /// UARTE0.
    pub uarte: uarte::Uarte,
    /// NVMC.
    pub nvmc: nvmc::Nvmc,
    /// WDT.
    pub wdt: wdt::Wdt,
    /// USBD.
    pub usbd: usbd::Usbd,
    /// The USB host on the board's port (outside the chip: a reset does not touch it).
    pub usb_host: crate::usb_host::Host,
    /// NVIC, SCB, MPU.
    pub scs: scs::Scs,
    /// The interrupt being handled (set by the CPU model).
    pub active_irq: Option<u32>,
    /// The watchdog fired.
    pub watchdog_reset: bool,
    /// A fatal modelling error (unmodelled address, an access the part rejects).
    pub fault: Option<String>,
    /// The flash lost power (injected cut): the run stops.
    pub power_cut: bool,
    /// Start address of the translated block being executed (for fault messages).
    pub pc: Rc<Cell<u64>>,
    /// The sensor supply (P0.22) was seen driven high with standard drive: the sensors'
    /// current drops its voltage (brown-out); the sensor does not work.
    pub vdd_env_drop: bool,
    sensor_powered: bool,
}

/// The sensor behind the TWIM: powered by P0.22 (high drive), its bus pulled up by P1.00.
struct SensorBus<'a> {
    sensor: &'a mut Lsm9ds1Model,
    usable: bool,
}

impl twim::Bus for SensorBus<'_> {
    fn transaction(&mut self, address: u8, ops: &mut [Operation<'_>]) -> Result<(), twim::Nack> {
        if !self.usable {
            return Err(twim::Nack);
        }
        self.sensor.transaction(address, ops).map_err(|_| twim::Nack)
    }

    fn acks(&mut self, address: u8) -> bool {
        self.usable && self.sensor.acks(address)
    }
}

impl Periph {
    /// Peripherals at power-on with this sensor and flash (booting through the bootloader).
    pub fn new(sensor: Lsm9ds1Model, flash: NorSim, instructions: Rc<Cell<u64>>) -> Self {
        let mut p = Self {
            instructions,
            skipped_s: 0.0,
            sensor,
            flash,
            button: false,
            bootloader: true,
            stock: Default::default(),
            debug_interface: false,
            off: None,
            clock: Default::default(),
            power: power::Power::new(),
            gpio: Default::default(),
            twim: Default::default(),
            pwm: Default::default(),
            timers: [timer::Timer::new(4), timer::Timer::new(4), timer::Timer::new(4), timer::Timer::new(6), timer::Timer::new(6)],
            rtc: Default::default(),
            uarte: uarte::Uarte::new(false),
            nvmc: Default::default(),
            wdt: wdt::Wdt::new(),
            usbd: usbd::Usbd::new(),
            usb_host: crate::usb_host::Host::new(),
            scs: Default::default(),
            active_irq: None,
            watchdog_reset: false,
            fault: None,
            power_cut: false,
            pc: Rc::new(Cell::new(0)),
            vdd_env_drop: false,
            sensor_powered: false,
        };
        p.reset(ResetKind::PowerOn);
        p
    }

    /// Virtual time since power-on (s).
    pub fn now(&self) -> f64 {
        self.instructions.get() as f64 / CPU_HZ + self.skipped_s
    }

    /// A reset of `kind`: the MCU's peripherals to their reset state (the WDT only when `kind`
    /// resets it), then what the bootloader leaves when [`Periph::bootloader`] is set. Not the
    /// flash, the sensor, the rig or the time. A power-on also removes the sensor's power.
    pub fn reset(&mut self, kind: ResetKind) {
        let t = self.now();
        let bl = self.bootloader;
        self.clock = clock::Clock::new(bl);
        self.power.reset(kind);
        if bl {
            self.power.dcdcen = 1;
        }
        if !matches!(kind, ResetKind::OffWake(_)) {
            self.gpio = Default::default();
        }
        self.off = None;
        self.usb_host.stand_in = None;
        if bl {
            self.gpio.port[0].cnf[13] = 0x3; // the bootloader's LED pin: output, input disconnected
        }
        let hang = self.twim.hang;
        self.twim = twim::Twim::new();
        self.twim.hang = hang;
        self.pwm = pwm::Pwm::new(bl);
        self.timers = [timer::Timer::new(4), timer::Timer::new(4), timer::Timer::new(4), timer::Timer::new(6), timer::Timer::new(6)];
        self.rtc = [rtc::Rtc::new(false, t), rtc::Rtc::new(bl, t), rtc::Rtc::new(false, t)];
        self.uarte = uarte::Uarte::new(bl);
        self.nvmc = nvmc::Nvmc::new(bl);
        if kind.resets_wdt() {
            self.wdt = wdt::Wdt::new();
        }
        // The USBD to its reset state (pull-up off: the host sees a disconnect); the generation
        // moves on so that the host retries what it was waiting for.
        let generation = self.usbd.generation + 1;
        self.usbd = usbd::Usbd::new();
        self.usbd.generation = generation;
        self.usbd.changed_at = t;
        self.scs = scs::Scs::new(bl);
        self.active_irq = None;
        self.watchdog_reset = false;
        self.power_cut = false;
        self.fault = None;
        self.sensor.rig_mut().servo_off();
        self.sync_sensor_power();
    }

    /// The LEDs as seen on the board.
    pub fn leds(&self) -> Leds {
        let low = |pin| self.gpio.drives(0, pin, false);
        let d13 = match self.pwm.channel_on(0, 13) {
            Some(ch) => self.pwm.running && self.pwm.duty[ch] > 0.0,
            None => self.gpio.drives(0, 13, true),
        };
        Leds { d13, red: low(24), green: low(16), blue: low(6) }
    }

    /// The sensor is powered (P0.22 high with high drive).
    pub fn sensor_powered(&self) -> bool {
        self.sensor_powered
    }

    fn sync_sensor_power(&mut self) {
        if self.gpio.vdd_env_weak() {
            self.vdd_env_drop = true;
        }
        let on = self.gpio.vdd_env_on();
        if on != self.sensor_powered {
            let t = self.now();
            self.sensor.advance_to(t);
            self.sensor.set_powered(on);
            self.sensor_powered = on;
        }
    }

    /// Time of the next event that needs the CPU (s): a timer interrupt or the watchdog.
    pub fn next_event(&self) -> Option<f64> {
        let t = self.now();
        let mut next: Option<f64> = None;
        let mut add = |e: f64| next = Some(next.map_or(e, |n: f64| n.min(e)));
        for (i, tm) in self.timers.iter().enumerate() {
            if self.scs.nvic_enabled & (1 << TIMER_IRQ[i]) != 0 {
                if let Some(e) = tm.next_compare0(t) {
                    add(e);
                }
            }
        }
        if let Some(d) = self.wdt.deadline() {
            add(d);
        }
        // The USB host's activity wakes a CPU that waits for the USBD interrupt.
        if self.scs.nvic_enabled & (1 << USBD_IRQ) != 0 && self.usbd.inten() != 0 {
            let phy = self.usb_phy();
            if let Some(e) = self.usb_host.next_time(&self.usbd) {
                add(e);
            }
            if let Some(e) = self.usbd.ready_time(phy) {
                add(e);
            }
        }
        if self.scs.nvic_enabled & (1 << POWER_CLOCK_IRQ) != 0 && self.clock.inten() & power::USBPWRRDY != 0 {
            if let Some(e) = self.power.output_ready_time() {
                add(e);
            }
        }
        next
    }

    /// What the USBD sees of VBUS and the clocks.
    pub fn usb_phy(&self) -> usbd::Phy {
        usbd::Phy { vbus: self.power.vbus(), output_ready: self.power.output_ready(), hfxo: self.clock.hfxo_running }
    }

    /// Runs the USB supply, the USBD's READY and the host up to now, and raises the USBD and
    /// POWER interrupt lines.
    pub fn advance_usb(&mut self) {
        let t = self.now();
        self.power.settle(t);
        self.clock.settle(t);
        let phy = self.usb_phy();
        self.usbd.settle(t, phy);
        if let Err(e) = self.usb_host.advance(t, &mut self.usbd, phy) {
            self.fail(e, base(pac::USBD::PTR.cast()) as u64);
        }
        self.usb_lines();
    }

    fn usb_lines(&mut self) {
        if self.usbd.line() && self.active_irq != Some(USBD_IRQ) {
            self.scs.nvic_pending |= 1 << USBD_IRQ;
        }
        if self.power.usb_events & self.clock.inten() & POWER_USB_EVENTS != 0 && self.active_irq != Some(POWER_CLOCK_IRQ) {
            self.scs.nvic_pending |= 1 << POWER_CLOCK_IRQ;
        }
    }

    /// Raises timer events and interrupt lines, and the watchdog, up to now.
    pub fn update(&mut self) {
        let t = self.now();
        let instr = self.instructions.get();
        for (tm, irq) in self.timers.iter_mut().zip(TIMER_IRQ) {
            tm.update(t);
            if tm.line(instr) && self.active_irq != Some(irq) {
                self.scs.nvic_pending |= 1 << irq;
            }
        }
        // The WDT does not run in System OFF.
        if self.off.is_none() && self.wdt.deadline().is_some_and(|d| t > d) {
            self.watchdog_reset = true;
        }
        self.sensor.advance_to(t);
        self.sync_sensor_power();
        self.advance_usb();
    }

    /// The CPU returns from the handler of `irq`: a level interrupt still asserted (an event not
    /// cleared, or a clear still in flight) becomes pending again.
    pub fn exception_return(&mut self, irq: u32) {
        self.active_irq = None;
        let instr = self.instructions.get();
        if let Some(i) = TIMER_IRQ.iter().position(|&n| n == irq) {
            if self.timers[i].line(instr) {
                self.scs.nvic_pending |= 1 << irq;
            }
            self.timers[i].note_return(instr);
        }
        if irq == USBD_IRQ || irq == POWER_CLOCK_IRQ {
            self.usb_lines();
        }
    }

    fn fail(&mut self, what: String, addr: u64) {
        if self.fault.is_none() {
            self.fault = Some(format!("{what} at 0x{addr:08X} (in the block at PC 0x{:08X})", self.pc.get()));
        }
    }

    /// An MMIO read.
    pub fn read(&mut self, addr: u64) -> u64 {
        match self.access(addr, Access::Read, None) {
            Ok(v) => v as u64,
            Err(e) => {
                self.fail(format!("read: {e}"), addr);
                0
            }
        }
    }

    /// An MMIO write.
    pub fn write(&mut self, addr: u64, value: u64, mem: &mut dyn Dma) {
        if let Err(e) = self.access(addr, Access::Write(value as u32), Some(mem)) {
            self.fail(format!("write: {e}"), addr);
        }
    }

    fn access(&mut self, addr: u64, a: Access, mem: Option<&mut dyn Dma>) -> Result<u32, String> {
        let t = self.now();
        let a32 = addr as u32;
        let (blk, o) = (a32 & !0xFFF, a32 & 0xFFF);
        let timers = [
            base(pac::TIMER0::PTR.cast()),
            base(pac::TIMER1::PTR.cast()),
            base(pac::TIMER2::PTR.cast()),
            base(pac::TIMER3::PTR.cast()),
            base(pac::TIMER4::PTR.cast()),
        ];
        let rtcs = [base(pac::RTC0::PTR.cast()), base(pac::RTC1::PTR.cast()), base(pac::RTC2::PTR.cast())];
        let mut no_dma = NoDma;
        let mem: &mut dyn Dma = match mem {
            Some(m) => m,
            None => &mut no_dma,
        };
        match blk {
            b if b == base(pac::CLOCK::PTR.cast()) => {
                if power::Power::claims(o) {
                    self.power.access(o, a, t)
                } else {
                    self.clock.access(o, a, t)
                }
            }
            b if b == base(pac::P0::PTR.cast()) => {
                let v = self.gpio.access(o, a, self.button)?;
                if a.is_write() {
                    self.sync_sensor_power();
                }
                Ok(v)
            }
            b if b == base(pac::TWIM0::PTR.cast()) => {
                self.sensor.advance_to(t);
                // The sensor lives through each transfer: what it produces while a burst runs
                // is there when the burst reaches it (a BMI270 FIFO read after a stall).
                self.sensor.bus_hz = self.twim.bus_hz().ok();
                self.sync_sensor_power();
                let usable = self.sensor_powered && self.gpio.pullups_on();
                let wiring = twim::Wiring { scl_sda_cnf: [self.gpio.cnf(0, 15), self.gpio.cnf(0, 14)] };
                let mut bus = SensorBus { sensor: &mut self.sensor, usable };
                let (v, bus_s) = self.twim.access(o, a, t, &mut bus, &wiring, mem)?;
                self.skipped_s += bus_s;
                Ok(v)
            }
            b if timers.contains(&b) => {
                let i = timers.iter().position(|&x| x == b).unwrap_or(0);
                let instr = self.instructions.get();
                self.timers[i].access(o, a, t, instr)
            }
            b if rtcs.contains(&b) => {
                let i = rtcs.iter().position(|&x| x == b).unwrap_or(0);
                self.rtc[i].access(o, a, t)
            }
            b if b == base(pac::UARTE0::PTR.cast()) => self.uarte.access(o, a, t),
            b if b == base(pac::PWM0::PTR.cast()) => {
                let v = self.pwm.access(o, a, t, mem)?;
                if a.is_write() {
                    self.drive_servos();
                }
                Ok(v)
            }
            b if b == base(pac::NVMC::PTR.cast()) => {
                let (v, op) = self.nvmc.access(o, a)?;
                if let nvmc::FlashOp::ErasePage(page) = op {
                    let off = (page - STORAGE.0) as u32;
                    if self.flash.erase(off, off + 4096).is_err() {
                        self.power_cut = true;
                    }
                    self.skipped_s += nvmc::ERASE_S; // the CPU stalls during the erase
                }
                Ok(v)
            }
            b if b == base(pac::WDT::PTR.cast()) => self.wdt.access(o, a, t),
            b if b == base(pac::USBD::PTR.cast()) => {
                self.advance_usb();
                let phy = self.usb_phy();
                let v = self.usbd.access(o, a, t, phy, mem);
                self.power.set_usbd_enabled(self.usbd.enable == 1, t);
                self.usb_lines();
                v
            }
            usbd::ERRATA_BLOCK => self.usbd.errata_access(o, a),
            b if b == base(pac::FICR::PTR.cast()) => match (o, a) {
                (0x010, Access::Read) => Ok(4096), // CODEPAGESIZE
                (0x014, Access::Read) => Ok(256),  // CODESIZE
                (0x100, Access::Read) => Ok(0x52840),
                (0x104, Access::Read) => Ok(0x4141_4430), // INFO.VARIANT "AAD0"
                (0x060, Access::Read) => Ok(FICR_DEVICEID[0]),
                (0x064, Access::Read) => Ok(FICR_DEVICEID[1]),
                (0x0A4, Access::Read) => Ok(FICR_DEVICEADDR[0]),
                (0x0A8, Access::Read) => Ok(FICR_DEVICEADDR[1]), // bits 31:16 read 1 on the part
                (_, Access::Read) => Ok(0xFFFF_FFFF),
                _ => Err("FICR is read-only".into()),
            },
            b if b == base(pac::UICR::PTR.cast()) => match a {
                Access::Read => Ok(0xFFFF_FFFF),
                Access::Write(_) => Err("UICR write".into()),
            },
            0xE000_E000 => self.scs.access(o, a),
            _ => Err("unmodelled peripheral".into()),
        }
    }

    /// Forwards the PWM outputs routed to the servo pins to the rig.
    fn drive_servos(&mut self) {
        let pan = self.pwm.pulse_on(0, 27);
        let tilt = self.pwm.pulse_on(1, 2);
        let rig = self.sensor.rig_mut();
        match pan {
            0 => rig.servo_off(),
            us => rig.set_pulse_us(us as f64),
        }
        if tilt > 0 {
            rig.set_tilt_pulse_us(tilt as f64);
        }
    }

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

    /// A CPU write to the storage flash: a word program when NVMC.CONFIG = WEN (and the MPU
    /// lets privileged code write there).
    pub fn flash_write(&mut self, addr: u64, size: usize, value: u64) {
        if let Err(e) = self.scs.mpu.check(addr, mpu::Check::Write) {
            self.fail(e, addr);
            return;
        }
        if self.nvmc.config != 1 || size != 4 || !addr.is_multiple_of(4) {
            self.fail("flash write without NVMC write enable or unaligned".into(), addr);
            return;
        }
        let o = (addr - STORAGE.0) as u32;
        if self.flash.write(o, &(value as u32).to_le_bytes()).is_err() {
            self.power_cut = true;
        }
        self.skipped_s += nvmc::WRITE_S;
    }
}

/// An access that moves no EasyDMA data (reads give zeros).
pub struct NoDma;

impl Dma for NoDma {
    fn read(&mut self, _: u64, buf: &mut [u8]) {
        buf.fill(0);
    }
    fn write(&mut self, _: u64, _: &[u8]) {}
}
