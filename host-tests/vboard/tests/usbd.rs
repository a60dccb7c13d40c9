//! The USBD and POWER USB models at the register level, and the virtual host against a small
//! register-level driver written here (what nrf-usbd + usb-device + usbd-serial do, reduced to
//! the requests the host sends): no firmware, fast.

use crate::common;

use common::{periph, r, w, wait, Ram};
use rig_sim::lsm_model::Board;
use std::cell::RefCell;
use std::rc::Rc;
use vboard::periph::usbd::{Handshake, OutBuf, Packet};
use vboard::periph::{Dma, Periph, ResetKind};
use vboard::usb_host::UsbHost;

const USBD: u64 = 0x4002_7000;
const POWER: u64 = 0x4000_0000;
const BUF: u32 = 0x2000_0100;

fn epin(n: u64) -> u64 {
    USBD + 0x600 + 0x14 * n
}

fn epout(n: u64) -> u64 {
    USBD + 0x700 + 0x14 * n
}

/// Takes what OUT endpoint `n` received (SIZE.EPOUT[n] bytes) by EasyDMA to RAM at `at`.
fn dma_out(p: &mut Periph, ram: &mut Ram, n: u64, at: u32) -> Vec<u8> {
    let size = r(p, USBD + 0x4A0 + 4 * n);
    w(p, ram, epout(n), at);
    w(p, ram, epout(n) + 4, size);
    w(p, ram, USBD + 0x028 + 4 * n, 1); // TASKS_STARTEPOUT[n]
    let mut d = vec![0u8; size as usize];
    ram.read(at as u64, &mut d);
    d
}

/// Writes an errata register as nrfx does: 0x4006EC00 reads 0 while locked; the key toggles.
fn errata(p: &mut Periph, ram: &mut Ram, reg: u64, v: u32) {
    if r(p, 0x4006_EC00) == 0 {
        w(p, ram, 0x4006_EC00, 0x9375);
        w(p, ram, reg, v);
        w(p, ram, 0x4006_EC00, 0x9375);
    } else {
        w(p, ram, reg, v);
    }
}

/// VBUS in, then nrfx's enable: errata 187 and 171 begun, ENABLE, READY and OUTPUTRDY waited
/// for, READY cleared, the errata ended, the pull-up connected.
fn enable(p: &mut Periph, ram: &mut Ram) {
    let t = p.now();
    p.power.plug(t);
    wait(p, 2e-3);
    errata(p, ram, 0x4006_ED14, 3);
    errata(p, ram, 0x4006_EC14, 0xC0);
    w(p, ram, USBD + 0x500, 1);
    wait(p, 1.1e-3);
    assert_ne!(r(p, USBD + 0x400) & (1 << 11), 0, "READY");
    assert_eq!(r(p, POWER + 0x438), 3, "VBUSDETECT and OUTPUTRDY");
    w(p, ram, USBD + 0x400, 1 << 11);
    errata(p, ram, 0x4006_EC14, 0);
    errata(p, ram, 0x4006_ED14, 0);
    w(p, ram, USBD + 0x504, 1);
}

#[test]
fn the_usb_regulator_needs_vbus_and_enable_and_ready_needs_erratum_187() {
    let (mut p, mut ram) = (periph(Board::Rev1, true), Ram::default());
    // No VBUS: READY never comes.
    assert_eq!(r(&mut p, POWER + 0x438), 0, "USBREGSTATUS");
    w(&mut p, &mut ram, USBD + 0x500, 1);
    wait(&mut p, 5e-3);
    assert_eq!(r(&mut p, USBD + 0x400), 0);
    // The pull-up before READY is rejected.
    w(&mut p, &mut ram, USBD + 0x504, 1);
    assert!(p.fault.take().is_some_and(|f| f.contains("READY")));
    w(&mut p, &mut ram, USBD + 0x500, 0);
    // VBUS with the USBD disabled: USBDETECTED and VBUSDETECT at once, but the regulator stays
    // off (the stock bootloader hands over in this state).
    let t = p.now();
    p.power.plug(t);
    assert_eq!(r(&mut p, POWER + 0x11C), 1, "USBDETECTED");
    wait(&mut p, 5e-3);
    assert_eq!((r(&mut p, POWER + 0x438), r(&mut p, POWER + 0x124)), (1, 0), "no OUTPUTRDY/USBPWRRDY without ENABLE");
    // ENABLE without erratum 187's workaround: the regulator comes up 1 ms later, READY never.
    w(&mut p, &mut ram, USBD + 0x500, 1);
    wait(&mut p, 0.9e-3);
    assert_eq!(r(&mut p, POWER + 0x438), 1, "not yet");
    wait(&mut p, 0.2e-3);
    assert_eq!((r(&mut p, POWER + 0x438), r(&mut p, POWER + 0x124)), (3, 1));
    wait(&mut p, 5e-3);
    assert_eq!(r(&mut p, USBD + 0x400) & (1 << 11), 0, "no READY: erratum 187");
    // ENABLE = 0 switches the regulator off again.
    w(&mut p, &mut ram, USBD + 0x500, 0);
    assert_eq!(r(&mut p, POWER + 0x438), 1);
    // A write to 0x4006ED14 while locked is ignored (0x4006EC00 reads 0: locked).
    assert_eq!(r(&mut p, 0x4006_EC00), 0);
    w(&mut p, &mut ram, 0x4006_ED14, 3);
    assert_eq!((r(&mut p, 0x4006_ED14), p.usbd.locked_writes), (0, 1));
    // nrfx's sequence: READY 10 µs after ENABLE, EVENTS_USBEVENT with it.
    errata(&mut p, &mut ram, 0x4006_ED14, 3);
    assert_eq!((r(&mut p, 0x4006_ED14), r(&mut p, 0x4006_EC00)), (3, 0), "written, locked again");
    w(&mut p, &mut ram, USBD + 0x500, 1);
    wait(&mut p, 20e-6);
    assert_ne!(r(&mut p, USBD + 0x400) & (1 << 11), 0, "READY");
    assert_eq!(r(&mut p, USBD + 0x158), 1, "EVENTS_USBEVENT");
    w(&mut p, &mut ram, USBD + 0x400, 1 << 11);
    assert_eq!(r(&mut p, USBD + 0x400), 0, "EVENTCAUSE is write-1-to-clear");
    // Unplug: USBREMOVED, USBREGSTATUS 0; the events clear by writing 0.
    w(&mut p, &mut ram, POWER + 0x11C, 0);
    let t = p.now();
    p.power.unplug(t);
    assert_eq!((r(&mut p, POWER + 0x438), r(&mut p, POWER + 0x120), r(&mut p, POWER + 0x11C)), (0, 1, 0));
    w(&mut p, &mut ram, POWER + 0x120, 0);
    assert_eq!(r(&mut p, POWER + 0x120), 0);
    // Plugged back with ENABLE still 1: the regulator comes up again.
    let t = p.now();
    p.power.plug(t);
    wait(&mut p, 1.1e-3);
    assert_eq!(r(&mut p, POWER + 0x438), 3);
    // The interrupt: INTENSET.USBREMOVED raises POWER_CLOCK (IRQ 0) on the next unplug.
    w(&mut p, &mut ram, POWER + 0x304, 1 << 8);
    let t = p.now();
    p.power.unplug(t);
    p.update();
    assert_ne!(p.scs.nvic_pending & 1, 0);
    // VBUS survives a soft reset (it is physical); GPREGRET too.
    let t = p.now();
    p.power.plug(t);
    w(&mut p, &mut ram, POWER + 0x51C, 0xB0);
    p.reset(ResetKind::Soft);
    assert_eq!((r(&mut p, POWER + 0x438) & 1, r(&mut p, POWER + 0x51C)), (1, 0xB0));

    // Cold boot: VBUS but no HFXO: READY comes (nrfx enables before Zephyr starts the HFXO),
    // but the host sees no device until the crystal runs.
    let (mut p, mut ram) = (periph(Board::Rev1, false), Ram::default());
    let t = p.now();
    p.power.plug(t);
    errata(&mut p, &mut ram, 0x4006_ED14, 3);
    w(&mut p, &mut ram, USBD + 0x500, 1);
    wait(&mut p, 2e-3);
    assert_ne!(r(&mut p, USBD + 0x400) & (1 << 11), 0, "READY without the HFXO");
    w(&mut p, &mut ram, USBD + 0x504, 1);
    assert!(!p.usbd.connected(p.usb_phy()), "no bus without the HFXO");
    w(&mut p, &mut ram, POWER, 1); // CLOCK TASKS_HFCLKSTART
    wait(&mut p, 1e-3);
    assert!(p.usbd.connected(p.usb_phy()));
    // READY with INTEN.USBEVENT raises IRQ 39 (NVIC word 1).
    w(&mut p, &mut ram, USBD + 0x304, 1 << 22);
    p.update();
    assert_ne!(p.scs.nvic_pending & (1 << 39), 0);
    assert_eq!(r(&mut p, 0xE000_E204) & (1 << 7), 1 << 7, "ISPR[1] bit 7");
    w(&mut p, &mut ram, 0xE000_E284, 1 << 7);
    assert_eq!(p.scs.nvic_pending & (1 << 39), 0, "ICPR[1]");
}

#[test]
fn ep0_setup_and_control_transfers_with_easydma() {
    let (mut p, mut ram) = (periph(Board::Rev1, true), Ram::default());
    enable(&mut p, &mut ram);
    let phy = p.usb_phy();
    assert!(p.usbd.connected(phy));
    p.usbd.bus_reset(phy);
    assert_eq!(r(&mut p, USBD + 0x100), 1, "EVENTS_USBRESET");
    // SETUP: GET_DESCRIPTOR(device, 64): registers and EP0SETUP.
    let get = [0x80, 6, 0, 1, 0, 0, 64, 0];
    assert_eq!(p.usbd.setup(0, get, phy), Ok(Handshake::Ack));
    assert_eq!(r(&mut p, USBD + 0x15C), 1);
    let regs: Vec<u32> = (0..8).map(|i| r(&mut p, USBD + 0x480 + 4 * i)).collect();
    assert_eq!(regs, get.iter().map(|&b| b as u32).collect::<Vec<_>>());
    // IN data stage: NAK until STARTEPIN[0]; EasyDMA from RAM.
    assert_eq!(p.usbd.in_token(0, 0, phy), Ok(Err(Handshake::Nak)));
    let desc: Vec<u8> = (0..18).collect();
    ram.write(BUF as u64, &desc);
    w(&mut p, &mut ram, epin(0), BUF);
    w(&mut p, &mut ram, epin(0) + 4, 18);
    w(&mut p, &mut ram, USBD + 0x200, 1 << 2); // SHORTS EP0DATADONE_EP0STATUS
    w(&mut p, &mut ram, USBD + 0x004, 1);
    assert_eq!((r(&mut p, USBD + 0x104), r(&mut p, USBD + 0x108)), (1, 1), "STARTED, ENDEPIN[0]");
    assert_eq!((r(&mut p, USBD + 0x468), r(&mut p, epin(0) + 8)), (1, 18), "EPSTATUS.EPIN0, AMOUNT");
    w(&mut p, &mut ram, USBD + 0x468, 1);
    assert_eq!(r(&mut p, USBD + 0x468), 0, "EPSTATUS is write-1-to-clear");
    assert_eq!(p.usbd.in_token(0, 0, phy), Ok(Ok(Packet { data: desc.clone(), toggle: true })));
    assert_eq!(r(&mut p, USBD + 0x128), 1, "EP0DATADONE");
    // Status stage: the short started EP0STATUS, so the host's ZLP is ACKed.
    assert_eq!(p.usbd.out_token(0, 0, &[], true, phy), Ok(Handshake::Ack));
    // Without the short: NAK until EP0STATUS.
    w(&mut p, &mut ram, USBD + 0x200, 0);
    p.usbd.setup(0, get, phy).unwrap();
    w(&mut p, &mut ram, USBD + 0x004, 1);
    assert!(p.usbd.in_token(0, 0, phy).unwrap().is_ok());
    assert_eq!(p.usbd.out_token(0, 0, &[], true, phy), Ok(Handshake::Nak));
    w(&mut p, &mut ram, USBD + 0x050, 1);
    assert_eq!(p.usbd.out_token(0, 0, &[], true, phy), Ok(Handshake::Ack));
    // EP0STALL: data stage STALLs until the next SETUP.
    p.usbd.setup(0, get, phy).unwrap();
    w(&mut p, &mut ram, USBD + 0x054, 1);
    assert_eq!(p.usbd.in_token(0, 0, phy), Ok(Err(Handshake::Stall)));
    assert_eq!(r(&mut p, USBD + 0x420), 1, "HALTED.EPIN[0]");
    p.usbd.setup(0, get, phy).unwrap();
    assert_eq!(p.usbd.in_token(0, 0, phy), Ok(Err(Handshake::Nak)));
    // Control write: SET_LINE_CODING (7 bytes): NAK until EP0RCVOUT, then EP0DATADONE, SIZE,
    // STARTEPOUT[0] into RAM, status NAK until EP0STATUS.
    let coding = [0x00, 0xC2, 0x01, 0x00, 0, 0, 8];
    p.usbd.setup(0, [0x21, 0x20, 0, 0, 0, 0, 7, 0], phy).unwrap();
    assert_eq!(p.usbd.out_token(0, 0, &coding, true, phy), Ok(Handshake::Nak));
    w(&mut p, &mut ram, USBD + 0x04C, 1);
    assert_eq!(p.usbd.out_token(0, 0, &coding, true, phy), Ok(Handshake::Ack));
    assert_eq!((r(&mut p, USBD + 0x128), r(&mut p, USBD + 0x4A0)), (1, 7));
    w(&mut p, &mut ram, epout(0), BUF + 0x100);
    w(&mut p, &mut ram, epout(0) + 4, 7);
    w(&mut p, &mut ram, USBD + 0x028, 1);
    assert_eq!((r(&mut p, USBD + 0x130), r(&mut p, epout(0) + 8)), (1, 7), "ENDEPOUT[0], AMOUNT");
    let mut got = [0u8; 7];
    ram.read((BUF + 0x100) as u64, &mut got);
    assert_eq!(got, coding);
    assert_eq!(p.usbd.in_token(0, 0, phy), Ok(Err(Handshake::Nak)), "status stage waits for EP0STATUS");
    w(&mut p, &mut ram, USBD + 0x050, 1);
    assert_eq!(p.usbd.in_token(0, 0, phy), Ok(Ok(Packet { data: vec![], toggle: true })));
    // SET_ADDRESS: the hardware completes the status stage and takes the address; the old
    // address is not answered any more.
    p.usbd.setup(0, [0x00, 5, 9, 0, 0, 0, 0, 0], phy).unwrap();
    assert_eq!(r(&mut p, USBD + 0x470), 0);
    assert_eq!(p.usbd.in_token(0, 0, phy), Ok(Ok(Packet { data: vec![], toggle: true })));
    assert_eq!(r(&mut p, USBD + 0x470), 9, "USBADDR");
    assert_eq!(p.usbd.setup(0, get, phy), Ok(Handshake::Silent));
    assert_eq!(p.usbd.setup(9, get, phy), Ok(Handshake::Ack));
    // A bus reset returns to address 0.
    p.usbd.bus_reset(phy);
    assert_eq!(r(&mut p, USBD + 0x470), 0);
    assert!(p.fault.is_none(), "{:?}", p.fault);
}

#[test]
fn bulk_in_and_out() {
    let (mut p, mut ram) = (periph(Board::Rev1, true), Ram::default());
    enable(&mut p, &mut ram);
    let phy = p.usb_phy();
    p.usbd.bus_reset(phy);
    w(&mut p, &mut ram, USBD + 0x510, 0b111); // EPINEN: 0, 1, 2
    w(&mut p, &mut ram, USBD + 0x514, 0b11); // EPOUTEN: 0, 1
                                             // Bulk IN 2: NAK until loaded; the host's ACK sets EPDATASTATUS.EPIN2 and EPDATA.
    assert_eq!(p.usbd.in_token(0, 2, phy), Ok(Err(Handshake::Nak)));
    let data: Vec<u8> = (0..64).map(|i| i as u8 ^ 0x5A).collect();
    ram.write(BUF as u64, &data);
    w(&mut p, &mut ram, epin(2), BUF);
    w(&mut p, &mut ram, epin(2) + 4, 64);
    w(&mut p, &mut ram, USBD + 0x00C, 1);
    assert_eq!(r(&mut p, USBD + 0x110), 1, "ENDEPIN[2]");
    assert_eq!(r(&mut p, USBD + 0x46C), 0, "not yet taken");
    assert_eq!(p.usbd.in_token(0, 2, phy), Ok(Ok(Packet { data: data.clone(), toggle: false })));
    assert_eq!((r(&mut p, USBD + 0x46C), r(&mut p, USBD + 0x160)), (1 << 2, 1));
    w(&mut p, &mut ram, USBD + 0x46C, 1 << 2);
    assert_eq!(r(&mut p, USBD + 0x46C), 0, "EPDATASTATUS is write-1-to-clear");
    assert_eq!(p.usbd.in_token(0, 2, phy), Ok(Err(Handshake::Nak)), "one packet per STARTEPIN");
    w(&mut p, &mut ram, USBD + 0x00C, 1);
    assert_eq!(p.usbd.in_token(0, 2, phy).unwrap().map(|p| p.toggle), Ok(true), "DATA1 next");
    w(&mut p, &mut ram, USBD + 0x46C, 1 << 2);
    // DTOGGLE reads and sets the toggle.
    w(&mut p, &mut ram, USBD + 0x50C, 0x82); // select IN 2
    assert_eq!(r(&mut p, USBD + 0x50C) >> 8, 1, "DATA0 again after two packets");
    w(&mut p, &mut ram, USBD + 0x50C, 0x82 | (2 << 8));
    assert_eq!(r(&mut p, USBD + 0x50C) >> 8, 2);
    // Bulk OUT 1: NAK until SIZE.EPOUT[1] is written; then one packet; DMA re-arms.
    assert_eq!(p.usbd.out_token(0, 1, b"hello", false, phy), Ok(Handshake::Nak));
    w(&mut p, &mut ram, USBD + 0x4A4, 0);
    assert_eq!(p.usbd.out_token(0, 1, b"hello", false, phy), Ok(Handshake::Ack));
    assert_eq!((r(&mut p, USBD + 0x46C), r(&mut p, USBD + 0x4A4)), (1 << 17, 5));
    assert_eq!(p.usbd.out_token(0, 1, b"world", true, phy), Ok(Handshake::Nak), "full until read");
    w(&mut p, &mut ram, USBD + 0x46C, 1 << 17);
    w(&mut p, &mut ram, epout(1), BUF + 0x200);
    w(&mut p, &mut ram, epout(1) + 4, 5);
    w(&mut p, &mut ram, USBD + 0x02C, 1);
    assert_eq!(r(&mut p, USBD + 0x134), 1, "ENDEPOUT[1]");
    let mut got = [0u8; 5];
    ram.read((BUF + 0x200) as u64, &mut got);
    assert_eq!(&got, b"hello");
    assert_eq!(p.usbd.out_token(0, 1, b"world", true, phy), Ok(Handshake::Ack), "re-armed by the DMA");
    // A repeated toggle is ACKed and dropped; a SIZE write discards an unread packet.
    w(&mut p, &mut ram, USBD + 0x02C, 1);
    assert_eq!(p.usbd.out_token(0, 1, b"again", true, phy), Ok(Handshake::Ack));
    assert_eq!((p.usbd.toggle_drops, p.usbd.out_buf[1].clone()), (1, OutBuf::Armed));
    p.usbd.out_token(0, 1, b"lost", false, phy).unwrap();
    w(&mut p, &mut ram, USBD + 0x4A4, 0);
    assert_eq!(p.usbd.discarded_out, 1);
    // EPSTALL halts; a disabled endpoint does not answer.
    w(&mut p, &mut ram, USBD + 0x518, 0x182);
    assert_eq!(p.usbd.in_token(0, 2, phy), Ok(Err(Handshake::Stall)));
    assert_eq!(r(&mut p, USBD + 0x428), 1, "HALTED.EPIN[2]");
    w(&mut p, &mut ram, USBD + 0x518, 0x082);
    assert_eq!(p.usbd.in_token(0, 2, phy), Ok(Err(Handshake::Nak)));
    assert_eq!(p.usbd.in_token(0, 3, phy), Ok(Err(Handshake::Silent)));
    // SOF: FRAMECNTR and EVENTS_SOF.
    p.usbd.sof(0x7FF, phy);
    assert_eq!((r(&mut p, USBD + 0x520), r(&mut p, USBD + 0x154)), (0x7FF, 1));
    assert!(p.fault.is_none(), "{:?}", p.fault);
}

#[test]
fn the_usbd_rejects_what_the_part_rejects() {
    type Case<'a> = (&'a str, &'a dyn Fn(&mut Periph, &mut Ram));
    let cases: [Case; 6] = [
        ("outside Data RAM", &|p, ram| {
            w(p, ram, epin(0), 0x0001_0000); // flash
            w(p, ram, epin(0) + 4, 8);
            w(p, ram, USBD + 0x004, 1);
        }),
        ("> 64", &|p, ram| {
            w(p, ram, epin(0), BUF);
            w(p, ram, epin(0) + 4, 65);
            w(p, ram, USBD + 0x004, 1);
        }),
        ("not enabled in EPINEN", &|p, ram| {
            w(p, ram, epin(3), BUF);
            w(p, ram, USBD + 0x010, 1);
        }),
        ("no OUT packet", &|p, ram| {
            w(p, ram, epout(0), BUF);
            w(p, ram, USBD + 0x028, 1);
        }),
        ("ENABLE = 0", &|p, ram| {
            w(p, ram, USBD + 0x500, 0);
            w(p, ram, USBD + 0x050, 1);
        }),
        ("read-only", &|p, ram| w(p, ram, USBD + 0x470, 5)),
    ];
    for (want, case) in cases {
        let (mut p, mut ram) = (periph(Board::Rev1, true), Ram::default());
        enable(&mut p, &mut ram);
        case(&mut p, &mut ram);
        assert!(p.fault.as_deref().is_some_and(|f| f.contains(want)), "{want}: {:?}", p.fault);
    }
    // A ZLP (MAXCNT 0) with PTR 0, as nrf-usbd writes it, is fine; the errata registers too.
    let (mut p, mut ram) = (periph(Board::Rev1, true), Ram::default());
    enable(&mut p, &mut ram);
    w(&mut p, &mut ram, epin(0), 0);
    w(&mut p, &mut ram, epin(0) + 4, 0);
    w(&mut p, &mut ram, USBD + 0x004, 1);
    w(&mut p, &mut ram, USBD + 0xC1C, 0x82); // erratum 199
    assert_eq!(r(&mut p, USBD + 0xC1C), 0x82);
    assert!(p.fault.is_none(), "{:?}", p.fault);
}

/// A register-level stand-in for nrf-usbd + usb-device + usbd-serial (the requests the host
/// sends, the descriptors the firmware has), polled every 2 ms like the firmware's main loop;
/// bulk OUT data is echoed upper-cased on bulk IN.
struct MiniFw {
    pending_in: Vec<u8>,
    echo: Vec<u8>,
    in_busy: bool,
    stall_string: Option<u8>,
    configured: bool,
    line: Vec<u8>,
    dtr: u16,
    dir_in: bool,
}

const DEVICE: [u8; 18] = [18, 1, 0x00, 0x02, 0xEF, 0x02, 0x01, 64, 0x41, 0x23, 0x5A, 0x80, 0x10, 0x00, 1, 2, 3, 1];

fn config() -> Vec<u8> {
    let mut c = vec![9, 2, 0, 0, 2, 1, 0, 0x80, 50];
    c.extend([8, 11, 0, 2, 2, 2, 0, 0]); // IAD
    c.extend([9, 4, 0, 0, 1, 2, 2, 0, 0]); // communication interface
    c.extend([5, 0x24, 0x00, 0x10, 0x01, 5, 0x24, 0x01, 0x00, 0x01, 4, 0x24, 0x02, 0x02, 5, 0x24, 0x06, 0, 1]);
    c.extend([7, 5, 0x81, 3, 8, 0, 255]); // notification
    c.extend([9, 4, 1, 0, 2, 10, 0, 0, 0]); // data interface
    c.extend([7, 5, 0x01, 2, 64, 0, 0, 7, 5, 0x82, 2, 64, 0, 0]);
    let n = c.len() as u16;
    c[2..4].copy_from_slice(&n.to_le_bytes());
    c
}

fn string(s: &str) -> Vec<u8> {
    let mut d = vec![0, 3];
    d.extend(s.encode_utf16().flat_map(|u| u.to_le_bytes()));
    d[0] = d.len() as u8;
    d
}

impl MiniFw {
    fn new() -> Self {
        Self {
            pending_in: vec![],
            echo: vec![],
            in_busy: false,
            stall_string: None,
            configured: false,
            line: vec![],
            dtr: 0,
            dir_in: false,
        }
    }

    fn ep0_write(&mut self, p: &mut Periph, ram: &mut Ram, chunk: &[u8]) {
        ram.write(BUF as u64, chunk);
        w(p, ram, epin(0), BUF);
        w(p, ram, epin(0) + 4, chunk.len() as u32);
        w(p, ram, USBD + 0x200, u32::from(chunk.len() < 64) << 2);
        w(p, ram, USBD + 0x004, 1);
        assert_eq!(r(p, USBD + 0x108), 1);
        w(p, ram, USBD + 0x108, 0);
    }

    fn poll(&mut self, p: &mut Periph, ram: &mut Ram) {
        if r(p, USBD + 0x100) == 1 {
            w(p, ram, USBD + 0x100, 0);
            w(p, ram, USBD + 0x510, 0b111);
            w(p, ram, USBD + 0x514, 0b11);
            w(p, ram, USBD + 0x4A4, 0);
            self.in_busy = false;
            return;
        }
        if r(p, USBD + 0x128) == 1 {
            w(p, ram, USBD + 0x128, 0);
            if self.dir_in {
                if !self.pending_in.is_empty() {
                    let rest = std::mem::take(&mut self.pending_in);
                    let n = rest.len().min(64);
                    self.pending_in = rest[n..].to_vec();
                    self.ep0_write(p, ram, &rest[..n]);
                }
            } else {
                self.line = dma_out(p, ram, 0, BUF + 0x300);
                w(p, ram, USBD + 0x050, 1);
            }
        }
        if r(p, USBD + 0x15C) == 1 {
            w(p, ram, USBD + 0x15C, 0);
            w(p, ram, USBD + 0x200, 0);
            let s: Vec<u8> = (0..8).map(|i| r(p, USBD + 0x480 + 4 * i) as u8).collect();
            let wlen = u16::from_le_bytes([s[6], s[7]]) as usize;
            self.dir_in = s[0] & 0x80 != 0;
            if s[0] & 0x80 == 0 {
                w(p, ram, USBD + 0x04C, 1); // EP0RCVOUT
            }
            let reply: Option<Vec<u8>> = match (s[0], s[1], s[3]) {
                (0x80, 6, 1) => Some(DEVICE.to_vec()),
                (0x80, 6, 2) => Some(config()),
                (0x80, 6, 3) if Some(s[2]) == self.stall_string => None,
                (0x80, 6, 3) => Some(match s[2] {
                    0 => vec![4, 3, 0x09, 0x04],
                    1 => string("Arduino"),
                    2 => string("gyrocal Nano 33 BLE"),
                    _ => string("0123456789ABCDEF"),
                }),
                (0x00, 5, _) => return,
                (0x00, 9, _) => {
                    self.configured = true;
                    w(p, ram, USBD + 0x050, 1);
                    return;
                }
                (0x21, 0x20, _) => return, // data stage follows
                (0x21, 0x22, _) => {
                    self.dtr = s[2] as u16;
                    w(p, ram, USBD + 0x050, 1);
                    return;
                }
                _ => None,
            };
            match reply {
                Some(mut d) => {
                    d.truncate(wlen);
                    let first: Vec<u8> = d.iter().take(64).copied().collect();
                    self.pending_in = d[first.len()..].to_vec();
                    self.ep0_write(p, ram, &first);
                }
                None => w(p, ram, USBD + 0x054, 1), // EP0STALL
            }
            return;
        }
        if !self.configured {
            return;
        }
        let st = r(p, USBD + 0x46C);
        if st & (1 << 2) != 0 {
            w(p, ram, USBD + 0x46C, 1 << 2);
            self.in_busy = false;
        }
        if st & (1 << 17) != 0 {
            w(p, ram, USBD + 0x46C, 1 << 17);
            let d = dma_out(p, ram, 1, BUF + 0x400);
            self.echo.extend(d.iter().map(|b| b.to_ascii_uppercase()));
        }
        if !self.in_busy && !self.echo.is_empty() {
            let n = self.echo.len().min(64);
            let chunk: Vec<u8> = self.echo.drain(..n).collect();
            ram.write((BUF + 0x500) as u64, &chunk);
            w(p, ram, epin(2), BUF + 0x500);
            w(p, ram, epin(2) + 4, n as u32);
            w(p, ram, USBD + 0x00C, 1);
            w(p, ram, USBD + 0x110, 0);
            w(p, ram, USBD + 0x468, 1 << 2);
            self.in_busy = true;
        }
    }
}

/// Runs the stand-in firmware every 2 ms for `secs`.
fn run(p: &Rc<RefCell<Periph>>, ram: &mut Ram, fw: &mut MiniFw, secs: f64) {
    let steps = (secs / 2e-3).round() as usize;
    for _ in 0..steps {
        let mut pm = p.borrow_mut();
        wait(&mut pm, 2e-3);
        fw.poll(&mut pm, ram);
        assert!(pm.fault.is_none(), "{:?}", pm.fault);
    }
}

fn host_board() -> (Rc<RefCell<Periph>>, UsbHost, Ram, MiniFw) {
    let (mut p, mut ram) = (periph(Board::Rev1, true), Ram::default());
    enable(&mut p, &mut ram);
    let p = Rc::new(RefCell::new(p));
    let host = UsbHost::from_periph(p.clone());
    (p, host, ram, MiniFw::new())
}

#[test]
fn the_host_enumerates_like_linux_and_moves_bulk_data() {
    let (p, host, mut ram, mut fw) = host_board();
    run(&p, &mut ram, &mut fw, 0.5);
    assert!(host.enumerated(), "{:#?}", host.log());
    assert!(host.errors().is_empty(), "{:?}", host.errors());
    let log = host.log();
    let order: Vec<&str> =
        log.iter().filter_map(|l| l.split_once(' ').map(|x| x.1)).filter(|l| l.contains(" ok ") || l.contains("reset")).collect();
    let want = [
        "device connected: reset",
        "bus reset",
        "GET_DESCRIPTOR(device, 64) ok (18 bytes)",
        "bus reset",
        "SET_ADDRESS(1) ok (0 bytes)",
        "GET_DESCRIPTOR(device, 18) ok (18 bytes)",
        "GET_DESCRIPTOR(configuration, 9) ok (9 bytes)",
        "GET_DESCRIPTOR(configuration, wTotalLength) ok (75 bytes)",
        "GET_DESCRIPTOR(string 0) ok (4 bytes)",
        "GET_DESCRIPTOR(string 2) ok (40 bytes)",
        "GET_DESCRIPTOR(string 1) ok (16 bytes)",
        "GET_DESCRIPTOR(string 3) ok (34 bytes)",
        "SET_CONFIGURATION(1) ok (0 bytes)",
        "SET_LINE_CODING(115200 8N1) ok (0 bytes)",
        "SET_CONTROL_LINE_STATE(0x3) ok (0 bytes)",
    ];
    assert_eq!(order, want, "{log:#?}");
    let dd = host.device_descriptor().unwrap();
    assert_eq!((dd.vid, dd.pid, dd.max_packet0), (0x2341, 0x805A, 64));
    assert_eq!(host.product().as_deref(), Some("gyrocal Nano 33 BLE"));
    assert_eq!(host.manufacturer().as_deref(), Some("Arduino"), "MiniFw's string");
    let cdc = host.cdc().unwrap();
    assert_eq!((cdc.comm_interface, cdc.notify_in, cdc.bulk_in, cdc.bulk_out), (0, Some(0x81), (0x82, 64), (0x01, 64)));
    assert_eq!(fw.line, vec![0x00, 0xC2, 0x01, 0x00, 0, 0, 8]);
    assert_eq!((fw.dtr, p.borrow().usbd.usbaddr), (3, 1));
    // Bulk: 1000 bytes out, echoed back upper-cased.
    let text: Vec<u8> = (0..1000).map(|i| b"abcdefghij"[i % 10]).collect();
    host.write(&text);
    run(&p, &mut ram, &mut fw, 0.2);
    assert_eq!(host.read(), text.to_ascii_uppercase());
    // A host that does not read: the device's packet stays in its buffer.
    host.set_reading(false);
    host.write(b"x");
    run(&p, &mut ram, &mut fw, 0.02);
    assert!(host.read().is_empty() && fw.in_busy);
    host.set_reading(true);
    run(&p, &mut ram, &mut fw, 0.02);
    assert_eq!(host.read(), b"X");
    // Class requests later: line coding and DTR.
    host.set_line_coding(1200);
    host.set_dtr(false);
    run(&p, &mut ram, &mut fw, 0.05);
    assert_eq!((u32::from_le_bytes(fw.line[..4].try_into().unwrap()), fw.dtr), (1200, 0));
    assert_eq!(host.with(|h| h.line), (1200, 0));
    // Unplug: POWER.USBREMOVED, the host loses the device; plugged back: a new enumeration
    // (next address).
    let t = p.borrow().now();
    p.borrow_mut().power.unplug(t);
    run(&p, &mut ram, &mut fw, 0.01);
    assert!(!host.enumerated());
    assert_eq!(r(&mut p.borrow_mut(), POWER + 0x120), 1, "USBREMOVED");
    let t = p.borrow().now();
    p.borrow_mut().power.plug(t);
    run(&p, &mut ram, &mut fw, 0.5);
    assert!(host.enumerated(), "{:#?}", host.log());
    assert_eq!(p.borrow().usbd.usbaddr, 2);
    assert_eq!(host.with(|h| h.enumerations), 2);
}

#[test]
fn the_host_reports_a_stall_and_a_silent_device() {
    let (p, host, mut ram, mut fw) = host_board();
    fw.stall_string = Some(3);
    run(&p, &mut ram, &mut fw, 0.5);
    assert!(!host.enumerated());
    assert_eq!(host.error().as_deref(), Some("STALL on GET_DESCRIPTOR(string 3) (data stage)"));
    // A device that never answers EP0: a timeout after 5 s.
    let (p, host, mut ram, _) = host_board();
    run(&p, &mut ram, &mut MiniFw { configured: false, ..MiniFw::new() }, 0.0);
    for _ in 0..3000 {
        wait(&mut p.borrow_mut(), 2e-3);
    }
    let e = host.error().unwrap_or_default();
    assert!(e.starts_with("timeout: GET_DESCRIPTOR(device, 64)"), "{e}");
}

#[test]
fn the_pty_forwards_open_baud_and_close() {
    use vboard::pty::PtyBridge;
    let (p, host, mut ram, mut fw) = host_board();
    run(&p, &mut ram, &mut fw, 0.5);
    assert!(host.enumerated());
    let mut bridge = PtyBridge::new(host.clone()).unwrap();
    bridge.pump().unwrap();
    assert!(!bridge.slave_open());
    // A program opens the port at 1200 baud, writes, reads the echo, closes: cdc-acm's requests.
    let path = std::ffi::CString::new(bridge.slave_path().to_str().unwrap()).unwrap();
    // SAFETY: test-only libc calls on a descriptor this test owns.
    let fd = unsafe { libc::open(path.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK) };
    assert!(fd >= 0);
    unsafe {
        let mut t: libc::termios = std::mem::zeroed();
        libc::tcgetattr(fd, &mut t);
        libc::cfmakeraw(&mut t);
        libc::cfsetspeed(&mut t, libc::B1200);
        libc::tcsetattr(fd, libc::TCSANOW, &t);
        assert_eq!(libc::write(fd, b"ping".as_ptr().cast(), 4), 4);
    }
    assert!(bridge.slave_open());
    assert_eq!(bridge.slave_baud().unwrap(), 1200);
    bridge.pump().unwrap();
    assert_eq!(host.queued(), ["SET_CONTROL_LINE_STATE(0x3)", "SET_LINE_CODING(1200 8N1)"]);
    for _ in 0..50 {
        run(&p, &mut ram, &mut fw, 0.002);
        bridge.pump().unwrap();
    }
    let mut buf = [0u8; 16];
    let n = unsafe { libc::read(fd, buf.as_mut_ptr().cast(), buf.len()) };
    assert_eq!(&buf[..n.max(0) as usize], b"PING");
    assert_eq!((u32::from_le_bytes(fw.line[..4].try_into().unwrap()), fw.dtr), (1200, 3));
    unsafe { libc::close(fd) };
    bridge.pump().unwrap();
    assert!(!host.with(|h| h.reading()));
    run(&p, &mut ram, &mut fw, 0.02);
    assert_eq!(fw.dtr, 0, "closing the port drops DTR");
}
