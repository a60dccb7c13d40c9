//! Timestamps for FIFO batches from the MCU clock.
//!
//! A batch of `n` samples read at MCU time `t` ends with the newest sample; the samples are
//! spaced by the sensor's *measured* period (MCU time elapsed over samples received since the
//! first batch), never the nominal ODR, which is several percent off on real boards.

/// Assigns MCU timestamps to FIFO samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stamper {
    nominal_period_s: f64,
    first: Option<(f64, u64)>,
    received: u64,
    last: Option<f64>,
}

impl Stamper {
    /// `nominal_hz` is used only until two batches have been seen.
    pub fn new(nominal_hz: f32) -> Self {
        Self { nominal_period_s: 1.0 / nominal_hz.max(1.0) as f64, first: None, received: 0, last: None }
    }

    /// The measured sample period (s), or the nominal one before it can be measured.
    pub fn period_s(&self) -> f64 {
        match self.first {
            Some((t0, n0)) if self.received > n0 + 16 => {
                let t = self.last.unwrap_or(t0);
                if t > t0 {
                    (t - t0) / (self.received - n0) as f64
                } else {
                    self.nominal_period_s
                }
            }
            _ => self.nominal_period_s,
        }
    }

    /// Registers a batch of `n` samples read at `t_read_s`; `stamp(i)` of the returned batch gives
    /// the time of sample `i` (0 = oldest).
    pub fn batch(&mut self, t_read_s: f64, n: usize) -> Batch {
        if self.first.is_none() && n > 0 {
            self.first = Some((t_read_s, n as u64));
        }
        self.received += n as u64;
        self.last = Some(t_read_s);
        Batch { t_read_s, n, period_s: self.period_s() }
    }

    /// Forgets the history (after a FIFO overrun, the count no longer matches the time).
    pub fn restart(&mut self) {
        *self = Self { nominal_period_s: self.nominal_period_s, first: None, received: 0, last: None };
    }
}

/// Timestamps of one batch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Batch {
    t_read_s: f64,
    n: usize,
    period_s: f64,
}

impl Batch {
    /// Time (s) of sample `i` of the batch (0 = oldest).
    pub fn stamp(&self, i: usize) -> f64 {
        self.t_read_s - (self.n.saturating_sub(1 + i)) as f64 * self.period_s
    }
}
