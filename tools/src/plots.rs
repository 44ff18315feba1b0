//! Report plots (PNG): error against gather time and error against storage, one curve per
//! compressor kind through its sweep points, and the image error of every compressor and
//! method against its storage. Text is drawn with the bundled DejaVu Sans
//! (assets/fonts), so plots look the same on machines without system fonts.

use crate::metrics::CompressorRecord;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
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

/// Height in pixels of the colour bar [`with_colour_bar`] puts under an error picture.
pub const COLOUR_BAR_HEIGHT: u32 = 60;

/// `picture` (a false-colour error map, [`biscale_shading::image::error_image`]) with its colour
/// bar below: the viridis ramp from 0 to `scale`, ticks at 0, half and full scale, and
/// `label` saying what is measured and in which unit (one or two lines, split at `\n`). The
/// bar is at least 300 pixels wide; a narrower picture is centred above it on white.
pub fn with_colour_bar(picture: &image::RgbImage, scale: f32, label: &str) -> Result<image::RgbImage, String> {
    register_font();
    let w = picture.width().max(300);
    let mut bar = vec![255u8; (w * COLOUR_BAR_HEIGHT * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut bar, (w, COLOUR_BAR_HEIGHT)).into_drawing_area();
        let (x0, x1) = (10i32, w as i32 - 10);
        let e = |e: DrawingAreaErrorKind<_>| e.to_string();
        for x in x0..x1 {
            let c = biscale_shading::image::viridis((x - x0) as f32 / (x1 - x0 - 1).max(1) as f32);
            root.draw(&Rectangle::new([(x, 3), (x + 1, 15)], RGBColor(c[0], c[1], c[2]).filled())).map_err(e)?;
        }
        for (frac, h) in [(0.0f32, HPos::Left), (0.5, HPos::Center), (1.0, HPos::Right)] {
            let x = x0 + ((x1 - x0 - 1) as f32 * frac).round() as i32;
            root.draw(&PathElement::new(vec![(x, 15), (x, 19)], BLACK)).map_err(e)?;
            let style = ("sans-serif", 12).into_font().color(&BLACK).pos(Pos::new(h, VPos::Top));
            root.draw(&Text::new(tick_label((scale * frac) as f64), (x, 20), style)).map_err(e)?;
        }
        for (i, line) in label.lines().take(2).enumerate() {
            let style = ("sans-serif", 12).into_font().color(&BLACK).pos(Pos::new(HPos::Center, VPos::Top));
            root.draw(&Text::new(line.to_string(), (w as i32 / 2, 33 + 13 * i as i32), style)).map_err(e)?;
        }
        root.present().map_err(|e| e.to_string())?;
    }
    let mut out = image::RgbImage::from_pixel(w, picture.height() + COLOUR_BAR_HEIGHT, image::Rgb([255, 255, 255]));
    image::imageops::replace(&mut out, picture, ((w - picture.width()) / 2) as i64, 0);
    let bar = image::RgbImage::from_raw(w, COLOUR_BAR_HEIGHT, bar).ok_or("colour bar buffer size")?;
    image::imageops::replace(&mut out, &bar, 0, picture.height() as i64);
    Ok(out)
}

#[cfg(test)]
mod tests {
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
    }

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
