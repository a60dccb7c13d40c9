//! `gyrocal-calib LOG --report report.html`: one self-contained HTML page to look at. Its plots
//! (SVG, drawn with `plotters`) show where the poses are on the sphere, the paper's invariant per
//! rig pose before and after calibration, each rig move's axis residual, and the residual gyro
//! bias of every rest over time; beside them `K` with its 1σ, the quality figures and what to do
//! about whatever is weak.
//!
//! The invariant: on a rig turning about one axis `u`, the gravity direction `a_i` of every pose
//! keeps one angle to `u`, so `a_i · ū` (ū the mean of the moves' directions `K γ / |K γ|`, γ
//! a move's integrated gyro) is the same at every pose with the right `K`; with a wrong one it
//! swings with the shaft angle (the paper's figure of `A · (K g)`). On a pan/tilt rig, the poses
//! and moves of the most used tilt setting (one pan axis).

use crate::allan::{Allan, Noise};
use crate::csvlog::Row;
use crate::offline::{Calibration, Segment};
use calib_core::formats::record::Record;
use calib_core::math::vec3::{mat_to_real, sub, to_real};
use nalgebra::{Matrix3, Vector3};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;

/// Plot size (px).
const SIZE: (u32, u32) = (640, 320);
/// Marker colours, distinct so that a rendered plot can be checked by colour.
pub const RIG: RGBColor = RGBColor(214, 39, 40);
/// See [`RIG`].
pub const HAND: RGBColor = RGBColor(31, 119, 180);
/// See [`RIG`].
pub const BEFORE: RGBColor = RGBColor(255, 127, 14);
/// See [`RIG`].
pub const AFTER: RGBColor = RGBColor(44, 160, 44);
/// See [`RIG`].
pub const RESIDUAL: RGBColor = RGBColor(148, 103, 189);
/// The bias plot's x, y, z.
pub const AXES: [RGBColor; 3] = [RGBColor(230, 25, 75), RGBColor(60, 180, 75), RGBColor(0, 130, 200)];
/// Marker radius (px).
pub const MARKER: u32 = 4;

/// One plot: its SVG document and, per series, the pixel centre of every marker drawn.
#[derive(Debug, Clone)]
pub struct Plot {
    /// The SVG document.
    pub svg: String,
    /// Per series, in order: the markers' centres (px).
    pub markers: Vec<Vec<(i32, i32)>>,
}

/// The report's plots.
#[derive(Debug, Clone)]
pub struct Plots {
    /// Pose directions (calibrated gravity) on the sphere: longitude and latitude (°); rig
    /// poses, then hand-held ones.
    pub sphere: Plot,
    /// The invariant per rig pose, before (`K = I`) and after calibration.
    pub invariant: Option<Plot>,
    /// Each rig move's axis residual (°): the angle of its `K γ` from the mean axis.
    pub residuals: Option<Plot>,
    /// Each rest's gyro bias minus the calibration's (°/s; x, y, z) over time (s): the rests as
    /// still as the rig's thresholds.
    pub bias: Plot,
    /// The magnetometer's hand-held readings, raw and calibrated, in the x–y plane (µT), with
    /// the calibrated field's circle: the ellipsoid and its sphere.
    pub mag: Option<Plot>,
    /// The magnetometer's invariant per hand-held pose: the dip (°) through the ellipsoid alone
    /// and through the calibration with the die's alignment.
    pub mag_dip: Option<Plot>,
    /// The heading error per hand-held move (°), before (the ellipsoid alone) and after: the
    /// tilt-compensated heading at the move's end against the one its start predicts through the
    /// calibrated gyro's rotation (the log has no true heading; the gyro, calibrated to a few
    /// 1e-4, is the reference).
    pub mag_heading: Option<Plot>,
}

fn unit(v: [f32; 3]) -> Vector3<f64> {
    Vector3::new(v[0] as f64, v[1] as f64, v[2] as f64).normalize()
}

/// The still segments' calibrated gravity directions.
fn direction(c: &Calibration, s: &Segment) -> Vector3<f64> {
    unit(c.accel.apply(s.accel.mean().map(|v| v as f32)))
}

/// The most used tilt setting of the rig poses (0.5° steps; 0 without a tilt column).
fn main_tilt(c: &Calibration) -> i32 {
    let tilt = |s: &Segment| (s.tilt_deg.unwrap_or(0.0) * 2.0).round() as i32;
    let rig: Vec<i32> = c.phases.segments.iter().filter(|s| s.is_rig_pose()).map(tilt).collect();
    rig.iter().copied().max_by_key(|t| rig.iter().filter(|u| *u == t).count()).unwrap_or(0)
}

/// A rig pose at the tilt setting `tilt`.
fn at_tilt(s: &Segment, tilt: i32) -> bool {
    s.is_rig_pose() && (s.tilt_deg.unwrap_or(0.0) * 2.0).round() as i32 == tilt
}

/// The moves between consecutive rig poses of the tilt setting `tilt`: (from, to,
/// bias-corrected integrated gyro in °).
fn moves<'a>(rows: &[Row], c: &'a Calibration, tilt: i32) -> Vec<(&'a Segment, &'a Segment, Vector3<f64>)> {
    let seg = &c.phases.segments;
    seg.windows(2)
        .filter(|w| at_tilt(&w[0], tilt) && at_tilt(&w[1], tilt) && w[0].servo_deg != w[1].servo_deg)
        .map(|w| {
            let mut g = Vector3::zeros();
            for p in rows[w[0].last..=w[1].last].windows(2) {
                let d = sub(p[1].gyro_dps, c.bias.bias_dps);
                g += Vector3::new(d[0] as f64, d[1] as f64, d[2] as f64) * (p[1].t.s() - p[0].t.s());
            }
            (&w[0], &w[1], g)
        })
        .collect()
}

fn chart_err<E: std::fmt::Debug>(e: E) -> String {
    format!("plot: {e:?}")
}

/// One series of a scatter plot: its colour, label and points.
type Series<'a> = (RGBColor, &'a str, Vec<(f64, f64)>);

/// A plot of `series` as markers and `lines` (colour, points) with axis names, on any
/// coordinates (linear or logarithmic).
fn plot<X, Y>(title: &str, x: (&str, X), y: (&str, Y), series: &[Series], lines: &[(RGBColor, Vec<(f64, f64)>)]) -> Result<Plot, String>
where
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let mut svg = String::new();
    let mut markers = vec![];
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(chart_err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 16))
            .margin(10)
            .x_label_area_size(32)
            .y_label_area_size(64)
            .build_cartesian_2d(x.1, y.1)
            .map_err(chart_err)?;
        chart.configure_mesh().x_desc(x.0).y_desc(y.0).light_line_style(WHITE).draw().map_err(chart_err)?;
        for (colour, label, pts) in series {
            markers.push(pts.iter().map(|p| chart.backend_coord(p)).collect());
            let c = *colour;
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, MARKER, c.filled())))
                .map_err(chart_err)?
                .label(*label)
                .legend(move |(x, y)| Circle::new((x, y), MARKER, c.filled()));
        }
        for (colour, pts) in lines {
            chart.draw_series(LineSeries::new(pts.iter().copied(), colour.stroke_width(1))).map_err(chart_err)?;
        }
        chart.configure_series_labels().background_style(TRANSPARENT).border_style(TRANSPARENT).draw().map_err(chart_err)?;
        root.present().map_err(chart_err)?;
    }
    Ok(Plot { svg, markers })
}

/// A scatter plot on linear axes.
fn scatter(title: &str, x: (&str, std::ops::Range<f64>), y: (&str, std::ops::Range<f64>), series: &[Series]) -> Result<Plot, String> {
    plot(title, x, y, series, &[])
}

/// `lo..hi` widened by 10 % (and never empty).
fn span(values: impl Iterator<Item = f64> + Clone) -> std::ops::Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if !lo.is_finite() {
        return 0.0..1.0;
    }
    let pad = ((hi - lo) * 0.1).max(1e-9 * hi.abs().max(1.0));
    lo - pad..hi + pad
}

/// The record's `K` (the full one if there is one), as a matrix.
fn k_of(rec: &Record) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| rec.gyro_k[i][j] as f64)
}

/// The plots of a calibrated log.
pub fn plots(rows: &[Row], c: &Calibration) -> Result<Plots, String> {
    let seg = &c.phases.segments;
    let lonlat = |v: Vector3<f64>| (v.y.atan2(v.x).to_degrees(), v.z.clamp(-1.0, 1.0).asin().to_degrees());
    let rig: Vec<(f64, f64)> = seg.iter().filter(|s| s.is_rig_pose()).map(|s| lonlat(direction(c, s))).collect();
    let hand: Vec<(f64, f64)> = seg.iter().filter(|s| !s.is_rig_pose()).map(|s| lonlat(direction(c, s))).collect();
    let sphere = scatter(
        "Poses: the gravity direction of each (sensor frame)",
        ("longitude atan2(y, x) (°)", -180.0..180.0),
        ("latitude asin(z) (°)", -90.0..90.0),
        &[(RIG, "rig poses", rig), (HAND, "hand-held poses", hand)],
    )?;
    let k = c.record().map(|r| k_of(&r)).unwrap_or_else(Matrix3::identity);
    let tilt = main_tilt(c);
    let mv = moves(rows, c, tilt);
    let (mut invariant, mut residuals) = (None, None);
    if !mv.is_empty() {
        // The moves' mean axis, each signed along the first.
        let axis = |k: &Matrix3<f64>| {
            let first = (k * mv[0].2).normalize();
            mv.iter().map(|m| (k * m.2).normalize()).map(|d| if d.dot(&first) < 0.0 { -d } else { d }).sum::<Vector3<f64>>().normalize()
        };
        let (u_raw, u_cal) = (axis(&Matrix3::identity()), axis(&k));
        let poses: Vec<&Segment> = seg.iter().filter(|s| at_tilt(s, tilt)).collect();
        let at = |u: Vector3<f64>| poses.iter().enumerate().map(|(i, s)| (i as f64, direction(c, s).dot(&u))).collect::<Vec<_>>();
        let (before, after) = (at(u_raw), at(u_cal));
        let y = span(before.iter().chain(&after).map(|p| p.1));
        invariant = Some(scatter(
            "The invariant per rig pose: gravity · rig axis",
            ("rig pose", -0.5..poses.len() as f64 - 0.5),
            ("a · (K γ̄) / |K γ̄|", y),
            &[(BEFORE, "before (K = I)", before), (AFTER, "after (K)", after)],
        )?);
        let res: Vec<(f64, f64)> =
            mv.iter().enumerate().map(|(i, m)| (i as f64, (k * m.2).normalize().dot(&u_cal).abs().min(1.0).acos().to_degrees())).collect();
        let y = span(res.iter().map(|p| p.1).chain([0.0]));
        residuals = Some(scatter(
            "Each rig move: its axis from the mean axis (°)",
            ("move", -0.5..mv.len() as f64 - 0.5),
            ("angle (°)", y),
            &[(RESIDUAL, "after (K)", res)],
        )?);
    }
    let t0 = rows.first().map_or(0.0, |r| r.t.s());
    let series: Vec<Series> = (0..3)
        .map(|a| {
            // The rests that measure the bias: a hand's shaky pose does not.
            let pts = seg
                .iter()
                .filter(|s| c.phases.measures_bias(s))
                .map(|s| ((rows[s.first].t.s() + rows[s.last].t.s()) / 2.0 - t0, s.gyro.mean()[a] - c.bias.bias_dps[a] as f64))
                .collect();
            (AXES[a], ["x", "y", "z"][a], pts)
        })
        .collect();
    let x = span(series.iter().flat_map(|s| s.2.iter().map(|p| p.0)));
    let y = span(series.iter().flat_map(|s| s.2.iter().map(|p| p.1)));
    // Headroom above the markers for the legend's three rows (it covered a rest's marker otherwise).
    let y = y.start..y.end + 0.3 * (y.end - y.start);
    let bias = scatter("Each rest's gyro bias minus the calibration's, against time", ("time (s)", x), ("°/s", y), &series)?;
    let (mag, mag_dip, mag_heading) = mag_plots(rows, c, &k)?;
    Ok(Plots { sphere, invariant, residuals, bias, mag, mag_dip, mag_heading })
}

/// [`Plots::mag`], [`Plots::mag_dip`] and [`Plots::mag_heading`], when the log's magnetometer
/// was calibrated; `k` the gyro's `K`.
type MagPlots = (Option<Plot>, Option<Plot>, Option<Plot>);
fn mag_plots(rows: &[Row], c: &Calibration, k: &Matrix3<f64>) -> Result<MagPlots, String> {
    let Some((outcome, cal, (ea, eo))) = c.mag.as_ref().and_then(|m| Some((m, m.cal.as_ref().ok()?, m.ellipsoid?))) else {
        return Ok((None, None, None));
    };
    let (a, o, ea, eo) = (mat_to_real(&cal.a), to_real(cal.offset_ut), mat_to_real(&ea), to_real(eo));
    let readings: Vec<Vector3<f64>> = outcome.readings(rows).map(to_real).collect();
    let raw: Vec<(f64, f64)> = readings.iter().map(|r| (r.x, r.y)).collect();
    let calibrated: Vec<(f64, f64)> = readings.iter().map(|r| a * (r - o)).map(|r| (r.x, r.y)).collect();
    let b = cal.field_ut as f64;
    let circle: Vec<(f64, f64)> = (0..=72).map(|i| (i as f64 * 5.0).to_radians()).map(|t| (b * t.cos(), b * t.sin())).collect();
    let x = span(raw.iter().chain(&calibrated).map(|p| p.0).chain([-b, b]));
    let y = span(raw.iter().chain(&calibrated).map(|p| p.1).chain([-b, b]));
    let field = plot(
        "Magnetometer, the readings of the fit: raw on their ellipsoid, calibrated on the sphere",
        ("x (µT)", x),
        ("y (µT)", y),
        &[(BEFORE, "raw", raw), (AFTER, "calibrated", calibrated)],
        &[(AFTER, circle)],
    )?;
    // The dip at each pose of the fit: the same everywhere when the field is aligned with gravity.
    let (first, last) = outcome.stretch.unwrap_or((1, 0));
    let dip = |a: &Matrix3<f64>, o: &Vector3<f64>| {
        c.phases
            .segments
            .iter()
            .filter(|s| !s.is_rig_pose() && first <= s.first && s.last <= last)
            .filter_map(|s| {
                let readings: Vec<Vector3<f64>> = rows[s.first..=s.last].iter().filter_map(|r| r.mag_ut).map(to_real).collect();
                let mean = readings.iter().sum::<Vector3<f64>>() / readings.len().max(1) as f64;
                let f = direction(c, s);
                let mm = a * (mean - o);
                (!readings.is_empty()).then(|| (-f.dot(&mm) / mm.norm()).clamp(-1.0, 1.0).asin().to_degrees())
            })
            .enumerate()
            .map(|(i, d)| (i as f64, d))
            .collect::<Vec<_>>()
    };
    let (before, after) = (dip(&ea, &eo), dip(&a, &o));
    let y = span(before.iter().chain(&after).map(|p| p.1));
    let dips = scatter(
        "The magnetometer's invariant per hand-held pose: the dip of the field",
        ("pose of the fit", -0.5..before.len().max(1) as f64 - 0.5),
        ("dip (°)", y),
        &[(BEFORE, "ellipsoid alone", before), (AFTER, "with the die's alignment", after)],
    )?;
    // Per move between consecutive poses of the fit: the gyro's rotation (K (g − b) integrated
    // as a rotation), the field at the start carried to the end, both headings at the end.
    let poses: Vec<&Segment> = c.phases.segments.iter().filter(|s| !s.is_rig_pose() && first <= s.first && s.last <= last).collect();
    let mean_field = |s: &Segment| {
        let r: Vec<Vector3<f64>> = rows[s.first..=s.last].iter().filter_map(|r| r.mag_ut).map(to_real).collect();
        (!r.is_empty()).then(|| r.iter().sum::<Vector3<f64>>() / r.len() as f64)
    };
    let bias = to_real(c.bias.bias_dps);
    // Per move, once: both poses' mean fields, the gyro's rotation from the start pose's middle
    // to the end's (body at the end to body at the start), the direction at the end.
    let moves: Vec<_> = poses
        .windows(2)
        .filter_map(|w| {
            let (mi, mj) = (mean_field(w[0])?, mean_field(w[1])?);
            let (from, to) = ((w[0].first + w[0].last) / 2, (w[1].first + w[1].last) / 2);
            let mut q = nalgebra::UnitQuaternion::identity();
            for p in rows[from..=to].windows(2) {
                let w_rad = (k * (to_real(p[1].gyro_dps) - bias)).map(f64::to_radians);
                q *= nalgebra::UnitQuaternion::from_scaled_axis(w_rad * (p[1].t.s() - p[0].t.s()));
            }
            Some((mi, mj, q, direction(c, w[1])))
        })
        .collect();
    let heading_error = |a: &Matrix3<f64>, o: &Vector3<f64>| {
        moves
            .iter()
            .filter_map(|(mi, mj, q, fj)| {
                let predicted = q.inverse() * (a * (mi - o));
                let h = |m: Vector3<f64>| calib_core::estimators::mag::heading_deg(*fj, m);
                Some((h(a * (mj - o))? - h(predicted)? + 540.0) % 360.0 - 180.0)
            })
            .enumerate()
            .map(|(i, e)| (i as f64, e))
            .collect::<Vec<_>>()
    };
    let (before, after) = (heading_error(&ea, &eo), heading_error(&a, &o));
    let y = span(before.iter().chain(&after).map(|p| p.1).chain([0.0]));
    // Headroom above the markers for the legend.
    let y = y.start..y.end + 0.5 * (y.end - y.start);
    let headings = scatter(
        "Heading error per hand-held move: the end's heading against the start's carried by the gyro",
        ("move of the fit", -0.5..before.len().max(1) as f64 - 0.5),
        ("heading error (°)", y),
        &[(BEFORE, "ellipsoid alone", before), (AFTER, "with the die's alignment", after)],
    )?;
    Ok((Some(field), Some(dips), Some(headings)))
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// What to do about whatever is weak in `c`.
fn advice(c: &Calibration) -> Vec<String> {
    let mut out: Vec<String> = c.missing().iter().map(|m| format!("Missing: {m}.")).collect();
    if let Some(r) = c.record() {
        let worst = r.sigma_k.iter().flatten().fold(0.0f32, |a, b| a.max(*b));
        if worst > 1e-3 {
            out.push(format!(
                "An element of K is uncertain to {worst:.1e} (1σ): more rig poses or hand-held poses spread over the sphere, held still longer."
            ));
        }
        if r.accel_rms_g > 0.005 {
            out.push(format!(
                "The accelerometer fit leaves {:.4} g RMS: hold each hand-held pose still, and spread them wider.",
                r.accel_rms_g
            ));
        }
    }
    if c.handheld_poses > 0 && c.handheld_poses < 9 {
        out.push(format!("{} hand-held poses: 9 or more allow the 9-parameter accelerometer model.", c.handheld_poses));
    }
    if out.is_empty() {
        out.push("Nothing weak: every figure is within what the firmware accepts.".into());
    }
    out
}

/// The report page of log `name`.
pub fn html(name: &str, rows: &[Row], c: &Calibration) -> Result<String, String> {
    let p = plots(rows, c)?;
    let mut h = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>gyrocal report: {n}</title>\n<style>body{{font-family:sans-serif;max-width:700px;margin:auto}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}</style></head><body>\n<h1>gyrocal report</h1>\n<p>Log <code>{n}</code>: {rows} samples at {rate:.2} Hz, {poses} rig poses, {hand} hand-held poses{replayed}.</p>\n",
        n = escape(name),
        rows = rows.len(),
        rate = c.time_base.rate_hz,
        poses = c.rig_poses,
        hand = c.handheld_poses,
        replayed = c.replayed.map_or(String::new(), |cfg| format!("; replayed through the firmware's procedure ({cfg})")),
    );
    match c.record() {
        Some(r) => {
            h += &format!("<h2>Gyro K ({:?}) with its 1σ</h2>\n<table>", r.method);
            for i in 0..3 {
                h += "<tr>";
                for j in 0..3 {
                    h += &format!("<td>{:.6} ± {:.1e}</td>", r.gyro_k[i][j], r.sigma_k[i][j]);
                }
                h += "</tr>";
            }
            let b = r.gyro_bias_dps;
            h += &format!(
                "</table>\n<p>Bias {:.4}, {:.4}, {:.4} °/s; made at {} Hz, ±{} °/s, ±{} g; accelerometer {:?}, residual {:.4} g.</p>\n",
                b[0], b[1], b[2], r.setup.odr_hz, r.setup.gyro_range_dps, r.setup.accel_range_g, r.accel_model, r.accel_rms_g
            );
        }
        None => h += "<h2>No gyro calibration</h2>\n",
    }
    h += "<h2>What to do</h2>\n<ul>";
    for a in advice(c) {
        h += &format!("<li>{}</li>", escape(&a));
    }
    h += "</ul>\n<h2>Plots</h2>\n";
    if let Some(m) = c.mag.as_ref().and_then(|m| m.cal.as_ref().ok()) {
        h += &format!(
            "<h2>Magnetometer</h2>\n<p>Field {:.2} ± {:.2} µT at a dip of {:.2} ± {:.2}° ({}); the die turned {:.2} ± {:.2}° onto the accelerometer; |m| − B {:.2} µT RMS; {:.0} % of the sphere's directions reached; {} points, {} poses.</p>\n",
            m.field_ut, m.sigma_field_ut, m.dip_deg, m.sigma_dip_deg, calib_core::formats::text::DIP_SIGN, m.alignment_deg, m.sigma_alignment_deg, m.residual_ut, m.coverage * 100.0, m.samples, m.poses
        );
    }
    for plot in [
        Some(&p.sphere),
        p.invariant.as_ref(),
        p.residuals.as_ref(),
        Some(&p.bias),
        p.mag.as_ref(),
        p.mag_dip.as_ref(),
        p.mag_heading.as_ref(),
    ]
    .into_iter()
    .flatten()
    {
        h += &format!("<figure>{}</figure>\n", plot.svg);
    }
    if p.invariant.is_none() {
        h += "<p>No rig moves in the log: no invariant or move residual to show.</p>\n";
    }
    h += "</body></html>\n";
    Ok(h)
}

/// An Allan-deviation plot (log–log) of one sensor: each axis' curve as markers and its fitted
/// noise model (white + random walk) as a line.
pub fn adev_plot(title: &str, unit: &str, n: &Noise) -> Result<Plot, String> {
    let taus = || n.tau_s.iter().copied();
    let values = || n.adev.iter().flatten().copied().filter(|v| *v > 0.0);
    let (t0, t1) = (taus().fold(f64::INFINITY, f64::min), taus().fold(0.0, f64::max));
    let (v0, v1) = (values().fold(f64::INFINITY, f64::min), values().fold(0.0, f64::max));
    if !(t0 > 0.0 && t1 > t0 && v0 > 0.0 && v1 >= v0) {
        return Err("no Allan deviation to plot".into());
    }
    let names = ["x", "y", "z"];
    let series: Vec<Series> =
        (0..3).map(|a| (AXES[a], names[a], n.tau_s.iter().zip(&n.adev).map(|(t, s)| (*t, s[a])).filter(|p| p.1 > 0.0).collect())).collect();
    let lines: Vec<(RGBColor, Vec<(f64, f64)>)> = (0..3)
        .map(|a| {
            let (wn, rw) = (n.noise_density[a].value, n.random_walk[a].value);
            (AXES[a], n.tau_s.iter().map(|&t| (t, (wn * wn / t + rw * rw * t / 3.0).sqrt())).collect())
        })
        .collect();
    let y = format!("σ(τ) ({unit})");
    plot(title, ("τ (s)", (t0 / 1.5..t1 * 1.5).log_scale()), (y.as_str(), (v0 / 2.0..v1 * 2.0).log_scale()), &series, &lines)
}

/// The page of `calib allan`'s figures for log `name`: a table per sensor and its plot.
pub fn allan_html(name: &str, a: &Allan) -> Result<String, String> {
    let mut h = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>gyrocal noise: {n}</title>\n<style>body{{font-family:sans-serif;max-width:700px;margin:auto}}table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}</style></head><body>\n<h1>gyrocal noise figures</h1>\n<p>Log <code>{n}</code>: {d:.0} s still at {r:.2} Hz. N: white-noise density (two-sided, Kalibr's), K: random walk, min σ / 0.664: the classic bias instability; 1σ after ±.</p>\n",
        n = escape(name),
        d = a.duration_s,
        r = a.sample_rate_hz
    );
    for (title, unit, n) in [("Gyro", "°/s", &a.gyro), ("Accelerometer", "g", &a.accel)] {
        h += &format!("<h2>{title}</h2>\n<table><tr><th>axis</th><th>N ({unit}/√Hz)</th><th>K ({unit}/s/√Hz)</th><th>min σ / 0.664 ({unit})</th></tr>");
        for k in 0..3 {
            let (wn, rw) = (n.noise_density[k], n.random_walk[k]);
            let walk =
                if rw.value > 0.0 { format!("{:.2e} ± {:.1e}", rw.value, rw.sigma) } else { format!("none seen (≤ {:.1e})", rw.sigma) };
            h += &format!(
                "<tr><td>{}</td><td>{:.3e} ± {:.1e}</td><td>{walk}</td><td>{:.2e}</td></tr>",
                ["x", "y", "z"][k],
                wn.value,
                wn.sigma,
                n.adev_floor[k].0
            );
        }
        h += &format!("</table>\n<figure>{}</figure>\n", adev_plot(&format!("{title}: Allan deviation"), unit, n)?.svg);
    }
    h += "</body></html>\n";
    Ok(h)
}
