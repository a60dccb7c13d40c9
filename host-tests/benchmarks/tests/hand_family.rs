//! The full `K`'s 1σ across rig-sim's hand family (issue 48): on one servo with 12 hand-held
//! poses, `gyrocal-calib`'s 1σ covers its error for every hand, whatever its amplitude, band,
//! axes and pivot (the family: `rig_sim::sim::HANDS`).

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
