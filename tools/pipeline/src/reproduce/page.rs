//! `index.html`: one self-contained page (no scripts, no files it needs beside it) with every
//! table and its caption, the runs behind them (linked to their reports), what is not
//! reproduced yet, and the provenance: the biscale build, the machine and the date.

use super::published::Published;
use super::tables::{html_escape, html_text};
use crate::metrics::RunRecord;
use std::fmt::Write;

/// A run as the page lists it.
pub struct RunLine {
    pub name: String,
    pub config: String,
    pub vertices: usize,
    /// The mesh file, or how the command made it.
    pub mesh: String,
    pub seconds: f64,
}

pub struct Page<'a> {
    /// The command's own provenance record.
    pub record: &'a RunRecord,
    pub quick: bool,
    /// Each table's and figure's HTML, in the page's order.
    pub sections: &'a [String],
    pub runs: &'a [RunLine],
    pub published: &'a Published,
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}\
table{border-collapse:collapse;margin:1em 0}caption{caption-side:bottom;text-align:left;font-size:90%;\
color:#444;padding-top:.5em;max-width:1100px}th,td{padding:2px 8px;text-align:right;border-bottom:1px solid #ddd}\
th:first-child,td:first-child{text-align:left}.pair{border-left:1px solid #999}code{background:#f4f4f4}\
figure{margin:1em 0}.panel{display:inline-block;vertical-align:top;margin:0 .5% .5em 0;font-size:85%;text-align:center}\
.panel img{width:100%;image-rendering:pixelated}figcaption{font-size:90%;color:#444;max-width:1100px}";

/// What is not reproduced yet, one line each.
pub const NOT_YET: &[&str] = &[
    "The paper's own scenes: Table I's Armor and Chair are open stand-ins of the same character (the teapot \
     subdivided, a generated chair) with synthesized BTFs, not its scanned meshes and measured BTFs; Fig. 5 is made \
     on the bundled teapot and Fig. 6's comparison on the bundled bunny.",
    "A PDF of the tables: `tables/*.tex` are written, not typeset (they need `\\usepackage{booktabs}`).",
];

/// The page.
pub fn index(p: &Page<'_>) -> String {
    let r = p.record;
    let mut s = String::new();
    let _ = write!(
        s,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>biscale reproduce</title>\n\
         <style>{STYLE}</style>\n</head>\n<body>\n"
    );
    let _ = writeln!(
        s,
        "<h1>Radiance Transfer Biclustering (Sun, Hou, Ren, Zhou, Guo; IEEE TVCG), reproduced by biscale</h1>"
    );
    let git = match (&r.git_commit, r.git_dirty) {
        (Some(c), Some(true)) => format!("commit <code>{}</code> (with uncommitted changes)", html_escape(c)),
        (Some(c), _) => format!("commit <code>{}</code>", html_escape(c)),
        _ => "no git commit recorded".into(),
    };
    let _ = writeln!(
        s,
        "<p>{}. biscale {} ({git}, {}). Machine: {} ({}, {} cores, {} threads). Started {} UTC, {:.0} s wall. \
         Command: <code>{}</code>.</p>",
        if p.quick {
            "Made with <code>--quick</code>: every item at small sizes, to show the pipeline end to end; the figures \
             are not at the paper's scale"
        } else {
            "Every item at the paper's settings"
        },
        html_escape(&r.biscale_version),
        html_escape(&r.rustc),
        html_escape(&r.host),
        html_escape(&r.cpu_model),
        r.cores,
        r.threads,
        html_escape(&r.started_at),
        r.wall_seconds,
        html_escape(&r.command.join(" "))
    );
    let pl = &p.published.platform;
    let _ = writeln!(
        s,
        "<p>\"ours\": measured by the runs below on this machine, CPU only. \"paper\": the published figures \
         (<code>paper/published.toml</code>), measured on a {} ({}) with an {}; light {}, visibility {}, local \
         directions {}. Hover over an \"ours\" figure for its ratio to the paper's and its notes; \
         <a href=\"numbers.csv\">numbers.csv</a> has every figure, <code>tables/</code> the LaTeX.</p>",
        html_escape(&pl.cpu),
        html_escape(&pl.memory),
        html_escape(&pl.gpu),
        html_escape(&pl.light),
        html_escape(&pl.visibility),
        html_escape(&pl.local_directions)
    );
    for section in p.sections {
        s += section;
    }
    let _ = writeln!(s, "<h2>Runs</h2>\n<table>\n<tr><th>run</th><th>config</th><th>mesh</th><th>vertices</th><th>wall s</th><th>report</th></tr>");
    for run in p.runs {
        let _ = writeln!(
            s,
            "<tr><td>{}</td><td><code>{}</code></td><td>{}</td><td>{}</td><td>{:.1}</td><td><a href=\"runs/{}/report.html\">report</a></td></tr>",
            html_escape(&run.name),
            html_escape(&run.config),
            html_escape(&run.mesh),
            run.vertices,
            run.seconds,
            html_escape(&run.name)
        );
    }
    let _ = writeln!(s, "</table>\n<h2>Not reproduced yet</h2>\n<ul>");
    for line in NOT_YET {
        let _ = writeln!(s, "<li>{}</li>", html_text(line));
    }
    let _ = writeln!(s, "</ul>\n</body>\n</html>");
    s
}
