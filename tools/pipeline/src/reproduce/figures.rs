//! The paper's figures as `biscale reproduce` makes them: panels (images the runs wrote, or
//! `biscale viz`'s pictures) copied into `figures/<id>/`, each set under one caption, written
//! as a LaTeX `figure*` (`figures/<id>.tex`, needs `graphicx`) and embedded in `index.html` as
//! data URIs, so the page stays one file.

use super::tables::{html_escape, html_text, latex_caption, latex_escape};
use crate::error::{io_err, PipelineError, Result};
use std::fmt::Write;
use std::path::Path;

/// The width in pixels of a figure's own colour bar ([`FigureSet::add_colour_bar`]), about
/// the page's, and the height of its text: at a 17 cm text width the text is about 8 pt.
pub const COLOUR_BAR_WIDTH: u32 = 1200;
pub const COLOUR_BAR_FONT: u32 = 20;

/// One picture of a figure.
#[derive(Clone, Debug, PartialEq)]
pub struct Panel {
    /// Where it is in the output folder: `figures/<id>/<name>.png`; empty for a spacer (an
    /// empty place in a row, [`FigureSet::spacer`]).
    pub file: String,
    pub label: String,
    /// Where it was copied from, relative to the output folder (`runs/<run>/images/...`).
    pub source: String,
    /// Across the whole figure on a row of its own (a plot under the images).
    pub wide: bool,
}

/// A figure of the paper: its panels under one caption.
#[derive(Clone, Debug, PartialEq)]
pub struct FigureSet {
    /// The item (`--only`'s name).
    pub item: String,
    /// `figures/<id>/`, `figures/<id>.tex`.
    pub id: String,
    pub title: String,
    pub caption: String,
    /// Panels per row in the page and the LaTeX.
    pub per_row: usize,
    pub panels: Vec<Panel>,
}

impl FigureSet {
    pub fn new(item: &str, id: &str, title: impl Into<String>, caption: impl Into<String>, per_row: usize) -> Self {
        Self {
            item: item.into(),
            id: id.into(),
            title: title.into(),
            caption: caption.into(),
            per_row: per_row.max(1),
            panels: vec![],
        }
    }

    /// An empty place in the row (under a panel that has nothing below it).
    pub fn spacer(&mut self) {
        self.panels.push(Panel { file: String::new(), label: String::new(), source: String::new(), wide: false });
    }

    /// The panels that are pictures (not spacers).
    pub fn pictures(&self) -> impl Iterator<Item = &Panel> {
        self.panels.iter().filter(|p| !p.file.is_empty())
    }

    /// A panel's file `figures/<id>/<name>.png` (relative to `out`) and its path, its folder
    /// made.
    fn destination(&self, out: &Path, name: &str) -> Result<(String, std::path::PathBuf)> {
        let file = format!("figures/{}/{name}.png", self.id);
        let dst = out.join(&file);
        let dir = dst.parent().expect("a file under figures/");
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        Ok((file, dst))
    }

    /// Copy `from` (relative to the output folder `out`) into `figures/<id>/<name>.png` and add
    /// it as a panel.
    pub fn add(&mut self, out: &Path, from: &str, name: &str, label: impl Into<String>) -> Result<()> {
        let src = out.join(from);
        if !src.is_file() {
            return Err(PipelineError::Mismatch {
                path: src,
                what: format!("figure {} needs this image, which its run did not write", self.id),
            });
        }
        let (file, dst) = self.destination(out, name)?;
        if src != dst {
            std::fs::copy(&src, &dst).map_err(io_err(&dst))?;
        }
        self.panels.push(Panel { file, label: label.into(), source: from.into(), wide: false });
        Ok(())
    }

    /// [`Self::add`] for an error figure whose panels share one scale: the run's picture
    /// without its colour bar (one bar for the figure follows, [`Self::add_colour_bar`]).
    pub fn add_error(&mut self, out: &Path, from: &str, name: &str, label: impl Into<String>) -> Result<()> {
        let src = out.join(from);
        let mismatch = |path: &Path, what: String| PipelineError::Mismatch { path: path.to_path_buf(), what };
        let figure = image::open(&src)
            .map_err(|e| mismatch(&src, format!("figure {} needs this error image: {e}", self.id)))?
            .into_rgb8();
        let picture = crate::plots::without_colour_bar(&figure).map_err(|what| mismatch(&src, what))?;
        let (file, dst) = self.destination(out, name)?;
        biscale_core::scene::image::write_rgb8_png(&picture, &dst)?;
        self.panels.push(Panel { file, label: label.into(), source: from.into(), wide: false });
        Ok(())
    }

    /// The figure's one colour bar, 0 to `scale`, across it on a row of its own
    /// (`figures/<id>/colour-bar.png`): its text is sized for the figure's width
    /// ([`COLOUR_BAR_FONT`] pixels in [`COLOUR_BAR_WIDTH`]), so it stays readable in print.
    pub fn add_colour_bar(&mut self, out: &Path, scale: f32, label: &str) -> Result<()> {
        let (file, dst) = self.destination(out, "colour-bar")?;
        let bar = crate::plots::colour_bar(COLOUR_BAR_WIDTH, COLOUR_BAR_FONT, scale, label)
            .map_err(|what| PipelineError::Mismatch { path: dst.clone(), what })?;
        biscale_core::scene::image::write_rgb8_png(&bar, &dst)?;
        let source = format!("drawn by biscale reproduce (full scale {scale:.3e})");
        self.panels.push(Panel { file, label: String::new(), source, wide: true });
        Ok(())
    }

    /// [`Self::add`] across the whole figure, on a row of its own.
    pub fn add_wide(&mut self, out: &Path, from: &str, name: &str, label: impl Into<String>) -> Result<()> {
        self.add(out, from, name, label)?;
        if let Some(p) = self.panels.last_mut() {
            p.wide = true;
        }
        Ok(())
    }
}

/// `figures/<id>.tex`: a `figure*` with one `\includegraphics` per panel, labelled, and the
/// caption.
pub fn latex(f: &FigureSet) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "% Written by `biscale reproduce`; needs \\usepackage{{graphicx}}. Paths relative to the output folder."
    );
    let _ = writeln!(s, "\\begin{{figure*}}[t]\n\\centering");
    let width = 0.98 / f.per_row as f64;
    for (i, p) in f.panels.iter().enumerate() {
        if p.wide {
            // A line break after an empty label would end no line: LaTeX stops there.
            let _ = match p.label.is_empty() {
                true => writeln!(s, "\\par\\includegraphics[width=\\linewidth]{{{}}}\\par\\smallskip", p.file),
                false => writeln!(
                    s,
                    "\\par\\includegraphics[width=\\linewidth]{{{}}}\\\\\\footnotesize {}\\\\[2pt]",
                    p.file,
                    latex_escape(&p.label)
                ),
            };
            continue;
        }
        let end = if (i + 1) % f.per_row == 0 { "\\\\[2pt]" } else { "\\hfill" };
        let _ = match p.file.is_empty() {
            true => writeln!(s, "\\begin{{minipage}}[t]{{{width:.3}\\textwidth}}\\mbox{{}}\\end{{minipage}}{end}"),
            false => writeln!(
                s,
                "\\begin{{minipage}}[t]{{{width:.3}\\textwidth}}\\centering\\includegraphics[width=\\linewidth]{{{}}}\\\\\\footnotesize {}\\end{{minipage}}{end}",
                p.file,
                latex_escape(&p.label),
            ),
        };
    }
    let _ = writeln!(s, "\\caption{{{}}}", latex_caption(&f.title, &latex_escape(&f.caption.replace('`', ""))));
    let _ = writeln!(s, "\\label{{fig:reproduce-{}}}\n\\end{{figure*}}", f.id);
    s
}

/// The figure as HTML, every panel embedded as a data URI read from the output folder.
pub fn html(f: &FigureSet, out: &Path) -> Result<String> {
    let mut s = String::new();
    let _ = writeln!(s, "<h2 id=\"{}\">{}</h2>\n<figure>", html_escape(&f.id), html_escape(&f.title));
    let width = 100.0 / f.per_row as f64 - 1.0;
    for p in &f.panels {
        if p.file.is_empty() {
            let _ = writeln!(s, "<div class=\"panel\" style=\"width:{width:.1}%\"></div>");
            continue;
        }
        let path = out.join(&p.file);
        let bytes = biscale_core::io::read_regular(&path, 256 << 20, "figure panel").map_err(io_err(&path))?;
        let width = if p.wide { 99.0 } else { width };
        let _ = writeln!(
            s,
            "<div class=\"panel\" style=\"width:{width:.1}%\"><img src=\"data:image/png;base64,{}\" alt=\"{}\" title=\"{}\"><br>{}</div>",
            crate::html::base64(&bytes),
            html_escape(&p.label),
            html_escape(&p.file),
            html_escape(&p.label)
        );
    }
    let _ = writeln!(s, "<figcaption>{}</figcaption>\n</figure>", html_text(&f.caption));
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn panels_are_copied_and_written_both_ways() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        std::fs::create_dir_all(out.join("runs/a/images")).unwrap();
        std::fs::write(out.join("runs/a/images/x.png"), b"\x89PNG fake").unwrap();
        let mut f = FigureSet::new("fig7", "fig7", "Fig. 7", "The temple & `five` BTFs", 2);
        f.add(out, "runs/a/images/x.png", "bicluster", "lossless_bicluster").unwrap();
        assert_eq!(std::fs::read(out.join("figures/fig7/bicluster.png")).unwrap(), b"\x89PNG fake");
        let e = f.add(out, "runs/a/images/missing.png", "m", "m").unwrap_err().to_string();
        assert!(e.contains("missing.png") && e.contains("fig7"), "{e}");
        assert_eq!(f.panels.len(), 1);
        f.spacer();
        assert_eq!((f.panels.len(), f.pictures().count()), (2, 1));
        let tex = latex(&f);
        assert!(tex.contains("\\includegraphics[width=\\linewidth]{figures/fig7/bicluster.png}"), "{tex}");
        assert!(tex.contains("lossless\\_bicluster") && tex.contains("The temple \\& five BTFs"), "{tex}");
        let h = html(&f, out).unwrap();
        assert!(h.contains("data:image/png;base64,iVBORyBmYWtl"), "{h}");
        assert!(h.contains("<figcaption>The temple &amp; <code>five</code> BTFs</figcaption>"), "{h}");
        assert!(tex.contains("\\mbox{}") && h.contains("style=\"width:49.0%\"></div>"), "a spacer: {tex} {h}");
        f.add_wide(out, "runs/a/images/x.png", "plot", "the plot").unwrap();
        let (tex, h) = (latex(&f), html(&f, out).unwrap());
        assert!(tex.contains("\\par\\includegraphics[width=\\linewidth]{figures/fig7/plot.png}"), "{tex}");
        assert!(h.contains("style=\"width:99.0%\"><img"), "{h}");
        // A colour bar has no label, and so no line break after it (pdflatex refuses one).
        f.add_colour_bar(out, 0.5, "luminance").unwrap();
        let tex = latex(&f);
        let bar = tex.lines().find(|l| l.contains("colour-bar.png")).unwrap();
        assert_eq!(bar, "\\par\\includegraphics[width=\\linewidth]{figures/fig7/colour-bar.png}\\par\\smallskip");
    }
}
