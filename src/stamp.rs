//! Timestamps for FIFO batches from the MCU clock.
//!
//! The sensor samples on its own oscillator, several percent off the nominal ODR but steady: the
//! time of sample `k` is `t₀ + k·P`. Each FIFO read at MCU time `t` bounds the newest sample
//! (`t₀ + k·P ≤ t < t₀ + (k+1)·P` plus the read latency); a least-squares line through
//! (newest index, read time) over every batch gives `P` and `t₀` (offset by the mean latency, a
//! constant that no integral sees). So samples get evenly spaced times at the measured period,
//! never the nominal ODR, and not the batch-to-batch jitter of the read times.

use calib_core::math::lsq::NormalEquations;

/// Assigns MCU timestamps to FIFO samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stamper {
    nominal_period_s: f64,
    /// Rows `[1, k_newest] · [t₀, P] ≈ t_read`, indices from the first sample since (re)start.
    fit: NormalEquations<2>,
    first_read_s: Option<f64>,
    received: u64,
    line: Option<(f64, f64)>,
}

/// Reads needed before the line is trusted.
const MIN_BATCHES: u32 = 8;
/// A newest sample this many periods and [`LATE_S`] older than its read: samples lost
/// ([`Batch::late`]).
const LATE_PERIODS: f64 = 4.0;
/// The read latency allowed beyond [`LATE_PERIODS`] (s).
const LATE_S: f64 = 0.005;

impl Stamper {
    /// `nominal_hz` is used only until the period has been measured.
    pub fn new(nominal_hz: f32) -> Self {
        Self {
            nominal_period_s: 1.0 / nominal_hz.max(1.0) as f64,
            fit: NormalEquations::new(),
            first_read_s: None,
            received: 0,
            line: None,
        }
    }

    /// The measured sample period (s), or the nominal one before it can be measured.
    pub fn period_s(&self) -> f64 {
        self.line.map_or(self.nominal_period_s, |(_, p)| p)
    }

    /// Registers a batch of `n` samples read at `t_read_s`; `stamp(i)` of the returned batch gives
    /// the time of sample `i` (0 = oldest).
    pub fn batch(&mut self, t_read_s: f64, n: usize) -> Batch {
        self.add(t_read_s, n, true)
    }

    /// [`Self::batch`] for a batch whose newest sample's time is not known to better than a
    /// period (a BMI270 read without a trusted sensortime date): its samples are counted, its
    /// time does not enter the line.
    pub fn undated(&mut self, t_read_s: f64, n: usize) -> Batch {
        self.add(t_read_s, n, false)
    }

    fn add(&mut self, t_read_s: f64, n: usize, dated: bool) -> Batch {
        let t0 = *self.first_read_s.get_or_insert(t_read_s);
        let first_index = self.received;
        self.received += n as u64;
        if n > 0 && dated {
            // Times relative to the first read keep the sums well conditioned.
            let _ = self.fit.add_row(&[1.0, (self.received - 1) as f64], t_read_s - t0, 1.0);
            if self.fit.rows() >= MIN_BATCHES {
                // The line alone: its condition number and covariance are not used.
                if let Ok(x) = self.fit.estimate() {
                    if x[1] > 0.5 * self.nominal_period_s && x[1] < 2.0 * self.nominal_period_s {
                        self.line = Some((t0 + x[0], x[1]));
                    }
                }
            }
        }
        match self.line {
            Some((a, p)) => Batch { origin_s: a + first_index as f64 * p, period_s: p },
            // Before the fit: the newest sample at the read time, nominal spacing.
            None => Batch { origin_s: t_read_s - n.saturating_sub(1) as f64 * self.nominal_period_s, period_s: self.nominal_period_s },
        }
    }

    /// Forgets the history (after a FIFO overrun the sample count no longer matches the time).
    pub fn restart(&mut self) {
        *self = Self::new((1.0 / self.nominal_period_s) as f32);
    }
}

/// Timestamps of one batch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Batch {
    origin_s: f64,
    period_s: f64,
}

impl Batch {
    /// Time (s) of sample `i` of the batch (0 = oldest).
    pub fn stamp(&self, i: usize) -> f64 {
        self.origin_s + i as f64 * self.period_s
    }

    /// Whether its newest (`n − 1`th) sample, read at `t_read_s`, is older than a read can see
    /// (at most a period and the read's latency): samples were lost uncounted, an overrun whose
    /// flag a later slot read cleared (e.g. past a long call inside the batch before). The
    /// stamper must then [`Stamper::restart`]: its count is wrong for good.
    pub fn late(&self, t_read_s: f64, n: usize) -> bool {
        n > 0 && t_read_s - self.stamp(n - 1) > LATE_PERIODS * self.period_s + LATE_S
    }
}
