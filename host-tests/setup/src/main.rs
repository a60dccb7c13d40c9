//! `gyrocal-setup COMMAND [ARGS…]`: the cargo aliases of the README's commands. Checks what
//! COMMAND needs (the emulator's system tools, the firmware's linker), installs flip-link into
//! `target/tools` when it is missing, says what a first run builds, then runs cargo.

use gyrocal_setup::{find_linker, missing_message, Linker, Platform, Probe, FLIP_LINK_VERSION};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

/// A README command: its cargo arguments and what its build needs.
struct Job {
    name: &'static str,
    cargo: &'static [&'static str],
    /// Builds the Unicorn emulator (vboard): cmake, a C compiler, make, libclang.
    emulator: bool,
    /// Builds the firmware: flip-link.
    firmware: bool,
    /// Run this binary of the build (beside this one) with the arguments, rather than `cargo
    /// run`: `cargo` then only builds, with the package set the binary itself builds with, so
    /// that the two share one feature resolution (a `cargo run -p benchmarks` would compile the
    /// shared crates a second time).
    exec: Option<&'static str>,
    /// What a first run of an emulator job compiles besides the firmware, and how long it took
    /// on 2 cores (docs/testing.md#a-fresh-machine).
    first_build: Option<&'static str>,
}

const HOST: [&str; 4] = ["--profile", "host", "--target", "host-tuple"];

const JOBS: [Job; 4] = [
    Job {
        name: "demo",
        cargo: &["run", "-p", "vboard", "--bin", "demo", "--"],
        emulator: true,
        firmware: true,
        exec: None,
        first_build: Some("the host crates and the Unicorn emulator from its C sources (about 2 min on 2 cores)"),
    },
    Job {
        name: "test-host",
        cargo: &[
            "test",
            "-p",
            "calib-core",
            "-p",
            "calib",
            "-p",
            "rig-sim",
            "-p",
            "benchmarks",
            "-p",
            "vboard",
            "-p",
            "gyrocal-setup",
            "-p",
            "gyrocal-fuzz",
        ],
        emulator: true,
        firmware: true,
        exec: None,
        first_build: Some("the host crates, the Unicorn emulator from its C sources and the tests (about 4 min on 2 cores)"),
    },
    Job {
        name: "results",
        // The package set `results` builds the benchmarks and the demo with.
        cargo: &["build", "-p", "benchmarks", "-p", "vboard", "--bins"],
        emulator: true,
        firmware: true,
        exec: Some("results"),
        first_build: Some("the host crates, the Unicorn emulator from its C sources and the benchmarks (about 3 min on 2 cores)"),
    },
    Job {
        name: "flash-usb",
        cargo: &["run", "-p", "calib", "--bin", "gyrocal-flash", "--"],
        emulator: false,
        firmware: true,
        exec: None,
        first_build: None,
    },
];

/// The workspace root (this crate is `host-tests/setup`).
fn root() -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    p.canonicalize().unwrap_or(p)
}

fn main() -> ExitCode {
    let mut args = std::env::args().skip(1);
    let name = args.next().unwrap_or_default();
    let Some(job) = JOBS.iter().find(|j| j.name == name) else {
        let names: Vec<&str> = JOBS.iter().map(|j| j.name).collect();
        eprintln!("gyrocal-setup: unknown command {name:?} (one of: {})", names.join(", "));
        return ExitCode::from(2);
    };
    let rest: Vec<String> = args.collect();
    let probe = Probe::from_env();
    if job.emulator {
        let missing = probe.missing_for_emulator();
        if !missing.is_empty() {
            let os_release = std::fs::read_to_string("/etc/os-release").ok();
            eprint!("{}", missing_message(job.name, &missing, Platform::detect(os_release.as_deref())));
            return ExitCode::from(1);
        }
    }
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| root().join("target"));
    let tools = target.join("tools");
    let mut path = probe.path.clone();
    if job.firmware {
        match find_linker(&probe, &tools) {
            Linker::OnPath(_) => {}
            Linker::InProject(_) => path.insert(0, tools.join("bin")),
            Linker::Missing => {
                if let Err(e) = install_flip_link(&tools) {
                    eprintln!("gyrocal: {e}");
                    return ExitCode::from(1);
                }
                path.insert(0, tools.join("bin"));
            }
        }
    }
    first_run_note(job, &target);
    let Ok(path) = std::env::join_paths(path) else {
        eprintln!("gyrocal-setup: PATH has a directory with a ':' in its name");
        return ExitCode::from(1);
    };
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.arg(job.cargo[0]).args(HOST).args(&job.cargo[1..]).current_dir(root()).env("PATH", &path);
    if let Some(bin) = job.exec {
        match cmd.status() {
            Ok(s) if s.success() => {}
            Ok(s) => return ExitCode::from(s.code().unwrap_or(1).clamp(1, 255) as u8),
            Err(e) => {
                eprintln!("gyrocal-setup: cannot run cargo: {e}");
                return ExitCode::from(1);
            }
        }
        let dir = std::env::current_exe().ok().and_then(|e| e.parent().map(Path::to_path_buf)).unwrap_or_default();
        cmd = Command::new(dir.join(bin));
        cmd.current_dir(root()).env("PATH", &path);
    }
    cmd.args(&rest);
    // `cargo run`'s package variables are this crate's, not the command's.
    for (k, _) in std::env::vars_os() {
        let k = k.to_string_lossy();
        if k.starts_with("CARGO_PKG_")
            || k.starts_with("CARGO_MANIFEST_")
            || ["CARGO_CRATE_NAME", "CARGO_BIN_NAME", "CARGO_PRIMARY_PACKAGE"].contains(&k.as_ref())
        {
            cmd.env_remove(k.as_ref());
        }
    }
    run(cmd)
}

/// `cargo install flip-link` into `tools` (`target/tools/bin/flip-link`), for the host.
fn install_flip_link(tools: &Path) -> Result<(), String> {
    eprintln!(
        "gyrocal: flip-link, the firmware's linker (it puts the stack below the static RAM so that \
         an overflow faults), is not on PATH: installing flip-link {FLIP_LINK_VERSION} into {} \
         (cargo install from crates.io, about half a minute)",
        tools.display()
    );
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let status = Command::new(cargo)
        .args(["install", "flip-link", "--locked", "--version", FLIP_LINK_VERSION, "--target", "host-tuple", "--root"])
        .arg(tools)
        .current_dir(root())
        .status()
        .map_err(|e| format!("cannot run cargo to install flip-link: {e}"))?;
    if !status.success() {
        return Err(format!(
            "installing flip-link failed ({status}); install it yourself with `cargo install flip-link --locked` \
             (it needs crates.io), then run the command again"
        ));
    }
    Ok(())
}

/// Says what a first run compiles, and how long that takes on a 2-core machine, when the host
/// build (the emulator's output marks it) or the firmware is not in `target` yet.
fn first_run_note(job: &Job, target: &Path) {
    let profile_dir = std::env::current_exe().ok().and_then(|e| e.parent().map(Path::to_path_buf));
    let emulator_built = profile_dir
        .and_then(|d| std::fs::read_dir(d.join("build")).ok())
        .is_some_and(|mut es| es.any(|e| e.is_ok_and(|e| e.file_name().to_string_lossy().starts_with("unicorn-engine-sys-"))));
    let firmware_built = target.join("thumbv7em-none-eabihf/release/gyrocal-fw").is_file();
    let firmware = if job.firmware && !firmware_built { ", then the firmware (about 40 s)" } else { "" };
    if let Some(what) = job.first_build.filter(|_| !emulator_built) {
        eprintln!("gyrocal: first run: compiling {what}{firmware}; later runs start in seconds");
    } else if !firmware.is_empty() {
        eprintln!("gyrocal: compiling the firmware (about 40 s on 2 cores)");
    }
}

#[cfg(unix)]
fn run(mut cmd: Command) -> ExitCode {
    use std::os::unix::process::CommandExt;
    let e = cmd.exec();
    eprintln!("gyrocal-setup: cannot run cargo: {e}");
    ExitCode::from(1)
}

#[cfg(not(unix))]
fn run(mut cmd: Command) -> ExitCode {
    match cmd.status() {
        Ok(s) => ExitCode::from(s.code().unwrap_or(1) as u8),
        Err(e) => {
            eprintln!("gyrocal-setup: cannot run cargo: {e}");
            ExitCode::from(1)
        }
    }
}
