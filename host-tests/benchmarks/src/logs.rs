//! A log's text through `gyrocal-calib`'s code, as a user runs it.

use calib::{csvlog, offline};

/// `text` read and calibrated at the setup it states (the tool's default options); the error as
/// the tool words it.
pub fn calibrate(text: &str) -> Result<offline::Calibration, String> {
    let log = csvlog::parse(text).map_err(|e| e.to_string())?;
    offline::calibrate_log(&log, &offline::Options::default(), None).map_err(|e| e.to_string())
}
