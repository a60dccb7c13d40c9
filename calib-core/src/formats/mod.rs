//! The byte and text formats: the recorded log, the flash record and its A/B region, the
//! console's line protocol and text, the exports.

pub mod export;
pub mod log;
pub mod protocol;
pub mod record;
pub mod region;
pub mod text;
