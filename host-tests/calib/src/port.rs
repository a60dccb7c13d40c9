//! A calibration over the board's USB serial port (`calib --port`), nothing but a USB cable: the
//! board's protocol ([`calib_core::formats::protocol`]) is one-byte commands in, text lines out, which
//! the session knows only as the [`Event`]s they parse to.
//!
//! The session: open the port ([`open`]), drain stale input, [`Command::Stored`] for the stored
//! record (the run starts from its accelerometer calibration), [`Command::RawLog`] until the log
//! header arrives (the end marker instead means raw-log mode was on: again), then
//! [`Command::Calibrate`]; then every line is saved to the log file as received (without CR),
//! the phases and a progress bar (from the plan and the pose lines) go to the user, and in the
//! `reattach` phase the user's Enter is answered with [`Command::Calibrate`]. It ends on
//! [`Event::Failed`] ([`SessionError::CalibrationFailed`]) or on the JSON line after
//! [`RecordLine::CalibrationDone`], then [`Command::RawLog`] again and the end marker. The saved
//! log is then calibrated on the PC ([`offline::calibrate_with`]) and the two `K` compared
//! ([`cross_check`]).
//!
//! The port is read all the time, also while waiting for the user: the board never blocks on
//! USB, it drops whole lines the PC does not read, and a row lost is a gap in the log.

use crate::csvlog::{self, Row};
use crate::offline;
use calib_core::formats::export::RecordJson;
use calib_core::formats::protocol::{self, Command, Event, RecordLine};
use calib_core::formats::record::Record;
use calib_core::procedure::Phase;
use serialport::SerialPort;
use std::fmt;
use std::fs::File;
use std::io::{self, BufRead, BufWriter, Write};
use std::path::PathBuf;
use std::sync::mpsc::{self, TryRecvError};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// Arduino's 1200-baud touch: the port opened at 1200 baud, DTR dropped, closed. The gyrocal
/// firmware (like Arduino's own cores) then leaves for the bootloader's serial mode. The DTR
/// ioctl fails on a pseudo-terminal: ignored.
pub fn touch_1200(port: &str) -> Result<(), serialport::Error> {
    let mut p = serialport::new(port, 1200).timeout(Duration::from_millis(100)).open()?;
    let _ = p.write_data_terminal_ready(false);
    Ok(())
}

/// Baud rate the port is opened at: CDC-ACM ignores it, but 1200 would reset the board into its
/// bootloader (the 1200-baud touch).
pub const BAUD: u32 = 115_200;
/// The part of the cross-check's tolerance on each |ΔK| that the log's rounding takes. The board
/// and calib run the same code on the same samples: what differs is the log's rounding of each
/// sample (1 µs, 1 µg, 10 µ°/s: 1.2e-7 in K measured on a simulated run), the JSON's 7 decimals
/// (5e-8) and the record's `f32` (6e-8 at 1). Measured in the tests: 4.6e-8 to 1.2e-7 (the fake
/// board), 2.4e-7 (the simulated board's own record, from unrounded samples). 1e-5 is 40× that.
pub const K_TOLERANCE: f32 = 1e-5;
/// The other part, in the element's 1σ (the board's record): the board solves in `f32`, calib in
/// `f64`, and vboard's precision test holds the difference within a tenth of the 1σ (0.05σ
/// measured). With [`K_TOLERANCE`], still far below what one row lost in a move does (its gyro
/// integral short by a sample: 3 rows lost moved K by 5.8e-4, ≈ 4σ).
pub const K_TOLERANCE_SIGMA: f32 = 0.1;
/// How long one read of the port waits: the session checks its timeouts and the user's Enter
/// this often.
const POLL: Duration = Duration::from_millis(50);
/// How long the board may take to answer a command.
const ANSWER: Duration = Duration::from_secs(10);
/// Lines after `calibration done` within which its result line must come.
const RESULT_WITHIN_LINES: usize = 200;

/// The session's limits and where it saves the log.
#[derive(Debug, Clone)]
pub struct Options {
    /// Where every received line is saved.
    pub log: PathBuf,
    /// Longest time without a byte from the board.
    pub silence: Duration,
    /// Longest whole session (the user's re-clamp included).
    pub timeout: Duration,
    /// Redraw the progress bar in place with `\r` (the user's output is a terminal); otherwise
    /// one line per captured pose.
    pub redraw: bool,
}

impl Options {
    /// Saving to `log`; 30 s of silence, 600 s in all; no redraw.
    pub fn new(log: impl Into<PathBuf>) -> Self {
        Options { log: log.into(), silence: Duration::from_secs(30), timeout: Duration::from_secs(600), redraw: false }
    }
}

/// `gyrocal-<unix time in s>.csv`, in the current directory.
pub fn default_log_path() -> PathBuf {
    let t = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs());
    PathBuf::from(format!("gyrocal-{t}.csv"))
}

/// What a session brought back.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The board's result line (JSON), as received.
    pub json: String,
    /// The board's record rebuilt from it ([`record_from_json`]).
    pub record: Record,
    /// Lines saved to the log.
    pub lines: usize,
    /// The board's `K` beside calib's on the saved log.
    pub check: CrossCheck,
    /// The record the board had when the run started (its `s` answer), which the run started
    /// from: the saved log replays from it ([`offline::calibrate_log`]).
    pub stored: Option<Record>,
}

/// calib's result on the saved log, beside the board's.
#[derive(Debug, Clone)]
pub struct CrossCheck {
    /// calib's result as a record ([`offline::Calibration::record`]).
    pub calib: Record,
    /// |K_board − K_calib| of the element nearest its tolerance, or beyond it by the most.
    pub max_diff: f32,
    /// That element's tolerance: [`K_TOLERANCE`] and [`K_TOLERANCE_SIGMA`] of its 1σ.
    pub tolerance: f32,
    /// Where it is (row, column).
    pub at: (usize, usize),
    /// Rows in the saved log.
    pub rows: usize,
    /// Rows missing from it: gaps in its time column (a gap of n sample periods is n − 1 rows).
    pub lost_rows: usize,
    /// Bytes the board said it dropped since its boot (its last `USB: <n> bytes dropped` line).
    pub dropped_bytes: u64,
    /// The configuration calib replayed the log under; `None` (a failed check): calib found the
    /// phases from the data instead.
    pub replayed: Option<&'static str>,
}

/// What a session waits for when it fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Awaiting {
    /// The answer to [`Command::Stored`].
    StoredRecord,
    /// The raw-log header (the answer to [`Command::RawLog`]).
    RawLogHeader,
    /// The calibration's lines.
    Calibration,
    /// The user's Enter after the re-clamp.
    Enter,
    /// The end marker of the raw log (the answer to [`Command::RawLog`]).
    RawLogEnd,
}

impl fmt::Display for Awaiting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (what, answer_to) = match self {
            Awaiting::StoredRecord => ("the stored calibration", Some(Command::Stored)),
            Awaiting::RawLogHeader => ("the raw-log header", Some(Command::RawLog)),
            Awaiting::Calibration => ("the calibration", None),
            Awaiting::Enter => ("Enter (the board clamped back)", None),
            Awaiting::RawLogEnd => ("the end marker of the raw log", Some(Command::RawLog)),
        };
        match answer_to {
            Some(c) => write!(f, "{what} (its answer to {})", c.byte() as char),
            None => f.write_str(what),
        }
    }
}

/// Why a session failed. [`SessionError::exit_code`] is `calib`'s exit code for it.
#[derive(Debug)]
pub enum SessionError {
    /// The port could not be opened.
    Open {
        /// The port's path.
        port: String,
        /// Why.
        error: serialport::Error,
    },
    /// Reading or writing the port failed (the board was unplugged or reset).
    Port(io::Error),
    /// The log file could not be written.
    LogFile {
        /// Its path.
        path: PathBuf,
        /// Why.
        error: io::Error,
    },
    /// No byte from the board for this long.
    Silent {
        /// The limit (s).
        secs: u64,
        /// What the session was waiting for.
        waiting_for: Awaiting,
    },
    /// The whole session took longer than its limit.
    Timeout {
        /// The limit (s).
        secs: u64,
        /// What the session was waiting for.
        waiting_for: Awaiting,
    },
    /// The board did not answer a command in time.
    NoAnswer {
        /// What the session waited for.
        waiting_for: Awaiting,
        /// The limit (s).
        secs: u64,
    },
    /// The board's calibration failed: its message.
    CalibrationFailed(String),
    /// The board's result line is not the expected JSON: why.
    BadResult(String),
    /// The saved log is not a valid log.
    Log(csvlog::LogError),
    /// calib could not calibrate the saved log: why.
    Offline(String),
    /// The board's `K` and calib's on the saved log disagree.
    Mismatch {
        /// The comparison.
        check: Box<CrossCheck>,
        /// The board's record.
        board: Box<Record>,
        /// The likely cause.
        reason: String,
    },
}

impl SessionError {
    /// `calib`'s exit code: 1 the calibration failed (on the board, or calib on the log), 2 port,
    /// file or input error, 3 malformed data from the board, 5 cross-check failed, 6 timeout.
    pub fn exit_code(&self) -> u8 {
        match self {
            SessionError::CalibrationFailed(_) | SessionError::Offline(_) => 1,
            SessionError::Open { .. } | SessionError::Port(_) | SessionError::LogFile { .. } => 2,
            SessionError::BadResult(_) | SessionError::Log(_) => 3,
            SessionError::Mismatch { .. } => 5,
            SessionError::Silent { .. } | SessionError::Timeout { .. } | SessionError::NoAnswer { .. } => 6,
        }
    }
}

impl fmt::Display for SessionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SessionError::Open { port, error } => write!(f, "{port}: cannot open the port: {error}"),
            SessionError::Port(e) => write!(f, "the port failed: {e} (board unplugged or reset?)"),
            SessionError::LogFile { path, error } => write!(f, "{}: cannot write the log: {error}", path.display()),
            SessionError::Silent { secs, waiting_for } => {
                write!(f, "no byte from the board for {secs} s while waiting for {waiting_for}: is the gyrocal firmware running on it?")
            }
            SessionError::Timeout { secs, waiting_for } => {
                write!(f, "the session took longer than {secs} s (--timeout), waiting for {waiting_for}")
            }
            SessionError::NoAnswer { waiting_for, secs } => write!(
                f,
                "the board did not send {waiting_for} within {secs} s: is the gyrocal firmware with the USB protocol \
                 running on it?"
            ),
            SessionError::CalibrationFailed(m) => write!(f, "calibration failed, nothing stored: {m}"),
            SessionError::BadResult(m) => write!(f, "the board's result line: {m}"),
            SessionError::Log(e) => write!(f, "the saved log: {e}"),
            SessionError::Offline(m) => write!(f, "calib on the saved log: {m}"),
            SessionError::Mismatch { check: c, board, reason } => {
                let (i, j) = c.at;
                write!(
                    f,
                    "cross-check failed: the board's K[{i}][{j}] = {:.7} ({} K), calib's on the saved log {:.7} ({} K), differ by \
                     {:.1e} (tolerance {:.1e}): {reason}",
                    board.gyro_k[i][j],
                    board.method.name(),
                    c.calib.gyro_k[i][j],
                    c.calib.method.name(),
                    c.max_diff,
                    c.tolerance
                )
            }
        }
    }
}

impl std::error::Error for SessionError {}

/// Opens `path` at [`BAUD`] with DTR on (the DTR/RTS ioctls fail on a pseudo-terminal: ignored).
pub fn open(path: &str) -> Result<Box<dyn SerialPort>, SessionError> {
    serialport::new(path, BAUD).dtr_on_open(true).timeout(POLL).open().map_err(|error| SessionError::Open { port: path.into(), error })
}

/// Runs a session on `port` (see the module). `input` gives the user's Enter (the CLI passes
/// stdin): each line answers one `reattach`, also if typed ahead; it is read on a thread of its
/// own that ends with `input` or at its next line; without input the board's button goes on.
/// `ui` gets the phases, instructions and progress. The board's result line is returned in the
/// [`Outcome`], not printed.
pub fn run(
    port: &mut dyn SerialPort,
    input: impl BufRead + Send + 'static,
    ui: &mut dyn Write,
    opts: &Options,
) -> Result<Outcome, SessionError> {
    let file = File::create(&opts.log).map_err(|error| SessionError::LogFile { path: opts.log.clone(), error })?;
    let mut ui = Ui { out: ui, redraw: opts.redraw, bar_open: false };
    let enter = enter_lines(input);
    port.set_timeout(POLL).map_err(|e| SessionError::Port(e.into()))?;
    let mut link = Link::new(port, file, opts);
    link.drain()?;

    // The record the run starts from (its accelerometer calibration replaces the hand-held
    // poses): the answer is a record line and its JSON, or none stored.
    link.send(Command::Stored)?;
    let asked = Instant::now();
    let stored = loop {
        let waiting_for = Awaiting::StoredRecord;
        match link.line(waiting_for)?.as_deref().map(protocol::parse) {
            Some(Some(Event::ResultJson(j))) => break Some(record_from_json(j).map_err(SessionError::BadResult)?),
            Some(Some(Event::NoRecord)) => break None,
            _ if asked.elapsed() >= ANSWER => return Err(SessionError::NoAnswer { waiting_for, secs: ANSWER.as_secs() }),
            _ => {}
        }
    };

    // Raw-log mode on; the command toggles, so the end marker instead of the header: it was on,
    // again.
    link.send(Command::RawLog)?;
    let asked = Instant::now();
    loop {
        let waiting_for = Awaiting::RawLogHeader;
        match link.line(waiting_for)?.as_deref().map(protocol::parse) {
            Some(Some(Event::RawLogStart)) => break,
            Some(Some(Event::RawLogEnd)) => link.send(Command::RawLog)?,
            _ if asked.elapsed() >= ANSWER => return Err(SessionError::NoAnswer { waiting_for, secs: ANSWER.as_secs() }),
            _ => {}
        }
    }
    let c = Command::Calibrate.byte() as char;
    ui.say(&format!("calib: raw log on, saving every line to {}; calibrating ({c})", opts.log.display()));
    link.send(Command::Calibrate)?;

    // `done`: lines since the calibration-done line.
    let (mut progress, mut reattach, mut done, mut dropped) = (Progress::default(), false, None, 0u64);
    let mut input_open = true;
    let json = loop {
        if reattach && input_open {
            match enter.try_recv() {
                Ok(()) => {
                    link.send(Command::Calibrate)?;
                    reattach = false;
                    ui.say(&format!("calib: continuing ({c})"));
                }
                Err(TryRecvError::Empty) => {}
                Err(TryRecvError::Disconnected) => {
                    input_open = false;
                    ui.say("calib: no input to press Enter on: press the board's button (D2) once it is clamped back");
                }
            }
        }
        let waiting_for = if reattach { Awaiting::Enter } else { Awaiting::Calibration };
        let Some(l) = link.line(waiting_for)? else { continue };
        match protocol::parse(&l) {
            Some(Event::Plan { rig_poses, handheld_poses }) => {
                progress.plan = (rig_poses as usize, handheld_poses as usize);
                ui.say(&l);
            }
            Some(Event::Phase { phase, instruction }) => {
                ui.say(&match instruction {
                    Some(i) => format!("phase {}: {i}", phase.name()),
                    None => format!("phase {}", phase.name()),
                });
                if phase == Phase::Reattach {
                    ui.say("calib: clamp the board back on the servo shaft, then press Enter");
                    reattach = true;
                } else if reattach {
                    ui.say("calib: the board goes on (its button was pressed)");
                    reattach = false;
                }
            }
            Some(Event::HandHeldPose { index }) => {
                progress.handheld = progress.handheld.max(index as usize + 1);
                ui.bar(&progress);
            }
            Some(Event::RigPose { index }) => {
                progress.rig = progress.rig.max(index as usize + 1);
                ui.bar(&progress);
            }
            Some(Event::Failed { reason }) => {
                let _ = link.send(Command::RawLog); // best effort: the board back to its normal log
                link.finish()?;
                return Err(SessionError::CalibrationFailed(reason.to_string()));
            }
            Some(Event::Record { line: RecordLine::CalibrationDone, .. }) => {
                done = Some(0);
                ui.say(&l);
            }
            Some(Event::ResultJson(j)) if done.is_some() => break j.to_string(),
            Some(Event::UsbDropped { bytes }) => {
                dropped = bytes as u64;
                ui.say(&format!("calib: warning: the board says {l}"));
            }
            _ => {
                if let Some(n) = done.as_mut() {
                    *n += 1;
                    if *n > RESULT_WITHIN_LINES {
                        let _ = link.send(Command::RawLog);
                        link.finish()?;
                        return Err(SessionError::BadResult(format!(
                            "no result line (JSON) within {RESULT_WITHIN_LINES} lines after the calibration-done line (a firmware \
                             without it?)"
                        )));
                    }
                }
            }
        }
    };
    // Raw-log mode off: the end marker closes the log.
    link.send(Command::RawLog)?;
    let asked = Instant::now();
    let waiting_for = Awaiting::RawLogEnd;
    while link.line(waiting_for)?.as_deref().and_then(protocol::parse) != Some(Event::RawLogEnd) {
        if asked.elapsed() >= ANSWER {
            return Err(SessionError::NoAnswer { waiting_for, secs: ANSWER.as_secs() });
        }
    }
    let (text, lines) = link.finish()?;

    let record = record_from_json(&json).map_err(SessionError::BadResult)?;
    let check = cross_check(&record, &text, dropped, stored.as_ref())?;
    ui.say(&format!(
        "calib: cross-check passed: calib's K on the saved log ({} rows, replayed as `{}`{}) agrees with the board's to \
         {:.1e} (tolerance {:.1e}){}",
        check.rows,
        check.replayed.unwrap_or_default(),
        if stored.is_some() { " from the stored record" } else { "" },
        check.max_diff,
        check.tolerance,
        match check.lost_rows {
            0 => String::new(),
            n => format!("; {n} rows were lost on USB, without effect on K"),
        }
    ));
    Ok(Outcome { json, record, lines, check, stored })
}

/// Reads `input` on a thread: one message per line (the user's Enter); disconnected at its end.
fn enter_lines(input: impl BufRead + Send + 'static) -> mpsc::Receiver<()> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for l in input.lines() {
            if l.is_err() || tx.send(()).is_err() {
                break;
            }
        }
    });
    rx
}

/// The board's lines, saved as they arrive, with the session's timeouts.
struct Link<'a> {
    port: &'a mut dyn SerialPort,
    pending: Vec<u8>,
    log: BufWriter<File>,
    text: String,
    lines: usize,
    opts: &'a Options,
    start: Instant,
    last_byte: Instant,
}

impl<'a> Link<'a> {
    fn new(port: &'a mut dyn SerialPort, file: File, opts: &'a Options) -> Self {
        let now = Instant::now();
        Link { port, pending: vec![], log: BufWriter::new(file), text: String::new(), lines: 0, opts, start: now, last_byte: now }
    }

    fn send(&mut self, cmd: Command) -> Result<(), SessionError> {
        self.port.write_all(&[cmd.byte()]).and_then(|_| self.port.flush()).map_err(SessionError::Port)
    }

    /// One read of the port (up to [`POLL`]) into `pending`; the number of bytes.
    fn read(&mut self) -> Result<usize, SessionError> {
        let mut buf = [0u8; 4096];
        match self.port.read(&mut buf) {
            Ok(n) => {
                self.pending.extend_from_slice(&buf[..n]);
                Ok(n)
            }
            Err(e) if matches!(e.kind(), io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted) => Ok(0),
            Err(e) => Err(SessionError::Port(e)),
        }
    }

    /// Discards what the board sent before the session: until 250 ms of quiet, at most 2 s
    /// (a board already in raw-log mode never goes quiet).
    fn drain(&mut self) -> Result<(), SessionError> {
        let (t0, mut quiet) = (Instant::now(), Instant::now());
        while t0.elapsed() < Duration::from_secs(2) && quiet.elapsed() < Duration::from_millis(250) {
            if self.read()? > 0 {
                quiet = Instant::now();
            }
        }
        self.pending.clear();
        self.last_byte = Instant::now();
        Ok(())
    }

    /// The next line, saved; `None` if no whole line arrived within one poll. Fails after
    /// [`Options::silence`] without a byte or [`Options::timeout`] in all.
    fn line(&mut self, waiting_for: Awaiting) -> Result<Option<String>, SessionError> {
        if self.pending.contains(&b'\n') {
            return self.take_line().map(Some);
        }
        if self.read()? > 0 {
            self.last_byte = Instant::now();
        } else if self.last_byte.elapsed() >= self.opts.silence {
            return Err(SessionError::Silent { secs: self.opts.silence.as_secs(), waiting_for });
        }
        if self.start.elapsed() >= self.opts.timeout {
            return Err(SessionError::Timeout { secs: self.opts.timeout.as_secs(), waiting_for });
        }
        if self.pending.contains(&b'\n') {
            self.take_line().map(Some)
        } else {
            Ok(None)
        }
    }

    fn take_line(&mut self) -> Result<String, SessionError> {
        let end = self.pending.iter().position(|&b| b == b'\n').unwrap_or(self.pending.len());
        let raw: Vec<u8> = self.pending.drain(..(end + 1).min(self.pending.len())).collect();
        let mut l = String::from_utf8_lossy(&raw[..end]).into_owned();
        if l.ends_with('\r') {
            l.pop();
        }
        writeln!(self.log, "{l}").map_err(|error| SessionError::LogFile { path: self.opts.log.clone(), error })?;
        self.text.push_str(&l);
        self.text.push('\n');
        self.lines += 1;
        Ok(l)
    }

    /// Flushes the log file; the saved text and its number of lines.
    fn finish(mut self) -> Result<(String, usize), SessionError> {
        self.log.flush().map_err(|error| SessionError::LogFile { path: self.opts.log.clone(), error })?;
        Ok((self.text, self.lines))
    }
}

/// Poses announced (`plan`: rig, hand-held) and captured so far.
#[derive(Debug, Default)]
struct Progress {
    plan: (usize, usize),
    handheld: usize,
    rig: usize,
}

impl Progress {
    /// The poses to take: the hand-held step goes on past its planned count until its moves
    /// give `K` their goal, so the count grows with it.
    fn total(&self) -> usize {
        self.plan.0 + self.plan.1.max(self.handheld)
    }
}

/// The user's output: messages, and the progress bar between them.
struct Ui<'a> {
    out: &'a mut dyn Write,
    redraw: bool,
    bar_open: bool,
}

impl Ui<'_> {
    /// One message line (write errors on the user's output are ignored).
    fn say(&mut self, msg: &str) {
        if std::mem::take(&mut self.bar_open) {
            let _ = writeln!(self.out);
        }
        let _ = writeln!(self.out, "{msg}");
    }

    /// `[#####-----] 5/32 poses (h hand-held, r rig)`.
    fn bar(&mut self, p: &Progress) {
        const WIDTH: usize = 30;
        let done = p.handheld + p.rig;
        let fill = (done * WIDTH).checked_div(p.total()).unwrap_or(0).min(WIDTH);
        let bar = format!(
            "[{}{}] {done}/{} poses ({} hand-held, {} rig)",
            "#".repeat(fill),
            "-".repeat(WIDTH - fill),
            p.total(),
            p.handheld,
            p.rig
        );
        if self.redraw {
            let _ = write!(self.out, "\r{bar}");
            let _ = self.out.flush();
            self.bar_open = true;
        } else {
            let _ = writeln!(self.out, "{bar}");
        }
    }
}

/// The record a result line (`calib_core::formats::export`'s JSON, [`RecordJson`]) was written from
/// ([`RecordJson::record`]): `null` is NaN; `K`, `b`, `M` and `o` must be numbers, the names known.
pub fn record_from_json(line: &str) -> Result<Record, String> {
    let j: RecordJson = serde_json::from_str(line).map_err(|e| format!("not the expected JSON ({e}): {line}"))?;
    j.record().map_err(|e| format!("{e}: {line}"))
}

/// Rows missing from a log: a gap of n median sample periods (n ≥ 1.5) is n − 1 rows.
pub fn lost_rows(rows: &[Row]) -> usize {
    let mut dt: Vec<f64> = rows.windows(2).map(|w| w[1].t.s() - w[0].t.s()).collect();
    if dt.is_empty() {
        return 0;
    }
    dt.sort_by(f64::total_cmp);
    let median = dt[dt.len() / 2];
    dt.iter().filter(|&&d| d > 1.5 * median).map(|d| (d / median).round() as usize - 1).sum()
}

/// Calibrates the saved log (`log_text`) with calib ([`offline::calibrate_log`]: defaults,
/// the replay starting from `stored`, the record the board had when the run started, as it did)
/// and compares its `K` with the board's. Passes when every element agrees to its tolerance
/// ([`K_TOLERANCE`] and [`K_TOLERANCE_SIGMA`] of its 1σ) with the same method on a replayed log; otherwise [`SessionError::Mismatch`] naming the
/// likely cause (rows lost on USB, with their number). `dropped_bytes`: the board's own count.
pub fn cross_check(board: &Record, log_text: &str, dropped_bytes: u64, stored: Option<&Record>) -> Result<CrossCheck, SessionError> {
    let log = csvlog::parse(log_text).map_err(SessionError::Log)?;
    let c = offline::calibrate_log(&log, &offline::Options::default(), stored).map_err(|e| SessionError::Offline(e.to_string()))?;
    let calib = c.record().ok_or_else(|| SessionError::Offline(format!("no gyro calibration: {}", c.missing().join("; "))))?;
    let (mut worst, mut max_diff, mut tolerance, mut at) = (-1.0f32, 0.0, K_TOLERANCE, (0, 0));
    for i in 0..3 {
        for j in 0..3 {
            let (d, tol) = ((board.gyro_k[i][j] - calib.gyro_k[i][j]).abs(), K_TOLERANCE + K_TOLERANCE_SIGMA * board.sigma_k[i][j]);
            // A NaN is the worst.
            if d / tol > worst || (d / tol).is_nan() {
                (worst, max_diff, tolerance, at) = (d / tol, d, tol, (i, j));
            }
        }
    }
    let check = CrossCheck {
        calib,
        max_diff,
        tolerance,
        at,
        rows: log.rows.len(),
        lost_rows: lost_rows(&log.rows),
        dropped_bytes,
        replayed: c.replayed,
    };
    if worst <= 1.0 && board.method == calib.method && c.replayed.is_some() {
        return Ok(check);
    }
    let reason = if check.lost_rows > 0 {
        let board_says = match dropped_bytes {
            0 => String::new(),
            n => format!("; the board says {n} bytes dropped since boot"),
        };
        format!(
            "{} of {} rows were lost on USB (gaps in the saved log's time column{board_says}): the PC did not read the \
             port fast enough. Run again (no USB hub, a less busy PC)",
            check.lost_rows,
            check.rows + check.lost_rows
        )
    } else if c.replayed.is_none() {
        "calib could not replay the saved log through the firmware's procedure from the board's stored record (not a \
         whole run of this firmware's procedure: another firmware version than this calib's?)"
            .into()
    } else {
        "every row arrived and the log replays, yet the results differ: the board's firmware and this calib are not the \
         same version?"
            .into()
    };
    Err(SessionError::Mismatch { check: Box::new(check), board: Box::new(*board), reason })
}

#[cfg(test)]
mod tests {
    use super::*;
    use calib_core::Time;

    #[test]
    fn gaps_in_time_are_lost_rows() {
        let row = |t_s: f64| Row {
            t: Time::from_s(t_s).unwrap(),
            accel_g: [0.0, 0.0, 1.0],
            gyro_dps: [0.0; 3],
            servo_deg: None,
            tilt_deg: None,
            mag_ut: None,
            temp_c: None,
        };
        let mut rows: Vec<Row> = (0..100).map(|i| row(i as f64 / 119.0)).collect();
        assert_eq!(lost_rows(&rows), 0);
        rows.drain(40..43);
        rows.remove(70);
        assert_eq!(lost_rows(&rows), 4);
    }
}
