//! The rig axes from their poses (calibrated accelerometer frame, g): one plane fit per axis, the
//! pose noise the planes show, and how far from coplanar the fitted axes are.

use super::{Axes, FullAxis, FullLimits, MAX_AXES, MIN_NOISE_DOF};
use crate::estimators::axis::Plane;
use crate::math::real::{self, Real};
use crate::math::vec3::tangent_basis;
use crate::math::vec3::Length;
use crate::Error;
use nalgebra::Vector3;

/// Plane fit of one axis' pose tips.
#[derive(Clone, Copy)]
pub(super) struct Fit {
    /// Unit axis (signed as in the module doc of [`super`]).
    pub u: Vector3<Real>,
    /// Orthonormal in-plane basis: the two tilt directions of `u`.
    pub e: [Vector3<Real>; 2],
    /// `1 / √(n λ_k)` (1/g): axis tilt towards `e_k` per unit pose noise.
    pub tilt_per_g: [Real; 2],
    /// Least 1σ of the direction (rad): the axis' own tilt when it is taken along gravity.
    pub floor_rad: Real,
    /// Near vertical: only the direction of `K Γ` is used.
    pub direction_only: bool,
    /// Angle of the axis from vertical (°).
    pub tilt_deg: Real,
    /// RMS distance of the tips from the plane (g).
    pub plane_rms_g: Real,
    /// Sum of squared distances from the plane (g²) and its degrees of freedom.
    pub ss: Real,
    pub dof: u32,
    /// Poses on the plane.
    pub poses: u8,
}

impl Fit {
    /// 1σ (rad) of the axis direction towards `e_k` for a pose noise `sigma_a` (g).
    pub fn dir_sigma(&self, k: usize, sigma_a: Real) -> Real {
        (sigma_a * self.tilt_per_g[k]).max(self.floor_rad)
    }

    /// 1σ (°) of the axis direction, the worse of the two tilt directions.
    pub fn sigma_deg(&self, sigma_a: Real) -> Real {
        self.dir_sigma(0, sigma_a).max(self.dir_sigma(1, sigma_a)).to_degrees()
    }
}

/// The fit of every axis id with moves (index = axis id) and the pose noise that weights them.
pub(super) struct Fits {
    pub axis: [Option<Fit>; MAX_AXES],
    /// Pose-mean noise per component (g): `σ_a` of the module doc of [`super`].
    pub sigma_a: Real,
}

impl Fits {
    /// The axes with moves used (`per_axis`, moves per axis id), in axis-id order, and their count.
    pub fn used(&self, per_axis: &[u8; MAX_AXES]) -> ([Vector3<Real>; MAX_AXES], usize) {
        let mut us = [Vector3::zeros(); MAX_AXES];
        let mut n_axes = 0;
        for a in 0..MAX_AXES {
            if let (Some(f), true) = (self.axis[a], per_axis[a] > 0) {
                us[n_axes] = f.u;
                n_axes += 1;
            }
        }
        (us, n_axes)
    }

    /// Every axis id as reported, with its moves used (`per_axis`).
    pub fn reports(&self, per_axis: &[u8; MAX_AXES]) -> [FullAxis; MAX_AXES] {
        let mut axes = [FullAxis::default(); MAX_AXES];
        for (a, f) in self.axis.iter().enumerate() {
            if let Some(f) = f {
                axes[a] = FullAxis {
                    u: [f.u[0] as f32, f.u[1] as f32, f.u[2] as f32],
                    tilt_deg: f.tilt_deg as f32,
                    plane_rms_g: f.plane_rms_g as f32,
                    sigma_deg: f.sigma_deg(self.sigma_a) as f32,
                    poses: f.poses,
                    moves: per_axis[a],
                    direction_only: f.direction_only,
                };
            }
        }
        axes
    }
}

impl Axes {
    /// Fits every axis with moves, measures `σ_a` from the planes, rejects a plane much noisier
    /// than the others and takes a near-vertical axis whose circle is too small to fit along
    /// gravity.
    pub(super) fn fit_axes(&self, limits: &FullLimits) -> Result<Fits, Error> {
        let mut fits: [Option<Fit>; MAX_AXES] = [None; MAX_AXES];
        let mut fallbacks: [Option<Fit>; MAX_AXES] = [None; MAX_AXES];
        for a in 0..MAX_AXES {
            if self.moves().iter().any(|m| m.axis as usize == a) {
                let (f, fallback) = self.fit(a, limits)?;
                fallbacks[a] = fallback;
                fits[a] = Some(f);
            }
        }
        let sigma_a = pose_noise(&fits, limits);
        // A plane much noisier than the others: the board slipped (or the shaft wobbles) on that axis.
        for f in fits.iter().flatten().filter(|f| f.dof >= MIN_NOISE_DOF) {
            let (noise_g, limit_g) = (real::sqrt(f.ss / f.dof as Real), limits.max_plane_noise_ratio as Real * sigma_a);
            if noise_g > limit_g {
                // The value compared is reported (the plane's RMS over its poses is smaller).
                return Err(Error::AxisNotFixed { plane_rms_g: noise_g as f32, limit_g: limit_g as f32 });
            }
        }
        for a in 0..MAX_AXES {
            let Some(f) = fits[a] else { continue };
            if !(f.sigma_deg(sigma_a) <= limits.max_axis_sigma_deg as Real) {
                match fallbacks[a] {
                    Some(g) => fits[a] = Some(g), // no circle to fit: the axis is along gravity
                    None => {
                        return Err(Error::AxisUndetermined {
                            axis: a as u8,
                            sigma_deg: f.sigma_deg(sigma_a) as f32,
                            limit_deg: limits.max_axis_sigma_deg,
                        })
                    }
                }
            }
        }
        Ok(Fits { axis: fits, sigma_a })
    }

    /// Plane fit of axis `a`, signed by its moves, and for a near-vertical axis the fallback along
    /// gravity. `σ_a` is not known yet: the caller chooses and checks the axis' direction 1σ.
    fn fit(&self, a: usize, limits: &FullLimits) -> Result<(Fit, Option<Fit>), Error> {
        let Plane { n, mean, vals, u, e, tilt_deg, radial, off_plane_ms } = self.poses.plane(self.members[a]);
        let nf = n as Real;
        let spread = real::sqrt((vals[1] + vals[2]).max(0.0));
        let min_tilt = (limits.geometry.min_tilt_deg as Real).to_radians();
        // Every tip nearly at one place: a (near) vertical axis. Its circle, when the noise lets it
        // be fitted, gives the axis; else the mean gravity direction does (as in `Poses::geometry`).
        let vertical = spread < 0.3 * min_tilt;
        let sign = |mut f: Fit| {
            let s: Real = self
                .moves()
                .iter()
                .filter(|m| m.axis as usize == a)
                .map(|m| m.commanded_deg as Real * Vector3::from(m.gamma_deg).dot(&f.u))
                .sum();
            if s < 0.0 {
                f.u = -f.u;
            }
            f
        };
        let along_gravity = || {
            let u = mean.unit();
            let r = 1.0 / real::sqrt(nf);
            let e = tangent_basis(&u);
            // Along gravity the axis is off by up to its own tilt: that bounds the direction's 1σ.
            let floor_rad = crate::math::trig::atan2(spread, mean.length());
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
        let plane_rms_g = real::sqrt(off_plane_ms);
        if !(plane_rms_g <= limits.geometry.max_plane_rms_g as Real) {
            return Err(Error::AxisNotFixed { plane_rms_g: plane_rms_g as f32, limit_g: limits.geometry.max_plane_rms_g });
        }
        let per = |l: Real| if l > 0.0 { 1.0 / real::sqrt(nf * l) } else { Real::INFINITY };
        let plane = sign(Fit {
            u,
            e,
            tilt_per_g: [per(vals[1]), per(vals[2])],
            floor_rad: limits.accel_systematic_g as Real / radial.max(1e-3),
            direction_only: vertical || tilt_deg < limits.geometry.min_tilt_deg as Real,
            tilt_deg,
            plane_rms_g,
            // A near-vertical axis' plane residual is not counted in the pose noise.
            ss: if vertical { 0.0 } else { nf * off_plane_ms },
            dof: if vertical { 0 } else { n as u32 - 3 },
            poses: n as u8,
        });
        Ok((plane, vertical.then(along_gravity)))
    }
}

/// Pose-mean noise per component (g): the median over the planes of their residual noise
/// `√(ss / (n − 3))`, floored by `min_accel_sigma_g`.
fn pose_noise(fits: &[Option<Fit>; MAX_AXES], limits: &FullLimits) -> Real {
    let (mut noise, mut n_noise) = ([0.0 as Real; MAX_AXES], 0);
    for f in fits.iter().flatten().filter(|f| f.dof > 0) {
        noise[n_noise] = real::sqrt(f.ss / f.dof as Real);
        n_noise += 1;
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
    let floor = limits.min_accel_sigma_g as Real;
    if n_noise > 0 {
        noise[(n_noise - 1) / 2].max(floor)
    } else {
        floor
    }
}

/// How far from coplanar unit axes are (rad): the largest angle of an axis from the plane of two
/// others (0 for fewer than 3 axes), and the smallest angle between two (∞ for fewer than 2).
pub(super) fn spread_rad(us: &[Vector3<Real>]) -> (Real, Real) {
    let (mut non_coplanar, mut min_pair) = (0.0 as Real, Real::INFINITY);
    for i in 0..us.len() {
        for j in i + 1..us.len() {
            let c = us[i].cross(&us[j]);
            min_pair = min_pair.min(crate::math::trig::atan2(c.length(), us[i].dot(&us[j]).abs()));
            if c.length() > 1e-9 {
                for k in (0..us.len()).filter(|&k| k != i && k != j) {
                    // The angle of u_k from the plane ⟂ c (no asin linked into the firmware).
                    non_coplanar = non_coplanar.max(crate::math::trig::atan2(us[k].dot(&c).abs(), us[k].cross(&c).length()));
                }
            }
        }
    }
    (non_coplanar, min_pair)
}
