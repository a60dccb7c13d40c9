//! Noise figures for a fusion filter from a long static log (the console's raw-log mode with
//! the board lying still): the overlapping Allan deviation of each gyro and accelerometer axis,
//! and from it the white-noise density, the random walk and the bias instability (IEEE Std
//! 952-1997 Annex C; Kalibr's `imu.yaml` takes the first two).
//!
//! The Allan variance of the noise model `σ²(τ) = 3Q²/τ² + N²/τ + (2 ln 2 / π) B² + K² τ / 3`
//! (angle quantisation, white noise, flicker, random walk) is fitted to the curve by
//! non-negative weighted least squares, each point weighted by its own uncertainty (relative 1σ
//! of an Allan deviation from `n` clusters: `1 / √(2 (n − 1))`). The points of an overlapping
//! curve share most of their data, so the fit's formal 1σ is scaled by √([`PER_DECADE`]): one
//! independent point per decade of τ.
//!
//! `N` (units/√Hz) is the two-sided density (`σ(1 s)` of the white noise; per sample
//! `σ = N √ODR`), the output's rounding to whole counts included: what Kalibr calls the noise
//! density. A datasheet's (one-sided: RMS noise = density · √bandwidth) is `√2 N`. `K`
//! (units/s/√Hz) is the random walk: when the log shows none, 0, and its 1σ is the largest `K`
//! the longest τ allows. `B` is the bias instability, also given as the classic
//! `min σ(τ) / 0.664`.

use crate::csvlog::Row;
use crate::offline::phases;
use serde::Serialize;

/// Largest share of the samples that may be missing (gaps), of the still stretch.
pub const MAX_MISSING_SHARE: f64 = 1e-3;
/// Shortest still log accepted (s): below it the random walk cannot be seen at all.
pub const MIN_DURATION_S: f64 = 100.0;
/// Share of the log that must be one still segment.
pub const MIN_STILL_SHARE: f64 = 0.9;
/// Clusters at the longest τ (fewer give an uncertainty above 1/√(2·8) = 25 %).
const MIN_CLUSTERS: usize = 9;
/// Points of the curve per decade of τ.
const PER_DECADE: f64 = 10.0;

/// Why a log gives no noise figures.
#[derive(Debug, Clone, PartialEq)]
pub enum AllanError {
    /// Shorter than [`MIN_DURATION_S`].
    TooShort {
        /// Its duration (s).
        duration_s: f64,
    },
    /// Samples are missing (gaps in the time column): the curve would be wrong.
    Gaps {
        /// Samples missing.
        missing: usize,
    },
    /// Not one still period: the board moved.
    NotStatic {
        /// The longest still stretch (s).
        still_s: f64,
        /// The log's duration (s).
        duration_s: f64,
    },
}

impl std::fmt::Display for AllanError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            AllanError::TooShort { duration_s } => {
                write!(f, "the log is {duration_s:.0} s long: an Allan analysis needs at least {MIN_DURATION_S:.0} s of the board lying still (an hour or more to see the random walk)")
            }
            AllanError::Gaps { missing } => write!(
                f,
                "{missing} samples are missing from the still stretch (gaps in the time column): log over RTT, or read the USB port without pauses"
            ),
            AllanError::NotStatic { still_s, duration_s } => write!(
                f,
                "the board moved: the longest still stretch is {still_s:.0} s of {duration_s:.0} s (an Allan analysis needs one still log; lay the board down and log again)"
            ),
        }
    }
}

/// An estimate and its 1σ.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Estimate {
    /// The value.
    pub value: f64,
    /// Its 1σ.
    pub sigma: f64,
}

/// One sensor's noise figures, per axis, in its units (°/s or g).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Noise {
    /// White-noise density `N` (units/√Hz, two-sided: Kalibr's noise density).
    pub noise_density: [Estimate; 3],
    /// The same as a datasheet gives it (one-sided, `√2 N`).
    pub datasheet_density: [f64; 3],
    /// Random walk `K` (units/s/√Hz: Kalibr's random walk); 0 when the log shows none (its 1σ
    /// then the largest the log allows).
    pub random_walk: [Estimate; 3],
    /// Bias instability `B` from the fitted flicker floor (units; 0 when there is none).
    pub bias_instability: [f64; 3],
    /// The curve's minimum / 0.664 (units) and where it is (s): the classic reading of `B`.
    pub adev_floor: [(f64, f64); 3],
    /// The Allan deviation: τ (s).
    pub tau_s: Vec<f64>,
    /// σ(τ) per axis (units).
    pub adev: Vec<[f64; 3]>,
    /// Relative 1σ of each point.
    pub adev_rel_sigma: Vec<f64>,
}

/// The noise figures of a static log.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Allan {
    /// Sample rate (Hz, measured).
    pub sample_rate_hz: f64,
    /// Duration analysed (s).
    pub duration_s: f64,
    /// Gyro (°/s).
    pub gyro: Noise,
    /// Accelerometer (g).
    pub accel: Noise,
}

/// Overlapping Allan deviation of evenly sampled `x` (one axis per column) at rate `fs` (Hz),
/// at cluster sizes spread [`PER_DECADE`] per decade up to `len / MIN_CLUSTERS`: (τ, σ, relative
/// 1σ of σ).
pub fn adev(x: &[[f64; 3]], fs: f64) -> Vec<(f64, [f64; 3], f64)> {
    let n = x.len();
    // Cumulative sums: θ_k = Σ_{i<k} x_i / fs.
    let mut theta = vec![[0.0f64; 3]; n + 1];
    for (i, v) in x.iter().enumerate() {
        theta[i + 1] = std::array::from_fn(|a| theta[i][a] + v[a] / fs);
    }
    let mut ms: Vec<usize> =
        (0..).map(|i| (10f64.powf(i as f64 / PER_DECADE)).round() as usize).take_while(|&m| m * MIN_CLUSTERS <= n).collect();
    ms.dedup();
    ms.into_iter()
        .map(|m| {
            let tau = m as f64 / fs;
            let terms = n + 1 - 2 * m;
            let sigma = std::array::from_fn(|a| {
                let s: f64 = (0..terms).map(|k| (theta[k + 2 * m][a] - 2.0 * theta[k + m][a] + theta[k][a]).powi(2)).sum();
                (s / (2.0 * tau * tau * terms as f64)).sqrt()
            });
            (tau, sigma, 1.0 / (2.0 * (n / m - 1) as f64).sqrt())
        })
        .collect()
}

/// Flicker term of the Allan variance per B²: 2 ln 2 / π.
const FLICKER: f64 = 2.0 * std::f64::consts::LN_2 / std::f64::consts::PI;

/// Fits `σ² = q/τ² + a/τ + f + c τ` (all ≥ 0) to one axis' curve, each point's σ² weighted by its
/// uncertainty `2 rel σ²`: the coefficients and their 1σ.
fn fit(curve: &[(f64, f64, f64)]) -> ([f64; 4], [f64; 4]) {
    let basis = |tau: f64| [1.0 / (tau * tau), 1.0 / tau, 1.0, tau];
    let mut active = [true; 4];
    loop {
        let idx: Vec<usize> = (0..4).filter(|&j| active[j]).collect();
        let k = idx.len();
        let (mut ata, mut atb) = (nalgebra::DMatrix::<f64>::zeros(k, k), nalgebra::DVector::<f64>::zeros(k));
        // A flat curve point (an axis that never changed) carries no weight it could be fitted by.
        for &(tau, s, rel) in curve.iter().filter(|p| p.1 > 0.0) {
            let (b, y, w) = (basis(tau), s * s, 1.0 / (2.0 * rel * s * s).powi(2));
            for (r, &jr) in idx.iter().enumerate() {
                atb[r] += w * b[jr] * y;
                for (c, &jc) in idx.iter().enumerate() {
                    ata[(r, c)] += w * b[jr] * b[jc];
                }
            }
        }
        let Some(inv) = ata.clone().try_inverse() else { return ([0.0; 4], [f64::INFINITY; 4]) };
        let x = &inv * atb;
        // The most negative coefficient leaves the model; refit.
        match (0..k).filter(|&r| x[r] < 0.0).min_by(|&a, &b| x[a].total_cmp(&x[b])) {
            Some(r) => active[idx[r]] = false,
            None => {
                let (mut v, mut s) = ([0.0; 4], [0.0; 4]);
                for (r, &j) in idx.iter().enumerate() {
                    (v[j], s[j]) = (x[r], (PER_DECADE * inv[(r, r)]).sqrt());
                }
                return (v, s);
            }
        }
    }
}

/// `√v` with the 1σ of `√v` from the 1σ of `v`.
fn root(v: f64, sigma: f64, scale: f64) -> Estimate {
    let value = (scale * v).sqrt();
    // d√(s v) = s dv / (2 √(s v)); at 0 the bound √(s σ).
    let sigma = if value > 0.0 { scale * sigma / (2.0 * value) } else { (scale * sigma).sqrt() };
    Estimate { value, sigma: sigma.min(f64::MAX) }
}

fn noise(x: &[[f64; 3]], fs: f64) -> Noise {
    let curve = adev(x, fs);
    let axis = |a: usize| {
        let pts: Vec<(f64, f64, f64)> = curve.iter().map(|(t, s, r)| (*t, s[a], *r)).collect();
        let (v, s) = fit(&pts);
        let floor = pts.iter().map(|p| (p.1, p.0)).min_by(|a, b| a.0.total_cmp(&b.0)).unwrap_or((0.0, 0.0));
        let walk = match pts.last() {
            // None seen: at most what would make the random walk all of σ at the longest τ.
            Some(&(tau, sigma, _)) if v[3] == 0.0 => Estimate { value: 0.0, sigma: sigma * (3.0 / tau).sqrt() },
            _ => root(v[3], s[3], 3.0),
        };
        (root(v[1], s[1], 1.0), walk, (v[2] / FLICKER).sqrt(), (floor.0 / 0.664, floor.1))
    };
    let axes: [_; 3] = std::array::from_fn(axis);
    Noise {
        noise_density: axes.map(|a| a.0),
        datasheet_density: axes.map(|a| a.0.value * std::f64::consts::SQRT_2),
        random_walk: axes.map(|a| a.1),
        bias_instability: axes.map(|a| a.2),
        adev_floor: axes.map(|a| a.3),
        tau_s: curve.iter().map(|c| c.0).collect(),
        adev: curve.iter().map(|c| c.1).collect(),
        adev_rel_sigma: curve.iter().map(|c| c.2).collect(),
    }
}

/// The noise figures of a static log: the longest still stretch (it must be
/// [`MIN_STILL_SHARE`] of the log and at least [`MIN_DURATION_S`] long, with at most
/// [`MAX_MISSING_SHARE`] of its samples missing), at its median rate.
pub fn analyse(rows: &[Row]) -> Result<Allan, AllanError> {
    let duration_s = match (rows.first(), rows.last()) {
        (Some(a), Some(b)) => b.t.s() - a.t.s(),
        _ => 0.0,
    };
    if duration_s < MIN_DURATION_S {
        return Err(AllanError::TooShort { duration_s });
    }
    let ph = phases(rows);
    let (first, last) = ph
        .segments
        .iter()
        .map(|s| (s.first, s.last))
        .max_by(|a, b| (rows[a.1].t.s() - rows[a.0].t.s()).total_cmp(&(rows[b.1].t.s() - rows[b.0].t.s())))
        .unwrap_or((0, 0));
    let still_s = rows[last].t.s() - rows[first].t.s();
    if still_s < MIN_STILL_SHARE * duration_s || still_s < MIN_DURATION_S {
        return Err(AllanError::NotStatic { still_s, duration_s });
    }
    // Holes anywhere in the log (a still stretch stops at one, so the longest would hide them).
    let mut dt: Vec<f64> = rows.windows(2).map(|w| w[1].t.s() - w[0].t.s()).collect();
    dt.sort_by(f64::total_cmp);
    let median = dt[dt.len() / 2];
    let missing: usize = dt.iter().filter(|&&d| d > 1.5 * median).map(|d| (d / median).round() as usize - 1).sum();
    if missing as f64 > MAX_MISSING_SHARE * rows.len() as f64 {
        return Err(AllanError::Gaps { missing });
    }
    let span = &rows[first..=last];
    let fs = 1.0 / median;
    let gyro: Vec<[f64; 3]> = span.iter().map(|r| r.gyro_dps.map(f64::from)).collect();
    let accel: Vec<[f64; 3]> = span.iter().map(|r| r.accel_g.map(f64::from)).collect();
    Ok(Allan { sample_rate_hz: fs, duration_s: still_s, gyro: noise(&gyro, fs), accel: noise(&accel, fs) })
}

impl Allan {
    /// Kalibr's `imu.yaml` (SI units: rad/s, m/s²; the largest axis of each figure), with the
    /// figures' provenance in comments.
    pub fn kalibr_yaml(&self, topic: &str) -> String {
        const G: f64 = 9.80665;
        let rad = std::f64::consts::PI / 180.0;
        // The largest axis; a random walk the log did not show: the largest it allows.
        let max = |e: &[Estimate; 3]| e.iter().map(|e| if e.value > 0.0 { e.value } else { e.sigma }).fold(0.0, f64::max);
        format!(
            "# IMU noise model for Kalibr, from gyrocal-calib allan ({:.0} s still at {:.1} Hz).\n\
             # Continuous-time, two-sided densities (sigma(tau = 1 s) of the white noise); the largest axis;\n\
             # a random walk the log did not show is the largest it allows.\n\
             # Kalibr's authors advise inflating these for real use (unmodelled effects).\n\
             rostopic: {topic}\n\
             update_rate: {:.1}\n\
             accelerometer_noise_density: {:.6e}  # m/s^2/sqrt(Hz)\n\
             accelerometer_random_walk: {:.6e}  # m/s^3/sqrt(Hz)\n\
             gyroscope_noise_density: {:.6e}  # rad/s/sqrt(Hz)\n\
             gyroscope_random_walk: {:.6e}  # rad/s^2/sqrt(Hz)\n",
            self.duration_s,
            self.sample_rate_hz,
            self.sample_rate_hz,
            max(&self.accel.noise_density) * G,
            max(&self.accel.random_walk) * G,
            max(&self.gyro.noise_density) * rad,
            max(&self.gyro.random_walk) * rad,
        )
    }
}
