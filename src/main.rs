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

mod console;
mod mag;

use console::{Console, LINE};
use gyrocal_fw::board::{self, flash_map, quiesce, start_hfxo, Bus, Clock, Leds, Wait};

use calib_core::estimators::mag::heading_deg;
use calib_core::formats::protocol::{self, RecordLine};
use calib_core::formats::record::{Record, SensorSetup};
use calib_core::formats::text::{Fixed, Int, Level as Log, Text, V3};
use calib_core::math::stats::Moments3;
use calib_core::math::vec3::to_real;
use calib_core::procedure::{Config, ErrorClass, Led, Phase, Procedure, Report, Running, Sample, Shell};
use calib_core::Time;
use core::mem::MaybeUninit;
use embedded_hal::digital::InputPin;
use gyrocal_fw::bmi270::{self, Bmi270};
use gyrocal_fw::button::{Button, Press};
use gyrocal_fw::led::render;
use gyrocal_fw::lsm9ds1::{Lsm9ds1, Odr, RawSample, SensorConfig, SensorError, FIFO_DEPTH};
use gyrocal_fw::serial::{self, Command};
use gyrocal_fw::stamp::Stamper;
use gyrocal_fw::storage::{Storage, StoreError};
use hal::gpio::Level;
use hal::pac::{self, interrupt};
use hal::pwm::{Channel, Prescaler, Pwm};
use mag::Magnetometer;
use nrf52840_hal as hal;
use panic_probe as _;

/// Loop period (µs): the FIFO (32 slots) lasts 33 ms at 952 Hz.
const TICK_US: u32 = 2_000;
/// Commands (button, USB) one main-loop tick takes; more are reported as ignored, never dropped
/// silently.
const COMMANDS_PER_TICK: usize = 8;
/// FIFO read period (s).
const FIFO_POLL_S: f32 = 0.010;
/// Watchdog timeout (s).
const WATCHDOG_S: u32 = 2;
/// Servo PWM: 1 µs ticks, 20 ms period.
const PWM_TOP: u16 = 20_000;
/// A servo pulse change waits until the PWM period in progress is this far along (µs): nrf-hal's
/// `set_duty_off` restarts the period (SEQSTART), so a restart earlier would hand the servo a
/// frame shorter than 16 ms or stretch the pulse it is outputting (≤ 2.5 ms).
const SERVO_UPDATE_FROM_US: u32 = 16_000;
/// … and no later than this (µs): a margin before the next period's rising edge.
const SERVO_UPDATE_UNTIL_US: u32 = PWM_TOP as u32 - 500;
/// Whole PWM periods (µs) by which [`Io::flush_servos`] moves the period's start on.
const PWM_WHOLE_US: u64 = 50 * PWM_TOP as u64;

/// This firmware's own sensor settings: 119 Hz (952 Hz with `--features odr952`), ±500 °/s, ±2 g.
const OWN: SensorConfig = SensorConfig { odr: if cfg!(feature = "odr952") { Odr::Hz952 } else { Odr::Hz119 }, ..SensorConfig::DEFAULT };
/// The settings at boot: [`OWN`], or Arduino_LSM9DS1's with `--features arduino-lsm9ds1`. The
/// console's `p` switches between the two until reset.
const SENSOR: SensorConfig = if cfg!(feature = "arduino-lsm9ds1") { SensorConfig::ARDUINO_LSM9DS1 } else { OWN };

/// The procedure's configuration: the defaults, or with a pan/tilt bracket (`--features
/// tilt-servo`, the tilt servo on D10) the pan/tilt plan and the full 3×3 `K`; the sensor's ranges.
const CONFIG: Config = Config { setup: SENSOR.setup(), ..if cfg!(feature = "tilt-servo") { Config::PAN_TILT } else { Config::DEFAULT } };

/// The procedure state (poses, moves, queue: ~48 KiB) in static RAM, built once at boot in
/// place: `cortex_m::singleton!` would build it on the stack first (a 49 KiB frame, the boot's
/// peak stack).
#[inline(never)]
fn procedure(stored: Option<Record>) -> &'static mut Procedure {
    static mut STATE: (MaybeUninit<Procedure>, bool) = (MaybeUninit::uninit(), false);
    cortex_m::interrupt::free(|_| {
        // SAFETY: the only access to STATE, once (the flag), inside a critical section.
        let state = unsafe { &mut *core::ptr::addr_of_mut!(STATE) };
        if core::mem::replace(&mut state.1, true) {
            cortex_m::peripheral::SCB::sys_reset();
        }
        Procedure::init(&mut state.0, CONFIG, stored)
    })
}

#[interrupt]
fn TIMER2() {
    board::tick_handled();
}

/// The outputs the procedure drives: servo PWM, LEDs, the record storage, the applied
/// calibration, the log.
struct Io {
    pwm: Pwm<pac::PWM0>,
    /// Servo pulses (µs, 0 = off) waiting for their moment in the PWM period.
    servo_pending: [Option<u16>; 2],
    /// When the PWM period last restarted (µs, MCU clock); None before the first pulse.
    pwm_restart_us: Option<u64>,
    storage: Option<Storage<hal::nvmc::Nvmc<pac::NVMC>>>,
    led: Led,
    /// The newest record (loaded at boot or stored since): applied to the samples only while
    /// the sensor runs at the setup it was made at.
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

impl Io {
    /// Applies a pending servo pulse if the PWM period in progress is in its update window
    /// ([`SERVO_UPDATE_FROM_US`]..[`SERVO_UPDATE_UNTIL_US`]), one channel per period (each call
    /// restarts the period): the servos only ever see whole 16–20 ms frames and whole pulses.
    /// Called every loop tick (2 ms, inside the 3.5 ms window); a change waits ≤ 20 ms.
    fn flush_servos(&mut self, now_us: u64) {
        // The period's start moves on by whole periods (1 s) so that its phase is 32-bit
        // arithmetic (no 64-bit division linked); this runs every ≤ 1 s.
        if let Some(t0) = self.pwm_restart_us.as_mut() {
            if now_us.saturating_sub(*t0) >= PWM_WHOLE_US {
                *t0 += PWM_WHOLE_US;
            }
        }
        let due = self.pwm_restart_us.is_none_or(|t0| {
            let into = (now_us.saturating_sub(t0).min(u32::MAX as u64) as u32) % PWM_TOP as u32;
            (SERVO_UPDATE_FROM_US..SERVO_UPDATE_UNTIL_US).contains(&into)
        });
        if !due {
            return;
        }
        let Some(ch) = self.servo_pending.iter().position(Option::is_some) else { return };
        let pulse = self.servo_pending[ch].take().unwrap_or(0);
        self.pwm.set_duty_off(channel(ch as u8), pulse);
        if pulse > 0 || self.pwm_restart_us.is_some() {
            self.pwm_restart_us = Some(now_us);
        }
    }
}

impl Shell for Io {
    fn servo(&mut self, ch: u8, pulse_us: u16) {
        self.servo_pending[usize::from(ch & 1)] = Some(CONFIG.clamp_pulse(pulse_us as f32));
    }

    fn servo_off(&mut self, ch: u8) {
        self.servo_pending[usize::from(ch & 1)] = Some(0);
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
        self.console.say(Log::Info, format_args!("record {} stored in slot {} and verified", Int(rec.seq.into()), Int(slot as i64)));
        Ok(())
    }

    fn apply(&mut self, rec: &Record) {
        self.applied = Some(*rec);
    }
}

/// The sensor: initialised until it answers (retried every 2 s), then its FIFO drained every
/// 10 ms into the procedure, timestamped by the MCU clock; in raw-log mode every sample also
/// goes out as a CSV row.
struct Sensing {
    bus: Option<Bus>,
    sensor: Option<Lsm9ds1<Bus>>,
    /// A Rev2 board's BMI270, brought up.
    rev2: Option<Bmi270<Bus>>,
    /// The settings the LSM9DS1 runs (or is to run) at.
    config: SensorConfig,
    /// The settings a Rev2's BMI270 runs (or is to run) at.
    bmi: bmi270::Config,
    stamper: Stamper,
    next_try: Time,
    last_poll: Time,
    /// The board's magnetometer.
    mag: Magnetometer,
    /// Raw-log mode.
    raw: bool,
    /// The calibrated rate and heading since the last rate line.
    live: Live,
}

impl Sensing {
    fn new(bus: Option<Bus>) -> Self {
        Self {
            bus,
            sensor: None,
            rev2: None,
            config: SENSOR,
            bmi: bmi270::Config::DEFAULT,
            stamper: Stamper::new(SENSOR.odr.hz()),
            next_try: Time::ZERO,
            last_poll: Time::ZERO,
            mag: Magnetometer::new(),
            raw: false,
            live: Live::default(),
        }
    }

    /// One loop tick at `now`: (re)initialise, or drain the FIFO. A lost sample or a failed
    /// read enters the procedure.
    fn service(&mut self, now: Time, clock: &mut Clock, procedure: &mut Procedure, io: &mut Io) {
        if self.sensor.is_none() && self.rev2.is_none() && now >= self.next_try {
            if let Some(i2c) = self.bus.take() {
                match Lsm9ds1::init(i2c, self.config, &mut Wait(clock)) {
                    Ok(s) => {
                        let (c, mut line) = (self.config, heapless::String::<LINE>::new());
                        let _ = protocol::sensor_ready(&mut line, c.odr.hz() as u32, c.gyro.range_dps() as u32, c.accel.range_g() as u32);
                        io.console.send(Log::Info, &line);
                        if self.raw {
                            io.console.raw_setup(&c.setup());
                        }
                        self.stamper.restart();
                        self.sensor = Some(s);
                        self.say_applied(io);
                    }
                    // A Rev2 board: its BMI270 at its setup (its BMM150 comes up at the first poll).
                    Err((SensorError::Rev2Bmi270, i2c)) => match Bmi270::init(i2c, self.bmi, &mut Wait(clock)) {
                        Ok(s) => {
                            let setup = s.setup();
                            let c = s.config();
                            io.console.say(
                                Log::Info,
                                format_args!(
                                    "Nano 33 BLE Rev2: BMI270 ready (Bosch's configuration loaded): {} Hz, +-{} dps, +-{} g; GYR_CAS {} (not applied), user gain {}",
                                    Int(c.odr.hz() as i64),
                                    Int(c.gyro_range_dps.into()),
                                    Int(c.accel_range_g.into()),
                                    Int(s.gyr_cas().into()),
                                    Text(if s.user_gain() { "on" } else { "off" })
                                ),
                            );
                            // Idle at boot (and after a re-initialisation): refused only mid-run,
                            // which the fault that re-initialised it has ended.
                            let _ = procedure.handle_setup(setup);
                            if self.raw {
                                io.console.raw_setup(&setup);
                            }
                            self.stamper = Stamper::new(setup.odr_hz);
                            self.rev2 = Some(s);
                            self.say_applied(io);
                        }
                        Err((e, i2c)) => {
                            io.console.say(Log::Error, format_args!("Nano 33 BLE Rev2: {e}; retrying"));
                            io.led = Led::Error(ErrorClass::Sensor);
                            self.bus = Some(i2c);
                            self.next_try = now.plus_s(2.0);
                        }
                    },
                    Err((e, i2c)) => {
                        io.console.sensor_error(&e);
                        io.led = Led::Error(ErrorClass::Sensor);
                        self.bus = Some(i2c);
                        self.next_try = now.plus_s(2.0);
                    }
                }
            }
        }
        if now.since(self.last_poll) < FIFO_POLL_S {
            return;
        }
        self.last_poll = now;
        if self.rev2.is_some() {
            return self.service_rev2(now, clock, procedure, io);
        }
        let Some(s) = self.sensor.as_mut() else { return };
        let mag_ut = self.mag.poll(s.bus_mut(), false, now, clock, &mut io.console);
        let (stamper, raw, live, setup) = (&mut self.stamper, self.raw, &mut self.live, self.config.setup());
        // Read until at most one slot is left (at most 4 batches: 32 slots take 8.6 ms at
        // 400 kHz, in which 8 more arrive at 952 Hz, then 2, then 0-1): the tick after the read
        // may run a step of a fit or of the solve (≤ 2 M instructions, 31 ms), and at 952 Hz
        // the FIFO holds 34 ms. A FIFO full at the status read loses a sample unseen if one
        // arrives before the first slot is read (the read clears the overrun flag): it is named
        // as a loss that may have happened.
        let mut result = Ok(0);
        for round in 0..4 {
            let mag_ut = mag_ut.filter(|_| round == 0);
            result = s.fifo_status().and_then(|st| {
                let (n, t_read) = (st.level.min(FIFO_DEPTH) as usize, clock.now());
                let batch = stamper.batch(t_read, n);
                // An overrun, flagged or seen by the samples' count (`Batch::late`: a slot read
                // after it clears the flag).
                let lost = st.overrun || batch.late(t_read, n);
                if lost || st.full {
                    io.console.send(Log::Warn, if lost { "FIFO overrun: samples lost" } else { "FIFO found full: a sample may be lost" });
                    stamper.restart();
                    // At least one sample overwritten: a running calibration fails (named).
                    procedure.handle_samples_lost(1);
                    procedure.drive(now, io);
                }
                // One reading per batch; a failed one leaves the samples without it.
                let temp_c = s.temperature_c().ok();
                // The batch read whole before the procedure sees it: a long call on one of its
                // samples (a pose's end) must not be followed by slot reads, which would clear
                // an overrun flag the next status read is to find.
                let mut slots = [RawSample::default(); FIFO_DEPTH as usize];
                for slot in &mut slots[..n] {
                    *slot = s.read_slot()?;
                }
                for (i, raw_slot) in slots[..n].iter().enumerate() {
                    let (accel_g, gyro_dps) = s.convert(raw_slot);
                    let sample = Sample { t: batch.stamp(i), accel_g, gyro_dps, temp_c };
                    // A new field reading goes with the batch's newest sample (read just before).
                    feed(sample, mag_ut.filter(|_| i + 1 == n), setup, raw, live, procedure, io);
                }
                Ok(n)
            });
            if !matches!(result, Ok(n) if n >= 2) {
                break;
            }
        }
        if let Err(e) = result {
            io.console.say(Log::Error, format_args!("LSM9DS1 read failed: {e}; reinitialising"));
            procedure.handle_sensor_fault();
            procedure.drive(now, io);
            self.reinitialise(now);
        }
    }

    /// The LSM9DS1 released and brought up again from 0.5 s on (its magnetometer with it).
    fn reinitialise(&mut self, now: Time) {
        self.bus = self.sensor.take().map(|s| s.release());
        self.mag.reset();
        self.next_try = now.plus_s(0.5);
    }
}

impl Sensing {
    /// The LSM9DS1's FIFO paused ([`Lsm9ds1::pause_fifo`]); false without one, or if the write
    /// failed (the FIFO then runs on, and an overrun is named as any other).
    fn pause_fifo(&mut self) -> bool {
        self.sensor.as_mut().is_some_and(|s| s.pause_fifo().is_ok())
    }

    /// The FIFO on again after [`Self::pause_fifo`], its timestamps started anew; a failed write
    /// reinitialises the sensor (named).
    fn resume_fifo(&mut self, now: Time, io: &mut Io) {
        let Some(s) = self.sensor.as_mut() else { return };
        self.stamper.restart();
        if let Err(e) = s.resume_fifo() {
            io.console.say(Log::Error, format_args!("LSM9DS1 FIFO not resumed: {e}; reinitialising"));
            self.reinitialise(now);
        }
    }

    /// The setup the sensor runs at (the Rev2's BMI270, or the LSM9DS1's).
    fn setup(&self) -> SensorSetup {
        self.rev2.as_ref().map_or(self.config.setup(), |b| b.setup())
    }

    /// Says when the stored record was made at another setup than the sensor now runs (it is
    /// then not applied).
    fn say_applied(&self, io: &mut Io) {
        if io.applied.is_some_and(|r| r.setup != self.setup()) {
            io.console.send(Log::Warn, "the stored record was made at another sensor setup: not applied");
        }
    }

    /// A Rev2 board's FIFO drained into the procedure (as the LSM9DS1's: timestamps by the MCU
    /// clock, each batch's newest sample dated by the sensortime frame after it, the die
    /// temperature read once a batch; lost samples and failed reads enter the procedure).
    fn service_rev2(&mut self, now: Time, clock: &mut Clock, procedure: &mut Procedure, io: &mut Io) {
        let Some(b) = self.rev2.as_mut() else { return };
        let mag_ut = self.mag.poll(b.bus_mut(), true, now, clock, &mut io.console);
        let mut got = heapless::Vec::<([f32; 3], [f32; 3]), { bmi270::FIFO_BYTES / 13 + 1 }>::new();
        match b.read_fifo(|a, g| {
            let _ = got.push((a, g));
        }) {
            Ok(r) => {
                if r.lost > 0 {
                    io.console.say(Log::Warn, format_args!("BMI270 FIFO: {} samples lost", Int(r.lost as i64)));
                }
                if let Some(n) = r.gyro_started_after {
                    io.console.say(Log::Info, format_args!("BMI270: gyro started after {} accelerometer-only frames", Int(n as i64)));
                }
                if r.partial > 0 {
                    io.console
                        .say(Log::Warn, format_args!("BMI270 FIFO: {} frames held one sensor alone: samples lost", Int(r.partial as i64)));
                }
                let missing = r.lost + r.partial;
                if missing > 0 {
                    self.stamper.restart();
                    procedure.handle_samples_lost(missing.min(u16::MAX as usize) as u16);
                    procedure.drive(now, io);
                }
                // The newest sample's time: the read's, less its age by the part's sensortime;
                // without a date, its samples are counted but do not move the time line.
                let batch = match r.newest_age_us {
                    Some(age) => self.stamper.batch(Time::from_us(clock.now().us() - i64::from(age)), got.len()),
                    None => self.stamper.undated(clock.now(), got.len()),
                };
                // One reading per batch; a failed or invalid one leaves the samples without it.
                let temp_c = if got.is_empty() { None } else { b.temperature_c().ok().flatten() };
                for (i, &(accel_g, gyro_dps)) in got.iter().enumerate() {
                    let sample = Sample { t: batch.stamp(i), accel_g, gyro_dps, temp_c };
                    // A new field reading goes with the batch's newest sample (read just before).
                    feed(sample, mag_ut.filter(|_| i + 1 == got.len()), b.setup(), self.raw, &mut self.live, procedure, io);
                }
            }
            Err(e) => {
                io.console.say(Log::Error, format_args!("{e}; reinitialising"));
                procedure.handle_sensor_fault();
                procedure.drive(now, io);
                self.bus = self.rev2.take().map(|s| s.release());
                self.mag.reset();
                self.next_try = now.plus_s(0.5);
            }
        }
    }

    /// Runs the sensor at `config` (a Rev2's BMI270 at `bmi`) from the next tick on:
    /// re-initialised (its ready line and, in raw-log mode, the log's setup comment say the new
    /// settings).
    fn reconfigure(&mut self, config: SensorConfig, bmi: bmi270::Config, now: Time) {
        (self.config, self.bmi) = (config, bmi);
        self.stamper = Stamper::new(config.odr.hz());
        if let Some(s) = self.sensor.take() {
            self.bus = Some(s.release());
        }
        if let Some(s) = self.rev2.take() {
            self.bus = Some(s.release());
        }
        self.mag.reset();
        self.next_try = now;
    }
}

/// One reading (and the field read with it) into the procedure, as the raw log holds it (a
/// replay of the log sees what the procedure saw); its row in raw-log mode; the calibrated rate
/// (and, with a field, the heading) when the stored record was made at `setup`, the sensor's.
fn feed(sample: Sample, mag_ut: Option<[f32; 3]>, setup: SensorSetup, raw: bool, live: &mut Live, procedure: &mut Procedure, io: &mut Io) {
    let (accel_g, gyro_dps) = calib_core::formats::log::as_logged(sample.accel_g, sample.gyro_dps);
    let sample = Sample { accel_g, gyro_dps, temp_c: calib_core::formats::log::temp_as_logged(sample.temp_c), ..sample };
    let mag_ut = mag_ut.map(calib_core::formats::log::mag_as_logged);
    if raw {
        io.console.raw_row(&sample, mag_ut, procedure.servo_deg(), procedure.tilt_deg());
    }
    if let Some(m) = mag_ut {
        procedure.handle_mag(m);
        procedure.drive(sample.t, io);
    }
    if let Some(rec) = io.applied.filter(|r| r.setup == setup) {
        live.rate.add(rec.apply_gyro(gyro_dps));
        if let (Some(cal), Some(m)) = (rec.mag, mag_ut) {
            live.heading_deg = heading_deg(to_real(rec.accel().apply(accel_g)), to_real(cal.apply(m)));
        }
    }
    procedure.handle_sample(&sample);
    procedure.drive(sample.t, io);
}

/// This tick's commands, the button's first (a full tick of USB commands never hides a press),
/// into the procedure and the console.
fn take_commands(now: Time, pressed: Option<Press>, power: &pac::POWER, procedure: &mut Procedure, io: &mut Io, sensing: &mut Sensing) {
    let mut commands = heapless::Vec::<Command, COMMANDS_PER_TICK>::new();
    io.console.poll_usb(power, now, &mut commands);
    let pressed = match pressed {
        Some(Press::Short) => Some(Command::Calibrate),
        Some(Press::Long) => Some(Command::RawLog),
        None => None,
    };
    // The press goes first; a full tick of USB commands loses its last. (Not `insert(0, ..)`:
    // the only `memmove` in the image, 1.5 KiB of flash.)
    if pressed.is_some() && commands.is_full() {
        commands.pop();
        io.console.ignored_beyond_tick(1);
    }
    let mut ignored = 0u32;
    for c in pressed.into_iter().chain(commands) {
        match c {
            Command::Calibrate => {
                if matches!(procedure.phase(), Phase::Idle | Phase::Done | Phase::Failed) {
                    let (rig, hand) = procedure.plan();
                    let mut line = heapless::String::<LINE>::new();
                    let _ = protocol::plan(&mut line, rig as usize, hand as usize);
                    io.console.send(Log::Info, &line);
                }
                if !procedure.handle_button(now) {
                    ignored += 1;
                }
            }
            Command::RawLog => {
                sensing.raw = !sensing.raw;
                io.console.set_raw_log(sensing.raw, &sensing.setup());
            }
            Command::Setup => {
                let (mut next, mut bmi) = (sensing.config, sensing.bmi);
                let setup = match sensing.rev2.as_ref() {
                    // A Rev2: its BMI270 at this firmware's or Arduino_BMI270_BMM150's settings.
                    Some(b) => {
                        bmi = if bmi == bmi270::Config::ARDUINO { bmi270::Config::DEFAULT } else { bmi270::Config::ARDUINO };
                        bmi.setup(b.setup().sensor)
                    }
                    None => {
                        next = if next == SensorConfig::ARDUINO_LSM9DS1 { OWN } else { SensorConfig::ARDUINO_LSM9DS1 };
                        next.setup()
                    }
                };
                match procedure.handle_setup(setup) {
                    Ok(()) => sensing.reconfigure(next, bmi, now),
                    Err(Running) => io.console.send(Log::Warn, "p: the sensor setup cannot change while a calibration runs"),
                }
            }
            Command::Stored => io.console.stored(io.applied.as_ref()),
            Command::Help => serial::HELP.iter().for_each(|l| io.console.send(Log::Info, l)),
        }
    }
    io.console.ignored_running(ignored);
    io.console.report_ignored(now);
}

/// The calibrated readings the rate line gives: the mean rate (°/s) since the last line and the
/// latest tilt-compensated heading of the board's x axis (°, from magnetic north, clockwise from
/// above; with a stored magnetometer calibration), to point x at north once and see the field's
/// sign right (a field taken negated reads 180° off).
#[derive(Default)]
struct Live {
    rate: Moments3,
    heading_deg: Option<f32>,
}

/// The periodic status lines: the calibrated rate (and heading) once a second, and the RTT bytes
/// dropped while no host read (said once one reads again).
#[derive(Default)]
struct Status {
    last_rate_line: Time,
    last_drop_check: Time,
    dropped_reported: u32,
}

impl Status {
    fn lines(&mut self, now: Time, console: &mut Console, show_rate: bool, live: &mut Live) {
        if show_rate && now.since(self.last_rate_line) >= 1.0 && live.rate.count() > 0 {
            let m = V3(live.rate.mean(), 3);
            match live.heading_deg.take() {
                Some(h) => console
                    .say(Log::Info, format_args!("rate {m} dps (calibrated, 1 s mean); x heads {} deg from magnetic north", Fixed(h, 0))),
                None => console.say(Log::Info, format_args!("rate {m} dps (calibrated, 1 s mean)")),
            }
            live.rate = Moments3::new();
            self.last_rate_line = now;
        }
        if now.since(self.last_drop_check) >= 1.0 {
            self.last_drop_check = now;
            let dropped = gyrocal_fw::rtt::dropped_bytes();
            if dropped != self.dropped_reported {
                console.say(Log::Warn, format_args!("RTT: {} log bytes dropped since boot (no host was reading)", Int(dropped.into())));
                self.dropped_reported = dropped;
            }
        }
    }
}

/// RESETREAS.RESETPIN.
const RESETREAS_RESETPIN: u32 = 1;

#[cortex_m_rt::entry]
fn main() -> ! {
    let (Some(p), Some(mut core)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) else {
        cortex_m::peripheral::SCB::sys_reset();
    };
    quiesce(&p, &mut core);
    let raw_reason = p.POWER.resetreas.read().bits();
    // SAFETY: RESETREAS bits are cleared by writing 1.
    p.POWER.resetreas.write(|w| unsafe { w.bits(raw_reason) });
    // Erratum 136: after a pin reset other RESETREAS bits may be set too; with RESETPIN set,
    // only it is true (nrfx's system_nrf52840.c clears the others).
    let reset_reason = if raw_reason & RESETREAS_RESETPIN != 0 { RESETREAS_RESETPIN } else { raw_reason };
    defmt::info!("gyrocal-fw {=str}; reset reason 0x{=u32:08X}", env!("CARGO_PKG_VERSION"), reset_reason);
    if !start_hfxo(&p.CLOCK) {
        defmt::error!("the 32 MHz crystal did not start: gyro integrals would be timed by the RC oscillator (1.5 %); resetting");
        cortex_m::peripheral::SCB::sys_reset();
    }

    let Some(mut wd) = board::watchdog(p.WDT, WATCHDOG_S) else {
        defmt::error!("watchdog in an unknown state; rebooting");
        cortex_m::peripheral::SCB::sys_reset();
    };

    let mut clock = Clock::start(p.TIMER1);
    let _tick = board::start_tick(p.TIMER2, TICK_US, &mut core);

    let p0 = hal::gpio::p0::Parts::new(p.P0);
    let p1 = hal::gpio::p1::Parts::new(p.P1);
    let mut leds = Leds {
        d13: p0.p0_13.into_push_pull_output(Level::Low).degrade(),
        red: p0.p0_24.into_push_pull_output(Level::High).degrade(),
        green: p0.p0_16.into_push_pull_output(Level::High).degrade(),
        blue: p0.p0_06.into_push_pull_output(Level::High).degrade(),
    };
    let mut button_pin = p1.p1_11.into_pullup_input();

    let mut bus = Some(board::sensor_bus(p0.p0_22, p1.p1_00, p0.p0_15, p0.p0_14, p.TWIM0, &mut clock));

    // Servo PWM: 1 MHz, 20 ms period; duty 0 = no pulse until the procedure commands one.
    let pwm = Pwm::new(p.PWM0);
    pwm.set_prescaler(Prescaler::Div16).set_max_duty(PWM_TOP);
    // nRF PWM sequence values: bit 15 set = falling edge first = HIGH for `duty` ticks from the
    // start of the period. nrf-hal's `set_duty_off` sets bit 15 (`set_duty_on` would invert).
    // Both channels at 0 before the pins are routed: between the two calls the second channel
    // plays its zeroed buffer value (no bit 15: HIGH all period), a glitch on a servo pin.
    pwm.set_duty_off(Channel::C0, 0);
    pwm.set_duty_off(Channel::C1, 0);
    pwm.set_output_pin(Channel::C0, p0.p0_27.into_push_pull_output(Level::Low).degrade())
        .set_output_pin(Channel::C1, p1.p1_02.into_push_pull_output(Level::Low).degrade());

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
    let mut console = Console::new(p.USBD, &p.FICR);
    let mut applied: Option<Record> = None;
    match storage.as_mut().map(|s| s.load()) {
        Some(Ok(Some((slot, rec)))) => {
            let mut line = heapless::String::<LINE>::new();
            let _ = protocol::record(&mut line, RecordLine::Loaded, &rec);
            console.send(Log::Info, &line);
            console.say(Log::Info, format_args!("record read from slot {}; applied at the sensor setup it was made at", Int(slot as i64)));
            applied = Some(rec);
        }
        Some(Ok(None)) => match storage.as_mut().and_then(|s| s.unsupported_version()) {
            Some(v) => console.say(
                Log::Warn,
                format_args!(
                    "unsupported record version {} in flash (made before the board frame): kept, not applied; calibrate again",
                    Int(v.into())
                ),
            ),
            None => console.send(Log::Warn, "no calibration stored: raw gyro readings until the button is pressed"),
        },
        _ => console.send(Log::Error, "calibration storage unreadable"),
    }

    let procedure = procedure(applied);
    let mut io = Io { pwm, servo_pending: [None; 2], pwm_restart_us: None, storage, led: Led::Idle, applied, console };
    let mut button = Button::new();
    let mut sensing = Sensing::new(bus.take());
    let mut status = Status::default();

    loop {
        wd.pet();
        let now = clock.now();

        sensing.service(now, &mut clock, procedure, &mut io);
        let pressed = button.update(now, button_pin.is_low().unwrap_or(false));
        take_commands(now, pressed, &p.POWER, procedure, &mut io, &mut sensing);
        procedure.drive(now, &mut io);
        procedure.handle_tick(now);
        // A store's page erase stalls the CPU for up to 85 ms (PS tERASEPAGE), beyond the
        // 952 Hz FIFO's 34 ms: the LSM9DS1's FIFO is paused around it (the calibration is over,
        // the samples of that stretch are not wanted). The BMI270's 6 KB hold 4.7 s.
        let paused = procedure.storing() && sensing.pause_fifo();
        procedure.drive(now, &mut io);
        if paused {
            sensing.resume_fifo(clock.now(), &mut io);
        }
        io.flush_servos(clock.now_us());

        let applied = io.applied.is_some_and(|r| r.setup == sensing.setup());
        status.lines(now, &mut io.console, applied && !sensing.raw, &mut sensing.live);
        leds.show(render(io.led, clock.now_ms()));
        board::sleep();
    }
}
