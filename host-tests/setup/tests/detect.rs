//! The set-up check on a machine without the tools: the command stops before building anything
//! and names each missing tool with the exact install line; flip-link is found or planned.

use gyrocal_setup::{find_linker, missing_message, Linker, Platform, Probe, SystemTool};
use std::path::{Path, PathBuf};
use std::process::Command;

/// A fresh directory under cargo's test scratch directory.
fn scratch(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("setup").join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// An executable shell script `name` in `dir`.
fn tool(dir: &Path, name: &str) {
    use std::os::unix::fs::PermissionsExt;
    let p = dir.join(name);
    std::fs::write(&p, "#!/bin/sh\nexit 0\n").unwrap();
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
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
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown command \"demp\" (one of: demo, test-host, results, flash-usb)"));
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
