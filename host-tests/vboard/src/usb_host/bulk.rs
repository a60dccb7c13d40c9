//! Bulk transfers on the CDC data interface: the IN endpoint polled while reading (received
//! bytes kept for [`Host::read`]), bytes queued by [`Host::write`] sent to the OUT endpoint in
//! packets of up to wMaxPacketSize, and the data toggles of both.

use super::{txn_s, Host, Next};
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

    /// Takes the bytes received on bulk IN so far.
    pub fn read(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.rx)
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
                    self.rx.extend_from_slice(&p.data);
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
