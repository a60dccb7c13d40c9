//! Whole logs on the PC: the format itself ([`calib_core::formats::log`]) is shared with the firmware's
//! raw-log mode; this adds reading a whole text into rows and writing one.

use calib_core::formats::log::{self, Line};
pub use calib_core::formats::log::{LogError, Row, HEADER};
use calib_core::formats::record::SensorSetup;

/// A parsed log.
#[derive(Debug, Clone, PartialEq)]
pub struct Log {
    /// The samples, in time order.
    pub rows: Vec<Row>,
    /// Log messages between the rows that were skipped.
    pub messages: usize,
    /// The sensor setup the log states ([`log::write_setup`]; the firmware's raw log does), if
    /// it states one.
    pub setup: Option<SensorSetup>,
    /// The line number of a last line cut mid-row (the text ends without a newline in a row
    /// that does not parse: a recording stopped while writing), which was left out.
    pub cut_line: Option<u32>,
}

/// Parses a whole log: lines before the header are skipped, comments skipped, log messages
/// skipped and counted, the data end at the end marker or the end of the text; time must
/// increase. A last line cut mid-row is left out and named ([`Log::cut_line`]).
pub fn parse(text: &str) -> Result<Log, LogError> {
    let last = text.lines().count() as u32;
    let unterminated = !text.is_empty() && !text.ends_with('\n');
    let mut lines = text.lines().enumerate().map(|(i, l)| (i as u32 + 1, l));
    let cols = loop {
        match lines.next() {
            Some((_, l)) if log::is_header(l) => break log::parse_header(l.trim())?,
            Some(_) => {}
            None => return Err(LogError::NoHeader),
        }
    };
    let (mut rows, mut messages, mut setup, mut cut_line) = (Vec::<Row>::new(), 0, None, None);
    for (n, l) in lines {
        let line = match log::parse_line(l, &cols, n) {
            Err(_) if unterminated && n == last && !rows.is_empty() => {
                cut_line = Some(n);
                break;
            }
            line => line?,
        };
        match line {
            Line::Skip => {}
            Line::Setup(s) => match setup {
                Some(old) if old != s => return Err(LogError::SetupChanged { line: n }),
                _ => setup = Some(s),
            },
            Line::Message => messages += 1,
            Line::End => break,
            Line::Row(r) => {
                if rows.last().is_some_and(|p| r.t_s <= p.t_s) {
                    return Err(LogError::NonMonotonicTime { line: n });
                }
                rows.push(r);
            }
        }
    }
    if rows.is_empty() {
        return Err(LogError::Empty);
    }
    Ok(Log { rows, messages, setup, cut_line })
}

/// The header line, with its newline.
pub fn header() -> String {
    format!("{HEADER}\n")
}

/// Appends one row and its newline.
pub fn format_row(out: &mut String, r: &Row) {
    let _ = log::write_row(out, r);
    out.push('\n');
}

/// Every column a log may have: [`log::COLUMNS`] then [`log::MAG_COLUMNS`].
fn all_columns() -> impl Iterator<Item = &'static str> {
    log::COLUMNS.iter().chain(log::MAG_COLUMNS.iter()).copied()
}

/// One column of `--columns`: this log column from that source column, times a factor.
#[derive(Debug, Clone, PartialEq)]
struct Source {
    name: String,
    factor: f64,
}

/// Converts a CSV log with other column names or units into this format. `spec` is a comma
/// list of `COLUMN=SOURCE`, `COLUMN=SOURCE*F` or `COLUMN=SOURCE/F` (e.g.
/// `t_s=time/1000,ax_g=acc_x/9.80665,gx_dps=gyr_x*57.29578`); a column not named is taken from a
/// source column of its own name, if any (servo columns may be absent: hand-held). The source's
/// header is its first line that is neither empty nor a `#` comment.
pub fn remap(text: &str, spec: &str) -> Result<String, String> {
    let mut map: Vec<(usize, Source)> = vec![];
    for item in spec.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let (col, src) = item.split_once('=').ok_or(format!("--columns: {item:?} is not COLUMN=SOURCE"))?;
        let at = all_columns()
            .position(|c| c == col.trim())
            .ok_or(format!("--columns: unknown column {col:?} (one of {HEADER},{})", log::MAG_COLUMNS.join(",")))?;
        let (name, factor) = match src.find(['*', '/']) {
            Some(i) => {
                let f: f64 = src[i + 1..].trim().parse().map_err(|_| format!("--columns: {:?} is not a number", &src[i + 1..]))?;
                if !(f.is_finite() && f != 0.0) {
                    return Err(format!("--columns: factor {f} must be finite and non-zero"));
                }
                (src[..i].trim(), if &src[i..i + 1] == "*" { f } else { 1.0 / f })
            }
            None => (src.trim(), 1.0),
        };
        map.push((at, Source { name: name.to_string(), factor }));
    }
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.trim().starts_with('#'));
    let (_, source_header) = lines.next().ok_or("--columns: the log has no header line")?;
    let names: Vec<&str> = source_header.split(',').map(str::trim).collect();
    let mut from: [Option<(usize, f64)>; 12] = [None; 12];
    for (i, col) in all_columns().enumerate() {
        let src = map.iter().find(|(at, _)| *at == i).map(|(_, s)| s.clone()).unwrap_or(Source { name: col.to_string(), factor: 1.0 });
        from[i] = match names.iter().position(|n| *n == src.name) {
            Some(k) => Some((k, src.factor)),
            None if i >= 7 => None,
            None => return Err(format!("--columns: no source column {:?} for {col} in the header {source_header:?}", src.name)),
        };
    }
    let mag = match from[9..].iter().filter(|s| s.is_some()).count() {
        0 => false,
        3 => true,
        _ => return Err(format!("--columns: the magnetometer needs all three of {} or none", log::MAG_COLUMNS.join(","))),
    };
    let mut out = if mag { format!("{HEADER},{}\n", log::MAG_COLUMNS.join(",")) } else { header() };
    for (n, l) in lines {
        let f: Vec<&str> = l.split(',').map(str::trim).collect();
        let mut v = [None; 12];
        for (i, src) in from.iter().enumerate() {
            if let Some((k, factor)) = *src {
                let text = f.get(k).copied().unwrap_or("");
                if !text.is_empty() {
                    let x: f64 = text.parse().map_err(|_| format!("line {}: column {:?}: {text:?} is not a number", n + 1, names[k]))?;
                    v[i] = Some(x * factor);
                }
            }
        }
        let need = |i: usize| v[i].ok_or(format!("line {}: no value for {}", n + 1, log::COLUMNS[i]));
        let row = Row {
            t_s: need(0)?,
            accel_g: [need(1)? as f32, need(2)? as f32, need(3)? as f32],
            gyro_dps: [need(4)? as f32, need(5)? as f32, need(6)? as f32],
            servo_deg: v[7].map(|x| x as f32),
            tilt_deg: v[8].map(|x| x as f32),
            mag_ut: match (v[9], v[10], v[11]) {
                (Some(x), Some(y), Some(z)) => Some([x as f32, y as f32, z as f32]),
                _ => None,
            },
            temp_c: None,
        };
        let _ = log::write_row(&mut out, &row);
        if mag {
            let _ = log::write_mag(&mut out, row.mag_ut);
        }
        out.push('\n');
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use calib_core::formats::record::Sensor;

    #[test]
    fn parses_by_column_name_with_comments_preamble_and_empty_servo() {
        let log = "INFO boot line of a logger\n# made by hand\nservo_deg,t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,extra\n\
                   10.5,0.0,0,0,1,0.1,0.2,0.3,x\n,0.01,0,0,1,0.1,0.2,0.3,y\n";
        // The header must name t_s first to be recognised; this one does not.
        assert_eq!(parse(log), Err(LogError::NoHeader));
        let log = log.replace("servo_deg,t_s,", "t_s,servo_deg,").replace("10.5,0.0,", "0.0,10.5,").replace(",0.01,", "0.01,,");
        let rows = parse(&log).unwrap().rows;
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].servo_deg, Some(10.5));
        assert_eq!(rows[1].servo_deg, None);
        assert_eq!(rows[1].tilt_deg, None);
        assert_eq!(rows[1].gyro_dps, [0.1, 0.2, 0.3]);
    }

    #[test]
    fn bad_logs_are_named() {
        let h = header();
        assert_eq!(parse(""), Err(LogError::NoHeader));
        assert_eq!(parse("t_s,ax_g\n1,2\n"), Err(LogError::MissingColumn("ay_g")));
        assert_eq!(parse(&h), Err(LogError::Empty));
        assert!(matches!(parse(&format!("{h}0,1,2\n")), Err(LogError::ShortRow { line: 2, .. })));
        assert_eq!(parse(&format!("{h}0,a,0,1,0,0,0,,\n")), Err(LogError::BadNumber { line: 2, column: "ax_g" }));
        assert_eq!(parse(&format!("{h}0,NaN,0,1,0,0,0,,\n")), Err(LogError::BadNumber { line: 2, column: "ax_g" }));
        // Finite as an f64, infinite as the f32 a row holds (found by the log reader's fuzz target).
        assert_eq!(parse(&format!("{h}0,-1e300,0,1,0,0,0,,\n")), Err(LogError::BadNumber { line: 2, column: "ax_g" }));
        assert_eq!(parse(&format!("{h}0,0,0,1,0,0,4e38,,\n")), Err(LogError::BadNumber { line: 2, column: "gz_dps" }));
        assert_eq!(parse(&format!("{h}1,0,0,1,0,0,0,,\n1,0,0,1,0,0,0,,\n")), Err(LogError::NonMonotonicTime { line: 3 }));
    }

    #[test]
    fn the_setup_comment_round_trips_and_a_change_is_an_error() {
        let line = |s: &SensorSetup| {
            let mut l = String::new();
            log::write_setup(&mut l, s).unwrap();
            l
        };
        let a = line(&SensorSetup::ARDUINO_LSM9DS1);
        assert_eq!(a, "# sensor setup: odr_hz=119.0 gyro_range_dps=2000.0 accel_range_g=4.0 sensor=lsm9ds1");
        let bmi = SensorSetup { odr_hz: 100.0, sensor: Sensor::Bmi270 { gyr_cas: -3, user_gain: true }, ..SensorSetup::DEFAULT };
        assert_eq!(line(&bmi), "# sensor setup: odr_hz=100.0 gyro_range_dps=500.0 accel_range_g=2.0 sensor=bmi270 gyr_cas=-3 user_gain=1");
        for s in [SensorSetup::DEFAULT, SensorSetup::ARDUINO_LSM9DS1, SensorSetup { odr_hz: 952.0, ..SensorSetup::DEFAULT }, bmi] {
            assert_eq!(log::parse_setup(&line(&s)), Some(s));
        }
        // A log from before the Rev2 support: an LSM9DS1's.
        let old = "# sensor setup: odr_hz=119.0 gyro_range_dps=2000.0 accel_range_g=4.0";
        assert_eq!(log::parse_setup(old), Some(SensorSetup::ARDUINO_LSM9DS1));
        for bad in [
            "# sensor setup: odr_hz=119.0 gyro_range_dps=2000.0",
            "# sensor setup: odr_hz=-1.0 gyro_range_dps=2000.0 accel_range_g=4.0",
            "# sensor setup: odr_hz=100.0 gyro_range_dps=500.0 accel_range_g=2.0 sensor=bmi270 gyr_cas=64 user_gain=0",
            "# sensor setup: odr_hz=100.0 gyro_range_dps=500.0 accel_range_g=2.0 sensor=bmi270 gyr_cas=1",
            "# sensor setup: odr_hz=100.0 gyro_range_dps=500.0 accel_range_g=2.0 sensor=bmi160",
        ] {
            assert_eq!(log::parse_setup(bad), None, "{bad}");
        }
        let row = "0.0,0,0,1,0,0,0,,\n";
        let log = format!("{}{a}\n{row}{a}\n", header());
        assert_eq!(parse(&log).unwrap().setup, Some(SensorSetup::ARDUINO_LSM9DS1));
        assert_eq!(parse(&format!("{}{row}", header())).unwrap().setup, None);
        let changed = format!("{log}{}\n", line(&SensorSetup::DEFAULT));
        assert_eq!(parse(&changed), Err(LogError::SetupChanged { line: 5 }));
    }

    #[test]
    fn format_then_parse_round_trips_and_the_end_marker_ends_the_data() {
        let r = Row {
            t_s: 1.25,
            accel_g: [0.5, -0.25, 0.75],
            gyro_dps: [1.5, -2.0, 3.0],
            servo_deg: Some(30.0),
            tilt_deg: None,
            mag_ut: None,
            temp_c: None,
        };
        let mut s = header();
        format_row(&mut s, &r);
        format_row(&mut s, &Row { t_s: 1.5, servo_deg: None, tilt_deg: Some(-25.0), ..r });
        s.insert_str(header().len(), "phase: bias, a log message\n");
        s.push_str(calib_core::formats::log::END);
        s.push_str("\nINFO a log line after the raw log\n");
        let log = parse(&s).unwrap();
        assert_eq!(log.messages, 1);
        let rows = log.rows;
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0], r);
        assert_eq!((rows[1].servo_deg, rows[1].tilt_deg), (None, Some(-25.0)));
    }

    #[test]
    fn other_tools_logs_convert_by_name_and_unit() {
        let text = "# from another tool\ntime_ms,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n0,0,0,9.80665,0.01,0,0\n10,0,9.80665,0,0,0.02,0\n";
        let spec = "t_s=time_ms/1000,ax_g=acc_x/9.80665,ay_g=acc_y/9.80665,az_g=acc_z/9.80665,gx_dps=gyr_x*57.29578,gy_dps=gyr_y*57.29578,gz_dps=gyr_z*57.29578";
        let rows = parse(&remap(text, spec).unwrap()).unwrap().rows;
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[1].t_s, 0.01);
        assert_eq!(rows[0].accel_g, [0.0, 0.0, 1.0]);
        assert!((rows[0].gyro_dps[0] - 0.5729578).abs() < 1e-5 && rows[1].servo_deg.is_none());
        assert!(remap(text, "t_s=nope").unwrap_err().contains("no source column \"nope\""));
        assert!(remap(text, "x=time_ms").unwrap_err().contains("unknown column"));
        assert!(remap(text, "t_s=time_ms/0").is_err());
    }

    #[test]
    fn magnetometer_columns_are_optional_and_empty_without_a_reading() {
        let mut s = format!("{HEADER},mx_ut,my_ut,mz_ut\n");
        let r = Row {
            t_s: 1.0,
            accel_g: [0.0, 0.0, 1.0],
            gyro_dps: [0.0; 3],
            servo_deg: None,
            tilt_deg: None,
            mag_ut: Some([21.5, -3.25, -40.125]),
            temp_c: None,
        };
        for row in [r, Row { t_s: 1.01, mag_ut: None, ..r }] {
            let _ = log::write_row(&mut s, &row);
            let _ = log::write_mag(&mut s, row.mag_ut);
            s.push('\n');
        }
        let back = parse(&s).unwrap().rows;
        assert_eq!((back[0].mag_ut, back[1].mag_ut), (Some([21.5, -3.25, -40.125]), None));
        // Two of the three columns: named, not guessed.
        let e = parse(&format!("{HEADER},mx_ut,my_ut\n1,0,0,1,0,0,0,,,1,2\n")).unwrap_err();
        assert_eq!(e, LogError::MissingColumn("mz_ut"));
        // A field that is not a number.
        let e = parse(&format!("{HEADER},mx_ut,my_ut,mz_ut\n1,0,0,1,0,0,0,,,1,x,2\n")).unwrap_err();
        assert!(matches!(e, LogError::BadNumber { line: 2, column: "my_ut" }), "{e:?}");
        // --columns maps a source's magnetometer (gauss) into µT.
        let text = "time,ax,ay,az,gx,gy,gz,magx,magy,magz\n0.5,0,0,1,0,0,0,0.2,-0.1,0.4\n";
        let spec = "t_s=time,ax_g=ax,ay_g=ay,az_g=az,gx_dps=gx,gy_dps=gy,gz_dps=gz,mx_ut=magx*100,my_ut=magy*100,mz_ut=magz*100";
        let rows = parse(&remap(text, spec).unwrap()).unwrap().rows;
        assert_eq!(rows[0].mag_ut, Some([20.0, -10.0, 40.0]));
        let partial = spec.split(",mx_ut").next().unwrap().to_string() + ",mx_ut=magx";
        assert!(remap(text, &partial).unwrap_err().contains("all three"));
    }

    #[test]
    fn fixed_decimals_are_exact_for_sensor_counts() {
        // Every LSB value of the ±2 g / ±500 °/s ranges survives the text round trip.
        for counts in [-32768i32, -12345, -1, 0, 1, 777, 32767] {
            let r = Row {
                t_s: 12345.678901,
                accel_g: [counts as f32 * 0.000061; 3],
                gyro_dps: [counts as f32 * 0.0175; 3],
                servo_deg: Some(-12.34),
                tilt_deg: Some(90.0),
                mag_ut: None,
                temp_c: None,
            };
            let mut s = header();
            format_row(&mut s, &r);
            let back = parse(&s).unwrap().rows[0];
            assert!((back.t_s - r.t_s).abs() < 1e-6);
            for i in 0..3 {
                assert!((back.accel_g[i] - r.accel_g[i]).abs() <= 5e-7, "{counts}: {} vs {}", back.accel_g[i], r.accel_g[i]);
                assert!((back.gyro_dps[i] - r.gyro_dps[i]).abs() <= 5e-6);
            }
            assert_eq!(back.servo_deg, Some(-12.34));
        }
    }
}
