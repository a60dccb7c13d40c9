//! The phases of a log, found from the data: still windows grouped into still segments (poses),
//! and the longest steady-rate run (the paper's spin).

use super::*;

/// A still segment: consecutive still windows.
#[derive(Debug, Clone, Copy)]
pub struct Segment {
    /// First row index.
    pub first: usize,
    /// Last row index (inclusive).
    pub last: usize,
    /// Accelerometer statistics (raw g).
    pub accel: Moments3,
    /// Gyro statistics (raw °/s).
    pub gyro: Moments3,
    /// Commanded servo angle (°), `None` for a hand-held pose.
    pub servo_deg: Option<f32>,
    /// Commanded tilt angle (°), when the log has the column.
    pub tilt_deg: Option<f32>,
}

impl Segment {
    /// A rig pose: the servo commanded (at any tilt). A segment with no servo commanded is a
    /// hand-held accelerometer pose.
    pub fn is_rig_pose(&self) -> bool {
        self.servo_deg.is_some()
    }

    /// The 1σ (g) of the pose's mean along gravity: the part's noise and the hand's motion
    /// that the mean keeps, each from the pose's own readings along `u` (the mean's
    /// direction), their variances added.
    /// - Noise: `σ²/n` over its `n` samples, `σ²` from second differences,
    ///   `Σ (a_{k+1} − 2a_k + a_{k−1})² / 6(n − 2)`. A sway (0.1–2 Hz) does not show in them and
    ///   a 10 Hz tremor leaks 1.2 % of its variance at 119 Hz (first differences: 14 %), where
    ///   the samples' spread would take them whole (free-hand logs with no still rig pose: 1.4×
    ///   the error's variance). `noise_g` ([`Phases::accel_noise_g`]) where the readings never
    ///   change.
    /// - Motion: a held board's mean over a pose of length `T` is off by `Δv / T`, its
    ///   velocity's change across the pose. Within it the velocity is `v(0) + B(t) + (t/T) Δv`
    ///   with `B(t) = ∫ (a·u − ā) dt`. A motion faster than the pose, of velocity variance
    ///   `σ_v²`, gives `Δv` the variance `2σ_v²` and `B` the mean square `5σ_v²/3`; averaged
    ///   over a flat velocity spectrum at 0.3–1.5 Hz (a sway) or 8–12 Hz (a tremor) with
    ///   `T` ≈ 2.4 s, `E[Δv²] / E[⟨B²⟩]` is 1.2–1.35. So `(Δv/T)² ≈ 6⟨B²⟩/5T²`, less the noise's
    ///   own share of `⟨B²⟩` (`σ² T²/6n`): in all `0.8 σ²/n + 1.2 ⟨B²⟩/T²`, never below
    ///   `σ²/n`. Against the simulator's truth over its hand family (40 rigs, 12 poses each),
    ///   the error's mean square over this variance's mean is 0.87–1.07 (it sets the
    ///   propagated 1σ); with the larger of `σ/√n` and `√(2⟨B²⟩)/T` it was 0.54–1.0.
    ///
    /// `rows`: the log the segment indexes.
    pub fn accel_sigma_of_mean(&self, rows: &[Row], noise_g: f64) -> f64 {
        let rows = &rows[self.first..=self.last];
        let mean = Vector3::from(self.accel.mean());
        let norm = mean.norm().max(1e-9);
        let u = mean / norm;
        let along: Vec<f64> = rows.iter().map(|r| Vector3::from(r.accel_g.map(f64::from)).dot(&u) - norm).collect();
        let (mut b, mut b2) = (0.0, 0.0);
        for (w, a) in rows.windows(2).zip(&along[1..]) {
            b += a * (w[1].t.s() - w[0].t.s());
            b2 += b * b;
        }
        let d2: f64 = along.windows(3).map(|w| (w[2] - 2.0 * w[1] + w[0]).powi(2)).sum();
        let n = rows.len() as f64;
        let t = rows[rows.len() - 1].t.s() - rows[0].t.s();
        let noise = if d2 > 0.0 { d2 / (6.0 * (n - 2.0)) } else { noise_g * noise_g } / n;
        let motion = if t > 0.0 { 1.2 * b2 / n / (t * t) } else { 0.0 };
        (0.8 * noise + motion).max(noise).sqrt()
    }

    /// The tilt setting of a rig pose (°, 0 without a tilt column), to 0.5°.
    pub(super) fn tilt_setting(&self) -> i32 {
        (self.tilt_deg.unwrap_or(0.0) * 2.0).round() as i32
    }
}

/// A steady-rate run: the paper's spin.
#[derive(Debug, Clone, Copy)]
pub struct SteadySpin {
    /// First and last row index (inclusive) of the averaged part.
    pub rows: (usize, usize),
    /// Mean raw gyro over it (°/s).
    pub gyro: Moments3,
}

/// The phases found in a log.
#[derive(Debug, Clone)]
pub struct Phases {
    /// Thresholds used for the rig's poses and the bias (raised to the log's noise floor).
    pub rest: RestConfig,
    /// Thresholds used for hand-held poses (a hand's, at least the rig's).
    pub hand_rest: RestConfig,
    /// The accelerometer's noise (g, 1σ a sample, its noisiest axis): the 10th percentile of
    /// the 0.25 s windows' standard deviations, the log's stillest.
    pub accel_noise_g: f64,
    /// Still segments in time order.
    pub segments: Vec<Segment>,
}

impl Phases {
    /// A segment as still as the rig's thresholds: it measures the gyro bias (a hand's shaky
    /// pose does not).
    pub fn measures_bias(&self, s: &Segment) -> bool {
        s.gyro.max_std() <= self.rest.gyro_std_max_dps as f64
    }
}

/// Shortest still segment used as a pose (s).
const MIN_SEGMENT_S: f64 = 0.5;

fn window_len(rows: &[Row], window_s: f64) -> Vec<(usize, usize)> {
    let mut out = vec![];
    let mut start = 0;
    for i in 0..rows.len() {
        if rows[i].t.s() - rows[start].t.s() >= window_s {
            out.push((start, i));
            start = i + 1;
            if start >= rows.len() {
                break;
            }
        }
    }
    out
}

fn stats(rows: &[Row]) -> (Moments3, Moments3) {
    let (mut a, mut g) = (Moments3::new(), Moments3::new());
    for r in rows {
        a.add(r.accel_g);
        g.add(r.gyro_dps);
    }
    (a, g)
}

fn percentile(mut v: Vec<f64>, p: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p) as usize]
}

/// Finds still segments and the steady-rate spin.
pub fn phases(rows: &[Row]) -> Phases {
    let defaults = CONFIG.rest;
    // Noise floor: the 10th percentile of the per-window standard deviations.
    let windows = window_len(rows, defaults.window_s as f64);
    let (mut sa, mut sg) = (vec![], vec![]);
    for &(a, b) in &windows {
        let (wa, wg) = stats(&rows[a..=b]);
        sa.push(wa.max_std());
        sg.push(wg.max_std());
    }
    let (fa, fg) = (percentile(sa, 0.1), percentile(sg, 0.1));
    let accel_std_max_g = defaults.accel_std_max_g.max((3.0 * fa) as f32);
    let rest = RestConfig {
        accel_std_max_g,
        gyro_std_max_dps: defaults.gyro_std_max_dps.max((3.0 * fg) as f32),
        accel_drift_max_g: defaults.accel_drift_max_g.max(0.7 * accel_std_max_g),
        ..defaults
    };

    let hand = CONFIG.hand_rest;
    let hand_rest = RestConfig {
        accel_std_max_g: hand.accel_std_max_g.max(rest.accel_std_max_g),
        gyro_std_max_dps: hand.gyro_std_max_dps.max(rest.gyro_std_max_dps),
        accel_drift_max_g: hand.accel_drift_max_g.max(rest.accel_drift_max_g),
        ..hand
    };

    // Both detectors close their windows at the same rows: a window with no servo commanded is
    // judged by the hand's thresholds.
    let (mut det, mut hand_det) = (RestDetector::new(rest), RestDetector::new(hand_rest));
    let mut segments: Vec<Segment> = vec![];
    let mut open: Option<Segment> = None;
    let mut start = 0;
    for (i, r) in rows.iter().enumerate() {
        // A hole in the samples (a log cut, samples lost) ends the stillness: the board may have
        // moved unseen, so no window or pose spans it.
        if i > 0 && r.t.s() - rows[i - 1].t.s() > CONFIG.rotation.max_gap_s as f64 {
            close(&mut open, &mut segments, rows);
            det.reset();
            hand_det.reset();
            start = i;
        }
        let (w, hw) = (det.update(r.t, r.accel_g, r.gyro_dps), hand_det.update(r.t, r.accel_g, r.gyro_dps));
        let (Some(w), Some(hw)) = (w, hw) else { continue };
        let span = &rows[start..=i];
        start = i + 1;
        let (servo, tilt) = (column_of(span, |r| r.servo_deg), column_of(span, |r| r.tilt_deg));
        let w = if servo == Some(None) { hw } else { w };
        let still = w.still && w.state == RestState::Still && servo.is_some() && tilt.is_some();
        let (servo, tilt) = (servo.flatten(), tilt.flatten());
        let same = |a: Option<f32>, b: Option<f32>| match (a, b) {
            (None, None) => true,
            (Some(a), Some(b)) => (a - b).abs() < 0.5,
            _ => false,
        };
        match (&mut open, still) {
            (Some(seg), true) if same(seg.servo_deg, servo) && same(seg.tilt_deg, tilt) => {
                seg.accel.merge(&w.accel);
                seg.gyro.merge(&w.gyro);
                seg.last = i;
            }
            (_, true) => {
                close(&mut open, &mut segments, rows);
                let first = i + 1 - span.len();
                open = Some(Segment { first, last: i, accel: w.accel, gyro: w.gyro, servo_deg: servo, tilt_deg: tilt });
            }
            (_, false) => close(&mut open, &mut segments, rows),
        }
    }
    close(&mut open, &mut segments, rows);
    Phases { rest, hand_rest, accel_noise_g: fa, segments }
}

/// A command column over a window: `Some(None)` all empty, `Some(Some(mean))` all set and
/// within 0.5°, `None` mixed or moving.
fn column_of(rows: &[Row], col: impl Fn(&Row) -> Option<f32>) -> Option<Option<f32>> {
    let set: Vec<f32> = rows.iter().filter_map(col).collect();
    if set.is_empty() {
        return Some(None);
    }
    if set.len() != rows.len() {
        return None;
    }
    let (lo, hi) = set.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), v| (l.min(*v), h.max(*v)));
    (hi - lo < 0.5).then(|| Some(set.iter().sum::<f32>() / set.len() as f32))
}

fn close(open: &mut Option<Segment>, segments: &mut Vec<Segment>, rows: &[Row]) {
    if let Some(seg) = open.take() {
        if rows[seg.last].t.s() - rows[seg.first].t.s() >= MIN_SEGMENT_S {
            segments.push(seg);
        }
    }
}

/// The longest run of windows whose mean bias-free gyro vector stays within 5 % of the run's
/// mean so far (a hobby servo's rate wobbles by ±4 % over 0.25 s windows: measured 20.3–21.4 °/s
/// on a 20.6 °/s spin of the simulated servo's vibration), above `steady.min_dps`, averaged over `steady.min_s` at least once `steady`'s start and
/// end are skipped, as the firmware averages its rotation.
pub fn steady_spin(rows: &[Row], bias_dps: [f32; 3], window_s: f32, steady: &SteadyRate) -> Option<SteadySpin> {
    let windows = window_len(rows, window_s as f64);
    let b = v64(bias_dps);
    let means: Vec<Vector3<f64>> = windows.iter().map(|&(a, c)| Vector3::from(stats(&rows[a..=c]).1.mean()) - b).collect();
    // The averaged rows of windows i..=j.
    let averaged = |i: usize, j: usize| {
        let (t0, t1) = (rows[windows[i].0].t.s(), rows[windows[j].1].t.s());
        let first = (windows[i].0..=windows[j].1).find(|&r| steady.averaged(rows[r].t.s() - t0, t1 - t0))?;
        let last = (windows[i].0..=windows[j].1).rev().find(|&r| steady.averaged(rows[r].t.s() - t0, t1 - t0))?;
        (rows[last].t.s() - rows[first].t.s() >= steady.min_s as f64).then_some((first, last))
    };
    let mut best: Option<(usize, usize)> = None;
    let mut i = 0;
    while i < means.len() {
        let mut j = i;
        if means[i].norm() > steady.min_dps as f64 {
            let mut sum = means[i];
            while j + 1 < means.len() && (means[j + 1] - sum / (j + 1 - i) as f64).norm() <= 0.05 * (sum / (j + 1 - i) as f64).norm() {
                j += 1;
                sum += means[j];
            }
        }
        if let Some(r) = averaged(i, j).filter(|_| j > i) {
            if best.is_none_or(|(a, b)| r.1 - r.0 > b - a) {
                best = Some(r);
            }
        }
        i = j + 1;
    }
    best.map(|rows_range| SteadySpin { rows: rows_range, gyro: stats(&rows[rows_range.0..=rows_range.1]).1 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use calib_core::Time;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A 2 s pose at 119 Hz, gravity on z plus `motion(t)` (g, along gravity) and white noise of
    /// `noise_g` a sample; its segment over every row.
    fn pose(motion: impl Fn(f64) -> f64, noise_g: f64, rng: &mut ChaCha8Rng) -> (Vec<Row>, Segment) {
        let rows: Vec<Row> = (0..238)
            .map(|i| {
                let t = i as f64 / 119.0;
                let mut n = || (rng.random::<f64>() - 0.5) * noise_g * 12f64.sqrt();
                let a = [n(), n(), 1.0 + motion(t) + n()].map(|v| v as f32);
                Row {
                    t: Time::from_s(t).unwrap(),
                    accel_g: a,
                    gyro_dps: [0.0; 3],
                    servo_deg: None,
                    tilt_deg: None,
                    mag_ut: None,
                    temp_c: None,
                }
            })
            .collect();
        let (accel, gyro) = stats(&rows);
        (rows.clone(), Segment { first: 0, last: rows.len() - 1, accel, gyro, servo_deg: None, tilt_deg: None })
    }

    /// The fractions of `runs` poses whose mean's error along gravity lies within the 1σ
    /// [`Segment::accel_sigma_of_mean`] gives and within 2σ, and the median 1σ (g).
    fn coverage(runs: usize, motion: impl Fn(&mut ChaCha8Rng) -> Box<dyn Fn(f64) -> f64>) -> (f64, f64, f64) {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let (mut one, mut two, mut sigmas) = (0, 0, vec![]);
        for _ in 0..runs {
            let m = motion(&mut rng);
            let (rows, seg) = pose(m, 1e-3, &mut rng);
            let s = seg.accel_sigma_of_mean(&rows, 1e-3);
            let e = (seg.accel.mean()[2] - 1.0).abs();
            one += (e <= s) as usize;
            two += (e <= 2.0 * s) as usize;
            sigmas.push(s);
        }
        sigmas.sort_by(f64::total_cmp);
        (one as f64 / runs as f64, two as f64 / runs as f64, sigmas[runs / 2])
    }

    #[test]
    fn a_still_pose_has_its_noise_over_root_n() {
        // Its noise from the pose's own second differences: within 5 % of the truth (their
        // variance's spread over 238 samples is ±10 %). Measured: 68 % / 96 % over 400 poses.
        let (one, two, s) = coverage(400, |_| Box::new(|_| 0.0));
        assert!((s / (1e-3 / 238f64.sqrt()) - 1.0).abs() < 0.05, "{s}");
        assert!((0.62..=0.74).contains(&one) && two >= 0.92, "{one} {two}");
    }

    #[test]
    fn a_swaying_hand_is_covered_and_a_tremor_is_not_taken_for_noise() {
        // The linear acceleration of a sway (0.4-1.5 Hz, 2 mg) that a 2 s pose does not average
        // away: its spread over √n alone (about 0.13 mg) would be far too small. Measured:
        // 67 % / 96 %.
        let sway = |rng: &mut ChaCha8Rng| -> Box<dyn Fn(f64) -> f64> {
            let (f, ph) = (rng.random_range(0.4..1.5), rng.random_range(0.0..core::f64::consts::TAU));
            Box::new(move |t| 2e-3 * (core::f64::consts::TAU * f * t + ph).sin())
        };
        let (one, two, _) = coverage(400, sway);
        assert!(one >= 0.6 && two >= 0.92, "sway: {one} {two}");
        // A 10 Hz tremor of 20 mg: its spread over √n is 0.9 mg, its mean error below 0.32 mg.
        // Measured: 68 % / 99 %, median 1σ 0.20 mg.
        let tremor = |rng: &mut ChaCha8Rng| -> Box<dyn Fn(f64) -> f64> {
            let (f, ph) = (rng.random_range(8.0..12.0), rng.random_range(0.0..core::f64::consts::TAU));
            Box::new(move |t| 20e-3 * (core::f64::consts::TAU * f * t + ph).sin())
        };
        let (one, two, s) = coverage(400, tremor);
        assert!(two >= 0.92 && one >= 0.6, "tremor: {one} {two}");
        assert!(s < 0.35e-3, "tremor: median 1 sigma {s} g");
    }
}
