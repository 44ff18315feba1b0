//! Bar charts of a transfer matrix and its biclusters: bicluster sizes (rows r, columns l)
//! and values (of `T`, and of the biclusters' column constants), log-scaled counts.

use super::raster::{fmt_value, text, Canvas};
use super::{draw_err, Result};
use biscale_compressors::bicluster::{BiclusterView, Distribution};
use biscale_core::compress::CompressedForm;
use biscale_core::transfer::TransferMatrix;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::{Path, PathBuf};

/// Size of the histogram pictures: two charts side by side.
pub const HISTOGRAM_SIZE: (u32, u32) = (1100, 460);

/// One bar: label under it, count, colour.
pub(super) struct Bar {
    label: String,
    count: u64,
    colour: RGBColor,
}

/// A bar chart with a log count axis on `area`.
fn bar_chart(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    bars: &[Bar],
) -> Result<()> {
    if bars.is_empty() {
        let (w, h) = area.dim_in_pixel();
        return text(
            area,
            &format!("{title}: nothing to show"),
            w as i32 / 2,
            h as i32 / 2,
            16,
            Pos::new(HPos::Center, VPos::Center),
        );
    }
    let max = bars.iter().map(|b| b.count).max().unwrap_or(1).max(1) as f64;
    let nb = bars.len() as u32;
    // Bars start at 0.5 so that a count of 1 still shows on the log axis.
    let base = 0.5f64;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(58)
        .y_label_area_size(70)
        .build_cartesian_2d((0u32..nb - 1).into_segmented(), (base..max * 2.0).log_scale())
        .map_err(draw_err)?;
    // At most ~14 labels: every `step`-th bar.
    let step = (bars.len()).div_ceil(14);
    let labels: Vec<String> =
        bars.iter().enumerate().map(|(i, b)| if i % step == 0 { b.label.clone() } else { String::new() }).collect();
    let label_size = if nb > 8 { 11 } else { 13 };
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_labels(nb as usize)
        .x_label_style(("sans-serif", label_size))
        .y_label_style(("sans-serif", 13))
        .axis_desc_style(("sans-serif", 14))
        .x_label_formatter(&|v| match v {
            SegmentValue::CenterOf(i) => labels.get(*i as usize).cloned().unwrap_or_default(),
            _ => String::new(),
        })
        .y_label_formatter(&|v| if *v >= 1.0 { format!("{v:.0}") } else { String::new() })
        .draw()
        .map_err(draw_err)?;
    chart
        .draw_series(bars.iter().enumerate().filter(|(_, b)| b.count > 0).map(|(i, b)| {
            let (x0, x1) = (SegmentValue::Exact(i as u32), SegmentValue::Exact(i as u32 + 1));
            let mut r = Rectangle::new([(x0, base), (x1, b.count as f64)], b.colour.filled());
            r.set_margin(0, 0, 3, 3);
            r
        }))
        .map_err(draw_err)?;
    Ok(())
}

fn two_charts(
    path: &Path,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>, &DrawingArea<BitMapBackend<'_>, Shift>) -> Result<()>,
) -> Result<PathBuf> {
    let (w, h) = HISTOGRAM_SIZE;
    Canvas::new(w, h).finish(path, |root| {
        let (left, right) = root.split_horizontally((w / 2) as i32);
        draw(&left, &right)
    })
}

pub(super) fn log2_bars(values: &[u64], colour: RGBColor) -> Vec<Bar> {
    Distribution::of(values)
        .histogram
        .iter()
        .map(|&(lo, hi, count)| Bar {
            label: if lo == hi { format!("{lo}") } else { format!("{lo}-{hi}") },
            count,
            colour,
        })
        .collect()
}

/// Histograms of the bicluster sizes of `form`: rows r (left) and columns l (right) per
/// bicluster, power-of-two bins (1, 2-3, 4-7, ...), log-scaled counts; written as a PNG of
/// [`HISTOGRAM_SIZE`] at `path`. Returns `path`.
pub fn write_bicluster_size_histograms(form: &CompressedForm, path: &Path) -> Result<PathBuf> {
    let bv = BiclusterView::new(form)?;
    let r: Vec<u64> = bv.bicluster_rows().into_iter().map(u64::from).collect();
    let l: Vec<u64> = bv.bc_col_ptr.windows(2).map(|w| (w[1] - w[0]) as u64).collect();
    let (dr, dl) = (Distribution::of(&r), Distribution::of(&l));
    two_charts(path, |left, right| {
        bar_chart(
            left,
            &format!("rows r per bicluster ({} biclusters, mean {:.1}, max {})", r.len(), dr.mean, dr.max),
            "r (rows = vertices x local bins)",
            "biclusters",
            &log2_bars(&r, RGBColor(70, 130, 220)),
        )?;
        bar_chart(
            right,
            &format!("columns l per bicluster (mean {:.1}, max {})", dl.mean, dl.max),
            "l (cubemap texels)",
            "biclusters",
            &log2_bars(&l, RGBColor(230, 140, 40)),
        )
    })
}

/// Bars for the values `xs`: one per distinct value when there are at most 24 of them (the
/// reference `T` has four: 1/4, 1/2, 3/4, 1), else 24 equal-width bins.
pub(super) fn value_bars(xs: &[f32], colour: RGBColor) -> Vec<Bar> {
    let mut s: Vec<f32> = xs.iter().copied().filter(|x| x.is_finite()).collect();
    s.sort_by(f32::total_cmp);
    let mut distinct: Vec<(f32, u64)> = vec![];
    for &x in &s {
        match distinct.last_mut() {
            Some(d) if d.0 == x => d.1 += 1,
            _ => distinct.push((x, 1)),
        }
    }
    let fmt = |x: f32| {
        let t = format!("{x:.3}");
        let t = t.trim_end_matches('0').trim_end_matches('.');
        if t == "-0" {
            "0".to_string()
        } else {
            t.to_string()
        }
    };
    if distinct.len() <= 24 {
        return distinct.into_iter().map(|(x, count)| Bar { label: fmt(x), count, colour }).collect();
    }
    let (lo, hi) = (s[0], s[s.len() - 1]);
    let nb = 24usize;
    let width = (hi - lo) / nb as f32;
    let mut counts = vec![0u64; nb];
    for &x in &s {
        counts[(((x - lo) / width) as usize).min(nb - 1)] += 1;
    }
    counts
        .into_iter()
        .enumerate()
        .map(|(i, count)| {
            let centre = lo + (i as f32 + 0.5) * width;
            Bar { label: fmt(centre), count, colour }
        })
        .collect()
}

/// One bar per integer code from the smallest to the largest of `codes`, labelled `code / q`.
pub(super) fn code_bars(codes: &[i8], q: u32) -> Vec<Bar> {
    let (lo, hi) = codes.iter().fold((i32::MAX, i32::MIN), |(a, b), &c| (a.min(c as i32), b.max(c as i32)));
    if lo > hi {
        return vec![];
    }
    let mut counts = vec![0u64; (hi - lo + 1) as usize];
    for &c in codes {
        counts[(c as i32 - lo) as usize] += 1;
    }
    counts
        .into_iter()
        .enumerate()
        .map(|(i, count)| {
            let code = lo + i as i32;
            let colour = if code < 0 { RGBColor(230, 120, 30) } else { RGBColor(70, 130, 220) };
            Bar { label: fmt_value(code as f64 / q as f64), count, colour }
        })
        .collect()
}

/// Histograms of the values of `T`'s non-zeros (left) and, with a bicluster `form`, of its
/// column constants `code / q` over all biclusters (right: one count per stored constant;
/// negative ones, in orange, are residual corrections of earlier biclusters); log-scaled
/// counts; a PNG of [`HISTOGRAM_SIZE`] at `path`. Returns `path`.
pub fn write_value_histograms(t: &TransferMatrix, form: Option<&CompressedForm>, path: &Path) -> Result<PathBuf> {
    let values: Vec<f32> = t.csr().data().iter().copied().filter(|&v| v != 0.0).collect();
    let consts = match form {
        Some(f) => {
            let bv = BiclusterView::new(f)?;
            Some((bv.bc_vals.to_vec(), bv.value_scale))
        }
        None => None,
    };
    two_charts(path, |left, right| {
        bar_chart(
            left,
            &format!("values of T ({} non-zeros)", values.len()),
            "visibility fraction",
            "entries",
            &value_bars(&values, RGBColor(110, 110, 110)),
        )?;
        match &consts {
            Some((c, q)) => bar_chart(
                right,
                &format!("bicluster column constants ({} stored, q = {q})", c.len()),
                "constant = code / q (negative: residual corrections)",
                "constants",
                &code_bars(c, *q),
            ),
            None => {
                let (w, h) = right.dim_in_pixel();
                text(
                    right,
                    "no bicluster form given",
                    w as i32 / 2,
                    h as i32 / 2,
                    16,
                    Pos::new(HPos::Center, VPos::Center),
                )
            }
        }
    })
}
