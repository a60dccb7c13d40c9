//! The estimators at the end of the rig, the record built from their result, and the store.

use super::*;
use crate::estimators::bias::RestNoise;
use crate::estimators::full::{iterate_end, GAUSS_NEWTON_ITERATIONS, GAUSS_NEWTON_STEP};
use crate::estimators::mag::{MagMove, REFINE_STEPS};
use crate::math::real::Real;
use crate::Time;

impl Procedure {
    /// The end of the pan/tilt plan: its steps follow on the ticks ([`Self::solve_step`]), the
    /// accelerometer's fit first.
    pub(super) fn solve_full(&mut self, t: Time) {
        self.step = Step::Solving { stage: SolveStage::PanTilt, k: None, iterations: 0, next: t };
    }

    /// The pan/tilt plan's accelerometer from the rig poses (`nine`: its 9-parameter fit, if
    /// made) and the poses calibrated with it; the solve of the full `K` follows
    /// ([`SolveStage::Solve`]).
    fn pan_tilt_accel(&mut self, nine: Option<AccelCal>) {
        if let Err(e) = self.fit_accel(nine) {
            // Poses too little spread for the accelerometer: the rig's geometry, seen on the raw
            // poses, says what to change (an upright bracket's pan axis is vertical; coplanar
            // axes); else the fit's own error.
            let vertical = |g| match g {
                Err(e @ Error::AxisNearVertical { .. }) => Err(e),
                _ => Ok(()),
            };
            let geometry = self
                .load_setting(0)
                .and_then(|_| vertical(self.poses.geometry(&self.cfg.geometry, false)))
                .and_then(|_| self.axes.solve(&self.cfg.full).map(|_| ()));
            return self.fail(geometry.err().unwrap_or(e));
        }
        self.axes.calibrate_poses(&self.accel_cal);
    }

    /// The end of the full `K` (or its error): with the pan/tilt plan, beside it the one-axis
    /// sweep estimator of the tilt setting whose pan axis is the most oblique to the sensor
    /// axes, then the store; with the one-servo plan [`Self::finish_full`].
    fn end_full(&mut self, full: Result<FullCal, Error>, t: Time) {
        if self.one_servo() {
            return self.finish_full(full, t);
        }
        let oblique = |a: &FullAxis| a.u.iter().fold(f32::INFINITY, |m, c| m.min(c.abs()));
        let setting = match &full {
            Ok(f) => (0..TILT_SETTINGS).max_by(|&a, &b| oblique(&f.axes[a]).total_cmp(&oblique(&f.axes[b]))).unwrap_or(0),
            Err(_) => 0,
        };
        if let Err(e) = self.one_axis_beside(setting) {
            return self.fail(e);
        }
        self.store_full(full, t);
    }

    /// Reports a full `K` (or fails with why there is none), validates it and hands its record
    /// to the shell.
    pub(super) fn store_full(&mut self, full: Result<FullCal, Error>, t: Time) {
        let full = match full {
            Ok(f) => f,
            Err(e) => return self.fail(e),
        };
        self.full = Some(full);
        self.push(Command::Report(Report::FullK {
            k: full.k,
            sigma_k: full.sigma_k,
            condition: full.condition,
            non_coplanar_deg: full.non_coplanar_deg,
            residual_rms_deg: full.residual_rms_deg,
            axes: full.n_axes,
            moves: full.moves,
        }));
        if let Err(e) = pipeline::validate_full(&full, &self.cfg.acceptance) {
            return self.fail(e);
        }
        let poses = self.axes.poses().len() as u8;
        let record = self.context(t).full(&full, poses);
        self.store(record, t);
    }

    /// The poses and pan moves of one tilt setting as a one-axis rig (`poses`, `moves`).
    pub(super) fn load_setting(&mut self, setting: usize) -> Result<(), Error> {
        self.poses.clear();
        self.moves.clear();
        let per = self.cfg.rig_steps() as usize;
        for p in setting * per..((setting + 1) * per).min(self.axes.poses().len()) {
            let v = self.axes.poses().get(p);
            self.poses.push([v[0] as f32, v[1] as f32, v[2] as f32])?;
        }
        let first = (setting * per) as u8;
        for m in self.axes.moves().iter().filter(|m| m.axis as usize == setting) {
            self.moves.push(m.from - first, m.to - first, m.gamma_deg)?;
        }
        Ok(())
    }

    /// The sweep estimator on the (calibrated) poses and pan moves of one tilt setting, reported
    /// for comparison with the full `K`.
    pub(super) fn one_axis_beside(&mut self, setting: usize) -> Result<(), Error> {
        self.load_setting(setting)?;
        match sweep::solve(&self.poses, &self.moves, &self.cfg.geometry) {
            Ok(cal) => self.push(Command::Report(Report::Gyro(cal))),
            Err(error) => self.push(Command::Report(Report::EstimatorFailed { method: Method::Sweep, error })),
        }
        Ok(())
    }

    /// The end of the one-axis plan: the solve's steps follow on the ticks ([`Self::solve_step`]),
    /// the warm-up and the diagonal estimators first.
    pub(super) fn solve(&mut self, t: Time) {
        self.step = Step::Solving { stage: SolveStage::Warmup, k: None, iterations: 0, next: t };
    }

    /// The diagonal estimators; with hand-held moves the full `K` follows, one Gauss–Newton
    /// iteration a step; else the record of the one-axis `K`.
    fn diagonal(&mut self, t: Time) {
        let solved = OneAxis::diagonal(&self.poses, &self.moves, self.gbar, &self.cfg.geometry);
        for (method, r) in [(Method::Sweep, Some(solved.sweep)), (Method::Paper, solved.paper)] {
            match r {
                Some(Ok(cal)) => self.push(Command::Report(Report::Gyro(cal))),
                Some(Err(error)) => self.push(Command::Report(Report::EstimatorFailed { method, error })),
                None => {}
            }
        }
        // With hand-held moves: the rig's axis and their rotation constraints give the full K.
        if !self.rotations.moves().is_empty() {
            return match solved.load_axes(&self.poses, &self.moves, &mut self.axes) {
                Ok(k) => self.step = Step::Solving { stage: SolveStage::Iterate, k, iterations: 0, next: t.plus_s(SOLVE_STEP_S) },
                Err(e) => self.finish_full(Err(e), t),
            };
        }
        match solved.chosen(&self.cfg.acceptance) {
            Ok(c) => {
                let record = self.context(t).one_axis(&c);
                self.store(record, t);
            }
            Err(e) => self.fail(e),
        }
    }

    /// One call of the solve ([`Step::Solving`]), between two FIFO reads. The pan/tilt plan:
    /// its accelerometer, the solve in parts below, the sweep estimator beside it and the store.
    /// The one-servo plan: the
    /// warm-up; the diagonal estimators; each
    /// Gauss–Newton iteration of the full `K` (the rig's rows, then the rotations' a batch a
    /// call); once it converged (or the iterations ran out, or a step could not be taken) the
    /// solve at the last iterate in the parts of [`Axes::solve_after`]; the magnetometer refined
    /// with it; each move's misfit and the store. The stage changes in place.
    #[inline(never)]
    pub(super) fn solve_step(&mut self, t: Time) {
        let Step::Solving { stage, k, iterations, next } = &mut self.step else { return };
        *next = t.plus_s(SOLVE_STEP_S);
        let (limits, rl, at) = (&self.cfg.full, &self.cfg.rotation, k.unwrap_or_default());
        // The call's work: `Some` stage to go on with, `None` another batch of this one, an
        // error the solve's end. An iteration's error goes on to the solve, whose checks name a
        // bad geometry better, and is the solve's otherwise.
        let step: Result<Option<SolveStage>, Error> = match stage {
            // Each plan's own stages (a firmware built for one plan links the other's not).
            SolveStage::Warmup
            | SolveStage::Diagonal
            | SolveStage::Iterate
            | SolveStage::IterateRows { .. }
            | SolveStage::RefineMag { .. }
                if self.cfg.is_pan_tilt() =>
            {
                return
            }
            SolveStage::PanTilt | SolveStage::PanTiltNine(_) | SolveStage::PanTiltAccel(_) if !self.cfg.is_pan_tilt() => return,
            SolveStage::PanTilt => Ok(Some(match pipeline::nine_params(&self.accel_poses, &mut self.rows) {
                Some(p) => SolveStage::PanTiltNine(p),
                None => SolveStage::PanTiltAccel(None),
            })),
            SolveStage::PanTiltNine(p) => Ok(Some(SolveStage::PanTiltAccel(self.accel_poses.calibration9(p, &self.rows).ok()))),
            SolveStage::PanTiltAccel(nine) => {
                let nine = *nine;
                *stage = SolveStage::Solve { failed: None };
                self.pan_tilt_accel(nine);
                return;
            }
            SolveStage::Warmup => {
                if let Some(tempco) = self.temp_fit.finish() {
                    self.rotations.follow_warmup(&tempco.dps_per_c);
                }
                Ok(Some(SolveStage::Diagonal))
            }
            SolveStage::Diagonal => return self.diagonal(t),
            SolveStage::Iterate => match self.axes.iterate_rig(limits, &mut self.rows, *k) {
                Ok(a) => {
                    *k = Some(a);
                    Ok(Some(SolveStage::IterateRows { sum: RowSum::new() }))
                }
                Err(e) => Ok(Some(SolveStage::Solve { failed: Some(e) })),
            },
            SolveStage::IterateRows { sum } => {
                let rows = self.rotations.add_rows_batch(&mut self.rows, sum, &at, rl, ROW_CHUNKS);
                match rows.and_then(|done| done.map(|_| iterate_end(&self.rows, &at)).transpose()) {
                    Ok(None) => Ok(None),
                    Ok(Some((x, change))) => {
                        *k = Some(x);
                        *iterations += 1;
                        let last = change < GAUSS_NEWTON_STEP || *iterations >= GAUSS_NEWTON_ITERATIONS;
                        Ok(Some(if last { SolveStage::Solve { failed: None } } else { SolveStage::Iterate }))
                    }
                    Err(e) => Ok(Some(SolveStage::Solve { failed: Some(e) })),
                }
            }
            SolveStage::Solve { failed } => {
                let failed = *failed;
                let none = self.cfg.is_pan_tilt() || self.rotations.moves().is_empty();
                self.axes.solve_rig(limits, Some((&self.rotations, rl)), &mut self.rows).and_then(|part| match failed {
                    Some(e) => Err(e),
                    // The pan/tilt plan: no rotations.
                    None if none => Ok(Some(SolveStage::SolveK { part, rotation: None })),
                    None => Ok(Some(SolveStage::SolveRows { part, sum: RowSum::new() })),
                })
            }
            SolveStage::SolveRows { part, sum } => {
                let (part, done) = (*part, *iterations);
                let rows = self.rotations.add_rows_batch(&mut self.rows, sum, &at, rl, ROW_CHUNKS);
                rows.and_then(|sums| sums.map(|(_, rss, n)| full::rotation_fit(&self.rotations, rl, rss, n, done)).transpose())
                    .map(|fit| fit.map(|rotation| SolveStage::SolveK { part, rotation: Some(rotation) }))
            }
            SolveStage::SolveK { part, rotation } => full::solve_k(&self.rows, limits).map(|(sol, condition)| {
                Some(SolveStage::SolveEnd { part: *part, rotation: *rotation, x: sol.x, rss: sol.rss, dof: sol.dof, condition })
            }),
            SolveStage::SolveEnd { part, rotation, x, rss, dof, condition } => {
                let sol = self.rows.solution(*x, *rss, *dof, *condition);
                sol.and_then(|sol| self.axes.solve_end(limits, part, &self.rows, &sol, *condition, *rotation)).map(|f| {
                    self.full = Some(f);
                    Some(SolveStage::Store)
                })
            }
            // The magnetometer's refinement, one step a call: the first, then the others.
            SolveStage::Store if !self.cfg.is_pan_tilt() => {
                let next = match self.full.and_then(|f| self.refine_mag(&f.k, Matrix3::identity(), 1)) {
                    Some((_, (rot, _))) => SolveStage::RefineMag { rot, left: (REFINE_STEPS - 1) as u8 },
                    None => SolveStage::StoreEnd,
                };
                if let Step::Solving { stage, .. } = &mut self.step {
                    *stage = next;
                }
                return;
            }
            SolveStage::RefineMag { rot, left } => {
                let (rot, left) = (*rot, *left);
                let next = match self.full.and_then(|f| self.refine_mag(&f.k, rot, 1)) {
                    Some((cal, (rot, sol))) if left <= 1 => {
                        let c = self.mag.refined(&cal, &rot, &sol);
                        self.mag_cal = Some(c);
                        self.push(Command::Report(Report::Mag(c)));
                        SolveStage::StoreEnd
                    }
                    Some((_, (rot, _))) => SolveStage::RefineMag { rot, left: left - 1 },
                    None => SolveStage::StoreEnd,
                };
                if let Step::Solving { stage, .. } = &mut self.step {
                    *stage = next;
                }
                return;
            }
            SolveStage::Store | SolveStage::StoreEnd => {
                let full = self.full.ok_or(Error::NoUsableMove);
                return self.end_full(full, t);
            }
        };
        match step {
            Ok(Some(next)) => *stage = next,
            Ok(None) => {}
            Err(e) => self.end_full(Err(e), t),
        }
    }

    /// The full `K` of the one-axis plan with hand-held moves (the magnetometer refined with it
    /// in the call before): each move's misfit reported and the record stored (or the failure
    /// said).
    fn finish_full(&mut self, full: Result<FullCal, Error>, t: Time) {
        // Each move's misfit at the solution (none without one).
        let residual_deg = full.as_ref().map_or([0.0; MAX_ROTATION_MOVES], |f| self.rotations.residuals_deg(&f.k, &self.cfg.rotation));
        let (moves, rejected) = (self.rotations.moves().len() as u8, self.rotations.rejected());
        self.push(Command::Report(Report::Rotations { moves, rejected, residual_deg }));
        self.store_full(full, t)
    }

    /// `steps` of the magnetometer's refinement ([`MagCalibrator::refine_steps`]) from the die's
    /// rotation `rot`, with the hand-held moves as the full `K` turns them, when this run fitted
    /// it and every hand-held pose from its first has its field (so that the moves' poses are
    /// its poses): the fit refined and where the steps reached; `None` (the fit at the re-clamp
    /// stays) otherwise or when a step fails.
    fn refine_mag(&self, k: &crate::Mat3, rot: Matrix3<Real>, steps: usize) -> Option<(MagCal, Alignment)> {
        let cal = self.mag_cal.filter(|_| self.mag.poses() > 0)?;
        let first = self.mag_first_pose;
        if self.mag.poses() + first as usize != self.accel_poses.len() {
            return None;
        }
        let mut moves = heapless::Vec::<MagMove, MAX_ROTATION_MOVES>::new();
        for m in self.rotations.moves() {
            let (Some(from), Some(to)) = (m.from.checked_sub(first), m.to.checked_sub(first)) else { continue };
            if let Some(r) = self.rotations.rotation(m, k) {
                let r = core::array::from_fn(|i| core::array::from_fn(|j| r[(i, j)] as f32));
                let _ = moves.push(MagMove { from, to, r });
            }
        }
        self.mag.refine_steps(&cal, &moves, rot, steps).ok().map(|a| (cal, a))
    }

    /// Hands a built record to the shell to store (or fails: a NaN or an infinite number).
    pub(super) fn store(&mut self, record: Record, t: Time) {
        match record.check_finite().map(|_| record).map_err(|_| Error::ResultNotFinite) {
            Ok(record) => {
                self.push(Command::Report(Report::TempCo(record.tempco)));
                self.enter(Step::Storing { record }, t);
                self.push(Command::Store(()));
            }
            Err(e) => self.fail(e),
        }
    }

    /// The shell's answer to [`Command::Store`]: only a verified store reports the result,
    /// applies it, shows it as done and moves the sequence number on; a failed one fails the
    /// calibration with [`Error::Storage`] (the previous record stays in use).
    pub fn handle_stored(&mut self, t: Time, result: Result<(), StoreError>) {
        self.stored_answer(t, result);
        self.settle();
    }

    pub(super) fn stored_answer(&mut self, t: Time, result: Result<(), StoreError>) {
        let Step::Storing { record } = self.step else { return };
        match result {
            Ok(()) => {
                self.stored = Some(record);
                self.phase_t0 = t;
                self.step = Step::Finished(Phase::Done);
                self.push(Command::Report(Report::Done(())));
                self.push(Command::Apply(()));
                self.push(Command::Led(Led::Done));
            }
            Err(e) => self.fail(Error::Storage(e)),
        }
    }

    /// The mean sensor temperature of the calibration so far (°C), if any was read.
    fn temp_c(&self) -> Option<f32> {
        let mut temp = self.temp;
        temp.merge(&self.window_read.temp);
        (temp.count() > 0).then(|| temp.mean())
    }

    /// The gyro bias a record made at MCU time `t` holds, with its 1σ: the rests' at the
    /// record's temperature when the tempco is known (`b(T) = b + c (T − temp_c)` then holds),
    /// else their line's at `t` ([`Drift::at`]: over the rig's many short rests less noisy
    /// than [`Drift::predict`]'s, measured by drift-bench); the 1σ [`Drift::predict`]'s. The
    /// first rest's alone is minutes old on a warming board. `None` before the bias rest.
    pub fn bias_at(&self, t: Time) -> Option<Bias> {
        let first = self.bias?;
        let residual = self.temp_c().and_then(|t| self.temp_fit.residual_at(t)).or_else(|| self.drift.at(t).map(|r| r.residual_dps));
        let sigma = self.drift.predict(t, RestNoise::Own(first.sigma_dps)).map_or(first.sigma_dps, |(_, s)| s);
        let bias_dps = residual.map_or(first.bias_dps, |r| core::array::from_fn(|k| first.bias_dps[k] + r[k]));
        Some(Bias { bias_dps, sigma_dps: sigma, ..first })
    }

    /// The gyro bias's random walk the rests of this calibration show (°/s/√s,
    /// [`crate::estimators::bias::TempFit::walk_dps_rtsec`]), `None` while the tempco is unknown.
    pub fn bias_walk_dps_rtsec(&self) -> Option<f32> {
        self.temp_fit.walk_dps_rtsec()
    }

    /// The record's calibration-independent part (sequence, temperature, bias, accelerometer) at
    /// MCU time `t` ([`Self::bias_at`]).
    pub(super) fn context(&self, t: Time) -> record::Context {
        record::Context {
            seq: self.stored.map_or(1, |r| r.seq.wrapping_add(1)),
            temp_c: self.temp_c(),
            gyro_bias_dps: self.bias_at(t).map_or([0.0; 3], |b| b.bias_dps),
            accel: self.accel_cal,
            setup: self.cfg.setup,
            tempco: self.temp_fit.finish(),
            mag: self.mag_cal,
        }
    }
}
