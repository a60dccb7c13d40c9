//! The rig's move equations `K Γ = Δθ u` as weighted rows linear in vec `K` (°), their residuals
//! and the 1σ of `K` with the axis-direction errors that an axis' moves share.

use super::fit::Fits;
use super::{vec_index, Axes, AxisMove, FullLimits, MAX_AXES};
use crate::estimators::axis::{turn_deg, unwrap_near};
use crate::math::lsq::{NormalEquations, Solution};
use crate::math::real::{self, sq, Real};
use crate::math::vec3::Length;
use crate::{Error, Mat3};
use nalgebra::Vector3;

/// One row `vᵀ K Γ = y` (°) and its variance (°²).
#[derive(Clone, Copy)]
struct Row {
    v: Vector3<Real>,
    y: Real,
    var: Real,
}

/// The rows of one usable move: the two `e_k` rows first, then the `u` row of a full axis.
struct MoveRows {
    rows: [Row; 3],
    n: usize,
    /// `Γ` (°, raw gyro axes).
    gamma: Vector3<Real>,
    /// Signed turn (°): the accelerometer's, or `Γ·u` for a direction-only axis.
    turn: Real,
}

impl MoveRows {
    fn used(&self) -> &[Row] {
        &self.rows[..self.n]
    }
}

/// `x` with `x·vec K = vᵀ K Γ` (column-major vec `K`): `x[3c + r] = Γ_c v_r`.
fn regressor(v: &Vector3<Real>, gamma: &Vector3<Real>) -> [Real; 9] {
    core::array::from_fn(|i| gamma[i / 3] * v[i % 3])
}

/// The rig's moves about their fitted axes: the source of every rig row.
pub(super) struct Rig<'a> {
    pub axes: &'a Axes,
    pub fits: Fits,
    pub limits: &'a FullLimits,
}

/// The rig's normal equations and the moves that went in.
pub(super) struct RigEquations {
    pub ne: NormalEquations<9>,
    pub used: u16,
    /// Moves that turned less than `min_move_deg`.
    pub skipped: u16,
    /// Moves used per axis id.
    pub per_axis: [u8; MAX_AXES],
}

impl Rig<'_> {
    /// The rows of move `m` with the noise model of the module doc of [`super`]; `None` when its
    /// axis is not fitted or it turns less than `min_move_deg`.
    fn rows(&self, m: &AxisMove) -> Option<MoveRows> {
        let (limits, sigma_a) = (self.limits, self.fits.sigma_a);
        let f = self.fits.axis[m.axis as usize]?;
        let sg2 = sq(limits.gamma_sigma_deg as Real);
        let gamma = Vector3::from(m.gamma_deg);
        let (pa, pb) = (self.axes.poses.get(m.from as usize), self.axes.poses.get(m.to as usize));
        let e_row = |k: usize, turn: Real| Row { v: f.e[k], y: 0.0, var: sg2 + sq(turn.abs() * f.dir_sigma(k, sigma_a)) };
        if f.direction_only {
            let turn = gamma.length();
            let rows = [e_row(0, turn), e_row(1, turn), Row { v: f.u, y: 0.0, var: 1.0 }];
            (turn >= limits.min_move_deg as Real).then(|| MoveRows { rows, n: 2, gamma, turn: gamma.dot(&f.u) })
        } else {
            let dtheta = unwrap_near(turn_deg(&f.u, &pa, &pb), gamma.dot(&f.u));
            let r2 = |p: Vector3<Real>| (p - f.u * p.dot(&f.u)).norm_squared();
            let var = sg2 + sq(sigma_a.to_degrees()) * (1.0 / r2(pa) + 1.0 / r2(pb));
            (dtheta.abs() >= limits.min_move_deg as Real).then(|| MoveRows {
                rows: [e_row(0, dtheta), e_row(1, dtheta), Row { v: f.u, y: dtheta, var }],
                n: 3,
                gamma,
                turn: dtheta,
            })
        }
    }

    /// Every usable move's rows, weighted by their inverse variance (1/°²).
    pub fn equations(&self) -> Result<RigEquations, Error> {
        let mut eq = RigEquations { ne: NormalEquations::new(), used: 0, skipped: 0, per_axis: [0; MAX_AXES] };
        for m in self.axes.moves() {
            match self.rows(m) {
                Some(mr) => {
                    for row in mr.used() {
                        eq.ne.add_row(&regressor(&row.v, &mr.gamma), row.y, 1.0 / row.var)?;
                    }
                    eq.used += 1;
                    eq.per_axis[m.axis as usize] = eq.per_axis[m.axis as usize].saturating_add(1);
                }
                None => eq.skipped += 1,
            }
        }
        Ok(eq)
    }

    /// RMS of the unweighted residuals (°) of every rig row at `k` (vec `K`), checked against
    /// `max_residual_rms_deg`.
    pub fn residual_rms_deg(&self, k: &[Real; 9]) -> Result<Real, Error> {
        let (mut rss_deg, mut nrows) = (0.0, 0u32);
        for mr in self.axes.moves().iter().filter_map(|m| self.rows(m)) {
            for row in mr.used() {
                let x = regressor(&row.v, &mr.gamma);
                let r = (0..9).map(|i| x[i] * k[i]).sum::<Real>() - row.y;
                rss_deg += r * r;
                nrows += 1;
            }
        }
        let rms = real::sqrt(rss_deg / nrows.max(1) as Real);
        let limit_deg = self.limits.max_residual_rms_deg;
        if nrows > 0 && !(rms <= limit_deg as Real) {
            return Err(Error::MovesInconsistent { residual_rms_deg: rms as f32, limit_deg });
        }
        Ok(rms)
    }

    /// 1σ of every element of `K` (row-major) from the solution `sol` of `ne`: `s² N⁻¹` treats rows
    /// as independent, but an axis' direction error is shared by all its moves (absorbed into `K`,
    /// unseen in the residual): it is added once per axis and tilt direction,
    /// `δk = N⁻¹ Σ_m w x (turn_m δu_k)` with `δu_k` of 1σ `σ_a / √(n λ_k)` (rad).
    pub fn sigma_k(&self, ne: &NormalEquations<9>, sol: &Solution<9>) -> Result<Mat3, Error> {
        let ninv = ne.inverse()?;
        let mut cov = sol.covariance;
        for (a, f) in self.fits.axis.iter().enumerate() {
            let Some(f) = f else { continue };
            for k in 0..2 {
                let mut v = [0.0; 9];
                for mr in self.axes.moves().iter().filter(|m| m.axis as usize == a).filter_map(|m| self.rows(m)) {
                    let row = mr.rows[k];
                    let x = regressor(&row.v, &mr.gamma);
                    for i in 0..9 {
                        v[i] += mr.turn * x[i] / row.var;
                    }
                }
                let c: [Real; 9] = core::array::from_fn(|i| (0..9).map(|j| ninv[i][j] * v[j]).sum());
                let s2u = sq(f.dir_sigma(k, self.fits.sigma_a));
                for i in 0..9 {
                    for j in 0..9 {
                        cov[i][j] += s2u * c[i] * c[j];
                    }
                }
            }
        }
        Ok(core::array::from_fn(|r| core::array::from_fn(|c| real::sqrt(cov[vec_index(r, c)][vec_index(r, c)].max(0.0)) as f32)))
    }
}
