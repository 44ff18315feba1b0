//! The self-contained HTML report: the report's document model ([`crate::report::document`])
//! rendered as one page, every table a real `<table>` from the same [`Table`] that
//! `report.md` prints, and every plot and image embedded as a base64 data URI, so the one
//! file can be mailed or archived and opened without the program or the output folder (the
//! plots link to their SVG twins beside it).

use crate::metrics::Metrics;
use crate::report::{Block, Cell, Figure, Inline, Table};
use std::fmt::Write;
use std::path::Path;

/// Standard base64 (RFC 4648) with padding, as data URIs take it.
pub fn base64(bytes: &[u8]) -> String {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// The largest image a page embeds (a run's largest PNG is a few megabytes).
const MAX_EMBEDDED_BYTES: u64 = 256 << 20;

/// `<img>` with the PNG at `out_dir/rel` embedded, or a note when it is missing. Only a
/// regular file inside `out_dir` is read ([`biscale_core::io::inside_folder`]): a path that
/// is absolute, climbs out or passes through a link is noted as refused, never read.
fn img(out_dir: &Path, rel: &str, alt: &str) -> String {
    let path = match biscale_core::io::inside_folder(out_dir, rel) {
        Ok(p) => p,
        Err(why) => return format!("<em>{} refused: it {}</em>", escape(rel), escape(&why)),
    };
    match biscale_core::io::read_regular(&path, MAX_EMBEDDED_BYTES, "image") {
        Ok(bytes) => format!("<img alt=\"{}\" src=\"data:image/png;base64,{}\">", escape(alt), base64(&bytes)),
        Err(_) => format!("<em>{} missing</em>", escape(rel)),
    }
}

/// Markdown inline text as HTML: `` `code` ``, `[text](link)` and `![alt](image)` (a link to
/// the image) are marked up; everything else is escaped text.
pub fn inline(text: &str) -> String {
    let mut out = String::new();
    let mut rest = text;
    while !rest.is_empty() {
        if let Some(r) = rest.strip_prefix("![").or_else(|| rest.strip_prefix('[')) {
            if let Some((label, after)) = r.split_once("](") {
                if let Some((path, tail)) = after.split_once(')') {
                    if !label.contains('[') {
                        let _ = write!(out, "<a href=\"{}\">{}</a>", escape(path), escape(label));
                        rest = tail;
                        continue;
                    }
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
        let next = rest[first..].find(['!', '`', '[']).map_or(rest.len(), |i| i + first);
        out.push_str(&escape(&rest[..next]));
        rest = &rest[next..];
    }
    out
}

/// A heading's anchor: its words in lower case joined by `-` (`#equal-storage`).
fn anchor(text: &str) -> String {
    let words: Vec<String> =
        text.split(|c: char| !c.is_alphanumeric()).filter(|w| !w.is_empty()).map(|w| w.to_lowercase()).collect();
    words.join("-")
}

/// A table cell as HTML: text escaped, code and links marked up, images embedded.
fn cell(c: &Cell, out_dir: &Path) -> String {
    c.0.iter()
        .map(|i| match i {
            Inline::Text(t) => escape(t),
            Inline::Code(t) => format!("<code>{}</code>", escape(t)),
            Inline::Link { text, href } => format!("<a href=\"{}\">{}</a>", escape(href), escape(text)),
            // Linked to the file, to see it at full size beside the page.
            Inline::Image { src, alt } => format!("<a href=\"{}\">{}</a>", escape(src), img(out_dir, src, alt)),
            Inline::Break => "<br>".into(),
        })
        .collect()
}

/// A [`Table`] as an HTML `<table>`: the header as `<th>` cells, every row as `<td>` cells.
pub fn table(t: &Table, out_dir: &Path) -> String {
    let mut s = match t.class {
        Some(c) => format!("<table class=\"{c}\">"),
        None => "<table>".to_string(),
    };
    let head: String = t.header.iter().map(|h| format!("<th>{}</th>", escape(h))).collect();
    let _ = write!(s, "<tr>{head}</tr>");
    for row in &t.rows {
        let cells: String = row.iter().map(|c| format!("<td>{}</td>", cell(c, out_dir))).collect();
        let _ = write!(s, "<tr>{cells}</tr>");
    }
    s + "</table>"
}

fn figure(f: &Figure, out_dir: &Path) -> String {
    let picture = img(out_dir, &f.src, &f.caption);
    let picture = match &f.link {
        Some(link) => format!("<a href=\"{}\">{picture}</a>", escape(link)),
        None => picture,
    };
    let link = f.link.as_ref().map_or(String::new(), |l| format!(" (<a href=\"{}\">SVG</a>)", escape(l)));
    format!("<figure>{picture}<figcaption>{}{link}</figcaption></figure>", escape(&f.caption))
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}\
     table{border-collapse:collapse;font-size:13px;margin:0.5em 0}\
     td,th{border:1px solid #ccc;padding:3px 6px;text-align:right}th{background:#f3f3f3}\
     td:first-child{text-align:left;white-space:nowrap}img{max-width:100%}\
     table.figures{width:100%;table-layout:fixed}table.figures td,table.figures th{text-align:center;vertical-align:top}\
     table.figures td:first-child{text-align:left;width:12%;white-space:normal;overflow-wrap:anywhere}\
     table.figures img{width:100%;image-rendering:pixelated;display:block}\
     table.thumbnails img{width:160px;image-rendering:pixelated;display:block}\
     .grid{display:grid;grid-template-columns:repeat(auto-fill,minmax(320px,1fr));gap:12px}\
     .wide figure{margin:1em 0}.wide img{width:100%}\
     figure{margin:0}figcaption{font-size:13px;color:#555}pre{background:#f7f7f7;padding:8px;font-size:12px}";

/// The report page: [`crate::report::document`] as HTML, with the images of `out_dir`
/// embedded; `plots` are the plots written (PNG, caption).
pub fn html(m: &Metrics, plan_text: &str, out_dir: &Path, plots: &[(String, String)]) -> String {
    page(&m.experiment, crate::report::document(m, plan_text, plots), out_dir)
}

/// Blocks of the document model as one page titled `biscale: <title>`, with the images of
/// `out_dir` embedded.
pub fn page(title: &str, blocks: Vec<Block>, out_dir: &Path) -> String {
    let mut s = format!(
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>biscale: {}</title><style>{STYLE}</style></head><body>",
        escape(title)
    );
    for block in blocks {
        match block {
            Block::Heading(level, text) => {
                let l = level.clamp(1, 6);
                // Sections get an anchor (`report.html#comparison`).
                match l {
                    2 => write!(s, "<h2 id=\"{}\">{}</h2>", anchor(&text), inline(&text)),
                    _ => write!(s, "<h{l}>{}</h{l}>", inline(&text)),
                }
                .expect("writing to a String");
            }
            Block::Para(text) => {
                let _ = write!(s, "<p>{}</p>", inline(&text));
            }
            Block::List(items) => {
                let li: String = items.iter().map(|i| format!("<li>{}</li>", inline(i))).collect();
                let _ = write!(s, "<ul>{li}</ul>");
            }
            Block::Pre(text) => {
                let _ = write!(s, "<pre>{}</pre>", escape(text.trim_end()));
            }
            Block::Table(t) => s.push_str(&table(&t, out_dir)),
            Block::Figures { figures, wide } => {
                let class = if wide { "wide" } else { "grid" };
                let inner: String = figures.iter().map(|f| figure(f, out_dir)).collect();
                let _ = write!(s, "<div class=\"{class}\">{inner}</div>");
            }
        }
    }
    s + "</body></html>"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inline_markdown_becomes_code_and_links_and_the_rest_is_escaped() {
        assert_eq!(
            inline("Storage for `5%` & ![b](images/b.png) or [SVG](p.svg) < 2"),
            "Storage for <code>5%</code> &amp; <a href=\"images/b.png\">b</a> or <a href=\"p.svg\">SVG</a> &lt; 2"
        );
        // Multi-byte text, a lone `!` or `[` and an unclosed backtick pass through as text.
        assert_eq!(inline("≤ 5 µs! a [b `c"), "≤ 5 µs! a [b `c");
    }

    #[test]
    fn a_table_is_one_model_printed_as_markdown_and_as_html() {
        let mut t = Table::new(&["setting", "MB | bytes"]);
        t.text_row(["haar-t4", "<= 4.2"]);
        t.rows.push(vec![
            Cell(vec![
                Inline::Text("bicluster".into()),
                Inline::Break,
                Inline::Link { text: "EXR".into(), href: "images/b.exr".into() },
            ]),
            Cell::image("images/missing.png", "b"),
        ]);
        assert_eq!(
            t.markdown(),
            "| setting | MB \\| bytes |\n|---|---|\n| haar-t4 | <= 4.2 |\n\
             | bicluster<br>[EXR](images/b.exr) | ![b](images/missing.png) |\n"
        );
        let dir = std::env::temp_dir();
        assert_eq!(
            table(&t, &dir),
            "<table><tr><th>setting</th><th>MB | bytes</th></tr><tr><td>haar-t4</td><td>&lt;= 4.2</td></tr>\
             <tr><td>bicluster<br><a href=\"images/b.exr\">EXR</a></td>\
             <td><a href=\"images/missing.png\"><em>images/missing.png missing</em></a></td></tr></table>"
        );
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
