//! Report plots: error against gather time and error against storage, one curve per
//! compressor kind through its sweep points, every point labelled with its setting, and the
//! image error of every compressor and method against its storage. Each plot is drawn once per
//! backend by one routine and written twice, as PNG and as SVG beside it. Text is drawn with
//! the bundled DejaVu Sans (assets/fonts), so plots look the same on machines without system
//! fonts.

use crate::metrics::CompressorRecord;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Once;

static FONT: Once = Once::new();

pub(crate) fn register_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../../../assets/fonts/DejaVuSans.ttf");
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .unwrap_or_else(|_| panic!("the bundled DejaVuSans.ttf is a valid font"));
    });
}

/// One named curve of (x, y) points, each with its label (the setting, short: a record's
/// name without its kind, `t12` for `haar-t12`; an empty label draws none).
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
    pub labels: Vec<String>,
}

/// A setting's label on a plot whose curves are its kind: its name without the `kind-`
/// prefix (`t12` for `haar-t12`), or the whole name when that is all there is.
pub fn short_label(name: &str, kind: &str) -> String {
    match name.strip_prefix(kind).and_then(|r| r.strip_prefix('-')) {
        Some(rest) if !rest.is_empty() => rest.to_string(),
        _ => name.to_string(),
    }
}

/// Group records by compressor kind ([`crate::compare::series_of`]: a Python compressor is its
/// own series) into series of `(x(record), y(record))`, each curve
/// running through its settings in order of storage (the sweep's order), so an x that need
/// not grow with storage, like gather time, does not zigzag the curve.
pub fn series_by_kind(
    records: &[CompressorRecord],
    x: impl Fn(&CompressorRecord) -> f64,
    y: impl Fn(&CompressorRecord) -> f64,
) -> Vec<Series> {
    series_by(records.iter().map(|r| (crate::compare::series_of(r), r)), x, y)
}

/// Group `(series name, record)` pairs into series of `(x(record), y(record))`, each in order
/// of the records' storage.
pub fn series_by<'a>(
    records: impl IntoIterator<Item = (String, &'a CompressorRecord)>,
    x: impl Fn(&CompressorRecord) -> f64,
    y: impl Fn(&CompressorRecord) -> f64,
) -> Vec<Series> {
    let mut by_name: BTreeMap<String, Vec<&CompressorRecord>> = BTreeMap::new();
    for (name, r) in records {
        by_name.entry(name).or_default().push(r);
    }
    by_name
        .into_iter()
        .map(|(name, mut rs)| {
            rs.sort_by_key(|r| r.bytes);
            let points = rs.iter().map(|r| (x(r), y(r))).collect();
            Series { name, points, labels: rs.iter().map(|r| short_label(&r.name, &r.kind)).collect() }
        })
        .collect()
}

/// Smallest error drawn on a log axis (lossless compressors sit at f32 rounding, ~1e-7).
pub const ERROR_FLOOR: f64 = 1e-9;

/// The values a log axis draws: a record's figure outside it (a gather of 5e-324 ms or 1e308
/// ms in a tampered `metrics.json`) is left off the plot rather than stretching the axis over
/// hundreds of decades.
pub const PLOT_RANGE: std::ops::RangeInclusive<f64> = 1e-30..=1e30;

/// A level drawn across a plot (dashed) with, on it, where named series cross it: the
/// equal-quality storage read off the error-against-storage curves.
pub struct Guide {
    pub y: f64,
    pub label: String,
    /// `(series name, x)`: a cross in that series' colour at `(x, y)`.
    pub marks: Vec<(String, f64)>,
}

/// A tick label a reader can take in at a glance: `2`, `40`, `0.5`, `3e-4`, `2e5`.
pub fn tick_label(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-2..1e4).contains(&a) {
        format!("{v:.0e}")
    } else if (v - v.round()).abs() < 1e-6 * a.max(1.0) {
        format!("{v:.0}")
    } else {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// The pixels between two neighbouring tick labels of an axis, at least.
pub const TICK_LABEL_GAP: f64 = 8.0;

/// `d x 10^e` as the nearest f64 (`2e-3` is 0.002, not `2.0 * 10f64.powi(-3)`).
fn decimal(d: u32, e: i32) -> f64 {
    format!("{d}e{e}").parse().expect("a decimal literal")
}

/// Tick values for a log axis over `[lo, hi]` drawn `pixels` long, whose labels
/// ([`tick_label`]) take `extent(label)` pixels along the axis (their width on an x axis, their
/// height on a y axis). Every tick is `d x 10^k` with `d` 1, 2 or 5: 1, 2 and 5 per decade when
/// the range spans at most three decades and their labels fit (so a range of 2 to 6 ms is not
/// left with one tick), else the decades, else every second, third, ... decade: the densest
/// of these whose neighbouring labels keep [`TICK_LABEL_GAP`] pixels apart.
pub fn log_ticks(lo: f64, hi: f64, pixels: f64, extent: impl Fn(&str) -> f64) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && lo.is_finite() && hi.is_finite()) {
        return vec![];
    }
    let (e0, e1) = (lo.log10().floor() as i32 - 1, hi.log10().ceil() as i32 + 1);
    let ticks = |steps: &[u32], stride: i32| -> Vec<f64> {
        let mut out = vec![];
        for e in (e0..=e1).filter(|e| e.rem_euclid(stride) == 0) {
            for &d in steps {
                let v = decimal(d, e);
                if v >= lo && v <= hi {
                    out.push(v);
                }
            }
        }
        out
    };
    let span = (hi / lo).ln();
    let fits = |t: &[f64]| {
        t.windows(2).all(|w| {
            let apart = pixels * (w[1] / w[0]).ln() / span;
            apart >= (extent(&tick_label(w[0])) + extent(&tick_label(w[1]))) / 2.0 + TICK_LABEL_GAP
        })
    };
    let mut candidates = vec![];
    if hi / lo <= 1e3 * (1.0 + 1e-9) {
        candidates.push(ticks(&[1, 2, 5], 1));
    }
    for stride in 1..=(e1 - e0).max(1) {
        candidates.push(ticks(&[1], stride));
    }
    let last = candidates.last().cloned().unwrap_or_default();
    candidates.into_iter().find(|t| !t.is_empty() && fits(t)).unwrap_or(last)
}

/// The light grid lines under `ticks` ([`log_ticks`]): 1..9 per decade where the ticks are
/// 1-2-5 or every decade of a range of at most four decades, else every decade.
fn log_light_points(lo: f64, hi: f64, ticks: &[f64]) -> Vec<f64> {
    let every_decade = ticks.windows(2).all(|w| w[1] / w[0] < 10.5);
    let steps: Vec<u32> = if every_decade && hi / lo <= 1e4 { (1..=9).collect() } else { vec![1] };
    let (e0, e1) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    (e0..=e1).flat_map(|e| steps.iter().map(move |&d| decimal(d, e))).filter(|v| *v >= lo && *v <= hi).collect()
}

/// An axis-aligned box in pixels (y down).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rect {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl Rect {
    pub fn new(x: f64, y: f64, w: f64, h: f64) -> Self {
        Rect { x0: x, y0: y, x1: x + w, y1: y + h }
    }
    pub fn overlaps(&self, o: &Rect) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }
    pub fn inside(&self, o: &Rect) -> bool {
        self.x0 >= o.x0 && self.x1 <= o.x1 && self.y0 >= o.y0 && self.y1 <= o.y1
    }
}

/// Where each point's label goes: `anchors` are the markers' centres (radius `radius`),
/// `sizes` the labels' widths and heights, all in pixels. A label sits beside its marker
/// (right, left, above, below, then the diagonals), and, where all of those are taken, stacked
/// further above, below or to the right; it never covers a marker, another label or an
/// `obstacle` (the legend), and stays inside `area`; it keeps off the `soft` ones (the
/// curves) too where any place allows. A label with no free place is left out (`None`).
/// Points are labelled in order, so earlier ones get the nearer places.
pub fn place_labels(
    anchors: &[(f64, f64)],
    sizes: &[(f64, f64)],
    radius: f64,
    area: Rect,
    obstacles: &[Rect],
    soft: &[Rect],
) -> Vec<Option<Rect>> {
    let markers: Vec<Rect> =
        anchors.iter().map(|&(x, y)| Rect::new(x - radius, y - radius, 2.0 * radius, 2.0 * radius)).collect();
    let g = radius + 3.0;
    let mut placed: Vec<Rect> = vec![];
    anchors
        .iter()
        .zip(sizes)
        .map(|(&(px, py), &(w, h))| {
            let mut offsets = vec![
                (g, -h / 2.0),
                (-g - w, -h / 2.0),
                (-w / 2.0, -g - h),
                (-w / 2.0, g),
                (g / 2.0, -g - h),
                (g / 2.0, g),
                (-g / 2.0 - w, -g - h),
                (-g / 2.0 - w, g),
            ];
            for k in 1..=3 {
                let k = k as f64 * (h + 2.0);
                offsets.extend([(-w / 2.0, -g - h - k), (-w / 2.0, g + k), (g, -h / 2.0 - k), (g, -h / 2.0 + k)]);
            }
            let spots: Vec<Rect> = offsets
                .into_iter()
                .map(|(dx, dy)| Rect::new(px + dx, py + dy, w, h))
                .filter(|r| r.inside(&area) && !markers.iter().chain(&placed).chain(obstacles).any(|o| r.overlaps(o)))
                .collect();
            let clear = spots.iter().find(|r| !soft.iter().any(|o| r.overlaps(o)));
            let spot = clear.or(spots.first()).copied();
            placed.extend(spot);
            spot
        })
        .collect()
}

/// Size in pixels (width, height) of the plots.
pub const PLOT_SIZE: (u32, u32) = (1000, 620);
const TICK_FONT: u32 = 14;
const POINT_FONT: u32 = 12;
const MARKER_RADIUS: i32 = 4;

/// The text's width and height in pixels in the bundled font at `px`.
fn text_size(text: &str, px: u32) -> (f64, f64) {
    register_font();
    match ("sans-serif", px).into_font().box_size(text) {
        Ok((w, h)) => (w as f64, h as f64),
        Err(_) => (0.6 * px as f64 * text.chars().count() as f64, px as f64),
    }
}

/// What one plot draws, the same for both files.
struct Figure<'a> {
    title: &'a str,
    x_label: &'a str,
    y_label: &'a str,
    series: Vec<Series>,
    guide: Option<&'a Guide>,
    x: (f64, f64),
    y: (f64, f64),
}

/// A log-log plot of `series` written to `path` (PNG, [`PLOT_SIZE`]) and beside it as SVG
/// (`path` with the extension `svg`), both drawn by one routine.
pub fn log_log_plot(path: &Path, title: &str, x_label: &str, y_label: &str, series: &[Series]) -> Result<(), String> {
    log_log_plot_with(path, title, x_label, y_label, series, None)
}

/// [`log_log_plot`] with an optional [`Guide`].
pub fn log_log_plot_with(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    guide: Option<&Guide>,
) -> Result<(), String> {
    register_font();
    // The points a log-log plot can draw (x > 0; errors below the floor drawn at it), each
    // with its label.
    let series: Vec<Series> = series
        .iter()
        .map(|s| {
            let (points, labels) = s
                .points
                .iter()
                .enumerate()
                .filter(|(_, (x, y))| PLOT_RANGE.contains(x) && y.is_finite() && *y <= *PLOT_RANGE.end())
                .map(|(i, &(x, y))| ((x, y.max(ERROR_FLOOR)), s.labels.get(i).cloned().unwrap_or_default()))
                .unzip();
            Series { name: s.name.clone(), points, labels }
        })
        .collect();
    let pts: Vec<(f64, f64)> = series.iter().flat_map(|s| s.points.iter().copied()).collect();
    if pts.is_empty() {
        return Err("nothing to plot".into());
    }
    let span = |v: Vec<f64>| {
        let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        (lo / 2.0, hi * 2.0)
    };
    let figure = Figure {
        title,
        x_label,
        y_label,
        x: span(pts.iter().map(|p| p.0).collect()),
        y: span(pts.iter().map(|p| p.1).collect()),
        series,
        guide,
    };
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, PLOT_SIZE).into_drawing_area();
        draw(&root, &figure)?;
        root.present().map_err(|e| e.to_string())?;
    }
    std::fs::rename(&tmp, path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, PLOT_SIZE).into_drawing_area();
        draw(&root, &figure)?;
        root.present().map_err(|e| e.to_string())?;
    }
    let svg_path = path.with_extension("svg");
    let tmp = path.with_extension("tmp.svg");
    std::fs::write(&tmp, svg).map_err(|e| format!("{}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, &svg_path).map_err(|e| format!("{}: {e}", svg_path.display()))
}

/// Draw `f` on `root`: axes with [`log_ticks`], one curve and marker per point per series,
/// the guide, the legend in the emptiest corner, and every point's label ([`place_labels`]).
fn draw<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, f: &Figure<'_>) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(e)?;
    let ((x0, x1), (y0, y1)) = (f.x, f.y);
    // The plotting area's size, near enough for choosing ticks (the exact one is known only
    // once the chart is built, and the ticks are part of building it).
    let (w, h) = (PLOT_SIZE.0 as f64 - 2.0 * 12.0 - 72.0, PLOT_SIZE.1 as f64 - 2.0 * 12.0 - 48.0 - 36.0);
    let x_ticks = log_ticks(x0, x1, w, |l| text_size(l, TICK_FONT).0);
    let y_ticks = log_ticks(y0, y1, h, |l| text_size(l, TICK_FONT).1);
    let mut chart = ChartBuilder::on(root)
        .caption(f.title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(48)
        .y_label_area_size(72)
        .build_cartesian_2d(
            (x0..x1).log_scale().with_key_points(x_ticks.clone()).with_light_points(log_light_points(x0, x1, &x_ticks)),
            (y0..y1).log_scale().with_key_points(y_ticks.clone()).with_light_points(log_light_points(y0, y1, &y_ticks)),
        )
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc(f.x_label)
        .y_desc(f.y_label)
        .label_style(("sans-serif", TICK_FONT))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(200, 200, 200))
        .x_label_formatter(&|v| tick_label(*v))
        .y_label_formatter(&|v| tick_label(*v))
        .draw()
        .map_err(e)?;
    let colours = series_colours(&f.series.iter().map(|s| s.name.as_str()).collect::<Vec<_>>());
    let colour = |i: usize| colours[i];
    for (i, s) in f.series.iter().enumerate() {
        let c = colour(i);
        chart
            .draw_series(LineSeries::new(s.points.clone(), c.stroke_width(2)))
            .map_err(e)?
            .label(s.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart.draw_series(s.points.iter().map(|&p| Circle::new(p, MARKER_RADIUS, c.filled()))).map_err(e)?;
    }
    let mut crosses = vec![];
    if let Some(g) = f.guide.filter(|g| g.y > y0 && g.y < y1) {
        let dashes: Vec<PathElement<(f64, f64)>> = (0..40)
            .map(|i| {
                let at = |t: f64| x0 * (x1 / x0).powf(t);
                PathElement::new(vec![(at(i as f64 / 40.0), g.y), (at((i as f64 + 0.5) / 40.0), g.y)], BLACK)
            })
            .collect();
        chart
            .draw_series(dashes)
            .map_err(e)?
            .label(g.label.clone())
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 8, y), (x + 12, y), (x + 20, y)], BLACK));
        for (name, x) in &g.marks {
            let Some(i) = f.series.iter().position(|s| &s.name == name) else { continue };
            if *x > x0 && *x < x1 {
                chart.draw_series([Cross::new((*x, g.y), 7, colour(i).stroke_width(3))]).map_err(e)?;
                crosses.push(chart.backend_coord(&(*x, g.y)));
            }
        }
    }
    // The legend in the corner of the plotting area with the fewest points under it.
    let (xr, yr) = chart.plotting_area().get_pixel_range();
    let area = Rect { x0: xr.start as f64, y0: yr.start as f64, x1: xr.end as f64, y1: yr.end as f64 };
    let mut names: Vec<&str> = f.series.iter().map(|s| s.name.as_str()).collect();
    if let Some(g) = f.guide.filter(|g| g.y > y0 && g.y < y1) {
        names.push(&g.label);
    }
    let anchors: Vec<(f64, f64)> = f
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| chart.backend_coord(p)))
        .map(|(x, y)| (x as f64, y as f64))
        .collect();
    let legend = legend_rect(area, &names, &anchors);
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::Coordinate((legend.x0 - area.x0) as i32, (legend.y0 - area.y0) as i32))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", TICK_FONT))
        .draw()
        .map_err(e)?;
    // Every point's label, in its series' colour darkened for reading on white.
    let labels: Vec<(&str, usize)> =
        f.series.iter().enumerate().flat_map(|(i, s)| s.labels.iter().map(move |l| (l.as_str(), i))).collect();
    let sizes: Vec<(f64, f64)> = labels.iter().map(|(l, _)| text_size(l, POINT_FONT)).collect();
    let mut obstacles = vec![legend];
    obstacles.extend(crosses.iter().map(|&(x, y)| Rect::new(x as f64 - 8.0, y as f64 - 8.0, 16.0, 16.0)));
    // The curves, as small boxes every few pixels along each segment, and the guide's line.
    let curves: Vec<Vec<(f64, f64)>> = (f.series.iter())
        .map(|s| s.points.iter().map(|p| chart.backend_coord(p)).map(|(x, y)| (x as f64, y as f64)).collect())
        .collect();
    let mut soft = curve_boxes(&curves);
    if let Some(g) = f.guide.filter(|g| g.y > y0 && g.y < y1) {
        let y = chart.backend_coord(&(x0, g.y)).1 as f64;
        soft.push(Rect { x0: area.x0, y0: y - 1.0, x1: area.x1, y1: y + 1.0 });
    }
    let places = place_labels(&anchors, &sizes, MARKER_RADIUS as f64 + 1.0, area, &obstacles, &soft);
    for ((text, i), spot) in labels.iter().zip(places) {
        let Some(r) = spot.filter(|_| !text.is_empty()) else { continue };
        let c = colour(*i);
        let dark = RGBColor((c.0 as f64 * 0.6) as u8, (c.1 as f64 * 0.6) as u8, (c.2 as f64 * 0.6) as u8);
        let style = ("sans-serif", POINT_FONT).into_font().color(&dark).pos(Pos::new(HPos::Left, VPos::Top));
        root.draw(&Text::new(text.to_string(), (r.x0.round() as i32, r.y0.round() as i32), style)).map_err(e)?;
    }
    Ok(())
}

/// The legend's box: in the corner of the plotting `area` with the fewest of the points
/// (`anchors`, in pixels) under it, sized for `names`.
fn legend_rect(area: Rect, names: &[&str], anchors: &[(f64, f64)]) -> Rect {
    let text_w = names.iter().map(|n| text_size(n, TICK_FONT).0).fold(0.0, f64::max);
    let (lw, lh) =
        (text_w + 30.0 + 20.0 + 4.0, (names.len() as f64 - 1.0).max(0.0) * 1.25 * TICK_FONT as f64 + 18.0 + 20.0);
    let corners = [
        (area.x1 - lw - 5.0, area.y0 + 5.0),
        (area.x0 + 5.0, area.y0 + 5.0),
        (area.x1 - lw - 5.0, area.y1 - lh - 5.0),
        (area.x0 + 5.0, area.y1 - lh - 5.0),
    ];
    let covered = |r: &Rect| {
        let near = |&(x, y): &(f64, f64)| r.overlaps(&Rect::new(x - 12.0, y - 12.0, 24.0, 24.0));
        anchors.iter().filter(|p| near(p)).count()
    };
    corners.iter().map(|&(x, y)| Rect::new(x, y, lw, lh)).min_by_key(|r| covered(r)).expect("four corners")
}

/// Small boxes every few pixels along each curve's segments (pixel coordinates): what a
/// point's label should avoid covering.
fn curve_boxes(curves: &[Vec<(f64, f64)>]) -> Vec<Rect> {
    let mut soft = vec![];
    for px in curves {
        for w in px.windows(2) {
            let steps = ((w[1].0 - w[0].0).hypot(w[1].1 - w[0].1) / 4.0).ceil().max(1.0) as usize;
            for i in 0..=steps {
                let t = i as f64 / steps as f64;
                let (x, y) = (w[0].0 + t * (w[1].0 - w[0].0), w[0].1 + t * (w[1].1 - w[0].1));
                soft.push(Rect::new(x - 1.5, y - 1.5, 3.0, 3.0));
            }
        }
    }
    soft
}

/// Whether `text` is XML whose elements nest: every opened tag closed in order, comments,
/// declarations and self-closing tags allowed; the check the report's SVG plots pass.
pub fn xml_tags_balance(text: &str) -> Result<(), String> {
    let mut open: Vec<&str> = vec![];
    let mut rest = text;
    while let Some(i) = rest.find('<') {
        rest = &rest[i..];
        if let Some(r) = rest.strip_prefix("<!--") {
            let end = r.find("-->").ok_or("an unclosed comment")?;
            rest = &r[end + 3..];
            continue;
        }
        let end = rest.find('>').ok_or("an unclosed tag")?;
        let tag = &rest[1..end];
        rest = &rest[end + 1..];
        if tag.starts_with('?') || tag.starts_with('!') || tag.ends_with('/') {
            continue;
        }
        if let Some(name) = tag.strip_prefix('/') {
            match open.pop() {
                Some(o) if o == name.trim() => {}
                o => return Err(format!("</{}> closes {o:?}", name.trim())),
            }
        } else {
            let name = tag.split_whitespace().next().unwrap_or("");
            if name.is_empty() {
                return Err("an empty tag".into());
            }
            open.push(name);
        }
    }
    match open.is_empty() {
        true => Ok(()),
        false => Err(format!("unclosed elements {open:?}")),
    }
}

/// Height in pixels of the colour bar [`with_colour_bar`] puts under an error picture at most
/// 300 pixels wide ([`colour_bar_height`] under a wider one).
pub const COLOUR_BAR_HEIGHT: u32 = 60;

/// The height of the colour bar under a picture `width` pixels wide: [`COLOUR_BAR_HEIGHT`] up
/// to 300 pixels, and in proportion beyond, so its text keeps its size beside the picture
/// when the figure is shown shrunk to a column of the report.
pub fn colour_bar_height(width: u32) -> u32 {
    COLOUR_BAR_HEIGHT * width.max(300) / 300
}

/// `picture` (a false-colour error map, [`biscale_shading::image::error_image`]) with its colour
/// bar below: the viridis ramp from 0 to `scale`, ticks at 0, half and full scale, and
/// `label` saying what is measured and in which unit (one or two lines, split at `\n`; a line
/// too long for the bar is set in a smaller size, not clipped). The bar is at least 300 pixels
/// wide; a narrower picture is centred above it on white. Under a
/// wider picture the bar, its ticks and text grow with it ([`colour_bar_height`]).
pub fn with_colour_bar(picture: &image::RgbImage, scale: f32, label: &str) -> Result<image::RgbImage, String> {
    let w = picture.width().max(300);
    let k = w as f64 / 300.0;
    let bar = draw_colour_bar((w, colour_bar_height(w)), k, (12.0 * k).round() as u32, scale, label)?;
    let mut out = image::RgbImage::from_pixel(w, picture.height() + bar.height(), image::Rgb([255, 255, 255]));
    image::imageops::replace(&mut out, picture, ((w - picture.width()) / 2) as i64, 0);
    image::imageops::replace(&mut out, &bar, 0, picture.height() as i64);
    Ok(out)
}

/// The picture of a [`with_colour_bar`] figure, its bar cut off (a picture narrower than 300
/// pixels keeps the white it was centred on).
pub fn without_colour_bar(figure: &image::RgbImage) -> Result<image::RgbImage, String> {
    let (w, h) = figure.dimensions();
    let bar = colour_bar_height(w);
    match h.checked_sub(bar) {
        Some(p) if p > 0 && w >= 300 => Ok(image::imageops::crop_imm(figure, 0, 0, w, p).to_image()),
        _ => Err(format!("a {w}x{h} picture is not an error figure with a colour bar ({bar} pixels high)")),
    }
}

/// A colour bar alone, `width` pixels wide with its text `font` pixels high (the bar and ticks
/// in proportion: `COLOUR_BAR_HEIGHT * font / 12` high): the one bar under a figure whose
/// panels share a scale, sized for the figure's width rather than a panel's.
pub fn colour_bar(width: u32, font: u32, scale: f32, label: &str) -> Result<image::RgbImage, String> {
    let k = font.max(6) as f64 / 12.0;
    if (width as f64) < 100.0 * k {
        return Err(format!("a colour bar {width} pixels wide is too narrow for {font}-pixel text"));
    }
    draw_colour_bar((width, (COLOUR_BAR_HEIGHT as f64 * k).round() as u32), k, font.max(6), scale, label)
}

/// The bar of [`with_colour_bar`] and [`colour_bar`], `w` x `h` pixels: every length of the
/// 300-pixel layout times `k`, text `font` pixels high.
fn draw_colour_bar((w, h): (u32, u32), k: f64, font: u32, scale: f32, label: &str) -> Result<image::RgbImage, String> {
    register_font();
    let at = |v: f64| (v * k).round() as i32;
    let mut bar = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut bar, (w, h)).into_drawing_area();
        let (x0, x1) = (at(10.0), w as i32 - at(10.0));
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        for x in x0..x1 {
            let c = biscale_shading::image::viridis((x - x0) as f32 / (x1 - x0 - 1).max(1) as f32);
            root.draw(&Rectangle::new([(x, at(3.0)), (x + 1, at(15.0))], RGBColor(c[0], c[1], c[2]).filled()))
                .map_err(e)?;
        }
        for (frac, hp) in [(0.0f32, HPos::Left), (0.5, HPos::Center), (1.0, HPos::Right)] {
            let x = x0 + ((x1 - x0 - 1) as f32 * frac).round() as i32;
            root.draw(&PathElement::new(vec![(x, at(15.0)), (x, at(19.0))], BLACK)).map_err(e)?;
            let style = ("sans-serif", font).into_font().color(&BLACK).pos(Pos::new(hp, VPos::Top));
            root.draw(&Text::new(tick_label((scale * frac) as f64), (x, at(20.0)), style)).map_err(e)?;
        }
        for (i, line) in label.lines().take(2).enumerate() {
            // A line wider than the bar is set smaller until it fits, never clipped.
            let avail = w as f64 - 2.0 * at(6.0) as f64;
            let width = text_size(line, font).0;
            let font = match width > avail {
                true => ((font as f64 * avail / width).floor() as u32).max(6),
                false => font,
            };
            let style = ("sans-serif", font).into_font().color(&BLACK).pos(Pos::new(HPos::Center, VPos::Top));
            root.draw(&Text::new(line.to_string(), (w as i32 / 2, at(33.0 + 13.0 * i as f64)), style)).map_err(e)?;
        }
        root.present().map_err(|e| e.to_string())?;
    }
    image::RgbImage::from_raw(w, h, bar).ok_or_else(|| "colour bar buffer size".to_string())
}

/// The layout of a contact sheet for [`labelled_sheet`]: `panels` grids side by side,
/// `panel_gap` pixels apart, each of `rows` x `columns` equal tiles with 1-pixel gaps
/// (`biscale_shading::synth::contact_sheet` and `comparison_sheet`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SheetLayout {
    pub panels: u32,
    pub panel_gap: u32,
    pub rows: u32,
    pub columns: u32,
}

/// Tiles narrower than this are magnified (nearest) by an integer factor in a
/// [`labelled_sheet`], so that a column's label fits over it.
pub const LABELLED_TILE: u32 = 72;

/// `sheet` laid out as `layout` with its labels: `title` above, each panel's title over it,
/// each column's label (one or two lines, split at `\n`) over its tiles in every panel and
/// each row's beside the first panel. The sheet is magnified by an integer factor so a tile is
/// at least [`LABELLED_TILE`] pixels wide. Errors when the sheet's size does not divide into
/// the layout or the label counts differ from it.
pub fn labelled_sheet(
    sheet: &image::RgbImage,
    layout: SheetLayout,
    title: &str,
    panel_titles: &[String],
    column_labels: &[String],
    row_labels: &[String],
) -> Result<image::RgbImage, String> {
    register_font();
    let SheetLayout { panels, panel_gap, rows, columns } = layout;
    if panels == 0 || rows == 0 || columns == 0 {
        return Err("a sheet needs at least one panel, row and column".into());
    }
    let (w, h) = sheet.dimensions();
    let panel_w = w.checked_sub((panels - 1) * panel_gap).map(|x| x / panels).unwrap_or(0);
    let tile_w = panel_w.checked_sub(columns - 1).map(|x| x / columns).unwrap_or(0);
    let tile_h = h.checked_sub(rows - 1).map(|x| x / rows).unwrap_or(0);
    if tile_w == 0
        || tile_h == 0
        || panel_w * panels + (panels - 1) * panel_gap != w
        || tile_w * columns + columns - 1 != panel_w
        || tile_h * rows + rows - 1 != h
    {
        return Err(format!("a {w}x{h} sheet is not {panels} panel(s) of {rows}x{columns} tiles"));
    }
    if column_labels.len() != columns as usize || row_labels.len() != rows as usize {
        return Err(format!(
            "{} column and {} row labels for {columns} columns and {rows} rows",
            column_labels.len(),
            row_labels.len()
        ));
    }
    if !(panel_titles.is_empty() || panel_titles.len() == panels as usize) {
        return Err(format!("{} panel titles for {panels} panels", panel_titles.len()));
    }
    let k = LABELLED_TILE.div_ceil(tile_w).max(1);
    let big = image::imageops::resize(sheet, w * k, h * k, image::imageops::FilterType::Nearest);
    let font = 13u32;
    let line = font as i32 + 3;
    let lines = |s: &str| s.lines().count().max(1) as i32;
    let head_lines = column_labels.iter().map(|l| lines(l)).max().unwrap_or(1);
    let left =
        row_labels.iter().flat_map(|l| l.lines()).map(|l| text_size(l, font).0.ceil() as u32).max().unwrap_or(0) + 12;
    let top = 8 + line * (1 + (!panel_titles.is_empty()) as i32 + head_lines);
    let (cw, ch) = (left + w * k + 8, top as u32 + h * k + 8);
    let mut buf = vec![255u8; (cw * ch * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (cw, ch)).into_drawing_area();
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        let text = |s: &str, x: i32, y: i32, hp: HPos| {
            let style = ("sans-serif", font).into_font().color(&BLACK).pos(Pos::new(hp, VPos::Top));
            Text::new(s.to_string(), (x, y), style)
        };
        root.draw(&text(title, 4, 4, HPos::Left)).map_err(e)?;
        let x0 = left as i32;
        let panel_x = |p: u32| x0 + ((p * (panel_w + panel_gap)) * k) as i32;
        let mut y = 4 + line;
        if !panel_titles.is_empty() {
            for (p, t) in panel_titles.iter().enumerate() {
                let cx = panel_x(p as u32) + (panel_w * k / 2) as i32;
                root.draw(&text(t, cx, y, HPos::Center)).map_err(e)?;
            }
            y += line;
        }
        for p in 0..panels {
            for (c, label) in column_labels.iter().enumerate() {
                let cx = panel_x(p) + ((c as u32 * (tile_w + 1)) * k + tile_w * k / 2) as i32;
                for (i, l) in label.lines().enumerate() {
                    root.draw(&text(l, cx, y + line * i as i32, HPos::Center)).map_err(e)?;
                }
            }
        }
        for (r, label) in row_labels.iter().enumerate() {
            let n = lines(label);
            let cy = top + ((r as u32 * (tile_h + 1)) * k + tile_h * k / 2) as i32 - n * line / 2;
            for (i, l) in label.lines().enumerate() {
                root.draw(&text(l, x0 - 6, cy + line * i as i32, HPos::Right)).map_err(e)?;
            }
        }
        root.present().map_err(|e| e.to_string())?;
    }
    let mut out = image::RgbImage::from_raw(cw, ch, buf).ok_or("sheet buffer size")?;
    image::imageops::replace(&mut out, &big, left as i64, top as i64);
    Ok(out)
}

/// Each series' colour, the same for a method in every plot of a run and of `reproduce`: by
/// the kind its name starts with (a kind in an error-vs-storage plot, a setting's label such as
/// `bicluster-e0.03` in an animation's), from a fixed palette for the built-in kinds (Okabe and
/// Ito's, which colour-blind readers tell apart: the paper's biclustering vermillion, CPCA
/// blue, Haar green, the SH method purple, the uncompressed render black, raw sparse grey) and
/// from a hash of the kind for any other (a plugin, a Python compressor), so it too keeps its
/// colour from plot to plot. A second series of one kind in the same plot is set lighter, a
/// third darker, and so on.
pub fn series_colours(names: &[&str]) -> Vec<RGBAColor> {
    let base = |name: &str| -> RGBColor {
        let kind = name.split(['-', ' ', '(']).next().unwrap_or(name);
        match kind {
            "uncompressed" => RGBColor(0, 0, 0),
            "sparse" => RGBColor(120, 120, 120),
            "bicluster" => RGBColor(213, 94, 0),
            "cpca" => RGBColor(0, 114, 178),
            "haar" => RGBColor(0, 158, 115),
            "sh" => RGBColor(204, 121, 167),
            other => {
                // FNV-1a: stable across runs and platforms.
                let h =
                    other.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x100_0000_01b3));
                let c = Palette99::pick(h as usize % 99).to_rgba();
                RGBColor(c.0, c.1, c.2)
            }
        }
    };
    let mut seen: BTreeMap<(u8, u8, u8), usize> = BTreeMap::new();
    names
        .iter()
        .map(|name| {
            let c = base(name);
            let n = seen.entry((c.0, c.1, c.2)).or_default();
            let shade = |c: u8, to: f64, t: f64| (c as f64 + (to - c as f64) * t).round() as u8;
            // 0: as is; then lighter and darker by turns, each step further.
            let (to, t) = match *n {
                0 => (0.0, 0.0),
                k if k % 2 == 1 => (255.0, 0.35 * k.div_ceil(2) as f64),
                k => (0.0, 0.3 * (k / 2) as f64),
            };
            *n += 1;
            let t = t.min(0.8);
            RGBColor(shade(c.0, to, t), shade(c.1, to, t), shade(c.2, to, t)).to_rgba()
        })
        .collect()
}

/// One setting's per-frame figures on a [`frame_plot`].
pub struct FrameCurve {
    pub name: String,
    /// Each frame's image error (relative L2; a curve of zeros, the target itself, is left off
    /// the error panel).
    pub error: Vec<f64>,
    /// Each frame's wall time in ms.
    pub ms: Vec<f64>,
}

/// An animation's per-frame plot: image error (log scale) above, frame time below, both
/// against the frame index, every curve on one pair of axes; written to `path` (PNG,
/// [`PLOT_SIZE`]) and beside it as SVG, drawn by one routine.
pub fn frame_plot(path: &Path, title: &str, curves: &[FrameCurve]) -> Result<(), String> {
    register_font();
    let frames = curves.iter().map(|c| c.error.len().max(c.ms.len())).max().unwrap_or(0);
    if frames == 0 {
        return Err("nothing to plot".into());
    }
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, PLOT_SIZE).into_drawing_area();
        draw_frames(&root, title, curves, frames)?;
        root.present().map_err(|e| e.to_string())?;
    }
    std::fs::rename(&tmp, path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, PLOT_SIZE).into_drawing_area();
        draw_frames(&root, title, curves, frames)?;
        root.present().map_err(|e| e.to_string())?;
    }
    let svg_path = path.with_extension("svg");
    let tmp = path.with_extension("tmp.svg");
    std::fs::write(&tmp, svg).map_err(|e| format!("{}: {e}", tmp.display()))?;
    std::fs::rename(&tmp, &svg_path).map_err(|e| format!("{}: {e}", svg_path.display()))
}

/// A frame index on the axis: whole frames only (the mesh's fractional ticks stay unlabelled).
fn frame_label(v: &f64) -> String {
    match (v - v.round()).abs() < 1e-6 {
        true => format!("{v:.0}"),
        false => String::new(),
    }
}

fn draw_frames<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
    curves: &[FrameCurve],
    frames: usize,
) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(e)?;
    let root = root.titled(title, ("sans-serif", 20)).map_err(e)?;
    let (top, bottom) = root.split_vertically(PLOT_SIZE.1 as i32 / 2 - 10);
    let x = 0f64..(frames.max(2) - 1) as f64;
    let span = |v: Vec<f64>| v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let errors: Vec<f64> =
        curves.iter().flat_map(|c| c.error.iter().copied()).filter(|x| PLOT_RANGE.contains(x)).collect();
    let (lo, hi) = if errors.is_empty() { (1e-3, 1.0) } else { span(errors) };
    let (lo, hi) = ((lo / 2.0).max(ERROR_FLOOR), hi * 2.0);
    let ms: Vec<f64> = curves.iter().flat_map(|c| c.ms.iter().copied()).filter(|x| x.is_finite()).collect();
    let (_, ms_hi) = if ms.is_empty() { (0.0, 1.0) } else { span(ms) };
    let colours = series_colours(&curves.iter().map(|c| c.name.as_str()).collect::<Vec<_>>());
    let colour = |i: usize| colours[i];
    let mut chart = ChartBuilder::on(&top)
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(70)
        .build_cartesian_2d(x.clone(), (lo..hi).log_scale())
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("frame")
        .y_desc("rel. L2 vs uncompressed")
        .x_labels(frames.clamp(2, 13))
        .x_label_formatter(&frame_label)
        .y_label_formatter(&|v| tick_label(*v))
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(e)?;
    for (i, c) in curves.iter().enumerate() {
        if c.error.iter().all(|&x| x == 0.0) {
            continue;
        }
        let points: Vec<(f64, f64)> = c
            .error
            .iter()
            .enumerate()
            .filter(|(_, y)| y.is_finite())
            .map(|(f, &y)| (f as f64, y.max(ERROR_FLOOR)))
            .collect();
        let style = ShapeStyle::from(colour(i)).stroke_width(2);
        chart
            .draw_series(LineSeries::new(points, style))
            .map_err(e)?
            .label(c.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 13))
        .draw()
        .map_err(e)?;
    let mut chart = ChartBuilder::on(&bottom)
        .margin(10)
        .x_label_area_size(30)
        .y_label_area_size(70)
        .build_cartesian_2d(x, 0f64..ms_hi * 1.1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("frame")
        .y_desc("frame time, ms (gather + shade)")
        .x_labels(frames.clamp(2, 13))
        .x_label_formatter(&frame_label)
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(e)?;
    for (i, c) in curves.iter().enumerate() {
        let points: Vec<(f64, f64)> =
            c.ms.iter().enumerate().filter(|(_, y)| y.is_finite()).map(|(f, &y)| (f as f64, y)).collect();
        let style = ShapeStyle::from(colour(i)).stroke_width(2);
        chart
            .draw_series(LineSeries::new(points, style))
            .map_err(e)?
            .label(c.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 13))
        .draw()
        .map_err(e)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    /// A label longer than the bar is set smaller, inside the bar's margins, not clipped at
    /// its edges (the run's own labels fit at every width from 300 to 1000 pixels; a longer
    /// `against` name need not).
    #[test]
    fn a_labelled_sheet_keeps_every_tile_and_refuses_a_wrong_layout() {
        // Two panels 8 apart of 2 rows x 3 columns of 10x6 tiles: 2 x 32 + 8 = 72 by 13.
        let mut sheet = image::RgbImage::from_pixel(72, 13, image::Rgb([0, 0, 0]));
        sheet.put_pixel(0, 0, image::Rgb([255, 0, 0]));
        sheet.put_pixel(71, 12, image::Rgb([0, 0, 255]));
        let layout = SheetLayout { panels: 2, panel_gap: 8, rows: 2, columns: 3 };
        let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
        let cols = s(&["light 0\n90 deg", "light 5", "light 9"]);
        let rows = s(&["view 0", "view 3\n35 deg"]);
        let out = labelled_sheet(&sheet, layout, "a BTF", &s(&["dense", "lpca"]), &cols, &rows).unwrap();
        // Tiles 10 wide are magnified 8 times (72 / 10 rounded up): the sheet is 576x104,
        // placed whole with its first and last pixels where they were, and labels above and
        // left of it (dark text pixels there).
        let k = LABELLED_TILE.div_ceil(10);
        assert_eq!(k, 8);
        let (x0, y0) = (out.width() - 8 - 72 * k, out.height() - 8 - 13 * k);
        assert_eq!(out.get_pixel(x0, y0).0, [255, 0, 0]);
        assert_eq!(out.get_pixel(x0 + 72 * k - 1, y0 + 13 * k - 1).0, [0, 0, 255]);
        let dark = |xs: std::ops::Range<u32>, ys: std::ops::Range<u32>| {
            xs.flat_map(|x| ys.clone().map(move |y| (x, y))).filter(|&(x, y)| out.get_pixel(x, y).0[0] < 128).count()
        };
        assert!(dark(0..x0, y0..y0 + 13 * k) > 20, "row labels");
        assert!(dark(x0..out.width(), 0..y0) > 50, "title and column labels");
        // Wrong layouts and label counts are errors, not panics.
        let bad = SheetLayout { rows: 3, ..layout };
        assert!(labelled_sheet(&sheet, bad, "", &[], &cols, &s(&["a", "b", "c"])).unwrap_err().contains("not 2 panel"));
        assert!(labelled_sheet(&sheet, layout, "", &[], &cols, &s(&["a"])).unwrap_err().contains("1 row labels"));
        let zero = SheetLayout { panels: 0, ..layout };
        assert!(labelled_sheet(&sheet, zero, "", &[], &cols, &rows).is_err());
    }

    #[test]
    fn a_long_colour_bar_label_fits_inside_the_bar() {
        let long = "luminance of |error| vs the uncompressed render of the paper's cosine rule (linear radiance)\nlargest 0.25";
        for w in [300, 320, 640, 1000] {
            let out = with_colour_bar(&image::RgbImage::new(w, 30), 0.25, long).unwrap();
            let h = colour_bar_height(w);
            let lum = |x: u32, y: u32| out.get_pixel(x, y).0.iter().map(|&c| c as u32).sum::<u32>();
            // The label lines, below the tick labels.
            let dark_at = |x: u32| (30 + h * 33 / 60..30 + h).any(|y| lum(x, y) < 600);
            assert!((0..w).filter(|&x| dark_at(x)).count() as u32 > w / 3, "{w}: the label is drawn");
            let edge = (w / 100).max(2);
            assert!(!(0..edge).chain(w - edge..w).any(dark_at), "{w}: nothing at the bar's edges");
        }
    }

    #[test]
    fn a_colour_bar_runs_from_zero_to_the_scale_under_the_picture() {
        let picture = image::RgbImage::from_pixel(120, 30, image::Rgb([1, 2, 3]));
        let out = with_colour_bar(&picture, 0.25, "luminance of |error|").unwrap();
        // At least 300 wide, the picture centred on top, the bar below.
        assert_eq!((out.width(), out.height()), (300, 30 + COLOUR_BAR_HEIGHT));
        assert_eq!(out.get_pixel(90, 0).0, [1, 2, 3]);
        assert_eq!(out.get_pixel(89, 0).0, [255, 255, 255]);
        assert_eq!(out.get_pixel(210, 29).0, [255, 255, 255]);
        // The ramp's ends are viridis(0) and viridis(1), and it brightens left to right.
        let ramp = |x: u32| out.get_pixel(x, 30 + 8).0;
        assert_eq!(ramp(10), biscale_shading::image::viridis(0.0));
        assert_eq!(ramp(289), biscale_shading::image::viridis(1.0));
        let lum = |p: [u8; 3]| p.iter().map(|&c| c as u32).sum::<u32>();
        assert!(lum(ramp(10)) < lum(ramp(150)) && lum(ramp(150)) < lum(ramp(289)));
        // Tick labels are drawn: dark pixels under the ramp.
        let dark = (30 + 20..30 + COLOUR_BAR_HEIGHT).flat_map(|y| (0..300).map(move |x| (x, y)));
        assert!(dark.filter(|&(x, y)| lum(out.get_pixel(x, y).0) < 200).count() > 50);
        // Under a picture twice as wide, the bar is twice as tall, its ramp and text too.
        let wide = with_colour_bar(&image::RgbImage::new(600, 30), 0.25, "luminance of |error|").unwrap();
        assert_eq!(colour_bar_height(600), 120);
        assert_eq!((wide.width(), wide.height()), (600, 30 + 120));
        assert_eq!(wide.get_pixel(20, 30 + 16).0, biscale_shading::image::viridis(0.0));
        assert_eq!(wide.get_pixel(150, 30 + 34).0, [255, 255, 255], "below the ramp, which ends at 30");
        // Cut off again, the picture is what went in; at any width (60 * w / 300 rounds down).
        for w in [300, 308, 384, 600] {
            let picture = image::RgbImage::from_fn(w, 17, |x, y| image::Rgb([x as u8, y as u8, 7]));
            let figure = with_colour_bar(&picture, 1.0, "x").unwrap();
            assert_eq!(without_colour_bar(&figure).unwrap(), picture, "{w}");
        }
        assert!(without_colour_bar(&image::RgbImage::new(300, 60)).is_err(), "all bar, no picture");
        assert!(without_colour_bar(&image::RgbImage::new(200, 90)).is_err(), "narrower than any figure");
        // A bar alone for a figure: its text size is set apart from its width.
        let alone = colour_bar(1200, 20, 0.5, "luminance of |error|").unwrap();
        assert_eq!((alone.width(), alone.height()), (1200, 100));
        assert_eq!(
            alone.get_pixel(1200 - 18, 12).0,
            biscale_shading::image::viridis(1.0),
            "ramp ends 10 k = 17 from the edge"
        );
        assert!(colour_bar(120, 20, 0.5, "x").is_err(), "too narrow for its text");
    }

    /// A kind keeps its colour across plots (a kind's name in one, a setting's label in the
    /// other); two series of one kind in a plot differ; an unknown kind's colour is stable.
    #[test]
    fn each_method_keeps_its_colour_from_plot_to_plot() {
        let storage = super::series_colours(&["sparse", "bicluster", "cpca", "haar", "my-plugin"]);
        let frames =
            super::series_colours(&["uncompressed", "bicluster-b1024", "bicluster-e0.1", "haar-t6", "my-plugin"]);
        assert_eq!(storage[1], frames[1], "bicluster");
        assert_eq!(storage[3], frames[3], "haar");
        assert_eq!(storage[4], frames[4], "a plugin's colour comes from its name");
        assert_ne!(frames[1], frames[2], "a second bicluster setting is set apart");
        let all: std::collections::HashSet<_> = storage.iter().map(|c| (c.0, c.1, c.2)).collect();
        assert_eq!(all.len(), storage.len(), "every kind its own colour");
    }

    #[test]
    fn log_ticks_are_one_two_five_times_a_power_of_ten_and_their_labels_never_overlap() {
        use super::{log_ticks, tick_label, TICK_LABEL_GAP};

        // A label 8 pixels a character wide (wider than the plots' 14-pixel font draws).
        let extent = |l: &str| 8.0 * l.chars().count() as f64;
        let labels = |t: &[f64]| t.iter().map(|&v| tick_label(v)).collect::<Vec<_>>();
        for (lo, hi) in [(2.0, 6.0), (0.8, 120.0), (1e-8, 1e-1), (1.5, 7.0), (0.6, 35.0), (1e-9, 1.0), (0.05, 4e4)] {
            for pixels in [900.0, 300.0, 120.0] {
                let t = log_ticks(lo, hi, pixels, extent);
                assert!(!t.is_empty(), "[{lo}, {hi}] at {pixels}");
                for &v in &t {
                    assert!(v >= lo && v <= hi, "{v} outside [{lo}, {hi}]");
                    let d = v / 10f64.powf(v.log10().floor());
                    assert!([1.0, 2.0, 5.0].iter().any(|m| (d - m).abs() < 1e-9), "{v} is not 1, 2 or 5 x 10^k");
                }
                // Labels strictly increasing (read back as numbers) and apart by their widths.
                let read: Vec<f64> = labels(&t).iter().map(|l| l.parse().unwrap()).collect();
                assert!(read.windows(2).all(|w| w[0] < w[1]), "{:?}", labels(&t));
                for (w, l) in t.windows(2).zip(labels(&t).windows(2)) {
                    let apart = pixels * (w[1] / w[0]).ln() / (hi / lo).ln();
                    let need = (extent(&l[0]) + extent(&l[1])) / 2.0 + TICK_LABEL_GAP;
                    assert!(apart >= need, "{l:?} {apart:.1} px apart at {pixels} px for [{lo}, {hi}]");
                }
            }
        }
        // 1, 2, 5 on short ranges; plain labels, never "10.000" or "1e1".
        assert_eq!(labels(&log_ticks(2.0, 6.0, 900.0, extent)), ["2", "5"]);
        assert_eq!(labels(&log_ticks(0.8, 120.0, 900.0, extent)), ["1", "2", "5", "10", "20", "50", "100"]);
        let wide = labels(&log_ticks(1e-8, 1e-1, 900.0, extent));
        assert_eq!(wide, ["1e-8", "1e-7", "1e-6", "1e-5", "1e-4", "1e-3", "0.01", "0.1"]);
        // Too little room for every decade: every second or third one.
        let few = log_ticks(1e-8, 1e-1, 120.0, extent);
        assert!(few.len() >= 2 && few.len() < 8, "{:?}", labels(&few));
        // Short labels on a short axis drop the 2s and 5s first.
        assert_eq!(labels(&log_ticks(0.8, 120.0, 120.0, extent)), ["1", "10", "100"]);
        assert!(log_ticks(0.0, 1.0, 900.0, extent).is_empty());
    }

    #[test]
    fn point_labels_keep_off_markers_each_other_and_the_legend_or_are_left_out() {
        use super::{place_labels, Rect};
        let area = Rect::new(0.0, 0.0, 400.0, 300.0);
        let legend = Rect::new(300.0, 0.0, 100.0, 60.0);
        let check = |anchors: &[(f64, f64)], sizes: &[(f64, f64)]| {
            let placed = place_labels(anchors, sizes, 5.0, area, &[legend], &[]);
            let markers: Vec<Rect> = anchors.iter().map(|&(x, y)| Rect::new(x - 5.0, y - 5.0, 10.0, 10.0)).collect();
            let got: Vec<Rect> = placed.iter().flatten().copied().collect();
            for (i, r) in got.iter().enumerate() {
                assert!(r.inside(&area) && !r.overlaps(&legend), "{r:?}");
                assert!(markers.iter().all(|m| !r.overlaps(m)), "{r:?} covers a marker");
                assert!(got[i + 1..].iter().all(|o| !r.overlaps(o)), "{r:?} overlaps another label");
            }
            placed
        };
        // Two points close together: both labelled, the second moved out of the first's way.
        let two = check(&[(100.0, 100.0), (100.0, 108.0)], &[(40.0, 12.0), (40.0, 12.0)]);
        assert!(two.iter().all(Option::is_some), "{two:?}");
        // The first sits to the right of its marker, beside it.
        let r = two[0].unwrap();
        assert!(r.x0 > 105.0 && r.x0 < 115.0 && (r.y0 + 6.0 - 100.0).abs() < 1.0, "{r:?}");
        // Twenty points on one spot: some labels stacked, the rest left out, none overlapping.
        let crowd = check(&[(200.0, 150.0); 20], &[(50.0, 12.0); 20]);
        let shown = crowd.iter().flatten().count();
        assert!((8..20).contains(&shown), "{shown}");
        // Near the legend and the edge: the label goes where there is room.
        let corner = check(&[(390.0, 80.0)], &[(60.0, 12.0)]);
        assert!(corner[0].is_some_and(|r| r.x1 <= 390.0), "{corner:?}");
        // A curve through the right-hand place moves the label off it where there is room,
        // and never keeps it from being shown.
        let curve = [Rect::new(105.0, 90.0, 60.0, 20.0)];
        let moved = place_labels(&[(100.0, 100.0)], &[(40.0, 12.0)], 5.0, area, &[], &curve);
        assert!(moved[0].is_some_and(|r| !r.overlaps(&curve[0])), "{moved:?}");
        let kept = place_labels(&[(100.0, 100.0)], &[(40.0, 12.0)], 5.0, area, &[], &[area]);
        assert_eq!(kept, [Some(Rect::new(108.0, 94.0, 40.0, 12.0))], "beside the marker, as without the curve");
    }

    #[test]
    fn xml_tag_balance_is_checked() {
        use super::xml_tags_balance;
        xml_tags_balance("<svg a=\"1\"><!-- <x> --><g><text>a &lt; b</text><line/></g></svg>").unwrap();
        assert!(xml_tags_balance("<svg><g></svg>").is_err());
        assert!(xml_tags_balance("<svg><g>").is_err());
        assert!(xml_tags_balance("<svg></g>").is_err());
    }

    #[test]
    fn tick_labels_are_short() {
        use super::tick_label;
        let got: Vec<String> = [40.0, 2.5, 0.05, 0.125, 3e-4, 2e5, 1.0].iter().map(|&v| tick_label(v)).collect();
        assert_eq!(got, ["40", "2.5", "0.05", "0.125", "3e-4", "2e5", "1"]);
    }

    use super::*;

    #[test]
    fn writes_a_png_and_an_svg_twin_with_every_point_labelled() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.png");
        let labels = |l: &[&str]| l.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let series = vec![
            Series {
                name: "haar".into(),
                points: vec![(1.0, 0.1), (2.0, 0.05), (4.0, 0.01)],
                labels: labels(&["t4", "t8", "t16"]),
            },
            Series { name: "bicluster".into(), points: vec![(3.0, 0.0)], labels: labels(&["bicluster"]) },
        ];
        log_log_plot(&p, "error against storage", "MB", "rel. error", &series).unwrap();
        let guide = Guide { y: 0.05, label: "target".into(), marks: vec![("haar".into(), 2.0)] };
        log_log_plot_with(&p, "with a guide", "MB", "rel. error", &series, Some(&guide)).unwrap();
        let img = image::open(&p).unwrap();
        assert_eq!((img.width(), img.height()), PLOT_SIZE);
        let svg = std::fs::read_to_string(p.with_extension("svg")).unwrap();
        assert!(svg.starts_with("<svg"), "{}", &svg[..80]);
        xml_tags_balance(&svg).unwrap();
        // The texts drawn: title, ticks, legend and every point's label.
        let texts: Vec<&str> = (svg.split("<text").skip(1))
            .filter_map(|t| t.split_once('>').map(|(_, r)| r.split("</text>").next().unwrap_or("").trim()))
            .collect();
        for text in ["with a guide", "t4", "t8", "t16", "bicluster", "target", "0.01", "1", "2"] {
            assert!(texts.contains(&text), "the SVG lacks {text}: {texts:?}");
        }
        assert!(!dir.path().join("p.tmp.png").exists() && !dir.path().join("p.tmp.svg").exists());
        assert!(log_log_plot(&p, "t", "x", "y", &[]).is_err());
    }

    #[test]
    fn a_setting_is_labelled_without_its_kind() {
        assert_eq!(short_label("haar-t12", "haar"), "t12");
        assert_eq!(short_label("bicluster", "bicluster"), "bicluster");
        assert_eq!(short_label("cpca-k32-c8", "cpca"), "k32-c8");
        assert_eq!(short_label("haarish", "haar"), "haarish");
    }
}
