//! The full `K`'s 1σ across rig-sim's hand family (issue 48): on one servo with 12 hand-held
//! poses, `gyrocal-calib`'s 1σ covers its error for every hand, whatever its amplitude, band,
//! axes and pivot (the family: `rig_sim::sim::HANDS`), and for poses at random attitudes; and
//! a held pose's own 1σ, which the accelerometer's starts from, covers its mean's error.

use calib::{csvlog, offline};
use rig_sim::pan_tilt;
use rig_sim::sim::{Rig, RigConfig, HANDS};

/// Rigs per hand: 108 elements of `K` each, a coverage known to ±2 % (binomial).
const RIGS: usize = 12;

#[test]
fn the_full_k_sigma_covers_its_error_for_every_hand_of_the_family() {
    for hand in HANDS {
        let (mut within, mut n, mut sq) = ([0usize; 2], 0usize, 0.0f64);
        for run in 0..RIGS {
            let seed = 2027 + run as u64;
            let mut rig = Rig::new(RigConfig { hand: Some(hand), ..pan_tilt::rig_config(2027, run) }, seed);
            let log = pan_tilt::log_at(&mut rig, true, &[0.0]);
            let rows = csvlog::parse(&log).unwrap().rows;
            let c = offline::calibrate_with(&rows, None, true).unwrap_or_else(|e| panic!("{} rig {run}: {e}", hand.name()));
            let f = c.full.unwrap_or_else(|| panic!("{} rig {run}: no full K", hand.name())).unwrap();
            let [a, b] = pan_tilt::k_error_covered(f.k, f.sigma_k, c.accel.m, &rig);
            within = [within[0] + a, within[1] + b];
            n += 9;
            sq += pan_tilt::k_error(f.k, c.accel.m, &rig).map_or(f64::NAN, |(_, rms)| rms * rms);
        }
        let [c1, c2] = within.map(|w| w as f64 / n as f64);
        let rms = (sq / RIGS as f64).sqrt();
        println!("MEASURED {}: K within 1 sigma {:.0} %, within 2 sigma {:.0} %, RMS of E {rms:.2e}", hand.name(), 100.0 * c1, 100.0 * c2);
        // A true 1σ gives 68 % / 95 %. Before a swaying pose stopped passing for a rest (its
        // sway's net turn in its gyro mean, taken as the bias), the nod gave 56 % / 93 % and an
        // RMS of 4.3e-4 on these rigs (57-59 % / 87-89 %, 3.6e-4 over 60).
        assert!((0.55..=0.85).contains(&c1) && c2 >= 0.90, "{}: {:.0} % / {:.0} %", hand.name(), 100.0 * c1, 100.0 * c2);
        assert!(rms < 3e-4, "{}: RMS of E {rms:.2e}", hand.name());
    }
}

#[test]
fn the_full_k_sigma_covers_its_error_with_poses_at_random_attitudes() {
    // The other pose set: 12 attitudes drawn uniformly (not near an icosahedron's
    // vertices), a braced and a nodding hand: at least 3 rigs in 4 give a full K, and its 1σ
    // covers its error as with the simulated operator's poses.
    use rand::SeedableRng;
    for hand in [rig_sim::sim::HandLevel::Braced, rig_sim::sim::HandLevel::Nod] {
        let (mut within, mut n, mut refused) = ([0usize; 2], 0usize, vec![]);
        for run in 0..RIGS {
            let seed = 4049 + run as u64;
            let mut rig = Rig::new(RigConfig { hand: Some(hand), ..pan_tilt::rig_config(4049, run) }, seed);
            let poses = pan_tilt::random_attitudes(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed), 12);
            let log = pan_tilt::log_posed(&mut rig, &poses, &[0.0]);
            let rows = csvlog::parse(&log).unwrap().rows;
            match offline::calibrate_with(&rows, None, true).map(|c| (c.full, c.accel.m)) {
                Ok((Some(Ok(f)), m)) => {
                    let [a, b] = pan_tilt::k_error_covered(f.k, f.sigma_k, m, &rig);
                    within = [within[0] + a, within[1] + b];
                    n += 9;
                }
                Ok((Some(Err(e)), _)) => refused.push(e.to_string()),
                Ok((None, _)) => refused.push("no full K".into()),
                Err(e) => refused.push(e.to_string()),
            }
        }
        let [c1, c2] = within.map(|w| w as f64 / n.max(1) as f64);
        println!(
            "MEASURED random poses, {}: K within 1 sigma {:.0} %, within 2 sigma {:.0} % over {} rigs; refused {refused:?}",
            hand.name(),
            100.0 * c1,
            100.0 * c2,
            n / 9
        );
        assert!(n / 9 >= RIGS * 3 / 4, "{}: {refused:?}", hand.name());
        assert!((0.55..=0.85).contains(&c1) && c2 >= 0.90, "{}: {:.0} % / {:.0} %", hand.name(), 100.0 * c1, 100.0 * c2);
    }
}

#[test]
fn a_held_pose_s_1sigma_covers_the_error_of_its_mean_for_every_hand() {
    // The accelerometer's 1σ starts from each pose's own (`Segment::accel_sigma_of_mean`): a
    // 2 s pose held by each hand of the family, 240 attitudes, against the simulator's truth: the
    // mean reading along gravity less the still part's (`C g + o` over the pose's attitudes).
    // Its error is the hand's linear acceleration left in the mean and the part's noise.
    use calib_core::formats::log::Row;
    use calib_core::math::stats::Moments3;
    use nalgebra::{UnitQuaternion, Vector3};
    const POSES: usize = 240;
    for hand in HANDS {
        let (mut within, mut ratios, mut squares) = ([0usize; 2], vec![], [0.0; 2]);
        for run in 0..POSES {
            let mut rig = Rig::new(RigConfig { hand: Some(hand), ..pan_tilt::rig_config(2027, run) }, 100 + run as u64);
            let row = |r: rig_sim::sim::Reading| rig_sim::harness::bare_row(&r);
            // A second still on the shaft (the log's noise floor), the hand's motion setting in,
            // then the pose.
            let mut rows: Vec<Row> = (0..119).map(|_| row(rig.next_sample())).collect();
            let r = run as f64;
            rig.detach_to(UnitQuaternion::from_euler_angles(0.3 * r, 0.7 + 0.1 * r, 0.2), 0.5);
            for _ in 0..3 * 119 {
                rig.next_sample();
            }
            let (first, mut accel, mut still) = (rows.len(), Moments3::new(), Vector3::zeros());
            for _ in 0..238 {
                let reading = rig.next_sample();
                let t = rig.truth();
                still += t.accel_c * (t.q_wb.inverse() * Vector3::z()) + t.accel_offset_g;
                accel.add(reading.accel_g);
                rows.push(row(reading));
            }
            let still = still / 238.0;
            let pose = offline::Segment { first, last: rows.len() - 1, accel, gyro: Moments3::new(), servo_deg: None, tilt_deg: None };
            let sigma = pose.accel_sigma_of_mean(&rows, offline::phases(&rows[..first]).accel_noise_g);
            let mean = Vector3::from(accel.mean());
            let e = (mean - still).dot(&mean.normalize()).abs();
            within = [within[0] + (e <= sigma) as usize, within[1] + (e <= 2.0 * sigma) as usize];
            ratios.push(e / sigma);
            squares = [squares[0] + e * e, squares[1] + sigma * sigma];
        }
        ratios.sort_by(f64::total_cmp);
        let [c1, c2] = within.map(|w| w as f64 / POSES as f64);
        // The propagated 1σ sums the poses' variances: their mean must be the errors' mean square.
        let square_ratio = squares[0] / squares[1];
        println!(
            "MEASURED {}: a pose's mean within 1 sigma {:.0} %, 2 sigma {:.0} %, median error/sigma {:.2}, mean square error / mean variance {square_ratio:.2}",
            hand.name(),
            100.0 * c1,
            100.0 * c2,
            ratios[POSES / 2]
        );
        // A true 1σ gives 68 % / 95 %; over 240 poses ±3 % / ±1.4 % (binomial): the bounds are
        // 3 of those from it. The ratio's own spread over 240 poses is ±10 %. Measured:
        // 65-72 % / 92-94 %, the median error 0.54-0.77 σ (a normal one: 0.67), the ratio
        // 0.84-1.07 (with the larger of the noise and √(2⟨B²⟩)/T, before: 0.68-1.17).
        assert!((0.59..=0.77).contains(&c1) && c2 >= 0.91, "{}: {:.0} % / {:.0} %", hand.name(), 100.0 * c1, 100.0 * c2);
        assert!((0.7..=1.3).contains(&square_ratio), "{}: mean square error / mean variance {square_ratio:.2}", hand.name());
    }
}
