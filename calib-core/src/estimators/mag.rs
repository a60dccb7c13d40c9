//! Magnetometer calibration (DESIGN §4.8): `m = A (m_raw − o)` (µT) in the calibrated
//! accelerometer's frame, from the hand-held step only (a servo's motor magnet moves with the
//! shaft: the rig's samples never enter).
//!
//! 1. Hard and soft iron: an ellipsoid (quadric) fit of raw samples spread over the sphere gives
//!    the offset `o` and a symmetric `A_s` with `|A_s (m_raw − o)| = B`, the field strength
//!    (µT: `A_s` keeps the raw scale's geometric mean).
//! 2. Alignment: `A = R A_s`, `R` the small rotation of the magnetometer's die against the
//!    accelerometer, from the seed paper's invariant applied to the field: at every still pose
//!    the angle between gravity and the field is the same, `f̂ᵢ · R ûᵢ = −sin(dip)`, linear in
//!    `R`'s angles for a small rotation (two Gauss–Newton steps).

use crate::math::linalg::{inverse3, sym_eigen};
use crate::math::lsq::{NormalEquations, Solution};
use crate::math::real::{self, Real};
use crate::math::vec3::Length;
use crate::math::vec3::{mat_to_real, to_real};
use crate::{Error, Mat3, Vec3};
use nalgebra::{Matrix3, Vector3};

/// Points kept for the ellipsoid: each the mean of consecutive raw readings within
/// [`MIN_SPACING_UT`] of the first of them (a still pose is one precise point, a move a trail).
pub const MAX_MAG_SAMPLES: usize = 192;
/// Still poses kept for the alignment.
pub const MAX_MAG_POSES: usize = 32;
/// Distance (µT) from the last kept sample below which a raw sample adds nothing new.
pub const MIN_SPACING_UT: f32 = 5.0;
/// A kept point's unit (µT): 1/128 µT in an `i16` from the first point, ±256 µT of it. The
/// points lie on the field's ellipsoid, at most its diameter apart (2 × 65 µT at the most
/// intense Earth field, times the soft iron's gain); a point farther is no Earth field and is
/// not kept. A point takes 8 B instead of 16; its rounding (0.002 µT RMS) is 1/20 of the noise
/// of a still pose's mean (0.3 µT over 40 readings, 0.047 µT).
const POINT_UT: Real = 1.0 / 128.0;

/// A point (µT) as kept, relative to `origin` (µT); `None` beyond [`POINT_UT`]'s range.
fn to_point(mean_ut: [Real; 3], origin: [f32; 3]) -> Option<[i16; 3]> {
    let q = core::array::from_fn(|k| real::round((mean_ut[k] - origin[k] as Real) / POINT_UT));
    q.iter().all(|v: &Real| v.abs() <= i16::MAX as Real).then(|| q.map(|v| v as i16))
}

/// A kept point in µT (on the FPU: exact but for the sum's rounding, 6e-5 µT at 1000 µT).
fn from_point(p: [i16; 3], origin: [f32; 3]) -> [f32; 3] {
    core::array::from_fn(|k| origin[k] + p[k] as f32 * POINT_UT as f32)
}
/// Readings within this distance (µT, raw) of a pose's mean are that pose's, left out with it
/// when a disturbed pose is looked for.
const EXCLUDE_UT: f32 = 2.0 * MIN_SPACING_UT;
/// Samples the ellipsoid needs (9 unknowns, with room to spare).
pub const MIN_SAMPLES: usize = 30;
/// Poses the alignment needs (4 unknowns).
pub const MIN_POSES: usize = 6;
/// Gauss–Newton steps of [`MagCalibrator::refine`].
pub const REFINE_STEPS: usize = 3;
/// Directions of the sphere ([`COVERAGE_BINS`] cells) the samples must reach.
pub const MIN_COVERAGE: f32 = 0.6;
/// Sphere cells of the coverage figure: the faces of an icosahedron (nearest face centre).
pub const COVERAGE_BINS: usize = 20;

/// Limits of a magnetometer calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MagLimits {
    /// Largest deviation of a pose's field strength from the fit's (µT).
    pub max_field_dev_ut: f32,
    /// Largest deviation of a pose's dip from the mean dip (°).
    pub max_dip_dev_deg: f32,
    /// Largest RMS of `|m| − B` over the samples (µT).
    pub max_residual_ut: f32,
}

impl Default for MagLimits {
    /// A few µT and degrees: a room's field varies by less across a hand's reach; a magnet, a
    /// laptop or a servo within 10 cm adds more.
    fn default() -> Self {
        Self { max_field_dev_ut: 3.0, max_dip_dev_deg: 3.0, max_residual_ut: 2.0 }
    }
}

/// A magnetometer calibration `m = A (m_raw − o)` (µT, the calibrated accelerometer's frame)
/// with its quality.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct MagCal {
    /// Soft iron, scale and alignment `A` (row-major).
    pub a: Mat3,
    /// Hard iron and the part's offset `o` (µT, raw frame).
    pub offset_ut: Vec3,
    /// Field strength `B` (µT) and its 1σ.
    pub field_ut: f32,
    /// 1σ of the field strength (µT): the poses' scatter over √n.
    pub sigma_field_ut: f32,
    /// Dip (inclination, °, positive: the field points below the horizon) and its 1σ.
    pub dip_deg: f32,
    /// 1σ of the dip (°).
    pub sigma_dip_deg: f32,
    /// Angle of the die's rotation `R` found against the accelerometer (°) and its 1σ.
    pub alignment_deg: f32,
    /// 1σ of the alignment, largest over its three angles (°).
    pub sigma_alignment_deg: f32,
    /// RMS of `|m| − B` over the samples (µT).
    pub residual_ut: f32,
    /// Fraction of the sphere's [`COVERAGE_BINS`] cells the calibrated samples reach.
    pub coverage: f32,
    /// Samples in the ellipsoid fit.
    pub samples: u16,
    /// Still poses in the alignment.
    pub poses: u8,
}

impl MagCal {
    /// Calibrated field (µT) from a raw reading (µT).
    pub fn apply(&self, m_raw: Vec3) -> Vec3 {
        let d = [m_raw[0] - self.offset_ut[0], m_raw[1] - self.offset_ut[1], m_raw[2] - self.offset_ut[2]];
        core::array::from_fn(|i| self.a[i][0] * d[0] + self.a[i][1] * d[1] + self.a[i][2] * d[2])
    }

    /// Whether a still pose (gravity's direction `f`, raw field `m_raw` in µT) sees the field
    /// the calibration saw, within `limits`: `Err` names the pose's field and dip.
    pub fn check_pose(&self, index: u8, f: Vec3, m_raw: Vec3, limits: &MagLimits) -> Result<(), Error> {
        let a = mat_to_real(&self.a);
        let (b, dip) = field_and_dip(&to_real(f), &(a * (to_real(m_raw) - to_real(self.offset_ut))));
        check(index, b, dip, self.field_ut as Real, (self.dip_deg as Real).to_radians(), limits)
    }
}

/// `asin(x)` (rad) with `x` clamped to ±1, through the `atan2` the firmware has already.
fn asin(x: Real) -> Real {
    let x = x.clamp(-1.0, 1.0);
    crate::math::trig::atan2(x, real::sqrt(1.0 - x * x))
}

/// The rotation by about `θ` (rad, small) without trigonometry: Cayley's
/// `(I − [θ/2]×)⁻¹ (I + [θ/2]×)`, a rotation by `2 atan(|θ|/2)` about `θ`.
fn cayley(theta: &Vector3<Real>) -> Matrix3<Real> {
    let h = theta / 2.0;
    let k = h.cross_matrix();
    let i = Matrix3::identity();
    inverse3(&(i - k)).map_or(i, |inv| inv * (i + k))
}

/// The angle (rad) of rotation matrix `r`: `atan2(sin, cos)` from its skew part and trace.
fn angle_of(r: &Matrix3<Real>) -> Real {
    let v = Vector3::new(r[(2, 1)] - r[(1, 2)], r[(0, 2)] - r[(2, 0)], r[(1, 0)] - r[(0, 1)]);
    crate::math::trig::atan2(v.length() / 2.0, (r.trace() - 1.0) / 2.0)
}

/// Strength (µT) and dip (rad, positive below the horizon) of field `m` with gravity along `f`.
fn field_and_dip(f: &Vector3<Real>, m: &Vector3<Real>) -> (Real, Real) {
    let b = m.length();
    (b, asin(-f.unit().dot(m) / b))
}

/// A pose's field `b` (µT) and dip (rad) against the expected ones, within `limits`.
fn check(index: u8, b: Real, dip: Real, field: Real, expected_dip: Real, limits: &MagLimits) -> Result<(), Error> {
    let (db, dd) = (b - field, (dip - expected_dip).to_degrees());
    if db.abs() <= limits.max_field_dev_ut as Real && dd.abs() <= limits.max_dip_dev_deg as Real {
        return Ok(());
    }
    Err(Error::MagDisturbed {
        pose: index,
        field_ut: b as f32,
        expected_ut: field as f32,
        dip_deg: dip.to_degrees() as f32,
        expected_dip_deg: expected_dip.to_degrees() as f32,
    })
}

/// A move between two of the magnetometer's still poses as the calibrated gyro measured it:
/// `r` takes a vector in the body frame at pose `to` to the frame at pose `from`
/// ([`crate::estimators::rotation::Rotations::rotation`]); the field must follow it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MagMove {
    /// Start pose (the magnetometer's pose index).
    pub from: u8,
    /// End pose.
    pub to: u8,
    /// The rotation (row-major).
    pub r: Mat3,
}

/// Raw magnetometer samples and still poses of the hand-held step, fitted at the end.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MagCalibrator {
    /// Cluster means ([`POINT_UT`] from `origin`) and their reading counts.
    samples: heapless::Vec<([i16; 3], u16), MAX_MAG_SAMPLES>,
    /// The first cluster's mean (µT): the kept points' origin.
    origin: Option<[f32; 3]>,
    /// Per pose: gravity's direction (calibrated accelerometer, unit) and the raw field mean (µT).
    poses: heapless::Vec<([f32; 3], [f32; 3]), MAX_MAG_POSES>,
    /// The open cluster: its first reading, the sum of its readings and their count.
    cluster: Option<([f32; 3], [Real; 3], u32)>,
}

impl MagCalibrator {
    /// Empty.
    pub const fn new() -> Self {
        Self { samples: heapless::Vec::new(), origin: None, poses: heapless::Vec::new(), cluster: None }
    }

    /// Offers one raw reading (µT): it joins the open cluster when within [`MIN_SPACING_UT`] of
    /// its first reading, else the cluster's mean is kept (while there is room) and a new one
    /// opens. Non-finite readings are refused.
    pub fn add_sample(&mut self, m_raw: Vec3) -> Result<(), Error> {
        if !m_raw.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        match &mut self.cluster {
            Some((first, sum, n)) if dist(first, &m_raw) < MIN_SPACING_UT => {
                (0..3).for_each(|k| sum[k] += m_raw[k] as Real);
                *n += 1;
            }
            _ => {
                self.close_cluster();
                self.cluster = Some((m_raw, m_raw.map(|v| v as Real), 1));
            }
        }
        Ok(())
    }

    /// Keeps the open cluster's mean (while there is room).
    fn close_cluster(&mut self) {
        if let Some((_, sum, n)) = self.cluster.take() {
            let mean = sum.map(|v| v / n as Real);
            let origin = *self.origin.get_or_insert(mean.map(|v| v as f32));
            if let Some(p) = to_point(mean, origin) {
                let _ = self.samples.push((p, n.min(u16::MAX as u32) as u16));
            }
        }
    }

    /// Adds a still pose: gravity's direction from the calibrated accelerometer (any length) and
    /// the raw field averaged over the same window (µT).
    pub fn add_pose(&mut self, f: Vec3, m_raw: Vec3) -> Result<(), Error> {
        if !f.iter().chain(m_raw.iter()).all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        self.poses.push((f, m_raw)).map_err(|_| Error::CapacityExceeded { max: MAX_MAG_POSES as u8 })
    }

    /// Points kept for the ellipsoid (the open cluster's included).
    pub fn samples(&self) -> usize {
        self.points().count()
    }

    /// The kept points (µT), then the open cluster's mean (rounded as a kept one) while there
    /// is room for it.
    fn points(&self) -> impl Iterator<Item = ([f32; 3], u16)> + '_ {
        let origin = |mean: [Real; 3]| self.origin.unwrap_or(mean.map(|v| v as f32));
        let open = self.cluster.filter(|_| !self.samples.is_full()).and_then(|(_, sum, n)| {
            let mean = sum.map(|v| v / n as Real);
            Some((from_point(to_point(mean, origin(mean))?, origin(mean)), n.min(u16::MAX as u32) as u16))
        });
        let o = self.origin.unwrap_or_default();
        self.samples.iter().map(move |&(p, n)| (from_point(p, o), n)).chain(open)
    }

    /// Still poses kept.
    pub fn poses(&self) -> usize {
        self.poses.len()
    }

    /// [`Error::MagTooFew`] with the counts kept.
    fn too_few(&self) -> Error {
        let samples = self.samples().min(u16::MAX as usize) as u16;
        Error::MagTooFew { samples, need_samples: MIN_SAMPLES as u16, poses: self.poses.len() as u8, need_poses: MIN_POSES as u8 }
    }

    /// Replaces every pose's gravity direction `f` by `map(f)`: poses taken before the
    /// accelerometer was calibrated, brought into its calibrated frame.
    pub fn map_poses(&mut self, map: impl Fn(Vec3) -> Vec3) {
        self.poses.iter_mut().for_each(|p| p.0 = map(p.0));
    }

    /// The ellipsoid alone (`A` symmetric, no alignment): what the usual tools fit.
    pub fn fit_ellipsoid(&self) -> Result<Ellipsoid, Error> {
        self.fit_ellipsoid_without(None)
    }

    /// [`Self::fit_ellipsoid`] without the points within [`EXCLUDE_UT`] of `near` (µT, raw): a
    /// disturbed pose's readings.
    fn fit_ellipsoid_without(&self, near: Option<[f32; 3]>) -> Result<Ellipsoid, Error> {
        let c = self.ellipsoid_centre(near)?;
        let mut ne = NormalEquations::<9>::new();
        self.add_ellipsoid_rows(&mut ne, &c, near, 0..usize::MAX)?;
        ellipsoid_from(&ne, &c)
    }

    /// The first part of [`Self::fit_ellipsoid`] (for a caller that runs each part in a call of
    /// its own): the kept points' mean (µT, raw), the origin of the fit's rows (for their
    /// conditioning); [`Error::MagTooFew`] with too few points. (`near`: see
    /// [`Self::fit_ellipsoid_without`].)
    pub fn ellipsoid_centre(&self, near: Option<[f32; 3]>) -> Result<Vector3<Real>, Error> {
        let kept = self.points().filter(|(m, _)| near.is_none_or(|p| dist(&p, m) >= EXCLUDE_UT));
        let (sum, n) = kept.fold((Vector3::zeros(), 0usize), |(s, n), (m, _)| (s + to_real(m), n + 1));
        if n < MIN_SAMPLES {
            return Err(self.too_few());
        }
        Ok(sum / n as Real)
    }

    /// The quadric's rows `xᵀQx + bᵀx = 1` (9 unknowns, `x` about `c` in 50 µT) of the kept
    /// points numbered `range` (before `near`'s are left out) into `ne`; whether it reached
    /// the last point.
    pub fn add_ellipsoid_rows(
        &self,
        ne: &mut NormalEquations<9>,
        c: &Vector3<Real>,
        near: Option<[f32; 3]>,
        range: core::ops::Range<usize>,
    ) -> Result<bool, Error> {
        let kept = |m: &[f32; 3]| near.is_none_or(|p| dist(&p, m) >= EXCLUDE_UT);
        let mut points = self.points().skip(range.start);
        for (m, k) in points.by_ref().take(range.end - range.start).filter(|(m, _)| kept(m)) {
            let p = (to_real(m) - c) / 50.0;
            let (x, y, z) = (p[0], p[1], p[2]);
            ne.add_row(&[x * x, y * y, z * z, 2.0 * x * y, 2.0 * x * z, 2.0 * y * z, x, y, z], 1.0, k as Real)?;
        }
        Ok(points.next().is_none())
    }

    /// The ellipsoid and its alignment ([`Self::solve`]'s second part): the die's rotation `R`
    /// and the fit of the gravity–field angle; [`Error::MagTooFew`] with too few poses.
    pub fn alignment(&self, e: &Ellipsoid) -> Result<Alignment, Error> {
        if self.poses.len() < MIN_POSES {
            return Err(self.too_few());
        }
        self.align(&e.0, &e.1, None)
    }

    /// The calibration: ellipsoid, alignment, quality and the checks of `limits`.
    pub fn solve(&self, limits: &MagLimits) -> Result<MagCal, Error> {
        let e = self.fit_ellipsoid()?;
        self.finish(&e, &self.alignment(&e)?, limits)
    }

    /// [`Self::solve`]'s last part: the calibration from the ellipsoid `e` and its alignment,
    /// its quality and the checks of `limits`.
    pub fn finish(&self, e: &Ellipsoid, alignment: &Alignment, limits: &MagLimits) -> Result<MagCal, Error> {
        let (&(a_s, o, field), (r, sol)) = (e, alignment);
        let a = r * a_s;
        let c = sol.x[3];
        let dip = asin(-c);
        let sigma_dip = sol.sigma(3) / real::sqrt((1.0 - c * c).max(1e-6));
        let sigma_align = (0..3).map(|i| sol.sigma(i)).fold(0.0, Real::max);
        let angle = angle_of(r);
        // Per pose: field strength and dip against the fit's.
        if let Err(e) = self.check_poses(&a, &o, field, dip, None, limits) {
            // A magnet near one pose pulls the ellipsoid and the alignment towards it, so that
            // others deviate too: name the pose without whose readings the rest agree, if there
            // is one (the fits again without each pose: on the MCU ~0.1 s each, on this error
            // path only).
            return Err((0..self.poses.len()).find_map(|k| self.blame(k, limits)).unwrap_or(e));
        }
        let (mut sum, mut sum2) = (0.0, 0.0);
        for p in &self.poses {
            let b = (a * (to_real(p.1) - o)).length();
            sum += b;
            sum2 += b * b;
        }
        let n = self.poses.len() as Real;
        let sigma_field = real::sqrt(((sum2 - sum * sum / n) / (n - 1.0)).max(0.0) / n);
        let mut bins = 0u32;
        let mut rss = 0.0;
        for (m, _) in self.points() {
            let v = a * (to_real(m) - o);
            rss += (v.length() - field) * (v.length() - field);
            bins |= 1 << face(&v);
        }
        let residual = real::sqrt(rss / self.samples() as Real);
        let coverage = bins.count_ones() as f32 / COVERAGE_BINS as f32;
        if !(residual <= limits.max_residual_ut as Real) {
            return Err(Error::MagFitPoor { residual_ut: residual as f32, limit_ut: limits.max_residual_ut });
        }
        if !(coverage >= MIN_COVERAGE) {
            return Err(Error::MagCoverageThin { coverage, need: MIN_COVERAGE });
        }
        Ok(MagCal {
            a: core::array::from_fn(|i| core::array::from_fn(|j| a[(i, j)] as f32)),
            offset_ut: [o[0] as f32, o[1] as f32, o[2] as f32],
            field_ut: field as f32,
            sigma_field_ut: sigma_field as f32,
            dip_deg: dip.to_degrees() as f32,
            sigma_dip_deg: sigma_dip.to_degrees() as f32,
            alignment_deg: angle.to_degrees() as f32,
            sigma_alignment_deg: sigma_align.to_degrees() as f32,
            residual_ut: residual as f32,
            coverage,
            samples: self.samples() as u16,
            poses: self.poses.len() as u8,
        })
    }

    /// `cal` (from [`Self::solve`]) with its alignment refined by the gyro's rotations between
    /// the poses beside the gravity–field angle: `û_from = R û_to` for every move, i.e.
    /// `û_i − R û_j + (R [û_j]× − [û_i]×) θ = 0` with the angle rows of [`Self::solve`]
    /// (re-linearised, three steps). The rotation about the field's own direction, which the
    /// angle leaves weakest, is what the moves add. Hard and soft iron, field and residual stay.
    pub fn refine(&self, cal: &MagCal, moves: &[MagMove]) -> Result<MagCal, Error> {
        let (rot, sol) = self.refine_steps(cal, moves, Matrix3::identity(), REFINE_STEPS)?;
        Ok(self.refined(cal, &rot, &sol))
    }

    /// [`Self::refine`] in parts (for a caller that runs each in a call of its own): `steps`
    /// (≥ 1) of its [`REFINE_STEPS`] from the die's rotation `rot` (the identity at first);
    /// the rotation and the last step's fit. [`Self::refined`] is the result.
    pub fn refine_steps(&self, cal: &MagCal, moves: &[MagMove], mut rot: Matrix3<Real>, steps: usize) -> Result<Alignment, Error> {
        let (a0, o) = (mat_to_real(&cal.a), to_real(cal.offset_ut));
        let n = self.poses.len();
        let mut sol = None;
        for _ in 0..steps {
            let a = rot * a0;
            let u = |i: usize| -> Vector3<Real> { (a * (to_real(self.poses[i].1) - o)).unit() };
            let mut ne = NormalEquations::<4>::new();
            self.angle_rows(&mut ne, &a, &o, None)?;
            for m in moves.iter().filter(|m| (m.from as usize) < n && (m.to as usize) < n) {
                let (ui, uj, r) = (u(m.from as usize), u(m.to as usize), mat_to_real(&m.r));
                let res = ui - r * uj;
                let h = r * uj.cross_matrix() - ui.cross_matrix();
                for row in 0..3 {
                    ne.add_row(&[h[(row, 0)], h[(row, 1)], h[(row, 2)], 0.0], -res[row], 1.0)?;
                }
            }
            let s = ne.solve()?;
            rot = cayley(&Vector3::new(s.x[0], s.x[1], s.x[2])) * rot;
            sol = Some(s);
        }
        Ok((rot, sol.ok_or(Error::MagFitFailed)?))
    }

    /// [`Self::refine`]'s result: `cal` with the die's rotation `rot` and the fit `sol` of
    /// [`Self::refine_steps`].
    pub fn refined(&self, cal: &MagCal, rot: &Matrix3<Real>, sol: &Solution<4>) -> MagCal {
        let a = rot * mat_to_real(&cal.a);
        // The die's rotation: A's polar factor, A (AᵀA)^(−1/2).
        let ata = a.transpose() * a;
        let m: [[Real; 3]; 3] = core::array::from_fn(|i| core::array::from_fn(|j| ata[(i, j)]));
        let (vals, vecs) = sym_eigen(&m);
        let v = Matrix3::from_fn(|r, k| vecs[r][k]);
        let inv_sqrt = v * Matrix3::from_diagonal(&Vector3::from_fn(|i, _| 1.0 / real::sqrt(vals[i].max(1e-12)))) * v.transpose();
        let c = sol.x[3];
        MagCal {
            a: core::array::from_fn(|i| core::array::from_fn(|j| a[(i, j)] as f32)),
            dip_deg: asin(-c).to_degrees() as f32,
            sigma_dip_deg: (sol.sigma(3) / real::sqrt((1.0 - c * c).max(1e-6))).to_degrees() as f32,
            alignment_deg: angle_of(&(a * inv_sqrt)).to_degrees() as f32,
            sigma_alignment_deg: (0..3).map(|i| sol.sigma(i)).fold(0.0, Real::max).to_degrees() as f32,
            ..*cal
        }
    }

    /// The error of pose `k` when the others, fitted without it and its readings, agree.
    fn blame(&self, k: usize, limits: &MagLimits) -> Option<Error> {
        let p = self.poses[k];
        let (a_s, o, field) = self.fit_ellipsoid_without(Some(p.1)).ok()?;
        let (r, sol) = self.align(&a_s, &o, Some(k)).ok()?;
        let dip = asin(-sol.x[3]);
        self.check_poses(&(r * a_s), &o, field, dip, Some(k), limits).ok()?;
        let (b, pose_dip) = field_and_dip(&to_real(p.0), &(r * a_s * (to_real(p.1) - o)));
        check(k as u8, b, pose_dip, field, dip, limits).err()
    }

    /// The die's rotation `R` and the fit (`x[3]` = `−sin(dip)`) from the gravity–field angle
    /// of the poses (`skip` left out): `f̂ · (I + [θ]×) û = c`, i.e. `f̂·û + θ·(û × f̂) = c`,
    /// re-linearised about the last `R` (three steps).
    fn align(&self, a_s: &Matrix3<Real>, o: &Vector3<Real>, skip: Option<usize>) -> Result<Alignment, Error> {
        let mut r = Matrix3::identity();
        let mut sol = None;
        for _ in 0..3 {
            let mut ne = NormalEquations::<4>::new();
            self.angle_rows(&mut ne, &(r * a_s), o, skip)?;
            let s = ne.solve()?;
            r = cayley(&Vector3::new(s.x[0], s.x[1], s.x[2])) * r;
            sol = Some(s);
        }
        Ok((r, sol.ok_or(Error::MagFitFailed)?))
    }

    /// The gravity–field angle's rows of the poses (but `skip`) through `a`, `o`, linearised in
    /// the rotation `θ` of [`Self::align`]: `f̂·û + θ·(û × f̂) = c`.
    #[inline(never)]
    fn angle_rows(&self, ne: &mut NormalEquations<4>, a: &Matrix3<Real>, o: &Vector3<Real>, skip: Option<usize>) -> Result<(), Error> {
        for (_, p) in self.poses.iter().enumerate().filter(|(i, _)| Some(*i) != skip) {
            let (f, u) = (to_real(p.0).unit(), (a * (to_real(p.1) - o)).unit());
            let x = u.cross(&f);
            ne.add_row(&[x[0], x[1], x[2], -1.0], -f.dot(&u), 1.0)?;
        }
        Ok(())
    }

    /// Every pose (but `skip`) sees `field` (µT) at `dip` (rad) through `a`, `o`, within
    /// `limits`; else the error of the one furthest from them.
    fn check_poses(
        &self,
        a: &Matrix3<Real>,
        o: &Vector3<Real>,
        field: Real,
        dip: Real,
        skip: Option<usize>,
        limits: &MagLimits,
    ) -> Result<(), Error> {
        let mut worst: Option<(Real, Error)> = None;
        for (i, p) in self.poses.iter().enumerate().filter(|(i, _)| Some(*i) != skip) {
            let (b, pose_dip) = field_and_dip(&to_real(p.0), &(a * (to_real(p.1) - o)));
            if let Err(e) = check(i as u8, b, pose_dip, field, dip, limits) {
                let far = ((b - field) / limits.max_field_dev_ut as Real)
                    .abs()
                    .max(((pose_dip - dip).to_degrees() / limits.max_dip_dev_deg as Real).abs());
                if worst.as_ref().is_none_or(|w| far > w.0) {
                    worst = Some((far, e));
                }
            }
        }
        worst.map_or(Ok(()), |(_, e)| Err(e))
    }
}

/// The ellipsoid's map onto the sphere: `A_s` (symmetric, scaled to the field), its centre
/// (µT, raw: the hard iron) and the field's strength `B` (µT, the radii's geometric mean).
pub type Ellipsoid = (Matrix3<Real>, Vector3<Real>, Real);

/// The die's rotation `R` onto the accelerometer and the fit of the gravity–field angle
/// (`x[3]` = `−sin(dip)`).
pub type Alignment = (Matrix3<Real>, Solution<4>);

/// [`MagCalibrator::fit_ellipsoid`]'s last part: the ellipsoid from the quadric's rows `ne`
/// about `c` ([`MagCalibrator::add_ellipsoid_rows`]).
pub fn ellipsoid_from(ne: &NormalEquations<9>, c: &Vector3<Real>) -> Result<Ellipsoid, Error> {
    // The parameters alone (no condition number: a 9×9 eigen-decomposition costs ~2 M
    // instructions on the MCU); a degenerate spread fails the eigenvalue and coverage checks.
    let q = ne.estimate()?;
    let shape = Matrix3::new(q[0], q[3], q[4], q[3], q[1], q[5], q[4], q[5], q[2]);
    let inv = inverse3(&shape).ok_or(Error::Singular)?;
    let centre = -0.5 * inv * Vector3::new(q[6], q[7], q[8]);
    let s = 1.0 + centre.dot(&(shape * centre));
    if !(s > 0.0) {
        return Err(Error::MagFitFailed);
    }
    let p = shape / s;
    let (vals, vecs) =
        sym_eigen(&[[p[(0, 0)], p[(0, 1)], p[(0, 2)]], [p[(1, 0)], p[(1, 1)], p[(1, 2)]], [p[(2, 0)], p[(2, 1)], p[(2, 2)]]]);
    if !vals.iter().all(|v| *v > 0.0) {
        return Err(Error::MagFitFailed);
    }
    // A_s = √P maps the (scaled) ellipsoid to the unit sphere; B = the radii's geometric mean.
    let v = Matrix3::from_fn(|r, k| vecs[r][k]);
    let sqrt = v * Matrix3::from_diagonal(&Vector3::from_fn(|i, _| real::sqrt(vals[i]))) * v.transpose();
    let field = 50.0 / crate::math::linalg::cbrt(real::sqrt(vals[0] * vals[1] * vals[2]));
    let a_s = sqrt * (field / 50.0);
    Ok((a_s, c + centre * 50.0, field))
}

/// Tilt-compensated heading (°, 0..360, clockwise from magnetic north seen from above) of the
/// body's x axis, from the specific force `f` (g, up) and the field `m` (µT), both in the body
/// frame. `None` when the field is parallel to gravity.
pub fn heading_deg(f: Vector3<Real>, m: Vector3<Real>) -> Option<Real> {
    let up = f.try_unit(1e-9)?;
    let north = (m - up * m.dot(&up)).try_unit(1e-9)?;
    let east = north.cross(&up);
    let h = crate::math::trig::atan2(east[0], north[0]).to_degrees();
    Some(if h < 0.0 { h + 360.0 } else { h })
}

fn dist(a: &[f32; 3], b: &[f32; 3]) -> f32 {
    crate::math::vec3::sqrtf((0..3).map(|i| (a[i] - b[i]) * (a[i] - b[i])).sum())
}

/// The icosahedron's face centres ([`face`]): the dodecahedron's vertices, `(±1, ±1, ±1)` and
/// the cyclic permutations of `(0, ±1/φ, ±φ)`, each of length √3.
const FACE_CENTRES: [[f32; 3]; COVERAGE_BINS] = {
    let (phi, iphi) = (1.618_034_f32, 0.618_034_f32);
    const fn sign(s: usize, bit: u32) -> f32 {
        if s & (1 << bit) != 0 {
            -1.0
        } else {
            1.0
        }
    }
    let mut centres = [[0.0f32; 3]; COVERAGE_BINS];
    let mut s = 0;
    while s < 8 {
        centres[s] = [sign(s, 0), sign(s, 1), sign(s, 2)];
        s += 1;
    }
    let mut s = 0;
    while s < 4 {
        let (a, b) = (sign(s, 0) * iphi, sign(s, 1) * phi);
        let k = 8 + 3 * s;
        (centres[k], centres[k + 1], centres[k + 2]) = ([0.0, a, b], [a, b, 0.0], [b, 0.0, a]);
        s += 1;
    }
    centres
};

/// The icosahedron face (0..20) nearest to direction `v`: the largest dot product with a face
/// centre (single precision: a coverage bin, on the FPU).
fn face(v: &Vector3<Real>) -> u32 {
    let v = [v[0] as f32, v[1] as f32, v[2] as f32];
    let dot = |c: &[f32; 3]| c[0] * v[0] + c[1] * v[1] + c[2] * v[2];
    let mut best = (0, f32::NEG_INFINITY);
    for (k, c) in FACE_CENTRES.iter().enumerate() {
        let d = dot(c);
        if d > best.1 {
            best = (k as u32, d);
        }
    }
    best.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::test_noise::Gaussian;
    use nalgebra::{Rotation3, UnitQuaternion};

    /// A magnetometer: `m_raw = S b_B + h`, `S` soft iron times a 1.5° die rotation.
    struct Part {
        s: Matrix3<Real>,
        h: Vector3<Real>,
        field_w: Vector3<Real>,
    }

    impl Part {
        fn new() -> Self {
            let soft = Matrix3::new(1.04, 0.02, -0.01, 0.02, 0.97, 0.015, -0.01, 0.015, 1.01);
            let die = Rotation3::new(Vector3::new(0.8, -1.0, 0.6).normalize() * (1.5 as Real).to_radians()).into_inner();
            let dip = (62 as Real).to_radians();
            Self { s: soft * die, h: Vector3::new(20.0, -35.0, 12.0), field_w: Vector3::new(libm::cos(dip), 0.0, -libm::sin(dip)) * 48.0 }
        }

        /// (specific force in B (g), raw field (µT)) at attitude `q` (body → world, z up).
        fn read(&self, q: &UnitQuaternion<Real>, noise: &mut Gaussian, sigma_ut: Real) -> (Vector3<Real>, [f32; 3]) {
            let m = self.s * (q.inverse() * self.field_w) + self.h + Vector3::from_fn(|_, _| sigma_ut * noise.next());
            (q.inverse() * Vector3::z(), [m[0] as f32, m[1] as f32, m[2] as f32])
        }
    }

    fn random_attitude(g: &mut Gaussian) -> UnitQuaternion<Real> {
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(g.next(), g.next(), g.next(), g.next()))
    }

    /// A hand-held step: 12 poses, held 40 samples each, and 30 samples along each move between.
    fn session(part: &Part, disturb_pose: Option<usize>) -> MagCalibrator {
        let mut g = Gaussian::new(0x5eed_1234_abcd_0001);
        let mut c = MagCalibrator::new();
        let poses: [UnitQuaternion<Real>; 12] = core::array::from_fn(|_| random_attitude(&mut g));
        for (i, q) in poses.iter().enumerate() {
            let extra = if disturb_pose == Some(i) { Vector3::new(8.0, 0.0, 0.0) } else { Vector3::zeros() };
            let (mut fsum, mut msum) = (Vector3::zeros(), Vector3::zeros());
            for _ in 0..40 {
                let (f, m) = part.read(q, &mut g, 0.3);
                let m = to_real(m) + extra;
                c.add_sample([m[0] as f32, m[1] as f32, m[2] as f32]).unwrap();
                (fsum, msum) = (fsum + f, msum + m);
            }
            let (f, m) = (fsum / 40.0, msum / 40.0);
            c.add_pose([f[0] as f32, f[1] as f32, f[2] as f32], [m[0] as f32, m[1] as f32, m[2] as f32]).unwrap();
            if let Some(next) = poses.get(i + 1) {
                for k in 0..30 {
                    let (_, m) = part.read(&q.slerp(next, k as Real / 30.0), &mut g, 0.3);
                    c.add_sample(m).unwrap();
                }
            }
        }
        c
    }

    /// (RMS, largest) tilt-compensated heading error (°) over random attitudes of field `a`,
    /// offset `o` against the truth.
    fn heading_error(part: &Part, a: &Matrix3<Real>, o: &Vector3<Real>) -> (Real, Real) {
        let mut g = Gaussian::new(0x0dd_ba11);
        let (mut ss, mut max) = (0.0, 0.0 as Real);
        for _ in 0..500 {
            let q = random_attitude(&mut g);
            let (f, m) = part.read(&q, &mut g, 0.0);
            let truth = heading_deg(f, q.inverse() * part.field_w).unwrap();
            let est = heading_deg(f, a * (to_real(m) - o)).unwrap();
            let e = (est - truth + 540.0) % 360.0 - 180.0;
            ss += e * e;
            max = max.max(e.abs());
        }
        (libm::sqrt(ss / 500.0), max)
    }

    #[test]
    fn the_gyro_s_rotations_between_poses_refine_the_alignment() {
        let part = Part::new();
        let c = session(&part, None);
        let cal = c.solve(&MagLimits::default()).unwrap();
        // The session's poses (its first draws) and the moves between them as an exact gyro
        // would measure them: body at the next pose to body at this one.
        let mut g = Gaussian::new(0x5eed_1234_abcd_0001);
        let poses: [UnitQuaternion<Real>; 12] = core::array::from_fn(|_| random_attitude(&mut g));
        let moves: [MagMove; 11] = core::array::from_fn(|i| {
            let r = (poses[i].inverse() * poses[i + 1]).to_rotation_matrix().into_inner();
            MagMove { from: i as u8, to: i as u8 + 1, r: core::array::from_fn(|a| core::array::from_fn(|b| r[(a, b)] as f32)) }
        });
        let refined = c.refine(&cal, &moves).unwrap();
        let o = to_real(cal.offset_ut);
        let (before, _) = heading_error(&part, &mat_to_real(&cal.a), &o);
        let (after, max) = heading_error(&part, &mat_to_real(&refined.a), &o);
        assert!(after <= before * 1.05 && after < 0.2 && max < 0.6, "{before:.3} -> {after:.3} deg RMS ({max:.3} max)");
        assert!((refined.alignment_deg - 1.5).abs() < 0.3, "die {} deg", refined.alignment_deg);
        assert!(refined.sigma_alignment_deg < cal.sigma_alignment_deg, "{} vs {}", refined.sigma_alignment_deg, cal.sigma_alignment_deg);
        assert_eq!((refined.field_ut, refined.offset_ut, refined.residual_ut), (cal.field_ut, cal.offset_ut, cal.residual_ut));
        // Without moves: the angle alone again.
        let alone = c.refine(&cal, &[]).unwrap();
        assert!((alone.alignment_deg - cal.alignment_deg).abs() < 0.01 && (alone.dip_deg - cal.dip_deg).abs() < 0.01);
    }

    #[test]
    fn hard_soft_iron_and_the_die_rotation_are_found() {
        let part = Part::new();
        let c = session(&part, None);
        let cal = c.solve(&MagLimits::default()).unwrap();
        let a = mat_to_real(&cal.a);
        let o = to_real(cal.offset_ut);
        assert!((o - part.h).norm() < 0.3, "offset {o} vs {}", part.h);
        assert!((cal.field_ut - 48.0 * 1.0).abs() < 1.5, "{cal:?}");
        assert!((cal.dip_deg - 62.0).abs() < 3.0 * cal.sigma_dip_deg.max(0.05), "{cal:?}");
        assert!((cal.alignment_deg - 1.5).abs() < 0.5 && cal.coverage >= 0.6, "{cal:?}");
        let (rms, max) = heading_error(&part, &a, &o);
        let (a_s, o_s, _) = c.fit_ellipsoid().unwrap();
        let (rms_s, max_s) = heading_error(&part, &a_s, &o_s);
        assert!(rms < 0.3 && max < 1.0, "aligned: {rms:.3} RMS, {max:.3} max (ellipsoid only {rms_s:.3}, {max_s:.3})");
        assert!(rms_s > 3.0 * rms, "the ellipsoid alone leaves the die's rotation: {rms_s:.3} vs {rms:.3}");
    }

    #[test]
    fn a_magnet_near_one_pose_is_named() {
        let e = session(&Part::new(), Some(5)).solve(&MagLimits::default()).unwrap_err();
        assert!(matches!(e, Error::MagDisturbed { pose: 5, .. }), "{e:?}");
    }

    #[test]
    fn thin_coverage_and_too_few_samples_are_named() {
        let part = Part::new();
        let mut g = Gaussian::new(7);
        let mut c = MagCalibrator::new();
        assert!(matches!(c.solve(&MagLimits::default()), Err(Error::MagTooFew { samples: 0, .. })));
        // Turns about one vertical axis only: a ring, not a sphere.
        for k in 0..200 {
            let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), k as Real * 0.05);
            let (f, m) = part.read(&q, &mut g, 0.3);
            c.add_sample(m).unwrap();
            if k % 30 == 0 {
                c.add_pose([f[0] as f32, f[1] as f32, f[2] as f32], m).unwrap();
            }
        }
        let e = c.solve(&MagLimits::default()).unwrap_err();
        assert!(matches!(e, Error::Singular | Error::IllConditioned { .. } | Error::MagFitFailed | Error::MagCoverageThin { .. }), "{e:?}");
    }
}
