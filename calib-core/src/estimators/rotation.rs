//! Rotation constraints on the full `K` (DESIGN §4.2): every move between two static poses, e.g.
//! a hand-held one, turns the gravity direction seen at the start into the one seen at the end.
//! With `ω = K (g − b)` integrated over the move to the rotation `R(K)` (end body → start body),
//! `R g_j = g_i`: two equations per move (the turn about gravity is unseen), nonlinear in `K`.
//!
//! Streaming and bounded: a move is kept as chunks of at most [`CHUNK_DEG`] of raw turn, each its
//! bias-free gyro integral `Γ_c = ∫ w dt` (°) and its coning integral `β_c = ½ ∫ Γ(t) × w dt`
//! (°², `Γ(t)` the chunk's integral so far). At any `K` a chunk's rotation vector is
//! `φ_c = K Γ_c + det(K) K⁻ᵀ β_c` (exact for the cross product,
//! `(K a) × (K b) = det K · K⁻ᵀ (a × b)`; the Bortz vector to second order, `φ̇ = ω + ½ φ × ω`),
//! and `R = Π_c Exp(φ_c)`. So the rotation is re-composed at every Gauss–Newton iterate: the
//! result does not depend on where the iteration starts (no linearisation point is kept), and
//! the memory is [`MAX_CHUNKS`] chunks of 32 bytes.
//!
//! Jacobian (vec `K` column-major, [`crate::estimators::full::vec_index`]): composing
//! `J ← Exp(φ_c)ᵀ J + J_r(φ_c) (Γ_cᵀ ⊗ I)` (the preintegration recursion; the coning term's small
//! derivative is left out, which slows Gauss–Newton a little but does not move its fixed point)
//! gives `R(K + δK) ≈ R Exp(J δk)`. In the tangent basis `(e₁, e₂)` of `g_i` the residual is
//! `r_k = e_kᵀ R g_j` with the row `∂r_k/∂k = −e_kᵀ R [g_j]× J`.
//!
//! Bias: each chunk loses the residual bias tracked between the rests that bound its move
//! ([`RestBias::integral_deg`], when the move ends); the coning integrals keep the reference
//! bias (a 0.01 °/s error there is ≈ 1e-7 rad per chunk).
//!
//! Noise (1σ per row, rad): `σ² = σ_i² + σ_j² + σ_Γ²`, `σ_i` the direction noise of pose `i`
//! (its mean's noise per component over `|f|`), `σ_Γ` the gyro integral's noise over one move.
//!
//! The Earth's rate (DESIGN §4.5): a hand-held pose too shaky to measure the bias takes it from
//! the rests, which hold the Earth's rate in *their* poses' frames, so a move's integral keeps
//! `ε = Ω G w` (rad, in its start pose's frame): `w` the Earth's rate in the frame of the first
//! rest over its magnitude `Ω`, `G = Δt Aᵢᵀ − P Mᵢ − Q Mⱼ` (s) with `A` a pose's attitude in that
//! frame ([`Rotations::push_attitude`]), `M` the part of its bias that is Earth's rate
//! ([`Rotations::settle_bias`]), `P`, `Q` the move's bias weights rotated into its start frame.
//! Up to `Ω` × 4 s ≈ 0.02° per move, 2e-4 of a 90° turn. `w` is estimated with the moves, its
//! prior `N(0, I/3)` per component (`|w| = 1`), and marginalised out of the normal equations of
//! `K` (their σ includes it); poses without an attitude (a log, a lost track) add no such term.

use crate::estimators::accel::AccelCal;
use crate::estimators::axis::Poses;
use crate::estimators::bias::RestBias;
use crate::estimators::gyro::SCALE_RANGE;
use crate::math::linalg::{cofactor, sym_eigen};
use crate::math::lsq::NormalEquations;
use crate::math::real::{self, sq, widen, Real, Scalar, Sum};
use crate::math::vec3::Length;
use crate::math::vec3::{sqrtf, tangent_basis, to_real as v64};
use crate::{Error, Mat3, Time, Vec3};
use nalgebra::{Matrix3, Vector3};

/// Rotation moves kept.
pub const MAX_ROTATION_MOVES: usize = 24;
/// Poses the moves run between, with their rests (48 B each): the firmware's hand-held step
/// holds up to `Config::max_hand_poses` (20 by default) and ends when the store is full; a power
/// of two, so that an index wraps without a division.
pub const MAX_ROTATION_POSES: usize = 32;
/// Chunks of all moves together (32 B each): 432 of the gyro's (a 180° hand move takes ≈ 35;
/// with 384, one drifting one-servo run in seven of drift-bench's ran out before its hand-held
/// goal; with 416, rotation-bench's free hand lost moves for room in the firmware's runs,
/// 1.28e-4 RMS of E instead of 1.22e-4), and each kept move's two turns inside its poses
/// ([`PoseRest::rise_deg`]).
pub const MAX_CHUNKS: usize = 432 + 2 * MAX_ROTATION_MOVES;
/// Poses whose attitude is kept for the Earth's rate ([`Rotations::push_attitude`]): the
/// firmware's hand-held step has up to 20 (`Config::max_hand_poses`); later poses' moves go
/// without the Earth's term.
pub const EARTH_POSES: usize = 20;
/// The Earth's rate (rad/s).
pub const EARTH_RATE_RAD_S: Real = 7.292_115e-5;

/// A chunk closes once its raw turn reaches this (°): the neglected third-order term is then
/// below 1e-5 rad per chunk (`precision.rs`: a 540° move with coning at 952 Hz composes to
/// within 1.6e-5 rad of its rotation integrated finely). Larger chunks were measured and not
/// kept: at 7.5° that move is 3.8e-5 rad off but a drifting bias's E grows past its tests'
/// bounds (6.3e-6, settled predictions 2.5e-5), at 6° the move is 6.8e-5 rad off.
pub const CHUNK_DEG: Real = 5.0;

/// Requirements of the rotation constraints.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RotationLimits {
    /// Moves that turn less than this (°, raw `|Σ Γ_c|` or the gravity angle) are not used.
    pub min_move_deg: f32,
    /// Largest raw turn between two samples (°): beyond it (fewer than 3 samples per radian) the
    /// rate between two samples is not known well enough to integrate. Below it a fast move is
    /// integrated, its third-order error carried in its weight ([`RotationMove::int_sigma_rad`]).
    pub max_step_deg: f32,
    /// Largest change of the bias-free gyro mean between the two poses of a move (°/s): beyond it
    /// the bias drifted over the move.
    pub max_bias_change_dps: f32,
    /// Smallest eigenvalue (of 1) of the mean `n nᵀ` of the moves' rotation axes: below it the
    /// moves do not turn about three dimensions.
    pub min_axis_spread: f32,
    /// 1σ of a move's gyro integral per component (°).
    pub gamma_sigma_deg: f32,
    /// Floor of a pose's direction noise (rad).
    pub min_direction_sigma: f32,
    /// Largest RMS residual of the rotation rows (°): a slip, a pose that moved, a wrong
    /// column. Real hand-held sessions leave 0.2–0.4° (an accelerometer misalignment that poses
    /// on six faces cannot show, a hand's sway); their scatter widens `K`'s 1σ, which the
    /// acceptance bounds.
    pub max_residual_rms_deg: f32,
    /// A move whose end poses see gravity within this angle (°) of each other and whose raw turn
    /// lies within it of gravity is a turn about the vertical (e.g. on a table): the
    /// accelerometer cannot see its angle, only its axis.
    pub vertical_deg: f32,
    /// 1σ of a vertical turn's axis against the gravity of its poses (°): a table's tilt, a
    /// hand's wobble.
    pub vertical_axis_sigma_deg: f32,
    /// The user says every vertical turn is a whole number of revolutions (the Ferraris
    /// protocol's 360° turns): its angle is known too, `N · 360°` with `N` the raw turn rounded.
    pub whole_turns: bool,
    /// Longest time between two samples of a move (s): over a longer hole the board may have
    /// turned unseen.
    pub max_gap_s: f32,
}

impl RotationLimits {
    /// The defaults (also as `Default`).
    pub const DEFAULT: RotationLimits = RotationLimits {
        min_move_deg: 15.0,
        max_step_deg: 20.0,
        max_bias_change_dps: 0.2,
        min_axis_spread: 0.02,
        gamma_sigma_deg: 0.02,
        min_direction_sigma: 1e-5,
        max_residual_rms_deg: 1.0,
        vertical_deg: 15.0,
        vertical_axis_sigma_deg: 1.0,
        whole_turns: false,
        max_gap_s: 0.1,
    };
}

impl Default for RotationLimits {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Why a move was not kept (counted in [`Rotations::rejected`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Rejected {
    /// A sample reached the gyro's full scale.
    Saturated,
    /// A step between two samples turned more than `max_step_deg`.
    TooFast,
    /// The move turned less than `min_move_deg`.
    TooShort,
    /// The bias-free gyro mean differs between its two poses by more than `max_bias_change_dps`.
    BiasDrifted,
    /// No room for its chunks or for one more move.
    Full,
    /// Gravity turned between its two poses by far more than the gyro did (the log was cut
    /// between the poses, or the columns are not one sensor's).
    Unseen,
    /// Samples are missing from it ([`RotationLimits::max_gap_s`]): the board may have turned
    /// unseen (a log cut or a lost stretch of samples).
    Gap,
}

/// The number of [`Rejected`] reasons.
pub const REJECTED_REASONS: usize = 7;

impl Rejected {
    /// Every reason, in index order.
    pub const ALL: [Rejected; REJECTED_REASONS] = [
        Rejected::Saturated,
        Rejected::TooFast,
        Rejected::TooShort,
        Rejected::BiasDrifted,
        Rejected::Full,
        Rejected::Unseen,
        Rejected::Gap,
    ];

    /// Its name in reports and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Rejected::Saturated => "saturated",
            Rejected::TooFast => "too_fast",
            Rejected::TooShort => "too_short",
            Rejected::BiasDrifted => "bias_drifted",
            Rejected::Full => "no_room",
            Rejected::Unseen => "unseen",
            Rejected::Gap => "gap",
        }
    }

    /// What it means, for a person.
    pub fn describe(self) -> &'static str {
        match self {
            Rejected::Saturated => "the gyro reached its full scale",
            Rejected::TooFast => "it turned too far between two samples",
            Rejected::TooShort => "it turned too little",
            Rejected::BiasDrifted => "the gyro bias changed between its two poses",
            Rejected::Full => "no room for it",
            Rejected::Unseen => "gravity turned more than the gyro did",
            Rejected::Gap => "samples are missing from it",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Default)]
struct Chunk {
    gamma: [f32; 3],
    coning: [f32; 3],
    /// Its first and last sample times from the start of its move (s).
    span_s: [f32; 2],
}

/// One kept move between two poses.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct RotationMove {
    /// Start pose.
    pub from: u8,
    /// End pose.
    pub to: u8,
    first: u16,
    n: u16,
    /// Duration (s).
    pub duration_s: f32,
    /// Raw gyro turn `|Σ Γ_c|` (°).
    pub turn_deg: f32,
    /// A turn about the vertical ([`RotationLimits::vertical_deg`]): its rows constrain `K Γ`
    /// to gravity's direction (and with [`RotationLimits::whole_turns`] its length).
    pub vertical: bool,
    /// Estimated integration error of the move (rad): the third-order terms of the two-sample
    /// scheme, `Σ |d_{k−1} × d_k| |d_k| / 12` over its sample increments `d` (0 about a fixed axis).
    pub int_sigma_rad: f32,
    /// MCU time of its first sample: its chunks' spans count from it.
    t0: Time,
}

impl RotationMove {
    /// The chunks it is kept as: its cost in the solve ([`Rotations::add_rows_batch`]).
    pub fn chunks(&self) -> usize {
        self.n as usize
    }
}

/// The bias-free gyro turn inside a pose, `A = Σ ω Δt` and `C = Σ t ω Δt` (° and °·s, sensor
/// frame, MCU time), for the mean-instant integration of DESIGN §4.7: a pose's attitude is the
/// mean over its samples, so a move is integrated from the mean instant of one pose to that of
/// the next, i.e. over both poses weighted by a ramp. [`PoseTurn::rise_deg`] is the part inside
/// the pose (bounded sums, no buffer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseTurn {
    /// MCU time of its first sample (none yet): `c` is kept from it, so that f32 holds it.
    t0: Option<Time>,
    /// `A` (°) and `Σ (t − t0) ω Δt` (°·s): f32 on the FPU (a pose's turn is its sway, tenths
    /// of a degree, over seconds: rounding ~1e-8°).
    a: [f32; 3],
    c: [f32; 3],
}

impl PoseTurn {
    /// Nothing turned.
    pub const fn new() -> Self {
        Self { t0: None, a: [0.0; 3], c: [0.0; 3] }
    }

    /// A sample at MCU time `t`, `dt_s` (s) after the previous one, bias-free gyro (°/s).
    pub fn add(&mut self, t: Time, dt_s: Real, w_dps: Vec3) {
        if dt_s > 0.0 && dt_s.is_finite() {
            let t0 = *self.t0.get_or_insert(t);
            let (t, dt) = (t.since(t0) as f32, dt_s as f32);
            for k in 0..3 {
                let d = w_dps[k] * dt;
                self.a[k] += d;
                self.c[k] += t * d;
            }
        }
    }

    /// The turn of a later stretch added.
    pub fn merge(&mut self, o: &PoseTurn) {
        let (Some(t0), Some(o_t0)) = (self.t0, o.t0) else {
            if self.t0.is_none() {
                *self = *o;
            }
            return;
        };
        let shift = o_t0.since(t0) as f32;
        for k in 0..3 {
            self.a[k] += o.a[k];
            self.c[k] += o.c[k] + shift * o.a[k];
        }
    }

    /// `Σ ((t − t_first) / T) ω Δt` (°) over a pose from `t_first` to `t_last`: the turn from the
    /// pose's mean instant to its end. 0 for a pose of no length or no turn.
    pub fn rise_deg(&self, t_first: Time, t_last: Time) -> Vec3 {
        let span = t_last.since(t_first) as f32;
        let Some(t0) = self.t0.filter(|_| span > 0.0) else {
            return [0.0; 3];
        };
        let from = t_first.since(t0) as f32;
        core::array::from_fn(|k| (self.c[k] - from * self.a[k]) / span)
    }
}

impl Default for PoseTurn {
    fn default() -> Self {
        Self::new()
    }
}

/// A pose's rest as the moves see it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseRest {
    /// Its bias.
    pub bias: RestBias,
    /// The bias is a prediction until [`Rotations::settle_bias`].
    pub predicted: bool,
    /// Its turn from its mean instant to its end (°, sensor frame, less the reference bias:
    /// [`PoseTurn::rise_deg`]); zero when the moves are integrated from the mean instants by
    /// their samples' weights.
    pub rise_deg: Vec3,
    /// Its length (s).
    pub span_s: f32,
    /// A predicted bias's pose: its mean temperature (°C). Once [`Rotations::settle_bias`] puts
    /// the bias on the line between two rests, that temperature less the line between theirs: the
    /// warm-up a line in time misses ([`Rotations::follow_warmup`]). NaN for a measured bias, an
    /// unknown temperature, and after [`Rotations::follow_warmup`].
    pub warm_c: f32,
}

impl PoseRest {
    /// A measured bias of no time, no turn, no temperature.
    const NONE: Self = Self {
        bias: RestBias { t: Time::ZERO, residual_dps: [0.0; 3] },
        predicted: false,
        rise_deg: [0.0; 3],
        span_s: 0.0,
        warm_c: f32::NAN,
    };
}

impl Default for PoseRest {
    fn default() -> Self {
        Self::NONE
    }
}

impl From<RestBias> for PoseRest {
    fn from(bias: RestBias) -> Self {
        Self { bias, ..Self::NONE }
    }
}

/// The move being integrated.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Open {
    from: u8,
    first: usize,
    /// The open chunk's raw turn (°) and coning integral (°²): f32 on the FPU (a chunk turns at
    /// most [`CHUNK_DEG`], so its sums round at ~1e-6°; `precision.rs` bounds it).
    gamma: [f32; 3],
    coning: [f32; 3],
    last: Option<(Time, [f32; 3])>,
    t0: Time,
    chunk_t0: Time,
    /// The move's raw turn so far (°): its closed chunks' sums.
    total: [Real; 3],
    /// The square of its largest step (°²).
    max_step_deg: f32,
    /// The longest time between two of its samples (s).
    max_gap_s: f32,
    /// The previous sample increment (°) and the integration error so far (rad).
    step: [f32; 3],
    int_err: f32,
    why: Option<Rejected>,
}

/// The static poses and the chunked moves between them (bounded, no heap): up to `M` kept moves,
/// `C` chunks and `P` poses, the firmware's [`MAX_ROTATION_MOVES`], [`MAX_CHUNKS`] and
/// [`MAX_ROTATION_POSES`] unless a PC sizes them to a whole log.
#[derive(Debug, Clone, PartialEq)]
pub struct Rotations<const M: usize = MAX_ROTATION_MOVES, const C: usize = MAX_CHUNKS, const P: usize = MAX_ROTATION_POSES> {
    poses: Poses,
    /// Per pose (same index): the noise of its mean (g) and its rest.
    sigma_g: [f32; P],
    rest: [PoseRest; P],
    chunks: heapless::Vec<Chunk, C>,
    moves: heapless::Vec<RotationMove, M>,
    open: Option<Open>,
    rejected: [u16; REJECTED_REASONS],
    /// Per reason, the largest offending value (see [`Rotations::worst`]).
    worst: [f32; REJECTED_REASONS],
    bias_jump: Option<BiasJump>,
    /// Per pose ([`EARTH_POSES`]): its attitude's transpose `Aᵀ` and the Earth's-rate part of
    /// its bias `M` (its bias holds `M w`), when known.
    earth: [Option<(Matrix3<f32>, Matrix3<f32>)>; EARTH_POSES],
    /// `M` of the latest measured rest (the first rest: `I`, it defines the frame).
    rest_earth: Option<Matrix3<f32>>,
}

/// The rotation rows' sums that [`Rotations::add_rows_batch`] carries from one batch of moves to
/// the next: the Earth's rate's parts and the residual sums at the linearisation point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowSum {
    /// `Σ w h xᵀ` of the rows' Earth's-rate parts (the rows' `w` columns), in [`Sum`] as the
    /// normal equations' sums are: the elimination takes large sums apart.
    cross: [[Sum; 3]; 9],
    /// The normal equations of the Earth's rate `w` alone, with its prior `N(0, I/3)`.
    earth: NormalEquations<3>,
    /// Weighted residual sum; unweighted one of the rotation rows (rad²) and their count.
    wrss: Real,
    rss: Real,
    n: usize,
    /// The next kept move.
    next: usize,
}

impl RowSum {
    /// No move yet: the Earth's rate's prior alone.
    pub const fn new() -> Self {
        Self { cross: [[<Sum as Scalar>::ZERO; 3]; 9], earth: NormalEquations::prior(3.0), wrss: 0.0, rss: 0.0, n: 0, next: 0 }
    }

    /// Ends the sums of `ne` (every move added): the Earth's rate marginalised out of `ne` if
    /// `earth_rate`. Returns [`Rotations::add_rows`]'s residual sums and rows.
    fn finish(&self, ne: &mut NormalEquations<9>, earth_rate: bool) -> Result<(Real, Real, usize), Error> {
        if earth_rate {
            ne.eliminate(&self.cross, &self.earth)?;
        }
        Ok((self.wrss, self.rss, self.n))
    }
}

impl Default for RowSum {
    fn default() -> Self {
        Self::new()
    }
}

/// The largest bias change between the two rests of a move rejected as
/// [`Rejected::BiasDrifted`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BiasJump {
    /// Largest per-axis change (°/s).
    pub dps: f32,
    /// The same per minute between the two rests (°/s/min).
    pub dps_per_min: f32,
    /// The limit it exceeded ([`RotationLimits::max_bias_change_dps`], °/s).
    pub limit_dps: f32,
}

/// No rotation constraints, for the solvers that take them (their store's size is then moot).
pub const NONE: Option<(&Rotations, &RotationLimits)> = None;

impl<const M: usize, const C: usize, const P: usize> Default for Rotations<M, C, P> {
    fn default() -> Self {
        Self::new()
    }
}

/// Smallest turn (°) of a move counted for the gyro's handedness ([`Rotations::mirrored`]).
pub const MIRROR_MIN_TURN_DEG: f32 = 20.0;
/// Largest (°): near a half turn the sine of gravity's turn changes sign.
pub const MIRROR_MAX_TURN_DEG: f32 = 150.0;
/// Least sine of gravity's turn about the gyro's axis that counts (0.1: 6°, far above a pose's
/// noise of hundredths of a degree; a turn about gravity itself turns it by nothing).
pub const MIRROR_MIN_SINE: Real = 0.1;

/// The angle between two vectors (°).
/// Closes the open move `o`'s chunk at its last sample's time `t_end` into `chunks`.
fn flush<const C: usize>(chunks: &mut heapless::Vec<Chunk, C>, o: &mut Open, t_end: Time) {
    let span_s = [o.chunk_t0.since(o.t0) as f32, t_end.since(o.t0) as f32];
    for k in 0..3 {
        o.total[k] += o.gamma[k] as Real;
    }
    o.chunk_t0 = t_end;
    if chunks.push(Chunk { gamma: o.gamma, coning: o.coning, span_s }).is_err() {
        o.why.get_or_insert(Rejected::Full);
    }
    o.gamma = [0.0; 3];
    o.coning = [0.0; 3];
}

fn angle_deg(a: &Vector3<Real>, b: &Vector3<Real>) -> Real {
    crate::math::trig::atan2(a.cross(b).length(), a.dot(b)).to_degrees()
}

/// The whole number of revolutions nearest to a turn (rad), in rad (at least one).
fn whole_turn_rad(turn_rad: Real) -> Real {
    let rev = 2.0 * crate::math::real::consts::PI;
    real::round(turn_rad / rev).max(1.0) * rev
}

/// `[v]×`.
fn skew<T: nalgebra::RealField + Copy>(v: &Vector3<T>) -> Matrix3<T> {
    let z = T::zero();
    Matrix3::new(z, -v[2], v[1], v[2], z, -v[0], -v[1], v[0], z)
}

/// `Exp(φ)` and the right Jacobian `J_r(φ)` of a chunk's rotation vector (rad): Rodrigues'
/// coefficients `sin t / t`, `(1 − cos t) / t²`, `(t − sin t) / t³` by their Taylor series to
/// `t⁸`, whose error is below 1e-13 for `t ≤ 0.25` rad (a chunk turns [`CHUNK_DEG`] = 0.09 rad
/// raw and a sample's step more; no trigonometry is linked into the firmware for it). In `f32`:
/// the single-precision FPU of the Cortex-M4F composes a move 100× faster than soft `f64`, to
/// ≈ 1e-6 rad (tested). Both are `d I + u [φ]× + v φ φᵀ` (`[φ]×² = φ φᵀ − t² I`), built element
/// by element on the FPU: no matrix products per sample.
pub(crate) fn exp_jr(phi: &Vector3<f32>) -> (Matrix3<f32>, Matrix3<f32>) {
    let r = Rodrigues::of(phi);
    let (b, c) = (r.series(B), r.series(C));
    (r.matrix(1.0 - b * r.t2, r.series(A), b), r.matrix(1.0 - c * r.t2, -b, c))
}

/// [`exp_jr`]'s `Exp(φ)` alone, the same bits: a rotation without its Jacobian.
pub(crate) fn exp(phi: &Vector3<f32>) -> Matrix3<f32> {
    let r = Rodrigues::of(phi);
    let b = r.series(B);
    r.matrix(1.0 - b * r.t2, r.series(A), b)
}

/// Taylor coefficients of `sin t / t`, `(1 − cos t) / t²` and `(t − sin t) / t³` in `t²`.
const A: [f32; 5] = [1.0, -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362_880.0];
const B: [f32; 5] = [0.5, -1.0 / 24.0, 1.0 / 720.0, -1.0 / 40_320.0, 1.0 / 3_628_800.0];
const C: [f32; 5] = [1.0 / 6.0, -1.0 / 120.0, 1.0 / 5040.0, -1.0 / 362_880.0, 1.0 / 39_916_800.0];

/// A rotation vector `φ` and `t² = |φ|²`, for [`exp_jr`]'s matrices.
struct Rodrigues {
    p: [f32; 3],
    t2: f32,
}

impl Rodrigues {
    fn of(phi: &Vector3<f32>) -> Self {
        let p = [phi[0], phi[1], phi[2]];
        Self { p, t2: p[0] * p[0] + p[1] * p[1] + p[2] * p[2] }
    }

    /// A series `c` at `t²`.
    fn series(&self, c: [f32; 5]) -> f32 {
        let t2 = self.t2;
        c[0] + t2 * (c[1] + t2 * (c[2] + t2 * (c[3] + t2 * c[4])))
    }

    /// `d I + u [φ]× + v φ φᵀ`.
    fn matrix(&self, d: f32, u: f32, v: f32) -> Matrix3<f32> {
        let p = self.p;
        let s = [[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]];
        Matrix3::from_fn(|i, j| if i == j { d } else { 0.0 } + u * s[i][j] + v * p[i] * p[j])
    }
}

impl<const M: usize, const C: usize, const P: usize> Rotations<M, C, P> {
    /// Nothing recorded.
    pub const fn new() -> Self {
        let mut out = core::mem::MaybeUninit::uninit();
        // SAFETY: `init_in` writes every field.
        unsafe {
            Self::init_in(out.as_mut_ptr());
            out.assume_init()
        }
    }

    /// Forgets everything, in place (a `Self::new()` assigned would pass ~23 KiB through the
    /// stack).
    pub fn clear(&mut self) {
        // SAFETY: `self` is valid for writes; no field has drop glue to skip.
        unsafe { Self::init_in(self) }
    }

    /// Writes [`Self::new`]'s fields at `p`, each in place.
    ///
    /// # Safety
    /// `p` must be valid for writes and aligned; what it held is overwritten, not dropped.
    pub(crate) const unsafe fn init_in(p: *mut Self) {
        use core::ptr::addr_of_mut;
        // SAFETY: the caller's contract.
        unsafe {
            addr_of_mut!((*p).poses).write(Poses::new());
            addr_of_mut!((*p).sigma_g).write([0.0; P]);
            let mut i = 0;
            while i < P {
                addr_of_mut!((*p).rest[i]).write(PoseRest::NONE);
                i += 1;
            }
            addr_of_mut!((*p).chunks).write(heapless::Vec::new());
            addr_of_mut!((*p).moves).write(heapless::Vec::new());
            addr_of_mut!((*p).open).write(None);
            addr_of_mut!((*p).rejected).write([0; REJECTED_REASONS]);
            addr_of_mut!((*p).worst).write([0.0; REJECTED_REASONS]);
            addr_of_mut!((*p).bias_jump).write(None);
            addr_of_mut!((*p).earth).write([None; EARTH_POSES]);
            addr_of_mut!((*p).rest_earth).write(Some(Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)));
        }
    }

    /// Adds a static pose: its mean specific force (raw until [`Self::calibrate_poses`], g), the
    /// noise of that mean per component (g) and its rest; returns its index. The move into it
    /// ends at its mean instant, the move out of it starts there ([`PoseRest::rise_deg`]).
    pub fn push_pose(&mut self, accel_g: Vec3, sigma_g: f32, rest: impl Into<PoseRest>) -> Result<u8, Error> {
        let i = self.poses.len();
        let (Some(s), Some(r)) = (self.sigma_g.get_mut(i), self.rest.get_mut(i)) else {
            return Err(Error::CapacityExceeded { max: P as u8 });
        };
        *s = if sigma_g.is_finite() { sigma_g } else { 0.0 };
        *r = rest.into();
        if !r.rise_deg.iter().all(|v| v.is_finite()) {
            r.rise_deg = [0.0; 3];
        }
        self.poses.push(accel_g)
    }

    /// Pose `pose`'s attitude (rotation from its body frame to the first rest's, from the gyro
    /// with `K = I`): its moves get the Earth's-rate term of the module doc. Its bias holds the
    /// Earth's rate of the latest measured rest: exactly when it is that rest; a prediction
    /// (`Drift::at`'s line over the rests so far) until [`Self::settle_bias`] puts it on the line
    /// between two rests.
    pub fn push_attitude(&mut self, pose: u8, attitude: Matrix3<f32>) {
        if let Some(e) = self.earth.get_mut(pose as usize) {
            *e = self.rest_earth.map(|m| (attitude.transpose(), m));
        }
    }

    /// Two measured rests `before` and `after` bound poses whose bias was predicted: their bias
    /// becomes the line between the two at their times, and the kept moves into and out of them
    /// lose the difference (the bias integrals are linear in it). `after_attitude`: the
    /// attitude of `after` as in [`Self::push_attitude`] (`None`: unknown, the poses settled lose
    /// their Earth's-rate term). `temps_c`: the two rests' mean temperatures (°C, NaN unknown).
    pub fn settle_bias(&mut self, before: &RestBias, after: &RestBias, after_attitude: Option<Matrix3<f32>>, temps_c: [f32; 2]) {
        let after_earth = after_attitude.map(|a| a.transpose());
        for p in 0..self.poses.len().min(P) {
            let old = self.rest[p];
            if !old.predicted || old.bias.t < before.t || old.bias.t > after.t {
                continue;
            }
            let new = before.between(after, old.bias.t);
            let span = after.t.since(before.t);
            let f = if span > 0.0 { (old.bias.t.since(before.t) / span) as f32 } else { 0.0 };
            if let Some(e) = self.earth.get_mut(p) {
                *e = match (*e, self.rest_earth, after_earth) {
                    (Some((at, _)), Some(mb), Some(ma)) => Some((at, mb * (1.0 - f) + ma * f)),
                    _ => None,
                };
            }
            self.shift_bias(p, core::array::from_fn(|k| new.residual_dps[k] - old.bias.residual_dps[k]));
            self.rest[p].bias = new;
            self.rest[p].predicted = false;
            self.rest[p].warm_c = old.warm_c - (temps_c[0] + (temps_c[1] - temps_c[0]) * f);
        }
        self.rest_earth = after_earth;
    }

    /// The settled poses' bias follows the warm-up: each moves by `c` times its temperature's
    /// distance from the line of its two rests' ([`PoseRest::warm_c`]), `c` the zero rate's
    /// temperature coefficient (°/s per °C) fitted over all the rests. A line in time misses the
    /// curve of a warming part's bias (DESIGN §4.5, `b(T)`); the walk stays on the line. Once.
    pub fn follow_warmup(&mut self, dps_per_c: &Vec3) {
        for p in 0..self.poses.len().min(P) {
            let warm_c = core::mem::replace(&mut self.rest[p].warm_c, f32::NAN);
            if warm_c.is_finite() && !self.rest[p].predicted {
                let delta = dps_per_c.map(|c| c * warm_c);
                self.shift_bias(p, delta);
                let r = &mut self.rest[p].bias.residual_dps;
                *r = core::array::from_fn(|k| r[k] + delta[k]);
            }
        }
    }

    /// The kept moves into and out of pose `p` lose `delta` (°/s) more of its bias: a chunk over
    /// `[t₀, t₁]` loses `delta (t₁ − t₀) w`, `w` pose `p`'s weight on the line between the move's
    /// two rests at the chunk's middle ([`RestBias::integral_deg`] with `delta` at `p`'s end and
    /// 0 at the other). In f32 from the move's start (times within a move: ≤ 1e-6 s of error).
    fn shift_bias(&mut self, p: usize, delta: Vec3) {
        for m in self.moves.iter().filter(|m| m.from as usize == p || m.to as usize == p) {
            let at = |q: u8| self.rest[q as usize].bias.t.since(m.t0) as f32;
            let (ta, span) = (at(m.from), at(m.to) - at(m.from));
            let (wa, wb) = (f32::from(u8::from(m.from as usize == p)), f32::from(u8::from(m.to as usize == p)));
            for c in &mut self.chunks[m.first as usize..(m.first + m.n) as usize] {
                let f = if span > 0.0 { (0.5 * (c.span_s[0] + c.span_s[1]) - ta) / span } else { 0.5 };
                let lost = (c.span_s[1] - c.span_s[0]) * (wa + (wb - wa) * f);
                c.gamma = core::array::from_fn(|k| c.gamma[k] - delta[k] * lost);
            }
        }
    }

    /// A turn known as a whole (°, sensor frame, less the reference bias) as a chunk of the open
    /// move over `span_s` (s from the move's start; the bias tracked loses its integral over it,
    /// negative for a span that runs backwards: a turn undone).
    fn push_turn(&mut self, o: &mut Open, turn_deg: Vec3, span_s: [f32; 2]) {
        if turn_deg.iter().all(|v| *v == 0.0) {
            return;
        }
        for k in 0..3 {
            o.total[k] += turn_deg[k] as Real;
        }
        if self.chunks.push(Chunk { gamma: turn_deg, coning: [0.0; 3], span_s }).is_err() {
            o.why.get_or_insert(Rejected::Full);
        }
    }

    /// Starts integrating a move from pose `from`'s end (a move still open is dropped); the
    /// turn from its mean instant to its end is the move's first chunk (over the pose's last
    /// half: a ramp's weight).
    pub fn begin(&mut self, from: u8) {
        let mut o = Open {
            from,
            first: self.chunks.len(),
            gamma: [0.0; 3],
            coning: [0.0; 3],
            last: None,
            t0: Time::ZERO,
            chunk_t0: Time::ZERO,
            total: [0.0; 3],
            max_step_deg: 0.0,
            max_gap_s: 0.0,
            step: [0.0; 3],
            int_err: 0.0,
            why: None,
        };
        let rest = self.rest[from as usize % P];
        self.push_turn(&mut o, rest.rise_deg, [-rest.span_s / 2.0, 0.0]);
        self.open = Some(o);
    }

    /// Adds a sample of the open move: MCU time and bias-free gyro (°/s); `saturated` if it
    /// reached full scale. Without an open move, nothing.
    pub fn add(&mut self, t: Time, w_dps: Vec3, saturated: bool) {
        let Self { open: Some(o), chunks, .. } = self else { return };
        if saturated {
            o.why.get_or_insert(Rejected::Saturated);
        }
        match o.last {
            None => {
                o.t0 = t;
                o.chunk_t0 = t;
            }
            Some((t_prev, w_prev)) => {
                if t <= t_prev {
                    return;
                }
                let dt = t.since(t_prev) as f32;
                o.max_gap_s = o.max_gap_s.max(dt);
                let d = Vector3::from_fn(|i, _| 0.5 * (w_prev[i] + w_dps[i]) * dt);
                let c = Vector3::from(o.gamma).cross(&d) * 0.5;
                for i in 0..3 {
                    o.coning[i] += c[i];
                    o.gamma[i] += d[i];
                }
                let (dv, prev) = (d.map(f32::to_radians), Vector3::from(o.step).map(f32::to_radians));
                let d2 = d.norm_squared();
                o.int_err += sqrtf(prev.cross(&dv).norm_squared() * dv.norm_squared()) / 12.0;
                o.step = d.into();
                // The largest step's square until the move ends.
                o.max_step_deg = o.max_step_deg.max(d2);
                if Vector3::from(o.gamma).norm_squared() >= (CHUNK_DEG * CHUNK_DEG) as f32 {
                    flush(chunks, o, t);
                }
            }
        }
        o.last = Some((t, w_dps));
    }

    /// Ends the open move at pose `to` and keeps it (its chunks less the bias tracked between
    /// the two poses' rests), or counts why not.
    pub fn end(&mut self, to: u8, limits: &RotationLimits) -> Result<(), Rejected> {
        let Some(mut o) = self.open.take() else { return Ok(()) };
        let t_end = o.last.map_or(o.chunk_t0, |(t, _)| t);
        if Vector3::from(o.gamma).norm_squared() > 0.0 {
            flush(&mut self.chunks, &mut o, t_end);
        }
        // Back from the end of pose `to` to its mean instant: its turn undone.
        let (end_s, rest) = (t_end.since(o.t0) as f32, self.rest[to as usize % P]);
        self.push_turn(&mut o, rest.rise_deg.map(|v| -v), [end_s + rest.span_s / 2.0, end_s]);
        let total = Vector3::from(o.total);
        let turn = total.length();
        let (ra, rb) = (self.rest[o.from as usize % P].bias, self.rest[to as usize % P].bias);
        let (a, b) = (v64(ra.residual_dps), v64(rb.residual_dps));
        let (gi, gj) = (self.poses.get(o.from as usize).unit(), self.poses.get(to as usize).unit());
        let gravity_deg = angle_deg(&gi, &gj);
        let bias_change = (a - b).amax();
        let candidates = [
            (o.why, 0.0),
            ((o.max_gap_s > limits.max_gap_s).then_some(Rejected::Gap), o.max_gap_s as Real),
            ((o.max_step_deg > limits.max_step_deg * limits.max_step_deg).then_some(Rejected::TooFast), sqrtf(o.max_step_deg) as Real),
            // Gravity turned more than any plausible scale lets the gyro's turn explain.
            ((gravity_deg > SCALE_RANGE.1 * turn + 5.0).then_some(Rejected::Unseen), gravity_deg),
            ((turn < limits.min_move_deg as Real).then_some(Rejected::TooShort), turn),
            ((bias_change > limits.max_bias_change_dps as Real).then_some(Rejected::BiasDrifted), bias_change),
        ];
        let (why, worst) = candidates.into_iter().find_map(|(w, v)| w.map(|w| (w, v))).map_or((None, 0.0), |(w, v)| (Some(w), v));
        let off_gravity = angle_deg(&total, &gi);
        let vertical = gravity_deg < limits.vertical_deg as Real && off_gravity.min(180.0 - off_gravity) < limits.vertical_deg as Real;
        let duration_s = o.last.map_or(0.0, |(t, _)| t.since(o.t0) as f32);
        let n = (self.chunks.len() - o.first) as u16;
        let kept = RotationMove {
            from: o.from,
            to,
            first: o.first as u16,
            n,
            duration_s,
            turn_deg: turn as f32,
            vertical,
            int_sigma_rad: o.int_err,
            t0: o.t0,
        };
        let result = match why {
            None => {
                for c in &mut self.chunks[o.first..] {
                    let drift = ra.integral_deg(&rb, o.t0.plus_s(c.span_s[0] as Real), o.t0.plus_s(c.span_s[1] as Real));
                    c.gamma = core::array::from_fn(|k| (c.gamma[k] as Real - drift[k]) as f32);
                }
                self.moves.push(kept).map_err(|_| Rejected::Full)
            }
            Some(why) => Err(why),
        };
        if let Err(why) = result {
            if why == Rejected::BiasDrifted {
                let dps = bias_change as f32;
                let dt_s = rb.t.since(ra.t).abs().max(1e-3) as f32;
                if self.bias_jump.is_none_or(|j| dps > j.dps) {
                    self.bias_jump = Some(BiasJump { dps, dps_per_min: 60.0 * dps / dt_s, limit_dps: limits.max_bias_change_dps });
                }
            }
            self.chunks.truncate(o.first);
            self.rejected[why as usize] = self.rejected[why as usize].saturating_add(1);
            self.worst[why as usize] = self.worst[why as usize].max(worst as f32);
        }
        result
    }

    /// Moves rejected, by reason (in the order of [`Rejected::ALL`]).
    pub fn rejected(&self) -> [u16; REJECTED_REASONS] {
        self.rejected
    }

    /// Per reason (in the order of [`Rejected::ALL`]), the largest offending value among the
    /// moves rejected for it: the step (°) of [`Rejected::TooFast`], the turn (°) of
    /// [`Rejected::TooShort`], the bias change (°/s) of [`Rejected::BiasDrifted`], gravity's
    /// turn (°) of [`Rejected::Unseen`]; 0 for the others.
    pub fn worst(&self) -> [f32; REJECTED_REASONS] {
        self.worst
    }

    /// Moves kept plus those dropped for a changing bias ([`Rejected::BiasDrifted`]).
    pub fn moves_before_drift(&self) -> usize {
        self.moves.len() + self.rejected[Rejected::BiasDrifted as usize] as usize
    }

    /// [`Error::BiasDrifting`] (with the largest change) when the moves dropped for a changing
    /// bias are why fewer than three are left: the drift, not the poses, is the cause.
    pub fn drift_error(&self) -> Option<Error> {
        let j = self.bias_jump?;
        (self.moves.len() < 3 && self.moves_before_drift() >= 3).then_some(Error::BiasDrifting {
            off_trend_dps: j.dps,
            limit_dps: j.limit_dps,
            dps_per_min: j.dps_per_min,
        })
    }

    /// Why the moves do not determine `K`, when the dropped ones are at least as many as the
    /// kept: [`Error::MovesDropped`] naming the most common reason with its worst value (or
    /// [`Error::BiasDrifting`], [`Self::drift_error`], when that reason is the bias).
    pub fn drop_error(&self, limits: &RotationLimits) -> Option<Error> {
        let dropped: u32 = self.rejected.iter().map(|&n| n as u32).sum();
        if dropped == 0 || (dropped as usize) < self.moves.len() {
            return None;
        }
        let (i, _) = self.rejected.iter().enumerate().max_by_key(|(i, n)| (**n, core::cmp::Reverse(*i)))?;
        let reason = Rejected::ALL[i];
        if reason == Rejected::BiasDrifted {
            if let Some(e) = self.drift_error() {
                return Some(e);
            }
        }
        let limit = match reason {
            Rejected::TooFast => limits.max_step_deg,
            Rejected::TooShort => limits.min_move_deg,
            Rejected::BiasDrifted => limits.max_bias_change_dps,
            Rejected::Full => M as f32,
            Rejected::Gap => limits.max_gap_s,
            Rejected::Saturated | Rejected::Unseen => 0.0,
        };
        let total = (dropped as usize + self.moves.len()).min(u8::MAX as usize) as u8;
        Some(Error::MovesDropped { dropped: dropped.min(u8::MAX as u32) as u8, total, reason, value: self.worst[i], limit })
    }

    /// The kept moves.
    pub fn moves(&self) -> &[RotationMove] {
        &self.moves
    }

    /// The poses.
    pub fn poses(&self) -> &Poses {
        &self.poses
    }

    /// Replaces every raw pose by the calibrated `f = M (a − o)` (and scales its noise by `M`'s).
    pub fn calibrate_poses(&mut self, accel: &AccelCal) {
        let m = Matrix3::from_fn(|r, c| accel.m[r][c] as Real);
        let o = v64(accel.offset_g);
        self.poses.map(|a| m * (a - o));
        let gain = (real::sqrt(m.norm_squared()) / real::sqrt(3.0)) as f32;
        for s in &mut self.sigma_g[..self.poses.len()] {
            *s *= gain;
        }
    }

    /// The chunks of kept move `m`.
    fn chunks_of(&self, m: &RotationMove) -> &[Chunk] {
        let first = m.first as usize;
        self.chunks.get(first..first + m.n as usize).unwrap_or_default()
    }

    /// `R` and `J` (3×9, rad per unit of `vec K`) of move `m` at `K`, composed in `f32`, and
    /// the Earth's-rate gain `G` of the module doc (s; zero without both poses' attitudes).
    fn compose(&self, m: &RotationMove, k: &Matrix3<Real>, cof: &Matrix3<Real>) -> (Matrix3<Real>, [[Real; 9]; 3], Matrix3<Real>) {
        let (k, cof) = (k.map(|v| v as f32), cof.map(|v| v as f32));
        let (mut r, mut j) = (Matrix3::<f32>::identity(), [[0.0f32; 9]; 3]);
        // Σ R_<c s_c (1 − f_c), Σ R_<c s_c f_c and Σ s_c over the chunks (s_c its signed length,
        // f_c where its middle lies between the two rests, as `RestBias::integral_deg` weighs it).
        let (mut p, mut q, mut dt) = (Matrix3::<f32>::zeros(), Matrix3::<f32>::zeros(), 0.0f32);
        let (ta, tb) = (self.rest[m.from as usize % P].bias.t, self.rest[m.to as usize % P].bias.t);
        // The chunks' middles from `ta` (s) count from the move's start.
        let (from_ta, span) = (m.t0.since(ta) as f32, tb.since(ta) as f32);
        for c in self.chunks_of(m) {
            let s = c.span_s[1] - c.span_s[0];
            let f = if tb > ta { (from_ta + 0.5 * (c.span_s[0] + c.span_s[1])) / span } else { 0.5 };
            p += r * (s * (1.0 - f));
            q += r * (s * f);
            dt += s;
            let gamma = Vector3::from(c.gamma).map(f32::to_radians);
            let coning = Vector3::from(c.coning).map(|v| v.to_radians().to_radians());
            let phi = k * gamma + cof * coning;
            let (e, jr) = exp_jr(&phi);
            let et = e.transpose();
            let mut next = [[0.0f32; 9]; 3];
            for (row, n) in next.iter_mut().enumerate() {
                for (col, x) in n.iter_mut().enumerate() {
                    // Eᵀ J + J_r (Γᵀ ⊗ I): column 3c + r of the second term is J_r[row][r] Γ_c.
                    let prior: f32 = (0..3).map(|i| et[(row, i)] * j[i][col]).sum();
                    *x = prior + jr[(row, col % 3)] * gamma[col / 3];
                }
            }
            j = next;
            r *= e;
        }
        let earth = |pose: u8| self.earth.get(pose as usize).copied().flatten();
        let g = match (earth(m.from), earth(m.to)) {
            (Some((ai, mi)), Some((_, mj))) => ai * dt - p * mi - q * mj,
            _ => Matrix3::zeros(),
        };
        (r.map(|v| v as Real), j.map(|row| row.map(|v| v as Real)), g.map(|v| v as Real))
    }

    /// The rotation of move `m` at `K` (row-major): `R` takes a vector in the body frame at its
    /// end pose to the frame at its start pose (`R g_to ≈ g_from`). `None` for a singular `K`.
    pub fn rotation(&self, m: &RotationMove, k: &Mat3) -> Option<Matrix3<Real>> {
        let km = Matrix3::from_fn(|r, c| k[r][c] as Real);
        let cof = cofactor(&km)?;
        Some(self.turn(m, &km, &cof))
    }

    /// [`Self::compose`]'s `R` alone, the same bits, at a fraction of its cost (no Jacobian).
    fn turn(&self, m: &RotationMove, k: &Matrix3<Real>, cof: &Matrix3<Real>) -> Matrix3<Real> {
        let (k, cof) = (k.map(|v| v as f32), cof.map(|v| v as f32));
        let mut r = Matrix3::<f32>::identity();
        for c in self.chunks_of(m) {
            let gamma = Vector3::from(c.gamma).map(f32::to_radians);
            let coning = Vector3::from(c.coning).map(|v| v.to_radians().to_radians());
            r *= exp(&(k * gamma + cof * coning));
        }
        r.map(|v| v as Real)
    }

    /// Adds the rows of every kept move, linearised at `k` (vec `K`), as rows linear in vec `K`:
    /// `H·k' ≈ H·k − r`, with the Earth's rate `w` of the module doc marginalised out. Returns the
    /// weighted residual sum at `k`, and the unweighted one (rad²) of the rotation rows with their
    /// count (a vertical turn's rows are in the weighted sum only), all at `w = 0`.
    pub fn add_rows(&self, ne: &mut NormalEquations<9>, k: &[Real; 9], limits: &RotationLimits) -> Result<(Real, Real, usize), Error> {
        self.rows(ne, k, limits, 0, true)
    }

    /// [`Self::add_rows`] of the kept moves from the `first` on, the Earth's rate marginalised
    /// out if `earth`.
    fn rows(
        &self,
        ne: &mut NormalEquations<9>,
        k: &[Real; 9],
        limits: &RotationLimits,
        first: usize,
        earth_rate: bool,
    ) -> Result<(Real, Real, usize), Error> {
        let mut sum = RowSum::new();
        sum.next = first;
        self.add_moves(ne, &mut sum, k, limits, usize::MAX)?;
        sum.finish(ne, earth_rate)
    }

    /// [`Self::add_rows`] a batch at a time, for a caller that bounds its calls' length: the rows
    /// of the moves from `sum`'s next on, until they held `max_chunks` chunks (the cost of a move
    /// is its chunks'), into `ne` and `sum`. Once every move is in, the Earth's rate
    /// marginalised out and [`Self::add_rows`]'s sums; `None` before. The same sums in the same
    /// order as [`Self::add_rows`]: the same bits.
    pub fn add_rows_batch(
        &self,
        ne: &mut NormalEquations<9>,
        sum: &mut RowSum,
        k: &[Real; 9],
        limits: &RotationLimits,
        max_chunks: usize,
    ) -> Result<Option<(Real, Real, usize)>, Error> {
        match self.add_moves(ne, sum, k, limits, max_chunks)? {
            true => sum.finish(ne, true).map(Some),
            false => Ok(None),
        }
    }

    /// The loop of [`Self::add_rows_batch`]: true once every move is in.
    #[inline(never)] // one copy for the solve's iterations, its end and the hand-held step
    fn add_moves(
        &self,
        ne: &mut NormalEquations<9>,
        sum: &mut RowSum,
        k: &[Real; 9],
        limits: &RotationLimits,
        max_chunks: usize,
    ) -> Result<bool, Error> {
        let km = Matrix3::from_fn(|r, c| k[crate::estimators::full::vec_index(r, c)]);
        let cof = cofactor(&km).ok_or(Error::Singular)?;
        let sg = (limits.gamma_sigma_deg as Real).to_radians();
        let mut chunks = 0;
        for m in self.moves().get(sum.next..).unwrap_or_default() {
            if chunks >= max_chunks {
                return Ok(false);
            }
            chunks += m.n as usize;
            sum.next += 1;
            let (pi, pj) = (self.poses.get(m.from as usize), self.poses.get(m.to as usize));
            let (gi, gj) = (pi.unit(), pj.unit());
            let dir = |p: &Vector3<Real>, i: u8| (self.sigma_g[i as usize] as Real / p.length()).max(limits.min_direction_sigma as Real);
            let (di, dj) = (dir(&pi, m.from), dir(&pj, m.to));
            let s2 = di * di + dj * dj + sg * sg + sq(m.int_sigma_rad as Real);
            if m.vertical {
                // Linear rows in `K Γ̂` (Γ̂ = Γ/|Γ|, so that a residual is an angle): no part
                // across gravity (1σ the axis' tilt), and with whole turns `N·360°/|Γ|` along it
                // (1σ the hand's realignment of the start attitude, as an angle over the turn).
                let gamma = self.total_rad(m);
                let (len, unit) = (gamma.length(), gamma.unit());
                let up = if unit.dot(&gi) >= 0.0 { gi } else { -gi };
                let tilt = (limits.vertical_axis_sigma_deg as Real).to_radians();
                let noise = (sg * sg + sq(m.int_sigma_rad as Real)) / (len * len);
                let mut row = |e: Vector3<Real>, target: Real, s2: Real| -> Result<(), Error> {
                    let h: [Real; 9] = core::array::from_fn(|c| unit[c / 3] * e[c % 3]);
                    let res = (0..9).map(|c| h[c] * k[c]).sum::<Real>() - target;
                    ne.add_row(&h, target, 1.0 / s2)?;
                    sum.wrss += res * res / s2;
                    Ok(())
                };
                for e in tangent_basis(&up) {
                    row(e, 0.0, di * di + dj * dj + tilt * tilt + noise)?;
                }
                if limits.whole_turns {
                    row(up, whole_turn_rad(len) / len, sq(tilt / len) + noise)?;
                }
                continue;
            }
            sum.n += 2;
            let w = 1.0 / s2;
            let (r, j, g) = self.compose(m, &km, &cof);
            let rg = r * gj;
            let a = -(r * skew(&gj)); // ∂(R g_j)/∂(J δk) = −R [g_j]×
            for e in tangent_basis(&gi) {
                let res = e.dot(&rg);
                let ea = e.transpose() * a;
                let h: [Real; 9] = core::array::from_fn(|c| (0..3).map(|i| ea[i] * j[i][c]).sum());
                let y = (0..9).map(|c| h[c] * k[c]).sum::<Real>() - res;
                ne.add_row(&h, y, w)?;
                // The residual's part `ε·(R g_j × e)` from `ε = Ω G w`.
                let x: [Real; 3] = (g.transpose() * rg.cross(&e) * -EARTH_RATE_RAD_S).into();
                for (c, row) in sum.cross.iter_mut().enumerate() {
                    for b in 0..3 {
                        row[b] += widen(w) * widen(h[c]) * widen(x[b]);
                    }
                }
                sum.earth.add_row(&x, y, w)?;
                sum.wrss += w * res * res;
                sum.rss += res * res;
            }
        }
        Ok(true)
    }

    /// The misfit of every kept move at `K` (row-major): the angle (°) between `R g_j` and `g_i`;
    /// for a vertical turn, between `K Γ` and gravity (with whole turns, or the turn's distance
    /// from its whole revolutions if larger).
    pub fn residuals_deg(&self, k: &Mat3, limits: &RotationLimits) -> [f32; M] {
        let km = Matrix3::from_fn(|r, c| k[r][c] as Real);
        let mut out = [0.0; M];
        let Some(cof) = cofactor(&km) else { return out };
        for (o, m) in out.iter_mut().zip(self.moves()) {
            let (gi, gj) = (self.poses.get(m.from as usize).unit(), self.poses.get(m.to as usize).unit());
            *o = if m.vertical {
                let turn = km * self.total_rad(m);
                let off = angle_deg(&turn, &gi);
                let excess = if limits.whole_turns { (turn.length() - whole_turn_rad(turn.length())).abs().to_degrees() } else { 0.0 };
                off.min(180.0 - off).max(excess) as f32
            } else {
                angle_deg(&(self.turn(m, &km, &cof) * gj), &gi) as f32
            };
        }
        out
    }

    /// The gyro mirrored relative to the accelerometer ([`Error::AxesMirrored`]): of the kept
    /// moves that are not vertical turns and turn by [`MIRROR_MIN_TURN_DEG`] to
    /// [`MIRROR_MAX_TURN_DEG`], those where gravity turns clearly (the sine of its turn about the
    /// gyro's axis beyond [`MIRROR_MIN_SINE`]) are counted by the rule it follows: the right-hand
    /// rule turns the body's gravity against the body (`(g_from × g_to) · Γ < 0`), its mirror
    /// with it. Mirrored: at least two follow the left-hand rule and more than three times as many
    /// as the right. A slip or a shaky pose moves a few moves; a mirror moves all of them.
    pub fn mirrored(&self) -> Option<Error> {
        let (mut right_hand, mut left_hand) = (0u8, 0u8);
        for m in self.moves() {
            if m.vertical || !(m.turn_deg >= MIRROR_MIN_TURN_DEG && m.turn_deg <= MIRROR_MAX_TURN_DEG) {
                continue;
            }
            // The poses' gravity is 1 g to within the accelerometer's calibration.
            let (gi, gj) = (self.poses.get(m.from as usize), self.poses.get(m.to as usize));
            let s = gi.cross(&gj).dot(&self.total_rad(m).unit());
            if s < -MIRROR_MIN_SINE {
                right_hand += 1;
            } else if s > MIRROR_MIN_SINE {
                left_hand += 1;
            }
        }
        (left_hand >= 2 && left_hand as u16 > 3 * right_hand as u16).then_some(Error::AxesMirrored { right_hand, left_hand })
    }

    /// The bias-free gyro integral of kept move `m` (rad): `Σ Γ_c`.
    fn total_rad(&self, m: &RotationMove) -> Vector3<Real> {
        self.chunks_of(m).iter().map(|c| v64(c.gamma)).sum::<Vector3<Real>>().map(Real::to_radians)
    }

    /// Adds the rows of the latest kept move at `K = I`, without the Earth's rate: called as
    /// each move is kept, the normal equations whose inverse is the 1σ the moves alone give `K`,
    /// before the rig's axis joins them (a later [`Self::settle_bias`] changes a move's bias by
    /// far less than its noise; a row that is not finite is left out).
    pub fn add_last_at_identity(&self, ne: &mut NormalEquations<9>, limits: &RotationLimits) {
        let _ = self.rows(ne, &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], limits, self.moves.len().saturating_sub(1), false);
    }

    /// Smallest eigenvalue (of 1) of the mean `n nᵀ` over the kept moves' raw rotation axes:
    /// 1/3 for axes spread evenly in three dimensions, 0 for coplanar ones.
    pub fn axis_spread(&self) -> f32 {
        let mut s = [[0.0; 3]; 3];
        let n = self.moves.len().max(1) as Real;
        for m in self.moves() {
            let total: Vector3<Real> = self.chunks_of(m).iter().map(|c| v64(c.gamma)).sum();
            let u = total.unit();
            for i in 0..3 {
                for j in 0..3 {
                    s[i][j] += u[i] * u[j] / n;
                }
            }
        }
        sym_eigen(&s).0[0] as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::secs;

    /// Three 30° moves whose rests disagree on the bias by 0.3 °/s (> 0.2): all dropped, and the
    /// shortage is named as the drift, with the largest change and its rate.
    #[test]
    fn moves_dropped_for_a_changing_bias_are_named_as_drift() {
        let lim = RotationLimits::DEFAULT;
        let mut r = <Rotations>::new();
        for i in 0..4u8 {
            let t0 = 10.0 * Real::from(i);
            r.push_pose([0.0, 0.0, 1.0], 1e-4, RestBias { t: secs(t0), residual_dps: [0.3 * f32::from(i), 0.0, 0.0] }).unwrap();
            if i > 0 {
                r.begin(i - 1);
                for k in 0..100 {
                    r.add(secs(t0 - 5.0 + 0.01 * Real::from(k)), [30.0, 0.0, 0.0], false);
                }
                assert_eq!(r.end(i, &lim), Err(Rejected::BiasDrifted));
            }
        }
        assert_eq!((r.moves().len(), r.moves_before_drift()), (0, 3));
        match r.drift_error() {
            Some(Error::BiasDrifting { off_trend_dps, limit_dps, dps_per_min }) => {
                assert!((off_trend_dps - 0.3).abs() < 1e-5 && limit_dps == 0.2 && (dps_per_min - 1.8).abs() < 1e-4);
            }
            e => panic!("{e:?}"),
        }
        // Bias steady: nothing dropped, nothing to blame.
        assert_eq!(<Rotations>::new().drift_error(), None);
    }

    /// [`Rotations::shift_bias`] in `f32` from the move's start against the `f64` integral it
    /// replaced ([`RestBias::integral_deg`] of each chunk): a 20 s move at 952 Hz starting an
    /// hour in, its rests 1000 s apart, a shift of 0.3 °/s at either end. Each chunk agrees
    /// within an `f32` step of its 5° (the old path rounded to `f32` too).
    #[test]
    fn bias_shifts_in_f32_match_the_f64_integral() {
        let lim = RotationLimits::DEFAULT;
        for p in [0usize, 1] {
            let mut r = <Rotations>::new();
            let (t_from, t_to) = (3600.0, 4600.0);
            r.push_pose([0.0, 0.0, 1.0], 1e-4, RestBias { t: secs(t_from), residual_dps: [0.0; 3] }).unwrap();
            r.push_pose([0.0, 0.0, 1.0], 1e-4, RestBias { t: secs(t_to), residual_dps: [0.0; 3] }).unwrap();
            r.begin(0);
            for k in 0..=20 * 952 {
                r.add(secs(t_from + 500.0 + Real::from(k) / 952.0), [9.0, -4.0, 2.0], false);
            }
            assert_eq!(r.end(1, &lim), Ok(()));
            let before = r.chunks.clone();
            let delta = [0.3, -0.2, 0.1];
            r.shift_bias(p, delta);
            let m = r.moves[0];
            let only = |q: usize| RestBias { t: r.rest[q].bias.t, residual_dps: if q == p { delta } else { [0.0; 3] } };
            let mut worst = 0.0 as Real;
            for (c0, c1) in before[m.first as usize..(m.first + m.n) as usize].iter().zip(&r.chunks[m.first as usize..]) {
                let lost = only(0).integral_deg(&only(1), m.t0.plus_s(c0.span_s[0] as Real), m.t0.plus_s(c0.span_s[1] as Real));
                for k in 0..3 {
                    let want = (c0.gamma[k] as Real - lost[k]) as f32;
                    worst = worst.max((c1.gamma[k] - want).abs() as Real);
                }
            }
            assert!(m.n > 30 && worst <= 1e-6, "pose {p}: {} chunks, worst {worst:e} deg", m.n);
        }
    }

    #[test]
    fn exp_and_its_right_jacobian_match_finite_differences() {
        let phi = Vector3::new(0.08f32, -0.05, 0.12);
        let (e, jr) = exp_jr(&phi);
        assert!((e * e.transpose() - Matrix3::identity()).amax() < 1e-6);
        // Exp(φ + δ) ≈ Exp(φ) Exp(J_r δ), to f32 precision.
        let d = Vector3::new(1e-3f32, -2e-3, 1.5e-3);
        let lhs = exp_jr(&(phi + d)).0;
        let rhs = e * exp_jr(&(jr * d)).0;
        assert!((lhs - rhs).amax() < 2e-6, "{}", (lhs - rhs).amax());
        // The series against the closed form (f64) up to 0.25 rad.
        for t in [1e-7 as Real, 0.01, 0.1, 0.25] {
            let phi = Vector3::new(0.6, -0.48, 0.64) * t;
            let exact = nalgebra::Rotation3::from_scaled_axis(phi).into_inner();
            assert!((exp_jr(&phi.map(|v| v as f32)).0.map(|v| v as Real) - exact).amax() < 3e-7, "t {t}");
        }
    }

    #[test]
    fn a_move_about_one_axis_composes_to_its_turn_at_any_k() {
        let mut r = <Rotations>::new();
        r.push_pose([0.0, 0.0, 1.0], 1e-4, RestBias::default()).unwrap();
        r.push_pose([0.0, 1.0, 0.0], 1e-4, RestBias::default()).unwrap();
        r.begin(0);
        for i in 0..=900 {
            r.add(secs(i as Real * 0.001), [90.0, 0.0, 0.0], false);
        }
        assert_eq!(r.end(1, &RotationLimits::DEFAULT), Ok(()));
        assert_eq!(r.moves()[0].n, 17);
        let k = Matrix3::from_diagonal(&Vector3::new(1.1, 1.0, 1.0));
        let cof = cofactor(&k).unwrap();
        let (rot, _, _) = r.compose(&r.moves()[0], &k, &cof);
        let expect = nalgebra::Rotation3::from_scaled_axis(Vector3::new(((81.0 as Real) * 1.1).to_radians(), 0.0, 0.0)).into_inner();
        // Stored and composed in f32: 17 chunks round to ≈ 3e-7 rad (a K error of 2e-7).
        assert!((rot - expect).amax() < 1e-6, "{rot} vs {expect}");
    }
}
