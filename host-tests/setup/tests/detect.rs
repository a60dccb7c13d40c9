//! The set-up check on a machine without the tools: the command stops before building anything
//! and names each missing tool with the exact install line; flip-link is found or planned.

use gyrocal_setup::{compiler_headers, find_linker, missing_message, Linker, Platform, Probe, SystemTool, ToolchainFile, WHEELS};
use std::path::{Path, PathBuf};
use std::process::Command;

/// A fresh directory under cargo's test scratch directory.
fn scratch(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("setup").join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// An executable shell script `name` in `dir` that exits 0.
fn tool(dir: &Path, name: &str) {
    script(dir, name, "exit 0");
}

/// An executable shell script `name` in `dir` with `body`.
fn script(dir: &Path, name: &str, body: &str) {
    use std::os::unix::fs::PermissionsExt;
    let p = dir.join(name);
    std::fs::write(&p, format!("#!/bin/sh\n{body}\n")).unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
}

/// A fake rustc and rustup in `bin`: the toolchain has the host's rust-std and rustfmt only;
/// every `add` is written to `log`.
fn fake_toolchain(bin: &Path, log: &Path) {
    script(bin, "rustc", "echo 'rustc 1.95.0'; echo 'host: x86_64-unknown-linux-gnu'");
    script(
        bin,
        "rustup",
        &format!(
            "case \"$1 $2\" in\n\
             'component list') printf 'cargo-x86_64-unknown-linux-gnu\\nrustfmt-x86_64-unknown-linux-gnu\\n' ;;\n\
             'target list') echo x86_64-unknown-linux-gnu ;;\n\
             *) echo \"$@\" >> {} ;;\n\
             esac",
            log.display()
        ),
    );
}

/// `gyrocal-setup setup` with `PATH` = `bin`, `LIBCLANG_PATH` as given, its tools in `target`.
fn setup(bin: &Path, libclang: Option<&Path>, target: &Path) -> std::process::Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_gyrocal-setup"));
    cmd.arg("setup").env("PATH", bin).env("CARGO_TARGET_DIR", target).env_remove("LIBCLANG_PATH").env_remove("BINDGEN_EXTRA_CLANG_ARGS");
    if let Some(l) = libclang {
        cmd.env("LIBCLANG_PATH", l);
    }
    cmd.output().unwrap()
}

#[test]
fn the_commands_stop_naming_the_install_line_when_path_lacks_the_tools() {
    let empty = scratch("empty-path");
    for command in ["demo", "test-host", "results"] {
        let out = Command::new(env!("CARGO_BIN_EXE_gyrocal-setup"))
            .arg(command)
            .env("PATH", &empty)
            .env_remove("LIBCLANG_PATH")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{command}: {err}");
        assert!(err.contains(&format!("`cargo {command}` needs what is not on this machine (nothing was built)")), "{err}");
        for named in ["cmake (builds the Unicorn emulator's C sources): not on PATH", "a C compiler", "make (cmake's build tool)"] {
            assert!(err.contains(named), "{command} does not name {named:?}: {err}");
        }
        // libclang is found or not by the machine's own library directories: both lines start so.
        for line in [
            "Debian/Ubuntu: sudo apt-get update && sudo apt-get install -y build-essential cmake",
            "Fedora:        sudo dnf install -y gcc make cmake",
            "Arch:          sudo pacman -S --needed base-devel cmake",
            "macOS:         xcode-select --install && brew install cmake",
        ] {
            assert!(err.contains(line), "{command} does not give {line:?}: {err}");
        }
        assert!(!err.contains("first run"), "{command} went on to build: {err}");
    }
}

#[test]
fn an_unknown_command_is_named() {
    let out = Command::new(env!("CARGO_BIN_EXE_gyrocal-setup")).arg("demp").output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown command \"demp\" (one of: demo, test-host, results, flash-usb, setup)"));
}

#[test]
fn libclang_is_looked_for_where_clang_sys_looks() {
    let root = scratch("root");
    let bin = scratch("bin");
    for t in ["cc", "make", "cmake"] {
        tool(&bin, t);
    }
    let probe = Probe { path: vec![bin.clone()], libclang_path: None, root: root.clone() };
    assert_eq!(probe.missing_for_emulator(), vec![SystemTool::Libclang]);
    let msg = missing_message("demo", &[SystemTool::Libclang], Some(Platform::Debian));
    assert!(msg.contains("libclang (bindgen's, for Unicorn's bindings): no libclang.so"), "{msg}");
    assert!(msg.contains("Debian/Ubuntu: sudo apt-get update && sudo apt-get install -y libclang-dev   <- this machine"), "{msg}");
    assert!(msg.contains("Fedora:        sudo dnf install -y clang-devel\n"), "{msg}");
    assert!(msg.contains("Arch:          sudo pacman -S --needed clang\n"), "{msg}");
    assert!(msg.contains("macOS:         xcode-select --install\n"), "{msg}");

    // Debian's layout: libclang-cpp is not libclang; a versioned libclang is.
    let lib = root.join("usr/lib/llvm-14/lib");
    std::fs::create_dir_all(&lib).unwrap();
    std::fs::write(lib.join("libclang-cpp.so.14"), b"").unwrap();
    assert_eq!(probe.libclang(), None);
    std::fs::write(lib.join("libclang-14.so.1"), b"").unwrap();
    assert_eq!(probe.libclang(), Some(lib.join("libclang-14.so.1")));
    assert!(probe.missing_for_emulator().is_empty());

    // LIBCLANG_PATH is looked in first.
    let own = scratch("own-libclang");
    std::fs::write(own.join("libclang.so"), b"").unwrap();
    let probe = Probe { libclang_path: Some(own.clone()), ..probe };
    assert_eq!(probe.libclang(), Some(own.join("libclang.so")));
}

#[test]
fn flip_link_is_found_on_path_or_in_the_project_or_planned() {
    let tools = scratch("tools");
    let empty = scratch("no-flip-link");
    let probe = Probe { path: vec![empty], libclang_path: None, root: PathBuf::from("/") };
    assert_eq!(find_linker(&probe, &tools), Linker::Missing);
    std::fs::create_dir_all(tools.join("bin")).unwrap();
    tool(&tools.join("bin"), "flip-link");
    assert_eq!(find_linker(&probe, &tools), Linker::InProject(tools.join("bin/flip-link")));
    let on_path = scratch("flip-link-on-path");
    tool(&on_path, "flip-link");
    let probe = Probe { path: vec![on_path.clone()], ..probe };
    assert_eq!(find_linker(&probe, &tools), Linker::OnPath(on_path.join("flip-link")));
}

#[test]
fn the_platform_comes_from_os_release() {
    let ubuntu = "NAME=\"Ubuntu\"\nID=ubuntu\nID_LIKE=debian\n";
    let rocky = "ID=\"rocky\"\nID_LIKE=\"rhel centos fedora\"\n";
    let manjaro = "ID=manjaro\nID_LIKE=arch\n";
    if cfg!(target_os = "macos") {
        return;
    }
    assert_eq!(Platform::detect(Some(ubuntu)), Some(Platform::Debian));
    assert_eq!(Platform::detect(Some(rocky)), Some(Platform::Fedora));
    assert_eq!(Platform::detect(Some(manjaro)), Some(Platform::Arch));
    assert_eq!(Platform::detect(Some("ID=alpine\n")), None);
    assert_eq!(Platform::detect(None), None);
}

#[test]
fn the_toolchain_file_is_read_and_compared_with_rustups_lists() {
    let file = ToolchainFile::parse(&std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../rust-toolchain.toml")).unwrap());
    assert_eq!(file.targets, ["thumbv7em-none-eabihf"]);
    assert_eq!(file.components, ["clippy", "rustfmt", "llvm-tools"]);
    let several =
        ToolchainFile::parse("[toolchain]\nchannel = \"1.95.0\" # pinned\ncomponents = [\n  \"rustfmt\",\n  'llvm-tools', # objcopy\n]\n");
    assert_eq!(several.components, ["rustfmt", "llvm-tools"]);
    assert!(several.targets.is_empty());
    let host = "x86_64-unknown-linux-gnu";
    let installed = "cargo-x86_64-unknown-linux-gnu\nclippy-x86_64-unknown-linux-gnu\nrust-std-thumbv7em-none-eabihf\n";
    let (components, targets) = file.missing(installed, "x86_64-unknown-linux-gnu\n", host);
    assert_eq!(components, ["rustfmt", "llvm-tools"]);
    assert_eq!(targets, ["thumbv7em-none-eabihf"]);
    let (components, targets) = file.missing(
        "clippy-x86_64-unknown-linux-gnu\nrustfmt-x86_64-unknown-linux-gnu\nllvm-tools-x86_64-unknown-linux-gnu\n",
        "thumbv7em-none-eabihf\nx86_64-unknown-linux-gnu\n",
        host,
    );
    assert!(components.is_empty() && targets.is_empty());
}

#[test]
fn a_toolchain_without_the_firmwares_target_gets_it_added() {
    let bin = scratch("toolchain-bin");
    let log = bin.join("rustup.log");
    for t in ["cc", "make", "cmake", "flip-link"] {
        tool(&bin, t);
    }
    fake_toolchain(&bin, &log);
    let lib = scratch("toolchain-lib");
    std::fs::write(lib.join("libclang.so"), b"").unwrap();
    let out = setup(&bin, Some(&lib), &scratch("toolchain-target"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let added = std::fs::read_to_string(&log).unwrap();
    assert_eq!(added, "target add thumbv7em-none-eabihf\ncomponent add clippy llvm-tools\n", "{err}");
    assert!(err.contains("the toolchain lacks the firmware's target thumbv7em-none-eabihf"), "{err}");
    // Everything else was there: the environment is the caller's.
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(stdout.trim(), format!("export PATH='{}'", bin.display()), "{err}");
}

#[test]
fn cmake_and_libclang_come_from_pypis_wheels_into_the_project() {
    let bin = scratch("wheels-bin");
    let log = bin.join("calls.log");
    let target = scratch("wheels-target");
    for t in ["make", "flip-link"] {
        tool(&bin, t);
    }
    fake_toolchain(&bin, &log);
    // The C compiler's own headers, where gcc keeps them.
    let include = scratch("wheels-include");
    for h in ["stdbool.h", "stddef.h", "stdarg.h"] {
        std::fs::write(include.join(h), b"").unwrap();
    }
    script(&bin, "cc", &format!("echo {}", include.display()));
    // pip: lays the two wheels' files out as PyPI's do.
    script(
        &bin,
        "python3",
        &format!(
            "echo \"python3 $*\" >> {log}\nfor a; do d=\"$t\"; t=\"$a\"; [ \"$d\" = --target ] && dir=\"$a\"; done\n\
             /bin/mkdir -p \"$dir/cmake/data/bin\" \"$dir/clang/native\"\n\
             printf '#!/bin/sh\\n' > \"$dir/cmake/data/bin/cmake\"; /bin/chmod +x \"$dir/cmake/data/bin/cmake\"\n\
             : > \"$dir/clang/native/libclang.so\"",
            log = log.display()
        ),
    );
    let out = setup(&bin, None, &target);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let calls = std::fs::read_to_string(&log).unwrap();
    let py = target.join("tools/py");
    assert!(
        calls.contains(&format!(
            "python3 -m pip install --quiet --disable-pip-version-check --no-warn-script-location --upgrade --target {} {}",
            py.display(),
            WHEELS.join(" ")
        )),
        "{calls}"
    );
    assert!(err.contains("installing PyPI's wheels cmake==4.4.5 libclang==18.1.1"), "{err}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains(&format!("export PATH='{}:{}'\n", py.join("cmake/data/bin").display(), bin.display())), "{stdout}");
    // libclang from the wheel unless the system's library directories have one.
    if stdout.contains("LIBCLANG_PATH") {
        assert!(stdout.contains(&format!("export LIBCLANG_PATH='{}'", py.join("clang/native").display())), "{stdout}");
        assert!(stdout.contains(&format!("export BINDGEN_EXTRA_CLANG_ARGS='-isystem {}'", include.display())), "{stdout}");
    }
    // A second run finds them in the project: nothing installed again.
    std::fs::remove_file(&log).unwrap();
    let again = setup(&bin, None, &target);
    assert!(again.status.success());
    assert!(!std::fs::read_to_string(&log).unwrap_or_default().contains("pip"));
    assert_eq!(again.stdout, out.stdout);
}

#[test]
fn without_pypi_apt_installs_them_as_root_on_debian() {
    if Platform::detect(std::fs::read_to_string("/etc/os-release").ok().as_deref()) != Some(Platform::Debian) {
        return;
    }
    let bin = scratch("apt-bin");
    let log = bin.join("calls.log");
    for t in ["cc", "make", "flip-link"] {
        tool(&bin, t);
    }
    fake_toolchain(&bin, &log);
    script(&bin, "python3", "echo 'ERROR: Could not find a version that satisfies the requirement cmake==4.4.5' >&2; exit 1");
    script(&bin, "id", "echo 0");
    // apt-get: logs, and its install puts cmake on PATH.
    script(
        &bin,
        "apt-get",
        &format!("echo \"apt-get $* $DEBIAN_FRONTEND\" >> {}\n[ \"$1\" = install ] && printf '#!/bin/sh\\n' > {cmake} && /bin/chmod +x {cmake}; exit 0", log.display(), cmake = bin.join("cmake").display()),
    );
    let lib = scratch("apt-lib");
    std::fs::write(lib.join("libclang.so"), b"").unwrap();
    let out = setup(&bin, Some(&lib), &scratch("apt-target"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("the wheels' way failed: `python3 -m pip install"), "{err}");
    assert!(err.contains("installing Debian's cmake with apt-get (as root"), "{err}");
    let calls = std::fs::read_to_string(&log).unwrap();
    assert!(calls.contains("apt-get update -qq noninteractive\napt-get install -y -qq cmake noninteractive\n"), "{calls}");

    // Not root, no sudo: the install line, and what was tried.
    let bin = scratch("apt-none-bin");
    for t in ["cc", "make", "flip-link"] {
        tool(&bin, t);
    }
    fake_toolchain(&bin, &bin.join("calls.log"));
    script(&bin, "python3", "exit 1");
    script(&bin, "id", "echo 1000");
    script(&bin, "sudo", "echo 'sudo: a password is required' >&2; exit 1");
    let out = setup(&bin, Some(&lib), &scratch("apt-none-target"));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("`cargo setup` needs what is not on this machine"), "{err}");
    assert!(err.contains("sudo apt-get update && sudo apt-get install -y cmake   <- this machine"), "{err}");
    assert!(err.contains("(PyPI's wheels were tried: `python3 -m pip install"), "{err}");
}

#[test]
fn bindgen_gets_the_compilers_own_headers_or_the_wheels_way_fails() {
    let include = scratch("headers");
    assert!(compiler_headers(&include).unwrap_err().contains("stdbool.h, stddef.h, stdarg.h"));
    for h in ["stdbool.h", "stddef.h", "stdarg.h"] {
        std::fs::write(include.join(h), b"").unwrap();
    }
    assert_eq!(compiler_headers(&include), Ok(include.clone()));
    // gcc answers a bare `include` when it has none.
    assert!(compiler_headers(Path::new("include")).is_err());
}
