//! What the README's commands need before their long builds start, found or installed.
//!
//! `cargo demo`, `cargo test-host`, `cargo results` and `cargo flash-usb` run through
//! `gyrocal-setup` (`.cargo/config.toml`). Before anything is compiled it adds what
//! `rust-toolchain.toml` asks of the toolchain and rustup has not installed (a toolchain that was
//! already present keeps its own targets), finds the Unicorn emulator's build tools (cmake, a C
//! compiler, make, libclang for bindgen) and the firmware's linker (flip-link), and installs what
//! is missing: cmake and libclang from PyPI's wheels into the project's own `target/tools/py`
//! (no root needed, nothing outside the project touched), else with apt where it runs as root or
//! with password-less sudo on Debian/Ubuntu; flip-link with `cargo install` into `target/tools`
//! (never replaced by another linker). What it cannot install (a C compiler, make) is named with
//! its one-line install command for each platform.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// A tool a command needs that the system's package manager provides.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SystemTool {
    /// `cmake`: builds Unicorn's C sources.
    Cmake,
    /// `cc` (or `gcc`/`clang`): compiles them.
    CCompiler,
    /// `make`: cmake's default generator.
    Make,
    /// `libclang`: bindgen generates Unicorn's Rust bindings with it.
    Libclang,
}

impl SystemTool {
    /// What the tool is and what it is needed for.
    pub fn what(self) -> &'static str {
        match self {
            SystemTool::Cmake => "cmake (builds the Unicorn emulator's C sources): not on PATH",
            SystemTool::CCompiler => "a C compiler (cc, gcc or clang): not on PATH",
            SystemTool::Make => "make (cmake's build tool): not on PATH",
            SystemTool::Libclang => {
                "libclang (bindgen's, for Unicorn's bindings): no libclang.so in LIBCLANG_PATH, \
                 llvm-config --libdir or the system's library directories"
            }
        }
    }
}

/// The platforms whose install line is named.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Platform {
    /// Debian, Ubuntu and their derivatives (apt).
    Debian,
    /// Fedora, RHEL and their derivatives (dnf).
    Fedora,
    /// Arch and its derivatives (pacman).
    Arch,
    /// macOS (Xcode's command-line tools and Homebrew).
    MacOs,
}

impl Platform {
    /// Every platform, in the order the message lists them.
    pub const ALL: [Platform; 4] = [Platform::Debian, Platform::Fedora, Platform::Arch, Platform::MacOs];

    /// This machine's platform: macOS by the build target, Linux distributions by the `ID` and
    /// `ID_LIKE` of `/etc/os-release` (`os_release`, its text); `None` when unknown.
    pub fn detect(os_release: Option<&str>) -> Option<Platform> {
        if cfg!(target_os = "macos") {
            return Some(Platform::MacOs);
        }
        let ids: Vec<&str> = os_release?
            .lines()
            .filter_map(|l| l.strip_prefix("ID=").or_else(|| l.strip_prefix("ID_LIKE=")))
            .flat_map(|v| v.trim_matches('"').split_whitespace())
            .collect();
        let has = |names: &[&str]| ids.iter().any(|id| names.contains(id));
        if has(&["debian", "ubuntu"]) {
            Some(Platform::Debian)
        } else if has(&["fedora", "rhel", "centos"]) {
            Some(Platform::Fedora)
        } else if has(&["arch"]) {
            Some(Platform::Arch)
        } else {
            None
        }
    }

    /// The platform's name in the message.
    pub fn name(self) -> &'static str {
        match self {
            Platform::Debian => "Debian/Ubuntu",
            Platform::Fedora => "Fedora",
            Platform::Arch => "Arch",
            Platform::MacOs => "macOS",
        }
    }

    /// The packages of `missing` on this Linux platform (Debian's and Arch's compiler and make
    /// share one), each named once, in the order of `missing`; empty on macOS.
    pub fn packages(self, missing: &[SystemTool]) -> Vec<&'static str> {
        use SystemTool::*;
        let mut packages: Vec<&str> = Vec::new();
        for &tool in missing {
            let package = match (self, tool) {
                (Platform::MacOs, _) => continue,
                (Platform::Debian, CCompiler | Make) => "build-essential",
                (Platform::Fedora, CCompiler) => "gcc",
                (Platform::Fedora, Make) => "make",
                (_, CCompiler | Make) => "base-devel",
                (_, Cmake) => "cmake",
                (Platform::Debian, Libclang) => "libclang-dev",
                (Platform::Fedora, Libclang) => "clang-devel",
                (_, Libclang) => "clang",
            };
            if !packages.contains(&package) {
                packages.push(package);
            }
        }
        packages
    }

    /// The one-line command that installs `missing` on this platform.
    pub fn install_line(self, missing: &[SystemTool]) -> String {
        use SystemTool::*;
        let command = match self {
            Platform::Debian => "sudo apt-get update && sudo apt-get install -y",
            Platform::Fedora => "sudo dnf install -y",
            Platform::Arch => "sudo pacman -S --needed",
            Platform::MacOs => {
                // The command-line tools bring clang, libclang and make; Homebrew brings cmake.
                let xcode = missing.iter().any(|t| *t != Cmake);
                return match (xcode, missing.contains(&Cmake)) {
                    (true, true) => "xcode-select --install && brew install cmake".into(),
                    (true, false) => "xcode-select --install".into(),
                    _ => "brew install cmake".into(),
                };
            }
        };
        format!("{command} {}", self.packages(missing).join(" "))
    }
}

/// Where the tools are looked for: the `PATH` directories, `LIBCLANG_PATH`, and the root under
/// which the system's library directories are searched (`/`; a test's directory in tests).
#[derive(Clone, Debug)]
pub struct Probe {
    /// The directories of `PATH`, in order.
    pub path: Vec<PathBuf>,
    /// `LIBCLANG_PATH`: a directory or the library itself.
    pub libclang_path: Option<PathBuf>,
    /// The file-system root of the library directories (`/`).
    pub root: PathBuf,
}

impl Probe {
    /// This process's `PATH` and `LIBCLANG_PATH`, the system's root.
    pub fn from_env() -> Probe {
        Probe {
            path: std::env::var_os("PATH").map(|p| std::env::split_paths(&p).collect()).unwrap_or_default(),
            libclang_path: std::env::var_os("LIBCLANG_PATH").map(PathBuf::from),
            root: PathBuf::from("/"),
        }
    }

    /// The first executable named `name` on `PATH`.
    pub fn which(&self, name: &str) -> Option<PathBuf> {
        self.path.iter().map(|d| d.join(name)).find(|p| is_executable(p))
    }

    /// What the Unicorn emulator's build needs that is not here, in the order the build would
    /// stop for it.
    pub fn missing_for_emulator(&self) -> Vec<SystemTool> {
        let mut missing = Vec::new();
        if !["cc", "gcc", "clang"].iter().any(|c| self.which(c).is_some()) {
            missing.push(SystemTool::CCompiler);
        }
        if self.which("make").is_none() {
            missing.push(SystemTool::Make);
        }
        if self.which("cmake").is_none() {
            missing.push(SystemTool::Cmake);
        }
        if self.libclang().is_none() {
            missing.push(SystemTool::Libclang);
        }
        missing
    }

    /// A libclang bindgen's clang-sys would load: in `LIBCLANG_PATH`, in `llvm-config
    /// --libdir`, or in the directories clang-sys 1.9 searches (`build/common.rs`).
    pub fn libclang(&self) -> Option<PathBuf> {
        if let Some(p) = &self.libclang_path {
            if p.is_file() {
                return Some(p.clone());
            }
            if let Some(found) = libclang_in(p) {
                return Some(found);
            }
        }
        if let Some(llvm_config) = self.which("llvm-config") {
            let out = std::process::Command::new(llvm_config).arg("--libdir").output().ok()?;
            let dir = PathBuf::from(String::from_utf8_lossy(&out.stdout).trim());
            if let Some(found) = libclang_in(&dir) {
                return Some(found);
            }
        }
        let patterns: &[&str] = if cfg!(target_os = "macos") {
            &[
                "usr/local/opt/llvm*/lib/llvm*/lib",
                "Library/Developer/CommandLineTools/usr/lib",
                "Applications/Xcode.app/Contents/Developer/Toolchains/XcodeDefault.xctoolchain/usr/lib",
                "usr/local/opt/llvm*/lib",
                "opt/homebrew/opt/llvm/lib",
            ]
        } else {
            &["usr/local/llvm*/lib*", "usr/local/lib*/*/*", "usr/local/lib*/*", "usr/local/lib*", "usr/lib*/*/*", "usr/lib*/*", "usr/lib*"]
        };
        patterns.iter().flat_map(|p| expand(&self.root, p)).find_map(|d| libclang_in(&d))
    }
}

fn is_executable(p: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        p.metadata().map(|m| m.is_file() && m.permissions().mode() & 0o111 != 0).unwrap_or(false)
    }
    #[cfg(not(unix))]
    {
        p.is_file()
    }
}

/// The libclang in `dir`: clang-sys's names (`libclang.so`, `libclang-*.so`, `libclang.so.*`,
/// `libclang-*.so.*`; `libclang.dylib` on macOS), `libclang-cpp` left out.
fn libclang_in(dir: &Path) -> Option<PathBuf> {
    let entries = std::fs::read_dir(dir).ok()?;
    entries.filter_map(Result::ok).map(|e| e.path()).find(|p| {
        let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let lib = name == "libclang.so"
            || name == "libclang.dylib"
            || name.starts_with("libclang.so.")
            || (name.starts_with("libclang-") && !name.starts_with("libclang-cpp") && (name.ends_with(".so") || name.contains(".so.")));
        lib && p.is_file()
    })
}

/// The directories under `root` that `pattern` matches, `*` matching within one component.
fn expand(root: &Path, pattern: &str) -> Vec<PathBuf> {
    let mut dirs = vec![root.to_path_buf()];
    for part in pattern.split('/') {
        let mut next = Vec::new();
        for d in &dirs {
            match part.split_once('*') {
                None => next.push(d.join(part)),
                Some((pre, post)) => {
                    let Ok(entries) = std::fs::read_dir(d) else { continue };
                    let mut found: Vec<PathBuf> = entries
                        .filter_map(Result::ok)
                        .filter(|e| {
                            let n = e.file_name();
                            let n = n.to_string_lossy();
                            n.len() >= pre.len() + post.len() && n.starts_with(pre) && n.ends_with(post)
                        })
                        .map(|e| e.path())
                        .collect();
                    found.sort();
                    next.extend(found);
                }
            }
        }
        dirs = next.into_iter().filter(|d| d.is_dir()).collect();
    }
    dirs
}

/// The message for `missing` system tools: each named with what it is for, then the install
/// line of every platform, this machine's (`here`) marked.
pub fn missing_message(command: &str, missing: &[SystemTool], here: Option<Platform>) -> String {
    let mut m = format!("gyrocal: `cargo {command}` needs what is not on this machine (nothing was built):\n");
    for t in missing {
        let _ = writeln!(m, "  - {}", t.what());
    }
    m.push_str("Install with your package manager, then run the command again:\n");
    for p in Platform::ALL {
        let mark = if Some(p) == here { "   <- this machine" } else { "" };
        let _ = writeln!(m, "  {:<14} {}{mark}", format!("{}:", p.name()), p.install_line(missing));
    }
    m
}

/// The flip-link version `cargo install` fetches (the one the firmware is built and CI'd with).
pub const FLIP_LINK_VERSION: &str = "0.1.12";

/// Where the firmware's linker comes from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Linker {
    /// flip-link on `PATH`.
    OnPath(PathBuf),
    /// flip-link in the project's `target/tools/bin` (installed by an earlier run).
    InProject(PathBuf),
    /// Not here: to be installed with `cargo install` into `target/tools`.
    Missing,
}

/// Finds flip-link on `PATH` or in `tools` (`target/tools`).
pub fn find_linker(probe: &Probe, tools: &Path) -> Linker {
    let local = tools.join("bin").join("flip-link");
    if let Some(p) = probe.which("flip-link") {
        Linker::OnPath(p)
    } else if is_executable(&local) {
        Linker::InProject(local)
    } else {
        Linker::Missing
    }
}

/// What `rust-toolchain.toml` asks rustup for besides the channel.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ToolchainFile {
    /// `components` (`clippy`, `llvm-tools`, …).
    pub components: Vec<String>,
    /// `targets` (`thumbv7em-none-eabihf`).
    pub targets: Vec<String>,
}

impl ToolchainFile {
    /// The `components` and `targets` arrays of a `rust-toolchain.toml` (`text`), on one line or
    /// several; comments and other keys ignored.
    pub fn parse(text: &str) -> ToolchainFile {
        let lines: Vec<&str> = text.lines().map(|l| l.split('#').next().unwrap_or("")).collect();
        let array = |key: &str| -> Vec<String> {
            let Some(i) = lines.iter().position(|l| l.split_once('=').is_some_and(|(k, _)| k.trim() == key)) else {
                return Vec::new();
            };
            let rest = lines[i..].join(" ");
            let value = rest.split_once('=').map_or("", |(_, v)| v).trim_start();
            let Some(inner) = value.strip_prefix('[').and_then(|v| v.split(']').next()) else { return Vec::new() };
            inner.split(',').map(|v| v.trim().trim_matches(['"', '\'']).to_string()).filter(|v| !v.is_empty()).collect()
        };
        ToolchainFile { components: array("components"), targets: array("targets") }
    }

    /// The components and targets not in rustup's `component list --installed` (lines
    /// `NAME-HOST`) and `target list --installed` (one target a line), for the toolchain's `host`.
    pub fn missing(&self, installed_components: &str, installed_targets: &str, host: &str) -> (Vec<String>, Vec<String>) {
        let has_component = |c: &str| installed_components.lines().any(|l| l.trim() == c || l.trim() == format!("{c}-{host}"));
        let has_target = |t: &str| installed_targets.lines().any(|l| l.trim() == t);
        (
            self.components.iter().filter(|c| !has_component(c)).cloned().collect(),
            self.targets.iter().filter(|t| !has_target(t)).cloned().collect(),
        )
    }
}

/// The wheels of PyPI that give the Unicorn build its cmake and bindgen its libclang without root,
/// pinned to the versions tried (docs/testing.md#a-fresh-machine).
pub const WHEELS: [&str; 2] = ["cmake==4.4.5", "libclang==18.1.1"];

/// cmake and libclang from PyPI's wheels, installed with `pip install --target` into `dir`
/// (`target/tools/py`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Wheels {
    /// The `--target` directory.
    pub dir: PathBuf,
}

impl Wheels {
    /// The directory of the `cmake` wheel's executable (its `bin/cmake` is a Python launcher).
    pub fn cmake_bin(&self) -> PathBuf {
        self.dir.join("cmake/data/bin")
    }

    /// The directory of the `libclang` wheel's `libclang.so` (for `LIBCLANG_PATH`).
    pub fn libclang_dir(&self) -> PathBuf {
        self.dir.join("clang/native")
    }

    /// Both tools are in `dir`.
    pub fn installed(&self) -> bool {
        is_executable(&self.cmake_bin().join("cmake")) && libclang_in(&self.libclang_dir()).is_some()
    }
}

/// The C headers every compiler ships itself (`stdbool.h`, `stddef.h`, `stdarg.h`), which a
/// libclang without its own resource directory (the wheel's) cannot find: bindgen is pointed at
/// the C compiler's (`cc -print-file-name=include`, `include`: its answer) with `-isystem`.
pub fn compiler_headers(include: &Path) -> Result<PathBuf, String> {
    let missing: Vec<&str> = ["stdbool.h", "stddef.h", "stdarg.h"].into_iter().filter(|h| !include.join(h).is_file()).collect();
    if include.is_absolute() && missing.is_empty() {
        Ok(include.to_path_buf())
    } else {
        Err(format!(
            "the C compiler's own headers ({}) are not in {:?} (`cc -print-file-name=include`): the wheel's libclang has none of its own",
            missing.join(", "),
            include
        ))
    }
}
