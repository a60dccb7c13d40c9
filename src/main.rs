//! Nano 33 BLE gyroscope self-calibration firmware: the thin I/O shell around
//! `calib_core::procedure`. It moves bytes between the peripherals and the procedure and adds no
//! calibration logic of its own.
//!
//! Boot: put what the Arduino bootloader leaves running into a known state, start the crystal,
//! the watchdog, the clocks, the sensor rail. Loop (woken every 2 ms by TIMER2): pet the
//! watchdog, drain the LSM9DS1 FIFO (timestamps from the 1 MHz TIMER1 on the crystal), serve
//! USB (started once VBUS is present) and take its commands and the button's, feed the
//! procedure, execute its commands (servo PWM, LEDs, log lines, flash store, apply), refresh
//! the LEDs, sleep. Every log line goes to RTT and to the USB port ([`Console`]); neither ever
//! blocks (`gyrocal_fw::rtt`, `gyrocal_fw::serial::Outbox`).
#![no_std]
#![no_main]

use calib_core::export::Format;
use calib_core::procedure::{Config, ErrorClass, Led, Phase, Procedure, Report, Sample, Shell};
use calib_core::record::Record;
use calib_core::text::{Level as Log, V3};
use core::fmt::{self, Write};
use cortex_m::peripheral::NVIC;
use embedded_hal::delay::DelayNs;
use embedded_hal::digital::{InputPin, OutputPin};
use embedded_hal::i2c::{ErrorType, I2c, Operation};
use gyrocal_fw::bootloader::FlashMap;
use gyrocal_fw::button::{Button, Press};
use gyrocal_fw::led::{render, Lights};
use gyrocal_fw::lsm9ds1::{AccelScale, GyroScale, Lsm9ds1, Odr, SensorConfig, SensorError, FIFO_DEPTH};
use gyrocal_fw::serial::{self, Command};
use gyrocal_fw::stamp::Stamper;
use gyrocal_fw::storage::{Storage, StoreError};
use gyrocal_fw::usb::{Error as UsbError, Usb};
use hal::gpio::{DriveConfig, Level, Output, Pin, PushPull};
use hal::pac::{self, interrupt};
use hal::pwm::{Channel, Prescaler, Pwm};
use hal::{twim, wdt, Timer, Twim};
use nrf52840_hal as hal;
use panic_probe as _;

/// Loop period (µs): the FIFO (32 slots) lasts 33 ms at 952 Hz.
const TICK_US: u32 = 2_000;
/// Commands (button, USB) one main-loop tick takes; more are reported as ignored, never dropped
/// silently.
const COMMANDS_PER_TICK: usize = 8;
/// FIFO read period (s).
const FIFO_POLL_S: f64 = 0.010;
/// Watchdog timeout (s).
const WATCHDOG_S: u32 = 2;
/// Servo PWM: 1 µs ticks, 20 ms period.
const PWM_TOP: u16 = 20_000;
/// Polls of EVENTS_HFCLKSTARTED before giving up on the crystal (≥ 10 ms at 64 MHz; the
/// crystal starts in ≈ 0.36 ms).
const HFXO_POLLS: u32 = 200_000;
/// Polls of UARTE0's EVENTS_RXTO after STOPRX (≥ 1 ms at 64 MHz; one character at 115 200 Bd
/// is 87 µs).
const UARTE_STOP_POLLS: u32 = 20_000;
/// TWIM0 FREQUENCY: nRF52840 erratum 219 (at the 400 kHz setting the SCL low time is below the
/// I2C minimum); Nordic's fix is this 390 kHz value.
const TWIM_FREQUENCY_390K: u32 = 0x0620_0000;

/// Sensor settings: 119 Hz (952 Hz with `--features odr952`), ±500 °/s, ±2 g.
const SENSOR: SensorConfig =
    SensorConfig { odr: if cfg!(feature = "odr952") { Odr::Hz952 } else { Odr::Hz119 }, gyro: GyroScale::Dps500, accel: AccelScale::G2 };

/// The procedure's configuration: the defaults, or with a pan/tilt bracket (`--features
/// tilt-servo`, the tilt servo on D10) the pan/tilt plan and the full 3×3 `K`; the sensor's ranges.
const CONFIG: Config = Config {
    accel_range_g: SENSOR.accel.range_g(),
    gyro_range_dps: SENSOR.gyro.range_dps(),
    ..if cfg!(feature = "tilt-servo") { Config::PAN_TILT } else { Config::DEFAULT }
};

/// The procedure state (poses, moves, queue: ~11 KiB) in static RAM. Built once at boot in its
/// own stack frame, so that the main loop's frame does not keep room for a copy of it.
#[inline(never)]
fn procedure(stored: Option<Record>) -> &'static mut Procedure {
    match cortex_m::singleton!(: Procedure = Procedure::new(CONFIG, stored)) {
        Some(p) => p,
        None => cortex_m::peripheral::SCB::sys_reset(),
    }
}

/// The four LEDs (RGB active low).
struct Leds {
    d13: Pin<Output<PushPull>>,
    red: Pin<Output<PushPull>>,
    green: Pin<Output<PushPull>>,
    blue: Pin<Output<PushPull>>,
}

impl Leds {
    fn show(&mut self, l: Lights) {
        let set = |p: &mut Pin<Output<PushPull>>, on: bool| {
            let _ = if on { p.set_high() } else { p.set_low() };
        };
        set(&mut self.d13, l.d13);
        set(&mut self.red, !l.red);
        set(&mut self.green, !l.green);
        set(&mut self.blue, !l.blue);
    }
}

/// Microseconds since boot from TIMER1, free-running at 1 MHz in 32-bit mode with no shortcut,
/// so that it wraps at exactly 2³² µs (71.6 min); extended to 64 bits (read more often than
/// that: the loop runs every 2 ms).
struct Clock {
    timer: pac::TIMER1,
    last: u32,
    high: u64,
}

impl Clock {
    fn start(timer: pac::TIMER1) -> Self {
        // SAFETY (all writes): TIMER1 is ours; values from the PS (PRESCALER 4: 16 MHz / 2⁴).
        timer.tasks_stop.write(|w| unsafe { w.bits(1) });
        timer.shorts.reset();
        timer.intenclr.write(|w| unsafe { w.bits(u32::MAX) });
        timer.mode.write(|w| w.mode().timer());
        timer.bitmode.write(|w| w.bitmode()._32bit());
        timer.prescaler.write(|w| unsafe { w.prescaler().bits(4) });
        timer.tasks_clear.write(|w| unsafe { w.bits(1) });
        timer.tasks_start.write(|w| unsafe { w.bits(1) });
        Self { timer, last: 0, high: 0 }
    }

    fn now_us(&mut self) -> u64 {
        // SAFETY: CAPTURE[0] copies the counter into CC[0].
        self.timer.tasks_capture[0].write(|w| unsafe { w.bits(1) });
        let v = self.timer.cc[0].read().bits();
        if v < self.last {
            self.high += 1 << 32;
        }
        self.last = v;
        self.high + v as u64
    }

    fn now_s(&mut self) -> f64 {
        self.now_us() as f64 * 1e-6
    }
}

/// Busy waits on [`Clock`] (the sensor's reset; at most tens of ms, below the watchdog's 2 s).
struct Wait<'a>(&'a mut Clock);

impl DelayNs for Wait<'_> {
    fn delay_ns(&mut self, ns: u32) {
        let end = self.0.now_us() + (ns as u64).div_ceil(1000);
        while self.0.now_us() < end {}
    }
}

/// TWIM0 as the sensor's bus. After a failed transfer (e.g. an address NACK) the TWIM is
/// disabled and enabled again before the next one: a TWIM that received a STOP task while idle
/// fails the transfers that follow (embassy-rs/embassy #6722), which would spoil the Rev2 probe
/// at 0x68 that follows a NACK at 0x6B.
struct Bus(Twim<pac::TWIM0>);

impl ErrorType for Bus {
    type Error = twim::Error;
}

impl I2c for Bus {
    fn transaction(&mut self, address: u8, operations: &mut [Operation<'_>]) -> Result<(), Self::Error> {
        let r = self.0.transaction(address, operations);
        if r.is_err() {
            self.0.disable();
            // Let the bus go idle: 30 µs at 64 MHz, more than one byte time at 390 kHz (23 µs).
            cortex_m::asm::delay(64 * 30);
            self.0.enable();
        }
        r
    }
}

#[interrupt]
fn TIMER2() {
    // Only wakes the loop: clear the compare event, and read it back so that the write has
    // reached the peripheral before the handler returns (else the interrupt fires again).
    // SAFETY: this timer's own event register.
    let t = unsafe { &*pac::TIMER2::ptr() };
    t.events_compare[0].write(|w| unsafe { w.bits(0) });
    let _ = t.events_compare[0].read().bits();
}

/// Puts what the stock Arduino bootloader leaves running into a known state: it jumps here
/// with the MPU on (flash read/execute only: a store to the record pages would fault), UARTE0
/// receiving, PWM0 driving P0.13, RTC1 running with its interrupt enabled, and interrupts
/// enabled in the NVIC whose handlers this firmware does not have. Nothing here relies on a
/// reset value.
fn quiesce(p: &pac::Peripherals, core: &mut cortex_m::Peripherals) {
    // SAFETY (whole function): writes to peripherals this firmware owns, values from the PS and
    // the ARMv7-M ARM; no other code runs yet.
    unsafe {
        core.MPU.ctrl.write(0);
        core.SYST.csr.write(0);
        for i in 0..2 {
            core.NVIC.icer[i].write(u32::MAX);
            core.NVIC.icpr[i].write(u32::MAX);
        }
        // ICSR.PENDSTCLR: no stale SysTick.
        core.SCB.icsr.write(1 << 25);
    }
    cortex_m::asm::dsb();
    cortex_m::asm::isb();

    let u = &p.UARTE0;
    if u.enable.read().bits() != 0 {
        u.events_rxto.write(|w| unsafe { w.bits(0) });
        u.tasks_stoprx.write(|w| unsafe { w.bits(1) });
        u.tasks_stoptx.write(|w| unsafe { w.bits(1) });
        for _ in 0..UARTE_STOP_POLLS {
            if u.events_rxto.read().bits() != 0 {
                break;
            }
        }
    }
    u.intenclr.write(|w| unsafe { w.bits(u32::MAX) });
    u.enable.write(|w| w.enable().disabled());
    // Pins disconnected (PSEL.CONNECT = 1).
    u.psel.txd.write(|w| unsafe { w.bits(u32::MAX) });
    u.psel.rxd.write(|w| unsafe { w.bits(u32::MAX) });
    u.psel.rts.write(|w| unsafe { w.bits(u32::MAX) });
    u.psel.cts.write(|w| unsafe { w.bits(u32::MAX) });

    let r = &p.RTC1;
    r.tasks_stop.write(|w| unsafe { w.bits(1) });
    r.intenclr.write(|w| unsafe { w.bits(u32::MAX) });
    r.evtenclr.write(|w| unsafe { w.bits(u32::MAX) });

    let pwm = &p.PWM0;
    pwm.tasks_stop.write(|w| unsafe { w.bits(1) });
    pwm.enable.write(|w| w.enable().disabled());
    for out in pwm.psel.out.iter() {
        out.write(|w| unsafe { w.bits(u32::MAX) });
    }

    // P1.00 (the I2C pull-ups' enable) is also TRACEDATA0: no trace on the pins.
    p.CLOCK.traceconfig.write(|w| unsafe { w.bits(0) });
}

/// What the UICR and the start of the flash say about the bootloader.
fn flash_map(uicr: &pac::UICR) -> FlashMap {
    let nrffw0 = uicr.nrffw[0].read().bits();
    // SAFETY: aligned reads of mapped flash (0x4: the vector table at 0x0; a bootloader's
    // vector table only where UICR says one starts, inside the 1 MiB flash).
    let word = |a: u32| unsafe { core::ptr::read_volatile(a as *const u32) };
    let bootloader_entry = (nrffw0 < 0x10_0000 && nrffw0.is_multiple_of(4)).then(|| word(nrffw0 + 4));
    FlashMap { nrffw0, nrffw1: uicr.nrffw[1].read().bits(), reset_vector_0: word(4), bootloader_entry }
}

/// Starts the 32 MHz crystal, the time base of every gyro integral, clearing a stale
/// HFCLKSTARTED first (the bootloader may have started it already). Bounded.
fn start_hfxo(clock: &pac::CLOCK) -> bool {
    // SAFETY: CLOCK is ours; event and task registers take 0 / 1.
    clock.events_hfclkstarted.write(|w| unsafe { w.bits(0) });
    clock.tasks_hfclkstart.write(|w| unsafe { w.bits(1) });
    for _ in 0..HFXO_POLLS {
        if clock.events_hfclkstarted.read().bits() != 0 {
            clock.events_hfclkstarted.write(|w| unsafe { w.bits(0) });
            let stat = clock.hfclkstat.read();
            return stat.src().is_xtal() && stat.state().is_running();
        }
    }
    false
}

/// Longest log line (B): the full `K` line is ~330 B; a longer one is cut.
const LINE: usize = 640;
/// Longest export text (B): the C snippet is ~1.3 KiB.
const EXPORT: usize = 2048;

/// Every log line after boot: over RTT (defmt) and, while a terminal has the USB port open,
/// over USB serial, with the same text (`calib_core::text`).
struct Console {
    usb: Option<&'static mut Usb>,
    /// The USBD until USB starts (VBUS present and the USBD ready).
    usbd: Option<pac::USBD>,
    next_usb_try: f64,
    usb_dropped_reported: u32,
}

// The methods are `#[inline(never)]`: inlined at each call site they cost 1.5 KiB of flash.
impl Console {
    /// Formats and sends a line.
    #[inline(never)]
    fn say(&mut self, level: Log, args: fmt::Arguments) {
        let mut line = heapless::String::<LINE>::new();
        // A line longer than LINE is sent cut.
        let _ = line.write_fmt(args);
        self.send(level, &line);
    }

    /// Sends a line.
    #[inline(never)]
    fn send(&mut self, level: Log, line: &str) {
        match level {
            Log::Info => defmt::info!("{=str}", line),
            Log::Warn => defmt::warn!("{=str}", line),
            Log::Error => defmt::error!("{=str}", line),
        }
        if let Some(u) = self.usb.as_mut() {
            u.line(line);
        }
    }

    /// Sends a line of the raw log (a CSV row, its header or its end marker): printed without
    /// a level, so that the message text alone is a log `calib` reads.
    #[inline(never)]
    fn raw(&mut self, line: &str) {
        defmt::println!("{=str}", line);
        if let Some(u) = self.usb.as_mut() {
            u.line(line);
        }
    }

    /// Sends a multi-line text (export snippets) line by line.
    #[inline(never)]
    fn lines(&mut self, text: &str) {
        text.lines().for_each(|l| self.send(Log::Info, l));
    }

    #[inline(never)]
    fn report(&mut self, r: &Report) {
        let mut line = heapless::String::<LINE>::new();
        let _ = calib_core::text::report(&mut line, r);
        self.send(calib_core::text::level(r), &line);
        if let Report::Done(rec) = r {
            self.export(rec, Format::Json);
        }
    }

    /// Sends a record in an export format.
    #[inline(never)]
    fn export(&mut self, rec: &Record, format: Format) {
        let mut text = heapless::String::<EXPORT>::new();
        match calib_core::export::write(&mut text, rec, format) {
            Ok(()) => self.lines(&text),
            Err(_) => self.send(Log::Error, "export did not fit its buffer"),
        }
    }

    /// The stored calibration (`s`): its line, the JSON line, the C snippet.
    #[inline(never)]
    fn stored(&mut self, rec: Option<&Record>) {
        let Some(rec) = rec else {
            return self.send(Log::Info, "no calibration stored");
        };
        let mut line = heapless::String::<LINE>::new();
        let _ = calib_core::text::record(&mut line, "stored", rec);
        self.send(Log::Info, &line);
        self.export(rec, Format::Json);
        self.export(rec, Format::C);
    }

    /// Starts USB once VBUS is present (retried every second), serves it every tick, and says
    /// once a second how many bytes a terminal that stopped reading missed.
    #[inline(never)]
    fn poll_usb(&mut self, power: &pac::POWER, now: f64, commands: &mut heapless::Vec<Command, COMMANDS_PER_TICK>) {
        if self.usb.is_none() && now >= self.next_usb_try {
            if let Some(usbd) = self.usbd.take() {
                match Usb::start(usbd, power) {
                    Ok(u) => {
                        self.usb = Some(u);
                        self.say(Log::Info, format_args!("USB: started (CDC-ACM serial; type h for help)"));
                    }
                    Err((e, usbd)) => {
                        if e == UsbError::NotReady {
                            defmt::warn!("USB: VBUS present but the USBD did not become ready; retrying");
                        }
                        self.usbd = Some(usbd);
                        self.next_usb_try = now + 1.0;
                    }
                }
            }
        }
        if let Some(u) = self.usb.as_mut() {
            let mut refused = 0u32;
            u.poll(power, now, |c| {
                if commands.push(c).is_err() {
                    refused += 1;
                }
            });
            if refused > 0 {
                self.say(Log::Warn, format_args!("USB: {refused} command(s) ignored: more than {} in one tick", COMMANDS_PER_TICK));
            }
            let Some(u) = self.usb.as_mut() else { return };
            let dropped = u.out.dropped();
            if dropped != self.usb_dropped_reported && u.out.is_empty() && u.listening() {
                self.usb_dropped_reported = dropped;
                self.say(Log::Warn, format_args!("USB: {dropped} bytes dropped since boot (the host was not reading)"));
            }
        }
    }
}

impl Console {
    #[inline(never)]
    fn sensor_error(&mut self, e: &SensorError) {
        match e {
            SensorError::Rev2Bmi270 => self.say(
                Log::Error,
                format_args!("{e}: BMI270 found at 0x68: this is a Nano 33 BLE Rev2, which has no LSM9DS1; not supported"),
            ),
            SensorError::Missing => self.say(
                Log::Error,
                format_args!("{e}: no LSM9DS1 at 0x6B: check sensor power (P0.22), I2C pull-ups (P1.00) and the board revision"),
            ),
            other => self.say(Log::Error, format_args!("LSM9DS1 error: {other}")),
        }
    }

    /// Raw-log mode (a long press or `r` toggles it): every sample as a row of
    /// `calib_core::log` after its header line; the end marker when it is switched off. The
    /// other log lines in between are not rows (`calib` skips and counts them), so the message
    /// text alone (`probe-rs run --log-format "{s}"`, or what the USB port sends) is a log
    /// `calib` reads.
    #[inline(never)]
    fn set_raw_log(&mut self, on: bool) {
        self.raw(if on { calib_core::log::HEADER } else { calib_core::log::END });
    }

    #[inline(never)]
    fn raw_row(&mut self, s: &Sample, servo_deg: Option<f32>, tilt_deg: Option<f32>) {
        let row = calib_core::log::Row { t_s: s.t_s, accel_g: s.accel_g, gyro_dps: s.gyro_dps, servo_deg, tilt_deg };
        let mut line = heapless::String::<{ calib_core::log::MAX_ROW }>::new();
        if calib_core::log::write_row(&mut line, &row).is_ok() {
            self.raw(&line);
        }
    }
}

/// The outputs the procedure drives: servo PWM, LEDs, the record storage, the applied
/// calibration, the log.
struct Io {
    pwm: Pwm<pac::PWM0>,
    storage: Option<Storage<hal::nvmc::Nvmc<pac::NVMC>>>,
    led: Led,
    applied: Option<Record>,
    console: Console,
}

fn channel(ch: u8) -> Channel {
    if ch == 0 {
        Channel::C0
    } else {
        Channel::C1
    }
}

impl Shell for Io {
    fn servo(&mut self, ch: u8, pulse_us: u16) {
        self.pwm.set_duty_off(channel(ch), CONFIG.clamp_pulse(pulse_us as f32));
    }

    fn servo_off(&mut self, ch: u8) {
        self.pwm.set_duty_off(channel(ch), 0);
    }

    fn led(&mut self, led: Led) {
        self.led = led;
    }

    #[inline(never)]
    fn report(&mut self, report: &Report) {
        self.console.report(report);
    }

    fn store(&mut self, rec: &Record) -> Result<(), StoreError> {
        let slot = self.storage.as_mut().ok_or(StoreError::Unavailable)?.store(rec)?;
        self.console.say(Log::Info, format_args!("record {} stored in slot {slot} and verified", rec.seq));
        Ok(())
    }

    fn apply(&mut self, rec: &Record) {
        self.applied = Some(*rec);
    }
}

#[cortex_m_rt::entry]
fn main() -> ! {
    let (Some(p), Some(mut core)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
        cortex_m::peripheral::SCB::sys_reset();
    };
    quiesce(&p, &mut core);
    let reset_reason = p.POWER.resetreas.read().bits();
    // SAFETY: RESETREAS bits are cleared by writing 1.
    p.POWER.resetreas.write(|w| unsafe { w.bits(reset_reason) });
    defmt::info!("gyrocal-fw {=str}; reset reason 0x{=u32:08X}", env!("CARGO_PKG_VERSION"), reset_reason);
    if !start_hfxo(&p.CLOCK) {
        defmt::error!("the 32 MHz crystal did not start: gyro integrals would be timed by the RC oscillator (1.5 %); resetting");
        cortex_m::peripheral::SCB::sys_reset();
    }

    let mut wd = match wdt::Watchdog::try_new(p.WDT) {
        Ok(mut w) => {
            w.set_lfosc_ticks(WATCHDOG_S * 32_768);
            w.activate::<wdt::count::One>().handles.0
        }
        // Already running after a soft reset: recover its handle.
        Err(w) => match wdt::Watchdog::try_recover::<wdt::count::One>(w) {
            Ok(parts) => parts.handles.0,
            Err(_) => {
                defmt::error!("watchdog in an unknown state; rebooting");
                cortex_m::peripheral::SCB::sys_reset();
            }
        },
    };

    let mut clock = Clock::start(p.TIMER1);
    let mut tick = Timer::periodic(p.TIMER2);
    tick.enable_interrupt();
    tick.start(TICK_US);
    // SAFETY: the handler only clears its event; no shared state.
    unsafe { NVIC::unmask(pac::Interrupt::TIMER2) };
    core.SCB.clear_sleepdeep();

    let p0 = hal::gpio::p0::Parts::new(p.P0);
    let p1 = hal::gpio::p1::Parts::new(p.P1);
    let mut leds = Leds {
        d13: p0.p0_13.into_push_pull_output(Level::Low).degrade(),
        red: p0.p0_24.into_push_pull_output(Level::High).degrade(),
        green: p0.p0_16.into_push_pull_output(Level::High).degrade(),
        blue: p0.p0_06.into_push_pull_output(Level::High).degrade(),
    };
    let mut button_pin = p1.p1_11.into_pullup_input();

    // Sensor power (high drive, as Arduino's core does, against a voltage drop on the sensor
    // rail), then (after ~10 ms) the I2C pull-ups: the IMU does not answer before both.
    let _vdd_env = p0.p0_22.into_push_pull_output_drive(Level::High, DriveConfig::HighDrive0HighDrive1);
    let t0 = clock.now_us();
    while clock.now_us() - t0 < 10_000 {}
    let _pullups = p1.p1_00.into_push_pull_output(Level::High);
    let t0 = clock.now_us();
    while clock.now_us() - t0 < 5_000 {}

    let pins = twim::Pins { scl: p0.p0_15.into_floating_input().degrade(), sda: p0.p0_14.into_floating_input().degrade() };
    let mut bus = Some(Bus(Twim::new(p.TWIM0, pins, twim::Frequency::K400)));
    // SAFETY: a plain register write to the TWIM we own, before any transfer.
    unsafe { (*pac::TWIM0::ptr()).frequency.write(|w| w.bits(TWIM_FREQUENCY_390K)) };
    let sensor_cfg = SENSOR;
    let mut sensor: Option<Lsm9ds1<Bus>> = None;

    // Servo PWM: 1 MHz, 20 ms period; duty 0 = no pulse until the procedure commands one.
    let pwm = Pwm::new(p.PWM0);
    pwm.set_prescaler(Prescaler::Div16)
        .set_max_duty(PWM_TOP)
        .set_output_pin(Channel::C0, p0.p0_27.into_push_pull_output(Level::Low).degrade())
        .set_output_pin(Channel::C1, p1.p1_02.into_push_pull_output(Level::Low).degrade());
    // nRF PWM sequence values: bit 15 set = falling edge first = HIGH for `duty` ticks from the
    // start of the period. nrf-hal's `set_duty_off` sets bit 15 (`set_duty_on` would invert).
    pwm.set_duty_off(Channel::C0, 0);
    pwm.set_duty_off(Channel::C1, 0);

    // Calibration records in the reserved flash region (never the bootloader).
    extern "C" {
        static mut __storage_start: u8;
        static __storage_end: u8;
    }
    // SAFETY: the linker reserves this region for us alone; nothing else aliases it.
    let region: &'static mut [u8] = unsafe {
        let start = core::ptr::addr_of_mut!(__storage_start);
        let len = core::ptr::addr_of!(__storage_end) as usize - start as usize;
        core::slice::from_raw_parts_mut(start, len)
    };
    let map = flash_map(&p.UICR);
    let bootloader = map.bootloader();
    defmt::info!("bootloader: {}", bootloader);
    let mut storage = match map.records_safe() {
        Ok(()) => Storage::new(hal::nvmc::Nvmc::new(p.NVMC, region)).ok(),
        Err(c) => {
            defmt::error!(
                "calibration records disabled: the pages at 0xF8000 may belong to the bootloader ({}); nothing will be written",
                c
            );
            None
        }
    };
    let mut console = Console { usb: None, usbd: Some(p.USBD), next_usb_try: 0.0, usb_dropped_reported: 0 };
    let mut applied: Option<Record> = None;
    match storage.as_mut().map(|s| s.load()) {
        Some(Ok(Some((slot, rec)))) => {
            let mut line = heapless::String::<LINE>::new();
            let _ = calib_core::text::record(&mut line, "loaded", &rec);
            console.send(Log::Info, &line);
            console.say(Log::Info, format_args!("record read from slot {slot}; applied"));
            applied = Some(rec);
        }
        Some(Ok(None)) => console.send(Log::Warn, "no calibration stored: raw gyro readings until the button is pressed"),
        _ => console.send(Log::Error, "calibration storage unreadable"),
    }

    let procedure = procedure(applied);
    let mut io = Io { pwm, storage, led: Led::Idle, applied, console };
    let mut button = Button::new();
    let mut stamper = Stamper::new(sensor_cfg.odr.hz());
    let (mut raw_mode, mut last_poll, mut last_rate_line, mut next_sensor_try) = (false, 0.0f64, 0.0f64, 0.0f64);
    let (mut last_drop_check, mut dropped_reported) = (0.0f64, 0u32);
    let mut rate = calib_core::stats::Welford3::new();

    loop {
        wd.pet();
        let now = clock.now_s();

        // Sensor: (re)initialise until it answers, then drain its FIFO every 10 ms.
        if sensor.is_none() && now >= next_sensor_try {
            if let Some(i2c) = bus.take() {
                match Lsm9ds1::init(i2c, sensor_cfg, &mut Wait(&mut clock)) {
                    Ok(s) => {
                        let c = sensor_cfg;
                        io.console.say(
                            Log::Info,
                            format_args!(
                                "LSM9DS1 ready: {} Hz, +-{} dps, +-{} g",
                                c.odr.hz() as u32,
                                c.gyro.range_dps() as u32,
                                c.accel.range_g() as u32
                            ),
                        );
                        stamper.restart();
                        sensor = Some(s);
                    }
                    Err((e, i2c)) => {
                        io.console.sensor_error(&e);
                        io.led = Led::Error(ErrorClass::Sensor);
                        bus = Some(i2c);
                        next_sensor_try = now + 2.0;
                    }
                }
            }
        }
        if now - last_poll >= FIFO_POLL_S {
            last_poll = now;
            if let Some(s) = sensor.as_mut() {
                let result = s.fifo_status().and_then(|st| {
                    if st.overrun {
                        io.console.send(Log::Warn, "FIFO overrun: samples lost");
                        stamper.restart();
                        // At least one sample overwritten: a running calibration fails (named).
                        procedure.handle_samples_lost(1);
                        procedure.drive(now, &mut io);
                    }
                    let n = st.level.min(FIFO_DEPTH) as usize;
                    let batch = stamper.batch(clock.now_s(), n);
                    // One reading per batch; a failed one leaves the samples without it.
                    let temp_c = s.temperature_c().ok();
                    for i in 0..n {
                        let raw = s.read_slot()?;
                        let (accel_g, gyro_dps) = s.convert(&raw);
                        let sample = Sample { t_s: batch.stamp(i), accel_g, gyro_dps, temp_c };
                        if raw_mode {
                            io.console.raw_row(&sample, procedure.servo_deg(), procedure.tilt_deg());
                        }
                        if let Some(rec) = io.applied {
                            rate.add(rec.apply_gyro(gyro_dps));
                        }
                        procedure.handle_sample(&sample);
                        procedure.drive(sample.t_s, &mut io);
                    }
                    Ok(())
                });
                if let Err(e) = result {
                    io.console.say(Log::Error, format_args!("LSM9DS1 read failed: {e}; reinitialising"));
                    procedure.handle_sensor_fault();
                    procedure.drive(now, &mut io);
                    bus = sensor.take().map(|s| s.release());
                    next_sensor_try = now + 0.5;
                }
            }
        }

        let mut commands = heapless::Vec::<Command, COMMANDS_PER_TICK>::new();
        io.console.poll_usb(&p.POWER, now, &mut commands);
        let pressed = match button.update(now, button_pin.is_low().unwrap_or(false)) {
            Some(Press::Short) => Some(Command::Calibrate),
            Some(Press::Long) => Some(Command::RawLog),
            None => None,
        };
        // The button goes first: a full tick of USB commands never hides a press.
        if let Some(c) = pressed {
            if commands.insert(0, c).is_err() {
                commands.pop();
                let _ = commands.insert(0, c);
                io.console.send(Log::Warn, "USB: a command ignored: the button press came in the same tick");
            }
        }
        for c in commands {
            match c {
                Command::Calibrate => {
                    if matches!(procedure.phase(), Phase::Idle | Phase::Done | Phase::Failed) {
                        let (rig, hand) = procedure.plan();
                        let mut line = heapless::String::<LINE>::new();
                        let _ = calib_core::text::plan(&mut line, rig as usize, hand as usize);
                        io.console.send(Log::Info, &line);
                    }
                    procedure.handle_button(now);
                }
                Command::RawLog => {
                    raw_mode = !raw_mode;
                    io.console.set_raw_log(raw_mode);
                }
                Command::Stored => io.console.stored(io.applied.as_ref()),
                Command::Help => serial::HELP.iter().for_each(|l| io.console.send(Log::Info, l)),
            }
        }
        procedure.drive(now, &mut io);
        procedure.handle_tick(now);
        procedure.drive(now, &mut io);

        // After calibration: the calibrated rate, averaged, once a second.
        if io.applied.is_some() && now - last_rate_line >= 1.0 && rate.count() > 0 && !raw_mode {
            let m = rate.mean();
            io.console.say(Log::Info, format_args!("rate {} dps (calibrated, 1 s mean)", V3(m.map(|v| v as f32), 3)));
            rate = calib_core::stats::Welford3::new();
            last_rate_line = now;
        }

        // Log bytes lost while no host read RTT: said once the host reads again.
        if now - last_drop_check >= 1.0 {
            last_drop_check = now;
            let dropped = gyrocal_fw::rtt::dropped_bytes();
            if dropped != dropped_reported {
                io.console.say(Log::Warn, format_args!("RTT: {dropped} log bytes dropped since boot (no host was reading)"));
                dropped_reported = dropped;
            }
        }

        leds.show(render(io.led, clock.now_us() / 1000));
        cortex_m::asm::wfi();
    }
}
