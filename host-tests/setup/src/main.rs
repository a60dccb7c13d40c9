//! `gyrocal-setup COMMAND [ARGS…]`: the cargo aliases of the README's commands. Sets up what
//! COMMAND needs (the toolchain's targets and components, the emulator's build tools, the
//! firmware's linker), installing what is missing, says what a first run builds, then runs cargo.
//! `gyrocal-setup setup` does the set-up of every command and prints the shell `export` lines of
//! the environment it found or made (`eval "$(cargo setup)"`, as `.ci/run` does).

use gyrocal_setup::{
    compiler_headers, find_linker, missing_message, Linker, Platform, Probe, SystemTool, ToolchainFile, Wheels, FLIP_LINK_VERSION, WHEELS,
};
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};
use std::time::Instant;

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

const JOBS: [Job; 5] = [
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
    Job { name: "setup", cargo: &[], emulator: true, firmware: true, exec: None, first_build: None },
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
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| root().join("target"));
    let tools = target.join("tools");
    let mut env = Env { probe: Probe::from_env(), vars: Vec::new() };
    // The system's tools first: what cannot be installed stops the command within seconds.
    let set_up = if job.emulator { emulator(&mut env, &tools, job.name) } else { Ok(()) }.and_then(|()| toolchain()).and_then(|()| {
        if job.firmware {
            linker(&mut env, &tools)
        } else {
            Ok(())
        }
    });
    if let Err(e) = set_up {
        eprint!("gyrocal: {e}");
        if !e.ends_with('\n') {
            eprintln!();
        }
        return ExitCode::from(1);
    }
    let Ok(path) = std::env::join_paths(&env.probe.path) else {
        eprintln!("gyrocal-setup: PATH has a directory with a ':' in its name");
        return ExitCode::from(1);
    };
    if job.cargo.is_empty() {
        let quote = |v: &OsString| format!("'{}'", v.to_string_lossy().replace('\'', "'\\''"));
        println!("export PATH={}", quote(&path));
        for (k, v) in &env.vars {
            println!("export {k}={}", quote(v));
        }
        return ExitCode::SUCCESS;
    }
    first_run_note(job, &target);
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.arg(job.cargo[0]).args(HOST).args(&job.cargo[1..]).current_dir(root()).env("PATH", &path).envs(env.vars.iter().cloned());
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
        cmd.current_dir(root()).env("PATH", &path).envs(env.vars.iter().cloned());
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

/// The environment the command runs in: the `PATH` and `LIBCLANG_PATH` the tools were found by
/// (with the project's own tools first) and the variables the set-up adds.
struct Env {
    probe: Probe,
    vars: Vec<(&'static str, OsString)>,
}

impl Env {
    fn set(&mut self, key: &'static str, value: OsString) {
        self.vars.retain(|(k, _)| *k != key);
        self.vars.push((key, value));
    }
}

/// Output of `program args…` (stdout), or why it could not be run.
fn output(program: &str, args: &[&str]) -> Result<String, String> {
    let o = Command::new(program).args(args).current_dir(root()).output().map_err(|e| format!("cannot run {program}: {e}"))?;
    if o.status.success() {
        Ok(String::from_utf8_lossy(&o.stdout).into_owned())
    } else {
        Err(format!("`{program} {}` failed ({}): {}", args.join(" "), o.status, String::from_utf8_lossy(&o.stderr).trim()))
    }
}

/// Runs `program args…` with `envs` and its output shown (a step of an install), or says why it
/// failed.
fn step(program: &str, args: &[&str], envs: &[(&str, &str)]) -> Result<(), String> {
    let status = Command::new(program)
        .args(args)
        .envs(envs.iter().copied())
        .current_dir(root())
        .status()
        .map_err(|e| format!("cannot run {program}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("`{program} {}` failed ({status})", args.join(" ")))
    }
}

/// Adds the targets and components of `rust-toolchain.toml` that the active toolchain lacks
/// (rustup adds them only when it installs a toolchain, not to one already present).
fn toolchain() -> Result<(), String> {
    let file = ToolchainFile::parse(&std::fs::read_to_string(root().join("rust-toolchain.toml")).unwrap_or_default());
    let host = output("rustc", &["-vV"])?.lines().find_map(|l| l.strip_prefix("host: ").map(str::to_string)).unwrap_or_default();
    let (components, targets) =
        match (output("rustup", &["component", "list", "--installed"]), output("rustup", &["target", "list", "--installed"])) {
            (Ok(c), Ok(t)) => file.missing(&c, &t, &host),
            (Err(e), _) | (_, Err(e)) => {
                // Without rustup the toolchain's own directories tell whether a target is there.
                let sysroot = output("rustc", &["--print", "sysroot"])?;
                let absent: Vec<&String> =
                    file.targets.iter().filter(|t| !Path::new(sysroot.trim()).join("lib/rustlib").join(t).is_dir()).collect();
                if absent.is_empty() {
                    return Ok(());
                }
                return Err(format!(
                    "the toolchain lacks the target {absent:?} of rust-toolchain.toml and rustup cannot add it ({e}): \
                 install rustup (https://rustup.rs), then run the command again"
                ));
            }
        };
    if components.is_empty() && targets.is_empty() {
        return Ok(());
    }
    let t0 = Instant::now();
    for (kind, names, what) in [("target", &targets, "the firmware's"), ("component", &components, "rust-toolchain.toml's")] {
        if names.is_empty() {
            continue;
        }
        eprintln!(
            "gyrocal: the toolchain lacks {what} {kind} {} (rust-toolchain.toml; a toolchain installed before keeps its own set): \
             rustup {kind} add {}",
            names.join(", "),
            names.join(" ")
        );
        let mut args = vec![kind, "add"];
        args.extend(names.iter().map(String::as_str));
        step("rustup", &args, &[])?;
    }
    eprintln!("gyrocal: toolchain ready ({:.0} s)", t0.elapsed().as_secs_f64());
    Ok(())
}

/// Finds the Unicorn emulator's build tools and installs what is missing: cmake and libclang from
/// PyPI's wheels into `tools/py` (no root, nothing outside the project touched, any Linux with
/// Python); where that fails, with apt when this runs as root or with password-less sudo on
/// Debian/Ubuntu; what neither can give (a C compiler, make, without root) is named with its
/// install line for each platform.
fn emulator(env: &mut Env, tools: &Path, command: &str) -> Result<(), String> {
    let missing = env.probe.missing_for_emulator();
    if missing.is_empty() {
        return Ok(());
    }
    let platform = Platform::detect(std::fs::read_to_string("/etc/os-release").ok().as_deref());
    let mut failed = String::new();
    if !missing.iter().any(|t| matches!(t, SystemTool::CCompiler | SystemTool::Make)) {
        let wheels = Wheels { dir: tools.join("py") };
        match install_wheels(&wheels).and_then(|()| use_wheels(env, &wheels, &missing)) {
            Ok(()) => return Ok(()),
            Err(e) => {
                eprintln!("gyrocal: the wheels' way failed: {e}");
                failed = format!("(PyPI's wheels were tried: {e})\n");
            }
        }
    }
    if platform == Some(Platform::Debian) {
        if let Some(sudo) = privileged() {
            apt(&sudo, &platform.map(|p| p.packages(&missing)).unwrap_or_default())?;
            let after = env.probe.missing_for_emulator();
            if after.is_empty() {
                return Ok(());
            }
            failed = format!("{failed}(apt-get installed its packages, but these are still missing: {after:?})\n");
        }
    }
    let message = missing_message(command, &missing, platform);
    Err(format!("{}{failed}", message.trim_start_matches("gyrocal: ")))
}

/// `pip install --target` of the pinned wheels into `wheels.dir`, unless an earlier run did.
fn install_wheels(wheels: &Wheels) -> Result<(), String> {
    if wheels.installed() {
        return Ok(());
    }
    let t0 = Instant::now();
    eprintln!(
        "gyrocal: cmake and libclang for the Unicorn emulator's build: installing PyPI's wheels {} into {} \
         (python3 -m pip install --target; 150 MB, a few seconds; no root needed)",
        WHEELS.join(" "),
        wheels.dir.display()
    );
    let dir = wheels.dir.to_string_lossy();
    let mut args =
        vec!["-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--no-warn-script-location", "--upgrade", "--target", &dir];
    args.extend(WHEELS);
    // pip's warning for root is about the system's site-packages; this is a target directory.
    step("python3", &args, &[("PIP_ROOT_USER_ACTION", "ignore")])?;
    if !wheels.installed() {
        return Err(format!("pip left no cmake in {} or no libclang in {}", wheels.cmake_bin().display(), wheels.libclang_dir().display()));
    }
    eprintln!("gyrocal: wheels installed ({:.0} s)", t0.elapsed().as_secs_f64());
    Ok(())
}

/// Points the command at the wheels for what the system lacks: cmake first on `PATH`; libclang by
/// `LIBCLANG_PATH`, with the C compiler's own headers for bindgen (`BINDGEN_EXTRA_CLANG_ARGS`).
fn use_wheels(env: &mut Env, wheels: &Wheels, missing: &[SystemTool]) -> Result<(), String> {
    let mut probe = env.probe.clone();
    let mut vars = Vec::new();
    if missing.contains(&SystemTool::Cmake) {
        probe.path.insert(0, wheels.cmake_bin());
    }
    if missing.contains(&SystemTool::Libclang) {
        let cc = ["cc", "gcc", "clang"].iter().find_map(|c| probe.which(c)).ok_or("no C compiler on PATH")?;
        let include = output(&cc.to_string_lossy(), &["-print-file-name=include"])?;
        let headers = compiler_headers(Path::new(include.trim()))?;
        let mut args = std::env::var_os("BINDGEN_EXTRA_CLANG_ARGS").unwrap_or_default();
        if !args.is_empty() {
            args.push(" ");
        }
        args.push(format!("-isystem {}", headers.display()));
        probe.libclang_path = Some(wheels.libclang_dir());
        vars.push(("LIBCLANG_PATH", wheels.libclang_dir().into_os_string()));
        vars.push(("BINDGEN_EXTRA_CLANG_ARGS", args));
    }
    let still = probe.missing_for_emulator();
    if !still.is_empty() {
        return Err(format!("the wheels in {} do not give {still:?}", wheels.dir.display()));
    }
    env.probe = probe;
    for (k, v) in vars {
        env.set(k, v);
    }
    Ok(())
}

/// How this process can run apt-get: as root (no prefix) or with password-less sudo (`sudo -n`).
fn privileged() -> Option<Vec<&'static str>> {
    if output("id", &["-u"]).is_ok_and(|u| u.trim() == "0") {
        Some(Vec::new())
    } else if output("sudo", &["-n", "true"]).is_ok() {
        Some(vec!["sudo", "-n"])
    } else {
        None
    }
}

/// `apt-get update` and `apt-get install -y packages`, as root or through `sudo -n`.
fn apt(sudo: &[&str], packages: &[&str]) -> Result<(), String> {
    let t0 = Instant::now();
    let how = if sudo.is_empty() { "as root" } else { "with password-less sudo" };
    eprintln!("gyrocal: installing Debian's {} with apt-get ({how}, about a minute)", packages.join(" "));
    let run = |args: &[&str]| {
        let mut all: Vec<&str> = sudo.to_vec();
        all.push("apt-get");
        all.extend(args);
        step(all[0], &all[1..], &[("DEBIAN_FRONTEND", "noninteractive")])
    };
    run(&["update", "-qq"])?;
    let mut install = vec!["install", "-y", "-qq"];
    install.extend(packages);
    run(&install)?;
    eprintln!("gyrocal: apt-get done ({:.0} s)", t0.elapsed().as_secs_f64());
    Ok(())
}

/// flip-link on `PATH`, in `tools/bin`, or installed there; the project's copy first on `PATH`.
fn linker(env: &mut Env, tools: &Path) -> Result<(), String> {
    match find_linker(&env.probe, tools) {
        Linker::OnPath(_) => return Ok(()),
        Linker::InProject(_) => {}
        Linker::Missing => install_flip_link(tools)?,
    }
    env.probe.path.insert(0, tools.join("bin"));
    Ok(())
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
