//! calib's tests in one binary: one link, and every file's runs share the test threads.

mod allan;
mod arduino;
mod common;
mod corruption;
mod export;
mod flash_usb;
mod mag;
mod mirrored;
mod offline;
mod port;
mod real;
mod real_boards;
mod report;
