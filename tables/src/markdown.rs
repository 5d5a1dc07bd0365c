//! Markdown: one pipe table per block (Markdown has no spanning headers), the
//! same numbers as the LaTeX table, bold as `**mean**`.

use crate::caption::{caption, Style};
use crate::model::{Group, Row, TableModel, Value};
use crate::numfmt::{markdown_escape, percent};
use crate::TableKind;
use std::fmt::Write;

fn group_title(kind: TableKind, g: &Group) -> String {
    if kind == TableKind::Datasize {
        format!("{}, {} % data", g.task, percent(g.data_fraction))
    } else {
        g.task.clone()
    }
}

fn row_label(row: &Row, annotate_source: bool) -> String {
    let mut s = markdown_escape(&row.method);
    if row.dagger() {
        s.push_str(Style::Plain.dagger());
    }
    if row.ddagger() {
        s.push_str(Style::Plain.ddagger());
    }
    let ann = row.annotations(annotate_source);
    if !ann.is_empty() {
        let _ = write!(s, " ({})", markdown_escape(&ann.join(", ")));
    }
    s
}

fn cell(v: &Option<Value>) -> String {
    match v {
        None => "–".to_string(),
        Some(v) => {
            let mean = if v.bold {
                format!("**{}**", v.mean_text())
            } else {
                v.mean_text()
            };
            if v.shows_spread() {
                format!("{mean} ± {}", v.std_text())
            } else {
                mean
            }
        }
    }
}

pub fn render(m: &TableModel) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "**D3IL {} table ({} observations, {} results).** {}",
        m.kind,
        m.obs,
        m.source.as_str(),
        markdown_escape(&caption(m, Style::Plain))
    );
    for block in &m.blocks {
        out.push('\n');
        let mut header = vec!["Method".to_string()];
        for g in &block.groups {
            let title = markdown_escape(&group_title(m.kind, g));
            for metric in &g.metrics {
                header.push(format!("{title} {}", metric.title()));
            }
        }
        let _ = writeln!(out, "| {} |", header.join(" | "));
        let align: Vec<&str> = header
            .iter()
            .enumerate()
            .map(|(i, _)| if i == 0 { ":--" } else { "--:" })
            .collect();
        let _ = writeln!(out, "| {} |", align.join(" | "));
        for row in &block.rows {
            let mut cells = vec![row_label(row, m.annotate_source())];
            cells.extend(row.values.iter().flatten().map(cell));
            let _ = writeln!(out, "| {} |", cells.join(" | "));
        }
    }
    out
}
