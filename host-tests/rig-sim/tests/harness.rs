//! The `simulate` binary: a simulated calibration run written as a log of calib_core::formats::log.

use calib_core::formats::log::{is_header, parse_header, parse_line, Line};

#[test]
fn simulate_writes_a_log_of_the_shared_format() {
    let path = std::env::temp_dir().join(format!("simulate-{}.csv", std::process::id()));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_simulate")).arg(&path).args(["--seed", "4"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&path).unwrap();
    let header = text.lines().find(|l| is_header(l)).expect("a header");
    let cols = parse_header(header).unwrap();
    let rows = text.lines().skip_while(|l| !is_header(l)).skip(1).enumerate().filter_map(|(i, l)| {
        match parse_line(l, &cols, i as u32 + 2).unwrap() {
            Line::Row(r) => Some(r),
            _ => None,
        }
    });
    let (n, handheld) = rows.fold((0, 0), |(n, h), r| (n + 1, h + usize::from(r.servo_deg.is_none())));
    assert!(n > 5000 && handheld > 1000, "{n} rows, {handheld} hand-held");
    assert!(text.contains("# true K diagonal"));
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_simulate")).arg(&path).args(["--odr", "100"]).output().unwrap();
    assert_eq!(bad.status.code(), Some(2));
    std::fs::remove_file(&path).ok();
}
