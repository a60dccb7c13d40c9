//! defmt over SEGGER RTT that never blocks, whatever the host asks.
//!
//! `probe-rs run` and `cargo embed` set the up channel to block-if-full; a logger that obeys
//! spins while the buffer is full, so once the probe is detached nobody drains it and the
//! watchdog resets the board mid-calibration. This logger ignores the channel's mode: each
//! defmt frame is staged in the ring behind the published write offset and published whole
//! when it ends, or, if it did not fit in the free space, dropped whole and its bytes counted
//! ([`dropped_bytes`]). The host never sees a torn frame, so the defmt stream stays decodable.
//!
//! [`Frame`] is the staging logic over a plain buffer (host-tested); the global logger and the
//! `_SEGGER_RTT` control block exist on the target only.

/// Up-buffer size (bytes). Raw-log mode at 952 Hz (913 Hz with the sensor's −4 % ODR) writes
/// 69 B per sample, 63 KB/s (measured on the virtual board): 8 KiB hold 0.13 s of it, while
/// probe-rs reads back to back when data flow (every 100 ms when idle).
pub const BUF_SIZE: usize = 8192;

/// A frame being staged in a ring buffer of `size` bytes whose host reads from `read` and whose
/// published write offset is `start`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    /// Published write offset when the frame started.
    start: usize,
    /// Where the next byte of the frame goes.
    cursor: usize,
    /// Bytes of the frame so far (staged or not).
    len: usize,
    /// The frame no longer fits: it will be dropped.
    overflow: bool,
}

impl Frame {
    /// Starts a frame at the published write offset `write`.
    pub fn start(write: usize) -> Self {
        Self { start: write, cursor: write, len: 0, overflow: false }
    }

    /// Stages `bytes` into `buf` if the whole frame so far still fits in the space the host has
    /// freed (`read` = the host's read offset); otherwise marks the frame dropped.
    pub fn stage(&mut self, buf: &mut [u8], read: usize, bytes: &[u8]) {
        self.len += bytes.len();
        let size = buf.len();
        if self.overflow || size == 0 || read >= size {
            self.overflow = true;
            return;
        }
        // Free bytes from the frame's start (one slot stays empty: full ≠ empty).
        let free = (read + size - self.start - 1) % size;
        if self.len > free {
            self.overflow = true;
            return;
        }
        for &b in bytes {
            buf[self.cursor] = b;
            self.cursor = (self.cursor + 1) % size;
        }
    }

    /// Ends the frame: the write offset to publish, or `Err(len)` with the bytes dropped.
    pub fn finish(self) -> Result<usize, usize> {
        if self.overflow {
            Err(self.len)
        } else {
            Ok(self.cursor)
        }
    }
}

#[cfg(all(target_os = "none", feature = "defmt"))]
mod logger {
    use super::{Frame, BUF_SIZE};
    use core::cell::UnsafeCell;
    use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

    /// SEGGER RTT up channel descriptor (layout fixed by the RTT protocol).
    #[repr(C)]
    struct Channel {
        name: *const u8,
        buffer: *mut u8,
        size: u32,
        write: AtomicU32,
        read: AtomicU32,
        flags: AtomicU32,
    }

    /// SEGGER RTT control block: the host finds it by its id in RAM.
    #[repr(C)]
    struct Header {
        id: [u8; 16],
        max_up_channels: u32,
        max_down_channels: u32,
        up: Channel,
    }

    // SAFETY: the pointers are to statics; the offsets are atomics shared with the host.
    unsafe impl Sync for Header {}

    struct Buffer(UnsafeCell<[u8; BUF_SIZE]>);
    // SAFETY: written only by the logger inside its critical section, read by the host.
    unsafe impl Sync for Buffer {}

    #[link_section = ".uninit.rtt.BUFFER"]
    static BUFFER: Buffer = Buffer(UnsafeCell::new([0; BUF_SIZE]));
    static NAME: [u8; 6] = *b"defmt\0";

    #[no_mangle]
    static _SEGGER_RTT: Header = Header {
        id: *b"SEGGER RTT\0\0\0\0\0\0",
        max_up_channels: 1,
        max_down_channels: 0,
        up: Channel {
            name: NAME.as_ptr(),
            buffer: BUFFER.0.get() as *mut u8,
            size: BUF_SIZE as u32,
            write: AtomicU32::new(0),
            read: AtomicU32::new(0),
            // Non-blocking, skip (the host may set block-if-full; it is ignored).
            flags: AtomicU32::new(0),
        },
    };

    static DROPPED: AtomicU32 = AtomicU32::new(0);

    struct State {
        taken: AtomicBool,
        primask_active: UnsafeCell<bool>,
        ring: UnsafeCell<Frame>,
        encoder: UnsafeCell<defmt::Encoder>,
    }
    // SAFETY: accessed only between acquire and release, with interrupts disabled.
    unsafe impl Sync for State {}

    static STATE: State = State {
        taken: AtomicBool::new(false),
        primask_active: UnsafeCell::new(false),
        ring: UnsafeCell::new(Frame { start: 0, cursor: 0, len: 0, overflow: false }),
        encoder: UnsafeCell::new(defmt::Encoder::new()),
    };

    /// Stages encoded bytes of the current frame.
    ///
    /// SAFETY: only between acquire and release.
    unsafe fn stage(bytes: &[u8]) {
        let read = _SEGGER_RTT.up.read.load(Ordering::Relaxed) as usize;
        // SAFETY: exclusive between acquire and release; the host never writes the buffer.
        let buf = unsafe { &mut *BUFFER.0.get() };
        unsafe { (*STATE.ring.get()).stage(buf, read, bytes) };
    }

    #[defmt::global_logger]
    struct Logger;

    // SAFETY: acquire/release bracket every frame with interrupts disabled; no re-entry.
    unsafe impl defmt::Logger for Logger {
        fn acquire() {
            let primask = cortex_m::register::primask::read();
            cortex_m::interrupt::disable();
            if STATE.taken.swap(true, Ordering::Acquire) {
                // A frame inside a frame (a log call in an interrupt during a log call is
                // impossible here: interrupts are off). Nothing sensible to do but reset.
                cortex_m::peripheral::SCB::sys_reset();
            }
            // SAFETY: taken; interrupts are disabled.
            unsafe {
                *STATE.primask_active.get() = primask.is_active();
                *STATE.ring.get() = Frame::start(_SEGGER_RTT.up.write.load(Ordering::Relaxed) as usize);
                (*STATE.encoder.get()).start_frame(|b| stage(b));
            }
        }

        unsafe fn flush() {
            // Never waits for the host.
        }

        unsafe fn release() {
            // SAFETY: called after acquire, per the defmt contract.
            unsafe {
                (*STATE.encoder.get()).end_frame(|b| stage(b));
                match (*STATE.ring.get()).finish() {
                    Ok(write) => _SEGGER_RTT.up.write.store(write as u32, Ordering::Release),
                    Err(n) => {
                        DROPPED.fetch_add(n as u32, Ordering::Relaxed);
                    }
                }
                let enable = *STATE.primask_active.get();
                STATE.taken.store(false, Ordering::Release);
                if enable {
                    cortex_m::interrupt::enable();
                }
            }
        }

        unsafe fn write(bytes: &[u8]) {
            // SAFETY: called between acquire and release.
            unsafe { (*STATE.encoder.get()).write(bytes, |b| stage(b)) };
        }
    }

    /// Log bytes dropped since boot because the host did not read the buffer.
    pub fn dropped_bytes() -> u32 {
        DROPPED.load(Ordering::Relaxed)
    }
}

#[cfg(all(target_os = "none", feature = "defmt"))]
pub use logger::dropped_bytes;
