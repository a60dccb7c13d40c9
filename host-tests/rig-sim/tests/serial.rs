//! The USB console's logic (`gyrocal_fw::serial`): whole lines or none, dropped bytes counted,
//! the commands, the 1200-baud touch.

use gyrocal_fw::serial::{Command, Outbox, Touch, HELP, TOUCH_BAUD};

/// Drains the outbox as the USB endpoint does, `packet` bytes at a time.
fn drain<const N: usize>(o: &mut Outbox<N>, packet: usize) -> String {
    let mut out = Vec::new();
    loop {
        let chunk = o.peek(packet).to_vec();
        if chunk.is_empty() {
            break;
        }
        o.consume(chunk.len());
        out.extend(chunk);
    }
    String::from_utf8(out).unwrap()
}

#[test]
fn lines_go_in_whole_or_are_dropped_and_counted() {
    let mut o = Outbox::<64>::new();
    assert!(o.push_line("first line"));
    assert!(o.push_line(&"x".repeat(40)));
    // 12 + 42 = 54 of 64 bytes queued: a 9-byte line (+ CRLF) no longer fits.
    assert!(!o.push_line("123456789"));
    assert_eq!(o.dropped(), 11);
    assert_eq!(drain(&mut o, 8), format!("first line\r\n{}\r\n", "x".repeat(40)));
    assert!(o.is_empty());
    // Wrapping around the ring end keeps the bytes in order.
    for i in 0..20 {
        assert!(o.push_line(&format!("line {i:02}")));
        assert_eq!(drain(&mut o, 5), format!("line {i:02}\r\n"));
    }
    o.push_line("pending");
    o.clear();
    assert_eq!(o.dropped(), 11 + 9);
    assert_eq!(drain(&mut o, 64), "");
}

#[test]
fn the_console_takes_the_protocols_command_bytes() {
    // The console's commands and help are `calib_core::protocol`'s (every byte is tested there).
    let _: calib_core::protocol::Command = Command::Help;
    assert_eq!(HELP, calib_core::protocol::HELP);
    for c in Command::ALL {
        assert_eq!(Command::decode(c.byte()), Some(c));
    }
    assert_eq!(Command::decode(b'\n'), None);
}

#[test]
fn the_touch_needs_1200_baud_and_dtr_low_for_200_ms() {
    let mut t = Touch::default();
    // Opening at 115 200 Bd with DTR up, or closing it (DTR low): no touch.
    assert!(!t.update(0.0, 115_200, true));
    assert!(!t.update(1.0, 115_200, false));
    assert!(!t.update(5.0, 115_200, false));
    // 1200 Bd with DTR still up: not yet.
    assert!(!t.update(6.0, TOUCH_BAUD, true));
    assert!(!t.update(6.1, TOUCH_BAUD, false));
    assert!(!t.update(6.29, TOUCH_BAUD, false));
    assert!(t.update(6.31, TOUCH_BAUD, false));
    // DTR back up in between restarts the wait.
    let mut t = Touch::default();
    assert!(!t.update(0.0, TOUCH_BAUD, false));
    assert!(!t.update(0.15, TOUCH_BAUD, true));
    assert!(!t.update(0.3, TOUCH_BAUD, false));
    assert!(t.update(0.51, TOUCH_BAUD, false));
}
