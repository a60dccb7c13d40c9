//! What the README's commands need before their long builds start, found or named.
//!
//! `cargo demo`, `cargo test-host`, `cargo results` and `cargo flash-usb` run through
//! `gyrocal-setup` (`.cargo/config.toml`): it looks for the system's build tools of the Unicorn
//! emulator (cmake, a C compiler, make, libclang for bindgen) and for the firmware's linker
//! (flip-link). What only the system's package manager has is named with its one-line install
//! command for each platform, before anything is compiled; flip-link, which cargo can install, is
//! installed into the project's own `target/tools` (never replaced by another linker).

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
        // The package of each tool on this Linux platform (Debian's and Arch's compiler and make
        // share one), each named once, in the order of `missing`.
        let mut packages: Vec<&str> = Vec::new();
        for &tool in missing {
            let package = match (self, tool) {
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
        format!("{command} {}", packages.join(" "))
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
