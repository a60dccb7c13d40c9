//! Every loss enters the procedure: lost samples and a sensor fault fail a running calibration
//! with their own error, and a command queue that overflowed can never let a store through.

use calib_core::procedure::{Command, Config, ErrorClass, Led, Phase, Procedure, Report};
use calib_core::Error;
use rig_sim::harness::at;
use rig_sim::harness::{run, Faults};
use rig_sim::sim::Rig;
use rig_sim::variant::Variant;

#[test]
fn samples_lost_during_the_rig_moves_fail_with_that_error_and_store_nothing() {
    for phase in [Phase::Bias, Phase::HandHeld, Phase::RigPoses, Phase::Spin] {
        let mut rig = Rig::new(Variant::Hobby.config(50, 0), 50);
        let mut p = Procedure::new(Config::default(), None);
        let out = run(&mut rig, &mut p, Faults { samples_lost_in: Some(phase), ..Faults::default() }, 900.0, |_, _, _| {});
        assert_eq!(out.error, Some(Error::SamplesLost { count: 1 }), "{phase:?}");
        assert!(out.stored.is_empty() && out.applied.is_empty(), "{phase:?}");
        assert_eq!(out.led, Some(Led::Error(ErrorClass::Sensor)), "{phase:?}");
    }
}

#[test]
fn a_sensor_fault_fails_a_running_calibration_and_is_ignored_when_idle() {
    let mut p = Procedure::new(Config::default(), None);
    p.handle_sensor_fault();
    assert_eq!((p.phase(), p.poll()), (Phase::Idle, None), "idle: nothing to fail");
    p.handle_button(at(0.0));
    while p.poll().is_some() {}
    p.handle_sensor_fault();
    let cmds: Vec<Command> = std::iter::from_fn(|| p.poll()).collect();
    assert_eq!(p.phase(), Phase::Failed);
    assert!(cmds.contains(&Command::Report(Report::Failed(Error::SensorFault))), "{cmds:?}");
}

#[test]
fn a_queue_that_overflows_just_before_the_store_fails_and_no_store_follows() {
    // The shell stops draining in the paper's spin (a servo command every sample) until
    // well past the solve: the overflow fails the calibration; the spin does not go on to a
    // store.
    let mut rig = Rig::new(Variant::Hobby.config(51, 0), 51);
    let mut p = Procedure::new(Config::default(), None);
    let faults = Faults { no_drain_in: Some((Phase::Spin, 119 * 30)), ..Faults::default() };
    let out = run(&mut rig, &mut p, faults, 900.0, |_, _, _| {});
    assert_eq!(out.error, Some(Error::CommandQueueFull), "{:?}", out.reports.last());
    assert!(out.stored.is_empty() && out.applied.is_empty(), "stored after a failure: {:?}", out.stored);
    assert_eq!(p.phase(), Phase::Failed);
}
