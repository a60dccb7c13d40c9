//! The calibration's decisions, made once: the firmware's procedure and the offline tool both
//! call these, so that they choose, gate and reject alike.

use crate::estimators::accel::{AccelCal, AccelCalibrator, Params};
use crate::estimators::axis::{turn_deg, GeometryLimits, Poses};
use crate::estimators::bias::Drift;
use crate::estimators::full::{Axes, FullCal, FullLimits};
use crate::estimators::gyro::GyroCal;
use crate::estimators::rotation::{RotationLimits, Rotations};
use crate::estimators::sweep::Moves;
use crate::estimators::{paper, sweep};
use crate::math::lsq::NormalEquations;
use crate::math::real::Real;
use crate::math::vec3::to_real as v64;
use crate::{Error, Time, Vec3};
use nalgebra::Vector3;

/// What a result must meet to be stored or printed.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Acceptance {
    /// Accepted range of each scale factor.
    pub k_min: f32,
    /// See `k_min`.
    pub k_max: f32,
    /// Largest accepted 1σ of a scale factor.
    pub max_sigma_k: f32,
    /// Largest accepted accelerometer residual | |a| − 1 | RMS after calibration (g).
    pub max_accel_rms_g: f32,
}

/// Poses the 6-parameter accelerometer fit needs: one more than its unknowns, since a fit with
/// as many unknowns as poses interpolates them (residual 0, 1σ 0) and determines nothing.
pub const SIX_PARAM_POSES: usize = 7;
/// Poses from which the 9-parameter fit is tried beside the 6-parameter one (one degree of
/// freedom left): which is taken is [`ModelTest`]'s decision, never the count.
pub const NINE_PARAM_POSES: usize = 10;

/// The F-test of the 9-parameter accelerometer model against the 6-parameter one: do its three
/// cross terms explain more of the residual than three random parameters would?
/// `F = ((RSS₆ − RSS₉) / 3) / (RSS₉ / (n − 9))` over the `n` poses, against its 95 % point
/// `F₀.₉₅(3, n − 9)`. Self-normalising: it needs no noise figure, and with few degrees of
/// freedom it asks for much (216 at 10 poses, 3.7 at 19).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct ModelTest {
    /// The statistic.
    pub f: f32,
    /// Its 95 % point at these degrees of freedom: above it the 9-parameter model is taken.
    pub critical: f32,
    /// RMS of `|f| − 1` of each model (g).
    pub rms_six_g: f32,
    /// See `rms_six_g`.
    pub rms_nine_g: f32,
}

/// `F₀.₉₅(3, d)` for `d` = 1..=20 (the regularised incomplete beta function, as statistical
/// tables give it); beyond, `χ²₃(0.95)/3 + 8.44 / (d − 3.40)`, within 0.5 % of it.
const F3_95: [f32; 20] = [
    215.71, 19.164, 9.2766, 6.5914, 5.4095, 4.7571, 4.3468, 4.0662, 3.8625, 3.7083, 3.5874, 3.4903, 3.4105, 3.3439, 3.2874, 3.2389, 3.1968,
    3.1599, 3.1274, 3.0984,
];

impl ModelTest {
    /// The test of `nine` against `six`, both fitted to the same `n` poses.
    pub fn new(six: &AccelCal, nine: &AccelCal, n: usize) -> Self {
        let d = n.saturating_sub(9).max(1);
        let (rss6, rss9) = (six.rms_after_g * six.rms_after_g, nine.rms_after_g * nine.rms_after_g);
        let f = (rss6 - rss9) / 3.0 / (rss9 / d as f32);
        let critical = F3_95.get(d - 1).copied().unwrap_or(2.6049 + 8.44 / (d as f32 - 3.40));
        ModelTest { f, critical, rms_six_g: six.rms_after_g, rms_nine_g: nine.rms_after_g }
    }

    /// The cross terms are significant: the 9-parameter model is taken.
    pub fn nine(&self) -> bool {
        self.f > self.critical
    }
}

/// The 9-parameter accelerometer fit, made from [`NINE_PARAM_POSES`] poses on (`None` below, or
/// when it fails): the half of [`fit_accel_tested`] the board makes a sample before the other
/// half ([`choose_accel`]), so that neither call outlasts the sensor's FIFO.
pub fn fit_nine<const N: usize>(poses: &AccelCalibrator<N>) -> Option<AccelCal> {
    let mut ne = NormalEquations::new();
    nine_params(poses, &mut ne).and_then(|p| poses.calibration9(&p, &ne).ok())
}

/// [`fit_nine`]'s first part (the board makes each in a call of its own): the parameters
/// ([`AccelCalibrator::solve9_params`], the last iteration's equations in `ne`); `None` as
/// [`fit_nine`]. The second is [`AccelCalibrator::calibration9`].
pub fn nine_params<const N: usize>(poses: &AccelCalibrator<N>, ne: &mut NormalEquations<9>) -> Option<Params> {
    (poses.len() >= NINE_PARAM_POSES).then(|| poses.solve9_params(ne).ok()).flatten()
}

/// The accelerometer fit the poses support: the 6-parameter one, or the 9-parameter one where
/// [`ModelTest`] finds its cross terms significant (or the 6-parameter fit fails); rejected if
/// its residual exceeds the acceptance. Also the test, when both models were fitted.
pub fn fit_accel_tested<const N: usize>(poses: &AccelCalibrator<N>, acc: &Acceptance) -> Result<(AccelCal, Option<ModelTest>), Error> {
    choose_accel(poses, fit_nine(poses), acc)
}

/// [`fit_accel_tested`] with the 9-parameter fit `nine` ([`fit_nine`]) already made.
pub fn choose_accel<const N: usize>(
    poses: &AccelCalibrator<N>,
    nine: Option<AccelCal>,
    acc: &Acceptance,
) -> Result<(AccelCal, Option<ModelTest>), Error> {
    let n = poses.len();
    if n < SIX_PARAM_POSES {
        return Err(Error::TooFewPoses { have: n as u8, need: SIX_PARAM_POSES as u8 });
    }
    let (fit, test) = match (poses.solve6(), nine) {
        (Ok(six), Some(nine)) => {
            let test = ModelTest::new(&six, &nine, n);
            (if test.nine() { nine } else { six }, Some(test))
        }
        (Ok(six), None) => (six, None),
        (Err(_), Some(nine)) => (nine, None),
        (Err(e), None) => return Err(e),
    };
    if !(fit.rms_after_g <= acc.max_accel_rms_g) {
        return Err(Error::AccelFitFailed);
    }
    Ok((fit, test))
}

/// The estimator's result to use: the speed-free sweep estimator, else the paper's.
pub fn choose(sweep: Result<GyroCal, Error>, paper: Option<Result<GyroCal, Error>>) -> Result<GyroCal, Error> {
    match (sweep, paper) {
        (Ok(c), _) | (Err(_), Some(Ok(c))) => Ok(c),
        (Err(e), _) => Err(e),
    }
}

/// A scale factor `k` of axis `i` with its 1σ and the fit's weighted residual `noise_ratio`
/// (NaN when the estimator has none): outside the accepted range it is
/// [`Error::ResultRejected`], too uncertain [`Error::TooUncertain`].
fn check_scale(i: usize, k: f32, sigma: f32, noise_ratio: f32, acc: &Acceptance) -> Result<(), Error> {
    if !(k >= acc.k_min && k <= acc.k_max) {
        return Err(Error::ResultRejected { axis: i as u8, k, sigma });
    }
    if !(sigma <= acc.max_sigma_k) {
        return Err(Error::TooUncertain { axis: i as u8, k, sigma, limit: acc.max_sigma_k, noise_ratio });
    }
    Ok(())
}

/// Rejects a result whose scale factors are implausible or too uncertain.
pub fn validate(cal: &GyroCal, acc: &Acceptance) -> Result<(), Error> {
    for i in 0..3 {
        check_scale(i, cal.k[i][i], cal.quality.sigma_k[i], f32::NAN, acc)?;
    }
    Ok(())
}

/// What a one-servo rig gives (its calibrated poses and the moves between them about the one
/// axis, the paper's spin when there was one, the hand-held moves when there were any): each
/// estimator's outcome, and with hand-held moves the full `K`.
#[derive(Debug, Clone, Copy)]
pub struct OneAxis {
    /// The speed-free sweep estimator.
    pub sweep: Result<GyroCal, Error>,
    /// The paper's estimator (`None` without a spin).
    pub paper: Option<Result<GyroCal, Error>>,
    /// With hand-held moves: the full `K` from the rig's axis and their rotation constraints
    /// (not yet validated).
    pub full: Option<Result<FullCal, Error>>,
}

impl OneAxis {
    /// Solves a one-servo rig. `spin`: the spin's mean bias-corrected rate (°/s, sensor frame)
    /// and the shaft rate (°/s); `rotations`: the hand-held moves (`None` or none kept: no full
    /// `K`). `axes` is scratch for the full solve, started at the diagonal of the one-axis result.
    pub fn solve<const M: usize, const C: usize, const P: usize>(
        poses: &Poses,
        moves: &Moves,
        spin: Option<(Vec3, f32)>,
        rotations: Option<(&Rotations<M, C, P>, &RotationLimits)>,
        limits: (&GeometryLimits, &FullLimits),
        axes: &mut Axes,
    ) -> Self {
        let mut one = Self::diagonal(poses, moves, spin, limits.0);
        one.full = rotations.filter(|(r, _)| !r.moves().is_empty()).map(|rot| {
            let start = one.load_axes(poses, moves, axes)?;
            axes.solve_from(limits.1, Some(rot), start)
        });
        one
    }

    /// The sweep and the paper's estimators alone (`full` is `None`).
    #[inline(never)]
    pub fn diagonal(poses: &Poses, moves: &Moves, spin: Option<(Vec3, f32)>, limits: &GeometryLimits) -> Self {
        let sweep = sweep::solve(poses, moves, limits);
        let paper = spin.map(|(g, w)| paper::solve(poses, g, w, limits));
        OneAxis { sweep, paper, full: None }
    }

    /// The rig's poses and moves as one axis of `axes`, for the full `K` with rotation
    /// constraints; returns where its Gauss–Newton starts (vec `K` of the sweep's, else the
    /// paper's estimate, if either succeeded).
    #[inline(never)]
    pub fn load_axes(&self, poses: &Poses, moves: &Moves, axes: &mut Axes) -> Result<Option<[Real; 9]>, Error> {
        let start = self.sweep.as_ref().ok().or(self.paper.as_ref().and_then(|p| p.as_ref().ok()));
        axes.clear();
        for p in poses.iter() {
            axes.push_pose([p[0] as f32, p[1] as f32, p[2] as f32])?;
        }
        for m in moves.as_slice() {
            axes.push_move(0, m.from, m.to, 0.0, m.gamma_deg)?;
        }
        Ok(start.map(|c| core::array::from_fn(|i| c.k[i % 3][i / 3] as Real)))
    }

    /// The diagonal result to store when there is no full `K`: [`choose`]n and [`validate`]d.
    pub fn chosen(&self, acc: &Acceptance) -> Result<GyroCal, Error> {
        choose(self.sweep, self.paper).and_then(|c| validate(&c, acc).map(|_| c))
    }
}

/// Largest accepted cross-axis term of a full `K` (|K_ij|, i ≠ j): low-cost MEMS couple ≈ 1 %.
pub const MAX_CROSS_AXIS: f32 = 0.1;

/// Rejects a full `K` whose scale factors are implausible or too uncertain, or whose cross-axis
/// terms are implausible.
pub fn validate_full(cal: &FullCal, acc: &Acceptance) -> Result<(), Error> {
    for i in 0..3 {
        check_scale(i, cal.k[i][i], cal.sigma_k[i][i], cal.noise_ratio, acc)?;
        for j in (0..3).filter(|&j| j != i) {
            if !(cal.k[i][j].abs() <= MAX_CROSS_AXIS) {
                return Err(Error::ResultRejected { axis: i as u8, k: cal.k[i][j], sigma: cal.sigma_k[i][j] });
            }
        }
    }
    Ok(())
}

/// Largest distance (°/s) of a rest's bias from the line through its neighbours
/// ([`Drift::off_trend_dps`]) under which moves that disagree with one `K` are blamed on the rig
/// (a slip) rather than on the bias ([`Error::BiasDrifting`]). A smooth drift, however fast, is
/// tracked (a warm-up of τ ≥ 1 min leaves < 1e-3 °/s); rest-mean noise is ≈ 0.007 °/s per axis;
/// 0.05 °/s left in over half of a 4 s rest-to-rest span is 0.1°, most of the residual limit.
pub const MAX_OFF_TREND_DPS: f32 = 0.05;

/// A solve's error as the user must read it: any error becomes [`Error::AxesMirrored`] when the
/// moves turn gravity as the left-hand rule says ([`Rotations::mirrored`]); [`Error::MovesInconsistent`] becomes
/// [`Error::BiasDrifting`] when a rest's bias left the trend of its neighbours by more than
/// [`MAX_OFF_TREND_DPS`]; a full `K` the moves between poses do not determine
/// ([`Error::RotationAxesCoplanar`], a singular or unobservable normal matrix) is blamed on the
/// moves dropped when they are why too few are left ([`Rotations::drop_error`]: the most common
/// reason with its numbers, [`Error::BiasDrifting`] for a changing bias). A slip
/// moves the board, not the bias: it stays `MovesInconsistent` (or `AxisNotFixed`).
pub fn blame<const M: usize, const C: usize, const P: usize>(
    e: Error,
    drift: &Drift,
    rotations: Option<(&Rotations<M, C, P>, &RotationLimits)>,
) -> Error {
    if let Some(mirrored) = rotations.and_then(|(r, _)| r.mirrored()) {
        return mirrored;
    }
    match e {
        Error::MovesInconsistent { .. } if drift.off_trend_dps() > MAX_OFF_TREND_DPS => {
            Error::BiasDrifting { off_trend_dps: drift.off_trend_dps(), limit_dps: MAX_OFF_TREND_DPS, dps_per_min: drift.dps_per_min() }
        }
        Error::RotationAxesCoplanar { .. } | Error::Singular | Error::FullKUnobservable { .. } | Error::TooFewRows { .. } => {
            rotations.and_then(|(r, limits)| r.drop_error(limits)).unwrap_or(e)
        }
        e => e,
    }
}

/// The paper's constant-rate spin: which part of it is averaged (the servo speeds up after
/// the start and slows before the end), how long that part must be, and the least rate.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SteadyRate {
    /// Skipped after the spin starts (s).
    pub skip_start_s: f32,
    /// Skipped before it ends (s).
    pub skip_end_s: f32,
    /// Shortest averaged part a log's steady run needs (s).
    pub min_s: f32,
    /// Smallest shaft rate that counts as a spin (°/s).
    pub min_dps: f32,
}

impl SteadyRate {
    /// One second skipped at the start, half a second at the end; ≥ 3 s at ≥ 2 °/s.
    pub const DEFAULT: SteadyRate = SteadyRate { skip_start_s: 1.0, skip_end_s: 0.5, min_s: 3.0, min_dps: 2.0 };

    /// A sample `elapsed_s` after the start of a spin that lasts `duration_s` is averaged.
    pub fn averaged(&self, elapsed_s: Real, duration_s: Real) -> bool {
        elapsed_s > self.skip_start_s as Real && elapsed_s < duration_s - self.skip_end_s as Real
    }
}

/// Where the paper's estimator takes the shaft rate `ω_n` from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RateSource {
    /// The rate the servo was commanded at (a positional servo; a log's servo column).
    Commanded,
    /// The rate gravity turned about the axis, seen by the calibrated accelerometer (a
    /// continuous servo's speed is unknown).
    Gravity,
}

impl RateSource {
    /// Its name in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            RateSource::Commanded => "servo column",
            RateSource::Gravity => "accelerometer",
        }
    }
}

/// The angle gravity turns about a fixed axis over a spin, summed sample to sample, and the
/// time it took: the shaft's rate without knowing the servo's speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GravityTurn {
    axis: Option<Vector3<Real>>,
    prev: Option<Vec3>,
    turn_deg: Real,
    t_first: Option<Time>,
    t_last: Time,
}

impl GravityTurn {
    /// About `axis` (unit, calibrated accelerometer frame); `None`: no axis, no rate.
    pub fn new(axis: Option<Vector3<Real>>) -> Self {
        Self { axis, prev: None, turn_deg: 0.0, t_first: None, t_last: Time::ZERO }
    }

    /// A calibrated accelerometer sample (g) at `t`.
    pub fn add(&mut self, t: Time, accel_g: Vec3) {
        if let (Some(u), Some(p)) = (self.axis, self.prev) {
            self.turn_deg += turn_deg(&u, &v64(p), &v64(accel_g));
        }
        self.prev = Some(accel_g);
        self.t_first.get_or_insert(t);
        self.t_last = t;
    }

    /// Mean rate of the turn (°/s, ≥ 0; 0 before two samples).
    pub fn rate_dps(&self) -> f32 {
        match self.t_first {
            Some(t0) if self.t_last > t0 => (self.turn_deg.abs() / self.t_last.since(t0)) as f32,
            _ => 0.0,
        }
    }
}

/// The shaft rate for the paper's estimator (°/s) and its source: the commanded rate when the
/// servo turned at a known one, else the rate gravity turned.
pub fn spin_rate(commanded_dps: Option<f32>, gravity: &GravityTurn) -> (f32, RateSource) {
    match commanded_dps {
        Some(w) => (w, RateSource::Commanded),
        None => (gravity.rate_dps(), RateSource::Gravity),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimators::accel::AccelModel;
    use crate::estimators::bias::RestBias;
    use crate::estimators::rotation;
    use crate::time::secs;

    #[test]
    fn a_too_uncertain_scale_names_disagreeing_moves_apart_from_too_few() {
        use core::fmt::Write;
        let acc = crate::procedure::Config::DEFAULT.acceptance;
        let text = |ratio: f32| {
            let e = check_scale(1, 1.0057, 0.0051, ratio, &acc).unwrap_err();
            let mut s = heapless::String::<400>::new();
            write!(s, "{e}").unwrap();
            s
        };
        assert!(check_scale(1, 1.0057, 0.0049, 15.0, &acc).is_ok());
        let disagree = text(15.2);
        assert!(
            disagree.contains("known only to 1 sigma 0.0051 (limit 0.0050)") && disagree.contains("disagree by 15.2 times their noise"),
            "{disagree}"
        );
        let few = text(0.9);
        assert!(few.contains("agree within their noise (0.9 times it) but turn too little about y") && !few.contains("disagree"), "{few}");
        let unknown = text(f32::NAN);
        assert!(!unknown.contains("disagree") && unknown.contains("about varied axes"), "{unknown}");
    }

    #[test]
    fn moves_that_disagree_are_blamed_on_the_bias_only_when_it_left_its_trend() {
        let inconsistent = Error::MovesInconsistent { residual_rms_deg: 0.3, limit_deg: 0.15 };
        let rest = |t: f64, b: f32| RestBias { t: secs(t), residual_dps: [b, 0.0, 0.0] };
        // A fast but smooth warm-up (0.3 °/s per minute): the rig, not the bias.
        let mut smooth = Drift::new();
        for i in 0..10 {
            smooth.add(rest(4.0 * i as Real, 0.02 * i as f32));
        }
        assert_eq!(blame(inconsistent, &smooth, rotation::NONE), inconsistent);
        // One rest 0.08 °/s off the line of its neighbours: the bias.
        let mut uneven = smooth;
        uneven.add(rest(40.0, 0.28));
        uneven.add(rest(44.0, 0.22));
        match blame(inconsistent, &uneven, rotation::NONE) {
            Error::BiasDrifting { off_trend_dps, limit_dps, dps_per_min } => {
                assert!((off_trend_dps - 0.08).abs() < 1e-4 && limit_dps == MAX_OFF_TREND_DPS && dps_per_min > 0.25);
            }
            e => panic!("{e:?}"),
        }
        // Other errors are never renamed.
        assert_eq!(blame(Error::NoUsableMove, &uneven, rotation::NONE), Error::NoUsableMove);
    }

    #[test]
    fn an_accelerometer_fit_needs_one_pose_more_than_its_unknowns() {
        // Poses of a sensor with gains 1.01, 0.99, 1.02 and offsets 10, -20, 5 mg, with a little
        // noise: a fit with as many unknowns as poses would pass through them (1σ 0).
        let poses = |n: usize| {
            let mut c = <AccelCalibrator>::new();
            for k in 0..n {
                let (th, ph) = (k as Real * 2.4, libm::acos(1.0 - 2.0 * (k as Real + 0.5) / n as Real));
                let f = [libm::sin(ph) * libm::cos(th), libm::sin(ph) * libm::sin(th), libm::cos(ph)];
                let noise = 1e-4 * libm::sin(7.3 * k as Real);
                let a = [f[0] * 1.01 + 0.010 + noise, f[1] * 0.99 - 0.020 - noise, f[2] * 1.02 + 0.005 + noise];
                c.add_pose(a.map(|v| v as f32)).unwrap();
            }
            c
        };
        let acc = crate::procedure::Config::DEFAULT.acceptance;
        assert_eq!(fit_accel_tested(&poses(6), &acc), Err(Error::TooFewPoses { have: 6, need: 7 }));
        let (six, test) = fit_accel_tested(&poses(9), &acc).unwrap();
        assert_eq!((six.model, test), (AccelModel::SixParam, None), "9 poses: 6 parameters, not 9");
        // From 10 poses both are fitted and the F-test chooses (the same error on every axis here
        // is a cross term's shape, which it finds).
        let (ten, test) = fit_accel_tested(&poses(10), &acc).unwrap();
        let test = test.expect("both models fitted");
        assert_eq!(ten.model, if test.nine() { AccelModel::NineParam } else { AccelModel::SixParam }, "{test:?}");
    }
}
