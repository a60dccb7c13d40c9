//! USBD, the full-speed USB device controller (nRF52840 PS v1.7 §6.35; base 0x40027000, IRQ 39),
//! register side and bus side. The bus side ([`Usbd::setup`], [`Usbd::in_token`],
//! [`Usbd::out_token`], [`Usbd::bus_reset`], [`Usbd::sof`]) is driven by the virtual host
//! (`crate::usb_host`); it answers as the part's serial interface engine does: ACK, NAK, STALL or
//! nothing.
//!
//! What the part does and the model enforces:
//! - EVENTCAUSE.READY (with EVENTS_USBEVENT) comes [`READY_S`] after ENABLE = 1, and only while
//!   VBUS is present (POWER.USBREGSTATUS.VBUSDETECT); the HFXO is not needed for it (nrfx's
//!   `nrfx_usbd_enable` waits for READY before Zephyr's driver requests the HFXO). ENABLE = 0
//!   returns the peripheral to its reset state. ENABLE also switches the USB regulator on (POWER
//!   model). The pull-up (USBPULLUP) may only be connected once READY was seen; the host sees
//!   the device only with VBUS, the regulator's output ready (it powers the pull-up), the pull-up
//!   and the HFXO running.
//! - Erratum 187 ("USB cannot be enabled", every nRF52840 revision but engineering A): READY
//!   comes only if 0x4006ED14 held 3 when ENABLE was written. The undocumented registers
//!   0x4006EC14 and 0x4006ED14 take a write only while unlocked: 0x4006EC00 reads 0 while locked,
//!   and each write of 0x9375 to it toggles the lock (nrfx's `nrf52_errata_187/171` sequences:
//!   `if (*0x4006EC00 == 0) *0x4006EC00 = 0x9375; reg = v; *0x4006EC00 = 0x9375;`); a write while
//!   locked is ignored and counted ([`Usbd::locked_writes`]). 0x40027C1C (erratum 199's
//!   register, 0x82 during EasyDMA) is stored.
//! - VBUS removed while enabled: the bus state goes (address, control transfer, endpoint
//!   buffers, halts, toggles, as a bus reset without its event); the registers stay; POWER raises
//!   USBREMOVED and drops the regulator.
//! - Tasks need ENABLE = 1 (else the run stops). STARTEPIN[n]/STARTEPOUT[n] need the endpoint
//!   enabled (EPINEN/EPOUTEN), MAXCNT ≤ 64 and, when MAXCNT > 0, PTR..PTR+MAXCNT in Data RAM
//!   (EasyDMA reaches only RAM); a zero-length IN (MAXCNT = 0, any PTR: nrf-usbd writes 0) is a
//!   ZLP. STARTEPOUT[n] needs a packet in the endpoint buffer (after EPDATA / EP0DATADONE).
//!   EasyDMA is instantaneous: STARTED, EPSTATUS (the registers are captured) and ENDEPIN/ENDEPOUT
//!   are set by the task itself. ISO tasks are not modelled (they stop the run).
//! - Control endpoint: the SETUP stage is always ACKed (BMREQUESTTYPE..WLENGTHH, EP0SETUP); it
//!   clears EP0STALL. IN data stage: NAK until STARTEPIN[0] loaded a packet; the host's ACK raises
//!   EP0DATADONE. OUT data stage: NAK until TASKS_EP0RCVOUT; the ACKed packet raises EP0DATADONE
//!   with its size in SIZE.EPOUT[0] (one packet per EP0RCVOUT). Status stage: NAK until
//!   TASKS_EP0STATUS (no event when it completes). SET_ADDRESS is handled by the hardware: its
//!   status stage completes without EP0STATUS and USBADDR takes the address then. TASKS_EP0STALL
//!   stalls the data and status stages until the next SETUP. SHORTS EP0DATADONE_EP0STATUS,
//!   ENDEPOUT0_EP0STATUS and ENDEPOUT0_EP0RCVOUT work; EP0DATADONE_STARTEPIN0/STARTEPOUT0 (DMA
//!   started by the bus) are not modelled and stop the run when they would fire.
//! - Bulk/interrupt IN n (1–7): NAK until STARTEPIN[n] loaded a packet; the host's ACK sets
//!   EPDATASTATUS.EPINn and EVENTS_EPDATA. A second STARTEPIN before the host took the first
//!   packet replaces it (counted in [`Usbd::in_overwrites`]).
//! - Bulk/interrupt OUT n (1–7): NAK until armed by a write to SIZE.EPOUT[n] (after reset and
//!   ENABLE the endpoint NAKs) or by the end of the EasyDMA of the previous packet (ENDEPOUT[n]);
//!   the ACKed packet sets EPDATASTATUS.EPOUTn, SIZE.EPOUT[n] and EVENTS_EPDATA, and the endpoint
//!   NAKs until STARTEPOUT[n]. A SIZE.EPOUT[n] write while a packet waits discards it (counted in
//!   [`Usbd::discarded_out`], embassy-rs/embassy#6688).
//! - Endpoints not enabled in EPINEN/EPOUTEN do not answer at all; EPSTALL halts (STALL
//!   handshake, HALTED.EPIN/EPOUT); data toggles per endpoint (DTOGGLE reads/sets them; a bus
//!   reset sets DATA0); a packet whose toggle repeats the last one is ACKed and dropped.
//! - A bus reset: EVENTS_USBRESET, USBADDR = 0, the control transfer abandoned, IN buffers
//!   emptied, OUT endpoints NAKing until re-armed, halts and toggles cleared. SOF (every 1 ms
//!   from the host): EVENTS_SOF and FRAMECNTR (11 bits).
//! - EVENTCAUSE, EPSTATUS, EPDATASTATUS are write-1-to-clear; events are set by the part and
//!   written 0 (or 1) by software; the interrupt line is (events & INTEN) ≠ 0 (a level).
//!
//! Not modelled: suspend/resume (the host never stops SOFs; EVENTCAUSE.SUSPEND/RESUME stay 0,
//! LOWPOWER is stored), remote wake-up, DPDMDRIVE/DPDMNODRIVE (accepted, no effect), ISO
//! endpoints, errata 171/199/211's symptoms (their registers are accepted).

use super::Access;

/// Time from ENABLE = 1 (with VBUS and the HFXO) to EVENTCAUSE.READY (s): a model value, a few
/// microseconds.
pub const READY_S: f64 = 10e-6;
/// Largest packet of a bulk/interrupt/control endpoint (bytes, full speed).
pub const MAX_PACKET: u32 = 64;
/// Data RAM (EasyDMA's reach): [start, end).
pub const RAM: (u32, u32) = (0x2000_0000, 0x2004_0000);

// Event indices ((offset - 0x100) / 4), also the INTEN bits.
/// EVENTS_USBRESET.
pub const EV_USBRESET: u32 = 0;
/// EVENTS_STARTED.
pub const EV_STARTED: u32 = 1;
/// EVENTS_ENDEPIN[0] (ENDEPIN[n] = 2 + n).
pub const EV_ENDEPIN0: u32 = 2;
/// EVENTS_EP0DATADONE.
pub const EV_EP0DATADONE: u32 = 10;
/// EVENTS_ENDEPOUT[0] (ENDEPOUT[n] = 12 + n).
pub const EV_ENDEPOUT0: u32 = 12;
/// EVENTS_SOF.
pub const EV_SOF: u32 = 21;
/// EVENTS_USBEVENT.
pub const EV_USBEVENT: u32 = 22;
/// EVENTS_EP0SETUP.
pub const EV_EP0SETUP: u32 = 23;
/// EVENTS_EPDATA.
pub const EV_EPDATA: u32 = 24;

/// EVENTCAUSE.READY.
pub const CAUSE_READY: u32 = 1 << 11;

// SHORTS bits.
const EP0DATADONE_STARTEPIN0: u32 = 1 << 0;
const EP0DATADONE_STARTEPOUT0: u32 = 1 << 1;
const EP0DATADONE_EP0STATUS: u32 = 1 << 2;
const ENDEPOUT0_EP0STATUS: u32 = 1 << 3;
const ENDEPOUT0_EP0RCVOUT: u32 = 1 << 4;

// Register offsets (PS §6.35.13).
const TASKS_STARTEPIN0: u32 = 0x004;
const TASKS_STARTISOIN: u32 = 0x024;
const TASKS_STARTEPOUT0: u32 = 0x028;
const TASKS_STARTISOOUT: u32 = 0x048;
const TASKS_EP0RCVOUT: u32 = 0x04C;
const TASKS_EP0STATUS: u32 = 0x050;
const TASKS_EP0STALL: u32 = 0x054;
const TASKS_DPDMDRIVE: u32 = 0x058;
const TASKS_DPDMNODRIVE: u32 = 0x05C;
const EVENTS: u32 = 0x100;
const EVENTS_LAST: u32 = 0x160;
const SHORTS: u32 = 0x200;
const INTEN: u32 = 0x300;
const INTENSET: u32 = 0x304;
const INTENCLR: u32 = 0x308;
const EVENTCAUSE: u32 = 0x400;
const HALTED_EPIN0: u32 = 0x420;
const HALTED_EPOUT0: u32 = 0x444;
const EPSTATUS: u32 = 0x468;
const EPDATASTATUS: u32 = 0x46C;
const USBADDR: u32 = 0x470;
const BMREQUESTTYPE: u32 = 0x480;
const WLENGTHH: u32 = 0x49C;
const SIZE_EPOUT0: u32 = 0x4A0;
const SIZE_ISOOUT: u32 = 0x4C0;
const ENABLE: u32 = 0x500;
const USBPULLUP: u32 = 0x504;
const DPDMVALUE: u32 = 0x508;
const DTOGGLE: u32 = 0x50C;
const EPINEN: u32 = 0x510;
const EPOUTEN: u32 = 0x514;
const EPSTALL: u32 = 0x518;
const ISOSPLIT: u32 = 0x51C;
const FRAMECNTR: u32 = 0x520;
const LOWPOWER: u32 = 0x52C;
const ISOINCONFIG: u32 = 0x530;
const EPIN0: u32 = 0x600;
const ISOIN: u32 = 0x6A0;
const EPOUT0: u32 = 0x700;
const ISOOUT: u32 = 0x7A0;
const EP_STRIDE: u32 = 0x14;

/// 0x4006EC00's unlock/lock key.
const ERRATA_KEY: u32 = 0x9375;
/// USBD offset of erratum 199's register (0x40027C1C).
const ERRATA_199: u32 = 0xC1C;
/// Address block and offsets of the undocumented registers nrf-usbd pokes (errata 171, 187).
pub const ERRATA_BLOCK: u32 = 0x4006_E000;
const ERRATA_REGS: [u32; 3] = [0xC00, 0xC14, 0xD14];

/// The handshake (or silence) the device answers a token with.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Handshake {
    /// Data accepted (OUT, SETUP), or the data stage / status stage done.
    Ack,
    /// Not ready: the host retries.
    Nak,
    /// The endpoint is halted (or the control request rejected).
    Stall,
    /// No answer: the device is not connected, not addressed, or the endpoint is not enabled.
    Silent,
}

/// A data packet the device sent for an IN token, with its data toggle (false = DATA0).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packet {
    /// The payload (0–64 bytes).
    pub data: Vec<u8>,
    /// DATA1 (true) or DATA0.
    pub toggle: bool,
}

/// A bulk/interrupt OUT endpoint's buffer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum OutBuf {
    /// Not armed: OUT tokens are NAKed.
    Nak,
    /// Armed: the next packet is ACKed.
    Armed,
    /// A packet waits for STARTEPOUT.
    Full(Vec<u8>),
}

/// Where the control endpoint is in the current transfer.
#[derive(Debug, Clone, Default)]
struct Ep0 {
    /// The SETUP of the current transfer (none after reset).
    setup: Option<[u8; 8]>,
    /// Packet loaded by STARTEPIN[0], waiting for an IN token.
    in_buf: Option<Vec<u8>>,
    /// EP0RCVOUT given: the next OUT data packet is ACKed.
    rcvout: bool,
    /// OUT data received, waiting for STARTEPOUT[0].
    out_buf: Option<Vec<u8>>,
    /// EP0STATUS given: the status stage is ACKed.
    status: bool,
    /// EP0STALL given: data and status stages STALL until the next SETUP.
    stall: bool,
}

/// USBD state.
#[derive(Debug, Clone)]
pub struct Usbd {
    /// ENABLE.
    pub enable: u32,
    /// USBPULLUP.
    pub pullup: u32,
    /// Time of ENABLE = 1 (s).
    enabled_at: Option<f64>,
    /// READY has been raised since ENABLE.
    ready_done: bool,
    eventcause: u32,
    events: u32,
    shorts: u32,
    inten: u32,
    epstatus: u32,
    epdatastatus: u32,
    /// USBADDR (set by the hardware at the status stage of SET_ADDRESS; 0 after reset).
    pub usbaddr: u8,
    setup_regs: [u8; 8],
    size_epout: [u32; 8],
    epinen: u32,
    epouten: u32,
    dtoggle_sel: u32,
    toggle_in: [bool; 8],
    toggle_out: [bool; 8],
    halted_in: u32,
    halted_out: u32,
    framecntr: u32,
    lowpower: u32,
    isosplit: u32,
    isoinconfig: u32,
    dpdmvalue: u32,
    epin: [[u32; 3]; 8],
    epout: [[u32; 3]; 8],
    isoin: [u32; 3],
    isoout: [u32; 3],
    size_isoout: u32,
    /// Bulk/interrupt IN buffers (index 0 unused: EP0 has its own state).
    in_buf: [Option<Vec<u8>>; 8],
    /// Bulk/interrupt OUT buffers (index 0 unused).
    pub out_buf: [OutBuf; 8],
    ep0: Ep0,
    /// SET_ADDRESS seen: the address taken at its status stage.
    pending_address: Option<u8>,
    errata: [u32; 3],
    /// 0x4006EC00's lock is open.
    errata_unlocked: bool,
    /// ENABLE was written with erratum 187's workaround in place (0x4006ED14 = 3).
    errata_187_ok: bool,
    /// Writes to 0x4006EC14/ED14 ignored because the lock was closed.
    pub locked_writes: u32,
    /// 0x40027C1C (erratum 199).
    errata_199: u32,
    /// VBUS was present at the last settle.
    had_vbus: bool,
    /// Incremented by every register write (the host retries NAKed tokens after a change).
    pub generation: u64,
    /// Time of the last register write (s).
    pub changed_at: f64,
    /// STARTEPIN[n] (n ≥ 1) given while the previous packet was still in the buffer.
    pub in_overwrites: u32,
    /// OUT packets discarded by a SIZE.EPOUT write before they were read.
    pub discarded_out: u32,
    /// Packets ACKed but dropped because their data toggle repeated the previous one.
    pub toggle_drops: u32,
}

impl Default for Usbd {
    fn default() -> Self {
        Self::new()
    }
}

/// Electrical conditions the USBD depends on.
#[derive(Debug, Clone, Copy)]
pub struct Phy {
    /// VBUS present (POWER.USBREGSTATUS.VBUSDETECT).
    pub vbus: bool,
    /// The USB regulator's output is ready (USBREGSTATUS.OUTPUTRDY).
    pub output_ready: bool,
    /// The HFXO runs.
    pub hfxo: bool,
}

impl Usbd {
    /// After reset.
    pub fn new() -> Self {
        Self {
            enable: 0,
            pullup: 0,
            enabled_at: None,
            ready_done: false,
            eventcause: 0,
            events: 0,
            shorts: 0,
            inten: 0,
            epstatus: 0,
            epdatastatus: 0,
            usbaddr: 0,
            setup_regs: [0; 8],
            size_epout: [0; 8],
            epinen: 1,
            epouten: 1,
            dtoggle_sel: 0,
            toggle_in: [false; 8],
            toggle_out: [false; 8],
            halted_in: 0,
            halted_out: 0,
            framecntr: 0,
            lowpower: 0,
            isosplit: 0,
            isoinconfig: 0,
            dpdmvalue: 0,
            epin: [[0; 3]; 8],
            epout: [[0; 3]; 8],
            isoin: [0; 3],
            isoout: [0; 3],
            size_isoout: 0,
            in_buf: Default::default(),
            out_buf: std::array::from_fn(|_| OutBuf::Nak),
            ep0: Ep0::default(),
            pending_address: None,
            errata: [0; 3],
            errata_unlocked: false,
            errata_187_ok: false,
            locked_writes: 0,
            errata_199: 0,
            had_vbus: false,
            generation: 0,
            changed_at: 0.0,
            in_overwrites: 0,
            discarded_out: 0,
            toggle_drops: 0,
        }
    }

    /// Whether event `ev` (an `EV_*` index) is set.
    pub fn event(&self, ev: u32) -> bool {
        self.events & (1 << ev) != 0
    }

    /// The interrupt line (IRQ 39): an event set whose INTEN bit is set.
    pub fn line(&self) -> bool {
        self.events & self.inten != 0
    }

    /// INTEN.
    pub fn inten(&self) -> u32 {
        self.inten
    }

    /// The host sees a device: enabled, READY seen, pull-up connected, VBUS with the regulator's
    /// output ready, HFXO.
    pub fn connected(&self, phy: Phy) -> bool {
        self.enable == 1 && self.ready_done && self.pullup == 1 && phy.vbus && phy.output_ready && phy.hfxo
    }

    /// When READY will be raised (s), if it is pending.
    pub fn ready_time(&self, phy: Phy) -> Option<f64> {
        match self.enabled_at {
            Some(t) if !self.ready_done && phy.vbus && self.errata_187_ok => Some(t + READY_S),
            _ => None,
        }
    }

    /// Raises READY when its time has come; drops the bus state when VBUS went.
    pub fn settle(&mut self, t: f64, phy: Phy) {
        if self.had_vbus && !phy.vbus {
            self.drop_bus_state();
        }
        self.had_vbus = phy.vbus;
        if let Some(r) = self.ready_time(phy) {
            if t >= r {
                self.ready_done = true;
                self.eventcause |= CAUSE_READY;
                self.events |= 1 << EV_USBEVENT;
            }
        } else if self.enable == 1 && !self.ready_done && !phy.vbus {
            // READY waits for VBUS: it comes READY_S after VBUS is there.
            self.enabled_at = Some(t);
        }
    }

    /// The bus state a bus reset or a VBUS loss clears.
    fn drop_bus_state(&mut self) {
        self.usbaddr = 0;
        self.ep0 = Ep0::default();
        self.pending_address = None;
        self.in_buf = Default::default();
        self.out_buf = std::array::from_fn(|_| OutBuf::Nak);
        self.toggle_in = [false; 8];
        self.toggle_out = [false; 8];
        self.halted_in = 0;
        self.halted_out = 0;
    }

    /// An access to the errata block 0x4006E000 at offset `o`: the three registers nrf-usbd
    /// pokes are stored and read back; anything else is unmodelled.
    pub fn errata_access(&mut self, o: u32, a: Access) -> Result<u32, String> {
        match (ERRATA_REGS.iter().position(|&r| r == o), a) {
            (Some(0), Access::Read) => Ok(u32::from(self.errata_unlocked)),
            (Some(0), Access::Write(v)) => {
                if v == ERRATA_KEY {
                    self.errata_unlocked = !self.errata_unlocked;
                }
                Ok(0)
            }
            (Some(i), Access::Write(v)) => {
                if self.errata_unlocked {
                    self.errata[i] = v;
                } else {
                    self.locked_writes += 1;
                }
                Ok(0)
            }
            (Some(i), Access::Read) => Ok(self.errata[i]),
            (None, _) => Err(format!("undocumented register 0x{:08X}", ERRATA_BLOCK + o)),
        }
    }

    /// The value of 0x4006ED14 (erratum 187: 3 while enabling; erratum 211: 3 while enabled).
    pub fn errata_ed14(&self) -> u32 {
        self.errata[2]
    }

    fn task_check(&self, name: &str) -> Result<(), String> {
        if self.enable != 1 {
            return Err(format!("USBD {name} while ENABLE = 0"));
        }
        Ok(())
    }

    /// A register access at offset `o`; `mem` is the EasyDMA's view of RAM.
    pub fn access(&mut self, o: u32, a: Access, t: f64, phy: Phy, mem: &mut dyn super::Dma) -> Result<u32, String> {
        self.settle(t, phy);
        let Access::Write(v) = a else { return self.read(o) };
        self.generation += 1;
        self.changed_at = t;
        let trig = v & 1 != 0;
        match o {
            o if (TASKS_STARTEPIN0..TASKS_STARTISOIN).contains(&o) => {
                if trig {
                    self.task_check("TASKS_STARTEPIN")?;
                    self.start_in(((o - TASKS_STARTEPIN0) / 4) as usize, mem)?;
                }
            }
            o if (TASKS_STARTEPOUT0..TASKS_STARTISOOUT).contains(&o) => {
                if trig {
                    self.task_check("TASKS_STARTEPOUT")?;
                    self.start_out(((o - TASKS_STARTEPOUT0) / 4) as usize, mem)?;
                }
            }
            TASKS_STARTISOIN | TASKS_STARTISOOUT => {
                if trig {
                    return Err("USBD isochronous endpoints are not modelled".into());
                }
            }
            TASKS_EP0RCVOUT => {
                if trig {
                    self.task_check("TASKS_EP0RCVOUT")?;
                    self.ep0.rcvout = true;
                }
            }
            TASKS_EP0STATUS => {
                if trig {
                    self.task_check("TASKS_EP0STATUS")?;
                    self.ep0.status = true;
                }
            }
            TASKS_EP0STALL => {
                if trig {
                    self.task_check("TASKS_EP0STALL")?;
                    self.ep0.stall = true;
                }
            }
            TASKS_DPDMDRIVE | TASKS_DPDMNODRIVE => {
                if trig {
                    self.task_check("TASKS_DPDM(NO)DRIVE")?;
                }
            }
            o if (EVENTS..=EVENTS_LAST).contains(&o) => {
                let bit = 1 << ((o - EVENTS) / 4);
                if trig {
                    self.events |= bit;
                } else {
                    self.events &= !bit;
                }
            }
            SHORTS => self.shorts = v & 0x1F,
            INTEN => self.inten = v & 0x1FF_FFFF,
            INTENSET => self.inten |= v & 0x1FF_FFFF,
            INTENCLR => self.inten &= !v,
            EVENTCAUSE => self.eventcause &= !v,
            EPSTATUS => self.epstatus &= !v,
            EPDATASTATUS => self.epdatastatus &= !v,
            o if (SIZE_EPOUT0..SIZE_EPOUT0 + 32).contains(&o) => {
                let n = ((o - SIZE_EPOUT0) / 4) as usize;
                self.size_epout[n] = 0;
                if n > 0 {
                    if matches!(self.out_buf[n], OutBuf::Full(_)) {
                        self.discarded_out += 1;
                        self.epdatastatus &= !(1 << (16 + n));
                    }
                    self.out_buf[n] = OutBuf::Armed;
                }
            }
            SIZE_ISOOUT => self.size_isoout = 0,
            ENABLE => {
                let was = self.enable;
                if v & 1 == 0 {
                    let keep = (self.errata, self.errata_unlocked, self.locked_writes, self.generation, self.changed_at);
                    let counts = (self.in_overwrites, self.discarded_out, self.toggle_drops, self.had_vbus);
                    *self = Self::new();
                    (self.errata, self.errata_unlocked, self.locked_writes, self.generation, self.changed_at) = keep;
                    (self.in_overwrites, self.discarded_out, self.toggle_drops, self.had_vbus) = counts;
                } else if was == 0 {
                    self.enable = 1;
                    self.enabled_at = Some(t);
                    self.errata_187_ok = self.errata[2] == 3;
                    self.settle(t, phy);
                }
            }
            USBPULLUP => {
                if v & 1 == 1 && !(self.enable == 1 && self.ready_done) {
                    return Err("USBD USBPULLUP connected before ENABLE = 1 and EVENTCAUSE.READY".into());
                }
                self.pullup = v & 1;
            }
            DPDMVALUE => self.dpdmvalue = v & 0x1F,
            DTOGGLE => {
                self.dtoggle_sel = v & 0x87;
                let (ep, is_in) = ((v & 7) as usize, v & 0x80 != 0);
                let t = if is_in { &mut self.toggle_in[ep] } else { &mut self.toggle_out[ep] };
                match (v >> 8) & 3 {
                    1 => *t = false,
                    2 => *t = true,
                    _ => {}
                }
            }
            EPINEN => self.epinen = v & 0x1FF,
            EPOUTEN => self.epouten = v & 0x1FF,
            EPSTALL => {
                let (ep, is_in, stall) = (v & 7, v & 0x80 != 0, v & 0x100 != 0);
                let h = if is_in { &mut self.halted_in } else { &mut self.halted_out };
                if stall {
                    *h |= 1 << ep;
                } else {
                    *h &= !(1 << ep);
                }
            }
            ISOSPLIT => self.isosplit = v,
            ERRATA_199 => self.errata_199 = v,
            LOWPOWER => self.lowpower = v & 1,
            ISOINCONFIG => self.isoinconfig = v & 1,
            o if (EPIN0..ISOIN).contains(&o) => {
                let (n, r) = (((o - EPIN0) / EP_STRIDE) as usize, ((o - EPIN0) % EP_STRIDE) / 4);
                match r {
                    0 | 1 => self.epin[n][r as usize] = v,
                    2 => return Err("USBD EPIN.AMOUNT is read-only".into()),
                    _ => return Err(format!("USBD register 0x{o:03X}")),
                }
            }
            o if (EPOUT0..ISOOUT).contains(&o) => {
                let (n, r) = (((o - EPOUT0) / EP_STRIDE) as usize, ((o - EPOUT0) % EP_STRIDE) / 4);
                match r {
                    0 | 1 => self.epout[n][r as usize] = v,
                    2 => return Err("USBD EPOUT.AMOUNT is read-only".into()),
                    _ => return Err(format!("USBD register 0x{o:03X}")),
                }
            }
            o if (ISOIN..ISOIN + 12).contains(&o) => self.isoin[((o - ISOIN) / 4) as usize] = v,
            o if (ISOOUT..ISOOUT + 12).contains(&o) => self.isoout[((o - ISOOUT) / 4) as usize] = v,
            EVENTCAUSE..=USBADDR | BMREQUESTTYPE..=WLENGTHH | FRAMECNTR => {
                return Err(format!("USBD register 0x{o:03X} is read-only"));
            }
            _ => return Err(format!("USBD register 0x{o:03X}")),
        }
        Ok(0)
    }

    fn read(&mut self, o: u32) -> Result<u32, String> {
        Ok(match o {
            o if o < EVENTS => 0, // tasks read 0
            o if (EVENTS..=EVENTS_LAST).contains(&o) => u32::from(self.events & (1 << ((o - EVENTS) / 4)) != 0),
            SHORTS => self.shorts,
            INTEN | INTENSET | INTENCLR => self.inten,
            EVENTCAUSE => self.eventcause,
            o if (HALTED_EPIN0..HALTED_EPIN0 + 32).contains(&o) => {
                let n = (o - HALTED_EPIN0) / 4;
                let h = if n == 0 { self.ep0.stall } else { self.halted_in & (1 << n) != 0 };
                u32::from(h)
            }
            o if (HALTED_EPOUT0..HALTED_EPOUT0 + 32).contains(&o) => {
                let n = (o - HALTED_EPOUT0) / 4;
                let h = if n == 0 { self.ep0.stall } else { self.halted_out & (1 << n) != 0 };
                u32::from(h)
            }
            EPSTATUS => self.epstatus,
            EPDATASTATUS => self.epdatastatus,
            USBADDR => self.usbaddr as u32,
            o if (BMREQUESTTYPE..=WLENGTHH).contains(&o) => self.setup_regs[((o - BMREQUESTTYPE) / 4) as usize] as u32,
            o if (SIZE_EPOUT0..SIZE_EPOUT0 + 32).contains(&o) => self.size_epout[((o - SIZE_EPOUT0) / 4) as usize],
            SIZE_ISOOUT => self.size_isoout,
            ENABLE => self.enable,
            USBPULLUP => self.pullup,
            DPDMVALUE => self.dpdmvalue,
            DTOGGLE => {
                let (ep, is_in) = ((self.dtoggle_sel & 7) as usize, self.dtoggle_sel & 0x80 != 0);
                let t = if is_in { self.toggle_in[ep] } else { self.toggle_out[ep] };
                self.dtoggle_sel | (if t { 2 } else { 1 } << 8)
            }
            EPINEN => self.epinen,
            EPOUTEN => self.epouten,
            EPSTALL => 0, // write-only
            ISOSPLIT => self.isosplit,
            FRAMECNTR => self.framecntr,
            LOWPOWER => self.lowpower,
            ISOINCONFIG => self.isoinconfig,
            o if (EPIN0..ISOIN).contains(&o) => {
                let (n, r) = (((o - EPIN0) / EP_STRIDE) as usize, ((o - EPIN0) % EP_STRIDE) / 4);
                if r > 2 {
                    return Err(format!("USBD register 0x{o:03X}"));
                }
                self.epin[n][r as usize]
            }
            o if (EPOUT0..ISOOUT).contains(&o) => {
                let (n, r) = (((o - EPOUT0) / EP_STRIDE) as usize, ((o - EPOUT0) % EP_STRIDE) / 4);
                if r > 2 {
                    return Err(format!("USBD register 0x{o:03X}"));
                }
                self.epout[n][r as usize]
            }
            o if (ISOIN..ISOIN + 12).contains(&o) => self.isoin[((o - ISOIN) / 4) as usize],
            o if (ISOOUT..ISOOUT + 12).contains(&o) => self.isoout[((o - ISOOUT) / 4) as usize],
            ERRATA_199 => self.errata_199,
            _ => return Err(format!("USBD register 0x{o:03X}")),
        })
    }

    /// Checks an EasyDMA buffer: MAXCNT ≤ 64 and, when it moves bytes, inside Data RAM.
    fn dma_check(what: &str, n: usize, ptr: u32, maxcnt: u32) -> Result<(), String> {
        if maxcnt > MAX_PACKET {
            return Err(format!("USBD {what}[{n}].MAXCNT = {maxcnt} > 64"));
        }
        let end = ptr as u64 + maxcnt as u64;
        if maxcnt > 0 && !(ptr >= RAM.0 && end <= RAM.1 as u64) {
            return Err(format!("USBD {what}[{n}].PTR 0x{ptr:08X} (+{maxcnt}) is outside Data RAM (EasyDMA reaches only RAM)"));
        }
        Ok(())
    }

    /// STARTEPIN[n]: EasyDMA from RAM into the endpoint buffer.
    fn start_in(&mut self, n: usize, mem: &mut dyn super::Dma) -> Result<(), String> {
        if self.epinen & (1 << n) == 0 {
            return Err(format!("USBD TASKS_STARTEPIN[{n}] on an IN endpoint not enabled in EPINEN (0x{:03X})", self.epinen));
        }
        let [ptr, maxcnt, _] = self.epin[n];
        Self::dma_check("EPIN", n, ptr, maxcnt)?;
        let mut buf = vec![0u8; maxcnt as usize];
        if maxcnt > 0 {
            mem.read(ptr as u64, &mut buf);
        }
        self.epin[n][2] = maxcnt;
        if n == 0 {
            self.ep0.in_buf = Some(buf);
        } else {
            if self.in_buf[n].is_some() {
                self.in_overwrites += 1;
            }
            self.in_buf[n] = Some(buf);
        }
        self.epstatus |= 1 << n;
        self.events |= (1 << EV_STARTED) | (1 << (EV_ENDEPIN0 + n as u32));
        Ok(())
    }

    /// STARTEPOUT[n]: EasyDMA from the endpoint buffer into RAM.
    fn start_out(&mut self, n: usize, mem: &mut dyn super::Dma) -> Result<(), String> {
        if self.epouten & (1 << n) == 0 {
            return Err(format!("USBD TASKS_STARTEPOUT[{n}] on an OUT endpoint not enabled in EPOUTEN (0x{:03X})", self.epouten));
        }
        let [ptr, maxcnt, _] = self.epout[n];
        Self::dma_check("EPOUT", n, ptr, maxcnt)?;
        let data = if n == 0 {
            self.ep0.out_buf.take()
        } else {
            match std::mem::replace(&mut self.out_buf[n], OutBuf::Armed) {
                OutBuf::Full(d) => Some(d),
                other => {
                    self.out_buf[n] = other;
                    None
                }
            }
        };
        let Some(data) = data else {
            return Err(format!("USBD TASKS_STARTEPOUT[{n}] with no OUT packet received (the PS: only after EPDATA / EP0DATADONE)"));
        };
        let k = data.len().min(maxcnt as usize);
        if k > 0 {
            mem.write(ptr as u64, &data[..k]);
        }
        self.epout[n][2] = k as u32;
        self.epstatus |= 1 << (16 + n);
        self.events |= (1 << EV_STARTED) | (1 << (EV_ENDEPOUT0 + n as u32));
        if n == 0 {
            if self.shorts & ENDEPOUT0_EP0STATUS != 0 {
                self.ep0.status = true;
            }
            if self.shorts & ENDEPOUT0_EP0RCVOUT != 0 {
                self.ep0.rcvout = true;
            }
        }
        Ok(())
    }

    // ----- bus side (the host) -----

    /// The host drives a bus reset.
    pub fn bus_reset(&mut self, phy: Phy) {
        if !self.connected(phy) {
            return;
        }
        self.events |= 1 << EV_USBRESET;
        self.drop_bus_state();
    }

    /// Start of frame `frame` (11 bits).
    pub fn sof(&mut self, frame: u16, phy: Phy) {
        if self.connected(phy) {
            self.framecntr = (frame & 0x7FF) as u32;
            self.events |= 1 << EV_SOF;
        }
    }

    fn addressed(&self, addr: u8, phy: Phy) -> bool {
        self.connected(phy) && addr == self.usbaddr
    }

    /// A SETUP transaction to `addr` with this packet.
    pub fn setup(&mut self, addr: u8, pkt: [u8; 8], phy: Phy) -> Result<Handshake, String> {
        if !self.addressed(addr, phy) {
            return Ok(Handshake::Silent);
        }
        self.ep0 = Ep0 { setup: Some(pkt), ..Ep0::default() };
        self.setup_regs = pkt;
        self.pending_address = (pkt[0] == 0x00 && pkt[1] == 0x05).then_some(pkt[2] & 0x7F);
        self.events |= 1 << EV_EP0SETUP;
        Ok(Handshake::Ack)
    }

    fn ep0_done(&mut self) -> Result<(), String> {
        self.events |= 1 << EV_EP0DATADONE;
        if self.shorts & (EP0DATADONE_STARTEPIN0 | EP0DATADONE_STARTEPOUT0) != 0 {
            return Err("USBD SHORTS EP0DATADONE_STARTEPIN0/STARTEPOUT0 are not modelled".into());
        }
        if self.shorts & EP0DATADONE_EP0STATUS != 0 {
            self.ep0.status = true;
        }
        Ok(())
    }

    /// An IN token to `addr`, endpoint `ep`: the packet sent (the host ACKs it) or a handshake.
    pub fn in_token(&mut self, addr: u8, ep: usize, phy: Phy) -> Result<Result<Packet, Handshake>, String> {
        if !self.addressed(addr, phy) || ep > 7 || self.epinen & (1 << ep) == 0 {
            return Ok(Err(Handshake::Silent));
        }
        if ep == 0 {
            let Some(setup) = self.ep0.setup else { return Ok(Err(Handshake::Silent)) };
            if setup[0] & 0x80 == 0 {
                // Status stage of a control write / no-data request: a ZLP.
                if let Some(a) = self.pending_address {
                    self.usbaddr = a;
                    self.pending_address = None;
                    self.ep0.setup = None;
                    return Ok(Ok(Packet { data: vec![], toggle: true }));
                }
                if self.ep0.stall {
                    return Ok(Err(Handshake::Stall));
                }
                if self.ep0.status {
                    self.ep0.status = false;
                    self.ep0.setup = None;
                    return Ok(Ok(Packet { data: vec![], toggle: true }));
                }
                return Ok(Err(Handshake::Nak));
            }
            if self.ep0.stall {
                return Ok(Err(Handshake::Stall));
            }
            return match self.ep0.in_buf.take() {
                Some(data) => {
                    self.ep0_done()?;
                    Ok(Ok(Packet { data, toggle: true }))
                }
                None => Ok(Err(Handshake::Nak)),
            };
        }
        if self.halted_in & (1 << ep) != 0 {
            return Ok(Err(Handshake::Stall));
        }
        match self.in_buf[ep].take() {
            Some(data) => {
                let toggle = self.toggle_in[ep];
                self.toggle_in[ep] = !toggle;
                self.epdatastatus |= 1 << ep;
                self.events |= 1 << EV_EPDATA;
                Ok(Ok(Packet { data, toggle }))
            }
            None => Ok(Err(Handshake::Nak)),
        }
    }

    /// An OUT transaction to `addr`, endpoint `ep`, with `data` and its toggle.
    pub fn out_token(&mut self, addr: u8, ep: usize, data: &[u8], toggle: bool, phy: Phy) -> Result<Handshake, String> {
        if !self.addressed(addr, phy) || ep > 7 || self.epouten & (1 << ep) == 0 {
            return Ok(Handshake::Silent);
        }
        if ep == 0 {
            let Some(setup) = self.ep0.setup else { return Ok(Handshake::Silent) };
            if self.ep0.stall {
                return Ok(Handshake::Stall);
            }
            if setup[0] & 0x80 != 0 {
                // Status stage of a control read (a ZLP from the host).
                if self.ep0.status {
                    self.ep0.status = false;
                    self.ep0.setup = None;
                    return Ok(Handshake::Ack);
                }
                return Ok(Handshake::Nak);
            }
            if !self.ep0.rcvout || self.ep0.out_buf.is_some() {
                return Ok(Handshake::Nak);
            }
            self.ep0.rcvout = false;
            self.size_epout[0] = data.len() as u32;
            self.ep0.out_buf = Some(data.to_vec());
            self.ep0_done()?;
            return Ok(Handshake::Ack);
        }
        if self.halted_out & (1 << ep) != 0 {
            return Ok(Handshake::Stall);
        }
        if self.out_buf[ep] != OutBuf::Armed {
            return Ok(Handshake::Nak);
        }
        if toggle != self.toggle_out[ep] {
            self.toggle_drops += 1; // a repeated packet: ACKed, dropped
            return Ok(Handshake::Ack);
        }
        self.toggle_out[ep] = !toggle;
        self.size_epout[ep] = data.len() as u32;
        self.out_buf[ep] = OutBuf::Full(data.to_vec());
        self.epdatastatus |= 1 << (16 + ep);
        self.events |= 1 << EV_EPDATA;
        Ok(Handshake::Ack)
    }
}
