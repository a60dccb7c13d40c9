//! rig-sim's tests in one binary: one link, and every file's runs share the test threads.

mod bmi270;
mod bmm150;
mod bootloader;
mod estimators;
mod harness;
mod losses;
mod precision;
mod procedure;
mod record;
mod rtt;
mod sensor;
mod serial;
mod sim;
mod storage;
