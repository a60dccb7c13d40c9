//! The rig: the servo(s) driven through the static poses, the moves between them and the paper's
//! constant-rate spin.

use super::*;
use crate::math::real::{self, Real};
use crate::Time;

impl Procedure {
    pub(super) fn park_servo(&mut self) {
        if let ServoKind::Continuous { .. } = self.cfg.servo() {
            self.push(Command::ServoOff { channel: 0 });
        }
        self.set_angle(self.cfg.pose_first_deg);
        if self.cfg.is_pan_tilt() {
            self.set_tilt(self.cfg.tilt_settings_deg[0]);
        }
    }

    /// Sets the commanded angle (°): drives a positional servo; for a continuous servo it is
    /// only the nominal angle (commanded speed × time) logged in the `servo_deg` column.
    pub(super) fn set_angle(&mut self, deg: f32) {
        self.servo_deg = Some(deg);
        if let ServoKind::Positional = self.cfg.servo() {
            let pulse = self.cfg.pulse_for_deg(deg);
            if self.last_pulse != Some(pulse) {
                self.last_pulse = Some(pulse);
                self.push(Command::Servo { channel: 0, pulse_us: pulse });
            }
        }
    }

    /// Starts a commanded turn from the current angle: a positional ramp to `to_deg` at
    /// `rate_dps`, or a continuous servo at speed `dir` (±1) for `secs`.
    pub(super) fn start_ramp(&mut self, t: Time, to_deg: f32, rate_dps: f32, dir: f32, secs: f32) -> Ramp {
        let from_deg = self.servo_deg.unwrap_or(self.cfg.pose_first_deg);
        match self.cfg.servo() {
            ServoKind::Positional => {
                Ramp { channel: 0, from_deg, to_deg, t0: t, duration_s: (to_deg - from_deg).abs() / rate_dps.max(1.0) }
            }
            ServoKind::Continuous { neutral_us, span_us, speed, nominal_rate_dps, .. } => {
                let pulse = self.cfg.clamp_pulse(neutral_us as f32 + dir * speed * span_us as f32);
                self.push(Command::Servo { channel: 0, pulse_us: pulse });
                Ramp { channel: 0, from_deg, to_deg: from_deg + dir * nominal_rate_dps * secs, t0: t, duration_s: secs }
            }
        }
    }

    /// Sets the commanded tilt (°, 0 = level) and drives the tilt servo (channel 1) there.
    pub(super) fn set_tilt(&mut self, deg: f32) {
        self.tilt_deg = Some(deg);
        let pulse = self.cfg.pulse_for_deg(deg + 90.0);
        if self.last_tilt_pulse != Some(pulse) {
            self.last_tilt_pulse = Some(pulse);
            self.push(Command::Servo { channel: 1, pulse_us: pulse });
        }
    }

    pub(super) fn begin_rig(&mut self, t: Time) {
        self.rest.reset();
        self.park_servo();
        self.poses.clear();
        self.moves.clear();
        self.axes.clear();
        self.integ = Integrator::new();
        self.enter(Step::WaitRest, t);
    }

    pub(super) fn finish_pose(&mut self, k: u16, capture: &Capture, s: &Sample) {
        let (pan_tilt, (setting, j)) = (self.cfg.is_pan_tilt(), self.cfg.plan_at(k));
        // The pan/tilt plan keeps the raw means: its accelerometer is fitted to them at the end,
        // from the first visit of every pan angle at every setting.
        let a = if pan_tilt { capture.accel_mean() } else { self.accel_cal.apply(capture.accel_mean()) };
        let idx = match if pan_tilt { self.axes.push_pose(a) } else { self.poses.push(a) } {
            Ok(i) => i,
            Err(e) => return self.fail(e),
        };
        let forward_pass = k < self.cfg.rig_steps() * TILT_SETTINGS as u16;
        if pan_tilt && forward_pass && j < self.cfg.pose_count as u16 {
            if let Err(e) = self.accel_poses.add_pose(a) {
                return self.fail(e);
            }
        }
        let rest = capture.rest(self.bias);
        let before = self.drift.last().unwrap_or(rest);
        self.note_rest(capture, rest);
        let servo_deg = self.servo_deg.unwrap_or(f32::NAN);
        self.push(Command::Report(Report::RigPose { index: idx, servo_deg, accel_g: a }));
        if k > 0 {
            let gamma = self.integ.gamma_tracked(&before, &rest);
            let turned = real::sqrt(gamma.iter().map(|v| v * v).sum::<Real>()) as f32;
            // Step 0 of a later tilt setting (and every return step) is reached by a tilt move
            // (about the hinge, axis id `TILT_SETTINGS`); every other step by a pan move about
            // the setting's own axis.
            let tilt_move = pan_tilt && j == 0;
            let (channel, commanded) = match self.cfg.servo() {
                _ if tilt_move => (1, self.cfg.tilt_settings_deg[setting] - self.cfg.tilt_settings_deg[self.cfg.plan_at(k - 1).0]),
                ServoKind::Positional => (0, self.cfg.step_deg(j) - self.cfg.step_deg(j - 1)),
                ServoKind::Continuous { nominal_rate_dps, move_s, .. } => (0, nominal_rate_dps * move_s),
            };
            if turned < self.cfg.min_turn_fraction * commanded.abs() {
                return self.fail(Error::ServoNotTurning { channel, commanded_deg: commanded.abs(), measured_deg: turned });
            }
            let axis = if tilt_move { TILT_SETTINGS } else { setting } as u8;
            let pushed =
                if pan_tilt { self.axes.push_move(axis, idx - 1, idx, commanded, gamma) } else { self.moves.push(idx - 1, idx, gamma) };
            if let Err(e) = pushed {
                return self.fail(e);
            }
            self.push(Command::Report(Report::Move { from: idx - 1, to: idx, gyro_turn_deg: turned }));
        }
        self.integ = Integrator::new();
        self.integ.add(s.t, self.bias.map_or(s.gyro_dps, |b| sub(s.gyro_dps, b.bias_dps)));
        let next = k + 1;
        if next < self.cfg.plan_steps() {
            let (nextetting, nj) = self.cfg.plan_at(next);
            let ramp = if pan_tilt && nj == 0 {
                let (from_deg, to_deg) = (self.cfg.tilt_settings_deg[setting], self.cfg.tilt_settings_deg[nextetting]);
                let duration_s = (to_deg - from_deg).abs() / self.cfg.move_rate_dps.max(1.0);
                Ramp { channel: 1, from_deg, to_deg, t0: s.t, duration_s }
            } else {
                // Forward over the first half of each round trip, back over the second.
                let forward = self.cfg.pose_slot(nj) > self.cfg.pose_slot(j);
                let move_s = if let ServoKind::Continuous { move_s, .. } = self.cfg.servo() { move_s } else { 0.0 };
                let dir = if forward { 1.0 } else { -1.0 };
                self.start_ramp(s.t, self.cfg.step_deg(nj), self.cfg.move_rate_dps, dir, move_s)
            };
            self.step = Step::Move { k: next, ramp };
        } else if pan_tilt {
            self.solve_full(s.t);
        } else if self.cfg.spin_rate_dps > 0.0 {
            let ramp = self.start_ramp(s.t, self.cfg.pose_last_deg, self.cfg.spin_rate_dps, 1.0, self.cfg.spin_s);
            // The axis gravity turns about: a continuous servo's rate (a positional one's is
            // commanded).
            let continuous = matches!(self.cfg.servo(), ServoKind::Continuous { .. });
            let axis = continuous.then(|| self.poses.geometry(&self.cfg.geometry, false).ok().map(|g| g.u)).flatten();
            let spin = Spin { ramp, rate: Moments3::new(), gravity: GravityTurn::new(axis) };
            self.enter(Step::Spin { spin }, s.t);
        } else {
            self.solve(s.t);
        }
    }

    pub(super) fn finish_spin(&mut self, spin: &Spin, t: Time) {
        self.push(Command::ServoOff { channel: 0 });
        self.servo_deg = None;
        self.last_pulse = None;
        // A continuous servo's speed is unknown: the rate at which gravity turns about the axis.
        let commanded = matches!(self.cfg.servo(), ServoKind::Positional).then_some(self.cfg.spin_rate_dps);
        let (omega, _) = pipeline::spin_rate(commanded, &spin.gravity);
        if spin.rate.count() > 0 {
            // The spin's bias: the last pose's rest, just before it.
            let r = self.drift.last().map_or([0.0; 3], |r| r.residual_dps);
            self.gbar = Some((sub(spin.rate.mean().map(|v| v as f32), r), omega));
        }
        self.solve(t);
    }
}
