//! The zoo's table (`d3il tables --table zoo`): the paper's
//! methods trained here with the reference code on demonstrations recorded
//! from our tasks, evaluated here. A table of its own, one per data source:
//! these are not the paper's numbers, so they are never mixed or ranked
//! with its rows (the paper tables leave them out).

use crate::numfmt::{latex_escape, markdown_escape, mean_std, three_decimals};
use crate::{write_csv, Format, TablesError};
use d3il_protocol::Stat;
use std::fmt::Write;

/// One row: a method on a task, aggregated over its training seeds as the
/// boards aggregate them (mean and sample standard deviation).
#[derive(Debug, Clone, PartialEq)]
pub struct ZooRow {
    /// The task as the paper titles it (`Aligning (T2)`).
    pub task: String,
    pub method: String,
    /// "trained here on d3il demos v1".
    pub data_source: String,
    /// `paper` or `quick`.
    pub protocol: String,
    /// The initial-state set (`aligning-v2.json`).
    pub initial_states: String,
    pub success: Stat,
    /// Conditional behaviour entropy (the paper's "Entropy").
    pub entropy: Stat,
    /// Behaviour entropy H(pi(beta)).
    pub behaviour: Option<Stat>,
    pub n_seeds: usize,
    /// The physics fingerprint of the build that made the results.
    pub physics_fingerprint: Option<String>,
}

/// What every format says about the rows.
pub const NOTE: &str = "The paper's methods trained here with the D3IL reference code on demonstrations recorded from our tasks (docs/zoo.md), evaluated here with the paper protocol; not the paper's numbers, never ranked with them. Mean ± sample standard deviation over training seeds (one seed: its value). Entropy: conditional behaviour entropy; H: behaviour entropy.";

const HEADER: [&str; 7] = [
    "Task",
    "Method",
    "Success rate",
    "Entropy",
    "H",
    "Seeds",
    "Physics fingerprint",
];

const CSV_HEADER: [&str; 14] = [
    "data_source",
    "task",
    "method",
    "protocol",
    "initial_states",
    "success_mean",
    "success_std",
    "conditional_entropy_mean",
    "conditional_entropy_std",
    "behaviour_entropy_mean",
    "behaviour_entropy_std",
    "n_seeds",
    "physics_fingerprint",
    "note",
];

/// The rows grouped by data source, in order of first appearance.
fn by_source(rows: &[ZooRow]) -> Vec<(&str, Vec<&ZooRow>)> {
    let mut out: Vec<(&str, Vec<&ZooRow>)> = vec![];
    for r in rows {
        match out.iter_mut().find(|(s, _)| *s == r.data_source) {
            Some((_, v)) => v.push(r),
            None => out.push((&r.data_source, vec![r])),
        }
    }
    out
}

fn stat(s: Stat, n: usize) -> String {
    mean_std(s.mean, s.std, n)
}

fn cells(r: &ZooRow) -> Vec<String> {
    let mut method = r.method.clone();
    if r.protocol != "paper" {
        method.push_str(&format!(" ({} protocol)", r.protocol));
    }
    vec![
        r.task.clone(),
        method,
        stat(r.success, r.n_seeds),
        stat(r.entropy, r.n_seeds),
        r.behaviour
            .map(|b| stat(b, r.n_seeds))
            .unwrap_or_else(|| "—".into()),
        r.n_seeds.to_string(),
        r.physics_fingerprint.clone().unwrap_or_else(|| "—".into()),
    ]
}

/// Renders the zoo's rows as one table per data source.
pub fn render_zoo(rows: &[ZooRow], format: Format) -> Result<String, TablesError> {
    if rows.is_empty() {
        return Err(TablesError::NoFigureData {
            figure: "zoo table",
            hint: "no zoo cell is in the database; `d3il serve` and `d3il tables --table zoo` load the zoo \
                   (assets/zoo, or --zoo DIR; docs/zoo.md)",
        });
    }
    let groups = by_source(rows);
    Ok(match format {
        Format::Markdown => {
            let mut out = String::new();
            for (source, rows) in &groups {
                let _ = writeln!(
                    out,
                    "**D3IL zoo: {}.** {}\n",
                    markdown_escape(source),
                    markdown_escape(NOTE)
                );
                let _ = writeln!(out, "| {} |", HEADER.join(" | "));
                let _ = writeln!(out, "| :-- | :-- | --: | --: | --: | --: | :-- |");
                for r in rows {
                    let c: Vec<String> = cells(r).iter().map(|s| markdown_escape(s)).collect();
                    let _ = writeln!(out, "| {} |", c.join(" | "));
                }
                out.push('\n');
            }
            out
        }
        Format::Latex => {
            let mut out = String::new();
            for (source, rows) in &groups {
                let _ = writeln!(out, "\\begin{{table}}[t]\n\\centering\\small");
                let _ = writeln!(
                    out,
                    "\\caption{{{}}}",
                    latex_escape(&format!("D3IL zoo: {source}. {NOTE}"))
                );
                let _ = writeln!(out, "\\begin{{tabular}}{{llrrrrl}}\n\\toprule");
                let h: Vec<String> = HEADER.iter().map(|s| latex_escape(s)).collect();
                let _ = writeln!(out, "{} \\\\\n\\midrule", h.join(" & "));
                for r in rows {
                    let c: Vec<String> = cells(r).iter().map(|s| latex_escape(s)).collect();
                    let _ = writeln!(out, "{} \\\\", c.join(" & "));
                }
                let _ = writeln!(out, "\\bottomrule\n\\end{{tabular}}\n\\end{{table}}\n");
            }
            out
        }
        Format::Csv => write_csv(
            &CSV_HEADER,
            rows.iter().map(|r| {
                let (b_mean, b_std) = r
                    .behaviour
                    .map(|b| (three_decimals(b.mean), three_decimals(b.std)))
                    .unwrap_or_default();
                vec![
                    r.data_source.clone(),
                    r.task.clone(),
                    r.method.clone(),
                    r.protocol.clone(),
                    r.initial_states.clone(),
                    three_decimals(r.success.mean),
                    three_decimals(r.success.std),
                    three_decimals(r.entropy.mean),
                    three_decimals(r.entropy.std),
                    b_mean,
                    b_std,
                    r.n_seeds.to_string(),
                    r.physics_fingerprint.clone().unwrap_or_default(),
                    "not the paper's numbers; never ranked with them".to_string(),
                ]
            }),
        )?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(method: &str, success: f64) -> ZooRow {
        ZooRow {
            task: "Aligning (T2)".into(),
            method: method.into(),
            data_source: "trained here on d3il demos v1".into(),
            protocol: "paper".into(),
            initial_states: "aligning-v2.json".into(),
            success: Stat {
                mean: success,
                std: 0.01,
            },
            entropy: Stat {
                mean: 0.5,
                std: 0.0,
            },
            behaviour: None,
            n_seeds: 3,
            physics_fingerprint: Some("0123456789abcdef".into()),
        }
    }

    #[test]
    fn every_format_names_the_data_source_and_every_row() {
        let rows = [row("BC-MLP", 0.8), row("BESO", 0.9)];
        for f in Format::ALL {
            let out = render_zoo(&rows, f).unwrap();
            assert!(out.contains("d3il demos v1"), "{f}: {out}");
            assert!(out.contains("BC-MLP") && out.contains("BESO"), "{f}: {out}");
            assert!(out.contains("0.800"), "{f}: {out}");
        }
        let md = render_zoo(&rows, Format::Markdown).unwrap();
        assert!(md.contains("0.800 ± 0.010"), "{md}");
        assert!(render_zoo(&[], Format::Csv).is_err());
    }
}
