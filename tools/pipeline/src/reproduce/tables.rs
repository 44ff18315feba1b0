//! The tables of `biscale reproduce` as one model ([`PaperTable`]: columns, rows, each cell an
//! "ours" and a "paper" figure) written three ways: LaTeX with booktabs ([`latex`]), the rows
//! of `numbers.csv` ([`csv`]) and HTML ([`html`]). Captions are plain text in which
//! `` `code` `` is marked, so one caption serves the page and the paper.

use std::fmt::Write;

/// An "ours" figure that is a bound rather than a value (the equal-quality read-off).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Bound {
    #[default]
    Exact,
    /// At most this (the cheapest setting measured already meets the target).
    AtMost,
    /// More than this (no setting measured meets the target).
    MoreThan,
}

/// One column's pair of figures.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Cell {
    pub ours: Option<f64>,
    pub bound: Bound,
    pub paper: Option<f64>,
    /// Shown instead of the number (a text row: a setting's name).
    pub ours_text: Option<String>,
    pub paper_text: Option<String>,
    /// Why a figure is missing, or what to know of it (`numbers.csv`'s note).
    pub note: Option<String>,
    /// The run folder the "ours" figure comes from, relative to the output folder.
    pub source: Option<String>,
    /// The "ours" figure is a time taken while the machine's load exceeded its CPUs: marked
    /// `(busy)` in every table and said in `numbers.csv`, never shown as a plain result.
    pub busy: bool,
    /// The load the "ours" figure was timed under, `(peak 1-minute load, CPUs)`; `None` for a
    /// figure that is not a time. Printed in the caption of every table ([`load_sentence`]).
    pub load: Option<(f64, usize)>,
}

impl Cell {
    /// `ours / paper`, when both are there.
    pub fn ratio(&self) -> Option<f64> {
        match (self.ours, self.paper) {
            (Some(o), Some(p)) if p != 0.0 => Some(o / p),
            _ => None,
        }
    }
}

/// One row: a figure in every column.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    /// `numbers.csv`'s row key.
    pub key: String,
    pub label: String,
    pub unit: String,
    pub decimals: usize,
    /// A row of names, not numbers: shown in the tables, left out of `numbers.csv`.
    pub text: bool,
    pub cells: Vec<Cell>,
}

impl Row {
    /// A row of figures (`text: false`).
    pub fn numeric(key: &str, label: &str, unit: &str, decimals: usize, cells: Vec<Cell>) -> Self {
        Self { key: key.into(), label: label.into(), unit: unit.into(), decimals, text: false, cells }
    }
}

/// A column: a scene or a size, its "ours" and "paper" side by side, or "ours" alone where
/// the paper printed no figure (its Figs. 1 and 5 are images).
#[derive(Clone, Debug, PartialEq)]
pub struct Column {
    /// `numbers.csv`'s column key and the heading over the pair.
    pub name: String,
    /// Under the heading: what "ours" is here (`ours, 1,879 v.`).
    pub ours_head: String,
    /// Over the paper's figures; `None`: the column has no paper figures and is printed alone.
    pub paper_head: Option<String>,
}

impl Column {
    /// A column of ours beside the paper's.
    pub fn pair(name: impl Into<String>, ours_head: impl Into<String>, paper_head: impl Into<String>) -> Self {
        Self { name: name.into(), ours_head: ours_head.into(), paper_head: Some(paper_head.into()) }
    }

    /// A column of ours alone.
    pub fn ours(name: impl Into<String>, ours_head: impl Into<String>) -> Self {
        Self { name: name.into(), ours_head: ours_head.into(), paper_head: None }
    }

    /// How many printed columns it takes.
    fn span(&self) -> usize {
        1 + usize::from(self.paper_head.is_some())
    }
}

/// One table of the paper with our figures beside its own.
#[derive(Clone, Debug, PartialEq)]
pub struct PaperTable {
    /// The item (`--only`'s name).
    pub item: String,
    /// `tables/<file>.tex`.
    pub file: String,
    pub title: String,
    pub caption: String,
    pub columns: Vec<Column>,
    pub rows: Vec<Row>,
}

/// The caption's sentence that gives the load beside every timed figure: per timed row, each
/// column's 1-minute load in column order (`--` where the column has no time), so a reader of
/// the LaTeX or the page sees what `numbers.csv`'s notes say. `None` when nothing is timed.
pub fn load_sentence(t: &PaperTable) -> Option<String> {
    let cpus = t.rows.iter().flat_map(|r| &r.cells).find_map(|c| c.load.map(|(_, n)| n))?;
    let rows: Vec<String> = t
        .rows
        .iter()
        .filter(|r| r.cells.iter().any(|c| c.load.is_some()))
        .map(|r| {
            let loads: Vec<String> =
                r.cells.iter().map(|c| c.load.map_or("--".into(), |(l, _)| format!("{l:.1}"))).collect();
            format!("{} {}", r.label, loads.join(" / "))
        })
        .collect();
    let names: Vec<&str> = t.columns.iter().map(|c| c.name.as_str()).collect();
    Some(format!(
        "Load while timed (peak 1-minute average on {cpus} CPUs; {}): {}.",
        names.join(" / "),
        rows.join("; ")
    ))
}

/// The caption with its load sentence, as every table prints it.
fn full_caption(t: &PaperTable) -> String {
    match load_sentence(t) {
        Some(l) => format!("{} {l}", t.caption),
        None => t.caption.clone(),
    }
}

/// `numbers.csv`'s header.
pub const CSV_HEADER: &str = "item,row,column,ours,paper,ratio,unit,source,note";

/// A figure as the tables print it: `decimals` places, thousands grouped with commas.
pub fn number(x: f64, decimals: usize) -> String {
    if !x.is_finite() {
        return "--".into();
    }
    let s = format!("{:.decimals$}", x.abs());
    let (int, frac) = s.split_once('.').map_or((s.as_str(), None), |(i, f)| (i, Some(f)));
    let mut grouped = String::new();
    for (i, ch) in int.chars().enumerate() {
        if i > 0 && (int.len() - i) % 3 == 0 {
            grouped.push(',');
        }
        grouped.push(ch);
    }
    let sign = if x < 0.0 && s.chars().any(|c| c.is_ascii_digit() && c != '0') { "-" } else { "" };
    match frac {
        Some(f) => format!("{sign}{grouped}.{f}"),
        None => format!("{sign}{grouped}"),
    }
}

/// A published figure as the paper printed it (the shortest form of its value, `10.6`, `12`,
/// `0.62`, thousands grouped), or at `decimals` places when it has more than two (a figure
/// derived from published ones, such as non-zeros per vertex).
pub fn as_printed(x: f64, decimals: usize) -> String {
    let shortest = format!("{x}");
    match shortest.split_once('.') {
        Some((_, frac)) if frac.len() > 2 => number(x, decimals),
        Some((_, frac)) => number(x, frac.len()),
        None => number(x, 0),
    }
}

/// A cell's "ours" and "paper" text (`--` where there is no figure).
fn shown(c: &Cell, decimals: usize) -> (String, String) {
    let ours = match (&c.ours_text, c.ours) {
        (Some(t), _) => t.clone(),
        (None, Some(x)) => {
            let prefix = match c.bound {
                Bound::Exact => "",
                Bound::AtMost => "<= ",
                Bound::MoreThan => "> ",
            };
            let busy = if c.busy { " (busy)" } else { "" };
            format!("{prefix}{}{busy}", number(x, decimals))
        }
        (None, None) => "--".into(),
    };
    let paper = match (&c.paper_text, c.paper) {
        (Some(t), _) => t.clone(),
        (None, Some(x)) => as_printed(x, decimals),
        (None, None) => "--".into(),
    };
    (ours, paper)
}

/// A number for `numbers.csv`: Rust's shortest round-trip form, so a reader gets the very f64.
fn csv_number(x: Option<f64>) -> String {
    x.filter(|x| x.is_finite()).map_or(String::new(), |x| format!("{x}"))
}

fn csv_field(s: &str) -> String {
    match s.contains([',', '"', '\n']) {
        true => format!("\"{}\"", s.replace('"', "\"\"")),
        false => s.to_string(),
    }
}

/// `numbers.csv`: [`CSV_HEADER`], then one line per numeric figure of every table.
pub fn csv(tables: &[PaperTable]) -> String {
    let mut s = format!("{CSV_HEADER}\n");
    for t in tables {
        for r in t.rows.iter().filter(|r| !r.text) {
            for (col, c) in t.columns.iter().zip(&r.cells) {
                let mut note = c.note.clone().unwrap_or_default();
                let bound = match c.bound {
                    Bound::Exact => "",
                    Bound::AtMost => "an upper bound: the cheapest setting measured already meets the target",
                    Bound::MoreThan => "a lower bound: no setting measured meets the target",
                };
                if !bound.is_empty() && c.ours.is_some() {
                    note = if note.is_empty() { bound.into() } else { format!("{bound}; {note}") };
                }
                if c.busy && c.ours.is_some() {
                    let busy = "BUSY: timed while the load exceeded the CPUs, not a result";
                    note = if note.is_empty() { busy.into() } else { format!("{busy}; {note}") };
                }
                let fields = [
                    csv_field(&t.item),
                    csv_field(&r.key),
                    csv_field(&col.name),
                    csv_number(c.ours),
                    csv_number(c.paper),
                    csv_number(c.ratio()),
                    csv_field(&r.unit),
                    csv_field(c.source.as_deref().unwrap_or("")),
                    csv_field(&note),
                ];
                let _ = writeln!(s, "{}", fields.join(","));
            }
        }
    }
    s
}

/// Text escaped for LaTeX.
pub fn latex_escape(s: &str) -> String {
    let mut out = String::new();
    for ch in s.chars() {
        match ch {
            '\\' => out.push_str("\\textbackslash{}"),
            '&' | '%' | '$' | '#' | '_' | '{' | '}' => {
                out.push('\\');
                out.push(ch);
            }
            '~' => out.push_str("\\textasciitilde{}"),
            '|' => out.push_str("\\textbar{}"),
            '^' => out.push_str("\\textasciicircum{}"),
            '<' => out.push_str("$<$"),
            '>' => out.push_str("$>$"),
            _ => out.push(ch),
        }
    }
    out
}

/// Caption text as LaTeX: `` `code` `` as `\texttt`, the rest escaped.
fn latex_text(s: &str) -> String {
    s.split('`')
        .enumerate()
        .map(|(i, part)| match i % 2 {
            1 => format!("\\texttt{{{}}}", latex_escape(part)),
            _ => part.split("<=").map(latex_escape).collect::<Vec<_>>().join("$\\le$"),
        })
        .collect()
}

/// A float's caption: what of the paper it reproduces, then what it shows (`body`, LaTeX
/// already). LaTeX numbers the float itself, so the paper's own title is said as the paper's,
/// not printed as a second title (`Table 1: Table I: ...`).
pub fn latex_caption(title: &str, body: &str) -> String {
    format!("Reproducing the paper's {}. {body}", latex_escape(title.trim_end_matches('.')))
}

/// A one-column heading set on two or more lines where it has parts (`all-frequency, raw T`,
/// `SH order 2 (equal storage)`): a column is then as wide as its longest part, not its whole
/// name (a nested tabular: no package needed).
fn latex_stacked(name: &str) -> String {
    let lines: Vec<String> = name.replace(" (", "\n(").replace(", ", ",\n").split('\n').map(latex_escape).collect();
    match lines.len() {
        1 => lines[0].clone(),
        _ => format!("\\begin{{tabular}}[b]{{@{{}}c@{{}}}}{}\\end{{tabular}}", lines.join("\\\\")),
    }
}

/// A cell's figure as LaTeX (`<=` and `>` as math, `--` as an en dash).
fn latex_figure(s: &str) -> String {
    match s {
        "--" => "--".into(),
        _ => match (s.strip_prefix("<= "), s.strip_prefix("> ")) {
            (Some(x), _) => format!("$\\le$ {}", latex_escape(x)),
            (_, Some(x)) => format!("$>$ {}", latex_escape(x)),
            _ => latex_escape(s),
        },
    }
}

/// The most data columns one LaTeX tabular holds: wider tables are split into stacked
/// tabulars of whole columns (Table I's four scenes into two of two), so that each fits a
/// 17 cm text width at `\small` without being scaled below print size.
const LATEX_MAX_SPANS: usize = 6;

/// The table as a LaTeX `table` float (booktabs: `\toprule`, `\midrule`, `\bottomrule`), a
/// pair of columns per scene, "ours" left of "paper"; more than [`LATEX_MAX_SPANS`] data
/// columns are split into as few stacked tabulars as that allows, as even as whole columns go,
/// each repeating the row labels. A tabular still wider than the line (a long row label) is
/// scaled down to it; a narrower one is left at its size.
pub fn latex(t: &PaperTable) -> String {
    let mut s = String::new();
    let _ =
        writeln!(s, "% Written by `biscale reproduce`; needs \\usepackage{{booktabs}} and \\usepackage{{graphicx}}.");
    let _ = writeln!(s, "\\begin{{table*}}[t]\n\\centering\n\\small");
    let _ = writeln!(s, "\\caption{{{}}}", latex_caption(&t.title, &latex_text(&full_caption(t))));
    let _ = writeln!(s, "\\label{{tab:reproduce-{}}}", t.file.replace('_', "-"));
    let spans: usize = t.columns.iter().map(Column::span).sum();
    let groups = spans.div_ceil(LATEX_MAX_SPANS).max(1);
    let (mut start, mut used) = (0, 0);
    for g in 0..groups {
        // Whole columns up to this group's share of the spans.
        let share = (spans * (g + 1)).div_ceil(groups);
        let mut end = start;
        while end < t.columns.len() && (used + t.columns[end].span() <= share || end == start) {
            used += t.columns[end].span();
            end += 1;
        }
        if g + 1 == groups {
            end = t.columns.len();
        }
        if end > start {
            if start > 0 {
                let _ = writeln!(s, "\\par\\medskip");
            }
            s += &latex_tabular(t, start..end);
        }
        start = end;
    }
    let _ = writeln!(s, "\\end{{table*}}");
    s
}

/// One tabular of `t`: its row labels and units, and the columns `range`.
fn latex_tabular(t: &PaperTable, range: std::ops::Range<usize>) -> String {
    let mut s = String::new();
    let cols = &t.columns[range.clone()];
    let spans: usize = cols.iter().map(Column::span).sum();
    let _ = writeln!(s, "\\resizebox{{\\ifdim\\width>\\linewidth\\linewidth\\else\\width\\fi}}{{!}}{{%");
    let _ = writeln!(s, "\\begin{{tabular}}{{ll{}}}", "r".repeat(spans));
    let _ = writeln!(s, "\\toprule");
    let heads: Vec<String> = cols
        .iter()
        .map(|c| match c.span() {
            1 => latex_stacked(&c.name),
            n => format!("\\multicolumn{{{n}}}{{c}}{{{}}}", latex_escape(&c.name)),
        })
        .collect();
    let _ = writeln!(s, " & & {} \\\\", heads.join(" & "));
    let mut rules = vec![];
    let mut at = 3;
    for c in cols {
        if c.span() == 2 {
            rules.push(format!("\\cmidrule(lr){{{}-{}}}", at, at + 1));
        }
        at += c.span();
    }
    if !rules.is_empty() {
        let _ = writeln!(s, "{}", rules.join(" "));
    }
    let sub: Vec<String> = cols
        .iter()
        .map(|c| match &c.paper_head {
            Some(p) => format!("{} & {}", latex_escape(&c.ours_head), latex_escape(p)),
            None => latex_escape(&c.ours_head),
        })
        .collect();
    let _ = writeln!(s, " & unit & {} \\\\", sub.join(" & "));
    let _ = writeln!(s, "\\midrule");
    for r in &t.rows {
        let cells: Vec<String> = cols
            .iter()
            .zip(&r.cells[range.clone()])
            .map(|(col, c)| {
                let (o, p) = shown(c, r.decimals);
                match col.paper_head {
                    Some(_) => format!("{} & {}", latex_figure(&o), latex_figure(&p)),
                    None => latex_figure(&o),
                }
            })
            .collect();
        let _ = writeln!(s, "{} & {} & {} \\\\", latex_escape(&r.label), latex_escape(&r.unit), cells.join(" & "));
    }
    let _ = writeln!(s, "\\bottomrule\n\\end{{tabular}}}}");
    s
}

/// Text escaped for HTML.
pub fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// Caption text as HTML: `` `code` `` as `<code>`, the rest escaped.
pub fn html_text(s: &str) -> String {
    s.split('`')
        .enumerate()
        .map(|(i, part)| match i % 2 {
            1 => format!("<code>{}</code>", html_escape(part)),
            _ => html_escape(part),
        })
        .collect()
}

/// The table as an HTML `<table>` with its caption, each cell's note as its title.
pub fn html(t: &PaperTable) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "<h2 id=\"{}\">{}</h2>", html_escape(&t.file), html_escape(&t.title));
    let _ = writeln!(s, "<table>\n<caption>{}</caption>", html_text(&full_caption(t)));
    let heads: String = t
        .columns
        .iter()
        .map(|c| format!("<th colspan=\"{}\" class=\"pair\">{}</th>", c.span(), html_escape(&c.name)))
        .collect();
    let _ = writeln!(s, "<tr><th></th><th></th>{heads}</tr>");
    let sub: String = t
        .columns
        .iter()
        .map(|c| match &c.paper_head {
            Some(p) => format!("<th class=\"pair\">{}</th><th>{}</th>", html_escape(&c.ours_head), html_escape(p)),
            None => format!("<th class=\"pair\">{}</th>", html_escape(&c.ours_head)),
        })
        .collect();
    let _ = writeln!(s, "<tr><th>figure</th><th>unit</th>{sub}</tr>");
    for r in &t.rows {
        let cells: String = t
            .columns
            .iter()
            .zip(&r.cells)
            .map(|(col, c)| {
                let (o, p) = shown(c, r.decimals);
                let mut title = c.note.clone().unwrap_or_default();
                if let Some(x) = c.ratio() {
                    title = format!("ours / paper = {x:.3}{}{title}", if title.is_empty() { "" } else { "; " });
                }
                let attr = if title.is_empty() { String::new() } else { format!(" title=\"{}\"", html_escape(&title)) };
                match col.paper_head {
                    Some(_) => format!("<td class=\"pair\"{attr}>{}</td><td>{}</td>", html_escape(&o), html_escape(&p)),
                    None => format!("<td class=\"pair\"{attr}>{}</td>", html_escape(&o)),
                }
            })
            .collect();
        let _ = writeln!(s, "<tr><td>{}</td><td>{}</td>{cells}</tr>", html_escape(&r.label), html_escape(&r.unit));
    }
    let _ = writeln!(s, "</table>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table() -> PaperTable {
        let cell = |ours, paper| Cell { ours, paper, source: Some("runs/bunny".into()), ..Cell::default() };
        PaperTable {
            item: "table1".into(),
            file: "table1".into(),
            title: "Table I".into(),
            caption: "Ours from `runs/bunny`, 50% of the paper's & more".into(),
            columns: vec![Column::pair("Bunny", "ours", "paper"), Column::pair("Armor", "ours", "paper")],
            rows: vec![
                Row {
                    key: "data_size".into(),
                    label: "data size".into(),
                    unit: "MB".into(),
                    decimals: 0,
                    text: false,
                    cells: vec![
                        cell(Some(1292.107776), Some(1400.0)),
                        Cell { note: Some("not reproduced: no mesh".into()), ..cell(None, Some(9500.0)) },
                    ],
                },
                Row {
                    key: "setting".into(),
                    label: "setting".into(),
                    unit: String::new(),
                    decimals: 0,
                    text: true,
                    cells: vec![
                        Cell { ours_text: Some("cpca-k32-c8".into()), ..Cell::default() },
                        Cell { bound: Bound::AtMost, ..cell(Some(5.5), None) },
                    ],
                },
            ],
        }
    }

    /// A heading with parts is stacked (one line a part), a plain one left alone; bars are
    /// escaped for text mode; the caption says which of the paper's floats it reproduces
    /// without repeating a title; more than six data columns split into stacked tabulars.
    #[test]
    fn latex_fits_a_page_and_escapes_text_mode_symbols() {
        assert_eq!(latex_stacked("Bunny"), "Bunny");
        assert_eq!(
            latex_stacked("SH order 2 (equal storage)"),
            "\\begin{tabular}[b]{@{}c@{}}SH order 2\\\\(equal storage)\\end{tabular}"
        );
        assert_eq!(latex_escape("|error|"), "\\textbar{}error\\textbar{}");
        let mut t = table();
        let tex = latex(&t);
        assert!(tex.contains("\\caption{Reproducing the paper's Table I. Ours from"), "{tex}");
        assert_eq!(tex.matches("\\begin{tabular}{ll").count(), 1);
        let wide: Vec<Column> = (0..4).map(|i| Column::pair(format!("S{i}"), "ours", "paper")).collect();
        t.columns = wide;
        for r in &mut t.rows {
            r.cells = (0..4).map(|_| r.cells[0].clone()).collect();
        }
        let tex = latex(&t);
        assert_eq!(tex.matches("\\begin{tabular}{llrrrr}").count(), 2, "{tex}");
        assert!(
            tex.find("S1").unwrap() < tex.find("\\medskip").unwrap()
                && tex.find("S2").unwrap() > tex.find("\\medskip").unwrap()
        );
    }

    /// Every timed figure's load is printed in the caption of the LaTeX and HTML tables, in
    /// column order, with `--` for a column without a time; a table with no time has none.
    #[test]
    fn the_load_of_every_timed_figure_is_in_the_caption() {
        let mut t = table();
        assert_eq!(load_sentence(&t), None);
        t.rows[0].cells[1].load = Some((0.84, 2));
        let sentence = load_sentence(&t).unwrap();
        assert_eq!(sentence, "Load while timed (peak 1-minute average on 2 CPUs; Bunny / Armor): data size -- / 0.8.");
        assert!(latex(&t).contains("data size -- / 0.8."), "{}", latex(&t));
        assert!(html(&t).contains(&html_text(&sentence)), "{}", html(&t));
    }

    /// A time taken on a busy machine is marked in the HTML and LaTeX tables and said in
    /// `numbers.csv`, before any other note; an unmarked one is printed plain.
    #[test]
    fn a_busy_time_is_marked_everywhere_it_is_printed() {
        let mut t = table();
        t.rows[0].cells[0].busy = true;
        t.rows[0].cells[0].note = Some("timed at load 6.5 on 2 CPUs".into());
        let (tex, page, numbers) = (latex(&t), html(&t), csv(std::slice::from_ref(&t)));
        assert!(tex.contains("1,292 (busy)") && page.contains("1,292 (busy)"), "{tex}\n{page}");
        let line = numbers.lines().find(|l| l.contains("data_size") && l.contains("Bunny")).unwrap();
        assert!(
            line.contains("BUSY: timed while the load exceeded the CPUs, not a result; timed at load 6.5"),
            "{line}"
        );
        t.rows[0].cells[0].busy = false;
        assert!(!latex(&t).contains("(busy)") && !csv(&[t]).contains("BUSY"));
    }

    #[test]
    fn numbers_are_grouped_and_rounded() {
        assert_eq!(number(1292.107776, 0), "1,292");
        assert_eq!(number(18858.6, 0), "18,859");
        assert_eq!(number(0.6234, 2), "0.62");
        assert_eq!(number(123456.789, 1), "123,456.8");
        assert_eq!(number(-1234.5, 1), "-1,234.5");
        assert_eq!(number(f64::NAN, 1), "--");
        assert_eq!(as_printed(10.6, 2), "10.6");
        assert_eq!(as_printed(1400.0, 2), "1,400");
        assert_eq!(as_printed(0.62, 1), "0.62");
        assert_eq!(as_printed(3225.8064516129034, 0), "3,226");
    }

    #[test]
    fn latex_has_booktabs_rules_pairs_and_escapes() {
        let tex = latex(&table());
        for rule in ["\\toprule", "\\midrule", "\\bottomrule", "\\cmidrule(lr){3-4}", "\\cmidrule(lr){5-6}"] {
            assert!(tex.contains(rule), "{rule}: {tex}");
        }
        assert!(tex.contains("\\begin{tabular}{llrrrr}"), "{tex}");
        assert!(tex.contains("data size & MB & 1,292 & 1,400 & -- & 9,500 \\\\"), "{tex}");
        assert!(tex.contains("\\texttt{runs/bunny}, 50\\% of the paper's \\& more"), "{tex}");
        assert!(tex.contains("cpca-k32-c8 & -- & $\\le$ 6 & --"), "{tex}");
        assert_eq!(latex_escape("a_b#c~<"), "a\\_b\\#c\\textasciitilde{}$<$");
        assert_eq!(latex_text("at most (<=) or `a_b`"), "at most ($\\le$) or \\texttt{a\\_b}");
    }

    #[test]
    fn a_column_without_paper_figures_is_printed_alone() {
        let mut t = table();
        t.columns[1] = Column::ours("SH order 5", "ours");
        let tex = latex(&t);
        assert!(tex.contains("\\begin{tabular}{llrrr}"), "{tex}");
        assert!(tex.contains("\\cmidrule(lr){3-4}") && !tex.contains("{5-6}"), "{tex}");
        assert!(tex.contains(" & & \\multicolumn{2}{c}{Bunny} & SH order 5 \\\\"), "{tex}");
        assert!(tex.contains("data size & MB & 1,292 & 1,400 & -- \\\\"), "{tex}");
        let h = html(&t);
        assert!(h.contains("<th colspan=\"1\" class=\"pair\">SH order 5</th>"), "{h}");
        assert!(h.contains("<th class=\"pair\">ours</th><th>paper</th><th class=\"pair\">ours</th></tr>"), "{h}");
    }

    #[test]
    fn csv_has_a_line_per_numeric_figure_with_the_ratio() {
        let csv = csv(&[table()]);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], CSV_HEADER);
        assert_eq!(lines.len(), 3, "{csv}");
        assert_eq!(
            lines[1],
            format!("table1,data_size,Bunny,1292.107776,1400,{},MB,runs/bunny,", 1292.107776 / 1400.0)
        );
        assert_eq!(lines[2], "table1,data_size,Armor,,9500,,MB,runs/bunny,not reproduced: no mesh");
    }

    #[test]
    fn html_escapes_and_titles_cells_with_the_ratio() {
        let h = html(&table());
        assert!(
            h.contains("<caption>Ours from <code>runs/bunny</code>, 50% of the paper's &amp; more</caption>"),
            "{h}"
        );
        assert!(h.contains("title=\"ours / paper = 0.923\""), "{h}");
        assert!(h.contains("&lt;= 6"), "{h}");
    }
}
