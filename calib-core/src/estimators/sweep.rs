//! The speed-free sweep estimator (DESIGN §4.2): over a move from pose `i` to pose `j`,
//! `K Γ = Δθ u`, with `Γ = ∫ (g − b) dt` from the MCU clock, `u` the normal of the plane of the
//! pose accelerations and `Δθ` the turn read from the accelerometer. No servo speed, no constant
//! rate; back-and-forth moves cancel a residual bias.

use crate::estimators::axis::{turn_deg, unwrap_near, GeometryLimits, Poses};
use crate::estimators::bias::RestBias;
use crate::estimators::gyro::{GyroCal, GyroQuality, Method, SCALE_RANGE};
use crate::math::lsq::NormalEquations;
use crate::math::real::{self, Real};
use crate::math::stats::Spread;
use crate::{Error, Time, Vec3};
use nalgebra::Vector3;

/// Largest number of moves kept.
pub const MAX_MOVES: usize = 64;
/// Moves that turn the shaft less than this (°) are not used.
pub const MIN_MOVE_DEG: Real = 10.0;

/// Trapezoidal integral of the bias-free gyro over one move (°, sensor frame).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Integrator {
    /// `Σ ½ (ω_{k−1} + ω_k) Δt` (°) in f32 on the FPU, Kahan-compensated (`lost`: what the last
    /// addition rounded away): a 100 000-sample move at 952 Hz stays within 1e-8 of the f64 sum,
    /// where a plain f32 sum is off by 6e-6 (`precision.rs`), and no software double
    /// is spent per sample.
    gamma: [f32; 3],
    lost: [f32; 3],
    t_first: Time,
    last: Option<(Time, [f32; 3])>,
    samples: u32,
}

impl Integrator {
    /// Empty: the next sample starts the move.
    pub const fn new() -> Self {
        Self { gamma: [0.0; 3], lost: [0.0; 3], t_first: Time::ZERO, last: None, samples: 0 }
    }

    /// Adds a sample: MCU time and bias-free gyro `g − b` (°/s). Out-of-order samples are ignored.
    pub fn add(&mut self, t: Time, g: Vec3) {
        if let Some((t0, g0)) = self.last {
            if t <= t0 {
                return;
            }
            let dt = t.since(t0) as f32;
            for k in 0..3 {
                // Kahan: the term less what the sum lost last time; what this addition loses.
                let term = 0.5 * (g0[k] + g[k]) * dt - self.lost[k];
                let next = self.gamma[k] + term;
                self.lost[k] = (next - self.gamma[k]) - term;
                self.gamma[k] = next;
            }
        } else {
            self.t_first = t;
        }
        self.last = Some((t, g));
        self.samples += 1;
    }

    /// `Γ` so far (°).
    pub fn gamma(&self) -> [Real; 3] {
        core::array::from_fn(|k| self.gamma[k] as Real - self.lost[k] as Real)
    }

    /// `Γ` so far less the residual bias tracked between the rests `from` and `to` that bound
    /// the move (°).
    pub fn gamma_tracked(&self, from: &RestBias, to: &RestBias) -> [Real; 3] {
        let t_last = self.last.map_or(self.t_first, |(t, _)| t);
        let (gamma, drift) = (self.gamma(), from.integral_deg(to, self.t_first, t_last));
        core::array::from_fn(|k| gamma[k] - drift[k])
    }

    /// Samples integrated.
    pub fn samples(&self) -> u32 {
        self.samples
    }
}

/// One move between two recorded poses.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Move {
    /// Index of the start pose.
    pub from: u8,
    /// Index of the end pose.
    pub to: u8,
    /// `Γ = ∫ (g − b) dt` over the move (°).
    pub gamma_deg: [Real; 3],
}

/// The moves of a sweep session (bounded, no heap).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Moves {
    moves: heapless::Vec<Move, MAX_MOVES>,
}

impl Moves {
    /// No moves.
    pub const fn new() -> Self {
        Self { moves: heapless::Vec::new() }
    }

    /// Number of moves.
    pub fn len(&self) -> usize {
        self.moves.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.moves.is_empty()
    }

    /// Forgets every move.
    pub fn clear(&mut self) {
        self.moves.clear();
    }

    /// Records a move from pose `from` to pose `to` with its gyro integral.
    // Not inlined: the pan/tilt plan's copy from its full-K moves (`load_setting`) would be a
    // `memmove` (LLVM cannot prove the two stores apart), which links compiler_builtins'
    // 1.5 KiB memmove into that build.
    #[inline(never)]
    pub fn push(&mut self, from: u8, to: u8, gamma_deg: [Real; 3]) -> Result<(), Error> {
        if !gamma_deg.iter().all(|v| v.is_finite()) {
            return Err(Error::NonFinite);
        }
        self.moves.push(Move { from, to, gamma_deg }).map_err(|_| Error::CapacityExceeded { max: MAX_MOVES as u8 })
    }

    /// The moves.
    pub fn as_slice(&self) -> &[Move] {
        &self.moves
    }
}

/// Solves `K Γ = Δθ u` (diagonal `K`) over all moves whose poses exist and turn ≥ `MIN_MOVE_DEG`.
pub fn solve(poses: &Poses, moves: &Moves, limits: &GeometryLimits) -> Result<GyroCal, Error> {
    let geo = poses.geometry(limits, false)?;
    let u = geo.u;
    let mut ne = NormalEquations::<3>::new();
    let mut used = 0u16;
    // (start-pose acceleration, Γ, Δθ) of each used move, recomputed below for the invariant.
    let usable = |m: &Move| -> Option<(Vector3<Real>, Vector3<Real>, Real)> {
        let n = poses.len();
        if m.from as usize >= n || m.to as usize >= n {
            return None;
        }
        let gamma = Vector3::from(m.gamma_deg);
        let (a, b) = (poses.get(m.from as usize), poses.get(m.to as usize));
        let dtheta = unwrap_near(turn_deg(&u, &a, &b), gamma.dot(&u));
        (dtheta.abs() >= MIN_MOVE_DEG).then_some((a, gamma, dtheta))
    };
    for (_, gamma, dtheta) in moves.as_slice().iter().filter_map(usable) {
        for k in 0..3 {
            let mut x = [0.0; 3];
            x[k] = gamma[k];
            ne.add_row(&x, dtheta * u[k], 1.0)?;
        }
        used += 1;
    }
    if used == 0 {
        return Err(Error::NoUsableMove);
    }
    let sol = ne.solve()?;
    let k = Vector3::from(sol.x);
    for (axis, &v) in k.iter().enumerate() {
        if !(v > SCALE_RANGE.0 && v < SCALE_RANGE.1) {
            return Err(Error::ImplausibleScale { axis: axis as u8, value: v as f32 });
        }
    }
    let invariant = |kk: Vector3<Real>| {
        Spread::of(&mut moves.as_slice().iter().filter_map(usable).map(|(a, g, dth)| a.dot(&kk.component_mul(&g)) / dth))
    };
    let quality = GyroQuality {
        invariant_before: invariant(Vector3::repeat(1.0)),
        invariant_after: invariant(k),
        sigma_k: core::array::from_fn(|i| sol.sigma(i) as f32),
        condition: sol.condition as f32,
        residual_rms: real::sqrt(sol.rss / ne.rows() as Real) as f32,
        axis: u.map(|v| v as f32).into(),
        tilt_deg: geo.tilt_deg as f32,
        span_deg: geo.span_deg as f32,
        min_axis_component: geo.min_component as f32,
        plane_rms_g: geo.plane_rms_g as f32,
        poses: poses.len() as u8,
        rows: used,
    };
    let mut km = [[0.0f32; 3]; 3];
    for i in 0..3 {
        km[i][i] = k[i] as f32;
    }
    Ok(GyroCal { k: km, method: Method::Sweep, quality })
}
