//! Accelerometer calibration from static poses: `f = M (a − o)` with `|f| = 1 g`.
//!
//! Two models, both fed one pose mean at a time (raw g, sensor frame):
//! - 6 parameters (`M` diagonal): the linearised fit of Ye, Guo & Su (2017),
//!   `Σ α_i a_i² + Σ β_i a_i = 1`, then Gauss-Newton on `|f| − 1`;
//! - 9 parameters (`M` upper triangular, offsets): a quadric (ellipsoid) fit, Cholesky of its
//!   shape matrix, then Gauss-Newton.
//!
//! Poses must point the sensor in many directions (Ye: 6 axis poses or 12 icosahedron poses);
//! poses on one servo cone do not determine the model.

use crate::math::linalg::{cholesky, cholesky_inverse};
use crate::math::lsq::NormalEquations;
use crate::math::real::{self, Real};
use crate::{Error, Mat3, Vec3};

/// Largest number of accelerometer poses kept.
pub const MAX_ACCEL_POSES: usize = 32;
/// Gauss–Newton iterates of an accelerometer fit, at most.
pub const GAUSS_NEWTON_STEPS: usize = 12;

/// Which accelerometer model a calibration uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[cfg_attr(feature = "serde", serde(rename_all = "snake_case"))]
pub enum AccelModel {
    /// Identity: no calibration applied.
    None,
    /// Diagonal gains and offsets.
    SixParam,
    /// Upper-triangular gain matrix (scale and non-orthogonality) and offsets.
    NineParam,
}

impl AccelModel {
    /// Lower-case name, as in logs and JSON.
    pub fn name(self) -> &'static str {
        match self {
            AccelModel::None => "none",
            AccelModel::SixParam => "six_param",
            AccelModel::NineParam => "nine_param",
        }
    }
}

/// An accelerometer calibration `f = M (a − o)` (g, sensor frame) with its fit quality.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct AccelCal {
    /// Gain matrix `M` (row-major).
    pub m: Mat3,
    /// Offset `o` (g).
    pub offset_g: Vec3,
    /// The model fitted.
    pub model: AccelModel,
    /// RMS of `|a| − 1` over the poses before calibration (g).
    pub rms_before_g: f32,
    /// RMS of `|f| − 1` over the poses after calibration (g).
    pub rms_after_g: f32,
    /// Condition number of the last Gauss-Newton normal matrix.
    pub condition: f32,
    /// Poses used.
    pub poses: u8,
}

impl AccelCal {
    /// No correction.
    pub const IDENTITY: AccelCal = AccelCal {
        m: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        offset_g: [0.0; 3],
        model: AccelModel::None,
        rms_before_g: 0.0,
        rms_after_g: 0.0,
        condition: 1.0,
        poses: 0,
    };

    /// Calibrated specific force `M (a − o)` (g) from a raw reading (g).
    pub fn apply(&self, a: Vec3) -> Vec3 {
        let d = [a[0] - self.offset_g[0], a[1] - self.offset_g[1], a[2] - self.offset_g[2]];
        let mut f = [0.0; 3];
        for (fi, row) in f.iter_mut().zip(self.m.iter()) {
            *fi = row[0] * d[0] + row[1] * d[1] + row[2] * d[2];
        }
        f
    }
}

/// The 1σ of an [`AccelCal`]'s offsets and diagonal gains ([`AccelCalibrator::sigma`]).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct AccelSigma {
    /// 1σ of the offsets (g).
    pub offset_g: Vec3,
    /// 1σ of the diagonal gains.
    pub gain: Vec3,
    /// `χ²` of the fit's residuals against the poses' own 1σ.
    pub chi2: f32,
    /// Its degrees of freedom: poses less the model's parameters.
    pub dof: u8,
    /// The factor the variances were scaled by: `(χ² − (χ²₉₅ − ν))/ν` where `χ²` lies beyond
    /// its 95 % point `χ²₉₅` (the residuals show an error the poses' 1σ do not), else 1.
    pub scale: f32,
}

/// Static accelerometer poses (mean readings, g), with the linear fits accumulated as they come.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct AccelCalibrator<const N: usize = MAX_ACCEL_POSES> {
    poses: heapless::Vec<[Real; 3], N>,
    lin6: NormalEquations<6>,
    lin9: NormalEquations<9>,
}

/// Parameters of a Gauss-Newton iteration: offsets then the gain entries it fits.
/// The fit's parameters: `[o; kx, ky, kz]` (6) or `[o; m00, m01, m02, m11, m12, m22]` (9).
pub type Params = [Real; 9];

impl<const N: usize> AccelCalibrator<N> {
    /// No poses.
    pub const fn new() -> Self {
        Self { poses: heapless::Vec::new(), lin6: NormalEquations::new(), lin9: NormalEquations::new() }
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// True when no pose was added.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Forgets every pose.
    pub fn clear(&mut self) {
        self.poses.clear();
        self.lin6 = NormalEquations::new();
        self.lin9 = NormalEquations::new();
    }

    /// Pose `i` (raw g); the last pose for an out-of-range index, zero when empty.
    pub fn pose(&self, i: usize) -> nalgebra::Vector3<Real> {
        let a = self.poses.get(i).or(self.poses.last()).copied().unwrap_or_default();
        nalgebra::Vector3::new(a[0], a[1], a[2])
    }

    /// Adds the mean raw reading (g) of one static pose.
    pub fn add_pose(&mut self, a: Vec3) -> Result<(), Error> {
        // Checked before the rows go in: a rejected pose leaves the fits as they were.
        let full = Error::CapacityExceeded { max: N.min(u8::MAX as usize) as u8 };
        if self.poses.is_full() {
            return Err(full);
        }
        let [x, y, z] = [a[0] as Real, a[1] as Real, a[2] as Real];
        self.lin6.add_row(&[x * x, y * y, z * z, x, y, z], 1.0, 1.0)?;
        self.lin9.add_row(&[x * x, y * y, z * z, 2.0 * x * y, 2.0 * x * z, 2.0 * y * z, x, y, z], 1.0, 1.0)?;
        self.poses.push([x, y, z]).map_err(|_| full)
    }

    /// Fits the 6-parameter model (needs ≥ 6 well-spread poses).
    pub fn solve6(&self) -> Result<AccelCal, Error> {
        self.need(6)?;
        let s = self.lin6.estimate()?;
        let mut p: Params = [0.0; 9];
        let mut sum = 1.0;
        for i in 0..3 {
            if !(s[i] > 0.0) {
                return Err(Error::AccelFitFailed);
            }
            p[i] = -s[3 + i] / (2.0 * s[i]);
            sum += s[i] * p[i] * p[i];
        }
        let d = 1.0 / sum;
        for i in 0..3 {
            p[3 + i] = real::sqrt(s[i] * d);
        }
        self.refine::<6>(p, AccelModel::SixParam)
    }

    /// Fits the 9-parameter model (needs ≥ 9 well-spread poses).
    pub fn solve9(&self) -> Result<AccelCal, Error> {
        let mut ne = NormalEquations::new();
        let p = self.solve9_params(&mut ne)?;
        self.calibration9(&p, &ne)
    }

    /// [`Self::solve9`]'s first part (for a caller that runs each in a call of its own): the
    /// parameters, by Gauss–Newton from the quadric's, the last iteration's equations in `ne`.
    pub fn solve9_params(&self, ne: &mut NormalEquations<9>) -> Result<Params, Error> {
        let p = self.start9()?;
        self.iterate::<9>(p, ne)
    }

    /// [`Self::solve9_params`]'s start: the quadric's linear fit and from it the triangular
    /// model's parameters, for [`Self::gauss_newton_step`] to refine.
    pub fn start9(&self) -> Result<Params, Error> {
        self.need(9)?;
        // The quadric's parameters alone: the last step's equations are checked in full.
        let q = self.lin9.estimate()?;
        let shape = [[q[0], q[3], q[4]], [q[3], q[1], q[5]], [q[4], q[5], q[2]]];
        let l = cholesky(&shape, 1e-12).ok_or(Error::AccelFitFailed)?;
        let inv = cholesky_inverse(&l);
        let mut o = [0.0; 3];
        for (i, oi) in o.iter_mut().enumerate() {
            *oi = -0.5 * (0..3).map(|j| inv[i][j] * q[6 + j]).sum::<Real>();
        }
        let s = 1.0 + (0..3).map(|i| (0..3).map(|j| o[i] * shape[i][j] * o[j]).sum::<Real>()).sum::<Real>();
        if !(s > 0.0) {
            return Err(Error::AccelFitFailed);
        }
        // shape / s = L Lᵀ = Mᵀ M with M = Lᵀ / √s upper triangular.
        let r = 1.0 / real::sqrt(s);
        Ok([o[0], o[1], o[2], l[0][0] * r, l[1][0] * r, l[2][0] * r, l[1][1] * r, l[2][1] * r, l[2][2] * r])
    }

    /// [`Self::solve9`]'s second part: the calibration at `p` from the last iteration's
    /// equations `ne` ([`Self::solve9_params`]), their condition checked.
    pub fn calibration9(&self, p: &Params, ne: &NormalEquations<9>) -> Result<AccelCal, Error> {
        self.calibration(p, AccelModel::NineParam, ne.check()?)
    }

    /// [`Self::calibration9`] with the equations' condition number already computed
    /// ([`NormalEquations::condition`]: a caller that runs the two in calls of their own).
    pub fn calibration9_given(&self, p: &Params, ne: &NormalEquations<9>, condition: Real) -> Result<AccelCal, Error> {
        self.calibration(p, AccelModel::NineParam, ne.check_given(condition)?)
    }

    fn need(&self, n: usize) -> Result<(), Error> {
        if self.poses.len() < n {
            return Err(Error::TooFewPoses { have: self.poses.len() as u8, need: n as u8 });
        }
        Ok(())
    }

    /// Gauss-Newton on `|M (a − o)| − 1` over the poses; `P` = 6 (diagonal) or 9 (triangular).
    fn refine<const P: usize>(&self, p: Params, model: AccelModel) -> Result<AccelCal, Error> {
        let mut ne = NormalEquations::<P>::new();
        let p = self.iterate(p, &mut ne)?;
        self.calibration(&p, model, ne.check()?)
    }

    /// [`Self::refine`]'s iterates, by their estimate alone, from `p`; the last one's equations
    /// (checked in full by the caller: their condition number) left in `ne`.
    fn iterate<const P: usize>(&self, mut p: Params, ne: &mut NormalEquations<P>) -> Result<Params, Error> {
        for _ in 0..GAUSS_NEWTON_STEPS {
            if self.gauss_newton_step(&mut p, ne)? {
                break;
            }
        }
        Ok(p)
    }

    /// One Gauss–Newton iterate of [`Self::iterate`]: the equations at `p` (left in `ne`) and `p`
    /// moved by their estimate; true once that step is below 1e-12.
    pub fn gauss_newton_step<const P: usize>(&self, p: &mut Params, ne: &mut NormalEquations<P>) -> Result<bool, Error> {
        *ne = NormalEquations::<P>::new();
        for a in &self.poses {
            let (r, jac) = residual(p, a, P == 6);
            ne.add_row(&core::array::from_fn(|i| jac[i]), -r, 1.0)?;
        }
        let x = ne.estimate()?;
        let mut step = 0.0 as Real;
        for i in 0..P {
            p[i] += x[i];
            step = step.max(x[i].abs());
        }
        Ok(step < 1e-12)
    }

    /// The 1σ of `cal`, fitted to these poses, from each pose's own 1σ `pose_sigma_g` (g, the
    /// error of its mean along gravity, in the order the poses came) propagated through the
    /// fit: `var = Σ s_i² t_i t_iᵀ` with `t_i = (JᵀJ)⁻¹ J_i` at the solution. Where `χ²`, the
    /// least `Σ (r_i / s_i)²` near the solution, lies beyond its 95 % point `χ²₉₅`, the
    /// residuals show an error the poses' own 1σ do not (a model that does not fit, a disturbed
    /// pose): scaled by `1 + (χ² − χ²₉₅)/ν`, the residuals' excess over what chance gives 19
    /// times in 20. It is 1 at that point and `χ²/ν` less a constant beyond it: `χ²/ν` alone
    /// jumps from 1 to 2.6 there (3 degrees of freedom), and with the poses' 1σ right it put
    /// rotation-bench's accelerometer gains within 1σ in up to 82 % of rigs (without any
    /// scaling 72 %; with this 78 %, 40 rigs). The residual alone is not the scale: with a few
    /// poses more than unknowns (12 poses, 9 parameters) its variance has 3 degrees of freedom
    /// and is often small by chance. `None` for the identity, a count that differs from the
    /// poses' or a 1σ not above zero.
    pub fn sigma(&self, cal: &AccelCal, pose_sigma_g: &[Real]) -> Option<AccelSigma> {
        let o = cal.offset_g.map(|v| v as Real);
        let m = cal.m.map(|r| r.map(|v| v as Real));
        match cal.model {
            AccelModel::SixParam => self.propagate::<6>(&[o[0], o[1], o[2], m[0][0], m[1][1], m[2][2], 0.0, 0.0, 0.0], pose_sigma_g),
            AccelModel::NineParam => {
                self.propagate::<9>(&[o[0], o[1], o[2], m[0][0], m[0][1], m[0][2], m[1][1], m[1][2], m[2][2]], pose_sigma_g)
            }
            AccelModel::None => None,
        }
    }

    /// [`Self::sigma`] for the `P` parameters `p`.
    fn propagate<const P: usize>(&self, p: &Params, pose_sigma_g: &[Real]) -> Option<AccelSigma> {
        if pose_sigma_g.len() != self.poses.len() || !pose_sigma_g.iter().all(|s| *s > 0.0 && s.is_finite()) {
            return None;
        }
        // The fit's own (unweighted) normal matrix, and the weighted equations of its residuals:
        // their least sum, one linearised step from the solution, is the χ² of the poses
        // weighted by their own 1σ (the unweighted residuals are not: a noisy pose pulls the
        // fit away from the still ones).
        let (mut ne, mut weighted) = (NormalEquations::<P>::new(), NormalEquations::<P>::new());
        for (a, s) in self.poses.iter().zip(pose_sigma_g) {
            let (r, jac) = residual(p, a, P == 6);
            let jac = core::array::from_fn(|i| jac[i]);
            ne.add_row(&jac, 0.0, 1.0).ok()?;
            weighted.add_row(&jac, -r, 1.0 / (s * s)).ok()?;
        }
        let inv = ne.inverse().ok()?;
        let chi2 = weighted.solve().ok()?.rss.max(0.0);
        let mut var = [0.0; P];
        for (a, s) in self.poses.iter().zip(pose_sigma_g) {
            let (_, jac) = residual(p, a, P == 6);
            let t: [Real; P] = core::array::from_fn(|k| (0..P).map(|j| inv[k][j] * jac[j]).sum());
            for (v, tk) in var.iter_mut().zip(t) {
                *v += s * s * tk * tk;
            }
        }
        let dof = self.poses.len().saturating_sub(P);
        let nu = dof.max(1) as Real;
        let chi2_95 = crate::math::lsq::chi2_95(nu);
        let scale = if dof > 0 && chi2 > chi2_95 { (chi2 - (chi2_95 - nu)) / nu } else { 1.0 };
        let sigma = |i: [usize; 3]| i.map(|i| real::sqrt(var[i] * scale) as f32);
        Some(AccelSigma {
            offset_g: sigma([0, 1, 2]),
            gain: sigma(if P == 6 { [3, 4, 5] } else { [3, 6, 8] }),
            chi2: chi2 as f32,
            dof: dof.min(u8::MAX as usize) as u8,
            scale: scale as f32,
        })
    }

    /// The calibration of the refined parameters `p`; the same code for both models.
    fn calibration(&self, p: &Params, model: AccelModel, condition: Real) -> Result<AccelCal, Error> {
        let six = model == AccelModel::SixParam;
        let m = gain_matrix(p, six);
        if !(0..3).all(|i| m[i][i] > 0.0) || !p.iter().all(|v| v.is_finite()) {
            return Err(Error::AccelFitFailed);
        }
        let rms = |f: &dyn Fn(&[Real; 3]) -> Real| {
            real::sqrt(self.poses.iter().map(|a| f(a) * f(a)).sum::<Real>() / self.poses.len() as Real) as f32
        };
        Ok(AccelCal {
            m: m.map(|row| row.map(|v| v as f32)),
            offset_g: [p[0] as f32, p[1] as f32, p[2] as f32],
            model,
            rms_before_g: rms(&|a| norm(a) - 1.0),
            rms_after_g: rms(&|a| residual(p, a, six).0),
            condition: condition as f32,
            poses: self.poses.len() as u8,
        })
    }
}

fn norm(v: &[Real; 3]) -> Real {
    real::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
}

/// Gain matrix from the parameters: `[o; kx, ky, kz]` (`six`) or `[o; m00, m01, m02, m11, m12, m22]`.
fn gain_matrix(p: &Params, six: bool) -> [[Real; 3]; 3] {
    if six {
        [[p[3], 0.0, 0.0], [0.0, p[4], 0.0], [0.0, 0.0, p[5]]]
    } else {
        [[p[3], p[4], p[5]], [0.0, p[6], p[7]], [0.0, 0.0, p[8]]]
    }
}

/// Residual `|M (a − o)| − 1` (g) and its gradient with respect to the parameters (the first 6
/// when `six`). One copy for both models: not inlined.
#[inline(never)]
fn residual(p: &Params, a: &[Real; 3], six: bool) -> (Real, Params) {
    let m = gain_matrix(p, six);
    let d = [a[0] - p[0], a[1] - p[1], a[2] - p[2]];
    let f: [Real; 3] = core::array::from_fn(|i| (0..3).map(|j| m[i][j] * d[j]).sum());
    let n = norm(&f).max(1e-12);
    let mut jac = [0.0; 9];
    for k in 0..3 {
        jac[k] = -(0..3).map(|i| m[i][k] * f[i]).sum::<Real>() / n;
    }
    if six {
        for i in 0..3 {
            jac[3 + i] = f[i] * d[i] / n;
        }
    } else {
        let mut idx = 3;
        for i in 0..3 {
            for j in i..3 {
                jac[idx] = f[i] * d[j] / n;
                idx += 1;
            }
        }
    }
    (n - 1.0, jac)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Raw reading of a true unit specific force `f` for `a = M⁻¹ f + o` (M triangular).
    fn raw(m: &[[Real; 3]; 3], o: &[Real; 3], f: [Real; 3]) -> Vec3 {
        // Back-substitution of the upper-triangular M.
        let mut d = [0.0; 3];
        for i in (0..3).rev() {
            let s: Real = (i + 1..3).map(|j| m[i][j] * d[j]).sum();
            d[i] = (f[i] - s) / m[i][i];
        }
        [(d[0] + o[0]) as f32, (d[1] + o[1]) as f32, (d[2] + o[2]) as f32]
    }

    fn icosahedron() -> [[Real; 3]; 12] {
        let t = (1.0 + libm::sqrt(5.0)) / 2.0;
        let n = libm::sqrt(1.0 + t * t);
        let v = [
            [-1.0, t, 0.0],
            [1.0, t, 0.0],
            [-1.0, -t, 0.0],
            [1.0, -t, 0.0],
            [0.0, -1.0, t],
            [0.0, 1.0, t],
            [0.0, -1.0, -t],
            [0.0, 1.0, -t],
            [t, 0.0, -1.0],
            [t, 0.0, 1.0],
            [-t, 0.0, -1.0],
            [-t, 0.0, 1.0],
        ];
        v.map(|p| [p[0] / n, p[1] / n, p[2] / n])
    }

    #[test]
    fn six_param_exact_on_six_axis_poses() {
        let m = [[1.02, 0.0, 0.0], [0.0, 0.97, 0.0], [0.0, 0.0, 1.01]];
        let o = [0.02, -0.015, 0.03];
        let mut c = <AccelCalibrator>::new();
        for f in [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]] {
            c.add_pose(raw(&m, &o, f)).unwrap();
        }
        let cal = c.solve6().unwrap();
        for i in 0..3 {
            assert!((cal.m[i][i] as Real - m[i][i]).abs() < 2e-6, "{:?}", cal.m);
            assert!((cal.offset_g[i] as Real - o[i]).abs() < 2e-6);
        }
        assert!(cal.rms_after_g < 1e-6 && cal.rms_before_g > 1e-3);
    }

    #[test]
    fn nine_param_exact_on_icosahedron() {
        let m = [[1.02, 0.004, -0.003], [0.0, 0.97, 0.006], [0.0, 0.0, 1.01]];
        let o = [0.02, -0.015, 0.03];
        let mut c = <AccelCalibrator>::new();
        for f in icosahedron() {
            c.add_pose(raw(&m, &o, f)).unwrap();
        }
        let cal = c.solve9().unwrap();
        for i in 0..3 {
            for j in 0..3 {
                assert!((cal.m[i][j] as Real - m[i][j]).abs() < 2e-6, "{:?}", cal.m);
            }
            assert!((cal.offset_g[i] as Real - o[i]).abs() < 2e-6);
        }
    }

    #[test]
    fn too_few_and_degenerate_poses_are_errors() {
        let mut c = <AccelCalibrator>::new();
        for f in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]] {
            c.add_pose(f).unwrap();
        }
        assert_eq!(c.solve6(), Err(Error::TooFewPoses { have: 3, need: 6 }));
        // Eight poses on one cone (a servo's): the ellipsoid is not determined.
        let mut c = <AccelCalibrator>::new();
        for k in 0..8 {
            let th = k as Real * 0.7;
            let v = [0.6 * libm::cos(th), 0.6 * libm::sin(th), 0.8];
            c.add_pose([v[0] as f32, v[1] as f32, v[2] as f32]).unwrap();
        }
        assert!(matches!(c.solve6(), Err(Error::Singular | Error::IllConditioned { .. } | Error::AccelFitFailed)));
    }

    /// Fraction of the 9-parameter fit's offsets and diagonal gains within 1σ and 2σ over
    /// `runs` sensors, each pose of `poses` given noise of 1σ `sigma(k)` (g) per axis on its
    /// mean, and stated to the fit as `stated(k)`.
    fn coverage(poses: &[[Real; 3]], sigma: impl Fn(usize) -> Real, stated: impl Fn(usize) -> Real, runs: usize) -> [Real; 2] {
        let mut noise = crate::math::test_noise::Gaussian::new(0x9e37_79b9_7f4a_7c15);
        let (m, o) = ([[1.01, 0.002, -0.003], [0.0, 0.99, 0.001], [0.0, 0.0, 1.02]], [0.01, -0.02, 0.005]);
        let mut within = [0u32; 2];
        let stated: heapless::Vec<Real, 32> = (0..poses.len()).map(stated).collect();
        for _ in 0..runs {
            let mut c = <AccelCalibrator>::new();
            for (k, f) in poses.iter().enumerate() {
                c.add_pose(raw(&m, &o, *f).map(|v| (v as Real + sigma(k) * noise.next()) as f32)).unwrap();
            }
            let cal = c.solve9().unwrap();
            let sig = c.sigma(&cal, &stated).unwrap();
            for i in 0..3 {
                let errs = [(cal.offset_g[i] as Real - o[i], sig.offset_g[i]), (cal.m[i][i] as Real - m[i][i], sig.gain[i])];
                for (e, s) in errs {
                    within[0] += (e.abs() <= s as Real) as u32;
                    within[1] += (e.abs() <= 2.0 * s as Real) as u32;
                }
            }
        }
        within.map(|n| n as Real / (6 * runs) as Real)
    }

    #[test]
    fn sigma_covers_the_error_with_three_spare_poses() {
        // 12 poses for 9 unknowns, each pose's 1σ known: propagated, it covers as a 1σ should.
        // The residual's 3 degrees of freedom would not (its variance alone: 64 % / 89 %).
        let [one, two] = coverage(&icosahedron(), |_| 1e-4, |_| 1e-4, 1500);
        assert!((0.62..=0.74).contains(&one) && two >= 0.92, "within 1 sigma {one:.3}, 2 sigma {two:.3}");
    }

    #[test]
    fn sigma_covers_the_error_of_noisy_poses_among_still_ones() {
        // 20 still rig poses round a cone and 12 hand-held ones ten times noisier: one pooled
        // residual variance would be set by the still poses (50 % / 82 %); each pose's own
        // variance propagated is not.
        let mut poses = [[0.0; 3]; 32];
        for (k, p) in poses.iter_mut().enumerate() {
            let th = k as Real * crate::math::real::consts::TAU / 20.0;
            *p = if k < 20 { [0.6 * libm::cos(th), 0.6 * libm::sin(th), 0.8] } else { icosahedron()[k - 20] };
        }
        let noise = |k: usize| if k < 20 { 1e-5 } else { 1e-4 };
        let [one, two] = coverage(&poses, noise, noise, 1500);
        assert!((0.62..=0.74).contains(&one) && two >= 0.92, "within 1 sigma {one:.3}, 2 sigma {two:.3}");
    }

    #[test]
    fn residuals_beyond_the_poses_own_sigma_scale_it() {
        // Every pose's error three times what it states (a hand's motion its scatter does not
        // show): χ² finds it and the 1σ grows with it; unscaled, a third of the errors would lie
        // within 2σ.
        let poses = [icosahedron(), icosahedron().map(|p| p.map(|v| -v))].concat();
        let [one, two] = coverage(&poses, |_| 3e-4, |_| 1e-4, 1000);
        assert!(one >= 0.55 && two >= 0.90, "within 1 sigma {one:.3}, 2 sigma {two:.3}");
        // Stated right, nothing is scaled: the test is at its 5 % level.
        let mut noise = crate::math::test_noise::Gaussian::new(7);
        let mut scaled = 0;
        for _ in 0..400 {
            let mut c = <AccelCalibrator>::new();
            for f in &poses {
                c.add_pose(f.map(|v| (v + 1e-4 * noise.next()) as f32)).unwrap();
            }
            let cal = c.solve9().unwrap();
            scaled += (c.sigma(&cal, &[1e-4; 24]).unwrap().scale > 1.0) as u32;
        }
        assert!(scaled <= 40, "scaled in {scaled} of 400");
    }

    #[test]
    fn sigma_needs_one_positive_sigma_per_pose() {
        let mut c = <AccelCalibrator>::new();
        for f in icosahedron() {
            c.add_pose(f.map(|v| v as f32)).unwrap();
        }
        let cal = c.solve9().unwrap();
        assert!(c.sigma(&cal, &[1e-4; 12]).is_some());
        assert_eq!(c.sigma(&cal, &[1e-4; 11]), None);
        assert_eq!(c.sigma(&cal, &[[1e-4; 11].as_slice(), &[0.0]].concat()), None);
        assert_eq!(c.sigma(&AccelCal::IDENTITY, &[1e-4; 12]), None);
    }

    /// How often the F-test takes the 9-parameter model over `runs` sensors of gain `m` and the
    /// poses `poses`, each mean given 1σ `sigma` (g) of noise per axis.
    fn nine_taken(m: &[[Real; 3]; 3], poses: &[[Real; 3]], sigma: Real, runs: usize) -> Real {
        let mut noise = crate::math::test_noise::Gaussian::new(0x2545_f491_4f6c_dd1d);
        let acc = crate::procedure::Config::DEFAULT.acceptance;
        let mut nine = 0;
        for _ in 0..runs {
            let mut c = AccelCalibrator::<32>::new();
            for f in poses {
                c.add_pose(raw(m, &[0.01, -0.02, 0.005], *f).map(|v| (v as Real + sigma * noise.next()) as f32)).unwrap();
            }
            let (fit, test) = crate::procedure::pipeline::fit_accel_tested(&c, &acc).unwrap();
            assert_eq!(fit.model == AccelModel::NineParam, test.unwrap().nine());
            nine += test.unwrap().nine() as usize;
        }
        nine as Real / runs as Real
    }

    #[test]
    fn the_nine_parameter_model_only_where_its_cross_terms_are_significant() {
        let ico = icosahedron();
        // The icosahedron's 12 and a cube's 8 corners (b = 0b1xx: x negative, ...).
        let twenty: [[Real; 3]; 20] = core::array::from_fn(|k| match k {
            k if k < 12 => ico[k],
            k => core::array::from_fn(|i| if (k - 12) >> i & 1 == 1 { -1.0 } else { 1.0 } / libm::sqrt(3.0)),
        });
        let diagonal = [[1.02, 0.0, 0.0], [0.0, 0.97, 0.0], [0.0, 0.0, 1.01]];
        let crossed = [[1.02, 0.01, -0.008], [0.0, 0.97, 0.012], [0.0, 0.0, 1.01]];
        // No cross terms: taken at the test's 5 % level, whatever the poses.
        for poses in [&ico[..10], &twenty[..]] {
            let false_alarm = nine_taken(&diagonal, poses, 2e-4, 400);
            assert!(false_alarm <= 0.09, "{} poses: 9 parameters taken in {false_alarm:.3}", poses.len());
        }
        // 1 % cross terms, 0.2 mg poses: the 6-parameter residual is ~25 times the 9's, which
        // even one degree of freedom (10 poses: F > 216) finds.
        for poses in [&ico[..10], &twenty[..]] {
            let found = nine_taken(&crossed, poses, 2e-4, 200);
            assert!(found >= 0.95, "{} poses: 9 parameters taken in {found:.3}", poses.len());
        }
    }
}
