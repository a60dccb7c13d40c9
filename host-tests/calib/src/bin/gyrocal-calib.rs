//! `calib LOG.csv [--method paper|sweep] [--columns MAP] [--no-rotations] [--export c|json|rust|record]`:
//! calibrates a recorded log with calib-core and prints one JSON object. `calib allan LOG
//! [--yaml imu.yaml]`: the noise figures of a long static log. `calib --port PATH`:
//! calibrates a board over its USB serial port, saves its log, prints its result and
//! cross-checks it. `calib --help` says everything. (A log to try it on:
//! `cargo run --release -p rig-sim --target host-tuple --bin simulate -- OUT.csv`.)
//!
//! Exit codes: 0 a full calibration (with `--port`: the board's, cross-checked), 4 partial,
//! 1 nothing calibrated (the board's calibration failed), 2 usage, I/O or port error, 3 malformed
//! log (or result line), 5 cross-check failed, 6 the board did not answer or `--timeout`.

use calib::port::{self, Options};
use calib::{csvlog, offline};
use calib_core::estimators::accel::AccelModel;
use calib_core::estimators::frame::DataFrame;
use calib_core::estimators::gyro::Method;
use calib_core::formats::export::{self, Format, RecordJson};
use calib_core::formats::record::Record;
use calib_core::formats::region;
use clap::{Parser, ValueEnum};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

fn fail(code: u8, msg: impl std::fmt::Display) -> ExitCode {
    eprintln!("calib: {msg}");
    ExitCode::from(code)
}

/// Gyro and accelerometer calibration of a recorded log with the firmware's own calib-core code,
/// or of a board over its USB serial port (--port).
///
/// Exit codes: 0 a full calibration (with --port: the board's, and the cross-check passed);
/// 4 partial (the log supports only part of it: the JSON has what could be calibrated and
/// `quality.missing` names the rest); 1 nothing could be calibrated (with --port: the board's
/// calibration failed); 2 usage, file or port error; 3 malformed log (or the board's result
/// line); 5 the cross-check failed (the board's K and calib's on the saved log differ); 6 the
/// board did not answer (nothing for 30 s, or no answer to a command in 10 s), or the session
/// exceeded --timeout.
#[derive(Parser, Debug)]
#[command(name = "gyrocal-calib", version, args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
struct Args {
    #[command(subcommand)]
    command: Option<Sub>,
    /// The log to calibrate (CSV: t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,servo_deg[,tilt_deg]).
    #[arg(required_unless_present = "port", conflicts_with = "port")]
    log: Option<String>,
    /// Use only this gyro estimator (default: sweep, else paper).
    #[arg(long, value_enum, conflicts_with = "port")]
    method: Option<MethodArg>,
    /// Read a log with other column names or units: COLUMN=SOURCE[*F|/F],… e.g.
    /// `t_s=time/1000,ax_g=acc_x/9.80665,gx_dps=gyr_x*57.29578`.
    #[arg(long, value_name = "MAP", conflicts_with = "port")]
    columns: Option<String>,
    /// Leave out the rotation constraints of the moves between hand-held poses (to see what
    /// they add to the full K).
    #[arg(long, conflicts_with = "port")]
    no_rotations: bool,
    /// Every turn about the vertical in the log (the board turned flat on a table, as in the
    /// Ferraris protocol) is a whole number of revolutions: its angle constrains the scale too.
    /// Without it such a turn constrains its axis only.
    #[arg(long, conflicts_with = "port")]
    whole_turns: bool,
    /// The gyro's full scale (°/s) when the log does not state it: readings at it are clipped
    /// and the moves holding them are not used; a reading beyond 1.2 times it (more than a
    /// part's counts reach) is an error naming its line. Without it: the log's setup comment,
    /// else runs of equal extreme readings.
    #[arg(long, value_name = "DPS", conflicts_with = "port")]
    range: Option<f32>,
    /// Calibrate the board on this USB serial port (Linux /dev/ttyACM0, macOS
    /// /dev/cu.usbmodemXXXX, Windows COM5): follow the phases shown, press Enter when asked.
    /// Its result (JSON) is printed, its log saved and calibrated by calib too: the two K must
    /// agree.
    #[arg(long, value_name = "PATH")]
    port: Option<String>,
    /// With --port: where to save the board's log (default gyrocal-<unix time>.csv).
    #[arg(long = "log", id = "save_log", value_name = "FILE", requires = "port")]
    save_log: Option<PathBuf>,
    /// With --port: the longest session (s), the re-clamp included.
    #[arg(long, value_name = "SECS", default_value_t = 600, requires = "port")]
    timeout: u64,
    /// Write the result as JSON (one line), a C snippet (arrays and gyrocal_apply()) or Rust
    /// constants: to stdout instead of the usual output, or to --out; `record`: the two record
    /// pages (8 KiB) as they would be in the board's flash at 0xF8000 (needs --out), for the
    /// GyroCal Arduino library's or calib_core::formats::region's loader.
    #[arg(long, value_enum)]
    export: Option<ExportArg>,
    /// Also write a report to look at: one self-contained HTML page with plots (the poses on the
    /// sphere, the paper's invariant before and after, each move's residual, the bias over time),
    /// K with its 1σ and what to do about whatever is weak. With --port: of the saved log.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
    /// With --export: the file to write it to (the usual output stays on stdout).
    #[arg(long, value_name = "FILE", requires = "export")]
    out: Option<PathBuf>,
    /// With --export c|rust: the calibration for data read another way than this firmware's
    /// (the board frame, docs/frames.md), its outputs in the board frame: `arduino-lsm9ds1` as
    /// Arduino_LSM9DS1 returns an LSM9DS1 (its raw axes), `bosch` a BMI270 as Bosch's
    /// BMI270_SensorAPI (and Arduino_BMI270_BMM150 1.0.x) returns it (GYR_CAS applied, Bosch's
    /// axes), `arduino` as Arduino_BMI270_BMM150 1.1.0 on does (CAS applied, then x = -y, y = -x).
    #[arg(long, value_enum, default_value_t = FrameArg::Board, requires = "export")]
    frame: FrameArg,
}

#[derive(Clone, Copy, Debug, PartialEq, ValueEnum)]
enum FrameArg {
    Board,
    ArduinoLsm9ds1,
    Bosch,
    Arduino,
}

impl FrameArg {
    fn frame(self) -> DataFrame {
        match self {
            FrameArg::Board => DataFrame::Board,
            FrameArg::ArduinoLsm9ds1 => DataFrame::ArduinoLsm9ds1,
            FrameArg::Bosch => DataFrame::BoschApi,
            FrameArg::Arduino => DataFrame::ArduinoBmi270,
        }
    }
}

#[derive(clap::Subcommand, Debug)]
enum Sub {
    /// Noise figures of a long static log (the board lying still in raw-log mode, an hour or
    /// more): the Allan deviation of each axis, the white-noise density, random walk and bias
    /// instability with their 1σ, as one JSON object; --yaml writes Kalibr's imu.yaml.
    Allan {
        /// The static log (CSV as for calibration).
        log: String,
        /// Read a log with other column names or units (as for calibration).
        #[arg(long, value_name = "MAP")]
        columns: Option<String>,
        /// Also write Kalibr's imu.yaml (SI units) to this file.
        #[arg(long, value_name = "FILE")]
        yaml: Option<PathBuf>,
        /// The rostopic written in the YAML.
        #[arg(long, default_value = "/imu0")]
        topic: String,
        /// Also write a page with the figures and the Allan-deviation plots (HTML).
        #[arg(long, value_name = "FILE")]
        report: Option<PathBuf>,
    },
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum MethodArg {
    Paper,
    Sweep,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum ExportArg {
    C,
    Json,
    Rust,
    Record,
}

/// The export of `rec`: JSON through its serde schema ([`RecordJson`], the one the board writes
/// by hand), C and Rust by `calib_core::formats::export` (text, ending in a newline), the record pages by
/// `calib_core::formats::region::image`.
fn export_bytes(rec: &Record, format: ExportArg, frame: FrameArg) -> Result<Vec<u8>, String> {
    let failed = |e: &dyn std::fmt::Display| format!("--export: the record could not be written: {e}");
    let mut text = String::new();
    if frame != FrameArg::Board {
        rec.in_frame(frame.frame()).map_err(|e| format!("--frame: {e}"))?;
        let f = match format {
            ExportArg::C => Format::C,
            ExportArg::Rust => Format::Rust,
            ExportArg::Json | ExportArg::Record => return Err("--frame: JSON and the record are always in the board frame".into()),
        };
        export::write_in(&mut text, rec, f, frame.frame()).map_err(|e| failed(&e))?;
        return Ok((text + "\n").into_bytes());
    }
    match format {
        ExportArg::Record => return region::image(rec).map(|r| r.to_vec()).map_err(|e| failed(&e)),
        ExportArg::Json => text = serde_json::to_string(&RecordJson::from(rec)).map_err(|e| failed(&e))?,
        ExportArg::C => export::write(&mut text, rec, Format::C).map_err(|e| failed(&e))?,
        ExportArg::Rust => export::write(&mut text, rec, Format::Rust).map_err(|e| failed(&e))?,
    }
    Ok((text + "\n").into_bytes())
}

/// Prints `usual` on stdout unless the export goes there instead; writes the export.
fn output(usual: &str, export: Option<(&Record, ExportArg, FrameArg)>, out: Option<&Path>) -> Result<(), String> {
    let Some((rec, format, frame)) = export else {
        println!("{usual}");
        return Ok(());
    };
    let bytes = export_bytes(rec, format, frame)?;
    match out {
        Some(path) => {
            println!("{usual}");
            std::fs::write(path, bytes).map_err(|e| format!("{}: {e}", path.display()))
        }
        None => std::io::Write::write_all(&mut std::io::stdout(), &bytes).map_err(|e| format!("stdout: {e}")),
    }
}

fn main() -> ExitCode {
    let args = Args::parse_from(calib::cli_args());
    if let Some(Sub::Allan { log, columns, yaml, topic, report }) = &args.command {
        return allan(log, columns.as_deref(), yaml.as_deref(), topic, report.as_deref());
    }
    if matches!(args.export, Some(ExportArg::Record)) && args.out.is_none() {
        return fail(2, "--export record writes the 8 KiB flash image: give --out FILE");
    }
    // clap requires LOG without --port.
    match &args.port {
        Some(p) => by_port(&args, p),
        None => offline_log(&args, args.log.as_deref().unwrap_or_default()),
    }
}

fn by_port(args: &Args, path: &str) -> ExitCode {
    let mut opts = Options::new(args.save_log.clone().unwrap_or_else(port::default_log_path));
    opts.timeout = Duration::from_secs(args.timeout);
    opts.redraw = std::io::stderr().is_terminal();
    let result =
        port::open(path).and_then(|mut p| port::run(&mut *p, std::io::BufReader::new(std::io::stdin()), &mut std::io::stderr(), &opts));
    match result {
        Ok(o) => {
            eprintln!("calib: the board's log is in {} ({} lines)", opts.log.display(), o.lines);
            if let Err(e) = output(&o.json, args.export.map(|f| (&o.record, f, args.frame)), args.out.as_deref()) {
                return fail(2, e);
            }
            // The report of the saved log, replayed from the record the board started with.
            if let Some(file) = &args.report {
                let log = std::fs::read_to_string(&opts.log)
                    .map_err(|e| e.to_string())
                    .and_then(|t| csvlog::parse(&t).map_err(|e| e.to_string()));
                let written = log.and_then(|l| {
                    let c = offline::calibrate_log(&l, &offline::Options::default(), o.stored.as_ref()).map_err(|e| e.to_string())?;
                    write_report(file, &opts.log.display().to_string(), &l, &c)
                });
                if let Err(e) = written {
                    return fail(2, format!("--report: {e} (the board's calibration is stored)"));
                }
            }
            ExitCode::SUCCESS
        }
        Err(e) => {
            if !matches!(e, port::SessionError::Open { .. }) {
                eprintln!("calib: the lines received are in {}", opts.log.display());
            }
            fail(e.exit_code(), e)
        }
    }
}

/// Reads and parses a log (remapped by `--columns`): exit 2 on I/O, 3 when malformed. Holes in
/// time are said with what spans them.
fn read_log(path: &str, columns: Option<&str>) -> Result<csvlog::Log, ExitCode> {
    let bytes = std::fs::read(path).map_err(|e| fail(2, format!("{path}: {e}")))?;
    let mut text = csvlog::decode(&bytes).map_err(|e| fail(3, format!("{path}: {e}")))?;
    if let Some(spec) = columns {
        text = csvlog::remap(&text, spec).map_err(|e| fail(3, format!("{path}: {e}")))?.into();
    }
    let log = csvlog::parse(&text).map_err(|e| fail(3, format!("{path}: {e}")))?;
    if let Some(n) = log.cut_line {
        eprintln!("calib: warning: {path}: line {n} was cut mid-row (the recording stopped while writing it): read up to line {}", n - 1);
    }
    for hole in &log.holes {
        eprintln!("calib: warning: {path}: {hole}");
    }
    Ok(log)
}

fn allan(path: &str, columns: Option<&str>, yaml: Option<&Path>, topic: &str, report: Option<&Path>) -> ExitCode {
    let log = match read_log(path, columns) {
        Ok(l) => l,
        Err(code) => return code,
    };
    let a = match calib::allan::analyse(&log.rows) {
        Ok(a) => a,
        Err(e) => return fail(1, format!("{path}: {e}")),
    };
    if let Some(file) = yaml {
        if let Err(e) = std::fs::write(file, a.kalibr_yaml(topic)) {
            return fail(2, format!("{}: {e}", file.display()));
        }
    }
    if let Some(file) = report {
        let written =
            calib::report::allan_html(path, &a).and_then(|page| std::fs::write(file, page).map_err(|e| format!("{}: {e}", file.display())));
        if let Err(e) = written {
            return fail(2, format!("--report: {e}"));
        }
    }
    match serde_json::to_string(&serde_json::json!({ "allan": a })) {
        Ok(j) => {
            println!("{j}");
            ExitCode::SUCCESS
        }
        Err(e) => fail(2, e),
    }
}

/// Writes the report of `log` (named `name`) to `file`.
fn write_report(file: &Path, name: &str, log: &csvlog::Log, c: &offline::Calibration) -> Result<(), String> {
    let page = calib::report::html(name, &log.rows, c)?;
    std::fs::write(file, page).map_err(|e| format!("{}: {e}", file.display()))?;
    eprintln!("calib: report written to {}", file.display());
    Ok(())
}

fn offline_log(args: &Args, path: &str) -> ExitCode {
    let method = args.method.map(|m| match m {
        MethodArg::Paper => Method::Paper,
        MethodArg::Sweep => Method::Sweep,
    });
    let log = match read_log(path, args.columns.as_deref()) {
        Ok(l) => l,
        Err(code) => return code,
    };
    // A reading beyond the full scale the user states: a bad number, or not this log's range.
    if let Some(Err(e)) = args.range.map(|r| log.check_full_scale(Some(r), calib_core::formats::log::Bound::RangeOption)) {
        return fail(3, format!("{path}: {e}"));
    }
    let options = offline::Options { method, no_rotations: args.no_rotations, whole_turns: args.whole_turns, range_dps: args.range };
    let c = match offline::calibrate_log(&log, &options, None) {
        Ok(c) => c,
        Err(e) => return fail(1, format!("{path}: {e}")),
    };
    if let Some(file) = &args.report {
        if let Err(e) = write_report(file, path, &log, &c) {
            return fail(2, format!("--report: {e}"));
        }
    }
    if let Some(calib_core::Error::AxesMirrored { right_hand, left_hand }) = c.mirrored {
        eprintln!(
            "calib: {path}: the gyro's axes are mirrored relative to the accelerometer's, as the LSM9DS1's raw axes are: \
             {left_hand} moves turn gravity by the left-hand rule, {right_hand} by the right; \
             calibrated in the log's own axes (K and the bias apply to the readings as logged; \
             `quality.gyro_axes` in the JSON)"
        );
    }
    if let Some(axes) = c.mag.as_ref().and_then(|m| m.axes.as_ref()) {
        eprintln!("calib: {path}: {}", axes.describe());
    }
    for l in &c.left_out {
        eprintln!("calib: {path}: warning: {l}");
    }
    let missing = c.missing();
    if let Err(e) = &c.gyro {
        if c.accel.model == AccelModel::None && !matches!(c.full, Some(Ok(_))) {
            return fail(1, format!("{path}: {e}"));
        }
    }
    let record = c.record();
    if args.export.is_some() && record.is_none() {
        return fail(4, format!("{path}: --export: no gyro calibration to export (partial: {})", missing.join("; ")));
    }
    if let Err(e) = output(&c.json(log.messages), args.export.zip(record.as_ref()).map(|(f, r)| (r, f, args.frame)), args.out.as_deref()) {
        return fail(2, e);
    }
    for m in &missing {
        eprintln!("calib: {path}: partial calibration, missing {m}");
    }
    if missing.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(4)
    }
}
