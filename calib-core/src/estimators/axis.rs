//! Static rig poses and the geometry they imply: the rotation axis in the sensor frame, the
//! axis tilt, the shaft turn between two poses, and the geometry checks both gyro estimators need.
//!
//! Convention (DESIGN §4): turning the shaft by `+θ` about `u` (right hand) rotates the specific
//! force `A`, seen in the sensor frame B, by `−θ` about `u`; `A·u` is the same in every pose.

use crate::math::linalg::sym_eigen;
use crate::math::real::{self, Real};
use crate::math::vec3::to_real;
use crate::math::vec3::Length;
use crate::{Error, Vec3};
use nalgebra::Vector3;

/// Largest number of rig poses kept.
pub const MAX_POSES: usize = 64;

/// Requirements on the rig geometry.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GeometryLimits {
    /// Fewest static poses.
    pub min_poses: u8,
    /// Smallest angle between the rotation axis and vertical (°).
    pub min_tilt_deg: f32,
    /// Largest angle between the rotation axis and vertical for the paper estimator (°).
    pub max_tilt_deg_paper: f32,
    /// Smallest |component| of the unit rotation axis on every sensor axis.
    pub min_axis_component: f32,
    /// Smallest shaft-angle span of the poses (°).
    pub min_span_deg: f32,
    /// Largest RMS distance of the pose tips from their plane (g).
    pub max_plane_rms_g: f32,
}

impl GeometryLimits {
    /// The defaults (also as `Default`).
    pub const DEFAULT: GeometryLimits = GeometryLimits {
        min_poses: 4,
        min_tilt_deg: 10.0,
        max_tilt_deg_paper: 80.0,
        min_axis_component: 0.1,
        min_span_deg: 90.0,
        max_plane_rms_g: 0.01,
    };
}

impl Default for GeometryLimits {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The rig geometry measured from the poses.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Geometry {
    /// Unit rotation axis in B, signed so that `A·u ≥ 0`.
    pub u: Vector3<Real>,
    /// Angle between the axis and vertical (°).
    pub tilt_deg: Real,
    /// Shaft-angle span of the poses (°), unwrapped along the pose order.
    pub span_deg: Real,
    /// Smallest |u_k|.
    pub min_component: Real,
    /// RMS distance of the pose tips from their plane (g).
    pub plane_rms_g: Real,
}

/// Mean calibrated accelerometer readings (g, B) of the static rig poses (bounded, no heap):
/// kept in f32 (a pose's mean is known to ~1e-4 g; f32 rounds at 6e-8 g), computed with in f64.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Poses {
    a: heapless::Vec<Vec3, MAX_POSES>,
}

impl Poses {
    /// No poses.
    pub const fn new() -> Self {
        Self { a: heapless::Vec::new() }
    }

    /// Number of poses.
    pub fn len(&self) -> usize {
        self.a.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }

    /// Forgets every pose.
    pub fn clear(&mut self) {
        self.a.clear();
    }

    /// Adds a pose (calibrated specific force, g); returns its index.
    pub fn push(&mut self, a: Vec3) -> Result<u8, Error> {
        if !a.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        self.a.push(a).map_err(|_| Error::CapacityExceeded { max: MAX_POSES as u8 })?;
        Ok((self.a.len() - 1) as u8)
    }

    /// Pose `i` as a vector (g). Panics never: out-of-range indices give the last pose, zero when empty.
    pub fn get(&self, i: usize) -> Vector3<Real> {
        to_real(self.a.get(i).or(self.a.last()).copied().unwrap_or_default())
    }

    /// Replaces every pose `a` by `f(a)` (e.g. raw readings by calibrated ones).
    pub fn map(&mut self, f: impl Fn(Vector3<Real>) -> Vector3<Real>) {
        for a in &mut self.a {
            let v = f(to_real(*a));
            *a = [v[0] as f32, v[1] as f32, v[2] as f32];
        }
    }

    /// Iterator over the poses.
    pub fn iter(&self) -> impl Iterator<Item = Vector3<Real>> + '_ {
        self.a.iter().map(|a| to_real(*a))
    }

    /// Plane fit of the poses whose bit is set in `mask` (bit `p`: pose `p`).
    pub(crate) fn plane(&self, mask: u64) -> Plane {
        let tips = || self.iter().enumerate().filter(move |&(p, _)| mask >> p & 1 != 0).map(|(_, t)| t);
        let n = tips().count();
        let nf = n as Real;
        let mean = tips().sum::<Vector3<Real>>() / nf;
        let mut scatter = [[0.0; 3]; 3];
        for t in tips() {
            let d = t - mean;
            for i in 0..3 {
                for j in 0..3 {
                    scatter[i][j] += d[i] * d[j] / nf;
                }
            }
        }
        let (vals, vecs) = sym_eigen(&scatter);
        let col = |k: usize| Vector3::new(vecs[0][k], vecs[1][k], vecs[2][k]);
        let mut u = col(0);
        if u.dot(&mean) < 0.0 {
            u = -u;
        }
        let (axial, radial, off) = tips().fold((0.0, 0.0, 0.0), |(ax, ra, off), t| {
            let (along, off_plane) = (t.dot(&u), (t - mean).dot(&u));
            (ax + along / nf, ra + (t - u * along).length() / nf, off + off_plane * off_plane / nf)
        });
        let (e, tilt_deg) = ([col(1), col(2)], crate::math::trig::atan2(radial, axial).to_degrees());
        Plane { n, mean, vals, u, e, tilt_deg, radial, off_plane_ms: off }
    }

    /// Measures and checks the geometry. `paper` adds the paper estimator's own requirement
    /// (axis not near horizontal, where `A·u → 0`).
    pub fn geometry(&self, limits: &GeometryLimits, paper: bool) -> Result<Geometry, Error> {
        if self.len() < (limits.min_poses as usize).max(3) {
            return Err(Error::TooFewPoses { have: self.len() as u8, need: limits.min_poses.max(3) });
        }
        let Plane { mean, vals, u, tilt_deg, off_plane_ms, .. } = self.plane(u64::MAX);
        // Gravity that barely changes between poses means a vertical axis whatever the fit says
        // (a circle of radius sin(tilt) ≤ tilt in rad; no trigonometry on the target).
        let spread = real::sqrt((vals[1] + vals[2]).max(0.0));
        let min_tilt = (limits.min_tilt_deg as Real).to_radians();
        if spread < 0.3 * min_tilt || tilt_deg < limits.min_tilt_deg as Real {
            let tilt = crate::math::trig::atan2(spread, mean.length()).to_degrees().min(tilt_deg);
            return Err(Error::AxisNearVertical { tilt_deg: tilt as f32, limit_deg: limits.min_tilt_deg });
        }
        // Shaft angle of each pose, unwrapped along the pose order (consecutive poses < 180° apart).
        let (mut at, mut lo, mut hi) = (0.0 as Real, 0.0 as Real, 0.0 as Real);
        for i in 1..self.len() {
            at += turn_deg(&u, &self.get(i - 1), &self.get(i));
            lo = lo.min(at);
            hi = hi.max(at);
        }
        let span_deg = hi - lo;
        if span_deg < limits.min_span_deg as Real {
            return Err(Error::AngleSpanTooSmall { span_deg: span_deg as f32, min_deg: limits.min_span_deg });
        }
        let plane_rms_g = real::sqrt(off_plane_ms);
        if plane_rms_g > limits.max_plane_rms_g as Real {
            return Err(Error::AxisNotFixed { plane_rms_g: plane_rms_g as f32, limit_g: limits.max_plane_rms_g });
        }
        let (axis, min_component) = (0..3).map(|k| (k, u[k].abs())).fold((0, Real::INFINITY), |b, c| if c.1 < b.1 { c } else { b });
        if min_component < limits.min_axis_component as Real {
            return Err(Error::WeakSensorAxis { axis: axis as u8, component: min_component as f32, min: limits.min_axis_component });
        }
        if paper && tilt_deg > limits.max_tilt_deg_paper as Real {
            return Err(Error::AxisNearHorizontal { tilt_deg: tilt_deg as f32, limit_deg: limits.max_tilt_deg_paper });
        }
        Ok(Geometry { u, tilt_deg, span_deg, min_component, plane_rms_g })
    }
}

/// Plane fit of pose tips ([`Poses::plane`]).
pub(crate) struct Plane {
    /// Number of tips.
    pub n: usize,
    /// Mean tip (g).
    pub mean: Vector3<Real>,
    /// Eigenvalues (ascending, g²) of the tips' scatter `Σ d dᵀ / n` about the mean.
    pub vals: [Real; 3],
    /// Unit normal (the first eigenvector), signed towards the mean.
    pub u: Vector3<Real>,
    /// The other two eigenvectors (in-plane, same order as `vals[1..]`).
    pub e: [Vector3<Real>; 2],
    /// Angle of `u` from the mean tip direction (°): `atan2` of the mean radial and axial distances.
    pub tilt_deg: Real,
    /// Mean distance of the tips from the line along `u` (g).
    pub radial: Real,
    /// Mean square of the tips' distances from their plane (g²): `vals[0]`, summed from the
    /// distances themselves. The eigenvalue is found to ± the rounding of the largest (1e-8 g²
    /// in `f32`, as large as a still rig's plane residual: the firmware's K came out 0.13σ off
    /// the PC's, its 1σ 6 %).
    pub off_plane_ms: Real,
}

/// Shaft turn (°, in (−180, 180]) about `u` that takes pose `from` to pose `to`.
pub fn turn_deg(u: &Vector3<Real>, from: &Vector3<Real>, to: &Vector3<Real>) -> Real {
    let p = from - u * from.dot(u);
    let q = to - u * to.dot(u);
    -crate::math::trig::atan2(u.dot(&p.cross(&q)), p.dot(&q)).to_degrees()
}

/// `angle_deg + k·360°` nearest to `reference_deg`: resolves the turn measured modulo a full turn
/// with the gyro's own (uncalibrated) integral.
pub fn unwrap_near(angle_deg: Real, reference_deg: Real) -> Real {
    angle_deg + 360.0 * real::round((reference_deg - angle_deg) / 360.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Specific force seen in B when the shaft (axis `u`, tilt `tilt` from vertical) is at `th`.
    pub(crate) fn pose(u: Vector3<Real>, tilt: Real, th: Real) -> Vec3 {
        let e1 = u.cross(&Vector3::new(0.3, -0.5, 0.8)).normalize();
        let e2 = u.cross(&e1);
        // Rotating the shaft by th rotates A by −th about u.
        let (s, c) = (libm::sin(-th), libm::cos(-th));
        let a = u * libm::cos(tilt) + (e1 * c + e2 * s) * libm::sin(tilt);
        [a[0] as f32, a[1] as f32, a[2] as f32]
    }

    fn axis() -> Vector3<Real> {
        Vector3::new(0.5, -0.6, 0.62).normalize()
    }

    #[test]
    fn recovers_axis_tilt_span_and_turn_sign() {
        let u = axis();
        let mut p = Poses::new();
        for k in 0..6 {
            p.push(pose(u, 0.7, (k as Real * 30.0).to_radians())).unwrap();
        }
        let g = p.geometry(&GeometryLimits::default(), true).unwrap();
        assert!((g.u - u).norm() < 1e-6, "{:?}", g.u);
        assert!((g.tilt_deg - (0.7 as Real).to_degrees()).abs() < 1e-4);
        assert!((g.span_deg - 150.0).abs() < 1e-4);
        assert!((turn_deg(&u, &p.get(0), &p.get(2)) - 60.0).abs() < 1e-4);
        assert!((turn_deg(&(-u), &p.get(0), &p.get(2)) + 60.0).abs() < 1e-4);
    }

    #[test]
    fn unwrap_picks_the_branch_nearest_the_gyro() {
        assert_eq!(unwrap_near(-170.0, 185.0), 190.0);
        assert_eq!(unwrap_near(10.0, 372.0), 370.0);
        assert_eq!(unwrap_near(10.0, 12.0), 10.0);
    }

    #[test]
    fn degenerate_geometries_are_named() {
        let lim = GeometryLimits::default();
        let mk = |u: Vector3<Real>, tilt: Real, step: Real, n: usize| {
            let mut p = Poses::new();
            for k in 0..n {
                p.push(pose(u, tilt, (k as Real * step).to_radians())).unwrap();
            }
            p
        };
        assert!(matches!(mk(axis(), 0.02, 30.0, 6).geometry(&lim, false), Err(Error::AxisNearVertical { .. })));
        assert!(matches!(mk(axis(), 0.7, 5.0, 6).geometry(&lim, false), Err(Error::AngleSpanTooSmall { .. })));
        assert!(matches!(mk(axis(), 0.7, 30.0, 3).geometry(&lim, false), Err(Error::TooFewPoses { .. })));
        let weak = Vector3::new(0.05, 0.7, 0.7).normalize();
        assert!(matches!(mk(weak, 0.7, 30.0, 6).geometry(&lim, false), Err(Error::WeakSensorAxis { axis: 0, .. })));
        assert!(matches!(mk(axis(), 1.5, 30.0, 6).geometry(&lim, true), Err(Error::AxisNearHorizontal { .. })));
        assert!(mk(axis(), 1.5, 30.0, 6).geometry(&lim, false).is_ok());
    }
}
