//! The run's report as one document model ([`document`]): headings, paragraphs, lists,
//! preformatted text, [`Table`]s and figures, rendered twice, as Markdown (`report.md`,
//! [`markdown`]) and as one self-contained HTML page (`report.html`, `crate::html`). Every
//! table of both files is a [`Table`] (header and rows of cells), so the two print the same
//! numbers. Readable without the program.

use crate::metrics::{CompressorRecord, Metrics, Timing, TransferMetrics, NOISY_SPREAD};
use biscale_compressors::registry::{self, Role};
use std::fmt::Write;

/// One piece of a table cell.
#[derive(Clone, Debug, PartialEq)]
pub enum Inline {
    Text(String),
    Code(String),
    Link {
        text: String,
        href: String,
    },
    /// An image of the output folder (path relative to it): a Markdown image, embedded in
    /// the HTML page.
    Image {
        src: String,
        alt: String,
    },
    /// A line break inside the cell.
    Break,
}

/// A table cell: its pieces in order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cell(pub Vec<Inline>);

impl From<String> for Cell {
    fn from(s: String) -> Self {
        Cell(vec![Inline::Text(s)])
    }
}

impl From<&str> for Cell {
    fn from(s: &str) -> Self {
        Cell(vec![Inline::Text(s.to_string())])
    }
}

impl Cell {
    pub fn image(src: &str, alt: &str) -> Self {
        Cell(vec![Inline::Image { src: src.to_string(), alt: alt.to_string() }])
    }

    /// The cell's text without markup (images by their alt text).
    pub fn plain(&self) -> String {
        self.0
            .iter()
            .map(|i| match i {
                Inline::Text(t) | Inline::Code(t) => t.clone(),
                Inline::Link { text, .. } => text.clone(),
                Inline::Image { alt, .. } => alt.clone(),
                Inline::Break => " ".into(),
            })
            .collect()
    }

    /// The cell as Markdown: `|` escaped, images and links in Markdown's syntax, breaks as
    /// `<br>` (a pipe table's cell is one line).
    pub fn markdown(&self) -> String {
        self.0
            .iter()
            .map(|i| match i {
                Inline::Text(t) => t.replace('|', "\\|"),
                Inline::Code(t) => format!("`{}`", t.replace('|', "\\|")),
                Inline::Link { text, href } => format!("[{}]({href})", text.replace('|', "\\|")),
                Inline::Image { src, alt } => format!("![{}]({src})", alt.replace('|', "\\|")),
                Inline::Break => "<br>".into(),
            })
            .collect()
    }
}

/// A table of both reports: its header and one row of cells per line.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    pub header: Vec<String>,
    pub rows: Vec<Vec<Cell>>,
    /// A class for the HTML page's styling (`figures`: a table of images drawn full width;
    /// `thumbnails`: small images).
    pub class: Option<&'static str>,
}

impl Table {
    pub fn new(header: &[&str]) -> Self {
        Table { header: header.iter().map(|h| h.to_string()).collect(), rows: vec![], class: None }
    }

    /// Append a row of text cells.
    pub fn text_row<S: Into<String>>(&mut self, cells: impl IntoIterator<Item = S>) {
        self.rows.push(cells.into_iter().map(|c| Cell::from(c.into())).collect());
    }

    /// The table as a Markdown pipe table (header, rule, rows), ending in a newline.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let head: Vec<String> = self.header.iter().map(|h| h.replace('|', "\\|")).collect();
        let _ = writeln!(s, "| {} |\n|{}", head.join(" | "), "---|".repeat(self.header.len()));
        for row in &self.rows {
            let cells: Vec<String> = row.iter().map(Cell::markdown).collect();
            let _ = writeln!(s, "| {} |", cells.join(" | "));
        }
        s
    }
}

/// An image shown as a figure: its file (relative to the output folder), caption, and a
/// file the figure links to (a plot's SVG).
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    pub src: String,
    pub caption: String,
    pub link: Option<String>,
}

impl Figure {
    fn new(src: impl Into<String>, caption: impl Into<String>) -> Self {
        Figure { src: src.into(), caption: caption.into(), link: None }
    }
}

/// One block of the report.
#[derive(Clone, Debug, PartialEq)]
pub enum Block {
    /// A heading of level 1..3.
    Heading(u8, String),
    /// A paragraph of Markdown inline text: `` `code` `` and `[text](link)` are marked up.
    Para(String),
    /// A bulleted list of inline texts like [`Block::Para`]'s.
    List(Vec<String>),
    /// Preformatted text (the plan).
    Pre(String),
    Table(Table),
    /// Figures side by side, or one under the other across the page (`wide`: the plots).
    Figures {
        figures: Vec<Figure>,
        wide: bool,
    },
}

/// The report of a run: `plan` is the plan's text, `plots` the plots written (PNG path
/// relative to the output folder, caption; each has an SVG twin beside it).
pub fn document(m: &Metrics, plan: &str, plots: &[(String, String)]) -> Vec<Block> {
    let mut d = vec![];
    let para = |d: &mut Vec<Block>, s: String| d.push(Block::Para(s));
    d.push(Block::Heading(1, format!("biscale run: {}", m.experiment)));
    para(&mut d, format!("Config `{}`, backend {}.", m.config, m.backend));
    if let Some(w) = timing_warning(m) {
        para(&mut d, format!("Warning: {w}."));
    }
    if let Some(r) = &m.run {
        para(&mut d, format!("Run: {}.", r.summary()));
        let mut t = Table::new(&["stage", "wall s", "CPU s"]);
        for s in &r.stages {
            let cpu = s.cpu_seconds.map_or("?".into(), |c| format!("{c:.2}"));
            t.text_row([s.stage.clone(), format!("{:.2}", s.wall_seconds), cpu]);
        }
        d.push(Block::Table(t));
    }
    d.push(Block::Pre(plan.to_string()));

    d.push(Block::Heading(2, "Scene".into()));
    let mut items = vec![format!(
        "mesh `{}`: {} vertices, {} triangles; material {}",
        m.scene.mesh, m.scene.vertices, m.scene.triangles, m.scene.material
    )];
    items.extend(m.scene.repairs.iter().map(|r| format!("repair: {r}")));
    items.extend(m.scene.material_notes.iter().map(|n| format!("materials: {n}")));
    items.push(format!(
        "light: {} at 6x{r}x{r}, rotated {}°, total power (RGB) {:.4} {:.4} {:.4}",
        m.lighting.source,
        m.lighting.rotation_degrees,
        m.lighting.total_power[0],
        m.lighting.total_power[1],
        m.lighting.total_power[2],
        r = m.lighting.cubemap_resolution
    ));
    d.push(Block::List(items));
    if let Some(b) = btf_table(m) {
        d.push(Block::Heading(3, "BTFs".into()));
        d.push(Block::Table(b.table));
        para(&mut d, b.total);
        d.push(Block::Figures { figures: b.figures, wide: false });
    }

    let t = &m.transfer;
    d.push(Block::Heading(2, "Transfer matrix".into()));
    para(&mut d, transfer_summary(t));
    let mut hist = Table::new(&["value", "count"]);
    for v in &t.value_histogram {
        hist.text_row([v.value.to_string(), v.count.to_string()]);
    }
    d.push(Block::Table(hist));

    d.push(Block::Heading(2, "Compressors".into()));
    let u = &m.uncompressed;
    para(
        &mut d,
        format!(
            "Uncompressed `T L`: gather {} ms (f64 reference{}), shade {} ms. {}",
            timing_cell(u.gather_ms, u.gather_timing.as_ref(), 2),
            match m.sharded.as_ref().is_some_and(|s| s.streamed) {
                true => ": the products over the shards' parts of T summed, reading the files left out",
                false => "",
            },
            timing_cell(u.shade_ms, u.shade_timing.as_ref(), 1),
            timing_note(m)
        ),
    );
    d.push(Block::Table(compressor_table(m)));
    para(&mut d, LDR_NOTE.into());
    if let Some(t) = statistics_table(m) {
        d.push(Block::Heading(3, "What each compressor reports of its form".into()));
        d.push(Block::Table(t));
    }
    if let Some(g) = gpu_table(m) {
        d.push(Block::Heading(3, g.0));
        d.push(Block::Table(g.1));
    }
    d.extend(frame_model_blocks(m));
    if let Some(r) = &m.reference {
        para(
            &mut d,
            format!(
                "Ground truth (direct light) traced per pixel at {}x{} in {:.1} s{} (each pixel's own visibility, each \
                 texel's own cosine, the BRDF at each texel's own direction). Uncompressed vertex render against it: \
                 RMSE {:.4}, PSNR {:.2} dB, rel. L2 {:.4}; LDR PSNR / SSIM / FLIP {}.",
                r.width,
                r.height,
                r.seconds,
                if r.cached { " (cached)" } else { "" },
                r.uncompressed_vs_reference.rmse,
                r.uncompressed_vs_reference.psnr,
                r.uncompressed_vs_reference.rel_l2,
                ldr_cell(&r.uncompressed_vs_reference)
            ),
        );
    }
    para(&mut d, light_moments_summary(m));
    d.extend(comparisons(m));
    d.extend(low_vs_all_blocks(m));
    d.extend(animation_blocks(m));
    d.extend(comparison_rows(m));
    if !plots.is_empty() {
        d.push(Block::Heading(2, "Plots".into()));
        para(
            &mut d,
            "Every point is labelled with its setting (without its kind, which the legend gives by colour); \
             each plot links to its SVG."
                .into(),
        );
        let figures = plots
            .iter()
            .map(|(png, caption)| Figure { src: png.clone(), caption: caption.clone(), link: Some(svg_twin(png)) })
            .collect();
        d.push(Block::Figures { figures, wide: true });
    }
    d
}

/// The SVG written beside a plot's PNG.
pub fn svg_twin(png: &str) -> String {
    match png.strip_suffix(".png") {
        Some(stem) => format!("{stem}.svg"),
        None => format!("{png}.svg"),
    }
}

/// The run's Markdown report (`report.md`): [`document`] as Markdown.
pub fn markdown(m: &Metrics, plan: &str, plots: &[(String, String)]) -> String {
    markdown_of(document(m, plan, plots))
}

/// Blocks of the document model as Markdown.
pub fn markdown_of(blocks: Vec<Block>) -> String {
    let mut s = String::new();
    for block in blocks {
        match block {
            Block::Heading(level, text) => {
                let _ = writeln!(s, "{} {text}\n", "#".repeat(level.clamp(1, 6) as usize));
            }
            Block::Para(text) => {
                let _ = writeln!(s, "{text}\n");
            }
            Block::List(items) => {
                for i in items {
                    let _ = writeln!(s, "- {i}");
                }
                s.push('\n');
            }
            Block::Pre(text) => {
                let _ = writeln!(s, "```\n{}\n```\n", text.trim_end());
            }
            Block::Table(t) => {
                let _ = writeln!(s, "{}", t.markdown());
            }
            Block::Figures { figures, .. } => {
                for f in figures {
                    match &f.link {
                        Some(link) => {
                            let _ = writeln!(
                                s,
                                "[![{}]({})]({link})\n\n*{}* ([SVG]({link}))\n",
                                f.caption, f.src, f.caption
                            );
                        }
                        None => {
                            let _ = writeln!(s, "![{}]({})\n", f.caption, f.src);
                        }
                    }
                }
            }
        }
    }
    s
}

/// The wgpu table: its heading and table, when the run used the GPU backend.
fn gpu_table(m: &Metrics) -> Option<(String, Table)> {
    let adapter = m.compressors.iter().find_map(|c| c.gpu.as_ref())?.adapter.clone();
    let ranged = m.compressors.iter().filter_map(|c| c.gpu.as_ref()).any(|g| ranged(&[&g.gather_timing]));
    let mut t = Table::new(&[
        "setting",
        ms_header("gather", ranged),
        ms_header("shade", ranged),
        "timing",
        "rel. err L*",
        "image rel. L2 vs CPU",
        "coverage mismatches",
    ]);
    for c in &m.compressors {
        if let Some(g) = &c.gpu {
            t.text_row([
                c.name.clone(),
                timing_cell(g.gather_ms, g.gather_timing.as_ref(), 2),
                timing_cell(g.shade_ms, g.shade_timing.as_ref(), 2),
                g.timing.clone(),
                format!("{:.2e}", g.rel_error_lstar),
                format!("{:.2e}", g.image_vs_cpu.rel_l2),
                g.coverage_mismatch.to_string(),
            ]);
        }
    }
    Some((format!("wgpu backend ({adapter})"), t))
}

/// The frame-time model's section (`metrics.json`'s `frame_model`): each form's gather and
/// shade, counted, measured, floored here and projected; a projected figure is labelled a
/// floor (its frame rate a ceiling) and kept out of the measured columns.
fn frame_model_blocks(m: &Metrics) -> Vec<Block> {
    let Some(f) = &m.frame_model else { return vec![] };
    let (here, proj) = (&f.machine, &f.projection);
    let lavapipe = m.compressors.iter().filter_map(|c| c.gpu.as_ref()).any(|g| g.adapter.contains("llvmpipe"));
    let mut blocks = vec![
        Block::Heading(3, "Frame-time model".into()),
        Block::Para(format!(
            "Per frame at {}x{}, {} sample(s) per pixel, moments resolved {}: the bytes each stage must move and \
             the flops it must do (`biscale_shading::frame_model`), and its floor `max(bytes / bandwidth, flops / \
             peak)`. Here: {} at {:.1} GB/s and {:.1} GFLOP/s fp32 ({}). Projected: {} at {:.0} GB/s and {:.0} \
             GFLOP/s ({}). A projected time is a floor, a lower bound, so the frame rate it implies is a ceiling; \
             it is never a measurement.{}",
            f.width,
            f.height,
            f.samples_per_pixel,
            f.resolve.name(),
            here.name,
            here.bandwidth_gb_s,
            here.peak_gflop_s,
            here.source,
            proj.name,
            proj.bandwidth_gb_s,
            proj.peak_gflop_s,
            proj.source,
            match lavapipe {
                true => " The GPU times are lavapipe's, on this machine's CPU, so they share its floor.",
                false => "",
            }
        )),
    ];
    let mut t = Table::new(&[
        "setting",
        "stage",
        "MB",
        "Gflop",
        "CPU ms (x floor)",
        "GPU ms (x floor)",
        "floor here ms",
        "projected floor ms",
    ]);
    let ratio = |ms: Option<f64>, floor: f64, shown: bool| match ms {
        Some(ms) if shown && floor > 0.0 => format!("{} ({:.1}x)", short_ms(ms), ms / floor),
        Some(ms) => short_ms(ms),
        None => "-".into(),
    };
    let mut ceilings = Table::new(&[
        "setting",
        "light change, run size (fps ceiling)",
        "view change, run size (fps ceiling)",
        "light change, 1920x1080 (fps ceiling)",
        "view change, 1920x1080 (fps ceiling)",
    ]);
    for form in &f.forms {
        for s in [&form.gather, &form.shade] {
            t.text_row([
                form.name.clone(),
                s.stage.clone(),
                format!("{:.2}", s.bytes / 1e6),
                format!("{:.3}", s.flops / 1e9),
                ratio(s.cpu_ms, s.floor_ms, true),
                ratio(s.gpu_ms, s.floor_ms, lavapipe),
                format!("{:.3}", s.floor_ms),
                format!("{:.4}", s.projected_ms),
            ]);
        }
        let fps = |ms: f64| format!("{:.0}", 1e3 / ms);
        let (g, v, hd) = (form.gather.projected_ms, form.shade.projected_ms, form.shade_1080p_projected_ms);
        ceilings.text_row([form.name.clone(), fps(g + v), fps(v), fps(g + hd), fps(hd)]);
    }
    blocks.push(Block::Table(t));
    blocks.push(Block::Para(format!(
        "Projected on the {} (floors, so these frame rates are ceilings, not measurements):",
        proj.name
    )));
    blocks.push(Block::Table(ceilings));
    blocks
}

/// What the comparison's figures show: their colour scales, the inset and the exposure.
fn comparison_text(m: &Metrics) -> String {
    use crate::plots::tick_label;
    let figures = m.figures.as_ref();
    let mut text = String::new();
    if let Some(scale) = m.compressors.iter().find_map(|c| c.image.error_scale) {
        let _ = write!(
            text,
            "Every compressor's error figure has one colour scale, full scale {} (luminance of |error| against the \
             uncompressed render, linear radiance; `[report] error_scale` fixes it).",
            tick_label(scale as f64)
        );
    }
    if let Some(scale) = m.methods.iter().find_map(|c| c.record.image.error_scale) {
        let _ = write!(
            text,
            " The methods' error figures share another, full scale {}: their errors are of another size.",
            tick_label(scale as f64)
        );
    }
    if let Some(s) = figures.and_then(|f| f.reference_error_scale) {
        let _ = write!(
            text,
            " Errors against the ground truth (at its resolution) share the full scale {}, the largest of their own \
             99th percentiles.",
            tick_label(s as f64)
        );
    }
    if let Some(f) = figures {
        let [x, y, w, h] = f.inset;
        let _ = write!(
            text,
            " Inset: the {w}x{h} pixels at ({x}, {y}) ({}), magnified {}x by nearest neighbour and marked in red on \
             every image.",
            f.inset_from, f.inset_magnification
        );
    }
    if let Some(t) = &m.tone_map {
        let _ = write!(
            text,
            " Every image is tone mapped at {:+.1} stops ({}), which clips {:.1}% of the uncompressed render's mesh              pixels{}.",
            t.exposure,
            match t.auto {
                true => "`[report] exposure = \"auto\"`: the 99th percentile of the mesh's pixels at white",
                false => "`[report] exposure`",
            },
            100.0 * t.clipped,
            match t.clipped > 0.1 {
                true => ". Warning: the renders saturate there and their insets may show nothing; `exposure = \
                         \"auto\"` would choose one that clips at most 1%",
                false => "",
            }
        );
    }
    text
}

/// The comparison section: one row per image (the uncompressed render, every compressor and
/// method setting, the ground truth): the render with the inset region marked, its error
/// against the uncompressed render, against the ground truth (when traced), and the inset.
fn comparison_rows(m: &Metrics) -> Vec<Block> {
    use crate::plots::tick_label;
    let mut d = vec![Block::Heading(2, "Comparison".into())];
    let figures = m.figures.as_ref();
    let reference = m.reference.is_some();
    let text = comparison_text(m);
    if !text.is_empty() {
        d.push(Block::Para(text.trim_start().to_string()));
    }
    let mut header = vec!["setting", "render", "error vs uncompressed"];
    if reference {
        header.push("error vs ground truth");
    }
    if figures.is_some() {
        header.push("inset");
    }
    let mut t = Table::new(&header);
    t.class = Some("figures");
    let row_of = |name: &str| figures.and_then(|f| f.rows.iter().find(|r| r.name == name));
    let dash = || Cell::from("-");
    let push = |t: &mut Table, label: Cell, name: &str, png: &str, error: Cell| {
        let row = row_of(name);
        let mut cells = vec![label, Cell::image(row.map_or(png, |r| &r.thumbnail), name), error];
        if reference {
            cells.push(match row.and_then(|r| r.error_vs_reference_png.as_ref()) {
                Some(e) => Cell::image(e, &format!("{name}: error vs ground truth")),
                None => dash(),
            });
        }
        if figures.is_some() {
            cells.push(row.map_or_else(dash, |r| Cell::image(&r.inset, &format!("{name}: inset"))));
        }
        t.rows.push(cells);
    };
    let label = |name: &str, lines: Vec<String>, exr: Option<&str>| {
        let mut c = vec![Inline::Text(name.to_string())];
        for l in lines {
            c.extend([Inline::Break, Inline::Text(l)]);
        }
        if let Some(exr) = exr {
            c.extend([Inline::Break, Inline::Link { text: "EXR".into(), href: exr.to_string() }]);
        }
        Cell(c)
    };
    push(
        &mut t,
        label("uncompressed T", vec![], Some("images/uncompressed.exr")),
        "uncompressed",
        "images/uncompressed.png",
        dash(),
    );
    if m.uncompressed.light_moments {
        push(
            &mut t,
            label("uncompressed, paper's bin-mean cosine", vec![], Some("images/uncompressed_paper.exr")),
            "uncompressed_paper",
            "images/uncompressed_paper.png",
            dash(),
        );
    }
    let records = m.compressors.iter().map(|c| (c, false)).chain(m.methods.iter().map(|r| (&r.record, true)));
    for (c, method) in records {
        let mut lines = vec![if c.lossless { "lossless".to_string() } else { "lossy".to_string() }];
        lines.push(format!("{:.2} MB", c.bytes as f64 / 1e6));
        if let Some(max) = c.image.error_max {
            lines.push(format!("largest error {}", tick_label(max as f64)));
        }
        if method {
            lines.push("error vs uncompressed at its own scale".into());
        }
        let error = match &c.image.error_png {
            Some(e) => Cell::image(e, &format!("{}: error vs uncompressed", c.name)),
            None => dash(),
        };
        push(&mut t, label(&c.name, lines, Some(&c.image.exr)), &c.name, &c.image.png, error);
    }
    if reference {
        let shading = m.reference.as_ref().map(|r| r.shading.clone()).filter(|s| !s.is_empty());
        push(
            &mut t,
            label("ground truth (direct light)", shading.into_iter().collect(), Some("images/reference.exr")),
            "reference",
            "images/reference.png",
            dash(),
        );
    }
    d.push(Block::Table(t));
    d
}

/// The transfer matrix in one sentence (both reports).
pub fn transfer_summary(t: &TransferMetrics) -> String {
    let built = match t.cached {
        true => "loaded from the stage cache".to_string(),
        false => format!(
            "built in {:.2} s ({} rays{}, {:.1} M rays/s)",
            t.build_seconds,
            t.rays_traced,
            match t.visibility {
                Some(biscale_core::transfer::Visibility::Coverage) => " decided by coverage",
                Some(biscale_core::transfer::Visibility::Rays) => " traced",
                None => "",
            },
            t.rays_per_second / 1e6
        ),
    };
    format!(
        "T is {} x {} ({} local directions per vertex) with {} non-zeros ({:.2}% dense), {built}.",
        t.rows,
        t.cols,
        t.local_dirs,
        t.nnz,
        100.0 * t.nnz as f64 / (t.rows as f64 * t.cols as f64).max(1.0),
    )
}

/// The low- vs all-frequency comparison of both reports: a table of storage, precompute,
/// gather and shade time and image error per method, and the figures to show side by side
/// (error images against the all-frequency uncompressed render). `None` when no method
/// setting ran.
pub struct LowVsAll {
    pub table: Table,
    pub figures: Vec<Figure>,
}

/// The materials' BTF representations as a table, when any is not dense: storage and table
/// error of every setting and, from the BTF study, its image error and shade time.
pub struct BtfTable {
    pub table: Table,
    /// One sentence: the materials' own BTFs, dense and as stored (what decides whether the
    /// scene fits a GPU), and how the study was made.
    pub total: String,
    /// Each studied setting's image and its error against the all-dense image.
    pub figures: Vec<Figure>,
}

/// [`BtfTable`] of a run, `None` when every BTF is dense.
pub fn btf_table(m: &Metrics) -> Option<BtfTable> {
    if m.scene.btfs.iter().all(|b| b.representation == "dense") {
        return None;
    }
    let pct = |x: f64| format!("{:.2}%", 100.0 * x);
    let mut figures = vec![];
    let rows: Vec<Vec<String>> = m
        .scene
        .btfs
        .iter()
        .map(|b| {
            let st = b.study.as_ref();
            if let Some(st) = st {
                figures.push(Figure::new(st.png.clone(), format!("{} {}", b.material, b.representation)));
                figures.push(Figure::new(
                    st.error_png.clone(),
                    format!(
                        "{} {}: |error| against dense BTFs (full scale {:.3e})",
                        b.material, b.representation, st.error_scale
                    ),
                ));
            }
            let pre = st.and_then(|s| s.precomputed.as_ref());
            vec![
                b.material.clone(),
                b.representation.clone(),
                if b.primary { "yes".into() } else { "study".into() },
                format!("{:.2}", b.dense_bytes as f64 * 1e-6),
                format!("{:.2}", b.bytes as f64 * 1e-6),
                format!("1:{:.0}", b.compression_ratio),
                pct(b.relative_rms_error),
                format!("{:.1}", b.build_seconds),
                st.map_or("-".into(), |s| pct(s.vs_dense.rel_l2)),
                st.and_then(|s| s.vs_reference.as_ref()).map_or("-".into(), |e| pct(e.rel_l2)),
                st.map_or("-".into(), |s| {
                    format!("{:.0} ({:.0}; rays {:.0})", s.shade_ms, s.dense_shade_ms, s.rays_ms)
                }),
                pre.map_or("-".into(), |p| {
                    format!("{:.0} + {:.0} once ({:.1} MB)", p.shade_ms, p.precompute_ms, p.bytes as f64 * 1e-6)
                }),
            ]
        })
        .collect();
    let (dense, stored): (u64, u64) =
        m.scene.btfs.iter().filter(|b| b.primary).fold((0, 0), |(d, b), r| (d + r.dense_bytes, b + r.bytes));
    let total = format!(
        "The materials' own BTFs: {:.2} MB dense, {:.2} MB as stored (1:{:.0}). Every shader evaluates a compressed \
         BTF from its eigen-BRDFs. Image errors: each setting shaded with the uncompressed L* (the other materials \
         dense) against the all-dense image and the ground truth; shade ms: CPU median, the all-dense image's and \
         the primary rays' alone (the floor of both) in brackets; precomputed: per-vertex dot products for the fixed light, ms per frame + ms once.",
        dense as f64 * 1e-6,
        stored as f64 * 1e-6,
        dense as f64 / stored.max(1) as f64
    );
    let mut table = Table::new(&[
        "material",
        "BTF",
        "own",
        "dense MB (f32)",
        "stored MB",
        "ratio",
        "table rel. RMS",
        "build s",
        "image vs dense",
        "image vs ground truth",
        "shade ms (dense)",
        "precomputed ms",
    ]);
    for row in rows {
        table.text_row(row);
    }
    Some(BtfTable { table, total, figures })
}

/// Bytes as megabytes at two decimals (the low- vs all-frequency table).
fn megabytes(b: u64) -> String {
    format!("{:.2}", b as f64 / 1e6)
}

/// A record's relative L2 error against the ground truth, `-` without one.
fn vs_reference_cell(c: &CompressorRecord) -> String {
    c.image.vs_reference.map_or("-".into(), |e| format!("{:.4}", e.rel_l2))
}

/// A record's LDR PSNR / SSIM / FLIP against the ground truth, `-` without one.
fn vs_reference_ldr_cell(c: &CompressorRecord) -> String {
    c.image.vs_reference.map_or("-".into(), |e| ldr_cell(&e))
}

/// Precompute: the transfer's build plus its form's; `cached` when the transfer came from the
/// cache (nothing was built), and the sum marked when only the form did (its build time is the
/// earlier run's that built it).
fn precompute_cell(s: f64, cached: bool, form_cached: bool) -> String {
    match (cached, form_cached) {
        (true, _) => "cached".to_string(),
        (false, true) => format!("{s:.2} (form cached)"),
        (false, false) => format!("{s:.2}"),
    }
}

pub fn low_vs_all(m: &Metrics) -> Option<LowVsAll> {
    if m.methods.is_empty() {
        return None;
    }
    let records = m.compressors.iter().chain(m.methods.iter().map(|r| &r.record));
    let ranged = ranged(&[&m.uncompressed.gather_timing, &m.uncompressed.shade_timing])
        || records.into_iter().any(|c| ranged(&[&c.gather_timing, &c.shade_timing]));
    let header = &[
        "method",
        "transfer MB",
        "meso MB",
        "precompute s",
        ms_header("gather", ranged),
        ms_header("shade", ranged),
        "rel. L2 vs ground truth",
        "LDR PSNR / SSIM / FLIP vs ground truth",
        "rel. L2 vs all-frequency",
        "negative pixels",
    ];
    let (mb, err, ldr, seconds) = (megabytes, vs_reference_cell, vs_reference_ldr_cell, precompute_cell);
    let mut rows = vec![];
    let mut figures = vec![];
    let t = &m.transfer;
    let gather = |c: &CompressorRecord| timing_cell(c.gather_ms, c.gather_timing.as_ref(), 2);
    let shade = |c: &CompressorRecord| timing_cell(c.shade_ms, c.shade_timing.as_ref(), 1);
    // The all-frequency side: the raw matrix (or the f64 product when sparse did not run), and
    // the paper's compressed form.
    match m.compressors.iter().find(|c| registry::role_of(&c.kind) == Role::Raw) {
        Some(c) => rows.push(vec![
            format!("all-frequency, {}", c.name),
            mb(c.bytes),
            mb(m.scene.btf_bytes),
            seconds(t.build_seconds, t.cached, false),
            gather(c),
            shade(c),
            err(c),
            ldr(c),
            "0 (itself)".into(),
            "-".into(),
        ]),
        None => rows.push(vec![
            "all-frequency, uncompressed".into(),
            mb(4 * (t.rows as u64 + 1) + 8 * t.nnz as u64),
            mb(m.scene.btf_bytes),
            seconds(t.build_seconds, t.cached, false),
            timing_cell(m.uncompressed.gather_ms, m.uncompressed.gather_timing.as_ref(), 2),
            timing_cell(m.uncompressed.shade_ms, m.uncompressed.shade_timing.as_ref(), 1),
            m.reference.as_ref().map_or("-".into(), |r| format!("{:.4}", r.uncompressed_vs_reference.rel_l2)),
            m.reference.as_ref().map_or("-".into(), |r| ldr_cell(&r.uncompressed_vs_reference)),
            "0 (itself)".into(),
            "-".into(),
        ]),
    }
    for c in m.compressors.iter().filter(|c| registry::role_of(&c.kind) == Role::Paper) {
        rows.push(vec![
            format!("all-frequency, {}", c.name),
            mb(c.bytes),
            mb(m.scene.btf_bytes),
            seconds(t.build_seconds + c.build_seconds, t.cached, c.cached),
            gather(c),
            shade(c),
            err(c),
            ldr(c),
            format!("{:.2e}", c.image.vs_uncompressed.rel_l2),
            "-".into(),
        ]);
        figures.push(Figure::new(c.image.png.clone(), format!("all-frequency: {}", c.name)));
    }
    for r in &m.methods {
        let c = &r.record;
        let (meso, pre, neg) = match &r.sh {
            Some(sh) => (
                mb(sh.rtt.bytes),
                seconds(sh.transfer.seconds + c.build_seconds, sh.transfer.cached, c.cached),
                format!("{:.2}%", 100.0 * sh.negative_pixels),
            ),
            None => ("-".into(), seconds(c.build_seconds, false, c.cached), "-".into()),
        };
        rows.push(vec![
            format!(
                "low-frequency, {}{}",
                c.name,
                if r.sh.as_ref().is_some_and(|s| s.diffuse) { " (diffuse PRT)" } else { "" }
            ),
            mb(c.bytes),
            meso,
            pre,
            gather(c),
            shade(c),
            err(c),
            ldr(c),
            format!("{:.4}", c.image.vs_uncompressed.rel_l2),
            neg,
        ]);
        figures.push(Figure::new(c.image.png.clone(), format!("low-frequency: {}", c.name)));
        if let Some(e) = &c.image.error_png {
            let caption = format!("{}: |error| against the all-frequency uncompressed render", c.name);
            figures.push(Figure::new(e.clone(), caption));
        }
    }
    if let Some(r) = &m.reference {
        let caption = match r.shading.is_empty() {
            true => "ground truth (direct light)".to_string(),
            false => format!("ground truth (direct light); {}", r.shading),
        };
        figures.push(Figure::new("images/reference.png", caption));
    }
    let mut table = Table::new(header);
    for row in rows {
        table.text_row(row);
    }
    Some(LowVsAll { table, figures })
}

/// The low- vs all-frequency section (nothing without method settings).
fn low_vs_all_blocks(m: &Metrics) -> Vec<Block> {
    let Some(l) = low_vs_all(m) else { return vec![] };
    let mut d = vec![Block::Heading(2, "Low- vs all-frequency".into())];
    d.push(Block::Para(
        "The same scene, BTFs, light, camera and reference through the all-frequency method (bins T) and the \
         low-frequency one (SH light, per-vertex SH transfer, radiance transfer textures). Transfer MB is the \
         transfer's stored form, meso MB the BTF tables (all-frequency) or radiance transfer textures (SH), at f32; \
         precompute is the transfer's build plus its compression (`cached` when the transfer came from the stage \
         cache)."
            .into(),
    ));
    d.push(Block::Table(l.table));
    d.push(Block::Figures { figures: l.figures, wide: false });
    d
}

/// The animation section (`[runtime.animation]`; nothing without one): per path, a table of
/// each setting's per-frame error and frame time, the animated PNGs and the per-frame plot.
fn animation_blocks(m: &Metrics) -> Vec<Block> {
    if m.animations.is_empty() {
        return vec![];
    }
    let mut d = vec![Block::Heading(2, "Animation".into())];
    d.push(Block::Para(
        "Every frame rendered on the CPU for the uncompressed T and each animated setting, one repeat each; error: \
         relative L2 against the uncompressed render of the same frame over the covered pixels, at the report's \
         exposure. Frame time: gather (the light path only: on the camera path the light and L* do not change) plus \
         shade, in ms. The animated PNGs play in a browser."
            .into(),
    ));
    let stat = |v: &[f64]| {
        let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
        s.sort_by(f64::total_cmp);
        let median = if s.is_empty() { f64::NAN } else { s[s.len() / 2] };
        (median, s.last().copied().unwrap_or(f64::NAN))
    };
    for a in &m.animations {
        let what = match a.path.as_str() {
            "light" => "the light turned about +Y",
            _ => "the camera orbited about its target",
        };
        d.push(Block::Heading(
            3,
            format!("{what}: {} frames, {:.1} degrees apart, {} fps", a.frames, a.step_degrees, a.fps),
        ));
        let mut t = Table::new(&[
            "setting",
            "median rel. L2",
            "worst rel. L2",
            "median gather ms",
            "median shade ms",
            "median frame ms",
        ]);
        for s in &a.series {
            let frame: Vec<f64> = s.gather_ms.iter().zip(&s.shade_ms).map(|(g, h)| g + h).collect();
            let (e_med, e_max) = stat(&s.rel_l2);
            t.text_row(vec![
                s.name.clone(),
                format!("{e_med:.2e}"),
                format!("{e_max:.2e}"),
                format!("{:.2}", stat(&s.gather_ms).0),
                format!("{:.1}", stat(&s.shade_ms).0),
                format!("{:.1}", stat(&frame).0),
            ]);
        }
        d.push(Block::Table(t));
        let mut figures: Vec<Figure> = a.series.iter().map(|s| Figure::new(s.apng.clone(), s.name.clone())).collect();
        figures.push(Figure {
            src: a.plot.clone(),
            caption: "per-frame error and frame time".into(),
            link: Some(svg_twin(&a.plot)),
        });
        d.push(Block::Figures { figures, wide: false });
    }
    d
}

/// How the report prints a timed step (both reports): the median over the repeats, with the
/// fastest and slowest in brackets; and, when a form came from the stage cache, whose its build
/// time is.
pub fn timing_note(m: &Metrics) -> String {
    let mut s = match m.uncompressed.gather_timing.map(|t| t.repeats) {
        Some(1) => "Times are the wall clock of a single repeat (`[runtime] repeats = 1`): nothing shows how much \
                    they vary."
            .to_string(),
        repeats => format!(
            "Times are the median wall clock over {}, with the fastest and slowest repeat in brackets: \
             `median (min-max)`.",
            repeats.map_or("`[runtime] repeats`".to_string(), |n| format!("{n} repeats"))
        ),
    };
    if m.compressors.iter().chain(m.methods.iter().map(|r| &r.record)).any(|c| c.cached) {
        s += " A form marked `cached` came from the stage cache: its build time is the one measured by the earlier \
              run that built it, on a machine and under a load the cache does not record.";
    }
    s
}

/// A timed step's table cell: `median (min-max)` at `decimals` decimals when its repeats are
/// recorded ([`Timing::median_range`]), else the median (`median_ms`, an older record's only
/// figure).
pub fn timing_cell(median_ms: f64, timing: Option<&Timing>, decimals: usize) -> String {
    timing.map_or_else(|| format!("{median_ms:.decimals$}"), |t| t.median_range(decimals))
}

/// Whether any of these timings has more than one repeat (its cells then show a range).
fn ranged(timings: &[&Option<Timing>]) -> bool {
    timings.iter().any(|t| t.is_some_and(|t| t.repeats > 1))
}

/// A timing column's header: `gather ms`, or `gather ms, median (min-max)` when its cells show
/// ranges.
fn ms_header(step: &str, ranged: bool) -> &'static str {
    match (step, ranged) {
        ("gather", false) => "gather ms",
        ("gather", true) => "gather ms, median (min-max)",
        ("shade", false) => "shade ms",
        ("shade", true) => "shade ms, median (min-max)",
        _ => unreachable!("a timing column is a gather or a shade"),
    }
}

/// Every timed step of a run whose repeats are recorded, named as the report's warning names
/// it (`gather of uncompressed T`, `shade of `sparse``, `GPU gather of `haar-t4``), in the
/// order the run timed them.
pub fn timed_steps(m: &Metrics) -> Vec<(String, Timing)> {
    let mut steps = vec![];
    let mut push = |what: String, t: &Option<Timing>| {
        if let Some(t) = t {
            steps.push((what, *t));
        }
    };
    push("gather of uncompressed `T`".into(), &m.uncompressed.gather_timing);
    push("shade of uncompressed `T`".into(), &m.uncompressed.shade_timing);
    for c in m.compressors.iter().chain(m.methods.iter().map(|r| &r.record)) {
        push(format!("gather of `{}`", c.name), &c.gather_timing);
        push(format!("shade of `{}`", c.name), &c.shade_timing);
        if let Some(g) = &c.gpu {
            push(format!("GPU gather of `{}`", c.name), &g.gather_timing);
            push(format!("GPU shade of `{}`", c.name), &g.shade_timing);
        }
    }
    steps
}

/// Most noisy steps the warning names; the rest are counted.
const NAMED_NOISY_STEPS: usize = 3;

/// The one-line warning of both reports and the run's log, when any timed step is noisy
/// ([`Timing::noisy`]: its repeats' interquartile range is over [`NOISY_SPREAD`] of its
/// median) or the machine's load average exceeded its CPUs while the steps were timed
/// ([`crate::metrics::LoadRecord::overloaded`]); `None` when the timings look trustworthy.
/// The noisiest steps come first.
pub fn timing_warning(m: &Metrics) -> Option<String> {
    let mut noisy: Vec<(String, Timing)> = timed_steps(m).into_iter().filter(|(_, t)| t.noisy()).collect();
    let overloaded = m.load.is_some_and(|l| l.overloaded());
    if noisy.is_empty() && !overloaded {
        return None;
    }
    let load = m.load.and_then(|l| l.peak().map(|p| format!("load {p:.1} on {} CPUs", l.cpus_online)));
    let advice = "treat speed ratios with care";
    if noisy.is_empty() {
        let load = load.expect("an overloaded record has a reading");
        return Some(format!("the machine was busy while the run timed its steps ({load}); {advice}"));
    }
    noisy.sort_by(|a, b| b.1.spread.total_cmp(&a.1.spread));
    let named: Vec<String> = noisy
        .iter()
        .take(NAMED_NOISY_STEPS)
        .map(|(what, t)| {
            format!(
                "{what} ranged {}-{} ms over {} repeats (median {}, spread {:.2})",
                short_ms(t.min_ms),
                short_ms(t.max_ms),
                t.repeats,
                short_ms(t.median_ms),
                t.spread
            )
        })
        .collect();
    let more = match noisy.len().saturating_sub(NAMED_NOISY_STEPS) {
        0 => String::new(),
        n => format!(" and {n} more step{}", if n == 1 { "" } else { "s" }),
    };
    let load = match (load, overloaded) {
        (Some(l), true) => format!("; the machine was busy ({l})"),
        (Some(l), false) => format!(" ({l})"),
        (None, _) => String::new(),
    };
    Some(format!(
        "timings are noisy (interquartile range over {NOISY_SPREAD} of the median): {}{more}{load}; {advice}",
        named.join(", ")
    ))
}

/// Milliseconds to two or three significant figures, for a sentence.
fn short_ms(ms: f64) -> String {
    match ms.abs() {
        x if x >= 100.0 => format!("{ms:.0}"),
        x if x >= 10.0 => format!("{ms:.1}"),
        x if x >= 0.1 => format!("{ms:.2}"),
        _ => format!("{ms:.3}"),
    }
}

/// What the tables' LDR figures are (both reports).
pub const LDR_NOTE: &str =
    "LDR PSNR / SSIM / FLIP: after the PNGs' tone map (x 2^exposure, the stops `tone_map` records, \
     clamped to [0, 1], sRGB-encoded), over the covered pixels: PSNR in dB with peak 1; SSIM with an 11x11 Gaussian \
     window (sigma 1.5), the mean of R, G and B (1 = equal); mean LDR FLIP of the 8-bit PNGs (0 = equal).";

/// An image error's LDR figures as one table cell: `LDR PSNR / SSIM / FLIP`.
pub fn ldr_cell(e: &crate::metrics::ImageErrors) -> String {
    format!("{:.2} / {:.4} / {:.4}", e.ldr_psnr, e.ssim, e.flip)
}

/// The compressor table of both reports: one row per setting.
/// The rows each setting's kind draws from its form's `stats` (`registry::Kind::report`: the
/// compressor, not the report, says what its statistics mean), one row per setting and
/// figure; `None` when no kind has any.
pub fn statistics_table(m: &Metrics) -> Option<Table> {
    statistics_table_with(m, biscale_compressors::registry::find)
}

/// [`statistics_table`] with the kinds looked up by `find`.
pub fn statistics_table_with<'k>(
    m: &Metrics,
    find: impl Fn(&str) -> Option<&'k biscale_compressors::registry::Kind>,
) -> Option<Table> {
    let mut t = Table::new(&["setting", "figure", "value"]);
    for c in &m.compressors {
        let (Some(stats), Some(kind)) = (&c.stats, find(&c.kind)) else { continue };
        for (name, value) in (kind.report)(stats) {
            t.text_row([c.name.clone(), name, value]);
        }
    }
    (!t.rows.is_empty()).then_some(t)
}

pub fn compressor_table(m: &Metrics) -> Table {
    let ranged = m.compressors.iter().any(|c| ranged(&[&c.gather_timing, &c.shade_timing]));
    let header = &[
        "setting",
        "lossless",
        "MB",
        "bytes/nnz",
        "Mflop/gather",
        "build s",
        ms_header("gather", ranged),
        ms_header("shade", ranged),
        "rel. err L*",
        "RMSE vs uncompressed",
        "PSNR vs uncompressed",
        "PSNR vs ground truth",
        "LDR PSNR / SSIM / FLIP vs uncompressed",
        "LDR PSNR / SSIM / FLIP vs ground truth",
    ];
    let rows = m
        .compressors
        .iter()
        .map(|c| {
            vec![
                c.name.clone(),
                if c.lossless { "yes" } else { "no" }.to_string(),
                format!("{:.3}", c.bytes as f64 / 1e6),
                format!("{:.3}", c.bytes_per_nnz),
                format!("{:.3}", c.flops_per_gather as f64 / 1e6),
                format!("{:.2}{}", c.build_seconds, if c.cached { " (cached)" } else { "" }),
                timing_cell(c.gather_ms, c.gather_timing.as_ref(), 2),
                timing_cell(c.shade_ms, c.shade_timing.as_ref(), 1),
                format!("{:.2e}", c.rel_error_lstar),
                format!("{:.3e}", c.image.vs_uncompressed.rmse),
                format!("{:.2}", c.image.vs_uncompressed.psnr),
                c.image.vs_reference.map_or("-".into(), |e| format!("{:.2}", e.psnr)),
                ldr_cell(&c.image.vs_uncompressed),
                c.image.vs_reference.map_or("-".into(), |e| ldr_cell(&e)),
            ]
        })
        .collect::<Vec<Vec<String>>>();
    let mut table = Table::new(header);
    for row in rows {
        table.text_row(row);
    }
    table
}

/// The storage budget of the equal-storage comparison: the lossless biclustering's storage
/// when it ran (the paper compares at the size biclustering needs), else the median.
pub fn storage_budget(m: &Metrics) -> Option<(u64, String)> {
    // The lossless biclustering when it ran (the paper's storage), else the first bicluster.
    let bicluster = |lossless: bool| {
        m.compressors.iter().find(|c| registry::role_of(&c.kind) == Role::Paper && (c.lossless || !lossless))
    };
    if let Some(b) = bicluster(true).or_else(|| bicluster(false)) {
        return Some((b.bytes, format!("the storage of {}", b.name)));
    }
    let mut bytes: Vec<u64> = m.compressors.iter().map(|c| c.bytes).collect();
    bytes.sort();
    bytes.get(bytes.len() / 2).map(|&b| (b, "the median storage".to_string()))
}

/// Equal-storage and equal-quality sections (only when at least two kinds ran).
pub fn comparisons(m: &Metrics) -> Vec<Block> {
    use crate::compare::{by_kind, equal_storage, storage_for_error, StorageForError};
    let mut d = vec![];
    let kinds = by_kind(&m.compressors);
    if kinds.len() < 2 {
        return d;
    }
    if let Some((budget, why)) = storage_budget(m) {
        d.push(Block::Heading(2, "Equal storage".into()));
        d.push(Block::Para(format!("Each compressor's setting closest to {why} ({:.2} MB):", budget as f64 / 1e6)));
        let mut t = Table::new(&["setting", "MB", "rel. err L*", "PSNR vs uncompressed", "image", "error"]);
        t.class = Some("thumbnails");
        for r in equal_storage(&m.compressors, budget) {
            t.rows.push(vec![
                r.name.clone().into(),
                format!("{:.2}", r.bytes as f64 / 1e6).into(),
                format!("{:.2e}", r.rel_error_lstar).into(),
                format!("{:.2}", r.image.vs_uncompressed.psnr).into(),
                Cell::image(&r.image.png, &r.name),
                r.image.error_png.as_ref().map_or_else(|| "-".into(), |e| Cell::image(e, "error")),
            ]);
        }
        d.push(Block::Table(t));
    }
    d.push(Block::Heading(2, "Equal quality".into()));
    d.push(Block::Para(format!(
        "Storage each compressor needs for a relative L* error of {:.2e} (log-log interpolation along its sweep):",
        m.target_error
    )));
    let mut t = Table::new(&["compressor", "storage needed"]);
    for (kind, recs) in &kinds {
        let text = match storage_for_error(recs, m.target_error) {
            Some(StorageForError::AtMost { bytes, setting }) => {
                format!("at most {:.2} MB ({setting} already meets it)", bytes as f64 / 1e6)
            }
            Some(StorageForError::Between { bytes, below, above }) => {
                format!("about {:.2} MB (between {below} and {above})", bytes / 1e6)
            }
            Some(StorageForError::NotReached { best_error, setting }) => {
                format!("not reached by the sweep (best {best_error:.2e} at {setting}): sweep further")
            }
            None => "-".into(),
        };
        t.text_row([kind.clone(), text]);
    }
    d.push(Block::Table(t));
    // The same read-off at the field's usual targets, one column each: where each
    // compressor's curve crosses them (interpolated between two measured settings, never
    // extrapolated).
    let targets = crate::compare::equal_quality_targets(m.target_error);
    d.push(Block::Para(
        "At other targets (MB; `<=`: the cheapest setting already meets it; `>`: not reached, so it needs more than \
         the largest setting measured):"
            .into(),
    ));
    let head: Vec<String> = targets.iter().map(|t| format!("{t:.1e}")).collect();
    let mut t = Table { header: std::iter::once("compressor".to_string()).chain(head).collect(), ..Table::default() };
    for (kind, recs) in &kinds {
        let cells = targets.iter().map(|&t| match storage_for_error(recs, t) {
            Some(StorageForError::AtMost { bytes, .. }) => format!("<= {:.2}", bytes as f64 / 1e6),
            Some(StorageForError::Between { bytes, .. }) => format!("{:.2}", bytes / 1e6),
            Some(StorageForError::NotReached { .. }) => {
                format!("> {:.2}", recs.iter().map(|r| r.bytes).max().unwrap_or(0) as f64 / 1e6)
            }
            None => "-".into(),
        });
        t.text_row(std::iter::once(kind.clone()).chain(cells));
    }
    d.push(Block::Table(t));
    d
}

/// One sentence on the cosine rule of the run's `L*` (`[runtime] light_moments`) and, with
/// moments, what they change: the paper-mode image against the moments' one, and both against
/// the (exact-cosine) reference when one was traced.
pub(crate) fn light_moments_summary(m: &Metrics) -> String {
    if !m.uncompressed.light_moments {
        return "Cosine rule: the paper's, every texel of a local bin weighted by the bin's mean cosine \
                (`[runtime] light_moments = false`)."
            .into();
    }
    let mut s = String::from(
        "Cosine rule: light moments, every texel weighted by its own cosine (three gathers of the light's \
         direction moments through each form; `[runtime] light_moments = true`).",
    );
    use biscale_shading::runtime::MomentsResolve;
    match m.uncompressed.moments_resolve {
        Some(MomentsResolve::Pixel) => s.push_str(
            " Resolved per pixel (`[runtime] moments_resolve = \"pixel\"`): each vertex's three moment \
             gathers are resolved at every pixel's own frame and the resolved rows blended across the \
             triangle, so no image of this run shades an L* resolved in the vertices' frames.",
        ),
        Some(MomentsResolve::PixelAnalytic) => s.push_str(
            " Resolved per pixel with the analytic BRDF (`[runtime] moments_resolve = \"pixel_analytic\"`): \
             at every pixel each local bin of the triangle's vertices is shaded by the material's own \
             BRDF at the bin's mean light direction and the pixel's view, not by the BTF's light and \
             view tables, and the three vertices blended (flat analytic materials; any other \
             material is resolved from its tables as with `\"pixel\"`).",
        ),
        Some(MomentsResolve::Vertex) => s.push_str(
            " Resolved per vertex (`[runtime] moments_resolve = \"vertex\"`): each vertex's L* is interpolated \
             across its triangles.",
        ),
        None => {}
    }
    match m.lighting.texel_directions {
        Some(biscale_core::sampling::TexelDirections::Mean) => s.push_str(
            " Each cubemap texel's light comes from the power-weighted mean direction of the source pixels it \
             averages, per channel (`[lighting] texel_directions = \"mean\"`): a sun where it is in its texel, \
             not at the texel's centre (T still bins texels by their centres).",
        ),
        Some(biscale_core::sampling::TexelDirections::Centre) => s.push_str(
            " Each cubemap texel's light comes from the texel's centre (`[lighting] texel_directions = \"centre\"`, \
             or a light not splatted from an image).",
        ),
        None => {}
    }
    if let Some(e) = &m.uncompressed.paper_vs_moments {
        let _ = write!(s, " The paper's bin-mean-cosine image differs from it by rel. L2 {:.4}.", e.rel_l2);
    }
    if let Some((r, paper)) = m.reference.as_ref().and_then(|r| r.uncompressed_paper_vs_reference.map(|p| (r, p))) {
        let _ = write!(
            s,
            " Against the ground truth (direct light): rel. L2 {:.4} with moments, {:.4} with the paper's rule.",
            r.uncompressed_vs_reference.rel_l2, paper.rel_l2
        );
    }
    s
}

/// The documents of a run from its record alone: the plots ([`write_plots`]), `report.html`
/// and `report.md`, written atomically into `out_dir`, which holds the run's `images/`. A run
/// writes them so, and `biscale report` re-renders them so from a `metrics.json` and its
/// `plan.txt`, with no tracing.
pub fn write_documents(m: &Metrics, plan: &str, out_dir: &std::path::Path) -> Result<(), biscale_core::CoreError> {
    use biscale_core::io::write_atomic_bytes;
    let plots = write_plots(m, out_dir);
    let html = crate::html::html(m, plan, out_dir, &plots);
    write_atomic_bytes(&out_dir.join("report.html"), html.as_bytes())?;
    let markdown = markdown(m, plan, &plots);
    write_atomic_bytes(&out_dir.join("report.md"), markdown.as_bytes())?;
    Ok(())
}

/// The comparison plots (only when there is something to compare); returns (path, caption).
pub fn write_plots(m: &Metrics, out_dir: &std::path::Path) -> Vec<(String, String)> {
    /// A plot's file stem, title, x-axis label and x value of a record.
    type Plot = (&'static str, &'static str, &'static str, fn(&crate::metrics::CompressorRecord) -> f64);
    let mut out = vec![];
    let mut plot_with = |file: &str,
                         title: &str,
                         x_label: &str,
                         y_label: &str,
                         series: &[crate::plots::Series],
                         guide: Option<&crate::plots::Guide>| {
        let rel = format!("{file}.png");
        match crate::plots::log_log_plot_with(&out_dir.join(&rel), title, x_label, y_label, series, guide) {
            Ok(()) => out.push((rel, title.to_string())),
            Err(e) => eprintln!("warning: plot {file}: {e}"),
        }
    };
    if m.compressors.len() >= 2 {
        let plots: [Plot; 2] = [
            ("error_vs_time", "relative error of L* against gather time", "gather time (ms, CPU)", |r| r.gather_ms),
            ("error_vs_storage", "relative error of L* against storage", "storage (MB)", |r| r.bytes as f64 / 1e6),
        ];
        // On the storage plot, the equal-quality storage of each kind at the report's target.
        let guide = crate::plots::Guide {
            y: m.target_error,
            label: format!("target {:.1e}", m.target_error),
            marks: crate::compare::by_kind(&m.compressors)
                .into_iter()
                .filter_map(|(kind, recs)| {
                    let bytes = crate::compare::storage_for_error(&recs, m.target_error)?.bytes()?;
                    Some((kind, bytes / 1e6))
                })
                .collect(),
        };
        for (file, title, x_label, x) in plots {
            let series = crate::plots::series_by_kind(&m.compressors, x, |r| r.rel_error_lstar);
            let guide = (file == "error_vs_storage").then_some(&guide);
            plot_with(file, title, x_label, "relative L2 error of L*", &series, guide);
        }
    }
    // The image error of every compressor and method (SH through its order sweep) against the
    // storage of its transfer: where SH saturates and all-frequency transfer is needed. Against
    // the reference when one was traced, else against the all-frequency uncompressed image.
    if !m.methods.is_empty() {
        let against_reference = m.reference.is_some();
        let y = |r: &crate::metrics::CompressorRecord| match (against_reference, &r.image.vs_reference) {
            (true, Some(e)) => e.rel_l2,
            _ => r.image.vs_uncompressed.rel_l2,
        };
        let named = m.compressors.iter().map(|c| (crate::compare::series_of(c), c)).chain(m.methods.iter().map(|r| {
            let compressor = r.sh.as_ref().map_or("", |s| s.compressor.as_str());
            let name = if registry::role_of(compressor) == Role::Raw {
                r.record.kind.clone()
            } else {
                format!("{} + {compressor}", r.record.kind)
            };
            (name, &r.record)
        }));
        let series = crate::plots::series_by(named, |r| r.bytes as f64 / 1e6, y);
        let y_label = if against_reference {
            "relative L2 image error vs ground truth"
        } else {
            "relative L2 image error vs all-frequency"
        };
        plot_with(
            "image_error_vs_storage",
            "image error against transfer storage",
            "storage (MB)",
            y_label,
            &series,
            None,
        );
    }
    // BTF storage against the image error it adds (vs the all-dense image), one series per
    // material; dense settings sit at error 0 (drawn at the plot's floor).
    let mut by_material: std::collections::BTreeMap<&str, Vec<(f64, f64, String)>> = Default::default();
    for b in &m.scene.btfs {
        if let Some(st) = &b.study {
            let point = (b.bytes as f64 / 1e6, st.vs_dense.rel_l2, b.representation.clone());
            by_material.entry(&b.material).or_default().push(point);
        }
    }
    if by_material.values().map(Vec::len).sum::<usize>() >= 2 {
        let series: Vec<crate::plots::Series> = by_material
            .into_iter()
            .map(|(name, mut points)| {
                points.sort_by(|a, b| a.0.total_cmp(&b.0));
                let (points, labels) = points.into_iter().map(|(x, y, label)| ((x, y), label)).unzip();
                crate::plots::Series { name: name.to_string(), points, labels }
            })
            .collect();
        plot_with(
            "btf_error_vs_storage",
            "image error against BTF storage",
            "BTF storage (MB)",
            "relative L2 image error vs dense BTFs",
            &series,
            None,
        );
    }
    out
}
