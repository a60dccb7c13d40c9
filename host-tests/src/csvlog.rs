//! Whole logs on the PC: the format itself ([`calib_core::log`]) is shared with the firmware's
//! raw-log mode; this adds reading a whole text into rows and writing one.

pub use calib_core::log::{LogError, Row, HEADER};
use calib_core::log::{self, Line};

/// A parsed log.
#[derive(Debug, Clone, PartialEq)]
pub struct Log {
    /// The samples, in time order.
    pub rows: Vec<Row>,
    /// Log messages between the rows that were skipped.
    pub messages: usize,
}

/// Parses a whole log: lines before the header are skipped, comments skipped, log messages
/// skipped and counted, the data end at the end marker or the end of the text; time must
/// increase.
pub fn parse(text: &str) -> Result<Log, LogError> {
    let mut lines = text.lines().enumerate().map(|(i, l)| (i as u32 + 1, l));
    let cols = loop {
        match lines.next() {
            Some((_, l)) if log::is_header(l) => break log::parse_header(l.trim())?,
            Some(_) => {}
            None => return Err(LogError::NoHeader),
        }
    };
    let (mut rows, mut messages) = (Vec::<Row>::new(), 0);
    for (n, l) in lines {
        match log::parse_line(l, &cols, n)? {
            Line::Skip => {}
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
    Ok(Log { rows, messages })
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

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(parse(&format!("{h}1,0,0,1,0,0,0,,\n1,0,0,1,0,0,0,,\n")), Err(LogError::NonMonotonicTime { line: 3 }));
    }

    #[test]
    fn format_then_parse_round_trips_and_the_end_marker_ends_the_data() {
        let r = Row { t_s: 1.25, accel_g: [0.5, -0.25, 0.75], gyro_dps: [1.5, -2.0, 3.0], servo_deg: Some(30.0), tilt_deg: None };
        let mut s = header();
        format_row(&mut s, &r);
        format_row(&mut s, &Row { t_s: 1.5, servo_deg: None, tilt_deg: Some(-25.0), ..r });
        s.insert_str(header().len(), "phase: bias, a log message\n");
        s.push_str(calib_core::log::END);
        s.push_str("\nINFO a log line after the raw log\n");
        let log = parse(&s).unwrap();
        assert_eq!(log.messages, 1);
        let rows = log.rows;
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0], r);
        assert_eq!((rows[1].servo_deg, rows[1].tilt_deg), (None, Some(-25.0)));
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
