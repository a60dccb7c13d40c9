//! The board's virtual CDC-ACM port as a pseudo-terminal: a program that opens
//! [`PtyBridge::slave_path`] (e.g. `calib --port /dev/pts/N` through the serialport crate) talks
//! to the emulated board as it would to `/dev/ttyACM0`.
//!
//! What Linux's cdc-acm does and the bridge forwards to the virtual host ([`UsbHost`]):
//! - the port is opened: bulk IN reading starts and DTR|RTS are raised
//!   (SET_CONTROL_LINE_STATE 3), then the slave's baud rate is sent as SET_LINE_CODING;
//! - the baud rate changes while open (tcsetattr, read with TCGETS2 on the master: a pty shares
//!   its termios): SET_LINE_CODING;
//! - the port is closed (the master polls POLLHUP: no process has the slave open): DTR|RTS
//!   dropped (SET_CONTROL_LINE_STATE 0) and reading stops (cdc-acm submits no IN URBs on a
//!   closed port);
//! - an open, baud change and close all between two pumps (a program doing the 1200-baud touch
//!   faster than the bridge polls) is replayed as open, SET_LINE_CODING, close.
//!
//! Bytes: the master is non-blocking both ways; what the program writes goes to
//! [`UsbHost::write`] (bulk OUT), what the host reads goes to the master. The pty starts in raw
//! mode (no echo, no line editing) so that the board's output is never echoed back to it.

use crate::mcu::{Mcu, Stop};
use crate::usb_host::UsbHost;
use std::ffi::CStr;
use std::io;
use std::path::{Path, PathBuf};

/// A pty whose slave is the board's USB serial port.
pub struct PtyBridge {
    master: libc::c_int,
    path: PathBuf,
    host: UsbHost,
    open: bool,
    baud: u32,
    pending: Vec<u8>,
    /// Bytes moved program → board and board → program.
    pub moved: (u64, u64),
}

fn os_err(what: &str) -> io::Error {
    let e = io::Error::last_os_error();
    io::Error::new(e.kind(), format!("{what}: {e}"))
}

impl PtyBridge {
    /// Creates the pty (raw mode, 115200 baud) for `host`'s port.
    pub fn new(host: UsbHost) -> io::Result<Self> {
        // SAFETY: plain libc calls on a descriptor this function owns; buffers sized as passed.
        unsafe {
            let m = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK);
            if m < 0 {
                return Err(os_err("posix_openpt"));
            }
            if libc::grantpt(m) != 0 || libc::unlockpt(m) != 0 {
                libc::close(m);
                return Err(os_err("grantpt/unlockpt"));
            }
            let mut name = [0 as libc::c_char; 128];
            if libc::ptsname_r(m, name.as_mut_ptr(), name.len()) != 0 {
                libc::close(m);
                return Err(os_err("ptsname_r"));
            }
            let path = PathBuf::from(CStr::from_ptr(name.as_ptr()).to_string_lossy().into_owned());
            // Linux reports POLLHUP on the master only once a slave was opened and closed: do
            // that once, so that "nobody has the port open" reads as POLLHUP from the start.
            let s = libc::open(name.as_ptr(), libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK);
            if s >= 0 {
                libc::close(s);
            }
            let mut t: libc::termios = std::mem::zeroed();
            if libc::tcgetattr(m, &mut t) == 0 {
                libc::cfmakeraw(&mut t);
                libc::cfsetspeed(&mut t, libc::B115200);
                libc::tcsetattr(m, libc::TCSANOW, &t);
            }
            let mut b = Self { master: m, path, host, open: false, baud: 0, pending: vec![], moved: (0, 0) };
            b.baud = b.slave_baud()?;
            Ok(b)
        }
    }

    /// The slave's path (/dev/pts/N).
    pub fn slave_path(&self) -> &Path {
        &self.path
    }

    /// The host this bridge feeds.
    pub fn host(&self) -> &UsbHost {
        &self.host
    }

    /// The baud rate the slave side set (its termios output speed, read through TCGETS2 so that
    /// arbitrary rates set with BOTHER are seen too).
    pub fn slave_baud(&self) -> io::Result<u32> {
        // SAFETY: TCGETS2 fills a termios2 on a descriptor we own.
        unsafe {
            let mut t2: libc::termios2 = std::mem::zeroed();
            if libc::ioctl(self.master, libc::TCGETS2, &mut t2) != 0 {
                return Err(os_err("TCGETS2"));
            }
            Ok(t2.c_ospeed)
        }
    }

    /// Whether a process has the slave open (the master does not report POLLHUP).
    pub fn slave_open(&self) -> bool {
        let mut p = libc::pollfd { fd: self.master, events: libc::POLLIN, revents: 0 };
        // SAFETY: one pollfd, zero timeout.
        let n = unsafe { libc::poll(&mut p, 1, 0) };
        n >= 0 && p.revents & libc::POLLHUP == 0
    }

    /// Moves bytes both ways and forwards opens, closes and baud changes to the host.
    pub fn pump(&mut self) -> io::Result<()> {
        let open = self.slave_open();
        let baud = self.slave_baud()?;
        match (self.open, open) {
            (false, true) => {
                self.host.set_reading(true);
                self.host.set_dtr(true);
                self.host.set_line_coding(baud);
            }
            (true, false) => {
                if baud != self.baud {
                    self.host.set_line_coding(baud);
                }
                self.host.set_dtr(false);
                self.host.set_reading(false);
            }
            (true, true) if baud != self.baud => self.host.set_line_coding(baud),
            (false, false) if baud != self.baud => {
                // Opened, set and closed between two pumps.
                self.host.set_dtr(true);
                self.host.set_line_coding(baud);
                self.host.set_dtr(false);
            }
            _ => {}
        }
        self.open = open;
        self.baud = baud;
        // Program → board.
        let mut buf = [0u8; 4096];
        loop {
            // SAFETY: reads into a local buffer of the given length.
            let n = unsafe { libc::read(self.master, buf.as_mut_ptr().cast(), buf.len()) };
            if n > 0 {
                self.host.write(&buf[..n as usize]);
                self.moved.0 += n as u64;
            } else {
                break; // EAGAIN (nothing), EIO (slave closed) or EOF
            }
        }
        // Board → program (kept while nobody has the port open: cdc-acm would not read then).
        self.pending.extend(self.host.read());
        if open {
            while !self.pending.is_empty() {
                // SAFETY: writes from a live buffer of the given length.
                let n = unsafe { libc::write(self.master, self.pending.as_ptr().cast(), self.pending.len()) };
                if n <= 0 {
                    break; // the pty buffer is full: retried at the next pump
                }
                self.pending.drain(..n as usize);
                self.moved.1 += n as u64;
            }
        }
        Ok(())
    }

    /// Runs `mcu` for `secs` of virtual time, pumping every `step_s`; with `pace`, no faster
    /// than the wall clock (so that a program's timeouts mean what they say).
    pub fn run_for(&mut self, mcu: &mut Mcu, secs: f64, step_s: f64, pace: bool) -> Result<(), String> {
        let (t0, w0) = (mcu.now(), std::time::Instant::now());
        let end = t0 + secs;
        while mcu.now() < end {
            let t = (mcu.now() + step_s).min(end);
            match mcu.run_until(t) {
                Stop::Time => {}
                s => return Err(format!("the emulation stopped: {s:?}")),
            }
            self.pump().map_err(|e| format!("pty: {e}"))?;
            if pace {
                let ahead = (mcu.now() - t0) - w0.elapsed().as_secs_f64();
                if ahead > 0.0 {
                    std::thread::sleep(std::time::Duration::from_secs_f64(ahead));
                }
            }
        }
        Ok(())
    }
}

impl Drop for PtyBridge {
    fn drop(&mut self) {
        // SAFETY: the master descriptor is ours.
        unsafe {
            libc::close(self.master);
        }
    }
}
