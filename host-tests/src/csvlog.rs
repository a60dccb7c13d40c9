//! The recorded log (DESIGN §5): one CSV row per IMU sample,
//! `t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,servo_deg[,tilt_deg]`, `#` comment lines.
//! Columns are found by name; extra columns are ignored.

use std::fmt::{self, Write as _};

/// One IMU sample of a log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Row {
    /// MCU timestamp (s).
    pub t_s: f64,
    /// Raw accelerometer (g).
    pub accel_g: [f32; 3],
    /// Raw gyro (°/s).
    pub gyro_dps: [f32; 3],
    /// Commanded rotation-servo angle (°); `None` while no servo is commanded.
    pub servo_deg: Option<f32>,
    /// Commanded tilt-servo angle (°), when the log has the column.
    pub tilt_deg: Option<f32>,
}

/// Why a log cannot be read. Lines are 1-based.
#[derive(Debug, Clone, PartialEq)]
pub enum LogError {
    /// No header line.
    NoHeader,
    /// A required column is missing from the header.
    MissingColumn(&'static str),
    /// A row has fewer fields than the header.
    ShortRow { line: usize, have: usize, need: usize },
    /// A field is not a number.
    BadNumber { line: usize, column: String, text: String },
    /// A field is NaN or infinite.
    NotFinite { line: usize, column: String },
    /// Time does not increase.
    NonMonotonicTime { line: usize, t_s: f64, previous_s: f64 },
    /// The log has no data rows.
    Empty,
}

impl fmt::Display for LogError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LogError::NoHeader => write!(f, "no header line (expected {})", HEADER),
            LogError::MissingColumn(c) => write!(f, "missing column {c:?} in the header (expected {HEADER})"),
            LogError::ShortRow { line, have, need } => write!(f, "line {line}: {have} fields, the header has {need}"),
            LogError::BadNumber { line, column, text } => write!(f, "line {line}: column {column}: {text:?} is not a number"),
            LogError::NotFinite { line, column } => write!(f, "line {line}: column {column}: NaN or infinite value"),
            LogError::NonMonotonicTime { line, t_s, previous_s } => {
                write!(f, "line {line}: time {t_s} s does not increase (previous {previous_s} s)")
            }
            LogError::Empty => f.write_str("the log has no data rows"),
        }
    }
}

/// The header this project writes.
pub const HEADER: &str = "t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,servo_deg";
const REQUIRED: [&str; 8] = ["t_s", "ax_g", "ay_g", "az_g", "gx_dps", "gy_dps", "gz_dps", "servo_deg"];

/// Parses a whole log.
pub fn parse(text: &str) -> Result<Vec<Row>, LogError> {
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())).filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let (_, header) = lines.next().ok_or(LogError::NoHeader)?;
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let mut idx = [0usize; 8];
    for (slot, name) in idx.iter_mut().zip(REQUIRED) {
        *slot = names.iter().position(|n| *n == name).ok_or(LogError::MissingColumn(name))?;
    }
    let tilt = names.iter().position(|n| *n == "tilt_deg");
    let mut rows: Vec<Row> = Vec::new();
    for (line, l) in lines {
        let fields: Vec<&str> = l.split(',').map(str::trim).collect();
        if fields.len() < names.len() {
            return Err(LogError::ShortRow { line, have: fields.len(), need: names.len() });
        }
        let num = |col: usize| -> Result<f64, LogError> {
            let text = fields[col];
            let v: f64 = text.parse().map_err(|_| LogError::BadNumber { line, column: names[col].into(), text: text.into() })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(LogError::NotFinite { line, column: names[col].into() })
            }
        };
        let opt = |col: usize| -> Result<Option<f32>, LogError> {
            if fields[col].is_empty() {
                Ok(None)
            } else {
                num(col).map(|v| Some(v as f32))
            }
        };
        let t_s = num(idx[0])?;
        if let Some(prev) = rows.last() {
            if t_s <= prev.t_s {
                return Err(LogError::NonMonotonicTime { line, t_s, previous_s: prev.t_s });
            }
        }
        rows.push(Row {
            t_s,
            accel_g: [num(idx[1])? as f32, num(idx[2])? as f32, num(idx[3])? as f32],
            gyro_dps: [num(idx[4])? as f32, num(idx[5])? as f32, num(idx[6])? as f32],
            servo_deg: opt(idx[7])?,
            tilt_deg: tilt.map(opt).transpose()?.flatten(),
        });
    }
    if rows.is_empty() {
        return Err(LogError::Empty);
    }
    Ok(rows)
}

/// The header line (with newline), with the optional `tilt_deg` column.
pub fn header(tilt: bool) -> String {
    if tilt {
        format!("{HEADER},tilt_deg\n")
    } else {
        format!("{HEADER}\n")
    }
}

/// Formats one row for a header made by [`header`]`(tilt)`.
pub fn format_row(out: &mut String, r: &Row, tilt: bool) {
    let _ = write!(
        out,
        "{:.6},{:.6},{:.6},{:.6},{:.5},{:.5},{:.5},",
        r.t_s, r.accel_g[0], r.accel_g[1], r.accel_g[2], r.gyro_dps[0], r.gyro_dps[1], r.gyro_dps[2]
    );
    if let Some(s) = r.servo_deg {
        let _ = write!(out, "{s:.3}");
    }
    if tilt {
        out.push(',');
        if let Some(t) = r.tilt_deg {
            let _ = write!(out, "{t:.3}");
        }
    }
    out.push('\n');
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_by_column_name_with_comments_and_empty_servo() {
        let log = "# made by hand\nservo_deg,t_s,ax_g,ay_g,az_g,gx_dps,gy_dps,gz_dps,extra\n\
                   10.5,0.0,0,0,1,0.1,0.2,0.3,x\n,0.01,0,0,1,0.1,0.2,0.3,y\n";
        let rows = parse(log).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].servo_deg, Some(10.5));
        assert_eq!(rows[1].servo_deg, None);
        assert_eq!(rows[1].gyro_dps, [0.1, 0.2, 0.3]);
    }

    #[test]
    fn bad_logs_are_named() {
        let h = format!("{HEADER}\n");
        assert_eq!(parse(""), Err(LogError::NoHeader));
        assert_eq!(parse("t_s,ax_g\n1,2\n"), Err(LogError::MissingColumn("ay_g")));
        assert_eq!(parse(&h), Err(LogError::Empty));
        assert!(matches!(parse(&format!("{h}0,1,2\n")), Err(LogError::ShortRow { line: 2, .. })));
        assert!(matches!(parse(&format!("{h}0,a,0,1,0,0,0,\n")), Err(LogError::BadNumber { line: 2, .. })));
        assert!(matches!(parse(&format!("{h}0,NaN,0,1,0,0,0,\n")), Err(LogError::NotFinite { line: 2, .. })));
        assert!(matches!(
            parse(&format!("{h}1,0,0,1,0,0,0,\n1,0,0,1,0,0,0,\n")),
            Err(LogError::NonMonotonicTime { line: 3, .. })
        ));
    }

    #[test]
    fn format_then_parse_round_trips() {
        let r = Row { t_s: 1.25, accel_g: [0.5, -0.25, 0.75], gyro_dps: [1.5, -2.0, 3.0], servo_deg: Some(30.0), tilt_deg: None };
        let mut s = header(false);
        format_row(&mut s, &r, false);
        format_row(&mut s, &Row { t_s: 1.5, servo_deg: None, ..r }, false);
        let rows = parse(&s).unwrap();
        assert_eq!(rows[0], r);
        assert_eq!(rows[1].servo_deg, None);
        let mut s = header(true);
        format_row(&mut s, &Row { tilt_deg: Some(-25.0), ..r }, true);
        format_row(&mut s, &Row { t_s: 1.5, ..r }, true);
        let rows = parse(&s).unwrap();
        assert_eq!((rows[0].tilt_deg, rows[1].tilt_deg), (Some(-25.0), None));
    }
}
