//! The workspace-hack crate keeps the README's single-package commands on the test build's
//! features: every dependency of `cargo simulate`, `cargo calib`, `cargo demo`, `cargo results`
//! and `cargo install` resolves to a (package, features) pair `cargo test-host` builds, so none
//! of them compiles a crate again (host-tests/workspace-hack/Cargo.toml).

use std::collections::BTreeSet;
use std::process::Command;

/// `cargo test-host`'s packages (host-tests/setup/src/main.rs, the `test-host` job).
const TEST_HOST: [&str; 7] = ["calib-core", "calib", "rig-sim", "benchmarks", "vboard", "gyrocal-setup", "gyrocal-fuzz"];

/// The packages a README command builds on its own (the `results` job builds two at once).
const SINGLE: [&[&str]; 4] = [&["rig-sim"], &["calib"], &["vboard"], &["benchmarks", "vboard"]];

/// Every `package version [features]` line `cargo tree` resolves for `packages` on the host.
fn resolved(packages: &[&str], edges: &str) -> BTreeSet<String> {
    let manifest = concat!(env!("CARGO_MANIFEST_DIR"), "/../../Cargo.toml");
    let mut cmd = Command::new(env!("CARGO"));
    cmd.args(["tree", "--locked", "--offline", "--manifest-path", manifest, "--target", "host-tuple"]);
    cmd.args(["-e", edges, "-f", "{p} [{f}]", "--prefix", "none"]);
    for p in packages {
        cmd.args(["-p", p]);
    }
    let out = cmd.output().expect("cargo tree runs");
    assert!(out.status.success(), "cargo tree failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout).unwrap().lines().map(|l| l.trim_end_matches(" (*)").to_string()).filter(|l| !l.is_empty()).collect()
}

#[test]
fn workspace_hack_unifies_features() {
    // Every unit, and apart the binaries' own units (normal edges alone: a build script's
    // dependency, compiled for the host, shares a line with the binaries' copy otherwise).
    for (with, without) in [("normal,build,dev", "normal,build"), ("normal,dev,no-proc-macro", "normal,no-proc-macro")] {
        unified(&resolved(&TEST_HOST, with), without);
    }
}

/// Each single-package build's `edges` resolve to lines of `test`.
fn unified(test: &BTreeSet<String>, edges: &str) {
    for packages in SINGLE {
        let own = resolved(packages, edges);
        let extra: Vec<_> = own.difference(test).collect();
        assert!(
            extra.is_empty(),
            "`cargo run -p {}` resolves {} crate(s) with features the test build does not: {extra:?}; \
             add the missing features to host-tests/workspace-hack/Cargo.toml",
            packages.join(" -p "),
            extra.len()
        );
    }
}
