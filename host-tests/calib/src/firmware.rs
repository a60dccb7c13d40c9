//! The firmware ELF of this workspace: `cargo build --release -p gyrocal-fw` in the workspace's
//! one target directory, one variant (feature set) at a time, each ELF copied out to
//! `target/firmware/<variant>/` ([`BINS`]) so that building another variant never replaces it.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The package's programs: the calibration firmware, and the example that loads its record
/// (`src/bin/calibrated-rates.rs`).
pub const BINS: [&str; 2] = ["gyrocal-fw", "calibrated-rates"];

/// The workspace root (this crate is `host-tests/calib`).
pub fn root() -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    p.canonicalize().unwrap_or(p)
}

/// The workspace's target directory (`CARGO_TARGET_DIR` if set, else `target/`).
pub fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| root().join("target"))
}

/// The directory of a variant's ELF: `target/firmware/default` or `target/firmware/<f1-f2>`.
pub fn variant_dir(features: &[&str]) -> PathBuf {
    let name = if features.is_empty() { "default".to_string() } else { features.join("-") };
    target_dir().join("firmware").join(name)
}

/// Builds the release firmware with `features` (nothing to do when it is up to date) and
/// returns the path of its copied-out ELF (the example's beside it, [`BINS`]). Builds and copies are serialised across threads and
/// processes by a lock file, so that the ELF copied is the one just built.
pub fn build(features: &[&str]) -> Result<PathBuf, String> {
    let dir = variant_dir(features);
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let lock_path = target_dir().join("firmware/.lock");
    let lock = std::fs::File::create(&lock_path).map_err(|e| format!("{}: {e}", lock_path.display()))?;
    lock.lock().map_err(|e| format!("{}: {e}", lock_path.display()))?;
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args(["build", "--release", "-p", "gyrocal-fw"]).current_dir(root());
    // The image is rustc's own: a workspace wrapper (CI lints the host crates with clippy-driver
    // while it builds them, and clippy-driver turns MIR optimisations off: +1.4 KiB of flash)
    // is not used for it.
    cmd.env_remove("RUSTC_WORKSPACE_WRAPPER");
    if !features.is_empty() {
        cmd.arg("--features").arg(features.join(","));
    }
    let status = cmd.status().map_err(|e| format!("cannot run cargo: {e}"))?;
    if !status.success() {
        return Err(format!("the firmware build failed ({status})"));
    }
    for bin in BINS {
        let (built, elf) = (target_dir().join("thumbv7em-none-eabihf/release").join(bin), dir.join(bin));
        std::fs::copy(&built, &elf).map_err(|e| format!("{} -> {}: {e}", built.display(), elf.display()))?;
    }
    Ok(dir.join(BINS[0]))
}
