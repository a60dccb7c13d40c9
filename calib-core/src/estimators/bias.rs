//! Gyro bias from a rest period, and the bias tracked between rests.
//!
//! A MEMS gyro's zero rate moves over a calibration (warm-up after power-on, temperature, bias
//! instability), and every rest measures it anew, together with the Earth's rate in that pose's
//! frame. A move's integral therefore subtracts the bias of the two rests that bound it, linear in
//! time between their mean times ([`RestBias::integral_deg`]): a drift that is smooth over a few
//! seconds (a warm-up of τ ≥ 1 min) leaves `h² b'' / 8` (h the rest-to-rest time), and the
//! Earth's rate is removed to first order in the move's turn with no latitude needed.

use crate::math::real::{self, Real};
use crate::math::stats::Moments3;
use crate::{Error, Time, Vec3};

/// Limits applied to a bias estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BiasLimits {
    /// Fewest samples of rest.
    pub min_samples: u32,
    /// Largest |bias| per axis (°/s). LSM9DS1 zero-rate level: ±30 °/s typical at 2000 °/s FS.
    pub max_bias_dps: f32,
    /// Largest per-axis gyro standard deviation during the rest (°/s).
    pub max_std_dps: f32,
    /// Largest per-axis accelerometer standard deviation during the rest (g).
    pub max_accel_std_g: f32,
}

impl BiasLimits {
    /// The defaults (also as `Default`).
    pub const DEFAULT: BiasLimits = BiasLimits { min_samples: 100, max_bias_dps: 30.0, max_std_dps: 0.8, max_accel_std_g: 0.006 };
}

impl Default for BiasLimits {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A gyro bias estimate (raw units: °/s in the sensor frame).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Bias {
    /// Mean gyro reading at rest (°/s).
    pub bias_dps: Vec3,
    /// 1σ of the mean (°/s).
    pub sigma_dps: Vec3,
    /// Per-axis noise standard deviation (°/s).
    pub noise_dps: Vec3,
    /// Samples averaged.
    pub samples: u32,
}

/// A rest's gyro mean relative to the bias the integrals subtract (°/s, sensor frame) and the
/// mean time of its samples (MCU clock).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct RestBias {
    /// Mean time of the rest's samples.
    #[cfg_attr(feature = "serde", serde(rename = "t_s"))]
    pub t: Time,
    /// Its mean gyro reading minus the reference bias (°/s).
    pub residual_dps: Vec3,
}

impl RestBias {
    /// A rest from its first and last sample times, its mean gyro reading (°/s) and the
    /// reference bias the integrals subtract (°/s).
    pub fn new(t_first: Time, t_last: Time, gyro_mean_dps: Vec3, reference_dps: Vec3) -> Self {
        let residual_dps = core::array::from_fn(|k| gyro_mean_dps[k] - reference_dps[k]);
        Self { t: t_first.midpoint(t_last), residual_dps: if residual_dps.iter().all(|v| v.is_finite()) { residual_dps } else { [0.0; 3] } }
    }

    /// `∫ b(t) dt` over `[t0, t1]` (°), `b` the residual bias on the line through `self` and `to`
    /// (constant when both rests are at one time): what a move's integral over that span must
    /// lose.
    pub fn integral_deg(&self, to: &RestBias, t0: Time, t1: Time) -> [Real; 3] {
        let span = to.t.since(self.t);
        let f = if span > 0.0 { 0.5 * (t0.since(self.t) + t1.since(self.t)) / span } else { 0.5 };
        core::array::from_fn(|k| {
            let (a, b) = (self.residual_dps[k] as Real, to.residual_dps[k] as Real);
            t1.since(t0) * (a + (b - a) * f)
        })
    }

    /// The bias at time `t` on the line from `self` to `to` (`self`'s when both are at one
    /// time).
    pub fn between(&self, to: &RestBias, t: Time) -> RestBias {
        let span = to.t.since(self.t);
        let f = if span > 0.0 { (t.since(self.t) / span) as f32 } else { 0.0 };
        RestBias { t, residual_dps: core::array::from_fn(|k| self.residual_dps[k] + (to.residual_dps[k] - self.residual_dps[k]) * f) }
    }

    /// The bias's largest rate of change from `self` to a later rest `to` (°/s per minute, ≥ 0;
    /// 0 for rests at one time).
    pub fn drift_dps_per_min(&self, to: &RestBias) -> f32 {
        let span = to.t.since(self.t);
        if !(span > 0.0) {
            return 0.0;
        }
        let change = (0..3).map(|k| (to.residual_dps[k] - self.residual_dps[k]).abs()).fold(0.0f32, f32::max);
        (change as Real * 60.0 / span) as f32
    }
}

/// Longest gap (s) between consecutive rests for [`Drift::off_trend_dps`]: over a longer gap
/// (the board re-attached) even a smooth warm-up curves away from a line.
pub const MAX_TREND_GAP_S: Real = 10.0;

/// The rests of a calibration in time order: the bias's drift over it, and how far a rest's
/// bias left the line through its two neighbours (what tracking cannot follow: a smooth drift
/// of τ ≥ 1 min stays within 1e-3 °/s of it over 10 s; rest-mean noise ≈ 0.007 °/s).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Drift {
    first: Option<RestBias>,
    before: Option<RestBias>,
    last: Option<RestBias>,
    off_trend_dps: f32,
    line: Line,
    recent: Line,
}

/// A hand-held pose measures the bias when its gyro scatter is within this factor of the bias
/// rest's noise (per axis, largest): [`Drift::shaky`].
pub const HAND_STILL_NOISE: f32 = 1.2;

/// Memory of [`Drift::at`]'s line (s): older rests fade by `e^(−Δt/τ)`, so a warm-up's curve
/// (τ ≥ 1 min) is followed and rest noise is still averaged over several rests.
pub const TREND_MEMORY_S: Real = 30.0;

/// Memory of [`Drift::predict`]'s line (s). A fading line lags a curve by `b'' τ²` where it
/// ends: 0.013 °/s for τ = 30 s at the end of a 0.2 °/s warm-up of 60 s, 2e-3 for 12 s, while
/// its noise at the end grows only as `√(2/Σw)` of a rest's.
pub const PREDICT_MEMORY_S: Real = 12.0;

/// A line through the rests' biases, least squares with fading weights (sums of `w`, `w t`,
/// `w t²`, `w b`, `w t b`, `w b²` and, for its noise, `w²`, `w² t`, `w² t²`; `t` from the first
/// rest).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Line {
    t0: Time,
    t_last: Time,
    s: [Real; 3],
    b: [Real; 3],
    tb: [Real; 3],
    bb: [Real; 3],
    w2: [Real; 3],
}

impl Line {
    const EMPTY: Line = Line { t0: Time::ZERO, t_last: Time::ZERO, s: [0.0; 3], b: [0.0; 3], tb: [0.0; 3], bb: [0.0; 3], w2: [0.0; 3] };

    /// A rest, older ones faded by `e^(−Δt/memory_s)`; the first sets `t0`.
    fn add(&mut self, rest: &RestBias, first: bool, memory_s: Real) {
        if first {
            self.t0 = rest.t;
        } else {
            let fade = real::exp(-rest.t.since(self.t_last).max(0.0) / memory_s);
            for v in self.s.iter_mut().chain(self.b.iter_mut()).chain(self.tb.iter_mut()).chain(self.bb.iter_mut()) {
                *v *= fade;
            }
            for v in self.w2.iter_mut() {
                *v *= fade * fade;
            }
        }
        let t = rest.t.since(self.t0);
        self.t_last = rest.t;
        self.s = [self.s[0] + 1.0, self.s[1] + t, self.s[2] + t * t];
        self.w2 = [self.w2[0] + 1.0, self.w2[1] + t, self.w2[2] + t * t];
        for k in 0..3 {
            let b = rest.residual_dps[k] as Real;
            self.b[k] += b;
            self.tb[k] += t * b;
            self.bb[k] += b * b;
        }
    }

    /// Weighted mean time from `t0` and `Σw (t − t̄)²`; `None` for rests at one time (their mean
    /// then).
    fn spread(&self) -> (Real, Option<Real>) {
        let tm = self.s[1] / self.s[0];
        let sxx = (self.s[2] - self.s[1] * tm).max(0.0);
        (tm, (sxx > 1e-6 * self.s[2]).then_some(sxx))
    }

    /// Mean and slope of axis `k`.
    fn fit(&self, k: usize) -> (Real, Real) {
        let mean = self.b[k] / self.s[0];
        match self.spread() {
            (_, Some(sxx)) => (mean, (self.tb[k] - self.s[1] * mean) / sxx),
            (_, None) => (mean, 0.0),
        }
    }

    /// `Σ wᵢ² cᵢ²` for the prediction `Σ wᵢ cᵢ bᵢ` at `t` (its variance over a rest's), and the
    /// effective number of rests `(Σw)² / Σw²`.
    fn lever(&self, t: Time) -> (Real, Real) {
        let (tm, sxx) = self.spread();
        let (s0, w) = (self.s[0], &self.w2);
        let mut l = w[0] / (s0 * s0);
        if let Some(sxx) = sxx {
            let d = t.since(self.t0) - tm;
            l += 2.0 * d / (s0 * sxx) * (w[1] - tm * w[0]) + d * d / (sxx * sxx) * (w[2] - 2.0 * tm * w[1] + tm * tm * w[0]);
        }
        (l.max(0.0), s0 * s0 / w[0])
    }

    /// The line's bias at `t`.
    fn at(&self, t: Time) -> Vec3 {
        let tm = self.spread().0;
        core::array::from_fn(|k| {
            let (mean, slope) = self.fit(k);
            (mean + slope * (t.since(self.t0) - tm)) as f32
        })
    }
}

impl Drift {
    /// No rest yet.
    pub const fn new() -> Self {
        Self { first: None, before: None, last: None, off_trend_dps: 0.0, line: Line::EMPTY, recent: Line::EMPTY }
    }

    /// A rest, in time order.
    pub fn add(&mut self, rest: RestBias) {
        let first = self.first.is_none();
        self.line.add(&rest, first, TREND_MEMORY_S);
        self.recent.add(&rest, first, PREDICT_MEMORY_S);
        self.first.get_or_insert(rest);
        if let (Some(a), Some(m)) = (self.before, self.last) {
            if m.t.since(a.t) <= MAX_TREND_GAP_S && rest.t.since(m.t) <= MAX_TREND_GAP_S && rest.t > a.t {
                let f = m.t.since(a.t) as f32 / rest.t.since(a.t) as f32;
                for k in 0..3 {
                    let line = a.residual_dps[k] + (rest.residual_dps[k] - a.residual_dps[k]) * f;
                    self.off_trend_dps = self.off_trend_dps.max((m.residual_dps[k] - line).abs());
                }
            }
        }
        self.before = self.last;
        self.last = Some(rest);
    }

    /// The largest distance of a rest's bias from the line through its neighbours (°/s, any
    /// axis; rests more than [`MAX_TREND_GAP_S`] apart are not compared).
    pub fn off_trend_dps(&self) -> f32 {
        self.off_trend_dps
    }

    /// A hand-held pose: its rest `measured` (its gyro mean), its largest per-axis gyro
    /// standard deviation and the bias rest's noise (°/s). As still as the bias rest (within
    /// [`HAND_STILL_NOISE`] times its noise: the board laid down) it is a rest and `None` is
    /// returned; otherwise the bias [`Self::at`] the pose's time, a prediction until the next
    /// rest (`Rotations::settle_bias`): a hand's sway turns the board by tenths of a degree
    /// within a pose, so its gyro mean is not the bias.
    pub fn shaky(&self, measured: RestBias, gyro_std_dps: f32, noise_dps: f32) -> Option<RestBias> {
        (gyro_std_dps > HAND_STILL_NOISE * noise_dps).then(|| self.at(measured.t).unwrap_or(measured))
    }

    /// The latest rest.
    pub fn last(&self) -> Option<RestBias> {
        self.last
    }

    /// The bias at MCU time `t` as the rests so far give it (their line, recent rests weighted
    /// most: [`TREND_MEMORY_S`]; one rest or rests at one time: their mean): what a pose too
    /// shaky to measure it (a hand's sway) uses. `None` before the first rest.
    pub fn at(&self, t: Time) -> Option<RestBias> {
        self.last?;
        Some(RestBias { t, residual_dps: self.line.at(t) })
    }

    /// The bias at `t` on the line of the latest rests ([`PREDICT_MEMORY_S`]: the bias a
    /// calibration hands over) with its 1σ per axis (°/s): the line's prediction error `s² Σ wᵢ²
    /// cᵢ²` (the prediction is `Σ wᵢ cᵢ bᵢ`), `s²` a rest's variance ([`RestNoise`]: its own
    /// noise, or the rests' scatter about the line where that exceeds it), a bias walk of
    /// [`BIAS_WALK_DPS_RTSEC`] from the latest rest to `t`, and the Earth's rate every rest
    /// measures as bias in its own pose ([`EARTH_RATE_AXIS_DPS`]).
    pub fn predict(&self, t: Time, noise: RestNoise) -> Option<(RestBias, Vec3)> {
        self.last?;
        let l = &self.recent;
        let params = if l.spread().1.is_some() { 2.0 } else { 1.0 };
        let (lever, n_eff) = l.lever(t);
        let dof = n_eff - params;
        let walk = BIAS_WALK_DPS_RTSEC as Real * BIAS_WALK_DPS_RTSEC as Real * t.since(l.t_last).abs();
        let sigma = core::array::from_fn(|k| {
            let (mean, slope) = l.fit(k);
            // Σw (b − mean − slope (t − t̄))².
            let ss = (l.bb[k] - l.b[k] * mean - slope * (l.tb[k] - l.s[1] * mean)).max(0.0);
            // E[Σw r²] = σ² Σw (1 − params / n_eff).
            let scatter = if dof > 0.0 { ss / (l.s[0] * dof / n_eff) } else { 0.0 };
            let s2 = match noise {
                RestNoise::Own(sigma) => {
                    let own = sigma[k] as Real * sigma[k] as Real;
                    if dof < 1.0 {
                        // Too few rests to test the scatter (the χ² point's approximation fails
                        // there too): the larger of it, scaled for its few degrees of freedom,
                        // and the own noise.
                        (scatter * crate::math::lsq::few_dof_factor(dof)).max(own)
                    } else if scatter * dof > own * crate::math::lsq::chi2_95(dof) {
                        scatter
                    } else {
                        own
                    }
                }
                RestNoise::Bound(sigma) => scatter.max(sigma[k] as Real * sigma[k] as Real),
            };
            real::sqrt(s2 * lever + walk + EARTH_RATE_AXIS_DPS * EARTH_RATE_AXIS_DPS) as f32
        });
        Some((RestBias { t, residual_dps: l.at(t) }, sigma))
    }

    /// The bias's largest rate of change from the first rest to the latest (°/s per minute).
    pub fn dps_per_min(&self) -> f32 {
        match (self.first, self.last) {
            (Some(a), Some(b)) => a.drift_dps_per_min(&b),
            _ => 0.0,
        }
    }
}

/// A rest mean's noise (1σ per axis, °/s) as [`Drift::predict`] takes it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RestNoise {
    /// Still rests' own (their samples' spread over `√n`, from hundreds of samples): the rests'
    /// scatter about their line takes its place only where it exceeds it beyond chance (χ²'s
    /// 95 % point, as the accelerometer's 1σ: [`crate::math::lsq::chi2_95`]), a drift the line
    /// does not follow. Below one degree of freedom beyond the line, where no test can be
    /// made, the larger of the two (the scatter times [`crate::math::lsq::few_dof_factor`]).
    Own(Vec3),
    /// A rough one: rests held by a hand, whose means carry their sway's net turn, with the
    /// spread of every still segment pooled (a hand's tremor and sway in it). The larger of it
    /// and the rests' scatter about their line is their variance: from the few rests of a log
    /// (3-4 effective beyond the line's two) the scatter can fall below it by chance.
    Bound(Vec3),
}

/// 1σ per axis of the Earth's rate (15.04 °/h) along an axis of unknown direction (`/√3`), °/s:
/// a rest measures it as bias, in the attitude the board happens to have.
pub const EARTH_RATE_AXIS_DPS: Real = crate::estimators::rotation::EARTH_RATE_RAD_S * (180.0 / crate::math::real::consts::PI) / 1.732_050_8;

/// Least temperature span (°C) over the rests for [`TempFit`] to give a coefficient.
pub const MIN_TEMP_SPAN_C: f32 = 1.0;
/// Standard errors of the walk's estimate added to it in [`TempCo`]'s 1σ ([`TempFit`]): with
/// 0.5, 92–100 % of the coefficients lie within 2σ for walks from none to 4e-3 °/s/√s (tested).
pub const WALK_UPPER_Z: Real = 0.5;

/// Bias rate random walk (°/s/√s) assumed by [`Drift::predict`] from the latest rest to the
/// record's time (seconds: a small term); [`TempFit`] measures the calibration's own.
pub const BIAS_WALK_DPS_RTSEC: f32 = 5e-4;

/// The zero rate's temperature coefficient: `b(T) = b₀ + c (T − T₀)`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct TempCo {
    /// `c` per sensor axis (°/s per °C).
    pub dps_per_c: Vec3,
    /// Its 1σ (°/s per °C): the rests' white scatter and their bias walk ([`TempFit::finish`]).
    pub sigma_dps_per_c: Vec3,
    /// Lowest and highest rest temperature (°C).
    pub range_c: [f32; 2],
}

/// Fits [`TempCo`] over the rests of a calibration, each with its mean temperature (bounded
/// sums, no buffer), and measures the bias's random walk from the rests' scatter.
///
/// The rests' biases about the fitted line are white noise of variance `s_w²` (a rest mean's
/// noise, the Earth's rate in its pose) plus a random walk of density `q` over the MCU time `t`.
/// Two sums tell them apart: the residuals' squares, `E = (n − 2) s_w² + e q²`, and their
/// consecutive differences', `E = 2 (n − 1) s_w² + Σ Δt q²` (a walk moves little from one rest to
/// the next but far over the run); `e = Σ Δtⱼ (n − kⱼ)(1 − (n − kⱼ)/n) − V / Sxx` is a walk's exact
/// share of the residual sum over these rests (`kⱼ` rests before rest `j`), and the walk's
/// variance in the slope is `q² V / Sxx²` with `V = Σ Δtⱼ (kⱼ T̄ − Pⱼ)²` (`Pⱼ` the sum of the
/// temperatures before rest `j`): what a steadily rising temperature cannot tell from a tempco.
///
/// One run shows its walk poorly: the residuals keep only its part off the temperature curve,
/// a few degrees of freedom, and the rests' white noise leaves a floor (30 rests of 0.007 °/s
/// cannot exclude a walk of ≈ 1e-3 °/s/√s). The 1σ therefore takes `q²` plus
/// [`WALK_UPPER_Z`] standard errors of its estimate: the white sums' (`2 n^1.5 s_w² / |det|`,
/// i.i.d. rests) and the walk's own (`√(2/ν) q²`, `ν ≈ 2.5`: a Brownian bridge's energy lies in its
/// first modes).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TempFit {
    n: u32,
    st: Real,
    stt: Real,
    sb: [Real; 3],
    stb: [Real; 3],
    sbb: [Real; 3],
    t_range: [f32; 2],
    /// The first rest's temperature (°C): the reference of the walk's sums.
    first_c: Real,
    /// The latest rest: time, temperature (°C from the first rest's) and bias (°/s).
    last: (Time, Real, [Real; 3]),
    /// `Σ Δt`, `Σ Δt k`, `Σ Δt k²`, `Σ Δt k P`, `Σ Δt P²` (temperatures from the first rest's).
    walk: [Real; 5],
    /// `Σ` of the temperatures so far, from the first rest's (°C).
    prefix_c: Real,
    /// Per axis `Σ Δb²`, `Σ Δb ΔT`; and `Σ ΔT²`, over consecutive rests.
    dbb: [Real; 3],
    dbt: [Real; 3],
    dtt: Real,
}

impl TempFit {
    /// No rest yet.
    pub const fn new() -> Self {
        Self {
            n: 0,
            st: 0.0,
            stt: 0.0,
            sb: [0.0; 3],
            stb: [0.0; 3],
            sbb: [0.0; 3],
            t_range: [0.0; 2],
            first_c: 0.0,
            last: (Time::ZERO, 0.0, [0.0; 3]),
            walk: [0.0; 5],
            prefix_c: 0.0,
            dbb: [0.0; 3],
            dbt: [0.0; 3],
            dtt: 0.0,
        }
    }

    /// A rest and its mean temperature (°C); a non-finite temperature is left out.
    pub fn add(&mut self, temp_c: f32, rest: &RestBias) {
        if !temp_c.is_finite() {
            return;
        }
        if self.n == 0 {
            self.t_range = [temp_c; 2];
            self.first_c = temp_c as Real;
        }
        let b = rest.residual_dps.map(|v| v as Real);
        let rel = temp_c as Real - self.first_c;
        if self.n > 0 {
            let (t_last, rel_last, b_last) = self.last;
            let (dt, k, p) = (rest.t.since(t_last).max(0.0), self.n as Real, self.prefix_c);
            for (s, v) in self.walk.iter_mut().zip([1.0, k, k * k, k * p, p * p]) {
                *s += dt * v;
            }
            let d_t = rel - rel_last;
            self.dtt += d_t * d_t;
            for k in 0..3 {
                let d_b = b[k] - b_last[k];
                self.dbb[k] += d_b * d_b;
                self.dbt[k] += d_b * d_t;
            }
        }
        self.last = (rest.t, rel, b);
        self.prefix_c += rel;
        self.t_range = [self.t_range[0].min(temp_c), self.t_range[1].max(temp_c)];
        // From the first rest's temperature: `Σ t² − (Σ t)²/n` of temperatures near 24 °C over
        // a 1 °C span loses a part in 6000 to the sums' rounding (in f32 the firmware's tempco
        // came out 0.2 % off the PC's).
        let t = rel;
        self.n += 1;
        self.st += t;
        self.stt += t * t;
        for k in 0..3 {
            self.sb[k] += b[k];
            self.stb[k] += t * b[k];
            self.sbb[k] += b[k] * b[k];
        }
    }

    /// The rests' bias at `temp_c` on the fitted line (relative to their reference, °/s), `None`
    /// while the coefficient is unknown ([`Self::finish`]).
    pub fn residual_at(&self, temp_c: f32) -> Option<Vec3> {
        let c = self.finish()?.dps_per_c;
        let n = self.n as Real;
        let dt = temp_c as Real - self.first_c - self.st / n;
        Some(core::array::from_fn(|k| (self.sb[k] / n + c[k] as Real * dt) as f32))
    }

    /// The coefficient, or `None` when fewer than 4 rests or a span below [`MIN_TEMP_SPAN_C`]
    /// leave it unknown.
    pub fn finish(&self) -> Option<TempCo> {
        let (c, sigma, _) = self.fit()?;
        c.iter().chain(sigma.iter()).all(|v| v.is_finite()).then_some(TempCo {
            dps_per_c: c,
            sigma_dps_per_c: sigma,
            range_c: self.t_range,
        })
    }

    /// The bias's random walk the rests show (°/s/√s, the largest axis'; the type doc), `None`
    /// while the coefficient is unknown ([`Self::finish`]).
    pub fn walk_dps_rtsec(&self) -> Option<f32> {
        self.finish().and(self.fit()).map(|(_, _, q)| q)
    }

    /// Per axis the coefficient and its 1σ (°/s per °C), and the walk (the type doc).
    fn fit(&self) -> Option<(Vec3, Vec3, f32)> {
        let span = self.t_range[1] - self.t_range[0];
        if self.n < 4 || !(span >= MIN_TEMP_SPAN_C) {
            return None;
        }
        let n = self.n as Real;
        let sxx = self.stt - self.st * self.st / n;
        if !(sxx > 0.0) {
            return None;
        }
        let [s_dt, s_dtk, a, b, c2] = self.walk;
        let mean = self.st / n;
        let v = (mean * mean * a - 2.0 * mean * b + c2).max(0.0);
        // A walk's share of the residual sum: Σ Δt (n − k) − Σ Δt (n − k)² / n − V / Sxx.
        let e = ((n * s_dt - s_dtk) - (n * n * s_dt - 2.0 * n * s_dtk + a) / n - v / sxx).max(0.0);
        let det = (n - 2.0) * s_dt - 2.0 * (n - 1.0) * e;
        let (mut c, mut sigma, mut q_max) = ([0.0f32; 3], [0.0f32; 3], 0.0f32);
        for k in 0..3 {
            let sxy = self.stb[k] - self.st * self.sb[k] / n;
            let syy = self.sbb[k] - self.sb[k] * self.sb[k] / n;
            let slope = sxy / sxx;
            let ss = (syy - slope * sxy).max(0.0);
            let dd = (self.dbb[k] - 2.0 * slope * self.dbt[k] + slope * slope * self.dtt).max(0.0);
            // (white, q²) from the two sums, each kept ≥ 0.
            let q2 = if det != 0.0 && e > 0.0 { ((n - 2.0) * dd - 2.0 * (n - 1.0) * ss) / det } else { 0.0 };
            let (white, q2) = match q2 {
                q2 if !(q2 > 0.0) => (ss / (n - 2.0), 0.0),
                q2 if ss < e * q2 => (0.0, ss / e),
                q2 => ((ss - e * q2) / (n - 2.0), q2),
            };
            let se = if det != 0.0 { 2.0 * n * real::sqrt(n) * white / det.abs() } else { 0.0 };
            let upper = q2 + WALK_UPPER_Z * real::sqrt(se * se + 0.8 * q2 * q2);
            c[k] = slope as f32;
            sigma[k] = real::sqrt(white / sxx + upper * v / (sxx * sxx)) as f32;
            q_max = q_max.max(real::sqrt(q2) as f32);
        }
        Some((c, sigma, q_max))
    }
}

/// Accumulates a rest period, then checks it and returns the bias.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BiasEstimator {
    gyro: Moments3,
    accel: Moments3,
}

impl BiasEstimator {
    /// Empty.
    pub const fn new() -> Self {
        Self { gyro: Moments3::new(), accel: Moments3::new() }
    }

    /// Adds one rest sample: raw gyro (°/s), raw accel (g).
    pub fn add(&mut self, gyro_dps: Vec3, accel_g: Vec3) {
        self.gyro.add(gyro_dps);
        self.accel.add(accel_g);
    }

    /// Adds a whole window of rest samples (gyro °/s, accel g), summarised.
    pub fn add_window(&mut self, gyro: &Moments3, accel: &Moments3) {
        self.gyro.merge(gyro);
        self.accel.merge(accel);
    }

    /// Mean accelerometer reading over the rest (g): a free static pose.
    pub fn accel_mean(&self) -> Vec3 {
        let m = self.accel.mean();
        [m[0] as f32, m[1] as f32, m[2] as f32]
    }

    /// The bias, or why the rest period does not give one.
    pub fn finish(&self, limits: &BiasLimits) -> Result<Bias, Error> {
        let n = self.gyro.count();
        if n < limits.min_samples.max(2) {
            return Err(Error::TooFewSamples { have: n, need: limits.min_samples.max(2) });
        }
        let (g_std, a_std) = (self.gyro.max_std(), self.accel.max_std());
        if !(g_std <= limits.max_std_dps as Real && a_std <= limits.max_accel_std_g as Real) {
            return Err(Error::NotStill { gyro_std_dps: g_std as f32, accel_std_g: a_std as f32 });
        }
        let (m, v) = (self.gyro.mean(), self.gyro.variance());
        let mut out = Bias { bias_dps: [0.0; 3], sigma_dps: [0.0; 3], noise_dps: [0.0; 3], samples: n };
        for k in 0..3 {
            if !m[k].is_finite() {
                return Err(Error::NonFinite);
            }
            if m[k].abs() > limits.max_bias_dps as Real {
                return Err(Error::BiasOutOfRange { axis: k as u8, bias_dps: m[k] as f32, limit_dps: limits.max_bias_dps });
            }
            out.bias_dps[k] = m[k] as f32;
            out.noise_dps[k] = real::sqrt(v[k]) as f32;
            out.sigma_dps[k] = real::sqrt(v[k] / n as Real) as f32;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::secs;

    #[test]
    fn a_shaky_pose_takes_the_bias_from_the_rests_line_and_a_still_one_measures_it() {
        let mut d = Drift::new();
        let rest = |t: f64, b: f32| RestBias { t: secs(t), residual_dps: [b, -b, 0.0] };
        assert_eq!(d.at(secs(5.0)), None);
        // Rests on the line 0.01 t (°/s): the line is followed, recent rests weighted most.
        for t in [0.0, 4.0, 8.0, 12.0] {
            d.add(rest(t, 0.01 * t as f32));
        }
        let p = d.at(secs(20.0)).unwrap();
        assert!((p.residual_dps[0] - 0.2).abs() < 1e-5 && (p.residual_dps[1] + 0.2).abs() < 1e-5, "{p:?}");
        // Shaky (gyro scatter 0.5 °/s against a rest noise of 0.2): the prediction; still: none.
        let measured = rest(20.0, 0.9);
        assert_eq!(d.shaky(measured, 0.5, 0.2), Some(p));
        assert_eq!(d.shaky(measured, 0.2, 0.2), None);
        // Settled later between two rests: the line between them.
        let between = rest(12.0, 0.12).between(&rest(32.0, 0.52), secs(20.0));
        assert!((between.residual_dps[0] - 0.28).abs() < 1e-6);
    }

    #[test]
    fn bias_is_the_rest_mean_and_checks_apply() {
        let mut b = BiasEstimator::new();
        for k in 0..200 {
            let e = if k % 2 == 0 { 0.1 } else { -0.1 };
            b.add([1.0 + e, -2.0, 0.5 - e], [0.0, 0.0, 1.0]);
        }
        let r = b.finish(&BiasLimits::default()).unwrap();
        assert!((r.bias_dps[0] - 1.0).abs() < 1e-6 && (r.bias_dps[1] + 2.0).abs() < 1e-6);
        assert!((r.noise_dps[0] - 0.1).abs() < 1e-3 && r.sigma_dps[0] < 0.01);
        let tight = BiasLimits { max_bias_dps: 1.5, ..BiasLimits::default() };
        assert!(matches!(b.finish(&tight), Err(Error::BiasOutOfRange { axis: 1, .. })));
        let few = BiasLimits { min_samples: 500, ..BiasLimits::default() };
        assert_eq!(b.finish(&few), Err(Error::TooFewSamples { have: 200, need: 500 }));
    }

    #[test]
    fn a_move_loses_the_integral_of_the_bias_line_between_its_rests() {
        let (a, b) = (
            RestBias::new(secs(9.0), secs(11.0), [1.1, 2.0, 0.0], [1.0, 2.0, 0.0]),
            RestBias::new(secs(19.0), secs(21.0), [1.3, 1.9, 0.0], [1.0, 2.0, 0.0]),
        );
        assert_eq!((a.t.s(), b.t.s()), (10.0, 20.0));
        // Over [12, 16]: the line is 0.1 + 0.02 (t - 10) on x, its mean at t = 14 is 0.18.
        let i = a.integral_deg(&b, secs(12.0), secs(16.0));
        assert!((i[0] - 4.0 * 0.18).abs() < 1e-6 && (i[1] + 4.0 * 0.04).abs() < 1e-6 && i[2] == 0.0, "{i:?}");
        // Drift: 0.2 °/s on x over 10 s.
        assert!((a.drift_dps_per_min(&b) - 1.2).abs() < 1e-5);
        assert_eq!(b.drift_dps_per_min(&a), 0.0);
        // Two rests at one time: a constant.
        assert!((a.integral_deg(&a, secs(0.0), secs(2.0))[0] - 0.2).abs() < 1e-6);
        assert_eq!(RestBias::new(secs(0.0), secs(1.0), [f32::NAN, 0.0, 0.0], [0.0; 3]).residual_dps, [0.0; 3]);
    }

    #[test]
    fn a_bias_off_the_line_of_its_neighbours_is_measured_a_smooth_drift_is_not() {
        let rest = |t: f64, b: f32| RestBias { t: secs(t), residual_dps: [b, 0.0, -b] };
        let mut smooth = Drift::new();
        for i in 0..20 {
            let t = 4.0 * i as Real;
            smooth.add(rest(t, 0.2 * (1.0 - (-t / 60.0).exp()) as f32));
        }
        assert!(smooth.off_trend_dps() < 2e-3, "{}", smooth.off_trend_dps());
        assert!(smooth.dps_per_min() > 0.1);
        let mut jump = smooth;
        jump.add(rest(80.0, 0.3));
        jump.add(rest(84.0, 0.2));
        // 0.3 at 80 s against the line from 0.144 (76 s) to 0.2 (84 s): 0.128 off.
        assert!((jump.off_trend_dps() - 0.128).abs() < 2e-3, "{}", jump.off_trend_dps());
        // Across a long gap (re-attached), no comparison.
        let mut gap = Drift::new();
        for (t, b) in [(0.0, 0.0), (4.0, 0.1), (100.0, 0.0)] {
            gap.add(rest(t, b));
        }
        assert_eq!(gap.off_trend_dps(), 0.0);
    }

    /// A rest every 4 s for 80 s, on x the bias `x(t)` gives (°/s).
    fn every_4_s(mut x: impl FnMut(Real) -> Real) -> Drift {
        let mut d = Drift::new();
        for i in 0..=20 {
            let t = 4.0 * i as Real;
            d.add(RestBias { t: secs(t), residual_dps: [x(t) as f32, 0.0, 0.0] });
        }
        d
    }

    /// A warm-up (0.2 °/s along 1 − e^(−t/60 s)) seen by a rest every 4 s for 80 s, each rest
    /// mean with 0.007 °/s of noise, 2000 times: the bias predicted for the end (82 s) lies
    /// within its 1σ and 2σ of the curve there as an honest σ promises, and far closer than the
    /// first rest.
    #[test]
    fn the_bias_predicted_for_the_end_of_a_warm_up_covers_the_truth() {
        let mut noise = crate::math::test_noise::Gaussian::new(0x9e37_79b9_7f4a_7c15);
        let curve = |t: f64| 0.2 * (1.0 - libm::exp(-t / 60.0));
        let (mut within, mut err2, runs) = ([0u32; 2], 0.0, 2000);
        for _ in 0..runs {
            let d = every_4_s(|t| curve(t) + 0.007 * noise.next());
            let (at, sigma) = d.predict(secs(82.0), RestNoise::Own([0.007; 3])).unwrap();
            let e = (at.residual_dps[0] as Real - curve(82.0)).abs();
            within[0] += (e <= sigma[0] as Real) as u32;
            within[1] += (e <= 2.0 * sigma[0] as Real) as u32;
            err2 += e * e;
        }
        let [one, two] = within.map(|n| n as Real / runs as Real);
        let rms = libm::sqrt(err2 / runs as Real);
        assert!((0.6..=0.85).contains(&one) && two >= 0.92, "within 1 sigma {one:.3}, 2 sigma {two:.3}");
        assert!(rms < 0.01 && rms < 0.1 * curve(82.0), "RMS {rms:.4}");
    }

    /// Still rests (a rest every 4 s for 80 s, each mean with 0.007 °/s of its own noise), 2000
    /// times: on a constant bias the σ is the rests' own noise propagated, whatever their
    /// scatter, but in the ~5 % of runs whose scatter exceeds χ²'s 95 % point (measured 5.0 %);
    /// on a bias walking at 0.01 °/s/√s (0.02 °/s between rests, 3 times their noise) the
    /// scatter takes its place and the bias predicted for the last rest (80 s) lies within its
    /// 1σ and 2σ as an honest σ promises (measured 67 % / 97 %).
    #[test]
    fn still_rests_take_their_own_noise_unless_the_scatter_exceeds_it() {
        let mut noise = crate::math::test_noise::Gaussian::new(0x2545_f491_4f6c_dd1d);
        let runs = 2000;
        let run = |noise: &mut crate::math::test_noise::Gaussian, walk: Real| {
            let mut b = 0.0;
            let d = every_4_s(|t| {
                if t > 0.0 {
                    b += walk * 2.0 * noise.next();
                }
                b + 0.007 * noise.next()
            });
            let (at, sigma) = d.predict(secs(80.0), RestNoise::Own([0.007; 3])).unwrap();
            ((at.residual_dps[0] as Real - b).abs(), sigma[0] as Real)
        };
        let own = every_4_s(|_| 0.0).predict(secs(80.0), RestNoise::Own([0.007; 3])).unwrap().1[0] as Real;
        let constant = (0..runs).filter(|_| run(&mut noise, 0.0).1 == own).count() as Real / runs as Real;
        assert!((0.92..=0.97).contains(&constant), "own noise's sigma in {constant:.3} of the runs");
        let within = (0..runs).fold([0u32; 2], |w, _| {
            let (e, s) = run(&mut noise, 0.01);
            [w[0] + (e <= s) as u32, w[1] + (e <= 2.0 * s) as u32]
        });
        let [one, two] = within.map(|n| n as Real / runs as Real);
        assert!((0.6..=0.8).contains(&one) && two >= 0.92, "walking: within 1 sigma {one:.3}, 2 sigma {two:.3}");
    }

    /// Three rests 4 s apart (0.8 effective rests beyond the line's two): too few to test their
    /// scatter, which then counts, scaled for its few degrees of freedom, beside their own noise.
    #[test]
    fn still_rests_too_few_to_test_keep_their_scatter() {
        let three = |b: f32| {
            let mut d = Drift::new();
            for (t, b) in [(0.0, 0.0), (4.0, b), (8.0, 0.0)] {
                d.add(RestBias { t: secs(t), residual_dps: [b; 3] });
            }
            d.predict(secs(8.0), RestNoise::Own([0.001; 3])).unwrap().1[0]
        };
        let (quiet, scattered) = (three(0.0), three(0.05));
        assert!(scattered > 10.0 * quiet, "{scattered} against {quiet}");
    }

    /// Hand-held rests (a rest every 4 s for 80 s) whose means carry a sway's net turn, 0.02 °/s
    /// each, beside a pooled floor of 0.007 °/s, 2000 times: the scatter is their variance and
    /// the bias predicted for the last rest lies within its 1σ and 2σ as an honest σ promises
    /// (measured 68 % / 94 %); a floor above the scatter (0.05 °/s) is taken instead.
    #[test]
    fn hand_held_rests_take_the_larger_of_their_scatter_and_the_floor() {
        let mut noise = crate::math::test_noise::Gaussian::new(0x6a09_e667_f3bc_c909);
        let (mut within, runs) = ([0u32; 2], 2000);
        let rests = |noise: &mut crate::math::test_noise::Gaussian| every_4_s(|_| 0.02 * noise.next());
        for _ in 0..runs {
            let (at, sigma) = rests(&mut noise).predict(secs(80.0), RestNoise::Bound([0.007; 3])).unwrap();
            let e = (at.residual_dps[0] as Real).abs();
            within = [within[0] + (e <= sigma[0] as Real) as u32, within[1] + (e <= 2.0 * sigma[0] as Real) as u32];
        }
        let [one, two] = within.map(|n| n as Real / runs as Real);
        assert!((0.6..=0.8).contains(&one) && two >= 0.92, "within 1 sigma {one:.3}, 2 sigma {two:.3}");
        let d = rests(&mut noise);
        let (own, floor) =
            (d.predict(secs(80.0), RestNoise::Own([0.05; 3])).unwrap().1, d.predict(secs(80.0), RestNoise::Bound([0.05; 3])).unwrap().1);
        assert_eq!(own[0], floor[0], "a floor above the scatter is the variance");
    }

    #[test]
    fn the_temperature_coefficient_is_fitted_over_the_rests_when_the_span_allows() {
        let mut fit = TempFit::new();
        for i in 0..10 {
            let (t, temp) = (10.0 * i as Real, 25.0 + 0.3 * i as f32);
            let wiggle = if i % 2 == 0 { 0.002 } else { -0.002 };
            let b = [0.04 * (temp - 25.0) + wiggle, -0.03 * (temp - 25.0), 0.0];
            fit.add(temp, &RestBias { t: secs(t), residual_dps: b });
            if i == 2 {
                assert_eq!(fit.finish(), None, "3 rests over 0.6 C");
            }
        }
        fit.add(f32::NAN, &RestBias::default());
        let c = fit.finish().expect("10 rests over 2.7 C");
        assert!((c.dps_per_c[0] - 0.04).abs() < 2e-3 && (c.dps_per_c[1] + 0.03).abs() < 1e-5, "{c:?}");
        assert_eq!(c.range_c, [25.0, 27.7]);
        // 1σ: x's white scatter (alternating: no walk measured) is 8.1e-4 alone; with the walk
        // that 10 rests of it cannot exclude, 2.3e-3. y's exact line: none.
        assert!((c.sigma_dps_per_c[0] - 2.34e-3).abs() < 1e-5 && c.sigma_dps_per_c[1] < 1e-6, "{c:?}");
        // No walk: zero to the sums' rounding (a part's is ~1e-3 °/s/√s).
        assert!(fit.walk_dps_rtsec().is_some_and(|q| q < 1e-8), "{:?}", fit.walk_dps_rtsec());
    }

    #[test]
    fn the_walk_is_measured_from_the_rests_and_the_tempco_covers_it() {
        extern crate std;
        use std::{println, vec};
        // 30 rests 3 s apart on a warm-up of 4 °C (τ = 90 s), rest means of 0.007 °/s noise, a
        // tempco of 0.04 °/s/°C and a random walk from none to 16× the former assumed 5e-4.
        let mut noise = crate::math::test_noise::Gaussian::new(7);
        for q in [0.0, 2.5e-4, 1e-3, 4e-3] {
            let (mut within, mut walks, trials) = (0, vec![], 400);
            for _ in 0..trials {
                let (mut fit, mut walk) = (TempFit::new(), 0.0);
                for i in 0..30 {
                    let t = 3.0 * i as Real;
                    walk += q * libm::sqrt(3.0) * noise.next();
                    let temp = 25.0 + 4.0 * (1.0 - libm::exp(-t / 90.0));
                    let b = 0.04 * (temp - 25.0) + walk + 0.007 * noise.next();
                    fit.add(temp as f32, &RestBias { t: secs(t), residual_dps: [b as f32, 0.0, 0.0] });
                }
                let c = fit.finish().unwrap();
                within += usize::from((c.dps_per_c[0] - 0.04).abs() <= 2.0 * c.sigma_dps_per_c[0]);
                walks.push(fit.walk_dps_rtsec().unwrap() as Real);
            }
            walks.sort_by(Real::total_cmp);
            let (cover, median) = (within as Real / trials as Real, walks[trials / 2]);
            println!("MEASURED walk {q:.1e}: tempco within 2 sigma {:.0} %, median walk measured {median:.1e}", 100.0 * cover);
            assert!(cover >= 0.92, "walk {q:e}: {cover}");
            // Small walks: below the floor 30 such rests leave (≈ 1e-3); large ones: within 30 %.
            let right = if q < 1e-3 { median < 1e-3 } else { (median / q - 1.0).abs() < 0.3 };
            assert!(right, "walk {q:e}: median measured {median:e}");
        }
    }

    #[test]
    fn motion_is_not_a_rest() {
        let mut b = BiasEstimator::new();
        for k in 0..200 {
            b.add([if k % 2 == 0 { 5.0 } else { -5.0 }, 0.0, 0.0], [0.0, 0.0, 1.0]);
        }
        assert!(matches!(b.finish(&BiasLimits::default()), Err(Error::NotStill { .. })));
    }
}
