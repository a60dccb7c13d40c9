//! The real firmware on the virtual USB port: enumeration by the virtual host, a command, the
//! 1200-baud touch (a smoke test of the USBD model against nrf-usbd + usb-device + usbd-serial).

use rig_sim::lsm_model::Board;
use rig_sim::nor::NorSim;
use rig_sim::variant::Variant;
use vboard::bench::{build_firmware, Bench};
use vboard::usb_host::UsbHost;

fn usb_bench() -> (Bench, UsbHost) {
    let elf = build_firmware(&[]).unwrap();
    let b = Bench::new(elf, Variant::Hobby.config(3, 0), 3, Board::Rev1, NorSim::new(8, 3), false).unwrap();
    let host = UsbHost::new(&b.mcu);
    host.attach();
    (b, host)
}

#[test]
fn the_firmware_enumerates_answers_help_and_does_the_1200_baud_touch() {
    let (mut b, host) = usb_bench();
    if let Err(e) = host.wait_enumerated(&mut b.mcu, 5.0) {
        panic!("{e}\nhost: {:#?}\nboard: {:#?}", host.log(), b.mcu.log);
    }
    println!("enumerated at {:.3} s: {:?} {:?}", b.mcu.now(), host.product(), host.device_descriptor());
    assert!(host.with(|h| h.bos.is_some()), "usb-device says bcdUSB 2.1: Linux reads its BOS descriptor");
    host.write(b"h");
    let out = host.run_and_read(&mut b.mcu, 0.5).unwrap();
    let text = String::from_utf8_lossy(&out);
    println!("{text}");
    assert!(text.contains("1200"), "help text: {text:?}\nhost: {:#?}\nboard: {:#?}", host.log(), b.mcu.log);
    assert!(host.errors().is_empty(), "{:?}", host.errors());
    // The touch: 1200 Bd, then DTR dropped: GPREGRET = 0xB0 and a soft reset.
    host.set_line_coding(1200);
    host.set_dtr(false);
    b.run_for(1.0);
    assert_eq!(b.mcu.resets, 1, "{:#?}", b.mcu.log);
    assert_eq!(b.mcu.periph.borrow_mut().read(0x4000_051C), 0xB0, "GPREGRET");
    // After the reset the board comes back on the bus.
    host.wait_enumerated(&mut b.mcu, 5.0).unwrap();
}

#[test]
fn a_program_on_the_pty_gets_the_help_and_its_1200_baud_touch_resets_the_board() {
    use vboard::pty::PtyBridge;
    let (mut b, host) = usb_bench();
    host.wait_enumerated(&mut b.mcu, 5.0).unwrap();
    let mut bridge = PtyBridge::new(host.clone()).unwrap();
    let path = std::ffi::CString::new(bridge.slave_path().to_str().unwrap()).unwrap();
    // SAFETY: test-only libc calls on descriptors this test owns.
    let open = |baud: libc::speed_t| unsafe {
        let fd = libc::open(path.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK);
        assert!(fd >= 0);
        let mut t: libc::termios = std::mem::zeroed();
        libc::tcgetattr(fd, &mut t);
        libc::cfmakeraw(&mut t);
        libc::cfsetspeed(&mut t, baud);
        libc::tcsetattr(fd, libc::TCSANOW, &t);
        fd
    };
    let fd = open(libc::B115200);
    bridge.run_for(&mut b.mcu, 0.1, 1e-3, false).unwrap();
    assert_eq!(unsafe { libc::write(fd, b"h".as_ptr().cast(), 1) }, 1);
    bridge.run_for(&mut b.mcu, 0.3, 1e-3, false).unwrap();
    let mut buf = vec![0u8; 4096];
    let n = unsafe { libc::read(fd, buf.as_mut_ptr().cast(), buf.len()) };
    let text = String::from_utf8_lossy(&buf[..n.max(0) as usize]).to_string();
    assert!(text.contains("1200-baud touch"), "{text:?}");
    unsafe { libc::close(fd) };
    // The touch as bossac/arduino-cli do it: open at 1200 Bd, close.
    let fd = open(libc::B1200);
    unsafe { libc::close(fd) };
    bridge.run_for(&mut b.mcu, 1.0, 1e-3, false).unwrap();
    assert_eq!(b.mcu.resets, 1, "{:#?}\n{:#?}", host.log(), b.mcu.log);
    assert_eq!(b.mcu.periph.borrow_mut().read(0x4000_051C), 0xB0, "GPREGRET");
}
