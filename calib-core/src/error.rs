//! The one error type of the crate: every failure names the requirement that was not met.

use crate::formats::record::StoreError;
use crate::formats::text::{Fixed, Int, Text};
use crate::procedure::Phase;
use core::fmt;

/// Why a calibration step failed. Values in the variants are in the units their names state.
#[allow(missing_docs)] // variant fields are named with their units
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error {
    /// A least-squares problem has fewer independent rows than unknowns.
    TooFewRows { have: u32, need: u32 },
    /// The normal matrix is not positive definite: the data do not determine every unknown.
    Singular,
    /// The (equilibrated) normal matrix is too badly conditioned to trust the solution.
    IllConditioned { condition: f32, limit: f32 },
    /// A sample or parameter was NaN or infinite.
    NonFinite,
    /// Too few static poses for this estimator.
    TooFewPoses { have: u8, need: u8 },
    /// No room for another pose or move (bounded storage, no heap).
    CapacityExceeded { max: u8 },
    /// The rotation axis is within `limit_deg` of vertical: every pose sees the same gravity.
    AxisNearVertical { tilt_deg: f32, limit_deg: f32 },
    /// The rotation axis is within `limit_deg` of horizontal: `A·u → 0` (paper estimator only).
    AxisNearHorizontal { tilt_deg: f32, limit_deg: f32 },
    /// A sensor axis sees too small a component of the rotation axis to calibrate it.
    WeakSensorAxis { axis: u8, component: f32, min: f32 },
    /// The static poses span too small a shaft angle.
    AngleSpanTooSmall { span_deg: f32, min_deg: f32 },
    /// The pose accelerations do not lie on one plane: the axis moved (loose clamp, hand-held).
    AxisNotFixed { plane_rms_g: f32, limit_g: f32 },
    /// The mean spin rate is too small to scale the gyro (paper estimator).
    NoSpin { rate_dps: f32, min_dps: f32 },
    /// The scale solution has mixed signs or a gain outside the plausible range.
    ImplausibleScale { axis: u8, value: f32 },
    /// No move between two poses turned the shaft by a usable angle.
    NoUsableMove,
    /// Too few samples in a rest period or segment.
    TooFewSamples { have: u32, need: u32 },
    /// The sensor moved during a period that must be still.
    NotStill { gyro_std_dps: f32, accel_std_g: f32 },
    /// The gyro bias exceeds the datasheet range: wrong sensor settings or a broken part.
    BiasOutOfRange { axis: u8, bias_dps: f32, limit_dps: f32 },
    /// An accelerometer fit gave a non-ellipsoid (negative gain) or did not converge.
    AccelFitFailed,
    /// No sensor sample for `gap_s` seconds: the sensor or its bus stopped.
    SensorTimeout { gap_s: f32 },
    /// A phase did not complete within its time limit.
    PhaseTimeout { phase: Phase, limit_s: f32 },
    /// Servo `channel` (0 rotation, 1 tilt) was commanded to turn but the gyro saw (almost) no
    /// rotation: unplugged or stalled.
    ServoNotTurning { channel: u8, commanded_deg: f32, measured_deg: f32 },
    /// A static pose kept being disturbed: retaken `retries` times.
    PoseDisturbed { index: u8, retries: u8 },
    /// A gyro sample reached its full scale during a rig move or pose (the spin: either sensor's):
    /// lower the rate or raise the range.
    Saturated,
    /// The calibration result failed validation (scale out of range or too uncertain).
    ResultRejected { axis: u8, k: f32, sigma: f32 },
    /// A scale factor is known only to `sigma` (1σ), above the accepted `limit`; `noise_ratio`:
    /// the fit's weighted residual (≈ 1 when the moves agree within their noise; NaN unknown),
    /// which tells disagreeing moves from too few of them about this axis.
    TooUncertain { axis: u8, k: f32, sigma: f32, limit: f32, noise_ratio: f32 },
    /// The magnetometer's samples fit no ellipsoid (a quadric that is not one).
    MagFitFailed,
    /// Too few distinct magnetometer readings (`samples`) or still poses with a reading
    /// (`poses`) for its fit: the readings stopped, or the board turned too little.
    MagTooFew { samples: u16, need_samples: u16, poses: u8, need_poses: u8 },
    /// A still pose's field strength or dip differs from the others': a magnet, a laptop or a
    /// servo near the board.
    MagDisturbed { pose: u8, field_ut: f32, expected_ut: f32, dip_deg: f32, expected_dip_deg: f32 },
    /// The calibrated field's strength scatters by `residual_ut` RMS (µT), above `limit_ut`.
    MagFitPoor { residual_ut: f32, limit_ut: f32 },
    /// The samples reach only `coverage` of the sphere's directions, below `need`.
    MagCoverageThin { coverage: f32, need: f32 },
    /// The record could not be stored; the previous one is kept.
    Storage(StoreError),
    /// The shell did not drain the command queue: a command would have been lost.
    CommandQueueFull,
    /// Samples were lost during the calibration (FIFO overrun, failed read): the gyro integrals
    /// have a gap.
    SamplesLost { count: u16 },
    /// The sensor stopped answering during the calibration (I2C error).
    SensorFault,
    /// The result holds a NaN or an infinite number: never stored.
    ResultNotFinite,
    /// Full `K`: moves about too few rotation axes (each tilt setting's pan axis, the hinge).
    TooFewAxes { have: u8, need: u8 },
    /// Full `K`: the rotation axes lie (nearly) in one plane; `angle_deg` is the largest angle of
    /// an axis from the plane of two others.
    AxesCoplanar { angle_deg: f32, limit_deg: f32 },
    /// Full `K`: an axis' poses do not span a plane (too few, or only two orientations), so its
    /// direction is uncertain by `sigma_deg`.
    AxisUndetermined { axis: u8, sigma_deg: f32, limit_deg: f32 },
    /// Full `K`: the normal matrix has a (near) null direction, e.g. an upright bracket (vertical
    /// pan shaft) leaves the scale across the hinge unobservable.
    FullKUnobservable { condition: f32, limit: f32 },
    /// The moves between static poses (e.g. hand-held) turn about too few directions: the
    /// smallest eigenvalue of the mean `n nᵀ` of their axes is `spread` (of 1/3 at best).
    RotationAxesCoplanar { spread: f32, limit: f32 },
    /// Full `K`: the moves disagree with one rigid `K` (RMS residual of the move equations).
    MovesInconsistent { residual_rms_deg: f32, limit_deg: f32 },
    /// The gyro turns the wrong way for the accelerometer: of the moves that tell, `left_hand`
    /// turn gravity as the left-hand rule in these axes says and `right_hand` as the right-hand
    /// rule ([`crate::estimators::rotation::Rotations::mirrored`]). The axes' map (the driver's
    /// for this board, a log's columns) is off by a reflection; not a slip ([`crate::board`]).
    AxesMirrored { right_hand: u8, left_hand: u8 },
    /// The gyro bias moved unevenly, which tracking between rests cannot follow: the moves
    /// disagree with one `K` and a rest's bias left the line through its neighbours by
    /// `off_trend_dps` (> `limit_dps`), or so many hand-held moves changed bias between their
    /// rests by more than the limit that too few are left (`off_trend_dps` the largest change).
    /// `dps_per_min`: the drift over the calibration, or across the largest change.
    BiasDrifting { off_trend_dps: f32, limit_dps: f32, dps_per_min: f32 },
    /// The moves between poses do not determine `K` because `dropped` of the `total` were
    /// dropped, most of them for `reason`: its worst value `value` (a step or turn in °, a bias change in °/s, a gap in s) against
    /// `limit`.
    MovesDropped { dropped: u8, total: u8, reason: crate::estimators::rotation::Rejected, value: f32, limit: f32 },
}

/// A fit's weighted residual above which its moves disagree (rather than agree, but too few).
pub const DISAGREE_RATIO: f32 = 2.0;

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::TooFewRows { have, need } => {
                let (have, need) = (Int(have.into()), Int(need.into()));
                write!(f, "least squares needs {need} rows, has {have}")
            }
            Error::Singular => f.write_str("normal matrix singular: the data do not determine every parameter"),
            Error::IllConditioned { condition, limit } => {
                write!(f, "normal matrix ill-conditioned: condition {condition} > limit {limit}", condition = Fixed(condition, 0), limit = Fixed(limit, 0))
            }
            Error::NonFinite => f.write_str("non-finite value (NaN or infinity) in the input"),
            Error::TooFewPoses { have, need } => {
                let (have, need) = (Int(have.into()), Int(need.into()));
                write!(f, "too few static poses: {have}, need {need}")
            }
            Error::CapacityExceeded { max } => {
                let max = Int(max.into());
                write!(f, "capacity exceeded: at most {max} entries")
            }
            Error::AxisNearVertical { tilt_deg, limit_deg } => write!(
                f,
                "rotation axis {tilt_deg} deg from vertical, need at least {limit_deg} deg: tilt the servo", tilt_deg = Fixed(tilt_deg, 1), limit_deg = Fixed(limit_deg, 1)),
            Error::AxisNearHorizontal { tilt_deg, limit_deg } => write!(
                f,
                "rotation axis {tilt_deg} deg from vertical, need at most {limit_deg} deg for the paper method", tilt_deg = Fixed(tilt_deg, 1), limit_deg = Fixed(limit_deg, 1)),
            Error::WeakSensorAxis { axis, component, min } => write!(
                f,
                "sensor axis {} has rotation-axis component {component} < {min}: remount the board askew",
                Text(["x", "y", "z"][axis as usize % 3]), component = Fixed(component, 3), min = Fixed(min, 3)),
            Error::AngleSpanTooSmall { span_deg, min_deg } => {
                write!(f, "poses span {span_deg} deg of shaft angle, need {min_deg} deg", span_deg = Fixed(span_deg, 1), min_deg = Fixed(min_deg, 1))
            }
            Error::AxisNotFixed { plane_rms_g, limit_g } => write!(
                f,
                "pose accelerations off their plane by {plane_rms_g} g rms > {limit_g} g: the axis moved", plane_rms_g = Fixed(plane_rms_g, 4), limit_g = Fixed(limit_g, 4)),
            Error::NoSpin { rate_dps, min_dps } => {
                write!(f, "spin rate {rate_dps} deg/s below {min_dps} deg/s", rate_dps = Fixed(rate_dps, 2), min_dps = Fixed(min_dps, 2))
            }
            Error::ImplausibleScale { axis, value } => write!(
                f,
                "implausible scale factor {value} on axis {}{}",
                Text(["x", "y", "z"][axis as usize % 3]),
                Text(if value < 0.0 { ": negative: mirrored axes" } else { "" }),
                value = Fixed(value, 4)
            ),
            Error::NoUsableMove => f.write_str("no move between poses turned the shaft by a usable angle"),
            Error::TooFewSamples { have, need } => {
                let (have, need) = (Int(have.into()), Int(need.into()));
                write!(f, "too few samples: {have}, need {need}")
            }
            Error::NotStill { gyro_std_dps, accel_std_g } => write!(
                f,
                "motion during a still period: gyro std {gyro_std_dps} deg/s, accel std {accel_std_g} g", gyro_std_dps = Fixed(gyro_std_dps, 3), accel_std_g = Fixed(accel_std_g, 4)),
            Error::BiasOutOfRange { axis, bias_dps, limit_dps } => write!(
                f,
                "gyro bias {bias_dps} deg/s on axis {} exceeds {limit_dps} deg/s",
                Text(["x", "y", "z"][axis as usize % 3]), bias_dps = Fixed(bias_dps, 2), limit_dps = Fixed(limit_dps, 1)),
            Error::AccelFitFailed => f.write_str("accelerometer fit failed: poses do not describe an ellipsoid"),
            Error::SensorTimeout { gap_s } => write!(f, "no sensor sample for {gap_s} s: sensor or I2C bus stopped", gap_s = Fixed(gap_s, 2)),
            Error::PhaseTimeout { phase, limit_s } => write!(f, "phase {} did not complete within {limit_s} s", Text(phase.name()), limit_s = Fixed(limit_s, 0)),
            Error::ServoNotTurning { channel, commanded_deg, measured_deg } => write!(
                f,
                "{} servo commanded {commanded_deg} deg but the gyro saw {measured_deg} deg: servo unplugged or stalled",
                Text(if channel == 1 { "tilt (D10)" } else { "rotation (D9)" }), commanded_deg = Fixed(commanded_deg, 1), measured_deg = Fixed(measured_deg, 1)),
            Error::PoseDisturbed { index, retries } => {
                let (index, retries) = (Int(index.into()), Int(retries.into()));
                write!(f, "static pose {index} disturbed {retries} times: keep the rig still")
            }
            Error::Saturated => f.write_str("sensor saturated during a move: lower the servo rate or raise the range"),
            Error::ResultRejected { axis, k, sigma } => write!(
                f,
                "result rejected: axis {} scale {k} (1 sigma {sigma}) outside the accepted range",
                Text(["x", "y", "z"][axis as usize % 3]), k = Fixed(k, 4), sigma = Fixed(sigma, 4)),
            Error::TooUncertain { axis, k, sigma, limit, noise_ratio } => {
                let name = Text(["x", "y", "z"][axis as usize % 3]);
                write!(
                    f,
                    "result rejected: axis {name} scale {k} is known only to 1 sigma {sigma} (limit {limit}): ",
                    k = Fixed(k, 4),
                    sigma = Fixed(sigma, 4),
                    limit = Fixed(limit, 4)
                )?;
                if noise_ratio > DISAGREE_RATIO {
                    write!(f, "the moves disagree by {} times their noise", Fixed(noise_ratio, 1))
                } else if noise_ratio >= 0.0 {
                    write!(
                        f,
                        "the moves agree within their noise ({} times it) but turn too little about {name}: make more moves about axes near {name}",
                        Fixed(noise_ratio, 1)
                    )
                } else {
                    f.write_str("make more moves, about varied axes")
                }
            }
            Error::MagFitFailed => f.write_str("magnetometer: the samples fit no ellipsoid: turn the board through every direction, away from magnets"),
            Error::MagTooFew { samples, need_samples, poses, need_poses } => {
                let (samples, need_samples, poses, need_poses) = (Int(samples.into()), Int(need_samples.into()), Int(poses.into()), Int(need_poses.into()));
                write!(
                f,
                "magnetometer: {samples} distinct readings and {poses} still poses with one (need {need_samples} and {need_poses}): its readings stopped, or the board was turned through too few orientations"
            )
            }
            Error::MagDisturbed { pose, field_ut, expected_ut, dip_deg, expected_dip_deg } => {
                let pose = Int(pose.into());
                write!(
                f,
                "magnetometer: the field at pose {pose} is {field} uT at dip {dip} deg, the others' {expected} uT at {expected_dip} deg: a magnet, a laptop or the servo near the board; calibrate it away from them",
                field = Fixed(field_ut, 1),
                dip = Fixed(dip_deg, 1),
                expected = Fixed(expected_ut, 1),
                expected_dip = Fixed(expected_dip_deg, 1)
            )
            }
            Error::MagFitPoor { residual_ut, limit_ut } => write!(
                f,
                "magnetometer: the calibrated field's strength scatters by {} uT RMS (limit {}): the field changed during the step (a magnet or metal moving near it)",
                Fixed(residual_ut, 2),
                Fixed(limit_ut, 2)
            ),
            Error::MagCoverageThin { coverage, need } => write!(
                f,
                "magnetometer: the samples reach {} % of the sphere's directions (need {} %): turn the board through more orientations",
                Fixed(coverage * 100.0, 0),
                Fixed(need * 100.0, 0)
            ),
            Error::Storage(e) => write!(f, "storing the record failed: {e}; the previous record is kept"),
            Error::CommandQueueFull => f.write_str("command queue full: the shell did not drain the procedure's commands"),
            Error::SamplesLost { count } => {
                let count = Int(count.into());
                write!(
                f,
                "{count} sample(s) lost (a FIFO overrun or a failed read): the gyro integral has a gap; rerun (no host can cause it: \
                 the board never waits for RTT or USB; if it repeats, check the sensor's I2C wiring and supply)"
            )
            }
            Error::SensorFault => f.write_str("the sensor stopped answering during the calibration (I2C error): check the board, rerun"),
            Error::ResultNotFinite => f.write_str("the result holds a NaN, an infinite number or a value beyond what a part can have: not stored"),
            Error::TooFewAxes { have, need } => {
                let (have, need) = (Int(have.into()), Int(need.into()));
                write!(
                f,
                "moves about {have} rotation axes, the full K needs {need} non-coplanar: use at least 2 tilt settings with tilt moves between them"
            )
            }
            Error::AxesCoplanar { angle_deg, limit_deg } => write!(
                f,
                "rotation axes nearly coplanar: best axis {angle_deg} deg from the plane of two others, need {limit_deg} deg: add tilt moves (the hinge axis) or spread the tilt settings", angle_deg = Fixed(angle_deg, 1), limit_deg = Fixed(limit_deg, 1)),
            Error::AxisUndetermined { axis, sigma_deg, limit_deg } => {
                let axis = Int(axis.into());
                write!(
                f,
                "axis {axis}: its poses do not span a plane (direction 1 sigma {sigma_deg} deg > {limit_deg} deg): give it at least 3 poses at distinct angles", sigma_deg = Fixed(sigma_deg, 2), limit_deg = Fixed(limit_deg, 2))
            }
            Error::FullKUnobservable { condition, limit } => write!(
                f,
                "full K unobservable: normal-matrix condition {condition} > {limit} (upright bracket?): tilt the pan servo's shaft >= 20 deg from vertical", condition = Fixed(condition, 0), limit = Fixed(limit, 0)),
            Error::RotationAxesCoplanar { spread, limit } => write!(
                f,
                "the moves between poses turn about too few directions (axis spread {spread} < {limit}): turn the board about varied axes, not only about one", spread = Fixed(spread, 3), limit = Fixed(limit, 3)),
            Error::AxesMirrored { right_hand, left_hand } => {
                let (right_hand, left_hand) = (Int(right_hand.into()), Int(left_hand.into()));
                write!(
                f,
                "gyro axes mirrored: {left_hand} moves left-handed, {right_hand} right-handed: wrong axis map, not a slip")
            }
            Error::MovesInconsistent { residual_rms_deg, limit_deg } => write!(
                f,
                "moves disagree with one K: residual {residual_rms_deg} deg rms > {limit_deg} deg: the board slipped on the bracket or a pose moved; re-clamp and rerun", residual_rms_deg = Fixed(residual_rms_deg, 3), limit_deg = Fixed(limit_deg, 3)),
            Error::BiasDrifting { off_trend_dps, limit_dps, dps_per_min } => write!(
                f,
                "the gyro bias changed unevenly between rests ({off_trend_dps} deg/s off a steady drift, > {limit_dps}; drift {dps_per_min} deg/s per minute), so the moves disagree with one K: the gyro's temperature changed unevenly (still warming up, a draught, a hand on the board); wait 5 min after power-on, shield the board, keep it still longer at each pose, and rerun", off_trend_dps = Fixed(off_trend_dps, 3), limit_dps = Fixed(limit_dps, 3), dps_per_min = Fixed(dps_per_min, 3)),
            Error::MovesDropped { dropped, total, reason, value, limit } => {
                let (dropped, total) = (Int(dropped.into()), Int(total.into()));
                use crate::estimators::rotation::Rejected;
                let (value, limit) = if reason == Rejected::Gap {
                    (Fixed(value, 3), Fixed(limit, 3))
                } else {
                    (Fixed(value, 1), Fixed(limit, 1))
                };
                write!(f, "{dropped} of {total} moves between poses were dropped: ")?;
                match reason {
                    Rejected::Saturated => f.write_str("they reached the gyro's full scale; turn more slowly or use a larger full scale"),
                    Rejected::TooFast => write!(f, "they turned up to {value} deg between two samples (limit {limit} deg); turn more slowly or log at a higher rate"),
                    Rejected::TooShort => write!(f, "they turned less than {limit} deg (at most {value} deg); turn the board further between poses"),
                    Rejected::BiasDrifted => write!(f, "the gyro bias changed between their poses by up to {value} deg/s (limit {limit}); keep the board still longer at each pose"),
                    Rejected::Full => write!(f, "no room for more (at most {limit} moves)"),
                    Rejected::Gap => write!(f, "samples are missing from them (up to {value} s between two samples, limit {limit} s): the board may have turned unseen; record the whole session without gaps"),
                    Rejected::Unseen => write!(f, "gravity turned up to {value} deg between their poses while the gyro turned far less; the log was cut between its poses (sections glued together?) or the gyro and accelerometer columns are not one sensor's: record the whole session, moves included"),
                }
            }
        }
    }
}
