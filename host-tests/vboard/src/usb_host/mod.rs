//! A virtual USB host on the board's USB port: a full-speed root port with a Linux-like
//! enumeration and a cdc-acm driver, run on the emulated clock against the USBD model
//! ([`crate::periph::usbd`]).
//!
//! Timeline (virtual time): once the device is connected (VBUS, the USBD enabled with its pull-up
//! on), the host debounces for [`DEBOUNCE_S`], resets the bus for [`RESET_S`] (the device sees
//! EVENTS_USBRESET), waits [`RECOVERY_S`] with SOFs every 1 ms, then enumerates like Linux's hub
//! driver and cdc-acm:
//! 1. GET_DESCRIPTOR(device, wLength 64) at address 0 (EP0 max packet assumed 64), then a second
//!    bus reset;
//! 2. SET_ADDRESS, [`SET_ADDRESS_WAIT_S`];
//! 3. GET_DESCRIPTOR(device, 18); for bcdUSB ≥ 2.01 (usb-device says 2.1) the BOS descriptor
//!    (5 bytes, then wTotalLength; a STALL there is tolerated, as Linux does);
//!    GET_DESCRIPTOR(configuration, 9), then with wTotalLength;
//! 4. GET_DESCRIPTOR(string 0, 255), then the product, manufacturer and serial-number strings
//!    (wLength 255, the first language id);
//! 5. SET_CONFIGURATION(bConfigurationValue) (the host's data toggles to DATA0);
//! 6. cdc-acm: SET_LINE_CODING(115200 8N1), SET_CONTROL_LINE_STATE(DTR | RTS) to the
//!    communication interface.
//!
//! Then [`Host::enumerated`] is true and, while reading ([`Host::set_reading`]), the host polls
//! the data interface's bulk IN endpoint continuously (a new IN token right after each packet,
//! retried after a NAK as soon as the device changed anything: several 64-byte packets per 1 ms
//! frame while the device has data), and sends queued bytes to bulk OUT in packets of up to
//! wMaxPacketSize. Each transaction takes its full-speed bus time ([`txn_s`]).
//!
//! Control transfers stop at the first STALL (the request fails), time out after
//! [`CONTROL_TIMEOUT_S`] (Linux's USB_CTRL_GET_TIMEOUT), and fail on a malformed descriptor; an
//! enumeration failure is kept in [`Host::error`] (also in [`Host::errors`], with class-request
//! and bulk errors) and the host leaves the port disabled until the device disconnects. A
//! disconnect (pull-up off, VBUS removed, the board reset) is seen at the next transaction or
//! clock step; the next connection enumerates again (with the next device address).
//!
//! Layout: `descriptors` (parsing and validating what the device sends), `control` (EP0: the
//! enumeration script and the class requests), `bulk` (the serial data), `port` (connect, reset,
//! SOFs, the clock that steps the rest) and `handle` ([`UsbHost`], what tests and the pty bridge
//! hold); this file has the timings and the [`Host`] state they share.

mod bulk;
mod control;
mod descriptors;
mod handle;
mod port;

pub use bulk::URB_SIZE;
pub use descriptors::{
    find_cdc, parse_configuration, parse_device, parse_string, Cdc, Configuration, DeviceDescriptor, Endpoint, Interface,
};
pub use handle::{usb_board, UsbHost};
pub use port::PortState;

use control::{Control, Op};
use port::Running;
use std::collections::VecDeque;

/// Connect debounce (s): USB 2.0 TATTDB, 100 ms (Linux waits at least that).
pub const DEBOUNCE_S: f64 = 0.1;
/// Bus reset length (s): USB 2.0 TDRST, 10 ms minimum.
pub const RESET_S: f64 = 0.01;
/// Reset recovery (s): USB 2.0 TRSTRCY, 10 ms.
pub const RECOVERY_S: f64 = 0.01;
/// Wait after SET_ADDRESS (s): Linux's 10 ms (USB 2.0 asks for 2 ms).
pub const SET_ADDRESS_WAIT_S: f64 = 0.01;
/// A control transfer not done after this long fails (s): Linux's 5000 ms.
pub const CONTROL_TIMEOUT_S: f64 = 5.0;
/// Host software gap between two control transfers (s).
pub const CONTROL_GAP_S: f64 = 100e-6;

/// Bus time of one transaction with `len` data bytes at 12 Mbit/s (s): token, data with CRC and
/// bit stuffing (~7/6), handshake, inter-packet gaps.
pub fn txn_s(len: usize) -> f64 {
    (len as f64 + 3.0) * 8.0 * 7.0 / 6.0 / 12e6 + 3e-6
}

/// When a pipe tries next.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Next {
    At(f64),
    /// NAKed: retry once the device's registers changed after this generation.
    AfterChange(u64),
}

/// The host's state (lives in [`crate::periph::Periph::usb_host`], stepped by the board's clock).
#[derive(Debug, Clone)]
pub struct Host {
    /// The port.
    pub port: PortState,
    now: f64,
    addr: u8,
    next_devnum: u8,
    mps0: usize,
    next_sof: Option<f64>,
    frame: u16,
    script: VecDeque<Op>,
    running: Running,
    ctrl: Option<Control>,
    ctrl_not_before: f64,
    enumerated: bool,
    /// The device descriptor as parsed.
    pub device: Option<DeviceDescriptor>,
    /// The configuration as parsed.
    pub configuration: Option<Configuration>,
    /// The BOS descriptor (raw), if the device has one.
    pub bos: Option<Vec<u8>>,
    /// The CDC-ACM function.
    pub cdc: Option<Cdc>,
    /// The first language id (string descriptor 0).
    pub langid: Option<u16>,
    /// The string descriptors read: (index, text).
    pub strings: Vec<(u8, String)>,
    reading: bool,
    rx: Vec<u8>,
    /// The read URB being filled.
    urb: Vec<u8>,
    /// Since when its first byte waits (s).
    urb_since: Option<f64>,
    max_urb_wait_s: f64,
    /// Zero-length packets received on bulk IN.
    pub zlps: u32,
    tx: VecDeque<u8>,
    in_next: Next,
    out_next: Next,
    in_toggle: bool,
    out_toggle: bool,
    /// Why the last enumeration failed (cleared when a new one starts).
    pub error: Option<String>,
    /// Every error so far (enumeration, class requests, bulk transfers), in order.
    pub errors: Vec<String>,
    /// What the host did, one line per request or bus event (time-stamped).
    pub log: Vec<String>,
    /// Bytes received from / sent to the device so far.
    pub rx_total: u64,
    /// Bytes sent to the device so far.
    pub tx_total: u64,
    /// The size of each bulk OUT packet the device acknowledged, in order (B).
    pub out_packets: Vec<u16>,
    /// IN packets ignored because their data toggle repeated the last one.
    pub toggle_errors: u32,
    /// Enumerations completed.
    pub enumerations: u32,
    /// The line coding last set (baud) and the control line state (bit 0 DTR, bit 1 RTS).
    pub line: (u32, u16),
    /// A device whose USB stack is not emulated (the stock bootloader in SAM-BA mode):
    /// (VID:PID, manufacturer, product), set by the board model while it is on the port.
    pub stand_in: Option<((u16, u16), &'static str, &'static str)>,
}

impl Default for Host {
    fn default() -> Self {
        Self::new()
    }
}

impl Host {
    /// No device, reading on.
    pub fn new() -> Self {
        Self {
            port: PortState::NoDevice,
            now: 0.0,
            addr: 0,
            next_devnum: 1,
            mps0: 64,
            next_sof: None,
            frame: 0,
            script: VecDeque::new(),
            running: Running::Idle,
            ctrl: None,
            ctrl_not_before: 0.0,
            enumerated: false,
            device: None,
            configuration: None,
            bos: None,
            cdc: None,
            langid: None,
            strings: vec![],
            reading: true,
            rx: vec![],
            urb: vec![],
            urb_since: None,
            max_urb_wait_s: 0.0,
            zlps: 0,
            tx: VecDeque::new(),
            in_next: Next::At(0.0),
            out_next: Next::At(0.0),
            in_toggle: false,
            out_toggle: false,
            error: None,
            errors: vec![],
            log: vec![],
            rx_total: 0,
            tx_total: 0,
            out_packets: Vec::new(),
            toggle_errors: 0,
            enumerations: 0,
            line: (0, 0),
            stand_in: None,
        }
    }

    /// The enumeration (with the cdc-acm requests) completed and the device is still there.
    pub fn enumerated(&self) -> bool {
        self.enumerated
    }

    /// The string descriptor `index`, if read.
    pub fn string(&self, index: u8) -> Option<&str> {
        self.strings.iter().find(|s| s.0 == index).map(|s| s.1.as_str())
    }

    /// The product string (iProduct), if read.
    pub fn product(&self) -> Option<&str> {
        self.string(self.device.as_ref()?.strings.1)
    }

    /// The manufacturer string (iManufacturer), if read.
    pub fn manufacturer(&self) -> Option<&str> {
        self.string(self.device.as_ref()?.strings.0)
    }
}
