//! The flash record: round trip of any record, and a decoder that never panics on any bytes.

use calib_core::estimators::accel::AccelModel;
use calib_core::estimators::bias::TempCo;
use calib_core::estimators::gyro::Method;
use calib_core::estimators::mag::MagCal;
use calib_core::formats::record::{DecodeError, Record, Sensor, SensorSetup, LEN};
use proptest::prelude::*;

fn finite() -> impl Strategy<Value = f32> {
    prop::num::f32::NORMAL | prop::num::f32::ZERO | prop::num::f32::SUBNORMAL
}

/// A 3×3 matrix within `d` of the identity (`Record::plausible`'s 0.5).
fn near_identity(d: f32) -> impl Strategy<Value = [f32; 9]> {
    prop::array::uniform9(-d..=d).prop_map(|mut v| {
        for i in [0, 4, 8] {
            v[i] += 1.0;
        }
        v
    })
}

prop_compose! {
    /// Any record a part can have: the fields applied to readings within `Record::plausible`'s
    /// bounds, every other field any finite number.
    fn any_record()(
        seq in any::<u32>(), temp_c in prop::option::of(-60.0f32..=150.0), k in near_identity(0.5),
        b in prop::array::uniform3(-4000.0f32..=4000.0), m in near_identity(0.5),
        o in prop::array::uniform3(-32.0f32..=32.0), s in prop::array::uniform9(finite()),
        q in prop::array::uniform8(finite()), method in 0u8..3, model in 0u8..3,
        poses in any::<u8>(), rows in any::<u16>(),
        setup in (1e-3f32..=10_000.0, 1e-3f32..=4000.0, 1e-3f32..=32.0),
        tempco in prop::option::of((prop::array::uniform3(-1.0f32..=1.0), prop::array::uniform5(finite()))),
        part in prop::option::of((-64i8..64, any::<bool>())),
        mag in prop::option::of((prop::array::uniform9(-10.0f32..=10.0), prop::array::uniform3(-5000.0f32..=5000.0), prop::array::uniform8(finite()), any::<u16>(), any::<u8>())),
    ) -> Record {
        let setup = [setup.0, setup.1, setup.2];
        let tempco = tempco.map(|(c, t)| [c[0], c[1], c[2], t[0], t[1], t[2], t[3], t[4]]);
        let mag = mag.map(|(a, o, q, samples, poses)| {
            let v: [f32; 20] = core::array::from_fn(|i| if i < 9 { a[i] } else if i < 12 { o[i - 9] } else { q[i - 12] });
            (v, samples, poses)
        });
        Record {
            seq, temp_c,
            gyro_k: [[k[0], k[1], k[2]], [k[3], k[4], k[5]], [k[6], k[7], k[8]]],
            gyro_bias_dps: b,
            method: [Method::Paper, Method::Sweep, Method::Full][method as usize],
            accel_m: [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]],
            accel_offset_g: o,
            accel_model: [AccelModel::None, AccelModel::SixParam, AccelModel::NineParam][model as usize],
            poses, rows, sigma_k: [[s[0], s[1], s[2]], [s[3], s[4], s[5]], [s[6], s[7], s[8]]],
            invariant_before_rel: q[0], invariant_after_rel: q[1], condition: q[2],
            tilt_deg: q[3], span_deg: q[4], accel_rms_g: q[5], residual_rms: q[6], non_coplanar_deg: q[7],
            setup: SensorSetup { odr_hz: setup[0], gyro_range_dps: setup[1], accel_range_g: setup[2],
                sensor: part.map_or(Sensor::Lsm9ds1, |(gyr_cas, user_gain)| Sensor::Bmi270 { gyr_cas, user_gain }) },
            tempco: tempco.map(|t| TempCo { dps_per_c: [t[0], t[1], t[2]], sigma_dps_per_c: [t[3], t[4], t[5]], range_c: [t[6], t[7]] }),
            mag: mag.map(|(v, samples, poses)| MagCal {
                a: [[v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]]], offset_ut: [v[9], v[10], v[11]],
                field_ut: v[12], sigma_field_ut: v[13], dip_deg: v[14], sigma_dip_deg: v[15],
                alignment_deg: v[16], sigma_alignment_deg: v[17], residual_ut: v[18], coverage: v[19], samples, poses,
            }),
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn round_trip(r in any_record()) {
        let bytes = r.encode().unwrap();
        prop_assert_eq!(Record::decode(&bytes), Ok(r));
        // Any single flipped bit is caught (CRC-32 detects every 1-bit error).
        for bit in [0usize, 37, 333, 8 * LEN - 1] {
            let mut c = bytes;
            c[bit / 8] ^= 1 << (bit % 8);
            prop_assert!(Record::decode(&c).is_err());
        }
        // Every truncation is reported as such.
        let truncated = matches!(Record::decode(&bytes[..LEN - 1]), Err(DecodeError::Truncated { .. }));
        prop_assert!(truncated);
    }

    #[test]
    fn a_record_beyond_what_a_part_can_have_is_never_encoded(r in any_record(), at in 0usize..9, v in 1.01f32..1e30) {
        let mut bad = r;
        bad.gyro_k[at / 3][at % 3] += if at % 4 == 0 { v } else { -v };
        prop_assert!(bad.encode().is_err());
    }

    #[test]
    fn decoder_never_panics(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        let _ = Record::decode(&bytes);
    }

    #[test]
    fn decoder_never_panics_on_mutated_records(r in any_record(), at in 0usize..LEN, v in any::<u8>(), cut in 0usize..=LEN) {
        let mut b = r.encode().unwrap();
        b[at] = v;
        let _ = Record::decode(&b[..cut]);
    }
}
