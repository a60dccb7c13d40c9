//! Helpers shared by the register-level model tests (`models.rs`, `usbd.rs`): a sparse RAM for
//! EasyDMA, the peripherals of a board just powered on (no CPU), register writes and reads, and
//! idle time.

use rig_sim::lsm_model::{Board, Lsm9ds1Model};
use rig_sim::nor::NorSim;
use rig_sim::sim::Rig;
use rig_sim::variant::Variant;
use std::cell::Cell;
use std::collections::HashMap;
use std::rc::Rc;
use vboard::periph::{Dma, Periph, ResetKind};

/// RAM for EasyDMA: unwritten bytes read 0.
#[derive(Default)]
pub struct Ram(HashMap<u64, u8>);

impl Dma for Ram {
    fn read(&mut self, addr: u64, buf: &mut [u8]) {
        for (i, b) in buf.iter_mut().enumerate() {
            *b = *self.0.get(&(addr + i as u64)).unwrap_or(&0);
        }
    }
    fn write(&mut self, addr: u64, data: &[u8]) {
        for (i, b) in data.iter().enumerate() {
            self.0.insert(addr + i as u64, *b);
        }
    }
}

/// The peripherals of `board` after a power-on reset, booted through the bootloader or cold.
pub fn periph(board: Board, bootloader: bool) -> Periph {
    let sensor = Lsm9ds1Model::new(Rig::new(Variant::Hobby.config(1, 0), 1), board);
    let mut p = Periph::new(sensor, NorSim::new(8, 1), Rc::new(Cell::new(0)));
    p.bootloader = bootloader;
    p.reset(ResetKind::PowerOn);
    p
}

/// Writes register `addr`.
pub fn w(p: &mut Periph, ram: &mut Ram, addr: u64, v: u32) {
    p.write(addr, v as u64, ram);
}

/// Reads register `addr`.
pub fn r(p: &mut Periph, addr: u64) -> u32 {
    p.read(addr) as u32
}

/// Lets `s` seconds pass (the CPU idle) and updates the models.
pub fn wait(p: &mut Periph, s: f64) {
    p.skipped_s += s;
    p.update();
}
