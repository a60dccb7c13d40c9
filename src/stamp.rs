//! Timestamps for FIFO batches from the MCU clock.
//!
//! The sensor samples on its own oscillator, several percent off the nominal ODR but steady: the
//! time of sample `k` is `t₀ + k·P`. Each FIFO read at MCU time `t` bounds the newest sample
//! (`t₀ + k·P ≤ t < t₀ + (k+1)·P` plus the read latency); a least-squares line through
//! (newest index, read time) over every batch gives `P` and `t₀` (offset by the mean latency, a
//! constant that no integral sees). So samples get evenly spaced times at the measured period,
//! never the nominal ODR, and not the batch-to-batch jitter of the read times.

use calib_core::math::wide::Wide;
use calib_core::Time;

/// Assigns MCU timestamps to FIFO samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stamper {
    nominal_period_s: Wide,
    /// Rows `t_read ≈ t₀ + k_newest·P` (s from the first read), indices from the first sample
    /// since (re)start.
    fit: LineSums,
    first_read: Option<Time>,
    received: u64,
    /// `(t₀, P)` (s).
    line: Option<(Wide, Wide)>,
}

/// Reads needed before the line is trusted.
const MIN_BATCHES: u32 = 8;
/// A newest sample this many periods (µs per s) and [`LATE_US`] older than its read: samples
/// lost ([`Batch::late`]).
const LATE_PERIODS_US: Wide = Wide::new(4e6);
/// The read latency allowed beyond [`LATE_PERIODS_US`] (µs).
const LATE_US: i64 = 5_000;
/// µs in a second.
const MEGA: Wide = Wide::new(1e6);

impl Stamper {
    /// `nominal_hz` is used only until the period has been measured.
    pub fn new(nominal_hz: f32) -> Self {
        Self {
            nominal_period_s: Wide::ONE / Wide::new(nominal_hz.max(1.0)),
            fit: LineSums::EMPTY,
            first_read: None,
            received: 0,
            line: None,
        }
    }

    /// The measured sample period (s), or the nominal one before it can be measured.
    pub fn period_s(&self) -> f32 {
        self.line.map_or(self.nominal_period_s, |(_, p)| p).to_f32()
    }

    /// Registers a batch of `n` samples read at `t_read`; `stamp(i)` of the returned batch gives
    /// the time of sample `i` (0 = oldest).
    pub fn batch(&mut self, t_read: Time, n: usize) -> Batch {
        self.add(t_read, n, true)
    }

    /// [`Self::batch`] for a batch whose newest sample's time is not known to better than a
    /// period (a BMI270 read without a trusted sensortime date): its samples are counted, its
    /// time does not enter the line.
    pub fn undated(&mut self, t_read: Time, n: usize) -> Batch {
        self.add(t_read, n, false)
    }

    fn add(&mut self, t_read: Time, n: usize, dated: bool) -> Batch {
        let t0 = *self.first_read.get_or_insert(t_read);
        // Times relative to the first read keep the sums well conditioned.
        let t_s = Wide::from_i64(t_read.us() - t0.us()) / MEGA;
        let first_index = self.received;
        self.received += n as u64;
        if n > 0 && dated {
            self.fit.add(Wide::from_i64((self.received - 1) as i64), t_s);
            if self.fit.n >= MIN_BATCHES {
                if let Some((a, p)) = self.fit.line() {
                    let nominal = self.nominal_period_s;
                    if p + p > nominal && p < nominal + nominal {
                        self.line = Some((a, p));
                    }
                }
            }
        }
        let (origin_s, period_s) = match self.line {
            Some((a, p)) => (a + Wide::from_i64(first_index as i64) * p, p),
            // Before the fit: the newest sample at the read time, nominal spacing.
            None => (t_s - Wide::from_i64(n.saturating_sub(1) as i64) * self.nominal_period_s, self.nominal_period_s),
        };
        Batch { t0, origin_s, period_s }
    }

    /// Forgets the history (after a FIFO overrun the sample count no longer matches the time).
    pub fn restart(&mut self) {
        *self = Self { fit: LineSums::EMPTY, first_read: None, received: 0, line: None, ..*self };
    }
}

/// The sums of a least-squares line `t ≈ a + k·p` through rows `(k, t)`, in [`Wide`] (48 bits):
/// sample indices reach millions and times thousands of seconds, beyond `f32`'s 24 bits.
#[derive(Debug, Clone, Copy, PartialEq)]
struct LineSums {
    n: u32,
    k: Wide,
    kk: Wide,
    t: Wide,
    kt: Wide,
}

impl LineSums {
    const EMPTY: LineSums = LineSums { n: 0, k: Wide::ZERO, kk: Wide::ZERO, t: Wide::ZERO, kt: Wide::ZERO };

    fn add(&mut self, k: Wide, t: Wide) {
        self.n += 1;
        self.k += k;
        self.kk += k * k;
        self.t += t;
        self.kt += k * t;
    }

    /// `(a, p)`; `None` while every row has one index.
    fn line(&self) -> Option<(Wide, Wide)> {
        let n = Wide::from_i64(self.n.into());
        let d = n * self.kk - self.k * self.k;
        (d > Wide::ZERO).then(|| {
            let p = (n * self.kt - self.k * self.t) / d;
            ((self.t - p * self.k) / n, p)
        })
    }
}

/// Timestamps of one batch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Batch {
    /// The first read's time, which the others count from.
    t0: Time,
    origin_s: Wide,
    period_s: Wide,
}

impl Batch {
    /// Time of sample `i` of the batch (0 = oldest), to the nearest µs.
    pub fn stamp(&self, i: usize) -> Time {
        let s = self.origin_s + Wide::from_i64(i as i64) * self.period_s;
        Time::from_us(self.t0.us().saturating_add((s * MEGA).round_i64()))
    }

    /// Whether its newest (`n − 1`th) sample, read at `t_read`, is older than a read can see
    /// (at most a period and the read's latency): samples were lost uncounted, an overrun whose
    /// flag a later slot read cleared (e.g. past a long call inside the batch before). The
    /// stamper must then [`Stamper::restart`]: its count is wrong for good.
    pub fn late(&self, t_read: Time, n: usize) -> bool {
        n > 0 && t_read.us() - self.stamp(n - 1).us() > (LATE_PERIODS_US * self.period_s).round_i64() + LATE_US
    }
}
