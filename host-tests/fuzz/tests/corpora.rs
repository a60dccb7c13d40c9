//! Replays every committed fuzz corpus (`corpus/<target>/`) through its target's body, and the
//! GyroCal C loader's (`corpus/gyrocal_c/`) through the C harness built with AddressSanitizer and
//! UndefinedBehaviorSanitizer: what the fuzzers found stays found.

use std::path::{Path, PathBuf};
use std::process::Command;

fn corpus(name: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus").join(name);
    let mut files: Vec<PathBuf> =
        std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())).map(|e| e.unwrap().path()).collect();
    files.sort();
    files
}

#[test]
fn every_rust_corpus_replays() {
    for (name, body) in gyrocal_fuzz::TARGETS {
        let files = corpus(name);
        assert!(files.len() >= 5, "{name}: {} inputs", files.len());
        for f in files {
            let data = std::fs::read(&f).unwrap();
            if std::panic::catch_unwind(|| body(&data)).is_err() {
                panic!("{name}: {} fails", f.display());
            }
        }
    }
}

#[test]
fn the_gyrocal_c_corpus_replays_under_asan_and_ubsan() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let exe = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gyrocal_fuzz_replay");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let built = Command::new(&cc)
        .args(["-std=c99", "-g", "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-DGYROCAL_FUZZ_REPLAY"])
        .arg("-I")
        .arg(root.join("../../calib-core/arduino/GyroCal/src"))
        .arg(root.join("c/gyrocal_fuzz.c"))
        .arg(root.join("../../calib-core/arduino/GyroCal/src/gyrocal.c"))
        .args(["-lm", "-o"])
        .arg(&exe)
        .status()
        .unwrap();
    assert!(built.success(), "{cc} could not build the harness with the sanitizers");
    let files = corpus("gyrocal_c");
    assert!(files.len() >= 5, "gyrocal_c: {} inputs", files.len());
    let out = Command::new(&exe).args(&files).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), format!("replayed {}", files.len()));
}
