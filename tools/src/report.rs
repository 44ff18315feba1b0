//! The run's Markdown report: what ran, the transfer matrix, and one row per compressor
//! setting, with links to the images. Readable without the program.

use crate::metrics::{Metrics, TransferMetrics};
use crate::plan::Plan;
use std::fmt::Write;

pub fn markdown(m: &Metrics, plan: &Plan) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# biscale run: {}\n", m.experiment);
    let _ = writeln!(s, "Config `{}`, backend {}.\n", m.config, m.backend);
    if let Some(r) = &m.run {
        let _ = writeln!(s, "Run: {}.\n", r.summary());
        let _ = writeln!(s, "| stage | wall s | CPU s |\n|---|---|---|");
        for t in &r.stages {
            let cpu = t.cpu_seconds.map_or("?".into(), |c| format!("{c:.2}"));
            let _ = writeln!(s, "| {} | {:.2} | {cpu} |", t.stage, t.wall_seconds);
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "```\n{plan}```\n");
    let _ = writeln!(s, "## Scene\n");
    let _ = writeln!(
        s,
        "- mesh `{}`: {} vertices, {} triangles; material {}",
        m.scene.mesh, m.scene.vertices, m.scene.triangles, m.scene.material
    );
    for r in &m.scene.repairs {
        let _ = writeln!(s, "- repair: {r}");
    }
    for n in &m.scene.material_notes {
        let _ = writeln!(s, "- materials: {n}");
    }
    let _ = writeln!(
        s,
        "- light: {} at 6x{r}x{r}, rotated {}°, total power (RGB) {:.4} {:.4} {:.4}",
        m.lighting.source,
        m.lighting.rotation_degrees,
        m.lighting.total_power[0],
        m.lighting.total_power[1],
        m.lighting.total_power[2],
        r = m.lighting.cubemap_resolution
    );
    if let Some(b) = btf_table(m) {
        let _ = writeln!(s, "\n| {} |\n|{}", b.header.join(" | "), "---|".repeat(b.header.len()));
        for row in &b.rows {
            let _ = writeln!(s, "| {} |", row.join(" | "));
        }
        let _ = writeln!(s, "\n{}\n", b.total);
        for (png, caption) in &b.figures {
            let _ = writeln!(s, "![{caption}]({png})\n");
        }
    }
    let t = &m.transfer;
    let _ = writeln!(s, "\n## Transfer matrix\n");
    let _ = writeln!(s, "{}\n", transfer_summary(t));
    let _ = writeln!(s, "| value | count |\n|---|---|");
    for v in &t.value_histogram {
        let _ = writeln!(s, "| {} | {} |", v.value, v.count);
    }
    let _ = writeln!(s, "\n## Compressors\n");
    let _ = writeln!(
        s,
        "Uncompressed `T L`: gather {:.2} ms (f64 reference), shade {:.1} ms.\n",
        m.uncompressed.gather_ms, m.uncompressed.shade_ms
    );
    let (header, rows) = compressor_table(m);
    let _ = writeln!(s, "| {} |\n|{}", header.join(" | "), "---|".repeat(header.len()));
    for row in rows {
        let _ = writeln!(s, "| {} |", row.join(" | "));
    }
    let _ = writeln!(s, "\n{LDR_NOTE}");
    if m.compressors.iter().any(|c| c.gpu.is_some()) {
        let adapter = m.compressors.iter().find_map(|c| c.gpu.as_ref()).map(|g| g.adapter.clone()).unwrap_or_default();
        let _ = writeln!(s, "\n### wgpu backend ({adapter})\n");
        let _ = writeln!(
            s,
            "| setting | gather ms | shade ms | timing | rel. err L* | image rel. L2 vs CPU | coverage mismatches |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|");
        for c in &m.compressors {
            if let Some(g) = &c.gpu {
                let _ = writeln!(
                    s,
                    "| {} | {:.2} | {:.2} | {} | {:.2e} | {:.2e} | {} |",
                    c.name,
                    g.gather_ms,
                    g.shade_ms,
                    g.timing,
                    g.rel_error_lstar,
                    g.image_vs_cpu.rel_l2,
                    g.coverage_mismatch
                );
            }
        }
    }
    if let Some(r) = &m.reference {
        let _ = writeln!(
            s,
            "\nGround truth (direct light) traced per pixel at {}x{} in {:.1} s (each pixel's own visibility, each texel's own cosine, the BRDF at each texel's own direction). Uncompressed vertex render against it: RMSE {:.4}, PSNR {:.2} dB, rel. L2 {:.4}; LDR PSNR / SSIM / FLIP {}.",
            r.width, r.height, r.seconds, r.uncompressed_vs_reference.rmse, r.uncompressed_vs_reference.psnr, r.uncompressed_vs_reference.rel_l2,
            ldr_cell(&r.uncompressed_vs_reference)
        );
    }
    let _ = writeln!(s, "\n{}", light_moments_summary(m));
    s.push_str(&comparisons_markdown(m));
    s.push_str(&low_vs_all_markdown(m));
    let _ = writeln!(s, "\n## Images\n");
    let _ = writeln!(s, "![uncompressed](images/uncompressed.png)\n");
    if m.reference.is_some() {
        let _ = writeln!(s, "![ground truth (direct light)](images/reference.png)\n");
    }
    if m.uncompressed.light_moments {
        let _ = writeln!(s, "![uncompressed, paper's bin-mean cosine](images/uncompressed_paper.png)\n");
    }
    if let Some(scale) = m.compressors.iter().find_map(|c| c.image.error_scale) {
        let _ = writeln!(
            s,
            "Every compressor's error figure has one colour scale, full scale {} (luminance of |error| against the \
             uncompressed render, linear radiance; `[report] error_scale` fixes it).\n",
            crate::plots::tick_label(scale as f64)
        );
    }
    for c in &m.compressors {
        let _ = writeln!(s, "**{}** ([EXR]({})):\n\n![{}]({})\n", c.name, c.image.exr, c.name, c.image.png);
        if let (Some(e), Some(max)) = (&c.image.error_png, c.image.error_max) {
            let _ = writeln!(s, "![{} error]({e})\n\nlargest error {}\n", c.name, crate::plots::tick_label(max as f64));
        }
    }
    s
}

/// The transfer matrix in one sentence (both reports).
pub fn transfer_summary(t: &TransferMetrics) -> String {
    let built = match t.cached {
        true => "loaded from the stage cache".to_string(),
        false => format!(
            "built in {:.2} s ({} rays, {:.1} M rays/s)",
            t.build_seconds,
            t.rays_traced,
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

/// The low- vs all-frequency comparison of both reports: a table (header, rows) of storage,
/// precompute, gather and shade time and image error per method, and the figures to show side
/// by side (`(image, caption)`, error images against the all-frequency uncompressed render).
/// `None` when no method setting ran.
pub struct LowVsAll {
    pub header: &'static [&'static str],
    pub rows: Vec<Vec<String>>,
    pub figures: Vec<(String, String)>,
}

/// The materials' BTF representations as a table, when any is not dense: storage and table
/// error of every setting and, from the BTF study, its image error and shade time.
pub struct BtfTable {
    pub header: [&'static str; 12],
    pub rows: Vec<Vec<String>>,
    /// One sentence: the materials' own BTFs, dense and as stored (what decides whether the
    /// scene fits a GPU), and how the study was made.
    pub total: String,
    /// `(image, caption)`: each studied setting's image and its error against the all-dense
    /// image.
    pub figures: Vec<(String, String)>,
}

/// [`BtfTable`] of a run, `None` when every BTF is dense.
pub fn btf_table(m: &Metrics) -> Option<BtfTable> {
    if m.scene.btfs.iter().all(|b| b.representation == "dense") {
        return None;
    }
    let pct = |x: f64| format!("{:.2}%", 100.0 * x);
    let mut figures = vec![];
    let rows = m
        .scene
        .btfs
        .iter()
        .map(|b| {
            let st = b.study.as_ref();
            if let Some(st) = st {
                figures.push((st.png.clone(), format!("{} {}", b.material, b.representation)));
                figures.push((
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
    Some(BtfTable {
        header: [
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
        ],
        rows,
        total,
        figures,
    })
}

pub fn low_vs_all(m: &Metrics) -> Option<LowVsAll> {
    if m.methods.is_empty() {
        return None;
    }
    const HEADER: &[&str] = &[
        "method",
        "transfer MB",
        "meso MB",
        "precompute s",
        "gather ms",
        "shade ms",
        "rel. L2 vs ground truth",
        "LDR PSNR / SSIM / FLIP vs ground truth",
        "rel. L2 vs all-frequency",
        "negative pixels",
    ];
    let mb = |b: u64| format!("{:.2}", b as f64 / 1e6);
    let err =
        |c: &crate::metrics::CompressorRecord| c.image.vs_reference.map_or("-".into(), |e| format!("{:.4}", e.rel_l2));
    let ldr = |c: &crate::metrics::CompressorRecord| c.image.vs_reference.map_or("-".into(), |e| ldr_cell(&e));
    let mut rows = vec![];
    let mut figures = vec![];
    let t = &m.transfer;
    let seconds = |s: f64, cached: bool| if cached { "cached".to_string() } else { format!("{s:.2}") };
    // The all-frequency side: the raw matrix (or the f64 product when sparse did not run), and
    // the paper's compressed form.
    match m.compressors.iter().find(|c| c.kind == "sparse") {
        Some(c) => rows.push(vec![
            format!("all-frequency, {}", c.name),
            mb(c.bytes),
            mb(m.scene.btf_bytes),
            seconds(t.build_seconds, t.cached),
            format!("{:.2}", c.gather_ms),
            format!("{:.1}", c.shade_ms),
            err(c),
            ldr(c),
            "0 (itself)".into(),
            "-".into(),
        ]),
        None => rows.push(vec![
            "all-frequency, uncompressed".into(),
            mb(4 * (t.rows as u64 + 1) + 8 * t.nnz as u64),
            mb(m.scene.btf_bytes),
            seconds(t.build_seconds, t.cached),
            format!("{:.2}", m.uncompressed.gather_ms),
            format!("{:.1}", m.uncompressed.shade_ms),
            m.reference.as_ref().map_or("-".into(), |r| format!("{:.4}", r.uncompressed_vs_reference.rel_l2)),
            m.reference.as_ref().map_or("-".into(), |r| ldr_cell(&r.uncompressed_vs_reference)),
            "0 (itself)".into(),
            "-".into(),
        ]),
    }
    for c in m.compressors.iter().filter(|c| c.kind == "bicluster") {
        rows.push(vec![
            format!("all-frequency, {}", c.name),
            mb(c.bytes),
            mb(m.scene.btf_bytes),
            seconds(t.build_seconds + c.build_seconds, t.cached),
            format!("{:.2}", c.gather_ms),
            format!("{:.1}", c.shade_ms),
            err(c),
            ldr(c),
            format!("{:.2e}", c.image.vs_uncompressed.rel_l2),
            "-".into(),
        ]);
        figures.push((c.image.png.clone(), format!("all-frequency: {}", c.name)));
    }
    for r in &m.methods {
        let c = &r.record;
        let (meso, pre, neg) = match &r.sh {
            Some(sh) => (
                mb(sh.rtt.bytes),
                seconds(sh.transfer.seconds + c.build_seconds, sh.transfer.cached),
                format!("{:.2}%", 100.0 * sh.negative_pixels),
            ),
            None => ("-".into(), format!("{:.2}", c.build_seconds), "-".into()),
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
            format!("{:.2}", c.gather_ms),
            format!("{:.1}", c.shade_ms),
            err(c),
            ldr(c),
            format!("{:.4}", c.image.vs_uncompressed.rel_l2),
            neg,
        ]);
        figures.push((c.image.png.clone(), format!("low-frequency: {}", c.name)));
        if let Some(e) = &c.image.error_png {
            figures.push((e.clone(), format!("{}: |error| against the all-frequency uncompressed render", c.name)));
        }
    }
    if m.reference.is_some() {
        figures.push(("images/reference.png".into(), "ground truth (direct light)".into()));
    }
    Some(LowVsAll { header: HEADER, rows, figures })
}

/// The low- vs all-frequency section as Markdown (empty without method settings).
pub fn low_vs_all_markdown(m: &Metrics) -> String {
    let Some(l) = low_vs_all(m) else { return String::new() };
    let mut s = String::new();
    let _ = writeln!(s, "\n## Low- vs all-frequency\n");
    let _ = writeln!(
        s,
        "The same scene, BTFs, light, camera and reference through the all-frequency method (bins T) and the \
         low-frequency one (SH light, per-vertex SH transfer, radiance transfer textures). Transfer MB is the \
         transfer's stored form, meso MB the BTF tables (all-frequency) or radiance transfer textures (SH), at f32; \
         precompute is the transfer's build plus its compression (`cached` when the transfer came from the stage \
         cache).\n"
    );
    let _ = writeln!(s, "| {} |\n|{}", l.header.join(" | "), "---|".repeat(l.header.len()));
    for row in &l.rows {
        let _ = writeln!(s, "| {} |", row.join(" | "));
    }
    let _ = writeln!(s);
    for (png, caption) in &l.figures {
        let _ = writeln!(s, "![{caption}]({png})\n");
    }
    s
}

/// What the tables' LDR figures are (both reports).
pub const LDR_NOTE: &str = "LDR PSNR / SSIM / FLIP: after the PNGs' tone map (x 2^exposure of `[report] exposure`, \
     clamped to [0, 1], sRGB-encoded), over the covered pixels: PSNR in dB with peak 1; SSIM with an 11x11 Gaussian \
     window (sigma 1.5), the mean of R, G and B (1 = equal); mean LDR FLIP of the 8-bit PNGs (0 = equal).";

/// An image error's LDR figures as one table cell: `LDR PSNR / SSIM / FLIP`.
pub fn ldr_cell(e: &crate::metrics::ImageErrors) -> String {
    format!("{:.2} / {:.4} / {:.4}", e.ldr_psnr, e.ssim, e.flip)
}

/// The compressor table of both reports (Markdown and HTML): its header and one row of
/// cells per setting.
pub fn compressor_table(m: &Metrics) -> (&'static [&'static str], Vec<Vec<String>>) {
    const HEADER: &[&str] = &[
        "setting",
        "lossless",
        "MB",
        "bytes/nnz",
        "Mflop/gather",
        "build s",
        "gather ms",
        "shade ms",
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
                format!("{:.2}", c.gather_ms),
                format!("{:.1}", c.shade_ms),
                format!("{:.2e}", c.rel_error_lstar),
                format!("{:.3e}", c.image.vs_uncompressed.rmse),
                format!("{:.2}", c.image.vs_uncompressed.psnr),
                c.image.vs_reference.map_or("-".into(), |e| format!("{:.2}", e.psnr)),
                ldr_cell(&c.image.vs_uncompressed),
                c.image.vs_reference.map_or("-".into(), |e| ldr_cell(&e)),
            ]
        })
        .collect();
    (HEADER, rows)
}

/// The storage budget of the equal-storage comparison: the lossless biclustering's storage
/// when it ran (the paper compares at the size biclustering needs), else the median.
pub fn storage_budget(m: &Metrics) -> Option<(u64, String)> {
    // The lossless biclustering when it ran (the paper's storage), else the first bicluster.
    let bicluster = |lossless: bool| m.compressors.iter().find(|c| c.kind == "bicluster" && (c.lossless || !lossless));
    if let Some(b) = bicluster(true).or_else(|| bicluster(false)) {
        return Some((b.bytes, format!("the storage of {}", b.name)));
    }
    let mut bytes: Vec<u64> = m.compressors.iter().map(|c| c.bytes).collect();
    bytes.sort();
    bytes.get(bytes.len() / 2).map(|&b| (b, "the median storage".to_string()))
}

/// Equal-storage and equal-quality sections (only when at least two kinds ran).
pub fn comparisons_markdown(m: &Metrics) -> String {
    use crate::compare::{by_kind, equal_storage, storage_for_error, StorageForError};
    let mut s = String::new();
    let kinds = by_kind(&m.compressors);
    if kinds.len() < 2 {
        return s;
    }
    if let Some((budget, why)) = storage_budget(m) {
        let _ = writeln!(
            s,
            "\n## Equal storage\n\nEach compressor's setting closest to {why} ({:.2} MB):\n",
            budget as f64 / 1e6
        );
        let _ = writeln!(
            s,
            "| setting | MB | rel. err L* | PSNR vs uncompressed | image | error |\n|---|---|---|---|---|---|"
        );
        for r in equal_storage(&m.compressors, budget) {
            let _ = writeln!(
                s,
                "| {} | {:.2} | {:.2e} | {:.2} | ![{}]({}) | {} |",
                r.name,
                r.bytes as f64 / 1e6,
                r.rel_error_lstar,
                r.image.vs_uncompressed.psnr,
                r.name,
                r.image.png,
                r.image.error_png.as_ref().map_or("-".into(), |e| format!("![error]({e})"))
            );
        }
    }
    let _ = writeln!(
        s,
        "\n## Equal quality\n\nStorage each compressor needs for a relative L* error of {:.2e} (log-log interpolation along its sweep):\n",
        m.target_error
    );
    let _ = writeln!(s, "| compressor | storage needed |\n|---|---|");
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
        let _ = writeln!(s, "| {kind} | {text} |");
    }
    // The same read-off at the field's usual targets, one column each: where each
    // compressor's curve crosses them (interpolated between two measured settings, never
    // extrapolated).
    let targets = crate::compare::equal_quality_targets(m.target_error);
    let _ = writeln!(
        s,
        "\nAt other targets (MB; `<=`: the cheapest setting already meets it; `>`: not reached, so it needs more than the largest setting measured):\n"
    );
    let head: Vec<String> = targets.iter().map(|t| format!("{t:.1e}")).collect();
    let _ = writeln!(s, "| compressor | {} |\n|---|{}", head.join(" | "), "---|".repeat(targets.len()));
    for (kind, recs) in &kinds {
        let cells: Vec<String> = targets
            .iter()
            .map(|&t| match storage_for_error(recs, t) {
                Some(StorageForError::AtMost { bytes, .. }) => format!("<= {:.2}", bytes as f64 / 1e6),
                Some(StorageForError::Between { bytes, .. }) => format!("{:.2}", bytes / 1e6),
                Some(StorageForError::NotReached { .. }) => {
                    format!("> {:.2}", recs.iter().map(|r| r.bytes).max().unwrap_or(0) as f64 / 1e6)
                }
                None => "-".into(),
            })
            .collect();
        let _ = writeln!(s, "| {kind} | {} |", cells.join(" | "));
    }
    s
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
