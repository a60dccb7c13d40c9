use rig_sim::lsm_model::Board;
use rig_sim::nor::NorSim;
use vboard::bench::{Bench, Event, Outcome};
#[test]
fn scratch_tilt_with_base_firmware() {
    let elf = std::fs::read(std::env::var("BASE_ELF").unwrap()).unwrap();
    let rig = rig_sim::pan_tilt::rig_config(36, 0);
    let mut b = Bench::new(elf, rig, 36, Board::Rev1, NorSim::new(8, 36), false).unwrap();
    b.run_for(2.0);
    let mut asked = false;
    let outcome = b.calibrate_with(300.0, |e, _| asked |= matches!(e, Event::HandHeldPose(_) | Event::Reattached));
    assert_eq!(outcome, Outcome::Done);
    assert!(!asked, "asked");
}
