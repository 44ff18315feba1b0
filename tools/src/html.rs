//! The self-contained HTML report: the Markdown report's tables plus every plot and image
//! embedded as base64 data URIs, so the one file can be mailed or archived and opened
//! without the program or the output folder.

use crate::metrics::Metrics;
use std::fmt::Write;
use std::path::Path;

/// Standard base64 (RFC 4648) with padding.
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for chunk in bytes.chunks(3) {
        let b = [chunk[0], *chunk.get(1).unwrap_or(&0), *chunk.get(2).unwrap_or(&0)];
        let n = (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32;
        for i in 0..4 {
            if i <= chunk.len() {
                s.push(A[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// `<img>` with the PNG at `out_dir/rel` embedded, or a note when it is missing.
fn img(out_dir: &Path, rel: &str, alt: &str) -> String {
    match std::fs::read(out_dir.join(rel)) {
        Ok(bytes) => format!("<img alt=\"{}\" src=\"data:image/png;base64,{}\">", escape(alt), base64(&bytes)),
        Err(_) => format!("<p><em>{} missing</em></p>", escape(rel)),
    }
}

/// The small Markdown the report's comparison sections use, as HTML: `##`/`###` headings,
/// pipe tables (first row the header, the `|---|` row dropped), paragraphs, and inline
/// `` `code` `` and images, which become links to the file (the page shows them embedded
/// below the tables). Everything else is escaped text.
pub fn markdown_to_html(md: &str) -> String {
    fn inline(text: &str) -> String {
        let mut out = String::new();
        let mut rest = text;
        while !rest.is_empty() {
            if let Some(r) = rest.strip_prefix("![") {
                if let Some((alt, after)) = r.split_once("](") {
                    if let Some((path, tail)) = after.split_once(')') {
                        let _ = write!(out, "<a href=\"{}\">{}</a>", escape(path), escape(alt));
                        rest = tail;
                        continue;
                    }
                }
            }
            if let Some(r) = rest.strip_prefix('`') {
                if let Some((code, tail)) = r.split_once('`') {
                    let _ = write!(out, "<code>{}</code>", escape(code));
                    rest = tail;
                    continue;
                }
            }
            // Past the first character (which may be several bytes), up to the next marker.
            let first = rest.chars().next().map_or(1, char::len_utf8);
            let next = rest[first..].find(['!', '`']).map_or(rest.len(), |i| i + first);
            out.push_str(&escape(&rest[..next]));
            rest = &rest[next..];
        }
        out
    }
    let row = |line: &str| -> Vec<String> {
        let t = line.trim().trim_start_matches('|').trim_end_matches('|');
        t.split('|').map(|c| inline(c.trim())).collect()
    };
    let mut out = String::new();
    let mut para: Vec<&str> = vec![];
    let flush = |para: &mut Vec<&str>, out: &mut String| {
        if !para.is_empty() {
            let _ = write!(out, "<p>{}</p>", inline(&para.join(" ")));
            para.clear();
        }
    };
    let lines: Vec<&str> = md.lines().collect();
    let mut i = 0;
    while i < lines.len() {
        let line = lines[i].trim_end();
        if let Some(h) = line.strip_prefix("### ") {
            flush(&mut para, &mut out);
            let _ = write!(out, "<h3>{}</h3>", inline(h));
        } else if let Some(h) = line.strip_prefix("## ") {
            flush(&mut para, &mut out);
            let _ = write!(out, "<h2>{}</h2>", inline(h));
        } else if line.starts_with('|') {
            flush(&mut para, &mut out);
            let _ = write!(out, "<table>");
            let mut first = true;
            while i < lines.len() && lines[i].trim_start().starts_with('|') {
                let l = lines[i];
                let is_rule = l.chars().all(|c| matches!(c, '|' | '-' | ':' | ' '));
                if !is_rule {
                    let tag = if first { "th" } else { "td" };
                    let cells: String = row(l).iter().map(|c| format!("<{tag}>{c}</{tag}>")).collect();
                    let _ = write!(out, "<tr>{cells}</tr>");
                    first = false;
                }
                i += 1;
            }
            let _ = write!(out, "</table>");
            continue;
        } else if line.trim().is_empty() {
            flush(&mut para, &mut out);
        } else {
            para.push(line.trim());
        }
        i += 1;
    }
    flush(&mut para, &mut out);
    out
}

/// The report page. `markdown_tables` is reused from the Markdown report as preformatted text
/// where a table would add nothing.
pub fn html(m: &Metrics, plan_text: &str, out_dir: &Path, plots: &[(String, String)]) -> String {
    let mut s = String::new();
    let _ = write!(
        s,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>biscale: {name}</title><style>\
         body{{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}}\
         table{{border-collapse:collapse;font-size:13px}}td,th{{border:1px solid #ccc;padding:3px 6px;text-align:right}}\
         th{{background:#f3f3f3}}td:first-child{{text-align:left}}img{{max-width:100%}}\
         .grid{{display:grid;grid-template-columns:repeat(auto-fill,minmax(320px,1fr));gap:12px}}\
         figure{{margin:0}}figcaption{{font-size:13px;color:#555}}pre{{background:#f7f7f7;padding:8px;font-size:12px}}\
         </style></head><body><h1>biscale run: {name}</h1>",
        name = escape(&m.experiment)
    );
    let _ = write!(s, "<p>Config <code>{}</code>, backend {}.</p>", escape(&m.config), escape(&m.backend));
    if let Some(r) = &m.run {
        let _ = write!(
            s,
            "<p>Run: {}.</p><table><tr><th>stage</th><th>wall s</th><th>CPU s</th></tr>",
            escape(&r.summary())
        );
        for t in &r.stages {
            let cpu = t.cpu_seconds.map_or("?".into(), |c| format!("{c:.2}"));
            let _ = write!(s, "<tr><td>{}</td><td>{:.2}</td><td>{cpu}</td></tr>", escape(&t.stage), t.wall_seconds);
        }
        s += "</table>";
    }
    let _ = write!(s, "<pre>{}</pre>", escape(plan_text));
    let _ = write!(
        s,
        "<h2>Scene and transfer</h2><p>{} vertices, {} triangles, material {}. Light {} (total power {:.4}, {:.4}, {:.4}).</p>\
         <p>{}</p>",
        m.scene.vertices,
        m.scene.triangles,
        escape(&m.scene.material),
        escape(&m.lighting.source),
        m.lighting.total_power[0],
        m.lighting.total_power[1],
        m.lighting.total_power[2],
        escape(&crate::report::transfer_summary(&m.transfer)),
    );
    let cells =
        |tag: &str, row: &[String]| row.iter().map(|c| format!("<{tag}>{}</{tag}>", escape(c))).collect::<String>();
    if let Some(b) = crate::report::btf_table(m) {
        let header: Vec<String> = b.header.iter().map(|h| h.to_string()).collect();
        let _ = write!(s, "<h3>BTFs</h3><table><tr>{}</tr>", cells("th", &header));
        for row in &b.rows {
            let _ = write!(s, "<tr>{}</tr>", cells("td", row));
        }
        let _ = write!(s, "</table><p>{}</p><div class=\"grid\">", escape(&b.total));
        for (png, caption) in &b.figures {
            let _ = write!(
                s,
                "<figure>{}<figcaption>{}</figcaption></figure>",
                img(out_dir, png, caption),
                escape(caption)
            );
        }
        let _ = write!(s, "</div>");
    }
    let (header, rows) = crate::report::compressor_table(m);
    let header: Vec<String> = header.iter().map(|h| h.to_string()).collect();
    let _ = write!(s, "<h2>Compressors</h2><table><tr>{}</tr>", cells("th", &header));
    for row in rows {
        let _ = write!(s, "<tr>{}</tr>", cells("td", &row));
    }
    let _ = write!(s, "</table>{}", markdown_to_html(crate::report::LDR_NOTE));
    if let Some(r) = &m.reference {
        let _ = write!(
            s,
            "<p>Ground truth (direct light) traced per pixel at {}x{} in {:.1} s (each pixel's own visibility, each texel's own cosine, the BRDF at each texel's own direction); error of the uncompressed vertex render against it: RMSE {:.4}, PSNR {:.2} dB; LDR PSNR / SSIM / FLIP {}.</p>",
            r.width, r.height, r.seconds, r.uncompressed_vs_reference.rmse, r.uncompressed_vs_reference.psnr,
            crate::report::ldr_cell(&r.uncompressed_vs_reference)
        );
    }
    // One paragraph, its config keys as code, as in report.md.
    let _ = write!(s, "{}", markdown_to_html(&crate::report::light_moments_summary(m)));
    let comparisons = crate::report::comparisons_markdown(m);
    if !comparisons.is_empty() {
        // The comparison sections as HTML tables, with the equal-storage images below.
        let _ = write!(s, "{}", markdown_to_html(&comparisons));
        if let Some((budget, _)) = crate::report::storage_budget(m) {
            let _ = write!(s, "<div class=\"grid\">");
            for r in crate::compare::equal_storage(&m.compressors, budget) {
                let _ = write!(
                    s,
                    "<figure>{}<figcaption>{} ({:.2} MB)</figcaption></figure>",
                    img(out_dir, &r.image.png, &r.name),
                    escape(&r.name),
                    r.bytes as f64 / 1e6
                );
                if let Some(e) = &r.image.error_png {
                    let _ = write!(
                        s,
                        "<figure>{}<figcaption>{}: error</figcaption></figure>",
                        img(out_dir, e, &r.name),
                        escape(&r.name)
                    );
                }
            }
            let _ = write!(s, "</div>");
        }
    }
    if let Some(l) = crate::report::low_vs_all(m) {
        let header: Vec<String> = l.header.iter().map(|h| h.to_string()).collect();
        let _ = write!(s, "<h2>Low- vs all-frequency</h2><table><tr>{}</tr>", cells("th", &header));
        for row in &l.rows {
            let _ = write!(s, "<tr>{}</tr>", cells("td", row));
        }
        let _ = write!(s, "</table><div class=\"grid\">");
        for (png, caption) in &l.figures {
            let _ = write!(
                s,
                "<figure>{}<figcaption>{}</figcaption></figure>",
                img(out_dir, png, caption),
                escape(caption)
            );
        }
        let _ = write!(s, "</div>");
    }
    if !plots.is_empty() {
        let _ = write!(s, "<h2>Plots</h2><div class=\"grid\">");
        for (rel, caption) in plots {
            let _ = write!(
                s,
                "<figure>{}<figcaption>{}</figcaption></figure>",
                img(out_dir, rel, caption),
                escape(caption)
            );
        }
        let _ = write!(s, "</div>");
    }
    let _ = write!(s, "<h2>Images</h2><div class=\"grid\">");
    let _ = write!(
        s,
        "<figure>{}<figcaption>uncompressed T</figcaption></figure>",
        img(out_dir, "images/uncompressed.png", "uncompressed")
    );
    if m.reference.is_some() {
        let _ = write!(
            s,
            "<figure>{}<figcaption>ground truth (direct light)</figcaption></figure>",
            img(out_dir, "images/reference.png", "reference")
        );
    }
    for c in &m.compressors {
        let _ = write!(
            s,
            "<figure>{}<figcaption>{}</figcaption></figure>",
            img(out_dir, &c.image.png, &c.name),
            escape(&c.name)
        );
        if let Some(e) = &c.image.error_png {
            let _ = write!(
                s,
                "<figure>{}<figcaption>{}: |error| against the uncompressed render (full scale {}, shared; largest {})</figcaption></figure>",
                img(out_dir, e, &c.name),
                escape(&c.name),
                crate::plots::tick_label(c.image.error_scale.unwrap_or(0.0) as f64),
                crate::plots::tick_label(c.image.error_max.unwrap_or(0.0) as f64)
            );
        }
    }
    let _ = write!(s, "</div></body></html>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn comparison_markdown_becomes_tables_headings_and_links() {
        // Regression: report.html printed these sections as raw Markdown in <pre>.
        let md = "\n## Equal quality\n\nStorage for `5%` (log-log):\n\n| compressor | MB |\n|---|---|\n\
                  | haar | <= 4.2 |\n| bicluster | ![b](images/b.png) & more |\n\nAfter.\n";
        let h = markdown_to_html(md);
        assert_eq!(
            h,
            "<h2>Equal quality</h2><p>Storage for <code>5%</code> (log-log):</p>\
             <table><tr><th>compressor</th><th>MB</th></tr><tr><td>haar</td><td>&lt;= 4.2</td></tr>\
             <tr><td>bicluster</td><td><a href=\"images/b.png\">b</a> &amp; more</td></tr></table><p>After.</p>"
        );
        assert!(!h.contains("|---|") && !h.contains("!["));
        // Multi-byte text, a lone `!` and an unclosed backtick pass through as text.
        assert_eq!(markdown_to_html("≤ 5 µs! a `b"), "<p>≤ 5 µs! a `b</p>");
    }

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }
}
