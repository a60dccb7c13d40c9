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

use crate::mcu::{Mcu, Stop};
use crate::periph::usbd::{Handshake, Phy, Usbd};
use crate::periph::Periph;
use std::cell::RefCell;
use std::collections::VecDeque;
use std::rc::Rc;

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

/// The standard device descriptor.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceDescriptor {
    /// bcdUSB.
    pub usb: u16,
    /// bDeviceClass, bDeviceSubClass, bDeviceProtocol.
    pub class: (u8, u8, u8),
    /// bMaxPacketSize0.
    pub max_packet0: u8,
    /// idVendor.
    pub vid: u16,
    /// idProduct.
    pub pid: u16,
    /// bcdDevice.
    pub device: u16,
    /// iManufacturer, iProduct, iSerialNumber.
    pub strings: (u8, u8, u8),
    /// bNumConfigurations.
    pub num_configurations: u8,
}

/// An endpoint descriptor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Endpoint {
    /// bEndpointAddress (bit 7: IN).
    pub address: u8,
    /// bmAttributes (bits 1:0: 0 control, 1 iso, 2 bulk, 3 interrupt).
    pub attributes: u8,
    /// wMaxPacketSize.
    pub max_packet: u16,
    /// bInterval.
    pub interval: u8,
}

/// An interface descriptor with its endpoints.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Interface {
    /// bInterfaceNumber.
    pub number: u8,
    /// bInterfaceClass, bInterfaceSubClass, bInterfaceProtocol.
    pub class: (u8, u8, u8),
    /// Its endpoints.
    pub endpoints: Vec<Endpoint>,
}

/// The configuration descriptor as parsed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Configuration {
    /// The raw bytes (wTotalLength).
    pub raw: Vec<u8>,
    /// bConfigurationValue.
    pub value: u8,
    /// bmAttributes.
    pub attributes: u8,
    /// bMaxPower (2 mA units).
    pub max_power: u8,
    /// The interfaces in order.
    pub interfaces: Vec<Interface>,
}

/// The CDC-ACM function found in the configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cdc {
    /// The communication interface (class requests go there).
    pub comm_interface: u8,
    /// Its notification endpoint (interrupt IN), if any.
    pub notify_in: Option<u8>,
    /// The data interface.
    pub data_interface: u8,
    /// Bulk IN endpoint address and max packet.
    pub bulk_in: (u8, u16),
    /// Bulk OUT endpoint address and max packet.
    pub bulk_out: (u8, u16),
}

/// Parses a device descriptor.
pub fn parse_device(d: &[u8]) -> Result<DeviceDescriptor, String> {
    if d.len() != 18 || d[0] != 18 || d[1] != 1 {
        return Err(format!(
            "malformed device descriptor: {} bytes, bLength {}, bDescriptorType {}",
            d.len(),
            d.first().copied().unwrap_or(0),
            d.get(1).copied().unwrap_or(0)
        ));
    }
    let u = |i: usize| u16::from_le_bytes([d[i], d[i + 1]]);
    if ![8, 16, 32, 64].contains(&d[7]) {
        return Err(format!("malformed device descriptor: bMaxPacketSize0 {}", d[7]));
    }
    Ok(DeviceDescriptor {
        usb: u(2),
        class: (d[4], d[5], d[6]),
        max_packet0: d[7],
        vid: u(8),
        pid: u(10),
        device: u(12),
        strings: (d[14], d[15], d[16]),
        num_configurations: d[17],
    })
}

/// Parses a full configuration descriptor (with its interfaces and endpoints).
pub fn parse_configuration(d: &[u8]) -> Result<Configuration, String> {
    if d.len() < 9 || d[0] != 9 || d[1] != 2 {
        return Err("malformed configuration descriptor header".into());
    }
    let total = u16::from_le_bytes([d[2], d[3]]) as usize;
    if total != d.len() {
        return Err(format!("malformed configuration descriptor: wTotalLength {total}, {} bytes received", d.len()));
    }
    let mut interfaces: Vec<Interface> = vec![];
    let mut i = 9;
    while i < d.len() {
        let (len, ty) = (d[i] as usize, d.get(i + 1).copied().unwrap_or(0));
        if len < 2 || i + len > d.len() {
            return Err(format!(
                "malformed configuration descriptor: a descriptor of bLength {len} at byte {i} overruns wTotalLength {total}"
            ));
        }
        let s = &d[i..i + len];
        match ty {
            4 => {
                if len < 9 {
                    return Err(format!("malformed interface descriptor at byte {i} (bLength {len})"));
                }
                interfaces.push(Interface { number: s[2], class: (s[5], s[6], s[7]), endpoints: vec![] });
            }
            5 => {
                if len < 7 {
                    return Err(format!("malformed endpoint descriptor at byte {i} (bLength {len})"));
                }
                let ep = Endpoint { address: s[2], attributes: s[3], max_packet: u16::from_le_bytes([s[4], s[5]]), interval: s[6] };
                if ep.max_packet == 0 || ep.max_packet > 64 {
                    return Err(format!("endpoint 0x{:02X}: wMaxPacketSize {} is not a full-speed value", ep.address, ep.max_packet));
                }
                match interfaces.last_mut() {
                    Some(itf) => itf.endpoints.push(ep),
                    None => return Err(format!("endpoint descriptor at byte {i} before any interface")),
                }
            }
            _ => {}
        }
        i += len;
    }
    Ok(Configuration { raw: d.to_vec(), value: d[5], attributes: d[7], max_power: d[8], interfaces })
}

/// The CDC-ACM function of a configuration: the communication interface (class 2, subclass 2)
/// and the data interface (class 10) with one bulk IN and one bulk OUT endpoint.
pub fn find_cdc(c: &Configuration) -> Result<Cdc, String> {
    let comm =
        c.interfaces.iter().find(|i| i.class.0 == 2 && i.class.1 == 2).ok_or("no CDC-ACM communication interface (class 2, subclass 2)")?;
    let data = c.interfaces.iter().find(|i| i.class.0 == 10).ok_or("no CDC data interface (class 10)")?;
    let bulk = |dir_in: bool| {
        data.endpoints.iter().find(|e| e.attributes & 3 == 2 && (e.address & 0x80 != 0) == dir_in).map(|e| (e.address, e.max_packet))
    };
    let notify_in = comm.endpoints.iter().find(|e| e.attributes & 3 == 3 && e.address & 0x80 != 0).map(|e| e.address);
    Ok(Cdc {
        comm_interface: comm.number,
        notify_in,
        data_interface: data.number,
        bulk_in: bulk(true).ok_or("the CDC data interface has no bulk IN endpoint")?,
        bulk_out: bulk(false).ok_or("the CDC data interface has no bulk OUT endpoint")?,
    })
}

/// Parses a string descriptor (UTF-16LE).
pub fn parse_string(d: &[u8]) -> Result<String, String> {
    if d.len() < 2 || d[0] as usize != d.len() || d[1] != 3 || !d.len().is_multiple_of(2) {
        return Err(format!("malformed string descriptor: {} bytes, bLength {}", d.len(), d.first().copied().unwrap_or(0)));
    }
    let units: Vec<u16> = d[2..].chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
    String::from_utf16(&units).map_err(|e| format!("malformed string descriptor: {e}"))
}

/// What a control transfer is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Tag {
    Device64,
    SetAddress(u8),
    Device18,
    Bos5,
    BosFull(u16),
    Config9,
    ConfigFull,
    String0,
    String(u8),
    SetConfiguration(u8),
    /// SET_LINE_CODING (baud).
    LineCoding(u32),
    /// SET_CONTROL_LINE_STATE (wValue).
    LineState(u16),
}

/// A step of the host's script.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Op {
    Reset,
    Wait(f64),
    Control(Tag),
    /// A class request asked for through the API (waits for the enumeration).
    User(Tag),
    /// The enumeration is complete.
    Configured,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    Setup,
    DataIn,
    DataOut,
    StatusIn,
    StatusOut,
}

/// When a pipe tries next.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Next {
    At(f64),
    /// NAKed: retry once the device's registers changed after this generation.
    AfterChange(u64),
}

#[derive(Debug, Clone)]
struct Control {
    tag: Tag,
    setup: [u8; 8],
    out: Vec<u8>,
    sent: usize,
    got: Vec<u8>,
    stage: Stage,
    next: Next,
    deadline: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Running {
    Idle,
    Reset(f64),
    Wait(f64),
}

/// Where the port is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PortState {
    /// Nothing connected.
    NoDevice,
    /// Connected, debouncing until this time (s).
    Debounce(f64),
    /// Enumerating (or running requests).
    Active,
    /// The enumeration failed: the port is disabled until a disconnect.
    Failed,
}

/// The host's state (lives in [`Periph::usb_host`], stepped by the board's clock).
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
    /// IN packets ignored because their data toggle repeated the last one.
    pub toggle_errors: u32,
    /// Enumerations completed.
    pub enumerations: u32,
    /// The line coding last set (baud) and the control line state (bit 0 DTR, bit 1 RTS).
    pub line: (u32, u16),
}

impl Default for Host {
    fn default() -> Self {
        Self::new()
    }
}

fn setup(bm: u8, req: u8, value: u16, index: u16, length: u16) -> [u8; 8] {
    let (v, i, l) = (value.to_le_bytes(), index.to_le_bytes(), length.to_le_bytes());
    [bm, req, v[0], v[1], i[0], i[1], l[0], l[1]]
}

fn describe(tag: Tag) -> String {
    match tag {
        Tag::Device64 => "GET_DESCRIPTOR(device, 64)".into(),
        Tag::SetAddress(a) => format!("SET_ADDRESS({a})"),
        Tag::Device18 => "GET_DESCRIPTOR(device, 18)".into(),
        Tag::Bos5 => "GET_DESCRIPTOR(BOS, 5)".into(),
        Tag::BosFull(n) => format!("GET_DESCRIPTOR(BOS, {n})"),
        Tag::Config9 => "GET_DESCRIPTOR(configuration, 9)".into(),
        Tag::ConfigFull => "GET_DESCRIPTOR(configuration, wTotalLength)".into(),
        Tag::String0 => "GET_DESCRIPTOR(string 0)".into(),
        Tag::String(i) => format!("GET_DESCRIPTOR(string {i})"),
        Tag::SetConfiguration(c) => format!("SET_CONFIGURATION({c})"),
        Tag::LineCoding(b) => format!("SET_LINE_CODING({b} 8N1)"),
        Tag::LineState(v) => format!("SET_CONTROL_LINE_STATE(0x{v:X})"),
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
            toggle_errors: 0,
            enumerations: 0,
            line: (0, 0),
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

    /// Start (true, the default) or stop polling bulk IN (a program that does not read).
    pub fn set_reading(&mut self, on: bool) {
        if on && !self.reading {
            self.in_next = Next::At(self.now);
        }
        self.reading = on;
    }

    /// Whether the host polls bulk IN.
    pub fn reading(&self) -> bool {
        self.reading
    }

    /// Queues bytes for bulk OUT.
    pub fn write(&mut self, data: &[u8]) {
        if self.tx.is_empty() {
            self.out_next = Next::At(self.now);
        }
        self.tx.extend(data);
    }

    /// Bytes queued for bulk OUT, not yet accepted by the device.
    pub fn pending_tx(&self) -> usize {
        self.tx.len()
    }

    /// Takes the bytes received on bulk IN so far.
    pub fn read(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.rx)
    }

    /// Queues SET_LINE_CODING(baud, 8N1) (sent once enumerated).
    pub fn set_line_coding(&mut self, baud: u32) {
        self.script.push_back(Op::User(Tag::LineCoding(baud)));
    }

    /// Queues SET_CONTROL_LINE_STATE with DTR (and RTS) set or cleared.
    pub fn set_dtr(&mut self, dtr: bool) {
        self.script.push_back(Op::User(Tag::LineState(if dtr { 3 } else { 0 })));
    }

    /// The control requests queued and not yet started, described.
    pub fn queued(&self) -> Vec<String> {
        self.script
            .iter()
            .filter_map(|op| match op {
                Op::Control(t) | Op::User(t) => Some(describe(*t)),
                _ => None,
            })
            .collect()
    }

    /// Whether control requests are still queued or running.
    pub fn busy(&self) -> bool {
        self.ctrl.is_some() || !self.script.is_empty() || self.running != Running::Idle
    }

    fn note(&mut self, s: String) {
        self.log.push(format!("{:.6} {s}", self.now));
    }

    fn fail(&mut self, e: String) {
        self.note(format!("error: {e}"));
        self.errors.push(e.clone());
        if !self.enumerated {
            self.error = Some(e);
            self.port = PortState::Failed;
            self.script.clear();
            self.ctrl = None;
            self.running = Running::Idle;
            self.next_sof = None;
        }
    }

    fn disconnect(&mut self) {
        if self.port != PortState::NoDevice {
            self.note("device disconnected".into());
        }
        self.port = PortState::NoDevice;
        self.enumerated = false;
        self.script.retain(|op| matches!(op, Op::User(_)));
        self.ctrl = None;
        self.running = Running::Idle;
        self.next_sof = None;
        self.addr = 0;
    }

    fn start_enumeration(&mut self) {
        self.note("device connected: reset".into());
        self.error = None;
        self.device = None;
        self.configuration = None;
        self.bos = None;
        self.cdc = None;
        self.langid = None;
        self.strings.clear();
        self.mps0 = 64;
        self.addr = 0;
        self.port = PortState::Active;
        let user: Vec<Op> = self.script.drain(..).collect();
        self.script = [Op::Reset, Op::Wait(RECOVERY_S), Op::Control(Tag::Device64)].into_iter().collect();
        self.script.extend(user);
    }

    /// The next time the host does something by itself (s), for a CPU asleep in `wfi`.
    pub fn next_time(&self, dev: &Usbd) -> Option<f64> {
        let mut t: Option<f64> = None;
        let mut add = |x: f64| t = Some(t.map_or(x, |y: f64| y.min(x)));
        if let PortState::Debounce(d) = self.port {
            add(d);
        }
        if let Some(s) = self.next_sof {
            add(s);
        }
        match self.running {
            Running::Reset(e) | Running::Wait(e) => add(e),
            Running::Idle => {}
        }
        let when = |n: Next| match n {
            Next::At(x) => Some(x),
            Next::AfterChange(g) => (g != dev.generation).then(|| dev.changed_at.max(self.now)),
        };
        if let Some(c) = &self.ctrl {
            if let Some(x) = when(c.next) {
                add(x);
            }
            add(c.deadline);
        }
        if self.enumerated {
            if self.reading {
                if let Some(x) = when(self.in_next) {
                    add(x);
                }
            }
            if !self.tx.is_empty() {
                if let Some(x) = when(self.out_next) {
                    add(x);
                }
            }
        }
        t
    }

    /// Runs the host up to time `t` (s) against `dev`. An `Err` is a modelling fault raised by
    /// the device model (the run stops).
    pub fn advance(&mut self, t: f64, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        for _ in 0..1_000_000 {
            let connected = dev.connected(phy);
            if !connected && self.port != PortState::NoDevice {
                self.now = self.now.max(dev.changed_at.min(t));
                self.disconnect();
            }
            if connected && self.port == PortState::NoDevice {
                self.now = self.now.max(t);
                self.port = PortState::Debounce(self.now + DEBOUNCE_S);
                self.note("device seen (pull-up): debounce".into());
            }
            // Start the next step of the script when nothing runs.
            if self.port == PortState::Active && self.running == Running::Idle && self.ctrl.is_none() {
                if let Some(op) = self.script.front().copied() {
                    let user = matches!(op, Op::User(_));
                    if !user || self.enumerated {
                        self.script.pop_front();
                        self.begin(op, dev, phy);
                        continue;
                    }
                }
            }
            let Some(next) = self.next_time(dev) else { break };
            if next > t {
                break;
            }
            self.now = self.now.max(next);
            self.step(dev, phy)?;
        }
        self.now = self.now.max(t);
        Ok(())
    }

    fn begin(&mut self, op: Op, dev: &mut Usbd, phy: Phy) {
        match op {
            Op::Reset => {
                self.note("bus reset".into());
                self.running = Running::Reset(self.now + RESET_S);
                self.next_sof = None;
                dev.bus_reset(phy);
                self.addr = 0;
            }
            Op::Wait(s) => self.running = Running::Wait(self.now + s),
            Op::Configured => {
                self.enumerated = true;
                self.enumerations += 1;
                self.in_next = Next::At(self.now);
                self.out_next = Next::At(self.now);
                self.note("enumerated".into());
            }
            Op::Control(tag) | Op::User(tag) => {
                let iface = self.cdc.map_or(0, |c| c.comm_interface as u16);
                let (s, out) = match tag {
                    Tag::Device64 => (setup(0x80, 6, 0x0100, 0, 64), vec![]),
                    Tag::SetAddress(a) => (setup(0x00, 5, a as u16, 0, 0), vec![]),
                    Tag::Device18 => (setup(0x80, 6, 0x0100, 0, 18), vec![]),
                    Tag::Bos5 => (setup(0x80, 6, 0x0F00, 0, 5), vec![]),
                    Tag::BosFull(n) => (setup(0x80, 6, 0x0F00, 0, n), vec![]),
                    Tag::Config9 => (setup(0x80, 6, 0x0200, 0, 9), vec![]),
                    Tag::ConfigFull => {
                        let total = self.configuration.as_ref().map_or(9, |c| c.raw.len() as u16);
                        (setup(0x80, 6, 0x0200, 0, total), vec![])
                    }
                    Tag::String0 => (setup(0x80, 6, 0x0300, 0, 255), vec![]),
                    Tag::String(i) => (setup(0x80, 6, 0x0300 | i as u16, self.langid.unwrap_or(0x0409), 255), vec![]),
                    Tag::SetConfiguration(c) => (setup(0x00, 9, c as u16, 0, 0), vec![]),
                    Tag::LineCoding(b) => {
                        let mut d = b.to_le_bytes().to_vec();
                        d.extend([0, 0, 8]);
                        (setup(0x21, 0x20, 0, iface, 7), d)
                    }
                    Tag::LineState(v) => (setup(0x21, 0x22, v, iface, 0), vec![]),
                };
                let start = self.now.max(self.ctrl_not_before);
                self.ctrl = Some(Control {
                    tag,
                    setup: s,
                    out,
                    sent: 0,
                    got: vec![],
                    stage: Stage::Setup,
                    next: Next::At(start),
                    deadline: start + CONTROL_TIMEOUT_S,
                });
            }
        }
    }

    /// Does what is due at `self.now`.
    fn step(&mut self, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        let now = self.now;
        if let PortState::Debounce(d) = self.port {
            if now >= d {
                self.start_enumeration();
                return Ok(());
            }
        }
        if let Running::Reset(e) = self.running {
            if now >= e {
                self.running = Running::Idle;
                self.next_sof = Some(now);
            }
            return Ok(());
        }
        if let Running::Wait(e) = self.running {
            if now >= e {
                self.running = Running::Idle;
            }
        }
        if self.next_sof.is_some_and(|s| now >= s) {
            dev.sof(self.frame, phy);
            self.frame = (self.frame + 1) & 0x7FF;
            self.next_sof = self.next_sof.map(|s| s + 1e-3);
            return Ok(());
        }
        let due = |n: Next, dev: &Usbd| match n {
            Next::At(x) => now >= x,
            Next::AfterChange(g) => g != dev.generation && now >= dev.changed_at,
        };
        if let Some(c) = &self.ctrl {
            if now >= c.deadline {
                let stage = c.stage;
                let tag = c.tag;
                self.ctrl = None;
                self.control_done(
                    tag,
                    Err(format!(
                        "timeout: {} not completed within {CONTROL_TIMEOUT_S} s (stage {stage:?}, the device NAKs)",
                        describe(tag)
                    )),
                    dev,
                );
                return Ok(());
            }
            if due(c.next, dev) {
                return self.control_step(dev, phy);
            }
        }
        if self.enumerated && self.reading && due(self.in_next, dev) {
            return self.bulk_in(dev, phy);
        }
        if self.enumerated && !self.tx.is_empty() && due(self.out_next, dev) {
            return self.bulk_out(dev, phy);
        }
        Ok(())
    }

    fn silent(&mut self, what: &str, dev: &Usbd, phy: Phy) {
        if dev.connected(phy) {
            self.fail(format!("no response from the device to {what}"));
        } else {
            self.disconnect();
        }
    }

    fn control_step(&mut self, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        let Some(mut c) = self.ctrl.take() else { return Ok(()) };
        let now = self.now;
        let what = describe(c.tag);
        let mps = self.mps0;
        let nak = |c: &mut Control, dev: &Usbd| c.next = Next::AfterChange(dev.generation);
        match c.stage {
            Stage::Setup => match dev.setup(self.addr, c.setup, phy)? {
                Handshake::Ack => {
                    c.stage = if c.setup[0] & 0x80 != 0 {
                        Stage::DataIn
                    } else if c.setup[6] != 0 || c.setup[7] != 0 {
                        Stage::DataOut
                    } else {
                        Stage::StatusIn
                    };
                    c.next = Next::At(now + txn_s(8));
                }
                Handshake::Silent => {
                    self.silent(&format!("the SETUP of {what}"), dev, phy);
                    return Ok(());
                }
                h => {
                    self.control_done(c.tag, Err(format!("{what}: SETUP answered {h:?}")), dev);
                    return Ok(());
                }
            },
            Stage::DataIn => match dev.in_token(self.addr, 0, phy)? {
                Ok(p) => {
                    if p.data.len() > mps {
                        self.control_done(c.tag, Err(format!("{what}: babble: a {}-byte packet on EP0 (max {mps})", p.data.len())), dev);
                        return Ok(());
                    }
                    let want = u16::from_le_bytes([c.setup[6], c.setup[7]]) as usize;
                    let room = want - c.got.len().min(want);
                    c.got.extend_from_slice(&p.data[..p.data.len().min(room)]);
                    if p.data.len() < mps || c.got.len() >= want {
                        c.stage = Stage::StatusOut;
                    }
                    c.next = Next::At(now + txn_s(p.data.len()));
                }
                Err(Handshake::Nak) => nak(&mut c, dev),
                Err(Handshake::Stall) => {
                    self.control_done(c.tag, Err(format!("STALL on {what} (data stage)")), dev);
                    return Ok(());
                }
                Err(_) => {
                    self.silent(&format!("the data stage of {what}"), dev, phy);
                    return Ok(());
                }
            },
            Stage::DataOut => {
                let end = (c.sent + mps).min(c.out.len());
                let chunk = c.out[c.sent..end].to_vec();
                match dev.out_token(self.addr, 0, &chunk, true, phy)? {
                    Handshake::Ack => {
                        c.sent = end;
                        if c.sent >= c.out.len() {
                            c.stage = Stage::StatusIn;
                        }
                        c.next = Next::At(now + txn_s(chunk.len()));
                    }
                    Handshake::Nak => nak(&mut c, dev),
                    Handshake::Stall => {
                        self.control_done(c.tag, Err(format!("STALL on {what} (data stage)")), dev);
                        return Ok(());
                    }
                    Handshake::Silent => {
                        self.silent(&format!("the data stage of {what}"), dev, phy);
                        return Ok(());
                    }
                }
            }
            Stage::StatusIn => match dev.in_token(self.addr, 0, phy)? {
                Ok(p) if p.data.is_empty() => {
                    self.ctrl_not_before = now + txn_s(0) + CONTROL_GAP_S;
                    self.control_done(c.tag, Ok(vec![]), dev);
                    return Ok(());
                }
                Ok(p) => {
                    self.control_done(c.tag, Err(format!("{what}: {} data bytes in the status stage", p.data.len())), dev);
                    return Ok(());
                }
                Err(Handshake::Nak) => nak(&mut c, dev),
                Err(Handshake::Stall) => {
                    self.control_done(c.tag, Err(format!("STALL on {what} (status stage)")), dev);
                    return Ok(());
                }
                Err(_) => {
                    self.silent(&format!("the status stage of {what}"), dev, phy);
                    return Ok(());
                }
            },
            Stage::StatusOut => match dev.out_token(self.addr, 0, &[], true, phy)? {
                Handshake::Ack => {
                    self.ctrl_not_before = now + txn_s(0) + CONTROL_GAP_S;
                    let got = std::mem::take(&mut c.got);
                    self.control_done(c.tag, Ok(got), dev);
                    return Ok(());
                }
                Handshake::Nak => nak(&mut c, dev),
                Handshake::Stall => {
                    self.control_done(c.tag, Err(format!("STALL on {what} (status stage)")), dev);
                    return Ok(());
                }
                Handshake::Silent => {
                    self.silent(&format!("the status stage of {what}"), dev, phy);
                    return Ok(());
                }
            },
        }
        self.ctrl = Some(c);
        Ok(())
    }

    /// A control transfer ended: the enumeration's next step.
    fn control_done(&mut self, tag: Tag, r: Result<Vec<u8>, String>, dev: &mut Usbd) {
        let _ = dev;
        let d = match r {
            Ok(d) => {
                self.note(format!("{} ok ({} bytes)", describe(tag), d.len()));
                d
            }
            Err(e) if matches!(tag, Tag::Bos5 | Tag::BosFull(_)) && e.starts_with("STALL") => {
                // Linux goes on without the BOS descriptor.
                self.note(format!("{e}: ignored"));
                self.script.push_front(Op::Control(Tag::Config9));
                return;
            }
            Err(e) => {
                self.fail(e);
                return;
            }
        };
        let front = |h: &mut Host, ops: &[Op]| {
            for op in ops.iter().rev() {
                h.script.push_front(*op);
            }
        };
        let r: Result<(), String> = (|| {
            match tag {
                Tag::Device64 => {
                    if d.len() < 8 || d[1] != 1 {
                        return Err(format!("malformed device descriptor: {} bytes to GET_DESCRIPTOR(device, 64)", d.len()));
                    }
                    if ![8, 16, 32, 64].contains(&d[7]) {
                        return Err(format!("malformed device descriptor: bMaxPacketSize0 {}", d[7]));
                    }
                    self.mps0 = d[7] as usize;
                    let a = self.next_devnum;
                    self.next_devnum = if a >= 127 { 1 } else { a + 1 };
                    front(self, &[Op::Reset, Op::Wait(RECOVERY_S), Op::Control(Tag::SetAddress(a))]);
                }
                Tag::SetAddress(a) => {
                    self.addr = a;
                    front(self, &[Op::Wait(SET_ADDRESS_WAIT_S), Op::Control(Tag::Device18)]);
                }
                Tag::Device18 => {
                    let dd = parse_device(&d)?;
                    self.mps0 = dd.max_packet0 as usize;
                    let bos = dd.usb >= 0x0201;
                    self.device = Some(dd);
                    front(self, &[Op::Control(if bos { Tag::Bos5 } else { Tag::Config9 })]);
                }
                Tag::Bos5 => {
                    if d.len() != 5 || d[0] != 5 || d[1] != 0x0F {
                        return Err(format!("malformed BOS descriptor: {} bytes to GET_DESCRIPTOR(BOS, 5)", d.len()));
                    }
                    let total = u16::from_le_bytes([d[2], d[3]]);
                    front(self, &[Op::Control(if total > 5 { Tag::BosFull(total) } else { Tag::Config9 })]);
                }
                Tag::BosFull(n) => {
                    if d.len() != n as usize {
                        return Err(format!("malformed BOS descriptor: wTotalLength {n}, {} bytes received", d.len()));
                    }
                    let mut i = 5;
                    while i < d.len() {
                        let len = d[i] as usize;
                        if len < 3 || i + len > d.len() || d[i + 1] != 0x10 {
                            return Err(format!("malformed BOS descriptor: a capability of bLength {len} at byte {i}"));
                        }
                        i += len;
                    }
                    self.bos = Some(d.clone());
                    front(self, &[Op::Control(Tag::Config9)]);
                }
                Tag::Config9 => {
                    if d.len() != 9 || d[0] != 9 || d[1] != 2 {
                        return Err(format!("malformed configuration descriptor: {} bytes to GET_DESCRIPTOR(configuration, 9)", d.len()));
                    }
                    let total = u16::from_le_bytes([d[2], d[3]]);
                    if total < 9 {
                        return Err(format!("malformed configuration descriptor: wTotalLength {total}"));
                    }
                    self.configuration = Some(Configuration {
                        raw: vec![0; total as usize],
                        value: d[5],
                        attributes: d[7],
                        max_power: d[8],
                        interfaces: vec![],
                    });
                    front(self, &[Op::Control(Tag::ConfigFull)]);
                }
                Tag::ConfigFull => {
                    let c = parse_configuration(&d)?;
                    self.cdc = Some(find_cdc(&c)?);
                    self.configuration = Some(c);
                    front(self, &[Op::Control(Tag::String0)]);
                }
                Tag::String0 => {
                    if d.len() < 4 || d[1] != 3 || d[0] as usize != d.len() {
                        return Err(format!("malformed string descriptor 0 ({} bytes)", d.len()));
                    }
                    self.langid = Some(u16::from_le_bytes([d[2], d[3]]));
                    let (m, p, s) = self.device.as_ref().map_or((0, 0, 0), |dd| dd.strings);
                    let mut ops = vec![];
                    for i in [p, m, s] {
                        if i != 0 && !ops.contains(&Op::Control(Tag::String(i))) {
                            ops.push(Op::Control(Tag::String(i)));
                        }
                    }
                    let cfg = self.configuration.as_ref().map_or(1, |c| c.value);
                    ops.extend([
                        Op::Control(Tag::SetConfiguration(cfg)),
                        Op::Control(Tag::LineCoding(115_200)),
                        Op::Control(Tag::LineState(3)),
                        Op::Configured,
                    ]);
                    front(self, &ops);
                }
                Tag::String(i) => {
                    let s = parse_string(&d).map_err(|e| format!("string {i}: {e}"))?;
                    self.strings.retain(|x| x.0 != i);
                    self.strings.push((i, s));
                }
                Tag::SetConfiguration(_) => {
                    self.in_toggle = false;
                    self.out_toggle = false;
                }
                Tag::LineCoding(b) => self.line.0 = b,
                Tag::LineState(v) => self.line.1 = v,
            }
            Ok(())
        })();
        if let Err(e) = r {
            self.fail(e);
        }
    }

    fn bulk_in(&mut self, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        let Some(cdc) = self.cdc else { return Ok(()) };
        let (ep, mps) = cdc.bulk_in;
        match dev.in_token(self.addr, (ep & 0x7F) as usize, phy)? {
            Ok(p) => {
                if p.data.len() > mps as usize {
                    self.errors.push(format!("babble on bulk IN 0x{ep:02X}: {} bytes (max {mps})", p.data.len()));
                } else if p.toggle != self.in_toggle {
                    self.toggle_errors += 1;
                } else {
                    self.in_toggle = !self.in_toggle;
                    self.rx_total += p.data.len() as u64;
                    self.rx.extend_from_slice(&p.data);
                }
                self.in_next = Next::At(self.now + txn_s(p.data.len()));
            }
            Err(Handshake::Nak) => self.in_next = Next::AfterChange(dev.generation),
            Err(Handshake::Stall) => {
                self.errors.push(format!("bulk IN 0x{ep:02X} stalled: reading stops"));
                self.reading = false;
            }
            Err(_) => self.silent(&format!("bulk IN 0x{ep:02X}"), dev, phy),
        }
        Ok(())
    }

    fn bulk_out(&mut self, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        let Some(cdc) = self.cdc else { return Ok(()) };
        let (ep, mps) = cdc.bulk_out;
        let n = self.tx.len().min(mps as usize);
        let pkt: Vec<u8> = self.tx.iter().take(n).copied().collect();
        match dev.out_token(self.addr, ep as usize, &pkt, self.out_toggle, phy)? {
            Handshake::Ack => {
                self.out_toggle = !self.out_toggle;
                self.tx.drain(..n);
                self.tx_total += n as u64;
                self.out_next = Next::At(self.now + txn_s(n));
            }
            Handshake::Nak => self.out_next = Next::AfterChange(dev.generation),
            Handshake::Stall => {
                self.errors.push(format!("bulk OUT 0x{ep:02X} stalled: {} bytes dropped", self.tx.len()));
                self.tx.clear();
            }
            Handshake::Silent => self.silent(&format!("bulk OUT 0x{ep:02X}"), dev, phy),
        }
        Ok(())
    }
}

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
