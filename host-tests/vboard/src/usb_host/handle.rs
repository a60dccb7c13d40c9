//! The host handle: [`UsbHost`], what tests, the testbed and the pty bridge hold (the cable, the
//! host's findings, the serial data, runs of the board until enumerated or idle), and
//! [`usb_board`].

use super::{Cdc, Configuration, DeviceDescriptor, Host};
use crate::mcu::{Mcu, Stop};
use crate::periph::Periph;
use std::cell::RefCell;
use std::rc::Rc;

/// A handle on the board's USB host (shares the board's peripherals; use it between runs).
#[derive(Clone)]
pub struct UsbHost {
    periph: Rc<RefCell<Periph>>,
}

impl UsbHost {
    /// The host of `mcu`'s board.
    pub fn new(mcu: &Mcu) -> Self {
        Self { periph: mcu.periph.clone() }
    }

    /// The host of these peripherals (a board without a CPU, for model tests).
    pub fn from_periph(periph: Rc<RefCell<Periph>>) -> Self {
        Self { periph }
    }

    /// The control requests queued and not yet started, described.
    pub fn queued(&self) -> Vec<String> {
        self.with(|h| h.queued())
    }

    /// Runs `f` on the host state.
    pub fn with<R>(&self, f: impl FnOnce(&mut Host) -> R) -> R {
        f(&mut self.periph.borrow_mut().usb_host)
    }

    /// Plugs the cable in: VBUS on (POWER.USBDETECTED now, USBPWRRDY ~1 ms later).
    pub fn attach(&self) {
        let mut p = self.periph.borrow_mut();
        let t = p.now();
        p.power.plug(t);
    }

    /// Unplugs the cable: VBUS off (POWER.USBREMOVED); the host sees a disconnect.
    pub fn detach(&self) {
        let mut p = self.periph.borrow_mut();
        let t = p.now();
        p.power.unplug(t);
    }

    /// See [`Host::enumerated`].
    pub fn enumerated(&self) -> bool {
        self.with(|h| h.enumerated())
    }

    /// Why the last enumeration failed.
    pub fn error(&self) -> Option<String> {
        self.with(|h| h.error.clone())
    }

    /// Every error so far.
    pub fn errors(&self) -> Vec<String> {
        self.with(|h| h.errors.clone())
    }

    /// The device descriptor as parsed.
    pub fn device_descriptor(&self) -> Option<DeviceDescriptor> {
        self.with(|h| h.device.clone())
    }

    /// The VID:PID of the device on the port: the enumerated one, or the stock bootloader's
    /// stand-in in SAM-BA mode.
    pub fn vid_pid(&self) -> Option<(u16, u16)> {
        self.with(|h| match (&h.stand_in, h.enumerated()) {
            (Some(s), _) => Some(s.0),
            (None, true) => h.device.as_ref().map(|d| (d.vid, d.pid)),
            _ => None,
        })
    }

    /// See [`Host::urb_pending`].
    pub fn urb_pending(&self) -> usize {
        self.with(|h| h.urb_pending())
    }

    /// See [`Host::max_urb_wait_s`].
    pub fn max_urb_wait_s(&self) -> f64 {
        self.with(|h| h.max_urb_wait_s())
    }

    /// Zero-length packets received on bulk IN.
    pub fn zlps(&self) -> u32 {
        self.with(|h| h.zlps)
    }

    /// The configuration descriptor as parsed.
    pub fn configuration(&self) -> Option<Configuration> {
        self.with(|h| h.configuration.clone())
    }

    /// The CDC-ACM function as found.
    pub fn cdc(&self) -> Option<Cdc> {
        self.with(|h| h.cdc)
    }

    /// The string descriptors read: (index, text).
    pub fn strings(&self) -> Vec<(u8, String)> {
        self.with(|h| h.strings.clone())
    }

    /// The product string.
    pub fn product(&self) -> Option<String> {
        self.with(|h| h.product().map(String::from))
    }

    /// The manufacturer string.
    pub fn manufacturer(&self) -> Option<String> {
        self.with(|h| h.manufacturer().map(String::from))
    }

    /// See [`Host::set_line_coding`].
    pub fn set_line_coding(&self, baud: u32) {
        self.with(|h| h.set_line_coding(baud))
    }

    /// See [`Host::set_dtr`].
    pub fn set_dtr(&self, dtr: bool) {
        self.with(|h| h.set_dtr(dtr))
    }

    /// See [`Host::write`].
    pub fn write(&self, data: &[u8]) {
        self.with(|h| h.write(data))
    }

    /// See [`Host::read`].
    pub fn read(&self) -> Vec<u8> {
        self.with(|h| h.read())
    }

    /// See [`Host::set_reading`].
    pub fn set_reading(&self, on: bool) {
        self.with(|h| h.set_reading(on))
    }

    /// The host's log (time-stamped requests and bus events).
    pub fn log(&self) -> Vec<String> {
        self.with(|h| h.log.clone())
    }

    /// Runs `mcu` (the board of this host) until enumerated, for at most `timeout_s` of virtual
    /// time: `Err` with the enumeration error, the emulation stop, or a timeout.
    pub fn wait_enumerated(&self, mcu: &mut Mcu, timeout_s: f64) -> Result<(), String> {
        let end = mcu.now() + timeout_s;
        while mcu.now() < end {
            if self.enumerated() {
                return Ok(());
            }
            if let Some(e) = self.error() {
                return Err(e);
            }
            let t = (mcu.now() + 0.01).min(end);
            match mcu.run_until(t) {
                Stop::Time => {}
                s => return Err(format!("the emulation stopped: {s:?}")),
            }
        }
        if self.enumerated() {
            return Ok(());
        }
        Err(format!(
            "timeout: not enumerated within {timeout_s} s (host log tail: {:?})",
            self.log().iter().rev().take(4).collect::<Vec<_>>()
        ))
    }

    /// Runs `mcu` until the host's queued control requests are done (at most `timeout_s`).
    pub fn wait_idle(&self, mcu: &mut Mcu, timeout_s: f64) -> Result<(), String> {
        let end = mcu.now() + timeout_s;
        while self.with(|h| h.busy()) {
            if mcu.now() >= end {
                return Err(format!("timeout: control requests still pending after {timeout_s} s"));
            }
            match mcu.run_until((mcu.now() + 0.005).min(end)) {
                Stop::Time => {}
                s => return Err(format!("the emulation stopped: {s:?}")),
            }
        }
        Ok(())
    }

    /// Runs `mcu` for `secs` and returns the bytes received meanwhile.
    pub fn run_and_read(&self, mcu: &mut Mcu, secs: f64) -> Result<Vec<u8>, String> {
        let t = mcu.now() + secs;
        match mcu.run_until(t) {
            Stop::Time => Ok(self.read()),
            s => Err(format!("the emulation stopped: {s:?}")),
        }
    }
}

/// The board with the USB cable plugged in from power-on: returns it with its host.
pub fn usb_board(mcu: Mcu) -> (Mcu, UsbHost) {
    let host = UsbHost::new(&mcu);
    host.attach();
    (mcu, host)
}
