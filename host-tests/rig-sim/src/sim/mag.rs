//! The board's magnetometer (Rev1: the LSM9DS1's, Rev2: a BMM150), in the board frame (each
//! part model reads it in its own axes): `m_raw = S b_B + h + noise`, `S` soft iron times the die's
//! small rotation against the accelerometer, `h` hard iron and offset; plus, while the board
//! is clamped on the shaft, the servo motor's magnet as a dipole that turns with the motor.

use nalgebra::{Matrix3, Rotation3, Unit, UnitQuaternion, Vector3};
use rand::Rng;
use rand_distr::StandardNormal;

/// Which part, for its rate, resolution and noise.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MagPart {
    /// The LSM9DS1's magnetometer at ±4 gauss: 0.14 mgauss/LSB (datasheet Table 3), read at
    /// 40 Hz; RMS noise 0.3 µT (assumed: the datasheet gives none).
    Lsm9ds1,
    /// A BMM150 at its high-accuracy preset (nXY 47, nZ 83, 20 Hz: 0.3 µT RMS noise, datasheet
    /// Table 3 as docs/mag-sources.md gives it), the one a calibration should use; 0.3 µT
    /// resolution.
    Bmm150,
}

impl MagPart {
    /// Output data rate (Hz).
    pub fn odr_hz(self) -> f64 {
        match self {
            Self::Lsm9ds1 => 40.0,
            Self::Bmm150 => 20.0,
        }
    }

    /// Output resolution (µT).
    pub fn lsb_ut(self) -> f64 {
        match self {
            Self::Lsm9ds1 => 0.014,
            Self::Bmm150 => 0.3,
        }
    }

    /// RMS noise per reading (µT).
    pub fn noise_ut(self) -> f64 {
        match self {
            Self::Lsm9ds1 => 0.3,
            Self::Bmm150 => 0.3,
        }
    }

    /// What the part reports of a field `m` (µT, board frame; both parts' axes are the board's
    /// up to order and sign): the LSM9DS1's int16 counts saturate (−458.8..458.7 µT at
    /// ±4 gauss, as its register model, `lsm_mag_model`, clamps them; the datasheet does not
    /// say what it reads beyond full scale); the BMM150 overflows beyond ±1300 µT in x and y,
    /// ±2500 µT in z (its datasheet's field range), a reading its driver skips: `None`
    /// (docs/mag-sources.md).
    pub fn report(self, m: [f64; 3]) -> Option<[f64; 3]> {
        match self {
            Self::Lsm9ds1 => Some(m.map(|v| v.clamp(i16::MIN as f64 * self.lsb_ut(), i16::MAX as f64 * self.lsb_ut()))),
            Self::Bmm150 => (m[0].abs() <= 1300.0 && m[1].abs() <= 1300.0 && m[2].abs() <= 2500.0).then_some(m),
        }
    }
}

/// The magnetometer's errors and the fields it sees, as the scoring needs them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MagTruth {
    /// `S`: soft iron times the die rotation (raw per true field in B).
    pub s: Matrix3<f64>,
    /// Hard iron and offset `h` (µT).
    pub h: Vector3<f64>,
    /// The Earth's field in W (µT; W's z up).
    pub field_w: Vector3<f64>,
    /// The die's rotation against the accelerometer (°).
    pub die_deg: f64,
}

/// A magnetometer drawn for one rig.
#[derive(Clone, Debug)]
pub struct Magnetometer {
    part: MagPart,
    truth: MagTruth,
    /// Motor magnet's moment (A·m²) and the gear ratio from shaft to motor.
    dipole_am2: f64,
    gear: f64,
    next_t_s: f64,
    /// Readings per second (Hz): the part's ([`MagPart::odr_hz`]) until a register model sets
    /// its own.
    odr_hz: f64,
    /// A stray field at the board (µT, in W): a magnet or a laptop brought near it.
    pub stray_w: Vector3<f64>,
}

/// The motor's centre relative to the shaft axis at the horn (m): 2 cm down the shaft, 1.2 cm
/// aside (a micro servo's case).
const MOTOR_DOWN_M: f64 = 0.02;
const MOTOR_ASIDE_M: f64 = 0.012;

impl Magnetometer {
    /// Draws a part's errors and a site's field: field 40–60 µT at a dip of 50–70° towards a
    /// random azimuth, hard iron U(±40) µT per axis, soft iron `I` + symmetric U(±5 %) diagonal
    /// and U(±2 %) off it, the die turned U(0, 2°) about a random axis; a motor magnet of
    /// U(0.005, 0.02) A·m² (tens to a hundred µT at 2–3 cm) geared U(150, 300):1.
    pub fn draw(part: MagPart, rng: &mut impl Rng) -> Self {
        let (b, dip, azimuth) =
            (rng.random_range(40.0..60.0), rng.random_range(50.0f64..70.0).to_radians(), rng.random_range(0.0..360.0f64).to_radians());
        let field_w = Vector3::new(dip.cos() * azimuth.cos(), dip.cos() * azimuth.sin(), -dip.sin()) * b;
        let h = Vector3::from_fn(|_, _| rng.random_range(-40.0..40.0));
        let mut soft = Matrix3::identity();
        for i in 0..3 {
            soft[(i, i)] += rng.random_range(-0.05..0.05);
            for j in i + 1..3 {
                let v = rng.random_range(-0.02..0.02);
                (soft[(i, j)], soft[(j, i)]) = (v, v);
            }
        }
        let axis = Vector3::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal)).normalize();
        let die_deg = rng.random_range(0.0..2.0);
        let die = Rotation3::new(axis * f64::to_radians(die_deg)).into_inner();
        Self {
            part,
            truth: MagTruth { s: soft * die, h, field_w, die_deg },
            dipole_am2: rng.random_range(0.005..0.02),
            gear: rng.random_range(150.0..300.0),
            next_t_s: 0.0,
            odr_hz: part.odr_hz(),
            stray_w: Vector3::zeros(),
        }
    }

    /// The truth (for scoring only).
    pub fn truth(&self) -> MagTruth {
        self.truth
    }

    /// The part.
    pub fn part(&self) -> MagPart {
        self.part
    }

    /// Readings from now on at `hz` (a register model's configured rate); ignored unless > 0.
    pub fn set_odr_hz(&mut self, hz: f64) {
        if hz > 0.0 {
            self.odr_hz = hz;
        }
    }

    /// A reading (µT) when one is due at true time `t_s`, for attitude `q_wb`; `shaft` while
    /// the board is clamped on the shaft: (shaft axis in W, shaft angle (rad), the sensor's
    /// offset from the axis in W (m)).
    pub fn measure(
        &mut self,
        t_s: f64,
        q_wb: &UnitQuaternion<f64>,
        shaft: Option<(Unit<Vector3<f64>>, f64, Vector3<f64>)>,
        rng: &mut impl Rng,
    ) -> Option<[f32; 3]> {
        if t_s < self.next_t_s {
            return None;
        }
        self.next_t_s = t_s + 1.0 / self.odr_hz;
        let motor = shaft.map_or(Vector3::zeros(), |(axis, angle, sensor_w)| self.motor_field_w(&axis, angle, &sensor_w));
        let b_b = q_wb.inverse() * (self.truth.field_w + motor + self.stray_w);
        let noise = Vector3::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal)) * self.part.noise_ut();
        let m = self.part.report((self.truth.s * b_b + self.truth.h + noise).into())?;
        let lsb = self.part.lsb_ut();
        Some(m.map(|v| ((v / lsb).round() * lsb) as f32))
    }

    /// The motor magnet's field (µT, in W) at the sensor: a dipole `μ0/4π (3(m·r̂)r̂ − m)/r³`
    /// whose moment turns about the shaft with the motor.
    fn motor_field_w(&self, axis: &Unit<Vector3<f64>>, angle: f64, sensor_w: &Vector3<f64>) -> Vector3<f64> {
        let e1 = axis.cross(&Vector3::x()).try_normalize(1e-6).unwrap_or_else(|| axis.cross(&Vector3::y()).normalize());
        let e2 = axis.cross(&e1);
        let motor = -axis.into_inner() * MOTOR_DOWN_M + e1 * MOTOR_ASIDE_M;
        let phi = angle * self.gear;
        let moment = (e1 * phi.cos() + e2 * phi.sin()) * self.dipole_am2;
        let r = sensor_w - motor;
        let (d, rhat) = (r.norm(), r.normalize());
        // μ0/4π = 1e-7 T·m/A = 0.1 µT·m/A.
        (rhat * (3.0 * moment.dot(&rhat)) - moment) * (0.1 / (d * d * d))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each part reports a field beyond its range as the part does: the LSM9DS1 at its `i16`
    /// limit, the BMM150 not at all (an overflow); within it, the field.
    #[test]
    fn a_field_beyond_the_parts_range_reads_as_the_part_reads_it() {
        let lsm = MagPart::Lsm9ds1.report([5100.0, -5100.0, 30.0]).unwrap();
        assert_eq!(lsm, [32767.0 * 0.014, -32768.0 * 0.014, 30.0]);
        assert_eq!(MagPart::Bmm150.report([1301.0, 0.0, 0.0]), None);
        assert_eq!(MagPart::Bmm150.report([0.0, 0.0, -2501.0]), None);
        assert_eq!(MagPart::Bmm150.report([1299.0, -1299.0, 2499.0]), Some([1299.0, -1299.0, 2499.0]));
    }
}
