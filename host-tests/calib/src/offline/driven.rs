//! The data-driven path: a log that is not a run of the firmware's procedure (another tool's,
//! another sensor's, `--no-rotations`, `--method`) turned into the inputs of calib-core's
//! estimators from the phases found in it. The decisions (which estimator, which `K`, what is
//! accepted, whom an error blames) are calib-core's [`pipeline`] ones, as in the firmware.

use super::*;
use calib_core::estimators::bias::{RestNoise, TempFit};
use calib_core::Time;
use nalgebra::Matrix3;

/// The log's phases with the bias they are corrected by.
struct Log<'a> {
    rows: &'a [Row],
    ph: &'a Phases,
    bias: Bias,
    /// Per segment (same index): its rest's bias, and whether it measured it.
    rests: Vec<(RestBias, bool)>,
}

impl<'a> Log<'a> {
    /// Every still segment measures the bias anew (a move loses the bias tracked between the
    /// rests that bound it), but for a hand's shaky pose ([`Drift::shaky`]), which takes it
    /// from the line between the rests before and after it (the drift's line through those
    /// before when none follows), as the firmware settles it. Shaky against a rest's own noise
    /// ([`rest_noise_dps`]), as the firmware judges against its first rest's.
    fn new(rows: &'a [Row], ph: &'a Phases, bias: Bias) -> Self {
        let noise = rest_noise_dps(ph).unwrap_or_else(|| bias.noise_dps.iter().fold(0.0f32, |m, v| m.max(*v)));
        let mut drift = Drift::new();
        let mut rests: Vec<(RestBias, bool)> = ph
            .segments
            .iter()
            .map(|s| {
                let measured = RestBias::new(rows[s.first].t, rows[s.last].t, s.gyro.mean().map(|v| v as f32), bias.bias_dps);
                let predicted = if s.is_rig_pose() { None } else { drift.shaky(measured, s.gyro.max_std() as f32, noise) };
                match predicted {
                    Some(p) => (p, false),
                    None => {
                        drift.add(measured);
                        (measured, true)
                    }
                }
            })
            .collect();
        for i in 0..rests.len() {
            let before = rests[..i].iter().rev().find(|r| r.1);
            let after = rests[i + 1..].iter().find(|r| r.1);
            if let (false, Some((a, _)), Some((b, _))) = (rests[i].1, before, after) {
                rests[i].0 = a.between(b, rests[i].0.t);
            }
        }
        Log { rows, ph, bias, rests }
    }

    /// A segment's mean temperature (°C), NaN when its rows have none.
    fn temp_c(&self, s: &Segment) -> f32 {
        let t: Vec<f32> = self.rows[s.first..=s.last].iter().filter_map(|r| r.temp_c).filter(|t| t.is_finite()).collect();
        if t.is_empty() {
            f32::NAN
        } else {
            t.iter().sum::<f32>() / t.len() as f32
        }
    }

    fn rest(&self, s: &Segment) -> RestBias {
        self.ph.segments.iter().position(|x| x.first == s.first).map_or(RestBias::default(), |i| self.rests[i].0)
    }

    /// The bias-corrected gyro integrated from the end of `from` to the end of `to` (°, sensor
    /// frame), the bias tracked between the two rests.
    fn gamma(&self, from: &Segment, to: &Segment) -> [f64; 3] {
        let mut it = Integrator::new();
        for r in &self.rows[from.last..=to.last] {
            it.add(r.t, sub(r.gyro_dps, self.bias.bias_dps));
        }
        it.gamma_tracked(&self.rest(from), &self.rest(to))
    }

    fn drift(&self) -> Drift {
        let mut drift = Drift::new();
        for (r, _) in self.rests.iter().filter(|(_, measured)| *measured) {
            drift.add(*r);
        }
        drift
    }

    /// The gyro bias at the log's end on the rests' line with its 1σ ([`Drift::predict`], the
    /// floor a rest mean's noise: the rig's still poses' own when the log has them, else the
    /// pooled one): the bias as the calibration hands over. (The pooled mean the
    /// moves are corrected against is the bias of no instant when it drifts.)
    fn bias_at_end(&self) -> Bias {
        let t_end = self.rows.last().map_or(Time::ZERO, |r| r.t);
        let n = self.ph.segments.iter().zip(&self.rests).filter(|(_, r)| r.1).map(|(s, _)| s.gyro.count()).next_back().unwrap_or(1);
        // A rest's own noise: the rig's still poses' ([`rest_noise_dps`]; the pooled figure
        // holds a hand's sway) when the log has them.
        let of_mean = |v: f32| v / (n.max(1) as f32).sqrt();
        let noise = match rest_noise_dps(self.ph) {
            Some(v) => RestNoise::Own([of_mean(v); 3]),
            None => RestNoise::Bound(self.bias.noise_dps.map(of_mean)),
        };
        match self.drift().predict(t_end, noise) {
            Some((r, sigma_dps)) => {
                Bias { bias_dps: core::array::from_fn(|k| self.bias.bias_dps[k] + r.residual_dps[k]), sigma_dps, ..self.bias }
            }
            None => self.bias,
        }
    }

    fn rig(&self) -> impl Iterator<Item = &Segment> {
        self.ph.segments.iter().filter(|s| s.is_rig_pose())
    }
}

/// The gyro noise of a rest (°/s, its largest axis): the median over the rig's still poses of
/// each one's own spread; `None` without them (a log of hand-held poses alone: the pooled
/// spread of its still segments). Not [`Bias::noise_dps`] when the log has rig poses: that
/// pools every segment under the rig's stillness threshold (0.8 °/s) about one mean, a hand's
/// poses with it, and reads 0.2–0.5 °/s on a swaying hand where a rest's own is 0.06; a swaying
/// pose then passed for a rest and took its own gyro mean as the bias, its sway's net turn over
/// the pose included (a slow nod's: 0.03 °/s per axis), which every move into and out of it,
/// and the poses whose bias the line through it gives, integrated.
fn rest_noise_dps(ph: &Phases) -> Option<f32> {
    let mut own: Vec<f64> = ph.segments.iter().filter(|s| s.is_rig_pose() && ph.measures_bias(s)).map(|s| s.gyro.max_std()).collect();
    own.sort_by(f64::total_cmp);
    own.get(own.len() / 2).map(|v| *v as f32)
}

/// The tilt settings of the rig poses (0.5° steps) with their pose counts, in order of first use.
fn settings(log: &Log) -> Vec<(i32, usize)> {
    let mut settings: Vec<(i32, usize)> = vec![];
    for s in log.rig() {
        match settings.iter_mut().find(|(t, _)| *t == s.tilt_setting()) {
            Some((_, n)) => *n += 1,
            None => settings.push((s.tilt_setting(), 1)),
        }
    }
    settings
}

/// Calibrates a log from its phases.
pub(super) fn calibrate(
    rows: &[Row],
    options: &Options,
    range_dps: Option<f32>,
    time_base: TimeBase,
    ph: Phases,
) -> Result<Calibration, OfflineError> {
    let (method, rotations_on) = (options.method, !options.no_rotations);
    let cfg = &Config { rotation: RotationLimits { whole_turns: options.whole_turns, ..CONFIG.rotation }, ..CONFIG };
    // Bias: the still segments pooled, against the log's own noise floor (a hand's shaky poses
    // only when there is nothing else).
    let mut b = BiasEstimator::new();
    let any_steady = ph.segments.iter().any(|s| ph.measures_bias(s));
    for s in ph.segments.iter().filter(|s| !any_steady || ph.measures_bias(s)) {
        b.add_window(&s.gyro, &s.accel);
    }
    let limits = BiasLimits { min_samples: 20, max_std_dps: ph.rest.gyro_std_max_dps, max_accel_std_g: f32::INFINITY, ..cfg.bias };
    let bias = b.finish(&limits).map_err(stage("gyro bias"))?;
    let log = Log::new(rows, &ph, bias);
    let settings = settings(&log);
    let pan_tilt = settings.len() >= 2;

    let (accel, accel_sigma, accel_test, handheld_poses) = accel(&log, pan_tilt)?;
    let main_setting = settings.iter().max_by_key(|(_, n)| *n).map(|(t, _)| *t);
    let (poses, moves) = one_axis_rig(&log, main_setting, &accel)?;
    let rotations = rotations(&log, &accel, range_dps, &cfg.rotation);
    let spin = spin(&log, &poses, &accel);

    // `--method paper|sweep` asks for that one-axis estimator alone; `--no-rotations` leaves the
    // hand-held moves out.
    let one_axis_only = matches!(method, Some(Method::Paper | Method::Sweep));
    let with_rotations = (rotations_on && !one_axis_only).then_some((&*rotations, &cfg.rotation));
    let (sweep, paper, full) = if pan_tilt {
        let full = (!one_axis_only).then(|| pan_tilt_full(&log, &settings, &accel, with_rotations));
        (sweep::solve(&poses, &moves, &cfg.geometry), spin.map(|(g, w, _)| paper::solve(&poses, g, w, &cfg.geometry)), full)
    } else {
        let mut axes = full::Axes::new();
        let limits = (&cfg.geometry, &cfg.full);
        let one = pipeline::OneAxis::solve(&poses, &moves, spin.map(|(g, w, _)| (g, w)), with_rotations, limits, &mut axes);
        (one.sweep, one.paper, one.full)
    };
    let drift = log.drift();
    let full_tried = full.as_ref().and_then(|f| f.as_ref().ok()).map(|f| f.k);
    let full = full.map(|f| {
        f.and_then(|f| pipeline::validate_full(&f, &cfg.acceptance).map(|_| f))
            .map_err(|e| pipeline::blame(e, &drift, Some((&*rotations, &cfg.rotation))))
    });
    let left_out = left_out(&log, &rotations, &poses, main_setting, (handheld_poses, pan_tilt));
    let chosen = match method {
        Some(Method::Sweep | Method::Full) => sweep.map_err(stage("sweep estimator")),
        Some(Method::Paper) => paper.ok_or(OfflineError::NoSpin).and_then(|p| p.map_err(stage("paper estimator"))),
        None => pipeline::choose(sweep, paper).map_err(stage("sweep estimator")),
    };
    // The firmware's acceptance: a result it would not store is not given either; a scale near
    // a unit factor names the mistake.
    let scale = implied_scale(chosen.as_ref().map_err(|e| match e {
        OfflineError::Calib { error, .. } => error,
        _ => &Error::NoUsableMove,
    }));
    let gyro = match scale.and_then(gyro_units) {
        Some(e) => Err(e),
        None => chosen.and_then(|c| pipeline::validate(&c, &cfg.acceptance).map(|_| c).map_err(stage("validation"))),
    };
    if let Err(e @ OfflineError::GyroUnits { .. }) = gyro {
        return Err(e);
    }
    // A log of hand-held poses only: its gyro result is the full K of their moves, and so is
    // its error (never the servo sweep's "too few static poses: 0").
    let hand_held = |error: Error| OfflineError::Calib { stage: HAND_HELD_STAGE, error };
    let gyro = match (&full, gyro) {
        (Some(Err(error)), Err(_)) if poses.is_empty() => Err(hand_held(*error)),
        // No full K was tried: every move between the poses was dropped.
        (None, Err(_)) if poses.is_empty() && with_rotations.is_some() && rotations.moves().is_empty() => {
            Err(hand_held(rotations.drop_error(&cfg.rotation).unwrap_or(Error::NoUsableMove)))
        }
        (_, g) => g,
    };
    Ok(Calibration {
        gyro,
        full,
        bias: log.bias_at_end(),
        accel,
        accel_sigma,
        sweep,
        paper,
        spin_rate: spin.map(|(_, w, source)| (w, source)),
        rig_poses: poses.len(),
        moves: moves.len(),
        handheld_poses,
        replayed: None,
        replayed_record: None,
        hand_moves: Some(HandMoves::of(&rotations, &cfg.rotation)),
        time_base,
        phases: ph,
        setup: None,
        mag: None,
        left_out,
        full_tried,
        rotations: Some(rotations),
        accel_test,
        mirrored: None,
    })
}

/// The stage that names a hand-held log's gyro error.
pub(super) const HAND_HELD_STAGE: &str = "full K from the moves between hand-held poses";

/// The accelerometer from the hand-held poses, and on a pan/tilt rig from every rig pose too
/// (spread over pan × tilt, they are no cone), by the model the F-test chooses; identity below
/// the poses a fit needs. Also its 1σ from each pose's own ([`Segment::accel_sigma_of_mean`]),
/// the test and the number of poses used.
fn accel(log: &Log, pan_tilt: bool) -> Result<(AccelCal, Option<AccelSigma>, Option<pipeline::ModelTest>, usize), OfflineError> {
    let mut acc = AccelCalibrator::<HOST_ACCEL_POSES>::new();
    let mut sigma = vec![];
    for s in log.ph.segments.iter().filter(|s| !s.is_rig_pose() || pan_tilt) {
        if acc.add_pose(s.accel.mean().map(|v| v as f32)).is_err() {
            break;
        }
        sigma.push(s.accel_sigma_of_mean(log.rows, log.ph.accel_noise_g));
    }
    let (cal, test) = match acc.len() {
        n if n >= pipeline::SIX_PARAM_POSES => pipeline::fit_accel_tested(&acc, &CONFIG.acceptance).map_err(stage("accelerometer"))?,
        _ => (AccelCal::IDENTITY, None),
    };
    Ok((cal, acc.sigma(&cal, &sigma), test, acc.len()))
}

/// What the fixed-size stores left out of the data-driven path, each with its count, why, and
/// what to do: poses beyond [`MAX_POSES`] (the index a pose has) or [`HOST_ACCEL_POSES`], moves
/// without room. `accel`: the accelerometer poses used, and whether the rig's were offered.
fn left_out(log: &Log, rotations: &HostRotations, poses: &Poses, main_setting: Option<i32>, accel: (usize, bool)) -> Vec<String> {
    let mut out = vec![];
    let offered = log.ph.segments.iter().filter(|s| !s.is_rig_pose() || accel.1).count();
    if offered > accel.0 {
        out.push(format!(
            "{} of {offered} accelerometer poses left out of its fit: at most {HOST_ACCEL_POSES} are kept; split the log",
            offered - accel.0
        ));
    }
    let hand = log.ph.segments.iter().filter(|s| !s.is_rig_pose()).count();
    if hand > rotations.poses().len() {
        out.push(format!(
            "{} of {hand} hand-held poses left out of the moves between poses: at most {MAX_POSES} are indexed; split the log",
            hand - rotations.poses().len()
        ));
    }
    let rig = log.rig().filter(|s| Some(s.tilt_setting()) == main_setting).count();
    if rig > poses.len() {
        out.push(format!(
            "{} of {rig} rig poses left out of the one-axis estimators: at most {MAX_POSES} are kept; split the log",
            rig - poses.len()
        ));
    }
    let no_room = rotations.rejected()[calib_core::estimators::rotation::Rejected::Full as usize];
    if no_room > 0 {
        out.push(format!("{no_room} moves between hand-held poses left out for want of room: split the log"));
    }
    out
}

/// One axis (the most populated tilt setting): its calibrated rig poses and the moves between
/// consecutive ones, for the one-axis estimators.
fn one_axis_rig(log: &Log, setting: Option<i32>, accel: &AccelCal) -> Result<(Poses, Moves), OfflineError> {
    let (mut poses, mut moves) = (Poses::new(), Moves::new());
    let mut prev: Option<(u8, &Segment)> = None;
    for s in &log.ph.segments {
        if !s.is_rig_pose() || Some(s.tilt_setting()) != setting {
            prev = None;
            continue;
        }
        if poses.len() == MAX_POSES {
            break;
        }
        let idx = poses.push(accel.apply(s.accel.mean().map(|v| v as f32))).map_err(stage("rig poses"))?;
        if let Some((from, p)) = prev {
            if moves.len() < MAX_MOVES {
                moves.push(from, idx, log.gamma(p, s)).map_err(stage("moves"))?;
            }
        }
        prev = Some((idx, s));
    }
    Ok((poses, moves))
}

/// Rotation constraints: every move between two consecutive hand-held poses (calibrated gravity
/// directions at both ends, the gyro integrated between them in chunks). A pose's gravity is its
/// mean over the pose, the mean attitude of a board that sways: each move runs from the mean
/// instant of one pose to that of the next (DESIGN §4.7, [`PoseTurn`]), as in the firmware. A
/// rejected move is counted, not an error.
///
/// A shaky pose's bias is the line between the rests around it ([`Log::new`]); as in the
/// firmware's hand-held step ([`Rotations::settle_bias`]) each rest settles the poses since the
/// one before, which gives their moves the Earth's rate each rest measured in its own attitude
/// ([`Attitude`]) and the warm-up a line in time misses: the poses' temperatures against the
/// line of their rests', times the zero rate's coefficient the rests show
/// ([`Rotations::follow_warmup`], [`TempFit`]; a log without temperatures keeps the line).
/// A still pose measures its own Earth's rate with its bias (removed to first order, the
/// module doc of [`calib_core::estimators::rotation`]) and takes no attitude: the Earth's
/// rate's `w` is then only estimated where a shaky pose needs it. (Its prior, `|w| = 1`, is
/// scaled with the rows' scatter like the rest of the solve: on the Ferraris session's still
/// poses, whose moves scatter 13× their noise, `w` took up that misfit and widened y's 1σ from
/// 0.0045 to 0.0052.)
fn rotations(log: &Log, accel: &AccelCal, range_dps: Option<f32>, limits: &RotationLimits) -> Box<HostRotations> {
    // 260 KB of chunks: on the heap.
    let mut rotations = Box::new(HostRotations::new());
    let mut prev: Option<(u8, &Segment)> = None;
    let rows = log.rows;
    let gyro = |r: &Row| sub(r.gyro_dps, log.bias.bias_dps);
    let (mut attitude, mut before, mut temp_fit) = (Attitude::default(), None, TempFit::new());
    for (s, &(bias, measured)) in log.ph.segments.iter().zip(&log.rests) {
        attitude.advance(&rows[..=s.last], log.bias.bias_dps, range_dps, limits.max_gap_s);
        let temp_c = log.temp_c(s);
        if measured {
            if let Some((b, b_temp_c)) = before {
                rotations.settle_bias(&b, &bias, attitude.get(), [b_temp_c, temp_c]);
            }
            before = Some((bias, temp_c));
            temp_fit.add(temp_c, &bias);
            attitude.start(s.last);
        }
        if s.is_rig_pose() {
            prev = None;
            continue;
        }
        let mut turn = PoseTurn::new();
        for i in s.first.max(1)..=s.last {
            turn.add(rows[i].t, rows[i].t.since(rows[i - 1].t), gyro(&rows[i]));
        }
        let (t_first, t_last) = (rows[s.first].t, rows[s.last].t);
        let rest = PoseRest {
            bias,
            predicted: !measured,
            rise_deg: turn.rise_deg(t_first, t_last),
            span_s: t_last.since(t_first) as f32,
            warm_c: if measured { f32::NAN } else { temp_c },
        };
        let sigma = s.accel.max_std_of_mean();
        let Ok(idx) = rotations.push_pose(s.accel.mean().map(|v| v as f32), sigma as f32, rest) else { break };
        if let Some(a) = attitude.get().filter(|_| !measured) {
            rotations.push_attitude(idx, a);
        }
        if let Some((from, p)) = prev {
            rotations.begin(from);
            for r in &rows[p.last..=s.last] {
                rotations.add(r.t, gyro(r), r.gyro_dps.iter().any(|v| clipped(*v, range_dps)));
            }
            let _ = rotations.end(idx, limits);
        }
        prev = Some((idx, s));
    }
    if let Some(tempco) = temp_fit.finish() {
        rotations.follow_warmup(&tempco.dps_per_c);
    }
    rotations.calibrate_poses(accel);
    rotations
}

/// The board's attitude (body to the first rest's frame) from the end of the log's first
/// measured rest, the gyro less the reference bias integrated with `K = I`, as the firmware
/// tracks it through its hand-held step for the Earth's rate ([`Rotations::push_attitude`]).
/// Lost for good at a clipped sample or a step beyond 0.25 rad, as there, or a hole in time
/// longer than a move may have ([`RotationLimits::max_gap_s`]: the board may have turned unseen).
#[derive(Default)]
struct Attitude {
    /// The attitude, once started and while known.
    at: Option<Matrix3<f64>>,
    /// Started (at the first rest).
    started: bool,
    /// The last row integrated.
    row: usize,
}

impl Attitude {
    /// Starts at the identity at row `row`, the end of the first rest (later rests: nothing).
    fn start(&mut self, row: usize) {
        if !self.started {
            (self.at, self.started, self.row) = (Some(Matrix3::identity()), true, row);
        }
    }

    /// Integrates `rows` after the last one integrated (°/s less `bias_dps`).
    fn advance(&mut self, rows: &[Row], bias_dps: Vec3, range_dps: Option<f32>, max_gap_s: f32) {
        for i in self.row + 1..rows.len() {
            let dt = rows[i].t.since(rows[i - 1].t);
            let phi = v64(sub(rows[i].gyro_dps, bias_dps)).map(|v| v.to_radians() * dt);
            let lost = rows[i].gyro_dps.iter().any(|v| clipped(*v, range_dps)) || phi.norm_squared() > 0.0625 || dt > max_gap_s as f64;
            self.at = self.at.filter(|_| !lost).map(|a| a * nalgebra::Rotation3::new(phi).into_inner());
        }
        self.row = self.row.max(rows.len().saturating_sub(1));
    }

    /// The attitude (`f32`, as the rotations keep it), when known.
    fn get(&self) -> Option<Matrix3<f32>> {
        self.at.map(|a| a.map(|v| v as f32))
    }
}

/// Pan/tilt: the full `K` (not yet validated) from the pan moves of every setting with poses at
/// ≥ 3 shaft angles (the plane through their tips fixes its axis), the tilt moves between
/// settings about the hinge, and the hand-held moves when asked.
fn pan_tilt_full(
    log: &Log,
    settings: &[(i32, usize)],
    accel: &AccelCal,
    rotations: Option<(&HostRotations, &RotationLimits)>,
) -> Result<FullCal, Error> {
    let pan_angles = |setting: i32| {
        let mut a: Vec<i32> =
            log.rig().filter(|s| s.tilt_setting() == setting).filter_map(|s| s.servo_deg).map(|d| d.round() as i32).collect();
        a.sort_unstable();
        a.dedup();
        a.len()
    };
    let hinge = settings.len().min(full::MAX_AXES - 1) as u8;
    let mut axes = full::Axes::new();
    let mut prev: Option<(&Segment, u8)> = None;
    for s in &log.ph.segments {
        if !s.is_rig_pose() {
            prev = None;
            continue;
        }
        let idx = axes.push_pose(accel.apply(s.accel.mean().map(|v| v as f32)))?;
        if let Some((p, from)) = prev {
            let d_pan = s.servo_deg.unwrap_or(0.0) - p.servo_deg.unwrap_or(0.0);
            let d_tilt = (s.tilt_setting() - p.tilt_setting()) as f32 / 2.0;
            let axis = settings.iter().position(|(t, _)| *t == s.tilt_setting()).unwrap_or(0).min(full::MAX_AXES - 2) as u8;
            if d_tilt == 0.0 && d_pan.abs() >= 1.0 && pan_angles(s.tilt_setting()) >= 3 {
                axes.push_move(axis, from, idx, d_pan, log.gamma(p, s))?;
            } else if d_pan.abs() < 0.5 && d_tilt.abs() >= 1.0 {
                axes.push_move(hinge, from, idx, d_tilt, log.gamma(p, s))?;
            }
        }
        prev = Some((s, idx));
    }
    axes.solve_with(&CONFIG.full, rotations)
}

/// The paper's constant-rate spin: its mean bias-corrected rate (°/s; the bias of the rest just
/// before it removed), the shaft rate (°/s: commanded when the servo column ramps linearly,
/// else the rate gravity turns about the rig's axis) and where that came from.
fn spin(log: &Log, poses: &Poses, accel: &AccelCal) -> Option<(Vec3, f32, &'static str)> {
    let cfg = &CONFIG;
    let rot = steady_spin(log.rows, log.bias.bias_dps, cfg.rest.window_s, &cfg.steady)?;
    let span = &log.rows[rot.rows.0..=rot.rows.1];
    let mut gravity = GravityTurn::new(poses.geometry(&cfg.geometry, false).ok().map(|g| g.u));
    for r in span {
        gravity.add(r.t, accel.apply(r.accel_g));
    }
    let (w, source) = pipeline::spin_rate(servo_rate(span, cfg.steady.min_dps), &gravity);
    if w <= 0.0 {
        return None;
    }
    let before = log.ph.segments.iter().rfind(|s| s.last < rot.rows.0).map_or([0.0; 3], |s| log.rest(s).residual_dps);
    Some((sub(sub(rot.gyro.mean().map(|v| v as f32), log.bias.bias_dps), before), w, source.name()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 90 °/s about z (plus the reference bias) for 1 s at 100 Hz from row 0.
    fn turning(bias_dps: Vec3) -> Vec<Row> {
        (0..=100)
            .map(|i| Row {
                t: Time::from_s(i as f64 * 0.01).unwrap(),
                accel_g: [0.0, 0.0, 1.0],
                gyro_dps: [bias_dps[0], bias_dps[1], 90.0 + bias_dps[2]],
                servo_deg: None,
                tilt_deg: None,
                mag_ut: None,
                temp_c: None,
            })
            .collect()
    }

    #[test]
    fn the_attitude_is_the_gyro_integrated_and_lost_at_a_clip_or_a_hole() {
        let bias = [0.3, -0.2, 0.1];
        let rows = turning(bias);
        let mut a = Attitude::default();
        a.advance(&rows[..=10], bias, None, 0.1);
        assert_eq!(a.get(), None, "not started before the first rest");
        a.start(10);
        a.advance(&rows, bias, None, 0.1);
        // 0.9 s at 90 °/s: 81° about z, body to the first rest's frame.
        let want = nalgebra::Rotation3::from_axis_angle(&nalgebra::Vector3::z_axis(), 81f64.to_radians()).into_inner();
        let got = a.get().expect("tracked").map(|v| v as f64);
        assert!((got - want).amax() < 1e-5, "{got} against {want}");
        // A clipped sample (a stated range of 90 °/s) or a hole of 0.2 s loses it for good.
        let clipped = |range: Option<f32>, rows: &[Row]| {
            let mut a = Attitude::default();
            a.start(0);
            a.advance(rows, bias, range, 0.1);
            a.get()
        };
        assert_eq!(clipped(Some(90.0), &rows), None);
        let mut holed = rows.clone();
        for r in &mut holed[50..] {
            r.t = r.t.plus_s(0.2);
        }
        assert_eq!(clipped(None, &holed), None);
        assert!(clipped(None, &rows).is_some());
    }
}
