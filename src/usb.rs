//! USB CDC-ACM serial port on the USBD (nRF52840 PS v1.7 §6.35): `usb-device` and
//! `usbd-serial`'s `CdcAcmClass` over `nrf-usbd`, as nrf-hal's USB example uses them.
//!
//! - Only while VBUS is present (POWER.USBREGSTATUS): without a USB host the board runs the
//!   same, and [`Usb::start`] is retried by the caller.
//! - No unbounded wait: `nrf-usbd`'s enable spins on EVENTCAUSE.READY with no timeout, so
//!   [`Usb::start`] first enables the USBD itself and waits for READY for at most
//!   [`READY_POLLS`] polls, leaving READY set so that `nrf-usbd`'s spin ends at once. Its other
//!   waits are for EasyDMA (a 64 B endpoint copy, microseconds).
//! - Never blocks on the host: [`Usb::poll`] hands the host at most one packet per endpoint
//!   per call from the [`Outbox`]; lines that do not fit are dropped whole and counted.
//! - The 1200-baud touch ([`Touch`]) writes the bootloader's magic to GPREGRET and resets.

use crate::serial::{Command, Outbox, Touch, GPREGRET_SERIAL_BOOTLOADER};
use nrf52840_hal::pac;
use usb_device::bus::UsbBusAllocator;
use usb_device::device::{StringDescriptors, UsbDevice, UsbDeviceBuilder, UsbDeviceState, UsbVidPid};
use usbd_serial::CdcAcmClass;

/// The Nano 33 BLE's Arduino VID:PID (what the Arduino core enumerates as), so that Arduino's
/// tools and bossac find the port.
pub const VID_PID: (u16, u16) = (0x2341, 0x805A);
/// Bulk and EP0 packet size (B; full speed).
pub const PACKET: usize = 64;
/// Outbox size (B): 0.75 s of raw-log rows at 119 Hz (8.2 KB/s), more than the longest call
/// that does not poll USB (the solve, ≤ 0.5 s) with its report lines.
pub const OUTBOX: usize = 6144;
/// Polls of EVENTCAUSE.READY after ENABLE (≥ 1 ms at 64 MHz; the PS gives no figure, real
/// parts take microseconds).
pub const READY_POLLS: u32 = 20_000;
/// Packets handed to the bulk IN endpoint per [`Usb::poll`] at most (the endpoint takes one at
/// a time: the rest wait for the next poll).
const PACKETS_PER_POLL: usize = 4;

/// Why USB did not start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// No VBUS (no USB host, or only a battery).
    NoVbus,
    /// VBUS present but the USB regulator's output not ready yet (POWER.USBREGSTATUS.OUTPUTRDY).
    RegulatorNotReady,
    /// The USBD did not signal READY after ENABLE within [`READY_POLLS`].
    NotReady,
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

/// The serial port.
pub struct Usb {
    dev: UsbDevice<'static, Bus>,
    acm: CdcAcmClass<'static, Bus>,
    /// Lines waiting for the host.
    pub out: Outbox<OUTBOX>,
    touch: Touch,
}

impl Usb {
    /// Starts USB if VBUS is present and the USBD becomes ready (the caller keeps the HFXO
    /// running, which the USBD needs). At most once: on success the USBD is owned for good (the
    /// port, its 6 KiB outbox included, in static RAM); on failure it is disabled again and
    /// handed back.
    #[inline(never)]
    pub fn start(usbd: pac::USBD, power: &pac::POWER) -> Result<&'static mut Self, (Error, pac::USBD)> {
        if !vbus(power) {
            return Err((Error::NoVbus, usbd));
        }
        if !power.usbregstatus.read().outputrdy().bit_is_set() {
            return Err((Error::RegulatorNotReady, usbd));
        }
        // ENABLE with nrf-usbd's own errata 187/171 sequence around it (it repeats it, harmlessly).
        // SAFETY: the addresses and values of nrf-usbd's errata module (Nordic's workarounds).
        unsafe {
            for (a, v) in [(0x4006_EC00u32, 0x9375u32), (0x4006_ED14, 3), (0x4006_EC00, 0x9375), (0x4006_EC14, 0xC0), (0x4006_EC00, 0x9375)]
            {
                core::ptr::write_volatile(a as *mut u32, v);
            }
        }
        usbd.enable.write(|w| w.enable().enabled());
        if !(0..READY_POLLS).any(|_| usbd.eventcause.read().ready().is_ready()) {
            usbd.enable.write(|w| w.enable().disabled());
            return Err((Error::NotReady, usbd));
        }
        let Some(alloc) = cortex_m::singleton!(: UsbBusAllocator<Bus> = UsbBusAllocator::new(nrf_usbd::Usbd::new(Usbd0(usbd)))) else {
            cortex_m::peripheral::SCB::sys_reset();
        };
        let alloc: &'static UsbBusAllocator<Bus> = alloc;
        let acm = CdcAcmClass::new(alloc, PACKET as u16);
        let strings = [StringDescriptors::default().manufacturer("Arduino").product("gyrocal Nano 33 BLE")];
        let builder = UsbDeviceBuilder::new(alloc, UsbVidPid(VID_PID.0, VID_PID.1))
            .device_class(usbd_serial::USB_CLASS_CDC)
            .max_power(100)
            .and_then(|b| b.strings(&strings))
            .and_then(|b| b.max_packet_size_0(PACKET as u8));
        let Ok(builder) = builder else {
            // Constant arguments within usb-device's limits: unreachable.
            cortex_m::peripheral::SCB::sys_reset();
        };
        let dev = builder.build();
        match cortex_m::singleton!(: Usb = Usb { dev, acm, out: Outbox::new(), touch: Touch::default() }) {
            Some(usb) => Ok(usb),
            None => cortex_m::peripheral::SCB::sys_reset(),
        }
    }

    /// Whether a terminal has the port open (configured, DTR set): lines are queued only then.
    pub fn listening(&self) -> bool {
        self.dev.state() == UsbDeviceState::Configured && self.acm.dtr()
    }

    /// Queues a line for the host if a terminal listens (see [`Outbox::push_line`]).
    pub fn line(&mut self, line: &str) {
        if self.listening() {
            self.out.push_line(line);
        }
    }

    /// Serves the bus (call every loop tick, at `now_s` s): control requests, received
    /// commands (each handed to `command`), queued lines out, the 1200-baud touch. Without
    /// VBUS it only drops what is queued.
    #[inline(never)]
    pub fn poll(&mut self, power: &pac::POWER, now_s: f64, mut command: impl FnMut(Command)) {
        if !vbus(power) {
            self.out.clear();
            return;
        }
        self.dev.poll(&mut [&mut self.acm]);
        let mut buf = [0u8; PACKET];
        if let Ok(n) = self.acm.read_packet(&mut buf) {
            buf[..n].iter().filter_map(|&b| Command::decode(b)).for_each(&mut command);
        }
        if !self.listening() {
            self.out.clear();
        }
        for _ in 0..PACKETS_PER_POLL {
            let chunk = self.out.peek(PACKET);
            if chunk.is_empty() {
                break;
            }
            match self.acm.write_packet(chunk) {
                Ok(n) => self.out.consume(n),
                Err(_) => break,
            }
        }
        if self.touch.update(now_s, self.acm.line_coding().data_rate(), self.acm.dtr()) {
            // SAFETY: GPREGRET is retained across the soft reset; the bootloader reads it.
            power.gpregret.write(|w| unsafe { w.bits(GPREGRET_SERIAL_BOOTLOADER) });
            cortex_m::peripheral::SCB::sys_reset();
        }
    }
}
