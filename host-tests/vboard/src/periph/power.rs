//! POWER (nRF52840 PS v1.7 §5.3): RESETREAS (cumulative reset reasons, cleared by writing 1),
//! DCDCEN/DCDCEN0, POFCON, GPREGRET, RAM power, and the USB supply (§5.3.3 "USB regulator"):
//! VBUS plugged with [`Power::plug`] sets USBREGSTATUS.VBUSDETECT and EVENTS_USBDETECTED at
//! once. The USB regulator is switched on only "when the USBD peripheral is enabled through the
//! ENABLE register and VBUS is detected" (PS §5.3.3): USBREGSTATUS.OUTPUTRDY and
//! EVENTS_USBPWRRDY come [`USB_OUTPUTRDY_S`] after both hold ([`Power::set_usbd_enabled`]), and
//! go when either goes; the stock bootloader never enables the USBD before it jumps to the
//! application, so nothing is up at hand-over. [`Power::unplug`] clears VBUSDETECT and
//! OUTPUTRDY and sets EVENTS_USBREMOVED. The events are cleared by writing 0;
//! their INTEN bits (USBDETECTED 7, USBREMOVED 8, USBPWRRDY 9) live in the INTEN register shared
//! with CLOCK (the CLOCK model holds it). VBUS is physical: it survives every reset. The board
//! starts without VBUS. Shares its address block with CLOCK.

use super::{off, Access};

/// Time from VBUS with USBD.ENABLE = 1 to USBREGSTATUS.OUTPUTRDY (s): the USB regulator's
/// start-up. The nRF52840 PS gives no figure; the nRF5340 PS's t_USBPWRRDY is 1 ms.
pub const USB_OUTPUTRDY_S: f64 = 1e-3;
/// EVENTS_USBDETECTED's bit in `usb_events` and in INTEN.
pub const USBDETECTED: u32 = 1 << 7;
/// EVENTS_USBREMOVED's bit.
pub const USBREMOVED: u32 = 1 << 8;
/// EVENTS_USBPWRRDY's bit.
pub const USBPWRRDY: u32 = 1 << 9;

/// Why the chip reset (PS §5.3.6 "Reset behavior").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ResetKind {
    /// Power-on or brown-out: everything resets, RESETREAS reads 0.
    PowerOn,
    /// The reset pin (the Nano's RESET button): resets the WDT too; RESETREAS gets RESETPIN and,
    /// as erratum 136 says, another bit (SREQ).
    Pin,
    /// The watchdog fired: resets the WDT too.
    Watchdog,
    /// AIRCR.SYSRESETREQ: the WDT keeps running.
    Soft,
    /// CPU lock-up: the WDT keeps running.
    Lockup,
    /// Wake-up from System OFF: resets the WDT; GPREGRET and the GPIO configuration stay; RAM
    /// not retained (RAMn.POWER's retention bits) is lost (PS v1.7 §5.3.2 System OFF mode,
    /// §5.3.6 reset behaviour table).
    OffWake(Wake),
}

/// What woke the chip from System OFF (RESETREAS bit).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wake {
    /// GPIO DETECT (RESETREAS.OFF, bit 16).
    Detect,
    /// VBUS rising (RESETREAS.VBUS, bit 20).
    Vbus,
}

impl ResetKind {
    /// RESETREAS bit (0 for power-on, which clears the register).
    fn resetreas_bit(self) -> u32 {
        match self {
            ResetKind::PowerOn => 0,
            // Erratum 136: a pin reset may set other bits too (here SREQ).
            ResetKind::Pin => (1 << 0) | (1 << 2),
            ResetKind::Watchdog => 1 << 1,
            ResetKind::Soft => 1 << 2,
            ResetKind::Lockup => 1 << 3,
            ResetKind::OffWake(Wake::Detect) => 1 << 16,
            ResetKind::OffWake(Wake::Vbus) => 1 << 20,
        }
    }

    /// Whether this reset resets the watchdog (PS: not by soft reset or CPU lock-up).
    pub fn resets_wdt(self) -> bool {
        !matches!(self, ResetKind::Soft | ResetKind::Lockup)
    }
}

/// POWER state.
#[derive(Debug, Clone)]
pub struct Power {
    /// RESETREAS.
    pub resetreas: u32,
    /// RESETREAS as the firmware first read it after the last reset.
    pub resetreas_read: Option<u32>,
    /// DCDCEN (REG1 DC/DC).
    pub dcdcen: u32,
    /// DCDCEN0 (REG0 DC/DC).
    pub dcdcen0: u32,
    pofcon: u32,
    /// GPREGRET (retained through every reset but power-on).
    pub gpregret: u32,
    gpregret2: u32,
    inten: u32,
    ram_power: [u32; 9],
    /// VBUS present since this time (s); `None`: unplugged.
    pub vbus_since: Option<f64>,
    /// USBREGSTATUS.OUTPUTRDY.
    output_ready: bool,
    /// USBD.ENABLE = 1 (the regulator's other condition).
    usbd_enabled: bool,
    /// The regulator has been on (VBUS and USBD.ENABLE) since this time (s).
    regulator_since: Option<f64>,
    /// EVENTS_USBDETECTED/USBREMOVED/USBPWRRDY (bits as in INTEN).
    pub usb_events: u32,
    /// SYSTEMOFF was written (the board model decides what follows).
    pub system_off: bool,
}

impl Power {
    /// At power-on.
    pub fn new() -> Self {
        Self {
            resetreas: 0,
            resetreas_read: None,
            dcdcen: 0,
            dcdcen0: 0,
            pofcon: 0,
            gpregret: 0,
            gpregret2: 0,
            inten: 0,
            ram_power: [0xFFFF; 9],
            vbus_since: None,
            output_ready: false,
            usbd_enabled: false,
            regulator_since: None,
            usb_events: 0,
            system_off: false,
        }
    }

    /// USBD.ENABLE changed at time `t` (s): the regulator follows VBUS && ENABLE.
    pub fn set_usbd_enabled(&mut self, on: bool, t: f64) {
        self.settle(t);
        self.usbd_enabled = on;
        self.update_regulator(t);
    }

    fn update_regulator(&mut self, t: f64) {
        if self.usbd_enabled && self.vbus_since.is_some() {
            self.regulator_since.get_or_insert(t);
        } else {
            self.regulator_since = None;
            self.output_ready = false;
        }
    }

    /// VBUS is plugged in at time `t` (s).
    pub fn plug(&mut self, t: f64) {
        if self.vbus_since.is_none() {
            self.vbus_since = Some(t);
            self.usb_events |= USBDETECTED;
            self.update_regulator(t);
        }
    }

    /// VBUS is removed at time `t` (s).
    pub fn unplug(&mut self, t: f64) {
        self.settle(t);
        if self.vbus_since.take().is_some() {
            self.usb_events |= USBREMOVED;
            self.update_regulator(t);
        }
    }

    /// Raises OUTPUTRDY/USBPWRRDY when the regulator is up.
    pub fn settle(&mut self, t: f64) {
        if let Some(t0) = self.regulator_since {
            if !self.output_ready && t >= t0 + USB_OUTPUTRDY_S {
                self.output_ready = true;
                self.usb_events |= USBPWRRDY;
            }
        }
    }

    /// When OUTPUTRDY will come (s), if it is pending.
    pub fn output_ready_time(&self) -> Option<f64> {
        self.regulator_since.filter(|_| !self.output_ready).map(|t0| t0 + USB_OUTPUTRDY_S)
    }

    /// VBUS present (USBREGSTATUS.VBUSDETECT).
    pub fn vbus(&self) -> bool {
        self.vbus_since.is_some()
    }

    /// The USB regulator's output is ready (USBREGSTATUS.OUTPUTRDY).
    pub fn output_ready(&self) -> bool {
        self.output_ready
    }

    /// After a reset of `kind`: RESETREAS accumulates; GPREGRET and DCDCEN survive all but
    /// power-on (retained registers). Every reset resets the USBD, so the regulator goes off.
    pub fn reset(&mut self, kind: ResetKind) {
        let vbus = self.vbus_since;
        (self.usbd_enabled, self.regulator_since, self.output_ready) = (false, None, false);
        if kind == ResetKind::PowerOn {
            *self = Self::new();
            self.vbus_since = vbus;
        } else {
            self.usb_events = 0;
            self.system_off = false;
            self.resetreas |= kind.resetreas_bit();
            self.resetreas_read = None;
            self.pofcon = 0;
            self.inten = 0;
        }
    }

    /// Whether offset `o` of the 0x4000_0000 block is a POWER register.
    pub fn claims(o: u32) -> bool {
        let ram0 = off!(power, ram0);
        [
            off!(power, tasks_constlat),
            off!(power, tasks_lowpwr),
            off!(power, events_pofwarn),
            off!(power, events_sleepenter),
            off!(power, events_sleepexit),
            off!(power, events_usbdetected),
            off!(power, events_usbremoved),
            off!(power, events_usbpwrrdy),
            off!(power, resetreas),
            off!(power, ramstatus),
            off!(power, usbregstatus),
            off!(power, systemoff),
            off!(power, pofcon),
            off!(power, gpregret),
            off!(power, gpregret2),
            off!(power, dcdcen),
            off!(power, dcdcen0),
            off!(power, mainregstatus),
        ]
        .contains(&o)
            || (ram0..ram0 + 9 * 16).contains(&o)
        // INTENSET/INTENCLR are shared with CLOCK (one register): CLOCK models them.
    }

    /// A register access at offset `o` at time `t` (s).
    pub fn access(&mut self, o: u32, a: Access, t: f64) -> Result<u32, String> {
        self.settle(t);
        let ram0 = off!(power, ram0);
        let usb_event = [
            (off!(power, events_usbdetected), USBDETECTED),
            (off!(power, events_usbremoved), USBREMOVED),
            (off!(power, events_usbpwrrdy), USBPWRRDY),
        ]
        .iter()
        .find(|e| e.0 == o)
        .map(|e| e.1);
        Ok(match o {
            o if o == off!(power, tasks_constlat) || o == off!(power, tasks_lowpwr) => 0,
            _ if usb_event.is_some() => {
                let bit = usb_event.unwrap_or(0);
                if let Access::Write(v) = a {
                    if v & 1 != 0 {
                        self.usb_events |= bit;
                    } else {
                        self.usb_events &= !bit;
                    }
                }
                u32::from(self.usb_events & bit != 0)
            }
            o if o == off!(power, events_pofwarn) || o == off!(power, events_sleepenter) || o == off!(power, events_sleepexit) => 0,
            o if o == off!(power, resetreas) => {
                self.resetreas_read.get_or_insert(self.resetreas);
                if let Access::Write(v) = a {
                    self.resetreas &= !v; // write 1 to clear
                }
                self.resetreas
            }
            o if o == off!(power, ramstatus) => 0xF,
            o if o == off!(power, usbregstatus) => {
                if a.is_write() {
                    return Err("POWER.USBREGSTATUS is read-only".into());
                }
                u32::from(self.vbus()) | (u32::from(self.output_ready) << 1)
            }
            o if o == off!(power, systemoff) => match a {
                Access::Write(v) => {
                    self.system_off |= v & 1 != 0;
                    0
                }
                Access::Read => return Err("POWER.SYSTEMOFF is write-only".into()),
            },
            o if o == off!(power, pofcon) => a.rw(&mut self.pofcon),
            o if o == off!(power, gpregret) => a.rw(&mut self.gpregret),
            o if o == off!(power, gpregret2) => a.rw(&mut self.gpregret2),
            o if o == off!(power, dcdcen) => a.rw(&mut self.dcdcen),
            o if o == off!(power, dcdcen0) => a.rw(&mut self.dcdcen0),
            o if o == off!(power, mainregstatus) => 0, // normal voltage mode (VDD, not VDDH)
            o if (ram0..ram0 + 9 * 16).contains(&o) => {
                let (n, r) = (((o - ram0) / 16) as usize, (o - ram0) % 16);
                match (r, a) {
                    (0, a) => a.rw(&mut self.ram_power[n]),
                    (4, Access::Write(v)) => {
                        self.ram_power[n] |= v;
                        self.ram_power[n]
                    }
                    (8, Access::Write(v)) => {
                        self.ram_power[n] &= !v;
                        self.ram_power[n]
                    }
                    _ => self.ram_power[n],
                }
            }
            _ => {
                let _ = self.inten;
                return Err(format!("POWER register 0x{o:03X}"));
            }
        })
    }
}

impl Default for Power {
    fn default() -> Self {
        Self::new()
    }
}
