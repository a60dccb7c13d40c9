//! USB CDC-ACM serial port on the USBD (nRF52840 PS v1.7 §6.35): `usb-device` and
//! `usbd-serial`'s `CdcAcmClass` over `nrf-usbd`, as nrf-hal's USB example uses them, started
//! and stopped the way Nordic's nrfx driver (`nrfx_usbd.c`, nrfx 4.2) does it.
//!
//! - Start ([`Link`]): on VBUS (POWER.USBREGSTATUS.VBUSDETECT) the errata 187 and 171 sequences
//!   and ENABLE; the USB regulator switches on only then ("when the USBD is enabled through the
//!   ENABLE register and VBUS is detected", PS §5.3.3). Across loop ticks, for at most
//!   [`START_TIMEOUT_S`], the firmware waits for EVENTCAUSE.READY and USBREGSTATUS.OUTPUTRDY;
//!   only then the errata sequences end, erratum 211's begins (kept while enabled) and the
//!   pull-up connects. A start that times out disables the USBD and says which of the two did
//!   not come ([`Error`]).
//! - Stop: VBUS gone (the board runs on another supply) disconnects the pull-up and disables
//!   the USBD, as nrfx does on USBREMOVED; the next VBUS starts it again and the host's bus
//!   reset re-initialises `usb-device`.
//! - `nrf-usbd` is built once, after the first start: its `enable` repeats the 187/171 sequences
//!   (blind 0x9375 toggles, consistent because they find the lock closed), finds READY already
//!   set (its spin on READY has no timeout) and connects the pull-up. Its EasyDMA transfers run
//!   inside [`Usb::poll`]'s calls into it, which set erratum 199's register around them (it has
//!   no 199 workaround).
//! - Never blocks on the host: at most [`PACKETS_PER_POLL`] packets per poll from the
//!   [`Outbox`]; lines that do not fit are dropped whole and counted. A burst that ends on a
//!   full 64-byte packet is closed with a zero-length packet (Linux's cdc-acm completes its
//!   128-byte reads only on a short packet).
//! - The 1200-baud touch ([`Touch`]): [`Usb::poll`] says when it is complete; the caller
//!   enters the bootloader with [`enter_bootloader`].

use crate::serial::{Command, Outbox, Touch, GPREGRET_SERIAL_BOOTLOADER};
use calib_core::formats::text::{Hex, Int, Text};
use calib_core::Time;
use core::sync::atomic::{compiler_fence, Ordering};
use nrf52840_hal::pac;
use usb_device::bus::UsbBusAllocator;
use usb_device::device::{StringDescriptors, UsbDevice, UsbDeviceBuilder, UsbDeviceState, UsbVidPid};
use usbd_serial::CdcAcmClass;

/// The Nano 33 BLE's Arduino VID:PID (what the Arduino core gives sketches), so that Arduino's
/// tools and bossac find the port and its 1200-baud touch.
pub const VID_PID: (u16, u16) = (0x2341, 0x805A);
/// Manufacturer string: this firmware's, not Arduino's.
pub const MANUFACTURER: &str = "gyrocal";
/// Product string.
pub const PRODUCT: &str = "gyrocal Nano 33 BLE";
/// Bulk and EP0 packet size (B; full speed).
pub const PACKET: usize = 64;
/// Outbox size (B): 0.5 s of raw-log rows at 119 Hz (8.2 KB/s), for the longest call that does
/// not poll USB (the pan/tilt plan's end, ≈ 23 M instructions, ≈ 0.4 s at 64 MHz; a step of the
/// solve ≤ 8.2 M, see docs/limits.md) and its report lines; lines that do not fit are dropped
/// whole and counted.
pub const OUTBOX: usize = 4096;
/// Longest wait for READY and OUTPUTRDY after ENABLE (s): nrfx waits for READY without a
/// bound; the regulator needs ~1 ms (nRF5340 PS t_USBPWRRDY; the nRF52840 PS gives no figure).
pub const START_TIMEOUT_S: f32 = 0.05;
/// Wait before the next start after one timed out (s).
pub const RETRY_S: f32 = 1.0;
/// Packets handed to the bulk IN endpoint per [`Usb::poll`] at most (the endpoint takes one at
/// a time: the rest wait for the next poll).
const PACKETS_PER_POLL: usize = 4;

/// Why USB did not start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Error {
    /// EVENTCAUSE.READY came.
    pub ready: bool,
    /// USBREGSTATUS.OUTPUTRDY came.
    pub regulator: bool,
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter) -> core::fmt::Result {
        let what = Text(match (self.ready, self.regulator) {
            (false, false) => "neither USBD READY nor the USB regulator's OUTPUTRDY",
            (false, true) => "no USBD READY (the regulator is up)",
            _ => "no USB regulator OUTPUTRDY (the USBD is READY)",
        });
        write!(
            f,
            "USB did not start: {what} {} ms after ENABLE; retrying in {} s",
            Int((START_TIMEOUT_S * 1e3) as i64),
            Int(RETRY_S as i64)
        )
    }
}

/// The USBD register block for `nrf-usbd`.
pub struct Usbd0(pac::USBD);

// SAFETY: the only owner of the USBD; REGISTERS is its address.
unsafe impl nrf_usbd::UsbPeripheral for Usbd0 {
    const REGISTERS: *const () = pac::USBD::PTR as *const ();
}

type Bus = nrf_usbd::Usbd<Usbd0>;

/// Whether VBUS is present (POWER.USBREGSTATUS.VBUSDETECT).
pub fn vbus(power: &pac::POWER) -> bool {
    power.usbregstatus.read().vbusdetect().bit_is_set()
}

fn usbd() -> &'static pac::usbd::RegisterBlock {
    // SAFETY: register accesses only; the USBD's state machine is this module's alone.
    unsafe { &*pac::USBD::ptr() }
}

/// Reads the packet waiting at bulk OUT endpoint `ep` (1–7), if one does, as embassy-nrf does
/// since embassy-rs/embassy#6688: the end of its EasyDMA (ENDEPOUT) arms the endpoint for the
/// next packet by itself, so SIZE.EPOUT is not written after it. nrf-usbd 0.3's `read` writes
/// it, and that discards a packet the host delivered in between (silent loss under a fast host:
/// 4 of 11 back-to-back packets on the virtual board). The DMA of ≤ 64 bytes is waited for a
/// bounded number of polls.
fn read_out(ep: usize, buf: &mut [u8; PACKET]) -> Option<usize> {
    let r = usbd();
    if ep == 0 || ep > 7 || r.epdatastatus.read().bits() & (1 << (16 + ep)) == 0 {
        return None;
    }
    let size = (r.size.epout[ep].read().bits() as usize).min(PACKET);
    // SAFETY: write-1-to-clear of this endpoint's bit; the DMA targets `buf`, which outlives it
    // (it is waited for below), with MAXCNT = SIZE as the PS requires.
    r.epdatastatus.write(|w| unsafe { w.bits(1 << (16 + ep)) });
    let dma = [&r.epout0, &r.epout1, &r.epout2, &r.epout3, &r.epout4, &r.epout5, &r.epout6, &r.epout7][ep];
    dma.ptr.write(|w| unsafe { w.bits(buf.as_mut_ptr() as u32) });
    dma.maxcnt.write(|w| unsafe { w.bits(size as u32) });
    compiler_fence(Ordering::Release);
    r.events_endepout[ep].reset();
    r.tasks_startepout[ep].write(|w| w.tasks_startepout().set_bit());
    let done = (0..10_000).any(|_| r.events_endepout[ep].read().bits() != 0);
    r.events_endepout[ep].reset();
    compiler_fence(Ordering::Acquire);
    done.then_some(size)
}

/// The undocumented registers of nrfx's USBD errata workarounds (nrf52_erratas.h).
mod errata {
    const LOCK: u32 = 0x4006_EC00;
    const KEY: u32 = 0x9375;
    /// Erratum 171 (all nRF52840 revisions): 0xC0 during ENABLE.
    pub const E171: u32 = 0x4006_EC14;
    /// Errata 187 (3 during ENABLE) and 211 (3 while enabled), all revisions but engineering A.
    pub const E187_211: u32 = 0x4006_ED14;
    /// Erratum 199 (all revisions): 0x82 while EasyDMA runs, 0 after.
    pub const E199: u32 = 0x4002_7C1C;

    /// Writes `v` to `reg` as nrfx does: the lock reads 0 while closed and a write of the key
    /// toggles it, so it is opened only if closed, then closed again.
    #[inline(never)]
    pub fn poke(reg: u32, v: u32) {
        // SAFETY: the addresses and values of Nordic's errata workarounds.
        unsafe {
            if core::ptr::read_volatile(LOCK as *const u32) == 0 {
                core::ptr::write_volatile(LOCK as *mut u32, KEY);
                core::ptr::write_volatile(reg as *mut u32, v);
                core::ptr::write_volatile(LOCK as *mut u32, KEY);
            } else {
                core::ptr::write_volatile(reg as *mut u32, v);
            }
        }
    }

    /// Erratum 199's register (a plain USBD register).
    pub fn dma(on: bool) {
        // SAFETY: as nrfx's usbd_dma_pending_set/clear.
        unsafe { core::ptr::write_volatile(E199 as *mut u32, if on { 0x82 } else { 0 }) }
    }
}

/// Where the USBD is in its start and stop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Link {
    /// Disabled.
    Off {
        /// The next start not before this time.
        next_try: Time,
    },
    /// Waiting for READY and OUTPUTRDY.
    Enabling {
        /// When ENABLE was written.
        since: Time,
    },
    /// Enabled, pull-up connected.
    Up,
}

/// What one [`Link::handle_tick`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Step {
    /// Nothing new.
    Idle,
    /// READY and OUTPUTRDY are there: end the errata sequences and connect.
    Ready,
    /// The start timed out (the USBD is disabled again).
    Failed(Error),
    /// VBUS went: the USBD is disabled.
    Stopped,
}

impl Link {
    /// Disabled, to start at once.
    pub const fn new() -> Self {
        Link::Off { next_try: Time::ZERO }
    }

    /// Advances at `now`: starts on VBUS, waits (bounded) for READY and OUTPUTRDY, stops
    /// without VBUS.
    pub fn handle_tick(&mut self, now: Time, power: &pac::POWER) -> Step {
        let vbus = vbus(power);
        match *self {
            Link::Off { next_try } if vbus && now >= next_try => {
                errata::poke(errata::E187_211, 3);
                errata::poke(errata::E171, 0xC0);
                usbd().enable.write(|w| w.enable().enabled());
                *self = Link::Enabling { since: now };
                Step::Idle
            }
            Link::Enabling { .. } | Link::Up if !vbus => {
                disable();
                *self = Link::Off { next_try: now };
                Step::Stopped
            }
            Link::Enabling { since } => {
                let ready = usbd().eventcause.read().ready().is_ready();
                let regulator = power.usbregstatus.read().outputrdy().bit_is_set();
                if ready && regulator {
                    *self = Link::Up;
                    Step::Ready
                } else if now.since(since) > START_TIMEOUT_S {
                    disable();
                    *self = Link::Off { next_try: now.plus_s(RETRY_S) };
                    Step::Failed(Error { ready, regulator })
                } else {
                    Step::Idle
                }
            }
            _ => Step::Idle,
        }
    }
}

impl Default for Link {
    fn default() -> Self {
        Self::new()
    }
}

/// The end of nrfx's enable after READY (what `nrf-usbd`'s `enable` does the first time):
/// READY cleared, errata 171 and 187 ended, erratum 211 begun, the pull-up connected.
fn connect() {
    usbd().eventcause.write(|w| w.ready().clear_bit_by_one());
    errata::poke(errata::E171, 0);
    errata::poke(errata::E187_211, 0);
    errata::poke(errata::E187_211, 3);
    usbd().usbpullup.write(|w| w.connect().enabled());
}

/// The pull-up disconnected, the USBD disabled (its registers to reset values), erratum 211
/// ended.
fn disable() {
    usbd().usbpullup.write(|w| w.connect().disabled());
    usbd().enable.write(|w| w.enable().disabled());
    errata::poke(errata::E187_211, 0);
}

/// The USB serial number: FICR.DEVICEADDR[1] and [0] as 16 hex digits, as Arduino's core
/// (ArduinoCore-mbed's USB PluggableUSBDevice) makes it, so that two boards are two ports.
pub fn serial_number(ficr: &pac::FICR) -> &'static str {
    use core::fmt::Write;
    let Some(s) = cortex_m::singleton!(: heapless::String<16> = heapless::String::new()) else {
        return "";
    };
    // 16 hex digits always fit.
    let _ = write!(s, "{}{}", Hex(ficr.deviceaddr[1].read().bits(), 8), Hex(ficr.deviceaddr[0].read().bits(), 8));
    s.as_str()
}

/// The serial port.
pub struct Usb {
    dev: UsbDevice<'static, Bus>,
    acm: CdcAcmClass<'static, Bus>,
    /// Lines waiting for the host.
    pub out: Outbox<OUTBOX>,
    touch: Touch,
    /// Reconnected after a stop: `usb-device` still holds the old session until the host's bus
    /// reset, and the endpoints are disabled: nothing is sent before that reset.
    awaiting_reset: bool,
}

impl Usb {
    /// Builds the port once [`Link::handle_tick`] said [`Step::Ready`] for the first time: at
    /// most once (the USBD is owned for good; the port, its 4 KiB outbox included, in static
    /// RAM). The HFXO, which the USBD needs on the bus, runs already.
    #[inline(never)]
    #[allow(clippy::mut_from_ref)] // the port is a singleton, not borrowed from `serial`
    pub fn build(usbd: pac::USBD, serial: &'static str) -> &'static mut Self {
        let Some(alloc) = cortex_m::singleton!(: UsbBusAllocator<Bus> = UsbBusAllocator::new(nrf_usbd::Usbd::new(Usbd0(usbd)))) else {
            cortex_m::peripheral::SCB::sys_reset();
        };
        let alloc: &'static UsbBusAllocator<Bus> = alloc;
        let acm = CdcAcmClass::new(alloc, PACKET as u16);
        let strings = [StringDescriptors::default().manufacturer(MANUFACTURER).product(PRODUCT).serial_number(serial)];
        let builder = UsbDeviceBuilder::new(alloc, UsbVidPid(VID_PID.0, VID_PID.1))
            .device_class(usbd_serial::USB_CLASS_CDC)
            .max_power(100)
            .and_then(|b| b.strings(&strings))
            .and_then(|b| b.max_packet_size_0(PACKET as u8));
        let Ok(builder) = builder else {
            // Constant arguments within usb-device's limits: unreachable.
            cortex_m::peripheral::SCB::sys_reset();
        };
        // nrf-usbd's enable: READY is set, so its spin ends at once; it connects the pull-up.
        let dev = builder.build();
        errata::poke(errata::E187_211, 3);
        match cortex_m::singleton!(: Usb = Usb { dev, acm, out: Outbox::new(), touch: Touch::default(), awaiting_reset: false }) {
            Some(usb) => usb,
            None => cortex_m::peripheral::SCB::sys_reset(),
        }
    }

    /// After a restart ([`Step::Ready`] again): connects; the host's bus reset re-initialises
    /// `usb-device`.
    pub fn reconnect(&mut self) {
        self.out.clear();
        self.awaiting_reset = true;
        connect();
    }

    /// Whether a terminal has the port open (configured, DTR set): lines are queued only then.
    pub fn listening(&self) -> bool {
        !self.awaiting_reset && self.dev.state() == UsbDeviceState::Configured && self.acm.dtr()
    }

    /// Queues a line for the host if a terminal listens (see [`Outbox::push_line`]).
    pub fn line(&mut self, line: &str) {
        if self.listening() {
            self.out.push_line(line);
        }
    }

    /// Serves the bus while the link is up (call every loop tick, at `now`): control
    /// requests, received commands (each handed to `command`), queued lines out. True once the
    /// 1200-baud touch is complete (the caller enters the bootloader).
    #[inline(never)]
    pub fn poll(&mut self, now: Time, mut command: impl FnMut(Command)) -> bool {
        errata::dma(true);
        self.dev.poll(&mut [&mut self.acm]);
        if self.dev.state() != UsbDeviceState::Configured {
            self.awaiting_reset = false;
        }
        let mut buf = [0u8; PACKET];
        if let Some(n) = read_out(self.acm.read_ep().address().index(), &mut buf) {
            buf[..n].iter().filter_map(|&b| Command::decode(b)).for_each(&mut command);
        }
        if !self.listening() {
            self.out.clear();
        }
        for _ in 0..PACKETS_PER_POLL {
            let Some(chunk) = self.out.next_packet(PACKET) else { break };
            let zlp = chunk.is_empty();
            match self.acm.write_packet(chunk) {
                Ok(n) => self.out.sent(n, PACKET),
                Err(_) => break,
            }
            if zlp {
                break;
            }
        }
        errata::dma(false);
        self.touch.update(now, self.acm.line_coding().data_rate(), self.acm.dtr())
    }

    /// The link went down: nothing queued survives (counted as dropped).
    pub fn stopped(&mut self) {
        self.out.clear();
    }
}

/// The button pin (P1.11, to ground), the wake-up source of [`enter_bootloader`].
const WAKE_PIN: usize = 11;
/// Polls after SYSTEMOFF before the fallback reset (~20 ms at 64 MHz): under a debugger System
/// OFF is only emulated and the CPU runs on (PS §5.3.2 "Emulated System OFF mode").
const EMULATED_OFF_POLLS: u32 = 300_000;

/// Leaves the application for the stock bootloader's serial (SAM-BA) mode without handing it
/// the running watchdog, which it never feeds (its image has no WDT code) and which a soft
/// reset keeps (PS §5.3.6, reset behaviour): GPREGRET = 0xB0 (retained in System OFF and
/// through its wake-up reset), then System OFF with a wake-up that is already due: P1.11 with
/// its pull-up and SENSE = high, which reads high unless the button is held (then the board
/// wakes when it is released). The wake from System OFF is a reset that resets the watchdog.
/// Under a debugger (emulated System OFF) it ends in a soft reset after
/// [`EMULATED_OFF_POLLS`].
pub fn enter_bootloader(power: &pac::POWER) -> ! {
    // SAFETY: plain register writes on the way out; nothing else runs after them.
    unsafe {
        power.gpregret.write(|w| w.bits(GPREGRET_SERIAL_BOOTLOADER));
        (*pac::P1::ptr()).pin_cnf[WAKE_PIN].write(|w| w.dir().input().input().connect().pull().pullup().sense().high());
        power.systemoff.write(|w| w.systemoff().enter());
    }
    cortex_m::asm::dsb();
    for _ in 0..EMULATED_OFF_POLLS {
        cortex_m::asm::nop();
    }
    cortex_m::peripheral::SCB::sys_reset()
}
