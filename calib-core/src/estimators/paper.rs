//! The paper's estimator (Li et al.; DESIGN §4.1): static poses `A_i` and the mean bias-free
//! gyro reading `ḡ` during a constant-rate spin at the known servo speed `ω_n`.
//!
//! Rows `x_i = A_i ∘ ḡ`, `X β̂ ≈ 1`, `K = L diag(β̂)`, `|L| = ω_n / ‖β̂ ∘ ḡ‖`, the sign of `L`
//! chosen so that `K` has a positive diagonal (β̂ alone cannot tell it).

use crate::estimators::axis::{GeometryLimits, Poses};
use crate::estimators::gyro::{GyroCal, GyroQuality, Method, SCALE_RANGE};
use crate::math::lsq::NormalEquations;
use crate::math::real::{self, Real};
use crate::math::stats::Spread;
use crate::math::vec3::Length;
use crate::{Error, Vec3};
use nalgebra::Vector3;

/// Smallest usable |ḡ| (°/s).
pub const MIN_RATE_DPS: f32 = 1.0;

/// Solves the paper's estimator.
///
/// `poses`: calibrated static accelerations (g); `gbar_dps`: mean bias-free gyro (°/s, B) over
/// the constant-rate spin; `omega_n_dps`: the servo speed believed to produce it (°/s).
pub fn solve(poses: &Poses, gbar_dps: Vec3, omega_n_dps: f32, limits: &GeometryLimits) -> Result<GyroCal, Error> {
    if !(gbar_dps.iter().all(|v| v.is_finite()) && omega_n_dps.is_finite()) {
        return Err(Error::NonFinite);
    }
    let geo = poses.geometry(limits, true)?;
    let g = Vector3::new(gbar_dps[0] as Real, gbar_dps[1] as Real, gbar_dps[2] as Real);
    let omega = (omega_n_dps as Real).abs();
    if g.length() < MIN_RATE_DPS as Real || omega < MIN_RATE_DPS as Real {
        return Err(Error::NoSpin { rate_dps: g.length().min(omega) as f32, min_dps: MIN_RATE_DPS });
    }
    // Σ A Aᵀ is accumulated from the poses, then scaled by ḡ: the rows A_i ∘ ḡ.
    let mut ne = NormalEquations::<3>::new();
    for a in poses.iter() {
        ne.add_row(&[a[0], a[1], a[2]], 1.0, 1.0)?;
    }
    let sol = ne.scaled(&[g[0], g[1], g[2]]).solve()?;
    let beta = Vector3::from(sol.x);
    let sign = if beta.sum() < 0.0 { -1.0 } else { 1.0 };
    let l = sign * omega / beta.component_mul(&g).length();
    let k = beta * l;
    for (axis, &v) in k.iter().enumerate() {
        if !(v > SCALE_RANGE.0 && v < SCALE_RANGE.1) {
            return Err(Error::ImplausibleScale { axis: axis as u8, value: v as f32 });
        }
    }
    let kg = k.component_mul(&g);
    let rows = poses.len() as Real;
    let quality = GyroQuality {
        invariant_before: Spread::of(&mut poses.iter().map(|a| a.dot(&g))),
        invariant_after: Spread::of(&mut poses.iter().map(|a| a.dot(&kg))),
        sigma_k: core::array::from_fn(|i| (l.abs() * sol.sigma(i)) as f32),
        condition: sol.condition as f32,
        residual_rms: real::sqrt(sol.rss / rows) as f32,
        axis: geo.u.map(|v| v as f32).into(),
        tilt_deg: geo.tilt_deg as f32,
        span_deg: geo.span_deg as f32,
        min_axis_component: geo.min_component as f32,
        plane_rms_g: geo.plane_rms_g as f32,
        poses: poses.len() as u8,
        rows: poses.len() as u16,
    };
    let mut km = [[0.0f32; 3]; 3];
    for i in 0..3 {
        km[i][i] = k[i] as f32;
    }
    Ok(GyroCal { k: km, method: Method::Paper, quality })
}
