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

/// The text the host received in `secs` of board time.
fn read_for(b: &mut Bench, host: &UsbHost, secs: f64) -> String {
    String::from_utf8_lossy(&host.run_and_read(&mut b.mcu, secs).unwrap()).into_owned()
}

#[test]
fn commands_over_usb_start_a_calibration_and_raw_log_rows_feed_calib() {
    let (mut b, host) = usb_bench();
    host.wait_enumerated(&mut b.mcu, 5.0).unwrap();
    b.run_for(1.0);
    host.write(b"x\r\n");
    let help = read_for(&mut b, &host, 0.3);
    assert!(help.starts_with("commands: c calibrate"), "unknown input gets the help: {help:?}");
    host.write(b"s");
    assert_eq!(read_for(&mut b, &host, 0.3), "no calibration stored\r\n");
    // Raw-log mode: the header, then rows calib reads.
    host.write(b"R");
    let text = read_for(&mut b, &host, 3.0);
    assert!(text.starts_with(calib_core::log::HEADER), "{:?}", &text[..text.len().min(200)]);
    host.write(b"c");
    let text = text + &read_for(&mut b, &host, 3.0);
    assert!(text.contains("\r\nplan: 13 rig poses, 12 hand-held poses\r\n"), "{text:?}");
    assert!(text.contains("\r\nphase: wait-rest: keep the rig still\r\n"));
    host.write(b"r");
    let text = text + &read_for(&mut b, &host, 0.5);
    // The end marker (report lines may follow it: the bias phase ends about now).
    assert!(text.contains(&format!("\r\n{}\r\n", calib_core::log::END)), "{:?}", &text[text.len().saturating_sub(400)..]);
    let log = calib::csvlog::parse(&text.replace("\r\n", "\n")).unwrap();
    // 6 s at 119 Hz (the sensor's ODR error: ±10 %), none lost.
    assert!((600..=800).contains(&log.rows.len()), "{} rows", log.rows.len());
    assert_eq!(calib::port::lost_rows(&log.rows), 0);
    assert!(host.errors().is_empty(), "{:?}", host.errors());
}

#[test]
fn a_host_that_stops_reading_never_stalls_the_board_and_is_told_what_it_missed() {
    let (mut b, host) = usb_bench();
    host.wait_enumerated(&mut b.mcu, 5.0).unwrap();
    host.write(b"r");
    read_for(&mut b, &host, 0.5);
    // The terminal hangs: no IN tokens for 10 s of raw rows (80 KB), more than the outbox holds.
    host.set_reading(false);
    let loops = b.mcu.instructions();
    b.run_for(10.0);
    assert_eq!(b.mcu.watchdog_resets, 0, "the loop stalled on USB");
    assert!(b.mcu.instructions() - loops > 10_000_000, "the firmware kept running");
    host.set_reading(true);
    let text = read_for(&mut b, &host, 2.0);
    let line = text.lines().find(|l| l.starts_with("USB: ")).unwrap_or_else(|| panic!("no drop report: {text:?}"));
    let n: u32 = line.split(' ').nth(1).and_then(|n| n.parse().ok()).unwrap();
    assert!(n > 50_000, "{line}");
    assert!(line.ends_with("bytes dropped since boot (the host was not reading)"), "{line}");
    // Whole lines were dropped: every row that arrived parses.
    let rows = text.lines().filter(|l| l.matches(',').count() == 8).count();
    assert!(rows > 100, "{rows}");
}

#[test]
fn without_vbus_the_usbd_stays_off_and_the_board_runs() {
    // (Every other vboard test runs without VBUS too: the calibrations in board.rs among them.)
    let elf = build_firmware(&[]).unwrap();
    let mut b = Bench::new(elf, Variant::Hobby.config(5, 0), 5, Board::Rev1, NorSim::new(8, 5), false).unwrap();
    b.run_for(3.0);
    assert_eq!(b.mcu.periph.borrow().usbd.enable, 0, "USBD enabled without VBUS");
    assert!(b.mcu.log.iter().any(|l| l.contains("LSM9DS1 ready")), "{:#?}", b.mcu.log);
    assert!(!b.mcu.log.iter().any(|l| l.contains("USB")), "{:#?}", b.mcu.log);
    // Plugged in later: USB starts then.
    let host = UsbHost::new(&b.mcu);
    host.attach();
    host.wait_enumerated(&mut b.mcu, 5.0).unwrap();
    b.run_for(0.1);
    assert!(b.mcu.log.iter().any(|l| l.contains("USB: started")), "{:#?}", b.mcu.log);
    // Unplugged and plugged back (the board on another supply): the port comes back.
    host.detach();
    b.run_for(1.0);
    host.attach();
    host.wait_enumerated(&mut b.mcu, 5.0).unwrap();
    host.write(b"s");
    assert_eq!(read_for(&mut b, &host, 0.3), "no calibration stored\r\n");
}

#[test]
fn calib_port_on_the_pty_calibrates_the_board_and_reads_back_its_json_line() {
    let elf = build_firmware(&[]).unwrap();
    let mut b = Bench::new(elf, Variant::Hobby.config(6, 0), 6, Board::Rev1, NorSim::new(8, 6), false).unwrap();
    b.mcu.rtt_detach();
    let log = std::env::temp_dir().join(format!("gyrocal-usb-test-{}.csv", std::process::id()));
    let (outcome, session) = b.calibrate_over_usb(&log, Box::new(std::io::sink())).unwrap();
    assert_eq!(outcome, vboard::bench::Outcome::Done);
    let out = session.unwrap_or_else(|e| panic!("calib --port: {e}"));
    assert!(out.json.starts_with("{\"gyro\":{\"K\":"), "{}", out.json);
    let stored = b.stored().expect("a record in flash");
    assert_eq!(out.record.seq, stored.seq);
    for i in 0..9 {
        assert!((out.record.gyro_k[i / 3][i % 3] - stored.gyro_k[i / 3][i % 3]).abs() < 1e-6, "K[{i}]");
    }
    assert!(out.check.max_diff < calib::port::K_TOLERANCE);
    assert!(b.max_scale_error_pct(&out.record) < 0.1, "{}", b.max_scale_error_pct(&out.record));
    let _ = std::fs::remove_file(log);
    // A terminal opened afterwards: `s` gives the stored record as its line, the JSON line and C.
    b.usb = None;
    let host = UsbHost::new(&b.mcu);
    host.set_reading(true);
    host.set_dtr(true);
    b.run_for(0.1);
    host.read();
    host.write(b"s");
    let text = read_for(&mut b, &host, 0.5);
    let lines: Vec<&str> = text.lines().filter(|l| !l.starts_with("rate ")).collect();
    assert!(lines[0].starts_with(&format!("stored record {} (full K): K = [", stored.seq)), "{text}");
    assert_eq!(lines[1], out.json, "the same JSON line as after the calibration");
    assert!(text.contains("static const float GYRO_K[3][3] = {") && text.contains("gyrocal_apply"), "{text}");
}
