//! The firmware's never-blocking RTT staging: frames are published whole or dropped whole and
//! counted, whatever the host reads, and the ring wraps correctly.

use gyrocal_fw::rtt::Frame;

/// A ring of `size` bytes with a host that reads from `read`; returns (published write offset,
/// bytes dropped) after writing `frames` (each one defmt frame, written in `chunk`-byte pieces).
fn write(buf: &mut [u8], mut write: usize, read: usize, frames: &[&[u8]], chunk: usize) -> (usize, usize) {
    let mut dropped = 0;
    for f in frames {
        let mut frame = Frame::start(write);
        for c in f.chunks(chunk.max(1)) {
            frame.stage(buf, read, c);
        }
        match frame.finish() {
            Ok(w) => write = w,
            Err(n) => dropped += n,
        }
    }
    (write, dropped)
}

/// What the host would read from `read` to `write`.
fn readable(buf: &[u8], read: usize, write: usize) -> Vec<u8> {
    let n = buf.len();
    (0..(write + n - read) % n).map(|i| buf[(read + i) % n]).collect()
}

#[test]
fn frames_that_fit_are_published_whole_and_in_order() {
    let mut buf = [0u8; 16];
    let (w, dropped) = write(&mut buf, 0, 0, &[b"abc", b"defgh"], 2);
    assert_eq!((w, dropped), (8, 0));
    assert_eq!(readable(&buf, 0, w), b"abcdefgh");
}

#[test]
fn a_frame_that_does_not_fit_is_dropped_whole_and_counted() {
    let mut buf = [0u8; 16];
    // 15 usable bytes (one slot stays free); the host never reads.
    let (w, dropped) = write(&mut buf, 0, 0, &[b"0123456789", b"abcdef", b"xyz"], 4);
    assert_eq!(dropped, 6, "the 6-byte frame does not fit after 10 bytes");
    assert_eq!(readable(&buf, 0, w), b"0123456789xyz", "no torn frame; the later small frame fits");
    // Full: everything more is dropped, nothing published moves.
    let (w2, dropped) = write(&mut buf, w, 0, &[b"12", b"3"], 1);
    assert_eq!((w2, dropped), (w + 2, 1));
}

#[test]
fn frames_wrap_around_the_end_of_the_buffer() {
    let mut buf = [0u8; 16];
    // The host has read up to 12; the writer is at 12.
    let (w, dropped) = write(&mut buf, 12, 12, &[b"ABCDEFGH"], 3);
    assert_eq!((w, dropped), (4, 0));
    assert_eq!(readable(&buf, 12, w), b"ABCDEFGH");
}

#[test]
fn space_the_host_frees_is_used_again() {
    let mut buf = [0u8; 8];
    let (w, d) = write(&mut buf, 0, 0, &[b"1234567"], 7);
    assert_eq!((w, d), (7, 0));
    assert_eq!(write(&mut buf, w, 0, &[b"8"], 1).1, 1, "full");
    // The host read everything.
    let (w2, d) = write(&mut buf, w, 7, &[b"abcdef"], 2);
    assert_eq!(d, 0);
    assert_eq!(readable(&buf, 7, w2), b"abcdef");
}

#[test]
fn a_frame_larger_than_the_buffer_is_dropped_without_touching_unread_bytes() {
    let mut buf = [0u8; 8];
    let (w, _) = write(&mut buf, 0, 0, &[b"abc"], 3);
    let (w2, d) = write(&mut buf, w, 0, &[&[0x55; 20]], 5);
    assert_eq!((w2, d), (3, 20));
    assert_eq!(readable(&buf, 0, w2), b"abc");
}
