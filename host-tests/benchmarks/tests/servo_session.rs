//! The firmware's procedure on a hobby-servo rig: the sweep estimator is
//! immune to the servo's angle-scale error, the paper's estimator inherits it one to one.

use benchmarks::hobby_servo::trial;
use rig_sim::sim::ServoModel;
use rig_sim::variant::Variant;

#[test]
fn sweep_ignores_servo_scale_error_paper_inherits_it() {
    let mut cfg = Variant::Hobby.config(7, 0);
    let ServoModel::Positional(servo) = &mut cfg.servo else { panic!("positional servo expected") };
    servo.scale_error = 0.03;
    let s = trial(cfg, 1).unwrap();
    let sweep = s.rel_errors(&s.sweep).unwrap();
    let paper = s.rel_errors(&s.paper).unwrap();
    for i in 0..3 {
        assert!(sweep[i].abs() < 0.003, "sweep axis {i}: {:.4} %", sweep[i] * 100.0);
        // The true rate is 1.03 × the commanded one: K comes out 1/1.03 too small.
        assert!((paper[i] - (1.0 / 1.03 - 1.0)).abs() < 0.005, "paper axis {i}: {:.4} %", paper[i] * 100.0);
    }
    let q = s.sweep.unwrap().quality;
    assert!(q.invariant_after.relative_std() < q.invariant_before.relative_std());
    assert_eq!(q.poses, 13);
}
