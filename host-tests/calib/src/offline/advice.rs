//! What to do about moves that disagree, from the log's own evidence: "hold each pose still"
//! only when the poses' gyro scatter says they were not; otherwise what disagrees, with its
//! numbers (the worst moves at the rejected `K`, the accelerometer model's misfit at the poses).

use super::*;
use calib_core::DISAGREE_RATIO;

/// A hand-held pose whose largest per-axis gyro scatter exceeds this many times the still
/// board's noise was held unsteadily (a braced hand's tremor stays near the floor; 1.2 is what
/// makes a pose too shaky to measure the bias, [`calib_core::estimators::bias::HAND_STILL_NOISE`]).
const SHAKY_POSE_NOISE: f64 = 3.0;
/// A move this many times the median misfit is named as the one that disagrees.
const OUTLIER_MOVE: f32 = 3.0;

impl Calibration {
    /// For a gyro rejected because its moves disagree ([`Error::TooUncertain`] beyond
    /// [`DISAGREE_RATIO`], [`Error::MovesInconsistent`]): the evidence and what to do.
    pub fn advice(&self) -> Option<String> {
        let error = match (&self.full, &self.gyro) {
            (Some(Err(e)), _) | (None, Err(OfflineError::Calib { error: e, .. })) => e,
            _ => return None,
        };
        let disagree = match error {
            Error::TooUncertain { noise_ratio, .. } => *noise_ratio > DISAGREE_RATIO,
            Error::MovesInconsistent { .. } => true,
            _ => false,
        };
        if !disagree {
            return None;
        }
        let mut said = vec![self.stillness()?];
        said.extend(self.worst_move());
        said.extend(self.accel_misfit());
        Some(said.join("; "))
    }

    /// The hand-held poses' gyro scatter against the still board's noise: "hold each pose
    /// still" when the worst is beyond [`SHAKY_POSE_NOISE`] times it, else that they were still.
    fn stillness(&self) -> Option<String> {
        let floor = self.bias.noise_dps.iter().fold(0.0f32, |m, v| m.max(*v)) as f64;
        let hand = self.phases.segments.iter().filter(|s| !s.is_rig_pose());
        let (k, worst) = hand.enumerate().map(|(k, s)| (k, s.gyro.max_std())).max_by(|a, b| a.1.total_cmp(&b.1))?;
        let ratio = worst / floor;
        Some(if ratio > SHAKY_POSE_NOISE {
            format!("hold each pose still: pose {k}'s gyro scatters by {worst:.3} deg/s, {ratio:.1} times the still board's {floor:.3}")
        } else {
            format!(
                "the poses were still (gyro scatter at most {worst:.3} deg/s, {ratio:.1} times the still board's {floor:.3}): not the hand"
            )
        })
    }

    /// The move that misfits most at the rejected `K`, when it stands out from the others.
    fn worst_move(&self) -> Option<String> {
        let (r, k) = (self.rotations.as_deref()?, self.full_tried?);
        let res = r.residuals_deg(&k, &CONFIG.rotation);
        let mut misfits: Vec<(usize, f32)> = res.iter().copied().take(r.moves().len()).enumerate().collect();
        misfits.sort_by(|a, b| a.1.total_cmp(&b.1));
        let median = misfits.get(misfits.len() / 2)?.1;
        let &(i, worst) = misfits.last()?;
        let m = &r.moves()[i];
        Some(if worst > OUTLIER_MOVE * median {
            format!(
                "the move from pose {} to {} misfits by {worst:.2} deg, {:.1} times the median {median:.2} deg: repeat it or leave it out",
                m.from,
                m.to,
                worst / median
            )
        } else {
            format!(
                "no move stands out (worst {worst:.2} deg, median {median:.2} deg over {}): the moves as a whole disagree",
                misfits.len()
            )
        })
    }

    /// The accelerometer model's misfit at the poses against the poses' own noise: gravity's
    /// direction at every pose carries it.
    fn accel_misfit(&self) -> Option<String> {
        let noise = self.phases.segments.iter().filter(|s| !s.is_rig_pose()).map(|s| s.accel.radial_std_of_mean()).fold(0.0, f64::max);
        let rms = self.accel.rms_after_g as f64;
        (self.accel.poses > 0 && rms > 3.0 * noise).then(|| {
            format!(
                "the accelerometer's {} model misses 1 g by {:.2} mg RMS at the poses, {:.0} times their noise: gravity's direction at each is uncertain by about {:.3} deg",
                self.accel.model.name(),
                rms * 1e3,
                rms / noise.max(1e-9),
                rms.to_degrees()
            )
        })
    }
}
