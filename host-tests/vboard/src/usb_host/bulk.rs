//! Bulk transfers on the CDC data interface: the IN endpoint polled while reading, bytes queued
//! by [`Host::write`] sent to the OUT endpoint in packets of up to wMaxPacketSize, and the data
//! toggles of both.
//!
//! Reads complete as Linux's cdc-acm reads: into URBs of [`URB_SIZE`] bytes (its read URBs are
//! 2 × wMaxPacketSize), each complete, and handed to the reader ([`Host::read`]), when full or
//! when a short packet (a zero-length one included) arrives. A burst that ends exactly on a
//! full packet stays in the URB until the device sends more or a ZLP ([`Host::urb_pending`],
//! [`Host::max_urb_wait_s`]).

use super::{txn_s, Host, Next};

/// cdc-acm's read URB size (B) for a 64-byte bulk IN endpoint.
pub const URB_SIZE: usize = 128;
use crate::periph::usbd::{Handshake, Phy, Usbd};

impl Host {
    /// Start (true, the default) or stop polling bulk IN (a program that does not read).
    pub fn set_reading(&mut self, on: bool) {
        if on && !self.reading {
            self.in_next = Next::At(self.now);
        }
        self.reading = on;
    }

    /// Whether the host polls bulk IN.
    pub fn reading(&self) -> bool {
        self.reading
    }

    /// Queues bytes for bulk OUT.
    pub fn write(&mut self, data: &[u8]) {
        if self.tx.is_empty() {
            self.out_next = Next::At(self.now);
        }
        self.tx.extend(data);
    }

    /// Bytes queued for bulk OUT, not yet accepted by the device.
    pub fn pending_tx(&self) -> usize {
        self.tx.len()
    }

    /// Takes the bytes of the completed URBs so far.
    pub fn read(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.rx)
    }

    /// Bytes received in the URB not completed yet (the reader does not have them).
    pub fn urb_pending(&self) -> usize {
        self.urb.len()
    }

    /// Longest time received bytes waited in an incomplete URB so far, the current one
    /// included (s).
    pub fn max_urb_wait_s(&self) -> f64 {
        let current = self.urb_since.map_or(0.0, |t| self.now - t);
        self.max_urb_wait_s.max(current)
    }

    /// A packet into the URB; the URB completes when full or on a short packet.
    fn urb_packet(&mut self, data: &[u8], mps: usize) {
        if !data.is_empty() && self.urb.is_empty() {
            self.urb_since = Some(self.now);
        }
        self.urb.extend_from_slice(data);
        if data.is_empty() {
            self.zlps += 1;
        }
        if data.len() < mps || self.urb.len() >= URB_SIZE {
            if let Some(t) = self.urb_since.take() {
                self.max_urb_wait_s = self.max_urb_wait_s.max(self.now - t);
            }
            let urb = std::mem::take(&mut self.urb);
            self.rx.extend_from_slice(&urb);
        }
    }

    /// One IN token to bulk IN: data (kept if its toggle is the expected one), NAK (retry after
    /// a change) or STALL (reading stops).
    pub(super) fn bulk_in(&mut self, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        let Some(cdc) = self.cdc else { return Ok(()) };
        let (ep, mps) = cdc.bulk_in;
        match dev.in_token(self.addr, (ep & 0x7F) as usize, phy)? {
            Ok(p) => {
                if p.data.len() > mps as usize {
                    self.errors.push(format!("babble on bulk IN 0x{ep:02X}: {} bytes (max {mps})", p.data.len()));
                } else if p.toggle != self.in_toggle {
                    self.toggle_errors += 1;
                } else {
                    self.in_toggle = !self.in_toggle;
                    self.rx_total += p.data.len() as u64;
                    self.urb_packet(&p.data, mps as usize);
                }
                self.in_next = Next::At(self.now + txn_s(p.data.len()));
            }
            Err(Handshake::Nak) => self.in_next = Next::AfterChange(dev.generation),
            Err(Handshake::Stall) => {
                self.errors.push(format!("bulk IN 0x{ep:02X} stalled: reading stops"));
                self.reading = false;
            }
            Err(_) => self.silent(&format!("bulk IN 0x{ep:02X}"), dev, phy),
        }
        Ok(())
    }

    /// One packet of the queued bytes to bulk OUT: ACK (dropped from the queue), NAK (retry
    /// after a change) or STALL (the queue dropped).
    pub(super) fn bulk_out(&mut self, dev: &mut Usbd, phy: Phy) -> Result<(), String> {
        let Some(cdc) = self.cdc else { return Ok(()) };
        let (ep, mps) = cdc.bulk_out;
        let n = self.tx.len().min(mps as usize);
        let pkt: Vec<u8> = self.tx.iter().take(n).copied().collect();
        match dev.out_token(self.addr, ep as usize, &pkt, self.out_toggle, phy)? {
            Handshake::Ack => {
                self.out_toggle = !self.out_toggle;
                self.tx.drain(..n);
                self.tx_total += n as u64;
                self.out_packets.push(n as u16);
                self.out_next = Next::At(self.now + txn_s(n));
            }
            Handshake::Nak => self.out_next = Next::AfterChange(dev.generation),
            Handshake::Stall => {
                self.errors.push(format!("bulk OUT 0x{ep:02X} stalled: {} bytes dropped", self.tx.len()));
                self.tx.clear();
            }
            Handshake::Silent => self.silent(&format!("bulk OUT 0x{ep:02X}"), dev, phy),
        }
        Ok(())
    }
}
