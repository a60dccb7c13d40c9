//! The console (part of the firmware binary, not of the library): every log line after boot,
//! to RTT (defmt) and to the USB serial port, and the USB commands.

use super::COMMANDS_PER_TICK;
use calib_core::formats::export::Format;
use calib_core::formats::protocol::{self, Ignored, RecordLine};
use calib_core::formats::record::{Record, SensorSetup};
use calib_core::formats::text::Level as Log;
use calib_core::procedure::{Report, Sample};
use calib_core::Time;
use core::fmt::{self, Write};
use gyrocal_fw::lsm9ds1::SensorError;
use gyrocal_fw::serial::Command;
use gyrocal_fw::usb::{self, Link, Step, Usb};
use hal::pac;
use nrf52840_hal as hal;

/// Longest log line (B): the full `K` line is ~330 B; a longer one is cut.
pub(crate) const LINE: usize = 640;
/// Longest JSON line of a record (B, on the stack while it is sent): one with the magnetometer
/// is ~1.3 KiB.
pub(crate) const EXPORT: usize = 2048;

/// Every log line after boot: over RTT (defmt) and, while a terminal has the USB port open,
/// over USB serial, with the same text (`calib_core::formats::text`).
pub(crate) struct Console {
    /// The port, built at the first start.
    usb: Option<&'static mut Usb>,
    /// The USBD until the first start.
    usbd: Option<pac::USBD>,
    /// Where the USBD is in its start and stop.
    link: Link,
    /// The USB serial number (from FICR).
    serial: &'static str,
    usb_dropped_reported: u32,
    /// When the dropped bytes were last reported.
    usb_dropped_at: Time,
    /// Commands not carried out since boot, the counts last logged, and when.
    ignored: Ignored,
    ignored_reported: Ignored,
    ignored_at: Time,
}

// The methods are `#[inline(never)]`: inlined at each call site they cost 1.5 KiB of flash.
impl Console {
    /// No USB yet: it starts once VBUS is present.
    pub(crate) fn new(usbd: pac::USBD, ficr: &pac::FICR) -> Self {
        let serial = usb::serial_number(ficr);
        Self {
            usb: None,
            usbd: Some(usbd),
            link: Link::new(),
            serial,
            usb_dropped_reported: 0,
            usb_dropped_at: Time::MIN,
            ignored: Ignored::default(),
            ignored_reported: Ignored::default(),
            ignored_at: Time::MIN,
        }
    }

    /// The port while its link is up.
    fn port(&mut self) -> Option<&mut Usb> {
        match self.link {
            Link::Up => self.usb.as_deref_mut(),
            _ => None,
        }
    }
}

impl Console {
    /// Formats and sends a line.
    #[inline(never)]
    pub(crate) fn say(&mut self, level: Log, args: fmt::Arguments) {
        let mut line = heapless::String::<LINE>::new();
        // A line longer than LINE is sent cut.
        let _ = line.write_fmt(args);
        self.send(level, &line);
    }

    /// Sends a line.
    #[inline(never)]
    pub(crate) fn send(&mut self, level: Log, line: &str) {
        match level {
            Log::Info => defmt::info!("{=str}", line),
            Log::Warn => defmt::warn!("{=str}", line),
            Log::Error => defmt::error!("{=str}", line),
        }
        if let Some(u) = self.port() {
            u.line(line);
        }
    }

    /// Sends a line of the raw log (a CSV row, its header or its end marker): printed without
    /// a level, so that the message text alone is a log `calib` reads.
    #[inline(never)]
    pub(crate) fn raw(&mut self, line: &str) {
        defmt::println!("{=str}", line);
        if let Some(u) = self.port() {
            u.line(line);
        }
    }

    #[inline(never)]
    pub(crate) fn report(&mut self, r: &Report) {
        let mut line = heapless::String::<LINE>::new();
        let _ = calib_core::formats::text::report(&mut line, r);
        self.send(calib_core::formats::text::level(r), &line);
        if let Report::Done(rec) = r {
            self.json(rec);
        }
    }

    /// Sends a record's JSON line (`gyrocal-calib`'s schema).
    #[inline(never)]
    pub(crate) fn json(&mut self, rec: &Record) {
        let mut text = heapless::String::<EXPORT>::new();
        match calib_core::formats::export::write(&mut text, rec, Format::Json) {
            Ok(()) => self.send(Log::Info, &text),
            Err(_) => self.send(Log::Error, "the JSON line did not fit its buffer"),
        }
    }

    /// `c` presses that did nothing: a calibration was running.
    pub(crate) fn ignored_running(&mut self, n: u32) {
        self.ignored.running += n;
    }

    /// A command that did not fit in this tick (the button's press took its place).
    pub(crate) fn ignored_beyond_tick(&mut self, n: u32) {
        self.ignored.beyond_tick += n;
    }

    /// Logs the commands ignored since boot when they changed, at most once a second, until a
    /// line of them reached the RTT buffer whole (a frame the full buffer dropped is said again).
    #[inline(never)]
    pub(crate) fn report_ignored(&mut self, now: Time) {
        if self.ignored == self.ignored_reported || now.since(self.ignored_at) < 1.0 {
            return;
        }
        let mut line = heapless::String::<LINE>::new();
        let _ = protocol::ignored(&mut line, self.ignored, COMMANDS_PER_TICK as u32);
        let dropped = gyrocal_fw::rtt::dropped_bytes();
        self.send(Log::Warn, &line);
        if gyrocal_fw::rtt::dropped_bytes() == dropped {
            self.ignored_reported = self.ignored;
        }
        self.ignored_at = now;
    }

    /// The stored calibration (`s`): its line and the JSON line. (C and Rust come from the PC,
    /// `gyrocal-calib --port … --export c`, from this very line; a sketch loads the record itself.)
    #[inline(never)]
    pub(crate) fn stored(&mut self, rec: Option<&Record>) {
        let Some(rec) = rec else {
            return self.send(Log::Info, protocol::NO_RECORD);
        };
        let mut line = heapless::String::<LINE>::new();
        let _ = protocol::record(&mut line, RecordLine::Stored, rec);
        self.send(Log::Info, &line);
        self.json(rec);
    }

    /// Starts and stops USB with VBUS ([`Link`]), serves it every tick, enters the bootloader
    /// on the 1200-baud touch, and says (at most once a second) how many bytes a terminal that
    /// stopped reading missed.
    #[inline(never)]
    pub(crate) fn poll_usb(&mut self, power: &pac::POWER, now: Time, commands: &mut heapless::Vec<Command, COMMANDS_PER_TICK>) {
        match self.link.handle_tick(now, power) {
            Step::Ready => {
                match (self.usb.as_mut(), self.usbd.take()) {
                    (Some(u), _) => u.reconnect(),
                    (None, Some(usbd)) => self.usb = Some(Usb::build(usbd, self.serial)),
                    (None, None) => {}
                }
                self.send(Log::Info, protocol::USB_STARTED);
            }
            Step::Failed(e) => self.say(Log::Error, format_args!("{e}")),
            Step::Stopped => {
                if let Some(u) = self.usb.as_mut() {
                    u.stopped();
                }
                self.send(Log::Warn, "USB: VBUS gone: the USB port is off until VBUS returns");
            }
            Step::Idle => {}
        }
        let Some(u) = self.port() else { return };
        let mut refused = 0u32;
        let touch = u.poll(now, |c| {
            if commands.push(c).is_err() {
                refused += 1;
            }
        });
        if touch {
            defmt::info!("USB: 1200-baud touch: entering the bootloader (System OFF, wake at once)");
            usb::enter_bootloader(power);
        }
        self.ignored.beyond_tick += refused;
        let Some(u) = self.port() else { return };
        let (dropped, idle) = (u.out.dropped(), u.out.is_empty() && u.listening());
        if dropped != self.usb_dropped_reported && idle && now.since(self.usb_dropped_at) >= 1.0 {
            self.usb_dropped_reported = dropped;
            self.usb_dropped_at = now;
            let mut line = heapless::String::<LINE>::new();
            let _ = protocol::usb_dropped(&mut line, dropped);
            self.send(Log::Warn, &line);
        }
    }
}

impl Console {
    #[inline(never)]
    pub(crate) fn sensor_error(&mut self, e: &SensorError) {
        // (A Rev2's BMI270 never comes here: the caller starts its driver.)
        match e {
            SensorError::Missing => self.say(
                Log::Error,
                format_args!("{e}: no LSM9DS1 at 0x6B: check sensor power (P0.22), I2C pull-ups (P1.00) and the board revision"),
            ),
            other => self.say(Log::Error, format_args!("LSM9DS1 error: {other}")),
        }
    }

    /// Raw-log mode (a long press or `r` toggles it): every sample as a row of
    /// `calib_core::formats::log` after its header line and the setup comment; the end marker when it is
    /// switched off. The other log lines in between are not rows (`calib` skips and counts them),
    /// so the message text alone (`probe-rs run --log-format "{s}"`, or what the USB port sends)
    /// is a log `calib` reads.
    #[inline(never)]
    pub(crate) fn set_raw_log(&mut self, on: bool, setup: &SensorSetup) {
        self.raw(protocol::raw_log(on));
        if on {
            self.raw_setup(setup);
        }
    }

    /// The raw log's setup comment ([`calib_core::formats::log::write_setup`]).
    pub(crate) fn raw_setup(&mut self, setup: &SensorSetup) {
        let mut line = heapless::String::<{ calib_core::formats::log::MAX_ROW }>::new();
        if calib_core::formats::log::write_setup(&mut line, setup).is_ok() {
            self.raw(&line);
        }
    }

    #[inline(never)]
    pub(crate) fn raw_row(&mut self, s: &Sample, mag_ut: Option<[f32; 3]>, servo_deg: Option<f32>, tilt_deg: Option<f32>) {
        use calib_core::formats::log::{write_mag, write_row, write_temp, Row, MAX_ROW};
        let row = Row { t: s.t, accel_g: s.accel_g, gyro_dps: s.gyro_dps, servo_deg, tilt_deg, mag_ut, temp_c: s.temp_c };
        let mut line = heapless::String::<MAX_ROW>::new();
        if write_row(&mut line, &row).and_then(|_| write_mag(&mut line, mag_ut)).and_then(|_| write_temp(&mut line, s.temp_c)).is_ok() {
            self.raw(&line);
        }
    }
}
