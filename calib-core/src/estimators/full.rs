//! The full 9-parameter gyro scale matrix `K` (scale and cross-axis, DESIGN §4.2) from moves
//! about several non-coplanar axes, e.g. a pan/tilt bracket: every tilt setting gives one pan
//! axis in the sensor frame, the tilt hinge is one more.
//!
//! Frames and units. Poses are calibrated accelerometer readings `f = M (a − o)` (g): `K` maps
//! the raw gyro (°/s) into that calibrated accelerometer frame, `ω = K (g − b)`. Gyro integrals
//! `Γ = ∫ (g − b) dt` are in ° (from [`crate::estimators::sweep::Integrator`]), turns in °.
//!
//! Equations. Every move `m` from pose `i` to pose `j` about axis `u` gives `K Γ_m = Δθ_m u`,
//! written in the orthonormal basis `(u, e₁, e₂)` of the axis' plane fit: `uᵀ K Γ = Δθ` and
//! `e_kᵀ K Γ = 0`. Each is linear in `vec K` (column-major, `k[3 c + r] = K[r][c]`, so
//! `vᵀ K Γ = (Γ ⊗ v)·k`, see [`vec_index`]) and goes into one [`NormalEquations<9>`]. An axis
//! within `min_tilt_deg` of vertical shows no turn to the accelerometer: its moves give only the
//! two `e_k` rows (`(I − u uᵀ) K Γ = 0`).
//!
//! Noise model (one row, 1σ in °): `σ_a` is the pose-mean noise per component (g), measured as
//! the median over axes of each plane's residual noise `√(Σ d² / (n − 3))`, `d` the distances of
//! the pose tips from the plane (floored by `min_accel_sigma_g`); `σ_Γ` (`gamma_sigma_deg`) the gyro integral's noise (white noise and
//! residual bias over one move).
//! - along `u`: `σ² = σ_Γ² + (180/π)² σ_a² (1/r_i² + 1/r_j²)`, `r` the distance of a pose tip from
//!   the axis (the turn is the angle between the two tips' projections);
//! - along `e_k`: `σ² = σ_Γ² + (|Δθ| σ_a / √(n λ_k))²`, the tilt of the fitted normal towards
//!   `e_k` (plane fit of `n` tips with in-plane scatter eigenvalue `λ_k`, g²) times the turn (for
//!   a direction-only axis `|Γ|`). A near-vertical axis keeps the normal of its small circle when
//!   that is known to `max_axis_sigma_deg`; else (tips at one place) `u` is the mean gravity
//!   direction with `λ_k = 1`.
//!
//! The 1σ of `K`: the covariance `s² N⁻¹` scaled by the weighted residual (`s² = rss / dof`),
//! plus, once per axis and tilt direction, the axis-direction error that all the axis' moves share
//! (absorbed into `K`, unseen in the residual). Correlations between moves that share a pose are
//! neglected.
//!
//! Axis signs: each axis is signed so that `Σ_m commanded_m (Γ_m·u) > 0` over its moves, i.e.
//! `u` is the right-hand axis of increasing commanded servo angle as the gyro sees it; when no
//! commanded turn is given (all 0) `u` points along the mean specific force (`f·u ≥ 0`). The
//! equations themselves do not depend on the sign (`Δθ` flips with `u`).

use crate::math::real::{self, Real};
mod fit;
mod gauss_newton;
mod rows;

use crate::estimators::accel::AccelCal;
use crate::estimators::axis::{GeometryLimits, Poses};
use crate::estimators::gyro::SCALE_RANGE;
use crate::estimators::rotation::{RotationLimits, Rotations};
use crate::estimators::sweep::MAX_MOVES;
use crate::math::lsq::{NormalEquations, Solution};
use crate::math::vec3::to_real as v64;
use crate::{Error, Mat3, Vec3};
pub use gauss_newton::{rotation_fit, RotationFit};
use nalgebra::{Matrix3, Vector3};
use rows::{Rig, RigEquations};

/// Largest number of rotation axes (e.g. 7 tilt settings and the hinge).
pub const MAX_AXES: usize = 8;
/// Most Gauss–Newton iterations with rotation constraints (it converges in 3–5 from the rig's
/// or a diagonal K, in ≤ 6 from `K = I`); they bound the solve's time on the MCU.
pub const GAUSS_NEWTON_ITERATIONS: u8 = 10;
/// Gauss–Newton stops once no element of `K` moves by more than this: 1000× below the 1σ of a
/// good calibration in `f64`; 100× in `f32` (the firmware), whose converged iterates still move
/// by their rounding (≈ 3e-7: with 1e-7 every solve ran all its iterations, 8 s longer).
pub const GAUSS_NEWTON_STEP: Real = if cfg!(feature = "single") { 1e-6 } else { 1e-7 };
/// Fewest non-coplanar axes that determine the full `K`.
pub const NEED_AXES: u8 = 3;

/// Fewest degrees of freedom (poses − 3) of a plane for the relative noise check.
const MIN_NOISE_DOF: u32 = 3;

/// Index of `K[row][col]` in `vec K` (column-major): `3 col + row`.
pub const fn vec_index(row: usize, col: usize) -> usize {
    3 * col + row
}

/// The end of a Gauss–Newton iteration cut into calls ([`Axes::iterate_rig`]): the next iterate
/// from `ne`, the rig's and the rotations' rows linearised at `k` (the Earth's rate
/// marginalised out), and the largest change of an element.
pub fn iterate_end(ne: &NormalEquations<9>, k: &[Real; 9]) -> Result<([Real; 9], Real), Error> {
    gauss_newton::next(ne, k)
}

/// Requirements and noise levels of the full-`K` estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FullLimits {
    /// Rig-geometry limits used here: `min_tilt_deg` (below it an axis gives direction-only rows)
    /// and `max_plane_rms_g` (pose tips off their axis plane; 3 mg by default, tighter than the
    /// one-axis estimators' 10 mg: a 1e-4 `K` needs axes fixed to a few mrad).
    pub geometry: GeometryLimits,
    /// Moves that turn less than this (°, accelerometer turn, or |Γ| for direction-only axes) are skipped.
    pub min_move_deg: f32,
    /// Smallest angle (°) of some axis from the plane of two others: below it the axes are coplanar.
    pub min_axis_angle_deg: f32,
    /// Largest 1σ (°) of a fitted axis direction: beyond it the axis' poses do not span a plane.
    pub max_axis_sigma_deg: f32,
    /// Largest condition number of the equilibrated 9×9 normal matrix (a near-null direction beyond).
    pub max_condition: f32,
    /// Largest RMS residual of the move equations (°): beyond it the moves disagree with one `K`.
    pub max_residual_rms_deg: f32,
    /// Largest ratio of one plane's residual noise to the median over the axes (planes with
    /// ≥ 3 degrees of freedom): beyond it that axis moved (a board that slipped between settings).
    pub max_plane_noise_ratio: f32,
    /// 1σ of a move's gyro integral per component (°): white noise and residual bias.
    pub gamma_sigma_deg: f32,
    /// Floor of the measured pose-mean noise per component (g).
    pub min_accel_sigma_g: f32,
    /// Systematic error of a calibrated pose (g) that averaging does not remove (what the
    /// accelerometer fit leaves): it tilts an axis fitted to a circle of radius `r` by up to
    /// `accel_systematic_g / r`, which floors the axis direction's 1σ (small circles: axes near
    /// vertical).
    pub accel_systematic_g: f32,
}

impl FullLimits {
    /// The defaults (also as `Default`).
    pub const DEFAULT: FullLimits = FullLimits {
        geometry: GeometryLimits { max_plane_rms_g: 0.003, ..GeometryLimits::DEFAULT },
        min_move_deg: 10.0,
        min_axis_angle_deg: 10.0,
        max_axis_sigma_deg: 1.0,
        max_condition: 1e5,
        max_residual_rms_deg: 0.15,
        max_plane_noise_ratio: 4.0,
        gamma_sigma_deg: 0.01,
        min_accel_sigma_g: 1e-5,
        accel_systematic_g: 1e-4,
    };
}

impl Default for FullLimits {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// One move between two recorded poses, about a caller-numbered axis.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AxisMove {
    /// Axis id (`< MAX_AXES`): e.g. the tilt-setting index for pan moves, one more id for the hinge.
    pub axis: u8,
    /// Index of the start pose.
    pub from: u8,
    /// Index of the end pose.
    pub to: u8,
    /// Commanded servo turn (°, end minus start; only its sign is used, to sign the axis; 0 if unknown).
    pub commanded_deg: f32,
    /// `Γ = ∫ (g − b) dt` over the move (°, raw gyro axes).
    pub gamma_deg: [Real; 3],
}

/// The static poses and the moves about several axes: the estimator's whole input (bounded, no heap).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Axes {
    poses: Poses,
    moves: heapless::Vec<AxisMove, MAX_MOVES>,
    /// Bit `p` of `members[a]`: pose `p` lies on axis `a`'s plane.
    members: [u64; MAX_AXES],
}

/// One axis as measured, in the result.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct FullAxis {
    /// Unit axis in the calibrated accelerometer frame (signed as in the module doc).
    pub u: Vec3,
    /// Angle of the axis from vertical (°).
    pub tilt_deg: f32,
    /// RMS distance of its pose tips from their plane (g).
    pub plane_rms_g: f32,
    /// 1σ of the axis direction (°, the worse of the two tilt directions).
    pub sigma_deg: f32,
    /// Poses on its plane.
    pub poses: u8,
    /// Moves used (0: axis id unused or all its moves skipped).
    pub moves: u8,
    /// Near vertical: only the direction of `K Γ` was used.
    pub direction_only: bool,
}

/// The full gyro calibration `ω = K (g − b)` with its quality report.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct FullCal {
    /// Scale matrix `K` (row-major, dimensionless): raw gyro → calibrated accelerometer frame.
    pub k: Mat3,
    /// 1σ of every element of `K` (row-major), from the covariance scaled by the residual.
    pub sigma_k: Mat3,
    /// Condition number of the equilibrated 9×9 normal matrix.
    pub condition: f32,
    /// Largest angle (°) of an axis from the plane of two others (90° for three orthogonal axes).
    pub non_coplanar_deg: f32,
    /// Smallest angle (°) between two axes used.
    pub min_pair_angle_deg: f32,
    /// RMS residual of the move equations (°, unweighted).
    pub residual_rms_deg: f32,
    /// Weighted residual `√(rss / dof)`: ≈ 1 when the noise model is right.
    pub noise_ratio: f32,
    /// Pose-mean noise used in the weights (g, per component).
    pub accel_sigma_g: f32,
    /// Moves used.
    pub moves: u16,
    /// Moves skipped (turn below `min_move_deg`).
    pub moves_skipped: u16,
    /// Least-squares rows.
    pub rows: u16,
    /// Axes used.
    pub n_axes: u8,
    /// Every axis id (index = the caller's axis id; `moves == 0` when unused).
    pub axes: [FullAxis; MAX_AXES],
    /// Rotation constraints used ([`Axes::solve_with`]; 0 without).
    pub rotation_moves: u16,
    /// RMS residual of the rotation rows (°, the gravity direction's misfit).
    pub rotation_residual_rms_deg: f32,
    /// Gauss–Newton iterations (0 without rotation constraints).
    pub iterations: u8,
}

/// What the rig's part of a solve gave ([`Axes::solve_rig`]), for its end ([`Axes::solve_end`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigPart {
    used: u16,
    skipped: u16,
    per_axis: [u8; MAX_AXES],
    n_axes: u8,
    non_coplanar_deg: Real,
    min_pair_rad: Real,
}

impl Axes {
    /// No poses, no moves.
    pub const fn new() -> Self {
        Self { poses: Poses::new(), moves: heapless::Vec::new(), members: [0; MAX_AXES] }
    }

    /// Forgets everything (in place).
    pub fn clear(&mut self) {
        self.poses.clear();
        self.moves.clear();
        self.members = [0; MAX_AXES];
    }

    /// Adds a static pose (calibrated specific force `f = M (a − o)`, g); returns its index.
    pub fn push_pose(&mut self, accel_g: Vec3) -> Result<u8, Error> {
        self.poses.push(accel_g)
    }

    /// Replaces every pose `a` (raw, g) by the calibrated `f = M (a − o)`: for a plan whose
    /// accelerometer is fitted to these very poses once they are all taken.
    pub fn calibrate_poses(&mut self, accel: &AccelCal) {
        let m = Matrix3::from_fn(|r, c| accel.m[r][c] as Real);
        let o = v64(accel.offset_g);
        self.poses.map(|a| m * (a - o));
    }

    /// Records a move about `axis` from pose `from` to pose `to`; both poses join the axis' plane.
    pub fn push_move(&mut self, axis: u8, from: u8, to: u8, commanded_deg: f32, gamma_deg: [Real; 3]) -> Result<(), Error> {
        if !(gamma_deg.iter().all(|v| v.is_finite()) && commanded_deg.is_finite()) {
            return Err(Error::NonFinite);
        }
        // Checked before the poses join the axis: a rejected move changes nothing.
        let full = Error::CapacityExceeded { max: MAX_MOVES as u8 };
        if self.moves.is_full() {
            return Err(full);
        }
        self.add_pose_to_axis(axis, from)?;
        self.add_pose_to_axis(axis, to)?;
        self.moves.push(AxisMove { axis, from, to, commanded_deg, gamma_deg }).map_err(|_| full)
    }

    /// Puts pose `pose` on axis `axis`' plane without a move (e.g. an extra pose at that setting).
    pub fn add_pose_to_axis(&mut self, axis: u8, pose: u8) -> Result<(), Error> {
        if axis as usize >= MAX_AXES {
            return Err(Error::CapacityExceeded { max: MAX_AXES as u8 });
        }
        if pose as usize >= self.poses.len() {
            return Err(Error::TooFewPoses { have: self.poses.len() as u8, need: pose.saturating_add(1) });
        }
        self.members[axis as usize] |= 1u64 << pose;
        Ok(())
    }

    /// The poses.
    pub fn poses(&self) -> &Poses {
        &self.poses
    }

    /// The moves.
    pub fn moves(&self) -> &[AxisMove] {
        &self.moves
    }

    /// Solves for the full `K` over all moves. Errors (each names what to change): an axis whose
    /// poses are off their plane ([`Error::AxisNotFixed`]) or do not span one
    /// ([`Error::AxisUndetermined`]); fewer than 3 axes ([`Error::TooFewAxes`]) or coplanar ones
    /// ([`Error::AxesCoplanar`]); a null direction of the normal matrix, e.g. an upright bracket
    /// ([`Error::FullKUnobservable`]); an implausible diagonal ([`Error::ImplausibleScale`]);
    /// moves that disagree with one `K` ([`Error::MovesInconsistent`]).
    pub fn solve(&self, limits: &FullLimits) -> Result<FullCal, Error> {
        self.solve_with(limits, crate::estimators::rotation::NONE)
    }

    /// [`Self::solve`] with the rotation constraints of `rotations` too (e.g. hand-held moves),
    /// by Gauss–Newton from the rig's own solution (or `K = I` when the rig alone does not
    /// determine `K`): one least squares over every row, each weighted by its noise. With fewer
    /// than 3 rig axes the rotations' axes must span three dimensions
    /// ([`Error::RotationAxesCoplanar`]); a rotation residual above its limit is
    /// [`Error::MovesInconsistent`].
    pub fn solve_with<const M: usize, const C: usize, const P: usize>(
        &self,
        limits: &FullLimits,
        rotations: Option<(&Rotations<M, C, P>, &RotationLimits)>,
    ) -> Result<FullCal, Error> {
        self.solve_from(limits, rotations, None)
    }

    /// [`Self::solve_with`] with Gauss–Newton started at `start` (vec `K`, column-major) instead:
    /// the rotations are re-composed at every iterate, so the result does not depend on it.
    pub fn solve_from<const M: usize, const C: usize, const P: usize>(
        &self,
        limits: &FullLimits,
        rotations: Option<(&Rotations<M, C, P>, &RotationLimits)>,
        start: Option<[Real; 9]>,
    ) -> Result<FullCal, Error> {
        self.solve_after(limits, rotations, start, 0, false)
    }

    /// One Gauss–Newton iteration of [`Self::solve_with`] cut into calls of bounded length (the
    /// firmware's solve; [`Self::solve_after`] then finishes it): this, the rig's rows (into
    /// `ne`) and where the iteration from `k` linearises (vec `K`; `None`: where the solve
    /// starts); then the rotations' rows a batch at a time into `ne`
    /// ([`Rotations::add_rows_batch`]); then [`iterate_end`]. The solve's checks are
    /// [`Self::solve_after`]'s: an error here is only that this step could not be taken.
    pub fn iterate_rig(&self, limits: &FullLimits, ne: &mut NormalEquations<9>, k: Option<[Real; 9]>) -> Result<[Real; 9], Error> {
        let rig = Rig { axes: self, fits: self.fit_axes(limits)?, limits };
        *ne = rig.equations()?.ne;
        Ok(gauss_newton::linearisation(ne, k, limits))
    }

    /// [`Self::solve_from`] after `done` iterations already taken by [`Self::iterate_rig`] up to
    /// `start`: at most the rest of [`GAUSS_NEWTON_ITERATIONS`] (none when `start` is the
    /// `last` iterate: converged, or the iterations ran out), and the result counts them all.
    /// In parts: [`Self::solve_rig`], the rotation rows at the solution, [`solve_k`],
    /// [`Self::solve_end`] (the firmware runs each in calls of its own).
    pub fn solve_after<const M: usize, const C: usize, const P: usize>(
        &self,
        limits: &FullLimits,
        rotations: Option<(&Rotations<M, C, P>, &RotationLimits)>,
        start: Option<[Real; 9]>,
        done: u8,
        last: bool,
    ) -> Result<FullCal, Error> {
        let mut ne = NormalEquations::new();
        let part = self.solve_rig(limits, rotations, &mut ne)?;
        let rotation = match rotations.filter(|(r, _)| !r.moves().is_empty()) {
            None => None,
            Some((r, rl)) => {
                let left = if last && start.is_some() { 0 } else { GAUSS_NEWTON_ITERATIONS.saturating_sub(done).max(1) };
                let (total, mut fit) = gauss_newton::with_rotations(&ne, r, rl, start, left, limits)?;
                fit.iterations += done;
                ne = total;
                Some(fit)
            }
        };
        let (sol, condition) = solve_k(&ne, limits)?;
        self.solve_end(limits, &part, &ne, &sol, condition, rotation)
    }

    /// The solve's first part: the rig's axes fitted, their rows (into `ne`) and the checks of
    /// the axes with the rotations'.
    pub fn solve_rig<const M: usize, const C: usize, const P: usize>(
        &self,
        limits: &FullLimits,
        rotations: Option<(&Rotations<M, C, P>, &RotationLimits)>,
        ne: &mut NormalEquations<9>,
    ) -> Result<RigPart, Error> {
        let rig = Rig { axes: self, fits: self.fit_axes(limits)?, limits };
        let RigEquations { ne: rows, used, skipped, per_axis } = rig.equations()?;
        let (us, n_axes) = rig.fits.used(&per_axis);
        let (non_coplanar_deg, min_pair_rad) = check_axes(&us[..n_axes], rotations.filter(|(r, _)| !r.moves().is_empty()), limits)?;
        *ne = rows;
        Ok(RigPart { used, skipped, per_axis, n_axes: n_axes as u8, non_coplanar_deg, min_pair_rad })
    }

    /// The solve's end: the result from `ne` (the rig's rows and the rotations' at the
    /// solution, `part` and `rotation` what they gave) and its solution `sol` ([`solve_k`]):
    /// the rig's residual and the 1σ of `K`.
    pub fn solve_end(
        &self,
        limits: &FullLimits,
        part: &RigPart,
        ne: &NormalEquations<9>,
        sol: &Solution<9>,
        condition: Real,
        rotation: Option<RotationFit>,
    ) -> Result<FullCal, Error> {
        let rig = Rig { axes: self, fits: self.fit_axes(limits)?, limits };
        let residual_rms_deg = rig.residual_rms_deg(&sol.x)?;
        Ok(FullCal {
            k: core::array::from_fn(|r| core::array::from_fn(|c| sol.x[vec_index(r, c)] as f32)),
            sigma_k: rig.sigma_k(ne, sol)?,
            condition: condition as f32,
            non_coplanar_deg: part.non_coplanar_deg as f32,
            min_pair_angle_deg: part.min_pair_rad.to_degrees() as f32,
            residual_rms_deg: residual_rms_deg as f32,
            noise_ratio: real::sqrt(sol.rss / sol.dof.max(1) as Real) as f32,
            accel_sigma_g: rig.fits.sigma_a as f32,
            moves: part.used,
            moves_skipped: part.skipped,
            rows: ne.rows() as u16,
            n_axes: part.n_axes,
            axes: rig.fits.reports(&part.per_axis),
            rotation_moves: rotation.map_or(0, |r| r.moves),
            rotation_residual_rms_deg: rotation.map_or(0.0, |r| r.residual_rms_deg),
            iterations: rotation.map_or(0, |r| r.iterations),
        })
    }
}

/// Checks that the used rig axes `us` (unit) and the rotations together turn about three
/// dimensions: ≥ [`NEED_AXES`] axes off one plane by `min_axis_angle_deg`, or rotation axes
/// spread by `min_axis_spread`. Returns the axes' non-coplanarity (°) and smallest pair angle (rad).
fn check_axes<const M: usize, const C: usize, const P: usize>(
    us: &[Vector3<Real>],
    rotations: Option<(&Rotations<M, C, P>, &RotationLimits)>,
    limits: &FullLimits,
) -> Result<(Real, Real), Error> {
    let n_axes = us.len();
    match rotations {
        Some((r, rl)) if n_axes < NEED_AXES as usize => {
            let spread = r.axis_spread();
            if !(spread >= rl.min_axis_spread) {
                return Err(Error::RotationAxesCoplanar { spread, limit: rl.min_axis_spread });
            }
        }
        None if n_axes < NEED_AXES as usize => return Err(Error::TooFewAxes { have: n_axes as u8, need: NEED_AXES }),
        _ => {}
    }
    let (non_coplanar, min_pair) = fit::spread_rad(us);
    let non_coplanar_deg = non_coplanar.to_degrees();
    if !(non_coplanar_deg >= limits.min_axis_angle_deg as Real) && n_axes >= NEED_AXES as usize {
        return Err(Error::AxesCoplanar { angle_deg: non_coplanar_deg as f32, limit_deg: limits.min_axis_angle_deg });
    }
    Ok((non_coplanar_deg, min_pair))
}

/// Solves the normal equations for vec `K` and checks it: a null direction (e.g. the upright
/// bracket: `K → K + d (I − u_h u_hᵀ) K`) is named, not solved, and the diagonal must be a
/// plausible scale. Returns the solution and the condition number.
/// The solution of `ne` (the rig's rows and the rotations' at the solution) and its condition:
/// a null direction ([`Error::FullKUnobservable`]) or an implausible diagonal
/// ([`Error::ImplausibleScale`]) refused.
pub fn solve_k(ne: &NormalEquations<9>, limits: &FullLimits) -> Result<(Solution<9>, Real), Error> {
    // The solve's own condition number (one computation): beyond lsq's limit too, it is this.
    let unobservable = |condition: Real| Error::FullKUnobservable { condition: condition as f32, limit: limits.max_condition };
    let sol = ne.solve().map_err(|e| match e {
        Error::IllConditioned { condition, .. } => unobservable(condition as Real),
        Error::Singular => unobservable(Real::INFINITY),
        e => e,
    })?;
    let condition = sol.condition;
    if !(condition <= limits.max_condition as Real) {
        return Err(unobservable(condition));
    }
    for i in 0..3 {
        let v = sol.x[vec_index(i, i)];
        if !(v > SCALE_RANGE.0 && v < SCALE_RANGE.1) {
            return Err(Error::ImplausibleScale { axis: i as u8, value: v as f32 });
        }
    }
    Ok((sol, condition))
}
