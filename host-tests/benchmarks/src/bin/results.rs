//! `cargo results [-- --check [--full]]`: runs every benchmark (fixed seeds, deterministic) and
//! the emulated board's demos, and writes `docs/results.md` from their JSON summaries and RESULT
//! lines, then the same page from a quick set of the same runs (3 rigs, 2 logs, fewer paper
//! runs; the demos and real sessions whole) to `host-tests/benchmarks/results-quick.md`.
//! `--check` writes nothing and exits 1 when the quick set's page on disk differs from the one
//! its runs give (CI, in a fifth of the time: any change to a code path behind the page changes
//! it, and `cargo results` rewrites both); `--check --full` checks docs/results.md itself. Wall-clock figures (the demo's SPEED line) and the
//! USB demo (its timing depends on threads) are not on the page.

use clap::Parser;
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

/// docs/results.md from the benchmarks.
#[derive(Parser, Debug)]
#[command(name = "results")]
struct Args {
    /// Write nothing; exit 1 if the quick set's page (host-tests/benchmarks/results-quick.md)
    /// differs from what its runs give.
    #[arg(long)]
    check: bool,
    /// With `--check`: the full set against docs/results.md instead.
    #[arg(long)]
    full: bool,
}

/// One run: a binary beside this one and its arguments.
struct Run {
    bin: &'static str,
    args: Vec<String>,
}

fn root() -> PathBuf {
    calib::firmware::root()
}

/// The binaries of the host profile (this one's directory).
fn bin_dir() -> Result<PathBuf, String> {
    let exe = std::env::current_exe().map_err(|e| format!("current exe: {e}"))?;
    exe.parent().map(Path::to_path_buf).ok_or_else(|| "no directory for the current exe".into())
}

/// Builds the benchmark and demo binaries (host profile, this binary's target).
fn build() -> Result<(), String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let status = Command::new(cargo)
        .args(["build", "--profile", "host", "--target", "host-tuple", "-p", "benchmarks", "-p", "vboard", "--bins"])
        .current_dir(root())
        .status()
        .map_err(|e| format!("cannot run cargo: {e}"))?;
    status.success().then_some(()).ok_or_else(|| format!("the benchmark build failed ({status})"))
}

/// Runs the list with as many at a time as there are cores; stdout of each, in order.
fn run_all(runs: &[Run]) -> Result<Vec<String>, String> {
    let dir = bin_dir()?;
    let workers = std::thread::available_parallelism().map_or(2, |n| n.get()).min(runs.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let out: Vec<std::sync::Mutex<Option<Result<String, String>>>> = runs.iter().map(|_| std::sync::Mutex::new(None)).collect();
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                let Some(r) = runs.get(i) else { break };
                eprintln!("results: {} {}", r.bin, r.args.join(" "));
                let t0 = std::time::Instant::now();
                let res = Command::new(dir.join(r.bin)).args(&r.args).current_dir(root()).output();
                eprintln!("results: {} {}: {:.1} s", r.bin, r.args.join(" "), t0.elapsed().as_secs_f64());
                let res = match res {
                    Ok(o) if o.status.success() => {
                        let stdout = String::from_utf8_lossy(&o.stdout).into_owned();
                        // Wall-clock figures are not on the page: shown here.
                        for l in stdout.lines().filter(|l| l.starts_with("SPEED ")) {
                            eprintln!("results: {} {}: {l}", r.bin, r.args.join(" "));
                        }
                        Ok(stdout)
                    }
                    Ok(o) => Err(format!("{} {}: {}\n{}", r.bin, r.args.join(" "), o.status, String::from_utf8_lossy(&o.stderr))),
                    Err(e) => Err(format!("{}: {e}", r.bin)),
                };
                if let Ok(mut slot) = out[i].lock() {
                    *slot = Some(res);
                }
            });
        }
    });
    out.into_iter().map(|m| m.into_inner().ok().flatten().unwrap_or_else(|| Err("no result".into()))).collect()
}

/// The last stdout line as JSON.
fn json(stdout: &str) -> Result<Value, String> {
    let last = stdout.lines().last().ok_or("no output")?;
    serde_json::from_str(last).map_err(|e| format!("last line is not JSON ({e}): {last}"))
}

/// `key=value` fields of the first line starting with `tag ` (e.g. `RESULT`).
fn fields(stdout: &str, tag: &str) -> Result<Vec<(String, String)>, String> {
    let line = stdout.lines().find(|l| l.starts_with(&format!("{tag} "))).ok_or_else(|| format!("no {tag} line"))?;
    Ok(line.split_whitespace().skip(1).filter_map(|kv| kv.split_once('=')).map(|(k, v)| (k.to_string(), v.to_string())).collect())
}

fn field<'a>(f: &'a [(String, String)], k: &str) -> &'a str {
    f.iter().find(|(key, _)| key == k).map_or("?", |(_, v)| v.as_str())
}

/// The number after `prefix` in the first line that contains it.
fn after<'a>(stdout: &'a str, prefix: &str) -> &'a str {
    stdout.lines().find_map(|l| l.split_once(prefix).map(|(_, r)| r.split_whitespace().next().unwrap_or("?"))).unwrap_or("?")
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

/// 3 significant digits in engineering style (e.g. `1.33e-4`).
fn e3(x: f64) -> String {
    if x == 0.0 {
        "0".into()
    } else {
        format!("{x:.2e}")
    }
}

fn count(v: &Value) -> usize {
    v.as_array().map_or(0, Vec::len)
}

/// The demos' stdout, by run.
struct Demos<'a> {
    plain: &'a str,
    tilt: &'a str,
    raw: &'a str,
    no_probe: &'a str,
    rev2: &'a str,
    odr952: &'a str,
}

fn demo_section(d: &Demos, budgets: &[(String, String)]) -> Result<String, String> {
    let Demos { plain, tilt, raw, no_probe, rev2, odr952 } = *d;
    let r = fields(plain, "RESULT")?;
    let r952 = fields(odr952, "RESULT")?;
    let r2 = fields(rev2, "RESULT")?;
    let t = fields(tilt, "RESULT")?;
    let rt = fields(raw, "ROUNDTRIP")?;
    let np = fields(no_probe, "RESULT")?;
    let mut s = String::from("## Demo\n\nThe firmware ELF on the emulated board (`cargo demo`, seed 1; `host-tests/vboard`; the one-servo runs' rig without \
     cross-axis coupling, `--tilt`'s with U(±1 %) and the accelerometer's misalignment U(±0.3 %)); each run stores one record or says why not.\n\n");
    s += "| run | result |\n|---|---|\n";
    // A full K's errors: scale, cross-axis, largest |E|.
    let full = |f: &[(String, String)]| {
        format!(
            "max scale error {} %, max cross-axis error {} %, largest |E| {}",
            field(f, "max_scale_error_pct"),
            field(f, "max_cross_axis_error_pct"),
            field(f, "max_abs_e")
        )
    };
    // The magnetometer's tilt-compensated heading error over random attitudes.
    let mag = |f: &[(String, String)]| {
        format!("magnetometer heading error {}° RMS, {}° max", field(f, "mag_heading_rms_deg"), field(f, "mag_heading_max_deg"))
    };
    s += &format!("| `cargo demo` (one servo + hand-held poses, full K) | {}, {}, stored {} |\n", full(&r), mag(&r), field(&r, "stored"));
    s += &format!(
        "| `cargo demo -- --tilt` (pan/tilt, full K) | {}, stored {}, rig time {} s |\n",
        full(&t),
        field(&t, "stored"),
        after(tilt, "rig time: ")
    );
    s += &format!(
        "| `cargo demo -- --raw-log FILE` | calib on the raw log vs the firmware's K: {} % (largest element), vs the truth: scale {} %, cross-axis {} % |\n",
        field(&rt, "calib_vs_firmware_max_pct"),
        field(&rt, "calib_scale_error_pct"),
        field(&rt, "calib_cross_axis_error_pct")
    );
    s += &format!("| `cargo demo -- --no-probe` | {}, stored {} |\n", full(&np), field(&np, "stored"));
    s += &format!(
        "| `cargo demo -- --odr952` (the `odr952` build: 952 Hz, a FIFO of 34 ms) | {}, stored {}, FIFO overruns {} |\n",
        full(&r952),
        field(&r952, "stored"),
        after(odr952, "FIFO overruns: ").trim_end_matches(',')
    );
    s += &format!(
        "| `cargo demo -- --rev2` (Rev2: BMI270 + BMM150; its z→x coupling is cross-axis) | {}, {}, stored {}, board {} |\n\n",
        full(&r2),
        mag(&r2),
        field(&r2, "stored"),
        field(&r2, "board")
    );
    s += &format!(
        "Cost on the MCU (`cargo demo`): `Procedure::handle_sample` {} instructions per sample on average; its longest call \
         {} instructions; the longest `Procedure::handle_tick` (a fit or a step of the solve, one a FIFO read) {} instructions \
         (64 MHz: the virtual board counts one instruction a cycle, a lower bound for a Cortex-M4 with flash wait states, \
         [limits](limits.md)); peak stack {} bytes; FIFO overruns {} in the whole run. At 952 Hz (`--odr952`): {} instructions \
         per sample, the longest calls {} and {} instructions, FIFO overruns {} (the LSM9DS1's FIFO is paused around the \
         store's page erase, which stalls the CPU for up to 85 ms). Rev2 (`--rev2`, the BMI270 at 100 Hz): {} instructions per \
         sample, the longest calls {} and {} instructions, peak stack {} bytes, FIFO overruns {}. Issue 50's limits: 4 000 \
         instructions a sample, 2 000 000 a call, 32 KiB of stack, no overrun.\n\n",
        after(plain, "calls, ").trim_end_matches(','),
        after(plain, "handle_sample call: "),
        after(plain, "(a fit or a step of the solve): "),
        after(plain, "peak stack: "),
        after(plain, "FIFO overruns: ").trim_end_matches(','),
        after(odr952, "calls, ").trim_end_matches(','),
        after(odr952, "handle_sample call: "),
        after(odr952, "(a fit or a step of the solve): "),
        after(odr952, "FIFO overruns: ").trim_end_matches(','),
        after(rev2, "calls, ").trim_end_matches(','),
        after(rev2, "handle_sample call: "),
        after(rev2, "(a fit or a step of the solve): "),
        after(rev2, "peak stack: "),
        after(rev2, "FIFO overruns: ").trim_end_matches(',')
    );
    s += "## Firmware\n\nRelease builds (`.ci/firmware-check`; budgets: flash 128 KiB, static RAM 48 KiB).\n\n| build | flash | static RAM |\n|---|---|---|\n";
    for (name, check) in budgets {
        s += &format!("| {name} | {} B | {} B |\n", after(check, "flash "), after(check, "static RAM "));
    }
    Ok(s)
}

fn paper_section(j: &Value) -> String {
    let failed = |t: &str| count(&j[t]["failed"]);
    let mut s = format!(
        "## Paper tables\n\n`cargo paper-tables` (seed {}): the paper's simulation (Li et al.: its rates, noise and poses, none of the \
         physics above) with calib-core's estimators directly, ours beside the paper's.\n\nTable I (scale-factor error after \
         calibration, {} runs, {} failed):\n\n| axis | status | mean (ours / paper) | variance (ours / paper) |\n|---|---|---|---|\n",
        j["seed"],
        j["runs"],
        failed("table1")
    );
    for r in j["table1"]["rows"].as_array().into_iter().flatten() {
        s += &format!(
            "| {} | {} | {} / {} | {} / {} |\n",
            r["axis"].as_str().unwrap_or("?"),
            r["status"].as_str().unwrap_or("?"),
            e3(f(&r["ours"]["mean"])),
            e3(f(&r["paper"]["mean"])),
            e3(f(&r["ours"]["variance"])),
            e3(f(&r["paper"]["variance"]))
        );
    }
    s += &format!("\nTable II (RMS error of the scale factors, {} runs per case, {} failed):\n\n", j["runs"], failed("table2"));
    s += "| axis | uncalibrated | with accel error | accel pre-calibrated | without accel error |\n|---|---|---|---|---|\n";
    for r in j["table2"]["rows"].as_array().into_iter().flatten() {
        s += &format!(
            "| {} | {} | {} | {} | {} |\n",
            r["axis"].as_str().unwrap_or("?"),
            e3(f(&r["rms_uncalibrated"])),
            e3(f(&r["rms_with_accel_error"])),
            e3(f(&r["rms_with_accel_error_precalibrated"])),
            e3(f(&r["rms_without_accel_error"]))
        );
    }
    s += &format!(
        "\nTable III (estimated scale factor under gyro noise, {} runs per noise level, {} failed):\n\n",
        j["noise_runs"],
        failed("table3")
    );
    s += "| axis | noise (°/s) | mean (ours / paper) | variance (ours / paper) |\n|---|---|---|---|\n";
    for r in j["table3"]["rows"].as_array().into_iter().flatten() {
        s += &format!(
            // The paper prints its means with 3 decimals.
            "| {} | {} | {:.4} / {:.3} | {} / {} |\n",
            r["axis"].as_str().unwrap_or("?"),
            f(&r["noise_sd_dps"]),
            f(&r["ours"]["mean"]),
            f(&r["paper"]["mean"]),
            e3(f(&r["ours"]["variance"])),
            e3(f(&r["paper"]["variance"]))
        );
    }
    s += "\nThe paper's estimator (known servo speed) against the speed-free sweep on simulated rigs (calib-core's estimators on \
          rig-sim's rigs, one servo; \"misaligned\": gyro cross-axis ±0.2°, accelerometer ±0.1°, the others none; scale error, %):\n\n\
          | rig | paper RMS | paper max | sweep RMS | sweep max | failed (paper / sweep) |\n|---|---|---|---|---|---|\n";
    for (k, name) in
        [("exact_servo", "exact servo speed"), ("hobby_servo", "hobby servo"), ("hobby_servo_misaligned", "hobby servo, misaligned")]
    {
        let h = &j["hobby_servo"][k];
        s += &format!(
            "| {name} | {:.3} | {:.3} | {:.3} | {:.3} | {} / {} |\n",
            f(&h["paper_rms_pct"]),
            f(&h["paper_max_pct"]),
            f(&h["sweep_rms_pct"]),
            f(&h["sweep_max_pct"]),
            count(&h["paper_failed"]),
            count(&h["sweep_failed"])
        );
    }
    s
}

fn calib_bench_section(j: &Value) -> String {
    let mut s = format!(
        "## Calib bench\n\n`calib-bench --logs {}` (rigs `Variant::HobbyMisaligned` seed {}: servo scale error U(−3, 3) %, gyro \
         cross-axis misalignment ±0.2°, accelerometer ±0.1°; noise seeds {} + log): `gyrocal-calib`'s offline path on simulated logs of \
         the procedure, scored on the record it gives (what it prints and exports: the full K its replay of the firmware's procedure \
         stores, else the diagonal one): `E = Qᵀ K̂ K⁻¹ − I` (RMS over the 9 elements, mean over the logs; the largest |E_ij|); full K: the logs \
         that gave one; failed: the logs that gave no gyro calibration. The continuous servo's rows replay calib-core's procedure \
         with a continuous servo, which no firmware build has.\n\n\
         | servo | ODR (Hz) | path | RMS of E | largest | full K | failed |\n|---|---|---|---|---|---|---|\n",
        j["logs_per_row"], j["rig_seed"], j["noise_seed"]
    );
    for r in j["rows"].as_array().into_iter().flatten() {
        s += &format!(
            "| {} | {} | {} | {} | {} | {} / {} | {} |\n",
            r["servo"].as_str().unwrap_or("?"),
            f(&r["odr_hz"]),
            r["path"].as_str().unwrap_or("?"),
            e3(f(&r["rms_mean"])),
            e3(f(&r["max"])),
            r["full_k"],
            r["scored"],
            count(&r["failed"])
        );
    }
    s
}

/// The sensor a benchmark's JSON says it simulated: `the LSM9DS1 at 119 Hz, ±500 °/s, ±2 g`.
fn sensor_of(j: &Value) -> String {
    let setup = &j["setup"];
    format!(
        "the {} at {} Hz, ±{} °/s, ±{} g",
        setup["sensor"].as_str().unwrap_or("LSM9DS1"),
        f(&setup["odr_hz"]),
        f(&setup["gyro_range_dps"]),
        f(&setup["accel_range_g"])
    )
}

fn full_k_section(heading: &str, j: &Value) -> String {
    let mut s = format!(
        "## {heading}\n\n`full-k-bench` (seed {}, {} pan/tilt rigs, {}; gyro cross-axis coupling U(±1 %), accelerometer misalignment \
         U(±0.3 %)): every element of `E = Qᵀ K̂ K⁻¹ − I`; rig time {:.1} s mean, {:.1} s max. Paths: \"firmware\" rows are the firmware's \
         procedure (the `tilt-servo` build's pan/tilt plan), \"calib\" rows `gyrocal-calib` on logs of a scripted pan/tilt protocol with 12 \
         hand-held poses; the diagonal rows are the sweep `K` reported beside the full one; failed: rigs without that `K`.\n\n\
         | method | RMS of E (mean over rigs) | largest | rigs | failed |\n|---|---|---|---|---|\n",
        j["seed"],
        j["rigs"],
        sensor_of(j),
        f(&j["rig_time_s"]["mean"]),
        f(&j["rig_time_s"]["max"])
    );
    for r in j["rows"].as_array().into_iter().flatten() {
        s += &format!(
            "| {} | {} | {} | {} | {} |\n",
            r["method"].as_str().unwrap_or("?"),
            e3(f(&r["rms_mean"])),
            e3(f(&r["max"])),
            r["rigs"],
            count(&r["failed"])
        );
    }
    s
}

/// A share as a whole percentage, `–` when there is none.
/// A signed number with one decimal and a true minus sign.
fn signed(x: f64) -> String {
    format!("{x:+.1}").replace('-', "−")
}

fn percent(v: &Value) -> String {
    v.as_f64().map_or("–".into(), |x| format!("{:.0} %", 100.0 * x))
}

fn rotation_section(heading: &str, j: &Value) -> String {
    let mut s = format!(
        "## {heading}\n\n`rotation-bench` (seed {}, {} rigs per row, {}, the hand-held poses held by a {} hand): the full K with and without \
         the rotation constraints of the moves between static poses (one servo without them gives no full K: that row scores the diagonal \
         sweep K); every rig with gyro cross-axis coupling U(±1 %) and accelerometer misalignment U(±0.3 %); E as above; failed: rigs without \
         that K. Paths: \"(firmware)\" rows are the firmware's procedure (one servo, the simulated operator's hand-held poses: 12, and more while the moves leave K short of its goal, up to 20), the others \
         `gyrocal-calib`'s data-driven path on simulated logs. Coverage: the share of the full K's elements whose error \
         `E_ij` lies within their reported 1σ and 2σ (a true 1σ gives 68 % and 95 %).\n\n| rig | rotations | RMS of E | largest | rigs | failed | within 1σ | within 2σ |\n|---|---|---|---|---|---|---|---|\n",
        j["seed"],
        j["rigs"],
        sensor_of(j),
        j["hand"].as_str().unwrap_or("braced")
    );
    for r in j["rows"].as_array().into_iter().flatten() {
        s += &format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
            r["rig"].as_str().unwrap_or("?"),
            r["label"].as_str().unwrap_or(if r["rotations"].as_bool() == Some(true) { "on" } else { "off" }),
            e3(f(&r["rms_mean"])),
            e3(f(&r["max"])),
            r["rigs"],
            count(&r["failed"]),
            percent(&r["within_1sigma"]),
            percent(&r["within_2sigma"])
        );
    }
    s += "\nThe offline tool's other 1σ on the same logs (per axis, the rows with rotations): the gyro bias it gives for the log's end against \
          the truth then, the accelerometer's offsets and diagonal gains (in the fit's upper-triangular gauge).\n\n\
          | rig | bias within 1σ / 2σ | accel offset | accel gain |\n|---|---|---|---|\n";
    for r in j["rows"].as_array().into_iter().flatten().filter(|r| r["bias_within"].is_array()) {
        let pair = |v: &Value| format!("{} / {}", percent(&v[0]), percent(&v[1]));
        s += &format!(
            "| {} | {} | {} | {} |\n",
            r["rig"].as_str().unwrap_or("?"),
            pair(&r["bias_within"]),
            pair(&r["accel_offset_within"]),
            pair(&r["accel_gain_within"])
        );
    }
    s
}

/// The rotation bench's rows with rotations across rig-sim's hand family (`HandLevel`), one
/// rotation-bench summary per hand: every 1σ the offline tool and the firmware give, side by side.
fn family_section(runs: &[Value]) -> String {
    let mut s = format!(
        "## Rotation bench across the hand family\n\n`rotation-bench --hand H` (seed {}, {} rigs per row, {}): the rows with rotations of \
         the two sections above for every hand of rig-sim's family (`HandLevel`): braced and free pivot at the sensor with a sway and a \
         translation of their own; wrist (sway ≈ 0.05° at 0.4–1.5 Hz about a pivot 8–15 cm away), arm (≈ 0.15°, 20–40 cm) and nod (≈ 0.15° \
         at 0.15–0.5 Hz about one axis, 25–40 cm) feel their sway's own linear acceleration `α × r + ω × (ω × r)`. Coverage: within \
         1σ / 2σ (a true 1σ gives 68 % / 95 %); \"–\": not given on that path.\n\n\
         | hand | rig | RMS of E | largest | rigs | failed | K | bias | accel offset | accel gain |\n|---|---|---|---|---|---|---|---|---|---|\n",
        runs.first().map_or(Value::Null, |j| j["seed"].clone()),
        runs.first().map_or(Value::Null, |j| j["rigs"].clone()),
        runs.first().map_or("?".into(), sensor_of),
    );
    for j in runs {
        for r in j["rows"].as_array().into_iter().flatten().filter(|r| r["rotations"].as_bool() == Some(true)) {
            let pair = |a: &Value, b: &Value| if a.is_null() { "–".to_string() } else { format!("{} / {}", percent(a), percent(b)) };
            s += &format!(
                "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                j["hand"].as_str().unwrap_or("?"),
                r["rig"].as_str().unwrap_or("?"),
                e3(f(&r["rms_mean"])),
                e3(f(&r["max"])),
                r["rigs"],
                count(&r["failed"]),
                pair(&r["within_1sigma"], &r["within_2sigma"]),
                pair(&r["bias_within"][0], &r["bias_within"][1]),
                pair(&r["accel_offset_within"][0], &r["accel_offset_within"][1]),
                pair(&r["accel_gain_within"][0], &r["accel_gain_within"][1]),
            );
        }
    }
    s
}

/// A drift-bench table under `heading` (its sensor setup said).
fn drift_section(heading: &str, j: &Value) -> String {
    let mut s = format!(
        "## {heading}

`drift-bench` (seed {}, {} rigs per row, {}; one-servo rigs without cross-axis coupling, pan/tilt rigs with U(±1 %)): the \
         firmware's procedure on simulated rigs with the gyro bias constant, drifting as on a \
         board just powered up (warm-up, bias and scale tempco, a random walk drawn per rig log-uniform over {:.2e}..{:.2e} °/s/√s, Earth rate; \
         the bias tracked between rests, the Earth's rate in the hand-held poses estimated with K; K scored at the run's mean temperature), and drifting after a \
         warm-up wait; E as above, \"E in 2σ\" the fraction of E's elements within twice the 1σ the record gives them, time from power-on to the store (the harness presses the button 1 s in) plus the wait; the bias's temperature coefficient: the runs \
         that reported it (the others: a span below 1 °C, unknown) and the fraction of its axes within 2σ of the truth; the stored \
         bias (applied with the tempco at the run's last temperature, as a sketch does) against the truth at the run's end, RMS over \
         axes, beside the first rest's alone (what records held before).\n\n\
         | plan | bias | RMS of E | largest | E in 2σ | time (s) | stored | failed | tempco runs | tempco within 2σ | bias error (°/s) | first rest's |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n",
        j["seed"],
        j["rigs"],
        sensor_of(j),
        f(&j["walk_range"][0]),
        f(&j["walk_range"][1])
    );
    for r in j["rows"].as_array().into_iter().flatten() {
        s += &format!(
            "| {} | {} | {} | {} | {} | {:.0} | {} | {} | {} | {} | {:.4} | {:.4} |\n",
            r["plan"].as_str().unwrap_or("?"),
            r["bias"].as_str().unwrap_or("?"),
            e3(f(&r["rms_mean"])),
            e3(f(&r["max"])),
            percent(&r["e_within_2sigma"]),
            f(&r["time_s"]),
            r["stored"],
            count(&r["failed"]),
            r["tempco_runs"],
            if r["tempco_runs"].as_u64() == Some(0) { "–".to_string() } else { percent(&r["tempco_within_2sigma"]) },
            f(&r["bias_rms_dps"]),
            f(&r["first_rest_bias_rms_dps"])
        );
    }
    s += "\nThe bias's temperature coefficient over the walk's range: the same drifting rigs with the walk at the range's ends and middle, \
          and drawn per rig. Its 1σ counts the walk the rests' scatter shows (`TempFit`: the scatter about the fitted line beside \
          that of consecutive rests) plus half a standard error of that estimate, which one run leaves large; \
          \"walk measured\" is that estimate (median), which takes every slow misfit of the rests for walk: the Earth's rate that \
          differs from pose to pose, the temperature register's steps (1/16 °C on the LSM9DS1: ±1.2e-3 °/s at 0.04 °/s/°C).\n\n\
          | plan | walk (°/s/√s) | tempco runs | within 1σ | within 2σ | median 1σ (°/s/°C) | walk measured (median) |\n|---|---|---|---|---|---|---|\n";
    for r in j["walks"].as_array().into_iter().flatten() {
        s += &format!(
            "| {} | {} | {} | {} | {} | {:.4} | {:.2e} |\n",
            r["plan"].as_str().unwrap_or("?"),
            r["walk"].as_f64().map_or("drawn".to_string(), |q| format!("{q:.2e}")),
            r["tempco_runs"],
            percent(&r["within_1sigma"]),
            percent(&r["within_2sigma"]),
            f(&r["sigma_median"]),
            f(&r["walk_measured_median"])
        );
    }
    s += &format!(
        "\nE across the part's ODR error: the same drifting rigs, every one at a fixed error, at the ends and the middle of the \
         range the rows above draw from ({}..{} %). The largest |E| is the largest of the runs' 9 elements; over {} runs \
         it is the tail of the plan's noise (on one servo: its hand moves, 11 to 19, and which moves the operator made), not of the \
         ODR error ([limits](limits.md)); \"E in 2σ\" says whether the record's 1σ covers it.\n\n\
         | plan | ODR error | RMS of E | largest | E in 2σ | stored | failed |\n|---|---|---|---|---|---|---|\n",
        signed(f(&j["odr_range_pct"][0])),
        signed(f(&j["odr_range_pct"][1])),
        j["rigs"]
    );
    for r in j["odr_rows"].as_array().into_iter().flatten() {
        s += &format!(
            "| {} | {} % | {} | {} | {} | {} | {} |\n",
            r["plan"].as_str().unwrap_or("?"),
            signed(f(&r["odr_error_pct"])),
            e3(f(&r["rms_mean"])),
            e3(f(&r["max"])),
            percent(&r["e_within_2sigma"]),
            r["stored"],
            count(&r["failed"])
        );
    }
    s
}

fn real_section(j: &Value) -> String {
    let mut s = String::from(
        "## Real recordings\n\n`real-bench`: `gyrocal-calib`'s code on public sessions recorded on real IMUs by other projects \
         (`../shared/data/real/`: sources, licences and conversions in its README), hand-held, beside imucal 2.6.0's \
         `FerrarisCalibration` (its own section list of the session) where it gives one. z: (ours − peer) / our 1σ.\n\n\
         | session | options | K diagonal (1σ) | peer | z | moves between poses |\n|---|---|---|---|---|---|\n",
    );
    for r in j["sessions"].as_array().into_iter().flatten() {
        let three = |v: &Value, d: usize| (0..3).map(|i| format!("{:.*}", d, f(&v[i]))).collect::<Vec<_>>().join(", ");
        let result = match r["k"].as_array() {
            Some(_) => (0..3).map(|i| format!("{:.4} ({:.4})", f(&r["k"][i]), f(&r["sigma_k"][i]))).collect::<Vec<_>>().join(", "),
            None => format!("none: {}", r["error"].as_str().unwrap_or("?")),
        };
        let peer = if r["peer_k"].is_null() { "–".to_string() } else { three(&r["peer_k"], 4) };
        let z = if r["z"].is_null() { "–".to_string() } else { three(&r["z"], 1) };
        let m = &r["hand_moves"];
        let moves = if m.is_null() {
            "–".to_string()
        } else {
            let dropped = m["dropped"].as_object().map_or(String::new(), |d| {
                d.iter().filter(|(_, n)| n.as_u64() != Some(0)).map(|(k, n)| format!("{n} {k}")).collect::<Vec<_>>().join(", ")
            });
            format!(
                "{} of {} kept ({} vertical, {}); dropped: {}",
                m["kept"],
                m["total"],
                m["vertical"],
                m["vertical_turns"].as_str().unwrap_or("?"),
                if dropped.is_empty() { "none".into() } else { dropped }
            )
        };
        s += &format!(
            "| `{}` | `{}` | {result} | {peer} | {z} | {moves} |\n",
            r["session"].as_str().unwrap_or("?"),
            r["options"].as_str().unwrap_or("?")
        );
    }
    s
}

fn mag_section(rev1: &Value, rev2: &Value) -> String {
    let mut s = format!(
        "## Magnetometer\n\n`mag-bench` (seed {}, {} rigs per row, {} random attitudes each): `gyrocal-calib`'s magnetometer \
         calibration from the hand-held step (hard and soft iron, and the die's rotation onto the calibrated accelerometer \
         from the gravity–field angle) beside the ellipsoid alone that the usual tools fit, on one-servo rigs (gyro cross-axis \
         coupling U(±1 %), accelerometer misalignment U(±0.3 %)) with the \
         board's magnetometer (the site's field 40–60 µT at a dip of 50–70°, hard iron ±40 µT, soft iron ±5 %, the die \
         turned up to 2°, the servo's motor magnet near the board on the shaft; a braced hand): the tilt-compensated \
         heading error against the truth, in the calibrated accelerometer's frame; rig readings: those of each log left \
         out of the fit (a servo commanded, or a rest next to the rig whose field is not the hand's). Paths: the script \
         and \"log\" rows are `gyrocal-calib` on a log; \"record\" is the magnetometer the firmware's procedure fits \
         and stores itself (calib-core's procedure on the simulated rig, from the hand-held step's second pose on; the \
         firmware ELF on the emulated board does the same: the demo rows above).\n\n\
         | part | log | heading RMS | largest | ellipsoid alone: RMS | largest | rigs | failed | rig readings left out |\n\
         |---|---|---|---|---|---|---|---|---|\n",
        rev1["seed"], rev1["rigs"], rev1["attitudes"]
    );
    for (part, j) in [("LSM9DS1 (Rev1)", rev1), ("BMM150 (Rev2)", rev2)] {
        for r in j["rows"].as_array().into_iter().flatten() {
            s += &format!(
                "| {part} | {} | {:.3}° | {:.3}° | {:.3}° | {:.3}° | {} | {} | {} |\n",
                r["log"].as_str().unwrap_or("?"),
                f(&r["rms_deg"]),
                f(&r["max_deg"]),
                f(&r["ellipsoid_rms_deg"]),
                f(&r["ellipsoid_max_deg"]),
                r["rigs"],
                count(&r["failed"]),
                r["rig_readings_left_out_per_log"]
            );
        }
    }
    // The bound (0.3° RMS, 1° at the largest): the rows beyond it, named.
    let over: Vec<String> = [("LSM9DS1", rev1), ("BMM150", rev2)]
        .iter()
        .flat_map(|(part, j)| j["rows"].as_array().into_iter().flatten().map(move |r| (part, r)))
        .filter(|(_, r)| f(&r["rms_deg"]) > 0.3 || f(&r["max_deg"]) > 1.0)
        .map(|(part, r)| {
            format!("{part}'s \"{}\" ({:.3}° RMS, {:.3}° largest)", r["log"].as_str().unwrap_or("?"), f(&r["rms_deg"]), f(&r["max_deg"]))
        })
        .collect();
    s += &match over.len() {
        0 => "\nEvery row is within the bound of issue 33 (0.3° RMS, 1° at the largest).\n".to_string(),
        _ => format!("\nBeyond the bound of issue 33 (0.3° RMS, 1° at the largest): {}.\n", over.join(", ")),
    };
    s
}

fn ahrs_section(rev1: &Value, rev2: &Value) -> String {
    let mut s = format!(
        "## What it buys an AHRS filter\n\n`ahrs-bench` (seed {}, {} rigs each, {} failed / {} failed): Madgwick's filter (the `ahrs` crate, \
         beta {}) fed {} s of a hand turning the board between random attitudes right after its calibration, as raw readings, \
         with only the gyro calibrated, with the magnetometer's ellipsoid alone (gyro and accelerometer calibrated) and fully \
         calibrated (`gyrocal-calib` on the scripted one-servo log of rigs with gyro cross-axis coupling U(±1 %): `K`, bias, `M`, the magnetometer's `A` with the die's \
         alignment); the heading error of the filter's body x axis against the truth after {} s of settling, while that axis \
         is within 60° of the horizon (its heading is defined). The filter starts at its own first readings' attitude.\n\n\
         | fed | LSM9DS1 (Rev1): RMS | largest | BMI270 + BMM150 (Rev2): RMS | largest |\n|---|---|---|---|---|\n",
        rev1["seed"],
        rev1["rigs"],
        count(&rev1["failed"]),
        count(&rev2["failed"]),
        rev1["beta"],
        rev1["motion_s"],
        rev1["settle_s"]
    );
    let rows2 = rev2["rows"].as_array().cloned().unwrap_or_default();
    for (i, r) in rev1["rows"].as_array().into_iter().flatten().enumerate() {
        let r2 = rows2.get(i).cloned().unwrap_or(Value::Null);
        s += &format!(
            "| {} | {:.2}° | {:.2}° | {:.2}° | {:.2}° |\n",
            r["fed"].as_str().unwrap_or("?"),
            f(&r["rms_deg"]),
            f(&r["max_deg"]),
            f(&r2["rms_deg"]),
            f(&r2["max_deg"])
        );
    }
    s
}

/// A run's arguments for the quick set (`--check`): the same code paths on fewer rigs, logs
/// and runs; the demos and the real sessions as they are.
fn quick(r: Run) -> Run {
    let a = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let mut args = r.args;
    // Drop a count the full set gives, then the quick one.
    if let Some(i) = args.iter().position(|x| x == "--rigs" || x == "--logs") {
        args.drain(i..i + 2);
    }
    args.extend(match r.bin {
        "rotation-bench" | "full-k-bench" | "mag-bench" | "ahrs-bench" | "drift-bench" => a(&["--rigs", "3"]),
        "calib-bench" => a(&["--logs", "2"]),
        "paper-tables" => a(&["--runs", "10", "--noise-runs", "500", "--rig-runs", "3"]),
        _ => vec![],
    });
    Run { bin: r.bin, args }
}

/// Rigs per row of the rotation bench's runs (every hand of the family, Rev2's): a coverage of 68 %
/// over 20 rigs' 60 bias or accelerometer values has a binomial σ of 6 %, so "within 60–75 %
/// on every row" would say little; over 100 rigs (300 values) 2.7 %, which put three of the
/// family's 60 coverages at 76–78 % that read 74–75 % over 300 rigs; over 300 (900 values,
/// three values of a rig not independent) 1.6 %.
const FAMILY_RIGS: &str = "300";

/// The page from the full set of runs, or (`quick`) from the quick set.
fn page(quick_set: bool) -> Result<String, String> {
    let raw = calib::firmware::target_dir().join("results/raw.csv");
    if let Some(d) = raw.parent() {
        std::fs::create_dir_all(d).map_err(|e| format!("{}: {e}", d.display()))?;
    }
    let a = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let runs = [
        Run { bin: "rotation-bench", args: a(&["--json", "--rigs", FAMILY_RIGS]) },
        Run { bin: "paper-tables", args: a(&["--json"]) },
        Run { bin: "full-k-bench", args: a(&["--json"]) },
        Run { bin: "calib-bench", args: a(&["--logs", "10", "--json"]) },
        Run { bin: "demo", args: a(&["--quiet"]) },
        Run { bin: "demo", args: a(&["--quiet", "--tilt"]) },
        Run { bin: "demo", args: vec!["--quiet".into(), "--raw-log".into(), raw.display().to_string()] },
        Run { bin: "demo", args: a(&["--quiet", "--no-probe"]) },
        Run { bin: "drift-bench", args: a(&["--rigs", "20", "--json"]) },
        Run { bin: "drift-bench", args: a(&["--rigs", "20", "--setup", "arduino-lsm9ds1", "--json"]) },
        Run { bin: "drift-bench", args: a(&["--rigs", "20", "--setup", "bmi270", "--json"]) },
        Run { bin: "demo", args: a(&["--quiet", "--rev2"]) },
        Run { bin: "full-k-bench", args: a(&["--setup", "bmi270", "--json"]) },
        Run { bin: "rotation-bench", args: a(&["--setup", "bmi270", "--json", "--rigs", FAMILY_RIGS]) },
        Run { bin: "real-bench", args: a(&["--json"]) },
        Run { bin: "rotation-bench", args: a(&["--hand", "free", "--json", "--rigs", FAMILY_RIGS]) },
        Run { bin: "mag-bench", args: a(&["--json"]) },
        Run { bin: "mag-bench", args: a(&["--setup", "bmi270", "--json"]) },
        Run { bin: "ahrs-bench", args: a(&["--json"]) },
        Run { bin: "ahrs-bench", args: a(&["--setup", "bmi270", "--json"]) },
        Run { bin: "rotation-bench", args: a(&["--hand", "wrist", "--json", "--rigs", FAMILY_RIGS]) },
        Run { bin: "rotation-bench", args: a(&["--hand", "arm", "--json", "--rigs", FAMILY_RIGS]) },
        Run { bin: "rotation-bench", args: a(&["--hand", "nod", "--json", "--rigs", FAMILY_RIGS]) },
        Run { bin: "demo", args: a(&["--quiet", "--odr952"]) },
    ];
    let runs: Vec<Run> = if quick_set { runs.into_iter().map(quick).collect() } else { runs.into() };
    let out = run_all(&runs)?;
    let mut budgets = vec![];
    for (name, variant) in [("default", &[][..]), ("`tilt-servo`", &["tilt-servo"][..])] {
        let elf = calib::firmware::variant_dir(variant).join("gyrocal-fw");
        let o = Command::new("bash")
            .arg(".ci/firmware-check")
            .arg(&elf)
            .current_dir(root())
            .output()
            .map_err(|e| format!("firmware-check: {e}"))?;
        if !o.status.success() {
            return Err(format!("firmware-check {}: {}", elf.display(), String::from_utf8_lossy(&o.stdout)));
        }
        budgets.push((name.to_string(), String::from_utf8_lossy(&o.stdout).into_owned()));
    }
    let mut s = String::from(if quick_set {
        "<!-- The quick set of `cargo results` (3 rigs, 2 logs, 10 paper runs): what CI's `cargo results -- --check` \
         reruns and compares. Not the figures: those are docs/results.md. -->\n\n"
    } else {
        ""
    });
    s.push_str(
        "# Results\n\n<!-- Generated by `cargo results` from the benchmarks' JSON summaries and the demos' RESULT lines; \
         CI runs `cargo results -- --check`. Do not edit. -->\n\nEvery figure below comes from a run with a fixed seed: \
         `cargo results` reruns them all and rewrites this page. No board was used: the demos run the firmware ELF on the \
         emulated board, the benchmarks run calib-core on simulated rigs ([the virtual board](../host-tests/vboard/README.md), \
         [testing](testing.md)). Each table says its path: the firmware ELF on the emulated board, the firmware's procedure \
         (calib-core's `Procedure`, the code the ELF runs) on a simulated rig, `gyrocal-calib` on a simulated log, or calib-core's \
         estimators directly; its seeds, its failures and the cross-axis coupling of its rigs. The rest of the physics every rig \
         draws (rig-sim's `RigConfig::realistic`) unless a table says otherwise: the sensor's ODR error, U(−5, −2) % for the \
         LSM9DS1 and U(−2, 2) % for the BMI270; a gyro bias that moves as on a board just powered up (a warm-up of U(2, 6) °C along \
         1 − e^(−t/τ), τ U(60, 150) s, a zero-rate tempco of ±U(0.03, 0.05) °/s/°C, a scale tempco of U(±0.02 %)/°C, a random walk \
         log-uniform over 1.25e-4–2e-3 °/s/√s, the Earth's rate at a latitude of U(−60°, 60°)); the servo's angle-scale error U(±3 %). \
         Neither datasheet gives the ODR tolerance or the walk: [limits](limits.md).\n\n",
    );
    let demos = Demos { plain: &out[4], tilt: &out[5], raw: &out[6], no_probe: &out[7], rev2: &out[11], odr952: &out[23] };
    s += &demo_section(&demos, &budgets)?;
    s += "\n";
    s += &paper_section(&json(&out[1])?);
    s += "\n";
    s += &calib_bench_section(&json(&out[3])?);
    s += "\n";
    s += &full_k_section("Full-K bench", &json(&out[2])?);
    s += "\n";
    s += &rotation_section("Rotation bench", &json(&out[0])?);
    s += "\n";
    s += &drift_section("Drift", &json(&out[8])?);
    s += "\n";
    s += &drift_section("At Arduino_LSM9DS1's setup", &json(&out[9])?);
    s += "\n";
    s += &drift_section("Rev2: the BMI270", &json(&out[10])?);
    s += "\n";
    s += &full_k_section("Rev2: full-K bench", &json(&out[12])?);
    s += "\n";
    s += &rotation_section("Rev2: rotation bench", &json(&out[13])?);
    s += "\n";
    s += &rotation_section("Rotation bench, held in the air", &json(&out[15])?);
    s += "\n";
    let family = [0, 15, 20, 21, 22].map(|i| json(&out[i]));
    s += &family_section(&family.into_iter().collect::<Result<Vec<_>, _>>()?);
    s += "\n";
    s += &real_section(&json(&out[14])?);
    s += "\n";
    s += &mag_section(&json(&out[16])?, &json(&out[17])?);
    s += "\n";
    s += &ahrs_section(&json(&out[18])?, &json(&out[19])?);
    Ok(s)
}

/// `results` of `page`: written to `path`, or (`check`) compared with it.
fn settle(path: &Path, new: &str, check: bool) -> ExitCode {
    if check {
        let old = std::fs::read_to_string(path).unwrap_or_default();
        if old == new {
            println!("results: {} is up to date", path.display());
            return ExitCode::SUCCESS;
        }
        let stale = old.lines().zip(new.lines()).position(|(a, b)| a != b).unwrap_or(old.lines().count().min(new.lines().count()));
        eprintln!(
            "results: {} is stale (first difference at line {}): run `cargo results` and commit it\n  page: {}\n  runs: {}",
            path.display(),
            stale + 1,
            old.lines().nth(stale).unwrap_or(""),
            new.lines().nth(stale).unwrap_or("")
        );
        return ExitCode::from(1);
    }
    if let Err(e) = std::fs::write(path, new) {
        eprintln!("results: {}: {e}", path.display());
        return ExitCode::from(2);
    }
    println!("results: wrote {}", path.display());
    ExitCode::SUCCESS
}

fn main() -> ExitCode {
    let args = Args::parse_from(calib::cli_args());
    let full = root().join("docs/results.md");
    let fingerprint = root().join("host-tests/benchmarks/results-quick.md");
    if let Err(e) = build() {
        eprintln!("results: {e}");
        return ExitCode::from(2);
    }
    // CI: the quick set against its committed page (every code path behind the page, on fewer
    // rigs); `--full`: the page itself. Without `--check`, both pages are written.
    let sets: &[(bool, &Path)] = match (args.check, args.full) {
        (true, false) => &[(true, &fingerprint)],
        (true, true) => &[(false, &full)],
        (false, _) => &[(false, &full), (true, &fingerprint)],
    };
    for &(quick_set, path) in sets {
        let new = match page(quick_set) {
            Ok(p) => p,
            Err(e) => {
                eprintln!("results: {e}");
                return ExitCode::from(2);
            }
        };
        let code = settle(path, &new, args.check);
        if code != ExitCode::SUCCESS {
            return code;
        }
    }
    ExitCode::SUCCESS
}
