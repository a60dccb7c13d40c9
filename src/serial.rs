//! The USB serial console's logic, independent of the USB stack (host-tested): the outbox of
//! text lines that never blocks, the one-letter commands ([`Command`], the protocol's), and the
//! 1200-baud touch.
//!
//! The USB part itself (`usb`, target only) moves the outbox into the CDC bulk IN endpoint
//! packet by packet when the host takes them, and the bytes of the bulk OUT endpoint into
//! [`Command::decode`].

/// Text lines waiting for the host, in a ring of `N` bytes. A line goes in whole with its
/// `"\r\n"` or not at all (the host never sees a torn line); bytes that did not fit are
/// counted, and the loop never waits for the host.
pub struct Outbox<const N: usize> {
    buf: [u8; N],
    /// Index of the oldest byte.
    head: usize,
    /// Bytes queued.
    len: usize,
    dropped: u32,
    /// The last packet sent was a full one: a zero-length packet ends the burst.
    zlp_due: bool,
}

impl<const N: usize> Outbox<N> {
    /// Empty.
    pub const fn new() -> Self {
        Self { buf: [0; N], head: 0, len: 0, dropped: 0, zlp_due: false }
    }

    /// Queues `line` and `"\r\n"`, or drops them (counted) if they do not fit.
    pub fn push_line(&mut self, line: &str) -> bool {
        let need = line.len() + 2;
        if need > N - self.len {
            self.dropped = self.dropped.saturating_add(need as u32);
            return false;
        }
        for &b in line.as_bytes().iter().chain(b"\r\n") {
            self.buf[(self.head + self.len) % N] = b;
            self.len += 1;
        }
        true
    }

    /// The oldest queued bytes, up to `max` (contiguous in the ring; empty when none).
    pub fn peek(&self, max: usize) -> &[u8] {
        let end = (self.head + self.len.min(max)).min(N);
        &self.buf[self.head..end]
    }

    /// Removes the `n` oldest bytes (after the host took them).
    pub fn consume(&mut self, n: usize) {
        let n = n.min(self.len);
        self.head = (self.head + n) % N;
        self.len -= n;
    }

    /// The next bulk IN packet of `packet` bytes at most: the oldest bytes, or an empty one (a
    /// zero-length packet) after a burst that ended on a full packet, since a host completes a
    /// read only on a short packet; `None` when there is nothing to send.
    pub fn next_packet(&self, packet: usize) -> Option<&[u8]> {
        let chunk = self.peek(packet);
        (!chunk.is_empty() || self.zlp_due).then_some(chunk)
    }

    /// The host took `n` bytes of the packet [`Self::next_packet`] gave (0: the ZLP).
    pub fn sent(&mut self, n: usize, packet: usize) {
        self.consume(n);
        self.zlp_due = n == packet;
    }

    /// Drops everything queued (the host went away), counted.
    pub fn clear(&mut self) {
        self.dropped = self.dropped.saturating_add(self.len as u32);
        self.head = 0;
        self.len = 0;
        self.zlp_due = false;
    }

    /// Bytes queued.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Nothing queued.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes dropped since boot.
    pub fn dropped(&self) -> u32 {
        self.dropped
    }
}

impl<const N: usize> Default for Outbox<N> {
    fn default() -> Self {
        Self::new()
    }
}

/// The commands a terminal or `calib --port` sends, one byte each, and the help: the board↔PC
/// protocol's, defined once in `calib_core::formats::protocol`.
pub use calib_core::formats::protocol::{Command, HELP};
use calib_core::math::real::Real;
use calib_core::Time;

/// Line coding rate (Bd) that asks for the bootloader (Arduino's "1200-baud touch").
pub const TOUCH_BAUD: u32 = 1200;
/// How long DTR must stay low at 1200 Bd before the reset (s): ArduinoCore-mbed waits 200 ms so
/// that the host's control transfer completes first.
pub const TOUCH_DELAY_S: Real = 0.2;
/// GPREGRET value that keeps the Arduino bootloader in its serial (bossac) mode after the reset
/// (`DFU_MAGIC_SERIAL_ONLY_RESET`).
pub const GPREGRET_SERIAL_BOOTLOADER: u32 = 0xB0;

/// Detects the 1200-baud touch: the line coding at [`TOUCH_BAUD`] with DTR low for
/// [`TOUCH_DELAY_S`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Touch {
    since: Option<Time>,
}

impl Touch {
    /// Feeds the line state at time `now`; true once the touch is complete.
    pub fn update(&mut self, now: Time, baud: u32, dtr: bool) -> bool {
        if baud != TOUCH_BAUD || dtr {
            self.since = None;
            return false;
        }
        let since = *self.since.get_or_insert(now);
        now.since(since) >= TOUCH_DELAY_S
    }
}
