//! The magnetometer from a log's hand-held rows ([`calib_core::estimators::mag`]). A servo's motor magnet
//! adds tens to hundreds of µT near the board and moves with the shaft, so nothing recorded
//! on the rig enters the fit: not the rows with a servo commanded, and not a still segment with
//! the servo columns empty that sits next to them (the firmware's bias rest before the board
//! is picked up, the settling after it is put back) unless its field agrees with the poses
//! held in the hand. The hand-held stretch runs from its first pose to its last.

use super::mag_axes::{self, MagAxes};
use super::*;
use calib_core::estimators::mag::{MagCal, MagCalibrator, MagLimits, MagMove};
use calib_core::Mat3;

/// The magnetometer's calibration from a log, with the readings used and left out.
#[derive(Debug, Clone)]
pub struct MagOutcome {
    /// The calibration, or why there is none.
    pub cal: Result<MagCal, Error>,
    /// Readings in the hand-held stretch, offered to the fit.
    pub used: usize,
    /// Readings left out: on the rig (a servo commanded, or a still segment next to the rig
    /// whose field is not the hand-held poses').
    pub left_out: usize,
    /// The same readings' ellipsoid alone (`A` symmetric, µT offset): what the usual tools
    /// fit, for comparison.
    pub ellipsoid: Option<([[f32; 3]; 3], [f32; 3])>,
    /// The hand-held stretch whose readings were offered: first and last row (inclusive).
    pub stretch: Option<(usize, usize)>,
    /// The magnetometer's axes turned against the accelerometer's, as the data show (`None`:
    /// as logged). `A` and the offset apply to the readings as logged.
    pub axes: Option<MagAxes>,
}

impl MagOutcome {
    /// The other reading of turned axes ([`MagAxes::mirror`]): the field negated.
    pub fn mirror_axes(&mut self) {
        let Some(axes) = self.axes.as_mut() else { return };
        axes.mirror();
        let neg = |a: Mat3| a.map(|row| row.map(|v| -v));
        if let Ok(c) = self.cal.as_mut() {
            c.a = neg(c.a);
            c.dip_deg = -c.dip_deg;
        }
        self.ellipsoid = self.ellipsoid.map(|(a, o)| (neg(a), o));
    }

    /// The readings offered to the fit (µT): the hand-held rows of the stretch.
    pub fn readings<'a>(&self, rows: &'a [Row]) -> impl Iterator<Item = [f32; 3]> + 'a {
        let (a, b) = self.stretch.unwrap_or((1, 0));
        rows.get(a..=b).unwrap_or(&[]).iter().filter(|r| hand_held(r)).filter_map(|r| r.mag_ut)
    }
}

fn hand_held(r: &Row) -> bool {
    r.servo_deg.is_none() && r.tilt_deg.is_none()
}

/// `None` when the log has no magnetometer readings. `turns`: the hand-held moves and the full
/// `K` (the data-driven path), which refine the alignment as on the board
/// ([`MagCalibrator::refine`]): a rotation pose is a hand-held segment, in order.
/// When the magnetometer's axes are turned against the accelerometer's ([`mag_axes::find`]),
/// the readings are calibrated in the turned axes and `A` and the offset put back for the
/// readings as logged ([`MagOutcome::axes`]).
pub fn calibrate(rows: &[Row], ph: &Phases, accel: &AccelCal, turns: Option<(&HostRotations, Mat3)>) -> Option<MagOutcome> {
    let (_, interior, _) = hand_segments(rows, ph);
    let Some(axes) = mag_axes::find(rows, &interior, accel) else { return calibrate_as_logged(rows, ph, accel, turns) };
    let turned: Vec<Row> = rows.iter().map(|r| Row { mag_ut: r.mag_ut.map(|m| axes.apply(m)), ..*r }).collect();
    let mut out = calibrate_as_logged(&turned, ph, accel, turns)?;
    if let Ok(c) = out.cal.as_mut() {
        (c.a, c.offset_ut) = axes.logged(c.a, c.offset_ut);
    }
    out.ellipsoid = out.ellipsoid.map(|(a, o)| axes.logged(a, o));
    out.axes = Some(axes);
    Some(out)
}

/// The hand-held segments, and among them those away from the rig and those next to it (no
/// other segment between them and a rig row or, on a log with a rig, the log's start), which
/// are tested before they are used.
fn hand_segments<'a>(rows: &[Row], ph: &'a Phases) -> (Vec<&'a Segment>, Vec<&'a Segment>, Vec<&'a Segment>) {
    let rig = rows.iter().any(|r| !hand_held(r));
    let segs: Vec<&Segment> = ph.segments.iter().filter(|s| !s.is_rig_pose()).collect();
    let touches_rig = |s: &Segment, dir: isize| {
        let mut i = if dir < 0 { s.first as isize - 1 } else { s.last as isize + 1 };
        while i >= 0 && (i as usize) < rows.len() {
            let r = &rows[i as usize];
            if !hand_held(r) {
                return true;
            }
            if ph.segments.iter().any(|o| o.first <= i as usize && i as usize <= o.last) {
                return false;
            }
            i += dir;
        }
        rig && dir < 0
    };
    let (interior, boundary) = segs.iter().partition(|s| !(rig && (touches_rig(s, -1) || touches_rig(s, 1))));
    (segs, interior, boundary)
}

/// [`calibrate`] of the readings in the axes they have.
fn calibrate_as_logged(rows: &[Row], ph: &Phases, accel: &AccelCal, turns: Option<(&HostRotations, Mat3)>) -> Option<MagOutcome> {
    let readings = rows.iter().filter(|r| r.mag_ut.is_some()).count();
    if readings == 0 {
        return None;
    }
    let limits = MagLimits::default();
    let (segs, interior, boundary) = hand_segments(rows, ph);
    let mut chosen = interior.clone();
    if let Some((Ok(first), ..)) = fit(rows, &chosen, accel, &limits) {
        for s in &boundary {
            if let Some(m) = mean_field(rows, s) {
                if first.check_pose(0, accel.apply(s.accel.mean().map(|v| v as f32)), m, &limits).is_ok() {
                    chosen.push(s);
                }
            }
        }
        chosen.sort_by_key(|s| s.first);
    }
    let none = || (Err(MagCalibrator::new().solve(&limits).unwrap_err()), 0, None);
    let (mut cal, used, ellipsoid) = fit(rows, &chosen, accel, &limits).unwrap_or_else(none);
    if let (Ok(c), Some((rotations, k))) = (&cal, turns) {
        // The chosen poses that have readings, in the fit's order; each move's ends among them.
        let posed: Vec<usize> = chosen.iter().filter(|s| mean_field(rows, s).is_some()).map(|s| s.first).collect();
        let at = |pose: u8| segs.get(pose as usize).and_then(|s| posed.iter().position(|f| *f == s.first)).map(|i| i as u8);
        let moves: Vec<MagMove> = rotations
            .moves()
            .iter()
            .filter_map(|m| {
                let r = rotations.rotation(m, &k)?;
                Some(MagMove { from: at(m.from)?, to: at(m.to)?, r: core::array::from_fn(|i| core::array::from_fn(|j| r[(i, j)] as f32)) })
            })
            .collect();
        if let Some(Ok(refined)) = fit_calibrator(rows, &chosen, accel).map(|c2| c2.refine(c, &moves)) {
            cal = Ok(refined);
        }
    }
    // A disturbed pose is named by its place among all the log's hand-held poses.
    if let Err(Error::MagDisturbed { pose, .. }) = &mut cal {
        if let Some(k) = chosen.get(*pose as usize).and_then(|s| segs.iter().position(|o| o.first == s.first)) {
            *pose = k as u8;
        }
    }
    let stretch = chosen.first().zip(chosen.last()).map(|(a, b)| (a.first, b.last));
    Some(MagOutcome { cal, used, left_out: readings - used, ellipsoid, stretch, axes: None })
}

/// The fit of the poses `segs` (time order) and the readings from the first to the last, the
/// readings used and their ellipsoid alone; `None` without a pose.
type Fit = (Result<MagCal, Error>, usize, Option<([[f32; 3]; 3], [f32; 3])>);
fn fit(rows: &[Row], segs: &[&Segment], accel: &AccelCal, limits: &MagLimits) -> Option<Fit> {
    let (first, last) = (segs.first()?.first, segs.last()?.last);
    let used = rows[first..=last].iter().filter(|r| hand_held(r)).filter(|r| r.mag_ut.is_some()).count();
    let c = match calibrator(rows, segs, accel)? {
        Ok(c) => c,
        Err(e) => return Some((Err(e), used, None)),
    };
    let ellipsoid = c
        .fit_ellipsoid()
        .ok()
        .map(|(a, o, _)| (core::array::from_fn(|i| core::array::from_fn(|j| a[(i, j)] as f32)), [o[0] as f32, o[1] as f32, o[2] as f32]));
    Some((c.solve(limits), used, ellipsoid))
}

/// The readings from the first to the last of the poses `segs` and those poses, gathered.
pub(super) fn calibrator(rows: &[Row], segs: &[&Segment], accel: &AccelCal) -> Option<Result<MagCalibrator, Error>> {
    let (first, last) = (segs.first()?.first, segs.last()?.last);
    let mut c = MagCalibrator::new();
    for m in rows[first..=last].iter().filter(|r| hand_held(r)).filter_map(|r| r.mag_ut) {
        if let Err(e) = c.add_sample(m) {
            return Some(Err(e));
        }
    }
    for s in segs {
        if let Some(m) = mean_field(rows, s) {
            if let Err(e) = c.add_pose(accel.apply(s.accel.mean().map(|v| v as f32)), m) {
                return Some(Err(e));
            }
        }
    }
    Some(Ok(c))
}

/// [`calibrator`] when it gathers.
fn fit_calibrator(rows: &[Row], segs: &[&Segment], accel: &AccelCal) -> Option<MagCalibrator> {
    calibrator(rows, segs, accel)?.ok()
}

/// The mean raw field (µT) of a segment's readings.
pub(super) fn mean_field(rows: &[Row], s: &Segment) -> Option<[f32; 3]> {
    let mut w = Moments3::new();
    rows[s.first..=s.last].iter().filter_map(|r| r.mag_ut).for_each(|m| w.add(m));
    (w.count() > 0).then(|| w.mean().map(|v| v as f32))
}
