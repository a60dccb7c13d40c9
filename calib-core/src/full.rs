//! The full 9-parameter gyro scale matrix `K` (scale and cross-axis, DESIGN §4.2) from moves
//! about several non-coplanar axes, e.g. a pan/tilt bracket: every tilt setting gives one pan
//! axis in the sensor frame, the tilt hinge is one more.
//!
//! Frames and units. Poses are calibrated accelerometer readings `f = M (a − o)` (g): `K` maps
//! the raw gyro (°/s) into that calibrated accelerometer frame, `ω = K (g − b)`. Gyro integrals
//! `Γ = ∫ (g − b) dt` are in ° (from [`crate::sweep::Integrator`]), turns in °.
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

use crate::accel::AccelCal;
use crate::axis::{turn_deg, unwrap_near, GeometryLimits, Plane, Poses};
use crate::gyro::SCALE_RANGE;
use crate::lsq::NormalEquations;
use crate::rotation::{RotationLimits, Rotations};
use crate::sweep::MAX_MOVES;
use crate::vec3::{tangent_basis, to_f64 as v64};
use crate::{Error, Mat3, Vec3};
use nalgebra::{Matrix3, Vector3};

/// Largest number of rotation axes (e.g. 7 tilt settings and the hinge).
pub const MAX_AXES: usize = 8;
/// Most Gauss–Newton iterations with rotation constraints (it converges in 3–5 from the rig's
/// or a diagonal K, in ≤ 6 from `K = I`); they bound the solve's time on the MCU.
pub const GAUSS_NEWTON_ITERATIONS: u8 = 10;
/// Gauss–Newton stops once no element of `K` moves by more than this (100× below the 1σ of a
/// good calibration).
pub const GAUSS_NEWTON_STEP: f64 = 1e-7;
/// Fewest non-coplanar axes that determine the full `K`.
pub const NEED_AXES: u8 = 3;

/// Fewest degrees of freedom (poses − 3) of a plane for the relative noise check.
const MIN_NOISE_DOF: u32 = 3;

/// Index of `K[row][col]` in `vec K` (column-major): `3 col + row`.
pub const fn vec_index(row: usize, col: usize) -> usize {
    3 * col + row
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
    pub gamma_deg: [f64; 3],
}

/// The static poses and the moves about several axes: the estimator's whole input (bounded).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Axes {
    poses: Poses,
    moves: [AxisMove; MAX_MOVES],
    n: usize,
    /// Bit `p` of `members[a]`: pose `p` lies on axis `a`'s plane.
    members: [u64; MAX_AXES],
}

impl Default for Axes {
    fn default() -> Self {
        Self::new()
    }
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

/// Plane fit of one axis' pose tips.
#[derive(Clone, Copy)]
struct Fit {
    u: Vector3<f64>,
    e: [Vector3<f64>; 2],
    /// `1 / √(n λ_k)` (1/g): axis tilt towards `e_k` per unit pose noise.
    tilt_per_g: [f64; 2],
    /// Least 1σ of the direction (rad): the axis' own tilt when it is taken along gravity.
    floor_rad: f64,
    direction_only: bool,
    tilt_deg: f64,
    plane_rms_g: f64,
    /// Sum of squared distances from the plane (g²) and its degrees of freedom.
    ss: f64,
    dof: u32,
    poses: u8,
}

impl Fit {
    /// 1σ (rad) of the axis direction towards `e_k` for a pose noise `sigma_a` (g).
    fn dir_sigma(&self, k: usize, sigma_a: f64) -> f64 {
        (sigma_a * self.tilt_per_g[k]).max(self.floor_rad)
    }
}

impl Axes {
    /// No poses, no moves.
    pub const fn new() -> Self {
        Self {
            poses: Poses::new(),
            moves: [AxisMove { axis: 0, from: 0, to: 0, commanded_deg: 0.0, gamma_deg: [0.0; 3] }; MAX_MOVES],
            n: 0,
            members: [0; MAX_AXES],
        }
    }

    /// Forgets everything.
    pub fn clear(&mut self) {
        *self = Self::new();
    }

    /// Adds a static pose (calibrated specific force `f = M (a − o)`, g); returns its index.
    pub fn push_pose(&mut self, accel_g: Vec3) -> Result<u8, Error> {
        self.poses.push(accel_g)
    }

    /// Replaces every pose `a` (raw, g) by the calibrated `f = M (a − o)`: for a plan whose
    /// accelerometer is fitted to these very poses once they are all taken.
    pub fn calibrate_poses(&mut self, accel: &AccelCal) {
        let m = Matrix3::from_fn(|r, c| accel.m[r][c] as f64);
        let o = v64(accel.offset_g);
        self.poses.map(|a| m * (a - o));
    }

    /// Records a move about `axis` from pose `from` to pose `to`; both poses join the axis' plane.
    pub fn push_move(&mut self, axis: u8, from: u8, to: u8, commanded_deg: f32, gamma_deg: [f64; 3]) -> Result<(), Error> {
        if !(gamma_deg.iter().all(|v| v.is_finite()) && commanded_deg.is_finite()) {
            return Err(Error::NonFinite);
        }
        if self.n == MAX_MOVES {
            return Err(Error::CapacityExceeded { max: MAX_MOVES as u8 });
        }
        self.add_pose_to_axis(axis, from)?;
        self.add_pose_to_axis(axis, to)?;
        self.moves[self.n] = AxisMove { axis, from, to, commanded_deg, gamma_deg };
        self.n += 1;
        Ok(())
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
        &self.moves[..self.n]
    }

    /// Plane fit of axis `a`, signed by its moves, and for a near-vertical axis the fallback along
    /// gravity. `σ_a` is not known yet: the caller chooses and checks the axis' direction 1σ.
    fn fit(&self, a: usize, limits: &FullLimits) -> Result<(Fit, Option<Fit>), Error> {
        let Plane { n, mean, vals, u, e, tilt_deg, radial } = self.poses.plane(self.members[a]);
        let nf = n as f64;
        let spread = libm::sqrt((vals[1] + vals[2]).max(0.0));
        let min_tilt = (limits.geometry.min_tilt_deg as f64).to_radians();
        // Every tip nearly at one place: a (near) vertical axis. Its circle, when the noise lets it
        // be fitted, gives the axis; else the mean gravity direction does (as in `Poses::geometry`).
        let vertical = spread < 0.3 * min_tilt;
        let sign = |mut f: Fit| {
            let s: f64 = self
                .moves()
                .iter()
                .filter(|m| m.axis as usize == a)
                .map(|m| m.commanded_deg as f64 * Vector3::from(m.gamma_deg).dot(&f.u))
                .sum();
            if s < 0.0 {
                f.u = -f.u;
            }
            f
        };
        let along_gravity = || {
            let u = mean.normalize();
            let r = 1.0 / libm::sqrt(nf);
            let e = tangent_basis(&u);
            // Along gravity the axis is off by up to its own tilt: that bounds the direction's 1σ.
            let floor_rad = libm::atan2(spread, mean.norm());
            let tilt_deg = floor_rad.to_degrees();
            let f = Fit {
                u,
                e,
                tilt_per_g: [r, r],
                floor_rad,
                direction_only: true,
                tilt_deg,
                plane_rms_g: 0.0,
                ss: 0.0,
                dof: 0,
                poses: n as u8,
            };
            sign(f)
        };
        if n < 3 {
            if vertical {
                return Ok((along_gravity(), None));
            }
            return Err(Error::AxisUndetermined { axis: a as u8, sigma_deg: f32::INFINITY, limit_deg: limits.max_axis_sigma_deg });
        }
        let plane_rms_g = libm::sqrt(vals[0].max(0.0));
        if !(plane_rms_g <= limits.geometry.max_plane_rms_g as f64) {
            return Err(Error::AxisNotFixed { plane_rms_g: plane_rms_g as f32, limit_g: limits.geometry.max_plane_rms_g });
        }
        let per = |l: f64| if l > 0.0 { 1.0 / libm::sqrt(nf * l) } else { f64::INFINITY };
        let plane = sign(Fit {
            u,
            e,
            tilt_per_g: [per(vals[1]), per(vals[2])],
            floor_rad: limits.accel_systematic_g as f64 / radial.max(1e-3),
            direction_only: vertical || tilt_deg < limits.geometry.min_tilt_deg as f64,
            tilt_deg,
            plane_rms_g,
            // A near-vertical axis' plane residual is not counted in the pose noise.
            ss: if vertical { 0.0 } else { nf * vals[0].max(0.0) },
            dof: if vertical { 0 } else { n as u32 - 3 },
            poses: n as u8,
        });
        Ok((plane, vertical.then(along_gravity)))
    }

    /// Solves for the full `K` over all moves. Errors (each names what to change): an axis whose
    /// poses are off their plane ([`Error::AxisNotFixed`]) or do not span one
    /// ([`Error::AxisUndetermined`]); fewer than 3 axes ([`Error::TooFewAxes`]) or coplanar ones
    /// ([`Error::AxesCoplanar`]); a null direction of the normal matrix, e.g. an upright bracket
    /// ([`Error::FullKUnobservable`]); an implausible diagonal ([`Error::ImplausibleScale`]);
    /// moves that disagree with one `K` ([`Error::MovesInconsistent`]).
    pub fn solve(&self, limits: &FullLimits) -> Result<FullCal, Error> {
        self.solve_with(limits, None)
    }

    /// [`Self::solve`] with the rotation constraints of `rotations` too (e.g. hand-held moves),
    /// by Gauss–Newton from the rig's own solution (or `K = I` when the rig alone does not
    /// determine `K`): one least squares over every row, each weighted by its noise. With fewer
    /// than 3 rig axes the rotations' axes must span three dimensions
    /// ([`Error::RotationAxesCoplanar`]); a rotation residual above its limit is
    /// [`Error::MovesInconsistent`].
    pub fn solve_with(&self, limits: &FullLimits, rotations: Option<(&Rotations, &RotationLimits)>) -> Result<FullCal, Error> {
        self.solve_from(limits, rotations, None)
    }

    /// [`Self::solve_with`] with Gauss–Newton started at `start` (vec `K`, column-major) instead:
    /// the rotations are re-composed at every iterate, so the result does not depend on it.
    pub fn solve_from(
        &self,
        limits: &FullLimits,
        rotations: Option<(&Rotations, &RotationLimits)>,
        start: Option<[f64; 9]>,
    ) -> Result<FullCal, Error> {
        let mut fits: [Option<Fit>; MAX_AXES] = [None; MAX_AXES];
        let mut fallbacks: [Option<Fit>; MAX_AXES] = [None; MAX_AXES];
        // Pose noise: the median over axes of each plane's residual noise `√(ss / (n − 3))`.
        let (mut noise, mut n_noise) = ([0.0f64; MAX_AXES], 0);
        for a in 0..MAX_AXES {
            if self.moves().iter().any(|m| m.axis as usize == a) {
                let (f, fallback) = self.fit(a, limits)?;
                fallbacks[a] = fallback;
                if f.dof > 0 {
                    noise[n_noise] = libm::sqrt(f.ss / f.dof as f64);
                    n_noise += 1;
                }
                fits[a] = Some(f);
            }
        }
        let noise = &mut noise[..n_noise];
        // Insertion sort (at most MAX_AXES values): the core sort would link 2 KiB into the firmware.
        for i in 1..n_noise {
            let mut j = i;
            while j > 0 && noise[j - 1].total_cmp(&noise[j]).is_gt() {
                noise.swap(j - 1, j);
                j -= 1;
            }
        }
        let floor = limits.min_accel_sigma_g as f64;
        let sigma_a = if n_noise > 0 { noise[(n_noise - 1) / 2].max(floor) } else { floor };
        // A plane much noisier than the others: the board slipped (or the shaft wobbles) on that axis.
        for f in fits.iter().flatten().filter(|f| f.dof >= MIN_NOISE_DOF) {
            let limit_g = limits.max_plane_noise_ratio as f64 * sigma_a;
            if libm::sqrt(f.ss / f.dof as f64) > limit_g {
                return Err(Error::AxisNotFixed { plane_rms_g: f.plane_rms_g as f32, limit_g: limit_g as f32 });
            }
        }
        let sigma_deg = |f: &Fit| f.dir_sigma(0, sigma_a).max(f.dir_sigma(1, sigma_a)).to_degrees();
        for a in 0..MAX_AXES {
            let Some(f) = fits[a] else { continue };
            if !(sigma_deg(&f) <= limits.max_axis_sigma_deg as f64) {
                match fallbacks[a] {
                    Some(g) => fits[a] = Some(g), // no circle to fit: the axis is along gravity
                    None => {
                        return Err(Error::AxisUndetermined {
                            axis: a as u8,
                            sigma_deg: sigma_deg(&f) as f32,
                            limit_deg: limits.max_axis_sigma_deg,
                        })
                    }
                }
            }
        }

        // The rows of every usable move; the same closure gives the residuals after the solve.
        let sq = |x: f64| x * x;
        let sg2 = sq(limits.gamma_sigma_deg as f64);
        // Rows as (direction v, target, variance): the two `e_k` rows first, then the `u` row of a full axis;
        // with `Γ` and the signed turn (the accelerometer's, or `Γ·u` for a direction-only axis).
        type Rows = ([(Vector3<f64>, f64, f64); 3], usize, Vector3<f64>, f64);
        let rows_of = |m: &AxisMove| -> Option<Rows> {
            let f = fits[m.axis as usize]?;
            let gamma = Vector3::from(m.gamma_deg);
            let (pa, pb) = (self.poses.get(m.from as usize), self.poses.get(m.to as usize));
            let e_row = |k: usize, turn: f64| (f.e[k], 0.0, sg2 + sq(turn.abs() * f.dir_sigma(k, sigma_a)));
            if f.direction_only {
                let turn = gamma.norm();
                (turn >= limits.min_move_deg as f64).then(|| ([e_row(0, turn), e_row(1, turn), (f.u, 0.0, 1.0)], 2, gamma, gamma.dot(&f.u)))
            } else {
                let dtheta = unwrap_near(turn_deg(&f.u, &pa, &pb), gamma.dot(&f.u));
                let r2 = |p: Vector3<f64>| (p - f.u * p.dot(&f.u)).norm_squared();
                let s2 = sg2 + sq(sigma_a.to_degrees()) * (1.0 / r2(pa) + 1.0 / r2(pb));
                (dtheta.abs() >= limits.min_move_deg as f64)
                    .then(|| ([e_row(0, dtheta), e_row(1, dtheta), (f.u, dtheta, s2)], 3, gamma, dtheta))
            }
        };
        let regressor = |v: &Vector3<f64>, gamma: &Vector3<f64>| -> [f64; 9] {
            core::array::from_fn(|i| gamma[i / 3] * v[i % 3]) // x[3c + r] = Γ_c v_r
        };
        let mut ne = NormalEquations::<9>::new();
        let (mut used, mut skipped) = (0u16, 0u16);
        let mut per_axis = [0u8; MAX_AXES];
        for m in self.moves() {
            match rows_of(m) {
                Some((rows, n, gamma, _)) => {
                    for (v, y, s2) in &rows[..n] {
                        ne.add_row(&regressor(v, &gamma), *y, 1.0 / s2)?;
                    }
                    used += 1;
                    per_axis[m.axis as usize] = per_axis[m.axis as usize].saturating_add(1);
                }
                None => skipped += 1,
            }
        }

        // Axes used, and how far from coplanar they are.
        let mut us = [Vector3::zeros(); MAX_AXES];
        let mut n_axes = 0;
        for a in 0..MAX_AXES {
            if let (Some(f), true) = (fits[a], per_axis[a] > 0) {
                us[n_axes] = f.u;
                n_axes += 1;
            }
        }
        let rotations = rotations.filter(|(r, _)| !r.moves().is_empty());
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
        let (mut non_coplanar, mut min_pair) = (0.0f64, f64::INFINITY);
        for i in 0..n_axes {
            for j in i + 1..n_axes {
                let c = us[i].cross(&us[j]);
                min_pair = min_pair.min(libm::atan2(c.norm(), us[i].dot(&us[j]).abs()));
                if c.norm() > 1e-9 {
                    for k in (0..n_axes).filter(|&k| k != i && k != j) {
                        // The angle of u_k from the plane ⟂ c (no asin linked into the firmware).
                        non_coplanar = non_coplanar.max(libm::atan2(us[k].dot(&c).abs(), us[k].cross(&c).norm()));
                    }
                }
            }
        }
        let non_coplanar_deg = non_coplanar.to_degrees();
        if !(non_coplanar_deg >= limits.min_axis_angle_deg as f64) && n_axes >= NEED_AXES as usize {
            return Err(Error::AxesCoplanar { angle_deg: non_coplanar_deg as f32, limit_deg: limits.min_axis_angle_deg });
        }

        // The rotation rows, linearised at each iterate; the rotations are re-composed there.
        let (ne, rotation) = match rotations {
            None => (ne, None),
            Some((r, rl)) => {
                let identity = core::array::from_fn(|i| if i % 4 == 0 { 1.0 } else { 0.0 });
                // The rig's own K when it determines one, else `K = I`.
                let mut k = match start {
                    Some(k) => k,
                    None if ne.condition() <= limits.max_condition as f64 => ne.solve().map_or(identity, |s| s.x),
                    None => identity,
                };
                let mut iterations = 0u8;
                let (total, rss) = loop {
                    let mut total = ne;
                    r.add_rows(&mut total, &k, rl)?;
                    iterations += 1;
                    let x = total.estimate()?;
                    let step = (0..9).map(|i| (x[i] - k[i]).abs()).fold(0.0, f64::max);
                    k = x;
                    if step < GAUSS_NEWTON_STEP || iterations == GAUSS_NEWTON_ITERATIONS {
                        // The rows at the solution, for its covariance and residual.
                        let mut at = ne;
                        let (_, rss) = r.add_rows(&mut at, &k, rl)?;
                        break (at, rss);
                    }
                };
                let rms_deg = libm::sqrt(rss / (2 * r.moves().len()) as f64).to_degrees();
                if !(rms_deg <= rl.max_residual_rms_deg as f64) {
                    return Err(Error::MovesInconsistent { residual_rms_deg: rms_deg as f32, limit_deg: rl.max_residual_rms_deg });
                }
                (total, Some((r.moves().len() as u16, rms_deg as f32, iterations)))
            }
        };

        // A null direction (e.g. the upright bracket: K → K + d (I − u_h u_hᵀ) K) is named, not solved.
        let condition = ne.condition();
        if !(condition <= limits.max_condition as f64) {
            return Err(Error::FullKUnobservable { condition: condition as f32, limit: limits.max_condition });
        }
        let sol = ne.solve()?;
        let kk = |r: usize, c: usize| sol.x[vec_index(r, c)];
        for i in 0..3 {
            let v = kk(i, i);
            if !(v > SCALE_RANGE.0 && v < SCALE_RANGE.1) {
                return Err(Error::ImplausibleScale { axis: i as u8, value: v as f32 });
            }
        }

        // Unweighted residuals (°) of every row used.
        let (mut rss_deg, mut nrows) = (0.0, 0u32);
        for (rows, n, gamma, _) in self.moves().iter().filter_map(rows_of) {
            for (v, y, _) in &rows[..n] {
                let x = regressor(v, &gamma);
                let r = (0..9).map(|i| x[i] * sol.x[i]).sum::<f64>() - y;
                rss_deg += r * r;
                nrows += 1;
            }
        }
        let residual_rms_deg = libm::sqrt(rss_deg / nrows.max(1) as f64);
        if nrows > 0 && !(residual_rms_deg <= limits.max_residual_rms_deg as f64) {
            return Err(Error::MovesInconsistent { residual_rms_deg: residual_rms_deg as f32, limit_deg: limits.max_residual_rms_deg });
        }

        // 1σ: `s² N⁻¹` treats rows as independent, but an axis' direction error is shared by all its
        // moves (it is absorbed into K, not seen in the residual): add it once per axis and
        // direction, `δk = N⁻¹ Σ_m w x (turn_m δu_k)` with `δu_k` of 1σ `σ_a / √(n λ_k)` (rad).
        let ninv = ne.inverse()?;
        let mut cov = sol.covariance;
        for (a, f) in fits.iter().enumerate() {
            let Some(f) = f else { continue };
            for k in 0..2 {
                let mut v = [0.0; 9];
                for (rows, _, gamma, turn) in self.moves().iter().filter(|m| m.axis as usize == a).filter_map(rows_of) {
                    let x = regressor(&rows[k].0, &gamma);
                    for i in 0..9 {
                        v[i] += turn * x[i] / rows[k].2;
                    }
                }
                let c: [f64; 9] = core::array::from_fn(|i| (0..9).map(|j| ninv[i][j] * v[j]).sum());
                let s2u = sq(f.dir_sigma(k, sigma_a));
                for i in 0..9 {
                    for j in 0..9 {
                        cov[i][j] += s2u * c[i] * c[j];
                    }
                }
            }
        }

        let mut axes = [FullAxis::default(); MAX_AXES];
        for (a, f) in fits.iter().enumerate() {
            if let Some(f) = f {
                axes[a] = FullAxis {
                    u: [f.u[0] as f32, f.u[1] as f32, f.u[2] as f32],
                    tilt_deg: f.tilt_deg as f32,
                    plane_rms_g: f.plane_rms_g as f32,
                    sigma_deg: sigma_deg(f) as f32,
                    poses: f.poses,
                    moves: per_axis[a],
                    direction_only: f.direction_only,
                };
            }
        }
        Ok(FullCal {
            k: core::array::from_fn(|r| core::array::from_fn(|c| kk(r, c) as f32)),
            sigma_k: core::array::from_fn(|r| core::array::from_fn(|c| libm::sqrt(cov[vec_index(r, c)][vec_index(r, c)].max(0.0)) as f32)),
            condition: condition as f32,
            non_coplanar_deg: non_coplanar_deg as f32,
            min_pair_angle_deg: min_pair.to_degrees() as f32,
            residual_rms_deg: residual_rms_deg as f32,
            noise_ratio: libm::sqrt(sol.rss / sol.dof.max(1) as f64) as f32,
            accel_sigma_g: sigma_a as f32,
            moves: used,
            moves_skipped: skipped,
            rows: ne.rows() as u16,
            n_axes: n_axes as u8,
            axes,
            rotation_moves: rotation.map_or(0, |r| r.0),
            rotation_residual_rms_deg: rotation.map_or(0.0, |r| r.1),
            iterations: rotation.map_or(0, |r| r.2),
        })
    }
}
