//! The USB console's logic (`gyrocal_fw::serial`): whole lines or none, dropped bytes counted,
//! the commands, the 1200-baud touch.

use gyrocal_fw::serial::{Command, Outbox, Touch, HELP, TOUCH_BAUD};
use rig_sim::harness::at;

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

/// The packets the endpoint sends for what is queued, as lengths (0: a ZLP), until none.
fn packets<const N: usize>(o: &mut Outbox<N>) -> Vec<usize> {
    let mut sent = vec![];
    while let Some(p) = o.next_packet(64) {
        let n = p.len();
        o.sent(n, 64);
        sent.push(n);
    }
    sent
}

#[test]
fn a_burst_that_ends_on_a_full_packet_is_closed_by_a_zlp_and_only_then() {
    let mut o = Outbox::<1024>::new();
    // 126 + 2 = 128 bytes: two full packets, then the ZLP a host needs to complete its read.
    o.push_line(&"a".repeat(126));
    assert_eq!(packets(&mut o), [64, 64, 0]);
    // 129 bytes: the short last packet ends the burst.
    o.push_line(&"b".repeat(127));
    assert_eq!(packets(&mut o), [64, 64, 1]);
    // More queued after a full packet: no ZLP in the middle of a burst.
    o.push_line(&"c".repeat(62));
    assert_eq!(o.next_packet(64).map(<[u8]>::len), Some(64));
    o.sent(64, 64);
    o.push_line("d");
    assert_eq!(packets(&mut o), [3]);
    // A full packet and then the host went away: nothing owed after a clear.
    o.push_line(&"e".repeat(62));
    o.sent(64, 64);
    o.clear();
    assert_eq!(o.next_packet(64), None);
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
    // The console's commands and help are `calib_core::formats::protocol`'s (every byte is tested there).
    let _: calib_core::formats::protocol::Command = Command::Help;
    assert_eq!(HELP, calib_core::formats::protocol::HELP);
    for c in Command::ALL {
        assert_eq!(Command::decode(c.byte()), Some(c));
    }
    assert_eq!(Command::decode(b'\n'), None);
}

#[test]
fn the_touch_needs_1200_baud_and_dtr_low_for_200_ms() {
    let mut t = Touch::default();
    // Opening at 115 200 Bd with DTR up, or closing it (DTR low): no touch.
    assert!(!t.update(at(0.0), 115_200, true));
    assert!(!t.update(at(1.0), 115_200, false));
    assert!(!t.update(at(5.0), 115_200, false));
    // 1200 Bd with DTR still up: not yet.
    assert!(!t.update(at(6.0), TOUCH_BAUD, true));
    assert!(!t.update(at(6.1), TOUCH_BAUD, false));
    assert!(!t.update(at(6.29), TOUCH_BAUD, false));
    assert!(t.update(at(6.31), TOUCH_BAUD, false));
    // DTR back up in between restarts the wait.
    let mut t = Touch::default();
    assert!(!t.update(at(0.0), TOUCH_BAUD, false));
    assert!(!t.update(at(0.15), TOUCH_BAUD, true));
    assert!(!t.update(at(0.3), TOUCH_BAUD, false));
    assert!(t.update(at(0.51), TOUCH_BAUD, false));
}
