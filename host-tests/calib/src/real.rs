//! Public sessions recorded on real IMUs by other projects, read from `../shared/data/real/`
//! beside the repository (sources, licences and conversions in its README; never copied into the
//! project), and the peer's result on them.

use std::path::PathBuf;
use std::process::Command;

/// imucal 2.6.0 (PyPI) `FerrarisCalibration`'s gyro `K` diagonal on the continuous Ferraris
/// session with imucal's own section list (`example_data/example_ferraris_session_list.json`,
/// 102.4 Hz), converted to `ω = K (g − b)` as `K = (K_g R_g)⁻¹`.
pub const IMUCAL_FERRARIS_K: [f64; 3] = [0.972794, 1.01787, 1.00169];

/// The directory of the shared real recordings.
pub fn dir() -> PathBuf {
    crate::firmware::root().join("../shared/data/real")
}

/// A session's text as a log (`gzip -dc` of `<name>.gz`). imu_tk's whitespace-separated raw
/// counts (`.txt`) get the log's header and commas, numbers as they are: what a user converting
/// it without the sensitivities would write.
pub fn session(name: &str) -> Result<String, String> {
    let path = dir().join(format!("{name}.gz"));
    let out = Command::new("gzip").arg("-dc").arg(&path).output().map_err(|e| format!("gzip: {e}"))?;
    if !out.status.success() {
        return Err(format!("{}: cannot read it ({})", path.display(), out.status));
    }
    let text = String::from_utf8(out.stdout).map_err(|e| format!("{}: {e}", path.display()))?;
    if !name.ends_with(".txt") {
        return Ok(text);
    }
    let rows: Vec<String> = text.lines().map(|l| format!("{},", l.split_whitespace().collect::<Vec<_>>().join(","))).collect();
    Ok(format!("t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,servo_deg\n{}\n", rows.join("\n")))
}
