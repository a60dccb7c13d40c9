//! The rig rows and the rotation constraints ([`crate::estimators::rotation`]) in one least squares over vec
//! `K` (column-major), by Gauss–Newton: the rotation rows are re-linearised at every iterate.

use super::{FullLimits, GAUSS_NEWTON_STEP};
use crate::estimators::rotation::{RotationLimits, Rotations};
use crate::math::lsq::NormalEquations;
use crate::math::real::{self, Real};
use crate::Error;

/// What the rotation constraints gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RotationFit {
    /// Rotation moves used.
    pub moves: u16,
    /// RMS residual of the rotation rows at the solution (°).
    pub residual_rms_deg: f32,
    /// Gauss–Newton iterations.
    pub iterations: u8,
}

/// The rotation rows at the solution ([`Rotations::add_rows`]'s unweighted residual sum `rss`
/// over `n` rows, of `r`'s moves) after `iterations`: a residual above
/// `max_residual_rms_deg` is [`Error::MovesInconsistent`].
pub fn rotation_fit<const M: usize, const C: usize, const P: usize>(
    r: &Rotations<M, C, P>,
    rl: &RotationLimits,
    rss: Real,
    n: usize,
    iterations: u8,
) -> Result<RotationFit, Error> {
    let rms_deg = real::sqrt(rss / n.max(1) as Real).to_degrees();
    if !(rms_deg <= rl.max_residual_rms_deg as Real) {
        return Err(Error::MovesInconsistent { residual_rms_deg: rms_deg as f32, limit_deg: rl.max_residual_rms_deg });
    }
    Ok(RotationFit { moves: r.moves().len() as u16, residual_rms_deg: rms_deg as f32, iterations })
}

/// One Gauss–Newton iteration: the rig rows `rig` plus the rotation rows of `r` linearised at
/// `k` (vec `K`; `None`: [`linearisation`]). Returns the next iterate and the largest change of
/// an element.
pub(super) fn step<const M: usize, const C: usize, const P: usize>(
    rig: &NormalEquations<9>,
    r: &Rotations<M, C, P>,
    rl: &RotationLimits,
    k: Option<[Real; 9]>,
    limits: &FullLimits,
) -> Result<([Real; 9], Real), Error> {
    let k = linearisation(rig, k, limits);
    let mut total = *rig;
    r.add_rows(&mut total, &k, rl)?;
    next(&total, &k)
}

/// Where an iteration linearises: at `k`, or without one at the rig's own `K` when it
/// determines one (`rig`, its rows), else at `K = I`.
pub(super) fn linearisation(rig: &NormalEquations<9>, k: Option<[Real; 9]>, limits: &FullLimits) -> [Real; 9] {
    let identity = core::array::from_fn(|i| if i % 4 == 0 { 1.0 } else { 0.0 });
    match k {
        Some(k) => k,
        None if rig.condition() <= limits.max_condition as Real => rig.solve().map_or(identity, |s| s.x),
        None => identity,
    }
}

/// The next iterate from the rows linearised at `k` (`total`: the rig's and the rotations'),
/// and the largest change of an element.
pub(super) fn next(total: &NormalEquations<9>, k: &[Real; 9]) -> Result<([Real; 9], Real), Error> {
    let x = total.estimate()?;
    Ok((x, (0..9).map(|i| (x[i] - k[i]).abs()).fold(0.0, Real::max)))
}

/// The rig rows `rig` plus the rotation rows of `r` linearised at the solution, iterated from
/// `start` (as [`step`]) until no element moves by [`GAUSS_NEWTON_STEP`], at most
/// `max_iterations` times (none: `start` is the solution). A rotation residual above
/// `max_residual_rms_deg` is [`Error::MovesInconsistent`].
pub(super) fn with_rotations<const M: usize, const C: usize, const P: usize>(
    rig: &NormalEquations<9>,
    r: &Rotations<M, C, P>,
    rl: &RotationLimits,
    start: Option<[Real; 9]>,
    max_iterations: u8,
    limits: &FullLimits,
) -> Result<(NormalEquations<9>, RotationFit), Error> {
    let mut iterations = 0u8;
    let k = match start {
        Some(k) if max_iterations == 0 => k,
        mut k => loop {
            let (x, change) = step(rig, r, rl, k, limits)?;
            iterations += 1;
            k = Some(x);
            if change < GAUSS_NEWTON_STEP || iterations >= max_iterations {
                break x;
            }
        },
    };
    // The rows at the solution, for its covariance and residual.
    let mut total = *rig;
    let (_, rss, n) = r.add_rows(&mut total, &k, rl)?;
    Ok((total, rotation_fit(r, rl, rss, n, iterations)?))
}
