//! Timestamps for FIFO batches from the MCU clock.
//!
//! The sensor samples on its own oscillator, several percent off the nominal ODR but steady: the
//! time of sample `k` is `t₀ + k·P`. Each FIFO read at MCU time `t` bounds the newest sample
//! (`t₀ + k·P ≤ t < t₀ + (k+1)·P` plus the read latency); a least-squares line through
//! (newest index, read time) over every batch gives `P` and `t₀` (offset by the mean latency, a
//! constant that no integral sees). So samples get evenly spaced times at the measured period,
//! never the nominal ODR, and not the batch-to-batch jitter of the read times.

use calib_core::Time;

/// Assigns MCU timestamps to FIFO samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stamper {
    nominal_period_s: f64,
    /// Rows `t_read ≈ t₀ + k_newest·P`, indices from the first sample since (re)start.
    fit: LineSums,
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
        Self { nominal_period_s: 1.0 / nominal_hz.max(1.0) as f64, fit: LineSums::EMPTY, first_read_s: None, received: 0, line: None }
    }

    /// The measured sample period (s), or the nominal one before it can be measured.
    pub fn period_s(&self) -> f64 {
        self.line.map_or(self.nominal_period_s, |(_, p)| p)
    }

    /// Registers a batch of `n` samples read at `t_read`; `stamp(i)` of the returned batch gives
    /// the time of sample `i` (0 = oldest).
    pub fn batch(&mut self, t_read: Time, n: usize) -> Batch {
        self.add(t_read.s(), n, true)
    }

    /// [`Self::batch`] for a batch whose newest sample's time is not known to better than a
    /// period (a BMI270 read without a trusted sensortime date): its samples are counted, its
    /// time does not enter the line.
    pub fn undated(&mut self, t_read: Time, n: usize) -> Batch {
        self.add(t_read.s(), n, false)
    }

    fn add(&mut self, t_read_s: f64, n: usize, dated: bool) -> Batch {
        let t0 = *self.first_read_s.get_or_insert(t_read_s);
        let first_index = self.received;
        self.received += n as u64;
        if n > 0 && dated {
            // Times relative to the first read keep the sums well conditioned.
            self.fit.add((self.received - 1) as f64, t_read_s - t0);
            if self.fit.n >= MIN_BATCHES {
                if let Some((a, p)) = self.fit.line() {
                    if p > 0.5 * self.nominal_period_s && p < 2.0 * self.nominal_period_s {
                        self.line = Some((t0 + a, p));
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

/// The sums of a least-squares line `t ≈ a + k·p` through rows `(k, t)`, in `f64`: sample
/// indices reach millions and times thousands of seconds, beyond `f32`'s 24 bits.
#[derive(Debug, Clone, Copy, PartialEq)]
struct LineSums {
    n: u32,
    k: f64,
    kk: f64,
    t: f64,
    kt: f64,
}

impl LineSums {
    const EMPTY: LineSums = LineSums { n: 0, k: 0.0, kk: 0.0, t: 0.0, kt: 0.0 };

    fn add(&mut self, k: f64, t: f64) {
        self.n += 1;
        self.k += k;
        self.kk += k * k;
        self.t += t;
        self.kt += k * t;
    }

    /// `(a, p)`; `None` while every row has one index.
    fn line(&self) -> Option<(f64, f64)> {
        let n = self.n as f64;
        let d = n * self.kk - self.k * self.k;
        (d > 0.0).then(|| {
            let p = (n * self.kt - self.k * self.t) / d;
            ((self.t - p * self.k) / n, p)
        })
    }
}

/// Timestamps of one batch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Batch {
    origin_s: f64,
    period_s: f64,
}

impl Batch {
    /// Time of sample `i` of the batch (0 = oldest), to the nearest µs.
    pub fn stamp(&self, i: usize) -> Time {
        Time::from_s(self.stamp_s(i)).unwrap_or(Time::ZERO)
    }

    fn stamp_s(&self, i: usize) -> f64 {
        self.origin_s + i as f64 * self.period_s
    }

    /// Whether its newest (`n − 1`th) sample, read at `t_read`, is older than a read can see
    /// (at most a period and the read's latency): samples were lost uncounted, an overrun whose
    /// flag a later slot read cleared (e.g. past a long call inside the batch before). The
    /// stamper must then [`Stamper::restart`]: its count is wrong for good.
    pub fn late(&self, t_read: Time, n: usize) -> bool {
        n > 0 && t_read.s() - self.stamp_s(n - 1) > LATE_PERIODS * self.period_s + LATE_S
    }
}
