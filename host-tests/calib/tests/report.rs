//! `gyrocal-calib LOG --report`: the page holds K and the plots, and the plots, rendered (resvg),
//! draw what the log holds: one marker per distinct pose direction, the invariant flat after
//! calibration and swinging before.

use calib::csvlog;
use calib::offline::calibrate_log;
use calib::report::{self, Plots, AFTER, BEFORE, HAND, RIG};
use calib_core::procedure::{Config, Procedure};
use common::{calib, simulated_log};
use plotters::style::RGBColor;
use rig_sim::harness::{record_log, Faults};
use rig_sim::sim::Rig;
use rig_sim::variant::Variant;

use crate::common;

/// The SVG rendered to RGBA pixels (width, pixels).
fn render(svg: &str) -> (usize, Vec<[u8; 4]>) {
    let tree = resvg::usvg::Tree::from_str(svg, &resvg::usvg::Options::default()).expect("valid SVG");
    let size = tree.size().to_int_size();
    let mut pixmap = resvg::tiny_skia::Pixmap::new(size.width(), size.height()).unwrap();
    resvg::render(&tree, resvg::tiny_skia::Transform::default(), &mut pixmap.as_mut());
    (size.width() as usize, pixmap.pixels().iter().map(|p| [p.red(), p.green(), p.blue(), p.alpha()]).collect())
}

/// The blobs of exactly `c` (4-connected), as (pixels, top row, bottom row).
fn blobs(img: &(usize, Vec<[u8; 4]>), c: RGBColor) -> Vec<(usize, usize, usize)> {
    let (w, px) = img;
    let is = |i: usize| px[i] == [c.0, c.1, c.2, 255];
    let mut seen = vec![false; px.len()];
    let mut out = vec![];
    for start in 0..px.len() {
        if seen[start] || !is(start) {
            continue;
        }
        let (mut stack, mut n, mut top, mut bottom) = (vec![start], 0, usize::MAX, 0);
        seen[start] = true;
        while let Some(i) = stack.pop() {
            n += 1;
            (top, bottom) = (top.min(i / w), bottom.max(i / w));
            let (x, y) = (i % w, i / w);
            let near = [(x > 0).then(|| i - 1), (x + 1 < *w).then(|| i + 1), (y > 0).then(|| i - w), (i + w < px.len()).then(|| i + w)];
            for j in near.into_iter().flatten() {
                if !seen[j] && is(j) {
                    seen[j] = true;
                    stack.push(j);
                }
            }
        }
        out.push((n, top, bottom));
    }
    out
}

/// Blobs the size of a marker (the legend's included).
fn markers(img: &(usize, Vec<[u8; 4]>), c: RGBColor) -> Vec<(usize, usize, usize)> {
    blobs(img, c).into_iter().filter(|b| b.0 >= 9).collect()
}

/// How many blobs `centres` make when each is a marker of [`report::MARKER`] px: those whose
/// centres lie within `touch` px merge (discs that overlap, `2 MARKER`; up to `2 MARKER + 2`
/// the anti-aliased edges of two discs may join them or not).
fn expected_blobs(centres: &[(i32, i32)], touch: u32) -> usize {
    let mut group: Vec<usize> = (0..centres.len()).collect();
    fn root(g: &mut [usize], i: usize) -> usize {
        if g[i] == i {
            i
        } else {
            let r = root(g, g[i]);
            g[i] = r;
            r
        }
    }
    let touch = touch as i32;
    for i in 0..centres.len() {
        for j in 0..i {
            let (dx, dy) = (centres[i].0 - centres[j].0, centres[i].1 - centres[j].1);
            if dx * dx + dy * dy <= touch * touch {
                let (a, b) = (root(&mut group, i), root(&mut group, j));
                group[a] = b;
            }
        }
    }
    (0..centres.len()).filter(|&i| root(&mut group, i) == i).count()
}

/// Every marker is drawn in its colour (most of its disc: a 1-px line drawn over the markers may
/// cross it) unless a marker of a series drawn later (`later`) covers it, and the plot has as
/// many marker blobs of the colour as the centres make (+ the legend's; exactly when nothing
/// covers them).
fn drawn_as_placed(img: &(usize, Vec<[u8; 4]>), c: RGBColor, centres: &[(i32, i32)], later: &[(i32, i32)], what: &str) {
    let (w, px) = img;
    let reach = (2 * report::MARKER + 1) as i32;
    let covered = |p: &(i32, i32)| later.iter().any(|q| (p.0 - q.0).pow(2) + (p.1 - q.1).pow(2) <= reach * reach);
    let open: Vec<(i32, i32)> = centres.iter().copied().filter(|p| !covered(p)).collect();
    let r = report::MARKER as i32 - 1;
    for &(x, y) in &open {
        let disc: Vec<[u8; 4]> = (-r..=r)
            .flat_map(|dy| (-r..=r).filter(move |dx| dx * dx + dy * dy <= r * r).map(move |dx| (x + dx, y + dy)))
            .map(|(x, y)| px[y as usize * w + x as usize])
            .collect();
        let own = disc.iter().filter(|p| **p == [c.0, c.1, c.2, 255]).count();
        assert!(2 * own > disc.len(), "{what}: no marker at ({x}, {y}): {own} of {} pixels {c:?}", disc.len());
    }
    let found = markers(img, c).len();
    let (joined, apart) = (2 * report::MARKER + 2, 2 * report::MARKER);
    let (least, most) = (expected_blobs(&open, joined) + 1, expected_blobs(centres, apart) + 1 + (centres.len() - open.len()));
    println!(
        "{what}: {} markers ({} covered by later ones), {found} blobs drawn, {least}..={most} expected",
        centres.len(),
        centres.len() - open.len()
    );
    assert!(open.len() * 2 > centres.len() && (least..=most).contains(&found), "{what}");
}

#[test]
fn the_report_draws_one_marker_per_pose_and_the_invariant_flattened_by_the_calibration() {
    // The procedure's 12 hand-held poses, no more (the markers of further ones fall on the first
    // ones', and the bias plot's longer time axis puts a rest under its legend).
    let mut rig = Rig::new(Variant::Hobby.config(9, 0), 3);
    let mut p = Procedure::new(Config { hand_k_sigma: 1.0, ..Config::default() }, None);
    let text = record_log(&mut rig, &mut p, Faults::default(), "# test log\n").0;
    let log = csvlog::parse(&text).unwrap();
    let c = calibrate_log(&log, &Default::default(), None).unwrap();
    assert_eq!(c.replayed, Some("default, 12 hand-held poses"));
    let Plots { sphere, invariant, residuals, bias, mag, mag_dip, mag_heading } = report::plots(&log.rows, &c).unwrap();
    // A marker per pose, where the data puts it.
    let rig = c.phases.segments.iter().filter(|s| s.is_rig_pose()).count();
    let hand = c.phases.segments.len() - rig;
    assert!(rig >= 10 && hand >= 10 && sphere.markers[0].len() == rig && sphere.markers[1].len() == hand);
    let img = render(&sphere.svg);
    drawn_as_placed(&img, RIG, &sphere.markers[0], &sphere.markers[1], "rig poses");
    drawn_as_placed(&img, HAND, &sphere.markers[1], &[], "hand-held poses");
    // The invariant: the calibrated one flat, the raw one swinging with the shaft angle.
    let invariant = invariant.expect("rig moves");
    let img = render(&invariant.svg);
    drawn_as_placed(&img, BEFORE, &invariant.markers[0], &invariant.markers[1], "invariant before");
    drawn_as_placed(&img, AFTER, &invariant.markers[1], &[], "invariant after");
    let spread = |m: &[(i32, i32)]| m.iter().map(|p| p.1).max().unwrap() - m.iter().map(|p| p.1).min().unwrap();
    let (before, after) = (spread(&invariant.markers[0]), spread(&invariant.markers[1]));
    println!("invariant: before over {before} px, after over {after} px");
    assert!(before > 40 && after < before / 4, "before {before} px, after {after} px");
    // Residuals and the bias are drawn too.
    let residuals = residuals.expect("rig moves");
    drawn_as_placed(&render(&residuals.svg), report::RESIDUAL, &residuals.markers[0], &[], "move residuals");
    let img = render(&bias.svg);
    for (a, colour) in report::AXES.iter().enumerate() {
        let rests = c.phases.segments.iter().filter(|s| c.phases.measures_bias(s)).count();
        assert!(rests >= rig && bias.markers[a].len() == rests);
        let later: Vec<(i32, i32)> = bias.markers[a + 1..].concat();
        drawn_as_placed(&img, *colour, &bias.markers[a], &later, "bias");
    }
    // The magnetometer: every hand-held reading raw and calibrated; its invariant (the dip at
    // each pose) flatter with the die's alignment than through the ellipsoid alone.
    let (mag, dip) = (mag.expect("the simulated log has a magnetometer"), mag_dip.expect("and it calibrates"));
    let outcome = c.mag.as_ref().unwrap();
    let readings = outcome.readings(&log.rows).count();
    assert!(readings == outcome.used && readings > 500 && mag.markers[0].len() == readings && mag.markers[1].len() == readings);
    // Calibrated, the readings lie on the sphere: their x–y projections inside its circle (drawn
    // as a line of the same colour), the raw ones off centre by the hard iron.
    let cal = outcome.cal.as_ref().unwrap();
    let inside = outcome.readings(&log.rows).all(|m| {
        let v = cal.apply(m);
        (v[0] * v[0] + v[1] * v[1]).sqrt() <= cal.field_ut + 2.0
    });
    assert!(inside && mag.svg.contains("polyline"), "the sphere's circle and the readings inside it");
    let img = render(&dip.svg);
    drawn_as_placed(&img, BEFORE, &dip.markers[0], &dip.markers[1], "dip, ellipsoid alone");
    drawn_as_placed(&img, AFTER, &dip.markers[1], &[], "dip, aligned");
    let (before, after) = (spread(&dip.markers[0]), spread(&dip.markers[1]));
    println!("dip: ellipsoid alone over {before} px, aligned over {after} px");
    // One marker per pose of the stretch (a replayed log's calibration is the procedure's, which
    // leaves out the step's first pose).
    assert!(dip.markers[0].len() >= cal.poses as usize && after * 2 < before, "before {before} px, after {after} px");
    // The heading error per move (the gyro's rotation as the reference): smaller with the die's
    // alignment than through the ellipsoid alone.
    let headings = mag_heading.expect("a heading plot");
    let img = render(&headings.svg);
    drawn_as_placed(&img, BEFORE, &headings.markers[0], &headings.markers[1], "heading, ellipsoid alone");
    drawn_as_placed(&img, AFTER, &headings.markers[1], &[], "heading, aligned");
    let (before, after) = (spread(&headings.markers[0]), spread(&headings.markers[1]));
    println!("heading error per move: ellipsoid alone over {before} px, aligned over {after} px");
    assert!(headings.markers[0].len() + 1 == dip.markers[0].len() && after * 2 < before, "before {before} px, after {after} px");
}

#[test]
fn calib_writes_a_self_contained_page_with_k_and_its_plots() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("report");
    std::fs::create_dir_all(&dir).unwrap();
    let (log, page) = (dir.join("sim.csv"), dir.join("report.html"));
    std::fs::write(&log, simulated_log(Variant::Hobby.config(9, 1)).0).unwrap();
    let (code, out, err) = calib(&[log.to_str().unwrap(), "--report", page.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("\"gyro\""), "the usual JSON stays on stdout");
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.starts_with("<!DOCTYPE html>") && html.contains("± ") && html.contains("What to do"));
    assert_eq!(html.matches("<svg").count(), 7, "sphere, invariant, residuals, bias, the magnetometer's field, dip and heading");
    assert!(html.contains("<h2>Magnetometer</h2>") && html.contains("dip of"));
    assert!(!html.contains("src=\"http") && !html.contains("<script"), "self-contained");
    let (code, _, err) = calib(&[log.to_str().unwrap(), "--report", dir.join("no/such/dir/r.html").to_str().unwrap()]);
    assert_eq!(code, 2, "{err}");
}
