//! Report plots (PNG): error against gather time and error against storage, one curve per
//! compressor kind through its sweep points, and the image error of every compressor and
//! method against its storage. Text is drawn with the bundled DejaVu Sans
//! (assets/fonts), so plots look the same on machines without system fonts.

use crate::metrics::CompressorRecord;
use plotters::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Once;

static FONT: Once = Once::new();

pub(crate) fn register_font() {
    FONT.call_once(|| {
        let bytes: &'static [u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .unwrap_or_else(|_| panic!("the bundled DejaVuSans.ttf is a valid font"));
    });
}

/// One named curve of (x, y) points.
pub struct Series {
    pub name: String,
    pub points: Vec<(f64, f64)>,
}

/// Group records by compressor kind into series of `(x(record), y(record))`, each curve
/// running through its settings in order of storage (the sweep's order), so an x that need
/// not grow with storage, like gather time, does not zigzag the curve.
pub fn series_by_kind(
    records: &[CompressorRecord],
    x: impl Fn(&CompressorRecord) -> f64,
    y: impl Fn(&CompressorRecord) -> f64,
) -> Vec<Series> {
    series_by(records.iter().map(|r| (r.kind.clone(), r)), x, y)
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
            Series { name, points: rs.iter().map(|r| (x(r), y(r))).collect() }
        })
        .collect()
}

/// Smallest error drawn on a log axis (lossless compressors sit at f32 rounding, ~1e-7).
pub const ERROR_FLOOR: f64 = 1e-9;

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

/// Tick values for a log axis over `[lo, hi]`: 1, 2 and 5 per decade when it spans at most
/// three decades (so a range of 2 to 6 ms is not left with one tick), else the decades.
pub fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && lo.is_finite() && hi.is_finite()) {
        return vec![];
    }
    let steps: &[f64] = if hi / lo <= 1e3 { &[1.0, 2.0, 5.0] } else { &[1.0] };
    let mut out = vec![];
    for e in lo.log10().floor() as i32..=hi.log10().ceil() as i32 {
        for &m in steps {
            let v = m * 10f64.powi(e);
            if v >= lo && v <= hi {
                out.push(v);
            }
        }
    }
    out
}

/// A log-log plot of `series` written to `path` (PNG, 800 x 560).
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
    let pts: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|(x, y)| x.is_finite() && y.is_finite() && *x > 0.0)
        .map(|(x, y)| (x, y.max(ERROR_FLOOR)))
        .collect();
    if pts.is_empty() {
        return Err("nothing to plot".into());
    }
    let span = |v: Vec<f64>| {
        let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        (lo / 2.0, hi * 2.0)
    };
    let (x0, x1) = span(pts.iter().map(|p| p.0).collect());
    let (y0, y1) = span(pts.iter().map(|p| p.1).collect());
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, (800, 560)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(48)
            .y_label_area_size(72)
            .build_cartesian_2d((x0..x1).log_scale().with_key_points(log_ticks(x0, x1)), (y0..y1).log_scale())
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .label_style(("sans-serif", 14))
            .x_labels(8)
            .y_labels(8)
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .draw()
            .map_err(|e| e.to_string())?;
        for (i, s) in series.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let points: Vec<(f64, f64)> = s
                .points
                .iter()
                .filter(|(x, y)| x.is_finite() && y.is_finite() && *x > 0.0)
                .map(|&(x, y)| (x, y.max(ERROR_FLOOR)))
                .collect();
            chart
                .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))
                .map_err(|e| e.to_string())?
                .label(s.name.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
            chart.draw_series(points.iter().map(|&p| Circle::new(p, 4, colour.filled()))).map_err(|e| e.to_string())?;
        }
        if let Some(g) = guide.filter(|g| g.y > y0 && g.y < y1) {
            let dashes: Vec<PathElement<(f64, f64)>> = (0..40)
                .map(|i| {
                    let at = |f: f64| x0 * (x1 / x0).powf(f);
                    PathElement::new(vec![(at(i as f64 / 40.0), g.y), (at((i as f64 + 0.5) / 40.0), g.y)], BLACK)
                })
                .collect();
            chart
                .draw_series(dashes)
                .map_err(|e| e.to_string())?
                .label(g.label.clone())
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 8, y), (x + 12, y), (x + 20, y)], BLACK));
            for (name, x) in &g.marks {
                let Some(i) = series.iter().position(|s| &s.name == name) else { continue };
                if *x > x0 && *x < x1 {
                    let colour = Palette99::pick(i).to_rgba();
                    chart.draw_series([Cross::new((*x, g.y), 7, colour.stroke_width(3))]).map_err(|e| e.to_string())?;
                }
            }
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    std::fs::rename(&tmp, path).map_err(|e| format!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    #[test]
    fn log_ticks_are_one_two_five_on_short_ranges() {
        use super::log_ticks;
        assert_eq!(log_ticks(1.5, 7.0), vec![2.0, 5.0]);
        let t = log_ticks(0.6, 35.0);
        assert_eq!(t.len(), 5, "{t:?}"); // 1 2 5 10 20
        assert!((t[4] - 20.0).abs() < 1e-9 && (t[0] - 1.0).abs() < 1e-12, "{t:?}");
        assert_eq!(log_ticks(1e-9, 1.0).len(), 10); // decades only
        assert!(log_ticks(0.0, 1.0).is_empty());
    }

    #[test]
    fn tick_labels_are_short() {
        use super::tick_label;
        let got: Vec<String> = [40.0, 2.5, 0.05, 0.125, 3e-4, 2e5, 1.0].iter().map(|&v| tick_label(v)).collect();
        assert_eq!(got, ["40", "2.5", "0.05", "0.125", "3e-4", "2e5", "1"]);
    }

    use super::*;

    #[test]
    fn writes_a_png_with_the_expected_size() {
        let dir = std::env::temp_dir().join(format!("biscale-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("p.png");
        let series = vec![
            Series { name: "haar".into(), points: vec![(1.0, 0.1), (2.0, 0.05), (4.0, 0.01)] },
            Series { name: "bicluster".into(), points: vec![(3.0, 0.0)] },
        ];
        log_log_plot(&p, "error against storage", "MB", "rel. error", &series).unwrap();
        let guide = Guide { y: 0.05, label: "target".into(), marks: vec![("haar".into(), 2.0)] };
        log_log_plot_with(&p, "with a guide", "MB", "rel. error", &series, Some(&guide)).unwrap();
        let img = image::open(&p).unwrap();
        assert_eq!((img.width(), img.height()), (800, 560));
        assert!(log_log_plot(&p, "t", "x", "y", &[]).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
