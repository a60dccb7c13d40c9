//! The gyro bias and the hand-held accelerometer poses.

use super::*;
use crate::math::real::{self, Real};
use crate::math::vec3::Length;
use crate::Time;

impl Procedure {
    pub(super) fn finish_bias(&mut self, capture: &Capture, t: Time) {
        let mut est = BiasEstimator::new();
        est.add_window(&capture.gyro, &capture.accel);
        match est.finish(&self.cfg.bias) {
            Ok(b) => {
                self.bias = Some(b);
                self.note_rest(capture, capture.rest(self.bias));
                self.push(Command::Report(Report::Bias(b)));
                // The pan/tilt plan fits the accelerometer to its own rig poses.
                if self.cfg.is_pan_tilt() {
                    self.begin_rig(t);
                } else if self.accel_cal.model == AccelModel::None {
                    self.servo_deg = None;
                    self.last_pulse = None;
                    self.push(Command::ServoOff { channel: 0 });
                    self.attitude = Some(Matrix3::identity());
                    self.enter(Step::HandHeld { capture: Capture::default(), due: HandDue::None }, t);
                } else {
                    self.begin_rig(t);
                }
            }
            Err(e) => self.fail(e),
        }
    }

    pub(super) fn finish_accel_pose(&mut self, capture: &Capture, t: Time) {
        // The previous pose's end first, if its ticks have not finished it (it may end the step).
        for _ in 0..2 {
            self.hand_due(t);
        }
        if !matches!(self.step, Step::HandHeld { .. }) {
            return;
        }
        let a = capture.accel_mean();
        let min_sep = self.cfg.accel_min_separation_deg as Real;
        let new = v64(a);
        let need = self.cfg.accel_poses.max(6) as usize;
        // The accelerometer's poses lie apart from each other; a pose after them (a move only)
        // from the one before it. The rotations hold the raw poses of the step so far.
        let extra = self.accel_poses.len() >= need;
        let poses = self.rotations.poses();
        let distinct = (if extra { poses.len().saturating_sub(1) } else { 0 }..poses.len()).all(|i| {
            let old = poses.get(i);
            crate::math::trig::atan2(old.cross(&new).length(), old.dot(&new)).to_degrees() >= min_sep
        });
        self.step = Step::HandHeld { capture: Capture::default(), due: HandDue::None };
        if !distinct {
            return;
        }
        let sigma = capture.accel.radial_std_of_mean() as f32;
        if !extra {
            if let Err(e) = self.accel_poses.add_pose(a) {
                return self.fail(e);
            }
            // Gravity's direction in the raw accelerometer's axes until it is calibrated.
            if capture.mag.count() > 0 {
                if self.mag.poses() == 0 {
                    self.mag_first_pose = (self.accel_poses.len() - 1) as u8;
                }
                if let Err(e) = self.mag.add_pose(a, capture.mag.mean().map(|v| v as f32)) {
                    return self.fail(e);
                }
            }
        }
        // The move from the previous pose to this one: a rotation constraint on the full K.
        let (bias, predicted) = self.hand_rest(capture);
        let rise_deg = capture.turn.rise_deg(capture.t_first, capture.t_last);
        let warm_c = if predicted { capture.temp_c() } else { f32::NAN };
        let rest = PoseRest { bias, predicted, rise_deg, span_s: capture.t_last.since(capture.t_first) as f32, warm_c };
        let to = match self.rotations.push_pose(a, sigma, rest) {
            Ok(to) => to,
            Err(e) => return self.fail(e),
        };
        if let Some(att) = self.attitude {
            self.rotations.push_attitude(to, att);
        }
        self.push(Command::Report(Report::AccelPose { index: to, accel_g: a }));
        if to > 0 {
            let rejected = self.rotations.end(to, &self.cfg.rotation).err();
            self.step = Step::HandHeld { capture: Capture::default(), due: HandDue::Rows { to, rejected } };
        }
        self.rotations.begin(to);
    }

    /// One part of a hand-held pose's end ([`HandDue`]), the next on the next tick.
    fn hand_due(&mut self, t: Time) {
        let Step::HandHeld { due, .. } = self.step else { return };
        let next = match due {
            HandDue::None => return,
            HandDue::Rows { to, rejected } => {
                // Each kept move's rows once.
                if rejected.is_none() {
                    self.rotations.add_last_at_identity(&mut self.rows, &self.cfg.rotation);
                }
                HandDue::Report { to, rejected }
            }
            HandDue::Report { .. } => HandDue::None,
        };
        if let Step::HandHeld { due, .. } = &mut self.step {
            *due = next;
        }
        if let HandDue::Report { to, rejected } = due {
            self.hand_move_end(to, rejected, t);
        }
    }

    /// The move into hand-held pose `to` reported with `K`'s 1σ by the moves so far; the step
    /// ends once the moves give `K` to its goal (or no pose has room), or fails when their axes
    /// are coplanar.
    fn hand_move_end(&mut self, to: u8, rejected: Option<rotation::Rejected>, t: Time) {
        let (goal, room, need) = (self.cfg.hand_k_sigma, rejected != Some(rotation::Rejected::Full), self.cfg.accel_poses.max(6) as usize);
        let turn_deg = self.rotations.moves().last().filter(|_| rejected.is_none()).map_or(0.0, |m| m.turn_deg);
        let k_sigma = if self.accel_poses.len() >= need {
            self.rows.inverse().map_or(f32::NAN, |inv| real::sqrt((0..9).fold(0.0 as Real, |m, i| m.max(inv[i][i]))) as f32)
        } else {
            f32::NAN
        };
        let (spread, min_spread) = (self.rotations.axis_spread(), self.cfg.rotation.min_axis_spread);
        self.push(Command::Report(Report::HandMove { from: to - 1, to, rejected, turn_deg, spread, need: min_spread, k_sigma, goal }));
        if self.accel_poses.len() < need {
            return;
        }
        // The hand-held moves must turn about three dimensions to give the full K: named at
        // once, not after further poses. (Counting the moves dropped for a changing bias:
        // `fail` names the drift then.)
        if self.rotations.moves_before_drift() >= 3 && !(spread >= min_spread) {
            return self.fail(Error::RotationAxesCoplanar { spread, limit: min_spread });
        }
        // Further poses while the moves leave K short of the goal (and there is room for them).
        if !(k_sigma <= goal) && usize::from(to) + 1 < usize::from(self.cfg.max_hand_poses) && room {
            return;
        }
        // The accelerometer's fits and the magnetometer's follow on the ticks (`fit_due`).
        self.enter(Step::Reattach { accel: AccelFit::Nine, mag: MagFit::Due(MagStage::Start), pressed: false }, t)
    }

    /// The hand-held step's fits in parts, one a tick, each within the sensor's FIFO time (the
    /// shell reads it between ticks): the accelerometer's ([`AccelFit`]), then the
    /// magnetometer's ([`MagFit`]); then, once the button was pressed ([`Self::handle_button`]),
    /// the rig.
    pub(super) fn fit_due(&mut self, t: Time) {
        let Step::Reattach { accel, mag, pressed } = self.step else { return self.hand_due(t) };
        if !self.one_servo() {
            return;
        }
        let next = match accel {
            AccelFit::Nine if self.accel_poses.len() < pipeline::NINE_PARAM_POSES => AccelFit::Choice(None),
            AccelFit::Nine => match self.accel_poses.start9() {
                Ok(p) => AccelFit::NineIter { p, left: crate::estimators::accel::GAUSS_NEWTON_STEPS as u8 },
                Err(_) => AccelFit::Choice(None),
            },
            AccelFit::NineIter { mut p, left } => match self.accel_poses.gauss_newton_step(&mut p, &mut self.rows) {
                Ok(true) => AccelFit::NineEnd(p),
                Ok(false) if left <= 1 => AccelFit::NineEnd(p),
                Ok(false) => AccelFit::NineIter { p, left: left - 1 },
                Err(_) => AccelFit::Choice(None),
            },
            AccelFit::NineEnd(p) => AccelFit::NineCal(p, self.rows.condition()),
            AccelFit::NineCal(p, condition) => AccelFit::Choice(self.accel_poses.calibration9_given(&p, &self.rows, condition).ok()),
            AccelFit::Choice(nine) => return self.fit_accel_pending(nine),
            AccelFit::Done => {
                return match mag {
                    MagFit::Due(stage) => self.fit_mag_step(stage),
                    MagFit::Done if pressed => self.begin_rig(t),
                    _ => {}
                }
            }
        };
        if let Step::Reattach { accel, .. } = &mut self.step {
            *accel = next;
        }
    }

    /// The accelerometer's fit by the model [`pipeline::ModelTest`] chooses, with the
    /// 9-parameter fit made on an earlier tick: the hand-held poses then calibrated, the
    /// magnetometer due; a failure fails the calibration.
    fn fit_accel_pending(&mut self, nine: Option<AccelCal>) {
        match self.fit_accel(nine) {
            Ok(()) => {
                self.rotations.calibrate_poses(&self.accel_cal);
                if let Step::Reattach { accel, .. } = &mut self.step {
                    *accel = AccelFit::Done;
                }
            }
            Err(e) => self.fail(e),
        }
    }

    /// A hand-held pose's bias and whether it is a prediction ([`Drift::hand_rest`]); a
    /// measured one is a rest of the calibration.
    fn hand_rest(&mut self, capture: &Capture) -> (RestBias, bool) {
        let measured = capture.rest(self.bias);
        let noise = self.bias.map_or(0.0, |b| b.noise_dps.iter().fold(0.0f32, |m, v| m.max(*v)));
        match self.drift.shaky(measured, capture.gyro.max_std() as f32, noise) {
            Some(predicted) => (predicted, true),
            None => {
                self.note_rest(capture, measured);
                (measured, false)
            }
        }
    }

    /// A rest of the calibration: its bias joins the drift and the temperature fit, and settles
    /// the predicted bias of the hand-held poses since the previous rest. The first rig rest
    /// after the hand-held step ends the attitude's tracking.
    pub(super) fn note_rest(&mut self, capture: &Capture, rest: RestBias) {
        let temp_c = capture.temp_c();
        if let Some(before) = self.drift.last() {
            self.rotations.settle_bias(&before, &rest, self.attitude, [self.rest_temp_c, temp_c]);
        }
        self.rest_temp_c = temp_c;
        if !matches!(self.step, Step::HandHeld { .. }) {
            self.attitude = None;
        }
        self.drift.add(rest);
        self.temp_fit.add(capture.temp_c(), &rest);
    }

    /// One part of the magnetometer's fit to the hand-held step's readings in the calibrated
    /// accelerometer's frame ([`MagStage`]), the next on the next tick; the calibration
    /// reported at the end, nothing to do when none was read (no magnetometer). A failure fails
    /// the calibration.
    fn fit_mag_step(&mut self, stage: MagStage) {
        let mag = &mut self.mag;
        let next = match stage {
            MagStage::Start if mag.samples() == 0 && mag.poses() == 0 => Ok(None),
            MagStage::Start => {
                let accel = self.accel_cal;
                mag.map_poses(|f| accel.apply(f));
                // The hand-held step's rows are done with: the ellipsoid's take their place.
                self.rows = NormalEquations::new();
                mag.ellipsoid_centre(None).map(|centre| Some(MagStage::Rows { centre, next: 0 }))
            }
            MagStage::Rows { centre, next } => {
                let from = usize::from(next);
                match mag.add_ellipsoid_rows(&mut self.rows, &centre, None, from..from + MAG_ROWS_PER_CALL) {
                    Ok(false) => Ok(Some(MagStage::Rows { centre, next: next.saturating_add(MAG_ROWS_PER_CALL as u16) })),
                    Ok(true) => ellipsoid_from(&self.rows, &centre).map(|e| Some(MagStage::Align(e))),
                    Err(e) => Err(e),
                }
            }
            MagStage::Align(e) => mag.alignment(&e).map(|a| Some(MagStage::Finish(e, a))),
            MagStage::Finish(e, a) => mag.finish(&e, &a, &MagLimits::default()).map(|cal| {
                self.mag_cal = Some(cal);
                self.push(Command::Report(Report::Mag(cal)));
                None
            }),
        };
        let fit = match next {
            Ok(Some(stage)) => MagFit::Due(stage),
            Ok(None) => MagFit::Done,
            // A disturbed pose is named by its hand-held pose number (the field is read from pose 1 on).
            Err(Error::MagDisturbed { pose, field_ut, expected_ut, dip_deg, expected_dip_deg }) => {
                let pose = pose.saturating_add(self.mag_first_pose);
                return self.fail(Error::MagDisturbed { pose, field_ut, expected_ut, dip_deg, expected_dip_deg });
            }
            Err(e) => return self.fail(e),
        };
        if let Step::Reattach { mag, .. } = &mut self.step {
            *mag = fit;
        }
    }

    /// Fits the accelerometer to the poses by the model [`pipeline::ModelTest`] chooses (`nine`:
    /// the 9-parameter fit, [`pipeline::fit_nine`]), checks and reports it.
    pub(super) fn fit_accel(&mut self, nine: Option<AccelCal>) -> Result<(), Error> {
        let (fit, _) = pipeline::choose_accel(&self.accel_poses, nine, &self.cfg.acceptance)?;
        self.accel_cal = fit;
        self.push(Command::Report(Report::Accel(fit)));
        Ok(())
    }
}
