//! The console (part of the firmware binary, not of the library): every log line after boot,
//! to RTT (defmt) and to the USB serial port, and the USB commands.

use super::COMMANDS_PER_TICK;
use calib_core::export::Format;
use calib_core::procedure::{Report, Sample};
use calib_core::protocol::{self, RecordLine};
use calib_core::record::Record;
use calib_core::text::Level as Log;
use core::fmt::{self, Write};
use gyrocal_fw::lsm9ds1::SensorError;
use gyrocal_fw::serial::Command;
use gyrocal_fw::usb::{Error as UsbError, Usb};
use hal::pac;
use nrf52840_hal as hal;

/// Longest log line (B): the full `K` line is ~330 B; a longer one is cut.
pub(crate) const LINE: usize = 640;
/// Longest export text (B): the C snippet is ~1.3 KiB.
pub(crate) const EXPORT: usize = 2048;

/// Every log line after boot: over RTT (defmt) and, while a terminal has the USB port open,
/// over USB serial, with the same text (`calib_core::text`).
pub(crate) struct Console {
    usb: Option<&'static mut Usb>,
    /// The USBD until USB starts (VBUS present and the USBD ready).
    usbd: Option<pac::USBD>,
    next_usb_try: f64,
    usb_dropped_reported: u32,
}

// The methods are `#[inline(never)]`: inlined at each call site they cost 1.5 KiB of flash.
impl Console {
    /// No USB yet: it starts once VBUS is present and the USBD is ready.
    pub(crate) fn new(usbd: pac::USBD) -> Self {
        Self { usb: None, usbd: Some(usbd), next_usb_try: 0.0, usb_dropped_reported: 0 }
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
        if let Some(u) = self.usb.as_mut() {
            u.line(line);
        }
    }

    /// Sends a line of the raw log (a CSV row, its header or its end marker): printed without
    /// a level, so that the message text alone is a log `calib` reads.
    #[inline(never)]
    pub(crate) fn raw(&mut self, line: &str) {
        defmt::println!("{=str}", line);
        if let Some(u) = self.usb.as_mut() {
            u.line(line);
        }
    }

    /// Sends a multi-line text (export snippets) line by line.
    #[inline(never)]
    pub(crate) fn lines(&mut self, text: &str) {
        text.lines().for_each(|l| self.send(Log::Info, l));
    }

    #[inline(never)]
    pub(crate) fn report(&mut self, r: &Report) {
        let mut line = heapless::String::<LINE>::new();
        let _ = calib_core::text::report(&mut line, r);
        self.send(calib_core::text::level(r), &line);
        if let Report::Done(rec) = r {
            self.export(rec, Format::Json);
        }
    }

    /// Sends a record in an export format.
    #[inline(never)]
    pub(crate) fn export(&mut self, rec: &Record, format: Format) {
        let mut text = heapless::String::<EXPORT>::new();
        match calib_core::export::write(&mut text, rec, format) {
            Ok(()) => self.lines(&text),
            Err(_) => self.send(Log::Error, "export did not fit its buffer"),
        }
    }

    /// The stored calibration (`s`): its line, the JSON line, the C snippet.
    #[inline(never)]
    pub(crate) fn stored(&mut self, rec: Option<&Record>) {
        let Some(rec) = rec else {
            return self.send(Log::Info, protocol::NO_RECORD);
        };
        let mut line = heapless::String::<LINE>::new();
        let _ = protocol::record(&mut line, RecordLine::Stored, rec);
        self.send(Log::Info, &line);
        self.export(rec, Format::Json);
        self.export(rec, Format::C);
    }

    /// Starts USB once VBUS is present (retried every second), serves it every tick, and says
    /// once a second how many bytes a terminal that stopped reading missed.
    #[inline(never)]
    pub(crate) fn poll_usb(&mut self, power: &pac::POWER, now: f64, commands: &mut heapless::Vec<Command, COMMANDS_PER_TICK>) {
        if self.usb.is_none() && now >= self.next_usb_try {
            if let Some(usbd) = self.usbd.take() {
                match Usb::start(usbd, power) {
                    Ok(u) => {
                        self.usb = Some(u);
                        self.send(Log::Info, protocol::USB_STARTED);
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
                let mut line = heapless::String::<LINE>::new();
                let _ = protocol::usb_dropped(&mut line, dropped);
                self.send(Log::Warn, &line);
            }
        }
    }
}

impl Console {
    #[inline(never)]
    pub(crate) fn sensor_error(&mut self, e: &SensorError) {
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
    pub(crate) fn set_raw_log(&mut self, on: bool) {
        self.raw(protocol::raw_log(on));
    }

    #[inline(never)]
    pub(crate) fn raw_row(&mut self, s: &Sample, servo_deg: Option<f32>, tilt_deg: Option<f32>) {
        let row = calib_core::log::Row { t_s: s.t_s, accel_g: s.accel_g, gyro_dps: s.gyro_dps, servo_deg, tilt_deg };
        let mut line = heapless::String::<{ calib_core::log::MAX_ROW }>::new();
        if calib_core::log::write_row(&mut line, &row).is_ok() {
            self.raw(&line);
        }
    }
}
