//! The virtual board's tests in one binary: one link, and the long emulated runs of every file
//! share the test threads (they ran one file after another).

mod board;
mod boot;
mod common;
mod flash;
mod models;
mod runtime;
mod usb_firmware;
mod usbd;
